//! End to end: the real `softarm` binary as separate processes over real iceoryx2 services, one
//! namespace per test.

use std::path::Path;
use std::time::Duration;

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use softarm_test_support::{DEMO_WAYPOINTS, TestStack, alive, eventually, output, set_id};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

#[test]
fn a_set_is_executed_and_stats_arrive_for_every_execution() {
    let mut s = TestStack::new(BIN, "execute", true);
    s.up();
    // Before any execution: an answer, not silence (text), and a valid empty one (JSON).
    let none = s.run(&["stats"]);
    let text = String::from_utf8_lossy(&none.stdout);
    assert!(
        none.status.success() && text.starts_with("no executions yet in namespace"),
        "{text}"
    );
    let none = s.run(&["stats", "--json"]);
    let json: serde_json::Value = serde_json::from_slice(&none.stdout).unwrap();
    assert_eq!(json, serde_json::json!([]));
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 2);
    assert_eq!(code, 0, "{out}{err}");
    let id = set_id(&out);
    let stats = s.wait_stats(id, 2, Duration::from_secs(60));
    let executions: Vec<u64> = stats
        .iter()
        .map(|v| v["execution"].as_u64().unwrap())
        .collect();
    assert_eq!(executions, vec![1, 2]);
    let text = String::from_utf8_lossy(&s.run(&["stats"]).stdout).to_string();
    assert!(
        text.starts_with(" exec") && !text.contains("no executions"),
        "{text}"
    );
    for v in &stats {
        let errors = v["errors_mm"].as_array().unwrap();
        assert_eq!(errors.len(), 5, "{v}");
        let mean = v["mean_mm"].as_f64().unwrap();
        let max = v["max_mm"].as_f64().unwrap();
        assert!(mean.is_finite() && mean > 0.0 && mean < 100.0, "{v}");
        assert!(
            errors.iter().all(|e| e.as_f64().unwrap() <= max + 1e-9),
            "{v}"
        );
    }
    // The learner answered the set's request for first estimates.
    assert!(s.logs().contains("first estimates sent"), "{}", s.logs());
    // The learner checkpoints after each execution: after the stats are out, so on a loaded
    // machine the file may come a moment later.
    let checkpoint = s.dir.join("state/learner.toml");
    eventually("the learner's checkpoint", Duration::from_secs(30), || {
        checkpoint.exists().then_some(())
    });
    // Status names every process and reports tick timing.
    let st = s.status();
    for p in ["controller", "learner", "sim"] {
        assert!(
            st["alive"].as_array().unwrap().iter().any(|a| a == p),
            "{st}"
        );
    }
    assert!(
        st["controller"]["latency_ns"]["p99"].as_u64().unwrap() > 0,
        "{st}"
    );
    // Execution 2 applied the learner's estimates (one comes per conditioning sample), and
    // status reports the last completed execution's count; no conditioning sample was lost.
    let applied = stats[1]["reconditions"].as_u64().unwrap();
    assert!(applied >= 1, "{}", stats[1]);
    let st = s.wait_status(
        "the last execution's re-conditionings",
        Duration::from_secs(10),
        |st| st["controller"]["reconditions"]["last"] == applied,
    );
    assert_eq!(st["controller"]["outbox"]["samples_dropped"], 0, "{st}");
}

#[test]
fn an_invalid_set_is_rejected_with_its_reason_and_the_running_one_goes_on() {
    let mut s = TestStack::new(BIN, "reject", true);
    s.up();
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 3);
    assert_eq!(code, 0, "{out}{err}");
    let id = set_id(&out);

    // Refused before it is sent.
    let bad = s.dir.join("late.toml");
    std::fs::write(&bad, "duration_s = 2.0\n[[point]]\nt_s = 1.0\nposition_m = [0.1, 0.0, -0.45]\n[[point]]\nt_s = 3.0\nposition_m = [0.0, 0.0, -0.5]\n").unwrap();
    let (code, out, _) = s.submit(&bad, 1);
    assert_eq!(code, 2, "{out}");
    assert!(
        out.contains("point 2: time 3 s is outside (0, 2] s"),
        "{out}"
    );

    // Refused by the controller: this client's config allows a bigger workspace than the stack's.
    let wide = s.dir.join("wide.toml");
    let text = std::fs::read_to_string(&s.config).unwrap().replace(
        "workspace_max_m = [0.45, 0.45, 0.05]",
        "workspace_max_m = [0.45, 0.45, 0.5]",
    );
    std::fs::write(&wide, text).unwrap();
    let far = s.dir.join("far.toml");
    std::fs::write(
        &far,
        "duration_s = 2.0\n[[point]]\nt_s = 1.0\nposition_m = [0.0, 0.0, 0.3]\n",
    )
    .unwrap();
    let out = output(s.command().args([
        "submit",
        far.to_str().unwrap(),
        "--config",
        wide.to_str().unwrap(),
    ]));
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(2), "{text}");
    assert!(
        text.contains("point 1: position") && text.contains("outside the workspace box"),
        "{text}"
    );

    // The first set runs on, all three executions.
    let stats = s.wait_stats(id, 3, Duration::from_secs(90));
    let executions: Vec<u64> = stats
        .iter()
        .map(|v| v["execution"].as_u64().unwrap())
        .collect();
    assert_eq!(executions, vec![1, 2, 3]);
}

