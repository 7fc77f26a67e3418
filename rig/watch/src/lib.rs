//! `Watch`: an independent subscriber of `setpoint`, `stats` and `estop` that checks, sample by
//! sample, what a person beside the arm relies on, whatever happens to the processes:
//!
//! - every setpoint within the actuator limits;
//! - no step faster than the slew limit within one controller's stream, and across a restart
//!   (a new controller starts its sequence again) no jump; leaving STOPPED, where the controller
//!   restarts from the measured state on purpose, no jump from where the motors are;
//! - while a driver is surely gone (an outage its caller declares), nothing executed on its
//!   stale data from twice the stale age on, and HOLD said;
//! - once an e-stop is engaged, only STOPPED setpoints until it is reset, across restarts;
//! - no execution's statistics twice, and none lost: a set's executions arrive as 1, 2, 3, ...
//!
//! The rules are in [`Checker`], pure and unit-tested; [`Watch`] feeds it from a thread of its
//! own. Memory stays bounded over hours: only the last setpoint and the execution counts per
//! set are kept.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use softarm_config::Config;
use softarm_ipc::{
    Actuators, ControllerState, EstopState, ExecutionStats, MotorState, Namespace, Node, Setpoint,
};
use softarm_runtime::now_ns;

/// The limits the invariants are checked against: the config's.
#[derive(Debug, Clone)]
pub struct Limits {
    /// One per actuator of the arm.
    pub actuator_min: Vec<f64>,
    pub actuator_max: Vec<f64>,
    /// Normalised units per second.
    pub slew_per_s: f64,
    /// The controller's period (s): one tick of slack for the limiter's own discretisation.
    pub period_s: f64,
    /// Tracker data older than this puts the controller in HOLD.
    pub stale_ns: u64,
    /// The largest step across a controller restart from the last setpoint, and leaving
    /// STOPPED from the measured state: the controller starts from the measured state, which
    /// backlash and lag leave this close to the last setpoint.
    pub restart_step: f64,
}

impl Limits {
    pub fn from_config(c: &Config) -> Self {
        Self {
            actuator_min: c
                .controller
                .actuator_min
                .values(c.layout().actuators().len()),
            actuator_max: c
                .controller
                .actuator_max
                .values(c.layout().actuators().len()),
            slew_per_s: c.controller.slew_per_s,
            period_s: 1.0 / c.controller.rate_hz,
            stale_ns: (c.controller.tracker_timeout_ms * 1e6) as u64,
            restart_step: 0.02,
        }
    }
}

/// What was checked, and what broke.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Report {
    pub setpoints: u64,
    /// Controller runs the setpoints came from (1 + restarts seen).
    pub streams: u64,
    /// Executions whose statistics arrived, and the sets they belong to.
    pub executions: u64,
    pub sets: u64,
    /// Outages declared and e-stops seen, each checked.
    pub outages: u64,
    pub estops: u64,
    /// Broken invariants: the count, and the first few said in words.
    pub violations: u64,
    pub messages: Vec<String>,
}

/// How many violations are described; the rest are only counted.
const MESSAGES: usize = 20;

#[derive(Debug, Clone, Copy)]
struct Outage {
    from_ns: u64,
    to_ns: u64,
    hold_seen: bool,
}

/// The invariants, fed one sample at a time.
#[derive(Debug)]
pub struct Checker {
    limits: Limits,
    last: Option<Setpoint>,
    /// Where the motors are, as the driver last said.
    measured: Option<Actuators>,
    outages: Vec<Outage>,
    /// Since when the e-stop is engaged (its stamp), if it is.
    estop_since: Option<u64>,
    /// Per set, the executions whose statistics arrived.
    executions: BTreeMap<u64, Vec<u32>>,
    /// Time between consecutive setpoints of one controller both in EXECUTE (ns): how long an
    /// execution has been playing, HOLD's pauses left out.
    executing_ns: u64,
    report: Report,
}

impl Checker {
    pub fn new(limits: Limits) -> Self {
        Self {
            limits,
            last: None,
            measured: None,
            outages: Vec::new(),
            estop_since: None,
            executions: BTreeMap::new(),
            executing_ns: 0,
            report: Report {
                streams: 0,
                ..Report::default()
            },
        }
    }

    fn violation(&mut self, message: String) {
        self.report.violations += 1;
        if self.report.messages.len() < MESSAGES {
            self.report.messages.push(message);
        }
    }

