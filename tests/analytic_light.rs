//! The analytic direct light (`[render] direct_light = "analytic"`): a control variate
//! must not change what is computed. Over many seeds its mean equals the sampled
//! estimator's within statistical error (the whole image and each quarter, on a plane
//! partly shadowed from the ring by an occluder; both backends on a glossy conductor, the
//! software one also on a rough one; and among other lights: a panel hiding part of the
//! ring from half of the plane and a dome around everything), and it lowers the variance.

mod common;

use glam::Vec3;
use synosis::scene::Mesh;
use synosis::scene::config::{DirectLight, LookAt, SceneConfig};
use synosis::scene::lights::LightEntry;
use synosis::trace::Backend;

/// A 30 x 30 mm plane at z = 10 with a quad 3 mm above it: it hides part of the plane
/// from the camera and shadows part of the ring light for the plane around it.
fn scene_mesh() -> Mesh {
    common::labelled_plane(
        30.0,
        10.0,
        &[],
        [
            Vec3::new(2.0, -14.0, 13.0),
            Vec3::new(14.0, -14.0, 13.0),
            Vec3::new(14.0, 2.0, 13.0),
            Vec3::new(2.0, 2.0, 13.0),
        ],
    )
}

const W: u32 = 32;
const H: u32 = 24;

fn config(alpha: f32, direct: DirectLight, seed: u32, spp: u32) -> SceneConfig {
    let mut cfg = SceneConfig::default();
    cfg.camera.view = "A0".into();
    cfg.set_resolution(W, H).expect("size");
    cfg.material.alpha = alpha;
    cfg.render.spp = spp;
    cfg.render.batch_spp = spp;
    cfg.render.max_bounces = 3;
    cfg.render.seed = seed;
    cfg.render.direct_light = direct;
    cfg.validate().expect("valid");
    cfg
}

/// `config` under three lights, the camera straight above the plane: the ring on the
/// camera, a 10 mm panel facing down at height 60 and `panel_x` mm off the axis, and a
/// dome around everything (beyond the ring seen from anywhere on the plane). At x = 30
/// the panel stands near the ring's bounding cone seen from the plane's +x half (the
/// control variate leaves the ring to the sampled estimator there) and clear of it from
/// the -x half; at x = 22 it hides the +x side of the ring, where the plane's +x half
/// sees the ring's reflection, from there (rays to the ring meet the panel first: a
/// control variate that used the ring there would be biased).
fn among_other_lights(mut cfg: SceneConfig, panel_x: f64) -> SceneConfig {
    let panel = format!(
        "kind = \"panel\"\nposition_mm = [{panel_x}, 0, 60]\ndirection = [0, 0, -1]\nsize_mm = [10, 10]"
    );
    let entries = [
        "kind = \"ring\"",
        &panel,
        "kind = \"dome\"\nradius_mm = 300\nradiance = 0.2",
    ];
    cfg.light.list = Some(
        entries
            .iter()
            .map(|t| toml::from_str::<LightEntry>(t).expect("light entry"))
            .collect(),
    );
    cfg.camera.look_at = Some(LookAt {
        eye: [0.0, 0.0, 100.0],
        target: [0.0, 0.0, 10.0],
        up: [0.0, 1.0, 0.0],
    });
    cfg.validate().expect("valid");
    cfg
}

/// One device, path tracer and GPU scene per backend for every render of the test.
struct Renderer(common::SceneRenderer);

impl Renderer {
    fn new(backend: Backend) -> Renderer {
        let cfg = config(0.15, DirectLight::Sampled, 0, 4);
        Renderer(common::SceneRenderer::new(backend, scene_mesh(), &cfg))
    }

    fn radiance(&self, cfg: &SceneConfig) -> Vec<f64> {
        let f = self.0.render(cfg, false);
        f.radiance.data.iter().map(|&v| v as f64).collect()
    }
}

