//! `physics="rom"` through the sensor: the default model is found, its output is a sensible
//! depth image, and a gel other than the model's is refused at load with a clear message.

use std::sync::Arc;

use nalgebra::Isometry3;
use tacrom::config::{Config, RawConfig, ATTR_MODEL, ATTR_PHYSICS, ATTR_RESOLUTION, ATTR_SIZE};
use tacrom::geometry::{Placed, Sphere};
use tacrom::sensor::TactileSensor;

#[test]
fn rom_is_the_default_physics_and_presses_a_sphere() {
    let config = Config::from_raw(
        "touch",
        &RawConfig::default().with(ATTR_RESOLUTION, "160 120"),
    )
    .unwrap();
    assert_eq!(config.physics.name(), "rom");
    let mut sensor = TactileSensor::new(config).unwrap();
    let placed = [Placed {
        shape: Arc::new(Sphere::new(0.005)),
        pose: Isometry3::translation(0.0, 0.0, 0.005 - 0.5e-3),
    }];
    let mut out = vec![0.0; 160 * 120];
    let eval = sensor.evaluate(&placed, &mut out);
    assert!(eval.rom.is_some(), "{:?}", eval.warnings);
    let peak = out.iter().cloned().fold(0.0, f64::max);
    assert!((peak - 0.5e-3).abs() < 0.05e-3, "peak {peak}");
    assert!(out.iter().all(|d| d.is_finite() && *d >= 0.0));
}

#[test]
fn a_gel_other_than_the_models_is_refused() {
    let raw = RawConfig::default()
        .with(ATTR_PHYSICS, "rom")
        .with(ATTR_SIZE, "0.03 0.03 0.005");
    let e = TactileSensor::new(Config::from_raw("touch", &raw).unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("'touch'") && e.contains("'model'") && e.contains("gel size"),
        "{e}"
    );
    let raw = RawConfig::default().with(ATTR_MODEL, "/no/such/model");
    let e = TactileSensor::new(Config::from_raw("touch", &raw).unwrap())
        .unwrap_err()
        .to_string();
    assert!(e.contains("/no/such/model"), "{e}");
}
