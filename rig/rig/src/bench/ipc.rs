//! Setpoint-sized messages from another process (`softarm-rig bench --peer`, hidden), one way: the
//! peer stamps CLOCK_MONOTONIC into a [`Setpoint`] and sends it; this process takes now − stamp
//! on receipt. Three variants in turn, each started by a byte from this side over the socket:
//!
//! 1. iceoryx2 publish/subscribe, the subscriber busy-polling;
//! 2. iceoryx2 publish/subscribe, the subscriber blocked on an iceoryx2 event the peer notifies
//!    after each sample;
//! 3. a Unix-domain stream socket, the same bytes, a blocking read.

use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow, bail};
use serde_json::{Map, Value, json};
use softarm_ipc::iceoryx2::port::listener::Listener;
use softarm_ipc::iceoryx2::prelude::{ServiceName, ipc};
use softarm_ipc::iceoryx2::service::port_factory::event::PortFactory as EventService;
use softarm_ipc::{Namespace, Node, PubSub, Setpoint, Sub};
use softarm_runtime::clock::Ticker;
use softarm_runtime::now_ns;

use super::{Out, Stats, header, json_with, row};
use softarm_stack::sandbox::RemoveOnDrop;

/// Messages sent before those timed, per variant.
const WARMUP: usize = 50;
/// Bytes of a message: a `Setpoint`.
const SIZE: usize = std::mem::size_of::<Setpoint>();
/// The byte that starts the next variant.
const GO: u8 = b'g';
/// Longest silence within a variant before its missing messages count as lost: long, since a
/// loaded machine was seen to keep the peer from its CPU for over 3 s (the variant then had no
/// message at all). A peer that is alive always ends a variant with its last message.
const SILENCE: Duration = Duration::from_secs(30);

/// The services both ends open alike: data (busy-polled), data (event-woken), the event.
struct Services {
    polled: PubSub<Setpoint>,
    woken: PubSub<Setpoint>,
    event: EventService<ipc::Service>,
}

impl Services {
    fn open(node: &Node) -> anyhow::Result<Self> {
        let name = |s: &str| {
            let full = format!("{}/bench/{s}", node.namespace.as_str());
            ServiceName::new(&full).map_err(|e| anyhow!("service name {full:?}: {e:?}"))
        };
        let data = |s: &str| -> anyhow::Result<PubSub<Setpoint>> {
            node.node
                .service_builder(&name(s)?)
                .publish_subscribe::<Setpoint>()
                .history_size(0)
                .subscriber_max_buffer_size(256)
                .max_publishers(1)
                .max_subscribers(1)
                .max_nodes(4)
                .open_or_create()
                .map_err(|e| anyhow!("opening the bench's service {s}: {e:?}"))
        };
        Ok(Self {
            polled: data("polled")?,
            woken: data("woken")?,
            event: node
                .node
                .service_builder(&name("wake")?)
                .event()
                .max_notifiers(1)
                .max_listeners(1)
                .max_nodes(4)
                .open_or_create()
                .map_err(|e| anyhow!("opening the bench's event service: {e:?}"))?,
        })
    }
}

/// The message: a setpoint's bytes as `#[repr(C)]` lays them out, seq and stamp first.
fn encode(seq: u64, stamp_ns: u64) -> [u8; SIZE] {
    let mut b = [0u8; SIZE];
    b[..8].copy_from_slice(&seq.to_ne_bytes());
    b[8..16].copy_from_slice(&stamp_ns.to_ne_bytes());
    b
}

fn decode(b: &[u8; SIZE]) -> (u64, u64) {
    let word = |r: std::ops::Range<usize>| u64::from_ne_bytes(b[r].try_into().expect("8 bytes"));
    (word(0..8), word(8..16))
}

/// One variant's latencies; messages before [`WARMUP`] are not timed.
struct Received {
    hist: hdrhistogram::Histogram<u64>,
    got: usize,
}

impl Received {
    fn new() -> Self {
        Self {
            hist: super::histogram(),
            got: 0,
        }
    }

    fn take(&mut self, seq: u64, stamp_ns: u64) {
        let now = now_ns();
        self.got += 1;
        if seq >= WARMUP as u64 {
            self.hist
                .saturating_record(now.saturating_sub(stamp_ns).max(1));
        }
    }
}

