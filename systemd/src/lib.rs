//! `softarm install` / `softarm uninstall`: the stack as a system service. The binary (without
//! its debug info, which goes to /usr/lib/debug for backtraces and debuggers), a config in
//! /etc/softarm (never overwriting an edited one), the state folder, the systemd units
//! (`systemd/` of the repository, built in), the `softarm` user and group, and a reload of
//! systemd. `--dry-run` prints each step and does nothing; `--root DIR` stages everything under
//! DIR, as DESTDIR does for packagers, and leaves the running system alone.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};
use softarm_config::host::HostConfig;
use softarm_config::{Config, ConfigError, DEFAULT};

const USER: &str = "softarm";
const ETC: &str = "etc/softarm";
const STATE: &str = "var/lib/softarm";
/// iceoryx2's folder for the installed stack (`host.ipc_root` is `RUN/iceoryx2`): the stack's
/// own, so nobody else's use of iceoryx2 on the computer can own it first.
const RUN: &str = "run/softarm";
/// iceoryx2's root folder in RUN: the config's `host.ipc_root`.
const IPC_ROOT: &str = "run/softarm/iceoryx2";
/// Recreates RUN at every boot (/run is a tmpfs).
const TMPFILES: &str = "etc/tmpfiles.d/softarm.conf";
const UNITS: &str = "etc/systemd/system";
/// The operator gate under the prefix.
const GATE: &str = "libexec/softarm/softarm";
/// Where the units in the repository start the binary; `--prefix` rewrites it.
const UNIT_BINARY: &str = "/usr/local/bin/softarm";
/// Where a backtrace (Rust's, through the binary's `.gnu_debuglink`) and gdb look for the debug
/// info of `/DIR/softarm`: `/usr/lib/debug/DIR/softarm.debug`.
const DEBUG_ROOT: &str = "/usr/lib/debug";
/// The name of the debug info's file, which the installed binary's `.gnu_debuglink` names.
const DEBUG_FILE: &str = "softarm.debug";

/// The units, as in `systemd/`.
const UNIT_FILES: [(&str, &str); 6] = [
    (
        "softarm-controller.service",
        include_str!("../softarm-controller.service"),
    ),
    (
        "softarm-learner.service",
        include_str!("../softarm-learner.service"),
    ),
    (
        "softarm-driver@.service",
        include_str!("../softarm-driver@.service"),
    ),
    (
        "softarm-ros2.service",
        include_str!("../softarm-ros2.service"),
    ),
    (
        "softarm-view.service",
        include_str!("../softarm-view.service"),
    ),
    ("softarm.target", include_str!("../softarm.target")),
];

/// Where an install goes, and whether to do it.
#[derive(clap::Args)]
pub struct Target {
    /// The binary is PREFIX/bin/softarm, and the units start it from there.
    #[arg(long, default_value = "/usr/local")]
    prefix: PathBuf,
    /// Stages (or removes a staged install) under this folder and leaves the running system
    /// alone: no user is created and systemd is not touched.
    #[arg(long, value_name = "DIR")]
    root: Option<PathBuf>,
    /// Prints each step without doing it.
    #[arg(long)]
    dry_run: bool,
}

impl Target {
    /// (the folder everything goes under, whether that is the running system).
    fn root(&self) -> (PathBuf, bool) {
        match &self.root {
            Some(r) => (r.clone(), false),
            None => (PathBuf::from("/"), true),
        }
    }
}

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    target: Target,
    /// The config to install (default: the embedded simulation config).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// The operators' group: its members may run every command on the stack (status, submit,
    /// the e-stop and its reset) through the operator gate. Created if it does not exist.
    #[arg(long, value_name = "NAME", default_value = USER)]
    group: String,
}

#[derive(clap::Args)]
pub struct UninstallArgs {
    #[command(flatten)]
    target: Target,
}

