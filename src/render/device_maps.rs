//! Slope maps' texels on a device, uploaded once and shared by every scene on that
//! device that shows the map at the same time: the renderers beside one another on one
//! device (`vk::Context::beside`, a dataset run's `--renderers`), which render the views
//! of one object instance side by side, and the next instance of a renderer when it keeps
//! a face texture (the buffers of the scene's old maps are still held while its new ones
//! are looked up). A map is identified by its allocation (`Arc<SlopeMap>`: the texture
//! cache hands out one per texture), a device by its `VkDevice`.
//!
//! Nothing is kept for later: an entry holds its buffer weakly, so a map's buffer lives
//! exactly as long as some scene uses it (GPU memory as when every scene had its own,
//! at most), and an entry whose map is gone is dropped at the next lookup. The buffers
//! are device-local (`Buffer::resident`): the path tracer reads them at every textured
//! hit, and host-visible upload memory may be system memory on a discrete GPU.
//!
//! Before this, each renderer converted and uploaded every map of every instance it
//! rendered (docs/benchmarks/dataset.md, "Each slope map converted and uploaded once a
//! device, ahead of its image").

use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard, Weak};

use ash::vk;
use ash::vk::Handle;
use rayon::prelude::*;

use super::slope::{self, NotFinite, SlopeMap};
use crate::vk::{Buffer, Context, VkError};

/// What a shared buffer holds of its map.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Content {
    /// The texel words the shader reads (`slope::texel_words`).
    Texels,
    /// The moment pyramid of `texture_filter = "lean"` (`slope::map_moments`).
    Moments,
}

/// Why a shared buffer could not be made.
#[derive(Debug, thiserror::Error)]
pub enum SharedMapError {
    #[error(transparent)]
    Vk(#[from] VkError),
    /// A slope of the map is not finite (nothing is kept).
    #[error("slopes must be finite")]
    NotFinite,
    /// The moment pyramid does not fit one storage buffer.
    #[error(transparent)]
    Slope(#[from] slope::SlopeError),
}

type Key = (u64, usize, Content);

struct Entry {
    map: Weak<SlopeMap>,
    /// Locked while the buffer is made, so that scenes asking at once wait for one upload.
    buffer: Arc<Mutex<Weak<Buffer>>>,
}

fn entries() -> MutexGuard<'static, HashMap<Key, Entry>> {
    static ENTRIES: std::sync::OnceLock<Mutex<HashMap<Key, Entry>>> = std::sync::OnceLock::new();
    let m = ENTRIES.get_or_init(Default::default);
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Texel words per conversion task.
const CHUNK: usize = 1 << 16;

/// `map`'s texel words on `ctx`'s device: the buffer another scene on that device uses
/// now, or a new one in device-local memory (`Buffer::resident`: converted straight into
/// it where the host can map it, else into a staging buffer copied by the GPU), in
/// parallel on the caller's rayon pool (a render thread calls it on the render threads'
/// pool, a run's preparing thread on the global one).
pub fn texels(ctx: &Arc<Context>, map: &Arc<SlopeMap>) -> Result<Arc<Buffer>, SharedMapError> {
    texels_via(ctx, map, false)
}

/// [`texels`]; `staged`: through a staging copy even where device memory is mappable
/// (`Buffer::resident_via`; tests).
pub fn texels_via(
    ctx: &Arc<Context>,
    map: &Arc<SlopeMap>,
    staged: bool,
) -> Result<Arc<Buffer>, SharedMapError> {
    shared(ctx, map, Content::Texels, |ctx| {
        let (size, usage) = (
            map.data.len() as u64 * 4,
            vk::BufferUsageFlags::STORAGE_BUFFER,
        );
        Buffer::resident_via(ctx, "slope map texels", size, usage, staged, |bytes| {
            let words: &mut [u32] = bytemuck::try_cast_slice_mut(&mut bytes[..size as usize])
                .map_err(|e| VkError::Other(format!("slope map texels: mapped memory: {e}")))?;
            words
                .par_chunks_mut(CHUNK)
                .zip(map.data.par_chunks(CHUNK))
                .try_for_each(|(out, slopes)| slope::texel_words_into(slopes, out))
                .map_err(|NotFinite| SharedMapError::NotFinite)
        })
    })
}

/// `map`'s moment pyramid (`texture_filter = "lean"`) on `ctx`'s device, shared as
/// [`texels`] is; `region` names the map in errors, `max_bytes` is one storage buffer's
/// range.
pub fn moments(
    ctx: &Arc<Context>,
    map: &Arc<SlopeMap>,
    region: u32,
    max_bytes: u64,
) -> Result<Arc<Buffer>, SharedMapError> {
    shared(ctx, map, Content::Moments, |ctx| {
        let words = slope::texel_words(map).map_err(|NotFinite| SharedMapError::NotFinite)?;
        let (w, h) = (map.width as u32, map.height as u32);
        let pyramid = slope::map_moments(&words, w, h, region, max_bytes)?;
        let bytes: &[u8] = bytemuck::cast_slice(&pyramid);
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
        Buffer::resident(ctx, "slope moments", bytes.len() as u64, usage, |out| {
            out[..bytes.len()].copy_from_slice(bytes);
            Ok(())
        })
    })
}

/// The buffer of (`ctx`'s device, `map`, `content`) while any scene holds it, else the one
/// `make` makes (kept weakly).
fn shared(
    ctx: &Arc<Context>,
    map: &Arc<SlopeMap>,
    content: Content,
    make: impl FnOnce(&Arc<Context>) -> Result<Buffer, SharedMapError>,
) -> Result<Arc<Buffer>, SharedMapError> {
    let key = (
        ctx.device.handle().as_raw(),
        Arc::as_ptr(map) as usize,
        content,
    );
    let slot = {
        let mut all = entries();
        // A live map's address is its own; an entry whose map is gone is stale (and
        // another map may come to live at its address).
        all.retain(|_, e| e.map.strong_count() > 0);
        all.entry(key)
            .or_insert_with(|| Entry {
                map: Arc::downgrade(map),
                buffer: Arc::new(Mutex::new(Weak::new())),
            })
            .buffer
            .clone()
    };
    let mut held = slot.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(b) = held.upgrade() {
        return Ok(b);
    }
    let b = Arc::new(make(ctx)?);
    *held = Arc::downgrade(&b);
    Ok(b)
}
