//! The elastomer as a quasi-static MLS-MPM simulation.
//!
//! [`Gel`] holds a block of silicone, bonded to the sensor at its bottom face, discretised
//! by the moving least squares material point method (MLS-MPM, Hu et al. 2018) with APIC
//! transfers (Jiang et al. 2015) and quadratic B-spline weights. [`Gel::solve`] brings it
//! to static equilibrium under rigid indenters given as signed distance fields;
//! [`Gel::surface_depth`] samples the indentation of its top face on a pixel grid,
//! [`Gel::surface_shear`] its in-plane displacement, [`Gel::surface_displacement`] the
//! displacement of one surface point, and [`Gel::force`] returns the total contact force.
//!
//! # Frame and discretisation
//!
//! Sensor frame: origin at the centre of the undeformed top face, +z out of the gel, the
//! gel in `[-Lx/2, Lx/2] x [-Ly/2, Ly/2] x [-T, 0]`. The background grid has spacing
//! `dx`, centred laterally on the gel (mirror symmetric); a node plane lies exactly on the
//! bonded bottom `z = -T`. Along each axis the gel
//! gets `n = max(1, round(L / dx))` cells' worth of particles, two per cell, at spacing
//! `s = L / (2 n)`: the simulated block has exactly the requested size, and when `L / dx`
//! is not an integer the particles are slightly closer or farther apart than `dx / 2`
//! (4 mm at dx = 0.3 mm: 13 cells, 26 particles, s = 0.154 mm). Particle volume is
//! `sx sy sz` (`dx^3 / 8` when the size fits the grid).
//!
//! # Internal units and mass scaling
//!
//! Inside the solver lengths are in cells (`dx`), time in steps (`dt = 1`) and stresses
//! in units of the P-wave modulus `M = lambda + 2 mu`, and everything is f32 (values of
//! order one; f64 is no more accurate at the solver tolerance, and slower; measured:
//! `docs/solvers.md`, "Two solvers and a third").
//! The density is a free parameter at equilibrium, so it is chosen (mass scaling) to make
//! the P-wave speed `c_p = sqrt(M / rho)` exactly `cfl` cells per step: `rho' = 1 / cfl^2`.
//! The CFL condition `c_p dt <= cfl dx` then holds by construction and the number of steps
//! depends only on the geometry in cells, Poisson's ratio and the tolerance, not on `E` or
//! the real density. Forces convert back as `F = F' M dx^2`.
//!
//!
//! # Near incompressibility
//!
//! Near incompressibility (Poisson 0.49, 0.499): volumetric locking comes from imposing the
//! volume constraint at every particle (8 per cell) with about 3 velocity unknowns per
//! node. As in F-bar / B-bar (de Souza Neto et al. 1996; Hughes 1980), the pressure term
//! of the stress uses a smoothed volume ratio `J_bar`: `J` is scattered to the nodes with
//! the mass and gathered back with the weights (one step behind, which is immaterial at
//! equilibrium), so there is about one volume constraint per node; the deviatoric part
//! uses the particle's own `F` ([`SolverOptions::fbar`]). `det F` is clamped to
//! `[J_MIN, J_MAX]`. Stability needs nothing more (the step follows `c_p`), but the shear
//! modes that carry an indentation are `sqrt(M / mu)` times slower than `c_p`, so the
//! iteration count grows like that ratio (about 3.2x at 0.49, 10x at 0.499, relative to
//! 0.43); the cap bounds the cost and the report says when it was hit.
//!
//! # Robustness
//!
//! A non-finite value in any particle after a step, or in any particle at the start of a
//! solve (then the gel restarts from rest), is recorded
//! ([`SolveReport::nonfinite_recovered`]) and the gel is restored to its state at the start
//! of the solve (the previous good equilibrium; if that is itself bad, the undeformed gel).
//! Indenters with non-finite poses are skipped. Particles are clamped inside the grid and
//! `det F` to `[J_MIN, J_MAX]` (inverted particles included, by clamping the signed
//! singular values of `F`, which forgets that part of the deformation); a solve that ends with a particle at a clamp (an indenter driven through
//! the gel) makes the next solve start from the undeformed gel
//! ([`SolveReport::restarted`]).
//!
//! # Parts
//!
//! * `params.rs`: parameters, options, their validation, errors and the solve report;
//! * `indenters.rs`: matching indenters between solves, their start poses and sweep;
//! * `region.rs`: the active region a solve moves;
//! * `relax.rs`: dynamic relaxation, the convergence test, one step (the default solver);
//! * `total.rs`: the same relaxation on nodal displacements with fixed quadrature points
//!   ([`Solver::Total`], experimental: total-Lagrangian, so its equilibrium does not
//!   depend on the path);
//! * `newton/`: the equilibrium as an energy minimum by Newton's method
//!   ([`Solver::Newton`]; total-Lagrangian nodal displacements, sparse Cholesky, contact
//!   on a surface lattice finer than the particles, lagged friction);
//! * `transfer.rs`: the four parts of a step; `contact.rs`: the contact forces;
//!   `materials/`: the constitutive models, one file each with both its forms (the
//!   relaxation's f32 stress, Newton's f64 energy); `rotation.rs`: the polar rotation the
//!   corotated model reads; `choice.rs`: which solver a gel gets; `surface.rs`: the depth
//!   and shear images.

pub mod choice;
mod contact;
pub(crate) mod gel_cache;
pub mod hertz;
mod indenters;
mod linear;
mod materials;
mod newton;
mod params;
mod pressure;
pub use pressure::spread_loads;
mod region;
mod relax;
mod rotation;
mod solver;
mod state;
pub use state::StateBounds;
pub use surface::{Part, ONE_STEP_FRACTION};
mod surface;
mod total;
mod transfer;

#[cfg(test)]
mod tests;

use nalgebra::{Isometry3, Point3, Vector2, Vector3};

use std::sync::Arc;

use crate::geometry::{PixelGrid, Placed, Sdf};
use crate::scratch::{recycled, refill};

