//! Per-actuator values as every payload carries them.

use iceoryx2::prelude::*;
use softarm_space::MAX_ACTUATORS;

/// One value per actuator of the arm, in the arm's order: room for [`MAX_ACTUATORS`] and the
/// count the arm has (`softarm_arm::Layout::actuators`); the values past the count are zero.
///
/// A fixed capacity, not an iceoryx2 slice: every payload stays one `repr(C)` size, so a
/// publisher's samples are preallocated once, a late subscriber's history and the Python
/// mirror's ctypes stay plain, and the tick fills it without asking for a length. 16 doubles
/// are 128 bytes, nothing beside a cache line or two at 500 Hz. Which arm the count belongs to
/// is the services' `softarm.arm` attribute: a process built for another arm cannot connect.
///
/// The fields are the wire layout (the Python mirror and the layout tests read them); code
/// builds one with [`Actuators::new`] and reads it as a slice, which a bad `count` cannot
/// overrun.
#[derive(Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("softarm::Actuators")]
#[repr(C)]
pub struct Actuators {
    pub count: u32,
    pub _pad: u32,
    pub values: [f64; MAX_ACTUATORS],
}

impl Actuators {
    /// No actuators: what a payload's `Default` carries.
    pub const EMPTY: Self = Self {
        count: 0,
        _pad: 0,
        values: [0.0; MAX_ACTUATORS],
    };

    /// `values`, one per actuator; more than [`MAX_ACTUATORS`] is a bug of the caller (every
    /// arm is checked against it when its description is read).
    pub fn new(values: &[f64]) -> Self {
        assert!(
            values.len() <= MAX_ACTUATORS,
            "{} actuators; a payload carries at most {MAX_ACTUATORS}",
            values.len()
        );
        let mut a = Self::EMPTY;
        a.count = values.len() as u32;
        a.values[..values.len()].copy_from_slice(values);
        a
    }

    /// `n` actuators, each `v`.
    pub fn filled(n: usize, v: f64) -> Self {
        Self::new(&[v; MAX_ACTUATORS][..n.min(MAX_ACTUATORS)])
    }

    /// The values as `N` of them, when the payload carries exactly `N` (a peer that fills
    /// in fewer or more says nothing this process can use).
    pub fn fixed<const N: usize>(&self) -> Option<[f64; N]> {
        self.as_slice().try_into().ok()
    }

    pub fn as_slice(&self) -> &[f64] {
        // A count beyond the capacity comes only from a peer's bug: it reads as the capacity.
        &self.values[..(self.count as usize).min(MAX_ACTUATORS)]
    }

    pub fn as_mut_slice(&mut self) -> &mut [f64] {
        let n = (self.count as usize).min(MAX_ACTUATORS);
        &mut self.values[..n]
    }
}

impl Default for Actuators {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl std::ops::Deref for Actuators {
    type Target = [f64];
    fn deref(&self) -> &[f64] {
        self.as_slice()
    }
}

impl std::ops::DerefMut for Actuators {
    fn deref_mut(&mut self) -> &mut [f64] {
        self.as_mut_slice()
    }
}

impl<const N: usize> From<[f64; N]> for Actuators {
    fn from(values: [f64; N]) -> Self {
        Self::new(&values)
    }
}

impl<const N: usize> From<&[f64; N]> for Actuators {
    fn from(values: &[f64; N]) -> Self {
        Self::new(values)
    }
}

impl std::fmt::Debug for Actuators {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.as_slice()).finish()
    }
}

/// As a list of the arm's values, no padding.
impl serde::Serialize for Actuators {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(self.as_slice())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_count_bounds_what_is_read_and_written() {
        let a = Actuators::from([0.1, 0.2, 0.3]);
        assert_eq!(a.len(), 3);
        assert_eq!(a.as_slice(), &[0.1, 0.2, 0.3]);
        assert_eq!(a.fixed::<3>(), Some([0.1, 0.2, 0.3]));
        assert_eq!(a.fixed::<6>(), None, "a payload of three is no arm of six");
        assert_eq!(Actuators::default().len(), 0);
        assert_eq!(Actuators::filled(16, 0.5).iter().sum::<f64>(), 8.0);
        let mut broken = a;
        broken.count = 99;
        assert_eq!(
            broken.len(),
            MAX_ACTUATORS,
            "a peer's bad count reads as the capacity"
        );
        assert_eq!(
            serde_json::to_string(&a).unwrap(),
            "[0.1,0.2,0.3]",
            "JSON has the arm's values only"
        );
        assert_eq!(std::mem::size_of::<Actuators>(), 8 + 8 * MAX_ACTUATORS);
    }

    #[test]
    #[should_panic(expected = "at most 16")]
    fn more_than_the_capacity_is_a_bug() {
        let _ = Actuators::new(&[0.0; 17]);
    }
}
