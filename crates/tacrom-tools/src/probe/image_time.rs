//! Time of the gel's depth image (the inverse map from pixels to surface points) after a
//! press: `tacrom probe image_time [SOLVER] [DEPTH_MM] [THREADS] [lattice|full] [slide]
//! [reps=N]` (defaults: linear, 0.5, 1, full, pressed only, 20). Prints the median of N
//! images at 320 x 240 (with `lattice`: on rom's 100 x 100 lattice over the whole 30 mm
//! gel, its observation's coarse depth) and a checksum of the image's bits. With `slide`
//! the ball then slides 1 mm along x in four frames (the gel's friction drags the surface
//! sideways, as in `tacrom/Press-v1`'s sweep) before the images are made.

use nalgebra::Isometry3;
use std::sync::Arc;
use std::time::Instant;
use tacrom::geometry::*;
use tacrom::mpm::*;

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let solver = Solver::named(args.get(1).map_or("linear", |s| s.as_str())).expect("solver");
    let depth: f64 = args.get(2).map_or(0.5, |s| s.parse().unwrap()) * 1e-3;
    let threads: usize = args.get(3).map_or(1, |s| s.parse().unwrap());
    let mut g = Gel::new(
        GelParams::default(),
        SolverOptions {
            solver,
            threads,
            ..Default::default()
        },
    )
    .unwrap();
    let ball: Arc<dyn Sdf> = Arc::new(Sphere::new(5e-3));
    let frames = if args.iter().any(|a| a == "slide") {
        5
    } else {
        1
    };
    for k in 0..frames {
        g.solve(&[Placed {
            shape: ball.clone(),
            pose: Isometry3::translation(0.25e-3 * k as f64, 0.0, 5e-3 - depth),
        }]);
    }
    let reps: usize = args
        .iter()
        .find_map(|a| a.strip_prefix("reps=").and_then(|n| n.parse().ok()))
        .unwrap_or(20);
    let grid = match args.get(4).map(|s| s.as_str()) {
        Some("lattice") => PixelGrid {
            width: 100,
            height: 100,
            fov_x: 0.03,
            fov_y: 0.03,
        },
        _ => PixelGrid {
            width: 320,
            height: 240,
            fov_x: 0.024,
            fov_y: 0.018,
        },
    };
    let mut out = vec![0.0; grid.width * grid.height];
    let mut times = Vec::new();
    for _ in 0..reps {
        let t0 = Instant::now();
        g.surface_depth(&grid, &mut out);
        times.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let peak = out.iter().copied().fold(0.0, f64::max);
    let bits = out.iter().fold(0u64, |h, v| h.rotate_left(5) ^ v.to_bits());
    println!(
        "median {:.2} ms, peak {peak:.6e} m, bits {bits:016x}",
        times[reps / 2]
    );
}
