//! `softarm train`: drives the arm through the paper's III-B demonstrations via the running
//! controller and records actuation and end-effector position; then the offline pipeline
//! ([`softarm_model::pipeline`]) trains the actuation- and task-space ProMPs and the forward
//! model and pre-trains the learner against the forward model; the bundle is written
//! (atomically) where the controller and learner pick it up.

pub mod recipe;
pub mod recording;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail, ensure};
use softarm_config::Config;
/// Where training's progress goes: `softarm train` the log's, the demo its own lines.
pub use softarm_identify::run::Output;
use softarm_identify::run::{Bar, bar_to};
use softarm_ipc::{
    Client, ControllerState, DemonstrateReply, DemonstrateRequest, MotorState, Namespace, Node,
    Setpoint, Sub, TrackerSample,
};
use softarm_method::skill::Recording;
use softarm_model::bundle::Model;
use softarm_model::pipeline::{
    self, IMITATION_PASSES, PipelineError, Step, TrainReport, Training, TrainingData,
};
use softarm_runtime::now_ns;

/// What `softarm train` made and measured, for the user.
#[derive(Debug, Clone)]
pub struct Trained {
    pub demos: usize,
    pub samples: usize,
    pub demonstrate_s: f64,
    /// The RBF forward model's error on every 5th demonstration, held out of its fit (m):
    /// mean, max.
    pub forward_error_m: (f64, f64),
    /// The same for the polynomial kinematics.
    pub kinematics_error_m: (f64, f64),
    /// The polynomial's degree, as chosen on demonstrations other than the held-out ones.
    pub kinematics_degree: usize,
    /// The RBF forward model's error on the samples it was fitted to (m): mean, standard
    /// deviation; the paper's figure is of this kind.
    pub forward_fitted_m: (f64, f64),
    /// The forward model's width (× the mean nearest-centre distance), as chosen on
    /// demonstrations other than the held-out ones.
    pub forward_width_factor: f64,
    pub pretrain_s: f64,
    pub pretrain_updates: u64,
    pub model_id: String,
}

impl Trained {
    /// What was made and how good it is, in one sentence for the user.
    pub fn summary(&self) -> String {
        format!(
            "{} demonstrations ({} samples, {:.1} s); the RBF forward model (width {}) is off by \
             {:.2} ± {:.2} mm on the samples it was fitted to (the paper reports 3.7 ± 1.6 mm \
             so), on held-out demonstrations by {:.2} mm mean, {:.2} mm max, the polynomial \
             kinematics (degree {}) by {:.2} mm mean, {:.2} mm max; pre-training {:.1} s, {} \
             updates",
            self.demos,
            self.samples,
            self.demonstrate_s,
            self.forward_width_factor,
            self.forward_fitted_m.0 * 1e3,
            self.forward_fitted_m.1 * 1e3,
            self.forward_error_m.0 * 1e3,
            self.forward_error_m.1 * 1e3,
            self.kinematics_degree,
            self.kinematics_error_m.0 * 1e3,
            self.kinematics_error_m.1 * 1e3,
            self.pretrain_s,
            self.pretrain_updates
        )
    }
}

struct Sample<const N: usize> {
    demo: u32,
    class: u32,
    stamp_ns: u64,
    commanded: [f64; N],
    measured: [f64; N],
    position: [f64; 3],
}

