//! The arm softarm drives, described once at the bottom: its modules in order from the base,
//! each with its actuators (tendons, pneumatic chambers), where they run and what lengths they
//! span, and the actuators' names. Every process takes the arm from here, as ros2_control
//! takes a robot's joints from its description.
//!
//! [`Description`] is what a config file says (serde, with defaults: evenly spaced tendons,
//! names `a1`..`aN`); [`Layout::new`] checks it and gives the arm in the form the math reads:
//! actuators in the arm's order (module by module, tendons before chambers), each knowing its
//! module, radius and angle. No math beyond the checks: the kinematics of a layout is crate
//! `softarm-kinematics`.
//!
//! Conventions (the PCC model's): a module's frame has z along its straight backbone; an
//! actuator at radius r and angle β (the module's rotation included) has length
//! l − θ r cos(β − φ) when the module of backbone length l bends by θ towards φ. A tendon pulls,
//! so it bends its module towards its angle; a chamber pushes, so one off the axis bends the
//! module away from its angle, and one on the axis (radius 0) lengthens it.

use std::f64::consts::{PI, TAU};
use std::ops::Range;

use serde::{Deserialize, Serialize};

pub use softarm_space::MAX_ACTUATORS;
/// Most modules an arm may have.
pub const MAX_MODULES: usize = 8;
/// Longest length anywhere in a description (m).
pub const MAX_LENGTH_M: f64 = 10.0;
/// Largest routing radius (m).
pub const MAX_RADIUS_M: f64 = 1.0;

/// How the arm is mounted.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Mount {
    /// Base frame diag(1, −1, −1): the arm points down, −Z.
    #[default]
    Hanging,
    /// Base frame identity: the arm points up, +Z.
    Standing,
}

/// Where a distal module's tendons run.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Routing {
    /// Each tendon ends in its own module and runs through no other.
    #[default]
    Independent,
    /// A module's tendons run from the base through every module before it (usual on
    /// tendon-driven continuum robots): pulling one bends each module it passes.
    Coupled,
}

/// What an actuator is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    /// Pulls: bends its module towards its angle.
    Tendon,
    /// Pushes: lengthens its module (on the axis) or bends it away from its angle.
    Chamber,
}

impl Kind {
    fn key(self) -> &'static str {
        match self {
            Kind::Tendon => "tendons",
            Kind::Chamber => "chambers",
        }
    }
}

/// The `[arm]` section as written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Description {
    #[serde(default)]
    pub mount: Mount,
    #[serde(default)]
    pub routing: Routing,
    /// Rigid connector between consecutive modules (m).
    #[serde(default)]
    pub connector_m: f64,
    /// Rigid tool after the last module, to the point the tracker sees (m).
    #[serde(default)]
    pub tool_m: f64,
    /// The modules, from the base.
    pub modules: Vec<ModuleDescription>,
}

/// One module as written: its tendons and chambers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ModuleDescription {
    /// The angle every actuator angle of the module is measured from (degrees).
    #[serde(default)]
    pub rotation_deg: f64,
    /// A backbone of fixed length (m), as a tendon-driven continuum robot's rod; absent, the
    /// module is as long as its actuators make it (a soft module).
    #[serde(default)]
    pub backbone_m: Option<f64>,
    #[serde(default)]
    pub tendons: Option<Group>,
    #[serde(default)]
    pub chambers: Option<Group>,
}

/// Actuators of one kind in a module.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Group {
    pub count: usize,
    /// Distance from the backbone (m): a tendon's routing radius; 0 for a chamber on the axis
    /// (the default for chambers).
    #[serde(default)]
    pub radius_m: f64,
    /// Each actuator's angle from the module's rotation (degrees); evenly spaced from 0 when
    /// absent.
    #[serde(default)]
    pub angles_deg: Option<Vec<f64>>,
    /// Each actuator's length at normalised actuation 0 and 1 (m): for a coupled tendon, its
    /// whole run from the base.
    pub length_m: [f64; 2],
    /// Names (ROS 2 joints, the view, logs); `aK` by the actuator's place in the arm when
    /// absent.
    #[serde(default)]
    pub names: Option<Vec<String>>,
}

/// A description that is not an arm: which key, and why, with what would be valid.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Invalid {
    /// The key, e.g. `arm.modules[1].tendons.angles_deg`.
    pub key: String,
    pub message: String,
}

impl std::fmt::Display for Invalid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.key, self.message)
    }
}

impl std::error::Error for Invalid {}

fn invalid<T>(key: impl Into<String>, message: impl Into<String>) -> Result<T, Invalid> {
    Err(Invalid {
        key: key.into(),
        message: message.into(),
    })
}

