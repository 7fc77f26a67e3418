//! The stack in 3-D, in Foxglove's well-known schema `foxglove.SceneUpdate` (protobuf, the
//! `foxglove` crate's types): what `softarm view` serves live on the channel `scene` and
//! `softarm record` writes beside the services, so a recording opens with the arm drawn. Built
//! from the samples alone; no I/O.
//!
//! Every entity is in the frame `base` (the tracker's and the way-points' frame, metres):
//!
//! - `base`: the frame's axes (x red, y green, z blue, 50 mm) and the mount plate.
//! - `arm`: the backbone the configured arm model (`[arm]`, `pcc::Arm::backbone`) gives for
//!   the newest measured actuation (`motor_state`): a line strip per module and one per
//!   connector after it (the tool after the last), so the last point of the last line is the
//!   modelled end effector. Metadata
//!   `motor_state.seq` and `motor_state.stamp_ns` name the sample it was drawn from.
//! - `tracker`: the newest tracker position (a red sphere) and its path over `view.trail_s`.
//! - `waypoints`: the running set's way-points, numbered from 1 as `softarm stats` numbers its
//!   conditioning points (from `estimate_request`, or from `cp_sample` for a view started
//!   after the set).
//! - `reached`: where the tracker was at each conditioning point, per execution (the newest
//!   [`EXECUTIONS_DRAWN`], older ones paler), and a line from each way-point to the newest
//!   execution's reached point: the error `softarm stats` reports.
//!
//! `arm` and `tracker` are in every update; `base`, `waypoints` and `reached` when they change
//! and once a second (a viewer that joins late, or seeks in a recording, has them within 1 s).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use foxglove::messages::{
    ArrowPrimitive, Color, CylinderPrimitive, KeyValuePair, LinePrimitive, Point3, Pose,
    Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, TextPrimitive, Timestamp, Vector3,
    line_primitive,
};
use softarm_config::Config;
use softarm_ipc::{ConditioningSample, MAX_WAYPOINTS, MotorState, Position, TrackerSample};

use crate::Payload;
use softarm_kinematics::pcc::Arm;

/// The scene's channel.
pub const TOPIC: &str = "scene";
/// The frame of every entity.
pub const FRAME: &str = "base";
/// Executions whose reached points are drawn, the newest.
pub const EXECUTIONS_DRAWN: usize = 5;
/// Points along each module's arc.
const ARC_POINTS: usize = 16;
/// Tracker samples kept at most (whatever `trail_s` and the rate), and drawn at most.
const TRAIL_KEPT: usize = 8192;
const TRAIL_DRAWN: usize = 300;
/// How often the entities that rarely change are sent again.
const REFRESH: Duration = Duration::from_secs(1);

/// What the scene draws with: the arm model, its rate and the trail's length.
#[derive(Debug, Clone, Copy)]
pub struct Settings {
    pub arm: Arm,
    pub rate_hz: f64,
    pub trail_s: f64,
}

impl Settings {
    /// The config's `[arm]` and `[view]`.
    pub fn of(c: &Config) -> Self {
        Self {
            arm: Arm::new(
                &c.layout(),
                c.arm.actuator_offset_m.as_deref().unwrap_or_default(),
            ),
            rate_hz: c.view.scene_hz,
            trail_s: c.view.trail_s,
        }
    }
}

/// A set's way-points as far as known.
struct SetPoints {
    set_id: u64,
    points: Vec<Option<Position>>,
}

/// One execution's reached points.
struct Reached {
    execution: u32,
    points: Vec<Option<Position>>,
}

/// The scene as the samples so far describe it.
pub struct Scene {
    settings: Settings,
    motor: Option<MotorState>,
    trail: VecDeque<TrackerSample>,
    set: Option<SetPoints>,
    reached: VecDeque<Reached>,
    /// Way-points or reached points changed since they were last sent.
    changed: bool,
    last_full: Option<Instant>,
    next: Option<Instant>,
}

fn finite(p: &[f64]) -> bool {
    p.iter().all(|v| v.is_finite())
}

