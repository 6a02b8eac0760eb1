//! Tests of the MPM gel.
use super::*;
use crate::geometry::Sphere;

fn sphere_at(r: f64, x: f64, y: f64, z: f64) -> Placed {
    Placed { shape: Arc::new(Sphere { radius: r }), pose: Isometry3::translation(x, y, z) }
}

#[test]
#[ignore]
fn debug_trace() {
    let params = GelParams { friction: 0.0, ..Default::default() };
    let opts = SolverOptions { max_iterations: 40, ..Default::default() };
    let mut gel = Gel::new(params, opts).unwrap();
    let s = sphere_at(5e-3, 0.0, 0.0, 5e-3 - 0.1e-3);
    let rep = gel.solve(&[s]);
    let active = gel.columns.iter().filter(|c| c.active).count();
    let gmin = gel.columns.iter().filter(|c| c.active).map(|c| c.g).fold(f32::INFINITY, f32::min);
    println!("{rep:?} active {active} gmin {gmin} force {:?}", gel.force());
    let zmin = gel.top.iter().map(|&i| gel.particles[i as usize].x.z).fold(f32::INFINITY, f32::min);
    let zmax = gel.top.iter().map(|&i| gel.particles[i as usize].x.z).fold(f32::NEG_INFINITY, f32::max);
    println!("top z range {zmin} {zmax} ref {}", gel.top_ref[0].z);
}

