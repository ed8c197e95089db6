//! Dataset job machinery: resume after a kill, shards merged equal the whole, splits,
//! bad job files, labels (COCO RLE, LabelMe polygons), the compare layout, re-running
//! the post-processing. Images come from a CPU *test double* renderer (below), not the
//! GPU renderer: these tests check the job machinery, not the pixels.

#[path = "common/files.rs"]
mod files;

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use glam::Vec3;
use synosis::dataset::renderer::{ImageRenderer, ImageRequest, RenderedImage, TextureMap};
use synosis::dataset::seed::splitmix64;
use synosis::dataset::textures::{TextureSource, TextureWant};
use synosis::dataset::{
    self, DatasetError, Finish, Job, Label, Prepared, RunOptions, Shard, Split, labels, post,
};
use synosis::scene::face_frames;

/// TEST DOUBLE, not a renderer: orthographic z-buffer rasterisation of the labelled
/// mesh along the view direction, with a "radiance" made from the face, the defect
/// class and the seed. Deterministic, so the job machinery can be compared bit for bit.
struct OrthoLabelTestDouble {
    calls: usize,
}

impl ImageRenderer for OrthoLabelTestDouble {
    fn describe(&self) -> String {
        "ortho-label-test-double".into()
    }

    fn render(&mut self, req: &ImageRequest) -> Result<RenderedImage, String> {
        self.calls += 1;
        let (w, h) = (req.width as usize, req.height as usize);
        let mesh = req.mesh;
        let face: u8 = match req.view.as_bytes()[0] {
            b'A' => 1,
            b'B' => 2,
            _ => 3,
        };
        let deg: f32 = req.view[1..].parse().map_err(|_| "bad view".to_string())?;
        let frame = *face_frames(mesh)
            .iter()
            .find(|f| f.face == face)
            .ok_or("face missing")?;
        let a = deg.to_radians();
        let d = (frame.normal * a.cos() + frame.v * a.sin()).normalize();
        let right = frame.u;
        let up = d.cross(right).normalize();
        let px = 30.0 / w as f32; // 30 mm across the image
        let proj = |p: Vec3| {
            let q = p - frame.centre;
            (
                q.dot(right) / px + w as f32 / 2.0,
                -q.dot(up) / px + h as f32 / 2.0,
                q.dot(d),
            )
        };
        let n = w * h;
        let mut zbuf = vec![f32::NEG_INFINITY; n];
        let mut out = RenderedImage {
            width: req.width,
            height: req.height,
            radiance: vec![0.0; n],
            class: vec![0; n],
            instance: vec![0; n],
            face: vec![0; n],
            coverage: vec![0.0; n],
            object: vec![0; n],
            pixel_spp: None,
        };
        for t in 0..mesh.triangles.len() {
            if mesh.area_normal(t).dot(d) <= 0.0 {
                continue;
            }
            let [p0, p1, p2] = mesh.corners(t).map(proj);
            let area = (p1.0 - p0.0) * (p2.1 - p0.1) - (p1.1 - p0.1) * (p2.0 - p0.0);
            if area.abs() < 1e-12 {
                continue;
            }
            let x0 = p0.0.min(p1.0).min(p2.0).floor().max(0.0) as usize;
            let x1 = (p0.0.max(p1.0).max(p2.0).ceil() as usize).min(w);
            let y0 = p0.1.min(p1.1).min(p2.1).floor().max(0.0) as usize;
            let y1 = (p0.1.max(p1.1).max(p2.1).ceil() as usize).min(h);
            let l = mesh.labels[t];
            for y in y0..y1 {
                for x in x0..x1 {
                    let (cx, cy) = (x as f32 + 0.5, y as f32 + 0.5);
                    let e = |a: (f32, f32, f32), b: (f32, f32, f32)| {
                        ((b.0 - a.0) * (cy - a.1) - (b.1 - a.1) * (cx - a.0)) / area
                    };
                    let (b0, b1, b2) = (e(p1, p2), e(p2, p0), e(p0, p1));
                    if b0 < 0.0 || b1 < 0.0 || b2 < 0.0 {
                        continue;
                    }
                    let z = b0 * p0.2 + b1 * p1.2 + b2 * p2.2;
                    let p = y * w + x;
                    if z > zbuf[p] {
                        zbuf[p] = z;
                        out.face[p] = l.face;
                        out.class[p] = l.class;
                        out.instance[p] = l.instance;
                        out.object[p] = 1;
                        out.coverage[p] = if l.class > 0 { 1.0 } else { 0.0 };
                        let jitter =
                            (splitmix64(req.seed ^ p as u64) >> 40) as f32 / (1u64 << 24) as f32;
                        out.radiance[p] = 0.15
                            + 0.1 * l.face as f32
                            + 0.3 * (l.class > 0) as u8 as f32
                            + 0.05 * jitter
                            + 0.2 * req.alpha;
                    }
                }
            }
        }
        Ok(out)
    }
}

/// TEST DOUBLE for the texture module: flat slope maps of the requested size.
struct FlatTexturesTestDouble {
    made: usize,
}

impl TextureSource for FlatTexturesTestDouble {
    fn make(
        &mut self,
        _f: &Finish,
        _i: u32,
        _s: u64,
        size: usize,
        spacing_um: f64,
    ) -> Result<TextureMap, String> {
        self.made += 1;
        Ok(TextureMap {
            width: size,
            height: size,
            spacing_um,
            data: vec![[0.0, 0.0]; size * size],
        })
    }
}

/// Large defects so they cover pixels at 64 x 48 over 30 mm.
const DEFECT_SPEC: &str = r#"
faces = ["A", "B", "C"]
resolution = 3
max_tries = 10000
[[dent]]
name = "big dent"
quantity = 3
diameter_mm = [2.0, 4.0]
elongation = [1.0, 1.5]
depth = [0.1, 0.2]
rotation_deg = [0.0, 180.0]
rim_height = [0.0, 0.0]
rim_width = 0.5
[[scratch]]
name = "wide scratch"
quantity = 1
width_mm = [1.0, 1.5]
depth = [0.05, 0.1]
path_length_mm = [6.0, 10.0]
step_mm = 1.0
curviness_deg = [0.0, 10.0]
depth_variation = 0.2
"#;

const POST: &str = r#"
[[postprocess]]
step = "linear"
by_type = { sandblasted = [0.632, 34.0], parallel = [1.481, 39.0] }
[[postprocess]]
step = "defocus"
[[postprocess]]
step = "background_noise"
amplitude = 5.0
[[postprocess]]
step = "blooming"
[[postprocess]]
step = "dilate_masks"
[[postprocess]]
step = "visibility_filter"
"#;

fn job_text(defective: i64, free: i64) -> String {
    format!(
        r#"
seed = 11
views = ["A0", "B10", "C20"]
[render]
width = 64
height = 48
spp = 1
bounces = 1
[texture]
size_px = 80
spacing_um = 400.0
cache = 2
[defects]
spec = "defects.toml"
[[finish]]
name = "sandblasted-2.5bar"
kind = "sandblasted"
textures = 2
exemplar = {{ pressure_bar = 2.5 }}
[[finish]]
name = "parallel-d4-ae0.5"
kind = "milled"
textures = 2
params = {{ path = "parallel", head_diameter_mm = 4.0, radial_depth = 0.5 }}
[[object]]
name = "body"
mesh = "testbody-b"
defective = {defective}
defect_free = {free}
{POST}"#
    )
}

/// [`job_text`] without its `[[postprocess]]` steps: image.png is the sensor's image.
fn job_text_without_postprocess(defective: i64, free: i64) -> String {
    job_text(defective, free)
        .split("[[postprocess]]")
        .next()
        .unwrap()
        .to_string()
}

struct Fixture {
    _tmp: tempfile::TempDir,
    root: PathBuf,
    prep: Prepared,
}

fn fixture(defective: i64, free: i64) -> Fixture {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().to_path_buf();
    std::fs::write(root.join("defects.toml"), DEFECT_SPEC).unwrap();
    let text = job_text(defective, free);
    std::fs::write(root.join("job.toml"), &text).unwrap();
    let prep = dataset::prepare(&root.join("job.toml")).unwrap();
    Fixture {
        _tmp: tmp,
        root,
        prep,
    }
}

fn run_all(
    f: &Fixture,
    out: &Path,
    shard: Shard,
    fail_after: Option<usize>,
) -> Result<dataset::RunReport, DatasetError> {
    dataset::run(
        &f.prep,
        out,
        &mut OrthoLabelTestDouble { calls: 0 },
        &mut FlatTexturesTestDouble { made: 0 },
        RunOptions {
            shard,
            fail_after,
            ..Default::default()
        },
    )
}

/// Each of `count` shards run into a folder of its own, `root/<prefix><i>`; the folders.
fn run_shard_folders(f: &Fixture, prefix: &str, count: usize) -> Vec<PathBuf> {
    let dirs: Vec<PathBuf> = (0..count)
        .map(|i| f.root.join(format!("{prefix}{i}")))
        .collect();
    for (index, d) in dirs.iter().enumerate() {
        run_all(f, d, Shard { index, count }, None).unwrap();
    }
    dirs
}

/// The id of the job's first image whose instance falls to `shard` of 3 shards.
fn image_of_shard(f: &Fixture, shard: usize) -> String {
    f.prep
        .plan
        .items
        .iter()
        .find(|it| it.instance % 3 == shard)
        .unwrap()
        .id()
}

/// Manifest lines without the timing fields.
fn manifest_without_times(dir: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(dir.join("manifest.jsonl"))
        .unwrap()
        .lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            let o = v.as_object_mut().unwrap();
            o.remove("finished_unix");
            o.remove("render_seconds");
            o.remove("stage_seconds");
            v
        })
        .collect()
}

/// Every file under images/ and coco/, by relative path, with its bytes.
fn tree(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    files::files_under(dir, &["images", "coco"])
}

fn assert_same_dataset(a: &Path, b: &Path) {
    assert_eq!(manifest_without_times(a), manifest_without_times(b));
    let (ta, tb) = (tree(a), tree(b));
    assert_eq!(ta.keys().collect::<Vec<_>>(), tb.keys().collect::<Vec<_>>());
    for (k, v) in &ta {
        assert!(v == &tb[k], "{k} differs");
    }
}

/// `RunOptions::limit` (`bench-gpu --consecutive`): the first images in the job's order,
/// the run left unfinished, and a later run without a limit ends in the same dataset as
/// one run of all.
#[test]
fn a_limited_run_renders_the_first_images_and_leaves_the_rest() {
    let f = fixture(2, 2);
    let total = f.prep.plan.items.len();
    let full = f.root.join("full");
    run_all(&f, &full, Shard::ALL, None).unwrap();
    let part = f.root.join("part");
    let mut seen = Vec::new();
    let mut progress = |done: usize, of: usize| seen.push((done, of));
    let r = dataset::run(
        &f.prep,
        &part,
        &mut OrthoLabelTestDouble { calls: 0 },
        &mut FlatTexturesTestDouble { made: 0 },
        RunOptions {
            limit: Some(7),
            progress: Some(&mut progress),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!((r.rendered, r.already_done, r.finished), (7, 0, false));
    assert_eq!(
        seen.last(),
        Some(&(7, 7)),
        "progress counts the limited run"
    );
    assert!(!part.join("manifest.jsonl").exists() && !part.join("coco").exists());
    let m = std::fs::read_to_string(part.join("manifests/shard-0-of-1.jsonl")).unwrap();
    let indices: Vec<u64> = m
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["index"]
                .as_u64()
                .unwrap()
        })
        .collect();
    assert_eq!(indices, (0..7).collect::<Vec<u64>>());
    // A limit past what is left renders what is left and finishes.
    let r = run_all_limited(&f, &part, Some(total));
    assert_eq!(
        (r.rendered, r.already_done, r.finished),
        (total - 7, 7, true)
    );
    assert_same_dataset(&full, &part);
}

fn run_all_limited(f: &Fixture, out: &Path, limit: Option<usize>) -> dataset::RunReport {
    dataset::run(
        &f.prep,
        out,
        &mut OrthoLabelTestDouble { calls: 0 },
        &mut FlatTexturesTestDouble { made: 0 },
        RunOptions {
            limit,
            ..Default::default()
        },
    )
    .unwrap()
}

#[test]
fn killed_run_resumes_to_the_same_dataset() {
    let f = fixture(2, 2);
    let total = f.prep.plan.items.len();
    assert_eq!(total, 2 * 4 * 3);
    let full = f.root.join("full");
    let r = run_all(&f, &full, Shard::ALL, None).unwrap();
    assert_eq!((r.rendered, r.already_done, r.finished), (total, 0, true));

    let res = f.root.join("resumed");
    match run_all(&f, &res, Shard::ALL, Some(5)) {
        Err(DatasetError::Interrupted { done: 5 }) => {}
        other => panic!("expected an interruption after 5 images, got {other:?}"),
    }
    assert!(
        !res.join("manifest.jsonl").exists(),
        "an unfinished run must not look finished"
    );
    // What a kill leaves: a temp file beside a half-made image, temporary COCO and
    // manifest files, and half a manifest line.
    std::fs::write(res.join("images/000005/.image.png.tmp-4242"), b"half").unwrap();
    std::fs::create_dir_all(res.join("coco")).unwrap();
    std::fs::write(res.join("coco/.train.json.tmp-4242"), b"{").unwrap();
    std::fs::write(res.join("manifests/.shard-0-of-1.jsonl.tmp-4242"), b"{").unwrap();
    let m = res.join("manifests/shard-0-of-1.jsonl");
    let mut text = std::fs::read_to_string(&m).unwrap();
    assert_eq!(text.lines().count(), 5);
    text.push_str("{\"index\": 5, \"id\": \"0000");
    std::fs::write(&m, text).unwrap();

    let r = run_all(&f, &res, Shard::ALL, None).unwrap();
    assert_eq!((r.already_done, r.rendered), (5, total - 5));
    assert_eq!(r.stray_temps_removed, 3);
    assert_same_dataset(&full, &res);
    // Nothing else is left behind: the folder holds exactly what a clean run's holds.
    assert_eq!(listing(&full), listing(&res));
    // A second run has nothing left to do.
    let r = run_all(&f, &res, Shard::ALL, None).unwrap();
    assert_eq!((r.already_done, r.rendered), (total, 0));
}

