//! The view's front door: a TCP relay in front of the `foxglove` crate's server that accepts the
//! subprotocol the Foxglove WebSocket protocol documents, `foxglove.websocket.v1`, as well as
//! the names the crate negotiates, `foxglove.sdk.v1` and `foxglove.sdk.v1.1` (the same
//! messages; only the name differs).
//!
//! The server listens on an ephemeral loopback port; the door on the configured address. Per
//! connection the door reads the client's HTTP upgrade request (at most [`MAX_HEAD`] bytes
//! within [`HEAD_TIMEOUT`], else the connection is dropped and logged) and:
//!
//! - offering `foxglove.sdk.v1` or `foxglove.sdk.v1.1`: passes it unchanged;
//! - offering `foxglove.websocket.v1` and neither of those: renames its offer to
//!   `foxglove.sdk.v1` and, in the server's `101` answer, `foxglove.sdk.v1` back to
//!   `foxglove.websocket.v1`;
//! - offering none: passes it unchanged, so the server answers its own HTTP 400, and logs why.
//!
//! Then it copies bytes both ways unchanged, each way on a thread of its own with a fixed
//! buffer, and the kernel's send buffer to the client fixed too: a client that reads slowly
//! blocks only its copy, the back-pressure reaches the server, whose queue for that client
//! (`view.backlog`) drops its oldest messages. At most [`MAX_CONNECTIONS`] connections at
//! once (two threads each); another gets HTTP 503. When either side closes or fails, both
//! sockets are shut down and both threads end.

use std::collections::HashMap;
use std::io::{self, Read, Write};
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use nix::sys::socket::{setsockopt, sockopt};

/// The subprotocol github.com/foxglove/ws-protocol documents, which older clients offer.
pub const DOCUMENTED: &str = "foxglove.websocket.v1";
/// The crate's name for the documented protocol, which the door offers the server instead.
pub const SDK_V1: &str = "foxglove.sdk.v1";
/// The crate's newer variant (schemas advertised once per connection), passed through.
pub const SDK_V1_1: &str = "foxglove.sdk.v1.1";
/// What the door accepts, for the log.
pub const ACCEPTED: &str = "foxglove.websocket.v1, foxglove.sdk.v1 or foxglove.sdk.v1.1";

/// Connections served at once; more are refused (HTTP 503) so the threads stay bounded.
pub const MAX_CONNECTIONS: usize = 16;
/// The most bytes of HTTP head read from a client (or the server) before giving up on it.
pub const MAX_HEAD: usize = 16 * 1024;
/// How long a client (or the server) has to send its whole head.
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(5);
/// Each way's copy buffer: what a connection costs the door, whatever the client's speed.
const COPY_BUFFER: usize = 16 * 1024;
/// The kernel's send buffer of the door's socket to the client (Linux doubles it: 512 KiB,
/// about 1 s of everything, enough for the full rate over a remote viewer's round trip of a
/// few hundred ms). Left to autotuning it grows to `net.ipv4.tcp_wmem`'s maximum (4 MiB, 8 s
/// of everything), where a slow client's messages would wait instead of being dropped from the
/// server's queue for it. The receive buffer from the server is left alone: it grows only as
/// fast as the door reads, and fixed at 64 KiB on loopback (whose segments are 64 KiB) it
/// stalled the flow for seconds after a pause.
const SOCKET_BUFFER: usize = 256 * 1024;
/// The header that carries the subprotocols, compared case-insensitively.
const PROTOCOL_HEADER: &str = "sec-websocket-protocol";

/// The door, listening; [`Door::stop`] (or dropping it) closes every connection and ends its
/// threads.
pub struct Door {
    address: SocketAddr,
    stop: Arc<AtomicBool>,
    accept: Option<JoinHandle<()>>,
}

impl Door {
    /// Listens on `listen` and relays each connection to the server at `upstream`.
    pub fn start(listen: SocketAddr, upstream: SocketAddr) -> io::Result<Self> {
        let listener = TcpListener::bind(listen)?;
        let address = listener.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let accept = std::thread::Builder::new()
            .name("view-door".into())
            .spawn(move || accept_loop(&listener, upstream, &flag))?;
        Ok(Self {
            address,
            stop,
            accept: Some(accept),
        })
    }

