//! A throwaway stack (sim, controller, learner) in a namespace and a state folder of its own,
//! without a model (the controller runs IDLE, which is all the tick's timing needs):
//!
//! - the controller's tick wake-up latency, from its `status`, against a bare absolute-deadline
//!   loop run in this process at the same rate over the same window;
//! - tracker sample → setpoint → driver through the running controller;
//! - the resident memory of each process at the end of the window.
//!
//! The controller's latency histogram counts every tick since its first; `status` carries its
//! percentiles, which cannot be differenced. So the window is the controller's own: from its
//! first deadline (recovered from the statuses' tick counts and stamps) to the deadline of the
//! last status taken, `--seconds` later. The bare loop starts before the stack does, keeps every
//! wake with its deadline, and only the wakes whose deadlines fall in that window are counted.

use std::collections::VecDeque;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow, bail};
use hdrhistogram::Histogram;
use serde_json::{Value, json};
use softarm_config::{DEFAULT, Override};
use softarm_ipc::{ControllerState, ControllerStatus, Node, Sub};
use softarm_runtime::clock::Ticker;
use softarm_runtime::now_ns;

use super::{Out, Stats, duration, header, json_with, row};
use softarm_stack::sandbox::Sandbox;
use softarm_stack::supervisor::{self, Supervisor};

pub(super) struct Settings<'a> {
    pub config: Option<&'a Path>,
    pub rate_hz: Option<f64>,
    pub fifo: Option<i32>,
    pub seconds: f64,
    /// Setpoints to time end to end.
    pub setpoints: usize,
}

/// The JSON sections this part fills.
pub(super) struct StackRun {
    pub wakeup: Value,
    pub end_to_end: Value,
    pub rss_kib: Value,
}

const ROLES: [&str; 3] = ["sim", "controller", "learner"];

pub(super) fn run(s: &Settings, out: &Out, stop: &AtomicBool) -> anyhow::Result<StackRun> {
    let sandbox = sandbox_for(s)?;
    let config = &sandbox.config;
    let rate = config.controller.rate_hz;
    let priority = config.controller.realtime_priority;

    // Subscribed before anything publishes.
    let node = Node::open(sandbox.namespace.clone(), "bench")?;
    let status = node.subscriber(&node.status()?)?;

    // The bare loop first: its wakes must cover the controller's first deadline.
    let capacity = ((s.seconds + 120.0) * rate) as usize;
    let bare = BareLoop::start(rate, (priority > 0).then_some(priority), capacity)?;

    out.progress(&format!(
        "starting sim, controller and learner in namespace {}",
        sandbox.namespace.as_str()
    ));
    // The children's own warnings (no model yet) are expected here.
    let mut sup = sandbox.supervisor(&ROLES, "error")?;
    let window = Window::await_end(s, rate, out, &mut sup, &status, stop)?;
    let bare = bare.finish()?;
    let rss = rss(&sup);
    let wakeup = wakeup_section(&window, &bare, rate, out)?;
    let rss_kib = rss_section(&rss, out);

    out.progress(&format!(
        "timing {} setpoints end to end through the controller (busy-polling)",
        s.setpoints
    ));
    let (from_tracker, from_tick) = end_to_end(&node, s.setpoints, rate, stop)?;
    drop(status);
    out.progress("stopping the stack");
    sup.stop(Duration::from_secs(5));
    if !sup.pids().is_empty() {
        bail!("a process of the stack is still running");
    }
    let end_to_end = end_to_end_section(s, config, &from_tracker, &from_tick, out);
    Ok(StackRun {
        wakeup,
        end_to_end,
        rss_kib,
    })
}

/// The given (or embedded) config in the bench's own namespace, with its own state and no
/// model.
fn sandbox_for(s: &Settings) -> anyhow::Result<Sandbox> {
    let text = match s.config {
        Some(p) => {
            std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?
        }
        None => DEFAULT.to_string(),
    };
    let mut overrides: Vec<Override> = vec![("model.dir", "no-model".into())];
    if let Some(r) = s.rate_hz {
        overrides.push(("controller.rate_hz", r.into()));
    }
    if let Some(p) = s.fifo {
        overrides.push(("controller.realtime_priority", i64::from(p).into()));
    }
    Sandbox::for_command("bench", &text, &overrides)
}

