//! Bad command lines, end to end: the real binary with malformed, out-of-range, non-finite,
//! missing and misplaced arguments for every subcommand. Each is refused in bounded time with
//! its exit code (2: a usage error clap catches, or `submit`'s rejection; 78: a refused config;
//! 3: `status` of a stack that is not running; 1: the rest) and a message naming the argument or
//! file and what is wrong, and changes nothing: the case's folder (its fixtures, existing outputs
//! among them) is the same byte for byte afterwards, and no process is left running in it.
//!
//! To add a case, add a line to [`CASES`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use softarm_test_support::{
    DEMO_WAYPOINTS, Guard, config_text, hardware_config_text, output, with_overrides,
};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
/// The test rig's binary: the product's commands, and `emulate`, `soak`, `bench`.
const RIG: &str = env!("CARGO_BIN_EXE_softarm-rig");
/// Longest any case may take: none waits for a stack that is not there.
const LIMIT: Duration = Duration::from_secs(20);

/// One command line and what it must give. In `args`, `{ns}` is the case's own namespace;
/// other names are fixtures in the case's folder (see [`fixtures`]), its working folder.
struct Case {
    name: &'static str,
    /// `softarm` ([`BIN`]) or `softarm-rig` ([`RIG`]).
    bin: &'static str,
    args: &'static [&'static str],
    code: i32,
    /// Each is in stderr.
    stderr: &'static [&'static str],
    /// Each is in stdout (`submit` prints its rejections there: they are its answer).
    stdout: &'static [&'static str],
}

const fn case(
    name: &'static str,
    args: &'static [&'static str],
    code: i32,
    stderr: &'static [&'static str],
) -> Case {
    Case {
        name,
        bin: BIN,
        args,
        code,
        stderr,
        stdout: &[],
    }
}

/// [`case`] of the test rig's binary.
const fn rig(
    name: &'static str,
    args: &'static [&'static str],
    code: i32,
    stderr: &'static [&'static str],
) -> Case {
    Case {
        bin: RIG,
        ..case(name, args, code, stderr)
    }
}

/// `submit` refusing the set: exit 2, the reason on stdout.
const fn rejected(
    name: &'static str,
    args: &'static [&'static str],
    why: &'static [&'static str],
) -> Case {
    Case {
        name,
        bin: BIN,
        args,
        code: 2,
        stderr: &[],
        stdout: why,
    }
}

const USAGE: i32 = 2;
const CONFIG: i32 = 78;
const FAILED: i32 = 1;

