//! Every pub/sub service of a stack as a channel of a log, in one place for the two that log
//! them: `softarm record` (an MCAP file) and `softarm view` (the Foxglove WebSocket protocol).
//!
//! A channel's topic is the service's name (`setpoint`, `tracker`, ...); its messages are JSON
//! (`message_encoding = "json"`), one object per sample with the payload's field names
//! (`contract/ipc/src/lib.rs`), NaN as `null`; its schema is a JSON Schema (`encoding = "jsonschema"`)
//! named after the payload's iceoryx2 type name (`softarm::Setpoint`, ...), made from the
//! payload's type (its default value), so it is known before the first sample.
//!
//! The subscribers are one more reader of each service: they never publish, so the controller
//! does not notice them; a reader that falls behind loses its own oldest samples (iceoryx2's
//! safe overflow), never anyone else's.
//!
//! Beside them the stack in 3-D ([`scene`]), which both draw from the same samples.

pub mod scene;

use std::collections::BTreeMap;

use anyhow::Context;
use serde::Serialize;
use serde_json::{Value, json};
use softarm_ipc::iceoryx2::prelude::ZeroCopySend;
use softarm_ipc::{
    ActuationEstimate, ConditioningSample, ControllerStatus, EstimateRequest, EstopState,
    ExecutionStats, MAX_ACTUATORS, MotorState, Node, Setpoint, Sub, TrackerSample,
};

/// The topics, in the order they are opened.
pub const TOPICS: [&str; 9] = [
    "setpoint",
    "tracker",
    "motor_state",
    "cp_sample",
    "estimate_request",
    "estimate",
    "stats",
    "status",
    "estop",
];

/// What a log needs to declare a channel.
#[derive(Debug, Clone)]
pub struct Spec {
    pub topic: &'static str,
    /// The payload's iceoryx2 type name.
    pub schema_name: &'static str,
    /// The JSON Schema, as text.
    pub schema: String,
}

/// A sample of any service, as it arrived.
#[derive(Debug, Clone, Copy)]
pub enum Payload {
    Setpoint(Setpoint),
    Tracker(TrackerSample),
    MotorState(MotorState),
    CpSample(ConditioningSample),
    EstimateRequest(EstimateRequest),
    Estimate(ActuationEstimate),
    Stats(ExecutionStats),
    Status(ControllerStatus),
    Estop(EstopState),
}

macro_rules! each_payload {
    ($p:expr, $v:ident => $e:expr) => {
        match $p {
            Payload::Setpoint($v) => $e,
            Payload::Tracker($v) => $e,
            Payload::MotorState($v) => $e,
            Payload::CpSample($v) => $e,
            Payload::EstimateRequest($v) => $e,
            Payload::Estimate($v) => $e,
            Payload::Stats($v) => $e,
            Payload::Status($v) => $e,
            Payload::Estop($v) => $e,
        }
    };
}

impl Payload {
    /// The sample's own stamp (CLOCK_MONOTONIC, ns).
    pub fn stamp_ns(&self) -> u64 {
        each_payload!(self, v => v.stamp_ns)
    }

    /// The message: the payload as JSON, NaN as `null`.
    pub fn json(&self) -> Vec<u8> {
        let mut value = each_payload!(self, v => serde_json::to_value(v))
            .expect("a payload of numbers and arrays is JSON");
        // A per-point array holds the set's points alone: the rest of its fixed capacity is no
        // point, and drawn as zeros it would look like a point reached exactly.
        // So does the motors' error array, which has the arm's actuators alone.
        let points = match self {
            Payload::Stats(s) => Some(("errors_m", s.errors().len())),
            Payload::EstimateRequest(r) => Some(("desired", r.points().len())),
            Payload::MotorState(m) => Some(("hardware_error", m.actuation.len())),
            _ => None,
        };
        if let Some((field, n)) = points
            && let Some(Value::Array(items)) = value.get_mut(field)
        {
            items.truncate(n);
        }
        value.to_string().into_bytes()
    }
}

/// The services whose messages carry an array of one element per way-point of the set, and
/// that array: a message has as many elements as the set has points ([`Payload::json`]), so
/// its schema allows fewer than the capacity.
const PER_POINT: [(&str, &str); 3] = [
    ("stats", "errors_m"),
    ("estimate_request", "desired"),
    ("motor_state", "hardware_error"),
];

