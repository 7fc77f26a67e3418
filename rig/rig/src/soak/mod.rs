//! `softarm-rig soak --minutes M`: the simulated stack run for a long time the way a lab runs it,
//! with things going wrong on purpose, and a report of what held.
//!
//! - Continuous executions: way-point sets one after another, the demo set and seeded random
//!   variations of it (new places for the learner's lattices every set).
//! - Scenario changes between sets: the sim becomes another arm (tool change, creep, twist,
//!   stiffer, nominal, or the `--scenarios` given, which may change while they run) in turn.
//!   Every change of the arm (another scenario, a step of one that changes while it runs, read
//!   off the sim's own clock) is reported with the executions it took to get back under
//!   2.5 mm.
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
use softarm_clients::{stats, status, submit};
use softarm_config::scenario::Scenario;
use softarm_config::waypoints::WaypointFile;
use softarm_ipc::{ControllerStatus, Node, Sub, TrackerSample};
use softarm_model::bundle::{Model, read_checkpoint};
use softarm_runtime::now_ns;
use softarm_watch::{Limits, Watch};

use softarm_stack::sandbox::{ModelFolder, Sandbox};

mod report;
pub mod sets;
pub use report::{ArmChange, BACK_UNDER_MM, Learning, Report, Rss};
use report::{count_execution, failures, learning, print_report};
use softarm_stack::supervisor::{self, Supervisor};

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
    /// The scenarios the sim becomes in turn, names or files, comma-separated (default:
    /// tool-change,creep,twist,stiffer,nominal); scenarios that change while they run
    /// (tool-swap, creeping, ...) run from their start each time.
    #[arg(long, value_delimiter = ',', value_name = "NAME|FILE,...")]
    scenarios: Vec<String>,
    /// Where the trained model is kept between runs (default: the demo's, in the user's cache;
    /// with `--config`, that config's `model.dir`).
    #[arg(long)]
    model_dir: Option<PathBuf>,
    /// Soaks the stack this config describes instead of the simulated arm: its drivers, devices
    /// and model (e.g. the config `softarm-rig emulate --write-config` wrote, for the real arm's
    /// code path against emulated devices). Without a sim there are no scenario changes.
    #[arg(long, value_name = "FILE", conflicts_with = "arm")]
    config: Option<PathBuf>,
    /// The arm the sim runs: a shipped arm (paper, hybrid, tdcr) or an arm file, such as the
    /// twin `softarm train --from` writes; its model the demo's for that arm, its sets on its
    /// own demonstrations, its scenarios by default those of any arm (tool-change, nominal).
    #[arg(long, value_name = "NAME|FILE")]
    arm: Option<String>,
    /// After `--minutes`, go on (without kills or changes of the arm) until this many
    /// executions have finished and one after the last change of the arm, for at most as long
    /// again (at least 5 minutes): a slow machine gets through what a soak is run to see,
    /// and one where the stack no longer executes fails, saying so.
    #[arg(long, default_value_t = 0)]
    at_least_executions: u64,
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

/// The processes besides the drivers the config names.
const PROCESSES: [&str; 2] = ["controller", "learner"];
/// The scenarios the sim goes through, in turn.
const SCENARIOS: [&str; 5] = ["tool-change", "creep", "twist", "stiffer", "nominal"];
/// ...on another arm (`--arm`): the shipped scenarios that change any arm.
const ANY_ARM_SCENARIOS: [&str; 2] = ["tool-change", "nominal"];
/// How far a process may grow from the start to the end of a soak (KiB).
const RSS_BOUND_KIB: u64 = 16 * 1024;
/// A killed process must be back, and an execution finished after it, within this.
const RECOVERY: Duration = Duration::from_secs(90);

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
        eprintln!("softarm-rig soak: {line}");
    }
}