/// Mean and standard error of the mean of `x`.
fn mean_se(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// Per seed: the mean over the whole image and over each quarter; and the mean over
/// pixels of the per-pixel variance across seeds.
fn statistics(images: &[Vec<f64>]) -> (Vec<Vec<f64>>, f64) {
    let mut areas = vec![Vec::new(); 5];
    for img in images {
        let mut sums = [0.0; 5];
        let mut counts = [0.0; 5];
        for (i, v) in img.iter().enumerate() {
            let (x, y) = (i as u32 % W, i as u32 / W);
            let q = 1 + (x >= W / 2) as usize + 2 * (y >= H / 2) as usize;
            for k in [0, q] {
                sums[k] += v;
                counts[k] += 1.0;
            }
        }
        for k in 0..5 {
            areas[k].push(sums[k] / counts[k]);
        }
    }
    (areas, pixel_variance(images))
}

/// The mean over pixels of each pixel's variance across `images` (one per seed).
fn pixel_variance(images: &[Vec<f64>]) -> f64 {
    let n = images.len() as f64;
    let px = images[0].len();
    (0..px)
        .map(|i| {
            let m = images.iter().map(|img| img[i]).sum::<f64>() / n;
            images.iter().map(|img| (img[i] - m).powi(2)).sum::<f64>() / (n - 1.0)
        })
        .sum::<f64>()
        / px as f64
}

/// Estimator B's means over seeds (per area, `statistics`) equal estimator A's within 4
/// standard errors, and B's pixel variance is at least `gain` times lower; `labels`: the
/// names of A and B ("sampled" and "analytic": the control variate against the sampled
/// estimator).
fn same_mean_less_variance(
    name: &str,
    labels: [&str; 2],
    (sampled, var_s): (&[Vec<f64>], f64),
    (analytic, var_a): (&[Vec<f64>], f64),
    gain: f64,
) {
    let [la, lb] = labels;
    for (k, (s, a)) in sampled.iter().zip(analytic).enumerate() {
        let ((ms, es), (ma, ea)) = (mean_se(s), mean_se(a));
        let z = (ma - ms) / (es * es + ea * ea).sqrt();
        eprintln!(
            "{name}, area {k}: {la} {ms:.6} +- {es:.1e}, {lb} {ma:.6} +- {ea:.1e}, z {z:+.2}"
        );
        assert!(ms > 0.0 && ma > 0.0, "{name}: a dark image tests nothing");
        assert!(
            z.abs() < 4.0,
            "{name}, area {k}: the means differ by {z:.1} standard errors"
        );
    }
    eprintln!(
        "{name}: pixel variance {la} {var_s:.3e}, {lb} {var_a:.3e} ({:.1}x)",
        var_s / var_a
    );
    assert!(
        var_a * gain <= var_s,
        "{name}: {lb} must lower the variance ({var_s:.3e} -> {var_a:.3e})"
    );
}

/// [`same_mean_less_variance`] of the sampled and the analytic direct light, each
/// estimator's seeds rendered by `run` (the sampled one first) and taken through
/// [`statistics`].
fn sampled_against_analytic(name: &str, run: impl Fn(DirectLight) -> Vec<Vec<f64>>, gain: f64) {
    let (sampled, var_s) = statistics(&run(DirectLight::Sampled));
    let (analytic, var_a) = statistics(&run(DirectLight::Analytic));
    same_mean_less_variance(
        name,
        ["sampled", "analytic"],
        (&sampled, var_s),
        (&analytic, var_a),
        gain,
    );
}

#[test]
fn the_analytic_direct_light_is_unbiased_and_lowers_the_variance() {
    const SEEDS: u32 = 10;
    const SPP: u32 = 16;
    // Both backends on the glossy conductor (the BSDF sample's light-only trace differs
    // between them), the software one also on a rough conductor (wider lobe: clipped
    // band quads, a weaker fit).
    // (backend, alphas, the panel's x among other lights or the ring alone, the least
    // variance reduction required).
    for (backend, alphas, panel_x, gain) in [
        (Backend::RayQuery, &[0.15][..], None, 2.0),
        (Backend::Software, &[0.15, 0.5][..], None, 2.0),
        (Backend::Software, &[0.15][..], Some(30.0), 1.5),
        (Backend::Software, &[0.15][..], Some(22.0), 1.0),
    ] {
        let r = Renderer::new(backend);
        for &alpha in alphas {
            let run = |direct| -> Vec<Vec<f64>> {
                (0..SEEDS)
                    .map(|s| {
                        let cfg = config(alpha, direct, 1000 + s, SPP);
                        r.radiance(&match panel_x {
                            Some(x) => among_other_lights(cfg, x),
                            None => cfg,
                        })
                    })
                    .collect()
            };
            let name = format!(
                "{} alpha {alpha}{}",
                backend.name(),
                panel_x.map_or(String::new(), |x| format!(", three lights, panel at x {x}"))
            );
            sampled_against_analytic(&name, run, gain);
        }
    }
}

#[test]
fn direct_light_parses_and_names_its_values() {
    let c = SceneConfig::parse("[render]\ndirect_light = \"sampled\"\n").expect("parse");
    assert_eq!(c.render.direct_light, DirectLight::Sampled);
    assert_eq!(
        SceneConfig::default().render.direct_light,
        DirectLight::Analytic
    );
    let e = SceneConfig::parse("[render]\ndirect_light = \"ltc\"\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("direct_light") && e.contains("sampled") && e.contains("analytic"),
        "{e}"
    );
    // Jobs: the same field and values in `[render]`.
    let scenes = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"));
    let job = |text: &str| {
        common::small_smoke_text().replace("[render]\n", &format!("[render]\n{text}\n"))
    };
    let j = synosis::dataset::Job::parse(&job("direct_light = \"sampled\""), "job", scenes)
        .expect("job");
    assert_eq!(j.render.direct_light, Some(DirectLight::Sampled));
    let e = synosis::dataset::Job::parse(&job("direct_light = \"exact\""), "job", scenes)
        .unwrap_err()
        .to_string();
    assert!(e.contains("direct_light") && e.contains("analytic"), "{e}");
    // analytic_rays: [1, 64] in scene files and jobs, named with its range when outside.
    assert_eq!(SceneConfig::default().render.analytic_rays, 1);
    for bad in ["0", "65"] {
        let e = SceneConfig::parse(&format!("[render]\nanalytic_rays = {bad}\n"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("render.analytic_rays") && e.contains("[1, 64]"),
            "{e}"
        );
        let e =
            synosis::dataset::Job::parse(&job(&format!("analytic_rays = {bad}")), "job", scenes)
                .unwrap_err()
                .to_string();
        assert!(
            e.contains("render.analytic_rays") && e.contains("64"),
            "{e}"
        );
    }
    let j = synosis::dataset::Job::parse(&job("analytic_rays = 64"), "job", scenes).expect("job");
    assert_eq!(j.render.analytic_rays, Some(64));
    // light_samples and bsdf_samples: [1, 64] likewise.
    assert_eq!(SceneConfig::default().render.light_samples, 1);
    assert_eq!(SceneConfig::default().render.bsdf_samples, 1);
    for field in ["light_samples", "bsdf_samples"] {
        for bad in ["0", "65"] {
            let e = SceneConfig::parse(&format!("[render]\n{field} = {bad}\n"))
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(&format!("render.{field}")) && e.contains("[1, 64]"),
                "{e}"
            );
            let e = synosis::dataset::Job::parse(&job(&format!("{field} = {bad}")), "job", scenes)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(&format!("render.{field}")) && e.contains("64"),
                "{e}"
            );
        }
    }
    let j =
        synosis::dataset::Job::parse(&job("light_samples = 8\nbsdf_samples = 3"), "job", scenes)
            .expect("job");
    assert_eq!(j.render.light_samples, Some(8));
    assert_eq!(j.render.bsdf_samples, Some(3));
}

