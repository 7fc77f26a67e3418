//! The real arm's drivers in the config: `[tendon]` (a tendon motor per actuator on a Dynamixel bus) and
//! `[tracker]` (a Bird-protocol electromagnetic tracker), and the two conversions they define:
//! normalised actuation ↔ motor ticks ([`Mapping`]) and tracker frame ↔ base frame ([`Frame`]).
//! Pure: the drivers and their emulators share these, so both ends agree by construction and
//! the config check can refuse limits that contradict each other.

use std::f64::consts::TAU;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};
use softarm_arm::{Kind, Layout};
use softarm_space::{MAX_ACTUATORS, Position};

/// Metres per inch: the Bird protocol reports inches.
pub const METRES_PER_INCH: f64 = 0.0254;

/// The ticks a goal position may take: the motors run in position control (operating mode 3,
/// one turn). Multi-turn (extended position) mode is not offered: the motor forgets its turn
/// count on a power cycle, so `zero_ticks` would no longer hold, and it ignores the limits.
pub const TICKS_RANGE: (i32, i32) = (0, 4095);

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TendonConfig {
    /// The serial device of the motor bus (a udev rule gives it a stable name).
    pub port: PathBuf,
    /// The bus's baud rate, as the motors are set to.
    pub baud: u32,
    /// The motor id of each actuator, in the arm's order (`[arm]`): one per actuator, unique
    /// on its bus.
    pub ids: Vec<u8>,
    /// More motor buses (`[[tendon.extra_bus]]`), each with its port and the actuators on it;
    /// every other actuator's motor is on `port`. All at `baud`, driven in one cycle.
    #[serde(default)]
    pub extra_bus: Vec<ExtraBus>,
    /// Goal positions written and positions and currents read per second.
    pub rate_hz: f64,
    /// Motor ticks per spool revolution (4096 on X-series).
    pub ticks_per_rev: u32,
    /// Spool radius per motor (m): tendon length per radian.
    pub spool_radius_m: Vec<f64>,
    /// Each motor's position (ticks) with its actuator at its shortest (normalised 0).
    pub zero_ticks: Vec<i32>,
    /// +1 when more ticks lengthen the actuator, -1 when they shorten it.
    pub direction: Vec<i8>,
    /// The motors' own position limits (ticks), written to them at start: a goal outside is
    /// refused by the motor itself. Every setpoint the controller may send maps inside.
    pub min_ticks: Vec<i32>,
    pub max_ticks: Vec<i32>,
    /// Profile Velocity written to the motors (units of 0.229 rev/min; 0 = as fast as they
    /// go): how fast a motor may move to a new goal, so one that gets its torque back after a
    /// pause or a reconnection moves at a bounded speed.
    pub profile_velocity: u32,
    /// Torque comes on only for a first setpoint this close (normalised) to where each motor
    /// stands: the controller starts from the measured state, anything else is a wrong command.
    pub max_engage_step: f64,
    /// No setpoint for this long (ms): hold the last position...
    pub hold_after_ms: f64,
    /// ...and this long (ms): torque off.
    pub torque_off_after_ms: f64,
}

/// Another motor bus of the tendon driver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ExtraBus {
    /// Its serial device.
    pub port: PathBuf,
    /// The actuators whose motors are on it (1 = the arm's first), each on one bus.
    pub actuators: Vec<usize>,
}

/// One motor bus of the tendon driver: its section (`port`, `ids` and every per-motor list
/// of its actuators alone) and which of the arm's actuators they are.
#[derive(Debug, Clone, PartialEq)]
pub struct Bus {
    pub tendon: TendonConfig,
    /// The arm's actuators on it (0-based, in the arm's order), one per motor of `tendon`.
    pub actuators: Vec<usize>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum TrackerRecord {
    /// X, Y, Z.
    Position,
    /// X, Y, Z and the three angles (read, not used for control).
    PositionAngles,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum TrackerMode {
    /// The device sends records continuously (STREAM).
    Stream,
    /// The driver asks for each record (POINT) at `rate_hz`.
    Point,
}

/// The half-space around the transmitter the tracker reports positions in (its HEMISPHERE
/// setting). The transmitter's field is symmetric through its centre, so the unit cannot tell a
/// sensor at p from one at -p: it reports every position in the selected hemisphere, and a
/// sensor on the other side of the boundary plane comes out mirrored through the transmitter's
/// centre. The names are the Bird's, on the tracker's own axes (X forward, Y right, Z down),
/// not the room's.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum TrackerHemisphere {
    /// +X (the unit's own default).
    #[default]
    Forward,
    /// -X.
    Aft,
    /// -Z (Z points down on a Bird).
    Upper,
    /// +Z.
    Lower,
    /// -Y.
    Left,
    /// +Y.
    Right,
}

impl TrackerHemisphere {
    /// Every hemisphere, in the order the docs list them.
    pub const ALL: [Self; 6] = [
        Self::Forward,
        Self::Aft,
        Self::Upper,
        Self::Lower,
        Self::Left,
        Self::Right,
    ];

