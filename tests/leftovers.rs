//! End to end: a process killed with SIGKILL and started again, 50 times in a row. Every start
//! succeeds (no port limit reached by the dead ones' leftovers), and nothing piles up in shared
//! memory or under the iceoryx2 root: each start cleans up after the dead. The processes run
//! with an iceoryx2 config of their own (`config/iceoryx2.toml` in their working folder: a root
//! path and a file prefix), so the count sees their files only, whatever else runs.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::Stdio;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use softarm_test_support::{Guard, TestStack};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
const RESTARTS: usize = 50;

/// Files of this iceoryx2 instance: in /dev/shm by prefix, and everything under its root.
fn files(prefix: &str, root: &Path) -> usize {
    let shm = std::fs::read_dir("/dev/shm")
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with(prefix))
        .count();
    fn walk(p: &Path) -> usize {
        std::fs::read_dir(p).map_or(0, |d| {
            d.flatten()
                .map(|e| {
                    let p = e.path();
                    if p.is_dir() { walk(&p) } else { 1 }
                })
                .sum()
        })
    }
    shm + walk(root)
}

/// Starts `softarm <role>` in `dir` and waits until it says `ready` on stderr; killed when
/// dropped, so a failing test leaves it behind neither.
fn start(s: &TestStack, dir: &Path, role: &str, ready: &str) -> Guard {
    let mut child = Guard::spawn(
        s.command()
            .arg(role)
            .arg("--config")
            .arg(&s.config)
            .current_dir(dir)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped()),
    );
    let err = child.stderr.take().unwrap();
    let (tx, rx) = mpsc::channel();
    let ready = ready.to_string();
    std::thread::spawn(move || {
        let mut log = String::new();
        for line in BufReader::new(err).lines().map_while(Result::ok) {
            log += &line;
            log.push('\n');
            if line.contains(&ready) {
                let _ = tx.send(Ok(()));
            }
        }
        let _ = tx.send(Err(log));
    });
    // Bounded by the work it does, not the wall clock: on a loaded machine a start that cleans
    // up after fifty dead predecessors took over 30 s of wall clock. 20 s of its own CPU time
    // without being ready is a process that is stuck; the wall-clock bound only catches one
    // that waits for ever.
    let started = Instant::now();
    loop {
        match rx.recv_timeout(Duration::from_millis(200)) {
            Ok(Ok(())) => return child,
            Ok(Err(log)) => panic!("{role} ended before it was ready:\n{log}"),
            Err(_) => {
                let cpu = cpu_s(child.id());
                assert!(
                    cpu < 20.0 && started.elapsed() < Duration::from_secs(300),
                    "{role} not ready after {cpu:.1} s of its CPU time, {:?} in all",
                    started.elapsed()
                );
            }
        }
    }
}

/// The CPU time process `pid` has used (user and system, s), from `/proc/<pid>/stat`.
fn cpu_s(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command name, which is in parentheses and may hold spaces: utime and
    // stime are the 14th and 15th fields of the line, the 12th and 13th after it.
    let after = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
    let ticks: f64 = after
        .split_whitespace()
        .skip(11)
        .take(2)
        .filter_map(|v| v.parse::<f64>().ok())
        .sum();
    ticks
        / nix::unistd::sysconf(nix::unistd::SysconfVar::CLK_TCK)
            .ok()
            .flatten()
            .unwrap_or(100) as f64
}

fn kill9(mut child: Guard) {
    kill(Pid::from_raw(child.id() as i32), Signal::SIGKILL).unwrap();
    child.wait().unwrap();
}

#[test]
fn fifty_kills_leave_nothing_behind() {
    let s = TestStack::new(BIN, "leftovers", false);
    let dir = s.dir.join("run");
    let root = s.dir.join("iox2-root");
    let prefix = format!("sfleft{}_", std::process::id());
    std::fs::create_dir_all(dir.join("config")).unwrap();
    std::fs::write(
        dir.join("config/iceoryx2.toml"),
        format!(
            "[global]\nroot-path = \"{}/\"\nprefix = \"{prefix}\"\n",
            root.display()
        ),
    )
    .unwrap();

    // The sim and the learner: publishers and subscribers of several services each.
    let sim = start(&s, &dir, "sim", "sim running");
    let learner = start(&s, &dir, "learner", "waiting for `softarm train`");
    let alive = files(&prefix, &root);
    assert!(alive > 5, "only {alive} files: the config was not used?");
    kill9(learner);
    for _ in 0..RESTARTS {
        kill9(start(&s, &dir, "learner", "waiting for `softarm train`"));
    }
    kill9(sim);
    for _ in 0..RESTARTS {
        kill9(start(&s, &dir, "sim", "sim running"));
    }
    // The same two running again: the same files as at the start.
    let sim = start(&s, &dir, "sim", "sim running");
    let learner = start(&s, &dir, "learner", "waiting for `softarm train`");
    let again = files(&prefix, &root);
    kill9(sim);
    kill9(learner);
    eprintln!("{alive} files with a sim and a learner alive; {again} after {RESTARTS} kills each");
    assert_eq!(
        again, alive,
        "after {RESTARTS} kills each: {again} files, with the same processes alive {alive}"
    );
    // Cleaned by the next start: the dead nodes' files go.
    let sim = start(&s, &dir, "sim", "sim running");
    let _ = kill(Pid::from_raw(sim.id() as i32), Signal::SIGTERM);
    let mut sim = sim;
    sim.wait().unwrap();
    let _ = std::fs::remove_dir_all(&root);
    for e in std::fs::read_dir("/dev/shm").unwrap().flatten() {
        if e.file_name().to_string_lossy().starts_with(&prefix) {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// What bounds a start above: the CPU time a process used, read back for this one as it
/// spins (however busy the machine: the spin goes on until the count has moved).
#[test]
fn a_process_cpu_time_is_read_from_proc() {
    let (pid, start) = (std::process::id(), Instant::now());
    let before = cpu_s(pid);
    let mut x = 0u64;
    while cpu_s(pid) < before + 0.2 {
        for _ in 0..1_000_000 {
            x = std::hint::black_box(x.wrapping_add(1));
        }
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "the CPU time read stays at {before} s ({x})"
        );
    }
}
