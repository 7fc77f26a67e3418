//! How softarm learns the conditioning points, pure math: no I/O, no clock, no iceoryx2 (Cargo
//! enforces it). Apart from the method so that what only the learner, the model pipeline and
//! the rehearsal need is linked by nothing else: the controller and the drivers read the
//! learner's parameters (`softarm_sections::learner`) without linking this. It links the
//! kinematics and forward models (`softarm-kinematics`), not the method.
//!
//! - [`cacla`] — CACLA-MTL (Alg. 1): [`cacla::Actor`], [`cacla::Critic`], one visit's update,
//!   pre-training; what every point shares.
//! - [`online`] — the online learner over a running set: its one per-point state
//!   (`online::Point`), Alg. 1 as printed or damped Gauss-Newton steps
//!   (`softarm_sections::learner::Algorithm`).
//! - [`arm`] — what the online learner knows of the arm beyond its trained model: the
//!   corrections of the visited points, and the footprint that says when the arm has changed.
//! - [`calibration`] — the configured arm fitted to the footprint: what carries a changed
//!   arm to targets never visited.
//! - [`within`] — what the running execution's points show of the arm, for the points still
//!   to come in it.

pub mod arm;
pub mod cacla;
pub mod calibration;
pub mod online;
pub mod within;

/// The arm the tests run on: the default `[arm]` (the paper's two modules of three tendons).
#[cfg(test)]
pub(crate) mod default_arm {
    use softarm_kinematics::pcc;
    use softarm_sections::arm::ArmConfig;

    /// The default `[arm]`'s actuators.
    pub(crate) const N: usize = 6;

    /// The default `[arm]`'s PCC kinematics.
    pub(crate) fn arm() -> pcc::Arm {
        of(&ArmConfig::default())
    }

    /// The PCC kinematics of `[arm]` as `config` says (the default's shorthand keys changed).
    pub(crate) fn of(config: &ArmConfig) -> pcc::Arm {
        pcc::Arm::of_config(config).unwrap()
    }

    /// The default `[arm]` with a tool `tool_m` longer.
    pub(crate) fn longer_tool(tool_m: f64) -> pcc::Arm {
        arm().changed(tool_m, 0.0, &[0.0; N], &[0.0; 2])
    }
}
