//! softarm's own recordings (`softarm record`, MCAP) as a recording to identify the arm from
//! (`softarm train --from run.mcap`): the tracker's samples beside the motors' state, where the
//! arm stood still.
//!
//! A recording of the stack is a trajectory, not a row per settled pose: a tracker sample is
//! kept where every motor moved less than [`STILL`] (normalised) over the [`STILL_S`] before
//! it (slowly enough that the tip is where the motors put it), paired with the motors' state
//! nearest it in time within [`PAIRED_S`], and no closer than [`EVERY_S`] to the last kept.
//! Such a recording has no labels: its motions are its stretches of time, as an unlabelled
//! CSV's ([`softarm_identify::recording::stretch`]).

use std::path::Path;

use anyhow::{Context, Result, bail};
use serde_json::Value;
use softarm_arm::Layout;
use softarm_identify::recording::{Recording, Row, stretch};

/// How still the motors must have been (normalised actuation) over [`STILL_S`] seconds: a
/// tenth of the stroke a second.
const STILL: f64 = 0.02;
const STILL_S: f64 = 0.2;
/// The motors' state paired with a tracker sample: at most this far apart in time (s).
const PAIRED_S: f64 = 0.05;
/// At most a row every this many seconds.
const EVERY_S: f64 = 0.2;

fn numbers(v: &Value) -> Option<Vec<f64>> {
    v.as_array()?.iter().map(Value::as_f64).collect()
}

/// The recording at `path` of `arm`, as `softarm train --from` and `softarm model check` take
/// it: softarm's own (`.mcap`, [`read`]), else a CSV through the column map at `columns`
/// (`--columns`).
pub fn read_any(path: &Path, columns: Option<&Path>, arm: &Layout) -> Result<Recording> {
    if path.extension().is_some_and(|e| e == "mcap") {
        return read(path, arm);
    }
    let columns = columns.with_context(|| {
        format!(
            "{}: a CSV recording needs its column map: --columns FILE",
            path.display()
        )
    })?;
    Ok(softarm_identify::run::read_recording(path, columns, arm)?)
}

/// Reads `path` (an MCAP recording of a stack) for `arm`.
pub fn read(path: &Path, arm: &Layout) -> Result<Recording> {
    let n = arm.actuators().len();
    let messages = crate::record::read(path)?;
    let mut motors: Vec<(f64, Vec<f64>)> = Vec::new();
    let mut tracker: Vec<(f64, [f64; 3])> = Vec::new();
    for (k, m) in messages.iter().enumerate() {
        let at = || format!("{}: message {} ({})", path.display(), k + 1, m.topic);
        let stamp = || -> Result<f64> {
            let ns = m.value["stamp_ns"]
                .as_u64()
                .with_context(|| format!("{}: no stamp_ns", at()))?;
            Ok(ns as f64 * 1e-9)
        };
        match m.topic.as_str() {
            "motor_state" => {
                let a = numbers(&m.value["actuation"])
                    .with_context(|| format!("{}: actuation is not a list of numbers", at()))?;
                if a.len() != n {
                    bail!(
                        "{}: {} actuators; the arm has {n}: a recording of another arm",
                        at(),
                        a.len()
                    );
                }
                if a.iter().any(|v| !v.is_finite()) {
                    bail!("{}: an actuation that is not a finite number", at());
                }
                motors.push((stamp()?, a));
            }
            "tracker" => {
                let p = numbers(&m.value["position"])
                    .filter(|p| p.len() == 3)
                    .with_context(|| format!("{}: position is not three numbers", at()))?;
                // The tracker marks a sample it did not see NaN: left out, not an error.
                if p.iter().all(|v| v.is_finite()) {
                    tracker.push((stamp()?, [p[0], p[1], p[2]]));
                }
            }
            _ => {}
        }
    }
    if motors.is_empty() || tracker.is_empty() {
        bail!(
            "{}: {} motor states and {} tracker samples; identifying the arm needs both \
             (record a running stack with `softarm record`)",
            path.display(),
            motors.len(),
            tracker.len()
        );
    }
    motors.sort_by(|a, b| a.0.total_cmp(&b.0));
    tracker.sort_by(|a, b| a.0.total_cmp(&b.0));
    let zero: Vec<f64> = (arm.actuators().iter())
        .map(|a| 0.5 * (a.min_m + a.max_m))
        .collect();
    let start = tracker[0].0;
    let mut rows = Vec::new();
    let mut last = f64::NEG_INFINITY;
    for (t, position) in tracker {
        if t - last < EVERY_S {
            continue;
        }
        let Some(now) = nearest(&motors, t).filter(|m| (m.0 - t).abs() <= PAIRED_S) else {
            continue;
        };
        let still = (motors.iter())
            .filter(|m| (t - STILL_S..=t).contains(&m.0))
            .all(|m| m.1.iter().zip(&now.1).all(|(a, b)| (a - b).abs() < STILL));
        if !still {
            continue;
        }
        last = t;
        rows.push(Row {
            line: rows.len() as u64 + 1,
            time_s: t - start,
            pull_m: (0..n)
                .map(|i| zero[i] - arm.actuators()[i].length_of(now.1[i]))
                .collect(),
            tip_m: position,
            motion: stretch(t - start),
            hold: false,
        });
    }
    Ok(Recording::new(path.into(), rows, zero, 1))
}

