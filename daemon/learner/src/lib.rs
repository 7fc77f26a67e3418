//! The learner process: CACLA-MTL at the conditioning points. Each `ConditioningSample` is one
//! visit (Alg. 1) and is answered with the `ActuationEstimate` the controller asked for next.
//! The state is checkpointed atomically after every execution and at exit, and resumed at start
//! when it descends from the current model bundle.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime};

use softarm_ipc::{ActuationEstimate, Contract, Namespace, now_ns};

use softarm_model::bundle::{BundleError, Model, read_checkpoint, write_checkpoint};
use softarm_method::cacla::{Learner, LearnerConfig};
use softarm_model::config::Config;

struct Loaded {
    learner: Learner,
    model_id: String,
}

fn stamp(dir: &Path) -> Option<SystemTime> {
    std::fs::metadata(dir.join("model.toml"))
        .and_then(|m| m.modified())
        .ok()
}

/// The checkpoint if it descends from the bundle in `model_dir`, else the bundle's learner.
fn load(config: &Config) -> Result<Loaded, BundleError> {
    let model_dir = config.model_dir();
    let model = Model::read(&model_dir)?;
    let state = match read_checkpoint(&config.state_dir()) {
        Ok((state, from)) if from == model.id => {
            tracing::info!(dir = %config.state_dir().display(), "resuming from the learner checkpoint");
            state
        }
        Ok(_) => {
            tracing::info!(
                "the checkpoint belongs to an older model: starting from the new bundle"
            );
            model.learner.clone()
        }
        Err(BundleError::Missing { .. }) => model.learner.clone(),
        Err(e) => {
            tracing::error!("{e}; starting from the model bundle instead");
            model.learner.clone()
        }
    };
    let mut state = state;
    state.config = runtime_config(state.config, config.learner);
    let learner = Learner::restore(&state).map_err(|why| BundleError::Invalid {
        path: model_dir.clone(),
        why,
    })?;
    Ok(Loaded {
        learner,
        model_id: model.id,
    })
}

/// Rates, discount and exploration come from the config, so they can be tuned without
/// retraining; the lattices (spacing, span, width, box) are the trained model's own.
fn runtime_config(trained: LearnerConfig, configured: LearnerConfig) -> LearnerConfig {
    let runtime = LearnerConfig {
        alpha_critic: configured.alpha_critic,
        alpha_actor: configured.alpha_actor,
        gamma: configured.gamma,
        sigma_max: configured.sigma_max,
        sigma_mid_m: configured.sigma_mid_m,
        sigma_slope_per_m: configured.sigma_slope_per_m,
        seed: configured.seed,
        ..trained
    };
    if runtime != configured {
        tracing::warn!(
            "the [learner] lattice settings differ from the trained model's; the model's are used              (run `softarm train` to apply the new ones)"
        );
    }
    runtime
}

fn checkpoint(config: &Config, l: &Loaded) {
    if let Err(e) = write_checkpoint(&config.state_dir(), &l.learner.state(), &l.model_id) {
        tracing::error!("checkpoint not written: {e}");
    }
}

/// Runs the learner until `stop` is set.
pub fn run(config: &Config, stop: &AtomicBool) -> Result<(), String> {
    let namespace = Namespace::new(&config.namespace())?;
    let e = |e: softarm_ipc::Error| e.to_string();
    let ipc = Contract::new(namespace, "learner").map_err(e)?;
    let samples = ipc.subscriber(&ipc.cp_sample().map_err(e)?).map_err(e)?;
    let estimates = ipc.publisher(&ipc.estimate().map_err(e)?).map_err(e)?;

    let mut loaded: Option<Loaded> = None;
    // The bundle version last tried, so a bad bundle is reported once, not every look.
    let mut tried: Option<SystemTime> = None;
    let mut warned = false;
    let mut last_check = Instant::now() - Duration::from_secs(10);
    let mut set_id = 0u64;
    let mut seq = 0u64;
    while !stop.load(Ordering::Relaxed) {
        // Estimates are needed within the 100 ms before the next group's window: 2 ms is plenty.
        std::thread::sleep(Duration::from_millis(2));
        // A new bundle (after `softarm train`) replaces what the learner had.
        if last_check.elapsed() >= Duration::from_millis(200) {
            last_check = Instant::now();
            let current = stamp(&config.model_dir());
            if current.is_some() && current != tried {
                tried = current;
                match load(config) {
                    Ok(l) => {
                        tracing::info!(model = %l.model_id, "learner ready");
                        loaded = Some(l);
                        set_id = 0;
                    }
                    Err(e) => tracing::error!("{e}"),
                }
            } else if current.is_none() && !warned {
                warned = true;
                tracing::warn!(
                    "no model bundle in {} yet: waiting for `softarm train`",
                    config.model_dir().display()
                );
            }
        }
        // Without a model, samples wait in the subscriber's buffer until one is loaded.
        let Some(l) = loaded.as_mut() else {
            continue;
        };
        while let Ok(Some(s)) = samples.receive() {
            let s = *s;
            if s.set_id != set_id {
                l.learner.forget_points();
                set_id = s.set_id;
            }
            let executed = s.executed == 1;
            if executed {
                if s.reached.iter().all(|v| v.is_finite()) {
                    let visit =
                        l.learner
                            .observe(s.point as usize, &s.desired, &s.actuation, &s.reached);
                    tracing::debug!(point = s.point, error_mm = visit.error * 1e3, td = ?visit.td_error, "visit");
                } else {
                    tracing::warn!(
                        point = s.point,
                        "no tracker position at the point: visit skipped"
                    );
                }
            }
            // The first execution of a set runs on the actor's means, without exploration.
            let (point, target) = if executed {
                (s.next_point, s.next_desired)
            } else {
                (s.point, s.desired)
            };
            let explore = executed && s.next_execution >= 2;
            let actuation = l.learner.act(point as usize, &target, explore);
            seq += 1;
            let _ = estimates.send_copy(ActuationEstimate {
                seq,
                stamp_ns: now_ns(),
                set_id: s.set_id,
                point,
                _pad: 0,
                actuation,
            });
            if executed && s.point + 1 == s.points {
                checkpoint(config, l);
            }
        }
    }
    if let Some(l) = &loaded {
        checkpoint(config, l);
    }
    tracing::info!("learner stopped");
    Ok(())
}
