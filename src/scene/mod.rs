//! Scene description: meshes and their labels, glTF import/export.

pub mod gltf_io;
pub mod mesh;
pub mod procedural;
pub mod testbody;

pub use gltf_io::{Degenerates, Imported, MeshError, export_mesh, import_mesh};
pub use mesh::{Mesh, TriLabel};
pub use testbody::{FaceFrame, Variant, face_frames, testbody};
pub mod camera;
pub mod config;
