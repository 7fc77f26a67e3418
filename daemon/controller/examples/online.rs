//! Diagnostic: Alg. 2 in one process, faster than real time: the Eq. 11 engine, the limiter, the
//! simulated plant (with realism) and the learner, executing the demo way-point set.
//! `cargo run --release -p softarm-daemon --example online -- MODEL_DIR [EXECUTIONS]`
//! Config overrides as TOML in LEARNER / REALISM, e.g. LEARNER='alpha_actor = 0.5'.
use softarm_controller::Limiter;
use softarm_method::cacla::{CaclaMtl, LearnerConfig};
use softarm_method::classify::classify;
use softarm_method::engine::{Planner, Timeline};
use softarm_method::plant::Plant;
use softarm_model::bundle::Model;
use softarm_model::config::Config;
use softarm_model::waypoints::WaypointFile;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let model = Model::read(std::path::Path::new(&args[1])).unwrap();
    let executions: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(20);
    let config = Config::default_sim(".".into());
    let env = |k: &str| std::env::var(k).unwrap_or_default().replace(';', "\n");
    let mut lc: toml::Table = toml::Table::try_from(config.learner).unwrap();
    lc.extend(toml::from_str::<toml::Table>(&env("LEARNER")).unwrap());
    let lconf: LearnerConfig = lc.try_into().unwrap();
    let mut rc: toml::Table = toml::Table::try_from(config.sim.realism).unwrap();
    rc.extend(toml::from_str::<toml::Table>(&env("REALISM")).unwrap());
    let realism = rc.try_into().unwrap();
    let mut state = model.learner.clone();
    state.config = lconf;
    let mut learner = CaclaMtl::restore(&state).unwrap();
    let file = WaypointFile::parse(include_str!("../../../config/waypoints/demo.toml")).unwrap();
    let n = file.point.len();
    let t: Vec<f64> = file.point.iter().map(|p| p.t_s).collect();
    let p: Vec<[f64; 3]> = file.point.iter().map(|p| p.position_m).collect();
    let z: Vec<f64> = t.iter().map(|t| t / file.duration_s).collect();
    let rate = config.controller.rate_hz;
    let q = classify(&model.task, &p, &z, 1e-6).unwrap();
    let planner = Planner::<6>::new(
        model.actuation.clone(),
        &t,
        &q,
        Timeline::new(file.duration_s, rate).unwrap(),
        config.activation,
        1e-6,
    )
    .unwrap();
    let cond = planner.conditioning_ticks().to_vec();
    let initial: Vec<[f64; 6]> = (0..n).map(|i| learner.act(i, &p[i], false)).collect();
    let (mut engine, mut replanner) = planner.start(&initial).unwrap();
    let mut plant = Plant::new(config.arm, realism, [0.5; 6]).unwrap();
    let dt = 1.0 / rate;
    let mut lim = Limiter::new(
        [0.0; 6],
        [1.0; 6],
        config.controller.slew_per_s,
        rate,
        [0.5; 6],
    );
    let rest = (config.controller.rest_s * rate) as usize;
    let mut last = 0.0;
    let mut means = Vec::new();
    for e in 1..=executions {
        for _ in 0..rest {
            let c = lim.apply(&engine.evaluate(0));
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
                errs[i] = ((0..3).map(|d| (reached[d] - p[i][d]).powi(2)).sum::<f64>()).sqrt();
                learner.observe(i, &p[i], &c, &reached);
                let (np, ne) = if i + 1 < n { (i + 1, e) } else { (0, e + 1) };
                let a = learner.act(np, &p[np], ne >= 2);
                replanner.recondition(np, &a).unwrap();
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
}
