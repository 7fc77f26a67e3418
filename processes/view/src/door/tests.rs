use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use super::*;

/// Generous: the tests wait this long for what should come at once, and assert no timing.
const PATIENCE: Duration = Duration::from_secs(30);

fn request(protocols: &[&str]) -> String {
    let mut r =
        "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
                 Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
            .to_string();
    for p in protocols {
        r += &format!("Sec-WebSocket-Protocol: {p}\r\n");
    }
    r + "\r\n"
}

fn names(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

#[test]
fn the_offered_subprotocols_are_read_from_every_header_and_list() {
    let head = request(&["a.v1, foxglove.websocket.v1", " b "]).replace(
        "Sec-WebSocket-Protocol:  b ",
        "sec-websocket-PROTOCOL:\tb ,, c",
    );
    assert_eq!(
        offered(head.as_bytes()).unwrap(),
        names(&["a.v1", "foxglove.websocket.v1", "b", "c"])
    );
    assert_eq!(offered(request(&[]).as_bytes()).unwrap(), names(&[]));
}

#[test]
fn the_plan_prefers_what_the_server_speaks_and_renames_only_the_documented_name() {
    assert_eq!(plan(&names(&[DOCUMENTED])), Plan::Rename);
    assert_eq!(plan(&names(&["x", DOCUMENTED])), Plan::Rename);
    assert_eq!(plan(&names(&[DOCUMENTED, SDK_V1])), Plan::Pass);
    assert_eq!(plan(&names(&[SDK_V1_1, DOCUMENTED])), Plan::Pass);
    assert_eq!(plan(&names(&[SDK_V1])), Plan::Pass);
    assert_eq!(plan(&names(&["foo.v1"])), Plan::Refused);
    assert_eq!(plan(&names(&[])), Plan::Refused);
    // Names are tokens, compared whole: a prefix or another case is another name.
    assert_eq!(plan(&names(&["foxglove.websocket.v10"])), Plan::Refused);
    assert_eq!(plan(&names(&["Foxglove.WebSocket.v1"])), Plan::Refused);
}

#[test]
fn a_renamed_request_offers_the_servers_name_once_and_keeps_every_other_line() {
    let head = request(&["foo.v1, foxglove.websocket.v1"]).replace(
        "\r\n\r\n",
        "\r\nX-Other: 1\r\nSEC-WEBSOCKET-PROTOCOL: bar\r\n\r\n",
    );
    let renamed = String::from_utf8(rename_request(head.as_bytes()).unwrap()).unwrap();
    let expected = head
        .replace(
            "Sec-WebSocket-Protocol: foo.v1, foxglove.websocket.v1",
            "Sec-WebSocket-Protocol: foxglove.sdk.v1",
        )
        .replace("SEC-WEBSOCKET-PROTOCOL: bar\r\n", "");
    assert_eq!(renamed, expected);
    assert_eq!(offered(renamed.as_bytes()).unwrap(), names(&[SDK_V1]));
}

#[test]
fn the_servers_answer_names_the_documented_protocol_and_a_refusal_is_untouched() {
    let ok = "HTTP/1.1 101 Switching Protocols\r\nconnection: Upgrade\r\nupgrade: websocket\r\n\
              sec-websocket-accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n\
              sec-websocket-protocol: foxglove.sdk.v1\r\n\r\n";
    let renamed = String::from_utf8(rename_response(ok.as_bytes()).unwrap()).unwrap();
    assert_eq!(
        renamed,
        ok.replace(
            "sec-websocket-protocol: foxglove.sdk.v1",
            "sec-websocket-protocol: foxglove.websocket.v1"
        )
    );
    let refused = "HTTP/1.1 400 Bad Request\r\ncontent-length: 3\r\n\r\n";
    assert_eq!(
        rename_response(refused.as_bytes()).unwrap(),
        refused.as_bytes()
    );
    let newer = ok.replace(SDK_V1, SDK_V1_1);
    assert_eq!(rename_response(newer.as_bytes()).unwrap(), newer.as_bytes());
}

#[test]
fn a_malformed_head_is_refused_saying_why() {
    let good = request(&[DOCUMENTED]);
    for (head, says) in [
        (good.trim_end().to_string(), "blank line"),
        ("\r\n\r\n".to_string(), "no request or status line"),
        (
            good.replace("Upgrade: websocket\r\n", "Upgrade: websocket\nX: y\r\n"),
            "bare CR or LF",
        ),
        (
            good.replace("Upgrade: websocket\r\n", "Upgrade: web\rsocket\r\n"),
            "bare CR or LF",
        ),
        (
            good.replace("Upgrade: websocket\r\n", "Upgrade:\r\n websocket\r\n"),
            "folded",
        ),
        (
            good.replace("Upgrade: websocket\r\n", "Upgrade websocket\r\n"),
            "no colon",
        ),
        (
            good.replace("Upgrade: websocket\r\n", ": websocket\r\n"),
            "no header name",
        ),
        (
            good.replace("Upgrade: websocket\r\n", "Up grade: websocket\r\n"),
            "no header name",
        ),
    ] {
        for e in [
            offered(head.as_bytes()).unwrap_err(),
            rename_request(head.as_bytes()).unwrap_err(),
            rename_response(head.as_bytes()).unwrap_err(),
        ] {
            assert!(e.contains(says), "{head:?}: {e}");
        }
    }
}

#[test]
fn a_head_ends_at_the_first_blank_line() {
    assert_eq!(head_end(b"GET / HTTP/1.1\r\n\r\nrest\r\n\r\n"), Some(18));
    assert_eq!(head_end(b"GET / HTTP/1.1\r\n\r"), None);
    assert_eq!(head_end(b"GET / HTTP/1.1\n\n"), None);
}

/// A connected pair of sockets: (this end, the other end).
fn pair() -> (TcpStream, TcpStream) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let a = TcpStream::connect(listener.local_addr().unwrap()).unwrap();
    (a, listener.accept().unwrap().0)
}

