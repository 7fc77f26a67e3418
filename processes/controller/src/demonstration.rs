//! Playing the demonstration sequences (`softarm demonstrate`): each after a rest that slews to
//! its start, sampled at the tick rate by linear interpolation, tagged with its index and class
//! so the recorder can tell them apart.

use softarm_config::{Config, Controller};

/// The demonstration tag of a setpoint that is not part of a demonstration.
pub(crate) const NO_DEMO: u32 = u32::MAX;

/// Demonstration sequences to play, as the service thread hands them to the tick.
pub struct DemoSequences<const N: usize> {
    /// (class, samples) per demonstration.
    pub(crate) sequences: Vec<(usize, Vec<[f64; N]>)>,
    /// Ticks per sequence sample.
    pub(crate) ticks_per_sample: usize,
}

impl<const N: usize> DemoSequences<N> {
    /// The configured recipe's sequences for `seed`, at the controller's rate.
    pub(crate) fn new(config: &Config, seed: u64) -> Self {
        let recipe = &config.demonstrations;
        let classes = softarm_method::skill::classes(recipe, &config.layout());
        Self {
            sequences: softarm_method::skill::sequences(recipe, &classes, seed),
            ticks_per_sample: (config.controller.rate_hz / recipe.sample_rate_hz)
                .round()
                .max(1.0) as usize,
        }
    }

    /// How long playing them takes (s), rests included.
    pub(crate) fn duration_s(&self, config: &Config) -> f64 {
        self.sequences.len() as f64
            * (config.demonstrations.duration_s + rest_s(&config.controller))
    }
}

/// The rest before each demonstration (s): long enough to reach its start.
pub(crate) fn rest_s(c: &Controller) -> f64 {
    c.rest_s.max(0.5)
}

/// Playing the demonstration sequences, each after a rest that slews to its start.
pub(crate) struct DemoPlayback<const N: usize> {
    sequences: Box<DemoSequences<N>>,
    demo: usize,
    /// Ticks into this demo; negative while resting before it.
    k: i64,
}

impl<const N: usize> DemoPlayback<N> {
    pub(crate) fn new(sequences: Box<DemoSequences<N>>, rest_ticks: i64) -> Self {
        Self {
            sequences,
            demo: 0,
            k: -rest_ticks,
        }
    }

    /// The target of this tick, and (demo, class) while a demonstration is being recorded.
    pub(crate) fn step(&mut self, rest_ticks: i64) -> ([f64; N], Option<(u32, u32)>) {
        let (class, seq) = &self.sequences.sequences[self.demo];
        let ticks_per_sample = self.sequences.ticks_per_sample;
        let out = if self.k < 0 {
            (seq[0], None)
        } else {
            let target = sample_at(seq, self.k as usize, ticks_per_sample);
            (target, Some((self.demo as u32, *class as u32)))
        };
        self.k += 1;
        if self.k >= 0 && self.k as usize > (seq.len() - 1) * ticks_per_sample {
            self.demo += 1;
            self.k = -rest_ticks;
        }
        out
    }

    pub(crate) fn done(&self) -> bool {
        self.demo >= self.sequences.sequences.len()
    }

    /// The sequences back, to be freed off the tick thread.
    pub(crate) fn into_sequences(self) -> Box<DemoSequences<N>> {
        self.sequences
    }
}

/// The demonstration sequence at tick k, linearly interpolated between its samples.
fn sample_at<const N: usize>(seq: &[[f64; N]], k: usize, ticks_per_sample: usize) -> [f64; N] {
    let i = (k / ticks_per_sample).min(seq.len() - 1);
    let j = (i + 1).min(seq.len() - 1);
    let f = (k % ticks_per_sample) as f64 / ticks_per_sample as f64;
    std::array::from_fn(|d| seq[i][d] + f * (seq[j][d] - seq[i][d]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default `[arm]`'s actuators.
    const N: usize = 6;

    #[test]
    fn demonstrations_interpolate_between_samples() {
        let seq = vec![[0.0; N], [1.0; N]];
        assert_eq!(sample_at(&seq, 0, 4), [0.0; N]);
        assert_eq!(sample_at(&seq, 2, 4), [0.5; N]);
        assert_eq!(sample_at(&seq, 4, 4), [1.0; N]);
        assert_eq!(sample_at(&seq, 9, 4), [1.0; N]);
    }

    #[test]
    fn each_demonstration_rests_then_plays_tagged() {
        let sequences = DemoSequences {
            sequences: vec![
                (3, vec![[0.0; N], [1.0; N]]),
                (5, vec![[0.5; N], [0.25; N]]),
            ],
            ticks_per_sample: 2,
        };
        let mut p = DemoPlayback::new(Box::new(sequences), 1);
        let mut steps = Vec::new();
        while !p.done() {
            let (target, tag) = p.step(1);
            steps.push((target[0], tag));
            assert!(steps.len() < 100);
        }
        // Per demonstration one tick of rest at its start, then (samples - 1) * 2 + 1 ticks.
        assert_eq!(
            steps,
            [
                (0.0, None),
                (0.0, Some((0, 3))),
                (0.5, Some((0, 3))),
                (1.0, Some((0, 3))),
                (0.5, None),
                (0.5, Some((1, 5))),
                (0.375, Some((1, 5))),
                (0.25, Some((1, 5))),
            ]
        );
        assert_eq!(p.into_sequences().sequences.len(), 2);
    }
}
