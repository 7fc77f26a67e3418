//! `softarm`: one command for every process and client of the stack. Two binaries share it:
//! `softarm` (`src/main.rs`), the product, which `softarm install` installs, and `softarm-rig`
//! (`src/rig.rs`, the `rig` feature), the same commands and the test rig's (`emulate`, `soak`,
//! `bench`), for a work tree and the tests (decision 0014).

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::{Parser, Subcommand};
use softarm_channels::scene;
use softarm_clients::{estop, stats, status, submit};
use softarm_config::files::FileKind;
use softarm_config::load::Loader;
use softarm_config::scenario::OnArm;
use softarm_config::{Config, ConfigError};
use softarm_record::{plot, poses, record};
use softarm_runtime::stop_flag;
use softarm_sim::command::plant_refused;
use softarm_sim::plant::Physics;
use softarm_stack::demo;
use softarm_stack::supervisor as up;
use softarm_systemd as install;
use softarm_train as train;

/// Task-driven skill learning for a two-module soft continuum arm: ProMPs blended by the paper's
/// Eq. 11, conditioning points learned online by CACLA-MTL.
#[derive(Parser)]
#[command(name = "softarm", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

/// Which stack: the config file, and optionally another namespace than the config's.
#[derive(clap::Args, Clone)]
pub struct Stack {
    /// The config file (default: $SOFTARM_CONFIG, else the installed /etc/softarm/softarm.toml
    /// if there is one, else the embedded simulation config).
    #[arg(long, global = true)]
    config: Option<PathBuf>,
    /// The iceoryx2 namespace (default: the config's, softarm/<robot-id>).
    #[arg(long, global = true)]
    namespace: Option<String>,
}

impl Stack {
    /// How this command finds, reads and joins its config: `softarm-config`'s loader.
    fn loader(&self) -> Loader {
        Loader {
            config: self.config.clone(),
            namespace: self.namespace.clone(),
        }
    }
}

