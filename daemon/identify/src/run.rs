//! The commands: `softarm train --from` (a recording → an identified model and its twin) and
//! `softarm model check` (a model against a recording), with progress for people.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use softarm_arm::Layout;

use crate::check::{self, Check};
use crate::file::{self, FORMAT, Identified, ModelFileError, ResidualTried};
use crate::fit::{self, Sample};
use crate::recording::{self, Columns, Recording, RecordingError};
use crate::residual;
use crate::tendon::Structure;

/// What went wrong, for the user: a recording, a column map, a model file, or writing.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Recording(#[from] RecordingError),
    #[error(transparent)]
    Model(#[from] ModelFileError),
    #[error("{}: {message}", path.display())]
    Write { path: PathBuf, message: String },
}

/// The model file's name in the output folder, and the twin's.
pub const MODEL_FILE: &str = "identified.toml";
pub const TWIN_FILE: &str = "twin-arm.toml";

/// Rows a fit needs at least, per parameter: each row gives three numbers.
const ROWS_PER_PARAMETER: usize = 2;

/// A progress bar on a terminal (hidden elsewhere): what `train` and `train --from` show of
/// anything over a few seconds.
pub fn bar(len: u64, what: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(len);
    b.set_style(
        ProgressStyle::with_template("{msg:>16} [{bar:40}] {pos}/{len} ({elapsed})")
            .expect("a valid template")
            .progress_chars("=> "),
    );
    b.set_message(what.to_string());
    b
}

/// What `train --from` fitted, before anything is written.
#[derive(Debug, Clone)]
pub struct Identification {
    pub model: Identified,
    pub recording: Recording,
    /// The calibrated arm as an `[arm]` file.
    pub twin: String,
    /// The model on the recording it was fitted to.
    pub check: Check,
    /// The configured arm's length, base to tip (m): what a fit's miss is judged against.
    pub arm_length_m: f64,
}

/// Calibrates the physical model and its residual to `recording` of `arm` (read by
/// [`read_recording`], or as softarm's own recordings are). Writes nothing.
pub fn identify(recording: Recording, arm: &Layout) -> Result<Identification, Error> {
    let structure = Structure::of(arm);
    let needed = ROWS_PER_PARAMETER * structure.slots.count();
    if recording.len() < needed {
        return Err(RecordingError {
            file: recording.path.clone(),
            line: None,
            column: None,
            message: format!(
                "{} rows; calibrating this arm's {} parameters needs at least {needed}",
                recording.len(),
                structure.slots.count()
            ),
        }
        .into());
    }
    let motions = recording.motions();
    let samples: Vec<Sample> = (recording.rows.iter())
        .map(|r| Sample {
            pull_m: r.pull_m.clone(),
            tip_m: r.tip_m,
            group: motions.binary_search(&r.motion).unwrap_or(0),
        })
        .collect();
    let nominal = structure.nominal(arm);
    let fits = (fit::STRENGTHS.len() * fit::FOLDS + 1) as u64;
    let progress = bar(fits, "calibrating");
    let calibration = fit::calibrate(&structure, &nominal, &samples, &mut || progress.inc(1));
    progress.finish_and_clear();
    let scale_m: Vec<f64> = (arm.actuators().iter())
        .map(|a| (a.max_m - a.min_m).abs())
        .collect();
    let candidates = (residual::WIDTHS.len() * residual::RIDGES.len() * fit::FOLDS) as u64;
    let progress = bar(candidates, "residual");
    let (learnt, tried) = fit::residual(&structure, &calibration, &samples, &scale_m, &mut || {
        progress.inc(1)
    });
    progress.finish_and_clear();
    let source = (recording.path.file_name()).map_or_else(
        || recording.path.display().to_string(),
        |n| n.to_string_lossy().into(),
    );
    let model = Identified {
        format: FORMAT,
        arm: arm.identity(),
        recording: source.clone(),
        rows: recording.len(),
        strength: calibration.strength,
        validated: (calibration.validated.iter())
            .map(|v| [v.strength, v.held_out_rms_m * 1e3])
            .collect(),
        fitted_rms_mm: calibration.fitted.rms_m * 1e3,
        theta: calibration.fitted.theta,
        residual_validated: (tried.iter())
            .map(|t| ResidualTried {
                width: t.width_ridge.map(|(w, _)| w),
                ridge: t.width_ridge.map(|(_, r)| r),
                held_out_rms_mm: t.held_out_rms_m * 1e3,
            })
            .collect(),
        residual: learnt,
    };
    let check = check_model(&model, arm, &recording, false);
    let twin = file::twin(arm, &model.theta, &source);
    let slots = structure.slots;
    let arm_length_m = (0..slots.modules)
        .map(|m| nominal[slots.length(m)])
        .sum::<f64>()
        + arm.connector_m * slots.modules.saturating_sub(1) as f64
        + arm.tool_m;
    Ok(Identification {
        model,
        recording,
        twin,
        check,
        arm_length_m,
    })
}