/// This side: subscribers, listener and socket first, then the peer; the `ipc` object of the
/// JSON output.
pub(super) fn run(
    samples: usize,
    rate_hz: f64,
    out: &Out,
    stop: &AtomicBool,
) -> anyhow::Result<Value> {
    let pid = std::process::id();
    let namespace = format!("softarm/bench-{pid}");
    let dir = std::env::temp_dir().join(format!("softarm-bench-ipc-{pid}"));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let _cleanup = RemoveOnDrop(dir.clone());
    let socket = dir.join("peer.sock");

    let node = Node::open(Namespace::new(&namespace)?, "bench")?;
    let services = Services::open(&node)?;
    let polled = node.subscriber(&services.polled)?;
    let woken = node.subscriber(&services.woken)?;
    let listener = services
        .event
        .listener_builder()
        .create()
        .map_err(|e| anyhow!("creating the bench's listener: {e:?}"))?;
    let server =
        UnixListener::bind(&socket).with_context(|| format!("binding {}", socket.display()))?;

    out.progress(&format!(
        "timing {samples} messages per variant from another process at {rate_hz} Hz"
    ));
    let mut peer = Peer::start(&namespace, &socket, samples, rate_hz)?;
    let mut stream = accept(&server, &mut peer.0, stop)?;
    stream.set_read_timeout(Some(SILENCE))?;
    let last = (WARMUP + samples) as u64 - 1;

    stream.write_all(&[GO])?;
    let r1 = busy_polled(&polled, last, stop);
    stream.write_all(&[GO])?;
    let r2 = event_woken(&woken, &listener, last, stop)?;
    stream.write_all(&[GO])?;
    let r3 = socket_read(&mut stream, last, stop);
    if stop.load(Ordering::Relaxed) {
        bail!("interrupted");
    }
    peer.wait()?;
    report(samples, rate_hz, out, [&r1, &r2, &r3])
}

/// 1. The subscriber busy-polling, until message `last` or [`SILENCE`].
fn busy_polled(polled: &Sub<Setpoint>, last: u64, stop: &AtomicBool) -> Received {
    let mut r = Received::new();
    let mut heard = Instant::now();
    let mut spins = 0u64;
    loop {
        if let Ok(Some(s)) = polled.receive() {
            r.take(s.seq, s.stamp_ns);
            heard = Instant::now();
            if s.seq >= last {
                return r;
            }
            continue;
        }
        spins += 1;
        if spins.is_multiple_of(4096) && (stop.load(Ordering::Relaxed) || heard.elapsed() > SILENCE)
        {
            return r;
        }
        std::hint::spin_loop();
    }
}

/// 2. The subscriber woken by the peer's event after each sample.
fn event_woken(
    woken: &Sub<Setpoint>,
    listener: &Listener<ipc::Service>,
    last: u64,
    stop: &AtomicBool,
) -> anyhow::Result<Received> {
    let mut r = Received::new();
    while !stop.load(Ordering::Relaxed) {
        let events = match listener.timed_wait(|_| {}, SILENCE) {
            Ok(n) => n,
            Err(_) if stop.load(Ordering::Relaxed) => break,
            Err(e) => bail!("waiting on the bench's listener: {e:?}"),
        };
        while let Ok(Some(s)) = woken.receive() {
            r.take(s.seq, s.stamp_ns);
            if s.seq >= last {
                return Ok(r);
            }
        }
        if events == 0 {
            break;
        }
    }
    Ok(r)
}

/// 3. The same bytes over the Unix-domain socket, a blocking read.
fn socket_read(stream: &mut UnixStream, last: u64, stop: &AtomicBool) -> Received {
    let mut r = Received::new();
    let mut buf = [0u8; SIZE];
    while !stop.load(Ordering::Relaxed) && stream.read_exact(&mut buf).is_ok() {
        let (seq, stamp) = decode(&buf);
        r.take(seq, stamp);
        if seq >= last {
            break;
        }
    }
    r
}

/// The three variants' table, and the `ipc` object of the JSON output.
fn report(samples: usize, rate_hz: f64, out: &Out, r: [&Received; 3]) -> anyhow::Result<Value> {
    out.text(&header(&format!(
        "A setpoint ({SIZE} bytes) from another process, one way: stamp -> received ({samples} \
         per variant at {rate_hz} Hz, after {WARMUP} untimed)"
    )));
    let total = WARMUP + samples;
    let mut results = Map::new();
    for (key, name, r) in [
        ("iceoryx2_poll", "iceoryx2, subscriber busy-polling", r[0]),
        (
            "iceoryx2_event",
            "iceoryx2, woken by an iceoryx2 event",
            r[1],
        ),
        ("unix_socket", "Unix-domain socket, blocking read", r[2]),
    ] {
        let s = Stats::of(&r.hist)
            .ok_or_else(|| anyhow!("{name}: no message arrived from the peer"))?;
        let lost = total.saturating_sub(r.got);
        out.text(&row(
            name,
            &s,
            &if lost > 0 {
                format!("  lost {lost}")
            } else {
                String::new()
            },
        ));
        results.insert(key.into(), json_with(&s, &[("lost", json!(lost))]));
    }
    results.insert("payload_bytes".into(), json!(SIZE));
    results.insert("rate_hz".into(), json!(rate_hz));
    results.insert("warmup".into(), json!(WARMUP));
    Ok(Value::Object(results))
}

