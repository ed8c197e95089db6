//! Speed against error of the path tracer: renders a scene at a list of spp, times each
//! render, and computes the RMSE against a high-spp reference (rendered first, with
//! another seed). Writes a Markdown table, an SVG plot (log-log RMSE over seconds) and the
//! reference image (EXR), and can export the scene for Mitsuba 3 (tools/mitsuba_scene.py).
//! Run by tools/bench-convergence; results in docs/benchmarks/rendering.md.
//!
//! `cargo run --release --example render_convergence -- --help`

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context as _;
use clap::Parser;
use synosis::render::energy::EnergyTables;
use synosis::render::path_trace::{MAT_LIGHT, MAT_TABLE, RenderScene, load_object, path_trace};
use synosis::scene::config::{DirectLight, LightSampling, SamplerKind, SceneConfig};
use synosis::trace::Backend;
use synosis::vk::{Context, ContextOptions};

#[derive(Parser)]
struct Args {
    /// Scene file.
    #[arg(long, default_value = "scenes/demo.toml")]
    scene: PathBuf,
    /// Image size (keeps the field of view).
    #[arg(long, default_value_t = 153)]
    width: u32,
    #[arg(long, default_value_t = 128)]
    height: u32,
    /// Comma-separated spp list.
    #[arg(long, default_value = "1,4,16,64,256,1024")]
    spp: String,
    /// Reference spp (Sobol, facing light sampling, ray query, seed + 1000).
    #[arg(long, default_value_t = 4096)]
    ref_spp: u32,
    /// Configurations to time, each backend:sampler:light[:direct] (direct: "sampled",
    /// the default, or "analytic"), comma-separated, e.g.
    /// "ray-query:sobol:facing,software:sobol:facing,ray-query:independent:uniform".
    #[arg(
        long,
        default_value = "ray-query:sobol:facing,software:sobol:facing,ray-query:independent:uniform"
    )]
    configs: String,
    /// Turn Kulla-Conty compensation off (Mitsuba's roughconductor has none).
    #[arg(long)]
    no_compensation: bool,
    /// The reference's configuration (the --configs syntax; default: ray query, Sobol,
    /// facing, the scene's direct light).
    #[arg(long)]
    ref_config: Option<String>,
    /// Render the reference as two halves of --ref-spp with independent seeds and
    /// average them: their difference estimates the reference's own noise, which is
    /// taken out of every row's RMSE ("net RMSE" = sqrt(RMSE^2 - reference variance);
    /// the row and the reference are independent).
    #[arg(long)]
    ref_halves: bool,
    /// Reuse this reference (an earlier run's `<name>-reference.exr` of the same scene
    /// and size) instead of rendering one.
    #[arg(long)]
    reference: Option<PathBuf>,
    /// Output directory for the table (.md), the plot (.svg) and the reference (.exr).
    #[arg(long, default_value = "target/convergence")]
    out: PathBuf,
    /// File name stem of the outputs.
    #[arg(long, default_value = "render-convergence")]
    name: String,
    /// Also write the scene for tools/mitsuba_scene.py into this directory.
    #[arg(long)]
    export_mitsuba: Option<PathBuf>,
    /// Also write every row's image (`<name>-<config>-<spp>.exr`, ':' as '_').
    #[arg(long)]
    save_images: bool,
}

struct Row {
    label: String,
    spp: u32,
    secs: f64,
    gpu_ms: f64,
    rmse: f64,
    /// 1-minute load average after the render (2 shared cores: context for the seconds).
    load: f64,
}

fn load_avg() -> f64 {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(f64::NAN)
}

