//! Radial-basis-function approximators. Pure math.
//!
//! - [`Lattice`]: normalised Gaussian RBFs on a regular lattice over a box, any dimension,
//!   evaluated on the `span` centres nearest to the input per axis only; [`LinearRbf`] keeps its
//!   weights in a hash map, so a 6-D lattice over the whole workspace (10⁸ centres) costs memory
//!   only where the input has been.
//! - [`RbfNetwork`]: the forward model actuation(N) → position(3), Gaussian centres picked from
//!   the data plus an affine part, output weights by ridge least squares.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use serde::{Deserialize, Serialize};

use softarm_sections::forward_model::NetworkConfig;
pub use softarm_sections::learner::MAX_SPAN;
use softarm_space::Position;

/// Largest lattice dimension.
pub const MAX_DIM: usize = 8;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RbfError {
    #[error("lattice: {0}")]
    Lattice(String),
    #[error("forward model: {0}")]
    Network(String),
}

/// A regular lattice of Gaussian centres over a box.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Lattice {
    lower: Vec<f64>,
    spacing: Vec<f64>,
    counts: Vec<u64>,
    /// Standard deviation of each Gaussian, in cells.
    width: f64,
    /// Centres evaluated per axis: the `span` nearest to the input (2 brackets it, 3 is the
    /// nearest and its two neighbours).
    span: usize,
}

impl Lattice {
    /// Centres every `spacing[d]` from `lower[d]` to at least `upper[d]`, Gaussians of σ =
    /// `width` cells, the `span` nearest centres per axis evaluated.
    pub fn new(
        lower: &[f64],
        upper: &[f64],
        spacing: &[f64],
        width: f64,
        span: usize,
    ) -> Result<Self, RbfError> {
        let bad = |s: String| Err(RbfError::Lattice(s));
        let dim = lower.len();
        if dim == 0 || dim > MAX_DIM || upper.len() != dim || spacing.len() != dim {
            return bad(format!(
                "lower, upper and spacing need the same 1..={MAX_DIM} dimensions, got {}, {}, {}",
                lower.len(),
                upper.len(),
                spacing.len()
            ));
        }
        let mut counts = Vec::with_capacity(dim);
        for d in 0..dim {
            if !(lower[d].is_finite() && upper[d].is_finite() && upper[d] > lower[d]) {
                return bad(format!(
                    "axis {d}: the box [{}, {}] is empty",
                    lower[d], upper[d]
                ));
            }
            if !(spacing[d].is_finite() && spacing[d] > 0.0) {
                return bad(format!("axis {d}: spacing must be > 0, got {}", spacing[d]));
            }
            counts.push(((upper[d] - lower[d]) / spacing[d]).ceil() as u64 + 1);
        }
        if counts
            .iter()
            .try_fold(1u64, |a, &c| a.checked_mul(c))
            .is_none()
        {
            return bad("more centres than a 64-bit index can count".into());
        }
        if !(width.is_finite() && width > 0.0) {
            return bad(format!("width must be > 0 cells, got {width}"));
        }
        if !(2..=MAX_SPAN).contains(&span) {
            return bad(format!(
                "span must be 2 to {MAX_SPAN} centres per axis, got {span}"
            ));
        }
        Ok(Self {
            lower: lower.to_vec(),
            spacing: spacing.to_vec(),
            counts,
            width,
            span,
        })
    }

    pub fn dim(&self) -> usize {
        self.lower.len()
    }

    /// Centres evaluated per axis.
    pub fn span(&self) -> usize {
        self.span
    }

    /// Total number of lattice centres (mostly never stored).
    pub fn centres(&self) -> u64 {
        self.counts.iter().product()
    }

