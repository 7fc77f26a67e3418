//! `softarm status`: which processes are alive, the controller's state, tick timing, data ages,
//! the points that ran on their estimate in time per execution, and what the tick's outbox
//! could not keep.

use std::time::Duration;

use softarm_ipc::{ControllerState, ControllerStatus, DriverState, MotorState, Namespace, Node};

pub struct Report {
    /// The stack's processes with a live iceoryx2 node (this client excluded).
    pub alive: Vec<String>,
    pub controller: Option<ControllerStatus>,
    /// The newest `motor_state` of the driver (sim or tendon), if one is publishing.
    pub motors: Option<MotorState>,
}

/// `softarm status`'s exit code when the stack is not running (`systemctl status` uses 3 too).
pub const NOT_RUNNING: u8 = 3;

impl Report {
    /// The controller is alive and publishing its status.
    pub fn running(&self) -> bool {
        self.controller.is_some() && self.alive.iter().any(|n| n == "controller")
    }
}

/// How long `status` waits for a driver's `motor_state` once the controller's status is in:
/// many of the drivers' periods (5 to 10 ms), so only a driver that is not publishing is missed.
const MOTOR_STATE_WAIT: Duration = Duration::from_millis(200);

/// Looks at a namespace: the node list and the newest controller status (waiting up to
/// `timeout` for it).
pub fn status(namespace: &Namespace, timeout: Duration) -> Result<Report, softarm_ipc::Error> {
    let ipc = Node::open(namespace.clone(), "status")?;
    let sub = ipc.subscriber(&ipc.status()?)?;
    let motor_sub = ipc.subscriber(&ipc.motor_state()?)?;
    let mut newest = None;
    let mut motors = None;
    let mut status_at = None;
    crate::poll(timeout, || {
        while let Ok(Some(s)) = sub.receive() {
            newest = Some(*s);
            status_at.get_or_insert_with(std::time::Instant::now);
        }
        while let Ok(Some(m)) = motor_sub.receive() {
            motors = Some(*m);
        }
        // The controller's status may come at once (the service keeps the last); the driver's
        // next motor_state is a period away. Without this wait the driver's line was missing now
        // and then (seen in a test reading DEGRADED from it).
        let driver_had_its_chance = status_at.is_some_and(|t| t.elapsed() >= MOTOR_STATE_WAIT);
        (newest.is_some() && (motors.is_some() || driver_had_its_chance)).then_some(())
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
        motors,
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
        None if r.alive.iter().any(|n| n == "controller") => {
            out += "controller: its process is alive, but no status came in time: it is frozen, \
                    or its shared memory belongs to another user than this command's (run it as \
                    the stack's user, as root, or as one of the stack's operators)\n"
        }
        None => out += "controller: not running\n",
        Some(s) => {
            let state = ControllerState::from_u32(s.state).map_or("?", |s| s.name());
            let l = &s.latency;
            out += &format!(
                "controller: {state}{}, {} Hz, model {}\n\
                 tick wake-up latency µs: min {} p50 {} p99 {} p99.9 {} max {} ({} ticks, {} overruns)\n\
                 data age: tracker {}, motors {}\n\
                 points on their estimate in time: {} this execution, {} in the last\n\
                 points the tracker did not see at their time: {} (their error unknown, nothing learnt)\n\
                 outbox: {} dropped ({} conditioning samples), {} waiting; group solves held: {}\n\
                 actuator lag: {}\n",
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
                ms(s.motor_age_ns),
                s.reconditions_current,
                s.reconditions_last,
                s.points_unseen,
                s.outbox_dropped,
                s.samples_dropped,
                s.outbox_backlog,
                s.held_solves,
                lag(s.lag_ns, s.lead_ns)
            );
        }
    }
    if let Some(m) = &r.motors {
        let state = DriverState::from_u32(m.state).map_or("?", |s| s.name());
        let errors: Vec<String> = m
            .hardware_errors()
            .iter()
            .enumerate()
            .filter(|(_, e)| **e != 0)
            .map(|(i, e)| format!("actuator {} {e:#04x}", i + 1))
            .collect();
        out += &format!(
            "driver: {state}{}; goal writes {} in {} cycles with a setpoint; replies lost {:.1} % \
             over the last second; dropped {}, CRC errors {}, garbage {} bytes, read time-outs {}, \
             reopens {}; hardware errors: {}\n",
            bus_verdict(m),
            m.goal_writes,
            m.setpoint_cycles,
            f64::from(m.loss_permille) / 10.0,
            m.dropped,
            m.crc_errors,
            m.garbage_bytes,
            m.timeouts,
            m.reopens,
            if errors.is_empty() {
                "none".into()
            } else {
                errors.join(", ")
            }
        );
    }
    out
}

/// The actuators' lag and the lead Eq. 11 runs with, in words.
fn lag(lag_ns: u64, lead_ns: u64) -> String {
    if lag_ns == u64::MAX {
        return "not measured yet (the arm has not moved enough)".into();
    }
    format!("{}, Eq. 11 evaluated {} ahead", ms(lag_ns), ms(lead_ns))
}

/// What the loss rate says about the bus, in words (the thresholds the tendon driver uses).
fn bus_verdict(m: &MotorState) -> &'static str {
    match m.loss_permille {
        500.. => " (bus failing: most replies lost)",
        10.. => " (bus degraded: replies being lost)",
        _ => "",
    }
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
            "reconditions": {"current": s.reconditions_current, "last": s.reconditions_last},
            "outbox": {"dropped": s.outbox_dropped, "samples_dropped": s.samples_dropped, "backlog": s.outbox_backlog},
            "held_solves": s.held_solves,
            "points_unseen": s.points_unseen,
            "lag_ns": (s.lag_ns != u64::MAX).then_some(s.lag_ns),
            "lead_ns": s.lead_ns,
        })
    });
    let driver = r.motors.map(|m| {
        serde_json::json!({
            "state": DriverState::from_u32(m.state).map_or("?", |s| s.name()),
            "faults": m.faults,
            "bus": {
                "loss_permille": m.loss_permille,
                "dropped": m.dropped,
                "crc_errors": m.crc_errors,
                "garbage_bytes": m.garbage_bytes,
                "timeouts": m.timeouts,
                "reopens": m.reopens,
                "setpoint_cycles": m.setpoint_cycles,
                "goal_writes": m.goal_writes,
            },
            "hardware_error": m.hardware_errors(),
            "current_a": m.current_a.iter().map(|c| c.is_finite().then_some(*c)).collect::<Vec<_>>(),
        })
    });
    serde_json::json!({ "alive": r.alive, "controller": controller, "driver": driver }).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reconditionings_drops_and_held_solves_are_shown() {
        let r = Report {
            alive: vec!["controller".into()],
            controller: Some(ControllerStatus {
                state: ControllerState::Execute as u32,
                set_id: 9,
                execution: 3,
                reconditions_current: 1,
                reconditions_last: 4,
                outbox_backlog: 2,
                outbox_dropped: 17,
                samples_dropped: 5,
                held_solves: 6,
                lag_ns: 23_400_000,
                lead_ns: 23_400_000,
                points_unseen: 3,
                ..Default::default()
            }),
            motors: Some(MotorState {
                state: DriverState::Fault as u32,
                faults: 12,
                dropped: 7,
                crc_errors: 5,
                garbage_bytes: 40,
                timeouts: 6,
                loss_permille: 123,
                actuation: [0.5; 6].into(),
                hardware_error: [0, 0, 0x20, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
                ..Default::default()
            }),
        };
        let t = text(&r);
        assert!(
            t.contains("points on their estimate in time: 1 this execution, 4 in the last"),
            "{t}"
        );
        assert!(
            t.contains(
                "outbox: 17 dropped (5 conditioning samples), 2 waiting; group solves held: 6"
            ),
            "{t}"
        );
        let j: serde_json::Value = serde_json::from_str(&json(&r)).unwrap();
        let c = &j["controller"];
        assert_eq!(
            c["reconditions"],
            serde_json::json!({"current": 1, "last": 4})
        );
        assert_eq!(
            c["outbox"],
            serde_json::json!({"dropped": 17, "samples_dropped": 5, "backlog": 2})
        );
        assert_eq!(c["held_solves"], 6);
        assert_eq!(c["points_unseen"], 3);
        assert!(
            t.contains("points the tracker did not see at their time: 3"),
            "{t}"
        );
        assert!(
            t.contains("actuator lag: 23.4 ms, Eq. 11 evaluated 23.4 ms ahead"),
            "{t}"
        );
        assert_eq!(
            (c["lag_ns"].as_u64(), c["lead_ns"].as_u64()),
            (Some(23_400_000), Some(23_400_000))
        );
        assert!(
            t.contains(
                "driver: FAULT (bus degraded: replies being lost); goal writes 0 in 0 cycles with \
                 a setpoint; replies lost 12.3 % over the last second; dropped 7, CRC errors 5, \
                 garbage 40 bytes, read time-outs 6, reopens 0; hardware errors: actuator 3 0x20"
            ),
            "{t}"
        );
        assert_eq!(j["driver"]["state"], "FAULT");
        assert_eq!(
            j["driver"]["bus"],
            serde_json::json!({"loss_permille": 123, "dropped": 7, "crc_errors": 5,
                "garbage_bytes": 40, "timeouts": 6, "reopens": 0, "setpoint_cycles": 0,
                "goal_writes": 0})
        );
        assert_eq!(j["driver"]["hardware_error"][2], 0x20);
    }
}
