//! `softarm soak --minutes M`: the simulated stack run for a long time the way a lab runs it,
//! with things going wrong on purpose, and a report of what held.
//!
//! - Continuous executions: way-point sets one after another, the demo set and seeded random
//!   variations of it (new places for the learner's lattices every set).
//! - Scenario changes between sets: the sim becomes another arm (tool change, creep, twist,
//!   stiffer, nominal) in turn.
//! - Random kills: sim, controller or learner SIGKILLed at seeded moments; each must come back
//!   (restarted by the supervisor here, as `softarm up` does) and an execution must finish after.
//! - An independent [`Watch`] checks every setpoint and statistic against the safety invariants
//!   (limits, slew, HOLD while the sim is gone, no statistics twice or lost): violations must
//!   be 0.
//! - Resident memory of each process and the learner's stored lattice weights, at the start
//!   (after the first execution) and at the end; the controller's tick latency percentiles.
//!
//! Exit 1 if an invariant broke, a kill was not survived or a process grew beyond the bound.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::Serialize;
use softarm_clients::watch::{self, Limits, Watch};
use softarm_clients::{stats, status, submit};
use softarm_config::DEFAULT;
use softarm_config::waypoints::{Point, WaypointFile};
use softarm_ipc::{ControllerStatus, Latency, Node};
use softarm_model::bundle::{Model, read_checkpoint};
use softarm_runtime::now_ns;

use crate::demo;
use crate::scratch::Scratch;
use crate::up::{self, Supervisor};

#[derive(clap::Args)]
pub struct Args {
    /// How long to run (minutes).
    #[arg(long, value_parser = minutes, allow_negative_numbers = true)]
    minutes: f64,
    /// Seeds the sets, the kills, the plant and the learner: the same seed, the same run.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Mean time between random kills (s); 0: no kills.
    #[arg(long, default_value_t = 45.0, value_parser = seconds, allow_negative_numbers = true)]
    kill_every_s: f64,
    /// Time between scenario changes (s), made between sets; 0: the nominal arm throughout.
    #[arg(long, default_value_t = 120.0, value_parser = seconds, allow_negative_numbers = true)]
    scenario_every_s: f64,
    /// Where the trained model is kept between runs (default: the demo's, in the user's cache).
    #[arg(long)]
    model_dir: Option<PathBuf>,
    /// The report as one JSON object on stdout, and nothing else there.
    #[arg(long)]
    json: bool,
}

fn minutes(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
    if !(v.is_finite() && v > 0.0 && v <= 7.0 * 24.0 * 60.0) {
        return Err(format!("must be more than 0 and at most a week, got {s}"));
    }
    Ok(v)
}

fn seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
    if !(v == 0.0 || (v.is_finite() && v >= 5.0)) {
        return Err(format!("must be 0 (never) or at least 5 seconds, got {s}"));
    }
    Ok(v)
}

const ROLES: [&str; 3] = ["sim", "controller", "learner"];
/// The scenarios the sim goes through, in turn.
const SCENARIOS: [&str; 5] = ["tool-change", "creep", "twist", "stiffer", "nominal"];
/// How far a process may grow from the start to the end of a soak (KiB).
const RSS_BOUND_KIB: u64 = 16 * 1024;
/// A killed process must be back, and an execution finished after it, within this.
const RECOVERY: Duration = Duration::from_secs(90);

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

/// A set's executions as they ended.
struct SetSeen {
    id: u64,
    /// Index of the scenario it ran on.
    scenario: usize,
    executions: u32,
    /// Mean error of its first and its last execution (mm).
    first_mm: f64,
    last_mm: f64,
}

/// A kill whose recovery is being waited for.
struct Pending {
    role: &'static str,
    old: u32,
    at: Instant,
    back: bool,
}

/// The set under way.
struct Running {
    id: u64,
    executions: u32,
}

fn say(json: bool, line: &str) {
    if !json {
        eprintln!("softarm soak: {line}");
    }
}

