//! CPU time of one noise check at the paper's image size (1224 x 1025): the estimate
//! (`CameraNoise::estimate`) and, for `[render] adaptive_radius`, each pixel's samples
//! (`CameraNoise::pixel_samples_wanted`) and the list of pixels still sampling, as
//! `render::path_trace::render_frame` makes them between batches (issue 15: on one H100
//! the renderers' checks were much of the render threads' time).
//!
//! The sums are synthetic but shaped like a paper frame's: the object over about half
//! the image, its radiance smooth with a few percent of bright, noisy (glint) pixels,
//! "halves" sums of 4 samples a pixel; then a second check at 8 samples with a third of
//! the pixels stopped at 4.
//!
//! cargo run --release --example bench_noise_check
//! Env: BENCH_REPEAT (checks timed, default 20). The checks run on `on_render_pool`, as a
//! render's do: a thread per core, at most 8.

use std::time::Instant;

use rand::{Rng, SeedableRng, rngs::StdRng};
use synosis::render::cpu::on_render_pool;
use synosis::render::noise::{CameraNoise, NoiseEstimator, PixelSamples};
use synosis::render::sensor::Responsivity;
use synosis::render::view::tile_order;
use synosis::scene::config::SensorConfig;

/// A check to time: its name, the sums, the samples so far, the pixels still sampling.
type Check<'a> = (&'a str, &'a [f32], &'a [f32], PixelSamples<'a>, &'a [u32]);

const W: usize = 1224;
const H: usize = 1025;

/// Sums of `n` samples a pixel ("halves": radiance, and the even and odd levels' sums).
fn sums(n: u32, object: &[bool], seed: u64) -> (Vec<f32>, Vec<f32>) {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut sum = vec![0.0f32; W * H];
    let mut noise = vec![0.0f32; 2 * W * H];
    for i in 0..W * H {
        let (x, y) = ((i % W) as f32 / W as f32, (i / W) as f32 / H as f32);
        let (mean, spread) = if object[i] {
            let glint = rng.random::<f32>() < 0.03;
            let m = 0.05 + 0.4 * (6.0 * x).sin().abs() * (4.0 * y).cos().abs();
            if glint { (m * 8.0, 3.0) } else { (m, 0.4) }
        } else {
            (0.002, 0.1)
        };
        let mut levels = [0.0f32; 2];
        for s in 0..n {
            let v = (mean * (1.0 + spread * (rng.random::<f32>() - 0.5) * 3.4)).max(0.0);
            sum[i] += v;
            // Level of sample index s: 0 for index 0, log2(s) + 1 otherwise.
            let level = if s == 0 { 0 } else { 32 - s.leading_zeros() };
            if s == 0 || s.is_power_of_two() {
                levels[(level & 1) as usize] = 0.0; // a new level starts
            }
            levels[(level & 1) as usize] += v;
        }
        noise[2 * i] = levels[0];
        noise[2 * i + 1] = levels[1];
    }
    (sum, noise)
}

fn main() {
    let repeat: usize = std::env::var("BENCH_REPEAT")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20);
    let object: Vec<bool> = (0..W * H)
        .map(|i| {
            let (x, y) = (
                (i % W) as f64 / W as f64 - 0.5,
                (i / W) as f64 / H as f64 - 0.5,
            );
            (x / 0.4).powi(2) + (y / 0.35).powi(2) < 1.0
        })
        .collect();
    let exposure: Vec<bool> = object.clone();
    let camera = CameraNoise {
        resp: Responsivity {
            width: W as u32,
            height: H as u32,
            electrons_per_s: (0..W * H)
                .map(|i| 2.0e6 * (1.0 - 1e-7 * i as f64))
                .collect(),
        },
        sensor: SensorConfig::default(),
        exposure_factor: 1.0,
    };
    let est = NoiseEstimator::Halves;
    let (target, radius) = (10.0, 4u32);
    // Check 1 at 4 samples, every pixel; check 2 at 8 with a third stopped at 4.
    let (s4, n4) = sums(4, &object, 1);
    let (s8, n8) = sums(8, &object, 2);
    let counts: Vec<u32> = (0..W * H).map(|i| if i % 3 == 0 { 4 } else { 8 }).collect();
    let order = tile_order(W as u32, H as u32);
    let sampling: Vec<u32> = order
        .iter()
        .copied()
        .filter(|&i| counts[i as usize] == 8)
        .collect();
    println!(
        "noise check at {W} x {H}, {} threads on the render threads' pool, {repeat} repeats",
        on_render_pool(rayon::current_num_threads)
    );
    println!();
    println!(
        "| check | estimate, ms | samples wanted, ms | pixel list, ms | total, ms | pixels kept |"
    );
    println!("|---|---:|---:|---:|---:|---:|");
    let checks: [Check; 2] = [
        ("4 spp, every pixel", &s4, &n4, PixelSamples::All(4), &order),
        (
            "8 spp, a third stopped at 4",
            &s8,
            &n8,
            PixelSamples::Each(&counts),
            &sampling,
        ),
    ];
    for (name, sum, noise, n, list) in checks {
        let (mut t_est, mut t_want, mut t_list, mut kept) = (0.0, 0.0, 0.0, 0);
        for _ in 0..repeat {
            let t = Instant::now();
            let (_, image) =
                on_render_pool(|| camera.estimate(est, sum, noise, n, &exposure, &object))
                    .expect("the estimate");
            t_est += t.elapsed().as_secs_f64();
            let t = Instant::now();
            let want = on_render_pool(|| {
                camera.pixel_samples_wanted(
                    est, sum, noise, n, &image, &object, W, target, None, radius,
                )
            });
            t_want += t.elapsed().as_secs_f64();
            let t = Instant::now();
            let done = n.most() as f64;
            let (keep, _stop): (Vec<u32>, Vec<u32>) =
                list.iter().partition(|&&i| want[i as usize] > done);
            t_list += t.elapsed().as_secs_f64();
            kept = keep.len();
        }
        let ms = |s: f64| 1e3 * s / repeat as f64;
        println!(
            "| {name} | {:.1} | {:.1} | {:.1} | {:.1} | {kept} |",
            ms(t_est),
            ms(t_want),
            ms(t_list),
            ms(t_est + t_want + t_list)
        );
    }
}
