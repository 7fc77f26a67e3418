//! Diagnostic: Alg. 2 in one process, faster than real time ([`Rehearsal`]): the demo way-point
//! set on a scenario's arm, per execution the error at each conditioning point, as
//! `softarm demo` prints them for the running stack.
//! `cargo run --release -p softarm-rehearsal --example online -- MODEL_DIR [EXECUTIONS]`
//! Environment: ARM (a shipped arm's name or an `[arm]` file, default the default config's: the
//! paper's arm), SCENARIO (shipped name or file, default nominal), ALGORITHM (gauss-newton |
//! paper), SEED (the learner's and the plant's, as `softarm demo --seed`; default the config's),
//! SET (a way-point file, default config/waypoints/demo.toml, the paper's arm's), SECOND (a
//! way-point file run
//! once afterwards on the adapted learner, and once on a fresh one), LEARNER (TOML overrides of
//! [learner], `;` for newlines), QUICK=1 (write the tests' quick model of the arm,
//! `softarm_test_support::quick_model_of`, to MODEL_DIR first), STALL=WHO:EVERY_MS:FOR_MS
//! (a loaded machine: `controller`, `sim` or `learner` kept from its CPU for FOR_MS every
//! EVERY_MS), SETS=K (the set submitted K times over, EXECUTIONS each, on the same learner
//! and arm: what a lab submitting a new set as its arm drifts sees at each set's start),
//! RUST_LOG (the learner's and the controller's log lines on stderr, e.g. `softarm_learner=info`).

use anyhow::{Context, bail};
use softarm_config::Config;
use softarm_config::learner::LearnerConfig;
use softarm_config::scenario::{OnArm, Scenario};
use softarm_config::waypoints::WaypointFile;
use softarm_ipc::ExecutionStats;
use softarm_learner::{Learner, online_learner};
use softarm_model::bundle::Model;
use softarm_rehearsal::{Rehearsal, Stalled, Stalls};
use softarm_sim::plant::Body;

fn env(k: &str) -> String {
    std::env::var(k).unwrap_or_default()
}

/// The default sim config on ARM's arm, with SEED and the [learner] of LEARNER and ALGORITHM.
fn config() -> anyhow::Result<Config> {
    let mut config = Config::default_sim(".".into());
    if !env("ARM").is_empty() {
        config = softarm_config::arms::into_config(config, &env("ARM"), None)?;
    }
    if !env("SEED").is_empty() {
        let seed: u64 = env("SEED").parse().context("SEED must be a whole number")?;
        config.learner.seed = seed;
        config.sim.realism.seed = seed;
    }
    let mut lc = toml::Table::try_from(config.learner)?;
    let overrides = env("LEARNER").replace(';', "\n");
    lc.extend(toml::from_str::<toml::Table>(&overrides).context("LEARNER")?);
    if !env("ALGORITHM").is_empty() {
        lc.insert("algorithm".into(), toml::Value::String(env("ALGORITHM")));
    }
    config.learner = lc.try_into::<LearnerConfig>().context("LEARNER")?;
    Ok(config)
}

fn load(var: &str, default: &str) -> anyhow::Result<WaypointFile> {
    let path = match env(var).as_str() {
        "" => default.to_string(),
        p => p.to_string(),
    };
    WaypointFile::load(std::path::Path::new(&path)).map_err(anyhow::Error::msg)
}

/// A stack of `config` with a fresh learner of `model`, its sim on `on`'s arm.
fn rehearsal<'a, const N: usize>(
    model: &'a Model<N>,
    config: &'a Config,
    on: &OnArm,
) -> anyhow::Result<Rehearsal<'a, N>> {
    let online = online_learner(
        model.learner.clone(),
        model.kinematics.clone(),
        config.learner,
        softarm_kinematics::pcc::Arm::of_config(&config.arm).map_err(anyhow::Error::msg)?,
    )
    .map_err(anyhow::Error::msg)?;
    let body = Body::of_arm(&on.arm, &on.steps).map_err(anyhow::Error::msg)?;
    let r = Rehearsal::new(model, config, Learner::new(online, config), body, &on.sim)?;
    Ok(match stalls()? {
        Some(s) => r.with_stalls(s),
        None => r,
    })
}

