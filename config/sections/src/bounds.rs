//! The range checks most keys share, worded once: `KEY: must be in (lo, hi] unit, got v`,
//! `KEY: must be lo to hi, got v` (what `softarm config reference` shows as a key's range).

/// The lower end of a range: included or not.
#[derive(Debug, Clone, Copy)]
pub enum Lower {
    Closed(f64),
    Open(f64),
}
use Lower::{Closed, Open};

/// A finite `v` within the range, or `KEY: message` naming the range.
pub fn within(key: &str, v: f64, lower: Lower, upper: f64, unit: &str) -> Result<(), String> {
    let (ok, bracket, lo) = match lower {
        Closed(lo) => (v >= lo, '[', lo),
        Open(lo) => (v > lo, '(', lo),
    };
    if v.is_finite() && ok && v <= upper {
        return Ok(());
    }
    Err(format!(
        "{key}: must be in {bracket}{lo}, {upper}]{unit}, got {v:?}"
    ))
}

/// `v` in `lo..=hi`, or `KEY: message` naming the range.
pub fn count(key: &str, v: usize, lo: usize, hi: usize) -> Result<(), String> {
    if (lo..=hi).contains(&v) {
        return Ok(());
    }
    Err(format!("{key}: must be {lo} to {hi}, got {v}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_range_is_named_with_its_ends() {
        within("a.b", 1.0, Closed(1.0), 2.0, " s").unwrap();
        assert_eq!(
            within("a.b", 1.0, Open(1.0), 2.0, " s").unwrap_err(),
            "a.b: must be in (1, 2] s, got 1.0"
        );
        assert_eq!(
            within("a.b", f64::NAN, Closed(0.0), 1.0, "").unwrap_err(),
            "a.b: must be in [0, 1], got NaN"
        );
        count("a.n", 4, 1, 4).unwrap();
        assert_eq!(
            count("a.n", 0, 1, 4).unwrap_err(),
            "a.n: must be 1 to 4, got 0"
        );
    }
}
