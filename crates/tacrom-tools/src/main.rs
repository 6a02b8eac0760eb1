//! `tacrom`: the command-line tool.
//!
//! ```text
//! tacrom bench  [--quick | --full] [options]   error against run time of every mode
//! tacrom render [options]                      press one indenter, write its depth PNG
//! tacrom stability [--physics P] [--dx MM]     the stability suite's table
//! tacrom mpm [--fine] [options]                Hertz validation and solver cost per dx
//! tacrom gen-data [options]                    paired coarse/reference presses for training
//! tacrom help
//! ```
//!
//! Lengths on the command line are in millimetres.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use tacrom::config::{Config, RawConfig};
use tacrom::geometry::Placed;
use tacrom::sensor::TactileSensor;
use tacrom_tools::bench::plot::depth_image;
use tacrom_tools::bench::protocol::{Indenter, ModeSpec};
use tacrom_tools::bench::{BenchError, BenchOptions, IndenterSource};

const USAGE: &str = "\
tacrom: tools for the tacrom tactile sensor

USAGE:
  tacrom bench  [--quick | --full] [OPTIONS]
  tacrom render [OPTIONS]
  tacrom stability [--physics P,...] [--dx MM]
  tacrom mpm [--fine] [OPTIONS]
  tacrom gen-data [OPTIONS]         (see `tacrom gen-data --help`)
  tacrom eval-rom --data DIR,... [OPTIONS]
  tacrom help

