//! Helpers for the end-to-end tests: a stack of real `softarm` processes in a namespace and a
//! folder of its own, so tests run in parallel without crosstalk.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use softarm_method::cacla::{CaclaMtl, PretrainConfig, pretrain};
use softarm_method::pcc::ArmGeometry;
use softarm_method::rbf::{NetworkConfig, RbfNetwork};
use softarm_method::skill::{DemoRecipe, demonstrations, forward_data, train_primitives};
use softarm_model::bundle::Model;
use softarm_model::config::DEFAULT;

pub const BIN: &str = env!("CARGO_BIN_EXE_softarm");
pub const DEMO_WAYPOINTS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/config/waypoints/demo.toml");

pub struct TestStack {
    pub dir: PathBuf,
    pub config: PathBuf,
    pub namespace: String,
    pub up: Option<Child>,
}

/// The embedded default with a namespace, folders and quick training settings of the test's own.
pub fn config_text(dir: &Path, namespace: &str) -> String {
    let mut doc: toml::Table = toml::from_str(DEFAULT).unwrap();
    let mut set = |section: &str, key: &str, v: toml::Value| {
        doc[section].as_table_mut().unwrap().insert(key.into(), v);
    };
    set("robot", "namespace", namespace.into());
    set(
        "model",
        "dir",
        dir.join("model").display().to_string().into(),
    );
    set(
        "state",
        "dir",
        dir.join("state").display().to_string().into(),
    );
    set("demonstrations", "demos_per_class", 3.into());
    set("demonstrations", "duration_s", 1.5.into());
    set("pretrain", "budget_s", 2.0.into());
    toml::to_string(&doc).unwrap()
}

/// A model bundle made straight from the kinematic plant, in a second or two.
pub fn quick_model(dir: &Path) {
    let arm = ArmGeometry::default();
    let recipe = DemoRecipe {
        demos_per_class: 6,
        ..Default::default()
    };
    let recs = demonstrations(&arm, &recipe, 5);
    let (actuation, task) = train_primitives(&recs, 15).unwrap();
    let (a, p) = forward_data(&recs);
    let forward = RbfNetwork::fit(
        &a,
        &p,
        &NetworkConfig {
            centres: 80,
            ..Default::default()
        },
    )
    .unwrap();
    let mut learner = CaclaMtl::new(Default::default()).unwrap();
    learner.imitate(&p, &a, 2);
    pretrain(
        &mut learner,
        &forward,
        &p,
        &PretrainConfig {
            max_epochs: 300,
            ..Default::default()
        },
        |_| true,
    );
    Model {
        actuation,
        task,
        forward,
        learner: learner.state(),
        demo_duration_s: recipe.duration_s,
        id: String::new(),
    }
    .write(dir)
    .unwrap();
}

impl TestStack {
    /// A folder, config and namespace for test `name`; with a model bundle if asked.
    pub fn new(name: &str, with_model: bool) -> Self {
        let pid = std::process::id();
        let dir = std::env::temp_dir().join(format!("softarm-test-{name}-{pid}"));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let namespace = format!("softarm/test-{name}-{pid}");
        let config = dir.join("softarm.toml");
        std::fs::write(&config, config_text(&dir, &namespace)).unwrap();
        if with_model {
            quick_model(&dir.join("model"));
        }
        Self {
            dir,
            config,
            namespace,
            up: None,
        }
    }

    /// `softarm <args> --config <this stack's config>`.
    pub fn run(&self, args: &[&str]) -> Output {
        Command::new(BIN)
            .args(args)
            .arg("--config")
            .arg(&self.config)
            .env("RUST_LOG", "warn")
            .output()
            .unwrap()
    }

    pub fn spawn(&self, args: &[&str]) -> Child {
        let log = std::fs::File::create(self.dir.join(format!("{}.log", args[0]))).unwrap();
        Command::new(BIN)
            .args(args)
            .arg("--config")
            .arg(&self.config)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap()
    }

    /// Starts `softarm up` and waits until the controller is IDLE and every process is alive.
    pub fn up(&mut self) {
        self.up = Some(self.spawn(&["up"]));
        let model = self.dir.join("model/model.toml").exists();
        self.wait_status("the stack to come up", Duration::from_secs(60), |s| {
            let alive = s["alive"].as_array().map(|a| a.len()).unwrap_or(0) >= 3;
            let c = &s["controller"];
            alive && c["state"] == "IDLE" && (!model || c["model_loaded"] == true)
        });
    }

