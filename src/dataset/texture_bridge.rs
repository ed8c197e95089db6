//! The production [`TextureSource`]: the texture module (`crate::texture`).
//!
//! The texture module (milled + sandblasted height maps -> slope maps) has not landed in
//! this build yet, so this source refuses with a clear error instead of inventing
//! textures. Finish parameters are only checked for their shape here.

use super::job::{Finish, FinishKind};
use super::renderer::TextureMap;
use super::textures::TextureSource;

pub const UNAVAILABLE: &str =
    "the texture module (milled/sandblasted synthesis) is not available in this build";

/// Shape checks that need no texture code.
pub fn validate(f: &Finish) -> Result<(), String> {
    if f.kind == FinishKind::Milled
        && let Some(v) = &f.variation
        && !(v.is_str() || v.is_table())
    {
        return Err("variation must be \"paper\", \"none\" or a table of value sets".into());
    }
    Ok(())
}

/// Textures from `crate::texture`.
#[derive(Default)]
pub struct ModuleTextures;

impl TextureSource for ModuleTextures {
    fn make(
        &mut self,
        _f: &Finish,
        _i: u32,
        _seed: u64,
        _size: usize,
        _spacing: f64,
    ) -> Result<TextureMap, String> {
        Err(UNAVAILABLE.into())
    }
}
