//! The end-to-end harness: a stack of real `softarm` processes in a folder and an iceoryx2
//! namespace of its own (the product's sandbox, `processes/stack/src/sandbox.rs::Sandbox`, as
//! `softarm demo` has), so tests run in parallel without crosstalk. The binary's path comes from
//! the caller: `env!("CARGO_BIN_EXE_softarm")` (and `softarm-rig`'s, for `emulate`) exists only
//! in the root package's tests.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use softarm_config::Config;
use softarm_stack::sandbox::Sandbox;

use crate::config::{config_text, hardware_config_text, with_overrides};
use crate::model::quick_model;
use crate::process::{Guard, eventually, output};
use crate::turns::{Devices, DevicesTurn, StackTurn};

/// The demo way-point set.
pub const DEMO_WAYPOINTS: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../config/waypoints/demo.toml"
);

/// A test's own stack: `dir` holds its config (`config`), model, state and logs; `up` is
/// `softarm up` once started. Dropping it stops `up` (and kills what is left of its process
/// group) and removes `dir` (kept when the test failed).
pub struct TestStack {
    pub bin: PathBuf,
    pub dir: PathBuf,
    pub config: PathBuf,
    pub namespace: String,
    pub up: Option<Guard>,
    /// The namespace and folder; before the turns, so the folder goes before they are given back.
    sandbox: Sandbox,
    /// The stack's place on the machine, and its devices' turn if it has emulated devices
    /// ([`crate::turns`]); given back after the stack stopped.
    _turn: StackTurn,
    devices: Option<DevicesTurn>,
}

impl TestStack {
    /// A folder, config and namespace for test `name`, run with the `softarm` binary `bin`;
    /// with a quick model bundle if asked.
    pub fn new(bin: impl AsRef<Path>, name: &str, with_model: bool) -> Self {
        Self::with_config(bin, name, with_model, config_text)
    }

    /// [`TestStack::new`] with the config `text(dir, namespace)` gives.
    pub fn with_config(
        bin: impl AsRef<Path>,
        name: &str,
        with_model: bool,
        text: impl FnOnce(&Path, &str) -> String,
    ) -> Self {
        let turn = StackTurn::take();
        // Numbered too: two tests of one name side by side would share a namespace.
        static STACKS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = STACKS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let pid = std::process::id();
        // Folder `<tmp>/softarm-test-...`, namespace `softarm/test-...`.
        let sandbox = Sandbox::new(&format!("test-{name}-{pid}-{n}"), text, &[])
            .unwrap_or_else(|e| panic!("the stack of {name}: {e:#}"));
        let dir = sandbox.dir().to_path_buf();
        if with_model {
            quick_model(&dir.join("model"));
        }
        Self {
            bin: bin.as_ref().to_path_buf(),
            dir,
            config: sandbox.config_path.clone(),
            namespace: sandbox.namespace.as_str().to_string(),
            up: None,
            sandbox,
            _turn: turn,
            devices: None,
        }
    }

    /// The real arm's stack without the arm, as a user runs it: a stack on the hardware config
    /// (with a quick model), `softarm-rig emulate` (the binary `rig`) started from it (stdout
    /// piped: it prints the device paths; its log in the stack's folder), and the stack switched
    /// to the config the emulator writes, naming its devices. It waits for its `devices` turn
    /// first.
    pub fn emulated(
        bin: impl AsRef<Path>,
        rig: impl AsRef<Path>,
        name: &str,
        devices: Devices,
    ) -> (Self, Guard) {
        let turn = DevicesTurn::take(devices);
        let mut s = Self::with_config(bin, name, true, |dir, ns| {
            hardware_config_text(dir, ns, Path::new("/dev/null"), Path::new("/dev/null"))
        });
        let emulated = s.dir.join("emulated.toml");
        let log = std::fs::File::create(s.dir.join("emulate.log")).unwrap();
        let emulator = Guard::spawn(
            Command::new(rig.as_ref())
                .args(["emulate", "--config"])
                .arg(&s.config)
                .arg("--write-config")
                .arg(&emulated)
                .stdout(Stdio::piped())
                .stderr(log),
        );
        eventually("the emulated config", Duration::from_secs(30), || {
            emulated.exists().then_some(())
        });
        s.config = emulated;
        s.devices = Some(turn);
        (s, emulator)
    }

    /// A stack for the real arm's code path: the hardware config with quick time-outs (hold
    /// after 150 ms without a setpoint, torque off after 2 s) and the devices `devices` starts
    /// for it (emulators) from the config's `[tendon]` and `[tracker]`. `devices` gives back
    /// what it started and the devices' paths (tendon, tracker), which the config then names.
    /// It waits for its `turn` first.
    pub fn with_devices<D>(
        bin: impl AsRef<Path>,
        name: &str,
        turn: Devices,
        devices: impl FnOnce(&Config) -> (D, PathBuf, PathBuf),
    ) -> (Self, Config, D) {
        Self::with_devices_for(bin, name, turn, |text| text, devices)
    }

    /// [`TestStack::with_devices`] on the hardware config as `adapt` changes it (another arm
    /// and its motors, say).
    pub fn with_devices_for<D>(
        bin: impl AsRef<Path>,
        name: &str,
        turn: Devices,
        adapt: impl Fn(String) -> String,
        devices: impl FnOnce(&Config) -> (D, PathBuf, PathBuf),
    ) -> (Self, Config, D) {
        let bin = bin.as_ref();
        let turn = DevicesTurn::take(turn);
        // The devices need the config's [tendon] and [tracker]; the ports are filled in after.
        let probe = Self::with_config(bin, name, false, |dir, ns| {
            adapt(hardware_config_text(
                dir,
                ns,
                Path::new("/dev/null"),
                Path::new("/dev/null"),
            ))
        });
        let c = Config::load(&probe.config).unwrap();
        let (started, tendon, tracker) = devices(&c);
        drop(probe);
        let mut s = Self::with_config(bin, name, false, |dir, ns| {
            let text = adapt(hardware_config_text(dir, ns, &tendon, &tracker));
            with_overrides(
                &text,
                &[
                    ("tendon.hold_after_ms", 150.0.into()),
                    ("tendon.torque_off_after_ms", 2000.0.into()),
                ],
            )
        });
        let c = Config::load(&s.config).unwrap();
        s.devices = Some(turn);
        (s, c, started)
    }

