//! Which reference can train and judge a model for any gel: candidate solves against the
//! finest solve each gel calls for, on presses spanning the gel family (thin and thick
//! gels, Poisson's ratios 0.3 to 0.49, friction 0 to 1, sharp, flat and curved indenters,
//! centres, edges and corners):
//!
//! `tacrom probe reference_study [key=value ...] [report]`
//!
//! Keys (defaults): `out` (out/reference-study), `shard` (K/N, 0/1: every N-th task of
//! the list, heaviest first), `methods` (all; a comma list of [`METHODS`] names),
//! `presses` (all; a comma list of [`PRESSES`] names), `order` (`light`: lightest task
//! first; heaviest first otherwise), `threads` (1), `patterns` (the
//! benchmark's pattern folder). Each task (a press solved by a method) writes
//! `out/PRESS/METHOD.json` (force, seconds, solver report) after `METHOD.npy` (the depth
//! over the press's window, float32 metres), so a run resumes where it stopped and shards
//! may run on other machines into copies of the folder. With `claim=1`, workers started
//! on one folder (each `shard=0/1`) take the tasks heaviest first, each task once (the
//! worker that creates `METHOD.claim` solves it; delete the claims of a stopped run
//! before resuming it). `report` solves nothing: it reads
//! the folder and prints (and writes `out/report.md`) every method against `finest`,
//! per press and summed up.
//!
//! The finest solve has the default fine mode's cells through the layer, 13.3 (0.3 mm on
//! the 4 mm gel; `dx = 0.075 T`), by the reference's own solver rule (the relaxation below
//! Poisson 0.49, Newton's method from it) to the fine mode's tolerance. Every press is
//! solved from rest in one pose, as `tacrom gen-data` solves its pairs.
//!
//! The depth is compared over the window of the indenter's footprint grown by 1.5 gel
//! thicknesses (clipped to the gel), sampled every `T / 40` (at most 0.05 mm), where
//! either depth exceeds 1 um (the MAE), with the difference of the deepest points and of
//! the normal force.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use tacrom::geometry::{Cuboid, Cylinder, PixelGrid, Placed};
use tacrom::mpm::choice::{choose, Role};
use tacrom::mpm::{Gel, GelParams, Solver, SolverOptions};

use crate::bench::protocol::Indenter;

