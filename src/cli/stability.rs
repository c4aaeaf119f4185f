//! `hslt stability`: the stiff and extreme cases of the HSLT method as a Markdown table.

use anyhow::bail;
use clap::Args;

#[derive(Args, Debug)]
pub struct StabilityArgs {
    /// Run only these cases (numbers 1-15, comma-separated); all by default.
    #[arg(long, value_delimiter = ',')]
    pub case: Vec<usize>,
    /// The test suite's smaller sample counts instead of the table's.
    #[arg(long)]
    pub quick: bool,
}

pub(super) fn run_stability(args: StabilityArgs) -> anyhow::Result<i32> {
    use crate::stability::{self, Effort};
    let known: Vec<usize> = stability::cases().iter().map(|c| c.number).collect();
    if let Some(bad) = args.case.iter().find(|n| !known.contains(n)) {
        bail!("--case {bad}: no such stability case (known: {known:?})");
    }
    let effort = if args.quick { Effort::Quick } else { Effort::Full };
    let runs = stability::run(effort, &args.case);
    print!("{}", stability::table(&runs));
    Ok(if runs.iter().all(|r| r.report.passed()) { 0 } else { 1 })
}
