//! `softarm estop [--reset]`: engages or releases the e-stop, and says so only once the stack
//! has. The running controller and drivers hear it on the `estop` service; the latch file
//! (`<state.dir>/estop`) keeps it for every process that starts later (and the running ones
//! read it too), so it stays engaged until an explicit reset, whoever sent it and whatever
//! restarted since. A process confirms by what it publishes after the e-stop was sent: the
//! controller's `status` and the moving driver's `motor_state` say STOPPED (or, after a reset,
//! no longer do).

use std::time::{Duration, Instant};

use anyhow::{Context, anyhow};

use softarm_ipc::{
    ControllerState, ControllerStatus, DriverState, EstopState, MotorState, Namespace, Node, Pub,
    Sub,
};
use softarm_runtime::{EstopLatch, now_ns};

/// The processes that move the arm, and so must confirm: the controller by its `status`, a
/// driver that moves actuators ([`softarm_ipc::Driver::moves`]) by its `motor_state`.
const CONTROLLER: &str = "controller";

/// How long `softarm estop` waits for the stack to confirm.
pub const CONFIRM_TIMEOUT: Duration = Duration::from_secs(5);

/// An open line to a stack's e-stop: the publisher, and the subscriptions it is confirmed on.
pub struct Estop {
    publisher: Pub<EstopState>,
    status: Sub<ControllerStatus>,
    motors: Sub<MotorState>,
    /// Last, so the ports go before it.
    node: Node,
}

/// One e-stop (or reset) sent, and what the stack has said since.
#[derive(Debug, Clone)]
pub struct Pending {
    pub engaged: bool,
    pub sent_ns: u64,
    /// Processes that heard the sample when it was sent.
    pub receivers: usize,
    /// The controller's state in its newest status since the e-stop was sent.
    controller: Option<ControllerState>,
    /// The moving driver's state in its newest `motor_state` since it was sent.
    driver: Option<DriverState>,
}

/// Who has confirmed and who has not, among the processes alive.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Confirmation {
    /// `role STATE`, for each process that says what was asked.
    pub confirmed: Vec<String>,
    /// `role: why not`, for each process alive that has not (yet).
    pub missing: Vec<String>,
}

impl Pending {
    /// Whether `state` is what the controller says once this e-stop (or reset) took.
    fn controller_took(&self, state: ControllerState) -> bool {
        (state == ControllerState::Stopped) == self.engaged
    }

    fn driver_took(&self, state: DriverState) -> bool {
        (state == DriverState::Stopped) == self.engaged
    }

    /// Who of `alive` (the roles of the stack's live nodes) confirmed.
    pub fn confirmation(&self, alive: &[String]) -> Confirmation {
        let mut c = Confirmation::default();
        let wanted = if self.engaged {
            "STOPPED"
        } else {
            "not STOPPED"
        };
        for role in alive {
            let (said, took) = if role == CONTROLLER {
                (
                    self.controller.map(ControllerState::name),
                    self.controller.is_some_and(|s| self.controller_took(s)),
                )
            } else if softarm_ipc::Driver::named(role).is_some_and(|d| d.moves) {
                (
                    self.driver.map(DriverState::name),
                    self.driver.is_some_and(|s| self.driver_took(s)),
                )
            } else {
                continue;
            };
            match said {
                Some(state) if took => c.confirmed.push(format!("{role} {state}")),
                Some(state) => c
                    .missing
                    .push(format!("{role}: says {state}, not {wanted}")),
                None => c.missing.push(format!(
                    "{role}: alive, but has published nothing since (frozen, its device \
                     silent, or it cannot read what this process sent)"
                )),
            }
        }
        c
    }
}

impl Confirmation {
    pub fn complete(&self) -> bool {
        self.missing.is_empty()
    }
}

impl Estop {
    pub fn open(namespace: &Namespace) -> anyhow::Result<Self> {
        let node = Node::open(namespace.clone(), "estop")?;
        Ok(Self {
            publisher: node.publisher(&node.estop()?)?,
            status: node.subscriber(&node.status()?)?,
            motors: node.subscriber(&node.motor_state()?)?,
            node,
        })
    }

    /// Engages (`engaged`) or releases the e-stop.
    ///
    /// Engaging publishes first (the arm stops at once), then latches on disk; should the latch
    /// fail, the running processes are stopped all the same and the error says what a restart
    /// would miss. Releasing writes the latch first and publishes only once it is written, so no
    /// process can be released while a restarted one would still find it engaged.
    pub fn send(&self, latch: &EstopLatch, engaged: bool) -> anyhow::Result<Pending> {
        // What came before is not an answer to this.
        while let Ok(Some(_)) = self.status.receive() {}
        while let Ok(Some(_)) = self.motors.receive() {}
        let sent_ns = now_ns();
        let receivers = if engaged {
            let receivers = self.publish(true)?;
            latch.set(true).with_context(|| {
                format!(
                    "the e-stop reached {receivers} running processes, but a process started \
                     from now on would not know: fix the folder's permissions and send it again"
                )
            })?;
            receivers
        } else {
            latch
                .set(false)
                .context("the e-stop stays engaged: its latch could not be released")?;
            self.publish(false)?
        };
        Ok(Pending {
            engaged,
            sent_ns,
            receivers,
            controller: None,
            driver: None,
        })
    }

