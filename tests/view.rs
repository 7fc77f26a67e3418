//! End to end: `softarm view` started by `softarm up` (`[view] enabled = true`), against an
//! independent client of the Foxglove WebSocket protocol (`clients/python/examples/
//! view_client.py`: Python `websockets`, and `protobuf` to decode the scene with the schema the
//! server advertises). It sees every service as a channel with its schema and the scene,
//! subscribes, gets messages that decode to what `softarm stats` and `softarm status` say, and
//! scene updates whose arm ends where the sim's tracker says, sample for sample; it is refused
//! when it tries to publish or set parameters. A client that reads nothing for 20 s loses
//! messages rather than stalling the stack or growing the view. The client offers the
//! subprotocol the protocol documents, `foxglove.websocket.v1`, which the view's door renames
//! for the `foxglove` crate's server; one offering the crate's name gets it, one offering
//! neither gets HTTP 400.
//!
//! Without `python3` with `websockets` and `protobuf`, a test says "not run" and passes, unless
//! `SOFTARM_REQUIRE_PYTHON=1` (CI).

use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use serde_json::Value;
use softarm_clients::stats;
use softarm_ipc::ControllerState;
use softarm_stack::supervisor::rss_kib;
use softarm_test_support::{
    DEMO_WAYPOINTS, Guard, TestStack, config_text, eventually, output, set_id, with_overrides,
};

use crate::python::{python, run_python};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
const CLIENT: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/clients/python/examples/view_client.py"
);

/// A stack whose `up` starts the view on a free loopback port; `noiseless`: the sim's tracker
/// without noise or drift.
fn stack(name: &str, noiseless: bool) -> TestStack {
    let mut s = TestStack::with_config(BIN, name, true, |dir, ns| {
        let mut all = vec![
            ("view.enabled", true.into()),
            ("view.listen", "127.0.0.1:0".into()),
        ];
        if noiseless {
            all.push(("sim.realism.tracker_noise_m", 0.0.into()));
            all.push(("sim.realism.drift_m", 0.0.into()));
        }
        with_overrides(&config_text(dir, ns), &all)
    });
    s.up();
    s
}

/// The view's address, from the line it logs once it listens.
fn url(s: &TestStack) -> String {
    eventually("the view listening", Duration::from_secs(60), || {
        let logs = s.logs();
        let at = logs.find("serving the stack on ws://")? + "serving the stack on ".len();
        Some(logs[at..].split_whitespace().next()?.to_string())
    })
}

/// `view_client.py ARGS`, which prints one JSON object.
fn client(py: &str, url: &str, args: &[&str]) -> Value {
    let mut all = vec![CLIENT, "--url", url];
    all.extend_from_slice(args);
    let out = run_python(py, &all);
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&out.stdout)))
}

