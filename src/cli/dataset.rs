//! `synosis dataset`: run a dataset job (sharded, resumable), merge shards, re-run the
//! post-processing, re-make one image, or check a job file.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use synosis::dataset::{self, RunOptions, Shard, gpu::GpuRenderer, texture_bridge::ModuleTextures};

#[derive(Args)]
pub struct DatasetArgs {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Render a job's images into a folder; killed and restarted, it redoes only unfinished ones.
    Run(RunArgs),
    /// Join shard outputs (the first folder is the target) into one manifest and COCO files.
    Merge {
        /// Dataset folders of one job; the first is the target (it may hold shards too).
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
    },
    /// Re-run post-processing from the stored raw radiance and labels (no rendering).
    Postprocess {
        /// A dataset folder (with job.toml and the raw files of its images).
        dir: PathBuf,
        /// A job whose [[postprocess]] steps replace the stored ones (the rest must match).
        #[arg(long)]
        job: Option<PathBuf>,
    },
    /// Re-make image K of a job alone.
    RenderOne {
        /// The job file (TOML, docs/dataset.md).
        job: PathBuf,
        /// Image number K (0-based, as in images/<K as 6 digits>/).
        #[arg(long)]
        index: usize,
        /// Folder to write images/<K>/ and one-<K>.json into (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Replace the image's seed (path-tracer samples, sensor noise, post-processing
        /// noise) by this one; the scene (instance, defects, textures, view) stays: an
        /// independent render of the same image, for error measurements.
        #[arg(long)]
        image_seed: Option<u64>,
    },
    /// Validate a job (meshes, defect sets included) and print its size; renders nothing.
    Check {
        /// The job file (TOML, docs/dataset.md).
        job: PathBuf,
    },
    /// Write the realism report (HTML + PNGs) of a rendered dataset folder.
    Report {
        /// A rendered dataset folder.
        dir: PathBuf,
        /// Report folder (default DIR/report).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Example images per finish.
        #[arg(long, default_value_t = 4)]
        examples: usize,
    },
    /// Render N images per finish of a job (defective instances first) into --out and
    /// write their realism report (OUT/report/report.html): a look before the full run.
    Preview {
        /// The job file (TOML, docs/dataset.md).
        job: PathBuf,
        /// Images per finish.
        #[arg(long, default_value_t = 2)]
        per_finish: usize,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(Args)]
struct RunArgs {
    /// The job file (TOML, docs/dataset.md).
    job: PathBuf,
    /// Dataset folder (created if missing; a folder holding another job is refused).
    #[arg(long)]
    out: PathBuf,
    /// "i/n": this process renders shard i of n. Default: from SLURM_ARRAY_TASK_ID /
    /// SLURM_ARRAY_TASK_COUNT (and _MIN, _STEP), or JOB_COMPLETION_INDEX with --shard-count (or
    /// SYNOSIS_SHARD_COUNT); else the whole job.
    #[arg(long)]
    shard: Option<String>,
    /// Shard count to pair with JOB_COMPLETION_INDEX (Kubernetes indexed jobs).
    #[arg(long)]
    shard_count: Option<usize>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Write the run's timeline as a Chrome trace (Perfetto, chrome://tracing): each image
    /// and its stages on the thread that ran them, the renderer's CPU phases, the GPU
    /// passes; the GPU's busy share of the run goes to stderr.
    #[arg(long)]
    profile: Option<PathBuf>,
    #[command(flatten)]
    concurrency: Concurrency,
}

/// How many images a run (`dataset run`, `bench-gpu`) keeps in flight and how many
/// renderers share the device: declared once for both commands.
#[derive(clap::Args, Debug, Clone, Copy)]
pub(super) struct Concurrency {
    /// Images in flight: 1 makes, renders and writes one image after the other; N >= 2
    /// renders one while N - 1 writer threads write earlier ones and the next images'
    /// meshes and textures are made ahead (same files either way). Default: 3 on a GPU,
    /// 1 on a CPU Vulkan device (lavapipe), where the overlap only competes for the cores;
    /// with several renderers, one per renderer and two more.
    #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=64))]
    in_flight: Option<usize>,
    /// Renderers, each with its own Vulkan context (queue) on the one device and its own
    /// thread, rendering the next images at once (with --in-flight 2 or more): the GPU
    /// samples one image while another renderer's CPU work (scene set-up, noise checks,
    /// read-back) runs (same files either way). Default: 6 on a GPU for a job with
    /// `[render] noise_target` (at most one per 2 GiB of device memory), else 1 (also on
    /// a CPU Vulkan device such as lavapipe).
    #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=8))]
    renderers: Option<usize>,
}

/// Renderers on a GPU by default (`--renderers`) for a job with `[render] noise_target`:
/// its noise checks are CPU work between short batches, and while one renderer does
/// them the others' batches keep the GPU busy (the paper job at the recommended setting
/// on an H100: 3 renderers 1.3x the images per hour of 1, 6 about 1.2x more than 3). A
/// job of fixed samples keeps 1: there the GPU is busy already, and two renderers sharing
/// it made the paper job at 256 spp 0.64x as fast (docs/benchmarks/dataset.md, "Several
/// renderers" and "Renderers beside one another").
pub const DEFAULT_GPU_RENDERERS_ADAPTIVE: usize = 6;

/// Device-local memory per default renderer: the default is at most one renderer per this
/// much of the GPU's largest device-local heap (each holds its GPU scene, its images'
/// slope maps and sums: about 1 GiB at the paper job's 5792^2 maps and 1224 x 1025
/// pixels, measured on the H100), so that a smaller GPU is not filled.
pub const DEVICE_BYTES_PER_DEFAULT_RENDERER: u64 = 2 << 30;

impl Concurrency {
    /// Refuses `--renderers` above 1 with `--in-flight 1` (one image made, rendered and
    /// written at a time), before any work.
    pub(super) fn check(&self) -> Result<()> {
        if let (Some(n), Some(1)) = (self.renderers, self.in_flight)
            && n > 1
        {
            anyhow::bail!(
                "--renderers {n}: several renderers need --in-flight 2 or more (with --in-flight 1 one image is made, rendered and written at a time)"
            );
        }
        Ok(())
    }

