//! The CPU side of a render thread's work between batches (issue 15): the thread pool
//! its per-pixel work runs on, and the per-pixel vectors it keeps between noise checks.
//!
//! **The pool** ([`on_render_pool`]): a noise check, a view's light cover and a frame's
//! mean image are per-pixel (or per-triangle) work the render thread waits on while the
//! GPU has nothing of its to do. On the global pool they would queue behind the next
//! object instance's textures (a dataset run makes them on its preparing thread); this
//! pool is theirs alone, at most 8 threads shared by every renderer of the process.
//!
//! **The vectors** ([`Scratch`]): a check every few batches works on about a dozen
//! per-pixel arrays (up to 10 MB each at the paper's size: the sums read back, the mean
//! image, each pixel's variance, its neighbourhood mean, its share); made afresh, each is
//! memory the kernel maps page by page, and in a renderer's process those page faults
//! cost about as much as the arithmetic (docs/benchmarks/dataset.md, "A noise check's CPU
//! time" and "A noise check's arrays kept"). A [`Scratch`] takes a vector from a
//! process-wide pool of its element type and gives it back when dropped, so the next
//! check reuses memory already mapped. The pool keeps at most [`KEPT`] vectors of a type
//! (what the checks running at once used, in a run of several renderers); a vector
//! beyond that is freed.

use std::ops::{Deref, DerefMut};
use std::sync::Mutex;

/// Runs `f` (a render thread's per-pixel work between batches: a noise check, a view's
/// light cover, a frame's mean image) on the render threads' own pool: the global pool is
/// often busy with the next object instance's textures, and work queued behind them
/// leaves the GPU idle. At most 8 threads, shared by every renderer of the process.
pub fn on_render_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    static POOL: std::sync::OnceLock<Option<rayon::ThreadPool>> = std::sync::OnceLock::new();
    let pool = POOL.get_or_init(|| {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        rayon::ThreadPoolBuilder::new()
            .num_threads(cores.min(8))
            .thread_name(|i| format!("render cpu {}", i + 1))
            .build()
            .ok()
    });
    match pool {
        Some(p) => p.install(f),
        None => f(), // no thread could be made: the global pool
    }
}

/// Vectors a pool keeps at most, per element type.
pub const KEPT: usize = 48;

/// An element type with a pool of its own.
pub trait Recyclable: Copy + Send + 'static {
    fn pool() -> &'static Mutex<Vec<Vec<Self>>>;
}

macro_rules! recyclable {
    ($($t:ty),*) => {$(
        impl Recyclable for $t {
            fn pool() -> &'static Mutex<Vec<Vec<$t>>> {
                static POOL: Mutex<Vec<Vec<$t>>> = Mutex::new(Vec::new());
                &POOL
            }
        }
    )*};
}

recyclable!(f64, f32, u32, bool);

/// A vector from its element type's pool, given back when dropped.
#[derive(Debug)]
pub struct Scratch<T: Recyclable>(Vec<T>);

impl<T: Recyclable> Scratch<T> {
    /// A vector from the pool, as it was given back (a new one where the pool is empty).
    fn take() -> Vec<T> {
        T::pool()
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop()
            .unwrap_or_default()
    }

    /// An empty vector, with the capacity of one used before where the pool has one.
    pub fn empty() -> Self {
        let mut v = Self::take();
        v.clear();
        Scratch(v)
    }

    /// `len` copies of `value`.
    pub fn filled(len: usize, value: T) -> Self {
        let mut s = Self::empty();
        s.0.resize(len, value);
        s
    }

    /// `len` values, those the reused vector held left as they were (`fill` past its
    /// length): for an array whose every value is written before it is read.
    pub fn stale(len: usize, fill: T) -> Self {
        let mut v = Self::take();
        v.resize(len, fill);
        Scratch(v)
    }

    /// The vector itself, kept out of the pool.
    pub fn into_vec(mut self) -> Vec<T> {
        std::mem::take(&mut self.0)
    }
}

impl<T: Recyclable> Drop for Scratch<T> {
    fn drop(&mut self) {
        if self.0.capacity() == 0 {
            return;
        }
        let mut pool = T::pool().lock().unwrap_or_else(|e| e.into_inner());
        if pool.len() < KEPT {
            pool.push(std::mem::take(&mut self.0));
        }
    }
}

impl<T: Recyclable> Deref for Scratch<T> {
    type Target = Vec<T>;
    fn deref(&self) -> &Vec<T> {
        &self.0
    }
}

impl<T: Recyclable> DerefMut for Scratch<T> {
    fn deref_mut(&mut self) -> &mut Vec<T> {
        &mut self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_vector_comes_back_with_its_memory_and_the_asked_values() {
        // u32's pool is shared with other tests in this process: check values, and the
        // memory only of a vector this test made and gave back last.
        let mut a = Scratch::<u32>::filled(1000, 7);
        assert!(a.iter().all(|&v| v == 7));
        a[3] = 9;
        let ptr = a.as_ptr();
        drop(a);
        let b = Scratch::<u32>::stale(10, 1);
        let same = b.as_ptr() == ptr;
        if same {
            assert_eq!(b[3], 9, "stale keeps what the vector held");
        }
        assert_eq!(b.len(), 10);
        drop(b);
        let c = Scratch::<u32>::filled(2000, 5);
        assert_eq!(c.len(), 2000);
        assert!(c.iter().all(|&v| v == 5), "filled writes every value");
        let e = Scratch::<u32>::empty();
        assert!(e.is_empty());
    }

    #[test]
    fn the_pool_keeps_at_most_kept_vectors() {
        let many: Vec<Scratch<bool>> = (0..KEPT + 5).map(|_| Scratch::filled(8, true)).collect();
        drop(many);
        let held = bool::pool().lock().unwrap().len();
        assert!(held <= KEPT, "{held} vectors kept");
        let out = Scratch::<bool>::filled(4, false).into_vec();
        assert_eq!(out, vec![false; 4]);
    }
}
