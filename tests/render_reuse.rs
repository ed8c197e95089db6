//! A dataset job builds the path tracer (pipelines, energy tables) once per process and
//! the GPU scene (acceleration structure, materials, labels) once per run of images of
//! the same mesh, not once per image. Its own test binary: the counters are per process.

mod common;

use synosis::dataset::gpu::GpuRenderer;
use synosis::dataset::{self, Shard};
use synosis::render::{GpuScene, PathTracer};
use synosis::trace::AccelChoice;

#[test]
fn a_job_builds_pipelines_once_and_each_mesh_once() {
    let tmp = tempfile::tempdir().unwrap();
    let (tracers0, scenes0) = (PathTracer::built_count(), GpuScene::built_count());
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
}
