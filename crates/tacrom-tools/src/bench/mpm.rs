//! The gel's own benchmark (`tacrom mpm`): Hertz validation per resolution, the solver's
//! cost per resolution and thread count, its work per frame against the material, and
//! contacts smaller than the coarse grid's particle spacing.
//!
//! * **Hertz.** A frictionless rigid sphere (R = 5 mm) pressed at the centre of the
//!   default gel through increasing depths, one continuous sequence per grid spacing (the
//!   first press starts from the flat gel, every later one from the previous equilibrium).
//!   The total contact force is compared with [`hertz_bonded`] (Hertz with the bonded-layer
//!   correction of Dimitriadis et al. 2002).
//! * **Cost.** A moving press with friction (the default gel): after one warm-up press at
//!   0.1 mm, each frame presses 0.05 mm deeper and slides 0.02 mm along x, the kind of
//!   motion an arm makes between two sensor readings. Per spacing and thread count: median
//!   and 90th percentile of the solve time per frame, iterations per frame,
//!   particle-steps per second (active particles times iterations over solve time), and memory per
//!   particle (particle state plus the grid's share).
//!
//! * **Small contacts.** A sphere of radius 0.5 mm and a 90-degree cone tip pressed 0.1
//!   to 0.4 mm (frictionless, one continuous sequence each) into the coarse gel, whose
//!   surface particles lie 0.7 mm apart, against the same presses on a 0.5 mm grid
//!   ([`SMALL_REFERENCE_DX`], relaxation): the force ratio per depth.
//!
//! The fine spacing (0.3 mm, about 1e6 particles) takes minutes per frame; it runs with
//! `--fine`, a few frames only.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::Isometry3;

use super::BenchError;
use crate::progress::Progress;
use tacrom::geometry::{Placed, Sdf, Sphere, TriMesh};
use tacrom::mpm::hertz::{hertz_bonded, sneddon_cone};
use tacrom::mpm::{Gel, GelParams, Solver, SolverOptions};

/// Radius of the validation sphere (m).
pub const SPHERE_RADIUS: f64 = 5e-3;

/// Radius of the small-contact sphere (m).
pub const SMALL_SPHERE_RADIUS: f64 = 0.5e-3;

/// Grid spacing of the small-contact reference presses (m).
pub const SMALL_REFERENCE_DX: f64 = 0.5e-3;

/// Grid spacing the small contacts are measured on: the coarse gel's (m).
pub const SMALL_DX: f64 = 1.4e-3;

/// What `tacrom mpm` runs.
#[derive(Clone, Debug)]
pub struct MpmBenchOptions {
    /// Grid spacings of the Hertz sequences (m).
    pub hertz_dx: Vec<f64>,
    /// Depths of each Hertz sequence (m), increasing.
    pub depths: Vec<f64>,
    /// Grid spacings of the cost runs (m).
    pub speed_dx: Vec<f64>,
    /// Thread counts of the cost runs.
    pub threads: Vec<usize>,
    /// Solver tolerances of the cost runs (the fine mode's 1e-3, the coarse and rom modes'
    /// 3e-3, [`tacrom::config::Physics::default_tolerance`], and 1e-2).
    pub tolerances: Vec<f64>,
    /// Measured frames of a cost run (after the warm-up), for spacings of at least 0.5 mm.
    pub frames: usize,
    /// Measured frames below 0.5 mm.
    pub fine_frames: usize,
    /// Report folder.
    pub out: PathBuf,
    /// Progress lines on stderr.
    pub progress: bool,
    /// The equilibrium solvers, each run on every row.
    pub solvers: Vec<Solver>,
    /// Young's moduli (Pa) of the work-per-frame runs (coarse grid, Poisson 0.43).
    pub youngs: Vec<f64>,
    /// Poisson's ratios of the work-per-frame runs (coarse grid, the default modulus).
    pub poissons: Vec<f64>,
    /// Measured frames of a work-per-frame run.
    pub work_frames: usize,
    /// Depths of the small-contact presses (m), increasing; empty: not run.
    pub small_depths: Vec<f64>,
    /// The gel's friction coefficient in the cost runs (the default gel's, 0.5).
    pub friction: f64,
}

impl MpmBenchOptions {
    /// Coarse to 0.5 mm: a few minutes on two cores.
    pub fn standard() -> Self {
        Self {
            hertz_dx: vec![1.4e-3, 1.0e-3, 0.7e-3, 0.5e-3],
            depths: vec![0.1e-3, 0.2e-3, 0.3e-3, 0.4e-3, 0.5e-3],
            speed_dx: vec![1.4e-3, 1.0e-3, 0.7e-3, 0.5e-3],
            threads: vec![1, 2],
            tolerances: vec![1e-3, 3e-3, 1e-2],
            frames: 12,
            fine_frames: 3,
            out: PathBuf::from("out/bench/mpm"),
            solvers: vec![Solver::default()],
            progress: true,
            youngs: vec![1e4, 1e5, 1e6, 1e7],
            poissons: vec![0.3, 0.43, 0.49, 0.499],
            work_frames: 4,
            small_depths: vec![0.1e-3, 0.2e-3, 0.3e-3, 0.4e-3],
            friction: GelParams::default().friction,
        }
    }