/// The controller's timed window: from its first deadline to the deadline of the first status
/// whose tick ends `seconds` of periods.
struct Window {
    first_deadline: u64,
    last_deadline: u64,
    last: ControllerStatus,
    /// The controller's scheduling policy, as the kernel reports it.
    scheduling: String,
}

impl Window {
    /// Follows the controller's statuses until they cover the window; refused if the
    /// controller exits or restarts meanwhile.
    fn await_end(
        s: &Settings,
        rate: f64,
        out: &Out,
        sup: &mut Supervisor,
        status: &Sub<ControllerStatus>,
        stop: &AtomicBool,
    ) -> anyhow::Result<Self> {
        let period_ns = (1e9 / rate).round().max(1.0) as u64;
        let window_ns = (s.seconds * 1e9) as u64;
        let pid_of = |sup: &Supervisor| {
            sup.pids()
                .into_iter()
                .find(|(r, _)| r == "controller")
                .map(|(_, p)| p)
        };
        let controller_pid = pid_of(sup).context("the controller did not start")?;
        let mut first_deadline = u64::MAX;
        let mut last: Option<ControllerStatus> = None;
        let up_by = Instant::now() + Duration::from_secs(30);
        let mut scheduling = None;
        loop {
            if stop.load(Ordering::Relaxed) {
                bail!("interrupted");
            }
            sup.poll();
            if pid_of(sup) != Some(controller_pid) {
                bail!("the controller exited: its latency would not cover the window");
            }
            while let Ok(Some(sample)) = status.receive() {
                let st = *sample;
                if last.is_some_and(|l| st.ticks < l.ticks) {
                    bail!("the controller restarted: its latency would not cover the window");
                }
                // That tick's deadline is first + (ticks − 1 + overruns) periods, and it woke
                // less than a period after it: the smallest estimate is the closest.
                let index = (st.ticks.saturating_sub(1) + st.overruns).saturating_mul(period_ns);
                first_deadline = first_deadline.min(st.stamp_ns.saturating_sub(index));
                last = Some(st);
            }
            let Some(l) = last else {
                if Instant::now() > up_by {
                    bail!("the controller published no status within 30 s")
                }
                std::thread::sleep(Duration::from_millis(5));
                continue;
            };
            if scheduling.is_none() {
                scheduling = Some(scheduling_of(controller_pid));
                out.progress(&format!(
                    "controller up ({}); timing {} s of ticks beside the bare loop",
                    ControllerState::from_u32(l.state).map_or("?", |s| s.name()),
                    s.seconds
                ));
            }
            // Its tick's deadline is the last of the window: periods since the first.
            let covered = (l.ticks + l.overruns).saturating_mul(period_ns);
            if covered >= window_ns {
                return Ok(Self {
                    first_deadline,
                    last_deadline: first_deadline
                        + (l.ticks.saturating_sub(1) + l.overruns) * period_ns,
                    last: l,
                    scheduling: scheduling.unwrap_or_default(),
                });
            }
            if Instant::now() > up_by + Duration::from_secs_f64(s.seconds) {
                bail!("the controller's statuses stopped before the window's end");
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

/// The controller's tick wake-up beside the bare loop's over the same window: the table, and
/// its JSON section.
fn wakeup_section(w: &Window, bare: &Bare, rate: f64, out: &Out) -> anyhow::Result<Value> {
    let period_ns = (1e9 / rate).round().max(1.0) as u64;
    let last = &w.last;
    let controller = Stats::from_latency(&last.latency);
    let (bare_stats, bare_overruns) = bare.window(w.first_deadline, w.last_deadline)?;
    if bare.first_ns > w.first_deadline {
        bail!("the bare loop started after the controller's first tick");
    }
    let ratio: Vec<f64> = controller
        .values()
        .iter()
        .zip(bare_stats.values())
        .map(|(c, b)| *c as f64 / b.max(1) as f64)
        .collect();
    // Periods from the first deadline to the last, both included.
    let window_s = (w.last_deadline + period_ns - w.first_deadline) as f64 / 1e9;
    let state = ControllerState::from_u32(last.state).map_or("?", |s| s.name());
    let model = if last.model_loaded == 1 {
        "model loaded"
    } else {
        "no model"
    };
    const NOTE: &str = "the controller's latency histogram is cumulative since its first tick \
        and its status carries percentiles only, so the window is the controller's whole run: \
        from its first deadline to the deadline of the last status taken; the bare loop started \
        before the stack and only its wakes with deadlines in that window are counted; both \
        histograms 1 µs to 60 s at 2 significant digits, min and max exact";
    out.text(&header(&format!(
        "Tick wake-up latency at {rate} Hz over the same {window_s:.1} s window (controller {state}, \
         {model}; controller {}, bare loop {})",
        w.scheduling, bare.scheduling
    )));
    out.text(&row(
        "controller tick (its status, whole run)",
        &controller,
        &format!("  overruns {}", last.overruns),
    ));
    out.text(&row(
        "bare loop in this process, same window",
        &bare_stats,
        &format!("  overruns {bare_overruns}"),
    ));
    out.text(&format!(
        "{:<w$} {:>7} {}",
        "controller / bare",
        "",
        ratio
            .iter()
            .map(|r| format!("{:>10}", format!("×{r:.2}")))
            .collect::<Vec<_>>()
            .join(" "),
        w = super::NAME_WIDTH
    ));
    out.text(
        "(the controller's histogram counts every tick since its first, so the window is its \
         whole run,\n first deadline to the last status's; the bare loop, started before the \
         stack, counts its wakes in that window only)",
    );
    Ok(json!({
        "rate_hz": rate,
        "window_s": window_s,
        "window_start_ns": w.first_deadline,
        "window_end_ns": w.last_deadline,
        "window_note": NOTE,
        "controller_state": state,
        "model_loaded": last.model_loaded == 1,
        "controller": json_with(&controller, &[
            ("overruns", json!(last.overruns)),
            ("scheduling", json!(w.scheduling)),
        ]),
        "bare": json_with(&bare_stats, &[
            ("overruns", json!(bare_overruns)),
            ("scheduling", json!(bare.scheduling)),
        ]),
        "ratio": {
            "min": ratio[0], "p50": ratio[1], "p99": ratio[2], "p999": ratio[3], "max": ratio[4],
        },
    }))
}

/// Resident memory per process at the end of the window: the line, and its JSON section.
fn rss_section(rss: &[(String, u64)], out: &Out) -> Value {
    out.text(&format!(
        "\nResident memory (VmRSS) at the end of the window: {}",
        rss.iter()
            .map(|(r, kib)| format!("{r} {:.1} MiB", *kib as f64 / 1024.0))
            .collect::<Vec<_>>()
            .join(", ")
    ));
    Value::Object(rss.iter().map(|(r, kib)| (r.clone(), json!(kib))).collect())
}

/// Setpoints through the running controller: the table, and its JSON section.
fn end_to_end_section(
    s: &Settings,
    config: &softarm_config::Config,
    from_tracker: &Stats,
    from_tick: &Stats,
    out: &Out,
) -> Value {
    let rate = config.controller.rate_hz;
    out.text(&header(&format!(
        "Through the running controller, to a busy-polling subscriber in this process ({} \
         setpoints; tracker at {} Hz, io thread {} after each deadline)",
        s.setpoints,
        config.sim.rate_hz,
        duration(250_000u64.min((5e8 / rate) as u64)),
    )));
    out.text(&row(
        "tracker sample -> setpoint received",
        from_tracker,
        "",
    ));
    out.text(&row("setpoint stamp (tick) -> received", from_tick, ""));
    json!({
        "tracker_to_driver": from_tracker.json(),
        "setpoint_to_driver": from_tick.json(),
        "tracker_rate_hz": config.sim.rate_hz,
    })
}

/// One wake of the bare loop: its deadline, how late, periods skipped.
#[derive(Clone, Copy)]
struct Wake {
    deadline_ns: u64,
    latency_ns: u64,
    missed: u64,
}

/// What the bare loop saw.
struct Bare {
    first_ns: u64,
    wakes: Vec<Wake>,
    scheduling: String,
}

impl Bare {
    /// The wakes whose deadlines fall in [from, to], recorded as the controller records its own
    /// (1 µs to 60 s, 2 significant digits, min and max exact), and their skipped periods.
    fn window(&self, from: u64, to: u64) -> anyhow::Result<(Stats, u64)> {
        let mut h =
            Histogram::<u64>::new_with_bounds(1_000, 60_000_000_000, 2).expect("valid bounds");
        let (mut min, mut max, mut overruns) = (u64::MAX, 0, 0);
        for w in self
            .wakes
            .iter()
            .filter(|w| (from..=to).contains(&w.deadline_ns))
        {
            h.saturating_record(w.latency_ns);
            min = min.min(w.latency_ns);
            max = max.max(w.latency_ns);
            overruns += w.missed;
        }
        if h.is_empty() {
            bail!("the bare loop has no wake in the controller's window");
        }
        let at = |q: f64| h.value_at_quantile(q).clamp(min, max);
        let stats = Stats {
            n: h.len(),
            min,
            p50: at(0.5),
            p99: at(0.99),
            p999: at(0.999),
            max,
        };
        Ok((stats, overruns))
    }
}

/// The bare absolute-deadline loop on a thread of its own, as the controller's tick: a
/// [`Ticker`], and each wake kept with its deadline (in memory reserved before the loop).
struct BareLoop {
    /// The loop stops after its first wake for a deadline at or after this.
    end_ns: Arc<AtomicU64>,
    handle: Option<JoinHandle<Bare>>,
}

impl BareLoop {
    fn start(rate: f64, fifo: Option<i32>, capacity: usize) -> anyhow::Result<Self> {
        let end_ns = Arc::new(AtomicU64::new(u64::MAX));
        let end = end_ns.clone();
        let handle = std::thread::Builder::new()
            .name("bench-bare-loop".into())
            .spawn(move || {
                let scheduling = match fifo {
                    None => "normal".to_string(),
                    Some(p) => match super::set_fifo(p) {
                        Ok(()) => format!("SCHED_FIFO {p}"),
                        Err(_) => format!("normal (SCHED_FIFO {p} refused)"),
                    },
                };
                let period_ns = (1e9 / rate).round().max(1.0) as u64;
                let first_ns = now_ns() + period_ns;
                let mut ticker = Ticker::starting_at(rate, first_ns);
                let mut wakes = Vec::with_capacity(capacity);
                let mut index = 0;
                loop {
                    let deadline_ns = first_ns + index * period_ns;
                    let w = ticker.wait();
                    wakes.push(Wake {
                        deadline_ns,
                        latency_ns: w.latency_ns,
                        missed: w.missed,
                    });
                    index += 1 + w.missed;
                    if deadline_ns >= end.load(Ordering::Relaxed) || wakes.len() == capacity {
                        break;
                    }
                }
                Bare {
                    first_ns,
                    wakes,
                    scheduling,
                }
            })
            .context("starting the bare loop")?;
        Ok(Self {
            end_ns,
            handle: Some(handle),
        })
    }

    /// Stops the loop (at its next wake) and hands over what it saw.
    fn finish(mut self) -> anyhow::Result<Bare> {
        self.end_ns.store(0, Ordering::Relaxed);
        self.handle
            .take()
            .expect("joined once")
            .join()
            .map_err(|_| anyhow!("the bare loop panicked"))
    }
}

impl Drop for BareLoop {
    fn drop(&mut self) {
        self.end_ns.store(0, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// The tick thread's scheduling (the controller's main thread), from /proc.
fn scheduling_of(pid: u32) -> String {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command's closing parenthesis start at field 3; rt_priority is field 40,
    // policy field 41.
    let rest: Vec<&str> = stat
        .rsplit_once(')')
        .map_or(Vec::new(), |(_, r)| r.split_whitespace().collect());
    match (rest.get(40 - 3), rest.get(41 - 3)) {
        (Some(prio), Some(&"1")) => format!("SCHED_FIFO {prio}"),
        (Some(prio), Some(&"2")) => format!("SCHED_RR {prio}"),
        (_, Some(_)) => "normal".into(),
        _ => "unknown".into(),
    }
}

/// VmRSS (KiB) of each process of the stack, and of this one.
fn rss(sup: &Supervisor) -> Vec<(String, u64)> {
    let mut out: Vec<(String, u64)> = sup
        .pids()
        .into_iter()
        .filter_map(|(role, pid)| Some((role, supervisor::rss_kib(&pid.to_string())?)))
        .collect();
    out.sort_by_key(|(role, _)| ROLES.iter().position(|r| r == role));
    if let Some(kib) = supervisor::rss_kib("self") {
        out.push(("bench".into(), kib));
    }
    out
}

/// Busy-polls `tracker` and `setpoint` until `n` setpoints were timed: for each, receive time −
/// the stamp of the newest tracker sample the controller could have used (stamped at or before
/// the setpoint), and receive time − the setpoint's own stamp (the tick's wake-up).
fn end_to_end(
    node: &Node,
    n: usize,
    rate: f64,
    stop: &AtomicBool,
) -> anyhow::Result<(Stats, Stats)> {
    let tracker = node.subscriber(&node.tracker()?)?;
    let setpoint = node.subscriber(&node.setpoint()?)?;
    // What history handed over is old.
    while let Ok(Some(_)) = tracker.receive() {}
    while let Ok(Some(_)) = setpoint.receive() {}
    let mut from_tracker = super::histogram();
    let mut from_tick = super::histogram();
    // Tracker stamps, oldest first; setpoints waiting for a newer tracker sample (until one
    // arrives, a sample stamped before the setpoint may still be on its way).
    let mut stamps: VecDeque<u64> = VecDeque::with_capacity(64);
    let mut pending: VecDeque<(u64, u64)> = VecDeque::with_capacity(64);
    let limit = Instant::now() + Duration::from_secs_f64(n as f64 / rate + 15.0);
    let mut last_setpoint = Instant::now();
    let mut spins = 0u64;
    while (from_tracker.len() as usize) < n {
        while let Ok(Some(t)) = tracker.receive() {
            if stamps.len() == stamps.capacity() {
                stamps.pop_front();
            }
            stamps.push_back(t.stamp_ns);
        }
        while let Ok(Some(s)) = setpoint.receive() {
            let now = now_ns();
            from_tick.saturating_record(now.saturating_sub(s.stamp_ns).max(1));
            if pending.len() == pending.capacity() {
                pending.pop_front();
            }
            pending.push_back((s.stamp_ns, now));
            last_setpoint = Instant::now();
        }
        while let (Some(&(stamp, received)), Some(&newest)) = (pending.front(), stamps.back()) {
            if newest <= stamp {
                break;
            }
            pending.pop_front();
            if let Some(used) = stamps.iter().rev().find(|t| **t <= stamp) {
                from_tracker.saturating_record(received.saturating_sub(*used).max(1));
            }
        }
        spins += 1;
        if spins.is_multiple_of(4096) {
            if stop.load(Ordering::Relaxed) {
                bail!("interrupted");
            }
            let now = Instant::now();
            if now > limit || now - last_setpoint > Duration::from_secs(3) {
                break;
            }
        }
        std::hint::spin_loop();
    }
    match (Stats::of(&from_tracker), Stats::of(&from_tick)) {
        (Some(a), Some(b)) => Ok((a, b)),
        _ => bail!("no setpoint with its tracker sample arrived from the controller"),
    }
}