/// Records demonstrations through the running stack in `namespace`: (samples, demonstrations,
/// seconds it took).
fn record<const N: usize>(
    namespace: &Namespace,
    seed: u64,
    out: Output,
    stop: &AtomicBool,
) -> Result<(Vec<Sample<N>>, usize, f64)> {
    let mut r = Recorder::<N>::open(namespace)?;
    let (demos, deadline) = r.request(namespace, seed)?;
    tracing::info!(
        "recording {demos} demonstrations through the stack (giving up after {:.0} s)",
        deadline.as_secs_f64()
    );
    let progress = bar_to(demos as u64, "demonstrations", out);
    let start = Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(1));
        r.take_setpoints_and_motor_states();
        r.take_tracker_samples(demos, &progress);
        if r.finished()? {
            break;
        }
        if stop.load(Ordering::Relaxed) {
            bail!("stopped during the demonstrations; nothing was written");
        }
        if start.elapsed() > deadline {
            bail!(
                "the demonstrations did not finish within {:.0} s (controller in HOLD? sim running?); \
                 nothing was written",
                deadline.as_secs_f64()
            );
        }
    }
    // The bar counts the demonstrations done: the last is done once it has played.
    progress.set_position(demos as u64);
    progress.finish_and_clear();
    Ok((r.samples, demos, start.elapsed().as_secs_f64()))
}

/// The recording of one `softarm train`: its ports, the latest setpoint and motor state, and
/// a sample per tracker sample taken while a demonstration plays.
struct Recorder<const N: usize> {
    setpoints: Sub<Setpoint>,
    motors: Sub<MotorState>,
    tracker: Sub<TrackerSample>,
    demonstrate: Client<DemonstrateRequest, DemonstrateReply>,
    setpoint: Option<Setpoint>,
    measured: Option<[f64; N]>,
    samples: Vec<Sample<N>>,
    seen_last: bool,
    demonstrating: bool,
    /// Last, so the ports go before it.
    _node: Node,
}

impl<const N: usize> Recorder<N> {
    fn open(namespace: &Namespace) -> Result<Self> {
        let node = Node::open(namespace.clone(), "train")
            .with_context(|| format!("joining namespace {:?}", namespace.as_str()))?;
        Ok(Self {
            setpoints: node
                .subscriber(&node.setpoint().context("the setpoint service")?)
                .context("subscribing to setpoints")?,
            motors: node
                .subscriber(&node.motor_state().context("the motor_state service")?)
                .context("subscribing to motor_state")?,
            tracker: node
                .subscriber(&node.tracker().context("the tracker service")?)
                .context("subscribing to the tracker")?,
            demonstrate: node
                .client(&node.demonstrate().context("the demonstrate service")?)
                .context("a client of the demonstrate service")?,
            setpoint: None,
            measured: None,
            samples: Vec::new(),
            seen_last: false,
            demonstrating: false,
            _node: node,
        })
    }

    /// Asks the controller to play the demonstrations: (how many, how long to wait at most).
    fn request(&self, namespace: &Namespace, seed: u64) -> Result<(usize, Duration)> {
        let pending = self
            .demonstrate
            .send_copy(DemonstrateRequest {
                seq: now_ns(),
                stamp_ns: now_ns(),
                seed,
            })
            .map_err(|x| anyhow!("sending the request: {x:?}"))?;
        let reply = softarm_clients::poll(Duration::from_secs(5), || {
            pending.receive().ok().flatten().map(|r| *r)
        })
        .ok_or_else(|| {
            anyhow!(softarm_clients::unreachable(
                namespace.as_str(),
                "the demonstration request"
            ))
        })?;
        ensure!(
            reply.accepted == 1,
            "the controller refused to demonstrate: it is busy (executing, planning or in HOLD); \
             wait for it to be IDLE"
        );
        let demos = reply.demos as usize;
        let expected = reply.duration_s;
        tracing::info!(demos, seconds = %format_args!("{expected:.1}"), "playing demonstrations");
        let deadline = deadline(expected).ok_or_else(|| {
            anyhow!(
                "the controller announced {demos} demonstrations taking {expected} s, which is no \
                 usable duration; nothing was written"
            )
        })?;
        Ok((demos, deadline))
    }

    fn take_setpoints_and_motor_states(&mut self) {
        while let Ok(Some(s)) = self.setpoints.receive() {
            self.setpoint = Some(*s);
        }
        while let Ok(Some(m)) = self.motors.receive() {
            if let Some(a) = m.actuation.fixed() {
                self.measured = Some(a);
            }
        }
    }

