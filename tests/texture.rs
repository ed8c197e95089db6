//! Reference checks of the texture models (SPEC 1, QUALITY "textures"). Sizes are small
//! so the file runs in well under two minutes in the dev profile.

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use synosis::texture::*;

/// Normalised autocorrelation of a set of 1D profiles at lags `0..=max_lag`.
fn acf(profiles: &[Vec<f32>], max_lag: usize) -> Vec<f64> {
    let mut num = vec![0.0f64; max_lag + 1];
    let mut cnt = vec![0usize; max_lag + 1];
    for p in profiles {
        let m = p.iter().map(|&v| v as f64).sum::<f64>() / p.len() as f64;
        let q: Vec<f64> = p.iter().map(|&v| v as f64 - m).collect();
        for lag in 0..=max_lag.min(q.len() - 1) {
            for i in 0..q.len() - lag {
                num[lag] += q[i] * q[i + lag];
                cnt[lag] += 1;
            }
        }
    }
    let c0 = num[0] / cnt[0] as f64;
    num.iter()
        .zip(&cnt)
        .map(|(&n, &c)| if c > 0 { n / c as f64 / c0 } else { 0.0 })
        .collect()
}

/// Lag of the largest autocorrelation in `[lo, hi]` (pixels).
fn peak(a: &[f64], lo: usize, hi: usize) -> usize {
    (lo..=hi.min(a.len() - 1))
        .max_by(|&x, &y| a[x].total_cmp(&a[y]))
        .unwrap()
}

/// Period (pixels) of the strongest spectral line between `lo` and `hi` pixels, from
/// Hann-windowed profiles, and its power relative to the median power of that band.
/// The spectrum ignores the long-wavelength structure that dominates an acf.
fn spectral_period(profiles: &[Vec<f32>], lo: f64, hi: f64) -> (f64, f64) {
    let steps = 300;
    let power: Vec<(f64, f64)> = (0..=steps)
        .map(|k| {
            let period = lo + (hi - lo) * k as f64 / steps as f64;
            let f = std::f64::consts::TAU / period;
            let mut pw = 0.0;
            for p in profiles {
                let n = p.len();
                let m = p.iter().map(|&v| v as f64).sum::<f64>() / n as f64;
                let (mut re, mut im) = (0.0, 0.0);
                for (i, &v) in p.iter().enumerate() {
                    let w = 0.5 - 0.5 * (std::f64::consts::TAU * i as f64 / n as f64).cos();
                    let q = (v as f64 - m) * w;
                    re += q * (f * i as f64).cos();
                    im += q * (f * i as f64).sin();
                }
                pw += re * re + im * im;
            }
            (period, pw)
        })
        .collect();
    let best = power
        .iter()
        .cloned()
        .fold((0.0, -1.0), |a, b| if b.1 > a.1 { b } else { a });
    let mut sorted: Vec<f64> = power.iter().map(|p| p.1).collect();
    sorted.sort_by(f64::total_cmp);
    (best.0, best.1 / sorted[sorted.len() / 2])
}

fn rows(m: &HeightMap) -> Vec<Vec<f32>> {
    (0..m.height)
        .map(|y| m.data[y * m.width..(y + 1) * m.width].to_vec())
        .collect()
}

fn cols(m: &HeightMap, step: usize) -> Vec<Vec<f32>> {
    (0..m.width)
        .step_by(step)
        .map(|x| (0..m.height).map(|y| m.get(x, y)).collect())
        .collect()
}

fn bilinear(m: &HeightMap, x: f64, y: f64) -> Option<f32> {
    let (fx, fy) = (x - 0.5, y - 0.5);
    if fx < 0.0 || fy < 0.0 || fx >= (m.width - 1) as f64 || fy >= (m.height - 1) as f64 {
        return None;
    }
    let (i, j) = (fx as usize, fy as usize);
    let (u, v) = ((fx - i as f64) as f32, (fy - j as f64) as f32);
    let g = |a, b| m.get(a, b);
    Some(
        g(i, j) * (1.0 - u) * (1.0 - v)
            + g(i + 1, j) * u * (1.0 - v)
            + g(i, j + 1) * (1.0 - u) * v
            + g(i + 1, j + 1) * u * v,
    )
}

