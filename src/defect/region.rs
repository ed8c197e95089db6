//! A labelled face seen in its own 2D frame: its triangles, its border, and distance
//! queries used to keep defects inside the face.

use std::collections::HashSet;

use glam::{DVec2, DVec3};

use crate::scene::Mesh;
use crate::scene::mesh::{FaceId, face_name};
use crate::scene::testbody::face_frames;

use super::DefectError;

/// One face in 2D: origin `centre`, axes `u`, `v` (see [`crate::scene::FaceFrame`]).
#[derive(Clone, Debug)]
pub(crate) struct Region {
    pub face: FaceId,
    pub centre: DVec3,
    pub normal: DVec3,
    pub u: DVec3,
    pub v: DVec3,
    /// The face's triangles in (u, v), counter-clockwise, with their mesh index.
    pub tris: Vec<(usize, [DVec2; 3])>,
    /// Border edges in (u, v): edges of a face triangle not shared with another
    /// triangle of the same face.
    pub border: Vec<[DVec2; 2]>,
}

impl Region {
    pub fn to_uv(&self, p: DVec3) -> DVec2 {
        let d = p - self.centre;
        DVec2::new(d.dot(self.u), d.dot(self.v))
    }

    /// Regions of the given faces; faces with no triangles are left out.
    pub fn of_mesh(mesh: &Mesh, faces: &[FaceId]) -> Vec<Region> {
        let frames = face_frames(mesh);
        let mut out = Vec::new();
        for f in frames.iter().filter(|f| faces.contains(&f.face)) {
            let mut r = Region {
                face: f.face,
                centre: f.centre.as_dvec3(),
                normal: f.normal.as_dvec3(),
                u: f.u.as_dvec3(),
                v: f.v.as_dvec3(),
                tris: Vec::new(),
                border: Vec::new(),
            };
            let mut directed = HashSet::new();
            for (t, tri) in mesh.triangles.iter().enumerate() {
                if mesh.labels[t].face != f.face {
                    continue;
                }
                let c = mesh.corners(t).map(|p| r.to_uv(p.as_dvec3()));
                r.tris.push((t, c));
                for k in 0..3 {
                    directed.insert((tri[k], tri[(k + 1) % 3]));
                }
            }
            for &(t, _) in &r.tris {
                let tri = mesh.triangles[t];
                for k in 0..3 {
                    let (a, b) = (tri[k], tri[(k + 1) % 3]);
                    if !directed.contains(&(b, a)) {
                        let pa = r.to_uv(mesh.positions[a as usize].as_dvec3());
                        let pb = r.to_uv(mesh.positions[b as usize].as_dvec3());
                        r.border.push([pa, pb]);
                    }
                }
            }
            out.push(r);
        }
        out
    }

    /// Largest distance of a face vertex from the face plane, mm.
    pub fn planarity(&self, mesh: &Mesh) -> f64 {
        self.tris
            .iter()
            .flat_map(|&(t, _)| mesh.corners(t))
            .map(|p| (p.as_dvec3() - self.centre).dot(self.normal).abs())
            .fold(0.0, f64::max)
    }

    pub fn check_planar(&self, mesh: &Mesh) -> Result<(), DefectError> {
        let off = self.planarity(mesh);
        // f32 positions of a 50 mm body carry about 4e-6 mm of rounding.
        if off > 1e-3 {
            return Err(DefectError::NotPlanar {
                face: face_name(self.face).into(),
                offset_mm: off,
            });
        }
        Ok(())
    }

    pub fn contains(&self, p: DVec2) -> bool {
        self.tris.iter().any(|(_, [a, b, c])| {
            let s = |x: DVec2, y: DVec2| (y - x).perp_dot(p - x);
            s(*a, *b) >= 0.0 && s(*b, *c) >= 0.0 && s(*c, *a) >= 0.0
        })
    }

    /// Distance from a point to the border.
    pub fn border_distance(&self, p: DVec2) -> f64 {
        self.border
            .iter()
            .map(|&[a, b]| point_segment_distance(p, a, b))
            .fold(f64::INFINITY, f64::min)
    }

    /// Distance from a segment to the border (0 if they cross).
    pub fn segment_border_distance(&self, p: DVec2, q: DVec2) -> f64 {
        self.border
            .iter()
            .map(|&[a, b]| segment_segment_distance(p, q, a, b))
            .fold(f64::INFINITY, f64::min)
    }

    /// Whether a disk of radius `r` at `p` lies inside the face.
    pub fn disk_fits(&self, p: DVec2, r: f64) -> bool {
        self.contains(p) && self.border_distance(p) >= r
    }

    /// Whether the polyline, thickened by `r`, lies inside the face.
    pub fn polyline_fits(&self, pts: &[DVec2], r: f64) -> bool {
        if pts.is_empty() || !self.disk_fits(pts[0], r) {
            return false;
        }
        pts.windows(2)
            .all(|w| self.segment_border_distance(w[0], w[1]) >= r)
    }
}

pub(crate) fn point_segment_distance(p: DVec2, a: DVec2, b: DVec2) -> f64 {
    let d = b - a;
    let l2 = d.length_squared();
    let t = if l2 > 0.0 {
        ((p - a).dot(d) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + d * t)).length()
}

pub(crate) fn segment_segment_distance(p: DVec2, q: DVec2, a: DVec2, b: DVec2) -> f64 {
    let o = |x: DVec2, y: DVec2, z: DVec2| (y - x).perp_dot(z - x);
    let (d1, d2) = (o(a, b, p), o(a, b, q));
    let (d3, d4) = (o(p, q, a), o(p, q, b));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return 0.0;
    }
    point_segment_distance(p, a, b)
        .min(point_segment_distance(q, a, b))
        .min(point_segment_distance(a, p, q))
        .min(point_segment_distance(b, p, q))
}
