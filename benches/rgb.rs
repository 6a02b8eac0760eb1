//! Cost of the `rgb` output's writer: one 320 x 240 image shaded from a depth image, on one
//! thread. `cargo bench --bench rgb`.
//!
//! Three depth images: the flat gel (every pixel the background), a 5 mm sphere pressed
//! 1 mm (rigid cap, a third of the image sloped) and a surface sloped everywhere (the worst
//! case), each with the built-in optics and with calibrated optics (a 41 x 41 table of the
//! built-in response over a 320 x 240 background, as `tacrom calibrate` writes). Then the
//! same through a rigid-physics sensor: the render stage of an evaluation with outputs
//! `depth` against `depth rgb`, built-in and with an `optics` file.

use std::sync::Arc;
use std::time::Instant;

use nalgebra::Isometry3;
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{PixelGrid, Placed, Sphere};
use tacrom::render::calibrated::{CalibratedOptics, GradientTable, RgbImage};
use tacrom::render::rgb::{render, render_calibrated, Optics, CHANNELS};
use tacrom::sensor::TactileSensor;

/// Least, median and 90th percentile of `times` (s), in ms: on a busy machine the least is
/// the best estimate of the cost itself.
fn stats(mut times: Vec<f64>) -> (f64, f64, f64) {
    times.sort_by(f64::total_cmp);
    let at = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize] * 1e3;
    (at(0.0), at(0.5), at(0.9))
}

/// Calibrated optics equal to the built-in ones: the built-in colour change at 41 x 41
/// gradients over +-0.7 (each the centre of a 3 x 3 plane of that slope), over the built-in
/// background on `width x height` pixels.
fn calibrated_like_built_in(width: usize, height: usize) -> CalibratedOptics {
    let optics = Optics::default();
    let (n, g) = (41, 0.7);
    let plane = PixelGrid {
        width: 3,
        height: 3,
        fov_x: 3e-4,
        fov_y: 3e-4,
    };
    let mut values = Vec::with_capacity(3 * n * n);
    let mut rgb = vec![0.0; 27];
    for j in 0..n {
        for i in 0..n {
            let gx = -g + 2.0 * g * i as f64 / (n - 1) as f64;
            let gy = -g + 2.0 * g * j as f64 / (n - 1) as f64;
            let depth: Vec<f64> = (0..9)
                .map(|p| 1e-3 + gx * plane.x(p % 3) + gy * plane.y(p / 3))
                .collect();
            render(&optics, &plane, &depth, &mut rgb);
            values.extend((0..3).map(|k| rgb[12 + k] - optics.background[k]));
        }
    }
    let table = GradientTable::new([n, n], [g, g], values).expect("table");
    let background = RgbImage::uniform(width, height, optics.background);
    CalibratedOptics::new(table, background).expect("optics")
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
            "{title:<44} {:>10} {:>10} {:>10}",
            "least ms", "median ms", "p90 ms"
        )
    };
    header("rgb render, 320 x 240");
    let calibrated = calibrated_like_built_in(grid.width, grid.height);
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
        for model in ["built-in", "calibrated"] {
            let mut times = Vec::with_capacity(frames);
            for _ in 0..frames {
                let t0 = Instant::now();
                let depth = std::hint::black_box(&depth);
                if model == "built-in" {
                    render(&optics, &grid, depth, &mut out);
                } else {
                    render_calibrated(&calibrated, &grid, depth, &mut out);
                }
                times.push(t0.elapsed().as_secs_f64());
                std::hint::black_box(&out);
            }
            let (least, median, p90) = stats(times);
            let label = format!(
                "{name} ({:.0} % sloped), {model}",
                100.0 * sloped_px as f64 / n as f64
            );
            println!("{label:<44} {least:>10.3} {median:>10.3} {p90:>10.3}");
        }
    }

    // Through the sensor: the render stage (all writers) with and without rgb.
    header("rigid sensor, render stage");
    let ball: Arc<dyn tacrom::geometry::Sdf> = Arc::new(Sphere::new(radius));
    let dir = std::env::temp_dir().join(format!("tacrom-bench-rgb-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("scratch folder");
    let optics_file = dir.join("optics.json");
    calibrated.save(&optics_file, None).expect("optics file");
    let file = optics_file.to_str().expect("path");
    for (label, outputs, optics_attr) in [
        ("depth", "depth", ""),
        ("depth rgb", "depth rgb", ""),
        ("depth rgb, calibrated optics", "depth rgb", file),
    ] {
        let mut raw = RawConfig::default()
            .with("physics", "rigid")
            .with("outputs", outputs);
        if !optics_attr.is_empty() {
            raw = raw.with("optics", optics_attr);
        }
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
        println!("{label:<44} {least:>10.3} {median:>10.3} {p90:>10.3}");
    }
}
