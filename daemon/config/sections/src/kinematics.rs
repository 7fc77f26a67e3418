//! `[kinematics]`: how the polynomial kinematics are fitted (the fit itself is
//! `softarm_kinematics::poly`).

use serde::{Deserialize, Serialize};

/// The highest degree offered: 462 terms at degree 5 is already more than D_fwd supports well.
pub const MAX_DEGREE: usize = 5;

/// How the polynomial is fitted; part of `[forward_model]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PolynomialConfig {
    /// The highest total degree tried; training keeps the degree least wrong on held-out demonstrations.
    pub degree: usize,
    /// Ridge λ of the fit.
    pub ridge: f64,
}

impl Default for PolynomialConfig {
    fn default() -> Self {
        Self {
            degree: 4,
            ridge: 1e-8,
        }
    }
}
