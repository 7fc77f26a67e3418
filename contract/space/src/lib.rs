//! The two spaces the method works in, named once: actuation space (the arm's actuators, each
//! normalised to [0, 1]; as many as its `[arm]` has, [`MIN_ACTUATORS`]..=[`MAX_ACTUATORS`])
//! and task space (end-effector positions in metres, base frame).

/// Most actuators an arm may have: the capacity of every per-actuator payload.
pub const MAX_ACTUATORS: usize = 16;

/// Fewest actuators an arm may have: one module bending every way needs three.
pub const MIN_ACTUATORS: usize = 3;

/// Runs `$body` with the const `$N` set to the arm's actuator count `$n`, known only at run
/// time: the body is compiled once for every count an arm may have ([`MIN_ACTUATORS`] ..=
/// [`MAX_ACTUATORS`]), so what it calls keeps its per-actuator values in fixed arrays, sized at
/// compile time, allocation-free on the tick. Any other count gives `$other` (with `$n` bound
/// to `$count`).
///
/// ```
/// fn run<const N: usize>() -> usize { N }
/// let n = 9;
/// let got = softarm_space::with_actuators!(n, N => run::<N>(), other => panic!("{other}"));
/// assert_eq!(got, 9);
/// ```
#[macro_export]
macro_rules! with_actuators {
    ($n:expr, $N:ident => $body:expr, $count:ident => $other:expr) => {
        $crate::with_actuators!(@arms $n, $N, $body, $count, $other;
            3 4 5 6 7 8 9 10 11 12 13 14 15 16)
    };
    (@arms $n:expr, $N:ident, $body:expr, $count:ident, $other:expr; $($k:literal)*) => {
        match $n {
            $($k => {
                const $N: usize = $k;
                $body
            })*
            $count => $other,
        }
    };
}

/// At most this many way-points (conditioning points) in a set.
pub const MAX_WAYPOINTS: usize = 16;

/// An end-effector position (m, base/tracker frame).
pub type Position = [f64; 3];

/// ‖a − b‖ (m).
pub fn distance(a: &Position, b: &Position) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// An axis-aligned box in task space (m): where way-points may lie, what the learner's lattices
/// span.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Workspace {
    pub min_m: Position,
    pub max_m: Position,
}

impl Workspace {
    /// A box; each axis must be finite and not empty.
    pub fn new(min_m: Position, max_m: Position) -> Result<Self, String> {
        for d in 0..3 {
            if !(min_m[d].is_finite() && max_m[d].is_finite() && min_m[d] < max_m[d]) {
                return Err(format!(
                    "axis {} ({}): the box {} .. {} m is empty or not finite",
                    d,
                    ["x", "y", "z"][d],
                    min_m[d],
                    max_m[d]
                ));
            }
        }
        Ok(Self { min_m, max_m })
    }

    pub fn contains(&self, p: &Position) -> bool {
        (0..3).all(|d| p[d] >= self.min_m[d] && p[d] <= self.max_m[d])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn with_actuators_runs_every_count_an_arm_may_have_and_no_other() {
        fn n<const N: usize>() -> usize {
            N
        }
        for k in 0..=MAX_ACTUATORS + 1 {
            let got = with_actuators!(k, N => Some(n::<N>()), _other => None);
            let valid = (MIN_ACTUATORS..=MAX_ACTUATORS).contains(&k);
            assert_eq!(got, valid.then_some(k), "{k} actuators");
        }
    }

    #[test]
    fn boxes_are_checked_and_contain_their_edges() {
        let w = Workspace::new([-1.0, -1.0, -1.0], [1.0, 1.0, 0.0]).unwrap();
        assert!(w.contains(&[1.0, -1.0, 0.0]));
        assert!(!w.contains(&[0.0, 0.0, 0.1]));
        assert!(!w.contains(&[f64::NAN, 0.0, 0.0]));
        assert!(
            Workspace::new([0.0; 3], [1.0, 0.0, 1.0])
                .unwrap_err()
                .contains("axis 1")
        );
        assert!(Workspace::new([0.0; 3], [1.0, 1.0, f64::INFINITY]).is_err());
        assert_eq!(distance(&[0.0, 3.0, 0.0], &[4.0, 0.0, 0.0]), 5.0);
    }
}
