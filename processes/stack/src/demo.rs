//! `softarm demo`: the one-command showcase. Brings the simulated stack up in a namespace of its
//! own, trains if no readable bundle exists, submits the demo way-point set (or `--set`), prints
//! the error at every conditioning point per execution, optionally runs a second set once on
//! what was learnt (`--then`), and stops everything. On an arm that changes while it runs
//! (`--drift`, or a `--scenario` with steps or a drift) each row also says the sim's time and
//! what had changed by then.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use softarm_clients::{stats, submit};
use softarm_config::scenario::Scenario;
use softarm_config::waypoints::{WaypointFile, validate};
use softarm_config::{Config, DEFAULT};
use softarm_ipc::{ExecutionStats, Namespace, Node, Sub, TrackerSample};
use softarm_record::{plot, record};

use crate::sandbox::{self, ModelFolder, Sandbox};
use crate::supervisor::{self, Supervisor};

#[derive(clap::Args)]
pub struct Args {
    /// Executions of the way-point set (default 20; with --drift 40).
    #[arg(long, allow_negative_numbers = true)]
    executions: Option<u32>,
    /// Seeds the demonstrations, the plant and the learner.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    /// One JSON object per execution on stdout (as `softarm stats --follow --json`), nothing else.
    #[arg(long)]
    json: bool,
    /// Where the trained model is kept between runs (default: the user's cache folder).
    #[arg(long)]
    model_dir: Option<PathBuf>,
    /// The arm to run: a shipped arm (paper, hybrid, tdcr) or an arm file (an `[arm]` section
    /// on its own, as in config/arms/); default the paper's. Another arm brings the boxes its
    /// reach bounds, its own trained model, and without --set a way-point set on its own
    /// demonstrations.
    #[arg(long, value_name = "NAME|FILE")]
    arm: Option<String>,
    /// The sim's plant as a MuJoCo model (softarm built with `--features mujoco`): a plant file
    /// (its `[mujoco]`, and the `[arm]` it models, e.g. config/mujoco/opencr-ftdcr-v6.toml), or
    /// `generated` for a model generated from the arm. Trained on that plant.
    #[arg(long, value_name = "FILE|generated")]
    mujoco: Option<String>,
    /// Runs the set on another arm than the model was trained on: a shipped scenario (nominal,
    /// tool-change, creep, twist, stiffer, not-pcc, ...) or a scenario file. The model stays the
    /// nominal one.
    #[arg(long)]
    scenario: Option<String>,
    /// Runs the set again and again on an arm that changes while it runs: a scenario with steps
    /// or a drift (tool-swap, creeping, stiffness-cycle, combined, sequence) or such a file. Each row
    /// adds the sim's time and what had changed by then.
    #[arg(long, value_name = "NAME|FILE", conflicts_with = "scenario")]
    drift: Option<String>,
    /// The online learner: gauss-newton (Jacobian-directed steps; "softarm", its former name,
    /// still works) or paper (Alg. 1 as printed).
    #[arg(long, value_enum, default_value_t = Learner::GaussNewton)]
    learner: Learner,
    /// The way-point file to run (default: the demo set, config/waypoints/demo.toml).
    #[arg(long, value_name = "FILE")]
    set: Option<PathBuf>,
    /// A second way-point file, run once after the first set's executions, on what the learner
    /// learnt: how far it carries to points it has not visited.
    #[arg(long, value_name = "FILE")]
    then: Option<PathBuf>,
    /// Records the run here (MCAP), and plots it beside it (the same name, .png).
    #[arg(long, value_name = "FILE", default_value = "softarm-demo.mcap")]
    record: PathBuf,
    /// Neither records nor plots.
    #[arg(long)]
    no_record: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, clap::ValueEnum)]
enum Learner {
    /// `learner.algorithm = "gauss-newton"`; `softarm` is its former name.
    #[value(alias = "softarm")]
    GaussNewton,
    Paper,
}

/// Executions of a `--drift` demo unless `--executions` says: about four minutes, past the
/// shipped steps at 90 s.
const DRIFT_EXECUTIONS: u32 = 40;

impl Args {
    /// The scenario asked for, by `--drift` or `--scenario`.
    fn scenario_arg(&self) -> Option<&str> {
        self.drift.as_deref().or(self.scenario.as_deref())
    }

