//! The dataset job with the real GPU renderer (lavapipe in CI), both trace backends,
//! validation layers on: the smoke job's first images render, the annotation agrees
//! with the view, and the labels are consistent with the radiance.

use synosis::dataset::gpu::GpuRenderer;
use synosis::dataset::texture_bridge::ModuleTextures;
use synosis::dataset::{self, RunOptions, Shard};
use synosis::trace::AccelChoice;

fn smoke(accel: AccelChoice, name: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenes/smoke-dataset.toml"
    ))
    .unwrap()
    .replace("width = 64", "width = 32")
    .replace("height = 48", "height = 24")
    .replace("spp = 4", "spp = 1");
    let prep = dataset::prepare_text(&text, "smoke", tmp.path()).unwrap();
    // Both backends are required: tools/setup installs lavapipe with ray query.
    let mut r = GpuRenderer::new(accel, true).unwrap_or_else(|e| panic!("{e} (run tools/setup)"));
    let out = tmp.path().join(name);
    // Shard 0 of 4: the first instance's two views.
    let rep = dataset::run(
        &prep,
        &out,
        &mut r,
        &mut ModuleTextures::default(),
        RunOptions {
            shard: Shard { index: 0, count: 4 },
            fail_after: None,
            progress: None,
        },
    )
    .unwrap();
    assert_eq!(rep.rendered, 4);
    let entries = dataset::read_manifest(&out.join("manifests/shard-0-of-4.jsonl"), false).unwrap();
    for e in entries {
        assert!(e.renderer.starts_with("gpu-path-tracer"));
        let dir = out.join("images").join(&e.id);
        let faces = image::open(dir.join("faces.png")).unwrap().into_luma8();
        let face = e.viewpoint.as_bytes()[0] - b'A' + 1;
        let seen = faces.as_raw().iter().filter(|&&f| f == face).count();
        assert!(
            seen > faces.as_raw().len() / 4,
            "{}: face {face} covers {seen} px",
            e.id
        );
        let (_, _, rad) = synosis::image_io::read_exr_f32(&dir.join("radiance.exr")).unwrap();
        assert!(rad.iter().all(|v| v.is_finite() && *v >= 0.0));
        assert!(rad.iter().any(|v| *v > 0.0), "{}: black image", e.id);
    }
}

#[test]
fn smoke_job_renders_on_the_gpu_software_backend() {
    smoke(AccelChoice::Software, "sw");
}

#[test]
fn smoke_job_renders_on_the_gpu_ray_query_backend() {
    smoke(AccelChoice::RayQuery, "rq");
}
