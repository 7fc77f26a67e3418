//! `softarm ros2`: the running stack bridged to ROS 2, with `ros2-client` (pure Rust over
//! RustDDS: no ROS install, DDS/RTPS on the wire as any ROS 2 Jazzy node speaks it).
//!
//! Under the ROS 2 namespace of the stack's namespace (`softarm/<robot.id>` →
//! `/softarm/<robot_id>`, [`convert::ros_namespace`]):
//!
//! - out: `setpoint` and `joint_states` (`sensor_msgs/JointState`, the controller's setpoints
//!   and the driver's measured actuation, joints named as `[arm]` names the actuators), `tracker`
//!   (`geometry_msgs/PointStamped`, frame `base`), each the newest sample at most
//!   `ros2.topic_hz` a second; `diagnostics` (`diagnostic_msgs/DiagnosticArray`: controller,
//!   driver, e-stop, the last execution, the bridge) `ros2.status_hz` a second;
//! - in: `estop` (`std_msgs/Empty`), always: engages the e-stop as `softarm estop` does (a
//!   reset is never possible from ROS 2); `waypoints` (`trajectory_msgs/MultiDOFJointTrajectory`),
//!   submitted as `softarm submit` does only with `ros2.accept_waypoints`, else refused.
//!
//! It is one more subscriber of the stack's services, like the view: the controller never
//! waits for it, and it dying costs the stack nothing. The stack dying leaves it up, saying so
//! in the diagnostics (STALE).
//!
//! The loop, every millisecond or sooner, as named steps ([`Bridge::step`]): `receive` (every
//! sample waiting), `publish` (the newest of each topic when due), `take_estop`,
//! `take_waypoints`, `collect` (the controller's answers to sets submitted), `report` (the
//! diagnostics when due).

pub mod convert;
pub mod msg;

use std::net::{IpAddr, Ipv4Addr};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::Context as _;
use ros2_client::dds::rustdds::{DomainParticipantBuilder, Topic};
use ros2_client::{
    Context, MessageTypeName, Name, NodeName, NodeOptions, Publisher, QosProfile, Subscription,
};
use serde::Serialize;
use serde::de::DeserializeOwned;
use softarm_channels::{Payload, Services};
use softarm_clients::estop::{CONFIRM_TIMEOUT, Estop, Pending};
use softarm_clients::submit::{self, Outcome};
use softarm_config::Config;
use softarm_config::ros2::Discovery;
use softarm_ipc::{
    ControllerStatus, ExecutionStats, MotorState, Namespace, Node, Setpoint, TrackerSample,
};

use crate::convert::{BridgeReport, Snapshot};
use crate::msg::{
    DiagnosticArray, Empty, JointState, MultiDofJointTrajectory, PointStamped, TypeName,
};

/// The topics, relative to the stack's ROS 2 namespace.
pub mod topic {
    pub const SETPOINT: &str = "setpoint";
    pub const JOINT_STATES: &str = "joint_states";
    pub const TRACKER: &str = "tracker";
    pub const DIAGNOSTICS: &str = "diagnostics";
    pub const WAYPOINTS: &str = "waypoints";
    pub const ESTOP: &str = "estop";
}

/// How long a set submitted waits for the controller's answer.
const SUBMIT_TIMEOUT: Duration = Duration::from_secs(10);