#[test]
fn milled_parallel_peaks_at_rho_and_delta() {
    // (d, a_e, delta): path spacing rho = (1 - (1 - a_e - 0.04)) d.
    for (d, ae, delta) in [(2.0, 0.2, 0.09), (3.0, 0.5, 0.07), (2.5, 0.8, 0.11)] {
        let p = MilledParams {
            head_diameter_mm: d,
            radial_depth: ae,
            delta_mm: delta,
            ..Default::default()
        };
        let rho = p.rho_mm();
        // Path-normal direction (y): coarse pixels, several path spacings.
        let s = 10.0;
        let n = ((3.2 * rho * 1000.0 / s) as usize).max(200);
        let m = generate_milled(&p, 160, n, s, 11, &NoProgress).unwrap();
        let rho_px = rho * 1000.0 / s;
        let a = acf(&cols(&m, 4), (1.4 * rho_px) as usize);
        let k = peak(&a, (0.6 * rho_px) as usize, (1.4 * rho_px) as usize);
        assert!(
            (k as f64 - rho_px).abs() <= 0.03 * rho_px + 1.0,
            "d={d} a_e={ae}: acf peak at {k} px, rho = {rho_px:.1} px"
        );
        let lo = (0.5 * rho_px) as usize;
        assert!(
            a[k] > a[lo] + 0.1,
            "d={d} a_e={ae}: rho peak {} not above acf(rho/2) {}",
            a[k],
            a[lo]
        );
        // Along the path (x): fine pixels; the spectrum ignores the long-wavelength
        // ring structure that dominates an autocorrelation.
        let s = 4.0;
        let m = generate_milled(&p, 480, 240, s, 12, &NoProgress).unwrap();
        let dpx = delta * 1000.0 / s;
        let (per, strength) = spectral_period(&rows(&m), 0.6 * dpx, 1.6 * dpx);
        assert!(
            (per - dpx).abs() <= 0.04 * dpx,
            "d={d} delta={delta}: spectral line at {per:.2} px, delta = {dpx:.2} px"
        );
        assert!(
            strength > 5.0,
            "d={d} delta={delta}: line only {strength:.1} x median"
        );
    }
}

#[test]
fn milled_spiral_peaks_at_rho_and_delta() {
    for (d, ae, delta) in [(2.0, 0.2, 0.09), (2.0, 0.5, 0.1)] {
        let p = MilledParams {
            head_diameter_mm: d,
            radial_depth: ae,
            delta_mm: delta,
            path: ToolPath::Spiral,
            ..Default::default()
        };
        let rho = p.rho_mm();
        let s = 8.0;
        let n = 640;
        let m = generate_milled(&p, n, n, s, 5, &NoProgress).unwrap();
        let c = n as f64 / 2.0;
        // Radial profiles from the spiral centre: successive turns are rho apart.
        let rho_px = rho * 1000.0 / s;
        let profiles: Vec<Vec<f32>> = (0..48)
            .map(|k| {
                let t = k as f64 * std::f64::consts::TAU / 48.0;
                (20..(c as usize - 2))
                    .filter_map(|r| bilinear(&m, c + r as f64 * t.cos(), c + r as f64 * t.sin()))
                    .collect()
            })
            .collect();
        let a = acf(&profiles, (1.4 * rho_px) as usize);
        let k = peak(&a, (0.6 * rho_px) as usize, (1.4 * rho_px) as usize);
        assert!(
            (k as f64 - rho_px).abs() <= 0.05 * rho_px + 1.0,
            "spiral d={d} a_e={ae}: radial peak at {k}, rho = {rho_px:.1} px"
        );
        // Along the path: put the spiral centre 20 mm left of a small image, where turns
        // are nearly straight; arcs around the centre then follow the path and ring
        // crossings repeat every delta of arc length (within R / r = 5 %).
        let s = 5.0;
        let (w, h) = (256usize, 400usize);
        let cy = h as f64 * s / 2000.0;
        let far = MilledParams {
            spiral_center_mm: Some([-20.0, cy]),
            ..p.clone()
        };
        let m = generate_milled(&far, w, h, s, 6, &NoProgress).unwrap();
        let dpx = delta * 1000.0 / s;
        let (cxp, cyp) = (-20_000.0 / s, cy * 1000.0 / s);
        let arcs: Vec<Vec<f32>> = (0..16)
            .map(|k| {
                let r = 20_000.0 / s + 10.0 + k as f64 * 14.0;
                let half = (h as f64 / 2.0 - 2.0) / r;
                let steps = (2.0 * half * r) as usize;
                (0..steps)
                    .filter_map(|i| {
                        let t = -half + i as f64 / r;
                        bilinear(&m, cxp + r * t.cos(), cyp + r * t.sin())
                    })
                    .collect()
            })
            .collect();
        let (per, strength) = spectral_period(&arcs, 0.6 * dpx, 1.6 * dpx);
        assert!(
            (per - dpx).abs() <= 0.05 * dpx,
            "spiral delta={delta}: spectral line at {per:.2} px, delta = {dpx:.2} px"
        );
        assert!(
            strength > 5.0,
            "spiral delta={delta}: line only {strength:.1} x median"
        );
    }
}

