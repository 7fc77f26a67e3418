//! End to end: `softarm-rig bench --json` on short settings. Every section is there with samples
//! and ordered, finite percentiles, and the throwaway stack is gone afterwards. Timing values
//! are never asserted: they are whatever the machine gives.

use std::io::Read;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
use softarm_test_support::Guard;

/// The test rig's binary: bench is its command.
const RIG: &str = env!("CARGO_BIN_EXE_softarm-rig");

/// Runs `softarm-rig <args>` to completion (killed and failed after `limit`); its stdout, and the
/// exited process, whose group is killed when dropped: after the check that nothing is left.
fn run(args: &[&str], limit: Duration) -> (String, Guard) {
    let mut child = Guard::spawn(
        Command::new(RIG)
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped()),
    );
    let mut stdout = child.stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        stdout.read_to_string(&mut s).unwrap();
        s
    });
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "softarm-rig {args:?} did not finish within {} s",
                limit.as_secs()
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let out = reader.join().unwrap();
    assert!(status.success(), "softarm-rig {args:?}: {status}\n{out}");
    (out, child)
}

/// A percentile summary: samples, and min ≤ p50 ≤ p99 ≤ p99.9 ≤ max, all whole ns.
fn check_stats(doc: &Value, path: &str) {
    let s = doc
        .pointer(path)
        .unwrap_or_else(|| panic!("no {path} in {doc}"));
    let get = |k: &str| {
        s[k].as_u64()
            .unwrap_or_else(|| panic!("{path}/{k} is not a count of ns: {s}"))
    };
    assert!(get("n") > 0, "{path}: no samples: {s}");
    let v = ["min_ns", "p50_ns", "p99_ns", "p999_ns", "max_ns"].map(get);
    assert!(v.windows(2).all(|w| w[0] <= w[1]), "{path}: {s}");
}

/// The processes of the bench's stack (their command lines name its run folder).
fn leftovers(pid: u32) -> Vec<String> {
    // The stack's run with /tmp/softarm-bench-<pid>/softarm.toml, the peer in softarm/bench-<pid>.
    let marks = [format!("bench-{pid}/"), format!("bench-{pid} ")];
    std::fs::read_dir("/proc")
        .unwrap()
        .flatten()
        .filter_map(|e| std::fs::read(e.path().join("cmdline")).ok())
        .map(|c| String::from_utf8_lossy(&c).replace('\0', " "))
        .filter(|c| marks.iter().any(|m| c.contains(m)))
        .collect()
}

#[test]
fn bench_json_has_every_section() {
    let (out, bench) = run(
        &[
            "bench",
            "--json",
            "--seconds",
            "2",
            "--ticks",
            "2000",
            "--reconditions",
            "5",
            "--samples",
            "300",
        ],
        Duration::from_secs(240),
    );
    let doc: Value = serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("{e}: {out}"));

    let m = &doc["machine"];
    assert!(m["cores"].as_u64().unwrap() > 0, "{m}");
    for k in ["cpu", "kernel"] {
        assert!(!m[k].as_str().unwrap().is_empty(), "{m}");
    }

    for path in [
        "/wakeup/controller",
        "/wakeup/bare",
        "/ipc/iceoryx2_poll",
        "/ipc/iceoryx2_event",
        "/ipc/unix_socket",
        "/end_to_end/tracker_to_driver",
        "/end_to_end/setpoint_to_driver",
        "/calls/eq11_tick",
        "/calls/recondition",
        "/calls/eq11_tick_d9",
        "/calls/recondition_d9",
        "/calls/eq11_tick_d16",
        "/calls/recondition_d16",
        "/calls/cacla_update",
        "/calls/pcc_forward",
        "/calls/rbf_forward",
        "/calls/poly_forward",
    ] {
        check_stats(&doc, path);
    }
    let w = &doc["wakeup"];
    assert!(
        w["controller"]["overruns"].is_u64() && w["bare"]["overruns"].is_u64(),
        "{w}"
    );
    for k in ["min", "p50", "p99", "p999", "max"] {
        let r = w["ratio"][k].as_f64().unwrap();
        assert!(r.is_finite() && r >= 0.0, "ratio {k}: {w}");
    }
    let window = w["window_s"].as_f64().unwrap();
    assert!(window.is_finite() && window > 0.0, "{w}");
    for role in ["sim", "controller", "learner", "bench"] {
        assert!(
            doc["rss_kib"][role].as_u64().unwrap() > 0,
            "{}",
            doc["rss_kib"]
        );
    }

    // The stack and the peer are gone, and so is the run folder.
    let pid = bench.id();
    assert!(leftovers(pid).is_empty(), "{:?}", leftovers(pid));
    assert!(
        !std::env::temp_dir()
            .join(format!("softarm-bench-{pid}"))
            .exists()
    );
}

#[test]
fn the_bare_loop_alone_still_runs() {
    let (out, _) = run(
        &["bench", "--wakeup", "0.2", "--rate-hz", "1000", "--json"],
        Duration::from_secs(60),
    );
    let doc: Value = serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("{e}: {out}"));
    check_stats(&doc, "/bare");
    assert!(doc["bare"]["overruns"].is_u64(), "{doc}");
}
