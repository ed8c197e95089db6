//! `synosis bench-gpu`: the per-image benchmark of a dataset job on whatever Vulkan device
//! is present (lavapipe included): images per hour, the stage split, the GPU's busy share
//! of the run, peak memory, and the ray throughput of the backend. `tools/bench-gpu`
//! wraps it; docs/benchmarks.md keeps the tables with their dates and devices.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context as _, Result};
use clap::Args;
use synosis::dataset::{self, RunOptions, Shard, gpu::GpuRenderer, texture_bridge::ModuleTextures};
use synosis::vk::Profiler;

#[derive(Args)]
pub struct BenchGpuArgs {
    /// The dataset job to time (docs/dataset.md).
    #[arg(long, default_value = "scenes/paper-dataset.toml")]
    job: PathBuf,
    /// Work folder (the images are written there; it must be empty or absent).
    #[arg(long)]
    out: PathBuf,
    /// Object instances to render (each with all of the job's views): the shard 0 of
    /// `instances in the job / this` is rendered (instances spread over the job, each of
    /// another finish in the paper job, as in a run of many shards), or with
    /// `--consecutive` the job's first this many.
    #[arg(long, default_value_t = 1)]
    instances: usize,
    /// Render the job's first `--instances` object instances in the job's order
    /// (finish-major: the first finish's, sharing its textures as a whole-job run's
    /// instances do) instead of a shard spread over the job.
    #[arg(long)]
    consecutive: bool,
    /// Override the job's `[render] width` (pixels; the camera keeps its sensor size).
    #[arg(long)]
    width: Option<u32>,
    /// Override the job's `[render] height`.
    #[arg(long)]
    height: Option<u32>,
    /// Override the job's `[render] spp`.
    #[arg(long)]
    spp: Option<u32>,
    /// Rays per set of the throughput test (primary and random rays on a 100 k-triangle
    /// mesh): this squared; 0 skips it.
    #[arg(long, default_value_t = 1024)]
    rays_side: u32,
    /// Also write the numbers as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Also write the run's Chrome trace here.
    #[arg(long)]
    profile: Option<PathBuf>,
    #[command(flatten)]
    concurrency: super::dataset::Concurrency,
}

/// The job text with `[render]` overrides.
fn job_text(a: &BenchGpuArgs) -> Result<String> {
    let text = std::fs::read_to_string(&a.job)
        .with_context(|| format!("reading the job {}", a.job.display()))?;
    let mut v: toml::Table =
        toml::from_str(&text).with_context(|| format!("parsing the job {}", a.job.display()))?;
    let render = v
        .entry("render")
        .or_insert_with(|| toml::Value::Table(Default::default()));
    let r = render
        .as_table_mut()
        .context("the job's `render` is not a table")?;
    for (key, val) in [("width", a.width), ("height", a.height), ("spp", a.spp)] {
        if let Some(x) = val {
            r.insert(key.into(), toml::Value::Integer(x as i64));
        }
    }
    Ok(toml::to_string(&v)?)
}

fn peak_rss_mib() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// This process's CPU time so far (user + system, all threads), from /proc/self/stat's
/// utime and stime in the kernel's fixed user-space tick of 1/100 s (USER_HZ).
fn process_cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The fields after the command name (which is in parentheses and may hold spaces):
    // state is field 3, utime 14 and stime 15.
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