/// The paper's variation sets must give visibly different instances: the centre jitter
/// (Sigma_c, a standard deviation by the paper's 3-sigma rule) keeps crisp feed marks at
/// delta at the paper's default and blurs them at the set's larger values, while the
/// path spacing rho stays.
#[test]
fn centre_jitter_varies_the_feed_marks_and_keeps_the_path() {
    let strength = |center_noise: f64| {
        let p = MilledParams {
            head_diameter_mm: 2.0,
            radial_depth: 0.5,
            delta_mm: 0.09,
            center_noise,
            ..Default::default()
        };
        let s = 4.0;
        let m = generate_milled(&p, 480, 240, s, 12, &NoProgress).unwrap();
        let dpx = p.delta_mm * 1000.0 / s;
        let line = spectral_period(&rows(&m), 0.6 * dpx, 1.6 * dpx).1;
        // Across the path: the rho peak of the autocorrelation.
        let s = 10.0;
        let rho_px = p.rho_mm() * 1000.0 / s;
        let m = generate_milled(&p, 160, 400, s, 11, &NoProgress).unwrap();
        let a = acf(&cols(&m, 4), (1.4 * rho_px) as usize);
        let k = peak(&a, (0.6 * rho_px) as usize, (1.4 * rho_px) as usize);
        assert!(
            (k as f64 - rho_px).abs() <= 0.03 * rho_px + 1.0,
            "center_noise {center_noise}: rho peak at {k} px, rho = {rho_px:.1} px"
        );
        line
    };
    let s: Vec<f64> = [0.01, 0.2, 0.4, 0.8].iter().map(|&c| strength(c)).collect();
    eprintln!("delta line / band median at center_noise 0.01, 0.2, 0.4, 0.8: {s:.1?}");
    assert!(s[0] > 10.0, "the default shows crisp feed marks: {s:?}");
    assert!(
        s.windows(2).all(|w| w[1] < w[0]),
        "jitter must blur monotonically: {s:?}"
    );
    assert!(s[3] < 0.3 * s[0], "the largest set value blurs them: {s:?}");
}

