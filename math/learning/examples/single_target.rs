//! Diagnostic: CACLA-MTL on one target against the default `[arm]`'s PCC model; prints the
//! moving error.
//!
//! `LEARNER="alpha_actor = 0.3; sigma_max = 0.02" cargo run --release -p softarm-learning \
//!  --example single_target` overrides `[learner]` keys (`;` separates them).

use std::process::ExitCode;

use softarm_kinematics::forward::ForwardModel;
use softarm_kinematics::pcc;
use softarm_learning::cacla::CaclaMtl;
use softarm_sections::arm::ArmConfig;
use softarm_sections::learner::LearnerConfig;
use softarm_space::distance;

/// The default `[arm]`'s actuators.
const N: usize = 6;

fn main() -> ExitCode {
    let overrides = std::env::var("LEARNER")
        .unwrap_or_default()
        .replace(';', "\n");
    let config: LearnerConfig = match toml::from_str(&overrides) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("LEARNER: not [learner] keys: {e}");
            return ExitCode::from(2);
        }
    };
    let mut l = match CaclaMtl::<N>::new(config) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("LEARNER: {e}");
            return ExitCode::from(2);
        }
    };
    let arm = pcc::Arm::of_config(&ArmConfig::default()).expect("the default [arm]");
    let target = arm.position(&[0.3, 0.6, 0.7, 0.55, 0.4, 0.5]);
    let (mut sum, mut improved, mut n) = (0.0, 0, 0);
    let mut memory = None;
    for k in 0..20000 {
        let a = l.act(memory.as_ref(), &target, true);
        let v = l.observe(&mut memory, &target, &a, &arm.position(&a));
        sum += v.error;
        n += 1;
        improved += v.actor_updated as u32;
        if (k + 1) % 2000 == 0 {
            let mean_error = distance(&target, &arm.position(&l.actor(&target)));
            println!(
                "{:>6}: explored {:6.2} mm, actor mean {:6.2} mm, δ>0 {:4.1}%, V(t,t)={:.4}",
                k + 1,
                sum / n as f64 * 1e3,
                mean_error * 1e3,
                100.0 * improved as f64 / n as f64,
                l.value(&target, &target)
            );
            (sum, n, improved) = (0.0, 0, 0);
        }
    }
    ExitCode::SUCCESS
}
