//! What the physical model still misses, learnt: Gaussian-kernel ridge regression of the tip's
//! miss on the actuators' pulls (each scaled by its stroke).
//!
//! Why this kind: a kernel's correction fades to nothing away from the poses it was fitted on,
//! so on motions beyond the recording the physical model speaks alone, where a polynomial
//! residual would extrapolate. Its width and ridge, or none at all, are chosen by the same
//! cross-validation over held-out motions as the physical model's prior. Pure math.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// A fitted residual: correction(x) = Σ_j w_j exp(−|x − c_j|² / 2ℓ²), x the scaled pulls.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Residual {
    /// ℓ, in strokes.
    pub width: f64,
    /// The ridge added to the kernel's diagonal (its diagonal is 1).
    pub ridge: f64,
    /// Each actuator's scale (m): its stroke.
    pub scale_m: Vec<f64>,
    /// The centres (scaled pulls), one per row fitted.
    pub centers: Vec<Vec<f64>>,
    /// The weights (m), x y z per centre.
    pub weights: Vec<[f64; 3]>,
}

/// Most centres a residual has: a longer recording is fitted on every k-th row, so that a
/// fit stays a linear solve of at most this size (its cost grows with the cube).
pub const MAX_CENTERS: usize = 1500;

/// The widths (in strokes) and ridges cross-validation chooses from.
pub const WIDTHS: [f64; 4] = [0.05, 0.1, 0.2, 0.4];
pub const RIDGES: [f64; 3] = [0.1, 1.0, 10.0];

fn scaled(pull_m: &[f64], scale_m: &[f64]) -> Vec<f64> {
    pull_m.iter().zip(scale_m).map(|(p, s)| p / s).collect()
}

fn kernel(a: &[f64], b: &[f64], width: f64) -> f64 {
    let d2: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    (-d2 / (2.0 * width * width)).exp()
}

impl Residual {
    /// Fits the misses `miss_m` (measured − physical, m) at pulls `pull_m`; `None` if the
    /// kernel system cannot be solved.
    pub fn fit(
        pull_m: &[&[f64]],
        miss_m: &[[f64; 3]],
        scale_m: &[f64],
        width: f64,
        ridge: f64,
    ) -> Option<Self> {
        let stride = pull_m.len().div_ceil(MAX_CENTERS).max(1);
        let kept: Vec<usize> = (0..pull_m.len()).step_by(stride).collect();
        let centers: Vec<Vec<f64>> = (kept.iter()).map(|j| scaled(pull_m[*j], scale_m)).collect();
        let miss_m: Vec<[f64; 3]> = kept.iter().map(|j| miss_m[*j]).collect();
        let n = centers.len();
        let mut k = DMatrix::from_fn(n, n, |i, j| kernel(&centers[i], &centers[j], width));
        for i in 0..n {
            k[(i, i)] += ridge;
        }
        let chol = k.cholesky()?;
        let mut weights = vec![[0.0; 3]; n];
        for axis in 0..3 {
            let y = DVector::from_fn(n, |i, _| miss_m[i][axis]);
            let w = chol.solve(&y);
            for i in 0..n {
                weights[i][axis] = w[i];
            }
        }
        Some(Self {
            width,
            ridge,
            scale_m: scale_m.to_vec(),
            centers,
            weights,
        })
    }

    /// The correction (m) at pulls `pull_m`.
    pub fn correction(&self, pull_m: &[f64]) -> [f64; 3] {
        let x = scaled(pull_m, &self.scale_m);
        let mut out = [0.0; 3];
        for (c, w) in self.centers.iter().zip(&self.weights) {
            let k = kernel(&x, c, self.width);
            for axis in 0..3 {
                out[axis] += k * w[axis];
            }
        }
        out
    }

    /// Whether it is usable: every number finite, the shapes agreeing.
    pub fn is_valid(&self, actuators: usize) -> bool {
        self.width > 0.0
            && self.ridge > 0.0
            && self.scale_m.len() == actuators
            && self.scale_m.iter().all(|s| s.is_finite() && *s > 0.0)
            && self.centers.len() == self.weights.len()
            && (self.centers.iter())
                .all(|c| c.len() == actuators && c.iter().all(|v| v.is_finite()))
            && (self.weights.iter()).all(|w| w.iter().all(|v| v.is_finite()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn it_learns_a_smooth_miss_and_fades_away_from_its_data() {
        let pulls: Vec<Vec<f64>> = (0..40).map(|k| vec![k as f64 * 0.0005, 0.0]).collect();
        let miss: Vec<[f64; 3]> = (pulls.iter())
            .map(|p| [0.002 * (p[0] * 200.0).sin(), 0.0, 0.001])
            .collect();
        let refs: Vec<&[f64]> = pulls.iter().map(|p| p.as_slice()).collect();
        let r = Residual::fit(&refs, &miss, &[0.02, 0.02], 0.1, 0.01).unwrap();
        let at = r.correction(&[0.0101, 0.0]);
        assert!((at[0] - 0.002 * (2.02f64).sin()).abs() < 2e-4, "{at:?}");
        assert!((at[2] - 0.001).abs() < 1e-4, "{at:?}");
        // Far from every pull it was fitted on: nothing.
        let far = r.correction(&[0.0, 0.02]);
        assert!(far.iter().all(|v| v.abs() < 1e-6), "{far:?}");
        assert!(r.is_valid(2) && !r.is_valid(3));
        // A long recording: at most MAX_CENTERS of its rows, spread over all of it.
        let pulls: Vec<Vec<f64>> = (0..4000).map(|k| vec![k as f64 * 5e-6, 0.0]).collect();
        let refs: Vec<&[f64]> = pulls.iter().map(|p| p.as_slice()).collect();
        let miss = vec![[0.001, 0.0, 0.0]; 4000];
        let r = Residual::fit(&refs, &miss, &[0.02, 0.02], 0.1, 0.01).unwrap();
        assert!(r.centers.len() <= MAX_CENTERS && r.centers.len() > MAX_CENTERS / 2);
        assert!(r.centers.last().unwrap()[0] > 0.9 * 4000.0 * 5e-6 / 0.02);
    }
}
