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
    Config::from_raw("touch", &raw(physics, output)).expect("valid configuration")
}

/// The attributes of [`config`].
fn raw(physics: &str, output: &str) -> RawConfig {
    RawConfig::default()
        .with(ATTR_PHYSICS, physics)
        .with(ATTR_OUTPUTS, output)
        .with(ATTR_RESOLUTION, "24 18")
}

/// The physics an output is tested with: the least that computes it.
fn physics_for(output: tacrom::sensor::outputs::Output) -> &'static str {
    if output.spec().needs_gel {
        "coarse"
    } else {
        "rigid"
    }
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
        let physics = physics_for(output);
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

/// `view="camera"` mirrors every image output left-right, exactly, and the markers'
/// columns with it; vectors (force) and the markers' displacements are the gel's, the same
/// in both views. Pressed off-centre, so that the mirror is not the image itself.
#[test]
fn the_camera_view_mirrors_every_image_and_nothing_else() {
    use tacrom::config::ATTR_VIEW;
    use tacrom::sensor::outputs::Shape;
    let (w, h) = (24, 18);
    for output in TABLE {
        let physics = physics_for(output);
        let name = output.name();
        let run = |view: &str| {
            let raw = raw(physics, name).with(ATTR_VIEW, view);
            let mut s = TactileSensor::new(Config::from_raw("touch", &raw).unwrap()).unwrap();
            eval(&mut s, &ball(2.5e-3, 0.4e-3))
        };
        let (indenter, camera) = (run("indenter"), run("camera"));
        match output.spec().shape {
            Shape::Image { channels } => {
                assert_ne!(
                    indenter, camera,
                    "{name}: an off-centre press is not symmetric"
                );
                for r in 0..h {
                    for c in 0..w {
                        for k in 0..channels {
                            let a = indenter[(r * w + c) * channels + k];
                            let b = camera[(r * w + (w - 1 - c)) * channels + k];
                            assert_eq!(a, b, "{name}: pixel ({r}, {c}) channel {k}");
                        }
                    }
                }
            }
            Shape::PerMarker(n) => {
                for (a, b) in indenter.chunks_exact(n).zip(camera.chunks_exact(n)) {
                    // Mirrored by one subtraction: equal to its rounding.
                    let mirrored = (w - 1) as f64 - b[0];
                    assert!(
                        (a[0] - mirrored).abs() < 1e-12,
                        "{name}: the marker's column"
                    );
                    assert_eq!(a[1..], b[1..], "{name}: its row and displacement");
                }
            }
            Shape::Vector(_) => assert_eq!(indenter, camera, "{name}"),
        }
    }
}