/// The product's commands: every process and client of the stack.
#[derive(Subcommand)]
pub enum Command {
    /// The showcase: the simulated stack, trained if needed, learning a way-point set.
    Demo(demo::Args),
    /// Controller, learner and the configured drivers as children, in the foreground.
    Up {
        #[command(flatten)]
        stack: Stack,
        /// Runs the sim on another arm than the config's: a shipped scenario (nominal,
        /// tool-change, creep, twist, stiffer, not-pcc; changing while it runs: tool-swap,
        /// creeping, stiffness-cycle, combined, sequence) or a scenario file.
        #[arg(long)]
        scenario: Option<String>,
    },
    /// The fixed-rate controller process.
    Controller(Stack),
    /// The CACLA-MTL learner process.
    Learner(Stack),
    /// The simulated plant (driver process).
    Sim {
        #[command(flatten)]
        stack: Stack,
        /// Overrides [arm] and [sim.realism] for this process only, and may change the arm while
        /// it runs ([[step]], [drift]): a shipped scenario (nominal, tool-change, creep, twist,
        /// stiffer, not-pcc, tool-swap, creeping, stiffness-cycle, combined, sequence) or a scenario file.
        #[arg(long)]
        scenario: Option<String>,
    },
    /// The tendon motors of the real arm (driver process): Dynamixel Protocol 2.0, [tendon].
    Tendon(Stack),
    /// The tracker of the real arm (driver process): Ascension Bird protocol, [tracker].
    Tracker(Stack),
    /// Demonstrations through the running stack, then ProMPs, forward model, pre-training;
    /// or, with --from, the arm's physical model calibrated to a recording its lab made.
    Train {
        #[command(flatten)]
        stack: Stack,
        /// Seeds the demonstration sequences.
        #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
        seed: u64,
        /// A recording of the arm (CSV: actuator commands beside a tracked tip, a row per
        /// settled pose, with --columns; or softarm's own, .mcap): calibrates the arm to it
        /// instead, and writes the model, the calibrated arm (the twin, an [arm] file) and a
        /// model bundle into --output.
        #[arg(long, value_name = "FILE")]
        from: Option<PathBuf>,
        #[command(flatten)]
        recording: RecordingArgs,
        /// Where --from writes (default: the config's model folder).
        #[arg(long, value_name = "DIR", requires = "from")]
        output: Option<PathBuf>,
    },
    /// Models of the arm.
    Model {
        #[command(subcommand)]
        command: ModelCommand,
    },
    /// Submits a way-point set; exit 0 accepted, 2 rejected, 1 no controller.
    Submit {
        /// Way-point file (TOML: duration_s, [[point]] t_s, position_m).
        waypoints: PathBuf,
        #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
        executions: u32,
        /// Follow the set's stats until its executions are done.
        #[arg(long)]
        wait: bool,
        #[command(flatten)]
        stack: Stack,
    },
    /// The error at each conditioning point per execution.
    Stats {
        /// Keep printing new executions.
        #[arg(long)]
        follow: bool,
        /// JSON: one array of the executions; with --follow, one object per execution and line.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        stack: Stack,
    },
    /// Which processes are alive, the controller's state, tick timing, data ages; exits with
    /// 3 when the stack is not running.
    Status {
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        stack: Stack,
    },
    /// Engages the e-stop (latched), or releases it with --reset; exits 0 once the controller
    /// and the drivers running say they took it, 1 if one did not, 3 if none runs (latched).
    Estop {
        #[arg(long)]
        reset: bool,
        /// How long to wait for the running processes to confirm (s).
        #[arg(long, default_value_t = 5.0)]
        timeout: f64,
        #[command(flatten)]
        stack: Stack,
    },
    /// Checks configuration files.
    Config {
        #[command(subcommand)]
        command: ConfigCommand,
    },
    /// Records every service of the stack into an MCAP file (Foxglove, the `mcap` Python
    /// package) until Ctrl-C or --duration.
    Record {
        /// The recording (.mcap).
        #[arg(short, long)]
        output: PathBuf,
        /// Stop after this many seconds.
        #[arg(long, allow_negative_numbers = true)]
        duration: Option<f64>,
        #[command(flatten)]
        stack: Stack,
    },
    /// Serves the running stack live over the Foxglove WebSocket protocol (read-only): every
    /// service as a channel, and the arm, way-points and tracker in 3-D.
    View {
        /// IP address and port (default: the config's view.listen, 127.0.0.1:8765); other than
        /// loopback only with view.allow_remote = true in the config.
        #[arg(long)]
        listen: Option<String>,
        /// Instead of serving: write the Foxglove layout for the config's arm (its actuators
        /// by name) to this file, and exit.
        #[arg(long, value_name = "FILE")]
        layout: Option<PathBuf>,
        #[command(flatten)]
        stack: Stack,
    },
    /// Bridges the running stack to ROS 2 over DDS (no ROS install): joint states, tracker and
    /// diagnostics out; the e-stop in, way-point sets in with ros2.accept_waypoints.
    Ros2 {
        #[command(flatten)]
        stack: Stack,
    },
    /// The per-execution statistics and a timing summary from a recording.
    Replay {
        recording: PathBuf,
        /// One JSON object.
        #[arg(long)]
        json: bool,
    },
    /// The paper's Fig. 4 view of a recording: paths and way-points in three projections,
    /// and the error at each conditioning point per execution (PNG, or SVG by extension).
    Plot {
        recording: PathBuf,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Installs the stack as systemd services: binary, config, state folder, units, user.
    Install(install::Args),
    /// Removes the units and the binary; keeps the config, the state and the user.
    Uninstall(install::UninstallArgs),
}

/// A recording's column map, and the arm it is of.
#[derive(clap::Args, Clone)]
pub struct RecordingArgs {
    /// How a CSV recording's columns map onto the arm (TOML; e.g.
    /// config/recordings/opencr-tdcr/columns.toml).
    #[arg(long, value_name = "FILE")]
    columns: Option<PathBuf>,
    /// The arm the recording is of (a shipped arm's name or an [arm] file; default the
    /// config's).
    #[arg(long, value_name = "NAME|FILE")]
    arm: Option<String>,
}

impl RecordingArgs {
    /// The config with `--arm`'s arm in it (and the boxes its reach bounds), else as loaded.
    fn config(&self, stack: &Stack) -> anyhow::Result<Config> {
        let loader = stack.loader();
        loader.with_arm(loader.load()?, self.arm.as_deref())
    }
}

#[derive(Subcommand)]
pub enum ModelCommand {
    /// How well a model predicts a recording it was not trained on: RMS, mean, RMS with the
    /// mean offset removed, p95 and max of the tip's miss (mm), overall and per motion family.
    Check {
        /// The recording (CSV with --columns, or softarm's own .mcap).
        recording: PathBuf,
        #[command(flatten)]
        columns: RecordingArgs,
        /// The model: identified.toml, or the folder `train --from` wrote it in (default: the
        /// config's model folder).
        #[arg(long, value_name = "FILE|DIR")]
        model: Option<PathBuf>,
        /// One JSON object.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        stack: Stack,
    },
}

#[derive(Subcommand)]
pub enum ConfigCommand {
    /// Checks a file softarm reads: a config, an [arm] file, a way-point set, a scenario or a
    /// recording's column map (told apart by its keys); prints what it took the file for, or
    /// the first error with its key and line.
    Check {
        file: PathBuf,
        /// What the file is, when its keys do not say.
        #[arg(long = "as", value_enum)]
        kind: Option<FileKindArg>,
        /// The arm a column map, way-point set or scenario is checked on (a shipped arm's name
        /// or an [arm] file; default the config's).
        #[arg(long, value_name = "NAME|FILE")]
        arm: Option<String>,
        #[command(flatten)]
        stack: Stack,
    },
    /// Prints the embedded default config.
    Default,
    /// Prints the reference of every config key (Markdown: docs/config.md).
    Reference,
}

/// Logs to stderr at `default`'s level unless `RUST_LOG` says otherwise.
pub fn init_logging(default: &str) {
    let env = std::env::var("RUST_LOG").unwrap_or_default();
    let mut filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    // RustDDS (the ROS 2 bridge's DDS) logs every discovery step at info and warns of every
    // path it does not use (multicast on loopback): its errors only, unless RUST_LOG names it.
    if !env.contains("rustdds") {
        filter = filter.add_directive("rustdds=error".parse().expect("a valid directive"));
    }
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .try_init();
}

/// The MuJoCo model `[sim.mujoco]` describes for the sim's arm, if it describes one: MuJoCo
/// is the binary's, behind its `mujoco` feature (`softarm_sim::command::PhysicsOf`).
#[cfg(feature = "mujoco")]
fn physics(c: &Config, on: &OnArm) -> anyhow::Result<Option<Box<dyn Physics>>> {
    let Some(mujoco) = &on.sim.mujoco else {
        return Ok(None);
    };
    // Refused as a config is: exit 78, which `up` and systemd do not restart.
    let arm = softarm_mujoco::MujocoArm::new(mujoco, &c.arm, &on.arm, &on.steps, &c.base_dir)
        .map_err(|e| plant_refused(e.0))?;
    Ok(Some(Box::new(arm)))
}

#[cfg(not(feature = "mujoco"))]
fn physics(_c: &Config, on: &OnArm) -> anyhow::Result<Option<Box<dyn Physics>>> {
    match on.sim.mujoco {
        None => Ok(None),
        Some(_) => Err(plant_refused(
            "sim.mujoco: this softarm was built without MuJoCo; build it with `--features \
             mujoco` and MuJoCo's library (docs/guide/mujoco.md), or remove [sim.mujoco] to run \
             the sim's own kinematics"
                .into(),
        )
        .into()),
    }
}

/// The processes that keep the arm's pace (the controller, the drivers) lock their memory
/// when `controller.mlockall` says so.
fn keep_pace(c: &Config) {
    if c.controller.mlockall
        && let Err(e) = softarm_runtime::lock_memory()
    {
        tracing::warn!("{e}; going on");
    }
}

/// Runs `command`; its exit code.
pub fn run(command: Command) -> anyhow::Result<ExitCode> {
    match command {
        Command::Demo(args) => demo::run(&args, &*stop_flag()?)?,
        Command::Up { stack, scenario } => {
            let loader = stack.loader();
            let config = loader.load()?;
            up::run_config(loader.args(), &config, scenario.as_deref(), &*stop_flag()?)?
        }
        Command::Controller(stack) => {
            let c = stack.loader().load()?;
            keep_pace(&c);
            softarm_controller::run(&c, &*stop_flag()?)?
        }
        Command::Learner(stack) => softarm_learner::run(&stack.loader().load()?, &*stop_flag()?)?,
        Command::Sim { stack, scenario } => {
            let c = stack.loader().load()?;
            keep_pace(&c);
            softarm_sim::command::run(&c, scenario.as_deref(), &physics)?
        }
        Command::Tendon(stack) => {
            let c = stack.loader().load_with("tendon", |c| c.tendon.is_some())?;
            keep_pace(&c);
            softarm_tendon::run(&c, c.bus()?, &*stop_flag()?)?
        }
        Command::Tracker(stack) => {
            let c = stack
                .loader()
                .load_with("tracker", |c| c.tracker.is_some())?;
            keep_pace(&c);
            softarm_tracker::run(&c, c.bus()?, &*stop_flag()?)?
        }
        Command::Train {
            stack,
            from: Some(from),
            recording,
            output,
            ..
        } => {
            let config = recording.config(&stack)?;
            let out = output.unwrap_or_else(|| config.model_dir());
            let rows = poses::read_any(&from, recording.columns.as_deref(), &config.layout())?;
            let trained = train::recording::train_from(&config, rows, &out)
                .with_context(|| format!("train --from {}", from.display()))?;
            println!("{}", trained.summary());
        }
        Command::Model {
            command:
                ModelCommand::Check {
                    recording,
                    columns,
                    model,
                    json,
                    stack,
                },
        } => {
            let config = columns.config(&stack)?;
            let model = softarm_identify::run::model_file(model, &config.model_dir());
            let arm = config.layout();
            let rows = poses::read_any(&recording, columns.columns.as_deref(), &arm)?;
            let check = train::recording::check(&arm, &rows, &model)?;
            if json {
                println!("{}", check.json());
            } else {
                print!("{}", check.table());
            }
        }
        Command::Train { stack, seed, .. } => {
            let loader = stack.loader();
            let config = loader.load()?;
            let out = softarm_identify::run::Output::log();
            let r = train::train(&config, &loader.namespace()?, seed, out, &*stop_flag()?)?;
            println!(
                "trained model {} in {}: {}",
                r.model_id,
                config.model_dir().display(),
                r.summary()
            );
        }
        Command::Submit {
            waypoints,
            executions,
            wait,
            stack,
        } => {
            // The file is read as whoever submits it: an operator's own set is theirs to read.
            let (config, text) = stack
                .loader()
                .load_reading(|| std::fs::read_to_string(&waypoints))?;
            let code = submit::run(&config, &waypoints, text, executions, wait)?;
            return Ok(ExitCode::from(code));
        }
        Command::Stats {
            follow,
            json,
            stack,
        } => stats::show(&stack.loader().namespace()?, follow, json)?,
        Command::Status { json, stack } => {
            let r = status::status(&stack.loader().namespace()?, Duration::from_secs(1))?;
            if json {
                println!("{}", status::json(&r));
            } else {
                print!("{}", status::text(&r));
            }
            if !r.running() {
                // As `systemctl status` does for a unit that is not active: scripts and health
                // checks can use the exit code alone.
                return Ok(ExitCode::from(status::NOT_RUNNING));
            }
        }
        Command::Estop {
            reset,
            timeout,
            stack,
        } => {
            let timeout = Duration::try_from_secs_f64(timeout)
                .ok()
                .filter(|t| *t <= Duration::from_secs(600))
                .context("--timeout: give 0 to 600 seconds")?;
            if !estop::run(&stack.loader().load()?, reset, timeout)? {
                // Latched, but no process took it: as `status` says of a stack not running.
                return Ok(ExitCode::from(status::NOT_RUNNING));
            }
        }
        Command::Config { command } => match command {
            ConfigCommand::Check {
                file,
                kind,
                arm,
                stack,
            } => check_file(&file, kind.map(FileKind::from), arm.as_deref(), &stack)?,
            ConfigCommand::Default => print!("{}", softarm_config::DEFAULT),
            ConfigCommand::Reference => print!("{}", softarm_config::reference::markdown()),
        },
        Command::Record {
            output,
            duration,
            stack,
        } => {
            let config = stack.loader().load()?;
            let settings = scene::Settings::of(&config);
            let namespace = config.bus()?;
            record::run(&namespace, &settings, &output, duration, &*stop_flag()?)?
        }
        Command::View {
            layout: Some(file),
            stack,
            ..
        } => {
            let config = stack.loader().load()?;
            softarm_view::write_layout(&file, &config.layout())?;
            println!(
                "{}: the Foxglove layout for {}",
                file.display(),
                config.arm_identity()
            );
        }
        Command::View {
            listen,
            layout: None,
            stack,
        } => softarm_view::run(&stack.loader().load()?, listen.as_deref(), &*stop_flag()?)?,
        Command::Ros2 { stack } => softarm_ros2::run(&stack.loader().load()?, &*stop_flag()?)?,
        Command::Replay { recording, json } => record::replay_command(&recording, json)?,
        Command::Plot { recording, output } => plot::run(&recording, &output)?,
        Command::Install(args) => install::install(&args)?,
        Command::Uninstall(args) => install::uninstall(&args)?,
    }
    Ok(ExitCode::SUCCESS)
}

/// `softarm config check FILE`: the file taken for what its keys say (or `kind`), checked as
/// softarm reads it, against the config's arm and limits (or `arm`'s).
fn check_file(
    file: &Path,
    kind: Option<FileKind>,
    arm: Option<&str>,
    stack: &Stack,
) -> anyhow::Result<()> {
    let origin = file.display().to_string();
    let text = std::fs::read_to_string(file).map_err(|e| ConfigError {
        origin: origin.clone(),
        line: None,
        message: format!("cannot read the file: {e}"),
    })?;
    let (kind, taken) = match kind {
        Some(k) => (k, "checked as"),
        None => (FileKind::of(&text, &origin)?, "taken for"),
    };
    // A whole config is checked on its own; the rest on the config they would be used with
    // (which an outsider to an installed stack may not read: not asked for one).
    let config = match kind {
        FileKind::Config => Config::default_sim(PathBuf::from(".")),
        _ => {
            let loader = stack.loader();
            loader.with_arm(loader.read()?, arm)?
        }
    };
    let found = match kind {
        FileKind::ColumnMap => {
            let columns = softarm_identify::recording::Columns::parse(file, &text)?;
            columns.check(file, &config.layout())?;
            format!(
                "{} actuator columns, for the arm of {}",
                columns.actuators.len(),
                config.arm_identity()
            )
        }
        k => softarm_config::files::check(k, &text, file, &config)?,
    };
    println!("{origin}: ok, {taken} {}: {found}", kind.name());
    Ok(())
}

/// `--as`: what `softarm config check` checks a file as.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum FileKindArg {
    Config,
    Arm,
    Waypoints,
    Scenario,
    Columns,
    Plant,
}

