//! CACLA-MTL, the paper's Alg. 1: one actor-critic shared by every conditioning point, which
//! estimates the actuation that puts the end effector on each point and corrects it online.
//! Pure math: no I/O, no clock (pre-training is given its budget as a closure).
//!
//! The critic V(p_desired, p_current) and the actor Ac(p_desired) → N actuations are linear
//! in normalised RBF features on sparse lattices ([`softarm_kinematics::rbf`]). Per point n the learner keeps
//! k_n, the last reached position and the last error. Three corrections to the printed paper
//! (see docs/ARCHITECTURE.md, "Where the paper lives") are marked `Correction` below.

use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use softarm_kinematics::forward::ForwardModel;
use softarm_kinematics::rbf::{Features, Lattice, LinearRbf, RbfError};
use softarm_sections::learner::{LearnerConfig, PretrainConfig};
use softarm_space::{Position, distance};

/// Alg. 1's memory of one conditioning point: k_n, and the state and error of its last visit,
/// which the next visit's δ needs. Held by whoever visits the points, not by [`CaclaMtl`] (which
/// holds what every point shares, the actor and the critic): the online learner keeps it in its
/// one per-point state (`online::Point`), pre-training in its own list. Of the running set only:
/// never stored in a bundle or checkpoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointMemory {
    /// k_n: visits so far.
    pub visits: u64,
    pub target: Position,
    /// Where the end effector was at the last visit.
    pub position: Position,
    /// g at the last visit (m).
    pub error: f64,
}

/// The outcome of one visit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Visit {
    /// g = ‖p_desired − p_reached‖ (m).
    pub error: f64,
    /// δ, or `None` on a first visit.
    pub td_error: Option<f64>,
    pub actor_updated: bool,
}

/// Everything that makes a learner what it is (of an arm of `N` actuators): what a bundle or a
/// checkpoint saves, restored exactly.
#[derive(Debug, Clone, PartialEq)]
pub struct LearnerState<const N: usize> {
    pub config: LearnerConfig,
    pub actor: Vec<(u64, [f64; N])>,
    pub critic: Vec<(u64, [f64; 1])>,
}

/// The critic V(p_desired, p_current): linear in normalised RBF features on a sparse 6-D
/// lattice over (p_desired, p_current).
pub struct Critic {
    weights: LinearRbf<1>,
    /// φ(s) of the last state evaluated; [`Critic::update`] moves along it.
    features: Features,
}

impl Critic {
    fn new(weights: LinearRbf<1>) -> Self {
        Self {
            weights,
            features: Features::default(),
        }
    }

    /// V(p_desired, p_current).
    pub fn value(&mut self, target: &Position, current: &Position) -> f64 {
        let s = [
            target[0], target[1], target[2], current[0], current[1], current[2],
        ];
        self.weights.lattice().features(&s, &mut self.features);
        self.weights.value(&self.features)[0]
    }

    /// V(s) += α δ for the state last passed to [`Critic::value`].
    fn update(&mut self, rate: f64, td: f64) {
        self.weights.update(&self.features, rate, &[td]);
    }
}

/// The actor Ac(p_desired) → `N` actuations: linear in normalised RBF features on a sparse 3-D
/// lattice over p_desired.
pub struct Actor<const N: usize> {
    weights: LinearRbf<N>,
    features: Features,
}

impl<const N: usize> Actor<N> {
    fn new(weights: LinearRbf<N>) -> Self {
        Self {
            weights,
            features: Features::default(),
        }
    }

    /// Ac(p_desired), clipped to [0, 1].
    pub fn actuation(&mut self, target: &Position) -> [f64; N] {
        self.weights.lattice().features(target, &mut self.features);
        self.weights
            .value(&self.features)
            .map(|v| v.clamp(0.0, 1.0))
    }

    /// Moves Ac(p_desired) the fraction `fraction` of the way toward `action` (normalised LMS).
    fn move_toward(&mut self, target: &Position, fraction: f64, action: &[f64; N]) {
        self.weights.lattice().features(target, &mut self.features);
        self.weights.move_toward(&self.features, fraction, action);
    }
}

