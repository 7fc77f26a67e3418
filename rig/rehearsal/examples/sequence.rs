//! Diagnostic: one learner through a sequence of arm changes, beside a fresh learner per phase.
use anyhow::Context;
use softarm_config::Config;
use softarm_config::arm::ArmGeometry;
use softarm_config::learner::Algorithm;
use softarm_config::waypoints::WaypointFile;
use softarm_learner::{Learner, online_learner};
use softarm_model::bundle::Model;
use softarm_rehearsal::Rehearsal;

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
    let model = Model::read(std::path::Path::new(&dir))?;
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
    let nominal = ArmGeometry::default();
    let mut p2 = nominal;
    p2.tool_m += 0.025;
    p2.actuator_offset_m[2] = 0.003;
    let mut p3 = nominal;
    p3.module_rotation_deg[0] = 7.0;
    p3.actuator_radius_m = 0.027;
    let mut p5 = nominal;
    p5.actuator_offset_m = [-0.002; 6];
    p5.tool_m -= 0.010;
    let phases = [
        (nominal, &demo, "nominal"),
        (p2, &demo, "tool+25"),
        (p3, &near, "twist+radius"),
        (nominal, &demo, "nominal"),
        (p5, &third, "shorter"),
    ];
    let executions: u32 = std::env::var("EXEC")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(6);
    let learner = || -> anyhow::Result<Learner<6>> {
        let online = online_learner(
            model.learner.clone(),
            model.kinematics.clone(),
            config.learner,
            softarm_kinematics::pcc::Arm::of_geometry(&config.paper_arm().unwrap()),
        )
        .map_err(anyhow::Error::msg)?;
        Ok(Learner::new(online, &config))
    };
    let mut running = Rehearsal::new(&model, &config, learner()?, nominal, &config.sim)?;
    for (arm, set, name) in phases {
        running.change_arm(arm)?;
        let changes_before = running.learner().arm_changes();
        let lag = running.lag().clone();
        let r: Vec<String> = running
            .rehearse(set, executions)?
            .iter()
            .map(|s| format!("{:5.1}", s.mean_m * 1e3))
            .collect();
        let mut fresh =
            Rehearsal::new(&model, &config, learner()?, arm, &config.sim)?.with_lag(&lag);
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