pub use choice::{
    choose, Choice, Role, AUTO_NEWTON_POISSON, COARSE_START_UNKNOWNS, LINEAR_UNKNOWNS,
    MISSED_FRACTION, MULTIGRID_UNKNOWNS, UNRESOLVED_POINTS,
};
use contact::{ActiveContact, SlotContact, StepIndenter};
use indenters::{match_indenters, Sweep};
pub use materials::{ConstitutiveModel, FixedCorotatedModel, NeoHookeanModel};
pub use params::{
    GelParams, Linear, Material, MpmError, SolveReport, Solver, SolverOptions, ACTIVE_MARGIN,
    CAP_CELLS, FBAR_POISSON, J_MAX, J_MIN, NESTED_MARGIN,
};
pub use rotation::extract_rotation;
use solver::Equilibrium;
use transfer::{ChunkStats, LayerStats, Node, Particle, Region, Stencil, StepCtx};

/// Rotation-extraction steps per time step (fixed corotated), warm-started.
const ROT_ITERS: usize = 1;

/// Grid nodes added around the gel on each lateral side and above it (cells).
const PAD: usize = 3;
/// Grid nodes below the bonded face (cells); all of them are fixed.
const PAD_BOTTOM: usize = 2;

/// Most points per indenter that [`Gel::unloaded_penetration`] samples.
pub const MISSED_SAMPLES: usize = 16_384;

/// Moves at most of the compass search for a tip between those samples.
const COMPASS_MOVES: usize = 200;

/// Geometry of the particle lattice and grid, fixed at construction.
#[derive(Clone, Copy, Debug)]
struct Layout {
    dx: f64,
    /// SI position of node (0, 0, 0).
    origin: Vector3<f64>,
    dims: [usize; 3],
    /// Particles per axis.
    lattice: [usize; 3],
    /// Particle spacing per axis (m).
    spacing: [f64; 3],
}

impl Layout {
    /// The lattice and grid of a gel with `params` (see the module docs, "Frame and
    /// discretisation").
    fn new(params: &GelParams) -> Self {
        let dx = params.dx;
        let cells: [usize; 3] =
            std::array::from_fn(|k| ((params.size[k] / dx).round() as usize).max(1));
        let lattice: [usize; 3] = std::array::from_fn(|k| 2 * cells[k]);
        let spacing: [f64; 3] = std::array::from_fn(|k| params.size[k] / lattice[k] as f64);
        let [lx, ly, t] = params.size;
        // Lateral node counts are odd and the grid is centred on the gel, so the discrete
        // problem is mirror symmetric in x and y; a node plane lies on the bonded face.
        let half_span = |l: f64| (0.5 * l / dx).ceil() as usize + PAD;
        let (hx, hy) = (half_span(lx), half_span(ly));
        let dims = [
            2 * hx + 1,
            2 * hy + 1,
            PAD_BOTTOM + (t / dx).ceil() as usize + PAD + 1,
        ];
        let origin = Vector3::new(
            -(hx as f64) * dx,
            -(hy as f64) * dx,
            -t - PAD_BOTTOM as f64 * dx,
        );
        Layout {
            dx,
            origin,
            dims,
            lattice,
            spacing,
        }
    }

    /// Undeformed position (cells) of lattice particle `(ix, iy, iz)`.
    fn rest_position(&self, size: &[f64; 3], ix: usize, iy: usize, iz: usize) -> Vector3<f32> {
        let [lx, ly, t] = *size;
        let p = Vector3::new(
            -0.5 * lx + (ix as f64 + 0.5) * self.spacing[0],
            -0.5 * ly + (iy as f64 + 0.5) * self.spacing[1],
            -t + (iz as f64 + 0.5) * self.spacing[2],
        );
        ((p - self.origin) / self.dx).cast::<f32>()
    }

    /// Half the vertical particle spacing (cells): from a top particle to the surface.
    fn half_top(&self) -> f32 {
        (0.5 * self.spacing[2] / self.dx) as f32
    }

    /// The undeformed particles at rest, x-major (`ix` outer, `iz` inner) so that memory
    /// order follows the x bins.
    fn rest_particles(&self, size: &[f64; 3]) -> Vec<Particle> {
        let [nxp, nyp, nzp] = self.lattice;
        let mut particles = Vec::with_capacity(nxp * nyp * nzp);
        for ix in 0..nxp {
            for iy in 0..nyp {
                for iz in 0..nzp {
                    particles.push(Particle::at_rest(self.rest_position(size, ix, iy, iz)));
                }
            }
        }
        particles
    }

    /// The top-surface slots (row-major `iy * nx + ix`): the index of each slot's
    /// particle in [`Layout::rest_particles`], and its undeformed surface point (cells).
    fn top_slots(&self, size: &[f64; 3]) -> (Vec<u32>, Vec<Vector3<f32>>) {
        let [nxp, nyp, nzp] = self.lattice;
        let lift = Vector3::new(0.0, 0.0, self.half_top());
        (0..nxp * nyp)
            .map(|slot| {
                let (ix, iy) = (slot % nxp, slot / nxp);
                let index = ((ix * nyp + iy) * nzp + nzp - 1) as u32;
                (index, self.rest_position(size, ix, iy, nzp - 1) + lift)
            })
            .unzip()
    }
}

/// The part of a particle's state that a solve starts from (its velocity and `C` are zero
/// then).
#[derive(Clone, Copy, Debug)]
struct Snapshot {
    x: Vector3<f32>,
    f: nalgebra::Matrix3<f32>,
    q: nalgebra::UnitQuaternion<f32>,
    jr: f32,
}

impl Snapshot {
    fn of(p: &Particle) -> Self {
        Self {
            x: p.x,
            f: p.f,
            q: p.q,
            jr: p.jr,
        }
    }

    fn is_finite(&self) -> bool {
        (self.x.sum() + self.f.sum() + self.jr + self.q.coords.sum()).is_finite()
    }
}