    /// The smallest fraction of the full (untruncated) kernel mass that the neighbourhood keeps,
    /// over all input positions: the 1-D worst case over offsets within a cell, to the power dim.
    pub fn kept_mass(&self) -> f64 {
        let g = |d: f64| (-d * d / (2.0 * self.width * self.width)).exp();
        let worst = (0..100)
            .map(|i| {
                let u = i as f64 / 100.0;
                let lo = self.first_index(u);
                let kept: f64 = (lo..lo + self.span as i64).map(|c| g(u - c as f64)).sum();
                let all: f64 = (-60..=60).map(|c| g(u - c as f64)).sum();
                kept / all
            })
            .fold(1.0, f64::min);
        worst.powi(self.dim() as i32)
    }

    /// The first of the `span` centres nearest to lattice coordinate u.
    fn first_index(&self, u: f64) -> i64 {
        (u - 0.5 * (self.span - 1) as f64 + 0.5).floor() as i64
    }

    /// Writes the normalised features of `x` (clamped into the box) into `out`: the key of each
    /// nearby centre and its weight, summing to 1. Reuses `out`'s buffers.
    pub fn features(&self, x: &[f64], out: &mut Features) {
        debug_assert_eq!(x.len(), self.dim());
        out.clear();
        let dim = self.dim();
        // Per axis: the nearby indices and their 1-D Gaussian factors.
        let mut first = [0u64; MAX_DIM];
        let mut factors = [[0.0f64; MAX_SPAN]; MAX_DIM];
        let mut lens = [0usize; MAX_DIM];
        for d in 0..dim {
            let max = (self.counts[d] - 1) as f64;
            let u = ((x[d] - self.lower[d]) / self.spacing[d]).clamp(0.0, max);
            let lo = self.first_index(u).max(0);
            let hi = (self.first_index(u) + self.span as i64 - 1).min(max as i64);
            first[d] = lo as u64;
            lens[d] = (hi - lo + 1) as usize;
            for (j, i) in (lo..=hi).enumerate() {
                let dist = (u - i as f64) / self.width;
                factors[d][j] = (-0.5 * dist * dist).exp();
            }
        }
        // Odometer over the neighbourhood.
        let mut idx = [0usize; MAX_DIM];
        let mut total = 0.0;
        loop {
            let mut key = 0u64;
            let mut w = 1.0;
            for d in (0..dim).rev() {
                key = key * self.counts[d] + first[d] + idx[d] as u64;
                w *= factors[d][idx[d]];
            }
            out.keys.push(key);
            out.values.push(w);
            total += w;
            let mut d = 0;
            loop {
                if d == dim {
                    for v in &mut out.values {
                        *v /= total;
                    }
                    return;
                }
                idx[d] += 1;
                if idx[d] < lens[d] {
                    break;
                }
                idx[d] = 0;
                d += 1;
            }
        }
    }
}

/// Normalised features of one input: parallel keys and weights. Keep one and reuse it.
#[derive(Debug, Clone, Default)]
pub struct Features {
    keys: Vec<u64>,
    values: Vec<f64>,
}

impl Features {
    fn clear(&mut self) {
        self.keys.clear();
        self.values.clear();
    }

    pub fn iter(&self) -> impl Iterator<Item = (u64, f64)> + '_ {
        self.keys.iter().copied().zip(self.values.iter().copied())
    }

    pub fn len(&self) -> usize {
        self.keys.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }
}

/// Lattice keys are already well spread integers: one multiply mixes them enough, at a fraction
/// of SipHash's cost.
#[derive(Default)]
pub struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 = (self.0 ^ *b as u64).wrapping_mul(0x100_0000_01b3);
        }
    }
    fn write_u64(&mut self, k: u64) {
        self.0 = (k ^ (k >> 29)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
}

/// A stored weight and when it was last trained (the approximator's update count then).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Entry<const OUT: usize> {
    w: [f64; OUT],
    touched: u64,
}

type SparseMap<const OUT: usize> = HashMap<u64, Entry<OUT>, BuildHasherDefault<KeyHasher>>;