/// More light and BSDF samples for the direct light at the camera ray's first hit
/// (`[render] light_samples`, `bsdf_samples`) keep the mean and lower the noise: the plane
/// partly shadowed from the ring by the quad, alone and among three lights (the panel
/// clear of the ring from half of the plane, the dome; each strategy's samples averaged
/// under the MIS weights, the control variate's terms weighted alike). Over seeds, with
/// 3 + 3 samples the means over the image and each quarter equal the 1 + 1 sampled
/// estimator's within statistical error, for both estimators, and the pixel variance
/// falls.
#[test]
fn more_light_and_bsdf_samples_keep_the_mean_and_lower_the_noise() {
    const SEEDS: u32 = 10;
    const SPP: u32 = 8;
    let r = Renderer::new(Backend::Software);
    for panel_x in [None, Some(30.0)] {
        let run = |direct, lights: u32, bsdfs: u32| -> (Vec<Vec<f64>>, f64) {
            let images: Vec<Vec<f64>> = (0..SEEDS)
                .map(|s| {
                    let mut cfg = config(0.15, direct, 2000 + s, SPP);
                    cfg.render.light_samples = lights;
                    cfg.render.bsdf_samples = bsdfs;
                    r.radiance(&match panel_x {
                        Some(x) => among_other_lights(cfg, x),
                        None => cfg,
                    })
                })
                .collect();
            statistics(&images)
        };
        let name = panel_x.map_or("the ring".to_string(), |x| {
            format!("three lights, panel at x {x}")
        });
        let (reference, var_ref) = run(DirectLight::Sampled, 1, 1);
        // (estimator, its 1 + 1 pixel variance, the least variance reduction required).
        for (direct, gain) in [(DirectLight::Sampled, 1.5), (DirectLight::Analytic, 1.2)] {
            let var1 = match direct {
                DirectLight::Sampled => var_ref,
                _ => run(direct, 1, 1).1,
            };
            let (lights, bsdfs) = (3, 3);
            let (more, var) = run(direct, lights, bsdfs);
            let what = format!("{name}, {direct:?}, {lights} light + {bsdfs} BSDF samples");
            for (k, (m, m0)) in more.iter().zip(&reference).enumerate() {
                let ((a, ea), (b, eb)) = (mean_se(m), mean_se(m0));
                let z = (a - b) / (ea * ea + eb * eb).sqrt();
                eprintln!(
                    "{what}, area {k}: {a:.6} +- {ea:.1e}, sampled 1 + 1 {b:.6} +- {eb:.1e}, \
                     z {z:+.2}"
                );
                assert!(a > 0.0 && b > 0.0, "{what}: a dark image tests nothing");
                assert!(
                    z.abs() < 4.0,
                    "{what}, area {k}: the mean differs by {z:.1} standard errors"
                );
            }
            eprintln!(
                "{what}: pixel variance {var:.3e}, 1 + 1 {var1:.3e} ({:.2}x)",
                var1 / var
            );
            assert!(
                var * gain <= var1,
                "{what}: more samples must lower the variance ({var1:.3e} -> {var:.3e})"
            );
        }
    }
}

