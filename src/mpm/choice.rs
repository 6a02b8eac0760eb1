//! Which equilibrium solver a gel gets, and why: every rule in one place.
//!
//! A gel runs one of the solvers of [`Solver`]. The choice is made here, once per gel
//! ([`choose`]) and, for the frames whose contact the gel's particles cannot carry, once
//! per frame ([`frame_fallback`]); Newton's method picks its linear method per region here
//! too ([`newton_multigrid`]). Each rule gives its reason ([`Choice::why`]); the
//! measurements behind the rules and their constants are in `docs/solvers.md`, "Which
//! solver a gel gets" and the sections each constant names.
//!
//! In short: a configuration that names a solver gets it; `rom` with its shipped models
//! runs the linear solver wherever it factors; otherwise Newton's method from
//! Poisson's ratio [`AUTO_NEWTON_POISSON`] on (where the relaxation stops at its iteration
//! cap), dynamic relaxation below it; for `coarse` and `rom`, a frame whose contact the
//! relaxation's surface points miss is solved by the linear solver (Newton's method on a
//! grid too fine for the linear solver's [`LINEAR_UNKNOWNS`]). A reduced-order model then
//! checks its recipe's solver against the choice.

use super::{GelParams, Linear, Solver};

/// Poisson's ratio from which [`choose`] gives Newton's method.
pub const AUTO_NEWTON_POISSON: f64 = 0.49;

/// Unknowns of a Newton region above which [`Linear::Automatic`] preconditions with the
/// two-grid cycle instead of factoring: between the default gel's regions at 0.7 mm
/// (about 19,600 unknowns), where the factorisation is the faster, and 0.6 mm (about
/// 31,000), where the two-grid cycle is (measured: `docs/solvers.md`, "Friction's sliding
/// points: a majorizing stiffness; the two-grid cycle from 0.6 mm").
pub const MULTIGRID_UNKNOWNS: usize = 25_000;

/// Unknowns of a gel above which Newton's method starts each frame from a gel twice as
/// coarse ([`SolverOptions::coarse_start_above`]) and nests its solve in it: the default
/// gel at 0.7 mm (about 40,000 unknowns) and finer, not at 1.0 mm (about 14,000). It was
/// 60,000 (0.5 mm and finer) before the nested solve, which made the 0.7 mm gel's presses
/// faster too (measured: `docs/solvers.md`, "A nested solve: the fine grid only near the
/// contact").
pub const COARSE_START_UNKNOWNS: usize = 20_000;

/// Most unknowns (three per grid node, an upper bound) [`Solver::Linear`] factors: the
/// default gel at 1.0 mm (22,869), not at 0.7 mm (57,132), where the factorisation and
/// the node columns cost seconds and hundreds of megabytes (measured: `docs/solvers.md`,
/// "The linear solver: a coarse frame in milliseconds").
pub const LINEAR_UNKNOWNS: usize = 30_000;

/// Penetration, as a fraction of the contact points' spacing `s`, above which a gel that
/// carries no force has missed a contact that fell between its contact points (the
/// sensor warns; [`SolverOptions::fallback`] solves the frame again). A smooth
/// body of radius `R` can sink `s^2 / 4R` between four points untouched (26 um for a 5 mm
/// sphere on the coarse gel); 5 % of `s` (36 um there) stays silent for bodies of radius
/// above 5 `s`, such as a ball landing on the gel, and catches a 0.5 mm sphere or a cone
/// tip, which sink up to 0.25 mm untouched (measured: `docs/solvers.md`, "What the
/// relaxation's answer depends on").
pub const MISSED_FRACTION: f64 = 0.05;

/// Top-surface points in an indenter's rigid footprint at most with which the relaxation
/// does not resolve a contact (see [`SolverOptions::fallback`]): with one or two of its
/// points in contact, small spheres carried far too little or far too much force
/// (measured: `docs/solvers.md`, "What the relaxation's answer depends on").
pub const UNRESOLVED_POINTS: usize = 4;

/// What a sensor's physics asks of its gel's solver when the configuration names none.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// A reference (`fine`): the automatic rule alone.
    Reference,
    /// `coarse`, and `rom` with another model (`model="rom-default"`, the relaxation's, or
    /// one of the user's, whose recipe names the solver it needs): the automatic rule with
    /// the per-frame fallback for small contacts.
    Coarse,
    /// `rom` with its default model, unnamed or named (`rom-linear-narrow` from 3.5 mm,
    /// `rom-linear` below, [`crate::rom::shipped_model`]): the linear gel where it
    /// factors, at every Poisson's ratio (its stiffness at rest is factored once, so a
    /// near-incompressible gel costs it nothing more, and its models serve 0.3 to 0.49);
    /// the relaxation's rule elsewhere (where the shipped models serve no gel). The linear
    /// gel's rom is the most accurate mode of the full profile in depth and SSIM, on
    /// shapes outside the training families too, and the faster rom in both environments
    /// (measured: `docs/modes.md`, "The default: rom on the linear gel").
    ShippedRom,
}

