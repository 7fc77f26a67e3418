//! `softarm stats`: the error at each conditioning point per execution.

use std::time::Duration;

use softarm_ipc::{ExecutionStats, Namespace, Node, Sub};

/// Estimates of an execution that were not in force when it ran: the learner's (or the
/// replanning's) answer came after the point's group had started. None for a set's first
/// execution, which runs on the first estimates whatever comes during it.
pub fn late_estimates(s: &ExecutionStats) -> u32 {
    if s.execution <= 1 {
        0
    } else {
        s.count.saturating_sub(s.reconditions)
    }
}

/// One JSON object per execution: `execution`, `errors_mm` (`null` for a point the tracker
/// did not see), `mean_mm`, `max_mm` (of the points seen), `unseen` ([`ExecutionStats::unseen`]),
/// `reconditions` (estimates applied during it), `late_estimates` ([`late_estimates`]),
/// `within` (per point: whether it ran on an estimate corrected within the execution),
/// `beyond_reach` (per point: whether its target is beyond the arm's reach), and the set.
pub fn json_line(s: &ExecutionStats) -> String {
    serde_json::json!({
        "set_id": s.set_id,
        "execution": s.execution,
        "executions": s.executions,
        "errors_mm": s.errors().iter().map(|e| round3(e * 1e3)).collect::<Vec<_>>(),
        "mean_mm": round3(s.mean_m * 1e3),
        "max_mm": round3(s.max_m * 1e3),
        "unseen": s.unseen(),
        "reconditions": s.reconditions,
        "late_estimates": late_estimates(s),
        "within": (0..s.errors().len()).map(|n| s.corrected_within(n)).collect::<Vec<_>>(),
        "beyond_reach": (0..s.errors().len()).map(|n| s.beyond_reach(n)).collect::<Vec<_>>(),
    })
    .to_string()
}

/// An `ExecutionStats` as the recorder writes it (its fields as JSON), back as a payload.
pub fn from_json(v: &serde_json::Value) -> Option<ExecutionStats> {
    let u = |k: &str| v[k].as_u64();
    let mut s = ExecutionStats {
        seq: u("seq")?,
        stamp_ns: u("stamp_ns")?,
        set_id: u("set_id")?,
        execution: u("execution")? as u32,
        executions: u("executions")? as u32,
        count: u("count")? as u32,
        reconditions: u("reconditions")? as u32,
        within: u("within").unwrap_or(0) as u32,
        beyond_reach: u("beyond_reach").unwrap_or(0) as u32,
        mean_m: v["mean_m"].as_f64().unwrap_or(f64::NAN),
        max_m: v["max_m"].as_f64().unwrap_or(f64::NAN),
        ..Default::default()
    };
    for (i, e) in v["errors_m"]
        .as_array()?
        .iter()
        .take(s.errors_m.len())
        .enumerate()
    {
        s.errors_m[i] = e.as_f64().unwrap_or(f64::NAN);
    }
    Some(s)
}

fn round3(v: f64) -> f64 {
    (v * 1e3).round() / 1e3
}

/// The table header for `points` conditioning points.
pub fn table_header(points: usize) -> String {
    let mut h = format!("{:>5}", "exec");
    for n in 1..=points {
        h += &format!(" {:>7}", format!("CP{n} mm"));
    }
    h + &format!(
        " {:>8} {:>8} {:>5} {:>6}",
        "mean mm", "max mm", "late", "unseen"
    )
}

/// A row of the table: a point the tracker did not see is `-`; one that ran on an estimate
/// corrected within the execution is marked `*`, one whose target is beyond the arm's reach
/// `!` (its error is how near the arm comes).
pub fn table_row(s: &ExecutionStats) -> String {
    let mm = |v: f64, width: usize| {
        if v.is_finite() {
            format!(" {:>width$.2}", v * 1e3)
        } else {
            format!(" {:>width$}", "-")
        }
    };
    let mut r = format!("{:>5}", s.execution);
    for (n, e) in s.errors().iter().enumerate() {
        r += &if s.beyond_reach(n) {
            mm(*e, 6) + "!"
        } else if s.corrected_within(n) {
            mm(*e, 6) + "*"
        } else {
            mm(*e, 7)
        };
    }
    r + &mm(s.mean_m, 8) + &mm(s.max_m, 8) + &format!(" {:>5} {:>6}", late_estimates(s), s.unseen())
}

/// A subscription to `stats` (the last 64 executions arrive first).
pub struct Stats {
    ipc: Node,
    sub: Sub<ExecutionStats>,
}

impl Stats {
    pub fn open(namespace: &Namespace) -> Result<Self, softarm_ipc::Error> {
        let ipc = Node::open(namespace.clone(), "stats")?;
        let sub = ipc.subscriber(&ipc.stats()?)?;
        Ok(Self { ipc, sub })
    }

    /// Whether a controller runs in the namespace (its node is alive): without one no stats
    /// can come.
    pub fn controller_running(&self) -> bool {
        self.ipc.alive_nodes().is_ok_and(|nodes| {
            nodes
                .iter()
                .any(|n| n.split('.').next() == Some("controller"))
        })
    }

    /// The next execution's stats, waiting up to `timeout`.
    pub fn next(&self, timeout: Duration) -> Option<ExecutionStats> {
        crate::poll(timeout, || self.sub.receive().ok().flatten().map(|s| *s))
    }
}

/// What `softarm stats` says when the controller holds no execution: an answer, not silence,
/// so that "nothing has run yet" reads apart from "broken".
pub fn none_yet(namespace: &Namespace) -> String {
    format!(
        "no executions yet in namespace {:?}: `softarm submit FILE` runs a set (the controller \
         keeps its last 64 executions)",
        namespace.as_str()
    )
}

