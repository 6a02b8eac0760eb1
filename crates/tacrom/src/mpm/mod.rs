//! The elastomer as a quasi-static MLS-MPM simulation.
//!
//! [`Gel`] holds a block of silicone, bonded to the sensor at its bottom face, discretised
//! by the moving least squares material point method (MLS-MPM, Hu et al. 2018) with APIC
//! transfers (Jiang et al. 2015) and quadratic B-spline weights. [`Gel::solve`] brings it
//! to static equilibrium under rigid indenters given as signed distance fields;
//! [`Gel::surface_depth`] samples the indentation of its top face on a pixel grid and
//! [`Gel::force`] returns the total contact force.
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
//! order one; f64 measured no more accurate at the solver tolerance and half as fast).
//! The density is a free parameter at equilibrium, so it is chosen (mass scaling) to make
//! the P-wave speed `c_p = sqrt(M / rho)` exactly `cfl` cells per step: `rho' = 1 / cfl^2`.
//! The CFL condition `c_p dt <= cfl dx` then holds by construction and the number of steps
//! depends only on the geometry in cells, Poisson's ratio and the tolerance, not on `E` or
//! the real density. Forces convert back as `F = F' M dx^2`.
//!
//! # Quasi-static solve
//!
//! Dynamic relaxation: explicit steps with mass-proportional damping `v <- v / (1 + c)`,
//! `c = 2 zeta omega_1`, tuned to the lowest mode of the bonded layer, the thickness-shear
//! quarter wave `omega_1 = (pi / 2) c_s / T` (`zeta` = [`SolverOptions::damping`], 1 for
//! critical). Every mode then decays at least like `exp(-omega_1 t)`. Each solve starts
//! from the previous equilibrium (warm start) with zero velocity. It stops when the
//! largest out-of-balance nodal force (stress plus contact force left after the
//! constraints, plus the damping force) divided by the force scale is below
//! [`SolverOptions::tolerance`], or after [`Gel::iteration_cap`] steps. The
//! force scale is the largest nodal reaction (bonded nodes, contact load) of this step or of
//! the previous equilibrium (so that unloading is measured against the load it releases),
//! and at least `1e-4 mu dx^2` (a strain of `1e-4`).
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
//! # Indenters and sliding
//!
//! Each indenter is a rigid signed distance field. Contact acts on the surface point of
//! each top particle (`x_p + (s_z / 2) F e_z`, the point the depth image shows), with an
//! augmented Lagrangian normal force and a Coulomb-capped stick spring (see
//! [`contact`]); the contact forces enter the grid as nodal forces, so the force on the
//! indenters is their sum, exact at equilibrium. (An earlier velocity constraint on every
//! grid node within 1.5 cells below the surface acted as a rigid slab and gave forces
//! 12-18 % above Hertz that did not converge under refinement.) Indenters are matched to
//! those of the previous call by identity: the same shape (`Arc::ptr_eq` of
//! [`Placed::shape`]), and among several sharing one shape, the nearest previous pose; an
//! indenter without a match is new, and the contact state (multipliers, stick anchors) of
//! a previous indenter without a successor is released. During the first steps of
//! a solve, each indenter moves from its previous pose to the current one (linear in
//! translation, slerp in rotation) at most [`SolverOptions::sweep_rate`] cells per step;
//! a new indenter starts lifted just clear of the surface. Stick anchors are fixed in the
//! indenter's frame and persist between solves, so friction drags the surface along while
//! the indenter slides and holds it afterwards: the shear history of a sliding contact is
//! kept.
//!
//! The convergence test's force scale also counts the mean contact force per cell of
//! contact area (mean pressure times `dx^2`), and its residual the constraint error
//! `k |g|` of every loaded surface point.
//!
//! # Active region
//!
//! A contact deforms a bonded layer only near itself: the surface settles within about
//! one thickness of the contact edge. A solve therefore moves only the particles of a
//! lattice box, the contact footprint (top-surface points within half a cell of an
//! indenter at its start or end pose, with contact state, or in contact at the end of the
//! last solve) grown by [`SolverOptions::active_margin`] thicknesses (1.5 by default) on
//! every side and widened to every point indented by more than 1 % of the largest
//! indentation (so that where an indenter was, the gel relaxes). The rest of the gel
//! keeps its state and is not scattered; the grid nodes that have one of its particles
//! in their support are held fixed, a rigid wall around the active box. A solve with no
//! indenter near the gel (unloading) moves the whole gel. Measured on the coarse grid
//! (`tests.rs`): images within 0.6 % of the peak depth and forces within 0.8 % of the
//! whole gel's, with 45 % of the particles; at dx = 0.7 mm, 35 % of the particles and
//! Hertz force errors 0.3 to 0.9 points higher. `f64::INFINITY` solves the whole gel
//! every time.
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

/// The quasi-static solver's name, recorded in a reduced-order model's recipe: a model
/// trained on one solver's coarse solutions refuses another's.
pub const SOLVER: &str = "relaxation";

mod contact;
pub mod hertz;
mod material;
mod surface;
mod transfer;

#[cfg(test)]
mod tests;

use nalgebra::{Isometry3, Point3, Vector3};

use std::sync::Arc;

