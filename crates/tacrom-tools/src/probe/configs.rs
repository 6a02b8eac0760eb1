//! Random configurations loaded and evaluated in one process: `tacrom probe configs
//! [COUNT] [SEED] [MAX_CELLS]` draws `COUNT` sensor configurations (default 1,000, seed 1)
//! from the attribute table (`tacrom::attributes`), loads each as a plugin instance would
//! (`Config::from_raw`, then `TactileSensor::new`) and evaluates three frames (a random
//! shape pressed somewhere over the gel, the same slid and turned, then a pose with NaN in
//! it), then drops it. Every attribute is set with some chance, to a value inside its
//! range, at an end of it, just outside it or not a number at all; each mode (`rigid`,
//! `coarse` with any solver, `rom` with any shipped model) is drawn. Left out: `fine`
//! (seconds a frame), the attributes that name files or bodies of a scene (`optics`,
//! `indenters`, `gel_geom`), gels of more than `MAX_CELLS` grid cells (default 50,000;
//! the plugin accepts up to 2e7), and new gels on the linear solver (each one's surface
//! compliance takes tens of seconds: those keep their sensor's gel; every model but
//! `rom-default` runs on it), so that thousands of
//! configurations fit in minutes. Counts per mode of configurations loaded, refused (with the attribute named)
//! and evaluated, panics (each printed with its configuration, to replay), non-finite
//! outputs, and the resident memory (free heap pages handed back first) at each tenth.
//! With `TACROM_CONFIGS_TRACE` set, each configuration is printed before it is loaded;
//! `TACROM_CONFIGS_ONLY=I` evaluates configuration `I` alone (the others are drawn, not
//! loaded), to replay one.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand_core::{Rng as _, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::collections::BTreeMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;
use std::time::Instant;
use tacrom::attributes::{Valid, TABLE};
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{Capsule, Cuboid, Cylinder, Placed, Sdf, Sphere};
use tacrom::sensor::TactileSensor;

/// Attributes the campaign does not set: they name files or the scene's bodies.
const SKIPPED: [&str; 3] = ["optics", "indenters", "gel_geom"];

/// The shipped models a `rom` configuration may name (and one that does not exist).
const MODELS: [&str; 5] = [
    "rom-linear-narrow",
    "rom-linear",
    "rom-default",
    "rom-family",
    "no-such-model",
];

struct Rng(Xoshiro256PlusPlus);

impl Rng {
    fn unit(&mut self) -> f64 {
        (self.0.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }
    fn below(&mut self, n: usize) -> usize {
        (self.unit() * n as f64) as usize % n.max(1)
    }
    fn between(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    /// Log-uniform in `[lo, hi]` (both positive).
    fn log_between(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + (hi.ln() - lo.ln()) * self.unit()).exp()
    }
    fn pick<'a>(&mut self, words: &[&'a str]) -> &'a str {
        words[self.below(words.len())]
    }
}

/// A value that is not a valid number, or a number outside every range.
fn garbage(rng: &mut Rng) -> String {
    rng.pick(&[
        "nan",
        "inf",
        "-inf",
        "-1",
        "0",
        "1e400",
        "abc",
        "1 2 3 4 5",
        "",
        "1,5",
    ])
    .to_string()
}

/// A number for a range `[lo, hi]`: mostly inside (log-uniform where it spans decades),
/// sometimes an end or just outside.
fn in_range(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    let u = rng.unit();
    if u < 0.08 {
        lo
    } else if u < 0.16 {
        hi
    } else if u < 0.18 {
        lo - 0.01 * (hi - lo).abs() - 1e-12
    } else if u < 0.2 {
        hi * 1.01 + 1e-12
    } else if lo > 0.0 && hi / lo > 100.0 {
        rng.log_between(lo, hi)
    } else {
        rng.between(lo, hi)
    }
}

