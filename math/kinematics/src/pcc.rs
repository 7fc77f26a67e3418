//! Piecewise-constant-curvature kinematics of any arm, from its layout, with the conventions
//! of the independent NumPy model the tests agree with (on the paper's arm, the default
//! `[arm]`). Pure math.
//!
//! Module frame: z along the straight backbone; actuator i at β_i = ψ + (i − 1)·120°, radius d.
//! A module bends towards φ by θ = κ·l, and actuator i has length l − θ d cos(β_i − φ).
//! Everything is written in θ, never 1/κ, so a straight module (κ → 0) is exact.

use nalgebra::{Matrix3, Vector3};

pub use crate::arc::{Arc, Pose};
use crate::arc::{module_pose, tapered_module_pose};
use crate::arcs::{Routes, Undetermined};
use softarm_arm::{Layout, MAX_ACTUATORS, MAX_MODULES};

use softarm_sections::arm::{ArmConfig, Mount};

/// Base → tip of modules `arcs` from `base`, each made by `module`, a connector between
/// consecutive ones and the tool after the last.
fn chain(
    base: Pose,
    arcs: &[Arc],
    connector_m: f64,
    tool_m: f64,
    module: impl Fn(&Arc) -> Pose,
) -> Pose {
    let mut pose = base;
    for (m, arc) in arcs.iter().enumerate() {
        if m > 0 {
            pose = pose.then(&Pose::translation_z(connector_m));
        }
        pose = pose.then(&module(arc));
    }
    pose.then(&Pose::translation_z(tool_m))
}

fn base_of(mount: Mount) -> Pose {
    match mount {
        Mount::Hanging => Pose {
            rotation: Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)),
            position: Vector3::zeros(),
        },
        Mount::Standing => Pose::identity(),
    }
}

/// The PCC kinematics of any arm, from its layout: each actuator's length from its own stroke
/// (plus an offset), the arcs by least squares ([`Routes::arcs`]), the modules chained with
/// the connector between consecutive ones and the tool after the last. `Copy` and heap-free.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arm {
    routes: Routes,
    min_m: [f64; MAX_ACTUATORS],
    max_m: [f64; MAX_ACTUATORS],
    offset_m: [f64; MAX_ACTUATORS],
    connector_m: f64,
    tool_m: f64,
    mount: Mount,
}

impl Arm {
    /// `layout`'s arm, each actuator's length changed by `offset_m` (one per actuator, or empty
    /// for none).
    pub fn new(layout: &Layout, offset_m: &[f64]) -> Self {
        let (mut min_m, mut max_m, mut off) = (
            [0.0; MAX_ACTUATORS],
            [0.0; MAX_ACTUATORS],
            [0.0; MAX_ACTUATORS],
        );
        for (i, a) in layout.actuators().iter().enumerate() {
            min_m[i] = a.min_m;
            max_m[i] = a.max_m;
            off[i] = offset_m.get(i).copied().unwrap_or(0.0);
        }
        Self {
            routes: Routes::of(layout),
            min_m,
            max_m,
            offset_m: off,
            connector_m: layout.connector_m,
            tool_m: layout.tool_m,
            mount: layout.mount,
        }
    }

    /// The arm `[arm]` describes, its `actuator_offset_m` included; the error is the
    /// section's own, for an `arm` that is not valid.
    pub fn of_config(arm: &ArmConfig) -> Result<Self, String> {
        let offsets = arm.actuator_offset_m.as_deref().unwrap_or_default();
        Ok(Self::new(&arm.layout()?, offsets))
    }

    pub fn actuators(&self) -> usize {
        self.routes.actuators()
    }

    pub fn modules(&self) -> usize {
        self.routes.modules()
    }

    /// The module actuator `i` belongs to ([`Routes::owner`]).
    pub fn owner(&self, i: usize) -> usize {
        self.routes.owner(i)
    }

    /// This arm changed as a calibration changes it: the tool and the connectors longer by
    /// `tool_m` and `connector_m`, each actuator by `offset_m[i]`, each module's own actuators
    /// turned by `turn_rad[m]` about its axis. Heap-free.
    pub fn changed(
        &self,
        tool_m: f64,
        connector_m: f64,
        offset_m: &[f64],
        turn_rad: &[f64],
    ) -> Self {
        let mut a = *self;
        a.tool_m += tool_m;
        a.connector_m += connector_m;
        for i in 0..self.actuators() {
            a.offset_m[i] += offset_m[i];
            a.routes.turn(i, turn_rad[self.owner(i)]);
        }
        a
    }

