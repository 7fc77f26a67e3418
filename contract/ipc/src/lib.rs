//! The contract every softarm process shares: payload types, service names and the one function
//! per service that opens it with its settings. Every process builds its iceoryx2 node and ports
//! from here, so types and service settings can never diverge.
//!
//! Payloads are `#[repr(C)]`, fixed size, heap-free, and each carries a sequence number and a
//! CLOCK_MONOTONIC stamp in ns. Positions are metres in the tracker/base frame; actuation is
//! normalised per actuator to [0, 1].

use iceoryx2::node::NodeView;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::Path as IoxPath;
use iceoryx2::prelude::*;
use iceoryx2::service::attribute::{AttributeKey, AttributeValue};
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::builder::request_response::{
    RequestResponseOpenError, RequestResponseOpenOrCreateError,
};
use std::path::{Path, PathBuf};

pub use iceoryx2;

pub mod drivers;
pub use drivers::{DRIVERS, Driver};
pub mod own;
pub use softarm_space::{MAX_ACTUATORS, MAX_WAYPOINTS, MIN_ACTUATORS, Position, with_actuators};

mod actuators;
pub use actuators::Actuators;
/// Longest reason text in a reply.
pub const MAX_REASON: usize = 200;

/// What the controller is doing.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ControllerState {
    /// No way-point set: holds the last setpoint.
    #[default]
    Idle = 0,
    /// Playing demonstration sequences (training).
    Demonstrate = 1,
    // 2 was PLAN, never set; left free so the numbers of the others stay what peers expect.
    /// Executing a way-point set.
    Execute = 3,
    /// Tracker or motor data too old: setpoint frozen at the last safe value.
    Hold = 4,
    /// E-stop latched.
    Stopped = 5,
}

impl ControllerState {
    pub fn from_u32(v: u32) -> Option<Self> {
        use ControllerState::*;
        [Idle, Demonstrate, Execute, Hold, Stopped]
            .into_iter()
            .find(|s| *s as u32 == v)
    }

    pub fn name(self) -> &'static str {
        match self {
            ControllerState::Idle => "IDLE",
            ControllerState::Demonstrate => "DEMONSTRATE",
            ControllerState::Execute => "EXECUTE",
            ControllerState::Hold => "HOLD",
            ControllerState::Stopped => "STOPPED",
        }
    }
}

/// One per controller tick: the actuation to apply.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
// v2: per-actuator values for any arm (`Actuators`).
#[type_name("softarm::Setpoint.v2")]
#[repr(C)]
pub struct Setpoint {
    pub seq: u64,
    pub stamp_ns: u64,
    pub actuation: Actuators,
    /// `ControllerState` as u32.
    pub state: u32,
    /// While demonstrating: the demonstration's index and class, else u32::MAX.
    pub demo: u32,
    pub demo_class: u32,
    pub execution: u32,
}

/// An end-effector position from the tracker (or the simulated plant).
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
#[type_name("softarm::TrackerSample")]
#[repr(C)]
pub struct TrackerSample {
    pub seq: u64,
    pub stamp_ns: u64,
    pub position: Position,
}

/// What a driver does with the setpoints it receives.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DriverState {
    /// Applying each setpoint.
    #[default]
    Following = 0,
    /// No setpoint for a while: the last position is held.
    Holding = 1,
    /// Torque off: before the first setpoint, or when setpoints stopped for too long.
    Off = 2,
    /// The e-stop is latched: setpoints are ignored until a reset (torque off on the tendon
    /// driver, held in place by the sim).
    Stopped = 3,
    /// A motor reported a hardware error: it gets no more commands, the others hold.
    Fault = 4,
    /// Applying each setpoint, but the bus is losing replies (`MotorState::loss_permille`)
    /// or the motor data is older than the controller's input time-out: the goals go out, what
    /// the motors report arrives late or not at all (the controller holds on stale data).
    Degraded = 5,
}

impl DriverState {
    pub fn from_u32(v: u32) -> Option<Self> {
        use DriverState::*;
        [Following, Holding, Off, Stopped, Fault, Degraded]
            .into_iter()
            .find(|s| *s as u32 == v)
    }

    pub fn name(self) -> &'static str {
        match self {
            DriverState::Following => "FOLLOWING",
            DriverState::Holding => "HOLDING",
            DriverState::Off => "OFF",
            DriverState::Stopped => "STOPPED",
            DriverState::Fault => "FAULT",
            DriverState::Degraded => "DEGRADED",
        }
    }
}