#[rustfmt::skip]
const CASES: &[Case] = &[
    // Usage errors, caught by clap.
    case("no subcommand", &[], USAGE, &["Usage: softarm <COMMAND>"]),
    case("unknown subcommand", &["fly"], USAGE, &["unrecognized subcommand 'fly'"]),
    case("unknown flag", &["status", "--jsn"], USAGE, &["unexpected argument '--jsn'"]),
    case("record without --output", &["record", "--duration", "1"], USAGE, &["--output <OUTPUT>"]),
    case("record --duration not a number", &["record", "-o", "out.mcap", "--duration", "abc"], USAGE, &["invalid value 'abc' for '--duration"]),
    case("submit without a file", &["submit"], USAGE, &["<WAYPOINTS>"]),
    case("submit --executions negative", &["submit", "set.toml", "--executions", "-1"], USAGE, &["invalid value '-1' for '--executions"]),
    case("submit --executions not a number", &["submit", "set.toml", "--executions", "many"], USAGE, &["invalid value 'many' for '--executions"]),
    case("submit --executions beyond u32", &["submit", "set.toml", "--executions", "99999999999"], USAGE, &["'99999999999' for '--executions"]),
    case("train --seed negative", &["train", "--seed", "-1"], USAGE, &["invalid value '-1' for '--seed"]),
    case("train --output without --from", &["train", "--output", "out"], USAGE, &["--from <FILE>"]),
    case("train --from a CSV without its columns", &["train", "--from", "set.toml", "--config", "sim.toml"], FAILED, &["set.toml: a CSV recording needs its column map: --columns FILE"]),
    case("model without a subcommand", &["model"], USAGE, &["Usage: softarm model"]),
    case("model check without a recording", &["model", "check"], USAGE, &["<RECORDING>"]),
    case("model check with a column map that is not TOML", &["model", "check", "set.toml", "--columns", "garbage.toml", "--config", "sim.toml"], FAILED, &["garbage.toml:1:"]),
    case("demo --executions negative", &["demo", "--executions", "-5"], USAGE, &["invalid value '-5' for '--executions"]),
    case("demo --learner unknown", &["demo", "--learner", "magic"], USAGE, &["invalid value 'magic' for '--learner"]),
    case("demo --seed beyond u64", &["demo", "--seed", "99999999999999999999"], USAGE, &["for '--seed"]),
    rig("emulate without --config", &["emulate"], USAGE, &["--config <CONFIG>"]),
    rig("emulate --initial not a number", &["emulate", "--config", "hardware.toml", "--initial", "half"], USAGE, &["invalid value 'half' for '--initial"]),
    rig("bench --samples negative", &["bench", "--samples", "-1"], USAGE, &["invalid value '-1' for '--samples"]),
    rig("bench --seconds with a unit", &["bench", "--seconds", "1s"], USAGE, &["invalid value '1s' for '--seconds"]),
    case("config check without a file", &["config", "check"], USAGE, &["<FILE>"]),
    case("plot without --output", &["plot", "empty.mcap"], USAGE, &["--output <OUTPUT>"]),
    case("replay without a recording", &["replay"], USAGE, &["<RECORDING>"]),
    case("view --listen without an address", &["view", "--listen"], USAGE, &["a value is required for '--listen <LISTEN>'"]),
    rig("soak without --minutes", &["soak"], USAGE, &["--minutes <MINUTES>"]),

    // Out-of-range and non-finite numbers.
    case("record --duration 0", &["record", "-o", "out.mcap", "--duration", "0", "--namespace", "{ns}"], FAILED, &["--duration must be a positive number of seconds, got 0"]),
    case("record --duration negative", &["record", "-o", "out.mcap", "--duration", "-1", "--namespace", "{ns}"], FAILED, &["--duration must be a positive number of seconds, got -1"]),
    case("record --duration nan", &["record", "-o", "out.mcap", "--duration", "nan", "--namespace", "{ns}"], FAILED, &["--duration must be a positive number of seconds, got NaN"]),
    case("record --duration inf", &["record", "-o", "out.mcap", "--duration", "inf", "--namespace", "{ns}"], FAILED, &["--duration must be a positive number of seconds, got inf"]),
    case("record --duration too long", &["record", "-o", "out.mcap", "--duration", "1e300", "--namespace", "{ns}"], FAILED, &["--duration 1e300 s is too long"]),
    case("view --listen not an address", &["view", "--listen", "nowhere", "--namespace", "{ns}"], FAILED, &["--listen: \"nowhere\" is not an IP address and port (e.g. 127.0.0.1:8765)"]),
    case("view --listen a host name", &["view", "--listen", "localhost:8765", "--namespace", "{ns}"], FAILED, &["--listen: \"localhost:8765\" is not an IP address and port"]),
    case("view --listen port beyond 65535", &["view", "--listen", "127.0.0.1:70000", "--namespace", "{ns}"], FAILED, &["--listen: \"127.0.0.1:70000\" is not an IP address and port"]),
    case("view --listen beyond loopback", &["view", "--listen", "0.0.0.0:8765", "--namespace", "{ns}"], FAILED, &["--listen: 0.0.0.0:8765 is not a loopback address", "set view.allow_remote = true in the config"]),
    rig("emulate --initial above 1", &["emulate", "--config", "hardware.toml", "--initial", "2"], FAILED, &["--initial must be in [0, 1], got 2"]),
    rig("emulate --initial negative", &["emulate", "--config", "hardware.toml", "--initial", "-0.5"], FAILED, &["--initial must be in [0, 1], got -0.5"]),
    rig("emulate --initial nan", &["emulate", "--config", "hardware.toml", "--initial", "nan"], FAILED, &["--initial must be in [0, 1], got NaN"]),
    rig("emulate --corrupt-bytes above 1", &["emulate", "--config", "hardware.toml", "--corrupt-bytes", "2"], FAILED, &["--corrupt-bytes must be a probability in [0, 1], got 2"]),
    rig("emulate --drop-replies nan", &["emulate", "--config", "hardware.toml", "--drop-replies", "nan"], FAILED, &["--drop-replies must be a probability in [0, 1], got NaN"]),
    rig("emulate --fault-seed not a number", &["emulate", "--config", "hardware.toml", "--fault-seed", "x"], USAGE, &["invalid value 'x' for '--fault-seed"]),
    rig("bench --seconds 0", &["bench", "--seconds", "0"], FAILED, &["--seconds must be in [1, 600]"]),
    rig("bench --seconds inf", &["bench", "--seconds", "inf"], FAILED, &["--seconds must be in [1, 600]"]),
    rig("bench --samples 0", &["bench", "--samples", "0"], FAILED, &["--samples must be in [1, 1000000]"]),
    rig("bench --ipc-rate-hz 0", &["bench", "--ipc-rate-hz", "0"], FAILED, &["--ipc-rate-hz must be in [10, 20000]"]),
    rig("bench --ticks 0", &["bench", "--ticks", "0"], FAILED, &["--ticks and --reconditions must be > 0"]),
    rig("bench --rate-hz 0", &["bench", "--rate-hz", "0"], FAILED, &["--rate-hz must be in [10, 1000]", "got 0"]),
    rig("bench --rate-hz nan", &["bench", "--rate-hz", "nan"], FAILED, &["--rate-hz must be in [10, 1000]", "got NaN"]),
    rig("bench --fifo 0", &["bench", "--fifo", "0"], FAILED, &["--fifo must be a SCHED_FIFO priority in [1, 99], got 0"]),
    rig("bench --fifo 100", &["bench", "--fifo", "100"], FAILED, &["--fifo must be a SCHED_FIFO priority in [1, 99], got 100"]),
    rig("bench --wakeup 0", &["bench", "--wakeup", "0"], FAILED, &["--wakeup must be in (0, 3600] s"]),
    rig("bench --wakeup negative", &["bench", "--wakeup", "-1"], FAILED, &["--wakeup must be in (0, 3600] s"]),
    rig("bench --wakeup with --rate-hz 0", &["bench", "--wakeup", "0.1", "--rate-hz", "0"], FAILED, &["--rate-hz in [1, 10000]"]),
    case("demo --executions 0", &["demo", "--executions", "0"], FAILED, &["--executions must be at least 1"]),
    case("demo --executions above the limit", &["demo", "--executions", "10001"], FAILED, &["--executions: 10001 executions; 1 to 10000 are allowed"]),
    case("demo --seed beyond i64", &["demo", "--seed", "18446744073709551615"], FAILED, &["--seed must be at most 9223372036854775807"]),
    rejected("submit --executions 0", &["submit", "set.toml", "--executions", "0", "--namespace", "{ns}"], &["rejected: --executions 0: 1 to 10000 are allowed"]),
    rejected("submit --executions above the limit", &["submit", "set.toml", "--executions", "10001", "--namespace", "{ns}"], &["rejected: --executions 10001: 1 to 10000 are allowed"]),

    // Namespaces.
    case("--namespace with a space", &["status", "--namespace", "a b"], FAILED, &["--namespace: namespace \"a b\" is not valid"]),
    case("--namespace empty", &["stats", "--namespace", ""], FAILED, &["--namespace: namespace \"\" is not valid"]),
    case("--namespace too long", &["estop", "--namespace", "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa"], FAILED, &["--namespace: namespace \"aaaa", "use 1 to 100 of"]),
    case("--namespace starting with /", &["controller", "--namespace", "/softarm"], FAILED, &["--namespace: namespace \"/softarm\" is not valid"]),
    case("--namespace not ASCII", &["record", "-o", "keep.mcap", "--duration", "1", "--namespace", "bär"], FAILED, &["--namespace: namespace \"bär\" is not valid"]),

    // Files: missing, garbage, truncated, directories, wrong kinds, unwritable places.
    case("--config missing", &["status", "--config", "missing.toml"], CONFIG, &["missing.toml: cannot read the config: No such file"]),
    case("--config garbage", &["estop", "--config", "garbage.toml"], CONFIG, &["garbage.toml:1: key with no value"]),
    case("--config a directory", &["learner", "--config", "folder"], CONFIG, &["folder: cannot read the config: Is a directory"]),
    case("up --config garbage", &["up", "--config", "garbage.toml"], CONFIG, &["garbage.toml:1:"]),
    case("controller --config missing", &["controller", "--config", "missing.toml"], CONFIG, &["missing.toml: cannot read the config"]),
    case("sim --config garbage", &["sim", "--config", "garbage.toml"], CONFIG, &["garbage.toml:1:"]),
    case("train --config garbage", &["train", "--config", "garbage.toml"], CONFIG, &["garbage.toml:1:"]),
    case("submit --config garbage", &["submit", "set.toml", "--config", "garbage.toml"], CONFIG, &["garbage.toml:1:"]),
    case("record --config missing", &["record", "-o", "out.mcap", "--config", "missing.toml"], CONFIG, &["missing.toml: cannot read the config"]),
    case("view --config garbage", &["view", "--config", "garbage.toml"], CONFIG, &["garbage.toml:1: key with no value"]),
    case("up with view.listen beyond loopback", &["up", "--config", "remote.toml"], CONFIG, &["remote.toml:", ": view.listen: 0.0.0.0:8765 is not a loopback address"]),
    case("view with view.listen beyond loopback", &["view", "--config", "remote.toml"], CONFIG, &["remote.toml:", ": view.listen: 0.0.0.0:8765 is not a loopback address"]),
    case("ros2 --config garbage", &["ros2", "--config", "garbage.toml"], CONFIG, &["garbage.toml:1: key with no value"]),
    case("ros2 with ros2.domain_id beyond 232", &["ros2", "--config", "domain.toml"], CONFIG, &["domain.toml:", ": ros2.domain_id: must be 0 to 232"]),
    case("up with ros2.domain_id beyond 232", &["up", "--config", "domain.toml"], CONFIG, &["domain.toml:", ": ros2.domain_id: must be 0 to 232"]),
    rig("bench --config garbage", &["bench", "--config", "garbage.toml"], CONFIG, &["garbage.toml:1:"]),
    case("config check missing", &["config", "check", "missing.toml"], CONFIG, &["missing.toml: cannot read the file"]),
    case("config check garbage", &["config", "check", "garbage.toml"], CONFIG, &["garbage.toml:1: key with no value"]),
    case("config check a directory", &["config", "check", "folder"], CONFIG, &["folder: cannot read the file: Is a directory"]),
    case("config check a file of no kind", &["config", "check", "colour.toml"], CONFIG, &["colour.toml: cannot tell what this file is from its top-level keys (colour, shape): give `--as"]),
    case("config check a set beyond the workspace", &["config", "check", "far.toml", "--config", "sim.toml"], CONFIG, &["far.toml: against the config's limits: "]),
    case("config check a set past its duration", &["config", "check", "late.toml"], CONFIG, &["late.toml: ", "point"]),
    case("config check a bad arm file", &["config", "check", "arm-bad.toml"], CONFIG, &["arm-bad.toml:4: arm.modules[0].tendons"]),
    case("config check a set --as arm", &["config", "check", "set.toml", "--as", "arm"], CONFIG, &["set.toml:4: arm: unknown field `duration_s`"]),
    case("config check a column map of another arm", &["config", "check", "columns.toml"], FAILED, &["columns.toml: the column map names 3 actuators; the arm has 6"]),
    case("config check a column map with a bad unit", &["config", "check", "columns.toml", "--arm", "arm-three.toml"], FAILED, &["columns.toml", "unit `furlong` does not parse: give m, cm or mm"]),
    case("config check a scenario for another arm", &["config", "check", "scenario-bad.toml"], CONFIG, &["scenario-bad.toml", "arm.actuator_offset_m"]),
    case("sim --scenario unknown", &["sim", "--config", "sim.toml", "--scenario", "nowhere"], CONFIG, &["nowhere: no such scenario file, nor a shipped scenario"]),
    case("up --scenario unknown", &["up", "--config", "sim.toml", "--scenario", "nowhere"], CONFIG, &["nowhere: no such scenario"]),
    case("demo --scenario unknown", &["demo", "--scenario", "nowhere"], CONFIG, &["nowhere: no such scenario"]),
    case("demo --drift unknown", &["demo", "--drift", "nowhere"], CONFIG, &["nowhere: no such scenario"]),
    case("demo --drift a fixed arm", &["demo", "--drift", "twist"], FAILED, &["--drift twist: this scenario does not change while the arm runs"]),
    case("demo --drift with --scenario", &["demo", "--drift", "creeping", "--scenario", "twist"], USAGE, &["'--drift <NAME|FILE>' cannot be used with '--scenario <SCENARIO>'"]),
    rig("soak --scenarios unknown", &["soak", "--minutes", "1", "--scenarios", "creeping,nowhere"], CONFIG, &["--scenarios: nowhere: no such scenario"]),
    case("tendon without [tendon]", &["tendon", "--config", "sim.toml"], CONFIG, &["sim.toml: no [tendon] section"]),
    case("tracker without [tracker]", &["tracker", "--config", "sim.toml"], CONFIG, &["sim.toml: no [tracker] section"]),
    rig("emulate without [tendon]", &["emulate", "--config", "sim.toml"], CONFIG, &["sim.toml: no [tendon] section to emulate"]),
    rig("emulate --config garbage", &["emulate", "--config", "garbage.toml"], CONFIG, &["garbage.toml:1:"]),
    case("tendon with no device", &["tendon", "--config", "hardware.toml"], FAILED, &["cannot open the motor bus", "no-tendon (tendon.port)"]),
    case("tracker with no device", &["tracker", "--config", "hardware.toml"], FAILED, &["cannot open the tracker", "no-tracker (tracker.port)"]),
    rig("emulate --write-config over its --config", &["emulate", "--config", "hardware.toml", "--write-config", "./hardware.toml"], FAILED, &["--write-config ./hardware.toml is the --config it would copy"]),
    rig("emulate --write-config a directory", &["emulate", "--config", "hardware.toml", "--write-config", "folder"], FAILED, &["--write-config folder: it is a directory"]),
    rig("emulate --write-config under a file", &["emulate", "--config", "hardware.toml", "--write-config", "file/x.toml"], FAILED, &["--write-config file/x.toml: file is not a folder"]),
    case("record -o not .mcap", &["record", "-o", "out.txt", "--duration", "1", "--namespace", "{ns}"], FAILED, &["out.txt: a recording's name must end in .mcap"]),
    case("record -o a directory", &["record", "-o", "folder.mcap", "--duration", "1", "--namespace", "{ns}"], FAILED, &["cannot write the recording to folder.mcap: it is a directory"]),
    case("record -o under a file", &["record", "-o", "file/x.mcap", "--duration", "1", "--namespace", "{ns}"], FAILED, &["cannot write the recording to file/x.mcap: file is not a folder"]),
    case("record -o in no folder", &["record", "-o", "nowhere/x.mcap", "--duration", "1", "--namespace", "{ns}"], FAILED, &["cannot write the recording to nowhere/x.mcap: there is no folder nowhere"]),
    case("replay missing", &["replay", "missing.mcap"], FAILED, &["reading missing.mcap: No such file"]),
    case("replay a directory", &["replay", "folder"], FAILED, &["reading folder: Is a directory"]),
    case("replay garbage", &["replay", "garbage.toml"], FAILED, &["garbage.toml: damaged"]),
    case("replay truncated", &["replay", "truncated.mcap"], FAILED, &["truncated.mcap: damaged"]),
    case("plot -o .jpg", &["plot", "empty.mcap", "-o", "out.jpg"], FAILED, &["cannot write the plot to out.jpg: unsupported extension \"jpg\""]),
    case("plot -o a directory", &["plot", "empty.mcap", "-o", "folder"], FAILED, &["cannot write the plot to folder: it is a directory"]),
    case("plot -o under a file", &["plot", "empty.mcap", "-o", "file/x.svg"], FAILED, &["cannot write the plot to file/x.svg: file is not a folder"]),
    case("plot missing", &["plot", "missing.mcap", "-o", "out.png"], FAILED, &["reading missing.mcap: No such file"]),
    case("plot garbage", &["plot", "garbage.toml", "-o", "out.png"], FAILED, &["garbage.toml: damaged"]),
    case("plot truncated over an existing plot", &["plot", "truncated.mcap", "-o", "keep.png"], FAILED, &["truncated.mcap: damaged"]),
    case("plot a recording with nothing to plot", &["plot", "empty.mcap", "-o", "keep.svg"], FAILED, &["the recording has no conditioning samples"]),
    rejected("submit missing", &["submit", "missing.toml", "--namespace", "{ns}"], &["rejected: missing.toml: cannot read: No such file"]),
    rejected("submit garbage", &["submit", "garbage.toml", "--namespace", "{ns}"], &["rejected: garbage.toml: line 1"]),
    rejected("submit a directory", &["submit", "folder", "--namespace", "{ns}"], &["rejected: folder: cannot read: Is a directory"]),
    rejected("submit a point outside the workspace", &["submit", "far.toml", "--namespace", "{ns}"], &["rejected: far.toml: point 1: position", "outside the workspace box"]),
    rejected("submit a point after the duration", &["submit", "late.toml", "--namespace", "{ns}"], &["rejected: late.toml: line 6: point 2: time 3 s is outside (0, 2] s"]),
    case("demo --set missing", &["demo", "--set", "missing.toml"], FAILED, &["--set: missing.toml: cannot read: No such file"]),
    case("demo --set garbage", &["demo", "--set", "garbage.toml"], FAILED, &["--set: garbage.toml: line 1"]),
    case("demo --set outside the workspace", &["demo", "--set", "far.toml"], FAILED, &["--set far.toml: point 1: position", "outside the workspace box"]),
    case("demo --then a directory", &["demo", "--then", "folder"], FAILED, &["--then: folder: cannot read: Is a directory"]),
    case("demo --record not .mcap", &["demo", "--record", "out.txt"], FAILED, &["--record: out.txt: a recording's name must end in .mcap"]),
    case("demo --record in no folder", &["demo", "--record", "nowhere/x.mcap"], FAILED, &["--record: cannot write the recording to nowhere/x.mcap: there is no folder nowhere"]),
    case("demo --model-dir a file", &["demo", "--model-dir", "file"], FAILED, &["the model folder file is not a folder"]),
    case("emulate in the product", &["emulate", "--config", "hardware.toml"], USAGE, &["`emulate` is the test rig's", "softarm-rig emulate"]),
    case("soak in the product", &["soak", "--minutes", "1"], USAGE, &["`soak` is the test rig's", "softarm-rig soak"]),
    rig("install from the test rig", &["install", "--root", "root"], FAILED, &["softarm-rig is not installed: `softarm install` installs the product alone"]),
    case("install --prefix relative", &["install", "--root", "root", "--prefix", "relative"], FAILED, &["--prefix must be an absolute path, got relative"]),
    case("install --root a file", &["install", "--root", "file"], FAILED, &["writing file/usr/local/bin/softarm: Not a directory"]),
    case("uninstall --root without a folder", &["uninstall", "--root"], USAGE, &["a value is required for '--root <DIR>'"]),
    case("install --config garbage", &["install", "--root", "root", "--config", "garbage.toml"], CONFIG, &["garbage.toml:1: key with no value"]),
    case("uninstall --prefix relative", &["uninstall", "--root", "root", "--prefix", "relative"], FAILED, &["--prefix must be an absolute path, got relative"]),

    // Clients without a stack: said in bounded time, not waited for.
    case("status without a stack", &["status", "--namespace", "{ns}"], 3, &[]),
    case("stats without a stack", &["stats", "--namespace", "{ns}"], FAILED, &["no controller runs in namespace \"softarm/test-cli-", "is `softarm up` running there"]),
    case("stats --follow without a stack", &["stats", "--follow", "--namespace", "{ns}"], FAILED, &["no controller runs in namespace"]),
    case("train without a stack", &["train", "--config", "sim.toml"], FAILED, &["no controller answered the demonstration request in namespace \"softarm/test-cli-", "softarm up"]),
];

