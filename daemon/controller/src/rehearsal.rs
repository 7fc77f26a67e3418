//! Alg. 2 in one process, faster than real time and without iceoryx2: the controller's Eq. 11
//! engine and limiter drive a simulated plant (with its realism) at the controller's rate, and
//! an [`OnlineLearner`] gets each conditioning point's visit and answers with the next estimate
//! in the order the running stack asks for them. For tests that must fail when adaptation stops
//! working, and for tuning (`cargo run --release -p softarm-controller --example online`).

use anyhow::Context;
use softarm_config::Config;
use softarm_config::waypoints::WaypointFile;
use softarm_method::classify::classify;
use softarm_method::engine::{Planner, Timeline};
use softarm_method::online::OnlineLearner;
use softarm_method::plant::Plant;
use softarm_method::{ACTUATORS, Actuation, Position, distance};
use softarm_model::bundle::Model;

use crate::Limiter;

/// Runs `set` `executions` times on `plant`, which starts (and stays) where it is; returns the
/// error (m) at each conditioning point of each execution.
pub fn rehearse(
    model: &Model,
    config: &Config,
    set: &WaypointFile,
    executions: u32,
    learner: &mut OnlineLearner,
    plant: &mut Plant,
) -> anyhow::Result<Vec<Vec<f64>>> {
    let c = &config.controller;
    let rate = c.rate_hz;
    let n = set.point.len();
    let t: Vec<f64> = set.point.iter().map(|p| p.t_s).collect();
    let p: Vec<Position> = set.point.iter().map(|p| p.position_m).collect();
    let z: Vec<f64> = t.iter().map(|t| t / set.duration_s).collect();
    let classes = classify(&model.task, &p, &z, c.variance_floor)?;
    let planner = Planner::<ACTUATORS>::new(
        model.actuation.clone(),
        &t,
        &classes,
        Timeline::new(set.duration_s, rate)?,
        config.activation,
        c.variance_floor,
    )?;
    let cond = planner.conditioning_ticks().to_vec();
    let first = learner
        .start_set(&p)
        .context("the learner refused the set")?;
    let (mut engine, mut replanner) = planner.start(&first)?;
    let dt = 1.0 / rate;
    let mut limiter = Limiter::new(
        c.actuator_min,
        c.actuator_max,
        c.slew_per_s,
        rate,
        plant.state(),
    );
    let rest = (c.rest_s * rate).round() as usize;
    let mut errors = Vec::with_capacity(executions as usize);
    for e in 1..=executions {
        for _ in 0..rest {
            plant.step(&limiter.apply(&engine.rest()), dt);
        }
        let mut errs = vec![f64::NAN; n];
        let mut next = 0;
        for k in 0..engine.timeline().ticks() {
            let setpoint: Actuation = limiter.apply(&engine.tick(k));
            let m = plant.step(&setpoint, dt);
            let reached = m.position;
            if next < n && k == cond[next] {
                errs[next] = distance(&reached, &p[next]);
                learner.observe(next, &p[next], &setpoint, &reached, Some(&m.actuation))?;
                // The estimate wanted next: the following point, or the first of the next
                // execution, which explores from the second execution on.
                let (np, ne) = if next + 1 < n {
                    (next + 1, e)
                } else {
                    (0, e + 1)
                };
                let a = learner.estimate(np, &p[np], ne >= 2)?;
                replanner.recondition(np, &a)?;
                next += 1;
            }
        }
        errors.push(errs);
    }
    Ok(errors)
}

#[cfg(test)]
mod tests {
    use super::*;
    use softarm_config::scenario::Scenario;
    use softarm_method::cacla::{CaclaMtl, LearnerConfig};
    use softarm_method::online::Algorithm;

    fn mean(v: &[f64]) -> f64 {
        v.iter().sum::<f64>() / v.len() as f64
    }

    const DEMO: &str = include_str!("../../../config/waypoints/demo.toml");
    const SECOND: &str = include_str!("../../../config/waypoints/second.toml");

