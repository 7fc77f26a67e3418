//! The soak's report: what it measured, what failed it, and the lines the user reads.

use serde::Serialize;
use softarm_clients::watch;
use softarm_ipc::Latency;

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
/// first and of their last executions (mm), over the sets that ran at least twice.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Learning {
    pub scenario: String,
    pub sets: u64,
    pub executions: u64,
    pub first_mm: f64,
    pub last_mm: f64,
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
                twice.iter().map(|x| f(x)).sum::<f64>() / twice.len().max(1) as f64
            };
            (!mine.is_empty()).then(|| Learning {
                scenario: name.clone(),
                sets: mine.len() as u64,
                executions: mine.iter().map(|x| u64::from(x.executions)).sum(),
                first_mm: mean(&|x| x.first_mm),
                last_mm: mean(&|x| x.last_mm),
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
    println!("softarm soak: {:.1} min, seed {}", r.minutes, r.seed);
    println!(
        "  executions           {} in {} sets ({} refused), {} scenario changes",
        r.executions, r.sets_submitted, r.sets_rejected, r.scenario_changes
    );
    for l in &r.learning {
        println!(
            "  {:<20} {} sets, {} executions: mean error {:.2} mm on a set's first execution, \
             {:.2} mm on its last",
            l.scenario, l.sets, l.executions, l.first_mm, l.last_mm
        );
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