/// One actuator of a layout.
#[derive(Debug, Clone, PartialEq)]
pub struct Actuator {
    pub name: String,
    pub kind: Kind,
    /// Its module (0 = at the base).
    pub module: usize,
    pub radius_m: f64,
    /// Its angle in its module's frame, the module's rotation included (rad).
    pub angle_rad: f64,
    /// Length at normalised actuation 0 and 1 (m).
    pub min_m: f64,
    pub max_m: f64,
}

impl Actuator {
    /// Length (m) of normalised actuation `a`.
    pub fn length_of(&self, a: f64) -> f64 {
        self.min_m + a * (self.max_m - self.min_m)
    }

    /// Normalised actuation of length `l` (m).
    pub fn actuation_of(&self, l: f64) -> f64 {
        (l - self.min_m) / (self.max_m - self.min_m)
    }

    /// The direction (rad) it bends its module towards.
    fn pull_rad(&self) -> Option<f64> {
        match self.kind {
            _ if self.radius_m == 0.0 => None,
            Kind::Tendon => Some(self.angle_rad),
            Kind::Chamber => Some(self.angle_rad + PI),
        }
    }
}

/// One module of a layout.
#[derive(Debug, Clone, PartialEq)]
pub struct Module {
    /// Its fixed backbone length (m), if it has one.
    pub backbone_m: Option<f64>,
    /// Its own actuators, as indices into [`Layout::actuators`].
    pub actuators: Range<usize>,
}

/// A checked arm.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    modules: Vec<Module>,
    actuators: Vec<Actuator>,
    routing: Routing,
    pub mount: Mount,
    pub connector_m: f64,
    pub tool_m: f64,
}

impl Layout {
    /// Checks `d`; an error names the key (under `arm.`), what is wrong and what would do.
    pub fn new(d: &Description) -> Result<Self, Invalid> {
        let n = d.modules.len();
        if !(1..=MAX_MODULES).contains(&n) {
            return invalid(
                "arm.modules",
                format!("{n} modules; an arm has 1 to {MAX_MODULES}"),
            );
        }
        for (key, v) in [("arm.connector_m", d.connector_m), ("arm.tool_m", d.tool_m)] {
            length(key, v, 0.0)?;
        }
        let mut modules = Vec::with_capacity(n);
        let mut actuators = Vec::new();
        for (m, md) in d.modules.iter().enumerate() {
            let key = format!("arm.modules[{m}]");
            let start = actuators.len();
            module(&key, m, md, &mut actuators)?;
            if actuators.len() > MAX_ACTUATORS {
                return invalid(
                    key,
                    format!(
                        "brings the arm to {} actuators; an arm has at most {MAX_ACTUATORS}",
                        actuators.len()
                    ),
                );
            }
            modules.push(Module {
                backbone_m: md.backbone_m,
                actuators: start..actuators.len(),
            });
            bends_every_way(&key, &actuators[start..])?;
        }
        names(d, &mut actuators)?;
        Ok(Self {
            modules,
            actuators,
            routing: d.routing,
            mount: d.mount,
            connector_m: d.connector_m,
            tool_m: d.tool_m,
        })
    }

    /// The modules, from the base.
    pub fn modules(&self) -> &[Module] {
        &self.modules
    }

    /// The actuators, in the arm's order.
    pub fn actuators(&self) -> &[Actuator] {
        &self.actuators
    }

    pub fn routing(&self) -> Routing {
        self.routing
    }

    /// Whether actuator `i` runs through module `m`: its own, and with coupled routing a
    /// tendon also every module before it.
    pub fn passes(&self, i: usize, m: usize) -> bool {
        let a = &self.actuators[i];
        match (self.routing, a.kind) {
            (Routing::Coupled, Kind::Tendon) => m <= a.module,
            _ => m == a.module,
        }
    }

    /// The paper's kind of arm: two soft modules of three tendons at 120° each, ending in
    /// their module (whatever their radius, stroke and rotation).
    pub fn is_papers_kind(&self) -> bool {
        self.modules.len() == 2
            && self.routing == Routing::Independent
            && self.modules.iter().all(|m| {
                let own = &self.actuators[m.actuators.clone()];
                m.backbone_m.is_none()
                    && own.len() == 3
                    && own.iter().all(|a| a.kind == Kind::Tendon)
                    && (0..3).all(|k| {
                        let step = own[k].angle_rad - own[0].angle_rad;
                        (step - TAU * k as f64 / 3.0).abs() < 1e-9
                    })
            })
    }

