//! The `sim` driver process: the PCC plant with its realism layer behind the same services as
//! the hardware drivers. Consumes `setpoint` (and `estop`), publishes `tracker` and
//! `motor_state` at its own fixed rate on absolute deadlines.
//!
//! - [`plant`] — the simulated plant: the PCC kinematics behind a seeded realism layer, on an
//!   arm that changes over the plant's time as a scenario says (`[sim]` and the scenario's
//!   changes are plain data in `softarm-sections`). Pure math; here, with the process that
//!   runs it, so that neither the method nor the config links a simulator. The rehearsal steps
//!   the same plant ([`SimArm`]).
//! - [`command`] — `softarm sim`: the arm the config and a scenario give the process.

use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;

use softarm_driver::Commands;
use softarm_ipc::{
    Actuators, DriverState, MAX_ACTUATORS, MotorState, Namespace, Node, TrackerSample,
};
use softarm_runtime::clock::Ticker;
use softarm_runtime::{EstopLatch, now_ns};

use softarm_sections::sim::SimConfig;

pub mod command;
pub mod plant;

use crate::plant::{Body, Measurement, Physics, Plant};

/// Runs the simulated arm until `stop` is set; starts stopped if `latch` says the e-stop is
/// engaged. With `physics` (a MuJoCo model) the plant's actuators drive it in place of the
/// arm's kinematics.
pub fn run(
    config: &SimConfig,
    arm: Body,
    physics: Option<Box<dyn Physics>>,
    namespace: Namespace,
    latch: &EstopLatch,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let ipc = Node::open(namespace, "sim")?;
    let n = arm.start().actuators();
    let mut commands = Commands::open(&ipc, latch, n)?;
    // A real arm stays where it was while its driver restarts: a sim restarted beside a
    // running controller starts where the controller holds it, not at `initial_actuation`
    // (the controller would otherwise resume from a teleported arm). Also while the e-stop is
    // latched: a STOPPED controller's setpoint is not a command, but it is where the arm was
    // held when the motors stopped, and a controller restarted or reset later starts from
    // the measured state.
    let mut start = config.initial_actuation.values(n);
    {
        let held = ipc.subscriber(&ipc.setpoint()?)?;
        let waiting = std::time::Instant::now();
        'wait: while waiting.elapsed() < std::time::Duration::from_millis(100) {
            while let Ok(Some(s)) = held.receive() {
                let fresh = now_ns().saturating_sub(s.stamp_ns) <= 1_000_000_000;
                let held = s.actuation;
                if held.len() == n && fresh && held.iter().all(|a| (0.0..=1.0).contains(a)) {
                    tracing::info!(
                        actuation = ?held,
                        "a controller is running: starting where it holds the arm"
                    );
                    start = held.to_vec();
                    break 'wait;
                }
            }
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
    }
    let mut sim = SimArm::of_body(arm, config, &start)?;
    if let Some(physics) = physics {
        sim = sim.with_physics(physics)?;
    }
    let mut pace = Pace::new(config.rate_hz, sim.plant().physics());
    let tracker = ipc.publisher(&ipc.tracker()?)?;
    let motors = ipc.publisher(&ipc.motor_state()?)?;

    let mut seq = 0u64;
    let mut in_force = None;
    let mut ticker = Ticker::new(config.rate_hz);
    tracing::info!(
        rate_hz = config.rate_hz,
        steps = matches!(sim.plant().body(), Body::Stepped { .. }),
        drift = !config.drift.is_off(),
        "sim running"
    );
    while !stop.load(Ordering::Relaxed) {
        let wake = ticker.wait();
        // The sim follows whatever is fresh; a stale setpoint only at its start.
        let poll = commands.poll(now_ns(), 1_000_000_000);
        // Commands refused every other count.
        let setpoint = poll.setpoint.as_ref().map(|a| a.as_slice());
        let stepping = std::time::Instant::now();
        let m = sim.step(setpoint, poll.stopped, wake.missed + 1);
        pace.stepped(stepping.elapsed(), wake.missed);
        log_step(sim.plant(), &mut in_force);
        // The sample number counts the sim's periods, the ones it slept through too, so that
        // seq / rate_hz is the sim's own clock (its scenario's time) on a busy machine as well.
        seq += wake.missed + 1;
        let stamp_ns = now_ns();
        let _ = motors.send_copy(MotorState {
            seq,
            stamp_ns,
            actuation: Actuators::new(&m.actuation[..n]),
            current_a: Actuators::filled(n, f64::NAN),
            state: if poll.stopped {
                DriverState::Stopped
            } else {
                DriverState::Following
            } as u32,
            ..MotorState::default()
        });
        let _ = tracker.send_copy(TrackerSample {
            seq,
            stamp_ns,
            position: m.position,
        });
    }
    let refused = commands.refused();
    tracing::info!(
        overruns = ticker.overruns(),
        refused,
        slow_steps = pace.slow,
        steps = pace.steps,
        "sim stopped"
    );
    Ok(())
}

/// Whether the plant keeps the clock: a step of physics that took longer than the period it
/// simulated puts the next wake behind, and the plant then steps by all the time missed (it
/// stays on the clock, in coarser steps). Never silent: said when it starts and every 10 s
/// while it lasts, with the counts.
struct Pace {
    period: std::time::Duration,
    physics: Option<String>,
    steps: u64,
    slow: u64,
    missed: u64,
    said_at: Option<std::time::Instant>,
}

