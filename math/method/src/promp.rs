//! Probabilistic movement primitives (Paraschos et al., NIPS 2013): a Gaussian distribution over
//! the weights of normalised Gaussian basis functions, trained from demonstrations and
//! conditioned on via-points. Pure math: no I/O.
//!
//! Conventions (those of `movement_primitives` 0.9.1, which the tests cross-check):
//! phase z = t / T on [0, 1]; K centres `linspace(0, 1, K)`; basis variance
//! h = −1 / (8 K² ln 0.7) unless configured; weights DoF-major `[dof0 w0..wK-1, dof1 ...]`.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use softarm_kinematics::linalg::solve_spd;

/// What can go wrong building, training or conditioning a primitive.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PrimitiveError {
    #[error("a basis needs at least 2 functions per DoF, got K = {0}")]
    TooFewBasisFunctions(usize),
    #[error("a basis has at most {MAX_BASIS_FUNCTIONS} functions per DoF, got K = {0}")]
    TooManyBasisFunctions(usize),
    #[error("basis width (variance) must be finite and > 0, got {0}")]
    BadWidth(f64),
    #[error("no demonstrations to train from")]
    NoDemonstrations,
    #[error("demonstration {demo}: {why}")]
    BadDemonstration { demo: usize, why: String },
    #[error("{what} must be finite (got {value} at index {index})")]
    NonFinite {
        what: &'static str,
        index: usize,
        value: f64,
    },
    #[error("phase z = {0} is outside [0, 1]")]
    PhaseOutOfRange(f64),
    #[error("{what} has {got} values, the primitive has {expected} DoF")]
    DimensionMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{0} must be >= 0")]
    Negative(&'static str),
    #[error(
        "conditioning is degenerate: the predicted covariance plus the via-point noise is singular \
         (a DoF with zero variance conditioned with zero noise)"
    )]
    Singular,
}

/// Most basis functions per DoF: a model file cannot make [`Basis::new`] allocate without bound.
pub const MAX_BASIS_FUNCTIONS: usize = 1000;

/// K normalised Gaussian basis functions over the phase, shared by every DoF.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Basis {
    centres: Vec<f64>,
    /// Variance h of each unnormalised Gaussian exp(−(z − c)² / (2h)).
    width: f64,
}

impl Basis {
    /// K functions with centres evenly on [0, 1] (both ends included) and the given variance,
    /// or the `movement_primitives` default when `width` is `None`.
    pub fn new(k: usize, width: Option<f64>) -> Result<Self, PrimitiveError> {
        if k < 2 {
            return Err(PrimitiveError::TooFewBasisFunctions(k));
        }
        if k > MAX_BASIS_FUNCTIONS {
            return Err(PrimitiveError::TooManyBasisFunctions(k));
        }
        let width = width.unwrap_or_else(|| Self::default_width(k));
        if !(width.is_finite() && width > 0.0) {
            return Err(PrimitiveError::BadWidth(width));
        }
        let centres = (0..k).map(|i| i as f64 / (k - 1) as f64).collect();
        Ok(Self { centres, width })
    }

    /// h = −1 / (8 K² ln 0.7), the width `movement_primitives` uses: two neighbouring
    /// Gaussians (1/K apart; the centres are 1/(K − 1)) cross at 0.7 of their peak.
    pub fn default_width(k: usize) -> f64 {
        -1.0 / (8.0 * (k * k) as f64 * 0.7f64.ln())
    }

    pub fn len(&self) -> usize {
        self.centres.len()
    }

    pub fn is_empty(&self) -> bool {
        self.centres.is_empty()
    }

    pub fn width(&self) -> f64 {
        self.width
    }

    /// Normalised basis values at phase z, written into `out` (length K). Allocates nothing.
    /// Where every Gaussian underflows (a very narrow width between centres) the nearest centre
    /// takes it all, rather than 0/0.
    pub fn evaluate_into(&self, z: f64, out: &mut [f64]) {
        debug_assert_eq!(out.len(), self.len());
        let mut sum = 0.0;
        for (o, c) in out.iter_mut().zip(&self.centres) {
            let d = z - c;
            *o = (-d * d / (2.0 * self.width)).exp();
            sum += *o;
        }
        let k = self.centres.len();
        if sum == 0.0 && z.is_finite() && k > 0 {
            let nearest = ((z.clamp(0.0, 1.0) * (k - 1) as f64).round() as usize).min(k - 1);
            for (i, o) in out.iter_mut().enumerate() {
                *o = if i == nearest { 1.0 } else { 0.0 };
            }
            return;
        }
        for o in out.iter_mut() {
            *o /= sum;
        }
    }

