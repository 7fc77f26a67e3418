//! Actuator lengths to module arcs for any arm: k actuators at any radii and angles in each
//! module, tendons that end in their module or run through every module before it, chambers,
//! soft modules and fixed backbones. Pure math, no heap: what the sim's step and the learner
//! call every period.
//!
//! An actuator's length is the sum, over the modules it runs through, of l_m − r cos(β − φ_m) θ_m
//! (`softarm_arm`'s conventions). In u_m = θ_m cos φ_m, v_m = θ_m sin φ_m and, for a soft
//! module, its length l_m, that is linear: the arcs are the least-squares solution of one
//! linear system, exact when it is square (three actuators a module, the paper's arm), and the
//! best compromise when a module has more actuators than it has freedoms (a fourth tendon, a
//! chamber beside tendons) — what all of them together give.
//!
//! It is kinematics: every actuator's length is held. A tendon's tension bending the modules
//! it runs through where their own tendons are slack is statics, which this does not model.

use softarm_arm::{Layout, MAX_ACTUATORS, MAX_MODULES};

use crate::arc::Arc;

/// Most unknowns: three a module.
const MAX_UNKNOWNS: usize = 3 * MAX_MODULES;

/// What the arc fit needs of a layout, in fixed arrays: `Copy`, built without the heap, so a
/// geometry that changes while the arm runs (a drifting radius) costs no allocation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Routes {
    actuators: usize,
    modules: usize,
    radius_m: [f64; MAX_ACTUATORS],
    angle_rad: [f64; MAX_ACTUATORS],
    /// Bit m: the actuator runs through module m.
    passes: [u8; MAX_ACTUATORS],
    /// A module's fixed backbone length (m); `None`: its length is an unknown.
    backbone_m: [Option<f64>; MAX_MODULES],
}

const _: () = assert!(MAX_MODULES <= 8, "`passes` holds a module a bit");

/// The fit has no unique answer: the actuators cannot tell some module's shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the actuators do not determine module {module}'s shape (a singular fit)")]
pub struct Undetermined {
    pub module: usize,
}

impl Routes {
    /// The routes of `layout`.
    pub fn of(layout: &Layout) -> Self {
        let mut r = Self::empty(layout.actuators().len(), layout.modules().len());
        for (i, a) in layout.actuators().iter().enumerate() {
            r.radius_m[i] = a.radius_m;
            r.angle_rad[i] = a.angle_rad;
            r.passes[i] = (0..r.modules)
                .filter(|&m| layout.passes(i, m))
                .fold(0, |bits, m| bits | 1 << m);
        }
        for (m, module) in layout.modules().iter().enumerate() {
            r.backbone_m[m] = module.backbone_m;
        }
        r
    }

    /// `actuators` actuators on `modules` modules, none placed yet.
    pub fn empty(actuators: usize, modules: usize) -> Self {
        assert!(actuators <= MAX_ACTUATORS && (1..=MAX_MODULES).contains(&modules));
        Self {
            actuators,
            modules,
            radius_m: [0.0; MAX_ACTUATORS],
            angle_rad: [0.0; MAX_ACTUATORS],
            passes: [0; MAX_ACTUATORS],
            backbone_m: [None; MAX_MODULES],
        }
    }

    /// Places actuator `i`: its radius and angle (module rotation included), running through
    /// the modules whose bits `passes` sets.
    pub fn place(&mut self, i: usize, radius_m: f64, angle_rad: f64, passes: u8) {
        self.radius_m[i] = radius_m;
        self.angle_rad[i] = angle_rad;
        self.passes[i] = passes;
    }

    pub fn actuators(&self) -> usize {
        self.actuators
    }

    pub fn modules(&self) -> usize {
        self.modules
    }

    /// The module actuator `i` belongs to: the farthest from the base it runs through (its
    /// own; with coupled routing a tendon also runs through the ones before).
    pub fn owner(&self, i: usize) -> usize {
        7 - self.passes[i].leading_zeros() as usize
    }

