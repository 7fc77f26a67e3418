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
    let trained = softarm(&[
        "train",
        "--from",
        "tests/data/real-arm/train.csv",
        "--columns",
        COLUMNS,
        "--arm",
        ARM,
        "--output",
        out.to_str().unwrap(),
    ]);
    let said = String::from_utf8_lossy(&trained.stdout);
    assert!(
        trained.status.success(),
        "{said}{}",
        String::from_utf8_lossy(&trained.stderr)
    );
    assert!(said.contains("chosen by cross-validation"), "{said}");
    let model = out.join("identified.toml");
    let check = |recording: &str| {
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
    let held_out = check("tests/data/real-arm/val.csv");
    let seen = check("tests/data/real-arm/train.csv");
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
    // Checked against another arm, the model is refused by name.
    let other = softarm(&[
        "model",
        "check",
        "tests/data/real-arm/val.csv",
        "--columns",
        COLUMNS,
        "--arm",
        "paper",
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
        let r = softarm(&[
            "train",
            "--from",
            path.to_str().unwrap(),
            "--columns",
            COLUMNS,
            "--arm",
            ARM,
            "--output",
            out.to_str().unwrap(),
        ]);
        let said = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "case {k}");
        assert!(said.contains(&format!("bad{k}.csv:3")), "case {k}: {said}");
        assert!(said.contains(says), "case {k}: {said}");
        assert!(!out.exists(), "case {k} wrote {}", out.display());
    }
    // Too few rows for the arm's parameters.
    let path = dir.join("short.csv");
    std::fs::write(&path, lines[..40].join("\n")).unwrap();
    let r = softarm(&[
        "train",
        "--from",
        path.to_str().unwrap(),
        "--columns",
        COLUMNS,
        "--arm",
        ARM,
        "--output",
        dir.join("short").to_str().unwrap(),
    ]);
    let said = String::from_utf8_lossy(&r.stderr);
    assert!(said.contains("39 rows; calibrating this arm's"), "{said}");
    assert!(!dir.join("short").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
