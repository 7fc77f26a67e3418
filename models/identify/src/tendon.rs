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
use softarm_kinematics::arc::{Arc, module_centroid, module_pose, rot_x, rot_y, rot_z};

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
    /// Module 0's weight against gravity, as a vector in the backbone's frame at the base (in
    /// units of module 0's bend stiffness per metre: its mass times g over that stiffness,
    /// pointing up). A vector, not a size: where the arm's base points in the world (standing,
    /// hanging, on its side) the recording does not say.
    pub fn gravity_vector(&self, k: usize) -> usize {
        3 * self.modules + 11 + 3 * self.tendons + k
    }
    /// Module m's mass relative to module 0's, spread evenly along its arc (m ≥ 1; module 0's
    /// is the unit).
    pub fn weight(&self, m: usize) -> usize {
        3 * self.modules + 13 + 3 * self.tendons + m
    }
    /// The payload's mass at the marker (the marker, the last disc), relative to module 0's.
    pub fn payload(&self) -> usize {
        4 * self.modules + 13 + 3 * self.tendons
    }
    /// The slots of masses (every module's but the first, which is the unit, and the
    /// payload's): none is negative.
    pub fn masses(&self) -> std::ops::RangeInclusive<usize> {
        self.weight(1)..=self.payload()
    }
    /// The slots of gravity's terms: its vector, the modules' masses and the payload's.
    pub fn gravity(&self) -> std::ops::Range<usize> {
        self.gravity_vector(0)..self.payload() + 1
    }
    pub fn count(&self) -> usize {
        4 * self.modules + 14 + 3 * self.tendons
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
        // Modules alike but for their lengths, a light payload; no gravity until calibrated.
        for m in 1..s.modules {
            theta[s.weight(m)] = theta[s.length(m)] / theta[s.length(0)];
        }
        theta[s.payload()] = NOMINAL_PAYLOAD;
        theta
    }
}

/// The configured arm's stiffnesses relative to module 0's bend (per rad²): axial per m², a
/// tendon's per m². A stiff tendon against a bend of about a radian per few millimetres.
const AXIAL_STIFFNESS: f64 = 1e6;
const TENDON_STIFFNESS: f64 = 1e8;

/// A marker and last disc of a fifth of module 0's mass.
const NOMINAL_PAYLOAD: f64 = 0.2;

