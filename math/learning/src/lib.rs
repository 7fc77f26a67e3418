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