pub fn run(a: BenchGpuArgs) -> Result<()> {
    if a.instances == 0 {
        anyhow::bail!("--instances 0: allowed 1 or more");
    }
    a.concurrency.check()?;
    if a.out.exists() && std::fs::read_dir(&a.out)?.next().is_some() {
        anyhow::bail!("--out {}: must be empty or absent", a.out.display());
    }
    let text = job_text(&a)?;
    let base = a.job.parent().unwrap_or(Path::new("."));
    let prep = dataset::prepare_text(&text, &a.job.display().to_string(), base)
        .with_context(|| format!("job {}", a.job.display()))?;
    let n_inst = prep.plan.instances.len().max(1);
    let (shard, limit, chosen) = if a.consecutive {
        // The items of the first instances, which the job's order puts first.
        let chosen = a.instances.min(n_inst);
        let limit = prep
            .plan
            .items
            .iter()
            .take_while(|i| i.instance < chosen)
            .count();
        (Shard::ALL, Some(limit), chosen)
    } else {
        let count = (n_inst / a.instances).max(1);
        (Shard { index: 0, count }, None, n_inst.div_ceil(count))
    };

    let profiler = Profiler::new();
    let t0 = Instant::now();
    let accel = super::accel_from_env()?.unwrap_or(synosis::trace::AccelChoice::Auto);
    let mut renderer = GpuRenderer::new(accel, false).map_err(anyhow::Error::msg)?;
    let super::dataset::Started {
        renderers,
        in_flight,
        mut more,
    } = a.concurrency.start(&renderer, &prep.job)?;
    let startup_s = t0.elapsed().as_secs_f64();
    let describe = synosis::dataset::ImageRenderer::describe(&renderer);
    let bar = indicatif::ProgressBar::new(0);
    let mut progress = super::dataset::bar_progress(&bar);
    let loop_start_us = profiler.now_us();
    let cpu0 = process_cpu_s();
    let t1 = Instant::now();
    dataset::run(
        &prep,
        &a.out,
        &mut renderer,
        &mut ModuleTextures::default(),
        RunOptions {
            shard,
            progress: Some(&mut progress),
            profiler: Some(&profiler),
            in_flight,
            more_renderers: super::dataset::renderer_refs(&mut more),
            limit,
            ..Default::default()
        },
    )
    .map_err(|e| super::dataset::with_renderers_hint(e.into(), renderers))
    .with_context(|| format!("dataset run into {}", a.out.display()))?;
    bar.finish_and_clear();
    let loop_s = t1.elapsed().as_secs_f64();
    let loop_end_us = profiler.now_us();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    // The CPU share of the image loop: the process's CPU time over the loop's wall time
    // on all cores (1.0: every core busy all the time).
    let cpu = cpu0
        .zip(process_cpu_s())
        .map(|(a, b)| (b - a, (b - a) / (loop_s * cores as f64).max(1e-9)));
    if let Some(p) = &a.profile {
        profiler
            .write_chrome_trace(p)
            .with_context(|| format!("writing {}", p.display()))?;
    }
    let manifest = a.out.join("manifests").join(shard.file_name());
    let entries = dataset::read_manifest(&manifest, false)?;
    let n = entries.len().max(1) as f64;
    let mut stages: BTreeMap<String, f64> = BTreeMap::new();
    for e in &entries {
        for (k, v) in &e.stage_seconds {
            *stages.entry(k.clone()).or_default() += v / n;
        }
    }
    let gpu_ms = profiler.busy_ms("gpu");
    let busy = gpu_ms / ((loop_end_us - loop_start_us) / 1e3).max(1e-9);
    let per_image = loop_s / n;
    // From the first image's render on: the first object instance's mesh and textures
    // are made before it with nothing to overlap, which a long run pays once.
    let first_render_us = profiler
        .spans()
        .iter()
        .filter(|s| s.track == "cpu" && s.name == "render")
        .map(|s| s.start_us)
        .fold(f64::INFINITY, f64::min)
        .clamp(loop_start_us, loop_end_us);
    let steady = (loop_s - (first_render_us - loop_start_us) / 1e6).max(0.0) / n;
    // The device memory in live buffers and images after each image's render (the run's
    // profile counters): first, last and most, and the allocations' count first and last.
    let counter = |name: &str| -> Vec<f64> {
        profiler
            .counters()
            .iter()
            .filter(|c| c.name == name)
            .map(|c| c.value)
            .collect()
    };
    let (memory, allocations) = (
        counter(dataset::DEVICE_MEMORY_COUNTER),
        counter(dataset::DEVICE_ALLOCATIONS_COUNTER),
    );
    let device_memory = (memory.first().zip(memory.last()))
        .zip(allocations.first().zip(allocations.last()))
        .map(|((&m0, &m1), (&a0, &a1))| {
            let most = memory.iter().copied().fold(m0, f64::max);
            (m0, m1, most, a0, a1)
        });
    let (w, h, spp) = (
        prep.job.render.width,
        prep.job.render.height,
        prep.job.render.spp,
    );

    // The device's name, and the ray throughput of the renderer's backend on a
    // 100 k-triangle mesh, on one more context (the renderer keeps its own private).
    let ctx = synosis::vk::Context::new(&synosis::vk::ContextOptions {
        validation: false,
        ray_query: true,
    })?;
    let info = format!("{} ({})", ctx.info.name, ctx.info.driver_info);
    let rays = if a.rays_side > 0 {
        Some(ray_throughput(&ctx, accel, a.rays_side)?)
    } else {
        None
    };
    println!("| quantity | value |");
    println!("|---|---|");
    println!("| device | {info} |");
    println!("| renderer | {describe} |");
    println!(
        "| job | {} : {} images ({chosen} instance(s) of {n_inst}, {}), {w} x {h}, {spp} spp |",
        a.job.display(),
        entries.len(),
        if a.consecutive {
            "the first, consecutive"
        } else {
            "spread over the job"
        }
    );
    println!("| images in flight | {in_flight} |");
    println!("| renderers (device contexts) | {renderers} |");
    println!("| start-up (Vulkan, pipelines, energy tables) | {startup_s:.2} s |");
    println!(
        "| per image | {per_image:.2} s ({:.0} images per hour) |",
        3600.0 / per_image
    );
    println!(
        "| per image from the first render on (a long run) | {steady:.2} s ({:.0} images per hour) |",
        3600.0 / steady
    );
    for (k, v) in &stages {
        println!("| stage {k} | {v:.3} s |");
    }
    println!(
        "| GPU busy | {:.1} % of the image loop ({gpu_ms:.0} ms of {:.0} ms) |",
        100.0 * busy,
        loop_s * 1e3
    );
    if let Some((cpu_s, f)) = cpu {
        println!(
            "| CPU busy | {:.1} % of {cores} cores over the image loop ({cpu_s:.1} s of CPU time) |",
            100.0 * f
        );
    }
    if let Some(m) = peak_rss_mib() {
        println!("| peak memory (RSS) | {m:.0} MiB |");
    }
    if let Some((m0, m1, most, a0, a1)) = device_memory {
        println!(
            "| device memory in live buffers and images, after the first image / the last (most) | {m0:.1} / {m1:.1} MiB ({most:.1}); {a0:.0} / {a1:.0} allocations |"
        );
    }
    if let Some((name, tris, nrays, p, r)) = &rays {
        println!(
            "| rays ({name}, {tris} triangles, {nrays} per set) | primary {p:.1} Mrays/s, random {r:.1} Mrays/s (GPU pass time) |"
        );
    }
    if let Some(j) = &a.json {
        let v = serde_json::json!({
            "device": info,
            "renderer": describe,
            "images": entries.len(),
            "instances": chosen,
            "consecutive": a.consecutive,
            "width": w, "height": h, "spp": spp,
            "in_flight": in_flight,
            "renderers": renderers,
            "startup_s": startup_s,
            "per_image_s": per_image,
            "images_per_hour": 3600.0 / per_image,
            "steady_per_image_s": steady,
            "stages_s": stages,
            "gpu_busy_fraction": busy,
            "cpu_cores": cores,
            "cpu_busy_fraction": cpu.map(|c| c.1),
            "peak_rss_mib": peak_rss_mib(),
            "device_memory": device_memory.map(|(m0, m1, most, a0, a1)| serde_json::json!({
                "first_mib": m0, "last_mib": m1, "most_mib": most,
                "first_allocations": a0, "last_allocations": a1,
            })),
            "rays": rays.as_ref().map(|(name, tris, nrays, p, r)| serde_json::json!({
                "backend": name, "triangles": tris, "rays_per_set": nrays,
                "primary_mrays_s": p, "random_mrays_s": r,
            })),
        });
        synosis::util::write_atomic(j, serde_json::to_string_pretty(&v)?.as_bytes())
            .with_context(|| format!("writing {}", j.display()))?;
    }
    Ok(())
}