#[test]
fn milled_is_deterministic_and_moment_matched() {
    let p = MilledParams::default();
    let a = generate_milled(&p, 200, 150, 6.1, 3, &NoProgress).unwrap();
    let b = generate_milled(&p, 200, 150, 6.1, 3, &NoProgress).unwrap();
    let c = generate_milled(&p, 200, 150, 6.1, 4, &NoProgress).unwrap();
    assert_eq!(a, b);
    assert_ne!(a.data, c.data);
    let m = a.moments();
    assert!(m.mean_um.abs() < 1e-3, "mean {}", m.mean_um);
    assert!(
        (m.sq_um - MILLED_DEFAULT_MOMENTS.sq_um).abs() < 1e-3,
        "Sq {}",
        m.sq_um
    );
    assert!(a.data.iter().all(|v| v.is_finite()));
}

fn radial_spectrum(data: &[f32], n: usize, bins: usize) -> Vec<f64> {
    use rustfft::{FftPlanner, num_complex::Complex32};
    let mean = data.iter().map(|&v| v as f64).sum::<f64>() / data.len() as f64;
    let mut z: Vec<Complex32> = data
        .iter()
        .map(|&v| Complex32::new(v - mean as f32, 0.0))
        .collect();
    let mut pl = FftPlanner::new();
    let f = pl.plan_fft_forward(n);
    for r in z.chunks_mut(n) {
        f.process(r);
    }
    let mut t = vec![Complex32::new(0.0, 0.0); n * n];
    for y in 0..n {
        for x in 0..n {
            t[x * n + y] = z[y * n + x];
        }
    }
    for r in t.chunks_mut(n) {
        f.process(r);
    }
    let mut acc = vec![0.0f64; bins];
    let mut cnt = vec![0usize; bins];
    for fy in 0..n {
        for fx in 0..n {
            let (a, b) = (fx.min(n - fx) as f64, fy.min(n - fy) as f64);
            let r = (a * a + b * b).sqrt() / (n as f64 / 2.0);
            let bin = (r * bins as f64) as usize;
            if bin > 0 && bin < bins {
                acc[bin] += t[fx * n + fy].norm_sqr() as f64;
                cnt[bin] += 1;
            }
        }
    }
    acc.iter()
        .zip(&cnt)
        .map(|(&a, &c)| a / c.max(1) as f64)
        .collect()
}

fn stand_in(size: usize, seed: u64) -> HeightMap {
    StandInExemplar {
        size_px: size,
        spacing_um: 4.0,
        grain_size_um: 120.0,
        ..Default::default()
    }
    .generate(seed)
    .unwrap()
}

#[test]
fn adsn_matches_exemplar_moments_and_spectrum() {
    let n = 256;
    let ex = stand_in(n, 1);
    let em = ex.moments();
    let kernel = AdsnKernel::new(&ex, n).unwrap();
    assert_eq!(kernel.size, n);
    let per = periodic_component(&ex.data, n, n);
    let bins = 24;
    let ref_spec = radial_spectrum(&per, n, bins);
    let mut avg = vec![0.0f64; bins];
    let runs = 6;
    for seed in 0..runs / 2 {
        let (a, b) = kernel.realize_pair(&mut Pcg64Mcg::seed_from_u64(seed));
        for r in [a, b] {
            let map = HeightMap {
                width: n,
                height: n,
                spacing_um: 4.0,
                data: r.clone(),
            };
            let m = map.moments();
            // Per realisation: mean within 0.15 Sq, Sq within 15 % (finite-size spread).
            assert!(
                (m.mean_um - em.mean_um).abs() < 0.15 * em.sq_um,
                "mean {m:?} vs {em:?}"
            );
            assert!(
                (m.sq_um / em.sq_um - 1.0).abs() < 0.15,
                "Sq {m:?} vs {em:?}"
            );
            for (acc, v) in avg.iter_mut().zip(radial_spectrum(&r, n, bins)) {
                *acc += v / runs as f64;
            }
        }
    }
    // Radially averaged power spectrum within 25 % of the exemplar's periodic component
    // in every band carrying at least 0.1 % of the peak power.
    let top = ref_spec.iter().cloned().fold(0.0, f64::max);
    for b in 1..bins {
        if ref_spec[b] > 1e-3 * top {
            let ratio = avg[b] / ref_spec[b];
            assert!((0.75..1.33).contains(&ratio), "band {b}: ratio {ratio:.3}");
        }
    }
}

