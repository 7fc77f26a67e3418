//! `softarm up`: the stack's processes as children in the foreground. A child that dies is
//! reported and restarted with back-off; SIGINT or SIGTERM stops them all (SIGTERM, then SIGKILL
//! after a grace period) and leaves no process behind.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

struct Process {
    role: String,
    /// Arguments of this child only, after the common ones.
    extra: Vec<String>,
    child: Option<Child>,
    restarts: u32,
    /// When a dead child may start again.
    next_start: Instant,
    /// It refused its config (exit 78): starting it again cannot help.
    given_up: bool,
    started: Instant,
}

impl Process {
    /// What a slot holds while its process is taken out to be (re)started.
    fn vacant() -> Self {
        Self {
            role: String::new(),
            extra: Vec::new(),
            child: None,
            restarts: 0,
            next_start: Instant::now(),
            given_up: false,
            started: Instant::now(),
        }
    }
}

/// Children of one stack, all started with the same `--config` / `--namespace` arguments.
pub struct Supervisor {
    exe: PathBuf,
    common: Vec<String>,
    env: Vec<(String, String)>,
    processes: Vec<Process>,
}

impl Supervisor {
    pub fn new(common: Vec<String>, env: Vec<(String, String)>) -> anyhow::Result<Self> {
        let exe = std::env::current_exe().context("finding my own executable")?;
        Ok(Self {
            exe,
            common,
            env,
            processes: Vec::new(),
        })
    }

    /// Starts `role` (`softarm <role> ...`) and keeps it running.
    pub fn add(&mut self, role: &str) -> anyhow::Result<()> {
        self.add_with(role, Vec::new())
    }

    /// Starts `role` with arguments of its own (`softarm sim ... --scenario S`).
    pub fn add_with(&mut self, role: &str, extra: Vec<String>) -> anyhow::Result<()> {
        let mut p = Process {
            role: role.to_string(),
            extra,
            child: None,
            restarts: 0,
            next_start: Instant::now(),
            given_up: false,
            started: Instant::now(),
        };
        self.spawn(&mut p)?;
        self.processes.push(p);
        Ok(())
    }

    fn spawn(&self, p: &mut Process) -> anyhow::Result<()> {
        let mut cmd = Command::new(&self.exe);
        cmd.arg(&p.role)
            .args(&self.common)
            .args(&p.extra)
            .stdin(Stdio::null())
            .stderr(Stdio::piped());
        for (k, v) in &self.env {
            cmd.env(k, v);
        }
        let mut child = cmd
            .spawn()
            .with_context(|| format!("starting {}", p.role))?;
        // Each line a child logs goes to our stderr with its role in front.
        if let Some(err) = child.stderr.take() {
            let role = p.role.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(err).lines().map_while(Result::ok) {
                    let _ = writeln!(std::io::stderr(), "[{role}] {line}");
                }
            });
        }
        if URGENT.contains(&p.role.as_str()) || softarm_ipc::Driver::named(&p.role).is_some() {
            raise_priority(child.id(), &p.role);
        }
        p.child = Some(child);
        p.started = Instant::now();
        Ok(())
    }

    /// Reaps dead children and restarts them when their back-off has passed.
    pub fn poll(&mut self) {
        for i in 0..self.processes.len() {
            let p = &mut self.processes[i];
            if let Some(child) = p.child.as_mut()
                && let Ok(Some(status)) = child.try_wait()
            {
                p.child = None;
                if status.code() == Some(softarm_config::EXIT_CONFIG.into()) {
                    // As the systemd units' RestartPreventExitStatus=.
                    eprintln!(
                        "softarm up: {} refused its config ({status}); not restarting it: fix \
                         the config and start the stack again",
                        p.role
                    );
                    p.given_up = true;
                    continue;
                }
                // A child that ran a minute was healthy: its back-off starts over.
                if p.started.elapsed() > Duration::from_secs(60) {
                    p.restarts = 0;
                }
                let backoff = Duration::from_secs(1 << p.restarts.min(5));
                eprintln!(
                    "softarm up: {} exited ({status}); restarting in {} s",
                    p.role,
                    backoff.as_secs()
                );
                p.restarts += 1;
                p.next_start = Instant::now() + backoff;
            }
            let p = &self.processes[i];
            if p.child.is_none() && !p.given_up && Instant::now() >= p.next_start {
                let mut p = std::mem::replace(&mut self.processes[i], Process::vacant());
                if let Err(e) = self.spawn(&mut p) {
                    eprintln!("softarm up: {e}");
                    p.next_start = Instant::now() + Duration::from_secs(5);
                }
                self.processes[i] = p;
            }
        }
    }

    /// SIGTERM to every child, SIGKILL to those still there after `grace`; waits for all.
    pub fn stop(&mut self, grace: Duration) {
        for p in &self.processes {
            if let Some(c) = &p.child {
                let _ = kill(Pid::from_raw(c.id() as i32), Signal::SIGTERM);
            }
        }
        let deadline = Instant::now() + grace;
        for p in &mut self.processes {
            reap(p, deadline);
        }
    }

    /// Stops `role` (SIGTERM, SIGKILL after `grace`) and starts it again with `extra` as its
    /// own arguments.
    pub fn restart_with(
        &mut self,
        role: &str,
        extra: Vec<String>,
        grace: Duration,
    ) -> anyhow::Result<()> {
        let i = self
            .processes
            .iter()
            .position(|p| p.role == role)
            .with_context(|| format!("no {role} to restart"))?;
        let mut p = std::mem::replace(&mut self.processes[i], Process::vacant());
        if let Some(c) = &p.child {
            let _ = kill(Pid::from_raw(c.id() as i32), Signal::SIGTERM);
        }
        reap(&mut p, Instant::now() + grace);
        p.extra = extra;
        p.given_up = false;
        let spawned = self.spawn(&mut p);
        self.processes[i] = p;
        spawned
    }

    /// Process ids of the running children, by role.
    pub fn pids(&self) -> Vec<(String, u32)> {
        self.processes
            .iter()
            .filter_map(|p| p.child.as_ref().map(|c| (p.role.clone(), c.id())))
            .collect()
    }
}