#[test]
fn reading_a_head_returns_what_came_after_it_and_gives_up_past_its_bounds() {
    let deadline = || Instant::now() + PATIENCE;
    // In pieces, with the first bytes after it.
    let (mut w, r) = pair();
    w.write_all(b"GET / HTTP/1.1\r\nHost: x\r").unwrap();
    w.write_all(b"\n\r\n\x81\x02hi").unwrap();
    let (head, rest) = read_head(&r, deadline()).unwrap();
    assert_eq!(head, b"GET / HTTP/1.1\r\nHost: x\r\n\r\n");
    assert_eq!(rest, b"\x81\x02hi");

    // Oversized: the end just past MAX_HEAD bytes, or none in twice as many.
    let a = "a".repeat(MAX_HEAD);
    for long in [
        format!("GET / HTTP/1.1\r\nX: {a}\r\n\r\n"),
        format!("GET / HTTP/1.1\r\nX: {a}{a}"),
    ] {
        let (mut w, r) = pair();
        let writer = std::thread::spawn(move || {
            let _ = w.write_all(long.as_bytes());
            w
        });
        let e = read_head(&r, deadline()).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidData, "{e}");
        assert!(e.to_string().contains("16384 bytes"), "{e}");
        drop(r);
        drop(writer.join().unwrap());
    }

    // Closed before the end.
    let (mut w, r) = pair();
    w.write_all(b"GET / HTTP/1.1\r\n").unwrap();
    drop(w);
    let e = read_head(&r, deadline()).unwrap_err();
    assert_eq!(e.kind(), io::ErrorKind::UnexpectedEof, "{e}");

    // Silent past the deadline (one already passed).
    let (_w, r) = pair();
    let e = read_head(&r, Instant::now() + Duration::from_millis(1)).unwrap_err();
    assert_eq!(e.kind(), io::ErrorKind::TimedOut, "{e}");
}