    /// The config spelling.
    pub fn name(self) -> &'static str {
        match self {
            Self::Forward => "forward",
            Self::Aft => "aft",
            Self::Upper => "upper",
            Self::Lower => "lower",
            Self::Left => "left",
            Self::Right => "right",
        }
    }

    /// The unit vector (tracker frame) pointing into the hemisphere.
    pub fn direction(self) -> [f64; 3] {
        match self {
            Self::Forward => [1.0, 0.0, 0.0],
            Self::Aft => [-1.0, 0.0, 0.0],
            Self::Upper => [0.0, 0.0, -1.0],
            Self::Lower => [0.0, 0.0, 1.0],
            Self::Left => [0.0, -1.0, 0.0],
            Self::Right => [0.0, 1.0, 0.0],
        }
    }
}

// By hand rather than derived: serde's message for an unknown variant names neither the key
// nor, in this layout, the words a user can write instead.
impl<'de> Deserialize<'de> for TrackerHemisphere {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Names;
        impl serde::de::Visitor<'_> for Names {
            type Value = TrackerHemisphere;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("tracker.hemisphere: one of forward, aft, upper, lower, left, right")
            }
            fn visit_str<E: serde::de::Error>(self, s: &str) -> Result<Self::Value, E> {
                TrackerHemisphere::ALL
                    .into_iter()
                    .find(|h| h.name() == s)
                    .ok_or_else(|| {
                        E::custom(format!(
                            "tracker.hemisphere: must be one of forward, aft, upper, lower, \
                             left, right, got {s:?}"
                        ))
                    })
            }
        }
        d.deserialize_str(Names)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TrackerConfig {
    /// The tracker's serial device (a udev rule gives it a stable name).
    pub port: PathBuf,
    /// The tracker's baud rate, as its switches are set.
    pub baud: u32,
    pub record: TrackerRecord,
    pub mode: TrackerMode,
    /// Records per second: polled at this rate in point mode, expected at it in stream mode.
    pub rate_hz: f64,
    /// The device's position full scale (in): 36, or 72 with the extended range set.
    pub full_scale_in: f64,
    /// No record for this long (ms): the device is reported silent and asked again on the same
    /// port (silence is no reason to reopen it: a busy host delivers the bytes late).
    pub silent_after_ms: f64,
    /// Fastest the end effector can move (m/s). Records carry no checksum: one farther from
    /// the last than this allows (plus 5 mm) is held back until the next confirms it.
    pub max_speed_m_per_s: f64,
    /// Base frame from tracker frame: p_base = R(rotation_deg) · p_tracker + translation_m.
    pub translation_m: Position,
    /// Roll, pitch, yaw (°) about the tracker's x, y, z: R = Rz(yaw) · Ry(pitch) · Rx(roll).
    pub rotation_deg: [f64; 3],
    /// The side of the transmitter the sensor stays on, in the tracker's frame (before
    /// `rotation_deg`/`translation_m`); sent at open. Absent: forward, the unit's default.
    #[serde(default)]
    pub hemisphere: TrackerHemisphere,
}

/// A failed check: the dotted key and a message that does not repeat it.
pub(crate) type Invalid = (String, String);

fn invalid<T>(key: String, message: String) -> Result<T, Invalid> {
    Err((key, message))
}

/// Normalised actuation ↔ motor ticks for the tendon motors, one per actuator: the actuator
/// length of `a` (from its stroke in `[arm]`), wound onto the motor's spool. Fixed capacity, so
/// a driver's cycle copies it without allocating.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mapping {
    /// Ticks per normalised unit, signed by the motor's direction.
    ticks_per_unit: [f64; MAX_ACTUATORS],
    zero_ticks: [i32; MAX_ACTUATORS],
    motors: usize,
}

impl Mapping {
    /// The mapping of a checked section on its arm (one motor per actuator).
    pub fn new(tendon: &TendonConfig, arm: &Layout) -> Self {
        let motors = tendon.ids.len().min(arm.actuators().len());
        let mut ticks_per_unit = [0.0; MAX_ACTUATORS];
        let mut zero_ticks = [0; MAX_ACTUATORS];
        for (i, a) in arm.actuators().iter().take(motors).enumerate() {
            let radians = (a.max_m - a.min_m) / tendon.spool_radius_m[i];
            ticks_per_unit[i] =
                f64::from(tendon.direction[i]) * radians / TAU * f64::from(tendon.ticks_per_rev);
            zero_ticks[i] = tendon.zero_ticks[i];
        }
        Self {
            ticks_per_unit,
            zero_ticks,
            motors,
        }
    }

    /// The mapping of `actuators` (0-based, in that order) alone: one bus's motors.
    pub fn select(&self, actuators: &[usize]) -> Self {
        let mut m = Self {
            ticks_per_unit: [0.0; MAX_ACTUATORS],
            zero_ticks: [0; MAX_ACTUATORS],
            motors: actuators.len(),
        };
        for (k, &i) in actuators.iter().enumerate() {
            m.ticks_per_unit[k] = self.ticks_per_unit[i];
            m.zero_ticks[k] = self.zero_ticks[i];
        }
        m
    }

