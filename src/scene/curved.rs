//! Curved patches: the facets of a tessellated surface of revolution (a cylinder, a cone:
//! bores, holes, outer walls, chamfers) grouped into one patch with one map frame, so a
//! finish's slope map runs over it continuously instead of restarting on every facet
//! (docs/texture.md, "Curved regions").
//!
//! A patch is grown over the planar regions (`scene::regions`) that hold no inspected
//! face: two edge-adjacent regions join when their normals differ by at most
//! `smooth_angle_deg`. A group of at least `min_facets` regions becomes a patch when it
//! fits a surface of revolution with a straight generatrix: an axis `a` to which every
//! facet normal makes the same angle (within `fit_angle_deg`), and an axis line that the
//! normal line through every facet centroid meets (within `fit_distance`, a fraction of
//! the radius). Groups that do not fit keep their facets as planar regions, as before.
//!
//! The map frame of a patch: a point `centre` on the axis (at the patch's mean height),
//! the axis `a`, a reference radial direction `e0` (the area-weighted mean radial
//! direction of its facets; for a full revolution that of its first facet), the mean
//! radius, and the generatrix direction t = sin(beta) r + cos(beta) a in the (radial,
//! axial) plane (r the radial unit vector), oriented so that the outward normal is
//! (a x r) x t = cos(beta) r - sin(beta) a. A point p maps to
//! u = radius * theta (theta about `a` from `e0`) and v = rho sin(beta) + h cos(beta)
//! (rho its distance from the axis, h its height along `a` from `centre`): a function of
//! the position alone, so two facets sharing an edge give the same (u, v) there.
//!
//! A group that does not fit (a fillet on a torus, a sphere, a free-form CAD patch)
//! becomes a **triplanar** patch (`PatchKind::Triplanar`): the map is projected along
//! each of the three world axes and the three slopes are blended with weights
//! |n_k|^`TRIPLANAR_SHARPNESS` / sum (n the patch's smooth normal, interpolated from
//! per-vertex normals: [`smooth_corner_normals`]). Every projection and the smooth
//! normal are functions of the position on the surface, so the finish runs over the
//! facet edges without a seam (docs/texture.md, "Curved regions").

use std::collections::HashMap;

use glam::{DMat3, DVec2, DVec3, Vec3};

use super::mesh::{FACE_OTHER, Mesh};
use super::regions::PlanarRegion;

/// How facets are grouped into curved patches.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurvedTolerance {
    /// Largest angle between the normals of two neighbouring facets of one patch,
    /// degrees. Default 20 (a circle of 18 or more segments).
    pub smooth_angle_deg: f64,
    /// Fewest facets of a patch. Default 4.
    pub min_facets: usize,
    /// Largest deviation of a facet normal's angle to the axis from the patch's mean,
    /// degrees. Default 1.
    pub fit_angle_deg: f64,
    /// Largest distance between a facet's normal line and the axis, as a fraction of the
    /// patch's radius (at least 1 um). Default 0.01.
    pub fit_distance: f64,
    /// Groups that fit no surface of revolution become triplanar patches (else they
    /// keep their facets as planar regions). Default true.
    pub triplanar: bool,
}

impl Default for CurvedTolerance {
    fn default() -> Self {
        CurvedTolerance {
            smooth_angle_deg: 20.0,
            min_facets: 4,
            fit_angle_deg: 1.0,
            fit_distance: 0.01,
            triplanar: true,
        }
    }
}

/// How a curved patch's map is projected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PatchKind {
    /// About an axis, along a straight generatrix (a surface of revolution).
    Revolved,
    /// Along the three world axes, blended by the smooth normal (any other smooth
    /// surface). Its `centre` is the facets' area-weighted centroid, `axis` = +Z, `e0` =
    /// +X; `radius`, `sin_beta`, `cos_beta` and `full_turn` are unused (0, 0, 1, false).
    Triplanar,
}

