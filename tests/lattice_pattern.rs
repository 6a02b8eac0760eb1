//! At a GelSight Mini's pixel (0.0295 mm), the depth image shows no preference for the
//! lines of the reduced-order model's 0.3 mm lattice: its slope changes, folded by the
//! pixel's position modulo the lattice pitch into 12 phase bins, are as large in the
//! worst bin as within twice the median bin's. A surface interpolated linearly between
//! lattice points keeps its slope within a lattice cell and changes it at the lines (the
//! rgb image then shows the lattice as blocks); the coarse gel, which has no such lattice,
//! gives a ratio near 1. Measured outside the contact, where the surface is the model's
//! own (inside it the depth rule gives the indenter's shape).

use std::sync::Arc;

use nalgebra::{Isometry3, Vector3};
use tacrom::config::{
    Config, RawConfig, ATTR_FOV, ATTR_MODEL, ATTR_PHYSICS, ATTR_RESOLUTION, ATTR_SOLVER,
};
use tacrom::geometry::{Ellipsoid, Placed, Sdf, Sphere};
use tacrom::sensor::TactileSensor;

/// The Mini's pixel (m).
const PIXEL: f64 = 0.0295e-3;
/// Image size (pixels): 7.1 x 5.3 mm around the press.
const WIDTH: usize = 240;
const HEIGHT: usize = 180;
/// The shipped models' lattice: 100 points over 30 mm, the first at half a pitch from the
/// gel's edge (`models/*/manifest.json`, `lattice`).
const PITCH: f64 = 0.3e-3;
const HALF_GEL: f64 = 15e-3;
const BINS: usize = 12;
/// Pixels shallower than this (m) are the undeformed gel, left out.
const DEFORMED: f64 = 1e-6;

/// Phase bin of coordinate `x` (m, sensor frame) relative to the lattice lines.
fn bin(x: f64) -> usize {
    let phase = ((x + HALF_GEL) / PITCH - 0.5).rem_euclid(1.0);
    ((phase * BINS as f64) as usize).min(BINS - 1)
}

/// Adds the slope changes of the depth image `d` on the sensor's grid, at the pixels
/// `free` of contact, to the phase bins' sums and counts.
fn fold(
    d: &[f64],
    free: &[bool],
    x: impl Fn(usize) -> f64,
    y: impl Fn(usize) -> f64,
    sum: &mut [f64; BINS],
    count: &mut [usize; BINS],
) {
    let at = |r: usize, c: usize| d[r * WIDTH + c];
    for r in 1..HEIGHT - 1 {
        for c in 1..WIDTH - 1 {
            if !free[r * WIDTH + c] || at(r, c) < DEFORMED {
                continue;
            }
            let sx = (at(r, c + 1) - 2.0 * at(r, c) + at(r, c - 1)).abs();
            let sy = (at(r + 1, c) - 2.0 * at(r, c) + at(r - 1, c)).abs();
            sum[bin(x(c))] += sx;
            count[bin(x(c))] += 1;
            sum[bin(y(r))] += sy;
            count[bin(y(r))] += 1;
        }
    }
}

/// The worst phase bin's mean slope change over the median bin's.
fn worst_over_median(sum: &[f64; BINS], count: &[usize; BINS]) -> f64 {
    assert!(
        count.iter().all(|&n| n > 100),
        "too few deformed pixels: {count:?}"
    );
    let mut means: Vec<f64> = sum.iter().zip(count).map(|(s, &n)| s / n as f64).collect();
    let worst = means.iter().cloned().fold(0.0, f64::max);
    means.sort_by(f64::total_cmp);
    worst / (0.5 * (means[BINS / 2 - 1] + means[BINS / 2]))
}

