//! `softarm train`: drives the arm through the paper's III-B demonstrations via the running
//! controller, records actuation and end-effector position, trains the actuation- and
//! task-space ProMPs and the forward model, pre-trains the learner against the forward model,
//! and writes the model bundle (atomically) where the controller and learner pick it up.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use softarm_ipc::{ControllerState, DemonstrateRequest, Namespace, Node, now_ns};
use softarm_method::cacla::{CaclaMtl, pretrain};
use softarm_method::forward::ForwardModel;
use softarm_method::rbf::RbfNetwork;
use softarm_method::skill::{Recording, train_primitives};
use softarm_model::bundle::Model;
use softarm_model::config::Config;

/// What training measured.
#[derive(Debug, Clone)]
pub struct TrainReport {
    pub demos: usize,
    pub samples: usize,
    pub demonstrate_s: f64,
    /// Forward model error on every 5th sample, held out of its fit (m): mean, max.
    pub forward_error_m: (f64, f64),
    pub pretrain_s: f64,
    pub pretrain_updates: u64,
    pub model_id: String,
}

fn bar(len: u64, msg: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(len);
    b.set_style(
        ProgressStyle::with_template("{msg:>16} [{bar:40}] {pos}/{len} ({elapsed})")
            .expect("a valid template")
            .progress_chars("=> "),
    );
    b.set_message(msg.to_string());
    b
}

struct Sample {
    demo: u32,
    class: u32,
    stamp_ns: u64,
    commanded: [f64; 6],
    measured: [f64; 6],
    position: [f64; 3],
}

/// Records demonstrations through the running stack in `namespace`.
fn record(namespace: &Namespace, seed: u64) -> Result<(Vec<Sample>, usize, f64), String> {
    let e = |e: softarm_ipc::Error| e.to_string();
    let ipc = Node::open(namespace.clone(), "train").map_err(e)?;
    let setpoints = ipc.subscriber(&ipc.setpoint().map_err(e)?).map_err(e)?;
    let motors = ipc.subscriber(&ipc.motor_state().map_err(e)?).map_err(e)?;
    let tracker = ipc.subscriber(&ipc.tracker().map_err(e)?).map_err(e)?;
    let client = ipc.client(&ipc.demonstrate().map_err(e)?).map_err(e)?;
    let pending = client
        .send_copy(DemonstrateRequest {
            seq: now_ns(),
            stamp_ns: now_ns(),
            seed,
        })
        .map_err(|x| format!("sending the request: {x:?}"))?;
    let reply = crate::poll(Duration::from_secs(5), || {
        pending.receive().ok().flatten().map(|r| *r)
    })
    .ok_or_else(|| crate::unreachable(namespace.as_str(), "the demonstration request"))?;
    if reply.accepted != 1 {
        return Err(
            "the controller refused to demonstrate: it is busy (executing, planning or in HOLD); \
                    wait for it to be IDLE"
                .into(),
        );
    }
    let demos = reply.demos as usize;
    let expected = reply.duration_s;
    tracing::info!(demos, seconds = expected, "playing demonstrations");
    let progress = bar(demos as u64, "demonstrations");
    let start = Instant::now();
    let deadline = Duration::from_secs_f64(expected * 1.5 + 10.0);
    let mut samples = Vec::new();
    let mut setpoint = None;
    let mut measured = None;
    let mut seen_last = false;
    let mut demonstrating = false;
    loop {
        std::thread::sleep(Duration::from_millis(1));
        while let Ok(Some(s)) = setpoints.receive() {
            setpoint = Some(*s);
        }
        while let Ok(Some(m)) = motors.receive() {
            measured = Some(m.actuation);
        }
        while let Ok(Some(t)) = tracker.receive() {
            if let (Some(sp), Some(m)) = (setpoint, measured)
                && sp.demo != u32::MAX
                && sp.state == ControllerState::Demonstrate as u32
            {
                samples.push(Sample {
                    demo: sp.demo,
                    class: sp.demo_class,
                    stamp_ns: t.stamp_ns,
                    commanded: sp.actuation,
                    measured: m,
                    position: t.position,
                });
                progress.set_position(sp.demo as u64);
                seen_last |= sp.demo as usize + 1 == demos;
            }
        }
        if let Some(sp) = setpoint {
            let state = ControllerState::from_u32(sp.state);
            if seen_last && sp.demo == u32::MAX {
                break;
            }
            demonstrating |= state == Some(ControllerState::Demonstrate);
            if demonstrating && state == Some(ControllerState::Idle) {
                return Err("the controller stopped demonstrating before the last demonstration;                             nothing was written"
                    .into());
            }
            if matches!(state, Some(ControllerState::Stopped)) {
                return Err(
                    "the e-stop was engaged during the demonstrations; nothing was written".into(),
                );
            }
        }
        if start.elapsed() > deadline {
            return Err(format!(
                "the demonstrations did not finish within {:.0} s (controller in HOLD? sim running?); \
                 nothing was written",
                deadline.as_secs_f64()
            ));
        }
    }
    progress.finish_and_clear();
    Ok((samples, demos, start.elapsed().as_secs_f64()))
}

