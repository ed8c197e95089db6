//! `[render] noise_target` on lavapipe, validation on: a render with a noise target
//! stops before its maximum spp at an image equal, byte for byte, to a fixed-spp render
//! of the spp it chose, and the per-pixel variance estimate is honest (within a factor
//! of the measured error against an independent high-spp reference). Tiny images, few
//! bounces: seconds.

mod common;

use synosis::render::noise::{CameraNoise, NoiseEstimator, NoiseStop, RAY_LADDER, RayChoice};
use synosis::render::path_trace::{Frame, FrameOptions, RenderScene, load_object, render_frame};
use synosis::render::sensor::{Responsivity, saturation_electrons};
use synosis::render::settings::SamplerKind;
use synosis::render::{GpuScene, PathTracer, RenderSettings};
use synosis::scene::config::{SceneConfig, SensorConfig};
use synosis::trace::Backend;

/// The test body, face A seen at 20 degrees, test grooves (texture noise), 32 x 24.
fn scene_config(seed: u32, sampler: SamplerKind) -> SceneConfig {
    let mut cfg = SceneConfig::default();
    cfg.set_resolution(32, 24).unwrap();
    cfg.camera.view = "A20".into();
    cfg.texture.kind = "test-grooves".into();
    cfg.material.alpha = 0.02;
    cfg.render.max_bounces = 2;
    cfg.render.batch_spp = 8;
    cfg.render.seed = seed;
    cfg.render.sampler = sampler;
    cfg.validate().unwrap();
    cfg
}

fn stop(scene: &RenderScene, target: f64, min_spp: u32) -> NoiseStop {
    stop_with(scene, target, min_spp, NoiseEstimator::default())
}

fn stop_with(
    scene: &RenderScene,
    target: f64,
    min_spp: u32,
    estimator: NoiseEstimator,
) -> NoiseStop {
    let sensor = SensorConfig::default();
    NoiseStop {
        camera: CameraNoise {
            resp: Responsivity::new(&scene.view.camera, 25.0, 4.0, &sensor),
            sensor,
            exposure_factor: 1.0,
        },
        target,
        min_spp,
        estimator,
        adaptive_radius: None,
        growth: 0.0,
        rays: None,
    }
}

/// The test binary's shared path tracer (software traversal, as on data-centre GPUs,
/// `common::tracer`: pipelines are what costs on lavapipe) and the scene on it.
struct Gpu {
    tracer: std::sync::Arc<PathTracer>,
    gpu_scene: GpuScene,
    scene: RenderScene,
}

impl Gpu {
    fn new(cfg: &SceneConfig) -> Gpu {
        let tracer = common::tracer(Backend::Software);
        let object = load_object(cfg).unwrap();
        let scene = RenderScene::assemble(&object, cfg).unwrap();
        let mut gpu_scene = GpuScene::new(&tracer, &scene.stage, None).unwrap();
        gpu_scene
            .set_face_maps_filtered(
                &tracer,
                &scene.face_maps,
                &scene.placement,
                cfg.render.texture_filter,
            )
            .unwrap();
        Gpu {
            tracer,
            gpu_scene,
            scene,
        }
    }

    fn render(&self, cfg: &SceneConfig, spp: u32, noise: Option<&NoiseStop>) -> Frame {
        self.render_batches(cfg, spp, noise).0
    }

    /// The frame and the samples done after each batch.
    fn render_batches(
        &self,
        cfg: &SceneConfig,
        spp: u32,
        noise: Option<&NoiseStop>,
    ) -> (Frame, Vec<u32>) {
        let mut cfg = cfg.clone();
        cfg.render.spp = spp;
        let opts = FrameOptions {
            annotate_grid: Some(4),
            profiler: None,
            noise,
        };
        let settings = RenderSettings::from(&cfg);
        let mut batches = Vec::new();
        let f = render_frame(
            &self.tracer,
            &self.gpu_scene,
            &self.scene.view,
            &settings,
            opts,
            |done| batches.push(done),
        )
        .expect("render");
        common::assert_clean(self.tracer.context());
        (f, batches)
    }
}

