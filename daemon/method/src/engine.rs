//! The tick engine: the paper's Eq. 11 evaluated once per controller tick,
//!
//!   v(t) = Σ_i b_i(t) μ*_i(t),  μ*_i = (Σ_j a_j Λ_ij)⁻¹ Σ_j a_j Λ_ij μ_ij,  Λ_ij = (S_ij + floor·I)⁻¹,
//!
//! with every marginal N(μ_ij, S_ij) precomputed on the controller's tick grid in information
//! form (Λ, Λμ), so a tick is a few weighted sums and one D×D Cholesky solve per active group
//! (at most two are active). A tick allocates nothing and locks nothing.
//!
//! Groups are N copies of the M primitives; in group n, primitive Q[n] is conditioned on the
//! actuation estimate for conditioning point n (UpdatePrim). Re-conditioning runs off the tick
//! thread in a [`Replanner`]: it fills a spare table and sends it over a bounded lock-free
//! single-producer single-consumer ring ([`rtrb`]); the tick swaps it in while b_n = 0 or between
//! executions (the rest, and tick 0), so replanning never moves a setpoint already played, and
//! sends the old table back over another ring for reuse, so the tick never frees memory either.

use rtrb::{Consumer, Producer, PushError, RingBuffer};

use nalgebra::{DMatrix, DVector};

use crate::activation::{ActivationConfig, MAX_PRIMITIVES, Schedule, ScheduleError};
use crate::promp::{Primitive, PrimitiveError, solve_spd};

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EngineError {
    #[error(transparent)]
    Primitive(#[from] PrimitiveError),
    #[error(transparent)]
    Schedule(#[from] ScheduleError),
    #[error("tick rate must be finite and > 0, got {0} Hz")]
    Rate(f64),
    #[error("primitive {index}: {why}")]
    PrimitiveMismatch { index: usize, why: String },
    #[error("{what}: expected {expected}, got {got}")]
    Count {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("no group {group}: the plan has {groups}")]
    NoSuchGroup { group: usize, groups: usize },
    #[error("{what} must be finite (got {value} at index {index})")]
    NonFinite {
        what: &'static str,
        index: usize,
        value: f64,
    },
    #[error("the tick engine is gone (the controller stopped)")]
    Disconnected,
    #[error("{0} re-conditioned groups already wait for the tick; try again once it runs")]
    Busy(usize),
}

/// The controller's tick grid over one execution: tick k at t = k / rate, phase k / (ticks − 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timeline {
    rate_hz: f64,
    ticks: usize,
}

impl Timeline {
    /// The duration is snapped to whole ticks.
    pub fn new(duration_s: f64, rate_hz: f64) -> Result<Self, EngineError> {
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            return Err(EngineError::Rate(rate_hz));
        }
        if !(duration_s.is_finite() && duration_s > 0.0) {
            return Err(ScheduleError::Duration(duration_s).into());
        }
        let ticks = (duration_s * rate_hz).round().max(1.0) as usize + 1;
        Ok(Self { rate_hz, ticks })
    }

    pub fn ticks(&self) -> usize {
        self.ticks
    }

    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    pub fn duration(&self) -> f64 {
        (self.ticks - 1) as f64 / self.rate_hz
    }

    pub fn time_of(&self, tick: usize) -> f64 {
        tick as f64 / self.rate_hz
    }

    pub fn phase_of(&self, tick: usize) -> f64 {
        tick as f64 / (self.ticks - 1) as f64
    }

    /// The tick nearest to t, inside the execution.
    pub fn tick_of(&self, t: f64) -> usize {
        ((t * self.rate_hz).round().max(0.0) as usize).min(self.ticks - 1)
    }
}

/// One marginal in information form.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Information<const D: usize> {
    /// Λ = (S + floor·I)⁻¹
    precision: [[f64; D]; D],
    /// Λ μ
    shifted: [f64; D],
}

