//! `softarm record` and `softarm replay`: every pub/sub service of a namespace into an MCAP file,
//! and the file back into the per-execution statistics and a timing summary.
//!
//! The file: one channel per service, as [`softarm_channels`] describes them (topic the
//! service's name, JSON messages, a JSON Schema named after the payload's iceoryx2 type), and
//! the channel `scene`: the 3-D scene of [`softarm_channels::scene`] (`foxglove.SceneUpdate`,
//! protobuf, at `view.scene_hz`), so the recording opens in Foxglove with the arm drawn.
//! `log_time` is when the recorder received the sample (CLOCK_REALTIME, ns since the epoch, as
//! viewers expect); `publish_time` is the sample's own `stamp_ns` (CLOCK_MONOTONIC of the machine
//! that ran the stack; for the scene, when it was drawn). Foxglove and the `mcap` Python package
//! read it as it is.
//!
//! The recorder is one more subscriber: it never publishes, so the controller does not notice
//! it. It writes to `<file>.partial` and renames it once complete: a file named `run.mcap` is
//! always whole.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{Context, bail};
use foxglove::Encode;
use mcap::records::MessageHeader;
use serde::Serialize;
use serde_json::{Value, json};
use softarm_ipc::{Namespace, Node};

pub use softarm_channels::TOPICS;
use softarm_channels::scene::{self, Scene};
use softarm_channels::{Services, Spec};

type Writer = mcap::Writer<BufWriter<File>>;

/// A recording being written: the file, a channel per service and the scene's.
struct Recording {
    w: Writer,
    /// Per service, in the order of [`TOPICS`]: the channel and its messages so far.
    channels: Vec<(u16, u32)>,
    scene: Scene,
    scene_channel: (u16, u32),
}

impl Recording {
    /// Starts the file at `tmp` with a channel per service and one for the scene.
    fn create(tmp: &Path, specs: &[Spec], settings: scene::Settings) -> anyhow::Result<Self> {
        let file = File::create(tmp).with_context(|| format!("creating {}", tmp.display()))?;
        let mut w = mcap::WriteOptions::new()
            .profile("")
            .library(concat!("softarm ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .with_context(|| format!("starting the recording {}", tmp.display()))?;
        let mut channels = Vec::new();
        for s in specs {
            let id = w.add_schema(s.schema_name, "jsonschema", s.schema.as_bytes())?;
            channels.push((w.add_channel(id, s.topic, "json", &BTreeMap::new())?, 0));
        }
        let schema = foxglove::messages::SceneUpdate::get_schema()
            .context("the foxglove crate has a schema for SceneUpdate")?;
        let id = w.add_schema(&schema.name, &schema.encoding, &schema.data)?;
        let encoding = foxglove::messages::SceneUpdate::get_message_encoding();
        let scene_channel = (
            w.add_channel(id, scene::TOPIC, &encoding, &BTreeMap::new())?,
            0,
        );
        Ok(Self {
            w,
            channels,
            scene: Scene::new(settings),
            scene_channel,
        })
    }

    /// Writes every sample waiting and, when due, the scene; returns how many samples.
    fn step(&mut self, services: &mut Services) -> anyhow::Result<u64> {
        let n = services.drain(|i, p| {
            self.scene.take(p);
            let (channel, seq) = &mut self.channels[i];
            write(&mut self.w, (*channel, seq), p.stamp_ns(), &p.json())
        })?;
        let now = Instant::now();
        if self.scene.due(now) {
            let realtime = realtime_ns();
            let update = self.scene.update(now, realtime);
            let mut bytes = Vec::with_capacity(update.encoded_len().unwrap_or(0));
            update.encode(&mut bytes)?;
            let (channel, seq) = &mut self.scene_channel;
            write(&mut self.w, (*channel, seq), monotonic_ns(), &bytes)?;
        }
        Ok(n)
    }

    fn finish(mut self) -> anyhow::Result<u32> {
        self.w.finish()?;
        let file = self
            .w
            .into_inner()
            .into_inner()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        file.sync_all()?;
        Ok(self.scene_channel.1)
    }
}

/// One message: `log_time` the wall clock now, `publish_time` the sample's stamp.
fn write(
    w: &mut Writer,
    (channel, seq): (u16, &mut u32),
    stamp: u64,
    data: &[u8],
) -> anyhow::Result<()> {
    w.write_to_known_channel(
        &MessageHeader {
            channel_id: channel,
            sequence: *seq,
            log_time: realtime_ns(),
            publish_time: stamp,
        },
        data,
    )?;
    *seq += 1;
    Ok(())
}

fn realtime_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// The stamp of what the recorder makes itself (the scene): CLOCK_MONOTONIC like the samples'.
fn monotonic_ns() -> u64 {
    softarm_runtime::now_ns()
}

/// Where a recording is written until it is complete.
fn partial(out: &Path) -> PathBuf {
    let mut name = out.as_os_str().to_owned();
    name.push(".partial");
    PathBuf::from(name)
}

/// Records every pub/sub service of `namespace` and the scene `settings` draws into `out`
/// until `stop` is set or `duration` has passed; returns the messages written per topic.
pub fn record(
    namespace: &Namespace,
    out: &Path,
    settings: &scene::Settings,
    duration: Option<Duration>,
    stop: &AtomicBool,
) -> anyhow::Result<BTreeMap<String, u64>> {
    check_output(out)?;
    let node = Node::open(namespace.clone(), "record")?;
    let mut services = Services::open(&node)?;
    let tmp = partial(out);
    let mut r = Recording::create(&tmp, services.specs(), *settings)?;
    let start = Instant::now();
    let result = (|| -> anyhow::Result<()> {
        while !stop.load(Ordering::Relaxed) && duration.is_none_or(|d| start.elapsed() < d) {
            if r.step(&mut services)? == 0 {
                // Sensor topics arrive at up to 1 kHz into buffers of 4 or more.
                std::thread::sleep(Duration::from_micros(500));
            }
        }
        // What arrived during the last pause.
        r.step(&mut services)?;
        Ok(())
    })();
    let finished = result.and_then(|()| r.finish());
    let scenes = match finished {
        Ok(n) => n,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e.context(format!("recording {}", out.display())));
        }
    };
    if let Err(e) = std::fs::rename(&tmp, out) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e).with_context(|| format!("renaming {} into place", tmp.display()));
    }
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        let _ = File::open(dir).and_then(|d| d.sync_all());
    }
    let mut counts = services.counts();
    counts.insert(scene::TOPIC.into(), u64::from(scenes));
    Ok(counts)
}