#[test]
fn a_noise_target_stops_early_at_the_image_of_a_fixed_spp_render() {
    let cfg = scene_config(7, SamplerKind::Sobol);
    let gpu = Gpu::new(&cfg);
    let scene = &gpu.scene;
    // Probe: a target never reached runs to the maximum and reports its estimate there.
    let probe = gpu.render(&cfg, 64, Some(&stop(scene, 1e-9, 8)));
    assert_eq!(probe.spp, 64);
    let r64 = probe.noise.expect("estimate").ratio;
    assert!(r64 > 0.0 && r64.is_finite(), "{r64}");
    // A target the 64-spp image meets: the render stops well before 512 spp.
    let target = r64 * 1.05;
    let f = gpu.render(&cfg, 512, Some(&stop(scene, target, 8)));
    let est = f.noise.expect("estimate");
    eprintln!(
        "ratio {r64:.4} at 64 spp; target {target:.4}: stopped at {} spp with {:.4} ({} px, render {:.4} DN, camera {:.4} DN); checks {:?}",
        f.spp,
        est.ratio,
        est.pixels,
        est.render_rms_dn,
        est.camera_rms_dn,
        f.noise_checks
            .iter()
            .map(|c| (c.spp, c.ratio))
            .collect::<Vec<_>>()
    );
    assert!(f.spp >= 8 && f.spp < 512, "{}", f.spp);
    assert_eq!(est.spp, f.spp);
    assert!(est.ratio <= target);
    assert!(est.pixels > 100, "object pixels counted: {}", est.pixels);
    // The same image as a plain render of that many samples (no square sums).
    let fixed = gpu.render(&cfg, f.spp, None);
    assert_eq!(fixed.spp, f.spp);
    assert!(fixed.noise.is_none());
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert!(
        bits(&f.radiance.data) == bits(&fixed.radiance.data),
        "the progressive render differs from the fixed-spp one"
    );
    assert_eq!(f.annotation, fixed.annotation);
    // And the probe's 64-spp image equals a plain 64-spp render too (the square sums
    // change nothing).
    let plain = gpu.render(&cfg, 64, None);
    assert!(bits(&probe.radiance.data) == bits(&plain.radiance.data));
}

/// The shader adds each sample to a pixel's sums in sample order, so an image does not
/// depend on how its samples were split into batches (a first batch cut to end at the
/// first check keeps a stopped image equal to a fixed-spp render); the first check is at
/// `min_spp` itself when the batches are larger (a target met there stops the render at
/// `min_spp`).
#[test]
fn an_image_does_not_depend_on_its_batches_and_the_first_check_is_at_min_spp() {
    let cfg = scene_config(11, SamplerKind::Sobol);
    let gpu = Gpu::new(&cfg);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let with_batch = |batch: u32, spp: u32, noise: Option<&NoiseStop>| {
        let mut c = cfg.clone();
        c.render.batch_spp = batch;
        gpu.render(&c, spp, noise)
    };
    let whole = with_batch(12, 12, None);
    for batch in [1, 4, 5] {
        let f = with_batch(batch, 12, None);
        assert!(
            bits(&f.radiance.data) == bits(&whole.radiance.data),
            "12 spp in batches of {batch} differ from one batch of 12"
        );
        assert_eq!(f.annotation, whole.annotation, "batches of {batch}");
    }
    // With the squared sums of the "samples" estimator too (and its estimate equal).
    let probe = |batch: u32| {
        let s = stop_with(&gpu.scene, 1e-9, 12, NoiseEstimator::Samples);
        with_batch(batch, 12, Some(&s))
    };
    let (a, b) = (probe(12), probe(5));
    assert!(bits(&a.radiance.data) == bits(&b.radiance.data));
    assert_eq!(a.noise, b.noise, "the estimate from batches of 5 and of 12");
    // A first check at 2 with batches of 8: a target the 2-spp image meets stops there,
    // at the image of a 2-spp render.
    let r2 = with_batch(8, 2, Some(&stop(&gpu.scene, 1e-9, 2)))
        .noise
        .expect("estimate")
        .ratio;
    let f = with_batch(8, 64, Some(&stop(&gpu.scene, r2 * 1.01, 2)));
    assert_eq!(f.noise_checks.len(), 1, "{:?}", f.noise_checks);
    assert_eq!(f.spp, 2);
    let fixed = with_batch(8, 2, None);
    assert!(bits(&f.radiance.data) == bits(&fixed.radiance.data));
    // A target it does not meet: the first check at 2, the next ones where predicted, at
    // the end of the batch that reaches them; with "halves" (the default estimate) no
    // batch runs past a power of two: 2, 4, 8, 16, 24, 32, 40.
    let mut c = cfg.clone();
    c.render.batch_spp = 8;
    let (g, ends) = gpu.render_batches(&c, 40, Some(&stop(&gpu.scene, 1e-9, 2)));
    assert_eq!(g.spp, 40);
    assert_eq!(ends, [2, 4, 8, 16, 24, 32, 40]);
    let checks: Vec<u32> = g.noise_checks.iter().map(|c| c.spp).collect();
    assert_eq!(checks[0], 2, "{checks:?}");
    assert!(
        checks.iter().all(|c| ends.contains(c)),
        "{checks:?} {ends:?}"
    );
}

