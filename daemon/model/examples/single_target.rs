//! Diagnostic: CACLA-MTL on one target against the PCC model; prints the moving error.
use softarm_method::cacla::{Learner, LearnerConfig};
use softarm_method::pcc::ArmGeometry;
fn main() {
    let env = |k: &str| std::env::var(k).unwrap_or_default().replace(';', "\n");
    let config: LearnerConfig = toml::from_str(&env("LEARNER")).unwrap();
    let arm = ArmGeometry::default();
    let mut l = Learner::new(config).unwrap();
    let target = arm.position(&[0.3, 0.6, 0.7, 0.55, 0.4, 0.5]);
    let (mut sum, mut pos, mut n) = (0.0, 0, 0);
    for k in 0..20000 {
        let a = l.act(0, &target, true);
        let v = l.observe(0, &target, &a, &arm.position(&a));
        sum += v.error;
        n += 1;
        pos += v.actor_updated as u32;
        if (k + 1) % 2000 == 0 {
            let mean_err = {
                let m = l.actor(&target);
                let p = arm.position(&m);
                ((p[0] - target[0]).powi(2)
                    + (p[1] - target[1]).powi(2)
                    + (p[2] - target[2]).powi(2))
                .sqrt()
            };
            println!(
                "{:>6}: explored {:6.2} mm, actor mean {:6.2} mm, δ>0 {:4.1}%, V(t,t)={:.4}",
                k + 1,
                sum / n as f64 * 1e3,
                mean_err * 1e3,
                100.0 * pos as f64 / n as f64,
                l.value(&target, &target)
            );
            sum = 0.0;
            n = 0;
            pos = 0;
        }
    }
}
