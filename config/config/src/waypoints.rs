//! Way-point sets: the TOML file users write, and the validation the controller (and `softarm
//! submit`, before it sends) applies. Pure: no I/O but reading the file given.

use std::path::Path;

use serde::Deserialize;
use softarm_ipc::WaypointSet;
use softarm_space::MAX_WAYPOINTS;

use crate::activation::ActivationConfig;
use crate::{MAX_DURATION_S, WaypointLimits, key_line, line_at};

/// A way-point file: `duration_s`, and `[[point]]` tables with `t_s` and `position_m`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WaypointFile {
    pub duration_s: f64,
    pub point: Vec<Point>,
}

#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Point {
    pub t_s: f64,
    pub position_m: [f64; 3],
}

impl WaypointFile {
    pub fn load(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
        Self::parse(&text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Reads a file and checks what it can alone (the config's limits are [`validate`]'s):
    /// 1 to `MAX_WAYPOINTS` points, finite numbers, a duration in (0, `MAX_DURATION_S`] s and
    /// times inside it that increase strictly. Errors name the point, the field and the line.
    pub fn parse(text: &str) -> Result<Self, String> {
        let file: Self = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| format!("line {}: ", line_at(text, s.start)))
                .unwrap_or_default();
            format!("{line}{}", e.message())
        })?;
        file.check()
            .map_err(|(key, message)| match key_line(text, &key) {
                Some(line) => format!("line {line}: {message}"),
                None => message,
            })?;
        Ok(file)
    }

    /// The file's own checks: (dotted key of the culprit, message).
    fn check(&self) -> Result<(), (String, String)> {
        let n = self.point.len();
        if n == 0 || n > MAX_WAYPOINTS {
            let key = if n == 0 {
                "point".to_string()
            } else {
                format!("point[{MAX_WAYPOINTS}]")
            };
            return Err((key, format!("{n} points; a set has 1 to {MAX_WAYPOINTS}")));
        }
        let d = self.duration_s;
        if !(d.is_finite() && d > 0.0 && d <= MAX_DURATION_S) {
            return Err((
                "duration_s".into(),
                format!("duration_s = {d} s is outside (0, {MAX_DURATION_S}] s"),
            ));
        }
        let times: Vec<f64> = self.point.iter().map(|p| p.t_s).collect();
        let positions: Vec<[f64; 3]> = self.point.iter().map(|p| p.position_m).collect();
        check_points(d, &times, &positions)
    }

    /// The request payload; more than `MAX_WAYPOINTS` points is an error here already.
    pub fn to_set(&self, executions: u32) -> Result<WaypointSet, String> {
        if self.point.len() > MAX_WAYPOINTS {
            return Err(format!(
                "{} points; at most {MAX_WAYPOINTS} are allowed",
                self.point.len()
            ));
        }
        let mut set = WaypointSet {
            duration_s: self.duration_s,
            executions,
            count: self.point.len() as u32,
            ..Default::default()
        };
        for (i, p) in self.point.iter().enumerate() {
            set.times_s[i] = p.t_s;
            set.positions_m[i] = p.position_m;
        }
        Ok(set)
    }
}

/// Finite times and positions, times in (0, duration] that increase strictly: (dotted key in a
/// way-point file, message naming the point).
fn check_points(
    duration: f64,
    times: &[f64],
    positions: &[[f64; 3]],
) -> Result<(), (String, String)> {
    for (i, (&t, p)) in times.iter().zip(positions).enumerate() {
        let n = i + 1;
        if !t.is_finite() {
            return Err((
                format!("point[{i}].t_s"),
                format!("point {n}: t_s = {t} is not a finite number"),
            ));
        }
        if let Some(a) = p.iter().position(|v| !v.is_finite()) {
            return Err((
                format!("point[{i}].position_m"),
                format!(
                    "point {n}: position_m {} ({}) = {} is not a finite number",
                    a + 1,
                    ["x", "y", "z"][a],
                    p[a]
                ),
            ));
        }
        if !(t > 0.0 && t <= duration) {
            return Err((
                format!("point[{i}].t_s"),
                format!("point {n}: time {t} s is outside (0, {duration}] s"),
            ));
        }
        if i > 0 && t <= times[i - 1] {
            return Err((
                format!("point[{i}].t_s"),
                format!(
                    "point {n}: times must increase strictly ({t} s follows {} s)",
                    times[i - 1]
                ),
            ));
        }
    }
    Ok(())
}