pub fn run(args: &Args, stop: &AtomicBool) -> anyhow::Result<bool> {
    let rotation = rotation(args)?;
    let sandbox = sandbox_for(args)?;
    let model_dir = sandbox.config.model_dir();
    let roles = roles(&sandbox.config);
    let mut sup = sandbox.supervisor(&roles, "error")?;
    say(
        args.json,
        &format!(
            "stack up in namespace {}: {}{}",
            sandbox.namespace.as_str(),
            roles.join(", "),
            if roles.contains(&"sim") {
                ""
            } else {
                " (no sim: no scenario changes)"
            }
        ),
    );
    let folder = match (&args.model_dir, &args.config) {
        (None, None) => ModelFolder::Cache,
        _ => ModelFolder::Given,
    };
    sandbox.ready_with_model(&mut sup, stop, args.seed, folder, &|line| {
        say(args.json, line)
    })?;
    let lattice_start = lattices(&sandbox.config, &model_dir);
    let mut soak = Soak::start(args, stop, &sandbox, sup, roles, lattice_start, rotation)?;
    let minutes = Duration::from_secs_f64(args.minutes * 60.0);
    let end = soak.started + minutes;
    while Instant::now() < end {
        if stop.load(Ordering::Relaxed) {
            bail!("interrupted");
        }
        soak.step()?;
    }
    let overtime = Instant::now() + minutes.max(Duration::from_secs(300));
    soak.calm();
    while soak.owed() && Instant::now() < overtime {
        if stop.load(Ordering::Relaxed) {
            bail!("interrupted");
        }
        soak.step()?;
    }
    let owed = soak.owed();
    let mut report = soak.finish();
    if owed {
        report.failures.push(format!(
            "{} executions, {} of them after the last change of the arm, in {:.1} minutes \
             and as long again: --at-least-executions {} and one after the last change were not \
             reached (the stack executes too slowly, or not at all, on this machine)",
            report.executions,
            report
                .arm_changes
                .last()
                .map_or(report.executions, |c| c.executions),
            args.minutes,
            args.at_least_executions
        ));
    }
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_report(&report);
    }
    Ok(report.failures.is_empty())
}

/// The soak's own stack: the simulated arm of the shipped config, or the stack `--config`
/// describes; the soak's seed for the learner (and the sim's realism).
fn sandbox_for(args: &Args) -> anyhow::Result<Sandbox> {
    let seed = i64::try_from(args.seed).context("--seed must be at most 9223372036854775807")?;
    let (text, own) = match &args.config {
        Some(path) => (
            std::fs::read_to_string(path)
                .with_context(|| format!("reading the config {}", path.display()))?,
            Some(softarm_config::Config::load(path)?),
        ),
        None => (softarm_stack::demo::with_arm(args.arm.as_deref())?, None),
    };
    // The copy lives in the soak's folder: a relative model folder must not move with it.
    let model_dir = match (&args.model_dir, &own) {
        (Some(dir), _) => dir.clone(),
        (None, Some(c)) => c.model_dir(),
        (None, None) => softarm_stack::demo::model_cache(args.arm.as_deref(), args.seed),
    };
    let mut overrides = vec![
        ("learner.seed", seed.into()),
        ("model.dir", model_dir.display().to_string().into()),
    ];
    if own.is_none_or(|c| c.robot.drivers.iter().any(|d| d == "sim")) {
        overrides.push(("sim.realism.seed", seed.into()));
    }
    Sandbox::for_command("soak", &text, &overrides)
}

/// The learner's stored lattice weights (actor, critic) in the bundle at `model_dir`, for the
/// config's arm; (0, 0) if there is none.
fn lattices(config: &softarm_config::Config, model_dir: &std::path::Path) -> (usize, usize) {
    let n = config.layout().actuators().len();
    softarm_ipc::with_actuators!(n,
        N => Model::<N>::read(model_dir)
            .map(|m| (m.learner.actor.len(), m.learner.critic.len()))
            .unwrap_or_default(),
        _n => (0, 0))
}

