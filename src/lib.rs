//! synosis: physically based synthetic inspection images of machined metal parts.
//!
//! Data flows one way: configuration -> textures, defected meshes and the scene, built on
//! the CPU -> uploaded once -> the render graph runs its passes on Vulkan -> images and
//! labels are read back -> the dataset writer. `vk` knows nothing about scenes; `texture`,
//! `defect` and `metrics` know nothing about Vulkan.

pub mod dataset;
pub mod defect;
pub mod gpu_interface;
pub mod graph;
pub mod image_io;
pub mod metrics;
pub mod render;
pub mod scene;
pub mod shaders;
pub mod texture;
pub mod trace;
pub mod util;
pub mod vk;
