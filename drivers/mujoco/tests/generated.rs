//! The MuJoCo model generated from `[arm]` (`softarm_mujoco::generate::mjcf`) on the shipped
//! arms: it loads, its actuators are the arm's, and driven to lengths it settles where
//! softarm's PCC kinematics puts the end effector, sagging plausibly under gravity.
#![cfg(feature = "physics")]

use std::sync::Arc;

use mujoco_rs::prelude::*;
use softarm_arm::Layout;
use softarm_kinematics::arcs::Routes;
use softarm_kinematics::pcc::Arm;
use softarm_mujoco::generate::mjcf;
use softarm_sections::arm::ArmConfig;
use softarm_sections::mujoco::Generated;

/// The shipped arms, by name.
const ARMS: [(&str, &str); 4] = [
    ("paper", include_str!("../../../config/arms/paper.toml")),
    ("tdcr", include_str!("../../../config/arms/tdcr.toml")),
    ("hybrid", include_str!("../../../config/arms/hybrid.toml")),
    (
        "opencr",
        include_str!("../../../config/recordings/opencr-tdcr/arm.toml"),
    ),
];

const NO_GRAVITY: [f64; 3] = [0.0; 3];
const GRAVITY: [f64; 3] = [0.0, 0.0, -9.81];

/// How long a pose is held before the tip is read (s).
const SETTLE_S: f64 = 2.0;

fn layout(text: &str) -> Layout {
    toml::from_str::<ArmConfig>(text).unwrap().layout().unwrap()
}

fn model(layout: &Layout, generated: &Generated, gravity: [f64; 3]) -> MjModel {
    let xml = mjcf(layout, generated, gravity);
    MjModel::from_xml_string(&xml).unwrap_or_else(|e| panic!("{e}\n{xml}"))
}

/// A small seeded generator (xorshift64*): the same random poses on every machine.
struct Seeded(u64);

