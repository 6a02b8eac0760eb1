//! Cost of the image-side outputs after a solve: the depth, shear, marker, pressure and
//! marker-dot passes over a solved coarse gel at 320 x 240, one thread, and the sensor's render stage (everything
//! after the physics) per output set.
//!
//! `cargo bench --bench outputs` (add `-- --quick` for fewer repetitions).

use std::sync::Arc;
use std::time::Instant;

use nalgebra::Isometry3;
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{PixelGrid, Placed, Sdf, Sphere};
use tacrom::mpm::{Gel, GelParams, SolverOptions};
use tacrom::render::markers::Markers;
use tacrom::sensor::TactileSensor;

/// Median of `reps` timings of `f` (ms).
fn median_ms(reps: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let t0 = Instant::now();
            f();
            t0.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
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
    let params = GelParams {
        size: config.size,
        young: config.young,
        poisson: config.poisson,
        density: config.density,
        friction: config.friction,
        dx: config.dx.expect("coarse has a grid"),
        material: config.material,
    };
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
    ] {
        let raw = RawConfig::default()
            .with("physics", "coarse")
            .with("outputs", outputs);
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
        println!(
            "  {outputs:<22} physics {:8.3} ms   render {:8.3} ms",
            med(physics),
            med(render)
        );
    }
}
