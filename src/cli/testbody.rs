use clap::Args;
#[derive(Args)]
pub struct TestbodyArgs {}
pub fn run(_a: TestbodyArgs) -> anyhow::Result<()> {
    anyhow::bail!("the test body generator is not implemented yet")
}