fn main() -> anyhow::Result<()> {
    let a = Args::parse();
    let mut cfg = SceneConfig::load(&a.scene)?;
    cfg.set_resolution(a.width, a.height)?;
    if a.no_compensation {
        cfg.material.energy_compensation = false;
    }
    let spps: Vec<u32> = a
        .spp
        .split(',')
        .map(|s| s.trim().parse::<u32>().context("--spp"))
        .collect::<anyhow::Result<_>>()?;
    std::fs::create_dir_all(&a.out)?;
    let object = load_object(&cfg)?;
    let scene = RenderScene::assemble(&object, &cfg)?;
    let scene_sampling = cfg.light.sampling;
    if let Some(dir) = &a.export_mitsuba {
        export_mitsuba(dir, &scene, &cfg)?;
    }
    let tables = EnergyTables::compute();
    let ctx = Context::new(&ContextOptions {
        validation: false,
        ray_query: true,
    })?;
    // The light sampling is the assembled scene's (each emitter's), not a render setting:
    // a configuration with another one renders a scene assembled with it, once, before
    // its clock starts.
    let other_sampling = std::cell::OnceCell::new();
    let render = |cfg: &SceneConfig, backend| -> anyhow::Result<(Vec<f32>, f64, f64)> {
        let scene = if cfg.light.sampling == scene_sampling {
            &scene
        } else {
            if other_sampling.get().is_none() {
                let assembled = RenderScene::assemble(&object, cfg)?;
                let _ = other_sampling.set((cfg.light.sampling, assembled));
            }
            let (sampling, assembled) = other_sampling.get().expect("just set");
            anyhow::ensure!(
                *sampling == cfg.light.sampling,
                "a third light sampling ({:?}) in one run",
                cfg.light.sampling
            );
            assembled
        };
        let t = Instant::now();
        let img = path_trace(&ctx, scene, cfg, backend, &tables, None, |_| {})?;
        Ok((img.data, t.elapsed().as_secs_f64(), img.gpu_ms))
    };
    // Warm-up: lavapipe compiles the shader at the first dispatch.
    let mut used: Vec<Backend> = Vec::new();
    for c in a.configs.split(',').chain(a.ref_config.as_deref()) {
        let b = parse_config(c, &cfg)?.0;
        if !used.contains(&b) {
            used.push(b);
        }
    }
    if a.ref_config.is_none() && !used.contains(&Backend::RayQuery) {
        used.push(Backend::RayQuery);
    }
    for b in used {
        let mut w = cfg.clone();
        w.render.spp = 1;
        render(&w, b)?;
    }
    let (ref_backend, mut rc) = match &a.ref_config {
        Some(c) => parse_config(c, &cfg).context("--ref-config")?,
        None => {
            let mut rc = cfg.clone();
            rc.render.sampler = SamplerKind::Sobol;
            rc.light.sampling = LightSampling::Facing;
            (Backend::RayQuery, rc)
        }
    };
    rc.render.spp = a.ref_spp;
    rc.render.batch_spp = 64;
    rc.render.seed = cfg.render.seed.wrapping_add(1000);
    // The reference's own noise (variance per pixel, averaged over the image) when it
    // is rendered as two independent halves: Var(mean) = mean((R1 - R2)^2) / 4.
    let mut ref_var = None;
    let (reference, ref_secs, _) = match &a.reference {
        // A reference written by an earlier run of the same scene and size.
        Some(path) => {
            let (w, h, data) = synosis::image_io::read_exr_f32(path)
                .with_context(|| format!("--reference {}", path.display()))?;
            anyhow::ensure!(
                (w, h) == (a.width as usize, a.height as usize),
                "--reference {}: {w} x {h}, the run is {} x {}",
                path.display(),
                a.width,
                a.height
            );
            (data, 0.0, 0.0)
        }
        None if a.ref_halves => {
            anyhow::ensure!(
                a.ref_spp >= 2,
                "--ref-spp {}: at least 2 with --ref-halves",
                a.ref_spp
            );
            rc.render.spp = a.ref_spp / 2;
            let (r1, s1, g1) = render(&rc, ref_backend)?;
            rc.render.seed = cfg.render.seed.wrapping_add(2000);
            let (r2, s2, g2) = render(&rc, ref_backend)?;
            ref_var = Some(rmse(&r1, &r2).powi(2) / 4.0);
            let mean = r1.iter().zip(&r2).map(|(x, y)| 0.5 * (x + y)).collect();
            (mean, s1 + s2, g1 + g2)
        }
        None => render(&rc, ref_backend)?,
    };
    let ref_mean = reference.iter().map(|&v| v as f64).sum::<f64>() / reference.len() as f64;
    synosis::image_io::write_exr_f32(
        &a.out.join(format!("{}-reference.exr", a.name)),
        a.width as usize,
        a.height as usize,
        "Y",
        &reference,
    )?;
    eprintln!(
        "reference: {} spp in {ref_secs:.1} s, mean {ref_mean:.5}, load {:.2}",
        a.ref_spp,
        load_avg()
    );
    let mut rows = Vec::new();
    for c in a.configs.split(',') {
        let (backend, mut cc) = parse_config(c, &cfg)?;
        for &spp in &spps {
            cc.render.spp = spp;
            cc.render.batch_spp = spp.min(64);
            let (img, secs, gpu_ms) = render(&cc, backend)?;
            if a.save_images {
                synosis::image_io::write_exr_f32(
                    &a.out.join(format!(
                        "{}-{}-{spp}.exr",
                        a.name,
                        c.trim().replace(':', "_")
                    )),
                    a.width as usize,
                    a.height as usize,
                    "Y",
                    &img,
                )?;
            }
            let rmse = rmse(&img, &reference);
            eprintln!("{c} {spp:5} spp: {secs:8.2} s, RMSE {rmse:.3e}");
            rows.push(Row {
                label: c.trim().to_string(),
                spp,
                secs,
                gpu_ms,
                rmse,
                load: load_avg(),
            });
        }
    }
    // A row's RMSE without the reference's own noise (independent renders: the mean
    // squared difference is the sum of both variances and the squared bias).
    let net = |r: &Row| ref_var.map(|v| (r.rmse * r.rmse - v).max(0.0).sqrt());
    let mut md = String::new();
    writeln!(
        md,
        "Scene `{}` at {} x {}, {} bounces, compensation {}; reference: {} spp ({}, other seed{}), mean radiance {ref_mean:.5}.\n",
        a.scene.display(),
        a.width,
        a.height,
        cfg.render.max_bounces,
        if cfg.material.energy_compensation {
            "on"
        } else {
            "off"
        },
        a.ref_spp,
        a.ref_config
            .as_deref()
            .unwrap_or("Sobol, facing, ray query, the scene's direct light"),
        match ref_var {
            Some(v) => format!(
                "; two halves, its own noise {:.3e} RMSE, taken out of the net RMSE",
                v.sqrt()
            ),
            None => String::new(),
        }
    )?;
    let net_head = if ref_var.is_some() { " net RMSE |" } else { "" };
    writeln!(
        md,
        "| backend:sampler:light | spp | seconds (wall) | GPU ms | RMSE |{net_head} RMSE / mean | load (1 min) |"
    )?;
    writeln!(
        md,
        "|---|---|---|---|---|{}---|---|",
        if ref_var.is_some() { "---|" } else { "" }
    )?;
    for r in &rows {
        let net_col = net(r).map_or(String::new(), |n| format!(" {n:.3e} |"));
        writeln!(
            md,
            "| {} | {} | {:.2} | {:.0} | {:.3e} |{net_col} {:.3} | {:.2} |",
            r.label,
            r.spp,
            r.secs,
            r.gpu_ms,
            r.rmse,
            r.rmse / ref_mean,
            r.load
        )?;
    }
    let json: Vec<serde_json::Value> = rows
        .iter()
        .map(|r| {
            serde_json::json!({"label": r.label, "spp": r.spp, "secs": r.secs,
                "gpu_ms": r.gpu_ms, "rmse": r.rmse, "rmse_net": net(r), "load": r.load})
        })
        .collect();
    std::fs::write(
        a.out.join(format!("{}.json", a.name)),
        serde_json::to_string_pretty(&serde_json::json!({
            "ref_spp": a.ref_spp, "ref_secs": ref_secs, "ref_mean": ref_mean,
            "ref_config": a.ref_config, "ref_var": ref_var, "rows": json
        }))?,
    )?;
    std::fs::write(a.out.join(format!("{}.md", a.name)), &md)?;
    let series: Vec<(String, Vec<(f64, f64)>)> = group(&rows);
    std::fs::write(
        a.out.join(format!("{}.svg", a.name)),
        svg_plot(&series, "seconds (wall)", "RMSE"),
    )?;
    print!("{md}");
    Ok(())
}