    /// This arm with every tendon `dr_m` further from the backbone (a module stiffening or
    /// softening: the same length differences bend it less or more). Heap-free.
    pub fn widened(&self, dr_m: f64) -> Self {
        let mut a = *self;
        a.routes.widen(dr_m);
        a
    }

    /// End-effector pose for actuator lengths `lengths` (m, one per actuator), each module's
    /// curvature falling from base to tip by `taper` ([`tapered_module_pose`]; 0: PCC).
    pub fn pose_of_lengths(&self, lengths: &[f64], taper: f64) -> Result<Pose, Undetermined> {
        let arcs = self.routes.arcs(&lengths[..self.actuators()])?;
        let arcs = &arcs[..self.modules()];
        let base = base_of(self.mount);
        Ok(if taper == 0.0 {
            chain(base, arcs, self.connector_m, self.tool_m, module_pose)
        } else {
            chain(base, arcs, self.connector_m, self.tool_m, |a| {
                tapered_module_pose(a, taper)
            })
        })
    }

    /// Actuator lengths (m) of normalised actuation `a` (one per actuator), offsets included.
    pub fn lengths(&self, a: &[f64]) -> [f64; MAX_ACTUATORS] {
        let mut l = [0.0; MAX_ACTUATORS];
        for i in 0..self.actuators() {
            l[i] = self.min_m[i] + a[i] * (self.max_m[i] - self.min_m[i]) + self.offset_m[i];
        }
        l
    }

    /// Every module's arc for normalised actuation `a`.
    pub fn arcs(&self, a: &[f64]) -> Result<[Arc; MAX_MODULES], Undetermined> {
        self.routes.arcs(&self.lengths(a)[..self.actuators()])
    }

    /// End-effector pose for normalised actuation `a`.
    pub fn pose(&self, a: &[f64]) -> Result<Pose, Undetermined> {
        self.pose_of_lengths(&self.lengths(a), 0.0)
    }

