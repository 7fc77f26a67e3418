//! `softarm view`: the running stack, live, over the Foxglove WebSocket protocol (v1, the
//! `foxglove` crate's server), for Foxglove or Lichtblick. A viewer may offer the subprotocol
//! under the name the protocol documents, `foxglove.websocket.v1` (older Lichtblick, Foxglove
//! Studio, `@foxglove/ws-protocol` clients), or under the crate's names for the same messages,
//! `foxglove.sdk.v1` and `foxglove.sdk.v1.1` (schemas advertised once per connection). The crate
//! (0.30) negotiates only its own names, so it listens on an ephemeral loopback port behind a
//! front door ([`door`]) on the configured address, which renames `foxglove.websocket.v1` to
//! `foxglove.sdk.v1` in the handshake and back in the answer, then copies bytes unchanged. A
//! viewer that offers none of the three gets the server's HTTP 400, and the log says why.
//!
//! What it serves, read-only (no client publishing, no services, no parameters):
//!
//! - every pub/sub service of the namespace as a channel, exactly as `softarm record` writes
//!   them (`softarm_channels`: the service's name, JSON, a JSON Schema named after the
//!   payload's type), `log_time` the wall clock when the view received the sample;
//! - `scene`: the stack in 3-D (`softarm_channels::scene`, `foxglove.SceneUpdate`, protobuf) at
//!   `view.scene_hz`: the arm drawn from the measured actuation through the configured arm
//!   model, way-points, the tracker and its trail, the reached points, the base frame.
//!
//! It is one more subscriber, like the recorder: the controller never waits for it. Each client
//! gets at most `view.backlog` messages queued; a client that reads slower loses the oldest
//! (the server's queue drops them, it never blocks this loop nor grows; the door copies with a
//! fixed buffer, so a slow client holds up only its own copy). It listens on loopback unless the
//! config says `view.allow_remote = true`, and serves at most [`door::MAX_CONNECTIONS`] viewers
//! at once (more get HTTP 503).
//!
//! The loop, every millisecond or sooner: [`View::receive`] (every sample waiting, to its
//! channel and into the scene), [`View::draw`] (the scene when due), [`View::report`] (clients
//! that came or went, to the log). The door runs on threads of its own.

pub mod door;
pub mod layout;

use std::collections::HashMap;
use std::net::{Ipv4Addr, SocketAddr};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::Context as _;
use foxglove::messages::SceneUpdate;
use foxglove::{Channel, ChannelBuilder, Context, PartialMetadata, RawChannel, Schema};
use foxglove::{WebSocketServer, WebSocketServerHandle};
use softarm_channels::Services;
use softarm_channels::scene::{self, Scene};
use softarm_config::Config;
use softarm_ipc::{Namespace, Node};

use crate::door::Door;

/// `softarm view --layout FILE`: the Foxglove layout for `arm` ([`layout::for_arm`]) written
/// to `file`, whole or not at all.
pub fn write_layout(file: &std::path::Path, arm: &softarm_arm::Layout) -> anyhow::Result<()> {
    let json = serde_json::to_string_pretty(&layout::for_arm(arm))?;
    softarm_runtime::file::write_atomic(file, format!("{json}\n").as_bytes(), None)
        .with_context(|| format!("writing the layout to {}", file.display()))
}