    /// How many renderers: `--renderers`, or the default for the device and job:
    /// [`DEFAULT_GPU_RENDERERS_ADAPTIVE`] (at most one per
    /// [`DEVICE_BYTES_PER_DEFAULT_RENDERER`] of device memory) on a GPU for a job with a
    /// noise target, else 1. With one image in flight (`--in-flight 1`), 1: the image
    /// renders on the calling thread alone ([`Concurrency::check`] refused an explicit
    /// `--renderers` above 1 with it).
    fn renderers(&self, first: &GpuRenderer, job: &dataset::Job) -> usize {
        if self.in_flight == Some(1) {
            return 1;
        }
        self.renderers.unwrap_or_else(|| {
            if !first.device_is_cpu() && job.render.noise_target.is_some() {
                let fit = first.device_local_bytes() / DEVICE_BYTES_PER_DEFAULT_RENDERER;
                DEFAULT_GPU_RENDERERS_ADAPTIVE.min(fit as usize).max(1)
            } else {
                1
            }
        })
    }

    /// `--in-flight`, or its default for the renderer's device:
    /// [`dataset::DEFAULT_IN_FLIGHT`] on a GPU, 1 on a CPU implementation (lavapipe),
    /// where the render uses the same cores as the overlapped stages
    /// (docs/benchmarks/dataset.md, "Overlapped run"); with several renderers
    /// (`renderers` above 1), one per renderer and two more everywhere.
    fn in_flight(&self, renderers: usize, renderer: &GpuRenderer) -> usize {
        self.in_flight.unwrap_or(if renderers > 1 {
            // Every renderer an image, and two more being written.
            renderers + 2
        } else if renderer.device_is_cpu() {
            1
        } else {
            dataset::DEFAULT_IN_FLIGHT
        })
    }