#[test]
fn shards_merged_equal_the_unsharded_run_and_single_images_remake() {
    let f = fixture(2, 1);
    let full = f.root.join("full");
    run_all(&f, &full, Shard::ALL, None).unwrap();
    let dirs: Vec<PathBuf> = (0..3).map(|i| f.root.join(format!("shard{i}"))).collect();
    let mut counted = 0;
    for (i, d) in dirs.iter().enumerate() {
        let r = run_all(&f, d, Shard { index: i, count: 3 }, None).unwrap();
        assert!(!r.finished);
        counted += r.rendered;
    }
    assert_eq!(counted, f.prep.plan.items.len());
    // Merging before all shards are there names what is missing.
    let err = dataset::merge(&dirs[..1]).unwrap_err().to_string();
    assert!(err.contains("not finished"), "{err}");
    let n = dataset::merge(&dirs).unwrap();
    assert_eq!(n, f.prep.plan.items.len());
    assert_same_dataset(&full, &dirs[0]);

    // Any single image can be re-made alone, identically.
    let one = f.root.join("one");
    let k = 7;
    let e = dataset::render_one(
        &f.prep,
        k,
        &one,
        &mut OrthoLabelTestDouble { calls: 0 },
        &mut FlatTexturesTestDouble { made: 0 },
    )
    .unwrap();
    let id = format!("{k:06}");
    for name in dataset::runner::IMAGE_FILES {
        let a = std::fs::read(full.join("images").join(&id).join(name)).unwrap();
        let b = std::fs::read(one.join("images").join(&id).join(name)).unwrap();
        assert!(a == b, "{name} of image {k} differs when made alone");
        assert!(e.files.contains_key(name));
    }
}

#[test]
fn an_image_remade_with_another_seed_keeps_its_scene_and_changes_its_noise() {
    let f = fixture(1, 1);
    let (a, b) = (f.root.join("a"), f.root.join("b"));
    let k = 3;
    let mut textures = FlatTexturesTestDouble { made: 0 };
    let ea = dataset::render_one(
        &f.prep,
        k,
        &a,
        &mut OrthoLabelTestDouble { calls: 0 },
        &mut textures,
    )
    .unwrap();
    let eb = dataset::render_one_seeded(
        &f.prep,
        k,
        Some(12345),
        &b,
        &mut OrthoLabelTestDouble { calls: 0 },
        &mut textures,
    )
    .unwrap();
    assert_eq!(eb.seed, 12345);
    assert_ne!(ea.seed, eb.seed);
    // The same instance, defects, textures and view: labels and placement equal.
    assert_eq!((&ea.instance, &ea.viewpoint), (&eb.instance, &eb.viewpoint));
    assert_eq!(ea.face_textures, eb.face_textures);
    let id = format!("{k:06}");
    let read = |d: &PathBuf, n: &str| std::fs::read(d.join("images").join(&id).join(n)).unwrap();
    for name in [
        "object.png",
        "faces.png",
        "raw_mask.png",
        "raw_instances.png",
    ] {
        assert!(
            read(&a, name) == read(&b, name),
            "{name} differs under another image seed"
        );
    }
    // Other random numbers: the radiance differs.
    assert!(read(&a, "radiance.exr") != read(&b, "radiance.exr"));
}

#[test]
fn splits_keep_instances_together_with_ratios_and_label_balance() {
    // The paper's job: 10 finishes x (30 + 30) instances x 9 views.
    let job = Job::load(Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenes/paper-dataset.toml"
    )))
    .unwrap();
    let plan = dataset::expand(&job);
    assert_eq!(plan.items.len(), 5400);
    assert_eq!(
        plan.items
            .iter()
            .filter(|i| plan.instances[i.instance].label == Label::Defective)
            .count(),
        2700
    );
    let mut counts: BTreeMap<(usize, Label, Split), usize> = BTreeMap::new();
    for inst in &plan.instances {
        *counts
            .entry((inst.finish, inst.label, inst.split))
            .or_default() += 1;
    }
    for fi in 0..10 {
        for label in [Label::Defective, Label::DefectFree] {
            let got: Vec<usize> = Split::ALL
                .iter()
                .map(|&s| counts.get(&(fi, label, s)).copied().unwrap_or(0))
                .collect();
            assert_eq!(got, vec![21, 3, 6], "finish {fi} {label:?}");
        }
    }
    // A defect geometry is in one split only, whatever the finish.
    let mut set_split: BTreeMap<usize, BTreeSet<Split>> = BTreeMap::new();
    for inst in &plan.instances {
        if let Some(s) = inst.defect_set {
            set_split.entry(s).or_default().insert(inst.split);
        }
    }
    assert_eq!(set_split.len(), 30);
    assert!(set_split.values().all(|s| s.len() == 1));
    // Seeds differ per image and do not depend on the item order.
    let seeds: BTreeSet<u64> = plan.items.iter().map(|i| i.seed).collect();
    assert_eq!(seeds.len(), 5400);

    // On a rendered set: all images of one instance in one split.
    let f = fixture(2, 2);
    let out = f.root.join("out");
    run_all(&f, &out, Shard::ALL, None).unwrap();
    let mut by_instance: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for v in manifest_without_times(&out) {
        by_instance
            .entry(v["instance"].as_str().unwrap().to_string())
            .or_default()
            .insert(v["split"].as_str().unwrap().to_string());
    }
    assert_eq!(by_instance.len(), 8);
    assert!(by_instance.values().all(|s| s.len() == 1));
}

#[test]
fn paper_job_uses_the_papers_roughness_and_spiral_exit_lines() {
    let job = Job::load(Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenes/paper-dataset.toml"
    )))
    .unwrap();
    assert_eq!(job.material.roughness, Some([0.05, 0.3]));
    assert_eq!(job.material.alpha, None);
    let spirals: Vec<_> = job
        .finishes
        .iter()
        .filter(|f| f.texture_type() == "spiral")
        .collect();
    assert_eq!(spirals.len(), 4);
    for f in spirals {
        let p: synosis::texture::MilledParams =
            toml::Value::Table(f.params.clone()).try_into().unwrap();
        assert!(p.spiral_exit_line, "{}", f.name);
    }
    // Re-based on the default camera (issue 12): the scene's camera written out with a
    // lens, the EMVA sensor with auto exposure and vertical blooming; no per-finish
    // exposure factors (auto exposure), no appleseed-fitted linear step, no post
    // defocus or threshold blooming (the lens and the sensor do both).
    let def = synosis::scene::config::CameraConfig::default();
    let c = &job.camera_config;
    assert_eq!(
        (
            c.width,
            c.height,
            c.pixel_um,
            c.focal_mm,
            c.working_distance_mm
        ),
        (
            def.width,
            def.height,
            def.pixel_um,
            def.focal_mm,
            def.working_distance_mm
        )
    );
    assert_eq!(c.f_number, Some(11.0));
    match &job.sensor.model {
        dataset::job::SensorModel::Emva(s) => {
            let d = synosis::scene::config::SensorConfig::default();
            assert_eq!(s.exposure, d.exposure, "auto");
            assert_eq!(s.blooming, synosis::scene::config::Blooming::Vertical);
            // Exposed so that the brightest 5 % of the object's pixels saturate (issue 11,
            // docs/benchmarks/realism.md "Sixth pass"), not the sensor's default rule.
            assert_eq!((s.auto_percentile, s.auto_fraction), (95.0, 1.0));
            assert_ne!((d.auto_percentile, d.auto_fraction), (95.0, 1.0));
            let s = synosis::scene::config::SensorConfig {
                blooming: d.blooming,
                auto_percentile: d.auto_percentile,
                auto_fraction: d.auto_fraction,
                ..s.clone()
            };
            assert_eq!(s, d, "the documented defaults otherwise");
        }
        m => panic!("{m:?}"),
    }
    assert!(job.finishes.iter().all(|f| f.exposure.is_none()));
    let steps: Vec<&str> = job.postprocess.iter().map(|s| s.name()).collect();
    assert_eq!(
        steps,
        ["background_noise", "dilate_masks", "visibility_filter"]
    );
}

#[test]
fn roughness_is_appleseed_r_and_alpha_is_ggx_alpha() {
    let base = job_text(1, 1);
    let params = |text: &str| {
        let job = Job::parse(text, "job", Path::new(".")).unwrap();
        let plan = dataset::expand(&job);
        dataset::plan::instance_params(&job, &plan.instances[0])
    };
    let r = params(&base.replace(
        "[texture]",
        "[material]\nroughness = [0.05, 0.3]\n[texture]",
    ));
    let a = params(&base.replace("[texture]", "[material]\nalpha = [0.05, 0.3]\n[texture]"));
    let d = params(&base);
    // Same draw, two readings: alpha = r^2 for `roughness`, the draw itself for `alpha`.
    assert!((0.05..=0.3).contains(&a.alpha));
    assert!((r.alpha - a.alpha * a.alpha).abs() < 1e-12, "{r:?} {a:?}");
    assert!((r.roughness - a.alpha).abs() < 1e-12);
    // No [material]: the paper's roughness.
    assert_eq!(d, r);
}

#[test]
fn bad_job_files_fail_before_rendering_naming_the_field() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("defects.toml"), DEFECT_SPEC).unwrap();
    let good = job_text(1, 1);
    assert!(dataset::prepare_text(&good, "job", tmp.path()).is_ok());
    let cases: Vec<(String, &str)> = vec![
        // What the renderer would refuse at the first image is refused by the check.
        (good.replace("bounces = 1", "bounces = 0"), "render.bounces"),
        (good.replace("width = 64", "width = 1"), "render.width"),
        (
            good.replace(
                "mesh = \"testbody-b\"",
                "mesh = \"testbody-b\"\nfinishes = [\"spiral-d8\"]",
            ),
            "object[0].finishes[0]",
        ),
        (
            good.replace("defective = 1", "defective = -3"),
            "object[0].defective",
        ),
        (
            good.replace("defect_free = 1", "defect_free = -1"),
            "object[0].defect_free",
        ),
        (
            good.replace("mesh = \"testbody-b\"", "mesh = \"nowhere.glb\""),
            "object[0].mesh",
        ),
        (
            good.replace(
                "[texture]",
                "[split]\ntrain = 0.7\nval = 0.2\ntest = 0.2\n[texture]",
            ),
            "train + val + test must sum to 1",
        ),
        (good.replace("spp = 1", "spp = 0"), "render.spp"),
        (
            good.replace("[\"A0\", \"B10\", \"C20\"]", "[\"A0\", \"D10\"]"),
            "views[1]",
        ),
        (
            good.replace("size_px = 80", "size_px = 40"),
            "texture.size_px",
        ),
        (
            good.replace("textures = 2\nparams", "textures = 0\nparams"),
            "finish[1].textures",
        ),
        (
            good.replace("parallel = [1.481, 39.0]", "spiral = [1.526, 33.0]"),
            "postprocess[0].by_type",
        ),
        (
            good.replace("step = \"defocus\"", "step = \"defocus\"\nradius = 20.0"),
            "postprocess[1].radius",
        ),
        (
            good.replace("step = \"blooming\"", "step = \"blooming\"\nwidht = 3"),
            "unknown field `widht`",
        ),
        (
            good.replace("seed = 11", "seed = 11\nspp = 4"),
            "unknown field `spp`",
        ),
        (
            good.replace("spec = \"defects.toml\"", "spec = \"missing.toml\""),
            "missing.toml",
        ),
        (
            good.replace(
                "[texture]",
                "[material]\nroughness = [0.1, 0.2]\nalpha = [0.01, 0.04]\n[texture]",
            ),
            "material.roughness / material.alpha",
        ),
        (
            good.replace("[texture]", "[material]\nroughness = [0.3, 0.1]\n[texture]"),
            "material.roughness[1]",
        ),
    ];
    let before = listing(tmp.path());
    for (text, want) in cases {
        let err = match dataset::prepare_text(&text, "job", tmp.path()) {
            Ok(_) => panic!("accepted a job that should fail on {want}"),
            Err(e) => e.to_string(),
        };
        assert!(err.contains(want), "error {err:?} does not name {want:?}");
        // Checking writes nothing.
        assert_eq!(listing(tmp.path()), before);
    }
}

