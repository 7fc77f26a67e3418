//! A plant step allocates nothing, also on an arm a scenario changes. Proven with a counting
//! global allocator that counts only the threads that ask.

use softarm_test_alloc::{self as alloc, Counting};

#[global_allocator]
static GLOBAL: Counting = Counting;

/// The sim steps its plant at 200 Hz; a scenario's changes are evaluated every step, so the
/// step must not allocate either (fixed-size steps, no strings).
#[test]
fn a_plant_step_on_a_changing_arm_allocates_nothing() {
    use softarm_sections::arm::ArmConfig;
    use softarm_sections::changes::{Drift, Rates};
    use softarm_sections::sim::{Realism, SimConfig};
    use softarm_sim::plant::{Body, Plant};
    // The default [arm] (the paper's), its tool longer at each of 16 steps.
    let steps: Vec<(f64, ArmConfig)> = (1..=16)
        .map(|k| {
            let longer = ArmConfig {
                tool_m: Some(0.03 + 0.001 * k as f64),
                ..ArmConfig::default()
            };
            (k as f64 * 0.1, longer)
        })
        .collect();
    let drift = Drift {
        creep_mm_per_min: Rates::new(&[0.5, 0.0, 0.0, 0.0, 0.5, 0.0]).unwrap(),
        actuator_radius_amplitude_m: 0.002,
        actuator_radius_period_s: 1.0,
    };
    let sim = SimConfig {
        realism: Realism {
            curvature_taper: 0.5,
            ..Realism::default()
        },
        drift,
        ..SimConfig::default()
    };
    let body = Body::of_arm(&ArmConfig::default(), &steps).unwrap();
    let mut plant = Plant::of_sim(body, &sim, &[0.5; 6]).unwrap();

    let _counted = alloc::count_this_thread();
    let before = alloc::this_thread();
    let mut sink = 0.0;
    // Through every step and a few radius cycles.
    for k in 0..1000 {
        let a = 0.5 + 0.2 * (k as f64 * 0.01).sin();
        sink += plant.step(&[a; 6], 0.005).position[2];
    }
    let during = alloc::this_thread() - before;
    assert!(sink.is_finite());
    assert_eq!(plant.body().step_at(plant.time()), Some(15));
    assert_eq!(
        during, 0,
        "{during} allocations or frees in 1000 plant steps"
    );
}

/// Any arm's plant, too: the nine-tendon TDCR's, with every effect of the realism on, a
/// scenario's step taken and a drift (creep and radius cycle).
#[test]
fn a_plant_step_on_any_arm_allocates_nothing() {
    use softarm_sections::sim::Realism;
    use softarm_sim::plant::{Body, Plant};
    let text = include_str!("../../../contract/arm/testdata/tdcr.toml");
    let layout = softarm_arm::Layout::new(&toml::from_str(text).unwrap()).unwrap();
    let realism = Realism {
        curvature_taper: 0.3,
        drift_m: 0.0005,
        ..Realism::default()
    };
    // A scenario's step 2 s in: every tendon 0.2 mm longer.
    let start = softarm_kinematics::pcc::Arm::new(&layout, &[]);
    let crept = softarm_kinematics::pcc::Arm::new(&layout, &[0.0002; 9]);
    let body = Body::stepped(start, &[(2.0, crept)]).unwrap();
    let drift = softarm_sections::changes::Drift {
        creep_mm_per_min: softarm_sections::changes::Rates::new(&[0.1; 9]).unwrap(),
        actuator_radius_amplitude_m: 0.001,
        actuator_radius_period_s: 1.0,
    };
    let mut plant = Plant::of_body(body, realism, &[0.5; 9])
        .unwrap()
        .drifting(drift);

    let _counted = alloc::count_this_thread();
    let before = alloc::this_thread();
    let mut sink = 0.0;
    for k in 0..1000 {
        let a = 0.5 + 0.2 * (k as f64 * 0.01).sin();
        let m = plant.step(&[a; 9], 0.005);
        sink += m.position[2] + m.actuation[8];
    }
    let during = alloc::this_thread() - before;
    assert!(sink.is_finite() && sink > 0.0);
    assert_eq!(
        during, 0,
        "{during} allocations or frees in 1000 plant steps"
    );
}