#[test]
fn periodic_component_removes_border_cross() {
    // A ramp has a large jump across the periodic border; its periodic component has none.
    let n = 64;
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    use rand::Rng;
    let u: Vec<f32> = (0..n * n)
        .map(|i| (i % n) as f32 * 0.5 + (i / n) as f32 + rng.random_range(-2.0f32..2.0))
        .collect();
    let p = periodic_component(&u, n, n);
    let jump = |d: &[f32]| {
        (0..n)
            .map(|y| (d[y * n + n - 1] - d[y * n]).abs())
            .sum::<f32>()
            / n as f32
    };
    let step = |d: &[f32]| (0..n).map(|y| (d[y * n + 1] - d[y * n]).abs()).sum::<f32>() / n as f32;
    // Noise steps are ~1.3; the ramp adds a jump of 31.5 across the border.
    assert!(jump(&u) > 10.0 * step(&u));
    assert!(
        jump(&p) < 1.3 * step(&p),
        "jump {} step {}",
        jump(&p),
        step(&p)
    );
}

#[test]
fn sandblasted_has_no_visible_period() {
    let ex = stand_in(256, 2);
    let p = SandblastParams {
        patch_size: 64,
        overlap: 32,
        moments: None,
    };
    let out = generate_sandblasted(&ex, &p, 600, 600, 4.0, 9, &NoProgress).unwrap();
    let em = resample_nearest(&ex, 4.0).unwrap().moments();
    let m = out.moments();
    assert!((m.sq_um - em.sq_um).abs() < 1e-3 * em.sq_um);
    // Kernel domain is 256 px: a tiled single ADSN field would correlate 1.0 there.
    let a_r = acf(&rows(&out), 300);
    let a_c = acf(&cols(&out, 1), 300);
    for lag in [32usize, 64, 128, 256] {
        assert!(a_r[lag].abs() < 0.12, "row acf at {lag}: {}", a_r[lag]);
        assert!(a_c[lag].abs() < 0.12, "col acf at {lag}: {}", a_c[lag]);
    }
    let tail = a_r[40..=300]
        .iter()
        .chain(&a_c[40..=300])
        .fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(tail < 0.12, "secondary acf peak {tail}");
}

#[test]
fn quilting_cut_never_worse_than_straight() {
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    use rand::Rng;
    for trial in 0..40 {
        let (w, h) = (1 + trial % 9, 3 + trial % 17);
        let err: Vec<f32> = (0..w * h).map(|_| rng.random::<f32>().powi(2)).collect();
        let (path, cost) = min_vertical_cut(&err, w, h);
        let path_cost: f64 = path
            .iter()
            .enumerate()
            .map(|(y, &x)| err[y * w + x] as f64)
            .sum();
        assert!((path_cost - cost).abs() < 1e-9 * (1.0 + cost));
        for win in path.windows(2) {
            assert!(win[0].abs_diff(win[1]) <= 1, "path jumps");
        }
        for x in 0..w {
            let straight: f64 = (0..h).map(|y| err[y * w + x] as f64).sum();
            assert!(cost <= straight + 1e-9, "cut {cost} > straight {straight}");
        }
    }
    // Exhaustive optimality on a small grid.
    let (w, h) = (4, 5);
    let err: Vec<f32> = (0..w * h).map(|_| rng.random::<f32>()).collect();
    let (_, cost) = min_vertical_cut(&err, w, h);
    fn best(err: &[f32], w: usize, h: usize, y: usize, x: usize) -> f64 {
        let here = err[y * w + x] as f64;
        if y + 1 == h {
            return here;
        }
        let lo = x.saturating_sub(1);
        let hi = (x + 1).min(w - 1);
        here + (lo..=hi)
            .map(|nx| best(err, w, h, y + 1, nx))
            .fold(f64::INFINITY, f64::min)
    }
    let brute = (0..w)
        .map(|x| best(&err, w, h, 0, x))
        .fold(f64::INFINITY, f64::min);
    assert!((brute - cost).abs() < 1e-9, "dp {cost} brute {brute}");
}

