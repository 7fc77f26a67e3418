//! The method of "Task Driven Skill Learning in a Soft-Robotic Arm" (IROS 2021): the real-time
//! math of the controller and the demonstrations, pure math: no I/O, no clock, no iceoryx2
//! (Cargo enforces it: this crate depends on neither).
//!
//! - [`space`] — actuation and task space, named once (re-exported from `softarm-space`).
//! - [`promp`] — probabilistic movement primitives (train, condition, marginals).
//! - [`activation`] — a_j(t) and b_i(t) of Eq. 11.
//! - [`blend`] — Eq. 11, the conditioned primitives blended on the controller's tick grid
//!   ([`blend::Planner`] → [`blend::Blend`] + [`blend::Replanner`]).
//! - [`classify`] — ClassifyToPrimitives.
//! - [`skill`] — demonstrations by the paper's III-B recipe and the primitives trained on them.
//!
//! Elsewhere: the kinematics and forward models (PCC, RBF, polynomial) are crate
//! `softarm-kinematics`; the settings (`[activation]`, `[demonstrations]`, ...) plain data in
//! `softarm-sections`; the learning (CACLA-MTL, the online learner) `softarm-learning`; the
//! simulated plant and its scenario's changes the sim's (`softarm_sim::plant`).

pub mod activation;
pub mod blend;
pub mod classify;
pub mod promp;
pub mod skill;

/// The spaces, named once beneath the method and the contract (crate `softarm-space`).
pub use softarm_space as space;
pub use space::{MAX_WAYPOINTS, Position, Workspace, distance};