use crate::geometry::{Aabb, PixelGrid, Placed, Sdf};

use contact::{ActiveContact, ContactInput, SlotContact, StepIndenter};
pub use material::{extract_rotation, ConstitutiveModel, FixedCorotatedModel, NeoHookeanModel};
use transfer::{ChunkStats, LayerStats, Node, P2gInput, Particle, Region, Stencil, StepCtx};

/// Rotation-extraction steps per time step (fixed corotated), warm-started.
const ROT_ITERS: usize = 1;

/// Smallest `det F` a particle may reach; below it (inverted included) `F` is repaired
/// through its SVD.
pub const J_MIN: f64 = 0.2;
/// Largest `det F` a particle may reach; above it `F` is repaired through its SVD.
pub const J_MAX: f64 = 5.0;

/// Smallest Poisson's ratio at which [`SolverOptions::fbar`] applies: below it there is
/// no locking to cure, and the one-step-behind smoothing of `J` over the 27-node stencil
/// only softens a contact narrower than a few cells (measured: -14 % force, 18x more
/// iterations, R = 5 mm sphere at d = 0.2 mm, dx = 1.4 mm, Poisson 0.43).
pub const FBAR_POISSON: f64 = 0.45;

/// Default [`SolverOptions::active_margin`] (gel thicknesses). The surface of a bonded
/// layer settles within about one thickness of a contact (measured at dx = 0.7 mm, a
/// 0.5 mm sphere press: 29 um of indentation 2 mm beyond the contact edge, 1.2 um at
/// 3 mm, none beyond), so the rigid wall 1.5 thicknesses out changes little; see
/// `tacrom mpm` for the measured effect on force and cost.
pub const ACTIVE_MARGIN: f64 = 1.5;

/// Fraction of the largest surface indentation (vertical displacement, up or down) above
/// which a slot counts as deformed: the active region always covers the deformed slots,
/// so that where an indenter was, the gel relaxes.
const DEFORMED: f64 = 1e-2;

/// Layer thickness (cells) above which the iteration cap grows in proportion to it.
///
/// Both rates that bound the solve fall as one over the cells through the layer: the
/// slowest elastic mode (`omega_1`, see the module docs) and the contact multipliers'
/// gain ([`contact::multiplier_gain`]). A fixed cap that the coarse grid (2.9 cells) never
/// reaches then cuts off the fine grid (13 cells) before it converges: measured at
/// dx = 0.3 mm, a cold press to 0.4 mm took 2216 steps and the next, to 0.5 mm, was
/// still converging at 3000.
pub const CAP_CELLS: f64 = 3.2;

/// Grid nodes added around the gel on each lateral side and above it (cells).
const PAD: usize = 3;
/// Grid nodes below the bonded face (cells); all of them are fixed.
const PAD_BOTTOM: usize = 2;
/// Largest number of particles accepted (memory guard, about 0.3 GB).
const MAX_PARTICLES: usize = 1 << 30 >> 2;
/// Surface displacements below this (m) count as "no deformation" for [`Gel::surface_depth`].
const DEPTH_EPS: f64 = 1e-9;

/// Elastic energy of the gel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Material {
    /// Fixed corotated (Stomakhin et al. 2012); the usual MPM choice for soft solids.
    #[default]
    FixedCorotated,
    /// Compressible Neo-Hookean, with `det F` guarded (see [`NeoHookeanModel`]).
    NeoHookean,
}

/// Physical description of the gel, SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GelParams {
    /// Size `[Lx, Ly, T]` (m).
    pub size: [f64; 3],
    /// Young's modulus (Pa).
    pub young: f64,
    /// Poisson's ratio, in `(-1, 0.5)`.
    pub poisson: f64,
    /// Density (kg/m^3). Validated but irrelevant to the equilibrium (mass scaling).
    pub density: f64,
    /// Coulomb friction coefficient between the gel and the indenters.
    pub friction: f64,
    /// Grid spacing (m); two particles per axis per cell.
    pub dx: f64,
    /// Elastic energy.
    pub material: Material,
}

impl Default for GelParams {
    /// The GelSight Mini-like gel: 30 x 30 x 4 mm, E = 1.19e5 Pa, Poisson 0.43,
    /// 1050 kg/m^3, friction 0.5, coarse grid dx = 1.4 mm (about 1e4 particles).
    fn default() -> Self {
        Self {
            size: [0.03, 0.03, 0.004],
            young: 1.19e5,
            poisson: 0.43,
            density: 1050.0,
            friction: 0.5,
            dx: 1.4e-3,
            material: Material::FixedCorotated,
        }
    }
}

