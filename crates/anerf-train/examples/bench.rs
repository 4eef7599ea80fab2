//! Entry point of the benchmark until `anerf bench` exists:
//! `cargo run -p anerf-train --example bench -- --presets paper --steps 3`.

use anerf_train::bench::{run, BenchArgs};
use clap::Parser;

#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    args: BenchArgs,
}

fn main() -> anyhow::Result<()> {
    run(&Cli::parse().args)?;
    Ok(())
}
