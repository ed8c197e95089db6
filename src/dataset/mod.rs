//! The dataset generator (paper, "Synthetic dataset"): a TOML job -> an ordered list of
//! images with deterministic seeds -> rendered through an [`ImageRenderer`] ->
//! post-processed -> a dataset folder with images, masks, COCO and LabelMe labels and a
//! manifest that `synosis compare` reads. Resumable, shardable, memory-flat.
//! See docs/dataset.md.

pub mod camera;
mod coco;
mod error;
pub mod files;
pub mod gpu;
pub mod job;
pub mod labels;
pub mod lock;
pub mod plan;
pub mod post;
pub mod renderer;
pub mod report;
pub mod runner;
pub mod seed;
pub mod shard_env;
pub mod texture_bridge;
pub mod textures;

pub use error::{DatasetError, Result};
pub use job::{Finish, FinishKind, Job, Object, PAPER_VIEWS};
pub use plan::{InstancePlan, ItemPlan, Label, Plan, Split, expand};
pub use post::{Frame, PostStep};
pub use renderer::{FaceTexture, ImageRenderer, ImageRequest, RenderedImage, TextureMap};
pub use runner::{
    DEFAULT_IN_FLIGHT, DEVICE_ALLOCATIONS_COUNTER, DEVICE_MEMORY_COUNTER, ManifestEntry, Prepared,
    RunOptions, RunReport, Shard, Verifying, finish, merge, merge_with_progress, postprocess_dir,
    postprocess_dir_with_progress, prepare, prepare_text, read_manifest, render_one,
    render_one_seeded, run,
};
pub use textures::{TextureCache, TextureSource, TextureWant};
