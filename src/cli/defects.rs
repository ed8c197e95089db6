//! `synosis defects`: sample defects on a mesh's inspected faces and imprint them.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use synosis::defect::{DefectSpec, imprint_with_stats, sample_defects};
use synosis::scene::{Degenerates, export_mesh, import_mesh};

#[derive(Args)]
pub struct DefectsArgs {
    /// Input mesh (.glb or .gltf) with faces labelled A, B, C.
    pub mesh: PathBuf,
    /// Defect specification (TOML); without it, the paper's table.
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// Job seed; the same seed gives the same mesh, bit for bit.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output mesh (.glb or .gltf).
    #[arg(long)]
    pub out: PathBuf,
    /// JSON sidecar with every defect's parameters (default: OUT with extension
    /// .defects.json).
    #[arg(long)]
    pub sidecar: Option<PathBuf>,
}

pub fn run(a: DefectsArgs) -> anyhow::Result<()> {
    let spec = match &a.spec {
        Some(p) => DefectSpec::load(p)?,
        None => DefectSpec::paper(),
    };
    let mesh = import_mesh(&a.mesh, Degenerates::Reject)
        .with_context(|| format!("reading {}", a.mesh.display()))?
        .mesh;
    let set = sample_defects(&mesh, &spec, a.seed)
        .with_context(|| format!("sampling defects on {}", a.mesh.display()))?;
    let (out, stats) = imprint_with_stats(&mesh, &set).context("imprinting the defects")?;
    let sidecar = a
        .sidecar
        .clone()
        .unwrap_or_else(|| a.out.with_extension("defects.json"));
    let json = serde_json::to_vec_pretty(&set).context("serialising the defect set")?;
    export_mesh(&out, &a.out).with_context(|| format!("writing {}", a.out.display()))?;
    if let Err(e) = synosis::util::write_atomic(&sidecar, &json) {
        // Mesh and sidecar belong together: do not leave one without the other.
        let _ = std::fs::remove_file(&a.out);
        return Err(e).with_context(|| format!("writing {}", sidecar.display()));
    }
    println!(
        "wrote {} ({} defects, {} -> {} triangles, {} labelled) and {}",
        a.out.display(),
        set.defects.len(),
        stats.triangles_in,
        stats.triangles_out,
        stats.triangles_labelled,
        sidecar.display()
    );
    Ok(())
}