impl Identification {
    /// Writes the model and the twin into `out` ([`MODEL_FILE`], [`TWIN_FILE`]), each
    /// atomically; the paths written.
    pub fn write(&self, out: &Path) -> Result<(PathBuf, PathBuf), Error> {
        let model_path = out.join(MODEL_FILE);
        let twin_path = out.join(TWIN_FILE);
        fn failed(path: &Path) -> impl FnOnce(std::io::Error) -> Error + '_ {
            move |e| Error::Write {
                path: path.into(),
                message: e.to_string(),
            }
        }
        softarm_runtime::file::write_atomic(&twin_path, self.twin.as_bytes(), None)
            .map_err(failed(&twin_path))?;
        self.model.write(&model_path).map_err(failed(&model_path))?;
        Ok((model_path, twin_path))
    }

    /// What was fitted and chosen, in a few lines for the user.
    pub fn summary(&self) -> String {
        let m = &self.model;
        let strengths: Vec<(String, f64)> = (m.validated.iter())
            .map(|[s, rms]| (format!("{s}"), *rms))
            .collect();
        let residuals: Vec<(String, f64)> = (m.residual_validated.iter())
            .map(|t| match (t.width, t.ridge) {
                (Some(w), Some(r)) => (format!("{w}/{r}"), t.held_out_rms_mm),
                _ => ("none".into(), t.held_out_rms_mm),
            })
            .collect();
        let chosen = match &m.residual {
            Some(r) => format!("width {} strokes, ridge {}", r.width, r.ridge),
            None => "none".into(),
        };
        // A fit this far off its own rows is a map that reads the recording wrong, most often.
        let warning = if m.fitted_rms_mm > 100.0 * self.arm_length_m {
            format!(
                "warning: the physical model misses the rows it was fitted to by {:.0} mm RMS, a \
                 tenth of the arm's length or more: check the column map's units and signs, \
                 zero_length_m, and where the base is (tip.base_origin_m, base_rotation_deg)\n",
                m.fitted_rms_mm
            )
        } else {
            String::new()
        };
        format!(
            "calibrated the arm's physical model to {} ({} rows): on those rows it misses by \
             {:.2} mm RMS, with its residual by {:.2} mm ({:.2} with the mean offset removed)\n\
             {warning}the prior's strength: {}\n{}the residual (a kernel correction over the \
             pulls; none: the physical model alone): {chosen}\n{}",
            m.recording,
            m.rows,
            m.fitted_rms_mm,
            self.check.all.rms_mm,
            self.check.all.offset_removed_rms_mm,
            m.strength,
            tried_table("strength", &strengths),
            tried_table("width/ridge", &residuals),
        )
    }
}

/// Candidates and their RMS over held-out motions (mm), as indented lines of as many as fit
/// in 100 columns: what `train --from` prints of each choice it made.
pub fn tried_table(what: &str, tried: &[(String, f64)]) -> String {
    let cell = |(name, rms): &(String, f64)| format!("{name}: {rms:.2}");
    let width = tried.iter().map(|t| cell(t).len()).max().unwrap_or(0);
    let mut out = format!("  {what}, RMS mm over held-out motions:\n");
    for row in tried.chunks((96 / (width + 3)).max(1)) {
        let cells: Vec<String> = row.iter().map(|t| format!("{:<width$}", cell(t))).collect();
        out += &format!("    {}\n", cells.join("   ").trim_end());
    }
    out
}

/// The model on every row of `recording`; `physical_only`: without its residual.
pub fn check_model(
    model: &Identified,
    arm: &Layout,
    recording: &Recording,
    physical_only: bool,
) -> Check {
    let structure = Structure::of(arm);
    let predict = model.predictor(&structure, physical_only);
    let progress = bar(recording.len() as u64, "checking");
    let c = check::check(recording, predict, &mut || progress.inc(1));
    progress.finish_and_clear();
    c
}

/// Reads `recording_path` through the map at `columns_path` onto `arm`.
pub fn read_recording(
    recording_path: &Path,
    columns_path: &Path,
    arm: &Layout,
) -> Result<Recording, Error> {
    let columns = Columns::load(columns_path)?;
    Ok(recording::read(recording_path, &columns, arm)?)
}