fn nearest(motors: &[(f64, Vec<f64>)], t: f64) -> Option<&(f64, Vec<f64>)> {
    let i = motors.partition_point(|m| m.0 < t);
    let before = i.checked_sub(1).map(|j| &motors[j]);
    let after = motors.get(i);
    match (before, after) {
        (Some(b), Some(a)) => Some(if t - b.0 <= a.0 - t { b } else { a }),
        (b, a) => b.or(a),
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    fn arm() -> Layout {
        let text = softarm_config::arms::resolve("tdcr").unwrap();
        softarm_config::arms::check(&text, "tdcr")
            .unwrap()
            .layout()
            .unwrap()
    }

    /// An MCAP of motor states and tracker samples at 100 Hz, `count` actuators, the tracker's
    /// x the actuation: 4 s standing at 0.3, then 2 s moving (a quarter stroke a second) to
    /// 0.8 and 2 s standing there, and again.
    fn recording(path: &Path, count: usize, seconds: f64) {
        let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
        let mut w = mcap::WriteOptions::new().profile("").create(file).unwrap();
        let schema = w.add_schema("x", "jsonschema", b"{}").unwrap();
        let motors = w
            .add_channel(schema, "motor_state", "json", &BTreeMap::new())
            .unwrap();
        let tracker = w
            .add_channel(schema, "tracker", "json", &BTreeMap::new())
            .unwrap();
        let steps = (seconds * 100.0) as u64;
        for k in 0..steps {
            let t = k as f64 / 100.0;
            let phase = t % 4.0;
            let a = 0.3 + 0.5 * phase.min(2.0) / 2.0 * ((t / 4.0).floor() % 2.0);
            let stamp = 1_000_000_000 + k * 10_000_000;
            let m = serde_json::json!({"stamp_ns": stamp, "actuation": vec![a; count]});
            let p = serde_json::json!({"stamp_ns": stamp + 1_000_000, "position": [a, 0.0, 0.2]});
            for (channel, v) in [(motors, m), (tracker, p)] {
                let header = mcap::records::MessageHeader {
                    channel_id: channel,
                    sequence: k as u32,
                    log_time: stamp,
                    publish_time: stamp,
                };
                w.write_to_known_channel(&header, v.to_string().as_bytes())
                    .unwrap();
            }
        }
        w.finish().unwrap();
    }

    #[test]
    fn the_arm_standing_still_becomes_rows_and_moving_does_not() {
        let path = std::env::temp_dir().join(format!("softarm-mcap-{}.mcap", std::process::id()));
        recording(&path, 9, 40.0);
        let r = read(&path, &arm()).unwrap();
        // Six of every eight seconds standing, a row every 0.2 s: never while moving faster
        // than a tenth of the stroke a second (the ramp's first 80 ms are slower).
        assert!((140..=160).contains(&r.len()), "{}", r.len());
        let a = arm();
        for row in &r.rows {
            let x = row.tip_m[0];
            assert!(
                (x - 0.3).abs() < 0.021 || (x - 0.8).abs() < 1e-12,
                "{row:?}"
            );
            let length = r.zero_length_m[0] - row.pull_m[0];
            let actuation = a.actuators()[0].actuation_of(length);
            assert!((actuation - x).abs() < 1e-9, "{row:?}");
        }
        assert_eq!(r.motions()[..2], ["t000000", "t000030"]);
        let e = read(
            &path,
            &softarm_config::Config::default_sim(".".into()).layout(),
        )
        .unwrap_err();
        assert!(e.to_string().contains("9 actuators; the arm has 6"), "{e}");
        std::fs::remove_file(&path).unwrap();
    }
}
