//! The model: what `softarm train` makes and the controller and learner load.
//!
//! - [`bundle`]: model bundles and learner checkpoints (safetensors + TOML, atomic writes).
//! - [`pipeline`]: demonstrations → primitives → forward model → imitation → pre-training,
//!   written once for `softarm train`, the tests, the benches and the examples.
//!
//! Pure of iceoryx2 and of the config file: the pipeline takes its settings as a
//! [`pipeline::Training`]; `softarm-config` reads the file.

pub mod bundle;
pub mod pipeline;
