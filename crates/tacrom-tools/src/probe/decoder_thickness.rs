//! Which shipped decoder reads a gel of a given thickness better: `tacrom probe
//! decoder_thickness [T_MM ...]` (default 1, 1.4, 2, 3, 3.5, 4, 6) presses three spheres
//! (radius 2 mm 0.1 mm deep 0.4 mm off centre, 5 mm 0.2 mm deep at the centre, 1 mm 0.08 mm
//! deep 0.7 mm off centre) into a 12 x 12 mm gel of each thickness (Poisson's ratio 0.45)
//! and prints, per press, the depth image's mean absolute error (96 x 96 over 6 x 6 mm,
//! the pixels deeper than 1 um in either) against the relaxation at `T / 8`, and the
//! normal force's error, for the linear coarse gel and `physics="rom"` with each shipped
//! model of the linear gel named. The models read a gel in thicknesses, so a thinner gel
//! shows them the press scaled up (`docs/rom.md`, "Which decoder by thickness").

use nalgebra::Isometry3;
use std::sync::Arc;
use tacrom::config::{
    Config, RawConfig, ATTR_FOV, ATTR_MODEL, ATTR_OUTPUTS, ATTR_PHYSICS, ATTR_POISSON,
    ATTR_RESOLUTION, ATTR_SIZE, ATTR_SOLVER,
};
use tacrom::geometry::{PixelGrid, Placed, Sdf, Sphere};
use tacrom::mpm::{Gel, GelParams, SolverOptions};
use tacrom::sensor::TactileSensor;

const POISSON: f64 = 0.45;
const LATERAL: f64 = 0.012;

/// Runs the probe; `args[0]` is its name, the rest the thicknesses in mm.
pub fn run(args: Vec<String>) {
    let mut thicknesses: Vec<f64> = args[1..]
        .iter()
        .map(|a| a.parse::<f64>().expect("a thickness in mm") * 1e-3)
        .collect();
    if thicknesses.is_empty() {
        thicknesses = vec![1e-3, 1.4e-3, 2e-3, 3e-3, 3.5e-3, 4e-3, 6e-3];
    }
    let presses = [
        (2e-3, 0.1e-3, 0.4e-3),
        (5e-3, 0.2e-3, 0.0),
        (1e-3, 0.08e-3, 0.7e-3),
    ];
    let grid = PixelGrid {
        width: 96,
        height: 96,
        fov_x: 0.006,
        fov_y: 0.006,
    };
    let models = [
        tacrom::rom::LINEAR_MODEL,
        tacrom::rom::LINEAR_NARROW_MODEL,
        tacrom::rom::FAMILY_MODEL,
    ];
    print!("| T mm | sphere | coarse um (force %) |");
    for m in models {
        print!(" {m} um, over coarse (force %) |");
    }
    println!();
    let mut sums = vec![0.0; models.len()];
    for &t in &thicknesses {
        sums.iter_mut().for_each(|s| *s = 0.0);
        for &(r, d, x) in &presses {
            let placed = [Placed {
                shape: Arc::new(Sphere::new(r)) as Arc<dyn Sdf>,
                pose: Isometry3::translation(x, 0.0, r - d),
            }];
            let (reference, reference_force) = relaxation(t, &placed, &grid);
            let sensor = |physics: &str, model: Option<&str>| {
                let mut raw = RawConfig::default()
                    .with(ATTR_PHYSICS, physics)
                    .with(ATTR_SOLVER, "linear")
                    .with(ATTR_POISSON, &POISSON.to_string())
                    .with(ATTR_SIZE, &format!("{LATERAL} {LATERAL} {t}"))
                    .with(ATTR_FOV, &format!("{} {}", grid.fov_x, grid.fov_y))
                    .with(ATTR_RESOLUTION, &format!("{} {}", grid.width, grid.height))
                    .with(ATTR_OUTPUTS, "depth force");
                if let Some(m) = model {
                    raw = raw.with(ATTR_MODEL, m);
                }
                let config = Config::from_raw("probe", &raw).expect("configuration");
                against(config, &placed, &reference, reference_force)
            };
            let (coarse, coarse_force) = sensor("coarse", None);
            print!(
                "| {:.1} | R {:.0} mm, {:.2} mm at {:.1} mm | {:.2} ({:+.1}) |",
                t * 1e3,
                r * 1e3,
                d * 1e3,
                x * 1e3,
                coarse * 1e6,
                coarse_force * 100.0
            );
            for (k, m) in models.iter().enumerate() {
                let (e, f) = sensor("rom", Some(m));
                sums[k] += e;
                print!(" {:.2}, {:.2} ({:+.1}) |", e * 1e6, e / coarse, f * 100.0);
            }
            println!();
        }
        print!("| {:.1} | sum of the three | |", t * 1e3);
        for s in &sums {
            print!(" {:.2} |", s * 1e6);
        }
        println!();
    }
}

/// The relaxation's depth image and normal force at `T / 8` on a gel `t` thick.
fn relaxation(t: f64, placed: &[Placed], grid: &PixelGrid) -> (Vec<f64>, f64) {
    let params = GelParams {
        size: [LATERAL, LATERAL, t],
        poisson: POISSON,
        dx: t / 8.0,
        ..GelParams::default()
    };
    let mut gel = Gel::new(params, SolverOptions::default()).expect("gel");
    let report = gel.solve(placed);
    assert!(report.converged, "the reference at T = {t} m: {report:?}");
    let mut depth = vec![0.0; grid.width * grid.height];
    gel.surface_depth(grid, &mut depth);
    (depth, gel.force().z)
}

/// A sensor of `config` pressed once: its depth image's mean absolute error against
/// `reference` over the pixels deeper than 1 um in either, and its normal force's relative
/// error.
fn against(config: Config, placed: &[Placed], reference: &[f64], force: f64) -> (f64, f64) {
    let mut out = vec![0.0; config.sensordata_len()];
    let mut sensor = TactileSensor::new(config).expect("sensor");
    sensor.evaluate(placed, &mut out);
    let (mut sum, mut n) = (0.0, 0);
    for (a, b) in out[..reference.len()].iter().zip(reference) {
        if a.max(*b) > 1e-6 {
            sum += (a - b).abs();
            n += 1;
        }
    }
    (sum / n.max(1) as f64, sensor.force().z / force - 1.0)
}
