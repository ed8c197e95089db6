//! SPIR-V compiled by build.rs from glsl/.

include!(concat!(env!("OUT_DIR"), "/shaders.rs"));

/// The SPIR-V words of a shader variant, e.g. `spirv("raycast.sw")`.
pub fn spirv(name: &str) -> Option<Vec<u32>> {
    SHADERS.iter().find(|(n, _)| *n == name).map(|(_, bytes)| {
        bytes
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    })
}

/// Every shader variant's name, e.g. `raycast.sw`.
pub fn names() -> impl Iterator<Item = &'static str> {
    SHADERS.iter().map(|(n, _)| *n)
}