/// The arm with parameters `theta`, ready to evaluate.
#[derive(Debug, Clone, PartialEq)]
pub struct Model<'a> {
    structure: &'a Structure,
    theta: &'a [f64],
    /// Row i: how tendon i's path shortens per unit of each variable (u_0x, u_0y, c_0, ...).
    routing: DMatrix<f64>,
    stiffness: DVector<f64>,
    tendon_stiffness: f64,
    /// Module 0's weight against gravity in the backbone's frame at the base
    /// ([`Slots::gravity_vector`]).
    up: Vector3<f64>,
    /// Each module's mass relative to module 0's, then the payload's.
    masses: Vec<f64>,
    /// Whether gravity is on: else the arm settles exactly as one without it.
    heavy: bool,
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
        let up = Vector3::from_fn(|k, _| theta[s.gravity_vector(k)]);
        let masses = (0..=s.modules)
            .map(|m| match m {
                0 => 1.0,
                m if m == s.modules => theta[s.payload()],
                m => theta[s.weight(m)],
            })
            .collect();
        Self {
            structure,
            theta,
            routing,
            stiffness,
            tendon_stiffness: theta[s.tendon_stiffness()].exp(),
            up,
            masses,
            heavy: up != Vector3::zeros(),
        }
    }

    /// The shape the arm settles in with tendons pulled in by `pull_m`, from `start` (a shape
    /// near it, or zeros).
    ///
    /// Without gravity the energy is quadratic on each active set: Newton's step is exact.
    /// With it, Newton's steps on gravity's curvature where the arm is, until the shape stops
    /// moving.
    pub fn settle(&self, pull_m: &[f64], start: &Shape) -> Shape {
        self.settle_on(pull_m, start, None)
    }

    /// [`Model::settle`] on gravity's curvature `curvature` (of an arm near this one, in a
    /// shape near `start`: what a calibration's small changes of the parameters share), or
    /// on the curvature where the arm is at each step (`None`).
    pub fn settle_on(
        &self,
        pull_m: &[f64],
        start: &Shape,
        curvature: Option<&DMatrix<f64>>,
    ) -> Shape {
        let s = self.structure.slots;
        let demand: DVector<f64> =
            DVector::from_fn(s.tendons, |i, _| pull_m[i] - self.theta[s.offset(i)]);
        if self.heavy {
            return self.settle_heavy(&demand, start, curvature);
        }
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
            let (h, g) = self.elastic(&active, &demand);
            let Some(next) = h.cholesky().map(|c| c.solve(&g)) else {
                return DVector::from_element(x.len(), f64::NAN);
            };
            let moved = (&next - &x).amax();
            x = next;
            if moved < 1e-13 {
                break;
            }
        }
        x
    }

    /// The elastic energy's Hessian on the active set `active` of taut tendons, and its pull:
    /// (K + k_t Aᵀ A, k_t Aᵀ d) over the taut.
    fn elastic(&self, active: &[bool], demand: &DVector<f64>) -> (DMatrix<f64>, DVector<f64>) {
        let mut h = DMatrix::from_diagonal(&self.stiffness);
        let mut g = DVector::zeros(h.nrows());
        for (i, taut) in active.iter().enumerate() {
            if *taut {
                let row = self.routing.row(i);
                h += self.tendon_stiffness * row.transpose() * row;
                g += self.tendon_stiffness * demand[i] * row.transpose();
            }
        }
        (h, g)
    }

    /// [`Model::settle_on`] with gravity: Newton's steps on E + V_g, (H + ∇²V_g) δ = g − H x −
    /// ∇V_g. On `curvature` given (the chord method), the factor kept while the active set
    /// stands; else on the curvature where the arm is at each step (a shape far from `start`,
    /// where the first one is wrong). On H alone where H + ∇²V_g is not positive.
    fn settle_heavy(
        &self,
        demand: &DVector<f64>,
        start: &Shape,
        curvature: Option<&DMatrix<f64>>,
    ) -> Shape {
        let mut x = start.clone();
        let mut active = Vec::new();
        let mut system = None;
        for _ in 0..60 {
            let slack = demand - &self.routing * &x;
            let now: Vec<bool> = slack.iter().map(|v| *v > 0.0).collect();
            if now != active || system.is_none() || curvature.is_none() {
                let (h, g) = self.elastic(&now, demand);
                let here;
                let c = match curvature {
                    Some(c) => c,
                    None => {
                        here = self.gravity_curvature(&x);
                        &here
                    }
                };
                let factor = (&h + c).cholesky().or_else(|| h.clone().cholesky());
                let Some(factor) = factor else {
                    return DVector::from_element(x.len(), f64::NAN);
                };
                system = Some((h, g, factor));
                active = now;
            }
            let Some((h, g, factor)) = &system else {
                break;
            };
            let step = factor.solve(&(g - h * &x - self.gravity_gradient(&x)));
            x += &step;
            // A ten-thousandth of the smallest change a calibration's Jacobian makes.
            if step.amax() < 1e-11 {
                break;
            }
        }
        x
    }

    /// Whether gravity is on.
    pub fn is_heavy(&self) -> bool {
        self.heavy
    }

    /// ∇² of [`Model::gravity_energy`] at `shape`, by central differences of its gradient.
    pub fn gravity_curvature(&self, shape: &Shape) -> DMatrix<f64> {
        const STEP: f64 = 1e-6;
        let n = shape.len();
        let mut c = DMatrix::zeros(n, n);
        let mut moved = shape.clone();
        for k in 0..n {
            moved[k] = shape[k] + STEP;
            let up = self.gravity_gradient(&moved);
            moved[k] = shape[k] - STEP;
            let down = self.gravity_gradient(&moved);
            moved[k] = shape[k];
            c.set_column(k, &((up - down) / (2.0 * STEP)));
        }
        (&c + c.transpose()) * 0.5
    }

    /// The arm's potential energy in gravity for `shape` (units of module 0's bend stiffness):
    /// each module's weight at its arc's centroid, the payload at the marker.
    pub fn gravity_energy(&self, shape: &Shape) -> f64 {
        let mut height = 0.0;
        let marker = self.walk(shape, Matrix3::identity(), Vector3::zeros(), |m, c| {
            height += self.masses[m] * self.up.dot(&c);
        });
        height + self.masses[self.structure.slots.modules] * self.up.dot(&marker)
    }

    /// ∇ of [`Model::gravity_energy`] over the shape's variables, by virtual work: a change of
    /// module m's shape moves its own centroid, and everything beyond its end rigidly with the
    /// end's frame (its position, and its turn about the end), so each module's part needs the
    /// weight beyond it and that weight's first moment alone. Exact, in one walk out and back.
    pub fn gravity_gradient(&self, shape: &Shape) -> DVector<f64> {
        let s = self.structure.slots;
        let t = self.theta;
        let mut frames = Vec::with_capacity(s.modules);
        let (mut rotation, mut position) = (Matrix3::identity(), Vector3::zeros());
        for m in 0..s.modules {
            if m > 0 {
                position += rotation * Vector3::new(0.0, 0.0, self.structure.connector_m);
            }
            let arc = Slopes::of(
                shape[3 * m],
                shape[3 * m + 1],
                t[s.length(m)] - shape[3 * m + 2],
            );
            let centroid = position + rotation * arc.centroid;
            let end = position + rotation * arc.end;
            frames.push((rotation, centroid, end, arc));
            rotation *= arc.turn;
            position = end;
        }
        let marker =
            position + rotation * Vector3::new(t[s.marker(0)], t[s.marker(1)], t[s.marker(2)]);
        // Walking back: the weight beyond module m's end, and its first moment.
        let mut beyond = self.masses[s.modules];
        let mut moment = beyond * marker;
        let mut gradient = DVector::zeros(3 * s.modules);
        for m in (0..s.modules).rev() {
            let (rotation, centroid, end, arc) = &frames[m];
            let up = rotation.transpose() * self.up;
            let lever = rotation.transpose() * (moment - beyond * end).cross(&self.up);
            let own = self.masses[m];
            for k in 0..3 {
                gradient[3 * m + k] = own * up.dot(&arc.d_centroid[k])
                    + beyond * up.dot(&arc.d_end[k])
                    + arc.d_turn[k].dot(&lever);
            }
            beyond += own;
            moment += own * centroid;
        }
        gradient
    }

    /// Where the marker is (m, the recording's frame) for the arm in `shape`.
    pub fn marker(&self, shape: &Shape) -> [f64; 3] {
        let s = self.structure.slots;
        let t = self.theta;
        let position = Vector3::new(
            t[s.base_position(0)],
            t[s.base_position(1)],
            t[s.base_position(2)],
        );
        let rotation = base_rotation(self.structure, t);
        let p = self.walk(shape, rotation, position, |_, _| {});
        [p.x, p.y, p.z]
    }

    /// The arm in `shape` from a base at `rotation`, `position`: `centroid` is told each
    /// module's arc's centroid; the marker is returned.
    fn walk(
        &self,
        shape: &Shape,
        mut rotation: Matrix3<f64>,
        mut position: Vector3<f64>,
        mut centroid: impl FnMut(usize, Vector3<f64>),
    ) -> Vector3<f64> {
        let s = self.structure.slots;
        let t = self.theta;
        for m in 0..s.modules {
            if m > 0 {
                position += rotation * Vector3::new(0.0, 0.0, self.structure.connector_m);
            }
            let (ux, uy) = (shape[3 * m], shape[3 * m + 1]);
            let length = t[s.length(m)] - shape[3 * m + 2];
            let arc = Arc {
                length,
                theta: ux.hypot(uy),
                phi: uy.atan2(ux),
            };
            centroid(m, position + rotation * module_centroid(&arc));
            let module = module_pose(&arc);
            position += rotation * module.position;
            rotation *= module.rotation;
        }
        position + rotation * Vector3::new(t[s.marker(0)], t[s.marker(1)], t[s.marker(2)])
    }

    /// The marker for pulls `pull_m`: the shape it settles in, then where that puts it.
    pub fn predict(&self, pull_m: &[f64]) -> [f64; 3] {
        let shape = self.settle(pull_m, &DVector::zeros(3 * self.structure.slots.modules));
        self.marker(&shape)
    }
}

