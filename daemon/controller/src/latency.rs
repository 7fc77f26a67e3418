//! How late the tick thread wakes after its deadlines: an HDR histogram, allocated once before
//! the loop; recording and summarising allocate nothing.

use hdrhistogram::Histogram;
use softarm_ipc::Latency;

/// Latencies from 1 ns to 1 s at 3 significant digits (0.1 %); longer ones count as 1 s.
const LOWEST_NS: u64 = 1;
const HIGHEST_NS: u64 = 1_000_000_000;
const SIGNIFICANT_DIGITS: u8 = 3;

/// The tick's wake-up latency since the controller started.
pub(crate) struct TickLatency {
    hist: Histogram<u64>,
}

impl TickLatency {
    /// Allocates the histogram's counts (do this before the loop).
    pub(crate) fn new() -> Self {
        Self {
            hist: Histogram::new_with_bounds(LOWEST_NS, HIGHEST_NS, SIGNIFICANT_DIGITS)
                .expect("the latency histogram's bounds are valid"),
        }
    }

    pub(crate) fn record(&mut self, ns: u64) {
        self.hist.saturating_record(ns);
    }

    /// Min / p50 / p99 / p99.9 / max, each to the histogram's resolution.
    pub(crate) fn summary(&self) -> Latency {
        let h = &self.hist;
        if h.is_empty() {
            return Latency::default();
        }
        Latency {
            min_ns: h.min(),
            p50_ns: h.value_at_quantile(0.5),
            p99_ns: h.value_at_quantile(0.99),
            p999_ns: h.value_at_quantile(0.999),
            max_ns: h.max(),
            samples: h.len(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;

    /// Counts this thread's allocations and frees (the other tests of the binary run beside).
    struct Counting;

    thread_local! {
        static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    }

    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
            unsafe { System.alloc(layout) }
        }
        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
            unsafe { System.dealloc(ptr, layout) }
        }
        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new: usize) -> *mut u8 {
            let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
            unsafe { System.realloc(ptr, layout, new) }
        }
    }

    #[global_allocator]
    static GLOBAL: Counting = Counting;

    fn allocations() -> u64 {
        ALLOCATIONS.with(|c| c.get())
    }

    fn near(value: u64, want: u64) -> bool {
        value.abs_diff(want) <= want / 1000 + 1
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
        assert_eq!(s.min_ns, 500);
        assert!(near(s.max_ns, 50_000_000), "{s:?}");
        assert!((499_000..=502_000).contains(&s.p50_ns), "{s:?}");
        assert!((989_000..=992_000).contains(&s.p99_ns), "{s:?}");
        assert!((998_000..=1_001_000).contains(&s.p999_ns), "{s:?}");
        assert_eq!(s.samples, 1001);
    }

    #[test]
    fn latencies_past_the_bound_count_as_the_bound() {
        let mut h = TickLatency::new();
        h.record(0);
        h.record(u64::MAX);
        let s = h.summary();
        assert_eq!((s.min_ns, s.samples), (0, 2));
        assert!(near(s.max_ns, HIGHEST_NS), "{s:?}");
    }

    #[test]
    fn recording_and_summarising_allocate_nothing() {
        let mut h = TickLatency::new();
        let before = allocations();
        let mut sink = 0;
        for i in 0..100_000u64 {
            h.record(i.wrapping_mul(7919) % 3_000_000_000);
            if i % 1000 == 0 {
                sink += std::hint::black_box(h.summary()).p999_ns;
            }
        }
        assert_eq!(allocations() - before, 0);
        assert!(sink > 0);
    }

    #[test]
    fn the_counter_sees_allocations() {
        let before = allocations();
        drop(std::hint::black_box(Vec::<u8>::with_capacity(16)));
        assert_eq!(allocations() - before, 2);
    }
}