/// The peer's connection, or why it did not come.
fn accept(
    server: &UnixListener,
    peer: &mut Child,
    stop: &AtomicBool,
) -> anyhow::Result<UnixStream> {
    server.set_nonblocking(true)?;
    let limit = Instant::now() + Duration::from_secs(20);
    loop {
        match server.accept() {
            Ok((stream, _)) => {
                stream.set_nonblocking(false)?;
                return Ok(stream);
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(e) => return Err(e).context("accepting the peer"),
        }
        if let Some(status) = peer.try_wait()? {
            bail!("the peer exited before connecting ({status})");
        }
        if stop.load(Ordering::Relaxed) {
            bail!("interrupted");
        }
        if Instant::now() > limit {
            bail!("the peer did not connect within 20 s");
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// The peer process, killed if still there when dropped.
struct Peer(Child);

impl Peer {
    /// `softarm-rig bench --peer`: sends `samples` timed messages (after [`WARMUP`]) per variant at
    /// `rate_hz`, connecting to `socket`.
    fn start(namespace: &str, socket: &Path, samples: usize, rate_hz: f64) -> anyhow::Result<Self> {
        let child = Command::new(std::env::current_exe().context("finding my own executable")?)
            .args(["bench", "--peer", namespace, "--peer-socket"])
            .arg(socket)
            .args([
                "--samples",
                &samples.to_string(),
                "--ipc-rate-hz",
                &rate_hz.to_string(),
            ])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .context("starting the peer")?;
        Ok(Self(child))
    }

    /// Waits (a few seconds at most) for it to end, and insists it ended well.
    fn wait(&mut self) -> anyhow::Result<()> {
        let limit = Instant::now() + Duration::from_secs(10);
        loop {
            if let Some(status) = self.0.try_wait()? {
                if !status.success() {
                    bail!("the peer failed ({status})");
                }
                return Ok(());
            }
            if Instant::now() > limit {
                bail!("the peer did not finish");
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// The other end: publishers, notifier and socket, then each variant when asked, paced by a
/// [`Ticker`] at `rate_hz`, the stamp taken just before each send.
pub(super) fn peer(
    namespace: &str,
    socket: &Path,
    samples: usize,
    rate_hz: f64,
) -> anyhow::Result<()> {
    let node = Node::open(Namespace::new(namespace)?, "bench-peer")?;
    let services = Services::open(&node)?;
    let polled = node.publisher(&services.polled)?;
    let woken = node.publisher(&services.woken)?;
    let notifier = services
        .event
        .notifier_builder()
        .create()
        .map_err(|e| anyhow!("creating the peer's notifier: {e:?}"))?;
    let mut stream =
        UnixStream::connect(socket).with_context(|| format!("connecting {}", socket.display()))?;
    let total = (WARMUP + samples) as u64;
    let mut go = [0u8; 1];
    let paced = |send: &mut dyn FnMut(u64) -> anyhow::Result<()>| -> anyhow::Result<()> {
        let mut ticker = Ticker::new(rate_hz);
        for seq in 0..total {
            ticker.wait();
            send(seq)?;
        }
        Ok(())
    };
    let message = |seq: u64| Setpoint {
        seq,
        stamp_ns: now_ns(),
        ..Setpoint::default()
    };

    stream.read_exact(&mut go)?;
    paced(&mut |seq| {
        polled
            .send_copy(message(seq))
            .map_err(|e| anyhow!("publishing: {e:?}"))?;
        Ok(())
    })?;

    stream.read_exact(&mut go)?;
    paced(&mut |seq| {
        woken
            .send_copy(message(seq))
            .map_err(|e| anyhow!("publishing: {e:?}"))?;
        notifier.notify().map_err(|e| anyhow!("notifying: {e:?}"))?;
        Ok(())
    })?;

    stream.read_exact(&mut go)?;
    paced(&mut |seq| {
        stream.write_all(&encode(seq, now_ns()))?;
        Ok(())
    })?;
    Ok(())
}