/// What the actuators actually reached, normalised, and what the driver and the hardware say
/// about them.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
// v4: the bus counts, each event counted once, and the loss rate (v3 had one `faults` count
// that counted a lost reply several times); a peer built before cannot connect and misread it.
// v5: per-actuator values for any arm (`Actuators`).
#[type_name("softarm::MotorState.v5")]
#[repr(C)]
pub struct MotorState {
    pub seq: u64,
    /// When the data was asked for: the oldest motor's newest answer (its request's send
    /// time, so data that is old looks old).
    pub stamp_ns: u64,
    pub actuation: Actuators,
    /// Motor currents (A) where the driver measures them; NaN where it does not (the sim).
    pub current_a: Actuators,
    /// Communication faults since the driver started: replies lost (`dropped` +
    /// `crc_errors`) plus `reopens`, each event once.
    pub faults: u64,
    /// Replies asked for that never came whole (a garbled header counts here).
    pub dropped: u64,
    /// Replies that came whole with a wrong checksum.
    pub crc_errors: u64,
    /// Bytes on the line that belonged to no packet.
    pub garbage_bytes: u64,
    /// Reads that ended with a reply missing (one per read, whatever the number missing).
    pub timeouts: u64,
    /// Times the port was closed and opened again (an I/O error, the device gone).
    pub reopens: u64,
    /// Cycles that had a fresh setpoint to follow, and the goal writes sent: equal while the
    /// writes wait for nothing.
    pub setpoint_cycles: u64,
    pub goal_writes: u64,
    /// `DriverState` as u32.
    pub state: u32,
    /// Replies lost (dropped or bad checksum) per thousand asked for, over the last second.
    pub loss_permille: u32,
    /// Per motor, the hardware-error status it reports (0 = none; Dynamixel bits: 0x01 input
    /// voltage, 0x04 overheating, 0x08 encoder, 0x10 electrical shock, 0x20 overload).
    /// As many as `actuation` has.
    pub hardware_error: [u8; MAX_ACTUATORS],
    /// The driver's cycles since the oldest motor's data was asked for, at publishing (a
    /// freshness in the driver's own time: a loaded machine slows both alike).
    pub age_cycles: u16,
}

impl MotorState {
    pub fn driver_state(&self) -> Option<DriverState> {
        DriverState::from_u32(self.state)
    }

    /// The hardware-error status of each of the arm's motors.
    pub fn hardware_errors(&self) -> &[u8] {
        &self.hardware_error[..self.actuation.len()]
    }
}

/// Sent by the controller at each conditioning point: what was executed there and where the end
/// effector was (one visit of Alg. 1), and which estimate it wants next.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
// The type name changed with the layout (`conditioned` added), so a peer built before cannot
// connect and misread it.
// v5: per-actuator values for any arm (`Actuators`).
#[type_name("softarm::ConditioningSample.v5")]
#[repr(C)]
pub struct ConditioningSample {
    pub seq: u64,
    pub stamp_ns: u64,
    pub set_id: u64,
    pub execution: u32,
    pub point: u32,
    pub points: u32,
    pub _pad: u32,
    pub actuation: Actuators,
    pub desired: Position,
    pub reached: Position,
    /// The point whose estimate the controller wants next, and where it is.
    pub next_point: u32,
    /// The execution (1-based) that will use that estimate.
    pub next_execution: u32,
    pub next_desired: Position,
    /// What the actuators reported (`motor_state`) at the point; NaN without motor state. With
    /// `reached` a quasi-static pair of the arm, free of the lag between setpoint and actuator.
    pub measured: Actuators,
    /// The estimate the point's group ran conditioned on: the learner's for this execution,
    /// or an older one when that came too late (a loaded machine). What a learner stepping
    /// from its estimates steps from.
    pub conditioned: Actuators,
}

/// Sent by the controller when it accepts a way-point set: the learner answers with one
/// `ActuationEstimate` per point, the first estimates the set is planned with.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
#[type_name("softarm::EstimateRequest")]
#[repr(C)]
pub struct EstimateRequest {
    pub seq: u64,
    pub stamp_ns: u64,
    pub set_id: u64,
    pub count: u32,
    pub _pad: u32,
    pub desired: [Position; MAX_WAYPOINTS],
}

impl EstimateRequest {
    pub fn points(&self) -> &[Position] {
        &self.desired[..(self.count as usize).min(MAX_WAYPOINTS)]
    }
}

/// The learner's actuation for a conditioning point: the controller conditions group `point`
/// on it.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
// v2: per-actuator values for any arm (`Actuators`). v3: `within`. v4: `beyond_reach`.
#[type_name("softarm::ActuationEstimate.v4")]
#[repr(C)]
pub struct ActuationEstimate {
    pub seq: u64,
    pub stamp_ns: u64,
    pub set_id: u64,
    pub point: u32,
    /// The execution (1-based) it is for: it is in force there if it reaches the controller
    /// before the point's group starts in that execution (`ExecutionStats::reconditions`).
    pub execution: u32,
    pub actuation: Actuators,
    /// 1 if corrected within its execution by what the points before it showed of the arm
    /// (`ExecutionStats::within`), else 0.
    pub within: u32,
    /// 1 if the point's target is beyond the arm's reach: the estimate aims at the nearest
    /// place the arm reaches (`ExecutionStats::beyond_reach`), else 0.
    pub beyond_reach: u32,
    /// The `stamp_ns` (T_cond) of the sample it answers; 0 for a set's first estimates and a
    /// changed arm's.
    pub answers_ns: u64,
}

/// A way-point set to execute (request of `waypoints`).
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
#[type_name("softarm::WaypointSet")]
#[repr(C)]
pub struct WaypointSet {
    pub seq: u64,
    pub stamp_ns: u64,
    pub duration_s: f64,
    pub executions: u32,
    pub count: u32,
    pub times_s: [f64; MAX_WAYPOINTS],
    pub positions_m: [Position; MAX_WAYPOINTS],
}

/// Answer to a `WaypointSet`.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("softarm::WaypointReply")]
#[repr(C)]
pub struct WaypointReply {
    pub seq: u64,
    pub stamp_ns: u64,
    /// The set's id when accepted, 0 when rejected.
    pub set_id: u64,
    pub accepted: u32,
    pub reason_len: u32,
    pub reason: [u8; MAX_REASON],
}

