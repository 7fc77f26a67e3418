//! A physical model of a tendon-driven continuum arm, for identification: each module a
//! constant-curvature arc that its tendons bend and compress, tendons that only pull.
//!
//! The arm settles where its elastic energy is least: each module's bend u_m (a 2-vector,
//! θ (cos φ, sin φ)) costs ½ k_m |u_m|², its axial compression c_m costs ½ k_a c_m², and a
//! tendon pulled in by more than the arm's shape shortens its path stretches like a stiff
//! one-sided spring, ½ k_t max(0, d_i − o_i − s_i)², where its path shortens by
//! s_i = Σ over the modules it runs through of r_i (cos β_i, sin β_i)·u_m + c_m. A slack
//! tendon (pulled in less than its path shortened) pushes nothing: this is what a purely
//! geometric model, which makes every tendon's length the arc's, gets wrong when a lab slackens
//! the tendons it does not pull. Convex in (u, c): solved exactly by Newton's method on its
//! active set of taut tendons. Pure math, no I/O.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use softarm_arm::{Layout, Mount};

/// Where each parameter sits in the vector a calibration fits, for M modules and n tendons.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slots {
    pub modules: usize,
    pub tendons: usize,
}

impl Slots {
    /// Module m's backbone length (m).
    pub fn length(&self, m: usize) -> usize {
        m
    }
    /// Module m's bending stiffness, ln k_m (module 0's is the unit).
    pub fn bend_stiffness(&self, m: usize) -> usize {
        self.modules + m
    }
    /// Module m's rotation (rad): added to each of its tendons' angles.
    pub fn rotation(&self, m: usize) -> usize {
        2 * self.modules + m
    }
    /// ln k_a: axial stiffness.
    pub fn axial_stiffness(&self) -> usize {
        3 * self.modules
    }
    /// ln k_t: the tendons' stiffness.
    pub fn tendon_stiffness(&self) -> usize {
        3 * self.modules + 1
    }
    /// Tendon i's routing radius (m).
    pub fn radius(&self, i: usize) -> usize {
        3 * self.modules + 2 + i
    }
    /// Tendon i's angle (rad), in its module before the module's rotation.
    pub fn angle(&self, i: usize) -> usize {
        3 * self.modules + 2 + self.tendons + i
    }
    /// Tendon i's offset (m): how far it is pulled in where it turns taut on a straight arm.
    pub fn offset(&self, i: usize) -> usize {
        3 * self.modules + 2 + 2 * self.tendons + i
    }
    /// The tracked marker in the tip's frame (x, y, z; m).
    pub fn marker(&self, k: usize) -> usize {
        3 * self.modules + 2 + 3 * self.tendons + k
    }
    /// The base's tilt and turn (rotations about x, y, z; rad).
    pub fn base_rotation(&self, k: usize) -> usize {
        3 * self.modules + 5 + 3 * self.tendons + k
    }
    /// The base's position (m).
    pub fn base_position(&self, k: usize) -> usize {
        3 * self.modules + 8 + 3 * self.tendons + k
    }
    pub fn count(&self) -> usize {
        3 * self.modules + 11 + 3 * self.tendons
    }
}

/// A tendon arm's structure: which module each tendon ends in, which it runs through, and the
/// rigid connectors between modules.
#[derive(Debug, Clone, PartialEq)]
pub struct Structure {
    pub slots: Slots,
    /// `passes[i][m]`: tendon i runs through module m.
    pub passes: Vec<Vec<bool>>,
    pub owner: Vec<usize>,
    pub connector_m: f64,
    /// The mount's turn from the backbone's frame (z along the straight backbone) to the
    /// stack's base frame, where positions are given: a hanging arm's is diag(1, −1, −1).
    pub mount: Matrix3<f64>,
}

impl Structure {
    pub fn of(arm: &Layout) -> Self {
        let modules = arm.modules().len();
        let tendons = arm.actuators().len();
        Self {
            slots: Slots { modules, tendons },
            passes: (0..tendons)
                .map(|i| (0..modules).map(|m| arm.passes(i, m)).collect())
                .collect(),
            owner: arm.actuators().iter().map(|a| a.module).collect(),
            connector_m: arm.connector_m,
            mount: match arm.mount {
                Mount::Hanging => Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)),
                Mount::Standing => Matrix3::identity(),
            },
        }
    }

    /// The parameters of `arm` as configured: its backbones (or, for a module without one,
    /// its tendons' mean middle length less the modules before), radii, angles, the tool as
    /// the marker on the axis, no offsets, equal stiffnesses, the base at the origin.
    pub fn nominal(&self, arm: &Layout) -> Vec<f64> {
        let s = self.slots;
        let mut theta = vec![0.0; s.count()];
        let mut before = 0.0;
        for (m, module) in arm.modules().iter().enumerate() {
            let length = module.backbone_m.unwrap_or_else(|| {
                let own = &arm.actuators()[module.actuators.clone()];
                let mean =
                    own.iter().map(|a| 0.5 * (a.min_m + a.max_m)).sum::<f64>() / own.len() as f64;
                mean - before
            });
            theta[s.length(m)] = length;
            before += length;
        }
        theta[s.axial_stiffness()] = AXIAL_STIFFNESS.ln();
        theta[s.tendon_stiffness()] = TENDON_STIFFNESS.ln();
        for (i, a) in arm.actuators().iter().enumerate() {
            theta[s.radius(i)] = a.radius_m;
            theta[s.angle(i)] = a.angle_rad;
        }
        theta[s.marker(2)] = arm.tool_m;
        theta
    }
}

