//! The soak's report: what it measured, what failed it, and the lines the user reads.

use serde::Serialize;
use softarm_ipc::Latency;
use softarm_watch as watch;

use super::{RSS_BOUND_KIB, SetSeen};

/// Resident memory of one role over the run (KiB); the peak is over every process that held it.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Rss {
    pub start_kib: u64,
    pub end_kib: u64,
    pub peak_kib: u64,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct Report {
    pub minutes: f64,
    pub seed: u64,
    pub sets_submitted: u64,
    pub sets_rejected: u64,
    pub executions: u64,
    /// Per scenario, the learning it saw: see [`Learning`].
    pub learning: Vec<Learning>,
    pub scenario_changes: u64,
    /// Every change of the sim's arm and how many executions it took to get back under
    /// [`BACK_UNDER_MM`]: see [`ArmChange`].
    pub arm_changes: Vec<ArmChange>,
    pub kills: Vec<(String, u64)>,
    pub kills_survived: u64,
    pub kills_not_survived: Vec<String>,
    pub invariants: watch::Report,
    pub rss: Vec<(String, Rss)>,
    /// The learner's stored lattice weights (actor, critic) at the start and the end.
    pub lattice_start: (usize, usize),
    pub lattice_end: (usize, usize),
    /// The last controller's tick wake-up latency (its life since its last restart), and the
    /// worst p99 (over at least 5000 ticks) and max any controller reported.
    pub tick: Latency,
    pub tick_worst_p99_ns: u64,
    pub tick_worst_max_ns: u64,
    pub overruns: u64,
    /// What failed the soak, in words (empty: it passed).
    pub failures: Vec<String>,
}

/// The sets that ran on one scenario's arm: the mean error at the conditioning points of their
/// first and of their last executions (mm), over the sets that ran at least twice (executions
/// without a tracker, a sim being restarted, left out).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Learning {
    pub scenario: String,
    pub sets: u64,
    pub executions: u64,
    pub first_mm: f64,
    pub last_mm: f64,
    /// Sets that ran at least twice.
    pub twice: u64,
    /// Of those, the sets whose last execution was over [`BACK_UNDER_MM`].
    pub over: u64,
}

/// The mean error an arm change must be brought back under (mm).
pub const BACK_UNDER_MM: f64 = 2.5;

/// One change of the sim's arm: another scenario, a step of a scenario that changes while it
/// runs, or such a scenario started over by a restarted sim (its clock from 0 again).
#[derive(Debug, Clone, Default, Serialize)]
pub struct ArmChange {
    /// When it was seen (s into the soak).
    pub at_s: f64,
    /// What changed: the scenario's name, with the step.
    pub arm: String,
    /// Executions that ended after it, before the next change.
    pub executions: u64,
    /// Which of those was the first with a mean error at most [`BACK_UNDER_MM`] (1: the first
    /// execution after the change); none if none was.
    pub back_under: Option<u64>,
}

/// The changes so far; each execution counts for the last one.
pub(super) fn count_execution(changes: &mut [ArmChange], mean_mm: f64) {
    if let Some(c) = changes.last_mut() {
        c.executions += 1;
        if c.back_under.is_none() && mean_mm <= BACK_UNDER_MM {
            c.back_under = Some(c.executions);
        }
    }
}

/// Per scenario, the mean error of the first and of the last execution of its sets that ran
/// at least twice.
pub(super) fn learning(scenarios: &[String], sets: &[SetSeen]) -> Vec<Learning> {
    scenarios
        .iter()
        .enumerate()
        .filter_map(|(i, name)| {
            let mine: Vec<_> = sets.iter().filter(|x| x.scenario == i).collect();
            let twice: Vec<_> = mine.iter().filter(|x| x.executions >= 2).collect();
            let mean = |f: &dyn Fn(&SetSeen) -> f64| {
                let finite: Vec<f64> = twice
                    .iter()
                    .map(|x| f(x))
                    .filter(|v| v.is_finite())
                    .collect();
                finite.iter().sum::<f64>() / finite.len().max(1) as f64
            };
            (!mine.is_empty()).then(|| Learning {
                scenario: name.clone(),
                sets: mine.len() as u64,
                executions: mine.iter().map(|x| u64::from(x.executions)).sum(),
                first_mm: mean(&|x| x.first_mm),
                last_mm: mean(&|x| x.last_mm),
                twice: twice.len() as u64,
                over: twice.iter().filter(|x| x.last_mm > BACK_UNDER_MM).count() as u64,
            })
        })
        .collect()
}