impl WaypointReply {
    pub fn accepted(seq: u64, stamp_ns: u64, set_id: u64) -> Self {
        Self {
            seq,
            stamp_ns,
            set_id,
            accepted: 1,
            reason_len: 0,
            reason: [0; MAX_REASON],
        }
    }

    /// A rejection; the reason is cut at a character boundary to fit.
    pub fn rejected(seq: u64, stamp_ns: u64, reason: &str) -> Self {
        let mut end = reason.len().min(MAX_REASON);
        while !reason.is_char_boundary(end) {
            end -= 1;
        }
        let mut r = [0; MAX_REASON];
        r[..end].copy_from_slice(&reason.as_bytes()[..end]);
        Self {
            seq,
            stamp_ns,
            set_id: 0,
            accepted: 0,
            reason_len: end as u32,
            reason: r,
        }
    }

    pub fn reason(&self) -> &str {
        let n = (self.reason_len as usize).min(MAX_REASON);
        std::str::from_utf8(&self.reason[..n]).unwrap_or("(reason not UTF-8)")
    }
}

/// Asks the controller to play the demonstration sequences (request of `demonstrate`).
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
#[type_name("softarm::DemonstrateRequest")]
#[repr(C)]
pub struct DemonstrateRequest {
    pub seq: u64,
    pub stamp_ns: u64,
    pub seed: u64,
}

/// Answer to a `DemonstrateRequest`.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
#[type_name("softarm::DemonstrateReply")]
#[repr(C)]
pub struct DemonstrateReply {
    pub seq: u64,
    pub stamp_ns: u64,
    pub accepted: u32,
    /// Demonstrations that will be played.
    pub demos: u32,
    /// How long they take in all (s).
    pub duration_s: f64,
}

/// One per finished execution.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
// v2: `within`. v3: `beyond_reach`.
#[type_name("softarm::ExecutionStats.v3")]
#[repr(C)]
pub struct ExecutionStats {
    pub seq: u64,
    pub stamp_ns: u64,
    pub set_id: u64,
    /// 1-based within the set.
    pub execution: u32,
    pub executions: u32,
    pub count: u32,
    /// Points that ran conditioned on the learner's estimate for this execution (it came in
    /// time); `count − reconditions` ran on an older one.
    pub reconditions: u32,
    /// Bit n set: point n ran on an estimate the learner corrected within this execution, by
    /// what the points before it showed of the arm.
    pub within: u32,
    /// Bit n set: point n's target is beyond the arm's reach, and it ran on an estimate aimed
    /// at the nearest place the arm reaches.
    pub beyond_reach: u32,
    /// Eq. 9: ‖P_cond[n] − p_reached[n]‖ (m).
    pub errors_m: [f64; MAX_WAYPOINTS],
    pub mean_m: f64,
    pub max_m: f64,
}

impl ExecutionStats {
    pub fn errors(&self) -> &[f64] {
        &self.errors_m[..(self.count as usize).min(MAX_WAYPOINTS)]
    }
    /// Points the tracker did not see (their error is NaN, `null` in JSON): the mean and the
    /// worst are of the others.
    pub fn unseen(&self) -> usize {
        self.errors().iter().filter(|e| !e.is_finite()).count()
    }

    /// Whether point `n` ran on an estimate corrected within this execution.
    pub fn corrected_within(&self, n: usize) -> bool {
        n < 32 && self.within & (1 << n) != 0
    }

    /// Whether point `n`'s target is beyond the arm's reach.
    pub fn beyond_reach(&self, n: usize) -> bool {
        n < 32 && self.beyond_reach & (1 << n) != 0
    }
}

/// Min / p50 / p99 / p99.9 / max of the tick wake-up latency (ns).
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
#[type_name("softarm::Latency")]
#[repr(C)]
pub struct Latency {
    pub min_ns: u64,
    pub p50_ns: u64,
    pub p99_ns: u64,
    pub p999_ns: u64,
    pub max_ns: u64,
    pub samples: u64,
}

/// The controller's state, ~10 Hz.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
// The type name changed with the layout (re-conditionings, outbox drops, held solves; the
// actuators' lag; unseen points), so a peer built before cannot connect and misread it.
#[type_name("softarm::ControllerStatus.v4")]
#[repr(C)]
pub struct ControllerStatus {
    pub seq: u64,
    pub stamp_ns: u64,
    pub state: u32,
    pub execution: u32,
    pub set_id: u64,
    pub rate_hz: f64,
    pub ticks: u64,
    pub overruns: u64,
    pub latency: Latency,
    /// Age of the newest tracker / motor sample when last checked (ns); u64::MAX if none yet.
    pub tracker_age_ns: u64,
    pub motor_age_ns: u64,
    /// Whether the controller has a trained model loaded.
    pub model_loaded: u32,
    /// Points that ran on the learner's estimate for their execution
    /// ([`ExecutionStats::reconditions`]), so far in the execution under way (0 if none), and in
    /// the last completed one.
    pub reconditions_current: u32,
    pub reconditions_last: u32,
    /// Conditioning samples and stats waiting in the tick's backlog for room in its outbox.
    pub outbox_backlog: u32,
    /// Messages the tick's outbox dropped since the controller started (any kind), and the
    /// conditioning samples among them (lost to the learner).
    pub outbox_dropped: u64,
    pub samples_dropped: u64,
    /// Group evaluations whose solve failed since the controller started, each held at the
    /// group's last good value.
    pub held_solves: u64,
    /// The actuators' lag behind the setpoints as the controller measures it (ns); u64::MAX
    /// until the arm has moved enough to tell.
    pub lag_ns: u64,
    /// How far ahead of the clock Eq. 11 is evaluated: the lag, at most
    /// `controller.max_lead_s` (ns).
    pub lead_ns: u64,
    /// Points of finished executions the tracker did not see at their time (no sample in the
    /// window: a loaded machine, a tracker that dropped out) since the controller started:
    /// their error is unknown (`null` in `stats`), and nothing is learnt from them.
    pub points_unseen: u64,
}