#[test]
fn slopes_of_analytic_fields() {
    let (w, h, s) = (96, 80, 2.5);
    let mut sine = HeightMap::new(w, h, s);
    let (a, b, lx, ly) = (3.0f64, 2.0f64, 64.0 * s, 48.0 * s);
    let mut para = HeightMap::new(w, h, s);
    let (x0, y0, c) = (40.0 * s, 30.0 * s, 1e-3);
    for y in 0..h {
        for x in 0..w {
            let (px, py) = ((x as f64 + 0.5) * s, (y as f64 + 0.5) * s);
            sine.data[y * w + x] = (a * (std::f64::consts::TAU * px / lx).sin()
                + b * (std::f64::consts::TAU * py / ly).cos())
                as f32;
            para.data[y * w + x] = (c * ((px - x0).powi(2) + (py - y0).powi(2))) as f32;
        }
    }
    let ss = sine.slopes();
    let ps = para.slopes();
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let (px, py) = ((x as f64 + 0.5) * s, (y as f64 + 0.5) * s);
            let kx = std::f64::consts::TAU / lx;
            let ky = std::f64::consts::TAU / ly;
            let gx = a * kx * (kx * px).cos();
            let gy = -b * ky * (ky * py).sin();
            let g = ss.data[y * w + x];
            // Central difference error ~ (k s)^2 / 6 relative: < 0.3 % here.
            assert!(
                (g[0] as f64 - gx).abs() < 5e-3 * a * kx + 1e-6,
                "sine dx at {x},{y}"
            );
            assert!(
                (g[1] as f64 - gy).abs() < 5e-3 * b * ky + 1e-6,
                "sine dy at {x},{y}"
            );
            // Central differences are exact on a paraboloid (f32 rounding only).
            let g = ps.data[y * w + x];
            assert!(
                (g[0] as f64 - 2.0 * c * (px - x0)).abs() < 1e-4,
                "para dx at {x},{y}"
            );
            assert!(
                (g[1] as f64 - 2.0 * c * (py - y0)).abs() < 1e-4,
                "para dy at {x},{y}"
            );
            let n = ps.normal(x, y);
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-5);
            assert!((n[0] / n[2] + g[0]).abs() < 1e-5 && (n[1] / n[2] + g[1]).abs() < 1e-5);
        }
    }
}