/// What a case's folder holds before it runs.
fn fixtures(dir: &Path, namespace: &str, recording: &[u8]) {
    let write = |name: &str, bytes: &[u8]| std::fs::write(dir.join(name), bytes).unwrap();
    write("garbage.toml", b"garbage\n");
    write("colour.toml", b"colour = 3\n[shape]\nsides = 4\n");
    write(
        "arm-bad.toml",
        b"routing = \"coupled\"\n[[modules]]\nbackbone_m = 0.06\n\
          tendons = { count = 3, radius_m = -0.0045, length_m = [0.05, 0.07] }\n",
    );
    write(
        "arm-three.toml",
        b"[[modules]]\nbackbone_m = 0.06\n\
          tendons = { count = 3, radius_m = 0.0045, length_m = [0.05, 0.07] }\n",
    );
    write(
        "columns.toml",
        b"time = { column = \"t\", unit = \"s\" }\n\
          tip = { columns = [\"x\", \"y\", \"z\"], unit = \"furlong\" }\n\
          [[actuators]]\ncolumn = \"a\"\nunit = \"mm\"\n[[actuators]]\ncolumn = \"b\"\nunit = \"mm\"\n\
          [[actuators]]\ncolumn = \"c\"\nunit = \"mm\"\n",
    );
    write(
        "scenario-bad.toml",
        b"[arm]\nactuator_offset_m = [0.0, 0.0, 0.001]\n",
    );
    write("sim.toml", config_text(dir, namespace).as_bytes());
    let remote = [("view.listen", "0.0.0.0:8765".into())];
    write(
        "remote.toml",
        with_overrides(&config_text(dir, namespace), &remote).as_bytes(),
    );
    let domain = [("ros2.domain_id", 233.into())];
    write(
        "domain.toml",
        with_overrides(&config_text(dir, namespace), &domain).as_bytes(),
    );
    write(
        "hardware.toml",
        hardware_config_text(
            dir,
            namespace,
            &dir.join("no-tendon"),
            &dir.join("no-tracker"),
        )
        .as_bytes(),
    );
    write("set.toml", &std::fs::read(DEMO_WAYPOINTS).unwrap());
    write(
        "far.toml",
        b"duration_s = 2.0\n[[point]]\nt_s = 1.0\nposition_m = [0.0, 0.0, 0.3]\n",
    );
    write(
        "late.toml",
        b"duration_s = 2.0\n[[point]]\nt_s = 1.0\nposition_m = [0.1, 0.0, -0.45]\n\
          [[point]]\nt_s = 3.0\nposition_m = [0.0, 0.0, -0.5]\n",
    );
    write("empty.mcap", recording);
    write("truncated.mcap", &recording[..recording.len() / 2]);
    // Existing outputs a refused command must leave as they are.
    write("keep.mcap", b"an earlier recording\n");
    write("keep.png", b"an earlier plot\n");
    write("keep.svg", b"<svg>an earlier plot</svg>\n");
    write("file", b"a file where a folder is expected\n");
    std::fs::create_dir(dir.join("folder")).unwrap();
    std::fs::create_dir(dir.join("folder.mcap")).unwrap();
}

