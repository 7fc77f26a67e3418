//! End to end: what a user who is neither root nor an operator (an outsider, here `nobody`) can
//! do to a stack with an iceoryx2 root of its own (as installed: `host.ipc_root`) through
//! /dev/shm. They write garbage into, or cut short, every file of the stack's there, while the
//! stack starts and while it runs: every write is refused, iceoryx2's node counter included
//! (iceoryx2 would make it 0666; the stack makes it its own, 0600), and processes started after
//! still join. A counter they made before the stack did is refused, naming it and what to do.
//! Needs root, to run the outsider as another user.

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use softarm_ipc::own::{Leftovers, SHM_DIR, counter_path};
use softarm_test_support::{Guard, TestStack, config_text, output};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

/// The outsider's uid and gid: `nobody`'s.
fn outsider() -> (u32, u32) {
    nix::unistd::User::from_name("nobody")
        .ok()
        .flatten()
        .map_or((65534, 65534), |u| (u.uid.as_raw(), u.gid.as_raw()))
}

/// `sh -c script` as the outsider, with `args` as `$1...`.
fn as_outsider(script: &str, args: &[&str]) -> Command {
    let (uid, gid) = outsider();
    let mut c = Command::new("sh");
    c.arg("-c")
        .arg(script)
        .arg("sh")
        .args(args)
        .uid(uid)
        .gid(gid)
        .current_dir("/");
    c
}

/// Tries every file in /dev/shm whose name starts with `$1`: garbage over its start, then, if
/// `$2` is `cut`, cuts it to nothing; a line for each that worked. Neither creates a file (a
/// file the stack removed meanwhile stays gone). Garbage in iceoryx2 0.10's counter makes each
/// node made after fail; a counter cut to nothing makes each hang: so the stack starting is
/// only given garbage.
const ATTACK: &str = r#"
attack() {
    for f in /dev/shm/"$1"*; do
        [ -e "$f" ] || continue
        tries=$((tries + 1))
        if printf 'garbage!garbage!garbage!' | dd of="$f" conv=notrunc,nocreat status=none 2>/dev/null
        then echo "wrote $f"; fi
        if [ "$2" = cut ] && truncate --no-create -s 0 "$f" 2>/dev/null; then echo "cut $f"; fi
    done
}
tries=0
"#;

/// The files in /dev/shm and the iceoryx2 root of a stack of its own root go when the test
/// ends, pass or fail (declared before the stack, so dropped after it stopped).
pub(crate) struct Cleanup(pub(crate) Option<PathBuf>);

impl Drop for Cleanup {
    fn drop(&mut self) {
        if let Some(Ok(left)) = self.0.as_deref().map(Leftovers::of) {
            let _ = left.remove();
        }
    }
}

/// A stack whose config names an iceoryx2 root of its own, as an installed one's does.
fn stack_of_its_own(name: &str) -> (TestStack, PathBuf) {
    let s = TestStack::with_config(BIN, name, true, |dir, ns| {
        format!(
            "{}\n[host]\nipc_root = \"{}\"\n",
            config_text(dir, ns),
            dir.join("run/iceoryx2").display()
        )
    });
    let root = s.dir.join("run/iceoryx2");
    (s, root)
}

fn prefix_of(root: &Path) -> String {
    Leftovers::of(root).unwrap().prefix
}

