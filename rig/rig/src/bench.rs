//! `softarm-rig bench`: what the stack costs on this machine, as percentiles. By default, in one
//! run (about 30 s):
//!
//! - the controller's tick wake-up latency on a throwaway stack (sim, controller, learner in a
//!   namespace of its own), against a bare absolute-deadline loop in this process at the same
//!   rate over the same window ([`stack`]);
//! - tracker sample → setpoint → driver, end to end through that running controller ([`stack`]);
//! - the resident memory of each of its processes ([`stack`]);
//! - setpoint-sized messages from another process: iceoryx2 busy-polled, iceoryx2 woken by an
//!   iceoryx2 event, and a Unix-domain socket ([`ipc`]);
//! - single calls of the hot paths: the Eq. 11 tick, a re-conditioning, a CACLA-MTL update, the
//!   forward models ([`calls`]).
//!
//! `--wakeup SECONDS` runs the bare loop alone. Everything timed is recorded in hdrhistogram.

use std::path::PathBuf;

use hdrhistogram::Histogram;
use serde_json::{Value, json};
use softarm_config::Config;

mod calls;
mod ipc;
mod stack;

#[derive(clap::Args)]
pub struct Args {
    /// The window over which the controller's and the bare loop's wake-up latency are compared
    /// (s).
    #[arg(long, default_value_t = 15.0, allow_negative_numbers = true)]
    seconds: f64,
    /// Messages per variant of the process-to-process test, and setpoints timed end to end
    /// through the controller.
    #[arg(long, default_value_t = 3000, allow_negative_numbers = true)]
    samples: usize,
    /// The rate of the process-to-process messages.
    #[arg(long, default_value_t = 2000.0, allow_negative_numbers = true)]
    ipc_rate_hz: f64,
    /// Eq. 11 ticks to time (also bounds the CACLA-MTL updates and forward-model calls timed,
    /// 100,000 at most each).
    #[arg(long, default_value_t = 200_000, allow_negative_numbers = true)]
    ticks: usize,
    /// Re-conditionings to time.
    #[arg(long, default_value_t = 50, allow_negative_numbers = true)]
    reconditions: usize,
    /// One JSON object on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// The config whose controller is timed (default: the embedded simulation config). Its
    /// stack runs in a namespace and a state folder of its own, without a model.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Instead of everything else: the bare loop alone (absolute deadlines with
    /// clock_nanosleep, as the controller's tick) for this many seconds, and its wake-up
    /// latency. Run it beside a running stack to see what the controller's own latency
    /// (`softarm status`) adds.
    #[arg(long, value_name = "SECONDS", allow_negative_numbers = true)]
    wakeup: Option<f64>,
    /// The loop rate: the bare loop's with --wakeup, else the stack's controller.rate_hz
    /// (default: the config's).
    #[arg(long, allow_negative_numbers = true)]
    rate_hz: Option<f64>,
    /// SCHED_FIFO at this priority (needs CAP_SYS_NICE) for the bare loop, and in the full run
    /// for the controller's tick too (controller.realtime_priority). Without it both run as the
    /// config says.
    #[arg(long, value_name = "PRIORITY", allow_negative_numbers = true)]
    fifo: Option<i32>,
    /// The other end of the process-to-process test (internal): its namespace.
    #[arg(long, hide = true, requires = "peer_socket")]
    peer: Option<String>,
    /// The other end's Unix-domain socket (internal).
    #[arg(long, hide = true)]
    peer_socket: Option<PathBuf>,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    if let (Some(ns), Some(socket)) = (&args.peer, &args.peer_socket) {
        return ipc::peer(ns, socket, args.samples, args.ipc_rate_hz);
    }
    let config = match &args.config {
        Some(p) => Config::load(p)?,
        None => Config::default_sim(PathBuf::from(".")),
    };
    if let Some(seconds) = args.wakeup {
        let rate = args.rate_hz.unwrap_or(config.controller.rate_hz);
        return wakeup(seconds, rate, args.fifo, args.json);
    }
    full(args)
}

