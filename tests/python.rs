//! Python interop (`clients/python`): the ctypes mirrors of `softarm_ipc.py` against the Rust
//! payloads (size, alignment, field offsets and types, iceoryx2 type names), enums and service
//! settings; then the Python examples against a real stack: `read_live.py` reads its setpoints,
//! status and a submitted set's stats, `softarm_ipc.submit` sends a set the controller runs, and
//! `read_bundle.py` reads the stack's model bundle.
//!
//! Without `python3` (or `SOFTARM_PYTHON`), or without its packages (`pip install
//! iceoryx2==0.10.0 safetensors numpy`), a test says why on stderr and passes, unless
//! `SOFTARM_REQUIRE_PYTHON=1` (CI), where it fails.

use std::collections::BTreeMap;
use std::mem::{MaybeUninit, align_of, offset_of, size_of};
use std::path::Path;
use std::process::{Command, Output};
use std::time::Duration;

use softarm_ipc::iceoryx2::prelude::{PortFactory, ZeroCopySend};
use softarm_ipc::*;
use softarm_test_support::{DEMO_WAYPOINTS, TestStack, output, set_id};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
const PY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/clients/python");

/// The interpreter if it runs and imports `modules`; else why not: a panic under
/// `SOFTARM_REQUIRE_PYTHON=1`, a note and `None` otherwise.
pub(crate) fn python(modules: &[&str]) -> Option<String> {
    let py = std::env::var("SOFTARM_PYTHON").unwrap_or_else(|_| "python3".into());
    let check = if modules.is_empty() {
        "pass".to_string()
    } else {
        format!("import {}", modules.join(", "))
    };
    let why = match Command::new(&py).args(["-c", &check]).output() {
        Ok(o) if o.status.success() => return Some(py),
        Ok(o) => format!(
            "{py} cannot import {modules:?}: {}",
            String::from_utf8_lossy(&o.stderr)
                .trim()
                .lines()
                .last()
                .unwrap_or("")
        ),
        Err(e) => format!("no {py}: {e}"),
    };
    let install = "pip install iceoryx2==0.10.0 mcap safetensors numpy websockets protobuf cyclonedds==11.0.1";
    if std::env::var("SOFTARM_REQUIRE_PYTHON").as_deref() == Ok("1") {
        panic!("{why} (SOFTARM_REQUIRE_PYTHON=1; {install})");
    }
    eprintln!("not run: {why} ({install}; SOFTARM_REQUIRE_PYTHON=1 makes this a failure)");
    None
}

/// Runs `py <args>` from this package's folder (as the stack's processes run: iceoryx2 looks
/// for `config/iceoryx2.toml` there first) and insists on success.
pub fn run_python(py: &str, args: &[&str]) -> Output {
    let out = output(
        Command::new(py)
            .args(args)
            // No __pycache__ in the work tree.
            .env("PYTHONDONTWRITEBYTECODE", "1"),
    );
    assert!(
        out.status.success(),
        "{py} {args:?}: {}\n{}{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn json(text: &str) -> serde_json::Value {
    serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("not JSON ({e}): {text}"))
}