/// Latched e-stop state.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, serde::Serialize)]
#[type_name("softarm::EstopState")]
#[repr(C)]
pub struct EstopState {
    pub seq: u64,
    pub stamp_ns: u64,
    /// 1 engaged, 0 released (an explicit reset).
    pub engaged: u32,
    pub _pad: u32,
}

/// Which stack on this host: the namespace every service name starts with (`softarm/<robot-id>`
/// unless configured), and the iceoryx2 root folder its services live under (iceoryx2's own,
/// `/tmp/iceoryx2/`, unless the config names one: an installed stack has a folder of its own, so
/// nobody else's use of iceoryx2 can take its place). A stack of its own root also has its own
/// files in /dev/shm, its node counter included ([`own`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Namespace {
    name: String,
    root: Option<PathBuf>,
    /// iceoryx2's `global.prefix` for a stack of its own root ([`own::prefix`]).
    prefix: Option<String>,
    /// The arm this process drives (`softarm_arm::Layout::identity`), when it knows it.
    arm: Option<String>,
}

impl Namespace {
    /// A namespace; slashes separate levels, and only [A-Za-z0-9_./-] are allowed.
    pub fn new(name: &str) -> Result<Self, Error> {
        let ok = !name.is_empty()
            && name.len() <= 100
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-./".contains(c))
            && !name.starts_with('/')
            && !name.ends_with('/');
        if ok {
            Ok(Self {
                name: name.to_string(),
                root: None,
                prefix: None,
                arm: None,
            })
        } else {
            Err(Error(format!(
                "namespace {name:?} is not valid: use 1 to 100 of A-Z a-z 0-9 _ - . /, \
                 not starting or ending with /"
            )))
        }
    }

    /// The same namespace under the iceoryx2 root folder `root` (an absolute path), with the
    /// files in /dev/shm of its own that go with it ([`own::prefix`]).
    pub fn under(mut self, root: &Path) -> Result<Self, Error> {
        let text = root
            .to_str()
            .filter(|t| root.is_absolute() && !t.is_empty());
        let Some(text) = text else {
            return Err(Error(format!(
                "the iceoryx2 root {} must be an absolute path in UTF-8",
                root.display()
            )));
        };
        // iceoryx2 appends its folders to the root as it is written: it must end with `/`.
        let dir = format!("{}/", text.trim_end_matches('/'));
        IoxPath::new(dir.as_bytes()).map_err(|e| {
            Error(format!(
                "the iceoryx2 root {} is not a path iceoryx2 takes: {e:?}",
                root.display()
            ))
        })?;
        self.prefix = Some(own::prefix(&dir));
        self.root = Some(PathBuf::from(dir));
        Ok(self)
    }

    /// The same namespace for a process that drives arm `identity`
    /// (`softarm_arm::Layout::identity`): each service it creates carries the arm, and it
    /// opens no service of another arm's stack ([`Node`]). A process without one (a tool, a
    /// test) opens any.
    pub fn with_arm(mut self, identity: &str) -> Result<Self, Error> {
        arm_value(identity)?;
        self.arm = Some(identity.to_string());
        Ok(self)
    }

    /// The arm this process drives, if it knows it.
    pub fn arm(&self) -> Option<&str> {
        self.arm.as_deref()
    }

    pub fn as_str(&self) -> &str {
        &self.name
    }

    /// The iceoryx2 root folder of this stack; `None`: iceoryx2's default.
    pub fn root(&self) -> Option<&Path> {
        self.root.as_deref()
    }

    /// iceoryx2's `global.prefix` for this stack; `None`: iceoryx2's default (`iox2_`), or
    /// whatever an iceoryx2 config file names.
    pub fn prefix(&self) -> Option<&str> {
        self.prefix.as_deref()
    }

    /// iceoryx2's config for a node of this stack.
    fn iceoryx2_config(&self) -> Config {
        // iceoryx2 warns on stderr that it runs on its built-in defaults, which is intended.
        set_log_level(LogLevel::Error);
        let mut config = Config::global_config().clone();
        config.global.creation_timeout = CREATION_TIMEOUT;
        if let Some(root) = &self.root {
            let text = root.to_str().expect("checked by Namespace::under");
            let path = IoxPath::new(text.as_bytes()).expect("checked by Namespace::under");
            config.global.set_root_path(&path);
        }
        if let Some(prefix) = &self.prefix {
            config.global.prefix =
                FileName::new(prefix.as_bytes()).expect("softarm_, hex digits, _");
        }
        config
    }

    fn service(&self, name: &str) -> Result<ServiceName, Error> {
        let full = format!("{}/{name}", self.name);
        ServiceName::new(&full).map_err(|e| Error(format!("service name {full:?}: {e:?}")))
    }
}

/// The attribute every service of a process that knows its arm carries.
fn arm_key() -> AttributeKey {
    AttributeKey::try_from("softarm.arm").expect("a short key")
}