/// The scenarios the sim goes through (what the sim is given, resolved), refused before
/// anything starts if one is not there.
fn rotation(args: &Args) -> anyhow::Result<Vec<(String, Scenario)>> {
    let names: Vec<String> = match (args.scenarios.is_empty(), args.arm.as_deref()) {
        (false, _) => args.scenarios.clone(),
        (true, None | Some("paper")) => SCENARIOS.map(String::from).to_vec(),
        (true, Some(_)) => ANY_ARM_SCENARIOS.map(String::from).to_vec(),
    };
    names
        .into_iter()
        .map(|n| {
            let s = Scenario::resolve(&n).context("--scenarios")?;
            Ok((n, s))
        })
        .collect()
}

/// The processes the soak runs and kills: the config's drivers, the controller, the learner.
fn roles(config: &softarm_config::Config) -> Vec<&'static str> {
    softarm_ipc::DRIVERS
        .iter()
        .map(|d| d.name)
        .filter(|d| config.robot.drivers.iter().any(|c| c == d))
        .chain(PROCESSES)
        .collect()
}

/// A soak under way: the stack, what watches it, and what it has seen so far.
struct Soak<'a> {
    args: &'a Args,
    stop: &'a AtomicBool,
    sandbox: &'a Sandbox,
    sup: Supervisor,
    /// What runs and may be killed: the drivers first, then controller and learner.
    roles: Vec<&'static str>,
    demo_set: WaypointFile,
    /// How far a variation moves a point: [`sets::MOVE_M`] on the paper's arm, less on a
    /// smaller one.
    move_m: f64,
    watch: Watch,
    follower: stats::Stats,
    statuses: Sub<ControllerStatus>,
    _node: Node,
    rng: StdRng,
    report: Report,
    rss: Vec<(String, Rss)>,
    /// An execution has finished: memory is sampled from then on.
    warm: bool,
    sets: Vec<SetSeen>,
    /// The arms the sim has been, in order; sets name theirs by index.
    scenarios: Vec<String>,
    scenario: usize,
    /// What the sim becomes in turn: its argument and the scenario.
    rotation: Vec<(String, Scenario)>,
    /// The sim's clock, and the scenario it runs when that changes the arm while it runs.
    sim_clock: SimClock,
    running: Option<Running>,
    pending: Option<Pending>,
    last_status: Option<ControllerStatus>,
    started: Instant,
    kill_at: Option<Instant>,
    scenario_at: Option<Instant>,
    sample_at: Instant,
    progress_at: Instant,
}

impl<'a> Soak<'a> {
    fn start(
        args: &'a Args,
        stop: &'a AtomicBool,
        sandbox: &'a Sandbox,
        sup: Supervisor,
        roles: Vec<&'static str>,
        lattice_start: (usize, usize),
        rotation: Vec<(String, Scenario)>,
    ) -> anyhow::Result<Self> {
        let ns = &sandbox.namespace;
        let demo_set = softarm_stack::demo::demo_set(&sandbox.config)?;
        // Subscribed before the first set: nothing is missed.
        let watch = Watch::start(ns, Limits::from_config(&sandbox.config))?;
        let follower = stats::Stats::open(ns)?;
        let node = Node::open(ns.clone(), "soak")?;
        let statuses = node.subscriber(&node.status()?)?;
        let sim_clock = SimClock {
            tracker: node.subscriber(&node.tracker()?)?,
            rate_hz: sandbox.config.sim.rate_hz,
            seq: 0,
            changing: None,
            steps_seen: 0,
        };
        let mut rng = StdRng::seed_from_u64(args.seed);
        let kill_at = next_kill(args, &mut rng);
        Ok(Self {
            args,
            stop,
            sandbox,
            sup,
            demo_set,
            move_m: sets::move_for(
                sandbox.config.waypoints.reach_m,
                softarm_config::Config::default_sim(".".into())
                    .waypoints
                    .reach_m,
            ),
            watch,
            follower,
            statuses,
            _node: node,
            rng,
            report: Report {
                minutes: args.minutes,
                seed: args.seed,
                lattice_start,
                ..Report::default()
            },
            rss: roles
                .iter()
                .map(|r| (r.to_string(), Rss::default()))
                .collect(),
            warm: false,
            sets: Vec::new(),
            scenarios: vec!["nominal".to_string()],
            scenario: 0,
            rotation,
            sim_clock,
            running: None,
            pending: None,
            last_status: None,
            started: Instant::now(),
            kill_at,
            // Only a sim becomes another arm.
            scenario_at: every(args.scenario_every_s).filter(|_| roles.contains(&"sim")),
            roles,
            sample_at: Instant::now(),
            progress_at: Instant::now() + Duration::from_secs(30),
        })
    }

