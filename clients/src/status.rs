//! `softarm status`: which processes are alive, the controller's state, tick timing, data ages.

use std::time::Duration;

use softarm_ipc::{ControllerState, ControllerStatus, Namespace, Node};

pub struct Report {
    /// The stack's processes with a live iceoryx2 node (this client excluded).
    pub alive: Vec<String>,
    pub controller: Option<ControllerStatus>,
}

/// Looks at a namespace: the node list and the newest controller status (waiting up to
/// `timeout` for it).
pub fn status(namespace: &Namespace, timeout: Duration) -> Result<Report, softarm_ipc::Error> {
    let ipc = Node::open(namespace.clone(), "status")?;
    let sub = ipc.subscriber(&ipc.status()?)?;
    let mut newest = None;
    crate::poll(timeout, || {
        while let Ok(Some(s)) = sub.receive() {
            newest = Some(*s);
        }
        newest.map(|_| ())
    });
    let mut alive: Vec<String> = ipc
        .alive_nodes()?
        .into_iter()
        .filter(|n| n != "status")
        // One process may hold several nodes (controller, controller.service).
        .map(|n| n.split('.').next().unwrap_or(&n).to_string())
        .collect();
    alive.dedup();
    Ok(Report {
        alive,
        controller: newest,
    })
}

fn ms(ns: u64) -> String {
    if ns == u64::MAX {
        "never".into()
    } else {
        format!("{:.1} ms", ns as f64 / 1e6)
    }
}

fn us(ns: u64) -> String {
    format!("{:.1}", ns as f64 / 1e3)
}

pub fn text(r: &Report) -> String {
    let mut out = format!(
        "processes: {}\n",
        if r.alive.is_empty() {
            "none".to_string()
        } else {
            r.alive.join(", ")
        }
    );
    match &r.controller {
        None => out += "controller: no status (not running?)\n",
        Some(s) => {
            let state = ControllerState::from_u32(s.state).map_or("?", |s| s.name());
            let l = &s.latency;
            out += &format!(
                "controller: {state}{}, {} Hz, model {}\n\
                 tick wake-up latency µs: min {} p50 {} p99 {} p99.9 {} max {} ({} ticks, {} overruns)\n\
                 data age: tracker {}, motors {}\n",
                if s.set_id != 0 {
                    format!(" (set {}, execution {})", s.set_id, s.execution)
                } else {
                    String::new()
                },
                s.rate_hz,
                if s.model_loaded == 1 {
                    "loaded"
                } else {
                    "missing (run softarm train)"
                },
                us(l.min_ns),
                us(l.p50_ns),
                us(l.p99_ns),
                us(l.p999_ns),
                us(l.max_ns),
                s.ticks,
                s.overruns,
                ms(s.tracker_age_ns),
                ms(s.motor_age_ns)
            );
        }
    }
    out
}

pub fn json(r: &Report) -> String {
    let controller = r.controller.map(|s| {
        let l = s.latency;
        serde_json::json!({
            "state": ControllerState::from_u32(s.state).map_or("?", |s| s.name()),
            "set_id": s.set_id,
            "execution": s.execution,
            "rate_hz": s.rate_hz,
            "model_loaded": s.model_loaded == 1,
            "ticks": s.ticks,
            "overruns": s.overruns,
            "latency_ns": {"min": l.min_ns, "p50": l.p50_ns, "p99": l.p99_ns, "p999": l.p999_ns, "max": l.max_ns},
            "tracker_age_ns": (s.tracker_age_ns != u64::MAX).then_some(s.tracker_age_ns),
            "motor_age_ns": (s.motor_age_ns != u64::MAX).then_some(s.motor_age_ns),
        })
    });
    serde_json::json!({ "alive": r.alive, "controller": controller }).to_string()
}
