//! Buffers kept between frames, so that a steady frame reuses its allocations.

use std::sync::{Mutex, MutexGuard};

/// A value kept with its owner between frames for the allocations it holds (vectors
/// cleared and refilled, never read before they are written). A copy of the owner starts
/// with the default value (`Clone`), so a copied sensor does not carry another's buffers,
/// and a lock poisoned by a panic still hands its value out: nothing in it is read.
#[derive(Default)]
pub struct Kept<T>(Mutex<T>);

impl<T: Default> Kept<T> {
    /// The kept value, leaving the default in its place; [`Kept::put`] gives it back.
    pub fn take(&self) -> T {
        std::mem::take(&mut *self.lock())
    }

    /// Keeps `value` for the next [`Kept::take`].
    pub fn put(&self, value: T) {
        *self.lock() = value;
    }

    /// The kept value, through an exclusive borrow of its owner (no lock taken).
    pub fn get_mut(&mut self) -> &mut T {
        self.0.get_mut().unwrap_or_else(|e| e.into_inner())
    }

    fn lock(&self) -> MutexGuard<'_, T> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl<T: Default> Clone for Kept<T> {
    fn clone(&self) -> Self {
        Self::default()
    }
}

/// `v` cleared and filled with `n` copies of `value`, its allocation reused.
pub fn refill<T: Clone>(v: &mut Vec<T>, n: usize, value: T) {
    v.clear();
    v.resize(n, value);
}

/// The unit tests' global allocator, counting each thread's allocations
/// ([`counting::allocations`]): the tests of a frame's code that asserts it allocates
/// nothing once its buffers are sized.
#[cfg(test)]
pub(crate) mod counting {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;

    thread_local! {
        /// This thread's calls of `alloc` and `realloc` so far.
        static CALLS: Cell<usize> = const { Cell::new(0) };
    }

    struct Counting;

    fn count() {
        // (Not during the thread's teardown, where its counter is gone.)
        let _ = CALLS.try_with(|c| c.set(c.get() + 1));
    }

    // SAFETY: every call goes to the system allocator as it came.
    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            count();
            // SAFETY: the caller's layout, as `GlobalAlloc::alloc` takes it.
            unsafe { System.alloc(layout) }
        }

        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            // SAFETY: a block this allocator (the system's) gave out, with its layout.
            unsafe { System.dealloc(ptr, layout) }
        }

        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            count();
            // SAFETY: as `dealloc`, and the caller's new size.
            unsafe { System.realloc(ptr, layout, new_size) }
        }
    }

    #[global_allocator]
    static GLOBAL: Counting = Counting;

    /// `f`'s result and the allocations (and reallocations) this thread made while it
    /// ran: other threads' (the other tests') are not counted.
    pub(crate) fn allocations<R>(f: impl FnOnce() -> R) -> (R, usize) {
        let before = CALLS.with(Cell::get);
        let r = f();
        (r, CALLS.with(Cell::get) - before)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The counter sees this thread's allocations, each of them.
    #[test]
    fn the_counter_counts_this_threads_allocations() {
        let ((), none) = counting::allocations(|| {
            let x = [1.0f64; 8];
            std::hint::black_box(x);
        });
        assert_eq!(none, 0);
        let (v, two) = counting::allocations(|| {
            let mut v: Vec<u64> = Vec::with_capacity(1);
            v.extend(0..100);
            std::hint::black_box(v)
        });
        assert_eq!(v.len(), 100);
        assert!(two >= 2, "an allocation and at least one growth: {two}");
    }

    #[test]
    fn a_kept_buffer_comes_back_with_its_allocation_and_a_copy_starts_empty() {
        let kept: Kept<Vec<f64>> = Kept::default();
        let mut v = kept.take();
        refill(&mut v, 1000, 1.0);
        let at = v.as_ptr();
        kept.put(v);
        let mut again = kept.take();
        assert_eq!(again.as_ptr(), at, "the same allocation");
        refill(&mut again, 10, 2.0);
        assert_eq!(again, vec![2.0; 10]);
        assert_eq!(again.as_ptr(), at, "refilled in place");
        kept.put(again);
        assert!(kept.clone().take().is_empty(), "a copy starts empty");
    }
}
