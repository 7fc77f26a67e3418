//! Way-point sets: the TOML file users write, and the validation the controller (and `softarm
//! submit`, before it sends) applies. Pure: no I/O but reading the file given.

use std::path::Path;

use serde::Deserialize;
use softarm_ipc::{MAX_WAYPOINTS, WaypointSet};

use crate::config::WaypointLimits;
use softarm_method::activation::ActivationConfig;

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

    pub fn parse(text: &str) -> Result<Self, String> {
        toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| format!("line {}: ", text[..s.start].lines().count().max(1)))
                .unwrap_or_default();
            format!("{line}{}", e.message())
        })
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
            "duration {d} s is outside [{}, {}] s",
            limits.min_duration_s, limits.max_duration_s
        ));
    }
    if set.executions == 0 || set.executions > limits.max_executions {
        return Err(format!(
            "{} executions; 1 to {} are allowed",
            set.executions, limits.max_executions
        ));
    }
    let need = activation.window_s + activation.crossfade_s;
    for i in 0..n {
        let t = set.times_s[i];
        let p = set.positions_m[i];
        if !t.is_finite() || p.iter().any(|v| !v.is_finite()) {
            return Err(format!(
                "point {}: time and position must be finite numbers",
                i + 1
            ));
        }
        if !(t > 0.0 && t <= d) {
            return Err(format!("point {}: time {t} s is outside (0, {d}] s", i + 1));
        }
        if i > 0 {
            let gap = t - set.times_s[i - 1];
            if gap <= 0.0 {
                return Err(format!(
                    "point {}: times must increase strictly ({t} s follows {} s)",
                    i + 1,
                    set.times_s[i - 1]
                ));
            }
            if gap < need - 1e-9 {
                return Err(format!(
                    "points {} and {} are {gap:.3} s apart; they need at least {need:.3} s \
                     (activation window_s + crossfade_s)",
                    i,
                    i + 1
                ));
            }
        }
        for a in 0..3 {
            if p[a] < limits.workspace_min_m[a] || p[a] > limits.workspace_max_m[a] {
                return Err(format!(
                    "point {}: position {:?} m is outside the workspace box {:?}..{:?} m",
                    i + 1,
                    p,
                    limits.workspace_min_m,
                    limits.workspace_max_m
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> WaypointLimits {
        WaypointLimits {
            workspace_min_m: [-0.45, -0.45, -0.6],
            workspace_max_m: [0.45, 0.45, 0.05],
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
        check(
            &|s| s.positions_m[1][0] = f64::NAN,
            "point 2: time and position must be finite",
        );
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
}