    /// The run's renderers and images in flight for `first`'s device and `job`, and the
    /// renderers beside `first` ([`more_renderers`]).
    pub(super) fn start(&self, first: &GpuRenderer, job: &dataset::Job) -> Result<Started> {
        let renderers = self.renderers(first, job);
        Ok(Started {
            renderers,
            in_flight: self.in_flight(renderers, first),
            more: more_renderers(renderers, first)?,
        })
    }
}

/// What [`Concurrency::start`] chose and started.
pub(super) struct Started {
    /// Renderers in all, `first` included.
    pub renderers: usize,
    pub in_flight: usize,
    /// The renderers beside `first`.
    pub more: Vec<GpuRenderer>,
}

/// The `n - 1` renderers beside `first` on its Vulkan device
/// ([`GpuRenderer::beside`]: each its own context, queue, path tracer and GPU scenes),
/// made at once on threads of their own.
fn more_renderers(n: usize, first: &GpuRenderer) -> Result<Vec<GpuRenderer>> {
    first
        .beside(n.saturating_sub(1))
        .map_err(|e| with_renderers_hint(anyhow::Error::msg(e), n))
        .context("starting the GPU renderers beside the first")
}

/// What a failure says when `renderers` above 1 shared the GPU and it ran out of GPU
/// memory: the setting that decides it, its range, and what to do.
pub(super) fn renderers_memory_hint(error: &str, renderers: usize) -> Option<String> {
    const OUT_OF_GPU_MEMORY: [&str; 2] =
        ["GPU memory allocation failed", "ERROR_OUT_OF_DEVICE_MEMORY"];
    (renderers > 1 && OUT_OF_GPU_MEMORY.iter().any(|m| error.contains(m))).then(|| {
        format!(
            "--renderers {renderers}: the renderers share the GPU's memory, each with its own GPU scene and slope maps (allowed 1 to 8; fewer need less, 1 the least)"
        )
    })
}

/// `error` with [`renderers_memory_hint`] as its outer context where it applies.
pub(super) fn with_renderers_hint(error: anyhow::Error, renderers: usize) -> anyhow::Error {
    match renderers_memory_hint(&format!("{error:#}"), renderers) {
        Some(hint) => error.context(hint),
        None => error,
    }
}

/// `RunOptions::more_renderers` of `more`.
pub(super) fn renderer_refs(
    more: &mut [GpuRenderer],
) -> Vec<&mut (dyn dataset::ImageRenderer + Send)> {
    more.iter_mut()
        .map(|r| r as &mut (dyn dataset::ImageRenderer + Send))
        .collect()
}

/// A progress bar on stderr drawn with `template` (indicatif's; the default style if it
/// does not parse); `hidden`: one that draws nothing.
pub(super) fn styled_bar(template: &str, hidden: bool) -> indicatif::ProgressBar {
    let bar = if hidden {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(0)
    };
    bar.set_style(bar_style(template));
    bar
}

fn bar_style(template: &str) -> indicatif::ProgressStyle {
    indicatif::ProgressStyle::with_template(template)
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
}

/// `dataset run`'s bar through a run's steps (and `dataset merge`'s and `postprocess`'s
/// through theirs): checking the images earlier runs wrote, rendering, verifying every
/// image at the finish; each step after the first starts the
/// bar (and its elapsed time and ETA) afresh with its own words (the first keeps the time
/// since the run started: the renderer's start-up and the first image).
struct RunBar {
    bar: indicatif::ProgressBar,
    step: std::cell::Cell<Option<RunStep>>,
}

#[derive(Clone, Copy, PartialEq)]
enum RunStep {
    Verifying(dataset::Verifying),
    Rendering,
    /// `dataset postprocess`'s images.
    Postprocessing,
}

const RENDERING_BAR: &str = "{bar:40} {pos}/{len} images, {elapsed} elapsed, ETA {eta} ({per_sec})";

impl RunBar {
    fn new(hidden: bool) -> Self {
        let bar = styled_bar(RENDERING_BAR, hidden);
        bar.enable_steady_tick(Duration::from_millis(500));
        RunBar {
            bar,
            step: std::cell::Cell::new(None),
        }
    }