/// Everything: the stack, the messages, the calls.
fn full(args: &Args) -> anyhow::Result<()> {
    if !(args.seconds.is_finite() && args.seconds >= 1.0 && args.seconds <= 600.0) {
        anyhow::bail!("--seconds must be in [1, 600]");
    }
    if !(1..=1_000_000).contains(&args.samples) {
        anyhow::bail!("--samples must be in [1, 1000000]");
    }
    if !(args.ipc_rate_hz.is_finite() && (10.0..=20_000.0).contains(&args.ipc_rate_hz)) {
        anyhow::bail!("--ipc-rate-hz must be in [10, 20000]");
    }
    if args.ticks == 0 || args.reconditions == 0 {
        anyhow::bail!("--ticks and --reconditions must be > 0");
    }
    // The config's ranges, said here for the flags rather than for the bench's own config.
    if let Some(r) = args.rate_hz
        && !(10.0..=1000.0).contains(&r)
    {
        anyhow::bail!("--rate-hz must be in [10, 1000] (controller.rate_hz), got {r}");
    }
    if let Some(p) = args.fifo
        && !(1..=99).contains(&p)
    {
        anyhow::bail!("--fifo must be a SCHED_FIFO priority in [1, 99], got {p}");
    }
    let started = std::time::Instant::now();
    let stop = softarm_runtime::stop_flag()?;
    let out = Out { json: args.json };
    let machine = machine();
    out.text(&machine_text(&machine));

    let run = stack::run(
        &stack::Settings {
            config: args.config.as_deref(),
            rate_hz: args.rate_hz,
            fifo: args.fifo,
            seconds: args.seconds,
            setpoints: args.samples,
        },
        &out,
        &stop,
    )?;
    let messages = ipc::run(args.samples, args.ipc_rate_hz, &out, &stop)?;
    let calls = calls::run(args.ticks, args.reconditions, &out, &stop)?;

    let elapsed = started.elapsed().as_secs_f64();
    out.text(&format!("\n{elapsed:.0} s in all"));
    if args.json {
        let mut doc = json!({
            "machine": machine,
            "elapsed_s": elapsed,
        });
        let o = doc.as_object_mut().expect("an object");
        o.insert("wakeup".into(), run.wakeup);
        o.insert("end_to_end".into(), run.end_to_end);
        o.insert("rss_kib".into(), run.rss_kib);
        o.insert("ipc".into(), messages);
        o.insert("calls".into(), calls);
        println!("{doc}");
    }
    Ok(())
}

/// Where the text goes: the table on stdout, nothing with `--json`.
pub(crate) struct Out {
    json: bool,
}

impl Out {
    fn text(&self, s: &str) {
        if !self.json {
            println!("{s}");
        }
    }

    /// What is happening, on stderr, while it happens.
    fn progress(&self, s: &str) {
        if !self.json {
            eprintln!("softarm-rig bench: {s}");
        }
    }
}

/// Min / p50 / p99 / p99.9 / max of a histogram of durations (ns), and the count.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Stats {
    pub n: u64,
    pub min: u64,
    pub p50: u64,
    pub p99: u64,
    pub p999: u64,
    pub max: u64,
}

impl Stats {
    /// Quantiles to the histogram's resolution, kept within its min and max. `None` if empty.
    fn of(h: &Histogram<u64>) -> Option<Self> {
        if h.is_empty() {
            return None;
        }
        let (min, max) = (h.min(), h.max());
        let at = |q: f64| h.value_at_quantile(q).clamp(min, max);
        Some(Self {
            n: h.len(),
            min,
            p50: at(0.5),
            p99: at(0.99),
            p999: at(0.999),
            max,
        })
    }

    /// The same figures as `ControllerStatus.latency` carries them.
    fn from_latency(l: &softarm_ipc::Latency) -> Self {
        Self {
            n: l.samples,
            min: l.min_ns,
            p50: l.p50_ns,
            p99: l.p99_ns,
            p999: l.p999_ns,
            max: l.max_ns,
        }
    }

    fn values(&self) -> [u64; 5] {
        [self.min, self.p50, self.p99, self.p999, self.max]
    }

    fn json(&self) -> Value {
        json!({
            "n": self.n,
            "min_ns": self.min,
            "p50_ns": self.p50,
            "p99_ns": self.p99,
            "p999_ns": self.p999,
            "max_ns": self.max,
        })
    }
}

/// `Stats::json` with more fields.
fn json_with(s: &Stats, extra: &[(&str, Value)]) -> Value {
    let mut v = s.json();
    let o = v.as_object_mut().expect("an object");
    for (k, x) in extra {
        o.insert((*k).to_string(), x.clone());
    }
    v
}

/// An empty histogram of durations from 1 ns to an hour, in ns, to 3 significant digits.
fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 3_600_000_000_000, 3).expect("valid bounds")
}

/// Records `start.elapsed()` (beyond the bounds: clamped to them).
fn record(ns: &mut Histogram<u64>, start: std::time::Instant) {
    let v = u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
    ns.saturating_record(v.max(1));
}

/// A duration in ns, to three digits.
fn duration(v: u64) -> String {
    if v >= 1_000_000 {
        format!("{:.2} ms", v as f64 / 1e6)
    } else if v >= 1_000 {
        format!("{:.2} µs", v as f64 / 1e3)
    } else {
        format!("{v} ns")
    }
}

const NAME_WIDTH: usize = 44;

/// The column heads of a section's rows.
fn header(title: &str) -> String {
    format!(
        "\n{title}\n{:<NAME_WIDTH$} {:>7} {:>10} {:>10} {:>10} {:>10} {:>10}",
        "", "n", "min", "p50", "p99", "p99.9", "max"
    )
}