    /// The backbone for normalised actuation `a`, base to tip, as polylines in the base frame
    /// (m): each module (`per_module` + 1 points along its arc), then the connector after it,
    /// the tool after the last; each starts where the one before ends, and the last point is
    /// the end effector. For drawing the arm.
    pub fn backbone(
        &self,
        a: &[f64],
        per_module: usize,
    ) -> Result<Vec<Vec<[f64; 3]>>, Undetermined> {
        let per_module = per_module.max(1);
        let point = |p: &Pose| [p.position.x, p.position.y, p.position.z];
        let arcs = self.arcs(a)?;
        let mut lines = Vec::with_capacity(2 * self.modules());
        let mut pose = base_of(self.mount);
        for (m, arc) in arcs[..self.modules()].iter().enumerate() {
            lines.push(
                (0..=per_module)
                    .map(|k| {
                        let s = k as f64 / per_module as f64;
                        let part = Arc {
                            length: arc.length * s,
                            theta: arc.theta * s,
                            phi: arc.phi,
                        };
                        point(&pose.then(&module_pose(&part)))
                    })
                    .collect(),
            );
            pose = pose.then(&module_pose(arc));
            let rigid = if m + 1 < self.modules() {
                self.connector_m
            } else {
                self.tool_m
            };
            let next = pose.then(&Pose::translation_z(rigid));
            lines.push(vec![point(&pose), point(&next)]);
            pose = next;
        }
        Ok(lines)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forward::ForwardModel;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    /// The default `[arm]`'s actuators: the paper's arm.
    const N: usize = 6;

    /// The default `[arm]` (the paper's arm), each actuator's length changed by `offset_m`.
    fn paper(offset_m: &[f64]) -> Arm {
        let config = ArmConfig {
            actuator_offset_m: Some(offset_m.to_vec()),
            ..ArmConfig::default()
        };
        Arm::of_config(&config).unwrap()
    }

    fn position(arm: &Arm, a: &[f64; N]) -> [f64; 3] {
        ForwardModel::<N>::position(arm, a)
    }

    /// Module `module`'s arc for its three actuators' lengths `l` (the other module straight).
    fn arc_of(arm: &Arm, module: usize, l: [f64; 3]) -> Arc {
        let mut lengths = [0.22; N];
        lengths[3 * module..3 * module + 3].copy_from_slice(&l);
        arm.routes.arcs(&lengths).unwrap()[module]
    }

    fn close(got: [f64; 3], want: [f64; 3], tol: f64) {
        for d in 0..3 {
            assert!((got[d] - want[d]).abs() <= tol, "{got:?} vs {want:?}");
        }
    }

    /// Every value of the team's PCC reference table (an independent NumPy implementation,
    /// printed to 1e-6 m and copied here; agreement is to the printed digits, 5e-7 m).
    #[test]
    fn agrees_with_the_reference_values() {
        let arm = paper(&[0.0; N]);
        let table = [
            ([0.5; 6], [0.0, 0.0, -0.5]),
            ([0.0; 6], [0.0, 0.0, -0.44]),
            ([1.0; 6], [0.0, 0.0, -0.56]),
            ([0.0, 1.0, 1.0, 0.5, 0.5, 0.5], [0.427828, 0.0, -0.135513]),
            (
                [0.2, 0.8, 0.5, 0.9, 0.1, 0.4],
                [0.121233, 0.216720, -0.380126],
            ),
            (
                [1.0, 0.0, 0.5, 0.0, 1.0, 0.5],
                [-0.193725, -0.270876, -0.269483],
            ),
        ];
        for (a, p) in table {
            close(position(&arm, &a), p, 5e-7);
        }
        let m = module_pose(&arc_of(&arm, 0, [0.20, 0.22, 0.22])).position;
        close([m.x, m.y, m.z], [0.055553, 0.0, 0.203363], 5e-7);
    }

    /// The straight poses are exact to 1e-9 (and bit-for-bit continuous into tiny bends).
    #[test]
    fn straight_modules_are_exact() {
        let arm = paper(&[0.0; N]);
        close(position(&arm, &[0.5; 6]), [0.0, 0.0, -0.5], 1e-12);
        let tiny = position(&arm, &[0.5, 0.5 + 1e-12, 0.5, 0.5, 0.5, 0.5]);
        close(tiny, [0.0, 0.0, -0.5], 1e-9);
    }

    #[test]
    fn the_backbone_runs_from_the_base_to_the_end_effector() {
        let arm = paper(&[0.0, 0.0, 0.0, 0.0, 0.003, 0.0]);
        let mut rng = StdRng::seed_from_u64(3);
        for _ in 0..200 {
            let a: [f64; 6] = std::array::from_fn(|_| rng.random());
            let lines = arm.backbone(&a, 8).unwrap();
            assert_eq!(lines.iter().map(Vec::len).collect::<Vec<_>>(), [9, 2, 9, 2]);
            close(lines[0][0], [0.0; 3], 1e-15);
            for w in lines.windows(2) {
                close(w[1][0], *w[0].last().unwrap(), 1e-15);
            }
            close(*lines[3].last().unwrap(), position(&arm, &a), 1e-12);
            // The arc's points lie on it: as long as the module's backbone.
            let arc_length: f64 = lines[0]
                .windows(2)
                .map(|w| {
                    (0..3)
                        .map(|d| (w[1][d] - w[0][d]).powi(2))
                        .sum::<f64>()
                        .sqrt()
                })
                .sum();
            let l = arm.lengths(&a);
            let module = (l[0] + l[1] + l[2]) / 3.0;
            assert!(arc_length <= module + 1e-12 && arc_length > 0.98 * module);
        }
    }

    #[test]
    fn an_actuator_offset_is_that_actuator_longer() {
        let nominal = paper(&[0.0; N]);
        let crept = paper(&[0.0, 0.004, 0.0, 0.0, 0.0, 0.0]);
        let a = [0.3, 0.5, 0.6, 0.5, 0.4, 0.5];
        let mut longer = a;
        // The default stroke: 0.19 to 0.25 m.
        longer[1] += 0.004 / (0.25 - 0.19);
        let (p, q) = (position(&crept, &a), position(&nominal, &longer));
        assert!(
            (0..3).all(|d| (p[d] - q[d]).abs() < 1e-12),
            "{p:?} vs {q:?}"
        );
        assert_ne!(position(&crept, &a), position(&nominal, &a));
    }

    #[test]
    fn lengths_to_arc_to_lengths_round_trips() {
        let arm = paper(&[0.0; N]);
        let mut rng = StdRng::seed_from_u64(2);
        for _ in 0..500 {
            let a: [f64; N] = std::array::from_fn(|_| rng.random());
            let l = arm.lengths(&a);
            let arcs = arm.arcs(&a).unwrap();
            let mut back = [0.0; N];
            arm.routes.lengths(&arcs, &mut back);
            for i in 0..N {
                assert!(
                    (back[i] - l[i]).abs() < 1e-12,
                    "{l:?} -> {arcs:?} -> {back:?}"
                );
            }
        }
    }

    #[test]
    fn shortening_actuator_one_bends_towards_it() {
        for (module, psi) in [(0usize, 0.0f64), (1, 60.0)] {
            let arm = paper(&[0.0; N]);
            let arc = arc_of(&arm, module, [0.20, 0.22, 0.22]);
            assert!(
                (arc.phi - psi.to_radians()).abs() < 1e-12,
                "bends towards actuator 1"
            );
            let p = module_pose(&arc).position;
            let towards = Vector3::new(psi.to_radians().cos(), psi.to_radians().sin(), 0.0);
            assert!(p.dot(&towards) > 0.05);
        }
    }

    #[test]
    fn a_tapered_module_bends_as_much_but_more_at_its_base() {
        let arm = paper(&[0.0; N]);
        let arc = arc_of(&arm, 0, [0.20, 0.24, 0.23]);
        let pcc = module_pose(&arc);
        // No taper: the same arc, piece by piece (to rounding).
        let flat = tapered_module_pose(&arc, 0.0);
        assert!((flat.position - pcc.position).norm() < 1e-12);
        let tapered = tapered_module_pose(&arc, 0.5);
        // Same bend and plane: the tip points the same way.
        assert!((tapered.rotation - pcc.rotation).norm() < 1e-12);
        // More bend near the base swings the tip further out from the base's axis.
        let out = |p: &Pose| p.position.xy().norm();
        assert!(out(&tapered) > out(&pcc) + 1e-3, "{tapered:?} vs {pcc:?}");
        // The arm: taper 0 is pose_of_lengths exactly; a taper moves the tip by millimetres.
        let l = arm.lengths(&[0.2, 0.8, 0.5, 0.9, 0.1, 0.4]);
        let pose = |taper| arm.pose_of_lengths(&l, taper).unwrap();
        assert_eq!(
            pose(0.0),
            arm.pose(&[0.2, 0.8, 0.5, 0.9, 0.1, 0.4]).unwrap()
        );
        let moved = (pose(0.5).position - pose(0.0).position).norm();
        assert!(moved > 2e-3 && moved < 0.05, "{moved}");
    }

    /// The paper's arm by its shorthand keys is the paper's arm by its modules, offsets
    /// included, and the three-module TDCR draws as three modules, connectors and a tool ending
    /// at its pose.
    #[test]
    fn the_shorthand_and_the_modules_are_one_arm() {
        let offsets = [0.001, 0.0, -0.002, 0.0, 0.003, 0.0];
        let shorthand = paper(&offsets);
        let modules: softarm_arm::Description =
            toml::from_str(include_str!("../../../contract/arm/testdata/paper.toml")).unwrap();
        let arm = Arm::new(&Layout::new(&modules).unwrap(), &offsets);
        assert_eq!(arm, shorthand);
        let mut rng = StdRng::seed_from_u64(3);
        for _ in 0..50 {
            let a: [f64; N] = std::array::from_fn(|_| rng.random());
            let lines = arm.backbone(&a, 8).unwrap();
            assert_eq!(lines.len(), 4);
            close(*lines[3].last().unwrap(), position(&arm, &a), 1e-12);
        }
        let tdcr: softarm_arm::Description =
            toml::from_str(include_str!("../../../contract/arm/testdata/tdcr.toml")).unwrap();
        let tdcr = Arm::new(&Layout::new(&tdcr).unwrap(), &[]);
        let a = [0.3, 0.6, 0.5, 0.5, 0.2, 0.7, 0.4, 0.5, 0.6];
        let lines = tdcr.backbone(&a, 8).unwrap();
        assert_eq!(lines.len(), 6);
        let tip = tdcr.pose(&a).unwrap().position;
        close(*lines[5].last().unwrap(), [tip.x, tip.y, tip.z], 1e-12);
        for w in lines.windows(2) {
            close(w[0][w[0].len() - 1], w[1][0], 1e-12);
        }
    }
}
