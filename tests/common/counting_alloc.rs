//! The counting global allocator of the allocation tests. It forwards to
//! the system allocator and counts allocations and reallocations (frees are
//! not counted), either on the calling thread only or on every thread.
//!
//! A global allocator must be declared in the test crate itself:
//!
//! ```ignore
//! mod common;
//! use common::counting_alloc::CountingAlloc;
//!
//! #[global_allocator]
//! static GLOBAL: CountingAlloc = CountingAlloc;
//! ```

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Forwards to [`System`], counting as the `start_counting*` calls ask.
pub struct CountingAlloc;

thread_local! {
    /// Whether this thread's allocations are being counted.
    static THREAD_COUNTING: Cell<bool> = const { Cell::new(false) };
    /// Allocations this thread made while counting.
    static THREAD_ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

/// Whether every thread's allocations are being counted.
static ALL_COUNTING: AtomicBool = AtomicBool::new(false);
/// Allocations any thread made while `ALL_COUNTING` was on.
static ALL_ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

fn count_one() {
    if ALL_COUNTING.load(Ordering::Relaxed) {
        ALL_ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
    // `try_with`: the allocator also runs while a thread's locals are
    // being torn down.
    let _ = THREAD_COUNTING.try_with(|on| {
        if on.get() {
            let _ = THREAD_ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        }
    });
}

// SAFETY: forwards every call to the system allocator unchanged; counting
// touches only atomics and const-initialized thread-locals, which never
// allocate.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_one();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_one();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Starts counting the calling thread's allocations, from zero.
pub fn start_counting() {
    THREAD_ALLOCATIONS.with(|n| n.set(0));
    THREAD_COUNTING.with(|c| c.set(true));
}

/// Stops counting the calling thread's allocations and returns its count.
pub fn stop_counting() -> u64 {
    THREAD_COUNTING.with(|c| c.set(false));
    THREAD_ALLOCATIONS.with(Cell::get)
}

/// Starts counting the allocations of every thread, from zero.
pub fn start_counting_all_threads() {
    ALL_ALLOCATIONS.store(0, Ordering::SeqCst);
    ALL_COUNTING.store(true, Ordering::SeqCst);
}

/// Stops counting every thread's allocations and returns the count.
pub fn stop_counting_all_threads() -> u64 {
    ALL_COUNTING.store(false, Ordering::SeqCst);
    ALL_ALLOCATIONS.load(Ordering::SeqCst)
}