/// The glossy test body (alpha 0.05) seen from A20 with fine grooves (20 µm texels, 0.2 mm
/// period), `w` x `h` pixels at the paper camera's pixel: the scene of the tests below,
/// with `render` as its `[render]` section's lines and `more` as further sections.
fn grooved_body(render: &str, more: &str, w: u32, h: u32) -> SceneConfig {
    let text = format!(
        "[camera]\nwidth = 1224\nheight = 1025\nview = \"A20\"\n[material]\nalpha = 0.05\n\
         [render]\n{render}\n{more}\
         [texture]\nkind = \"test-grooves\"\nspacing_um = 20.0\n\
         groove_period_mm = 0.2\ngroove_max_slope_deg = 20.0\nrotation_deg = [25.0, 0.0, 0.0]\n"
    );
    let mut cfg = SceneConfig::parse(&text).expect("test scene");
    cfg.set_resolution(w, h).expect("size");
    cfg
}

/// More camera rays for the control variate's closed form (`[render] analytic_rays`)
/// keep the mean and average a texture that varies under the pixel: the test body's face
/// A with fine grooves (20 µm texels, 0.2 mm period: about two periods under each of the
/// 64 x 48 pixels), glossy. Over seeds, the mean over face A's inner pixels with 4 rays
/// equals the sampled estimator's and the 1-ray control variate's within statistical
/// error, and so does the mean over all other pixels (edges, faces B and C, the table,
/// where the extra rays' plane differs from their hits), and the pixel variance falls
/// below the 1-ray one's.
#[test]
fn more_analytic_rays_keep_the_mean_and_average_the_texture() {
    const SEEDS: u32 = 8;
    let cfg = |direct: &str, rays: u32, seed: u32| {
        let render = format!(
            "spp = 8\nbatch_spp = 8\nmax_bounces = 3\nseed = {seed}\n\
             direct_light = \"{direct}\"\nanalytic_rays = {rays}"
        );
        grooved_body(&render, "", 64, 48)
    };
    // Per seed: the mean over face A's inner pixels, the mean over every other pixel (the
    // extra rays' closed form takes the plane of the pixel centre's hit: edges, other
    // faces, the table and the background are where it differs from the hit's own), and
    // the inner pixels.
    let run = |direct: &str, rays: u32| -> (Vec<f64>, Vec<f64>, Vec<Vec<f64>>) {
        let mut means = Vec::new();
        let mut rest_means = Vec::new();
        let mut images = Vec::new();
        for s in 0..SEEDS {
            let (img, face) = common::render_faces(&cfg(direct, rays, 500 + s), Backend::Software);
            let inner = common::interior(&face, 64, 48);
            assert!(inner.len() > 400, "{} pixels of face A", inner.len());
            let px: Vec<f64> = inner.iter().map(|&i| img.data[i] as f64).collect();
            means.push(px.iter().sum::<f64>() / px.len() as f64);
            let mut is_inner = vec![false; img.data.len()];
            inner.iter().for_each(|&i| is_inner[i] = true);
            let rest: Vec<f64> = (0..img.data.len())
                .filter(|&i| !is_inner[i])
                .map(|i| img.data[i] as f64)
                .collect();
            assert!(rest.len() > 1000, "{} other pixels", rest.len());
            rest_means.push(rest.iter().sum::<f64>() / rest.len() as f64);
            images.push(px);
        }
        (means, rest_means, images)
    };
    let (ms, rs, _) = run("sampled", 1);
    let (m1, r1, i1) = run("analytic", 1);
    let (m4, r4, i4) = run("analytic", 4);
    for (part, m4, ms, m1) in [
        ("face A", &m4, &ms, &m1),
        ("the other pixels", &r4, &rs, &r1),
    ] {
        let (a, b) = (mean_se(m4), mean_se(ms));
        for (name, (mo, eo)) in [("sampled", b), ("analytic, 1 ray", mean_se(m1))] {
            let z = (a.0 - mo) / (a.1 * a.1 + eo * eo).sqrt();
            eprintln!(
                "{part}: 4 rays {:.6} +- {:.1e}, {name} {mo:.6} +- {eo:.1e}, z {z:+.2}",
                a.0, a.1
            );
            assert!(a.0 > 0.0, "a dark {part} tests nothing");
            assert!(
                z.abs() < 4.0,
                "{part}, 4 rays against {name}: the means differ by {z:.1} standard errors"
            );
        }
    }
    let (v1, v4) = (pixel_variance(&i1), pixel_variance(&i4));
    eprintln!(
        "pixel variance: 1 ray {v1:.3e}, 4 rays {v4:.3e} ({:.2}x)",
        v1 / v4
    );
    assert!(
        v4 * 1.5 <= v1,
        "4 rays must average the texture: {v1:.3e} -> {v4:.3e}"
    );
}