/// The threads a gel's parallel passes run on. Pools are shared, not owned: each OS
/// thread that solves gels keeps one rayon pool per thread count (thread-local), so a
/// process stepping many `MjData` from one thread holds one pool, not one per gel, and a
/// copy of a gel (`mj_copyData`) creates no thread. A one-thread pool is the calling
/// thread itself (rayon's `use_current_thread`): a single-threaded solve runs on the
/// caller, with no other OS thread. Results do not depend on the pool (fixed chunking).
#[derive(Clone, Copy, Debug)]
struct Pool {
    threads: usize,
}

thread_local! {
    /// This OS thread's pools, by thread count.
    static POOLS: std::cell::RefCell<Vec<(usize, std::rc::Rc<rayon::ThreadPool>)>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

impl Pool {
    /// A pool of `threads`, built now for the calling thread so that a refusal (the OS
    /// refusing a thread) is an error of the gel's construction.
    fn new(threads: usize) -> Result<Self, MpmError> {
        let pool = Self { threads };
        pool.get()?;
        Ok(pool)
    }

    /// The calling thread's pool of `self.threads`, built on first use.
    fn get(&self) -> Result<std::rc::Rc<rayon::ThreadPool>, MpmError> {
        POOLS.with(|pools| {
            if let Some((_, p)) = pools.borrow().iter().find(|(n, _)| *n == self.threads) {
                return Ok(p.clone());
            }
            let builder = || rayon::ThreadPoolBuilder::new().num_threads(self.threads);
            // The calling thread can be a worker of one such pool only (and not when it is
            // already a rayon worker): otherwise the pool gets its own thread.
            let pool = if self.threads == 1 {
                builder()
                    .use_current_thread()
                    .build()
                    .or_else(|_| builder().build())
            } else {
                builder().build()
            }
            .map_err(|e| MpmError::ThreadPool(e.to_string()))?;
            let pool = std::rc::Rc::new(pool);
            pools.borrow_mut().push((self.threads, pool.clone()));
            Ok(pool)
        })
    }

    /// Runs `f` in the calling thread's pool; directly when the caller is already a worker
    /// of a pool of this size (a pass nested in the solve), on the caller alone if no pool
    /// can be built.
    fn install<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        if rayon::current_thread_index().is_some() && rayon::current_num_threads() == self.threads {
            return f();
        }
        match self.get() {
            Ok(pool) => pool.install(f),
            Err(_) => f(),
        }
    }
}

/// The secant predictor's step: when every indenter moves on along the path of the last
/// solve (`last`, the same indenters' translations then), the multiple of the gel's last
/// change to move it on by (the projection of `motion` on `last`, at most 2); `None`
/// otherwise.
pub(crate) fn secant_scale(motion: &[Vector3<f64>], last: &[Vector3<f64>]) -> Option<f64> {
    if motion.len() != last.len() || motion.is_empty() {
        return None;
    }
    let along: f64 = motion.iter().zip(last).map(|(a, b)| a.dot(b)).sum();
    let before: f64 = last.iter().map(|b| b.norm_squared()).sum();
    (before > 0.0 && along > 0.0).then(|| (along / before).min(2.0))
}

/// A force and a torque (about a stated point), in one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Wrench {
    /// N.
    pub force: Vector3<f64>,
    /// N m.
    pub torque: Vector3<f64>,
}

/// The gel: particles, grid, workspaces and the state carried between solves.
#[derive(Clone)]
pub struct Gel {
    params: GelParams,
    options: SolverOptions,
    pool: Pool,
    layout: Layout,
    ctx: StepCtx,
    /// Internal moduli (units of `M`).
    mu: f32,
    lambda: f32,
    /// P-wave modulus `M = lambda + 2 mu` (Pa).
    modulus: f64,
    particles: Vec<Particle>,
    /// Elastic state at the start of the solve (velocities are zero then), for
    /// [`Gel::recover`]. The undeformed state is not stored: it follows from the lattice
    /// ([`Layout::rest_position`]).
    snapshot: Vec<Snapshot>,
    /// Stencil (base node, offsets) of each particle at its current position.
    stencils: Vec<Stencil>,
    /// Whether `order` / `offsets` still bin the particles by their current base x cell.
    binned: bool,
    /// Top-surface slot -> particle index; slots row-major `iy * nx_top + ix`.
    top: Vec<u32>,
    /// Reference surface point of each slot (cells).
    top_ref: Vec<Vector3<f32>>,
    /// Half the vertical particle spacing (cells): particle to surface.
    half_top: f32,
    /// Contact memory of each top slot (multiplier, stick anchor).
    contacts: Vec<SlotContact>,
    /// Contact force of each top slot in the current step.
    active: Vec<Option<ActiveContact>>,
    grid: Vec<Node>,
    order: Vec<u32>,
    offsets: Vec<u32>,
    cursor: Vec<u32>,
    layer_stats: Vec<LayerStats>,
    chunk_stats: Vec<ChunkStats>,
    step_ind: Vec<StepIndenter>,
    /// Shape and pose of each usable indenter of the previous solve, in the order that
    /// the contact state's indenter indices refer to.
    prev: Vec<(Arc<dyn Sdf>, Isometry3<f64>)>,
    /// The vectors of a solve's indenters, kept between solves.
    indenter_buffers: crate::scratch::Kept<indenters::Buffers>,
    force: Vector3<f64>,
    /// Displacement of the top surface per slot (m), after the last solve.
    surface_u: Vec<Vector3<f64>>,
    /// Lattice index range `[ix0, ix1) x [iy0, iy1)` where the surface moved.
    surface_box: Option<[usize; 4]>,
    /// The depth and shear images' buffers, kept between images.
    pixels: crate::scratch::Kept<surface::Pixels>,
    /// Whether the gel is undeformed and no indenter held a contact point of it in the
    /// last solve.
    resting: bool,
    /// Largest nodal reaction (internal units) at the end of the previous solve.
    last_reaction: f32,
    /// Largest nodal reaction of the last step.
    reaction: f32,
    /// Whether the last solve ended with `det F` at a clamp.
    clamped: bool,
    /// Lattice box of the top slots in contact at the end of the last solve.
    last_footprint: Option<[usize; 4]>,
    /// The last solve's contact loads, for [`Gel::contact_pressure`].
    loads: Vec<pressure::ContactLoad>,
    /// Whether the relaxation ran since its state was last put back to rest.
    relaxed: bool,
    /// The contact multipliers' gain in this relaxation, as a fraction of
    /// [`contact::multiplier_gain`]'s (see [`Gel::iterate`]).
    gain_scale: f32,
    /// The gel's equilibrium solver ([`SolverOptions::solver`]) and its state; `None`
    /// only while it solves a frame.
    solver: Option<Box<dyn Equilibrium>>,
    /// The solver of the frames the gel's own cannot carry ([`SolverOptions::fallback`],
    /// [`choice::frame_fallback`]) and its state, built at the first such frame.
    fallback: Option<Box<dyn Equilibrium>>,
}