impl Scene {
    pub fn new(settings: Settings) -> Self {
        Self {
            settings,
            motor: None,
            trail: VecDeque::new(),
            set: None,
            reached: VecDeque::new(),
            changed: true,
            last_full: None,
            next: None,
        }
    }

    /// Takes in a sample of any service.
    pub fn take(&mut self, p: &Payload) {
        match p {
            Payload::MotorState(m) if finite(&m.actuation) => self.motor = Some(*m),
            Payload::Tracker(t) if finite(&t.position) => self.track(t),
            Payload::EstimateRequest(r) => {
                let points = r.points().iter().map(|p| Some(*p)).collect();
                self.new_set(r.set_id, points);
            }
            Payload::CpSample(s) => self.conditioning_sample(s),
            _ => {}
        }
    }

    fn track(&mut self, t: &TrackerSample) {
        self.trail.push_back(*t);
        let span = (self.settings.trail_s * 1e9) as u64;
        while self
            .trail
            .front()
            .is_some_and(|f| t.stamp_ns.saturating_sub(f.stamp_ns) > span)
            || self.trail.len() > TRAIL_KEPT
        {
            self.trail.pop_front();
        }
    }

    fn new_set(&mut self, set_id: u64, points: Vec<Option<Position>>) {
        self.set = Some(SetPoints { set_id, points });
        self.reached.clear();
        self.changed = true;
    }

    fn conditioning_sample(&mut self, s: &ConditioningSample) {
        let (n, i) = (s.points as usize, s.point as usize);
        if n == 0 || n > MAX_WAYPOINTS || i >= n || s.execution == 0 {
            return;
        }
        if self
            .set
            .as_ref()
            .is_none_or(|set| set.set_id != s.set_id || set.points.len() != n)
        {
            self.new_set(s.set_id, vec![None; n]);
        }
        let set = self.set.as_mut().expect("just made");
        if set.points[i].is_none() && finite(&s.desired) {
            set.points[i] = Some(s.desired);
        }
        if !finite(&s.reached) {
            return;
        }
        if self
            .reached
            .back()
            .is_none_or(|r| r.execution != s.execution)
        {
            self.reached.push_back(Reached {
                execution: s.execution,
                points: vec![None; n],
            });
            while self.reached.len() > EXECUTIONS_DRAWN {
                self.reached.pop_front();
            }
        }
        let r = self.reached.back_mut().expect("just made");
        r.points[i] = Some(s.reached);
        self.changed = true;
    }

    /// Whether an update is due at `now` (`view.scene_hz`); if so, the next is one period on.
    pub fn due(&mut self, now: Instant) -> bool {
        let period = Duration::from_secs_f64(1.0 / self.settings.rate_hz);
        match self.next {
            Some(next) if now < next => false,
            Some(next) => {
                // Absolute deadlines; a late caller skips what it missed.
                let mut n = next + period;
                if n <= now {
                    n = now + period;
                }
                self.next = Some(n);
                true
            }
            None => {
                self.next = Some(now + period);
                true
            }
        }
    }

    /// The update for `now`, stamped `realtime_ns` (ns since the epoch).
    pub fn update(&mut self, now: Instant, realtime_ns: u64) -> SceneUpdate {
        let stamp = timestamp(realtime_ns);
        let mut entities = Vec::new();
        // Drawn from a reading of this arm's actuators (the stack's services carry no other).
        if let Some(m) = &self.motor
            && m.actuation.len() == self.settings.arm.actuators()
            && let Some(e) = self.arm(m, stamp)
        {
            entities.push(e);
        }
        if let Some(t) = self.tracker(stamp) {
            entities.push(t);
        }
        let full = self.changed || self.last_full.is_none_or(|t| now >= t + REFRESH);
        if full {
            entities.push(base(stamp));
            if let Some(set) = &self.set {
                entities.push(waypoints(set, stamp));
                entities.push(reached(set, &self.reached, stamp));
            }
            self.changed = false;
            self.last_full = Some(now);
        }
        SceneUpdate {
            deletions: Vec::new(),
            entities,
        }
    }

