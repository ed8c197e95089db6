//! `synosis render`: a path-traced inspection image of a scene file.

use std::path::PathBuf;

use anyhow::Context as _;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use synosis::render::annotate::DEFAULT_COVERAGE_GRID;
use synosis::render::energy::EnergyTables;
use synosis::render::noise::{CameraNoise, NoiseStop, RayChoice};
use synosis::render::path_trace::{FrameOptions, RenderScene, render_scene_on, spp_map};
use synosis::render::pixels::Exposure;
use synosis::render::sensor::{Responsivity, capture, exposure_time_s};
use synosis::render::{PathTracer, RenderSettings};
use synosis::scene::assemble::load_object_inspected;
use synosis::scene::config::{SceneConfig, parse_view};
use synosis::scene::mesh::is_inspected;
use synosis::trace::{AccelChoice, resolve};
use synosis::vk::{Context, ContextOptions, Profiler};

#[derive(Args)]
pub struct RenderArgs {
    /// Scene file (TOML, docs/scene-format.md).
    scene: PathBuf,
    /// Output directory (created if missing): radiance.exr, image.png, the annotation
    /// masks mask.png, instances.png, faces.png, coverage.png and, with `[render]
    /// adaptive_radius`, each pixel's samples spp.png (16-bit).
    #[arg(long)]
    out: PathBuf,
    /// Samples per pixel (overrides render.spp).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=1_048_576))]
    spp: Option<u32>,
    /// Image width; keeps the sensor size, so the pixel pitch scales (overrides camera.width).
    #[arg(long, requires = "height")]
    width: Option<u32>,
    /// Image height (with --width).
    #[arg(long, requires = "width")]
    height: Option<u32>,
    /// Trace backend (overrides SYNOSIS_ACCEL, which overrides render.accel).
    #[arg(long, value_enum)]
    accel: Option<AccelChoice>,
    /// Viewpoint, e.g. A20 (overrides camera.view and any look_at / matrix / opencv pose).
    #[arg(long)]
    view: Option<String>,
    /// Write a 16-bit PNG instead of 8-bit.
    #[arg(long)]
    png16: bool,
    /// Write a Chrome trace (Perfetto) of CPU phases and GPU passes.
    #[arg(long)]
    profile: Option<PathBuf>,
}

