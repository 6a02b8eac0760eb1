//! A sensor's frames allocate nothing once its buffers have grown: the linear gel's
//! contact solve (its dense systems made and updated at every frame of a moving press,
//! friction's anchors, the indenters' matching and sweep) keeps every vector and matrix
//! between frames. Counted by this test binary's global allocator on the evaluating thread
//! alone, in the release-like build the plugin ships (`cfg(test)` code of the library is
//! not compiled here). The learned decoder's modes are left out: `ort`'s session run
//! allocates its inputs' and outputs' lists at every run by design (`cargo bench --bench
//! allocations` counts them).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::Arc;

use nalgebra::{Isometry3, Vector3};
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{Cuboid, Placed, Sdf, Sphere};
use tacrom::sensor::TactileSensor;

struct Counting;

thread_local! {
    /// Whether this thread's allocations are counted, and how many were.
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static CALLS: Cell<usize> = const { Cell::new(0) };
}

fn count() {
    if COUNTING.with(Cell::get) {
        CALLS.with(|c| c.set(c.get() + 1));
    }
}

// SAFETY: every call is forwarded to the system allocator unchanged; the count touches
// const-initialised thread locals only, which do not allocate.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: the caller's layout, as `GlobalAlloc::alloc` takes it.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `alloc` or `realloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: as `GlobalAlloc::realloc` takes them.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// The allocations `f` makes on this thread.
fn allocations<R>(f: impl FnOnce() -> R) -> (R, usize) {
    CALLS.with(|c| c.set(0));
    COUNTING.with(|c| c.set(true));
    let r = f();
    COUNTING.with(|c| c.set(false));
    (r, CALLS.with(Cell::get))
}

fn linear_sensor(friction: &str) -> (TactileSensor, Vec<f64>) {
    let raw = RawConfig::default()
        .with("friction", friction)
        .with("physics", "coarse")
        .with("solver", "linear")
        .with("resolution", "64 48")
        .with("outputs", "depth force");
    let config = Config::from_raw("steady", &raw).expect("config");
    let out = vec![0.0; config.sensordata_len()];
    (TactileSensor::new(config).expect("sensor"), out)
}

/// Runs `frames` poses through a fresh linear sensor three times over (the buffers grow to
/// the largest contact of the path), then once more counting: the allocations of each
/// counted frame, and the force of the last.
fn counted_path(
    shape: Arc<dyn Sdf>,
    poses: &[Isometry3<f64>],
    friction: &str,
) -> (Vec<usize>, f64) {
    let (mut sensor, mut out) = linear_sensor(friction);
    let mut evaluate = |pose: &Isometry3<f64>| {
        let placed = [Placed {
            shape: shape.clone(),
            pose: *pose,
        }];
        allocations(|| {
            let _ = sensor.evaluate(&placed, &mut out);
        })
        .1
    };
    for _ in 0..3 {
        poses.iter().for_each(|p| {
            evaluate(p);
        });
    }
    let counted = poses.iter().map(&mut evaluate).collect();
    // The force output follows the image (`depth` then `force`: x, y, z).
    let n = out.len();
    (counted, out[n - 1])
}

/// A 5 mm sphere pressed 0.5 mm and slid 4 mm along x and back over 40 frames (the
/// contact's node columns change at every frame, its systems updated or made afresh):
/// and lifted clear for the last frames (the gel back at rest, and its next contact's
/// first frame solved without friction first): every frame of the fourth pass allocates
/// nothing, with friction (0.5) and without.
#[test]
fn a_sliding_press_allocates_nothing_once_grown() {
    let ball: Arc<dyn Sdf> = Arc::new(Sphere::new(0.005));
    let mut poses: Vec<Isometry3<f64>> = (0..40)
        .map(|k| {
            let s = (std::f64::consts::PI * k as f64 / 20.0).sin();
            Isometry3::translation(2e-3 * s, 0.0, 0.005 - 0.5e-3)
        })
        .collect();
    poses.extend((0..3).map(|_| Isometry3::translation(0.0, 0.0, 0.008)));
    for friction in ["0.5", "0"] {
        let (counted, _) = counted_path(ball.clone(), &poses, friction);
        assert!(
            counted.iter().all(|&c| c == 0),
            "friction {friction}, allocations per frame: {counted:?}"
        );
    }
}

/// A 24 mm box face pressed 0.3 mm (a contact over most of the gel, split first and
/// preconditioned) and shaken by microns as a held grasp trembles: nothing allocated in
/// the fourth pass, and the face carries a force (the path ran the solve).
#[test]
fn a_held_face_allocates_nothing_once_grown() {
    let face: Arc<dyn Sdf> = Arc::new(Cuboid::new(Vector3::new(0.012, 0.012, 0.005)));
    let poses: Vec<Isometry3<f64>> = (0..20)
        .map(|k| {
            let f = k as f64;
            let (x, z) = (2e-6 * (0.7 * f).sin(), 0.5e-6 * (1.3 * f).cos());
            Isometry3::translation(x, 0.0, 0.005 - 0.3e-3 + z)
        })
        .collect();
    let (counted, force) = counted_path(face, &poses, "0.5");
    assert!(force.abs() > 0.1, "force {force} N");
    assert!(
        counted.iter().all(|&c| c == 0),
        "allocations per frame: {counted:?}"
    );
}
