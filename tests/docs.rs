//! The docs name what exists: every `file.rs::item` a document cites is defined in that file,
//! every path it names is in the repository, every relative link resolves, and every
//! `softarm ...` and `softarm-rig ...` command line of README's and the guide's shell blocks
//! parses (`--help` appended: the command and each of its flags are known).

use std::path::{Path, PathBuf};
use std::process::Command;

use softarm_test_support::output;

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
const RIG: &str = env!("CARGO_BIN_EXE_softarm-rig");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The documents: README, CHANGELOG, everything under docs/, and the folders' READMEs.
fn documents() -> Vec<PathBuf> {
    let root = Path::new(ROOT);
    let mut out: Vec<PathBuf> = [
        "README.md",
        "CHANGELOG.md",
        "config/README.md",
        "systemd/README.md",
    ]
    .iter()
    .map(|p| root.join(p))
    .filter(|p| p.exists())
    .collect();
    let mut todo = vec![root.join("docs")];
    while let Some(dir) = todo.pop() {
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                todo.push(p);
            } else if p.extension().is_some_and(|x| x == "md") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// The inline code spans of `text` outside fenced blocks, each with its line.
fn code_spans(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut fenced = false;
    for (i, line) in text.lines().enumerate() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        let mut rest = line;
        while let Some(start) = rest.find('`') {
            let after = &rest[start + 1..];
            let Some(end) = after.find('`') else { break };
            out.push((i + 1, after[..end].to_string()));
            rest = &after[end + 1..];
        }
    }
    out
}

/// Whether `name` is defined in the Rust source `text` (as fn, struct, enum, trait, type,
/// const, static, mod or macro).
fn defines(text: &str, name: &str) -> bool {
    [
        "fn",
        "struct",
        "enum",
        "trait",
        "type",
        "const",
        "static",
        "mod",
        "macro_rules!",
    ]
    .iter()
    .any(|kw| {
        text.match_indices(&format!("{kw} {name}")).any(|(at, m)| {
            let next = text[at + m.len()..].chars().next();
            let before = text[..at].chars().next_back();
            !next.is_some_and(|c| c.is_alphanumeric() || c == '_')
                && !before.is_some_and(|c| c.is_alphanumeric() || c == '_')
        })
    })
}

/// The problem with code span `span`, if it cites something that is not there.
fn check_span(span: &str) -> Option<String> {
    let root = Path::new(ROOT);
    // What a build makes (target/) is not in the repository, but named as a user sees it.
    let top_level =
        |first: &str| root.join(first).exists() && !first.is_empty() && first != "target";
    if span.contains(char::is_whitespace) || span.contains(['*', '<', '{', '$', '~']) {
        return None;
    }
    if let Some((file, items)) = span.split_once(".rs::") {
        let file = format!("{file}.rs");
        if !file.contains('/') {
            return Some(format!(
                "{span}: name the file by its path from the repository's root"
            ));
        }
        let Ok(text) = std::fs::read_to_string(root.join(&file)) else {
            return Some(format!("{span}: there is no file {file}"));
        };
        for item in items.split("::") {
            let item = item.trim_end_matches("()");
            if !defines(&text, item) {
                return Some(format!("{span}: {file} defines no {item}"));
            }
        }
        return None;
    }
    let path = span.trim_end_matches('/');
    let first = path.split('/').next().unwrap_or_default();
    if path.contains('/') && !path.starts_with('/') && top_level(first) && !root.join(path).exists()
    {
        return Some(format!("{span}: there is no such path in the repository"));
    }
    None
}

/// Relative link targets of `text`: `](target)`.
fn links(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        for (at, _) in line.match_indices("](") {
            let rest = &line[at + 2..];
            if let Some(end) = rest.find(')') {
                let target = &rest[..end];
                if !target.contains("://")
                    && !target.starts_with('#')
                    && !target.starts_with("mailto:")
                {
                    out.push((
                        i + 1,
                        target.split('#').next().unwrap_or_default().to_string(),
                    ));
                }
            }
        }
    }
    out
}