/// Every file under `dir` (relative path -> contents; `None` for a folder).
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Option<Vec<u8>>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, Option<Vec<u8>>>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let path = e.path();
            let rel = path.strip_prefix(root).unwrap().to_path_buf();
            if e.file_type().unwrap().is_dir() {
                out.insert(rel, None);
                walk(root, &path, out);
            } else {
                out.insert(rel, Some(std::fs::read(&path).unwrap_or_default()));
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// What changed between two snapshots, one line per path.
fn changes(
    before: &BTreeMap<PathBuf, Option<Vec<u8>>>,
    after: &BTreeMap<PathBuf, Option<Vec<u8>>>,
) -> Vec<String> {
    let mut out = Vec::new();
    for (path, was) in before {
        match after.get(path) {
            None => out.push(format!("{} removed", path.display())),
            Some(now) if now != was => out.push(format!("{} changed", path.display())),
            _ => {}
        }
    }
    for path in after.keys().filter(|p| !before.contains_key(*p)) {
        out.push(format!("{} created", path.display()));
    }
    out
}

/// Processes (pid, command line) whose working folder is `dir` or below it.
fn processes_in(dir: &Path) -> Vec<(i32, String)> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        if std::fs::read_link(e.path().join("cwd")).is_ok_and(|cwd| cwd.starts_with(dir)) {
            let cmd = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
            out.push((pid, String::from_utf8_lossy(&cmd).replace('\0', " ")));
        }
    }
    out
}

