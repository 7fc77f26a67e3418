//! The activations of the paper's Eq. 11, from the conditioning times T_cond and the primitive
//! assignment Q only:
//! - a_j(t): each conditioning point owns the time nearest to it; a_j = 1 where the owner's
//!   primitive Q[n] = j, `floor` elsewhere, smooth cross-fades centred on the midpoints;
//! - b_i(t): 1 on a fixed window around T_cond[i], 0 inside every other window, smooth hand-over
//!   across the whole gap between windows, Σ_i b_i = 1.
//!
//! The hand-over is cyclic in the paper's sense: group i + 1 follows group i and group 0 follows
//! the last one, in the next execution. Group 0 holds from t = 0, the last group to the end.

pub use softarm_sections::activation::MAX_PRIMITIVES;
use softarm_sections::activation::{ActivationConfig, Fade};

use crate::space::MAX_WAYPOINTS;

/// The fade's value at s ∈ [0, 1] (clamped to it): 0 at 0, 1 at 1; its largest slope is
/// [`Fade::max_slope`].
pub fn fade(shape: Fade, s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    match shape {
        Fade::Cosine => 0.5 - 0.5 * (std::f64::consts::PI * s).cos(),
        Fade::Smoothstep => s * s * (3.0 - 2.0 * s),
        Fade::Smootherstep => s * s * s * (s * (6.0 * s - 15.0) + 10.0),
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScheduleError {
    #[error("need 1 to {MAX_WAYPOINTS} conditioning points, got {0}")]
    PointCount(usize),
    #[error("need 1 to {MAX_PRIMITIVES} primitives, got {0}")]
    PrimitiveCount(usize),
    #[error("{0} conditioning times but {1} primitive assignments")]
    Lengths(usize, usize),
    #[error("duration must be finite and > 0, got {0} s")]
    Duration(f64),
    #[error("conditioning point {index}: time {t} s is outside the execution [0, {duration}] s")]
    OutOfRange { index: usize, t: f64, duration: f64 },
    #[error(
        "conditioning points {0} and {1} are {2:.3} s apart; they need at least {3:.3} s \
         (window_s + crossfade_s)"
    )]
    TooClose(usize, usize, f64, f64),
    #[error("conditioning point {index} is assigned primitive {q}, there are only {m}")]
    NoSuchPrimitive { index: usize, q: usize, m: usize },
    /// The config's dotted key and what is wrong with it: `activation.KEY: message`.
    #[error("{0}")]
    Config(String),
}

/// At most two groups are active at once: the one whose window it is, or the two handing over.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActiveGroups {
    groups: [(usize, f64); 2],
    len: usize,
}

impl ActiveGroups {
    fn one(i: usize) -> Self {
        Self {
            groups: [(i, 1.0), (0, 0.0)],
            len: 1,
        }
    }

    fn two(i: usize, bi: f64, j: usize, bj: f64) -> Self {
        match (bi > 0.0, bj > 0.0) {
            (true, true) => Self {
                groups: [(i, bi), (j, bj)],
                len: 2,
            },
            (true, false) => Self::one(i),
            _ => Self::one(j),
        }
    }

    /// (group, b_i) of every group with b_i > 0.
    pub fn iter(&self) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.groups[..self.len].iter().copied()
    }

    pub fn weight_of(&self, group: usize) -> f64 {
        self.iter().find(|g| g.0 == group).map_or(0.0, |g| g.1)
    }
}

/// a_j(t) and b_i(t) for one way-point set. Copy, no heap: the tick evaluates it in place.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Schedule {
    t_cond: [f64; MAX_WAYPOINTS],
    q: [usize; MAX_WAYPOINTS],
    points: usize,
    primitives: usize,
    duration: f64,
    config: ActivationConfig,
}

