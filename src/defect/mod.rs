//! Defects as geometry: sampling dents and scratches on the inspected faces, and
//! imprinting them into the mesh as displaced, re-tessellated, labelled patches.
//!
//! Pipeline: [`DefectSpec`] (the paper's table by default, or TOML) -> [`sample_defects`]
//! -> [`DefectSet`] (face-local, re-applicable to any mesh with the same labelled faces)
//! -> [`imprint`] -> a watertight [`Mesh`](crate::scene::Mesh) whose defect triangles
//! carry class and instance labels. See docs/defects.md.

mod check;
mod imprint;
mod refine;
mod region;
mod sample;
mod slice;
mod spec;
mod tool;

pub use check::check_closed_manifold;
pub use imprint::{
    ImprintOptions, ImprintStats, ScratchMesh, imprint, imprint_traced, imprint_with_options,
    imprint_with_stats,
};
pub use sample::{Defect, DefectSet, Dent, Scratch, Shape, sample_defects};
pub use spec::{DefectSpec, DentSpec, Range, ScratchProfile, ScratchSpec};
pub use tool::DefectTool;

use std::path::PathBuf;

/// Everything that can go wrong between a spec and a defected mesh.
#[derive(Debug, thiserror::Error)]
pub enum DefectError {
    #[error("defect spec: {field} = {value}: {allowed}")]
    Spec {
        field: String,
        value: String,
        allowed: String,
    },
    #[error("defect spec {path}: {message}")]
    Parse { path: String, message: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("the mesh has no triangles labelled with the inspected face(s) {faces}")]
    NoFace { faces: String },
    #[error(
        "{name} (instance {instance}, {size_mm:.3} mm): no placement inside the inspected \
         faces found in {tries} tries; the defect is too large for the faces, or raise max_tries"
    )]
    NoFit {
        name: String,
        instance: u16,
        size_mm: f64,
        tries: u32,
    },
    #[error(
        "face {face} is not planar (a vertex lies {offset_mm:.2e} mm off its plane); \
         defects are imprinted only into planar faces"
    )]
    NotPlanar { face: String, offset_mm: f64 },
    #[error("defect instance {instance} on face {face}: that face is not in this mesh")]
    MissingFace { instance: u16, face: String },
    #[error(
        "defect instance {instance} does not fit inside face {face} of this mesh (it comes \
         from a differently shaped face)"
    )]
    OutsideFace { instance: u16, face: String },
    #[error("the mesh is not manifold: edge ({a}, {b}) is shared by more than two triangles")]
    NonManifold { a: u32, b: u32 },
    #[error(
        "imprinting would need more than {limit} triangles; lower `resolution` or the defect sizes"
    )]
    TooLarge { limit: usize },
    #[error("defect set: {0}")]
    BadSet(String),
}