/// One `--configs` entry, backend:sampler:light[:direct], on top of the scene's
/// settings; direct is "sampled" (the default), "analytic" (the scene's
/// `analytic_rays`) or "analyticN" (N camera rays per sample).
fn parse_config(c: &str, cfg: &SceneConfig) -> anyhow::Result<(Backend, SceneConfig)> {
    let parts: Vec<&str> = c.trim().split(':').collect();
    anyhow::ensure!(
        parts.len() == 3 || parts.len() == 4,
        "--configs: {c:?} is not backend:sampler:light[:direct]"
    );
    let backend = match parts[0] {
        "ray-query" => Backend::RayQuery,
        "software" => Backend::Software,
        "software-wide" => Backend::SoftwareWide,
        o => anyhow::bail!("backend {o:?}: allowed ray-query, software, software-wide"),
    };
    let mut cc = cfg.clone();
    cc.render.sampler = match parts[1] {
        "sobol" => SamplerKind::Sobol,
        "independent" => SamplerKind::Independent,
        o => anyhow::bail!("sampler {o:?}"),
    };
    cc.light.sampling = match parts[2] {
        "facing" => LightSampling::Facing,
        "uniform" => LightSampling::Uniform,
        o => anyhow::bail!("light sampling {o:?}"),
    };
    cc.render.direct_light = match parts.get(3).copied() {
        None | Some("sampled") => DirectLight::Sampled,
        Some("analytic") => DirectLight::Analytic,
        Some(o) => match o.strip_prefix("analytic").map(str::parse::<u32>) {
            Some(Ok(n)) => {
                cc.render.analytic_rays = n;
                DirectLight::Analytic
            }
            _ => anyhow::bail!("direct light {o:?}: sampled, analytic or analyticN"),
        },
    };
    cc.validate()?;
    Ok((backend, cc))
}

