//! The learner's parameters: the `[learner]` section (Alg. 1's hyper-parameters, read by
//! `softarm_learning::cacla`, and the online learner's settings, read by
//! `softarm_learning::online`: which algorithm runs, and the steps of the Gauss-Newton one) and
//! `[pretrain]`.
//!
//! Here, with the config's other sections as plain data, not beside the code that reads them:
//! the config (and so every process, the drivers too) reads these sections, and must not link
//! the learning code nor the math for it (Cargo enforces it; `tests/layering.rs` checks it). One type for the `[learner]` section, so
//! neither learning module imports the other's config: `cacla` reads the Alg. 1 fields,
//! `online` the rest. Not split in two: the section's keys sit
//! side by side in the TOML (and `deny_unknown_fields` does not work with `#[serde(flatten)]`),
//! and bundles and checkpoints store this type; its online-only fields are never serialised, so
//! the stored form is exactly Alg. 1's.

use serde::{Deserialize, Serialize};

use softarm_space::Position;

use crate::bounds::Lower::{Closed, Open};
use crate::bounds::{count, within};

/// Most centres a lattice evaluates per axis (`learner.critic_span`, `learner.actor_span`):
/// what `softarm_kinematics::rbf::Lattice` accepts.
pub const MAX_SPAN: usize = 9;

/// The smallest useful capacity of a linear RBF on a lattice of `dim` dimensions evaluating
/// `span` centres per axis: eight updates' worth of centres, so an eviction never reaches the
/// centres the update that caused it has just trained
/// (`softarm_kinematics::rbf::LinearRbf::min_capacity`).
pub const fn min_capacity(span: usize, dim: usize) -> usize {
    8 * span.pow(dim as u32)
}

/// Hyper-parameters; the `[learner]` section of the config. A key left out takes the starting
/// value the paper's method suggests (α_V 0.1, α_Ac 0.2, γ 0.5, b 30 mm, c 100 /m, lattices
/// 30/15 mm; h 0.03, see `sigma_max`); the shipped config sets some otherwise (the defaults
/// below are its values).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct LearnerConfig {
    /// α_V
    pub alpha_critic: f64,
    /// α_Ac
    pub alpha_actor: f64,
    /// γ
    pub gamma: f64,
    /// h: the largest exploration σ (normalised actuation). The usual starting value 0.15 is
    /// unstable on the suggested arm: σ = 0.15 moves the end effector ~135 mm, so the next
    /// σ(g) is h again and the error never falls (loop gain ≈ 0.9 m · h c / 4 ≈ 3.4). 0.03 keeps
    /// that gain below 1.
    pub sigma_max: f64,
    /// b: the error (m) at which σ is h/2.
    pub sigma_mid_m: f64,
    /// c: steepness of σ(g) (1/m).
    pub sigma_slope_per_m: f64,
    /// Critic lattice spacing over (p_desired, p_current) (m); the paper: 30 mm.
    pub critic_spacing_m: f64,
    /// Actor lattice spacing over p_desired (m); the paper: 15 mm.
    pub actor_spacing_m: f64,
    /// Gaussian σ of the critic's lattice functions, in cells.
    pub critic_width: f64,
    /// Gaussian σ of the actor's lattice functions, in cells.
    pub actor_width: f64,
    /// Centres evaluated per axis (2: the two bracketing the input, 3: the nearest and its
    /// neighbours).
    pub critic_span: usize,
    /// The same for the actor's lattice.
    pub actor_span: usize,
    /// The box the lattices span (m): the arm's reachable workspace.
    pub workspace_min_m: Position,
    /// The box's upper corner (m).
    pub workspace_max_m: Position,
    /// The actuation an untrained actor proposes.
    pub initial_actuation: f64,
    /// Most weights the actor's and the critic's lattices keep; past that the least recently
    /// trained are dropped. Settings of the running learner (never written into a bundle):
    /// they bound its memory over many sets (the default model stores ~4k and ~30k).
    #[serde(skip_serializing)]
    pub actor_max_centres: usize,
    /// The critic's, as `actor_max_centres`.
    #[serde(skip_serializing)]
    pub critic_max_centres: usize,
    /// Seeds the exploration noise.
    pub seed: u64,
    /// Which online learner runs ([`crate::online`]): `gauss-newton` or the paper's. Like
    /// `gauss_newton`, a setting of the running learner, read from the config and never written
    /// into a model bundle or checkpoint, so changing these never invalidates a trained model.
    #[serde(skip_serializing)]
    pub algorithm: Algorithm,
    /// `[learner.gauss_newton]`: the steps of [`Algorithm::GaussNewton`]. `correction` is its
    /// former name, still read; softarm-config warns when a file uses it.
    #[serde(skip_serializing, alias = "correction")]
    pub gauss_newton: GaussNewtonConfig,
}

