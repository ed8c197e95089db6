//! `synosis testbody`: writes the built-in test body (variant B or its mirror M).

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, ValueEnum};
use synosis::scene::testbody::{Variant, testbody};

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum VariantArg {
    B,
    M,
}

#[derive(Args)]
pub struct TestbodyArgs {
    /// Which body: b (base) or m (its mirror image across x = 0).
    #[arg(long, value_enum, default_value = "b")]
    pub variant: VariantArg,
    /// Output file (.glb or .gltf).
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(a: TestbodyArgs) -> anyhow::Result<()> {
    let variant = match a.variant {
        VariantArg::B => Variant::B,
        VariantArg::M => Variant::M,
    };
    let mesh = testbody(variant);
    synosis::scene::export_mesh(&mesh, &a.out)
        .with_context(|| format!("writing the test body to {}", a.out.display()))?;
    println!(
        "wrote {} ({} triangles)",
        a.out.display(),
        mesh.triangles.len()
    );
    Ok(())
}
