//! Running a job: preparation (everything checked before the first image), the resumable
//! per-shard loop, finishing (merged manifest, COCO per split), re-running the
//! post-processing, and re-making a single image.

use std::collections::{BTreeMap, BTreeSet};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use serde::{Deserialize, Serialize};
use serde_json::json;

use super::camera::{CameraRecord, Exposed, expose};
use super::coco;
use super::error::{DatasetError, Result};
use super::files;
use super::gpu::{MapsAhead, ScenePrep};
use super::job::{Job, builtin_variant};
use super::labels;
use super::lock;
use super::plan::{self, FaceChoice, InstancePlan, ItemPlan, Label, Plan, Split};
use super::post::{self, DefectVisibility, Frame};
use super::renderer::{FaceTexture, ImageRenderer, ImageRequest, RenderedImage, TextureMap};
use super::seed::{derive, name, tag};
use super::textures::{TextureCache, TextureSource, TextureWant, texture_error};
use crate::defect::{DefectSet, DefectSpec, imprint, imprint_traced, sample_defects};
use crate::render::PreparedScene;
use crate::render::path_trace::spp_map;
use crate::render::pixels::{quantise_units_deep, quantise_units8};
use crate::scene::assemble::Placement;
use crate::scene::materials::GltfMaterials;
use crate::scene::{Degenerates, Mesh, face_frames, testbody};
use crate::vk::Profiler;

/// A job with everything loaded and checked: meshes, defect sets, the plan.
pub struct Prepared {
    pub job: Job,
    /// The job file's text, copied into the output folder.
    pub job_text: String,
    pub plan: Plan,
    pub meshes: Vec<Mesh>,
    /// The glTF material of each triangle of `meshes[i]` when object i is a glTF file
    /// with materials (for `{ gltf_material = ... }` region selectors).
    pub gltf_materials: Vec<Option<GltfMaterials>>,
    pub defect_sets: Vec<DefectSet>,
}

/// Loads and checks a job file; nothing is rendered or written.
pub fn prepare(job_path: &Path) -> Result<Prepared> {
    let text = crate::limits::read_text(job_path).map_err(|e| DatasetError::io(job_path, e))?;
    let base = job_path.parent().unwrap_or(Path::new(".")).to_path_buf();
    prepare_text(&text, &job_path.display().to_string(), &base)
}

/// As [`prepare`], from the job's text; relative paths resolve against `base_dir`.
pub fn prepare_text(text: &str, origin: &str, base_dir: &Path) -> Result<Prepared> {
    let job = Job::parse(text, origin, base_dir)?;
    let mut meshes = Vec::new();
    let mut gltf_materials = Vec::new();
    for (i, o) in job.objects.iter().enumerate() {
        let (mesh, gltf) = match builtin_variant(&o.mesh) {
            Some(v) => (testbody(v), None),
            None => {
                let imported = crate::scene::load_mesh(
                    &job.resolve(&o.mesh),
                    o.unit,
                    crate::scene::GltfUnitDefault::Millimetres,
                    Degenerates::Drop,
                )
                .map_err(|source| DatasetError::Mesh {
                    object: o.name.clone(),
                    source,
                })?
                .imported;
                (imported.mesh, imported.materials)
            }
        };
        let mut mesh = mesh;
        if let Some(list) = &o.inspect {
            let field = |e: crate::scene::config::ConfigError| DatasetError::Field {
                file: job.origin.clone(),
                field: format!("object[{i}].inspect"),
                value: String::new(),
                allowed: e.to_string().replace("object.inspect: ", ""),
            };
            let sel = crate::scene::inspect::parse(list).map_err(field)?;
            crate::scene::inspect::apply(&mut mesh, &sel, &Default::default()).map_err(field)?;
        }
        check_texture_cover(&job, i, &mesh)?;
        check_region_materials(&job, i, &mesh, gltf.as_ref())?;
        meshes.push(mesh);
        gltf_materials.push(gltf);
    }
    let spec = if job.defects.spec == "paper" {
        DefectSpec::paper()
    } else {
        DefectSpec::load(&job.resolve(&job.defects.spec)).map_err(|source| {
            DatasetError::Defect {
                object: "(defects.spec)".into(),
                source,
            }
        })?
    };
    let any_defective = job.objects.iter().any(|o| o.defective > 0);
    let mut defect_sets = Vec::new();
    if any_defective {
        // Sampled once on the first object; re-applied to every object (face-local).
        for k in 0..job.defect_sets() {
            let seed = derive(job.seed, &[tag::DEFECT, k as u64]);
            let set =
                sample_defects(&meshes[0], &spec, seed).map_err(|source| DatasetError::Defect {
                    object: job.objects[0].name.clone(),
                    source,
                })?;
            defect_sets.push(set);
        }
        // Each set must fit each object that carries it: found now, not at image 4000.
        for (oi, o) in job.objects.iter().enumerate() {
            let used = (o.defective.max(0) as usize).min(defect_sets.len());
            for set in &defect_sets[..used] {
                imprint(&meshes[oi], set).map_err(|source| DatasetError::Defect {
                    object: o.name.clone(),
                    source,
                })?;
            }
        }
    }
    let plan = plan::expand(&job);
    check_render_settings(&job, &plan)?;
    Ok(Prepared {
        job,
        job_text: text.to_string(),
        plan,
        meshes,
        gltf_materials,
        defect_sets,
    })
}

/// An object's region materials select triangles of its mesh (a region id past the
/// last, a selector that chooses nothing, an unknown glTF material name are refused
/// now, as a scene file's are when its stage is built). Imprinted defects keep every
/// triangle's face label, region and glTF material, so what selects here selects on
/// each instance.
fn check_region_materials(
    job: &Job,
    object: usize,
    mesh: &Mesh,
    gltf: Option<&GltfMaterials>,
) -> Result<()> {
    use crate::scene::regions::{RegionTolerance, planar_regions, region_per_triangle};
    let entries = job.objects[object]
        .region_materials(
            object,
            crate::scene::config::MaterialConfig::default().alpha,
            job.scene_base().wavelength_nm(),
        )
        .map_err(|message| DatasetError::Parse {
            file: job.origin.clone(),
            message,
        })?;
    if entries.is_empty() {
        return Ok(());
    }
    let found = planar_regions(mesh, &RegionTolerance::default());
    let normals: Vec<glam::Vec3> = found.iter().map(|r| r.normal).collect();
    let region_of = region_per_triangle(mesh, &found);
    crate::scene::materials::assign(&entries, &mesh.labels, &normals, &region_of, gltf).map_err(
        |e| DatasetError::Parse {
            file: job.origin.clone(),
            message: e.to_string().replace(
                "material.region",
                &format!("object[{object}].material.region"),
            ),
        },
    )?;
    Ok(())
}

/// The renderer's own checks of each image's settings, run for every view and every
/// instance's roughness now, so `check` finds what the first image would fail on.
fn check_render_settings(job: &Job, plan: &Plan) -> Result<()> {
    let base = job.scene_base();
    let r = &job.render;
    let viewpoints = job.viewpoints();
    let mut cases = Vec::new();
    for (k, inst) in plan.instances.iter().enumerate() {
        let rough = plan::instance_params(job, inst).roughness;
        if k == 0 {
            cases.extend(viewpoints.iter().map(|v| (v, rough)));
        } else if let Some(v) = viewpoints.first() {
            cases.push((v, rough));
        }
    }
    for (vp, rough) in cases {
        let (view, pose) = match vp {
            super::job::Viewpoint::View(v) => (v.as_str(), None),
            super::job::Viewpoint::Pose(p) => (p.name.as_str(), Some(*p)),
        };
        super::renderer::render_config(
            &base,
            view,
            pose,
            r.width as u32,
            r.height as u32,
            r.spp as u32,
            r.bounces as u32,
            0,
            rough as f32,
        )
        .map_err(|message| DatasetError::Parse {
            file: job.origin.clone(),
            message: format!("{message} (the renderer's limit)"),
        })?;
    }
    Ok(())
}

/// The textures must cover each face whatever its rotation and translation.
fn check_texture_cover(job: &Job, object: usize, mesh: &Mesh) -> Result<()> {
    let frames = face_frames(mesh);
    if frames.is_empty() {
        return Err(DatasetError::Field {
            file: job.origin.clone(),
            field: format!("object[{object}].mesh"),
            value: job.objects[object].mesh.clone(),
            allowed: "a mesh with triangles labelled as inspected faces A, B or C".into(),
        });
    }
    let extent_mm = job.texture.size_px as f64 * job.texture.spacing_um / 1000.0;
    let r = job
        .mapping
        .rotation_deg
        .to_radians()
        .min(std::f64::consts::FRAC_PI_4);
    for f in frames {
        let (hu, hv) = (f.half_size.x as f64, f.half_size.y as f64);
        // Bounding box of the face rotated by up to r, plus the translation both ways.
        let need_u = 2.0 * (hu * r.cos() + hv * r.sin());
        let need_v = 2.0 * (hu * r.sin() + hv * r.cos());
        let shift_mm =
            2.0 * job.mapping.translation_px.for_face(f.face) * job.texture.spacing_um / 1000.0;
        let need = need_u.max(need_v) + shift_mm;
        if extent_mm + 1e-9 < need {
            let px = (need * 1000.0 / job.texture.spacing_um).ceil();
            return Err(DatasetError::Field {
                file: job.origin.clone(),
                field: "texture.size_px".into(),
                value: job.texture.size_px.to_string(),
                allowed: format!(
                    "textures of {extent_mm:.2} mm do not cover face {} of object {} ({need:.2} mm with rotation and translation): need size_px >= {px} at spacing_um = {}",
                    crate::scene::mesh::face_name(f.face),
                    job.objects[object].name,
                    job.texture.spacing_um
                ),
            });
        }
    }
    Ok(())
}

/// Which part of the work this process does: instances with `instance % count == index`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// "i/n".
    pub fn parse(s: &str) -> Option<Shard> {
        let (i, n) = s.split_once('/')?;
        let (index, count) = (i.trim().parse().ok()?, n.trim().parse().ok()?);
        (count > 0 && index < count).then_some(Shard { index, count })
    }

    /// The shard's manifest file name (`manifests/shard-i-of-n.jsonl`).
    pub fn file_name(&self) -> String {
        format!("shard-{}-of-{}.jsonl", self.index, self.count)
    }

    pub fn owns(&self, item: &ItemPlan) -> bool {
        item.instance % self.count == self.index
    }
}

/// One finished image, one line of the manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ManifestEntry {
    pub index: usize,
    pub id: String,
    /// Paths relative to the dataset folder (the layout `synosis compare` reads).
    pub image: String,
    pub faces: String,
    pub viewpoint: String,
    /// The free pose of a `[[pose]]` viewpoint (none for face-relative views, whose
    /// name is the view).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose: Option<super::job::JobPose>,
    pub finish: String,
    pub texture_type: String,
    pub split: Split,
    pub object: String,
    pub instance: String,
    pub label: Label,
    pub defect_set: Option<usize>,
    /// GGX alpha of the object's material.
    pub alpha: f64,
    /// appleseed / Disney roughness r = sqrt(alpha).
    pub roughness: f64,
    pub face_textures: Vec<FaceChoice>,
    pub seed: u64,
    pub width: u32,
    pub height: u32,
    /// Samples per pixel of this image (`[render] spp`, or fewer when
    /// `[render] noise_target` stopped the render earlier).
    pub spp: u32,
    pub bounces: u32,
    pub renderer: String,
    /// With `[render] noise_target`: the estimated render noise over the camera's own
    /// temporal noise at `spp` (rms of each over the object's pixels; src/render/noise.rs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_ratio: Option<f64>,
    /// With `[render] noise_target`: every check of the render, `[spp, ratio]` in order
    /// (the last is `spp`, `noise_ratio`): the estimated error per spp.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub noise_checks: Vec<(u32, f64)>,
    /// With `[render] adaptive_radius`: the mean samples per pixel (`spp` is then the
    /// most any pixel took).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_spp: Option<f64>,
    /// With `[render] analytic_rays_max`: the camera rays per sample of the analytic
    /// direct light's closed form the image chose at its first noise check for the
    /// samples after it (absent where it stopped at that check).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub analytic_rays: Option<u32>,
    pub noise_sigma: Option<f64>,
    /// The camera's intrinsics and lens at the image's resolution (OpenCV camera matrix
    /// and distortion; the pose is `viewpoint` / `pose`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraRecord>,
    /// The random exposure drawn for this image, EV stops (factor 2^ev;
    /// `[sensor] exposure_jitter_ev`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure_ev: Option<f64>,
    /// The EMVA 1288 sensor's exposure time of this image, ms (after auto exposure, the
    /// finish's factor and the jitter).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure_ms: Option<f64>,
    /// The bit depth of image.png's codes when it is deeper than 8 (an EMVA sensor of 10,
    /// 12 or 16 bit: a 16-bit PNG with the codes unscaled, 0 ..= 2^bit_depth - 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bit_depth: Option<u32>,
    pub defects: Vec<DefectVisibility>,
    /// File name -> content hash.
    pub files: BTreeMap<String, String>,
    /// File name -> size in bytes (resume and merge check it before the hash).
    #[serde(default)]
    pub sizes: BTreeMap<String, u64>,
    /// Timing: the only fields that differ between identical runs.
    pub finished_unix: u64,
    /// Wall time of the whole image (mesh, textures, render, post-processing, writing).
    pub render_seconds: f64,
    /// Wall time per stage: "defects" (imprinting the object instance's mesh, once per
    /// instance), "textures" (cache misses only), "render" (acceleration structure,
    /// path tracing, annotation, readback; the GPU renderer adds its parts as
    /// "render.acceleration", "render.path_trace_gpu", "render.annotate_gpu"), "write"
    /// (raw files, post-processing, writing).
    #[serde(default)]
    pub stage_seconds: BTreeMap<String, f64>,
}

