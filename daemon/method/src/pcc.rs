//! Piecewise-constant-curvature kinematics of the two-module, six-actuator arm, with the
//! conventions of the independent NumPy model the tests agree with. Pure math.
//!
//! Module frame: z along the straight backbone; actuator i at β_i = ψ + (i − 1)·120°, radius d.
//! A module bends towards φ by θ = κ·l, and actuator i has length l − θ d cos(β_i − φ).
//! Everything is written in θ, never 1/κ, so a straight module (κ → 0) is exact.

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

pub use crate::space::ACTUATORS;

/// Actuators per module and modules per arm.
pub const ACTUATORS_PER_MODULE: usize = 3;
pub const MODULES: usize = 2;
const _: () = assert!(ACTUATORS == ACTUATORS_PER_MODULE * MODULES);

/// How the arm is mounted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Mount {
    /// Base frame diag(1, −1, −1): the arm points down, −Z.
    Hanging,
    /// Base frame identity: the arm points up, +Z.
    Standing,
}

/// The arm's geometry; the `[arm]` section of the config. Defaults: two modules,
/// actuator radius 25 mm, actuator length 0.19–0.25 m, second module rotated 60°, hanging base.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ArmGeometry {
    /// Distance of each actuator from the backbone (m).
    pub actuator_radius_m: f64,
    /// Actuator length at normalised actuation 0 (m).
    pub actuator_min_m: f64,
    /// Actuator length at normalised actuation 1 (m).
    pub actuator_max_m: f64,
    /// ψ of each module: the angle of its actuator 1 (degrees).
    pub module_rotation_deg: [f64; MODULES],
    /// Rigid connector between the modules (m).
    pub connector_m: f64,
    /// Rigid tool after the second module (m).
    pub tool_m: f64,
    pub mount: Mount,
    /// Added to each actuator's length (m): tendon creep, a module that is not quite the one
    /// the model was trained on. Zero on the nominal arm.
    pub actuator_offset_m: [f64; ACTUATORS],
}

impl Default for ArmGeometry {
    fn default() -> Self {
        Self {
            actuator_radius_m: 0.025,
            actuator_min_m: 0.19,
            actuator_max_m: 0.25,
            module_rotation_deg: [0.0, 60.0],
            connector_m: 0.03,
            tool_m: 0.03,
            mount: Mount::Hanging,
            actuator_offset_m: [0.0; ACTUATORS],
        }
    }
}

/// Arc parameters of one constant-curvature module.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arc {
    /// Backbone length l (m).
    pub length: f64,
    /// Bending angle θ = κ l (rad), ≥ 0.
    pub theta: f64,
    /// Bending-plane angle φ (rad): the module bends towards φ.
    pub phi: f64,
}

impl Arc {
    pub fn curvature(&self) -> f64 {
        self.theta / self.length
    }
}

/// A rigid transform: rotation and translation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub rotation: Matrix3<f64>,
    pub position: Vector3<f64>,
}

impl Pose {
    pub fn identity() -> Self {
        Self {
            rotation: Matrix3::identity(),
            position: Vector3::zeros(),
        }
    }

    fn translation_z(z: f64) -> Self {
        Self {
            rotation: Matrix3::identity(),
            position: Vector3::new(0.0, 0.0, z),
        }
    }

    pub fn then(&self, next: &Pose) -> Pose {
        Pose {
            rotation: self.rotation * next.rotation,
            position: self.position + self.rotation * next.position,
        }
    }
}

/// (1 − cos θ)/θ² and sin θ/θ, by series near 0 where the quotients lose precision.
fn sinc_terms(theta: f64) -> (f64, f64) {
    let t2 = theta * theta;
    if theta.abs() < 1e-3 {
        (
            0.5 - t2 / 24.0 + t2 * t2 / 720.0,
            1.0 - t2 / 6.0 + t2 * t2 / 120.0,
        )
    } else {
        ((1.0 - theta.cos()) / t2, theta.sin() / theta)
    }
}

/// Constant-curvature pieces a tapered module is made of.
pub const TAPER_PIECES: usize = 16;