/// A linear function approximator on a lattice: f(x) = Σ φ_i(x) w_i, weights stored only where
/// trained, at most `capacity` of them: past that, the least recently trained go (an arm that
/// keeps meeting new sets would otherwise grow them without bound).
#[derive(Debug, Clone)]
pub struct LinearRbf<const OUT: usize> {
    lattice: Lattice,
    initial: [f64; OUT],
    weights: SparseMap<OUT>,
    capacity: usize,
    /// Updates so far: the recency stamp of the centres each one touches.
    clock: u64,
    evicted: u64,
}

/// The same function: the same weights (recency is bookkeeping).
impl<const OUT: usize> PartialEq for LinearRbf<OUT> {
    fn eq(&self, other: &Self) -> bool {
        self.lattice == other.lattice
            && self.initial == other.initial
            && self.weights.len() == other.weights.len()
            && self
                .weights
                .iter()
                .all(|(k, e)| other.weights.get(k).is_some_and(|o| o.w == e.w))
    }
}

impl<const OUT: usize> LinearRbf<OUT> {
    /// An untrained approximator keeping at most `capacity` weights (at least
    /// [`LinearRbf::min_capacity`] of `lattice`).
    pub fn new(lattice: Lattice, initial: [f64; OUT], capacity: usize) -> Self {
        let capacity = capacity.max(Self::min_capacity(&lattice));
        Self {
            lattice,
            initial,
            weights: SparseMap::default(),
            capacity,
            clock: 0,
            evicted: 0,
        }
    }

    /// The smallest useful capacity: eight updates' worth of centres, so an eviction never
    /// reaches the centres the update that caused it has just trained.
    pub fn min_capacity(lattice: &Lattice) -> usize {
        softarm_sections::learner::min_capacity(lattice.span(), lattice.dim())
    }

    pub fn lattice(&self) -> &Lattice {
        &self.lattice
    }

    /// Centres that have a stored weight.
    pub fn stored(&self) -> usize {
        self.weights.len()
    }

    /// Weights dropped by the capacity so far.
    pub fn evicted(&self) -> u64 {
        self.evicted
    }

    /// f(x), normalised over the centres that have been trained: an untrained centre next to
    /// trained ones does not drag the estimate toward `initial`. Where none is trained, `initial`.
    pub fn value(&self, features: &Features) -> [f64; OUT] {
        let mut out = [0.0; OUT];
        let mut mass = 0.0;
        for (key, phi) in features.iter() {
            if let Some(e) = self.weights.get(&key) {
                mass += phi;
                for o in 0..OUT {
                    out[o] += phi * e.w[o];
                }
            }
        }
        if mass <= 0.0 {
            return self.initial;
        }
        out.map(|v| v / mass)
    }

    /// w_i += rate · φ_i · step for every nearby centre (the gradient step of f toward
    /// f + step). A centre touched for the first time starts at the current estimate, so the
    /// function stays continuous as the trained region grows.
    pub fn update(&mut self, features: &Features, rate: f64, step: &[f64; OUT]) {
        let here = self.value(features);
        self.clock += 1;
        for (key, phi) in features.iter() {
            let e = self.weights.entry(key).or_insert(Entry {
                w: here,
                touched: 0,
            });
            e.touched = self.clock;
            for o in 0..OUT {
                e.w[o] += rate * phi * step[o];
            }
        }
        if self.weights.len() > self.capacity {
            self.evict();
        }
    }

    /// Drops the least recently trained weights (ties by key) down to 7/8 of the capacity, so
    /// evictions (a pass over all weights) come once per many updates. The order is total, so a
    /// restored approximator evicts exactly what the saved one would have.
    fn evict(&mut self) {
        let keep = self.capacity - self.capacity / 8;
        let drop = self.weights.len().saturating_sub(keep);
        if drop == 0 {
            return;
        }
        let mut order: Vec<(u64, u64)> =
            self.weights.iter().map(|(k, e)| (e.touched, *k)).collect();
        let (_, &mut threshold, _) = order.select_nth_unstable(drop - 1);
        // min_capacity keeps the update under way out of reach.
        debug_assert!(threshold.0 < self.clock || self.clock == 0);
        self.weights.retain(|k, e| (e.touched, *k) > threshold);
        self.evicted += drop as u64;
    }

