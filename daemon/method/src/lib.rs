//! The method of "Task Driven Skill Learning in a Soft-Robotic Arm" (IROS 2021), pure math:
//! no I/O, no clock, no iceoryx2 (Cargo enforces it: this crate depends on neither).
//!
//! - [`space`] — actuation and task space, named once (re-exported from `softarm-space`).
//! - [`promp`] — probabilistic movement primitives (train, condition, marginals).
//! - [`activation`] — a_j(t) and b_i(t) of Eq. 11.
//! - [`blend`] — Eq. 11, the conditioned primitives blended on the controller's tick grid
//!   ([`blend::Planner`] → [`blend::Blend`] + [`blend::Replanner`]).
//! - [`classify`] — ClassifyToPrimitives.
//! - [`skill`] — demonstrations by the paper's III-B recipe and the primitives trained on them.
//! - [`rbf`] — RBF lattices and the RBF forward-model network; [`forward`] — the
//!   `ForwardModel` trait.
//! - [`learner_config`] — the learner's parameters (`[learner]`, `[pretrain]`), read by the
//!   config; the learning itself (CACLA-MTL, the online learner) is crate `softarm-learning`.
//! - [`pcc`] — piecewise-constant-curvature kinematics; [`plant`]: the simulated plant;
//!   [`changes`]: how its arm changes over time (a scenario's steps and drifts).

pub mod activation;
pub mod blend;
pub mod changes;
pub mod classify;
pub mod forward;
pub mod learner_config;
pub mod pcc;
pub mod plant;
pub mod poly;
pub mod promp;
pub mod rbf;
pub mod skill;

/// The spaces, named once beneath the method and the contract (crate `softarm-space`).
pub use softarm_space as space;
pub use space::{ACTUATORS, Actuation, MAX_WAYPOINTS, Position, Workspace, distance};
