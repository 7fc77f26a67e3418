//! `softarm submit WAYPOINTS.toml`: validates locally, submits, reports the controller's answer.

use std::time::Duration;

use anyhow::{Context, anyhow};

use softarm_config::Config;
use softarm_config::waypoints::{WaypointFile, validate};
use softarm_ipc::{Namespace, Node, WaypointSet};
use softarm_runtime::now_ns;

use crate::stats;

/// How a submission ended; the exit code of `softarm submit`.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    Accepted { set_id: u64 },
    Rejected { reason: String },
    Unreachable { message: String },
}

impl Outcome {
    pub fn exit_code(&self) -> u8 {
        match self {
            Outcome::Accepted { .. } => 0,
            Outcome::Rejected { .. } => 2,
            Outcome::Unreachable { .. } => 1,
        }
    }
}

/// Reads and checks a way-point file against the config's limits: a set that would be refused
/// is refused here, before anything is sent.
/// The error is the reason, for the user.
pub fn prepare(
    config: &Config,
    file: &std::path::Path,
    executions: u32,
) -> Result<WaypointSet, String> {
    prepare_read(config, file, std::fs::read_to_string(file), executions)
}

/// [`prepare`] of a file already read (`text`, or why it could not be).
pub fn prepare_read(
    config: &Config,
    file: &std::path::Path,
    text: std::io::Result<String>,
    executions: u32,
) -> Result<WaypointSet, String> {
    let text = text.map_err(|e| format!("{}: cannot read: {e}", file.display()))?;
    let f = WaypointFile::parse(&text).map_err(|e| format!("{}: {e}", file.display()))?;
    let max = config.waypoints.max_executions;
    if !(1..=max).contains(&executions) {
        return Err(format!(
            "--executions {executions}: 1 to {max} are allowed (the config's \
             waypoints.max_executions)"
        ));
    }
    let set = f.to_set(executions)?;
    validate(&set, &config.waypoints, &config.activation)
        .map_err(|e| format!("{}: {e}", file.display()))?;
    Ok(set)
}

/// Sends a set and waits for the answer.
pub fn submit(namespace: &Namespace, mut set: WaypointSet, timeout: Duration) -> Outcome {
    let ipc = match Node::open(namespace.clone(), "submit") {
        Ok(c) => c,
        Err(e) => {
            return Outcome::Unreachable {
                message: e.to_string(),
            };
        }
    };
    let client = match ipc.waypoints().and_then(|s| ipc.client(&s)) {
        Ok(c) => c,
        Err(e) => {
            return Outcome::Unreachable {
                message: e.to_string(),
            };
        }
    };
    set.seq = now_ns();
    set.stamp_ns = now_ns();
    let pending = match client.send_copy(set) {
        Ok(p) => p,
        Err(e) => {
            return Outcome::Unreachable {
                message: format!("sending the set: {e:?}"),
            };
        }
    };
    let reply = crate::poll(timeout, || pending.receive().ok().flatten().map(|r| *r));
    match reply {
        Some(r) if r.accepted == 1 => Outcome::Accepted { set_id: r.set_id },
        Some(r) => Outcome::Rejected {
            reason: r.reason().to_string(),
        },
        None => Outcome::Unreachable {
            message: crate::unreachable(namespace.as_str(), "the way-point set"),
        },
    }
}

/// `softarm submit FILE [--executions N] [--wait]`: checks, sends, prints the answer, and with
/// `wait` a table row per execution of the set as its stats arrive; the exit code.
/// `softarm submit FILE`: `text` is FILE as read by whoever submits it.
pub fn run(
    config: &Config,
    file: &std::path::Path,
    text: std::io::Result<String>,
    executions: u32,
    wait: bool,
) -> anyhow::Result<u8> {
    let namespace = &config.bus()?;
    let set = match prepare_read(config, file, text, executions) {
        Ok(s) => s,
        Err(reason) => {
            println!("rejected: {reason}");
            return Ok(Outcome::Rejected { reason }.exit_code());
        }
    };
    // Subscribed before sending, so no execution's stats can pass unseen.
    let follower = if wait {
        Some(stats::Stats::open(namespace)?)
    } else {
        None
    };
    let outcome = submit(namespace, set, Duration::from_secs(10));
    match &outcome {
        Outcome::Accepted { set_id } => println!("accepted: set {set_id}"),
        Outcome::Rejected { reason } => println!("rejected: {reason}"),
        Outcome::Unreachable { message } => eprintln!("softarm: {message}"),
    }
    if let (Some(f), Outcome::Accepted { set_id }) = (follower, &outcome) {
        // Validated: the duration and the rest are bounded by the config's limits.
        let limit = Duration::try_from_secs_f64(set.duration_s + config.controller.rest_s + 30.0)
            .context("the set's duration")?;
        follow(&f, *set_id, executions, set.count as usize, limit)?;
    }
    Ok(outcome.exit_code())
}

/// Prints the stats of `executions` executions of set `set_id` as they arrive; an error when
/// none arrives within `limit`.
fn follow(
    f: &stats::Stats,
    set_id: u64,
    executions: u32,
    points: usize,
    limit: Duration,
) -> anyhow::Result<()> {
    println!("{}", stats::table_header(points));
    let mut done = 0;
    while done < executions {
        let s = f.next(limit).ok_or_else(|| {
            anyhow!(
                "no stats arrived within {} s: is the stack still running?",
                limit.as_secs()
            )
        })?;
        if s.set_id == set_id {
            println!("{}", stats::table_row(&s));
            done += 1;
        }
    }
    Ok(())
}
