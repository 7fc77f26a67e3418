//! A polynomial forward model: every monomial of degree ≤ d in the `N` (centred) actuations,
//! fitted by ridge least squares on D_fwd. The RBF network fits positions to about a millimetre
//! but its gradients between the demonstrations are poor; the arm's kinematics are smooth, so a
//! polynomial of low degree fits them as well (on the paper's arm degree 4, 210 terms; training
//! chooses the degree on held-out demonstrations) and its Jacobian is good enough to steer the
//! corrections of the online learner by (docs/ARCHITECTURE.md, "Adaptation").

pub use softarm_sections::kinematics::MAX_DEGREE;
use softarm_sections::kinematics::PolynomialConfig;
use softarm_space::Position;

use crate::forward::{ForwardModel, Jacobian};
use crate::linalg::Normal;

/// Monomials are of a − [`CENTRE`]: the middle of the actuation range keeps them well scaled.
const CENTRE: f64 = 0.5;

/// p(a) = Σ_m w_m Π_i (a_i − ½)^{e_{m,i}} per axis.
#[derive(Debug, Clone, PartialEq)]
pub struct Polynomial<const N: usize> {
    degree: usize,
    /// One exponent row per monomial, in the order [`exponents`] gives.
    exponents: Vec<[u8; N]>,
    /// One row per monomial, one column per axis.
    weights: Vec<Position>,
}

/// The exponents of every monomial of degree ≤ `degree` in `N` variables, constant first.
pub fn exponents<const N: usize>(degree: usize) -> Vec<[u8; N]> {
    let mut out = Vec::new();
    for total in 0..=degree {
        let mut e = [0u8; N];
        compositions(total, 0, &mut e, &mut out);
    }
    out
}

/// How many monomials of degree ≤ `degree` `inputs` variables have: C(inputs + degree, degree).
pub fn terms(inputs: usize, degree: usize) -> usize {
    (1..=degree).fold(1, |c, k| c * (inputs + k) / k)
}

fn compositions<const N: usize>(left: usize, i: usize, e: &mut [u8; N], out: &mut Vec<[u8; N]>) {
    if i == N - 1 {
        e[i] = left as u8;
        out.push(*e);
        return;
    }
    for k in (0..=left).rev() {
        e[i] = k as u8;
        compositions(left - k, i + 1, e, out);
    }
}

/// (a_i − ½)^k for k = 0..=degree, per actuator.
fn powers<const N: usize>(a: &[f64; N], degree: usize) -> [[f64; MAX_DEGREE + 1]; N] {
    let mut p = [[1.0; MAX_DEGREE + 1]; N];
    for (i, row) in p.iter_mut().enumerate() {
        let x = a[i] - CENTRE;
        for k in 1..=degree {
            row[k] = row[k - 1] * x;
        }
    }
    p
}

/// Π_i p_i^{e_i}, of the powers [`powers`] gives.
fn monomial<const N: usize>(p: &[[f64; MAX_DEGREE + 1]; N], e: &[u8; N]) -> f64 {
    (0..N).map(|i| p[i][e[i] as usize]).product()
}

impl<const N: usize> Polynomial<N> {
    /// Fits on (actuation, position) samples.
    pub fn fit(
        actuations: &[[f64; N]],
        positions: &[Position],
        config: &PolynomialConfig,
    ) -> Result<Self, String> {
        Self::check(actuations, positions, config)?;
        let normal = Self::normal_equations(actuations, positions, config.degree, &mut || {});
        Self::solve(&normal, config.degree, config.ridge)
    }

    /// What [`Polynomial::fit`] refuses before fitting: a degree or ridge out of range, as many
    /// actuations as positions, a value not finite.
    pub fn check(
        actuations: &[[f64; N]],
        positions: &[Position],
        config: &PolynomialConfig,
    ) -> Result<(), String> {
        if !(1..=MAX_DEGREE).contains(&config.degree) {
            return Err(format!(
                "degree must be 1 to {MAX_DEGREE}, got {}",
                config.degree
            ));
        }
        if !(config.ridge.is_finite() && config.ridge >= 0.0) {
            return Err(format!("ridge must be ≥ 0, got {}", config.ridge));
        }
        if actuations.len() != positions.len() {
            return Err(format!(
                "{} actuations but {} positions",
                actuations.len(),
                positions.len()
            ));
        }
        if actuations
            .iter()
            .flatten()
            .chain(positions.iter().flatten())
            .any(|v| !v.is_finite())
        {
            return Err("the samples contain a non-finite value".into());
        }
        Ok(())
    }