/// `[render] noise_target_growth`: with g = 0.5 the image stops where its noise meets a
/// target growing as sqrt(mean spp / min_spp), so an image whose noise needs many samples
/// to reach the base target stops earlier and noisier than the fixed target would make
/// it, at the criterion it was given; the same with `adaptive_radius` (the shares made
/// for the target predicted at the stop).
#[test]
fn a_growing_target_stops_where_the_noise_meets_it() {
    let cfg = scene_config(7, SamplerKind::Sobol);
    let gpu = Gpu::new(&cfg);
    let scene = &gpu.scene;
    let r64 = gpu
        .render(&cfg, 64, Some(&stop(scene, 1e-9, 8)))
        .noise
        .expect("estimate")
        .ratio;
    // The fixed target that 64 spp meets grown to 64 / 8: the base target is 8^-0.5 of it.
    let base = r64 * 1.05 / 8f64.sqrt();
    let fixed = gpu.render(&cfg, 1024, Some(&stop(scene, base, 8)));
    for adaptive in [None, Some(1)] {
        let s = NoiseStop {
            growth: 0.5,
            adaptive_radius: adaptive,
            ..stop(scene, base, 8)
        };
        let f = gpu.render(&cfg, 1024, Some(&s));
        let est = f.noise.expect("estimate");
        eprintln!(
            "adaptive {adaptive:?}: base target {base:.4}: fixed stop at {} spp ({:.4}); growing: most {} spp, mean {:.2}, ratio {:.4} against {:.4}; checks {:?}",
            fixed.spp,
            fixed.noise.unwrap().ratio,
            f.spp,
            est.mean_spp,
            est.ratio,
            s.target_at(est.mean_spp),
            f.noise_checks
                .iter()
                .map(|c| (c.spp, c.mean_spp, c.ratio))
                .collect::<Vec<_>>()
        );
        assert!(est.ratio <= s.target_at(est.mean_spp), "{est:?}");
        assert!(est.ratio > base, "stopped at the fixed target: {est:?}");
        assert!(
            est.mean_spp < 0.5 * fixed.mean_spp(),
            "{} against the fixed target's {}",
            est.mean_spp,
            fixed.mean_spp()
        );
        // Not before the noise met the grown target: the check before it did not.
        let checks = &f.noise_checks;
        if checks.len() > 1 {
            let c = checks[checks.len() - 2];
            assert!(c.ratio > s.target_at(c.mean_spp), "{checks:?}");
        }
    }
}

/// Measured rms error (DN) of `frame` against `reference` over the pixels the estimate
/// counts (object, not saturated), with the estimate's exposure.
fn measured_rms_dn(stop: &NoiseStop, frame: &Frame, reference: &[f32], t: f64) -> f64 {
    let s = &stop.camera.sensor;
    let full = saturation_electrons(s);
    let face = &frame.annotation.as_ref().unwrap().face;
    let (mut sum, mut n) = (0.0f64, 0usize);
    for (i, (&l, &r)) in frame.radiance.data.iter().zip(reference).enumerate() {
        let e = stop.camera.resp.electrons_per_s[i] * t;
        if face[i] == 0 || l as f64 * e >= full {
            continue;
        }
        sum += (s.gain_dn_per_electron * e * (l as f64 - r as f64)).powi(2);
        n += 1;
    }
    (sum / n as f64).sqrt()
}