impl std::fmt::Debug for Gel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Gel")
            .field("params", &self.params)
            .field("options", &self.options)
            .field("particles", &self.particles.len())
            .field("grid_dims", &self.layout.dims)
            .finish_non_exhaustive()
    }
}

const _: fn() = || {
    fn assert_send_sync<T: Send + Sync>() {}
    assert_send_sync::<Gel>();
};

impl Gel {
    /// Builds the undeformed gel after validating `params` and `options`.
    pub fn new(params: GelParams, options: SolverOptions) -> Result<Gel, MpmError> {
        Self::validate(&params, &options)?;
        let layout = Layout::new(&params);
        let pool = Pool::new(options.threads)?;
        let moduli = Moduli::of(&params);
        let ctx = step_context(&params, &options, &layout, moduli.mu);
        let particles = layout.rest_particles(&params.size);
        let (top, top_ref) = layout.top_slots(&params.size);
        let n = particles.len();
        let (dims, nxp) = (layout.dims, layout.lattice[0]);
        let top_len = top.len();
        let mut gel = Gel {
            params,
            options,
            pool,
            layout,
            ctx,
            mu: moduli.mu as f32,
            lambda: moduli.lambda as f32,
            modulus: moduli.modulus,
            snapshot: particles.iter().map(Snapshot::of).collect(),
            stencils: Vec::with_capacity(n),
            binned: false,
            particles,
            top,
            top_ref,
            half_top: layout.half_top(),
            contacts: vec![SlotContact::NONE; top_len],
            active: vec![None; top_len],
            grid: vec![Node::ZERO; dims.iter().product::<usize>()],
            order: Vec::with_capacity(n),
            offsets: Vec::with_capacity(dims[0] + 1),
            cursor: Vec::with_capacity(dims[0]),
            layer_stats: Vec::with_capacity(dims[0]),
            chunk_stats: Vec::with_capacity(nxp),
            step_ind: Vec::new(),
            prev: Vec::new(),
            indenter_buffers: Default::default(),
            force: Vector3::zeros(),
            surface_u: vec![Vector3::zeros(); top_len],
            surface_box: None,
            pixels: Default::default(),
            resting: true,
            last_reaction: 0.0,
            reaction: 0.0,
            clamped: false,
            last_footprint: None,
            relaxed: false,
            gain_scale: 1.0,
            loads: Vec::new(),
            solver: None,
            fallback: None,
        };
        let mut own = build_solver(gel.options.solver);
        let pool = gel.pool;
        pool.install(|| own.prepare(&gel));
        gel.solver = Some(own);
        Ok(gel)
    }

    /// Most steps per solve: [`SolverOptions::max_iterations`] scaled by the layer's
    /// thickness in cells over [`CAP_CELLS`] (at least 1).
    pub fn iteration_cap(&self) -> usize {
        let cells = self.params.size[2] / self.layout.dx;
        let scale = (cells / CAP_CELLS).max(1.0);
        ((self.options.max_iterations as f64 * scale).round() as usize).max(1)
    }

    /// Spacing (m) of the surface points that `solver`'s contact acts on in this gel: the
    /// top particles' for relaxation, for Newton a lattice four times finer, for the linear
    /// solver twice as fine. An indenter
    /// that reaches into the gel only between them loads it with no force.
    pub fn contact_spacing(&self, solver: Solver) -> f64 {
        let s = self.layout.spacing[0].max(self.layout.spacing[1]);
        match solver {
            Solver::Newton => s / newton::CONTACT_SUBDIVISION as f64,
            Solver::Linear => s / linear::SUBDIVISION as f64,
            Solver::Relaxation | Solver::Total => s,
        }
    }

    /// How deep (m, a lower bound) the indenters reach into the undeformed gel where the
    /// last solve found no contact force at all: 0 when the gel carries a force or when
    /// nothing reaches in. The undeformed top face is sampled at a quarter of
    /// [`Gel::contact_spacing`] of its solver (coarser over large footprints, at most
    /// [`MISSED_SAMPLES`] points per indenter); the signed distance there bounds the
    /// penetration from below. A contact smaller than the contact points' spacing can
    /// fall between them; the sensor warns with this.
    pub fn unloaded_penetration(&self, indenters: &[Placed]) -> f64 {
        if self.force != Vector3::zeros() {
            return 0.0;
        }
        self.reached_depth(indenters::usable(indenters))
    }