/// A valid recording of a namespace where nothing runs: the MCAP header, schemas, no message.
fn empty_recording(base: &Path) -> Vec<u8> {
    let out = base.join("empty.mcap");
    let status = Guard::spawn(
        Command::new(BIN)
            .args(["record", "-o"])
            .arg(&out)
            .args(["--duration", "0.1", "--namespace"])
            .arg(format!("softarm/test-cli-{}-recording", std::process::id()))
            .stdout(Stdio::null()),
    )
    .wait()
    .unwrap();
    assert!(status.success(), "recording the fixture: {status}");
    std::fs::read(&out).unwrap()
}

/// Runs case `i` in a folder of its own under `base`; what went wrong, if anything.
fn run(i: usize, c: &Case, base: &Path, recording: &[u8]) -> Option<String> {
    let dir = base.join(format!("case-{i}"));
    std::fs::create_dir_all(&dir).unwrap();
    let namespace = format!("softarm/test-cli-{}-{i}", std::process::id());
    fixtures(&dir, &namespace, recording);
    let before = snapshot(&dir);
    let args: Vec<String> = c
        .args
        .iter()
        .map(|a| a.replace("{ns}", &namespace))
        .collect();
    let (out, err) = (base.join(format!("{i}.out")), base.join(format!("{i}.err")));
    let started = Instant::now();
    // Its group is killed when `child` is dropped, after the check that nothing is left.
    let mut child = Guard::spawn(
        Command::new(c.bin)
            .args(&args)
            .current_dir(&dir)
            // Nothing the command might write for the user (a cache, a model) goes elsewhere.
            .env("HOME", &dir)
            .env("XDG_CACHE_HOME", dir.join("cache"))
            .env("RUST_LOG", "warn")
            .env_remove("RUST_BACKTRACE")
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&out).unwrap())
            .stderr(std::fs::File::create(&err).unwrap()),
    );
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if started.elapsed() > LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            break std::process::ExitStatus::default();
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let took = started.elapsed();
    let stdout = std::fs::read_to_string(&out).unwrap_or_default();
    let stderr = std::fs::read_to_string(&err).unwrap_or_default();
    let mut wrong = Vec::new();
    if took > LIMIT {
        wrong.push(format!("still running after {LIMIT:?}: killed"));
    } else if status.code() != Some(c.code) {
        wrong.push(format!("exit {status}, want {}", c.code));
    }
    if stderr.contains("panicked") {
        wrong.push("it panicked".into());
    }
    for want in c.stderr {
        let want = want.replace("{ns}", &namespace);
        if !stderr.contains(&want) {
            wrong.push(format!("stderr lacks {want:?}"));
        }
    }
    for want in c.stdout {
        if !stdout.contains(want) {
            wrong.push(format!("stdout lacks {want:?}"));
        }
    }
    for change in changes(&before, &snapshot(&dir)) {
        wrong.push(format!("state changed: {change}"));
    }
    for (pid, cmd) in processes_in(&dir) {
        // Not ours to leave running: ended, and the case fails.
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(pid),
            nix::sys::signal::Signal::SIGKILL,
        );
        wrong.push(format!("left running: {pid} {cmd}"));
    }
    if wrong.is_empty() {
        let _ = std::fs::remove_dir_all(&dir);
        return None;
    }
    Some(format!(
        "case {:?} (softarm {}) in {:.1} s:\n  {}\n  stdout: {}\n  stderr: {}",
        c.name,
        args.join(" "),
        took.as_secs_f64(),
        wrong.join("\n  "),
        stdout.trim_end(),
        stderr.trim_end()
    ))
}