/// The ratio of `physics` (with `solver`) for `shape` pressed `depth` at four positions a
/// quarter pitch apart along the diagonal (so that the contact's rim, where the slope
/// changes most, falls evenly over the phases), off the lattice's symmetry lines.
/// The worst over the median phase bin of `physics` with the attributes `extra` beside it.
fn ratio(
    physics: &str,
    extra: &[(&str, &str)],
    shape: Arc<dyn Sdf>,
    lowest: f64,
    depth: f64,
) -> f64 {
    let mut raw = RawConfig::default()
        .with(ATTR_PHYSICS, physics)
        .with(ATTR_RESOLUTION, &format!("{WIDTH} {HEIGHT}"))
        .with(
            ATTR_FOV,
            &format!("{} {}", WIDTH as f64 * PIXEL, HEIGHT as f64 * PIXEL),
        );
    for (attribute, value) in extra {
        raw = raw.with(attribute, value);
    }
    let config = Config::from_raw("touch", &raw).unwrap();
    let grid = (config.width, config.height, config.fov);
    let mut sensor = TactileSensor::new(config).unwrap();
    let rigid = raw.with(ATTR_PHYSICS, "rigid");
    let mut cap = TactileSensor::new(Config::from_raw("cap", &rigid).unwrap()).unwrap();
    let mut out = vec![0.0; WIDTH * HEIGHT];
    let mut penetration = vec![0.0; WIDTH * HEIGHT];
    let (w, h, fov) = grid;
    let x = |c: usize| -0.5 * fov[0] + (c as f64 + 0.5) * fov[0] / w as f64;
    let y = |r: usize| 0.5 * fov[1] - (r as f64 + 0.5) * fov[1] / h as f64;
    let (mut sum, mut count) = ([0.0; BINS], [0; BINS]);
    for k in 0..4 {
        let shift = 0.25 * PITCH * k as f64;
        let placed = [Placed {
            shape: shape.clone(),
            pose: Isometry3::translation(0.37e-3 + shift, -0.21e-3 + shift, lowest - depth),
        }];
        sensor.reset();
        let eval = sensor.evaluate(&placed, &mut out);
        assert!(eval.warnings.is_empty(), "{physics}: {:?}", eval.warnings);
        assert!(
            physics != "rom" || eval.rom.is_some(),
            "{physics}: the model ran"
        );
        // Outside the contact and its pixels' neighbours: there the surface is the model's
        // own (inside, the depth rule gives the indenter's shape).
        cap.evaluate(&placed, &mut penetration);
        let free: Vec<bool> = (0..WIDTH * HEIGHT)
            .map(|i| {
                let (r, c) = (i / WIDTH, i % WIDTH);
                (r.saturating_sub(2)..(r + 3).min(HEIGHT)).all(|rr| {
                    (c.saturating_sub(2)..(c + 3).min(WIDTH))
                        .all(|cc| penetration[rr * WIDTH + cc] <= 0.0)
                })
            })
            .collect();
        fold(&out, &free, x, y, &mut sum, &mut count);
    }
    worst_over_median(&sum, &count)
}

#[test]
fn the_depth_image_shows_no_lattice_at_the_minis_pixel() {
    let sphere: Arc<dyn Sdf> = Arc::new(Sphere::new(2e-3));
    let ellipsoid: Arc<dyn Sdf> = Arc::new(Ellipsoid::new(Vector3::new(3e-3, 1.5e-3, 1.5e-3)));
    let shapes = [("sphere", sphere, 2e-3), ("ellipsoid", ellipsoid, 1.5e-3)];
    let modes: [(&str, &[(&str, &str)]); 4] = [
        ("coarse", &[]),
        ("rom", &[]),
        ("rom", &[(ATTR_SOLVER, "linear")]),
        ("rom", &[(ATTR_MODEL, tacrom::rom::FAMILY_MODEL)]),
    ];
    let mut worst = Vec::new();
    for (name, shape, lowest) in &shapes {
        for (physics, extra) in modes {
            let r = ratio(physics, extra, shape.clone(), *lowest, 0.3e-3);
            eprintln!("{name}, {physics} {extra:?}: worst / median phase bin {r:.2}");
            worst.push((format!("{name}, {physics} {extra:?}"), r));
        }
    }
    for (what, r) in worst {
        assert!(
            r <= 2.0,
            "{what}: the worst phase bin's slope change is {r:.2} times the median's"
        );
    }
}
