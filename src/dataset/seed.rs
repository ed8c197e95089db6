//! Deterministic seed splitting: every random choice of a job flows from its one `u64`
//! seed through [`derive()`], keyed by what the choice is for, so any image (or texture, or
//! defect set) can be re-made alone, independent of the order or sharding of the run.
//!
//! The hash (documented in docs/dataset.md, stable across versions of this crate):
//! `h0 = splitmix64(seed ^ 0x5359_4E4F_5349_5321)`, then for each key part `p`:
//! `h = splitmix64(h ^ p)`. Names (object, finish, view) enter as their FNV-1a 64 hash,
//! so re-ordering the job file does not change any seed.

/// Domain tags: the first key part, so e.g. texture 3 and defect set 3 never share a seed.
pub mod tag {
    pub const OBJECT: u64 = 1;
    pub const TEXTURE: u64 = 2;
    pub const DEFECT: u64 = 3;
    pub const IMAGE: u64 = 4;
    pub const SPLIT: u64 = 5;
    pub const POST: u64 = 6;
    pub const REGIONS: u64 = 7;
    /// The per-image random exposure (`[sensor] exposure_jitter_ev`).
    pub const EXPOSURE: u64 = 8;
    /// The EMVA 1288 sensor's noise of an image.
    pub const SENSOR: u64 = 9;
}

/// SplitMix64 finaliser (Steele et al. 2014): a bijective 64-bit mixer.
pub fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// FNV-1a, 64 bit: names as key parts, and the content hashes in the manifest (a
/// change/corruption check, not a cryptographic one).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// The seed for one random choice: `seed` split by the key `parts` (a tag first).
pub fn derive(seed: u64, parts: &[u64]) -> u64 {
    let mut h = splitmix64(seed ^ 0x5359_4E4F_5349_5321);
    for &p in parts {
        h = splitmix64(h ^ p);
    }
    h
}

/// Key part for a name.
pub fn name(s: &str) -> u64 {
    fnv1a64(s.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv_reference_values() {
        // Published FNV-1a 64 test vectors.
        assert_eq!(fnv1a64(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn keys_separate() {
        let a = derive(7, &[tag::TEXTURE, 3]);
        let b = derive(7, &[tag::DEFECT, 3]);
        let c = derive(8, &[tag::TEXTURE, 3]);
        assert!(a != b && a != c && b != c);
        assert_eq!(a, derive(7, &[tag::TEXTURE, 3]));
    }
}
