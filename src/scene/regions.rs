//! Planar regions of a polyhedral mesh: maximal edge-connected sets of coplanar
//! triangles, found automatically so finishes can cover every face of any imported part
//! (docs/mesh-format.md, "Planar regions").
//!
//! Two edge-adjacent triangles are coplanar when their normals differ by at most
//! `angle_deg` and every corner of the candidate lies within `distance_mm` of the
//! region's plane (the plane of the triangle the region grew from). Edges are matched by
//! vertex position (welded on a grid of `distance_mm / 4`), so meshes with duplicated
//! vertices per face (flat-shaded glTF exports) work too.
//!
//! Defect triangles (label class != 0) are displaced out of their face's plane by the
//! imprint; they are not grown over but given to the region of their face's plane: the
//! region holding the most area of undefected triangles with the same face label. So a
//! defected mesh has the same regions (ids, planes, frames) as the undefected one.
//!
//! Ids are stable: regions are numbered by their plane (normal, then offset, quantised to
//! the tolerances), then by their lexicographically smallest corner, which none of the
//! imprint's refinement or displacement changes.

use std::collections::HashMap;

use glam::{DVec3, Vec3};

use super::mesh::{FACE_OTHER, FaceId, Mesh, is_inspected};
use super::testbody::frame_axes;

/// Coplanarity tolerances.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegionTolerance {
    /// Largest angle between two triangle normals of one region, degrees. Default 0.5.
    pub angle_deg: f64,
    /// Largest distance of a corner from the region's plane, mm. Default 1e-3 (1 um).
    pub distance_mm: f64,
}

impl Default for RegionTolerance {
    fn default() -> Self {
        RegionTolerance {
            angle_deg: 0.5,
            distance_mm: 1e-3,
        }
    }
}

/// One planar region.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanarRegion {
    /// Stable id, 0.. (see the module docs).
    pub id: u32,
    /// Triangle indices into the mesh, ascending (defect triangles of its face included).
    pub triangles: Vec<u32>,
    /// Total area of its triangles projected onto its plane, mm^2 (for undefected
    /// triangles their area; displaced defect triangles count with their footprint).
    pub area: f64,
    /// Area-weighted centroid of the projected triangles, in the plane.
    pub centre: Vec3,
    /// Outward unit normal (area-weighted).
    pub normal: Vec3,
    /// In-plane frame by the rule of `testbody::frame_axes` (u "up the slope").
    pub u: Vec3,
    pub v: Vec3,
    /// The inspected face (A, B, C) whose triangles it holds, else `FACE_OTHER`.
    pub face: FaceId,
}