    fn publish(&self, engaged: bool) -> anyhow::Result<usize> {
        self.publisher
            .send_copy(EstopState {
                seq: now_ns(),
                stamp_ns: now_ns(),
                engaged: engaged as u32,
                _pad: 0,
            })
            .map_err(|e| anyhow!("{e:?}"))
            .context("sending the e-stop")
    }

    /// Takes what the stack published since; returns the confirmation among the processes
    /// alive now.
    pub fn poll(&self, p: &mut Pending) -> anyhow::Result<Confirmation> {
        while let Ok(Some(s)) = self.status.receive() {
            if s.stamp_ns >= p.sent_ns {
                p.controller = ControllerState::from_u32(s.state).or(p.controller);
            }
        }
        while let Ok(Some(m)) = self.motors.receive() {
            if m.stamp_ns >= p.sent_ns {
                p.driver = DriverState::from_u32(m.state).or(p.driver);
            }
        }
        let mut alive: Vec<String> = self
            .node
            .alive_nodes()?
            .into_iter()
            .map(|n| n.split('.').next().unwrap_or(&n).to_string())
            .collect();
        alive.dedup();
        Ok(p.confirmation(&alive))
    }

    /// Sends, then waits up to `timeout` for every process alive to confirm.
    pub fn send_and_confirm(
        &self,
        latch: &EstopLatch,
        engaged: bool,
        timeout: Duration,
    ) -> anyhow::Result<(Pending, Confirmation)> {
        let mut pending = self.send(latch, engaged)?;
        let start = Instant::now();
        loop {
            let c = self.poll(&mut pending)?;
            if c.complete() || start.elapsed() >= timeout {
                return Ok((pending, c));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

/// `softarm estop [--reset]` for the stack of `config`: sends, then says who confirmed; an error
/// (exit 1) when a process alive did not. Whether any process took it: none running, the latch
/// alone holds it (what every process starting later reads), which the caller's exit code
/// says apart from "confirmed" (a config of another stack than the one meant lands here).
pub fn run(
    config: &softarm_config::Config,
    reset: bool,
    timeout: Duration,
) -> anyhow::Result<bool> {
    let latch = config.estop_latch();
    let namespace = config.bus()?;
    let estop = Estop::open(&namespace)?;
    let (_, c) = estop.send_and_confirm(&latch, !reset, timeout)?;
    let word = if reset { "released" } else { "engaged" };
    if !c.complete() {
        anyhow::bail!(
            "the e-stop is {word} in the latch {}, but not confirmed in {:.0} s by: {}. \
             `softarm status` says more",
            latch.path().display(),
            timeout.as_secs_f64(),
            c.missing.join("; ")
        );
    }
    if c.confirmed.is_empty() {
        // Not an error: the latch is what a process starting later reads.
        println!(
            "e-stop {word} (the latch {} says {word}; no running process in namespace {:?})",
            latch.path().display(),
            namespace.as_str(),
        );
        return Ok(false);
    } else {
        let latch = if reset {
            format!("the latch {} says released", latch.path().display())
        } else {
            format!("latched in {}", latch.path().display())
        };
        println!("e-stop {word}: {} ({latch})", c.confirmed.join(", "));
    }
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pending(
        engaged: bool,
        controller: Option<ControllerState>,
        driver: Option<DriverState>,
    ) -> Pending {
        Pending {
            engaged,
            sent_ns: 0,
            receivers: 0,
            controller,
            driver,
        }
    }

    fn roles(r: &[&str]) -> Vec<String> {
        r.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn only_the_processes_that_move_the_arm_must_confirm() {
        use ControllerState::*;
        let alive = roles(&["controller", "learner", "sim", "view"]);
        let p = pending(true, Some(Stopped), Some(DriverState::Stopped));
        let c = p.confirmation(&alive);
        assert!(c.complete(), "{c:?}");
        assert_eq!(c.confirmed, ["controller STOPPED", "sim STOPPED"]);

        let c = pending(true, Some(Idle), None).confirmation(&alive);
        assert_eq!(c.missing.len(), 2, "{c:?}");
        assert!(
            c.missing[0].contains("controller: says IDLE, not STOPPED"),
            "{c:?}"
        );
        assert!(
            c.missing[1].starts_with("sim: alive, but has published nothing"),
            "{c:?}"
        );

        // A reset is confirmed by states that are not STOPPED.
        let c = pending(false, Some(Idle), Some(DriverState::Holding)).confirmation(&alive);
        assert!(c.complete(), "{c:?}");
        let c = pending(false, Some(Stopped), Some(DriverState::Holding)).confirmation(&alive);
        assert!(!c.complete());

        // Nothing alive: nothing to wait for (the latch is what starts them stopped).
        assert!(pending(true, None, None).confirmation(&[]).complete());
        // The tracker reads only.
        assert!(
            pending(true, None, None)
                .confirmation(&roles(&["tracker"]))
                .complete()
        );
    }
}
