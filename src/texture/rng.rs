//! Deterministic seed splitting: every stream (ring k, patch row r, ...) gets its own
//! generator derived from the job seed, so results do not depend on thread scheduling.

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

/// SplitMix64 finaliser: decorrelates nearby seeds/stream ids.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

pub(crate) fn stream(seed: u64, a: u64, b: u64) -> Pcg64Mcg {
    let s = mix(mix(mix(seed) ^ a.wrapping_mul(0xA24B_AED4_963E_E407)) ^ b);
    Pcg64Mcg::seed_from_u64(s)
}