/// The estimate against the error measured on an independent high-spp reference: with
/// independent samples both estimators are the error's expectation; with the Sobol
/// sampler the per-sample estimate is conservative by the stratification it does not
/// see, and the halves (the default) see most of it, staying conservative.
#[test]
fn the_noise_estimate_is_within_a_factor_two_of_the_measured_error() {
    let gpu = Gpu::new(&scene_config(11, SamplerKind::Sobol));
    let scene = &gpu.scene;
    let spp = 32;
    let mut sobol_q = Vec::new();
    for sampler in [SamplerKind::Independent, SamplerKind::Sobol] {
        let cfg = scene_config(11, sampler);
        // An independent reference: another seed, 16 x the samples (its own error adds
        // 1/16 to the measured variance).
        let reference = gpu.render(&scene_config(1234, sampler), spp * 16, None);
        for estimator in [NoiseEstimator::Samples, NoiseEstimator::Halves] {
            let s = stop_with(scene, 1e-9, spp, estimator);
            let f = gpu.render(&cfg, spp, Some(&s));
            let est = f.noise.expect("estimate");
            let measured = measured_rms_dn(&s, &f, &reference.radiance.data, est.exposure_s);
            let q = est.render_rms_dn / measured;
            eprintln!(
                "{sampler:?} {spp} spp, {estimator:?}: estimated {:.4} DN, measured {measured:.4} DN (x{q:.3}), camera {:.4} DN",
                est.render_rms_dn, est.camera_rms_dn
            );
            assert!(measured > 0.0);
            match sampler {
                // Independent samples: the estimate is the error's expectation (halves:
                // one degree of freedom a pixel, a few hundred pixels).
                SamplerKind::Independent => assert!((0.6..=1.6).contains(&q), "{q}"),
                // Sobol: conservative (estimated >= measured), not by more than the
                // approximation allows on a textured face.
                SamplerKind::Sobol => {
                    assert!((0.8..=4.0).contains(&q), "{q}");
                    sobol_q.push(q);
                }
            }
        }
    }
    // The halves see the stratification: closer to the measured error.
    assert!(
        sobol_q[1] < 0.85 * sobol_q[0],
        "halves {:.3} against single samples {:.3}",
        sobol_q[1],
        sobol_q[0]
    );
}