#[test]
fn submit_without_a_stack_says_what_to_do() {
    let s = TestStack::new(BIN, "nostack", false);
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 1);
    assert_eq!(code, 1, "{out}{err}");
    assert!(
        err.contains("softarm up") && err.contains(&s.namespace),
        "{err}"
    );
}

#[test]
fn stopping_up_leaves_no_process_behind() {
    let mut s = TestStack::new(BIN, "stop", false);
    s.up();
    let children = s.children();
    let roles: Vec<&str> = children.iter().map(|c| c.0.as_str()).collect();
    assert_eq!(roles, vec!["controller", "learner", "sim"], "{children:?}");
    let out = s.run(&["status"]);
    assert_eq!(out.status.code(), Some(0), "running: {out:?}");
    let status = s.stop().unwrap();
    assert!(status.success(), "{status:?}");
    for (role, pid) in children {
        assert!(!alive(pid), "{role} ({pid}) survived");
    }
    // As `systemctl status` does: not running, exit code 3, for scripts and health checks.
    let out = s.run(&["status"]);
    assert_eq!(out.status.code(), Some(3), "stopped: {out:?}");
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("controller: not running"),
        "{out:?}"
    );
}

#[test]
fn a_killed_process_is_noticed_and_restarted() {
    let mut s = TestStack::new(BIN, "restart", true);
    s.up();
    let (_, learner) = s.children().into_iter().find(|c| c.0 == "learner").unwrap();
    kill(Pid::from_raw(learner), Signal::SIGKILL).unwrap();
    // The dead node leaves the node list, and `up` brings a new learner.
    s.wait_status("the new learner", Duration::from_secs(30), |st| {
        st["alive"]
            .as_array()
            .is_some_and(|a| a.iter().any(|n| n == "learner"))
    });
    let (_, again) = s.children().into_iter().find(|c| c.0 == "learner").unwrap();
    assert_ne!(again, learner);
    assert!(s.logs().contains("learner exited"), "{}", s.logs());
    // And the stack works.
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 1);
    assert_eq!(code, 0, "{out}{err}");
    s.wait_stats(set_id(&out), 1, Duration::from_secs(60));
}

#[test]
fn stale_tracker_data_holds_and_estop_stops() {
    let mut s = TestStack::new(BIN, "safety", false);
    s.up();
    let (_, sim) = s.children().into_iter().find(|c| c.0 == "sim").unwrap();
    // A frozen driver: no tracker data, so HOLD; it resumes when the data returns.
    kill(Pid::from_raw(sim), Signal::SIGSTOP).unwrap();
    s.wait_status("HOLD", Duration::from_secs(10), |st| {
        st["controller"]["state"] == "HOLD"
    });
    kill(Pid::from_raw(sim), Signal::SIGCONT).unwrap();
    s.wait_status("IDLE again", Duration::from_secs(10), |st| {
        st["controller"]["state"] == "IDLE"
    });

    let out = s.run(&["estop"]);
    assert!(out.status.success(), "{out:?}");
    s.wait_status("STOPPED", Duration::from_secs(10), |st| {
        st["controller"]["state"] == "STOPPED"
    });
    // Latched: still stopped a moment later, with no one holding the button.
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(s.status()["controller"]["state"], "STOPPED");
    let out = s.run(&["estop", "--reset"]);
    assert!(out.status.success(), "{out:?}");
    s.wait_status("IDLE after reset", Duration::from_secs(10), |st| {
        st["controller"]["state"] == "IDLE"
    });
}