/// An indenter of the study, in millimetres.
#[derive(Clone, Copy, Debug)]
enum Shape {
    /// A sphere of this radius.
    Sphere(f64),
    /// A flat-ended cylinder of this radius, end on.
    Punch(f64),
    /// A box of these half extents lying on one edge (a knife edge along y).
    Edge([f64; 3]),
    /// A benchmark pattern pressed with its patterned face, scaled (1: the file's mm).
    Pattern(&'static str, f64),
}

/// One press of the study: the gel (lengths in mm), the indenter, where and how deep.
#[derive(Clone, Copy, Debug)]
struct StudyPress {
    /// Name (folder of its results).
    name: &'static str,
    size: [f64; 3],
    poisson: f64,
    friction: f64,
    shape: Shape,
    x: f64,
    y: f64,
    depth: f64,
}

const fn press(
    name: &'static str,
    size: [f64; 3],
    poisson: f64,
    friction: f64,
    shape: Shape,
    [x, y]: [f64; 2],
    depth: f64,
) -> StudyPress {
    StudyPress {
        name,
        size,
        poisson,
        friction,
        shape,
        x,
        y,
        depth,
    }
}

use Shape::*;

/// The study's presses: five gels from 12 x 12 x 1 mm to 40 x 30 x 6 mm, depths from
/// 0.1 mm to a quarter of the thickness.
#[rustfmt::skip]
const PRESSES: [StudyPress; 24] = [
    press("t1-sphere2-shallow", [12.0, 12.0, 1.0], 0.45, 0.5, Sphere(2.0), [0.0, 0.0], 0.1),
    press("t1-sphere2-frictionless", [12.0, 12.0, 1.0], 0.45, 0.0, Sphere(2.0), [0.0, 0.0], 0.25),
    press("t1-cone", [12.0, 12.0, 1.0], 0.45, 0.5, Pattern("cone", 0.5), [0.0, 0.0], 0.2),
    press("t1-punch-edge", [12.0, 12.0, 1.0], 0.45, 1.0, Punch(1.5), [4.5, 0.0], 0.15),
    press("t1-slab", [12.0, 12.0, 1.0], 0.45, 0.5, Pattern("flat_slab", 0.4), [0.0, 0.0], 0.1),
    press("t1-sphere5-edge", [12.0, 12.0, 1.0], 0.3, 0.5, Sphere(5.0), [4.0, 0.0], 0.25),
    press("t1.5-sphere5", [18.0, 14.0, 1.5], 0.3, 0.5, Sphere(5.0), [0.0, 0.0], 0.2),
    press("t1.5-knife-edge", [18.0, 14.0, 1.5], 0.3, 0.5, Edge([1.5, 3.0, 1.5]), [7.0, 0.0], 0.2),
    press("t1.5-dots", [18.0, 14.0, 1.5], 0.3, 0.0, Pattern("dots", 0.6), [0.0, 0.0], 0.3),
    press("t1.5-sphere2-corner", [18.0, 14.0, 1.5], 0.3, 1.0, Sphere(2.0), [7.5, 5.5], 0.3),
    press("t2-sphere2-incompressible", [20.0, 20.0, 2.0], 0.49, 0.5, Sphere(2.0), [0.0, 0.0], 0.5),
    press("t2-cylinder-side", [20.0, 20.0, 2.0], 0.45, 0.5, Pattern("cylinder_side", 0.6), [0.0, 0.0], 0.3),
    press("t2-hexagon", [20.0, 20.0, 2.0], 0.45, 0.5, Pattern("hexagon", 0.7), [2.0, -2.0], 0.4),
    press("t4-sphere5-deep", [30.0, 30.0, 4.0], 0.43, 0.5, Sphere(5.0), [0.0, 0.0], 1.0),
    press("t4-sphere2-frictionless", [30.0, 30.0, 4.0], 0.43, 0.0, Sphere(2.0), [0.0, 0.0], 0.3),
    press("t4-cone", [30.0, 30.0, 4.0], 0.43, 0.5, Pattern("cone", 1.0), [0.0, 0.0], 0.5),
    press("t4-slab", [30.0, 30.0, 4.0], 0.43, 0.5, Pattern("flat_slab", 1.0), [0.0, 0.0], 0.2),
    press("t4-sphere5-edge", [30.0, 30.0, 4.0], 0.43, 1.0, Sphere(5.0), [12.0, 0.0], 0.5),
    press("t4-random", [30.0, 30.0, 4.0], 0.43, 0.5, Pattern("random", 1.0), [0.0, 0.0], 0.4),
    press("t4-torus", [30.0, 30.0, 4.0], 0.43, 0.5, Pattern("torus", 1.0), [4.0, -3.0], 0.3),
    press("t6-sphere5-deep", [40.0, 30.0, 6.0], 0.4, 0.5, Sphere(5.0), [0.0, 0.0], 1.5),
    press("t6-sphere2-edge", [40.0, 30.0, 6.0], 0.4, 0.0, Sphere(2.0), [17.0, 0.0], 0.5),
    press("t6-prism", [40.0, 30.0, 6.0], 0.4, 0.5, Pattern("prism", 1.0), [0.0, 0.0], 0.8),
    press("t6-cross-lines", [40.0, 30.0, 6.0], 0.4, 1.0, Pattern("cross_lines", 1.0), [0.0, 3.0], 0.6),
];

/// A way of solving a press: a solver at a spacing (in gel thicknesses), or a
/// combination of two such solves.
#[derive(Clone, Copy, Debug)]
enum Method {
    /// A solver at `dx = T * cells` to a tolerance; `None`: the reference's own rule.
    Solve(Option<Solver>, f64, f64),
    /// The default coarse gel: `dx = min(1.4 mm, T / 2)`, the sensor's coarse rule.
    Coarse,
    /// A sensor's coarse gel at `dx = T * cells` (its solver rule, the named solver where
    /// given, its 3e-3 tolerance): the candidates for a coarse grid that follows the
    /// thickness.
    CoarseAt(Option<Solver>, f64),
    /// `rom` at `dx = 0.35 T` with the shipped model `physics="rom"` takes by default for
    /// the press's gel ([`tacrom::rom::shipped_model`]: on the linear gel `rom-linear-narrow`
    /// from 3.5 mm and `rom-linear` below; `rom-default` on the relaxation), the model
    /// reading a window of its own lattice over the contact.
    Rom(Solver),
    /// Richardson extrapolation of two methods' depths and forces (the second at half the
    /// first's spacing), for convergence of this order.
    Extrapolated(&'static str, &'static str, f64),
}

/// The methods of the study: its finest solve and the candidates.
const METHODS: [(&str, Method); 19] = [
    ("finest", Method::Solve(None, 0.075, 1e-3)),
    (
        "finest-newton",
        Method::Solve(Some(Solver::Newton), 0.075, 1e-3),
    ),
    (
        "relax-t/8",
        Method::Solve(Some(Solver::Relaxation), 0.125, 1e-3),
    ),
    (
        "relax-t/6",
        Method::Solve(Some(Solver::Relaxation), 1.0 / 6.0, 1e-3),
    ),
    (
        "relax-t/4",
        Method::Solve(Some(Solver::Relaxation), 0.25, 1e-3),
    ),
    (
        "relax-t/8-tight",
        Method::Solve(Some(Solver::Relaxation), 0.125, 1e-4),
    ),
    (
        "newton-t/10",
        Method::Solve(Some(Solver::Newton), 0.1, 1e-3),
    ),
    (
        "newton-t/8",
        Method::Solve(Some(Solver::Newton), 0.125, 1e-3),
    ),
    (
        "newton-t/4",
        Method::Solve(Some(Solver::Newton), 0.25, 1e-3),
    ),
    (
        "extrap-relax-t/4-t/8",
        Method::Extrapolated("relax-t/4", "relax-t/8", 1.0),
    ),
    (
        "extrap-newton-t/4-t/8",
        Method::Extrapolated("newton-t/4", "newton-t/8", 1.0),
    ),
    ("coarse", Method::Coarse),
    ("coarse-t/2", Method::CoarseAt(None, 0.5)),
    ("coarse-t/2.86", Method::CoarseAt(None, 0.35)),
    ("coarse-t/4", Method::CoarseAt(None, 0.25)),
    (
        "coarse-linear-t/2.86",
        Method::CoarseAt(Some(Solver::Linear), 0.35),
    ),
    (
        "coarse-linear-t/4",
        Method::CoarseAt(Some(Solver::Linear), 0.25),
    ),
    ("rom", Method::Rom(Solver::Linear)),
    ("rom-relaxation", Method::Rom(Solver::Relaxation)),
];

/// What one task wrote besides its depth window.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct Outcome {
    /// The solver that ran.
    solver: String,
    /// Grid spacing (m).
    dx: f64,
    /// Normal force on the indenter (N).
    force: f64,
    /// Wall time of the solve from rest (s), threads as run.
    seconds: f64,
    threads: usize,
    iterations: usize,
    converged: bool,
    particles: usize,
}

