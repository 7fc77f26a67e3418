//! The MuJoCo plant's cost per sim period (5 ms of physics at the shipped 200 Hz, with the
//! sim's realism in front), for the lab's nine-tendon TDCR model and for models generated from
//! the shipped arms and a sixteen-tendon arm. Criterion's medians, then the percentiles of
//! single periods over a minute of simulated time (what the sim driver's `Pace` compares with
//! its period). `cargo bench -p softarm-mujoco --features physics --bench period`.

use std::hint::black_box;
use std::path::Path;
use std::time::Instant;

use criterion::{Criterion, criterion_group, criterion_main};
use softarm_mujoco::MujocoArm;
use softarm_sections::arm::ArmConfig;
use softarm_sections::mujoco::MujocoConfig;
use softarm_sections::sim::Realism;
use softarm_sim::plant::{Body, Plant};

const PERIOD_S: f64 = 0.005;

fn root() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
}

fn arm_of(file: &str) -> ArmConfig {
    let text = std::fs::read_to_string(root().join(file)).unwrap();
    toml::from_str(&text).unwrap()
}

/// Every plant measured: its name, its arm and its `[sim.mujoco]`.
fn plants() -> Vec<(String, ArmConfig, MujocoConfig, &'static Path)> {
    let folder = root().join("config/mujoco");
    let text = std::fs::read_to_string(folder.join("opencr-ftdcr-v6.toml")).unwrap();
    let mut table: toml::Table = toml::from_str(&text).unwrap();
    let lab_arm: ArmConfig = table.remove("arm").unwrap().try_into().unwrap();
    let lab: MujocoConfig = table.remove("mujoco").unwrap().try_into().unwrap();
    let lab_dir: &'static Path = Box::leak(folder.into_boxed_path());
    let mut all = vec![("lab TDCR (9)".to_string(), lab_arm, lab, lab_dir)];
    for (name, file) in [
        ("paper (6)", "config/arms/paper.toml"),
        ("tdcr (9)", "config/arms/tdcr.toml"),
        ("hybrid (8)", "config/arms/hybrid.toml"),
        ("sixteen (16)", "models/model/examples/sixteen-tendons.toml"),
    ] {
        all.push((
            format!("generated {name}"),
            arm_of(file),
            MujocoConfig::default(),
            root(),
        ));
    }
    all
}

fn plant(arm: &ArmConfig, mujoco: &MujocoConfig, dir: &Path) -> Plant {
    let n = arm.layout().unwrap().actuators().len();
    let physics = MujocoArm::new(mujoco, arm, arm, &[], dir).unwrap();
    let body = Body::of_arm(arm, &[]).unwrap();
    Plant::of_body(body, Realism::default(), &vec![0.5; n])
        .unwrap()
        .with_physics(Box::new(physics))
        .unwrap()
}

/// A command that keeps every actuator moving, as an execution does.
fn command(n: usize, k: usize, out: &mut [f64]) {
    for (i, a) in out[..n].iter_mut().enumerate() {
        *a = 0.5 + 0.3 * ((k as f64) * PERIOD_S * 1.3 + i as f64).sin();
    }
}

fn period(c: &mut Criterion) {
    for (name, arm, mujoco, dir) in plants() {
        let mut p = plant(&arm, &mujoco, dir);
        let n = p.actuators();
        let mut a = [0.5; 16];
        let mut k = 0;
        c.bench_function(&format!("period {name}"), |b| {
            b.iter(|| {
                k += 1;
                command(n, k, &mut a);
                black_box(p.step(&a[..n], PERIOD_S))
            })
        });
        // Single periods over a minute of the plant's clock.
        let mut p = plant(&arm, &mujoco, dir);
        p.step(&a[..n], PERIOD_S);
        let mut took: Vec<f64> = (0..12_000)
            .map(|k| {
                command(n, k, &mut a);
                let t = Instant::now();
                black_box(p.step(&a[..n], PERIOD_S));
                t.elapsed().as_secs_f64() * 1e6
            })
            .collect();
        took.sort_by(f64::total_cmp);
        let at = |q: f64| took[((took.len() - 1) as f64 * q) as usize];
        println!(
            "period {name}: p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs of a {:.0} µs period",
            at(0.5),
            at(0.99),
            took[took.len() - 1],
            PERIOD_S * 1e6
        );
    }
}

criterion_group!(benches, period);
criterion_main!(benches);
