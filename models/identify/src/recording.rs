//! A lab's recording of its arm, read through a column map: per row a time, each actuator's
//! value, the tip as the motion capture saw it, and optionally the motion it belongs to.
//!
//! Every value is checked as it is read; an error names the file, the line and the column,
//! and nothing is kept of a recording that has one.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use softarm_arm::{Kind, Layout};

/// What is wrong with a recording or its column map, and where.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}{}{}: {message}", file.display(), line.map(|l| format!(":{l}")).unwrap_or_default(), column.as_ref().map(|c| format!(": column `{c}`")).unwrap_or_default())]
pub struct RecordingError {
    pub file: PathBuf,
    /// The line (1 = the header), where one is to blame.
    pub line: Option<u64>,
    pub column: Option<String>,
    pub message: String,
}

/// How a recording's columns map onto the arm (a TOML file, e.g.
/// `config/recordings/opencr-tdcr.toml`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Columns {
    /// The time of each row; it may not go backwards.
    pub time: TimeColumn,
    /// The motion each row belongs to (e.g. `rep1_seg2_dir90`): cross-validation holds out
    /// whole motions, and the check reports per family of them. Without one, each 30 s of
    /// the recording is a motion.
    #[serde(default)]
    pub label: Option<String>,
    /// A label ending in this marks a row held at the end of its motion (same motion).
    #[serde(default = "hold_suffix")]
    pub hold_suffix: String,
    /// How many `_`-separated words of a motion name its family (`seg2_dir90` → `seg2_dir90`
    /// at 2), after a leading repetition word (`rep1`) is dropped.
    #[serde(default = "family_words")]
    pub family_words: usize,
    /// One per actuator, in the arm's order.
    pub actuators: Vec<ActuatorColumn>,
    pub tip: TipColumns,
}

fn hold_suffix() -> String {
    "_hold".into()
}
fn family_words() -> usize {
    2
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeColumn {
    pub column: String,
    /// `s`, `ms`, `us` or `ns`.
    pub unit: String,
}

/// One actuator's column: a tendon's displacement.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActuatorColumn {
    pub column: String,
    /// `m`, `cm` or `mm`.
    pub unit: String,
    /// +1: a larger value pulls the tendon in (shortens it in the arm); −1: it lets it out.
    #[serde(default = "one")]
    pub sign: f64,
    /// The tendon's length (m, as `[arm]`'s `length_m` measures it) where the value is 0;
    /// absent, the middle of its stroke.
    #[serde(default)]
    pub zero_length_m: Option<f64>,
}

fn one() -> f64 {
    1.0
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TipColumns {
    /// x, y, z.
    pub columns: [String; 3],
    /// `m`, `cm` or `mm`.
    pub unit: String,
    /// Where the arm's base is in the recording's frame (m, in `unit`s' frame): positions are
    /// taken to the base frame softarm's tracker reports in (z up; a standing arm points along
    /// +z, a hanging one along −z). The calibration finds what is left: a few degrees of tilt,
    /// centimetres of offset.
    #[serde(default)]
    pub base_origin_m: [f64; 3],
    /// How the base frame is turned in the recording's frame (degrees about x, then y, then
    /// z, each about the fixed axes).
    #[serde(default)]
    pub base_rotation_deg: [f64; 3],
}

impl TipColumns {
    /// A recorded position (m) in the base frame.
    fn to_base(&self, p: [f64; 3]) -> [f64; 3] {
        let [rx, ry, rz] = self.base_rotation_deg.map(f64::to_radians);
        let r = nalgebra::Rotation3::from_euler_angles(rx, ry, rz);
        let o = nalgebra::Vector3::from(self.base_origin_m);
        let b = r.inverse() * (nalgebra::Vector3::from(p) - o);
        [b.x, b.y, b.z]
    }
}

/// One row: a settled pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// The line it was read from.
    pub line: u64,
    pub time_s: f64,
    /// Each actuator's pull from the recording's zero (m): the tendon that much shorter.
    pub pull_m: Vec<f64>,
    /// The tip (m, base frame).
    pub tip_m: [f64; 3],
    /// Its motion (the label without the hold marker); empty without labels.
    pub motion: String,
    pub hold: bool,
}

/// A checked recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    pub path: PathBuf,
    pub rows: Vec<Row>,
    /// Each actuator's length (m) where its value is 0: a pull p puts it at zero − p.
    pub zero_length_m: Vec<f64>,
    family_words: usize,
}