fn rmse(a: &[f32], b: &[f32]) -> f64 {
    (a.iter()
        .zip(b)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        / a.len().max(1) as f64)
        .sqrt()
}

fn group(rows: &[Row]) -> Vec<(String, Vec<(f64, f64)>)> {
    let mut out: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    for r in rows {
        match out.iter_mut().find(|(l, _)| *l == r.label) {
            Some((_, pts)) => pts.push((r.secs, r.rmse)),
            None => out.push((r.label.clone(), vec![(r.secs, r.rmse)])),
        }
    }
    out
}

/// A log-log line plot written by hand (no plotting crate): one polyline per series,
/// decade grid lines, a legend.
pub fn svg_plot(series: &[(String, Vec<(f64, f64)>)], xlabel: &str, ylabel: &str) -> String {
    let (w, h, l, r, t, b) = (640.0, 420.0, 70.0, 20.0, 20.0, 50.0);
    let pts = series
        .iter()
        .flat_map(|s| s.1.iter())
        .filter(|p| p.0 > 0.0 && p.1 > 0.0);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in pts {
        x0 = x0.min(p.0.log10());
        x1 = x1.max(p.0.log10());
        y0 = y0.min(p.1.log10());
        y1 = y1.max(p.1.log10());
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    let (x0, x1, y0, y1) = (
        x0.floor(),
        x1.ceil().max(x0.floor() + 1.0),
        y0.floor(),
        y1.ceil().max(y0.floor() + 1.0),
    );
    let px = |x: f64| l + (x.log10() - x0) / (x1 - x0) * (w - l - r);
    let py = |y: f64| t + (y1 - y.log10()) / (y1 - y0) * (h - t - b);
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n"
    );
    for e in x0 as i32..=x1 as i32 {
        let x = px(10f64.powi(e));
        let _ = writeln!(
            s,
            "<line x1=\"{x:.1}\" y1=\"{t}\" x2=\"{x:.1}\" y2=\"{}\" stroke=\"#ddd\"/><text x=\"{x:.1}\" y=\"{}\" text-anchor=\"middle\">1e{e}</text>",
            h - b,
            h - b + 16.0
        );
    }
    for e in y0 as i32..=y1 as i32 {
        let y = py(10f64.powi(e));
        let _ = writeln!(
            s,
            "<line x1=\"{l}\" y1=\"{y:.1}\" x2=\"{}\" y2=\"{y:.1}\" stroke=\"#ddd\"/><text x=\"{}\" y=\"{:.1}\" text-anchor=\"end\">1e{e}</text>",
            w - r,
            l - 6.0,
            y + 4.0
        );
    }
    let _ = writeln!(
        s,
        "<text x=\"{}\" y=\"{}\" text-anchor=\"middle\">{xlabel}</text><text x=\"16\" y=\"{}\" text-anchor=\"middle\" transform=\"rotate(-90 16 {})\">{ylabel}</text>",
        (l + w - r) / 2.0,
        h - 10.0,
        (t + h - b) / 2.0,
        (t + h - b) / 2.0
    );
    let colours = [
        "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b",
    ];
    for (i, (label, pts)) in series.iter().enumerate() {
        let c = colours[i % colours.len()];
        let poly: Vec<String> = pts
            .iter()
            .filter(|p| p.0 > 0.0 && p.1 > 0.0)
            .map(|p| format!("{:.1},{:.1}", px(p.0), py(p.1)))
            .collect();
        let _ = writeln!(
            s,
            "<polyline fill=\"none\" stroke=\"{c}\" stroke-width=\"2\" points=\"{}\"/>",
            poly.join(" ")
        );
        for p in &poly {
            let (x, y) = p.split_once(',').unwrap_or(("0", "0"));
            let _ = writeln!(s, "<circle cx=\"{x}\" cy=\"{y}\" r=\"3\" fill=\"{c}\"/>");
        }
        let ly = t + 14.0 + 16.0 * i as f64;
        let _ = writeln!(
            s,
            "<line x1=\"{}\" y1=\"{ly}\" x2=\"{}\" y2=\"{ly}\" stroke=\"{c}\" stroke-width=\"2\"/><text x=\"{}\" y=\"{}\">{label}</text>",
            w - r - 250.0,
            w - r - 230.0,
            w - r - 225.0,
            ly + 4.0
        );
    }
    s.push_str("</svg>\n");
    s
}

