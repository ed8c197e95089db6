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
    if let Some(dir) = &a.export_mitsuba {
        export_mitsuba(dir, &scene, &cfg)?;
    }
    let tables = EnergyTables::compute();
    let ctx = Context::new(&ContextOptions {
        validation: false,
        ray_query: true,
    })?;
    let render = |cfg: &SceneConfig, backend| -> anyhow::Result<(Vec<f32>, f64, f64)> {
        let t = Instant::now();
        let img = path_trace(&ctx, &scene, cfg, backend, &tables, None, |_| {})?;
        Ok((img.data, t.elapsed().as_secs_f64(), img.gpu_ms))
    };
    // Warm-up: lavapipe compiles the shader at the first dispatch.
    for b in [Backend::RayQuery, Backend::Software] {
        let mut w = cfg.clone();
        w.render.spp = 1;
        render(&w, b)?;
    }
    let mut rc = cfg.clone();
    rc.render.spp = a.ref_spp;
    rc.render.batch_spp = 64;
    rc.render.seed = cfg.render.seed.wrapping_add(1000);
    rc.render.sampler = SamplerKind::Sobol;
    rc.light.sampling = LightSampling::Facing;
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
        None => render(&rc, Backend::RayQuery)?,
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
        let parts: Vec<&str> = c.trim().split(':').collect();
        anyhow::ensure!(
            parts.len() == 3 || parts.len() == 4,
            "--configs: {c:?} is not backend:sampler:light[:direct]"
        );
        let backend = match parts[0] {
            "ray-query" => Backend::RayQuery,
            "software" => Backend::Software,
            o => anyhow::bail!("backend {o:?}"),
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
            Some(o) => anyhow::bail!("direct light {o:?}"),
        };
        for &spp in &spps {
            cc.render.spp = spp;
            cc.render.batch_spp = spp.min(64);
            let (img, secs, gpu_ms) = render(&cc, backend)?;
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
    let mut md = String::new();
    writeln!(
        md,
        "Scene `{}` at {} x {}, {} bounces, compensation {}; reference: {} spp (Sobol, facing, ray query, other seed), mean radiance {ref_mean:.5}.\n",
        a.scene.display(),
        a.width,
        a.height,
        cfg.render.max_bounces,
        if cfg.material.energy_compensation {
            "on"
        } else {
            "off"
        },
        a.ref_spp
    )?;
    writeln!(
        md,
        "| backend:sampler:light | spp | seconds (wall) | GPU ms | RMSE | RMSE / mean | load (1 min) |"
    )?;
    writeln!(md, "|---|---|---|---|---|---|---|")?;
    for r in &rows {
        writeln!(
            md,
            "| {} | {} | {:.2} | {:.0} | {:.3e} | {:.3} | {:.2} |",
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
                "gpu_ms": r.gpu_ms, "rmse": r.rmse, "load": r.load})
        })
        .collect();
    std::fs::write(
        a.out.join(format!("{}.json", a.name)),
        serde_json::to_string_pretty(&serde_json::json!({
            "ref_spp": a.ref_spp, "ref_secs": ref_secs, "ref_mean": ref_mean, "rows": json
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

/// Object, table and light as binary PLY (flat, with the triangles' winding: the light's
/// normals point outward) and the camera and materials as JSON.
fn export_mitsuba(dir: &Path, scene: &RenderScene, cfg: &SceneConfig) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)?;
    let light = &scene.view.light.tris;
    for (name, pick) in [
        ("object", None),
        ("table", Some(MAT_TABLE)),
        ("light", Some(MAT_LIGHT)),
    ] {
        let (positions, tris): (&[glam::Vec3], Vec<[u32; 3]>) = if pick == Some(MAT_LIGHT) {
            (&light.positions, light.triangles.clone())
        } else {
            let tris = scene
                .stage
                .mesh
                .triangles
                .iter()
                .zip(&scene.stage.materials)
                .filter(|(_, m)| match pick {
                    Some(p) => **m == p,
                    None => **m != MAT_TABLE,
                })
                .map(|(t, _)| *t)
                .collect();
            (&scene.stage.mesh.positions, tris)
        };
        let mut f =
            std::io::BufWriter::new(std::fs::File::create(dir.join(format!("{name}.ply")))?);
        write!(
            f,
            "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
            tris.len() * 3,
            tris.len()
        )?;
        // Unshared vertices: Mitsuba would otherwise be free to smooth normals.
        for t in &tris {
            for &i in t {
                for c in positions[i as usize].to_array() {
                    f.write_all(&c.to_le_bytes())?;
                }
            }
        }
        for k in 0..tris.len() as i32 {
            f.write_all(&[3u8])?;
            for c in [3 * k, 3 * k + 1, 3 * k + 2] {
                f.write_all(&c.to_le_bytes())?;
            }
        }
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
    });
    std::fs::write(dir.join("scene.json"), serde_json::to_string_pretty(&json)?)?;
    Ok(())
}