impl Schedule {
    pub fn new(
        t_cond: &[f64],
        q: &[usize],
        primitives: usize,
        duration: f64,
        config: ActivationConfig,
    ) -> Result<Self, ScheduleError> {
        let n = t_cond.len();
        if n == 0 || n > MAX_WAYPOINTS {
            return Err(ScheduleError::PointCount(n));
        }
        if primitives == 0 || primitives > MAX_PRIMITIVES {
            return Err(ScheduleError::PrimitiveCount(primitives));
        }
        if q.len() != n {
            return Err(ScheduleError::Lengths(n, q.len()));
        }
        if !(duration.is_finite() && duration > 0.0) {
            return Err(ScheduleError::Duration(duration));
        }
        validate_config(&config)?;
        for (index, &t) in t_cond.iter().enumerate() {
            if !(t.is_finite() && (0.0..=duration).contains(&t)) {
                return Err(ScheduleError::OutOfRange { index, t, duration });
            }
        }
        let need = config.window_s + config.crossfade_s;
        for i in 1..n {
            let gap = t_cond[i] - t_cond[i - 1];
            // The epsilon forgives times snapped to a tick grid.
            if gap < need - 1e-9 {
                return Err(ScheduleError::TooClose(i - 1, i, gap, need));
            }
        }
        for (index, &qi) in q.iter().enumerate() {
            if qi >= primitives {
                return Err(ScheduleError::NoSuchPrimitive {
                    index,
                    q: qi,
                    m: primitives,
                });
            }
        }
        let mut s = Self {
            t_cond: [0.0; MAX_WAYPOINTS],
            q: [0; MAX_WAYPOINTS],
            points: n,
            primitives,
            duration,
            config,
        };
        s.t_cond[..n].copy_from_slice(t_cond);
        s.q[..n].copy_from_slice(q);
        Ok(s)
    }

    pub fn points(&self) -> usize {
        self.points
    }

    pub fn primitives(&self) -> usize {
        self.primitives
    }

    pub fn duration(&self) -> f64 {
        self.duration
    }

    pub fn t_cond(&self) -> &[f64] {
        &self.t_cond[..self.points]
    }

    /// Q: the primitive of each conditioning point.
    pub fn assignment(&self) -> &[usize] {
        &self.q[..self.points]
    }

    pub fn config(&self) -> &ActivationConfig {
        &self.config
    }

    /// b_i(t) of every active group.
    pub fn groups(&self, t: f64) -> ActiveGroups {
        let half = 0.5 * self.config.window_s;
        let t_cond = self.t_cond();
        for i in 0..self.points - 1 {
            let end = t_cond[i] + half;
            if t <= end {
                return ActiveGroups::one(i);
            }
            let start = t_cond[i + 1] - half;
            if t < start {
                let f = fade(self.config.fade, (t - end) / (start - end));
                return ActiveGroups::two(i, 1.0 - f, i + 1, f);
            }
        }
        ActiveGroups::one(self.points - 1)
    }

    /// b_i(t) of one group.
    pub fn b(&self, group: usize, t: f64) -> f64 {
        self.groups(t).weight_of(group)
    }

    /// a_j(t) for every primitive j, written into `out[..primitives]`.
    pub fn a(&self, t: f64, out: &mut [f64]) {
        let out = &mut out[..self.primitives];
        let c = self.config.crossfade_s;
        let floor = self.config.floor;
        out.fill(floor);
        let t_cond = self.t_cond();
        // Ownership is a partition of unity over the points; at most one midpoint fades at t.
        let mut owner = (self.points - 1, 1.0, None);
        for i in 0..self.points - 1 {
            let mid = 0.5 * (t_cond[i] + t_cond[i + 1]);
            if t < mid + 0.5 * c {
                let f = fade(self.config.fade, (t - (mid - 0.5 * c)) / c);
                owner = (i, 1.0 - f, Some((i + 1, f)));
                break;
            }
        }
        let (n, w, next) = owner;
        out[self.q[n]] += (1.0 - floor) * w;
        if let Some((m, f)) = next {
            out[self.q[m]] += (1.0 - floor) * f;
        }
    }
}

