//! The `sim` driver process: the PCC plant with its realism layer behind the same services as
//! the hardware drivers. Consumes `setpoint` (and `estop`), publishes `tracker` and
//! `motor_state` at its own fixed rate on absolute deadlines.

use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;

use softarm_ipc::clock::Ticker;
use softarm_ipc::{EstopLatch, MotorState, Namespace, Node, TrackerSample, now_ns};

use softarm_method::pcc::ArmGeometry;
use softarm_method::plant::{Plant, SimConfig};

/// Runs the simulated arm until `stop` is set; starts stopped if `latch` says the e-stop is
/// engaged.
pub fn run(
    config: &SimConfig,
    arm: &ArmGeometry,
    namespace: Namespace,
    latch: &EstopLatch,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let mut plant = Plant::new(*arm, config.realism, config.initial_actuation)
        .map_err(anyhow::Error::msg)
        .context("the simulated plant")?;
    let ipc = Node::open(namespace, "sim")?;
    let setpoints = ipc.subscriber(&ipc.setpoint()?)?;
    let estop = ipc.subscriber(&ipc.estop()?)?;
    let tracker = ipc.publisher(&ipc.tracker()?)?;
    let motors = ipc.publisher(&ipc.motor_state()?)?;

    let dt = 1.0 / config.rate_hz;
    let mut command = config.initial_actuation;
    let mut stopped = latch.engaged_or_safe(|e| tracing::error!("{e}; holding the motors"));
    if stopped {
        tracing::warn!(
            "the e-stop is latched ({}): holding the motors until `softarm estop --reset`",
            latch.path().display()
        );
    }
    let mut seq = 0u64;
    let mut refused = 0u64;
    let mut ticker = Ticker::new(config.rate_hz);
    tracing::info!(rate_hz = config.rate_hz, "sim running");
    while !stop.load(Ordering::Relaxed) {
        ticker.wait();
        while let Ok(Some(s)) = setpoints.receive() {
            // From the wire: a setpoint that is not a number is refused whole (a real driver
            // must never pass it to a motor); the last good one stays.
            if s.actuation.iter().all(|v| v.is_finite()) {
                command = s.actuation;
            } else {
                refused += 1;
                if refused.is_power_of_two() {
                    tracing::error!(
                        refused,
                        actuation = ?s.actuation,
                        "setpoint refused: not a number; holding the last good one"
                    );
                }
            }
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
            stopped: stopped as u32,
            _pad: 0,
        });
        let _ = tracker.send_copy(TrackerSample {
            seq,
            stamp_ns,
            position: m.position,
        });
    }
    tracing::info!(overruns = ticker.overruns(), refused, "sim stopped");
    Ok(())
}
