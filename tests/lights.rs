//! The light kinds on the GPU (both backends, validation on): a Lambertian plate's
//! rendered radiance under each kind against the irradiance integrated on the CPU, two
//! lights against the sum of the single-light images, `[light]` against the same ring as
//! a `[[light]]` entry.

mod common;

use glam::Vec3;
use synosis::render::path_trace::{MAT_TABLE, Radiance, RenderScene, load_object};
use synosis::scene::assemble::{EmitterSampling, LightGeometry};
use synosis::scene::config::SceneConfig;
use synosis::scene::light_cover::{ALL_CELLS, light_cover, seen_box};
use synosis::trace::Backend;

/// The paper camera's field of view at `w` x `h`, straight above face A (30 x 25 mm of
/// the plate from 90 mm), with `lights` (`[[light]]` tables) and direct light only.
fn plate_cfg(lights: &str, w: u32, h: u32, spp: u32) -> SceneConfig {
    let text = format!(
        "[camera]\nwidth = 1224\nheight = 1025\nview = \"A0\"\n[table]\nalbedo = 1.0\n[render]\nspp = {spp}\nbatch_spp = 1024\nseed = 7\nmax_bounces = 1\n{lights}"
    );
    let mut cfg = SceneConfig::parse(&text).expect("test scene");
    cfg.set_resolution(w, h).expect("size");
    cfg
}

/// Renders the plate (albedo 1, Lambertian) under `cfg`.
fn render_plate(cfg: &SceneConfig, backend: Backend) -> (RenderScene, Radiance) {
    let mut s = RenderScene::assemble(&common::face_a_plate(), cfg).expect("scene");
    for m in s.stage.materials.iter_mut().take(2) {
        *m = MAT_TABLE;
    }
    let img = common::path_trace_shared(&s, cfg, backend);
    (s, img)
}

/// Irradiance (W m^-2) at p (normal +z) from every light of `l`: the area lights'
/// triangles integrated with 144 nodes each (cos_p cos_l / r^2, radiance per light), the
/// spots in closed form I(theta) cos_p / r^2 with r in metres (smoothstep soft edge).
fn irradiance(l: &LightGeometry, p: Vec3) -> f64 {
    let mut e = common::light_integral(l, p, 12, |w| w.z);
    let p = p.as_dvec3();
    for em in &l.emitters {
        if let EmitterSampling::Spot {
            position,
            axis,
            intensity_w_sr,
            cos_edge,
            cos_inner,
        } = em.sampling
        {
            let d = position.as_dvec3() - p;
            let r2 = d.length_squared();
            let w = d / r2.sqrt();
            let c = (-w).dot(axis.as_dvec3());
            let (ce, ci) = (cos_edge as f64, cos_inner as f64);
            let f = if c >= ci {
                1.0
            } else if c <= ce {
                0.0
            } else {
                let t = (c - ce) / (ci - ce);
                t * t * (3.0 - 2.0 * t)
            };
            if w.z > 0.0 {
                e += intensity_w_sr as f64 * f * w.z / (r2 * 1e-6);
            }
        }
    }
    e
}

/// Mean of a 3 x 3 pixel block and the expected mean (E / pi over each pixel's footprint,
/// 3 x 3 points per pixel).
fn block(s: &RenderScene, img: &Radiance, cx: u32, cy: u32) -> (f64, f64) {
    let cam = s.view.camera;
    let (mut got, mut expect) = (0.0f64, 0.0f64);
    for px in cx - 1..=cx + 1 {
        for py in cy - 1..=cy + 1 {
            got += img.data[(py * cam.width + px) as usize] as f64 / 9.0;
            for a in 0..3 {
                for b in 0..3 {
                    let d = cam.dir(
                        px as f32 + (a as f32 + 0.5) / 3.0,
                        py as f32 + (b as f32 + 0.5) / 3.0,
                    );
                    let t = (10.0 - cam.eye.z) / d.z;
                    expect +=
                        irradiance(&s.view.light, cam.eye + d * t) / std::f64::consts::PI / 81.0;
                }
            }
        }
    }
    (got, expect)
}