#[test]
fn post_steps_match_hand_computed_cases() {
    // linear
    let v = post::linear(&[0.0, 100.0, 200.0], 0.632, 34.0);
    for (a, b) in v.iter().zip([34.0, 97.2, 160.4]) {
        assert!((a - b).abs() < 1e-4);
    }
    // defocus, radius 1 without alias blur: the 5-pixel plus, 1/5 each. On a 1 x 3 row
    // [0, 0, 10] with reflect-101 borders: x=2 sees itself three times (up, down,
    // centre) and x=1 twice -> 6; x=1 sees x=2 once -> 2.
    let k = post::defocus_kernel(1.0, 0.0);
    assert_eq!(k.side(), 3);
    assert_eq!(k.weights, vec![0.0, 0.2, 0.0, 0.2, 0.2, 0.2, 0.0, 0.2, 0.0]);
    let r = post::convolve(&[0.0, 0.0, 10.0], 3, 1, &k);
    assert!(
        (r[0] - 0.0).abs() < 1e-6 && (r[1] - 2.0).abs() < 1e-6 && (r[2] - 6.0).abs() < 1e-6,
        "{r:?}"
    );
    // With the 3x3 Gaussian (sigma 0.5: weights 0.106507, 0.786986, 0.106507), the
    // centre weight is 0.2 * (0.786986^2 + 4 * 0.786986 * 0.106507) = 0.190926.
    let k = post::defocus_kernel(1.0, 0.5);
    assert_eq!(k.side(), 5);
    assert!((k.weights[12] - 0.190926).abs() < 1e-5, "{}", k.weights[12]);
    assert!((k.weights.iter().sum::<f32>() - 1.0).abs() < 1e-5);
    // background noise: object untouched, background std = sigma
    let n = 200 * 200;
    let obj: Vec<u8> = (0..n).map(|i| (i % 2) as u8).collect();
    let img = vec![50.0f32; n];
    assert_eq!(post::background_noise(&img, &obj, 0.0, 1), img);
    let noisy = post::background_noise(&img, &obj, 3.0, 1);
    let bg: Vec<f32> = noisy
        .iter()
        .zip(&obj)
        .filter(|(_, o)| **o == 0)
        .map(|(v, _)| v - 50.0)
        .collect();
    assert!(noisy.iter().zip(&obj).all(|(v, o)| *o == 0 || *v == 50.0));
    let sd = (bg.iter().map(|x| x * x).sum::<f32>() / bg.len() as f32).sqrt();
    assert!((sd - 3.0).abs() < 0.05, "{sd}");
    // blooming: 4 x 2, column maxima [250, 100, 0, 255]; over 0.95 * 255: [250, 0, 0, 255].
    // Box 3 (columns x-1..x+1, reflect-101): [250, 250, 255, 255] / 3; x 0.06 ->
    // [5, 5, 5.1, 5.1] added to each column, clipped at 255.
    let b = post::blooming(
        &[250.0, 0.0, 0.0, 0.0, 0.0, 100.0, 0.0, 255.0],
        4,
        2,
        0.95 * 255.0,
        3,
        0.06,
    );
    let want = [255.0, 5.0, 5.1, 5.1, 5.0, 105.0, 5.1, 255.0];
    for (a, w) in b.iter().zip(want) {
        assert!((a - w).abs() < 1e-4, "{b:?}");
    }
    // dilation: instance 3 (dent) at (1,1), instance 1 (scratch) at (3,3) in 5 x 5; (2,2)
    // touches both and takes the smaller id.
    let mut inst = vec![0u16; 25];
    let mut class = vec![0u8; 25];
    inst[6] = 3;
    class[6] = 1;
    inst[18] = 1;
    class[18] = 2;
    let (c2, i2) = post::dilate_labels(&class, &inst, 5, 5);
    assert_eq!(i2[12], 1);
    assert_eq!(c2[12], 2);
    assert_eq!(i2.iter().filter(|&&i| i == 3).count(), 8); // 3x3 minus (2,2)
    assert_eq!(i2.iter().filter(|&&i| i == 1).count(), 9); // (2..=4)^2, (2,2) included
    // visibility: one defect pixel in a flat 7x7 field of 100; ring = 5x5 - 1 = 24 px.
    let mut img = vec![100.0f32; 49];
    let mut inst = vec![0u16; 49];
    inst[24] = 5;
    img[24] = 100.0 + 0.05 * 255.0 + 0.01;
    let v = post::visibilities(&img, &inst, 7, 7);
    assert!((v[&5] - (0.05 + 0.01 / 255.0)).abs() < 1e-6);
    let frame = |val: f32| {
        let mut img = vec![100.0f32; 49];
        img[24] = val;
        post::Frame {
            width: 7,
            height: 7,
            image: img,
            class: inst.iter().map(|&i| (i > 0) as u8).collect(),
            instance: inst.clone(),
            object: vec![1; 49],
        }
    };
    let steps = [post::PostStep::VisibilityFilter { threshold: 0.05 }];
    let kept = post::apply(&steps, "x", 0, frame(113.0));
    assert_eq!(kept.frame.instance[24], 5);
    assert!(kept.defects[0].kept);
    let dropped = post::apply(&steps, "x", 0, frame(112.0)); // 12 / 255 = 0.047 < 0.05
    assert_eq!(dropped.frame.instance[24], 0);
    assert_eq!(dropped.frame.class[24], 0);
    assert!(
        !dropped.defects[0].kept && (dropped.defects[0].visibility - 12.0 / 255.0).abs() < 1e-6
    );
    // quantize clamps and rounds
    assert_eq!(
        post::quantize(&[-3.0, 0.49, 0.5, 254.6, 300.0, f32::NAN]),
        vec![0, 0, 1, 255, 255, 0]
    );
}

fn blob_masks() -> Vec<(usize, usize, Vec<bool>)> {
    let mut v = Vec::new();
    // A pinch (two pixels touching at a corner, joined around), a ring (hole), random blobs.
    let (w, h) = (6, 5);
    let mut m = vec![false; w * h];
    for (x, y) in [(1, 1), (2, 2), (1, 2), (3, 2), (3, 1), (4, 1)] {
        m[y * w + x] = true;
    }
    v.push((w, h, m));
    // Parts one pixel wide: a lone pixel, a line, an L, a diagonal staircase (pinches).
    let (w, h) = (9, 7);
    let mut m = vec![false; w * h];
    for (x, y) in [
        (1, 1),
        (3, 1),
        (4, 1),
        (5, 1),
        (7, 1),
        (7, 2),
        (7, 3),
        (6, 3),
    ] {
        m[y * w + x] = true;
    }
    for k in 0..3 {
        m[(4 + k) * w + 1 + k] = true;
        m[(4 + k) * w + 2 + k] = true;
    }
    v.push((w, h, m));
    let mut s = 99u64;
    for _ in 0..20 {
        let (w, h) = (23, 17);
        let mut m = vec![false; w * h];
        for _ in 0..4 {
            s = splitmix64(s);
            let (cx, cy, r) = (
                (s % 23) as i64,
                ((s >> 8) % 17) as i64,
                1 + ((s >> 16) % 5) as i64,
            );
            for y in 0..h as i64 {
                for x in 0..w as i64 {
                    if (x - cx).pow(2) + (y - cy).pow(2) <= r * r + ((s >> 24) % 3) as i64 {
                        m[y as usize * w + x as usize] = true;
                    }
                }
            }
        }
        v.push((w, h, m));
    }
    v
}

/// LabelMe's `shape_to_mask` for a polygon: Pillow's `ImageDraw.polygon(xy, fill=1,
/// outline=1)`, which rounds the vertices to integers (`floor(v + 0.5)`), fills the
/// pixels whose centres are inside and draws the outline through the pixels on the
/// edges. Re-implemented here for rectilinear polygons (edges along x or y), the only
/// kind `trace_polygons` writes; a diagonal edge fails the test.
fn labelme_shape_to_mask(points: &[[f64; 2]], w: usize, h: usize, out: &mut [bool]) {
    let p: Vec<(i64, i64)> = points
        .iter()
        .map(|q| ((q[0] + 0.5).floor() as i64, (q[1] + 0.5).floor() as i64))
        .collect();
    let n = p.len();
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            let mut on_edge = false;
            let mut inside = false;
            for i in 0..n {
                let (a, b) = (p[i], p[(i + 1) % n]);
                assert!(a.0 == b.0 || a.1 == b.1, "diagonal edge {a:?} -> {b:?}");
                if (a.0.min(b.0)..=a.0.max(b.0)).contains(&x)
                    && (a.1.min(b.1)..=a.1.max(b.1)).contains(&y)
                {
                    on_edge = true;
                }
                // Even-odd crossing of the ray to +x at the pixel centre (half-open in y).
                if (a.1 > y) != (b.1 > y) && a.0 > x {
                    inside = !inside;
                }
            }
            if on_edge || inside {
                out[y as usize * w + x as usize] = true;
            }
        }
    }
}

/// The mask with its holes filled: background not 4-connected to the border (a
/// background pixel that reaches the outside only through a corner is a hole of the
/// polygon, which runs through that corner).
fn fill_holes(m: &[bool], w: usize, h: usize) -> Vec<bool> {
    let mut outside = vec![false; w * h];
    let mut stack: Vec<(i64, i64)> = Vec::new();
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            if (x == 0 || y == 0 || x == w as i64 - 1 || y == h as i64 - 1)
                && !m[y as usize * w + x as usize]
            {
                stack.push((x, y));
            }
        }
    }
    while let Some((x, y)) = stack.pop() {
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
            continue;
        }
        let i = y as usize * w + x as usize;
        if m[i] || outside[i] {
            continue;
        }
        outside[i] = true;
        for (dx, dy) in [(-1, 0), (1, 0), (0, -1), (0, 1)] {
            stack.push((x + dx, y + dy));
        }
    }
    outside.iter().map(|o| !o).collect()
}

/// The union over the 4-connected parts of `m` of each part with its holes filled
/// (what one polygon per part can describe).
fn components_with_holes_filled(m: &[bool], w: usize, h: usize) -> Vec<bool> {
    let mut seen = vec![false; w * h];
    let mut out = vec![false; w * h];
    for s in 0..w * h {
        if !m[s] || seen[s] {
            continue;
        }
        let mut part = vec![false; w * h];
        let mut stack = vec![s];
        while let Some(i) = stack.pop() {
            if !m[i] || seen[i] {
                continue;
            }
            seen[i] = true;
            part[i] = true;
            let (x, y) = (i % w, i / w);
            if x > 0 {
                stack.push(i - 1);
            }
            if x + 1 < w {
                stack.push(i + 1);
            }
            if y > 0 {
                stack.push(i - w);
            }
            if y + 1 < h {
                stack.push(i + w);
            }
        }
        for (o, f) in out.iter_mut().zip(fill_holes(&part, w, h)) {
            *o |= f;
        }
    }
    out
}

fn show(m: &[bool], w: usize) -> Vec<String> {
    m.chunks(w)
        .map(|r| r.iter().map(|&b| if b { '#' } else { '.' }).collect())
        .collect()
}

#[test]
fn coco_rle_and_labelme_polygons_give_back_the_masks() {
    for (w, h, m) in blob_masks() {
        let counts = labels::rle_counts(&m, w, h);
        let s = labels::rle_encode_string(&counts);
        let back = labels::rle_decode_string(&s).unwrap();
        assert_eq!(back, counts);
        assert_eq!(labels::rle_to_mask(&back, w, h).unwrap(), m);

        // LabelMe's shape_to_mask gives back each part exactly (holes filled), and so
        // does `synosis compare`'s reading of the polygons.
        let want = components_with_holes_filled(&m, w, h);
        let mut lm = vec![false; w * h];
        let mut filled = synosis::metrics::Mask::filled(w, h, false);
        for p in labels::trace_polygons(&m, w, h) {
            assert!(p.len() >= 3, "LabelMe needs 3 points or more");
            labelme_shape_to_mask(&p, w, h, &mut lm);
            filled.fill_polygon(&p);
        }
        assert_eq!(show(&lm, w), show(&want, w), "LabelMe's rasterisation");
        assert_eq!(
            show(&filled.data, w),
            show(&want, w),
            "compare's rasterisation"
        );
    }
}

