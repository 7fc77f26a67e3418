//! What every driver that moves the arm shares: taking setpoints and the e-stop from their
//! services ([`Commands`]), and deciding, alone, what is safe to do with them ([`Supervisor`]),
//! whatever the controller does. The sim and the tendon driver are built on these.

use softarm_ipc::{Actuation, DriverState, EstopLatch, EstopState, Node, Setpoint, Sub};

/// The setpoint and e-stop subscriptions of a driver, and what arrived on them.
pub struct Commands {
    setpoints: Sub<Setpoint>,
    estop: Sub<EstopState>,
    stopped: bool,
    refused: u64,
}

/// What arrived since the last [`Commands::poll`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Poll {
    /// The newest setpoint whose every value is a number, if one came.
    pub setpoint: Option<Actuation>,
    /// The e-stop is latched.
    pub stopped: bool,
}

impl Commands {
    /// Subscribes; starts stopped when `latch` says the e-stop is engaged (or cannot be read).
    pub fn open(node: &Node, latch: &EstopLatch) -> Result<Self, softarm_ipc::Error> {
        let stopped = latch.engaged_or_safe(|e| tracing::error!("{e}; holding the motors"));
        if stopped {
            tracing::warn!(
                "the e-stop is latched ({}): setpoints are ignored until `softarm estop --reset`",
                latch.path().display()
            );
        }
        Ok(Self {
            setpoints: node.subscriber(&node.setpoint()?)?,
            estop: node.subscriber(&node.estop()?)?,
            stopped,
            refused: 0,
        })
    }

    /// Takes everything that arrived.
    pub fn poll(&mut self) -> Poll {
        let mut setpoint = None;
        while let Ok(Some(s)) = self.setpoints.receive() {
            // From the wire: a setpoint that is not a number is refused whole (it must never
            // reach a motor); the last good one stays.
            if s.actuation.iter().all(|v| v.is_finite()) {
                setpoint = Some(s.actuation);
            } else {
                self.refused += 1;
                if self.refused.is_power_of_two() {
                    tracing::error!(
                        refused = self.refused,
                        actuation = ?s.actuation,
                        "setpoint refused: not a number; holding the last good one"
                    );
                }
            }
        }
        while let Ok(Some(s)) = self.estop.receive() {
            self.stopped = s.engaged != 0;
        }
        Poll {
            setpoint,
            stopped: self.stopped,
        }
    }

    /// Setpoints refused since the start (not numbers).
    pub fn refused(&self) -> u64 {
        self.refused
    }
}

/// When a driver stops following on its own.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timeouts {
    /// No setpoint for this long: hold the last position.
    pub hold_after_ns: u64,
    /// No setpoint for this long: torque off.
    pub off_after_ns: u64,
}

/// What the driver does this cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Action {
    /// Drive the motors to this actuation (torque on first, if it is off).
    Follow(Actuation),
    /// Keep the last goal, torque on.
    Hold,
    /// Torque off.
    Off,
}

/// The driver's own safety logic, pure: from what arrived and the time, the state it is in and
/// what to do. Torque comes on only with a fresh setpoint; an e-stop or a motor fault overrides
/// everything; setpoints that stop arriving lead to hold, then torque off.
#[derive(Debug, Clone)]
pub struct Supervisor {
    timeouts: Timeouts,
    /// When the last valid setpoint arrived (ns); `None` before the first, or since an e-stop.
    last_setpoint_ns: Option<u64>,
    state: DriverState,
}

impl Supervisor {
    pub fn new(timeouts: Timeouts) -> Self {
        Self {
            timeouts,
            last_setpoint_ns: None,
            state: DriverState::Off,
        }
    }

    pub fn state(&self) -> DriverState {
        self.state
    }

