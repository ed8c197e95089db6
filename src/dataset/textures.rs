//! Textures per (finish, instance): made through a [`TextureSource`] and kept in a
//! bounded cache, so memory stays flat over a long run however many finishes it has.

use std::collections::VecDeque;
use std::sync::Arc;

use super::error::{DatasetError, Result};
use super::job::Finish;
use super::renderer::TextureMap;

/// One texture a [`TextureSource::make_many`] call is asked for (the arguments of
/// [`TextureSource::make`]).
#[derive(Clone, Copy, Debug)]
pub struct TextureWant<'a> {
    pub finish: &'a Finish,
    pub instance: u32,
    pub seed: u64,
    pub size_px: usize,
    pub spacing_um: f64,
}

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

    /// Several textures (one image's faces), each result what `make` gives for it, in
    /// the order asked. By default one `make` after the other; a source may make them
    /// side by side.
    fn make_many(&mut self, wants: &[TextureWant<'_>]) -> Vec<Result<TextureMap, String>> {
        wants
            .iter()
            .map(|w| self.make(w.finish, w.instance, w.seed, w.size_px, w.spacing_um))
            .collect()
    }
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

    /// The textures of `keys` (one image's faces; a key may repeat), each made on a miss,
    /// the misses all at once by `make_all` (given the distinct missing keys in the
    /// order of `keys`, it returns their maps in that order) so that they can be made side
    /// by side. The hits are kept and the least recently used others evicted before the
    /// misses are made, so the peak stays `capacity` maps; when the keys' maps do not all
    /// fit, one key after the other as [`TextureCache::get`] (the same maps either way).
    pub fn get_many(
        &mut self,
        keys: &[(usize, u32)],
        mut make_all: impl FnMut(&[(usize, u32)]) -> Result<Vec<TextureMap>>,
    ) -> Result<Vec<Arc<TextureMap>>> {
        let mut distinct: Vec<(usize, u32)> = Vec::new();
        for k in keys {
            if !distinct.contains(k) {
                distinct.push(*k);
            }
        }
        if distinct.len() > self.capacity {
            return keys
                .iter()
                .map(|&k| {
                    self.get(k, || {
                        let mut one = make_all(&[k])?;
                        Ok(one.pop().expect("make_all returns one map per key"))
                    })
                })
                .collect();
        }
        // The hits to the most recent end, then room for the misses at the other.
        let mut misses = Vec::new();
        for k in &distinct {
            match self.entries.iter().position(|(e, _)| e == k) {
                Some(pos) => {
                    let e = self.entries.remove(pos).unwrap_or_else(|| unreachable!());
                    self.entries.push_back(e);
                }
                None => misses.push(*k),
            }
        }
        if !misses.is_empty() {
            while self.entries.len() + misses.len() > self.capacity {
                self.entries.pop_front();
            }
            let maps = make_all(&misses)?;
            assert_eq!(maps.len(), misses.len(), "make_all returns one map per key");
            self.made += maps.len();
            for (k, m) in misses.into_iter().zip(maps) {
                self.entries.push_back((k, Arc::new(m)));
            }
        }
        Ok(keys
            .iter()
            .map(|k| {
                let (_, m) = self
                    .entries
                    .iter()
                    .find(|(e, _)| e == k)
                    .unwrap_or_else(|| unreachable!("every key is in the cache now"));
                m.clone()
            })
            .collect())
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1 x 1 map whose one slope tells which key made it.
    fn map(k: (usize, u32)) -> TextureMap {
        TextureMap {
            width: 1,
            height: 1,
            spacing_um: 1.0,
            data: vec![[k.0 as f32, k.1 as f32]],
        }
    }

    fn keys_of(c: &TextureCache) -> Vec<(usize, u32)> {
        c.entries.iter().map(|(k, _)| *k).collect()
    }

    #[test]
    fn get_many_makes_the_misses_together_and_keeps_the_peak() {
        let mut c = TextureCache::new(3);
        let mut calls: Vec<Vec<(usize, u32)>> = Vec::new();
        let mut make = |ks: &[(usize, u32)]| {
            calls.push(ks.to_vec());
            Ok(ks.iter().map(|&k| map(k)).collect())
        };
        // A repeated key is made once; the maps come in the keys' order.
        let got = c.get_many(&[(0, 1), (0, 2), (0, 1)], &mut make).unwrap();
        assert_eq!(got.len(), 3);
        assert!(Arc::ptr_eq(&got[0], &got[2]));
        assert_eq!(got[1].data, vec![[0.0, 2.0]]);
        // Only the miss is made; the hit stays.
        let got = c.get_many(&[(0, 2), (0, 3)], &mut make).unwrap();
        assert_eq!(got[1].data, vec![[0.0, 3.0]]);
        assert_eq!(keys_of(&c), vec![(0, 1), (0, 2), (0, 3)]);
        // Two misses beside one hit: the hit kept, the two least recently used others
        // evicted before the misses are made, so never more than 3 maps.
        let got = c.get_many(&[(0, 4), (0, 1), (0, 5)], &mut make).unwrap();
        assert_eq!(
            got.iter().map(|m| m.data[0]).collect::<Vec<_>>(),
            vec![[0.0, 4.0], [0.0, 1.0], [0.0, 5.0]]
        );
        assert_eq!(keys_of(&c), vec![(0, 1), (0, 4), (0, 5)]);
        assert_eq!(c.made, 5);
        assert_eq!(
            calls,
            vec![vec![(0, 1), (0, 2)], vec![(0, 3)], vec![(0, 4), (0, 5)]]
        );
    }

    #[test]
    fn get_many_without_room_for_all_makes_one_after_the_other() {
        let mut c = TextureCache::new(1);
        let mut calls = Vec::new();
        let got = c
            .get_many(&[(1, 0), (2, 0)], |ks| {
                calls.push(ks.to_vec());
                Ok(ks.iter().map(|&k| map(k)).collect())
            })
            .unwrap();
        assert_eq!(calls, vec![vec![(1, 0)], vec![(2, 0)]]);
        assert_eq!(got[0].data, vec![[1.0, 0.0]]);
        assert_eq!(got[1].data, vec![[2.0, 0.0]]);
        assert_eq!(keys_of(&c), vec![(2, 0)]);
    }

    #[test]
    fn get_many_passes_a_failure_on_and_keeps_nothing_of_it() {
        let mut c = TextureCache::new(4);
        c.get_many(&[(0, 0)], |ks| Ok(ks.iter().map(|&k| map(k)).collect()))
            .unwrap();
        let err = c
            .get_many(&[(0, 0), (0, 1)], |_| {
                Err(DatasetError::Texture {
                    finish: "f".into(),
                    instance: 1,
                    message: "no memory".into(),
                })
            })
            .unwrap_err();
        assert!(err.to_string().contains("no memory"), "{err}");
        assert_eq!(keys_of(&c), vec![(0, 0)]);
        assert_eq!(c.made, 1);
    }
}