impl Default for LearnerConfig {
    fn default() -> Self {
        Self {
            alpha_critic: 0.1,
            alpha_actor: 0.2,
            gamma: 0.5,
            sigma_max: 0.03,
            sigma_mid_m: 0.03,
            sigma_slope_per_m: 100.0,
            critic_spacing_m: 0.03,
            actor_spacing_m: 0.015,
            critic_width: 0.5,
            actor_width: 0.5,
            critic_span: 2,
            actor_span: 3,
            // The reachable box of the default arm, with a margin.
            workspace_min_m: [-0.45, -0.45, -0.6],
            workspace_max_m: [0.45, 0.45, 0.05],
            initial_actuation: 0.5,
            // ~17 and ~13 MiB at most; the actor's covers the default workspace's whole lattice.
            actor_max_centres: 200_000,
            critic_max_centres: 500_000,
            seed: 1,
            algorithm: Algorithm::default(),
            gauss_newton: GaussNewtonConfig::default(),
        }
    }
}

impl LearnerConfig {
    /// Checks every field; the error is `learner.KEY: message`. Spans and lattice sizes are
    /// what `softarm_kinematics::rbf::Lattice::new` accepts (so the learner's lattices, the
    /// actor's 3-D and the critic's 6-D over the workspace, can always be made).
    pub fn validate(&self) -> Result<(), String> {
        let bad = |key: &str, m: String| Err(format!("learner.{key}: {m}"));
        let unit = [
            ("alpha_critic", self.alpha_critic),
            ("alpha_actor", self.alpha_actor),
            ("gamma", self.gamma),
            ("initial_actuation", self.initial_actuation),
        ];
        for (k, v) in unit {
            if !(0.0..=1.0).contains(&v) {
                return bad(k, format!("must be in [0, 1], got {v:?}"));
            }
        }
        // (key, value, largest, unit)
        let positive = [
            ("sigma_max", self.sigma_max, 1.0, ""),
            ("sigma_mid_m", self.sigma_mid_m, 1.0, " m"),
            ("sigma_slope_per_m", self.sigma_slope_per_m, 1e4, " /m"),
            ("critic_width", self.critic_width, 10.0, " cells"),
            ("actor_width", self.actor_width, 10.0, " cells"),
        ];
        for (k, v, max, u) in positive {
            if !(v.is_finite() && v > 0.0 && v <= max) {
                return bad(k, format!("must be in (0, {max}]{u}, got {v:?}"));
            }
        }
        for (k, v) in [
            ("critic_spacing_m", self.critic_spacing_m),
            ("actor_spacing_m", self.actor_spacing_m),
        ] {
            if !(v.is_finite() && (0.001..=1.0).contains(&v)) {
                return bad(k, format!("must be in [0.001, 1] m, got {v:?}"));
            }
        }
        let max_span = MAX_SPAN;
        for (k, v) in [
            ("critic_span", self.critic_span),
            ("actor_span", self.actor_span),
        ] {
            if !(2..=max_span).contains(&v) {
                return bad(
                    k,
                    format!("must be 2 to {max_span} centres per axis, got {v}"),
                );
            }
        }
        self.validate_lattices()?;
        self.gauss_newton.validate()?;
        for (k, v, least) in [
            (
                "actor_max_centres",
                self.actor_max_centres,
                min_capacity(self.actor_span, 3),
            ),
            (
                "critic_max_centres",
                self.critic_max_centres,
                min_capacity(self.critic_span, 6),
            ),
        ] {
            if !(least..=100_000_000).contains(&v) {
                return bad(
                    k,
                    format!(
                        "must be {least} (eight updates' worth of centres) to 100000000, got {v}"
                    ),
                );
            }
        }
        Ok(())
    }