fn arm_value(identity: &str) -> Result<AttributeValue, Error> {
    AttributeValue::try_from(identity).map_err(|e| {
        Error(format!(
            "the arm's identity {identity:?} does not fit an iceoryx2 attribute: {e:?}"
        ))
    })
}

/// How long opening a service waits for another process that is creating it (iceoryx2's
/// default: 1 s). A creator kept from its CPU for longer on a loaded machine made the opener
/// fail with `HangsInCreation` (seen: a controller's io thread that never opened `setpoint`).
const CREATION_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(10);

/// Anything iceoryx2 refused, with what was being done.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Error(pub String);

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Error {}

fn err<E: std::fmt::Debug>(what: String) -> impl FnOnce(E) -> Error {
    move |e| Error(format!("{what}: {e:?}"))
}

pub type IoxNode = iceoryx2::node::Node<ipc::Service>;
pub type PubSub<T> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>;
pub type ReqRes<Q, R> =
    iceoryx2::service::port_factory::request_response::PortFactory<ipc::Service, Q, (), R, ()>;
pub type Pub<T> = Publisher<ipc::Service, T, ()>;
pub type Sub<T> = Subscriber<ipc::Service, T, ()>;
pub type Server<Q, R> = iceoryx2::port::server::Server<ipc::Service, Q, (), R, ()>;
pub type Client<Q, R> = iceoryx2::port::client::Client<ipc::Service, Q, (), R, ()>;

/// A process's iceoryx2 node in its stack's namespace, and the one place each service is opened
/// with its settings. The node's name is `<namespace>/<role>`, so `softarm status` can tell which
/// processes of which stack are alive.
/// Samples of `tracker` and `motor_state` a subscriber can fall behind by without losing one:
/// 320 ms at the sim's 200 Hz. The learner's footprint needs every sample of the arm held still
/// between two sets (about 100 ms when the sim is restarted as another arm): with 8, a learner
/// kept from its CPU for 40 ms on a loaded machine lost them and missed the change.
pub const ARM_BUFFER: usize = 64;

pub struct Node {
    pub node: IoxNode,
    pub namespace: Namespace,
}

/// Node names are limited; keep the tail of long ones.
fn node_name(namespace: &Namespace, role: &str) -> String {
    let full = format!("{}/{role}", namespace.as_str());
    let n = full.len();
    if n > 100 {
        full[n - 100..].to_string()
    } else {
        full
    }
}

impl Node {
    /// Creates this process's node and cleans up the nodes of dead processes. Signals are left
    /// to the process (signal-hook), not iceoryx2.
    pub fn open(namespace: Namespace, role: &str) -> Result<Self, Error> {
        // Before iceoryx2 would make the counter world-writable.
        if let Some(prefix) = namespace.prefix() {
            own::make_counter(prefix)?;
        }
        let name = node_name(&namespace, role);
        let node_name =
            NodeName::new(&name).map_err(|e| Error(format!("node name {name:?}: {e:?}")))?;
        let node = NodeBuilder::new()
            .config(&namespace.iceoryx2_config())
            .name(&node_name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(err(format!("creating the iceoryx2 node {name:?}")))?;
        // What processes killed before left behind (their node, their ports' slots) goes now,
        // so a restarted process never meets "exceeds max supported" ports.
        let _ = node.try_cleanup_dead_nodes();
        Ok(Self { node, namespace })
    }

    fn pubsub<T: std::fmt::Debug + ZeroCopySend>(
        &self,
        name: &str,
        history: usize,
        buffer: usize,
        publishers: usize,
        subscribers: usize,
    ) -> Result<PubSub<T>, Error> {
        let service = self.namespace.service(name)?;
        let builder = || {
            self.node
                .service_builder(&service)
                .publish_subscribe::<T>()
                .history_size(history)
                .subscriber_max_buffer_size(buffer.max(history).max(1))
                .max_publishers(publishers)
                .max_subscribers(subscribers)
                .max_nodes(MAX_NODES)
        };
        let what = || format!("opening service {}/{name}", self.namespace.as_str());
        let Some(verifier) = self.arm_verifier()? else {
            return builder().open_or_create().map_err(err(what()));
        };
        match builder().open_or_create_with_attributes(&verifier) {
            Err(PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
                PublishSubscribeOpenError::IncompatibleAttributes,
            )) => {
                self.other_arm(&service, MessagingPattern::PublishSubscribe, name)?;
                builder().open().map_err(err(what()))
            }
            opened => opened.map_err(err(what())),
        }
    }

    /// What a service must carry for this process: its arm, when it knows it.
    fn arm_verifier(&self) -> Result<Option<AttributeVerifier>, Error> {
        let Some(arm) = self.namespace.arm() else {
            return Ok(None);
        };
        let verifier = AttributeVerifier::new()
            .require(&arm_key(), &arm_value(arm)?)
            .map_err(|e| Error(format!("the arm attribute: {e:?}")))?;
        Ok(Some(verifier))
    }