fn validate_config(c: &ActivationConfig) -> Result<(), ScheduleError> {
    c.validate().map_err(ScheduleError::Config)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn schedule() -> Schedule {
        Schedule::new(
            &[1.0, 2.5, 4.0, 6.0, 8.5],
            &[0, 1, 1, 2, 0],
            3,
            10.0,
            ActivationConfig::default(),
        )
        .unwrap()
    }

    #[test]
    fn b_is_a_partition_of_unity_and_one_in_each_window() {
        let s = schedule();
        for k in 0..=10_000 {
            let t = k as f64 * 1e-3;
            let g = s.groups(t);
            let sum: f64 = g.iter().map(|(_, b)| b).sum();
            assert!((sum - 1.0).abs() < 1e-15, "t = {t}: {sum}");
        }
        for (i, &tc) in s.t_cond().iter().enumerate() {
            for dt in [-0.1, 0.0, 0.1] {
                assert_eq!(s.b(i, tc + dt), 1.0);
                for other in (0..s.points()).filter(|&o| o != i) {
                    assert_eq!(s.b(other, tc + dt), 0.0);
                }
            }
        }
        assert_eq!(s.b(0, 0.0), 1.0);
        assert_eq!(s.b(4, 10.0), 1.0);
    }

    #[test]
    fn a_is_one_for_the_owner_and_floor_elsewhere() {
        let s = schedule();
        let mut a = [0.0; MAX_PRIMITIVES];
        for (n, &tc) in s.t_cond().iter().enumerate() {
            s.a(tc, &mut a);
            for j in 0..3 {
                let want = if j == s.assignment()[n] { 1.0 } else { 1e-3 };
                assert!(
                    (a[j] - want).abs() < 1e-15,
                    "point {n}, primitive {j}: {}",
                    a[j]
                );
            }
        }
        // Between points 1 and 2 both use primitive 1: no fade at all.
        s.a(3.25, &mut a);
        for (got, want) in a[..3].iter().zip([1e-3, 1.0, 1e-3]) {
            assert!((got - want).abs() < 1e-15, "{:?}", &a[..3]);
        }
    }

    #[test]
    fn no_activation_jumps_more_than_epsilon_between_1khz_ticks() {
        for fade in [Fade::Cosine, Fade::Smoothstep, Fade::Smootherstep] {
            let config = ActivationConfig {
                fade,
                crossfade_s: 0.2,
                ..Default::default()
            };
            let eps = config.max_rate_per_s * 1e-3;
            let s = Schedule::new(&[0.5, 1.0, 3.0], &[2, 0, 1], 3, 3.5, config).unwrap();
            let (mut a0, mut a1) = ([0.0; MAX_PRIMITIVES], [0.0; MAX_PRIMITIVES]);
            s.a(0.0, &mut a0);
            let mut worst = 0.0f64;
            for k in 1..=3500 {
                let (t0, t1) = ((k - 1) as f64 * 1e-3, k as f64 * 1e-3);
                s.a(t1, &mut a1);
                for j in 0..3 {
                    worst = worst.max((a1[j] - a0[j]).abs());
                }
                for i in 0..3 {
                    worst = worst.max((s.b(i, t1) - s.b(i, t0)).abs());
                }
                a0 = a1;
            }
            assert!(worst <= eps, "{fade:?}: {worst} > {eps}");
            assert!(
                worst > 0.5 * eps,
                "{fade:?}: the check saw no fade at all ({worst})"
            );
        }
    }

    #[test]
    fn steep_or_crowded_schedules_are_refused() {
        let steep = ActivationConfig {
            crossfade_s: 0.05,
            ..Default::default()
        };
        let e = Schedule::new(&[1.0], &[0], 1, 2.0, steep).unwrap_err();
        assert!(e.to_string().contains("widen crossfade_s"), "{e}");
        let c = ActivationConfig::default();
        assert_eq!(
            Schedule::new(&[1.0, 1.3], &[0, 0], 1, 2.0, c),
            Err(ScheduleError::TooClose(0, 1, 0.30000000000000004, 0.5))
        );
        assert!(matches!(
            Schedule::new(&[1.0, 3.0], &[0, 5], 3, 4.0, c),
            Err(ScheduleError::NoSuchPrimitive {
                index: 1,
                q: 5,
                m: 3
            })
        ));
        assert!(Schedule::new(&[1.0, 5.0], &[0, 0], 1, 4.0, c).is_err());
        assert!(Schedule::new(&[f64::NAN], &[0], 1, 4.0, c).is_err());
        assert!(Schedule::new(&[], &[], 1, 4.0, c).is_err());
    }

    #[test]
    fn config_errors_name_the_key_and_the_range() {
        let check = |edit: &dyn Fn(&mut ActivationConfig), want: &str| {
            let mut c = ActivationConfig::default();
            edit(&mut c);
            let e = c.validate().unwrap_err();
            assert!(e.starts_with(want), "{e} (wanted {want:?})");
            assert_eq!(
                Schedule::new(&[1.0], &[0], 1, 2.0, c).unwrap_err(),
                ScheduleError::Config(e)
            );
        };
        check(
            &|c| c.window_s = f64::NAN,
            "activation.window_s: must be in [0, 60] s",
        );
        check(
            &|c| c.window_s = 1e300,
            "activation.window_s: must be in [0, 60] s",
        );
        check(
            &|c| c.crossfade_s = f64::INFINITY,
            "activation.crossfade_s: must be in (0, 60] s",
        );
        check(
            &|c| c.crossfade_s = 0.0,
            "activation.crossfade_s: must be in (0, 60] s",
        );
        check(&|c| c.floor = 0.0, "activation.floor: must be in (0, 1]");
        check(
            &|c| c.max_rate_per_s = f64::INFINITY,
            "activation.max_rate_per_s: must be in (0, 1000] /s",
        );
        check(
            &|c| c.crossfade_s = 0.05,
            "activation.crossfade_s: 0.05 s changes activations",
        );
        ActivationConfig::default().validate().unwrap();
    }
}
