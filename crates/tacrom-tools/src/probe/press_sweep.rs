//! `tacrom/Press-v1`'s smooth sweep without MuJoCo: `tacrom probe press_sweep [FRAMES]
//! [WxH] [SOLVER] [TOLERANCE]` moves a 5 mm sphere as `examples/rl_throughput.py --policy sweep` asks
//! (x = 5 mm sin(2 pi k / 40), pressed 0.5 to 1 mm), one frame a step, through the default
//! sensor (`WxH`, default 64 x 48) and through its gel alone, and prints the median and mean
//! ms per frame of the evaluation and of its stages, with the gel's Newton steps and
//! contact points per frame, and a digest of every frame's sensor data (FNV-1a over the
//! values' bits): a change meant only to be faster leaves it as it was.

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::sync::Arc;
use std::time::Instant;
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{Placed, Sdf, Sphere};
use tacrom::sensor::TactileSensor;

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let frames: usize = args.get(1).map_or(400, |s| s.parse().expect("frames"));
    let resolution = args
        .get(2)
        .map_or("64 48".to_string(), |s| s.replace('x', " "));
    let solver = args.get(3).map_or("linear", |s| s.as_str());
    let mut raw = RawConfig::default()
        .with("resolution", &resolution)
        .with("solver", solver)
        .with("threads", "1");
    if let Some(tolerance) = args.get(4) {
        raw = raw.with("tolerance", tolerance);
    }
    let config = Config::from_raw("sweep", &raw).expect("config");
    let mut sensor = TactileSensor::new(config.clone()).expect("sensor");
    let mut out = vec![0.0; config.sensordata_len()];
    let options = tacrom::mpm::SolverOptions {
        solver: tacrom::mpm::Solver::named(solver).expect("solver"),
        threads: 1,
        tolerance: config.tolerance,
        ..Default::default()
    };
    let dx = config.dx.expect("a gel");
    let mut gel = tacrom::mpm::Gel::new(config.gel_params(dx), options).expect("gel");
    let sphere: Arc<dyn Sdf> = Arc::new(Sphere::new(0.005));
    let (mut total, mut gel_ms, mut encode, mut decode) = (vec![], vec![], vec![], vec![]);
    let (mut newton, mut points, mut passes) = (0usize, 0usize, 0usize);
    let mut digest: u64 = 0xcbf2_9ce4_8422_2325;
    for k in 0..frames {
        let phase = 2.0 * std::f64::consts::PI * k as f64 / 40.0;
        let x = 5e-3 * phase.sin();
        let depth = 0.5e-3 + 0.5e-3 * (0.5 + 0.5 * (phase / 3.0).sin());
        let pose = Isometry3::from_parts(
            Translation3::new(x, 0.0, 0.005 - depth),
            UnitQuaternion::identity(),
        );
        let placed = [Placed {
            shape: sphere.clone(),
            pose,
        }];
        let t = Instant::now();
        let report = gel.solve(&placed);
        gel_ms.push(t.elapsed().as_secs_f64() * 1e3);
        newton += report.cg_iterations;
        points += report.active_particles;
        passes += report.iterations;
        let t = Instant::now();
        let eval = sensor.evaluate(&placed, &mut out);
        total.push(t.elapsed().as_secs_f64() * 1e3);
        for v in &out {
            for byte in v.to_bits().to_le_bytes() {
                digest = (digest ^ u64::from(byte)).wrapping_mul(0x0100_0000_01b3);
            }
        }
        let rom = eval.rom.unwrap_or_default();
        encode.push(rom.encode_s * 1e3);
        decode.push(rom.decode_s * 1e3);
    }
    let stat = |v: &mut Vec<f64>| {
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        v.sort_by(f64::total_cmp);
        (v[v.len() / 2], mean)
    };
    let f = frames as f64;
    println!("stage            median ms   mean ms");
    for (name, v) in [
        ("evaluation", &mut total),
        ("gel alone", &mut gel_ms),
        ("observe+encode", &mut encode),
        ("decode", &mut decode),
    ] {
        let (m, mean) = stat(v);
        println!("{name:<16} {m:>9.3} {mean:>9.3}");
    }
    println!(
        "gel per frame: {:.2} passes, {:.2} Newton steps, {:.1} pressed points",
        passes as f64 / f,
        newton as f64 / f,
        points as f64 / f
    );
    println!("sensor data digest: {digest:016x}");
}
