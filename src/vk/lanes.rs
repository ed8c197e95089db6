//! Lavapipe's SIMD width: 512-bit lanes on the CPUs where they were measured faster.
//!
//! Mesa's lavapipe runs a shader's invocations in the lanes of one SIMD register: 256
//! bits (8 invocations) by default, also on CPUs with AVX-512, unless the environment
//! variable `LP_NATIVE_VECTOR_WIDTH` says otherwise; the driver reads it once, when it
//! loads. On an Intel Xeon with AVX-512 (family 6, model 207) 512-bit lanes traced the
//! paper job's crops in about 0.8 of the time, the images and labels the same bytes
//! (docs/benchmarks/dataset.md, "512-bit lanes on an Intel CPU"); on an AMD EPYC Zen 5
//! (family 26, whose AVX-512 units are 512 bits wide) in 0.76 of it (the same file,
//! "512-bit lanes on an AMD EPYC Zen 5"); on an AMD EPYC Zen 4 (family 25, which splits
//! a 512-bit operation in two) they were 1.25x to 1.35x slower on 2026-11-27 and gave
//! no gain on 2026-12-01 (1.045 of the time per sample). So a process asks for 512-bit
//! lanes on an Intel CPU with AVX-512F and on an AMD one of family 26 or later with
//! AVX-512F, unless the user set the variable (`LP_NATIVE_VECTOR_WIDTH=256` keeps the
//! driver's width), and leaves the driver's default elsewhere. Other drivers do not read
//! the variable. Not measured: family 26's mobile parts, which are said to split 512-bit
//! operations in two as Zen 4 does (they get 512 bits too; the variable overrides).
//!
//! **Each width its own shader cache.** Mesa's on-disk shader cache keys lavapipe's
//! compiled code by the shader and the CPU, not by the vector width, and its texel-fetch
//! and sampling functions (which every `texelFetch` calls) by the texture's format alone.
//! A process at one width given a cache filled at another runs the cached shaders at
//! their width's speed, and where a shader is not cached yet (another backend, a changed
//! shader: a new version of synosis) it compiles it at its own width and calls the cached
//! functions of the other: measured with Mesa 25.0.7 (the other backend's raycast), one
//! at 128 bits after one at 256 and one at 256 after one at 512 died of a segmentation
//! fault, one at 512 after one at 256 missed every triangle without an error (test
//! `tests/raycast.rs` `lane_widths_one_after_another_share_a_cache_folder`). So where the
//! width is set through the environment (here, or by the user), [`choose`] also points
//! `MESA_SHADER_CACHE_DIR` at a folder of that value's own, `lavapipe-lanes-<bits>`
//! inside the folder Mesa would use (`MESA_SHADER_CACHE_DIR`, else `XDG_CACHE_HOME`,
//! else `~/.cache`); a process at the driver's default width keeps Mesa's folder. Mesa's
//! other drivers read the variable too: on a machine whose GPU has a Mesa driver such a
//! process compiles into that folder as well (once).

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The environment variable lavapipe takes its vector width from, in bits.
pub const WIDTH_VAR: &str = "LP_NATIVE_VECTOR_WIDTH";

/// The environment variable naming the folder of Mesa's on-disk shader cache.
pub const CACHE_VAR: &str = "MESA_SHADER_CACHE_DIR";

/// How this process's lavapipe vector width was chosen.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LaneWidth {
    /// The user's environment set `LP_NATIVE_VECTOR_WIDTH` (its value).
    User(String),
    /// 512 bits, set here: an Intel CPU with AVX-512F, or an AMD one of family 26 (Zen 5)
    /// or later with AVX-512F.
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
                "512 bits (chosen for this CPU: AVX-512F, Intel or AMD Zen 5 or later; {WIDTH_VAR}=256 keeps the driver's 256)"
            ),
            LaneWidth::Driver => "the driver's default (256 bits with AVX2)".into(),
        }
    }
}

/// The first AMD CPU family (Zen 5) whose 512-bit lanes were measured faster; Zen 4
/// (family 25) runs a 512-bit operation as two 256-bit halves and gained nothing.
const AMD_WIDE_FAMILY: u32 = 26;

/// What [`wide_preferred`] looks at: the CPUID vendor ("GenuineIntel", "AuthenticAMD",
/// ...), the display family (base family plus, where the base is 15, the extended
/// family) and whether the CPU has AVX-512F.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Cpu {
    vendor: String,
    family: u32,
    avx512f: bool,
}

