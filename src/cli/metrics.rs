use clap::Args;
#[derive(Args)]
pub struct MetricsArgs {}
#[derive(Args)]
pub struct CompareArgs {}
pub fn run_metrics(_a: MetricsArgs) -> anyhow::Result<()> {
    anyhow::bail!("metrics are not implemented yet")
}
pub fn run_compare(_a: CompareArgs) -> anyhow::Result<()> {
    anyhow::bail!("compare is not implemented yet")
}