/// Finds the planar regions of `mesh` with the given tolerances. Degenerate triangles
/// (zero area) join the region of an edge neighbour, or form their own.
pub fn planar_regions(mesh: &Mesh, tol: &RegionTolerance) -> Vec<PlanarRegion> {
    let n = mesh.triangles.len();
    let cos_max = tol.angle_deg.to_radians().cos();
    let area_vec: Vec<DVec3> = (0..n).map(|t| mesh.area_normal(t).as_dvec3()).collect();
    let unit: Vec<DVec3> = area_vec.iter().map(|a| a.normalize_or_zero()).collect();
    let defect = |t: usize| mesh.labels.get(t).is_some_and(|l| l.class != 0);

    // Weld vertices by position, then map each undirected edge to its triangles.
    let welded = weld_positions(mesh, (tol.distance_mm / 4.0).max(1e-9));
    let mut edges: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (welded[tri[k] as usize], welded[tri[(k + 1) % 3] as usize]);
            if a != b {
                edges
                    .entry((a.min(b), a.max(b)))
                    .or_default()
                    .push(t as u32);
            }
        }
    }
    let edges = &edges;
    let welded = &welded;
    let neighbours = |t: usize| -> Vec<u32> {
        let tri = mesh.triangles[t];
        let mut out = Vec::new();
        for k in 0..3 {
            let (a, b) = (welded[tri[k] as usize], welded[tri[(k + 1) % 3] as usize]);
            if let Some(list) = edges.get(&(a.min(b), a.max(b))) {
                out.extend(list.iter().copied().filter(|&o| o as usize != t));
            }
        }
        out
    };

    // Grow regions over undefected triangles from each unassigned seed.
    let mut region_of = vec![u32::MAX; n];
    let mut groups: Vec<Vec<u32>> = Vec::new();
    for seed in 0..n {
        if region_of[seed] != u32::MAX || defect(seed) || unit[seed] == DVec3::ZERO {
            continue;
        }
        let r = groups.len() as u32;
        let (n0, p0) = (unit[seed], mesh.corners(seed)[0].as_dvec3());
        let mut stack = vec![seed as u32];
        let mut members = Vec::new();
        region_of[seed] = r;
        while let Some(t) = stack.pop() {
            members.push(t);
            for o in neighbours(t as usize) {
                let o_us = o as usize;
                if region_of[o_us] != u32::MAX || defect(o_us) || unit[o_us] == DVec3::ZERO {
                    continue;
                }
                let on_plane = mesh
                    .corners(o_us)
                    .iter()
                    .all(|c| (c.as_dvec3() - p0).dot(n0).abs() <= tol.distance_mm);
                if unit[o_us].dot(n0) >= cos_max && on_plane {
                    region_of[o_us] = r;
                    stack.push(o);
                }
            }
        }
        groups.push(members);
    }
    // Degenerate triangles: the region of a neighbour, else their own.
    for t in 0..n {
        if region_of[t] == u32::MAX && !defect(t) {
            let r = neighbours(t)
                .into_iter()
                .map(|o| region_of[o as usize])
                .find(|&r| r != u32::MAX)
                .unwrap_or_else(|| {
                    groups.push(Vec::new());
                    groups.len() as u32 - 1
                });
            region_of[t] = r;
            groups[r as usize].push(t as u32);
        }
    }

    // Defect triangles join the region of their face's plane: the region holding the
    // most undefected area of that face.
    let face_area = |members: &[u32], face: FaceId| -> f64 {
        members
            .iter()
            .filter(|&&t| mesh.labels.get(t as usize).is_some_and(|l| l.face == face))
            .map(|&t| area_vec[t as usize].length())
            .sum()
    };
    let mut best_for_face: HashMap<FaceId, Option<usize>> = HashMap::new();
    for t in 0..n {
        if !defect(t) {
            continue;
        }
        let face = mesh.labels[t].face;
        let best = *best_for_face.entry(face).or_insert_with(|| {
            (0..groups.len())
                .map(|g| (g, face_area(&groups[g], face)))
                .filter(|(_, a)| *a > 0.0)
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(g, _)| g)
        });
        match best {
            Some(g) => groups[g].push(t as u32),
            // A defect on a face with no undefected triangle left: its own region.
            None => groups.push(vec![t as u32]),
        }
    }

    // Geometry: the normal from the undefected triangles (exactly coplanar); area and
    // centre from all triangles projected onto the plane (a displaced defect triangle
    // keeps its projection), so an imprint changes neither.
    let mut regions: Vec<(PlanarRegion, [i64; 4], [i64; 3])> = groups
        .iter()
        .map(|members| {
            let mut an = members
                .iter()
                .filter(|&&t| !defect(t as usize))
                .map(|&t| area_vec[t as usize])
                .sum::<DVec3>();
            if an == DVec3::ZERO {
                an = members.iter().map(|&t| area_vec[t as usize]).sum();
            }
            let normal = an.normalize_or_zero();
            let mut weighted = DVec3::ZERO;
            let mut area = 0.0;
            let mut faces: HashMap<FaceId, f64> = HashMap::new();
            let mut min_corner = [i64::MAX; 3];
            for &t in members {
                let t = t as usize;
                let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
                let da = 0.5 * area_vec[t].dot(normal).abs();
                weighted += (a + b + c) / 3.0 * da;
                area += da;
                let face = mesh.labels.get(t).map_or(FACE_OTHER, |l| l.face);
                *faces.entry(face).or_default() += da;
                if !defect(t) {
                    for p in [a, b, c] {
                        let q = p.to_array().map(|c| (c / tol.distance_mm).round() as i64);
                        min_corner = min_corner.min(q);
                    }
                }
            }
            let mut centre = if area > 0.0 {
                weighted / area
            } else {
                members
                    .first()
                    .map_or(DVec3::ZERO, |&t| mesh.corners(t as usize)[0].as_dvec3())
            };
            // Onto the plane of the undefected triangles (defect corners lie off it).
            if let Some(&t) = members.iter().find(|&&t| !defect(t as usize)) {
                let p0 = mesh.corners(t as usize)[0].as_dvec3();
                centre -= normal * (centre - p0).dot(normal);
            }
            let (u, v) = if normal == DVec3::ZERO {
                (DVec3::X, DVec3::Y)
            } else {
                frame_axes(normal)
            };
            let face = faces
                .iter()
                .filter(|(f, _)| is_inspected(**f))
                .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(a.0)))
                .map_or(FACE_OTHER, |(f, _)| *f);
            // Sort key: the plane, quantised to the tolerances.
            let q = |x: f64, step: f64| (x / step).round() as i64;
            let step_n = tol.angle_deg.to_radians().max(1e-9);
            let key = [
                q(normal.x, step_n),
                q(normal.y, step_n),
                q(normal.z, step_n),
                q(normal.dot(centre), tol.distance_mm.max(1e-9)),
            ];
            let region = PlanarRegion {
                id: 0,
                triangles: members.clone(),
                area,
                centre: centre.as_vec3(),
                normal: normal.as_vec3(),
                u: u.as_vec3(),
                v: v.as_vec3(),
                face,
            };
            (region, key, min_corner)
        })
        .collect();
    regions.sort_by(|a, b| a.1.cmp(&b.1).then(a.2.cmp(&b.2)));
    regions
        .into_iter()
        .enumerate()
        .map(|(i, (mut r, _, _))| {
            r.id = i as u32;
            r.triangles.sort_unstable();
            r
        })
        .collect()
}