/// Runs the view of `config`'s stack until `stop` is set, listening on `listen` (a command
/// line's `--listen`) or the config's `view.listen`.
pub fn run(config: &Config, listen: Option<&str>, stop: &AtomicBool) -> anyhow::Result<()> {
    let address = match listen {
        Some(l) => config.view.address(l, "--listen"),
        None => config.view.address(&config.view.listen, "view.listen"),
    }
    .map_err(anyhow::Error::msg)?;
    let namespace = config.bus()?;
    let node = Node::open(namespace.clone(), "view")
        .with_context(|| format!("joining namespace {:?}", namespace.as_str()))?;
    let services = Services::open(&node)?;
    let mut view = View::open(config, &namespace, address, services)?;
    tracing::info!(
        "serving the stack on ws://{} (Foxglove WebSocket protocol, subprotocol {}): {} \
         channels, read-only",
        view.door.address(),
        door::ACCEPTED,
        view.channels.len() + 1
    );
    while !stop.load(Ordering::Relaxed) {
        if view.step()? == 0 {
            // Sensor topics arrive at up to 1 kHz into buffers of 4 or more.
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    tracing::info!(clients = view.server.client_count(), "view stopped");
    view.server.stop().detach_all();
    view.door.stop();
    drop(node);
    Ok(())
}

/// The server, its door and what it serves.
struct View {
    server: WebSocketServerHandle,
    door: Door,
    /// One per service, in the order of `Services::specs`.
    channels: Vec<Arc<RawChannel>>,
    scene_channel: Channel<SceneUpdate>,
    scene: Scene,
    services: Services,
    clients: usize,
    /// Keeps the channels' context alive as long as the server.
    _context: Arc<Context>,
}

impl View {
    /// Declares a channel per service and the scene's, and starts the server behind a door on
    /// `address`.
    fn open(
        config: &Config,
        namespace: &Namespace,
        address: SocketAddr,
        services: Services,
    ) -> anyhow::Result<Self> {
        let context = Context::new();
        let mut channels = Vec::new();
        for s in services.specs() {
            let schema = Schema::new(s.schema_name, "jsonschema", s.schema.clone().into_bytes());
            let channel = ChannelBuilder::new(s.topic)
                .context(&context)
                .message_encoding("json")
                .schema(schema)
                .build_raw()
                .with_context(|| format!("declaring the channel {}", s.topic))?;
            channels.push(channel);
        }
        let scene_channel = ChannelBuilder::new(scene::TOPIC)
            .context(&context)
            .build::<SceneUpdate>();
        let info = HashMap::from([
            ("namespace".to_string(), namespace.as_str().to_string()),
            ("softarm".to_string(), env!("CARGO_PKG_VERSION").to_string()),
        ]);
        // Only the door reaches it: an ephemeral loopback port.
        let server = WebSocketServer::new()
            .name(format!("softarm {}", namespace.as_str()))
            .context(&context)
            .bind(Ipv4Addr::LOCALHOST.to_string(), 0)
            .server_info(info)
            .message_backlog_size(config.view.backlog)
            .start_blocking()
            .context("starting the view's server on an ephemeral port of 127.0.0.1")?;
        let upstream = SocketAddr::from((Ipv4Addr::LOCALHOST, server.port()));
        let door = match Door::start(address, upstream) {
            Ok(d) => d,
            Err(e) => {
                server.stop().detach_all();
                return Err(e)
                    .with_context(|| format!("listening on {address} (view.listen or --listen)"));
            }
        };
        Ok(Self {
            server,
            door,
            channels,
            scene_channel,
            scene: Scene::new(scene::Settings::of(config)),
            services,
            clients: 0,
            _context: context,
        })
    }

    /// One pass of the loop; returns the samples received.
    fn step(&mut self) -> anyhow::Result<u64> {
        let n = self.receive()?;
        self.draw();
        self.report();
        Ok(n)
    }

    /// Every sample waiting: into the scene, and to its channel if a client subscribes.
    fn receive(&mut self) -> anyhow::Result<u64> {
        let (channels, scene) = (&self.channels, &mut self.scene);
        self.services.drain(|i, p| {
            scene.take(p);
            let channel = &channels[i];
            if channel.has_sinks() {
                let at = PartialMetadata::with_log_time(realtime_ns());
                channel.log_with_meta(&p.json(), at);
            }
            Ok(())
        })
    }

    /// The scene, when due and a client subscribes to it.
    fn draw(&mut self) {
        let now = Instant::now();
        if self.scene.due(now) && self.scene_channel.has_sinks() {
            let realtime = realtime_ns();
            let update = self.scene.update(now, realtime);
            self.scene_channel
                .log_with_meta(&update, PartialMetadata::with_log_time(realtime));
        }
    }

    /// Clients that connected or left, to the log.
    fn report(&mut self) {
        let clients = self.server.client_count();
        if clients != self.clients {
            tracing::info!(clients, "view clients");
            self.clients = clients;
        }
    }
}

fn realtime_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}
