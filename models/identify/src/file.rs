//! The identified model on disk (TOML, written atomically), and the calibrated arm written
//! out as an `[arm]` file the sim runs: the twin a lab rehearses on before its arm moves.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use softarm_arm::Layout;

use crate::residual::Residual;
use crate::tendon::{Model, Slots, Structure};

/// The format this build writes and reads.
/// 2: gravity's terms in the parameters, and which terms each candidate fitted.
pub const FORMAT: u32 = 2;

/// A physical model calibrated to a recording.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Identified {
    pub format: u32,
    /// The arm's identity ([`Layout::identity`]): another arm's model is refused.
    pub arm: String,
    /// The recording it was fitted to, and how many rows.
    pub recording: String,
    pub rows: usize,
    /// The prior's strength and the terms cross-validation chose, and what it measured of
    /// each candidate tried.
    pub strength: f64,
    pub gravity: bool,
    pub validated: Vec<CandidateTried>,
    /// RMS over the rows it was fitted to (mm).
    pub fitted_rms_mm: f64,
    /// The parameters, in [`Slots`]' order.
    pub theta: Vec<f64>,
    /// What cross-validation measured of each residual tried (none first).
    pub residual_validated: Vec<ResidualTried>,
    /// The residual it chose over the physical model, if any.
    pub residual: Option<Residual>,
}

/// One physical model cross-validation tried: a prior's strength, with gravity or not.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CandidateTried {
    pub strength: f64,
    pub gravity: bool,
    /// RMS over held-out motions (mm).
    pub held_out_rms_mm: f64,
}

/// One residual cross-validation tried.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResidualTried {
    /// Its width (strokes) and ridge; absent: the physical model alone.
    pub width: Option<f64>,
    pub ridge: Option<f64>,
    /// RMS over held-out motions (mm).
    pub held_out_rms_mm: f64,
}

/// A model file that cannot be used, and why.
#[derive(Debug, thiserror::Error)]
#[error("{}: {message}", path.display())]
pub struct ModelFileError {
    pub path: PathBuf,
    pub message: String,
}

impl Identified {
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        let text = toml::to_string(self).map_err(std::io::Error::other)?;
        let head = "# softarm: an arm identified from a recording (softarm train --from)\n";
        softarm_runtime::file::write_atomic(path, format!("{head}{text}").as_bytes(), None)
    }

    /// Reads `path` for `arm`: refused, saying why, if it is not a model file of this format,
    /// is for another arm, or holds a parameter that is not a number.
    pub fn read(path: &Path, arm: &Layout) -> Result<Self, ModelFileError> {
        let fail = |message: String| ModelFileError {
            path: path.into(),
            message,
        };
        let text = std::fs::read_to_string(path).map_err(|e| fail(format!("cannot read: {e}")))?;
        let model: Self = toml::from_str(&text).map_err(|e| {
            let line = e
                .span()
                .map(|s| 1 + text[..s.start].bytes().filter(|b| *b == b'\n').count());
            fail(match line {
                Some(l) => format!("line {l}: {}", e.message()),
                None => e.message().to_string(),
            })
        })?;
        if model.format != FORMAT {
            return Err(fail(format!(
                "format {}; this softarm reads format {FORMAT}: train it again",
                model.format
            )));
        }
        if model.arm != arm.identity() {
            return Err(fail(format!(
                "made for the arm {}, not the config's {}",
                model.arm,
                arm.identity()
            )));
        }
        let slots = Structure::of(arm).slots;
        if model.theta.len() != slots.count() {
            return Err(fail(format!(
                "{} parameters; this arm's model has {}",
                model.theta.len(),
                slots.count()
            )));
        }
        if let Some(k) = model.theta.iter().position(|v| !v.is_finite()) {
            return Err(fail(format!("parameter {k} is not a finite number")));
        }
        if let Some(r) = &model.residual
            && !r.is_valid(slots.tendons)
        {
            return Err(fail(format!(
                "its residual is not one of {} actuators with finite numbers",
                slots.tendons
            )));
        }
        Ok(model)
    }

    /// Where it puts the tip (m) at pulls `pull_m`: the physical model, and its residual
    /// unless `physical_only`.
    pub fn predictor<'a>(
        &'a self,
        structure: &'a Structure,
        physical_only: bool,
    ) -> impl Fn(&[f64]) -> [f64; 3] + 'a {
        let model = Model::new(structure, &self.theta);
        move |pull: &[f64]| {
            let mut p = model.predict(pull);
            if let (Some(r), false) = (&self.residual, physical_only) {
                let c = r.correction(pull);
                for k in 0..3 {
                    p[k] += c[k];
                }
            }
            p
        }
    }
}