    /// A sample per tracker sample while a demonstration plays, with the latest setpoint and
    /// motor state.
    fn take_tracker_samples(&mut self, demos: usize, progress: &Bar) {
        while let Ok(Some(t)) = self.tracker.receive() {
            if let (Some(sp), Some(m)) = (self.setpoint, self.measured)
                && let Some(commanded) = sp.actuation.fixed()
                && sp.demo != u32::MAX
                && sp.state == ControllerState::Demonstrate as u32
            {
                self.samples.push(Sample {
                    demo: sp.demo,
                    class: sp.demo_class,
                    stamp_ns: t.stamp_ns,
                    commanded,
                    measured: m,
                    position: t.position,
                });
                progress.set_position(sp.demo as u64);
                self.seen_last |= sp.demo as usize + 1 == demos;
            }
        }
    }

    /// True once the last demonstration has played; an error if the controller stopped
    /// demonstrating before (idle again, or the e-stop).
    fn finished(&mut self) -> Result<bool> {
        let Some(sp) = self.setpoint else {
            return Ok(false);
        };
        let state = ControllerState::from_u32(sp.state);
        if self.seen_last && sp.demo == u32::MAX {
            return Ok(true);
        }
        self.demonstrating |= state == Some(ControllerState::Demonstrate);
        if self.demonstrating && state == Some(ControllerState::Idle) {
            bail!(
                "the controller stopped demonstrating before the last demonstration; \
                 nothing was written"
            );
        }
        if matches!(state, Some(ControllerState::Stopped)) {
            bail!("the e-stop was engaged during the demonstrations; nothing was written");
        }
        Ok(false)
    }
}

/// How long to wait for demonstrations the controller says take `expected` s: half as long
/// again and 10 s more; `None` for a negative, non-finite or too large `expected`.
fn deadline(expected: f64) -> Option<Duration> {
    if expected.is_nan() || expected < 0.0 {
        return None;
    }
    Duration::try_from_secs_f64(expected * 1.5 + 10.0).ok()
}

/// The pre-training budget `pretrain.budget_s` as a duration; one too large to represent is no
/// limit at all.
fn budget(seconds: f64) -> Result<Duration> {
    ensure!(
        seconds >= 0.0,
        "pretrain.budget_s must be a number of seconds >= 0, got {seconds}"
    );
    Ok(Duration::try_from_secs_f64(seconds).unwrap_or(Duration::MAX))
}

/// The samples of demonstrations `0..demos`, one recording each: commanded actuation and
/// tracked position, times from the demonstration's first sample, strictly increasing.
fn recordings<const N: usize>(samples: &[Sample<N>], demos: usize) -> Result<Vec<Recording<N>>> {
    let mut recordings = Vec::with_capacity(demos);
    for d in 0..demos as u32 {
        let mine: Vec<&Sample<N>> = samples.iter().filter(|s| s.demo == d).collect();
        if mine.len() < 10 {
            bail!(
                "demonstration {d} has only {} samples (tracker or controller stalled); nothing was written",
                mine.len()
            );
        }
        let t0 = mine[0].stamp_ns;
        let mut times: Vec<f64> = mine
            .iter()
            .map(|s| s.stamp_ns.saturating_sub(t0) as f64 * 1e-9)
            .collect();
        // Timestamps of two samples can coincide: keep times strictly increasing.
        for i in 1..times.len() {
            if times[i] <= times[i - 1] {
                times[i] = times[i - 1] + 1e-6;
            }
        }
        recordings.push(Recording {
            class: mine[0].class as usize,
            times,
            actuation: mine.iter().map(|s| s.commanded).collect(),
            position: mine.iter().map(|s| s.position).collect(),
        });
    }
    Ok(recordings)
}