    fn say(&self, line: &str) {
        say(self.args.json, line);
    }

    /// One round: what arrived, then what is due.
    fn step(&mut self) -> anyhow::Result<()> {
        self.sup.poll();
        self.read_statuses();
        self.follow_sim_clock();
        self.take_executions();
        self.check_recovery();
        self.change_scenario()?;
        self.submit_next()?;
        self.kill_one()?;
        self.sample_memory();
        self.progress();
        Ok(())
    }

    fn pid_of(&self, role: &str) -> Option<u32> {
        self.sup
            .pids()
            .into_iter()
            .find(|(r, _)| r == role)
            .map(|(_, p)| p)
    }

    fn read_statuses(&mut self) {
        while let Ok(Some(s)) = self.statuses.receive() {
            // A young controller's percentiles are its start-up's: its max counts, its p99 not.
            let r = &mut self.report;
            if s.latency.samples >= 5000 {
                r.tick_worst_p99_ns = r.tick_worst_p99_ns.max(s.latency.p99_ns);
            }
            r.tick_worst_max_ns = r.tick_worst_max_ns.max(s.latency.max_ns);
            self.last_status = Some(*s);
        }
    }

    /// Executions as they end.
    fn take_executions(&mut self) {
        while let Some(s) = self.follower.next(Duration::from_millis(50)) {
            self.report.executions += 1;
            let mm = s.mean_m * 1e3;
            count_execution(&mut self.report.arm_changes, mm);
            match self.sets.iter_mut().find(|x| x.id == s.set_id) {
                Some(x) => {
                    x.executions += 1;
                    x.last_mm = mm;
                }
                None => self.sets.push(SetSeen {
                    id: s.set_id,
                    scenario: self.scenarios.len() - 1,
                    executions: 1,
                    first_mm: mm,
                    last_mm: mm,
                }),
            }
            if self
                .running
                .as_ref()
                .is_some_and(|r| r.id == s.set_id && s.execution >= r.executions)
            {
                self.running = None;
            }
            if let Some(p) = self.pending.take_if(|p| p.back) {
                self.say(&format!("{} kill survived: executing again", p.role));
                self.report.kills_survived += 1;
            }
            self.warm = true;
        }
    }

    /// A kill's recovery: the process back under a new pid and the stack answering, then an
    /// execution finished ([`Self::take_executions`]), within [`RECOVERY`].
    fn check_recovery(&mut self) {
        let Some(p) = self.pending.as_ref() else {
            return;
        };
        let (role, old, at, back) = (p.role, p.old, p.at, p.back);
        if !back
            && self.pid_of(role).is_some_and(|n| n != old)
            && status::status(&self.sandbox.namespace, Duration::from_millis(200)).is_ok_and(|r| {
                r.running()
                    && self
                        .roles
                        .iter()
                        .all(|role| r.alive.iter().any(|n| n == role))
            })
        {
            if let Some(p) = self.pending.as_mut() {
                p.back = true;
            }
            if role == "controller" {
                // A new controller forgets its set.
                self.running = None;
            }
        }
        if at.elapsed() > RECOVERY {
            let back = self.pending.as_ref().is_some_and(|p| p.back);
            let why = format!(
                "{role} killed {:.0} s into the soak: {} within {} s",
                (at - self.started).as_secs_f64(),
                if back {
                    "back, but no execution finished"
                } else {
                    "not back"
                },
                RECOVERY.as_secs()
            );
            self.say(&why);
            self.report.kills_not_survived.push(why);
            self.pending = None;
        }
    }

    /// No more kills and changes of the arm: the soak's time is up.
    fn calm(&mut self) {
        self.kill_at = None;
        self.scenario_at = None;
    }

