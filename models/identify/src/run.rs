//! The commands: `softarm train --from` (a recording → an identified model and its twin) and
//! `softarm model check` (a model against a recording), with progress for people.

use std::cell::RefCell;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use softarm_arm::Layout;

use crate::check::{self, Check};
use crate::file::{self, CandidateTried, FORMAT, Identified, ModelFileError, ResidualTried};
use crate::fit::{self, Sample};
use crate::recording::{self, Columns, Recording, RecordingError};
use crate::residual;
use crate::tendon::{Slots, Structure};

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

/// The model `softarm model check --model` names: the file, or the folder `train --from` wrote
/// it in; without one, the one in `model_dir` (the config's model folder).
pub fn model_file(given: Option<PathBuf>, model_dir: &Path) -> PathBuf {
    match given {
        Some(dir) if dir.is_dir() => dir.join(MODEL_FILE),
        Some(file) => file,
        None => model_dir.join(MODEL_FILE),
    }
}

/// Rows a fit needs at least, per parameter: each row gives three numbers.
const ROWS_PER_PARAMETER: usize = 2;

/// Where progress goes: on a terminal a bar on stderr, elsewhere (a log under systemd, a pipe, a
/// test) a line at a time to `lines`, which callers on the calling thread only ever call.
#[derive(Clone, Copy)]
pub struct Output<'a> {
    pub terminal: bool,
    pub lines: &'a dyn Fn(&str),
}

impl Output<'static> {
    /// A bar when stderr is a terminal, else lines in the log (at info).
    pub fn log() -> Self {
        fn info(line: &str) {
            tracing::info!("{line}");
        }
        Self {
            terminal: std::io::stderr().is_terminal(),
            lines: &info,
        }
    }
}

/// The progress of a step that takes more than a few seconds, for people: on a terminal a bar
/// (what, how far, the time so far and left); elsewhere a line as it starts, at every tenth of
/// the way and as it ends, each with the count and the time left. What `train` and
/// `train --from` show of every such step.
pub struct Bar<'a> {
    bar: ProgressBar,
    lines: Option<RefCell<Lines<'a>>>,
}

/// A [`Bar`] as lines: how far it was at the last line.
struct Lines<'a> {
    what: String,
    len: u64,
    pos: u64,
    /// The next tenth of `len` that prints a line.
    next_tenth: u64,
    start: Instant,
    say: &'a dyn Fn(&str),
}

/// A progress bar of `len` for `what` to the log ([`Output::log`]).
pub fn bar(len: u64, what: &str) -> Bar<'static> {
    bar_to(len, what, Output::log())
}

/// A progress bar of `len` for `what` to `out`.
pub fn bar_to<'a>(len: u64, what: &str, out: Output<'a>) -> Bar<'a> {
    if !out.terminal {
        let lines = Lines {
            what: what.to_string(),
            len,
            pos: 0,
            next_tenth: 1,
            start: Instant::now(),
            say: out.lines,
        };
        (lines.say)(&format!("{what}: 0/{len}"));
        return Bar {
            bar: ProgressBar::hidden(),
            lines: Some(RefCell::new(lines)),
        };
    }
    let b = ProgressBar::new(len);
    b.set_style(
        ProgressStyle::with_template(
            "{msg:>16} [{bar:40}] {pos}/{len} ({elapsed}, about {eta} left)",
        )
        .expect("a valid template")
        .progress_chars("=> "),
    );
    b.set_message(what.to_string());
    Bar {
        bar: b,
        lines: None,
    }
}

impl Bar<'_> {
    pub fn inc(&self, delta: u64) {
        self.bar.inc(delta);
        self.moved(|pos| pos.saturating_add(delta));
    }

    pub fn set_position(&self, pos: u64) {
        self.bar.set_position(pos);
        self.moved(|_| pos);
    }

    /// A new length (a step that learns how long it is as it goes).
    pub fn set_length(&self, len: u64) {
        self.bar.set_length(len);
        if let Some(lines) = &self.lines {
            let mut l = lines.borrow_mut();
            l.len = len;
            l.next_tenth = next_tenth(l.pos, len);
        }
    }

    /// Gone from the terminal; in the log, a last line with the time it took.
    pub fn finish_and_clear(&self) {
        self.bar.finish_and_clear();
        if let Some(lines) = &self.lines {
            let l = lines.borrow();
            (l.say)(&format!(
                "{}: {}/{} done in {:.1} s",
                l.what,
                l.pos,
                l.len,
                l.start.elapsed().as_secs_f64()
            ));
        }
    }

    /// A line at each tenth of the way passed.
    fn moved(&self, to: impl FnOnce(u64) -> u64) {
        let Some(lines) = &self.lines else {
            return;
        };
        let mut l = lines.borrow_mut();
        l.pos = to(l.pos).min(l.len);
        if l.len == 0 || l.pos * 10 < l.next_tenth * l.len {
            return;
        }
        l.next_tenth = next_tenth(l.pos, l.len);
        let elapsed = l.start.elapsed().as_secs_f64();
        let left = elapsed * (l.len - l.pos) as f64 / l.pos.max(1) as f64;
        (l.say)(&format!(
            "{}: {}/{} ({} %), about {left:.0} s left",
            l.what,
            l.pos,
            l.len,
            l.pos * 100 / l.len
        ));
    }
}

