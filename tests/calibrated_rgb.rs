//! The `rgb` output with calibrated optics (`optics` attribute) through the sensor: the
//! flat gel shows the calibration's background resampled to the sensor's image, exactly;
//! a press changes the image only where the surface is sloped.

use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::Isometry3;
use tacrom::config::{Config, RawConfig, ATTR_OPTICS, ATTR_OUTPUTS, ATTR_PHYSICS, ATTR_RESOLUTION};
use tacrom::geometry::{Placed, Sphere};
use tacrom::render::calibrated::{CalibratedOptics, GradientTable, RgbImage};
use tacrom::sensor::TactileSensor;

/// The background of the calibration: a ramp along each axis, one per channel, on
/// `80 x 60` pixels.
fn ramp(x: f64, y: f64) -> [f64; 3] {
    [40.0 + 2.0 * x, 200.0 - 2.5 * y, 60.0 + x + y]
}

/// Writes an optics file with the [`ramp`] background and a table that adds `(gx, gy)`
/// times 100 to red and green; returns its path.
/// Writes the test's optics file into a folder of its own (`name`): the tests of this file
/// run in parallel in one process.
fn write_optics(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "tacrom-calibrated-rgb-{}-{name}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    let (w, h) = (80, 60);
    let mut data = Vec::new();
    for r in 0..h {
        for c in 0..w {
            data.extend(ramp(c as f64, r as f64));
        }
    }
    let background = RgbImage {
        width: w,
        height: h,
        data,
    };
    let (n, g) = (21, 1.0);
    let mut values = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let (gx, gy) = (-g + 0.1 * i as f64, -g + 0.1 * j as f64);
            values.extend([100.0 * gx, 100.0 * gy, 0.0]);
        }
    }
    let table = GradientTable::new([n, n], [g, g], values).unwrap();
    let path = dir.join("optics.json");
    CalibratedOptics::new(table, background)
        .unwrap()
        .save(&path, None)
        .unwrap();
    path
}

fn sensor(path: &str, width: usize, height: usize) -> (TactileSensor, Config) {
    let raw = RawConfig::default()
        .with(ATTR_PHYSICS, "rigid")
        .with(ATTR_OUTPUTS, "rgb depth")
        .with(ATTR_RESOLUTION, &format!("{width} {height}"))
        .with(ATTR_OPTICS, path);
    let config = Config::from_raw("touch", &raw).unwrap();
    (TactileSensor::new(config.clone()).unwrap(), config)
}

#[test]
fn a_flat_gel_shows_the_calibrated_background_resampled_exactly() {
    let path = write_optics("flat");
    let file = CalibratedOptics::load(&path).unwrap();
    for (w, h) in [(80, 60), (40, 30), (120, 90), (33, 17)] {
        let (mut s, config) = sensor(path.to_str().unwrap(), w, h);
        let mut out = vec![f64::NAN; config.sensordata_len()];
        let _ = s.evaluate(&[], &mut out);
        let rgb = &out[..3 * w * h];
        // Exactly the file's background resampled to the sensor's image.
        assert_eq!(
            rgb,
            &file.background().resampled(w, h).data[..],
            "{w} x {h}"
        );
        // And, independently, the ramp itself wherever the sample point lies between the
        // calibration's pixel centres: bilinear interpolation of a linear function is
        // exact; the 16-bit PNG stores each value to within 1/514 of a grey level.
        let (sx, sy) = (80.0 / w as f64, 60.0 / h as f64);
        let mut checked = 0;
        for r in 0..h {
            for c in 0..w {
                let (x, y) = ((c as f64 + 0.5) * sx - 0.5, (r as f64 + 0.5) * sy - 0.5);
                if !((0.0..=79.0).contains(&x) && (0.0..=59.0).contains(&y)) {
                    continue;
                }
                let want = ramp(x, y);
                for k in 0..3 {
                    let got = rgb[3 * (r * w + c) + k];
                    assert!(
                        (got - want[k]).abs() <= 0.5 / 257.0 + 1e-9,
                        "({r}, {c}) {got}"
                    );
                }
                checked += 1;
            }
        }
        assert!(checked > w * h / 2, "{checked}");
    }
}

#[test]
fn a_press_changes_the_calibrated_image_only_where_the_surface_is_sloped() {
    let path = write_optics("press");
    let (w, h) = (64, 48);
    let (mut s, config) = sensor(path.to_str().unwrap(), w, h);
    let background = s.config().optics.as_ref().unwrap().background().clone();
    let mut out = vec![0.0; config.sensordata_len()];
    // A 5 mm sphere 0.5 mm deep, off centre towards +x.
    let placed = [Placed {
        shape: Arc::new(Sphere::new(5e-3)),
        pose: Isometry3::translation(2e-3, 0.0, 5e-3 - 0.5e-3),
    }];
    let _ = s.evaluate(&placed, &mut out);
    let (rgb, depth) = out.split_at(3 * w * h);
    let mut sloped = 0;
    for r in 0..h {
        for c in 0..w {
            let d = |rr: usize, cc: usize| depth[rr.min(h - 1) * w + cc.min(w - 1)];
            let flat = [
                (r, c),
                (r.saturating_sub(1), c),
                (r + 1, c),
                (r, c.saturating_sub(1)),
                (r, c + 1),
            ]
            .iter()
            .all(|&(rr, cc)| d(rr, cc) == 0.0);
            let px = &rgb[3 * (r * w + c)..3 * (r * w + c + 1)];
            let bg = background.pixel(r, c);
            if flat {
                assert_eq!(px, bg, "({r}, {c})");
            } else if px[0] != bg[0] || px[1] != bg[1] {
                sloped += 1;
                // Blue has no change in the table.
                assert_eq!(px[2], bg[2]);
            }
        }
    }
    // The contact (radius 2.2 mm, 5.9 px) is sloped nearly everywhere.
    assert!(sloped > 80, "{sloped}");
    // On the dent's +x side the depth falls towards +x (gx < 0): red, 100 gx, darkens.
    let (r0, c0) = (h / 2, (w as f64 / 2.0 + 2e-3 / 0.375e-3 + 3.0) as usize);
    let px = &rgb[3 * (r0 * w + c0)..];
    assert!(px[0] < background.pixel(r0, c0)[0] - 10.0, "{:?}", &px[..3]);
}