/// One thing an install or uninstall does; printed before it is done.
enum Step {
    CreateUser,
    /// The operators' group, when it is not the user's own.
    CreateGroup(String),
    /// The operator gate: the binary again, owned by the user and the operators' group,
    /// set-user-ID and set-group-ID, executable by the group alone. Staged (`system` false) without the bits.
    Gate {
        path: PathBuf,
        bytes: Vec<u8>,
        group: String,
    },
    /// A folder of the user's own (mode 770): the state, iceoryx2's.
    OwnDir {
        path: PathBuf,
        what: &'static str,
    },
    Write {
        path: PathBuf,
        text: Vec<u8>,
        mode: u32,
    },
    /// The config: written if absent, left alone if it is what we ship, else the shipped one
    /// goes beside it as `.new`.
    Config {
        path: PathBuf,
        text: String,
        /// The operators' group: they read it (mode 640) before the gate makes them the user.
        group: String,
        /// The gate `[host]` names; an edited config without a `[host]` gets one.
        gate: PathBuf,
    },
    Remove(PathBuf),
    /// A folder of ours, if nothing else is in it.
    RemoveDirIfEmpty(PathBuf),
    /// The stack's runtime files: RUN, with iceoryx2's root `ipc_root` in it, and the stack's
    /// files in /dev/shm; kept, saying so, while a process of the stack still runs.
    RemoveRuntime {
        run: PathBuf,
        ipc_root: PathBuf,
    },
    Systemctl(&'static [&'static str]),
    /// A systemctl call whose failure is reported, not fatal (stopping what may not run).
    SystemctlIfAny(&'static [&'static str]),
    Skip(String),
}

impl Step {
    fn describe(&self) -> String {
        match self {
            Step::CreateUser => format!(
                "create the system user and group `{USER}` (home /{STATE}, no login) unless they exist"
            ),
            Step::Write { path, mode, .. } => format!("write {} (mode {mode:o})", path.display()),
            Step::Config { path, .. } => format!(
                "write the config {} unless it exists (an edited one is kept; the shipped one goes beside it as softarm.toml.new)",
                path.display()
            ),
            Step::CreateGroup(g) => format!("create the system group `{g}` unless it exists"),
            Step::Gate { path, group, .. } => format!(
                "write the operator gate {} (owned by {USER}:{group}, set-user-ID and set-group-ID, mode 6750)",
                path.display()
            ),
            Step::OwnDir { path, what } => format!(
                "create {} ({what}), owned by {USER}:{USER}, mode 770",
                path.display()
            ),
            Step::Remove(p) => format!("remove {}", p.display()),
            Step::RemoveDirIfEmpty(p) => format!("remove the folder {} if empty", p.display()),
            Step::RemoveRuntime { run, ipc_root } => format!(
                "remove {} (iceoryx2's folder {} in it) and the stack's files in {} (prefix {}) \
                 unless a process of the stack still runs",
                run.display(),
                ipc_root.display(),
                softarm_ipc::own::SHM_DIR,
                shm_prefix(ipc_root)
            ),
            Step::Systemctl(args) | Step::SystemctlIfAny(args) => {
                format!("systemctl {}", args.join(" "))
            }
            Step::Skip(why) => format!("skip: {why}"),
        }
    }