/// Files under `images/<id>/`.
pub const IMAGE_FILES: [&str; 11] = [
    "radiance.exr",
    "raw_mask.png",
    "raw_instances.png",
    "object.png",
    "faces.png",
    "coverage.png",
    "image.png",
    "mask.png",
    "instances.png",
    "labelme.json",
    "coco.json",
];

pub struct RunOptions<'a> {
    pub shard: Shard,
    /// Test hook: after this many images, write the first file of the next one and stop
    /// with [`DatasetError::Interrupted`], as a kill would.
    pub fail_after: Option<usize>,
    /// Called after each image: (done in this shard, total in this shard).
    pub progress: Option<&'a mut dyn FnMut(usize, usize)>,
    /// Called while a run reads and hashes the files of images already written (every
    /// file of every image: what takes the time on a large dataset): (which check,
    /// entries verified, entries to verify), rising to (n, n).
    pub verifying: Option<&'a mut dyn FnMut(Verifying, usize, usize)>,
    /// Collects the run's timeline (`dataset run --profile`): each image and its stages
    /// on the thread that ran them, the renderer's CPU phases and GPU passes.
    pub profiler: Option<&'a Profiler>,
    /// Images in flight at once (`dataset run --in-flight`, default
    /// [`DEFAULT_IN_FLIGHT`]): 1 makes each image's inputs, renders and writes it one
    /// after the other on the calling thread; N >= 2 renders on the calling thread while
    /// N - 1 writer threads write the images rendered before and a preparing thread
    /// makes the next images' meshes and textures (at most one object instance ahead).
    /// The files and manifest are the same byte for byte (docs/dataset.md, "How a run
    /// is scheduled"). 0 is taken as 1.
    pub in_flight: usize,
    /// Renderers beside the one given to [`run`], each rendering on a thread of its own
    /// (with `in_flight` >= 2; one at a time uses the first only): every renderer takes
    /// the next image in the list's order, so on a GPU one renderer's CPU work (scene
    /// set-up, noise checks, read-back) runs while another's samples keep the GPU busy
    /// (`dataset run --renderers`). The files and manifest are the same byte for byte.
    pub more_renderers: Vec<&'a mut (dyn ImageRenderer + Send)>,
    /// At most this many of the shard's images still to do, the first in the job's
    /// order, then stop (`bench-gpu --consecutive`: a whole-job run's first object
    /// instances); a run that leaves images undone is not finished (no `manifest.jsonl`
    /// or `coco/`), and a later run without a limit goes on from there. None: all.
    pub limit: Option<usize>,
}

/// Which of a run's checks of the files already written [`RunOptions::verifying`] reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verifying {
    /// Before rendering: the images earlier runs listed in the folder's shard manifests,
    /// so that a resumed run renders only what is missing or differs.
    Resume,
    /// After the last image of a whole-job run: every image's files, before
    /// `manifest.jsonl` and `coco/` are written.
    Finish,
    /// `dataset merge`: the images of a folder merged into the target, before they are
    /// moved (then [`Verifying::Finish`] on the target).
    Merge,
}

/// A verification's progress callback: (the check, entries verified, entries to verify).
/// Its own lifetime, so that a caller's callback can be lent to one check after another.
type VerifyProgress<'a> = dyn FnMut(Verifying, usize, usize) + 'a;

impl Verifying {
    /// A few words for a progress bar.
    pub fn describe(self) -> &'static str {
        match self {
            Verifying::Resume => "checking earlier images",
            Verifying::Finish => "verifying all images",
            Verifying::Merge => "verifying a folder's images",
        }
    }
}

/// Images in flight by default: one rendering, two being written.
pub const DEFAULT_IN_FLIGHT: usize = 3;

impl Default for RunOptions<'_> {
    fn default() -> Self {
        RunOptions {
            shard: Shard::ALL,
            fail_after: None,
            progress: None,
            verifying: None,
            profiler: None,
            in_flight: DEFAULT_IN_FLIGHT,
            more_renderers: Vec::new(),
            limit: None,
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct RunReport {
    pub shard_items: usize,
    pub already_done: usize,
    pub rendered: usize,
    pub stray_temps_removed: usize,
    /// True when this run also wrote `manifest.jsonl` and the COCO files.
    pub finished: bool,
}

/// Renders this shard's unfinished images into `out`; with a single shard, finishes the
/// dataset too. Safe to kill at any moment and run again. An image counts as done when
/// any shard manifest in `out` lists it and its files still have the listed sizes and
/// hashes, whatever shard layout wrote it. A run that fails before its first image
/// leaves `out` as it found it.
pub fn run(
    prep: &Prepared,
    out: &Path,
    renderer: &mut dyn ImageRenderer,
    textures: &mut (dyn TextureSource + Send),
    opts: RunOptions,
) -> Result<RunReport> {
    if opts.shard.count == 0 || opts.shard.index >= opts.shard.count {
        return Err(DatasetError::layout(
            out,
            format!("bad shard {}/{}", opts.shard.index, opts.shard.count),
        ));
    }
    let before = Before::look(out);
    let mut rendered = 0;
    let mut created = Vec::new();
    let result = run_locked(
        prep,
        out,
        renderer,
        textures,
        opts,
        &mut rendered,
        &mut created,
    );
    if let Err(e) = &result
        && rendered == 0
        && !matches!(
            e,
            DatasetError::Interrupted { .. } | DatasetError::Locked { .. }
        )
    {
        before.restore(out, &created);
    }
    result
}

/// What `out` held before a run, to undo a run that fails before its first image.
struct Before {
    out: bool,
    job: bool,
    manifests: bool,
    images: bool,
    image_dirs: BTreeSet<std::ffi::OsString>,
}

impl Before {
    fn look(out: &Path) -> Before {
        let image_dirs = std::fs::read_dir(out.join("images"))
            .map(|rd| rd.flatten().map(|e| e.file_name()).collect())
            .unwrap_or_default();
        Before {
            out: out.exists(),
            job: out.join("job.toml").exists(),
            manifests: out.join("manifests").exists(),
            images: out.join("images").exists(),
            image_dirs,
        }
    }

    /// Best effort: removes what the run added (nothing else).
    fn restore(&self, out: &Path, shard_manifest_and_locks: &[PathBuf]) {
        if !self.out {
            let _ = std::fs::remove_dir_all(out);
            return;
        }
        for p in shard_manifest_and_locks {
            let _ = std::fs::remove_file(p);
        }
        if !self.job {
            let _ = std::fs::remove_file(out.join("job.toml"));
        }
        if let Ok(rd) = std::fs::read_dir(out.join("images")) {
            for e in rd.flatten() {
                if !self.image_dirs.contains(&e.file_name()) {
                    let _ = std::fs::remove_dir_all(e.path());
                }
            }
        }
        if !self.images {
            let _ = std::fs::remove_dir(out.join("images"));
        }
        if !self.manifests {
            let _ = std::fs::remove_dir(out.join("manifests"));
        }
    }
}

fn run_locked(
    prep: &Prepared,
    out: &Path,
    renderer: &mut dyn ImageRenderer,
    textures: &mut (dyn TextureSource + Send),
    mut opts: RunOptions,
    rendered: &mut usize,
    created: &mut Vec<PathBuf>,
) -> Result<RunReport> {
    let exclusive = opts.shard.count == 1;
    std::fs::create_dir_all(out.join("manifests")).map_err(|e| DatasetError::io(out, e))?;
    let access = if exclusive {
        lock::Access::Exclusive
    } else {
        lock::Access::Shard(opts.shard.index, opts.shard.count)
    };
    let _lock = lock::lock(out, access)?;
    created.extend(_lock.created.iter().cloned());
    claim_dir(out, &prep.job_text)?;
    let manifest_path = out.join("manifests").join(opts.shard.file_name());
    if !manifest_path.exists() {
        created.push(manifest_path.clone());
    }
    let mine: Vec<&ItemPlan> = prep
        .plan
        .items
        .iter()
        .filter(|i| opts.shard.owns(i))
        .collect();
    let wanted: BTreeSet<usize> = mine.iter().map(|i| i.index).collect();
    let mut verifying = opts.verifying.take();
    let done = verified_entries(
        out,
        &prep.plan,
        &wanted,
        Some(&manifest_path),
        None,
        Verifying::Resume,
        verifying.as_deref_mut(),
    )?
    .by_index;
    let mut stray = 0;
    if exclusive {
        stray += sweep_temps(out, None)?;
    } else {
        stray += sweep_temps(out, Some(&wanted))?;
    }
    let todo: Vec<&&ItemPlan> = mine
        .iter()
        .filter(|i| !done.contains_key(&i.index))
        .collect();
    let already = mine.len() - todo.len();
    let mut todo: Vec<&ItemPlan> = todo.into_iter().copied().collect();
    // Images this run leaves to a later one (RunOptions::limit).
    let left = todo.len().saturating_sub(opts.limit.unwrap_or(usize::MAX));
    todo.truncate(todo.len() - left);
    let total = mine.len() - left;
    if opts.in_flight <= 1 {
        let mut ctx = Ctx::new(prep, opts.profiler)?;
        for item in todo {
            if opts.fail_after == Some(*rendered) {
                return Err(interrupt(out, item, *rendered)?);
            }
            let entry = ctx.render_item(item, out, renderer, textures)?;
            append_line(&manifest_path, &entry)?;
            *rendered += 1;
            if let Some(p) = opts.progress.as_deref_mut() {
                p(already + *rendered, total);
            }
        }
    } else {
        let camera = image_camera_record(&prep.job)?;
        let mut progress = |done: usize| {
            if let Some(p) = opts.progress.as_deref_mut() {
                p(already + done, total);
            }
        };
        let overlapped = Overlapped {
            prep,
            out,
            camera: &camera,
            manifest: &manifest_path,
            profiler: opts.profiler,
            writers: opts.in_flight - 1,
        };
        overlapped.run(
            &todo,
            renderer,
            &mut opts.more_renderers,
            textures,
            opts.fail_after,
            &mut progress,
            rendered,
        )?;
    }
    let finished = exclusive && left == 0;
    if finished {
        finish_locked(out, verifying, None)?;
    }
    Ok(RunReport {
        shard_items: mine.len(),
        already_done: already,
        rendered: *rendered,
        stray_temps_removed: stray,
        finished,
    })
}

/// The `fail_after` test hook: what a kill in the middle of `item` leaves (one file in
/// place, no manifest line), as [`DatasetError::Interrupted`].
fn interrupt(out: &Path, item: &ItemPlan, done: usize) -> Result<DatasetError> {
    let dir = out.join("images").join(item.id());
    std::fs::create_dir_all(&dir).map_err(|e| DatasetError::io(&dir, e))?;
    files::write_gray8(&dir.join("faces.png"), 1, 1, &[0])?;
    Ok(DatasetError::Interrupted { done })
}

/// Manifest lines appended in the order of the run's list, whichever writer finishes
/// first: finished images wait in `ready` until every image before them is appended.
struct Commit {
    /// Position in the run's list of the next image to append.
    next: usize,
    ready: BTreeMap<usize, Result<ManifestEntry>>,
    /// The error of image `next` (its write or its line), which ends the run.
    error: Option<DatasetError>,
}

/// What the writer threads share.
struct Commits<'a> {
    state: Mutex<Commit>,
    /// The lowest position whose write failed (usize::MAX: none): later images are
    /// neither rendered nor written.
    failed: AtomicUsize,
    manifest: &'a Path,
}

impl Commits<'_> {
    fn state(&self) -> std::sync::MutexGuard<'_, Commit> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Image `pos` is written (or failed): appends every line whose turn has come.
    fn done(&self, pos: usize, result: Result<ManifestEntry>) {
        if result.is_err() {
            self.failed.fetch_min(pos, Ordering::SeqCst);
        }
        let mut c = self.state();
        c.ready.insert(pos, result);
        while c.error.is_none() {
            let next = c.next;
            let Some(r) = c.ready.remove(&next) else {
                break;
            };
            match r.and_then(|e| append_line(self.manifest, &e)) {
                Ok(()) => c.next += 1,
                Err(e) => {
                    self.failed.fetch_min(next, Ordering::SeqCst);
                    c.error = Some(e);
                }
            }
        }
    }
}