impl Seeded {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The poses each arm is driven to (normalised actuations): all at 0.5, each actuator alone at
/// 0.2 and at 0.8 (the others at 0.5), two random ones.
/// The random ones are made reachable: PCC's lengths of the arcs it fits to them. Lengths drawn
/// each on its own over-determine a module with more actuators than its shape has freedoms (a
/// fixed backbone, a chamber beside tendons); the least-squares residual PCC leaves is mm that
/// an actuator holding its length would hold against the others with forces past any range.
fn poses(layout: &Layout) -> Vec<(String, Vec<f64>)> {
    let n = layout.actuators().len();
    let mut all = vec![("all 0.5".to_string(), vec![0.5; n])];
    for i in 0..n {
        for a in [0.2, 0.8] {
            let mut p = vec![0.5; n];
            p[i] = a;
            all.push((format!("{} at {a}", i + 1), p));
        }
    }
    let mut rng = Seeded(0x005e_ed0f_a4a1);
    for k in 0..2 {
        let drawn: Vec<f64> = layout
            .actuators()
            .iter()
            .map(|a| a.length_of(rng.next()))
            .collect();
        let routes = Routes::of(layout);
        let arcs = routes.arcs(&drawn).unwrap();
        let mut reachable = vec![0.0; n];
        routes.lengths(&arcs, &mut reachable);
        let a = layout
            .actuators()
            .iter()
            .zip(&reachable)
            .map(|(a, &l)| a.actuation_of(l));
        all.push((format!("random {}", k + 1), a.collect()));
    }
    all
}

/// Where the model's tip settles at `lengths` (m) after [`SETTLE_S`] from rest, and how fast it
/// still moves then (m/s).
fn settle(model: &Arc<MjModel>, lengths: &[f64]) -> ([f64; 3], f64) {
    let tip = model
        .name_to_id(MjtObjBase::mjOBJ_SITE, "tip")
        .expect("a tip site");
    let mut data = MjData::new(model.clone());
    data.ctrl_mut()[..lengths.len()].copy_from_slice(lengths);
    let dt = model.opt().timestep;
    let steps = (SETTLE_S / dt).round() as usize;
    // The speed over the last 50 ms: a slow drift or a small ringing both show.
    let window = (0.05 / dt).round() as usize;
    let mut before = [0.0; 3];
    for s in 0..steps {
        if s == steps - window {
            before = data.site_xpos()[tip];
        }
        data.step();
    }
    let now = data.site_xpos()[tip];
    (now, distance(now, before) / (window as f64 * dt))
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

/// Per pose of `arm`: its name, PCC's end effector, the model's settled tip and its speed.
struct Settled {
    pose: String,
    pcc: [f64; 3],
    tip: [f64; 3],
    speed: f64,
}

fn settled(
    layout: &Layout,
    generated: &Generated,
    gravity: [f64; 3],
    poses: &[(String, Vec<f64>)],
) -> Vec<Settled> {
    let model = Arc::new(model(layout, generated, gravity));
    let pcc = Arm::new(layout, &[]);
    poses
        .iter()
        .map(|(pose, a)| {
            let lengths: Vec<f64> = layout
                .actuators()
                .iter()
                .zip(a)
                .map(|(act, &x)| act.length_of(x))
                .collect();
            let p = pcc.pose_of_lengths(&lengths, 0.0).unwrap().position;
            let (tip, speed) = settle(&model, &lengths);
            Settled {
                pose: pose.clone(),
                pcc: [p.x, p.y, p.z],
                tip,
                speed,
            }
        })
        .collect()
}

#[test]
fn every_shipped_arm_loads_with_the_arms_actuators_in_order_and_a_tip() {
    for (name, text) in ARMS {
        let layout = layout(text);
        let model = model(&layout, &Generated::default(), GRAVITY);
        let nu = model.ffi().nu as usize;
        assert_eq!(nu, layout.actuators().len(), "{name}");
        for (i, want) in layout.names().enumerate() {
            assert_eq!(
                model.id_to_name(MjtObjBase::mjOBJ_ACTUATOR, i),
                Some(want),
                "{name}"
            );
        }
        assert!(
            model.name_to_id(MjtObjBase::mjOBJ_SITE, "tip").is_some(),
            "{name}"
        );
        assert_eq!(model.opt().gravity, GRAVITY, "{name}");
    }
}

/// The most the settled tip may be from PCC's end effector without gravity (m), per arm: the
/// figures measured (worst over the poses) with a margin.
fn pcc_bound_m(arm: &str) -> f64 {
    match arm {
        "paper" => 0.007,
        "tdcr" => 0.012,
        "hybrid" => 0.010,
        "opencr" => 0.030,
        _ => unreachable!("a shipped arm"),
    }
}

#[test]
fn without_gravity_the_tip_settles_where_pcc_puts_it() {
    for (name, text) in ARMS {
        let layout = layout(text);
        let all = settled(&layout, &Generated::default(), NO_GRAVITY, &poses(&layout));
        let errors: Vec<f64> = all.iter().map(|s| distance(s.tip, s.pcc)).collect();
        let worst = errors.iter().copied().fold(0.0, f64::max);
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        for (s, e) in all.iter().zip(&errors) {
            eprintln!(
                "{name:7} {:12} pcc {:7.1} {:7.1} {:7.1} mm  off {:6.2} mm  speed {:.3} mm/s",
                s.pose,
                s.pcc[0] * 1e3,
                s.pcc[1] * 1e3,
                s.pcc[2] * 1e3,
                e * 1e3,
                s.speed * 1e3
            );
        }
        eprintln!(
            "{name}: to PCC worst {:.2} mm, mean {:.2} mm",
            worst * 1e3,
            mean * 1e3
        );
        for (s, e) in all.iter().zip(&errors) {
            assert!(
                s.speed < 1e-3,
                "{name} {}: still moving at {} m/s",
                s.pose,
                s.speed
            );
            assert!(*e < pcc_bound_m(name), "{name} {}: {e} m from PCC", s.pose);
        }
    }
}

/// Under gravity (9.81 m/s² down the world's z) the tip sags from where it settles without:
/// by mm, as a light arm held by its tendons sags, not by nothing nor by its length.
#[test]
fn with_gravity_the_tip_sags_by_millimetres() {
    for (name, text) in ARMS {
        let layout = layout(text);
        let all = poses(&layout);
        // Straight, bent by its first actuator, and a random pose.
        let some: Vec<_> = [0, 1, all.len() - 1].map(|k| all[k].clone()).into();
        // A TDCR weighs grams (the defaults' backbone module: 3 g), a soft module tens.
        let g = Generated::default();
        let backbone = layout.modules().iter().any(|m| m.backbone_m.is_some());
        let off = settled(&layout, &g, NO_GRAVITY, &some);
        let on = settled(&layout, &g, GRAVITY, &some);
        for (a, b) in off.iter().zip(&on) {
            let sag = distance(a.tip, b.tip);
            eprintln!(
                "{name:7} {:12} sag {:6.2} mm, speed {:.3} mm/s",
                a.pose,
                sag * 1e3,
                b.speed * 1e3
            );
            let bent = distance(a.pcc, [0.0, 0.0, a.pcc[2]]) > 0.01;
            if backbone {
                // A standing TDCR held 4.5 mm off its axis sags most, and the OpenCR arm's is
                // still creeping after 2 s (measured: 33 mm at 7 mm/s bent); bounded, not still.
                assert!(sag < 0.06, "{name} {}: sags {sag} m", a.pose);
            } else {
                assert!(
                    b.speed < 1e-3,
                    "{name} {}: moving at {} m/s",
                    a.pose,
                    b.speed
                );
                assert!(sag < 0.02, "{name} {}: sags {sag} m", a.pose);
                if bent {
                    assert!(sag > 0.002, "{name} {}: sags only {sag} m", a.pose);
                }
            }
        }
    }
}

/// Arms unlike the shipped ones load and step: tendons, chambers off the axis and on it, a
/// fixed backbone, coupled routing across connectors, no tool and no tool mass; five modules
/// (the most 16 actuators allow) hanging.
#[test]
fn other_arms_load_and_step() {
    let mixed = r#"
        routing = "coupled"
        mount = "standing"
        connector_m = 0.02
        [[modules]]
        tendons = { count = 4, radius_m = 0.02, length_m = [0.1, 0.14] }
        [[modules]]
        backbone_m = 0.1
        rotation_deg = 45
        tendons = { count = 3, radius_m = 0.01, length_m = [0.2, 0.26] }
        [[modules]]
        chambers = { count = 3, radius_m = 0.015, length_m = [0.1, 0.14] }
        [[modules]]
        chambers = { count = 1, length_m = [0.1, 0.14] }
        tendons = { count = 3, radius_m = 0.02, angles_deg = [10, 130, 250], length_m = [0.5, 0.6] }
    "#;
    let five = r#"
        connector_m = 0.01
        tool_m = 0.05
        [[modules]]
        tendons = { count = 3, radius_m = 0.02, length_m = [0.1, 0.12] }
        [[modules]]
        tendons = { count = 3, radius_m = 0.02, length_m = [0.1, 0.12] }
        [[modules]]
        tendons = { count = 3, radius_m = 0.02, length_m = [0.1, 0.12] }
        [[modules]]
        tendons = { count = 3, radius_m = 0.02, length_m = [0.1, 0.12] }
        [[modules]]
        tendons = { count = 3, radius_m = 0.02, length_m = [0.1, 0.12], names = ["a", "b", "c"] }
    "#;
    for text in [mixed, five] {
        let layout = layout(text);
        let generated = Generated {
            tool_mass_kg: 0.0,
            links_per_module: 4,
            ..Generated::default()
        };
        let model = MjModel::from_xml_string(&mjcf(&layout, &generated, GRAVITY)).unwrap();
        assert_eq!(model.ffi().nu as usize, layout.actuators().len());
        let mut data = MjData::new(Arc::new(model));
        let lengths: Vec<f64> = layout
            .actuators()
            .iter()
            .map(|a| a.length_of(0.3))
            .collect();
        data.ctrl_mut()[..lengths.len()].copy_from_slice(&lengths);
        for _ in 0..500 {
            data.step();
        }
        assert!(data.site_xpos().iter().flatten().all(|x| x.is_finite()));
    }
}

/// Wall time per step of the nine-tendon arm's model (the OpenCR TDCR): a timing, so it only
/// reports (`cargo test --release -p softarm-mujoco --features physics -- --ignored
/// --nocapture`); the sim runs the model lock-stepped at 2 ms, so it must be well under that.
#[test]
#[ignore = "a timing: run it on its own, in release"]
fn stepping_the_nine_tendon_arm() {
    let layout = layout(ARMS[3].1);
    let model = Arc::new(model(&layout, &Generated::default(), GRAVITY));
    let mut data = MjData::new(model.clone());
    let lengths: Vec<f64> = layout
        .actuators()
        .iter()
        .map(|a| a.length_of(0.3))
        .collect();
    data.ctrl_mut()[..lengths.len()].copy_from_slice(&lengths);
    let steps = (1.0 / model.opt().timestep).round() as u32;
    let start = std::time::Instant::now();
    for _ in 0..steps {
        data.step();
    }
    let per_step = start.elapsed() / steps;
    eprintln!("opencr: {steps} steps of 2 ms, {per_step:?} wall time per step");
}
