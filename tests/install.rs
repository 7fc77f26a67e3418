//! End to end: `softarm install --root DIR` stages the service install (binary without its
//! debug info, the debug info apart, config, state folder, units) without touching the running
//! system, never overwrites an edited config, and `uninstall` removes what it put there but the
//! config and the state.

use std::path::Path;
use std::process::{Command, Output};

use softarm_test_support::output;

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

fn softarm(args: &[&str], root: &Path) -> Output {
    let out = output(Command::new(BIN).args(args).arg("--root").arg(root));
    assert!(out.status.success(), "{args:?}: {out:?}");
    out
}

/// The names of the sections of the ELF file at `path` (64-bit, little-endian, as x86-64 and
/// aarch64 Linux build it).
fn sections(path: &Path) -> Vec<String> {
    let b = std::fs::read(path).unwrap();
    elf_sections(&b).into_iter().map(|(name, _)| name).collect()
}

/// The sections of an ELF file (64-bit, little-endian): each one's name and where its contents
/// are in `b`.
fn elf_sections(b: &[u8]) -> Vec<(String, std::ops::Range<usize>)> {
    assert!(
        b.starts_with(b"\x7fELF\x02\x01"),
        "not a 64-bit little-endian ELF"
    );
    let n = |at: usize, len: usize| {
        let mut v = [0u8; 8];
        v[..len].copy_from_slice(&b[at..at + len]);
        u64::from_le_bytes(v) as usize
    };
    let (table, size, count, names) = (n(0x28, 8), n(0x3a, 2), n(0x3c, 2), n(0x3e, 2));
    let strings = n(table + names * size + 0x18, 8);
    (0..count)
        .map(|i| {
            let header = table + i * size;
            let at = strings + n(header, 4);
            let end = at + b[at..].iter().position(|c| *c == 0).unwrap();
            let (offset, len) = (n(header + 0x18, 8), n(header + 0x20, 8));
            (
                String::from_utf8_lossy(&b[at..end]).into_owned(),
                offset..offset + len,
            )
        })
        .collect()
}