/// A run with several images in flight: the calling thread renders (the renderer
/// stays on it), and each of `more` renderers on a "render N" thread of its own, every
/// one taking the next image in the list's order; a "prepare" thread makes the next
/// images' inputs (mesh, textures) through a channel of one object instance's views;
/// `writers` "writer" threads take rendered images through a rendezvous channel (so at
/// most `writers + renderers` rendered images exist) and write them; manifest lines are
/// appended in the list's order ([`Commits`]). The first error in the list's order ends
/// the run, as it would end a run of one image at a time: every image before it is
/// written and listed, none after it is listed.
struct Overlapped<'a> {
    prep: &'a Prepared,
    out: &'a Path,
    camera: &'a CameraRecord,
    manifest: &'a Path,
    profiler: Option<&'a Profiler>,
    writers: usize,
}

/// What the render lanes share: the prepared inputs in the list's order with the
/// position of the next, the render errors and the test hook's stop.
struct Lanes<'t> {
    todo: &'t [&'t ItemPlan],
    /// The inputs' receiving end (None once the lanes are done, so that a preparing
    /// thread waiting to send stops) and the position of the next image.
    feed: Mutex<(Option<std::sync::mpsc::Receiver<Result<ItemInputs>>>, usize)>,
    fail_after: Option<usize>,
    /// The first render error in the list's order (position, error).
    stopped: Mutex<Option<(usize, DatasetError)>>,
    /// The position the test hook stopped at.
    interrupted: Mutex<Option<usize>>,
}

impl<'t> Lanes<'t> {
    /// The next image to render and its inputs, in the list's order; None when the list
    /// is done or the run stops (an error or the test hook at or before it).
    fn next(&self, commits: &Commits) -> Option<(usize, Result<ItemInputs>)> {
        let mut feed = self.feed.lock().unwrap_or_else(|p| p.into_inner());
        let pos = feed.1;
        if pos >= self.todo.len() || commits.failed.load(Ordering::SeqCst) <= pos {
            return None;
        }
        if self.fail_after == Some(pos) {
            *self.interrupted.lock().unwrap_or_else(|p| p.into_inner()) = Some(pos);
            commits.failed.fetch_min(pos, Ordering::SeqCst);
            return None;
        }
        // Err: the preparing thread ended (it panicked: the scope re-raises it).
        let got = feed.0.as_ref()?.recv().ok()?;
        feed.1 += 1;
        Some((pos, got))
    }

    /// One renderer's loop: renders images until the list is done or the run stops;
    /// `report` after each image taken (the calling thread's progress).
    fn render(
        &self,
        run: &Overlapped,
        commits: &Commits,
        renderer: &mut dyn ImageRenderer,
        job_tx: std::sync::mpsc::SyncSender<(usize, RenderedItem<'t>)>,
        report: &mut dyn FnMut(),
    ) {
        loop {
            report();
            let Some((pos, got)) = self.next(commits) else {
                break;
            };
            let item = self.todo[pos];
            let start = run.profiler.map(Profiler::now_us);
            let r = got.and_then(|i| render_stage(run.prep, item, i, renderer, run.profiler));
            image_span(run.profiler, item, start);
            match r {
                Ok(r) => {
                    if job_tx.send((pos, r)).is_err() {
                        break; // every writer panicked: the scope re-raises it
                    }
                }
                Err(e) => {
                    commits.failed.fetch_min(pos, Ordering::SeqCst);
                    let mut stopped = self.stopped.lock().unwrap_or_else(|p| p.into_inner());
                    if stopped.as_ref().is_none_or(|(p, _)| pos < *p) {
                        *stopped = Some((pos, e));
                    }
                    break;
                }
            }
        }
    }
}

impl Overlapped<'_> {
    #[allow(clippy::too_many_arguments)]
    fn run(
        &self,
        todo: &[&ItemPlan],
        renderer: &mut dyn ImageRenderer,
        more: &mut [&mut (dyn ImageRenderer + Send)],
        textures: &mut (dyn TextureSource + Send),
        fail_after: Option<usize>,
        progress: &mut dyn FnMut(usize),
        rendered: &mut usize,
    ) -> Result<()> {
        let commits = Commits {
            state: Mutex::new(Commit {
                next: 0,
                ready: BTreeMap::new(),
                error: None,
            }),
            failed: AtomicUsize::new(usize::MAX),
            manifest: self.manifest,
        };
        let spawn_err = |e| DatasetError::io(self.out, e);
        // Rendered images to the writers; the receiving end shared by them.
        let (job_tx, job_rx) = std::sync::mpsc::sync_channel::<(usize, RenderedItem)>(0);
        let job_rx = Mutex::new(job_rx);
        // One object instance ahead: the channel holds one instance's views less one
        // and the preparing thread the last, so the next instance's mesh and textures
        // are made while the current one's first view renders, never further ahead.
        let ahead = self.prep.job.viewpoints().len().saturating_sub(1);
        let (in_tx, in_rx) = std::sync::mpsc::sync_channel::<Result<ItemInputs>>(ahead);
        let lanes = Lanes {
            todo,
            feed: Mutex::new((Some(in_rx), 0)),
            fail_after,
            stopped: Mutex::new(None),
            interrupted: Mutex::new(None),
        };
        std::thread::scope(|s| -> Result<()> {
            let mut inputs = Inputs::new(self.prep, self.profiler);
            // The instances' scenes made here, ahead of their views, when every renderer
            // can take them (one backend).
            let preps: Vec<Option<ScenePrep>> = std::iter::once(renderer.scene_prep())
                .chain(more.iter().map(|r| r.scene_prep()))
                .collect();
            inputs.scene_prep = match &preps[0] {
                Some(p)
                    if preps
                        .iter()
                        .all(|q| q.as_ref().map(ScenePrep::backend) == Some(p.backend())) =>
                {
                    Some(p.on_own_queue())
                }
                _ => None,
            };
            let profiler = self.profiler;
            let preparing = std::thread::Builder::new()
                .name("prepare".into())
                .spawn_scoped(s, move || {
                    for item in todo {
                        let start = profiler.map(Profiler::now_us);
                        let r = inputs.make(item, textures);
                        image_span(profiler, item, start);
                        let failed = r.is_err();
                        if in_tx.send(r).is_err() || failed {
                            break;
                        }
                    }
                })
                .map_err(spawn_err)?;
            let mut writers = Vec::new();
            for w in 0..self.writers {
                let (job_rx, commits) = (&job_rx, &commits);
                let handle = std::thread::Builder::new()
                    .name(format!("writer {}", w + 1))
                    .spawn_scoped(s, move || {
                        loop {
                            let next = job_rx.lock().unwrap_or_else(|p| p.into_inner()).recv();
                            let Ok((pos, rendered)) = next else {
                                break;
                            };
                            if pos > commits.failed.load(Ordering::SeqCst) {
                                continue; // an earlier image failed: this one is not written
                            }
                            let start = self.profiler.map(Profiler::now_us);
                            let item = rendered.item;
                            let r = write_stage(
                                self.prep,
                                self.camera,
                                self.out,
                                rendered,
                                None,
                                self.profiler,
                            );
                            image_span(self.profiler, item, start);
                            commits.done(pos, r);
                        }
                    })
                    .map_err(spawn_err)?;
                writers.push(handle);
            }
            let mut others = Vec::new();
            for (k, r) in more.iter_mut().enumerate() {
                let (lanes, commits, tx) = (&lanes, &commits, job_tx.clone());
                let handle = std::thread::Builder::new()
                    .name(format!("render {}", k + 2))
                    .spawn_scoped(s, move || {
                        lanes.render(self, commits, &mut **r, tx, &mut || {})
                    })
                    .map_err(spawn_err)?;
                others.push(handle);
            }
            let mut reported = 0;
            let mut report = || {
                let upto = commits.state().next;
                while reported < upto {
                    reported += 1;
                    progress(reported);
                }
            };
            lanes.render(self, &commits, renderer, job_tx, &mut report);
            for h in others.into_iter().chain(writers) {
                if let Err(p) = h.join() {
                    std::panic::resume_unwind(p);
                }
            }
            // A preparing thread waiting to send (the run stopped early) stops.
            lanes.feed.lock().unwrap_or_else(|p| p.into_inner()).0 = None;
            if let Err(p) = preparing.join() {
                std::panic::resume_unwind(p);
            }
            report();
            Ok(())
        })?;
        let c = commits
            .state
            .into_inner()
            .unwrap_or_else(|p| p.into_inner());
        *rendered = c.next;
        if let Some(e) = c.error {
            return Err(e);
        }
        let stopped = lanes
            .stopped
            .into_inner()
            .unwrap_or_else(|p| p.into_inner());
        let interrupted = lanes
            .interrupted
            .into_inner()
            .unwrap_or_else(|p| p.into_inner());
        // The first of a render error and the test hook's stop in the list's order.
        match (stopped, interrupted) {
            (Some((p, e)), i) if i.is_none_or(|i| p < i) => Err(e),
            (_, Some(i)) => Err(interrupt(self.out, todo[i], *rendered)?),
            _ => Ok(()),
        }
    }
}

/// Checks an entry's files against the sizes and hashes it lists: `Err(reason)` when a
/// file is missing or differs.
pub fn verify_entry(dir: &Path, e: &ManifestEntry) -> std::result::Result<(), String> {
    if e.id != format!("{:06}", e.index) {
        return Err(format!("id {:?} is not image {}'s", e.id, e.index));
    }
    if e.files.is_empty() {
        return Err("lists no files".into());
    }
    let idir = dir.join("images").join(&e.id);
    for (name, hash) in &e.files {
        if name.contains(['/', '\\']) || name.starts_with('.') {
            return Err(format!("file name {name:?} is not a plain file name"));
        }
        let p = idir.join(name);
        if let Some(&size) = e.sizes.get(name) {
            match std::fs::metadata(&p) {
                Ok(m) if m.len() == size => {}
                Ok(m) => {
                    return Err(format!(
                        "{} is {} bytes, the manifest says {size}",
                        p.display(),
                        m.len()
                    ));
                }
                Err(err) => return Err(format!("{}: {err}", p.display())),
            }
        }
        let bytes = std::fs::read(&p).map_err(|err| format!("{}: {err}", p.display()))?;
        if files::content_hash(&bytes) != *hash {
            return Err(format!(
                "{} differs from its hash in the manifest",
                p.display()
            ));
        }
    }
    Ok(())
}

/// Images whose files this process has just verified in a folder, each with the
/// [`entry_digest`] of the entry they were verified against.
type Trusted = BTreeMap<usize, u64>;

/// What [`verify_entry`] checks an entry's files against (id, file names, hashes and
/// sizes), as one number: an entry with the same digest verifies the same files alike.
fn entry_digest(e: &ManifestEntry) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    (e.index, &e.id, &e.files, &e.sizes).hash(&mut h);
    h.finish()
}