/// Numerical settings of the quasi-static solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolverOptions {
    /// Convergence threshold on the relative out-of-balance force (see the module docs).
    pub tolerance: f64,
    /// Most steps per solve on a layer up to [`CAP_CELLS`] cells thick; a thicker layer
    /// gets proportionally more ([`Gel::iteration_cap`]).
    pub max_iterations: usize,
    /// Threads of the gel's own pool; results do not depend on it.
    pub threads: usize,
    /// Courant number `c_p dt / dx`, in `(0, 1)`.
    pub cfl: f64,
    /// Damping ratio relative to critical damping of the layer's lowest mode.
    pub damping: f64,
    /// Largest indenter motion per step while it moves from its previous pose (cells).
    pub sweep_rate: f64,
    /// F-bar volume smoothing against volumetric locking, for Poisson's ratios of at
    /// least [`FBAR_POISSON`].
    pub fbar: bool,
    /// Lateral margin, in gel thicknesses, around the contact footprint within which a
    /// solve moves the gel ([`Gel::solve`], "Active region"); `f64::INFINITY`: always
    /// the whole gel.
    pub active_margin: f64,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            tolerance: 1e-3,
            max_iterations: 3000,
            threads: 1,
            cfl: 0.5,
            damping: 1.0,
            sweep_rate: 0.1,
            fbar: true,
            active_margin: ACTIVE_MARGIN,
        }
    }
}

/// Errors of [`Gel::new`].
#[derive(Debug, thiserror::Error)]
pub enum MpmError {
    /// A parameter is out of its range.
    #[error("invalid gel parameter `{name}` = {value}: {reason}")]
    InvalidParameter {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What is required.
        reason: &'static str,
    },
    /// The thread pool could not be built.
    #[error("cannot build the MPM thread pool: {0}")]
    ThreadPool(String),
}

/// What one [`Gel::solve`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveReport {
    /// Steps taken.
    pub iterations: usize,
    /// Whether the residual fell below the tolerance (after the indenters finished moving).
    pub converged: bool,
    /// Relative out-of-balance force after the last step.
    pub residual: f64,
    /// Smallest `det F` over the particles after the last step.
    pub det_f_min: f64,
    /// Largest `det F` over the particles after the last step.
    pub det_f_max: f64,
    /// Whether non-finite values appeared and the gel was restored.
    pub nonfinite_recovered: bool,
    /// Steps spent moving the indenters from their previous poses.
    pub sweep_steps: usize,
    /// Number of indenters used (finite poses).
    pub indenters: usize,
    /// Whether the solve started from the undeformed gel because the previous one ended
    /// with `det F` at a clamp (the elastic state is then no longer trustworthy).
    pub restarted: bool,
    /// Particles the solve moved (the active region; the rest kept their state).
    pub active_particles: usize,
}

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

/// The gel's own worker threads. Cloning a gel (for `mj_copyData`) gives the copy a pool
/// of its own with the same number of threads.
struct Pool {
    pool: rayon::ThreadPool,
    threads: usize,
}

impl Pool {
    fn new(threads: usize) -> Result<Self, MpmError> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .map_err(|e| MpmError::ThreadPool(e.to_string()))?;
        Ok(Self { pool, threads })
    }
}

impl Clone for Pool {
    fn clone(&self) -> Self {
        // The only failure is the OS refusing a thread; a panic here is caught at the FFI
        // edge and reported as a failed copy.
        Pool::new(self.threads).expect("cannot build the MPM thread pool for a copy")
    }
}

