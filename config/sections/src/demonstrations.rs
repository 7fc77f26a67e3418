//! `[demonstrations]`: how demonstrations are made, as plain data with its validation. The
//! recipe itself is `softarm_method::skill`.

use serde::{Deserialize, Serialize};
use softarm_arm::Layout;

use crate::activation::MAX_PRIMITIVES;

/// The extremes of one primitive class: where its motions start and end, one normalised
/// actuation per actuator in the arm's order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ClassExtremes {
    pub start: Vec<f64>,
    pub end: Vec<f64>,
}

/// The paper's three motion classes of its two-module arm: a sweep of module 1 across the x–z
/// plane, a sweep that bends both modules the same way, and an S-shape (start, end).
pub const PAPER_CLASSES: [([f64; 6], [f64; 6]); 3] = [
    (
        [0.2, 0.8, 0.8, 0.5, 0.5, 0.5],
        [0.8, 0.3, 0.3, 0.5, 0.5, 0.5],
    ),
    (
        [0.8, 0.2, 0.7, 0.7, 0.2, 0.6],
        [0.6, 0.8, 0.2, 0.5, 0.8, 0.2],
    ),
    (
        [0.3, 0.6, 0.8, 0.8, 0.5, 0.3],
        [0.8, 0.5, 0.3, 0.3, 0.6, 0.8],
    ),
];

/// How many classes an arm gets when the recipe gives none (`softarm_method::skill::classes`
/// makes them): the paper's three on its kind of arm; else one sweep per module, all modules
/// together, and with more than one module an S; at most [`MAX_PRIMITIVES`].
pub fn derived_classes(arm: &Layout) -> usize {
    if arm.is_papers_kind() {
        return PAPER_CLASSES.len();
    }
    let modules = arm.modules().len();
    (modules + 1 + usize::from(modules > 1)).min(MAX_PRIMITIVES)
}

/// How demonstrations are made.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct DemoRecipe {
    /// Demonstrations recorded per class (primitive).
    pub demos_per_class: usize,
    /// Length of each demonstration (s).
    pub duration_s: f64,
    /// Recorded samples per second.
    pub sample_rate_hz: f64,
    /// Start, end and intermediate points are drawn uniformly within ± this of their nominal.
    pub spread: f64,
    /// Random points between start and end.
    pub intermediate_points: usize,
    /// One primitive each: its nominal start and end actuations, one per actuator. Absent:
    /// derived from the arm (`softarm_method::skill::classes`): the paper's three on its kind
    /// of arm, sweeps of each module and of all of them together on any other.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub classes: Option<Vec<ClassExtremes>>,
}

impl Default for DemoRecipe {
    fn default() -> Self {
        Self {
            demos_per_class: 20,
            duration_s: 4.0,
            sample_rate_hz: 50.0,
            spread: 0.1,
            intermediate_points: 2,
            classes: None,
        }
    }
}

impl DemoRecipe {
    /// The paper's classes, as given classes.
    pub fn paper_classes() -> Vec<ClassExtremes> {
        PAPER_CLASSES
            .iter()
            .map(|(start, end)| ClassExtremes {
                start: start.to_vec(),
                end: end.to_vec(),
            })
            .collect()
    }

    /// How many classes (primitives) it makes on `arm`: those given, or [`derived_classes`].
    pub fn class_count(&self, arm: &Layout) -> usize {
        self.classes
            .as_ref()
            .map_or_else(|| derived_classes(arm), Vec::len)
    }

    /// Checks every field for `arm`; the error is `demonstrations.KEY: message`. The bounds
    /// keep the demonstrations under an hour and their samples in memory.
    pub fn validate(&self, arm: &Layout) -> Result<(), String> {
        let bad = |key: &str, m: String| Err(format!("demonstrations.{key}: {m}"));
        let max_classes = MAX_PRIMITIVES;
        let actuators = arm.actuators().len();
        if let Some(classes) = &self.classes
            && (classes.is_empty() || classes.len() > max_classes)
        {
            return bad(
                "classes",
                format!(
                    "need 1 to {max_classes} classes (or none: derived from the arm), got {}",
                    classes.len()
                ),
            );
        }
        if !(2..=1000).contains(&self.demos_per_class) {
            return bad(
                "demos_per_class",
                format!("must be 2 to 1000, got {}", self.demos_per_class),
            );
        }
        if !(self.duration_s.is_finite() && self.duration_s > 0.0 && self.duration_s <= 600.0) {
            return bad(
                "duration_s",
                format!("must be in (0, 600] s, got {:?}", self.duration_s),
            );
        }
        if !(self.sample_rate_hz.is_finite()
            && self.sample_rate_hz > 0.0
            && self.sample_rate_hz <= 1000.0)
        {
            return bad(
                "sample_rate_hz",
                format!("must be in (0, 1000] Hz, got {:?}", self.sample_rate_hz),
            );
        }
        let per_demo = self.sample_rate_hz * self.duration_s;
        if !(10.0..=10_000.0).contains(&per_demo) {
            return bad(
                "sample_rate_hz",
                format!(
                    "{} Hz over duration_s = {} s makes {per_demo:.0} samples per \
                     demonstration; need 10 to 10000",
                    self.sample_rate_hz, self.duration_s
                ),
            );
        }
        let demos = self.class_count(arm) * self.demos_per_class;
        let total_s = demos as f64 * self.duration_s;
        if total_s > 3600.0 {
            return bad(
                "demos_per_class",
                format!(
                    "{demos} demonstrations of {} s take {total_s:.0} s; at most 3600 s in all",
                    self.duration_s
                ),
            );
        }
        if !(0.0..=0.5).contains(&self.spread) {
            return bad(
                "spread",
                format!("must be in [0, 0.5], got {:?}", self.spread),
            );
        }
        if self.intermediate_points > 100 {
            return bad(
                "intermediate_points",
                format!("must be 0 to 100, got {}", self.intermediate_points),
            );
        }
        self.validate_classes(actuators)
    }