/// Region id per triangle (`u32::MAX` for none, which `planar_regions` never leaves).
/// One id per vertex, equal for vertices whose positions round to the same cell of a
/// `cell_mm` grid (welds the duplicated vertices of a mesh with split normals or UVs).
pub(crate) fn weld_positions(mesh: &Mesh, cell_mm: f64) -> Vec<u32> {
    let mut weld: HashMap<[i64; 3], u32> = HashMap::new();
    mesh.positions
        .iter()
        .map(|p| {
            let key = p
                .as_dvec3()
                .to_array()
                .map(|c| (c / cell_mm).round() as i64);
            let next = weld.len() as u32;
            *weld.entry(key).or_insert(next)
        })
        .collect()
}

pub fn region_per_triangle(mesh: &Mesh, regions: &[PlanarRegion]) -> Vec<u32> {
    let mut out = vec![u32::MAX; mesh.triangles.len()];
    for r in regions {
        for &t in &r.triangles {
            out[t as usize] = r.id;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::mesh::{FACE_A, FACE_B, FACE_C};
    use crate::scene::testbody::{Variant, face_frames, testbody};

    /// The test body's planes: its cube faces (top, bottom, four sides) and the three
    /// cuts A, B, C; every triangle in exactly one region, each region one plane.
    #[test]
    fn test_body_regions_are_exactly_its_faces() {
        for variant in [Variant::B, Variant::M] {
            let mesh = testbody(variant);
            let regions = planar_regions(&mesh, &RegionTolerance::default());
            assert_eq!(regions.len(), 9, "{variant:?}");
            let per = region_per_triangle(&mesh, &regions);
            assert!(per.iter().all(|&r| r != u32::MAX));
            let total: usize = regions.iter().map(|r| r.triangles.len()).sum();
            assert_eq!(total, mesh.triangles.len());
            let body_area: f64 = (0..mesh.triangles.len())
                .map(|t| 0.5 * mesh.area_normal(t).as_dvec3().length())
                .sum();
            let region_area: f64 = regions.iter().map(|r| r.area).sum();
            assert!((body_area - region_area).abs() < 1e-6 * body_area);
            for r in &regions {
                // Every triangle lies in the region's plane with the region's normal.
                for &t in &r.triangles {
                    let t = t as usize;
                    let n = mesh.area_normal(t).normalize();
                    assert!(n.dot(r.normal) > 0.9999, "region {}: normal {n}", r.id);
                    for c in mesh.corners(t) {
                        assert!((c - r.centre).dot(r.normal).abs() < 1e-3);
                    }
                }
                assert!((r.u.dot(r.normal)).abs() < 1e-6 && (r.v.length() - 1.0).abs() < 1e-6);
            }
            // A, B, C: one region each, holding the labelled square and the rest of its
            // cut, with the face frame's normal and axes.
            for (face, frame) in [FACE_A, FACE_B, FACE_C].iter().zip(face_frames(&mesh)) {
                let held: Vec<&PlanarRegion> = regions.iter().filter(|r| r.face == *face).collect();
                assert_eq!(held.len(), 1, "face {face}");
                let r = held[0];
                assert!(
                    r.area > frame.area as f64 + 1.0,
                    "the cut is larger than the square"
                );
                assert!((r.normal - frame.normal).length() < 1e-5);
                assert!((r.u - frame.u).length() < 1e-5 && (r.v - frame.v).length() < 1e-5);
                let labelled = (0..mesh.triangles.len())
                    .filter(|&t| mesh.labels[t].face == *face)
                    .all(|t| per[t] == r.id);
                assert!(labelled);
            }
            // Six axis-aligned planes.
            let axis = regions
                .iter()
                .filter(|r| r.normal.abs().max_element() > 0.99999)
                .count();
            assert_eq!(axis, 6);
        }
    }

    #[test]
    fn ids_are_stable_under_reordering() {
        let mesh = testbody(Variant::B);
        let tol = RegionTolerance::default();
        let a = planar_regions(&mesh, &tol);
        // Reversed triangle order: the same regions with the same ids.
        let mut rev = mesh.clone();
        rev.triangles.reverse();
        rev.labels.reverse();
        let b = planar_regions(&rev, &tol);
        let m = mesh.triangles.len() as u32 - 1;
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(x.id, y.id);
            assert!((x.normal - y.normal).length() < 1e-6);
            let mut t: Vec<u32> = y.triangles.iter().map(|t| m - t).collect();
            t.sort_unstable();
            assert_eq!(x.triangles, t);
        }
    }

    #[test]
    fn duplicated_vertices_and_tolerances() {
        // Flat-shaded copy: every triangle has its own three vertices.
        let mesh = testbody(Variant::B);
        let mut flat = Mesh::default();
        for (t, tri) in mesh.triangles.iter().enumerate() {
            let base = flat.positions.len() as u32;
            flat.positions
                .extend(tri.iter().map(|&i| mesh.positions[i as usize]));
            flat.triangles.push([base, base + 1, base + 2]);
            flat.labels.push(mesh.labels[t]);
        }
        assert_eq!(planar_regions(&flat, &RegionTolerance::default()).len(), 9);
        // Two triangles folded by 2 degrees: one region at 3 degrees, two at 1.
        let s = 2f32.to_radians();
        let folded = Mesh {
            positions: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(10.0, 0.0, 0.0),
                Vec3::new(0.0, 10.0, 0.0),
                Vec3::new(-10.0 * s.cos(), 0.0, 10.0 * s.sin()),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            labels: vec![Default::default(); 2],
        };
        let tol = |angle_deg, distance_mm| RegionTolerance {
            angle_deg,
            distance_mm,
        };
        assert_eq!(planar_regions(&folded, &tol(3.0, 1.0)).len(), 1);
        assert_eq!(planar_regions(&folded, &tol(1.0, 1.0)).len(), 2);
        // Within the angle but a corner 0.35 mm off the plane: the distance decides.
        assert_eq!(planar_regions(&folded, &tol(3.0, 0.1)).len(), 2);
    }
}