    pub fn status(&self) -> serde_json::Value {
        let out = self.run(&["status", "--json"]);
        serde_json::from_slice(&out.stdout).unwrap_or(serde_json::Value::Null)
    }

    pub fn wait_status(
        &self,
        what: &str,
        limit: Duration,
        ok: impl Fn(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        let start = Instant::now();
        loop {
            let s = self.status();
            if ok(&s) {
                return s;
            }
            assert!(
                start.elapsed() < limit,
                "waited {limit:?} for {what}; last status {s}\n{}",
                self.logs()
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// Stats lines (JSON) of set `set_id` seen so far.
    pub fn stats(&self, set_id: u64) -> Vec<serde_json::Value> {
        let out = self.run(&["stats", "--json"]);
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .filter(|v| v["set_id"] == set_id)
            .collect()
    }

    pub fn wait_stats(
        &self,
        set_id: u64,
        executions: usize,
        limit: Duration,
    ) -> Vec<serde_json::Value> {
        let start = Instant::now();
        loop {
            let s = self.stats(set_id);
            if s.len() >= executions {
                return s;
            }
            assert!(
                start.elapsed() < limit,
                "waited {limit:?} for {executions} executions, got {}\n{}",
                s.len(),
                self.logs()
            );
            std::thread::sleep(Duration::from_millis(500));
        }
    }

    /// Submits a way-point file; (exit code, stdout, stderr).
    pub fn submit(&self, file: &Path, executions: u32) -> (i32, String, String) {
        let out = self.run(&[
            "submit",
            file.to_str().unwrap(),
            "--executions",
            &executions.to_string(),
        ]);
        (
            out.status.code().unwrap_or(-1),
            String::from_utf8_lossy(&out.stdout).to_string(),
            String::from_utf8_lossy(&out.stderr).to_string(),
        )
    }

    /// The pids of `up`'s children, by the role in their command line.
    pub fn children(&self) -> Vec<(String, i32)> {
        let up = self.up.as_ref().expect("up is running").id() as i32;
        children_of(up)
    }

    pub fn logs(&self) -> String {
        std::fs::read_to_string(self.dir.join("up.log")).unwrap_or_default()
    }

    /// SIGTERM to `up` and wait for it.
    pub fn stop(&mut self) -> Option<std::process::ExitStatus> {
        let mut up = self.up.take()?;
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(up.id() as i32),
            nix::sys::signal::Signal::SIGTERM,
        );
        let start = Instant::now();
        loop {
            if let Ok(Some(s)) = up.try_wait() {
                return Some(s);
            }
            if start.elapsed() > Duration::from_secs(20) {
                let _ = up.kill();
                return up.wait().ok();
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for TestStack {
    fn drop(&mut self) {
        self.stop();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Live processes whose parent is `parent`: (role from the command line, pid).
pub fn children_of(parent: i32) -> Vec<(String, i32)> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
            continue;
        };
        // Fields after the command name in parentheses: state, ppid, ...
        let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r.to_string()) else {
            continue;
        };
        let fields: Vec<&str> = rest.split_whitespace().collect();
        if fields.len() > 2 && fields[1].parse::<i32>() == Ok(parent) && fields[0] != "Z" {
            let cmd = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
            let args: Vec<String> = cmd
                .split(|b| *b == 0)
                .map(|a| String::from_utf8_lossy(a).to_string())
                .collect();
            out.push((args.get(1).cloned().unwrap_or_default(), pid));
        }
    }
    out.sort();
    out
}

pub fn alive(pid: i32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Ok(stat) => stat
            .rsplit_once(')')
            .map(|(_, r)| !r.trim_start().starts_with('Z'))
            .unwrap_or(false),
        Err(_) => false,
    }
}

/// The set id from `softarm submit`'s "accepted: set N".
pub fn set_id(stdout: &str) -> u64 {
    stdout
        .trim()
        .strip_prefix("accepted: set ")
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("not accepted: {stdout}"))
}