impl StudyPress {
    fn thickness(&self) -> f64 {
        self.size[2] * 1e-3
    }

    fn gel(&self, dx: f64) -> GelParams {
        GelParams {
            size: self.size.map(|v| v * 1e-3),
            poisson: self.poisson,
            friction: self.friction,
            dx,
            ..GelParams::default()
        }
    }

    /// The indenter, posed at this press's depth below its first contact.
    fn placed(&self, patterns: &Path) -> Result<Placed, String> {
        let mm = 1e-3;
        let indenter = match self.shape {
            Sphere(r) => Indenter::sphere(r * mm).map_err(|e| e.to_string())?,
            Pattern(name, scale) => {
                Indenter::from_mesh(&patterns.join(format!("{name}.stl")), scale * mm, true)
                    .map_err(|e| e.to_string())?
            }
            Punch(r) => Indenter {
                name: "punch".into(),
                shape: Arc::new(Cylinder::new(r * mm, 3.0 * mm)),
                rotation: UnitQuaternion::identity(),
                anchor: Vector3::new(0.0, 0.0, -3.0 * mm),
                fingerprint: String::new(),
            },
            Edge(h) => {
                // Turned 45 degrees about y: one edge (along y) lowest.
                let rotation = UnitQuaternion::from_axis_angle(
                    &Vector3::y_axis(),
                    std::f64::consts::FRAC_PI_4,
                );
                let lowest = -(h[0] + h[2]) * mm / std::f64::consts::SQRT_2;
                Indenter {
                    name: "edge".into(),
                    shape: Arc::new(Cuboid::new(Vector3::from(h) * mm)),
                    rotation,
                    anchor: Vector3::new(0.0, 0.0, lowest),
                    fingerprint: String::new(),
                }
            }
        };
        let pose = indenter.pose(self.x * mm, self.y * mm, self.depth * mm);
        Ok(Placed {
            shape: indenter.shape,
            pose,
        })
    }