/// Each kind, both backends: the plate's radiance in four 3 x 3 blocks against the
/// integral, within 1.5 % (as the ring light test).
#[test]
fn each_kind_matches_the_irradiance_integral() {
    let kinds = [
        (
            "ring at a free pose (facing)",
            "[[light]]\nkind = \"ring\"\nposition_mm = [25, 10, 120]\ndirection = [0, 0, -1]\nminor_radius_mm = 3\nradiance = 2.0\n",
        ),
        (
            "bar",
            "[[light]]\nkind = \"bar\"\nlook_at = { eye = [-40, 20, 60], target = [0, 0, 10], up = [0, 0, 1] }\nsize_mm = [80, 15, 10]\n",
        ),
        (
            "panel",
            "[[light]]\nkind = \"panel\"\nposition_mm = [40, -10, 70]\ndirection = [-0.3, 0, -1]\nup = [0, 1, 0]\nsize_mm = [50, 40]\nradiance = 3.0\n",
        ),
        (
            "dome",
            "[[light]]\nkind = \"dome\"\nradius_mm = 250\ncentre_mm = [20, 0, 0]\nsegments = [24, 6]\nradiance = 0.5\n",
        ),
        (
            "spot (soft edge across the view)",
            "[[light]]\nkind = \"spot\"\nlook_at = { eye = [60, 0, 110], target = [3, 0, 10], up = [0, 0, 1] }\nintensity_w_sr = 0.002\nhalf_angle_deg = 12\nfalloff_deg = 8\n",
        ),
    ];
    for (i, (name, lights)) in kinds.iter().enumerate() {
        let cfg = plate_cfg(lights, 16, 12, 2048);
        for backend in common::BACKENDS {
            let (s, img) = render_plate(&cfg, backend);
            let mut worst = 0.0f64;
            for (cx, cy) in [(8u32, 6u32), (2, 2), (13, 9), (4, 9)] {
                let (got, expect) = block(&s, &img, cx, cy);
                let rel = got / expect - 1.0;
                println!(
                    "{name} {} block ({cx}, {cy}): {got:.5} vs {expect:.5} ({:+.2} %)",
                    backend.name(),
                    100.0 * rel
                );
                assert!(expect > 0.0, "{name}: block ({cx}, {cy}) unlit");
                worst = worst.max(rel.abs());
            }
            assert!(
                worst < 0.015,
                "{name} ({}): worst relative error {worst}",
                backend.name()
            );
            if i == 4 {
                // The spot's soft edge crosses the view: the blocks differ.
                let (a, _) = block(&s, &img, 2, 2);
                let (b, _) = block(&s, &img, 13, 9);
                assert!((a / b - 1.0).abs() > 0.1, "spot edge not in view: {a} {b}");
            }
        }
    }
}

/// A fat ring light low over the plate hides parts of its tube from much of it (the far
/// side's inner face behind the near side), and many rays pass through its hole: with
/// `[render] light_shortcuts` (the default) shadow rays test a light triangle alone
/// where the view's light cover says nothing can hide it (src/scene/light_cover.rs) and
/// rays that can meet no light skip the lights (glsl/common/lights.glsl
/// `misses_lights`), and a path whose bounce's ray leaves the plate is put off and its
/// light looked up with other samples' at the end of a window of 8 (glsl/path_trace.comp
/// `main`, software backends); the images are the very bytes of `light_shortcuts =
/// false`, which traverses the lights for every ray as it comes, on every backend. Two light samples and four
/// BSDF directions at the first hit take every kind of trace. The cover marks some
/// cells of some triangles and not others, so both ways are taken; with the thinner
/// ring it lists the few triangles that can hide some (`LightCover::hiders`), which
/// shadow rays from an unmarked cell then test in place of the lights' traversal.
#[test]
fn light_shortcuts_change_no_pixel() {
    // The fat ring: most partly hidden triangles have more would-be hiders than a list
    // holds; the thin one (the demo's proportions) lists them for many.
    let fat =
        "major_radius_mm = 22\nminor_radius_mm = 16\nsegments_major = 48\nsegments_minor = 16\n";
    let thin =
        "major_radius_mm = 22\nminor_radius_mm = 4\nsegments_major = 48\nsegments_minor = 12\n";
    for (shape, lists) in [(fat, false), (thin, true)] {
        let ring = format!(
            "light_samples = 2\nbsdf_samples = 4\n[[light]]\nkind = \"ring\"\nposition_mm = [0, 0, 34]\ndirection = [0, 0, -1]\n{shape}sampling = \"uniform\"\n"
        );
        // 13 samples: main's windows of 8 (paths put off, their lights looked up
        // together at a window's end) and a last one of 5.
        let cfg = plate_cfg(&ring, 32, 24, 13);
        let off = plate_cfg(&format!("light_shortcuts = false\n{ring}"), 32, 24, 13);
        let s = RenderScene::assemble(&common::face_a_plate(), &cfg).expect("scene");
        let (lo, hi) = s.stage.mesh.bounds();
        let cover = light_cover(&s.view.light.tris, seen_box(&s.view.camera, [lo, hi]));
        let full = cover.masks.iter().filter(|&&m| m == ALL_CELLS).count();
        let partial = cover.masks.len() - full;
        let listed = cover.hiders.iter().filter(|h| !h.is_empty()).count();
        println!("cover: {full} clear from every cell, {partial} not, {listed} with hider lists");
        assert!(
            full > 0 && partial > 0 && (!lists || listed > 0),
            "cover: {full} clear from every cell, {partial} not, {listed} with hider lists"
        );
        for backend in common::BACKENDS {
            let a = render_plate(&cfg, backend).1;
            let b = render_plate(&off, backend).1;
            let differing = a.data.iter().zip(&b.data).filter(|(x, y)| x != y).count();
            println!(
                "{}: mean {:.5}, {differing} pixels differ",
                backend.name(),
                mean(&a.data)
            );
            assert_eq!(differing, 0, "{}", backend.name());
        }
    }
}

