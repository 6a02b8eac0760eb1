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
use tacrom::mpm::hertz::hertz_bonded;
use tacrom::mpm::{Gel, GelParams, Solver, SolverOptions};
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
/// inside the sphere; a compass search from it finds the axis, 0.3 mm inside) and the
/// remedies. The linear solver's finer contact lattice loads the gel: a force and no
/// warning.
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
        w.contains("'touch'") && w.contains("solver=\"linear\"") && w.contains("'dx'"),
        "{w}"
    );
    let reach: f64 = w
        .split("at least ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no depth in {w}"));
    assert!((0.25..=0.3).contains(&reach), "{w}");
    let (force, warnings) = press(Some("linear"), &small);
    assert!(force > 0.0, "{warnings:?}");
    assert!(warnings.is_empty(), "{warnings:?}");
}

/// With no solver named, the coarse sensor solves a frame whose contact the relaxation
/// misses by the linear solver (`SolverOptions::fallback`): the 0.5 mm sphere
/// pressed 0.3 mm gets the force of a sensor that names it, within 10 % of Hertz's on the
/// bonded layer (its small-contact model; measured 1.01), and no warning. A contact the
/// relaxation carries keeps the relaxation's force.
#[test]
fn the_default_coarse_sensor_solves_a_missed_contact_by_the_linear_solver() {
    let small = sphere(0.5e-3, 0.3e-3);
    let (force, warnings) = press(None, &small);
    let (linear, _) = press(Some("linear"), &small);
    assert!(force > 0.0, "{warnings:?}");
    assert!(warnings.is_empty(), "{warnings:?}");
    assert!(
        (force - linear).abs() <= 1e-9 * linear,
        "{force} against {linear}"
    );
    let p = GelParams::default();
    let hertz = hertz_bonded(p.young, p.poisson, 0.5e-3, 0.3e-3, p.size[2]);
    assert!(
        (force / hertz - 1.0).abs() < 0.1,
        "{force} N against Hertz's {hertz}"
    );
    let big = sphere(5e-3, 0.3e-3);
    assert_eq!(press(None, &big).0, press(Some("relaxation"), &big).0);
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

/// The fallback through a sequence: a 0.5 mm sphere pressed 0.1 to 0.4 mm, each frame
/// missed by the relaxation, gives the forces of a linear gel pressed the same way
/// (the fallback's state carries on from frame to frame); a 5 mm sphere 10 mm away is the
/// relaxation's own frame; the small sphere after it starts the linear solver afresh, as
/// on a new gel.
#[test]
fn the_fallback_follows_a_press_and_starts_afresh_after_the_relaxation() {
    let params = GelParams {
        friction: 0.0,
        ..Default::default()
    };
    let fallback = SolverOptions {
        fallback: true,
        ..Default::default()
    };
    let linear = SolverOptions {
        solver: Solver::Linear,
        ..Default::default()
    };
    let mut g = Gel::new(params, fallback).unwrap();
    let mut n = Gel::new(params, linear).unwrap();
    for d in [0.1e-3, 0.2e-3, 0.3e-3, 0.4e-3] {
        let rep = g.solve(&sphere(0.5e-3, d));
        n.solve(&sphere(0.5e-3, d));
        assert!(rep.fallback && rep.converged, "{rep:?}");
        let (a, b) = (g.force().z, n.force().z);
        assert!(a > 0.0 && (a - b).abs() <= 1e-9 * b, "{d}: {a} against {b}");
    }
    let far = [Placed {
        shape: Arc::new(Sphere::new(5e-3)),
        pose: Isometry3::translation(10e-3, 0.0, 5e-3 - 0.3e-3),
    }];
    let rep = g.solve(&far);
    assert!(!rep.fallback && g.force().z > 0.0, "{rep:?}");
    let mut fresh = Gel::new(params, linear).unwrap();
    let rep = g.solve(&sphere(0.5e-3, 0.2e-3));
    fresh.solve(&sphere(0.5e-3, 0.2e-3));
    assert!(rep.fallback, "{rep:?}");
    let (a, b) = (g.force().z, fresh.force().z);
    assert!((a - b).abs() <= 1e-9 * b, "{a} against {b}");
}