#[test]
fn install_stages_binary_config_state_and_units_and_keeps_an_edited_config() {
    let root = std::env::temp_dir().join(format!("softarm-install-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);

    // A dry run says every step and writes nothing.
    let out = softarm(&["install", "--dry-run"], &root);
    let text = String::from_utf8_lossy(&out.stdout);
    for step in [
        "usr/local/bin/softarm",
        "usr/lib/debug/usr/local/bin/softarm.debug",
        "etc/softarm/softarm.toml",
        "var/lib/softarm",
    ] {
        assert!(text.contains(step), "{text}");
    }
    assert!(!root.exists(), "a dry run wrote something");

    softarm(&["install"], &root);
    // The binary without its debug info (its symbols kept), naming the file that has it, where
    // a backtrace and gdb look for it; the gate the same binary.
    let bin = root.join("usr/local/bin/softarm");
    let debug = root.join("usr/lib/debug/usr/local/bin/softarm.debug");
    let (installed, built) = (sections(&bin), sections(Path::new(BIN)));
    assert!(built.iter().any(|s| s == ".debug_line"), "{built:?}");
    // (`.debug_gdb_scripts` is loaded with the program: it stays.)
    assert!(
        !installed
            .iter()
            .any(|s| s.starts_with(".debug_") && s != ".debug_gdb_scripts"),
        "{installed:?}"
    );
    assert!(installed.iter().any(|s| s == ".symtab"), "{installed:?}");
    assert!(
        installed.iter().any(|s| s == ".gnu_debuglink"),
        "{installed:?}"
    );
    assert!(sections(&debug).iter().any(|s| s == ".debug_line"));
    let link = std::fs::read(&bin).unwrap();
    let (_, at) = elf_sections(&link)
        .into_iter()
        .find(|(name, _)| name == ".gnu_debuglink")
        .unwrap();
    assert!(link[at].starts_with(b"softarm.debug\0"));
    assert!(std::fs::metadata(&bin).unwrap().len() < std::fs::metadata(BIN).unwrap().len());
    let version = output(Command::new(&bin).arg("--version"));
    assert!(version.status.success(), "{version:?}");
    let units = root.join("etc/systemd/system");
    for unit in [
        "softarm-controller.service",
        "softarm-learner.service",
        "softarm-driver@.service",
        "softarm-ros2.service",
        "softarm-view.service",
        "softarm.target",
    ] {
        let text = std::fs::read_to_string(units.join(unit)).unwrap();
        if unit.ends_with(".service") {
            assert!(
                text.contains("ExecStart=/usr/local/bin/softarm ")
                    && text.contains("--config /etc/softarm/softarm.toml")
                    && text.contains("RemoveIPC=no"),
                "{unit}: {text}"
            );
        }
    }
    // The config writes where the services may: /var/lib/softarm; and it is valid.
    let config = root.join("etc/softarm/softarm.toml");
    let text = std::fs::read_to_string(&config).unwrap();
    assert!(text.contains("dir = \"/var/lib/softarm/state\""), "{text}");
    assert!(text.contains("dir = \"/var/lib/softarm/model\""), "{text}");
    // Its host: the user, the operators, iceoryx2's own folder and the gate.
    for line in [
        "user = \"softarm\"",
        "group = \"softarm\"",
        "ipc_root = \"/run/softarm/iceoryx2\"",
        "gate = \"/usr/local/libexec/softarm/softarm\"",
    ] {
        assert!(text.contains(line), "{line}: {text}");
    }
    // Staged, the gate has no set-user-ID bit (root owns it here): a package sets owner and mode.
    let gate = root.join("usr/local/libexec/softarm/softarm");
    assert_eq!(std::fs::read(&gate).unwrap(), link);
    let mode =
        std::os::unix::fs::PermissionsExt::mode(&std::fs::metadata(&gate).unwrap().permissions());
    assert_eq!(mode & 0o7777, 0o750, "{mode:o}");
    let tmpfiles = std::fs::read_to_string(root.join("etc/tmpfiles.d/softarm.conf")).unwrap();
    assert!(
        tmpfiles.contains("d /run/softarm 0770 softarm softarm"),
        "{tmpfiles}"
    );
    assert!(root.join("run/softarm").is_dir());
    let check = output(Command::new(BIN).args(["config", "check"]).arg(&config));
    assert!(check.status.success(), "{check:?}");
    assert!(root.join("var/lib/softarm").is_dir());

    // Again: the same config is left as it is; an edited one is kept, the shipped one beside.
    let out = softarm(&["install"], &root);
    assert!(String::from_utf8_lossy(&out.stdout).contains("unchanged"));
    // The installed binary installing itself again: as it is, its debug info kept.
    let debug_info = std::fs::read(&debug).unwrap();
    let out = output(Command::new(&bin).arg("install").arg("--root").arg(&root));
    assert!(out.status.success(), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("the binary is the one installed, kept"),
        "{out:?}"
    );
    assert_eq!(std::fs::read(&bin).unwrap(), link);
    assert_eq!(std::fs::read(&debug).unwrap(), debug_info);
    let edited = text.replace("rate_hz = 500.0", "rate_hz = 250.0");
    std::fs::write(&config, &edited).unwrap();
    let out = softarm(&["install"], &root);
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("kept your edited config"),
        "{out:?}"
    );
    assert_eq!(std::fs::read_to_string(&config).unwrap(), edited);
    assert_eq!(
        std::fs::read_to_string(config.with_extension("toml.new")).unwrap(),
        text
    );

    // One from before `[host]`, edited: it gets its `[host]`, and keeps the edit.
    let hostless = edited[..edited.find("\n[host]").unwrap()].to_string() + "\n";
    std::fs::write(&config, &hostless).unwrap();
    let out = softarm(&["install"], &root);
    assert!(
        String::from_utf8_lossy(&out.stdout)
            .contains("kept your edited config and added its [host]"),
        "{out:?}"
    );
    let upgraded = std::fs::read_to_string(&config).unwrap();
    assert!(upgraded.starts_with(&hostless), "{upgraded}");
    assert!(upgraded.contains("user = \"softarm\"") && upgraded.contains("rate_hz = 250.0"));
    std::fs::write(&config, &edited).unwrap();

    // Uninstall: units, binary, its debug info, the gate and their folders go; config and
    // state stay.
    softarm(&["uninstall"], &root);
    assert!(!bin.exists());
    assert!(!debug.exists() && !root.join("usr/lib/debug/usr").exists());
    assert!(!gate.exists());
    assert!(!root.join("usr/local/libexec/softarm").exists());
    assert!(!root.join("etc/tmpfiles.d/softarm.conf").exists());
    assert!(!units.join("softarm.target").exists());
    assert_eq!(std::fs::read_to_string(&config).unwrap(), edited);
    assert!(root.join("var/lib/softarm").is_dir());
    std::fs::remove_dir_all(&root).unwrap();
}

/// What the stack leaves while it runs, in its iceoryx2 root (`/run/softarm/iceoryx2`, staged)
/// and in /dev/shm (its node counter, its services), stays while a process of it is alive (the
/// uninstall says so) and goes with the next uninstall once none is: nothing of it is left.
#[test]
fn uninstall_removes_the_stacks_runtime_files_once_it_stopped() {
    use softarm_ipc::own::Leftovers;
    use softarm_ipc::{Namespace, Node};
    let root = std::env::temp_dir().join(format!("softarm-install-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    softarm(&["install"], &root);
    let run = root.join("run/softarm");
    let ipc = run.join("iceoryx2");
    // A process of the stack, with a service: as the installed stack's, under its root.
    let ns = Namespace::new("softarm/install-run")
        .unwrap()
        .under(&ipc)
        .unwrap();
    let node = Node::open(ns, "controller").unwrap();
    let status = node.status().unwrap();
    let shm = Leftovers::of(&ipc).unwrap().shm;
    assert!(shm.len() >= 2, "{shm:?}");

    let out = softarm(&["uninstall"], &root);
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        said.contains("kept: the stack still runs (softarm/install-run/controller)"),
        "{said}"
    );
    assert!(ipc.join("nodes").is_dir());
    assert!(shm.iter().all(|f| f.exists()), "{shm:?}");
    drop((status, node));

    let out = softarm(&["uninstall"], &root);
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(said.contains("files in /dev/shm"), "{said}");
    let left = Leftovers::of(&ipc).unwrap();
    assert!(left.shm.is_empty(), "{:?}", left.shm);
    assert!(!run.exists() && !root.join("usr/local/libexec/softarm").exists());
    assert!(
        root.join("etc/softarm/softarm.toml").exists() && root.join("var/lib/softarm").is_dir()
    );
    std::fs::remove_dir_all(&root).unwrap();
}

/// The ROS 2 bridge's and the view's units are always written, and each wanted by the target
/// only when the config enables it.
#[test]
fn the_target_wants_the_ros2_bridge_and_the_view_only_when_enabled() {
    let root = std::env::temp_dir().join(format!("softarm-install-ros2-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    let shipped =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/softarm.toml"))
            .unwrap();
    let enable = |text: &str, section: &str| {
        let (at, _) = text
            .match_indices(&format!("[{section}] "))
            .next()
            .unwrap_or_else(|| panic!("no [{section}] in the shipped config"));
        let edited =
            text[..at].to_string() + &text[at..].replacen("enabled = false", "enabled = true", 1);
        assert_ne!(edited, text, "[{section}] enabled = false not found");
        edited
    };
    let configs = [
        ("ros2", enable(&shipped, "ros2")),
        ("view", enable(&shipped, "view")),
        ("both", enable(&enable(&shipped, "ros2"), "view")),
    ];
    let mut runs = vec![(None, "none")];
    for (name, text) in &configs {
        let path = root.join(format!("{name}.toml"));
        std::fs::write(&path, text).unwrap();
        runs.push((Some(path), *name));
    }
    for (config, name) in runs {
        let stage = root.join(format!("stage-{name}"));
        let mut args = vec!["install".to_string()];
        if let Some(c) = config {
            args.extend(["--config".to_string(), c.display().to_string()]);
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        softarm(&args, &stage);
        let units = stage.join("etc/systemd/system");
        let target = std::fs::read_to_string(units.join("softarm.target")).unwrap();
        let wants = target.lines().find(|l| l.starts_with("Wants=")).unwrap();
        for (unit, command) in [("ros2", "ros2"), ("view", "view")] {
            let file = format!("softarm-{unit}.service");
            let text = std::fs::read_to_string(units.join(&file)).unwrap();
            let exec = format!("ExecStart=/usr/local/bin/softarm {command} --config ");
            assert!(text.contains(&exec), "{file}: {text}");
            let wanted = name == unit || name == "both";
            assert_eq!(wants.contains(&file), wanted, "{name}: {wants}");
        }
    }
    std::fs::remove_dir_all(&root).unwrap();
}

/// Without objcopy the install is refused before it writes anything, saying what to install.
#[test]
fn without_objcopy_the_install_says_to_install_binutils_and_writes_nothing() {
    let root = std::env::temp_dir().join(format!("softarm-install-objcopy-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let empty = root.join("no-tools");
    std::fs::create_dir_all(&empty).unwrap();
    let stage = root.join("stage");
    let out = output(
        Command::new(BIN)
            .args(["install", "--root"])
            .arg(&stage)
            .env("PATH", &empty),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("objcopy not found") && err.contains("apt-get install binutils"),
        "{err}"
    );
    assert!(!stage.exists(), "something was staged without objcopy");
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn a_bad_config_to_install_is_refused_and_nothing_is_written() {
    let root = std::env::temp_dir().join(format!("softarm-install-bad-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    let refused = root.join("refused.toml");
    let shipped =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/softarm.toml"))
            .unwrap();
    std::fs::write(
        &refused,
        shipped.replace("rate_hz = 500.0", "rate_hz = 5000.0"),
    )
    .unwrap();
    let no_state = root.join("no-state.toml");
    std::fs::write(&no_state, "[robot]\nid = \"x\"\n").unwrap();
    for (config, says, code) in [
        (&refused, "controller.rate_hz", 78),
        (&no_state, "no-state.toml:1: missing field", 78),
    ] {
        let stage = root.join("stage");
        let out = output(
            Command::new(BIN)
                .args(["install", "--root"])
                .arg(&stage)
                .arg("--config")
                .arg(config),
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{err}");
        assert!(err.contains(says), "{err}");
        assert!(!stage.exists(), "something was staged for a refused config");
    }
    std::fs::remove_dir_all(&root).unwrap();
}
