//! Linear algebra the fits share (the forward models here, the ProMPs of `softarm-method`, the
//! model pipeline), and running their independent parts on every core.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;

use nalgebra::{DMatrix, DMatrixView};

/// Solves A X = B for a symmetric A: Cholesky when A is positive definite, else LU.
pub fn solve_spd(a: DMatrix<f64>, b: DMatrix<f64>) -> Option<DMatrix<f64>> {
    if let Some(ch) = a.clone().cholesky() {
        return Some(ch.solve(&b));
    }
    a.lu().solve(&b)
}

/// The cores this process may run on.
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// `work(0..jobs)` on every core, in order; `tick` called (on this thread) as each ends.
pub fn on_every_core<T: Send>(
    jobs: usize,
    work: impl Fn(usize) -> T + Sync,
    tick: &mut dyn FnMut(),
) -> Vec<T> {
    on_every_core_ticking(
        jobs,
        |job, ticked| {
            let out = work(job);
            ticked();
            out
        },
        tick,
    )
}

/// `work(job, ticked)` for `0..jobs` on every core, in order; each `ticked()` a job calls
/// calls `tick` on this thread: a few long jobs show how far each is.
pub fn on_every_core_ticking<T: Send>(
    jobs: usize,
    work: impl Fn(usize, &dyn Fn()) -> T + Sync,
    tick: &mut dyn FnMut(),
) -> Vec<T> {
    let workers = cores().min(jobs);
    let next = AtomicUsize::new(0);
    let (ticks, ticked) = mpsc::channel();
    let mut out: Vec<Option<T>> = (0..jobs).map(|_| None).collect();
    let done = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                let (ticks, next, work) = (ticks.clone(), &next, &work);
                scope.spawn(move || {
                    let tell = || {
                        let _ = ticks.send(());
                    };
                    let mut mine = Vec::new();
                    loop {
                        let job = next.fetch_add(1, Ordering::Relaxed);
                        if job >= jobs {
                            break;
                        }
                        mine.push((job, work(job, &tell)));
                    }
                    mine
                })
            })
            .collect();
        drop(ticks);
        for () in ticked {
            tick();
        }
        // A worker's panic is passed on, as the scope would.
        (handles.into_iter())
            .flat_map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
            .collect::<Vec<_>>()
    });
    for (job, result) in done {
        out[job] = Some(result);
    }
    out.into_iter().flatten().collect()
}

/// Parts of the rows the normal equations are summed in, each on a core: a fixed number, so
/// the sums (and the model) are the same to the last bit whatever the machine's cores.
pub const PARTS: usize = 2;

/// Rows of Φ built and multiplied at a time: a block's Φ stays in the cache while ΦᵀΦ grows.
pub const BLOCK_ROWS: usize = 256;

/// The normal equations of a least-squares fit of `outputs` values on `features` features:
/// ΦᵀΦ and ΦᵀY, summed over the rows a block at a time (never the whole Φ: 24 000 rows of
/// 4 845 features would be 940 MB), in parts on every core.
#[derive(Debug, Clone, PartialEq)]
pub struct Normal {
    /// ΦᵀΦ: features × features.
    pub gram: DMatrix<f64>,
    /// ΦᵀY: features × outputs.
    pub rhs: DMatrix<f64>,
    /// Rows summed.
    pub rows: usize,
}

impl Normal {
    /// Zero equations (no rows).
    pub fn zeros(features: usize, outputs: usize) -> Self {
        Self {
            gram: DMatrix::zeros(features, features),
            rhs: DMatrix::zeros(features, outputs),
            rows: 0,
        }
    }

    /// The equations of `rows` rows; `fill(row, φ, y)` writes a row's features and outputs.
    /// `tick` is called once per [`BLOCK_ROWS`] rows. The rows are summed in [`PARTS`] parts,
    /// a core each.
    pub fn of(
        rows: usize,
        features: usize,
        outputs: usize,
        fill: impl Fn(usize, &mut [f64], &mut [f64]) + Sync,
        tick: &mut dyn FnMut(),
    ) -> Self {
        let blocks = rows.div_ceil(BLOCK_ROWS);
        let parts = on_every_core_ticking(
            PARTS,
            |part, ticked| {
                let mut sum = Normal::zeros(features, outputs);
                // Contiguous blocks per part, each summed in order.
                for block in part * blocks / PARTS..(part + 1) * blocks / PARTS {
                    sum.add_block(block * BLOCK_ROWS, rows, &fill);
                    ticked();
                }
                sum
            },
            tick,
        );
        (parts.into_iter())
            .reduce(|a, b| a + b)
            .unwrap_or_else(|| Normal::zeros(features, outputs))
    }

