//! The benchmark's moving press, frame by frame, for profiling a solver:
//! `tacrom probe newton_profile SOLVER DX_M FRICTION FRAMES THREADS
//! POISSON TOLERANCE` (defaults: newton 1.4e-3 0.5 6 1 0.43 1e-3). Prints each frame's time, passes, inner steps (CG iterations, or the linear solver's Newton steps), factorisations,
//! steps that reused one, convergence and force; `perf record` on it shows where a
//! solver spends its time.

use nalgebra::Isometry3;
use std::sync::Arc;
use std::time::Instant;
use tacrom::geometry::*;
use tacrom::mpm::*;

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let solver = Solver::named(args.get(1).map(|s| s.as_str()).unwrap_or("newton")).unwrap();
    let dx: f64 = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(1.4e-3);
    let friction: f64 = args.get(3).map(|s| s.parse().unwrap()).unwrap_or(0.5);
    let frames: usize = args.get(4).map(|s| s.parse().unwrap()).unwrap_or(6);
    let threads: usize = args.get(5).map(|s| s.parse().unwrap()).unwrap_or(1);
    let poisson: f64 = args.get(6).map(|s| s.parse().unwrap()).unwrap_or(0.43);
    let tolerance: f64 = args.get(7).map(|s| s.parse().unwrap()).unwrap_or(1e-3);
    let params = GelParams {
        dx,
        friction,
        poisson,
        ..Default::default()
    };
    let options = SolverOptions {
        solver,
        threads,
        tolerance,
        ..Default::default()
    };
    let mut g = Gel::new(params, options).unwrap();
    let ball: Arc<dyn Sdf> = Arc::new(Sphere::new(5e-3));
    let at = |x: f64, d: f64| {
        [Placed {
            shape: ball.clone(),
            pose: Isometry3::translation(x, 0.0, 5e-3 - d),
        }]
    };
    let t0 = Instant::now();
    let r = g.solve(&at(0.0, 0.1e-3));
    println!(
        "first: {:.1} ms {:?}",
        t0.elapsed().as_secs_f64() * 1e3,
        (
            r.iterations,
            r.factorisations,
            r.reused,
            r.converged,
            r.residual
        )
    );
    for f in 1..=frames {
        let t0 = Instant::now();
        let r = g.solve(&at(0.02e-3 * f as f64, 0.1e-3 + 0.05e-3 * f as f64));
        println!(
            "frame {f}: {:.1} ms it {} steps {} fac {} reuse {} conv {} res {:.2e} active {} F {:?}",
            t0.elapsed().as_secs_f64() * 1e3,
            r.iterations,
            r.cg_iterations,
            r.factorisations,
            r.reused,
            r.converged,
            r.residual,
            r.active_particles,
            g.force()
        );
    }
}