/// Split paths (`[render] split_paths = true`): the first hit's BSDF directions each go
/// on as a path of weight 1 / `bsdf_samples`. On the glossy test body seen at 20 degrees
/// on a bright table (albedo 0.5: the light after the first bounce is there), 3 bounces,
/// the light past the first hit of each seed's image is isolated as its render with 3
/// bounces less the one with 1 (the same samples at the first hit, so the difference is
/// exactly what the paths add past it). Over seeds, its means over face A's inner pixels
/// and over the other pixels equal the unsplit render's within 4 standard errors, on
/// both backends (the split changes which rays are traced, not how), and its pixel
/// variance falls at least 1.5x with 3 branches.
#[test]
fn split_paths_keep_the_mean_of_the_light_past_the_first_hit() {
    const SEEDS: u32 = 6;
    const W: usize = 40;
    const H: usize = 30;
    let cfg = |split: bool, bounces: u32, seed: u32| {
        let render = format!(
            "spp = 8\nbatch_spp = 8\nmax_bounces = {bounces}\nseed = {seed}\n\
             direct_light = \"analytic\"\nbsdf_samples = 3\nsplit_paths = {split}"
        );
        grooved_body(&render, "[table]\nalbedo = 0.5\n", W as u32, H as u32)
    };
    for backend in [Backend::Software, Backend::RayQuery] {
        // Per seed: the means over face A's inner pixels and over the others of the light
        // past the first hit; and that light's images.
        let run = |split: bool| -> (Vec<f64>, Vec<f64>, Vec<Vec<f64>>) {
            let (mut inner_means, mut rest_means, mut images) =
                (Vec::new(), Vec::new(), Vec::new());
            for s in 0..SEEDS {
                let (img3, face) = common::render_faces(&cfg(split, 3, 700 + s), backend);
                let (img1, _) = common::render_faces(&cfg(split, 1, 700 + s), backend);
                let inner = common::interior(&face, W, H);
                assert!(inner.len() > 100, "{} pixels of face A", inner.len());
                let mut is_inner = vec![false; img3.data.len()];
                inner.iter().for_each(|&i| is_inner[i] = true);
                let past: Vec<f64> = img3
                    .data
                    .iter()
                    .zip(&img1.data)
                    .map(|(&a, &b)| a as f64 - b as f64)
                    .collect();
                let mean = |keep: bool| {
                    let v: Vec<f64> = (0..past.len())
                        .filter(|&i| is_inner[i] == keep)
                        .map(|i| past[i])
                        .collect();
                    v.iter().sum::<f64>() / v.len() as f64
                };
                inner_means.push(mean(true));
                rest_means.push(mean(false));
                images.push(past);
            }
            (inner_means, rest_means, images)
        };
        let (i_off, r_off, img_off) = run(false);
        let (i_on, r_on, img_on) = run(true);
        // Areas 0 and 1: face A's inner pixels, the other pixels.
        same_mean_less_variance(
            &format!("{}, the light past the first hit", backend.name()),
            ["unsplit", "split"],
            (&[i_off, r_off], pixel_variance(&img_off)),
            (&[i_on, r_on], pixel_variance(&img_on)),
            1.5,
        );
    }
}