/// (backend, triangles, rays per set, primary Mrays/s, random Mrays/s), best of three.
fn ray_throughput(
    ctx: &std::sync::Arc<synosis::vk::Context>,
    accel: synosis::trace::AccelChoice,
    side: u32,
) -> Result<(String, usize, usize, f64, f64)> {
    use synosis::render::raycast::{benchmark_rays, trace_rays};
    use synosis::scene::procedural::bumpy_sphere;
    use synosis::trace::TraceScene;
    let backend = synosis::trace::resolve(accel, &ctx.info)?;
    let mesh = bumpy_sphere(316, 159, 10.0, 0.05);
    let (primary, random) = benchmark_rays(&mesh, side);
    let scene = TraceScene::build(ctx, &mesh, backend, None)?;
    let mut rates = Vec::new();
    for rays in [&primary, &random] {
        trace_rays(ctx, &scene, &rays[..rays.len().min(4096)], None)?;
        let mut best = f64::INFINITY;
        for _ in 0..3 {
            best = best.min(trace_rays(ctx, &scene, rays, None)?.1.gpu_ms);
        }
        rates.push(rays.len() as f64 / best.max(1e-9) / 1e3);
    }
    Ok((
        backend.name().to_string(),
        mesh.triangles.len(),
        primary.len(),
        rates[0],
        rates[1],
    ))
}
