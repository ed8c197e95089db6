//! Timing of the metrics at the paper's image size (1224 x 1025):
//! SSIM on one pair, and the closest-sample search of `compare` on one viewpoint's worth
//! of random in-memory images, extrapolated to the full sets.
//!
//! cargo run --release --example bench_metrics
//! Env: BENCH_REAL (real images per viewpoint, default 30), BENCH_SYNTH (synthetic per
//! viewpoint, default 120; the paper has 600). With LPIPS's weights where synosis finds
//! them (tools/lpips-weights), also LPIPS: one image's features, one masked pair's
//! distance, and what `compare --lpips` adds at the paper's scale.

use std::time::Instant;

use rand::{Rng, SeedableRng, rngs::StdRng};
use rayon::prelude::*;
use synosis::metrics::{self, Alignment, GrayImage, Histogram, Mask, Ssim};

const W: usize = 1224;
const H: usize = 1025;

fn random_image(seed: u64) -> GrayImage {
    let mut rng = StdRng::seed_from_u64(seed);
    let data = (0..W * H)
        .map(|_| f32::from(rng.random_range(0u8..=255)))
        .collect();
    GrayImage::new(W, H, data).unwrap()
}

fn env(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Process CPU seconds (user + system) from /proc, assuming the usual 100 ticks/s: other
/// jobs on the machine inflate wall time, not this.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    // utime and stime are fields 14 and 15; after the ')' (field 2) they sit at 11 and 12.
    let tick = |k: usize| {
        f.get(k)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    (tick(11) + tick(12)) / 100.0
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    println!("threads: {}, image {W} x {H}", rayon::current_num_threads());
    let a = random_image(1);
    let b = random_image(2);
    let ssim = Ssim::default();

    let cpu0 = cpu_seconds();
    let mut t = Vec::new();
    for _ in 0..15 {
        let s = Instant::now();
        std::hint::black_box(ssim.mean(&a, &b).unwrap());
        t.push(s.elapsed().as_secs_f64());
    }
    println!(
        "SSIM mean, full image:            median {:7.2} ms wall (15 runs), {:.1} ms CPU per run",
        median(t) * 1e3,
        (cpu_seconds() - cpu0) / 15.0 * 1e3
    );

    let mut t = Vec::new();
    for _ in 0..7 {
        let s = Instant::now();
        std::hint::black_box(metrics::pair_metrics(&a, &b, None).unwrap());
        t.push(s.elapsed().as_secs_f64());
    }
    println!(
        "pair_metrics (WD+MAE+SSIM), full: median {:7.2} ms (7 runs)",
        median(t) * 1e3
    );

    // Meta-mask: a centred ellipse over ~half of the frame, like an observed face.
    let mut mask = Mask::filled(W, H, false);
    for y in 0..H {
        for x in 0..W {
            let (dx, dy) = ((x as f64 - 612.0) / 480.0, (y as f64 - 512.0) / 420.0);
            mask.data[y * W + x] = dx * dx + dy * dy <= 1.0;
        }
    }
    let ix = mask.indices();
    let rect = mask.bbox().unwrap();
    println!(
        "meta-mask: {} px ({:.0} % of the frame)",
        ix.len(),
        100.0 * ix.len() as f64 / (W * H) as f64
    );

    let n_real = env("BENCH_REAL", 30);
    let n_synth = env("BENCH_SYNTH", 120);
    let align = Alignment {
        factor: 0.632,
        bias: 34.0,
    };

    let s = Instant::now();
    let reals: Vec<_> = (0..n_real)
        .into_par_iter()
        .map(|i| {
            let img = random_image(100 + i as u64);
            let prep = ssim.prepare(&img, rect);
            let hist = Histogram::of(&img, Some(&ix));
            (img, prep, hist)
        })
        .collect();
    let t_real = s.elapsed().as_secs_f64();

    let cpu0 = cpu_seconds();
    let s = Instant::now();
    let (best_sum, pairs) = (0..n_synth)
        .into_par_iter()
        .map(|j| {
            let img = random_image(10_000 + j as u64).aligned(align);
            let prep = ssim.prepare(&img, rect);
            let hist = Histogram::of(&img, Some(&ix));
            let mut acc = 0.0;
            for (ri, rp, rh) in &reals {
                // As compare does: MAE and SSIM on the mask's pixels in one pass.
                let (ss, m) = ssim.mean_and_mae_prepared(ri, rp, &img, &prep, Some(&mask));
                acc += rh.wasserstein(&hist) + m + ss;
            }
            (acc, reals.len())
        })
        .reduce(|| (0.0, 0), |x, y| (x.0 + y.0, x.1 + y.1));
    let t_search = s.elapsed().as_secs_f64();
    let cpu_pair = (cpu_seconds() - cpu0) / pairs.max(1) as f64;
    println!("search CPU time: {:.2} ms per pair", cpu_pair * 1e3);
    std::hint::black_box(best_sum);
    let per_pair = t_search / pairs as f64;
    println!(
        "closest-sample search: {n_real} real prepared in {t_real:.2} s; {n_synth} synthetic x {n_real} real = {pairs} pairs in {t_search:.2} s ({:.2} ms/pair wall, incl. synthetic generation+prep)",
        per_pair * 1e3
    );
    println!(
        "extrapolated: per-viewpoint matching as compare does (9 viewpoints x 600 synth x 30 real = 162000 pairs): {:.1} min",
        162_000.0 * per_pair / 60.0
    );
    println!(
        "extrapolated: every pair 5400 x 270 = 1458000 pairs: {:.1} min",
        1_458_000.0 * per_pair / 60.0
    );
    println!(
        "from CPU time on {} free cores: 162000 pairs {:.1} min, 1458000 pairs {:.1} min",
        rayon::current_num_threads(),
        162_000.0 * cpu_pair / rayon::current_num_threads() as f64 / 60.0,
        1_458_000.0 * cpu_pair / rayon::current_num_threads() as f64 / 60.0
    );

    lpips(&mask);
}

/// LPIPS's two parts as `compare --lpips` uses them: features once per image, a masked
/// distance per pair.
fn lpips(mask: &Mask) {
    let net = match metrics::Lpips::load(None) {
        Ok(net) => net,
        Err(e) => {
            println!("LPIPS not timed: {e}");
            return;
        }
    };
    let a = random_image(1);
    let b = random_image(2);
    let cpu0 = cpu_seconds();
    let mut t = Vec::new();
    let mut feats = Vec::new();
    for img in [&a, &b, &a, &b, &a] {
        let s = Instant::now();
        feats.push(net.features(img, Some(mask)).unwrap());
        t.push(s.elapsed().as_secs_f64());
    }
    let t_feat = median(t);
    println!(
        "LPIPS features, one image: median {:.3} s wall (5 runs), {:.3} s CPU per run",
        t_feat,
        (cpu_seconds() - cpu0) / 5.0
    );
    let mut t = Vec::new();
    for _ in 0..15 {
        let s = Instant::now();
        std::hint::black_box(net.distance(&feats[0], &feats[1]).unwrap());
        t.push(s.elapsed().as_secs_f64());
    }
    let t_dist = median(t);
    println!(
        "LPIPS distance, one masked pair: median {:.2} ms wall (15 runs)",
        t_dist * 1e3
    );
    println!(
        "extrapolated: compare --lpips adds, at the paper's scale (5400 synthetic + 270 real images' features, 162000 pairs): {:.1} + {:.1} min",
        5670.0 * t_feat / 60.0,
        162_000.0 * t_dist / 60.0
    );
}