    /// Where it listens (the port chosen when the configured one was 0).
    pub fn address(&self) -> SocketAddr {
        self.address
    }

    /// Stops accepting, closes every connection and waits for their threads.
    pub fn stop(mut self) {
        self.halt();
    }

    fn halt(&mut self) {
        let Some(accept) = self.accept.take() else {
            return;
        };
        self.stop.store(true, Ordering::Release);
        // `accept` blocks: a connection of our own wakes it to see the flag.
        match TcpStream::connect_timeout(&reachable(self.address), Duration::from_secs(1)) {
            Ok(_) => {
                if accept.join().is_err() {
                    tracing::warn!("the view's door thread panicked");
                }
            }
            Err(e) => tracing::warn!(
                "could not wake the view's door on {} to stop it ({e}); it ends with the process",
                self.address
            ),
        }
    }
}

impl Drop for Door {
    fn drop(&mut self) {
        self.halt();
    }
}

/// `address` as a client reaches it: the wildcard address means this host's loopback.
fn reachable(address: SocketAddr) -> SocketAddr {
    match address.ip() {
        IpAddr::V4(ip) if ip.is_unspecified() => (Ipv4Addr::LOCALHOST, address.port()).into(),
        IpAddr::V6(ip) if ip.is_unspecified() => (Ipv6Addr::LOCALHOST, address.port()).into(),
        _ => address,
    }
}

/// Accepts until `stop`, a thread per connection; then closes them all and joins their threads.
fn accept_loop(listener: &TcpListener, upstream: SocketAddr, stop: &AtomicBool) {
    let open = Arc::new(Open::default());
    let mut threads: Vec<JoinHandle<()>> = Vec::new();
    for conn in listener.incoming() {
        if stop.load(Ordering::Acquire) {
            break;
        }
        threads.retain(|t| !t.is_finished());
        let client = match conn {
            Ok(c) => c,
            Err(e) => {
                // Out of file descriptors, say: wait rather than spin.
                tracing::warn!("the view's door could not accept a connection: {e}");
                std::thread::sleep(Duration::from_millis(100));
                continue;
            }
        };
        let id = match open.admit(&client) {
            Ok(id) => id,
            Err(why) => {
                refuse(client, &why);
                continue;
            }
        };
        let open = open.clone();
        let spawned = std::thread::Builder::new()
            .name("view-conn".into())
            .spawn(move || {
                let _entry = Entry { open: &open, id };
                serve(&client, upstream, &open, id);
            });
        match spawned {
            Ok(t) => threads.push(t),
            Err(e) => tracing::warn!("the view's door could not start a thread: {e}"),
        }
    }
    open.close_all();
    for t in threads {
        let _ = t.join();
    }
}

/// The sockets of the connections being served, so that a stop can shut them all down.
#[derive(Default)]
struct Open(Mutex<Sockets>);

#[derive(Default)]
struct Sockets {
    closing: bool,
    next: u64,
    by_connection: HashMap<u64, Vec<TcpStream>>,
}

impl Open {
    fn lock(&self) -> MutexGuard<'_, Sockets> {
        // A connection thread that panicked holding it left nothing half-done: go on.
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Registers a new connection's client socket; refused, saying why, when
    /// [`MAX_CONNECTIONS`] are open.
    fn admit(&self, client: &TcpStream) -> Result<u64, String> {
        let mut s = self.lock();
        if s.by_connection.len() >= MAX_CONNECTIONS {
            return Err(format!(
                "{MAX_CONNECTIONS} connections are open, the most it serves at once; try again \
                 when a viewer leaves"
            ));
        }
        let clone = client
            .try_clone()
            .map_err(|e| format!("it cannot take another connection now ({e})"))?;
        s.next += 1;
        let id = s.next;
        s.by_connection.insert(id, vec![clone]);
        Ok(id)
    }

    /// Registers connection `id`'s socket to the server; refused once the door is closing.
    fn add(&self, id: u64, server: &TcpStream) -> io::Result<()> {
        let mut s = self.lock();
        if s.closing {
            return Err(io::Error::other("the view is stopping"));
        }
        let clone = server.try_clone()?;
        s.by_connection.entry(id).or_default().push(clone);
        Ok(())
    }