fn mean(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64
}

/// Two lights (the ring on the camera and a bar beside it) on the conductor test body
/// (rough, on a grey table, 3 bounces) give the sum of the two single-light images within
/// Monte Carlo noise: whole image and 8 x 8 blocks; both backends.
#[test]
fn two_lights_give_the_sum_of_one_light_each() {
    let cfg = |lights: &str| {
        let text = format!(
            "[camera]\nwidth = 1224\nheight = 1025\nview = \"A20\"\n[material]\nalpha = 0.5\n[table]\nalbedo = 0.3\n[render]\nspp = 256\nbatch_spp = 256\nseed = 3\nmax_bounces = 3\n{lights}"
        );
        let mut c = SceneConfig::parse(&text).expect("scene");
        c.set_resolution(32, 24).expect("size");
        c
    };
    let ring = "[[light]]\nkind = \"ring\"\n";
    // The bar 90 mm beside the camera (clear of the ring: no shadows between them), aimed at the viewed face centre.
    let probe = cfg(ring);
    let cam = RenderScene::assemble(&load_object(&probe).expect("object"), &probe)
        .expect("scene")
        .view
        .camera;
    let eye = cam.eye + cam.right * 90.0;
    let target = cam.eye + cam.forward * probe.camera.working_distance_mm;
    let bar = format!(
        "[[light]]\nkind = \"bar\"\nlook_at = {{ eye = [{}, {}, {}], target = [{}, {}, {}], up = [{}, {}, {}] }}\nsize_mm = [10, 60, 10]\nradiance = 3.0\n",
        eye.x, eye.y, eye.z, target.x, target.y, target.z, cam.up.x, cam.up.y, cam.up.z
    );
    for backend in common::BACKENDS {
        let render = |c: &SceneConfig| {
            let object = load_object(c).expect("object");
            let s = RenderScene::assemble(&object, c).expect("scene");
            common::path_trace_shared(&s, c, backend)
        };
        let a = render(&cfg(ring));
        let b = render(&cfg(&bar));
        let both = render(&cfg(&format!("{ring}{bar}")));
        let sum: Vec<f32> = a.data.iter().zip(&b.data).map(|(x, y)| x + y).collect();
        let (ma, mb, mab) = (mean(&a.data), mean(&b.data), mean(&both.data));
        let rel = mab / (ma + mb) - 1.0;
        println!(
            "{}: ring {ma:.5} + bar {mb:.5} = {:.5}, both {mab:.5} ({:+.2} %)",
            backend.name(),
            ma + mb,
            100.0 * rel
        );
        // Each light must matter, or the sum says nothing.
        assert!(ma > 0.1 * mb && mb > 0.1 * ma, "{ma} {mb}");
        assert!(rel.abs() < 0.01, "{}: whole image {rel}", backend.name());
        let mut worst = 0.0f64;
        for by in 0..3 {
            for bx in 0..4 {
                let (mut s1, mut s2) = (0.0f64, 0.0f64);
                for y in by * 8..by * 8 + 8 {
                    for x in bx * 8..bx * 8 + 8 {
                        let i = y * 32 + x;
                        s1 += sum[i] as f64;
                        s2 += both.data[i] as f64;
                    }
                }
                if s1 > 0.2 * (ma + mb) * 64.0 {
                    worst = worst.max((s2 / s1 - 1.0).abs());
                }
            }
        }
        println!(
            "{}: worst 8 x 8 block {:+.2} %",
            backend.name(),
            100.0 * worst
        );
        assert!(worst < 0.03, "{}: 8 x 8 block {worst}", backend.name());
    }
}

