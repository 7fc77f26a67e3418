//! softarm's data on disk, and the offline pipeline that makes a model:
//!
//! - [`config`]: the one TOML file every process reads; errors name the key and its line.
//! - [`bundle`]: model bundles and learner checkpoints (safetensors + TOML, atomic writes).
//! - [`waypoints`]: way-point files and the checks a set must pass.
//! - [`hardware`]: the real arm's drivers' sections, motor ticks ↔ actuation, tracker ↔ base frame.
//! - [`scenario`]: scenario files, the sim's arm when it is not the one the model knows.
//! - [`pipeline`]: demonstrations → primitives → forward model → imitation → pre-training,
//!   written once for `softarm train`, the tests, the benches and the examples.
//!
//! No iceoryx2 here but the payload types of the contract.

pub mod bundle;
pub mod config;
pub mod hardware;
pub mod pipeline;
pub mod scenario;
pub mod waypoints;