    /// Moves f(x) the given fraction of the way toward `target` (normalised LMS: the gradient
    /// step divided by Σφ², so the fraction is exact at x whatever the lattice's width).
    pub fn move_toward(&mut self, features: &Features, fraction: f64, target: &[f64; OUT]) {
        let here = self.value(features);
        let energy: f64 = features.iter().map(|(_, phi)| phi * phi).sum();
        if energy <= 0.0 {
            return;
        }
        let step: [f64; OUT] = std::array::from_fn(|o| target[o] - here[o]);
        self.update(features, fraction / energy, &step);
    }

    /// Weights for saving, the least recently trained first (ties by key), so that
    /// [`LinearRbf::from_entries`] restores their recency too.
    pub fn to_entries(&self) -> Vec<(u64, [f64; OUT])> {
        let mut v: Vec<_> = self.weights.iter().collect();
        v.sort_unstable_by_key(|(k, e)| (e.touched, **k));
        v.into_iter().map(|(k, e)| (*k, e.w)).collect()
    }

    /// Saved weights, the least recently trained first; more than `capacity` keeps the most
    /// recent ones.
    pub fn from_entries(
        lattice: Lattice,
        initial: [f64; OUT],
        capacity: usize,
        entries: &[(u64, [f64; OUT])],
    ) -> Result<Self, RbfError> {
        let total = lattice.centres();
        let mut rbf = Self::new(lattice, initial, capacity);
        for (k, w) in entries {
            if *k >= total {
                return Err(RbfError::Lattice(format!(
                    "weight for centre {k}, the lattice has {total}"
                )));
            }
            if w.iter().any(|v| !v.is_finite()) {
                return Err(RbfError::Lattice(format!(
                    "weight of centre {k} is not finite"
                )));
            }
            rbf.clock += 1;
            let entry = Entry {
                w: *w,
                touched: rbf.clock,
            };
            if rbf.weights.insert(*k, entry).is_some() {
                return Err(RbfError::Lattice(format!("centre {k} stored twice")));
            }
        }
        if rbf.weights.len() > rbf.capacity {
            rbf.evict();
        }
        Ok(rbf)
    }
}

/// The forward model: y = Σ_c w_c exp(−‖a − c‖² / 2σ²) + W_lin [1, a], on `N` actuators. Saved by its parts ([`RbfNetwork::parts`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RbfNetwork<const N: usize> {
    centres: Vec<[f64; N]>,
    sigma: f64,
    /// One row per feature (centres, then 1 and the `N` actuations), one column per axis.
    weights: Vec<Position>,
}

impl<const N: usize> RbfNetwork<N> {
    /// Fits on (actuation, position) samples.
    pub fn fit(
        actuations: &[[f64; N]],
        positions: &[Position],
        config: &NetworkConfig,
    ) -> Result<Self, RbfError> {
        let bad = |s: String| Err(RbfError::Network(s));
        if actuations.len() != positions.len() {
            return bad(format!(
                "{} actuations but {} positions",
                actuations.len(),
                positions.len()
            ));
        }
        let n = actuations.len();
        let linear = N + 1;
        if config.centres == 0 || n < config.centres + linear {
            return bad(format!(
                "{n} samples are too few for {} centres (need at least {})",
                config.centres,
                config.centres + linear
            ));
        }
        if actuations
            .iter()
            .flatten()
            .chain(positions.iter().flatten())
            .any(|v| !v.is_finite())
        {
            return bad("the samples contain a non-finite value".into());
        }
        if !(config.width_factor > 0.0 && config.ridge >= 0.0) {
            return bad("width_factor must be > 0 and ridge >= 0".into());
        }
        let centres = farthest_points(actuations, config.centres);
        let mean_nn = centres
            .iter()
            .enumerate()
            .map(|(i, c)| {
                centres
                    .iter()
                    .enumerate()
                    .filter(|(j, _)| *j != i)
                    .map(|(_, o)| dist2(c, o))
                    .fold(f64::INFINITY, f64::min)
                    .sqrt()
            })
            .sum::<f64>()
            / centres.len() as f64;
        let sigma = (config.width_factor * mean_nn).max(1e-6);
        let mut net = Self {
            centres,
            sigma,
            weights: Vec::new(),
        };
        let f = net.centres.len() + linear;
        let normal = crate::linalg::Normal::of(
            n,
            f,
            3,
            |r, phi, y| {
                net.features(&actuations[r], phi);
                y.copy_from_slice(&positions[r]);
            },
            &mut || {},
        );
        let w = normal
            .solve(config.ridge)
            .ok_or_else(|| RbfError::Network("the least-squares system is singular".into()))?;
        net.weights = (0..f).map(|i| [w[(i, 0)], w[(i, 1)], w[(i, 2)]]).collect();
        Ok(net)
    }