    pub fn evaluate(&self, z: f64) -> DVector<f64> {
        let mut v = DVector::zeros(self.len());
        self.evaluate_into(z, v.as_mut_slice());
        v
    }
}

/// One demonstration: samples of D DoF at increasing times. Its phase runs from its first to
/// its last sample, so demonstrations of different lengths and durations train one primitive.
#[derive(Debug, Clone, PartialEq)]
pub struct Demonstration {
    pub times: Vec<f64>,
    /// One row per sample, one column per DoF.
    pub values: DMatrix<f64>,
}

impl Demonstration {
    pub fn new(times: Vec<f64>, values: DMatrix<f64>) -> Self {
        Self { times, values }
    }

    fn validate(&self, demo: usize, dofs: Option<usize>) -> Result<(), PrimitiveError> {
        let bad = |why: String| PrimitiveError::BadDemonstration { demo, why };
        if self.times.len() != self.values.nrows() {
            return Err(bad(format!(
                "{} times but {} samples",
                self.times.len(),
                self.values.nrows()
            )));
        }
        if self.times.len() < 2 {
            return Err(bad("needs at least 2 samples".into()));
        }
        if let Some(d) = dofs
            && self.values.ncols() != d
        {
            return Err(bad(format!(
                "has {} DoF, the first demonstration has {d}",
                self.values.ncols()
            )));
        }
        if let Some(i) = self.times.iter().position(|t| !t.is_finite()) {
            return Err(bad(format!("time {i} is not finite")));
        }
        if let Some(i) = self.values.iter().position(|v| !v.is_finite()) {
            return Err(bad(format!(
                "value at sample {}, DoF {} is not finite",
                i % self.values.nrows(),
                i / self.values.nrows()
            )));
        }
        if let Some(i) = self.times.windows(2).position(|w| w[1] <= w[0]) {
            return Err(bad(format!(
                "times must increase strictly (sample {} at {} s follows {} s)",
                i + 1,
                self.times[i + 1],
                self.times[i]
            )));
        }
        Ok(())
    }

    /// Phase of each sample: (t − t_first) / (t_last − t_first).
    fn phases(&self) -> impl Iterator<Item = f64> + '_ {
        let t0 = self.times[0];
        let span = self.times[self.times.len() - 1] - t0;
        self.times.iter().map(move |t| (t - t0) / span)
    }
}

/// How weights are fitted from demonstrations.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// λ of the per-demo ridge least squares.
    pub ridge: f64,
    /// Added to the diagonal of Σ_w: with fewer demos than weights Σ_w is singular.
    pub regularisation: f64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            ridge: 1e-12,
            regularisation: 1e-6,
        }
    }
}

/// Mean and covariance of the D DoF at one phase.
#[derive(Debug, Clone, PartialEq)]
pub struct Marginal {
    pub mean: DVector<f64>,
    pub cov: DMatrix<f64>,
}

/// A via-point: the trajectory passes through `value` at phase `phase` with covariance `noise`.
#[derive(Debug, Clone, PartialEq)]
pub struct ViaPoint {
    pub phase: f64,
    pub value: DVector<f64>,
    /// Σ_y*; zero means "exactly through".
    pub noise: DMatrix<f64>,
}

impl ViaPoint {
    /// A via-point to pass exactly through (Σ_y* = 0).
    pub fn exact(phase: f64, value: &[f64]) -> Self {
        Self {
            phase,
            value: DVector::from_column_slice(value),
            noise: DMatrix::zeros(value.len(), value.len()),
        }
    }
}

/// A ProMP: N(μ_w, Σ_w) over DoF-major basis weights.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Primitive {
    basis: Basis,
    dofs: usize,
    mean: DVector<f64>,
    cov: DMatrix<f64>,
}

impl Primitive {
    /// A primitive from an explicit weight distribution (e.g. loaded from a model bundle).
    pub fn from_weights(
        basis: Basis,
        dofs: usize,
        mean: DVector<f64>,
        cov: DMatrix<f64>,
    ) -> Result<Self, PrimitiveError> {
        let n = basis.len() * dofs;
        if mean.len() != n || cov.nrows() != n || cov.ncols() != n {
            return Err(PrimitiveError::DimensionMismatch {
                what: "weight distribution",
                expected: n,
                got: mean.len(),
            });
        }
        check_finite("mean weights", mean.as_slice())?;
        check_finite("weight covariance", cov.as_slice())?;
        Ok(Self {
            basis,
            dofs,
            mean,
            cov,
        })
    }