/// The first tenth of `len` past `pos`.
fn next_tenth(pos: u64, len: u64) -> u64 {
    if len == 0 {
        return 1;
    }
    pos * 10 / len + 1
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
    /// Where each parameter sits in the model's.
    pub slots: Slots,
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
    let fits = fit::calibration_fits() as u64;
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
        gravity: calibration.terms.gravity,
        validated: (calibration.validated.iter())
            .map(|v| CandidateTried {
                strength: v.strength,
                gravity: v.terms.gravity,
                held_out_rms_mm: v.held_out_rms_m * 1e3,
            })
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
        slots,
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
            .map(|t| {
                let gravity = if t.gravity { " gravity" } else { "" };
                (format!("{}{gravity}", t.strength), t.held_out_rms_mm)
            })
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
             {warning}the prior's strength: {}, {}\n{}the residual (a kernel correction over the \
             pulls; none: the physical model alone): {chosen}\n{}",
            m.recording,
            m.rows,
            m.fitted_rms_mm,
            self.check.all.rms_mm,
            self.check.all.offset_removed_rms_mm,
            m.strength,
            gravity_said(m, self.slots),
            tried_table(
                "strength (gravity: each module's weight and a payload fitted)",
                &strengths
            ),
            tried_table("width/ridge", &residuals),
        )
    }
}

/// What the model's gravity is, for people: module 0's weight as a vector, the others' masses
/// and the payload's relative to it, or none.
pub fn gravity_said(model: &Identified, slots: Slots) -> String {
    if !model.gravity {
        return "no gravity".into();
    }
    let t = &model.theta;
    let vector: Vec<f64> = (0..3).map(|k| t[slots.gravity_vector(k)]).collect();
    let size = vector.iter().map(|v| v * v).sum::<f64>().sqrt();
    let masses: Vec<String> = (1..slots.modules)
        .map(|m| format!("{:.2}", t[slots.weight(m)]))
        .collect();
    format!(
        "gravity: module 1's weight {size:.2} /m of its bending stiffness, up along ({:.2}, \
         {:.2}, {:.2}) in the backbone's frame; the other modules' masses {} of module 1's, \
         the payload's {:.2}",
        vector[0] / size,
        vector[1] / size,
        vector[2] / size,
        masses.join(", "),
        t[slots.payload()]
    )
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
    let mut c = check::check(recording, predict, &mut || progress.inc(1));
    progress.finish_and_clear();
    c.terms = format!(
        "the physical model: {}",
        gravity_said(model, structure.slots)
    );
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_model_is_the_file_named_or_the_one_in_its_folder() {
        let dir = std::env::temp_dir();
        let models = Path::new("/models");
        assert_eq!(model_file(Some(dir.clone()), models), dir.join(MODEL_FILE));
        let file = PathBuf::from("/somewhere/mine.toml");
        assert_eq!(model_file(Some(file.clone()), models), file);
        assert_eq!(model_file(None, models), models.join(MODEL_FILE));
    }

    /// Off a terminal a bar is lines: named, at the start, at each tenth of the way (never
    /// going back, a new length taken as it comes) and at the end.
    #[test]
    fn off_a_terminal_a_bar_is_lines_at_each_tenth() {
        let lines = RefCell::new(Vec::<String>::new());
        let say = |l: &str| lines.borrow_mut().push(l.to_string());
        let out = Output {
            terminal: false,
            lines: &say,
        };
        let b = bar_to(40, "calibrating", out);
        for _ in 0..20 {
            b.inc(1);
        }
        // Half-way, it learns it is shorter: at three quarters now.
        b.set_length(27);
        b.set_position(27);
        b.finish_and_clear();
        let lines = lines.into_inner();
        assert!(
            lines.iter().all(|l| l.starts_with("calibrating: ")),
            "{lines:#?}"
        );
        assert_eq!(lines[0], "calibrating: 0/40");
        let done: Vec<u64> = (lines.iter())
            .map(|l| {
                l["calibrating: ".len()..]
                    .split('/')
                    .next()
                    .unwrap()
                    .parse()
                    .unwrap()
            })
            .collect();
        assert_eq!(done, [0, 4, 8, 12, 16, 20, 27, 27], "{lines:#?}");
        assert!(lines[1].contains("(10 %), about"), "{}", lines[1]);
        assert!(
            lines[6].starts_with("calibrating: 27/27 (100 %)"),
            "{}",
            lines[6]
        );
        assert!(lines[7].contains("done in"), "{}", lines[7]);
    }
}