/// `softarm stats [--follow] [--json]`: the executions' stats the controller still holds (the
/// last 64), then with `follow` every new one; an error when no controller runs there.
/// `--json` alone prints one JSON array (`[]` when nothing has run); with `--follow`, one
/// JSON object per execution and line, as they finish.
pub fn show(namespace: &Namespace, follow: bool, json: bool) -> anyhow::Result<()> {
    let f = Stats::open(namespace)?;
    if !f.controller_running() {
        // No statistics can come: said, rather than nothing printed (or followed for ever) as
        // if no execution had finished yet.
        anyhow::bail!(
            "no controller runs in namespace {:?}: is `softarm up` running there (same \
             --config or --namespace)?",
            namespace.as_str()
        );
    }
    // The history the controller keeps arrives at once; 500 ms is ample on a loaded machine.
    let held: Vec<ExecutionStats> =
        std::iter::from_fn(|| f.next(Duration::from_millis(500))).collect();
    if json && !follow {
        println!("{}", json_array(&held));
        return Ok(());
    }
    if held.is_empty() && !json {
        println!("{}", none_yet(namespace));
    }
    let mut header = None;
    let mut print = |s: &ExecutionStats| {
        if json {
            println!("{}", json_line(s));
        } else {
            if header != Some(s.count) {
                println!("{}", table_header(s.count as usize));
                header = Some(s.count);
            }
            println!("{}", table_row(s));
        }
    };
    held.iter().for_each(&mut print);
    if !follow {
        return Ok(());
    }
    loop {
        if let Some(s) = f.next(Duration::from_secs(3600)) {
            print(&s);
        }
    }
}

/// The executions as one JSON array of [`json_line`]'s objects.
pub fn json_array(stats: &[ExecutionStats]) -> String {
    let lines: Vec<String> = stats.iter().map(json_line).collect();
    format!("[{}]", lines.join(","))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn estimates_not_in_force_are_counted_from_the_second_execution() {
        let s = |execution, reconditions| ExecutionStats {
            execution,
            executions: 5,
            count: 4,
            reconditions,
            ..Default::default()
        };
        assert_eq!(
            late_estimates(&s(1, 0)),
            0,
            "the first runs on the first estimates"
        );
        assert_eq!(late_estimates(&s(2, 4)), 0);
        assert_eq!(late_estimates(&s(3, 1)), 3);
        let j: serde_json::Value = serde_json::from_str(&json_line(&s(3, 1))).unwrap();
        assert_eq!(j["late_estimates"], 3);
        assert!(table_row(&s(3, 1)).ends_with("    3      0"));
        assert!(table_header(4).ends_with(" late unseen"));
    }

    #[test]
    fn points_corrected_within_the_execution_are_marked() {
        let s = ExecutionStats {
            execution: 1,
            count: 3,
            within: 0b110,
            errors_m: [
                0.02, 0.003, 0.004, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            ],
            ..Default::default()
        };
        let row = table_row(&s);
        assert!(row.starts_with("    1   20.00   3.00*   4.00*"), "{row}");
        assert_eq!(
            row.len(),
            table_row(&ExecutionStats { within: 0, ..s }).len()
        );
        let j: serde_json::Value = serde_json::from_str(&json_line(&s)).unwrap();
        assert_eq!(j["within"], serde_json::json!([false, true, true]));
        let recorded = serde_json::to_value(s).unwrap();
        assert_eq!(from_json(&recorded).unwrap().within, 0b110);
    }

    #[test]
    fn points_beyond_reach_are_marked() {
        let s = ExecutionStats {
            execution: 4,
            count: 3,
            beyond_reach: 0b1,
            within: 0b100,
            errors_m: [
                0.036, 0.001, 0.002, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                0.0,
            ],
            ..Default::default()
        };
        let row = table_row(&s);
        assert!(row.starts_with("    4  36.00!    1.00   2.00*"), "{row}");
        let j: serde_json::Value = serde_json::from_str(&json_line(&s)).unwrap();
        assert_eq!(j["beyond_reach"], serde_json::json!([true, false, false]));
        let recorded = serde_json::to_value(s).unwrap();
        assert_eq!(from_json(&recorded).unwrap().beyond_reach, 0b1);
    }

    #[test]
    fn no_execution_is_an_empty_array_and_executions_one_object_each() {
        let empty: serde_json::Value = serde_json::from_str(&json_array(&[])).unwrap();
        assert_eq!(empty, serde_json::json!([]));
        let s = |execution| ExecutionStats {
            execution,
            count: 2,
            ..Default::default()
        };
        let two: serde_json::Value = serde_json::from_str(&json_array(&[s(1), s(2)])).unwrap();
        let executions: Vec<_> = two
            .as_array()
            .unwrap()
            .iter()
            .map(|v| &v["execution"])
            .collect();
        assert_eq!(executions, [1, 2]);
    }

    #[test]
    fn a_point_the_tracker_did_not_see_is_counted_and_shown_as_such() {
        let mut s = ExecutionStats {
            execution: 2,
            count: 3,
            reconditions: 3,
            mean_m: 0.0015,
            max_m: 0.002,
            ..Default::default()
        };
        s.errors_m[..3].copy_from_slice(&[0.001, f64::NAN, 0.002]);
        assert_eq!(s.unseen(), 1);
        let j: serde_json::Value = serde_json::from_str(&json_line(&s)).unwrap();
        assert_eq!(j["errors_mm"], serde_json::json!([1.0, null, 2.0]));
        assert_eq!(j["unseen"], 1);
        let row = table_row(&s);
        assert!(row.contains("    1.00       -    2.00"), "{row}");
        assert!(row.ends_with("    0      1"), "{row}");
    }
}