/// Refuses, before anything is recorded, an output [`record`] could not write: a name not ending
/// in `.mcap`, a directory, a folder that is not there.
pub fn check_output(out: &Path) -> anyhow::Result<()> {
    match out.extension().and_then(|e| e.to_str()) {
        Some("mcap") => {}
        _ => bail!("{}: a recording's name must end in .mcap", out.display()),
    }
    crate::check_output_path(out, "the recording")
}

/// One message of a recording: its topic and JSON (`null` for the scene, which is protobuf).
#[derive(Debug, Clone)]
pub struct Message {
    pub topic: String,
    pub log_time: u64,
    pub publish_time: u64,
    pub value: Value,
}

/// Every message of a recording, in file order; those of channels not in JSON (the scene) with
/// the value `null`.
pub fn read(path: &Path) -> anyhow::Result<Vec<Message>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let mut out = Vec::new();
    for m in mcap::MessageStream::new(&bytes)
        .with_context(|| format!("{}: not an MCAP file", path.display()))?
    {
        let m = m.with_context(|| format!("{}: damaged", path.display()))?;
        if m.channel.message_encoding != "json" {
            out.push(Message {
                topic: m.channel.topic.clone(),
                log_time: m.log_time,
                publish_time: m.publish_time,
                value: Value::Null,
            });
            continue;
        }
        let value = serde_json::from_slice(&m.data).with_context(|| {
            format!(
                "{}: a message on {:?} is not JSON",
                path.display(),
                m.channel.topic
            )
        })?;
        out.push(Message {
            topic: m.channel.topic.clone(),
            log_time: m.log_time,
            publish_time: m.publish_time,
            value,
        });
    }
    Ok(out)
}

/// Messages per topic.
pub fn counts(messages: &[Message]) -> BTreeMap<String, u64> {
    let mut c = BTreeMap::new();
    for m in messages {
        *c.entry(m.topic.clone()).or_insert(0) += 1;
    }
    c
}