/// One random configuration: `(attribute, value)` pairs in MJCF's text.
fn draw(rng: &mut Rng) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = Vec::new();
    let physics = rng.pick(&["rigid", "rigid", "coarse", "rom"]);
    out.push(("physics".into(), physics.into()));
    // The gel's size first: the cell cap below needs its thickness.
    let mut thickness = 0.004;
    for a in TABLE.iter() {
        let name = a.name;
        if name == "physics" || SKIPPED.contains(&name) || !rng.chance(0.3) {
            continue;
        }
        if rng.chance(0.01) {
            out.push((name.into(), garbage(rng)));
            continue;
        }
        let value = match (name, a.valid) {
            ("sensor", _) => rng
                .pick(&["gelsight-mini", "gelsight-mini", "no-such-sensor"])
                .into(),
            ("size", _) => {
                let (x, y) = (rng.log_between(0.005, 0.06), rng.log_between(0.005, 0.06));
                thickness = rng.log_between(0.0005, 0.008);
                format!("{x} {y} {thickness}")
            }
            ("fov", _) => format!(
                "{} {}",
                rng.log_between(0.002, 0.04),
                rng.log_between(0.002, 0.04)
            ),
            ("dx", _) => format!("{}", thickness * rng.log_between(0.08, 0.6)),
            ("model", _) => rng.pick(&MODELS).into(),
            ("camera", _) => match rng.chance(0.5) {
                true => "orthographic".into(),
                false => format!("pinhole {}", rng.log_between(0.003, 1.0)),
            },
            ("resolution", _) => {
                let w = rng.log_between(1.0, 400.0).round();
                let h = rng.log_between(1.0, 300.0).round();
                format!("{w} {h}")
            }
            ("markers", Valid::Integers { .. }) => {
                format!("{} {}", 1 + rng.below(40), 1 + rng.below(40))
            }
            ("threads", _) => format!("{}", 1 + rng.below(2)),
            (_, Valid::Range(r)) => format!("{}", in_range(rng, r.lo, r.hi)),
            (_, Valid::Integers { lo, hi }) => {
                format!("{}", in_range(rng, lo as f64, hi as f64).round())
            }
            (_, Valid::Words { words, several }) => {
                if several {
                    let chosen: Vec<&str> =
                        words.iter().copied().filter(|_| rng.chance(0.4)).collect();
                    chosen.join(" ")
                } else {
                    rng.pick(words).into()
                }
            }
            _ => continue,
        };
        out.push((name.into(), value));
    }
    // On the linear gel (the `linear` solver, and `rom`'s default model) each new gel's
    // surface compliance takes tens of seconds to compute: those configurations keep the
    // gel of their sensor (the default or a named one), with or without friction.
    let set = |a: &str| out.iter().find(|(n, _)| n == a).map(|(_, v)| v.clone());
    let model = set("model").unwrap_or_default();
    let linear = match set("solver").as_deref() {
        Some("linear") => true,
        None => physics == "rom" && model != "rom-default",
        Some(_) => false,
    };
    if linear {
        out.retain(|(a, _)| !GEL.contains(&a.as_str()));
    }
    out
}

/// The attributes that make a gel (its surface compliance's cache key).
const GEL: [&str; 6] = ["size", "dx", "young", "poisson", "density", "material"];

/// A random shape pressed somewhere over a gel of `size` (m): its pose for frame `k` of
/// three (the third has NaN in its translation).
fn scene(rng: &mut Rng, size: [f64; 3]) -> (Arc<dyn Sdf>, [Isometry3<f64>; 3]) {
    let r = rng.log_between(2e-4, 0.01);
    let shape: Arc<dyn Sdf> = match rng.below(4) {
        0 => Arc::new(Sphere::new(r)),
        1 => Arc::new(Cuboid::new(Vector3::new(r, 0.7 * r, 0.5 * r))),
        2 => Arc::new(Capsule::new(0.5 * r, r)),
        _ => Arc::new(Cylinder::new(0.5 * r, r)),
    };
    let pose = |rng: &mut Rng| {
        let depth = rng.between(0.0, 0.6) * size[2];
        let rotation = UnitQuaternion::from_euler_angles(
            rng.between(-3.2, 3.2),
            rng.between(-3.2, 3.2),
            rng.between(-3.2, 3.2),
        );
        Isometry3::from_parts(
            Translation3::new(
                rng.between(-0.7, 0.7) * size[0],
                rng.between(-0.7, 0.7) * size[1],
                r - depth,
            ),
            rotation,
        )
    };
    let first = pose(rng);
    let second = pose(rng);
    let mut third = second;
    third.translation.vector.x = f64::NAN;
    (shape, [first, second, third])
}

