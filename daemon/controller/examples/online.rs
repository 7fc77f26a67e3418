//! Diagnostic: Alg. 2 in one process, faster than real time: the Eq. 11 engine, the limiter, the
//! simulated plant (with realism) and the learner, executing the demo way-point set.
//! `cargo run --release -p softarm-controller --example online -- MODEL_DIR [EXECUTIONS]`
//! Config overrides as TOML in LEARNER / REALISM, e.g. LEARNER='alpha_actor = 0.5'.

use anyhow::{Context, bail};
use softarm_controller::Limiter;
use softarm_method::cacla::{CaclaMtl, LearnerConfig};
use softarm_method::classify::classify;
use softarm_method::engine::{Planner, Timeline};
use softarm_method::plant::Plant;
use softarm_method::{ACTUATORS, Actuation, distance};
use softarm_model::bundle::Model;
use softarm_model::config::Config;
use softarm_model::waypoints::WaypointFile;

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
    if executions == 0 {
        bail!("EXECUTIONS must be at least 1");
    }
    let config = Config::default_sim(".".into());
    let env = |k: &str| std::env::var(k).unwrap_or_default().replace(';', "\n");
    let mut lc = toml::Table::try_from(config.learner)?;
    lc.extend(toml::from_str::<toml::Table>(&env("LEARNER")).context("LEARNER")?);
    let lconf: LearnerConfig = lc.try_into().context("LEARNER")?;
    let mut rc = toml::Table::try_from(config.sim.realism)?;
    rc.extend(toml::from_str::<toml::Table>(&env("REALISM")).context("REALISM")?);
    let realism = rc.try_into().context("REALISM")?;
    let mut state = model.learner.clone();
    state.config = lconf;
    let mut learner = CaclaMtl::restore(&state).map_err(anyhow::Error::msg)?;
    let file = WaypointFile::parse(include_str!("../../../config/waypoints/demo.toml"))
        .map_err(anyhow::Error::msg)?;
    let n = file.point.len();
    let t: Vec<f64> = file.point.iter().map(|p| p.t_s).collect();
    let p: Vec<[f64; 3]> = file.point.iter().map(|p| p.position_m).collect();
    let z: Vec<f64> = t.iter().map(|t| t / file.duration_s).collect();
    let rate = config.controller.rate_hz;
    let c = &config.controller;
    let q = classify(&model.task, &p, &z, c.variance_floor)?;
    let planner = Planner::<ACTUATORS>::new(
        model.actuation.clone(),
        &t,
        &q,
        Timeline::new(file.duration_s, rate)?,
        config.activation,
        c.variance_floor,
    )?;
    let cond = planner.conditioning_ticks().to_vec();
    let initial: Vec<Actuation> = (0..n).map(|i| learner.act(i, &p[i], false)).collect();
    let (mut engine, mut replanner) = planner.start(&initial)?;
    let mut plant = Plant::new(config.arm, realism, config.sim.initial_actuation)
        .map_err(anyhow::Error::msg)?;
    let dt = 1.0 / rate;
    let start = config.sim.initial_actuation;
    let mut lim = Limiter::new(c.actuator_min, c.actuator_max, c.slew_per_s, rate, start);
    let rest = (c.rest_s * rate).round() as usize;
    let mut last = 0.0;
    let mut means = Vec::new();
    for e in 1..=executions {
        for _ in 0..rest {
            let c = lim.apply(&engine.rest());
            plant.step(&c, dt);
        }
        let mut errs = vec![0.0; n];
        let mut next = 0;
        for k in 0..engine.timeline().ticks() {
            let c = lim.apply(&engine.tick(k));
            let m = plant.step(&c, dt);
            if next < n && k == cond[next] {
                let i = next;
                let reached = m.position;
                errs[i] = distance(&reached, &p[i]);
                learner.observe(i, &p[i], &c, &reached);
                let (np, ne) = if i + 1 < n { (i + 1, e) } else { (0, e + 1) };
                let a = learner.act(np, &p[np], ne >= 2);
                replanner.recondition(np, &a)?;
                next += 1;
            }
        }
        let mean = errs.iter().sum::<f64>() / n as f64;
        last = mean;
        means.push(mean);
        if e == 1 || e % 5 == 0 || std::env::var("ALL").is_ok() {
            println!(
                "{e:>3}: {} mean {:.2}",
                errs.iter()
                    .map(|x| format!("{:6.2}", x * 1e3))
                    .collect::<String>(),
                mean * 1e3
            );
        }
    }
    let tail = &means[means.len().saturating_sub(5)..];
    println!(
        "first {:.2} mm, last {:.2} mm, mean of the last 5 {:.2} mm",
        means[0] * 1e3,
        last * 1e3,
        tail.iter().sum::<f64>() / tail.len() as f64 * 1e3
    );
    Ok(())
}