#[test]
fn bad_arguments_are_refused_naming_what_and_where_and_change_nothing() {
    let base = std::env::temp_dir().join(format!("softarm-test-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&base);
    std::fs::create_dir_all(&base).unwrap();
    let recording = empty_recording(&base);
    // A few at a time: most cases take milliseconds, some wait a second or more for a stack.
    let next = AtomicUsize::new(0);
    let failures = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..4 {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(c) = CASES.get(i) else { break };
                    if let Some(f) = run(i, c, &base, &recording) {
                        failures.lock().unwrap().push((i, f));
                    }
                }
            });
        }
    });
    let mut failures = failures.into_inner().unwrap();
    failures.sort();
    let _ = std::fs::remove_dir_all(&base);
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n\n{}",
        failures.len(),
        CASES.len(),
        failures
            .iter()
            .map(|(_, f)| f.as_str())
            .collect::<Vec<_>>()
            .join("\n\n")
    );
}

/// The subcommands `bin --help` lists.
fn subcommands(bin: &str) -> Vec<String> {
    let out = output(Command::new(bin).arg("--help"));
    let help = String::from_utf8_lossy(&out.stdout);
    help.split("Commands:")
        .nth(1)
        .expect("a command list")
        .split("Options:")
        .next()
        .unwrap()
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .map(str::to_string)
        .collect()
}

