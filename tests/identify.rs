//! An arm identified from a real arm's recording, end to end through the binary: `softarm
//! train --from` on the OpenCR TDCR's training recording (tests/data/real-arm/, single- and
//! two-segment motions), `softarm model check` on its held-out one (three-segment motions the
//! training one never has), and bad recordings refused with their file, line and column while
//! nothing is written.

use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
const COLUMNS: &str = "config/recordings/opencr-tdcr/columns.toml";
const ARM: &str = "config/recordings/opencr-tdcr/arm.toml";

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn folder(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("softarm-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `softarm train --from RECORDING` of the OpenCR arm with its columns, into `out`.
fn train_opencr(recording: &Path, out: &Path) -> std::process::Output {
    softarm(&[
        "train",
        "--from",
        recording.to_str().unwrap(),
        "--columns",
        COLUMNS,
        "--arm",
        ARM,
        "--output",
        out.to_str().unwrap(),
    ])
}

fn softarm(args: &[&str]) -> std::process::Output {
    Command::new(BIN)
        .args(args)
        .current_dir(root())
        .env_remove("SOFTARM_CONFIG")
        .output()
        .expect("softarm runs")
}

/// A number after `"key":` in the JSON of `softarm model check` (its first occurrence: `all`).
fn figure(json: &str, key: &str) -> f64 {
    let at = json.find(&format!("\"{key}\":")).expect(key) + key.len() + 3;
    let end = json[at..].find([',', '}']).unwrap() + at;
    json[at..end].parse().unwrap()
}

#[test]
fn a_real_arm_calibrated_on_some_motions_predicts_others_it_never_saw() {
    let out = folder("identify");
    let trained = train_opencr(&root().join("tests/data/real-arm/train.csv"), &out);
    let said = String::from_utf8_lossy(&trained.stdout);
    assert!(
        trained.status.success(),
        "{said}{}",
        String::from_utf8_lossy(&trained.stderr)
    );
    assert!(said.contains("RMS mm over held-out motions"), "{said}");
    let model = out.join("identified.toml");
    // The model file, or the folder train wrote it in.
    let check = |recording: &str, model: &Path| {
        let c = softarm(&[
            "model",
            "check",
            recording,
            "--columns",
            COLUMNS,
            "--arm",
            ARM,
            "--model",
            model.to_str().unwrap(),
            "--json",
        ]);
        assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stderr));
        String::from_utf8(c.stdout).unwrap()
    };
    let held_out = check("tests/data/real-arm/val.csv", &model);
    let seen = check("tests/data/real-arm/train.csv", &out);
    // The arm repeats to about 4.4 mm RMS; a constant-curvature fit reaches 13 to 14 mm on
    // motions like these.
    let rms = figure(&held_out, "offset_removed_rms_mm");
    assert!(rms < 14.0 && rms > 4.0, "{held_out}");
    assert!(
        figure(&seen, "rms_mm") < figure(&held_out, "rms_mm"),
        "{seen}"
    );
    for family in ["all3_same", "all3_scurve", "all3_spiral"] {
        assert!(held_out.contains(&format!("\"{family}\":{{")), "{held_out}");
    }
    // Beside it, the physical model alone and the bundle's data-driven models, each checked.
    for model in ["physical", "rbf_network", "polynomial"] {
        assert!(
            held_out.contains(&format!("\"{model}\":{{\"all\":{{")),
            "{held_out}"
        );
    }
    // The bundle is one the stack reads for this arm.
    let arm_text = std::fs::read_to_string(root().join(ARM)).unwrap();
    let layout = softarm_config::arms::check(&arm_text, ARM)
        .unwrap()
        .layout()
        .unwrap();
    let bundle = softarm_model::bundle::Model::<9>::read_for_arm(&out, &layout.identity())
        .expect("the bundle reads back for its arm");
    assert_eq!(
        bundle.actuation.len(),
        3,
        "a primitive per class: pair, seg, tendon"
    );
    // The twin is an arm the sim runs.
    let twin = out.join("twin-arm.toml");
    let text = std::fs::read_to_string(&twin).unwrap();
    softarm_config::arms::check(&text, "twin-arm.toml").expect("the twin is an [arm]");
    // Checked against another arm (the same but for its first module's names), the model is
    // refused by name.
    let renamed = arm_text.replacen(
        "length_m = [0.087, 0.113] }",
        "length_m = [0.087, 0.113], names = [\"b1\", \"b2\", \"b3\"] }",
        1,
    );
    assert_ne!(renamed, arm_text);
    let other_arm = out.join("renamed-arm.toml");
    std::fs::write(&other_arm, renamed).unwrap();
    let other = softarm(&[
        "model",
        "check",
        "tests/data/real-arm/val.csv",
        "--columns",
        COLUMNS,
        "--arm",
        other_arm.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
    ]);
    assert!(!other.status.success());
    let said = String::from_utf8_lossy(&other.stderr);
    assert!(said.contains("identified.toml: made for the arm"), "{said}");
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn a_bad_recording_is_refused_where_it_is_bad_and_nothing_is_written() {
    let dir = folder("identify-bad");
    let good = std::fs::read_to_string(root().join("tests/data/real-arm/train.csv")).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    // (the field of line 3 spoilt, its new value, what the error must say)
    let cases = [
        (2, "zero", ":3: column `servo_1_mm`: `zero` is not a number"),
        (
            4,
            "NaN",
            ": column `servo_23_mm`: NaN is not a finite number",
        ),
        (0, "1675513850.0", "time goes backwards"),
        (3, "40.0", "outside its stroke"),
    ];
    for (k, (field, value, says)) in cases.iter().enumerate() {
        let mut text: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
        let mut fields: Vec<&str> = text[2].split(',').collect();
        fields[*field] = value;
        text[2] = fields.join(",");
        let path = dir.join(format!("bad{k}.csv"));
        std::fs::write(&path, text.join("\n")).unwrap();
        let out = dir.join(format!("out{k}"));
        let r = train_opencr(&path, &out);
        let said = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "case {k}");
        assert!(said.contains(&format!("bad{k}.csv:3")), "case {k}: {said}");
        assert!(said.contains(says), "case {k}: {said}");
        assert!(!out.exists(), "case {k} wrote {}", out.display());
    }
    // Too few rows for the arm's parameters.
    let path = dir.join("short.csv");
    std::fs::write(&path, lines[..40].join("\n")).unwrap();
    let r = train_opencr(&path, &dir.join("short"));
    let said = String::from_utf8_lossy(&r.stderr);
    assert!(said.contains("39 rows; calibrating this arm's"), "{said}");
    assert!(!dir.join("short").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// How far a twin is from the arm that made its recording: the worst backbone, radius and
/// angle, and the tool (each printed).
#[derive(Debug)]
struct Off {
    length_m: f64,
    radius_m: f64,
    angle_rad: f64,
    tool_m: f64,
    /// Each tendon's angle off, least first.
    angles_rad: Vec<f64>,
}

/// The twin at `path` against `truth` (an `[arm]`'s text): the same mount and actuator count,
/// and how far off.
fn twin_against(path: &Path, truth: &str) -> Off {
    let twin = std::fs::read_to_string(path).unwrap();
    let layout = |text: &str, name: &str| {
        softarm_config::arms::check(text, name)
            .unwrap()
            .layout()
            .unwrap()
    };
    let (found, truth) = (layout(&twin, "twin"), layout(truth, "truth"));
    assert_eq!(found.mount, truth.mount);
    assert_eq!(found.actuators().len(), truth.actuators().len());
    let mut off = Off {
        length_m: 0.0,
        radius_m: 0.0,
        angle_rad: 0.0,
        tool_m: (found.tool_m - truth.tool_m).abs(),
        angles_rad: Vec::new(),
    };
    for (f, t) in found.modules().iter().zip(truth.modules()) {
        let e = (f.backbone_m.unwrap() - t.backbone_m.unwrap()).abs();
        println!("backbone {:.2} mm off", e * 1e3);
        off.length_m = off.length_m.max(e);
    }
    for (f, t) in found.actuators().iter().zip(truth.actuators()) {
        let da = (f.angle_rad - t.angle_rad + std::f64::consts::PI)
            .rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        println!(
            "{}: radius {:.3} mm off, angle {:.2} deg off",
            f.name,
            (f.radius_m - t.radius_m) * 1e3,
            da.to_degrees()
        );
        off.radius_m = off.radius_m.max((f.radius_m - t.radius_m).abs());
        off.angle_rad = off.angle_rad.max(da.abs());
        off.angles_rad.push(da.abs());
    }
    off.angles_rad.sort_by(f64::total_cmp);
    println!("tool {:.2} mm off", off.tool_m * 1e3);
    off
}

/// The nine-tendon TDCR of `config/arms/tdcr.toml` as it really is in this test: other
/// backbones, radii, module rotations and tool. The sim runs it; the calibration is told
/// only the shipped TDCR.
const TRUE_TDCR: &str = r#"
routing = "coupled"
mount = "standing"
connector_m = 0.0
tool_m = 0.018
[[modules]]
backbone_m = 0.066
tendons = { count = 3, radius_m = 0.005, length_m = [0.056, 0.076] }
[[modules]]
backbone_m = 0.056
rotation_deg = 48
tendons = { count = 3, radius_m = 0.0042, length_m = [0.112, 0.132] }
[[modules]]
backbone_m = 0.062
rotation_deg = 75
tendons = { count = 3, radius_m = 0.0047, length_m = [0.174, 0.194] }
"#;

/// One settled pose of a recording made in the sim.
struct Pose {
    time_s: f64,
    label: String,
    /// Each tendon pulled in from its straight length (m), as the motor reports it.
    pull_m: Vec<f64>,
    /// The tip as the tracker sees it (m, the stack's base frame).
    tip_m: [f64; 3],
}

/// A lab's recording of `arm` (an `[arm]` file's text) in softarm's sim (its plant with the
/// shipped realism: lag, rate limit, backlash, correlated actuation noise, drift, tracker
/// noise): each motion bends each module by its share (`bends`) of the motion's amplitude
/// towards `direction_deg`, in eight poses, each held 2 s before it is logged. `straight_m`:
/// each tendon's length on the straight arm.
fn sim_poses(arm: &str, straight_m: &[f64], motions: &[(String, Vec<f64>, f64)]) -> Vec<Pose> {
    use softarm_sim::plant::{Body, Plant};
    let arm = softarm_config::arms::check(arm, "the true arm").unwrap();
    let layout = arm.layout().unwrap();
    let n = layout.actuators().len();
    let mut plant = Plant::of_body(
        Body::of_arm(&arm, &[]).unwrap(),
        softarm_config::sim::Realism::default(),
        &vec![0.5; n],
    )
    .unwrap();
    let mut out = Vec::new();
    for (label, bends, direction_deg) in motions {
        for step in 1..=8 {
            let theta = 0.1 * step as f64;
            let phi = direction_deg.to_radians();
            // Each tendon's length on the bent arm: what a lab's inverse kinematics commands.
            let command: Vec<f64> = (0..n)
                .map(|i| {
                    let a = &layout.actuators()[i];
                    let shortening: f64 = (0..=a.module)
                        .map(|m| a.radius_m * bends[m] * theta * (a.angle_rad - phi).cos())
                        .sum();
                    a.actuation_of(straight_m[i] - shortening)
                })
                .collect();
            let mut m = plant.step(&command, 0.01);
            for _ in 0..199 {
                m = plant.step(&command, 0.01);
            }
            out.push(Pose {
                time_s: plant.time(),
                label: label.clone(),
                pull_m: (0..n)
                    .map(|i| straight_m[i] - layout.actuators()[i].length_of(m.actuation[i]))
                    .collect(),
                tip_m: [m.position[0], m.position[1], m.position[2]],
            });
        }
    }
    out
}

/// [`sim_poses`] of [`TRUE_TDCR`] as CSV: t, label, a1..a9 (pulls, mm), x y z (mm).
fn sim_recording(motions: &[(String, [f64; 3], f64)]) -> String {
    let backbone = [0.066, 0.056, 0.062];
    let straight: Vec<f64> = (0..9)
        .map(|i| (0..=i / 3).map(|m| backbone[m]).sum())
        .collect();
    let motions: Vec<(String, Vec<f64>, f64)> = (motions.iter())
        .map(|(l, b, d)| (l.clone(), b.to_vec(), *d))
        .collect();
    let mut out = String::from("t,label,a1,a2,a3,a4,a5,a6,a7,a8,a9,x,y,z\n");
    for p in sim_poses(TRUE_TDCR, &straight, &motions) {
        let pulls: Vec<String> = p.pull_m.iter().map(|v| format!("{:.5}", v * 1e3)).collect();
        out.push_str(&format!(
            "{:.2},{},{},{:.4},{:.4},{:.4}\n",
            p.time_s,
            p.label,
            pulls.join(","),
            p.tip_m[0] * 1e3,
            p.tip_m[1] * 1e3,
            p.tip_m[2] * 1e3
        ));
    }
    out
}

#[test]
fn a_recording_made_in_the_sim_gives_back_the_arm_that_made_it() {
    let dir = folder("identify-sim");
    let mut train = Vec::new();
    for (k, bends) in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        .iter()
        .enumerate()
    {
        for d in [0.0, 90.0, 180.0, 270.0] {
            train.push((format!("rep1_seg{}_dir{d}", k + 1), *bends, d));
        }
    }
    for (name, bends) in [
        ("pair12_same", [1.0, 1.0, 0.0]),
        ("pair23_opp", [0.0, 1.0, -1.0]),
        ("pair13_opp", [1.0, 0.0, -1.0]),
    ] {
        for d in [45.0, 135.0, 225.0, 315.0] {
            train.push((format!("rep1_{name}_dir{d}"), bends, d));
        }
    }
    let held_out: Vec<(String, [f64; 3], f64)> = [30.0, 120.0, 210.0, 300.0]
        .iter()
        .flat_map(|d| {
            [
                (format!("rep1_all3_same_dir{d}"), [0.6, 0.6, 0.6], *d),
                (format!("rep1_all3_scurve_dir{d}"), [0.7, -0.5, 0.7], *d),
            ]
        })
        .collect();
    std::fs::write(dir.join("train.csv"), sim_recording(&train)).unwrap();
    std::fs::write(dir.join("val.csv"), sim_recording(&held_out)).unwrap();
    let mut map = String::from(
        "label = \"label\"\ntime = { column = \"t\", unit = \"s\" }\n\
         tip = { columns = [\"x\", \"y\", \"z\"], unit = \"mm\" }\n",
    );
    for i in 1..=9 {
        map.push_str(&format!(
            "[[actuators]]\ncolumn = \"a{i}\"\nunit = \"mm\"\n"
        ));
    }
    std::fs::write(dir.join("columns.toml"), map).unwrap();
    let path = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let trained = softarm(&[
        "train",
        "--from",
        &path("train.csv"),
        "--columns",
        &path("columns.toml"),
        "--arm",
        "tdcr",
        "--output",
        &path("model"),
    ]);
    let said = String::from_utf8_lossy(&trained.stdout);
    assert!(
        trained.status.success(),
        "{said}{}",
        String::from_utf8_lossy(&trained.stderr)
    );
    println!("{said}");
    let checked = softarm(&[
        "model",
        "check",
        &path("val.csv"),
        "--columns",
        &path("columns.toml"),
        "--arm",
        "tdcr",
        "--model",
        &path("model/identified.toml"),
        "--json",
    ]);
    let json = String::from_utf8(checked.stdout).unwrap();
    assert!(
        checked.status.success(),
        "{}",
        String::from_utf8_lossy(&checked.stderr)
    );
    println!("held out: {json}");

    // The geometry it found, against the arm that made the recording.
    let off = twin_against(&dir.join("model/twin-arm.toml"), TRUE_TDCR);
    // The sim's tracker alone is 0.5 mm per axis, 0.87 mm over three.
    let rms = figure(&json, "rms_mm");
    assert!(rms < 1.5, "{json}");
    // How the length splits between modules shows only in how the tip turns: the loosest.
    assert!(off.length_m < 0.004, "{off:?}");
    assert!(off.radius_m < 0.0005, "{off:?}");
    assert!(off.angle_rad < 3f64.to_radians(), "{off:?}");
    assert!(off.tool_m < 0.003, "{off:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A hanging arm of two modules of four tendons, as it really is in the next test.
const TRUE_HANGING: &str = r#"
routing = "coupled"
mount = "hanging"
connector_m = 0.0
tool_m = 0.015
[[modules]]
backbone_m = 0.09
rotation_deg = 20
tendons = { count = 4, radius_m = 0.006, length_m = [0.075, 0.105] }
[[modules]]
backbone_m = 0.08
rotation_deg = 35
tendons = { count = 4, radius_m = 0.005, length_m = [0.155, 0.185] }
"#;

/// What its lab configured: lengths, radii, rotations and tool a little off.
const CONFIGURED_HANGING: &str = r#"
routing = "coupled"
mount = "hanging"
connector_m = 0.0
tool_m = 0.01
[[modules]]
backbone_m = 0.095
tendons = { count = 4, radius_m = 0.0055, length_m = [0.075, 0.105] }
[[modules]]
backbone_m = 0.08
rotation_deg = 30
tendons = { count = 4, radius_m = 0.0055, length_m = [0.155, 0.185] }
"#;

/// Another arm, logged another way: two modules of four tendons hanging from a frame; no
/// labels; time in ms; the motion capture's own frame (the base 1.3 m up, turned 90°); each
/// tendon's length in metres from a zero 2 mm short of straight, larger let out; the columns
/// in another order beside one the map does not name. The same commands read it, the fit
/// finds the arm, and it predicts motions it never saw to within the sim's noise.
#[test]
fn a_recording_of_another_arm_logged_another_way_is_read_and_fitted() {
    let dir = folder("identify-other");
    let straight = [0.09, 0.09, 0.09, 0.09, 0.17, 0.17, 0.17, 0.17];
    let zero: Vec<f64> = straight.iter().map(|s| s - 0.002).collect();
    let origin = [0.5, -0.2, 1.3];
    let csv = |motions: &[(String, Vec<f64>, f64)]| {
        let mut out = String::from("time_ms,mx,my,mz,frame,t8,t7,t6,t5,t4,t3,t2,t1\n");
        for (k, p) in sim_poses(TRUE_HANGING, &straight, motions)
            .iter()
            .enumerate()
        {
            // The base frame turned 90° about z in the capture's: (x, y) -> (-y, x).
            let [x, y, z] = p.tip_m;
            let seen = [origin[0] - y, origin[1] + x, origin[2] + z];
            let lengths: Vec<String> = (0..8)
                .rev()
                .map(|i| format!("{:.7}", straight[i] - p.pull_m[i] - zero[i]))
                .collect();
            out.push_str(&format!(
                "{:.1},{:.6},{:.6},{:.6},{k},{}\n",
                p.time_s * 1e3,
                seen[0],
                seen[1],
                seen[2],
                lengths.join(",")
            ));
        }
        out
    };
    let mut train = Vec::new();
    for d in (0..8).map(|k| 45.0 * k as f64) {
        train.push((String::new(), vec![1.0, 0.0], d));
        train.push((String::new(), vec![0.0, 1.0], d));
    }
    for d in [0.0, 90.0, 180.0, 270.0] {
        train.push((String::new(), vec![1.0, -1.0], d));
    }
    let held_out: Vec<(String, Vec<f64>, f64)> = [20.0, 110.0, 200.0, 290.0]
        .iter()
        .flat_map(|d| {
            [
                (String::new(), vec![0.6, 0.6], *d),
                (String::new(), vec![0.8, 0.4], *d + 30.0),
            ]
        })
        .collect();
    std::fs::write(dir.join("train.csv"), csv(&train)).unwrap();
    std::fs::write(dir.join("val.csv"), csv(&held_out)).unwrap();
    std::fs::write(dir.join("arm.toml"), CONFIGURED_HANGING).unwrap();
    let mut map = String::from(
        "time = { column = \"time_ms\", unit = \"ms\" }\n\
         tip = { columns = [\"mx\", \"my\", \"mz\"], unit = \"m\", \
         base_origin_m = [0.5, -0.2, 1.3], base_rotation_deg = [0.0, 0.0, 90.0] }\n",
    );
    for (i, z) in zero.iter().enumerate() {
        map.push_str(&format!(
            "[[actuators]]\ncolumn = \"t{}\"\nunit = \"m\"\nsign = -1\nzero_length_m = {z}\n",
            i + 1
        ));
    }
    std::fs::write(dir.join("columns.toml"), map).unwrap();
    let path = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let with = |args: &[&str]| {
        let mut all: Vec<String> = args.iter().map(|a| a.to_string()).collect();
        all.extend(
            [
                "--columns",
                &path("columns.toml"),
                "--arm",
                &path("arm.toml"),
            ]
            .map(String::from),
        );
        let refs: Vec<&str> = all.iter().map(String::as_str).collect();
        let out = softarm(&refs);
        let said = String::from_utf8_lossy(&out.stdout).to_string();
        assert!(
            out.status.success(),
            "{args:?}: {said}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        said
    };
    println!(
        "{}",
        with(&[
            "train",
            "--from",
            &path("train.csv"),
            "--output",
            &path("model")
        ])
    );
    let json = with(&[
        "model",
        "check",
        &path("val.csv"),
        "--model",
        &path("model"),
        "--json",
    ]);
    println!("held out: {json}");
    let rms = figure(&json, "rms_mm");
    assert!(rms < 2.0, "{json}");
    // The twin: a hanging arm of eight tendons, each module turned as the true one is (the
    // base's turn the fit found in the tendons' angles: an [arm] has no base pose).
    let off = twin_against(&dir.join("model/twin-arm.toml"), TRUE_HANGING);
    assert!(off.radius_m < 0.0005, "{off:?}");
    // Four tendons a module: one of each opposite pair is slack in most poses, and its angle
    // shows only in the few that pull it; the rest within a degree and a half.
    assert!(off.angle_rad < 6f64.to_radians(), "{off:?}");
    assert!(off.angles_rad[6] < 1.5f64.to_radians(), "{off:?}");
    assert!(off.length_m < 0.006 && off.tool_m < 0.006, "{off:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A map that parses but reads the recording wrong (the tip in cm where the file has mm): the
/// fit is made, and the output says it misses by far more than a fit should and what to check.
#[test]
fn a_map_that_reads_a_recording_wrong_is_warned_of() {
    let dir = folder("identify-warned");
    let text = std::fs::read_to_string(root().join("tests/data/real-arm/train.csv")).unwrap();
    let rows: Vec<&str> = text.lines().take(201).collect();
    std::fs::write(dir.join("some.csv"), rows.join("\n")).unwrap();
    let map = std::fs::read_to_string(root().join(COLUMNS)).unwrap();
    let wrong = map.replace(
        "tip = { columns = [\"tip_x\", \"tip_y\", \"tip_z\"], unit = \"mm\" }",
        "tip = { columns = [\"tip_x\", \"tip_y\", \"tip_z\"], unit = \"cm\" }",
    );
    assert_ne!(wrong, map);
    std::fs::write(dir.join("cm.toml"), wrong).unwrap();
    let path = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let trained = softarm(&[
        "train",
        "--from",
        &path("some.csv"),
        "--columns",
        &path("cm.toml"),
        "--arm",
        ARM,
        "--output",
        &path("model"),
    ]);
    let said = String::from_utf8_lossy(&trained.stdout);
    assert!(trained.status.success(), "{said}");
    assert!(
        said.contains("warning: the physical model misses the rows it was fitted to")
            && said.contains("check the column map's units and signs"),
        "{said}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
