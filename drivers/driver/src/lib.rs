//! What every driver that moves the arm shares: taking setpoints and the e-stop from their
//! services ([`Commands`]), and deciding, alone, what is safe to do with them ([`Supervisor`]),
//! whatever the controller does. The sim and the tendon driver are built on these.

use softarm_ipc::{Actuators, ControllerState, DriverState, EstopState, Node, Setpoint, Sub};
use softarm_runtime::{EstopLatch, now_ns};

/// The setpoint and e-stop subscriptions of a driver, and what arrived on them.
pub struct Commands {
    setpoints: Sub<Setpoint>,
    estop: Sub<EstopState>,
    latch: EstopLatch,
    /// The newest `estop` sample said engaged.
    heard_engaged: bool,
    /// The latch file said engaged (or could not be read) when last looked at.
    latched: bool,
    latch_read_ns: u64,
    refused: u64,
    /// The arm's actuators: a setpoint with another count is refused.
    actuators: usize,
}

/// What arrived since the last [`Commands::poll`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Poll {
    /// The newest setpoint to follow, if one came: its every value a number, fresh, sent by a
    /// controller that is not stopped, and not in a poll that saw the e-stop engaged.
    pub setpoint: Option<Actuators>,
    /// The e-stop is latched.
    pub stopped: bool,
}

/// How often the latch file is read besides the `estop` service (ns): an `estop` sample can
/// be missed (its publisher gone before a blocked driver looked), the file cannot.
const LATCH_EVERY_NS: u64 = 50_000_000;

impl Commands {
    /// Subscribes, for an arm of `actuators`; starts stopped when `latch` says the e-stop is
    /// engaged (or cannot be read).
    pub fn open(
        node: &Node,
        latch: &EstopLatch,
        actuators: usize,
    ) -> Result<Self, softarm_ipc::Error> {
        let latched = latch.engaged_or_safe(|e| tracing::error!("{e}; holding the motors"));
        if latched {
            tracing::warn!(
                "the e-stop is latched ({}): setpoints are ignored until `softarm estop --reset`",
                latch.path().display()
            );
        }
        Ok(Self {
            setpoints: node.subscriber(&node.setpoint()?)?,
            estop: node.subscriber(&node.estop()?)?,
            latch: latch.clone(),
            heard_engaged: false,
            latched,
            latch_read_ns: now_ns(),
            refused: 0,
            actuators,
        })
    }

    fn stopped(&self) -> bool {
        self.heard_engaged || self.latched
    }