    fn features(&self, a: &[f64; N], out: &mut [f64]) {
        let inv = 1.0 / (2.0 * self.sigma * self.sigma);
        for (o, c) in out.iter_mut().zip(&self.centres) {
            *o = (-dist2(a, c) * inv).exp();
        }
        let m = self.centres.len();
        out[m] = 1.0;
        out[m + 1..m + 1 + N].copy_from_slice(a);
    }

    pub fn centres(&self) -> usize {
        self.centres.len()
    }

    /// (centres, σ, output weights), for saving.
    pub fn parts(&self) -> (&[[f64; N]], f64, &[Position]) {
        (&self.centres, self.sigma, &self.weights)
    }

    /// A network from saved parts; the weights need one row per centre plus `N` + 1.
    pub fn from_parts(
        centres: Vec<[f64; N]>,
        sigma: f64,
        weights: Vec<Position>,
    ) -> Result<Self, String> {
        if centres.is_empty() || weights.len() != centres.len() + N + 1 {
            return Err(format!(
                "forward model: {} centres need {} weight rows, got {}",
                centres.len(),
                centres.len() + N + 1,
                weights.len()
            ));
        }
        if !(sigma.is_finite() && sigma > 0.0) {
            return Err(format!("forward model: σ must be > 0, got {sigma}"));
        }
        Ok(Self {
            centres,
            sigma,
            weights,
        })
    }
}

impl<const N: usize> crate::forward::ForwardModel<N> for RbfNetwork<N> {
    fn position(&self, a: &[f64; N]) -> Position {
        let inv = 1.0 / (2.0 * self.sigma * self.sigma);
        let mut y = [0.0; 3];
        for (c, w) in self.centres.iter().zip(&self.weights) {
            let g = (-dist2(a, c) * inv).exp();
            for d in 0..3 {
                y[d] += g * w[d];
            }
        }
        let m = self.centres.len();
        for d in 0..3 {
            y[d] += self.weights[m][d];
            for (i, ai) in a.iter().enumerate() {
                y[d] += self.weights[m + 1 + i][d] * ai;
            }
        }
        y
    }
}