    /// The tracker or a driver is surely gone from `from_ns` to `to_ns` (killed, stopped): to
    /// be declared before setpoints from that window arrive.
    pub fn outage(&mut self, from_ns: u64, to_ns: u64) {
        self.report.outages += 1;
        self.outages.push(Outage {
            from_ns,
            to_ns,
            hold_seen: false,
        });
    }

    pub fn estop(&mut self, e: &EstopState) {
        if e.engaged != 0 {
            self.report.estops += 1;
            self.estop_since.get_or_insert(e.stamp_ns);
        } else {
            self.estop_since = None;
        }
    }

    pub fn motors(&mut self, m: &MotorState) {
        if m.actuation.iter().all(|v| v.is_finite()) {
            self.measured = Some(m.actuation);
        }
    }

    pub fn setpoint(&mut self, p: &Setpoint) {
        let l = self.limits.clone();
        self.report.setpoints += 1;
        if p.actuation.len() != l.actuator_min.len() {
            self.violation(format!(
                "a setpoint of {} actuators on an arm of {} (seq {})",
                p.actuation.len(),
                l.actuator_min.len(),
                p.seq
            ));
            return;
        }
        for a in 0..p.actuation.len() {
            let v = p.actuation[a];
            // A hair of slack for the limits' own rounding.
            if !(v >= l.actuator_min[a] - 1e-9 && v <= l.actuator_max[a] + 1e-9) {
                self.violation(format!(
                    "actuator {a}: setpoint {v} outside [{}, {}] (seq {})",
                    l.actuator_min[a], l.actuator_max[a], p.seq
                ));
            }
        }
        let restarted = self.last.is_none_or(|last| p.seq <= last.seq);
        if restarted {
            self.report.streams += 1;
        }
        let stopped = ControllerState::Stopped as u32;
        if let Some(last) = self.last {
            let dt = p.stamp_ns.saturating_sub(last.stamp_ns) as f64 * 1e-9;
            // Leaving STOPPED the controller starts again from where the motors are (no driver
            // followed the stopped setpoints): no jump from there. Unknown where: unchecked.
            let (from, allowed, how) = if last.state == stopped && p.state != stopped {
                match self.measured {
                    Some(m) => (m, l.restart_step, ", from the motors, leaving STOPPED"),
                    None => (p.actuation, f64::INFINITY, ""),
                }
            } else if restarted {
                (
                    last.actuation,
                    l.restart_step,
                    ", across a controller restart",
                )
            } else {
                let slew = l.slew_per_s * (dt + l.period_s) + 1e-9;
                (last.actuation, slew, "")
            };
            for a in 0..p.actuation.len() {
                let step = (p.actuation[a] - from[a]).abs();
                if step > allowed {
                    self.violation(format!(
                        "actuator {a} stepped {step:.4} in {:.1} ms (allowed {allowed:.4}{how}) \
                         at seq {}",
                        dt * 1e3,
                        p.seq
                    ));
                }
            }
        }
        let execute = p.state == ControllerState::Execute as u32;
        if let Some(last) = self.last
            && !restarted
            && execute
            && last.state == ControllerState::Execute as u32
        {
            self.executing_ns += p.stamp_ns.saturating_sub(last.stamp_ns);
        }
        self.last = Some(*p);

        let hold = p.state == ControllerState::Hold as u32;
        let mut closed = Vec::new();
        for (i, o) in self.outages.iter_mut().enumerate() {
            if p.stamp_ns >= o.to_ns {
                closed.push(i);
            } else if p.stamp_ns > o.from_ns {
                o.hold_seen |= hold;
            }
        }
        for &i in closed.iter().rev() {
            let o = self.outages.remove(i);
            if !o.hold_seen {
                self.violation(format!(
                    "no HOLD while a driver was gone ({:.2} s from {})",
                    (o.to_ns - o.from_ns) as f64 * 1e-9,
                    o.from_ns
                ));
            }
        }
        let stale_from = |o: &Outage| o.from_ns + 2 * self.limits.stale_ns;
        if execute
            && let Some(o) = self
                .outages
                .iter()
                .find(|o| p.stamp_ns >= stale_from(o) && p.stamp_ns < o.to_ns)
        {
            let late = p.stamp_ns - o.from_ns;
            self.violation(format!(
                "executed {:.0} ms after a driver went (stale age {:.0} ms, seq {})",
                late as f64 * 1e-6,
                self.limits.stale_ns as f64 * 1e-6,
                p.seq
            ));
        }
        // The controller hears the e-stop within a tick; a restarted one reads the latch before
        // its first tick. Twice the stale age is more than either needs on a loaded machine.
        if let Some(since) = self.estop_since
            && p.stamp_ns > since + 2 * self.limits.stale_ns
            && p.state != ControllerState::Stopped as u32
        {
            self.violation(format!(
                "state {} {:.0} ms after the e-stop (seq {})",
                ControllerState::from_u32(p.state).map_or("unknown", ControllerState::name),
                (p.stamp_ns - since) as f64 * 1e-6,
                p.seq
            ));
        }
    }