/// Everything the controller checks before it accepts a set. The reason names the point.
pub fn validate(
    set: &WaypointSet,
    limits: &WaypointLimits,
    activation: &ActivationConfig,
) -> Result<(), String> {
    let n = set.count as usize;
    if n == 0 || n > MAX_WAYPOINTS {
        return Err(format!("{n} points; a set has 1 to {MAX_WAYPOINTS}"));
    }
    let d = set.duration_s;
    if !(d.is_finite() && d >= limits.min_duration_s && d <= limits.max_duration_s) {
        return Err(format!(
            "duration {d} s is outside [{}, {}] s (the config's waypoints.min_duration_s and \
             max_duration_s)",
            limits.min_duration_s, limits.max_duration_s
        ));
    }
    if set.executions == 0 || set.executions > limits.max_executions {
        return Err(format!(
            "{} executions; 1 to {} are allowed (the config's waypoints.max_executions)",
            set.executions, limits.max_executions
        ));
    }
    let (times, positions) = (&set.times_s[..n], &set.positions_m[..n]);
    check_points(d, times, positions).map_err(|(_, message)| message)?;
    let need = activation.window_s + activation.crossfade_s;
    for i in 1..n {
        let gap = times[i] - times[i - 1];
        if gap < need - 1e-9 {
            return Err(format!(
                "points {} and {} are {gap:.3} s apart; they need at least {need:.3} s \
                 (activation window_s + crossfade_s)",
                i,
                i + 1
            ));
        }
    }
    let workspace = limits.workspace();
    if let Some(i) = positions.iter().position(|p| !workspace.contains(p)) {
        return Err(format!(
            "point {}: position {:?} m is outside the workspace box {:?}..{:?} m (the config's \
             waypoints.workspace_min_m and workspace_max_m)",
            i + 1,
            positions[i],
            workspace.min_m,
            workspace.max_m
        ));
    }
    let norm = |p: &[f64; 3]| p.iter().map(|v| v * v).sum::<f64>().sqrt();
    if let Some(i) = positions.iter().position(|p| norm(p) > limits.reach_m) {
        return Err(format!(
            "point {}: position {:?} m is {:.3} m from the base, beyond the arm's reach of {} m \
             (the config's waypoints.reach_m)",
            i + 1,
            positions[i],
            norm(&positions[i]),
            limits.reach_m
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use softarm_space::Workspace;

    fn limits() -> WaypointLimits {
        WaypointLimits {
            workspace_min_m: [-0.45, -0.45, -0.6],
            workspace_max_m: [0.45, 0.45, 0.05],
            reach_m: 0.6,
            min_duration_s: 1.0,
            max_duration_s: 60.0,
            max_executions: 100,
        }
    }

    const GOOD: &str = "duration_s = 4.0\n[[point]]\nt_s = 1.0\nposition_m = [0.1, 0.0, -0.45]\n\
                        [[point]]\nt_s = 3.0\nposition_m = [0.0, 0.1, -0.45]\n";

    #[test]
    fn a_good_set_passes() {
        let f = WaypointFile::parse(GOOD).unwrap();
        let set = f.to_set(3).unwrap();
        assert_eq!(set.count, 2);
        validate(&set, &limits(), &ActivationConfig::default()).unwrap();
    }

    #[test]
    fn bad_sets_name_what_is_wrong() {
        let a = ActivationConfig::default();
        let f = WaypointFile::parse(GOOD).unwrap();
        let check = |edit: &dyn Fn(&mut WaypointSet), want: &str| {
            let mut s = f.to_set(3).unwrap();
            edit(&mut s);
            let e = validate(&s, &limits(), &a).unwrap_err();
            assert!(e.contains(want), "{e} (wanted {want:?})");
        };
        check(&|s| s.times_s[1] = 5.0, "point 2: time 5 s is outside");
        check(&|s| s.times_s[1] = 0.5, "must increase strictly");
        check(&|s| s.times_s[1] = 1.2, "0.200 s apart");
        check(&|s| s.positions_m[0][2] = 0.3, "point 1: position");
        // Inside the box, beyond the arm: a corner of the box.
        check(
            &|s| s.positions_m[1] = [0.44, -0.44, 0.04],
            "point 2: position [0.44, -0.44, 0.04] m is 0.624 m from the base, beyond the arm's \
             reach of 0.6 m (the config's waypoints.reach_m)",
        );
        check(
            &|s| s.positions_m[1][0] = f64::NAN,
            "point 2: position_m 1 (x) = NaN is not a finite number",
        );
        check(
            &|s| s.times_s[0] = f64::INFINITY,
            "point 1: t_s = inf is not a finite number",
        );
        check(&|s| s.duration_s = 0.0, "duration 0 s is outside [1, 60] s");
        check(&|s| s.duration_s = f64::NAN, "duration NaN s");
        check(&|s| s.executions = 101, "101 executions; 1 to 100");
        check(&|s| s.count = 17, "17 points; a set has 1 to 16");
        check(&|s| s.count = u32::MAX, "points; a set has 1 to 16");
        check(&|s| s.duration_s = 100.0, "duration 100 s");
        check(&|s| s.executions = 0, "0 executions");
        check(&|s| s.count = 0, "0 points");
        assert!(
            WaypointFile::parse("duration_s = 1\nextra = 2")
                .unwrap_err()
                .contains("extra")
        );
        let e = WaypointFile::parse("duration_s = 1\n[[point]]\nt_s = 1\n").unwrap_err();
        assert!(e.contains("position_m"), "{e}");
    }

    fn file(points: usize) -> String {
        let mut s = String::from("duration_s = 100.0\n");
        for i in 0..points {
            s += &format!(
                "[[point]]\nt_s = {}.0\nposition_m = [0.0, 0.0, -0.5]\n",
                i + 1
            );
        }
        s
    }

    /// The message, and the line of the first line of `text` starting with `needle`.
    fn refused(text: &str, needle: &str, want: &str) {
        let e = WaypointFile::parse(text).unwrap_err();
        let line = text.lines().position(|l| l.starts_with(needle)).unwrap() + 1;
        assert!(
            e.starts_with(&format!("line {line}: ")),
            "{e} (wanted line {line})"
        );
        assert!(e.contains(want), "{e} (wanted {want:?})");
    }

    #[test]
    fn files_are_refused_with_the_point_field_and_line() {
        WaypointFile::parse(&file(MAX_WAYPOINTS)).unwrap();
        let many = file(MAX_WAYPOINTS + 1);
        let e = WaypointFile::parse(&many).unwrap_err();
        assert!(e.contains("17 points; a set has 1 to 16"), "{e}");
        let last = many
            .match_indices("[[point]]")
            .nth(MAX_WAYPOINTS)
            .unwrap()
            .0;
        assert!(
            e.starts_with(&format!("line {}: ", line_at(&many, last))),
            "{e}"
        );
        refused("duration_s = 1.0\npoint = []\n", "point", "0 points");
        refused(
            &file(2).replace("t_s = 2.0", "t_s = nan"),
            "t_s = nan",
            "point 2: t_s = NaN",
        );
        refused(
            &file(2).replacen("[0.0, 0.0, -0.5]", "[0.0, inf, -0.5]", 1),
            "position_m = [0.0, inf",
            "point 1: position_m 2 (y) = inf is not a finite number",
        );
        refused(
            &file(3).replace("t_s = 3.0", "t_s = 1.5"),
            "t_s = 1.5",
            "point 3: times must increase strictly (1.5 s follows 2 s)",
        );
        refused(
            &file(2).replace("t_s = 2.0", "t_s = 2.0e3"),
            "t_s = 2.0e3",
            "point 2: time 2000 s is outside (0, 100] s",
        );
        for d in ["0.0", "-1.0", "inf", "nan", "1e300"] {
            let text = file(1).replace("duration_s = 100.0", &format!("duration_s = {d}"));
            refused(&text, "duration_s", "is outside (0, 3600] s");
        }
        // An empty file and a file without points are TOML errors, with their line.
        assert!(WaypointFile::parse("").unwrap_err().contains("duration_s"));
        let e = WaypointFile::parse("duration_s = 1.0\n").unwrap_err();
        assert!(e.contains("point"), "{e}");
    }

    #[test]
    fn nothing_panics_on_too_many_points() {
        let f = WaypointFile {
            duration_s: 100.0,
            point: vec![
                Point {
                    t_s: 1.0,
                    position_m: [0.0, 0.0, -0.5],
                };
                MAX_WAYPOINTS + 4
            ],
        };
        assert!(f.to_set(1).unwrap_err().contains("20 points"));
        let set = WaypointSet {
            count: 1000,
            ..Default::default()
        };
        assert!(validate(&set, &limits(), &ActivationConfig::default()).is_err());
    }

    #[test]
    fn the_workspace_is_the_limits_box() {
        let w = limits().workspace();
        assert_eq!(Workspace::new(w.min_m, w.max_m), Ok(w));
        assert!(w.contains(&[0.45, -0.45, -0.6]));
        assert!(!w.contains(&[0.0, 0.0, 0.06]));
    }
}
