//! The triangle mesh every stage shares: positions, triangles and per-triangle labels.
//!
//! Labels travel with the geometry so the annotation pass needs no second mesh: each
//! triangle knows which inspected face it lies on and, after defect imprinting, which
//! defect class and instance it belongs to.

use glam::Vec3;

/// Which inspected face a triangle lies on. 0 is "other" (not inspected).
pub type FaceId = u8;
pub const FACE_OTHER: FaceId = 0;
pub const FACE_A: FaceId = 1;
pub const FACE_B: FaceId = 2;
pub const FACE_C: FaceId = 3;

/// Whether `face` is one of the inspected faces A, B, C (the pixels auto exposure
/// looks at).
pub fn is_inspected(face: FaceId) -> bool {
    matches!(face, FACE_A | FACE_B | FACE_C)
}

/// Defect class ids, as in the masks: 0 background / no defect, 1 dent, 2 scratch.
pub const CLASS_NONE: u8 = 0;
pub const CLASS_DENT: u8 = 1;
pub const CLASS_SCRATCH: u8 = 2;

/// Face name used in files ("A", "B", "C", or "other") for a face id.
pub fn face_name(face: FaceId) -> &'static str {
    match face {
        FACE_A => "A",
        FACE_B => "B",
        FACE_C => "C",
        _ => "other",
    }
}

/// Face id for a name in a file; `None` for an unknown name.
pub fn face_from_name(name: &str) -> Option<FaceId> {
    match name {
        "A" => Some(FACE_A),
        "B" => Some(FACE_B),
        "C" => Some(FACE_C),
        "other" | "" => Some(FACE_OTHER),
        _ => None,
    }
}

/// Per-triangle label: inspected face, defect class and defect instance (0 = none).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TriLabel {
    pub face: FaceId,
    pub class: u8,
    pub instance: u16,
}

/// An indexed triangle mesh in scene units (millimetres), with one label per triangle.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    pub labels: Vec<TriLabel>,
}

impl crate::trace::Triangles for Mesh {
    fn positions(&self) -> &[Vec3] {
        &self.positions
    }
    fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
}

impl Mesh {
    /// Axis-aligned bounds (min, max) of the corners the triangles use. Empty meshes give
    /// (+inf, -inf).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        use crate::trace::Triangles;
        self.corner_bounds()
            .map_or((Vec3::INFINITY, Vec3::NEG_INFINITY), |[lo, hi]| (lo, hi))
    }

    /// The three corners of triangle `t`.
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| self.positions[i as usize])
    }

    /// Geometric (unnormalised) normal of triangle `t`: (b - a) x (c - a).
    pub fn area_normal(&self, t: usize) -> Vec3 {
        let [a, b, c] = self.corners(t);
        (b - a).cross(c - a)
    }

    /// Triangles whose area is zero relative to their size (a repeated index, collinear
    /// corners): they can never be hit and would give a NaN normal.
    pub fn degenerate_triangles(&self) -> Vec<usize> {
        (0..self.triangles.len())
            .filter(|&t| {
                let [a, b, c] = self.corners(t);
                let scale = (b - a).length_squared().max((c - a).length_squared());
                let n2 = self.area_normal(t).length_squared();
                // NaN areas (non-finite corners) count as degenerate too.
                n2.partial_cmp(&(scale * scale * 1e-14)) != Some(std::cmp::Ordering::Greater)
            })
            .collect()
    }

    /// Removes the given triangles (and their labels); vertices stay.
    pub fn remove_triangles(&mut self, remove: &[usize]) {
        let mut drop = vec![false; self.triangles.len()];
        for &t in remove {
            drop[t] = true;
        }
        let mut k = 0;
        self.triangles.retain(|_| {
            k += 1;
            !drop[k - 1]
        });
        let mut k = 0;
        self.labels.retain(|_| {
            k += 1;
            !drop[k - 1]
        });
    }

    /// Appends another mesh (its indices shifted).
    pub fn append(&mut self, other: &Mesh) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.triangles
            .extend(other.triangles.iter().map(|t| t.map(|i| i + base)));
        self.labels.extend_from_slice(&other.labels);
    }
}