    /// How deep (m, a lower bound) `indenters` reach into the undeformed top face, sampled
    /// at a quarter of [`Gel::contact_spacing`] of the gel's solver (coarser over large
    /// footprints, at most [`MISSED_SAMPLES`] points per indenter); an indenter wholly
    /// below the face, as deep as its lower surface under the sample nearest to it; 0 if
    /// nowhere.
    pub(crate) fn reached_depth<'a>(&self, indenters: impl Iterator<Item = &'a Placed>) -> f64 {
        let [lx, ly, _] = self.params.size;
        let fine = 0.25 * self.contact_spacing(self.options.solver);
        let mut deepest = 0.0f64;
        for p in indenters {
            let b = p.aabb();
            if b.min.z.is_nan() || b.min.z >= 0.0 {
                continue;
            }
            let x0 = b.min.x.max(-0.5 * lx);
            let x1 = b.max.x.min(0.5 * lx);
            let y0 = b.min.y.max(-0.5 * ly);
            let y1 = b.max.y.min(0.5 * ly);
            if !(x1 >= x0 && y1 >= y0) {
                continue;
            }
            let area = (x1 - x0 + fine) * (y1 - y0 + fine);
            let pitch = fine.max((area / MISSED_SAMPLES as f64).sqrt());
            let nx = ((x1 - x0) / pitch).floor() as usize + 1;
            let ny = ((y1 - y0) / pitch).floor() as usize + 1;
            let inverse = p.pose.inverse();
            let distance = |x: f64, y: f64| {
                let x = x.clamp(-0.5 * lx, 0.5 * lx);
                let y = y.clamp(-0.5 * ly, 0.5 * ly);
                p.shape.distance(&(inverse * Point3::new(x, y, 0.0)))
            };
            // The sample nearest to reaching in.
            let mut best = (f64::INFINITY, 0.0, 0.0);
            for j in 0..ny {
                for i in 0..nx {
                    let x = x0 + (i as f64 + 0.5) * (x1 - x0) / nx as f64;
                    let y = y0 + (j as f64 + 0.5) * (y1 - y0) / ny as f64;
                    let d = distance(x, y);
                    if d < best.0 {
                        best = (d, x, y);
                    }
                }
            }
            // A tip narrower than the sampling reaches in between the samples, or deeper
            // than the deepest of them: a compass search from that sample down to a
            // sixty-fourth of their pitch finds it (where the sample lies within a pitch
            // of the indenter).
            if best.0 < pitch {
                let mut step = 0.5 * pitch;
                for _ in 0..COMPASS_MOVES {
                    if step <= pitch / 64.0 {
                        break;
                    }
                    let (_, x, y) = best;
                    let moves = [(step, 0.0), (-step, 0.0), (0.0, step), (0.0, -step)];
                    let mut moved = false;
                    for (u, v) in moves {
                        let d = distance(x + u, y + v);
                        if d < best.0 {
                            (best, moved) = ((d, x + u, y + v), true);
                        }
                    }
                    if !moved {
                        step *= 0.5;
                    }
                }
            }
            let under_the_face = b.min.x > -0.5 * lx
                && b.max.x < 0.5 * lx
                && b.min.y > -0.5 * ly
                && b.max.y < 0.5 * ly;
            if best.0 > 0.0 && best.0.is_finite() && under_the_face {
                // Outside at the face everywhere sampled: a body wholly below it (swept in
                // through it) lies under the nearest sample. Marched down to it and
                // through it, it reaches as deep as its lower surface there. (One beside
                // the gel, pressing its side, is the relaxation's.)
                let (_, x, y) = best;
                let at = |z: f64| p.shape.distance(&(inverse * Point3::new(x, y, -z)));
                let (mut z, mut d, mut entered) = (0.0, best.0, false);
                let (step, limit) = (fine / 16.0, self.params.size[2]);
                while d >= 0.0 && z <= limit {
                    z += d.max(step);
                    d = at(z);
                }
                while d < 0.0 && z <= limit {
                    entered = true;
                    z += (-d).max(step);
                    d = at(z);
                }
                if entered && d >= 0.0 && z <= limit {
                    deepest = deepest.max(z);
                }
            } else if best.0.is_finite() {
                deepest = deepest.max(-best.0);
            }
        }
        deepest
    }

    /// The top surface's rest points (the relaxation's contact points at rest) inside
    /// `indenters`, counted up to one more than `limit`: the rigid footprint in the
    /// relaxation's own points, a function of the poses alone.
    fn footprint_points(&self, indenters: &[Placed], limit: usize) -> usize {
        let (dx, origin) = (self.layout.dx, self.layout.origin);
        let mut count = 0;
        for p in indenters::usable(indenters) {
            let b = p.aabb();
            let inverse = p.pose.inverse();
            for r in &self.top_ref {
                let x = origin + r.cast::<f64>() * dx;
                let within =
                    (b.min.x..=b.max.x).contains(&x.x) && (b.min.y..=b.max.y).contains(&x.y);
                if within && p.shape.distance(&(inverse * Point3::from(x))) < 0.0 {
                    count += 1;
                    if count > limit {
                        return count;
                    }
                }
            }
        }
        count
    }

    /// The parameters the gel was built with.
    pub fn params(&self) -> &GelParams {
        &self.params
    }

    /// The solver options.
    pub fn options(&self) -> &SolverOptions {
        &self.options
    }

    /// Grid nodes per axis.
    pub fn grid_dims(&self) -> [usize; 3] {
        self.layout.dims
    }

    /// Particles per axis `[nx, ny, nz]`; their spacing is `size / lattice`.
    pub fn lattice(&self) -> [usize; 3] {
        self.layout.lattice
    }

    /// Back to the undeformed gel at rest, forgetting the previous indenter poses.
    pub fn reset(&mut self) {
        self.relaxed = true;
        self.rest_relaxation();
        self.prev.clear();
        self.force = Vector3::zeros();
        self.surface_u
            .iter_mut()
            .for_each(|u| *u = Vector3::zeros());
        self.surface_box = None;
        self.resting = true;
        self.loads.clear();
        if let Some(s) = self.solver.as_mut() {
            s.reset();
        }
        if let Some(f) = self.fallback.as_mut() {
            f.reset();
        }
    }

    /// The relaxation's own state back to the undeformed gel at rest (its particles, stick
    /// contacts, reaction scale, footprint and the solver's memory), where a solve since
    /// the last such reset moved it.
    fn rest_relaxation(&mut self) {
        if !std::mem::take(&mut self.relaxed) {
            return;
        }
        self.restore_rest();
        self.last_reaction = 0.0;
        self.clamped = false;
        self.last_footprint = None;
        self.contacts.fill(SlotContact::NONE);
        if let Some(s) = self.solver.as_mut().filter(|s| s.kind().relaxes()) {
            s.reset();
        }
    }

    /// Number of particles.
    pub fn num_particles(&self) -> usize {
        self.particles.len()
    }

    /// Total force of the gel on the indenters (sensor frame, N): the sum of the contact
    /// impulses of the last step of the last solve, divided by its time step.
    pub fn force(&self) -> Vector3<f64> {
        self.force
    }

    /// How deep (m) below the undeformed face the last solve's most deeply pressed contact
    /// point lies (0 where no point is loaded, or where the solver keeps no contact loads).
    pub fn deepest_load(&self) -> f64 {
        self.loads
            .iter()
            .filter(|l| l.force.z != 0.0)
            .fold(0.0, |m, l| m.max(-l.z))
    }

    /// The force and torque (about the sensor origin) of the gel on each of `indenters`
    /// (sensor frame; N and N m), from the last solve's contact loads: each load goes to
    /// the indenter nearest to the point where it acts. Their sum is [`Gel::force`] for
    /// the indenters that the last solve saw.
    pub fn wrenches(&self, indenters: &[Placed]) -> Vec<Wrench> {
        self.wrenches_and_spreads(indenters).0
    }

    /// [`Gel::wrenches`], and how far each of `indenters`' contact spreads about its centre
    /// of pressure: the in-plane second moment of the last solve's normal loads on it about
    /// their centre, over their sum (m^2; zero without a normal force). A contact's
    /// stiffness against a turn about the gel's normal is about its tangential stiffness
    /// times its spread (a flat round punch's: 1.5 times it on a half-space and on a thin
    /// incompressible layer), and against a tilt about an axis in the plane its normal
    /// stiffness times the part of the spread across the axis (half of it for a round
    /// punch: its stiffness exactly on a half-space, twice it on a thin incompressible
    /// layer).
    pub fn wrenches_and_spreads(&self, indenters: &[Placed]) -> (Vec<Wrench>, Vec<f64>) {
        let mut wrenches = vec![Wrench::default(); indenters.len()];
        // Per indenter: the normal loads' sum, their first and second moments in the plane.
        let mut sums = vec![(0.0, Vector2::zeros(), 0.0); indenters.len()];
        for (k, load) in self.loads_by_indenter(indenters) {
            let p = Vector3::new(load.at[0], load.at[1], load.z);
            wrenches[k].force += load.force;
            wrenches[k].torque += p.cross(&load.force);
            let (f, at) = (load.force.z, p.xy());
            if f > 0.0 {
                sums[k].0 += f;
                sums[k].1 += f * at;
                sums[k].2 += f * at.norm_squared();
            }
        }
        let spreads = sums
            .into_iter()
            .map(|(f, first, second)| {
                if f > 0.0 {
                    (second / f - (first / f).norm_squared()).max(0.0)
                } else {
                    0.0
                }
            })
            .collect();
        (wrenches, spreads)
    }

    /// The last solve's contact loads, each with the index of the indenter among
    /// `indenters` nearest to the point where it acts.
    fn loads_by_indenter<'a>(
        &'a self,
        indenters: &'a [Placed],
    ) -> impl Iterator<Item = (usize, &'a pressure::ContactLoad)> + 'a {
        let loads = if indenters.is_empty() {
            &[][..]
        } else {
            &self.loads[..]
        };
        loads.iter().map(move |load| {
            if indenters.len() == 1 {
                return (0, load);
            }
            let p = Point3::new(load.at[0], load.at[1], load.z);
            let mut best = (f64::INFINITY, 0);
            for (i, ind) in indenters.iter().enumerate() {
                let d = ind.shape.distance(&ind.pose.inverse_transform_point(&p));
                if d < best.0 {
                    best = (d, i);
                }
            }
            (best.1, load)
        })
    }

    /// Bytes held per particle (state, snapshot of the elastic state, stencil, sort
    /// index), not counting the grid.
    pub fn bytes_per_particle() -> usize {
        std::mem::size_of::<Particle>()
            + std::mem::size_of::<Snapshot>()
            + std::mem::size_of::<Stencil>()
            + std::mem::size_of::<u32>()
    }

    /// Puts every particle back at its undeformed lattice position, at rest.
    fn restore_rest(&mut self) {
        let [_, nyp, nzp] = self.layout.lattice;
        for (i, p) in self.particles.iter_mut().enumerate() {
            let (ix, iy, iz) = (i / (nyp * nzp), i / nzp % nyp, i % nzp);
            *p = Particle::at_rest(self.layout.rest_position(&self.params.size, ix, iy, iz));
        }
    }

    /// Bytes held by the grid.
    pub fn grid_bytes(&self) -> usize {
        self.grid.len() * std::mem::size_of::<Node>()
            + self.contacts.len() * std::mem::size_of::<SlotContact>()
            + self.active.len() * std::mem::size_of::<Option<ActiveContact>>()
    }

    /// Brings the gel to static equilibrium under `indenters` (sensor frame), starting from
    /// the previous equilibrium. See `relax.rs` for the method and the convergence test.
    /// Indenters with a non-finite pose are skipped.
    pub fn solve(&mut self, indenters: &[Placed]) -> SolveReport {
        // Every parallel pass of the solve runs in the calling thread's pool (for one
        // thread: on the caller itself), never in rayon's global pool, whose threads a
        // forked process does not have.
        let pool = self.pool;
        pool.install(|| self.solve_in_pool(indenters))
    }

    fn solve_in_pool(&mut self, indenters: &[Placed]) -> SolveReport {
        // The frame's vectors, their allocations kept from the frame before.
        let mut kept = std::mem::take(self.indenter_buffers.get_mut());
        let mut used: Vec<&Placed> = recycled(std::mem::take(&mut kept.used));
        used.extend(indenters::usable(indenters));
        let (report, used, starts) = self.solve_used(indenters, used, &mut kept);
        kept.used = recycled(used);
        kept.starts = starts;
        kept.current.clear();
        *self.indenter_buffers.get_mut() = kept;
        report
    }

    /// [`Gel::solve_in_pool`] for the usable indenters `used`, which it gives back with the
    /// sweep's starts (their allocations kept, as `kept`'s).
    fn solve_used<'a>(
        &mut self,
        indenters: &[Placed],
        used: Vec<&'a Placed>,
        kept: &mut indenters::Buffers,
    ) -> (SolveReport, Vec<&'a Placed>, Vec<Isometry3<f64>>) {
        let touching = used.iter().any(|p| self.reaches(p));
        let mut report = SolveReport::new(used.len());
        let repaired = self.restart_if_needed(&mut report);
        // Identity: which previous indenter each one is (same shape, nearest pose).
        match_indenters(&self.prev, &used, kept);
        let matched = &kept.matched;
        self.remap_contacts(matched, &mut kept.index);
        kept.current.clear();
        kept.current
            .extend(used.iter().map(|p| (p.shape.clone(), p.pose)));
        let starts = std::mem::take(&mut kept.starts);
        if !touching && self.resting {
            std::mem::swap(&mut self.prev, &mut kept.current);
            self.force = Vector3::zeros();
            self.loads.clear();
            return (report, used, starts);
        }
        let footprint = if touching {
            self.footprint_points(indenters, UNRESOLVED_POINTS)
        } else {
            0
        };
        let fallback = if self.options.fallback {
            let spacing = self.contact_spacing(Solver::Relaxation);
            let reached = || self.reached_depth(indenters::usable(indenters));
            choice::frame_fallback(&self.params, touching, footprint, reached, spacing)
        } else {
            None
        };
        let mut solver = match fallback {
            Some(kind) => {
                // The relaxation's surface points cannot carry this contact (`choice`). The
                // fallback's state carries on from its own last fallback frame; the
                // relaxation's goes back to rest, to start afresh from the frame it carries
                // again.
                self.rest_relaxation();
                report.fallback = true;
                match self.fallback.take() {
                    Some(s) if s.kind() == kind => s,
                    _ => build_solver(kind),
                }
            }
            None => self
                .solver
                .take()
                .expect("the gel's solver is in place between frames"),
        };
        let relaxes = solver.kind().relaxes();
        if relaxes && footprint == 0 {
            // No contact point of the undeformed gel lies inside an indenter: the
            // undeformed gel is at equilibrium (no stress, no contact force), and without
            // friction it is the only equilibrium (the least energy, zero, among the
            // states that do not penetrate); friction holds nothing where no normal force
            // acts. Relaxing towards it from the last frame's
            // deformation took steps for nothing, and a lift-off to a pose that leaves
            // the gel almost free could run to the iteration cap: its residual is measured
            // against the vanishing load.
            self.solver = Some(solver);
            if !self.resting {
                self.reset();
            }
            std::mem::swap(&mut self.prev, &mut kept.current);
            return (report, used, starts);
        }
        let sweep = if !relaxes || self.relaxed {
            self.plan_sweep(used, matched, starts)
        } else {
            // The relaxation's state is the gel at rest (a fresh gel, or one whose last
            // frames the fallback carried): its indenters come in from above the gel, as
            // into a fresh gel, not from poses it never saw. (Swept from the fallback's
            // last poses, a capsule 1.3 mm deep slid 0.65 mm started 1.3 mm inside the
            // undeformed gel and stopped at the iteration cap with no vertical force.)
            refill(&mut kept.none, matched.len(), None);
            self.plan_sweep(used, &kept.none, starts)
        };
        let frame = solver::Frame {
            indenters,
            sweep: &sweep,
            matched,
        };
        solver.solve(self, &frame, &mut report);
        // A solve that ended with a non-finite value kept no poses; one that began with a
        // non-finite particle says so after the poses are kept.
        if report.nonfinite_recovered {
            self.prev.clear();
        } else {
            std::mem::swap(&mut self.prev, &mut kept.current);
        }
        report.nonfinite_recovered |= repaired;
        self.resting = !touching && self.surface_box.is_none();
        if report.fallback {
            self.fallback = Some(solver);
        } else {
            self.solver = Some(solver);
            if self.options.fallback {
                // The gel's own solver carries this frame: a later fallback starts afresh.
                if let Some(f) = self.fallback.as_mut() {
                    f.reset();
                }
            }
        }
        (report, sweep.indenters, sweep.starts)
    }

    /// Starts from the undeformed gel ([`SolveReport::restarted`]) when the last solve
    /// crushed or stretched some particles to the `det F` clamp, where the elastic memory
    /// is lost, or when a particle is not finite. Returns whether one was not finite.
    fn restart_if_needed(&mut self, report: &mut SolveReport) -> bool {
        // A solve moves only its active region, so a particle outside it that went
        // non-finite (from outside the solver) would never be seen: check them all. Only
        // a relaxation moves them (and only its state carries them): under the other
        // solvers they stay at rest, and a frame does not stream them all.
        let relaxes =
            |s: &Option<Box<dyn Equilibrium>>| s.as_ref().is_some_and(|s| s.kind().relaxes());
        let moved = self.solver.is_none() || relaxes(&self.solver) || relaxes(&self.fallback);
        let repaired = moved && !self.particles.iter().all(Particle::is_finite);
        if self.clamped || repaired {
            self.reset();
            report.restarted = true;
        }
        repaired
    }

    /// The start of a relaxation's frame: the region it moves, and that the particles
    /// leave their rest.
    fn begin_relaxation(&mut self, sweep: &Sweep, report: &mut SolveReport) {
        report.sweep_steps = sweep.steps;
        self.ctx.region = self.active_region(sweep);
        report.active_particles = self.ctx.region.particles(self.ctx.column_len);
        self.relaxed = true;
    }

    /// The bookkeeping after a relaxation: what the next solve starts from (the reaction
    /// scale, the contact footprint, whether the gel ended at a clamp), the loads, the
    /// force and the surface displacement.
    fn finish_relaxation(&mut self, report: &mut SolveReport) {
        if report.nonfinite_recovered {
            let (lo, hi) = self.det_range();
            report.det_f_min = lo;
            report.det_f_max = hi;
            self.force = Vector3::zeros();
            self.last_reaction = 0.0;
            self.loads.clear();
        } else {
            self.last_reaction = self.reaction;
            self.record_loads();
        }
        self.update_surface();
        self.last_footprint = self.footprint();
        self.clamped = report.det_f_min <= J_MIN * 1.01 || report.det_f_max >= J_MAX * 0.99;
    }

    /// The contact loads of the relaxation's last step (the ones [`Gel::force`] sums).
    fn record_loads(&mut self) {
        let (dx, origin) = (self.layout.dx, self.layout.origin);
        let scale = self.modulus * dx * dx;
        self.loads.clear();
        for a in self.active.iter().flatten() {
            let x = (self.particles[a.particle as usize].x + a.d).cast::<f64>() * dx + origin;
            self.loads.push(pressure::ContactLoad {
                at: [x.x, x.y],
                z: x.z,
                force: -a.f.cast::<f64>() * scale,
            });
        }
    }

    /// Indentation of the deformed top surface at each pixel of `grid` (m, positive into
    /// the gel, clamped to `[0, T]`), row-major into `out` (`grid.height * grid.width`
    /// values; see [`PixelGrid`] for the orientation). See `surface.rs` for the method.
    ///
    /// # Panics
    /// If `out` is shorter than `grid.width * grid.height`.
    pub fn surface_depth(&self, grid: &PixelGrid, out: &mut [f64]) {
        surface::surface_depth(self, grid, out);
    }

    /// [`Gel::surface_depth`] at the pixels of `parts` only (a pixel in two parts is
    /// mapped twice, to the same value); the others are zero.
    ///
    /// # Panics
    /// If `out` is shorter than `grid.width * grid.height`.
    pub fn surface_depth_parts(&self, grid: &PixelGrid, parts: &[Part], out: &mut [f64]) {
        surface::surface_depth_parts(self, grid, parts, out);
    }

    /// In-plane displacement of the surface point seen at each pixel of `grid` (m, sensor
    /// frame x then y, zero where the gel is undeformed), the same inverse map as
    /// [`Gel::surface_depth`]: `H x W x 2` values, row-major, into `out`.
    ///
    /// # Panics
    /// If `out` is shorter than `2 * grid.width * grid.height`.
    pub fn surface_shear(&self, grid: &PixelGrid, out: &mut [f64]) {
        surface::surface_shear(self, grid, out);
    }

    /// [`Gel::surface_depth`] and [`Gel::surface_shear`] from one inverse map, at the cost
    /// of one.
    ///
    /// # Panics
    /// If `depth` or `shear` is too short for the grid.
    pub fn surface_depth_and_shear(&self, grid: &PixelGrid, depth: &mut [f64], shear: &mut [f64]) {
        surface::surface_depth_and_shear(self, grid, depth, shear);
    }

    /// Displacement `u(X)` (m, sensor frame) of the top-surface point whose undeformed
    /// position is `X = (x, y, 0)`, after the last solve: where a mark printed there now
    /// is, `X + u(X)`. Zero for an undeformed gel; clamped to the lattice's edge outside it.
    pub fn surface_displacement(&self, x: f64, y: f64) -> Vector3<f64> {
        surface::surface_displacement(self, x, y)
    }
}