    /// The arm's entity; `None` for an actuation whose arcs the model cannot tell.
    fn arm(&self, m: &MotorState, stamp: Timestamp) -> Option<SceneEntity> {
        let lines = self
            .settings
            .arm
            .backbone(m.actuation.as_slice(), ARC_POINTS)
            .ok()?;
        // Modules alternate two colours; connectors grey, the tool orange.
        let modules = [rgba(0.20, 0.45, 0.85, 1.0), rgba(0.15, 0.70, 0.65, 1.0)];
        let last = lines.len() - 1;
        let style = |k: usize| match k {
            k if k % 2 == 0 => (0.018, modules[(k / 2) % 2]),
            k if k == last => (0.006, rgba(0.95, 0.60, 0.10, 1.0)),
            _ => (0.008, rgba(0.55, 0.55, 0.55, 1.0)),
        };
        let mut e = entity("arm", stamp);
        e.lines = lines
            .iter()
            .enumerate()
            .map(|(k, points)| {
                let (thickness, color) = style(k);
                line(points, thickness, color)
            })
            .collect();
        let tip = *lines[last].last().expect("a tool line has two points");
        e.spheres = vec![sphere(tip, 0.008, rgba(0.95, 0.60, 0.10, 1.0))];
        e.metadata = vec![
            pair("motor_state.seq", m.seq.to_string()),
            pair("motor_state.stamp_ns", m.stamp_ns.to_string()),
        ];
        Some(e)
    }

    fn tracker(&self, stamp: Timestamp) -> Option<SceneEntity> {
        let newest = self.trail.back()?;
        let mut e = entity("tracker", stamp);
        e.spheres = vec![sphere(newest.position, 0.010, rgba(0.90, 0.15, 0.15, 0.9))];
        let stride = self.trail.len().div_ceil(TRAIL_DRAWN).max(1);
        let mut path: Vec<[f64; 3]> = self
            .trail
            .iter()
            .rev()
            .step_by(stride)
            .map(|t| t.position)
            .collect();
        path.reverse();
        if path.len() >= 2 {
            e.lines = vec![line(&path, 0.002, rgba(0.90, 0.15, 0.15, 0.6))];
        }
        e.metadata = vec![
            pair("tracker.seq", newest.seq.to_string()),
            pair("tracker.stamp_ns", newest.stamp_ns.to_string()),
        ];
        Some(e)
    }
}

/// The base frame's axes and the mount plate.
fn base(stamp: Timestamp) -> SceneEntity {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let axes = [
        (
            Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            },
            rgba(0.9, 0.1, 0.1, 1.0),
            "x",
        ),
        (
            Quaternion {
                x: 0.0,
                y: 0.0,
                z: h,
                w: h,
            },
            rgba(0.1, 0.8, 0.1, 1.0),
            "y",
        ),
        (
            Quaternion {
                x: 0.0,
                y: -h,
                z: 0.0,
                w: h,
            },
            rgba(0.1, 0.3, 0.9, 1.0),
            "z",
        ),
    ];
    let mut e = entity("base", stamp);
    e.arrows = axes
        .iter()
        .map(|(q, color, _)| ArrowPrimitive {
            pose: Some(Pose {
                position: Some(Vector3 {
                    x: 0.0,
                    y: 0.0,
                    z: 0.0,
                }),
                orientation: Some(*q),
            }),
            shaft_length: 0.04,
            shaft_diameter: 0.003,
            head_length: 0.01,
            head_diameter: 0.008,
            color: Some(*color),
        })
        .collect();
    let tip = |q: &str| match q {
        "x" => [0.058, 0.0, 0.0],
        "y" => [0.0, 0.058, 0.0],
        _ => [0.0, 0.0, 0.058],
    };
    e.texts = axes
        .iter()
        .map(|(_, color, name)| text(tip(name), name, 12.0, *color))
        .collect();
    e.cylinders = vec![CylinderPrimitive {
        pose: Some(pose_at([0.0, 0.0, 0.004])),
        size: Some(Vector3 {
            x: 0.12,
            y: 0.12,
            z: 0.008,
        }),
        bottom_scale: 1.0,
        top_scale: 1.0,
        color: Some(rgba(0.6, 0.6, 0.6, 0.5)),
    }];
    e
}

