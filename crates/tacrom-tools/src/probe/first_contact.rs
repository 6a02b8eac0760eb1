//! What a fresh sensor costs before its first ordinary frame: `tacrom probe first_contact
//! [PHYSICS] [SOLVER] [THREADS] [WIDTH HEIGHT]` (defaults: rom linear 1 320 240) builds the
//! sensor, presses a 5 mm sphere 0.5 mm deep into it, then 20 more frames sliding 1 mm,
//! and prints the load's time, the first contact's and the median of the rest (ms). The
//! gel cache is the environment's (`TACROM_CACHE`; `off` measures a load that computes
//! everything).

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::sync::Arc;
use std::time::Instant;
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{Placed, Sdf, Sphere};
use tacrom::sensor::TactileSensor;

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let arg = |i: usize, default: &str| args.get(i).map_or(default.to_owned(), |s| s.clone());
    let (physics, solver, threads) = (arg(1, "rom"), arg(2, "linear"), arg(3, "1"));
    let resolution = format!("{} {}", arg(4, "320"), arg(5, "240"));
    let mut raw = RawConfig::default()
        .with("physics", &physics)
        .with("threads", &threads)
        .with("resolution", &resolution);
    if solver != "auto" {
        raw = raw.with("solver", &solver);
    }
    let config = Config::from_raw("probe", &raw).expect("config");
    let t0 = Instant::now();
    let mut sensor = TactileSensor::new(config.clone()).expect("sensor");
    let load = t0.elapsed().as_secs_f64() * 1e3;
    let mut out = vec![0.0; config.sensordata_len()];
    let sphere: Arc<dyn Sdf> = Arc::new(Sphere::new(0.005));
    let mut frame = |x: f64| {
        let placed = [Placed {
            shape: sphere.clone(),
            pose: Isometry3::from_parts(
                Translation3::new(x, 0.0, 0.005 - 0.5e-3),
                UnitQuaternion::identity(),
            ),
        }];
        let t = Instant::now();
        let eval = sensor.evaluate(&placed, &mut out);
        assert!(eval.contact);
        t.elapsed().as_secs_f64() * 1e3
    };
    let first = frame(-0.5e-3);
    let mut rest: Vec<f64> = (1..=20)
        .map(|k| frame(-0.5e-3 + 1e-3 * k as f64 / 20.0))
        .collect();
    rest.sort_by(f64::total_cmp);
    println!("physics {physics}, solver {solver}, {threads} thread(s), {resolution}");
    println!("load ms  first contact ms  median of the next 20 ms  max ms");
    println!(
        "{load:7.1}  {first:16.1}  {:24.2}  {:6.2}",
        rest[rest.len() / 2],
        rest[rest.len() - 1]
    );
}