    /// Whether the soak still owes executions: fewer than `--at-least-executions`, or none yet
    /// after the last change of the arm (a change superseded by the next before an execution
    /// ran on it never gets one).
    fn owed(&self) -> bool {
        let r = &self.report;
        r.executions < self.args.at_least_executions
            || (self.args.at_least_executions > 0
                && r.arm_changes.last().is_some_and(|c| c.executions == 0))
    }

    /// Whether the sim is due to become another arm.
    fn scenario_due(&self) -> bool {
        self.scenario_at.is_some_and(|t| Instant::now() >= t)
    }

    /// Between sets: another arm, once due. Not while a killed process is still away; once it is
    /// back the change may come before the execution that proves its recovery.
    fn change_scenario(&mut self) -> anyhow::Result<()> {
        if self.running.is_some()
            || !self.pending.as_ref().is_none_or(|p| p.back)
            || !self.scenario_due()
        {
            return Ok(());
        }
        let (arg, scenario) = self.rotation[self.scenario % self.rotation.len()].clone();
        let name = scenario.name.clone();
        self.scenario += 1;
        self.say(&format!("the sim becomes scenario {name}"));
        self.sup.restart_with(
            "sim",
            supervisor::sim_args(Some(&arg)),
            Duration::from_secs(5),
        )?;
        self.sandbox.wait_for(
            "the scenario's sim coming up",
            Duration::from_secs(60),
            &mut self.sup,
            self.stop,
            &|r| r.alive.iter().any(|n| n == "sim") && r.running(),
        )?;
        self.sim_clock.restart(scenario);
        self.arm_changed(name.clone());
        self.scenarios.push(name);
        self.report.scenario_changes += 1;
        self.scenario_at = every(self.args.scenario_every_s);
        Ok(())
    }

    /// The sim's clock: the steps of a scenario that changes while it runs, and a sim restarted
    /// (after a kill) on one, which starts it over, are changes of the arm.
    fn follow_sim_clock(&mut self) {
        let changes = self.sim_clock.changes();
        for change in changes {
            self.say(&format!("the sim's arm changes: {change}"));
            self.arm_changed(change);
        }
    }

    fn arm_changed(&mut self, arm: String) {
        self.report.arm_changes.push(ArmChange {
            at_s: self.started.elapsed().as_secs_f64(),
            arm,
            ..ArmChange::default()
        });
    }

    /// The next set, once the last is done: the demo set every third, else a variation.
    fn submit_next(&mut self) -> anyhow::Result<()> {
        if self.running.is_some() || !self.pending.as_ref().is_none_or(|p| p.back) {
            return Ok(());
        }
        let (file, executions) = sets::nth(
            self.report.sets_submitted,
            &self.demo_set,
            self.move_m,
            self.sandbox.config.waypoints.reach_m,
            &mut self.rng,
        );
        let set = file.to_set(executions).map_err(anyhow::Error::msg)?;
        match submit::submit(&self.sandbox.namespace, set, Duration::from_secs(5)) {
            submit::Outcome::Accepted { set_id } => {
                self.report.sets_submitted += 1;
                self.running = Some(Running {
                    id: set_id,
                    executions,
                });
            }
            submit::Outcome::Rejected { reason } => {
                self.report.sets_submitted += 1;
                self.report.sets_rejected += 1;
                self.say(&format!("a set was refused: {reason}"));
            }
            // The controller restarting: try again.
            submit::Outcome::Unreachable { .. } => {}
        }
        Ok(())
    }