impl From<FileKindArg> for FileKind {
    fn from(k: FileKindArg) -> Self {
        match k {
            FileKindArg::Config => Self::Config,
            FileKindArg::Arm => Self::Arm,
            FileKindArg::Waypoints => Self::WaypointSet,
            FileKindArg::Scenario => Self::Scenario,
            FileKindArg::Columns => Self::ColumnMap,
            FileKindArg::Plant => Self::Plant,
        }
    }
}

/// The demo's own output is its table: its processes' logs only when something is wrong.
pub fn quiet(command: &Command) -> bool {
    matches!(command, Command::Demo(_))
}

/// The plant `softarm-rig emulate` couples its emulated devices through: the config's MuJoCo
/// model with `[sim.mujoco]`, else none (the emulators' own kinematics).
pub fn emulated_physics(c: &Config) -> anyhow::Result<Option<Box<dyn Physics>>> {
    let on = OnArm {
        arm: c.arm.clone(),
        sim: c.sim.clone(),
        steps: Vec::new(),
    };
    physics(c, &on)
}

/// The exit code of what `run` gave, the error said on stderr after `program`'s name: 78 for a
/// refused config (`up` and systemd do not restart it), else 1.
pub fn exit_code(program: &str, result: anyhow::Result<ExitCode>) -> ExitCode {
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("{program}: {e:#}");
            if e.chain().any(|c| c.is::<ConfigError>()) {
                ExitCode::from(softarm_config::EXIT_CONFIG)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}

/// The test rig's commands, which `softarm-rig` has and the product does not.
pub const RIG_COMMANDS: [&str; 3] = ["emulate", "soak", "bench"];

/// `softarm`, the product: what `softarm install` installs.
pub fn main() -> ExitCode {
    // `softarm soak` and the others were the product's before: said where they are now.
    if let Some(command) = std::env::args()
        .nth(1)
        .filter(|a| RIG_COMMANDS.contains(&a.as_str()))
    {
        eprintln!(
            "softarm: `{command}` is the test rig's, not the product's: run `softarm-rig {command}` \
             (in a work tree: `cargo run --release --bin softarm-rig -- {command}`)"
        );
        return ExitCode::from(2);
    }
    let cli = Cli::parse();
    init_logging(if quiet(&cli.command) { "warn" } else { "info" });
    exit_code("softarm", run(cli.command))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `softarm up`, soak and systemd start a driver as `softarm <name>`: each driver of the
    /// registry is a subcommand.
    #[test]
    fn every_driver_is_a_subcommand() {
        for d in softarm_ipc::DRIVERS {
            let e = Cli::try_parse_from(["softarm", d.name, "--help"])
                .err()
                .unwrap();
            assert_eq!(e.kind(), clap::error::ErrorKind::DisplayHelp, "{}", d.name);
        }
        let e = Cli::try_parse_from(["softarm", "no-such-driver", "--help"])
            .err()
            .unwrap();
        assert_ne!(e.kind(), clap::error::ErrorKind::DisplayHelp);
    }
}
