//! Cost of the image-side outputs after a solve: the depth, shear, marker, pressure and
//! marker-dot passes over a solved coarse gel at 320 x 240, one thread, the pinhole
//! camera's refraction pass over that depth image and over a rigid press, and the sensor's
//! render stage (everything after the physics) per output set.
//!
//! `cargo bench --bench outputs` (add `-- --quick` for fewer repetitions).

use std::sync::Arc;
use std::time::Instant;

use nalgebra::Isometry3;
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{PixelGrid, Placed, Sdf, Sphere};
use tacrom::mpm::{Gel, SolverOptions};
use tacrom::render::markers::Markers;
use tacrom::render::refraction::{Refraction, Sampling};
use tacrom::render::DepthRule;
use tacrom::sensor::TactileSensor;

/// Median of `reps` timings of `f` (ms).
fn median_ms(reps: usize, f: impl FnMut()) -> f64 {
    spread_ms(reps, f)[0]
}

/// Median and fastest of `reps` timings of `f` (ms): on a shared machine the fastest is
/// the cost undisturbed.
fn spread_ms(reps: usize, mut f: impl FnMut()) -> [f64; 2] {
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let t0 = Instant::now();
            f();
            t0.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    [t[t.len() / 2], t[0]]
}

/// A sphere of radius 5 mm pressed 0.1 to 0.8 mm while sliding 1 mm along +x, `frames`
/// poses (one shape, so that successive solves see the same indenter).
fn slide(frames: usize) -> Vec<Placed> {
    let ball: Arc<dyn Sdf> = Arc::new(Sphere::new(0.005));
    (0..frames)
        .map(|f| {
            let s = f as f64 / (frames - 1).max(1) as f64;
            let depth = 0.1e-3 + 0.7e-3 * s;
            Placed {
                shape: ball.clone(),
                pose: Isometry3::translation(-0.5e-3 + 1e-3 * s, 0.0, 0.005 - depth),
            }
        })
        .collect()
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let reps = if quick { 20 } else { 200 };
    let grid = PixelGrid {
        width: 320,
        height: 240,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    let pixels = grid.width * grid.height;

    // The passes over one solved gel.
    let config =
        Config::from_raw("bench", &RawConfig::default().with("physics", "coarse")).expect("config");
    let params = config.gel_params(config.dx.expect("coarse has a grid"));
    let mut gel = Gel::new(
        params,
        SolverOptions {
            threads: 1,
            tolerance: config.tolerance,
            ..SolverOptions::default()
        },
    )
    .expect("gel");
    for p in slide(6) {
        let _ = gel.solve(&[p]);
    }
    let mut depth = vec![0.0; pixels];
    let mut shear = vec![0.0; 2 * pixels];
    let mut markers = Markers::new(config.markers, &grid);
    let mut out = vec![0.0; markers.len() * Markers::VALUES];
    println!("one solved coarse gel (sphere 0.8 mm deep, slid 1 mm), 320 x 240, one thread:");
    println!(
        "  surface_depth        {:8.3} ms",
        median_ms(reps, || gel.surface_depth(&grid, &mut depth))
    );
    println!(
        "  surface_shear        {:8.3} ms",
        median_ms(reps, || gel.surface_shear(&grid, &mut shear))
    );
    println!(
        "  depth and shear      {:8.3} ms  (one inverse map)",
        median_ms(reps, || gel
            .surface_depth_and_shear(&grid, &mut depth, &mut shear))
    );
    println!(
        "  markers ({} x {})     {:8.3} ms",
        config.markers[0],
        config.markers[1],
        median_ms(reps, || {
            markers.update(|x| {
                let u = gel.surface_displacement(x[0], x[1]);
                [u.x, u.y]
            });
            markers.write(&grid, &mut out);
        })
    );

    let mut pressure = vec![0.0; pixels];
    println!(
        "  contact_pressure     {:8.3} ms",
        median_ms(reps, || gel.contact_pressure(&grid, &mut pressure))
    );
    let mut rgb = vec![128.0; 3 * pixels];
    println!(
        "  marker dots into rgb {:8.3} ms",
        median_ms(reps, || markers.draw(&grid, &mut rgb))
    );

    // The pinhole camera (10 and 20 mm below the 4 mm gel, index 1.4): every ray traced
    // through the solved gel's depth image (deformed, by a few micrometres at least, over
    // the whole image), then an rgb image resampled along them; and the rays through a
    // rigid sphere cap (flat beyond the contact).
    let t = config.size[2];
    let cap = slide(6)[5].clone();
    let rule = DepthRule::new(t, std::slice::from_ref(&cap));
    let mut zmin = vec![f64::INFINITY; pixels];
    cap.lower_surface(&grid, -t, 0.0, &mut zmin);
    let rigid: Vec<f64> = zmin
        .iter()
        .map(|&z| rule.depth(0.0, rule.penetration(z)))
        .collect();
    gel.surface_depth(&grid, &mut depth);
    for (d, &p) in depth.iter_mut().zip(&rigid) {
        *d = rule.depth(*d, p);
    }
    let mut seen = vec![0.0; pixels];
    let mut rgb_seen = vec![0.0; 3 * pixels];
    println!("  refraction pass, median (fastest) ms:");
    for distance in [0.01, 0.02] {
        let mut camera = Refraction::new(&grid, t, distance, 1.4);
        let [gel_med, gel_min] = spread_ms(reps, || {
            let _ = camera.refract(&depth, &mut seen);
        });
        let [rgb_med, rgb_min] = spread_ms(reps, || {
            camera.resample(&seen, 3, Sampling::Bilinear, &rgb, &mut rgb_seen)
        });
        let [cap_med, cap_min] = spread_ms(reps, || {
            let _ = camera.refract(&rigid, &mut seen);
        });
        println!(
            "    D {:2.0} mm: coarse gel {gel_med:6.3} ({gel_min:6.3}), rgb resampled along its \
             rays {rgb_med:6.3} ({rgb_min:6.3}), rigid sphere {cap_med:6.3} ({cap_min:6.3})",
            distance * 1e3,
        );
    }
    let seen_pixels = depth.iter().filter(|&&d| d > 0.0).count();
    println!(
        "    (coarse gel: {seen_pixels} of {pixels} pixels deeper than 0; rigid sphere: {})",
        rigid.iter().filter(|&&d| d > 0.0).count()
    );

    // The sensor per output set: one evaluation, its physics stage (solve and surface) and
    // its render stage (the writers).
    println!("sensor evaluation per output set, median over the slide's frames:");
    for outputs in [
        "depth",
        "depth shear markers",
        "shear markers",
        "markers",
        "depth pressure",
        "depth rgb",
        "depth rgb markers",
        "depth | pinhole",
        "depth rgb | pinhole",
    ] {
        let (outputs, camera) = match outputs.split_once(" | ") {
            Some((o, _)) => (o, "pinhole 0.02"),
            None => (outputs, "orthographic"),
        };
        let raw = RawConfig::default()
            .with("physics", "coarse")
            .with("outputs", outputs)
            .with("camera", camera)
            .with("index", "1.4");
        let config = Config::from_raw("bench", &raw).expect("config");
        let mut sensor = TactileSensor::new(config.clone()).expect("sensor");
        let mut out = vec![0.0; config.sensordata_len()];
        let (mut render, mut physics) = (Vec::new(), Vec::new());
        for p in slide(if quick { 6 } else { 12 }) {
            let eval = sensor.evaluate(&[p], &mut out);
            render.push(eval.times.render * 1e3);
            physics.push(eval.times.physics * 1e3);
        }
        let med = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let outputs = format!("{outputs} ({camera})");
        println!(
            "  {outputs:<36} physics {:8.3} ms   render {:8.3} ms",
            med(physics),
            med(render)
        );
    }
}