#[test]
fn output_is_readable_by_compare_and_standard_label_formats() {
    let f = fixture(2, 1);
    let out = f.root.join("out");
    run_all(&f, &out, Shard::ALL, None).unwrap();
    let samples = synosis::metrics::dataset::load_dir(&out).unwrap();
    assert_eq!(samples.len(), f.prep.plan.items.len());
    assert_eq!(samples[0].id, "000000");
    assert_eq!(samples[0].texture(), "sandblasted");
    let face_labels: Vec<String> = ["A", "B", "C"].iter().map(|s| s.to_string()).collect();
    let mut defect_images = 0;
    for s in &samples {
        let face = (s.viewpoint.as_bytes()[0] - b'A') as usize;
        let masks = s.face_masks(&face_labels, &[face]).unwrap();
        assert!(
            masks[0].count() > 100,
            "{}: observed face covers {} px",
            s.id,
            masks[0].count()
        );

        let dir = out.join("images").join(&s.id);
        let mask = image::open(dir.join("mask.png")).unwrap().into_luma8();
        let inst = image::open(dir.join("instances.png"))
            .unwrap()
            .into_luma16();
        let (w, h) = (mask.width() as usize, mask.height() as usize);
        // COCO fragment: each annotation decodes to its instance's pixels.
        let coco: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("coco.json")).unwrap()).unwrap();
        for a in coco["annotations"].as_array().unwrap() {
            let id = a["instance"].as_u64().unwrap() as u16;
            let counts =
                labels::rle_decode_string(a["segmentation"]["counts"].as_str().unwrap()).unwrap();
            let m = labels::rle_to_mask(&counts, w, h).unwrap();
            let want: Vec<bool> = inst.as_raw().iter().map(|&i| i == id).collect();
            assert_eq!(m, want);
            assert_eq!(
                a["area"].as_u64().unwrap() as usize,
                want.iter().filter(|b| **b).count()
            );
        }
        // LabelMe: the dent polygons fill back to the dent mask (within 1 px at borders).
        let lm = synosis::metrics::labelme::LabelMe::load(&dir.join("labelme.json")).unwrap();
        let dents: Vec<bool> = mask.as_raw().iter().map(|&c| c == 1).collect();
        if dents.iter().any(|b| *b) {
            defect_images += 1;
            let filled = lm.face_mask(&dir.join("labelme.json"), "dent").unwrap();
            let differing = filled
                .data
                .iter()
                .zip(&dents)
                .filter(|(a, b)| a != b)
                .count();
            assert!(
                differing * 10 <= dents.iter().filter(|b| **b).count(),
                "{}: {differing} px differ",
                s.id
            );
        }
        let face_poly = lm
            .face_mask(&dir.join("labelme.json"), &face_labels[face])
            .unwrap();
        assert!(face_poly.count() >= masks[0].count());
    }
    assert!(defect_images > 0, "the test set should show some dents");
    // Dataset-level COCO per split, ids unique.
    let mut images = 0;
    for split in ["train", "val", "test"] {
        let v: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join("coco").join(format!("{split}.json"))).unwrap(),
        )
        .unwrap();
        images += v["images"].as_array().unwrap().len();
        let ids: BTreeSet<u64> = v["annotations"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| a["id"].as_u64().unwrap())
            .collect();
        assert_eq!(ids.len(), v["annotations"].as_array().unwrap().len());
    }
    assert_eq!(images, samples.len());
}

/// `dataset merge`'s progress: (step, entries verified, entries to verify): each merged
/// folder's images (rising to its own), then the finish's (rising to the whole job); the
/// same files as a merge without it.
#[test]
fn merge_reports_its_verification_progress() {
    use dataset::Verifying;
    let f = fixture(2, 1);
    let n = f.prep.plan.items.len();
    let rising = |calls: &[(Verifying, usize, usize)], step: Verifying, want: usize| {
        let of: Vec<(usize, usize)> = calls
            .iter()
            .filter(|c| c.0 == step)
            .map(|c| (c.1, c.2))
            .collect();
        assert_eq!(of.last(), Some(&(want, want)), "{step:?}: {calls:?}");
        assert!(
            of.windows(2).all(|w| w[0].0 < w[1].0 && w[0].1 == w[1].1),
            "{step:?}: {calls:?}"
        );
    };
    // One folder: the finish alone.
    let out = f.root.join("out");
    run_all(&f, &out, Shard::ALL, None).unwrap();
    let before = tree(&out);
    let mut calls = Vec::new();
    let mut progress = |v: Verifying, done: usize, total: usize| calls.push((v, done, total));
    let merged =
        dataset::merge_with_progress(std::slice::from_ref(&out), Some(&mut progress)).unwrap();
    assert_eq!(merged, n);
    assert!(calls.iter().all(|c| c.0 == Verifying::Finish), "{calls:?}");
    rising(&calls, Verifying::Finish, n);
    assert_eq!(tree(&out), before);
    // Two shards' folders: the second's images verified, then the finish.
    let dirs = run_shard_folders(&f, "s", 2);
    let second = dataset::read_manifest(&dirs[1].join("manifests/shard-1-of-2.jsonl"), false)
        .unwrap()
        .len();
    let mut calls = Vec::new();
    let mut progress = |v: Verifying, done: usize, total: usize| calls.push((v, done, total));
    assert_eq!(
        dataset::merge_with_progress(&dirs, Some(&mut progress)).unwrap(),
        n
    );
    let first_finish = calls.iter().position(|c| c.0 == Verifying::Finish).unwrap();
    assert!(
        calls[..first_finish]
            .iter()
            .all(|c| c.0 == Verifying::Merge)
    );
    rising(&calls, Verifying::Merge, second);
    rising(&calls, Verifying::Finish, n);
    assert_same_dataset(&out, &dirs[0]);
}

/// `dataset run`'s checks of the files already written report their progress (every
/// file of every image is read and hashed): a resumed run's check of the images the
/// killed one listed, then the finish's of the whole job, each rising to (n, n).
#[test]
fn a_resumed_run_reports_its_verification_progress() {
    use dataset::Verifying;
    let f = fixture(2, 1);
    let total = f.prep.plan.items.len();
    let out = f.root.join("out");
    match run_all(&f, &out, Shard::ALL, Some(5)) {
        Err(DatasetError::Interrupted { done: 5 }) => {}
        other => panic!("expected an interruption after 5 images, got {other:?}"),
    }
    let mut calls: Vec<(Verifying, usize, usize)> = Vec::new();
    let mut verifying = |v, done, of| calls.push((v, done, of));
    let r = dataset::run(
        &f.prep,
        &out,
        &mut OrthoLabelTestDouble { calls: 0 },
        &mut FlatTexturesTestDouble { made: 0 },
        RunOptions {
            verifying: Some(&mut verifying),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(
        (r.already_done, r.rendered, r.finished),
        (5, total - 5, true)
    );
    let step = |which: Verifying| -> Vec<(usize, usize)> {
        calls
            .iter()
            .filter(|c| c.0 == which)
            .map(|c| (c.1, c.2))
            .collect()
    };
    for (which, n) in [(Verifying::Resume, 5), (Verifying::Finish, total)] {
        let seen = step(which);
        assert_eq!(seen.last(), Some(&(n, n)), "{which:?}: {calls:?}");
        assert!(
            seen.windows(2).all(|w| w[0].0 < w[1].0 && w[0].1 == w[1].1),
            "{which:?}: {calls:?}"
        );
    }
    let first_finish = calls.iter().position(|c| c.0 == Verifying::Finish);
    assert!(
        calls[..first_finish.unwrap()]
            .iter()
            .all(|c| c.0 == Verifying::Resume),
        "the resume check comes before the finish: {calls:?}"
    );
}

/// A `postprocess` that fails on one image (its radiance.exr gone) returns that image's
/// error, and the manifest it leaves still describes every other image's files: the
/// processed images' new lines, the failed one's old line (nothing half-written).
#[test]
fn a_failed_postprocess_leaves_a_manifest_that_matches_the_files() {
    let f = fixture(1, 1);
    let out = f.root.join("out");
    run_all(&f, &out, Shard::ALL, None).unwrap();
    let manifest = out.join("manifests/shard-0-of-1.jsonl");
    let before = dataset::read_manifest(&manifest, false).unwrap();
    // Steps that change every image: none (the plain sensor image).
    let plain = job_text_without_postprocess(1, 1);
    let pj = f.root.join("plain.toml");
    std::fs::write(&pj, &plain).unwrap();
    std::fs::remove_file(out.join("images/000003/radiance.exr")).unwrap();
    let err = dataset::postprocess_dir(&out, Some(&pj))
        .unwrap_err()
        .to_string();
    assert!(err.contains("000003"), "{err}");
    let after = dataset::read_manifest(&manifest, false).unwrap();
    assert_eq!(after.len(), before.len());
    let mut changed = 0;
    for (a, b) in after.iter().zip(&before) {
        assert_eq!(a.index, b.index);
        if a.index == 3 {
            assert_eq!(a.files, b.files, "the failed image keeps its line");
            continue;
        }
        synosis::dataset::runner::verify_entry(&out, a)
            .unwrap_or_else(|e| panic!("image {}: {e}", a.index));
        changed += (a.files != b.files) as usize;
    }
    assert!(changed > 0, "no image was processed");
}

/// `dataset postprocess` re-runs the steps from the raw files: the same steps give the
/// same files, its progress rising to every image and then the finish's verification.
#[test]
fn postprocess_reruns_from_raw_files() {
    use dataset::Verifying;
    let f = fixture(1, 1);
    let out = f.root.join("out");
    run_all(&f, &out, Shard::ALL, None).unwrap();
    let before = tree(&out);
    let total = f.prep.plan.items.len();
    let mut done = Vec::new();
    let mut verified = Vec::new();
    let mut progress = |d: usize, t: usize| done.push((d, t));
    let mut verifying = |v: Verifying, d: usize, t: usize| verified.push((v, d, t));
    let n = dataset::postprocess_dir_with_progress(
        &out,
        None,
        Some(&mut progress),
        Some(&mut verifying),
    )
    .unwrap();
    assert_eq!(n, total);
    assert_eq!(done.last(), Some(&(total, total)), "{done:?}");
    assert!(done.windows(2).all(|w| w[0].0 < w[1].0), "{done:?}");
    assert_eq!(
        verified.last(),
        Some(&(Verifying::Finish, total, total)),
        "{verified:?}"
    );
    assert_eq!(
        before,
        tree(&out),
        "re-running the same steps must give the same files"
    );

    // Without post-processing steps, image.png is the plain sensor image.
    let plain = job_text_without_postprocess(1, 1);
    let pj = f.root.join("plain.toml");
    std::fs::write(&pj, &plain).unwrap();
    dataset::postprocess_dir(&out, Some(&pj)).unwrap();
    let entries = manifest_without_times(&out);
    let e = &entries[0];
    let img = image::open(out.join(e["image"].as_str().unwrap()))
        .unwrap()
        .into_luma8();
    let (_, _, rad) =
        synosis::image_io::read_exr_f32(&out.join("images/000000/radiance.exr")).unwrap();
    for (p, l) in img.as_raw().iter().zip(&rad) {
        assert_eq!(*p, (255.0 * l).clamp(0.0, 255.0).round() as u8);
    }
    assert_eq!(
        e["files"]["image.png"].as_str().unwrap(),
        dataset::files::content_hash(&std::fs::read(out.join("images/000000/image.png")).unwrap())
    );
    // Exposure is re-done from the stored radiance: a finish's `exposure` multiplies
    // `[sensor] exposure` for its images only.
    let finish = e["finish"].as_str().unwrap().to_string();
    let exposed = plain
        .replace(
            &format!("name = \"{finish}\"\n"),
            &format!("name = \"{finish}\"\nexposure = 0.5\n"),
        )
        .replace("[texture]", "[sensor]\nexposure = 3.0\n[texture]");
    assert_ne!(exposed, plain);
    std::fs::write(&pj, &exposed).unwrap();
    dataset::postprocess_dir(&out, Some(&pj)).unwrap();
    let mut seen = [false; 2];
    for e in manifest_without_times(&out) {
        let img = image::open(out.join(e["image"].as_str().unwrap()))
            .unwrap()
            .into_luma8();
        let id = e["id"].as_str().unwrap();
        let (_, _, rad) =
            synosis::image_io::read_exr_f32(&out.join(format!("images/{id}/radiance.exr")))
                .unwrap();
        let k = if e["finish"].as_str().unwrap() == finish {
            1.5
        } else {
            3.0
        };
        seen[(k == 1.5) as usize] = true;
        for (p, l) in img.as_raw().iter().zip(&rad) {
            assert_eq!(*p, (255.0 * k * l).clamp(0.0, 255.0).round() as u8, "{id}");
        }
    }
    assert_eq!(seen, [true, true], "both finishes rendered");
    // A job differing in more than its post-processing is refused.
    std::fs::write(&pj, plain.replace("seed = 11", "seed = 12")).unwrap();
    assert!(dataset::postprocess_dir(&out, Some(&pj)).is_err());
}

#[test]
fn texture_cache_is_bounded() {
    let mut cache = dataset::TextureCache::new(2);
    let mut src = FlatTexturesTestDouble { made: 0 };
    let job = Job::load(Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenes/smoke-dataset.toml"
    )))
    .unwrap();
    for round in 0..3 {
        for key in [(0usize, 0u32), (0, 1), (1, 0)] {
            let m = cache
                .get(key, || {
                    Ok(src.make(&job.finishes[key.0], key.1, 0, 8, 1.0).unwrap())
                })
                .unwrap();
            assert_eq!(m.width, 8);
            assert!(cache.len() <= 2, "round {round}");
        }
    }
    // LRU with 3 keys cycling through 2 slots misses every time.
    assert_eq!(src.made, 9);
    let mut cache = dataset::TextureCache::new(3);
    for _ in 0..3 {
        for k in 0..3u32 {
            cache
                .get((0, k), || {
                    Ok(src.make(&job.finishes[0], k, 0, 8, 1.0).unwrap())
                })
                .unwrap();
        }
    }
    assert_eq!(cache.made, 3);
}

/// Every path under `dir` (hidden files included), relative, sorted.
fn listing(dir: &Path) -> Vec<String> {
    let mut v = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            v.push(p.strip_prefix(dir).unwrap().to_string_lossy().into_owned());
            if p.is_dir() {
                stack.push(p);
            }
        }
    }
    v.sort();
    v
}