    /// Turns actuator `i` by `d_rad` about its module's axis.
    pub fn turn(&mut self, i: usize, d_rad: f64) {
        self.angle_rad[i] += d_rad;
    }

    /// Moves every tendon `dr_m` further from the backbone; a chamber, on the axis, stays.
    pub fn widen(&mut self, dr_m: f64) {
        for r in self.radius_m[..self.actuators]
            .iter_mut()
            .filter(|r| **r > 0.0)
        {
            *r += dr_m;
        }
    }

    fn runs_through(&self, i: usize, m: usize) -> bool {
        self.passes[i] & (1 << m) != 0
    }

    /// The unknowns' columns: module m's length (soft modules only), u_m, v_m.
    fn columns(&self) -> ([Option<usize>; MAX_MODULES], [usize; MAX_MODULES], usize) {
        let (mut length, mut u, mut k) = ([None; MAX_MODULES], [0; MAX_MODULES], 0);
        for m in 0..self.modules {
            if self.backbone_m[m].is_none() {
                length[m] = Some(k);
                k += 1;
            }
            u[m] = k;
            k += 2;
        }
        (length, u, k)
    }

    /// Module arcs for actuator lengths `lengths` (m, one per actuator): the least-squares fit.
    /// Entries of the result past [`Routes::modules`] are straight and zero-length.
    pub fn arcs(&self, lengths: &[f64]) -> Result<[Arc; MAX_MODULES], Undetermined> {
        debug_assert_eq!(lengths.len(), self.actuators);
        let (col_length, col_u, k) = self.columns();
        // The normal equations AᵀA x = Aᵀb, built row by row.
        let mut ata = [[0.0; MAX_UNKNOWNS]; MAX_UNKNOWNS];
        let mut atb = [0.0; MAX_UNKNOWNS];
        for i in 0..self.actuators {
            let mut row = [0.0; MAX_UNKNOWNS];
            let mut b = lengths[i];
            let (s, c) = self.angle_rad[i].sin_cos();
            for m in (0..self.modules).filter(|&m| self.runs_through(i, m)) {
                match (col_length[m], self.backbone_m[m]) {
                    (Some(col), _) => row[col] = 1.0,
                    (None, Some(fixed)) => b -= fixed,
                    (None, None) => unreachable!("a module without a length column is fixed"),
                }
                row[col_u[m]] = -self.radius_m[i] * c;
                row[col_u[m] + 1] = -self.radius_m[i] * s;
            }
            for p in 0..k {
                atb[p] += row[p] * b;
                for q in 0..k {
                    ata[p][q] += row[p] * row[q];
                }
            }
        }
        let x = cholesky_solve(&mut ata, &mut atb, k).map_err(|col| Undetermined {
            module: (0..self.modules)
                .rfind(|&m| col_length[m].unwrap_or(col_u[m]) <= col)
                .unwrap_or(0),
        })?;
        let mut arcs = [Arc {
            length: 0.0,
            theta: 0.0,
            phi: 0.0,
        }; MAX_MODULES];
        for m in 0..self.modules {
            let (u, v) = (x[col_u[m]], x[col_u[m] + 1]);
            let theta = u.hypot(v);
            arcs[m] = Arc {
                length: col_length[m].map_or_else(|| self.backbone_m[m].unwrap_or(0.0), |c| x[c]),
                theta,
                phi: if theta == 0.0 { 0.0 } else { v.atan2(u) },
            };
        }
        Ok(arcs)
    }

    /// The actuator lengths (m) that module arcs `arcs` give, into `lengths` (one per actuator):
    /// what [`Routes::arcs`] inverts.
    pub fn lengths(&self, arcs: &[Arc], lengths: &mut [f64]) {
        for (i, l) in lengths.iter_mut().enumerate().take(self.actuators) {
            *l = (0..self.modules)
                .filter(|&m| self.runs_through(i, m))
                .map(|m| {
                    let a = &arcs[m];
                    a.length - self.radius_m[i] * a.theta * (self.angle_rad[i] - a.phi).cos()
                })
                .sum();
        }
    }
}