#[test]
fn train_writes_a_bundle_through_the_running_stack() {
    let mut s = TestStack::new(BIN, "train", false);
    s.up();
    // Without a model the controller says what to do.
    let (code, out, _) = s.submit(Path::new(DEMO_WAYPOINTS), 1);
    assert_eq!(code, 2, "{out}");
    assert!(out.contains("softarm train"), "{out}");

    let out = s.run(&["train"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("trained model") && text.contains("9 demonstrations"),
        "{text}"
    );
    assert!(s.dir.join("model/model.toml").exists());
    s.wait_status("the model loaded", Duration::from_secs(10), |st| {
        st["controller"]["model_loaded"] == true
    });
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 1);
    assert_eq!(code, 0, "{out}{err}");
    s.wait_stats(set_id(&out), 1, Duration::from_secs(60));
}

#[test]
fn config_check_names_the_key_and_line() {
    let s = TestStack::new(BIN, "config", false);
    let text = std::fs::read_to_string(&s.config)
        .unwrap()
        .replace("rate_hz = 500.0", "rate_hz = 5000.0");
    let bad = s.dir.join("bad.toml");
    std::fs::write(&bad, &text).unwrap();
    let out = output(s.command().args(["config", "check"]).arg(&bad));
    let err = String::from_utf8_lossy(&out.stderr);
    let line = text
        .lines()
        .position(|l| l.starts_with("rate_hz = 5000.0"))
        .unwrap()
        + 1;
    // EX_CONFIG: the units do not restart a process whose config is refused.
    assert_eq!(out.status.code(), Some(78));
    assert!(
        err.contains(&format!("bad.toml:{line}: controller.rate_hz")),
        "{err}"
    );
    let out = output(s.command().arg("controller").arg("--config").arg(&bad));
    assert_eq!(out.status.code(), Some(78), "{out:?}");
    let out = output(s.command().args(["config", "check"]).arg(&s.config));
    assert!(out.status.success());
}

#[test]
fn a_bad_scenario_is_refused_before_anything_starts() {
    let s = TestStack::new(BIN, "scenario", false);
    let bad = s.dir.join("bad-scenario.toml");
    std::fs::write(&bad, "# a typo\n[arm]\ntool_m = 0.05\ntool_mm = 0.06\n").unwrap();
    for role in ["sim", "up"] {
        let out = output(
            s.command()
                .arg(role)
                .arg("--scenario")
                .arg(&bad)
                .arg("--config")
                .arg(&s.config),
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(78), "{role}: {err}");
        assert!(
            err.contains("bad-scenario.toml:4: arm.tool_mm: unknown key"),
            "{role}: {err}"
        );
    }
    let out = output(
        s.command()
            .args(["sim", "--scenario", "no-such-arm", "--config"])
            .arg(&s.config),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(78), "{err}");
    assert!(err.contains("tool-change"), "names the shipped ones: {err}");
    // Nothing was started: no node of this namespace is alive.
    assert!(
        s.status()["alive"].as_array().is_none_or(|a| a.is_empty()),
        "{}",
        s.status()
    );
}

#[test]
fn shared_memory_is_for_the_owner_only() {
    // iceoryx2 creates the shared memory of every service and its folders without permissions
    // for others, so only the services' user (`softarm` under systemd) reaches the topics.
    let mut s = TestStack::new(BIN, "perms", false);
    s.up();
    let mut checked = 0;
    let shm = std::fs::read_dir("/dev/shm").unwrap();
    let root = std::fs::read_dir("/tmp/iceoryx2").unwrap();
    for entry in shm.chain(root).flatten() {
        let name = entry.file_name().to_string_lossy().to_string();
        if !(name.starts_with("iox2_") || ["nodes", "services"].contains(&name.as_str())) {
            continue;
        }
        // The one exception, iceoryx2's own: a 16-byte counter shared by every iceoryx2 user of
        // the machine, created world-writable (0666) by design. No topic data is in it.
        if name.ends_with(".global_mgmt") {
            continue;
        }
        let Ok(meta) = entry.metadata() else {
            continue; // gone meanwhile (another test's process ended)
        };
        let mode = std::os::unix::fs::PermissionsExt::mode(&meta.permissions());
        assert_eq!(mode & 0o007, 0, "{name}: mode {mode:o}");
        checked += 1;
    }
    assert!(checked > 3, "only {checked} iceoryx2 files found");
}