/// The set's way-points, numbered from 1, joined in order.
fn waypoints(set: &SetPoints, stamp: Timestamp) -> SceneEntity {
    let yellow = rgba(0.95, 0.80, 0.10, 0.8);
    let mut e = entity("waypoints", stamp);
    let known: Vec<(usize, Position)> = set
        .points
        .iter()
        .enumerate()
        .filter_map(|(i, p)| p.map(|p| (i, p)))
        .collect();
    e.spheres = known
        .iter()
        .map(|(_, p)| sphere(*p, 0.012, yellow))
        .collect();
    e.texts = known
        .iter()
        .map(|(i, p)| {
            let at = [p[0] + 0.012, p[1], p[2] + 0.012];
            text(at, &(i + 1).to_string(), 14.0, rgba(1.0, 1.0, 1.0, 1.0))
        })
        .collect();
    let path: Vec<Position> = known.iter().map(|(_, p)| *p).collect();
    if path.len() >= 2 {
        e.lines = vec![line(&path, 0.001, rgba(0.95, 0.80, 0.10, 0.4))];
    }
    e.metadata = vec![pair("set_id", set.set_id.to_string())];
    e
}

/// Each drawn execution's reached points (older paler), and the newest one's errors.
fn reached(set: &SetPoints, executions: &VecDeque<Reached>, stamp: Timestamp) -> SceneEntity {
    let mut e = entity("reached", stamp);
    let n = executions.len();
    for (k, r) in executions.iter().enumerate() {
        let alpha = 0.25 + 0.75 * (k + 1) as f64 / n as f64;
        let color = rgba(0.20, 0.85, 0.30, alpha);
        e.spheres
            .extend(r.points.iter().flatten().map(|p| sphere(*p, 0.006, color)));
    }
    if let Some(newest) = executions.back() {
        let mut pairs = Vec::new();
        for (want, got) in set.points.iter().zip(&newest.points) {
            if let (Some(w), Some(g)) = (want, got) {
                pairs.extend([p3(*w), p3(*g)]);
            }
        }
        if !pairs.is_empty() {
            let mut l = line(&[], 0.0015, rgba(0.20, 0.85, 0.30, 0.9));
            l.r#type = line_primitive::Type::LineList as i32;
            l.points = pairs;
            e.lines = vec![l];
        }
        e.metadata = vec![pair("execution", newest.execution.to_string())];
    }
    e
}

fn timestamp(realtime_ns: u64) -> Timestamp {
    Timestamp::new(
        (realtime_ns / 1_000_000_000).min(u64::from(u32::MAX)) as u32,
        (realtime_ns % 1_000_000_000) as u32,
    )
}

fn entity(id: &str, stamp: Timestamp) -> SceneEntity {
    SceneEntity {
        timestamp: Some(stamp),
        frame_id: FRAME.into(),
        id: id.into(),
        ..Default::default()
    }
}

fn rgba(r: f64, g: f64, b: f64, a: f64) -> Color {
    Color { r, g, b, a }
}

fn p3(p: [f64; 3]) -> Point3 {
    Point3 {
        x: p[0],
        y: p[1],
        z: p[2],
    }
}

fn pose_at(p: [f64; 3]) -> Pose {
    Pose {
        position: Some(Vector3 {
            x: p[0],
            y: p[1],
            z: p[2],
        }),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    }
}

fn sphere(p: [f64; 3], diameter: f64, color: Color) -> SpherePrimitive {
    SpherePrimitive {
        pose: Some(pose_at(p)),
        size: Some(Vector3 {
            x: diameter,
            y: diameter,
            z: diameter,
        }),
        color: Some(color),
    }
}

