//! Linear algebra the fits share (the forward models here, the ProMPs of `softarm-method`).

use nalgebra::DMatrix;

/// Solves A X = B for a symmetric A: Cholesky when A is positive definite, else LU.
pub fn solve_spd(a: DMatrix<f64>, b: DMatrix<f64>) -> Option<DMatrix<f64>> {
    if let Some(ch) = a.clone().cholesky() {
        return Some(ch.solve(&b));
    }
    a.lu().solve(&b)
}