    /// A service whose attributes are not this process's arm: an error naming both arms when
    /// it carries another, `Ok` when it carries none (a tool or a test created it), so the
    /// caller opens it as it is.
    fn other_arm(
        &self,
        service: &ServiceName,
        pattern: MessagingPattern,
        name: &str,
    ) -> Result<(), Error> {
        let config = self.namespace.iceoryx2_config();
        let details = ipc::Service::details(service, &config, pattern)
            .map_err(err(format!("reading the attributes of service {name}")))?;
        let mut theirs = None;
        if let Some(d) = &details {
            d.static_details
                .attributes()
                .iter_key_values(&arm_key(), |v| {
                    theirs = Some(v.to_string());
                    CallbackProgression::Stop
                });
        }
        match theirs {
            None => Ok(()),
            Some(theirs) => Err(Error(format!(
                "the stack in {} drives another arm: its service {name} is for {theirs}, and \
                 this process's config describes {}; run every process of a stack with the \
                 same [arm] (or give this one a namespace of its own)",
                self.namespace.as_str(),
                self.namespace.arm().unwrap_or("no arm")
            ))),
        }
    }

    /// `setpoint`: one per controller tick; late subscribers get the newest.
    pub fn setpoint(&self) -> Result<PubSub<Setpoint>, Error> {
        self.pubsub("setpoint", 1, 4, 2, MAX_SUBSCRIBERS)
    }

    /// `tracker`: from sim or the tracker driver. A subscriber may fall [`ARM_BUFFER`] samples
    /// behind without losing one.
    pub fn tracker(&self) -> Result<PubSub<TrackerSample>, Error> {
        self.pubsub("tracker", 1, ARM_BUFFER, 2, MAX_SUBSCRIBERS)
    }

    /// `motor_state`: from the drivers that move the arm ([`Driver::moves`]: sim or tendon).
    pub fn motor_state(&self) -> Result<PubSub<MotorState>, Error> {
        self.pubsub("motor_state", 1, ARM_BUFFER, 2, MAX_SUBSCRIBERS)
    }

    /// `cp_sample`: controller → learner at each conditioning point; none may be lost.
    pub fn cp_sample(&self) -> Result<PubSub<ConditioningSample>, Error> {
        self.pubsub("cp_sample", 0, 64, 2, MAX_SUBSCRIBERS)
    }

    /// `estimate_request`: controller → learner, the first estimates of a new set.
    pub fn estimate_request(&self) -> Result<PubSub<EstimateRequest>, Error> {
        self.pubsub("estimate_request", 0, 8, 2, MAX_SUBSCRIBERS)
    }

    /// `estimate`: learner → controller.
    pub fn estimate(&self) -> Result<PubSub<ActuationEstimate>, Error> {
        self.pubsub("estimate", 0, 64, 2, MAX_SUBSCRIBERS)
    }

    /// `stats`: one per finished execution; the last 64 reach late subscribers.
    pub fn stats(&self) -> Result<PubSub<ExecutionStats>, Error> {
        self.pubsub("stats", STATS_HISTORY, STATS_HISTORY, 2, MAX_SUBSCRIBERS)
    }

    /// `status`: ~10 Hz; late subscribers get the newest.
    pub fn status(&self) -> Result<PubSub<ControllerStatus>, Error> {
        self.pubsub("status", 1, 4, 2, MAX_SUBSCRIBERS)
    }

    /// `estop`: latched; late subscribers get the current state.
    pub fn estop(&self) -> Result<PubSub<EstopState>, Error> {
        self.pubsub("estop", 1, 4, 4, MAX_SUBSCRIBERS)
    }

    /// `waypoints`: request/response, validated by the controller.
    pub fn waypoints(&self) -> Result<ReqRes<WaypointSet, WaypointReply>, Error> {
        self.reqres("waypoints")
    }

    /// `demonstrate`: request/response, asks the controller to play the demonstrations.
    pub fn demonstrate(&self) -> Result<ReqRes<DemonstrateRequest, DemonstrateReply>, Error> {
        self.reqres("demonstrate")
    }

    fn reqres<Q: std::fmt::Debug + ZeroCopySend, R: std::fmt::Debug + ZeroCopySend>(
        &self,
        name: &str,
    ) -> Result<ReqRes<Q, R>, Error> {
        let service = self.namespace.service(name)?;
        let builder = || {
            self.node
                .service_builder(&service)
                .request_response::<Q, R>()
                .max_clients(MAX_SUBSCRIBERS)
                .max_servers(1)
                .max_nodes(MAX_NODES)
                .max_active_requests_per_client(2)
                .max_response_buffer_size(2)
        };
        let what = || format!("opening service {}/{name}", self.namespace.as_str());
        let Some(verifier) = self.arm_verifier()? else {
            return builder().open_or_create().map_err(err(what()));
        };
        match builder().open_or_create_with_attributes(&verifier) {
            Err(RequestResponseOpenOrCreateError::RequestResponseOpenError(
                RequestResponseOpenError::IncompatibleAttributes,
            )) => {
                self.other_arm(&service, MessagingPattern::RequestResponse, name)?;
                builder().open().map_err(err(what()))
            }
            opened => opened.map_err(err(what())),
        }
    }

    pub fn publisher<T: std::fmt::Debug + ZeroCopySend>(
        &self,
        service: &PubSub<T>,
    ) -> Result<Pub<T>, Error> {
        service.publisher_builder().create().map_err(err(format!(
            "creating a publisher in {}",
            self.namespace.as_str()
        )))
    }

    pub fn subscriber<T: std::fmt::Debug + ZeroCopySend>(
        &self,
        service: &PubSub<T>,
    ) -> Result<Sub<T>, Error> {
        service.subscriber_builder().create().map_err(err(format!(
            "creating a subscriber in {}",
            self.namespace.as_str()
        )))
    }