fn line(points: &[[f64; 3]], thickness: f64, color: Color) -> LinePrimitive {
    LinePrimitive {
        r#type: line_primitive::Type::LineStrip as i32,
        pose: Some(pose_at([0.0; 3])),
        thickness,
        scale_invariant: false,
        points: points.iter().map(|p| p3(*p)).collect(),
        color: Some(color),
        colors: Vec::new(),
        indices: Vec::new(),
    }
}

fn text(at: [f64; 3], s: &str, pixels: f64, color: Color) -> TextPrimitive {
    TextPrimitive {
        pose: Some(pose_at(at)),
        billboard: true,
        font_size: pixels,
        scale_invariant: true,
        color: Some(color),
        text: s.into(),
    }
}

fn pair(key: &str, value: String) -> KeyValuePair {
    KeyValuePair {
        key: key.into(),
        value,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use softarm_ipc::EstimateRequest;
    use softarm_kinematics::forward::ForwardModel;

    fn scene() -> Scene {
        Scene::new(Settings {
            arm: Arm::of_config(&softarm_config::arm::ArmConfig::default()).unwrap(),
            rate_hz: 30.0,
            trail_s: 1.0,
        })
    }

    fn ids(u: &SceneUpdate) -> Vec<&str> {
        u.entities.iter().map(|e| e.id.as_str()).collect()
    }

    fn sample(set_id: u64, execution: u32, point: u32, points: u32) -> Payload {
        let at = [0.01 * f64::from(point), 0.0, -0.45];
        Payload::CpSample(ConditioningSample {
            set_id,
            execution,
            point,
            points,
            desired: at,
            reached: [at[0], 0.002, -0.45],
            ..Default::default()
        })
    }

    #[test]
    fn the_arm_ends_where_the_model_puts_the_end_effector() {
        let mut s = scene();
        let t = Instant::now();
        assert!(s.update(t, 0).entities.iter().all(|e| e.id != "arm"));
        let a = [0.2, 0.8, 0.5, 0.9, 0.1, 0.4];
        s.take(&Payload::MotorState(MotorState {
            seq: 42,
            actuation: a.into(),
            ..Default::default()
        }));
        let u = s.update(t, 1_700_000_000_123_456_789);
        let arm = u.entities.iter().find(|e| e.id == "arm").unwrap();
        assert_eq!(arm.frame_id, FRAME);
        assert_eq!(
            arm.timestamp,
            Some(Timestamp::new(1_700_000_000, 123_456_789))
        );
        assert_eq!(arm.lines.len(), 4);
        let tip = arm.lines[3].points.last().unwrap();
        let want = ForwardModel::<6>::position(&scene().settings.arm, &a);
        assert!(
            (tip.x - want[0]).abs() + (tip.y - want[1]).abs() + (tip.z - want[2]).abs() < 1e-12
        );
        assert!(arm.metadata.contains(&pair("motor_state.seq", "42".into())));
        // A motor state that is not numbers draws nothing new.
        s.take(&Payload::MotorState(MotorState {
            seq: 43,
            actuation: [f64::NAN; 6].into(),
            ..Default::default()
        }));
        let u = s.update(t, 0);
        let arm = u.entities.iter().find(|e| e.id == "arm").unwrap();
        assert!(arm.metadata.contains(&pair("motor_state.seq", "42".into())));
    }

    #[test]
    fn way_points_and_reached_points_of_the_newest_executions() {
        let mut s = scene();
        let mut desired = [[0.0; 3]; MAX_WAYPOINTS];
        desired[..3].copy_from_slice(&[[0.1, 0.0, -0.4], [0.0, 0.1, -0.4], [0.0, 0.0, -0.5]]);
        s.take(&Payload::EstimateRequest(EstimateRequest {
            set_id: 7,
            count: 3,
            desired,
            ..Default::default()
        }));
        for execution in 1..=8 {
            for point in 0..3 {
                s.take(&sample(7, execution, point, 3));
            }
        }
        let u = s.update(Instant::now(), 0);
        assert_eq!(ids(&u), ["base", "waypoints", "reached"]);
        let w = &u.entities[1];
        let numbers: Vec<&str> = w.texts.iter().map(|t| t.text.as_str()).collect();
        assert_eq!(numbers, ["1", "2", "3"]);
        // From the request, not the samples' made-up positions.
        assert_eq!(w.spheres[0].pose.unwrap().position.unwrap().x, 0.1);
        let r = &u.entities[2];
        assert_eq!(r.spheres.len(), 3 * EXECUTIONS_DRAWN);
        assert!(r.metadata.contains(&pair("execution", "8".into())));
        // One error line per point, from the way-point to where the arm was.
        assert_eq!(r.lines[0].points.len(), 6);
        // A garbled sample changes nothing.
        s.take(&sample(7, 9, 5, 3));
        s.take(&sample(7, 0, 0, 3));
        s.take(&sample(7, 9, 0, 99));
        assert_eq!(ids(&s.update(Instant::now(), 0)), Vec::<&str>::new());
    }

    #[test]
    fn a_scene_started_during_a_set_learns_its_way_points_from_the_samples() {
        let mut s = scene();
        s.take(&sample(3, 2, 1, 4));
        let u = s.update(Instant::now(), 0);
        let w = u.entities.iter().find(|e| e.id == "waypoints").unwrap();
        assert_eq!(w.texts.len(), 1);
        assert_eq!(w.texts[0].text, "2");
        // Another set replaces it, and its reached points.
        s.take(&sample(4, 1, 0, 2));
        let u = s.update(Instant::now(), 0);
        let r = u.entities.iter().find(|e| e.id == "reached").unwrap();
        assert_eq!(r.spheres.len(), 1);
    }

    #[test]
    fn the_trail_is_bounded_in_time_and_in_count() {
        let mut s = scene();
        for i in 0..20_000u64 {
            s.take(&Payload::Tracker(TrackerSample {
                seq: i,
                // 10 kHz: a second is 10 000 samples, more than are kept.
                stamp_ns: i * 100_000,
                position: [0.0, 0.0, -0.5 + i as f64 * 1e-6],
            }));
        }
        assert_eq!(s.trail.len(), TRAIL_KEPT);
        let u = s.update(Instant::now(), 0);
        let t = u.entities.iter().find(|e| e.id == "tracker").unwrap();
        assert!(t.lines[0].points.len() <= TRAIL_DRAWN + 1);
        assert!(t.metadata.contains(&pair("tracker.seq", "19999".into())));
        // At 100 Hz, one second of it.
        for i in 0..500u64 {
            s.take(&Payload::Tracker(TrackerSample {
                seq: i,
                stamp_ns: 10_000_000_000 + i * 10_000_000,
                position: [0.0; 3],
            }));
        }
        assert_eq!(s.trail.len(), 101);
    }

    #[test]
    fn what_rarely_changes_goes_out_when_it_does_and_once_a_second() {
        let mut s = scene();
        let t0 = Instant::now();
        assert!(s.due(t0));
        assert!(!s.due(t0 + Duration::from_millis(20)));
        assert!(s.due(t0 + Duration::from_millis(34)));
        // A caller late by seconds gets one update, not a burst.
        assert!(s.due(t0 + Duration::from_secs(5)));
        assert!(!s.due(t0 + Duration::from_secs(5) + Duration::from_millis(1)));
        assert_eq!(ids(&s.update(t0, 0)), ["base"]);
        assert!(
            s.update(t0 + Duration::from_millis(500), 0)
                .entities
                .is_empty()
        );
        assert_eq!(ids(&s.update(t0 + Duration::from_secs(1), 0)), ["base"]);
        s.take(&sample(1, 1, 0, 1));
        assert_eq!(
            ids(&s.update(t0 + Duration::from_millis(1100), 0)),
            ["base", "waypoints", "reached"]
        );
    }
}
