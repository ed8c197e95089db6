//! glsl/common/convert.glsl's float-to-integer conversions give what GLSL's own give on
//! this device (lavapipe: saturating, NaN to 0) over their callers' ranges (f2u below
//! 2^24, the octahedral normals' codes included; f2i below 2^22 in magnitude), so the path
//! tracer's images did not change when it took them (docs/benchmarks/rendering.md, "What
//! lavapipe compiles lane by lane").

mod common;

use ash::vk;
use synosis::graph::Graph;
use synosis::vk::{BindingKind, Buffer, ComputePipeline, MemoryKind};

/// Floats at the edges (zeros, halves, the ranges' ends, NaN, subnormals) and random ones
/// over the ranges, as bits.
fn inputs() -> Vec<f32> {
    let mut xs = vec![
        0.0,
        -0.0,
        1e-40,
        -1e-40,
        0.49999997,
        0.5,
        0.99999994,
        1.0,
        1.5,
        2.5,
        -0.5,
        -0.99999994,
        -1.0,
        -1.5,
        -2.5,
        255.99998,
        256.0,
        4_194_302.5,
        4_194_303.0,
        -4_194_302.5,
        -4_194_303.0,
        8_388_606.5,
        8_388_607.0,
        8_388_607.5,
        8_388_608.0,
        8_388_609.0,
        12_345_679.0,
        16_777_214.0,
        16_777_215.0,
        -8_388_607.0,
        -3.0e38,
        f32::NAN,
        -f32::NAN,
    ];
    // A small xorshift: the same floats every run.
    let mut s = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    while xs.len() < 64 * 256 {
        let r = next();
        let x = match r % 4 {
            // uniform over both ranges
            0 => (r >> 8) as f32 / (1u64 << 56) as f32 * 2.0 * 4_194_303.0 - 4_194_303.0,
            1 => (r >> 8) as f32 / (1u64 << 56) as f32 * 16_777_215.0,
            // any float bits, kept where below 2^24 in magnitude (small ones, fractions)
            _ => f32::from_bits((r >> 16) as u32),
        };
        if x.is_nan() || x.abs() < 16_777_215.0 {
            xs.push(x);
        }
    }
    xs
}

#[test]
fn float_to_integer_conversions_match_glsls_own() {
    let ctx = common::gpu();
    let spirv = synosis::shaders::spirv("convert_check").expect("build.rs compiles convert_check");
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let pipe = ComputePipeline::new(
        &ctx,
        "convert_check",
        &spirv,
        &[BindingKind::StorageBuffer; 2],
        0,
        [64, 1, 1],
        &[],
    )
    .unwrap();
    let xs = inputs();
    let input = Buffer::from_slice(&ctx, "floats", &xs, storage).unwrap();
    let output = Buffer::new(
        &ctx,
        "conversions",
        xs.len() as u64 * 16,
        storage,
        MemoryKind::Readback,
    )
    .unwrap();
    let mut g = Graph::new(&ctx, "conversions");
    let i = g.import(&input);
    let mut o = g.import(&output);
    g.dispatch("convert", &pipe, [(xs.len() as u32).div_ceil(64), 1, 1])
        .read(0, &i)
        .write(1, &mut o)
        .submit();
    g.execute(None).unwrap();
    let out: Vec<[u32; 4]> = output.read::<[u32; 4]>().unwrap();
    let mut checked = [0usize; 2];
    for (x, [f2u, uint, f2i, int]) in xs.iter().zip(out) {
        // f2u: every x below 2^24 (negatives and NaN included): the octahedral normals'
        // codes reach 2^24 - 1.
        if x.is_nan() || *x < 16_777_215.5 {
            assert_eq!(f2u, uint, "f2u({x:e}) = {f2u}, uint() = {uint}");
            // lavapipe's uint(x) saturates (Rust's `as` does the same).
            assert_eq!(uint, *x as u32, "uint({x:e}) = {uint}");
            checked[0] += 1;
        }
        // f2i: |x| below 2^22, and NaN.
        if x.is_nan() || x.abs() < 4_194_303.5 {
            assert_eq!(
                f2i, int,
                "f2i({x:e}) = {}, int() = {}",
                f2i as i32, int as i32
            );
            assert_eq!(int as i32, *x as i32, "int({x:e}) = {}", int as i32);
            checked[1] += 1;
        }
    }
    assert!(checked[0] > 10_000 && checked[1] > 10_000, "{checked:?}");
    common::assert_clean(&ctx);
}