pub fn run(args: &Args, stop: &AtomicBool) -> anyhow::Result<bool> {
    let model_dir = args
        .model_dir
        .clone()
        .unwrap_or_else(|| demo::cache_dir().join(format!("demo-model-seed{}", args.seed)));
    let seed = i64::try_from(args.seed).context("--seed must be at most 9223372036854775807")?;
    let scratch = Scratch::new(
        "soak",
        DEFAULT,
        &[
            ("model.dir", model_dir.display().to_string().into()),
            ("learner.seed", seed.into()),
            ("sim.realism.seed", seed.into()),
        ],
    )?;
    let (config, ns) = (&scratch.config, &scratch.namespace);
    let demo_set = WaypointFile::parse(demo::WAYPOINTS)
        .map_err(anyhow::Error::msg)
        .context("the demo way-points")?;
    let mut sup = scratch.supervisor(&ROLES, "error")?;
    say(args.json, &format!("stack up in namespace {}", ns.as_str()));
    let wait_for = |what: &str, sup: &mut Supervisor, ok: &dyn Fn(&status::Report) -> bool| {
        scratch.wait_for(what, Duration::from_secs(60), sup, stop, ok)
    };
    scratch.ready_with_model(&mut sup, stop, args.seed, &|line| say(args.json, line))?;
    let lattice_start = Model::read(&model_dir)
        .map(|m| (m.learner.actor.len(), m.learner.critic.len()))
        .unwrap_or_default();

    // Subscribed before the first set: nothing is missed.
    let watch = Watch::start(ns, Limits::from_config(config))?;
    let follower = stats::Stats::open(ns)?;
    let node = Node::open(ns.clone(), "soak")?;
    let statuses = node.subscriber(&node.status()?)?;

    let mut rng = StdRng::seed_from_u64(args.seed);
    let mut report = Report {
        minutes: args.minutes,
        seed: args.seed,
        lattice_start,
        ..Report::default()
    };
    let mut rss: Vec<(String, Rss)> = ROLES
        .iter()
        .map(|r| (r.to_string(), Rss::default()))
        .collect();
    let mut warm = false;
    let mut sets: Vec<SetSeen> = Vec::new();
    let mut scenarios = vec!["nominal".to_string()];
    let mut scenario = 0;
    let mut running: Option<Running> = None;
    let mut pending: Option<Pending> = None;
    let mut last_status: Option<ControllerStatus> = None;

    let started = Instant::now();
    let end = started + Duration::from_secs_f64(args.minutes * 60.0);
    let next_kill = |rng: &mut StdRng| {
        (args.kill_every_s > 0.0).then(|| {
            Instant::now() + Duration::from_secs_f64(args.kill_every_s * rng.random_range(0.5..1.5))
        })
    };
    let mut kill_at = next_kill(&mut rng);
    let every = |s: f64| (s > 0.0).then(|| Instant::now() + Duration::from_secs_f64(s));
    let mut scenario_at = every(args.scenario_every_s);
    let mut sample_at = Instant::now();
    let mut progress_at = Instant::now() + Duration::from_secs(30);

    while Instant::now() < end {
        if stop.load(Ordering::Relaxed) {
            bail!("interrupted");
        }
        sup.poll();
        while let Ok(Some(s)) = statuses.receive() {
            // A young controller's percentiles are its start-up's: its max counts, its p99 not.
            if s.latency.samples >= 5000 {
                report.tick_worst_p99_ns = report.tick_worst_p99_ns.max(s.latency.p99_ns);
            }
            report.tick_worst_max_ns = report.tick_worst_max_ns.max(s.latency.max_ns);
            last_status = Some(*s);
        }
        let pid_of = |sup: &Supervisor, role: &str| {
            sup.pids()
                .into_iter()
                .find(|(r, _)| r == role)
                .map(|(_, p)| p)
        };

        // Executions as they end.
        while let Some(s) = follower.next(Duration::from_millis(50)) {
            report.executions += 1;
            let mm = s.mean_m * 1e3;
            match sets.iter_mut().find(|x| x.id == s.set_id) {
                Some(x) => {
                    x.executions += 1;
                    x.last_mm = mm;
                }
                None => sets.push(SetSeen {
                    id: s.set_id,
                    scenario: scenarios.len() - 1,
                    executions: 1,
                    first_mm: mm,
                    last_mm: mm,
                }),
            }
            if running
                .as_ref()
                .is_some_and(|r| r.id == s.set_id && s.execution >= r.executions)
            {
                running = None;
            }
            if let Some(p) = pending.take_if(|p| p.back) {
                say(
                    args.json,
                    &format!("{} kill survived: executing again", p.role),
                );
                report.kills_survived += 1;
            }
            warm = true;
        }

        // A kill's recovery: the process back under a new pid and the stack answering.
        if let Some(p) = pending.as_mut() {
            if !p.back
                && pid_of(&sup, p.role).is_some_and(|n| n != p.old)
                && status::status(ns, Duration::from_millis(200)).is_ok_and(|r| {
                    r.running() && ROLES.iter().all(|role| r.alive.iter().any(|n| n == role))
                })
            {
                p.back = true;
                if p.role == "controller" {
                    // A new controller forgets its set.
                    running = None;
                }
            }
            if p.at.elapsed() > RECOVERY {
                let why = format!(
                    "{} killed {:.0} s into the soak: {} within {} s",
                    p.role,
                    (p.at - started).as_secs_f64(),
                    if p.back {
                        "back, but no execution finished"
                    } else {
                        "not back"
                    },
                    RECOVERY.as_secs()
                );
                say(args.json, &why);
                report.kills_not_survived.push(why);
                pending = None;
            }
        }

        // Between sets: another arm, now and then.
        if running.is_none()
            && pending.is_none()
            && scenario_at.is_some_and(|t| Instant::now() >= t)
        {
            let name = SCENARIOS[scenario % SCENARIOS.len()];
            scenario += 1;
            say(args.json, &format!("the sim becomes scenario {name}"));
            sup.restart_with("sim", up::sim_args(Some(name)), Duration::from_secs(5))?;
            wait_for("the scenario's sim coming up", &mut sup, &|r| {
                r.alive.iter().any(|n| n == "sim") && r.running()
            })?;
            scenarios.push(name.to_string());
            report.scenario_changes += 1;
            scenario_at = every(args.scenario_every_s);
        }

        // The next set, once the last is done.
        if running.is_none() && pending.as_ref().is_none_or(|p| p.back) {
            let file = if report.sets_submitted.is_multiple_of(3) {
                demo_set.clone()
            } else {
                variation(&demo_set, &mut rng)
            };
            let executions = rng.random_range(3..=6);
            let set = file.to_set(executions).map_err(anyhow::Error::msg)?;
            match submit::submit(ns, set, Duration::from_secs(5)) {
                submit::Outcome::Accepted { set_id } => {
                    report.sets_submitted += 1;
                    running = Some(Running {
                        id: set_id,
                        executions,
                    });
                }
                submit::Outcome::Rejected { reason } => {
                    report.sets_submitted += 1;
                    report.sets_rejected += 1;
                    say(args.json, &format!("a set was refused: {reason}"));
                }
                // The controller restarting: try again.
                submit::Outcome::Unreachable { .. } => {}
            }
        }

        // A random kill, mid-execution or not.
        if pending.is_none() && kill_at.is_some_and(|t| Instant::now() >= t) {
            let role = ROLES[rng.random_range(0..ROLES.len())];
            if let Some(old) = pid_of(&sup, role) {
                if role == "sim" {
                    // The supervisor restarts it after a second at the earliest.
                    let t = now_ns();
                    watch.outage(t, t + 900_000_000);
                }
                kill(Pid::from_raw(old as i32), Signal::SIGKILL)
                    .with_context(|| format!("killing the {role} ({old})"))?;
                say(args.json, &format!("killed the {role} ({old})"));
                match report.kills.iter_mut().find(|k| k.0 == role) {
                    Some(k) => k.1 += 1,
                    None => report.kills.push((role.to_string(), 1)),
                }
                pending = Some(Pending {
                    role,
                    old,
                    at: Instant::now(),
                    back: false,
                });
            }
            kill_at = next_kill(&mut rng);
        }

        // Memory, every few seconds once warm.
        if warm && Instant::now() >= sample_at {
            sample_at = Instant::now() + Duration::from_secs(5);
            for (role, r) in rss.iter_mut() {
                if let Some(kib) = pid_of(&sup, role).and_then(|p| up::rss_kib(&p.to_string())) {
                    if r.start_kib == 0 {
                        r.start_kib = kib;
                    }
                    r.end_kib = kib;
                    r.peak_kib = r.peak_kib.max(kib);
                }
            }
        }
        if Instant::now() >= progress_at {
            progress_at = Instant::now() + Duration::from_secs(30);
            let w = watch.report();
            say(
                args.json,
                &format!(
                    "{:.1} of {} min: {} executions, {} kills, {} invariant violations",
                    started.elapsed().as_secs_f64() / 60.0,
                    args.minutes,
                    report.executions,
                    report.kills.iter().map(|k| k.1).sum::<u64>(),
                    w.violations
                ),
            );
        }
    }
    if let Some(p) = pending.take() {
        // Cut short by the end of the soak: judged by what it reached.
        if p.back {
            report.kills_survived += 1;
        } else if p.at.elapsed() > Duration::from_secs(20) {
            report
                .kills_not_survived
                .push(format!("{} killed at the end: not back in 20 s", p.role));
        }
    }

    report.invariants = watch.finish();
    report.lattice_end = read_checkpoint(&config.state_dir())
        .map(|(s, _)| (s.actor.len(), s.critic.len()))
        .unwrap_or(report.lattice_start);
    if let Some(s) = last_status {
        report.tick = s.latency;
        report.overruns = s.overruns;
    }
    sup.stop(Duration::from_secs(5));
    report.learning = scenarios
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
        .collect();
    report.rss = rss;

    // What fails the soak.
    if report.invariants.violations > 0 {
        report.failures.push(format!(
            "{} safety invariants broken",
            report.invariants.violations
        ));
    }
    for k in &report.kills_not_survived {
        report.failures.push(k.clone());
    }
    for (role, r) in &report.rss {
        if r.end_kib > r.start_kib + RSS_BOUND_KIB {
            report.failures.push(format!(
                "the {role} grew from {} to {} MiB",
                r.start_kib / 1024,
                r.end_kib / 1024
            ));
        }
    }
    if report.executions == 0 {
        report.failures.push("no execution finished".into());
    }
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_report(&report);
    }
    Ok(report.failures.is_empty())
}

/// The demo set moved: each point up to 25 mm away on each axis, a point sometimes left out.
fn variation(base: &WaypointFile, rng: &mut StdRng) -> WaypointFile {
    let mut point: Vec<Point> = base
        .point
        .iter()
        .map(|p| Point {
            t_s: p.t_s,
            position_m: p.position_m.map(|v| v + rng.random_range(-0.025..0.025)),
        })
        .collect();
    if point.len() > 2 && rng.random_bool(0.3) {
        point.remove(rng.random_range(0..point.len()));
    }
    WaypointFile {
        duration_s: base.duration_s,
        point,
    }
}

fn print_report(r: &Report) {
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
