//! Force (N) of a standing capsule (radius R, half-length 3 mm) pressed through and past its
//! radius into the default gel, each press from rest and as one sequence:
//! `tacrom probe deep SOLVER [RADIUS_MM [POISSON]]`.
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::sync::Arc;
use tacrom::geometry::{Capsule, Placed, Sdf};
use tacrom::mpm::{Gel, GelParams, Solver, SolverOptions};

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let arg = |i: usize, default: f64| args.get(i).map_or(default, |v| v.parse().unwrap());
    let solver = args.get(1).cloned().unwrap_or_else(|| "newton".into());
    let (r, nu) = (arg(2, 1.0) * 1e-3, arg(3, 0.43));
    let half = 3e-3;
    let p = GelParams {
        friction: 0.0,
        poisson: nu,
        ..GelParams::default()
    };
    let options = SolverOptions {
        solver: Solver::named(&solver).unwrap(),
        threads: 2,
        ..Default::default()
    };
    let cap: Arc<dyn Sdf> = Arc::new(Capsule::new(r, half));
    let depths = [0.2e-3, 0.5e-3, 0.8e-3, 1.0e-3, 1.2e-3, 1.5e-3, 2.0e-3];
    let mut seq = Gel::new(p.clone(), options.clone()).unwrap();
    for d in depths {
        let pose = Isometry3::from_parts(
            Translation3::new(0.0, 0.0, r + half - d),
            UnitQuaternion::identity(),
        );
        let placed = [Placed {
            shape: cap.clone(),
            pose,
        }];
        let mut fresh = Gel::new(p.clone(), options.clone()).unwrap();
        let a = fresh.solve(&placed);
        let b = seq.solve(&placed);
        println!(
            "{solver} r {:.1} nu {nu} d {:.1} mm: from rest {:.4}{} ({} it), sequence {:.4}{} ({} it)",
            r * 1e3,
            d * 1e3,
            fresh.force().z,
            if a.converged { "" } else { "*" },
            a.iterations,
            seq.force().z,
            if b.converged { "" } else { "*" },
            b.iterations,
        );
    }
}