#[derive(Default)]
struct Tally {
    drawn: usize,
    refused: usize,
    loaded: usize,
    frames: usize,
    non_finite: usize,
    panics: usize,
    seconds: f64,
}

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let count: usize = args.get(1).map_or(1000, |s| s.parse().expect("count"));
    let seed: u64 = args.get(2).map_or(1, |s| s.parse().expect("seed"));
    let max_cells: f64 = args.get(3).map_or(5e4, |s| s.parse().expect("cells"));
    // Each configuration printed before it is loaded: the last one printed is the one
    // that is running (for a run that stalls).
    let trace = std::env::var_os("TACROM_CONFIGS_TRACE").is_some();
    // One configuration replayed alone (its index), the others drawn and skipped.
    let only: Option<usize> = std::env::var("TACROM_CONFIGS_ONLY")
        .ok()
        .and_then(|s| s.parse().ok());
    let mut rng = Rng(Xoshiro256PlusPlus::seed_from_u64(seed));
    let mut tally: BTreeMap<String, Tally> = BTreeMap::new();
    let mut refusals: BTreeMap<String, usize> = BTreeMap::new();
    let mut memory = Vec::new();
    let start = Instant::now();
    // A panic is counted and printed with its configuration, not its default message.
    std::panic::set_hook(Box::new(|_| {}));
    for i in 0..count {
        let attrs = draw(&mut rng);
        let mut raw = RawConfig::default();
        for (a, v) in &attrs {
            raw = raw.with(a, v);
        }
        let physics = attrs[0].1.clone();
        let mode = attrs
            .iter()
            .find(|(a, _)| a == "solver")
            .map_or(physics.clone(), |(_, s)| format!("{physics}-{s}"));
        let scene_seed = rng.0.next_u64();
        if only.is_some_and(|o| o != i) {
            continue;
        }
        let t = tally.entry(mode).or_default();
        t.drawn += 1;
        let began = Instant::now();
        if trace {
            eprintln!("configuration {i}: {attrs:?}");
        }
        let outcome = catch_unwind(AssertUnwindSafe(|| {
            let config = match Config::from_raw("fuzz", &raw) {
                Ok(c) => c,
                Err(e) => return Err(e.to_string()),
            };
            if let Some(dx) = config.dx {
                let cells = config.size.iter().map(|s| s / dx).product::<f64>();
                if cells > max_cells {
                    return Err("over the campaign's cell cap".into());
                }
            }
            let mut sensor = TactileSensor::new(config.clone()).map_err(|e| e.to_string())?;
            let mut out = vec![0.0; config.sensordata_len()];
            let mut rng = Rng(Xoshiro256PlusPlus::seed_from_u64(scene_seed));
            let (shape, poses) = scene(&mut rng, config.size);
            let mut bad = 0;
            for pose in poses {
                let placed = [Placed {
                    shape: shape.clone(),
                    pose,
                }];
                let frame = Instant::now();
                let eval = sensor.evaluate(&placed, &mut out);
                if trace {
                    eprintln!(
                        "  frame: {:.3} s, solve {:?}, warnings {:?}",
                        frame.elapsed().as_secs_f64(),
                        eval.solve,
                        eval.warnings
                    );
                }
                bad += usize::from(out.iter().any(|v| !v.is_finite()));
            }
            Ok(bad)
        }));
        t.seconds += began.elapsed().as_secs_f64();
        match outcome {
            Ok(Ok(bad)) => {
                t.loaded += 1;
                t.frames += 3;
                t.non_finite += bad;
                if bad > 0 {
                    println!("non-finite output, configuration {i}: {attrs:?}");
                }
            }
            Ok(Err(why)) => {
                t.refused += 1;
                if trace {
                    eprintln!("  refused: {why}");
                }
                // The attribute a refusal names (`attribute 'NAME'`), or what it says.
                let named = match why.split("attribute '").nth(1) {
                    Some(rest) => rest.split('\'').next().unwrap_or("").to_string(),
                    None => why.chars().take(70).collect(),
                };
                *refusals.entry(named).or_default() += 1;
            }
            Err(_) => {
                t.panics += 1;
                println!("PANIC, configuration {i} (seed {seed}): {attrs:?}");
            }
        }
        if (i + 1) % (count / 10).max(1) == 0 {
            tacrom::release_free_memory();
            let rss = crate::bench::status_bytes("VmRSS").unwrap_or(0);
            memory.push((i + 1, rss));
            eprintln!(
                "{} configurations, {:.0} s, resident {:.1} MB",
                i + 1,
                start.elapsed().as_secs_f64(),
                rss as f64 / 1e6
            );
            if i + 1 < count {
                report(&tally, &refusals, &memory);
            }
        }
    }
    let _ = std::panic::take_hook();
    report(&tally, &refusals, &memory);
    println!(
        "{count} configurations in {:.1} s",
        start.elapsed().as_secs_f64()
    );
}

/// Prints the counts per mode, the refusals by attribute and the memory so far.
fn report(
    tally: &BTreeMap<String, Tally>,
    refusals: &BTreeMap<String, usize>,
    memory: &[(usize, u64)],
) {
    println!("| mode | drawn | refused | loaded and evaluated | frames | non-finite frames | panics | s |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    for (mode, t) in tally {
        println!(
            "| {mode} | {} | {} | {} | {} | {} | {} | {:.0} |",
            t.drawn, t.refused, t.loaded, t.frames, t.non_finite, t.panics, t.seconds
        );
    }
    println!("refusals by the attribute named: {refusals:?}");
    println!(
        "resident memory (configurations, MB): {:?}",
        memory
            .iter()
            .map(|&(n, b)| (n, (b as f64 / 1e5).round() / 10.0))
            .collect::<Vec<_>>()
    );
    if let (Some(&(n0, a)), Some(&(n1, b))) = (memory.get(memory.len() / 2), memory.last()) {
        if n1 > n0 {
            println!(
                "second half: {:.2} KiB per configuration",
                (b as f64 - a as f64) / 1024.0 / (n1 - n0) as f64
            );
        }
    }
}
