//! `[kinematics]`: how the polynomial kinematics are fitted (the fit itself is
//! `softarm_kinematics::poly`).

use serde::{Deserialize, Serialize};

use crate::bounds::Lower::Closed;
use crate::bounds::{count, within};

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

impl PolynomialConfig {
    /// Checks every field; the error is `kinematics.KEY: message`.
    pub fn validate(&self) -> Result<(), String> {
        count("kinematics.degree", self.degree, 1, MAX_DEGREE)?;
        within("kinematics.ridge", self.ridge, Closed(0.0), 1.0, "")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_degree_and_the_ridge_are_bounded_and_named() {
        PolynomialConfig::default().validate().unwrap();
        let degree = PolynomialConfig {
            degree: MAX_DEGREE + 1,
            ..Default::default()
        };
        assert_eq!(
            degree.validate().unwrap_err(),
            "kinematics.degree: must be 1 to 5, got 6"
        );
        let ridge = PolynomialConfig {
            ridge: f64::NAN,
            ..Default::default()
        };
        assert_eq!(
            ridge.validate().unwrap_err(),
            "kinematics.ridge: must be in [0, 1], got NaN"
        );
    }
}
