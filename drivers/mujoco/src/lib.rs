//! The sim's plant as a MuJoCo model: physics softarm did not write behind the sim's own
//! actuators (lag, rate limit, backlash, disturbance, drift) and tracker noise
//! (`softarm_sim::plant::Physics`).
//!
//! Two ways to a model, both `[sim.mujoco]` (`softarm_sections::mujoco::MujocoConfig`):
//! - **a lab's own MJCF** (`model`), with a map: which of its actuators is which of the arm's
//!   and what `ctrl` an actuation sets (by default the arm's actuator length, as for a position
//!   actuator on a tendon's length), which site is the tracked tip and where the marker sits
//!   in its frame, where the model's world is in the arm's base frame;
//! - **generated from `[arm]`** ([`generate`]): modules as chains of links with elastic joints,
//!   tendons routed through every link they pass, chambers as length actuators, gravity by the
//!   mount.
//!
//! The model runs lock-stepped to the plant's clock, in its own time step; a tip load comes on
//! at its time, and a scenario's steps change what an actuation sets (the arm's actuator
//! lengths) and where the tool ends (`tool_m`). Loading allocates; advancing does not.
//!
//! Empty without its `physics` feature, which links MuJoCo (decision 0011).
#![cfg(feature = "physics")]

use std::path::Path;
use std::sync::Arc;

use mujoco_rs::prelude::*;
use softarm_arm::{Layout, MAX_ACTUATORS};
use softarm_sections::arm::ArmConfig;
use softarm_sections::mujoco::{MujocoConfig, TipLoad};
use softarm_sim::plant::Physics;

pub mod generate;

/// Most steps of an arm's scenario the model follows.
const MAX_STEPS: usize = softarm_sections::changes::MAX_STEPS;

/// How long the model settles at the first actuation before its clock starts (s): it starts
/// at rest where it is first driven, as an arm switched on and left to hang (a standing TDCR
/// under gravity still creeps after 2 s).
const SETTLE_S: f64 = 5.0;

/// What an actuation sets, and where the tool ends, from a time on.
#[derive(Debug, Clone, Copy)]
struct Phase {
    from_s: f64,
    /// Per actuator, `ctrl` at actuation 0 and 1.
    ctrl: [[f64; 2]; MAX_ACTUATORS],
    /// The tool's length beyond the configured one (m), along the tip's z.
    tool_m: f64,
}

/// A MuJoCo model of the arm, its map onto the arm, and its clock.
pub struct MujocoArm {
    data: MjData<Arc<MjModel>>,
    n: usize,
    /// Per actuator of the arm, the model's actuator.
    actuator: [usize; MAX_ACTUATORS],
    /// The phase at time 0, then each scenario step's.
    phases: [Option<Phase>; MAX_STEPS + 1],
    tip_site: usize,
    tip_body: usize,
    marker_m: [f64; 3],
    /// World → base: rotation (row-major) and translation.
    rotation: [[f64; 3]; 3],
    translation: [f64; 3],
    load: Option<TipLoad>,
    gravity: [f64; 3],
    timestep: f64,
    /// Steps taken since the clock started.
    steps: u64,
    settled: bool,
    description: String,
}

/// A model that cannot run the arm: what is wrong, under which key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refused(pub String);

impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Refused {}

fn refused<T>(message: impl Into<String>) -> Result<T, Refused> {
    Err(Refused(message.into()))
}

impl MujocoArm {
    /// The model `config` describes for the `configured` arm (the one a lab's map and a
    /// generated model are of), run as the arm `start` (a scenario's: its actuators' lengths
    /// and tool may differ), which becomes each of `steps` (plant time in s, the arm from then
    /// on) at its time; `base_dir` is where a relative `model` starts.
    pub fn new(
        config: &MujocoConfig,
        configured: &ArmConfig,
        start: &ArmConfig,
        steps: &[(f64, ArmConfig)],
        base_dir: &Path,
    ) -> Result<Self, Refused> {
        let layout = configured.layout().map_err(Refused)?;
        let (model, description) = match &config.model {
            Some(file) => {
                let path = base_dir.join(file);
                (
                    load_file(&path)?,
                    format!("MuJoCo model {}", path.display()),
                )
            }
            None => {
                let gravity = config.gravity_m_s2.unwrap_or([0.0, 0.0, -9.81]);
                let xml = generate::mjcf(&layout, &config.generated, gravity);
                let model = MjModel::from_xml_string(&xml).map_err(|e| {
                    Refused(format!(
                        "sim.mujoco: the model generated from [arm] does not load ({e}); \
                         please report this with your [arm]"
                    ))
                })?;
                (model, "MuJoCo model generated from [arm]".to_string())
            }
        };
        Self::of_model(model, description, config, &layout, start, steps)
    }

