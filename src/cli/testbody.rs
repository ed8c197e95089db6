//! `synosis testbody`: writes the built-in test body (variant B or its mirror M) or the
//! example flange or dome.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, ValueEnum};
use synosis::scene::testbody::{Variant, testbody};

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum VariantArg {
    B,
    M,
    /// The example flange (bore, bolt holes, chamfer; docs/testbody.md).
    Flange,
    /// A hemispherical dome, 20 mm radius, 12 bands x 64 segments: a free-form curved
    /// surface (triplanar finish; docs/testbody.md).
    Dome,
}

#[derive(Args)]
pub struct TestbodyArgs {
    /// Which body: b (base), m (its mirror image across x = 0), flange or dome.
    #[arg(long, value_enum, default_value = "b")]
    pub variant: VariantArg,
    /// Output file (.glb, .gltf or .stl; STL carries no labels).
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(a: TestbodyArgs) -> anyhow::Result<()> {
    let mesh = match a.variant {
        VariantArg::B => testbody(Variant::B),
        VariantArg::M => testbody(Variant::M),
        VariantArg::Flange => synosis::scene::flange(&Default::default()),
        VariantArg::Dome => synosis::scene::procedural::dome(20.0, 12, 64),
    };
    synosis::scene::write_mesh(&mesh, &a.out)
        .with_context(|| format!("writing the test body to {}", a.out.display()))?;
    println!(
        "wrote {} ({} triangles)",
        a.out.display(),
        mesh.triangles.len()
    );
    Ok(())
}