    /// The bar at `step`, (done, total).
    fn show(&self, step: RunStep, done: usize, total: usize) {
        let before = self.step.get();
        if before != Some(step) {
            let style = match step {
                RunStep::Rendering => bar_style(RENDERING_BAR),
                RunStep::Postprocessing => bar_style(
                    "post-processing {bar:40} {pos}/{len} images, {elapsed} elapsed, ETA {eta}",
                ),
                RunStep::Verifying(v) => bar_style(&format!(
                    "{}: {{bar:24}} {{pos}}/{{len}}, {{elapsed}} elapsed, ETA {{eta}}",
                    v.describe()
                )),
            };
            self.bar.set_style(style);
            if before.is_some() {
                self.bar.reset();
            }
            self.step.set(Some(step));
        }
        self.bar.set_length(total as u64);
        self.bar.set_position(done as u64);
    }
}

/// A `RunOptions::progress` callback that moves `bar` to (done, total).
pub(super) fn bar_progress(bar: &indicatif::ProgressBar) -> impl FnMut(usize, usize) + '_ {
    |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    }
}

fn resolve_shard(a: &RunArgs) -> Result<Shard> {
    use synosis::dataset::shard_env::{self, ShardSource};
    let (shard, source) = shard_env::resolve_shard(a.shard.as_deref(), a.shard_count, &|n| {
        std::env::var(n).ok()
    })
    .map_err(anyhow::Error::msg)?;
    if source == ShardSource::Slurm
        && shard == Shard::ALL
        && let Some(s) = shard_env::single_shard_in(&a.out)
    {
        eprintln!(
            "{} holds only shard {}/{}'s work and this is a one-task array (a resubmitted task?): resuming shard {}/{}",
            a.out.display(),
            s.index,
            s.count,
            s.index,
            s.count
        );
        return Ok(s);
    }
    Ok(shard)
}

pub(super) fn gpu_renderer() -> Result<GpuRenderer> {
    let accel = super::accel_from_env()?.unwrap_or(synosis::trace::AccelChoice::Auto);
    GpuRenderer::new(accel, false)
        .map_err(anyhow::Error::msg)
        .context("starting the GPU renderer")
}