#[test]
fn an_independent_client_sees_every_service_and_the_arm_where_the_tracker_is() {
    let Some(py) = python(&["websockets", "google.protobuf"]) else {
        return;
    };
    // The sim's tracker without noise or drift: the tracker then reports exactly where the
    // arm model puts the end effector for the actuation the sim reports with the same seq.
    let s = stack("view", true);
    let url = url(&s);
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 2);
    assert_eq!(code, 0, "{out}{err}");
    let set = set_id(&out);
    let set_arg = set.to_string();
    let args = [
        "--json",
        "--seconds",
        "120",
        "--set-id",
        &set_arg,
        "--stats",
        "2",
    ];
    let got = client(&py, &url, &args);

    // What the server says about itself: read-only, and refuses what would not be.
    // The protocol v1 under the name ws-protocol documents, the only one the client offers
    // (the view's door renames it for the crate's server, which knows only its own names).
    assert_eq!(got["subprotocol"], "foxglove.websocket.v1", "{got}");
    assert_eq!(
        got["server"]["capabilities"],
        serde_json::json!([]),
        "{got}"
    );
    assert_eq!(got["server"]["metadata"]["namespace"], s.namespace.as_str());
    let refused = got["statuses"].to_string();
    assert!(
        refused.contains("does not support clientPublish") && refused.contains("parameters"),
        "{refused}"
    );

    // Every service and the scene, each with a schema that is what it says.
    let channels = got["channels"].as_object().unwrap();
    for topic in softarm_channels::TOPICS {
        let c = &channels[topic];
        assert_eq!(c["encoding"], "json", "{topic}: {c}");
        assert_eq!(c["schemaEncoding"], "jsonschema", "{topic}: {c}");
        assert!(
            c["schemaName"].as_str().unwrap().starts_with("softarm::"),
            "{c}"
        );
        assert_eq!(c["schema_ok"], true, "{topic}: {c}");
    }
    let scene = &channels["scene"];
    assert_eq!(scene["schemaName"], "foxglove.SceneUpdate");
    assert_eq!(
        (&scene["encoding"], &scene["schema_ok"]),
        (&"protobuf".into(), &true.into())
    );
    assert_eq!(channels.len(), 10, "{channels:?}");
    for topic in [
        "setpoint",
        "tracker",
        "motor_state",
        "cp_sample",
        "status",
        "scene",
    ] {
        assert!(
            got["counts"][topic].as_u64().unwrap_or(0) > 0,
            "{topic}: {got}"
        );
    }

    // The stats decode to what `softarm stats` prints, execution by execution.
    let cli = s.stats(set);
    let served: Vec<Value> = got["stats"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|v| v["set_id"] == set)
        .map(|v| {
            let line = stats::json_line(&stats::from_json(v).expect("a stats message"));
            serde_json::from_str(&line).unwrap()
        })
        .collect();
    assert_eq!(served.len(), 2, "{got}");
    assert_eq!(served, cli[..2], "served {served:?}\nsoftarm stats {cli:?}");

    // The status decodes to what `softarm status` says of the idle controller after the set.
    let status = &got["status"];
    let cli = s.status()["controller"].clone();
    let state = ControllerState::from_u32(status["state"].as_u64().unwrap() as u32).unwrap();
    assert_eq!(state.name(), cli["state"], "{status}\n{cli}");
    assert_eq!(status["set_id"], cli["set_id"]);
    assert_eq!(status["rate_hz"], cli["rate_hz"]);
    assert_eq!(status["model_loaded"] == 1, cli["model_loaded"] == true);
    assert!(
        status["ticks"].as_u64() <= cli["ticks"].as_u64(),
        "{status}\n{cli}"
    );

    // The scene: every entity, and the arm's tip where the tracker is, sample for sample.
    let scene = &got["scene"];
    for e in ["arm", "base", "reached", "tracker", "waypoints"] {
        assert!(
            scene["entities"].as_array().unwrap().contains(&e.into()),
            "{scene}"
        );
    }
    assert!(scene["pairs"].as_u64().unwrap() >= 10, "{scene}");
    let worst = scene["max_tip_error_m"].as_f64().unwrap();
    assert!(
        worst < 1e-3,
        "the arm's tip {worst} m from the tracker: {scene}"
    );
}

#[test]
fn a_client_offering_the_crates_name_gets_it_and_one_offering_another_gets_http_400() {
    let Some(py) = python(&["websockets", "google.protobuf"]) else {
        return;
    };
    let s = stack("view-names", false);
    let url = url(&s);

    // The crate's own name passes the door unchanged: the server negotiates it.
    let args = [
        "--json",
        "--seconds",
        "1",
        "--subprotocol",
        "foxglove.sdk.v1",
    ];
    let got = client(&py, &url, &args);
    assert_eq!(got["subprotocol"], "foxglove.sdk.v1", "{got}");
    let channels = got["channels"].as_object().unwrap();
    assert_eq!(channels.len(), 10, "{channels:?}");

    // Neither the documented name nor the crate's: the server's own refusal, and the view's
    // log says what it accepts.
    let out = output(
        Command::new(&py)
            .args([CLIENT, "--url", &url, "--json", "--subprotocol", "foo.v1"])
            .env("PYTHONDONTWRITEBYTECODE", "1"),
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(2), "{text}");
    let got: Value = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{e}: {text}"));
    assert_eq!(got["refused"]["status"], 400, "{got}");
    eventually("the view's log saying why", Duration::from_secs(30), || {
        s.logs()
            .contains(
                "offered the subprotocols [\"foo.v1\"]; the view accepts \
                 foxglove.websocket.v1, foxglove.sdk.v1 or foxglove.sdk.v1.1",
            )
            .then_some(())
    });
}