/// `softarm replay`: what a recording says about the run.
#[derive(Debug, Clone, Serialize)]
pub struct Replay {
    pub seconds: f64,
    pub counts: BTreeMap<String, u64>,
    /// One per finished execution, as `softarm stats --follow --json` prints it.
    pub executions: Vec<Value>,
    /// Setpoint intervals (µs): p50, p99, max, and how many were more than 1.5 periods.
    pub setpoint_interval_us: Option<Value>,
    /// The controller's last reported tick latency and overruns.
    pub controller: Option<Value>,
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

pub fn replay(messages: &[Message]) -> Replay {
    let first = messages.iter().map(|m| m.log_time).min().unwrap_or(0);
    let last = messages.iter().map(|m| m.log_time).max().unwrap_or(0);
    let executions = stats_of(messages)
        .iter()
        .filter_map(|s| serde_json::from_str(&softarm_clients::stats::json_line(s)).ok())
        .collect();
    let stamps: Vec<u64> = messages
        .iter()
        .filter(|m| m.topic == "setpoint")
        .map(|m| m.publish_time)
        .collect();
    let mut intervals: Vec<f64> = stamps
        .windows(2)
        .map(|w| w[1].saturating_sub(w[0]) as f64 / 1e3)
        .collect();
    let setpoint_interval_us = (!intervals.is_empty()).then(|| {
        intervals.sort_by(f64::total_cmp);
        let p50 = percentile(&intervals, 0.5);
        let late = intervals.iter().filter(|&&v| v > 1.5 * p50).count();
        json!({
            "p50": p50,
            "p99": percentile(&intervals, 0.99),
            "max": intervals.last().copied().unwrap_or(f64::NAN),
            "late": late,
        })
    });
    let controller = messages
        .iter()
        .rev()
        .find(|m| m.topic == "status")
        .map(|m| {
            json!({
                "ticks": m.value["ticks"],
                "overruns": m.value["overruns"],
                "latency_ns": m.value["latency"],
            })
        });
    Replay {
        seconds: last.saturating_sub(first) as f64 / 1e9,
        counts: counts(messages),
        executions,
        setpoint_interval_us,
        controller,
    }
}

/// The executions' statistics a recording holds, in order.
pub fn stats_of(messages: &[Message]) -> Vec<softarm_ipc::ExecutionStats> {
    messages
        .iter()
        .filter(|m| m.topic == "stats")
        .filter_map(|m| softarm_clients::stats::from_json(&m.value))
        .collect()
}

/// `softarm replay`'s table.
pub fn replay_text(r: &Replay, messages: &[Message]) -> String {
    let mut out = format!("{:.1} s recorded\n", r.seconds);
    for (topic, n) in &r.counts {
        out += &format!("  {topic:<17} {n:>8} samples\n");
    }
    let stats = stats_of(messages);
    if stats.is_empty() {
        out += "no execution finished in this recording\n";
    }
    let mut set = None;
    for s in &stats {
        if set != Some(s.set_id) {
            set = Some(s.set_id);
            out += &format!(
                "set {}\n{}\n",
                s.set_id,
                softarm_clients::stats::table_header(s.errors().len())
            );
        }
        out += &softarm_clients::stats::table_row(s);
        out.push('\n');
    }
    if let Some(s) = &r.setpoint_interval_us {
        out += &format!(
            "setpoint interval µs: p50 {:.1}, p99 {:.1}, max {:.1}; {} over 1.5× the median\n",
            s["p50"].as_f64().unwrap_or(f64::NAN),
            s["p99"].as_f64().unwrap_or(f64::NAN),
            s["max"].as_f64().unwrap_or(f64::NAN),
            s["late"]
        );
    }
    if let Some(c) = &r.controller {
        let l = &c["latency_ns"];
        let us = |k: &str| l[k].as_f64().map_or(f64::NAN, |v| v / 1e3);
        out += &format!(
            "controller (last status): {} ticks, {} overruns; wake-up latency µs p50 {:.1}, \
             p99 {:.1}, p99.9 {:.1}, max {:.1}\n",
            c["ticks"],
            c["overruns"],
            us("p50_ns"),
            us("p99_ns"),
            us("p999_ns"),
            us("max_ns")
        );
    }
    out
}

/// Writes what the recorder tells the user when it ends.
pub fn summary(
    out: &Path,
    counts: &BTreeMap<String, u64>,
    w: &mut impl Write,
) -> std::io::Result<()> {
    writeln!(w, "recorded {}", out.display())?;
    for (topic, n) in counts {
        writeln!(w, "  {topic:<17} {n:>8} samples")?;
    }
    Ok(())
}

/// `softarm record -o FILE [--duration S]`: records until stopped or for `duration` seconds,
/// then prints the channels' counts.
pub fn run(
    namespace: &Namespace,
    settings: &scene::Settings,
    output: &Path,
    duration: Option<f64>,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let duration = match duration {
        Some(d) if !(d.is_finite() && d > 0.0) => {
            bail!("--duration must be a positive number of seconds, got {d}");
        }
        Some(d) => Some(
            Duration::try_from_secs_f64(d)
                .map_err(|_| anyhow::anyhow!("--duration {d:e} s is too long"))?,
        ),
        None => None,
    };
    let counts = record(namespace, output, settings, duration, stop)?;
    summary(output, &counts, &mut std::io::stdout())?;
    Ok(())
}

/// `softarm replay FILE [--json]`: per-execution errors and timing from a recording.
pub fn replay_command(recording: &Path, json: bool) -> anyhow::Result<()> {
    let messages = read(recording)?;
    let r = replay(&messages);
    if json {
        println!("{}", serde_json::to_string(&r)?);
    } else {
        print!("{}", replay_text(&r, &messages));
    }
    Ok(())
}