    /// Adds the rows from `first` of a block of at most [`BLOCK_ROWS`] (of `rows` in all).
    fn add_block(
        &mut self,
        first: usize,
        rows: usize,
        fill: &impl Fn(usize, &mut [f64], &mut [f64]),
    ) {
        let (features, outputs) = self.rhs.shape();
        let n = BLOCK_ROWS.min(rows - first);
        // Φᵀ of the block, a column per row, and Yᵀ: each row's values contiguous.
        let mut phi_t = vec![0.0; features * n];
        let mut y_t = vec![0.0; outputs * n];
        for r in 0..n {
            fill(
                first + r,
                &mut phi_t[r * features..(r + 1) * features],
                &mut y_t[r * outputs..(r + 1) * outputs],
            );
        }
        let phi_t_m = DMatrixView::from_slice(&phi_t, features, n);
        let phi = DMatrixView::from_slice_with_strides(&phi_t, n, features, features, 1);
        let y = DMatrixView::from_slice_with_strides(&y_t, n, outputs, outputs, 1);
        // A general product on strided views: the blocked kernel, not a dot per entry.
        self.gram.gemm(1.0, &phi_t_m, &phi, 1.0);
        self.rhs.gemm(1.0, &phi_t_m, &y, 1.0);
        self.rows += n;
    }

    /// The equations of the first `features` features alone: a model whose features are the
    /// first of another's (a polynomial of lower degree) needs no rows summed again.
    pub fn leading(&self, features: usize) -> Self {
        Self {
            gram: self.gram.view((0, 0), (features, features)).into_owned(),
            rhs: (self.rhs.rows(0, features)).into_owned(),
            rows: self.rows,
        }
    }

    /// The weights minimising ‖ΦW − Y‖² + `ridge` ‖W‖²: features × outputs; `None` if singular.
    pub fn solve(&self, ridge: f64) -> Option<DMatrix<f64>> {
        let mut a = self.gram.clone();
        for i in 0..a.nrows() {
            a[(i, i)] += ridge;
        }
        solve_spd(a, self.rhs.clone()).filter(|w| w.iter().all(|v| v.is_finite()))
    }
}

impl std::ops::Add for Normal {
    type Output = Normal;

    /// The equations of both sets of rows.
    fn add(mut self, other: Normal) -> Normal {
        self.gram += other.gram;
        self.rhs += other.rhs;
        self.rows += other.rows;
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jobs_on_every_core_come_back_in_order_each_ticked_once() {
        let mut ticks = 0;
        // The first jobs the slowest: on two cores or more they end out of order.
        let slow_first = |j: usize| {
            std::thread::sleep(std::time::Duration::from_micros((37 - j as u64) * 300));
            j * j
        };
        let out = on_every_core(37, slow_first, &mut || ticks += 1);
        assert_eq!(out, (0..37).map(|j| j * j).collect::<Vec<_>>());
        assert_eq!(ticks, 37);
        assert!(on_every_core(0, |j| j, &mut || ticks += 1).is_empty());
        assert_eq!(ticks, 37);
    }

    #[test]
    fn normal_equations_in_blocks_are_those_of_the_whole_matrix() {
        // Rows over several blocks, the last one short.
        let rows = 2 * BLOCK_ROWS + 37;
        let (f, o) = (7, 3);
        let value = |r: usize, c: usize| ((r * 31 + c * 17) % 23) as f64 / 23.0 - 0.4;
        let phi = DMatrix::from_fn(rows, f, value);
        let y = DMatrix::from_fn(rows, o, |r, c| value(r + 5, c + 11));
        let mut ticks = 0;
        let normal = Normal::of(
            rows,
            f,
            o,
            |r, p, v| {
                (0..f).for_each(|c| p[c] = phi[(r, c)]);
                (0..o).for_each(|c| v[c] = y[(r, c)]);
            },
            &mut || ticks += 1,
        );
        assert_eq!(ticks, 3);
        assert_eq!(normal.rows, rows);
        assert!((&normal.gram - phi.tr_mul(&phi)).abs().max() < 1e-9);
        assert!((&normal.rhs - phi.tr_mul(&y)).abs().max() < 1e-9);
        // The leading features' equations, and the sum of two sets of rows.
        let lead = normal.leading(4);
        let phi4 = phi.columns(0, 4).into_owned();
        assert!((&lead.gram - phi4.tr_mul(&phi4)).abs().max() < 1e-9);
        let w = normal.solve(0.0).unwrap();
        let direct = solve_spd(phi.tr_mul(&phi), phi.tr_mul(&y)).unwrap();
        assert!((&w - &direct).abs().max() < 1e-9);
        let twice = normal.clone() + normal.clone();
        assert_eq!(twice.rows, 2 * rows);
        assert!((&twice.gram - 2.0 * &normal.gram).abs().max() < 1e-9);
        assert_eq!(
            Normal::of(0, f, o, |_, _, _| {}, &mut || {}),
            Normal::zeros(f, o)
        );
    }
}
