//! End to end: an installed stack's operators. The stack runs as a system user of its own (as
//! under systemd); root and a member of its operators' group run the e-stop and its reset, each
//! confirmed by what the controller and the sim then say; anyone else is refused with what to
//! do, and changes nothing. Root using every client first leaves nothing the stack's user
//! cannot open. Needs root (to create the users); CI runs as root.

use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use softarm_ipc::own::{Leftovers, counter_path};
use softarm_test_support::{DEMO_WAYPOINTS, Guard, TestStack, config_text, output, with_overrides};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

/// The test's users: the stack's own, an operator (in its group) and an outsider; removed
/// when dropped, after the stack (declared before it).
struct Users {
    service: String,
    operator: String,
    outsider: String,
}

fn sh(program: &str, args: &[&str]) {
    let out = output(Command::new(program).args(args));
    assert!(out.status.success(), "{program} {args:?}: {out:?}");
}

impl Users {
    fn create() -> Self {
        let id = std::process::id();
        let users = Self {
            service: format!("satest{id}svc"),
            operator: format!("satest{id}op"),
            outsider: format!("satest{id}out"),
        };
        users.remove();
        let system = [
            "--system",
            "--no-create-home",
            "--shell",
            "/usr/sbin/nologin",
        ];
        let mut args = system.to_vec();
        args.extend(["--user-group", &users.service]);
        sh("useradd", &args);
        let mut args = system.to_vec();
        args.extend(["-G", &users.service, &users.operator]);
        sh("useradd", &args);
        let mut args = system.to_vec();
        args.push(&users.outsider);
        sh("useradd", &args);
        users
    }

    fn remove(&self) {
        for u in [&self.operator, &self.outsider, &self.service] {
            let _ = Command::new("userdel").arg(u).output();
        }
        let _ = Command::new("groupdel").arg(&self.service).output();
    }

    fn uid(name: &str) -> (u32, u32) {
        let u = nix::unistd::User::from_name(name).unwrap().unwrap();
        (u.uid.as_raw(), u.gid.as_raw())
    }
}

impl Drop for Users {
    fn drop(&mut self) {
        self.remove();
    }
}

/// `path` owned by `owner`, with `mode`.
fn own(path: &Path, owner: (u32, u32), mode: u32) {
    std::os::unix::fs::chown(path, Some(owner.0), Some(owner.1)).unwrap();
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).unwrap();
}

/// The stack's folder laid out as `softarm install` lays out a host: the binary anyone may run,
/// the operator gate (set-user-ID the stack's user, the group's alone), the state and iceoryx2's
/// folder the user's own; the config's `[host]` naming them.
fn host(s: &mut TestStack, users: &Users) -> PathBuf {
    let service = Users::uid(&users.service);
    std::fs::set_permissions(&s.dir, std::fs::Permissions::from_mode(0o755)).unwrap();
    let bin = s.dir.join("bin/softarm");
    std::fs::create_dir_all(bin.parent().unwrap()).unwrap();
    std::fs::copy(BIN, &bin).unwrap();
    let gate = s.dir.join("libexec/softarm");
    std::fs::create_dir_all(gate.parent().unwrap()).unwrap();
    std::fs::copy(BIN, &gate).unwrap();
    // In this order: a change of owner clears the set-ID bits.
    own(&gate, service, 0o6750);
    let ipc = s.dir.join("run");
    for dir in [s.dir.join("state"), ipc.clone()] {
        std::fs::create_dir_all(&dir).unwrap();
        own(&dir, service, 0o770);
    }
    let text = config_text(&s.dir, &s.namespace)
        + "\n[host]\nuser = \"x\"\ngroup = \"x\"\nipc_root = \"/\"\ngate = \"/\"\n";
    let text = with_overrides(
        &text,
        &[
            ("host.user", users.service.as_str().into()),
            ("host.group", users.service.as_str().into()),
            (
                "host.ipc_root",
                ipc.join("iceoryx2").display().to_string().into(),
            ),
            ("host.gate", gate.display().to_string().into()),
        ],
    );
    std::fs::write(&s.config, text).unwrap();
    // As installed: root's, for root and the operators only.
    own(&s.config, (0, service.1), 0o640);
    s.bin = bin;
    ipc
}

