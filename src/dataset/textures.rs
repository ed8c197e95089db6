//! Textures per (finish, instance): made through a [`TextureSource`] and kept in a
//! bounded cache, so memory stays flat over a long run however many finishes it has.

use std::collections::VecDeque;
use std::sync::Arc;

use super::error::{DatasetError, Result};
use super::job::Finish;
use super::renderer::TextureMap;

/// Makes the slope map of one texture instance of a finish.
pub trait TextureSource {
    fn make(
        &mut self,
        finish: &Finish,
        instance: u32,
        seed: u64,
        size_px: usize,
        spacing_um: f64,
    ) -> Result<TextureMap, String>;
}

/// Least-recently-used cache of at most `capacity` textures. The job's item order
/// (finish-major) makes one finish's textures the working set.
pub struct TextureCache {
    capacity: usize,
    entries: VecDeque<((usize, u32), Arc<TextureMap>)>,
    pub made: usize,
}

impl TextureCache {
    pub fn new(capacity: usize) -> Self {
        TextureCache {
            capacity: capacity.max(1),
            entries: VecDeque::new(),
            made: 0,
        }
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The texture of (finish index, instance), made on a miss.
    pub fn get(
        &mut self,
        key: (usize, u32),
        make: impl FnOnce() -> Result<TextureMap>,
    ) -> Result<Arc<TextureMap>> {
        if let Some(pos) = self.entries.iter().position(|(k, _)| *k == key) {
            let e = self.entries.remove(pos).unwrap_or_else(|| unreachable!());
            let map = e.1.clone();
            self.entries.push_back(e);
            return Ok(map);
        }
        // Evict before making, so the peak is `capacity` maps, not one more.
        while self.entries.len() >= self.capacity {
            self.entries.pop_front();
        }
        let map = Arc::new(make()?);
        self.made += 1;
        self.entries.push_back((key, map.clone()));
        Ok(map)
    }
}

/// Checks a finish's texture parameters without making a texture.
pub fn validate_finish(f: &Finish) -> Result<(), String> {
    super::texture_bridge::validate(f)
}

pub(crate) fn texture_error(f: &Finish, instance: u32, message: String) -> DatasetError {
    DatasetError::Texture {
        finish: f.name.clone(),
        instance,
        message,
    }
}
