//! A lab's own MJCF through its map: the OpenCR TDCR's model (config/mujoco), as the sim runs
//! it. Built only with the `physics` feature (MuJoCo's library).
#![cfg(feature = "physics")]

use std::path::{Path, PathBuf};

use softarm_mujoco::MujocoArm;
use softarm_sections::arm::ArmConfig;
use softarm_sections::mujoco::{MujocoConfig, TipLoad};
use softarm_sim::plant::Physics;
use softarm_test_alloc::{self as alloc, Counting};

#[global_allocator]
static GLOBAL: Counting = Counting;

fn folder() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/mujoco")
}

/// The plant file's arm and map.
fn plant() -> (ArmConfig, MujocoConfig) {
    let text = std::fs::read_to_string(folder().join("opencr-ftdcr-v6.toml")).unwrap();
    let mut table: toml::Table = toml::from_str(&text).unwrap();
    let arm = table.remove("arm").unwrap().try_into().unwrap();
    let mujoco = table.remove("mujoco").unwrap().try_into().unwrap();
    (arm, mujoco)
}

fn arm_of(config: &MujocoConfig, arm: &ArmConfig, steps: &[(f64, ArmConfig)]) -> MujocoArm {
    MujocoArm::new(config, arm, arm, steps, &folder()).unwrap()
}

fn refused(config: &MujocoConfig) -> String {
    let (arm, _) = plant();
    match MujocoArm::new(config, &arm, &arm, &[], &folder()) {
        Ok(_) => panic!("taken"),
        Err(e) => e.to_string(),
    }
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

/// Holds `a` on every actuator but `pulled` (at `to`) until `t`.
fn hold(arm: &mut MujocoArm, t: f64, pulled: Option<(usize, f64)>) -> [f64; 3] {
    let mut a = [0.5; 9];
    if let Some((i, to)) = pulled {
        a[i] = to;
    }
    arm.advance(t, &a, &[0.0; 9])
}

#[test]
fn the_lab_model_stands_straight_and_each_tendon_bends_it_towards_its_side() {
    let (arm, config) = plant();
    let mut mj = arm_of(&config, &arm, &[]);
    // Straight: 222 mm of backbone and the 8 mm marker above the base.
    let straight = hold(&mut mj, 1.0, None);
    assert!(
        distance(straight, [0.0, 0.0, 0.230]) < 0.001,
        "{straight:?}"
    );
    // Tendon 1 of segment 1 sits at 0°: pulled (actuation 0: 13 mm shorter), the tip leans
    // towards +x; tendon 2 (120°) towards +y.
    let mut mj = arm_of(&config, &arm, &[]);
    let bent = hold(&mut mj, 1.0, Some((0, 0.0)));
    assert!(bent[0] > 0.03 && bent[1].abs() < 0.3 * bent[0], "{bent:?}");
    let mut mj = arm_of(&config, &arm, &[]);
    let bent = hold(&mut mj, 1.0, Some((1, 0.0)));
    assert!(bent[1] > 0.02 && bent[0] < 0.0, "{bent:?}");
}

#[test]
fn the_model_keeps_the_plants_clock_and_allocates_nothing_while_it_runs() {
    let (arm, config) = plant();
    let mut mj = arm_of(&config, &arm, &[]);
    hold(&mut mj, 0.01, None);
    let _counted = alloc::count_this_thread();
    let before = alloc::this_thread();
    let mut t = 0.01;
    for k in 0..400 {
        t += 0.005;
        hold(&mut mj, t, Some((k % 9, 0.3)));
    }
    let during = alloc::this_thread() - before;
    assert_eq!(during, 0, "{during} allocations or frees in 400 steps");
    // Whole 2 ms steps up to the plant's time: never ahead, less than a step behind.
    assert!(
        mj.time() <= t + 1e-9 && t - mj.time() < mj.timestep(),
        "{} {t}",
        mj.time()
    );
}

#[test]
fn a_tip_load_from_its_time_pulls_the_tip_and_a_longer_tool_moves_the_tracked_point() {
    let (arm, mut config) = plant();
    config.load = Some(TipLoad {
        from_s: 1.0,
        force_n: [0.25, 0.0, 0.0],
        mass_kg: 0.0,
    });
    let mut mj = arm_of(&config, &arm, &[]);
    let before = hold(&mut mj, 0.99, None);
    let after = hold(&mut mj, 3.0, None);
    // 0.25 N sideways on a thin rod: centimetres, not metres.
    let moved = after[0] - before[0];
    assert!((0.005..0.2).contains(&moved), "moved {moved} m");

    // A tool 20 mm longer from 1 s: the marker 20 mm further along the straight tip's axis.
    let (arm, config) = plant();
    let mut longer = arm.clone();
    let tool = |a: &ArmConfig| {
        toml::Value::try_from(a).unwrap()["tool_m"]
            .as_float()
            .unwrap()
    };
    let mut t: toml::Table = toml::Value::try_from(&longer).unwrap().try_into().unwrap();
    t.insert("tool_m".into(), (tool(&arm) + 0.02).into());
    longer = t.try_into().unwrap();
    let mut mj = arm_of(&config, &arm, &[(1.0, longer)]);
    let before = hold(&mut mj, 0.99, None);
    let after = hold(&mut mj, 1.5, None);
    assert!(
        (after[2] - before[2] - 0.02).abs() < 1e-4,
        "{before:?} {after:?}"
    );
}

#[test]
fn a_model_that_cannot_run_the_arm_is_refused_naming_the_key_and_what_would_do() {
    let (_, config) = plant();
    let mut c = config.clone();
    c.actuators[4].name = "seg_1_tendon_1".into();
    let e = refused(&c);
    assert!(
        e.starts_with("sim.mujoco.actuators[4].name:") && e.contains("seg_1_ten_1"),
        "{e}"
    );
    let mut c = config.clone();
    c.actuators.clear();
    c.tip_site = "tip".into();
    let e = refused(&c);
    assert!(
        e.starts_with("sim.mujoco.tip_site:") && e.contains("force_site_tip"),
        "{e}"
    );
    let mut c = config.clone();
    c.keyframe = Some("home".into());
    assert!(refused(&c).contains("no keyframe \"home\"; its keyframes: pretension"));
    let mut c = config.clone();
    c.model = Some("nothing-here.xml".into());
    let e = refused(&c);
    assert!(
        e.starts_with("sim.mujoco.model: cannot read") && e.contains("nothing-here.xml"),
        "{e}"
    );
    let mut c = config.clone();
    c.model = Some("README.md".into());
    let e = refused(&c);
    assert!(e.contains("MuJoCo does not load it"), "{e}");
}