#[test]
fn resume_and_merge_verify_files_and_redo_what_differs() {
    let f = fixture(2, 1);
    let total = f.prep.plan.items.len();
    let full = f.root.join("full");
    run_all(&f, &full, Shard::ALL, None).unwrap();
    let res = f.root.join("res");
    run_all(&f, &res, Shard::ALL, None).unwrap();
    // One file deleted, one changed in place (same size), one truncated.
    std::fs::remove_file(res.join("images/000003/image.png")).unwrap();
    let p = res.join("images/000007/mask.png");
    let mut b = std::fs::read(&p).unwrap();
    let last = b.len() - 20;
    b[last] ^= 0x55;
    std::fs::write(&p, &b).unwrap();
    let p = res.join("images/000011/radiance.exr");
    let b = std::fs::read(&p).unwrap();
    std::fs::write(&p, &b[..b.len() / 2]).unwrap();
    let r = run_all(&f, &res, Shard::ALL, None).unwrap();
    assert_eq!((r.already_done, r.rendered), (total - 3, 3));
    assert_same_dataset(&full, &res);
    assert_eq!(listing(&full), listing(&res));
    // The manifest holds one line per image (bad lines dropped, not duplicated).
    let m = dataset::read_manifest(&res.join("manifests/shard-0-of-1.jsonl"), false).unwrap();
    assert_eq!(m.len(), total);

    // merge: a shard folder with a deleted file does not pass it on, and the error names
    // the shard that must run again; running that shard into the target finishes it.
    let dirs = run_shard_folders(&f, "s", 3);
    let victim = image_of_shard(&f, 1);
    std::fs::remove_file(dirs[1].join("images").join(&victim).join("coco.json")).unwrap();
    let err = dataset::merge(&dirs).unwrap_err().to_string();
    assert!(err.contains("1 of") && err.contains("--shard 1/3"), "{err}");
    let r = run_all(&f, &dirs[0], Shard { index: 1, count: 3 }, None).unwrap();
    assert_eq!(r.rendered, 1);
    dataset::merge(&dirs[..1]).unwrap();
    assert_same_dataset(&full, &dirs[0]);
}

/// A merge verifies each moved image as it moves, and its finish then reads again only
/// the images it did not move by a rename (docs/dataset.md, "Commands", merge): the target's own
/// images are still read, so a file of the target's own shard changed before the merge
/// is found, and the error names that shard.
#[test]
fn merge_still_verifies_the_targets_own_images() {
    let f = fixture(2, 1);
    let dirs = run_shard_folders(&f, "t", 3);
    let own = image_of_shard(&f, 0);
    let p = dirs[0].join("images").join(&own).join("mask.png");
    let mut b = std::fs::read(&p).unwrap();
    let last = b.len() - 20;
    b[last] ^= 0x55;
    std::fs::write(&p, &b).unwrap();
    let err = dataset::merge(&dirs).unwrap_err().to_string();
    assert!(err.contains("1 of") && err.contains("--shard 0/3"), "{err}");
    // The other shards' images moved in; shard 0 run again into the target finishes it.
    let r = run_all(&f, &dirs[0], Shard { index: 0, count: 3 }, None).unwrap();
    assert_eq!(r.rendered, 1);
    dataset::merge(&dirs[..1]).unwrap();
    let full = f.root.join("full");
    run_all(&f, &full, Shard::ALL, None).unwrap();
    assert_same_dataset(&full, &dirs[0]);
}

/// The finish reads the shard manifests line by line (docs/dataset.md, "Memory at
/// scale"): a line naming an image outside the job, or one that is not an entry, is an
/// error naming its manifest and line, and leaves the finished files as they were.
#[test]
fn a_bad_manifest_line_is_named_by_its_number_and_the_finish_writes_nothing() {
    let f = fixture(2, 1);
    let out = f.root.join("out");
    run_all(&f, &out, Shard::ALL, None).unwrap();
    let finished = || {
        let mut t = tree(&out);
        t.insert(
            "manifest.jsonl".into(),
            std::fs::read(out.join("manifest.jsonl")).unwrap(),
        );
        t
    };
    let before = finished();
    let path = out.join("manifests/shard-0-of-1.jsonl");
    let text = std::fs::read_to_string(&path).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert!(lines.len() >= 4, "{} lines", lines.len());
    let cases = [
        ("outside", {
            let mut v: serde_json::Value = serde_json::from_str(lines[2]).unwrap();
            v["index"] = serde_json::json!(999);
            v.to_string()
        }),
        ("malformed", "{\"index\": ".to_string()),
    ];
    for (what, bad) in cases {
        let mut edited: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
        edited[2] = bad;
        std::fs::write(&path, edited.join("\n") + "\n").unwrap();
        let err = dataset::merge(std::slice::from_ref(&out))
            .unwrap_err()
            .to_string();
        assert!(err.contains("shard-0-of-1.jsonl, line 3"), "{what}: {err}");
        if what == "outside" {
            assert!(err.contains("image 999 is not in the job"), "{err}");
        }
        assert!(finished() == before, "{what}: the finish wrote something");
        std::fs::write(&path, &text).unwrap();
    }
    // Restored, the finish writes the same files again.
    dataset::merge(std::slice::from_ref(&out)).unwrap();
    assert!(finished() == before);
}

#[test]
fn a_resubmitted_array_task_renders_only_what_is_missing() {
    // Slurm array of 4 into one folder; task 2 dies after one image; resubmitted alone
    // (`sbatch --array=2`), it sees a one-task array, i.e. the whole job.
    let f = fixture(2, 2);
    let total = f.prep.plan.items.len();
    let full = f.root.join("full");
    run_all(&f, &full, Shard::ALL, None).unwrap();
    let out = f.root.join("shared");
    let mut per_shard = 0;
    for i in [0, 1, 3] {
        per_shard = run_all(&f, &out, Shard { index: i, count: 4 }, None)
            .unwrap()
            .rendered;
    }
    assert!(matches!(
        run_all(&f, &out, Shard { index: 2, count: 4 }, Some(1)),
        Err(DatasetError::Interrupted { done: 1 })
    ));
    let r = run_all(&f, &out, Shard::ALL, None).unwrap();
    assert_eq!(
        (r.already_done, r.rendered),
        (total - per_shard + 1, per_shard - 1)
    );
    assert!(r.finished);
    assert_same_dataset(&full, &out);
}

#[test]
fn a_second_writer_is_refused_naming_the_holder() {
    use synosis::dataset::lock::{Access, lock};
    let f = fixture(1, 0);
    let out = f.root.join("out");
    std::fs::create_dir_all(out.join("manifests")).unwrap();
    let pid = std::process::id().to_string();
    {
        let _held = lock(&out, Access::Exclusive).unwrap();
        let err = run_all(&f, &out, Shard::ALL, None).unwrap_err();
        assert!(matches!(err, DatasetError::Locked { .. }), "{err}");
        assert!(err.to_string().contains(&format!("pid {pid}")), "{err}");
        let err = run_all(&f, &out, Shard { index: 1, count: 2 }, None).unwrap_err();
        assert!(matches!(err, DatasetError::Locked { .. }), "{err}");
    }
    {
        // Shards of one layout run side by side; the same shard twice does not, nor a
        // whole-job run or a merge beside a shard.
        let _held = lock(&out, Access::Shard(0, 2)).unwrap();
        run_all(&f, &out, Shard { index: 1, count: 2 }, None).unwrap();
        let err = run_all(&f, &out, Shard { index: 0, count: 2 }, None).unwrap_err();
        assert!(err.to_string().contains(&format!("pid {pid}")), "{err}");
        assert!(matches!(
            run_all(&f, &out, Shard::ALL, None),
            Err(DatasetError::Locked { .. })
        ));
        assert!(matches!(
            dataset::merge(std::slice::from_ref(&out)),
            Err(DatasetError::Locked { .. })
        ));
    }
    // Another process holding the lock, then killed (-9): the OS releases it.
    // (-o: the lock is held by flock itself, not by the `sleep` it runs.)
    let mut child = std::process::Command::new("flock")
        .arg("-o")
        .arg(out.join(synosis::dataset::lock::DIR_LOCK))
        .args(["sleep", "30"])
        .spawn()
        .expect("flock(1) from util-linux");
    let t0 = std::time::Instant::now();
    loop {
        match run_all(&f, &out, Shard::ALL, None) {
            Err(DatasetError::Locked { .. }) => break,
            other => {
                assert!(t0.elapsed().as_secs() < 10, "never locked: {other:?}");
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
        }
    }
    child.kill().unwrap();
    child.wait().unwrap();
    // flock's child (`sleep`) shares the lock's open file until it closes it before its
    // exec; on a loaded machine it may not have run that far when flock is killed (seen
    // once under load: the run right after the kill refused), and the lock goes when it
    // does: released within seconds, not after the 30 s of `sleep`.
    let t0 = std::time::Instant::now();
    let r = loop {
        match run_all(&f, &out, Shard::ALL, None) {
            Err(DatasetError::Locked { .. }) if t0.elapsed().as_secs() < 10 => {
                std::thread::sleep(std::time::Duration::from_millis(20))
            }
            other => break other.unwrap(),
        }
    };
    assert!(r.finished);
}

/// TEST DOUBLE: a renderer that always fails.
struct FailingRenderer;

impl ImageRenderer for FailingRenderer {
    fn describe(&self) -> String {
        "failing-test-double".into()
    }
    fn render(&mut self, _req: &ImageRequest) -> Result<RenderedImage, String> {
        Err("device lost (test double)".into())
    }
}

#[test]
fn a_run_failing_before_its_first_image_leaves_the_folder_as_found() {
    let f = fixture(1, 0);
    let run_failing = |out: &Path| {
        dataset::run(
            &f.prep,
            out,
            &mut FailingRenderer,
            &mut FlatTexturesTestDouble { made: 0 },
            RunOptions::default(),
        )
    };
    // A new folder: gone again.
    let new = f.root.join("new");
    let err = run_failing(&new).unwrap_err().to_string();
    assert!(err.contains("device lost"), "{err}");
    assert!(!new.exists());
    // An existing folder with a file of the user's: as it was.
    let old = f.root.join("old");
    std::fs::create_dir_all(&old).unwrap();
    std::fs::write(old.join("notes.txt"), "mine").unwrap();
    run_failing(&old).unwrap_err();
    assert_eq!(listing(&old), vec!["notes.txt".to_string()]);
    // And the next run is not refused.
    run_all(&f, &old, Shard::ALL, None).unwrap();
}

#[test]
fn shard_settings_from_the_environment_are_resolved_or_refused() {
    use synosis::dataset::shard_env::{ShardSource, resolve_shard};
    let env = |vars: &'static [(&'static str, &'static str)]| {
        move |n: &str| {
            vars.iter()
                .find(|(k, _)| *k == n)
                .map(|(_, v)| v.to_string())
        }
    };
    let ok = |shard: Option<&str>, count: Option<usize>, vars: &'static [(&str, &str)]| {
        resolve_shard(shard, count, &env(vars)).map(|(s, src)| (s.index, s.count, src))
    };
    // A stepped array, --array=0-6:2: tasks 0, 2, 4, 6 are shards 0..4.
    let stepped: &[(&str, &str)] = &[
        ("SLURM_ARRAY_TASK_ID", "4"),
        ("SLURM_ARRAY_TASK_MIN", "0"),
        ("SLURM_ARRAY_TASK_STEP", "2"),
        ("SLURM_ARRAY_TASK_COUNT", "4"),
    ];
    assert_eq!(ok(None, None, stepped), Ok((2, 4, ShardSource::Slurm)));
    // 1-based.
    let one_based: &[(&str, &str)] = &[
        ("SLURM_ARRAY_TASK_ID", "4"),
        ("SLURM_ARRAY_TASK_MIN", "1"),
        ("SLURM_ARRAY_TASK_COUNT", "4"),
    ];
    assert_eq!(ok(None, None, one_based), Ok((3, 4, ShardSource::Slurm)));
    assert_eq!(
        ok(None, Some(3), &[("JOB_COMPLETION_INDEX", "2")]),
        Ok((2, 3, ShardSource::Kubernetes))
    );
    assert_eq!(
        ok(Some("1/5"), None, stepped),
        Ok((1, 5, ShardSource::Flag))
    );
    assert_eq!(ok(None, None, &[]), Ok((0, 1, ShardSource::Whole)));
    // Refused, each naming what to do.
    type Vars = &'static [(&'static str, &'static str)];
    let refused: Vec<(Option<usize>, Vars, &str)> = vec![
        // A list array (--array=1,3,7): not evenly spaced.
        (
            None,
            &[
                ("SLURM_ARRAY_TASK_ID", "7"),
                ("SLURM_ARRAY_TASK_MIN", "1"),
                ("SLURM_ARRAY_TASK_COUNT", "3"),
            ],
            "--array=0-2",
        ),
        // Both Slurm and Kubernetes.
        (
            None,
            &[
                ("SLURM_ARRAY_TASK_ID", "1"),
                ("SLURM_ARRAY_TASK_COUNT", "4"),
                ("JOB_COMPLETION_INDEX", "1"),
            ],
            "ambiguous",
        ),
        // --shard-count without an index.
        (Some(4), &[], "without JOB_COMPLETION_INDEX"),
        (
            None,
            &[("SYNOSIS_SHARD_COUNT", "4")],
            "without JOB_COMPLETION_INDEX",
        ),
        // --shard-count on a Slurm task.
        (
            Some(4),
            &[
                ("SLURM_ARRAY_TASK_ID", "1"),
                ("SLURM_ARRAY_TASK_COUNT", "4"),
            ],
            "Slurm array task",
        ),
        (None, &[("JOB_COMPLETION_INDEX", "1")], "--shard-count"),
        (
            None,
            &[("SLURM_ARRAY_TASK_ID", "x")],
            "not a non-negative integer",
        ),
    ];
    for (count, vars, want) in refused {
        let e = ok(None, count, vars).unwrap_err();
        assert!(e.contains(want), "{vars:?}: {e:?} does not say {want:?}");
    }
    assert!(
        ok(Some("1/4"), Some(4), &[])
            .unwrap_err()
            .contains("together")
    );
}

