//! `softarm config reference`: every key of the config, made from the config itself so that it
//! cannot drift. What a key is and does: the type's doc comment (schemars), else the comment
//! beside it in the shipped config. Its default: the shipped config's value (the real arm's
//! sections: `config/hardware.toml`'s), else the type's `Default`. Its range: what the
//! validator says when the key is set far out of it, in the validator's own words.

use serde_json::Value;

use crate::{Config, DEFAULT, with_overrides};

/// The real arm's config: the sections the simulation default has not.
const HARDWARE: &str = include_str!("../../../config/hardware.toml");

/// One key of the reference.
struct Row {
    key: String,
    kind: String,
    default: String,
    unit: &'static str,
    range: String,
    what: String,
}

/// The reference, as Markdown (what `docs/config.md` holds).
pub fn markdown() -> String {
    let schema = serde_json::to_value(schemars::schema_for!(Config)).expect("a schema is JSON");
    let defs = schema.get("$defs").cloned().unwrap_or(Value::Null);
    let mut sections = Vec::new();
    walk("", &schema, &defs, &mut sections);
    let mut out = String::from(HEADER);
    for (section, what, rows) in sections {
        if rows.is_empty() {
            continue;
        }
        out += &format!("\n## `[{section}]`\n\n");
        if !what.is_empty() {
            out += &format!("{what}\n\n");
        }
        out += "| key | type | default | unit | range | what it does |\n";
        out += "|---|---|---|---|---|---|\n";
        for r in rows {
            out += &format!(
                "| `{}` | {} | {} | {} | {} | {} |\n",
                r.key,
                cell(&r.kind),
                cell(&r.default),
                r.unit,
                cell(&r.range),
                cell(&r.what)
            );
        }
    }
    out
}

const HEADER: &str = "# Config reference\n\n\
Every key of softarm's config file, one section a table. Written by `softarm config reference` \
from the config's own types (their doc comments, else the comment beside the key in the shipped \
config; their defaults) and its validator (the range is what `softarm config check` says of a \
value far outside it); a test fails when this file and the command differ. Defaults are the shipped simulation config's (`config/softarm.toml`), for \
the real arm's sections `config/hardware.toml`'s; \"none\" is a key that may be left out. \
Relative paths start at the config file's folder.\n";

/// A table cell: one line, no column breaks.
fn cell(s: &str) -> String {
    s.split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .replace('|', "\\|")
}

/// `schema` with a `$ref` followed, an `Option`'s `null` dropped.
fn resolve<'a>(schema: &'a Value, defs: &'a Value) -> &'a Value {
    if let Some(r) = schema.get("$ref").and_then(Value::as_str) {
        let name = r.trim_start_matches("#/$defs/");
        return defs.get(name).map_or(schema, |d| resolve(d, defs));
    }
    for key in ["anyOf", "oneOf"] {
        if let Some(Value::Array(alts)) = schema.get(key) {
            let not_null: Vec<&Value> = alts
                .iter()
                .filter(|a| a.get("type").and_then(Value::as_str) != Some("null"))
                .collect();
            if let [one] = not_null[..] {
                return resolve(one, defs);
            }
        }
    }
    schema
}

fn description(schema: &Value) -> String {
    schema
        .get("description")
        .and_then(Value::as_str)
        .unwrap_or_default()
        .to_string()
}

/// The sections under `prefix` (a table schema), each with its rows, in the shipped config's
/// order (then the keys it does not name, alphabetically).
fn walk(prefix: &str, table: &Value, defs: &Value, out: &mut Vec<(String, String, Vec<Row>)>) {
    let Some(Value::Object(props)) = table.get("properties") else {
        return;
    };
    let mut names: Vec<&String> = props.keys().collect();
    names.sort_by_key(|n| {
        (
            position(&join(prefix, n)).unwrap_or(usize::MAX),
            n.to_string(),
        )
    });
    let mut rows = Vec::new();
    let mut nested = Vec::new();
    for name in names {
        let key = join(prefix, name);
        let own = &props[name];
        let schema = resolve(own, defs);
        if schema.get("properties").is_some() {
            nested.push((key, schema));
            continue;
        }
        let mut what = description(own);
        if what.is_empty() {
            what = description(schema);
        }
        if what.is_empty() {
            what = shipped_comment(&key).unwrap_or_default();
        }
        let kind = kind(schema, defs);
        rows.push(Row {
            range: range(&key, &kind),
            kind,
            default: default(&key, own, schema),
            unit: unit(name),
            what,
            key: name.to_string(),
        });
    }
    if !prefix.is_empty() {
        out.push((prefix.to_string(), description(table), rows));
    }
    for (key, schema) in nested {
        walk(&key, schema, defs, out);
    }
}