/// `[render] split_paths`: false by default, true in scene files and jobs only with
/// `bsdf_samples` >= 2 (the branches are its directions); each refusal names the field.
#[test]
fn split_paths_parses_and_needs_bsdf_samples() {
    assert!(!SceneConfig::default().render.split_paths);
    let c = SceneConfig::parse("[render]\nbsdf_samples = 4\nsplit_paths = true\n").expect("parse");
    assert!(c.render.split_paths);
    let e = SceneConfig::parse("[render]\nsplit_paths = true\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("render.bsdf_samples") && e.contains("split_paths"),
        "{e}"
    );
    let e = SceneConfig::parse("[render]\nsplit_paths = \"on\"\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("split_paths"), "{e}");
    let scenes = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"));
    let job = |text: &str| {
        common::small_smoke_text().replace("[render]\n", &format!("[render]\n{text}\n"))
    };
    let j =
        synosis::dataset::Job::parse(&job("bsdf_samples = 2\nsplit_paths = true"), "job", scenes)
            .expect("job");
    assert_eq!(j.render.split_paths, Some(true));
    let e = synosis::dataset::Job::parse(&job("split_paths = true"), "job", scenes)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("render.bsdf_samples") && e.contains("split_paths"),
        "{e}"
    );
    let e = synosis::dataset::Job::parse(&job("split_paths = 2"), "job", scenes)
        .unwrap_err()
        .to_string();
    assert!(e.contains("split_paths"), "{e}");
}

/// Paths put off (glsl/path_trace.comp, `main`'s windows) under the analytic direct
/// light with extra camera rays: a bounce's ray that leaves the glossy test body, the
/// first bounce's too (whose control-variate term awaits the light it meets), ends its
/// path but for the light it may meet, which is looked up at the window's end, and the
/// extra rays' term is added after it. The image is the one of the rays traced as they
/// come (`light_shortcuts = false`) byte for byte, on both backends, at 13 samples (a
/// window of 8 and one of 5), with two BSDF samples at the first hit and 3 bounces, over
/// grooves that vary under the pixel.
#[test]
fn paths_put_off_under_the_analytic_light_change_no_pixel() {
    let cfg = |shortcuts: bool| {
        let render = format!(
            "spp = 13\nbatch_spp = 13\nmax_bounces = 3\nseed = 11\n\
             direct_light = \"analytic\"\nanalytic_rays = 4\nbsdf_samples = 2\n\
             light_shortcuts = {shortcuts}"
        );
        grooved_body(&render, "", 32, 24)
    };
    for backend in common::BACKENDS {
        let (a, face_a) = common::render_faces(&cfg(true), backend);
        let (b, face_b) = common::render_faces(&cfg(false), backend);
        let m = a.data.iter().map(|&x| x as f64).sum::<f64>() / a.data.len() as f64;
        let differing = a.data.iter().zip(&b.data).filter(|(x, y)| x != y).count();
        eprintln!("{}: mean {m:.5}, {differing} pixels differ", backend.name());
        assert!(m > 0.0, "a dark image tests nothing");
        assert_eq!(differing, 0, "{}", backend.name());
        assert_eq!(face_a, face_b, "{}: labels", backend.name());
    }
}

