//! A dataset job builds the path tracer (pipelines, energy tables) once per process and
//! the GPU scene (acceleration structure, materials, labels) once per run of images of
//! the same mesh, not once per image; with images in flight and two renderers, each
//! mesh run's scene is made once (on the preparing thread) and uploaded by both. Its own
//! test binary: the counters are per process.

mod common;

use synosis::dataset::gpu::GpuRenderer;
use synosis::dataset::{self, Shard};
use synosis::render::{GpuScene, PathTracer, PreparedScene};
use synosis::trace::AccelChoice;

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
}