    fn close_all(&self) {
        let mut s = self.lock();
        s.closing = true;
        for socket in s.by_connection.values().flatten() {
            let _ = socket.shutdown(Shutdown::Both);
        }
    }
}

/// A connection's registration, removed however its thread ends.
struct Entry<'a> {
    open: &'a Open,
    id: u64,
}

impl Drop for Entry<'_> {
    fn drop(&mut self) {
        self.open.lock().by_connection.remove(&self.id);
    }
}

/// Answers 503 to a connection the door cannot take, saying `why`, and closes it.
fn refuse(mut client: TcpStream, why: &str) {
    tracing::warn!(
        "the view refused a connection from {}: {why}",
        peer(&client)
    );
    let body = format!("softarm view: {why}\n");
    let _ = client.set_write_timeout(Some(Duration::from_secs(1)));
    let _ = write!(
        client,
        "HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain; charset=utf-8\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    let _ = client.shutdown(Shutdown::Write);
    // Closing with the request unread would reset the connection, and the client might lose
    // the answer: read it first, bounded in bytes and time (this is the accept thread).
    let deadline = Instant::now() + Duration::from_secs(1);
    let _ = read_head(&client, deadline);
}

fn peer(s: &TcpStream) -> String {
    s.peer_addr()
        .map_or_else(|_| "an unknown address".into(), |a| a.to_string())
}

/// One connection: the handshake, then bytes both ways until either side ends.
fn serve(client: &TcpStream, upstream: SocketAddr, open: &Open, id: u64) {
    let peer = peer(client);
    match handshake(client, upstream, open, id) {
        Ok(server) => splice(client, &server),
        Err(e) => tracing::info!("the view dropped the connection from {peer}: {e}"),
    }
    let _ = client.shutdown(Shutdown::Both);
}

/// Reads the client's request, connects to the server and passes the request on, renamed if
/// need be, and the server's answer back (renamed the other way). Returns the server's socket.
fn handshake(
    mut client: &TcpStream,
    upstream: SocketAddr,
    open: &Open,
    id: u64,
) -> Result<TcpStream, String> {
    let (head, rest) = read_head(client, Instant::now() + HEAD_TIMEOUT)
        .map_err(|e| format!("reading its upgrade request: {e}"))?;
    let offered = offered(&head).map_err(|e| format!("its upgrade request is malformed: {e}"))?;
    let plan = plan(&offered);
    if plan == Plan::Refused {
        // The server's 400 says only "Missing expected sec-websocket-protocol header".
        let what = if offered.is_empty() {
            "no subprotocol".to_string()
        } else {
            format!("the subprotocols {offered:?}")
        };
        tracing::warn!(
            "a client at {} offered {what}; the view accepts {ACCEPTED}: its server refuses \
             the connection (HTTP 400)",
            peer(client)
        );
    }
    let mut server = TcpStream::connect_timeout(&upstream, HEAD_TIMEOUT)
        .map_err(|e| format!("connecting to the view's server at {upstream}: {e}"))?;
    open.add(id, &server).map_err(|e| e.to_string())?;
    setsockopt(client, sockopt::SndBuf, &SOCKET_BUFFER)
        .map_err(|e| format!("fixing its send buffer at {SOCKET_BUFFER} bytes: {e}"))?;
    let request = match plan {
        Plan::Rename => rename_request(&head)?,
        Plan::Pass | Plan::Refused => head,
    };
    let sent = server
        .write_all(&request)
        .and_then(|()| server.write_all(&rest));
    sent.map_err(|e| format!("passing its request to the view's server at {upstream}: {e}"))?;
    if plan == Plan::Rename {
        let (head, rest) = read_head(&server, Instant::now() + HEAD_TIMEOUT)
            .map_err(|e| format!("reading the view's server's answer: {e}"))?;
        let answer = rename_response(&head)
            .map_err(|e| format!("the view's server's answer is malformed: {e}"))?;
        let sent = client
            .write_all(&answer)
            .and_then(|()| client.write_all(&rest));
        sent.map_err(|e| format!("passing the server's answer on: {e}"))?;
    }
    // From here on a quiet connection is a healthy one.
    client.set_read_timeout(None).map_err(|e| e.to_string())?;
    server.set_read_timeout(None).map_err(|e| e.to_string())?;
    Ok(server)
}

/// Copies both ways, one on a thread of its own, until either side ends.
fn splice(client: &TcpStream, server: &TcpStream) {
    std::thread::scope(|s| {
        let down = std::thread::Builder::new()
            .name("view-conn-down".into())
            .spawn_scoped(s, || copy(server, client));
        if down.is_err() {
            tracing::warn!("the view's door could not start a thread; dropping a connection");
            let _ = server.shutdown(Shutdown::Both);
            return;
        }
        copy(client, server);
    });
}

/// Copies `from` to `to` with a fixed buffer until either fails or `from` ends; then shuts
/// both down, which ends the copy the other way too.
fn copy(mut from: &TcpStream, mut to: &TcpStream) {
    let mut buffer = vec![0; COPY_BUFFER];
    loop {
        match from.read(&mut buffer) {
            Ok(0) => break,
            Ok(n) => {
                if to.write_all(&buffer[..n]).is_err() {
                    break;
                }
            }
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(_) => break,
        }
    }
    let _ = from.shutdown(Shutdown::Both);
    let _ = to.shutdown(Shutdown::Both);
}

/// Reads an HTTP head from `stream` by `deadline`: (the head, through its blank line; what
/// came after it). Fails past [`MAX_HEAD`] bytes, at the deadline, or if the stream ends first.
fn read_head(mut stream: &TcpStream, deadline: Instant) -> io::Result<(Vec<u8>, Vec<u8>)> {
    let mut buffer = Vec::with_capacity(1024);
    let mut chunk = [0; 4096];
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(timed_out());
        }
        stream.set_read_timeout(Some(left))?;
        let n = match stream.read(&mut chunk) {
            Ok(0) => {
                let e = format!(
                    "closed after {} bytes, before the end of the head",
                    buffer.len()
                );
                return Err(io::Error::new(io::ErrorKind::UnexpectedEof, e));
            }
            Ok(n) => n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            // What a read timeout looks like on Linux (EAGAIN) and elsewhere.
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                return Err(timed_out());
            }
            Err(e) => return Err(e),
        };
        // Only the new bytes and the three before them can complete the blank line.
        let from = buffer.len().saturating_sub(3);
        buffer.extend_from_slice(&chunk[..n]);
        if let Some(end) = head_end(&buffer[from..]).map(|e| e + from) {
            if end > MAX_HEAD {
                return Err(too_long());
            }
            let rest = buffer.split_off(end);
            return Ok((buffer, rest));
        }
        if buffer.len() >= MAX_HEAD {
            return Err(too_long());
        }
    }
}

