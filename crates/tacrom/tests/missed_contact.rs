//! A contact smaller than the gel resolves is not silently lost: when an indenter reaches
//! into the gel only between the solver's contact points, the gel carries no force and
//! the sensor says so, naming the sensor, how deep the indenter reaches, the spacing and
//! what to change. A contact the gel does resolve gives no such warning.

use std::sync::Arc;

use nalgebra::Isometry3;
use tacrom::config::{
    Config, RawConfig, ATTR_FRICTION, ATTR_OUTPUTS, ATTR_PHYSICS, ATTR_RESOLUTION, ATTR_SOLVER,
};
use tacrom::geometry::{Placed, Sphere};
use tacrom::mpm::{Gel, GelParams, SolverOptions};
use tacrom::sensor::TactileSensor;

/// A sphere of radius `r` over the origin pressed `d` into the undeformed face.
fn sphere(r: f64, d: f64) -> [Placed; 1] {
    [Placed {
        shape: Arc::new(Sphere::new(r)),
        pose: Isometry3::translation(0.0, 0.0, r - d),
    }]
}

/// The force and the warnings of one evaluation of a fresh coarse sensor.
fn press(solver: Option<&str>, placed: &[Placed]) -> (f64, Vec<String>) {
    let mut raw = RawConfig::default()
        .with(ATTR_PHYSICS, "coarse")
        .with(ATTR_OUTPUTS, "force")
        .with(ATTR_RESOLUTION, "32 24")
        .with(ATTR_FRICTION, "0");
    if let Some(s) = solver {
        raw = raw.with(ATTR_SOLVER, s);
    }
    let config = Config::from_raw("touch", &raw).expect("valid configuration");
    let mut out = vec![f64::NAN; config.sensordata_len()];
    let mut sensor = TactileSensor::new(config).expect("sensor");
    let eval = sensor.evaluate(placed, &mut out);
    (out[2], eval.warnings)
}

/// A sphere of radius 0.5 mm pressed 0.3 mm into the coarse gel reaches between its top
/// particles (0.7 mm apart): relaxation gives no force and the sensor warns, naming the
/// sensor, the depth it reaches (a lower bound: the signed distance at the sampled points
/// of the top face, 0.17 mm apart; the nearest to the axis, 0.12 mm off it, is 0.268 mm
/// inside the sphere) and the remedies. Newton's finer contact lattice loads the gel: a force and no warning.
#[test]
fn a_contact_between_the_contact_points_warns() {
    let small = sphere(0.5e-3, 0.3e-3);
    let (force, warnings) = press(Some("relaxation"), &small);
    assert_eq!(force, 0.0, "{warnings:?}");
    let w = warnings
        .iter()
        .find(|w| w.contains("between its contact points"))
        .unwrap_or_else(|| panic!("no warning: {warnings:?}"));
    assert!(
        w.contains("'touch'") && w.contains("newton") && w.contains("'dx'"),
        "{w}"
    );
    let reach: f64 = w
        .split("at least ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no depth in {w}"));
    assert!((0.25..=0.3).contains(&reach), "{w}");
    let (force, warnings) = press(Some("newton"), &small);
    assert!(force > 0.0, "{warnings:?}");
    assert!(warnings.is_empty(), "{warnings:?}");
}

/// A 5 mm sphere pressed 0.3 mm meets the particles: a force and no warning. Pressed
/// 0.02 mm over the middle of four top particles (0.714 mm apart), it touches none of
/// them (it would need `s^2 / 4R` = 0.026 mm): no force, but a body this large only grazes
/// the gel there, and the sensor stays silent.
#[test]
fn a_resolved_or_grazing_contact_does_not_warn() {
    let (force, warnings) = press(None, &sphere(5e-3, 0.3e-3));
    assert!(force > 0.0);
    assert!(warnings.is_empty(), "{warnings:?}");
    let (force, warnings) = press(None, &sphere(5e-3, 0.02e-3));
    assert_eq!(force, 0.0);
    assert!(warnings.is_empty(), "{warnings:?}");
}

/// The gel's own measure: zero once it carries a force or when nothing reaches in, and
/// close to the depth when a contact falls between the particles.
#[test]
fn unloaded_penetration_measures_only_missed_contacts() {
    let mut g = Gel::new(GelParams::default(), SolverOptions::default()).unwrap();
    let above = sphere(0.5e-3, -0.1e-3);
    g.solve(&above);
    assert_eq!(g.unloaded_penetration(&above), 0.0);
    let small = sphere(0.5e-3, 0.3e-3);
    g.solve(&small);
    let missed = g.unloaded_penetration(&small);
    assert!((0.25e-3..=0.3e-3).contains(&missed), "{missed}");
    let big = sphere(5e-3, 0.3e-3);
    g.solve(&big);
    assert!(g.force().z > 0.0);
    assert_eq!(g.unloaded_penetration(&big), 0.0);
}
