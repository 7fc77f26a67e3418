//! A setting with a value per actuator, for any arm: one number for every actuator, or a list
//! of one per actuator in the arm's order.

use serde::{Deserialize, Serialize};

/// One number for every actuator, or one per actuator (checked against the arm's count where
/// the config is validated).
#[derive(Debug, Clone, PartialEq, Serialize, schemars::JsonSchema)]
#[serde(untagged)]
pub enum PerActuator {
    All(f64),
    Each(Vec<f64>),
}

impl PerActuator {
    /// The value of actuator `i`.
    pub fn get(&self, i: usize) -> f64 {
        match self {
            Self::All(v) => *v,
            Self::Each(v) => v[i],
        }
    }

    /// The values of an arm of `n` actuators (a list must have `n`: see [`PerActuator::check`]).
    pub fn values(&self, n: usize) -> Vec<f64> {
        (0..n).map(|i| self.get(i)).collect()
    }

    /// The values as an array of `N`, for math that runs an arm of `N` actuators.
    pub fn fixed<const N: usize>(&self) -> [f64; N] {
        std::array::from_fn(|i| self.get(i))
    }

    /// Checks it for an arm of `n` actuators: a list has `n` values, each (and a single
    /// number) in `range`. The error is `KEY: message`.
    pub fn check(
        &self,
        key: &str,
        n: usize,
        range: std::ops::RangeInclusive<f64>,
    ) -> Result<(), String> {
        if let Self::Each(v) = self
            && v.len() != n
        {
            return Err(format!(
                "{key}: {} values for an arm of {n} actuators; give one per actuator in the \
                 arm's order, or one number for all",
                v.len()
            ));
        }
        for i in 0..n {
            let v = self.get(i);
            if !range.contains(&v) {
                let what = match self {
                    Self::All(_) => "it is".to_string(),
                    Self::Each(_) => format!("actuator {} is", i + 1),
                };
                return Err(format!(
                    "{key}: {what} {v:?}; must be in [{}, {}]",
                    range.start(),
                    range.end()
                ));
            }
        }
        Ok(())
    }
}

// By hand: serde's untagged error ("did not match any variant") says nothing a user can act on.
impl<'de> Deserialize<'de> for PerActuator {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Values;
        impl<'de> serde::de::Visitor<'de> for Values {
            type Value = PerActuator;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number for every actuator, or a list of one per actuator")
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Self::Value, E> {
                Ok(PerActuator::All(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Self::Value, E> {
                Ok(PerActuator::All(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Self::Value, E> {
                Ok(PerActuator::All(v as f64))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<Self::Value, A::Error> {
                let mut v = Vec::new();
                while let Some(x) = seq.next_element::<f64>()? {
                    v.push(x);
                }
                Ok(PerActuator::Each(v))
            }
        }
        d.deserialize_any(Values)
    }
}

impl From<Vec<f64>> for PerActuator {
    fn from(v: Vec<f64>) -> Self {
        Self::Each(v)
    }
}

impl<const N: usize> From<[f64; N]> for PerActuator {
    fn from(v: [f64; N]) -> Self {
        Self::Each(v.to_vec())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Deserialize)]
    struct S {
        v: PerActuator,
    }

    fn parse(text: &str) -> Result<PerActuator, String> {
        toml::from_str::<S>(text)
            .map(|s| s.v)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn one_number_or_one_per_actuator() {
        assert_eq!(parse("v = 0.5").unwrap().values(3), [0.5; 3]);
        assert_eq!(parse("v = 1").unwrap().values(2), [1.0; 2]);
        let each = parse("v = [0.1, 0.2, 0.3]").unwrap();
        assert_eq!(each.fixed::<3>(), [0.1, 0.2, 0.3]);
        assert!(each.check("k", 3, 0.0..=1.0).is_ok());
        assert_eq!(
            each.check("c.k", 9, 0.0..=1.0).unwrap_err(),
            "c.k: 3 values for an arm of 9 actuators; give one per actuator in the arm's \
             order, or one number for all"
        );
        assert_eq!(
            parse("v = [0.1, 2.0]")
                .unwrap()
                .check("k", 2, 0.0..=1.0)
                .unwrap_err(),
            "k: actuator 2 is 2.0; must be in [0, 1]"
        );
        let e = parse("v = \"x\"").unwrap_err();
        assert!(e.contains("a number for every actuator, or a list"), "{e}");
        assert!(parse("v = [0.1, \"x\"]").is_err());
    }
}