    /// How many motors it maps.
    pub fn motors(&self) -> usize {
        self.motors
    }

    /// The goal position of motor `i` for actuation `a` (rounded to the nearest tick).
    pub fn ticks(&self, i: usize, a: f64) -> i32 {
        // `as` saturates: no actuation, however wild, wraps around.
        (f64::from(self.zero_ticks[i]) + a * self.ticks_per_unit[i]).round() as i32
    }

    /// The actuation motor `i` stands at (ticks from the wire: any i32).
    pub fn actuation(&self, i: usize, ticks: i32) -> f64 {
        (f64::from(ticks) - f64::from(self.zero_ticks[i])) / self.ticks_per_unit[i]
    }

    /// Every motor's goal for `a` (one value per motor; the rest of the array 0).
    pub fn all_ticks(&self, a: &[f64]) -> [i32; MAX_ACTUATORS] {
        let mut t = [0; MAX_ACTUATORS];
        for i in 0..self.motors.min(a.len()) {
            t[i] = self.ticks(i, a[i]);
        }
        t
    }
}

impl TendonConfig {
    /// The buses of a checked section: `port`'s first, with every actuator not on an extra
    /// bus, then each `extra_bus` in order.
    pub fn buses(&self) -> Vec<Bus> {
        let n = self.ids.len();
        let extra: Vec<usize> = self
            .extra_bus
            .iter()
            .flat_map(|b| b.actuators.iter().map(|a| a - 1))
            .collect();
        let main: Vec<usize> = (0..n).filter(|i| !extra.contains(i)).collect();
        std::iter::once((self.port.clone(), main))
            .chain(
                (self.extra_bus.iter())
                    .map(|b| (b.port.clone(), b.actuators.iter().map(|a| a - 1).collect())),
            )
            .map(|(port, actuators)| self.bus(port, actuators))
            .collect()
    }

    fn bus(&self, port: PathBuf, actuators: Vec<usize>) -> Bus {
        fn pick<T: Copy>(all: &[T], which: &[usize]) -> Vec<T> {
            which.iter().map(|&i| all[i]).collect()
        }
        let tendon = TendonConfig {
            port,
            ids: pick(&self.ids, &actuators),
            extra_bus: Vec::new(),
            spool_radius_m: pick(&self.spool_radius_m, &actuators),
            zero_ticks: pick(&self.zero_ticks, &actuators),
            direction: pick(&self.direction, &actuators),
            min_ticks: pick(&self.min_ticks, &actuators),
            max_ticks: pick(&self.max_ticks, &actuators),
            ..self.clone()
        };
        Bus { tendon, actuators }
    }

    /// Checks the section against the arm and the controller's actuator limits: every setpoint
    /// the controller may send must map to ticks the motors accept.
    /// `controller_rate_hz`: the time-outs must span several of the controller's periods.
    pub(crate) fn validate(
        &self,
        arm: &Layout,
        actuator_min: &[f64],
        actuator_max: &[f64],
        controller_rate_hz: f64,
    ) -> Result<(), Invalid> {
        let key = |k: &str| format!("tendon.{k}");
        let n = arm.actuators().len();
        self.validate_arm(arm)?;
        self.validate_buses(n)?;
        self.validate_ids()?;
        if !(self.rate_hz.is_finite() && (1.0..=1000.0).contains(&self.rate_hz)) {
            return invalid(
                key("rate_hz"),
                format!("must be in [1, 1000] Hz, got {:?}", self.rate_hz),
            );
        }
        if !(16..=1 << 20).contains(&self.ticks_per_rev) {
            return invalid(
                key("ticks_per_rev"),
                format!("must be 16 to 1048576, got {}", self.ticks_per_rev),
            );
        }
        self.validate_motors(n)?;
        self.validate_mapping(arm, actuator_min, actuator_max)?;
        if self.profile_velocity > 32767 {
            return invalid(
                key("profile_velocity"),
                format!("must be 0 to 32767, got {}", self.profile_velocity),
            );
        }
        if !(self.max_engage_step.is_finite()
            && self.max_engage_step > 0.0
            && self.max_engage_step <= 1.0)
        {
            return invalid(
                key("max_engage_step"),
                format!("must be in (0, 1], got {:?}", self.max_engage_step),
            );
        }
        self.validate_timeouts(controller_rate_hz)
    }

