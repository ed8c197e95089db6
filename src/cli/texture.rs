use clap::Args;
#[derive(Args)]
pub struct TextureArgs {}
pub fn run(_a: TextureArgs) -> anyhow::Result<()> {
    anyhow::bail!("texture synthesis is not implemented yet")
}