/// A stand-in for the foxglove server: answers each upgrade with 101 naming the first
/// subprotocol offered and `hello` right behind it, then echoes. Sends each request head it got.
fn fake_server() -> (SocketAddr, mpsc::Receiver<String>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let address = listener.local_addr().unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for conn in listener.incoming() {
            let (mut conn, tx) = (conn.unwrap(), tx.clone());
            std::thread::spawn(move || {
                let Ok((head, rest)) = read_head(&conn, Instant::now() + PATIENCE) else {
                    return;
                };
                let first = offered(&head).unwrap().first().cloned().unwrap_or_default();
                let _ = tx.send(String::from_utf8(head).unwrap());
                let answer = format!(
                    "HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: {first}\r\n\r\nhello"
                );
                conn.write_all(answer.as_bytes()).unwrap();
                conn.write_all(&rest).unwrap();
                conn.set_read_timeout(None).unwrap();
                let mut buffer = [0; 1024];
                while let Ok(n @ 1..) = conn.read(&mut buffer) {
                    if conn.write_all(&buffer[..n]).is_err() {
                        break;
                    }
                }
            });
        }
    });
    (address, rx)
}

fn door(upstream: SocketAddr) -> Door {
    Door::start("127.0.0.1:0".parse().unwrap(), upstream).unwrap()
}

/// Connects through `door` offering `protocols`, with `extra` right behind the request;
/// returns the socket and the answer's head and what came after it.
fn connect(door: &Door, protocols: &[&str], extra: &[u8]) -> (TcpStream, String, Vec<u8>) {
    let mut s = TcpStream::connect(door.address()).unwrap();
    let mut bytes = request(protocols).into_bytes();
    bytes.extend_from_slice(extra);
    s.write_all(&bytes).unwrap();
    let (head, rest) = read_head(&s, Instant::now() + PATIENCE).unwrap();
    (s, String::from_utf8(head).unwrap(), rest)
}

/// Reads until `want` bytes came (or the stream ended).
fn read_n(mut s: &TcpStream, got: &mut Vec<u8>, want: usize) {
    s.set_read_timeout(Some(PATIENCE)).unwrap();
    let mut buffer = [0; 1024];
    while got.len() < want {
        match s.read(&mut buffer) {
            Ok(0) | Err(_) => break,
            Ok(n) => got.extend_from_slice(&buffer[..n]),
        }
    }
}

#[test]
fn the_door_renames_the_documented_subprotocol_both_ways_and_then_copies_bytes() {
    let (upstream, heads) = fake_server();
    let door = door(upstream);
    let (mut s, head, mut rest) = connect(&door, &[DOCUMENTED], b"early");
    assert!(
        head.contains("sec-websocket-protocol: foxglove.websocket.v1\r\n"),
        "{head}"
    );
    let seen = heads.recv_timeout(PATIENCE).unwrap();
    assert_eq!(
        offered(seen.as_bytes()).unwrap(),
        names(&[SDK_V1]),
        "{seen}"
    );
    // What the server sent behind its answer, then the client's early bytes, echoed.
    read_n(&s, &mut rest, 10);
    assert_eq!(rest, b"helloearly");
    s.write_all(b"more").unwrap();
    let mut echoed = Vec::new();
    read_n(&s, &mut echoed, 4);
    assert_eq!(echoed, b"more");
    door.stop();
}

#[test]
fn the_door_passes_the_servers_names_and_unknown_ones_unchanged() {
    let (upstream, heads) = fake_server();
    let door = door(upstream);
    for offer in [&[SDK_V1_1, DOCUMENTED][..], &[SDK_V1], &["foo.v1"], &[]] {
        let (_s, head, _) = connect(&door, offer, b"");
        let seen = heads.recv_timeout(PATIENCE).unwrap();
        assert_eq!(seen, request(offer));
        let first = offer.first().copied().unwrap_or_default();
        assert!(
            head.contains(&format!("sec-websocket-protocol: {first}\r\n")),
            "{head}"
        );
    }
}

