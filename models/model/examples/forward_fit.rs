//! The forward models' fit, measured: the RBF network and the polynomial on the III-B
//! demonstrations from the default `[arm]`'s PCC model, their error on the training samples
//! and on whole demonstrations held out of the fit (every 5th), over the RBF network's
//! settings.
//!
//! `cargo run --release -p softarm-model --example forward_fit [-- SEED]`

use softarm_kinematics::forward::ForwardModel;
use softarm_kinematics::poly::Polynomial;
use softarm_kinematics::rbf::RbfNetwork;
use softarm_method::space::{Position, distance};
use softarm_model::pipeline::{TrainingData, forward_model};
use softarm_sections::arm::ArmConfig;
use softarm_sections::demonstrations::DemoRecipe;
use softarm_sections::forward_model::NetworkConfig;
use softarm_sections::kinematics::PolynomialConfig;

/// The default `[arm]`'s actuators.
const N: usize = 6;

/// Mean and max error (mm) of `model` on the samples `pick` keeps.
fn errors(
    model: &dyn ForwardModel<N>,
    a: &[[f64; N]],
    p: &[Position],
    pick: &[usize],
) -> (f64, f64) {
    let e: Vec<f64> = pick
        .iter()
        .map(|&i| distance(&model.position(&a[i]), &p[i]) * 1e3)
        .collect();
    (
        e.iter().sum::<f64>() / e.len() as f64,
        e.iter().copied().fold(0.0, f64::max),
    )
}

fn main() -> anyhow::Result<()> {
    let seed = std::env::args().nth(1).map_or(Ok(1), |s| s.parse())?;
    let data = TrainingData::<N>::from_plant(&ArmConfig::default(), &DemoRecipe::default(), seed)?;
    let (a, p, demo) = (&data.actuations, &data.positions, &data.demo);
    let held: Vec<usize> = (0..a.len()).filter(|&i| demo[i] % 5 == 0).collect();
    let kept: Vec<usize> = (0..a.len()).filter(|&i| demo[i] % 5 != 0).collect();
    let (fa, fp): (Vec<[f64; N]>, Vec<Position>) = kept.iter().map(|&i| (a[i], p[i])).unzip();
    println!(
        "{} samples, {} demonstrations; {} held out",
        a.len(),
        data.recordings.len(),
        held.len()
    );
    let poly =
        Polynomial::fit(&fa, &fp, &PolynomialConfig::default()).map_err(anyhow::Error::msg)?;
    let (tm, tx) = errors(&poly, a, p, &kept);
    let (hm, hx) = errors(&poly, a, p, &held);
    println!("polynomial (shipped): train {tm:.2} / {tx:.2} mm, held out {hm:.2} / {hx:.2} mm");
    for centres in [100, 200, 400] {
        for width_factor in [0.75, 1.5, 3.0] {
            for ridge in [1e-8, 1e-5, 1e-3, 1e-1] {
                let config = NetworkConfig {
                    centres,
                    width_factor,
                    ridge,
                    widths: 1,
                };
                let net = RbfNetwork::fit(&fa, &fp, &config)?;
                let (tm, tx) = errors(&net, a, p, &kept);
                let (hm, hx) = errors(&net, a, p, &held);
                println!(
                    "rbf {centres:>3} centres, width {width_factor:4.2}, ridge {ridge:7.0e}: train {tm:6.2} / {tx:7.2} mm, held out {hm:6.2} / {hx:7.2} mm"
                );
            }
        }
    }
    let (net, held, width) = forward_model(a, p, demo, &NetworkConfig::default())?;
    let (tm, tx) = errors(&net, a, p, &kept);
    println!(
        "rbf as shipped (width {width} chosen on other demonstrations): held out {:.2} / {:.2} mm, \
         refitted on all: train {tm:.2} / {tx:.2} mm",
        held.mean_m * 1e3,
        held.max_m * 1e3
    );
    Ok(())
}