    /// Least-squares weights of one demonstration, DoF-major (ridge λ).
    pub fn fit_weights(
        basis: &Basis,
        demo: &Demonstration,
        ridge: f64,
    ) -> Result<DVector<f64>, PrimitiveError> {
        demo.validate(0, None)?;
        if !(ridge >= 0.0 && ridge.is_finite()) {
            return Err(PrimitiveError::Negative("ridge"));
        }
        fit_validated(basis, demo, 0, ridge)
    }

    /// Trains N(μ_w, Σ_w) from demonstrations: per-demo ridge least squares, then the sample
    /// mean and the (1/N) covariance of the weights, plus `regularisation` on the diagonal.
    pub fn train(
        basis: Basis,
        demos: &[Demonstration],
        config: &TrainConfig,
    ) -> Result<Self, PrimitiveError> {
        let first = demos.first().ok_or(PrimitiveError::NoDemonstrations)?;
        let dofs = first.values.ncols();
        if dofs == 0 {
            return Err(PrimitiveError::BadDemonstration {
                demo: 0,
                why: "has no DoF".into(),
            });
        }
        if !(config.ridge >= 0.0 && config.ridge.is_finite()) {
            return Err(PrimitiveError::Negative("ridge"));
        }
        if !(config.regularisation >= 0.0 && config.regularisation.is_finite()) {
            return Err(PrimitiveError::Negative("regularisation"));
        }
        for (i, d) in demos.iter().enumerate() {
            d.validate(i, Some(dofs))?;
        }
        let weights = demos
            .iter()
            .enumerate()
            .map(|(i, d)| fit_validated(&basis, d, i, config.ridge))
            .collect::<Result<Vec<_>, _>>()?;
        let n = weights.len() as f64;
        let mean = weights
            .iter()
            .fold(DVector::zeros(basis.len() * dofs), |a, w| a + w)
            / n;
        let mut cov = DMatrix::zeros(mean.len(), mean.len());
        for w in &weights {
            let d = w - &mean;
            cov.ger(1.0 / n, &d, &d, 1.0);
        }
        for i in 0..cov.nrows() {
            cov[(i, i)] += config.regularisation;
        }
        Ok(Self {
            basis,
            dofs,
            mean,
            cov,
        })
    }

    pub fn basis(&self) -> &Basis {
        &self.basis
    }

    pub fn dofs(&self) -> usize {
        self.dofs
    }

    pub fn weight_mean(&self) -> &DVector<f64> {
        &self.mean
    }

    pub fn weight_cov(&self) -> &DMatrix<f64> {
        &self.cov
    }

    /// Ψ(z)ᵀ x for a DoF-major weight vector x: the D values at phase z.
    fn project(&self, phi: &[f64], x: &DVector<f64>) -> DVector<f64> {
        let k = self.basis.len();
        DVector::from_fn(self.dofs, |d, _| {
            phi.iter()
                .zip(&x.as_slice()[d * k..(d + 1) * k])
                .map(|(p, w)| p * w)
                .sum()
        })
    }

    /// Σ_w Ψ(z): (D·K) × D, using that Ψ is block-diagonal with φ(z) in each block.
    pub(crate) fn cov_times_basis(&self, phi: &[f64]) -> DMatrix<f64> {
        let k = self.basis.len();
        let n = k * self.dofs;
        DMatrix::from_fn(n, self.dofs, |r, d| {
            phi.iter()
                .enumerate()
                .map(|(j, p)| self.cov[(r, d * k + j)] * p)
                .sum()
        })
    }

    /// Mean and covariance of the D DoF at phase z (no observation noise).
    pub fn marginal(&self, z: f64) -> Marginal {
        let phi = self.basis.evaluate(z);
        let g = self.cov_times_basis(phi.as_slice());
        let k = self.basis.len();
        let cov = DMatrix::from_fn(self.dofs, self.dofs, |a, b| {
            phi.iter()
                .enumerate()
                .map(|(j, p)| p * g[(a * k + j, b)])
                .sum()
        });
        Marginal {
            mean: self.project(phi.as_slice(), &self.mean),
            cov,
        }
    }

    /// The marginal at time t of an execution lasting `duration` s: temporal scaling runs the
    /// same weights over another duration.
    pub fn marginal_at(&self, t: f64, duration: f64) -> Marginal {
        self.marginal(t / duration)
    }