    fn executions(&self) -> u32 {
        let default = if self.drift.is_some() {
            DRIFT_EXECUTIONS
        } else {
            20
        };
        self.executions.unwrap_or(default)
    }
}

fn say(json: bool, line: &str) {
    if !json {
        eprintln!("{line}");
    }
}

pub fn run(args: &Args, stop: &AtomicBool) -> anyhow::Result<()> {
    let scenario = check(args)?;
    let started = Instant::now();
    let sandbox = sandbox_for(args)?;
    let (config, ns) = (&sandbox.config, &sandbox.namespace);
    if let Some(s) = &scenario {
        // Refused here, naming the key, rather than by a sim that will not start.
        s.check_on(config)?;
    }
    // The user's sets, read and checked as the controller will check them, before the stack.
    let (mut file, then) = sets(args, config)?;
    // On physics softarm did not write, the arm goes where its physics takes it, not where
    // PCC says: the derived set is taken from the model trained on it, after training.
    let on_the_model = args.set.is_none() && config.sim.mujoco.is_some();
    if args.set.is_none() && config.arm.shorthand().is_none() && !on_the_model {
        say_points(args, config, &file);
    }

    let mut sup = sandbox.supervisor(&["sim", "controller", "learner"], "warn")?;
    say(
        args.json,
        &format!("softarm demo: stack up in namespace {}", ns.as_str()),
    );
    let folder = match args.model_dir {
        Some(_) => ModelFolder::Given,
        None => ModelFolder::Cache,
    };
    sandbox.ready_with_model(&mut sup, stop, args.seed, folder, &|line| {
        say(args.json, &format!("softarm demo: {line}"))
    })?;
    if on_the_model {
        file = demo_set_on(config, &config.model_dir())?;
        file.to_set(args.executions())
            .and_then(|set| validate(&set, &config.waypoints, &config.activation))
            .map_err(|e| anyhow::anyhow!("the demo set on the trained model: {e}"))?;
        say_points(args, config, &file);
    }
    if let Some(s) = scenario.as_ref().filter(|s| !s.is_nominal()) {
        become_scenario(args, s, &sandbox, &mut sup, stop)?;
    }
    // On an arm that changes while it runs, the sim's clock beside each row.
    let mut changing = scenario
        .filter(Scenario::changes_over_time)
        .map(|s| Changing::open(ns, s, config.sim.rate_hz))
        .transpose()?;

    // Subscribe before submitting: no execution's stats can be missed.
    let follower = stats::Stats::open(ns)?;
    // The recorder is one more subscriber, on a thread of its own, from here to the end.
    let recording_stop = Arc::new(AtomicBool::new(false));
    let recording = (!args.no_record).then(|| {
        let (ns, out, stop) = (ns.clone(), args.record.clone(), recording_stop.clone());
        let scene = softarm_channels::scene::Settings::of(config);
        std::thread::spawn(move || record::record(&ns, &out, &scene, None, &stop))
    });
    let mut run_set = |file: &WaypointFile, executions: u32, sup: &mut Supervisor| {
        let rows = Rows {
            json: args.json,
            changing: changing.as_mut(),
        };
        run_set(
            ns,
            &follower,
            file,
            executions,
            config.controller.rest_s,
            rows,
            sup,
            stop,
        )
    };
    let rows = run_set(&file, args.executions(), &mut sup)?;
    let second = match &then {
        Some(file) => Some(run_set(file, 1, &mut sup)?),
        None => None,
    };
    recording_stop.store(true, Ordering::Relaxed);
    sup.stop(Duration::from_secs(5));
    if let Some(recording) = recording {
        let counts = recording
            .join()
            .map_err(|_| anyhow::anyhow!("the recorder panicked"))??;
        plot_recording(args, counts.values().sum())?;
    }
    summary(args, &rows, second.as_deref(), started);
    Ok(())
}

/// What can be refused before anything starts (a stack, minutes of training), rather than at
/// the end of the run; the scenario, resolved.
fn check(args: &Args) -> anyhow::Result<Option<Scenario>> {
    if args.executions() == 0 {
        bail!("--executions must be at least 1");
    }
    let scenario = args.scenario_arg().map(Scenario::resolve).transpose()?;
    if let Some(s) = scenario.as_ref().filter(|s| !s.changes_over_time())
        && args.drift.is_some()
    {
        bail!(
            "--drift {}: this scenario does not change while the arm runs (no [[step]], no \
             [drift]); --scenario runs it",
            s.name
        );
    }
    if !args.no_record {
        record::check_output(&args.record).context("--record")?;
        plot::check_output(&args.record.with_extension("png")).context("--record")?;
    }
    let model_dir = model_dir(args);
    if model_dir.exists() && !model_dir.is_dir() {
        bail!("the model folder {} is not a folder", model_dir.display());
    }
    Ok(scenario)
}