/// Base → tip of a module whose curvature is not constant but falls linearly along it,
/// κ(s) = κ̄ (1 + c (1 − 2 s / l)) for c = `taper` in [0, 1]: at the base (1 + c) κ̄, at the
/// tip (1 − c) κ̄, as a module loaded by what hangs below it bends more near its base. Length l,
/// total bend θ = κ̄ l and plane φ are `arc`'s, so the tip's orientation is PCC's and only its
/// position departs. Made of [`TAPER_PIECES`] constant-curvature pieces, each with the mean
/// curvature of its stretch (the bends add up to θ exactly).
pub fn tapered_module_pose(arc: &Arc, taper: f64) -> Pose {
    let n = TAPER_PIECES as f64;
    (0..TAPER_PIECES).fold(Pose::identity(), |pose, k| {
        let share = 1.0 + taper * (1.0 - (2 * k + 1) as f64 / n);
        let piece = Arc {
            length: arc.length / n,
            theta: arc.theta / n * share,
            phi: arc.phi,
        };
        pose.then(&ArmGeometry::module_pose(&piece))
    })
}

impl ArmGeometry {
    /// Longest length of the geometry (m): actuators, connector and tool.
    pub const MAX_LENGTH_M: f64 = 10.0;
    /// Largest actuator length offset (m), either way.
    pub const MAX_OFFSET_M: f64 = 0.05;
    /// Largest actuator radius (m).
    pub const MAX_RADIUS_M: f64 = 1.0;

    /// Checks the geometry; the error is `arm.KEY: message`.
    pub fn validate(&self) -> Result<(), String> {
        let max = Self::MAX_LENGTH_M;
        let r = Self::MAX_RADIUS_M;
        let positive = [
            ("actuator_radius_m", self.actuator_radius_m, r),
            ("actuator_min_m", self.actuator_min_m, max),
            ("actuator_max_m", self.actuator_max_m, max),
        ];
        for (key, v, max) in positive {
            if !(v.is_finite() && v > 0.0 && v <= max) {
                return Err(format!(
                    "arm.{key}: must be a length in (0, {max}] m, got {v:?}"
                ));
            }
        }
        for (key, v) in [("connector_m", self.connector_m), ("tool_m", self.tool_m)] {
            if !(v.is_finite() && (0.0..=max).contains(&v)) {
                return Err(format!(
                    "arm.{key}: must be a length in [0, {max}] m, got {v:?}"
                ));
            }
        }
        if self.actuator_max_m <= self.actuator_min_m {
            return Err(format!(
                "arm.actuator_max_m: {} m must exceed actuator_min_m = {} m",
                self.actuator_max_m, self.actuator_min_m
            ));
        }
        let o = Self::MAX_OFFSET_M;
        for (i, v) in self.actuator_offset_m.iter().enumerate() {
            if !(v.is_finite() && (-o..=o).contains(v)) {
                return Err(format!(
                    "arm.actuator_offset_m: actuator {} is {v:?}; each must be in [-{o}, {o}] m",
                    i + 1
                ));
            }
        }
        for (m, v) in self.module_rotation_deg.iter().enumerate() {
            if !(v.is_finite() && (-360.0..=360.0).contains(v)) {
                return Err(format!(
                    "arm.module_rotation_deg: module {} is {v:?}; each must be in [-360, 360] degrees",
                    m + 1
                ));
            }
        }
        Ok(())
    }

    /// Actuator length (m) of a normalised actuation.
    pub fn length_of(&self, a: f64) -> f64 {
        self.actuator_min_m + a * (self.actuator_max_m - self.actuator_min_m)
    }

    /// Normalised actuation of an actuator length (m).
    pub fn actuation_of(&self, length: f64) -> f64 {
        (length - self.actuator_min_m) / (self.actuator_max_m - self.actuator_min_m)
    }

    fn psi(&self, module: usize) -> f64 {
        self.module_rotation_deg[module].to_radians()
    }

    /// Lengths (m) of a module's three actuators → its arc (closed-form inverse).
    pub fn arc_of(&self, module: usize, l: [f64; 3]) -> Arc {
        let d = self.actuator_radius_m;
        let length = (l[0] + l[1] + l[2]) / 3.0;
        let bx = (l[1] + l[2] - 2.0 * l[0]) / (3.0 * d);
        let by = (l[2] - l[1]) / (3f64.sqrt() * d);
        let theta = bx.hypot(by);
        let phi = if theta == 0.0 {
            0.0
        } else {
            by.atan2(bx) + self.psi(module)
        };
        Arc { length, theta, phi }
    }

