//! An arm identified from the recordings its lab already has: actuator commands beside a
//! motion-capture tip, each row a settled pose.
//!
//! - [`recording`]: a CSV recording read through a column map ([`recording::Columns`]), every
//!   bad value refused with its file, line and column.
//! - [`tendon`]: a physical model of a tendon-driven continuum arm: constant-curvature modules
//!   bent and compressed by tendons that only pull. Pure math.
//! - [`fit`]: that model calibrated to a recording (geometry, offsets, stiffnesses, base pose,
//!   the marker), its regularisation chosen by cross-validation over held-out motions.
//! - [`residual`]: what the physical model still misses, learnt, fading away from the data.
//! - [`check`]: how well a model predicts a recording, overall and per label family.
//! - [`file`]: the identified model on disk, and the twin: the calibrated arm as an `[arm]`.
//! - [`run`]: the commands, `softarm train --from` and `softarm model check`.

pub mod check;
pub mod file;
pub mod fit;
pub mod recording;
pub mod residual;
pub mod run;
pub mod tendon;

/// What the tests of this crate share: two modules of three tendons, coupled, 100 mm each,
/// strokes of ±12.5 mm about the straight arm, a 10 mm tool.
#[cfg(test)]
pub(crate) fn test_arm() -> softarm_arm::Layout {
    test_arm_mounted("standing")
}

/// [`test_arm`] on another mount.
#[cfg(test)]
pub(crate) fn test_arm_mounted(mount: &str) -> softarm_arm::Layout {
    let d: softarm_arm::Description = toml::from_str(&format!(
        r#"
        routing = "coupled"
        mount = "{mount}"
        tool_m = 0.01
        [[modules]]
        backbone_m = 0.1
        tendons = {{ count = 3, radius_m = 0.0045, length_m = [0.0875, 0.1125] }}
        [[modules]]
        backbone_m = 0.1
        tendons = {{ count = 3, radius_m = 0.0045, length_m = [0.1875, 0.2125] }}
        "#
    ))
    .unwrap();
    softarm_arm::Layout::new(&d).unwrap()
}
