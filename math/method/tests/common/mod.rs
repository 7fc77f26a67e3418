//! Synthetic primitives shared by the blend tests and benches: M classes of smooth six-actuator
//! motions with demo-to-demo variation, so Σ_w is full of real structure.
#![allow(dead_code)]

use nalgebra::DMatrix;
use softarm_method::promp::{Basis, Demonstration, Primitive, TrainConfig};

pub const D: usize = 6;

/// `demos` demonstrations of class `class`, each with its own length and duration.
pub fn demonstrations(class: usize, demos: usize) -> Vec<Demonstration> {
    demonstrations_of(class, demos, D)
}

/// [`demonstrations`] of `dofs` actuators.
pub fn demonstrations_of(class: usize, demos: usize, dofs: usize) -> Vec<Demonstration> {
    (0..demos)
        .map(|i| {
            let fi = i as f64;
            let samples = 120 + 13 * (i % 5);
            let duration = 4.0 + 0.25 * (i % 3) as f64;
            let times: Vec<f64> = (0..samples)
                .map(|s| duration * s as f64 / (samples - 1) as f64)
                .collect();
            let values = DMatrix::from_fn(samples, dofs, |r, d| {
                let z = times[r] / duration;
                let c = class as f64;
                let df = d as f64;
                let centre = 0.5 + 0.25 * ((c + 1.0) * (df + 0.5)).sin();
                let amp = 0.2 + 0.02 * (1.3 * fi + df).sin();
                let shift = 0.3 * (0.7 * fi + 0.4 * df + c).sin();
                (centre
                    + amp * (std::f64::consts::PI * (z + shift) + df).sin()
                    + 0.03 * (5.0 * z + fi).cos())
                .clamp(0.0, 1.0)
            });
            Demonstration::new(times, values)
        })
        .collect()
}

/// M actuation-space primitives with K basis functions, trained on 20 demos each.
pub fn primitives(m: usize, k: usize) -> Vec<Primitive> {
    primitives_of(m, k, D)
}

/// [`primitives`] of `dofs` actuators.
pub fn primitives_of(m: usize, k: usize, dofs: usize) -> Vec<Primitive> {
    (0..m)
        .map(|class| {
            Primitive::train(
                Basis::new(k, None).unwrap(),
                &demonstrations_of(class, 20, dofs),
                &TrainConfig::default(),
            )
            .unwrap()
        })
        .collect()
}