    /// How far the tool can be from the mount at most (m): every module at its longest (its
    /// backbone, or its longest actuator's full length), the connectors and the tool in a
    /// line. An upper bound of the reach, for the boxes way-points and the learner's lattices
    /// may span.
    pub fn reach_m(&self) -> f64 {
        let modules: f64 = self
            .modules
            .iter()
            .map(|m| {
                m.backbone_m.unwrap_or_else(|| {
                    self.actuators[m.actuators.clone()]
                        .iter()
                        .map(|a| a.min_m.max(a.max_m))
                        .fold(0.0, f64::max)
                })
            })
            .sum();
        modules + self.connector_m * (self.modules.len() - 1) as f64 + self.tool_m
    }

    /// The names, in the arm's order.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.actuators.iter().map(|a| a.name.as_str())
    }

    /// Who the arm is to the processes that share it: its counts, first and last names and a
    /// hash of its whole structure (every module's actuators, kinds and names, the routing;
    /// not the lengths and radii a calibration changes). Two processes whose identities differ
    /// read each other's per-actuator data wrongly, so they refuse to share a stack. At most
    /// 256 bytes (an iceoryx2 attribute).
    pub fn identity(&self) -> String {
        // FNV-1a: stable across builds and platforms, unlike std's hasher.
        let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |bytes: &[u8]| {
            for &b in bytes {
                hash = (hash ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
            }
        };
        eat(format!("{:?};", self.routing).as_bytes());
        for a in &self.actuators {
            eat(format!("{}:{:?}:{};", a.module, a.kind, a.name).as_bytes());
        }
        let names: Vec<&str> = self.names().collect();
        format!(
            "{} actuators ({} .. {}) in {} modules, layout {hash:016x}",
            names.len(),
            names[0],
            names[names.len() - 1],
            self.modules.len()
        )
    }
}

/// Checks `length` at `key`: finite, above `min` (or at it, when `min` is 0), at most
/// [`MAX_LENGTH_M`].
fn length(key: &str, v: f64, min: f64) -> Result<(), Invalid> {
    let ok = v.is_finite() && v <= MAX_LENGTH_M && if min == 0.0 { v >= 0.0 } else { v > min };
    if ok {
        return Ok(());
    }
    let lower = if min == 0.0 { "[0" } else { "(0" };
    invalid(
        key,
        format!("{v:?} m; must be a length in {lower}, {MAX_LENGTH_M}] m"),
    )
}

/// Module `m`'s actuators appended to `out`.
fn module(
    key: &str,
    m: usize,
    md: &ModuleDescription,
    out: &mut Vec<Actuator>,
) -> Result<(), Invalid> {
    if !(md.rotation_deg.is_finite() && (-360.0..=360.0).contains(&md.rotation_deg)) {
        return invalid(
            format!("{key}.rotation_deg"),
            format!("{:?}; must be in [-360, 360] degrees", md.rotation_deg),
        );
    }
    if let Some(b) = md.backbone_m {
        length(&format!("{key}.backbone_m"), b, f64::MIN_POSITIVE)?;
    }
    if md.tendons.is_none() && md.chambers.is_none() {
        return invalid(
            key.to_string(),
            "has no actuators; give it `tendons` or `chambers` (or both)",
        );
    }
    for (kind, group) in [(Kind::Tendon, &md.tendons), (Kind::Chamber, &md.chambers)] {
        let Some(g) = group else { continue };
        let key = format!("{key}.{}", kind.key());
        group_actuators(&key, kind, m, md.rotation_deg, g, out)?;
        let on_axis = kind == Kind::Chamber && g.radius_m == 0.0;
        if on_axis && md.backbone_m.is_some() {
            return invalid(
                format!("{key}.radius_m"),
                "a chamber on the axis lengthens its module, which a fixed backbone \
                 (backbone_m) does not allow; drop backbone_m or put the chambers off the axis",
            );
        }
    }
    Ok(())
}

fn group_actuators(
    key: &str,
    kind: Kind,
    module: usize,
    rotation_deg: f64,
    g: &Group,
    out: &mut Vec<Actuator>,
) -> Result<(), Invalid> {
    if !(1..=MAX_ACTUATORS).contains(&g.count) {
        return invalid(
            format!("{key}.count"),
            format!("{}; must be 1 to {MAX_ACTUATORS}", g.count),
        );
    }
    let min_radius = if kind == Kind::Tendon {
        f64::MIN_POSITIVE
    } else {
        0.0
    };
    let radius_ok =
        g.radius_m.is_finite() && g.radius_m >= min_radius && g.radius_m <= MAX_RADIUS_M;
    if !radius_ok {
        let what = if kind == Kind::Tendon {
            format!("a tendon runs off the backbone: (0, {MAX_RADIUS_M}] m")
        } else {
            format!("[0, {MAX_RADIUS_M}] m (0: on the axis)")
        };
        return invalid(
            format!("{key}.radius_m"),
            format!("{:?}; must be in {what}", g.radius_m),
        );
    }
    let angles = angles(key, g)?;
    let [lo, hi] = g.length_m;
    length(&format!("{key}.length_m"), lo, f64::MIN_POSITIVE)?;
    length(&format!("{key}.length_m"), hi, f64::MIN_POSITIVE)?;
    if hi <= lo {
        return invalid(
            format!("{key}.length_m"),
            format!("[{lo}, {hi}]: the length at actuation 1 must exceed the length at 0"),
        );
    }
    for angle_deg in angles {
        out.push(Actuator {
            name: String::new(),
            kind,
            module,
            radius_m: g.radius_m,
            angle_rad: (rotation_deg + angle_deg).to_radians(),
            min_m: lo,
            max_m: hi,
        });
    }
    Ok(())
}