#[test]
fn every_item_path_and_link_the_docs_name_exists() {
    let mut wrong = Vec::new();
    let docs = documents();
    assert!(docs.len() >= 3, "{docs:?}");
    for doc in &docs {
        let text = std::fs::read_to_string(doc).unwrap();
        let name = doc.strip_prefix(ROOT).unwrap_or(doc).display().to_string();
        if text.contains("../shared") {
            wrong.push(format!(
                "{name}: points to ../shared, which users do not have"
            ));
        }
        for (line, span) in code_spans(&text) {
            if let Some(w) = check_span(&span) {
                wrong.push(format!("{name}:{line}: {w}"));
            }
        }
        for (line, target) in links(&text) {
            if !target.is_empty() && !doc.parent().unwrap().join(&target).exists() {
                wrong.push(format!("{name}:{line}: the link {target} leads nowhere"));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "{} wrong:\n{}",
        wrong.len(),
        wrong.join("\n")
    );
}

#[test]
fn a_renamed_item_fails_the_check() {
    assert_eq!(check_span("contract/space/src/lib.rs::distance"), None);
    assert_eq!(
        check_span("processes/controller/src/tick.rs::Tick::tick"),
        None
    );
    assert!(check_span("contract/space/src/lib.rs::distanse").is_some());
    assert!(check_span("space.rs::distance").is_some());
    assert!(check_span("models/model/tests/nowhere.rs").is_some());
    assert_eq!(check_span("config/config/tests/fuzz.rs"), None);
    assert_eq!(check_span("/etc/softarm/softarm.toml"), None);
}

/// The command lines of the ```sh blocks of `text`: `softarm ...` (after an optional `sudo`)
/// and `cargo run --release -- ...`, without their comments.
fn command_lines(text: &str) -> Vec<(usize, String)> {
    shell_lines(
        text,
        &[
            "softarm ",
            "cargo run --release -- ",
            "target/release/softarm ",
        ],
    )
}

/// The test rig's command lines, as [`command_lines`]: `softarm-rig ...` and `cargo run
/// --release --bin softarm-rig -- ...`.
fn rig_command_lines(text: &str) -> Vec<(usize, String)> {
    shell_lines(
        text,
        &[
            "softarm-rig ",
            "cargo run --release --bin softarm-rig -- ",
            "target/release/softarm-rig ",
        ],
    )
}

/// The arguments after one of `prefixes` of the lines of the ```sh blocks of `text` (after an
/// optional `sudo`), without their comments, each with its line.
fn shell_lines(text: &str, prefixes: &[&str]) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut in_sh = false;
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.starts_with("```") {
            in_sh = !in_sh && (t == "```sh" || t == "```bash" || t == "```console");
            continue;
        }
        if !in_sh {
            continue;
        }
        let t = t.split(" #").next().unwrap_or(t).trim();
        let t = t.strip_prefix("sudo ").unwrap_or(t);
        if let Some(args) = prefixes.iter().find_map(|p| t.strip_prefix(p)) {
            out.push((i + 1, args.to_string()));
        }
    }
    out
}

/// `args` with `[--optional ...]` groups in (brackets dropped) and out; `A|B` alternatives take
/// the first.
fn variants(args: &str) -> Vec<Vec<String>> {
    let words = |s: &str| -> Vec<String> {
        s.split_whitespace()
            .map(|w| w.split('|').next().unwrap_or(w).to_string())
            .collect()
    };
    let mut with = String::new();
    let mut without = String::new();
    let mut depth = 0;
    for c in args.chars() {
        match c {
            '[' => depth += 1,
            ']' => depth -= 1,
            _ => {
                with.push(c);
                if depth == 0 {
                    without.push(c);
                }
            }
        }
    }
    let mut v = vec![words(&with)];
    if without != with {
        v.push(words(&without));
    }
    v
}

#[test]
fn every_command_line_of_readme_and_the_guide_parses() {
    let root = Path::new(ROOT);
    let mut docs = vec![root.join("README.md")];
    docs.extend(
        documents()
            .into_iter()
            .filter(|d| d.starts_with(root.join("docs/guide"))),
    );
    let mut wrong = Vec::new();
    let mut checked = 0;
    for doc in docs {
        let text = std::fs::read_to_string(&doc).unwrap();
        let lines = command_lines(&text)
            .into_iter()
            .map(|l| (BIN, "softarm", l));
        let rig = rig_command_lines(&text)
            .into_iter()
            .map(|l| (RIG, "softarm-rig", l));
        for (bin, name, (line, args)) in lines.chain(rig) {
            for words in variants(&args) {
                checked += 1;
                let out = output(
                    Command::new(bin)
                        .args(&words)
                        .arg("--help")
                        .env("SOFTARM_CONFIG", root.join("config/softarm.toml")),
                );
                if !out.status.success() {
                    wrong.push(format!(
                        "{}:{line}: {name} {}: {}",
                        doc.strip_prefix(root).unwrap().display(),
                        words.join(" "),
                        String::from_utf8_lossy(&out.stderr)
                            .lines()
                            .next()
                            .unwrap_or_default()
                    ));
                }
            }
        }
    }
    assert!(checked >= 10, "only {checked} command lines found");
    assert!(
        wrong.is_empty(),
        "{} do not parse:\n{}",
        wrong.len(),
        wrong.join("\n")
    );
}

/// An installed stack has no model until it is trained: wherever the docs enable the stack,
/// the next softarm command they give is `softarm train` (an operator following them from
/// enable to submit was refused every set).
#[test]
fn where_the_docs_start_the_installed_stack_they_train_it_next() {
    let root = Path::new(ROOT);
    let mut enabled = 0;
    for doc in documents() {
        let text = std::fs::read_to_string(&doc).unwrap();
        let commands: Vec<(usize, String)> = command_lines(&text);
        for (i, line) in text.lines().enumerate() {
            if !line.contains("systemctl enable --now softarm.target") {
                continue;
            }
            enabled += 1;
            let next = commands.iter().find(|(at, _)| *at > i + 1);
            assert!(
                next.is_some_and(|(_, args)| args.starts_with("train")),
                "{}:{}: the stack is enabled, then `softarm {}` comes before `softarm train`",
                doc.strip_prefix(root).unwrap().display(),
                i + 1,
                next.map_or("(nothing)", |(_, a)| a.as_str())
            );
        }
    }
    assert!(enabled >= 2, "only {enabled} places enable the stack");
}