    pub fn stats(&mut self, s: &ExecutionStats) {
        let seen = self.executions.entry(s.set_id).or_default();
        if seen.contains(&s.execution) {
            let (set, execution) = (s.set_id, s.execution);
            self.violation(format!(
                "statistics of set {set} execution {execution} twice"
            ));
            return;
        }
        seen.push(s.execution);
        self.report.executions += 1;
    }

    /// Executions of `set` whose statistics arrived.
    pub fn executions_of(&self, set: u64) -> usize {
        self.executions.get(&set).map_or(0, Vec::len)
    }

    /// How long the controller has been executing, by its setpoints' stamps: the time between
    /// two consecutive setpoints of one controller both in EXECUTE, summed (HOLD, STOPPED and
    /// a restart count nothing).
    pub fn executing(&self) -> std::time::Duration {
        std::time::Duration::from_nanos(self.executing_ns)
    }

    /// The report, with the checks that need the whole run: no set's statistics lost.
    pub fn report(&self) -> Report {
        let mut checked = Checker {
            limits: self.limits.clone(),
            last: None,
            measured: None,
            outages: Vec::new(),
            estop_since: None,
            executions: BTreeMap::new(),
            executing_ns: self.executing_ns,
            report: self.report.clone(),
        };
        for (set, seen) in &self.executions {
            let mut sorted = seen.clone();
            sorted.sort_unstable();
            // A set's executions are numbered from 1; one that finished reports before the next
            // starts, so any gap is a lost one.
            if let Some(missing) =
                (1..=sorted.last().copied().unwrap_or(0)).find(|e| sorted.binary_search(e).is_err())
            {
                checked.violation(format!(
                    "set {set}: statistics of execution {missing} lost (have {sorted:?})"
                ));
            }
        }
        checked.report.sets = self.executions.len() as u64;
        checked.report
    }
}

