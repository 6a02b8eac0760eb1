//! Cost of the `rgb` output's writer: one 320 x 240 image shaded from a depth image, on one
//! thread. `cargo bench --bench rgb`.
//!
//! Three depth images: the flat gel (every pixel the background), a 5 mm sphere pressed
//! 1 mm (rigid cap, a third of the image sloped) and a surface sloped everywhere (the worst
//! case). Then the same through a rigid-physics sensor: the render stage of an evaluation
//! with outputs `depth` against `depth rgb`.

use std::sync::Arc;
use std::time::Instant;

use nalgebra::Isometry3;
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{PixelGrid, Placed, Sphere};
use tacrom::render::rgb::{render, Optics, CHANNELS};
use tacrom::sensor::TactileSensor;

/// Least, median and 90th percentile of `times` (s), in ms: on a busy machine the least is
/// the best estimate of the cost itself.
fn stats(mut times: Vec<f64>) -> (f64, f64, f64) {
    times.sort_by(f64::total_cmp);
    let at = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize] * 1e3;
    (at(0.0), at(0.5), at(0.9))
}

fn main() {
    let grid = PixelGrid {
        width: 320,
        height: 240,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    let n = grid.width * grid.height;
    let image = |f: &dyn Fn(f64, f64) -> f64| {
        let mut d = Vec::with_capacity(n);
        for r in 0..grid.height {
            for c in 0..grid.width {
                d.push(f(grid.x(c), grid.y(r)));
            }
        }
        d
    };
    let (radius, press) = (0.005, 0.001);
    let sphere = image(&|x, y| {
        let h = radius * radius - x * x - y * y;
        if h > 0.0 {
            (press - radius + h.sqrt()).max(0.0)
        } else {
            0.0
        }
    });
    let sloped = image(&|x, y| 1e-3 + 0.02 * x + 0.01 * (300.0 * y).sin());
    let optics = Optics::default();
    let mut out = vec![0.0; CHANNELS * n];
    let frames = 400;
    let header = |title: &str| {
        println!(
            "{title:<34} {:>10} {:>10} {:>10}",
            "least ms", "median ms", "p90 ms"
        )
    };
    header("rgb render, 320 x 240");
    for (name, depth) in [
        ("flat", vec![0.0; n]),
        ("sphere 1 mm", sphere),
        ("sloped everywhere", sloped),
    ] {
        let sloped_px = depth
            .chunks(grid.width)
            .flat_map(|row| row.windows(3).map(|w| w[2] != w[0]))
            .filter(|&s| s)
            .count();
        let mut times = Vec::with_capacity(frames);
        for _ in 0..frames {
            let t0 = Instant::now();
            render(&optics, &grid, std::hint::black_box(&depth), &mut out);
            times.push(t0.elapsed().as_secs_f64());
            std::hint::black_box(&out);
        }
        let (least, median, p90) = stats(times);
        let label = format!(
            "{name} ({:.0} % sloped)",
            100.0 * sloped_px as f64 / n as f64
        );
        println!("{label:<34} {least:>10.3} {median:>10.3} {p90:>10.3}");
    }

    // Through the sensor: the render stage (all writers) with and without rgb.
    header("rigid sensor, render stage");
    let ball: Arc<dyn tacrom::geometry::Sdf> = Arc::new(Sphere::new(radius));
    for outputs in ["depth", "depth rgb"] {
        let raw = RawConfig::default()
            .with("physics", "rigid")
            .with("outputs", outputs);
        let config = Config::from_raw("bench", &raw).expect("config");
        let mut sensor = TactileSensor::new(config.clone()).expect("sensor");
        let mut out = vec![0.0; config.sensordata_len()];
        let mut render_times = Vec::with_capacity(frames);
        for f in 0..frames {
            let s = f as f64 / (frames - 1) as f64;
            let placed = [Placed {
                shape: ball.clone(),
                pose: Isometry3::translation(-0.5e-3 + 1e-3 * s, 0.0, radius - 0.1e-3 - 0.9e-3 * s),
            }];
            let eval = sensor.evaluate(&placed, &mut out);
            render_times.push(eval.times.render);
            std::hint::black_box(&out);
        }
        let (least, median, p90) = stats(render_times);
        println!("{outputs:<34} {least:>10.3} {median:>10.3} {p90:>10.3}");
    }
}