    fn run(&self, system: bool) -> anyhow::Result<String> {
        match self {
            Step::CreateUser => {
                let exists = Command::new("getent")
                    .args(["passwd", USER])
                    .output()
                    .is_ok_and(|o| o.status.success());
                if exists {
                    return Ok("exists".into());
                }
                let home = format!("/{STATE}");
                run_command(
                    "useradd",
                    &[
                        "--system",
                        "--user-group",
                        "--home-dir",
                        &home,
                        "--no-create-home",
                        "--shell",
                        "/usr/sbin/nologin",
                        USER,
                    ],
                )?;
                Ok("created".into())
            }
            Step::Write { path, text, mode } => {
                write_atomic(path, text, *mode)?;
                Ok("done".into())
            }
            Step::Config {
                path,
                text,
                group,
                gate,
            } => match std::fs::read_to_string(path) {
                Ok(old) if old == *text => Ok("unchanged".into()),
                Ok(old) => {
                    let new = path.with_extension("toml.new");
                    write_atomic(&new, text.as_bytes(), 0o640)?;
                    // A config from before `[host]` would leave the stack to whoever runs a
                    // command first: it gets its `[host]`, the rest as the user left it.
                    let origin = path.display().to_string();
                    let hostless = Config::parse(&old, &origin, Path::new("/").join(ETC))
                        .is_ok_and(|c| c.host == HostConfig::default());
                    if !hostless {
                        return Ok(format!(
                            "kept your edited config; the shipped one is {}",
                            new.display()
                        ));
                    }
                    let hosted = with_host(&old, group, gate).map_err(anyhow::Error::msg)?;
                    write_atomic(path, hosted.as_bytes(), 0o640)?;
                    if system {
                        chown_to(path, "root", group)?;
                    }
                    Ok(format!(
                        "kept your edited config and added its [host] section; the shipped one \
                         is {}",
                        new.display()
                    ))
                }
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    write_atomic(path, text.as_bytes(), 0o640)?;
                    if system {
                        chown_to(path, "root", group)?;
                    }
                    Ok("done".into())
                }
                Err(e) => Err(e).with_context(|| format!("reading {}", path.display())),
            },
            Step::CreateGroup(g) => {
                let exists = Command::new("getent")
                    .args(["group", g])
                    .output()
                    .is_ok_and(|o| o.status.success());
                if exists {
                    return Ok("exists".into());
                }
                run_command("groupadd", &["--system", g])?;
                Ok("created".into())
            }
            Step::Gate { path, bytes, group } => {
                write_atomic(path, bytes, 0o750)?;
                if !system {
                    return Ok(format!(
                        "staged mode 750: a package sets owner {USER}:{group} and mode 6750"
                    ));
                }
                // In this order: a change of owner clears the set-ID bits.
                chown_to(path, USER, group)?;
                set_mode(path, 0o6750)?;
                Ok("done".into())
            }
            Step::OwnDir { path, .. } => {
                std::fs::create_dir_all(path)
                    .with_context(|| format!("creating {}", path.display()))?;
                set_mode(path, 0o770)?;
                if system {
                    chown(path, USER)?;
                }
                Ok("done".into())
            }
            Step::Remove(p) => match std::fs::remove_file(p) {
                Ok(()) => Ok("done".into()),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok("not there".into()),
                Err(e) => Err(e).with_context(|| format!("removing {}", p.display())),
            },
            Step::RemoveDirIfEmpty(p) => match std::fs::remove_dir(p) {
                Ok(()) => Ok("done".into()),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok("not there".into()),
                Err(e) if e.kind() == std::io::ErrorKind::DirectoryNotEmpty => {
                    Ok("kept: other files are in it".into())
                }
                Err(e) => Err(e).with_context(|| format!("removing {}", p.display())),
            },
            Step::RemoveRuntime { run, ipc_root } => remove_runtime(run, ipc_root),
            Step::Systemctl(args) => {
                run_command("systemctl", args)?;
                Ok("done".into())
            }
            Step::SystemctlIfAny(args) => Ok(match run_command("systemctl", args) {
                Ok(()) => "done".into(),
                Err(e) => format!("{e:#}; going on"),
            }),
            Step::Skip(_) => Ok(String::new()),
        }
    }
}

fn run_command(program: &str, args: &[&str]) -> anyhow::Result<()> {
    let out = Command::new(program)
        .args(args)
        .output()
        .with_context(|| format!("running {program} (is it installed?)"))?;
    if !out.status.success() {
        bail!(
            "{program} {} failed ({}): {}",
            args.join(" "),
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(())
}

fn set_mode(path: &Path, mode: u32) -> anyhow::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode))
        .with_context(|| format!("setting the mode of {}", path.display()))
}

