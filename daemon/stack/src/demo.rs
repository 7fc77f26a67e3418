//! `softarm demo`: the one-command showcase. Brings the simulated stack up in a namespace of its
//! own, trains if no readable bundle exists, submits the demo way-point set (or `--set`), prints
//! the error at every conditioning point per execution, optionally runs a second set once on
//! what was learnt (`--then`), and stops everything.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use softarm_clients::{plot, record, stats, submit};
use softarm_config::scenario::Scenario;
use softarm_config::waypoints::{WaypointFile, validate};
use softarm_config::{Config, DEFAULT};
use softarm_ipc::{ExecutionStats, Namespace};

use crate::scratch::{self, Scratch};
use crate::supervisor::{self, Supervisor};

#[derive(clap::Args)]
pub struct Args {
    /// Executions of the way-point set.
    #[arg(long, default_value_t = 20, allow_negative_numbers = true)]
    executions: u32,
    /// Seeds the demonstrations, the plant and the learner.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    /// One JSON object per execution on stdout (as `softarm stats --json`), nothing else.
    #[arg(long)]
    json: bool,
    /// Where the trained model is kept between runs (default: the user's cache folder).
    #[arg(long)]
    model_dir: Option<PathBuf>,
    /// Runs the set on another arm than the model was trained on: a shipped scenario (nominal,
    /// tool-change, creep, twist, stiffer) or a scenario file. The model stays the nominal one.
    #[arg(long)]
    scenario: Option<String>,
    /// The online learner: gauss-newton (Jacobian-directed steps; "softarm", its former name,
    /// still works) or paper (Alg. 1 as printed).
    #[arg(long, value_enum, default_value_t = Learner::GaussNewton)]
    learner: Learner,
    /// The way-point file to run (default: the demo set, config/waypoints/demo.toml).
    #[arg(long, value_name = "FILE")]
    set: Option<PathBuf>,
    /// A second way-point file, run once after the first set's executions, on what the learner
    /// learnt: how far it carries to points it has not visited.
    #[arg(long, value_name = "FILE")]
    then: Option<PathBuf>,
    /// Records the run here (MCAP), and plots it beside it (the same name, .png).
    #[arg(long, value_name = "FILE", default_value = "softarm-demo.mcap")]
    record: PathBuf,
    /// Neither records nor plots.
    #[arg(long)]
    no_record: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, clap::ValueEnum)]
enum Learner {
    /// `learner.algorithm = "gauss-newton"`; `softarm` is its former name.
    #[value(alias = "softarm")]
    GaussNewton,
    Paper,
}

fn say(json: bool, line: &str) {
    if !json {
        eprintln!("{line}");
    }
}

pub fn run(args: &Args, stop: &AtomicBool) -> anyhow::Result<()> {
    let scenario = check(args)?;
    let started = Instant::now();
    let scratch = scratch_for(args)?;
    let (config, ns) = (&scratch.config, &scratch.namespace);
    // The user's sets, read and checked as the controller will check them, before the stack.
    let (file, then) = sets(args, config)?;

    let mut sup = scratch.supervisor(&["sim", "controller", "learner"], "warn")?;
    say(
        args.json,
        &format!("softarm demo: stack up in namespace {}", ns.as_str()),
    );
    scratch.ready_with_model(&mut sup, stop, args.seed, &|line| {
        say(args.json, &format!("softarm demo: {line}"))
    })?;
    if let Some(s) = scenario.as_ref().filter(|s| !s.is_nominal()) {
        become_scenario(args, s, &scratch, &mut sup, stop)?;
    }

    // Subscribe before submitting: no execution's stats can be missed.
    let follower = stats::Stats::open(ns)?;
    // The recorder is one more subscriber, on a thread of its own, from here to the end.
    let recording_stop = Arc::new(AtomicBool::new(false));
    let recording = (!args.no_record).then(|| {
        let (ns, out, stop) = (ns.clone(), args.record.clone(), recording_stop.clone());
        let scene = softarm_clients::scene::Settings::of(config);
        std::thread::spawn(move || record::record(&ns, &out, &scene, None, &stop))
    });
    let run_set = |file: &WaypointFile, executions: u32, sup: &mut Supervisor| {
        run_set(
            ns,
            &follower,
            file,
            executions,
            config.controller.rest_s,
            args.json,
            sup,
            stop,
        )
    };
    let rows = run_set(&file, args.executions, &mut sup)?;
    let second = match &then {
        Some(file) => Some(run_set(file, 1, &mut sup)?),
        None => None,
    };
    recording_stop.store(true, Ordering::Relaxed);
    sup.stop(Duration::from_secs(5));
    if let Some(recording) = recording {
        let counts = recording
            .join()
            .map_err(|_| anyhow::anyhow!("the recorder panicked"))??;
        plot_recording(args, counts.values().sum())?;
    }
    summary(args, &rows, second.as_deref(), started);
    Ok(())
}