fn err_text(r: Result<HeightMap>) -> String {
    match r {
        Ok(_) => panic!("expected an error"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_parameters_name_the_field() {
    let base = MilledParams::default();
    let mk = |p: MilledParams| err_text(generate_milled(&p, 32, 32, 6.1, 0, &NoProgress));
    let e = mk(MilledParams {
        radial_depth: 1.2,
        ..base.clone()
    });
    assert!(e.contains("radial_depth") && e.contains("(0, 1)"), "{e}");
    let e = mk(MilledParams {
        radial_depth: 0.0,
        ..base.clone()
    });
    assert!(e.contains("radial_depth"), "{e}");
    let e = mk(MilledParams {
        gamma: 0.6,
        ..base.clone()
    });
    assert!(e.contains("gamma") && e.contains("alpha"), "{e}");
    let e = mk(MilledParams {
        w_minus_mean_mm: -0.1,
        ..base.clone()
    });
    assert!(e.contains("w_minus_mean_mm"), "{e}");
    let e = mk(MilledParams {
        w_outer_mean_mm: -0.1,
        ..base.clone()
    });
    assert!(e.contains("w_outer_mean_mm"), "{e}");
    let e = mk(MilledParams {
        delta_mm: f64::NAN,
        ..base.clone()
    });
    assert!(e.contains("delta_mm"), "{e}");
    let e = mk(MilledParams {
        spiral_center_mm: Some([1e6, 0.0]),
        path: ToolPath::Spiral,
        ..base.clone()
    });
    assert!(e.contains("spiral_center_mm"), "{e}");
    let e = err_text(generate_milled(
        &MilledParams {
            delta_mm: 1e-6,
            ..base.clone()
        },
        1000,
        1000,
        6.1,
        0,
        &NoProgress,
    ));
    assert!(e.contains("delta_mm") && e.contains("20 million"), "{e}");
    let e = mk(MilledParams {
        b_max: 0.05,
        ..base.clone()
    });
    assert!(e.contains("b_max"), "{e}");
    let e = err_text(generate_milled(&base, 32, 32, 0.0, 0, &NoProgress));
    assert!(e.contains("spacing_um") && e.contains("> 0"), "{e}");
    let e = err_text(generate_milled(&base, 0, 32, 6.1, 0, &NoProgress));
    assert!(e.contains("width"), "{e}");

    let flat = HeightMap {
        width: 64,
        height: 64,
        spacing_um: 2.0,
        data: vec![1.5; 64 * 64],
    };
    let sp = SandblastParams::default();
    let e = err_text(generate_sandblasted(
        &flat,
        &sp,
        64,
        64,
        6.1,
        0,
        &NoProgress,
    ));
    assert!(e.contains("constant"), "{e}");
    let ex = stand_in(64, 0);
    let e = err_text(generate_sandblasted(&ex, &sp, 64, 64, 1.0, 0, &NoProgress));
    assert!(e.contains("spacing_um"), "{e}");
    let bad = SandblastParams {
        overlap: 300,
        ..sp.clone()
    };
    let e = err_text(generate_sandblasted(&ex, &bad, 64, 64, 6.1, 0, &NoProgress));
    assert!(e.contains("overlap"), "{e}");
    let e = StandInExemplar {
        pressure_bar: -1.0,
        ..Default::default()
    }
    .generate(0)
    .map(|_| ())
    .unwrap_err()
    .to_string();
    assert!(e.contains("pressure_bar"), "{e}");

    let e = toml::from_str::<MilledParams>("head_diameter = 4.0")
        .unwrap_err()
        .to_string();
    assert!(e.contains("head_diameter"), "{e}");

    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.xyz");
    let e = err_text(read_xyz(&missing, XyzUnit::M));
    assert!(e.contains("nope.xyz"), "{e}");
    let garbage = dir.path().join("bad.xyz");
    std::fs::write(&garbage, "# header\n0 0 1\n0 1e-6 x\n").unwrap();
    let e = err_text(read_xyz(&garbage, XyzUnit::M));
    assert!(e.contains(":3:"), "{e}");
}

#[test]
fn xyz_and_exr_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (7usize, 5usize);
    let mut text = String::from("Alicona export\nx y z\n");
    for y in 0..h {
        for x in 0..w {
            if (x, y) == (3, 2) {
                continue; // an invalid point the instrument dropped
            }
            let z = (x * 10 + y) as f64 * 1e-6;
            text += &format!(
                "{:e} {:e} {:e}\n",
                x as f64 * 1.75e-6,
                y as f64 * 1.75e-6,
                z
            );
        }
    }
    let path = dir.path().join("m.xyz");
    std::fs::write(&path, text).unwrap();
    let m = read_xyz(&path, XyzUnit::M).unwrap();
    assert_eq!((m.width, m.height), (w, h));
    assert!((m.spacing_um - 1.75).abs() < 1e-6);
    assert!((m.get(4, 3) - 43.0).abs() < 1e-3);
    let valid_mean = m
        .data
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != 2 * w + 3)
        .map(|(_, &v)| v as f64)
        .sum::<f64>()
        / (w * h - 1) as f64;
    assert!((m.get(3, 2) as f64 - valid_mean).abs() < 1e-3);

    let exr = dir.path().join("h.exr");
    write_exr_height(&m, &exr).unwrap();
    let back = read_exr(&exr, 1.75).unwrap();
    assert_eq!(back.data, m.data);

    // The streamed 16-bit normal PNG decodes to the slope map's normals.
    let png = dir.path().join("n.png");
    write_normal_png16(&m, &png).unwrap();
    let img = image::open(&png).unwrap().into_rgb16();
    let slopes = m.slopes();
    for y in 0..h {
        for x in 0..w {
            let n = slopes.normal(x, y);
            let px = img.get_pixel(x as u32, y as u32).0;
            for c in 0..3 {
                let v = px[c] as f32 / 65535.0 * 2.0 - 1.0;
                assert!(
                    (v - n[c]).abs() < 1e-4,
                    "normal {c} at {x},{y}: {v} vs {}",
                    n[c]
                );
            }
        }
    }
}

#[test]
fn cli_writes_all_files_or_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.exr");
    let bin = env!("CARGO_BIN_EXE_synosis");
    let ok = std::process::Command::new(bin)
        .args([
            "texture",
            "milled",
            "--size",
            "96",
            "--spacing-um",
            "20",
            "--seed",
            "1",
        ])
        .args([
            "--head-diameter-mm",
            "2",
            "--radial-depth",
            "0.5",
            "--path",
            "spiral",
        ])
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    for f in ["t.exr", "t.normal.png", "t.preview.png"] {
        assert!(dir.path().join(f).is_file(), "{f} missing");
    }
    let normal = image::open(dir.path().join("t.normal.png")).unwrap();
    assert_eq!(normal.color(), image::ColorType::Rgb16);

    let out2 = dir.path().join("u.exr");
    let params = dir.path().join("p.toml");
    std::fs::write(&params, "[milled]\ngamma = 0.9\n").unwrap();
    let bad = std::process::Command::new(bin)
        .args(["texture", "milled", "--size", "64"])
        .arg("--params")
        .arg(&params)
        .arg("--out")
        .arg(&out2)
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("gamma"));
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('u') || n.contains("tmp"))
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
}

