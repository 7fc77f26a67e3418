//! How late the tick thread wakes after its deadlines: an HDR histogram, allocated once before
//! the loop; recording and summarising allocate nothing.

use hdrhistogram::Histogram;
use softarm_ipc::Latency;

/// Quantiles to 1 % from 1 µs to 60 s (about 3,500 counts, so the 10 Hz summary's scans stay
/// short); longer latencies count as 60 s. Min and max are kept exactly beside.
const LOWEST_NS: u64 = 1_000;
const HIGHEST_NS: u64 = 60_000_000_000;
const SIGNIFICANT_DIGITS: u8 = 2;

/// The tick's wake-up latency since the controller started.
pub(crate) struct TickLatency {
    hist: Histogram<u64>,
    min_ns: u64,
    max_ns: u64,
}

impl TickLatency {
    /// Allocates the histogram's counts (do this before the loop).
    pub(crate) fn new() -> Self {
        Self {
            hist: Histogram::new_with_bounds(LOWEST_NS, HIGHEST_NS, SIGNIFICANT_DIGITS)
                .expect("the latency histogram's bounds are valid"),
            min_ns: u64::MAX,
            max_ns: 0,
        }
    }

    pub(crate) fn record(&mut self, ns: u64) {
        self.hist.saturating_record(ns);
        self.min_ns = self.min_ns.min(ns);
        self.max_ns = self.max_ns.max(ns);
    }

    /// Min and max exactly; p50 / p99 / p99.9 to the histogram's resolution, never past max.
    pub(crate) fn summary(&self) -> Latency {
        let h = &self.hist;
        if h.is_empty() {
            return Latency::default();
        }
        let at = |q: f64| h.value_at_quantile(q).clamp(self.min_ns, self.max_ns);
        Latency {
            min_ns: self.min_ns,
            p50_ns: at(0.5),
            p99_ns: at(0.99),
            p999_ns: at(0.999),
            max_ns: self.max_ns,
            samples: h.len(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use softarm_test_alloc::{self as alloc, Counting};

    #[global_allocator]
    static GLOBAL: Counting = Counting;

    /// Within the histogram's 1 %.
    fn near(value: u64, want: u64) -> bool {
        value.abs_diff(want) <= want / 100 + 1
    }

    #[test]
    fn latency_percentiles_come_from_the_histogram() {
        let mut h = TickLatency::new();
        assert_eq!(h.summary().samples, 0);
        for i in 0..1000u64 {
            h.record(i * 1000 + 500);
        }
        h.record(50_000_000);
        let s = h.summary();
        assert_eq!((s.min_ns, s.max_ns), (500, 50_000_000));
        assert!(near(s.p50_ns, 500_500), "{s:?}");
        assert!(near(s.p99_ns, 990_500), "{s:?}");
        assert!(near(s.p999_ns, 999_500), "{s:?}");
        assert_eq!(s.samples, 1001);
    }

    #[test]
    fn min_and_max_are_exact_beyond_the_bounds() {
        let mut h = TickLatency::new();
        h.record(0);
        h.record(u64::MAX);
        let s = h.summary();
        assert_eq!((s.min_ns, s.max_ns, s.samples), (0, u64::MAX, 2));
        assert!(s.p50_ns <= s.p99_ns && s.p99_ns <= s.p999_ns, "{s:?}");
        assert!(near(s.p999_ns, HIGHEST_NS), "{s:?}");
    }

    #[test]
    fn recording_and_summarising_allocate_nothing() {
        let mut h = TickLatency::new();
        let _counted = alloc::count_this_thread();
        let before = alloc::this_thread();
        let mut sink = 0;
        for i in 0..100_000u64 {
            h.record(i.wrapping_mul(7919) % 3_000_000_000);
            if i % 1000 == 0 {
                sink += std::hint::black_box(h.summary()).p999_ns;
            }
        }
        assert_eq!(alloc::this_thread() - before, 0);
        assert!(sink > 0);
        // The counter sees what this thread allocates.
        drop(std::hint::black_box(Vec::<u8>::with_capacity(16)));
        assert_eq!(alloc::this_thread() - before, 2);
    }
}