    /// A random kill, mid-execution or not; none while a scenario change is due, so that kills
    /// coming one after another on a loaded machine never keep the arm from changing.
    fn kill_one(&mut self) -> anyhow::Result<()> {
        if self.pending.is_some()
            || self.scenario_due()
            || self.kill_at.is_none_or(|t| Instant::now() < t)
        {
            return Ok(());
        }
        let role = self.roles[self.rng.random_range(0..self.roles.len())];
        if let Some(old) = self.pid_of(role) {
            if softarm_ipc::Driver::named(role).is_some() {
                // The arm's data stops: HOLD is right. The supervisor restarts the driver after
                // a second at the earliest.
                let t = now_ns();
                self.watch.outage(t, t + 900_000_000);
            }
            kill(Pid::from_raw(old as i32), Signal::SIGKILL)
                .with_context(|| format!("killing the {role} ({old})"))?;
            self.say(&format!("killed the {role} ({old})"));
            match self.report.kills.iter_mut().find(|k| k.0 == role) {
                Some(k) => k.1 += 1,
                None => self.report.kills.push((role.to_string(), 1)),
            }
            self.pending = Some(Pending {
                role,
                old,
                at: Instant::now(),
                back: false,
            });
        }
        self.kill_at = next_kill(self.args, &mut self.rng);
        Ok(())
    }

    /// Memory, every few seconds once warm.
    fn sample_memory(&mut self) {
        if !self.warm || Instant::now() < self.sample_at {
            return;
        }
        self.sample_at = Instant::now() + Duration::from_secs(5);
        let pids: Vec<_> = self.sup.pids();
        for (role, r) in self.rss.iter_mut() {
            let pid = pids.iter().find(|(n, _)| n == role).map(|(_, p)| *p);
            if let Some(kib) = pid.and_then(|p| supervisor::rss_kib(&p.to_string())) {
                if r.start_kib == 0 {
                    r.start_kib = kib;
                }
                r.end_kib = kib;
                r.peak_kib = r.peak_kib.max(kib);
            }
        }
    }

    fn progress(&mut self) {
        if Instant::now() < self.progress_at {
            return;
        }
        self.progress_at = Instant::now() + Duration::from_secs(30);
        let w = self.watch.report();
        self.say(&format!(
            "{:.1} of {} min: {} executions, {} kills, {} invariant violations",
            self.started.elapsed().as_secs_f64() / 60.0,
            self.args.minutes,
            self.report.executions,
            self.report.kills.iter().map(|k| k.1).sum::<u64>(),
            w.violations
        ));
    }

    /// Stops the stack and makes the report, with what fails the soak.
    fn finish(mut self) -> Report {
        if let Some(p) = self.pending.take() {
            // Cut short by the end of the soak: judged by what it reached.
            if p.back {
                self.report.kills_survived += 1;
            } else if p.at.elapsed() > Duration::from_secs(20) {
                self.report
                    .kills_not_survived
                    .push(format!("{} killed at the end: not back in 20 s", p.role));
            }
        }
        let mut report = self.report;
        report.invariants = self.watch.finish();
        let n = self.sandbox.config.layout().actuators().len();
        let state_dir = self.sandbox.config.state_dir();
        report.lattice_end = softarm_ipc::with_actuators!(n,
            N => read_checkpoint::<N>(&state_dir)
                .map(|c| (c.state.actor.len(), c.state.critic.len()))
                .ok(),
            _n => None)
        .unwrap_or(report.lattice_start);
        if let Some(s) = self.last_status {
            report.tick = s.latency;
            report.overruns = s.overruns;
        }
        self.sup.stop(Duration::from_secs(5));
        report.learning = learning(&self.scenarios, &self.sets);
        report.rss = self.rss;
        report.failures = failures(&report);
        report
    }
}

/// The sim's own clock, from its tracker samples: a sample's number over the sim's rate is the
/// plant's time, which is what a scenario's steps are timed on.
struct SimClock {
    tracker: Sub<TrackerSample>,
    rate_hz: f64,
    /// The newest sample's number.
    seq: u64,
    /// The scenario the sim runs, if it changes the arm while it runs.
    changing: Option<Scenario>,
    /// Its steps already seen.
    steps_seen: usize,
}

impl SimClock {
    /// The sim was started again on `scenario`: what came before is the old sim's.
    fn restart(&mut self, scenario: Scenario) {
        while let Ok(Some(_)) = self.tracker.receive() {}
        self.seq = 0;
        self.steps_seen = 0;
        self.changing = scenario.changes_over_time().then_some(scenario);
    }

