//! Marginals on the tick grid, in information form, and the small dense linear algebra the
//! tick needs (no allocation: fixed-size arrays).

/// One marginal in information form.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Information<const D: usize> {
    /// Λ = (S + floor·I)⁻¹
    pub(super) precision: [[f64; D]; D],
    /// Λ μ
    pub(super) shifted: [f64; D],
}

impl<const D: usize> Information<D> {
    pub(super) const ZERO: Self = Self {
        precision: [[0.0; D]; D],
        shifted: [0.0; D],
    };

    pub(super) fn new(mean: &[f64; D], cov: &[[f64; D]; D], floor: f64) -> Self {
        let mut s = *cov;
        for (d, row) in s.iter_mut().enumerate() {
            row[d] += floor;
        }
        let mut precision = [[0.0; D]; D];
        match cholesky(&mut s) {
            Some(()) => inverse_of_factor(&s, &mut precision),
            // Cancellation in a conditioned covariance can leave it a hair indefinite; the
            // diagonal keeps the mean and a sane precision.
            None => {
                for d in 0..D {
                    precision[d][d] = 1.0 / (cov[d][d].max(0.0) + floor);
                }
            }
        }
        let mut shifted = [0.0; D];
        for d in 0..D {
            shifted[d] = (0..D).map(|e| precision[d][e] * mean[e]).sum();
        }
        Self { precision, shifted }
    }
}

/// The marginals of one primitive at every tick of the timeline, in information form.
#[derive(Debug, Clone, PartialEq)]
pub struct Table<const D: usize> {
    pub(super) entries: Box<[Information<D>]>,
    /// What a group's table was conditioned on; NaN and 0 for a primitive's own.
    pub(super) on: ConditionedOn<D>,
}

impl<const D: usize> Table<D> {
    pub(super) fn zeroed(ticks: usize) -> Self {
        Self {
            entries: vec![Information::ZERO; ticks].into_boxed_slice(),
            on: ConditionedOn::NONE,
        }
    }

    pub fn ticks(&self) -> usize {
        self.entries.len()
    }
}

/// What a group was conditioned on (UpdatePrim's input): the actuation estimate at its T_cond
/// and the execution (1-based) the estimate was for. A group runs on whatever table is in force
/// when its window comes, so an estimate that comes too late runs an execution later than
/// meant, and whoever learns from the point needs to know which one ran.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConditionedOn<const D: usize> {
    pub actuation: [f64; D],
    pub execution: u32,
    /// The estimate was corrected within its execution (the learner's word, told on).
    pub within: bool,
    /// The point's target is beyond the arm's reach: the estimate aims at the nearest place
    /// the arm reaches (the learner's word, told on).
    pub beyond_reach: bool,
}

impl<const D: usize> ConditionedOn<D> {
    /// Nothing: a primitive's own table, or a group not played yet.
    pub const NONE: Self = Self {
        actuation: [f64::NAN; D],
        execution: 0,
        within: false,
        beyond_reach: false,
    };
}

/// A re-conditioned table for one group, on its way to the tick.
pub struct Update<const D: usize> {
    pub(super) group: usize,
    pub(super) table: Table<D>,
}

/// In-place Cholesky: the lower triangle of `a` becomes L with A = L Lᵀ. Reads only the lower
/// triangle. `None` if A is not positive definite.
pub(super) fn cholesky<const D: usize>(a: &mut [[f64; D]; D]) -> Option<()> {
    for j in 0..D {
        let mut s = a[j][j];
        for k in 0..j {
            s -= a[j][k] * a[j][k];
        }
        if s <= 0.0 || !s.is_finite() {
            return None;
        }
        let l = s.sqrt();
        a[j][j] = l;
        for i in j + 1..D {
            let mut s = a[i][j];
            for k in 0..j {
                s -= a[i][k] * a[j][k];
            }
            a[i][j] = s / l;
        }
    }
    Some(())
}

/// A⁻¹ = L⁻ᵀ L⁻¹ from the factor L of [`cholesky`], into `out`: L⁻¹ by forward substitution,
/// then the symmetric product, about D³/3 multiplications where D solves of A x = e take 2 D³
/// (what a re-conditioning does at every tick of a set).
fn inverse_of_factor<const D: usize>(l: &[[f64; D]; D], out: &mut [[f64; D]; D]) {
    let mut inv = [[0.0; D]; D];
    for j in 0..D {
        inv[j][j] = 1.0 / l[j][j];
        for i in j + 1..D {
            let mut acc = 0.0;
            for k in j..i {
                acc += l[i][k] * inv[k][j];
            }
            inv[i][j] = -acc / l[i][i];
        }
    }
    for a in 0..D {
        for b in 0..=a {
            let mut acc = 0.0;
            for k in a..D {
                acc += inv[k][a] * inv[k][b];
            }
            out[a][b] = acc;
            out[b][a] = acc;
        }
    }
}

/// Solves L Lᵀ x = b with the factor from [`cholesky`].
pub(super) fn cholesky_solve<const D: usize>(l: &[[f64; D]; D], mut b: [f64; D]) -> [f64; D] {
    for i in 0..D {
        for k in 0..i {
            b[i] -= l[i][k] * b[k];
        }
        b[i] /= l[i][i];
    }
    for i in (0..D).rev() {
        for k in i + 1..D {
            b[i] -= l[k][i] * b[k];
        }
        b[i] /= l[i][i];
    }
    b
}
