//! The way-point sets soak runs: its pattern, the same whether the stack runs as processes
//! (`softarm-rig soak`) or in one process (`softarm-rehearsal`'s soak example and tests).

use rand::RngExt;
use softarm_config::waypoints::{Point, WaypointFile};

/// How far a variation moves each point along each axis on the paper's arm (m); another arm's
/// soak scales it by its reach ([`move_for`]).
pub const MOVE_M: f64 = 0.025;

/// [`MOVE_M`] for an arm of reach `reach_m`: as much of its reach as 25 mm is of the paper
/// arm's, `paper_reach_m`, and never more.
pub fn move_for(reach_m: f64, paper_reach_m: f64) -> f64 {
    MOVE_M * (reach_m / paper_reach_m).clamp(0.0, 1.0)
}

/// The `n`th set of a soak (from 0) and its executions: the demo set every third, else a
/// variation of it moving points up to `move_m` within `reach_m`; 3 to 6 executions each.
pub fn nth(
    n: u64,
    demo: &WaypointFile,
    move_m: f64,
    reach_m: f64,
    rng: &mut impl rand::Rng,
) -> (WaypointFile, u32) {
    let file = if n.is_multiple_of(3) {
        demo.clone()
    } else {
        variation(demo, move_m, reach_m, rng)
    };
    (file, rng.random_range(3..=6))
}

/// A set like `set` at new places: each point moved up to `move_m` along each axis, and, in
/// three of ten, one point left out (of sets of three or more). New places every set give the
/// learner's lattices new work, which is what a soak is for. A move that would take a point
/// beyond `reach_m` from the base (which the controller refuses) is made the other way, or,
/// if that leaves it too, not made: a set near full extension stays one the arm can take.
pub fn variation(
    set: &WaypointFile,
    move_m: f64,
    reach_m: f64,
    rng: &mut impl rand::Rng,
) -> WaypointFile {
    let within = |p: &[f64; 3]| p.iter().map(|v| v * v).sum::<f64>().sqrt() <= reach_m;
    let mut point: Vec<Point> = set
        .point
        .iter()
        .map(|p| {
            let by: [f64; 3] = std::array::from_fn(|_| rng.random_range(-move_m..move_m));
            let there = |sign: f64| std::array::from_fn(|k| p.position_m[k] + sign * by[k]);
            let position_m = [there(1.0), there(-1.0)]
                .into_iter()
                .find(within)
                .unwrap_or(p.position_m);
            Point {
                t_s: p.t_s,
                position_m,
            }
        })
        .collect();
    if point.len() > 2 && rng.random_bool(0.3) {
        point.remove(rng.random_range(0..point.len()));
    }
    WaypointFile {
        duration_s: set.duration_s,
        point,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn a_variation_keeps_the_times_and_moves_each_point_at_most_25_mm() {
        let demo = WaypointFile::parse(softarm_stack::sandbox::DEMO_WAYPOINTS).unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let mut shorter = 0;
        for _ in 0..50 {
            let v = variation(&demo, MOVE_M, 1.0, &mut rng);
            assert_eq!(v.duration_s, demo.duration_s);
            let left_out = demo.point.len() - v.point.len();
            assert!(left_out <= 1);
            shorter += left_out;
            // Each point of the variation is one of the demo's, in order, moved < 25 mm.
            let mut from = demo.point.iter();
            for p in &v.point {
                let o = from.find(|o| o.t_s == p.t_s).unwrap();
                for (a, b) in p.position_m.iter().zip(o.position_m) {
                    assert!((a - b).abs() < 0.025);
                }
            }
            v.to_set(3).unwrap();
        }
        assert!(shorter > 0 && shorter < 50);
        // An arm whose reach is just beyond the set's farthest point: every variation within it.
        let farthest = (demo.point.iter())
            .map(|p| p.position_m.iter().map(|v| v * v).sum::<f64>().sqrt())
            .fold(0.0, f64::max);
        for _ in 0..50 {
            let v = variation(&demo, MOVE_M, farthest + 0.002, &mut rng);
            for p in &v.point {
                let r = p.position_m.iter().map(|v| v * v).sum::<f64>().sqrt();
                assert!(r <= farthest + 0.002, "{r}");
            }
        }
        // A TDCR of 0.237 m reach against the paper arm's 0.6: about 10 mm.
        assert!((move_for(0.237, 0.6) - 0.025 * 0.395).abs() < 1e-12);
        assert_eq!(move_for(1.2, 0.6), MOVE_M);
    }
}
