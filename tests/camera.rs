//! The `camera` and `index` attributes through the sensor (no MuJoCo): the orthographic
//! camera is today's image bit for bit whatever the index; a pinhole camera's depth image
//! is the surface traced along its refracted rays, and its other images are the
//! orthographic ones sampled where those rays meet the surface; without contact every
//! camera shows the same image.
//!
//! Scenes: the default 30 x 30 x 4 mm gel and 24 x 18 mm image, pressed by a sphere of
//! radius 5 mm; the pinhole 10 mm below the gel (rays up to 48 degrees from the vertical at
//! the image's corners with index 1).

mod common;

use std::sync::{Arc, OnceLock};

use nalgebra::Isometry3;
use tacrom::config::{
    Config, RawConfig, ATTR_CAMERA, ATTR_INDEX, ATTR_OUTPUTS, ATTR_PHYSICS, ATTR_RESOLUTION,
};
use tacrom::geometry::{PixelGrid, Placed, Sdf, Sphere};
use tacrom::render::refraction::{Refraction, Sampling};
use tacrom::sensor::TactileSensor;

const R: f64 = 0.005;
const T: f64 = 0.004;
const D: f64 = 0.01;

/// The sphere centred over `(x, y)`, pressed `d` into the undeformed face (one shape for
/// every pose, so that successive solves see one indenter moving).
fn ball(x: f64, y: f64, d: f64) -> Placed {
    static BALL: OnceLock<Arc<dyn Sdf>> = OnceLock::new();
    Placed {
        shape: BALL.get_or_init(|| Arc::new(Sphere::new(R))).clone(),
        pose: Isometry3::translation(x, y, R - d),
    }
}

fn config(physics: &str, outputs: &str, resolution: &str, extra: &[(&str, &str)]) -> Config {
    let raw = extra.iter().fold(
        RawConfig::default()
            .with(ATTR_PHYSICS, physics)
            .with(ATTR_OUTPUTS, outputs)
            .with(ATTR_RESOLUTION, resolution),
        |r, (a, v)| r.with(a, v),
    );
    Config::from_raw("touch", &raw).expect("valid configuration")
}

/// The sensordata of each frame of a sphere pressed and slid off the centre, then lifted.
fn run(config: Config) -> (TactileSensor, Vec<Vec<f64>>) {
    let mut sensor = TactileSensor::new(config.clone()).expect("sensor");
    let frames = [
        vec![ball(1e-3, 0.5e-3, -0.5e-3)],
        vec![ball(1e-3, 0.5e-3, 0.3e-3)],
        vec![ball(1.5e-3, 0.5e-3, 0.6e-3)],
        vec![],
    ];
    let out = frames
        .iter()
        .map(|f| {
            let mut out = vec![f64::NAN; config.sensordata_len()];
            let _ = sensor.evaluate(f, &mut out);
            out
        })
        .collect();
    (sensor, out)
}

/// The values of output `name` in `out`.
fn output<'a>(config: &Config, out: &'a [f64], name: &str) -> &'a [f64] {
    let mut at = 0;
    for o in &config.outputs {
        let n = o.spec().len(&config.layout());
        if o.name() == name {
            return &out[at..at + n];
        }
        at += n;
    }
    panic!("no output {name}");
}

#[test]
fn orthographic_camera_with_any_index_is_the_default_image_bit_for_bit() {
    let all = "depth force contact rgb pressure shear markers";
    let (_, default) = run(config("coarse", all, "64 48", &[]));
    for extra in [
        vec![(ATTR_CAMERA, "orthographic")],
        vec![(ATTR_CAMERA, "orthographic"), (ATTR_INDEX, "1.4")],
        vec![(ATTR_INDEX, "3")],
    ] {
        let (_, other) = run(config("coarse", all, "64 48", &extra));
        for (f, (a, b)) in default.iter().zip(&other).enumerate() {
            // Bit for bit, NaN-free: compare the bit patterns.
            let (a, b): (Vec<u64>, Vec<u64>) = (
                a.iter().map(|v| v.to_bits()).collect(),
                b.iter().map(|v| v.to_bits()).collect(),
            );
            assert!(a == b, "{extra:?}: frame {f} differs");
        }
    }
    // The pressed frames are not trivially equal: the gel is deformed.
    let c = config("coarse", all, "64 48", &[]);
    assert!(output(&c, &default[2], "depth").iter().any(|&d| d > 1e-4));
}

