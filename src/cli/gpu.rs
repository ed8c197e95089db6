//! `synosis info` and `synosis raycast`.

use std::path::PathBuf;

use anyhow::Context as _;
use clap::Args;
use synosis::render::raycast::raycast;
use synosis::scene::Camera;
use synosis::scene::{Degenerates, import_mesh};
use synosis::trace::{AccelChoice, TraceScene, auto_backend, resolve};
use synosis::vk::{Context, ContextOptions, Profiler};

#[derive(Args)]
pub struct InfoArgs {
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

pub fn info(a: InfoArgs) -> anyhow::Result<()> {
    let ctx = Context::new(&ContextOptions {
        validation: false,
        ray_query: true,
    })?;
    let (auto, why) = auto_backend(&ctx.info);
    if a.json {
        let mut v = serde_json::to_value(&ctx.info)?;
        v["auto_backend"] = serde_json::Value::from(auto.name());
        v["auto_reason"] = serde_json::Value::from(why);
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    let i = &ctx.info;
    println!("device:          {} ({})", i.name, i.device_type);
    println!("driver:          {} {}", i.driver_name, i.driver_info);
    println!("vulkan:          {}", i.vulkan_version);
    println!(
        "ray query:       {}",
        if i.ray_query_supported { "yes" } else { "no" }
    );
    println!(
        "buffer addresses: {} (the path tracer and the software backends read their buffers through them)",
        if i.buffer_device_address { "yes" } else { "no" }
    );
    println!(
        "64-bit integers: {} (the software backends load their BVH eight bytes at a time)",
        if i.shader_int64 { "yes" } else { "no" }
    );
    println!(
        "subgroup arithmetic: {} (the path tracer's extra camera rays walk their loops in step)",
        if i.subgroup_arithmetic { "yes" } else { "no" }
    );
    if i.is_cpu {
        println!("lanes:           {}", i.cpu_lanes.describe());
        println!(
            "shader cache:    {}",
            match &i.cpu_shader_cache {
                Some(d) => format!("{d} (this lane width's own folder)"),
                None => "Mesa's own folder (the driver's default lane width)".into(),
            }
        );
    }
    println!("auto backend:    {} ({why})", auto.name());
    println!(
        "timestamps:      {} (period {} ns)",
        i.timestamps_supported, i.timestamp_period_ns
    );
    println!(
        "max storage buffer range: {} MiB",
        i.max_storage_buffer_range / (1 << 20)
    );
    println!("max texel buffer elements: {}", i.max_texel_buffer_elements);
    for (k, h) in i.memory_heaps.iter().enumerate() {
        let kind = match (h.device_local, h.host_visible) {
            (true, true) => " (device local, host visible)",
            (true, false) => " (device local)",
            (false, true) => " (host visible)",
            (false, false) => "",
        };
        println!(
            "memory heap {k}:   {:.1} GiB{kind}",
            h.size_bytes as f64 / (1u64 << 30) as f64,
        );
    }
    Ok(())
}

#[derive(Args)]
pub struct CompileArgs {
    /// Only this backend's pipelines (default: every backend the device supports).
    #[arg(long, value_enum)]
    accel: Option<AccelChoice>,
    /// Also the path tracer's split-paths variants (`[render] split_paths`, opt-in; about
    /// as long again on lavapipe): a job with split paths otherwise compiles them at its
    /// first image.
    #[arg(long)]
    split_paths: bool,
}

/// Compiles every pipeline into the driver's shader cache, the backends at once.
pub fn compile_cmd(a: CompileArgs) -> anyhow::Result<()> {
    use synosis::trace::Backend;
    let options = ContextOptions {
        validation: false,
        ray_query: true,
    };
    let ctx = Context::new(&options)?;
    // Without --accel: every backend the device can run, as `resolve` decides it (ray
    // query needs the extension, the software backends buffer device addresses).
    let backends: Vec<Backend> = match a.accel {
        Some(choice) => vec![resolve(choice, &ctx.info)?],
        None => [
            AccelChoice::RayQuery,
            AccelChoice::Software,
            AccelChoice::SoftwareWide,
        ]
        .into_iter()
        .filter_map(|c| resolve(c, &ctx.info).ok())
        .collect(),
    };
    let device = ctx.info.name.clone();
    drop(ctx);
    eprintln!(
        "compiling the pipelines of {}{} on {} (each run once on a 16 x 16 image)",
        backends
            .iter()
            .map(|b| b.name())
            .collect::<Vec<_>>()
            .join(", "),
        if a.split_paths {
            ", with the split-paths path tracers"
        } else {
            ""
        },
        device
    );
    let start = std::time::Instant::now();
    synosis::render::pipelines::prepare(&options, &backends, a.split_paths, &|b, t| {
        eprintln!("  {:<14} {:6.1} s", b.name(), t.as_secs_f64());
    })?;
    eprintln!("done in {:.1} s", start.elapsed().as_secs_f64());
    Ok(())
}

#[derive(Args)]
pub struct RaycastArgs {
    /// Mesh to raycast (.gltf or .glb).
    mesh: PathBuf,
    /// Output directory (created if missing): depth.exr and normals.png.
    #[arg(long)]
    out: PathBuf,
    /// Trace backend.
    #[arg(long, value_enum, default_value_t = AccelChoice::Auto)]
    accel: AccelChoice,
    /// Image width in pixels.
    #[arg(long, default_value_t = 640, value_parser = clap::value_parser!(u32).range(1..=16384))]
    width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 480, value_parser = clap::value_parser!(u32).range(1..=16384))]
    height: u32,
    /// Remove zero-area triangles instead of refusing the mesh.
    #[arg(long)]
    drop_degenerate: bool,
    /// Write a Chrome trace (Perfetto, chrome://tracing) of CPU phases and GPU passes.
    #[arg(long)]
    profile: Option<PathBuf>,
}

