//! Random press sequences through every output of a sensor, looking for what a user's
//! scene could break. Each sequence draws one or two indenters (spheres of radius 0.2 to 8
//! mm, boxes, a capsule, a cylinder and the pattern meshes of `tests/data`, turned at
//! random and tilted up to 0.6 rad), places them anywhere over the gel and up to 3 mm
//! beyond its edge, and moves them for 8 to 24 frames: deeper, shallower (to 2 mm and
//! back), sliding up to 1 mm, twisting, jumping or lifting off. Every frame must give
//! every output finite, depth within `[0, T]`, a force below the gel's whole modulus
//! times its area, and, with friction 0 and the indenters over the top face, a normal
//! force that pushes. A failure names the configuration, the sequence's seed and the
//! frame.
//!
//! `make test` runs a few sequences per mode with a fixed seed; a longer search:
//! `TACROM_FUZZ_SEQUENCES=500 TACROM_FUZZ_SEED=7 cargo test --release -p tacrom --test
//! fuzz -- --nocapture` (and `TACROM_FUZZ_ONLY=SEED` to replay one sequence frame by
//! frame, beside the same poses pressed into a fresh gel; `TACROM_FUZZ_WARNINGS=1` prints
//! every frame that warned).

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;
use tacrom::config::{Config, RawConfig, ATTR_OUTPUTS, ATTR_RESOLUTION};
use tacrom::geometry::*;
use tacrom::sensor::TactileSensor;

/// xorshift64*: numbers in `[0, 1)`.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

/// The shapes drawn from, by name; meshes are turned a half turn about x when drawn, so
/// that their patterned face presses.
fn shapes() -> Vec<(String, Arc<dyn Sdf>)> {
    let mut out: Vec<(String, Arc<dyn Sdf>)> = Vec::new();
    for r in [0.2e-3, 0.5e-3, 2e-3, 5e-3, 8e-3] {
        out.push((format!("sphere r {r}"), Arc::new(Sphere::new(r))));
    }
    for (name, half) in [
        ("box 3x3x2 mm", [1.5e-3, 1.5e-3, 1e-3]),
        ("box 20x8x5 mm", [10e-3, 4e-3, 2.5e-3]),
    ] {
        out.push((name.into(), Arc::new(Cuboid::new(Vector3::from(half)))));
    }
    out.push(("capsule r 1 mm".into(), Arc::new(Capsule::new(1e-3, 6e-3))));
    out.push((
        "cylinder r 3 mm".into(),
        Arc::new(Cylinder::new(3e-3, 2e-3)),
    ));
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let mut paths: Vec<_> = std::fs::read_dir(&dir)
        .expect("tests/data")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "stl"))
        .collect();
    paths.sort();
    for p in paths {
        let data = load_mesh(&p, 1e-3).expect("mesh");
        let mesh = TriMesh::with_options(data.vertices, data.faces, &MeshSdfOptions::default())
            .expect("mesh SDF");
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        out.push((name, Arc::new(mesh)));
    }
    out
}

/// The lowest corner of `shape`'s bounding box turned by `rotation`, below its origin (m).
fn lowest(shape: &dyn Sdf, rotation: &UnitQuaternion<f64>) -> f64 {
    let turned = Isometry3::from_parts(Translation3::identity(), *rotation);
    shape.aabb().transformed(&turned).min.z
}

/// One indenter of a sequence: its shape, rotation, position on the gel and press depth
/// (below the top face, of its bounding box's lowest corner).
type Body = (usize, UnitQuaternion<f64>, Vector3<f64>, f64);

fn draw(rng: &mut Rng, shapes: &[(String, Arc<dyn Sdf>)], size: [f64; 3]) -> Body {
    let s = (rng.next() * shapes.len() as f64) as usize;
    let flip = if shapes[s].0.ends_with(".stl") {
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    } else {
        UnitQuaternion::identity()
    };
    let tilt = UnitQuaternion::from_euler_angles(
        rng.range(-0.6, 0.6) * rng.next(),
        rng.range(-0.6, 0.6) * rng.next(),
        rng.range(-3.2, 3.2),
    );
    let at = Vector3::new(
        rng.range(-0.5 * size[0] - 3e-3, 0.5 * size[0] + 3e-3),
        rng.range(-0.5 * size[1] - 3e-3, 0.5 * size[1] + 3e-3),
        0.0,
    );
    (s, tilt * flip, at, rng.range(0.0, 0.6e-3))
}