/// Solves the symmetric positive definite `k`×`k` system `a x = b` in place (Cholesky); the
/// column whose pivot vanished when it is singular.
fn cholesky_solve(
    a: &mut [[f64; MAX_UNKNOWNS]; MAX_UNKNOWNS],
    b: &mut [f64; MAX_UNKNOWNS],
    k: usize,
) -> Result<[f64; MAX_UNKNOWNS], usize> {
    let scale = (0..k).map(|i| a[i][i]).fold(0.0, f64::max);
    for j in 0..k {
        let mut d = a[j][j];
        for p in 0..j {
            d -= a[j][p] * a[j][p];
        }
        // Not `d <= ..`: a NaN pivot is singular too.
        if d.is_nan() || d <= 1e-12 * scale {
            return Err(j);
        }
        let d = d.sqrt();
        a[j][j] = d;
        for i in j + 1..k {
            let mut s = a[i][j];
            for p in 0..j {
                s -= a[i][p] * a[j][p];
            }
            a[i][j] = s / d;
        }
    }
    // L y = b, then Lᵀ x = y.
    for i in 0..k {
        let mut s = b[i];
        for p in 0..i {
            s -= a[i][p] * b[p];
        }
        b[i] = s / a[i][i];
    }
    for i in (0..k).rev() {
        let mut s = b[i];
        for p in i + 1..k {
            s -= a[p][i] * b[p];
        }
        b[i] = s / a[i][i];
    }
    Ok(*b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};
    use softarm_arm::Description;

    fn layout(text: &str) -> Layout {
        Layout::new(&toml::from_str::<Description>(text).unwrap()).unwrap()
    }

    const PAPER: &str = include_str!("../../../contract/arm/testdata/paper.toml");
    const TDCR: &str = include_str!("../../../contract/arm/testdata/tdcr.toml");
    const HYBRID: &str = include_str!("../../../contract/arm/testdata/hybrid.toml");

    fn random_arcs(rng: &mut StdRng, routes: &Routes) -> [Arc; MAX_MODULES] {
        std::array::from_fn(|m| Arc {
            length: routes.backbone_m[m].unwrap_or_else(|| rng.random_range(0.19..0.25)),
            theta: rng.random_range(0.0..1.5),
            phi: rng.random_range(-3.1..3.1),
        })
    }

    /// On three actuators a module the fit is the closed form: l = the mean, and the bend
    /// from the differences (the paper's arm, whose PCC reference values the sim matches).
    #[test]
    fn three_tendons_at_120_degrees_give_the_closed_form() {
        let routes = Routes::of(&layout(PAPER));
        let mut rng = StdRng::seed_from_u64(1);
        for _ in 0..500 {
            let l: [f64; 6] = std::array::from_fn(|_| rng.random_range(0.19..0.25));
            let arcs = routes.arcs(&l).unwrap();
            for m in 0..2 {
                let d = 0.025;
                let [l0, l1, l2] = [l[3 * m], l[3 * m + 1], l[3 * m + 2]];
                let bx = (l1 + l2 - 2.0 * l0) / (3.0 * d);
                let by = (l2 - l1) / (3f64.sqrt() * d);
                let psi = (60.0 * m as f64).to_radians();
                let want_phi = by.atan2(bx) + psi;
                assert!((arcs[m].length - (l0 + l1 + l2) / 3.0).abs() < 1e-13);
                assert!((arcs[m].theta - bx.hypot(by)).abs() < 1e-9);
                let dphi = (arcs[m].phi - want_phi).rem_euclid(std::f64::consts::TAU);
                assert!(dphi.min(std::f64::consts::TAU - dphi) < 1e-9, "{dphi}");
            }
        }
    }

    /// Lengths made by arcs give the arcs back, on soft, fixed-backbone, coupled and mixed
    /// arms.
    #[test]
    fn the_fit_inverts_the_lengths_arcs_give() {
        let mut rng = StdRng::seed_from_u64(2);
        for text in [PAPER, TDCR, HYBRID] {
            let routes = Routes::of(&layout(text));
            let n = routes.actuators();
            for _ in 0..300 {
                let arcs = random_arcs(&mut rng, &routes);
                let mut l = [0.0; MAX_ACTUATORS];
                routes.lengths(&arcs, &mut l[..n]);
                let back = routes.arcs(&l[..n]).unwrap();
                for m in 0..routes.modules() {
                    let (a, b) = (&arcs[m], &back[m]);
                    assert!((a.length - b.length).abs() < 1e-12, "{text}");
                    let (ua, va) = (a.theta * a.phi.cos(), a.theta * a.phi.sin());
                    let (ub, vb) = (b.theta * b.phi.cos(), b.theta * b.phi.sin());
                    assert!((ua - ub).abs() < 1e-9 && (va - vb).abs() < 1e-9, "{text}");
                }
            }
        }
    }

    /// With coupled routing a distal tendon's length runs through the proximal modules: bending
    /// the base module by its own tendons while every distal tendon is held bends the next
    /// module back the other way (which gives the third module's tendons their path back, so
    /// it stays straight). With independent routing the others stay straight.
    #[test]
    fn coupled_tendons_tie_the_distal_modules_to_the_proximal_bend() {
        let coupled = Routes::of(&layout(TDCR));
        let independent = Routes::of(&layout(&TDCR.replace("\"coupled\"", "\"independent\"")));
        for (routes, coupled) in [(coupled, true), (independent, false)] {
            let straight = std::array::from_fn::<_, MAX_MODULES, _>(|m| Arc {
                length: routes.backbone_m[m].unwrap_or(0.0),
                theta: 0.0,
                phi: 0.0,
            });
            let mut l = [0.0; 9];
            routes.lengths(&straight, &mut l);
            // Module 0 bent by 0.5 rad towards its first tendon, the others held.
            let mut bent = straight;
            bent[0].theta = 0.5;
            let mut own = [0.0; 9];
            routes.lengths(&bent, &mut own);
            l[..3].copy_from_slice(&own[..3]);
            let arcs = routes.arcs(&l).unwrap();
            assert!((arcs[0].theta - 0.5).abs() < 0.2, "{:?}", arcs[0]);
            let back = arcs[1].theta > 0.1 && (arcs[1].phi - arcs[0].phi).cos() < -0.9;
            assert_eq!(back, coupled, "{:?}", arcs[1]);
            assert!(arcs[2].theta < 1e-9, "{:?}", arcs[2]);
        }
    }

    /// Two tendons cannot tell a soft module's bend from its length: no fit, said for which
    /// module. A chamber on the axis beside three tendons is one equation more, fitted.
    #[test]
    fn a_module_its_actuators_cannot_tell_is_undetermined() {
        let mut routes = Routes::empty(5, 2);
        for i in 0..3 {
            routes.place(i, 0.02, i as f64 * 2.1, 0b01);
        }
        routes.place(3, 0.02, 0.0, 0b10);
        routes.place(4, 0.02, 3.0, 0b10);
        assert_eq!(routes.arcs(&[0.2; 5]), Err(Undetermined { module: 1 }));
        let mut routes = Routes::empty(4, 1);
        for i in 0..3 {
            routes.place(i, 0.02, i as f64 * 2.1, 0b1);
        }
        routes.place(3, 0.0, 0.0, 0b1);
        let arcs = routes.arcs(&[0.2, 0.2, 0.2, 0.24]).unwrap();
        assert!(
            arcs[0].length > 0.2 && arcs[0].length < 0.24,
            "{:?}",
            arcs[0]
        );
    }
}
