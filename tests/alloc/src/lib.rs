//! A counting global allocator: every allocation, free and reallocation made on a thread that
//! asked to be counted ([`count_this_thread`]) adds one to that thread's count and to the
//! count of all counted threads; other threads go uncounted. The `#[global_allocator]` stays in
//! each test binary:
//!
//! ```
//! use softarm_test_alloc::{self as alloc, Counting};
//!
//! #[global_allocator]
//! static GLOBAL: Counting = Counting;
//!
//! fn main() {
//!     let counted = alloc::count_this_thread();
//!     let before = alloc::this_thread();
//!     drop(std::hint::black_box(Box::new(1)));
//!     assert_eq!(alloc::this_thread() - before, 2);
//!     drop(counted);
//! }
//! ```

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::marker::PhantomData;
use std::sync::atomic::{AtomicU64, Ordering};

/// The system allocator, counting on the threads that asked.
#[derive(Debug, Clone, Copy, Default)]
pub struct Counting;

static ALL: AtomicU64 = AtomicU64::new(0);

thread_local! {
    static COUNTED: Cell<bool> = const { Cell::new(false) };
    static MINE: Cell<u64> = const { Cell::new(0) };
}

fn count() {
    // `try_with`: no panic while the thread's locals are being torn down.
    if COUNTED.try_with(Cell::get).unwrap_or(false) {
        let _ = MINE.try_with(|c| c.set(c.get() + 1));
        ALL.fetch_add(1, Ordering::Relaxed);
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        count();
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new) }
    }
}

/// While the guard lives, this thread's allocations are counted.
#[must_use = "counting stops when the guard is dropped"]
#[derive(Debug)]
pub struct Counted {
    was: bool,
    /// Bound to the thread it counts.
    _thread: PhantomData<*const ()>,
}

/// Counts this thread's allocations until the guard is dropped.
pub fn count_this_thread() -> Counted {
    let was = COUNTED.with(|c| c.replace(true));
    Counted {
        was,
        _thread: PhantomData,
    }
}

impl Drop for Counted {
    fn drop(&mut self) {
        let _ = COUNTED.try_with(|c| c.set(self.was));
    }
}

/// Allocations, frees and reallocations counted on this thread so far.
pub fn this_thread() -> u64 {
    MINE.with(Cell::get)
}

/// Allocations, frees and reallocations counted on every thread so far.
pub fn all_threads() -> u64 {
    ALL.load(Ordering::Relaxed)
}
