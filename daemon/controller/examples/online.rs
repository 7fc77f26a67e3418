//! Diagnostic: Alg. 2 in one process, faster than real time ([`rehearse`]): the demo way-point
//! set on a scenario's arm, per execution the error at each conditioning point.
//! `cargo run --release -p softarm-controller --example online -- MODEL_DIR [EXECUTIONS]`
//! Environment: SCENARIO (shipped name or file, default nominal), ALGORITHM (softarm | paper),
//! SET (a way-point file, default config/waypoints/demo.toml), SECOND (a way-point file run
//! once afterwards on the adapted learner, and once on a fresh one), LEARNER (TOML overrides of
//! [learner], `;` for newlines).

use anyhow::{Context, bail};
use softarm_config::Config;
use softarm_config::scenario::Scenario;
use softarm_config::waypoints::WaypointFile;
use softarm_controller::rehearsal::rehearse;
use softarm_method::cacla::{CaclaMtl, LearnerConfig};
use softarm_method::online::OnlineLearner;
use softarm_method::plant::Plant;
use softarm_model::bundle::Model;

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(dir) = args.get(1) else {
        bail!("usage: online MODEL_DIR [EXECUTIONS]");
    };
    let model = Model::read(std::path::Path::new(dir))?;
    let executions: u32 = match args.get(2) {
        Some(s) => s.parse().context("EXECUTIONS must be a whole number")?,
        None => 20,
    };
    let env = |k: &str| std::env::var(k).unwrap_or_default();
    let config = Config::default_sim(".".into());
    let mut lc = toml::Table::try_from(config.learner)?;
    let overrides = env("LEARNER").replace(';', "\n");
    lc.extend(toml::from_str::<toml::Table>(&overrides).context("LEARNER")?);
    if !env("ALGORITHM").is_empty() {
        lc.insert("algorithm".into(), toml::Value::String(env("ALGORITHM")));
    }
    let lconf: LearnerConfig = lc.try_into().context("LEARNER")?;
    let scenario = Scenario::resolve(match env("SCENARIO").as_str() {
        "" => "nominal",
        s => s,
    })?;
    let (arm, sim) = scenario.apply(&config.arm, &config.sim)?;
    let load = |var: &str, default: &str| -> anyhow::Result<WaypointFile> {
        let path = match env(var).as_str() {
            "" => default.to_string(),
            p => p.to_string(),
        };
        WaypointFile::load(std::path::Path::new(&path)).map_err(anyhow::Error::msg)
    };
    let set = load("SET", "config/waypoints/demo.toml")?;
    let learner = || -> anyhow::Result<OnlineLearner> {
        let mut state = model.learner.clone();
        state.config = lconf;
        Ok(OnlineLearner::new(
            CaclaMtl::restore(&state).map_err(anyhow::Error::msg)?,
            model.kinematics.clone(),
        ))
    };
    let mut online = learner()?;
    let mut plant =
        Plant::new(arm, sim.realism, sim.initial_actuation).map_err(anyhow::Error::msg)?;
    let errors = rehearse(&model, &config, &set, executions, &mut online, &mut plant)?;
    println!(
        "{} on {} ({})",
        lconf.algorithm.name(),
        scenario.name,
        scenario.describe()
    );
    for (e, errs) in errors.iter().enumerate() {
        println!(
            "{:>3}: {} mean {:.2}",
            e + 1,
            errs.iter()
                .map(|x| format!("{:6.2}", x * 1e3))
                .collect::<String>(),
            mean(errs) * 1e3
        );
    }
    if !env("SECOND").is_empty() {
        let second = load("SECOND", "")?;
        let adapted = rehearse(&model, &config, &second, 1, &mut online, &mut plant)?;
        let mut fresh_plant =
            Plant::new(arm, sim.realism, sim.initial_actuation).map_err(anyhow::Error::msg)?;
        let fresh = rehearse(
            &model,
            &config,
            &second,
            1,
            &mut learner()?,
            &mut fresh_plant,
        )?;
        println!(
            "second set, first execution: adapted {:.2} mm, unadapted {:.2} mm",
            mean(&adapted[0]) * 1e3,
            mean(&fresh[0]) * 1e3
        );
    }
    Ok(())
}