/// Every subcommand of the product has a case, and every one the test rig adds has one of the
/// rig; the product has none of the rig's.
#[test]
fn every_subcommand_has_a_bad_argument_case() {
    let product = subcommands(BIN);
    assert!(product.len() >= 20, "{product:?}");
    let rig: Vec<String> = subcommands(RIG)
        .into_iter()
        .filter(|c| !product.contains(c))
        .collect();
    assert_eq!(rig, ["emulate", "bench", "soak"], "the test rig's own");
    let has_case = |bin: &str, c: &str| {
        CASES
            .iter()
            .any(|case| case.bin == bin && case.args.first() == Some(&c))
    };
    let missing: Vec<&String> = product
        .iter()
        .filter(|c| !has_case(BIN, c))
        .chain(rig.iter().filter(|c| !has_case(RIG, c)))
        .collect();
    assert!(
        missing.is_empty(),
        "no case for {missing:?}: add one to CASES"
    );
}

#[test]
fn estop_without_a_stack_latches_and_says_that_no_process_heard_it() {
    // Not a refusal: the latch is what every process that starts later reads.
    let dir = std::env::temp_dir().join(format!("softarm-test-cli-estop-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let namespace = format!("softarm/test-cli-estop-{}", std::process::id());
    let config = dir.join("sim.toml");
    std::fs::write(&config, config_text(&dir, &namespace)).unwrap();
    let latch = dir.join("state/estop");
    for (args, word) in [
        (&["estop"][..], "engaged"),
        (&["estop", "--reset"][..], "released"),
    ] {
        let started = Instant::now();
        let out = output(Command::new(BIN).args(args).arg("--config").arg(&config));
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            started.elapsed() < Duration::from_secs(5),
            "{args:?} took {:?}",
            started.elapsed()
        );
        // Latched, and said apart from "confirmed": a config of another stack lands here.
        assert_eq!(out.status.code(), Some(3), "{args:?}: {out:?}");
        assert!(
            stdout.contains(&format!(
                "e-stop {word} (the latch {} says {word}; no running process in namespace \"{namespace}\")",
                latch.display()
            )),
            "{args:?}: {stdout}"
        );
        assert_eq!(std::fs::read_to_string(&latch).unwrap().trim(), word);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `softarm config check` takes every file softarm ships for what it is and passes it (an arm
/// file was refused as a config with "unknown field connector_m").
#[test]
fn config_check_takes_every_shipped_file_for_what_it_is() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files: Vec<(PathBuf, &str, Vec<&str>)> = Vec::new();
    for (folder, kind) in [
        ("config/arms", "an [arm] file"),
        ("config/scenarios", "a scenario"),
        ("config/waypoints", "a way-point set"),
    ] {
        for e in std::fs::read_dir(root.join(folder)).unwrap().flatten() {
            files.push((e.path(), kind, vec![]));
        }
    }
    files.push((root.join("config/softarm.toml"), "a config", vec![]));
    files.push((root.join("config/hardware.toml"), "a config", vec![]));
    let recording = root.join("config/recordings/opencr-tdcr");
    let arm = recording.join("arm.toml");
    files.push((
        recording.join("columns.toml"),
        "a recording's column map",
        vec!["--arm", arm.to_str().unwrap()],
    ));
    files.push((arm.clone(), "an [arm] file", vec![]));
    let mujoco = root.join("config/mujoco");
    files.push((mujoco.join("opencr-ftdcr-v6.toml"), "a plant file", vec![]));
    for scenario in ["tip-load.toml", "gravity.toml"] {
        files.push((mujoco.join(scenario), "a scenario", vec![]));
    }
    for (file, kind, extra) in &files {
        let out = output(
            Command::new(BIN)
                .args(["config", "check"])
                .arg(file)
                .args(extra)
                .env("SOFTARM_CONFIG", root.join("config/softarm.toml")),
        );
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success() && stdout.contains(&format!(": ok, taken for {kind}: ")),
            "{}: {stdout}{}",
            file.display(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    assert!(files.len() >= 20, "{} files", files.len());
}