    /// A tendon motor per actuator of the arm: no chamber among them, and each per-motor
    /// list one value per actuator.
    fn validate_arm(&self, arm: &Layout) -> Result<(), Invalid> {
        let n = arm.actuators().len();
        if let Some(i) = arm.actuators().iter().position(|a| a.kind != Kind::Tendon) {
            return invalid(
                "tendon.ids".into(),
                format!(
                    "actuator {} ({}) of [arm] is a pneumatic chamber, which the tendon driver \
                     cannot drive: chambers run in the sim alone (robot.drivers = [\"sim\"] and \
                     no [tendon] section)",
                    i + 1,
                    arm.actuators()[i].name
                ),
            );
        }
        let lengths = [
            ("ids", self.ids.len()),
            ("spool_radius_m", self.spool_radius_m.len()),
            ("zero_ticks", self.zero_ticks.len()),
            ("direction", self.direction.len()),
            ("min_ticks", self.min_ticks.len()),
            ("max_ticks", self.max_ticks.len()),
        ];
        for (name, len) in lengths {
            if len != n {
                return invalid(
                    format!("tendon.{name}"),
                    format!(
                        "{len} values for an arm of {n} actuators ([arm]); give one per motor, \
                         in the arm's order"
                    ),
                );
            }
        }
        Ok(())
    }

    /// The buses: `port`, the extra buses (each checked by [`ExtraBus::validate`]) with
    /// actuators of the arm's `n`, `port`'s keeping at least one, and `baud`.
    fn validate_buses(&self, n: usize) -> Result<(), Invalid> {
        if self.port.as_os_str().is_empty() {
            return invalid("tendon.port".into(), "must name the serial device".into());
        }
        let mut taken: Vec<Option<usize>> = vec![None; n];
        for (k, b) in self.extra_bus.iter().enumerate() {
            let earlier =
                std::iter::once(&self.port).chain(self.extra_bus[..k].iter().map(|b| &b.port));
            b.validate(k, earlier, &mut taken)?;
        }
        if !self.extra_bus.is_empty() && taken.iter().all(Option::is_some) {
            return invalid(
                "tendon.port".into(),
                "every actuator is on an extra bus: put one on port's, or make one extra bus \
                 the port"
                    .into(),
            );
        }
        if !(9600..=10_500_000).contains(&self.baud) {
            return invalid(
                "tendon.baud".into(),
                format!("must be 9600 to 10500000 baud, got {}", self.baud),
            );
        }
        Ok(())
    }

    /// The motor ids: each a Dynamixel id, unique on its bus (two buses may each have a motor
    /// 1).
    fn validate_ids(&self) -> Result<(), Invalid> {
        let bus_of = |i: usize| {
            (self.extra_bus.iter())
                .position(|b| b.actuators.contains(&(i + 1)))
                .map_or(0, |k| k + 1)
        };
        for (i, &id) in self.ids.iter().enumerate() {
            if id > 252 {
                return invalid(
                    format!("tendon.ids[{i}]"),
                    format!("motor ids are 0 to 252, got {id}"),
                );
            }
            if let Some(first) = (0..i).find(|&j| self.ids[j] == id && bus_of(j) == bus_of(i)) {
                return invalid(
                    format!("tendon.ids[{i}]"),
                    format!(
                        "id {id} is the motor of actuator {} already, on the same bus; each \
                         motor drives one actuator",
                        first + 1
                    ),
                );
            }
        }
        Ok(())
    }

    /// Each of the `n` motors: its spool, its direction and its position limits, which
    /// position control must accept.
    fn validate_motors(&self, n: usize) -> Result<(), Invalid> {
        let (lowest, highest) = TICKS_RANGE;
        for i in 0..n {
            let r = self.spool_radius_m[i];
            if !(r.is_finite() && r > 0.0 && r <= 0.5) {
                return invalid(
                    format!("tendon.spool_radius_m[{i}]"),
                    format!("must be in (0, 0.5] m, got {r:?}"),
                );
            }
            if !matches!(self.direction[i], 1 | -1) {
                return invalid(
                    format!("tendon.direction[{i}]"),
                    format!("must be 1 or -1, got {}", self.direction[i]),
                );
            }
            let (lo, hi) = (self.min_ticks[i], self.max_ticks[i]);
            for (name, v) in [("min_ticks", lo), ("max_ticks", hi)] {
                if !(lowest..=highest).contains(&v) {
                    return invalid(
                        format!("tendon.{name}[{i}]"),
                        format!(
                            "{v} is outside what position control accepts, [{lowest}, \
                             {highest}]"
                        ),
                    );
                }
            }
            if lo >= hi {
                return invalid(
                    format!("tendon.max_ticks[{i}]"),
                    format!("{hi} must exceed min_ticks[{i}] = {lo}"),
                );
            }
        }
        Ok(())
    }

    /// The controller's limits (`actuator_min`, `actuator_max`, one per actuator of `arm`)
    /// map inside each motor's own: a motor that would be pushed past them is named.
    fn validate_mapping(
        &self,
        arm: &Layout,
        actuator_min: &[f64],
        actuator_max: &[f64],
    ) -> Result<(), Invalid> {
        let mapping = Mapping::new(self, arm);
        for i in 0..arm.actuators().len() {
            let ends = [actuator_min[i], actuator_max[i]];
            for (end, a) in ["actuator_min", "actuator_max"].into_iter().zip(ends) {
                let t = mapping.ticks(i, a);
                if !(self.min_ticks[i]..=self.max_ticks[i]).contains(&t) {
                    return invalid(
                        format!("tendon.zero_ticks[{i}]"),
                        format!(
                            "motor {} (actuator {}) would need {t} ticks at controller.{end} \
                             = {a}, outside its limits [{}, {}] (min_ticks, max_ticks); check \
                             zero_ticks, direction and spool_radius_m of this motor",
                            self.ids[i],
                            i + 1,
                            self.min_ticks[i],
                            self.max_ticks[i]
                        ),
                    );
                }
            }
        }
        Ok(())
    }

