//! The way-point sets soak runs: its pattern, the same whether the stack runs as processes
//! (`softarm soak`) or in one process (`softarm-rehearsal`'s soak example and tests).

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
/// variation of it moving points up to `move_m`; 3 to 6 executions each.
pub fn nth(
    n: u64,
    demo: &WaypointFile,
    move_m: f64,
    rng: &mut impl rand::Rng,
) -> (WaypointFile, u32) {
    let file = if n.is_multiple_of(3) {
        demo.clone()
    } else {
        variation(demo, move_m, rng)
    };
    (file, rng.random_range(3..=6))
}

/// A set like `set` at new places: each point moved up to `move_m` along each axis, and, in
/// three of ten, one point left out (of sets of three or more). New places every set give the
/// learner's lattices new work, which is what a soak is for.
pub fn variation(set: &WaypointFile, move_m: f64, rng: &mut impl rand::Rng) -> WaypointFile {
    let mut point: Vec<Point> = set
        .point
        .iter()
        .map(|p| Point {
            t_s: p.t_s,
            position_m: p.position_m.map(|v| v + rng.random_range(-move_m..move_m)),
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
            let v = variation(&demo, MOVE_M, &mut rng);
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
        // A TDCR of 0.237 m reach against the paper arm's 0.6: about 10 mm.
        assert!((move_for(0.237, 0.6) - 0.025 * 0.395).abs() < 1e-12);
        assert_eq!(move_for(1.2, 0.6), MOVE_M);
    }
}
