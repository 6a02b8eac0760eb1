//! The gel's own surface under a flat bar (8 x 2 mm face, pressed 0.5 mm from rest), row by
//! row, and the deepest surface point with its distance below the bar's face: a rigid flat
//! face holds an elastic layer's surface at its own depth, so any point deeper than 500 um
//! is an error of the discretisation (see `tests/stability.rs`).
//!
//! `tacrom probe overshoot [relaxation|newton] [TOLERANCE]
//! [dx=MM] [poisson=NU] [friction=MU]`

use std::sync::Arc;

use nalgebra::{Isometry3, Vector3};
use tacrom::geometry::{Cuboid, Placed, Sdf};
use tacrom::mpm::{Gel, GelParams, Solver, SolverOptions};

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let mut args = args.into_iter().skip(1);
    let solver = match args.next().as_deref() {
        Some("newton") => Solver::Newton,
        _ => Solver::Relaxation,
    };
    let tolerance = args
        .next()
        .map_or(1e-3, |t| t.parse().expect("a tolerance"));
    let options = SolverOptions {
        solver,
        tolerance,
        ..SolverOptions::default()
    };
    let mut params = GelParams::default();
    for kv in args {
        let (k, v) = kv.split_once('=').expect("KEY=VALUE");
        let v: f64 = v.parse().expect("a number");
        match k {
            "dx" => params.dx = v * 1e-3,
            "poisson" => params.poisson = v,
            "friction" => params.friction = v,
            _ => panic!("unknown parameter {k}"),
        }
    }
    let mut g = Gel::new(params, options).expect("a valid gel");
    let bar: Arc<dyn Sdf> = Arc::new(Cuboid::new(Vector3::new(0.004, 0.001, 0.002)));
    let placed = Placed {
        shape: bar,
        pose: Isometry3::translation(0.0, 0.0, 0.002 - 0.5e-3),
    };
    let report = g.solve(std::slice::from_ref(&placed));
    println!(
        "{solver:?}, tolerance {tolerance:e}: {} iterations",
        report.iterations
    );
    let xs = [
        -4.55, -3.85, -3.15, -2.45, -1.75, -1.05, -0.35, 0.35, 1.05, 1.75, 2.45,
    ];
    println!("depth (um) at rest positions x (mm) = {xs:?}");
    for y in [-1.75, -1.05, -0.35, 0.35] {
        let row: Vec<String> = xs
            .iter()
            .map(|&x| {
                format!(
                    "{:6.1}",
                    -g.surface_displacement(x * 1e-3, y * 1e-3).z * 1e6
                )
            })
            .collect();
        println!("  y {y:5.2} mm: {}", row.join(" "));
    }
    // Rest positions of the top particles: the lattice is 2 per cell, centred.
    let h = 0.5 * g.params().dx;
    let at: Vec<f64> = (0..12).map(|k| (k as f64 + 0.5) * h).collect();
    let row: Vec<String> = at
        .iter()
        .map(|&x| format!("{:6.1}", -g.surface_displacement(x, 0.5 * h).z * 1e6))
        .collect();
    println!(
        "top particles at y = {:.3} mm, x = (k + 1/2) {:.3} mm: {}",
        0.5 * h * 1e3,
        h * 1e3,
        row.join(" ")
    );
    let mut worst = (0.0, 0.0, 0.0);
    for a in 0..=240 {
        for b in 0..=240 {
            let (x, y) = (-6e-3 + 5e-5 * a as f64, -6e-3 + 5e-5 * b as f64);
            let d = -g.surface_displacement(x, y).z;
            if d > worst.0 {
                worst = (d, x, y);
            }
        }
    }
    let (d, x, y) = worst;
    println!(
        "deepest surface point: {:.1} um at rest position ({:.2}, {:.2}) mm, {:.1} um below the face",
        d * 1e6,
        x * 1e3,
        y * 1e3,
        (d - 0.5e-3) * 1e6
    );
}