/// `scene_mesh`'s plane stood up: a 30 x 30 mm wall in the plane y = 0 facing -y, from
/// the table (z = 0) to z = 30 (the quad behind it, out of every ray's way).
fn wall_mesh() -> Mesh {
    let mut m = common::labelled_plane(
        30.0,
        0.0,
        &[],
        [
            Vec3::new(-5.0, -5.0, -20.0),
            Vec3::new(5.0, -5.0, -20.0),
            Vec3::new(5.0, 5.0, -20.0),
            Vec3::new(-5.0, 5.0, -20.0),
        ],
    );
    // (x, y, z) -> (x, -z, y + 15): a rotation, so the plane's normal +z becomes -y.
    for p in &mut m.positions {
        *p = Vec3::new(p.x, -p.z, p.y + 15.0);
    }
    m
}

/// `config` with the camera level with the wall's centre, 90 mm in front of it: the
/// ring on the camera (radius 30 mm about the point 15 mm above the table) dips below
/// the table's plane, so the table hides the ring's lowest sixth from the wall, which
/// the control variate clips off its closed form and its samples alike
/// (glsl/common/analytic_light.glsl `ring_table_clip`); `table_mm`: the table's edge
/// length (at 40 mm the hidden part's shadow falls beyond it: no clip, and nothing hidden).
fn level_with_the_wall(mut cfg: SceneConfig, table_mm: f32, rays: u32) -> SceneConfig {
    cfg.camera.look_at = Some(LookAt {
        eye: [0.0, -90.0, 15.0],
        target: [0.0, 0.0, 15.0],
        up: [0.0, 0.0, 1.0],
    });
    cfg.table.size_mm = table_mm;
    cfg.render.analytic_rays = rays;
    cfg.validate().expect("valid");
    cfg
}

/// The table's clip keeps the mean and takes the table's shadow on the ring out of the
/// residual: on the wall level with the camera (`level_with_the_wall`), over seeds, the
/// control variate's mean over the image and each quarter equals the sampled estimator's
/// within statistical error (both backends; with 4 camera rays for the closed form, whose
/// recorded rings are clipped too; and on a small table, where nothing is clipped), and
/// its variance is far below the sampled estimator's (with the clip as without it on a
/// ring the table does not hide). Without the clip the control variate's variance was
/// 1.8x below the sampled estimator's on the large table (60 seeds), with it 18.8x.
#[test]
fn the_tables_clip_keeps_the_mean_and_lowers_the_variance() {
    const SEEDS: u32 = 24;
    const SPP: u32 = 16;
    // (backend, table edge mm, analytic rays, the least variance reduction required).
    for (backend, table_mm, rays, gain) in [
        (Backend::RayQuery, 400.0, 1, 6.0),
        (Backend::Software, 400.0, 4, 6.0),
        (Backend::Software, 40.0, 1, 6.0),
    ] {
        let r = Renderer(common::SceneRenderer::new(
            backend,
            wall_mesh(),
            &level_with_the_wall(config(0.15, DirectLight::Sampled, 0, 4), table_mm, 1),
        ));
        let run = |direct| -> Vec<Vec<f64>> {
            (0..SEEDS)
                .map(|s| {
                    // Seeds of their own per estimator: independent means.
                    let first = match direct {
                        DirectLight::Sampled => 3000,
                        DirectLight::Analytic => 4000,
                    };
                    let cfg = config(0.15, direct, first + s, SPP);
                    r.radiance(&level_with_the_wall(cfg, table_mm, rays))
                })
                .collect()
        };
        let name = format!("{}, table {table_mm} mm, {rays} rays", backend.name());
        sampled_against_analytic(&name, run, gain);
    }
}