fn join(prefix: &str, name: &str) -> String {
    if prefix.is_empty() {
        name.to_string()
    } else {
        format!("{prefix}.{name}")
    }
}

/// Where `key` stands in the shipped configs (the simulation's, then the real arm's).
fn position(key: &str) -> Option<usize> {
    crate::key_line(DEFAULT, key)
        .filter(|_| lookup(DEFAULT, key).is_some())
        .or_else(|| {
            crate::key_line(HARDWARE, key)
                .filter(|_| lookup(HARDWARE, key).is_some())
                .map(|l| l + 100_000)
        })
}

/// The value of dotted `key` in the TOML `text`.
fn lookup(text: &str, key: &str) -> Option<toml::Value> {
    let mut v = toml::Value::Table(text.parse::<toml::Table>().ok()?);
    for part in key.split('.') {
        v = v.get(part)?.clone();
    }
    Some(v)
}

/// The comment after `key = value` in the shipped config, if it has one.
fn shipped_comment(key: &str) -> Option<String> {
    let text = [DEFAULT, HARDWARE]
        .into_iter()
        .find(|t| lookup(t, key).is_some())?;
    let line = crate::key_line(text, key)?;
    let leaf = key.rsplit('.').next()?;
    let l = text.lines().nth(line - 1)?;
    if !l.trim_start().starts_with(leaf) {
        return None;
    }
    let (_, comment) = l.split_once(" # ")?;
    Some(comment.trim().to_string())
}

fn kind(schema: &Value, defs: &Value) -> String {
    let consts = |alts: &Vec<Value>| -> Option<Vec<String>> {
        alts.iter()
            .map(|a| {
                a.get("const")
                    .and_then(Value::as_str)
                    .map(|s| format!("`{s}`"))
            })
            .collect()
    };
    if let Some(Value::Array(values)) = schema.get("enum") {
        let v: Vec<String> = values
            .iter()
            .filter_map(Value::as_str)
            .map(|s| format!("`{s}`"))
            .collect();
        return format!("one of {}", v.join(", "));
    }
    if let Some(Value::Array(alts)) = schema.get("oneOf")
        && let Some(v) = consts(alts)
    {
        return format!("one of {}", v.join(", "));
    }
    match schema.get("type") {
        Some(Value::String(t)) if t == "array" => {
            let items = schema
                .get("items")
                .map_or(Value::Null, |i| resolve(i, defs).clone());
            let n = schema.get("minItems").and_then(Value::as_u64);
            let fixed = n.is_some() && n == schema.get("maxItems").and_then(Value::as_u64);
            let of = if items.get("properties").is_some() {
                let fields: Vec<&String> = items["properties"]
                    .as_object()
                    .map(|o| o.keys().collect())
                    .unwrap_or_default();
                format!(
                    "tables of {}",
                    fields
                        .iter()
                        .map(|f| format!("`{f}`"))
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            } else {
                format!("{}s", kind(&items, defs))
            };
            match (fixed, n) {
                (true, Some(n)) => format!("{n} {of}"),
                _ => format!("array of {of}"),
            }
        }
        Some(Value::String(t)) => t.clone(),
        Some(Value::Array(ts)) => ts
            .iter()
            .filter_map(Value::as_str)
            .filter(|t| *t != "null")
            .collect::<Vec<_>>()
            .join(" or "),
        _ => "value".into(),
    }
}

fn toml_text(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => format!("`\"{s}\"`"),
        toml::Value::Table(_) => "(a table)".into(),
        toml::Value::Array(a) if a.iter().any(toml::Value::is_table) => {
            format!("({} tables)", a.len())
        }
        other => format!("`{other}`"),
    }
}

fn default(key: &str, own: &Value, schema: &Value) -> String {
    if let Some(v) = lookup(DEFAULT, key).or_else(|| lookup(HARDWARE, key)) {
        return toml_text(&v);
    }
    match own.get("default").or_else(|| schema.get("default")) {
        Some(Value::Null) | None => "none".into(),
        Some(v) => format!("`{v}`"),
    }
}

/// The unit a key's name says (the config's convention: the unit is the name's last word).
fn unit(name: &str) -> &'static str {
    const UNITS: [(&str, &str); 11] = [
        ("_per_s", "1/s"),
        ("_mm_per_min", "mm/min"),
        ("_per_m", "1/m"),
        ("_hz", "Hz"),
        ("_ms", "ms"),
        ("_mm", "mm"),
        ("_deg", "°"),
        ("_s", "s"),
        ("_m", "m"),
        ("_us", "µs"),
        ("_permille", "‰"),
    ];
    UNITS
        .iter()
        .find(|(suffix, _)| name.ends_with(suffix))
        .map_or("", |(_, u)| u)
}