/// STALL=WHO:EVERY_MS:FOR_MS.
fn stalls() -> anyhow::Result<Option<Stalls>> {
    let v = env("STALL");
    if v.is_empty() {
        return Ok(None);
    }
    let parts: Vec<&str> = v.split(':').collect();
    let [who, every, length] = parts[..] else {
        bail!("STALL is WHO:EVERY_MS:FOR_MS, got {v}");
    };
    let of = match who {
        "controller" => Stalled::Controller,
        "sim" => Stalled::Sim,
        "learner" => Stalled::Learner,
        _ => bail!("STALL: WHO is controller, sim or learner, got {who}"),
    };
    let ms = |s: &str| -> anyhow::Result<u64> {
        Ok(s.parse::<u64>().context("STALL: a whole number of ms")? * 1_000_000)
    };
    Ok(Some(Stalls {
        of,
        every_ns: ms(every)?,
        for_ns: ms(length)?,
    }))
}

fn print(stats: &[ExecutionStats]) {
    for s in stats {
        println!(
            "{:>3}: {} mean {:.2} max {:.2} reconditions {}",
            s.execution,
            s.errors_m[..s.count as usize]
                .iter()
                .map(|x| format!("{:6.2}", x * 1e3))
                .collect::<String>(),
            s.mean_m * 1e3,
            s.max_m * 1e3,
            s.reconditions
        );
    }
}

fn main() -> anyhow::Result<()> {
    // The processes' log lines, on stderr, as RUST_LOG says (none without it).
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    let args: Vec<String> = std::env::args().collect();
    let Some(dir) = args.get(1) else {
        bail!("usage: online MODEL_DIR [EXECUTIONS]");
    };
    let config = config()?;
    if env("QUICK") == "1" {
        softarm_test_support::quick_model_of(std::path::Path::new(dir), &config);
    }
    let executions: u32 = match args.get(2) {
        Some(s) => s.parse().context("EXECUTIONS must be a whole number")?,
        None => 20,
    };
    let n = config.layout().actuators().len();
    softarm_ipc::with_actuators!(n, N => run::<N>(dir, &config, executions),
        n => bail!("an arm of {n} actuators"))
}

/// The rehearsal on an arm of `N` actuators.
fn run<const N: usize>(dir: &str, config: &Config, executions: u32) -> anyhow::Result<()> {
    let model = Model::<N>::read(std::path::Path::new(dir))?;
    let scenario = Scenario::resolve(match env("SCENARIO").as_str() {
        "" => "nominal",
        s => s,
    })?;
    let on = scenario.apply_to(&config.arm, &config.sim)?;
    let set = load("SET", "config/waypoints/demo.toml")?;
    let mut adapted = rehearsal(&model, config, &on)?;
    let sets: u32 = match env("SETS").as_str() {
        "" => 1,
        s => s.parse().context("SETS must be a whole number")?,
    };
    println!(
        "{} on {} ({}), errors at the conditioning points (mm)",
        config.learner.algorithm.name(),
        scenario.name,
        scenario.describe()
    );
    for k in 1..=sets {
        if sets > 1 {
            println!("set {k}:");
        }
        print(&adapted.rehearse(&set, executions)?);
    }
    if !env("SECOND").is_empty() {
        let second = load("SECOND", "")?;
        // The fresh learner beside the same controller: the lag it has measured.
        let fresh = rehearsal(&model, config, &on)?
            .with_lag(adapted.lag())
            .rehearse(&second, 1)?;
        let after = adapted.rehearse(&second, 1)?;
        println!("second set, adapted, then fresh:");
        print(&after);
        print(&fresh);
        println!(
            "second set, first execution: adapted {:.2} mm, unadapted {:.2} mm",
            after[0].mean_m * 1e3,
            fresh[0].mean_m * 1e3
        );
    }
    Ok(())
}