fn dist2<const N: usize>(a: &[f64; N], b: &[f64; N]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Greedy farthest-point sampling: spreads `m` centres over the data, deterministically.
fn farthest_points<const N: usize>(data: &[[f64; N]], m: usize) -> Vec<[f64; N]> {
    let mut chosen = vec![data[0]];
    let mut nearest: Vec<f64> = data.iter().map(|x| dist2(x, &data[0])).collect();
    while chosen.len() < m {
        let (i, _) =
            nearest.iter().enumerate().fold(
                (0, -1.0),
                |best, (i, &d)| if d > best.1 { (i, d) } else { best },
            );
        let c = data[i];
        chosen.push(c);
        for (n, x) in nearest.iter_mut().zip(data) {
            *n = n.min(dist2(x, &c));
        }
    }
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forward::ForwardModel;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn features_are_normalised_local_and_sparse() {
        let lat = Lattice::new(&[0.0; 6], &[1.0; 6], &[0.03; 6], 0.5, 3).unwrap();
        assert!(
            lat.centres() > 1_000_000_000,
            "a real 6-D lattice: {}",
            lat.centres()
        );
        let mut f = Features::default();
        lat.features(&[0.51, 0.2, 0.33, 0.9, 0.11, 0.5], &mut f);
        assert_eq!(f.len(), 729);
        assert!((f.iter().map(|(_, v)| v).sum::<f64>() - 1.0).abs() < 1e-12);
        let mut net = LinearRbf::<1>::new(lat.clone(), [0.0], usize::MAX);
        net.update(&f, 1.0, &[1.0]);
        assert_eq!(net.stored(), 729);
        // At a corner the neighbourhood is cut by the box.
        lat.features(&[-1.0; 6], &mut f);
        assert_eq!(f.len(), 64);
        assert!(
            lat.kept_mass() > 0.94 && lat.kept_mass() < 1.0,
            "{}",
            lat.kept_mass()
        );
        // Two bracketing centres per axis: 2^6 features, less of the mass.
        let two = Lattice::new(&[0.0; 6], &[1.0; 6], &[0.03; 6], 0.5, 2).unwrap();
        two.features(&[0.51, 0.2, 0.33, 0.9, 0.11, 0.5], &mut f);
        assert_eq!(f.len(), 64);
        assert!(
            (two.kept_mass() - 0.893f64.powi(6)).abs() < 0.01,
            "{}",
            two.kept_mass()
        );
    }

    #[test]
    fn past_its_capacity_a_linear_rbf_forgets_the_least_recently_trained_first() {
        // 2-D, span 2: 4 centres per update, so the smallest capacity is 32.
        let lat = Lattice::new(&[0.0, 0.0], &[1.0, 1.0], &[0.01, 0.01], 0.5, 2).unwrap();
        assert_eq!(LinearRbf::<1>::min_capacity(&lat), 32);
        let mut net = LinearRbf::<1>::new(lat.clone(), [0.0], 40);
        let mut f = Features::default();
        let at = |i: usize| {
            [
                0.005 + 0.02 * (i % 40) as f64,
                0.005 + 0.1 * (i / 40) as f64,
            ]
        };
        // A home point trained all along, and a walk over 400 new places.
        let home = [0.505, 0.905];
        let mut most = 0;
        for i in 0..400 {
            lat.features(&home, &mut f);
            net.move_toward(&f, 0.5, &[1.0]);
            lat.features(&at(i), &mut f);
            net.move_toward(&f, 0.5, &[-1.0]);
            most = most.max(net.stored());
        }
        assert!(most <= 40, "{most} stored, capacity 40");
        assert!(net.evicted() >= 400 * 4 - 40, "{}", net.evicted());
        // What it trains keeps coming back stays; the early walk is forgotten.
        lat.features(&home, &mut f);
        assert!(net.value(&f)[0] > 0.9, "{}", net.value(&f)[0]);
        lat.features(&at(0), &mut f);
        assert_eq!(
            net.value(&f),
            [0.0],
            "the first place walked is still stored"
        );
        lat.features(&at(399), &mut f);
        assert!(net.value(&f)[0] < -0.4, "{}", net.value(&f)[0]);

        // Saved and restored, recency survives: the next evictions drop the same ones.
        let entries = net.to_entries();
        let mut back = LinearRbf::from_entries(lat.clone(), [0.0], 40, &entries).unwrap();
        assert_eq!(back, net);
        lat.features(&[0.995, 0.005], &mut f);
        for n in [&mut net, &mut back] {
            for _ in 0..3 {
                n.move_toward(&f, 0.5, &[0.3]);
            }
        }
        assert_eq!(back, net);
        // A smaller capacity on restore keeps the most recent; a centre twice is refused.
        let small = LinearRbf::from_entries(lat.clone(), [0.0], 32, &entries).unwrap();
        assert!(small.stored() <= 32);
        lat.features(&home, &mut f);
        assert!(small.value(&f)[0] > 0.9);
        let twice = [entries[0], entries[0]];
        let e = LinearRbf::from_entries(lat, [0.0], 40, &twice).unwrap_err();
        assert!(e.to_string().contains("twice"), "{e}");
    }

    #[test]
    fn a_linear_rbf_learns_a_smooth_function() {
        let lat = Lattice::new(&[0.0, 0.0], &[1.0, 1.0], &[0.05, 0.05], 0.5, 5).unwrap();
        let mut net = LinearRbf::<1>::new(lat.clone(), [0.0], usize::MAX);
        let mut f = Features::default();
        let target = |x: f64, y: f64| (3.0 * x).sin() + y * y;
        let mut rng = StdRng::seed_from_u64(5);
        for _ in 0..100_000 {
            let (x, y): (f64, f64) = (rng.random(), rng.random());
            lat.features(&[x, y], &mut f);
            let v = net.value(&f)[0];
            net.update(&f, 0.5, &[target(x, y) - v]);
        }
        let mut worst = 0.0f64;
        for i in 1..10 {
            for j in 1..10 {
                let (x, y) = (i as f64 / 10.0, j as f64 / 10.0);
                lat.features(&[x, y], &mut f);
                worst = worst.max((net.value(&f)[0] - target(x, y)).abs());
            }
        }
        assert!(worst < 0.02, "{worst}");
        let mut moved = net.clone();
        lat.features(&[0.33, 0.71], &mut f);
        let before = moved.value(&f)[0];
        moved.move_toward(&f, 0.25, &[before + 1.0]);
        assert!((moved.value(&f)[0] - (before + 0.25)).abs() < 1e-12);
        let back =
            LinearRbf::from_entries(lat.clone(), [0.0], usize::MAX, &net.to_entries()).unwrap();
        assert_eq!(back, net);
        assert!(LinearRbf::from_entries(lat, [0.0], usize::MAX, &[(u64::MAX, [0.0])]).is_err());
    }

    #[test]
    fn bad_lattices_are_refused() {
        assert!(Lattice::new(&[0.0], &[0.0], &[0.1], 0.5, 3).is_err());
        assert!(Lattice::new(&[0.0], &[1.0], &[0.0], 0.5, 3).is_err());
        assert!(Lattice::new(&[0.0], &[1.0], &[0.1], 0.5, 1).is_err());
        assert!(Lattice::new(&[0.0], &[1.0], &[0.1], 0.5, 10).is_err());
        assert!(Lattice::new(&[0.0, 0.0], &[1.0], &[0.1], 0.5, 3).is_err());
    }

    #[test]
    fn network_fits_a_smooth_map_and_refuses_bad_data() {
        let mut a = Vec::new();
        let mut p = Vec::new();
        let mut rng = StdRng::seed_from_u64(6);
        for _ in 0..600 {
            let x: [f64; 6] = std::array::from_fn(|_| rng.random());
            a.push(x);
            p.push([x[0] * x[1], (x[2] - x[3]).sin(), x[4] + 0.5 * x[5] * x[5]]);
        }
        let cfg = NetworkConfig {
            centres: 100,
            ..Default::default()
        };
        let net = RbfNetwork::fit(&a[..500], &p[..500], &cfg).unwrap();
        let err: f64 = (500..600)
            .map(|i| {
                let y = net.position(&a[i]);
                (0..3).map(|d| (y[d] - p[i][d]).powi(2)).sum::<f64>().sqrt()
            })
            .sum::<f64>()
            / 100.0;
        assert!(err < 0.02, "held-out error {err}");
        assert!(RbfNetwork::fit(&a[..50], &p[..50], &cfg).is_err());
        let mut bad = p.clone();
        bad[3][1] = f64::NAN;
        assert!(RbfNetwork::fit(&a, &bad, &cfg).is_err());
    }
}
