//! Both emulators on pseudo-terminals, coupled through the arm: the tracker reports where the
//! piecewise-constant-curvature model of `[arm]` puts the end effector for the actuation the
//! emulated motors stand at (through the same [`Mapping`] and [`Frame`] the drivers use), so
//! the loop closes through the real drivers exactly as it does on the arm.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use anyhow::Context;
use softarm_config::Config;
use softarm_config::hardware::{Frame, Mapping};
use softarm_method::space::ACTUATORS;

use crate::bird::{self, BirdFaults};
use crate::dynamixel;
use crate::pty::Pty;

/// The two devices, running on their own threads until [`Rig::stop`] (or drop).
pub struct Rig {
    tendon_path: std::path::PathBuf,
    tracker_path: std::path::PathBuf,
    /// The motor bus: tests read goals and torque from it and inject faults.
    pub bus: Arc<Mutex<dynamixel::Bus>>,
    /// The tracker's fault switches.
    pub tracker_faults: Arc<BirdFaults>,
    /// Records the tracker has sent.
    pub records: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<std::io::Result<()>>>,
}

impl Rig {
    /// Starts both devices for `config`'s `[tendon]` and `[tracker]`, the motors standing at
    /// `initial` (normalised actuation), torque off.
    pub fn start(config: &Config, initial: f64) -> anyhow::Result<Self> {
        let tendon = config
            .tendon
            .as_ref()
            .context("the config has no [tendon] section to emulate")?;
        let tracker = config
            .tracker
            .as_ref()
            .context("the config has no [tracker] section to emulate")?;
        let mapping = Mapping::new(tendon, &config.arm);
        let frame = Frame::new(tracker);
        let arm = config.arm;

        let motors = (0..ACTUATORS)
            .map(|i| dynamixel::Motor::new(tendon.ids[i], mapping.ticks(i, initial)))
            .collect();
        let bus = Arc::new(Mutex::new(dynamixel::Bus::with_motors(motors)));
        let stop = Arc::new(AtomicBool::new(false));
        let tendon_pty = Pty::open().context("opening a pseudo-terminal for the motor bus")?;
        let tracker_pty = Pty::open().context("opening a pseudo-terminal for the tracker")?;
        let tendon_path = tendon_pty.path().to_path_buf();
        let tracker_path = tracker_pty.path().to_path_buf();

        let mut threads = Vec::new();
        {
            let (bus, stop) = (bus.clone(), stop.clone());
            threads.push(
                std::thread::Builder::new()
                    .name("emulated motors".into())
                    .spawn(move || dynamixel::serve(tendon_pty, bus, stop))?,
            );
        }
        let tracker_faults = Arc::new(BirdFaults::default());
        let records = Arc::new(AtomicU64::new(0));
        {
            let (bus, stop, faults, records) = (
                bus.clone(),
                stop.clone(),
                tracker_faults.clone(),
                records.clone(),
            );
            let ids = tendon.ids;
            let pose = move || {
                let ticks: [i32; ACTUATORS] = {
                    let b = bus.lock().unwrap();
                    std::array::from_fn(|i| b.motor(ids[i]).map_or(0, |m| m.present_position()))
                };
                let a = std::array::from_fn(|i| mapping.actuation(i, ticks[i]));
                (frame.to_tracker(arm.position(&a)), [0.0; 3])
            };
            let (rate, scale) = (tracker.rate_hz, tracker.full_scale_in);
            threads.push(
                std::thread::Builder::new()
                    .name("emulated tracker".into())
                    .spawn(move || {
                        bird::serve(tracker_pty, rate, scale, pose, faults, stop, records)
                    })?,
            );
        }
        Ok(Self {
            tendon_path,
            tracker_path,
            bus,
            tracker_faults,
            records,
            stop,
            threads,
        })
    }

    /// The motor bus's device (`/dev/pts/N`).
    pub fn tendon_path(&self) -> &std::path::Path {
        &self.tendon_path
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
        let mut result = Ok(());
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
