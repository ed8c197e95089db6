//! glsl/common/convert.glsl's float-to-integer conversions give what GLSL's own give on
//! this device (lavapipe: saturating, NaN to 0) over their callers' ranges (f2u below
//! 2^24, the octahedral normals' codes included; f2i below 2^22 in magnitude), so the path
//! tracer's images did not change when it took them (docs/benchmarks/rendering.md, "What
//! lavapipe compiles lane by lane"); the shader's octahedral normals
//! (glsl/common/octahedral.glsl) are their CPU mirror's (`scene::curved::decode_normal`);
//! a direction in one word (`rec_pack`, `rec_unpack`) comes back within its rounding;
//! and the analytic light's polygon edges (glsl/common/polygon_edge.glsl) are within
//! their fit's error of float64.

mod common;

use ash::vk;
use std::sync::Arc;
use synosis::graph::Graph;
use synosis::vk::{BindingKind, Buffer, ComputePipeline, Context, MemoryKind};

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

/// A check shader (`name`.comp, compiled by build.rs) with `bindings` storage buffers and
/// 64 invocations a workgroup, no push constants.
fn check_pipeline(ctx: &Arc<Context>, name: &str, bindings: usize) -> ComputePipeline {
    let spirv = synosis::shaders::spirv(name).unwrap_or_else(|| panic!("build.rs compiles {name}"));
    ComputePipeline::new(
        ctx,
        name,
        &spirv,
        &vec![BindingKind::StorageBuffer; bindings],
        0,
        [64, 1, 1],
        &[],
    )
    .unwrap()
}