/// What can be refused before anything starts (a stack, minutes of training), rather than at
/// the end of the run; the scenario, resolved.
fn check(args: &Args) -> anyhow::Result<Option<Scenario>> {
    if args.executions == 0 {
        bail!("--executions must be at least 1");
    }
    let scenario = args
        .scenario
        .as_deref()
        .map(Scenario::resolve)
        .transpose()?;
    if !args.no_record {
        record::check_output(&args.record).context("--record")?;
        plot::check_output(&args.record.with_extension("png")).context("--record")?;
    }
    let model_dir = model_dir(args);
    if model_dir.exists() && !model_dir.is_dir() {
        bail!("the model folder {} is not a folder", model_dir.display());
    }
    Ok(scenario)
}

fn model_dir(args: &Args) -> PathBuf {
    args.model_dir
        .clone()
        .unwrap_or_else(|| scratch::cache_dir().join(format!("demo-model-seed{}", args.seed)))
}

/// The embedded default, in this demo's own namespace, with its own state, model and seeds.
fn scratch_for(args: &Args) -> anyhow::Result<Scratch> {
    let seed = i64::try_from(args.seed).context("--seed must be at most 9223372036854775807")?;
    let algorithm = match args.learner {
        Learner::GaussNewton => "gauss-newton",
        Learner::Paper => "paper",
    };
    Scratch::new(
        "demo",
        DEFAULT,
        &[
            ("model.dir", model_dir(args).display().to_string().into()),
            ("learner.seed", seed.into()),
            ("learner.algorithm", algorithm.into()),
            ("sim.realism.seed", seed.into()),
        ],
    )
}

/// The set to run (`--set`, else the demo's) and the one to run once after (`--then`), each
/// refused where the controller would refuse it.
fn sets(args: &Args, config: &Config) -> anyhow::Result<(WaypointFile, Option<WaypointFile>)> {
    let file = match &args.set {
        Some(path) => load_set("--set", path, config, args.executions)?,
        None => {
            let file = WaypointFile::parse(scratch::DEMO_WAYPOINTS)
                .map_err(anyhow::Error::msg)
                .context("the demo way-points")?;
            file.to_set(args.executions)
                .and_then(|set| validate(&set, &config.waypoints, &config.activation))
                .map_err(|e| anyhow::anyhow!("--executions: {e}"))?;
            file
        }
    };
    let then = args
        .then
        .as_deref()
        .map(|path| load_set("--then", path, config, 1))
        .transpose()?;
    Ok((file, then))
}

/// Trained (or reused) on the nominal arm; now the sim becomes the scenario's arm.
fn become_scenario(
    args: &Args,
    s: &Scenario,
    scratch: &Scratch,
    sup: &mut Supervisor,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    say(
        args.json,
        &format!(
            "softarm demo: the sim runs scenario {}: {}",
            s.name,
            s.describe()
        ),
    );
    let arg = args.scenario.as_deref();
    sup.restart_with("sim", supervisor::sim_args(arg), Duration::from_secs(5))?;
    scratch.wait_for(
        "the scenario's sim coming up",
        Duration::from_secs(20),
        sup,
        stop,
        &|r| {
            r.alive.iter().any(|n| n == "sim")
                && r.controller
                    .is_some_and(|s| s.state == softarm_ipc::ControllerState::Idle as u32)
        },
    )
}