    /// The gel's top face sampled every `T / 40`, at most 0.05 mm.
    fn face(&self) -> PixelGrid {
        let pitch = (self.thickness() / 40.0).min(5e-5);
        let [lx, ly] = [self.size[0] * 1e-3, self.size[1] * 1e-3];
        PixelGrid {
            width: (lx / pitch).round() as usize,
            height: (ly / pitch).round() as usize,
            fov_x: lx,
            fov_y: ly,
        }
    }

    /// The window compared: the footprint grown by 1.5 thicknesses, clipped to the gel,
    /// as a pixel grid centred on the gel and the range of its columns and rows.
    fn window(&self, placed: &Placed) -> Window {
        let t = self.thickness();
        let grid = self.face();
        let b = placed.aabb();
        let grow = 1.5 * t;
        let range = |lo: f64, hi: f64, n: usize, at: &dyn Fn(usize) -> f64| {
            let inside: Vec<usize> = (0..n)
                .filter(|&i| (lo - grow..=hi + grow).contains(&at(i)))
                .collect();
            (inside[0], inside[inside.len() - 1] + 1)
        };
        let cols = range(b.min.x, b.max.x, grid.width, &|i| grid.x(i));
        let rows = range(b.min.y, b.max.y, grid.height, &|j| grid.y(j));
        Window { grid, cols, rows }
    }
}

/// A press's comparison window over its gel's pixel grid.
struct Window {
    grid: PixelGrid,
    cols: (usize, usize),
    rows: (usize, usize),
}

impl Window {
    fn shape(&self) -> [usize; 2] {
        [self.rows.1 - self.rows.0, self.cols.1 - self.cols.0]
    }

    fn crop(&self, image: &[f64]) -> Vec<f32> {
        let mut out = Vec::new();
        for j in self.rows.0..self.rows.1 {
            let row = &image[j * self.grid.width..(j + 1) * self.grid.width];
            out.extend(row[self.cols.0..self.cols.1].iter().map(|&v| v as f32));
        }
        out
    }
}

/// Settings of a run.
struct Settings {
    out: PathBuf,
    shard: (usize, usize),
    methods: Vec<String>,
    presses: Vec<String>,
    threads: usize,
    patterns: PathBuf,
    report: bool,
    claim: bool,
    lightest_first: bool,
}

fn method(name: &str) -> Option<Method> {
    METHODS.iter().find(|(n, _)| *n == name).map(|(_, m)| *m)
}

/// Runs the probe; `args[0]` is its name, the rest its arguments.
pub fn run(args: Vec<String>) {
    let mut s = Settings {
        out: PathBuf::from("out/reference-study"),
        shard: (0, 1),
        methods: METHODS.iter().map(|(n, _)| n.to_string()).collect(),
        presses: PRESSES.iter().map(|p| p.name.to_string()).collect(),
        threads: 1,
        patterns: tacrom::checkout_root().join("../shared/indenters/patterns"),
        report: false,
        claim: false,
        lightest_first: false,
    };
    for arg in args.into_iter().skip(1) {
        if arg == "report" {
            s.report = true;
            continue;
        }
        let (key, value) = arg
            .split_once('=')
            .unwrap_or_else(|| panic!("expected key=value or 'report', got '{arg}'"));
        let list = || value.split(',').map(str::to_owned).collect::<Vec<_>>();
        match key {
            "out" => s.out = value.into(),
            "shard" => s.shard = crate::cli::shard(value).unwrap_or_else(|e| panic!("{e}")),
            "methods" => s.methods = list(),
            "presses" => s.presses = list(),
            "threads" => s.threads = value.parse().expect("threads: a whole number"),
            "patterns" => s.patterns = value.into(),
            "claim" => s.claim = value == "1",
            "order" => s.lightest_first = value == "light",
            _ => panic!("unknown key '{key}'"),
        }
    }
    for m in &s.methods {
        assert!(method(m).is_some(), "unknown method '{m}'");
    }
    for p in &s.presses {
        assert!(PRESSES.iter().any(|q| q.name == p), "unknown press '{p}'");
    }
    if s.report {
        let text = report(&s);
        print!("{text}");
        std::fs::write(s.out.join("report.md"), text).expect("report.md");
    } else {
        solve_all(&s);
    }
}

