//! Scene description: meshes and their labels, glTF import/export, the test body, the
//! scene file, cameras and the ring light.

pub mod assemble;
pub mod calibration;
pub mod camera;
pub mod config;
pub mod flange;
pub mod gltf_io;
pub mod inspect;
pub mod light_cover;
pub mod lights;
pub mod materials;
pub mod mesh;
pub mod mesh_io;
pub mod procedural;
pub mod testbody;

pub use calibration::{Distortion, Intrinsics};
pub use camera::Camera;
pub use flange::{FlangeParams, flange};
pub use gltf_io::{Degenerates, Imported, MeshError, export_mesh, import_mesh};
pub use mesh::{Mesh, TriLabel};
pub use mesh_io::{GltfUnitDefault, LoadedMesh, MeshFormat, MeshUnit, load_mesh, write_mesh};
pub use testbody::{FaceFrame, Variant, face_frames, testbody};
pub mod curved;
pub mod regions;
pub use regions::{PlanarRegion, RegionTolerance, planar_regions};
