//! glsl/common/convert.glsl's float-to-integer conversions give what GLSL's own give on
//! this device (lavapipe: saturating, NaN to 0) over their callers' ranges (f2u below
//! 2^24, the octahedral normals' codes included; f2i below 2^22 in magnitude), so the path
//! tracer's images did not change when it took them (docs/benchmarks/rendering.md, "What
//! lavapipe compiles lane by lane"); the shader's octahedral normals
//! (glsl/common/octahedral.glsl) are their CPU mirror's (`scene::curved::decode_normal`);
//! and a direction in one word (`rec_pack`, `rec_unpack`) comes back within its rounding.

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

/// Runs glsl/convert_check.comp over `xs`: per float its conversions (f2u, uint(), the
/// bits of f2i and int()) and its octahedral decode.
fn run_checks(xs: &[f32]) -> (Vec<[u32; 4]>, Vec<[f32; 4]>) {
    let ctx = common::gpu();
    let spirv = synosis::shaders::spirv("convert_check").expect("build.rs compiles convert_check");
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let pipe = ComputePipeline::new(
        &ctx,
        "convert_check",
        &spirv,
        &[BindingKind::StorageBuffer; 3],
        0,
        [64, 1, 1],
        &[],
    )
    .unwrap();
    let input = Buffer::from_slice(&ctx, "floats", xs, storage).unwrap();
    let readback = |name: &str| {
        Buffer::new(
            &ctx,
            name,
            xs.len() as u64 * 16,
            storage,
            MemoryKind::Readback,
        )
        .unwrap()
    };
    let (output, normals) = (readback("conversions"), readback("normals"));
    let mut g = Graph::new(&ctx, "conversions");
    let i = g.import(&input);
    let mut o = g.import(&output);
    let mut n = g.import(&normals);
    g.dispatch("convert", &pipe, [(xs.len() as u32).div_ceil(64), 1, 1])
        .read(0, &i)
        .write(1, &mut o)
        .write(2, &mut n)
        .submit();
    g.execute(None).unwrap();
    let out = (
        output.read::<[u32; 4]>().unwrap(),
        normals.read::<[f32; 4]>().unwrap(),
    );
    common::assert_clean(&ctx);
    out
}

#[test]
fn float_to_integer_conversions_match_glsls_own() {
    let xs = inputs();
    let (out, _) = run_checks(&xs);
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
}

#[test]
fn octahedral_normals_decode_as_their_cpu_mirror() {
    use synosis::gpu_interface::OCT_LEVELS;
    use synosis::scene::curved::{decode_normal, encode_normal};
    // Codes at both coordinates' ends and middles (u * OCT_LEVELS + v, up to 2^24 - 1),
    // and those of normals all round the sphere.
    let edges = [0u32, 1, 2046, 2047, 2048, 2049, 4094, 4095];
    let mut codes: Vec<f32> = edges
        .iter()
        .flat_map(|&u| edges.iter().map(move |&v| (u * OCT_LEVELS + v) as f32))
        .collect();
    for i in 0..2000 {
        let (t, p) = (
            (i as f32 * 0.618_034).fract() * std::f32::consts::PI,
            i as f32 * 0.37,
        );
        let n = glam::Vec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
        codes.push(encode_normal(n));
    }
    let (_, normals) = run_checks(&codes);
    for (code, n) in codes.iter().zip(normals) {
        let want = decode_normal(*code);
        let err = (n[0] - want.x)
            .abs()
            .max((n[1] - want.y).abs())
            .max((n[2] - want.z).abs());
        assert!(err < 1e-5, "code {code}: shader {n:?}, CPU {want:?}");
    }
}

/// A direction through `rec_pack` and `rec_unpack` (glsl/common/octahedral.glsl: one word,
/// 16 bits an octahedral axis; the analytic light's recorded ring vertices) comes back
/// within 1e-4 of itself as a unit vector, all round the sphere and at lengths from 0.01
/// to 100 (glsl/convert_check.comp `rec_direction`), and the rounding is there (not
/// the identity).
#[test]
fn directions_in_one_word_round_trip() {
    let xs: Vec<f32> = inputs().into_iter().filter(|x| x.is_finite()).collect();
    let (_, normals) = run_checks(&xs);
    let moved: Vec<f32> = normals
        .iter()
        .map(|n| n[3])
        .filter(|m| !m.is_nan())
        .collect();
    assert!(moved.len() > 10_000, "{} directions", moved.len());
    let worst = moved.iter().fold(0.0f32, |a, &m| a.max(m));
    let mean = moved.iter().map(|&m| m as f64).sum::<f64>() / moved.len() as f64;
    eprintln!(
        "{} directions: moved {mean:.2e} on average, {worst:.2e} at most",
        moved.len()
    );
    assert!(worst < 1e-4, "a direction moved by {worst:e}");
    assert!(mean > 1e-7, "no rounding at all: {mean:e}");
}
