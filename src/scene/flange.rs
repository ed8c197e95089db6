//! The second example part (docs/testbody.md, "Flange"): a flat flange with a central
//! bore, a bolt circle of through holes and a 45-degree chamfer on its top outer edge,
//! generated in code. Unlike the polyhedral test body it has curved surfaces: the outer
//! cylinder, the chamfer (a cone), the bore and the hole walls, tessellated into planar
//! facets (one quad of two triangles per segment, full height), and two planar faces:
//! the top annulus (inside the chamfer, around the bore and the holes) and the bottom.
//! Watertight by index; outward normals; millimetres, bottom at z = 0, axis = +Z.

use glam::{DVec2, Vec3};

use super::mesh::{Mesh, TriLabel};

/// The flange's dimensions, mm, and tessellation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlangeParams {
    pub outer_radius: f64,
    pub thickness: f64,
    pub bore_radius: f64,
    /// Chamfer leg (45 degrees) on the top outer edge.
    pub chamfer: f64,
    pub hole_count: u32,
    pub hole_radius: f64,
    pub hole_circle_radius: f64,
    /// Segments of the outer circle (and the chamfer), of the bore, of each hole.
    pub outer_segments: u32,
    pub bore_segments: u32,
    pub hole_segments: u32,
}

impl Default for FlangeParams {
    fn default() -> Self {
        FlangeParams {
            outer_radius: 30.0,
            thickness: 8.0,
            bore_radius: 10.0,
            chamfer: 1.5,
            hole_count: 4,
            hole_radius: 3.0,
            hole_circle_radius: 20.0,
            outer_segments: 96,
            bore_segments: 64,
            hole_segments: 24,
        }
    }
}

impl FlangeParams {
    /// Number of curved-surface facets: outer wall, chamfer, bore, hole walls.
    pub fn facet_count(&self) -> usize {
        (2 * self.outer_segments + self.bore_segments + self.hole_count * self.hole_segments)
            as usize
    }
}

/// A closed polygonal circle: `n` points at angle offset 0 (ccw seen from +Z).
fn circle(centre: DVec2, r: f64, n: u32) -> Vec<DVec2> {
    (0..n)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            centre + DVec2::new(a.cos(), a.sin()) * r
        })
        .collect()
}

struct Builder {
    mesh: Mesh,
}

impl Builder {
    fn ring(&mut self, pts: &[DVec2], z: f64) -> Vec<u32> {
        pts.iter()
            .map(|p| {
                self.mesh
                    .positions
                    .push(Vec3::new(p.x as f32, p.y as f32, z as f32));
                self.mesh.positions.len() as u32 - 1
            })
            .collect()
    }

    /// A triangle wound so its normal points along `out` (outward).
    fn tri(&mut self, t: [u32; 3], out: glam::DVec3) {
        let [a, b, c] = t.map(|i| self.mesh.positions[i as usize].as_dvec3());
        let n = (b - a).cross(c - a);
        let t = if n.dot(out) < 0.0 {
            [t[0], t[2], t[1]]
        } else {
            t
        };
        self.mesh.triangles.push(t);
        self.mesh.labels.push(TriLabel::default());
    }

    /// A wall between two rings of equal size: one quad (two triangles) per segment,
    /// outward away from `axis_centre` when `outward`, towards it otherwise.
    fn wall(&mut self, lo: &[u32], hi: &[u32], centre: DVec2, outward: bool) {
        let n = lo.len();
        for k in 0..n {
            let (a, b) = (lo[k], lo[(k + 1) % n]);
            let (c, d) = (hi[(k + 1) % n], hi[k]);
            let mid = (self.mesh.positions[a as usize] + self.mesh.positions[b as usize])
                .as_dvec3()
                * 0.5;
            let radial = (mid.truncate() - centre).extend(0.0);
            let out = if outward { radial } else { -radial };
            // Chamfer quads lean inward; their normal still has this radial component.
            self.tri([a, b, c], out);
            self.tri([a, c, d], out);
        }
    }

    /// A planar cap at height z: the polygon `outer` minus `holes` (earcut), facing
    /// +Z when `up`.
    fn cap(&mut self, outer: &[u32], holes: &[Vec<u32>], up: bool) {
        let mut idx: Vec<u32> = outer.to_vec();
        let mut hole_starts = Vec::new();
        for h in holes {
            hole_starts.push(idx.len() as u32);
            // Holes run clockwise for earcut; any orientation works, normals are fixed below.
            idx.extend(h.iter().rev());
        }
        let pts: Vec<[f64; 2]> = idx
            .iter()
            .map(|&i| {
                let p = self.mesh.positions[i as usize];
                [p.x as f64, p.y as f64]
            })
            .collect();
        let mut out: Vec<u32> = Vec::new();
        earcut::Earcut::new().earcut(pts.iter().copied(), &hole_starts, &mut out);
        let dir = if up {
            glam::DVec3::Z
        } else {
            glam::DVec3::NEG_Z
        };
        for t in out.chunks_exact(3) {
            self.tri(
                [idx[t[0] as usize], idx[t[1] as usize], idx[t[2] as usize]],
                dir,
            );
        }
    }
}