/// The configured arm's stiffnesses relative to module 0's bend (per rad²): axial per m², a
/// tendon's per m². A stiff tendon against a bend of about a radian per few millimetres.
const AXIAL_STIFFNESS: f64 = 1e6;
const TENDON_STIFFNESS: f64 = 1e8;

/// The arm with parameters `theta`, ready to evaluate.
#[derive(Debug, Clone, PartialEq)]
pub struct Model<'a> {
    structure: &'a Structure,
    theta: &'a [f64],
    /// Row i: how tendon i's path shortens per unit of each variable (u_0x, u_0y, c_0, ...).
    routing: DMatrix<f64>,
    stiffness: DVector<f64>,
    tendon_stiffness: f64,
}

/// An arm's shape: each module's bend (2) and compression (1).
pub type Shape = DVector<f64>;

impl<'a> Model<'a> {
    pub fn new(structure: &'a Structure, theta: &'a [f64]) -> Self {
        let s = structure.slots;
        let vars = 3 * s.modules;
        let mut routing = DMatrix::zeros(s.tendons, vars);
        for i in 0..s.tendons {
            let beta = theta[s.angle(i)] + theta[s.rotation(structure.owner[i])];
            let r = theta[s.radius(i)];
            for m in 0..s.modules {
                if structure.passes[i][m] {
                    routing[(i, 3 * m)] = r * beta.cos();
                    routing[(i, 3 * m + 1)] = r * beta.sin();
                    routing[(i, 3 * m + 2)] = 1.0;
                }
            }
        }
        let mut stiffness = DVector::zeros(vars);
        for m in 0..s.modules {
            let k = if m == 0 {
                1.0
            } else {
                theta[s.bend_stiffness(m)].exp()
            };
            stiffness[3 * m] = k;
            stiffness[3 * m + 1] = k;
            stiffness[3 * m + 2] = theta[s.axial_stiffness()].exp();
        }
        Self {
            structure,
            theta,
            routing,
            stiffness,
            tendon_stiffness: theta[s.tendon_stiffness()].exp(),
        }
    }

    /// The shape the arm settles in with tendons pulled in by `pull_m`, from `start` (a shape
    /// near it, or zeros).
    pub fn settle(&self, pull_m: &[f64], start: &Shape) -> Shape {
        let s = self.structure.slots;
        let demand: DVector<f64> =
            DVector::from_fn(s.tendons, |i, _| pull_m[i] - self.theta[s.offset(i)]);
        let mut x = start.clone();
        let mut active = vec![false; s.tendons];
        for _ in 0..30 {
            let slack = &demand - &self.routing * &x;
            let now: Vec<bool> = slack.iter().map(|v| *v > 0.0).collect();
            if now == active && x != *start {
                break;
            }
            active = now;
            // Stationary point with this active set: (K + k_t Aᵀ A) x = k_t Aᵀ d over the taut.
            let mut h = DMatrix::from_diagonal(&self.stiffness);
            let mut g = DVector::zeros(x.len());
            for (i, taut) in active.iter().enumerate() {
                if *taut {
                    let row = self.routing.row(i);
                    h += self.tendon_stiffness * row.transpose() * row;
                    g += self.tendon_stiffness * demand[i] * row.transpose();
                }
            }
            let next = match h.cholesky() {
                Some(c) => c.solve(&g),
                None => return DVector::from_element(x.len(), f64::NAN),
            };
            let moved = (&next - &x).amax();
            x = next;
            if moved < 1e-13 {
                break;
            }
        }
        x
    }

