//! Surface textures at the meso scale (paper, "Texture Modeling"): height maps of milled
//! and sandblasted aluminium in micrometres, and the slope map the renderer uploads.
//!
//! Typical use:
//! ```no_run
//! use synosis::texture::*;
//! let p = MilledParams { head_diameter_mm: 8.0, radial_depth: 0.5, ..Default::default() };
//! let h = generate_milled(&p, 1024, 1024, 6.1, 42, &NoProgress).unwrap();
//! let slopes: SlopeMap = h.slopes(); // row 0 at the top, [dh/dx, dh/dy], unitless
//! ```
//! See `docs/texture.md` for every parameter, default, range and approximation.

mod error;
mod fft2;
mod io;
mod maps;
mod measurement;
mod milling;
mod progress;
mod rng;
pub mod sandblast;

pub use error::{Result, TextureError};
pub use io::{preview, write_exr_height, write_normal_png16, write_preview_png};
pub use maps::{HeightMap, Moments, SlopeMap, normal_from_slope};
pub use measurement::{
    FormRemoval, MIN_VALID_FRACTION, XyzUnit, load_height_map, load_measurement, read_exr,
    read_xyz, remove_form,
};
pub use milling::{
    MILLED_DEFAULT_MOMENTS, MilledParams, MilledVariation, ToolPath, generate_milled,
};
pub use progress::{NoProgress, Progress};
pub use sandblast::adsn::{AdsnKernel, periodic_component};
pub use sandblast::exemplar::{StandInExemplar, sandblast_default_moments};
pub use sandblast::quilting::min_vertical_cut;
pub use sandblast::{SandblastParams, generate_sandblasted, resample_nearest};
