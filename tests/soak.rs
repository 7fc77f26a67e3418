//! `softarm-rig soak`, short: the whole sim stack with continuous executions, a scenario change and
//! random kills, its report read back. The ten-minute figures are in the README; this checks
//! that the machinery runs and reports what happened. (On the real arm's code path, the tendon
//! and tracker drivers against `softarm-rig emulate`: `hardware_faults`.)

use std::process::Command;

use softarm_test_support::{output, quick_model};

/// The test rig's binary: soak is its command.
const RIG: &str = env!("CARGO_BIN_EXE_softarm-rig");

#[test]
fn a_short_soak_survives_its_kills_and_reports_everything() {
    let dir = std::env::temp_dir().join(format!("softarm-test-soak-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let model = dir.join("model");
    quick_model(&model);
    // First an arm that changes while it runs: its step comes 1 s into the sim's clock.
    let swap = dir.join("swap.toml");
    std::fs::write(&swap, "[[step]]\nat_s = 1.0\n[step.arm]\ntool_m = 0.05\n").unwrap();
    let rotation = format!("{},creep", swap.display());
    let out = output(
        Command::new(RIG)
            .args(["soak", "--minutes", "1", "--kill-every-s", "12"])
            .args(["--scenario-every-s", "10", "--seed", "3", "--json"])
            // What the checks below count, however slow the machine: 3 executions, one after
            // the last change of the arm (a minute of a loaded machine got through one change
            // only).
            .args(["--at-least-executions", "3"])
            .args(["--scenarios", &rotation])
            .arg("--model-dir")
            .arg(&model)
            .env("TMPDIR", &dir),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    // Nothing of the soak's own left behind: only the model is in its temporary folder.
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.file_name())
        .filter(|n| n != "model" && n != "swap.toml")
        .collect();
    let _ = std::fs::remove_dir_all(&dir);
    let r: serde_json::Value = serde_json::from_str(stdout.trim())
        .unwrap_or_else(|e| panic!("{e}: stdout {stdout:?}\nstderr {stderr}"));
    let ctx = format!("{r:#}\nstderr:\n{stderr}");
    assert!(out.status.success(), "{ctx}");
    assert_eq!(r["failures"].as_array().unwrap().len(), 0, "{ctx}");
    assert_eq!(r["invariants"]["violations"], 0, "{ctx}");
    // A minute at 500 Hz, less what kills and restarts cost.
    assert!(
        r["invariants"]["setpoints"].as_u64().unwrap() > 5000,
        "{ctx}"
    );
    assert!(r["executions"].as_u64().unwrap() >= 3, "{ctx}");
    let kills: u64 = r["kills"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k[1].as_u64().unwrap())
        .sum();
    assert!(kills >= 2, "{ctx}");
    assert!(r["kills_survived"].as_u64().unwrap() >= 1, "{ctx}");
    assert!(r["scenario_changes"].as_u64().unwrap() >= 1, "{ctx}");
    // Every arm change is there, the scenario's step among them, with the executions after it.
    let changes = r["arm_changes"].as_array().unwrap();
    let arms: Vec<&str> = changes.iter().map(|c| c["arm"].as_str().unwrap()).collect();
    assert_eq!(arms[0], "swap", "{ctx}");
    assert!(arms.contains(&"swap step 1"), "{ctx}");
    let counted: u64 = changes
        .iter()
        .map(|c| c["executions"].as_u64().unwrap())
        .sum();
    assert!(
        counted >= 1 && counted <= r["executions"].as_u64().unwrap(),
        "{ctx}"
    );
    for c in changes {
        let back = c["back_under"].as_u64();
        assert!(
            back.is_none_or(|n| n >= 1 && n <= c["executions"].as_u64().unwrap()),
            "{ctx}"
        );
    }
    for (role, rss) in r["rss"].as_array().unwrap().iter().map(|x| (&x[0], &x[1])) {
        assert!(rss["start_kib"].as_u64().unwrap() > 1000, "{role}: {ctx}");
        assert!(rss["peak_kib"].as_u64() >= rss["end_kib"].as_u64(), "{ctx}");
    }
    assert!(r["tick"]["samples"].as_u64().unwrap() > 0, "{ctx}");
    assert!(r["lattice_end"][1].as_u64().unwrap() > 0, "{ctx}");
    assert!(left.is_empty(), "left behind: {left:?}");
}

#[test]
fn a_soak_of_no_time_or_a_kill_every_instant_is_refused() {
    for (args, want) in [
        (&["--minutes", "0"][..], "--minutes"),
        (&["--minutes", "nan"][..], "--minutes"),
        (
            &["--minutes", "1", "--kill-every-s", "0.1"][..],
            "--kill-every-s",
        ),
        (
            &["--minutes", "1", "--scenario-every-s", "-3"][..],
            "--scenario-every-s",
        ),
    ] {
        let out = output(Command::new(RIG).arg("soak").args(args));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {err}");
    }
}
