//! tacrom: a high-detail tactile sensor for MuJoCo.
//!
//! A rigid object presses a soft gel; the sensor reports the deformed surface as a depth
//! image. `geometry`, `mpm`, `render` and `sensor` are plain Rust and know nothing of
//! MuJoCo; only [`mujoco`] and the C shim in `include/` touch its C API.
#![warn(missing_docs)]
#![warn(clippy::undocumented_unsafe_blocks)]

pub mod bench;
pub mod config;
pub mod datagen;
pub mod geometry;
pub mod mpm;
pub mod mujoco;
pub mod rom;
pub mod sensor;
pub mod stability;