/// What fails the soak, in words.
pub(super) fn failures(report: &Report) -> Vec<String> {
    let mut failures = Vec::new();
    if report.invariants.violations > 0 {
        failures.push(format!(
            "{} safety invariants broken",
            report.invariants.violations
        ));
    }
    failures.extend(report.kills_not_survived.iter().cloned());
    for (role, r) in &report.rss {
        if r.end_kib > r.start_kib + RSS_BOUND_KIB {
            failures.push(format!(
                "the {role} grew from {} to {} MiB",
                r.start_kib / 1024,
                r.end_kib / 1024
            ));
        }
    }
    if report.executions == 0 {
        failures.push("no execution finished".into());
    }
    failures
}

/// The demo set moved: each point up to 25 mm away on each axis, a point sometimes left out.
pub(super) fn print_report(r: &Report) {
    let us = |ns: u64| ns as f64 / 1e3;
    println!("softarm-rig soak: {:.1} min, seed {}", r.minutes, r.seed);
    println!(
        "  executions           {} in {} sets ({} refused), {} scenario changes",
        r.executions, r.sets_submitted, r.sets_rejected, r.scenario_changes
    );
    for l in &r.learning {
        println!(
            "  {:<20} {} sets, {} executions: mean error {:.2} mm on a set's first execution, \
             {:.2} mm on its last; {} of {} sets ended over {BACK_UNDER_MM} mm",
            l.scenario, l.sets, l.executions, l.first_mm, l.last_mm, l.over, l.twice
        );
    }
    for c in &r.arm_changes {
        let back = match c.back_under {
            Some(n) => format!(
                "under {BACK_UNDER_MM} mm at execution {n} of {}",
                c.executions
            ),
            None => format!(
                "not under {BACK_UNDER_MM} mm in {} executions",
                c.executions
            ),
        };
        println!("  arm change {:>6.0} s  {}: {back}", c.at_s, c.arm);
    }
    let kills: Vec<String> = r.kills.iter().map(|(k, n)| format!("{k} {n}")).collect();
    println!(
        "  kills                {} ({}), survived {}",
        r.kills.iter().map(|k| k.1).sum::<u64>(),
        if kills.is_empty() {
            "none".to_string()
        } else {
            kills.join(", ")
        },
        r.kills_survived
    );
    let w = &r.invariants;
    println!(
        "  invariant violations {} (over {} setpoints from {} controller runs, {} executions, \
         {} outages checked)",
        w.violations, w.setpoints, w.streams, w.executions, w.outages
    );
    for m in &w.messages {
        println!("    {m}");
    }
    for (role, m) in &r.rss {
        println!(
            "  RSS {role:<16} start {:.1} MiB, end {:.1} MiB, peak {:.1} MiB",
            m.start_kib as f64 / 1024.0,
            m.end_kib as f64 / 1024.0,
            m.peak_kib as f64 / 1024.0
        );
    }
    println!(
        "  lattice weights      actor {} -> {}, critic {} -> {}",
        r.lattice_start.0, r.lattice_end.0, r.lattice_start.1, r.lattice_end.1
    );
    println!(
        "  tick wake-up (us)    p50 {:.0}, p99 {:.0}, p99.9 {:.0}, max {:.0} over {} ticks of the \
         last controller; worst p99 {:.0}, worst max {:.0}; {} overruns",
        us(r.tick.p50_ns),
        us(r.tick.p99_ns),
        us(r.tick.p999_ns),
        us(r.tick.max_ns),
        r.tick.samples,
        us(r.tick_worst_p99_ns),
        us(r.tick_worst_max_ns),
        r.overruns
    );
    if r.failures.is_empty() {
        println!("  PASSED");
    } else {
        for f in &r.failures {
            println!("  FAILED: {f}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_arm_change_counts_the_executions_until_the_error_is_back_under() {
        let mut changes = Vec::new();
        // Executions before any change count for none.
        count_execution(&mut changes, 9.0);
        let change = |arm: &str| ArmChange {
            arm: arm.into(),
            ..ArmChange::default()
        };
        changes.push(change("tool-change"));
        for mm in [20.0, 6.0, 2.4, 3.0, 1.0] {
            count_execution(&mut changes, mm);
        }
        changes.push(change("creeping step 1"));
        for mm in [8.0, 4.0] {
            count_execution(&mut changes, mm);
        }
        let got: Vec<_> = changes
            .iter()
            .map(|c| (c.executions, c.back_under))
            .collect();
        assert_eq!(got, [(5, Some(3)), (2, None)]);
    }
}