#[test]
fn spiral_exit_line_only_touches_its_strip() {
    let base = MilledParams {
        head_diameter_mm: 1.0,
        path: ToolPath::Spiral,
        spiral_outward: false,
        ..Default::default()
    };
    let (n, s) = (200usize, 20.0);
    let a = generate_milled(&base, n, n, s, 2, &NoProgress).unwrap();
    let line = MilledParams {
        spiral_exit_line: true,
        spiral_exit_angle_deg: 0.0,
        ..base
    };
    let b = generate_milled(&line, n, n, s, 2, &NoProgress).unwrap();
    // The line runs right from the centre along y = centre; its rings (diameter 1 mm)
    // reach 0.5 mm + band widths from it. Moment matching is affine per map, so compare
    // correlations: far from the strip the maps agree up to that affine map.
    let corr = |keep: &dyn Fn(usize, usize) -> bool| {
        let (mut xs, mut ys) = (Vec::new(), Vec::new());
        for y in 0..n {
            for x in 0..n {
                if keep(x, y) {
                    xs.push(a.get(x, y) as f64);
                    ys.push(b.get(x, y) as f64);
                }
            }
        }
        let m = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let (mx, my) = (m(&xs), m(&ys));
        let cov: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
        let vx: f64 = xs.iter().map(|x| (x - mx).powi(2)).sum();
        let vy: f64 = ys.iter().map(|y| (y - my).powi(2)).sum();
        cov / (vx * vy).sqrt()
    };
    let c = n as f64 / 2.0;
    // Distance (mm) to the ray from the centre towards +x.
    let dist_mm = |x: usize, y: usize| {
        let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
        let dx = if px < c { px - c } else { 0.0 };
        (dx * dx + (py - c).powi(2)).sqrt() * s / 1000.0
    };
    let far = corr(&|x, y| dist_mm(x, y) > 0.9);
    let near = corr(&|x, y| dist_mm(x, y) < 0.3 && x > n / 2 + 10);
    assert!(
        far > 0.9999,
        "far from the exit line the maps differ: corr {far}"
    );
    assert!(near < 0.9, "the exit line left no mark: corr {near}");
}
