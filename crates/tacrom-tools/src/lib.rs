//! The `tacrom` command's library: the press benchmark, training-data generation, the
//! stability suite, the reduced-order model's features for the parity test and the
//! calibration of the `rgb` output's optics, and the fuzz target of that calibration's
//! input. Everything
//! here runs outside MuJoCo and is kept out of the plugin library that MuJoCo loads.
#![warn(missing_docs)]

pub mod bench;
pub mod calibrate;
pub mod cli;
pub mod datagen;
pub mod doc_tables;
pub mod fuzzing;
pub mod npy;
pub mod probe;
pub mod progress;
pub mod rom_features;
pub mod stability;
