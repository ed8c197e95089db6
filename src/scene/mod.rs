//! Scene description: meshes and their labels, glTF import/export.

pub mod gltf_io;
pub mod mesh;
pub mod testbody;

pub use gltf_io::{export_mesh, import_mesh, Degenerates, Imported, MeshError};
pub use mesh::{Mesh, TriLabel};
pub use testbody::{face_frames, testbody, FaceFrame, Variant};