    /// The standard runs plus the fine spacing (0.3 mm) in both parts.
    pub fn with_fine(mut self) -> Self {
        self.hertz_dx.push(0.3e-3);
        self.speed_dx.push(0.3e-3);
        self
    }
}

/// One Hertz press.
#[derive(Clone, Debug)]
pub struct HertzRow {
    /// Equilibrium solver.
    pub solver: Solver,
    /// Grid spacing (m).
    pub dx: f64,
    /// Particles.
    pub particles: usize,
    /// Indentation (m).
    pub depth: f64,
    /// Simulated force (N).
    pub force: f64,
    /// Analytic force (N).
    pub reference: f64,
    /// Iterations of this press.
    pub iterations: usize,
    /// Whether the solve converged.
    pub converged: bool,
    /// Solve time (s).
    pub seconds: f64,
}

impl HertzRow {
    /// Relative force error.
    pub fn error(&self) -> f64 {
        self.force / self.reference - 1.0
    }
}

/// One cost run.
#[derive(Clone, Debug)]
pub struct SpeedRow {
    /// Equilibrium solver.
    pub solver: Solver,
    /// Grid spacing (m).
    pub dx: f64,
    /// Particles.
    pub particles: usize,
    /// Solver threads.
    pub threads: usize,
    /// Solver tolerance.
    pub tolerance: f64,
    /// Measured frames.
    pub frames: usize,
    /// Median and 90th-percentile solve time per frame (ms).
    pub median_ms: f64,
    /// See `median_ms`.
    pub p90_ms: f64,
    /// Median iterations per frame.
    pub median_iterations: usize,
    /// Median Newton steps per frame on the coarse start's gels (grids twice as coarse,
    /// `SolverOptions::coarse_start_above`), not counted in `median_iterations`.
    pub median_coarse_iterations: usize,
    /// Median conjugate-gradient iterations per frame of Newton's linear solves (0 for the
    /// relaxation; the linear solver's contact Newton steps are its iterations).
    pub median_cg_iterations: usize,
    /// Median particles moved per frame (the solver's active region).
    pub median_active: usize,
    /// Particle-steps per second over the measured frames.
    pub particle_steps_per_s: f64,
    /// Frames that hit the iteration cap.
    pub unconverged: usize,
    /// Bytes per particle, the grid's share included.
    pub bytes_per_particle: f64,
    /// The gel's friction coefficient.
    pub friction: f64,
}

impl SpeedRow {
    /// The row's values in column order, for `speed.csv` (`csv`: full precision, SI) or
    /// the markdown table (rounded, dx in mm).
    fn cells(&self, csv: bool) -> [String; 15] {
        let r = self;
        let (dx, ms, p90, steps, bytes) = if csv {
            (
                format!("{:e}", r.dx),
                format!("{:.3}", r.median_ms),
                format!("{:.3}", r.p90_ms),
                format!("{:.4e}", r.particle_steps_per_s),
                format!("{:.1}", r.bytes_per_particle),
            )
        } else {
            (
                format!("{:.2}", r.dx * 1e3),
                format!("{:.1}", r.median_ms),
                format!("{:.1}", r.p90_ms),
                format!("{:.2e}", r.particle_steps_per_s),
                format!("{:.0}", r.bytes_per_particle),
            )
        };
        let tolerance = if csv {
            format!("{:e}", r.tolerance)
        } else {
            format!("{:.0e}", r.tolerance)
        };
        [
            r.solver.name().to_string(),
            dx,
            r.particles.to_string(),
            r.median_active.to_string(),
            tolerance,
            r.threads.to_string(),
            r.frames.to_string(),
            ms,
            p90,
            r.median_iterations.to_string(),
            r.median_coarse_iterations.to_string(),
            r.median_cg_iterations.to_string(),
            steps,
            r.unconverged.to_string(),
            bytes,
        ]
    }
}

/// The work per frame of one gel material in the moving press (coarse grid, one
/// thread, the default tolerance).
#[derive(Clone, Debug)]
pub struct WorkRow {
    /// Equilibrium solver.
    pub solver: Solver,
    /// Young's modulus (Pa).
    pub young: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Measured frames.
    pub frames: usize,
    /// Median and largest iterations per frame (explicit steps or Newton steps).
    pub median_iterations: usize,
    /// See `median_iterations`.
    pub max_iterations: usize,
    /// Sparse factorisations and steps solved by conjugate gradients with an earlier one,
    /// summed over the frames (Newton).
    pub factorisations: usize,
    /// See `factorisations`.
    pub reused: usize,
    /// Conjugate gradient iterations summed over the frames (Newton).
    pub cg_iterations: usize,
    /// Median solve time per frame (ms).
    pub median_ms: f64,
    /// Frames that hit the iteration cap.
    pub unconverged: usize,
}

