//! Labels from the path tracer's own camera samples (`[render] labels = "samples"`)
//! against the annotation pass, on both backends: bit-identical ids and coverage under a
//! thin lens on a scene with occluded and partly covered defects, the same image bytes,
//! the pinhole's agreement away from label edges, and a first batch too short to hold
//! the label samples.

mod common;

use glam::Vec3;
use synosis::render::Frame;
use synosis::render::annotate::Annotation;
use synosis::scene::Mesh;
use synosis::scene::config::{LabelSource, SceneConfig};
use synosis::trace::Backend;

/// A 30 x 30 mm plane (face A) at z = 10 in 0.5 mm cells with three labelled defects:
/// dent 1 on [2, 4.5] x [1.5, 4], scratch 2 on [-6, -3.5] x [-5.5, -3], dent 3 on
/// [3, 8] x [-8, -3], half hidden under an occluding quad 3 mm above the plane (its edge
/// at x = 5.5, out of focus under the thin lens: partly covered pixels).
fn scene_mesh() -> Mesh {
    use common::region as r;
    common::labelled_plane(
        30.0,
        10.0,
        &[
            r([2.0, 4.5], [1.5, 4.0], 1, 1),
            r([-6.0, -3.5], [-5.5, -3.0], 2, 2),
            r([3.0, 8.0], [-8.0, -3.0], 1, 3),
        ],
        [
            Vec3::new(5.5, -14.0, 13.0),
            Vec3::new(14.0, -14.0, 13.0),
            Vec3::new(14.0, -1.0, 13.0),
            Vec3::new(5.5, -1.0, 13.0),
        ],
    )
}

/// View A0 of the plane at 48 x 40 pixels, 2 bounces; `f_number` None: pinhole.
fn config(f_number: Option<f64>, spp: u32, labels: LabelSource) -> SceneConfig {
    let mut cfg = SceneConfig::default();
    cfg.camera.view = "A0".into();
    cfg.camera.f_number = f_number;
    cfg.set_resolution(48, 40).expect("size");
    cfg.render.spp = spp;
    cfg.render.batch_spp = 16;
    cfg.render.max_bounces = 2;
    cfg.render.labels = labels;
    cfg.validate().expect("valid");
    cfg
}

/// One device, path tracer and GPU scene per backend for every render of a test.
struct Renderer(common::SceneRenderer);

impl Renderer {
    fn new(backend: Backend) -> Renderer {
        let cfg = config(None, 16, LabelSource::Pass);
        Renderer(common::SceneRenderer::new(backend, scene_mesh(), &cfg))
    }

    fn render(&self, cfg: &SceneConfig) -> Frame {
        self.0.render(cfg, true)
    }
}

/// The floats' bit patterns, for byte-for-byte comparisons.
fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|c| c.to_bits()).collect()
}

fn pixels(a: &Annotation, instance: u16) -> usize {
    a.instance.iter().filter(|&&i| i == instance).count()
}

/// (a) + (b): under a thin lens the labels from the samples are the pass's, bit for bit,
/// and the radiance is the same bytes; the scene has what makes this worth testing. Then
/// (d) on the same renderer: a first batch too short to hold the label samples.
#[test]
fn thin_lens_labels_from_samples_equal_the_pass_and_the_image_is_unchanged() {
    for backend in common::BACKENDS {
        let r = Renderer::new(backend);
        let pass = r.render(&config(Some(4.0), 16, LabelSource::Pass));
        let samples = r.render(&config(Some(4.0), 16, LabelSource::Samples));
        let auto = r.render(&config(Some(4.0), 16, LabelSource::Auto));
        assert!(!pass.labels_from_samples);
        assert!(samples.labels_from_samples && auto.labels_from_samples);
        let (a, b) = (
            pass.annotation.clone().unwrap(),
            samples.annotation.clone().unwrap(),
        );
        // The scene: all three defects seen, dent 3 partly hidden (its 5 x 5 mm is 4
        // times dent 1's 2.5 x 2.5 mm, half of it under the occluder), partly covered
        // pixels at the defects' edges and the occluder's blurred edge.
        let (d1, d2, d3) = (pixels(&a, 1), pixels(&a, 2), pixels(&a, 3));
        let partial = a.coverage.iter().filter(|&&c| c > 0.0 && c < 1.0).count();
        eprintln!(
            "{}: dent 1 {d1} px, scratch 2 {d2} px, dent 3 {d3} px, {partial} partly covered",
            backend.name()
        );
        assert!(d1 > 0 && d2 > 0 && d3 > 0);
        assert!(d3 < 3 * d1, "dent 3 must be partly hidden: {d3} vs {d1}");
        assert!(partial >= 20, "{partial} partly covered pixels");
        assert_eq!(a.class, b.class, "{}: class", backend.name());
        assert_eq!(a.instance, b.instance, "{}: instance", backend.name());
        assert_eq!(a.face, b.face, "{}: face", backend.name());
        assert_eq!(bits(&a.coverage), bits(&b.coverage), "{}", backend.name());
        assert_eq!(Some(&b), auto.annotation.as_ref());
        for f in [&samples, &auto] {
            assert_eq!(
                bits(&pass.radiance.data),
                bits(&f.radiance.data),
                "{}: radiance must not change",
                backend.name()
            );
        }
        short_first_batch(&r, backend);
    }
}

