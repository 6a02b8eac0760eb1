//! Heap allocations per sensor evaluation in steady state: a sphere (R 5 mm) slid along x
//! while pressed 0.5 mm, at 64 x 48 (`tacrom/Press-v1`'s images) and 320 x 240, per
//! physics mode, and a 24 mm box face pressed 0.3 mm and shaken by a few microns (a held
//! grasp's contact over most of the gel) at 64 x 48; the path's 60 frames run once to warm
//! up (the gel, its caches and buffers, ONNX Runtime's buffers), then again counted.
//! Counts every call of the global allocator (`alloc`, `realloc`) in this process, ONNX
//! Runtime's own allocations through the C library excluded.
//!
//! `cargo bench --bench allocations`; `TACROM_ALLOCATION_SITES=MODE cargo bench --bench
//! allocations` also prints, for that mode's counted frames, the functions of the plugin
//! that allocate (the innermost `tacrom::` frame of each allocation's backtrace), with
//! their calls and bytes per frame (`TACROM_ALLOCATION_LINES=1` as well: with the
//! allocating source line of each).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use nalgebra::Isometry3;
use nalgebra::Vector3;
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{Cuboid, Placed, Sdf, Sphere};
use tacrom::sensor::TactileSensor;

/// The system allocator, counting calls and bytes.
struct Counting;

static CALLS: AtomicUsize = AtomicUsize::new(0);
static BYTES: AtomicUsize = AtomicUsize::new(0);
/// Whether allocations' backtraces are being gathered ([`SITES`]).
static TRACING: AtomicBool = AtomicBool::new(false);
/// Raw backtraces of the traced allocations, with their sizes (resolved after the frames).
static SITES: Mutex<Vec<(std::backtrace::Backtrace, usize)>> = Mutex::new(Vec::new());

thread_local! {
    /// Set while this thread records a backtrace: its own allocations are not traced.
    static INSIDE: Cell<bool> = const { Cell::new(false) };
}

fn count(bytes: usize) {
    if !TRACING.load(Ordering::Relaxed) {
        CALLS.fetch_add(1, Ordering::Relaxed);
        BYTES.fetch_add(bytes, Ordering::Relaxed);
        return;
    }
    // The recording's own allocations are neither counted nor traced.
    if INSIDE.with(|i| i.replace(true)) {
        return;
    }
    CALLS.fetch_add(1, Ordering::Relaxed);
    BYTES.fetch_add(bytes, Ordering::Relaxed);
    let trace = std::backtrace::Backtrace::force_capture();
    SITES.lock().unwrap().push((trace, bytes));
    INSIDE.with(|i| i.set(false));
}