/// One group of the object's triangles for Mitsuba: its vertices (unshared, three per
/// triangle), their map coordinates when the group carries a slope map, and which map.
#[derive(Default)]
struct ExportPart {
    positions: Vec<glam::Vec3>,
    uv: Vec<[f32; 2]>,
    /// (texel buffer, handedness): the shading frame's t = cross(n, map x) is +map up
    /// (1) or -map up (-1).
    map: Option<(usize, i32)>,
}

/// Splits the object's triangles by slope map: triangles without one, and per distinct
/// map and handedness of the triangle's frame one group with per-vertex map coordinates
/// (u = map x / width, v = map y / height, texel centres at (i + 0.5) / size, row 0 at
/// v = 0, as Mitsuba's bitmap texture reads them). The object's placed maps are planar
/// projections (`slope::lookup`), so interpolating the vertices' coordinates over a
/// triangle is the shader's lookup exactly. Returns the parts and the decoded slopes of
/// each texel buffer ([dh/dx, dh/dy] per texel, the f16 values the shader reads).
#[allow(clippy::type_complexity)]
fn object_parts(
    scene: &RenderScene,
) -> anyhow::Result<(Vec<ExportPart>, Vec<(u32, u32, Vec<[f32; 2]>)>)> {
    use synosis::gpu_interface::{
        MAP_BUFFER_MASK, MAP_LABELLED_ONLY, MAP_WRAP, MAT_LABELLED, MAT_MAP_SHIFT, MAT_SLOT_MASK,
    };
    use synosis::render::slope;
    let stage = &scene.stage;
    anyhow::ensure!(
        stage.surfaces.is_empty(),
        "--export-mitsuba: the scene has [[material.region]] entries; the export writes one material"
    );
    anyhow::ensure!(
        scene.face_maps.is_empty() || stage.curved.is_empty(),
        "--export-mitsuba: slope maps on curved patches (revolved, triplanar) are not exported"
    );
    let placed = synosis::scene::assemble::place_maps(
        &scene.face_maps,
        &stage.face_frames,
        &stage.regions,
        &scene.placement,
    )?;
    let slots = stage.regions.len() + stage.curved.len() + 1;
    let (headers, texels) = slope::pack(&placed, slots, u64::MAX)?;
    let mut buffers = Vec::new();
    for (b, t) in texels.iter().enumerate() {
        // The buffer's dimensions from any header that reads it (all read it whole).
        let dims = headers
            .iter()
            .find(|h| (h.dims[3] & MAP_BUFFER_MASK) as usize == b + 1)
            .map(|h| (h.dims[0], h.dims[1]));
        let slopes = t
            .iter()
            .map(|&w| slope::unpack_half2(w))
            .collect::<Vec<_>>();
        let (w, h) = dims.unwrap_or((0, 0));
        anyhow::ensure!(
            slopes.len() == (w * h) as usize,
            "slope buffer {b}: {} texels for a {w} x {h} map",
            slopes.len()
        );
        buffers.push((w, h, slopes));
    }
    let mut parts: Vec<ExportPart> = vec![ExportPart::default()];
    let v3 = |a: &[f32]| glam::Vec3::from_slice(&a[..3]);
    let words = synosis::render::gpu_scene::material_words(stage);
    for (t, &word) in stage.mesh.triangles.iter().zip(&words) {
        if word & 0xff == MAT_TABLE || word & 0xff == MAT_LIGHT {
            continue;
        }
        let p = t.map(|i| stage.mesh.positions[i as usize]);
        let h = &headers[((word >> MAT_MAP_SHIFT) & MAT_SLOT_MASK) as usize];
        let buffer = (h.dims[3] & MAP_BUFFER_MASK) as usize;
        let mapped =
            buffer != 0 && (h.dims[3] & MAP_LABELLED_ONLY == 0 || word & MAT_LABELLED != 0);
        if !mapped {
            parts[0].positions.extend(p);
            continue;
        }
        anyhow::ensure!(
            h.dims[3] & MAP_WRAP != 0,
            "--export-mitsuba: maps clipped to their extent (`[texture] cover = \"faces\"`) are not exported; use cover = \"part\""
        );
        let (ax, up) = (v3(&h.axis_x), v3(&h.axis_up));
        // Mitsuba's face normal (this winding) and its tangent frame's t = cross(n, s).
        let n = (p[1] - p[0]).cross(p[2] - p[0]).normalize();
        let hand = if n.cross(ax).dot(up) >= 0.0 { 1 } else { -1 };
        let key = Some((buffer - 1, hand));
        let i = match parts.iter().position(|q| q.map == key) {
            Some(i) => i,
            None => {
                parts.push(ExportPart {
                    map: key,
                    ..Default::default()
                });
                parts.len() - 1
            }
        };
        for q in p {
            parts[i].uv.push(slope::map_uv(h, q));
            parts[i].positions.push(q);
        }
    }
    Ok((parts, buffers))
}