    /// `hold_after_ms` and `torque_off_after_ms`, against this driver's rate (checked) and
    /// the controller's, `controller_rate_hz`.
    fn validate_timeouts(&self, controller_rate_hz: f64) -> Result<(), Invalid> {
        // A setpoint must be missed for several periods of both loops before the driver
        // stops following, or it would hold between two of them.
        let periods_ms = 3.0 * (1000.0 / self.rate_hz).max(1000.0 / controller_rate_hz);
        if !(self.hold_after_ms.is_finite() && self.hold_after_ms >= periods_ms) {
            return invalid(
                "tendon.hold_after_ms".into(),
                format!(
                    "must be at least 3 periods of tendon.rate_hz and controller.rate_hz, \
                     {periods_ms} ms, got {:?}",
                    self.hold_after_ms
                ),
            );
        }
        if !(self.torque_off_after_ms.is_finite()
            && self.torque_off_after_ms > self.hold_after_ms
            && self.torque_off_after_ms <= 600_000.0)
        {
            return invalid(
                "tendon.torque_off_after_ms".into(),
                format!(
                    "must be in (hold_after_ms, 600000] = ({}, 600000] ms, got {:?}",
                    self.hold_after_ms, self.torque_off_after_ms
                ),
            );
        }
        Ok(())
    }
}

impl ExtraBus {
    /// Checks `[[tendon.extra_bus]]` number `k`: a port, none of the buses' before it
    /// (`earlier`), and actuators of the arm's `taken.len()`, each on no bus yet (`taken`:
    /// which extra bus each is on; marked here).
    fn validate<'a>(
        &self,
        k: usize,
        mut earlier: impl Iterator<Item = &'a PathBuf>,
        taken: &mut [Option<usize>],
    ) -> Result<(), Invalid> {
        let key = |what: &str| format!("tendon.extra_bus[{k}].{what}");
        let n = taken.len();
        if self.port.as_os_str().is_empty() {
            return invalid(key("port"), "must name the serial device".into());
        }
        if earlier.any(|p| *p == self.port) {
            return invalid(
                key("port"),
                format!("{} is the port of another bus", self.port.display()),
            );
        }
        if self.actuators.is_empty() {
            return invalid(
                key("actuators"),
                "a bus drives at least one actuator".into(),
            );
        }
        for &a in &self.actuators {
            if !(1..=n).contains(&a) {
                return invalid(
                    key("actuators"),
                    format!("actuator {a}: the arm has actuators 1 to {n}"),
                );
            }
            if let Some(other) = taken[a - 1].replace(k) {
                return invalid(
                    key("actuators"),
                    format!("actuator {a} is on extra_bus[{other}] already"),
                );
            }
        }
        Ok(())
    }
}

/// Tracker frame (inches, as the device reports) ↔ base frame (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    rotation: [[f64; 3]; 3],
    translation_m: Position,
}

impl Frame {
    pub fn new(tracker: &TrackerConfig) -> Self {
        let [roll, pitch, yaw] = tracker.rotation_deg.map(f64::to_radians);
        let (sr, cr) = roll.sin_cos();
        let (sp, cp) = pitch.sin_cos();
        let (sy, cy) = yaw.sin_cos();
        // Rz(yaw) · Ry(pitch) · Rx(roll).
        let rotation = [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ];
        Self {
            rotation,
            translation_m: tracker.translation_m,
        }
    }

    /// A position the device reports (in, tracker frame) in the base frame (m).
    pub fn to_base(&self, tracker_in: [f64; 3]) -> Position {
        let p = tracker_in.map(|v| v * METRES_PER_INCH);
        std::array::from_fn(|r| {
            (0..3).map(|c| self.rotation[r][c] * p[c]).sum::<f64>() + self.translation_m[r]
        })
    }

    /// Where the device sees a base-frame position (in): the inverse of [`Frame::to_base`].
    pub fn to_tracker(&self, base_m: Position) -> [f64; 3] {
        let d: [f64; 3] = std::array::from_fn(|i| base_m[i] - self.translation_m[i]);
        std::array::from_fn(|c| {
            (0..3).map(|r| self.rotation[r][c] * d[r]).sum::<f64>() / METRES_PER_INCH
        })
    }
}