/// One module's arc in its base's frame ([`module_pose`], [`module_centroid`]) for bend
/// (ux, uy) and length L, with its derivatives by (ux, uy, compression): what settling the arm
/// needs. In Cartesian bends every term is smooth
/// through the straight arc: the end is L (ux F, uy F, sin θ/θ), the centroid L (ux A, uy A,
/// F), with F = (1 − cos θ)/θ² and A = (1 − sin θ/θ)/θ²; the turn is the rotation vector
/// (−uy, ux, 0), whose change turns the end by its left Jacobian.
#[derive(Debug, Clone, Copy)]
struct Slopes {
    end: Vector3<f64>,
    centroid: Vector3<f64>,
    turn: Matrix3<f64>,
    d_end: [Vector3<f64>; 3],
    d_centroid: [Vector3<f64>; 3],
    /// How the end turns (an angular change, in the base's frame) per unit of each.
    d_turn: [Vector3<f64>; 3],
}

impl Slopes {
    fn of(ux: f64, uy: f64, length: f64) -> Self {
        let t2 = ux * ux + uy * uy;
        let theta = t2.sqrt();
        // F, A, sin θ/θ and each one's derivative over θ, divided by θ.
        let (f, a, g, f1, a1, g1) = if theta < 1e-3 {
            (
                0.5 - t2 / 24.0,
                1.0 / 6.0 - t2 / 120.0,
                1.0 - t2 / 6.0,
                -1.0 / 12.0 + t2 / 180.0,
                -1.0 / 60.0 + t2 / 1260.0,
                -1.0 / 3.0 + t2 / 30.0,
            )
        } else {
            let (sn, cs) = theta.sin_cos();
            let f = (1.0 - cs) / t2;
            let g = sn / theta;
            let a = (1.0 - g) / t2;
            let dg = (theta * cs - sn) / t2;
            let df = sn / t2 - 2.0 * f / theta;
            let da = -dg / t2 - 2.0 * a / theta;
            (f, a, g, df / theta, da / theta, dg / theta)
        };
        let v = Vector3::new(-uy, ux, 0.0);
        let vx = v.cross_matrix();
        let left = Matrix3::identity() + f * vx + a * vx * vx;
        let turn = Matrix3::identity() + g * vx + f * vx * vx;
        Self {
            end: length * Vector3::new(ux * f, uy * f, g),
            centroid: length * Vector3::new(ux * a, uy * a, f),
            turn,
            d_end: [
                length * Vector3::new(f + ux * ux * f1, ux * uy * f1, ux * g1),
                length * Vector3::new(ux * uy * f1, f + uy * uy * f1, uy * g1),
                -Vector3::new(ux * f, uy * f, g),
            ],
            d_centroid: [
                length * Vector3::new(a + ux * ux * a1, ux * uy * a1, ux * f1),
                length * Vector3::new(ux * uy * a1, a + uy * uy * a1, uy * f1),
                -Vector3::new(ux * a, uy * a, f),
            ],
            d_turn: [
                left * Vector3::y(),
                -(left * Vector3::x()),
                Vector3::zeros(),
            ],
        }
    }
}

