//! How much of the decoder's region carries its correction: `tacrom probe rom_region`
//! presses a 5 mm sphere and a 10 mm flat cylinder 0.2, 0.5 and 1.0 mm into the default
//! gel on the linear solver, decodes with `models/rom-linear`, and prints, per band of
//! the coarse depth (and for the points the region's growth added), how many lattice
//! points the decoder ran at and the largest and mean size of its correction (decoded
//! minus coarse depth, um).

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::sync::Arc;
use tacrom::geometry::{Cylinder, Placed, Sdf, Sphere};
use tacrom::rom::features::{region, Observation};
use tacrom::rom::{Rom, RomOptions};

/// Runs the probe; `args[0]` is its name.
pub fn run(_args: Vec<String>) {
    let dir = tacrom::rom::shipped_model_dir("rom-linear").expect("models/rom-linear");
    let mut rom = Rom::load(
        &dir,
        RomOptions {
            refine: None,
            threads: 1,
            pressure: false,
            force: false,
        },
    )
    .expect("model");
    let spec = rom.manifest().lattice;
    let (eps, grow) = rom.manifest().region;
    let options = tacrom::mpm::SolverOptions {
        solver: tacrom::mpm::Solver::Linear,
        threads: 1,
        ..Default::default()
    };
    let shapes: [(&str, Arc<dyn Sdf>); 2] = [
        ("sphere R5", Arc::new(Sphere::new(0.005))),
        ("flat cylinder R5", Arc::new(Cylinder::new(0.005, 0.005))),
    ];
    println!("shape, depth mm | band (coarse um) | points | max |corr| um | mean |corr| um");
    for (name, shape) in shapes {
        for depth in [0.2e-3, 0.5e-3, 1.0e-3] {
            let params = tacrom::mpm::GelParams {
                dx: 0.0014,
                ..Default::default()
            };
            let mut gel = tacrom::mpm::Gel::new(params, options).expect("gel");
            let placed = [Placed {
                shape: shape.clone(),
                pose: Isometry3::from_parts(
                    Translation3::new(0.0, 0.0, shape.aabb().max.z.abs() - depth),
                    UnitQuaternion::identity(),
                ),
            }];
            gel.solve(&placed);
            let obs = Observation::from_gel(&gel, &placed, &spec);
            rom.infer(&obs).expect("infer");
            let mut seed = Vec::new();
            region(&obs, &spec, eps, 0, &mut Vec::new(), &mut seed);
            let mut grown = Vec::new();
            region(&obs, &spec, eps, grow, &mut Vec::new(), &mut grown);
            let decoded = rom.lattice_depth();
            let bands = [
                (0.0, 1.0),
                (1.0, 10.0),
                (10.0, 30.0),
                (30.0, 100.0),
                (100.0, 1e9),
            ];
            let mut rows = vec![(0usize, 0.0f64, 0.0f64); bands.len() + 1];
            for i in 0..spec.points() {
                if !grown[i] {
                    continue;
                }
                let c = obs.coarse[i] * 1e6;
                let corr = (decoded[i] - obs.coarse[i]).abs() * 1e6;
                let k = if !seed[i] {
                    bands.len()
                } else {
                    bands
                        .iter()
                        .position(|&(a, b)| c >= a && c < b)
                        .unwrap_or(0)
                };
                let r = &mut rows[k];
                r.0 += 1;
                r.1 = r.1.max(corr);
                r.2 += corr;
            }
            for (k, r) in rows.iter().enumerate() {
                let band = match bands.get(k) {
                    Some((a, b)) => format!("{a}..{b}"),
                    None => "grown".to_owned(),
                };
                if r.0 > 0 {
                    println!(
                        "{name}, {:.1} | {band} | {} | {:.3} | {:.3}",
                        depth * 1e3,
                        r.0,
                        r.1,
                        r.2 / r.0 as f64
                    );
                }
            }
        }
    }
}