/// The gel's moduli: Lame parameters in internal units (divided by `M`) and the P-wave
/// modulus `M = lambda + 2 mu` (Pa).
struct Moduli {
    mu: f64,
    lambda: f64,
    modulus: f64,
}

impl Moduli {
    fn of(params: &GelParams) -> Self {
        let (e, nu) = (params.young, params.poisson);
        let mu_si = e / (2.0 * (1.0 + nu));
        let lambda_si = e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
        let modulus = lambda_si + 2.0 * mu_si;
        Self {
            mu: mu_si / modulus,
            lambda: lambda_si / modulus,
            modulus,
        }
    }
}

/// The fixed quantities of every step (see the module docs, "Internal units and mass
/// scaling", and `relax.rs` for the damping); `mu` in internal units. The region is the whole
/// gel until a solve sets it.
impl Gel {
    /// The gel's own solver, where it is a `T`.
    fn own_solver<T: Equilibrium + 'static>(&self) -> Option<&T> {
        self.solver.as_ref()?.as_any().downcast_ref::<T>()
    }

    /// The gel's own solver, where it is a `T`.
    #[cfg(test)]
    fn own_solver_mut<T: Equilibrium + 'static>(&mut self) -> Option<&mut T> {
        self.solver.as_mut()?.as_any_mut().downcast_mut::<T>()
    }
}