/// The finished recording of `samples` samples drawn beside it (`.png`).
fn plot_recording(args: &Args, samples: u64) -> anyhow::Result<()> {
    let png = args.record.with_extension("png");
    let messages = record::read(&args.record)?;
    let data = record::plot_data(&messages, "softarm demo")?;
    plot::render(&data, &png)?;
    say(
        args.json,
        &format!(
            "softarm demo: recorded {} ({samples} samples; `softarm replay` reads it), plotted {}",
            args.record.display(),
            png.display()
        ),
    );
    Ok(())
}

fn summary(
    args: &Args,
    rows: &[ExecutionStats],
    second: Option<&[ExecutionStats]>,
    started: Instant,
) {
    let first = rows.first().expect("at least one execution");
    let last = rows.last().expect("at least one execution");
    say(
        args.json,
        &format!(
            "softarm demo: mean error at the conditioning points {:.2} mm (execution 1) -> {:.2} mm (execution {}); {:.0} s in all",
            first.mean_m * 1e3,
            last.mean_m * 1e3,
            last.execution,
            started.elapsed().as_secs_f64()
        ),
    );
    if let Some(s) = second.and_then(|r| r.first()) {
        say(
            args.json,
            &format!(
                "softarm demo: the second set's first execution: {:.2} mm",
                s.mean_m * 1e3
            ),
        );
    }
}

/// The way-point file of option `flag`, refused (naming both) where the controller would refuse
/// it for `executions` executions under `config`'s limits.
fn load_set(
    flag: &str,
    path: &Path,
    config: &Config,
    executions: u32,
) -> anyhow::Result<WaypointFile> {
    let file = WaypointFile::load(path)
        .map_err(anyhow::Error::msg)
        .context(flag.to_string())?;
    file.to_set(executions)
        .and_then(|set| validate(&set, &config.waypoints, &config.activation))
        .map_err(|e| anyhow::anyhow!("{flag} {}: {e}", path.display()))?;
    Ok(file)
}

/// Submits `file` for `executions` executions and prints each execution's row as it ends.
#[allow(clippy::too_many_arguments)]
fn run_set(
    ns: &Namespace,
    follower: &stats::Stats,
    file: &WaypointFile,
    executions: u32,
    rest_s: f64,
    json: bool,
    sup: &mut Supervisor,
    stop: &AtomicBool,
) -> anyhow::Result<Vec<ExecutionStats>> {
    let waypoints = file.to_set(executions).map_err(anyhow::Error::msg)?;
    let set_id = match submit::submit(ns, waypoints, Duration::from_secs(10)) {
        submit::Outcome::Accepted { set_id } => set_id,
        submit::Outcome::Rejected { reason } => {
            bail!("the way-point set was rejected: {reason}");
        }
        submit::Outcome::Unreachable { message } => bail!(message),
    };
    say(
        json,
        &format!(
            "softarm demo: {executions} executions of {} conditioning points ({} s each)",
            file.point.len(),
            file.duration_s
        ),
    );
    say(json, &stats::table_header(file.point.len()));
    // Both bounded by validation (the set's duration, the config's rest).
    let per_execution = Duration::try_from_secs_f64(file.duration_s + rest_s + 10.0)
        .context("the way-point set's duration")?;
    let mut rows: Vec<ExecutionStats> = Vec::new();
    while rows.len() < executions as usize {
        if stop.load(Ordering::Relaxed) {
            bail!("interrupted");
        }
        sup.poll();
        let Some(s) = follower.next(per_execution) else {
            bail!(
                "no stats for execution {} within {} s",
                rows.len() + 1,
                per_execution.as_secs()
            );
        };
        if s.set_id != set_id {
            continue;
        }
        if json {
            println!("{}", stats::json_line(&s));
        } else {
            println!("{}", stats::table_row(&s));
        }
        rows.push(s);
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::ValueEnum;

    #[test]
    fn the_learner_flag_takes_the_new_name_and_the_former_one() {
        assert_eq!(
            Learner::GaussNewton.to_possible_value().unwrap().get_name(),
            "gauss-newton"
        );
        for name in ["gauss-newton", "softarm"] {
            assert_eq!(
                Learner::from_str(name, false),
                Ok(Learner::GaussNewton),
                "{name}"
            );
        }
        assert_eq!(Learner::from_str("paper", false), Ok(Learner::Paper));
    }
}