impl<const D: usize> Information<D> {
    const ZERO: Self = Self {
        precision: [[0.0; D]; D],
        shifted: [0.0; D],
    };

    fn new(mean: &[f64; D], cov: &[[f64; D]; D], floor: f64) -> Self {
        let mut s = *cov;
        for (d, row) in s.iter_mut().enumerate() {
            row[d] += floor;
        }
        let mut precision = [[0.0; D]; D];
        match cholesky(&mut s) {
            Some(()) => {
                for (e, col) in (0..D).map(|e| (e, unit::<D>(e))) {
                    let x = cholesky_solve(&s, col);
                    for d in 0..D {
                        precision[d][e] = x[d];
                    }
                }
            }
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
    entries: Box<[Information<D>]>,
}

impl<const D: usize> Table<D> {
    fn zeroed(ticks: usize) -> Self {
        Self {
            entries: vec![Information::ZERO; ticks].into_boxed_slice(),
        }
    }

    pub fn ticks(&self) -> usize {
        self.entries.len()
    }
}

/// A re-conditioned table for one group, on its way to the tick.
pub struct Update<const D: usize> {
    group: usize,
    table: Table<D>,
}

/// Everything about a way-point set that does not change while it runs: the primitives'
/// marginals on the tick grid, ready to condition any group in a few milliseconds.
pub struct Planner<const D: usize> {
    primitives: Vec<Primitive>,
    schedule: Schedule,
    timeline: Timeline,
    cond_ticks: Vec<usize>,
    /// Basis values φ(z_k), ticks × K, row-major.
    phi: Vec<f64>,
    base_mean: Vec<Vec<[f64; D]>>,
    base_cov: Vec<Vec<[[f64; D]; D]>>,
    variance_floor: f64,
}

impl<const D: usize> Planner<D> {
    /// Precomputes the unconditioned marginals of every primitive on the tick grid. Conditioning
    /// times are snapped to the nearest tick, so each point is evaluated exactly where it was
    /// conditioned.
    pub fn new(
        primitives: Vec<Primitive>,
        t_cond: &[f64],
        assignment: &[usize],
        timeline: Timeline,
        activation: ActivationConfig,
        variance_floor: f64,
    ) -> Result<Self, EngineError> {
        if primitives.is_empty() || primitives.len() > MAX_PRIMITIVES {
            return Err(ScheduleError::PrimitiveCount(primitives.len()).into());
        }
        let basis = primitives[0].basis().clone();
        for (index, p) in primitives.iter().enumerate() {
            if p.dofs() != D {
                return Err(EngineError::PrimitiveMismatch {
                    index,
                    why: format!("has {} DoF, the engine drives {D}", p.dofs()),
                });
            }
            if *p.basis() != basis {
                return Err(EngineError::PrimitiveMismatch {
                    index,
                    why: "uses another basis than primitive 0".into(),
                });
            }
        }
        if !(variance_floor.is_finite() && variance_floor > 0.0) {
            return Err(EngineError::NonFinite {
                what: "variance floor (must be > 0)",
                index: 0,
                value: variance_floor,
            });
        }
        let duration = timeline.duration();
        for (index, &t) in t_cond.iter().enumerate() {
            // Half a tick of slack: the duration itself was snapped to the grid.
            if !(t.is_finite() && t >= 0.0 && t <= duration + 0.5 / timeline.rate_hz()) {
                return Err(ScheduleError::OutOfRange { index, t, duration }.into());
            }
        }
        let cond_ticks: Vec<usize> = t_cond.iter().map(|&t| timeline.tick_of(t)).collect();
        let snapped: Vec<f64> = cond_ticks.iter().map(|&k| timeline.time_of(k)).collect();
        let schedule = Schedule::new(
            &snapped,
            assignment,
            primitives.len(),
            timeline.duration(),
            activation,
        )?;

        let k = basis.len();
        let ticks = timeline.ticks();
        let mut phi = vec![0.0; ticks * k];
        for (tick, row) in phi.chunks_exact_mut(k).enumerate() {
            basis.evaluate_into(timeline.phase_of(tick), row);
        }
        let mut base_mean = Vec::with_capacity(primitives.len());
        let mut base_cov = Vec::with_capacity(primitives.len());
        for p in &primitives {
            let (m, c) = base_marginals::<D>(p, &phi, k);
            base_mean.push(m);
            base_cov.push(c);
        }
        Ok(Self {
            primitives,
            schedule,
            timeline,
            cond_ticks,
            phi,
            base_mean,
            base_cov,
            variance_floor,
        })
    }

    pub fn schedule(&self) -> &Schedule {
        &self.schedule
    }

    pub fn timeline(&self) -> &Timeline {
        &self.timeline
    }

    /// The tick of each conditioning point.
    pub fn conditioning_ticks(&self) -> &[usize] {
        &self.cond_ticks
    }

    /// The unconditioned marginals of primitive j as a table.
    fn base_table(&self, j: usize) -> Table<D> {
        let mut t = Table::zeroed(self.timeline.ticks());
        for (e, (m, c)) in t
            .entries
            .iter_mut()
            .zip(self.base_mean[j].iter().zip(&self.base_cov[j]))
        {
            *e = Information::new(m, c, self.variance_floor);
        }
        t
    }

    /// UpdatePrim: the marginals of primitive Q[group] conditioned on passing exactly through
    /// `actuation` at T_cond[group], written into `into`.
    ///
    /// Conditioning is a rank-D update of Σ_w, so with G = Σ_w Ψ*, S* = Ψ*ᵀ G and C(t) = Ψ(t)ᵀ G
    /// each tick's marginal is μ_b + C S*⁻¹ (y* − μ_b*) and S_b − C S*⁻¹ Cᵀ: O(K·D²) per tick
    /// instead of O(K²·D²) for Ψᵀ Σ_w Ψ.
    pub fn condition(
        &self,
        group: usize,
        actuation: &[f64; D],
        into: &mut Table<D>,
    ) -> Result<(), EngineError> {
        let groups = self.schedule.points();
        if group >= groups {
            return Err(EngineError::NoSuchGroup { group, groups });
        }
        if let Some(index) = actuation.iter().position(|v| !v.is_finite()) {
            return Err(EngineError::NonFinite {
                what: "actuation estimate",
                index,
                value: actuation[index],
            });
        }
        let j = self.schedule.assignment()[group];
        let p = &self.primitives[j];
        let k = p.basis().len();
        let star = self.cond_ticks[group];
        let phi_star = &self.phi[star * k..(star + 1) * k];
        let g = p.cov_times_basis(phi_star); // (D·K) × D
        let s_star = DMatrix::from_fn(D, D, |a, b| {
            (0..k).map(|i| phi_star[i] * g[(a * k + i, b)]).sum::<f64>()
        });
        let mean_star = self.base_mean[j][star];
        let residual = DVector::from_fn(D, |d, _| actuation[d] - mean_star[d]);
        let mut rhs = DMatrix::zeros(D, D * k + 1);
        rhs.columns_mut(0, D * k).copy_from(&g.transpose());
        rhs.column_mut(D * k).copy_from(&residual);
        // [S*⁻¹ Gᵀ | S*⁻¹ r] in one solve.
        let x = solve_spd(s_star, rhs).ok_or(PrimitiveError::Singular)?;
        if x.iter().any(|v| !v.is_finite()) {
            return Err(PrimitiveError::Singular.into());
        }
        let u = x.column(D * k);

        if into.entries.len() != self.timeline.ticks() {
            *into = Table::zeroed(self.timeline.ticks());
        }
        let (gs, xs) = (g.as_slice(), x.as_slice()); // column-major
        let rows_g = D * k;
        for (tick, entry) in into.entries.iter_mut().enumerate() {
            let phi = &self.phi[tick * k..(tick + 1) * k];
            // C = Ψᵀ G and E = Ψᵀ Xᵀ = C S*⁻¹.
            let mut c = [[0.0; D]; D];
            let mut e = [[0.0; D]; D];
            for d in 0..D {
                for b in 0..D {
                    let (mut sc, mut se) = (0.0, 0.0);
                    for (i, f) in phi.iter().enumerate() {
                        sc += f * gs[b * rows_g + d * k + i];
                        se += f * xs[(d * k + i) * D + b];
                    }
                    c[d][b] = sc;
                    e[d][b] = se;
                }
            }
            let mut mean = self.base_mean[j][tick];
            let mut cov = self.base_cov[j][tick];
            for d in 0..D {
                mean[d] += (0..D).map(|b| c[d][b] * u[b]).sum::<f64>();
                for b in 0..D {
                    cov[d][b] -= (0..D).map(|i| e[d][i] * c[b][i]).sum::<f64>();
                }
            }
            for d in 0..D {
                for b in 0..d {
                    let v = 0.5 * (cov[d][b] + cov[b][d]);
                    cov[d][b] = v;
                    cov[b][d] = v;
                }
            }
            *entry = Information::new(&mean, &cov, self.variance_floor);
        }
        Ok(())
    }

    /// Builds the tick engine with every group conditioned on its initial estimate, and the
    /// replanner that re-conditions groups while it runs.
    pub fn start(self, initial: &[[f64; D]]) -> Result<(TickEngine<D>, Replanner<D>), EngineError> {
        let n = self.schedule.points();
        if initial.len() != n {
            return Err(EngineError::Count {
                what: "initial actuation estimates",
                expected: n,
                got: initial.len(),
            });
        }
        let base = (0..self.primitives.len())
            .map(|j| self.base_table(j))
            .collect();
        let mut conditioned = Vec::with_capacity(n);
        for (group, a) in initial.iter().enumerate() {
            let mut t = Table::zeroed(self.timeline.ticks());
            self.condition(group, a, &mut t)?;
            conditioned.push(t);
        }
        // Bounded both ways: a replanner can be at most `n` updates ahead, and the retired
        // ring has room for every table that can be in flight.
        let (updates_tx, updates_rx) = RingBuffer::new(n);
        let (retired_tx, retired_rx) = RingBuffer::new(4 * n);
        let mut engine = TickEngine {
            schedule: self.schedule,
            timeline: self.timeline,
            base,
            conditioned,
            pending: (0..n).map(|_| None).collect(),
            pending_count: 0,
            updates: updates_rx,
            retired: retired_tx,
            held: vec![[0.0; D]; n],
            held_count: 0,
            applied: 0,
        };
        // Each group's first fallback, should its solve ever fail before one succeeded: its
        // value at its own point. A group that cannot be solved even there is a bad plan.
        for group in 0..n {
            let (tick, a) = engine.activations(self.cond_ticks[group]);
            engine.held[group] = engine
                .group_mean(group, tick, &a)
                .ok_or(PrimitiveError::Singular)?;
        }
        let replanner = Replanner {
            planner: self,
            updates: updates_tx,
            retired: retired_rx,
        };
        Ok((engine, replanner))
    }
}

/// The unconditioned marginal of `p` at every tick: μ = Ψᵀ μ_w and S[d][e] = φᵀ Σ_w[d,e] φ.
fn base_marginals<const D: usize>(
    p: &Primitive,
    phi: &[f64],
    k: usize,
) -> (Vec<[f64; D]>, Vec<[[f64; D]; D]>) {
    let mean_w = p.weight_mean().as_slice();
    let cov_w = p.weight_cov();
    let n = D * k;
    let cov = cov_w.as_slice(); // column-major, n × n
    let ticks = phi.len() / k;
    let mut means = Vec::with_capacity(ticks);
    let mut covs = Vec::with_capacity(ticks);
    let mut tmp = vec![0.0; n];
    for row in phi.chunks_exact(k) {
        let mut m = [0.0; D];
        for (d, md) in m.iter_mut().enumerate() {
            *md = (0..k).map(|i| row[i] * mean_w[d * k + i]).sum();
        }
        let mut s = [[0.0; D]; D];
        for e in 0..D {
            // tmp = Σ_w[:, e-block] φ
            for (r, t) in tmp.iter_mut().enumerate() {
                *t = (0..k).map(|i| cov[(e * k + i) * n + r] * row[i]).sum();
            }
            for d in 0..=e {
                let v: f64 = (0..k).map(|i| row[i] * tmp[d * k + i]).sum();
                s[d][e] = v;
                s[e][d] = v;
            }
        }
        means.push(m);
        covs.push(s);
    }
    (means, covs)
}

/// Re-conditions groups off the tick thread and hands the result to the [`TickEngine`].
pub struct Replanner<const D: usize> {
    planner: Planner<D>,
    updates: Producer<Update<D>>,
    retired: Consumer<Table<D>>,
}

impl<const D: usize> Replanner<D> {
    /// UpdatePrim for one group: conditions primitive Q[group] on `actuation` at T_cond[group]
    /// into a recycled table and sends it to the tick, which swaps it in while b_group = 0.
    /// Never blocks: while `n` updates already wait (the tick is not evaluating this set, e.g.
    /// in HOLD) it is refused with [`EngineError::Busy`]; once the tick engine is gone, with
    /// [`EngineError::Disconnected`].
    pub fn recondition(&mut self, group: usize, actuation: &[f64; D]) -> Result<(), EngineError> {
        let mut table = match self.retired.pop() {
            Ok(t) => t,
            Err(_) => Table::zeroed(self.planner.timeline.ticks()),
        };
        self.planner.condition(group, actuation, &mut table)?;
        if self.updates.is_abandoned() {
            return Err(EngineError::Disconnected);
        }
        match self.updates.push(Update { group, table }) {
            Ok(()) => Ok(()),
            // The table is freed here, on this thread, never on the tick's.
            Err(PushError::Full(_)) => Err(EngineError::Busy(self.updates.buffer().capacity())),
        }
    }
}

/// Evaluates Eq. 11 on the controller's tick thread.
pub struct TickEngine<const D: usize> {
    schedule: Schedule,
    timeline: Timeline,
    /// The unconditioned marginals of each primitive, shared by every group.
    base: Vec<Table<D>>,
    /// Per group: its primitive Q[n] conditioned at T_cond[n].
    conditioned: Vec<Table<D>>,
    /// Re-conditioned tables waiting for their group to be inactive.
    pending: Vec<Option<Table<D>>>,
    pending_count: usize,
    updates: Consumer<Update<D>>,
    retired: Producer<Table<D>>,
    /// Per group: its last μ*_i that solved, held when a solve fails.
    held: Vec<[f64; D]>,
    /// Group evaluations whose solve failed and were held.
    held_count: u64,
    /// Re-conditioned tables swapped in.
    applied: u64,
}

impl<const D: usize> TickEngine<D> {
    pub fn timeline(&self) -> &Timeline {
        &self.timeline
    }

    pub fn schedule(&self) -> &Schedule {
        &self.schedule
    }

    /// One controller tick of an execution: takes in re-conditioned groups that are inactive at
    /// this tick (every waiting group at tick 0, where nothing of the execution has played yet),
    /// then evaluates v. Allocates nothing, locks nothing, frees nothing.
    pub fn tick(&mut self, tick: usize) -> [f64; D] {
        self.take_updates((tick > 0).then_some(tick));
        self.evaluate_holding(tick)
    }

    /// One tick of the rest before an execution (or between two): takes in every waiting
    /// re-conditioned group, whatever its b, then evaluates v(0), the rest's target. Only v(0)
    /// can move, and the controller's slew limit smooths that. So every estimate that arrives
    /// before its group's next execution starts is in force in that execution, even a group
    /// active all along (a set of one point, b_0 = 1).
    pub fn rest(&mut self) -> [f64; D] {
        self.take_updates(None);
        self.evaluate_holding(0)
    }

    /// Whether any re-conditioned group still waits for its window to pass.
    pub fn has_pending(&self) -> bool {
        self.pending_count > 0
    }

    /// Re-conditioned tables swapped in so far.
    pub fn applied(&self) -> u64 {
        self.applied
    }

    /// Group evaluations so far whose solve failed, so that the group's last good value was
    /// held instead.
    pub fn held_solves(&self) -> u64 {
        self.held_count
    }

    /// Takes in what the replanner sent, then swaps in the waiting groups that are inactive at
    /// `tick` (every one if `None`). A table leaves only through the retired ring, and only when
    /// it has room: otherwise the swap waits for the next tick, so nothing is ever freed here.
    fn take_updates(&mut self, tick: Option<usize>) {
        while let Ok(u) = self.updates.peek() {
            let group = u.group;
            if self.pending[group].is_some() && self.retired.is_full() {
                break;
            }
            let Ok(Update { group, table }) = self.updates.pop() else {
                break;
            };
            // A newer estimate for the same group supersedes one still waiting.
            match self.pending[group].replace(table) {
                Some(old) => self.retire(old),
                None => self.pending_count += 1,
            }
        }
        if self.pending_count == 0 {
            return;
        }
        let active = tick.map(|k| {
            self.schedule
                .groups(self.timeline.time_of(k.min(self.timeline.ticks() - 1)))
        });
        for group in 0..self.pending.len() {
            if self.retired.is_full() {
                break;
            }
            if active.is_none_or(|a| a.weight_of(group) == 0.0)
                && let Some(mut table) = self.pending[group].take()
            {
                std::mem::swap(&mut self.conditioned[group], &mut table);
                self.pending_count -= 1;
                self.applied += 1;
                self.retire(table);
            }
        }
    }

    /// Only called with room in the ring (checked by the caller), which the replanner drains
    /// to reuse the tables; once it is gone they are freed with the engine, off the tick thread.
    fn retire(&mut self, table: Table<D>) {
        let sent = self.retired.push(table).is_ok();
        debug_assert!(sent, "the retired ring had room");
    }

    /// a_j at a tick (clamped to the timeline).
    fn activations(&self, tick: usize) -> (usize, [f64; MAX_PRIMITIVES]) {
        let tick = tick.min(self.timeline.ticks() - 1);
        let mut a = [0.0; MAX_PRIMITIVES];
        self.schedule.a(self.timeline.time_of(tick), &mut a);
        (tick, a)
    }

    /// μ*_i = (Σ_j a_j Λ_ij)⁻¹ Σ_j a_j Λ_ij μ_ij of one group; `None` if the solve fails.
    fn group_mean(&self, group: usize, tick: usize, a: &[f64; MAX_PRIMITIVES]) -> Option<[f64; D]> {
        let q = self.schedule.assignment();
        let mut lam = [[0.0; D]; D];
        let mut eta = [0.0; D];
        for (j, (&aj, base)) in a.iter().zip(&self.base).enumerate() {
            let table = if j == q[group] {
                &self.conditioned[group]
            } else {
                base
            };
            let e = &table.entries[tick];
            for d in 0..D {
                // Only the lower triangle: Cholesky reads nothing else.
                for c in 0..=d {
                    lam[d][c] += aj * e.precision[d][c];
                }
                eta[d] += aj * e.shifted[d];
            }
        }
        // Σ_j a_j Λ_j is positive definite in exact arithmetic (every a_j ≥ floor > 0 and every
        // Λ_j is); rounding in a degenerate covariance can still break it.
        cholesky(&mut lam)?;
        let mu = cholesky_solve(&lam, eta);
        mu.iter().all(|x| x.is_finite()).then_some(mu)
    }

    /// v at a tick (Eq. 11). Ticks past the end hold the last value. A group whose solve fails
    /// contributes its last good value, as on the tick.
    pub fn evaluate(&self, tick: usize) -> [f64; D] {
        let (tick, a) = self.activations(tick);
        let mut v = [0.0; D];
        for (group, b) in self.schedule.groups(self.timeline.time_of(tick)).iter() {
            let mu = self.group_mean(group, tick, &a).unwrap_or(self.held[group]);
            for d in 0..D {
                v[d] += b * mu[d];
            }
        }
        v
    }

    /// v at a tick, keeping each group's last good value and counting the held ones: a group
    /// whose solve fails keeps its share b_i of v at that value, instead of pulling v toward 0.
    fn evaluate_holding(&mut self, tick: usize) -> [f64; D] {
        let (tick, a) = self.activations(tick);
        let mut v = [0.0; D];
        for (group, b) in self.schedule.groups(self.timeline.time_of(tick)).iter() {
            match self.group_mean(group, tick, &a) {
                Some(mu) => self.held[group] = mu,
                None => self.held_count += 1,
            }
            for d in 0..D {
                v[d] += b * self.held[group][d];
            }
        }
        v
    }
}

fn unit<const D: usize>(e: usize) -> [f64; D] {
    let mut u = [0.0; D];
    u[e] = 1.0;
    u
}

/// In-place Cholesky: the lower triangle of `a` becomes L with A = L Lᵀ. Reads only the lower
/// triangle. `None` if A is not positive definite.
fn cholesky<const D: usize>(a: &mut [[f64; D]; D]) -> Option<()> {
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

/// Solves L Lᵀ x = b with the factor from [`cholesky`].
fn cholesky_solve<const D: usize>(l: &[[f64; D]; D], mut b: [f64; D]) -> [f64; D] {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::promp::{Basis, Demonstration, TrainConfig};

    const D: usize = 6;
    const RATE: f64 = 50.0;

    fn primitive(offset: f64) -> Primitive {
        let demos: Vec<Demonstration> = (0..8)
            .map(|i| {
                let times: Vec<f64> = (0..50).map(|s| 4.0 * s as f64 / 49.0).collect();
                let values = DMatrix::from_fn(50, D, |r, d| {
                    offset + 0.1 * (times[r] + 0.3 * d as f64 + 0.05 * i as f64).sin()
                });
                Demonstration::new(times, values)
            })
            .collect();
        Primitive::train(
            Basis::new(5, None).unwrap(),
            &demos,
            &TrainConfig::default(),
        )
        .unwrap()
    }

    /// Two points (1 s and 3 s) over 4 s at 50 Hz, on two primitives.
    fn start() -> (TickEngine<D>, Replanner<D>) {
        Planner::<D>::new(
            vec![primitive(0.4), primitive(0.6)],
            &[1.0, 3.0],
            &[0, 1],
            Timeline::new(4.0, RATE).unwrap(),
            ActivationConfig::default(),
            1e-6,
        )
        .unwrap()
        .start(&[[0.5; D], [0.55; D]])
        .unwrap()
    }

    /// Makes group `group`'s solve fail from tick `from` on: its own primitive's precision turns
    /// negative definite, as a covariance degenerate enough to break the Cholesky would.
    fn break_group(engine: &mut TickEngine<D>, group: usize, from: usize) {
        for e in &mut engine.conditioned[group].entries[from..] {
            for (d, row) in e.precision.iter_mut().enumerate() {
                *row = [0.0; D];
                row[d] = -1e9;
            }
        }
    }

    fn close(a: &[f64; D], b: &[f64; D], tol: f64) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
    }

    #[test]
    fn a_group_whose_solve_fails_holds_its_last_good_value_and_is_counted() {
        let (mut engine, _r) = start();
        let (mut intact, _ri) = start();
        let k1 = engine.timeline.tick_of(1.0);
        for k in 0..=k1 {
            assert_eq!(engine.tick(k), intact.tick(k));
        }
        let held = engine.held[0];
        break_group(&mut engine, 0, k1 + 1);
        assert_eq!(engine.held_solves(), 0);

        // Inside group 0's window (b_0 = 1): v holds group 0's last good value, exactly.
        let window_end = engine.timeline.tick_of(1.0 + 0.1);
        for (n, k) in (k1 + 1..=window_end).enumerate() {
            assert_eq!(engine.tick(k), held, "tick {k}");
            assert_eq!(engine.held_solves(), n as u64 + 1);
            intact.tick(k);
        }
        let before = engine.held_solves();

        // Handing over to group 1: group 0 keeps its b_0 share at the held value, so v stays
        // near the intact engine's (dropping the share would pull v up to b_0 · 0.5 toward 0;
        // the held value is only as stale as the trajectory's drift).
        let k3 = engine.timeline.tick_of(3.0 - 0.1);
        let mut handing_over = 0;
        for k in window_end + 1..k3 {
            let b0 = engine.schedule.b(0, engine.timeline.time_of(k));
            let (v, want) = (engine.tick(k), intact.tick(k));
            assert!(close(&v, &want, 0.1), "tick {k}: {v:?} vs {want:?}");
            if b0 > 0.0 {
                handing_over += 1;
                let one = intact.group_mean(1, k, &intact.activations(k).1).unwrap();
                let expect: [f64; D] = std::array::from_fn(|d| b0 * held[d] + (1.0 - b0) * one[d]);
                assert!(close(&v, &expect, 1e-12), "tick {k}");
            }
        }
        assert!(handing_over > 10);
        assert_eq!(engine.held_solves() - before, handing_over);
        // Group 1's own solves are fine: nothing more is counted once group 0 is inactive.
        let count = engine.held_solves();
        engine.tick(engine.timeline.tick_of(3.0));
        assert_eq!(engine.held_solves(), count);
    }

    #[test]
    fn the_tick_frees_nothing_when_the_retired_ring_is_full() {
        let (mut engine, mut replanner) = start();
        replanner.recondition(1, &[0.7; D]).unwrap();
        replanner.recondition(0, &[0.3; D]).unwrap();
        // Fill the retired ring, as if the replanner had not drained it.
        let capacity = engine.retired.buffer().capacity();
        let fill = |engine: &mut TickEngine<D>| {
            while !engine.retired.is_full() {
                engine.retire(Table::zeroed(1));
            }
        };
        fill(&mut engine);
        let before = engine.evaluate(engine.timeline.tick_of(3.0));
        // Group 1 is inactive at tick 1, but its old table has nowhere to go: nothing is
        // swapped (nor freed); the updates wait.
        engine.tick(1);
        engine.rest();
        assert_eq!(engine.applied(), 0);
        assert_eq!(engine.evaluate(engine.timeline.tick_of(3.0)), before);
        // A newer estimate for a waiting group waits in its ring too.
        replanner.recondition(1, &[0.8; D]).unwrap();
        fill(&mut engine);
        engine.tick(1);
        assert_eq!(engine.pending_count, 2);
        assert_eq!(engine.updates.slots(), 1);

        // Room again: the rest takes in all of them, each old table goes back.
        for _ in 0..capacity {
            replanner.retired.pop().unwrap();
        }
        engine.rest();
        assert_eq!(engine.applied(), 2);
        assert!(!engine.has_pending() && engine.updates.is_empty());
        // 1 superseded + 2 replaced.
        assert_eq!(replanner.retired.slots(), 3);
        let v = engine.evaluate(engine.timeline.tick_of(3.0));
        assert!(close(&v, &[0.8; D], 1e-3), "{v:?}");
    }
}