fn place(bodies: &[Body], shapes: &[(String, Arc<dyn Sdf>)]) -> Vec<Placed> {
    bodies
        .iter()
        .map(|(s, rot, at, depth)| {
            let shape = shapes[*s].1.clone();
            let z = -lowest(&*shape, rot) - depth;
            Placed {
                shape,
                pose: Isometry3::from_parts(Translation3::from(at + Vector3::z() * z), *rot),
            }
        })
        .collect()
}

/// The next frame's move of each body: deeper, shallower, a slide, a twist, a jump or a
/// lift off the gel.
fn step(rng: &mut Rng, bodies: &mut [Body]) {
    for body in bodies.iter_mut() {
        match (rng.next() * 6.0) as usize {
            0 => body.3 = (body.3 + rng.range(0.0, 0.4e-3)).min(2e-3),
            1 => body.3 = (body.3 - rng.range(0.0, 0.4e-3)).max(-0.2e-3),
            2 => body.2 += Vector3::new(rng.range(-1e-3, 1e-3), rng.range(-1e-3, 1e-3), 0.0),
            3 => {
                let turn =
                    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.range(-0.3, 0.3));
                body.1 = turn * body.1;
            }
            4 => body.3 = rng.range(0.0, 2e-3),
            _ => body.3 = -1e-3,
        }
    }
}

/// What is wrong with a frame's outputs `out` (depth, then force) for indenters
/// `placed`, if anything.
fn check(config: &Config, placed: &[Placed], out: &[f64]) -> Option<String> {
    if let Some(i) = out.iter().position(|v| !v.is_finite()) {
        return Some(format!("output {i} is {}", out[i]));
    }
    let n = config.width * config.height;
    let t = config.size[2];
    let (lo, hi) = out[..n]
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    if lo < 0.0 || hi > t * (1.0 + 1e-9) {
        return Some(format!("depth in [{lo}, {hi}] m, the gel {t} m thick"));
    }
    let force = Vector3::new(out[n], out[n + 1], out[n + 2]);
    // Every particle of the gel at a strain of one over its whole face would carry this.
    let bound = config.young * config.size[0] * config.size[1];
    if force.norm() > bound {
        return Some(format!("force {force:?} N beyond {bound} N"));
    }
    // Without friction, and with the indenters over the top face (not pressing the gel's
    // sides), every contact force lies along a contact normal of the top surface, which
    // the indenters press down: the normal force pushes.
    let over_the_face = placed.iter().all(|p| {
        let b = p.aabb();
        b.min.x.abs().max(b.max.x.abs()) < 0.5 * config.size[0]
            && b.min.y.abs().max(b.max.y.abs()) < 0.5 * config.size[1]
    });
    if config.friction == 0.0 && over_the_face && force.z < -1e-6 * force.norm().max(1e-3) {
        return Some(format!("frictionless normal force {} N", force.z));
    }
    None
}