/// Whether 512-bit lanes are asked for on `cpu`: an Intel CPU with AVX-512F, or an AMD
/// one of family [`AMD_WIDE_FAMILY`] or later with AVX-512F.
fn wide_preferred(cpu: &Cpu) -> bool {
    cpu.avx512f
        && match cpu.vendor.as_str() {
            "GenuineIntel" => true,
            "AuthenticAMD" => cpu.family >= AMD_WIDE_FAMILY,
            _ => false,
        }
}

/// Whether [`choose`] asks for 512-bit lanes on this CPU where the environment leaves
/// the width to it (`wide_preferred` of this CPU).
pub fn preferred_here() -> bool {
    wide_preferred(&host_cpu())
}

/// The display family from CPUID leaf 1's eax: bits 8 to 11, plus bits 20 to 27 where
/// those are 15.
fn display_family(leaf1_eax: u32) -> u32 {
    let base = (leaf1_eax >> 8) & 0xf;
    if base == 0xf {
        base + ((leaf1_eax >> 20) & 0xff)
    } else {
        base
    }
}

/// This CPU's vendor, family and AVX-512F (an empty vendor, 0 and false off x86-64).
fn host_cpu() -> Cpu {
    #[cfg(target_arch = "x86_64")]
    {
        // CPUID leaf 0 names the vendor in ebx, edx, ecx (12 ASCII bytes); leaf 1's eax
        // holds the family.
        let r = std::arch::x86_64::__cpuid(0);
        let mut v = Vec::with_capacity(12);
        for w in [r.ebx, r.edx, r.ecx] {
            v.extend_from_slice(&w.to_le_bytes());
        }
        let family = if r.eax >= 1 {
            display_family(std::arch::x86_64::__cpuid(1).eax)
        } else {
            0
        };
        Cpu {
            vendor: String::from_utf8_lossy(&v).into_owned(),
            family,
            avx512f: std::arch::is_x86_feature_detected!("avx512f"),
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        Cpu {
            vendor: String::new(),
            family: 0,
            avx512f: false,
        }
    }
}

/// The shader-cache folder of a process whose lane width is set to `bits` through the
/// environment: `lavapipe-lanes-<bits>` (the value's letters and digits, others as `_`)
/// inside the folder Mesa would use (`mesa_dir`, the value of `MESA_SHADER_CACHE_DIR`,
/// else `xdg`, `XDG_CACHE_HOME`, else `home`'s `.cache`; empty values count as unset), or
/// `mesa_dir` itself where it already is that folder (a process started by one that set
/// it). Values that differ get folders that differ, also where lavapipe reads them as one
/// width ("512", "0x200"). None where no folder is known (Mesa keeps no cache).
pub fn cache_dir_for(
    bits: &str,
    mesa_dir: Option<&OsStr>,
    xdg: Option<&OsStr>,
    home: Option<&OsStr>,
) -> Option<PathBuf> {
    let value: String = bits
        .trim()
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    let name = format!("lavapipe-lanes-{value}");
    fn set(v: Option<&OsStr>) -> Option<&Path> {
        v.filter(|v| !v.is_empty()).map(Path::new)
    }
    if let Some(dir) = set(mesa_dir) {
        if dir.file_name() == Some(OsStr::new(&name)) {
            return Some(dir.to_path_buf());
        }
        return Some(dir.join(name));
    }
    if let Some(dir) = set(xdg) {
        return Some(dir.join(name));
    }
    set(home).map(|h| h.join(".cache").join(name))
}

static CHOICE: OnceLock<LaneWidth> = OnceLock::new();
static CACHE: OnceLock<Option<PathBuf>> = OnceLock::new();

/// The shader-cache folder [`choose`] set for this process's width, or None where it left
/// Mesa's (the driver's default width; before `choose`).
pub fn cache_dir() -> Option<&'static Path> {
    CACHE.get().and_then(|c| c.as_deref())
}