/// `chown owner:softarm path`.
fn chown(path: &Path, owner: &str) -> anyhow::Result<()> {
    chown_to(path, owner, USER)
}

/// `chown owner:group path`.
fn chown_to(path: &Path, owner: &str, group: &str) -> anyhow::Result<()> {
    let user = nix::unistd::User::from_name(owner)?.with_context(|| format!("no user {owner}"))?;
    let g = nix::unistd::Group::from_name(group)?.with_context(|| format!("no group {group}"))?;
    nix::unistd::chown(path, Some(user.uid), Some(g.gid))
        .with_context(|| format!("chown {owner}:{group} {}", path.display()))
}

/// [`softarm_runtime::file::write_atomic`] with the mode set before the file appears.
fn write_atomic(path: &Path, bytes: &[u8], mode: u32) -> anyhow::Result<()> {
    softarm_runtime::file::write_atomic(path, bytes, Some(mode))
        .with_context(|| format!("writing {}", path.display()))
}

/// The prefix of the stack's files in /dev/shm for iceoryx2 root `ipc_root`.
fn shm_prefix(ipc_root: &Path) -> String {
    softarm_ipc::Namespace::new(USER)
        .and_then(|ns| ns.under(ipc_root))
        .ok()
        .and_then(|ns| ns.prefix().map(str::to_string))
        .unwrap_or_else(|| "?".into())
}

/// [`Step::RemoveRuntime`]: what the stack left, once it stopped. A process still running keeps
/// it all, said with what to do (not an error: the rest of the uninstall is done).
fn remove_runtime(run: &Path, ipc_root: &Path) -> anyhow::Result<String> {
    let left = softarm_ipc::own::Leftovers::of(ipc_root).map_err(anyhow::Error::msg)?;
    if !left.alive.is_empty() {
        return Ok(format!(
            "kept: the stack still runs ({}); stop it and run `softarm uninstall` again",
            left.alive.join(", ")
        ));
    }
    let shm = left.remove().map_err(anyhow::Error::msg)?;
    // The root checked above, then `run` if nothing else is in it: another root an edited
    // config put there was not checked for live processes, so it stays.
    match std::fs::remove_dir_all(ipc_root) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(e).with_context(|| format!("removing {}", ipc_root.display())),
    }
    match std::fs::remove_dir(run) {
        Ok(()) => {}
        Err(e)
            if matches!(
                e.kind(),
                std::io::ErrorKind::NotFound | std::io::ErrorKind::DirectoryNotEmpty
            ) => {}
        Err(e) => return Err(e).with_context(|| format!("removing {}", run.display())),
    }
    Ok(format!(
        "done ({shm} files in {})",
        softarm_ipc::own::SHM_DIR
    ))
}

/// `path` (absolute, as on the target system) under `root`.
fn under(root: &Path, path: &Path) -> PathBuf {
    root.join(path.strip_prefix("/").unwrap_or(path))
}

/// Where the debug info of the binary installed at `binary` goes: where a backtrace and gdb
/// look for the file its `.gnu_debuglink` names.
fn debug_file(binary: &Path) -> PathBuf {
    let dir = binary.parent().unwrap_or(Path::new("/"));
    Path::new(DEBUG_ROOT)
        .join(dir.strip_prefix("/").unwrap_or(dir))
        .join(DEBUG_FILE)
}