fn timed_out() -> io::Error {
    io::Error::new(
        io::ErrorKind::TimedOut,
        format!("no whole head within {} s", HEAD_TIMEOUT.as_secs()),
    )
}

fn too_long() -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("no end of the head in its first {MAX_HEAD} bytes"),
    )
}

/// Where an HTTP head ends (the index after its blank line), if `buffer` holds a whole one.
pub(crate) fn head_end(buffer: &[u8]) -> Option<usize> {
    buffer
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .map(|i| i + 4)
}

/// What the door does with a request, by the subprotocols it offers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Plan {
    /// It offers a name the server negotiates: passed unchanged.
    Pass,
    /// It offers the documented name and none the server negotiates: renamed both ways.
    Rename,
    /// None of those: passed unchanged, for the server to refuse.
    Refused,
}

pub(crate) fn plan(offered: &[String]) -> Plan {
    let has = |name: &str| offered.iter().any(|o| o == name);
    if has(SDK_V1) || has(SDK_V1_1) {
        Plan::Pass
    } else if has(DOCUMENTED) {
        Plan::Rename
    } else {
        Plan::Refused
    }
}

/// One header line of a head: (the whole line, its name, its value trimmed).
type Header<'a> = (&'a [u8], &'a [u8], &'a [u8]);