/// The process's choice, made at the first call: sets `LP_NATIVE_VECTOR_WIDTH=512` where
/// `wide_preferred` says so and the environment does not set it already, and, where the
/// width is set through the environment, `MESA_SHADER_CACHE_DIR` to that width's folder
/// ([`cache_dir_for`]). Called by `Context::new` before it loads the Vulkan loader (a
/// driver loaded earlier keeps the width and the folder it read).
pub fn choose() -> LaneWidth {
    CHOICE
        .get_or_init(|| {
            let width = if let Some(v) = std::env::var_os(WIDTH_VAR) {
                LaneWidth::User(v.to_string_lossy().into_owned())
            } else if preferred_here() {
                // SAFETY: set once, before this process loads any Vulkan driver (the
                // first `Context::new`, under its lifecycle lock), so no driver thread
                // reads the environment yet; Rust's own readers take std's lock.
                unsafe { std::env::set_var(WIDTH_VAR, "512") };
                LaneWidth::Wide
            } else {
                LaneWidth::Driver
            };
            let bits = match &width {
                LaneWidth::User(v) => Some(v.as_str()),
                LaneWidth::Wide => Some("512"),
                LaneWidth::Driver => None,
            };
            let dir = bits.and_then(|b| {
                cache_dir_for(
                    b,
                    std::env::var_os(CACHE_VAR).as_deref(),
                    std::env::var_os("XDG_CACHE_HOME").as_deref(),
                    std::env::var_os("HOME").as_deref(),
                )
            });
            if let Some(d) = &dir {
                // SAFETY: as above, before any driver has loaded.
                unsafe { std::env::set_var(CACHE_VAR, d) };
            }
            let _ = CACHE.set(dir);
            width
        })
        .clone()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wide_lanes_on_intel_and_amd_zen5_with_avx512() {
        let cpu = |vendor: &str, family, avx512f| Cpu {
            vendor: vendor.into(),
            family,
            avx512f,
        };
        assert!(wide_preferred(&cpu("GenuineIntel", 6, true)));
        assert!(!wide_preferred(&cpu("GenuineIntel", 6, false)));
        // Zen 4 (family 25) splits 512-bit operations in two: measured no faster.
        assert!(!wide_preferred(&cpu("AuthenticAMD", 25, true)));
        assert!(wide_preferred(&cpu("AuthenticAMD", 26, true)));
        assert!(wide_preferred(&cpu("AuthenticAMD", 27, true)));
        assert!(!wide_preferred(&cpu("AuthenticAMD", 26, false)));
        assert!(!wide_preferred(&cpu("HygonGenuine", 24, true)));
        assert!(!wide_preferred(&cpu("", 0, false)));
    }

    #[test]
    fn display_family_adds_the_extended_family_only_to_family_15() {
        // CPUID leaf 1 eax of an EPYC 9004 (Zen 4: family 0x19, model 0x11) and of an
        // EPYC 9005 (Zen 5: family 0x1a, model 0x02), and of an Intel Xeon (family 6,
        // model 0xcf: extended model 0xc, whose extended family bits are zero).
        assert_eq!(display_family(0x00a1_0f11), 25);
        assert_eq!(display_family(0x00b0_0f21), 26);
        assert_eq!(display_family(0x000c_06f2), 6);
        // A base family other than 15 ignores the extended family's bits.
        assert_eq!(display_family(0x0ff0_0600), 6);
    }

    #[test]
    fn each_width_caches_in_a_folder_of_its_own() {
        let os = |s: &'static str| Some(OsStr::new(s));
        let dir = |b, m, x, h| cache_dir_for(b, m, x, h).map(|p| p.display().to_string());
        // Mesa's order: its variable, XDG_CACHE_HOME, then ~/.cache; empty is unset.
        assert_eq!(
            dir("512", os("/c/m"), os("/x"), os("/h")).as_deref(),
            Some("/c/m/lavapipe-lanes-512")
        );
        assert_eq!(
            dir("256", None, os("/x"), os("/h")).as_deref(),
            Some("/x/lavapipe-lanes-256")
        );
        assert_eq!(
            dir(" 512\n", os(""), os(""), os("/h")).as_deref(),
            Some("/h/.cache/lavapipe-lanes-512")
        );
        // A child of a process that set the folder keeps it, not a folder inside it.
        assert_eq!(
            dir("512", os("/c/m/lavapipe-lanes-512"), None, None).as_deref(),
            Some("/c/m/lavapipe-lanes-512")
        );
        // ... unless its width is another.
        assert_eq!(
            dir("256", os("/c/m/lavapipe-lanes-512"), None, None).as_deref(),
            Some("/c/m/lavapipe-lanes-512/lavapipe-lanes-256")
        );
        // Any value its own folder (lavapipe reads "0x200" as 512, "wide" as its default).
        assert_eq!(
            dir("0x200", os("/c"), None, None).as_deref(),
            Some("/c/lavapipe-lanes-0x200")
        );
        assert_eq!(
            dir("a/../b", os("/c"), None, None).as_deref(),
            Some("/c/lavapipe-lanes-a____b")
        );
        // No folder at all: Mesa keeps no cache.
        assert_eq!(dir("512", None, None, None), None);
    }
}
