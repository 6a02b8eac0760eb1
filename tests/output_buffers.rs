//! Every output of the table, physical ones included, follows one rule for its buffers:
//! a copy of a pressed sensor writes what the original writes, a reset sensor and a
//! sensor whose indenter has left write what a fresh sensor writes, whatever the output.
//! An output whose buffer one of those paths forgot (not copied, not cleared) fails here
//! by name, without a test of its own.

use std::sync::Arc;

use nalgebra::Isometry3;
use tacrom::config::{Config, RawConfig, ATTR_OUTPUTS, ATTR_PHYSICS, ATTR_RESOLUTION};
use tacrom::geometry::{Placed, Sphere};
use tacrom::sensor::outputs::TABLE;
use tacrom::sensor::TactileSensor;

const R: f64 = 0.004;

fn ball(x: f64, depth: f64) -> Vec<Placed> {
    vec![Placed {
        shape: Arc::new(Sphere::new(R)),
        pose: Isometry3::translation(x, 0.0, R - depth),
    }]
}

fn config(physics: &str, output: &str) -> Config {
    let raw = RawConfig::default()
        .with(ATTR_PHYSICS, physics)
        .with(ATTR_OUTPUTS, output)
        .with(ATTR_RESOLUTION, "24 18");
    Config::from_raw("touch", &raw).expect("valid configuration")
}

fn eval(sensor: &mut TactileSensor, indenters: &[Placed]) -> Vec<f64> {
    let mut out = vec![f64::NAN; sensor.config().sensordata_len()];
    let _ = sensor.evaluate(indenters, &mut out);
    assert!(out.iter().all(|v| v.is_finite()));
    out
}

#[test]
fn every_outputs_buffer_is_copied_reset_and_cleared_without_contact() {
    for output in TABLE {
        let physics = if output.spec().needs_gel {
            "coarse"
        } else {
            "rigid"
        };
        let name = output.name();
        let fresh = {
            let mut s = TactileSensor::new(config(physics, name)).unwrap();
            eval(&mut s, &[])
        };
        let pressed = || {
            let mut s = TactileSensor::new(config(physics, name)).unwrap();
            let _ = eval(&mut s, &ball(0.0, 0.3e-3));
            let out = eval(&mut s, &ball(0.5e-3, 0.5e-3));
            assert_ne!(out, fresh, "{name}: a press changes the output");
            (s, out)
        };

        // Copied: the copy's next frame is the original's.
        let (mut original, _) = pressed();
        let mut copy = original.try_clone().unwrap();
        let next = ball(0.6e-3, 0.55e-3);
        assert_eq!(
            eval(&mut copy, &next),
            eval(&mut original, &next),
            "{name}: copy"
        );

        // Reset: the flat gel's outputs, as a fresh sensor writes them, before and after
        // its next frame without contact.
        let (mut reset, _) = pressed();
        reset.reset();
        assert_eq!(eval(&mut reset, &[]), fresh, "{name}: reset");

        // The indenter leaves: once the gel has relaxed, the no-contact frame writes the
        // flat gel's outputs.
        let (mut left, _) = pressed();
        let mut last = eval(&mut left, &[]);
        for _ in 0..3 {
            last = eval(&mut left, &[]);
        }
        let peak = fresh
            .iter()
            .chain(&last)
            .fold(0.0f64, |m, v| m.max(v.abs()));
        let worst = fresh
            .iter()
            .zip(&last)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(
            worst <= 1e-9 * peak.max(1.0),
            "{name}: after the indenter left, {worst:e} from the flat gel's outputs"
        );
    }
}
