//! The sensor's state as numbers: what the next frame depends on, written into MuJoCo's
//! `plugin_state` after each evaluation and read back from it where `mj_setState` put
//! another one there (see `docs/state.md`).
//!
//! One function per stateful type both writes and reads it ([`Persist::persist`], walking
//! its fields through an [`Io`]), so that the two directions cannot disagree. Every value
//! is stored exactly: an `f32` widened to `f64` and narrowed back keeps its bits, and
//! integers below 2^53 are exact. Reading is defensive: a state from elsewhere (another
//! model, a file, numbers written by hand) is checked as it is read, and a value out of
//! range, a length above its bound or a short buffer fails the read with the field's name
//! instead of giving the sensor a state it cannot hold.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use crate::geometry::{Placed, Sdf};
use nalgebra::{
    Isometry3, Matrix3, Point3, Quaternion, Translation3, UnitQuaternion, Vector2, Vector3,
};

/// A walk over a state: writing it into a buffer, or reading it from one.
#[derive(Debug)]
pub enum Io<'a> {
    /// Writing into `out` from `at`; `overflow` once a value did not fit (the rest is
    /// counted, not written, so that the length needed is known).
    Save {
        /// The buffer.
        out: &'a mut [f64],
        /// Values written (or counted) so far.
        at: usize,
    },
    /// Reading from `data` from `at`; `fault` names the first value that could not be
    /// read (later reads leave their fields unchanged).
    Load {
        /// The buffer.
        data: &'a [f64],
        /// Values read so far.
        at: usize,
        /// What went wrong first.
        fault: Option<String>,
    },
}

impl<'a> Io<'a> {
    /// A walk that writes into `out`.
    pub fn save(out: &'a mut [f64]) -> Self {
        Io::Save { out, at: 0 }
    }

    /// A walk that reads from `data`.
    pub fn load(data: &'a [f64]) -> Self {
        Io::Load {
            data,
            at: 0,
            fault: None,
        }
    }

    /// Whether this walk reads (fields take the stored values) rather than writes.
    pub fn loading(&self) -> bool {
        matches!(self, Io::Load { .. })
    }

    /// Values walked so far (written, counted or read).
    pub fn position(&self) -> usize {
        match self {
            Io::Save { at, .. } | Io::Load { at, .. } => *at,
        }
    }

    /// Whether a write ran past the buffer.
    pub fn overflowed(&self) -> bool {
        matches!(self, Io::Save { out, at } if *at > out.len())
    }

    /// The first fault of a read.
    pub fn fault(&self) -> Option<&str> {
        match self {
            Io::Load { fault, .. } => fault.as_deref(),
            Io::Save { .. } => None,
        }
    }

    /// Marks the read as failed (the first fault is kept).
    pub fn fail(&mut self, why: impl FnOnce() -> String) {
        if let Io::Load { fault, .. } = self {
            if fault.is_none() {
                *fault = Some(why());
            }
        }
    }

    /// One number: written, or read when the read has not failed.
    pub fn num(&mut self, v: &mut f64) {
        match self {
            Io::Save { out, at } => {
                if let Some(slot) = out.get_mut(*at) {
                    *slot = *v;
                }
                *at += 1;
            }
            Io::Load { data, at, fault } => {
                if fault.is_some() {
                    return;
                }
                match data.get(*at) {
                    Some(&x) => *v = x,
                    None => *fault = Some(format!("the state ends after {} values", data.len())),
                }
                *at += 1;
            }
        }
    }

    /// A number read back only if `check` accepts it (`what` names it in the fault).
    fn checked(&mut self, v: &mut f64, what: &str, check: impl Fn(f64) -> bool) {
        let mut x = *v;
        self.num(&mut x);
        if !self.loading() || self.fault().is_some() {
            return;
        }
        if check(x) {
            *v = x;
        } else {
            self.fail(|| format!("{what} = {x} is out of range"));
        }
    }