/// The group's angles (degrees from the module's rotation): as given, or evenly spaced.
fn angles(key: &str, g: &Group) -> Result<Vec<f64>, Invalid> {
    let Some(given) = &g.angles_deg else {
        return Ok((0..g.count)
            .map(|k| 360.0 * k as f64 / g.count as f64)
            .collect());
    };
    let key = format!("{key}.angles_deg");
    if given.len() != g.count {
        return invalid(
            key,
            format!(
                "{} angles for {} actuators; give one each",
                given.len(),
                g.count
            ),
        );
    }
    for (k, a) in given.iter().enumerate() {
        if !(a.is_finite() && (-360.0..=360.0).contains(a)) {
            return invalid(
                format!("{key}[{k}]"),
                format!("{a:?}; must be in [-360, 360] degrees"),
            );
        }
    }
    Ok(given.clone())
}

/// A module must bend towards every direction: the directions its actuators bend it (a
/// tendon towards its angle, a chamber off the axis away from it) leave no gap of 180° or more.
fn bends_every_way(key: &str, actuators: &[Actuator]) -> Result<(), Invalid> {
    let mut pulls: Vec<f64> = actuators
        .iter()
        .filter_map(Actuator::pull_rad)
        .map(|a| a.rem_euclid(TAU))
        .collect();
    pulls.sort_by(f64::total_cmp);
    let widest = match pulls.as_slice() {
        [] => TAU,
        [first, ..] => {
            let wrap = first + TAU - pulls[pulls.len() - 1];
            pulls.windows(2).map(|w| w[1] - w[0]).fold(wrap, f64::max)
        }
    };
    // A hair under 180°: three tendons at 0°, 120°, 240° written in degrees are fine.
    if widest < PI - 1e-9 {
        return Ok(());
    }
    let around: Vec<String> = pulls
        .iter()
        .map(|a| format!("{:.0}°", a.to_degrees()))
        .collect();
    invalid(
        key.to_string(),
        format!(
            "cannot bend in every direction: its actuators bend it towards [{}], which leaves a \
             gap of {:.0}°; a module needs at least three tendons (or chambers off the axis) \
             with no gap of 180° or more between neighbours, e.g. tendons = {{ count = 3, ... }} \
             evenly spaced",
            around.join(", "),
            widest.to_degrees()
        ),
    )
}

/// Names from the description, or `aK` by place; unique, and usable as a ROS 2 joint name.
fn names(d: &Description, actuators: &mut [Actuator]) -> Result<(), Invalid> {
    let mut i = 0;
    for (m, md) in d.modules.iter().enumerate() {
        for (kind, group) in [(Kind::Tendon, &md.tendons), (Kind::Chamber, &md.chambers)] {
            let Some(g) = group else { continue };
            let key = format!("arm.modules[{m}].{}.names", kind.key());
            if let Some(given) = &g.names
                && given.len() != g.count
            {
                return invalid(
                    key,
                    format!(
                        "{} names for {} actuators; give one each",
                        given.len(),
                        g.count
                    ),
                );
            }
            for k in 0..g.count {
                let name = g
                    .names
                    .as_ref()
                    .map_or_else(|| format!("a{}", i + 1), |n| n[k].clone());
                let usable = !name.is_empty()
                    && name.len() <= 64
                    && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
                    && !name.starts_with(|c: char| c.is_ascii_digit());
                if !usable {
                    return invalid(
                        format!("{key}[{k}]"),
                        format!(
                            "{name:?}; a name is 1 to 64 letters, digits and `_`, not starting \
                             with a digit"
                        ),
                    );
                }
                if let Some(first) = actuators[..i].iter().position(|a| a.name == name) {
                    return invalid(
                        format!("{key}[{k}]"),
                        format!(
                            "{name:?} names actuator {} already; names are unique",
                            first + 1
                        ),
                    );
                }
                actuators[i].name = name;
                i += 1;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