impl TrackerConfig {
    pub(crate) fn validate(&self) -> Result<(), Invalid> {
        let key = |k: &str| format!("tracker.{k}");
        if self.port.as_os_str().is_empty() {
            return invalid(key("port"), "must name the serial device".into());
        }
        if !(2400..=1_000_000).contains(&self.baud) {
            return invalid(
                key("baud"),
                format!("must be 2400 to 1000000 baud, got {}", self.baud),
            );
        }
        if !(self.rate_hz.is_finite() && (1.0..=1000.0).contains(&self.rate_hz)) {
            return invalid(
                key("rate_hz"),
                format!("must be in [1, 1000] Hz, got {:?}", self.rate_hz),
            );
        }
        if !matches!(self.full_scale_in, 36.0 | 72.0) {
            return invalid(
                key("full_scale_in"),
                format!(
                    "the device's full scale is 36 or 72 in, got {:?}",
                    self.full_scale_in
                ),
            );
        }
        let period_ms = 1000.0 / self.rate_hz;
        if !(self.silent_after_ms.is_finite()
            && self.silent_after_ms >= 2.0 * period_ms
            && self.silent_after_ms <= 60_000.0)
        {
            return invalid(
                key("silent_after_ms"),
                format!(
                    "must be in [2 record periods, 60000] = [{}, 60000] ms, got {:?}",
                    2.0 * period_ms,
                    self.silent_after_ms
                ),
            );
        }
        if !(self.max_speed_m_per_s.is_finite()
            && self.max_speed_m_per_s > 0.0
            && self.max_speed_m_per_s <= 100.0)
        {
            return invalid(
                key("max_speed_m_per_s"),
                format!("must be in (0, 100] m/s, got {:?}", self.max_speed_m_per_s),
            );
        }
        for i in 0..3 {
            if !(self.translation_m[i].is_finite() && self.translation_m[i].abs() <= 10.0) {
                return invalid(
                    format!("tracker.translation_m[{i}]"),
                    format!("must be in [-10, 10] m, got {:?}", self.translation_m[i]),
                );
            }
            if !(self.rotation_deg[i].is_finite() && self.rotation_deg[i].abs() <= 360.0) {
                return invalid(
                    format!("tracker.rotation_deg[{i}]"),
                    format!("must be in [-360, 360]°, got {:?}", self.rotation_deg[i]),
                );
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn tendon() -> TendonConfig {
        TendonConfig {
            port: "/dev/null".into(),
            baud: 1_000_000,
            ids: vec![1, 2, 3, 4, 5, 6],
            extra_bus: Vec::new(),
            rate_hz: 100.0,
            ticks_per_rev: 4096,
            spool_radius_m: vec![0.015; 6],
            zero_ticks: vec![700, 700, 700, 3400, 3400, 3400],
            direction: vec![1, 1, 1, -1, -1, -1],
            min_ticks: vec![600, 600, 600, 700, 700, 700],
            max_ticks: vec![3400, 3400, 3400, 3500, 3500, 3500],
            profile_velocity: 200,
            max_engage_step: 0.05,
            hold_after_ms: 100.0,
            torque_off_after_ms: 2000.0,
        }
    }

    #[test]
    fn mapping_winds_the_stroke_onto_the_spool_and_back() {
        let arm = crate::arm::ArmConfig::default().layout().unwrap();
        let m = Mapping::new(&tendon(), &arm);
        // 60 mm stroke on a 15 mm spool: 4 rad, 2607.9 ticks.
        assert_eq!(m.ticks(0, 0.0), 700);
        assert_eq!(m.ticks(0, 1.0), 700 + 2608);
        assert_eq!(m.ticks(3, 1.0), 3400 - 2608);
        for i in 0..6 {
            for a in [0.0, 0.25, 0.5, 0.99] {
                let back = m.actuation(i, m.ticks(i, a));
                assert!((back - a).abs() < 0.5 / 2607.9 + 1e-12, "{i} {a} {back}");
            }
        }
    }

    #[test]
    fn inconsistent_limits_are_refused_naming_the_motor() {
        let arm = crate::arm::ArmConfig::default().layout().unwrap();
        let mut t = tendon();
        t.validate(&arm, &[0.0; 6], &[1.0; 6], 500.0).unwrap();
        t.direction[1] = -1; // 700 - 2608 < 600
        let (key, message) = t.validate(&arm, &[0.0; 6], &[1.0; 6], 500.0).unwrap_err();
        assert_eq!(key, "tendon.zero_ticks[1]");
        assert!(message.contains("motor 2 (actuator 2)"), "{message}");
        // ...but fine when the controller never asks for more than 0.03 of the stroke.
        t.validate(&arm, &[0.0; 6], &[0.03; 6], 500.0).unwrap();

        let mut t = tendon();
        t.max_ticks[4] = 4096;
        assert_eq!(
            t.validate(&arm, &[0.0; 6], &[1.0; 6], 500.0).unwrap_err().0,
            "tendon.max_ticks[4]"
        );
        let mut t = tendon();
        t.ids[5] = 1;
        assert_eq!(
            t.validate(&arm, &[0.0; 6], &[1.0; 6], 500.0).unwrap_err(),
            (
                "tendon.ids[5]".into(),
                "id 1 is the motor of actuator 1 already, on the same bus; each motor drives one actuator".into()
            )
        );
        let mut t = tendon();
        t.hold_after_ms = 20.0; // two periods at 100 Hz
        assert_eq!(
            t.validate(&arm, &[0.0; 6], &[1.0; 6], 500.0).unwrap_err().0,
            "tendon.hold_after_ms"
        );
        let mut t = tendon();
        t.torque_off_after_ms = 50.0;
        assert_eq!(
            t.validate(&arm, &[0.0; 6], &[1.0; 6], 500.0).unwrap_err().0,
            "tendon.torque_off_after_ms"
        );
    }

    fn layout(file: &str) -> Layout {
        let d = toml::from_str(&std::fs::read_to_string(file).unwrap()).unwrap();
        Layout::new(&d).unwrap()
    }

    /// A motor per actuator on any tendon arm, each with its own stroke; a list of another
    /// length, or an arm with a chamber, is refused naming the key.
    #[test]
    fn a_motor_per_actuator_of_any_tendon_arm() {
        let tdcr = layout(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../contract/arm/testdata/tdcr.toml"
        ));
        let nine = TendonConfig {
            ids: (11..20).collect(),
            spool_radius_m: vec![0.005; 9],
            zero_ticks: vec![1000; 9],
            direction: vec![1; 9],
            min_ticks: vec![900; 9],
            max_ticks: vec![3700; 9],
            ..tendon()
        };
        nine.validate(&tdcr, &[0.0; 9], &[1.0; 9], 500.0).unwrap();
        let m = Mapping::new(&nine, &tdcr);
        assert_eq!(m.motors(), 9);
        // 20 mm of stroke on a 5 mm spool: 4 rad, as the paper's 60 mm on 15 mm.
        assert_eq!(m.ticks(8, 1.0), 1000 + 2608);
        let six = tendon();
        let (key, message) = six
            .validate(&tdcr, &[0.0; 9], &[1.0; 9], 500.0)
            .unwrap_err();
        assert_eq!(key, "tendon.ids");
        assert!(
            message.contains("6 values for an arm of 9 actuators"),
            "{message}"
        );
        let short = TendonConfig {
            direction: vec![1; 8],
            ..nine.clone()
        };
        let (key, _) = short
            .validate(&tdcr, &[0.0; 9], &[1.0; 9], 500.0)
            .unwrap_err();
        assert_eq!(key, "tendon.direction");
        let hybrid = layout(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../contract/arm/testdata/hybrid.toml"
        ));
        let (key, message) = nine
            .validate(&hybrid, &[0.0; 9], &[1.0; 9], 500.0)
            .unwrap_err();
        assert_eq!(key, "tendon.ids");
        assert!(message.contains("pneumatic chamber"), "{message}");
    }

    /// Motors on more than one bus: each bus's section holds its own actuators' motors, ids
    /// may repeat across buses but not on one, and an actuator on two buses, one the arm does
    /// not have, a port named twice or a main bus left empty are refused naming the key.
    #[test]
    fn motors_on_more_than_one_bus() {
        let tdcr = layout(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../contract/arm/testdata/tdcr.toml"
        ));
        let two = TendonConfig {
            ids: vec![1, 2, 3, 4, 5, 6, 1, 2, 3],
            extra_bus: vec![ExtraBus {
                port: "/dev/tendon-b".into(),
                actuators: vec![7, 8, 9],
            }],
            spool_radius_m: vec![0.005; 9],
            zero_ticks: (0..9).map(|i| 1000 + i).collect(),
            direction: vec![1; 9],
            min_ticks: vec![900; 9],
            max_ticks: vec![3700; 9],
            ..tendon()
        };
        two.validate(&tdcr, &[0.0; 9], &[1.0; 9], 500.0).unwrap();
        let buses = two.buses();
        assert_eq!(buses.len(), 2);
        assert_eq!(buses[0].actuators, [0, 1, 2, 3, 4, 5]);
        assert_eq!(buses[1].actuators, [6, 7, 8]);
        assert_eq!(buses[1].tendon.port, PathBuf::from("/dev/tendon-b"));
        assert_eq!(buses[1].tendon.ids, [1, 2, 3]);
        assert_eq!(buses[1].tendon.zero_ticks, [1006, 1007, 1008]);
        let m = Mapping::new(&two, &tdcr);
        let b = m.select(&buses[1].actuators);
        assert_eq!(b.motors(), 3);
        assert_eq!(b.ticks(2, 0.5), m.ticks(8, 0.5));
        // One bus: all of it.
        assert_eq!(tendon().buses()[0].actuators, [0, 1, 2, 3, 4, 5]);
        let refused = |t: TendonConfig, key: &str, says: &str| {
            let (k, message) = t.validate(&tdcr, &[0.0; 9], &[1.0; 9], 500.0).unwrap_err();
            assert_eq!(k, key, "{message}");
            assert!(message.contains(says), "{message}");
        };
        let with_bus = |port: &str, actuators: Vec<usize>| TendonConfig {
            extra_bus: vec![ExtraBus {
                port: port.into(),
                actuators,
            }],
            ..two.clone()
        };
        refused(
            TendonConfig {
                ids: vec![1, 2, 3, 4, 5, 6, 1, 2, 1],
                ..two.clone()
            },
            "tendon.ids[8]",
            "id 1 is the motor of actuator 7 already, on the same bus",
        );
        refused(
            TendonConfig {
                extra_bus: Vec::new(),
                ..two.clone()
            },
            "tendon.ids[6]",
            "id 1 is the motor of actuator 1 already",
        );
        refused(
            with_bus("/dev/tendon-b", vec![7, 8, 10]),
            "tendon.extra_bus[0].actuators",
            "actuator 10: the arm has actuators 1 to 9",
        );
        refused(
            with_bus("/dev/null", vec![7, 8, 9]),
            "tendon.extra_bus[0].port",
            "the port of another bus",
        );
        refused(
            with_bus("/dev/tendon-b", (1..=9).collect()),
            "tendon.port",
            "every actuator is on an extra bus",
        );
        let mut twice = with_bus("/dev/tendon-b", vec![7, 8, 9]);
        twice.extra_bus.push(ExtraBus {
            port: "/dev/tendon-c".into(),
            actuators: vec![9],
        });
        refused(
            twice,
            "tendon.extra_bus[1].actuators",
            "actuator 9 is on extra_bus[0] already",
        );
    }