/// The actor's 3-D and the critic's 6-D lattice of `config` (each a valid config makes).
pub fn lattices(config: &LearnerConfig) -> Result<(Lattice, Lattice), RbfError> {
    let (lo, hi) = (config.workspace_min_m, config.workspace_max_m);
    let actor = Lattice::new(
        &lo,
        &hi,
        &[config.actor_spacing_m; 3],
        config.actor_width,
        config.actor_span,
    )?;
    let lo6 = [lo[0], lo[1], lo[2], lo[0], lo[1], lo[2]];
    let hi6 = [hi[0], hi[1], hi[2], hi[0], hi[1], hi[2]];
    let critic = Lattice::new(
        &lo6,
        &hi6,
        &[config.critic_spacing_m; 6],
        config.critic_width,
        config.critic_span,
    )?;
    Ok((actor, critic))
}

/// CACLA-MTL: one actor and one critic shared by every conditioning point. Each point's own
/// memory ([`PointMemory`]) is passed in by the caller.
pub struct CaclaMtl<const N: usize> {
    config: LearnerConfig,
    actor: Actor<N>,
    critic: Critic,
    rng: StdRng,
}

impl<const N: usize> CaclaMtl<N> {
    pub fn new(config: LearnerConfig) -> Result<Self, String> {
        config.validate()?;
        let (actor, critic) = lattices(&config).map_err(|e| e.to_string())?;
        Ok(Self {
            actor: Actor::new(LinearRbf::new(
                actor,
                [config.initial_actuation; N],
                config.actor_max_centres,
            )),
            critic: Critic::new(LinearRbf::new(critic, [0.0], config.critic_max_centres)),
            rng: StdRng::seed_from_u64(config.seed),
            config,
        })
    }

    pub fn config(&self) -> &LearnerConfig {
        &self.config
    }

    /// Centres with stored weights: (actor, critic).
    pub fn stored_centres(&self) -> (usize, usize) {
        (self.actor.weights.stored(), self.critic.weights.stored())
    }

    /// Weights dropped by the capacities since this learner started: (actor, critic).
    pub fn evicted_centres(&self) -> (u64, u64) {
        (self.actor.weights.evicted(), self.critic.weights.evicted())
    }

    /// Correction (printed paper): σ(g) = h / (1 + exp(−c (g − b))). The printed sign of b
    /// cannot shrink σ below h/2 as g → 0.
    pub fn sigma(&self, error: f64) -> f64 {
        let c = &self.config;
        c.sigma_max / (1.0 + (-c.sigma_slope_per_m * (error - c.sigma_mid_m)).exp())
    }

    /// Ac(p_desired), clipped to [0, 1].
    pub fn actor(&mut self, target: &Position) -> [f64; N] {
        self.actor.actuation(target)
    }

    /// V(p_desired, p_current).
    pub fn value(&mut self, target: &Position, current: &Position) -> f64 {
        self.critic.value(target, current)
    }

    /// The actuation to try at a point whose memory is `memory`: a ~ N(Ac(p_desired),
    /// σ(g_prev)² I), clipped to [0, 1]. Without exploration, or on a first visit (no g_prev
    /// yet), the actor's mean.
    pub fn act(
        &mut self,
        memory: Option<&PointMemory>,
        target: &Position,
        explore: bool,
    ) -> [f64; N] {
        let mean = self.actor(target);
        let prev = memory.filter(|m| m.target == *target).copied();
        match prev {
            Some(m) if explore => {
                let sigma = self.sigma(m.error);
                mean.map(|v| {
                    let n: f64 = StandardNormal.sample(&mut self.rng);
                    (v + sigma * n).clamp(0.0, 1.0)
                })
            }
            _ => mean,
        }
    }

    /// One visit of Alg. 1: `action` was executed for the point whose memory is `memory` and
    /// the end effector reached `reached`. r = g_prev − g; δ = r + γ V(p_d, p_reached) −
    /// V(p_d, p_prev); the critic always moves by α_V δ; the actor moves toward `action` only if
    /// δ > 0. `memory` becomes this visit's.
    pub fn observe(
        &mut self,
        memory: &mut Option<PointMemory>,
        target: &Position,
        action: &[f64; N],
        reached: &Position,
    ) -> Visit {
        self.visit(memory, target, action, reached, true)
    }

