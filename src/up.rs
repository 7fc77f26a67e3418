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
    child: Option<Child>,
    restarts: u32,
    /// When a dead child may start again.
    next_start: Instant,
    started: Instant,
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
        let mut p = Process {
            role: role.to_string(),
            child: None,
            restarts: 0,
            next_start: Instant::now(),
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
                p.child = None;
                p.next_start = Instant::now() + backoff;
            }
            let p = &self.processes[i];
            if p.child.is_none() && Instant::now() >= p.next_start {
                let mut p = std::mem::replace(
                    &mut self.processes[i],
                    Process {
                        role: String::new(),
                        child: None,
                        restarts: 0,
                        next_start: Instant::now(),
                        started: Instant::now(),
                    },
                );
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
    }

    /// Process ids of the running children, by role.
    pub fn pids(&self) -> Vec<(String, u32)> {
        self.processes
            .iter()
            .filter_map(|p| p.child.as_ref().map(|c| (p.role.clone(), c.id())))
            .collect()
    }
}

impl Drop for Supervisor {
    fn drop(&mut self) {
        self.stop(Duration::from_secs(5));
    }
}

/// Runs controller, learner and the configured drivers until SIGINT or SIGTERM.
pub fn run(common: Vec<String>, drivers: &[String], stop: &AtomicBool) -> anyhow::Result<()> {
    let mut sup = Supervisor::new(common, Vec::new())?;
    for role in drivers
        .iter()
        .map(String::as_str)
        .chain(["controller", "learner"])
    {
        sup.add(role)?;
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