/// A task's relative cost: cells of the solved gel's grid, more for Newton's method.
fn cost(p: &StudyPress, m: Method) -> f64 {
    match m {
        Method::Solve(solver, cells, _) => {
            let dx = p.thickness() * cells;
            let n = p.size.iter().map(|v| v * 1e-3 / dx).product::<f64>();
            // Relaxation steps grow with the cells through the layer.
            n * (1.0 / cells)
                * if solver == Some(Solver::Newton) {
                    2.0
                } else {
                    1.0
                }
        }
        _ => 0.0,
    }
}

fn solve_all(s: &Settings) {
    let mut tasks: Vec<(StudyPress, &str, Method)> = Vec::new();
    for p in PRESSES
        .iter()
        .filter(|p| s.presses.iter().any(|n| n == p.name))
    {
        for (name, m) in METHODS
            .iter()
            .filter(|(n, _)| s.methods.iter().any(|x| x == n))
        {
            if !matches!(m, Method::Extrapolated(..)) {
                tasks.push((*p, name, *m));
            }
        }
    }
    tasks.sort_by(|a, b| cost(&b.0, b.2).total_cmp(&cost(&a.0, a.2)));
    if s.lightest_first {
        tasks.reverse();
    }
    let (k, n) = s.shard;
    for (p, name, m) in tasks.into_iter().skip(k).step_by(n) {
        let dir = s.out.join(p.name);
        let json = dir.join(file_name(name, "json"));
        if json.is_file() {
            continue;
        }
        std::fs::create_dir_all(&dir).expect("output folder");
        // Workers sharing a folder take each task once: the first to create its claim.
        if s.claim
            && std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(dir.join(file_name(name, "claim")))
                .is_err()
        {
            continue;
        }
        let placed = p
            .placed(&s.patterns)
            .unwrap_or_else(|e| panic!("{}: {e}", p.name));
        let window = p.window(&placed);
        match solve(&p, m, &placed, &window, s.threads) {
            Ok((outcome, depth)) => {
                crate::npy::write(&dir.join(file_name(name, "npy")), &window.shape(), &depth)
                    .expect("depth window");
                let text = serde_json::to_string_pretty(&outcome).expect("json");
                crate::npy::write_atomic(&json, text.as_bytes()).expect("outcome");
                println!(
                    "{} {name}: {:.1} s, {} iterations, converged {}, force {:.5} N",
                    p.name, outcome.seconds, outcome.iterations, outcome.converged, outcome.force
                );
            }
            Err(e) => println!("{} {name}: {e}", p.name),
        }
    }
}

/// A method's file name (`/` is not allowed in one).
fn file_name(method: &str, ext: &str) -> String {
    format!("{}.{ext}", method.replace('/', "_"))
}

fn solve(
    p: &StudyPress,
    m: Method,
    placed: &Placed,
    window: &Window,
    threads: usize,
) -> Result<(Outcome, Vec<f32>), String> {
    let t = p.thickness();
    let (named, dx, role, tolerance) = match m {
        Method::Solve(solver, cells, tolerance) => (solver, t * cells, Role::Reference, tolerance),
        Method::Coarse => (None, (1.4e-3f64).min(t / 2.0), Role::Coarse, 3e-3),
        Method::CoarseAt(solver, cells) => (solver, t * cells, Role::Coarse, 3e-3),
        Method::Rom(solver) => (Some(solver), t * 0.35, Role::Coarse, 3e-3),
        Method::Extrapolated(..) => unreachable!("extrapolations are not solved"),
    };
    let params = p.gel(dx);
    let choice = choose(&params, named, role);
    let options = SolverOptions {
        threads,
        solver: choice.solver,
        fallback: choice.fallback,
        tolerance,
        // A tighter tolerance gets the steps it needs.
        max_iterations: (SolverOptions::default().max_iterations as f64
            * (1e-3 / tolerance).max(1.0)) as usize,
        ..SolverOptions::default()
    };
    let mut gel = Gel::new(params, options).map_err(|e| e.to_string())?;
    let t0 = Instant::now();
    let r = gel.solve(std::slice::from_ref(placed));
    let seconds = t0.elapsed().as_secs_f64();
    let mut image = vec![0.0; window.grid.width * window.grid.height];
    let mut force = gel.force()[2];
    let mut seconds = seconds;
    if let Method::Rom(solver) = m {
        let name = tacrom::rom::shipped_model(solver.name(), params.size[2]);
        let dir = tacrom::rom::shipped_model_dir(name)
            .ok_or(format!("the shipped model {name} was not found"))?;
        let options = tacrom::rom::RomOptions {
            force: true,
            ..Default::default()
        };
        let mut rom = tacrom::rom::Rom::load(&dir, options).map_err(|e| e.to_string())?;
        rom.serve(params.size);
        let t0 = Instant::now();
        rom.evaluate(&gel, std::slice::from_ref(placed), &window.grid, &mut image)
            .map_err(|e| e.to_string())?;
        seconds += t0.elapsed().as_secs_f64();
        force *= rom.force_factor();
    } else {
        gel.surface_depth(&window.grid, &mut image);
    }
    Ok((
        Outcome {
            solver: choice.solver.name().to_owned(),
            dx,
            force,
            seconds,
            threads,
            iterations: r.iterations,
            converged: r.converged,
            particles: gel.num_particles(),
        },
        window.crop(&image),
    ))
}