/// A Rust payload's layout as `check_layout.py` prints a mirror's.
#[derive(Debug)]
struct Layout {
    name: &'static str,
    size: usize,
    align: usize,
    type_name: String,
    /// (field, offset, type as `std::any::type_name` says it, module paths stripped).
    fields: Vec<(&'static str, usize, String)>,
}

fn type_of<T>(_: *const T) -> String {
    std::any::type_name::<T>()
        .replace("softarm_ipc::actuators::", "")
        .replace("softarm_ipc::", "")
}

/// The layout of payload `$t`, whose fields must all be listed: the destructuring below stops
/// compiling when a field is added to the Rust type.
macro_rules! layout {
    ($t:ident { $($f:ident),* $(,)? }) => {{
        #[allow(dead_code)]
        fn every_field_is_listed(v: $t) {
            let $t { $($f: _),* } = v;
        }
        let value = MaybeUninit::<$t>::uninit();
        let p = value.as_ptr();
        Layout {
            name: stringify!($t),
            size: size_of::<$t>(),
            align: align_of::<$t>(),
            // SAFETY: only reads the name the type was declared with.
            type_name: unsafe { <$t as ZeroCopySend>::type_name() }.to_string(),
            fields: vec![$((
                stringify!($f),
                offset_of!($t, $f),
                // SAFETY: a place in allocated (if uninitialised) memory; nothing is read.
                type_of(unsafe { &raw const (*p).$f }),
            )),*],
        }
    }};
}

fn rust_layouts() -> Vec<Layout> {
    vec![
        layout!(Actuators {
            count,
            _pad,
            values
        }),
        layout!(Setpoint {
            seq,
            stamp_ns,
            actuation,
            state,
            demo,
            demo_class,
            execution
        }),
        layout!(TrackerSample {
            seq,
            stamp_ns,
            position
        }),
        layout!(MotorState {
            seq,
            stamp_ns,
            actuation,
            current_a,
            faults,
            dropped,
            crc_errors,
            garbage_bytes,
            timeouts,
            reopens,
            setpoint_cycles,
            goal_writes,
            state,
            loss_permille,
            hardware_error,
            age_cycles
        }),
        layout!(ConditioningSample {
            seq,
            stamp_ns,
            set_id,
            execution,
            point,
            points,
            _pad,
            actuation,
            desired,
            reached,
            next_point,
            next_execution,
            next_desired,
            measured,
            conditioned
        }),
        layout!(EstimateRequest {
            seq,
            stamp_ns,
            set_id,
            count,
            _pad,
            desired
        }),
        layout!(ActuationEstimate {
            seq,
            stamp_ns,
            set_id,
            point,
            execution,
            actuation,
            within,
            beyond_reach,
            answers_ns
        }),
        layout!(WaypointSet {
            seq,
            stamp_ns,
            duration_s,
            executions,
            count,
            times_s,
            positions_m
        }),
        layout!(WaypointReply {
            seq,
            stamp_ns,
            set_id,
            accepted,
            reason_len,
            reason
        }),
        layout!(DemonstrateRequest {
            seq,
            stamp_ns,
            seed
        }),
        layout!(DemonstrateReply {
            seq,
            stamp_ns,
            accepted,
            demos,
            duration_s
        }),
        layout!(ExecutionStats {
            seq,
            stamp_ns,
            set_id,
            execution,
            executions,
            count,
            reconditions,
            within,
            beyond_reach,
            errors_m,
            mean_m,
            max_m
        }),
        layout!(Latency {
            min_ns,
            p50_ns,
            p99_ns,
            p999_ns,
            max_ns,
            samples
        }),
        layout!(ControllerStatus {
            seq,
            stamp_ns,
            state,
            execution,
            set_id,
            rate_hz,
            ticks,
            overruns,
            latency,
            tracker_age_ns,
            motor_age_ns,
            model_loaded,
            reconditions_current,
            reconditions_last,
            outbox_backlog,
            outbox_dropped,
            samples_dropped,
            held_solves,
            lag_ns,
            lead_ns,
            points_unseen
        }),
        layout!(EstopState {
            seq,
            stamp_ns,
            engaged,
            _pad
        }),
    ]
}

/// Every `#[type_name("...")]` in `softarm-ipc`'s sources: a payload added there and not here
/// (or in Python) is noticed.
fn declared_type_names() -> Vec<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("contract/ipc/src");
    let mut names = Vec::new();
    for e in std::fs::read_dir(&dir).unwrap().flatten() {
        let text = std::fs::read_to_string(e.path()).unwrap_or_default();
        for part in text.split("#[type_name(\"").skip(1) {
            names.push(part.split('"').next().unwrap().to_string());
        }
    }
    names.sort();
    names
}