    pub fn server<Q: std::fmt::Debug + ZeroCopySend, R: std::fmt::Debug + ZeroCopySend>(
        &self,
        service: &ReqRes<Q, R>,
    ) -> Result<Server<Q, R>, Error> {
        service.server_builder().create().map_err(err(format!(
            "creating a server in {}",
            self.namespace.as_str()
        )))
    }

    pub fn client<Q: std::fmt::Debug + ZeroCopySend, R: std::fmt::Debug + ZeroCopySend>(
        &self,
        service: &ReqRes<Q, R>,
    ) -> Result<Client<Q, R>, Error> {
        service.client_builder().create().map_err(err(format!(
            "creating a client in {}",
            self.namespace.as_str()
        )))
    }

    /// Roles of the live nodes of this namespace (e.g. `["controller", "learner", "sim"]`,
    /// this process included); nodes of processes that died are cleaned up on the way.
    pub fn alive_nodes(&self) -> Result<Vec<String>, Error> {
        let prefix = format!("{}/", self.namespace.as_str());
        let mut names = Vec::new();
        let mut dead = false;
        IoxNode::list(self.node.config(), |state| {
            match &state {
                NodeState::Alive(view) => {
                    if let Some(d) = view.details()
                        && let Some(role) = d.name().to_string().strip_prefix(&prefix)
                    {
                        names.push(role.to_string());
                    }
                }
                NodeState::Dead(_) => dead = true,
                _ => {}
            }
            CallbackProgression::Continue
        })
        .map_err(err("listing iceoryx2 nodes".into()))?;
        if dead {
            self.node.try_cleanup_dead_nodes();
        }
        names.sort();
        Ok(names)
    }
}