/// A measurement named in a job: a milled finish is moment matched to it (after plane
/// levelling), a sandblasted finish synthesises from it; a missing file or a clash with
/// `exemplar` / `params.moments` fails naming the fields.
#[test]
fn measured_height_maps_drive_the_finishes() {
    use synosis::dataset::texture_bridge::ModuleTextures;
    use synosis::texture::{
        FormRemoval, HeightMap, SandblastParams, XyzUnit, generate_sandblasted, load_measurement,
        write_exr_height,
    };
    let tmp = tempfile::tempdir().unwrap();
    // A tilted plane (removed by levelling) plus bumps of Sq about 1.4 um.
    let mut m = HeightMap::new(96, 96, 2.0);
    for j in 0..96 {
        for i in 0..96 {
            let bumps = 2.0 * (i as f32 * 0.7).sin() * (j as f32 * 0.45).cos();
            m.data[j * 96 + i] = 40.0 + 0.5 * i as f32 - 0.3 * j as f32 + bumps;
        }
    }
    write_exr_height(&m, &tmp.path().join("scan.exr")).unwrap();
    let text = r#"
seed = 1
[render]
width = 8
height = 8
spp = 1
bounces = 1
[texture]
size_px = 64
spacing_um = 4.0
[[object]]
name = "o"
mesh = "testbody-b"
defective = 0
defect_free = 1
[[finish]]
name = "parallel-m"
kind = "milled"
textures = 1
params = { head_diameter_mm = 0.2, radial_depth = 0.5, delta_mm = 0.02 }
measurement = { path = "scan.exr", exr_spacing_um = 2.0 }
[[finish]]
name = "sandblasted-m"
kind = "sandblasted"
textures = 1
params = { patch_size = 32, overlap = 16 }
measurement = { path = "scan.exr", exr_spacing_um = 2.0 }
"#;
    let job = Job::parse(text, "job", tmp.path()).unwrap();
    let levelled = load_measurement(
        &tmp.path().join("scan.exr"),
        XyzUnit::M,
        2.0,
        FormRemoval::Plane,
    )
    .unwrap();
    let target = levelled.moments();
    assert!(
        target.mean_um.abs() < 1e-3 && (target.sq_um - 1.0).abs() < 0.1,
        "{target:?}"
    );
    let mut src = ModuleTextures::default();
    // Milled: the same map as with the levelled measurement's moments given by hand.
    let got = src.make(&job.finishes[0], 0, 5, 64, 4.0).unwrap();
    let mut by_hand = job.finishes[0].clone();
    by_hand.measurement = None;
    let mut moments = toml::Table::new();
    moments.insert("mean_um".into(), toml::Value::Float(target.mean_um));
    moments.insert("sq_um".into(), toml::Value::Float(target.sq_um));
    by_hand
        .params
        .insert("moments".into(), toml::Value::Table(moments));
    let want = ModuleTextures::default()
        .make(&by_hand, 0, 5, 64, 4.0)
        .unwrap();
    assert_eq!(got.data, want.data);
    // Sandblasted: synthesised from the levelled measurement.
    let got = src.make(&job.finishes[1], 0, 9, 64, 4.0).unwrap();
    let p = SandblastParams {
        patch_size: 32,
        overlap: 16,
        ..Default::default()
    };
    let want = generate_sandblasted(&levelled, &p, 64, 64, 4.0, 9, &synosis::texture::NoProgress)
        .unwrap()
        .slopes();
    assert_eq!(got.data, want.data);
    // Made side by side (`make_many`: one image's faces), from a fresh source (the
    // measurements loaded on the way): each the map `make` gives, in the order asked.
    let wants: Vec<TextureWant> = [(0, 5), (1, 9), (0, 6), (1, 10)]
        .into_iter()
        .map(|(f, seed)| TextureWant {
            finish: &job.finishes[f],
            instance: 0,
            seed,
            size_px: 64,
            spacing_um: 4.0,
        })
        .collect();
    let many = ModuleTextures::default().make_many(&wants);
    let mut one = ModuleTextures::default();
    for (w, got) in wants.iter().zip(many) {
        let want = one.make(w.finish, w.instance, w.seed, 64, 4.0).unwrap();
        assert_eq!(got.unwrap().data, want.data, "seed {}", w.seed);
    }
    // Errors name the fields.
    for (bad, want) in [
        (
            text.replace("path = \"scan.exr\", exr", "path = \"nope.exr\", exr"),
            "finish[0].measurement.path",
        ),
        (
            text.replace(
                "params = { patch_size = 32, overlap = 16 }",
                "params = { patch_size = 32, overlap = 16 }\nexemplar = { pressure_bar = 6.0 }",
            ),
            "finish[1].exemplar / finish[1].measurement",
        ),
        (
            text.replace(
                "delta_mm = 0.02 }",
                "delta_mm = 0.02, moments = { mean_um = 0.0, sq_um = 1.0 } }",
            ),
            "finish[0].params.moments / finish[0].measurement",
        ),
    ] {
        let e = Job::parse(&bad, "job", tmp.path()).unwrap_err().to_string();
        assert!(e.contains(want), "{e}");
    }
}

/// The realism report of a rendered folder: one page with every finish, example PNGs
/// beside it, and kept counts equal to the manifest's. The folder's report, read from its
/// manifest lines a batch at a time, reports its progress and equals the report of the
/// same entries held in memory (`dataset preview`'s), file for file; a shard manifest's
/// half last line (a run still appending) is left out.
#[test]
fn realism_report_summarises_a_dataset_folder() {
    use synosis::dataset::report::{folder_entries, write_folder_report, write_report};
    let f = fixture(2, 1);
    let out = f.root.join("out");
    run_all(&f, &out, Shard::ALL, None).unwrap();
    let entries = folder_entries(&out).unwrap();
    assert_eq!(entries.len(), f.prep.plan.items.len());
    let rdir = out.join("report");
    let mut seen = Vec::new();
    let mut progress = |done: usize, total: usize| seen.push((done, total));
    let reports = write_folder_report(&out, &f.prep.job, 2, &rdir, Some(&mut progress)).unwrap();
    let n = entries.len();
    assert_eq!(seen.last(), Some(&(n, n)), "{seen:?}");
    let in_memory = f.root.join("report-in-memory");
    let again = write_report(&out, &f.prep.job, &entries, 2, &in_memory).unwrap();
    let files = |d: &Path| files::files_under(d, &[""]);
    assert!(files(&rdir).contains_key("report.html"));
    assert_eq!(files(&rdir), files(&in_memory));
    assert_eq!(
        format!("{reports:?}"),
        format!("{again:?}"),
        "the folder's report and the in-memory one"
    );
    // From the shard manifests, one of them with a run's half-written last line.
    std::fs::remove_file(out.join("manifest.jsonl")).unwrap();
    let shard = std::fs::read_dir(out.join("manifests"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .find(|p| p.extension().is_some_and(|x| x == "jsonl"))
        .expect("a shard manifest");
    let mut text = std::fs::read_to_string(&shard).unwrap();
    text.push_str("{\"index\":0,\"id\":\"0000");
    std::fs::write(&shard, text).unwrap();
    assert_eq!(folder_entries(&out).unwrap().len(), n);
    let from_shards = f.root.join("report-from-shards");
    write_folder_report(&out, &f.prep.job, 2, &from_shards, None).unwrap();
    assert_eq!(files(&rdir), files(&from_shards));
    assert_eq!(reports.len(), f.prep.job.finishes.len());
    let html = std::fs::read_to_string(rdir.join("report.html")).unwrap();
    for r in &reports {
        assert!(html.contains(&r.name));
        assert_eq!(r.examples.len(), 2);
        for e in &r.examples {
            assert!(rdir.join(e).is_file(), "{e}");
            assert!(html.contains(e.as_str()));
        }
        let want: Vec<(u8, bool)> = entries
            .iter()
            .filter(|e| e.finish == r.name)
            .flat_map(|e| e.defects.iter().map(|d| (d.class, d.kept)))
            .collect();
        for class in [1u8, 2] {
            let n = want.iter().filter(|d| d.0 == class).count();
            let k = want.iter().filter(|d| d.0 == class && d.1).count();
            assert_eq!(r.kept(class), (k, n));
        }
        let pixels: u64 = r.histogram.iter().sum();
        assert!(pixels > 0 && r.p01_p99.0 <= r.p01_p99.1);
        // Per spec entry: the counts add up to the per-class ones.
        let by_kind: usize = r.kinds.values().map(|k| k.1).sum();
        assert_eq!(by_kind, r.kept(1).1 + r.kept(2).1);
    }
    // Every defect is named by the spec entry of its instance in the defect set.
    let mut named = 0;
    for e in &entries {
        let Some(k) = e.defect_set else { continue };
        for d in &e.defects {
            let want = f.prep.defect_sets[k]
                .defects
                .iter()
                .find(|x| x.instance == d.instance)
                .map(|x| x.name.clone());
            assert!(want.is_some(), "instance {} not in set {k}", d.instance);
            assert_eq!(d.kind, want);
            named += 1;
        }
    }
    assert!(named > 0, "the fixture has no visible defect");
    assert!(html.contains("<svg") && !html.contains("src=\"http"));
}

/// `[camera]` and the EMVA `[sensor]` in jobs: the scene file's fields and checks, errors
/// naming the field; the linear `exposure = <number>` stays the old model.
#[test]
fn job_camera_and_sensor_are_checked_like_a_scene_files() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("defects.toml"), DEFECT_SPEC).unwrap();
    let good = job_text(1, 1);
    let with = |extra: &str| good.replace("[texture]", &format!("{extra}\n[texture]"));
    // Old jobs: no [sensor], or a number, is the linear model.
    for text in [good.clone(), with("[sensor]\nexposure = 2")] {
        let job = dataset::prepare_text(&text, "job", tmp.path()).unwrap().job;
        assert!(matches!(
            job.sensor.model,
            dataset::job::SensorModel::Linear { .. }
        ));
        assert_eq!(job.sensor.exposure_jitter_ev, None);
    }
    let emva = with(
        "[camera]\nf_number = 8.0\n[sensor]\nexposure = \"auto\"\nbit_depth = 12\nblooming = \"vertical\"",
    );
    let job = dataset::prepare_text(&emva, "job", tmp.path()).unwrap().job;
    match &job.sensor.model {
        dataset::job::SensorModel::Emva(s) => {
            assert_eq!(s.bit_depth, 12);
            assert_eq!(s.quantum_efficiency, 0.6, "scene defaults for the rest");
        }
        m => panic!("{m:?}"),
    }
    assert_eq!(job.camera_config.f_number, Some(8.0));
    let target = emva.replace("spp = 1", "spp = 64\nnoise_target = 1.0\nmin_spp = 16");
    let job = dataset::prepare_text(&target, "job", tmp.path())
        .unwrap()
        .job;
    assert_eq!(job.render.noise_target, Some(1.0));
    assert_eq!(job.render.first_check_spp(), 16);
    assert_eq!(job.render.noise_estimate, None, "the default: halves");
    let samples = target.replace("min_spp = 16", "min_spp = 16\nnoise_estimate = \"samples\"");
    let job = dataset::prepare_text(&samples, "job", tmp.path())
        .unwrap()
        .job;
    assert_eq!(
        job.render.noise_estimate,
        Some(synosis::scene::config::NoiseEstimator::Samples)
    );
    let adaptive = target.replace("min_spp = 16", "min_spp = 16\nadaptive_radius = 4");
    let job = dataset::prepare_text(&adaptive, "job", tmp.path())
        .unwrap()
        .job;
    assert_eq!(job.render.adaptive_radius, Some(4));
    let growing = target.replace("min_spp = 16", "min_spp = 16\nnoise_target_growth = 0.5");
    let job = dataset::prepare_text(&growing, "job", tmp.path())
        .unwrap()
        .job;
    assert_eq!(job.render.noise_target_growth, Some(0.5));
    let chosen = target.replace(
        "min_spp = 16",
        "min_spp = 16\nanalytic_rays = 16\nanalytic_rays_max = 64\nanalytic_ray_cost = 0.05",
    );
    let job = dataset::prepare_text(&chosen, "job", tmp.path())
        .unwrap()
        .job;
    assert_eq!(job.render.analytic_rays_max, Some(64));
    assert_eq!(job.render.analytic_ray_cost, Some(0.05));
    let cases: Vec<(String, &str)> = vec![
        // `analytic_rays_max`: with a noise target, the analytic light, at least 2 rays
        // to start from and at most 64; its cost with it, in (0, 10].
        (
            emva.replace(
                "spp = 1",
                "spp = 64\nanalytic_rays = 4\nanalytic_rays_max = 16",
            ),
            "render.analytic_rays_max",
        ),
        (
            chosen.replace("analytic_rays = 16\n", "analytic_rays = 1\n"),
            "render.analytic_rays",
        ),
        (
            chosen.replace("analytic_rays = 16\n", ""),
            "render.analytic_rays",
        ),
        (
            chosen.replace("analytic_rays_max = 64", "analytic_rays_max = 8"),
            "render.analytic_rays_max",
        ),
        (
            chosen.replace("analytic_rays_max = 64", "analytic_rays_max = 65"),
            "render.analytic_rays_max",
        ),
        (
            chosen.replace(
                "analytic_rays = 16\n",
                "analytic_rays = 16\ndirect_light = \"sampled\"\n",
            ),
            "render.analytic_rays_max",
        ),
        (
            chosen.replace("analytic_ray_cost = 0.05", "analytic_ray_cost = 0.0"),
            "render.analytic_ray_cost",
        ),
        (
            chosen.replace("analytic_rays_max = 64\n", ""),
            "render.analytic_ray_cost",
        ),
        (
            with("[sensor]\nexposure = 1.0\nbit_depth = 12"),
            "linear model",
        ),
        (
            with("[camera]\nf_number = 8.0\n[sensor]\nbit_depth = 7"),
            "sensor.bit_depth",
        ),
        (
            with("[camera]\nf_number = 8.0\n[sensor]\nexposure = { ms = -1 }"),
            "sensor.exposure.ms",
        ),
        (
            with("[camera]\nf_number = 8.0\n[sensor]\ngian = 3"),
            "unknown field `gian`",
        ),
        (with("[sensor]\nexposure = \"auto\""), "camera.f_number"),
        // A noise target is relative to the camera's noise: the linear model has none.
        (
            good.replace("spp = 1", "spp = 1\nnoise_target = 1.0"),
            "render.noise_target",
        ),
        (
            emva.replace("spp = 1", "spp = 64\nnoise_target = 0.001"),
            "render.noise_target",
        ),
        (
            emva.replace("spp = 1", "spp = 64\nnoise_target = 1.0\nmin_spp = 128"),
            "render.min_spp",
        ),
        (
            emva.replace("spp = 1", "spp = 64\nmin_spp = 16"),
            "render.min_spp",
        ),
        (
            emva.replace("spp = 1", "spp = 64\nnoise_estimate = \"halves\""),
            "render.noise_estimate",
        ),
        (
            emva.replace("spp = 1", "spp = 64\nadaptive_radius = 4"),
            "render.adaptive_radius",
        ),
        (
            emva.replace(
                "spp = 1",
                "spp = 64\nnoise_target = 1.0\nadaptive_radius = 17",
            ),
            "render.adaptive_radius",
        ),
        (
            emva.replace("spp = 1", "spp = 64\nnoise_target_growth = 0.5"),
            "render.noise_target_growth",
        ),
        (
            emva.replace(
                "spp = 1",
                "spp = 64\nnoise_target = 1.0\nnoise_target_growth = 1.5",
            ),
            "render.noise_target_growth",
        ),
        (
            emva.replace("spp = 1", "spp = 64\nbatch_spp = 0"),
            "render.batch_spp",
        ),
        (
            emva.replace("spp = 1", "spp = 64\nbatch_spp = 1025"),
            "render.batch_spp",
        ),
        (
            emva.replace(
                "spp = 1",
                "spp = 64\nnoise_target = 1.0\nnoise_estimate = \"thirds\"",
            ),
            "unknown variant `thirds`",
        ),
        (with("[camera]\nf_number = 0.1"), "camera.f_number"),
        (with("[camera]\nview = \"A0\""), "camera.view"),
        (with("[camera]\nexposure = 2.0"), "camera.exposure"),
        (with("[camera]\npixel_um = 0"), "camera.pixel_um"),
        (with("[camera]\ncalibration = \"none.yaml\""), "none.yaml"),
        (
            with("[sensor]\nexposure_jitter_ev = [1.0, 0.5]"),
            "sensor.exposure_jitter_ev[1]",
        ),
        (
            with("[sensor]\nexposure_jitter_ev = [-20.0, 0.5]"),
            "sensor.exposure_jitter_ev[0]",
        ),
        (
            with("[sensor]\nexposure_jitter_ev = [0.0, 1.0]\nexposure_jitter_probability = 2"),
            "sensor.exposure_jitter_probability",
        ),
        (
            with("[sensor]\nexposure_jitter_probability = 0.5"),
            "only with sensor.exposure_jitter_ev",
        ),
    ];
    for (text, want) in cases {
        let err = match dataset::prepare_text(&text, "job", tmp.path()) {
            Ok(_) => panic!("accepted a job that should fail on {want}"),
            Err(e) => e.to_string(),
        };
        assert!(err.contains(want), "error {err:?} does not name {want:?}");
    }
}

