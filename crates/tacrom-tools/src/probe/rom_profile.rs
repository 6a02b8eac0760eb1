//! Where a rom frame's time goes: `tacrom probe rom_profile [SOLVER]
//! [THREADS] [WxH] [REFINE]` presses a 5 mm sphere from 0.1 to 1.0 mm while sliding 1 mm in 20 frames at
//! 320 x 240 (the sensor benchmark's press; `WxH` another resolution, `REFINE` the `refine`
//! attribute) and prints, per frame, the whole evaluation
//! and its stages: gel solve, observation and encoder, refinement (with its L-BFGS
//! evaluations and energy points), dense decoding and image; then a checksum of every
//! frame's sensor data.

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::sync::Arc;
use std::time::Instant;
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{Placed, Sdf, Sphere};
use tacrom::sensor::TactileSensor;

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let solver = args.get(1).map_or("linear", |s| s.as_str());
    let threads = args.get(2).map_or("1", |s| s.as_str());
    let resolution = args
        .get(3)
        .map_or("320 240".to_string(), |s| s.replace('x', " "));
    let mut raw = RawConfig::default().with("resolution", &resolution);
    if let Some(refine) = args.get(4) {
        raw = raw.with("refine", refine);
    }
    let raw = raw
        .with("physics", "rom")
        .with("solver", solver)
        .with("threads", threads);
    let config = Config::from_raw("profile", &raw).expect("config");
    let mut sensor = TactileSensor::new(config.clone()).expect("sensor");
    let mut out = vec![0.0; config.sensordata_len()];
    let sphere: Arc<dyn Sdf> = Arc::new(Sphere::new(0.005));
    // The same gel on its own, to time its solve.
    let options = tacrom::mpm::SolverOptions {
        solver: tacrom::mpm::Solver::named(solver).expect("solver"),
        threads: threads.parse().expect("threads"),
        tolerance: config.tolerance,
        ..Default::default()
    };
    let dx = config.dx.expect("a gel");
    let mut gel = tacrom::mpm::Gel::new(config.gel_params(dx), options).expect("gel");
    println!("frame   total  gel-solve  encode  refine(evals,points)  decode(points)  sink um");
    let frames = 20;
    let mut checksum: u64 = 0xcbf2_9ce4_8422_2325;
    for f in 0..frames {
        let s = f as f64 / (frames - 1) as f64;
        let depth = 0.1e-3 + 0.9e-3 * s;
        let pose = Isometry3::from_parts(
            Translation3::new(-0.5e-3 + 1e-3 * s, 0.0, 0.005 - depth),
            UnitQuaternion::identity(),
        );
        let placed = [Placed {
            shape: sphere.clone(),
            pose,
        }];
        let tg = Instant::now();
        gel.solve(&placed);
        let gel_ms = tg.elapsed().as_secs_f64() * 1e3;
        let t0 = Instant::now();
        let eval = sensor.evaluate(&placed, &mut out);
        let total = t0.elapsed().as_secs_f64() * 1e3;
        let rom = eval.rom.clone().unwrap_or_default();
        let evals = rom.refinement.as_ref().map_or(0, |r| r.evaluations);
        println!(
            "{f:>5} {total:>7.2} {gel_ms:>8.2} {:>7.2} {:>7.2}({evals:>2},{:>4}) {:>7.2}({:>5}) {:>7.1}",
            rom.encode_s * 1e3,
            rom.refine_s * 1e3,
            rom.energy_points,
            rom.decode_s * 1e3,
            rom.decoded,
            rom.bound_excess * 1e6
        );
        checksum = out.iter().fold(checksum, |h, v| {
            (h ^ v.to_bits()).wrapping_mul(0x100_0000_01b3)
        });
    }
    // Every frame's sensor data, bit for bit (a change meant to give the same answers
    // keeps it).
    println!("checksum of the sensor data: {checksum:016x}");
}