    #[test]
    fn frame_round_trips_and_rotates_as_documented() {
        let mut c = TrackerConfig {
            port: "/dev/null".into(),
            baud: 115_200,
            record: TrackerRecord::Position,
            mode: TrackerMode::Stream,
            rate_hz: 100.0,
            full_scale_in: 36.0,
            silent_after_ms: 200.0,
            max_speed_m_per_s: 2.0,
            translation_m: [0.1, -0.2, 0.3],
            rotation_deg: [0.0, 0.0, 90.0],
            hemisphere: TrackerHemisphere::Forward,
        };
        let f = Frame::new(&c);
        // Yaw 90°: the tracker's x is the base's y.
        let p = f.to_base([1.0 / METRES_PER_INCH, 0.0, 0.0]);
        assert!(
            (p[0] - 0.1).abs() < 1e-12 && (p[1] - 0.8).abs() < 1e-12,
            "{p:?}"
        );
        c.rotation_deg = [10.0, -20.0, 30.0];
        let f = Frame::new(&c);
        let q = [0.12, -0.05, -0.4];
        let back = f.to_base(f.to_tracker(q));
        for i in 0..3 {
            assert!((back[i] - q[i]).abs() < 1e-12);
        }
        c.validate().unwrap();
        c.silent_after_ms = 5.0;
        assert_eq!(c.validate().unwrap_err().0, "tracker.silent_after_ms");
    }