/// Manifest entries verified between two calls of a verification's progress callback.
pub(super) const VERIFY_CHUNK: usize = 64;
/// Manifest entries read and verified at once where no progress is watched: what a
/// verification holds of the entries besides their [`Listed`] records.
const VERIFY_BATCH: usize = 1024;

/// Where a manifest line is: its file (an index into [`Verified::manifests`]) and bytes
/// (the newline not included).
#[derive(Clone, Copy, Debug)]
pub(super) struct LineAt {
    pub(super) manifest: usize,
    pub(super) offset: u64,
    pub(super) len: usize,
}

/// A manifest line whose image's files verified: where the line is, and what the finish's
/// COCO files need of its entry. The entry itself is read again from its line when
/// `manifest.jsonl` is written, so that a whole job's entries (about 10 KiB an image in
/// memory) are never held at once (docs/dataset.md, "Memory at scale").
#[derive(Debug)]
struct Listed {
    at: LineAt,
    split: Split,
    id: String,
    image: String,
    width: u32,
    height: u32,
}

/// What [`verified_entries`] found: the manifests it read, and one verified line per
/// image index.
struct Verified {
    manifests: Vec<PathBuf>,
    by_index: BTreeMap<usize, Listed>,
}

/// Reads the manifest entries of `lines` (each in `manifests[at.manifest]`) from their
/// files, in their order.
pub(super) fn read_lines(manifests: &[PathBuf], lines: &[LineAt]) -> Result<Vec<ManifestEntry>> {
    let mut open: Option<(usize, std::fs::File)> = None;
    let mut buf = Vec::new();
    lines
        .iter()
        .map(|at| {
            use std::io::{Read, Seek, SeekFrom};
            let path = &manifests[at.manifest];
            if open.as_ref().is_none_or(|(mi, _)| *mi != at.manifest) {
                let f = std::fs::File::open(path).map_err(|e| DatasetError::io(path, e))?;
                open = Some((at.manifest, f));
            }
            let (_, f) = open.as_mut().expect("opened above");
            buf.resize(at.len, 0);
            f.seek(SeekFrom::Start(at.offset))
                .and_then(|_| f.read_exact(&mut buf))
                .map_err(|e| DatasetError::io(path, e))?;
            serde_json::from_slice(&buf).map_err(|e| DatasetError::Manifest {
                path: path.clone(),
                line: 0,
                message: format!("changed while it was read: {e}"),
            })
        })
        .collect()
}

/// Calls `each(line number, offset, line)` for every complete, non-blank line of the
/// manifest at `path` (none when it does not exist), reading it line by line; a half last
/// line is handled by `mode`.
pub(super) fn manifest_lines(
    path: &Path,
    mode: ReadMode,
    mut each: impl FnMut(usize, u64, &str) -> Result<()>,
) -> Result<()> {
    use std::io::BufRead;
    let f = match std::fs::File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(DatasetError::io(path, e)),
    };
    let mut reader = std::io::BufReader::new(f);
    let mut line = String::new();
    let (mut offset, mut n) = (0u64, 0usize);
    loop {
        line.clear();
        let read = reader
            .read_line(&mut line)
            .map_err(|e| DatasetError::io(path, e))?;
        if read == 0 {
            return Ok(());
        }
        n += 1;
        if !line.ends_with('\n') {
            // A kill during an append.
            return match mode {
                ReadMode::Strict => Err(DatasetError::Manifest {
                    path: path.into(),
                    line: n,
                    message: "incomplete last line (an interrupted run); run the shard again"
                        .into(),
                }),
                ReadMode::Repair => {
                    let f = std::fs::OpenOptions::new()
                        .write(true)
                        .open(path)
                        .map_err(|e| DatasetError::io(path, e))?;
                    f.set_len(offset)
                        .and_then(|_| f.sync_all())
                        .map_err(|e| DatasetError::io(path, e))
                }
                ReadMode::DropPartial => Ok(()),
            };
        }
        let text = line.trim_end_matches('\n');
        if !text.trim().is_empty() {
            each(n, offset, text)?;
        }
        offset += read as u64;
    }
}

/// Parses manifest line `n` of `path`.
pub(super) fn parse_entry(path: &Path, n: usize, line: &str) -> Result<ManifestEntry> {
    serde_json::from_str(line).map_err(|e| DatasetError::Manifest {
        path: path.into(),
        line: n,
        message: e.to_string(),
    })
}

/// The lines of every shard manifest in `dir` whose files verify, one per image index in
/// `wanted` (the first that verifies, in file name order). `own`, this run's manifest, is
/// repaired (half last line) and rewritten without the entries that fail. Every line is
/// parsed (a malformed one is an error) and its image's files read and hashed, a batch of
/// entries at a time, except where `trusted` holds the entry's [`entry_digest`] for its
/// image (files this process verified in `dir` and has not rewritten since: a merge's
/// moved images). `progress` is told (`step`, entries verified, entries to verify).
fn verified_entries(
    dir: &Path,
    plan: &Plan,
    wanted: &BTreeSet<usize>,
    own: Option<&Path>,
    trusted: Option<&Trusted>,
    step: Verifying,
    mut progress: Option<&mut VerifyProgress<'_>>,
) -> Result<Verified> {
    use rayon::prelude::*;
    let mut candidates: Vec<LineAt> = Vec::new();
    let mut manifests = shard_manifests(dir)?;
    if let Some(o) = own
        && !manifests.iter().any(|m| m == o)
    {
        manifests.push(o.to_path_buf());
    }
    for (mi, m) in manifests.iter().enumerate() {
        let mode = if Some(m.as_path()) == own {
            ReadMode::Repair
        } else {
            ReadMode::DropPartial
        };
        manifest_lines(m, mode, |n, offset, line| {
            let e = parse_entry(m, n, line)?;
            if e.index >= plan.items.len() {
                return Err(DatasetError::Manifest {
                    path: m.clone(),
                    line: n,
                    message: format!(
                        "image {} is not in the job ({} images)",
                        e.index,
                        plan.items.len()
                    ),
                });
            }
            if wanted.contains(&e.index) {
                candidates.push(LineAt {
                    manifest: mi,
                    offset,
                    len: line.len(),
                });
            }
            Ok(())
        })?;
    }
    // On all cores, a batch at a time; in smaller chunks where `progress` is watched, so
    // that it moves while the files are read (each chunk ends when its slowest image
    // does).
    let chunk_len = match progress {
        Some(_) => VERIFY_CHUNK,
        None => VERIFY_BATCH,
    };
    let mut by_index: BTreeMap<usize, Listed> = BTreeMap::new();
    let mut own_failed: BTreeSet<u64> = BTreeSet::new();
    let own_index = own.and_then(|o| manifests.iter().position(|m| m == o));
    let mut done = 0;
    for chunk in candidates.chunks(chunk_len) {
        let entries = read_lines(&manifests, chunk)?;
        let ok: Vec<bool> = entries
            .par_iter()
            .map(|e| {
                trusted.is_some_and(|t| t.get(&e.index) == Some(&entry_digest(e)))
                    || verify_entry(dir, e).is_ok()
            })
            .collect();
        for ((at, e), ok) in chunk.iter().zip(entries).zip(ok) {
            if ok {
                by_index.entry(e.index).or_insert_with(|| Listed {
                    at: *at,
                    split: e.split,
                    id: e.id,
                    image: e.image,
                    width: e.width,
                    height: e.height,
                });
            } else if Some(at.manifest) == own_index {
                own_failed.insert(at.offset);
            }
        }
        done += chunk.len();
        if let Some(p) = progress.as_deref_mut() {
            p(step, done, candidates.len());
        }
    }
    if !own_failed.is_empty()
        && let Some(o) = own
    {
        // The entries that failed are dropped (entries outside `wanted` are kept as they
        // are), the rest sorted by image, read again from their lines as they are written.
        let oi = own_index.expect("own is among the manifests");
        let mut kept: Vec<(usize, LineAt)> = Vec::new();
        manifest_lines(o, ReadMode::Strict, |n, offset, line| {
            if !own_failed.contains(&offset) {
                let at = LineAt {
                    manifest: oi,
                    offset,
                    len: line.len(),
                };
                kept.push((parse_entry(o, n, line)?.index, at));
            }
            Ok(())
        })?;
        kept.sort_by_key(|(index, _)| *index);
        let ats: Vec<LineAt> = kept.iter().map(|(_, at)| *at).collect();
        let written = write_manifest_from(o, &manifests, &ats)?;
        // The lines moved: each image's first line in the rewritten file.
        let mut at_index: BTreeMap<usize, LineAt> = BTreeMap::new();
        for (&(index, _), &(offset, len)) in kept.iter().zip(&written) {
            at_index.entry(index).or_insert(LineAt {
                manifest: oi,
                offset,
                len,
            });
        }
        for (index, listed) in by_index.iter_mut() {
            if listed.at.manifest == oi
                && let Some(at) = at_index.get(index)
            {
                // Each image's first verified line there is its first line now: the
                // failed ones before it are gone and the order within an image kept.
                listed.at = *at;
            }
        }
    }
    Ok(Verified {
        manifests,
        by_index,
    })
}

/// Removes temporary files a killed run left: with `only`, in those images' folders;
/// else everywhere in the dataset folder (only with the exclusive lock held).
fn sweep_temps(out: &Path, only: Option<&BTreeSet<usize>>) -> Result<usize> {
    let mut n = 0;
    match only {
        Some(items) => {
            for i in items {
                n += files::remove_stray_temps(&out.join("images").join(format!("{i:06}")))?;
            }
        }
        None => {
            for sub in ["", "manifests", "coco"] {
                n += files::remove_stray_temps(&out.join(sub))?;
            }
            if let Ok(rd) = std::fs::read_dir(out.join("images")) {
                for e in rd.flatten() {
                    if files::is_temp_name(&e.file_name().to_string_lossy()) {
                        // A folder being moved into place by a merge that was killed.
                        let p = e.path();
                        if p.is_dir() {
                            std::fs::remove_dir_all(&p).map_err(|err| DatasetError::io(&p, err))?;
                            n += 1;
                            continue;
                        }
                    }
                    n += files::remove_stray_temps(&e.path())?;
                }
                n += files::remove_stray_temps(&out.join("images"))?;
            }
        }
    }
    Ok(n)
}

/// Re-makes image `index` alone into `out/images/<id>/`; returns its manifest entry
/// (also written to `out/one-<id>.json`, outside the shard manifests).
pub fn render_one(
    prep: &Prepared,
    index: usize,
    out: &Path,
    renderer: &mut dyn ImageRenderer,
    textures: &mut dyn TextureSource,
) -> Result<ManifestEntry> {
    render_one_seeded(prep, index, None, out, renderer, textures)
}

/// [`render_one`] with the image's seed replaced by `image_seed` when given: the same
/// scene (object instance, defects, textures and their placement, view: all drawn from
/// the instance's seed) under other random numbers for the path tracer's samples, the
/// sensor's noise and the post-processing. For error measurements against an
/// independent reference (`synosis dataset render-one --image-seed`); the manifest entry
/// records the seed used.
pub fn render_one_seeded(
    prep: &Prepared,
    index: usize,
    image_seed: Option<u64>,
    out: &Path,
    renderer: &mut dyn ImageRenderer,
    textures: &mut dyn TextureSource,
) -> Result<ManifestEntry> {
    let mut item = prep
        .plan
        .items
        .get(index)
        .ok_or_else(|| DatasetError::Field {
            file: prep.job.origin.clone(),
            field: "--index".into(),
            value: index.to_string(),
            allowed: format!("the job has images 0..{}", prep.plan.items.len()),
        })?
        .clone();
    if let Some(s) = image_seed {
        item.seed = s;
    }
    std::fs::create_dir_all(out).map_err(|e| DatasetError::io(out, e))?;
    let mut ctx = Ctx::new(prep, None)?;
    let entry = ctx.render_item(&item, out, renderer, textures)?;
    let v = serde_json::to_value(&entry)
        .map_err(|e| DatasetError::io(out, std::io::Error::other(e)))?;
    files::write_json(&out.join(format!("one-{}.json", item.id())), &v)?;
    Ok(entry)
}

