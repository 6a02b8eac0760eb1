//! What a gel is built from: its physical parameters ([`GelParams`], [`Material`]), the
//! solver's settings ([`SolverOptions`]) and their validation ([`Gel::validate`]), the
//! errors ([`MpmError`]) and what a solve reports ([`SolveReport`]).

use super::Gel;

/// Smallest `det F` a particle may reach; below it (inverted included) `F` is repaired
/// through its SVD.
pub const J_MIN: f64 = 0.2;
/// Largest `det F` a particle may reach; above it `F` is repaired through its SVD.
pub const J_MAX: f64 = 5.0;

/// Smallest Poisson's ratio at which [`SolverOptions::fbar`] applies: below it there is
/// no locking to cure, and the one-step-behind smoothing of `J` over the 27-node stencil
/// only softens a contact narrower than a few cells (measured: `docs/solvers.md`, "Two
/// solvers and a third").
pub const FBAR_POISSON: f64 = 0.45;

/// Default [`SolverOptions::active_margin`] (gel thicknesses). The surface of a bonded
/// layer settles within about one thickness of a contact, so the rigid wall 1.5
/// thicknesses out changes little (measured: `docs/solvers.md`, "Two solvers and a
/// third").
pub const ACTIVE_MARGIN: f64 = 1.5;

/// Layer thickness (cells) above which the iteration cap grows in proportion to it.
///
/// Both rates that bound the solve fall as one over the cells through the layer: the
/// slowest elastic mode (`omega_1`, see `mpm/relax.rs`) and the contact multipliers'
/// gain (`contact::multiplier_gain`). A fixed cap that the coarse grid (2.9 cells) never
/// reaches then cuts off the fine grid (13 cells) before it converges (measured:
/// `docs/solvers.md`, "A wide flat contact on a finer grid: the multipliers' gain").
pub const CAP_CELLS: f64 = 3.2;

/// Largest number of particles accepted (memory guard, about 0.3 GB).
const MAX_PARTICLES: usize = 1 << 30 >> 2;

pub use super::materials::Material;

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
        use crate::attributes::defaults;
        Self {
            size: defaults::SIZE,
            young: defaults::YOUNG,
            poisson: defaults::POISSON,
            density: defaults::DENSITY,
            friction: defaults::FRICTION,
            dx: defaults::COARSE_DX,
            material: Material::FixedCorotated,
        }
    }
}

/// Numerical settings of the quasi-static solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolverOptions {
    /// Convergence threshold on the relative out-of-balance force (see the convergence
    /// test in `mpm/relax.rs`).
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
    /// solve moves the gel ([`Gel::solve`]; see `mpm/region.rs`); `f64::INFINITY`: always
    /// the whole gel.
    pub active_margin: f64,
    /// The equilibrium solver.
    pub solver: Solver,
    /// With [`Solver::Relaxation`]: a frame whose contact the relaxation does not resolve
    /// (the indenters' rigid footprint holds at most [`UNRESOLVED_POINTS`] of the top
    /// surface's rest points while they reach more than [`MISSED_FRACTION`] of the top
    /// particles' spacing into the gel) is solved again by [`Solver::Linear`], whose
    /// contact lattice and small-contact model carry it (by Newton's method on a grid too
    /// fine for the linear solver). What the sensor does for a coarse gel (and rom's)
    /// whose configuration names no solver.
    pub fallback: bool,
    /// How Newton's method solves its linear systems.
    pub linear: Linear,
    /// Newton's method on a gel of more unknowns than this first solves each frame on a
    /// gel twice as coarse (the same rule again there), and starts from that gel's change
    /// carried onto its own grid (see `mpm/newton/mod.rs`, "Coarse start"). Default
    /// [`COARSE_START_UNKNOWNS`] (the default gel at 0.7 mm and finer); `usize::MAX`: never
    /// (what a gel sets where the gel twice as coarse cannot be built, too thin for it).
    pub coarse_start_above: usize,
    /// Lateral margin, in gel thicknesses, around the contact footprint of a Newton solve
    /// that has a coarse start: the nodes beyond it take the displacement of the gel twice
    /// as coarse rather than being held fixed (see `mpm/newton/mod.rs`, "Nested solve").
    /// Default [`NESTED_MARGIN`]; a value of at least
    /// [`active_margin`](Self::active_margin) turns the nesting off.
    pub nested_margin: f64,
}