pub fn run(a: DatasetArgs) -> Result<()> {
    match a.cmd {
        Cmd::Run(r) => run_job(r),
        Cmd::Merge { dirs } => {
            // Verifying every file of every image is what takes the time: each merged
            // folder's, then the finish's of the whole dataset.
            let bar = RunBar::new(false);
            let mut progress = |v, done, total| bar.show(RunStep::Verifying(v), done, total);
            let n = dataset::merge_with_progress(&dirs, Some(&mut progress));
            bar.bar.finish_and_clear();
            let n = n.context("merge")?;
            println!(
                "{}: {n} images, manifest.jsonl and coco/*.json written",
                dirs[0].display()
            );
            Ok(())
        }
        Cmd::Postprocess { dir, job } => {
            // Each image's raw files read and its post-processed ones written, then (in a
            // finished folder) every image's files verified.
            let bar = RunBar::new(false);
            let mut progress = |done, total| bar.show(RunStep::Postprocessing, done, total);
            let mut verifying = |v, done, total| bar.show(RunStep::Verifying(v), done, total);
            let n = dataset::postprocess_dir_with_progress(
                &dir,
                job.as_deref(),
                Some(&mut progress),
                Some(&mut verifying),
            );
            bar.bar.finish_and_clear();
            let n = n.context("postprocess")?;
            println!("{}: {n} images post-processed", dir.display());
            Ok(())
        }
        Cmd::RenderOne {
            job,
            index,
            out,
            image_seed,
        } => {
            synosis::util::check_writable_dir(&out)
                .with_context(|| format!("--out {}", out.display()))?;
            let prep = dataset::prepare(&job).with_context(|| format!("job {}", job.display()))?;
            let mut renderer = gpu_renderer()?;
            let e = dataset::render_one_seeded(
                &prep,
                index,
                image_seed,
                &out,
                &mut renderer,
                &mut ModuleTextures::default(),
            )?;
            println!("{}", serde_json::to_string_pretty(&e)?);
            Ok(())
        }
        Cmd::Report { dir, out, examples } => {
            let job_path = dir.join("job.toml");
            let text = std::fs::read_to_string(&job_path)
                .with_context(|| format!("reading {}", job_path.display()))?;
            let job = dataset::Job::parse_stored(&text, &job_path.display().to_string())?;
            let out = out.unwrap_or_else(|| dir.join("report"));
            // Reading every image's files is what takes the time.
            let bar = styled_bar(
                "reading {bar:40} {pos}/{len} images, {elapsed} elapsed, ETA {eta}",
                false,
            );
            let mut progress = bar_progress(&bar);
            let reports = dataset::report::write_folder_report(
                &dir,
                &job,
                examples,
                &out,
                Some(&mut progress),
            );
            bar.finish_and_clear();
            let reports = reports?;
            print_report(&reports, &out);
            Ok(())
        }
        Cmd::Preview {
            job,
            per_finish,
            out,
        } => {
            let prep = dataset::prepare(&job).with_context(|| format!("job {}", job.display()))?;
            let items = dataset::report::preview_items(&prep, per_finish);
            let mut renderer = gpu_renderer()?;
            let mut textures = ModuleTextures::default();
            let mut entries = Vec::new();
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            for (k, &index) in items.iter().enumerate() {
                eprintln!("preview: image {index} ({}/{})", k + 1, items.len());
                entries.push(dataset::render_one(
                    &prep,
                    index,
                    &out,
                    &mut renderer,
                    &mut textures,
                )?);
            }
            let mut lines = String::new();
            for e in &entries {
                lines.push_str(&serde_json::to_string(e)?);
                lines.push('\n');
            }
            std::fs::write(out.join("preview.jsonl"), lines)?;
            std::fs::write(out.join("job.toml"), &prep.job_text)?;
            let rdir = out.join("report");
            let reports =
                dataset::report::write_report(&out, &prep.job, &entries, per_finish, &rdir)?;
            print_report(&reports, &rdir);
            Ok(())
        }
        Cmd::Check { job } => {
            let prep = dataset::prepare(&job).with_context(|| format!("job {}", job.display()))?;
            let count =
                |s: dataset::Split| prep.plan.instances.iter().filter(|i| i.split == s).count();
            println!(
                "{}: OK: {} images, {} object instances (train {}, val {}, test {}), {} defect sets, {} views",
                job.display(),
                prep.plan.items.len(),
                prep.plan.instances.len(),
                count(dataset::Split::Train),
                count(dataset::Split::Val),
                count(dataset::Split::Test),
                prep.defect_sets.len(),
                prep.job.viewpoints().len()
            );
            Ok(())
        }
    }
}