/// `[render] adaptive_radius`: each pixel stops when it has its share of the target's
/// samples. Every pixel's value is, bit for bit, that pixel in a fixed-spp render of its
/// own samples (the list dispatch samples the same sample indices), the labels are the
/// fixed render's, the criterion is met, and the error measured against an independent
/// reference is that of the image-wide stop at fewer samples in all.
#[test]
fn adaptive_pixels_each_stop_at_their_own_samples() {
    let cfg = scene_config(7, SamplerKind::Sobol);
    let gpu = Gpu::new(&cfg);
    let scene = &gpu.scene;
    let probe = gpu.render(&cfg, 64, Some(&stop(scene, 1e-9, 8)));
    let target = probe.noise.expect("estimate").ratio * 1.05;
    let whole = gpu.render(&cfg, 512, Some(&stop(scene, target, 8)));
    let adaptive_stop = NoiseStop {
        adaptive_radius: Some(1),
        growth: 0.0,
        ..stop(scene, target, 8)
    };
    let f = gpu.render(&cfg, 512, Some(&adaptive_stop));
    let est = f.noise.expect("estimate");
    let counts = f.pixel_spp.clone().expect("some pixels stopped early");
    eprintln!(
        "target {target:.4}: image-wide stop at {} spp; adaptive: mean {:.2}, most {} spp, ratio {:.4}; checks {:?}",
        whole.spp,
        f.mean_spp(),
        f.spp,
        est.ratio,
        f.noise_checks
            .iter()
            .map(|c| (c.spp, c.mean_spp, c.ratio))
            .collect::<Vec<_>>()
    );
    assert!(est.ratio <= target, "{}", est.ratio);
    assert_eq!(est.spp, f.spp);
    assert!((est.mean_spp - f.mean_spp()).abs() < 1e-9);
    // Each pixel stopped at a check.
    let checks: Vec<u32> = f.noise_checks.iter().map(|c| c.spp).collect();
    assert!(
        counts
            .iter()
            .all(|&c| c >= 8 && c <= f.spp && checks.contains(&c)),
        "{counts:?} {checks:?}"
    );
    assert!(counts.iter().any(|&c| c < f.spp), "{counts:?}");
    assert!(
        f.mean_spp() < whole.spp as f64,
        "adaptive mean {:.2} spp against the image-wide {}",
        f.mean_spp(),
        whole.spp
    );
    // Bit for bit the fixed-spp renders of each pixel's own samples.
    let mut distinct = counts.clone();
    distinct.sort_unstable();
    distinct.dedup();
    for &c in &distinct {
        let fixed = gpu.render(&cfg, c, None);
        let wrong = (0..counts.len())
            .filter(|&i| counts[i] == c)
            .filter(|&i| f.radiance.data[i].to_bits() != fixed.radiance.data[i].to_bits())
            .count();
        assert_eq!(
            wrong, 0,
            "{wrong} pixels of {c} spp differ from the {c}-spp render"
        );
        assert_eq!(f.annotation, fixed.annotation);
    }
    // The error against an independent reference: no worse than the image-wide stop's
    // (within the noise of one image), and no visible mean shift from pixels that stop
    // on a low estimate (the bias the neighbourhood's variance keeps small).
    let reference = gpu.render(&scene_config(1234, SamplerKind::Sobol), 1024, None);
    let r = &reference.radiance.data;
    let m_adaptive = measured_rms_dn(&adaptive_stop, &f, r, est.exposure_s);
    let m_whole = measured_rms_dn(&adaptive_stop, &whole, r, est.exposure_s);
    let face = &f.annotation.as_ref().unwrap().face;
    let object: Vec<usize> = (0..r.len()).filter(|&i| face[i] != 0).collect();
    let mean = |v: &[f32]| object.iter().map(|&i| v[i] as f64).sum::<f64>() / object.len() as f64;
    let shift = mean(&f.radiance.data) / mean(r) - 1.0;
    eprintln!(
        "measured rms error: adaptive {m_adaptive:.4} DN, image-wide {m_whole:.4} DN; object mean {shift:+.5} relative to the reference"
    );
    assert!(m_adaptive <= 1.3 * m_whole, "{m_adaptive} {m_whole}");
    assert!(shift.abs() < 0.01, "{shift}");
}