/// How Newton's method ([`Solver::Newton`]) solves the linear system of a step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Linear {
    /// A sparse factorisation up to [`MULTIGRID_UNKNOWNS`] unknowns in the solved region,
    /// the two-grid preconditioner beyond.
    #[default]
    Automatic,
    /// A sparse Cholesky factorisation, kept as the preconditioner of conjugate gradients
    /// on later steps.
    Factor,
    /// Conjugate gradients preconditioned by a two-grid cycle (`mpm/newton/multigrid.rs`).
    Multigrid,
}

/// Default [`SolverOptions::nested_margin`] (gel thicknesses). A nested solve's force
/// barely depends on its margin from a quarter of a thickness to one, where a rigid wall
/// that close stiffens the gel; half a thickness keeps the coarse field a millimetre or
/// more from the footprint's edge (measured: `docs/solvers.md`, "A nested solve: the fine
/// grid only near the contact").
pub const NESTED_MARGIN: f64 = 0.5;

/// How [`Gel::solve`] finds the equilibrium.
///
/// [`Gel::solve`]: super::Gel::solve
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Solver {
    /// Dynamic relaxation: damped explicit MLS-MPM steps (`mpm/relax.rs`).
    #[default]
    Relaxation,
    /// Newton's method on the total potential energy of the nodal displacements
    /// (`mpm/newton/`).
    Newton,
    /// Experimental: dynamic relaxation of the nodal displacements with fixed quadrature
    /// points (total-Lagrangian, `mpm/total.rs`), whose equilibrium does not depend on
    /// the path.
    Total,
    /// Linear elasticity about the undeformed gel with contact and Coulomb friction,
    /// solved on a surface compliance kept per node column (`mpm/linear.rs`): a
    /// frame costs no pass over the particles.
    Linear,
}

impl Solver {
    /// Every solver.
    pub const ALL: [Solver; 4] = [
        Solver::Relaxation,
        Solver::Newton,
        Solver::Total,
        Solver::Linear,
    ];

    /// The name recorded in a reduced-order model's recipe and used by the `solver`
    /// attribute.
    pub fn name(self) -> &'static str {
        match self {
            Solver::Relaxation => "relaxation",
            Solver::Newton => "newton",
            Solver::Total => "total",
            Solver::Linear => "linear",
        }
    }

    /// Whether this solver is a relaxation, moving the gel's own particles (their grid,
    /// stencils and contact memory), rather than a solver of its own fields.
    pub(crate) fn relaxes(self) -> bool {
        matches!(self, Solver::Relaxation | Solver::Total)
    }

    /// The solver called `name`.
    pub fn named(name: &str) -> Option<Solver> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }
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
            solver: Solver::Relaxation,
            fallback: false,
            linear: Linear::Automatic,
            coarse_start_above: super::choice::COARSE_START_UNKNOWNS,
            nested_margin: NESTED_MARGIN,
        }
    }
}

/// Errors of [`Gel::new`].
#[derive(Debug, thiserror::Error)]
pub enum MpmError {
    /// A parameter is outside its range in the attribute table.
    #[error("invalid gel parameter `{name}` = {value}: must be in {range}")]
    OutOfRange {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: f64,
        /// Its range ([`crate::attributes`]).
        range: crate::attributes::Range,
    },
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
    /// Newton solver: sparse factorisations of the stiffness matrix (linear solver: 1 where
    /// this solve factored the stiffness at rest, see `columns`).
    pub factorisations: usize,
    /// Newton solver: steps solved by conjugate gradients preconditioned with an earlier
    /// factorisation.
    pub reused: usize,
    /// Newton solver: conjugate gradient iterations, over all its steps (linear solver: the
    /// contact's Newton steps).
    pub cg_iterations: usize,
    /// Linear solver: node columns whose response this solve computed (one solve with the
    /// factorisation each): all of them at a relaxation's first fallback frame where the
    /// gel cache had none, else 0 (the linear solver's own gel computes them at load).
    pub columns: usize,
    /// Whether the relaxation did not resolve the contact and another solver solved the
    /// frame ([`SolverOptions::fallback`]).
    pub fallback: bool,
    /// Relaxation: how often the contact multipliers' gain was halved because their loop
    /// oscillated (see `mpm/relax.rs`).
    pub gain_halvings: usize,
    /// Newton: how often a substep that stalled far from equilibrium (its residual above
    /// ten times the tolerance) was taken again as two halves (see `mpm/newton/mod.rs`).
    pub substep_splits: usize,
    /// Newton steps of the coarse start's gels ([`SolverOptions::coarse_start_above`]),
    /// not counted in `iterations`.
    pub coarse_iterations: usize,
    /// Newton: the frame spent its bound on Newton steps and ended at the last
    /// equilibrium it found, short of the indenters' poses.
    pub work_bound: bool,
    /// Linear solver: friction's lagged normal forces did not settle within the frame's
    /// refreshes; the last refresh's change of the friction they cap, relative to the load.
    pub unsettled_friction: Option<f64>,
}
impl SolveReport {
    /// The report of a solve with `indenters` usable indenters that has not stepped yet.
    pub(super) fn new(indenters: usize) -> Self {
        Self {
            iterations: 0,
            converged: true,
            residual: 0.0,
            det_f_min: 1.0,
            det_f_max: 1.0,
            nonfinite_recovered: false,
            sweep_steps: 0,
            indenters,
            restarted: false,
            active_particles: 0,
            factorisations: 0,
            reused: 0,
            cg_iterations: 0,
            columns: 0,
            fallback: false,
            gain_halvings: 0,
            substep_splits: 0,
            coarse_iterations: 0,
            work_bound: false,
            unsettled_friction: None,
        }
    }
}