/// How the probes' values read in a message.
const PROBE_DIGITS: [&str; 6] = [
    "1e300",
    "1e18",
    "1000000000000000000",
    "2147483647",
    "4611686018427387904",
    "-1,",
];

/// What the validator says of `key` set far out of range, in its words (", got ..." dropped);
/// "any" when it takes both extremes.
fn range(key: &str, kind: &str) -> String {
    let section = key.rsplit_once('.').map_or("", |(s, _)| s);
    let Some(base) = [DEFAULT, HARDWARE]
        .into_iter()
        .find(|t| lookup(t, key).is_some())
        .or_else(|| {
            [DEFAULT, HARDWARE]
                .into_iter()
                .find(|t| lookup(t, section).is_some_and(|v| v.is_table()))
        })
    else {
        return String::new();
    };
    // A key the shipped config leaves out is probed as its type says.
    let current = match (lookup(base, key), kind) {
        (Some(v), _) => v,
        (None, "integer") => 0.into(),
        (None, "number") => 0.0.into(),
        (None, _) => return String::new(),
    };
    let number = |v: &toml::Value| matches!(v, toml::Value::Float(_) | toml::Value::Integer(_));
    let probes: Vec<toml::Value> = match &current {
        toml::Value::Float(_) => vec![(-1e300).into(), 1e300.into()],
        // Each where its type can hold it: a negative, an i32's largest, a u64's large.
        toml::Value::Integer(_) => vec![
            (-1i64).into(),
            i64::from(i32::MAX).into(),
            (1i64 << 62).into(),
        ],
        toml::Value::Array(a) if !a.is_empty() && a.iter().all(number) => {
            let probe = |x: f64| {
                let v: toml::Value = if matches!(a[0], toml::Value::Integer(_)) {
                    (x as i64).into()
                } else {
                    x.into()
                };
                toml::Value::Array(vec![v; a.len()])
            };
            vec![probe(-1e18), probe(1e18)]
        }
        _ => return String::new(),
    };
    let mut said = Vec::new();
    let mut accepted = 0;
    for p in probes {
        let Ok(text) = with_overrides(base, &[(key, p)]) else {
            continue;
        };
        match Config::parse(&text, "probe", "/".into()) {
            Ok(_) => accepted += 1,
            Err(e) => {
                let m = e.message;
                let Some(rest) = m.strip_prefix(key) else {
                    continue;
                };
                let rest =
                    rest.trim_start_matches(|c: char| c == '[' || c == ']' || c.is_ascii_digit());
                let Some(rest) = rest.strip_prefix(": ") else {
                    continue;
                };
                // What names the probe's own value says nothing of the range.
                let rest: Vec<&str> = rest
                    .split(", got ")
                    .next()
                    .unwrap_or(rest)
                    .split("; ")
                    .filter(|part| !PROBE_DIGITS.iter().any(|d| part.contains(d)))
                    .collect();
                let rest = rest.join("; ");
                if !rest.is_empty() && !said.contains(&rest) {
                    said.push(rest);
                }
            }
        }
    }
    if said.is_empty() && accepted > 0 {
        "any".into()
    } else {
        said.join("; ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_committed_reference_is_what_the_command_prints() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/config.md");
        let committed = std::fs::read_to_string(path).unwrap_or_default();
        assert!(
            committed == markdown(),
            "docs/config.md differs from `softarm config reference`: run \
             `cargo run -- config reference > docs/config.md`"
        );
    }

    #[test]
    fn every_key_of_the_shipped_configs_is_in_the_reference() {
        let md = markdown();
        for text in [DEFAULT, HARDWARE] {
            let table: toml::Table = text.parse().unwrap();
            for (section, v) in &table {
                let toml::Value::Table(keys) = v else {
                    continue;
                };
                assert!(md.contains(&format!("## `[{section}]`")), "[{section}]");
                for (key, v) in keys {
                    if !v.is_table() {
                        assert!(md.contains(&format!("| `{key}` |")), "{section}.{key}");
                    }
                }
            }
        }
        // Ranges come from the validator in its own words.
        assert!(
            md.contains("| `rate_hz` | number | `500.0` | Hz | must be in [10, 1000] Hz |"),
            "{md}"
        );
    }
}