/// Writes `job.toml` into a new folder, or checks the folder holds this same job.
fn claim_dir(out: &Path, job_text: &str) -> Result<()> {
    let path = out.join("job.toml");
    match std::fs::read_to_string(&path) {
        Ok(existing) if existing == job_text => Ok(()),
        Ok(_) => Err(DatasetError::layout(
            out,
            "holds a different job (job.toml differs); use another --out or the same job file",
        )),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            crate::util::write_atomic(&path, job_text.as_bytes())
                .map_err(|e| DatasetError::io(&path, e))
        }
        Err(e) => Err(DatasetError::io(path, e)),
    }
}

/// Times consecutive stages of one image on the current thread: each `stage` call records
/// the seconds since the previous one (or since `Laps::start`) under its name, in the
/// image's `stage_seconds` and, when profiling, as a CPU span on this thread.
struct Laps<'p> {
    lap: Instant,
    profiler: Option<&'p Profiler>,
}

impl<'p> Laps<'p> {
    fn start(profiler: Option<&'p Profiler>) -> Self {
        Laps {
            lap: Instant::now(),
            profiler,
        }
    }

    fn stage(&mut self, name: &str, stages: &mut BTreeMap<String, f64>) {
        let secs = self.lap.elapsed().as_secs_f64();
        stages.insert(name.to_string(), secs);
        if let Some(p) = self.profiler {
            p.cpu_span(name, p.now_us() - secs * 1e6, secs * 1e6);
        }
        self.lap = Instant::now();
    }
}

/// The CPU inputs of one image, made before it renders (on the preparing thread when
/// images overlap): the instance's mesh, its region materials and face textures.
struct ItemInputs {
    mesh: Arc<Mesh>,
    gltf: Option<Arc<GltfMaterials>>,
    materials: Vec<crate::scene::materials::RegionMaterial>,
    face_textures: Vec<FaceTexture>,
    /// The instance's scene made by the preparing thread (`Inputs::scene_prep`).
    scene: Option<Arc<PreparedScene>>,
    /// The face textures put on the renderers' device by the preparing thread (held
    /// until the image is rendered).
    maps_ahead: Option<MapsAhead>,
    /// "defects", "scene", "textures" and "maps" seconds.
    stages: BTreeMap<String, f64>,
}

/// One image rendered, waiting for its write stage.
struct RenderedItem<'p> {
    item: &'p ItemPlan,
    img: RenderedImage,
    /// Every stage so far ("defects", "scene", "textures", "maps", "render", the
    /// renderer's parts).
    stages: BTreeMap<String, f64>,
    /// `ImageRenderer::describe` of the renderer that made it.
    renderer: String,
    /// Samples per pixel rendered (`[render] spp`, or fewer with `noise_target`).
    spp: u32,
    /// The noise criterion's checks, (spp, ratio) in order (with `noise_target`).
    noise_checks: Vec<(u32, f64)>,
    /// Mean samples per pixel (with `[render] adaptive_radius`).
    mean_spp: Option<f64>,
    /// The rays chosen (`[render] analytic_rays_max`).
    analytic_rays: Option<u32>,
}

/// State kept between images by the stage that makes their inputs: the current
/// instance's mesh and the texture cache.
struct Inputs<'p> {
    prep: &'p Prepared,
    cache: TextureCache,
    /// The current instance's mesh, with its triangles' glTF materials when the object
    /// has them.
    mesh: Option<(usize, Arc<Mesh>, Option<Arc<GltfMaterials>>)>,
    /// How to make the renderers' scene of an instance here, ahead of its views (a run
    /// with images in flight: `ImageRenderer::scene_prep`); None: each renderer makes its
    /// own.
    scene_prep: Option<ScenePrep>,
    /// The last scene made, by the mesh key its requests carry.
    scene: Option<(u64, Arc<PreparedScene>)>,
    profiler: Option<&'p Profiler>,
}

impl<'p> Inputs<'p> {
    fn new(prep: &'p Prepared, profiler: Option<&'p Profiler>) -> Self {
        Inputs {
            prep,
            cache: TextureCache::new(prep.job.texture.cache as usize),
            mesh: None,
            scene_prep: None,
            scene: None,
            profiler,
        }
    }

    /// The scene of `item`'s instance when this stage makes them (`scene_prep`): the last
    /// one while the mesh key is the same (the views of an instance, every defect-free
    /// instance of an object), else made anew.
    fn scene(
        &mut self,
        item: &ItemPlan,
        mesh: &Mesh,
        gltf: Option<&GltfMaterials>,
        materials: &[crate::scene::materials::RegionMaterial],
    ) -> Result<Option<Arc<PreparedScene>>> {
        let Some(prep) = &self.scene_prep else {
            return Ok(None);
        };
        let key = mesh_key(&self.prep.plan.instances[item.instance], item.instance);
        if let Some((k, s)) = &self.scene
            && *k == key
        {
            return Ok(Some(s.clone()));
        }
        self.scene = None; // free the last before making the next
        let made = prep
            .prepare(
                mesh,
                materials,
                gltf,
                self.prep.job.mapping.defects,
                self.profiler,
            )
            .map_err(|message| DatasetError::Render {
                index: item.index,
                id: item.id(),
                message,
            })?;
        let made = Arc::new(made);
        self.scene = Some((key, made.clone()));
        Ok(Some(made))
    }

    /// The mesh of an instance: the object, with its defect set imprinted if defective,
    /// and its triangles' glTF materials (followed through the imprint's refinement).
    /// Only the current one is kept.
    fn mesh(&mut self, inst_index: usize) -> Result<(Arc<Mesh>, Option<Arc<GltfMaterials>>)> {
        if let Some((k, m, g)) = &self.mesh
            && *k == inst_index
        {
            return Ok((m.clone(), g.clone()));
        }
        self.mesh = None;
        let inst = &self.prep.plan.instances[inst_index];
        let base = &self.prep.meshes[inst.object];
        let gltf = self
            .prep
            .gltf_materials
            .get(inst.object)
            .and_then(|g| g.as_ref());
        let defect_err = |source| DatasetError::Defect {
            object: self.prep.job.objects[inst.object].name.clone(),
            source,
        };
        let (mesh, gltf) = match (inst.defect_set, gltf) {
            (Some(k), Some(g)) => {
                let (mesh, origin) =
                    imprint_traced(base, &self.prep.defect_sets[k]).map_err(defect_err)?;
                let of_triangle = origin
                    .iter()
                    .map(|&t| g.of_triangle.get(t as usize).copied().unwrap_or(u32::MAX))
                    .collect();
                let traced = GltfMaterials {
                    names: g.names.clone(),
                    of_triangle,
                };
                (mesh, Some(traced))
            }
            (Some(k), None) => (
                imprint(base, &self.prep.defect_sets[k]).map_err(defect_err)?,
                None,
            ),
            (None, g) => (base.clone(), g.cloned()),
        };
        let m = Arc::new(mesh);
        let g = gltf.map(Arc::new);
        self.mesh = Some((inst_index, m.clone(), g.clone()));
        Ok((m, g))
    }

    /// The image's mesh ("defects" stage), region materials and face textures
    /// ("textures" stage: cache misses made through `textures`).
    fn make(&mut self, item: &ItemPlan, textures: &mut dyn TextureSource) -> Result<ItemInputs> {
        let job = &self.prep.job;
        let inst: &InstancePlan = &self.prep.plan.instances[item.instance];
        let finish = &job.finishes[inst.finish];
        let params = plan::instance_params(job, inst);
        let mut stages = BTreeMap::new();
        let mut laps = Laps::start(self.profiler);
        let (mesh, gltf) = self.mesh(item.instance)?;
        laps.stage("defects", &mut stages);
        let materials = job.objects[inst.object]
            .region_materials(
                inst.object,
                params.alpha as f32,
                job.scene_base().wavelength_nm(),
            )
            .map_err(|message| DatasetError::Render {
                index: item.index,
                id: item.id(),
                message,
            })?;
        let scene = self.scene(item, &mesh, gltf.as_deref(), &materials)?;
        if scene.is_some() {
            laps.stage("scene", &mut stages);
        }
        let present: BTreeSet<u8> = mesh.labels.iter().map(|l| l.face).collect();
        let faces: Vec<_> = params
            .faces
            .iter()
            .filter(|f| present.contains(&f.face))
            .collect();
        let (size, spacing) = (job.texture.size_px as usize, job.texture.spacing_um);
        let keys: Vec<(usize, u32)> = faces.iter().map(|fc| (inst.finish, fc.texture)).collect();
        // The misses made side by side (`make_many`); the first failure in the faces'
        // order is the error, as when they are made one after the other.
        let maps = self.cache.get_many(&keys, |misses| {
            let wants: Vec<TextureWant> = misses
                .iter()
                .map(|&(_, t)| TextureWant {
                    finish,
                    instance: t,
                    seed: derive(job.seed, &[tag::TEXTURE, name(&finish.name), t as u64]),
                    size_px: size,
                    spacing_um: spacing,
                })
                .collect();
            textures
                .make_many(&wants)
                .into_iter()
                .zip(misses)
                .map(|(r, &(_, t))| r.map_err(|m| texture_error(finish, t, m)))
                .collect()
        })?;
        let face_textures: Vec<FaceTexture> = faces
            .iter()
            .zip(maps)
            .map(|(fc, map)| FaceTexture {
                face: fc.face,
                finish: finish.name.clone(),
                texture_instance: fc.texture,
                map,
                rotation_rad: (fc.rotation_deg as f32).to_radians(),
                offset_px: [fc.offset_px[0] as f32, fc.offset_px[1] as f32],
            })
            .collect();
        laps.stage("textures", &mut stages);
        let maps_ahead = match &self.scene_prep {
            Some(prep) => {
                let mut distinct: Vec<&FaceTexture> = Vec::new();
                for t in &face_textures {
                    if !distinct.iter().any(|d| Arc::ptr_eq(&d.map, &t.map)) {
                        distinct.push(t);
                    }
                }
                let maps: Vec<&Arc<TextureMap>> = distinct.iter().map(|t| &t.map).collect();
                let ahead = prep.upload_maps(&maps).map_err(|(i, e)| {
                    let t = distinct[i];
                    DatasetError::Render {
                        index: item.index,
                        id: item.id(),
                        message: format!(
                            "the slope map of face {} (finish {:?}, texture {}): {e}",
                            t.face, t.finish, t.texture_instance
                        ),
                    }
                })?;
                laps.stage("maps", &mut stages);
                Some(ahead)
            }
            None => None,
        };
        Ok(ItemInputs {
            mesh,
            gltf,
            materials,
            face_textures,
            scene,
            maps_ahead,
            stages,
        })
    }
}

/// The key of instance `index`'s mesh ([`ImageRequest::mesh_key`]): its own with a
/// defect set, else its object's (every defect-free instance of an object has its mesh).
fn mesh_key(inst: &InstancePlan, index: usize) -> u64 {
    match inst.defect_set {
        Some(_) => (1u64 << 32) | index as u64,
        None => inst.object as u64,
    }
}