    /// The given classes' start and end: one normalised actuation per actuator of an arm of
    /// `actuators`. The error is `demonstrations.classes[i].start` (or `end`): message.
    fn validate_classes(&self, actuators: usize) -> Result<(), String> {
        let bad = |key: &str, m: String| Err(format!("demonstrations.{key}: {m}"));
        for (i, c) in self.classes.iter().flatten().enumerate() {
            for (field, values) in [("start", &c.start), ("end", &c.end)] {
                if values.len() != actuators {
                    return bad(
                        &format!("classes[{i}].{field}"),
                        format!(
                            "{} values for an arm of {actuators} actuators; give one per \
                             actuator, or leave `classes` out to derive them from the arm",
                            values.len()
                        ),
                    );
                }
                if let Some(d) = values.iter().position(|v| !(0.0..=1.0).contains(v)) {
                    return bad(
                        &format!("classes[{i}].{field}"),
                        format!(
                            "actuator {} is {:?}; each must be in [0, 1]",
                            d + 1,
                            values[d]
                        ),
                    );
                }
            }
        }
        Ok(())
    }

    /// As [`DemoRecipe::validate`], and the samples no faster than the controller, ticking at
    /// `controller_rate_hz`, plays them: the config's check (training has no controller).
    pub fn validate_for(&self, arm: &Layout, controller_rate_hz: f64) -> Result<(), String> {
        self.validate(arm)?;
        if self.sample_rate_hz > controller_rate_hz {
            return Err(format!(
                "demonstrations.sample_rate_hz: {} Hz is faster than controller.rate_hz = {} Hz, \
                 which plays the samples",
                self.sample_rate_hz, controller_rate_hz
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_field_is_bounded_and_named() {
        let check = |edit: &dyn Fn(&mut DemoRecipe), want: &str| {
            let mut r = DemoRecipe {
                classes: Some(DemoRecipe::paper_classes()),
                ..DemoRecipe::default()
            };
            edit(&mut r);
            let e = r
                .validate(&crate::arm::ArmConfig::default().layout().unwrap())
                .unwrap_err();
            assert!(e.starts_with(want), "{e} (wanted {want:?})");
        };
        check(
            &|r| r.demos_per_class = 1 << 40,
            "demonstrations.demos_per_class: must be 2 to 1000",
        );
        check(
            &|r| r.duration_s = 1e300,
            "demonstrations.duration_s: must be in (0, 600] s, got 1e300",
        );
        check(
            &|r| r.sample_rate_hz = f64::INFINITY,
            "demonstrations.sample_rate_hz: must be in (0, 1000] Hz",
        );
        check(
            &|r| r.sample_rate_hz = 1.0,
            "demonstrations.sample_rate_hz: 1 Hz over duration_s = 4 s makes 4 samples",
        );
        check(
            &|r| r.intermediate_points = usize::MAX,
            "demonstrations.intermediate_points: must be 0 to 100",
        );
        check(
            &|r| r.spread = f64::NAN,
            "demonstrations.spread: must be in [0, 0.5]",
        );
        check(
            &|r| r.classes = Some(Vec::new()),
            "demonstrations.classes: need 1 to 8 classes (or none: derived from the arm), got 0",
        );
        check(
            &|r| {
                r.demos_per_class = 1000;
                r.duration_s = 600.0;
                r.sample_rate_hz = 10.0;
            },
            "demonstrations.demos_per_class: 3000 demonstrations of 600 s take 1800000 s",
        );
        check(
            &|r| r.classes.as_mut().unwrap()[1].end[3] = 1.5,
            "demonstrations.classes[1].end: actuator 4 is 1.5",
        );
        check(
            &|r| r.classes.as_mut().unwrap()[2].start[0] = f64::NAN,
            "demonstrations.classes[2].start: actuator 1 is NaN",
        );
        check(
            &|r| r.classes.as_mut().unwrap()[0].end.push(0.5),
            "demonstrations.classes[0].end: 7 values for an arm of 6 actuators",
        );
    }

    #[test]
    fn the_controller_plays_the_samples_no_faster_than_it_ticks() {
        let arm = crate::arm::ArmConfig::default().layout().unwrap();
        let r = DemoRecipe::default();
        r.validate_for(&arm, r.sample_rate_hz).unwrap();
        assert_eq!(
            r.validate_for(&arm, 40.0).unwrap_err(),
            "demonstrations.sample_rate_hz: 50 Hz is faster than controller.rate_hz = 40 Hz, \
             which plays the samples"
        );
        // The recipe's own checks come first.
        let bad = DemoRecipe {
            spread: 0.9,
            ..DemoRecipe::default()
        };
        assert!(
            bad.validate_for(&arm, 40.0)
                .unwrap_err()
                .starts_with("demonstrations.spread: ")
        );
    }
}