fn per_point(topic: &str) -> Option<(&'static str, &'static str)> {
    PER_POINT.into_iter().find(|(t, _)| *t == topic)
}

/// A JSON Schema for values of `T`, from its default value: numbers that are not integers may
/// be `null` (a NaN on the wire); an empty array there is per-actuator values
/// (`softarm_ipc::Actuators`), as many as the arm has.
fn schema<T: Serialize + Default + ZeroCopySend>(topic: &str) -> (&'static str, String) {
    // SAFETY: only reads the name the payload declares (`#[type_name]`).
    let name = unsafe { <T as ZeroCopySend>::type_name() };
    let mut s = json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": name,
        "description": format!("softarm service `{topic}`: {name} (contract/ipc/src/lib.rs)"),
    });
    let mut shape = schema_of(&serde_json::to_value(T::default()).expect("a payload is JSON"));
    if let Some((_, field)) = per_point(topic) {
        shape["properties"][field]["minItems"] = json!(0);
    }
    if let (Value::Object(a), Value::Object(b)) = (&mut s, shape) {
        a.extend(b);
    }
    (name, s.to_string())
}

/// A JSON Schema for values shaped like `v`.
fn schema_of(v: &Value) -> Value {
    match v {
        Value::Number(n) if n.is_u64() || n.is_i64() => json!({"type": "integer"}),
        Value::Number(_) | Value::Null => json!({"type": ["number", "null"]}),
        Value::Bool(_) => json!({"type": "boolean"}),
        Value::String(_) => json!({"type": "string"}),
        Value::Array(items) if items.is_empty() => json!({
            "type": "array",
            "minItems": 1,
            "maxItems": MAX_ACTUATORS,
            "items": {"type": ["number", "null"]},
        }),
        Value::Array(items) => json!({
            "type": "array",
            "minItems": items.len(),
            "maxItems": items.len(),
            "items": items.first().map_or(json!({}), schema_of),
        }),
        Value::Object(fields) => json!({
            "type": "object",
            "properties": fields.iter().map(|(k, v)| (k.clone(), schema_of(v))).collect::<serde_json::Map<_, _>>(),
            "required": fields.keys().collect::<Vec<_>>(),
        }),
    }
}

/// One subscription, typed.
trait Receive {
    fn take(&mut self) -> anyhow::Result<Option<Payload>>;
}

struct Source<T: std::fmt::Debug + ZeroCopySend + 'static> {
    sub: Sub<T>,
    wrap: fn(T) -> Payload,
}

impl<T: std::fmt::Debug + ZeroCopySend + Copy + 'static> Receive for Source<T> {
    fn take(&mut self) -> anyhow::Result<Option<Payload>> {
        match self.sub.receive() {
            Ok(Some(sample)) => Ok(Some((self.wrap)(*sample))),
            Ok(None) => Ok(None),
            Err(e) => Err(anyhow::anyhow!("{e:?}")),
        }
    }
}

/// A subscriber of every pub/sub service of a namespace, with each channel's [`Spec`].
pub struct Services {
    specs: Vec<Spec>,
    sources: Vec<Box<dyn Receive>>,
    counts: Vec<u64>,
}

impl Services {
    /// Subscribes to every service of `node`'s namespace, in the order of [`TOPICS`].
    pub fn open(node: &Node) -> anyhow::Result<Self> {
        let mut s = Self {
            specs: Vec::new(),
            sources: Vec::new(),
            counts: Vec::new(),
        };
        s.add(node, "setpoint", node.setpoint(), Payload::Setpoint)?;
        s.add(node, "tracker", node.tracker(), Payload::Tracker)?;
        s.add(node, "motor_state", node.motor_state(), Payload::MotorState)?;
        s.add(node, "cp_sample", node.cp_sample(), Payload::CpSample)?;
        let req = node.estimate_request();
        s.add(node, "estimate_request", req, Payload::EstimateRequest)?;
        s.add(node, "estimate", node.estimate(), Payload::Estimate)?;
        s.add(node, "stats", node.stats(), Payload::Stats)?;
        s.add(node, "status", node.status(), Payload::Status)?;
        s.add(node, "estop", node.estop(), Payload::Estop)?;
        debug_assert!(s.specs.iter().map(|c| c.topic).eq(TOPICS));
        Ok(s)
    }