/// `[render] analytic_rays_max`: the rays chosen at the first check follow what
/// the first samples measured (the most where rays cost nothing, fewer the more they
/// cost, fewer on a flat face, whose closed form varies less over a pixel, than on
/// grooves), and the image stays unbiased (its object's mean as an independent
/// reference's, its error no worse than the render that keeps its rays at equal samples).
#[test]
fn rays_chosen_at_the_first_check_follow_the_spread_and_keep_the_mean() {
    let mut cfg = scene_config(7, SamplerKind::Sobol);
    cfg.render.analytic_rays = 4;
    let gpu = Gpu::new(&cfg);
    let scene = &gpu.scene;
    let with = |cost: f64, target: f64| NoiseStop {
        rays: Some(RayChoice {
            min: 1,
            max: 64,
            cost,
        }),
        ..stop(scene, target, 8)
    };
    // A target never met: the choice by the variance per unit of time.
    let cheap = gpu.render(&cfg, 16, Some(&with(1e-6, 1e-9)));
    let dear = gpu.render(&cfg, 16, Some(&with(100.0, 1e-9)));
    let grooves = gpu.render(&cfg, 16, Some(&with(0.035, 1e-9)));
    let mut flat_cfg = cfg.clone();
    flat_cfg.texture.kind = "flat".into();
    let flat_gpu = Gpu::new(&flat_cfg);
    let flat = flat_gpu.render(
        &flat_cfg,
        16,
        Some(&NoiseStop {
            rays: Some(RayChoice {
                min: 1,
                max: 64,
                cost: 0.035,
            }),
            ..stop(&flat_gpu.scene, 1e-9, 8)
        }),
    );
    let chosen = |f: &Frame| f.analytic_rays_chosen.expect("a choice at the first check");
    eprintln!(
        "rays chosen: cost 1e-6 {}, cost 100 {}, grooves {}, flat {}",
        chosen(&cheap),
        chosen(&dear),
        chosen(&grooves),
        chosen(&flat)
    );
    assert_eq!(chosen(&cheap), 64);
    assert!(RAY_LADDER.contains(&chosen(&grooves)));
    assert!(
        chosen(&dear) < chosen(&cheap) && chosen(&dear) <= chosen(&grooves),
        "cost 100 {} against 1e-6 {} and 0.035 {}",
        chosen(&dear),
        chosen(&cheap),
        chosen(&grooves)
    );
    assert!(
        chosen(&flat) < chosen(&grooves),
        "flat {} grooves {}",
        chosen(&flat),
        chosen(&grooves)
    );
    // Without the setting: no choice.
    assert_eq!(
        gpu.render(&cfg, 16, Some(&stop(scene, 1e-9, 8)))
            .analytic_rays_chosen,
        None
    );
    // Unbiased: 64 samples with the rays changed at 8 (the most, so that the change is
    // large) against an independent 1024-sample reference, beside the same samples with
    // 4 rays throughout.
    let changed = gpu.render(&cfg, 64, Some(&with(1e-6, 1e-9)));
    let kept = gpu.render(&cfg, 64, Some(&stop(scene, 1e-9, 8)));
    assert_eq!(changed.spp, 64);
    let reference = gpu.render(&scene_config(1234, SamplerKind::Sobol), 1024, None);
    let r = &reference.radiance.data;
    let est = kept.noise.expect("estimate");
    let m_changed = measured_rms_dn(&with(1e-6, 1e-9), &changed, r, est.exposure_s);
    let m_kept = measured_rms_dn(&with(1e-6, 1e-9), &kept, r, est.exposure_s);
    let face = &kept.annotation.as_ref().unwrap().face;
    let object: Vec<usize> = (0..r.len()).filter(|&i| face[i] != 0).collect();
    let mean = |v: &[f32]| object.iter().map(|&i| v[i] as f64).sum::<f64>() / object.len() as f64;
    let shift = mean(&changed.radiance.data) / mean(r) - 1.0;
    eprintln!(
        "measured rms error at 64 spp: rays changed to 64 at 8 {m_changed:.4} DN, 4 rays throughout {m_kept:.4} DN; object mean {shift:+.5} relative to the reference"
    );
    assert!(m_changed <= 1.1 * m_kept, "{m_changed} {m_kept}");
    assert!(shift.abs() < 0.01, "{shift}");
}

/// Two scenes on one device showing the same maps read one upload of each map's texels
/// (`render::device_maps`), and render the same image.
#[test]
fn two_scenes_on_one_device_read_the_same_slope_texels() {
    let cfg = scene_config(3, SamplerKind::Sobol);
    let a = Gpu::new(&cfg);
    let mut other = GpuScene::new(&a.tracer, &a.scene.stage, None).unwrap();
    other
        .set_face_maps_filtered(
            &a.tracer,
            &a.scene.face_maps,
            &a.scene.placement,
            cfg.render.texture_filter,
        )
        .unwrap();
    let (ta, tb) = (
        a.gpu_scene.slope_texel_buffers(),
        other.slope_texel_buffers(),
    );
    let shared = ta.iter().zip(&tb).filter(|(x, y)| x == y).count();
    let mut distinct: Vec<_> = a
        .scene
        .face_maps
        .iter()
        .map(|m| std::sync::Arc::as_ptr(&m.slopes))
        .collect();
    distinct.sort();
    distinct.dedup();
    assert!(!distinct.is_empty(), "the scene has face maps");
    assert_eq!(shared, distinct.len(), "{ta:?} / {tb:?}");
    let b = Gpu {
        tracer: a.tracer.clone(),
        gpu_scene: other,
        scene: RenderScene::assemble(&load_object(&cfg).unwrap(), &cfg).unwrap(),
    };
    assert_eq!(
        a.render(&cfg, 2, None).radiance.data,
        b.render(&cfg, 2, None).radiance.data
    );
}