/// The EMVA sensor and the random exposure in a job: recorded per image, drawn from the
/// image's seed, and re-done by `postprocess` from the stored radiance, bit for bit when
/// nothing changed.
#[test]
fn emva_sensor_and_random_exposure_rerun_from_raw_files() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    std::fs::write(root.join("defects.toml"), DEFECT_SPEC).unwrap();
    let text = job_text(1, 1).replace(
        "[texture]",
        "[camera]\nf_number = 8.0\n[sensor]\nexposure = \"auto\"\nexposure_jitter_ev = [-0.5, 1.5]\n[texture]",
    );
    std::fs::write(root.join("job.toml"), &text).unwrap();
    let prep = dataset::prepare(&root.join("job.toml")).unwrap();
    let out = root.join("out");
    let run = |out: &Path| {
        dataset::run(
            &prep,
            out,
            &mut OrthoLabelTestDouble { calls: 0 },
            &mut FlatTexturesTestDouble { made: 0 },
            RunOptions::default(),
        )
        .unwrap()
    };
    run(&out);
    let entries = dataset::read_manifest(&out.join("manifest.jsonl"), false).unwrap();
    let mut evs = BTreeSet::new();
    for e in &entries {
        let ev = e.exposure_ev.expect("recorded");
        assert!((-0.5..=1.5).contains(&ev), "{ev}");
        assert_eq!(
            Some(ev),
            dataset::camera::exposure_jitter_ev(&prep.job, e.seed)
        );
        evs.insert(ev.to_bits());
        assert!(e.exposure_ms.is_some_and(|t| t > 0.0));
        // The default camera at 64 x 48 (sensor size kept) with the job's lens.
        let c = e.camera.as_ref().unwrap();
        let pitch_mm = 6.9e-3 * 1224.0 / 64.0;
        assert!((c.fx - 25.0 / pitch_mm).abs() < 1e-3 * c.fx, "{c:?}");
        assert_eq!((c.width, c.height, c.cx, c.cy), (64, 48, 31.5, 23.5));
        assert_eq!(c.f_number, Some(8.0));
        assert_eq!(c.working_distance_mm, 90.0);
    }
    assert!(evs.len() > entries.len() / 2, "jitter varies per image");
    // Reproducible: another run into another folder gives the same files.
    let again = root.join("again");
    run(&again);
    assert_same_dataset(&out, &again);
    // Postprocess re-does exposure and noise from radiance.exr: bit for bit.
    let before = tree(&out);
    let n = dataset::postprocess_dir(&out, None).unwrap();
    assert_eq!(n, entries.len());
    assert_eq!(before, tree(&out), "postprocess must reproduce the run");
    assert_eq!(manifest_without_times(&out), manifest_without_times(&again));

    // Without the jitter the auto time is the same for every image's radiance, so the
    // jittered time is it times 2^ev: the jitter multiplies the auto-chosen time.
    let pj = root.join("new.toml");
    std::fs::write(&pj, text.replace("exposure_jitter_ev = [-0.5, 1.5]\n", "")).unwrap();
    dataset::postprocess_dir(&out, Some(&pj)).unwrap();
    let plain = dataset::read_manifest(&out.join("manifest.jsonl"), false).unwrap();
    for (a, b) in entries.iter().zip(&plain) {
        assert_eq!(b.exposure_ev, None);
        let (ta, tb) = (a.exposure_ms.unwrap(), b.exposure_ms.unwrap());
        let k = a.exposure_ev.unwrap().exp2();
        assert!((ta - tb * k).abs() <= 1e-12 * ta, "{ta} vs {tb} x {k}");
    }
    // A fixed exposure time changes the images and is recorded (0.002 ms: about 1000
    // electrons in the brightest pixels here, well under the auto time's 9000).
    let fixed = text
        .replace("exposure = \"auto\"", "exposure = { ms = 0.002 }")
        .replace("exposure_jitter_ev = [-0.5, 1.5]\n", "");
    std::fs::write(&pj, &fixed).unwrap();
    dataset::postprocess_dir(&out, Some(&pj)).unwrap();
    let after = tree(&out);
    for e in dataset::read_manifest(&out.join("manifest.jsonl"), false).unwrap() {
        assert_eq!(e.exposure_ms, Some(0.002));
        let k = format!("images/{}/image.png", e.id);
        assert_ne!(
            before[&k], after[&k],
            "{k} did not change with the exposure"
        );
    }
    // The linear model with the jitter: 255 * 2^ev * L per pixel.
    let linear = job_text_without_postprocess(1, 1)
        .replace(
            "[texture]",
            "[camera]\nf_number = 8.0\n[sensor]\nexposure = 1.0\nexposure_jitter_ev = [-0.5, 1.5]\n[texture]",
        );
    std::fs::write(&pj, &linear).unwrap();
    dataset::postprocess_dir(&out, Some(&pj)).unwrap();
    for e in dataset::read_manifest(&out.join("manifest.jsonl"), false).unwrap() {
        assert_eq!(e.exposure_ms, None);
        let k = e.exposure_ev.unwrap().exp2();
        let img = image::open(out.join(&e.image)).unwrap().into_luma8();
        let (_, _, rad) =
            synosis::image_io::read_exr_f32(&out.join(format!("images/{}/radiance.exr", e.id)))
                .unwrap();
        let scale = (1.0 * k) as f32;
        for (p, l) in img.as_raw().iter().zip(&rad) {
            assert_eq!(*p, (255.0 * scale * l).clamp(0.0, 255.0).round() as u8);
        }
    }
}

/// Runs the test job (one defective and one defect-free instance, no post-processing
/// steps: image.png is the sensor's image) with `sensor` (TOML lines of `[camera]` and
/// `[sensor]`) on the CPU test doubles, into `root`/out.
fn run_sensor_job(root: &Path, sensor: &str) -> (dataset::Prepared, PathBuf) {
    std::fs::write(root.join("defects.toml"), DEFECT_SPEC).unwrap();
    let text =
        job_text_without_postprocess(1, 1).replace("[texture]", &format!("{sensor}\n[texture]"));
    std::fs::write(root.join("job.toml"), &text).unwrap();
    let prep = dataset::prepare(&root.join("job.toml")).unwrap();
    let out = root.join("out");
    dataset::run(
        &prep,
        &out,
        &mut OrthoLabelTestDouble { calls: 0 },
        &mut FlatTexturesTestDouble { made: 0 },
        RunOptions::default(),
    )
    .unwrap();
    (prep, out)
}

/// An image's stored radiance.exr and faces.png, what the sensor step reads.
fn stored_radiance_and_faces(out: &Path, e: &dataset::ManifestEntry) -> (Vec<f32>, Vec<u8>) {
    let dir = out.join("images").join(&e.id);
    let (_, _, rad) = synosis::image_io::read_exr_f32(&dir.join("radiance.exr")).unwrap();
    let faces = image::open(dir.join("faces.png"))
        .unwrap()
        .into_luma8()
        .into_raw();
    (rad, faces)
}

/// A sensor deeper than 8 bit writes its codes unscaled into a 16-bit image.png (as
/// `synosis render` does), records `bit_depth` in the manifest, and `postprocess`,
/// the realism report and `compare`'s reader read it back at the right scale.
#[test]
fn deep_sensor_writes_16_bit_codes() {
    use synosis::dataset::report::write_folder_report;
    let tmp = tempfile::tempdir().unwrap();
    let (prep, out) = run_sensor_job(
        tmp.path(),
        "[camera]\nf_number = 8.0\n[sensor]\nexposure = \"auto\"\nbit_depth = 12\ngain_dn_per_electron = 0.4",
    );
    let entries = dataset::read_manifest(&out.join("manifest.jsonl"), false).unwrap();
    let mut fine = 0usize;
    for e in &entries {
        assert_eq!(e.bit_depth, Some(12));
        let dec = png::Decoder::new(std::io::BufReader::new(
            std::fs::File::open(out.join(&e.image)).unwrap(),
        ));
        let reader = dec.read_info().unwrap();
        assert_eq!(reader.info().bit_depth, png::BitDepth::Sixteen, "{}", e.id);
        let codes: Vec<u16> = image::open(out.join(&e.image))
            .unwrap()
            .into_luma16()
            .into_raw();
        // The sensor's own image, recomputed from the stored radiance and faces: its
        // 8-bit units are code * 255 / 4095, so every pixel is a whole code.
        let (rad, faces) = stored_radiance_and_faces(&out, e);
        let exposed = dataset::camera::expose(
            &prep.job,
            &e.finish,
            e.seed,
            e.camera.as_ref().unwrap(),
            &rad,
            &faces,
        )
        .unwrap();
        assert_eq!(exposed.exposure_ms, e.exposure_ms);
        for (&c, &u) in codes.iter().zip(&exposed.image) {
            assert!(c <= 4095, "code {c} above 12 bit");
            let want = u as f64 * 4095.0 / 255.0;
            assert!((want - c as f64).abs() < 1e-3, "code {c} vs {want}");
            fine += (c % 16 != 0) as usize;
        }
        // compare's reader: 4095 -> 255.
        let g = synosis::metrics::GrayImage::load_codes(&out.join(&e.image), e.bit_depth).unwrap();
        for (&c, &v) in codes.iter().zip(&g.data) {
            assert!((v as f64 - c as f64 * 255.0 / 4095.0).abs() < 1e-4);
        }
    }
    // More than 8 bits of the codes are used (not an 8-bit image scaled up).
    assert!(fine > 0, "every code is a multiple of 16");
    // Postprocess from radiance.exr reproduces the run bit for bit.
    let before = tree(&out);
    dataset::postprocess_dir(&out, None).unwrap();
    assert_eq!(before, tree(&out));
    // The report reads the 12-bit codes at 8-bit scale: its histogram reaches the top
    // decile (auto exposure puts the 99.5th percentile at 90 % of saturation).
    let reports = write_folder_report(&out, &prep.job, 1, &out.join("report"), None).unwrap();
    let top: u64 = reports
        .iter()
        .map(|r| r.histogram[200..].iter().sum::<u64>())
        .sum();
    assert!(top > 0, "the report read 12-bit codes as 8-bit values");
}