/// The exponent of the triplanar blend weights |n_k|^p: 4 keeps one projection
/// dominant up to about 35 degrees from its axis and blends over the diagonals.
pub const TRIPLANAR_SHARPNESS: f32 = 4.0;

/// One curved patch and its map frame.
#[derive(Clone, Debug, PartialEq)]
pub struct CurvedPatch {
    /// The projection of its map.
    pub kind: PatchKind,
    /// Its planar regions (facets), ascending ids.
    pub regions: Vec<u32>,
    /// Total facet area, mm^2.
    pub area: f64,
    /// A point on the axis at the patch's mean height.
    pub centre: Vec3,
    /// Unit axis.
    pub axis: Vec3,
    /// Unit radial direction where theta = 0 (perpendicular to `axis`).
    pub e0: Vec3,
    /// Area-weighted mean distance of the facet centroids from the axis, mm.
    pub radius: f32,
    /// The generatrix direction in the (radial, axial) plane: (sin beta, cos beta).
    pub sin_beta: f32,
    pub cos_beta: f32,
    /// The facets go all the way round the axis (a bore, a hole, an outer wall).
    pub full_turn: bool,
}

impl CurvedPatch {
    /// (Revolved patches.) (u, v) of `p`, mm: arc length about the axis at the patch radius from `e0`, and
    /// the distance along the generatrix (see the module docs). theta is in (-pi, pi].
    pub fn uv(&self, p: Vec3) -> [f32; 2] {
        let (c, a, e0) = (
            self.centre.as_dvec3(),
            self.axis.as_dvec3(),
            self.e0.as_dvec3(),
        );
        let d = p.as_dvec3() - c;
        let h = d.dot(a);
        let r = d - a * h;
        let e1 = a.cross(e0);
        let theta = r.dot(e1).atan2(r.dot(e0));
        let rho = r.length();
        [
            (self.radius as f64 * theta) as f32,
            (rho * self.sin_beta as f64 + h * self.cos_beta as f64) as f32,
        ]
    }

    /// (Revolved patches.) Unit tangents at `p`: along increasing u (about the axis) and increasing v (along
    /// the generatrix); their cross product is the outward normal of the surface.
    pub fn tangents(&self, p: Vec3) -> (Vec3, Vec3) {
        let a = self.axis;
        let d = p - self.centre;
        let r = (d - a * d.dot(a)).normalize_or_zero();
        let t_u = a.cross(r);
        let t_v = r * self.sin_beta + a * self.cos_beta;
        (t_u, t_v)
    }
}

