//! The example flange (scenes/flange.stl, scenes/flange.toml, scenes/flange-dataset.toml):
//! the shipped file is the generated part, its scene loads with the top annulus as face
//! A, and its dataset job (ring plan + look-at pose) renders on the GPU, records its
//! viewpoints and resumes.

mod common;

use std::path::Path;

use synosis::dataset::gpu::GpuRenderer;
use synosis::dataset::{self, RunOptions};
use synosis::scene::config::SceneConfig;
use synosis::scene::{Degenerates, FlangeParams, GltfUnitDefault, flange, load_mesh};
use synosis::trace::AccelChoice;

fn scenes() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"))
}

#[test]
fn shipped_flange_is_the_generated_part_and_its_scene_loads() {
    let generated = flange(&FlangeParams::default());
    let shipped = load_mesh(
        &scenes().join("flange.stl"),
        None,
        GltfUnitDefault::Spec,
        Degenerates::Reject,
    )
    .unwrap()
    .imported
    .mesh;
    assert_eq!(shipped.triangles.len(), generated.triangles.len());
    for t in 0..generated.triangles.len() {
        assert_eq!(shipped.corners(t), generated.corners(t), "triangle {t}");
    }
    let cfg = SceneConfig::load(&scenes().join("flange.toml")).unwrap();
    let (mesh, inspected) = synosis::scene::assemble::load_object_inspected(&cfg).unwrap();
    assert_eq!(inspected.len(), 1);
    assert_eq!(inspected[0].regions.len(), 1, "the top annulus only");
    let frames = synosis::scene::face_frames(&mesh);
    assert_eq!(frames.len(), 1);
    assert!((frames[0].normal.z - 1.0).abs() < 1e-6 && (frames[0].centre.z - 8.0).abs() < 1e-5);
}

#[test]
fn flange_job_renders_plans_and_poses_and_resumes() {
    let text = std::fs::read_to_string(scenes().join("flange-dataset.toml"))
        .unwrap()
        .replace("width = 64", "width = 32")
        .replace("height = 48", "height = 24")
        .replace("spp = 4", "spp = 1")
        .replace("defect_free = 2", "defect_free = 1");
    let prep = dataset::prepare_text(&text, "flange", scenes()).unwrap();
    // Both trace backends.
    for accel in [AccelChoice::RayQuery, AccelChoice::Software] {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join(format!("ds-{accel:?}"));
        let mut r = GpuRenderer::new(accel, true).unwrap();
        let mut run = || {
            let mut textures = synosis::dataset::texture_bridge::ModuleTextures::default();
            let opts = RunOptions::default();
            dataset::run(&prep, &out, &mut r, &mut textures, opts).unwrap()
        };
        assert_eq!(run().rendered, 4);
        let entries = dataset::read_manifest(&out.join("manifest.jsonl"), false).unwrap();
        let names: Vec<&str> = entries.iter().map(|e| e.viewpoint.as_str()).collect();
        assert_eq!(names, ["A20", "A20@120", "A20@240", "overview"]);
        assert!(entries[..3].iter().all(|e| e.pose.is_none()));
        assert!(
            entries[3]
                .pose
                .as_ref()
                .is_some_and(|p| p.look_at.is_some())
        );
        // Face A (the top annulus) is seen in every image; the ring views differ.
        for e in &entries {
            let faces = image::open(out.join(&e.faces)).unwrap().to_luma8();
            assert!(
                faces.pixels().any(|p| p.0[0] == 1),
                "{}: face A visible",
                e.viewpoint
            );
        }
        let img = |k: usize| {
            std::fs::read(
                out.join("images")
                    .join(format!("{k:06}"))
                    .join("radiance.exr"),
            )
            .unwrap()
        };
        assert!(img(0) != img(1));
        // Resumable: a second run renders nothing.
        assert_eq!(run().rendered, 0);
    }
}