/// The traced allocations by the innermost plugin function in their backtraces: calls
/// and bytes per frame over `frames`, largest first.
fn print_sites(frames: usize) {
    let mut by: HashMap<String, (usize, usize)> = HashMap::new();
    for (trace, bytes) in SITES.lock().unwrap().drain(..) {
        let text = trace.to_string();
        let lines: Vec<&str> = text.lines().map(str::trim).collect();
        let innermost = lines.iter().enumerate().find_map(|(n, l)| {
            let (_, f) = l.split_once(": ")?;
            (f.starts_with("tacrom::") || f.starts_with("<tacrom::")).then_some((n, f))
        });
        let site = match innermost {
            None => "(outside the plugin)".to_owned(),
            // With `TACROM_ALLOCATION_LINES`, the function's source line too.
            Some((n, f)) => match lines.get(n + 1).and_then(|l| l.strip_prefix("at ")) {
                Some(at) if std::env::var_os("TACROM_ALLOCATION_LINES").is_some() => {
                    let at = at.rsplit_once("/src/").map_or(at, |(_, tail)| tail);
                    format!("{f} ({at})")
                }
                _ => f.to_owned(),
            },
        };
        let e = by.entry(site).or_default();
        e.0 += 1;
        e.1 += bytes;
    }
    let mut rows: Vec<_> = by.into_iter().collect();
    rows.sort_by(|a, b| b.1 .1.cmp(&a.1 .1));
    for (site, (calls, bytes)) in rows {
        println!(
            "    {:>8.1} calls {:>9.1} KiB  {site}",
            calls as f64 / frames as f64,
            bytes as f64 / frames as f64 / 1024.0
        );
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count(layout.size());
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Frames of the path; it is run once to warm up, then again counted.
const PATH: usize = 60;
const WARM: usize = PATH;
const COUNTED: usize = PATH;

fn main() {
    let modes: [(&str, &[(&str, &str)]); 5] = [
        ("rigid", &[("physics", "rigid")]),
        ("coarse", &[("physics", "coarse")]),
        (
            "coarse-linear",
            &[("physics", "coarse"), ("solver", "linear")],
        ),
        ("rom (default)", &[("physics", "rom")]),
        (
            "rom-default",
            &[("physics", "rom"), ("model", "rom-default")],
        ),
    ];
    println!(
        "{:<14} {:>9} {:>16} {:>16}",
        "mode", "image", "allocations/frame", "KiB/frame"
    );
    let ball: Arc<dyn Sdf> = Arc::new(Sphere::new(0.005));
    let face: Arc<dyn Sdf> = Arc::new(Cuboid::new(Vector3::new(0.012, 0.012, 0.005)));
    let traced = std::env::var("TACROM_ALLOCATION_SITES").ok();
    for (label, attributes) in modes {
        let trace = traced.as_deref() == Some(label.split(' ').next().unwrap_or(label));
        for (resolution, grasp) in [("64 48", false), ("320 240", false), ("64 48", true)] {
            if grasp && !matches!(attributes.first(), Some(&(_, "coarse")) | Some(&(_, "rom"))) {
                continue;
            }
            let mut raw = RawConfig::default()
                .with("resolution", resolution)
                .with("outputs", "depth");
            for (a, v) in attributes {
                raw = raw.with(a, v);
            }
            let config = Config::from_raw("bench", &raw).expect("config");
            let mut sensor = TactileSensor::new(config.clone()).expect("sensor");
            let mut out = vec![0.0; config.sensordata_len()];
            let mut counted = (0, 0);
            for frame in 0..WARM + COUNTED {
                let placed = [if grasp {
                    // Shaken as a simulated grasp holds it: microns along the face and
                    // into it.
                    let f = (frame % PATH) as f64;
                    let (x, z) = (2e-6 * (0.7 * f).sin(), 0.5e-6 * (1.3 * f).cos());
                    Placed {
                        shape: face.clone(),
                        pose: Isometry3::translation(x, 0.0, 0.005 - 0.3e-3 + z),
                    }
                } else {
                    let x = -2e-3 + 4e-3 * (frame % PATH) as f64 / PATH as f64;
                    Placed {
                        shape: ball.clone(),
                        pose: Isometry3::translation(x, 0.0, 0.005 - 0.5e-3),
                    }
                }];
                let (calls, bytes) = (CALLS.load(Ordering::Relaxed), BYTES.load(Ordering::Relaxed));
                TRACING.store(trace && frame >= WARM, Ordering::Relaxed);
                let _ = sensor.evaluate(&placed, &mut out);
                TRACING.store(false, Ordering::Relaxed);
                if frame >= WARM {
                    counted.0 += CALLS.load(Ordering::Relaxed) - calls;
                    counted.1 += BYTES.load(Ordering::Relaxed) - bytes;
                }
            }
            let case = match grasp {
                true => "box 64x48".to_owned(),
                false => resolution.replace(' ', "x"),
            };
            println!(
                "{label:<14} {:>9} {:>16.0} {:>16.1}",
                case,
                counted.0 as f64 / COUNTED as f64,
                counted.1 as f64 / COUNTED as f64 / 1024.0
            );
            if trace {
                print_sites(COUNTED);
            }
        }
    }
}
