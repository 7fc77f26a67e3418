//! `softarm train` SIGKILLed through a running stack, at seeded moments of its demonstrations
//! and its training, and at the moments of its bundle write: when the tensors file's temporary
//! appears, when the new tensors file is in place but the metadata not yet, and when the
//! metadata's temporary appears (found by polling the model folder every 0.2 ms for the
//! names `bundle::write` gives them; a kill that left the temporary behind was surely in the
//! middle of writing it). After each kill the folder reads back (`Model::read`) as the bundle
//! it held before or a complete new one, never a mix: the forward model's centres (a tensor)
//! and the demonstration duration (metadata) agree on which training made it. A complete
//! train in the middle and one at the end write readable new bundles, and the temporaries the
//! killed writers left are gone after them.
//! A failure names the seed; SOFTARM_FAULT_SEED=N reruns that sequence.

use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use rand::seq::SliceRandom;
use rand::{RngExt, SeedableRng};
use softarm_model::bundle::Model;
use softarm_test_support::{FaultSeed, Guard, TestStack, config_text, with_overrides};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

/// The trainings this test runs: the fewest and shortest demonstrations the config allows (two
/// per class of 0.5 s, after 0.5 s rests), a forward model of this many centres (the quick
/// model of the harness has 80), and 0.3 s of pre-training: about 6 s per train.
const CENTRES: usize = 100;
const DEMO_S: f64 = 0.5;

/// When a train is killed.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Kill {
    /// Not: it runs to its end.
    Never,
    /// This long after it started (demonstrations, fits, pre-training or the write).
    After(Duration),
    /// As soon as the temporary of its tensors file appears.
    TensorsTemporary,
    /// As soon as its new tensors file is in place (the metadata still the old).
    TensorsInPlace,
    /// As soon as the temporary of its metadata appears.
    MetadataTemporary,
}

fn names(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().to_string())
                .collect()
        })
        .unwrap_or_default()
}

fn temporaries(dir: &Path) -> Vec<String> {
    names(dir)
        .into_iter()
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

fn tensors_files(dir: &Path) -> Vec<String> {
    names(dir)
        .into_iter()
        .filter(|n| n.starts_with("model-") && n.ends_with(".safetensors"))
        .collect()
}

/// Which training made the bundle, checked whole: the quick model (`None`) or a train of this
/// test (`Some(id)`); a panic for anything else, e.g. one training's metadata over another's
/// tensors.
fn made_by(m: &Model<6>, quick: &Model<6>, seed: u64, when: &str) -> Option<String> {
    let centres = m.forward.centres();
    if m.id == quick.id {
        assert_eq!(
            (centres, m.demo_duration_s),
            (quick.forward.centres(), quick.demo_duration_s),
            "seed {seed}, {when}: the quick model's id over other contents"
        );
        None
    } else {
        assert_eq!(
            (centres, m.demo_duration_s),
            (CENTRES, DEMO_S),
            "seed {seed}, {when}: bundle {} mixes trainings",
            m.id
        );
        Some(m.id.clone())
    }
}

/// Runs `softarm train --seed train_seed` and kills it as `how` says: (whether it exited by
/// itself, the temporaries its pid left behind).
fn train(s: &TestStack, train_seed: u64, how: Kill, model: &Path) -> (bool, Vec<String>) {
    let log = std::fs::File::create(s.dir.join(format!("train-{train_seed}.log"))).unwrap();
    let mut child = Guard::spawn(
        s.command()
            .args(["train", "--seed", &train_seed.to_string(), "--config"])
            .arg(&s.config)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(log),
    );
    let pid = child.id();
    let ours = format!(".{pid}.tmp");
    let before: Vec<String> = tensors_files(model);
    let start = Instant::now();
    let log_path = s.dir.join(format!("train-{train_seed}.log"));
    // A train says each step it starts (the demonstrations with its own deadline, the fits,
    // the pre-training, the write): one that says nothing new for 60 s is stuck where its
    // last line says, however slow the machine is otherwise.
    let mut said = (0, Instant::now());
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let log = std::fs::read_to_string(s.dir.join(format!("train-{train_seed}.log")));
            assert!(
                status.success(),
                "train {train_seed} ({how:?}) failed: {status}: {log:?}"
            );
            return (true, Vec::new());
        }
        let now = names(model);
        let due = match how {
            Kill::Never => false,
            Kill::After(d) => start.elapsed() >= d,
            Kill::TensorsTemporary => now
                .iter()
                .any(|n| n.starts_with(".model-") && n.ends_with(&ours)),
            Kill::TensorsInPlace => now.iter().any(|n| {
                n.starts_with("model-") && n.ends_with(".safetensors") && !before.contains(n)
            }),
            Kill::MetadataTemporary => now
                .iter()
                .any(|n| n.starts_with(".model.toml.") && n.ends_with(&ours)),
        };
        if due {
            kill(Pid::from_raw(pid as i32), Signal::SIGKILL).unwrap();
            child.wait().unwrap();
            let left = temporaries(model)
                .into_iter()
                .filter(|n| n.ends_with(&ours))
                .collect();
            return (false, left);
        }
        let log = std::fs::read_to_string(&log_path).unwrap_or_default();
        if log.len() != said.0 {
            said = (log.len(), Instant::now());
        }
        assert!(
            said.1.elapsed() < Duration::from_secs(60),
            "train {train_seed} ({how:?}) said nothing new for 60 s ({:.0} s in all): {log}",
            start.elapsed().as_secs_f64()
        );
        std::thread::sleep(Duration::from_micros(200));
    }
}