    /// One cycle at `now_ns`: `fault` is true while any motor reports a hardware error.
    pub fn update(&mut self, now_ns: u64, poll: &Poll, fault: bool) -> Action {
        if poll.stopped {
            // Latched until reset; a setpoint that arrived with the e-stop does not count, so
            // after the reset the torque stays off until the controller sends a new one.
            self.last_setpoint_ns = None;
            self.state = DriverState::Stopped;
            return Action::Off;
        }
        if fault {
            // The faulted motor is off (the hardware turns it off; the driver leaves it alone);
            // the others keep their position until the driver is restarted, or go off with
            // the rest when the controller falls silent.
            if poll.setpoint.is_some() {
                self.last_setpoint_ns = Some(now_ns);
            }
            self.state = DriverState::Fault;
            let silent = self.last_setpoint_ns.map(|t| now_ns.saturating_sub(t));
            return match silent {
                Some(s) if s < self.timeouts.off_after_ns => Action::Hold,
                _ => Action::Off,
            };
        }
        if let Some(a) = poll.setpoint {
            self.last_setpoint_ns = Some(now_ns);
            self.state = DriverState::Following;
            return Action::Follow(a);
        }
        let Some(last) = self.last_setpoint_ns else {
            self.state = DriverState::Off;
            return Action::Off;
        };
        let silent = now_ns.saturating_sub(last);
        if silent >= self.timeouts.off_after_ns {
            self.state = DriverState::Off;
            Action::Off
        } else if silent >= self.timeouts.hold_after_ns {
            self.state = DriverState::Holding;
            Action::Hold
        } else {
            // Between setpoints: the last goal stands.
            Action::Hold
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn poll(setpoint: Option<f64>, stopped: bool) -> Poll {
        Poll {
            setpoint: setpoint.map(|v| [v; 6]),
            stopped,
        }
    }

    fn supervisor() -> Supervisor {
        Supervisor::new(Timeouts {
            hold_after_ns: 100 * MS,
            off_after_ns: 2000 * MS,
        })
    }

    #[test]
    fn torque_comes_on_only_with_a_setpoint() {
        let mut s = supervisor();
        assert_eq!(s.update(0, &poll(None, false), false), Action::Off);
        assert_eq!(s.state(), DriverState::Off);
        assert_eq!(
            s.update(MS, &poll(Some(0.4), false), false),
            Action::Follow([0.4; 6])
        );
        assert_eq!(s.state(), DriverState::Following);
        // Between setpoints the goal stands and the state stays.
        assert_eq!(s.update(5 * MS, &poll(None, false), false), Action::Hold);
        assert_eq!(s.state(), DriverState::Following);
    }

    #[test]
    fn silence_holds_then_turns_the_torque_off() {
        let mut s = supervisor();
        s.update(0, &poll(Some(0.4), false), false);
        assert_eq!(s.update(99 * MS, &poll(None, false), false), Action::Hold);
        assert_eq!(s.state(), DriverState::Following);
        assert_eq!(s.update(100 * MS, &poll(None, false), false), Action::Hold);
        assert_eq!(s.state(), DriverState::Holding);
        assert_eq!(s.update(2000 * MS, &poll(None, false), false), Action::Off);
        assert_eq!(s.state(), DriverState::Off);
        // A controller that comes back is followed again.
        assert_eq!(
            s.update(2500 * MS, &poll(Some(0.5), false), false),
            Action::Follow([0.5; 6])
        );
    }

    #[test]
    fn estop_wins_and_needs_a_fresh_setpoint_after_the_reset() {
        let mut s = supervisor();
        s.update(0, &poll(Some(0.4), false), false);
        assert_eq!(s.update(MS, &poll(Some(0.6), true), false), Action::Off);
        assert_eq!(s.state(), DriverState::Stopped);
        assert_eq!(s.update(2 * MS, &poll(None, true), true), Action::Off);
        // Reset: nothing moves until the controller speaks.
        assert_eq!(s.update(3 * MS, &poll(None, false), false), Action::Off);
        assert_eq!(s.state(), DriverState::Off);
        assert_eq!(
            s.update(4 * MS, &poll(Some(0.5), false), false),
            Action::Follow([0.5; 6])
        );
    }

    #[test]
    fn a_fault_holds_whatever_is_commanded() {
        let mut s = supervisor();
        s.update(0, &poll(Some(0.4), false), false);
        assert_eq!(s.update(MS, &poll(Some(0.9), false), true), Action::Hold);
        assert_eq!(s.state(), DriverState::Fault);
        assert_eq!(s.update(1500 * MS, &poll(None, false), true), Action::Hold);
        assert_eq!(s.update(2001 * MS, &poll(None, false), true), Action::Off);
        assert_eq!(s.state(), DriverState::Fault);
    }
}