/// The render stage of one image ("render": request, acceleration structure, path
/// tracing, annotation, readback, checks; plus the renderer's own parts).
fn render_stage<'p>(
    prep: &Prepared,
    item: &'p ItemPlan,
    inputs: ItemInputs,
    renderer: &mut dyn ImageRenderer,
    profiler: Option<&Profiler>,
) -> Result<RenderedItem<'p>> {
    let job = &prep.job;
    let inst: &InstancePlan = &prep.plan.instances[item.instance];
    let params = plan::instance_params(job, inst);
    let mut stages = inputs.stages;
    let mut laps = Laps::start(profiler);
    let viewpoints = job.viewpoints();
    let vp = &viewpoints[item.view];
    let pose = vp.pose();
    let noise = match job.render.noise_target {
        None => None,
        Some(_) => {
            let camera = image_camera_record(job)?;
            let finish = &job.finishes[inst.finish].name;
            super::camera::noise_stop(job, finish, item.seed, &camera).map_err(|m| {
                DatasetError::Render {
                    index: item.index,
                    id: item.id(),
                    message: format!("render.noise_target: {m}"),
                }
            })?
        }
    };
    let req = ImageRequest {
        pose,
        camera: &job.camera_config,
        lights: &job.lights,
        materials: &inputs.materials,
        gltf_materials: inputs.gltf.as_deref(),
        mesh: &inputs.mesh,
        mesh_key: mesh_key(inst, item.instance),
        scene: inputs.scene.as_deref(),
        view: vp.name(),
        alpha: params.alpha as f32,
        face_textures: inputs.face_textures,
        placement: Placement {
            cover: job.mapping.cover,
            seed: derive(inst.seed, &[tag::REGIONS]),
            rotation_range_deg: job.mapping.rotation_deg as f32,
            defects: job.mapping.defects,
        },
        width: job.render.width as u32,
        height: job.render.height as u32,
        spp: job.render.spp as u32,
        bounces: job.render.bounces as u32,
        seed: item.seed,
        noise: noise.as_ref(),
        labels: job.render.labels.unwrap_or_default(),
        direct_light: job.render.direct_light.unwrap_or_default(),
        analytic_rays: job
            .render
            .analytic_rays
            .map_or(crate::scene::config::DEFAULT_ANALYTIC_RAYS, |n| n as u32),
        light_samples: job
            .render
            .light_samples
            .map_or(crate::scene::config::DEFAULT_LIGHT_SAMPLES, |n| n as u32),
        bsdf_samples: job
            .render
            .bsdf_samples
            .map_or(crate::scene::config::DEFAULT_LIGHT_SAMPLES, |n| n as u32),
        split_paths: job.render.split_paths.unwrap_or(false),
        batch_spp: job
            .render
            .batch_spp
            .map_or(crate::scene::config::DEFAULT_BATCH_SPP, |n| n as u32),
    };
    let fail = |message: String| DatasetError::Render {
        index: item.index,
        id: item.id(),
        message,
    };
    let img = renderer.render(&req).map_err(fail)?;
    // The maps put on the device ahead were found there by the render: let them go with
    // the last scene that holds them.
    drop(inputs.maps_ahead);
    if let (Some(p), Some(r)) = (profiler, renderer.last_profile()) {
        p.absorb(r);
    }
    if let (Some(p), Some(m)) = (profiler, renderer.device_memory()) {
        p.counter(DEVICE_MEMORY_COUNTER, m.bytes as f64 / (1u64 << 20) as f64);
        p.counter(DEVICE_ALLOCATIONS_COUNTER, m.allocations as f64);
    }
    img.check(&req).map_err(fail)?;
    laps.stage("render", &mut stages);
    stages.extend(renderer.last_stages());
    let (spp, checks) = renderer.last_samples().unwrap_or((req.spp, Vec::new()));
    Ok(RenderedItem {
        item,
        img,
        stages,
        renderer: renderer.describe(),
        spp,
        noise_checks: checks.iter().map(|e| (e.spp, e.ratio)).collect(),
        mean_spp: match (
            req.noise.is_some_and(|n| n.adaptive_radius.is_some()),
            checks.last(),
        ) {
            (true, Some(e)) => Some(e.mean_spp),
            _ => None,
        },
        analytic_rays: renderer.last_rays(),
    })
}

/// The write stage of one image ("write": raw files, sensor, post-processing, PNG / EXR
/// / JSON encoding, labels, sizes) and its manifest entry (not yet appended).
/// `render_seconds` is `started.elapsed()` when given, else the sum of the image's
/// stages (its work on whichever threads, waiting between stages not counted).
fn write_stage(
    prep: &Prepared,
    camera: &CameraRecord,
    out: &Path,
    rendered: RenderedItem,
    started: Option<Instant>,
    profiler: Option<&Profiler>,
) -> Result<ManifestEntry> {
    let RenderedItem {
        item,
        img,
        mut stages,
        renderer,
        spp,
        noise_checks,
        mean_spp,
        analytic_rays,
    } = rendered;
    let job = &prep.job;
    let inst: &InstancePlan = &prep.plan.instances[item.instance];
    let finish = &job.finishes[inst.finish];
    let params = plan::instance_params(job, inst);
    let mut laps = Laps::start(profiler);
    let dir = out.join("images").join(item.id());
    std::fs::create_dir_all(&dir).map_err(|e| DatasetError::io(&dir, e))?;
    let mut hashes = write_raw(&dir, &img)?;
    let (frame, exposed) =
        raw_frame(job, &finish.name, item.seed, camera, &img).map_err(|message| {
            DatasetError::Render {
                index: item.index,
                id: item.id(),
                message: format!("[sensor]: {message}"),
            }
        })?;
    drop(img);
    let (post_hashes, mut defects, noise_sigma) =
        write_post(&dir, job, &finish.texture_type(), item.seed, frame)?;
    if let Some(k) = inst.defect_set {
        name_defects(&mut defects, &prep.defect_sets[k]);
    }
    hashes.extend(post_hashes);
    let sizes = file_sizes(&dir, &hashes)?;
    laps.stage("write", &mut stages);
    let render_seconds = match started {
        Some(t0) => t0.elapsed().as_secs_f64(),
        None => ["defects", "scene", "textures", "maps", "render", "write"]
            .iter()
            .filter_map(|k| stages.get(*k))
            .sum(),
    };
    let viewpoints = job.viewpoints();
    let vp = &viewpoints[item.view];
    let pose = vp.pose();
    let rel = |f: &str| format!("images/{}/{f}", item.id());
    Ok(ManifestEntry {
        index: item.index,
        id: item.id(),
        image: rel("image.png"),
        faces: rel("faces.png"),
        viewpoint: vp.name().to_string(),
        pose: pose.cloned(),
        finish: finish.name.clone(),
        texture_type: finish.texture_type(),
        split: inst.split,
        object: job.objects[inst.object].name.clone(),
        instance: inst.id.clone(),
        label: inst.label,
        defect_set: inst.defect_set,
        alpha: params.alpha,
        roughness: params.roughness,
        face_textures: params.faces,
        seed: item.seed,
        width: job.render.width as u32,
        height: job.render.height as u32,
        spp,
        bounces: job.render.bounces as u32,
        renderer,
        noise_ratio: noise_checks.last().map(|c| c.1),
        noise_checks,
        mean_spp,
        analytic_rays,
        noise_sigma,
        camera: Some(camera.clone()),
        exposure_ev: exposed.exposure_ev,
        exposure_ms: exposed.exposure_ms,
        bit_depth: job.sensor.model.deep_bit_depth(),
        defects,
        files: hashes,
        sizes,
        finished_unix: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0),
        render_seconds,
        stage_seconds: stages,
    })
}

/// The profile's counter of the renderers' device memory in live buffers and images
/// ([`ImageRenderer::device_memory`]), recorded after each image's render, MiB.
pub const DEVICE_MEMORY_COUNTER: &str = "device memory (MiB)";
/// The same memory's count of live allocations.
pub const DEVICE_ALLOCATIONS_COUNTER: &str = "device allocations";

/// Records "image <id>" on this thread from `start_us` to now (when profiling).
fn image_span(profiler: Option<&Profiler>, item: &ItemPlan, start_us: Option<f64>) {
    if let (Some(p), Some(t)) = (profiler, start_us) {
        p.cpu_span(&format!("image {}", item.id()), t, p.now_us() - t);
    }
}

/// State kept between images when they are made one after the other (`render-one`,
/// `in_flight = 1`): the inputs' state and the images' camera.
struct Ctx<'p> {
    prep: &'p Prepared,
    inputs: Inputs<'p>,
    camera: CameraRecord,
    profiler: Option<&'p Profiler>,
}

impl<'p> Ctx<'p> {
    fn new(prep: &'p Prepared, profiler: Option<&'p Profiler>) -> Result<Self> {
        let camera = image_camera_record(&prep.job)?;
        Ok(Ctx {
            prep,
            inputs: Inputs::new(prep, profiler),
            camera,
            profiler,
        })
    }

    /// Every stage of one image on this thread: inputs, render, write.
    fn render_item(
        &mut self,
        item: &ItemPlan,
        out: &Path,
        renderer: &mut dyn ImageRenderer,
        textures: &mut dyn TextureSource,
    ) -> Result<ManifestEntry> {
        let t0 = Instant::now();
        let image_start_us = self.profiler.map(Profiler::now_us);
        let inputs = self.inputs.make(item, textures)?;
        let rendered = render_stage(self.prep, item, inputs, renderer, self.profiler)?;
        let entry = write_stage(
            self.prep,
            &self.camera,
            out,
            rendered,
            Some(t0),
            self.profiler,
        )?;
        image_span(self.profiler, item, image_start_us);
        Ok(entry)
    }
}

/// The sizes of the listed files of an image folder.
fn file_sizes(dir: &Path, hashes: &BTreeMap<String, String>) -> Result<BTreeMap<String, u64>> {
    hashes
        .keys()
        .map(|name| {
            let p = dir.join(name);
            let m = std::fs::metadata(&p).map_err(|e| DatasetError::io(&p, e))?;
            Ok((name.clone(), m.len()))
        })
        .collect()
}