    /// The normal equations of a fit of `degree` on (actuation, position) samples, summed in
    /// blocks of rows on every core; `tick` once a block. Unchecked: [`Polynomial::fit`]
    /// checks its input first. Two sets of samples' equations add up to those of both, and a
    /// lower degree's are their leading terms' ([`Normal::leading`]), so a choice of degree on
    /// held-out samples sums each sample once per degree at most.
    pub fn normal_equations(
        actuations: &[[f64; N]],
        positions: &[Position],
        degree: usize,
        tick: &mut dyn FnMut(),
    ) -> Normal {
        let exponents = exponents::<N>(degree);
        Normal::of(
            actuations.len(),
            exponents.len(),
            3,
            |r, phi, y| {
                let p = powers(&actuations[r], degree);
                for (f, e) in phi.iter_mut().zip(&exponents) {
                    *f = monomial(&p, e);
                }
                y.copy_from_slice(&positions[r]);
            },
            tick,
        )
    }

    /// The polynomial of `degree` that solves `normal` (of that degree or higher) with `ridge`.
    pub fn solve(normal: &Normal, degree: usize, ridge: f64) -> Result<Self, String> {
        let exponents = exponents::<N>(degree);
        let terms = exponents.len();
        if normal.gram.nrows() < terms {
            return Err(format!(
                "equations of {} terms for the {terms} of degree {degree}",
                normal.gram.nrows()
            ));
        }
        if normal.rows < terms {
            return Err(format!(
                "{} samples are too few for the {terms} terms of degree {degree}",
                normal.rows
            ));
        }
        let w = normal
            .leading(terms)
            .solve(ridge)
            .ok_or("the least-squares system is singular: use a ridge > 0")?;
        Ok(Self {
            degree,
            exponents,
            weights: (0..terms)
                .map(|i| [w[(i, 0)], w[(i, 1)], w[(i, 2)]])
                .collect(),
        })
    }

    /// A model from saved weights (one row per monomial of `degree`).
    pub fn from_weights(degree: usize, weights: Vec<Position>) -> Result<Self, String> {
        if !(1..=MAX_DEGREE).contains(&degree) {
            return Err(format!(
                "polynomial: degree must be 1 to {MAX_DEGREE}, got {degree}"
            ));
        }
        let exponents = exponents(degree);
        if weights.len() != exponents.len() {
            return Err(format!(
                "polynomial: degree {degree} has {} terms, got {} weight rows",
                exponents.len(),
                weights.len()
            ));
        }
        if weights.iter().flatten().any(|v| !v.is_finite()) {
            return Err("polynomial: a weight is not finite".into());
        }
        Ok(Self {
            degree,
            exponents,
            weights,
        })
    }

    pub fn degree(&self) -> usize {
        self.degree
    }

    /// One row per monomial, for saving.
    pub fn weights(&self) -> &[Position] {
        &self.weights
    }

    fn term(&self, p: &[[f64; MAX_DEGREE + 1]; N], m: usize) -> f64 {
        monomial(p, &self.exponents[m])
    }
}

impl<const N: usize> ForwardModel<N> for Polynomial<N> {
    fn position(&self, a: &[f64; N]) -> Position {
        let p = powers(a, self.degree);
        let mut y = [0.0; 3];
        for (m, w) in self.weights.iter().enumerate() {
            let t = self.term(&p, m);
            for d in 0..3 {
                y[d] += t * w[d];
            }
        }
        y
    }

    fn jacobian(&self, a: &[f64; N]) -> Jacobian<N> {
        let p = powers(a, self.degree);
        let mut j = Jacobian::<N>::zeros();
        for (e, w) in self.exponents.iter().zip(&self.weights) {
            for i in 0..N {
                let k = e[i] as usize;
                if k == 0 {
                    continue;
                }
                // ∂/∂a_i of Π_j x_j^{e_j} = e_i x_i^{e_i − 1} Π_{j≠i} x_j^{e_j}
                let mut t = k as f64 * p[i][k - 1];
                for (j, row) in p.iter().enumerate() {
                    if j != i {
                        t *= row[e[j] as usize];
                    }
                }
                for d in 0..3 {
                    j[(d, i)] += t * w[d];
                }
            }
        }
        j
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};
    use softarm_sections::arm::ArmConfig;

