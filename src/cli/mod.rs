//! Subcommands. Each lives in its own file with a clap `Args` struct and a `run`.

mod defects;
mod metrics;
mod texture;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "synosis", version, about = "Synthetic, labelled inspection images of machined metal parts")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Synthesise a milled or sandblasted surface texture (height map + slope/normal map).
    Texture(texture::TextureArgs),
    /// Imprint dents and scratches into a mesh, with per-triangle labels.
    Defects(defects::DefectsArgs),
    /// Similarity metrics (histogram Wasserstein, MAE, SSIM) between two images.
    Metrics(metrics::MetricsArgs),
    /// Compare a real and a synthetic image set (domain similarity, as the paper).
    Compare(metrics::CompareArgs),
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Texture(a) => texture::run(a),
        Command::Defects(a) => defects::run(a),
        Command::Metrics(a) => metrics::run_metrics(a),
        Command::Compare(a) => metrics::run_compare(a),
    }
}