    /// The workspace the lattices span (a box from `workspace_min_m` to `workspace_max_m`)
    /// and the centres the spacings, already checked, make over it: few enough for
    /// `Lattice::new` to count. The error is `learner.KEY: message`.
    fn validate_lattices(&self) -> Result<(), String> {
        let bad = |key: &str, m: String| Err(format!("learner.{key}: {m}"));
        let (lo, hi) = (self.workspace_min_m, self.workspace_max_m);
        if let Err(e) = softarm_space::Workspace::new(lo, hi) {
            let key = if lo.iter().all(|v| v.is_finite()) {
                "workspace_max_m"
            } else {
                "workspace_min_m"
            };
            return bad(key, e);
        }
        // Lattice::new counts centres in a u64: keep well inside it.
        const MAX_CENTRES: f64 = 1e18;
        for (k, spacing, dims) in [
            ("actor_spacing_m", self.actor_spacing_m, 1),
            ("critic_spacing_m", self.critic_spacing_m, 2),
        ] {
            let per_box: f64 = (0..3)
                .map(|d| ((hi[d] - lo[d]) / spacing).ceil() + 1.0)
                .product();
            let centres = per_box.powi(dims);
            if centres.is_nan() || centres > MAX_CENTRES {
                return bad(
                    k,
                    format!(
                        "{spacing} m over the workspace makes {centres:.1e} lattice centres, more \
                         than {MAX_CENTRES:.0e}: widen the spacing or shrink the workspace"
                    ),
                );
            }
        }
        Ok(())
    }
}

/// Which online learner runs: `learner.algorithm`.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum Algorithm {
    /// The paper's Alg. 1, as printed (with its three corrections), for comparison.
    Paper,
    /// Directed exploration: damped Gauss-Newton steps with the forward model's Jacobian,
    /// learnt per point ([`crate::online`]). Spelt `softarm` before it was named for what it
    /// does; that spelling still loads (softarm-config warns).
    #[default]
    #[serde(rename = "gauss-newton", alias = "softarm")]
    GaussNewton,
}

impl Algorithm {
    pub fn name(self) -> &'static str {
        match self {
            Algorithm::Paper => "paper",
            Algorithm::GaussNewton => "gauss-newton",
        }
    }
}

/// `[learner.gauss_newton]`: the directed steps of [`Algorithm::GaussNewton`] (not to be
/// confused with the three `Correction`s to the printed paper in [`crate::cacla`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct GaussNewtonConfig {
    /// Fraction of the Gauss-Newton step taken. The error a step is taken on is filtered over
    /// the point's executions (a Kalman filter whose measurement noise is `noise_m`), so near
    /// the noise the steps average it out instead of chasing it.
    pub gain: f64,
    /// μ of the damped pseudo-inverse Jᵀ(JJᵀ + μ²I)⁻¹ (m): directions that move the end
    /// effector less than this per unit actuation are not pushed along.
    pub damping_m: f64,
    /// Largest step ‖Δa‖ of a point's first step (normalised units).
    pub trust_initial: f64,
    /// The trust region grows ×1.5 per improving step up to this, and halves per failed one
    /// down to `trust_min`.
    pub trust_max: f64,
    /// The smallest the trust region shrinks to.
    pub trust_min: f64,
    /// What one measurement of the error at a point scatters by (m): tracker noise, timing
    /// jitter, backlash. A rise smaller than this is noise, not a failed step.
    pub noise_m: f64,
    /// Gauss-Newton iterations of a set's first estimates against the trained kinematics.
    pub refine_steps: usize,
    /// The corrections of this many visited targets are kept (the oldest go first).
    pub transfer_points: usize,
    /// A point's Jacobian learns from a step only if the step was meant to move the end
    /// effector more than this (m, ‖J Δa‖): the noise of smaller moves would dominate.
    pub broyden_min_m: f64,
    /// The arm has changed when, where its actuators stood still, it is this far (m) from
    /// where it was before at the same actuation (most of the last checks): what was learnt of
    /// it is forgotten then. Over tracker noise and creep between visits, under any step of
    /// the arm that matters.
    pub change_threshold_m: f64,
}

