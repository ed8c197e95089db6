//! Lavapipe's SIMD width: 512-bit lanes on the CPUs where they were measured faster.
//!
//! Mesa's lavapipe runs a shader's invocations in the lanes of one SIMD register: 256
//! bits (8 invocations) by default, also on CPUs with AVX-512, unless the environment
//! variable `LP_NATIVE_VECTOR_WIDTH` says otherwise; the driver reads it once, when it
//! loads. On an Intel Xeon with AVX-512 (family 6, model 207) 512-bit lanes traced the
//! paper job's crops in about 0.8 of the time, the images and labels the same bytes; on
//! an AMD EPYC with AVX-512 (Zen 4, which splits a 512-bit operation in two) they were
//! 1.25x to 1.35x slower (docs/benchmarks/dataset.md, "512-bit lanes on an Intel CPU").
//! So a process asks for 512-bit lanes on an Intel CPU with AVX-512F, unless the user set
//! the variable (`LP_NATIVE_VECTOR_WIDTH=256` keeps the driver's width), and leaves the
//! driver's default elsewhere. Other drivers do not read the variable.

use std::sync::OnceLock;

/// The environment variable lavapipe takes its vector width from, in bits.
pub const WIDTH_VAR: &str = "LP_NATIVE_VECTOR_WIDTH";

/// How this process's lavapipe vector width was chosen.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LaneWidth {
    /// The user's environment set `LP_NATIVE_VECTOR_WIDTH` (its value).
    User(String),
    /// 512 bits, set here: an Intel CPU with AVX-512F.
    Wide,
    /// Left to the driver (256 bits where the CPU has AVX2 or AVX-512).
    Driver,
}

impl LaneWidth {
    /// One line for `synosis info`.
    pub fn describe(&self) -> String {
        match self {
            LaneWidth::User(v) => format!("{v} bits ({WIDTH_VAR} set in the environment)"),
            LaneWidth::Wide => format!(
                "512 bits (chosen for an Intel CPU with AVX-512F; {WIDTH_VAR}=256 keeps the driver's 256)"
            ),
            LaneWidth::Driver => "the driver's default (256 bits with AVX2)".into(),
        }
    }
}

/// Whether 512-bit lanes are asked for on a CPU of CPUID vendor `vendor`
/// ("GenuineIntel", "AuthenticAMD", ...) that has AVX-512F or not.
pub fn wide_preferred(vendor: &str, avx512f: bool) -> bool {
    vendor == "GenuineIntel" && avx512f
}

/// This CPU's vendor string and whether it has AVX-512F (none and false off x86-64).
fn host_cpu() -> (String, bool) {
    #[cfg(target_arch = "x86_64")]
    {
        // CPUID leaf 0 names the vendor in ebx, edx, ecx (12 ASCII bytes).
        let r = std::arch::x86_64::__cpuid(0);
        let mut v = Vec::with_capacity(12);
        for w in [r.ebx, r.edx, r.ecx] {
            v.extend_from_slice(&w.to_le_bytes());
        }
        (
            String::from_utf8_lossy(&v).into_owned(),
            std::arch::is_x86_feature_detected!("avx512f"),
        )
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        (String::new(), false)
    }
}

static CHOICE: OnceLock<LaneWidth> = OnceLock::new();

/// The process's choice, made at the first call: sets `LP_NATIVE_VECTOR_WIDTH=512` where
/// [`wide_preferred`] says so and the environment does not set it already. Called by
/// `Context::new` before it loads the Vulkan loader (a driver loaded earlier keeps the
/// width it read).
pub fn choose() -> LaneWidth {
    CHOICE
        .get_or_init(|| {
            if let Some(v) = std::env::var_os(WIDTH_VAR) {
                return LaneWidth::User(v.to_string_lossy().into_owned());
            }
            let (vendor, avx512f) = host_cpu();
            if !wide_preferred(&vendor, avx512f) {
                return LaneWidth::Driver;
            }
            // SAFETY: set once, before this process loads any Vulkan driver (the first
            // `Context::new`, under its lifecycle lock), so no driver thread reads the
            // environment yet; Rust's own readers take std's environment lock.
            unsafe { std::env::set_var(WIDTH_VAR, "512") };
            LaneWidth::Wide
        })
        .clone()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wide_lanes_only_on_intel_with_avx512() {
        assert!(wide_preferred("GenuineIntel", true));
        assert!(!wide_preferred("GenuineIntel", false));
        assert!(!wide_preferred("AuthenticAMD", true));
        assert!(!wide_preferred("", false));
    }
}