    /// Mean trajectory at the given phases, one row per phase.
    pub fn mean_trajectory(&self, phases: &[f64]) -> DMatrix<f64> {
        let mut out = DMatrix::zeros(phases.len(), self.dofs);
        let mut phi = vec![0.0; self.basis.len()];
        for (r, &z) in phases.iter().enumerate() {
            self.basis.evaluate_into(z, &mut phi);
            let m = self.project(&phi, &self.mean);
            out.row_mut(r).copy_from(&m.transpose());
        }
        out
    }

    /// Variance trajectory (the diagonal of each marginal covariance), one row per phase.
    pub fn variance_trajectory(&self, phases: &[f64]) -> DMatrix<f64> {
        let mut out = DMatrix::zeros(phases.len(), self.dofs);
        for (r, &z) in phases.iter().enumerate() {
            let m = self.marginal(z);
            out.row_mut(r).copy_from(&m.cov.diagonal().transpose());
        }
        out
    }

    /// Conditions on a via-point (Paraschos et al. 2013, Eq. 5):
    /// L = Σ_w Ψ (Σ_y* + Ψᵀ Σ_w Ψ)⁻¹, μ_w += L (y* − Ψᵀ μ_w), Σ_w −= L Ψᵀ Σ_w.
    /// The D×D system is solved (Cholesky, LU as fallback), never inverted. On error nothing
    /// changes.
    pub fn condition(&mut self, via: &ViaPoint) -> Result<(), PrimitiveError> {
        if !via.phase.is_finite() {
            return Err(PrimitiveError::NonFinite {
                what: "via-point phase",
                index: 0,
                value: via.phase,
            });
        }
        if !(0.0..=1.0).contains(&via.phase) {
            return Err(PrimitiveError::PhaseOutOfRange(via.phase));
        }
        if via.value.len() != self.dofs {
            return Err(PrimitiveError::DimensionMismatch {
                what: "via-point value",
                expected: self.dofs,
                got: via.value.len(),
            });
        }
        if via.noise.nrows() != self.dofs || via.noise.ncols() != self.dofs {
            return Err(PrimitiveError::DimensionMismatch {
                what: "via-point noise",
                expected: self.dofs,
                got: via.noise.nrows(),
            });
        }
        check_finite("via-point value", via.value.as_slice())?;
        check_finite("via-point noise", via.noise.as_slice())?;

        let phi = self.basis.evaluate(via.phase);
        let g = self.cov_times_basis(phi.as_slice()); // Σ_w Ψ
        let k = self.basis.len();
        let mut s = via.noise.clone();
        for a in 0..self.dofs {
            for b in 0..self.dofs {
                s[(a, b)] += phi
                    .iter()
                    .enumerate()
                    .map(|(j, p)| p * g[(a * k + j, b)])
                    .sum::<f64>();
            }
        }
        let residual = &via.value - self.project(phi.as_slice(), &self.mean);
        // X = S⁻¹ Gᵀ (D × DK), so L = Xᵀ.
        let x = solve_spd(s, g.transpose()).ok_or(PrimitiveError::Singular)?;
        let mean = &self.mean + x.tr_mul(&residual);
        let mut cov = &self.cov - &g * &x;
        symmetrise(&mut cov);
        if mean.iter().chain(cov.iter()).any(|v| !v.is_finite()) {
            return Err(PrimitiveError::Singular);
        }
        self.mean = mean;
        self.cov = cov;
        Ok(())
    }

    /// Conditions on several via-points in turn; all or nothing.
    pub fn condition_all(&mut self, vias: &[ViaPoint]) -> Result<(), PrimitiveError> {
        let mut next = self.clone();
        for v in vias {
            next.condition(v)?;
        }
        *self = next;
        Ok(())
    }
}