/// The binary as installed from `exe`, and its debug info: `exe` without its debug info (its
/// symbols kept, so a backtrace names the functions without the debug info), naming the file of
/// its debug info (`.gnu_debuglink`) so that a backtrace and gdb give the lines too. When `exe`
/// is the binary installed at `installed` (a `softarm install` of the installed softarm), it
/// is installed again as it is and its debug info kept (`None`): it has none to split.
fn installed_binary(exe: &Path, installed: &Path) -> anyhow::Result<(Vec<u8>, Option<Vec<u8>>)> {
    let bytes = std::fs::read(exe).with_context(|| format!("reading {}", exe.display()))?;
    if std::fs::read(installed).is_ok_and(|i| i == bytes) {
        return Ok((bytes, None));
    }
    drop(bytes);
    // A folder of our own, new (mkdtemp: never one someone else made).
    let dir = nix::unistd::mkdtemp(&std::env::temp_dir().join("softarm-install-XXXXXX"))
        .context("making a temporary folder")?;
    let split = || -> anyhow::Result<(Vec<u8>, Option<Vec<u8>>)> {
        let debug = dir.join(DEBUG_FILE);
        let stripped = dir.join("softarm");
        objcopy(&[
            OsStr::new("--only-keep-debug"),
            exe.as_os_str(),
            debug.as_os_str(),
        ])?;
        let link = format!("--add-gnu-debuglink={}", debug.display());
        objcopy(&[
            OsStr::new("--strip-debug"),
            // An already stripped binary's own link is replaced, not added to.
            OsStr::new("--remove-section=.gnu_debuglink"),
            OsStr::new(&link),
            exe.as_os_str(),
            stripped.as_os_str(),
        ])?;
        let read = |p: &Path| std::fs::read(p).with_context(|| format!("reading {}", p.display()));
        Ok((read(&stripped)?, Some(read(&debug)?)))
    };
    let r = split();
    let _ = std::fs::remove_dir_all(&dir);
    r
}