/// The model folder: `--model-dir`, else [`model_cache`], one of its own per MuJoCo plant
/// (by a hash of the plant file's text), which trains its own model.
fn model_dir(args: &Args) -> PathBuf {
    if let Some(dir) = &args.model_dir {
        return dir.clone();
    }
    let cache = model_cache(args.arm.as_deref(), args.seed);
    let Some(plant) = &args.mujoco else {
        return cache;
    };
    let text = std::fs::read_to_string(plant).unwrap_or_else(|_| plant.clone());
    let name = cache.file_name().map(|n| n.to_string_lossy().into_owned());
    let hash = softarm_model::bundle::fnv64(text.as_bytes());
    cache.with_file_name(format!("mujoco{hash:016x}-{}", name.unwrap_or_default()))
}

/// The demo's model folder in the cache, one per arm and seed (an arm file's by a hash of its
/// text, so an edited arm is trained again): what `softarm-rig soak --arm` uses too.
pub fn model_cache(arm: Option<&str>, seed: u64) -> PathBuf {
    let arm = match arm {
        None | Some("paper") => String::new(),
        Some(name)
            if softarm_config::arms::SHIPPED
                .iter()
                .any(|(n, _)| *n == name) =>
        {
            format!("{name}-")
        }
        Some(file) => {
            let text = softarm_config::arms::resolve(file).unwrap_or_default();
            format!("arm{:016x}-", softarm_model::bundle::fnv64(text.as_bytes()))
        }
    };
    sandbox::cache_dir().join(format!("demo-model-{arm}seed{seed}"))
}

/// The embedded default config, with `--arm`'s arm in it.
fn config_text(args: &Args) -> anyhow::Result<String> {
    let text = with_arm(args.arm.as_deref())?;
    let Some(plant) = &args.mujoco else {
        return Ok(text);
    };
    let plant = softarm_config::plant::Plant::resolve(plant)?;
    if plant.arm.is_some() && args.arm.is_some() {
        bail!(
            "--arm and --mujoco {}: the plant file says the arm it models; give one of them",
            plant.origin()
        );
    }
    Ok(plant.into_config(&text)?)
}

/// The embedded default config with `arm` (a shipped arm's name or an arm file) in it, and
/// the boxes its reach bounds; the default itself without one.
pub fn with_arm(arm: Option<&str>) -> anyhow::Result<String> {
    match arm {
        None => Ok(DEFAULT.to_string()),
        Some(arm) => {
            let text = softarm_config::arms::resolve(arm)?;
            Ok(softarm_config::arms::with_arm(DEFAULT, &text, arm)?)
        }
    }
}

/// The embedded default, in this demo's own namespace, with its own state, model and seeds.
fn sandbox_for(args: &Args) -> anyhow::Result<Sandbox> {
    let seed = i64::try_from(args.seed).context("--seed must be at most 9223372036854775807")?;
    let algorithm = match args.learner {
        Learner::GaussNewton => "gauss-newton",
        Learner::Paper => "paper",
    };
    Sandbox::for_command(
        "demo",
        &config_text(args)?,
        &[
            ("model.dir", model_dir(args).display().to_string().into()),
            ("learner.seed", seed.into()),
            ("learner.algorithm", algorithm.into()),
            ("sim.realism.seed", seed.into()),
        ],
    )
}

/// The set to run (`--set`, else the demo's) and the one to run once after (`--then`), each
/// refused where the controller would refuse it.
fn sets(args: &Args, config: &Config) -> anyhow::Result<(WaypointFile, Option<WaypointFile>)> {
    let file = match &args.set {
        Some(path) => load_set("--set", path, config, args.executions())?,
        None => {
            let file = demo_set(config)?;
            file.to_set(args.executions())
                .and_then(|set| validate(&set, &config.waypoints, &config.activation))
                .map_err(|e| anyhow::anyhow!("--executions: {e}"))?;
            file
        }
    };
    let then = args
        .then
        .as_deref()
        .map(|path| load_set("--then", path, config, 1))
        .transpose()?;
    Ok((file, then))
}