    /// Puts a quick model bundle in the stack's model folder (a stack made by
    /// [`TestStack::with_devices`] has none).
    pub fn add_quick_model(&self) {
        quick_model(&self.dir.join("model"));
    }

    /// `softarm` without arguments (nor this stack's config).
    pub fn command(&self) -> Command {
        Command::new(&self.bin)
    }

    /// `softarm <args> --config <this stack's config>`, run to its end ([`output`]).
    pub fn run(&self, args: &[&str]) -> Output {
        output(
            self.command()
                .args(args)
                .arg("--config")
                .arg(&self.config)
                .env("RUST_LOG", "warn"),
        )
    }

    /// `softarm <args> --config <this stack's config>` started, logging to `<args[0]>.log`.
    pub fn spawn(&self, args: &[&str]) -> Guard {
        let log = std::fs::File::create(self.dir.join(format!("{}.log", args[0]))).unwrap();
        Guard::spawn(
            self.command()
                .args(args)
                .arg("--config")
                .arg(&self.config)
                .env(
                    "RUST_LOG",
                    std::env::var("SOFTARM_TEST_LOG").unwrap_or_else(|_| "info".into()),
                )
                .stdout(Stdio::null())
                .stderr(log),
        )
    }

    /// Starts `softarm up` and waits until the controller is IDLE and every process is alive.
    pub fn up(&mut self) {
        self.up_with(&[]);
    }

    /// [`TestStack::up`] with more arguments for `softarm up` (e.g. `--scenario NAME`).
    pub fn up_with(&mut self, args: &[&str]) {
        let mut all = vec!["up"];
        all.extend_from_slice(args);
        self.up = Some(self.spawn(&all));
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

    /// The executions (JSON) of set `set_id` seen so far.
    pub fn stats(&self, set_id: u64) -> Vec<serde_json::Value> {
        let out = self.run(&["stats", "--json"]);
        match serde_json::from_slice::<serde_json::Value>(&out.stdout) {
            Ok(serde_json::Value::Array(all)) => {
                all.into_iter().filter(|v| v["set_id"] == set_id).collect()
            }
            _ => Vec::new(),
        }
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

    /// Submits a way-point file and waits until the controller executes it; its set id.
    pub fn executing(&self, file: &Path, executions: u32) -> u64 {
        let (code, out, err) = self.submit(file, executions);
        assert_eq!(code, 0, "{out}{err}");
        self.wait_status("EXECUTE", Duration::from_secs(30), |st| {
            st["controller"]["state"] == "EXECUTE"
        });
        set_id(&out)
    }

    /// The pids of `up`'s children, by the role in their command line.
    pub fn children(&self) -> Vec<(String, i32)> {
        let up = self.up.as_ref().expect("up is running").id() as i32;
        children_of(up)
    }

    pub fn logs(&self) -> String {
        std::fs::read_to_string(self.dir.join("up.log")).unwrap_or_default()
    }

    /// SIGTERM to `up` and wait for it; what is left of its group is killed after.
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
    /// Stops the stack; its folder goes with the sandbox, but is kept (and it says where) when
    /// the test failed: its logs and state are what tells why.
    fn drop(&mut self) {
        self.stop();
        if std::thread::panicking() {
            self.sandbox.keep();
            eprintln!(
                "the stack's folder is kept for inspection: {}",
                self.dir.display()
            );
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_ids_are_read_from_submits_answer() {
        assert_eq!(set_id("accepted: set 42\n"), 42);
        let refused = std::panic::catch_unwind(|| set_id("rejected: late"));
        assert!(refused.is_err());
    }

    #[test]
    fn children_are_found_by_parent_and_role_and_their_death_is_seen() {
        let me = std::process::id() as i32;
        assert!(alive(me));
        let mut child = Command::new("sleep").arg("30").spawn().unwrap();
        let pid = child.id() as i32;
        // Right after the spawn the child may still be in exec, its command line empty; another
        // test of this binary may have a `sleep 30` of its own: wait for this one's.
        let mut mine = children_of(me);
        for _ in 0..5000 {
            if mine.contains(&("30".to_string(), pid)) {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
            mine = children_of(me);
        }
        assert!(mine.contains(&("30".to_string(), pid)), "{pid}: {mine:?}");
        assert!(alive(pid));
        child.kill().unwrap();
        child.wait().unwrap();
        assert!(!alive(pid));
        assert!(!children_of(me).iter().any(|c| c.1 == pid));
    }

    #[test]
    fn a_stack_has_its_own_folder_config_and_namespace_and_cleans_up() {
        let dir;
        {
            let s = TestStack::new("/nonexistent/softarm", "support-self", false);
            dir = s.dir.clone();
            assert!(s.namespace.starts_with("softarm/test-support-self-"));
            let text = std::fs::read_to_string(&s.config).unwrap();
            assert!(text.contains(&s.namespace), "{text}");
            assert!(!s.dir.join("model/model.toml").exists());
            assert!(Path::new(DEMO_WAYPOINTS).exists());
        }
        assert!(!dir.exists());
    }
}
