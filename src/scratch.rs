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

#[cfg(test)]
mod tests {
    use super::*;

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