impl Recording {
    /// A recording of `rows` read some other way: `zero_length_m` as [`Recording::zero_length_m`],
    /// families of `family_words` words.
    pub fn new(
        path: PathBuf,
        rows: Vec<Row>,
        zero_length_m: Vec<f64>,
        family_words: usize,
    ) -> Self {
        Self {
            path,
            rows,
            zero_length_m,
            family_words,
        }
    }

    /// The family of a motion: its first words after a repetition word (`rep1_`).
    pub fn family_of(&self, motion: &str) -> String {
        family(motion, self.family_words)
    }

    /// The class of a motion, for its primitive: its first word without digits (`seg2_dir90`
    /// → `seg`), after a repetition word.
    pub fn class_of(&self, motion: &str) -> String {
        let first = family(motion, 1);
        let word: String = first.chars().filter(|c| !c.is_ascii_digit()).collect();
        if word.is_empty() { first } else { word }
    }

    /// The motions, each once, sorted.
    pub fn motions(&self) -> Vec<String> {
        let set: BTreeSet<&str> = self.rows.iter().map(|r| r.motion.as_str()).collect();
        set.into_iter().map(str::to_string).collect()
    }

    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }
}

fn family(motion: &str, words: usize) -> String {
    let mut parts: Vec<&str> = motion.split('_').collect();
    let repetition = |w: &str| {
        w.strip_prefix("rep")
            .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
    };
    if parts.len() > 1 && repetition(parts[0]) {
        parts.remove(0);
    }
    parts.truncate(words.max(1));
    parts.join("_")
}

/// Seconds of an unlabelled recording that make one motion, for cross-validation.
pub const STRETCH_S: f64 = 30.0;

/// The motion of an unlabelled row `since_s` after the first: its [`STRETCH_S`] stretch.
pub fn stretch(since_s: f64) -> String {
    format!("t{:06.0}", (since_s / STRETCH_S).floor() * STRETCH_S)
}

fn length_unit(unit: &str) -> Option<f64> {
    match unit {
        "m" => Some(1.0),
        "cm" => Some(1e-2),
        "mm" => Some(1e-3),
        _ => None,
    }
}

fn time_unit(unit: &str) -> Option<f64> {
    match unit {
        "s" => Some(1.0),
        "ms" => Some(1e-3),
        "us" => Some(1e-6),
        "ns" => Some(1e-9),
        _ => None,
    }
}

impl Columns {
    /// Reads a column map; an error names the file and its line.
    pub fn load(path: &Path) -> Result<Self, RecordingError> {
        let text = std::fs::read_to_string(path).map_err(|e| RecordingError {
            file: path.into(),
            line: None,
            column: None,
            message: format!("cannot read the column map: {e}"),
        })?;
        Self::parse(path, &text)
    }

    /// What can be checked of the map without the recording, on the arm it is for: one column
    /// per actuator, a tendon each, units that parse, signs of 1 or -1, zeros inside the
    /// strokes. `softarm config check` runs it alone; [`read`] first, for the units' scales.
    pub fn check(&self, path: &Path, arm: &Layout) -> Result<Scales, RecordingError> {
        let at = |column: Option<&str>, message: String| RecordingError {
            file: path.into(),
            line: None,
            column: column.map(str::to_string),
            message,
        };
        let n = arm.actuators().len();
        if let Some(a) = arm.actuators().iter().find(|a| a.kind != Kind::Tendon) {
            return Err(at(
                None,
                format!(
                    "actuator {} is a chamber: identification from a recording models tendon arms",
                    a.name
                ),
            ));
        }
        if self.actuators.len() != n {
            let names: Vec<&str> = arm.names().collect();
            return Err(at(
                None,
                format!(
                    "the column map names {} actuators; the arm has {n} ({}): one column each, in \
                 the arm's order (is it the recording's arm? give it with --arm)",
                    self.actuators.len(),
                    names.join(", ")
                ),
            ));
        }
        if let Some(v) = (self.tip.base_origin_m.iter())
            .chain(&self.tip.base_rotation_deg)
            .find(|v| !v.is_finite())
        {
            return Err(at(
                None,
                format!("tip.base_origin_m and tip.base_rotation_deg are numbers, not {v}"),
            ));
        }
        let unit = |column: &str, unit: &str, parse: fn(&str) -> Option<f64>, give: &str| {
            parse(unit).ok_or_else(|| {
                at(
                    Some(column),
                    format!("unit `{unit}` does not parse: give {give}"),
                )
            })
        };
        let lengths = "m, cm or mm";
        let scales = Scales {
            time: unit(
                &self.time.column,
                &self.time.unit,
                time_unit,
                "s, ms, us or ns",
            )?,
            actuators: (self.actuators.iter())
                .map(|a| unit(&a.column, &a.unit, length_unit, lengths))
                .collect::<Result<_, _>>()?,
            tip: unit(&self.tip.columns[0], &self.tip.unit, length_unit, lengths)?,
        };
        let strokes = self.strokes(arm);
        for (i, c) in self.actuators.iter().enumerate() {
            if !(c.sign == 1.0 || c.sign == -1.0) {
                return Err(at(
                    Some(&c.column),
                    format!("sign = {}: give 1 or -1", c.sign),
                ));
            }
            let (lo, hi, zero) = strokes[i];
            if !(lo..=hi).contains(&zero) {
                return Err(at(
                    Some(&c.column),
                    format!(
                        "zero_length_m = {zero} is outside actuator {}'s stroke, {lo} to {hi} m",
                        arm.actuators()[i].name
                    ),
                ));
            }
        }
        Ok(scales)
    }