#[test]
fn the_door_serves_a_bounded_number_of_connections_and_refuses_more_with_503() {
    let (upstream, _heads) = fake_server();
    let door = door(upstream);
    let mut open: Vec<TcpStream> = (0..MAX_CONNECTIONS)
        .map(|_| connect(&door, &[SDK_V1], b"").0)
        .collect();
    let (s, head, mut body) = connect(&door, &[SDK_V1], b"");
    assert!(head.starts_with("HTTP/1.1 503 "), "{head}");
    read_n(&s, &mut body, usize::MAX);
    assert!(
        String::from_utf8_lossy(&body).contains("16 connections are open"),
        "{body:?}"
    );
    // One leaves: another is served once the door has seen it go.
    drop(open.pop());
    let end = Instant::now() + PATIENCE;
    loop {
        let (s, head, _) = connect(&door, &[SDK_V1], b"");
        if head.starts_with("HTTP/1.1 101 ") {
            open.push(s);
            break;
        }
        assert!(Instant::now() < end, "still refused: {head}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn the_door_drops_an_oversized_request_without_asking_the_server() {
    let (upstream, heads) = fake_server();
    let door = door(upstream);
    let mut s = TcpStream::connect(door.address()).unwrap();
    let long = format!("GET / HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(MAX_HEAD));
    let _ = s.write_all(long.as_bytes());
    let mut got = Vec::new();
    read_n(&s, &mut got, 1);
    assert!(got.is_empty(), "{got:?}");
    drop(door);
    assert!(heads.try_recv().is_err(), "the server got a request");
}

#[test]
fn stopping_the_door_closes_its_connections_both_ways() {
    let (upstream, _heads) = fake_server();
    let door = door(upstream);
    let (s, head, mut rest) = connect(&door, &[SDK_V1], b"");
    assert!(head.starts_with("HTTP/1.1 101 "), "{head}");
    read_n(&s, &mut rest, 5);
    let address = door.address();
    door.stop();
    let mut after = Vec::new();
    read_n(&s, &mut after, 1);
    assert!(after.is_empty(), "{after:?}");
    assert!(TcpStream::connect(address).is_err(), "still listening");
}

/// The foxglove crate's own server behind the door: what the door renames, it accepts.
#[test]
fn the_crates_server_behind_the_door_negotiates_every_name_and_refuses_others() {
    let context = foxglove::Context::new();
    let server = foxglove::WebSocketServer::new()
        .context(&context)
        .bind("127.0.0.1", 0)
        .start_blocking()
        .unwrap();
    let door = door(SocketAddr::from(([127, 0, 0, 1], server.port())));
    for (offer, answer) in [
        (&[DOCUMENTED][..], Some(DOCUMENTED)),
        (&[SDK_V1], Some(SDK_V1)),
        (&[DOCUMENTED, SDK_V1_1], Some(SDK_V1_1)),
        (&["foo.v1"], None),
    ] {
        let (s, head, mut rest) = connect(&door, offer, b"");
        let head = head.to_ascii_lowercase();
        match answer {
            Some(name) => {
                assert!(head.starts_with("http/1.1 101 "), "{offer:?}: {head}");
                let header = format!("sec-websocket-protocol: {name}\r\n");
                assert!(head.contains(&header), "{offer:?}: {head}");
                // The server's first message, through the door.
                let end = Instant::now() + PATIENCE;
                while !String::from_utf8_lossy(&rest).contains("serverInfo") {
                    assert!(Instant::now() < end, "{rest:?}");
                    let want = rest.len() + 1;
                    read_n(&s, &mut rest, want);
                }
            }
            None => assert!(head.starts_with("http/1.1 400 "), "{offer:?}: {head}"),
        }
    }
    door.stop();
    server.stop().wait_blocking();
}
