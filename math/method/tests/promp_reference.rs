//! Cross-check against `movement_primitives` 0.9.1 (see tests/data/README.md): basis values,
//! per-demo weights, μ_w, Σ_w, mean/variance trajectories and conditioning agree to 1e-9.

use nalgebra::DMatrix;
use serde_json::Value;
use softarm_method::promp::{Basis, Demonstration, Primitive, TrainConfig, ViaPoint};

const TOL: f64 = 1e-9;

fn reference() -> Value {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/promp_movement_primitives.json"
    );
    serde_json::from_str(&std::fs::read_to_string(path).expect("reference file")).unwrap()
}

fn vector(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn matrix(v: &Value) -> Vec<Vec<f64>> {
    v.as_array().unwrap().iter().map(vector).collect()
}

/// Relative agreement, with an absolute floor of `TOL` for values near zero.
fn assert_close(what: &str, got: &[f64], want: &[f64]) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let err = (g - w).abs() / w.abs().max(scale * 1e-3).max(1e-12);
        assert!(
            err <= TOL,
            "{what}[{i}]: got {g:e}, want {w:e} (rel {err:e})"
        );
    }
}

/// The demonstrations regenerated from their formula (README), checked against the stored ones.
fn demos(reference: &Value) -> Vec<Demonstration> {
    let stored = reference["demos"].as_array().unwrap();
    (0..10)
        .map(|i| {
            let fi = i as f64;
            let a = 1.0 + 0.1 * (1.3 * fi).sin();
            let o = 0.05 * (0.7 * fi).cos();
            let s = 0.05 * (2.1 * fi + 0.4).sin();
            let times: Vec<f64> = (0..=100).map(|k| k as f64 / 100.0).collect();
            let values = DMatrix::from_fn(101, 2, |r, c| {
                let t = times[r];
                if c == 0 {
                    a * (std::f64::consts::PI * (t + s)).sin() + o
                } else {
                    (0.5 + 0.1 * (1.7 * fi).cos()) * t * t - 0.2 * a * t + 0.3 + o
                }
            });
            let want = matrix(&stored[i]);
            for r in 0..101 {
                assert_close("demo", &[values[(r, 0)], values[(r, 1)]], &want[r]);
            }
            Demonstration::new(times, values)
        })
        .collect()
}

fn trajectory(m: &DMatrix<f64>) -> Vec<f64> {
    (0..m.nrows())
        .flat_map(|r| [m[(r, 0)], m[(r, 1)]])
        .collect()
}

#[test]
fn agrees_with_movement_primitives() {
    let r = reference();
    let phases = vector(&r["T"]);
    let basis = Basis::new(10, None).unwrap();

    let phi: Vec<f64> = phases
        .iter()
        .flat_map(|&z| basis.evaluate(z).data.as_vec().clone())
        .collect();
    assert_close("phi_1d", &phi, &matrix(&r["phi_1d"]).concat());

    let demos = demos(&r);
    for (i, (d, want)) in demos.iter().zip(matrix(&r["ls_weights"])).enumerate() {
        let w = Primitive::fit_weights(&basis, d, 1e-12).unwrap();
        assert_close(&format!("ls_weights[{i}]"), w.as_slice(), &want);
    }

    let config = TrainConfig {
        ridge: 1e-12,
        regularisation: 0.0,
    };
    let p = Primitive::train(basis, &demos, &config).unwrap();
    assert_close(
        "ls_mu_w",
        p.weight_mean().as_slice(),
        &vector(&r["ls_mu_w"]),
    );
    let sigma: Vec<f64> = (0..20)
        .flat_map(|row| (0..20).map(move |c| (row, c)))
        .map(|(row, c)| p.weight_cov()[(row, c)])
        .collect();
    assert_close("ls_sigma_w", &sigma, &matrix(&r["ls_sigma_w"]).concat());

    assert_close(
        "ls_mean_traj",
        &trajectory(&p.mean_trajectory(&phases)),
        &matrix(&r["ls_mean_traj"]).concat(),
    );
    assert_close(
        "ls_var_traj",
        &trajectory(&p.variance_trajectory(&phases)),
        &matrix(&r["ls_var_traj"]).concat(),
    );

    let mut c = p.clone();
    let t_star = r["ls_cond_t_star"].as_f64().unwrap();
    c.condition(&ViaPoint::exact(t_star, &vector(&r["ls_cond_y_star"])))
        .unwrap();
    assert_close(
        "ls_cond_mu_w",
        c.weight_mean().as_slice(),
        &vector(&r["ls_cond_mu_w"]),
    );
    assert_close(
        "ls_cond_mean_traj",
        &trajectory(&c.mean_trajectory(&phases)),
        &matrix(&r["ls_cond_mean_traj"]).concat(),
    );
    assert_close(
        "ls_cond_var_traj",
        &trajectory(&c.variance_trajectory(&phases)),
        &matrix(&r["ls_cond_var_traj"]).concat(),
    );

    // Conditioning on y* = the stored point reproduces it.
    let m = c.marginal(t_star);
    assert_close(
        "conditioned mean at t*",
        m.mean.as_slice(),
        &vector(&r["ls_cond_y_star"]),
    );
}