#[test]
fn rigid_sphere_through_a_pinhole_matches_the_closed_form() {
    // The same closed form as the render unit test, now through the sensor: the rigid
    // mode's sphere-traced surface (1e-8 m hits) and the depth rule before the camera.
    let c = config(
        "rigid",
        "depth",
        "320 240",
        &[(ATTR_CAMERA, "pinhole 0.01"), (ATTR_INDEX, "1.4")],
    );
    let g = PixelGrid {
        width: 320,
        height: 240,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    let (px, py) = (g.fov_x / 320.0, g.fov_y / 240.0);
    let mut sensor = TactileSensor::new(c.clone()).expect("sensor");
    let mut out = vec![0.0; c.sensordata_len()];
    let (delta, centre) = (0.6e-3, [-3e-3, 2e-3]);
    let _ = sensor.evaluate(&[ball(centre[0], centre[1], delta)], &mut out);
    let contact = (2.0 * R * delta - delta * delta).sqrt();
    // Tolerance: the bilinear interpolation of the cap between pixel centres, (px^2 +
    // py^2) / 8 times its largest curvature R^2 / (R - delta)^3 (0.41 um), over the ray's
    // slowest climb through the surface 1 - s |g| (s the cap's steepest slope, |g| < 0.7
    // near it: above 0.6); at the rim, where the surface has a kink, s (px + py) / 4 over
    // the same (see render::refraction's tests); plus the rigid surface's 1e-8 m.
    let smooth = (px * px + py * py) / 8.0 * R * R / (R - delta).powi(3);
    let s = contact / (R - delta);
    let climb = 1.0 - s * 0.7;
    let tight = smooth / climb + 2e-8;
    let loose = (s * (px + py) / 4.0) / climb + 2e-8;
    let (mut worst, mut checked) = (0.0f64, 0);
    for row in 0..g.height {
        for col in 0..g.width {
            let (x, y) = (g.x(col), g.y(row));
            let r = x.hypot(y);
            let tb = common::snell_slope(r, T, D, 1.4);
            let gg = [tb * x / r, tb * y / r];
            assert!(gg[0].hypot(gg[1]) < 0.7 || (x - centre[0]).hypot(y - centre[1]) > 4e-3);
            // The refracted ray against the sphere: the larger root of the quadratic.
            let q = [x - centre[0], y - centre[1]];
            let zc = R - delta;
            let a = gg[0] * gg[0] + gg[1] * gg[1] + 1.0;
            let b = 2.0 * (zc - (q[0] * gg[0] + q[1] * gg[1]));
            let cc = q[0] * q[0] + q[1] * q[1] + zc * zc - R * R;
            let disc = b * b - 4.0 * a * cc;
            let expect = if disc < 0.0 {
                0.0
            } else {
                ((-b + disc.sqrt()) / (2.0 * a)).max(0.0)
            };
            let got = out[row * g.width + col];
            let err = (got - expect).abs();
            // Where the ray meets the cap more than a cell diagonal inside its rim, every
            // cell it can be in is smooth.
            let [u, v] = [col as f64 - got * gg[0] / px, row as f64 + got * gg[1] / py];
            let (sx, sy) = (g.x(0) + u * px, g.y(0) - v * py);
            let from_axis = (sx - centre[0]).hypot(sy - centre[1]);
            if from_axis < contact - px.hypot(py) {
                checked += 1;
                worst = worst.max(err);
                assert!(err <= tight, "({row}, {col}): {got} vs {expect}");
            } else {
                assert!(err <= loose, "({row}, {col}): {got} vs {expect}");
            }
        }
    }
    assert!(checked > 2500, "{checked}");
    eprintln!("rigid sphere through the pinhole: worst error {worst:.3e} m (bound {tight:.3e})");
}

#[test]
fn pinhole_images_are_the_orthographic_ones_seen_along_the_rays() {
    let outputs = "depth force contact rgb pressure shear";
    let c_ortho = config("coarse", outputs, "64 48", &[]);
    let c_pin = config(
        "coarse",
        outputs,
        "64 48",
        &[(ATTR_CAMERA, "pinhole 0.01"), (ATTR_INDEX, "1.4")],
    );
    let (ortho_sensor, ortho) = run(c_ortho.clone());
    let (pin_sensor, pin) = run(c_pin.clone());
    let g = *pin_sensor.grid();
    let mut cam = Refraction::new(&g, T, D, 1.4);
    for f in 0..ortho.len() {
        let (o, p) = (&ortho[f], &pin[f]);
        // The same solve: the force does not depend on the camera.
        assert_eq!(output(&c_ortho, o, "force"), output(&c_pin, p, "force"));
        let surface = output(&c_ortho, o, "depth");
        let mut depth = vec![0.0; surface.len()];
        let bent = cam.refract(surface, &mut depth);
        assert_eq!(output(&c_pin, p, "depth"), &depth[..], "frame {f}");
        for (name, channels, sampling) in [
            ("rgb", 3, Sampling::Bilinear),
            ("pressure", 1, Sampling::Bilinear),
            ("shear", 2, Sampling::Bilinear),
            ("contact", 1, Sampling::Nearest),
        ] {
            let mut seen = vec![0.0; channels * depth.len()];
            cam.resample(
                &depth,
                channels,
                sampling,
                output(&c_ortho, o, name),
                &mut seen,
            );
            assert_eq!(output(&c_pin, p, name), &seen[..], "frame {f}: {name}");
            if !bent {
                // Flat gel: every camera shows the same image.
                assert_eq!(output(&c_pin, p, name), output(&c_ortho, o, name));
            }
        }
        let mask = output(&c_pin, p, "contact");
        assert!(mask.iter().all(|&m| m == 0.0 || m == 1.0));
    }
    // The pressed frames differ from the orthographic ones; the frames without contact
    // (first and last) do not.
    let changed = |f: usize| {
        output(&c_ortho, &ortho[f], "depth")
            .iter()
            .zip(output(&c_pin, &pin[f], "depth"))
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    };
    assert!(changed(2) > 1e-5, "{}", changed(2));
    assert_eq!(changed(0), 0.0);
    assert_eq!(ortho[3], pin[3]);
    // The sensor exposes both images.
    assert_eq!(
        pin_sensor.surface_depth(),
        output(&c_ortho, &ortho[3], "depth")
    );
    assert_eq!(ortho_sensor.depth(), ortho_sensor.surface_depth());
}
