//! Diagnostic: `softarm-rig soak`'s pattern (`softarm_rig::soak::sets::nth`) in one process, faster than real time: sets one after
//! another (the demo set every third, else a variation of it, each point moved up to 25 mm and
//! sometimes one left out), 3 to 6 executions each, the arm changed to the next scenario of a
//! rotation every CHANGE_EVERY_S of simulated time; per set its executions' mean errors.
//! On the default `[arm]` (the paper's, whose the demo set is).
//! `cargo run --release -p softarm-rehearsal --example soak -- MODEL_DIR [MINUTES]`
//! Environment: SEED (default 1), SCENARIOS (comma-separated, default soak's rotation),
//! CHANGE_EVERY_S (default 120).
use anyhow::Context;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use softarm_config::Config;
use softarm_config::arm::ArmConfig;
use softarm_config::scenario::Scenario;
use softarm_config::waypoints::WaypointFile;
use softarm_learner::{Learner, online_learner};
use softarm_model::bundle::Model;
use softarm_rehearsal::Rehearsal;
use softarm_sim::plant::Body;

/// The default `[arm]`'s actuators.
const N: usize = 6;

/// The least error with which `arm` can reach `target` inside the actuators' range [0, 1]:
/// projected damped Gauss-Newton from several starts.
fn reachable(arm: &softarm_kinematics::pcc::Arm, target: &[f64; 3], rng: &mut StdRng) -> f64 {
    use softarm_kinematics::forward::{ForwardModel, finite_difference};
    let position = |a: &[f64; N]| ForwardModel::<N>::position(arm, a);
    let mut best = f64::INFINITY;
    for start in 0..12 {
        let mut a: [f64; N] = if start == 0 {
            [0.5; N]
        } else {
            std::array::from_fn(|_| rng.random_range(0.05..0.95))
        };
        for _ in 0..300 {
            let p = position(&a);
            let e = nalgebra::Vector3::new(target[0] - p[0], target[1] - p[1], target[2] - p[2]);
            let j = finite_difference(arm, &a);
            let jt = j.transpose();
            let m = j * jt + nalgebra::Matrix3::identity() * 1e-6;
            let Some(inv) = m.try_inverse() else { break };
            let step = jt * inv * e;
            for i in 0..N {
                a[i] = (a[i] + 0.5 * step[i]).clamp(0.0, 1.0);
            }
        }
        let p = position(&a);
        let d =
            ((target[0] - p[0]).powi(2) + (target[1] - p[1]).powi(2) + (target[2] - p[2]).powi(2))
                .sqrt();
        best = best.min(d);
    }
    best
}

/// The sim's arm `arm`, nothing changing it.
fn body(arm: &ArmConfig) -> anyhow::Result<Body> {
    Body::of_arm(arm, &[]).map_err(anyhow::Error::msg)
}

fn main() -> anyhow::Result<()> {
    let dir = std::env::args().nth(1).context("MODEL_DIR")?;
    let minutes: f64 = std::env::args()
        .nth(2)
        .map_or(Ok(12.0), |s| s.parse())
        .context("MINUTES")?;
    let env = |k: &str| std::env::var(k).ok();
    let seed: u64 = env("SEED").map_or(Ok(1), |s| s.parse())?;
    let every_s: f64 = env("CHANGE_EVERY_S").map_or(Ok(120.0), |s| s.parse())?;
    let rotation = env("SCENARIOS").unwrap_or("tool-change,creep,twist,stiffer,nominal".into());
    let model = Model::<N>::read(std::path::Path::new(&dir))?;
    let mut config = Config::default_sim(".".into());
    config.learner.seed = seed;
    config.sim.realism.seed = seed;
    if let Some(t) = env("TAPER") {
        config.sim.realism.curvature_taper = t.parse()?;
    }
    let demo = WaypointFile::load(std::path::Path::new("config/waypoints/demo.toml"))
        .map_err(anyhow::Error::msg)?;
    let kinematics =
        softarm_kinematics::pcc::Arm::of_config(&config.arm).map_err(anyhow::Error::msg)?;
    let online = || {
        online_learner(
            model.learner.clone(),
            model.kinematics.clone(),
            config.learner,
            kinematics,
        )
        .map_err(anyhow::Error::msg)
    };
    let learner = Learner::new(online()?, &config);
    let mut r = Rehearsal::new(&model, &config, learner, body(&config.arm)?, &config.sim)?;
    let mut arm = config.arm.clone();
    let mut rng = StdRng::seed_from_u64(seed);
    let scenarios: Vec<&str> = rotation.split(',').collect();
    let (mut t_s, mut next_change_s, mut next) = (0.0, every_s, 0);
    let (mut sets, mut over, mut worse, mut from_third) = (0u64, 0, 0, 0);
    let mut name = "nominal".to_string();
    while t_s < minutes * 60.0 {
        let changes = r.learner().arm_changes();
        if t_s >= next_change_s {
            let s = Scenario::resolve(scenarios[next % scenarios.len()])?;
            arm = s.apply_to(&config.arm, &config.sim)?.arm;
            r.change_arm(body(&arm)?)?;
            name = s.name.clone();
            next += 1;
            next_change_s += every_s;
        }
        let (set, executions) = softarm_rig::soak::sets::nth(
            sets,
            &demo,
            softarm_rig::soak::sets::MOVE_M,
            config.waypoints.reach_m,
            &mut rng,
        );
        // A fresh learner beside the same controller: the lag it had measured.
        let lag = r.lag().clone();
        let stats = r.rehearse(&set, executions)?;
        let fresh = Rehearsal::new(
            &model,
            &config,
            Learner::new(online()?, &config),
            body(&arm)?,
            &config.sim,
        )?
        .with_lag(&lag)
        .rehearse(&set, 1)?[0]
            .mean_m
            * 1e3;
        let means: Vec<f64> = stats.iter().map(|s| s.mean_m * 1e3).collect();
        let last = *means.last().unwrap_or(&f64::NAN);
        over += usize::from(last > 2.5);
        worse += usize::from(means[0] > 1.1 * fresh);
        from_third += means.iter().skip(2).filter(|m| **m > 2.0).count();
        println!(
            "{t_s:6.0} s {name:>12} set {sets:3} ({}): fresh {fresh:5.1} | {} | last {last:.1}{} changes seen {}",
            if sets % 3 == 0 { "demo" } else { "var " },
            means.iter().map(|m| format!("{m:5.1}")).collect::<String>(),
            if last > 2.5 { " OVER" } else { "" },
            r.learner().arm_changes() - changes
        );
        if std::env::var("POINTS").is_ok() {
            let mut r2 = StdRng::seed_from_u64(7);
            println!(
                "      reach {}",
                set.point
                    .iter()
                    .map(|p| {
                        let arm = softarm_kinematics::pcc::Arm::of_config(&arm).unwrap();
                        format!("{:6.1}", reachable(&arm, &p.position_m, &mut r2) * 1e3)
                    })
                    .collect::<String>()
            );
            for s in &stats {
                println!(
                    "      {}",
                    s.errors_m[..s.count as usize]
                        .iter()
                        .map(|e| format!("{:6.1}", e * 1e3))
                        .collect::<String>()
                );
            }
        }
        sets += 1;
        t_s += executions as f64 * (set.duration_s + config.controller.rest_s) + 0.2;
    }
    println!(
        "{sets} sets, {over} with the last execution over 2.5 mm, {worse} whose first execution \
         was over 1.1x a fresh learner's, {from_third} executions from the third on over 2 mm"
    );
    Ok(())
}