/// Everything `tacrom mpm` measured.
#[derive(Clone, Debug, Default)]
pub struct MpmBenchResult {
    /// Hertz presses, per spacing then depth.
    pub hertz: Vec<HertzRow>,
    /// Cost runs, per spacing then thread count.
    pub speed: Vec<SpeedRow>,
    /// Work per frame, per material.
    pub work: Vec<WorkRow>,
    /// Small contacts, per shape, solver and depth.
    pub small: Vec<SmallRow>,
}

/// One small-contact press.
#[derive(Clone, Debug)]
pub struct SmallRow {
    /// Indenter (`sphere` or `cone`).
    pub shape: &'static str,
    /// Equilibrium solver on the coarse grid.
    pub solver: Solver,
    /// Depth (m).
    pub depth: f64,
    /// Force on the coarse grid (N).
    pub force: f64,
    /// Force on the reference grid (N).
    pub reference: f64,
    /// The analytic force (N): Hertz on the bonded layer for the sphere, Sneddon's
    /// half-space cone for the cone.
    pub analytic: f64,
    /// Whether both solves (coarse and reference) converged.
    pub converged: bool,
}

impl SmallRow {
    /// Coarse force over the reference grid's.
    pub fn ratio(&self) -> f64 {
        self.force / self.reference
    }

    /// Coarse force over the analytic one.
    pub fn analytic_ratio(&self) -> f64 {
        self.force / self.analytic
    }
}

/// Semi-vertical angle of the small-contact cone (rad).
pub const CONE_HALF_ANGLE: f64 = std::f64::consts::FRAC_PI_4;

/// A cone with its tip at the origin pointing down (-z), half-angle 45 degrees, 3 mm tall
/// with a flat top, as a closed triangle mesh of 64 sides.
pub fn cone_tip() -> Arc<dyn Sdf> {
    let cone = TriMesh::cone_tip(3e-3, CONE_HALF_ANGLE, 64);
    Arc::new(cone.expect("the cone mesh is valid"))
}

/// The forces of a frictionless press of `shape` (lowest point `lowest` below its local
/// origin) through `depths` at spacing `dx`, one continuous sequence, each with whether
/// its solve converged.
fn small_sequence(
    shape: &Arc<dyn Sdf>,
    lowest: f64,
    depths: &[f64],
    dx: f64,
    solver: Solver,
    threads: usize,
) -> Result<Vec<(f64, bool)>, BenchError> {
    let mut g = gel(dx, 0.0, threads, SolverOptions::default().tolerance, solver)?;
    Ok(depths
        .iter()
        .map(|&d| {
            let placed = [Placed {
                shape: shape.clone(),
                pose: Isometry3::translation(0.0, 0.0, lowest - d),
            }];
            let converged = g.solve(&placed).converged;
            (g.force().z, converged)
        })
        .collect())
}