    fn of_model(
        mut model: MjModel,
        description: String,
        config: &MujocoConfig,
        layout: &Layout,
        start: &ArmConfig,
        steps: &[(f64, ArmConfig)],
    ) -> Result<Self, Refused> {
        let n = layout.actuators().len();
        if let Some(g) = config.gravity_m_s2 {
            model.opt_mut().gravity = g;
        }
        let gravity = model.opt().gravity;
        let timestep = model.opt().timestep;
        if !(timestep.is_finite() && timestep > 0.0) {
            return refused(format!(
                "{description}: its time step is {timestep}; it must be > 0"
            ));
        }
        let actuator = map_actuators(&model, config, n, &description)?;
        let tip_site = find(&model, MjtObjBase::mjOBJ_SITE, &config.tip_site).ok_or_else(|| {
            Refused(format!(
                "sim.mujoco.tip_site: {description} has no site {:?}; its sites: {}",
                config.tip_site,
                names(&model, MjtObjBase::mjOBJ_SITE, model.ffi().nsite as usize)
            ))
        })?;
        let tip_body = model.site_bodyid()[tip_site] as usize;
        let phases = phases(config, layout, start, steps)?;
        let keyframe = match &config.keyframe {
            Some(name) => Some(find(&model, MjtObjBase::mjOBJ_KEY, name).ok_or_else(|| {
                Refused(format!(
                    "sim.mujoco.keyframe: {description} has no keyframe {name:?}; its \
                     keyframes: {}",
                    names(&model, MjtObjBase::mjOBJ_KEY, model.ffi().nkey as usize)
                ))
            })?),
            None => (model.ffi().nkey > 0).then_some(0),
        };
        let mut data = MjData::new(Arc::new(model));
        if let Some(k) = keyframe {
            data.reset_keyframe(k)
                .map_err(|e| Refused(format!("{description}: keyframe {k}: {e}")))?;
        }
        data.forward();
        Ok(Self {
            data,
            n,
            actuator,
            phases,
            tip_site,
            tip_body,
            marker_m: config.marker_m,
            rotation: rotation_of(config.base_rotation_deg),
            translation: config.base_position_m,
            load: config.load,
            gravity,
            timestep,
            steps: 0,
            settled: false,
            description,
        })
    }

    /// The phase in force at `t`.
    fn phase(&self, t: f64) -> &Phase {
        let mut now = self.phases[0].as_ref().expect("the start's phase");
        for p in self.phases[1..].iter().map_while(Option::as_ref) {
            if p.from_s <= t {
                now = p;
            }
        }
        now
    }

    fn set_ctrl(&mut self, t: f64, actuation: &[f64], offset_m: &[f64]) {
        let phase = *self.phase(t);
        let ctrl = self.data.ctrl_mut();
        for i in 0..self.n {
            let [c0, c1] = phase.ctrl[i];
            ctrl[self.actuator[i]] = c0 + actuation[i] * (c1 - c0) + offset_m[i];
        }
    }

    fn set_load(&mut self, t: f64) {
        let Some(load) = self.load else { return };
        let on = t >= load.from_s;
        let site = self.data.site_xpos()[self.tip_site];
        let com = self.data.xipos()[self.tip_body];
        let mut f = [0.0; 3];
        if on {
            for k in 0..3 {
                f[k] = load.force_n[k] + load.mass_kg * self.gravity[k];
            }
        }
        // Applied at the site, not the body's centre of mass: the moment of the offset too.
        let r = [site[0] - com[0], site[1] - com[1], site[2] - com[2]];
        let torque = [
            r[1] * f[2] - r[2] * f[1],
            r[2] * f[0] - r[0] * f[2],
            r[0] * f[1] - r[1] * f[0],
        ];
        let applied = &mut self.data.xfrc_applied_mut()[self.tip_body];
        applied[..3].copy_from_slice(&f);
        applied[3..].copy_from_slice(&torque);
    }