impl Default for GaussNewtonConfig {
    fn default() -> Self {
        Self {
            gain: 1.0,
            damping_m: 0.005,
            trust_initial: 0.5,
            trust_max: 0.8,
            trust_min: 0.01,
            noise_m: 0.002,
            refine_steps: 10,
            transfer_points: 64,
            broyden_min_m: 0.005,
            change_threshold_m: 0.004,
        }
    }
}

impl GaussNewtonConfig {
    /// Checks every field; the error is `learner.gauss_newton.KEY: message`.
    pub fn validate(&self) -> Result<(), String> {
        let bad = |key: &str, m: String| Err(format!("learner.gauss_newton.{key}: {m}"));
        // (key, value, smallest (exclusive), largest)
        let ranges = [
            ("gain", self.gain, 0.0, 1.0),
            ("damping_m", self.damping_m, 0.0, 1.0),
            ("trust_initial", self.trust_initial, 0.0, 2.5),
            ("trust_max", self.trust_max, 0.0, 2.5),
            ("trust_min", self.trust_min, 0.0, 2.5),
            ("noise_m", self.noise_m, 0.0, 1.0),
            ("broyden_min_m", self.broyden_min_m, 0.0, 1.0),
            ("change_threshold_m", self.change_threshold_m, 0.0, 1.0),
        ];
        for (k, v, lo, hi) in ranges {
            if !(v.is_finite() && v > lo && v <= hi) {
                return bad(k, format!("must be in ({lo}, {hi}], got {v:?}"));
            }
        }
        if !(self.trust_min <= self.trust_initial && self.trust_initial <= self.trust_max) {
            return bad(
                "trust_initial",
                format!(
                    "must lie between trust_min ({}) and trust_max ({}), got {}",
                    self.trust_min, self.trust_max, self.trust_initial
                ),
            );
        }
        if self.refine_steps > 1000 {
            return bad(
                "refine_steps",
                format!("must be 0 to 1000, got {}", self.refine_steps),
            );
        }
        if !(1..=256).contains(&self.transfer_points) {
            return bad(
                "transfer_points",
                format!("must be 1 to 256, got {}", self.transfer_points),
            );
        }
        Ok(())
    }
}

/// Offline pre-training: epochs of random targets inside the demonstrated subspace, each
/// visited in turn (as the conditioning points of one execution are) until all are within the
/// threshold or the cap.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PretrainConfig {
    /// Targets drawn per epoch of pre-training against the forward model (0: no pre-training).
    pub targets_per_epoch: usize,
    /// An epoch ends early once every target is reached within this (m).
    pub threshold_m: f64,
    /// Visits of each target at most per epoch.
    pub visits_per_epoch: usize,
    /// Epochs at most (`budget_s` usually ends pre-training first).
    pub max_epochs: u64,
    /// Wall-clock budget (s) for whoever runs the pre-training (`softarm train`).
    pub budget_s: f64,
}

impl Default for PretrainConfig {
    fn default() -> Self {
        Self {
            targets_per_epoch: 5,
            threshold_m: 0.005,
            visits_per_epoch: 100,
            max_epochs: u64::MAX,
            budget_s: 30.0,
        }
    }
}