    /// Each actuator's stroke, as lengths (m), and its length at the recording's zero.
    fn strokes(&self, arm: &Layout) -> Vec<(f64, f64, f64)> {
        (arm.actuators().iter().zip(&self.actuators))
            .map(|(a, c)| {
                let (lo, hi) = (a.min_m.min(a.max_m), a.min_m.max(a.max_m));
                (lo, hi, c.zero_length_m.unwrap_or(0.5 * (lo + hi)))
            })
            .collect()
    }

    pub fn parse(path: &Path, text: &str) -> Result<Self, RecordingError> {
        toml::from_str(text).map_err(|e| RecordingError {
            file: path.into(),
            line: e
                .span()
                .map(|s| 1 + text[..s.start].bytes().filter(|b| *b == b'\n').count() as u64),
            column: None,
            message: e.message().to_string(),
        })
    }
}

/// What each unit of a column map multiplies its values by: to seconds, to metres.
#[derive(Debug, Clone, PartialEq)]
pub struct Scales {
    pub time: f64,
    pub actuators: Vec<f64>,
    pub tip: f64,
}

/// A value of a column the map names.
struct Field {
    index: usize,
    name: String,
    scale: f64,
}

/// Reads `path` (CSV, a header line first) as `columns` maps it onto `arm`. Refused, naming
/// the file, line and column: a column the file lacks, a unit that does not parse, fewer or
/// more actuators than the arm, a value that is not a finite number, time going backwards,
/// an actuator outside its stroke, an arm with chambers.
pub fn read(path: &Path, columns: &Columns, arm: &Layout) -> Result<Recording, RecordingError> {
    let at = |line: Option<u64>, column: Option<&str>, message: String| RecordingError {
        file: path.into(),
        line,
        column: column.map(str::to_string),
        message,
    };
    let scales = columns.check(path, arm)?;
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(path)
        .map_err(|e| at(None, None, format!("cannot read the recording: {e}")))?;
    let header = reader
        .headers()
        .map_err(|e| at(Some(1), None, format!("no header line: {e}")))?
        .clone();
    let find = |name: &str, scale: f64| -> Result<Field, RecordingError> {
        let index = header.iter().position(|h| h == name).ok_or_else(|| {
            at(
                Some(1),
                Some(name),
                match header.is_empty() {
                    true => "the recording has no such column: it has no header (is it empty?)"
                        .to_string(),
                    false => format!(
                        "the recording has no such column; it has: {}",
                        header.iter().collect::<Vec<_>>().join(", ")
                    ),
                },
            )
        })?;
        Ok(Field {
            index,
            name: name.into(),
            scale,
        })
    };
    let time = find(&columns.time.column, scales.time)?;
    let actuators: Vec<Field> = (columns.actuators.iter().zip(&scales.actuators))
        .map(|(a, scale)| find(&a.column, *scale))
        .collect::<Result<_, _>>()?;
    let tip: Vec<Field> = (columns.tip.columns.iter())
        .map(|c| find(c, scales.tip))
        .collect::<Result<_, _>>()?;
    let label = match &columns.label {
        Some(l) => Some(find(l, 1.0).map(|f| f.index)?),
        None => None,
    };
    let strokes = columns.strokes(arm);

    let mut rows = Vec::new();
    let mut last_time = f64::NEG_INFINITY;
    let mut first_time = None;
    for record in reader.records() {
        let record = record.map_err(|e| {
            let line = e.position().map(|p| p.line());
            at(line, None, format!("not a CSV row: {e}"))
        })?;
        let line = record.position().map_or(0, |p| p.line());
        let number = |f: &Field| -> Result<f64, RecordingError> {
            let text = record.get(f.index).unwrap_or("");
            let v: f64 = text.parse().map_err(|_| {
                at(
                    Some(line),
                    Some(&f.name),
                    format!("`{text}` is not a number"),
                )
            })?;
            if !v.is_finite() {
                return Err(at(
                    Some(line),
                    Some(&f.name),
                    format!("{text} is not a finite number"),
                ));
            }
            Ok(v * f.scale)
        };
        let time_s = number(&time)?;
        if time_s < last_time {
            return Err(at(
                Some(line),
                Some(&time.name),
                format!("time goes backwards: {time_s} s after {last_time} s"),
            ));
        }
        last_time = time_s;
        let mut pull_m = Vec::with_capacity(actuators.len());
        for (i, f) in actuators.iter().enumerate() {
            let pull = columns.actuators[i].sign * number(f)?;
            let (lo, hi, zero) = strokes[i];
            let length = zero - pull;
            if !(lo - 1e-12..=hi + 1e-12).contains(&length) {
                return Err(at(
                    Some(line),
                    Some(&f.name),
                    format!(
                        "{:.4} mm puts actuator {} at {length:.5} m, outside its stroke, {lo} \
                         to {hi} m (`[arm]`'s length_m): check the column's unit, sign and \
                         zero_length_m, and the arm's strokes",
                        pull * 1e3,
                        arm.actuators()[i].name
                    ),
                ));
            }
            pull_m.push(pull);
        }
        let mut recorded = [0.0; 3];
        for (k, f) in tip.iter().enumerate() {
            recorded[k] = number(f)?;
        }
        let tip_m = columns.tip.to_base(recorded);
        let first_time = *first_time.get_or_insert(time_s);
        let (motion, hold) = match label.and_then(|i| record.get(i)) {
            Some(raw) => {
                let hold = !columns.hold_suffix.is_empty() && raw.ends_with(&columns.hold_suffix);
                let end = raw.len() - if hold { columns.hold_suffix.len() } else { 0 };
                (raw[..end].to_string(), hold)
            }
            // Unlabelled: its stretches of time are its motions.
            None => (stretch(time_s - first_time), false),
        };
        rows.push(Row {
            line,
            time_s,
            pull_m,
            tip_m,
            motion,
            hold,
        });
    }
    Ok(Recording {
        path: path.into(),
        rows,
        zero_length_m: strokes.iter().map(|s| s.2).collect(),
        family_words: columns.family_words,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arm() -> softarm_arm::Layout {
        crate::test_arm()
    }

    fn columns() -> Columns {
        let mut text = String::from(
            "time = { column = \"t\", unit = \"s\" }\nlabel = \"label\"\n\
             tip = { columns = [\"x\", \"y\", \"z\"], unit = \"mm\" }\n",
        );
        for i in 1..=6 {
            text.push_str(&format!(
                "[[actuators]]\ncolumn = \"a{i}\"\nunit = \"mm\"\n"
            ));
        }
        Columns::parse(Path::new("map.toml"), &text).unwrap()
    }

    const HEADER: &str = "t,label,a1,a2,a3,a4,a5,a6,x,y,z\n";

    fn read_text(text: &str) -> Result<Recording, RecordingError> {
        let dir = std::env::temp_dir().join(format!("softarm-recording-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!("{:x}.csv", fnv(text)));
        std::fs::write(&path, text).unwrap();
        let r = read(&path, &columns(), &arm());
        std::fs::remove_file(&path).unwrap();
        r
    }

    fn fnv(s: &str) -> u64 {
        s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
        })
    }

    #[test]
    fn a_recording_is_read_in_metres_with_its_motions() {
        let r = read_text(&format!(
            "{HEADER}1.0,rep1_seg1_dir0,1,0,0,0,0,0,10,20,200\n\
             1.5,rep1_seg1_dir0_hold,2,0,0,0,0,-10,11,20,199\n"
        ))
        .unwrap();
        assert_eq!(r.len(), 2);
        assert!((r.rows[1].pull_m[0] - 0.002).abs() < 1e-15);
        assert!((r.rows[1].pull_m[5] + 0.010).abs() < 1e-15);
        assert_eq!(r.rows[0].tip_m, [0.01, 0.02, 0.2]);
        assert!(r.rows[1].hold && !r.rows[0].hold);
        // The recording's frame with the base 1 m up and turned upside down about x.
        let mut c = columns();
        c.tip.base_origin_m = [0.0, 0.0, 1.0];
        c.tip.base_rotation_deg = [180.0, 0.0, 0.0];
        let p = c.tip.to_base([0.01, 0.02, 0.8]);
        assert!(
            (p[0] - 0.01).abs() < 1e-12 && (p[1] + 0.02).abs() < 1e-12,
            "{p:?}"
        );
        assert!((p[2] - 0.2).abs() < 1e-12, "{p:?}");
        assert_eq!(r.motions(), vec!["rep1_seg1_dir0".to_string()]);
        assert_eq!(r.family_of("rep1_seg1_dir0"), "seg1_dir0");
        assert_eq!(r.family_of("rep12_all3_spiral_dir90"), "all3_spiral");
        assert_eq!(r.family_of("circle"), "circle");
        // Without labels: 30 s stretches.
        let mut c = columns();
        c.label = None;
        let dir = std::env::temp_dir();
        let path = dir.join(format!("softarm-unlabelled-{}.csv", std::process::id()));
        let rows: String = (0..4)
            .map(|k| format!("{},m,0,0,0,0,0,0,0,0,200\n", 100.0 + 20.0 * k as f64))
            .collect();
        std::fs::write(&path, format!("{HEADER}{rows}")).unwrap();
        let u = read(&path, &c, &arm()).unwrap();
        std::fs::remove_file(&path).unwrap();
        let motions: Vec<&str> = u.rows.iter().map(|r| r.motion.as_str()).collect();
        assert_eq!(motions, ["t000000", "t000000", "t000030", "t000060"]);
        assert_eq!(r.class_of("rep1_seg12_dir0"), "seg");
        assert_eq!(r.class_of("rep1_7"), "7");
        assert!((r.zero_length_m[3] - 0.2).abs() < 1e-12);
    }

    fn error(text: &str) -> RecordingError {
        read_text(&format!("{HEADER}{text}")).unwrap_err()
    }

    #[test]
    fn bad_values_are_refused_with_their_line_and_column() {
        let ok = "0,m,0,0,0,0,0,0,0,0,200\n";
        let e = error(&format!("{ok}1,m,0,0,x1,0,0,0,0,0,200\n"));
        assert_eq!((e.line, e.column.as_deref()), (Some(3), Some("a3")), "{e}");
        assert!(e.to_string().contains("`x1` is not a number"), "{e}");
        let e = error(&format!("{ok}1,m,0,0,0,0,0,0,NaN,0,200\n"));
        assert_eq!((e.line, e.column.as_deref()), (Some(3), Some("x")), "{e}");
        let e = error(&format!("{ok}-1,m,0,0,0,0,0,0,0,0,200\n"));
        assert_eq!((e.line, e.column.as_deref()), (Some(3), Some("t")), "{e}");
        assert!(e.message.contains("backwards"), "{e}");
        let e = error(&format!("{ok}1,m,0,0,0,0,13,0,0,0,200\n"));
        assert_eq!((e.line, e.column.as_deref()), (Some(3), Some("a5")), "{e}");
        assert!(e.message.contains("outside its stroke"), "{e}");
        let e = error(&format!("{ok}1,m,0,0,0\n"));
        assert_eq!(e.line, Some(3), "{e}");
    }

    #[test]
    fn a_map_that_does_not_fit_the_file_or_the_arm_is_refused() {
        let dir = std::env::temp_dir();
        let path = dir.join(format!("softarm-map-{}.csv", std::process::id()));
        std::fs::write(&path, format!("{HEADER}0,m,0,0,0,0,0,0,0,0,200\n")).unwrap();
        let mut c = columns();
        c.actuators[2].column = "servo_9".into();
        let e = read(&path, &c, &arm()).unwrap_err();
        assert_eq!(
            (e.line, e.column.as_deref()),
            (Some(1), Some("servo_9")),
            "{e}"
        );
        let mut c = columns();
        c.tip.unit = "furlong".into();
        let e = read(&path, &c, &arm()).unwrap_err();
        assert!(
            e.to_string()
                .contains("`furlong` does not parse: give m, cm or mm"),
            "{e}"
        );
        let mut c = columns();
        c.actuators.pop();
        let e = read(&path, &c, &arm()).unwrap_err();
        assert!(
            e.message.contains("names 5 actuators; the arm has 6"),
            "{e}"
        );
        std::fs::remove_file(&path).unwrap();
        let e = read_text("").unwrap_err();
        assert!(e.message.contains("it has no header (is it empty?)"), "{e}");
        let e = Columns::parse(Path::new("map.toml"), "time = 3\n").unwrap_err();
        assert_eq!(e.line, Some(1), "{e}");
    }
}
