//! Cost of the geoms the viewer callback draws for one sensor (`tacrom::visual`): a
//! 320 x 240 depth image pooled into the tile grid, the tiles posed in the world, and the
//! force arrow at the contact centroid, on one thread. `cargo bench --bench visual`.
//!
//! The callback adds MuJoCo's part (`mjv_initGeom` per geom) to this; the Python test
//! `tests/python/test_view.py` reports one whole `mjv_updateScene` with and without it.

use std::time::Instant;

use nalgebra::{Isometry3, Vector3};
use tacrom::geometry::PixelGrid;
use tacrom::visual::{sensor_geoms, ArrowStyle, Surface, Tiles, GEOM_BUDGET};

/// Least, median and 90th percentile of `times` (s), in us: on a busy machine the least is
/// the best estimate of the cost itself.
fn stats(mut times: Vec<f64>) -> (f64, f64, f64) {
    times.sort_by(f64::total_cmp);
    let at = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize] * 1e6;
    (at(0.0), at(0.5), at(0.9))
}

fn main() {
    let grid = PixelGrid {
        width: 320,
        height: 240,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    // A 5 mm sphere pressed 1 mm (rigid cap).
    let (radius, press) = (0.005, 0.001);
    let mut depth = Vec::with_capacity(grid.width * grid.height);
    for r in 0..grid.height {
        for c in 0..grid.width {
            let (x, y) = (grid.x(c), grid.y(r));
            let h = radius * radius - x * x - y * y;
            depth.push(if h > 0.0 {
                (press - radius + h.sqrt()).max(0.0)
            } else {
                0.0
            });
        }
    }
    let surface = Surface {
        depth: &depth,
        grid: &grid,
        thickness: 0.004,
    };
    let site = Isometry3::translation(0.0, 0.0, 0.1);
    let force = Vector3::new(0.1, 0.0, 1.5);
    let style = ArrowStyle {
        scale: 0.01,
        width: 0.001,
        rgba: [1.0, 0.0, 0.0, 1.0],
    };
    let frames = 2000;
    println!(
        "{:<40} {:>9} {:>10} {:>9}",
        "320 x 240, sphere 1 mm", "least us", "median us", "p90 us"
    );
    let mut geoms = Vec::with_capacity(GEOM_BUDGET);
    let mut run = |name: &str, f: &mut dyn FnMut(&mut Vec<_>)| {
        let mut times = Vec::with_capacity(frames);
        for _ in 0..frames {
            geoms.clear();
            let t0 = Instant::now();
            f(&mut geoms);
            times.push(t0.elapsed().as_secs_f64());
            std::hint::black_box(&geoms);
        }
        let (least, median, p90) = stats(times);
        println!(
            "{name:<40} {least:>9.1} {median:>10.1} {p90:>9.1}  ({} geoms)",
            geoms.len()
        );
    };
    run("pool only", &mut |_| {
        std::hint::black_box(Tiles::pool(&surface, GEOM_BUDGET - 1));
    });
    run("surface tiles", &mut |out| {
        sensor_geoms(&surface, &site, GEOM_BUDGET, None, out)
    });
    run("surface tiles and force arrow", &mut |out| {
        sensor_geoms(&surface, &site, GEOM_BUDGET, Some((&force, &style)), out)
    });
}
