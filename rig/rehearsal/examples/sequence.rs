//! Diagnostic: one learner through a sequence of arm changes, beside a fresh learner per phase,
//! on the default `[arm]` (the paper's, whose the demo set is).
use anyhow::Context;
use softarm_config::Config;
use softarm_config::arm::ArmConfig;
use softarm_config::learner::Algorithm;
use softarm_config::waypoints::WaypointFile;
use softarm_learner::{Learner, online_learner};
use softarm_model::bundle::Model;
use softarm_rehearsal::Rehearsal;
use softarm_sim::plant::Body;

/// The default `[arm]`'s actuators.
const N: usize = 6;

fn shifted(set: &WaypointFile, d: [f64; 3]) -> WaypointFile {
    let mut s = set.clone();
    for p in &mut s.point {
        for i in 0..3 {
            p.position_m[i] += d[i];
        }
    }
    s
}

fn main() -> anyhow::Result<()> {
    let dir = std::env::args().nth(1).context("MODEL_DIR")?;
    let model = Model::<N>::read(std::path::Path::new(&dir))?;
    let mut config = Config::default_sim(".".into());
    if let Ok(a) = std::env::var("ALGORITHM") {
        config.learner.algorithm = if a == "paper" {
            Algorithm::Paper
        } else {
            Algorithm::GaussNewton
        };
    }
    if let Ok(l) = std::env::var("LEARNER") {
        let mut t = toml::Table::try_from(config.learner.gauss_newton)?;
        t.extend(toml::from_str::<toml::Table>(&l.replace(';', "\n"))?);
        config.learner.gauss_newton = t.try_into()?;
    }
    let demo = WaypointFile::load(std::path::Path::new("config/waypoints/demo.toml"))
        .map_err(anyhow::Error::msg)?;
    let near = shifted(&demo, [0.008, 0.006, -0.004]);
    let third = shifted(&demo, [-0.01, -0.008, 0.006]);
    let nominal = ArmConfig::default();
    let p2 = ArmConfig {
        tool_m: Some(0.055),
        actuator_offset_m: Some(vec![0.0, 0.0, 0.003, 0.0, 0.0, 0.0]),
        ..ArmConfig::default()
    };
    let p3 = ArmConfig {
        module_rotation_deg: Some([7.0, 60.0]),
        actuator_radius_m: Some(0.027),
        ..ArmConfig::default()
    };
    let p5 = ArmConfig {
        actuator_offset_m: Some(vec![-0.002; N]),
        tool_m: Some(0.02),
        ..ArmConfig::default()
    };
    let body = |arm: &ArmConfig| Body::of_arm(arm, &[]).map_err(anyhow::Error::msg);
    let phases = [
        (&nominal, &demo, "nominal"),
        (&p2, &demo, "tool+25"),
        (&p3, &near, "twist+radius"),
        (&nominal, &demo, "nominal"),
        (&p5, &third, "shorter"),
    ];
    let executions: u32 = std::env::var("EXEC")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(6);
    let learner = || -> anyhow::Result<Learner<N>> {
        let online = online_learner(
            model.learner.clone(),
            model.kinematics.clone(),
            config.learner,
            softarm_kinematics::pcc::Arm::of_config(&config.arm).map_err(anyhow::Error::msg)?,
        )
        .map_err(anyhow::Error::msg)?;
        Ok(Learner::new(online, &config))
    };
    let mut running = Rehearsal::new(&model, &config, learner()?, body(&nominal)?, &config.sim)?;
    for (arm, set, name) in phases {
        running.change_arm(body(arm)?)?;
        let changes_before = running.learner().arm_changes();
        let lag = running.lag().clone();
        let r: Vec<String> = running
            .rehearse(set, executions)?
            .iter()
            .map(|s| format!("{:5.1}", s.mean_m * 1e3))
            .collect();
        let mut fresh =
            Rehearsal::new(&model, &config, learner()?, body(arm)?, &config.sim)?.with_lag(&lag);
        let f: Vec<String> = fresh
            .rehearse(set, executions)?
            .iter()
            .map(|s| format!("{:5.1}", s.mean_m * 1e3))
            .collect();
        println!(
            "{name:>14}: running {} | fresh {} (changes {} at hold, {} in all)",
            r.join(" "),
            f.join(" "),
            changes_before,
            running.learner().arm_changes()
        );
    }
    Ok(())
}