    /// A module's arc → its three actuator lengths (m): l_i = l − θ d cos(β_i − φ).
    pub fn lengths_of(&self, module: usize, arc: &Arc) -> [f64; 3] {
        let d = self.actuator_radius_m;
        let psi = self.psi(module);
        std::array::from_fn(|i| {
            let beta = psi + i as f64 * 2.0 * std::f64::consts::PI / 3.0;
            arc.length - arc.theta * d * (beta - arc.phi).cos()
        })
    }

    /// Base → tip of one module: R = Rz(φ) Ry(θ) Rz(−φ), p = l (cos φ f θ, sin φ f θ, g).
    pub fn module_pose(arc: &Arc) -> Pose {
        let (f, g) = sinc_terms(arc.theta);
        let (sp, cp) = arc.phi.sin_cos();
        let (st, ct) = arc.theta.sin_cos();
        let rz = |s: f64, c: f64| Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
        let ry = Matrix3::new(ct, 0.0, st, 0.0, 1.0, 0.0, -st, 0.0, ct);
        Pose {
            rotation: rz(sp, cp) * ry * rz(-sp, cp),
            position: arc.length * Vector3::new(cp * f * arc.theta, sp * f * arc.theta, g),
        }
    }

    fn base(&self) -> Pose {
        match self.mount {
            Mount::Hanging => Pose {
                rotation: Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)),
                position: Vector3::zeros(),
            },
            Mount::Standing => Pose::identity(),
        }
    }

    /// Arcs of both modules for actuator lengths in metres.
    pub fn arcs_of_lengths(&self, lengths: &[f64; ACTUATORS]) -> [Arc; MODULES] {
        std::array::from_fn(|m| {
            self.arc_of(m, [lengths[3 * m], lengths[3 * m + 1], lengths[3 * m + 2]])
        })
    }

    /// End-effector pose for actuator lengths in metres:
    /// T_EE = T_base · T_module1 · Trans_z(connector) · T_module2 · Trans_z(tool).
    pub fn pose_of_lengths(&self, lengths: &[f64; ACTUATORS]) -> Pose {
        let [m1, m2] = self.arcs_of_lengths(lengths);
        self.base()
            .then(&Self::module_pose(&m1))
            .then(&Pose::translation_z(self.connector_m))
            .then(&Self::module_pose(&m2))
            .then(&Pose::translation_z(self.tool_m))
    }

    /// [`ArmGeometry::pose_of_lengths`] on an arm that is not quite PCC: each module's
    /// curvature falls linearly from base to tip by `taper` ([`tapered_module_pose`]); the
    /// same actuator lengths give each module the same bend θ and plane φ, so the tip points
    /// the same way but sits elsewhere. `taper = 0` is exactly `pose_of_lengths`.
    pub fn pose_of_lengths_tapered(&self, lengths: &[f64; ACTUATORS], taper: f64) -> Pose {
        if taper == 0.0 {
            return self.pose_of_lengths(lengths);
        }
        let [m1, m2] = self.arcs_of_lengths(lengths);
        self.base()
            .then(&tapered_module_pose(&m1, taper))
            .then(&Pose::translation_z(self.connector_m))
            .then(&tapered_module_pose(&m2, taper))
            .then(&Pose::translation_z(self.tool_m))
    }

    /// Actuator lengths (m) of a normalised actuation, offsets included.
    pub fn lengths(&self, a: &[f64; ACTUATORS]) -> [f64; ACTUATORS] {
        std::array::from_fn(|i| self.length_of(a[i]) + self.actuator_offset_m[i])
    }

    /// End-effector pose for a normalised actuation a ∈ [0, 1]^6.
    pub fn pose(&self, a: &[f64; ACTUATORS]) -> Pose {
        self.pose_of_lengths(&self.lengths(a))
    }

    /// End-effector position (m) for a normalised actuation: the forward model of the plant.
    pub fn position(&self, a: &[f64; ACTUATORS]) -> [f64; 3] {
        let p = self.pose(a).position;
        [p.x, p.y, p.z]
    }

    /// The backbone for a normalised actuation, base to tip, as four polylines in the base
    /// frame (m): module 1 (`per_module` + 1 points along its arc), the connector, module 2
    /// (the same), the tool. Each starts where the one before ends; the last point is
    /// [`ArmGeometry::position`]. For drawing the arm.
    pub fn backbone(&self, a: &[f64; ACTUATORS], per_module: usize) -> [Vec<[f64; 3]>; 4] {
        let per_module = per_module.max(1);
        let point = |p: &Pose| [p.position.x, p.position.y, p.position.z];
        let arc = |from: &Pose, m: &Arc| -> Vec<[f64; 3]> {
            (0..=per_module)
                .map(|i| {
                    let s = i as f64 / per_module as f64;
                    let part = Arc {
                        length: m.length * s,
                        theta: m.theta * s,
                        phi: m.phi,
                    };
                    point(&from.then(&Self::module_pose(&part)))
                })
                .collect()
        };
        let [m1, m2] = self.arcs_of_lengths(&self.lengths(a));
        let base = self.base();
        let end1 = base.then(&Self::module_pose(&m1));
        let start2 = end1.then(&Pose::translation_z(self.connector_m));
        let end2 = start2.then(&Self::module_pose(&m2));
        let tip = end2.then(&Pose::translation_z(self.tool_m));
        [
            arc(&base, &m1),
            vec![point(&end1), point(&start2)],
            arc(&start2, &m2),
            vec![point(&end2), point(&tip)],
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    fn close(got: [f64; 3], want: [f64; 3], tol: f64) {
        for d in 0..3 {
            assert!((got[d] - want[d]).abs() <= tol, "{got:?} vs {want:?}");
        }
    }

    /// Every value of the team's PCC reference table (an independent NumPy implementation,
    /// printed to 1e-6 m and copied here; agreement is to the printed digits, 5e-7 m).
    #[test]
    fn agrees_with_the_reference_values() {
        let arm = ArmGeometry::default();
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
            close(arm.position(&a), p, 5e-7);
        }
        let m = ArmGeometry::module_pose(&arm.arc_of(0, [0.20, 0.22, 0.22])).position;
        close([m.x, m.y, m.z], [0.055553, 0.0, 0.203363], 5e-7);
    }

    /// The straight poses are exact to 1e-9 (and bit-for-bit continuous into tiny bends).
    #[test]
    fn straight_modules_are_exact() {
        let arm = ArmGeometry::default();
        close(arm.position(&[0.5; 6]), [0.0, 0.0, -0.5], 1e-12);
        let tiny = arm.position(&[0.5, 0.5 + 1e-12, 0.5, 0.5, 0.5, 0.5]);
        close(tiny, [0.0, 0.0, -0.5], 1e-9);
        // Series and closed form agree where they hand over.
        for theta in [0.999e-3, 1.001e-3] {
            let (f, g) = sinc_terms(theta);
            assert!((f - (1.0 - theta.cos()) / (theta * theta)).abs() < 1e-9);
            assert!((g - theta.sin() / theta).abs() < 1e-12);
        }
    }

    #[test]
    fn the_backbone_runs_from_the_base_to_the_end_effector() {
        let mut arm = ArmGeometry::default();
        arm.actuator_offset_m[4] = 0.003;
        let mut rng = StdRng::seed_from_u64(3);
        for _ in 0..200 {
            let a: [f64; 6] = std::array::from_fn(|_| rng.random());
            let lines = arm.backbone(&a, 8);
            assert_eq!(lines.iter().map(Vec::len).collect::<Vec<_>>(), [9, 2, 9, 2]);
            close(lines[0][0], [0.0; 3], 1e-15);
            for w in lines.windows(2) {
                close(w[1][0], *w[0].last().unwrap(), 1e-15);
            }
            close(*lines[3].last().unwrap(), arm.position(&a), 1e-12);
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
        let nominal = ArmGeometry::default();
        let mut crept = nominal;
        crept.actuator_offset_m[1] = 0.004;
        crept.validate().unwrap();
        let a = [0.3, 0.5, 0.6, 0.5, 0.4, 0.5];
        let mut longer = a;
        longer[1] += 0.004 / (nominal.actuator_max_m - nominal.actuator_min_m);
        let (p, q) = (crept.position(&a), nominal.position(&longer));
        assert!(
            (0..3).all(|d| (p[d] - q[d]).abs() < 1e-12),
            "{p:?} vs {q:?}"
        );
        assert_ne!(crept.position(&a), nominal.position(&a));
        crept.actuator_offset_m[5] = 0.06;
        let e = crept.validate().unwrap_err();
        assert!(e.starts_with("arm.actuator_offset_m: actuator 6"), "{e}");
    }

    #[test]
    fn lengths_to_arc_to_lengths_round_trips() {
        let arm = ArmGeometry::default();
        let mut rng = StdRng::seed_from_u64(2);
        for _ in 0..500 {
            let l: [f64; 3] = std::array::from_fn(|_| arm.length_of(rng.random()));
            for module in 0..2 {
                let arc = arm.arc_of(module, l);
                let back = arm.lengths_of(module, &arc);
                for i in 0..3 {
                    assert!(
                        (back[i] - l[i]).abs() < 1e-12,
                        "{l:?} -> {arc:?} -> {back:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn shortening_actuator_one_bends_towards_it() {
        for (module, psi) in [(0usize, 0.0f64), (1, 60.0)] {
            let arm = ArmGeometry::default();
            let arc = arm.arc_of(module, [0.20, 0.22, 0.22]);
            assert!(
                (arc.phi - psi.to_radians()).abs() < 1e-12,
                "bends towards actuator 1"
            );
            let p = ArmGeometry::module_pose(&arc).position;
            let towards = Vector3::new(psi.to_radians().cos(), psi.to_radians().sin(), 0.0);
            assert!(p.dot(&towards) > 0.05);
        }
    }

    #[test]
    fn a_tapered_module_bends_as_much_but_more_at_its_base() {
        let arm = ArmGeometry::default();
        let arc = arm.arc_of(0, [0.20, 0.24, 0.23]);
        let pcc = ArmGeometry::module_pose(&arc);
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
        assert_eq!(
            arm.pose_of_lengths_tapered(&l, 0.0),
            arm.pose_of_lengths(&l)
        );
        let moved = (arm.pose_of_lengths_tapered(&l, 0.5).position
            - arm.pose_of_lengths(&l).position)
            .norm();
        assert!(moved > 2e-3 && moved < 0.05, "{moved}");
    }

    #[test]
    fn bad_geometry_names_the_key() {
        let arm = ArmGeometry {
            actuator_max_m: 0.1,
            ..Default::default()
        };
        assert!(arm.validate().unwrap_err().contains("arm.actuator_max_m"));
        let arm = ArmGeometry {
            actuator_radius_m: f64::NAN,
            ..Default::default()
        };
        assert!(
            arm.validate()
                .unwrap_err()
                .contains("arm.actuator_radius_m")
        );
        assert!(ArmGeometry::default().validate().is_ok());
    }

    #[test]
    fn every_length_and_angle_is_bounded() {
        let check = |arm: ArmGeometry, want: &str| {
            let e = arm.validate().unwrap_err();
            assert!(e.starts_with(want), "{e} (wanted {want:?})");
        };
        let d = ArmGeometry::default();
        check(
            ArmGeometry {
                module_rotation_deg: [0.0, f64::NAN],
                ..d
            },
            "arm.module_rotation_deg: module 2 is NaN; each must be in [-360, 360] degrees",
        );
        check(
            ArmGeometry {
                module_rotation_deg: [1e300, 0.0],
                ..d
            },
            "arm.module_rotation_deg: module 1 is 1e300",
        );
        check(
            ArmGeometry {
                actuator_max_m: 1e300,
                ..d
            },
            "arm.actuator_max_m: must be a length in (0, 10] m",
        );
        check(
            ArmGeometry {
                actuator_radius_m: 2.0,
                ..d
            },
            "arm.actuator_radius_m: must be a length in (0, 1] m",
        );
        check(
            ArmGeometry {
                tool_m: f64::INFINITY,
                ..d
            },
            "arm.tool_m: must be a length in [0, 10] m",
        );
        check(
            ArmGeometry {
                actuator_max_m: 0.1,
                ..d
            },
            "arm.actuator_max_m: 0.1 m must exceed actuator_min_m = 0.19 m",
        );
    }
}
