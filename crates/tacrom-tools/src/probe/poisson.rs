//! Force of frictionless sphere presses over the bonded-layer Hertz force, for one solver,
//! Poisson's ratio and grid spacing: `tacrom probe poisson
//! SOLVER NU DX_MM` (defaults: linear, 0.48, 1.4). Spheres of radius 2 and 5 mm on the
//! default 30 x 30 x 4 mm gel, each pressed through 0.1 to 0.5 mm in one sequence; a `*`
//! marks a solve that did not converge. `default` is the relaxation with the fallback solver
//! for the frames whose contact it cannot carry, as a coarse sensor that names no solver.
use nalgebra::Isometry3;
use std::sync::Arc;
use tacrom::geometry::{Placed, Sdf, Sphere};
use tacrom::mpm::hertz::hertz_bonded;
use tacrom::mpm::{Gel, GelParams, Solver, SolverOptions};

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let solver = args.get(1).cloned().unwrap_or("linear".into());
    let nu: f64 = args.get(2).map_or(0.48, |v| v.parse().unwrap());
    let dx: f64 = args.get(3).map_or(1.4, |v| v.parse().unwrap());
    let p = GelParams {
        friction: 0.0,
        poisson: nu,
        dx: dx * 1e-3,
        ..GelParams::default()
    };
    for r in [2e-3, 5e-3] {
        let mut g = Gel::new(
            p,
            SolverOptions {
                solver: Solver::named(&solver).unwrap_or(Solver::Relaxation),
                fallback: solver == "default",
                threads: 2,
                ..Default::default()
            },
        )
        .unwrap();
        let ball: Arc<dyn Sdf> = Arc::new(Sphere::new(r));
        let mut row = format!("{solver} nu {nu} dx {dx} R {:.0}:", r * 1e3);
        for d in [0.1e-3, 0.2e-3, 0.3e-3, 0.4e-3, 0.5e-3] {
            let placed = [Placed {
                shape: ball.clone(),
                pose: Isometry3::translation(0.0, 0.0, r - d),
            }];
            let rep = g.solve(&placed);
            let f = g.force().z;
            let h = hertz_bonded(p.young, p.poisson, r, d, p.size[2]);
            row += &format!(" {:.3}{}", f / h, if rep.converged { "" } else { "*" });
        }
        println!("{row}");
    }
}