/// The flange mesh (unlabelled: scenes choose its inspected faces with `inspect`).
pub fn flange(p: &FlangeParams) -> Mesh {
    let mut b = Builder {
        mesh: Mesh::default(),
    };
    let o = DVec2::ZERO;
    let (t, c) = (p.thickness, p.chamfer);
    let outer = circle(o, p.outer_radius, p.outer_segments);
    let chamfer_in = circle(o, p.outer_radius - c, p.outer_segments);
    let bore = circle(o, p.bore_radius, p.bore_segments);
    let holes: Vec<(DVec2, Vec<DVec2>)> = (0..p.hole_count)
        .map(|k| {
            let a = std::f64::consts::TAU * (k as f64 + 0.5) / p.hole_count as f64;
            let centre = DVec2::new(a.cos(), a.sin()) * p.hole_circle_radius;
            (centre, circle(centre, p.hole_radius, p.hole_segments))
        })
        .collect();

    let outer_lo = b.ring(&outer, 0.0);
    let outer_hi = b.ring(&outer, t - c);
    let top_out = b.ring(&chamfer_in, t);
    let bore_lo = b.ring(&bore, 0.0);
    let bore_hi = b.ring(&bore, t);
    let hole_rings: Vec<(DVec2, Vec<u32>, Vec<u32>)> = holes
        .iter()
        .map(|(centre, pts)| (*centre, b.ring(pts, 0.0), b.ring(pts, t)))
        .collect();

    b.wall(&outer_lo, &outer_hi, o, true);
    b.wall(&outer_hi, &top_out, o, true);
    b.wall(&bore_lo, &bore_hi, o, false);
    for (centre, lo, hi) in &hole_rings {
        b.wall(lo, hi, *centre, false);
    }
    let mut top_holes = vec![bore_hi.clone()];
    top_holes.extend(hole_rings.iter().map(|h| h.2.clone()));
    b.cap(&top_out, &top_holes, true);
    let mut bottom_holes = vec![bore_lo.clone()];
    bottom_holes.extend(hole_rings.iter().map(|h| h.1.clone()));
    b.cap(&outer_lo, &bottom_holes, false);
    b.mesh
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::regions::{RegionTolerance, planar_regions};
    use std::collections::HashMap;

    /// Closed and consistently oriented: every undirected edge is used by exactly two
    /// triangles, once in each direction; the enclosed volume is the analytic one of
    /// the polygonal solid (within the tessellation).
    #[test]
    fn flange_is_watertight_with_outward_normals() {
        let p = FlangeParams::default();
        let m = flange(&p);
        assert!(m.degenerate_triangles().is_empty());
        let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
        for t in &m.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
            }
        }
        assert!(edges.values().all(|&v| v == 0), "every edge once each way");
        // Divergence theorem: V = sum over triangles of a . (b x c) / 6 > 0.
        let vol: f64 = (0..m.triangles.len())
            .map(|t| {
                let [a, b, c] = m.corners(t).map(|v| v.as_dvec3());
                a.dot(b.cross(c)) / 6.0
            })
            .sum();
        let poly =
            |r: f64, n: u32| 0.5 * n as f64 * r * r * (std::f64::consts::TAU / n as f64).sin();
        let ring = poly(p.outer_radius, p.outer_segments) * p.thickness
            - poly(p.bore_radius, p.bore_segments) * p.thickness
            - p.hole_count as f64 * poly(p.hole_radius, p.hole_segments) * p.thickness;
        // The chamfer removes about a triangle of 1.5 x 1.5 / 2 swept around the rim.
        let chamfer =
            std::f64::consts::TAU * (p.outer_radius - p.chamfer / 3.0) * p.chamfer * p.chamfer
                / 2.0;
        assert!(
            ((vol - (ring - chamfer)) / vol).abs() < 2e-3,
            "volume {vol} vs {}",
            ring - chamfer
        );
    }

    /// Region detection finds its two planar faces exactly (top annulus and bottom, with
    /// their analytic areas) and splits no curved surface into slivers: every other
    /// region is one full facet (a quad of two triangles), one per segment.
    #[test]
    fn regions_are_the_two_faces_and_whole_facets() {
        let p = FlangeParams::default();
        let m = flange(&p);
        let regions = planar_regions(&m, &RegionTolerance::default());
        assert_eq!(regions.len(), 2 + p.facet_count());
        assert_eq!(p.facet_count(), 352);
        let poly =
            |r: f64, n: u32| 0.5 * n as f64 * r * r * (std::f64::consts::TAU / n as f64).sin();
        let holes = poly(p.bore_radius, p.bore_segments)
            + p.hole_count as f64 * poly(p.hole_radius, p.hole_segments);
        let top = poly(p.outer_radius - p.chamfer, p.outer_segments) - holes;
        let bottom = poly(p.outer_radius, p.outer_segments) - holes;
        let flat: Vec<_> = regions
            .iter()
            .filter(|r| r.normal.z.abs() > 0.9999)
            .collect();
        assert_eq!(flat.len(), 2);
        for r in &flat {
            let want = if r.normal.z > 0.0 { top } else { bottom };
            assert!(
                (r.area - want).abs() < 1e-6 * want,
                "area {} vs {want}",
                r.area
            );
        }
        for r in regions.iter().filter(|r| r.normal.z.abs() <= 0.9999) {
            assert_eq!(r.triangles.len(), 2, "region {} is one whole facet", r.id);
        }
        // Chamfer facets lean 45 degrees; walls are vertical.
        let chamfer = regions
            .iter()
            .filter(|r| (r.normal.z - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-3)
            .count();
        assert_eq!(chamfer, p.outer_segments as usize);
        let vertical = regions.iter().filter(|r| r.normal.z.abs() < 1e-6).count();
        assert_eq!(vertical, p.facet_count() - p.outer_segments as usize);
    }
}
