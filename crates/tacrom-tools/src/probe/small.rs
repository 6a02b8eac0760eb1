//! Force of small frictionless presses on the coarse gel against the analytic force, per
//! solver: `tacrom probe small SOLVER` (`default`: the
//! relaxation with the fallback solver for the frames whose contact it cannot carry, as a
//! coarse sensor that names no solver). `PROBE_FRICTION=MU` sets the friction (default
//! 0), `PROBE_POISSON=NU` Poisson's ratio (default 0.43), `PROBE_DEBUG=1` prints each frame's solve, force and time. Spheres of radius 0.25
//! to 2 mm and a 45-degree cone, at the gel's centre and offset by a third and a half of a
//! contact-lattice spacing, each pressed through 0.05 to 0.4 mm in one sequence.

use nalgebra::Isometry3;
use std::sync::Arc;
use tacrom::geometry::{Placed, Sdf, Sphere, TriMesh};
use tacrom::mpm::hertz::{hertz_bonded, sneddon_cone};
use tacrom::mpm::{Gel, GelParams, Solver, SolverOptions};

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let solver = args.get(1).cloned().unwrap_or_else(|| "linear".into());
    let friction = std::env::var("PROBE_FRICTION").map_or(0.0, |v| v.parse().unwrap());
    let poisson = std::env::var("PROBE_POISSON").map_or(0.43, |v| v.parse().unwrap());
    let p = GelParams {
        friction,
        poisson,
        ..GelParams::default()
    };
    let depths = [0.05e-3, 0.1e-3, 0.2e-3, 0.3e-3, 0.4e-3];
    let alpha = std::f64::consts::FRAC_PI_4;
    let mut shapes: Vec<(String, Arc<dyn Sdf>, f64)> = [0.25e-3, 0.5e-3, 1e-3, 2e-3]
        .iter()
        .map(|&r| {
            (
                format!("sphere {:.2} mm", r * 1e3),
                Arc::new(Sphere::new(r)) as Arc<dyn Sdf>,
                r,
            )
        })
        .collect();
    shapes.push((
        "cone 45".into(),
        Arc::new(TriMesh::cone_tip(3e-3, alpha, 64).unwrap()),
        0.0,
    ));
    let spacing = 0.35e-3;
    let mut all = Vec::new();
    for (name, shape, lowest) in &shapes {
        for offset in [0.0, spacing / 3.0, spacing / 2.0] {
            let mut g = Gel::new(
                p,
                SolverOptions {
                    solver: Solver::named(&solver).unwrap_or(Solver::Relaxation),
                    fallback: solver == "default",
                    threads: 1,
                    ..Default::default()
                },
            )
            .unwrap();
            let mut row = format!("{name:<16} off {:.3} mm:", offset * 1e3);
            for &d in &depths {
                let placed = [Placed {
                    shape: shape.clone(),
                    pose: Isometry3::translation(offset, offset * 0.5, lowest - d),
                }];
                let t0 = std::time::Instant::now();
                let rep = g.solve(&placed);
                if std::env::var_os("PROBE_DEBUG").is_some() {
                    eprintln!(
                        "{name} {d}: fallback {} converged {} force {} {:.1} ms",
                        rep.fallback,
                        rep.converged,
                        g.force().z,
                        t0.elapsed().as_secs_f64() * 1e3
                    );
                }
                let f = g.force().z;
                let a = if name.starts_with("cone") {
                    sneddon_cone(p.young, p.poisson, alpha, d)
                } else {
                    hertz_bonded(p.young, p.poisson, *lowest, d, p.size[2])
                };
                row += &format!(" {:.2}", f / a);
                all.push(f / a);
            }
            println!("{row}");
        }
    }
    let worst = all.iter().map(|r| (r.ln()).abs()).fold(0.0, f64::max).exp();
    println!("worst factor {worst:.2}");
}