/// Nodes that may share one service: the processes of a stack and a few clients.
pub const MAX_NODES: usize = 16;
/// Subscribers (or clients) per service.
pub const MAX_SUBSCRIBERS: usize = 8;
/// Executions whose stats reach a late subscriber.
pub const STATS_HISTORY: usize = 64;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn namespaces_are_checked() {
        assert!(Namespace::new("softarm/arm-1").is_ok());
        for bad in ["", "/x", "x/", "a b", "ä"] {
            assert!(Namespace::new(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn a_stack_of_its_own_root_meets_no_other() {
        let dir = std::env::temp_dir().join(format!("softarm-ipc-root-{}", std::process::id()));
        let ns = Namespace::new("softarm/root-test").unwrap();
        let own = ns.clone().under(&dir).unwrap();
        assert_eq!(
            own.root().unwrap().to_str().unwrap(),
            format!("{}/", dir.display())
        );
        assert!(ns.clone().under(Path::new("relative/dir")).is_err());
        // A publisher under one root is not seen by a node of the same namespace elsewhere.
        let a = Node::open(own.clone(), "a").unwrap();
        let p = a.publisher(&a.status().unwrap()).unwrap();
        p.send_copy(ControllerStatus::default()).unwrap();
        assert!(
            dir.join("nodes").exists(),
            "iceoryx2 keeps its files under the stack's root"
        );
        let elsewhere = Node::open(ns, "b").unwrap();
        assert!(!elsewhere.alive_nodes().unwrap().contains(&"a".to_string()));
        let same = Node::open(own, "c").unwrap();
        assert_eq!(same.alive_nodes().unwrap(), ["a", "c"]);
        drop((p, a, same, elsewhere));
        own::Leftovers::of(&dir).unwrap().remove().unwrap();
    }

    /// The files in /dev/shm of a stack of its own root: every one's name starts with the
    /// root's prefix, and iceoryx2's node counter among them is the one made here, the user's
    /// alone (0600), which iceoryx2 counts its nodes in. One iceoryx2 would have made (0666),
    /// or one cut short, is replaced; one another user made first is refused, naming it.
    #[test]
    fn a_stack_of_its_own_root_has_its_own_node_counter() {
        use std::os::unix::fs::{MetadataExt, PermissionsExt};
        let dir = std::env::temp_dir().join(format!("softarm-ipc-shm-{}", std::process::id()));
        let ns = Namespace::new("softarm/shm-test")
            .unwrap()
            .under(&dir)
            .unwrap();
        let prefix = ns.prefix().unwrap().to_string();
        assert!(
            prefix.starts_with("softarm_") && prefix.ends_with('_'),
            "{prefix}"
        );
        let counter = own::counter_path(&prefix);
        let _ = std::fs::remove_file(&counter);
        let count =
            || u32::from_ne_bytes(std::fs::read(&counter).unwrap()[8..12].try_into().unwrap());
        let a = Node::open(ns.clone(), "a").unwrap();
        let m = std::fs::metadata(&counter).unwrap();
        assert_eq!(m.mode() & 0o7777, 0o600);
        assert_eq!(m.uid(), nix::unistd::geteuid().as_raw());
        // iceoryx2 counted the node in this file: it is the one iceoryx2 uses.
        assert_eq!(count(), 1);
        let counters = |ls: &own::Leftovers| -> Vec<PathBuf> {
            ls.shm
                .iter()
                .filter(|p| p.to_string_lossy().ends_with(".global_mgmt"))
                .cloned()
                .collect()
        };
        let ls = own::Leftovers::of(&dir).unwrap();
        assert_eq!(counters(&ls), std::slice::from_ref(&counter));
        assert_eq!(ls.alive, ["softarm/shm-test/a"]);
        assert!(ls.remove().unwrap_err().0.contains("still runs"));

        std::fs::set_permissions(&counter, std::fs::Permissions::from_mode(0o666)).unwrap();
        let b = Node::open(ns.clone(), "b").unwrap();
        assert_eq!(std::fs::metadata(&counter).unwrap().mode() & 0o7777, 0o600);
        std::fs::File::create(&counter).unwrap();
        let c = Node::open(ns.clone(), "c").unwrap();
        assert_eq!(std::fs::metadata(&counter).unwrap().len(), 16);
        assert_eq!(count(), 1, "a fresh counter, counted in");
        drop((a, b, c));

        if nix::unistd::geteuid().is_root() {
            std::os::unix::fs::chown(&counter, Some(65534), Some(65534)).unwrap();
            let e = Node::open(ns.clone(), "d").err().unwrap().0;
            assert!(
                e.contains(&counter.display().to_string())
                    && e.contains("uid 65534")
                    && e.contains("rm "),
                "{e}"
            );
            assert_eq!(
                std::fs::metadata(&counter).unwrap().uid(),
                65534,
                "left as it was"
            );
        }
        let ls = own::Leftovers::of(&dir).unwrap();
        assert!(ls.alive.is_empty(), "{:?}", ls.alive);
        assert_eq!(ls.remove().unwrap(), ls.shm.len());
        let ls = own::Leftovers::of(&dir).unwrap();
        assert!(ls.shm.is_empty() && !dir.exists(), "{ls:?}");
    }

    /// Services carry the arm of the process that made them: a process of another arm
    /// cannot open them and is told both arms; one of the same arm, or one that knows no arm,
    /// opens them; a service made by one that knows no arm is opened by any.
    #[test]
    fn a_process_of_another_arm_cannot_join() {
        let name = format!("softarm/arm-test-{}", std::process::id());
        let six = Namespace::new(&name)
            .unwrap()
            .with_arm("6 actuators (a1 .. a6) in 2 modules, layout 1")
            .unwrap();
        let nine = Namespace::new(&name)
            .unwrap()
            .with_arm("9 actuators (a1 .. a9) in 3 modules, layout 2")
            .unwrap();
        let stack = Node::open(six.clone(), "stack").unwrap();
        let _setpoint = stack.setpoint().unwrap();
        let _waypoints = stack.waypoints().unwrap();
        let other = Node::open(nine.clone(), "other").unwrap();
        for e in [
            other.setpoint().map(drop).unwrap_err(),
            other.waypoints().map(drop).unwrap_err(),
        ] {
            let e = e.to_string();
            assert!(e.contains("drives another arm"), "{e}");
            assert!(
                e.contains("6 actuators") && e.contains("9 actuators"),
                "{e}"
            );
        }
        Node::open(six, "same").unwrap().setpoint().unwrap();
        let tool = Node::open(Namespace::new(&name).unwrap(), "tool").unwrap();
        tool.setpoint().unwrap();
        // A service a tool made first carries no arm: every process opens it.
        let made_by_tool = tool.status().unwrap();
        other.status().unwrap();
        stack.status().unwrap();
        drop(made_by_tool);
        assert!(
            Namespace::new(&name)
                .unwrap()
                .with_arm(&"x".repeat(300))
                .is_err()
        );
    }

    #[test]
    fn reasons_fit_and_round_trip() {
        let r = WaypointReply::rejected(1, 0, "point 3: time 9 s is after the duration 8 s");
        assert_eq!(r.reason(), "point 3: time 9 s is after the duration 8 s");
        let long = "é".repeat(150);
        let r = WaypointReply::rejected(1, 0, &long);
        assert!(r.reason().len() <= MAX_REASON && r.reason().chars().all(|c| c == 'é'));
    }

    #[test]
    fn a_request_never_reads_past_its_points() {
        let mut r = EstimateRequest {
            count: 2,
            ..Default::default()
        };
        r.desired[1] = [0.1, 0.2, 0.3];
        assert_eq!(r.points(), &[[0.0; 3], [0.1, 0.2, 0.3]]);
        r.count = u32::MAX;
        assert_eq!(r.points().len(), MAX_WAYPOINTS);
    }

    /// Layouts peers rely on: a change needs a new type name (`.vN`).
    #[test]
    fn payload_sizes_and_alignments() {
        use std::mem::{align_of, size_of};
        assert_eq!(
            (size_of::<ExecutionStats>(), align_of::<ExecutionStats>()),
            (192, 8)
        );
        assert_eq!(
            (
                size_of::<ControllerStatus>(),
                align_of::<ControllerStatus>()
            ),
            (184, 8)
        );
        assert_eq!(
            (
                size_of::<ConditioningSample>(),
                align_of::<ConditioningSample>()
            ),
            (528, 8)
        );
        // A fixed capacity of 16 actuators and their count.
        assert_eq!(size_of::<Actuators>(), 136);
        assert_eq!(size_of::<Setpoint>(), 168);
        assert_eq!(size_of::<MotorState>(), 384);
        assert_eq!(size_of::<ActuationEstimate>(), 184);
    }

    #[test]
    fn states_round_trip() {
        for v in [0, 1, 3, 4, 5] {
            assert_eq!(ControllerState::from_u32(v).unwrap() as u32, v);
        }
        for v in [2, 6, u32::MAX] {
            assert_eq!(ControllerState::from_u32(v), None);
        }
    }
}