/// Runs `sequences` random sequences on a sensor of `spec` (`key=value,...`); returns
/// the failures and a count of the warnings given (their text up to the first number).
fn run(
    spec: &str,
    sequences: usize,
    seed: u64,
    only: Option<u64>,
) -> (Vec<String>, BTreeMap<String, usize>) {
    let shapes = shapes();
    let mut raw = RawConfig::default()
        .with(
            ATTR_OUTPUTS,
            "depth force contact rgb pressure shear markers",
        )
        .with(ATTR_RESOLUTION, "80 60");
    for kv in spec.split(',') {
        let (k, v) = kv.split_once('=').expect("key=value");
        raw = raw.with(k, v);
    }
    let config = Config::from_raw("fuzz", &raw).expect("config");
    let (mut failures, mut warnings) = (Vec::new(), BTreeMap::new());
    let show_warnings = std::env::var_os("TACROM_FUZZ_WARNINGS").is_some();
    let mut seq_seed = seed;
    for _ in 0..sequences {
        seq_seed = seq_seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        let this = only.unwrap_or(seq_seed);
        let mut rng = Rng(this | 1);
        let mut sensor = TactileSensor::new(config.clone()).expect("sensor");
        let mut out = vec![0.0; config.sensordata_len()];
        let count = if rng.next() < 0.2 { 2 } else { 1 };
        let mut bodies: Vec<Body> = (0..count)
            .map(|_| draw(&mut rng, &shapes, config.size))
            .collect();
        let frames = 8 + (rng.next() * 17.0) as usize;
        for f in 0..frames {
            let placed = place(&bodies, &shapes);
            let outcome = catch_unwind(AssertUnwindSafe(|| sensor.evaluate(&placed, &mut out)));
            let problem = match &outcome {
                Err(_) => Some("panic".to_owned()),
                Ok(eval) => {
                    for w in &eval.warnings {
                        let kind = w.split(|c: char| c.is_ascii_digit()).next().unwrap_or(w);
                        *warnings.entry(kind.to_owned()).or_insert(0) += 1;
                        if show_warnings {
                            println!(
                                "{spec} TACROM_FUZZ_ONLY={this} frame {f}: {w}; {}",
                                describe(&bodies, &shapes)
                            );
                        }
                    }
                    check(&config, &placed, &out)
                }
            };
            if only.is_some() {
                let mut fresh = TactileSensor::new(config.clone()).expect("sensor");
                let mut again = vec![0.0; out.len()];
                fresh.evaluate(&placed, &mut again);
                let n = config.width * config.height;
                let solved = outcome.as_ref().ok().and_then(|e| e.solve.as_ref());
                println!(
                    "frame {f}: {}; force {:?} N, a fresh gel's {:?} N; {}",
                    describe(&bodies, &shapes),
                    &out[n..n + 3],
                    &again[n..n + 3],
                    solved.map_or("no solve".into(), |r| format!(
                        "fallback {}, {} iterations, converged {}",
                        r.fallback, r.iterations, r.converged
                    ))
                );
            }
            if let Some(problem) = problem {
                failures.push(format!(
                    "{spec}: {problem}; TACROM_FUZZ_ONLY={this}, frame {f}: {}",
                    describe(&bodies, &shapes)
                ));
                break;
            }
            step(&mut rng, &mut bodies);
        }
        if only.is_some() {
            break;
        }
    }
    (failures, warnings)
}

fn describe(bodies: &[Body], shapes: &[(String, Arc<dyn Sdf>)]) -> String {
    bodies
        .iter()
        .map(|(s, r, at, d)| {
            format!(
                "{} turned {:?} at {:?} pressed {d:.2e}",
                shapes[*s].0,
                r.euler_angles(),
                at.as_slice()
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
}

fn env<T: std::str::FromStr>(name: &str) -> Option<T> {
    std::env::var(name).ok().and_then(|v| v.parse().ok())
}

/// The default modes, the linear solver and Newton's method, with the default friction
/// and without.
#[test]
fn random_press_sequences_keep_every_output_sound() {
    let sequences = env("TACROM_FUZZ_SEQUENCES").unwrap_or(4);
    let seed = env("TACROM_FUZZ_SEED").unwrap_or(1);
    let only = env("TACROM_FUZZ_ONLY");
    let specs = std::env::var("TACROM_FUZZ_CONFIGS").unwrap_or_else(|_| {
        "physics=rom;physics=coarse;physics=coarse,friction=0;\
         physics=rom,solver=linear;physics=coarse,solver=linear,friction=0;\
         physics=coarse,solver=newton;physics=coarse,solver=newton,friction=0"
            .into()
    });
    let mut failures = Vec::new();
    for spec in specs.split(';') {
        let (f, warnings) = run(spec, sequences, seed, only);
        println!("{spec}: {} failure(s); warnings {warnings:?}", f.len());
        failures.extend(f);
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