/// Runs glsl/convert_check.comp over `xs`: per float its conversions (f2u, uint(), the
/// bits of f2i and int()) and its octahedral decode.
fn run_checks(xs: &[f32]) -> (Vec<[u32; 4]>, Vec<[f32; 4]>) {
    let ctx = common::gpu();
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let pipe = check_pipeline(&ctx, "convert_check", 3);
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

/// Runs glsl/edge_check.comp over pairs of vectors: per pair edge_z(a, b) and the same
/// edge through GLSL's atan.
fn run_edges(pairs: &[[f32; 4]]) -> Vec<[f32; 2]> {
    let ctx = common::gpu();
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let pipe = check_pipeline(&ctx, "edge_check", 2);
    let input = Buffer::from_slice(&ctx, "pairs", pairs, storage).unwrap();
    let n = pairs.len() / 2;
    let output = Buffer::new(&ctx, "edges", n as u64 * 8, storage, MemoryKind::Readback).unwrap();
    let mut g = Graph::new(&ctx, "edges");
    let i = g.import(&input);
    let mut o = g.import(&output);
    g.dispatch("edges", &pipe, [(n as u32).div_ceil(64), 1, 1])
        .read(0, &i)
        .write(1, &mut o)
        .submit();
    g.execute(None).unwrap();
    let out = output.read::<[f32; 2]>().unwrap();
    common::assert_clean(&ctx);
    out
}

/// The analytic direct light's closed form sums, per edge of a ring's loops, the angle
/// between two directions times the z of their unit normal (over 2 pi; edge_z, from a
/// rational fit of theta / sin theta). Over 40 000 pairs at angles from 1e-4 rad to pi -
/// 1e-3 and at lengths from 0.01 to 1e8 (world vectors in mm, which a near-mirror lobe's
/// cosine space stretches up to 1e4 times; edge_z's product of the squared lengths stays
/// within f32 up to lengths of about 4e9), against float64 from the same f32 inputs:
/// with the first vector along x, where the inputs' products round once, within 3e-6 of
/// the edge's angle (the fit's own error: 1.5e-6); in every orientation within that plus
/// the f32 rounding of the cross product's terms. A zero vector, parallel and opposite
/// vectors give 0. The atan form it replaced is measured beside it and printed (NIR's
/// atan: a polynomial, 2.1e-5 of short edges' angle).
#[test]
fn polygon_edges_match_float64() {
    use glam::DVec3;
    let mut st = 0x2545_f491_4f6c_dd1d_u64;
    let mut unit = || {
        st ^= st << 13;
        st ^= st >> 7;
        st ^= st << 17;
        (st >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut pairs: Vec<[f32; 4]> = Vec::new();
    let push = |pairs: &mut Vec<[f32; 4]>, a: DVec3, b: DVec3| {
        pairs.push([a.x as f32, a.y as f32, a.z as f32, 0.0]);
        pairs.push([b.x as f32, b.y as f32, b.z as f32, 0.0]);
    };
    let pi = std::f64::consts::PI;
    for k in 0..40_000 {
        let theta = if k % 4 < 2 {
            10f64.powf(-4.0 + 3.7 * unit()) // 1e-4 to 0.5 rad: a ring's short edges
        } else {
            1e-4 + (pi - 1e-3 - 1e-4) * unit()
        };
        let (la, lb) = (
            10f64.powf(-2.0 + 10.0 * unit()),
            10f64.powf(-2.0 + 10.0 * unit()),
        );
        let r = 2.0 * pi * unit();
        let (u, w) = if k % 2 == 0 {
            (DVec3::X, DVec3::new(0.0, r.cos(), r.sin()))
        } else {
            let z = 2.0 * unit() - 1.0;
            let p = 2.0 * pi * unit();
            let u = DVec3::new(
                (1.0 - z * z).sqrt() * p.cos(),
                (1.0 - z * z).sqrt() * p.sin(),
                z,
            );
            let w = u.any_orthonormal_vector();
            (u, w * r.cos() + u.cross(w) * r.sin())
        };
        push(&mut pairs, u * la, (u * theta.cos() + w * theta.sin()) * lb);
    }
    let special = pairs.len() / 2;
    let v = DVec3::new(0.3, -0.5, 0.8);
    push(&mut pairs, DVec3::ZERO, v);
    push(&mut pairs, v, v * 2.0);
    push(&mut pairs, v, -v);
    let out = run_edges(&pairs);
    let eps = f32::EPSILON as f64;
    let (mut fit, mut fit_atan, mut short_atan, mut any) = (0f64, 0f64, 0f64, 0f64);
    for (k, e) in out.iter().take(special).enumerate() {
        let a = glam::Vec4::from(pairs[2 * k]).truncate().as_dvec3();
        let b = glam::Vec4::from(pairs[2 * k + 1]).truncate().as_dvec3();
        let c = a.cross(b);
        let s = c.length();
        let theta = s.atan2(a.dot(b));
        let want = theta * c.z / s / (2.0 * pi);
        let scale = theta / (2.0 * pi);
        let err = (e[0] as f64 - want).abs();
        let err_atan = (e[1] as f64 - want).abs();
        if k % 2 == 0 {
            assert!(
                err < 3e-6 * scale,
                "edge {k}: a {a}, b {b}, angle {theta:e}: edge_z {} against {want:e} ({:e} of the angle)",
                e[0],
                err / scale
            );
            fit = fit.max(err / scale);
            fit_atan = fit_atan.max(err_atan / scale);
            if theta < 0.1 {
                short_atan = short_atan.max(err_atan / scale);
            }
        } else {
            // The cross product's terms, each rounded in f32, then their differences.
            let terms = (a.y * b.z).abs()
                + (a.z * b.y).abs()
                + (a.z * b.x).abs()
                + (a.x * b.z).abs()
                + (a.x * b.y).abs()
                + (a.y * b.x).abs();
            let rounding = 8.0 * eps * terms / (a.length() * b.length())
                * (theta / theta.sin()).max(1.0)
                / (2.0 * pi);
            assert!(
                err < 3e-6 * scale + rounding,
                "edge {k}: a {a}, b {b}, angle {theta:e}: edge_z {} against {want:e} (tolerance {:e})",
                e[0],
                3e-6 * scale + rounding
            );
            any = any.max(err / (3e-6 * scale + rounding));
        }
    }
    eprintln!(
        "{special} edges; along x: edge_z within {fit:.2e} of the angle at most, the atan form {fit_atan:.2e} \
         ({short_atan:.2e} below 0.1 rad); every orientation: {any:.2} of the tolerance at most"
    );
    for (k, e) in out[special..].iter().enumerate() {
        assert_eq!(
            e[0], 0.0,
            "special pair {k} (zero, parallel, opposite): {}",
            e[0]
        );
    }
}