#[test]
fn train_killed_anywhere_leaves_a_whole_bundle_old_or_new() {
    let said = FaultSeed::from_env(3);
    let seed = said.0;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let started = Instant::now();
    let mut s = TestStack::with_config(BIN, "train-kill", true, |dir, ns| {
        with_overrides(
            &config_text(dir, ns),
            &[
                ("demonstrations.demos_per_class", 2.into()),
                ("demonstrations.duration_s", DEMO_S.into()),
                ("controller.rest_s", 0.5.into()),
                ("forward_model.centres", (CENTRES as i64).into()),
                ("pretrain.budget_s", 0.3.into()),
            ],
        )
    });
    let model = s.dir.join("model");
    s.up();
    let quick = Model::<6>::read(&model).unwrap();

    // Kills at seeded moments (over the ~6 s a train takes), and at each step of the write, in
    // a seeded order; a complete train somewhere among them, and one at the end.
    let mut plan = vec![
        Kill::After(Duration::from_millis(rng.random_range(200..6000))),
        Kill::After(Duration::from_millis(rng.random_range(200..6000))),
        Kill::TensorsTemporary,
        Kill::TensorsInPlace,
        Kill::MetadataTemporary,
    ];
    plan.shuffle(&mut rng);
    plan.insert(rng.random_range(1..plan.len()), Kill::Never);
    plan.push(Kill::Never);

    // The bundle in the folder before each train, by id (`None`: the quick model).
    let mut current: Option<String> = None;
    let mut mid_write = Vec::new();
    let mut left_since_complete = 0;
    let mut retries = 0;
    let mut round = 0;
    while round < plan.len() {
        let how = plan[round];
        s.wait_status("the controller IDLE", Duration::from_secs(30), |st| {
            st["controller"]["state"] == "IDLE"
        });
        let train_seed = 100 + round as u64 + 10 * retries;
        let (finished, left) = train(&s, train_seed, how, &model);
        let when = format!("round {round}, {how:?}");
        let m = Model::<6>::read(&model)
            .unwrap_or_else(|e| panic!("seed {seed}, {when}: the folder does not read: {e}"));
        let now = made_by(&m, &quick, seed, &when);
        eprintln!(
            "round {round} (seed {seed}): {how:?}: {}, left {left:?}; the folder holds {} \
             ({} tensors files)",
            if finished { "finished" } else { "killed" },
            now.as_deref().unwrap_or("the quick model"),
            tensors_files(&model).len()
        );
        if finished {
            assert!(
                now.is_some() && now != current,
                "seed {seed}, {when}: a complete train wrote no new bundle"
            );
            // The killed writers' temporaries and the old tensors are gone.
            assert_eq!(temporaries(&model), Vec::<String>::new(), "seed {seed}");
            assert_eq!(tensors_files(&model).len(), 1, "seed {seed}");
            left_since_complete = 0;
        } else {
            // The old bundle or a complete new one (`made_by` checked it whole).
            assert!(
                now == current || now.is_some(),
                "seed {seed}, {when}: back to an older bundle"
            );
            // Each killed writer leaves at most its one temporary.
            assert!(left.len() <= 1, "seed {seed}, {when}: {left:?}");
            left_since_complete += left.len();
            let temporaries = temporaries(&model).len();
            if now != current {
                // Its bundle got in place before the kill landed (on a loaded machine the kill
                // can come that late): its clean-up of earlier writers' temporaries may have
                // run too, but nothing may have been added.
                assert!(
                    temporaries <= left_since_complete,
                    "seed {seed}, {when}: {temporaries} temporaries"
                );
                left_since_complete = temporaries;
            } else {
                assert_eq!(temporaries, left_since_complete, "seed {seed}, {when}");
            }
            let at_write = matches!(how, Kill::TensorsTemporary | Kill::MetadataTemporary);
            if at_write && !left.is_empty() {
                mid_write.push(how);
            } else if at_write && retries < 3 {
                // The write was done before the kill landed: again, once more.
                retries += 1;
                plan.insert(round + 1, how);
            }
        }
        current = now;
        round += 1;
    }
    let elapsed = started.elapsed();
    s.stop();
    eprintln!(
        "seed {seed}: {} trains, killed mid-write at {mid_write:?}, {:.1} s",
        plan.len(),
        elapsed.as_secs_f64()
    );
    assert!(
        mid_write.contains(&Kill::TensorsTemporary) || mid_write.contains(&Kill::MetadataTemporary),
        "seed {seed}: no kill landed in the middle of a write"
    );
}

