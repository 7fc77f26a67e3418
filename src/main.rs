//! `softarm`: one command for every process and client of the stack.

use clap::{Parser, Subcommand};

mod bench;

/// Task-driven skill learning for a two-module soft continuum arm: ProMPs blended by the paper's
/// Eq. 11, conditioning points learned online by CACLA-MTL.
#[derive(Parser)]
#[command(name = "softarm", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Time the controller's hot paths on this machine: one Eq. 11 tick, re-conditioning a
    /// group, a CACLA-MTL update; prints min / p50 / p99 / p99.9 / max.
    Bench(bench::Args),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Bench(args) => bench::run(&args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("softarm: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
