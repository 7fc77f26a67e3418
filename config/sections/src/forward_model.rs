//! `[forward_model]`: how the RBF forward-model network is fitted (the fit itself is
//! `softarm_kinematics::rbf`).

use serde::{Deserialize, Serialize};

use crate::bounds::Lower::{Closed, Open};
use crate::bounds::{count, within};

/// How the forward model is fitted.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct NetworkConfig {
    /// Gaussian centres, picked from the data by farthest-point sampling.
    pub centres: usize,
    /// Gaussian standard deviation as a multiple of the mean nearest-centre distance: the
    /// narrowest tried.
    pub width_factor: f64,
    /// Ridge λ of the output weights.
    pub ridge: f64,
    /// How many widths training tries: `width_factor` × 1, 2, 4, …; the one least wrong on
    /// demonstrations held out of its fit is kept (1: `width_factor` alone).
    pub widths: usize,
}

impl Default for NetworkConfig {
    fn default() -> Self {
        Self {
            centres: 400,
            width_factor: 1.5,
            ridge: 1e-8,
            widths: 2,
        }
    }
}

impl NetworkConfig {
    /// Checks every field; the error is `forward_model.KEY: message`.
    pub fn validate(&self) -> Result<(), String> {
        count("forward_model.centres", self.centres, 1, 2000)?;
        within(
            "forward_model.width_factor",
            self.width_factor,
            Open(0.0),
            100.0,
            "",
        )?;
        within("forward_model.ridge", self.ridge, Closed(0.0), 1.0, "")?;
        count("forward_model.widths", self.widths, 1, 4)
    }
}