/// `softarm train` asked to stop (SIGTERM, as systemd or Ctrl-C asks) during its
/// demonstrations ends at its next step, says so, and writes nothing: the folder keeps the
/// bundle it had, and no temporary of its is left.
#[test]
fn train_asked_to_stop_ends_writing_nothing() {
    let mut s = TestStack::new(BIN, "train-stop", true);
    let model = s.dir.join("model");
    s.up();
    let quick = Model::<6>::read(&model).unwrap();
    let log_path = s.dir.join("train-stop.log");
    let mut child = Guard::spawn(
        s.command()
            .args(["train", "--config"])
            .arg(&s.config)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log_path).unwrap()),
    );
    // The shipped demonstrations take minutes: asked to stop once they are under way.
    let start = Instant::now();
    while !std::fs::read_to_string(&log_path)
        .unwrap_or_default()
        .contains("recording")
    {
        assert!(
            child.try_wait().unwrap().is_none(),
            "train ended before recording"
        );
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "train never began recording"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    kill(Pid::from_raw(child.id() as i32), Signal::SIGTERM).unwrap();
    let status = child.wait().unwrap();
    let log = std::fs::read_to_string(&log_path).unwrap();
    assert_eq!(status.code(), Some(1), "{status}: {log}");
    assert!(
        log.contains("stopped during the demonstrations; nothing was written"),
        "{log}"
    );
    assert_eq!(Model::<6>::read(&model).unwrap().id, quick.id);
    assert!(temporaries(&model).is_empty(), "{:?}", names(&model));
}
