//! `softarm-rig`: softarm with its test rig, for a work tree and the tests. Every command of
//! `softarm` (`src/lib.rs::Command`), and `emulate` (`softarm-emulate`), `soak` and `bench`
//! (`softarm-rig`). Built with the `rig` feature, on by default; never installed: `softarm
//! install` installs the product alone (decision 0014).

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use softarm::Command;
use softarm_emulate::command as emulate;
use softarm_rig::{bench, soak};
use softarm_runtime::stop_flag;

/// softarm with its test rig: every command of `softarm`, and emulators of the arm's devices,
/// a long run under a safety watch, and what the stack costs on this machine. For a work tree
/// and the tests; `softarm install` installs `softarm`, without the rig.
#[derive(Parser)]
#[command(name = "softarm-rig", version, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: RigCommand,
}

#[derive(Subcommand)]
enum RigCommand {
    #[command(flatten)]
    Product(Command),
    /// Emulators of the motor bus and the tracker on pseudo-terminals, coupled through the
    /// arm's model: the hardware stack without hardware.
    Emulate(emulate::Args),
    /// Times the stack on this machine (min / p50 / p99 / p99.9 / max): tick wake-up latency
    /// against a bare loop, messages between processes, end to end, hot-path calls, memory.
    Bench(bench::Args),
    /// Runs the simulated stack for a long time with continuous executions, scenario changes
    /// and random kills; reports invariant violations, memory and tick latency (exit 1 if
    /// anything failed).
    Soak(soak::Args),
}

fn run(command: RigCommand) -> anyhow::Result<ExitCode> {
    match command {
        RigCommand::Product(Command::Install(_)) => anyhow::bail!(
            "softarm-rig is not installed: `softarm install` installs the product alone, \
             without the test rig; run the `softarm` built beside this one \
             (target/release/softarm install)"
        ),
        RigCommand::Product(command) => return softarm::run(command),
        RigCommand::Emulate(args) => {
            emulate::run(&args, &*stop_flag()?, &softarm::emulated_physics)?
        }
        RigCommand::Bench(args) => bench::run(&args)?,
        RigCommand::Soak(args) => {
            if !soak::run(&args, &*stop_flag()?)? {
                return Ok(ExitCode::FAILURE);
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // The demo's and the soak's own output is their table.
    let quiet = match &cli.command {
        RigCommand::Product(c) => softarm::quiet(c),
        RigCommand::Soak(_) => true,
        _ => false,
    };
    softarm::init_logging(if quiet { "warn" } else { "info" });
    softarm::exit_code("softarm-rig", run(cli.command))
}