/// (d): a first batch of fewer samples than n x n (8 spp; 32 spp in batches of 4): the
/// path tracer traces the rest of the first 16 for their labels alone, so the labels
/// still come from its samples, equal to the pass's bit for bit under the thin lens, and
/// the image is the same bytes.
fn short_first_batch(r: &Renderer, backend: Backend) {
    for (spp, batch) in [(8, 16), (32, 4)] {
        let with = |labels| {
            let mut cfg = config(Some(4.0), spp, labels);
            cfg.render.batch_spp = batch;
            r.render(&cfg)
        };
        let (pass, samples) = (with(LabelSource::Pass), with(LabelSource::Samples));
        let what = format!("{}, {spp} spp in batches of {batch}", backend.name());
        assert!(
            !pass.labels_from_samples && samples.labels_from_samples,
            "{what}"
        );
        assert!(with(LabelSource::Auto).labels_from_samples, "{what}");
        let (a, b) = (pass.annotation.unwrap(), samples.annotation.unwrap());
        assert!(a.instance.iter().any(|&i| i != 0), "{what}: no defect seen");
        assert_eq!(bits(&a.coverage), bits(&b.coverage), "{what}: coverage");
        assert_eq!(a, b, "{what}: labels");
        assert_eq!(
            bits(&pass.radiance.data),
            bits(&samples.radiance.data),
            "{what}: radiance must not change"
        );
    }
}

/// (c): under a pinhole the samples (jittered Sobol points) are not the pass's rays
/// (centre ray, 4 x 4 grid). Asserted: ids equal wherever the pass's ids are the same
/// over the pixel's 3 x 3 neighbourhood, coverage equal wherever the pass's coverage is
/// 0 everywhere or 1 everywhere over it; the image is the same bytes.
#[test]
fn pinhole_labels_from_samples_agree_with_the_pass_away_from_label_edges() {
    let (w, h) = (48usize, 40usize);
    for backend in common::BACKENDS {
        let r = Renderer::new(backend);
        let pass = r.render(&config(None, 16, LabelSource::Auto));
        let samples = r.render(&config(None, 16, LabelSource::Samples));
        assert!(
            !pass.labels_from_samples,
            "auto keeps the pass under a pinhole"
        );
        assert!(samples.labels_from_samples);
        let (a, b) = (pass.annotation.unwrap(), samples.annotation.unwrap());
        let id = |x: &Annotation, i: usize| (x.face[i], x.class[i], x.instance[i]);
        let (mut interior, mut differ) = (0, 0);
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let i = y * w + x;
                let around = (0..9).map(|k| (y + k / 3 - 1) * w + x + k % 3 - 1);
                if around.clone().all(|j| id(&a, j) == id(&a, i)) {
                    interior += 1;
                    assert_eq!(id(&a, i), id(&b, i), "{}: pixel {x}, {y}", backend.name());
                }
                let cov: Vec<f32> = around.map(|j| a.coverage[j]).collect();
                if cov.iter().all(|&c| c == 0.0) || cov.iter().all(|&c| c == 1.0) {
                    assert_eq!(a.coverage[i], b.coverage[i], "{}: {x}, {y}", backend.name());
                }
                differ += (id(&a, i) != id(&b, i)) as usize;
            }
        }
        eprintln!(
            "{}: {interior} interior pixels agree, {differ} pixels at label edges differ",
            backend.name()
        );
        assert!(interior > w * h / 2);
        assert_eq!(bits(&pass.radiance.data), bits(&samples.radiance.data));
    }
}

/// (d): a wrong value names the field and the allowed values, in scene and job files.
#[test]
fn a_wrong_labels_value_is_rejected() {
    let e = SceneConfig::parse("[render]\nlabels = \"sample\"\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("labels") && e.contains("pass") && e.contains("samples"),
        "{e}"
    );
    for (text, want) in [
        ("labels = \"auto\"", Some(LabelSource::Auto)),
        ("labels = \"pass\"", Some(LabelSource::Pass)),
        ("labels = \"samples\"", Some(LabelSource::Samples)),
    ] {
        let c = SceneConfig::parse(&format!("[render]\n{text}\n")).unwrap();
        assert_eq!(Some(c.render.labels), want);
        let job = common::small_smoke_text().replace("[render]\n", &format!("[render]\n{text}\n"));
        let scenes = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"));
        let j = synosis::dataset::Job::parse(&job, "job", scenes).unwrap();
        assert_eq!(j.render.labels, want);
    }
    let job = common::small_smoke_text().replace("[render]\n", "[render]\nlabels = \"grid\"\n");
    let scenes = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"));
    let e = synosis::dataset::Job::parse(&job, "job", scenes)
        .unwrap_err()
        .to_string();
    assert!(e.contains("labels") && e.contains("samples"), "{e}");
}