/// A gel's solver and why it runs it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Choice {
    /// The solver of every frame.
    pub solver: Solver,
    /// Whether frames whose contact the relaxation's particles cannot resolve are solved
    /// by the fallback solver instead ([`frame_fallback`]).
    pub fallback: bool,
    /// The rule that chose, in words.
    pub why: &'static str,
}

impl std::fmt::Display for Choice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "solver \"{}\"", self.solver.name())?;
        if self.fallback {
            f.write_str(" (the linear solver for contacts it misses)")?;
        }
        write!(f, ": {}", self.why)
    }
}

/// The automatic rule, for a gel whose configuration names no solver: Newton's method where dynamic
/// relaxation does not reach equilibrium within its iteration cap, a Poisson's ratio
/// of at least [`AUTO_NEWTON_POISSON`], on every grid (Newton's method converges there,
/// the relaxation stops at its cap); relaxation everywhere else. On the fine grids
/// Newton is faster on a continued press and slower on one from rest, and the
/// benchmark's sequence of presses at 0.3 mm takes them about the same time at several
/// times the memory (measured: `docs/solvers.md`, "Which solver a gel gets").
/// `named` is the solver a configuration names, if any; `role` is what the sensor's
/// physics asks of the gel ([`Role`]): the per-frame fallback where the automatic rule
/// picks the relaxation's family (the sensor's `coarse` and `rom`), and for `rom` with
/// its shipped models the linear gel wherever it factors ([`linear_fits`]), at any
/// Poisson's ratio.
pub fn choose(params: &GelParams, named: Option<Solver>, role: Role) -> Choice {
    let small_contacts = role != Role::Reference;
    match named {
        Some(solver) => Choice {
            solver,
            fallback: false,
            why: "named by the configuration",
        },
        None if role == Role::ShippedRom && linear_fits(params) => Choice {
            solver: Solver::Linear,
            fallback: false,
            why: "rom's default: the linear gel where it factors, read by the shipped model \
                      trained on it (the full profile's most accurate mode, and rom's faster \
                      gel in Press-v1 and GripperLift-v1)",
        },
        None if params.poisson >= AUTO_NEWTON_POISSON => Choice {
            solver: Solver::Newton,
            fallback: small_contacts,
            why: "Poisson's ratio of 0.49 or more: the relaxation stops at its iteration cap \
                  there, Newton's method converges",
        },
        None => Choice {
            solver: Solver::Relaxation,
            fallback: small_contacts,
            why: "Poisson's ratio below 0.49: dynamic relaxation, the fastest solve per frame \
                  on every grid",
        },
    }
}

/// The solver of a frame that a gel with the fallback ([`Choice::fallback`]) does not
/// leave to its own solver, or `None`: a frame in contact (`touching`) whose contact
/// holds at most [`UNRESOLVED_POINTS`] of the relaxation's surface points (`footprint`)
/// while the indenters reach more than [`MISSED_FRACTION`] of their `spacing` below the
/// surface (`reached`, asked only then). Such a frame goes to the linear solver, whose
/// small contacts follow Hertz and Sneddon, or to Newton's method on a grid too fine for
/// the linear solver. The rule depends on the poses alone, so a body bouncing on the gel
/// meets one force law on the way in and out.
pub fn frame_fallback(
    params: &GelParams,
    touching: bool,
    footprint: usize,
    reached: impl FnOnce() -> f64,
    spacing: f64,
) -> Option<Solver> {
    let missed =
        touching && footprint <= UNRESOLVED_POINTS && reached() > MISSED_FRACTION * spacing;
    missed.then(|| {
        if linear_fits(params) {
            Solver::Linear
        } else {
            Solver::Newton
        }
    })
}

/// Whether Newton's method preconditions a region's linear systems with the two-grid
/// cycle rather than factoring them: as `method` says, and for [`Linear::Automatic`]
/// beyond [`MULTIGRID_UNKNOWNS`] unknowns in the region or in a nested solve.
pub fn newton_multigrid(method: Linear, unknowns: usize, nested: bool) -> bool {
    match method {
        Linear::Automatic => unknowns > MULTIGRID_UNKNOWNS || nested,
        Linear::Factor => false,
        Linear::Multigrid => true,
    }
}

/// Whether the grid of `params` has at most the [`LINEAR_UNKNOWNS`] that
/// [`Solver::Linear`] factors (three per node, an upper bound).
pub(crate) fn linear_fits(params: &GelParams) -> bool {
    let unknowns: f64 = 3.0
        * params
            .size
            .iter()
            .map(|&l| (l / params.dx).round().max(1.0) + 3.0)
            .product::<f64>();
    unknowns <= LINEAR_UNKNOWNS as f64
}