/// `[sensor] diffraction = true` in a job: the written image is the sensor step on the
/// radiance convolved with the lens's Airy pattern (`expose` with the job gives it back
/// from radiance.exr; without diffraction the same seed gives another image), the labels
/// are the geometry's, and `postprocess` reproduces the run bit for bit.
#[test]
fn diffraction_blurs_what_the_sensor_sees() {
    let tmp = tempfile::tempdir().unwrap();
    let (prep, out) = run_sensor_job(
        tmp.path(),
        "[camera]\nf_number = 16.0\n[sensor]\nexposure = \"auto\"\ndiffraction = true",
    );
    let mut plain = prep.job.clone();
    match &mut plain.sensor.model {
        dataset::job::SensorModel::Emva(s) => {
            assert!(s.diffraction);
            s.diffraction = false;
        }
        m => panic!("{m:?}"),
    }
    let entries = dataset::read_manifest(&out.join("manifest.jsonl"), false).unwrap();
    assert!(!entries.is_empty());
    for e in &entries {
        let codes = image::open(out.join(&e.image))
            .unwrap()
            .into_luma8()
            .into_raw();
        let (rad, faces) = stored_radiance_and_faces(&out, e);
        let expose = |job: &dataset::job::Job| {
            dataset::camera::expose(
                job,
                &e.finish,
                e.seed,
                e.camera.as_ref().unwrap(),
                &rad,
                &faces,
            )
            .unwrap()
        };
        let (on, off) = (expose(&prep.job), expose(&plain));
        assert_eq!(on.exposure_ms, e.exposure_ms);
        for (&c, &u) in codes.iter().zip(&on.image) {
            assert!((c as f32 - u).abs() < 1e-3, "code {c} vs {u}");
        }
        assert_ne!(on.image, off.image, "{}: diffraction changed nothing", e.id);
    }
    let before = tree(&out);
    dataset::postprocess_dir(&out, None).unwrap();
    assert_eq!(before, tree(&out));
}

/// Runs the whole job with `in_flight` images in flight (1: one after the other); the
/// progress calls it made.
fn run_in_flight(
    f: &Fixture,
    out: &Path,
    in_flight: usize,
    textures: &mut (dyn TextureSource + Send),
) -> (
    Result<dataset::RunReport, DatasetError>,
    Vec<(usize, usize)>,
) {
    run_lanes(f, out, in_flight, 1, None, None, textures)
}

/// As [`run_in_flight`] with `renderers` renderers (each an [`OrthoLabelTestDouble`],
/// failing on the image of seed `fail_seed` when given) and the `fail_after` test hook.
fn run_lanes(
    f: &Fixture,
    out: &Path,
    in_flight: usize,
    renderers: usize,
    fail_seed: Option<u64>,
    fail_after: Option<usize>,
    textures: &mut (dyn TextureSource + Send),
) -> (
    Result<dataset::RunReport, DatasetError>,
    Vec<(usize, usize)>,
) {
    let mut calls = Vec::new();
    let mut progress = |done: usize, total: usize| calls.push((done, total));
    let mut all: Vec<FailingAtTestDouble> = (0..renderers)
        .map(|_| FailingAtTestDouble {
            inner: OrthoLabelTestDouble { calls: 0 },
            seed: fail_seed,
        })
        .collect();
    let (first, more) = all.split_first_mut().expect("one renderer at least");
    let r = dataset::run(
        &f.prep,
        out,
        first,
        textures,
        RunOptions {
            progress: Some(&mut progress),
            in_flight,
            fail_after,
            more_renderers: more
                .iter_mut()
                .map(|r| r as &mut (dyn ImageRenderer + Send))
                .collect(),
            ..Default::default()
        },
    );
    (r, calls)
}

/// TEST DOUBLE: the [`OrthoLabelTestDouble`], failing on the image of one seed.
struct FailingAtTestDouble {
    inner: OrthoLabelTestDouble,
    seed: Option<u64>,
}

impl ImageRenderer for FailingAtTestDouble {
    fn describe(&self) -> String {
        self.inner.describe()
    }
    fn render(&mut self, req: &ImageRequest) -> Result<RenderedImage, String> {
        if Some(req.seed) == self.seed {
            return Err("device lost at this image (test double)".into());
        }
        self.inner.render(req)
    }
}

/// The shard manifest's image indices, in file order.
fn manifest_order(out: &Path) -> Vec<usize> {
    dataset::read_manifest(&out.join("manifests/shard-0-of-1.jsonl"), false)
        .unwrap()
        .iter()
        .map(|e| e.index)
        .collect()
}

#[test]
fn overlapped_runs_write_the_same_files_as_one_image_at_a_time() {
    let f = fixture(2, 2);
    let total = f.prep.plan.items.len();
    let one = f.root.join("one");
    let mut tex = FlatTexturesTestDouble { made: 0 };
    let (r, calls_one) = run_in_flight(&f, &one, 1, &mut tex);
    assert_eq!(r.unwrap().rendered, total);
    let made_one = tex.made;
    let want: Vec<(usize, usize)> = (1..=total).map(|k| (k, total)).collect();
    assert_eq!(calls_one, want);
    // With several renderers each takes the next image, on a thread of its own.
    for (in_flight, renderers) in [(2, 1), (4, 1), (2, 2), (3, 3)] {
        let out = f.root.join(format!("overlapped-{in_flight}-{renderers}"));
        let mut tex = FlatTexturesTestDouble { made: 0 };
        let (r, calls) = run_lanes(&f, &out, in_flight, renderers, None, None, &mut tex);
        let case = format!("in_flight {in_flight}, renderers {renderers}");
        assert_eq!(r.unwrap().rendered, total, "{case}");
        assert_same_dataset(&one, &out);
        assert_eq!(manifest_order(&out), manifest_order(&one), "{case}");
        assert_eq!(listing(&out), listing(&one), "{case}");
        // The progress counts written images, one call each, in order.
        assert_eq!(calls, want, "{case}");
        // The same texture cache misses (the inputs are made in the same order).
        assert_eq!(tex.made, made_one, "{case}");
    }
}

#[test]
fn a_render_error_or_a_kill_stops_a_run_of_several_renderers_as_it_stops_one() {
    let f = fixture(2, 2);
    let full = f.root.join("full");
    run_all(&f, &full, Shard::ALL, None).unwrap();
    // The 8th image fails to render, whichever renderer takes it.
    let seed = f.prep.plan.items[7].seed;
    let mut errors = Vec::new();
    for (in_flight, renderers) in [(1, 1), (3, 1), (3, 2), (2, 4)] {
        let case = format!("in_flight {in_flight}, renderers {renderers}");
        let out = f.root.join(format!("render-{in_flight}-{renderers}"));
        let mut tex = FlatTexturesTestDouble { made: 0 };
        let (r, calls) = run_lanes(&f, &out, in_flight, renderers, Some(seed), None, &mut tex);
        let err = r.unwrap_err();
        assert!(
            matches!(err, DatasetError::Render { .. }),
            "{case}: {err:?}"
        );
        errors.push(err.to_string());
        // The images before it are written and listed, none after it.
        assert_eq!(manifest_order(&out), (0..7).collect::<Vec<_>>(), "{case}");
        assert_eq!(calls.len(), 7, "{case}");
        let names = listing(&out);
        assert!(
            names.iter().all(|n| !n.contains(".tmp")),
            "{case}: {names:?}"
        );
        // Resumable: with a renderer that works it ends as an uninterrupted run.
        let (r, _) = run_lanes(&f, &out, in_flight, renderers, None, None, &mut tex);
        assert_eq!(r.unwrap().already_done, 7, "{case}");
        assert_same_dataset(&full, &out);
        // Killed after 5 images (the test hook): 5 listed, the run resumes.
        let out = f.root.join(format!("killed-{in_flight}-{renderers}"));
        let (r, _) = run_lanes(&f, &out, in_flight, renderers, None, Some(5), &mut tex);
        assert!(
            matches!(r, Err(DatasetError::Interrupted { done: 5 })),
            "{case}: {r:?}"
        );
        assert_eq!(manifest_order(&out), (0..5).collect::<Vec<_>>(), "{case}");
        let (r, _) = run_lanes(&f, &out, in_flight, renderers, None, None, &mut tex);
        assert_eq!(r.unwrap().already_done, 5, "{case}");
        assert_same_dataset(&full, &out);
    }
    assert!(errors.iter().all(|e| *e == errors[0]), "{errors:?}");
}

/// TEST DOUBLE: flat textures that fail from the `fail_at`-th make on.
struct FailingTexturesTestDouble {
    made: usize,
    fail_at: usize,
}

impl TextureSource for FailingTexturesTestDouble {
    fn make(
        &mut self,
        f: &Finish,
        i: u32,
        s: u64,
        size: usize,
        spacing_um: f64,
    ) -> Result<TextureMap, String> {
        self.made += 1;
        if self.made > self.fail_at {
            return Err("out of texture memory (test double)".into());
        }
        FlatTexturesTestDouble { made: 0 }.make(f, i, s, size, spacing_um)
    }
}

#[test]
fn a_failed_write_or_texture_stops_an_overlapped_run_as_it_stops_a_sequential_one() {
    let f = fixture(2, 2);
    let total = f.prep.plan.items.len();
    let full = f.root.join("full");
    run_all(&f, &full, Shard::ALL, None).unwrap();
    // An image file that cannot be written: a folder in its place.
    let blocked = |out: &Path| {
        let p = out.join("images/000004/mask.png");
        std::fs::create_dir_all(p.join("in-the-way")).unwrap();
        p
    };
    let mut errors = Vec::new();
    for in_flight in [1, 3] {
        let out = f.root.join(format!("write-{in_flight}"));
        let obstacle = blocked(&out);
        let (r, calls) =
            run_in_flight(&f, &out, in_flight, &mut FlatTexturesTestDouble { made: 0 });
        let err = r.unwrap_err();
        assert!(matches!(err, DatasetError::Io { .. }), "{err:?}");
        let msg = err.to_string();
        assert!(msg.contains("000004/mask.png"), "{msg}");
        errors.push(msg.replace(&format!("write-{in_flight}"), "OUT"));
        // The images before it are written and listed, none after it.
        assert_eq!(
            manifest_order(&out),
            vec![0, 1, 2, 3],
            "in_flight {in_flight}"
        );
        assert_eq!(calls.len(), 4);
        assert!(!out.join("manifest.jsonl").exists());
        // No temporary file is left. One at a time, no later image was started; with
        // writers in parallel a later one may be written whole, but is not listed (a
        // resume makes it again).
        let names = listing(&out);
        assert!(
            names.iter().all(|n| !n.contains(".tmp")),
            "in_flight {in_flight}: {names:?}"
        );
        if in_flight == 1 {
            assert!(!out.join("images/000005").exists());
        }
        // Resumable: with the obstacle gone it ends as an uninterrupted run.
        std::fs::remove_dir_all(&obstacle).unwrap();
        let (r, _) = run_in_flight(&f, &out, in_flight, &mut FlatTexturesTestDouble { made: 0 });
        assert_eq!(r.unwrap().already_done, 4);
        assert_same_dataset(&full, &out);
    }
    assert_eq!(errors[0], errors[1]);
    // A texture that cannot be made for a later instance: the earlier images are all
    // written and listed, in both modes, with the same error.
    let mut errors = Vec::new();
    let mut orders = Vec::new();
    for in_flight in [1, 3] {
        let out = f.root.join(format!("texture-{in_flight}"));
        let mut tex = FailingTexturesTestDouble {
            made: 0,
            fail_at: 2,
        };
        let (r, calls) = run_in_flight(&f, &out, in_flight, &mut tex);
        let err = r.unwrap_err();
        assert!(matches!(err, DatasetError::Texture { .. }), "{err:?}");
        errors.push(err.to_string());
        let order = manifest_order(&out);
        assert!(!order.is_empty() && order.len() < total, "{order:?}");
        assert_eq!(calls.len(), order.len());
        orders.push(order);
    }
    assert_eq!(errors[0], errors[1]);
    assert_eq!(orders[0], orders[1]);
}