/// The pipeline on `data`, each step's progress to `out`, pre-training for at most `budget`:
/// the model and what training measured, and the seconds pre-training took.
fn fit<const N: usize>(
    data: &TrainingData<N>,
    training: &Training,
    budget: Duration,
    out: Output,
    stop: &AtomicBool,
) -> (
    std::result::Result<(Model<N>, TrainReport), PipelineError>,
    f64,
) {
    let steps = std::cell::RefCell::new(Steps { out, now: None });
    // The budget and its progress bar start with the pre-training, after the fits.
    let mut started: Option<(Instant, Bar)> = None;
    let trained = pipeline::train_showing(
        data,
        training,
        &mut |step, done, total| steps.borrow_mut().show(step, done, total),
        |_| {
            let (start, progress) = started.get_or_insert_with(|| {
                steps.borrow_mut().end();
                (out.lines)(&format!(
                    "fitted: pre-training the learner for up to {:.1} s",
                    budget.as_secs_f64()
                ));
                (
                    Instant::now(),
                    bar_to(budget.as_secs(), "pre-training s", out),
                )
            });
            progress.set_position(start.elapsed().as_secs());
            start.elapsed() < budget && !stop.load(Ordering::Relaxed)
        },
    );
    steps.borrow_mut().end();
    let pretrain_s = started.map_or(0.0, |(start, progress)| {
        progress.finish_and_clear();
        start.elapsed().as_secs_f64()
    });
    (trained, pretrain_s)
}

/// The pipeline's steps as bars, one at a time: a step's bar ends as the next one starts.
struct Steps<'a> {
    out: Output<'a>,
    now: Option<(Step, Bar<'a>, u64)>,
}

/// Past this, a step's units (rows × terms² for the kinematics) show as a percentage.
const MAX_SHOWN: u64 = 1000;

impl<'a> Steps<'a> {
    fn show(&mut self, step: Step, done: u64, total: u64) {
        // Counted in percent past MAX_SHOWN units.
        let scale = |v: u64| {
            if total > MAX_SHOWN {
                (u128::from(v) * 100 / u128::from(total)) as u64
            } else {
                v
            }
        };
        if self.now.as_ref().is_none_or(|(s, _, _)| *s != step) {
            self.end();
            let what = if total > MAX_SHOWN {
                format!("{} %", step.name())
            } else {
                step.name().to_string()
            };
            self.now = Some((step, bar_to(scale(total), &what, self.out), total));
        }
        if let Some((_, bar, was)) = &mut self.now {
            if *was != total {
                *was = total;
                bar.set_length(scale(total));
            }
            bar.set_position(scale(done));
        }
    }

    fn end(&mut self) {
        if let Some((_, bar, _)) = self.now.take() {
            bar.finish_and_clear();
        }
    }
}

/// `softarm train`'s settings: the config's sections the pipeline reads.
pub fn training(config: &Config) -> Training {
    Training {
        basis_functions: config.model.basis_functions,
        forward: config.forward_model,
        kinematics: config.kinematics,
        learner: config.learner,
        pretrain: config.pretrain,
        imitation_passes: IMITATION_PASSES,
    }
}

/// Runs the whole training against the stack in `namespace`, for the config's arm, and writes
/// the bundle; each step's progress to `out`. Once `stop` is set it ends at its next step
/// (within the demonstrations' next millisecond, or the pre-training's next batch), writing
/// nothing.
pub fn train(
    config: &Config,
    namespace: &Namespace,
    seed: u64,
    out: Output,
    stop: &AtomicBool,
) -> Result<Trained> {
    let n = config.layout().actuators().len();
    softarm_ipc::with_actuators!(n, N => train_for::<N>(config, namespace, seed, out, stop), n => {
        unreachable!("a loaded config's arm has 3 to 16 actuators, not {n}")
    })
}