BENCH presses indenters on a grid of positions through increasing depths with every
physics mode and compares each with a fine-MPM reference (cached on disk). It writes
report.md, results.csv, error_vs_time.png and panels/*.png into --out.
  --quick                 two patterns, centre only, depths 0.2 0.5 1.0 mm, 64x48,
                          0.7 mm reference (a few minutes, cold cache included)
  --full                  every pattern, 3x3 grid, depths 0.1..0.5 and 1.0 mm, 320x240,
                          0.3 mm reference (the default profile; resumable)
  --indenters DIR         folder of STL/OBJ meshes [../shared/indenters/patterns, or
                          tests/data when that folder is absent]
  --scale S               mesh coordinate scale to metres [0.001]
  --no-flip               press with the mesh's bottom, not its top face
  --only NAME,...         only these meshes (file stems)
  --limit N               at most N meshes
  --grid N                N x N positions [3; quick 1]
  --spacing MM            spacing of the positions [2]
  --depths MM,...         depths of each press sequence, increasing
  --mode SPEC             a mode to compare (repeatable; replaces the default list):
                          a name (rigid, coarse, rom, ...) or LABEL:key=value,key=value
  --reference-dx MM       grid spacing of the fine reference [0.3; quick 0.7]
  --reference-threads N   solver threads of the reference [2]
  --threads N,...         thread counts each mode runs with [1,2]
  --resolution WxH        image size [320x240; quick 64x48]
  --set KEY=VALUE         a sensor attribute for all modes (young, poisson, size, ...)
  --cache DIR             reference cache [out/bench-cache]
  --no-cache              compute the reference, store nothing
  --out DIR               report folder [out/bench/<profile>]
  --panels N              press panels to draw [4; quick 2]
  --quiet                 no progress bar

RENDER presses one indenter and writes its depth image as a colour PNG with a colour bar.
  --mesh FILE             STL/OBJ indenter (with --scale, --no-flip as above)
  --sphere R_MM           or a sphere of this radius [5]
  --depth MM              indentation [0.5]
  --x MM, --y MM          position of the footprint's centre [0, 0]
  --physics P             rigid, coarse, fine, ... [rigid]
  --resolution WxH        image size [320x240]
  --set KEY=VALUE         any sensor attribute
  --out FILE              output PNG [out/render.png]

STABILITY runs the stability suite (stiff and near-incompressible gels, deep, sharp,
jumping, rotating, sliding, through-the-gel presses, non-finite poses; see
src/stability.rs) and prints one markdown table per mode; exits non-zero if a case fails.
  --physics P,...         modes to run [rigid,coarse]
  --dx MM                 MPM grid spacing [the mode's default]

MPM validates the gel against Hertz contact on a bonded layer (frictionless sphere,
R = 5 mm, force error per depth and grid spacing) and measures the solver's cost in a
moving press (ms per frame, iterations, particle-steps/s, bytes per particle) per grid
spacing and thread count. Writes report.md, hertz.csv and speed.csv into --out.
  --fine                  add the fine spacing 0.3 mm (about 1e6 particles; 30-60 min)
  --dx MM,...             spacings of both parts [1.4,1.0,0.7,0.5]
  --depths MM,...         Hertz depths [0.1,0.2,0.3,0.4,0.5]
  --threads N,...         thread counts of the cost runs [1,2]
  --frames N              measured frames per cost run [12; 3 below 0.5 mm]
  --tolerances T,...      solver tolerances of the cost runs [1e-3,3e-3,1e-2]
  --only hertz|speed      run one part only
  --out DIR               report folder [out/bench/mpm]
  --quiet                 no progress lines

EVAL-ROM compares rigid, coarse and reduced-order models with the reference of gen-data
sets on their held-out families (depth MAE, RMSE, SSIM over the 24 x 18 mm field of view;
inference time). Writes report.md and results.csv into --out.
  --data DIR,...          data sets (gen-data --out)
  --models DIR,...        model folders; the first also runs without refinement
                          [models/rom-default,models/rom-latent16,models/rom-no-multiscale]
  --all                   every sample, not only held-out families
  --compare DIR           a data set of the same presses (same seed and indices) whose
                          reference gets a row, e.g. the 0.7 mm set against the 0.3 mm one
  --out DIR               report folder [out/bench/eval-rom]
";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("bench") => bench(&args[1..]),
        Some("render") => render(&args[1..]),
        Some("stability") => stability(&args[1..]),
        Some("mpm") => mpm(&args[1..]),
        Some("gen-data") => tacrom_tools::datagen::run_cli(&args[1..]).map_err(BenchError::Usage),
        Some("eval-rom") => eval_rom(&args[1..]),
        Some("help" | "--help" | "-h") | None => {
            print!("{USAGE}");
            Ok(())
        }
        Some(other) => Err(BenchError::Usage(format!(
            "unknown command '{other}'; try 'tacrom help'"
        ))),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("tacrom: error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// A cursor over the arguments of a subcommand.
struct Args<'a> {
    args: &'a [String],
    at: usize,
}

impl<'a> Args<'a> {
    fn new(args: &'a [String]) -> Self {
        Self { args, at: 0 }
    }

    fn next_flag(&mut self) -> Option<&'a str> {
        let a = self.args.get(self.at)?;
        self.at += 1;
        Some(a)
    }

    fn value(&mut self, flag: &str) -> Result<&'a str, BenchError> {
        let v = self
            .args
            .get(self.at)
            .ok_or_else(|| usage(format!("{flag} needs a value")))?;
        self.at += 1;
        Ok(v)
    }

    fn number(&mut self, flag: &str) -> Result<f64, BenchError> {
        let v = self.value(flag)?;
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| usage(format!("{flag}: '{v}' is not a number")))
    }

    fn count(&mut self, flag: &str) -> Result<usize, BenchError> {
        let v = self.value(flag)?;
        v.parse::<usize>()
            .map_err(|_| usage(format!("{flag}: '{v}' is not a whole number")))
    }

    fn mm(&mut self, flag: &str) -> Result<f64, BenchError> {
        Ok(self.number(flag)? * 1e-3)
    }
}

fn usage(message: String) -> BenchError {
    BenchError::Usage(message)
}

fn list<T>(flag: &str, v: &str, parse: impl Fn(&str) -> Option<T>) -> Result<Vec<T>, BenchError> {
    v.split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| {
            parse(s.trim()).ok_or_else(|| usage(format!("{flag}: '{s}' is not a valid entry")))
        })
        .collect()
}

fn resolution(flag: &str, v: &str) -> Result<[usize; 2], BenchError> {
    let parts: Vec<&str> = v.split(['x', 'X', ' ']).collect();
    match parts.as_slice() {
        [w, h] => match (w.parse(), h.parse()) {
            (Ok(w), Ok(h)) => Ok([w, h]),
            _ => Err(usage(format!("{flag}: '{v}' is not WxH"))),
        },
        _ => Err(usage(format!("{flag}: '{v}' is not WxH"))),
    }
}

fn key_value(flag: &str, v: &str) -> Result<(String, String), BenchError> {
    v.split_once('=')
        .map(|(k, v)| (k.trim().to_owned(), v.trim().to_owned()))
        .ok_or_else(|| usage(format!("{flag}: '{v}' is not KEY=VALUE")))
}

fn default_indenters() -> PathBuf {
    let shared = PathBuf::from("../shared/indenters/patterns");
    if shared.is_dir() {
        shared
    } else {
        PathBuf::from("tests/data")
    }
}

fn bench(args: &[String]) -> Result<(), BenchError> {
    // The profile first: the other flags refine it, in any order.
    let quick = args.iter().any(|a| a == "--quick");
    let dir = default_indenters();
    let mut o = if quick {
        BenchOptions::quick(dir)
    } else {
        BenchOptions::full(dir)
    };
    let mut modes = Vec::new();
    let mut out_given = false;
    let mut a = Args::new(args);
    while let Some(flag) = a.next_flag() {
        match flag {
            "--quick" | "--full" => {}
            "--indenters" | "--scale" | "--no-flip" | "--only" | "--limit" => {
                let IndenterSource::Folder {
                    dir,
                    scale,
                    flip,
                    names,
                    limit,
                } = &mut o.indenters
                else {
                    unreachable!("the profiles read a folder")
                };
                match flag {
                    "--indenters" => {
                        *dir = PathBuf::from(a.value(flag)?);
                        // Another folder: its own meshes, not the profile's selection.
                        names.clear();
                    }
                    "--scale" => *scale = a.number(flag)?,
                    "--no-flip" => *flip = false,
                    "--only" => {
                        *names = list(flag, a.value(flag)?, |s| Some(s.to_owned()))?;
                    }
                    _ => *limit = Some(a.count(flag)?),
                }
            }
            "--grid" => o.grid = a.count(flag)?,
            "--spacing" => o.spacing = a.mm(flag)?,
            "--depths" => {
                o.depths = list(flag, a.value(flag)?, |s| {
                    s.parse::<f64>().ok().map(|v| v * 1e-3)
                })?
            }
            "--mode" => modes.push(ModeSpec::parse(a.value(flag)?)?),
            "--reference-dx" => o.reference_dx = a.mm(flag)?,
            "--reference-threads" => o.reference_threads = a.count(flag)?,
            "--threads" => o.threads = list(flag, a.value(flag)?, |s| s.parse().ok())?,
            "--resolution" => o.resolution = resolution(flag, a.value(flag)?)?,
            "--set" => o.attrs.push(key_value(flag, a.value(flag)?)?),
            "--cache" => o.cache = Some(PathBuf::from(a.value(flag)?)),
            "--no-cache" => o.cache = None,
            "--out" => {
                o.out = PathBuf::from(a.value(flag)?);
                out_given = true;
            }
            "--panels" => o.panels = a.count(flag)?,
            "--quiet" => o.progress = false,
            other => {
                return Err(usage(format!(
                    "bench: unknown option '{other}'; try 'tacrom help'"
                )))
            }
        }
    }
    if !modes.is_empty() {
        o.modes = modes;
    }
    if !out_given {
        o.out = PathBuf::from("out/bench").join(&o.profile);
    }
    let r = tacrom_tools::bench::run(&o)?;
    println!("{}", tacrom_tools::bench::report::markdown(&r));
    Ok(())
}

fn render(args: &[String]) -> Result<(), BenchError> {
    let mut mesh: Option<PathBuf> = None;
    let (mut scale, mut flip, mut radius) = (1e-3, true, 5e-3);
    let (mut depth, mut x, mut y) = (0.5e-3, 0.0, 0.0);
    let mut raw = RawConfig::default().with("outputs", "depth force");
    let mut out = PathBuf::from("out/render.png");
    let mut a = Args::new(args);
    while let Some(flag) = a.next_flag() {
        match flag {
            "--mesh" => mesh = Some(PathBuf::from(a.value(flag)?)),
            "--scale" => scale = a.number(flag)?,
            "--no-flip" => flip = false,
            "--sphere" => radius = a.mm(flag)?,
            "--depth" => depth = a.mm(flag)?,
            "--x" => x = a.mm(flag)?,
            "--y" => y = a.mm(flag)?,
            "--physics" => raw = raw.with("physics", a.value(flag)?),
            "--resolution" => {
                let [w, h] = resolution(flag, a.value(flag)?)?;
                raw = raw.with("resolution", &format!("{w} {h}"));
            }
            "--set" => {
                let (k, v) = key_value(flag, a.value(flag)?)?;
                raw = raw.with(&k, &v);
            }
            "--out" => out = PathBuf::from(a.value(flag)?),
            other => {
                return Err(usage(format!(
                    "render: unknown option '{other}'; try 'tacrom help'"
                )))
            }
        }
    }
    let indenter = match &mesh {
        Some(p) => Indenter::from_mesh(p, scale, flip)?,
        None => Indenter::sphere(radius)?,
    };
    let config = Config::from_raw("render", &raw).map_err(|e| BenchError::Config(e.to_string()))?;
    let mut sensor =
        TactileSensor::new(config.clone()).map_err(|e| BenchError::Config(e.to_string()))?;
    let mut data = vec![0.0; config.sensordata_len()];
    let placed = [Placed {
        shape: Arc::clone(&indenter.shape),
        pose: indenter.pose(x, y, depth),
    }];
    let t0 = std::time::Instant::now();
    let eval = sensor.evaluate(&placed, &mut data);
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    for w in &eval.warnings {
        eprintln!("tacrom: warning: {w}");
    }
    let title = format!(
        "{} {} at ({:.1}, {:.1}) mm, depth {:.2} mm",
        config.physics.name(),
        indenter.name,
        x * 1e3,
        y * 1e3,
        depth * 1e3
    );
    let canvas = depth_image(&title, config.width, config.height, sensor.depth());
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| BenchError::Output {
            path: parent.to_path_buf(),
            message: e.to_string(),
        })?;
    }
    canvas.save_png(&out).map_err(|e| BenchError::Output {
        path: out.clone(),
        message: e.to_string(),
    })?;
    let f = sensor.force();
    let max = sensor.depth().iter().copied().fold(0.0f64, f64::max);
    println!(
        "{}: max depth {:.1} um, force ({:.4}, {:.4}, {:.4}) N, {ms:.1} ms",
        out.display(),
        max * 1e6,
        f[0],
        f[1],
        f[2]
    );
    Ok(())
}

/// `tacrom stability`: the stability suite's table per mode.
fn mm_list(args: &mut Args<'_>, flag: &str) -> Result<Vec<f64>, BenchError> {
    let v = args.value(flag)?;
    v.split(',')
        .map(|x| {
            x.trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && *x > 0.0)
                .map(|x| x * 1e-3)
                .ok_or_else(|| usage(format!("{flag}: '{x}' is not a positive length in mm")))
        })
        .collect()
}

fn mpm(args: &[String]) -> Result<(), BenchError> {
    use tacrom_tools::bench::mpm::{markdown, run, MpmBenchOptions};
    let mut options = MpmBenchOptions::standard();
    let mut fine = false;
    let mut only = None;
    let mut a = Args::new(args);
    while let Some(flag) = a.next_flag() {
        match flag {
            "--fine" => fine = true,
            "--dx" => {
                let dx = mm_list(&mut a, flag)?;
                options.hertz_dx = dx.clone();
                options.speed_dx = dx;
            }
            "--depths" => options.depths = mm_list(&mut a, flag)?,
            "--threads" => {
                let v = a.value(flag)?;
                options.threads = list(flag, v, |x| x.parse().ok().filter(|&n: &usize| n > 0))?;
            }
            "--frames" => options.frames = a.count(flag)?.max(1),
            "--tolerances" => {
                let v = a.value(flag)?;
                options.tolerances = list(flag, v, |x| {
                    x.parse().ok().filter(|t: &f64| *t > 0.0 && *t < 1.0)
                })?;
            }
            "--only" => match a.value(flag)? {
                "hertz" => only = Some(true),
                "speed" => only = Some(false),
                other => return Err(usage(format!("--only: '{other}' is not hertz or speed"))),
            },
            "--out" => options.out = PathBuf::from(a.value(flag)?),
            "--quiet" => options.progress = false,
            other => return Err(usage(format!("mpm: unknown option '{other}'"))),
        }
    }
    if fine {
        options = options.with_fine();
    }
    match only {
        Some(true) => options.speed_dx.clear(),
        Some(false) => options.hertz_dx.clear(),
        None => {}
    }
    let result = run(&options)?;
    print!("{}", markdown(&result));
    println!("\nwritten to {}", options.out.display());
    Ok(())
}

fn eval_rom(args: &[String]) -> Result<(), BenchError> {
    use tacrom_tools::bench::heldout::{markdown, run, EvalOptions};
    let paths = |v: &str| {
        v.split(',')
            .filter(|s| !s.is_empty())
            .map(PathBuf::from)
            .collect()
    };
    let models = ["rom-default", "rom-latent16", "rom-no-multiscale"];
    let mut options = EvalOptions {
        data: Vec::new(),
        models: tacrom::rom::default_model_dir()
            .and_then(|d| {
                d.parent()
                    .map(|p| models.iter().map(|m| p.join(m)).collect::<Vec<_>>())
            })
            .unwrap_or_default()
            .into_iter()
            .filter(|m: &PathBuf| m.is_dir())
            .collect(),
        all: false,
        compare: None,
        out: PathBuf::from("out/bench/eval-rom"),
    };
    let mut a = Args::new(args);
    while let Some(flag) = a.next_flag() {
        match flag {
            "--data" => options.data = paths(a.value(flag)?),
            "--models" => options.models = paths(a.value(flag)?),
            "--all" => options.all = true,
            "--compare" => options.compare = Some(PathBuf::from(a.value(flag)?)),
            "--out" => options.out = PathBuf::from(a.value(flag)?),
            other => return Err(usage(format!("eval-rom: unknown option '{other}'"))),
        }
    }
    if options.data.is_empty() {
        return Err(usage("eval-rom: --data is required".to_owned()));
    }
    let result = run(&options)?;
    print!("{}", markdown(&result));
    println!("\nwritten to {}", options.out.display());
    Ok(())
}

fn stability(args: &[String]) -> Result<(), BenchError> {
    let mut modes = vec!["rigid".to_owned(), "coarse".to_owned()];
    let mut dx = None;
    let mut it = args.iter();
    while let Some(flag) = it.next() {
        let mut value = || {
            it.next()
                .cloned()
                .ok_or_else(|| BenchError::Usage(format!("{flag} needs a value")))
        };
        match flag.as_str() {
            "--physics" => modes = value()?.split(',').map(str::to_owned).collect(),
            "--dx" => {
                let v = value()?;
                let mm: f64 = v
                    .parse()
                    .ok()
                    .filter(|x: &f64| x.is_finite() && *x > 0.0)
                    .ok_or_else(|| {
                        BenchError::Usage(format!("--dx: '{v}' is not a positive length in mm"))
                    })?;
                dx = Some(mm * 1e-3);
            }
            other => {
                return Err(BenchError::Usage(format!(
                    "stability: unknown option '{other}'"
                )))
            }
        }
    }
    let root = tacrom::checkout_root().to_path_buf();
    let shared = root.join("../shared/indenters/patterns");
    let patterns = if shared.is_dir() {
        shared
    } else {
        root.join("tests/data")
    };
    let mut failed = 0;
    for mode in &modes {
        let mut raw = RawConfig::default().with("physics", mode);
        if let Some(dx) = dx {
            raw = raw.with("dx", &dx.to_string());
        }
        Config::from_raw("stability", &raw).map_err(|e| BenchError::Config(e.to_string()))?;
        let rows: Vec<_> = tacrom_tools::stability::cases(Some(&patterns))
            .iter()
            .map(|case| {
                let row = tacrom_tools::stability::run_case(case, mode, dx);
                eprintln!(
                    "  {mode}: {} {}",
                    row.name,
                    if row.ok() { "ok" } else { "FAIL" }
                );
                row
            })
            .collect();
        failed += rows.iter().filter(|r| !r.ok()).count();
        println!(
            "\n### physics = {mode}\n\n{}",
            tacrom_tools::stability::table(&rows)
        );
    }
    if failed > 0 {
        return Err(BenchError::Usage(format!(
            "{failed} stability case(s) failed"
        )));
    }
    Ok(())
}
