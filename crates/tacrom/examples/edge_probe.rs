//! scratch
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::sync::Arc;
use tacrom::geometry::*;
use tacrom::mpm::{Gel, GelParams, Solver, SolverOptions};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let solver = args[1].clone();
    let cap: usize = args.get(2).map_or(3000, |s| s.parse().unwrap());
    let x0: f64 = args
        .get(3)
        .map_or(15.506511190259104, |s| s.parse().unwrap())
        * 1e-3;
    let y0: f64 = args
        .get(4)
        .map_or(1.648008636813181, |s| s.parse().unwrap())
        * 1e-3;
    let depths: Vec<f64> = args
        .get(5)
        .map_or("0.6,1.0,1.3,1.5,1.71", |s| s.as_str())
        .split(',')
        .map(|d| d.parse::<f64>().unwrap() * 1e-3)
        .collect();
    let data = load_mesh(
        std::path::Path::new("crates/tacrom/tests/data/cross_lines.stl"),
        1e-3,
    )
    .unwrap();
    let mesh =
        TriMesh::with_options(data.vertices, data.faces, &MeshSdfOptions::default()).unwrap();
    let shape: Arc<dyn Sdf> = Arc::new(mesh);
    let rot = UnitQuaternion::from_euler_angles(
        -3.085342758413833,
        0.013728657889258351,
        -3.00989485073759,
    );
    let turned = Isometry3::from_parts(Translation3::identity(), rot);
    let lowest = shape.aabb().transformed(&turned).min.z;
    let p = GelParams {
        friction: 0.0,
        ..GelParams::default()
    };
    let mut g: Option<Gel> = None;
    for &d in &depths {
        let pose = Isometry3::from_parts(Translation3::new(x0, y0, -lowest - d), rot);
        let placed = [Placed {
            shape: shape.clone(),
            pose,
        }];
        let options = SolverOptions {
            solver: Solver::named(&solver).unwrap(),
            threads: 1,
            max_iterations: cap,
            ..Default::default()
        };
        if g.is_none() || std::env::var_os("FRESH").is_some() {
            g = Some(Gel::new(p.clone(), options).unwrap());
        }
        let g = g.as_mut().unwrap();
        let t = std::time::Instant::now();
        let r = g.solve(&placed);
        println!("d {:.2} mm: force {:.4?} converged {} it {} residual {:.3e} halvings {} det [{:.3}, {:.3}] {:.1} s",
            d * 1e3, g.force().as_slice(), r.converged, r.iterations, r.residual, r.gain_halvings, r.det_f_min, r.det_f_max, t.elapsed().as_secs_f64());
    }
}