/// Runs the whole training against the stack in `namespace` and writes the bundle.
pub fn train(config: &Config, namespace: &Namespace, seed: u64) -> Result<TrainReport, String> {
    let (samples, demos, demonstrate_s) = record(namespace, seed)?;
    let mut recordings = Vec::with_capacity(demos);
    for d in 0..demos as u32 {
        let mine: Vec<&Sample> = samples.iter().filter(|s| s.demo == d).collect();
        if mine.len() < 10 {
            return Err(format!(
                "demonstration {d} has only {} samples (tracker or controller stalled); nothing was written",
                mine.len()
            ));
        }
        let t0 = mine[0].stamp_ns;
        recordings.push(Recording {
            class: mine[0].class as usize,
            times: mine
                .iter()
                .map(|s| (s.stamp_ns - t0) as f64 * 1e-9)
                .collect(),
            actuation: mine.iter().map(|s| s.commanded).collect(),
            position: mine.iter().map(|s| s.position).collect(),
        });
    }
    // Timestamps of two samples can coincide: keep times strictly increasing.
    for r in &mut recordings {
        for i in 1..r.times.len() {
            if r.times[i] <= r.times[i - 1] {
                r.times[i] = r.times[i - 1] + 1e-6;
            }
        }
    }
    let (actuation, task) = train_primitives(&recordings, config.model.basis_functions)
        .map_err(|e| format!("training the primitives: {e}"))?;

    // D_fwd: what the actuators really did and where the end effector was.
    let acts: Vec<[f64; 6]> = samples.iter().map(|s| s.measured).collect();
    let positions: Vec<[f64; 3]> = samples.iter().map(|s| s.position).collect();
    let fit_idx: Vec<usize> = (0..acts.len()).filter(|i| i % 5 != 0).collect();
    let fit_a: Vec<_> = fit_idx.iter().map(|&i| acts[i]).collect();
    let fit_p: Vec<_> = fit_idx.iter().map(|&i| positions[i]).collect();
    let held = RbfNetwork::fit(&fit_a, &fit_p, &config.forward_model).map_err(|e| e.to_string())?;
    let errs: Vec<f64> = (0..acts.len())
        .step_by(5)
        .map(|i| {
            let y = held.position(&acts[i]);
            (0..3)
                .map(|d| (y[d] - positions[i][d]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .collect();
    let forward_error_m = (
        errs.iter().sum::<f64>() / errs.len() as f64,
        errs.iter().cloned().fold(0.0, f64::max),
    );
    let forward =
        RbfNetwork::fit(&acts, &positions, &config.forward_model).map_err(|e| e.to_string())?;

    let mut learner = CaclaMtl::new(config.learner)?;
    learner.imitate(&positions, &acts, 3);
    let budget = Duration::from_secs_f64(config.pretrain.budget_s);
    let progress = bar(budget.as_secs(), "pre-training s");
    let start = Instant::now();
    let report = pretrain(&mut learner, &forward, &positions, &config.pretrain, |_| {
        progress.set_position(start.elapsed().as_secs());
        start.elapsed() < budget
    });
    progress.finish_and_clear();
    let pretrain_s = start.elapsed().as_secs_f64();

    let model = Model {
        actuation,
        task,
        forward,
        learner: learner.state(),
        demo_duration_s: config.demonstrations.duration_s,
        id: String::new(),
    };
    let model_id = model
        .write(&config.model_dir())
        .map_err(|e| e.to_string())?;
    Ok(TrainReport {
        demos,
        samples: samples.len(),
        demonstrate_s,
        forward_error_m,
        pretrain_s,
        pretrain_updates: report.updates,
        model_id,
    })
}