    /// A visit that moves the critic and `memory` as [`CaclaMtl::observe`] does, but never the
    /// actor: the actor stays what pre-training made it, the prior of an arm whose changes are
    /// learnt elsewhere (the online learner's corrections under gauss-newton, which can be
    /// forgotten when the arm changes; an actor that absorbed the actions of an arm that is gone
    /// is wrong on the next).
    pub fn judge(
        &mut self,
        memory: &mut Option<PointMemory>,
        target: &Position,
        action: &[f64; N],
        reached: &Position,
    ) -> Visit {
        self.visit(memory, target, action, reached, false)
    }

    fn visit(
        &mut self,
        memory: &mut Option<PointMemory>,
        target: &Position,
        action: &[f64; N],
        reached: &Position,
        move_actor: bool,
    ) -> Visit {
        let error = distance(target, reached);
        let prev = memory.filter(|m| m.target == *target);
        let visits = prev.map_or(0, |m| m.visits) + 1;
        *memory = Some(PointMemory {
            visits,
            target: *target,
            position: *reached,
            error,
        });
        // Correction: no TD update on the first visit of a point, which has no previous state.
        let Some(prev) = prev else {
            return Visit {
                error,
                td_error: None,
                actor_updated: false,
            };
        };
        // Correction: both states come from this point's own history (the printed Eq. 6 mixes
        // in another point's state).
        let reward = prev.error - error;
        let next_value = self.value(target, reached);
        // Evaluated last, so the critic's update moves V(s_prev).
        let prev_value = self.value(target, &prev.position);
        let td = reward + self.config.gamma * next_value - prev_value;
        self.critic.update(self.config.alpha_critic, td);
        let actor_updated = move_actor && td > 0.0;
        if actor_updated {
            // Ac(p_desired) moves the fraction α_Ac of the way toward the executed action.
            self.actor
                .move_toward(target, self.config.alpha_actor, action);
        }
        Visit {
            error,
            td_error: Some(td),
            actor_updated,
        }
    }

    /// Supervised warm start of the actor on demonstrated (position, actuation) pairs: the
    /// demonstrations say which actuation reaches which position.
    pub fn imitate(&mut self, positions: &[Position], actuations: &[[f64; N]], passes: usize) {
        for _ in 0..passes {
            for (p, a) in positions.iter().zip(actuations) {
                // A running average of the demonstrated actuations near p.
                self.actor.move_toward(p, 0.2, a);
            }
        }
    }

    pub fn state(&self) -> LearnerState<N> {
        LearnerState {
            config: self.config,
            actor: self.actor.weights.to_entries(),
            critic: self.critic.weights.to_entries(),
        }
    }

