//! The Rust side of the shader interface declared in `src/gpu_interface.in` (build.rs
//! writes the GLSL side from the same file, as `interface.glsl`). What crosses the
//! boundary is declared there once: constants, binding numbers and the layout of every
//! parameter and push-constant block. A block whose Rust layout could differ from
//! std430 fails to compile (checks below each struct).

/// GLSL type -> Rust type of a block field.
macro_rules! gpu_field_ty {
    (vec4) => {
        [f32; 4]
    };
    (uvec4) => {
        [u32; 4]
    };
    (float) => {
        f32
    };
    (uint) => {
        u32
    };
    ($block:ident) => {
        $block
    };
}

/// Whether a field must start on a 16-byte boundary (vec4, uvec4, nested blocks).
macro_rules! gpu_field_wide {
    (float) => {
        false
    };
    (uint) => {
        false
    };
    ($other:ident) => {
        true
    };
}

macro_rules! gpu_constants {
    ($($(#[doc = $doc:literal])* $name:ident = $value:literal;)*) => {
        $($(#[doc = $doc])* pub const $name: u32 = $value;)*
    };
}

macro_rules! gpu_bindings {
    ($($(#[doc = $doc:literal])* $enum:ident $prefix:ident { $($b:ident),* $(,)? })*) => {
        $(
            $(#[doc = $doc])*
            #[derive(Clone, Copy, Debug, PartialEq, Eq)]
            #[repr(u32)]
            pub enum $enum { $($b),* }
            impl $enum {
                /// Number of bindings of the pass (after the backend's).
                pub const COUNT: usize = [$($enum::$b),*].len();
                /// The binding number, after `backend_bindings` of the trace backend.
                pub fn at(self, backend_bindings: u32) -> u32 {
                    backend_bindings + self as u32
                }
            }
        )*
    };
}

macro_rules! gpu_blocks {
    ($($(#[doc = $doc:literal])* $name:ident { $($f:ident : $t:ident),* $(,)? })*) => {
        $(
            $(#[doc = $doc])*
            #[repr(C)]
            #[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
            pub struct $name { $(pub $f: gpu_field_ty!($t)),* }
            const _: () = {
                assert!(std::mem::size_of::<$name>() % 16 == 0, "block size must be a multiple of 16");
                $(assert!(
                    !gpu_field_wide!($t) || std::mem::offset_of!($name, $f) % 16 == 0,
                    "vec4 / nested fields must be 16-byte aligned (std430)"
                );)*
            };
        )*
    };
}

macro_rules! gpu_specs {
    ($(#[doc = $doc:literal])* $block:ident { $($f:ident = $id:literal),* $(,)? }) => {
        /// How many of the path tracer's settings are specialization constants.
        pub const PATH_SPEC_COUNT: usize = [$($id),*].len();
        impl $block {
            $(#[doc = $doc])*
            ///
            /// The (constant_id, value) of each, from these parameters.
            pub fn specialization(&self) -> [(u32, u32); PATH_SPEC_COUNT] {
                [$(($id, self.$f)),*]
            }
        }
    };
}

include!("gpu_interface.in");

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_match_what_the_shaders_were_written_for() {
        assert_eq!(std::mem::size_of::<PathParams>(), 288);
        assert_eq!(std::mem::offset_of!(PathParams, table), 256);
        assert_eq!(std::mem::offset_of!(PathParams, cover_lo), 192);
        assert_eq!(std::mem::offset_of!(PathParams, cover_cell), 208);
        assert_eq!(std::mem::offset_of!(PathParams, lights_lo), 224);
        assert_eq!(std::mem::offset_of!(PathParams, lights_hi), 240);
        assert_eq!(std::mem::offset_of!(PathParams, texture_filter), 176);
        assert_eq!(std::mem::offset_of!(PathParams, width), 96);
        assert_eq!(std::mem::offset_of!(PathParams, light_first), 160);
        assert_eq!(std::mem::size_of::<PathPush>(), 32);
        // Push constants: 128 bytes is all Vulkan guarantees.
        assert_eq!(std::mem::size_of::<ImagePush>(), 128);
        assert_eq!(PathTraceBinding::COUNT, 24);
        assert_eq!(PathTraceBinding::LabelCoverage.at(2), 22);
        assert_eq!(PathTraceBinding::PixelList.at(2), 23);
        assert_eq!(PathTraceBinding::LightWeights.at(2), 24);
        assert_eq!(PathTraceBinding::Addresses.at(2), 25);
        assert_eq!(std::mem::size_of::<LightTri>(), 48);
        // path_trace.comp's map_buffer_addr picks a map's buffer among three consecutive
        // bindings.
        assert_eq!(
            PathTraceBinding::Slopes2.at(0),
            PathTraceBinding::Slopes0.at(0) + 2
        );
        assert_eq!(
            PathTraceBinding::Moments2.at(0),
            PathTraceBinding::Moments0.at(0) + 2
        );
        assert_eq!(std::mem::offset_of!(PathPush, pixel_count), 12);
        assert_eq!(std::mem::offset_of!(PathPush, labels), 8);
        assert_eq!(PathTraceBinding::NoiseSums.at(2), 19);
        assert_eq!(std::mem::offset_of!(PathParams, noise_sums), 188);
        assert_eq!(PathTraceBinding::CurvedMaps.at(2), 15);
        assert_eq!(PathTraceBinding::Moments0.at(2), 16);
        assert_eq!(PathTraceBinding::LightGeometry.at(2), 12);
        assert_eq!(PathTraceBinding::LightList.at(2), 13);
        assert_eq!(std::mem::size_of::<LightBlock>(), 80);
        assert_eq!(PathTraceBinding::Surfaces.at(2), 14);
        assert_eq!(std::mem::size_of::<SurfaceBlock>(), 32);
    }

    #[test]
    fn the_generated_header_declares_every_block_and_binding() {
        let glsl = include_str!(concat!(env!("OUT_DIR"), "/interface.glsl"));
        for name in [
            "struct PathParams",
            "struct CameraBlock",
            "#define PT_LIGHT_GEOMETRY",
            "struct LightBlock",
            "#define PT_LIGHT_LIST",
            "#define PT_MOMENTS2",
            "#define PT_NOISE_SUMS",
            "#define FILTER_LEAN 1u",
        ] {
            assert!(glsl.contains(name), "{name} missing from interface.glsl");
        }
        assert!(glsl.contains("#define MAT_LIGHT 2u"));
    }
}