#[test]
fn a_client_that_reads_nothing_loses_messages_not_the_stack_nor_the_views_memory() {
    let Some(py) = python(&["websockets", "google.protobuf"]) else {
        return;
    };
    let mut s = stack("view-slow", false);
    let url = url(&s);
    let view = eventually("the view process", Duration::from_secs(30), || {
        s.children().into_iter().find(|(role, _)| role == "view")
    })
    .1;
    let before_kib = rss_kib(&view.to_string()).unwrap();
    let ticks = |st: &Value| st["controller"]["ticks"].as_u64().unwrap_or(0);
    let ticks_before = ticks(&s.status());
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 3);
    assert_eq!(code, 0, "{out}{err}");
    let set = set_id(&out);

    // Reads nothing for 20 s, then reads what still comes for up to 10 s. The sockets' buffers
    // on the way hold the first several seconds (the server's send buffer grows to
    // net.ipv4.tcp_wmem's maximum, 4 MiB, about 8 s of everything), so the pause outlasts them.
    let mut slow = Guard::spawn(
        Command::new(&py)
            .arg(CLIENT)
            .args(["--url", &url, "--slow", "20", "--seconds", "10"])
            .env("PYTHONDONTWRITEBYTECODE", "1")
            .stdout(Stdio::piped()),
    );
    let mut stdout = slow.stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut b = Vec::new();
        stdout.read_to_end(&mut b).map(|_| b)
    });
    let mut peak_kib = before_kib;
    while slow.try_wait().unwrap().is_none() {
        peak_kib = peak_kib.max(rss_kib(&view.to_string()).unwrap_or(0));
        std::thread::sleep(Duration::from_millis(50));
    }
    let exit = slow.wait().unwrap();
    let stdout = reader.join().unwrap().unwrap();
    assert!(exit.success(), "view_client.py --slow: {exit}");
    let got: Value = serde_json::from_slice(&stdout)
        .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&stdout)));

    // It got something once it read again, and not what it missed: dropped, not queued.
    let setpoints = &got["setpoints"];
    eprintln!(
        "view RSS {before_kib} KiB, peak {peak_kib} KiB with a client that read nothing for 20 s; \
         it missed {} setpoints of seq {} to {}",
        setpoints["missing"], setpoints["first"], setpoints["last"]
    );
    assert!(setpoints["received"].as_u64().unwrap() > 0, "{got}");
    assert!(
        setpoints["missing"].as_u64().unwrap() > 0,
        "nothing dropped: {got}"
    );
    // The view's queue for it is bounded: its memory with it is what it was, give or take
    // view.backlog (1024) messages of a few kB.
    let grown_mib = peak_kib.saturating_sub(before_kib) as f64 / 1024.0;
    assert!(
        grown_mib < 32.0,
        "the view grew {grown_mib:.1} MiB ({before_kib} -> {peak_kib} KiB)"
    );

    // The stack ran on meanwhile: the set finished, the tick counted on, the view lives.
    s.wait_stats(set, 3, Duration::from_secs(120));
    let after = s.status();
    assert!(ticks(&after) > ticks_before, "{after}");
    assert!(
        after["controller"]["latency_ns"]["p99"].as_u64().unwrap() > 0,
        "{after}"
    );
    assert!(
        s.children()
            .iter()
            .any(|(role, pid)| role == "view" && *pid == view)
    );
    assert!(s.stop().is_some_and(|st| st.success()));
}