fn run_job(a: RunArgs) -> Result<()> {
    let shard = resolve_shard(&a)?;
    // Everything is checked before the renderer starts or a file is written.
    a.concurrency.check()?;
    synosis::util::check_writable_dir(&a.out)
        .with_context(|| format!("--out {}", a.out.display()))?;
    if let Some(p) = &a.profile
        && let Some(dir) = p.parent()
    {
        synosis::util::check_writable_dir(dir)
            .with_context(|| format!("--profile {}", p.display()))?;
    }
    let profiler = synosis::vk::Profiler::new();
    let prep = profiler
        .cpu("prepare job", || dataset::prepare(&a.job))
        .with_context(|| format!("job {}", a.job.display()))?;
    super::accel_from_env()?;
    let mut renderer = profiler.cpu("Vulkan init, pipelines, energy tables", gpu_renderer)?;
    let bar = RunBar::new(a.quiet);
    let mut progress = |done, total| bar.show(RunStep::Rendering, done, total);
    let mut verifying = |v, done, total| bar.show(RunStep::Verifying(v), done, total);
    let Started {
        renderers,
        in_flight,
        mut more,
    } = profiler.cpu("Vulkan init, pipelines, energy tables", || {
        a.concurrency.start(&renderer, &prep.job)
    })?;
    let result = dataset::run(
        &prep,
        &a.out,
        &mut renderer,
        &mut ModuleTextures::default(),
        RunOptions {
            shard,
            fail_after: None,
            progress: Some(&mut progress),
            verifying: Some(&mut verifying),
            profiler: a.profile.as_ref().map(|_| &profiler),
            in_flight,
            more_renderers: renderer_refs(&mut more),
            limit: None,
        },
    );
    bar.bar.finish_and_clear();
    // The profile is written even when the run stopped on an error (up to the error).
    if let Some(p) = &a.profile {
        profiler
            .write_chrome_trace(p)
            .with_context(|| format!("writing {}", p.display()))?;
        let wall = profiler.now_us() / 1e3;
        let gpu = profiler.busy_ms("gpu");
        eprintln!(
            "profile {}: {:.0} ms wall, GPU busy {:.0} ms ({:.1} %)",
            p.display(),
            wall,
            gpu,
            100.0 * gpu / wall.max(1e-9)
        );
    }
    let report = result
        .map_err(|e| with_renderers_hint(e.into(), renderers))
        .with_context(|| format!("dataset run into {}", a.out.display()))?;
    println!(
        "shard {}/{}: {} images ({} already done, {} rendered){}",
        shard.index,
        shard.count,
        report.shard_items,
        report.already_done,
        report.rendered,
        if report.finished {
            "; dataset finished (manifest.jsonl, coco/)"
        } else {
            "; run `synosis dataset merge` when all shards are done"
        }
    );
    Ok(())
}

fn print_report(reports: &[dataset::report::FinishReport], out: &std::path::Path) {
    println!(
        "finish\timages\tgrey_p1\tgrey_p99\trho_peak_db\tdents_kept\tscratches_kept\tkept_by_spec_entry"
    );
    for r in reports {
        let mut db: Vec<f64> = r.texture.iter().map(|t| t.1.peak_over_floor_db).collect();
        db.sort_by(f64::total_cmp);
        let (dk, dn) = r.kept(1);
        let (sk, sn) = r.kept(2);
        println!(
            "{}\t{}\t{}\t{}\t{}\t{dk}/{dn}\t{sk}/{sn}\t{}",
            r.name,
            r.images,
            r.p01_p99.0,
            r.p01_p99.1,
            db.get(db.len() / 2)
                .map_or("-".into(), |d| format!("{d:.1}")),
            dataset::report::kinds_list(&r.kinds)
        );
    }
    eprintln!("report: {}", out.join("report.html").display());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn out_of_gpu_memory_with_several_renderers_names_the_setting() {
        let oom = "image 7 (000007): GPU memory allocation failed: Out of memory";
        let hint = renderers_memory_hint(oom, 6).unwrap();
        assert!(
            hint.starts_with("--renderers 6:") && hint.contains("allowed 1 to 8"),
            "{hint}"
        );
        let vk = "Vulkan call failed: ERROR_OUT_OF_DEVICE_MEMORY";
        assert!(renderers_memory_hint(vk, 2).is_some());
        // One renderer, or another error: no hint.
        assert!(renderers_memory_hint(oom, 1).is_none());
        assert!(renderers_memory_hint("writing faces.png: disk full", 6).is_none());
        let e = with_renderers_hint(anyhow::anyhow!("{oom}"), 3);
        let text = format!("{e:#}");
        assert!(
            text.starts_with("--renderers 3:") && text.ends_with(oom),
            "{text}"
        );
    }
}
