//! How well a model predicts a recording: the tip's miss over every row, the same after the
//! mean miss is taken out (a marker or base offset, as system-identification work reports it),
//! and each per family of motions. Pure.

use std::collections::BTreeMap;

use crate::recording::Recording;

/// The tip's miss over some rows (mm).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Errors {
    pub rows: usize,
    pub rms_mm: f64,
    pub mean_mm: f64,
    /// The RMS after the rows' mean miss (`offset_mm`) is taken out.
    pub offset_removed_rms_mm: f64,
    pub p95_mm: f64,
    pub max_mm: f64,
    /// The mean miss (x, y, z).
    pub offset_mm: [f64; 3],
}

impl Errors {
    /// Of misses (m, x y z each).
    pub fn of(misses: &[[f64; 3]]) -> Self {
        let n = misses.len();
        if n == 0 {
            return Self::default();
        }
        let mut offset = [0.0; 3];
        for m in misses {
            for k in 0..3 {
                offset[k] += m[k] / n as f64;
            }
        }
        let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let mut d: Vec<f64> = misses.iter().map(|m| norm(*m)).collect();
        let rms = (d.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt();
        let removed = (misses.iter())
            .map(|m| norm([m[0] - offset[0], m[1] - offset[1], m[2] - offset[2]]).powi(2))
            .sum::<f64>()
            / n as f64;
        let mean = d.iter().sum::<f64>() / n as f64;
        d.sort_by(f64::total_cmp);
        // The nearest-rank 95th percentile.
        let p95 = d[((0.95 * n as f64).ceil() as usize).clamp(1, n) - 1];
        Self {
            rows: n,
            rms_mm: rms * 1e3,
            mean_mm: mean * 1e3,
            offset_removed_rms_mm: removed.sqrt() * 1e3,
            p95_mm: p95 * 1e3,
            max_mm: d[n - 1] * 1e3,
            offset_mm: offset.map(|o| o * 1e3),
        }
    }
}

/// A model's misses on a recording: over all rows, and per family (each with its own offset).
#[derive(Debug, Clone, PartialEq)]
pub struct Check {
    pub all: Errors,
    pub families: Vec<(String, Errors)>,
    /// The model's terms beyond its geometry (gravity), for people; empty: none said.
    pub terms: String,
}

/// Checks `predict` (pulls → tip, m) against every row of `recording`, calling `tick` per row.
pub fn check(
    recording: &Recording,
    mut predict: impl FnMut(&[f64]) -> [f64; 3],
    tick: &mut dyn FnMut(),
) -> Check {
    let mut all = Vec::with_capacity(recording.len());
    let mut by_family: BTreeMap<String, Vec<[f64; 3]>> = BTreeMap::new();
    for row in &recording.rows {
        let p = predict(&row.pull_m);
        let miss = [
            p[0] - row.tip_m[0],
            p[1] - row.tip_m[1],
            p[2] - row.tip_m[2],
        ];
        all.push(miss);
        (by_family.entry(recording.family_of(&row.motion)))
            .or_default()
            .push(miss);
        tick();
    }
    Check {
        all: Errors::of(&all),
        families: (by_family.into_iter())
            .map(|(f, m)| (f, Errors::of(&m)))
            .collect(),
        terms: String::new(),
    }
}

impl Check {
    /// A table for people: one row overall, one per family.
    pub fn table(&self) -> String {
        let mut out = if self.terms.is_empty() {
            String::new()
        } else {
            format!("{}\n", self.terms)
        };
        out += &format!(
            "{:<24} {:>5} {:>8} {:>8} {:>10} {:>8} {:>8}\n",
            "rows (mm)", "n", "rms", "mean", "rms-offset", "p95", "max"
        );
        let line = |name: &str, e: &Errors| {
            format!(
                "{name:<24} {:>5} {:>8.2} {:>8.2} {:>10.2} {:>8.2} {:>8.2}\n",
                e.rows, e.rms_mm, e.mean_mm, e.offset_removed_rms_mm, e.p95_mm, e.max_mm
            )
        };
        out.push_str(&line("all", &self.all));
        for (f, e) in &self.families {
            out.push_str(&line(&format!("  {f}"), e));
        }
        out
    }

    /// One JSON object: `all` and `families`, each with every figure in mm.
    pub fn json(&self) -> String {
        let one = |e: &Errors| {
            format!(
                "{{\"rows\":{},\"rms_mm\":{:.4},\"mean_mm\":{:.4},\"offset_removed_rms_mm\":{:.4},\
                 \"p95_mm\":{:.4},\"max_mm\":{:.4},\"offset_mm\":[{:.4},{:.4},{:.4}]}}",
                e.rows,
                e.rms_mm,
                e.mean_mm,
                e.offset_removed_rms_mm,
                e.p95_mm,
                e.max_mm,
                e.offset_mm[0],
                e.offset_mm[1],
                e.offset_mm[2]
            )
        };
        let families: Vec<String> = (self.families.iter())
            .map(|(f, e)| format!("{}:{}", json_string(f), one(e)))
            .collect();
        format!(
            "{{\"all\":{},\"families\":{{{}}},\"terms\":{}}}",
            one(&self.all),
            families.join(","),
            json_string(&self.terms)
        )
    }
}

fn json_string(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 => out.push_str(&format!("\\u{:04x}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_offset_is_taken_out_and_percentiles_are_of_the_rows() {
        let misses: Vec<[f64; 3]> = (0..20)
            .map(|k| [0.010, 0.0, if k % 2 == 0 { 0.001 } else { -0.001 }])
            .collect();
        let e = Errors::of(&misses);
        assert!((e.offset_mm[0] - 10.0).abs() < 1e-9);
        assert!((e.offset_removed_rms_mm - 1.0).abs() < 1e-9, "{e:?}");
        assert!((e.rms_mm - 101f64.sqrt()).abs() < 1e-9);
        assert!((e.max_mm - e.p95_mm).abs() < 1e-12);
        assert_eq!(Errors::of(&[]).rows, 0);
    }

    #[test]
    fn json_escapes_family_names() {
        let c = Check {
            all: Errors::default(),
            families: vec![("a\"b".into(), Errors::default())],
            terms: String::new(),
        };
        assert!(c.json().contains("\"a\\\"b\":{"), "{}", c.json());
    }
}