impl PretrainConfig {
    /// Checks every field; the error is `pretrain.KEY: message`.
    pub fn validate(&self) -> Result<(), String> {
        count(
            "pretrain.targets_per_epoch",
            self.targets_per_epoch,
            0,
            1000,
        )?;
        within(
            "pretrain.threshold_m",
            self.threshold_m,
            Open(0.0),
            1.0,
            " m",
        )?;
        count(
            "pretrain.visits_per_epoch",
            self.visits_per_epoch,
            1,
            100_000,
        )?;
        within(
            "pretrain.budget_s",
            self.budget_s,
            Closed(0.0),
            86_400.0,
            " s",
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_field_is_checked_and_spans_are_what_lattices_accept() {
        let check = |edit: &dyn Fn(&mut LearnerConfig), want: &str| {
            let mut c = LearnerConfig::default();
            edit(&mut c);
            let e = c.validate().unwrap_err();
            assert!(e.starts_with(want), "{e} (wanted {want:?})");
            assert_eq!(e.matches(want.split(':').next().unwrap()).count(), 1, "{e}");
        };
        check(
            &|c| c.critic_span = 1,
            "learner.critic_span: must be 2 to 9 centres per axis",
        );
        check(
            &|c| c.actor_span = 10,
            "learner.actor_span: must be 2 to 9 centres per axis",
        );
        check(
            &|c| c.alpha_actor = f64::NAN,
            "learner.alpha_actor: must be in [0, 1]",
        );
        check(
            &|c| c.sigma_max = 2.0,
            "learner.sigma_max: must be in (0, 1]",
        );
        check(
            &|c| c.sigma_slope_per_m = f64::INFINITY,
            "learner.sigma_slope_per_m: must be in (0, 10000] /m",
        );
        check(
            &|c| c.actor_width = 1e300,
            "learner.actor_width: must be in (0, 10] cells",
        );
        check(
            &|c| c.critic_spacing_m = 0.0,
            "learner.critic_spacing_m: must be in [0.001, 1] m",
        );
        check(
            &|c| c.workspace_min_m[1] = f64::NAN,
            "learner.workspace_min_m: axis 1 (y): the box NaN",
        );
        check(
            &|c| c.workspace_max_m[2] = -1.0,
            "learner.workspace_max_m: axis 2 (z): the box -0.6 .. -1 m is empty",
        );
        // A box so wide the lattices cannot be counted: an error, not an overflow.
        check(
            &|c| {
                c.workspace_min_m = [-1e300; 3];
                c.workspace_max_m = [1e300; 3];
            },
            "learner.actor_spacing_m: 0.015 m over the workspace makes inf lattice centres",
        );
        check(
            &|c| {
                c.workspace_min_m = [-1e3; 3];
                c.workspace_max_m = [1e3; 3];
            },
            "learner.critic_spacing_m: 0.03 m over the workspace makes",
        );
        // A wide neighbourhood needs room for its updates.
        check(
            &|c| c.critic_max_centres = 511,
            "learner.critic_max_centres: must be 512 (eight updates' worth of centres)",
        );
        check(
            &|c| {
                c.critic_span = 5;
                c.critic_max_centres = 100_000;
            },
            "learner.critic_max_centres: must be 125000",
        );
        check(
            &|c| c.actor_max_centres = usize::MAX,
            "learner.actor_max_centres: must be 216 (eight updates' worth of centres) to 100000000",
        );
        for span in [2, MAX_SPAN] {
            let c = LearnerConfig {
                critic_span: span,
                actor_span: span,
                critic_max_centres: 100_000_000,
                ..Default::default()
            };
            c.validate().unwrap();
        }
    }

    /// The names before the Gauss-Newton step was named for what it is still load, as the new
    /// ones (softarm-config says which to use instead).
    #[test]
    fn the_former_names_load_as_the_new_ones() {
        let new: LearnerConfig =
            toml::from_str("algorithm = \"gauss-newton\"\n[gauss_newton]\ngain = 0.5\n").unwrap();
        let old: LearnerConfig =
            toml::from_str("algorithm = \"softarm\"\n[correction]\ngain = 0.5\n").unwrap();
        assert_eq!(old, new);
        assert_eq!(new.algorithm, Algorithm::GaussNewton);
        assert_eq!(new.gauss_newton.gain, 0.5);
        assert_eq!(Algorithm::default().name(), "gauss-newton");
        // Both spellings at once is one key given twice.
        assert!(
            toml::from_str::<LearnerConfig>(
                "[gauss_newton]\ngain = 0.5\n[correction]\ngain = 0.4\n"
            )
            .is_err()
        );
    }
}