#[test]
fn python_mirrors_match_the_rust_payloads_enums_and_services() {
    let Some(py) = python(&[]) else { return };
    let script = format!("{PY}/check_layout.py");
    let out = run_python(&py, &[&script]);
    let mirrors = json(&String::from_utf8_lossy(&out.stdout));

    let rust = rust_layouts();
    let mut rust_names: Vec<String> = rust.iter().map(|l| l.type_name.clone()).collect();
    rust_names.sort();
    assert_eq!(
        rust_names,
        declared_type_names(),
        "a payload is missing here"
    );
    let mut python_names: Vec<&String> = mirrors.as_object().unwrap().keys().collect();
    python_names.sort();
    let mut expected: Vec<&str> = rust.iter().map(|l| l.name).collect();
    expected.sort();
    assert_eq!(python_names, expected, "mirrors in softarm_ipc.PAYLOADS");

    let mut mismatches = Vec::new();
    for r in &rust {
        let m = &mirrors[r.name];
        let mut check = |what: &str, python: String, rust: String| {
            if python != rust {
                mismatches.push(format!("{}.{what}: Python {python}, Rust {rust}", r.name));
            }
        };
        check("size", m["size"].to_string(), r.size.to_string());
        check("align", m["align"].to_string(), r.align.to_string());
        check(
            "type_name",
            m["type_name"].as_str().unwrap_or("?").into(),
            r.type_name.clone(),
        );
        // Field names in declaration order (ctypes keeps `_fields_` order; offsets must agree).
        let python_fields: BTreeMap<u64, String> = m["fields"]
            .as_object()
            .unwrap()
            .iter()
            .map(|(f, o)| (o.as_u64().unwrap(), f.clone()))
            .collect();
        let rust_fields: BTreeMap<u64, String> = r
            .fields
            .iter()
            .map(|(f, o, _)| (*o as u64, f.to_string()))
            .collect();
        check(
            "fields",
            format!("{python_fields:?}"),
            format!("{rust_fields:?}"),
        );
        for (f, _, t) in &r.fields {
            check(
                &format!("{f} type"),
                m["types"][*f].as_str().unwrap_or("missing").into(),
                t.clone(),
            );
        }
    }
    assert!(
        mismatches.is_empty(),
        "Python mirrors differ from the Rust payloads:\n{}",
        mismatches.join("\n")
    );

    // Enums: the same numbers and names (ControllerState 2 stays free).
    let out = run_python(&py, &[&script, "--enums"]);
    let enums = json(&String::from_utf8_lossy(&out.stdout));
    for v in 0..8u32 {
        let python = |e: &str| {
            enums[e]
                .as_object()
                .unwrap()
                .iter()
                .find(|(_, n)| n.as_u64() == Some(v as u64))
                .map(|(name, _)| name.clone())
        };
        assert_eq!(
            python("ControllerState").as_deref(),
            ControllerState::from_u32(v).map(|s| s.name()),
            "ControllerState {v}"
        );
        assert_eq!(
            python("DriverState").as_deref(),
            DriverState::from_u32(v).map(|s| s.name()),
            "DriverState {v}"
        );
    }

    // Services: the settings the Rust openers create them with (what a Python peer must not
    // exceed when it opens them, and creates them with when it is first), and the payload type
    // details iceoryx2 matches on.
    let out = run_python(&py, &[&script, "--services"]);
    let services = json(&String::from_utf8_lossy(&out.stdout));
    let ns = Namespace::new(&format!(
        "softarm/test-python-layout-{}",
        std::process::id()
    ))
    .unwrap();
    let node = Node::open(ns, "test").unwrap();
    let mut checked = Vec::new();
    macro_rules! pubsub {
        ($name:literal, $open:ident) => {{
            let service = node.$open().unwrap();
            let c = service.static_config();
            let payload = &c.message_type_details().payload;
            let p = &services["pubsub"][$name];
            let rust = format!(
                "{} {} {} {} {} {} {} {}",
                payload.type_name(),
                payload.size(),
                c.history_size(),
                c.subscriber_max_buffer_size(),
                c.max_publishers(),
                c.max_subscribers(),
                c.max_nodes(),
                payload.alignment()
            );
            let size = &mirrors
                .as_object()
                .unwrap()
                .values()
                .find(|m| m["type_name"] == p["payload"])
                .map(|m| (m["size"].clone(), m["align"].clone()))
                .unwrap_or_default();
            let python = format!(
                "{} {} {} {} {} {} {} {}",
                p["payload"].as_str().unwrap_or("?"),
                size.0,
                p["history"],
                p["subscriber_max_buffer_size"],
                p["max_publishers"],
                p["max_subscribers"],
                p["max_nodes"],
                size.1
            );
            assert_eq!(python, rust, "service {}: Python vs Rust", $name);
            checked.push($name);
        }};
    }
    pubsub!("setpoint", setpoint);
    pubsub!("tracker", tracker);
    pubsub!("motor_state", motor_state);
    pubsub!("cp_sample", cp_sample);
    pubsub!("estimate_request", estimate_request);
    pubsub!("estimate", estimate);
    pubsub!("stats", stats);
    pubsub!("status", status);
    pubsub!("estop", estop);
    macro_rules! reqres {
        ($name:literal, $open:ident) => {{
            let service = node.$open().unwrap();
            let c = service.static_config();
            let p = &services["request_response"][$name];
            let rust = format!(
                "{} {} {} {} {} {} {}",
                c.request_message_type_details().payload.type_name(),
                c.response_message_type_details().payload.type_name(),
                c.max_clients(),
                c.max_servers(),
                c.max_nodes(),
                c.max_active_requests_per_client(),
                c.max_response_buffer_size()
            );
            let python = format!(
                "{} {} {} {} {} {} {}",
                p["request"].as_str().unwrap_or("?"),
                p["response"].as_str().unwrap_or("?"),
                p["max_clients"],
                p["max_servers"],
                p["max_nodes"],
                p["max_active_requests_per_client"],
                p["max_response_buffer_size"]
            );
            assert_eq!(python, rust, "service {}: Python vs Rust", $name);
            checked.push($name);
        }};
    }
    reqres!("waypoints", waypoints);
    reqres!("demonstrate", demonstrate);
    let mut python_services: Vec<&str> = ["pubsub", "request_response"]
        .iter()
        .flat_map(|k| services[*k].as_object().unwrap().keys())
        .map(|k| k.as_str())
        .collect();
    python_services.sort();
    checked.sort();
    assert_eq!(
        python_services, checked,
        "every service of softarm_ipc.py checked"
    );
}