/// Ridge least squares of one validated demonstration. With λ = 0 and fewer samples than basis
/// functions ΦᵀΦ is singular: an error, as is any fit that does not come out finite.
fn fit_validated(
    basis: &Basis,
    demo: &Demonstration,
    index: usize,
    ridge: f64,
) -> Result<DVector<f64>, PrimitiveError> {
    let k = basis.len();
    let dofs = demo.values.ncols();
    let samples = demo.times.len();
    let singular = |why: String| PrimitiveError::BadDemonstration { demo: index, why };
    if ridge == 0.0 && samples < k {
        return Err(singular(format!(
            "{samples} samples cannot fit K = {k} basis functions without a ridge (ridge = 0); \
             give at least {k} samples or a ridge > 0"
        )));
    }
    let mut phi = DMatrix::zeros(samples, k);
    let mut row = vec![0.0; k];
    for (r, z) in demo.phases().enumerate() {
        basis.evaluate_into(z, &mut row);
        for (c, v) in row.iter().enumerate() {
            phi[(r, c)] = *v;
        }
    }
    let mut a = phi.tr_mul(&phi);
    for i in 0..k {
        a[(i, i)] += ridge;
    }
    let rhs = phi.tr_mul(&demo.values); // K × D
    let w = solve_spd(a, rhs)
        .filter(|w| w.iter().all(|v| v.is_finite()))
        .ok_or_else(|| {
            singular(format!(
                "the least-squares fit of K = {k} basis functions is singular (ridge = {ridge}); \
                 use a ridge > 0"
            ))
        })?;
    Ok(DVector::from_fn(k * dofs, |i, _| w[(i % k, i / k)]))
}

fn symmetrise(m: &mut DMatrix<f64>) {
    for r in 0..m.nrows() {
        for c in 0..r {
            let v = 0.5 * (m[(r, c)] + m[(c, r)]);
            m[(r, c)] = v;
            m[(c, r)] = v;
        }
    }
}