impl std::ops::Deref for Pool {
    type Target = rayon::ThreadPool;
    fn deref(&self) -> &rayon::ThreadPool {
        &self.pool
    }
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
    force: Vector3<f64>,
    /// Displacement of the top surface per slot (m), after the last solve.
    surface_u: Vec<Vector3<f64>>,
    /// Lattice index range `[ix0, ix1) x [iy0, iy1)` where the surface moved.
    surface_box: Option<[usize; 4]>,
    /// Whether the gel is undeformed and no indenter touched it in the last solve.
    resting: bool,
    /// Largest nodal reaction (internal units) at the end of the previous solve.
    last_reaction: f32,
    /// Largest nodal reaction of the last step.
    reaction: f32,
    /// Whether the last solve ended with `det F` at a clamp.
    clamped: bool,
    /// Lattice box of the top slots in contact at the end of the last solve.
    last_footprint: Option<[usize; 4]>,
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

/// Largest displacement (m) of a corner of `shape`'s bounding box between poses `a` and
/// `b`; 0 if not finite.
fn corner_motion(shape: &dyn Sdf, a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    let bb = shape.aabb();
    (0..8)
        .map(|i| {
            let c = Point3::new(
                if i & 1 == 0 { bb.min.x } else { bb.max.x },
                if i & 2 == 0 { bb.min.y } else { bb.max.y },
                if i & 4 == 0 { bb.min.z } else { bb.max.z },
            );
            let d = (a * c - b * c).norm();
            if d.is_finite() {
                d
            } else {
                0.0
            }
        })
        .fold(0.0, f64::max)
}

/// A lattice box `[ix0, ix1, iy0, iy1)` that holds nothing yet.
const EMPTY_BOX: [usize; 4] = [usize::MAX, 0, usize::MAX, 0];

/// Widens the lattice box `b` to hold slot `(ix, iy)`.
fn add_to_box(b: &mut [usize; 4], ix: usize, iy: usize) {
    *b = [
        b[0].min(ix),
        b[1].max(ix + 1),
        b[2].min(iy),
        b[3].max(iy + 1),
    ];
}

/// Matches the indenters of this solve to those of the previous one: same shape (the
/// same `Arc`), and among several sharing a shape, nearest pose first (greedy on the
/// largest bounding-box corner motion, ties in index order). Returns, for each current
/// indenter, the index of its previous self, or `None` for a new one.
fn match_indenters(prev: &[(Arc<dyn Sdf>, Isometry3<f64>)], now: &[&Placed]) -> Vec<Option<usize>> {
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (i, p) in now.iter().enumerate() {
        for (j, (shape, pose)) in prev.iter().enumerate() {
            if Arc::ptr_eq(shape, &p.shape) {
                pairs.push((corner_motion(p.shape.as_ref(), pose, &p.pose), i, j));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut matched = vec![None; now.len()];
    let mut taken = vec![false; prev.len()];
    for (_, i, j) in pairs {
        if matched[i].is_none() && !taken[j] {
            matched[i] = Some(j);
            taken[j] = true;
        }
    }
    matched
}

fn check(name: &'static str, value: f64, ok: bool, reason: &'static str) -> Result<(), MpmError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(MpmError::InvalidParameter {
            name,
            value,
            reason,
        })
    }
}

impl Gel {
    /// Checks `params` and `options` without building anything (cheap: a sensor calls it
    /// at model load and builds the gel on first contact).
    pub fn validate(params: &GelParams, options: &SolverOptions) -> Result<(), MpmError> {
        for (k, &l) in params.size.iter().enumerate() {
            let name = ["size[0]", "size[1]", "size[2]"][k];
            check(name, l, l > 0.0, "must be positive")?;
        }
        check(
            "young",
            params.young,
            params.young > 0.0,
            "must be positive",
        )?;
        check(
            "poisson",
            params.poisson,
            params.poisson > -1.0 && params.poisson < 0.5,
            "must lie in (-1, 0.5)",
        )?;
        check(
            "density",
            params.density,
            params.density > 0.0,
            "must be positive",
        )?;
        check(
            "friction",
            params.friction,
            params.friction >= 0.0,
            "must be non-negative",
        )?;
        check("dx", params.dx, params.dx > 0.0, "must be positive")?;
        let min_size = params.size.iter().cloned().fold(f64::INFINITY, f64::min);
        check(
            "dx",
            params.dx,
            params.dx <= 2.0 * min_size,
            "must not exceed twice the smallest gel dimension",
        )?;
        check(
            "tolerance",
            options.tolerance,
            options.tolerance > 0.0,
            "must be positive",
        )?;
        check(
            "max_iterations",
            options.max_iterations as f64,
            options.max_iterations > 0,
            "must be positive",
        )?;
        check(
            "threads",
            options.threads as f64,
            options.threads > 0,
            "must be positive",
        )?;
        check(
            "cfl",
            options.cfl,
            options.cfl > 0.0 && options.cfl < 1.0,
            "must lie in (0, 1)",
        )?;
        check(
            "damping",
            options.damping,
            options.damping > 0.0,
            "must be positive",
        )?;
        check(
            "sweep_rate",
            options.sweep_rate,
            options.sweep_rate > 0.0,
            "must be positive",
        )?;
        if options.active_margin.is_nan() || options.active_margin <= 0.0 {
            return Err(MpmError::InvalidParameter {
                name: "active_margin",
                value: options.active_margin,
                reason: "must be positive (infinite: the whole gel)",
            });
        }

        let dx = params.dx;
        let count: f64 = params
            .size
            .iter()
            .map(|&l| 2.0 * (l / dx).round().max(1.0))
            .product();
        check(
            "dx",
            dx,
            count <= MAX_PARTICLES as f64,
            "gives too many particles",
        )?;
        Ok(())
    }

    /// Builds the undeformed gel after validating `params` and `options`.
    pub fn new(params: GelParams, options: SolverOptions) -> Result<Gel, MpmError> {
        Self::validate(&params, &options)?;
        let dx = params.dx;
        let cells: [usize; 3] =
            std::array::from_fn(|k| ((params.size[k] / dx).round() as usize).max(1));
        let lattice: [usize; 3] = std::array::from_fn(|k| 2 * cells[k]);
        let count = lattice.iter().map(|&n| n as f64).product::<f64>();
        check(
            "dx",
            dx,
            count <= MAX_PARTICLES as f64,
            "gives too many particles",
        )?;
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
        let layout = Layout {
            dx,
            origin,
            dims,
            lattice,
            spacing,
        };

        let pool = Pool::new(options.threads)?;

        // Lame parameters, then internal units (divided by M = lambda + 2 mu).
        let (e, nu) = (params.young, params.poisson);
        let mu_si = e / (2.0 * (1.0 + nu));
        let lambda_si = e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
        let modulus = lambda_si + 2.0 * mu_si;
        let mu = mu_si / modulus;
        let lambda = lambda_si / modulus;
        // Mass scaling: rho' = 1 / cfl^2, so c_p = cfl cells per step.
        let rho = 1.0 / (options.cfl * options.cfl);
        let pvol = spacing.iter().map(|s| s / dx).product::<f64>();
        let pmass = rho * pvol;
        // Lowest mode of the bonded layer: thickness-shear quarter wave.
        let c_s = options.cfl * mu.sqrt();
        let omega1 = 0.5 * std::f64::consts::PI * c_s / (t / dx);
        let damping = 2.0 * options.damping * omega1;
        let ctx = StepCtx {
            dims,
            iz_bottom: PAD_BOTTOM,
            pmass: pmass as f32,
            pvol: pvol as f32,
            damping: damping as f32,
            fbar: options.fbar && params.poisson >= FBAR_POISSON,
            rot_iters: if params.material == Material::FixedCorotated {
                ROT_ITERS
            } else {
                0
            },
            row_len: lattice[1] * lattice[2],
            column_len: lattice[2],
            region: Region::whole(lattice, dims),
        };

        // Particles, x-major (ix outer, iz inner) so memory order follows the x bins.
        let n = lattice.iter().product::<usize>();
        let mut particles = Vec::with_capacity(n);
        let [nxp, nyp, nzp] = lattice;
        let mut top = vec![0u32; nxp * nyp];
        let mut top_ref = vec![Vector3::zeros(); nxp * nyp];
        let half_top = (0.5 * spacing[2] / dx) as f32;
        for ix in 0..nxp {
            for iy in 0..nyp {
                for iz in 0..nzp {
                    let x = layout.rest_position(&params.size, ix, iy, iz);
                    if iz + 1 == nzp {
                        let slot = iy * nxp + ix;
                        top[slot] = particles.len() as u32;
                        top_ref[slot] = x + Vector3::new(0.0, 0.0, half_top);
                    }
                    particles.push(Particle::at_rest(x));
                }
            }
        }
        let nodes = dims.iter().product::<usize>();
        let top_len = top.len();
        Ok(Gel {
            params,
            options,
            pool,
            layout,
            ctx,
            mu: mu as f32,
            lambda: lambda as f32,
            modulus,
            snapshot: particles.iter().map(Snapshot::of).collect(),
            stencils: Vec::with_capacity(n),
            binned: false,
            particles,
            top,
            top_ref,
            half_top,
            contacts: vec![SlotContact::NONE; top_len],
            active: vec![None; top_len],
            grid: vec![Node::ZERO; nodes],
            order: Vec::with_capacity(n),
            offsets: Vec::with_capacity(dims[0] + 1),
            cursor: Vec::with_capacity(dims[0]),
            layer_stats: Vec::with_capacity(dims[0]),
            chunk_stats: Vec::with_capacity(nxp),
            step_ind: Vec::new(),
            prev: Vec::new(),
            force: Vector3::zeros(),
            surface_u: vec![Vector3::zeros(); top_len],
            surface_box: None,
            resting: true,
            last_reaction: 0.0,
            reaction: 0.0,
            clamped: false,
            last_footprint: None,
        })
    }

    /// Most steps per solve: [`SolverOptions::max_iterations`] scaled by the layer's
    /// thickness in cells over [`CAP_CELLS`] (at least 1).
    pub fn iteration_cap(&self) -> usize {
        let cells = self.params.size[2] / self.layout.dx;
        let scale = (cells / CAP_CELLS).max(1.0);
        ((self.options.max_iterations as f64 * scale).round() as usize).max(1)
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
        self.restore_rest();
        self.prev.clear();
        self.force = Vector3::zeros();
        self.surface_u
            .iter_mut()
            .for_each(|u| *u = Vector3::zeros());
        self.surface_box = None;
        self.resting = true;
        self.last_reaction = 0.0;
        self.clamped = false;
        self.last_footprint = None;
        self.contacts.fill(SlotContact::NONE);
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
    /// the previous equilibrium. See the module docs for the method and the convergence
    /// test. Indenters with a non-finite pose are skipped.
    pub fn solve(&mut self, indenters: &[Placed]) -> SolveReport {
        let dx = self.layout.dx;
        let top_z = 0.0;
        // The usable indenters (finite poses), in slice order; contact state refers to
        // indenters by their index in this list.
        let used: Vec<&Placed> = indenters
            .iter()
            .filter(|p| {
                p.pose.translation.vector.iter().all(|v| v.is_finite())
                    && p.pose.rotation.coords.iter().all(|v| v.is_finite())
            })
            .collect();
        let reach = |p: &Placed| {
            let b = p.aabb();
            b.min.z <= top_z + 2.0 * dx && b.max.z >= -self.params.size[2] - 2.0 * dx
        };
        let touching = used.iter().any(|p| reach(p));
        let mut report = SolveReport {
            iterations: 0,
            converged: true,
            residual: 0.0,
            det_f_min: 1.0,
            det_f_max: 1.0,
            nonfinite_recovered: false,
            sweep_steps: 0,
            indenters: used.len(),
            restarted: false,
            active_particles: 0,
        };
        // A solve moves only its active region, so a particle outside it that went
        // non-finite (from outside the solver) would never be seen: check them all.
        let repaired = !self.particles.iter().all(Particle::is_finite);
        if self.clamped || repaired {
            // The last solve crushed or stretched some particles to the det F clamp, where
            // the elastic memory is lost, or the state is not finite: start again from the
            // undeformed gel.
            self.reset();
            report.restarted = true;
        }
        // Identity: which previous indenter each one is (same shape, nearest pose).
        let matched = match_indenters(&self.prev, &used);
        self.remap_contacts(&matched);
        let current: Vec<(Arc<dyn Sdf>, Isometry3<f64>)> =
            used.iter().map(|p| (p.shape.clone(), p.pose)).collect();
        if !touching && self.resting {
            self.prev = current;
            self.force = Vector3::zeros();
            return report;
        }

        // Start pose of each indenter: its previous pose, or lifted clear of the surface.
        let starts: Vec<Isometry3<f64>> = used
            .iter()
            .zip(&matched)
            .map(|(p, m)| {
                if let Some(j) = *m {
                    return self.prev[j].1;
                }
                let lift = top_z - p.aabb().min.z;
                let lift = if lift.is_finite() {
                    lift.clamp(0.0, self.params.size[2] + 4.0 * dx)
                } else {
                    0.0
                };
                let mut s = p.pose;
                s.translation.vector.z += lift;
                s
            })
            .collect();
        // Sweep length: the largest displacement of a bounding-box corner, in steps.
        let disp = used
            .iter()
            .zip(&starts)
            .map(|(p, start)| corner_motion(p.shape.as_ref(), start, &p.pose))
            .fold(0.0, f64::max);
        let max_iterations = self.iteration_cap();
        let cap = (max_iterations / 2).max(1);
        let sweep = ((disp / (self.options.sweep_rate * dx)).ceil() as usize).clamp(1, cap);
        report.sweep_steps = sweep;

        self.ctx.region = if touching {
            self.active_region(&used, &starts)
        } else {
            // Unloading: the whole gel relaxes.
            Region::whole(self.layout.lattice, self.layout.dims)
        };
        report.active_particles = self.ctx.region.particles(self.ctx.column_len);
        for (s, p) in self.snapshot.iter_mut().zip(&mut self.particles) {
            *s = Snapshot::of(p);
            p.v = Vector3::zeros();
            p.c = nalgebra::Matrix3::zeros();
        }
        transfer::compute_stencils(&self.particles, &mut self.stencils);
        self.binned = false;
        let interp = |a: &Isometry3<f64>, b: &Isometry3<f64>, s: f64| {
            a.try_lerp_slerp(b, s, 1e-9).unwrap_or(*b)
        };
        let tol = self.options.tolerance;
        for it in 0..max_iterations {
            let s_now = ((it + 1) as f64 / sweep as f64).min(1.0);
            let s_before = (it as f64 / sweep as f64).min(1.0);
            self.step_ind.clear();
            for (p, start) in used.iter().zip(&starts) {
                let now = interp(start, &p.pose, s_now);
                let before = interp(start, &p.pose, s_before);
                let b0 = p.shape.aabb().transformed(&now);
                let b1 = p.shape.aabb().transformed(&before);
                let bounds = Aabb::new(b0.min.inf(&b1.min), b0.max.sup(&b1.max))
                    .inflated((contact::CONTACT_BAND as f64 + 1.0) * dx);
                self.step_ind.push(StepIndenter {
                    shape: p.shape.clone(),
                    now,
                    bounds,
                });
            }
            let (residual, nonfinite, det_min, det_max) = match self.params.material {
                Material::FixedCorotated => {
                    let m = FixedCorotatedModel {
                        mu: self.mu,
                        lambda: self.lambda,
                    };
                    self.step(&m)
                }
                Material::NeoHookean => {
                    let m = NeoHookeanModel {
                        mu: self.mu,
                        lambda: self.lambda,
                    };
                    self.step(&m)
                }
            };
            report.iterations = it + 1;
            if nonfinite {
                self.recover();
                report.nonfinite_recovered = true;
                report.converged = false;
                report.residual = f64::INFINITY;
                break;
            }
            report.residual = residual;
            report.det_f_min = det_min;
            report.det_f_max = det_max;
            report.converged = it + 1 >= sweep && residual <= tol;
            if report.converged {
                break;
            }
        }
        if report.nonfinite_recovered {
            let (lo, hi) = self.det_range();
            report.det_f_min = lo;
            report.det_f_max = hi;
            self.force = Vector3::zeros();
            self.prev.clear();
            self.last_reaction = 0.0;
        } else {
            self.prev = current;
            self.last_reaction = self.reaction;
        }
        report.nonfinite_recovered |= repaired;
        self.update_surface();
        self.last_footprint = self.footprint();
        self.resting = !touching && self.surface_box.is_none();
        self.clamped = report.det_f_min <= J_MIN * 1.01 || report.det_f_max >= J_MAX * 0.99;
        report
    }

    /// The region this solve moves (see the module docs, "Active region"): the lattice box
    /// of the top-surface slots that an indenter reaches (within half a cell of its start
    /// or end pose), that hold contact state or that were in contact at the end of the last
    /// solve, grown by [`SolverOptions::active_margin`] thicknesses on every side, and
    /// widened to every slot whose indentation is above [`DEFORMED`] of the largest (so
    /// that a region an indenter leaves relaxes); and the nodes that stay free within it.
    /// Without a slot in contact now or at the end of the last solve, the whole gel (and
    /// [`Gel::solve`] takes the whole gel when no indenter reaches it: unloading).
    fn active_region(&self, used: &[&Placed], starts: &[Isometry3<f64>]) -> Region {
        let layout = &self.layout;
        let whole = Region::whole(layout.lattice, layout.dims);
        let margin = self.options.active_margin * self.params.size[2];
        if !margin.is_finite() {
            return whole;
        }
        let [nxp, nyp, _] = layout.lattice;
        let dx = layout.dx;
        let reach = 0.5 * dx;
        let poses: Vec<(&Placed, [Isometry3<f64>; 2], Aabb)> = used
            .iter()
            .zip(starts)
            .map(|(p, s)| {
                let a = p.shape.aabb().transformed(s);
                let b = p.shape.aabb().transformed(&p.pose);
                let bounds = Aabb::new(a.min.inf(&b.min), a.max.sup(&b.max)).inflated(reach);
                (*p, [*s, p.pose], bounds)
            })
            .collect();
        let last = self.last_footprint.unwrap_or([0; 4]);
        let umax = self.surface_u.iter().map(|u| u.z.abs()).fold(0.0, f64::max);
        let deformed = (DEFORMED * umax).max(DEPTH_EPS);
        let (mut fp, mut zone) = (EMPTY_BOX, EMPTY_BOX);
        for slot in 0..self.top.len() {
            let (ix, iy) = (slot % nxp, slot / nxp);
            if self.surface_u[slot].z.abs() > deformed {
                add_to_box(&mut zone, ix, iy);
            }
            let c = &self.contacts[slot];
            let mut hit = (last[0]..last[1]).contains(&ix) && (last[2]..last[3]).contains(&iy)
                || c.lambda > 0.0
                || c.indenter != u32::MAX;
            if !hit {
                let p = &self.particles[self.top[slot] as usize];
                let sp = (p.x + p.f.column(2) * self.half_top).cast::<f64>();
                let sp = Point3::from(layout.origin + sp * dx);
                hit = poses.iter().any(|(placed, pose, bounds)| {
                    (0..3).all(|k| sp[k] >= bounds.min[k] && sp[k] <= bounds.max[k])
                        && pose.iter().any(|q| {
                            let d = placed.shape.distance(&q.inverse_transform_point(&sp));
                            !d.is_finite() || d < reach
                        })
                });
            }
            if hit {
                add_to_box(&mut fp, ix, iy);
            }
        }
        if fp[0] == usize::MAX {
            return whole;
        }
        let grow = |k: usize| (margin / layout.spacing[k]).ceil() as usize;
        let mut lattice = [
            fp[0].saturating_sub(grow(0)),
            (fp[1] + grow(0)).min(nxp),
            fp[2].saturating_sub(grow(1)),
            (fp[3] + grow(1)).min(nyp),
        ];
        if zone[0] != usize::MAX {
            lattice = [
                lattice[0].min(zone[0]),
                lattice[1].max(zone[1]),
                lattice[2].min(zone[2]),
                lattice[3].max(zone[3]),
            ];
        }
        // A node is free when no inactive particle lies within its support (1.5 cells),
        // with a quarter cell to spare for the particles' motion.
        let free = |k: usize, lo: usize, hi: usize, n: usize| -> [usize; 2] {
            let at = |i: usize| {
                let mut idx = [0usize; 3];
                idx[k] = i;
                layout.rest_position(&self.params.size, idx[0], idx[1], idx[2])[k] as f64
            };
            let a = if lo > 0 {
                (at(lo - 1) + 1.75).floor() as usize + 1
            } else {
                0
            };
            let b = if hi < n {
                ((at(hi) - 1.75).ceil().max(0.0) as usize).min(layout.dims[k])
            } else {
                layout.dims[k]
            };
            [a.min(b), b]
        };
        Region {
            lattice,
            free_x: free(0, lattice[0], lattice[1], nxp),
            free_y: free(1, lattice[2], lattice[3], nyp),
        }
    }

    /// Lattice box of the top slots with a contact force at the last step or a positive
    /// multiplier.
    fn footprint(&self) -> Option<[usize; 4]> {
        let nxp = self.layout.lattice[0];
        let mut bx = EMPTY_BOX;
        for (slot, (a, c)) in self.active.iter().zip(&self.contacts).enumerate() {
            if a.is_some() || c.lambda > 0.0 {
                add_to_box(&mut bx, slot % nxp, slot / nxp);
            }
        }
        (bx[0] != usize::MAX).then_some(bx)
    }

    /// Renumbers the indenter indices of the contact state from the previous solve's list
    /// to this one's (`matched[i]`: the previous index of indenter `i`); the state held
    /// by a previous indenter that has no successor is released.
    fn remap_contacts(&mut self, matched: &[Option<usize>]) {
        let mut new_index = vec![u32::MAX; self.prev.len()];
        for (i, m) in matched.iter().enumerate() {
            if let Some(j) = *m {
                new_index[j] = i as u32;
            }
        }
        let map = |k: u32| new_index.get(k as usize).copied().unwrap_or(u32::MAX);
        for c in &mut self.contacts {
            if c.owner == u32::MAX && c.indenter == u32::MAX {
                continue;
            }
            let owner = map(c.owner);
            if owner == u32::MAX {
                *c = SlotContact::NONE;
                continue;
            }
            c.owner = owner;
            c.indenter = map(c.indenter);
        }
    }

    /// Restores the state at the start of the solve, or the undeformed gel if that state is
    /// itself not finite; zero velocities either way.
    fn recover(&mut self) {
        let good = self.snapshot.iter().all(Snapshot::is_finite);
        if good {
            for (p, s) in self.particles.iter_mut().zip(&self.snapshot) {
                *p = Particle {
                    x: s.x,
                    v: Vector3::zeros(),
                    c: nalgebra::Matrix3::zeros(),
                    f: s.f,
                    q: s.q,
                    jr: s.jr,
                };
            }
        } else {
            self.restore_rest();
        }
        self.contacts.fill(SlotContact::NONE);
        transfer::compute_stencils(&self.particles, &mut self.stencils);
        self.binned = false;
    }

    fn det_range(&self) -> (f64, f64) {
        self.particles
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                let j = p.f.determinant() as f64;
                (lo.min(j), hi.max(j))
            })
    }

    /// One MLS-MPM step: contact forces of the top particles, bin, P2G, grid update, G2P.
    /// Returns (relative residual, non-finite seen, det F min, det F max).
    fn step<M: ConstitutiveModel>(&mut self, model: &M) -> (f64, bool, f64, f64) {
        let Gel {
            pool,
            layout,
            ctx,
            particles,
            top,
            half_top,
            contacts,
            active,
            grid,
            order,
            offsets,
            cursor,
            stencils,
            binned,
            layer_stats,
            chunk_stats,
            step_ind,
            mu,
            modulus,
            force,
            last_reaction,
            reaction: last_step_reaction,
            params,
            ..
        } = self;
        let layout = *layout;
        let ctx = *ctx;
        let half_top = *half_top;
        let f = pool.install(|| {
            let input = ContactInput {
                layout: &layout,
                half_top,
                particles,
                top,
                indenters: step_ind,
                friction: params.friction as f32,
                gain: contact::multiplier_gain(params.size[2] / layout.dx),
                region: &ctx.region,
            };
            contact::update_contacts(&input, contacts, active);
            if !*binned {
                transfer::bin_particles(&ctx, stencils, order, offsets, cursor);
                *binned = true;
            }
            let input = P2gInput {
                particles,
                stencils,
                order,
                offsets,
            };
            transfer::particle_to_grid(&ctx, model, &input, grid);
            let f = contact::scatter_contacts(&ctx, stencils, active, grid);
            transfer::grid_update(&ctx, grid, layer_stats);
            transfer::grid_to_particle(&ctx, grid, particles, stencils, chunk_stats);
            f
        });
        let mut residual = 0.0f32;
        let mut reaction = (1e-4 * *mu).max(*last_reaction);
        let mut step_reaction = 0.0f32;
        for s in layer_stats.iter() {
            residual = residual.max(s.residual);
            step_reaction = step_reaction.max(s.reaction);
        }
        // Contact load scale: the mean contact force per cell of contact area (the
        // mean pressure times dx^2), comparable to a nodal force.
        let mut count = 0usize;
        for a in active.iter().flatten() {
            residual = residual.max(a.residual);
            count += 1;
        }
        if count > 0 {
            let area = count as f64 * layout.spacing[0] * layout.spacing[1] / layout.dx.powi(2);
            let load = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt() / area;
            step_reaction = step_reaction.max(load as f32);
        }
        reaction = reaction.max(step_reaction);
        let scale = *modulus * layout.dx * layout.dx;
        // The gel pushes the indenters with the opposite of the contact forces.
        *force = -Vector3::from(f) * scale;
        let mut nonfinite = !residual.is_finite() || !force.iter().all(|v| v.is_finite());
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for s in chunk_stats.iter() {
            nonfinite |= s.nonfinite;
            *binned &= !s.moved;
            lo = lo.min(s.det_min);
            hi = hi.max(s.det_max);
        }
        *last_step_reaction = step_reaction;
        (
            (residual / reaction) as f64,
            nonfinite,
            lo as f64,
            hi as f64,
        )
    }

    /// Recomputes the top-surface displacement field and the box where it is non-zero.
    fn update_surface(&mut self) {
        let [nxp, nyp, _] = self.layout.lattice;
        let dx = self.layout.dx;
        let mut bx = EMPTY_BOX;
        for (slot, u) in self.surface_u.iter_mut().enumerate() {
            let p = &self.particles[self.top[slot] as usize];
            let s = p.x + p.f.column(2) * self.half_top;
            let d = (s - self.top_ref[slot]).cast::<f64>() * dx;
            *u = if d.iter().all(|v| v.is_finite()) {
                d
            } else {
                Vector3::zeros()
            };
            if u.amax() > DEPTH_EPS {
                add_to_box(&mut bx, slot % nxp, slot / nxp);
            }
        }
        self.surface_box = (bx[0] != usize::MAX).then(|| [bx[0], bx[1], bx[2], bx[3]]);
        debug_assert!(bx[1] <= nxp && bx[3] <= nyp || bx[0] == usize::MAX);
    }

    /// Indentation of the deformed top surface at each pixel of `grid` (m, positive into
    /// the gel, clamped to `[0, T]`), row-major into `out` (`grid.height * grid.width`
    /// values; see [`PixelGrid`] for the orientation). See [`surface`] for the method.
    ///
    /// # Panics
    /// If `out` is shorter than `grid.width * grid.height`.
    pub fn surface_depth(&self, grid: &PixelGrid, out: &mut [f64]) {
        surface::surface_depth(self, grid, out);
    }
}
