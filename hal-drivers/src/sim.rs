//! The `sim` driver process: the PCC plant with its realism layer behind the same services as
//! the hardware drivers. Consumes `setpoint` (and `estop`), publishes `tracker` and
//! `motor_state` at its own fixed rate on absolute deadlines.

use std::sync::atomic::{AtomicBool, Ordering};

use serde::{Deserialize, Serialize};
use softarm_ipc::clock::Ticker;
use softarm_ipc::{Contract, MotorState, Namespace, TrackerSample, now_ns};

use crate::pcc::ArmGeometry;
use crate::plant::{Plant, Realism};

/// The `[sim]` section.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// Rate of `tracker` and `motor_state` (Hz).
    pub rate_hz: f64,
    /// Where the actuators rest at start.
    pub initial_actuation: [f64; 6],
    pub realism: Realism,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            rate_hz: 200.0,
            initial_actuation: [0.5; 6],
            realism: Realism::default(),
        }
    }
}

impl SimConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.rate_hz.is_finite() && (1.0..=5000.0).contains(&self.rate_hz)) {
            return Err(format!(
                "sim.rate_hz must be 1 to 5000, got {}",
                self.rate_hz
            ));
        }
        if self
            .initial_actuation
            .iter()
            .any(|a| !(0.0..=1.0).contains(a))
        {
            return Err("sim.initial_actuation must be in [0, 1]".into());
        }
        self.realism.validate()
    }
}

/// Runs the simulated arm until `stop` is set.
pub fn run(
    config: &SimConfig,
    arm: &ArmGeometry,
    namespace: Namespace,
    stop: &AtomicBool,
) -> Result<(), String> {
    let mut plant = Plant::new(*arm, config.realism, config.initial_actuation)?;
    let ipc = Contract::new(namespace, "sim").map_err(|e| e.to_string())?;
    let e = |e: softarm_ipc::Error| e.to_string();
    let setpoints = ipc.subscriber(&ipc.setpoint().map_err(e)?).map_err(e)?;
    let estop = ipc.subscriber(&ipc.estop().map_err(e)?).map_err(e)?;
    let tracker = ipc.publisher(&ipc.tracker().map_err(e)?).map_err(e)?;
    let motors = ipc.publisher(&ipc.motor_state().map_err(e)?).map_err(e)?;

    let dt = 1.0 / config.rate_hz;
    let mut command = config.initial_actuation;
    let mut stopped = false;
    let mut seq = 0u64;
    let mut ticker = Ticker::new(config.rate_hz);
    tracing::info!(rate_hz = config.rate_hz, "sim running");
    while !stop.load(Ordering::Relaxed) {
        ticker.wait();
        while let Ok(Some(s)) = setpoints.receive() {
            command = s.actuation;
        }
        while let Ok(Some(s)) = estop.receive() {
            stopped = s.engaged != 0;
        }
        if stopped {
            // E-stop: the motors hold where they are, whatever is commanded.
            command = plant.state();
        }
        let m = plant.step(&command, dt);
        seq += 1;
        let stamp_ns = now_ns();
        let _ = motors.send_copy(MotorState {
            seq,
            stamp_ns,
            actuation: m.actuation,
        });
        let _ = tracker.send_copy(TrackerSample {
            seq,
            stamp_ns,
            position: m.position,
        });
    }
    tracing::info!(overruns = ticker.overruns(), "sim stopped");
    Ok(())
}