    #[test]
    fn term_counts_are_binomial() {
        // C(6 + d, d)
        for (d, n) in [(1, 7), (2, 28), (3, 84), (4, 210), (5, 462)] {
            assert_eq!(exponents::<6>(d).len(), n);
            assert_eq!(terms(6, d), n);
        }
        assert_eq!(exponents::<6>(2)[0], [0; 6]);
        assert_eq!(exponents::<9>(3).len(), terms(9, 3));
        assert_eq!(terms(16, 4), 4845);
        assert_eq!(terms(16, 2), 153);
    }

    /// On any arm: the nine-tendon TDCR's kinematics.
    #[test]
    fn fits_a_nine_tendon_arm() {
        let text = include_str!("../../../contract/arm/testdata/tdcr.toml");
        let layout = softarm_arm::Layout::new(&toml::from_str(text).unwrap()).unwrap();
        let arm = crate::pcc::Arm::new(&layout, &[]);
        let mut rng = StdRng::seed_from_u64(9);
        // A fifth of each 20 mm stroke on a 4.5 mm radius still bends each segment by up to
        // 0.45 rad: the three together turn the tip by most of a right angle.
        let sample =
            |rng: &mut StdRng| -> [f64; 9] { std::array::from_fn(|_| rng.random_range(0.4..0.6)) };
        let a: Vec<[f64; 9]> = (0..4000).map(|_| sample(&mut rng)).collect();
        let p: Vec<Position> = a.iter().map(|a| arm.position(a)).collect();
        let config = PolynomialConfig::default();
        let poly = Polynomial::fit(&a, &p, &config).unwrap();
        for _ in 0..50 {
            let x = sample(&mut rng);
            let err = softarm_space::distance(&poly.position(&x), &arm.position(&x));
            assert!(err < 1e-3, "fit error {err} m");
            let j = poly.jacobian(&x);
            let truth = crate::forward::finite_difference(&arm, &x);
            assert!((j - truth).abs().max() < 0.02, "{j} vs {truth}");
        }
    }

    #[test]
    fn fits_the_arm_and_its_jacobian_matches_finite_differences() {
        // The default `[arm]`: the paper's.
        let arm = crate::pcc::Arm::of_config(&ArmConfig::default()).unwrap();
        let mut rng = StdRng::seed_from_u64(7);
        let sample = |rng: &mut StdRng| -> [f64; 6] {
            std::array::from_fn(|_| rng.random_range(0.25..0.75))
        };
        let a: Vec<[f64; 6]> = (0..2000).map(|_| sample(&mut rng)).collect();
        let p: Vec<Position> = a.iter().map(|a| arm.position(a)).collect();
        let poly = Polynomial::fit(&a, &p, &PolynomialConfig::default()).unwrap();
        for _ in 0..50 {
            let x = sample(&mut rng);
            let err = softarm_space::distance(&poly.position(&x), &arm.position(&x));
            assert!(err < 1e-3, "fit error {err} m");
            // The analytic Jacobian of the polynomial against its own finite differences...
            let j = poly.jacobian(&x);
            let fd = crate::forward::finite_difference(&poly, &x);
            assert!((j - fd).abs().max() < 1e-6, "{j} vs {fd}");
            // ...and against the arm's.
            let truth = crate::forward::finite_difference(&arm, &x);
            assert!((j - truth).abs().max() < 0.02, "{j} vs {truth}");
        }
        let back = Polynomial::from_weights(4, poly.weights().to_vec()).unwrap();
        assert_eq!(back, poly);
    }

    #[test]
    fn bad_input_is_refused() {
        let a = vec![[0.5; 6]; 300];
        let p = vec![[0.0; 3]; 300];
        let cfg = |degree, ridge| PolynomialConfig { degree, ridge };
        assert!(
            Polynomial::fit(&a, &p, &cfg(0, 0.0))
                .unwrap_err()
                .contains("degree")
        );
        assert!(Polynomial::fit(&a, &p[..10], &cfg(2, 0.0)).is_err());
        assert!(
            Polynomial::fit(&a[..20], &p[..20], &cfg(2, 1e-6))
                .unwrap_err()
                .contains("too few")
        );
        // Every sample at one actuation: singular without a ridge.
        assert!(
            Polynomial::fit(&a, &p, &cfg(2, 0.0))
                .unwrap_err()
                .contains("singular")
        );
        assert!(Polynomial::<6>::from_weights(2, vec![[0.0; 3]; 27]).is_err());
        assert!(Polynomial::<6>::from_weights(2, vec![[f64::NAN; 3]; 28]).is_err());
    }
}