/// A method's answer on a press, read back (extrapolations combined from their parts).
fn answer(s: &Settings, p: &StudyPress, name: &str) -> Option<(Outcome, Vec<f32>)> {
    match method(name)? {
        Method::Extrapolated(a, b, order) => {
            let (oa, da) = answer(s, p, a)?;
            let (ob, db) = answer(s, p, b)?;
            let k = 1.0 / (2f64.powf(order) - 1.0);
            let depth = da
                .iter()
                .zip(&db)
                .map(|(&x, &y)| (y + (y - x) * k as f32).max(0.0))
                .collect();
            let outcome = Outcome {
                solver: format!("{} + {}", oa.solver, ob.solver),
                dx: ob.dx,
                force: ob.force + (ob.force - oa.force) * k,
                seconds: oa.seconds + ob.seconds,
                threads: ob.threads,
                iterations: oa.iterations + ob.iterations,
                converged: oa.converged && ob.converged,
                particles: oa.particles + ob.particles,
            };
            Some((outcome, depth))
        }
        _ => {
            let dir = s.out.join(p.name);
            let text = std::fs::read_to_string(dir.join(file_name(name, "json"))).ok()?;
            let outcome: Outcome = serde_json::from_str(&text).ok()?;
            let (_, depth) = crate::npy::read::<f32>(&dir.join(file_name(name, "npy"))).ok()?;
            Some((outcome, depth))
        }
    }
}

/// One method against the finest solve on one press.
#[derive(Clone, Copy, Debug)]
struct Error {
    /// Depth MAE where either depth exceeds 1 um (um).
    mae: f64,
    /// Depth MAE over the gel's whole top face, as an image of it would count it (um;
    /// both depths taken equal outside the window).
    face: f64,
    /// Deepest point, method minus finest (um).
    peak: f64,
    /// Normal force, method over finest minus one (%).
    force: f64,
    seconds: f64,
    converged: bool,
}

/// `other` against `finest`; `face` is the number of points of the gel's top face.
fn compare(finest: &(Outcome, Vec<f32>), other: &(Outcome, Vec<f32>), face: usize) -> Error {
    let (mut sum, mut n) = (0.0, 0usize);
    let (mut peak_f, mut peak_o) = (0f64, 0f64);
    for (&f, &o) in finest.1.iter().zip(&other.1) {
        let (f, o) = (f64::from(f), f64::from(o));
        peak_f = peak_f.max(f);
        peak_o = peak_o.max(o);
        if f.max(o) > 1e-6 {
            sum += (f - o).abs();
            n += 1;
        }
    }
    Error {
        mae: sum / n.max(1) as f64 * 1e6,
        face: sum / face as f64 * 1e6,
        peak: (peak_o - peak_f) * 1e6,
        force: (other.0.force / finest.0.force - 1.0) * 100.0,
        seconds: other.0.seconds,
        converged: other.0.converged,
    }
}

