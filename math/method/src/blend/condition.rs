//! Conditioning: a set's primitives prepared on the tick grid ([`Planner`]), and a group
//! conditioned again on a new estimate off the tick thread ([`Replanner`], UpdatePrim).

use super::table::Information;
use super::*;

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
    ) -> Result<Self, BlendError> {
        if primitives.is_empty() || primitives.len() > MAX_PRIMITIVES {
            return Err(ScheduleError::PrimitiveCount(primitives.len()).into());
        }
        let basis = primitives[0].basis().clone();
        for (index, p) in primitives.iter().enumerate() {
            if p.dofs() != D {
                return Err(BlendError::PrimitiveMismatch {
                    index,
                    why: format!("has {} DoF, the blend drives {D}", p.dofs()),
                });
            }
            if *p.basis() != basis {
                return Err(BlendError::PrimitiveMismatch {
                    index,
                    why: "uses another basis than primitive 0".into(),
                });
            }
        }
        if !(variance_floor.is_finite() && variance_floor > 0.0) {
            return Err(BlendError::NonFinite {
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
    /// `actuation` at T_cond[group], written into `into`, which remembers them as meant for
    /// `execution`.
    ///
    /// Conditioning is a rank-D update of Σ_w, so with G = Σ_w Ψ*, S* = Ψ*ᵀ G and C(t) = Ψ(t)ᵀ G
    /// each tick's marginal is μ_b + C S*⁻¹ (y* − μ_b*) and S_b − C S*⁻¹ Cᵀ: O(K·D²) per tick
    /// instead of O(K²·D²) for Ψᵀ Σ_w Ψ.
    pub fn condition(
        &self,
        group: usize,
        actuation: &[f64; D],
        execution: u32,
        into: &mut Table<D>,
    ) -> Result<(), BlendError> {
        let groups = self.schedule.points();
        if group >= groups {
            return Err(BlendError::NoSuchGroup { group, groups });
        }
        if let Some(index) = actuation.iter().position(|v| !v.is_finite()) {
            return Err(BlendError::NonFinite {
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
        into.on = ConditionedOn {
            actuation: *actuation,
            execution,
            within: false,
            beyond_reach: false,
        };
        let (gs, xs) = (g.as_slice(), x.as_slice()); // column-major
        let rows_g = D * k;
        for (tick, entry) in into.entries.iter_mut().enumerate() {
            // Eq. 11 reads a group's table only where the group is active (b_i(t) > 0 around
            // its T_cond, and the hand-overs to its neighbours): the rest is never computed,
            // which is most of a long set's ticks.
            let t = self.timeline.time_of(tick);
            if !self.schedule.groups(t).iter().any(|(g, _)| g == group) {
                continue;
            }
            let phi = &self.phi[tick * k..(tick + 1) * k];
            // C = Ψᵀ G and E = Ψᵀ Xᵀ = C S*⁻¹, each row over the basis in memory order.
            let mut c = [[0.0; D]; D];
            let mut e = [[0.0; D]; D];
            for d in 0..D {
                for b in 0..D {
                    let g_col = &gs[b * rows_g + d * k..b * rows_g + (d + 1) * k];
                    c[d][b] = phi.iter().zip(g_col).map(|(f, g)| f * g).sum();
                }
                for (i, f) in phi.iter().enumerate() {
                    let x_col = &xs[(d * k + i) * D..(d * k + i + 1) * D];
                    for b in 0..D {
                        e[d][b] += f * x_col[b];
                    }
                }
            }
            let mut mean = self.base_mean[j][tick];
            let mut cov = self.base_cov[j][tick];
            for d in 0..D {
                mean[d] += (0..D).map(|b| c[d][b] * u[b]).sum::<f64>();
                // E Cᵀ = C S*⁻¹ Cᵀ is symmetric: one triangle, mirrored.
                for b in 0..=d {
                    let v = cov[d][b] - (0..D).map(|i| e[d][i] * c[b][i]).sum::<f64>();
                    cov[d][b] = v;
                    cov[b][d] = v;
                }
            }
            *entry = Information::new(&mean, &cov, self.variance_floor);
        }
        Ok(())
    }

    /// Builds the Blend with every group conditioned on its initial estimate (for the first
    /// execution), and the replanner that re-conditions groups while it runs.
    pub fn start(self, initial: &[[f64; D]]) -> Result<(Blend<D>, Replanner<D>), BlendError> {
        let on: Vec<ConditionedOn<D>> = initial
            .iter()
            .map(|a| ConditionedOn {
                actuation: *a,
                execution: 1,
                ..ConditionedOn::NONE
            })
            .collect();
        self.start_on(&on)
    }

    /// [`Planner::start`] on `initial`, whose learner's words (`within`, `beyond_reach`) the
    /// tables carry to [`Blend::conditioned_on`](super::Blend::conditioned_on); each for the
    /// first execution, whatever its `execution` says.
    pub fn start_on(
        self,
        initial: &[ConditionedOn<D>],
    ) -> Result<(Blend<D>, Replanner<D>), BlendError> {
        let n = self.schedule.points();
        if initial.len() != n {
            return Err(BlendError::Count {
                what: "initial actuation estimates",
                expected: n,
                got: initial.len(),
            });
        }
        let base = (0..self.primitives.len())
            .map(|j| self.base_table(j))
            .collect();
        let mut conditioned = Vec::with_capacity(n);
        for (group, on) in initial.iter().enumerate() {
            let mut t = Table::zeroed(self.timeline.ticks());
            self.condition(group, &on.actuation, 1, &mut t)?;
            (t.on.within, t.on.beyond_reach) = (on.within, on.beyond_reach);
            conditioned.push(t);
        }
        // Bounded both ways: a replanner can be at most `n` updates ahead, and the retired
        // ring has room for every table that can be in flight.
        let (updates_tx, updates_rx) = RingBuffer::new(n);
        let (retired_tx, retired_rx) = RingBuffer::new(4 * n);
        let mut blend = Blend {
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
            let (tick, a) = blend.activations(self.cond_ticks[group]);
            blend.held[group] = blend
                .group_mean(group, tick, &a)
                .ok_or(PrimitiveError::Singular)?;
        }
        let replanner = Replanner {
            planner: self,
            updates: updates_tx,
            retired: retired_rx,
        };
        Ok((blend, replanner))
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

/// Re-conditions groups off the tick thread and hands the result to the [`Blend`].
pub struct Replanner<const D: usize> {
    planner: Planner<D>,
    updates: Producer<Update<D>>,
    pub(super) retired: Consumer<Table<D>>,
}

impl<const D: usize> Replanner<D> {
    /// UpdatePrim for one group: conditions primitive Q[group] on `actuation` at T_cond[group]
    /// into a recycled table and sends it to the tick, which swaps it in while b_group = 0.
    /// `execution`: the one the estimate is for (see [`ConditionedOn`]).
    /// Never blocks: while `n` updates already wait (the tick is not evaluating this set, e.g.
    /// in HOLD) it is refused with [`BlendError::Busy`]; once the Blend is gone, with
    /// [`BlendError::Disconnected`].
    pub fn recondition(
        &mut self,
        group: usize,
        actuation: &[f64; D],
        execution: u32,
    ) -> Result<(), BlendError> {
        let on = ConditionedOn {
            actuation: *actuation,
            execution,
            within: false,
            beyond_reach: false,
        };
        self.recondition_on(group, &on)
    }

    /// [`Replanner::recondition`] on `on`, whose every word the table carries to
    /// [`Blend::conditioned_on`](super::Blend::conditioned_on).
    pub fn recondition_on(
        &mut self,
        group: usize,
        on: &ConditionedOn<D>,
    ) -> Result<(), BlendError> {
        let mut table = match self.retired.pop() {
            Ok(t) => t,
            Err(_) => Table::zeroed(self.planner.timeline.ticks()),
        };
        self.planner
            .condition(group, &on.actuation, on.execution, &mut table)?;
        (table.on.within, table.on.beyond_reach) = (on.within, on.beyond_reach);
        if self.updates.is_abandoned() {
            return Err(BlendError::Disconnected);
        }
        match self.updates.push(Update { group, table }) {
            Ok(()) => Ok(()),
            // The table is freed here, on this thread, never on the tick's.
            Err(PushError::Full(_)) => Err(BlendError::Busy(self.updates.buffer().capacity())),
        }
    }
}
