//! Force (N) of a frictionless capsule lying on the default gel, tilted along its axis and
//! turned about the vertical, pressed 0.05 to 0.3 mm (deepest point): `tacrom probe ridge SOLVER DX_MM [RADIUS_MM [YAW_RAD [TILT_RAD]]]` (defaults: radius
//! 0.5 mm, yaw 0, tilt 0.12; half-length 3 mm). A `*` marks a solve that did not converge.
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use std::sync::Arc;
use tacrom::geometry::{Capsule, Placed, Sdf};
use tacrom::mpm::{Gel, GelParams, Solver, SolverOptions};

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let arg = |i: usize, default: f64| args.get(i).map_or(default, |v| v.parse().unwrap());
    let solver = args.get(1).cloned().unwrap_or_else(|| "linear".into());
    let (dx, r, yaw, tilt) = (arg(2, 1.4), arg(3, 0.5) * 1e-3, arg(4, 0.0), arg(5, 0.12));
    let half = 3e-3;
    let p = GelParams {
        friction: 0.0,
        dx: dx * 1e-3,
        ..GelParams::default()
    };
    let options = SolverOptions {
        solver: Solver::named(&solver).unwrap(),
        threads: 2,
        max_iterations: 20000,
        ..Default::default()
    };
    let mut g = Gel::new(p, options).unwrap();
    let cap: Arc<dyn Sdf> = Arc::new(Capsule::new(r, half));
    // The capsule's axis is its local z: lay it along x, tilt it about y, turn it about z.
    let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
        * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::FRAC_PI_2 + tilt);
    // Lowest point of the tilted capsule: an end cap's bottom.
    let lowest = r + half * tilt.sin();
    let mut row = format!("{solver} dx {dx} r {:.2} yaw {yaw} tilt {tilt}:", r * 1e3);
    for d in [0.05e-3, 0.1e-3, 0.2e-3, 0.3e-3] {
        let pose = Isometry3::from_parts(Translation3::new(0.0, 0.0, lowest - d), rot);
        let rep = g.solve(&[Placed {
            shape: cap.clone(),
            pose,
        }]);
        row += &format!(
            " {:.4}{}",
            g.force().z,
            if rep.converged { "" } else { "*" }
        );
    }
    println!("{row}");
}