/// Says where the derived set's points are.
fn say_points(args: &Args, config: &Config, file: &WaypointFile) {
    let points: Vec<String> = file
        .point
        .iter()
        .map(|p| format!("{:?} m at {} s", p.position_m, p.t_s))
        .collect();
    say(
        args.json,
        &format!(
            "softarm demo: the arm {}; the way-points lie on its own demonstrations: {}",
            config.arm_identity(),
            points.join(", ")
        ),
    );
}

/// The demo's five points where the arm went in training
/// ([`softarm_method::skill::demo_points_seen`]): on the task-space primitives trained in `dir`
/// from what the tracker measured over the demonstrations, not through a model. What a MuJoCo
/// plant runs: there, PCC put three of five points 26 to 46 mm from every pose the arm took,
/// and the forward model put one at the whole arm's length from the base, which the arm came
/// within 8 to 10 mm of and no closer.
fn demo_set_on(config: &Config, dir: &Path) -> anyhow::Result<WaypointFile> {
    let layout = config.layout();
    let points = softarm_ipc::with_actuators!(layout.actuators().len(),
        N => {
            let model = softarm_model::bundle::Model::<N>::read(dir)
                .with_context(|| format!("the trained model in {}", dir.display()))?;
            softarm_method::skill::demo_points_seen(&model.task)
        },
        n => bail!("an arm of {n} actuators"));
    Ok(set_of(points))
}

/// The demo's way-point set on `config`'s arm: the shipped one on the paper's, else five points
/// on the arm's own nominal demonstrations ([`softarm_method::skill::demo_points`]) at the
/// shipped set's times.
pub fn demo_set(config: &Config) -> anyhow::Result<WaypointFile> {
    let shipped = WaypointFile::parse(sandbox::DEMO_WAYPOINTS)
        .map_err(anyhow::Error::msg)
        .context("the demo way-points")?;
    let layout = config.layout();
    // The shipped points are the paper's, on its kind of arm.
    if config.arm.shorthand().is_some() {
        return Ok(shipped);
    }
    let classes = softarm_method::skill::classes(&config.demonstrations, &layout);
    let arm = softarm_kinematics::pcc::Arm::of_config(&config.arm).map_err(anyhow::Error::msg)?;
    let points = softarm_ipc::with_actuators!(layout.actuators().len(),
        N => softarm_method::skill::demo_points::<N>(&classes, &arm),
        n => bail!("an arm of {n} actuators"));
    Ok(set_of(points))
}

/// `points` at the shipped set's times.
fn set_of(points: Vec<[f64; 3]>) -> WaypointFile {
    let shipped = WaypointFile::parse(sandbox::DEMO_WAYPOINTS).expect("the shipped set parses");
    // To the tenth of a millimetre, as a way-point file would say them.
    let round = |p: [f64; 3]| p.map(|v| (v * 1e4).round() / 1e4);
    WaypointFile {
        duration_s: shipped.duration_s,
        point: shipped
            .point
            .iter()
            .zip(points)
            .map(|(p, position)| softarm_config::waypoints::Point {
                t_s: p.t_s,
                position_m: round(position),
            })
            .collect(),
    }
}

/// Trained (or reused) on the nominal arm; now the sim becomes the scenario's arm.
fn become_scenario(
    args: &Args,
    s: &Scenario,
    sandbox: &Sandbox,
    sup: &mut Supervisor,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    say(
        args.json,
        &format!(
            "softarm demo: the sim runs scenario {}: {}",
            s.name,
            s.describe()
        ),
    );
    let arg = args.scenario_arg();
    sup.restart_with("sim", supervisor::sim_args(arg), Duration::from_secs(5))?;
    sandbox.wait_for(
        "the scenario's sim coming up",
        Duration::from_secs(20),
        sup,
        stop,
        &|r| {
            r.alive.iter().any(|n| n == "sim")
                && r.controller
                    .is_some_and(|s| s.state == softarm_ipc::ControllerState::Idle as u32)
        },
    )
}

/// The finished recording of `samples` samples drawn beside it (`.png`).
fn plot_recording(args: &Args, samples: u64) -> anyhow::Result<()> {
    let png = args.record.with_extension("png");
    let messages = record::read(&args.record)?;
    let data = plot::plot_data(&messages, "softarm demo")?;
    plot::render(&data, &png)?;
    say(
        args.json,
        &format!(
            "softarm demo: recorded {} ({samples} samples; `softarm replay` reads it), plotted {}",
            args.record.display(),
            png.display()
        ),
    );
    Ok(())
}