    /// Where the tracked point is now, in the base frame.
    fn tracked(&self, t: f64) -> [f64; 3] {
        let p = self.data.site_xpos()[self.tip_site];
        let m = self.data.site_xmat()[self.tip_site];
        let tool = self.phase(t).tool_m;
        let local = [self.marker_m[0], self.marker_m[1], self.marker_m[2] + tool];
        let mut world = p;
        for r in 0..3 {
            for c in 0..3 {
                world[r] += m[3 * r + c] * local[c];
            }
        }
        let mut base = self.translation;
        for r in 0..3 {
            for c in 0..3 {
                base[r] += self.rotation[r][c] * world[c];
            }
        }
        base
    }

    /// The model's own time (s since its clock started).
    pub fn time(&self) -> f64 {
        self.steps as f64 * self.timestep
    }

    /// Its time step (s).
    pub fn timestep(&self) -> f64 {
        self.timestep
    }
}

impl Physics for MujocoArm {
    fn actuators(&self) -> usize {
        self.n
    }

    fn advance(&mut self, t: f64, actuation: &[f64], offset_m: &[f64]) -> [f64; 3] {
        if !self.settled {
            self.set_ctrl(0.0, actuation, offset_m);
            for _ in 0..(SETTLE_S / self.timestep).ceil() as u64 {
                self.data.step();
            }
            self.settled = true;
        }
        self.set_ctrl(t, actuation, offset_m);
        // Whole steps up to t: the model lags the clock by less than one step.
        while (self.steps + 1) as f64 * self.timestep <= t + 1e-9 {
            self.set_load(self.time());
            self.data.step();
            self.steps += 1;
        }
        let tracked = self.tracked(t);
        if tracked.iter().all(|x| x.is_finite()) {
            tracked
        } else {
            [f64::NAN; 3]
        }
    }

    fn describe(&self) -> String {
        self.description.clone()
    }
}

fn load_file(path: &Path) -> Result<MjModel, Refused> {
    if let Err(e) = std::fs::metadata(path) {
        return refused(format!(
            "sim.mujoco.model: cannot read {}: {e}",
            path.display()
        ));
    }
    MjModel::from_xml(path).map_err(|e| {
        Refused(format!(
            "sim.mujoco.model: {}: MuJoCo does not load it: {e}",
            path.display()
        ))
    })
}

fn find(model: &MjModel, kind: MjtObjBase, name: &str) -> Option<usize> {
    model.name_to_id(kind, name)
}

fn names(model: &MjModel, kind: MjtObjBase, count: usize) -> String {
    let all: Vec<&str> = (0..count)
        .filter_map(|i| model.id_to_name(kind, i))
        .collect();
    if all.is_empty() {
        "none named".into()
    } else {
        all.join(", ")
    }
}

/// Per actuator of the arm, the model's actuator: as mapped, or the model's own in order.
fn map_actuators(
    model: &MjModel,
    config: &MujocoConfig,
    n: usize,
    description: &str,
) -> Result<[usize; MAX_ACTUATORS], Refused> {
    let nu = model.ffi().nu as usize;
    let mut ids = [0; MAX_ACTUATORS];
    if config.actuators.is_empty() {
        if nu != n {
            return refused(format!(
                "sim.mujoco.actuators: {description} has {nu} actuators ({}); the arm has {n}: \
                 map each of the arm's onto one of them with [[sim.mujoco.actuators]]",
                names(model, MjtObjBase::mjOBJ_ACTUATOR, nu)
            ));
        }
        for (i, id) in ids[..n].iter_mut().enumerate() {
            *id = i;
        }
        return Ok(ids);
    }
    for (i, a) in config.actuators.iter().enumerate() {
        ids[i] = find(model, MjtObjBase::mjOBJ_ACTUATOR, &a.name).ok_or_else(|| {
            Refused(format!(
                "sim.mujoco.actuators[{i}].name: {description} has no actuator {:?}; its \
                 actuators: {}",
                a.name,
                names(model, MjtObjBase::mjOBJ_ACTUATOR, nu)
            ))
        })?;
        if let Some(j) = config.actuators[..i].iter().position(|b| b.name == a.name) {
            return refused(format!(
                "sim.mujoco.actuators[{i}].name: {:?} is mapped already, as actuator {}",
                a.name,
                j + 1
            ));
        }
    }
    Ok(ids)
}