/// Runs the bridge of `config`'s stack until `stop` is set.
pub fn run(config: &Config, stop: &AtomicBool) -> anyhow::Result<()> {
    let namespace = config.bus()?;
    let node = Node::open(namespace.clone(), "ros2")
        .with_context(|| format!("joining namespace {:?}", namespace.as_str()))?;
    let services = Services::open(&node)?;
    let mut bridge = Bridge::open(config, namespace, services)?;
    tracing::info!(
        "bridging the stack to ROS 2 under {} (DDS domain {}, discovery {:?}, way-point sets {})",
        bridge.ros_namespace,
        config.ros2.domain_id,
        config.ros2.discovery,
        if config.ros2.accept_waypoints {
            "accepted"
        } else {
            "refused"
        }
    );
    while !stop.load(Ordering::Relaxed) {
        if bridge.step()? == 0 {
            // Sensor samples arrive at up to 1 kHz into buffers of 4 or more.
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    tracing::info!("ros2 bridge stopped");
    Ok(())
}

/// The DDS side: one participant, one node, a writer or reader per topic.
struct Ros {
    setpoint: Publisher<JointState>,
    joint_states: Publisher<JointState>,
    tracker: Publisher<PointStamped>,
    diagnostics: Publisher<DiagnosticArray>,
    waypoints: Subscription<MultiDofJointTrajectory>,
    /// A reliable reader and a best-effort one: a reliable reader matches no best-effort
    /// writer, and an e-stop is heard from either kind.
    estop: [Subscription<Empty>; 2],
    /// Keeps the participant and its discovery alive as long as the endpoints.
    _node: ros2_client::Node,
}

impl Ros {
    fn open(config: &Config, namespace: &str) -> anyhow::Result<Self> {
        let r = &config.ros2;
        let mut participant = DomainParticipantBuilder::new(r.domain_id);
        if r.discovery == Discovery::Localhost {
            // Advertise and multicast on loopback only; RustDDS also announces itself to the
            // well-known unicast ports on 127.0.0.1, so peers on this host find it.
            participant = participant.with_only_networks([IpAddr::V4(Ipv4Addr::LOCALHOST)]);
        }
        let participant = participant
            .build()
            .with_context(|| format!("joining DDS domain {} (ros2.domain_id)", r.domain_id))?;
        let context =
            Context::from_domain_participant(participant).context("starting the ROS 2 context")?;
        let node_name = NodeName::new(namespace, "softarm_bridge")
            .map_err(|e| anyhow::anyhow!("the ROS 2 node name under {namespace}: {e:?}"))?;
        let mut node = context
            .new_node(node_name, NodeOptions::new().enable_rosout(false))
            .context("creating the ROS 2 node")?;
        // Sensor topics: the newest matters, a late joiner needs no history.
        let sensor = QosProfile::publisher_default();
        // Commands and diagnostics: reliable, a few kept for a reader that is briefly behind.
        let reliable = QosProfile::publisher_default()
            .history(ros2_client::qos::History::KeepLast { depth: 8 });
        Ok(Self {
            setpoint: publisher(&mut node, namespace, topic::SETPOINT, &sensor)?,
            joint_states: publisher(&mut node, namespace, topic::JOINT_STATES, &sensor)?,
            tracker: publisher(&mut node, namespace, topic::TRACKER, &sensor)?,
            diagnostics: publisher(&mut node, namespace, topic::DIAGNOSTICS, &reliable)?,
            waypoints: subscription(&mut node, namespace, topic::WAYPOINTS, &reliable)?,
            estop: [
                subscription(&mut node, namespace, topic::ESTOP, &reliable)?,
                subscription(
                    &mut node,
                    namespace,
                    topic::ESTOP,
                    &reliable.reliability_best_effort(),
                )?,
            ],
            _node: node,
        })
    }
}

fn ros_topic<M: TypeName>(
    node: &mut ros2_client::Node,
    namespace: &str,
    name: &str,
    qos: &QosProfile,
) -> anyhow::Result<Topic> {
    let full = Name::new(namespace, name)
        .map_err(|e| anyhow::anyhow!("the ROS 2 topic name {namespace}/{name}: {e:?}"))?;
    node.create_topic(&full, MessageTypeName::new(M::PACKAGE, M::NAME), qos)
        .with_context(|| format!("creating the topic {namespace}/{name}"))
}

fn publisher<M: TypeName + Serialize>(
    node: &mut ros2_client::Node,
    namespace: &str,
    name: &str,
    qos: &QosProfile,
) -> anyhow::Result<Publisher<M>> {
    let t = ros_topic::<M>(node, namespace, name, qos)?;
    // The writer's own QoS: RustDDS takes the publisher's default, not the topic's.
    node.create_publisher(&t, Some(qos.clone()))
        .with_context(|| format!("publishing {namespace}/{name}"))
}

fn subscription<M: TypeName + DeserializeOwned + 'static>(
    node: &mut ros2_client::Node,
    namespace: &str,
    name: &str,
    qos: &QosProfile,
) -> anyhow::Result<Subscription<M>> {
    let t = ros_topic::<M>(node, namespace, name, qos)?;
    node.create_subscription(&t, Some(qos.clone()))
        .with_context(|| format!("subscribing to {namespace}/{name}"))
}

/// The newest sample of each service the bridge forwards, and when it came.
#[derive(Default)]
struct Latest {
    setpoint: Option<Setpoint>,
    motor: Option<(MotorState, Instant)>,
    tracker: Option<TrackerSample>,
    status: Option<(ControllerStatus, Instant)>,
    stats: Option<ExecutionStats>,
    /// Which of setpoint, motor state and tracker came since they were last published.
    fresh: [bool; 3],
}

impl Latest {
    fn take(&mut self, p: &Payload) {
        let now = Instant::now();
        match *p {
            Payload::Setpoint(s) => (self.setpoint, self.fresh[0]) = (Some(s), true),
            Payload::MotorState(m) => (self.motor, self.fresh[1]) = (Some((m, now)), true),
            Payload::Tracker(t) => (self.tracker, self.fresh[2]) = (Some(t), true),
            Payload::Status(s) => self.status = Some((s, now)),
            Payload::Stats(s) => self.stats = Some(s),
            _ => {}
        }
    }
}

/// The bridge: the stack's side, the ROS 2 side, and what it did.
struct Bridge {
    config: Config,
    /// The joints of every `JointState`: the arm's actuators by their names (`[arm]`).
    joints: Vec<String>,
    namespace: Namespace,
    ros_namespace: String,
    services: Services,
    ros: Ros,
    latest: Latest,
    /// System clock minus CLOCK_MONOTONIC (ns), taken once: sample stamps as ROS time.
    offset_ns: i128,
    topic_period: Duration,
    status_period: Duration,
    next_topics: Instant,
    next_status: Instant,
    report: BridgeReport,
    estop: Estop,
    /// The e-stop sent from ROS 2 that the stack has not confirmed yet, and when.
    estop_pending: Option<(Pending, Instant)>,
    /// The controller's answers to sets being submitted (each on a thread of its own, so the
    /// loop and the e-stop never wait for one).
    answers: (mpsc::Sender<Outcome>, mpsc::Receiver<Outcome>),
    submitting: bool,
    publish_failures: u64,
}

impl Bridge {
    fn open(config: &Config, namespace: Namespace, services: Services) -> anyhow::Result<Self> {
        let ros_namespace = convert::ros_namespace(namespace.as_str());
        let ros = Ros::open(config, &ros_namespace)?;
        let estop = Estop::open(&namespace)?;
        let now = Instant::now();
        Ok(Self {
            config: config.clone(),
            joints: config.layout().names().map(String::from).collect(),
            namespace,
            ros_namespace,
            services,
            ros,
            latest: Latest::default(),
            offset_ns: clock_offset_ns(),
            topic_period: Duration::from_secs_f64(1.0 / config.ros2.topic_hz),
            status_period: Duration::from_secs_f64(1.0 / config.ros2.status_hz),
            next_topics: now,
            next_status: now,
            report: BridgeReport {
                accept_waypoints: config.ros2.accept_waypoints,
                ..Default::default()
            },
            estop,
            estop_pending: None,
            answers: mpsc::channel(),
            submitting: false,
            publish_failures: 0,
        })
    }

    /// One pass of the loop; returns the stack's samples received.
    fn step(&mut self) -> anyhow::Result<u64> {
        let n = self.receive()?;
        self.publish();
        self.take_estop();
        self.take_waypoints();
        self.collect();
        self.report();
        Ok(n)
    }

    /// Every sample waiting, kept as the newest of its service.
    fn receive(&mut self) -> anyhow::Result<u64> {
        let latest = &mut self.latest;
        self.services.drain(|_, p| {
            latest.take(p);
            Ok(())
        })
    }

    /// The newest setpoint, motor state and tracker position, each if it is new and due.
    fn publish(&mut self) {
        let now = Instant::now();
        if now < self.next_topics {
            return;
        }
        self.next_topics = now + self.topic_period;
        let (l, offset) = (&mut self.latest, self.offset_ns);
        let mut ok = true;
        let joints = &self.joints;
        if let (Some(s), true) = (&l.setpoint, l.fresh[0])
            && let Some(j) = convert::setpoint_state(s, joints, offset)
        {
            ok &= self.ros.setpoint.publish(j).is_ok();
        }
        if let (Some((m, _)), true) = (&l.motor, l.fresh[1])
            && let Some(j) = convert::measured_state(m, joints, offset)
        {
            ok &= self.ros.joint_states.publish(j).is_ok();
        }
        if let (Some(t), true) = (&l.tracker, l.fresh[2]) {
            ok &= self
                .ros
                .tracker
                .publish(convert::tracker_point(t, offset))
                .is_ok();
        }
        l.fresh = [false; 3];
        self.count_failure(ok);
    }

    /// A failed write is a reader gone or slow: counted, logged once in a while.
    fn count_failure(&mut self, ok: bool) {
        if !ok {
            self.publish_failures += 1;
            if self.publish_failures.is_power_of_two() {
                tracing::warn!(
                    failures = self.publish_failures,
                    "a ROS 2 message could not be written (a slow or vanished reader)"
                );
            }
        }
    }

    /// Any e-stop message engages the e-stop as `softarm estop` does: published to the stack,
    /// then latched on disk. Nothing here can release it.
    fn take_estop(&mut self) {
        let mut heard = 0;
        for reader in &self.ros.estop {
            loop {
                match reader.take() {
                    Ok(Some(_)) => heard += 1,
                    Ok(None) => break,
                    Err(e) => {
                        // Even a message that does not decode asked for a stop.
                        tracing::warn!("an undecodable message on {}: {e:?}", topic::ESTOP);
                        heard += 1;
                    }
                }
            }
        }
        if heard == 0 {
            self.confirm_estop();
            return;
        }
        self.report.estops += 1;
        let latch = self.config.estop_latch();
        match self.estop.send(&latch, true) {
            Ok(p) => {
                tracing::warn!(
                    "e-stop from ROS 2 ({}/{}): sent to {} processes and latched; reset only \
                     with `softarm estop --reset` on this host",
                    self.ros_namespace,
                    topic::ESTOP,
                    p.receivers
                );
                self.report.estop_confirmation = Some("waiting for the stack".into());
                self.estop_pending = Some((p, Instant::now()));
            }
            Err(e) => {
                tracing::error!("e-stop from ROS 2: {e:#}");
                self.report.estop_confirmation = Some(format!("not sent: {e:#}"));
            }
        }
    }

    /// Whether the stack said STOPPED since the e-stop from ROS 2, without waiting: what the
    /// diagnostics say of it, and a log line either way.
    fn confirm_estop(&mut self) {
        let Some((pending, since)) = &mut self.estop_pending else {
            return;
        };
        let c = match self.estop.poll(pending) {
            Ok(c) => c,
            Err(e) => {
                tracing::error!("confirming the e-stop from ROS 2: {e:#}");
                return;
            }
        };
        let said = if c.complete() {
            tracing::warn!("e-stop from ROS 2 confirmed: {}", c.confirmed.join(", "));
            format!("confirmed: {}", c.confirmed.join(", "))
        } else if since.elapsed() >= CONFIRM_TIMEOUT {
            tracing::error!(
                "e-stop from ROS 2 not confirmed in {:.0} s by: {}",
                CONFIRM_TIMEOUT.as_secs_f64(),
                c.missing.join("; ")
            );
            format!("not confirmed by: {}", c.missing.join("; "))
        } else {
            return;
        };
        self.report.estop_confirmation = Some(said);
        self.estop_pending = None;
    }

    /// Way-point sets from ROS 2: refused unless `ros2.accept_waypoints`, checked as `softarm
    /// submit` checks a file, then submitted on a thread of their own.
    fn take_waypoints(&mut self) {
        loop {
            match self.ros.waypoints.take() {
                Ok(Some((t, _))) => self.offer(&t),
                Ok(None) => break,
                Err(e) => self.refuse(format!("the message does not decode: {e:?}")),
            }
        }
    }

    fn offer(&mut self, t: &MultiDofJointTrajectory) {
        if !self.config.ros2.accept_waypoints {
            return self.refuse(
                "ros2.accept_waypoints is false (read-only): set it to true in the config to \
                 execute sets from ROS 2"
                    .into(),
            );
        }
        if self.submitting {
            return self.refuse("the set before it is still being submitted".into());
        }
        let set = match convert::waypoint_set(t, &self.config) {
            Ok(s) => s,
            Err(why) => return self.refuse(why),
        };
        let (namespace, answers) = (self.namespace.clone(), self.answers.0.clone());
        self.submitting = true;
        std::thread::spawn(move || {
            let _ = answers.send(submit::submit(&namespace, set, SUBMIT_TIMEOUT));
        });
    }

    fn refuse(&mut self, why: String) {
        tracing::warn!(
            "way-point set from ROS 2 ({}/{}) refused, nothing submitted: {why}",
            self.ros_namespace,
            topic::WAYPOINTS
        );
        self.report.sets_refused += 1;
        self.report.last_refusal = Some(why);
    }

    /// The controller's answer to a set submitted, if it came.
    fn collect(&mut self) {
        let Ok(outcome) = self.answers.1.try_recv() else {
            return;
        };
        self.submitting = false;
        match outcome {
            Outcome::Accepted { set_id } => {
                tracing::info!("way-point set from ROS 2 accepted: set {set_id}");
                self.report.sets_accepted += 1;
                self.report.last_set_id = set_id;
                self.report.last_refusal = None;
            }
            Outcome::Rejected { reason } => self.refuse(format!("the controller: {reason}")),
            Outcome::Unreachable { message } => self.refuse(message),
        }
    }

    /// The diagnostics, when due.
    fn report(&mut self) {
        let now = Instant::now();
        if now < self.next_status {
            return;
        }
        self.next_status = now + self.status_period;
        let age = |at: Instant| now.duration_since(at).as_secs_f64();
        let snapshot = Snapshot {
            status: self.latest.status.map(|(s, at)| (s, age(at))),
            motor: self.latest.motor.map(|(m, at)| (m, age(at))),
            stats: self.latest.stats,
            estop_latched: self.config.estop_latch().engaged().ok(),
            bridge: self.report.clone(),
        };
        let stamp = convert::ros_time(softarm_runtime::now_ns(), self.offset_ns);
        let d = convert::diagnostics(&snapshot, &self.ros_namespace, stamp);
        let ok = self.ros.diagnostics.publish(d).is_ok();
        self.count_failure(ok);
    }
}

/// The system clock minus CLOCK_MONOTONIC, in ns.
fn clock_offset_ns() -> i128 {
    let real = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i128);
    real - softarm_runtime::now_ns() as i128
}
