//! An indenter that reaches the gel's base is warned about, naming the sensor and the
//! remedies; on a gel that pushes back (`coupling="on"`) the warning also names the physics
//! step, which drives a coupled grasp through the gel where it is too long for the gel's
//! contact, and a light body's joint damping taken after the contact solve, which does too
//! (docs/rl.md, "A long physics step: the fingers' damping, taken after the solve").

use std::sync::Arc;

use nalgebra::Isometry3;
use tacrom::config::{
    Config, RawConfig, ATTR_COUPLING, ATTR_OUTPUTS, ATTR_PHYSICS, ATTR_RESOLUTION, ATTR_SOLVER,
};
use tacrom::geometry::{Placed, Sphere};
use tacrom::sensor::TactileSensor;

/// The warnings of one evaluation of a fresh coarse sensor (the linear gel, 4 mm thick by
/// default) pressed by a 5 mm sphere `depth` (m) into its face, with `coupling`.
fn warnings(coupling: &str, depth: f64) -> Vec<String> {
    let raw = RawConfig::default()
        .with(ATTR_PHYSICS, "coarse")
        .with(ATTR_SOLVER, "linear")
        .with(ATTR_OUTPUTS, "force")
        .with(ATTR_RESOLUTION, "32 24")
        .with(ATTR_COUPLING, coupling);
    let config = Config::from_raw("touch", &raw).expect("valid configuration");
    let mut out = vec![f64::NAN; config.sensordata_len()];
    let mut sensor = TactileSensor::new(config).expect("sensor");
    let r = 5e-3;
    let placed = [Placed {
        shape: Arc::new(Sphere::new(r)),
        pose: Isometry3::translation(0.0, 0.0, r - depth),
    }];
    let eval = sensor.evaluate(&placed, &mut out);
    assert!(out.iter().all(|v| v.is_finite()), "{out:?}");
    eval.warnings
}

fn base_warning(warnings: &[String]) -> Option<&String> {
    warnings
        .iter()
        .find(|w| w.contains("reaches the gel's base"))
}

#[test]
fn an_indenter_through_the_gel_is_warned_about_and_a_coupled_gel_names_the_step() {
    let plain = warnings("off", 4.5e-3);
    let w = base_warning(&plain).unwrap_or_else(|| panic!("no warning: {plain:?}"));
    assert!(w.contains("sensor 'touch'") && w.contains("4.0 mm"), "{w}");
    assert!(w.contains("collision geom under the gel"), "{w}");
    assert!(
        !w.contains("timestep"),
        "a gel that does not push back: {w}"
    );

    let coupled = warnings("on", 4.5e-3);
    let w = base_warning(&coupled).unwrap_or_else(|| panic!("no warning: {coupled:?}"));
    assert!(w.contains("collision geom under the gel"), "{w}");
    assert!(w.contains("smaller timestep"), "{w}");
    assert!(w.contains("joint damping") && w.contains("armature"), "{w}");
}

#[test]
fn a_press_within_the_gel_is_not_warned_about() {
    for coupling in ["off", "on"] {
        let w = warnings(coupling, 1e-3);
        assert!(base_warning(&w).is_none(), "{coupling}: {w:?}");
    }
}