fn check_finite(what: &'static str, values: &[f64]) -> Result<(), PrimitiveError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(PrimitiveError::NonFinite {
            what,
            index,
            value: values[index],
        }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line_demos() -> Vec<Demonstration> {
        // y = slope·t + offset with different lengths and durations.
        (0..6)
            .map(|i| {
                let n = 30 + 7 * i;
                let dur = 1.0 + 0.3 * i as f64;
                let times: Vec<f64> = (0..n).map(|s| dur * s as f64 / (n - 1) as f64).collect();
                let slope = 1.0 + 0.1 * i as f64;
                let values = DMatrix::from_fn(n, 2, |r, c| {
                    let z = times[r] / dur;
                    if c == 0 {
                        slope * z
                    } else {
                        0.5 - 0.05 * i as f64 * z
                    }
                });
                Demonstration::new(times, values)
            })
            .collect()
    }

    #[test]
    fn basis_is_a_partition_of_unity() {
        let b = Basis::new(15, None).unwrap();
        for i in 0..=100 {
            let s: f64 = b.evaluate(i as f64 / 100.0).iter().sum();
            assert!((s - 1.0).abs() < 1e-14);
        }
        assert!(Basis::new(1, None).is_err());
        assert_eq!(
            Basis::new(5, Some(-1.0)),
            Err(PrimitiveError::BadWidth(-1.0))
        );
    }

    #[test]
    fn trains_from_demos_of_different_lengths() {
        let p = Primitive::train(
            Basis::new(10, None).unwrap(),
            &line_demos(),
            &TrainConfig::default(),
        )
        .unwrap();
        let m = p.marginal(0.5);
        // mean slope 1.25 at z = .5 → 0.625; offset DoF 0.5 − 0.125·0.5.
        assert!((m.mean[0] - 0.625).abs() < 1e-3, "{}", m.mean[0]);
        assert!((m.mean[1] - 0.4375).abs() < 1e-3, "{}", m.mean[1]);
        assert!(m.cov[(0, 0)] > 0.0);
    }

    #[test]
    fn conditioning_passes_through_the_point_with_zero_noise() {
        let mut p = Primitive::train(
            Basis::new(10, None).unwrap(),
            &line_demos(),
            &TrainConfig::default(),
        )
        .unwrap();
        p.condition(&ViaPoint::exact(0.3, &[0.9, 0.1])).unwrap();
        p.condition(&ViaPoint::exact(0.8, &[0.2, 0.6])).unwrap();
        for (z, y) in [(0.3, [0.9, 0.1]), (0.8, [0.2, 0.6])] {
            let m = p.marginal(z);
            assert!((m.mean[0] - y[0]).abs() < 1e-6 && (m.mean[1] - y[1]).abs() < 1e-6);
            assert!(m.cov.diagonal().iter().all(|v| v.abs() < 1e-6));
        }
    }

    #[test]
    fn temporal_scaling_runs_the_same_weights_over_another_duration() {
        let p = Primitive::train(
            Basis::new(10, None).unwrap(),
            &line_demos(),
            &TrainConfig::default(),
        )
        .unwrap();
        assert_eq!(p.marginal_at(1.0, 4.0), p.marginal(0.25));
        assert_eq!(p.marginal_at(3.0, 12.0), p.marginal(0.25));
    }

    #[test]
    fn bad_input_is_refused_and_changes_nothing() {
        let mut p = Primitive::train(
            Basis::new(10, None).unwrap(),
            &line_demos(),
            &TrainConfig::default(),
        )
        .unwrap();
        let before = p.clone();
        let bad = [
            ViaPoint::exact(0.5, &[f64::NAN, 0.0]),
            ViaPoint::exact(f64::INFINITY, &[0.0, 0.0]),
            ViaPoint::exact(1.5, &[0.0, 0.0]),
            ViaPoint::exact(0.5, &[0.0]),
        ];
        for v in &bad {
            assert!(p.condition(v).is_err(), "{v:?}");
        }
        assert!(
            p.condition_all(&[ViaPoint::exact(0.2, &[0.0, 0.0]), bad[0].clone()])
                .is_err()
        );
        assert_eq!(p, before);

        let mut demos = line_demos();
        demos[2].values[(3, 1)] = f64::NAN;
        let err = Primitive::train(
            Basis::new(10, None).unwrap(),
            &demos,
            &TrainConfig::default(),
        )
        .unwrap_err();
        assert!(err.to_string().contains("demonstration 2"), "{err}");
        assert_eq!(
            Primitive::train(Basis::new(10, None).unwrap(), &[], &TrainConfig::default()),
            Err(PrimitiveError::NoDemonstrations)
        );
    }

    #[test]
    fn zero_variance_dof_with_zero_noise_is_singular_not_nan() {
        let basis = Basis::new(4, None).unwrap();
        let p0 =
            Primitive::from_weights(basis, 1, DVector::zeros(4), DMatrix::zeros(4, 4)).unwrap();
        let mut p = p0.clone();
        assert_eq!(
            p.condition(&ViaPoint::exact(0.5, &[1.0])),
            Err(PrimitiveError::Singular)
        );
        assert_eq!(p, p0);
    }

    #[test]
    fn ridge_zero_on_degenerate_demos_is_an_error_not_a_panic() {
        let basis = Basis::new(10, None).unwrap();
        let ridge0 = TrainConfig {
            ridge: 0.0,
            ..Default::default()
        };
        // Three samples cannot fit ten weights without a ridge: ΦᵀΦ is singular.
        let few: Vec<Demonstration> = (0..3)
            .map(|i| {
                Demonstration::new(
                    vec![0.0, 0.5, 1.0],
                    DMatrix::from_fn(3, 2, |r, c| (r + c + i) as f64),
                )
            })
            .collect();
        let err = Primitive::train(basis.clone(), &few, &ridge0).unwrap_err();
        assert!(
            matches!(err, PrimitiveError::BadDemonstration { demo: 0, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("ridge > 0"), "{err}");
        assert!(Primitive::fit_weights(&basis, &few[1], 0.0).is_err());
        assert_eq!(
            Primitive::fit_weights(&basis, &few[1], f64::NAN),
            Err(PrimitiveError::Negative("ridge"))
        );
        // Enough samples, but every one on the first or last centre: exactly singular.
        let narrow = Basis::new(10, Some(1e-300)).unwrap();
        let mut times: Vec<f64> = (0..11).map(|i| i as f64 * 1e-3).collect();
        times.push(1.0);
        let clustered = Demonstration::new(times, DMatrix::from_element(12, 1, 0.5));
        let err = Primitive::train(narrow, &[clustered], &ridge0).unwrap_err();
        assert!(err.to_string().contains("singular"), "{err}");
        // With a ridge the same demos train.
        Primitive::train(basis.clone(), &few, &TrainConfig::default()).unwrap();
        Primitive::train(basis, &line_demos(), &ridge0).unwrap();
    }

    #[test]
    fn basis_sizes_and_widths_from_a_model_file_cannot_hurt() {
        assert_eq!(
            Basis::new(usize::MAX, None),
            Err(PrimitiveError::TooManyBasisFunctions(usize::MAX))
        );
        assert!(Basis::new(MAX_BASIS_FUNCTIONS, None).is_ok());
        // So narrow that every Gaussian underflows between the centres: the nearest takes it.
        let b = Basis::new(5, Some(1e-300)).unwrap();
        let v = b.evaluate(0.3);
        assert_eq!(v.as_slice(), &[0.0, 1.0, 0.0, 0.0, 0.0]);
        assert!(b.evaluate(f64::NAN).iter().all(|x| x.is_nan()));
    }
}