/// Writes flat triangles (three unshared vertices each: Mitsuba would otherwise be free
/// to smooth normals) as binary PLY, with per-vertex `u`, `v` when given.
fn write_ply(path: &Path, positions: &[glam::Vec3], uv: &[[f32; 2]]) -> anyhow::Result<()> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    let tris = positions.len() / 3;
    let uv_props = if uv.is_empty() {
        ""
    } else {
        "property float u\nproperty float v\n"
    };
    write!(
        f,
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n{uv_props}element face {tris}\nproperty list uchar int vertex_indices\nend_header\n",
        positions.len()
    )?;
    for (i, p) in positions.iter().enumerate() {
        for c in p.to_array() {
            f.write_all(&c.to_le_bytes())?;
        }
        if let Some(t) = uv.get(i) {
            for c in t {
                f.write_all(&c.to_le_bytes())?;
            }
        }
    }
    for k in 0..tris as i32 {
        f.write_all(&[3u8])?;
        for c in [3 * k, 3 * k + 1, 3 * k + 2] {
            f.write_all(&c.to_le_bytes())?;
        }
    }
    Ok(())
}

/// Object, table and light as binary PLY (flat, with the triangles' winding: the light's
/// normals point outward), the object split by slope map (`object_parts`; each map's
/// slopes as two one-channel EXRs, `slopes-B-x.exr` = dh/dx and `-y` = dh/dy), and the
/// camera, materials and parts as JSON.
fn export_mitsuba(dir: &Path, scene: &RenderScene, cfg: &SceneConfig) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)?;
    let light = &scene.view.light.tris;
    // Three unshared corners per triangle, in the triangle's winding.
    fn corners<'a>(
        positions: &[glam::Vec3],
        tris: impl Iterator<Item = &'a [u32; 3]>,
    ) -> Vec<glam::Vec3> {
        tris.flat_map(|t| t.map(|i| positions[i as usize]))
            .collect()
    }
    let stage = &scene.stage;
    let table = corners(
        &stage.mesh.positions,
        (stage.mesh.triangles.iter().zip(&stage.materials))
            .filter(|(_, m)| **m == MAT_TABLE)
            .map(|(t, _)| t),
    );
    write_ply(&dir.join("table.ply"), &table, &[])?;
    let lights = corners(&light.positions, light.triangles.iter());
    write_ply(&dir.join("light.ply"), &lights, &[])?;
    let (parts, buffers) = object_parts(scene)?;
    let mut part_json = Vec::new();
    for part in &parts {
        if part.positions.is_empty() {
            continue;
        }
        let name = match part.map {
            None => "object.ply".to_string(),
            Some((b, hand)) => format!("object-map{b}{}.ply", if hand > 0 { "p" } else { "n" }),
        };
        write_ply(&dir.join(&name), &part.positions, &part.uv)?;
        part_json.push(serde_json::json!({
            "ply": name,
            "map": part.map.map(|(b, _)| b),
            "handedness": part.map.map(|(_, h)| h),
        }));
    }
    let mut maps_json = Vec::new();
    for (b, (w, h, slopes)) in buffers.iter().enumerate() {
        if slopes.is_empty() {
            maps_json.push(serde_json::Value::Null);
            continue;
        }
        for (c, axis) in ["x", "y"].iter().enumerate() {
            let data: Vec<f32> = slopes.iter().map(|s| s[c]).collect();
            synosis::image_io::write_exr_f32(
                &dir.join(format!("slopes-{b}-{axis}.exr")),
                *w as usize,
                *h as usize,
                "Y",
                &data,
            )?;
        }
        maps_json.push(serde_json::json!({ "width": w, "height": h }));
    }
    let c = &scene.view.camera;
    let json = serde_json::json!({
        "eye": c.eye.to_array(),
        "forward": c.forward.to_array(),
        "up": c.up.to_array(),
        "right": c.right.to_array(),
        "fov_x_deg": 2.0 * c.tan_half_w.atan().to_degrees(),
        "width": c.width,
        "height": c.height,
        "alpha": cfg.material.alpha,
        "ior_n": cfg.material.ior_n,
        "ior_k": cfg.material.ior_k,
        "energy_compensation": cfg.material.energy_compensation,
        "table_albedo": cfg.table.albedo,
        "radiance": cfg.light.radiance,
        "max_bounces": cfg.render.max_bounces,
        "object_parts": part_json,
        "slope_maps": maps_json,
    });
    std::fs::write(dir.join("scene.json"), serde_json::to_string_pretty(&json)?)?;
    Ok(())
}