#[test]
fn python_reads_a_live_stack_and_submits_to_it() {
    const EXECUTIONS: u32 = 4;
    let Some(py) = python(&["iceoryx2", "safetensors", "numpy"]) else {
        return;
    };
    let mut s = TestStack::new(BIN, "python", true);

    // The model bundle, as numpy reads it.
    let model = s.dir.join("model");
    let out = run_python(
        &py,
        &[
            &format!("{PY}/examples/read_bundle.py"),
            model.to_str().unwrap(),
            "--json",
        ],
    );
    let bundle = json(&String::from_utf8_lossy(&out.stdout));
    let (file, b) = bundle.as_object().unwrap().iter().next().unwrap();
    assert!(
        file.starts_with("model-") && file.ends_with(".safetensors"),
        "{file}"
    );
    let k = b["meta"]["basis_functions"].as_u64().unwrap();
    let t = &b["tensors"];
    assert_eq!(
        t["promp.actuation.0.mean"]["shape"],
        serde_json::json!([6 * k])
    );
    assert_eq!(t["promp.task.2.cov"]["shape"][1], 3 * k, "{t}");
    assert_eq!(t["forward.weights"]["shape"][1], 3, "{t}");
    assert_eq!(t["actor.keys"]["dtype"], "uint64", "{t}");
    assert_eq!(t["kinematics.weights"]["dtype"], "float64", "{t}");

    s.up();
    // Four executions (23 s): Python is still in time to read setpoints live when it starts
    // seconds late on a loaded machine (with two, it came after both, read their stats from
    // the history and stopped at once, with 20 setpoints).
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), EXECUTIONS);
    assert_eq!(code, 0, "{out}{err}");
    let id = set_id(&out);

    // Python reads the set's execution as it happens: setpoints, status, every execution's
    // stats.
    let out = run_python(
        &py,
        &[
            &format!("{PY}/examples/read_live.py"),
            "--namespace",
            &s.namespace,
            "--seconds",
            "90",
            "--json",
            "--set-id",
            &id.to_string(),
            "--stats",
            &EXECUTIONS.to_string(),
        ],
    );
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    let summary = json(text.lines().last().unwrap_or(""));
    assert_eq!(summary["kind"], "summary", "{text}");
    assert!(summary["setpoints"].as_u64().unwrap() > 100, "{summary}");
    assert!(
        summary["states"]["EXECUTE"].as_u64().unwrap_or(0) > 0,
        "{summary}"
    );
    let actuation = summary["last_actuation"].as_array().unwrap();
    // The default [arm]: the paper's six actuators.
    assert_eq!(actuation.len(), 6, "{summary}");
    assert!(
        actuation
            .iter()
            .all(|a| (0.0..=1.0).contains(&a.as_f64().unwrap())),
        "{summary}"
    );
    assert_eq!(summary["status"]["model_loaded"], true, "{summary}");
    assert!(
        summary["status"]["rate_hz"].as_f64().unwrap() > 0.0,
        "{summary}"
    );
    let stats = summary["stats"].as_array().unwrap();
    let executions: Vec<u64> = stats
        .iter()
        .map(|v| v["execution"].as_u64().unwrap())
        .collect();
    assert_eq!(
        executions,
        (1..=EXECUTIONS as u64).collect::<Vec<_>>(),
        "{summary}"
    );
    // The same numbers as `softarm stats --json` (the Rust client) prints.
    let rust = s.wait_stats(id, EXECUTIONS as usize, Duration::from_secs(30));
    for (p, r) in stats.iter().zip(&rust) {
        assert_eq!(
            (p["set_id"].as_u64(), p["executions"].as_u64()),
            (Some(id), Some(EXECUTIONS as u64))
        );
        assert_eq!(p["count"], 5, "{p}");
        assert_eq!(p["execution"], r["execution"]);
        assert_eq!(p["reconditions"], r["reconditions"]);
        assert_eq!(p["within"], r["within"], "{p} vs {r}");
        assert_eq!(p["beyond_reach"], r["beyond_reach"], "{p} vs {r}");
        let (pe, re) = (
            p["errors_mm"].as_array().unwrap(),
            r["errors_mm"].as_array().unwrap(),
        );
        assert_eq!(pe.len(), re.len(), "{p} vs {r}");
        for (a, b) in pe.iter().zip(re).chain([(&p["mean_mm"], &r["mean_mm"])]) {
            let (a, b) = (a.as_f64().unwrap(), b.as_f64().unwrap());
            assert!(a.is_finite() && (a - b).abs() <= 1e-3, "{p} vs {r}");
        }
    }

    // A set submitted from Python over request-response runs like one from `softarm submit`.
    let submit = format!(
        "import sys; sys.path.insert(0, {PY:?}); import softarm_ipc as sa\n\
         node = sa.open_node({ns:?}, 'submit')\n\
         bad = sa.submit(node, {ns:?}, [1.0, 3.0], [[0.1, 0.0, -0.45], [0.0, 0.0, -0.5]], 2.0)\n\
         print('rejected' if not bad.accepted else 'accepted', bad.reason_text())\n\
         r = sa.submit(node, {ns:?}, [0.8, 1.8, 2.8], \
         [[0.165, 0.0, -0.471], [0.031, 0.0, -0.501], [-0.105, 0.0, -0.487]], 5.0)\n\
         print('accepted' if r.accepted else 'rejected', r.set_id, r.reason_text())\n",
        ns = s.namespace
    );
    let out = run_python(&py, &["-c", &submit]);
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("rejected point 2: time 3 s is outside (0, 2] s"),
        "{text}"
    );
    let accepted = lines.next().unwrap_or("");
    let python_id: u64 = accepted
        .strip_prefix("accepted ")
        .and_then(|r| r.trim().parse().ok())
        .unwrap_or_else(|| panic!("{text}"));
    assert!(python_id > id, "{text}");
    let stats = s.wait_stats(python_id, 1, Duration::from_secs(60));
    assert_eq!(
        stats[0]["errors_mm"].as_array().unwrap().len(),
        3,
        "{}",
        stats[0]
    );
}