/// A whole head (through its blank line) as its start line and header lines. Refuses what
/// could be read two ways (a folded line, a bare CR or LF, a line without a name), so that
/// the door and the server never disagree on which headers there are.
fn split_head(head: &[u8]) -> Result<(&[u8], Vec<Header<'_>>), String> {
    let body = head
        .strip_suffix(b"\r\n\r\n")
        .ok_or("the head does not end with a blank line")?;
    let mut lines = crlf_lines(body).into_iter();
    let start = lines.next().unwrap_or_default();
    if start.is_empty() || start.contains(&b'\r') || start.contains(&b'\n') {
        return Err("no request or status line".into());
    }
    let mut headers = Vec::new();
    for (i, line) in lines.enumerate() {
        let n = i + 2;
        if line.contains(&b'\r') || line.contains(&b'\n') {
            return Err(format!("line {n} has a bare CR or LF"));
        }
        if line.first().is_some_and(|b| b.is_ascii_whitespace()) {
            return Err(format!("line {n} is folded (starts with white space)"));
        }
        let colon = line.iter().position(|&b| b == b':');
        let colon = colon.ok_or(format!("line {n} is not a header (no colon)"))?;
        let name = &line[..colon];
        if name.is_empty() || name.iter().any(|b| b.is_ascii_whitespace()) {
            return Err(format!("line {n} has no header name"));
        }
        headers.push((line, name, line[colon + 1..].trim_ascii()));
    }
    Ok((start, headers))
}

/// `body` split at each CRLF.
fn crlf_lines(body: &[u8]) -> Vec<&[u8]> {
    let mut lines = Vec::new();
    let mut rest = body;
    while let Some(i) = rest.windows(2).position(|w| w == b"\r\n") {
        lines.push(&rest[..i]);
        rest = &rest[i + 2..];
    }
    lines.push(rest);
    lines
}

fn is_protocol(name: &[u8]) -> bool {
    name.eq_ignore_ascii_case(PROTOCOL_HEADER.as_bytes())
}

/// The subprotocols a request offers, in order: every `Sec-WebSocket-Protocol` header, each a
/// comma-separated list.
pub(crate) fn offered(head: &[u8]) -> Result<Vec<String>, String> {
    let (_, headers) = split_head(head)?;
    Ok(headers
        .iter()
        .filter(|(_, name, _)| is_protocol(name))
        .flat_map(|(_, _, value)| value.split(|&b| b == b','))
        .map(|v| String::from_utf8_lossy(v.trim_ascii()).into_owned())
        .filter(|v| !v.is_empty())
        .collect())
}

/// `head` with its `Sec-WebSocket-Protocol` headers replaced by one offering `foxglove.sdk.v1`
/// where the first was; every other line unchanged.
pub(crate) fn rename_request(head: &[u8]) -> Result<Vec<u8>, String> {
    let (start, headers) = split_head(head)?;
    let mut out = Vec::with_capacity(head.len());
    out.extend_from_slice(start);
    out.extend_from_slice(b"\r\n");
    let mut renamed = false;
    for (line, name, _) in headers {
        if !is_protocol(name) {
            out.extend_from_slice(line);
        } else if renamed {
            continue;
        } else {
            out.extend_from_slice(name);
            out.extend_from_slice(b": ");
            out.extend_from_slice(SDK_V1.as_bytes());
            renamed = true;
        }
        out.extend_from_slice(b"\r\n");
    }
    out.extend_from_slice(b"\r\n");
    Ok(out)
}

/// The server's answer with `foxglove.sdk.v1` named `foxglove.websocket.v1` in its
/// `Sec-WebSocket-Protocol` header; every other line unchanged (a refusal has no such header).
pub(crate) fn rename_response(head: &[u8]) -> Result<Vec<u8>, String> {
    let (start, headers) = split_head(head)?;
    let mut out = Vec::with_capacity(head.len() + 8);
    out.extend_from_slice(start);
    out.extend_from_slice(b"\r\n");
    for (line, name, value) in headers {
        if is_protocol(name) && value == SDK_V1.as_bytes() {
            out.extend_from_slice(name);
            out.extend_from_slice(b": ");
            out.extend_from_slice(DOCUMENTED.as_bytes());
        } else {
            out.extend_from_slice(line);
        }
        out.extend_from_slice(b"\r\n");
    }
    out.extend_from_slice(b"\r\n");
    Ok(out)
}

#[cfg(test)]
mod tests;