pub fn raycast_cmd(a: RaycastArgs) -> anyhow::Result<()> {
    let profiler = Profiler::new();
    let degenerates = if a.drop_degenerate {
        Degenerates::Drop
    } else {
        Degenerates::Reject
    };
    let imported = profiler.cpu("import glTF", || import_mesh(&a.mesh, degenerates))?;
    if imported.dropped_degenerate > 0 {
        eprintln!(
            "warning: dropped {} degenerate triangle(s)",
            imported.dropped_degenerate
        );
    }
    let mesh = imported.mesh;
    let ctx = profiler.cpu("Vulkan init", || {
        Context::new(&ContextOptions {
            validation: false,
            ray_query: true,
        })
    })?;
    let backend = resolve(a.accel, &ctx.info)?;
    let scene = TraceScene::build(&ctx, &mesh, backend, Some(&profiler))?;
    let cam = Camera::framing(&mesh, a.width, a.height);
    let img = raycast(&ctx, &scene, &cam, Some(&profiler))?;
    ctx.check_validation()?;

    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    profiler.cpu("write images", || -> anyhow::Result<()> {
        let depth = a.out.join("depth.exr");
        synosis::image_io::write_exr_f32(
            &depth,
            a.width as usize,
            a.height as usize,
            "Z",
            &img.depth,
        )
        .with_context(|| format!("writing {}", depth.display()))?;
        let normals = a.out.join("normals.png");
        synosis::image_io::write_png_rgba8(&normals, a.width, a.height, &img.normals)
            .with_context(|| format!("writing {}", normals.display()))?;
        Ok(())
    })?;
    let hits = img.depth.iter().filter(|&&d| d > 0.0).count();
    println!(
        "{}: {} triangles, {}x{}, {hits} pixels hit; build {:.1} ms, raycast pass {:.2} ms on {} ({})",
        a.mesh.display(),
        mesh.triangles.len(),
        a.width,
        a.height,
        scene.build_ms,
        img.timing.gpu_ms,
        ctx.info.name,
        backend.name()
    );
    if let Some(p) = &a.profile {
        profiler
            .write_chrome_trace(p)
            .with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}