fn summary(
    args: &Args,
    rows: &[ExecutionStats],
    second: Option<&[ExecutionStats]>,
    started: Instant,
) {
    let first = rows.first().expect("at least one execution");
    let last = rows.last().expect("at least one execution");
    say(
        args.json,
        &format!(
            "softarm demo: mean error at the conditioning points {:.2} mm (execution 1) -> {:.2} mm (execution {}); {:.0} s in all",
            first.mean_m * 1e3,
            last.mean_m * 1e3,
            last.execution,
            started.elapsed().as_secs_f64()
        ),
    );
    if let Some(s) = second.and_then(|r| r.first()) {
        say(
            args.json,
            &format!(
                "softarm demo: the second set's first execution: {:.2} mm",
                s.mean_m * 1e3
            ),
        );
    }
}

/// The way-point file of option `flag`, refused (naming both) where the controller would refuse
/// it for `executions` executions under `config`'s limits.
fn load_set(
    flag: &str,
    path: &Path,
    config: &Config,
    executions: u32,
) -> anyhow::Result<WaypointFile> {
    let file = WaypointFile::load(path)
        .map_err(anyhow::Error::msg)
        .context(flag.to_string())?;
    file.to_set(executions)
        .and_then(|set| validate(&set, &config.waypoints, &config.activation))
        .map_err(|e| anyhow::anyhow!("{flag} {}: {e}", path.display()))?;
    Ok(file)
}

/// The sim's clock and what its scenario had changed by then, for the rows of a demo on an arm
/// that changes while it runs.
struct Changing {
    scenario: Scenario,
    /// The sim's newest tracker sample: its number over the sim's rate is the plant's time.
    tracker: Sub<TrackerSample>,
    _node: Node,
    rate_hz: f64,
    seq: u64,
}

impl Changing {
    fn open(ns: &Namespace, scenario: Scenario, rate_hz: f64) -> anyhow::Result<Self> {
        let node = Node::open(ns.clone(), "demo")?;
        let tracker = node.subscriber(&node.tracker()?)?;
        Ok(Self {
            scenario,
            tracker,
            _node: node,
            rate_hz,
            seq: 0,
        })
    }

    /// The sim's time now (s since it started its scenario): the plant steps once per sample.
    fn sim_time_s(&mut self) -> f64 {
        while let Ok(Some(s)) = self.tracker.receive() {
            self.seq = s.seq;
        }
        self.seq as f64 / self.rate_hz
    }
}

/// How rows are printed: a table or JSON lines, with the sim's clock when the arm changes.
struct Rows<'a> {
    json: bool,
    changing: Option<&'a mut Changing>,
}

impl Rows<'_> {
    fn header(&self, points: usize) -> String {
        let h = stats::table_header(points);
        match self.changing {
            Some(_) => format!("{h} {:>6}  what had changed (the sim's clock)", "t s"),
            None => h,
        }
    }

    /// Execution `s`'s row, as it ends.
    fn row(&mut self, s: &ExecutionStats) -> String {
        let Some(c) = self.changing.as_deref_mut() else {
            return if self.json {
                stats::json_line(s)
            } else {
                stats::table_row(s)
            };
        };
        let t = c.sim_time_s();
        let changed = c.scenario.changed_at(t);
        if self.json {
            let mut v: serde_json::Value =
                serde_json::from_str(&stats::json_line(s)).unwrap_or_default();
            v["sim_time_s"] = serde_json::json!((t * 10.0).round() / 10.0);
            v["changed"] = changed.into();
            v.to_string()
        } else {
            format!("{} {t:>6.0}  {changed}", stats::table_row(s))
        }
    }
}