    /// The arm changes the sim's clock shows since last asked.
    fn changes(&mut self) -> Vec<String> {
        let mut newest = None;
        while let Ok(Some(s)) = self.tracker.receive() {
            newest = Some(s.seq);
        }
        let Some(seq) = newest else {
            return Vec::new();
        };
        // A number that went back: a new sim process, its scenario from its start.
        let restarted = seq < self.seq;
        self.seq = seq;
        let Some(s) = &self.changing else {
            return Vec::new();
        };
        let mut changes = Vec::new();
        if restarted {
            self.steps_seen = 0;
            changes.push(format!("{} from its start (the sim restarted)", s.name));
        }
        let due = steps_due(&s.step_times(), seq as f64 / self.rate_hz);
        for k in self.steps_seen..due {
            changes.push(format!("{} step {}", s.name, k + 1));
        }
        self.steps_seen = self.steps_seen.max(due);
        changes
    }
}

/// How many of the steps at `times` (in order) have come by time `t`.
fn steps_due(times: &[f64], t: f64) -> usize {
    times.iter().take_while(|at| **at <= t).count()
}

fn every(s: f64) -> Option<Instant> {
    (s > 0.0).then(|| Instant::now() + Duration::from_secs_f64(s))
}

fn next_kill(args: &Args, rng: &mut StdRng) -> Option<Instant> {
    (args.kill_every_s > 0.0).then(|| {
        Instant::now() + Duration::from_secs_f64(args.kill_every_s * rng.random_range(0.5..1.5))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(clap::Parser)]
    struct Soak {
        #[command(flatten)]
        args: Args,
    }

    fn args(line: &[&str]) -> Args {
        use clap::Parser;
        let line = ["soak", "--minutes", "1"].iter().chain(line);
        Soak::try_parse_from(line).unwrap().args
    }

    #[test]
    fn the_rotation_is_the_default_or_the_scenarios_given_and_each_must_exist() {
        let names = |a: &Args| -> Vec<String> {
            rotation(a).unwrap().into_iter().map(|(n, _)| n).collect()
        };
        assert_eq!(names(&args(&[])), SCENARIOS);
        let given = args(&["--scenarios", "tool-swap,creeping,nominal"]);
        assert_eq!(names(&given), ["tool-swap", "creeping", "nominal"]);
        assert!(rotation(&given).unwrap()[1].1.changes_over_time());
        let e = rotation(&args(&["--scenarios", "creeping,nowhere"])).unwrap_err();
        assert!(
            format!("{e:#}").contains("nowhere: no such scenario"),
            "{e:#}"
        );
    }

    #[test]
    fn another_arm_soaks_on_its_own_config_model_and_scenarios() {
        let tdcr = args(&["--arm", "tdcr"]);
        let names: Vec<String> = rotation(&tdcr)
            .unwrap()
            .into_iter()
            .map(|(n, _)| n)
            .collect();
        assert_eq!(names, ANY_ARM_SCENARIOS);
        let sandbox = sandbox_for(&tdcr).unwrap();
        assert_eq!(sandbox.config.layout().actuators().len(), 9);
        assert_eq!(
            sandbox.config.model_dir(),
            softarm_stack::demo::model_cache(Some("tdcr"), 1)
        );
        let set = softarm_stack::demo::demo_set(&sandbox.config).unwrap();
        assert_eq!(set.point.len(), 5);
        use clap::Parser;
        let both = [
            "soak",
            "--minutes",
            "1",
            "--arm",
            "tdcr",
            "--config",
            "x.toml",
        ];
        assert!(
            Soak::try_parse_from(both).is_err(),
            "--arm and --config together"
        );
    }

    #[test]
    fn steps_are_due_at_their_time_of_the_sims_clock() {
        let times = [90.0, 240.0];
        assert_eq!(steps_due(&times, 89.99), 0);
        assert_eq!(steps_due(&times, 90.0), 1);
        assert_eq!(steps_due(&times, 1e4), 2);
        assert_eq!(steps_due(&[], 1e4), 0);
    }
}
