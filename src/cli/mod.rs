//! Subcommands. Each lives in its own file with a clap `Args` struct and a `run`.

mod bench;
mod dataset;
mod defects;
mod gpu;
mod metrics;
mod render;
mod testbody;
mod texture;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "synosis",
    version,
    about = "Synthetic, labelled inspection images of machined metal parts"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Show the Vulkan device, driver, ray-query support and the backend auto picks.
    Info(gpu::InfoArgs),
    /// Compile every GPU pipeline into the driver's shader cache ahead of a job, several at
    /// once (lavapipe takes minutes per backend on a cold cache; later runs find them).
    Compile(gpu::CompileArgs),
    /// Raycast a mesh from above (depth.exr, normals.png): proves import, both backends, the graph.
    Raycast(gpu::RaycastArgs),
    /// Synthesise a milled or sandblasted surface texture (height map + slope/normal map).
    Texture(texture::TextureArgs),
    /// Imprint dents and scratches into a mesh, with per-triangle labels.
    Defects(defects::DefectsArgs),
    /// Write the built-in test body (variant B or its mirror M) as glTF.
    Testbody(testbody::TestbodyArgs),
    /// Similarity metrics (histogram Wasserstein, MAE, SSIM) between two images.
    Metrics(metrics::MetricsArgs),
    /// Path-trace an inspection image of a scene file (radiance.exr, image.png).
    Render(render::RenderArgs),
    /// Compare a real and a synthetic image set (domain similarity, as the paper).
    Compare(metrics::CompareArgs),
    /// Dataset jobs: run (sharded, resumable), merge, postprocess, render-one, check.
    Dataset(dataset::DatasetArgs),
    /// Time a dataset job on this Vulkan device: images per hour, stage split, GPU busy
    /// share, peak memory, ray throughput (a Markdown table on stdout).
    BenchGpu(bench::BenchGpuArgs),
}

/// The error and its causes on one line, each once: a library error that already shows
/// its cause (`path: No such file or directory`) is not followed by the cause again.
pub fn error_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let s = cause.to_string();
        if text.contains(&s) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&s);
    }
    text
}

/// `SYNOSIS_ACCEL` (`auto`, `software`, `software-wide`, `ray-query`), if set; another value is an error.
pub fn accel_from_env() -> anyhow::Result<Option<synosis::trace::AccelChoice>> {
    use synosis::trace::AccelChoice;
    match std::env::var("SYNOSIS_ACCEL") {
        Err(_) => Ok(None),
        Ok(v) => match v.trim() {
            "" => Ok(None),
            "auto" => Ok(Some(AccelChoice::Auto)),
            "software" => Ok(Some(AccelChoice::Software)),
            "software-wide" => Ok(Some(AccelChoice::SoftwareWide)),
            "ray-query" => Ok(Some(AccelChoice::RayQuery)),
            other => anyhow::bail!(
                "SYNOSIS_ACCEL={other:?}: allowed \"auto\", \"software\", \"software-wide\" or \"ray-query\""
            ),
        },
    }
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    synosis::render::settings::specialize_from_env().map_err(anyhow::Error::msg)?;
    match cli.command {
        Command::Info(a) => gpu::info(a),
        Command::Compile(a) => gpu::compile_cmd(a),
        Command::Raycast(a) => gpu::raycast_cmd(a),
        Command::Texture(a) => texture::run(a),
        Command::Defects(a) => defects::run(a),
        Command::Testbody(a) => testbody::run(a),
        Command::Metrics(a) => metrics::run_metrics(a),
        Command::Compare(a) => metrics::run_compare(a),
        Command::Render(a) => render::run(a),
        Command::Dataset(a) => dataset::run(a),
        Command::BenchGpu(a) => bench::run(a),
    }
}