const POSITIVE: &str = "must be positive";

/// `Ok` when `ok` holds and `value` is finite, else the [`MpmError::InvalidParameter`]
/// naming `name`.
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
        check_params(params)?;
        check_options(options)?;
        let count: f64 = params
            .size
            .iter()
            .map(|&l| 2.0 * (l / params.dx).round().max(1.0))
            .product();
        check(
            "dx",
            params.dx,
            count <= MAX_PARTICLES as f64,
            "gives too many particles",
        )?;
        check(
            "dx",
            params.dx,
            options.solver != Solver::Linear || super::choice::linear_fits(params),
            "is too small for solver=\"linear\": its grid has more unknowns than the 30,000 \
             it factors",
        )
    }
}

fn check_params(p: &GelParams) -> Result<(), MpmError> {
    use crate::attributes::{DENSITY, FRICTION, POISSON, SIZE, YOUNG};
    let sizes = ["size[0]", "size[1]", "size[2]"].into_iter().zip(p.size);
    let physical = [
        ("young", p.young, YOUNG),
        ("poisson", p.poisson, POISSON),
        ("density", p.density, DENSITY),
        ("friction", p.friction, FRICTION),
    ];
    for (name, value, attribute) in sizes.map(|(n, l)| (n, l, SIZE)).into_iter().chain(physical) {
        let range = attribute.valid.range();
        if !range.contains(value) {
            return Err(MpmError::OutOfRange { name, value, range });
        }
    }
    let min_size = p.size.iter().cloned().fold(f64::INFINITY, f64::min);
    [
        ("dx", p.dx, p.dx > 0.0, POSITIVE),
        (
            "dx",
            p.dx,
            p.dx <= 2.0 * min_size,
            "must not exceed twice the smallest gel dimension",
        ),
    ]
    .into_iter()
    .try_for_each(|(name, value, ok, reason)| check(name, value, ok, reason))
}

fn check_options(o: &SolverOptions) -> Result<(), MpmError> {
    let cfl_ok = o.cfl > 0.0 && o.cfl < 1.0;
    let (iterations, threads) = (o.max_iterations, o.threads);
    [
        ("tolerance", o.tolerance, o.tolerance > 0.0, POSITIVE),
        (
            "max_iterations",
            iterations as f64,
            iterations > 0,
            POSITIVE,
        ),
        ("threads", threads as f64, threads > 0, POSITIVE),
        ("cfl", o.cfl, cfl_ok, "must lie in (0, 1)"),
        ("damping", o.damping, o.damping > 0.0, POSITIVE),
        ("sweep_rate", o.sweep_rate, o.sweep_rate > 0.0, POSITIVE),
    ]
    .into_iter()
    .try_for_each(|(name, value, ok, reason)| check(name, value, ok, reason))?;
    // Not `check`: infinity is allowed (the whole gel; no nesting).
    for (name, value) in [
        ("active_margin", o.active_margin),
        ("nested_margin", o.nested_margin),
    ] {
        if value.is_nan() || value <= 0.0 {
            return Err(MpmError::InvalidParameter {
                name,
                value,
                reason: "must be positive (infinite: the whole gel)",
            });
        }
    }
    Ok(())
}