/// Eigenvector of the smallest eigenvalue of a symmetric 3 x 3 matrix (cyclic Jacobi).
fn smallest_eigenvector(m: DMat3) -> DVec3 {
    let mut a = m.to_cols_array_2d();
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..50 {
        let off = a[0][1].powi(2) + a[0][2].powi(2) + a[1][2].powi(2);
        if off < 1e-30 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q].abs() < 1e-300 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for row in &mut a {
                let (akp, akq) = (row[p], row[q]);
                row[p] = c * akp - s * akq;
                row[q] = s * akp + c * akq;
            }
            let (rp, rq) = (a[p], a[q]);
            for k in 0..3 {
                a[p][k] = c * rp[k] - s * rq[k];
                a[q][k] = s * rp[k] + c * rq[k];
            }
            for row in &mut v {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let k = (0..3)
        .min_by(|&i, &j| a[i][i].total_cmp(&a[j][j]))
        .unwrap_or(0);
    DVec3::new(v[0][k], v[1][k], v[2][k]).normalize_or_zero()
}

/// A facet of a candidate group: area, unit normal, centroid.
struct Facet {
    id: u32,
    area: f64,
    normal: DVec3,
    centroid: DVec3,
}

/// Fits a surface of revolution to `facets`; None if they do not fit the tolerances.
fn fit(facets: &[Facet], tol: &CurvedTolerance) -> Option<CurvedPatch> {
    let w: f64 = facets.iter().map(|f| f.area).sum();
    if w <= 0.0 {
        return None;
    }
    // The axis: every normal makes the same angle with it, so it is the direction in
    // which the normals vary least.
    let mean_n = facets.iter().map(|f| f.normal * f.area).sum::<DVec3>() / w;
    let mut cov = DMat3::ZERO;
    for f in facets {
        let d = f.normal - mean_n;
        cov += DMat3::from_cols(d * d.x, d * d.y, d * d.z) * f.area;
    }
    let a = smallest_eigenvector(cov);
    if a == DVec3::ZERO {
        return None;
    }
    let cos_axis = mean_n.dot(a);
    let max_dev = tol.fit_angle_deg.to_radians().sin();
    if facets
        .iter()
        .any(|f| (f.normal.dot(a) - cos_axis).abs() > max_dev)
    {
        return None;
    }
    // The axis line: the point of the plane perpendicular to `a` nearest (least squares)
    // to every facet's normal line (all meet the axis on a surface of revolution).
    let b1 = a.any_orthonormal_vector();
    let b2 = a.cross(b1);
    let to2 = |p: DVec3| DVec2::new(p.dot(b1), p.dot(b2));
    let mut lhs = [[0.0f64; 2]; 2];
    let mut rhs = DVec2::ZERO;
    let mut radial = Vec::with_capacity(facets.len());
    for f in facets {
        let m = to2(f.normal);
        if m.length() < 1e-6 {
            return None; // a facet facing along the axis: not a wall of revolution
        }
        let m = m.normalize();
        let p = to2(f.centroid);
        // (I - m m^T)
        let q = [[1.0 - m.x * m.x, -m.x * m.y], [-m.x * m.y, 1.0 - m.y * m.y]];
        for i in 0..2 {
            for j in 0..2 {
                lhs[i][j] += f.area * q[i][j];
            }
        }
        rhs += f.area * DVec2::new(q[0][0] * p.x + q[0][1] * p.y, q[1][0] * p.x + q[1][1] * p.y);
        radial.push(m);
    }
    let det = lhs[0][0] * lhs[1][1] - lhs[0][1] * lhs[1][0];
    let scale = lhs[0][0] + lhs[1][1];
    if det.abs() <= 1e-6 * scale * scale || !det.is_finite() {
        return None; // the normal lines are (nearly) parallel: no axis to find
    }
    let c2 = DVec2::new(
        (rhs.x * lhs[1][1] - rhs.y * lhs[0][1]) / det,
        (lhs[0][0] * rhs.y - lhs[1][0] * rhs.x) / det,
    );
    let h_mean = facets
        .iter()
        .map(|f| f.centroid.dot(a) * f.area)
        .sum::<f64>()
        / w;
    let centre = b1 * c2.x + b2 * c2.y + a * h_mean;
    // Radius, orientation of the generatrix, fit of the axis line.
    let mut radius = 0.0;
    let (mut nr, mut na) = (0.0, 0.0);
    let mut mean_dir = DVec3::ZERO;
    for (f, m) in facets.iter().zip(&radial) {
        let d = f.centroid - centre;
        let r = d - a * d.dot(a);
        let rho = r.length();
        if rho < 1e-9 {
            return None;
        }
        let rhat = r / rho;
        radius += rho * f.area;
        nr += f.normal.dot(rhat) * f.area;
        na += f.normal.dot(a) * f.area;
        mean_dir += rhat * f.area;
        // Distance of the facet's normal line from the axis, in the plane.
        let p = to2(f.centroid) - c2;
        let miss = (p - *m * p.dot(*m)).length();
        if miss > (tol.fit_distance * rho).max(1e-3) {
            return None;
        }
    }
    radius /= w;
    let len = (nr * nr + na * na).sqrt();
    if len < 1e-9 {
        return None;
    }
    let (cos_beta, sin_beta) = (nr / len, -na / len);
    // The reference direction: the patch's mean radial direction, or for a full turn
    // (where that mean vanishes) the first facet's.
    let first = {
        let d = facets[0].centroid - centre;
        (d - a * d.dot(a)).normalize()
    };
    let full_turn = mean_dir.length() < 0.05 * w;
    let e0 = if full_turn {
        first
    } else {
        mean_dir.normalize()
    };
    let mut regions: Vec<u32> = facets.iter().map(|f| f.id).collect();
    regions.sort_unstable();
    Some(CurvedPatch {
        kind: PatchKind::Revolved,
        regions,
        area: w,
        centre: centre.as_vec3(),
        axis: a.as_vec3(),
        e0: e0.as_vec3(),
        radius: radius as f32,
        sin_beta: sin_beta as f32,
        cos_beta: cos_beta as f32,
        full_turn,
    })
}

/// A triplanar patch over `facets` (a smooth group that is no surface of revolution).
fn triplanar(facets: &[Facet]) -> Option<CurvedPatch> {
    let w: f64 = facets.iter().map(|f| f.area).sum();
    if w <= 0.0 || w.is_nan() {
        return None;
    }
    let centre = facets.iter().map(|f| f.centroid * f.area).sum::<DVec3>() / w;
    let mut regions: Vec<u32> = facets.iter().map(|f| f.id).collect();
    regions.sort_unstable();
    Some(CurvedPatch {
        kind: PatchKind::Triplanar,
        regions,
        area: w,
        centre: centre.as_vec3(),
        axis: Vec3::Z,
        e0: Vec3::X,
        radius: 0.0,
        sin_beta: 0.0,
        cos_beta: 1.0,
        full_turn: false,
    })
}

/// Triplanar blend weights at unit normal `n`: |n_k|^[`TRIPLANAR_SHARPNESS`], summing
/// to 1 (the shader's `triplanar_weights`).
pub fn triplanar_weights(n: Vec3) -> [f32; 3] {
    let a = n.abs();
    let w = [a.x, a.y, a.z].map(|c| (c * c) * (c * c));
    let s = w[0] + w[1] + w[2];
    if s > 0.0 {
        w.map(|x| x / s)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// A unit normal octahedral-coded as one float (`Tri`'s w, src/gpu_interface.in): the
/// octahedron's two coordinates in [-1, 1] quantised to `OCT_STEPS` steps (under 0.1 degree
/// at worst), coded as the integer u * `OCT_LEVELS` + v, which f32 holds exactly.
pub fn encode_normal(n: Vec3) -> f32 {
    use crate::gpu_interface::{OCT_LEVELS, OCT_STEPS};
    let n = n / (n.x.abs() + n.y.abs() + n.z.abs()).max(1e-30);
    let (x, y) = if n.z >= 0.0 {
        (n.x, n.y)
    } else {
        ((1.0 - n.y.abs()) * sign(n.x), (1.0 - n.x.abs()) * sign(n.y))
    };
    let q = |c: f32| ((c.clamp(-1.0, 1.0) * 0.5 + 0.5) * OCT_STEPS as f32).round() as u32;
    (q(x) * OCT_LEVELS + q(y)) as f32
}

/// +1 or -1 (+1 at zero): the octahedral fold's sign.
fn sign(x: f32) -> f32 {
    if x >= 0.0 { 1.0 } else { -1.0 }
}

/// The unit normal of [`encode_normal`]'s code (the shader's `oct_decode`).
pub fn decode_normal(code: f32) -> Vec3 {
    use crate::gpu_interface::{OCT_LEVELS, OCT_STEPS};
    let k = code as u32;
    let c = |i: u32| i as f32 / OCT_STEPS as f32 * 2.0 - 1.0;
    let (x, y) = (c(k / OCT_LEVELS), c(k % OCT_LEVELS));
    let z = 1.0 - x.abs() - y.abs();
    let (x, y) = if z < 0.0 {
        ((1.0 - y.abs()) * sign(x), (1.0 - x.abs()) * sign(y))
    } else {
        (x, y)
    };
    Vec3::new(x, y, z).normalize()
}

/// Smooth per-corner normals of the triangles of triplanar patches: at each corner the
/// area-weighted mean normal of the patch's triangles that share its position (welded,
/// 0.25 um), so neighbouring facets agree on their common edge; `None` for triangles
/// outside a triplanar patch. `region_of`: each triangle's region; `curved_of`: the
/// patch of each region (`u32::MAX`: none).
pub fn smooth_corner_normals(
    mesh: &Mesh,
    region_of: &[u32],
    patches: &[CurvedPatch],
    curved_of: &[u32],
) -> Vec<Option<[Vec3; 3]>> {
    let patch_of = |t: usize| -> Option<u32> {
        let r = *region_of.get(t)?;
        let p = *curved_of.get(r as usize)?;
        (p != u32::MAX && patches.get(p as usize)?.kind == PatchKind::Triplanar).then_some(p)
    };
    let welded = super::regions::weld_positions(mesh, 2.5e-4);
    // Sum of area-weighted normals per (patch, welded vertex).
    let mut sums: HashMap<(u32, u32), DVec3> = HashMap::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let Some(p) = patch_of(t) else { continue };
        let [a, b, c] = tri.map(|i| mesh.positions[i as usize].as_dvec3());
        let n2 = (b - a).cross(c - a); // twice the area times the unit normal
        for &i in tri {
            *sums.entry((p, welded[i as usize])).or_default() += n2;
        }
    }
    mesh.triangles
        .iter()
        .enumerate()
        .map(|(t, tri)| {
            let p = patch_of(t)?;
            Some(tri.map(|i| {
                sums.get(&(p, welded[i as usize]))
                    .map_or(Vec3::Z, |s| s.normalize_or_zero().as_vec3())
            }))
        })
        .collect()
}

/// The curved patches of `mesh`: groups of its planar `regions` (ids = indices) without
/// an inspected face that fit a surface of revolution, or else (`tol.triplanar`) any
/// other smooth group, projected triplanar (module docs). `region_of`: each
/// triangle's region (`regions::region_per_triangle`). Patches are ordered by their
/// smallest region id.
pub fn curved_patches(
    mesh: &Mesh,
    regions: &[PlanarRegion],
    region_of: &[u32],
    tol: &CurvedTolerance,
) -> Vec<CurvedPatch> {
    let n = regions.len();
    let candidate = |r: u32| (r as usize) < n && regions[r as usize].face == FACE_OTHER;
    // Region adjacency over shared edges (vertices welded by position, 0.25 um grid).
    let welded = super::regions::weld_positions(mesh, 2.5e-4);
    let mut edges: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let r = region_of.get(t).copied().unwrap_or(u32::MAX);
        if !candidate(r) {
            continue;
        }
        for k in 0..3 {
            let (a, b) = (welded[tri[k] as usize], welded[tri[(k + 1) % 3] as usize]);
            if a != b {
                edges.entry((a.min(b), a.max(b))).or_default().push(r);
            }
        }
    }
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn root(parent: &mut [u32], mut x: u32) -> u32 {
        while parent[x as usize] != x {
            parent[x as usize] = parent[parent[x as usize] as usize];
            x = parent[x as usize];
        }
        x
    }
    let cos_smooth = tol.smooth_angle_deg.to_radians().cos();
    let mut keys: Vec<&(u32, u32)> = edges.keys().collect();
    keys.sort_unstable();
    for k in keys {
        let rs = &edges[k];
        for i in 0..rs.len() {
            for j in i + 1..rs.len() {
                let (a, b) = (rs[i], rs[j]);
                if a == b {
                    continue;
                }
                let (na, nb) = (regions[a as usize].normal, regions[b as usize].normal);
                if (na.dot(nb) as f64) >= cos_smooth {
                    let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
                    if ra != rb {
                        parent[ra.max(rb) as usize] = ra.min(rb);
                    }
                }
            }
        }
    }
    let mut groups: HashMap<u32, Vec<u32>> = HashMap::new();
    for r in 0..n as u32 {
        if candidate(r) {
            let g = root(&mut parent, r);
            groups.entry(g).or_default().push(r);
        }
    }
    let mut groups: Vec<Vec<u32>> = groups
        .into_values()
        .filter(|g| g.len() >= tol.min_facets.max(3))
        .collect();
    groups.sort_unstable_by_key(|g| g[0]);
    groups
        .iter()
        .filter_map(|g| {
            let facets: Vec<Facet> = g
                .iter()
                .map(|&r| {
                    let reg = &regions[r as usize];
                    Facet {
                        id: r,
                        area: reg.area,
                        normal: reg.normal.as_dvec3(),
                        centroid: reg.centre.as_dvec3(),
                    }
                })
                .collect();
            fit(&facets, tol).or_else(|| {
                if tol.triplanar {
                    triplanar(&facets)
                } else {
                    None
                }
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::regions::{RegionTolerance, planar_regions, region_per_triangle};
    use crate::scene::{FlangeParams, Variant, flange, testbody};

    fn patches(mesh: &Mesh) -> (Vec<PlanarRegion>, Vec<CurvedPatch>) {
        let found = planar_regions(mesh, &RegionTolerance::default());
        let region_of = region_per_triangle(mesh, &found);
        let p = curved_patches(mesh, &found, &region_of, &CurvedTolerance::default());
        (found, p)
    }

    #[test]
    fn the_flange_has_seven_surfaces_of_revolution_and_the_test_body_none() {
        // Neither revolved nor triplanar patches: the test bodies render as before.
        for v in [Variant::B, Variant::M] {
            assert!(patches(&testbody(v)).1.is_empty(), "{v:?}");
        }
        let fp = FlangeParams::default();
        let (regions, p) = patches(&flange(&fp));
        // Outer wall, chamfer, bore and 4 holes; every facet in one patch.
        assert_eq!(p.len(), 3 + fp.hole_count as usize);
        let facets: usize = p.iter().map(|c| c.regions.len()).sum();
        assert_eq!(facets, fp.facet_count());
        assert_eq!(regions.len(), fp.facet_count() + 2);
        let mut sizes: Vec<usize> = p.iter().map(|c| c.regions.len()).collect();
        sizes.sort_unstable();
        let h = fp.hole_segments as usize;
        let o = fp.outer_segments as usize;
        assert_eq!(
            sizes,
            [h, h, h, h, fp.bore_segments as usize, o, o],
            "{sizes:?}"
        );
        for c in &p {
            assert_eq!(c.kind, PatchKind::Revolved);
            assert!(c.full_turn);
            assert!((c.axis.z.abs() - 1.0).abs() < 1e-6, "axis {}", c.axis);
            // The generatrix: vertical walls (beta 0), the chamfer at 45 degrees.
            let slanted = (c.sin_beta.abs() - 0.5f32.sqrt()).abs() < 1e-3;
            assert!(c.sin_beta.abs() < 1e-4 || slanted, "{c:?}");
            // The outward normal (cos beta r - sin beta a) matches each facet's.
            for &r in &c.regions {
                let reg = &regions[r as usize];
                let (tu, tv) = c.tangents(reg.centre);
                assert!(tu.cross(tv).dot(reg.normal) > 0.99, "{c:?}");
            }
        }
        let bore = p
            .iter()
            .find(|c| c.regions.len() == fp.bore_segments as usize)
            .unwrap();
        let centre = glam::Vec2::new(bore.centre.x, bore.centre.y);
        assert!(centre.length() < 1e-4, "bore axis at {centre}");
        // The facet centroids lie at R cos(pi / n) from the axis.
        let want = fp.bore_radius * (std::f64::consts::PI / fp.bore_segments as f64).cos();
        assert!((bore.radius as f64 - want).abs() < 1e-4, "{}", bore.radius);
    }

    #[test]
    fn a_dome_is_one_triplanar_patch_with_smooth_corner_normals() {
        let (rings, segs) = (8, 32);
        let mesh = crate::scene::procedural::dome(10.0, rings, segs);
        let (regions, p) = patches(&mesh);
        // Every facet of the dome (quads and the pole's fan), not the bottom disc.
        assert_eq!(p.len(), 1, "{p:?}");
        assert_eq!(p[0].kind, PatchKind::Triplanar);
        assert_eq!(p[0].regions.len(), ((rings - 1) * segs + segs) as usize);
        assert_eq!(regions.len(), p[0].regions.len() + 1);
        // Without triplanar patches the dome keeps its facets planar (as before).
        let region_of = region_per_triangle(&mesh, &regions);
        let off = CurvedTolerance {
            triplanar: false,
            ..Default::default()
        };
        assert!(curved_patches(&mesh, &regions, &region_of, &off).is_empty());
        let mut curved_of = vec![u32::MAX; regions.len()];
        for &r in &p[0].regions {
            curved_of[r as usize] = 0;
        }
        let normals = smooth_corner_normals(&mesh, &region_of, &p, &curved_of);
        // Each corner's normal is the sphere's within a facet's half angle, and every
        // triangle holding a position gives it the same normal.
        let mut at: HashMap<[u32; 3], Vec3> = HashMap::new();
        let mut outside = 0;
        for (t, n) in normals.iter().enumerate() {
            let Some(n) = n else {
                outside += 1;
                continue;
            };
            for (k, &i) in mesh.triangles[t].iter().enumerate() {
                let q = mesh.positions[i as usize];
                let want = q.normalize();
                assert!(
                    n[k].dot(want) > (6f32).to_radians().cos(),
                    "{} {want}",
                    n[k]
                );
                let key = q.to_array().map(f32::to_bits);
                let prev = *at.entry(key).or_insert(n[k]);
                assert_eq!(prev, n[k], "corner {q}");
            }
        }
        assert_eq!(outside, segs as usize, "the bottom disc's triangles");
        // The octahedral code keeps a normal within 0.1 degrees, everywhere.
        for n in normals
            .iter()
            .flatten()
            .flatten()
            .chain(&[Vec3::X, -Vec3::Z, -Vec3::Y])
        {
            let back = decode_normal(encode_normal(*n));
            assert!(back.dot(*n) > 0.1f32.to_radians().cos(), "{n} -> {back}");
        }
        let w = triplanar_weights(Vec3::new(0.6, 0.0, 0.8));
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6 && w[1] == 0.0 && w[2] > w[0]);
        assert_eq!(triplanar_weights(Vec3::X), [1.0, 0.0, 0.0]);
    }

    #[test]
    fn uv_is_a_function_of_position_and_follows_the_surface() {
        let fp = FlangeParams::default();
        let (_, p) = patches(&flange(&fp));
        let bore = p
            .iter()
            .find(|c| c.regions.len() == fp.bore_segments as usize)
            .unwrap();
        // Around the axis u grows by radius x angle, along it v by the height (up or
        // down, with the generatrix's orientation).
        let at = |deg: f32, z: f32| {
            let e1 = bore.axis.cross(bore.e0);
            let (s, c) = deg.to_radians().sin_cos();
            bore.centre + (bore.e0 * c + e1 * s) * bore.radius + bore.axis * z
        };
        let [u0, v0] = bore.uv(at(10.0, 0.0));
        let [u1, v1] = bore.uv(at(30.0, 1.0));
        assert!((u1 - u0 - bore.radius * 20f32.to_radians()).abs() < 1e-4);
        assert!(((v1 - v0).abs() - 1.0).abs() < 1e-5);
    }
}
