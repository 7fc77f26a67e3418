//! Eq. 11 on the tick thread.

use super::table::{cholesky, cholesky_solve};
use super::*;

/// Evaluates Eq. 11 on the controller's tick thread.
pub struct Blend<const D: usize> {
    pub(super) schedule: Schedule,
    pub(super) timeline: Timeline,
    /// The unconditioned marginals of each primitive, shared by every group.
    pub(super) base: Vec<Table<D>>,
    /// Per group: its primitive Q[n] conditioned at T_cond[n].
    pub(super) conditioned: Vec<Table<D>>,
    /// Re-conditioned tables waiting for their group to be inactive.
    pub(super) pending: Vec<Option<Table<D>>>,
    pub(super) pending_count: usize,
    pub(super) updates: Consumer<Update<D>>,
    pub(super) retired: Producer<Table<D>>,
    /// Per group: its last μ*_i that solved, held when a solve fails.
    pub(super) held: Vec<[f64; D]>,
    /// Group evaluations whose solve failed and were held.
    pub(super) held_count: u64,
    /// Re-conditioned tables swapped in.
    pub(super) applied: u64,
}

impl<const D: usize> Blend<D> {
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

    /// What `group`'s table in force was conditioned on. A table is swapped in only while its
    /// group is inactive, so at the group's T_cond this is what its whole window ran on.
    pub fn conditioned_on(&self, group: usize) -> ConditionedOn<D> {
        self.conditioned[group].on
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
    /// to reuse the tables; once it is gone they are freed with the blend, off the tick thread.
    pub(super) fn retire(&mut self, table: Table<D>) {
        let sent = self.retired.push(table).is_ok();
        debug_assert!(sent, "the retired ring had room");
    }

    /// a_j at a tick (clamped to the timeline).
    pub(super) fn activations(&self, tick: usize) -> (usize, [f64; MAX_PRIMITIVES]) {
        let tick = tick.min(self.timeline.ticks() - 1);
        let mut a = [0.0; MAX_PRIMITIVES];
        self.schedule.a(self.timeline.time_of(tick), &mut a);
        (tick, a)
    }

    /// μ*_i = (Σ_j a_j Λ_ij)⁻¹ Σ_j a_j Λ_ij μ_ij of one group; `None` if the solve fails.
    pub(super) fn group_mean(
        &self,
        group: usize,
        tick: usize,
        a: &[f64; MAX_PRIMITIVES],
    ) -> Option<[f64; D]> {
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

    /// v at a tick (Eq. 11) without changing the blend, for the unit tests only (the controller
    /// and the integration tests go through `tick`). Ticks past the end hold the last value. A
    /// group whose solve fails contributes its last good value, as on the tick.
    #[cfg(test)]
    pub(super) fn evaluate(&self, tick: usize) -> [f64; D] {
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