/// [`train`] for an arm of `N` actuators.
fn train_for<const N: usize>(
    config: &Config,
    namespace: &Namespace,
    seed: u64,
    out: Output,
    stop: &AtomicBool,
) -> Result<Trained> {
    let budget = budget(config.pretrain.budget_s)?;
    let (samples, demos, demonstrate_s) = record::<N>(namespace, seed, out, stop)?;
    (out.lines)(&format!(
        "{demos} demonstrations recorded in {demonstrate_s:.1} s ({} samples): fitting the \
         primitives, the forward model and the kinematics",
        samples.len()
    ));
    let data = TrainingData {
        recordings: recordings(&samples, demos)?,
        duration_s: config.demonstrations.duration_s,
        // D_fwd: what the actuators really did and where the end effector was.
        actuations: samples.iter().map(|s| s.measured).collect(),
        positions: samples.iter().map(|s| s.position).collect(),
        demo: samples.iter().map(|s| s.demo as usize).collect(),
    };
    let (trained, pretrain_s) = fit(&data, &training(config), budget, out, stop);
    if stop.load(Ordering::Relaxed) {
        bail!("stopped while fitting the model; nothing was written");
    }
    let (mut model, report) =
        trained.context("training on the demonstrations; nothing was written")?;
    model.arm = config.arm_identity();
    tracing::info!(
        "writing the model bundle to {}",
        config.model_dir().display()
    );
    let model_id = model
        .write(&config.model_dir())
        .context("writing the model bundle")?;
    recipe::write(&config.model_dir(), &recipe::of(config, seed))
        .context("writing the model's recipe beside its bundle")?;
    Ok(Trained {
        demos,
        samples: samples.len(),
        demonstrate_s,
        forward_error_m: (report.forward_error.mean_m, report.forward_error.max_m),
        forward_width_factor: report.forward_width_factor,
        forward_fitted_m: (
            report.forward_error.fitted_mean_m,
            report.forward_error.fitted_sd_m,
        ),
        kinematics_error_m: (
            report.kinematics_error.mean_m,
            report.kinematics_error.max_m,
        ),
        kinematics_degree: report.kinematics_degree,
        pretrain_s,
        pretrain_updates: report.pretrain.updates,
        model_id,
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn training_from_a_config_takes_its_sections() {
        let c = softarm_config::Config::default_sim(std::path::PathBuf::from("/tmp/x"));
        let t = super::training(&c);
        assert_eq!(t.basis_functions, c.model.basis_functions);
        assert_eq!(t.forward, c.forward_model);
        assert_eq!(t.kinematics, c.kinematics);
        assert_eq!(t.learner, c.learner);
        assert_eq!(t.pretrain, c.pretrain);
        assert_eq!(t.imitation_passes, super::IMITATION_PASSES);
    }

    use super::*;

    fn sample(demo: u32, class: u32, stamp_ns: u64, v: f64) -> Sample<6> {
        Sample {
            demo,
            class,
            stamp_ns,
            commanded: [v; 6],
            measured: [v + 0.01; 6],
            position: [v, 0.0, -0.5],
        }
    }

    #[test]
    fn samples_become_one_recording_per_demonstration_with_increasing_times() {
        let mut samples = Vec::new();
        for d in 0..2u32 {
            for i in 0..12u64 {
                // Samples 2 and 3 share a stamp.
                let stamp =
                    1_000_000_000 * (d as u64 + 1) + 20_000_000 * if i == 3 { 2 } else { i };
                samples.push(sample(d, d + 1, stamp, 0.1 * i as f64));
            }
        }
        samples.push(sample(7, 0, 5, 0.5));
        let r = recordings(&samples, 2).unwrap();
        assert_eq!(r.len(), 2);
        for (d, rec) in r.iter().enumerate() {
            assert_eq!(rec.class, d + 1);
            assert_eq!(rec.times.len(), 12);
            assert_eq!(rec.times[0], 0.0);
            assert!(rec.times.windows(2).all(|w| w[1] > w[0]), "{:?}", rec.times);
            assert_eq!(rec.actuation[3], [0.30000000000000004; 6]);
            assert_eq!(rec.position[3][0], 0.30000000000000004);
        }
        // A stamp before the first one does not underflow.
        samples.insert(1, sample(0, 1, 0, 0.0));
        let r = recordings(&samples, 2).unwrap();
        assert!(r[0].times.windows(2).all(|w| w[1] > w[0]));
    }

    #[test]
    fn a_stalled_demonstration_is_an_error() {
        let samples: Vec<Sample<6>> = (0..30).map(|i| sample(i % 3, 0, i as u64, 0.5)).collect();
        let e = recordings(&samples, 4).unwrap_err().to_string();
        assert!(e.contains("demonstration 3 has only 0 samples"), "{e}");
        assert!(recordings(&samples, 3).is_ok());
    }

    /// Not on a terminal (a log, this test), every step of training says what it does and how
    /// far, in lines whose counts only grow, and each ends with the time it took.
    #[test]
    fn off_a_terminal_each_step_of_training_is_shown_as_lines() {
        let mut config = softarm_config::Config::default_sim(std::path::PathBuf::from("/tmp/x"));
        config.demonstrations.demos_per_class = 4;
        config.forward_model.centres = 60;
        let layout = config.layout();
        let arm = softarm_kinematics::pcc::Arm::of_config(&config.arm).unwrap();
        let data = TrainingData::<6>::of_arm(&layout, &arm, &config.demonstrations, 3).unwrap();
        let lines = std::cell::RefCell::new(Vec::<String>::new());
        let say = |l: &str| lines.borrow_mut().push(l.to_string());
        let out = Output {
            terminal: false,
            lines: &say,
        };
        let (trained, _) = fit(
            &data,
            &training(&config),
            Duration::ZERO,
            out,
            &AtomicBool::new(false),
        );
        trained.unwrap();
        let lines = lines.into_inner();
        let mut steps = Vec::new();
        for what in ["primitives", "forward model", "kinematics %", "imitation"] {
            // "what: done/total ...": counts never going back, the last one done.
            let counts: Vec<(u64, u64)> = (lines.iter())
                .filter_map(|l| l.strip_prefix(&format!("{what}: ")))
                .filter_map(|rest| {
                    let (done, total) = rest
                        .split_once(' ')
                        .unwrap_or((rest, ""))
                        .0
                        .split_once('/')?;
                    Some((done.parse().ok()?, total.parse().ok()?))
                })
                .collect();
            assert!(counts.len() >= 2, "{what}: {lines:#?}");
            assert!(
                counts.windows(2).all(|w| w[0].0 <= w[1].0),
                "{what}: {counts:?}"
            );
            let (done, total) = counts[counts.len() - 1];
            assert_eq!(done, total, "{what}: {lines:#?}");
            steps.push(lines.iter().position(|l| l.starts_with(what)).unwrap());
        }
        // In the pipeline's order, each ended before the next began, then pre-training.
        assert!(steps.windows(2).all(|w| w[0] < w[1]), "{lines:#?}");
        for what in ["primitives", "forward model", "kinematics %", "imitation"] {
            assert!(
                lines
                    .iter()
                    .any(|l| l.starts_with(what) && l.contains("done in")),
                "{what}"
            );
        }
        assert!(
            lines.iter().any(|l| l.starts_with("fitted: pre-training")),
            "{lines:#?}"
        );
    }

    #[test]
    fn unusable_durations_are_errors_not_panics() {
        assert_eq!(deadline(4.0), Some(Duration::from_secs(16)));
        for bad in [f64::NAN, -1.0, f64::INFINITY, 1e300] {
            assert_eq!(deadline(bad), None, "{bad}");
        }
        assert_eq!(budget(2.5).unwrap(), Duration::from_millis(2500));
        assert_eq!(budget(1e300).unwrap(), Duration::MAX);
        assert_eq!(budget(f64::INFINITY).unwrap(), Duration::MAX);
        for bad in [f64::NAN, -0.5] {
            let e = budget(bad).unwrap_err().to_string();
            assert!(e.contains("pretrain.budget_s"), "{e}");
        }
    }
}
