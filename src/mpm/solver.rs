//! The seam between a gel and its equilibrium solvers.
//!
//! A [`Gel`] holds the gel: its particles at their last equilibrium, its top surface's
//! displacement, the contact loads and force of the last frame, the indenters it saw.
//! How a frame reaches equilibrium is an [`Equilibrium`]: each solver owns the state it
//! keeps between frames and is built by `build_solver` (`mod.rs`) for the [`Solver`] that
//! [`super::choice`] gave the gel (and, for the frames the gel's own solver cannot carry,
//! for the one [`super::choice::frame_fallback`] names).
//!
//! | solver | its file | the state it owns |
//! |---|---|---|
//! | [`Solver::Relaxation`] | `relax.rs` | the secant predictor's memory |
//! | [`Solver::Total`] | `total.rs` | the nodal displacements, velocities and masses |
//! | [`Solver::Newton`] | `newton/` | the region, its displacements, contact anchors and kept factors; the gel twice as coarse that starts it |
//! | [`Solver::Linear`] | `linear.rs` | the node columns' compliance, the last frame's contact points and loads |
//!
//! The relaxations move the gel's particles themselves (their grid, stencils and contact
//! memory are the gel's discretisation and stay in [`Gel`]); Newton's method and the
//! linear solver write the surface, the loads and the force from their own fields.
//!
//! A frame goes: the gel matches the indenters to the last frame's, decides whether the
//! frame needs solving at all and which solver carries it ([`Gel::solve`]); the solver
//! solves it; the gel keeps the poses for the next frame.

use std::any::Any;
use std::sync::Arc;

use super::indenters::Sweep;
use super::materials::{ConstitutiveModel, WithModel};
use super::{Gel, Placed, SolveReport, Solver, StateBounds};
use crate::geometry::Sdf;
use crate::state::Io;

/// What a solver is given of one frame.
pub(in crate::mpm) struct Frame<'a> {
    /// The frame's indenters as the caller gave them (non-finite poses included; a
    /// solver skips those).
    pub indenters: &'a [Placed],
    /// The usable indenters' motion from the last frame's poses to this frame's.
    pub sweep: &'a Sweep<'a>,
    /// For each usable indenter, which of the last frame's it is (`None`: new).
    pub matched: &'a [Option<usize>],
}

/// An equilibrium solver of a gel: one frame at a time, with the state it keeps between
/// frames.
pub(in crate::mpm) trait Equilibrium: SolverCopy + Send + Sync {
    /// Which solver this is.
    fn kind(&self) -> Solver;

    /// Brings `gel` to equilibrium under `frame`'s indenters: the gel's surface
    /// displacement, contact loads and force are the frame's after it; `report` says how.
    fn solve(&mut self, gel: &mut Gel, frame: &Frame<'_>, report: &mut SolveReport);

    /// Computes what depends on `gel` alone, before the first frame (the linear solver's
    /// surface compliance, so that its first contact is an ordinary frame). Where it
    /// cannot, the first frame that needs it tries again and reports why.
    fn prepare(&mut self, _gel: &Gel) {}

    /// Forgets every earlier frame: the next starts from the undeformed gel at rest.
    fn reset(&mut self);

    /// Writes or reads the state this solver keeps between frames ([`crate::state`]),
    /// within `bounds`, for `gel` (`shapes` names the indenters' shapes by index, as in
    /// [`Gel::persist`]). Returns whether it is kept there: a solver whose state is not
    /// (the default) starts a restored gel's next frame afresh.
    fn persist(
        &mut self,
        _io: &mut Io<'_>,
        _gel: &Gel,
        _bounds: &StateBounds,
        _shapes: &[Arc<dyn Sdf>],
    ) -> bool {
        false
    }
}

/// What every solver has by being `Clone` (given to each by one blanket
/// implementation): a copy of itself and its state, and a view for downcasting in the
/// solvers' own code and tests.
pub(in crate::mpm) trait SolverCopy {
    /// A copy of the solver and its state.
    fn boxed_clone(&self) -> Box<dyn Equilibrium>;

    /// For downcasting in the solvers' own code and tests.
    fn as_any(&self) -> &dyn Any;

    /// For downcasting in tests.
    #[cfg(test)]
    fn as_any_mut(&mut self) -> &mut dyn Any;
}

impl<T: Equilibrium + Clone + 'static> SolverCopy for T {
    fn boxed_clone(&self) -> Box<dyn Equilibrium> {
        Box::new(self.clone())
    }

    fn as_any(&self) -> &dyn Any {
        self
    }

    #[cfg(test)]
    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
}

/// A relaxation, run with the constitutive model of the gel's material, which
/// [`relax_frame`] chooses once per frame for both of them.
pub(in crate::mpm) trait Relax {
    /// Relaxes `gel` to equilibrium over `sweep` with `model`.
    fn relax<M: ConstitutiveModel>(
        &mut self,
        gel: &mut Gel,
        model: &M,
        sweep: &Sweep,
        report: &mut SolveReport,
    );
}

/// A relaxation's frame: the region it moves, the relaxation with the gel's material, the
/// bookkeeping after it.
pub(in crate::mpm) fn relax_frame(
    solver: &mut impl Relax,
    gel: &mut Gel,
    frame: &Frame<'_>,
    report: &mut SolveReport,
) {
    gel.begin_relaxation(frame.sweep, report);
    struct Run<'a, 'f, R: Relax> {
        solver: &'a mut R,
        gel: &'a mut Gel,
        sweep: &'a Sweep<'f>,
        report: &'a mut SolveReport,
    }
    impl<R: Relax> WithModel for Run<'_, '_, R> {
        type Out = ();
        fn run<M: ConstitutiveModel>(self, model: M) {
            self.solver.relax(self.gel, &model, self.sweep, self.report);
        }
    }
    let (mu, lambda, material) = (gel.mu, gel.lambda, gel.params.material);
    material.with_model(
        mu,
        lambda,
        Run {
            solver,
            gel,
            sweep: frame.sweep,
            report,
        },
    );
    gel.finish_relaxation(report);
}

impl Clone for Box<dyn Equilibrium> {
    fn clone(&self) -> Self {
        self.boxed_clone()
    }
}

impl std::fmt::Debug for dyn Equilibrium {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.kind().name())
    }
}