    /// Takes everything that arrived; setpoints stamped more than `max_age_ns` before `now_ns`
    /// are not followed (a controller's last word kept by the service is not a command).
    pub fn poll(&mut self, now_ns: u64, max_age_ns: u64) -> Poll {
        let mut saw_stop = self.stopped();
        while let Ok(Some(s)) = self.estop.receive() {
            self.heard_engaged = s.engaged != 0;
            saw_stop |= self.heard_engaged;
        }
        if now_ns.saturating_sub(self.latch_read_ns) >= LATCH_EVERY_NS {
            self.latch_read_ns = now_ns;
            let latched = self
                .latch
                .engaged_or_safe(|e| tracing::error!("{e}; holding the motors"));
            if self.latched && !latched {
                // A reset writes the file before it publishes: the file is the authority
                // that one happened, even if its sample was missed.
                self.heard_engaged = false;
            }
            if latched && !self.stopped() {
                tracing::warn!("the e-stop latch is engaged: stopping");
            }
            self.latched = latched;
            saw_stop |= latched;
        }
        let mut setpoint = None;
        while let Ok(Some(s)) = self.setpoints.receive() {
            // From the wire: a setpoint that is not a number is refused whole (it must never
            // reach a motor); the last good one stays.
            let a = s.actuation;
            if a.len() != self.actuators || !a.iter().all(|v| v.is_finite()) {
                self.refused += 1;
                if self.refused.is_power_of_two() {
                    tracing::error!(
                        refused = self.refused,
                        actuation = ?s.actuation,
                        "setpoint refused: not a number, or not the arm's {} actuators; \
                         holding the last good one",
                        self.actuators
                    );
                }
                continue;
            }
            // A stopped controller's setpoint is its held target from before the e-stop, and
            // one from a poll that saw the e-stop (or its reset) may be too: the first to be
            // followed after a reset is one the controller sent after it.
            let stale = now_ns.saturating_sub(s.stamp_ns) > max_age_ns;
            if !saw_stop && !stale && s.state != ControllerState::Stopped as u32 {
                setpoint = Some(a);
            }
        }
        Poll {
            setpoint,
            stopped: saw_stop || self.stopped(),
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
    Follow(Actuators),
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
    use softarm_ipc::Namespace;

    /// `Commands` over real services, in a namespace of this test's own; the driver's node is
    /// the last element, to be dropped after its ports.
    fn commands(name: &str) -> (Commands, Node, EstopLatch, std::path::PathBuf, Node) {
        let ns = format!("softarm/test-driver-{name}-{}", std::process::id());
        let dir = std::env::temp_dir().join(ns.replace('/', "-"));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let latch = EstopLatch::new(dir.join("estop"));
        let ns = Namespace::new(&ns).unwrap();
        let driver = Node::open(ns.clone(), "driver").unwrap();
        let c = Commands::open(&driver, &latch, 6).unwrap();
        (c, Node::open(ns, "peer").unwrap(), latch, dir, driver)
    }

    fn setpoint(v: f64, state: ControllerState, stamp_ns: u64) -> Setpoint {
        Setpoint {
            stamp_ns,
            actuation: [v; 6].into(),
            state: state as u32,
            ..Setpoint::default()
        }
    }

    #[test]
    fn only_fresh_numbers_from_a_running_controller_are_followed() {
        let (mut c, peer, _latch, dir, _driver) = commands("fresh");
        let setpoints = peer.publisher(&peer.setpoint().unwrap()).unwrap();
        let now = now_ns();
        let max_age = 100 * MS;
        setpoints
            .send_copy(setpoint(0.4, ControllerState::Idle, now))
            .unwrap();
        assert_eq!(
            c.poll(now, max_age).setpoint,
            Some(Actuators::filled(6, 0.4))
        );
        setpoints
            .send_copy(setpoint(f64::NAN, ControllerState::Execute, now))
            .unwrap();
        assert_eq!(c.poll(now, max_age).setpoint, None);
        assert_eq!(c.refused(), 1);
        // The held target a stopped controller keeps sending is not a command.
        setpoints
            .send_copy(setpoint(0.6, ControllerState::Stopped, now))
            .unwrap();
        assert_eq!(c.poll(now, max_age).setpoint, None);
        // Nor is a controller's last word from long ago.
        setpoints
            .send_copy(setpoint(0.6, ControllerState::Hold, now - 2 * max_age))
            .unwrap();
        assert_eq!(c.poll(now, max_age).setpoint, None);
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_poll_that_sees_the_estop_follows_nothing_and_the_latch_file_is_heard() {
        let (mut c, peer, latch, dir, _driver) = commands("estop");
        let setpoints = peer.publisher(&peer.setpoint().unwrap()).unwrap();
        let estop = peer.publisher(&peer.estop().unwrap()).unwrap();
        let max_age = 100 * MS;
        // Engaged and released within one poll: stopped this poll, its setpoints dropped.
        estop
            .send_copy(EstopState {
                engaged: 1,
                ..Default::default()
            })
            .unwrap();
        estop
            .send_copy(EstopState {
                engaged: 0,
                ..Default::default()
            })
            .unwrap();
        setpoints
            .send_copy(setpoint(0.4, ControllerState::Idle, now_ns()))
            .unwrap();
        let p = c.poll(now_ns(), max_age);
        assert!(p.stopped);
        assert_eq!(p.setpoint, None);
        // The next poll follows again.
        setpoints
            .send_copy(setpoint(0.4, ControllerState::Idle, now_ns()))
            .unwrap();
        let p = c.poll(now_ns(), max_age);
        assert!(!p.stopped);
        assert_eq!(p.setpoint, Some(Actuators::filled(6, 0.4)));
        // Engaged on disk only (its sample missed): heard at the next look at the file.
        latch.set(true).unwrap();
        let later = now_ns() + LATCH_EVERY_NS;
        assert!(c.poll(later, u64::MAX).stopped);
        // An engage heard on the service, then a reset written to the file whose sample is
        // missed: the file says a reset happened.
        estop
            .send_copy(EstopState {
                engaged: 1,
                ..Default::default()
            })
            .unwrap();
        assert!(c.poll(later + 1, u64::MAX).stopped);
        latch.set(false).unwrap();
        // The poll that notices the reset still counts as stopped; the next is released.
        assert!(c.poll(later + 2 * LATCH_EVERY_NS, u64::MAX).stopped);
        assert!(!c.poll(later + 2 * LATCH_EVERY_NS + 1, u64::MAX).stopped);
        std::fs::remove_dir_all(dir).unwrap();
    }

    const MS: u64 = 1_000_000;

    fn poll(setpoint: Option<f64>, stopped: bool) -> Poll {
        Poll {
            setpoint: setpoint.map(|v| Actuators::filled(6, v)),
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
            Action::Follow(Actuators::filled(6, 0.4))
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
            Action::Follow(Actuators::filled(6, 0.5))
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
            Action::Follow(Actuators::filled(6, 0.5))
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