    /// Where the marker is (m, the recording's frame) for the arm in `shape`.
    pub fn marker(&self, shape: &Shape) -> [f64; 3] {
        let s = self.structure.slots;
        let t = self.theta;
        let mut rotation = self.structure.mount
            * rot_z(t[s.base_rotation(2)])
            * rot_y(t[s.base_rotation(1)])
            * rot_x(t[s.base_rotation(0)]);
        let mut position = Vector3::new(
            t[s.base_position(0)],
            t[s.base_position(1)],
            t[s.base_position(2)],
        );
        for m in 0..s.modules {
            if m > 0 {
                position += rotation * Vector3::new(0.0, 0.0, self.structure.connector_m);
            }
            let (ux, uy) = (shape[3 * m], shape[3 * m + 1]);
            let length = t[s.length(m)] - shape[3 * m + 2];
            let bend = ux.hypot(uy);
            let phi = uy.atan2(ux);
            let (f, g) = sinc_terms(bend);
            let (sp, cp) = phi.sin_cos();
            position += rotation * (length * Vector3::new(cp * f, sp * f, g));
            rotation *= rot_z(phi) * rot_y(bend) * rot_z(-phi);
        }
        let p = position + rotation * Vector3::new(t[s.marker(0)], t[s.marker(1)], t[s.marker(2)]);
        [p.x, p.y, p.z]
    }

    /// The marker for pulls `pull_m`: the shape it settles in, then where that puts it.
    pub fn predict(&self, pull_m: &[f64]) -> [f64; 3] {
        let shape = self.settle(pull_m, &DVector::zeros(3 * self.structure.slots.modules));
        self.marker(&shape)
    }
}

/// (1 − cos θ)/θ and sin θ/θ, by series near 0.
fn sinc_terms(theta: f64) -> (f64, f64) {
    if theta.abs() < 1e-4 {
        let t2 = theta * theta;
        (theta / 2.0 - theta * t2 / 24.0, 1.0 - t2 / 6.0)
    } else {
        ((1.0 - theta.cos()) / theta, theta.sin() / theta)
    }
}

fn rot_x(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}
fn rot_y(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}
fn rot_z(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arm() -> softarm_arm::Layout {
        crate::test_arm()
    }

    #[test]
    fn a_straight_arm_stands_at_its_length() {
        let arm = arm();
        let s = Structure::of(&arm);
        let theta = s.nominal(&arm);
        let p = Model::new(&s, &theta).predict(&[0.0; 6]);
        assert!((p[2] - 0.21).abs() < 1e-12 && p[0].abs() < 1e-12, "{p:?}");
        // Every tendon slack: still straight.
        let p = Model::new(&s, &theta).predict(&[-0.005; 6]);
        assert!((p[2] - 0.21).abs() < 1e-12, "{p:?}");
    }

    #[test]
    fn a_pulled_tendon_bends_its_module_towards_it_and_the_others_go_slack() {
        let arm = arm();
        let s = Structure::of(&arm);
        let theta = s.nominal(&arm);
        let model = Model::new(&s, &theta);
        // Tendon 4 (module 2, at 0°) pulled 3 mm, the others let out.
        let pull = [-0.005, -0.005, -0.005, 0.003, -0.005, -0.005];
        let shape = model.settle(&pull, &DVector::zeros(6));
        // Module 1 bends towards 0° too (the tendon runs through it), module 2 as well.
        assert!(shape[0] > 0.1 && shape[3] > 0.1, "{shape}");
        assert!(shape[1].abs() < 1e-9 && shape[4].abs() < 1e-9, "{shape}");
        // Its path shortened by (almost) its pull: a stiff tendon.
        let s4 = 0.0045 * (shape[0] + shape[3]) + shape[2] + shape[5];
        assert!((s4 - 0.003).abs() < 2e-5, "{s4}");
        let p = model.marker(&shape);
        assert!(p[0] > 0.02 && p[2] < 0.21, "{p:?}");
    }

    #[test]
    fn a_hanging_arm_points_down_in_the_stacks_frame() {
        let hanging = crate::test_arm_mounted("hanging");
        let s = Structure::of(&hanging);
        let theta = s.nominal(&hanging);
        let model = Model::new(&s, &theta);
        assert!((model.predict(&[0.0; 6])[2] + 0.21).abs() < 1e-12);
        // Pulled towards +x, it swings to +x as it does standing: diag(1, −1, −1) keeps x.
        let p = model.predict(&[0.003, -0.005, -0.005, 0.0, -0.005, -0.005]);
        assert!(p[0] > 0.01, "{p:?}");
    }

    #[test]
    fn equal_pulls_compress_and_do_not_bend() {
        let arm = arm();
        let s = Structure::of(&arm);
        let theta = s.nominal(&arm);
        let p = Model::new(&s, &theta).predict(&[0.001, 0.001, 0.001, 0.0, 0.0, 0.0]);
        assert!(p[0].abs() < 1e-12 && p[1].abs() < 1e-12, "{p:?}");
        assert!(p[2] < 0.21 - 1e-4, "{p:?}");
    }
}
