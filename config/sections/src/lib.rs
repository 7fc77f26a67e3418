//! The sections of the config that the math reads, as plain data: serde and schemars types with
//! their defaults and their validation (`validate`), no math, no I/O. `softarm-config` reads
//! them from the TOML file and re-exports these modules; the math crates (`softarm-kinematics`,
//! `softarm-method`, `softarm-learning`, the sim's plant) take them as settings and put their
//! math on them (e.g. `softarm_kinematics::pcc::Arm` for [`arm::ArmConfig`]). Below
//! the config, so the math links neither the config nor, through it, iceoryx2; and the config
//! (so every driver) links none of the math.
//!
//! - [`arm`] — `[arm]`: [`arm::ArmConfig`] (any arm; the paper's by its shorthand keys),
//!   [`arm::Mount`].
//! - [`per_actuator`] — a setting per actuator: [`per_actuator::PerActuator`].
//! - [`sim`] — `[sim]`: [`sim::SimConfig`], [`sim::Realism`].
//! - [`changes`] — a scenario's drift: [`changes::Drift`], and its bounds.
//! - [`learner`] — `[learner]`, `[pretrain]`: [`learner::LearnerConfig`],
//!   [`learner::GaussNewtonConfig`], [`learner::Algorithm`], [`learner::PretrainConfig`].
//! - [`forward_model`] — `[forward_model]`: [`forward_model::NetworkConfig`].
//! - [`kinematics`] — `[kinematics]`: [`kinematics::PolynomialConfig`].
//! - [`activation`] — `[activation]`: [`activation::ActivationConfig`], [`activation::Fade`].
//! - [`demonstrations`] — `[demonstrations]`: [`demonstrations::DemoRecipe`].
//! - [`bounds`] — the range checks most keys share, worded once: [`bounds::within`],
//!   [`bounds::count`].

pub mod activation;
pub mod arm;
pub mod bounds;
pub mod changes;
pub mod demonstrations;
pub mod forward_model;
pub mod kinematics;
pub mod learner;
pub mod mujoco;
pub mod per_actuator;
pub mod sim;
