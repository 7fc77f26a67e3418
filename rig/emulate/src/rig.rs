//! Both emulators on pseudo-terminals, coupled through the arm: the tracker reports where the
//! piecewise-constant-curvature model of `[arm]` puts the end effector for the actuation the
//! emulated motors stand at (through the same [`Mapping`] and [`Frame`] the drivers use), so
//! the loop closes through the real drivers exactly as it does on the arm. Given physics of
//! its own (a MuJoCo model, `[sim.mujoco]`), the motors drive that instead, stepped on a clock
//! of its own ([`Rig::start_with`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use anyhow::Context;
use softarm_config::Config;
use softarm_config::hardware::{Frame, Mapping};
use softarm_space::MAX_ACTUATORS;

use crate::bird::{self, BirdCounts, BirdFaults};
use crate::canary::Canary;
use crate::dynamixel;
use crate::pty::Pty;
use softarm_kinematics::pcc;
use softarm_sim::plant::Physics;

type Pose = Arc<dyn Fn() -> ([f64; 3], [f64; 3]) + Send + Sync>;

/// The tracker's emulator: what it needs to start (again) and the thread serving it.
struct Tracker {
    rate_hz: f64,
    full_scale_in: f64,
    pose: Pose,
    /// Stops this emulator alone (the bus has its own flag).
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<std::io::Result<()>>>,
}

/// The two devices, running on their own threads until [`Rig::stop`] (or drop).
pub struct Rig {
    /// Each motor bus's device, `tendon.port`'s first.
    tendon_paths: Vec<std::path::PathBuf>,
    tracker_path: std::path::PathBuf,
    /// The motor bus of `tendon.port`: tests read goals and torque from it and inject faults.
    pub bus: Arc<Mutex<dynamixel::Bus>>,
    /// Every motor bus, `tendon.port`'s first, then each `tendon.extra_bus`.
    pub buses: Vec<Arc<Mutex<dynamixel::Bus>>>,
    /// The tracker's fault switches.
    pub tracker_faults: Arc<BirdFaults>,
    /// What the tracker has done: records sent, opens heard.
    pub tracker_counts: Arc<BirdCounts>,
    /// The kernel's pty path, watched: what a driver did while it was stalled is the machine's.
    pub canary: Canary,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<std::io::Result<()>>>,
    tracker: Tracker,
}

impl Rig {
    /// Starts both devices for `config`'s `[tendon]` and `[tracker]`, the motors standing at
    /// `initial` (normalised actuation), torque off, at their factory settings (a Return Delay
    /// Time of 500 µs), on lines at `tendon.baud`.
    pub fn start(config: &Config, initial: f64) -> anyhow::Result<Self> {
        Self::start_with(config, initial, None)
    }

    /// [`Rig::start`], the motors driving `physics` (stepped every millisecond on a thread of
    /// its own, from where the motors stand) in place of the PCC model, if given.
    pub fn start_with(
        config: &Config,
        initial: f64,
        physics: Option<Box<dyn Physics>>,
    ) -> anyhow::Result<Self> {
        let tendon = config
            .tendon
            .as_ref()
            .context("the config has no [tendon] section to emulate")?;
        let tracker = config
            .tracker
            .as_ref()
            .context("the config has no [tracker] section to emulate")?;
        let layout = config.layout();
        let mapping = Mapping::new(tendon, &layout);
        let frame = Frame::new(tracker);
        let arm = pcc::Arm::of_config(&config.arm).map_err(anyhow::Error::msg)?;
        let n = mapping.motors();
        let stop = Arc::new(AtomicBool::new(false));
        let (mut buses, mut tendon_paths, mut threads) = (Vec::new(), Vec::new(), Vec::new());
        // Which bus and motor id each actuator has.
        let mut motor_of = vec![(0, 0); n];
        for (k, b) in tendon.buses().iter().enumerate() {
            let motors = (b.actuators.iter().zip(&b.tendon.ids))
                .map(|(&i, &id)| dynamixel::Motor::new(id, mapping.ticks(i, initial)))
                .collect();
            for (&i, &id) in b.actuators.iter().zip(&b.tendon.ids) {
                motor_of[i] = (k, id);
            }
            let mut bus = dynamixel::Bus::with_motors(motors);
            bus.set_baud(b.tendon.baud);
            let bus = Arc::new(Mutex::new(bus));
            let pty = Pty::open().context("opening a pseudo-terminal for a motor bus")?;
            tendon_paths.push(pty.path().to_path_buf());
            let (served, stop) = (bus.clone(), stop.clone());
            threads.push(
                std::thread::Builder::new()
                    .name(format!("emulated motors {}", k + 1))
                    .spawn(move || dynamixel::serve(pty, served, stop))?,
            );
            buses.push(bus);
        }
        let actuation = {
            let buses = buses.clone();
            move || {
                let mut a = [0.0; MAX_ACTUATORS];
                for (i, &(k, id)) in motor_of.iter().enumerate() {
                    let b = buses[k].lock().unwrap();
                    let ticks = b.motor(id).map_or(0, |m| m.present_position());
                    a[i] = mapping.actuation(i, ticks);
                }
                a
            }
        };
        if let Some(physics) = physics {
            let tip = Arc::new(Mutex::new([f64::NAN; 3]));
            let (seen, stopping) = (tip.clone(), stop.clone());
            threads.push(
                std::thread::Builder::new()
                    .name("emulated arm".into())
                    .spawn(move || step_physics(physics, n, actuation, &seen, &stopping))?,
            );
            let pose: Pose = Arc::new(move || (frame.to_tracker(*tip.lock().unwrap()), [0.0; 3]));
            return Self::serving(tendon_paths, buses, stop, threads, pose, tracker);
        }
        let pose: Pose = {
            // Where the last actuation put the tip, for an actuation whose arcs the model
            // cannot tell (the motors far outside their strokes).
            let last = Mutex::new([0.0; 3]);
            Arc::new(move || {
                let a = actuation();
                let mut last = last.lock().unwrap();
                if let Ok(p) = arm.pose(&a[..n]) {
                    *last = [p.position.x, p.position.y, p.position.z];
                }
                (frame.to_tracker(*last), [0.0; 3])
            })
        };
        Self::serving(tendon_paths, buses, stop, threads, pose, tracker)
    }

