//! A 5 mm sphere pressed into the default gel in steps, frame by frame, for measuring a
//! press's cost and how its answer depends on the solver's settings:
//!
//! `tacrom probe fine_press [key=value ...]`
//!
//! Keys (defaults): `dx` (0.3e-3 m), `depths` ("0.1,0.2,0.3" mm, pressed in order, each
//! solve warm-started from the last), `threads` (1), `friction` (0.5), `poisson` (0.43),
//! `tolerance` (1e-3), `solver` (relaxation), `cfl` (0.5), `damping` (1), `margin` (the
//! active margin, gel thicknesses: 1.5), `nested` (Newton's nested margin, gel
//! thicknesses: 0.5; `inf` turns the nesting off), `linear` (auto; Newton's linear
//! solves: auto, factor or multigrid), `coarse_start` (1; 0 turns Newton's coarse start
//! off, a larger number sets the unknowns above which a gel takes it), `surface` (a path:
//! the surface's displacement in um at every 0.1 mm of the central 24 x 24 mm is written
//! there, a line per depth). Prints each step's time, iterations, convergence and normal
//! force.

use nalgebra::Isometry3;
use std::sync::Arc;
use std::time::Instant;
use tacrom::geometry::*;
use tacrom::mpm::*;

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let mut params = GelParams {
        dx: 0.3e-3,
        ..Default::default()
    };
    let mut options = SolverOptions::default();
    let mut depths = vec![0.1e-3, 0.2e-3, 0.3e-3];
    let mut surface = None;
    for arg in args.into_iter().skip(1) {
        let (key, value) = arg
            .split_once('=')
            .unwrap_or_else(|| panic!("expected key=value, got '{arg}'"));
        let number = || -> f64 {
            value
                .parse()
                .unwrap_or_else(|_| panic!("{key}: not a number: '{value}'"))
        };
        match key {
            "dx" => params.dx = number(),
            "friction" => params.friction = number(),
            "thickness" => params.size[2] = number(),
            "poisson" => params.poisson = number(),
            "threads" => options.threads = number() as usize,
            "tolerance" => options.tolerance = number(),
            "cfl" => options.cfl = number(),
            "damping" => options.damping = number(),
            "margin" => options.active_margin = number(),
            "nested" => options.nested_margin = number(),
            "coarse_start" => {
                options.coarse_start_above = match number() {
                    0.0 => usize::MAX,
                    1.0 => options.coarse_start_above,
                    n => n as usize,
                }
            }
            "linear" => {
                options.linear = match value {
                    "auto" => Linear::Automatic,
                    "factor" => Linear::Factor,
                    "multigrid" => Linear::Multigrid,
                    _ => panic!("linear: auto, factor or multigrid, got '{value}'"),
                }
            }
            "solver" => {
                options.solver =
                    Solver::named(value).unwrap_or_else(|| panic!("unknown solver '{value}'"))
            }
            "depths" => {
                depths = value
                    .split(',')
                    .map(|d| d.parse::<f64>().expect("depths in mm") * 1e-3)
                    .collect()
            }
            "surface" => surface = Some(value.to_string()),
            _ => panic!("unknown key '{key}'"),
        }
    }
    let mut g = Gel::new(params, options).unwrap();
    let ball: Arc<dyn Sdf> = Arc::new(Sphere::new(5e-3));
    let total = Instant::now();
    let mut lines = Vec::new();
    for d in depths {
        let t0 = Instant::now();
        let r = g.solve(&[Placed {
            shape: ball.clone(),
            pose: Isometry3::translation(0.0, 0.0, 5e-3 - d),
        }]);
        println!(
            "depth {:.2} mm: {:.2} s, {} iterations (and {} on the coarse start's gels; {} factorisations or two-grid builds, {} CG), converged {}, residual {:.2e}, active {}, force {:.5} N",
            d * 1e3,
            t0.elapsed().as_secs_f64(),
            r.iterations,
            r.coarse_iterations,
            r.factorisations,
            r.cg_iterations,
            r.converged,
            r.residual,
            r.active_particles,
            g.force()[2]
        );
        // The surface's displacement (um) every 0.1 mm over the central 24 x 24 mm, one
        // line per depth: ux, uy, uz of each point, x fastest.
        let mut line = Vec::new();
        for j in -120..=120 {
            for i in -120..=120 {
                let u = g.surface_displacement(i as f64 * 1e-4, j as f64 * 1e-4) * 1e6;
                line.extend([u.x, u.y, u.z].map(|v| format!("{v:.4}")));
            }
        }
        lines.push(line.join(" "));
    }
    println!("total {:.1} s", total.elapsed().as_secs_f64());
    if let Some(path) = surface {
        std::fs::write(&path, lines.join("\n") + "\n").expect("surface file");
    }
}