    /// The shipped hardware config with its `[tracker]` `hemisphere` line replaced by `line`
    /// (or removed when empty).
    fn hardware_with(line: &str) -> String {
        let text = include_str!("../../../config/hardware.toml");
        let at = text
            .find("\nhemisphere = ")
            .expect("hardware.toml sets the hemisphere");
        let end = at + 1 + text[at + 1..].find('\n').unwrap();
        format!("{}\n{line}{}", &text[..at], &text[end..])
    }

    #[test]
    fn the_hemisphere_defaults_to_forward_and_reads_every_name() {
        let parse = |line: &str| crate::Config::parse(&hardware_with(line), "h.toml", ".".into());
        let c = parse("").unwrap();
        assert_eq!(
            c.tracker.unwrap().hemisphere,
            TrackerHemisphere::Forward,
            "absent: the unit's own default"
        );
        for h in TrackerHemisphere::ALL {
            let c = parse(&format!("hemisphere = \"{}\"", h.name())).unwrap();
            assert_eq!(c.tracker.unwrap().hemisphere, h);
        }
        // Each points along one axis, and opposite names point opposite ways.
        for (a, b) in [(0, 1), (2, 3), (4, 5)] {
            let (a, b) = (TrackerHemisphere::ALL[a], TrackerHemisphere::ALL[b]);
            let dot: f64 = (0..3).map(|i| a.direction()[i] * b.direction()[i]).sum();
            assert_eq!(dot, -1.0, "{a:?} {b:?}");
        }
    }

    #[test]
    fn a_bad_hemisphere_is_refused_naming_the_key_and_the_choices() {
        for bad in ["\"up\"", "\"Forward\"", "\"\"", "1"] {
            let text = hardware_with(&format!("hemisphere = {bad}"));
            let e = crate::Config::parse(&text, "h.toml", ".".into()).unwrap_err();
            let line = text
                .lines()
                .position(|l| l.starts_with("hemisphere"))
                .unwrap()
                + 1;
            assert_eq!(e.line, Some(line), "{e}");
            assert!(e.message.contains("tracker.hemisphere"), "{bad}: {e}");
            if bad.starts_with('"') {
                assert!(
                    e.message
                        .contains("forward, aft, upper, lower, left, right"),
                    "{bad}: {e}"
                );
            }
        }
    }
}