/// The renderer's outputs, kept raw so post-processing can be re-run without rendering.
fn write_raw(dir: &Path, img: &RenderedImage) -> Result<BTreeMap<String, String>> {
    let (w, h) = (img.width as usize, img.height as usize);
    let mut m = BTreeMap::new();
    m.insert(
        "radiance.exr".into(),
        files::write_exr(&dir.join("radiance.exr"), w, h, &img.radiance)?,
    );
    m.insert(
        "raw_mask.png".into(),
        files::write_gray8(&dir.join("raw_mask.png"), w, h, &img.class)?,
    );
    m.insert(
        "raw_instances.png".into(),
        files::write_gray16(&dir.join("raw_instances.png"), w, h, &img.instance)?,
    );
    let object: Vec<u8> = img
        .object
        .iter()
        .map(|&o| if o != 0 { 255 } else { 0 })
        .collect();
    m.insert(
        "object.png".into(),
        files::write_gray8(&dir.join("object.png"), w, h, &object)?,
    );
    m.insert(
        "faces.png".into(),
        files::write_gray8(&dir.join("faces.png"), w, h, &img.face)?,
    );
    let cov: Vec<u16> = img
        .coverage
        .iter()
        .map(|&c| (c.clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect();
    m.insert(
        "coverage.png".into(),
        files::write_gray16(&dir.join("coverage.png"), w, h, &cov)?,
    );
    if let Some(counts) = &img.pixel_spp {
        // `[render] adaptive_radius`: each pixel's samples.
        m.insert(
            "spp.png".into(),
            files::write_gray16(&dir.join("spp.png"), w, h, &spp_map(counts))?,
        );
    }
    Ok(m)
}

/// The camera record of a job's images (the job's camera at `[render] width, height`).
fn image_camera_record(job: &Job) -> Result<CameraRecord> {
    let cam = job.image_camera().map_err(|message| DatasetError::Parse {
        file: job.origin.clone(),
        message,
    })?;
    Ok(CameraRecord::of(&cam))
}

/// The frame the post-processing starts from: the rendered labels and the sensor's
/// image (`camera::expose`: the linear model or the EMVA 1288 sensor, the finish's
/// exposure factor, the image's random exposure).
fn raw_frame(
    job: &Job,
    finish: &str,
    image_seed: u64,
    camera: &CameraRecord,
    img: &RenderedImage,
) -> std::result::Result<(Frame, Exposed), String> {
    let mut exposed = expose(job, finish, image_seed, camera, &img.radiance, &img.face)?;
    let frame = Frame {
        width: img.width as usize,
        height: img.height as usize,
        image: std::mem::take(&mut exposed.image),
        class: img.class.clone(),
        instance: img.instance.clone(),
        object: img.object.clone(),
    };
    Ok((frame, exposed))
}

/// Reads the raw files of an image back into a frame (for `postprocess`) and runs the
/// sensor step on its radiance, as the run did.
fn read_raw_frame(
    job: &Job,
    e: &ManifestEntry,
    camera: &CameraRecord,
    dir: &Path,
) -> Result<(Frame, Exposed)> {
    let (w, h, radiance) = files::read_exr(&dir.join("radiance.exr"))?;
    let (_, _, class) = files::read_gray8(&dir.join("raw_mask.png"))?;
    let (_, _, instance) = files::read_gray16(&dir.join("raw_instances.png"))?;
    let (_, _, object) = files::read_gray8(&dir.join("object.png"))?;
    let (_, _, face) = files::read_gray8(&dir.join("faces.png"))?;
    if [class.len(), instance.len(), object.len(), face.len()]
        .iter()
        .any(|&n| n != w * h)
    {
        return Err(DatasetError::layout(dir, "raw files of different sizes"));
    }
    if (camera.width as usize, camera.height as usize) != (w, h) {
        return Err(DatasetError::layout(
            dir,
            format!(
                "radiance.exr is {w} x {h}, the camera {} x {}",
                camera.width, camera.height
            ),
        ));
    }
    let img = RenderedImage {
        width: w as u32,
        height: h as u32,
        radiance,
        class,
        instance,
        face,
        coverage: Vec::new(),
        object: object.iter().map(|&o| (o != 0) as u8).collect(),
        pixel_spp: None,
    };
    raw_frame(job, &e.finish, e.seed, camera, &img)
        .map_err(|m| DatasetError::layout(dir, format!("[sensor]: {m}")))
}

/// Names each defect by the spec entry it was drawn from ("big dent", ...).
fn name_defects(defects: &mut [DefectVisibility], set: &DefectSet) {
    for d in defects {
        d.kind = set
            .defects
            .iter()
            .find(|x| x.instance == d.instance)
            .map(|x| x.name.clone());
    }
}

type PostFiles = (BTreeMap<String, String>, Vec<DefectVisibility>, Option<f64>);

/// Post-processes a frame and writes image.png, mask.png, instances.png, labelme.json
/// and the image's COCO annotations.
fn write_post(
    dir: &Path,
    job: &Job,
    texture_type: &str,
    image_seed: u64,
    frame: Frame,
) -> Result<PostFiles> {
    let r = post::apply(
        &job.postprocess,
        texture_type,
        derive(image_seed, &[tag::POST]),
        frame,
    );
    let f = &r.frame;
    let (w, h) = (f.width, f.height);
    let mut m = BTreeMap::new();
    let png = dir.join("image.png");
    let hash = match job.sensor.model.deep_bit_depth() {
        Some(bits) => files::write_gray16(&png, w, h, &quantise_units_deep(&f.image, bits))?,
        None => files::write_gray8(&png, w, h, &quantise_units8(&f.image))?,
    };
    m.insert("image.png".into(), hash);
    m.insert(
        "mask.png".into(),
        files::write_gray8(&dir.join("mask.png"), w, h, &f.class)?,
    );
    m.insert(
        "instances.png".into(),
        files::write_gray16(&dir.join("instances.png"), w, h, &f.instance)?,
    );
    let faces = files::read_gray8(&dir.join("faces.png"))?.2;
    m.insert(
        "labelme.json".into(),
        files::write_json(&dir.join("labelme.json"), &labelme_json(f, &faces))?,
    );
    m.insert(
        "coco.json".into(),
        files::write_json(&dir.join("coco.json"), &coco::fragment(f))?,
    );
    Ok((m, r.defects, r.noise_sigma))
}

pub fn class_name(c: u8) -> &'static str {
    match c {
        1 => "dent",
        2 => "scratch",
        _ => "background",
    }
}

/// LabelMe 5 JSON: one polygon per connected part of each defect (label = class,
/// group_id = instance), and the visible inspected faces (labels "A", "B", "C", which
/// `synosis compare` reads in its LabelMe layout).
fn labelme_json(f: &Frame, faces: &[u8]) -> serde_json::Value {
    let mut shapes = Vec::new();
    for (id, class, _) in post::defect_pixels(&f.class, &f.instance) {
        let mask: Vec<bool> = f.instance.iter().map(|&i| i == id).collect();
        for poly in labels::trace_polygons(&mask, f.width, f.height) {
            shapes.push(json!({"label": class_name(class), "points": poly, "group_id": id, "shape_type": "polygon", "flags": {}}));
        }
    }
    for face in 1u8..=3 {
        let mask: Vec<bool> = faces.iter().map(|&x| x == face).collect();
        for poly in labels::trace_polygons(&mask, f.width, f.height) {
            shapes.push(json!({"label": crate::scene::mesh::face_name(face), "points": poly, "group_id": null, "shape_type": "polygon", "flags": {}}));
        }
    }
    json!({
        "version": "5.0.1",
        "flags": {},
        "shapes": shapes,
        "imagePath": "image.png",
        "imageData": null,
        "imageHeight": f.height,
        "imageWidth": f.width,
    })
}

/// Writes one manifest line (the entry's JSON and its newline), the one line format of
/// every manifest writer; returns the line's length without the newline.
fn write_manifest_line(w: &mut impl Write, entry: &ManifestEntry) -> std::io::Result<usize> {
    let line = serde_json::to_vec(entry).map_err(std::io::Error::other)?;
    w.write_all(&line)?;
    w.write_all(b"\n")?;
    Ok(line.len())
}

/// Appends one line and syncs; the line is complete before the call returns.
fn append_line(path: &Path, entry: &ManifestEntry) -> Result<()> {
    let mut line = Vec::new();
    write_manifest_line(&mut line, entry).map_err(|e| DatasetError::io(path, e))?;
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| DatasetError::io(path, e))?;
    f.write_all(&line).map_err(|e| DatasetError::io(path, e))?;
    f.sync_all().map_err(|e| DatasetError::io(path, e))
}

/// Reads a manifest. A kill during an append can leave a last line without its newline:
/// with `repair`, that line is dropped (its image is redone) and the file rewritten.
pub fn read_manifest(path: &Path, repair: bool) -> Result<Vec<ManifestEntry>> {
    read_manifest_mode(
        path,
        if repair {
            ReadMode::Repair
        } else {
            ReadMode::Strict
        },
    )
}

#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum ReadMode {
    /// A half last line is an error.
    Strict,
    /// A half last line is dropped and the file rewritten (this process owns the file).
    Repair,
    /// A half last line is ignored, the file left alone (another process may be
    /// appending to it).
    DropPartial,
}

fn read_manifest_mode(path: &Path, mode: ReadMode) -> Result<Vec<ManifestEntry>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(DatasetError::io(path, e)),
    };
    let complete = match text.rfind('\n') {
        Some(p) => &text[..=p],
        None => "",
    };
    if complete.len() != text.len() {
        match mode {
            ReadMode::Strict => {
                return Err(DatasetError::Manifest {
                    path: path.into(),
                    line: complete.lines().count() + 1,
                    message: "incomplete last line (an interrupted run); run the shard again"
                        .into(),
                });
            }
            ReadMode::Repair => crate::util::write_atomic(path, complete.as_bytes())
                .map_err(|e| DatasetError::io(path, e))?,
            ReadMode::DropPartial => {}
        }
    }
    let mut out = Vec::new();
    for (n, line) in complete.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        out.push(
            serde_json::from_str(line).map_err(|e| DatasetError::Manifest {
                path: path.into(),
                line: n + 1,
                message: e.to_string(),
            })?,
        );
    }
    Ok(out)
}

pub(super) fn shard_manifests(dir: &Path) -> Result<Vec<PathBuf>> {
    let mdir = dir.join("manifests");
    let rd = std::fs::read_dir(&mdir).map_err(|e| DatasetError::io(&mdir, e))?;
    let mut v: Vec<PathBuf> = rd
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.extension().is_some_and(|x| x == "jsonl")
                && !files::is_temp_name(&p.file_name().unwrap_or_default().to_string_lossy())
        })
        .collect();
    v.sort();
    Ok(v)
}

/// The job stored in a dataset folder (its relative mesh paths are not re-checked).
fn stored_job(dir: &Path) -> Result<(String, Job)> {
    let path = dir.join("job.toml");
    let text = crate::limits::read_text(&path).map_err(|e| DatasetError::io(&path, e))?;
    let job = Job::parse_stored(&text, &path.display().to_string())?;
    Ok((text, job))
}

/// Joins the shard manifests of `dir` into `manifest.jsonl` (by index) and writes
/// `coco/<split>.json`. Only images whose files match their manifest line count. Errors
/// naming the missing shards if any image of the job is missing.
pub fn finish(dir: &Path) -> Result<usize> {
    let _lock = lock::lock(dir, lock::Access::Exclusive)?;
    finish_locked(dir, None, None)
}

/// `progress`: ([`Verifying::Finish`], manifest entries verified, entries to verify) as
/// the images' files are read and hashed, the step that takes the time (every file of
/// every image but those `trusted`: a merge's, verified as they moved).
fn finish_locked(
    dir: &Path,
    progress: Option<&mut VerifyProgress<'_>>,
    trusted: Option<&Trusted>,
) -> Result<usize> {
    let (_, job) = stored_job(dir)?;
    let plan = plan::expand(&job);
    let all: BTreeSet<usize> = (0..plan.items.len()).collect();
    let verified = verified_entries(dir, &plan, &all, None, trusted, Verifying::Finish, progress)?;
    let by_index = &verified.by_index;
    let missing: Vec<usize> = (0..plan.items.len())
        .filter(|i| !by_index.contains_key(i))
        .collect();
    if !missing.is_empty() {
        return Err(missing_error(dir, &plan, &missing)?);
    }
    sweep_temps(dir, None)?;
    std::fs::create_dir_all(dir.join("coco")).map_err(|e| DatasetError::io(dir, e))?;
    for split in Split::ALL {
        let images: Vec<coco::SplitImage<'_>> = by_index
            .iter()
            .filter(|(_, l)| l.split == split)
            .map(|(&index, l)| coco::SplitImage {
                index,
                id: &l.id,
                file_name: &l.image,
                width: l.width,
                height: l.height,
            })
            .collect();
        let path = dir.join("coco").join(format!("{}.json", split.name()));
        coco::write_split(dir, split.name(), &images, &path)?;
    }
    // The entries read again from their lines, a batch at a time, as they are written.
    let lines: Vec<LineAt> = by_index.values().map(|l| l.at).collect();
    write_manifest_from(&dir.join("manifest.jsonl"), &verified.manifests, &lines)?;
    Ok(lines.len())
}

/// "k of n images not finished", naming the shards that own them (by the layout of the
/// folder's shard manifests) and the command that finishes them.
fn missing_error(dir: &Path, plan: &Plan, missing: &[usize]) -> Result<DatasetError> {
    let mut counts: BTreeMap<usize, usize> = BTreeMap::new();
    for m in shard_manifests(dir)? {
        let name = m
            .file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned();
        if let Some(n) = name
            .strip_suffix(".jsonl")
            .and_then(|n| n.split_once("-of-"))
            .and_then(|(_, n)| n.parse::<usize>().ok())
        {
            *counts.entry(n).or_default() += 1;
        }
    }
    // The layout most manifests were written with (ties: the larger count).
    let n = counts
        .iter()
        .max_by_key(|(n, k)| (**k, **n))
        .map(|(n, _)| *n)
        .unwrap_or(1);
    let shards: BTreeSet<usize> = missing
        .iter()
        .map(|&i| plan.items[i].instance % n)
        .collect();
    let first: Vec<String> = missing.iter().take(5).map(|i| i.to_string()).collect();
    let how = if n == 1 {
        format!(
            "run `synosis dataset run JOB --out {}` (it renders only what is missing)",
            dir.display()
        )
    } else {
        let list: Vec<String> = shards.iter().map(|s| format!("{s}/{n}")).collect();
        format!(
            "they belong to shard(s) {}: run `synosis dataset run JOB --out {} --shard {}` (it renders only the missing images), then `synosis dataset merge {}`",
            list.join(", "),
            dir.display(),
            list.join(" / --shard "),
            dir.display()
        )
    };
    Ok(DatasetError::layout(
        dir,
        format!(
            "{} of {} images not finished (e.g. {}); {how}",
            missing.len(),
            plan.items.len(),
            first.join(", ")
        ),
    ))
}

/// Merges shard outputs: the first folder is the target; the image folders and manifest
/// lines of the others whose files match their manifest are moved into it (replacing a
/// target image that is missing or differs); then the dataset is finished.
pub fn merge(dirs: &[PathBuf]) -> Result<usize> {
    merge_with_progress(dirs, None)
}