/// `softarm <args> --config <the stack's>` as `user` (root: `None`), with its groups.
fn run_as(s: &TestStack, user: Option<&str>, args: &[&str]) -> Output {
    let mut c = match user {
        Some(u) => {
            let mut c = Command::new("runuser");
            c.args(["-u", u, "--"]).arg(&s.bin);
            c
        }
        None => Command::new(&s.bin),
    };
    output(
        c.args(args)
            .arg("--config")
            .arg(&s.config)
            .env("RUST_LOG", "warn"),
    )
}

fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Starts `softarm up` as the stack's user, as systemd would, and waits until it is IDLE with a
/// model.
fn up_as_service(s: &mut TestStack, users: &Users) {
    let (uid, gid) = Users::uid(&users.service);
    let log = std::fs::File::create(s.dir.join("up.log")).unwrap();
    let child = Guard::spawn(
        Command::new(&s.bin)
            .args(["up", "--config"])
            .arg(&s.config)
            .env("RUST_LOG", "info")
            .uid(uid)
            .gid(gid)
            .stdout(Stdio::null())
            .stderr(log),
    );
    s.up = Some(child);
    s.wait_status("the stack to come up", Duration::from_secs(90), |st| {
        st["alive"].as_array().is_some_and(|a| a.len() >= 3)
            && st["controller"]["state"] == "IDLE"
            && st["controller"]["model_loaded"] == true
    });
}

/// What the controller and the sim say now (as root, which joins as the stack's user).
fn states(s: &TestStack) -> (String, String) {
    let st = s.status();
    (
        st["controller"]["state"]
            .as_str()
            .unwrap_or("?")
            .to_string(),
        st["driver"]["state"].as_str().unwrap_or("?").to_string(),
    )
}

/// Every file and folder under `dir` is `uid`'s.
fn all_owned_by(dir: &Path, uid: u32) -> Vec<String> {
    let mut wrong = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let m = e.metadata().unwrap();
            if m.uid() != uid {
                wrong.push(format!("{} (uid {})", e.path().display(), m.uid()));
            }
            if m.is_dir() {
                todo.push(e.path());
            }
        }
    }
    wrong
}