/// The solver `kind`, with no frame solved and nothing built yet ([`Equilibrium::prepare`]
/// builds what it can before the first frame). Which kind a gel gets is `choice.rs`'s.
fn build_solver(kind: Solver) -> Box<dyn Equilibrium> {
    match kind {
        Solver::Relaxation => Box::new(relax::Relaxation::default()),
        Solver::Total => Box::new(total::TotalRelaxation::default()),
        Solver::Newton => Box::new(newton::NewtonSolver::default()),
        Solver::Linear => Box::new(linear::LinearSolver::default()),
    }
}

fn step_context(params: &GelParams, options: &SolverOptions, layout: &Layout, mu: f64) -> StepCtx {
    let dx = layout.dx;
    // Mass scaling: rho' = 1 / cfl^2, so c_p = cfl cells per step.
    let rho = 1.0 / (options.cfl * options.cfl);
    let pvol = layout.spacing.iter().map(|s| s / dx).product::<f64>();
    let pmass = rho * pvol;
    // Lowest mode of the bonded layer: thickness-shear quarter wave.
    let c_s = options.cfl * mu.sqrt();
    let omega1 = 0.5 * std::f64::consts::PI * c_s / (params.size[2] / dx);
    let damping = 2.0 * options.damping * omega1;
    let [_, nyp, nzp] = layout.lattice;
    StepCtx {
        dims: layout.dims,
        iz_bottom: PAD_BOTTOM,
        pmass: pmass as f32,
        pvol: pvol as f32,
        damping: damping as f32,
        fbar: options.fbar && params.poisson >= FBAR_POISSON,
        rot_iters: if params.material.uses_rotation() {
            ROT_ITERS
        } else {
            0
        },
        row_len: nyp * nzp,
        column_len: nzp,
        region: Region::whole(layout.lattice, layout.dims),
    }
}
