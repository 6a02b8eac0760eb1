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

/// `v` emptied and given another element type of the same size and alignment (a borrow
/// of another lifetime, mostly), its allocation kept: the standard library collects a
/// vector's `into_iter`, adapted, in place (a unit test below checks it).
pub fn recycled<T, U>(mut v: Vec<T>) -> Vec<U> {
    v.clear();
    v.into_iter().filter_map(|_| None).collect()
}

/// A map from `u32` keys, kept as a vector sorted by key: as entries come and go, its
/// allocation stays (a `BTreeMap` allocates and frees nodes as it grows and shrinks).
/// Its entries iterate in key order, as a `BTreeMap`'s.
#[derive(Clone, Debug)]
pub struct SortedMap<V>(Vec<(u32, V)>);

impl<V> Default for SortedMap<V> {
    fn default() -> Self {
        Self(Vec::new())
    }
}

impl<V> SortedMap<V> {
    /// The value under `key`, if any.
    pub fn get(&self, key: &u32) -> Option<&V> {
        let i = self.0.binary_search_by_key(key, |e| e.0).ok()?;
        Some(&self.0[i].1)
    }

    /// Whether `key` has a value.
    pub fn contains_key(&self, key: &u32) -> bool {
        self.get(key).is_some()
    }

    /// Puts `value` under `key`; the value it replaces, if any.
    pub fn insert(&mut self, key: u32, value: V) -> Option<V> {
        match self.0.binary_search_by_key(&key, |e| e.0) {
            Ok(i) => Some(std::mem::replace(&mut self.0[i].1, value)),
            Err(i) => {
                self.0.insert(i, (key, value));
                None
            }
        }
    }

    /// Keeps the entries for which `keep` is true (it may change their values).
    pub fn retain(&mut self, mut keep: impl FnMut(&u32, &mut V) -> bool) {
        self.0.retain_mut(|(k, v)| keep(k, v));
    }

    /// Removes every entry, keeping the allocation.
    pub fn clear(&mut self) {
        self.0.clear();
    }

    /// The entries, in key order.
    pub fn entries(&self) -> &[(u32, V)] {
        &self.0
    }

    /// The entries as a vector, the map left empty (its allocation goes with them).
    pub fn take_entries(&mut self) -> Vec<(u32, V)> {
        std::mem::take(&mut self.0)
    }

    /// The map of `entries`: sorted by key, and of several under one key the last.
    pub fn from_entries(mut entries: Vec<(u32, V)>) -> Self {
        entries.sort_by_key(|e| e.0);
        entries.reverse();
        entries.dedup_by_key(|e| e.0);
        entries.reverse();
        Self(entries)
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

    /// A vector of borrows recycled for borrows of another lifetime keeps its allocation,
    /// empty, and allocates nothing.
    #[test]
    fn a_recycled_vector_keeps_its_allocation() {
        let (a, b) = (1.0f64, 2.0f64);
        let mut v: Vec<&f64> = Vec::with_capacity(16);
        v.push(&a);
        let at = v.as_ptr() as usize;
        let (w, calls) = counting::allocations(|| recycled::<&f64, &f64>(v));
        assert_eq!(calls, 0);
        assert!(w.is_empty() && w.capacity() == 16 && w.as_ptr() as usize == at);
        let mut w = w;
        w.push(&b);
        assert_eq!(*w[0], 2.0);
    }

    /// The sorted map answers as a `BTreeMap` through inserts (new and replacing),
    /// lookups and a `retain` that changes values, iterates in key order, and keeps the
    /// last of duplicate keys read back; once grown, its inserts and removals allocate
    /// nothing.
    #[test]
    fn the_sorted_map_answers_as_a_btree_map() {
        use std::collections::BTreeMap;
        let (mut map, mut tree) = (SortedMap::default(), BTreeMap::new());
        let mut x: u64 = 0x2545_f491_4f6c_dd1d;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x % 64) as u32
        };
        for round in 0..200 {
            let k = next();
            assert_eq!(map.insert(k, round), tree.insert(k, round), "round {round}");
            let q = next();
            assert_eq!(map.get(&q), tree.get(&q));
            assert_eq!(map.contains_key(&q), tree.contains_key(&q));
            if round % 10 == 9 {
                let cut = next();
                map.retain(|k, v| {
                    *v += 1;
                    *k > cut
                });
                tree.retain(|k, v| {
                    *v += 1;
                    *k > cut
                });
            }
            let entries: Vec<(u32, i32)> = tree.iter().map(|(k, v)| (*k, *v)).collect();
            assert_eq!(map.entries(), &entries[..], "round {round}");
        }
        let mut grown = SortedMap::default();
        (0..64).for_each(|k| {
            grown.insert(k, 0);
        });
        grown.retain(|_, _| false);
        let ((), calls) = counting::allocations(|| {
            (0..64).rev().for_each(|k| {
                grown.insert(k, 1);
            });
            grown.retain(|k, _| k % 2 == 0);
        });
        assert_eq!(calls, 0);
        let read = SortedMap::from_entries(vec![(3, 'a'), (1, 'b'), (3, 'c')]);
        assert_eq!(read.entries(), &[(1, 'b'), (3, 'c')]);
    }
}