/// `objcopy ARGS`: binutils', which comes with the C compiler a build needs.
fn objcopy(args: &[&OsStr]) -> anyhow::Result<()> {
    let out = match Command::new("objcopy").args(args).output() {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!(
            "objcopy not found: softarm install installs the binary without its debug info \
             (kept apart in {DEBUG_ROOT}, for backtraces) and needs objcopy for that; install \
             binutils (Debian, Ubuntu: `apt-get install binutils`; Fedora: `dnf install \
             binutils`) and run it again"
        ),
        r => r.context("running objcopy")?,
    };
    if !out.status.success() {
        bail!(
            "objcopy {} failed ({}): {}",
            args.iter()
                .map(|a| a.to_string_lossy())
                .collect::<Vec<_>>()
                .join(" "),
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(())
}

/// The config as installed: its model and state live in /var/lib/softarm, where the services
/// may write (the units make everything else read-only); `[host]` names the user, the
/// operators' `group`, iceoryx2's folder and the operator `gate`.
fn installed_config(
    source: Option<&Path>,
    group: &str,
    gate: &Path,
) -> anyhow::Result<(String, Config)> {
    let origin = source.map_or("the embedded config".into(), |p| p.display().to_string());
    let text = match source {
        Some(p) => {
            std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?
        }
        None => DEFAULT.to_string(),
    };
    // Checked as it is first, so a refusal names the user's file and line; then as installed.
    Config::parse(&text, &origin, Path::new("/").join(ETC))?;
    let text = softarm_config::with_overrides(
        &text,
        &[
            ("model.dir", format!("/{STATE}/model").into()),
            ("state.dir", format!("/{STATE}/state").into()),
        ],
    )
    .and_then(|text| with_host(&text, group, gate))
    .map_err(|message| ConfigError {
        origin: origin.clone(),
        line: None,
        message,
    })?;
    let config = Config::parse(
        &text,
        &format!("{origin} (as installed)"),
        Path::new("/").join(ETC),
    )?;
    Ok((text, config))
}

/// `text` (a valid config) with its `[host]` naming the stack's user, the operators' `group`,
/// iceoryx2's folder and the `gate`; a `[host]` section is added if it has none.
fn with_host(text: &str, group: &str, gate: &Path) -> Result<String, String> {
    let mut text = text.to_string();
    let has_host = text
        .parse::<toml_edit::DocumentMut>()
        .map_err(|e| e.to_string())?
        .contains_key("host");
    if !has_host {
        text.push_str("\n[host]                        # written by softarm install\n");
    }
    softarm_config::with_overrides(
        &text,
        &[
            ("host.user", USER.into()),
            ("host.group", group.into()),
            ("host.ipc_root", format!("/{IPC_ROOT}").into()),
            ("host.gate", gate.display().to_string().into()),
        ],
    )
}

pub fn install(args: &Args) -> anyhow::Result<()> {
    let (root, system) = args.target.root();
    let dry_run = args.target.dry_run;
    let binary = args.target.prefix.join("bin/softarm");
    if !binary.is_absolute() {
        bail!(
            "--prefix must be an absolute path, got {}",
            args.target.prefix.display()
        );
    }
    let gate = args.target.prefix.join(GATE);
    let (config_text, config) = installed_config(args.config.as_deref(), &args.group, &gate)?;
    let debug = debug_file(&binary);
    let exe = std::env::current_exe().context("finding my own executable")?;
    // Before any step: a machine without objcopy is told so before anything is written.
    let (exe_bytes, debug_bytes) = if dry_run {
        (Vec::new(), Some(Vec::new()))
    } else {
        installed_binary(&exe, &under(&root, &binary))?
    };
    let mut steps = vec![if system {
        Step::CreateUser
    } else {
        Step::Skip(format!("the user `{USER}` (staged under --root)"))
    }];
    if system && args.group != USER {
        steps.push(Step::CreateGroup(args.group.clone()));
    }
    steps.push(Step::Write {
        path: under(&root, &binary),
        text: exe_bytes.clone(),
        mode: 0o755,
    });
    steps.push(match debug_bytes {
        Some(bytes) => Step::Write {
            path: under(&root, &debug),
            text: bytes,
            mode: 0o644,
        },
        None => Step::Skip(format!(
            "{}: the binary is the one installed, kept with it",
            debug.display()
        )),
    });
    steps.push(Step::Gate {
        path: under(&root, &gate),
        bytes: exe_bytes,
        group: args.group.clone(),
    });
    steps.push(Step::Config {
        path: under(&root, &Path::new("/").join(ETC).join("softarm.toml")),
        text: config_text,
        group: args.group.clone(),
        gate: gate.clone(),
    });
    steps.push(Step::OwnDir {
        path: under(&root, &Path::new("/").join(STATE)),
        what: "models, checkpoints, the e-stop latch",
    });
    steps.push(Step::OwnDir {
        path: under(&root, &Path::new("/").join(RUN)),
        what: "iceoryx2's folder for the stack",
    });
    steps.push(Step::Write {
        path: under(&root, &Path::new("/").join(TMPFILES)),
        text: format!(
            "# softarm: iceoryx2's folder for the stack, made again at every boot.\n\
             d /{RUN} 0770 {USER} {USER} -\n"
        )
        .into_bytes(),
        mode: 0o644,
    });
    // The target wants the config's drivers, the ROS 2 bridge when `ros2.enabled` and the
    // view when `view.enabled`.
    let wanted: Vec<String> = config
        .robot
        .drivers
        .iter()
        .map(|d| format!("softarm-driver@{d}.service"))
        .chain(config.ros2.enabled.then(|| "softarm-ros2.service".into()))
        .chain(config.view.enabled.then(|| "softarm-view.service".into()))
        .collect();
    for (name, text) in UNIT_FILES {
        let mut text = text.replace(UNIT_BINARY, &binary.display().to_string());
        if name == "softarm.target" {
            text = text.replace("softarm-driver@sim.service", &wanted.join(" "));
        }
        steps.push(Step::Write {
            path: under(&root, &Path::new("/").join(UNITS).join(name)),
            text: text.into_bytes(),
            mode: 0o644,
        });
    }
    steps.push(if system {
        Step::Systemctl(&["daemon-reload"])
    } else {
        Step::Skip("systemctl daemon-reload (staged under --root)".into())
    });
    run_steps(&steps, dry_run, system)?;
    if !dry_run {
        println!(
            "installed. Start it with `systemctl enable --now softarm.target`; check it with \
             `softarm status` (as root or a member of the group `{}`).",
            args.group
        );
        if system && target_active() {
            // Not restarted here: that stops the arm, which is the operator's call.
            println!(
                "the stack runs the softarm installed before: restart it when the arm may stop \
                 (`systemctl restart softarm.target`). Until then this softarm's commands may \
                 not reach it (`softarm estop` among them: another version's shared memory)."
            );
        }
    }
    Ok(())
}

/// Whether `softarm.target` is active (a stack running the binary installed before).
fn target_active() -> bool {
    std::process::Command::new("systemctl")
        .args(["is-active", "--quiet", "softarm.target"])
        .status()
        .is_ok_and(|s| s.success())
}

pub fn uninstall(args: &UninstallArgs) -> anyhow::Result<()> {
    let (root, system) = args.target.root();
    if !args.target.prefix.is_absolute() {
        bail!(
            "--prefix must be an absolute path, got {}",
            args.target.prefix.display()
        );
    }
    let mut steps = vec![if system {
        Step::SystemctlIfAny(&["disable", "--now", "softarm.target"])
    } else {
        Step::Skip("systemctl disable --now softarm.target (staged under --root)".into())
    }];
    for (name, _) in UNIT_FILES {
        steps.push(Step::Remove(under(
            &root,
            &Path::new("/").join(UNITS).join(name),
        )));
    }
    let gate = args.target.prefix.join(GATE);
    let binary = args.target.prefix.join("bin/softarm");
    let debug = debug_file(&binary);
    for path in [&binary, &debug, &gate, &Path::new("/").join(TMPFILES)] {
        steps.push(Step::Remove(under(&root, path)));
    }
    // The debug info's folders below /usr/lib/debug, which the install made if nothing else
    // had, from the deepest up.
    for dir in debug
        .ancestors()
        .skip(1)
        .take_while(|d| d.starts_with(DEBUG_ROOT) && *d != Path::new(DEBUG_ROOT))
    {
        steps.push(Step::RemoveDirIfEmpty(under(&root, dir)));
    }
    if let Some(dir) = gate.parent() {
        steps.push(Step::RemoveDirIfEmpty(under(&root, dir)));
    }
    // Stopped above: what the stack left in /run (until the next boot) and /dev/shm.
    steps.push(Step::RemoveRuntime {
        run: under(&root, &Path::new("/").join(RUN)),
        ipc_root: under(&root, &Path::new("/").join(IPC_ROOT)),
    });
    steps.push(if system {
        Step::Systemctl(&["daemon-reload"])
    } else {
        Step::Skip("systemctl daemon-reload (staged under --root)".into())
    });
    steps.push(Step::Skip(format!(
        "/{ETC} (your config), /{STATE} (models, checkpoints, the e-stop latch) and the user \
         `{USER}` are kept; remove them by hand if you want them gone"
    )));
    run_steps(&steps, args.target.dry_run, system)
}

fn run_steps(steps: &[Step], dry_run: bool, system: bool) -> anyhow::Result<()> {
    for (i, step) in steps.iter().enumerate() {
        let what = step.describe();
        if dry_run {
            println!("{}. {what}", i + 1);
            continue;
        }
        let outcome = step
            .run(system)
            .with_context(|| format!("step {} ({what})", i + 1))?;
        if outcome.is_empty() {
            println!("{}. {what}", i + 1);
        } else {
            println!("{}. {what}: {outcome}", i + 1);
        }
    }
    Ok(())
}