    /// A learner for `model` with `algorithm` and a plant of `scenario`'s arm.
    fn setup(model: &Model, scenario: &str, algorithm: Algorithm) -> (OnlineLearner, Plant) {
        let config = Config::default_sim(".".into());
        let (arm, sim) = Scenario::resolve(scenario)
            .unwrap()
            .apply(&config.arm, &config.sim)
            .unwrap();
        let mut state = model.learner.clone();
        state.config = LearnerConfig {
            algorithm,
            ..config.learner
        };
        let learner =
            OnlineLearner::new(CaclaMtl::restore(&state).unwrap(), model.kinematics.clone());
        let plant = Plant::new(arm, sim.realism, sim.initial_actuation).unwrap();
        (learner, plant)
    }

    /// The mean error of each of `executions` executions of `set`.
    fn means(
        model: &Model,
        set: &str,
        executions: u32,
        learner: &mut OnlineLearner,
        plant: &mut Plant,
    ) -> Vec<f64> {
        let config = Config::default_sim(".".into());
        let set = WaypointFile::parse(set).unwrap();
        rehearse(model, &config, &set, executions, learner, plant)
            .unwrap()
            .iter()
            .map(|e| mean(e))
            .collect()
    }

    /// A quick model from the pipeline, the demo set, and per algorithm the mean error of each
    /// of `executions` executions on `scenario`'s arm.
    fn run(model: &Model, scenario: &str, algorithm: Algorithm, executions: u32) -> Vec<f64> {
        let (mut learner, mut plant) = setup(model, scenario, algorithm);
        means(model, DEMO, executions, &mut learner, &mut plant)
    }

    fn quick() -> Model {
        let dir = std::env::temp_dir().join(format!(
            "softarm-rehearsal-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        softarm_model::pipeline::quick_model(&dir);
        let model = Model::read(&dir).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        model
    }

    fn mm(v: &[f64]) -> Vec<String> {
        v.iter().map(|e| format!("{:.1}", e * 1e3)).collect()
    }

    #[test]
    fn softarm_adapts_to_a_changed_arm_where_the_paper_does_not() {
        let model = quick();
        for scenario in ["tool-change", "creep"] {
            let ours = run(&model, scenario, Algorithm::Softarm, 8);
            let paper = run(&model, scenario, Algorithm::Paper, 8);
            eprintln!(
                "{scenario}: softarm {:?}, paper {:?}",
                mm(&ours),
                mm(&paper)
            );
            assert!(
                ours[4..].iter().all(|e| *e <= 0.003),
                "{scenario}: softarm from execution 5 on {:?} mm",
                mm(&ours)
            );
            assert!(
                ours.iter().all(|e| *e <= 1.5 * ours[0]),
                "{scenario}: softarm wandered {:?} mm",
                mm(&ours)
            );
            assert!(
                paper[4..].iter().any(|e| *e > 0.003),
                "{scenario}: the paper's algorithm reached 3 mm as well {:?} mm: the test no longer \
                 tells them apart",
                mm(&paper)
            );
        }
    }

    #[test]
    fn what_the_demo_set_taught_carries_over_to_a_second_set() {
        let model = quick();
        let (mut learner, mut plant) = setup(&model, "tool-change", Algorithm::Softarm);
        let demo = means(&model, DEMO, 8, &mut learner, &mut plant);
        let adapted = means(&model, SECOND, 1, &mut learner, &mut plant)[0];
        let (mut fresh, mut plant) = setup(&model, "tool-change", Algorithm::Softarm);
        let unadapted = means(&model, SECOND, 1, &mut fresh, &mut plant)[0];
        eprintln!(
            "demo set {:?} mm; second set: adapted {:.1} mm, unadapted {:.1} mm",
            mm(&demo),
            adapted * 1e3,
            unadapted * 1e3
        );
        assert!(unadapted > 0.01, "the longer tool is felt: {unadapted} m");
        assert!(
            adapted <= 0.5 * unadapted,
            "second set: adapted {adapted} m, unadapted {unadapted} m"
        );
    }
}