/// The mount and the base's tilt and turn: from the backbone's frame at the base to the
/// stack's base frame.
fn base_rotation(structure: &Structure, theta: &[f64]) -> Matrix3<f64> {
    let s = structure.slots;
    structure.mount
        * rot_z(theta[s.base_rotation(2)])
        * rot_y(theta[s.base_rotation(1)])
        * rot_x(theta[s.base_rotation(0)])
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

    #[test]
    fn gravitys_force_is_the_gradient_of_its_energy() {
        let arm = arm();
        let structure = Structure::of(&arm);
        let s = structure.slots;
        let mut theta = structure.nominal(&arm);
        theta[s.gravity_vector(0)] = -0.6;
        theta[s.gravity_vector(1)] = 0.4;
        theta[s.gravity_vector(2)] = 2.0;
        theta[s.weight(1)] = 0.7;
        theta[s.payload()] = 0.3;
        theta[s.marker(0)] = 0.01;
        theta[s.base_rotation(1)] = 0.1;
        let model = Model::new(&structure, &theta);
        for shape in [
            DVector::from_vec(vec![0.3, -0.2, 0.001, -0.5, 0.4, 0.002]),
            DVector::from_vec(vec![1e-5, 0.0, 0.0, 0.0, 2e-4, 0.0]),
        ] {
            let exact = model.gravity_gradient(&shape);
            for k in 0..6 {
                let h = 1e-6;
                let (mut up, mut down) = (shape.clone(), shape.clone());
                up[k] += h;
                down[k] -= h;
                let fd = (model.gravity_energy(&up) - model.gravity_energy(&down)) / (2.0 * h);
                assert!(
                    (exact[k] - fd).abs() < 1e-7,
                    "{k}: {} against {fd}",
                    exact[k]
                );
            }
        }
    }

    #[test]
    fn a_heavy_arm_bent_sags_further_and_a_straight_one_stands() {
        let arm = arm();
        let structure = Structure::of(&arm);
        let s = structure.slots;
        let light = structure.nominal(&arm);
        let mut heavy = light.clone();
        heavy[s.gravity_vector(2)] = 3.0;
        heavy[s.payload()] = 0.3;
        // Straight and untensioned it stands where it did, but for its weight pressing it
        // together along its axis.
        let p = Model::new(&structure, &heavy).predict(&[-0.001; 6]);
        assert!(p[2] < 0.21 && p[2] > 0.2099 && p[0].abs() < 1e-12, "{p:?}");
        // Bent towards +x by module 1's tendon at 0°, the others slack: further out and down.
        let pull = [0.004, -0.005, -0.005, -0.005, -0.005, -0.005];
        let a = Model::new(&structure, &light).predict(&pull);
        let b = Model::new(&structure, &heavy).predict(&pull);
        assert!(b[0] > a[0] + 1e-3 && b[2] < a[2], "{a:?} {b:?}");
    }
}
