//! `[activation]`: the shape of Eq. 11's activations, as plain data with its validation. The
//! activations themselves are `softarm_method::activation`.

use serde::{Deserialize, Serialize};

/// At most this many primitives.
pub const MAX_PRIMITIVES: usize = 8;

/// Shape of a cross-fade from 0 to 1 over s ∈ [0, 1]; each is exactly 0 and 1 at the ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Fade {
    /// ½ − ½ cos(π s)
    Cosine,
    /// 3s² − 2s³
    Smoothstep,
    /// 6s⁵ − 15s⁴ + 10s³ (zero acceleration at the ends too)
    Smootherstep,
}

impl Fade {
    /// The largest slope d/ds over [0, 1].
    pub fn max_slope(self) -> f64 {
        match self {
            Fade::Cosine => std::f64::consts::FRAC_PI_2,
            Fade::Smoothstep => 1.5,
            Fade::Smootherstep => 1.875,
        }
    }
}

/// Shape of the activations; one section of the controller config.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ActivationConfig {
    /// Width (s) of the window around each T_cond where b_i = 1 and the point is evaluated.
    pub window_s: f64,
    /// Width (s) of the a_j cross-fade centred on the midpoint between two conditioning points.
    pub crossfade_s: f64,
    pub fade: Fade,
    /// a_j of the primitives that do not own the time.
    pub floor: f64,
    /// The fastest any activation may change (1/s): 10 /s is 0.01 between adjacent 1 kHz ticks.
    /// A schedule whose cross-fades would be steeper is refused.
    pub max_rate_per_s: f64,
}

impl Default for ActivationConfig {
    fn default() -> Self {
        Self {
            window_s: 0.2,
            crossfade_s: 0.3,
            fade: Fade::Cosine,
            floor: 1e-3,
            max_rate_per_s: 10.0,
        }
    }
}

impl ActivationConfig {
    /// Longest `window_s` and `crossfade_s` (s): a way-point set lasts at most an hour.
    pub const MAX_SPAN_S: f64 = 60.0;
    /// Largest `max_rate_per_s` (1/s).
    pub const MAX_RATE_PER_S: f64 = 1000.0;

    /// Checks every field; the error is `activation.KEY: message`.
    pub fn validate(&self) -> Result<(), String> {
        let bad = |key: &str, m: String| Err(format!("activation.{key}: {m}"));
        let max = Self::MAX_SPAN_S;
        if !(self.window_s.is_finite() && (0.0..=max).contains(&self.window_s)) {
            return bad(
                "window_s",
                format!("must be in [0, {max}] s, got {:?}", self.window_s),
            );
        }
        if !(self.crossfade_s.is_finite() && self.crossfade_s > 0.0 && self.crossfade_s <= max) {
            return bad(
                "crossfade_s",
                format!("must be in (0, {max}] s, got {:?}", self.crossfade_s),
            );
        }
        if !(self.floor > 0.0 && self.floor <= 1.0) {
            return bad("floor", format!("must be in (0, 1], got {:?}", self.floor));
        }
        let max_rate = Self::MAX_RATE_PER_S;
        if !(self.max_rate_per_s > 0.0 && self.max_rate_per_s <= max_rate) {
            return bad(
                "max_rate_per_s",
                format!(
                    "must be in (0, {max_rate}] /s, got {:?}",
                    self.max_rate_per_s
                ),
            );
        }
        // b's hand-over spans the gap between windows, which is at least crossfade_s wide, so
        // the a_j cross-fade is the steepest activation.
        let steepest = self.fade.max_slope() / self.crossfade_s;
        if steepest > self.max_rate_per_s {
            return bad(
                "crossfade_s",
                format!(
                    "{} s changes activations at {steepest:.2} /s, above max_rate_per_s = {}; \
                     widen crossfade_s to at least {:.3} s",
                    self.crossfade_s,
                    self.max_rate_per_s,
                    self.fade.max_slope() / self.max_rate_per_s
                ),
            );
        }
        Ok(())
    }
}