impl Pace {
    fn new(rate_hz: f64, physics: Option<String>) -> Self {
        if let Some(p) = &physics {
            tracing::info!(physics = %p, "the plant runs physics in place of its kinematics");
        }
        Self {
            period: std::time::Duration::from_secs_f64(1.0 / rate_hz),
            physics,
            steps: 0,
            slow: 0,
            missed: 0,
            said_at: None,
        }
    }

    fn stepped(&mut self, took: std::time::Duration, missed: u64) {
        self.steps += 1;
        self.missed += missed;
        // The first step settles the physics at its first actuation, before the clock counts.
        if self.steps == 1 || took <= self.period || self.physics.is_none() {
            return;
        }
        self.slow += 1;
        let due = self.said_at.is_none_or(|t| t.elapsed().as_secs() >= 10);
        if due {
            self.said_at = Some(std::time::Instant::now());
            tracing::warn!(
                took_ms = took.as_secs_f64() * 1e3,
                period_ms = self.period.as_secs_f64() * 1e3,
                slow_steps = self.slow,
                steps = self.steps,
                periods_missed = self.missed,
                "the physics falls behind the clock: a step took longer than the time it \
                 simulated (the plant keeps the clock in coarser steps); a faster machine, a \
                 lower sim.rate_hz or a simpler model keeps it"
            );
        }
    }
}

/// The simulated arm between two of the driver's wakes, without I/O: the plant and the command
/// it follows. The sim driver steps it on its deadlines, `softarm-rehearsal` on a simulated
/// clock.
pub struct SimArm {
    plant: Plant,
    /// What it follows, one per actuator.
    command: [f64; MAX_ACTUATORS],
    /// One period (s).
    dt: f64,
}

impl SimArm {
    /// The plant of `config` on `body` (its steps included, drifting as `config.drift` says),
    /// its actuators at `start` (one per actuator), which it follows until told otherwise.
    pub fn of_body(body: Body, config: &SimConfig, start: &[f64]) -> anyhow::Result<Self> {
        let plant = Plant::of_sim(body, config, start)
            .map_err(anyhow::Error::msg)
            .context("the simulated plant")?;
        Ok(Self::of_plant(plant, config, start))
    }

    /// This arm with `physics` in place of its kinematics ([`Plant::with_physics`]).
    pub fn with_physics(mut self, physics: Box<dyn Physics>) -> anyhow::Result<Self> {
        self.plant = self
            .plant
            .with_physics(physics)
            .map_err(anyhow::Error::msg)?;
        Ok(self)
    }

    fn of_plant(plant: Plant, config: &SimConfig, start: &[f64]) -> Self {
        let mut command = [0.0; MAX_ACTUATORS];
        command[..start.len()].copy_from_slice(start);
        Self {
            plant,
            command,
            dt: 1.0 / config.rate_hz,
        }
    }

    /// One wake, `periods` periods after the last (the ones slept through too): follows
    /// `setpoint` (one per actuator) if one came, holds where the motors are while `stopped`,
    /// and steps the plant by all that time. A real arm moves on while its driver waits for a
    /// CPU; a plant stepped by one period per late wake ran slower than the wall clock, so
    /// under load the arm fell behind its setpoints by tens of millimetres at a conditioning
    /// point (seen: 52 mm at one point of a demo).
    pub fn step(&mut self, setpoint: Option<&[f64]>, stopped: bool, periods: u64) -> Measurement {
        let n = self.plant.actuators();
        if let Some(a) = setpoint {
            self.command[..n].copy_from_slice(&a[..n]);
        }
        if stopped {
            // E-stop: the motors hold where they are, whatever is commanded.
            self.command[..n].copy_from_slice(self.plant.state());
        }
        self.plant
            .step(&self.command[..n], self.dt * periods as f64)
    }

    pub fn plant(&self) -> &Plant {
        &self.plant
    }

    /// What it follows.
    pub fn command(&self) -> &[f64] {
        &self.command[..self.plant.actuators()]
    }

    /// One period (s).
    pub fn dt(&self) -> f64 {
        self.dt
    }
}

/// Logs a scenario's step once it is in force (what it changes is in the scenario's line at
/// the start).
fn log_step(plant: &Plant, in_force: &mut Option<usize>) {
    let now = plant.body().step_at(plant.time());
    if now != *in_force {
        *in_force = now;
        tracing::info!(
            time_s = plant.time(),
            step = now.map(|k| k + 1),
            "the scenario's arm changes"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// A physics step longer than its period is counted (never silently), the first (its
    /// settling) is not, and a plant without physics counts none.
    #[test]
    fn a_physics_step_longer_than_its_period_is_counted() {
        let mut pace = Pace::new(200.0, Some("a model".into()));
        for took_ms in [300, 1, 6, 4, 12] {
            pace.stepped(Duration::from_millis(took_ms), 0);
        }
        assert_eq!((pace.steps, pace.slow), (5, 2));
        let mut kinematics = Pace::new(200.0, None);
        for _ in 0..3 {
            kinematics.stepped(Duration::from_millis(50), 1);
        }
        assert_eq!((kinematics.slow, kinematics.missed), (0, 3));
    }
}