#[test]
fn root_and_operators_stop_and_release_the_arm_and_anyone_else_is_refused() {
    if !nix::unistd::Uid::effective().is_root() {
        eprintln!("not run: creating the test's users needs root");
        return;
    }
    let users = Users::create();
    let mut shm = crate::shm::Cleanup(None);
    let mut s = TestStack::new(BIN, "operators", true);
    let ipc = host(&mut s, &users);
    shm.0 = Some(ipc.join("iceoryx2"));
    let (service_uid, _) = Users::uid(&users.service);
    up_as_service(&mut s, &users);
    for (role, pid) in s.children() {
        let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
        let uid = status.lines().find(|l| l.starts_with("Uid:")).unwrap();
        assert!(uid.contains(&service_uid.to_string()), "{role}: {uid}");
    }
    assert_eq!(states(&s).0, "IDLE");

    // The operator's own set, in a folder only they may read, is read as them: accepted. An
    // output only they may write is refused before anything is recorded, saying why.
    let own_dir = s.dir.join("operator");
    std::fs::create_dir_all(&own_dir).unwrap();
    let set = own_dir.join("set.toml");
    std::fs::copy(DEMO_WAYPOINTS, &set).unwrap();
    let operator = Users::uid(&users.operator);
    own(&set, operator, 0o600);
    own(&own_dir, operator, 0o700);
    let set = set.to_str().unwrap();
    let out = run_as(
        &s,
        Some(&users.operator),
        &["submit", set, "--executions", "3"],
    );
    assert!(out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("accepted: set"), "{}", text(&out));
    let mine = own_dir.join("run.mcap");
    let args = ["record", "-o", mine.to_str().unwrap(), "--duration", "0.2"];
    let out = run_as(&s, Some(&users.operator), &args);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(
        text(&out).contains(&format!(
            "{}, whom this command runs as, may not write",
            users.service
        )),
        "{}",
        text(&out)
    );

    // Root and the operator each stop the arm and release it, confirmed by both processes.
    for who in [None, Some(users.operator.as_str())] {
        let out = run_as(&s, who, &["estop"]);
        let said = text(&out);
        assert!(out.status.success(), "{who:?}: {said}");
        assert!(
            said.contains("e-stop engaged: controller STOPPED, sim STOPPED"),
            "{who:?}: {said}"
        );
        assert_eq!(states(&s), ("STOPPED".into(), "STOPPED".into()), "{who:?}");
        let out = run_as(&s, who, &["estop", "--reset"]);
        let said = text(&out);
        assert!(out.status.success(), "{who:?}: {said}");
        assert!(
            said.contains("e-stop released: controller IDLE"),
            "{who:?}: {said}"
        );
        let (controller, driver) = states(&s);
        assert_eq!(controller, "IDLE", "{who:?}");
        assert_ne!(driver, "STOPPED", "{who:?}");
    }

    // An outsider is refused, saying what to do, and nothing changes: not the arm, not the latch.
    let latch = s.dir.join("state/estop");
    let before = std::fs::read_to_string(&latch).unwrap();
    let refused = |config: &Path, why: &str| {
        for args in [&["estop"][..], &["estop", "--reset"], &["status"]] {
            let out = output(
                Command::new("runuser")
                    .args(["-u", &users.outsider, "--"])
                    .arg(&s.bin)
                    .args(args)
                    .arg("--config")
                    .arg(config),
            );
            let said = text(&out);
            assert_eq!(out.status.code(), Some(1), "{args:?}: {said}");
            assert!(
                said.contains(why)
                    && said.contains(&format!("usermod -aG {} {}", users.service, users.outsider)),
                "{args:?}: {said}"
            );
            assert_eq!(said.lines().count(), 1, "one line: {said}");
        }
    };
    // The installed config is not theirs to read; nor, were it, the stack theirs to join.
    refused(&s.config, "may not read the stack's config");
    let readable = s.dir.join("readable.toml");
    std::fs::copy(&s.config, &readable).unwrap();
    own(&readable, (0, 0), 0o644);
    refused(&readable, "may not operate this stack");
    assert_eq!(std::fs::read_to_string(&latch).unwrap(), before);
    assert_eq!(states(&s).0, "IDLE");
    let wrong = all_owned_by(&ipc, service_uid);
    assert!(wrong.is_empty(), "not the stack's user's: {wrong:?}");
    // Nor can they write iceoryx2's node counter: the stack's user's alone.
    let prefix = Leftovers::of(&ipc.join("iceoryx2")).unwrap().prefix;
    let counter = counter_path(&prefix);
    let meta = std::fs::metadata(&counter).unwrap();
    assert_eq!((meta.uid(), meta.mode() & 0o777), (service_uid, 0o600));
    let out = output(
        Command::new("runuser")
            .args(["-u", &users.outsider, "--", "sh", "-c"])
            .arg("printf garbage | dd of=\"$1\" conv=notrunc,nocreat status=none")
            .arg("sh")
            .arg(&counter),
    );
    assert!(
        !out.status.success() && text(&out).contains("Permission denied"),
        "{}",
        text(&out)
    );
    // What the operator wrote through the gate is the stack's, group and all, for its group.
    let latch = std::fs::metadata(&latch).unwrap();
    assert_eq!((latch.uid(), latch.gid()), Users::uid(&users.service));
    assert_eq!(latch.mode() & 0o007, 0, "{:o}", latch.mode());
    assert!(s.stop().unwrap().success());

    // Root first: every client on a host where nothing of the stack's iceoryx2 is left (as
    // after a reboot); then the stack's user starts it as if nothing happened.
    std::fs::remove_dir_all(ipc.join("iceoryx2")).unwrap();
    let recording = s.dir.join("state/root.mcap");
    let recording = recording.to_str().unwrap();
    for args in [
        &["status"][..],
        &["stats"],
        &["submit", DEMO_WAYPOINTS],
        &["estop"],
        &["estop", "--reset"],
        &["record", "-o", recording, "--duration", "0.3"],
    ] {
        let out = run_as(&s, None, args);
        assert!(
            !text(&out).contains("InternalError"),
            "{args:?}: {}",
            text(&out)
        );
    }
    let wrong = all_owned_by(&ipc, service_uid);
    assert!(wrong.is_empty(), "root left: {wrong:?}");
    let wrong = all_owned_by(&s.dir.join("state"), service_uid);
    assert!(wrong.is_empty(), "root left: {wrong:?}");
    up_as_service(&mut s, &users);
    let out = run_as(&s, Some(&users.operator), &["estop"]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(states(&s).0, "STOPPED");
    drop(s);
}