/// `[light]` and the same ring as a `[[light]]` entry render the identical image (the
/// list path adds nothing for one light); a spot-only scene (no light triangles) and a
/// dark one (radiance 0) render without NaN on both backends.
#[test]
fn one_ring_as_table_or_list_is_the_same_image() {
    let table = "[light]\nradiance = 1.5\nsegments_major = 32\nsampling = \"uniform\"\n";
    let list =
        "[[light]]\nkind = \"ring\"\nradiance = 1.5\nsegments_major = 32\nsampling = \"uniform\"\n";
    for backend in common::BACKENDS {
        let a = render_plate(&plate_cfg(table, 16, 12, 16), backend).1;
        let b = render_plate(&plate_cfg(list, 16, 12, 16), backend).1;
        assert!(a.data == b.data, "{}", backend.name());
        let spot = "[[light]]\nkind = \"spot\"\non_camera = true\nintensity_w_sr = 0.01\n";
        let s = render_plate(&plate_cfg(spot, 16, 12, 16), backend).1;
        assert!(s.data.iter().all(|v| v.is_finite() && *v > 0.0));
        let dark = "[[light]]\nkind = \"panel\"\nposition_mm = [0, 50, 60]\ndirection = [0, -1, -1]\nradiance = 0\n";
        let d = render_plate(&plate_cfg(dark, 16, 12, 16), backend).1;
        assert!(d.data.iter().all(|v| *v == 0.0));
    }
}

/// Bad `[[light]]` values are refused when the scene is parsed (before any rendering),
/// naming the entry, the field and the range.
#[test]
fn bad_lights_are_refused_by_name() {
    for (text, want) in [
        (
            "[[light]]\nkind = \"ring\"\n[[light]]\nkind = \"spot\"\non_camera = true\nhalf_angle_deg = 0\n",
            "light[1].half_angle_deg: 0 is out of range: allowed (0, 90] degrees",
        ),
        (
            "[[light]]\nkind = \"laser\"\n",
            "light[0]: unknown variant `laser`",
        ),
        (
            "[[light]]\nkind = \"panel\"\nposition_mm = [0, 0, 50]\ndirection = [0, 0, -1]\nsize = 3\n",
            "light[0]: unknown field `size`",
        ),
        (
            "[[light]]\nkind = \"dome\"\nradiance = 2e6\n",
            "light[0].radiance: 2000000 is out of range: allowed [0, 1e6]",
        ),
    ] {
        let e = SceneConfig::parse(text).unwrap_err().to_string();
        assert!(e.contains(want), "{text}: {e}");
    }
}

/// A dataset job's `[[light]]` entries replace the default ring: an explicit ring on the
/// camera renders the same bytes as none, a bar next to it changes the image, and a bad
/// entry is refused when the job is read, naming the field.
#[test]
fn job_lights_replace_the_default_ring() {
    use synosis::dataset::gpu::GpuRenderer;
    use synosis::dataset::{self, RunOptions};
    let base = "seed = 5\nviews = [\"A0\"]\n[render]\nwidth = 32\nheight = 24\nspp = 2\nbounces = 2\n\
        [material]\nalpha = [0.2, 0.3]\n[texture]\nsize_px = 80\nspacing_um = 400.0\ncache = 1\n\
        [[object]]\nname = \"testbody-b\"\nmesh = \"testbody-b\"\ndefective = 0\ndefect_free = 1\n\
        [[finish]]\nname = \"sandblasted-2.5bar\"\nkind = \"sandblasted\"\ntextures = 1\n\
        exemplar = { pressure_bar = 2.5 }\n";
    let scenes = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"));
    let mut r = GpuRenderer::new(synosis::trace::AccelChoice::Auto, true).unwrap();
    let mut run = |text: &str| {
        let prep = dataset::prepare_text(text, "lights", scenes).unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("ds");
        let mut textures = synosis::dataset::texture_bridge::ModuleTextures::default();
        let opts = RunOptions::default();
        assert_eq!(
            dataset::run(&prep, &out, &mut r, &mut textures, opts)
                .unwrap()
                .rendered,
            1
        );
        std::fs::read(out.join("images/000000/radiance.exr")).unwrap()
    };
    let ring = "[[light]]\nkind = \"ring\"\non_camera = true\n";
    let bar = "[[light]]\nkind = \"bar\"\nposition_mm = [60, 0, 120]\ndirection = [-0.5, 0, -1]\nradiance = 2.0\n";
    let none = run(base);
    assert!(
        run(&format!("{base}{ring}")) == none,
        "explicit ring != default"
    );
    assert!(
        run(&format!("{base}{ring}{bar}")) != none,
        "the bar changed nothing"
    );
    let bad = format!("{base}[[light]]\nkind = \"spot\"\non_camera = true\nhalf_angle_deg = 100\n");
    let e = dataset::prepare_text(&bad, "lights", scenes)
        .err()
        .expect("refused")
        .to_string();
    assert!(
        e.contains("light[0].half_angle_deg") && e.contains("(0, 90]"),
        "{e}"
    );
}