pub fn run(a: RenderArgs) -> anyhow::Result<()> {
    // Before any work: the output folder must be writable.
    synosis::util::check_writable_dir(&a.out)
        .with_context(|| format!("--out {}", a.out.display()))?;
    if let Some(p) = &a.profile
        && let Some(dir) = p.parent()
    {
        synosis::util::check_writable_dir(dir)
            .with_context(|| format!("--profile {}", p.display()))?;
    }
    let profiler = Profiler::new();
    let mut cfg = SceneConfig::load(&a.scene)?;
    if let Some(s) = a.spp {
        cfg.render.spp = s;
    }
    if let (Some(w), Some(h)) = (a.width, a.height) {
        cfg.set_resolution(w, h)?;
    }
    if let Some(acc) = super::accel_from_env()? {
        cfg.render.accel = acc;
    }
    if let Some(acc) = a.accel {
        cfg.render.accel = acc;
    }
    if let Some(v) = &a.view {
        parse_view(v).context("--view")?;
        cfg.camera.view = v.clone();
        // --view replaces any pose the file gives.
        cfg.camera.look_at = None;
        cfg.camera.matrix = None;
        cfg.camera.opencv = None;
    }
    cfg.validate()?;
    if a.png16 && cfg.sensor.is_some() {
        anyhow::bail!(
            "--png16: with a [sensor] section, sensor.bit_depth sets the PNG depth (8 -> 8-bit PNG, 10/12/16 -> 16-bit PNG)"
        );
    }
    // The device and the path tracer first: its pipeline is made on a thread of its own
    // (seconds on lavapipe) while the object and its maps are loaded below.
    let tables = profiler.cpu("energy tables", EnergyTables::compute);
    let ctx = profiler.cpu("Vulkan init", || {
        Context::new(&ContextOptions {
            validation: false,
            ray_query: true,
        })
    })?;
    let backend = resolve(cfg.render.accel, &ctx.info)?;
    let specialized = RenderSettings::from(&cfg).specialize;
    let tracer = profiler.cpu("path tracer (begun)", || {
        PathTracer::beginning(&ctx, backend, &tables, !specialized)
    })?;
    let (object, inspected) = profiler
        .cpu("load object", || load_object_inspected(&cfg))
        .context("loading the object")?;
    for f in &inspected {
        eprintln!(
            "inspect: face {} (id {} in faces.png) = {}: {} triangles, {:.1} mm^2{}",
            synosis::scene::mesh::face_name(f.face),
            f.face,
            f.selector.describe(),
            f.triangles,
            f.area,
            if f.regions.is_empty() {
                String::new()
            } else {
                format!(", regions {:?}", f.regions)
            }
        );
    }
    // Regions, curved patches, the finish's maps (a `file` height map read and turned into
    // slopes, or synthesised), lights and camera.
    let scene = profiler.cpu("assemble scene (regions, maps, slopes)", || {
        RenderScene::assemble(&object, &cfg)
    })?;
    print_region_materials(&scene.stage);
    let bar = ProgressBar::new(cfg.render.spp as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} spp {elapsed_precise} eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let start = std::time::Instant::now();
    // `[render] noise_target`: the camera the sensor step below exposes (validate checked
    // that a [sensor] and camera.f_number are there).
    let noise = match (cfg.render.noise_target, &cfg.sensor, cfg.camera.f_number) {
        (Some(target), Some(s), Some(n)) => Some(NoiseStop {
            camera: CameraNoise {
                resp: Responsivity::new(&scene.view.camera, cfg.camera.focal_mm as f64, n, s),
                sensor: s.clone(),
                exposure_factor: 1.0,
            },
            target: target as f64,
            // NoiseStop::first_check keeps it within [2, spp].
            min_spp: cfg
                .render
                .min_spp
                .unwrap_or(synosis::render::noise::DEFAULT_MIN_SPP),
            estimator: cfg.render.noise_estimate.unwrap_or_default(),
            adaptive_radius: cfg.render.adaptive_radius,
            growth: cfg.render.noise_target_growth.unwrap_or(0.0) as f64,
            // `[render] analytic_rays_max`: the rays chosen at the first check.
            rays: cfg
                .render
                .analytic_rays_max
                .map(|max| RayChoice::up_to(max, cfg.render.analytic_ray_cost.map(f64::from))),
        }),
        _ => None,
    };
    let opts = FrameOptions {
        annotate_grid: Some(DEFAULT_COVERAGE_GRID),
        profiler: Some(&profiler),
        noise: noise.as_ref(),
    };
    let frame = render_scene_on(&tracer, &scene, &cfg, opts, |done| {
        bar.set_position(done as u64)
    })?;
    let img = frame.radiance;
    bar.finish_and_clear();
    for e in &frame.noise_checks {
        eprintln!(
            "noise check: {} spp (mean {:.1}), render noise / camera noise {:.3}",
            e.spp, e.mean_spp, e.ratio
        );
    }
    if let Some(m) = frame.analytic_rays_chosen {
        eprintln!(
            "analytic rays: {m} per sample after the first check (chosen in [1, {}])",
            cfg.render.analytic_rays_max.unwrap_or(m)
        );
    }
    if let Some(e) = &frame.noise {
        eprintln!(
            "noise target {}: stopped at {} spp, render noise {:.3} DN rms over camera noise {:.3} DN rms = {:.3} ({} object pixels)",
            cfg.render.noise_target.unwrap_or_default(),
            frame.spp,
            e.render_rms_dn,
            e.camera_rms_dn,
            e.ratio,
            e.pixels
        );
    }
    let secs = start.elapsed().as_secs_f64();
    ctx.check_validation()?;
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let (w, h) = (img.width, img.height);
    // The EMVA 1288 sensor: exposure (auto: from the inspected faces' pixels) and noise
    // from the linear radiance, seeded by the image's seed.
    let captured = match &cfg.sensor {
        None => None,
        Some(s) => {
            let n = cfg.camera.f_number.context("camera.f_number")?;
            let resp = Responsivity::new(&scene.view.camera, cfg.camera.focal_mm as f64, n, s);
            let mask: Option<Vec<bool>> = frame
                .annotation
                .as_ref()
                .map(|a| a.face.iter().map(|&f| is_inspected(f)).collect());
            // The lens's diffraction on the radiance the sensor sees (radiance.exr stays
            // the path tracer's).
            let seen = synosis::render::optics::seen_by_sensor(
                &img.data,
                w as usize,
                h as usize,
                cfg.camera.pixel_um as f64,
                n,
                s,
                Some(&profiler),
            );
            let t = exposure_time_s(&resp, &seen, mask.as_deref(), s).context("[sensor]")?;
            let cap = capture(&resp, &seen, t, s, cfg.render.seed as u64).context("[sensor]")?;
            eprintln!(
                "sensor: exposure {:.6} ms, {} bit",
                cap.exposure_s * 1e3,
                cap.bit_depth
            );
            Some(cap)
        }
    };
    profiler.cpu("write images", || -> anyhow::Result<()> {
        let exr = a.out.join("radiance.exr");
        synosis::image_io::write_exr_f32(&exr, w as usize, h as usize, "Y", &img.data)
            .with_context(|| format!("writing {}", exr.display()))?;
        let png = a.out.join("image.png");
        if let Some(cap) = &captured {
            match cap.codes8() {
                Some(c8) => synosis::image_io::write_png_gray8(&png, w, h, &c8),
                None => synosis::image_io::write_png_gray16(&png, w, h, &cap.codes),
            }
        } else {
            let sensor = Exposure::new(cfg.camera.exposure, cfg.camera.gain);
            if a.png16 {
                synosis::image_io::write_png_gray16(&png, w, h, &sensor.quantise16(&img.data))
            } else {
                synosis::image_io::write_png_gray8(&png, w, h, &sensor.quantise8(&img.data))
            }
        }
        .with_context(|| format!("writing {}", png.display()))?;
        if let Some(ann) = &frame.annotation {
            ann.write_pngs(&a.out)
                .context("writing the annotation masks")?;
        }
        if let Some(counts) = &frame.pixel_spp {
            // `[render] adaptive_radius`: each pixel's samples, as a dataset image's.
            let path = a.out.join("spp.png");
            synosis::image_io::write_png_gray16(&path, w, h, &spp_map(counts))
                .with_context(|| format!("writing {}", path.display()))?;
        }
        Ok(())
    })?;
    let mean = img.data.iter().map(|&v| v as f64).sum::<f64>() / img.data.len().max(1) as f64;
    println!(
        "{} view {}: {}x{}, {} spp ({:?} sampler, {}, texture {}), {} bounces, {} in {:.1} s (GPU {:.0} ms), mean radiance {:.4}",
        a.scene.display(),
        cfg.camera.describe_pose(),
        w,
        h,
        frame.spp,
        cfg.render.sampler,
        cfg.light.describe(),
        cfg.texture.kind,
        cfg.render.max_bounces,
        backend.name(),
        secs,
        img.gpu_ms,
        mean
    );
    if let Some(p) = &a.profile {
        profiler
            .write_chrome_trace(p)
            .with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

/// On stderr: what each `[[material.region]]` entry got (triangles, material).
fn print_region_materials(stage: &synosis::scene::assemble::Stage) {
    use synosis::gpu_interface::MAT_REGION_FIRST;
    use synosis::scene::materials::SurfaceKind;
    for (i, m) in stage.surfaces.iter().enumerate() {
        let id = MAT_REGION_FIRST + i as u32;
        let n = stage.materials.iter().filter(|&&x| x == id).count();
        let what = match m.kind {
            SurfaceKind::Diffuse => format!("diffuse, albedo {}", m.albedo),
            SurfaceKind::Conductor => format!(
                "conductor{}, n {} k {}, alpha {}",
                m.preset.map_or(String::new(), |p| format!(" {}", p.name())),
                m.ior_n,
                m.ior_k,
                m.alpha
            ),
        };
        eprintln!(
            "material.region entry {i}: {n} triangles, {what}, finish {:?}",
            m.finish
        );
    }
}