    fn add<T>(
        &mut self,
        node: &Node,
        topic: &'static str,
        service: Result<softarm_ipc::PubSub<T>, softarm_ipc::Error>,
        wrap: fn(T) -> Payload,
    ) -> anyhow::Result<()>
    where
        T: std::fmt::Debug + ZeroCopySend + Serialize + Default + Copy + 'static,
    {
        let service = service.with_context(|| format!("the {topic} service"))?;
        let sub = node
            .subscriber(&service)
            .with_context(|| format!("subscribing to {topic}"))?;
        let (schema_name, schema) = schema::<T>(topic);
        self.specs.push(Spec {
            topic,
            schema_name,
            schema,
        });
        self.sources.push(Box::new(Source { sub, wrap }));
        self.counts.push(0);
        Ok(())
    }

    /// The channels, in the order of [`TOPICS`]; a sample's channel is its index here.
    pub fn specs(&self) -> &[Spec] {
        &self.specs
    }

    /// Hands every sample waiting to `f` (its channel's index and the payload), channel by
    /// channel; returns how many there were.
    pub fn drain(
        &mut self,
        mut f: impl FnMut(usize, &Payload) -> anyhow::Result<()>,
    ) -> anyhow::Result<u64> {
        let mut n = 0;
        for (i, source) in self.sources.iter_mut().enumerate() {
            while let Some(p) = source
                .take()
                .with_context(|| format!("receiving {}", self.specs[i].topic))?
            {
                f(i, &p)?;
                self.counts[i] += 1;
                n += 1;
            }
        }
        Ok(n)
    }

    /// Samples received per topic so far.
    pub fn counts(&self) -> BTreeMap<String, u64> {
        self.specs
            .iter()
            .zip(&self.counts)
            .map(|(s, n)| (s.topic.to_string(), *n))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use softarm_ipc::MAX_WAYPOINTS;

    #[test]
    fn a_schema_is_known_before_any_sample_and_matches_the_messages() {
        let (name, text) = schema::<MotorState>("motor_state");
        assert_eq!(name, "softarm::MotorState.v5");
        let s: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(s["title"], name);
        assert_eq!(s["properties"]["seq"]["type"], "integer");
        assert_eq!(s["properties"]["actuation"]["maxItems"], MAX_ACTUATORS);
        assert_eq!(
            s["properties"]["current_a"]["items"]["type"],
            json!(["number", "null"])
        );
        // A message has every field the schema requires, NaN as null, and the arm's
        // actuators alone in every per-actuator array.
        let m = MotorState {
            actuation: [0.5; 9].into(),
            current_a: [f64::NAN; 9].into(),
            stamp_ns: 7,
            ..Default::default()
        };
        let p = Payload::MotorState(m);
        assert_eq!(p.stamp_ns(), 7);
        let v: Value = serde_json::from_slice(&p.json()).unwrap();
        for k in s["required"].as_array().unwrap() {
            assert!(v.get(k.as_str().unwrap()).is_some(), "{k}");
        }
        assert_eq!(v["current_a"][0], Value::Null);
        for field in ["actuation", "current_a", "hardware_error"] {
            assert_eq!(v[field].as_array().unwrap().len(), 9, "{field}");
        }
    }

    /// A five-point set's stats carry five errors, not five and eleven zeros a plot would
    /// draw as points reached exactly; the schema allows it.
    #[test]
    fn per_point_arrays_hold_the_sets_points_alone() {
        let mut s = ExecutionStats {
            count: 5,
            ..Default::default()
        };
        s.errors_m[..5].copy_from_slice(&[0.001, 0.002, f64::NAN, 0.004, 0.005]);
        let v: Value = serde_json::from_slice(&Payload::Stats(s).json()).unwrap();
        assert_eq!(v["errors_m"], json!([0.001, 0.002, null, 0.004, 0.005]));
        let (_, text) = schema::<ExecutionStats>("stats");
        let schema: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(schema["properties"]["errors_m"]["minItems"], 0);
        assert_eq!(schema["properties"]["errors_m"]["maxItems"], MAX_WAYPOINTS);
        let r = EstimateRequest {
            count: 2,
            ..Default::default()
        };
        let v: Value = serde_json::from_slice(&Payload::EstimateRequest(r).json()).unwrap();
        assert_eq!(v["desired"].as_array().unwrap().len(), 2);
        for (topic, _) in PER_POINT {
            assert!(TOPICS.contains(&topic), "{topic}");
        }
    }
}