/// The small-contact presses (see the module docs) on the coarse grid per solver against
/// the reference grid.
pub fn small_run(
    depths: &[f64],
    solvers: &[Solver],
    threads: usize,
    progress: &Progress,
) -> Result<Vec<SmallRow>, BenchError> {
    // Each shape with the height of its lowest point below its local origin.
    let shapes: [(&'static str, Arc<dyn Sdf>, f64); 2] = [
        (
            "sphere",
            Arc::new(Sphere::new(SMALL_SPHERE_RADIUS)),
            SMALL_SPHERE_RADIUS,
        ),
        ("cone", cone_tip(), 0.0),
    ];
    let p = GelParams::default();
    let analytic = |name: &str, d: f64| match name {
        "sphere" => hertz_bonded(p.young, p.poisson, SMALL_SPHERE_RADIUS, d, p.size[2]),
        _ => sneddon_cone(p.young, p.poisson, CONE_HALF_ANGLE, d),
    };
    let mut rows = Vec::new();
    for (name, shape, lowest) in &shapes {
        progress.message(format!(
            "small {name}: reference dx {:.1} mm",
            SMALL_REFERENCE_DX * 1e3
        ));
        let reference = small_sequence(
            shape,
            *lowest,
            depths,
            SMALL_REFERENCE_DX,
            Solver::Relaxation,
            threads,
        )?;
        for &solver in solvers {
            let forces = small_sequence(shape, *lowest, depths, SMALL_DX, solver, threads)?;
            for ((&depth, &(force, ok)), &(reference, ref_ok)) in
                depths.iter().zip(&forces).zip(&reference)
            {
                rows.push(SmallRow {
                    shape: name,
                    solver,
                    depth,
                    force,
                    reference,
                    analytic: analytic(name, depth),
                    converged: ok && ref_ok,
                });
            }
            let ratios: Vec<String> = rows[rows.len() - depths.len()..]
                .iter()
                .map(|r| format!("{:.2}", r.ratio()))
                .collect();
            progress.line(&format!(
                "small {name} {}: force / {:.1} mm grid's {}",
                solver.name(),
                SMALL_REFERENCE_DX * 1e3,
                ratios.join(", ")
            ));
        }
        progress.advance(1);
    }
    Ok(rows)
}

fn sphere() -> Arc<dyn Sdf> {
    Arc::new(Sphere::new(SPHERE_RADIUS))
}

fn at(shape: &Arc<dyn Sdf>, x: f64, depth: f64) -> [Placed; 1] {
    [Placed {
        shape: shape.clone(),
        pose: Isometry3::translation(x, 0.0, SPHERE_RADIUS - depth),
    }]
}

fn gel(
    dx: f64,
    friction: f64,
    threads: usize,
    tolerance: f64,
    solver: Solver,
) -> Result<Gel, BenchError> {
    let params = GelParams {
        dx,
        friction,
        ..Default::default()
    };
    let options = SolverOptions {
        threads,
        tolerance,
        solver,
        ..Default::default()
    };
    Gel::new(params, options).map_err(|e| BenchError::Usage(format!("dx {dx:e} m: {e}")))
}

/// The Hertz sequence at spacing `dx` with `threads` solver threads; `progress` advances
/// and gets a line per depth.
pub fn hertz_sequence(
    dx: f64,
    depths: &[f64],
    threads: usize,
    solver: Solver,
    progress: &Progress,
) -> Result<Vec<HertzRow>, BenchError> {
    let mut g = gel(dx, 0.0, threads, SolverOptions::default().tolerance, solver)?;
    let p = *g.params();
    let ball = sphere();
    let mut rows = Vec::with_capacity(depths.len());
    for &d in depths {
        progress.message(format!("hertz dx {:.2} mm d {:.2} mm", dx * 1e3, d * 1e3));
        let t0 = Instant::now();
        let rep = g.solve(&at(&ball, 0.0, d));
        let row = HertzRow {
            solver,
            dx,
            particles: g.num_particles(),
            depth: d,
            force: g.force().z,
            reference: hertz_bonded(p.young, p.poisson, SPHERE_RADIUS, d, p.size[2]),
            iterations: rep.iterations,
            converged: rep.converged,
            seconds: t0.elapsed().as_secs_f64(),
        };
        progress.advance(1);
        progress.line(&format!(
            "hertz {} dx {:.2} mm d {:.2} mm: {:+.1} % ({} it, {:.1} s)",
            solver.name(),
            dx * 1e3,
            d * 1e3,
            100.0 * row.error(),
            row.iterations,
            row.seconds
        ));
        rows.push(row);
    }
    Ok(rows)
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// The moving press on `g`: a warm-up press at 0.1 mm, then `frames` (at least one)
/// frames, each 0.05 mm deeper and 0.02 mm further along x; each frame's solve time (s)
/// and report.
fn moving_press(g: &mut Gel, frames: usize) -> Vec<(f64, tacrom::mpm::SolveReport)> {
    let ball = sphere();
    g.solve(&at(&ball, 0.0, 0.1e-3));
    (1..=frames.max(1))
        .map(|f| {
            let placed = at(&ball, 0.02e-3 * f as f64, 0.1e-3 + 0.05e-3 * f as f64);
            let t0 = Instant::now();
            let rep = g.solve(&placed);
            (t0.elapsed().as_secs_f64(), rep)
        })
        .collect()
}

/// The moving press at spacing `dx` and solver `tolerance`: `frames` measured frames after
/// a warm-up.
pub fn speed_run(
    dx: f64,
    threads: usize,
    tolerance: f64,
    frames: usize,
    solver: Solver,
    friction: f64,
) -> Result<SpeedRow, BenchError> {
    let mut g = gel(dx, friction, threads, tolerance, solver)?;
    let n = g.num_particles();
    let (mut times, mut iters, mut active) = (Vec::new(), Vec::new(), Vec::new());
    let (mut unconverged, mut coarse, mut cg) = (0, Vec::new(), Vec::new());
    for (seconds, rep) in moving_press(&mut g, frames) {
        times.push(seconds);
        iters.push(rep.iterations);
        coarse.push(rep.coarse_iterations);
        cg.push(rep.cg_iterations);
        active.push(rep.active_particles);
        unconverged += usize::from(!rep.converged);
    }
    let total_time: f64 = times.iter().sum();
    let total_steps: f64 = iters
        .iter()
        .zip(&active)
        .map(|(&i, &a)| (i * a) as f64)
        .sum();
    active.sort_unstable();
    times.sort_by(f64::total_cmp);
    let mut sorted_iters = iters.clone();
    sorted_iters.sort_unstable();
    coarse.sort_unstable();
    cg.sort_unstable();
    Ok(SpeedRow {
        solver,
        dx,
        particles: n,
        threads,
        tolerance,
        frames: times.len(),
        median_ms: quantile(&times, 0.5) * 1e3,
        p90_ms: quantile(&times, 0.9) * 1e3,
        median_iterations: sorted_iters[sorted_iters.len() / 2],
        median_coarse_iterations: coarse[coarse.len() / 2],
        median_cg_iterations: cg[cg.len() / 2],
        median_active: active[active.len() / 2],
        particle_steps_per_s: total_steps / total_time,
        unconverged,
        bytes_per_particle: Gel::bytes_per_particle() as f64 + g.grid_bytes() as f64 / n as f64,
        friction,
    })
}

/// The moving press of [`speed_run`] on the coarse grid (one thread, the default
/// tolerance) for a gel of modulus `young` and Poisson's ratio `poisson`: the work per
/// frame.
pub fn work_run(
    young: f64,
    poisson: f64,
    frames: usize,
    solver: Solver,
) -> Result<WorkRow, BenchError> {
    let params = GelParams {
        young,
        poisson,
        ..Default::default()
    };
    let options = SolverOptions {
        solver,
        ..Default::default()
    };
    let mut g = Gel::new(params, options)
        .map_err(|e| BenchError::Usage(format!("E {young:e} Pa, Poisson {poisson}: {e}")))?;
    let (mut times, mut iters) = (Vec::new(), Vec::new());
    let (mut factorisations, mut reused, mut cg_iterations, mut unconverged) = (0, 0, 0, 0);
    for (seconds, rep) in moving_press(&mut g, frames) {
        times.push(seconds);
        iters.push(rep.iterations);
        factorisations += rep.factorisations;
        reused += rep.reused;
        cg_iterations += rep.cg_iterations;
        unconverged += usize::from(!rep.converged);
    }
    times.sort_by(f64::total_cmp);
    iters.sort_unstable();
    Ok(WorkRow {
        solver,
        young,
        poisson,
        frames: times.len(),
        median_iterations: iters[iters.len() / 2],
        max_iterations: *iters.last().unwrap_or(&0),
        factorisations,
        reused,
        cg_iterations,
        median_ms: quantile(&times, 0.5) * 1e3,
        unconverged,
    })
}

/// Runs the parts the options ask for and writes `report.md`, `hertz.csv`, `speed.csv`,
/// `work.csv` and `small.csv` into `options.out`.
pub fn run(options: &MpmBenchOptions) -> Result<MpmBenchResult, BenchError> {
    let mut result = MpmBenchResult::default();
    let most_threads = options.threads.iter().copied().max().unwrap_or(1);
    let progress = Progress::new(
        options.solvers.len()
            * (options.hertz_dx.len() * options.depths.len()
                + options.speed_dx.len() * options.tolerances.len() * options.threads.len()
                + options.youngs.len()
                + options.poissons.len())
            + if options.small_depths.is_empty() {
                0
            } else {
                2
            },
        options.progress,
    );
    for &dx in &options.hertz_dx {
        for &solver in &options.solvers {
            let rows = hertz_sequence(dx, &options.depths, most_threads, solver, &progress)?;
            result.hertz.extend(rows);
        }
    }
    for &dx in &options.speed_dx {
        let frames = if dx < 0.5e-3 {
            options.fine_frames
        } else {
            options.frames
        };
        for &tolerance in &options.tolerances {
            for &threads in &options.threads {
                // The solvers back to back, so that both see the same machine state.
                for &solver in &options.solvers {
                    let what = format!(
                        "speed {} dx {:.2} mm, tolerance {tolerance:.0e}, {threads} thread(s)",
                        solver.name(),
                        dx * 1e3
                    );
                    progress.message(what.clone());
                    let row = speed_run(dx, threads, tolerance, frames, solver, options.friction)?;
                    progress.advance(1);
                    progress.line(&format!(
                        "{what}: median {:.1} ms/frame, {} it, {:.2e} particle-steps/s",
                        row.median_ms, row.median_iterations, row.particle_steps_per_s
                    ));
                    result.speed.push(row);
                }
            }
        }
    }
    let default = GelParams::default();
    let materials = options
        .youngs
        .iter()
        .map(|&e| (e, default.poisson))
        .chain(options.poissons.iter().map(|&nu| (default.young, nu)));
    for (young, poisson) in materials {
        for &solver in &options.solvers {
            let what = format!("work {} E {young:.0e} Pa, Poisson {poisson}", solver.name());
            progress.message(what.clone());
            let row = work_run(young, poisson, options.work_frames, solver)?;
            progress.line(&format!(
                "{what}: median {} it ({} at most), {:.1} ms/frame, {} unconverged",
                row.median_iterations, row.max_iterations, row.median_ms, row.unconverged
            ));
            result.work.push(row);
        }
        progress.advance(1);
    }
    if !options.small_depths.is_empty() {
        result.small = small_run(
            &options.small_depths,
            &options.solvers,
            most_threads,
            &progress,
        )?;
    }
    progress.finish();
    write_report(&options.out, &result)?;
    Ok(result)
}

fn io_error(path: &Path, e: std::io::Error) -> BenchError {
    BenchError::Usage(format!("cannot write {}: {e}", path.display()))
}

/// Distinct values in first-seen order.
fn distinct(values: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut out: Vec<f64> = Vec::new();
    for v in values {
        if !out.contains(&v) {
            out.push(v);
        }
    }
    out
}

/// The markdown report: the Hertz error table (spacing by depth) and the cost table.
pub fn markdown(result: &MpmBenchResult) -> String {
    let mut s = String::new();
    if !result.hertz.is_empty() {
        let depths = distinct(result.hertz.iter().map(|r| r.depth));
        let dxs = distinct(result.hertz.iter().map(|r| r.dx));
        s.push_str(
            "## Hertz (bonded layer), force error per depth\n\nFrictionless sphere R = 5 mm \
             on the default gel (30 x 30 x 4 mm, E = 1.19e5 Pa, Poisson 0.43); Dimitriadis et \
             al. 2002. `*`: hit the iteration cap. Iterations: explicit steps (relaxation), \
             Newton steps (newton) or linearisations of the contact (linear).\n\n| solver \
             | dx (mm) | particles |",
        );
        for d in &depths {
            let _ = write!(s, " d = {:.2} mm |", d * 1e3);
        }
        s.push_str(" iterations | solve s |\n|---|---|---|");
        s.push_str(&"---|".repeat(depths.len() + 2));
        s.push('\n');
        let solvers = {
            let mut v: Vec<Solver> = Vec::new();
            for r in &result.hertz {
                if !v.contains(&r.solver) {
                    v.push(r.solver);
                }
            }
            v
        };
        for (dx, solver) in dxs
            .iter()
            .flat_map(|dx| solvers.iter().map(move |solver| (dx, solver)))
        {
            let rows: Vec<&HertzRow> = result
                .hertz
                .iter()
                .filter(|r| r.dx == *dx && r.solver == *solver)
                .collect();
            if rows.is_empty() {
                continue;
            }
            let _ = write!(
                s,
                "| {} | {:.2} | {} |",
                solver.name(),
                dx * 1e3,
                rows[0].particles
            );
            for d in &depths {
                match rows.iter().find(|r| r.depth == *d) {
                    Some(r) => {
                        let star = if r.converged { "" } else { "*" };
                        let _ = write!(s, " {:+.1} %{star} |", 100.0 * r.error());
                    }
                    None => s.push_str(" – |"),
                }
            }
            let its: Vec<String> = rows.iter().map(|r| r.iterations.to_string()).collect();
            let secs: f64 = rows.iter().map(|r| r.seconds).sum();
            let _ = writeln!(s, " {} | {:.1} |", its.join(" / "), secs);
        }
        s.push('\n');
    }
    if !result.speed.is_empty() {
        let _ = write!(
            s,
            "## Cost of a moving press\n\nDefault gel with friction {}, sphere R = 5 mm; each \
             frame 0.05 mm deeper and 0.02 mm along x, after a warm-up press at 0.1 mm. \
             Solve time only (no image). Active: particles the solve moved (median; the rest \
             of the gel keeps its state; linear: contact points carrying a force). \
             Particle-steps count active particles; iterations are explicit steps \
             (relaxation), Newton steps (newton) or linearisations of the contact \
             (linear); coarse start: Newton steps on the gels twice (and four times) as \
             coarse that start a fine grid's Newton solve (included in the time); CG: \
             conjugate-gradient iterations of Newton's linear solves (linear: the \
             contact's Newton steps).\n\n| \
             solver | dx (mm) | particles | active | tolerance | threads | frames | median \
             ms | p90 ms | iterations (median) | coarse start (median) | CG (median) | \
             particle-steps/s | unconverged | bytes/particle |\n\
             |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
            result.speed[0].friction
        );
        for r in &result.speed {
            let _ = writeln!(s, "| {} |", r.cells(false).join(" | "));
        }
    }
    if !result.work.is_empty() {
        s.push_str(
            "\n## Work per frame against the material\n\nThe moving press above on the coarse \
             grid (1.4 mm), one thread, tolerance 3e-3, friction 0.5; Young's modulus varied \
             at Poisson 0.43, Poisson's ratio at E = 1.19e5 Pa. Iterations: explicit steps \
             (relaxation), Newton steps (newton) or linearisations of the contact (linear); \
             factorisations (or two-grid builds), Newton steps solved by conjugate gradients \
             with an earlier one, and conjugate-gradient iterations (linear: the contact's \
             Newton steps) summed over the frames.\n\n| solver | E (Pa) | \
             Poisson | frames | iterations (median) | iterations (max) | factorisations | \
             CG steps | CG iterations | median ms | unconverged \
             |\n|---|---|---|---|---|---|---|---|---|---|---|\n",
        );
        for r in &result.work {
            let _ = writeln!(s, "| {} |", work_cells(r, false).join(" | "));
        }
    }
    if !result.small.is_empty() {
        let _ = write!(
            s,
            "\n## Small contacts\n\nA sphere of radius {:.1} mm and a 90-degree cone tip \
             pressed into the default gel (frictionless, one continuous sequence each) on the \
             coarse grid ({:.1} mm; surface particles {:.2} mm apart) against the same presses \
             on a {:.1} mm grid (relaxation) and the analytic force (sphere: Hertz on the \
             bonded layer; cone: Sneddon, half-space). `*`: a solve hit the iteration cap; \
             `-`: the reference is zero.\n\n| shape | solver | depth (mm) | force (N) | {:.1} \
             mm grid (N) | ratio | analytic (N) | ratio |\n|---|---|---|---|---|---|---|---|\n",
            SMALL_SPHERE_RADIUS * 1e3,
            SMALL_DX * 1e3,
            0.5 * SMALL_DX * 1e3,
            SMALL_REFERENCE_DX * 1e3,
            SMALL_REFERENCE_DX * 1e3,
        );
        for r in &result.small {
            let _ = writeln!(s, "| {} |", small_cells(r, false).join(" | "));
        }
    }
    s
}

/// A small-contact row's values in column order (`csv`: full precision).
fn small_cells(r: &SmallRow, csv: bool) -> [String; 8] {
    let star = if r.converged || csv { "" } else { "*" };
    // Forces of exactly zero print without the sign of a -0.0 sum.
    let force = |f: f64| format!("{:.5}", f + 0.0);
    let ratio = |q: f64| {
        if q.is_finite() {
            format!("{:.3}{star}", q + 0.0)
        } else {
            "-".to_string()
        }
    };
    [
        r.shape.to_string(),
        r.solver.name().to_string(),
        if csv {
            format!("{:e}", r.depth)
        } else {
            format!("{:.2}", r.depth * 1e3)
        },
        force(r.force),
        force(r.reference),
        ratio(r.ratio()),
        force(r.analytic),
        ratio(r.analytic_ratio()),
    ]
}

/// A work row's values in column order (`csv`: full precision).
fn work_cells(r: &WorkRow, csv: bool) -> [String; 11] {
    [
        r.solver.name().to_string(),
        format!("{:.2e}", r.young),
        format!("{}", r.poisson),
        r.frames.to_string(),
        r.median_iterations.to_string(),
        r.max_iterations.to_string(),
        r.factorisations.to_string(),
        r.reused.to_string(),
        r.cg_iterations.to_string(),
        if csv {
            format!("{:.3}", r.median_ms)
        } else {
            format!("{:.1}", r.median_ms)
        },
        r.unconverged.to_string(),
    ]
}

fn write_file(out: &Path, name: &str, text: String) -> Result<(), BenchError> {
    let path = out.join(name);
    std::fs::write(&path, text).map_err(|e| io_error(&path, e))
}

fn write_report(out: &Path, result: &MpmBenchResult) -> Result<(), BenchError> {
    std::fs::create_dir_all(out).map_err(|e| io_error(out, e))?;
    let header = format!(
        "# tacrom mpm\n\nCommand: `{}`. Machine: {}.\n\n",
        super::command_line(),
        super::machine()
    );
    write_file(out, "report.md", header + &markdown(result))?;
    let mut hertz = String::from(
        "solver,dx_m,particles,depth_m,force_n,hertz_n,error,iterations,converged,seconds\n",
    );
    for r in &result.hertz {
        let _ = writeln!(
            hertz,
            "{},{:e},{},{:e},{:e},{:e},{:.5},{},{},{:.3}",
            r.solver.name(),
            r.dx,
            r.particles,
            r.depth,
            r.force,
            r.reference,
            r.error(),
            r.iterations,
            r.converged,
            r.seconds
        );
    }
    write_file(out, "hertz.csv", hertz)?;
    let mut speed = String::from(
        "solver,dx_m,particles,median_active,tolerance,threads,frames,median_ms,p90_ms,median_iterations,median_coarse_iterations,median_cg_iterations,particle_steps_per_s,unconverged,bytes_per_particle\n",
    );
    for r in &result.speed {
        let _ = writeln!(speed, "{}", r.cells(true).join(","));
    }
    write_file(out, "speed.csv", speed)?;
    let mut work = String::from(
        "solver,young_pa,poisson,frames,median_iterations,max_iterations,factorisations,cg_steps,cg_iterations,median_ms,unconverged\n",
    );
    for r in &result.work {
        let _ = writeln!(work, "{}", work_cells(r, true).join(","));
    }
    write_file(out, "work.csv", work)?;
    let mut small = String::from(
        "shape,solver,depth_m,force_n,reference_n,ratio,analytic_n,analytic_ratio,converged\n",
    );
    for r in &result.small {
        let _ = writeln!(small, "{},{}", small_cells(r, true).join(","), r.converged);
    }
    write_file(out, "small.csv", small)
}

#[cfg(test)]
mod tests {
    use super::*;

    // The small-contact table: one row per shape, solver and depth, the ratios to both
    // references, a dash where the reference grid gives no force.
    #[test]
    fn markdown_lists_the_small_contacts_with_both_ratios() {
        let row = |depth: f64, force: f64, reference: f64| SmallRow {
            shape: "cone",
            solver: Solver::Newton,
            depth,
            force,
            reference,
            analytic: 0.01,
            converged: true,
        };
        let result = MpmBenchResult {
            small: vec![row(0.1e-3, 0.02, 0.0), row(0.2e-3, 0.03, 0.015)],
            ..Default::default()
        };
        let md = markdown(&result);
        assert!(
            md.contains("| cone | newton | 0.10 | 0.02000 | 0.00000 | - | 0.01000 | 2.000 |"),
            "{md}"
        );
        assert!(
            md.contains("| cone | newton | 0.20 | 0.03000 | 0.01500 | 2.000 | 0.01000 | 3.000 |"),
            "{md}"
        );
    }

    // The report has one Hertz row per spacing with one cell per depth, and marks
    // unconverged presses.
    #[test]
    fn markdown_tables_have_one_row_per_spacing() {
        let row = |dx: f64, depth: f64, converged: bool| HertzRow {
            solver: Solver::Relaxation,
            dx,
            particles: 10,
            depth,
            force: 1.1,
            reference: 1.0,
            iterations: 5,
            converged,
            seconds: 0.1,
        };
        let result = MpmBenchResult {
            hertz: vec![
                row(1e-3, 2e-4, true),
                row(1e-3, 5e-4, false),
                row(5e-4, 2e-4, true),
            ],
            speed: Vec::new(),
            work: Vec::new(),
            small: Vec::new(),
        };
        let md = markdown(&result);
        let lines: Vec<&str> = md.lines().filter(|l| l.starts_with("| ")).collect();
        assert_eq!(lines.len(), 3, "{md}");
        assert!(lines[1].contains("+10.0 %*"), "{md}");
        assert!(lines[2].contains("– |"), "{md}");
    }

    // Two solvers give a row each per spacing, side by side, named in the first column.
    #[test]
    fn markdown_puts_the_solvers_side_by_side() {
        let row = |solver: Solver, dx: f64| HertzRow {
            solver,
            dx,
            particles: 10,
            depth: 2e-4,
            force: 1.0,
            reference: 1.0,
            iterations: 5,
            converged: true,
            seconds: 0.1,
        };
        let result = MpmBenchResult {
            hertz: vec![
                row(Solver::Relaxation, 1e-3),
                row(Solver::Newton, 1e-3),
                row(Solver::Relaxation, 5e-4),
            ],
            speed: Vec::new(),
            work: Vec::new(),
            small: Vec::new(),
        };
        let md = markdown(&result);
        let lines: Vec<&str> = md.lines().filter(|l| l.starts_with("| ")).collect();
        assert_eq!(lines.len(), 4, "{md}");
        assert!(lines[1].starts_with("| relaxation | 1.00 |"), "{md}");
        assert!(lines[2].starts_with("| newton | 1.00 |"), "{md}");
        assert!(lines[3].starts_with("| relaxation | 0.50 |"), "{md}");
    }

    // The cost run at a coarse spacing reports consistent figures.
    #[test]
    fn speed_run_counts_particle_steps() {
        let r = speed_run(2e-3, 1, 1e-3, 2, Solver::Relaxation, 0.5).expect("run");
        assert_eq!(r.frames, 2);
        assert!(r.median_iterations > 0 && r.particle_steps_per_s > 0.0);
        assert!(r.bytes_per_particle >= Gel::bytes_per_particle() as f64);
        assert!(r.p90_ms >= r.median_ms);
    }

    // The work run of a stiff material on the Newton solver counts its factorisations and
    // conjugate-gradient steps: every Newton step is one or the other.
    #[test]
    fn work_run_counts_newton_steps() {
        let r = work_run(1e6, 0.43, 1, Solver::Newton).expect("run");
        assert_eq!((r.frames, r.unconverged), (1, 0));
        assert!(r.median_iterations > 0);
        assert_eq!(r.factorisations + r.reused, r.median_iterations);
        let md = markdown(&MpmBenchResult {
            work: vec![r],
            ..Default::default()
        });
        assert!(md.contains("| newton | 1.00e6 | 0.43 | 1 |"), "{md}");
    }
}