/// Submits `file` for `executions` executions and prints each execution's row as it ends.
#[allow(clippy::too_many_arguments)]
fn run_set(
    ns: &Namespace,
    follower: &stats::Stats,
    file: &WaypointFile,
    executions: u32,
    rest_s: f64,
    mut rows_out: Rows,
    sup: &mut Supervisor,
    stop: &AtomicBool,
) -> anyhow::Result<Vec<ExecutionStats>> {
    let json = rows_out.json;
    let waypoints = file.to_set(executions).map_err(anyhow::Error::msg)?;
    let set_id = match submit::submit(ns, waypoints, Duration::from_secs(10)) {
        submit::Outcome::Accepted { set_id } => set_id,
        submit::Outcome::Rejected { reason } => {
            bail!("the way-point set was rejected: {reason}");
        }
        submit::Outcome::Unreachable { message } => bail!(message),
    };
    say(
        json,
        &format!(
            "softarm demo: {executions} executions of {} conditioning points ({} s each)",
            file.point.len(),
            file.duration_s
        ),
    );
    say(json, &rows_out.header(file.point.len()));
    // Both bounded by validation (the set's duration, the config's rest).
    let per_execution = Duration::try_from_secs_f64(file.duration_s + rest_s + 10.0)
        .context("the way-point set's duration")?;
    let mut rows: Vec<ExecutionStats> = Vec::new();
    while rows.len() < executions as usize {
        if stop.load(Ordering::Relaxed) {
            bail!("interrupted");
        }
        sup.poll();
        let Some(s) = follower.next(per_execution) else {
            bail!(
                "no stats for execution {} within {} s",
                rows.len() + 1,
                per_execution.as_secs()
            );
        };
        if s.set_id != set_id {
            continue;
        }
        println!("{}", rows_out.row(&s));
        rows.push(s);
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::ValueEnum;

    #[derive(clap::Parser)]
    struct Demo {
        #[command(flatten)]
        args: Args,
    }

    fn parse(line: &[&str]) -> Result<Args, clap::Error> {
        use clap::Parser;
        Demo::try_parse_from(std::iter::once("demo").chain(line.iter().copied())).map(|d| d.args)
    }

    #[test]
    fn drift_takes_a_scenario_that_changes_and_runs_longer() {
        let a = parse(&["--drift", "creeping", "--no-record"]).unwrap();
        assert_eq!((a.executions(), a.scenario_arg()), (40, Some("creeping")));
        assert!(check(&a).unwrap().unwrap().changes_over_time());
        let a = parse(&["--drift", "tool-swap", "--executions", "3"]).unwrap();
        assert_eq!(a.executions(), 3);
        assert_eq!(parse(&["--scenario", "twist"]).unwrap().executions(), 20);
        let fixed = parse(&["--drift", "tool-change", "--no-record"]).unwrap();
        let e = check(&fixed).unwrap_err().to_string();
        assert!(e.contains("does not change while the arm runs"), "{e}");
        assert!(parse(&["--drift", "creeping", "--scenario", "twist"]).is_err());
    }

    /// On the paper's arm the shipped set; on another, five points the arm's own demonstrations
    /// pass through, apart from each other, that the controller admits.
    #[test]
    fn each_arm_gets_a_demo_set_on_its_own_demonstrations() {
        for (name, _) in softarm_config::arms::SHIPPED {
            let a = parse(&["--arm", name, "--no-record"]).unwrap();
            let c = Config::parse(&config_text(&a).unwrap(), name, ".".into()).unwrap();
            let file = demo_set(&c).unwrap();
            let set = file.to_set(20).unwrap();
            validate(&set, &c.waypoints, &c.activation).unwrap_or_else(|e| panic!("{name}: {e}"));
            let p: Vec<[f64; 3]> = file.point.iter().map(|p| p.position_m).collect();
            assert_eq!(p.len(), 5, "{name}");
            // Each point somewhere else, and the set moving from one to the next.
            for i in 0..p.len() {
                for j in 0..i {
                    let d = softarm_method::distance(&p[i], &p[j]);
                    let apart = if j + 1 == i { 0.005 } else { 0.001 };
                    assert!(
                        d > apart,
                        "{name}: points {} and {} are {d} m apart",
                        j + 1,
                        i + 1
                    );
                }
            }
            if name == "paper" {
                assert_eq!(file, WaypointFile::parse(sandbox::DEMO_WAYPOINTS).unwrap());
            }
        }
    }

    #[test]
    fn the_learner_flag_takes_the_new_name_and_the_former_one() {
        assert_eq!(
            Learner::GaussNewton.to_possible_value().unwrap().get_name(),
            "gauss-newton"
        );
        for name in ["gauss-newton", "softarm"] {
            assert_eq!(
                Learner::from_str(name, false),
                Ok(Learner::GaussNewton),
                "{name}"
            );
        }
        assert_eq!(Learner::from_str("paper", false), Ok(Learner::Paper));
    }
}