#[test]
fn an_outsider_can_write_none_of_the_stacks_shared_memory() {
    if !nix::unistd::geteuid().is_root() {
        eprintln!("not run: running the outsider as another user needs root");
        return;
    }
    let mut cleanup = Cleanup(None);
    let (mut s, root) = stack_of_its_own("shm-outsider");
    cleanup.0 = Some(root.clone());
    let prefix = prefix_of(&root);
    let stop = std::env::temp_dir().join(format!("softarm-shm-stop-{}", std::process::id()));
    let _ = std::fs::remove_file(&stop);

    // While the stack starts: the outsider tries every file as it appears, until told to stop,
    // and once more after that (so at least once with the stack up).
    let script = format!(
        "{ATTACK}\nwhile [ ! -e \"$2\" ]; do attack \"$1\"; sleep 0.02; done\nattack \"$1\"\n\
         echo \"tries $tries\""
    );
    let during = Guard::spawn(
        as_outsider(&script, &[&prefix, stop.to_str().unwrap()])
            .stdout(Stdio::piped())
            .stderr(Stdio::null()),
    );
    s.up();

    // While it runs: every file of the stack's, each tried once more.
    let left = Leftovers::of(&root).unwrap();
    let counter = counter_path(&prefix);
    assert!(
        left.shm.contains(&counter),
        "no counter among {:?}",
        left.shm
    );
    assert!(left.shm.len() > 5, "only {:?}", left.shm);
    let out = output(&mut as_outsider(
        &format!("{ATTACK}\nattack \"$1\" cut\necho \"tries $tries\""),
        &[&prefix],
    ));
    let said = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        said.starts_with("tries ") && !said.contains("wrote") && !said.contains("cut"),
        "{said}"
    );
    let out = output(&mut as_outsider(
        "printf 'garbage!' | dd of=\"$1\" conv=notrunc,nocreat status=none",
        &[counter.to_str().unwrap()],
    ));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("Permission denied"),
        "{out:?}"
    );

    std::fs::write(&stop, "").unwrap();
    let out = during.wait_with_output().unwrap();
    let _ = std::fs::remove_file(&stop);
    let said = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        said.starts_with("tries ") && !said.contains("wrote") && !said.contains("cut"),
        "{said}"
    );
    let tries: usize = said.trim().trim_start_matches("tries ").parse().unwrap();
    assert!(tries > 0, "{said}");

    // The counter is as the stack made it, and processes started now still join: a status (a
    // node of its own) sees all of the stack; an e-stop and its reset are confirmed.
    let meta = std::fs::metadata(&counter).unwrap();
    assert_eq!(
        std::os::unix::fs::PermissionsExt::mode(&meta.permissions()) & 0o777,
        0o600
    );
    let st = s.status();
    assert!(st["alive"].as_array().is_some_and(|a| a.len() >= 3), "{st}");
    for args in [&["estop"][..], &["estop", "--reset"]] {
        let out = s.run(args);
        assert!(out.status.success(), "{args:?}: {out:?}");
    }
    assert!(s.stop().unwrap().success());
}

#[test]
fn a_node_counter_an_outsider_made_first_is_refused_naming_it() {
    if !nix::unistd::geteuid().is_root() {
        eprintln!("not run: running the outsider as another user needs root");
        return;
    }
    let mut cleanup = Cleanup(None);
    let (s, root) = stack_of_its_own("shm-taken");
    cleanup.0 = Some(root.clone());
    let counter = counter_path(&prefix_of(&root));
    let _ = std::fs::remove_file(&counter);
    // The name is the stack's prefix (a hash of its root) and iceoryx2's: anyone can work it out.
    let out = output(&mut as_outsider(
        "umask 0; printf 'garbage!garbage!' >\"$1\"",
        &[counter.to_str().unwrap()],
    ));
    assert!(out.status.success(), "{out:?}");
    let before = std::fs::read(&counter).unwrap();

    let out = s.run(&["status"]);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "{out:?}");
    assert!(
        err.contains(&counter.display().to_string())
            && err.contains(&format!("uid {}", outsider().0))
            && err.contains("remove it as root"),
        "{err}"
    );
    assert_eq!(std::fs::read(&counter).unwrap(), before, "changed nothing");

    // Removed as the message says, the stack's next process makes its own.
    std::fs::remove_file(&counter).unwrap();
    let out = s.run(&["status"]);
    assert_eq!(out.status.code(), Some(3), "not running: {out:?}");
    let meta = std::fs::metadata(&counter).unwrap();
    assert_eq!(
        std::os::unix::fs::PermissionsExt::mode(&meta.permissions()) & 0o777,
        0o600
    );
    assert!(
        Path::new(SHM_DIR)
            .join(counter.file_name().unwrap())
            .exists()
    );
}