fn report(s: &Settings) -> String {
    let mut text = String::from(
        "# Reference candidates against the finest solve\n\n\
         Per press: depth MAE (um, where either depth exceeds 1 um), deepest point and \
         normal force against the finest solve's, seconds from rest on one thread.\n\n",
    );
    let presses: Vec<&StudyPress> = PRESSES
        .iter()
        .filter(|p| s.presses.iter().any(|n| n == p.name))
        .collect();
    text.push_str("| press | finest: solver, dx mm, force N, s |");
    let others: Vec<&String> = s.methods.iter().filter(|m| *m != "finest").collect();
    for m in &others {
        text.push_str(&format!(" {m}: MAE, peak um, force %, s |"));
    }
    text.push_str("\n|---|---|");
    text.push_str(&"---|".repeat(others.len()));
    text.push('\n');
    let mut all: Vec<Vec<Error>> = vec![Vec::new(); others.len()];
    let mut counted = 0;
    for p in presses {
        let Some(finest) = answer(s, p, "finest") else {
            text.push_str(&format!("| {} | not solved |\n", p.name));
            continue;
        };
        counted += 1;
        let face = p.face().width * p.face().height;
        text.push_str(&format!(
            "| {} | {} {:.3} {:.4} {:.0}{} |",
            p.name,
            finest.0.solver,
            finest.0.dx * 1e3,
            finest.0.force,
            finest.0.seconds,
            if finest.0.converged {
                ""
            } else {
                " (not converged)"
            }
        ));
        for (i, m) in others.iter().enumerate() {
            match answer(s, p, m) {
                Some(o) => {
                    let e = compare(&finest, &o, face);
                    all[i].push(e);
                    text.push_str(&format!(
                        " {:.2}, {:+.1}, {:+.1}, {:.1}{} |",
                        e.mae,
                        e.peak,
                        e.force,
                        e.seconds,
                        if e.converged { "" } else { "*" }
                    ));
                }
                None => text.push_str(" - |"),
            }
        }
        text.push('\n');
    }
    text.push_str(&format!(
        "\nOver the {counted} presses with a finest solve (* marks a solve stopped at its \
         cap):\n\n| method | presses | mean MAE um | worst MAE um | mean face MAE um | worst face MAE um | mean abs peak um | mean abs \
         force % | worst force % | median s | worst s |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n"
    ));
    for (m, errors) in others.iter().zip(&all) {
        if errors.is_empty() {
            continue;
        }
        let n = errors.len() as f64;
        let mean = |f: &dyn Fn(&Error) -> f64| errors.iter().map(f).sum::<f64>() / n;
        let worst = |f: &dyn Fn(&Error) -> f64| errors.iter().map(f).fold(0.0, f64::max);
        let mut secs: Vec<f64> = errors.iter().map(|e| e.seconds).collect();
        secs.sort_by(f64::total_cmp);
        text.push_str(&format!(
            "| {m} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.1} | {:.2} | {:.2} | {:.1} | {:.1} |\n",
            errors.len(),
            mean(&|e| e.mae),
            worst(&|e| e.mae),
            mean(&|e| e.face),
            worst(&|e| e.face),
            mean(&|e| e.peak.abs()),
            mean(&|e| e.force.abs()),
            worst(&|e| e.force.abs()),
            secs[secs.len() / 2],
            secs[secs.len() - 1],
        ));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every press's indenter reaches into its gel no deeper than a quarter of the
    /// thickness, and its window holds the press's centre (every press where the
    /// benchmark's patterns are present; those whose pattern the checkout's copies hold
    /// otherwise).
    #[test]
    fn the_presses_are_well_posed() {
        let shared = tacrom::checkout_root().join("../shared/indenters/patterns");
        let (patterns, all) = if shared.is_dir() {
            (shared, true)
        } else {
            (tacrom::checkout_root().join("tests/data/patterns"), false)
        };
        let mut checked = 0;
        for p in PRESSES {
            let placed = match p.placed(&patterns) {
                Ok(placed) => placed,
                Err(e) => {
                    assert!(!all, "{}: {e}", p.name);
                    continue;
                }
            };
            let b = placed.aabb();
            assert!(b.min.z < -0.99 * p.depth * 1e-3, "{}: {}", p.name, b.min.z);
            assert!(b.min.z > -1.01 * p.depth * 1e-3, "{}: {}", p.name, b.min.z);
            assert!(p.depth <= p.size[2] / 4.0 + 1e-9, "{}", p.name);
            let w = p.window(&placed);
            let (x, y) = (p.x * 1e-3, p.y * 1e-3);
            assert!(
                w.grid.x(w.cols.0) < x && x < w.grid.x(w.cols.1 - 1),
                "{}",
                p.name
            );
            let (y0, y1) = (w.grid.y(w.rows.0), w.grid.y(w.rows.1 - 1));
            assert!(y0.min(y1) < y && y < y0.max(y1), "{}", p.name);
            checked += 1;
        }
        assert!(checked >= 10, "{checked} presses checked");
    }
}