    /// A learner from saved state. The exploration stream restarts from the config's seed.
    pub fn restore(state: &LearnerState<N>) -> Result<Self, String> {
        let mut l = Self::new(state.config)?;
        let (actor, critic) = lattices(&state.config).map_err(|e| e.to_string())?;
        l.actor = Actor::new(
            LinearRbf::from_entries(
                actor,
                [state.config.initial_actuation; N],
                state.config.actor_max_centres,
                &state.actor,
            )
            .map_err(|e| format!("actor: {e}"))?,
        );
        l.critic = Critic::new(
            LinearRbf::from_entries(
                critic,
                [0.0],
                state.config.critic_max_centres,
                &state.critic,
            )
            .map_err(|e| format!("critic: {e}"))?,
        );
        Ok(l)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PretrainReport {
    pub epochs: u64,
    pub converged_epochs: u64,
    pub updates: u64,
}

/// Runs epochs against `model` until `max_epochs` or until `keep_going()` says stop (checked
/// once per epoch: the caller's clock, not ours). Targets are drawn from `pool`.
pub fn pretrain<const N: usize>(
    learner: &mut CaclaMtl<N>,
    model: &impl ForwardModel<N>,
    pool: &[Position],
    config: &PretrainConfig,
    mut keep_going: impl FnMut(&PretrainReport) -> bool,
) -> PretrainReport {
    let mut report = PretrainReport::default();
    if pool.is_empty() || config.targets_per_epoch == 0 {
        return report;
    }
    let mut targets = vec![[0.0; 3]; config.targets_per_epoch];
    let mut memory = vec![None; config.targets_per_epoch];
    while report.epochs < config.max_epochs && keep_going(&report) {
        memory.fill(None);
        for t in &mut targets {
            *t = pool[learner.rng.random_range(0..pool.len())];
        }
        let mut converged = false;
        for _ in 0..config.visits_per_epoch {
            let mut worst = 0.0f64;
            for (target, memory) in targets.iter().zip(&mut memory) {
                let a = learner.act(memory.as_ref(), target, true);
                let reached = model.position(&a);
                let v = learner.observe(memory, target, &a, &reached);
                report.updates += v.td_error.is_some() as u64;
                worst = worst.max(v.error);
            }
            if worst < config.threshold_m {
                converged = true;
                break;
            }
        }
        report.epochs += 1;
        report.converged_epochs += converged as u64;
    }
    report
}

/// Errors (m) of the actor's mean on `targets`, executed on `plant`.
pub fn evaluate<const N: usize>(
    learner: &mut CaclaMtl<N>,
    plant: &impl ForwardModel<N>,
    targets: &[Position],
) -> Vec<f64> {
    targets
        .iter()
        .map(|t| distance(t, &plant.position(&learner.actor(t))))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::default_arm::{N, arm};

    /// The config's checks (`LearnerConfig::validate`, which cannot build a lattice) accept
    /// only what [`Lattice::new`] accepts: a valid config always makes its lattices, with the
    /// capacities the config asks for at least.
    #[test]
    fn a_valid_config_makes_its_lattices() {
        for span in [2, softarm_kinematics::rbf::MAX_SPAN] {
            let c = LearnerConfig {
                critic_span: span,
                actor_span: span,
                critic_max_centres: 100_000_000,
                ..Default::default()
            };
            c.validate().unwrap();
            let (actor, critic) = lattices(&c).unwrap();
            assert_eq!((actor.dim(), critic.dim()), (3, 6));
            assert!(LinearRbf::<N>::min_capacity(&actor) <= c.actor_max_centres);
            assert!(LinearRbf::<1>::min_capacity(&critic) <= c.critic_max_centres);
        }
    }

    #[test]
    fn sigma_shrinks_with_the_error() {
        let l = CaclaMtl::<N>::new(LearnerConfig::default()).unwrap();
        assert!((l.sigma(0.03) - 0.015).abs() < 1e-12);
        assert!(l.sigma(0.0) < 0.002, "{}", l.sigma(0.0));
        assert!(l.sigma(0.2) > 0.0299);
    }

    #[test]
    fn first_visit_has_no_td_update_and_targets_reset_memory() {
        let mut l = CaclaMtl::<N>::new(LearnerConfig::default()).unwrap();
        let target = [0.1, 0.0, -0.45];
        let mut memory = None;
        let a = l.act(memory.as_ref(), &target, true);
        assert!(
            a.iter().all(|v| (v - 0.5).abs() < 1e-12),
            "first visit: the untrained mean, no exploration"
        );
        let v = l.observe(&mut memory, &target, &a, &[0.0, 0.0, -0.5]);
        assert_eq!(v.td_error, None);
        assert_eq!(l.stored_centres(), (0, 0));
        let v = l.observe(&mut memory, &target, &a, &[0.05, 0.0, -0.48]);
        assert!(v.td_error.unwrap() > 0.0 && v.actor_updated);
        assert_eq!(memory.unwrap().visits, 2);
        // Another target with the same memory starts over.
        let v = l.observe(&mut memory, &[0.0, 0.1, -0.45], &a, &[0.0, 0.0, -0.5]);
        assert_eq!(v.td_error, None);
    }

    /// A learner whose critic is not zero around two points with different histories, and
    /// the two points' memories.
    fn trained_critic() -> (CaclaMtl<N>, [Position; 2], [Option<PointMemory>; 2]) {
        let mut l = CaclaMtl::<N>::new(LearnerConfig::default()).unwrap();
        let targets = [[0.1, 0.0, -0.45], [0.02, 0.08, -0.48]];
        let mut memory = [None; 2];
        let a = [0.5; 6];
        for k in 0..6 {
            for (n, (t, m)) in targets.iter().zip(&mut memory).enumerate() {
                let off = 0.02 / (k + 1) as f64 * (n + 1) as f64;
                l.observe(m, t, &a, &[t[0] + off, t[1], t[2] - off]);
            }
        }
        (l, targets, memory)
    }

    #[test]
    fn the_td_error_uses_the_points_own_previous_state_not_the_printed_mix() {
        let (mut l, t, mut memory) = trained_critic();
        let (own, other) = (memory[0].unwrap(), memory[1].unwrap());
        let reached = [t[0][0] + 0.003, t[0][1], t[0][2]];
        let g = distance(&t[0], &reached);
        let gamma = l.config().gamma;
        let next = l.value(&t[0], &reached);
        let corrected = own.error - g + gamma * next - l.value(&t[0], &own.position);
        // As printed, V(s) is of another point's state: here point 1's.
        let printed = own.error - g + gamma * next - l.value(&t[1], &other.position);
        assert!(
            l.value(&t[0], &own.position).abs() > 1e-5,
            "the critic is not zero"
        );
        assert!(
            (corrected - printed).abs() > 1e-5,
            "{corrected} vs {printed}"
        );
        let v = l.observe(&mut memory[0], &t[0], &[0.5; 6], &reached);
        assert!((v.td_error.unwrap() - corrected).abs() < 1e-12);
    }

    #[test]
    fn the_actor_moves_toward_the_action_only_when_delta_is_positive() {
        let (mut l, t, [mut memory, _]) = trained_critic();
        let before = l.actor(&t[0]);
        let action = [0.9; 6];
        // Much worse than last time: δ < 0, the actor stays.
        let v = l.observe(
            &mut memory,
            &t[0],
            &action,
            &[t[0][0] + 0.08, t[0][1], t[0][2]],
        );
        assert!(v.td_error.unwrap() <= 0.0 && !v.actor_updated, "{v:?}");
        assert_eq!(l.actor(&t[0]), before);
        // On the point: δ > 0, the actor moves toward the action.
        let v = l.observe(&mut memory, &t[0], &action, &t[0]);
        assert!(v.td_error.unwrap() > 0.0 && v.actor_updated, "{v:?}");
        let after = l.actor(&t[0]);
        assert!((0..6).all(|i| (action[i] - after[i]).abs() < (action[i] - before[i]).abs()));
    }

    #[test]
    fn state_round_trips_exactly() {
        let arm = arm();
        let mut l = CaclaMtl::<N>::new(LearnerConfig::default()).unwrap();
        let pool = [[0.1, 0.05, -0.45], [-0.05, 0.1, -0.47]];
        let cfg = PretrainConfig {
            max_epochs: 5,
            ..Default::default()
        };
        pretrain(&mut l, &arm, &pool, &cfg, |_| true);
        l.observe(&mut None, &pool[0], &[0.4; 6], &[0.1, 0.0, -0.5]);
        let state = l.state();
        let mut r = CaclaMtl::<N>::restore(&state).unwrap();
        assert_eq!(r.state(), state);
        for p in &pool {
            assert_eq!(r.actor(p), l.actor(p));
            assert_eq!(r.value(p, &[0.0, 0.0, -0.5]), l.value(p, &[0.0, 0.0, -0.5]));
        }
        let mut bad = state.clone();
        bad.actor[0].1[2] = f64::NAN;
        assert!(
            CaclaMtl::<N>::restore(&bad)
                .err()
                .unwrap()
                .contains("actor")
        );
    }

    #[test]
    fn bad_config_names_the_key() {
        let c = LearnerConfig {
            gamma: 1.5,
            ..Default::default()
        };
        assert!(
            CaclaMtl::<N>::new(c)
                .err()
                .unwrap()
                .contains("learner.gamma")
        );
    }
}
