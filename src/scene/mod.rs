//! Scene description: meshes and their labels, glTF import/export, the test body, the
//! scene file, cameras and the ring light.

pub mod assemble;
pub mod calibration;
pub mod camera;
pub mod config;
pub mod gltf_io;
pub mod mesh;
pub mod procedural;
pub mod testbody;

pub use calibration::{Distortion, Intrinsics};
pub use camera::Camera;
pub use gltf_io::{Degenerates, Imported, MeshError, export_mesh, import_mesh};
pub use mesh::{Mesh, TriLabel};
pub use testbody::{FaceFrame, Variant, face_frames, testbody};
pub mod regions;
pub use regions::{PlanarRegion, RegionTolerance, planar_regions};