/// One row: a name, the count and the five figures; `tail` after them.
fn row(name: &str, s: &Stats, tail: &str) -> String {
    let v = s.values().map(duration);
    format!(
        "{name:<NAME_WIDTH$} {:>7} {:>10} {:>10} {:>10} {:>10} {:>10}{tail}",
        s.n, v[0], v[1], v[2], v[3], v[4]
    )
}

/// The machine the figures were taken on: cores, kernel, CPU model, load when the run began.
fn machine() -> Value {
    let read = |p: &str| std::fs::read_to_string(p).unwrap_or_default();
    let cpuinfo = read("/proc/cpuinfo");
    let field = |keys: &[&str]| {
        cpuinfo.lines().find_map(|l| {
            let (k, v) = l.split_once(':')?;
            keys.contains(&k.trim())
                .then(|| v.trim().to_string())
                .filter(|v| !v.is_empty())
        })
    };
    let cpu = field(&["model name", "Model", "Hardware", "cpu model", "cpu"])
        .unwrap_or_else(|| "unknown".into());
    let online = cpuinfo
        .lines()
        .filter(|l| l.split(':').next().is_some_and(|k| k.trim() == "processor"))
        .count();
    let version = read("/proc/sys/kernel/version").trim().to_string();
    let preempt = if version.contains("PREEMPT_RT") {
        "PREEMPT_RT"
    } else if version.contains("PREEMPT_DYNAMIC") {
        "PREEMPT_DYNAMIC"
    } else if version.contains("PREEMPT") {
        "PREEMPT"
    } else {
        "none"
    };
    json!({
        "cores": std::thread::available_parallelism().map_or(0, |n| n.get()),
        "cpus_online": online,
        "cpu": cpu,
        "kernel": read("/proc/sys/kernel/osrelease").trim(),
        "kernel_version": version,
        "preempt": preempt,
        "loadavg": read("/proc/loadavg").split_whitespace().take(3).collect::<Vec<_>>().join(" "),
        "softarm": env!("CARGO_PKG_VERSION"),
    })
}

fn machine_text(m: &Value) -> String {
    format!(
        "softarm-rig bench {}: {}, {} cores available ({} online), Linux {} ({}), load {}",
        m["softarm"].as_str().unwrap_or(""),
        m["cpu"].as_str().unwrap_or(""),
        m["cores"],
        m["cpus_online"],
        m["kernel"].as_str().unwrap_or(""),
        m["preempt"].as_str().unwrap_or(""),
        m["loadavg"].as_str().unwrap_or(""),
    )
}

/// SCHED_FIFO at `priority` for the calling thread.
fn set_fifo(priority: i32) -> anyhow::Result<()> {
    let param = nix::libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: plain syscall on this thread with a valid parameter struct.
    if unsafe { nix::libc::sched_setscheduler(0, nix::libc::SCHED_FIFO, &param) } != 0 {
        anyhow::bail!(
            "SCHED_FIFO priority {priority} refused: {}",
            std::io::Error::last_os_error()
        );
    }
    Ok(())
}

/// A bare absolute-deadline loop alone: the wake-up latency of each period, as the tick records
/// it.
fn wakeup(seconds: f64, rate_hz: f64, fifo: Option<i32>, json: bool) -> anyhow::Result<()> {
    if !(seconds > 0.0 && seconds <= 3600.0 && (1.0..=10_000.0).contains(&rate_hz)) {
        anyhow::bail!("--wakeup must be in (0, 3600] s and --rate-hz in [1, 10000]");
    }
    if let Some(priority) = fifo {
        set_fifo(priority)?;
    }
    let periods = (seconds * rate_hz).round() as u64;
    let mut ticker = softarm_runtime::clock::Ticker::new(rate_hz);
    let mut ns = histogram();
    for _ in 0..periods {
        ns.saturating_record(ticker.wait().latency_ns.max(1));
    }
    let s = Stats::of(&ns).ok_or_else(|| anyhow::anyhow!("no period timed"))?;
    let scheduling = fifo.map_or("normal scheduling".to_string(), |p| {
        format!("SCHED_FIFO {p}")
    });
    if json {
        let doc = json!({
            "machine": machine(),
            "bare": json_with(&s, &[
                ("overruns", json!(ticker.overruns())),
                ("rate_hz", json!(rate_hz)),
                ("scheduling", json!(scheduling)),
            ]),
        });
        println!("{doc}");
    } else {
        println!("{}", machine_text(&machine()));
        println!("{}", header("wake-up latency"));
        println!(
            "{}",
            row(
                &format!("bare loop, {rate_hz} Hz, {scheduling}"),
                &s,
                &format!("  overruns {}", ticker.overruns())
            )
        );
    }
    Ok(())
}
