//! A dataset job builds the path tracer (pipelines, energy tables) once per process and
//! the GPU scene (acceleration structure, materials, labels) once per run of images of
//! the same mesh, not once per image; with images in flight and two renderers, each
//! mesh run's scene is made once (on the preparing thread) and uploaded by both. Its own
//! test binary: the counters are per process.

mod common;

use std::sync::Arc;

use synosis::dataset::gpu::GpuRenderer;
use synosis::dataset::{self, Shard};
use synosis::render::device_maps::{self, SharedMapError};
use synosis::render::slope::{self, SlopeMap};
use synosis::render::{GpuScene, PathTracer, PreparedScene};
use synosis::trace::AccelChoice;
use synosis::vk::{Context, ContextOptions};

#[test]
fn a_job_builds_pipelines_once_and_each_mesh_once() {
    let tmp = tempfile::tempdir().unwrap();
    let (tracers0, scenes0) = (PathTracer::built_count(), GpuScene::built_count());
    let prepared0 = PreparedScene::prepared_count();
    let mut r = GpuRenderer::new(AccelChoice::Software, true).unwrap();
    let out = tmp.path().join("out");
    let rep = common::run_small_smoke(&mut r, &out, Shard { index: 0, count: 1 });
    assert_eq!(rep.rendered, 16);
    // Images of one mesh come one after the other: the views of a defective instance,
    // and every defect-free instance of a finish (the plain test body).
    let entries = dataset::read_manifest(&out.join("manifests/shard-0-of-1.jsonl"), false).unwrap();
    let keys: Vec<String> = entries
        .iter()
        .map(|e| match e.defect_set {
            Some(_) => e.instance.clone(),
            None => format!("{}/{}", e.finish, e.object),
        })
        .collect();
    let runs = 1 + keys.windows(2).filter(|w| w[0] != w[1]).count();
    assert_eq!(runs, 6, "{keys:?}");
    assert_eq!(
        PathTracer::built_count() - tracers0,
        1,
        "pipelines built once"
    );
    assert_eq!(
        GpuScene::built_count() - scenes0,
        runs,
        "one GPU scene per mesh run"
    );
    // Images in flight with two renderers: the run's preparing thread makes each mesh
    // run's scene (stage and acceleration structure) once, ahead of its views, and both
    // renderers upload it: one made per mesh run however many renderers there are.
    assert_eq!(PreparedScene::prepared_count() - prepared0, runs);
    let (prepared1, scenes1) = (PreparedScene::prepared_count(), GpuScene::built_count());
    let mut beside = r.beside(1).unwrap();
    let more = beside
        .iter_mut()
        .map(|r| r as &mut (dyn dataset::ImageRenderer + Send))
        .collect();
    let out2 = tmp.path().join("out2");
    let rep = common::run_small_smoke_lanes(&mut r, more, &out2, Shard { index: 0, count: 1 }, 3);
    assert_eq!(rep.rendered, 16);
    assert_eq!(
        PreparedScene::prepared_count() - prepared1,
        runs,
        "one scene made per mesh run, not one per renderer"
    );
    let uploads = GpuScene::built_count() - scenes1;
    assert!(
        (runs..=2 * runs).contains(&uploads),
        "{uploads} GPU scenes for {runs} mesh runs on two renderers"
    );
    assert_eq!(
        PathTracer::built_count() - tracers0,
        2,
        "one more for the second renderer"
    );
    // The preparing thread's uploads of an image's maps: a map that cannot go up is
    // named by its index (the run names its face and texture).
    let prep = dataset::ImageRenderer::scene_prep(&r)
        .unwrap()
        .on_own_queue();
    let good = Arc::new(SlopeMap {
        width: 4,
        height: 2,
        spacing_um: 6.0,
        data: vec![[0.01, -0.02]; 8],
    });
    let mut bad = (*good).clone();
    bad.data[5][0] = f32::INFINITY;
    assert!(prep.upload_maps(&[&good]).is_ok());
    match prep.upload_maps(&[&good, &Arc::new(bad)]) {
        Err((1, m)) => assert!(m.contains("finite"), "{m}"),
        Err(e) => panic!("{e:?}"),
        Ok(_) => panic!("a slope that is not finite went up"),
    }
}

/// A slope map's texels go to a device once while scenes there use it: contexts beside one
/// another (one `VkDevice`) get the same buffer, another device its own; the words are
/// `slope::texel_words`', also through the staging copy of devices whose memory cannot
/// be mapped; the buffer is freed once no one holds it and made anew when asked again; a
/// map is known by identity, not by content; a slope that is not finite is an error.
#[test]
fn a_slope_map_is_uploaded_once_per_device() {
    let opts = ContextOptions {
        validation: true,
        ray_query: false,
    };
    let ctx = Context::new(&opts).unwrap();
    let beside = ctx.beside().unwrap();
    let other = Context::new(&opts).unwrap();
    let map = Arc::new(SlopeMap {
        width: 37,
        height: 5,
        spacing_um: 6.0,
        data: (0..185)
            .map(|i| [i as f32 * 0.01 - 0.9, (i % 7) as f32 * -0.03])
            .collect(),
    });
    let words = slope::texel_words(&map).unwrap();
    let a = device_maps::texels(&ctx, &map).unwrap();
    let b = device_maps::texels(&beside, &map).unwrap();
    assert!(
        Arc::ptr_eq(&a, &b),
        "contexts on one device share the buffer"
    );
    let c = device_maps::texels(&other, &map).unwrap();
    assert!(!Arc::ptr_eq(&a, &c), "another device has its own");
    assert_eq!(a.read::<u32>().unwrap(), words);
    assert_eq!(c.read::<u32>().unwrap(), words);
    let twin = Arc::new((*map).clone());
    let t = device_maps::texels(&ctx, &twin).unwrap();
    assert!(!Arc::ptr_eq(&a, &t), "another map with the same texels");
    let weak = Arc::downgrade(&a);
    drop((a, b));
    assert!(
        weak.upgrade().is_none(),
        "nothing keeps a buffer no scene holds"
    );
    let again = device_maps::texels(&ctx, &map).unwrap();
    assert_eq!(again.read::<u32>().unwrap(), words);
    // Where device memory cannot be mapped (discrete GPUs) the words go through a
    // staging buffer and a copy on the GPU.
    let staged = Arc::new((*map).clone());
    let s = device_maps::texels_via(&other, &staged, true).unwrap();
    assert_eq!(s.read::<u32>().unwrap(), words, "through a staging copy");
    let mut bad = (*map).clone();
    bad.data[100][1] = f32::NAN;
    let bad = Arc::new(bad);
    assert!(matches!(
        device_maps::texels(&ctx, &bad),
        Err(SharedMapError::NotFinite)
    ));
    drop((again, c, t, s));
    ctx.check_validation().unwrap();
    other.check_validation().unwrap();
}