/// The calibrated arm as an `[arm]` file: `arm`'s structure and strokes with the fitted
/// backbones, radii (each module's mean), angles and the marker's height as the tool. What an
/// `[arm]` cannot say (slack, stiffnesses, compression, the marker off the axis, the base's
/// pose) stays in the model and is named in the file's head.
pub fn twin(arm: &Layout, theta: &[f64], source: &str) -> String {
    let structure = Structure::of(arm);
    let s: Slots = structure.slots;
    let mut out = format!(
        "# The arm calibrated from {source} by softarm train --from: its geometry as the sim\n\
         # runs it (the base's turn about its axis in the tendons' angles). Not in an [arm]\n\
         # file, so not in the twin: tendon slack and offsets, the modules' stiffnesses and\n\
         # compression, the marker off the axis ({:.1}, {:.1} mm), the base's tilt and position.\n",
        theta[s.marker(0)] * 1e3,
        theta[s.marker(1)] * 1e3
    );
    // An [arm] has no mass: the sim runs the twin without its weight.
    let weight: Vec<f64> = (0..3).map(|k| theta[s.gravity_vector(k)]).collect();
    if weight.iter().any(|w| *w != 0.0) {
        out.push_str(&format!(
            "# Nor its weight: module 1's ({:.2}, {:.2}, {:.2}) per metre of its bending\n\
             # stiffness, up in the backbone's frame; the others' masses and the payload's\n\
             # relative to module 1's: {:?}.\n",
            weight[0],
            weight[1],
            weight[2],
            ((1..s.modules).map(|m| theta[s.weight(m)]))
                .chain([theta[s.payload()]])
                .map(|v| (v * 100.0).round() / 100.0)
                .collect::<Vec<_>>()
        ));
    }
    out.push_str(&format!(
        "routing = \"{}\"\nmount = \"{}\"\nconnector_m = {}\ntool_m = {:.5}\n",
        routing_name(arm),
        mount_name(arm),
        arm.connector_m,
        theta[s.marker(2)].max(0.0)
    ));
    // A turn of the base about the backbone's axis turns every tendon with it: the same arm
    // as every tendon's angle turned by it (the fit cannot tell the two apart, and an [arm]
    // has no base pose).
    let base_turn = theta[s.base_rotation(2)];
    for (m, module) in arm.modules().iter().enumerate() {
        let own = module.actuators.clone();
        let radius = own.clone().map(|i| theta[s.radius(i)].abs()).sum::<f64>() / own.len() as f64;
        let angles: Vec<String> = (own.clone())
            .map(|i| {
                let deg = (theta[s.angle(i)] + theta[s.rotation(m)] + base_turn).to_degrees();
                format!("{:.2}", deg.rem_euclid(360.0))
            })
            .collect();
        let first = &arm.actuators()[own.start];
        let names: Vec<String> = (own.clone())
            .map(|i| format!("\"{}\"", arm.actuators()[i].name))
            .collect();
        out.push_str(&format!(
            "\n[[modules]]\nbackbone_m = {:.5}\ntendons = {{ count = {}, radius_m = {:.6}, angles_deg = [{}], length_m = [{}, {}], names = [{}] }}\n",
            theta[s.length(m)],
            own.len(),
            radius,
            angles.join(", "),
            first.min_m,
            first.max_m,
            names.join(", ")
        ));
    }
    out
}

fn routing_name(arm: &Layout) -> &'static str {
    match arm.routing() {
        softarm_arm::Routing::Coupled => "coupled",
        softarm_arm::Routing::Independent => "independent",
    }
}

fn mount_name(arm: &Layout) -> &'static str {
    match arm.mount {
        softarm_arm::Mount::Hanging => "hanging",
        softarm_arm::Mount::Standing => "standing",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model(arm: &Layout) -> Identified {
        Identified {
            format: FORMAT,
            arm: arm.identity(),
            recording: "r.csv".into(),
            rows: 100,
            strength: 1.0,
            gravity: false,
            validated: vec![CandidateTried {
                strength: 1.0,
                gravity: false,
                held_out_rms_mm: 2.0,
            }],
            fitted_rms_mm: 1.0,
            theta: Structure::of(arm).nominal(arm),
            residual_validated: vec![],
            residual: None,
        }
    }

    #[test]
    fn a_model_file_reads_back_and_a_bad_one_is_refused_saying_why() {
        let arm = crate::test_arm();
        let dir = std::env::temp_dir().join(format!("softarm-identified-{}", std::process::id()));
        let path = dir.join("identified.toml");
        model(&arm).write(&path).unwrap();
        assert_eq!(Identified::read(&path, &arm).unwrap(), model(&arm));
        let refused = |text: &str| {
            std::fs::write(&path, text).unwrap();
            Identified::read(&path, &arm).unwrap_err().to_string()
        };
        let good = std::fs::read_to_string(&path).unwrap();
        let e = refused("theta = 3\n");
        assert!(e.contains("identified.toml: line 1"), "{e}");
        let e = refused(&good.replace("format = 2", "format = 9"));
        assert!(e.contains("format 9; this softarm reads format 2"), "{e}");
        let e = refused(&good.replacen("theta = [", "theta = [nan, ", 1));
        assert!(e.contains("parameters; this arm's model has"), "{e}");
        let e = refused(&good.replacen("theta = [0.1", "theta = [nan", 1));
        assert!(e.contains("parameter 0 is not a finite number"), "{e}");
        let other = crate::test_arm_mounted("hanging");
        std::fs::write(&path, &good).unwrap();
        assert_eq!(Identified::read(&path, &other).unwrap().arm, arm.identity());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_twin_names_the_weight_it_cannot_carry() {
        let arm = crate::test_arm();
        let structure = Structure::of(&arm);
        let mut theta = structure.nominal(&arm);
        assert!(!twin(&arm, &theta, "r.csv").contains("weight"));
        theta[structure.slots.gravity_vector(2)] = -4.0;
        let text = twin(&arm, &theta, "r.csv");
        assert!(
            text.contains("Nor its weight: module 1's (0.00, 0.00, -4.00)"),
            "{text}"
        );
        // Still an [arm]: the weight only in comments.
        let d: softarm_arm::Description = toml::from_str(&text).unwrap();
        assert_eq!(softarm_arm::Layout::new(&d).unwrap().modules().len(), 2);
    }
}