/// [`merge`], calling `progress` with (step, entries verified, entries to verify) while
/// each merged folder's images are verified ([`Verifying::Merge`], once per folder) and
/// then the finish step verifies the merged dataset's files ([`Verifying::Finish`]).
pub fn merge_with_progress(
    dirs: &[PathBuf],
    mut progress: Option<&mut dyn FnMut(Verifying, usize, usize)>,
) -> Result<usize> {
    let Some((target, others)) = dirs.split_first() else {
        return Err(DatasetError::layout(".", "merge needs at least one folder"));
    };
    let (text, job) = stored_job(target)?;
    let _lock = lock::lock(target, lock::Access::Exclusive)?;
    let mut locks = Vec::new();
    for src in others {
        let (t2, _) = stored_job(src)?;
        if t2 != text {
            return Err(DatasetError::layout(
                src,
                format!("holds a different job than {}", target.display()),
            ));
        }
        locks.push(lock::lock(src, lock::Access::Exclusive)?);
    }
    let plan = plan::expand(&job);
    let all: BTreeSet<usize> = (0..plan.items.len()).collect();
    // The images just verified and renamed into the target (or found there equal): the
    // finish below need not read their files again (a copy across file systems is
    // read again).
    let mut trusted = Trusted::new();
    for src in others {
        let verified = verified_entries(
            src,
            &plan,
            &all,
            None,
            None,
            Verifying::Merge,
            progress.as_deref_mut(),
        )?;
        // Each verified line goes to the target's manifest of the same name.
        let mut by_manifest: BTreeMap<usize, Vec<(usize, LineAt)>> = BTreeMap::new();
        for (&index, listed) in &verified.by_index {
            by_manifest
                .entry(listed.at.manifest)
                .or_default()
                .push((index, listed.at));
        }
        std::fs::create_dir_all(target.join("manifests"))
            .map_err(|e| DatasetError::io(target, e))?;
        for (mi, lines) in by_manifest {
            for batch in lines.chunks(VERIFY_BATCH) {
                let ats: Vec<LineAt> = batch.iter().map(|(_, at)| *at).collect();
                let entries = read_lines(&verified.manifests, &ats)?;
                let renamed = move_images(src, target, &entries)?;
                for (e, renamed) in entries.iter().zip(renamed) {
                    if renamed {
                        trusted.insert(e.index, entry_digest(e));
                    }
                }
            }
            let from = &verified.manifests[mi];
            let dest = target
                .join("manifests")
                .join(from.file_name().unwrap_or_default());
            add_manifest_lines(&dest, from, &lines)?;
        }
    }
    drop(locks);
    finish_locked(target, progress, Some(&trusted))
}

/// Moves the folders of `entries` (verified in `src`) into `target`, where the target has
/// no copy of an image or one whose files differ from the entry (checked on all cores).
/// Per entry: whether the target's files are now the verified ones without a copy (moved
/// by a rename, or the target's own copy checked equal).
fn move_images(src: &Path, target: &Path, entries: &[ManifestEntry]) -> Result<Vec<bool>> {
    use rayon::prelude::*;
    let stale: Vec<bool> = entries
        .par_iter()
        .map(|e| target.join("images").join(&e.id).exists() && verify_entry(target, e).is_err())
        .collect();
    let mut same = Vec::with_capacity(entries.len());
    for (e, stale) in entries.iter().zip(stale) {
        let from = src.join("images").join(&e.id);
        let to = target.join("images").join(&e.id);
        if stale {
            std::fs::remove_dir_all(&to).map_err(|err| DatasetError::io(&to, err))?;
        }
        same.push(if to.exists() {
            true
        } else {
            move_dir(&from, &to)?
        });
    }
    Ok(same)
}

/// Adds the manifest lines `moved` of `from` ((image index, line), in image order) to the
/// target's manifest `dest`: its own lines kept, the moved ones for images it does not
/// list, all in image order (each image's lines in their order, its own first), written
/// whole or not at all, the entries read from their lines a batch at a time.
fn add_manifest_lines(dest: &Path, from: &Path, moved: &[(usize, LineAt)]) -> Result<()> {
    let manifests = [dest.to_path_buf(), from.to_path_buf()];
    let mut lines: Vec<(usize, LineAt)> = Vec::new();
    let mut have = BTreeSet::new();
    manifest_lines(dest, ReadMode::Strict, |n, offset, line| {
        let index = parse_entry(dest, n, line)?.index;
        have.insert(index);
        lines.push((
            index,
            LineAt {
                manifest: 0,
                offset,
                len: line.len(),
            },
        ));
        Ok(())
    })?;
    lines.extend(
        moved
            .iter()
            .filter(|(index, _)| !have.contains(index))
            .map(|&(index, at)| (index, LineAt { manifest: 1, ..at })),
    );
    lines.sort_by_key(|(index, _)| *index);
    let ats: Vec<LineAt> = lines.into_iter().map(|(_, at)| at).collect();
    write_manifest_from(dest, &manifests, &ats).map(|_| ())
}

/// Writes the manifest at `path` (whole or not at all) with the entries of `lines` (in
/// `manifests`), in their order, read from their lines a batch at a time; returns where
/// each written line is (offset, length without the newline).
fn write_manifest_from(
    path: &Path,
    manifests: &[PathBuf],
    lines: &[LineAt],
) -> Result<Vec<(u64, usize)>> {
    let mut failed = None;
    let mut written = Vec::with_capacity(lines.len());
    crate::util::write_atomic_with(path, |f| {
        let mut w = std::io::BufWriter::new(f);
        let mut offset = 0u64;
        for batch in lines.chunks(VERIFY_BATCH) {
            let entries = match read_lines(manifests, batch) {
                Ok(e) => e,
                Err(e) => {
                    failed = Some(e);
                    return Err(std::io::Error::other("a manifest line could not be read"));
                }
            };
            for e in &entries {
                let len = write_manifest_line(&mut w, e)?;
                written.push((offset, len));
                offset += len as u64 + 1;
            }
        }
        w.flush()
    })
    .map_err(|e| failed.take().unwrap_or_else(|| DatasetError::io(path, e)))?;
    Ok(written)
}

/// Moves the folder `from` to `to`: a rename (true), or across file systems a copy into
/// a temporary folder renamed into place, then `from` removed (false).
fn move_dir(from: &Path, to: &Path) -> Result<bool> {
    if let Some(p) = to.parent() {
        std::fs::create_dir_all(p).map_err(|e| DatasetError::io(p, e))?;
    }
    if std::fs::rename(from, to).is_ok() {
        return Ok(true);
    }
    // Another file system: copy to a temporary folder, then rename it into place.
    let tmp = crate::util::temp_sibling(to);
    std::fs::create_dir_all(&tmp).map_err(|e| DatasetError::io(&tmp, e))?;
    for e in std::fs::read_dir(from)
        .map_err(|e| DatasetError::io(from, e))?
        .flatten()
    {
        std::fs::copy(e.path(), tmp.join(e.file_name()))
            .map_err(|err| DatasetError::io(e.path(), err))?;
    }
    std::fs::rename(&tmp, to).map_err(|e| DatasetError::io(to, e))?;
    std::fs::remove_dir_all(from).map_err(|e| DatasetError::io(from, e))?;
    Ok(false)
}

/// Re-runs the post-processing of every finished image from its raw files. With
/// `new_job`, its `[[postprocess]]` steps and exposures (`[sensor] exposure`, each
/// finish's `exposure`) replace the stored ones (everything else in it must equal the
/// stored job). Returns the number of images processed.
pub fn postprocess_dir(dir: &Path, new_job: Option<&Path>) -> Result<usize> {
    postprocess_dir_with_progress(dir, new_job, None, None)
}

/// [`postprocess_dir`], calling `progress` with (images processed, images to process) as
/// the images are processed (on all cores, a batch of entries at a time, each shard
/// manifest rewritten as a stream), and `verifying` as the finish step then verifies a
/// finished folder's images ([`Verifying::Finish`]).
pub fn postprocess_dir_with_progress(
    dir: &Path,
    new_job: Option<&Path>,
    mut progress: Option<&mut dyn FnMut(usize, usize)>,
    verifying: Option<&mut dyn FnMut(Verifying, usize, usize)>,
) -> Result<usize> {
    use rayon::prelude::*;
    let (_, mut job) = stored_job(dir)?;
    let _lock = lock::lock(dir, lock::Access::Exclusive)?;
    if let Some(p) = new_job {
        let text = crate::limits::read_text(p).map_err(|e| DatasetError::io(p, e))?;
        let other = Job::parse_stored(&text, &p.display().to_string())?;
        if !job.same_except_postprocess(&other) {
            return Err(DatasetError::layout(
                dir,
                format!(
                    "{} differs from the stored job.toml in more than [[postprocess]]",
                    p.display()
                ),
            ));
        }
        crate::util::write_atomic(&dir.join("job.toml"), text.as_bytes())
            .map_err(|e| DatasetError::io(dir, e))?;
        job = other;
    }
    // Folders written before the manifest recorded the camera: the job's camera (the
    // calibration of a stored job is not read, so only an uncalibrated one).
    let job_camera = match &job.camera_config.calibration {
        None => Some(image_camera_record(&job)?),
        Some(_) => None,
    };
    let process = |e: &ManifestEntry| -> Result<ManifestEntry> {
        let mut e = e.clone();
        let idir = dir.join("images").join(&e.id);
        let camera = e.camera.clone().or_else(|| job_camera.clone()).ok_or_else(|| {
            DatasetError::layout(
                &idir,
                "the manifest line records no camera and the job's calibration is not read from a dataset folder: render the image again",
            )
        })?;
        let (frame, exposed) = read_raw_frame(&job, &e, &camera, &idir)?;
        let (hashes, defects, noise) = write_post(&idir, &job, &e.texture_type, e.seed, frame)?;
        e.files.extend(hashes);
        e.sizes = file_sizes(&idir, &e.files)?;
        // The raw labels are unchanged, so each instance keeps its spec entry.
        let kinds: BTreeMap<u16, Option<String>> = e
            .defects
            .iter()
            .map(|d| (d.instance, d.kind.clone()))
            .collect();
        e.defects = defects
            .into_iter()
            .map(|mut d| {
                d.kind = kinds.get(&d.instance).cloned().flatten();
                d
            })
            .collect();
        e.noise_sigma = noise;
        e.exposure_ev = exposed.exposure_ev;
        e.exposure_ms = exposed.exposure_ms;
        e.bit_depth = job.sensor.model.deep_bit_depth();
        Ok(e)
    };
    let manifests = shard_manifests(dir)?;
    let mut lines: Vec<Vec<LineAt>> = Vec::new();
    for (mi, m) in manifests.iter().enumerate() {
        let mut of = Vec::new();
        // Every line parsed first: a malformed one is an error naming it before any
        // image is processed.
        manifest_lines(m, ReadMode::Strict, |n, offset, line| {
            parse_entry(m, n, line)?;
            of.push(LineAt {
                manifest: mi,
                offset,
                len: line.len(),
            });
            Ok(())
        })?;
        lines.push(of);
    }
    let total: usize = lines.iter().map(Vec::len).sum();
    let mut n = 0;
    // The first image that could not be processed: no image is processed after its batch.
    let mut image_failed: Option<DatasetError> = None;
    for (m, of) in manifests.iter().zip(&lines) {
        if image_failed.is_some() {
            break;
        }
        // The manifest rewritten as its images are processed, a batch at a time. After an
        // image fails, the images not processed keep their lines (the failed one too), so
        // the manifest written still describes every image's files: a later run redoes
        // only what no longer matches. An unreadable line leaves the manifest as it was.
        let mut read_failed = None;
        crate::util::write_atomic_with(m, |f| {
            let mut w = std::io::BufWriter::new(f);
            for batch in of.chunks(VERIFY_CHUNK) {
                let entries = match read_lines(&manifests, batch) {
                    Ok(e) => e,
                    Err(e) => {
                        read_failed = Some(e);
                        return Err(std::io::Error::other("a manifest line could not be read"));
                    }
                };
                if image_failed.is_some() {
                    for e in &entries {
                        write_manifest_line(&mut w, e)?;
                    }
                    continue;
                }
                let results: Vec<Result<ManifestEntry>> = entries.par_iter().map(process).collect();
                for (old, result) in entries.iter().zip(results) {
                    match result {
                        Ok(e) => {
                            write_manifest_line(&mut w, &e)?;
                            n += 1;
                        }
                        Err(err) => {
                            image_failed.get_or_insert(err);
                            write_manifest_line(&mut w, old)?;
                        }
                    }
                }
                if let Some(p) = progress.as_deref_mut() {
                    p(n, total);
                }
            }
            w.flush()
        })
        .map_err(|e| read_failed.take().unwrap_or_else(|| DatasetError::io(m, e)))?;
    }
    if let Some(e) = image_failed {
        return Err(e);
    }
    if dir.join("manifest.jsonl").exists() {
        finish_locked(dir, verifying, None)?;
    }
    Ok(n)
}