/// Waits for a signalled child until `deadline`, then kills it.
fn reap(p: &mut Process, deadline: Instant) {
    if let Some(c) = p.child.as_mut() {
        loop {
            match c.try_wait() {
                Ok(Some(_)) | Err(_) => break,
                Ok(None) if Instant::now() >= deadline => {
                    eprintln!("softarm up: {} did not stop in time: killing it", p.role);
                    let _ = c.kill();
                    let _ = c.wait();
                    break;
                }
                Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            }
        }
    }
    p.child = None;
}

impl Drop for Supervisor {
    fn drop(&mut self) {
        self.stop(Duration::from_secs(5));
    }
}

/// Resident memory (VmRSS, KiB) of process `pid` (a number, or "self"), from /proc.
pub fn rss_kib(pid: &str) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}

/// Processes whose answers have a deadline: the learner's estimate and the controller's
/// replanning must be in force before the point's group starts, also on a busy machine; the
/// drivers write goals and read the motors and the tracker every period (a tendon driver left
/// waiting for a CPU on a loaded machine fell behind its bus by hundreds of cycles): every
/// driver of [`softarm_ipc::DRIVERS`], and these.
const URGENT: [&str; 2] = ["controller", "learner"];
/// Their nice value (the systemd units set the same).
const URGENT_NICE: i32 = -5;

/// Puts `pid` ahead of ordinary work, where allowed (root or CAP_SYS_NICE); else it runs at
/// the default, and says so once in the log.
fn raise_priority(pid: u32, role: &str) {
    // SAFETY: setpriority reads its arguments only.
    let r = unsafe {
        nix::libc::setpriority(nix::libc::PRIO_PROCESS, pid as nix::libc::id_t, URGENT_NICE)
    };
    static SAID: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    if r != 0 && !SAID.swap(true, std::sync::atomic::Ordering::Relaxed) {
        eprintln!(
            "softarm up: nice {URGENT_NICE} for the {role} refused (needs CAP_SYS_NICE): it and \
             the others run at the default priority"
        );
    }
}

/// The sim's own arguments for a scenario.
pub fn sim_args(scenario: Option<&str>) -> Vec<String> {
    scenario
        .map(|s| vec!["--scenario".to_string(), s.to_string()])
        .unwrap_or_default()
}

/// The optional processes `softarm up` starts beside the stack, as the config enables them.
#[derive(Debug, Clone, Copy, Default)]
pub struct Extras {
    /// `softarm view` (`[view] enabled`).
    pub view: bool,
    /// `softarm ros2` (`[ros2] enabled`).
    pub ros2: bool,
}

/// `softarm up [--scenario NAME|FILE]` on `config`: [`run`] with the drivers and the extras it
/// configures, `common` the arguments that start each child on the same stack. A scenario is
/// checked on the config's arm first: refused here, before anything starts, rather than by a
/// restarting sim.
pub fn run_config(
    common: Vec<String>,
    config: &softarm_config::Config,
    scenario: Option<&str>,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    if let Some(s) = scenario {
        softarm_config::scenario::Scenario::resolve(s)?.check_on(config)?;
    }
    let extras = Extras {
        view: config.view.enabled,
        ros2: config.ros2.enabled,
    };
    run(common, &config.robot.drivers, extras, scenario, stop)
}

/// Runs controller, learner, the configured drivers and the `extras` (the live view, the ROS 2
/// bridge) until SIGINT or SIGTERM; a scenario goes to the sim only.
pub fn run(
    common: Vec<String>,
    drivers: &[String],
    extras: Extras,
    scenario: Option<&str>,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let mut sup = Supervisor::new(common, Vec::new())?;
    for role in drivers
        .iter()
        .map(String::as_str)
        .chain(["controller", "learner"])
        .chain(extras.view.then_some("view"))
        .chain(extras.ros2.then_some("ros2"))
    {
        let extra = if role == "sim" {
            sim_args(scenario)
        } else {
            Vec::new()
        };
        sup.add_with(role, extra)?;
    }
    eprintln!(
        "softarm up: {} running; Ctrl-C stops them",
        sup.pids()
            .iter()
            .map(|(r, p)| format!("{r} ({p})"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(50));
        sup.poll();
    }
    eprintln!("softarm up: stopping");
    sup.stop(Duration::from_secs(5));
    Ok(())
}