    /// A whole number below `bound` (`what` names it in the fault).
    pub fn count(&mut self, v: &mut usize, bound: usize, what: &str) {
        let mut x = *v as f64;
        self.checked(&mut x, what, |x| {
            x >= 0.0 && x.fract() == 0.0 && x < bound as f64
        });
        *v = x as usize;
    }

    /// The length of a list of at most `cap` items; the list's own length when writing.
    pub fn len(&mut self, n: usize, cap: usize, what: &str) -> usize {
        let mut n = n;
        self.count(&mut n, cap + 1, what);
        n
    }
}

/// A type that walks its own state through an [`Io`]: writes every field the next frame
/// depends on, or reads each back.
pub trait Persist {
    /// Writes or reads `self`.
    fn persist(&mut self, io: &mut Io<'_>);
}

impl Persist for f64 {
    fn persist(&mut self, io: &mut Io<'_>) {
        io.num(self);
    }
}

impl Persist for f32 {
    fn persist(&mut self, io: &mut Io<'_>) {
        let mut x = *self as f64;
        // An f32 widened keeps its value; one that is not an f32's is refused.
        io.checked(&mut x, "an f32 value", |x| {
            x.is_nan() || x as f32 as f64 == x
        });
        *self = x as f32;
    }
}

impl Persist for bool {
    fn persist(&mut self, io: &mut Io<'_>) {
        let mut x = if *self { 1.0 } else { 0.0 };
        io.checked(&mut x, "a flag", |x| x == 0.0 || x == 1.0);
        *self = x == 1.0;
    }
}

impl Persist for u32 {
    fn persist(&mut self, io: &mut Io<'_>) {
        let mut x = *self as f64;
        io.checked(&mut x, "an index", |x| {
            x >= 0.0 && x.fract() == 0.0 && x <= u32::MAX as f64
        });
        *self = x as u32;
    }
}

impl Persist for usize {
    fn persist(&mut self, io: &mut Io<'_>) {
        // Indices and counts of this crate stay far below 2^53.
        io.count(self, 1 << 53, "a count");
    }
}

impl<T: Persist, const N: usize> Persist for [T; N] {
    fn persist(&mut self, io: &mut Io<'_>) {
        self.iter_mut().for_each(|x| x.persist(io));
    }
}

impl<A: Persist, B: Persist> Persist for (A, B) {
    fn persist(&mut self, io: &mut Io<'_>) {
        self.0.persist(io);
        self.1.persist(io);
    }
}

macro_rules! persist_storage {
    ($($ty:ty),*) => {
        $(impl Persist for $ty {
            fn persist(&mut self, io: &mut Io<'_>) {
                self.iter_mut().for_each(|x| x.persist(io));
            }
        })*
    };
}

persist_storage!(
    Vector2<f64>,
    Vector3<f32>,
    Vector3<f64>,
    Matrix3<f32>,
    Matrix3<f64>
);

impl Persist for Point3<f64> {
    fn persist(&mut self, io: &mut Io<'_>) {
        self.coords.persist(io);
    }
}

impl Persist for UnitQuaternion<f32> {
    fn persist(&mut self, io: &mut Io<'_>) {
        let mut q = *self.quaternion();
        q.coords.iter_mut().for_each(|x| x.persist(io));
        // Kept as stored: the bits of a unit quaternion the solver normalised itself.
        *self = UnitQuaternion::new_unchecked(q);
    }
}

impl Persist for Isometry3<f64> {
    fn persist(&mut self, io: &mut Io<'_>) {
        let mut t = self.translation.vector;
        let mut q = *self.rotation.quaternion();
        t.persist(io);
        q.coords.iter_mut().for_each(|x| x.persist(io));
        if io.loading() && io.fault().is_none() {
            let norm = q.norm();
            if !((norm - 1.0).abs() < 1e-6) {
                io.fail(|| format!("a pose's rotation has norm {norm}"));
                return;
            }
            *self = Isometry3::from_parts(
                Translation3::from(t),
                UnitQuaternion::new_unchecked(Quaternion::from(q.coords)),
            );
        }
    }
}

/// Each item of a list whose length the state's owner fixes (the particles, the top
/// slots): the lengths are not stored.
pub fn each<T: Persist>(io: &mut Io<'_>, items: &mut [T]) {
    items.iter_mut().for_each(|x| x.persist(io));
}

/// A list of at most `cap` items, its length first (`what` names it in a fault).
pub fn list<T: Persist + Default>(io: &mut Io<'_>, items: &mut Vec<T>, cap: usize, what: &str) {
    let n = io.len(items.len(), cap, what);
    if io.loading() {
        if io.fault().is_some() {
            return;
        }
        items.clear();
        items.resize_with(n, T::default);
    }
    each(io, items);
}

/// Indenters, each by its shape's index in `shapes` and its pose (a shape missing from
/// `shapes` is left out when writing); a read fails on an index outside `shapes`.
pub fn placed(io: &mut Io<'_>, items: &mut Vec<Placed>, shapes: &[Arc<dyn Sdf>], what: &str) {
    let mut named: Vec<(usize, Isometry3<f64>)> = items
        .iter()
        .filter_map(|p| {
            Some((
                shapes.iter().position(|s| Arc::ptr_eq(s, &p.shape))?,
                p.pose,
            ))
        })
        .collect();
    let n = io.len(named.len(), shapes.len(), what);
    if io.loading() {
        named.resize(n, (0, Isometry3::identity()));
    }
    for (i, pose) in &mut named {
        io.count(i, shapes.len(), "an indenter's shape");
        pose.persist(io);
    }
    if io.loading() && io.fault().is_none() {
        *items = named
            .into_iter()
            .map(|(i, pose)| Placed {
                shape: shapes[i].clone(),
                pose,
            })
            .collect();
    }
}

/// The most numbers [`placed`] takes for at most `indenters` indenters: the count, and
/// per indenter its shape's index, its translation and its rotation's quaternion.
pub const fn placed_len(indenters: usize) -> usize {
    1 + indenters * 8
}

/// Whether an optional value is there: a flag. Reading one into `None` makes it with
/// `make` (its failure is the read's fault), reading none drops it; what it holds is the
/// caller's to walk.
pub fn presence<T>(io: &mut Io<'_>, v: &mut Option<T>, make: impl FnOnce() -> Result<T, String>) {
    let mut some = v.is_some();
    some.persist(io);
    if io.loading() && io.fault().is_none() {
        match (some, v.is_some()) {
            (true, false) => match make() {
                Ok(x) => *v = Some(x),
                Err(e) => io.fail(|| e),
            },
            (false, true) => *v = None,
            _ => {}
        }
    }
}

/// An optional value: a flag, then the value where there is one (made with `make` when
/// reading one into `None`).
pub fn option<T: Persist>(io: &mut Io<'_>, v: &mut Option<T>, make: impl FnOnce() -> T) {
    presence(io, v, || Ok(make()));
    if let Some(x) = v.as_mut() {
        x.persist(io);
    }
}

/// A solver's secant memory: each unknown's change over the last solve (none, or one per
/// unknown: `unknowns` of them, any other length refused naming `whose`) and the
/// indenters' motion in it (at most `indenters`).
pub fn secant<T: Persist + Default>(
    io: &mut Io<'_>,
    change: &mut Vec<T>,
    motion: &mut Vec<Vector3<f64>>,
    unknowns: usize,
    indenters: usize,
    whose: &str,
) {
    list(io, change, unknowns, &format!("{whose} secant memory"));
    list(io, motion, indenters, &format!("{whose} secant motion"));
    let memory = change.len();
    if io.loading() && memory != 0 && memory != unknowns {
        io.fail(|| format!("{whose} secant memory holds {memory} of {unknowns} unknowns"));
    }
}

/// A map of at most `cap` entries, in key order.
pub fn btree<V: Persist + Default>(
    io: &mut Io<'_>,
    map: &mut BTreeMap<u32, V>,
    cap: usize,
    what: &str,
) {
    let mut entries: Vec<(u32, V)> = std::mem::take(map).into_iter().collect();
    list(io, &mut entries, cap, what);
    *map = entries.into_iter().collect();
}

/// A [`SortedMap`](crate::scratch::SortedMap) of at most `cap` entries, in key order (as
/// [`btree`] writes a map: the two read each other's).
pub fn sorted<V: Persist + Default>(
    io: &mut Io<'_>,
    map: &mut crate::scratch::SortedMap<V>,
    cap: usize,
    what: &str,
) {
    let mut entries = map.take_entries();
    list(io, &mut entries, cap, what);
    *map = crate::scratch::SortedMap::from_entries(entries);
}

/// A hash map of at most `cap` entries, in key order (so that equal maps give equal
/// states).
pub fn hash<V: Persist + Default>(
    io: &mut Io<'_>,
    map: &mut HashMap<u32, V>,
    cap: usize,
    what: &str,
) {
    let mut entries: Vec<(u32, V)> = map.drain().collect();
    entries.sort_unstable_by_key(|e| e.0);
    list(io, &mut entries, cap, what);
    map.extend(entries);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Default, Debug, PartialEq)]
    struct Thing {
        a: f32,
        b: Vec<Vector3<f64>>,
        c: Option<u32>,
        d: bool,
    }

    impl Persist for Thing {
        fn persist(&mut self, io: &mut Io<'_>) {
            self.a.persist(io);
            list(io, &mut self.b, 4, "b");
            option(io, &mut self.c, || 0);
            self.d.persist(io);
        }
    }

    fn thing() -> Thing {
        Thing {
            a: 0.1,
            b: vec![Vector3::new(1.0, -2.5, f64::MIN_POSITIVE), Vector3::zeros()],
            c: Some(7),
            d: true,
        }
    }

    #[test]
    fn a_state_read_back_is_the_state_written_bit_for_bit() {
        let mut t = thing();
        let mut buf = vec![0.0; 64];
        let mut io = Io::save(&mut buf);
        t.persist(&mut io);
        let n = io.position();
        assert!(!io.overflowed());
        let mut back = Thing::default();
        let mut io = Io::load(&buf[..n]);
        back.persist(&mut io);
        assert_eq!(io.fault(), None);
        assert_eq!(back, thing());
        assert_eq!(back.a.to_bits(), 0.1f32.to_bits());
    }

    #[test]
    fn a_short_buffer_counts_what_it_needs_and_says_so() {
        let mut t = thing();
        let mut buf = vec![0.0; 3];
        let mut io = Io::save(&mut buf);
        t.persist(&mut io);
        assert!(io.overflowed());
        assert_eq!(io.position(), 1 + 1 + 6 + 2 + 1);
    }

    #[test]
    fn a_foreign_state_is_refused_with_the_field_named() {
        let mut t = thing();
        let mut buf = vec![0.0; 64];
        let mut io = Io::save(&mut buf);
        t.persist(&mut io);
        // The list's length above its bound.
        let mut bad = buf.clone();
        bad[1] = 5.0;
        let mut back = Thing::default();
        let mut io = Io::load(&bad);
        back.persist(&mut io);
        assert!(io.fault().unwrap().contains("b = 5"), "{:?}", io.fault());
        assert!(back.b.is_empty(), "a failed read leaves the rest as it was");
        // A flag that is not 0 or 1, an f64 where an f32 was, a short buffer.
        for (at, v) in [(10, 0.5), (0, 0.1f64)] {
            let mut bad = buf.clone();
            bad[at] = v;
            let mut io = Io::load(&bad);
            Thing::default().persist(&mut io);
            assert!(io.fault().is_some(), "value {v} at {at} accepted");
        }
        let mut io = Io::load(&buf[..5]);
        Thing::default().persist(&mut io);
        assert!(io.fault().unwrap().contains("ends after 5"));
    }
}
