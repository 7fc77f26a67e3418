//! One constant-curvature module: its arc, the rigid transform from its base to its tip and
//! where its mass sits. Everything is written in θ, never 1/κ, so a straight module (κ → 0) is
//! exact. Pure math, no heap: what the PCC kinematics ([`crate::pcc`]) chain, the arc fit
//! ([`crate::arcs`]) gives and the identified arm (`softarm-identify`) settles.

use nalgebra::{Matrix3, Vector3};

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

    pub(crate) fn translation_z(z: f64) -> Self {
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
pub fn sinc_terms(theta: f64) -> (f64, f64) {
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
        pose.then(&module_pose(&piece))
    })
}

/// Base → tip of one module: R = Rz(φ) Ry(θ) Rz(−φ), p = l (cos φ f θ, sin φ f θ, g).
pub fn module_pose(arc: &Arc) -> Pose {
    let (f, g) = sinc_terms(arc.theta);
    let (sp, cp) = arc.phi.sin_cos();
    Pose {
        rotation: rot_z(arc.phi) * rot_y(arc.theta) * rot_z(-arc.phi),
        position: arc.length * Vector3::new(cp * f * arc.theta, sp * f * arc.theta, g),
    }
}

/// Where one module's mass is on average, in its base's frame: its arc's centroid over its
/// length, l (cos φ a, sin φ a, f) with a = (θ − sin θ)/θ² and f = (1 − cos θ)/θ² (where a
/// bent module's weight pulls).
pub fn module_centroid(arc: &Arc) -> Vector3<f64> {
    let theta = arc.theta;
    let t2 = theta * theta;
    let (f, across) = if theta.abs() < 1e-3 {
        let (f, _) = sinc_terms(theta);
        (f, theta / 6.0 - theta * t2 / 120.0)
    } else {
        ((1.0 - theta.cos()) / t2, (theta - theta.sin()) / t2)
    };
    let (sp, cp) = arc.phi.sin_cos();
    arc.length * Vector3::new(cp * across, sp * across, f)
}

/// A rotation by `a` about x.
pub fn rot_x(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}

/// A rotation by `a` about y.
pub fn rot_y(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}

/// A rotation by `a` about z.
pub fn rot_z(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Series and closed form agree where they hand over.
    #[test]
    fn the_series_hand_over_to_the_closed_form() {
        for theta in [0.999e-3, 1.001e-3] {
            let (f, g) = sinc_terms(theta);
            assert!((f - (1.0 - theta.cos()) / (theta * theta)).abs() < 1e-9);
            assert!((g - theta.sin() / theta).abs() < 1e-12);
        }
        let arc = |theta| Arc {
            length: 0.1,
            theta,
            phi: 0.3,
        };
        for theta in [0.999e-3, 1.001e-3] {
            let c = module_centroid(&arc(theta));
            let across = 0.1 * (theta - theta.sin()) / (theta * theta);
            assert!((c.xy().norm() - across).abs() < 1e-12, "{c}");
        }
    }

    /// The centroid is the mean of the arc's points, bent or straight.
    #[test]
    fn a_modules_centroid_is_the_mean_of_its_arc() {
        for theta in [0.0, 1e-5, 0.4, 2.0, 3.0] {
            let arc = Arc {
                length: 0.2,
                theta,
                phi: -1.1,
            };
            let n = 20_000;
            let mean = (0..n)
                .map(|k| {
                    let s = (k as f64 + 0.5) / n as f64;
                    module_pose(&Arc {
                        length: arc.length * s,
                        theta: arc.theta * s,
                        phi: arc.phi,
                    })
                    .position
                })
                .sum::<Vector3<f64>>()
                / n as f64;
            let c = module_centroid(&arc);
            assert!((c - mean).norm() < 1e-8, "θ {theta}: {c} vs {mean}");
        }
    }
}