    /// The rig of the motor buses started, its tracker serving `pose`.
    fn serving(
        tendon_paths: Vec<std::path::PathBuf>,
        buses: Vec<Arc<Mutex<dynamixel::Bus>>>,
        stop: Arc<AtomicBool>,
        threads: Vec<JoinHandle<std::io::Result<()>>>,
        pose: Pose,
        tracker: &softarm_config::hardware::TrackerConfig,
    ) -> anyhow::Result<Self> {
        let mut rig = Self {
            tendon_paths,
            tracker_path: std::path::PathBuf::new(),
            bus: buses[0].clone(),
            buses,
            tracker_faults: Arc::new(BirdFaults::default()),
            tracker_counts: Arc::new(BirdCounts::default()),
            canary: Canary::start().context("starting the pty canary")?,
            stop,
            threads,
            tracker: Tracker {
                rate_hz: tracker.rate_hz,
                full_scale_in: tracker.full_scale_in,
                pose,
                stop: Arc::new(AtomicBool::new(false)),
                thread: None,
            },
        };
        rig.start_tracker()?;
        Ok(rig)
    }

    /// Serves the tracker on a new pseudo-terminal.
    fn start_tracker(&mut self) -> anyhow::Result<()> {
        let pty = Pty::open().context("opening a pseudo-terminal for the tracker")?;
        self.tracker_path = pty.path().to_path_buf();
        let t = &mut self.tracker;
        t.stop = Arc::new(AtomicBool::new(false));
        let (faults, stop, counts, pose) = (
            self.tracker_faults.clone(),
            t.stop.clone(),
            self.tracker_counts.clone(),
            t.pose.clone(),
        );
        let (rate, scale) = (t.rate_hz, t.full_scale_in);
        t.thread = Some(
            std::thread::Builder::new()
                .name("emulated tracker".into())
                .spawn(move || {
                    bird::serve(pty, rate, scale, move || pose(), faults, stop, counts)
                })?,
        );
        Ok(())
    }

    /// The tracker's emulator restarted: its pseudo-terminal closed (a driver that has it open
    /// reads a hang-up) and a new one opened, at [`Rig::tracker_path`]. The unit starts over
    /// (not streaming, its defaults); the counts go on.
    pub fn restart_tracker(&mut self) -> anyhow::Result<()> {
        self.stop_tracker().context("the tracker emulator failed")?;
        self.start_tracker()
    }

    fn stop_tracker(&mut self) -> std::io::Result<()> {
        self.tracker.stop.store(true, Ordering::Relaxed);
        match self.tracker.thread.take().map(|t| t.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(std::io::Error::other("the tracker emulator panicked")),
            None => Ok(()),
        }
    }

    /// The device of `tendon.port`'s motor bus (`/dev/pts/N`).
    pub fn tendon_path(&self) -> &std::path::Path {
        &self.tendon_paths[0]
    }

    /// Every motor bus's device, `tendon.port`'s first, then each `tendon.extra_bus`'s.
    pub fn tendon_paths(&self) -> &[std::path::PathBuf] {
        &self.tendon_paths
    }

    /// The tracker's device.
    pub fn tracker_path(&self) -> &std::path::Path {
        &self.tracker_path
    }

    /// Stops both devices; an I/O error of either is returned.
    pub fn stop(mut self) -> std::io::Result<()> {
        self.halt()
    }

    fn halt(&mut self) -> std::io::Result<()> {
        self.stop.store(true, Ordering::Relaxed);
        let mut result = self.stop_tracker();
        for t in self.threads.drain(..) {
            match t.join() {
                Ok(Err(e)) if result.is_ok() => result = Err(e),
                Err(_) => result = Err(std::io::Error::other("an emulator thread panicked")),
                _ => {}
            }
        }
        result
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        let _ = self.halt();
    }
}

/// Steps `physics` every millisecond of the wall clock with the `n` actuations the motors
/// stand at, keeping where it puts the tip in `tip`, until `stop`.
fn step_physics(
    mut physics: Box<dyn Physics>,
    n: usize,
    actuation: impl Fn() -> [f64; MAX_ACTUATORS],
    tip: &Mutex<[f64; 3]>,
    stop: &AtomicBool,
) -> std::io::Result<()> {
    let start = std::time::Instant::now();
    let none = [0.0; MAX_ACTUATORS];
    while !stop.load(Ordering::Relaxed) {
        let a = actuation();
        let t = start.elapsed().as_secs_f64();
        let p = physics.advance(t, &a[..n], &none[..n]);
        *tip.lock().unwrap() = p;
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    Ok(())
}
