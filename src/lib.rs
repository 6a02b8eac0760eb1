//! tacrom: a high-detail tactile sensor for MuJoCo.
//!
//! A rigid object presses a soft gel; the sensor reports the deformed surface as a depth
//! image. `geometry`, `mpm`, `render`, `sensor` and `visual` (what the viewer draws) are
//! plain Rust and know nothing of MuJoCo; only [`mujoco`] and the C shim in `include/`
//! touch its C API.
#![warn(missing_docs)]
#![warn(clippy::undocumented_unsafe_blocks)]
// `!(x > 0.0)` is how this crate says "not positive, or NaN": the negation is the point.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod attributes;
pub mod config;
pub mod fuzzing;
pub mod geometry;
pub mod mpm;
pub mod mujoco;
pub mod render;
pub mod rom;
pub mod scratch;
pub mod sensor;
pub mod sensor_file;
pub mod state;
pub mod visual;

/// Hands the heap's free pages back to the operating system (glibc's `malloc_trim`), so
/// that the resident set holds what the process still uses, not what it freed; elsewhere
/// nothing.
pub fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        extern "C" {
            fn malloc_trim(pad: usize) -> std::ffi::c_int;
        }
        // SAFETY: malloc_trim takes no pointer; it only returns free heap pages.
        unsafe {
            malloc_trim(0);
        }
    }
}

/// The root of the source checkout this library was built from (this crate's folder, the
/// workspace's root). Tests and tools find the checkout's `.venv`, `models/` and the
/// benchmark meshes in `../shared` through it; an installed plugin looks beside itself
/// first.
pub fn checkout_root() -> &'static std::path::Path {
    static ROOT: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();
    ROOT.get_or_init(|| std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")))
}

/// The shipped folder `kind/name` (`models/rom-linear`, `sensors/gelsight-mini`) that
/// holds `file`: looked for beside the plugin library first, walking up from its folder
/// (an installed wheel keeps `tacrom/models` and `tacrom/sensors` above `tacrom/_lib`),
/// then in the checkout it was built from.
pub fn shipped_dir(kind: &str, name: &str, file: &str) -> Option<std::path::PathBuf> {
    let mut candidates = Vec::new();
    if let Some(lib) = rom::runtime::own_library_path() {
        for dir in lib.ancestors().skip(1).take(4) {
            candidates.push(dir.join(kind).join(name));
        }
    }
    candidates.push(checkout_root().join(kind).join(name));
    candidates.into_iter().find(|d| d.join(file).is_file())
}

/// The benchmark meshes (`../shared/indenters/patterns` beside the checkout) when present,
/// otherwise the copies of the few that the tests and the quick benchmark use
/// (`tests/data`: cone, cross_lines, dots, hexagon, moon, wave1; MIT, see
/// the LICENSE there).
pub fn pattern_dir() -> std::path::PathBuf {
    let shared = checkout_root().join("../shared/indenters/patterns");
    if shared.is_dir() {
        shared
    } else {
        vendored_patterns()
    }
}

/// The copies of the benchmark meshes the tests use, always present in the checkout.
pub fn vendored_patterns() -> std::path::PathBuf {
    checkout_root().join("tests/data")
}

/// A fingerprint of the physics' source (solver, geometry, sensor), computed at build time:
/// results cached or trained with one build are recognised as stale by another whose
/// physics differs.
pub const PHYSICS_FINGERPRINT: &str = env!("TACROM_PHYSICS_FINGERPRINT");

/// The fingerprint of the sources a gel solved by dynamic relaxation alone runs (all of
/// the physics but the other solvers and the unit tests): what a relaxation result
/// depends on ([`config::Config::physics_fingerprint`]).
pub const RELAXATION_FINGERPRINT: &str = env!("TACROM_RELAXATION_FINGERPRINT");

/// A reproducible stream of uniform numbers in `[0, 1)` from `seed` (a linear congruential
/// generator, 53 bits of its state), for tests that draw random cases.
#[cfg(test)]
pub(crate) fn test_uniform(mut seed: u64) -> impl FnMut() -> f64 {
    move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    }
}
