//! What the linear solver's frame costs against the size of its contact: `tacrom probe
//! contact_size [THREADS] [SIDES_MM...]` (defaults: 1, sides 1 10 24 41) presses a box
//! with a square face of each side flat into a gel 9 mm wider than it (at least the
//! default 30 mm; 4 mm thick, dx 1.4 mm, friction 0.5), 0.1 to 0.4 mm deep over 5 frames,
//! then slides it 0.3 mm along x over 10 more, holds it there for 10 more (a grasp held
//! still) and shakes it for 10 more by a few microns a frame, as a simulated grasp holds an
//! object (MuJoCo's soft contacts let it creep and tremble: up to 3 um along the face and
//! 1 um into it), and prints the node columns under the face (its side in cells plus the
//! B-splines' stencil, squared), the points carrying force at the end, the median and
//! largest time per frame of each phase, and the contact solve's Newton steps per frame of
//! each.

use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use tacrom::geometry::{Cuboid, Placed, Sdf};
use tacrom::mpm::{Gel, GelParams, Solver, SolverOptions};

fn median(mut t: Vec<f64>) -> f64 {
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let threads: usize = args.get(1).map_or(1, |s| s.parse().expect("threads"));
    let sides: Vec<f64> = if args.len() > 2 {
        args[2..]
            .iter()
            .map(|s| s.parse().expect("side (mm)"))
            .collect()
    } else {
        vec![1.0, 10.0, 24.0, 41.0]
    };
    println!(
        "side mm  gel mm  columns  points  press ms (median, max)  slide ms (median, max)  hold ms (median, max)  shaken ms (median, max)  Newton steps per frame (press, slide, hold, shaken)"
    );
    for side in sides {
        let side_m = side * 1e-3;
        let width = (side_m + 9e-3).max(0.03);
        let dx = 1.4e-3;
        let params = GelParams {
            size: [width, width, 0.004],
            friction: 0.5,
            dx,
            ..GelParams::default()
        };
        let options = SolverOptions {
            solver: Solver::Linear,
            threads,
            ..SolverOptions::default()
        };
        let t0 = Instant::now();
        let mut gel = Gel::new(params, options).expect("gel");
        let load = t0.elapsed().as_secs_f64();
        let half = 5e-3;
        let shape: Arc<dyn Sdf> =
            Arc::new(Cuboid::new(Vector3::new(side_m / 2.0, side_m / 2.0, half)));
        let mut times = [Vec::new(), Vec::new(), Vec::new(), Vec::new()];
        let mut steps = [Vec::new(), Vec::new(), Vec::new(), Vec::new()];
        let mut points = 0;
        for f in 0..35 {
            // The shaking: fixed, irregular offsets (golden-ratio sequences) in [-1, 1].
            let shake = |k: f64| match f {
                25.. => 2.0 * ((f as f64 * k).fract()) - 1.0,
                _ => 0.0,
            };
            let depth = 0.1e-3 + 0.3e-3 * (f.min(4) as f64 / 4.0) + 1e-6 * shake(0.618_034);
            let x = 0.3e-3 * (f.clamp(5, 14) - 5) as f64 / 9.0 + 3e-6 * shake(0.754_878);
            let y = 3e-6 * shake(0.569_840);
            let placed = [Placed {
                shape: shape.clone(),
                pose: Isometry3::from_parts(
                    Translation3::new(x, y, half - depth),
                    UnitQuaternion::identity(),
                ),
            }];
            let t = Instant::now();
            let report = gel.solve(&placed);
            let ms = t.elapsed().as_secs_f64() * 1e3;
            let phase = match f {
                0..5 => 0,
                5..15 => 1,
                15..25 => 2,
                _ => 3,
            };
            times[phase].push(ms);
            steps[phase].push(report.cg_iterations as f64);
            points = report.active_particles;
        }
        let columns = ((side_m / dx).ceil() + 3.0).powi(2);
        let max = |t: &[f64]| t.iter().copied().fold(0.0, f64::max);
        println!(
            "{side:7.1}  {:6.0}  {columns:7.0}  {points:6}  {:10.2} {:10.2}  {:10.2} {:10.2}  {:9.2} {:9.2}  {:10.2} {:10.2}  {:5.0} {:5.0} {:5.0} {:5.0}   (load {load:.2} s)",
            width * 1e3,
            median(times[0].clone()),
            max(&times[0]),
            median(times[1].clone()),
            max(&times[1]),
            median(times[2].clone()),
            max(&times[2]),
            median(times[3].clone()),
            max(&times[3]),
            median(steps[0].clone()),
            median(steps[1].clone()),
            median(steps[2].clone()),
            median(steps[3].clone()),
        );
    }
}