/// A [`Checker`] fed by a thread of its own from the stack's services.
pub struct Watch {
    checker: Arc<Mutex<Checker>>,
    done: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Watch {
    /// Subscribes at once (nothing published after this returns is missed), then watches until
    /// [`Watch::finish`].
    pub fn start(namespace: &Namespace, limits: Limits) -> anyhow::Result<Self> {
        let checker = Arc::new(Mutex::new(Checker::new(limits)));
        let done = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let thread = {
            let (checker, done, namespace) = (checker.clone(), done.clone(), namespace.clone());
            std::thread::spawn(move || {
                let ports = (|| -> anyhow::Result<_> {
                    let node = Node::open(namespace, "watch")?;
                    let setpoints = node.subscriber(&node.setpoint()?)?;
                    let stats = node.subscriber(&node.stats()?)?;
                    let estop = node.subscriber(&node.estop()?)?;
                    let motors = node.subscriber(&node.motor_state()?)?;
                    Ok((node, setpoints, stats, estop, motors))
                })();
                let (_node, setpoints, stats, estop, motors) = match ports {
                    Ok(p) => {
                        let _ = ready_tx.send(Ok(()));
                        p
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                // Setpoints stamped after the e-stop drain began wait for the next round, so an
                // e-stop is always applied before the setpoints that came after it.
                let mut pending: Vec<Setpoint> = Vec::with_capacity(4096);
                while !done.load(Ordering::Relaxed) {
                    let round = now_ns();
                    let mut c = lock(&checker);
                    while let Ok(Some(e)) = estop.receive() {
                        c.estop(&e);
                    }
                    while let Ok(Some(m)) = motors.receive() {
                        c.motors(&m);
                    }
                    pending.retain(|p| {
                        let now = p.stamp_ns <= round;
                        if now {
                            c.setpoint(p);
                        }
                        !now
                    });
                    while let Ok(Some(p)) = setpoints.receive() {
                        if p.stamp_ns <= round && pending.is_empty() {
                            c.setpoint(&p);
                        } else {
                            pending.push(*p);
                        }
                    }
                    while let Ok(Some(s)) = stats.receive() {
                        c.stats(&s);
                    }
                    drop(c);
                    std::thread::sleep(Duration::from_micros(500));
                }
                let mut c = lock(&checker);
                for p in &pending {
                    c.setpoint(p);
                }
            })
        };
        ready_rx
            .recv()
            .map_err(|_| anyhow::anyhow!("the watch thread ended before subscribing"))??;
        Ok(Self {
            checker,
            done,
            thread: Some(thread),
        })
    }

    /// See [`Checker::outage`].
    pub fn outage(&self, from_ns: u64, to_ns: u64) {
        lock(&self.checker).outage(from_ns, to_ns);
    }

    pub fn executions_of(&self, set: u64) -> usize {
        lock(&self.checker).executions_of(set)
    }

    /// [`Checker::executing`] of what the watch has seen so far.
    pub fn executing(&self) -> std::time::Duration {
        lock(&self.checker).executing()
    }

    /// The report so far.
    pub fn report(&self) -> Report {
        lock(&self.checker).report()
    }

    /// Stops watching; the report over everything seen.
    pub fn finish(mut self) -> Report {
        self.done.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        lock(&self.checker).report()
    }
}

impl Drop for Watch {
    fn drop(&mut self) {
        self.done.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A panic elsewhere while holding the lock leaves the checker as consistent as any sample
/// boundary: go on with it.
fn lock(m: &Mutex<Checker>) -> MutexGuard<'_, Checker> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn limits() -> Limits {
        Limits {
            actuator_min: vec![0.0; 6],
            actuator_max: vec![1.0; 6],
            slew_per_s: 1.5,
            period_s: 0.002,
            stale_ns: 100 * MS,
            restart_step: 0.02,
        }
    }

    fn at(seq: u64, t_ms: u64, v: f64, state: ControllerState) -> Setpoint {
        Setpoint {
            seq,
            stamp_ns: 1_000_000 * MS + t_ms * MS,
            actuation: [v; 6].into(),
            state: state as u32,
            ..Default::default()
        }
    }

    fn run(points: &[Setpoint], before: impl FnOnce(&mut Checker)) -> Report {
        let mut c = Checker::new(limits());
        before(&mut c);
        for p in points {
            c.setpoint(p);
        }
        c.report()
    }

    #[test]
    fn a_smooth_stream_and_a_restart_close_by_break_nothing() {
        use ControllerState::*;
        let mut v = Vec::new();
        for i in 0..100 {
            v.push(at(i + 1, 2 * i, 0.5 + 0.002 * i as f64, Execute));
        }
        // A new controller: its sequence starts again, 0.01 away.
        v.push(at(1, 1000, 0.698 + 0.01, Idle));
        let r = run(&v, |_| {});
        assert_eq!(r.violations, 0, "{:?}", r.messages);
        assert_eq!((r.setpoints, r.streams), (101, 2));
    }

    #[test]
    fn limits_slew_and_restart_jumps_are_violations() {
        use ControllerState::*;
        let out = run(&[at(1, 0, 1.2, Execute)], |_| {});
        assert_eq!(out.violations, 6, "{:?}", out.messages);
        assert!(out.messages[0].contains("outside"), "{:?}", out.messages);
        let nan = run(&[at(1, 0, f64::NAN, Execute)], |_| {});
        assert_eq!(nan.violations, 6);
        // 0.006 allowed in 2 ms (with a tick of slack); 0.01 is not.
        let slew = run(&[at(1, 0, 0.5, Execute), at(2, 2, 0.51, Execute)], |_| {});
        assert_eq!(slew.violations, 6, "{:?}", slew.messages);
        assert!(slew.messages[0].contains("stepped"));
        let jump = run(&[at(5, 0, 0.5, Execute), at(1, 2, 0.53, Idle)], |_| {});
        assert_eq!(jump.violations, 6);
        assert!(jump.messages[0].contains("restart"), "{:?}", jump.messages);
    }

    #[test]
    fn an_outage_needs_a_hold_and_no_execution_on_stale_data() {
        use ControllerState::*;
        let t0 = 1_000_000 * MS;
        let gone = |c: &mut Checker| c.outage(t0 + 100 * MS, t0 + 900 * MS);
        // Executing up to twice the stale age after the driver went, then HOLD: fine.
        let good = run(
            &[
                at(1, 100, 0.5, Execute),
                at(2, 250, 0.5, Execute),
                at(3, 300, 0.5, Hold),
                at(4, 950, 0.5, Execute),
            ],
            gone,
        );
        assert_eq!(good.violations, 0, "{:?}", good.messages);
        let executed = run(
            &[
                at(1, 250, 0.5, Hold),
                at(2, 350, 0.5, Execute),
                at(3, 950, 0.5, Execute),
            ],
            gone,
        );
        assert_eq!(executed.violations, 1, "{:?}", executed.messages);
        let no_hold = run(&[at(1, 300, 0.5, Idle), at(2, 950, 0.5, Idle)], gone);
        assert_eq!(no_hold.violations, 1, "{:?}", no_hold.messages);
        assert!(no_hold.messages[0].contains("no HOLD"));
    }

    #[test]
    fn only_stopped_setpoints_while_the_estop_is_engaged() {
        use ControllerState::*;
        let t0 = 1_000_000 * MS;
        let estop = |engaged: u32, t_ms: u64| EstopState {
            stamp_ns: t0 + t_ms * MS,
            engaged,
            ..Default::default()
        };
        let mut c = Checker::new(limits());
        c.setpoint(&at(1, 0, 0.5, Execute));
        c.estop(&estop(1, 10));
        c.setpoint(&at(2, 20, 0.5, Execute)); // the controller has a moment to hear it
        c.setpoint(&at(3, 300, 0.5, Stopped));
        c.setpoint(&at(1, 400, 0.5, Stopped)); // restarted, still stopped
        assert_eq!(c.report().violations, 0, "{:?}", c.report().messages);
        c.setpoint(&at(2, 500, 0.5, Idle)); // restarted and forgot the latch
        assert_eq!(c.report().violations, 1);
        c.estop(&estop(0, 600));
        c.setpoint(&at(3, 700, 0.5, Idle));
        assert_eq!(c.report().violations, 1);
        assert_eq!(c.report().estops, 1);
    }

    #[test]
    fn leaving_stopped_starts_from_the_motors_not_from_the_held_setpoint() {
        use ControllerState::*;
        let motors = |v: f64| MotorState {
            actuation: [v; 6].into(),
            ..Default::default()
        };
        let mut c = Checker::new(limits());
        c.setpoint(&at(1, 0, 0.5, Stopped));
        c.motors(&motors(0.45));
        // The reset: from the motors (0.45), 0.05 from the held setpoint.
        c.setpoint(&at(2, 2, 0.451, Idle));
        assert_eq!(c.report().violations, 0, "{:?}", c.report().messages);
        // Anywhere else is a jump.
        c.setpoint(&at(3, 4, 0.451, Stopped));
        c.setpoint(&at(4, 6, 0.48, Idle));
        let r = c.report();
        assert_eq!(r.violations, 6, "{:?}", r.messages);
        assert!(
            r.messages[0].contains("leaving STOPPED"),
            "{:?}",
            r.messages
        );
    }

    #[test]
    fn statistics_twice_or_lost_are_violations() {
        let s = |set_id, execution| ExecutionStats {
            set_id,
            execution,
            ..Default::default()
        };
        let mut c = Checker::new(limits());
        for (set, e) in [(7, 1), (7, 2), (8, 1), (7, 3)] {
            c.stats(&s(set, e));
        }
        let r = c.report();
        assert_eq!((r.violations, r.executions, r.sets), (0, 4, 2));
        assert_eq!(c.executions_of(7), 3);
        c.stats(&s(7, 3));
        assert_eq!(c.report().violations, 1);
        c.stats(&s(8, 3));
        let r = c.report();
        assert_eq!(r.violations, 2, "{:?}", r.messages);
        assert!(
            r.messages[1].contains("execution 2 lost"),
            "{:?}",
            r.messages
        );
    }

    /// Executing time is what the setpoints say: HOLD pauses it, a restart adds nothing.
    #[test]
    fn executing_time_counts_consecutive_execute_setpoints_alone() {
        use ControllerState::{Execute, Hold};
        let mut c = Checker::new(limits());
        for p in [
            at(1, 0, 0.5, Execute),
            at(2, 10, 0.5, Execute),
            at(3, 20, 0.5, Hold),
            at(4, 1_020, 0.5, Hold),
            at(5, 1_030, 0.5, Execute),
            at(6, 1_050, 0.5, Execute),
            // A restarted controller: its first setpoint is not the last one's successor.
            at(1, 1_060, 0.5, Execute),
            at(2, 1_064, 0.5, Execute),
        ] {
            c.setpoint(&p);
        }
        assert_eq!(c.executing(), std::time::Duration::from_millis(10 + 20 + 4));
    }
}
