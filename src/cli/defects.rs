use clap::Args;
#[derive(Args)]
pub struct DefectsArgs {}
pub fn run(_a: DefectsArgs) -> anyhow::Result<()> {
    anyhow::bail!("defect imprinting is not implemented yet")
}