/// What an actuation sets from the start and from each step, and the tool's change, as the
/// arm `start` and each of `steps` differ from the configured arm `base`.
fn phases(
    config: &MujocoConfig,
    base: &Layout,
    start: &ArmConfig,
    steps: &[(f64, ArmConfig)],
) -> Result<[Option<Phase>; MAX_STEPS + 1], Refused> {
    if steps.len() > MAX_STEPS {
        return refused(format!(
            "a scenario of {} steps; at most {MAX_STEPS}",
            steps.len()
        ));
    }
    let mut all = [None; MAX_STEPS + 1];
    let arms = std::iter::once((0.0, start)).chain(steps.iter().map(|(t, a)| (*t, a)));
    for (k, (at_s, arm)) in arms.enumerate() {
        let key = if k == 0 {
            "arm".to_string()
        } else {
            format!("step[{}]", k - 1)
        };
        let now = arm.layout().map_err(|e| Refused(format!("{key}: {e}")))?;
        if let Some(what) = beyond_lengths(base, &now) {
            return refused(format!(
                "{key}: changes the arm's {what}; on a MuJoCo plant a scenario changes the \
                 actuators' lengths and the tool's (offsets, tool_m) and nothing else"
            ));
        }
        all[k] = Some(phase(config, base, &now, at_s));
    }
    Ok(all)
}

fn phase(config: &MujocoConfig, base: &Layout, now: &Layout, from_s: f64) -> Phase {
    let mut ctrl = [[0.0; 2]; MAX_ACTUATORS];
    for (i, (b, a)) in base.actuators().iter().zip(now.actuators()).enumerate() {
        let given = config.actuators.get(i).and_then(|m| m.ctrl);
        // A step's change of the arm's lengths moves what the actuation sets by as much.
        let change = [a.min_m - b.min_m, a.max_m - b.max_m];
        let [c0, c1] = given.unwrap_or([b.min_m, b.max_m]);
        ctrl[i] = [c0 + change[0], c1 + change[1]];
    }
    Phase {
        from_s,
        ctrl,
        tool_m: now.tool_m - base.tool_m,
    }
}

/// What of the arm `now` changes beyond its actuators' lengths and its tool, if anything.
fn beyond_lengths(base: &Layout, now: &Layout) -> Option<&'static str> {
    if base.modules() != now.modules() || base.mount != now.mount {
        return Some("modules");
    }
    if base.connector_m != now.connector_m {
        return Some("connector_m");
    }
    let same = |a: &softarm_arm::Actuator, b: &softarm_arm::Actuator| {
        a.kind == b.kind
            && a.module == b.module
            && a.radius_m == b.radius_m
            && a.angle_rad == b.angle_rad
    };
    if !base
        .actuators()
        .iter()
        .zip(now.actuators())
        .all(|(a, b)| same(a, b))
    {
        return Some("routing (radius or angle)");
    }
    None
}

/// The rotation of extrinsic x, y, z angles (degrees), row-major.
fn rotation_of(deg: [f64; 3]) -> [[f64; 3]; 3] {
    let [x, y, z] = deg.map(f64::to_radians);
    let rx = [
        [1.0, 0.0, 0.0],
        [0.0, x.cos(), -x.sin()],
        [0.0, x.sin(), x.cos()],
    ];
    let ry = [
        [y.cos(), 0.0, y.sin()],
        [0.0, 1.0, 0.0],
        [-y.sin(), 0.0, y.cos()],
    ];
    let rz = [
        [z.cos(), -z.sin(), 0.0],
        [z.sin(), z.cos(), 0.0],
        [0.0, 0.0, 1.0],
    ];
    mul(rz, mul(ry, rx))
}

fn mul(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|r| std::array::from_fn(|c| (0..3).map(|k| a[r][k] * b[k][c]).sum()))
}
