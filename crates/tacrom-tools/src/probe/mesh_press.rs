//! A pattern mesh pressed into the gel, each solver side by side, for comparing their
//! forces and costs on a shape other than a sphere:
//!
//! `tacrom probe mesh_press MESH DX_M FRICTION DEPTHS_MM SOLVERS`
//!
//! (defaults: ../shared/indenters/patterns/hexagon.stl 1.4e-3 0 "0.2,0.5,1.0"
//! "relaxation,newton,linear"). The mesh (millimetres) is turned a half turn about x, so
//! that the face at its top presses, and centred over the gel. Prints each press's time,
//! iterations, convergence and normal force.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use std::sync::Arc;
use std::time::Instant;
use tacrom::geometry::*;

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let path = args
        .get(1)
        .cloned()
        .unwrap_or_else(|| "../shared/indenters/patterns/hexagon.stl".into());
    let dx: f64 = args.get(2).map_or(1.4e-3, |s| s.parse().unwrap());
    let friction: f64 = args.get(3).map_or(0.0, |s| s.parse().unwrap());
    let depths: Vec<f64> = args
        .get(4)
        .map_or("0.2,0.5,1.0", |s| s.as_str())
        .split(',')
        .map(|d| d.parse::<f64>().unwrap() * 1e-3)
        .collect();
    let solvers = args
        .get(5)
        .cloned()
        .unwrap_or_else(|| "relaxation,newton,linear".into());
    let data = load_mesh(std::path::Path::new(&path), 1e-3).expect("mesh");
    let rotation = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    let mesh = TriMesh::with_options(data.vertices, data.faces, &MeshSdfOptions::default())
        .expect("mesh sdf");
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for p in mesh.vertices() {
        let q = rotation * p;
        lo = lo.inf(&q.coords);
        hi = hi.sup(&q.coords);
    }
    let anchor = Vector3::new(0.5 * (lo.x + hi.x), 0.5 * (lo.y + hi.y), lo.z);
    let shape: Arc<dyn Sdf> = Arc::new(mesh);
    for name in solvers.split(',') {
        let solver = tacrom::mpm::Solver::named(name).expect("solver");
        let params = tacrom::mpm::GelParams {
            dx,
            friction,
            ..Default::default()
        };
        let options = tacrom::mpm::SolverOptions {
            solver,
            ..Default::default()
        };
        let mut g = tacrom::mpm::Gel::new(params, options).unwrap();
        for &d in &depths {
            let pose =
                Isometry3::from_parts(Translation3::from(-anchor - Vector3::z() * d), rotation);
            let t0 = Instant::now();
            let r = g.solve(&[Placed {
                shape: shape.clone(),
                pose,
            }]);
            println!(
                "{name} d {:.2} mm: {:.1} ms it {} conv {} res {:.2e} active {} Fz {:.5} N",
                d * 1e3,
                t0.elapsed().as_secs_f64() * 1e3,
                r.iterations,
                r.converged,
                r.residual,
                r.active_particles,
                g.force().z
            );
        }
    }
}
