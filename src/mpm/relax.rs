//! The quasi-static solve: dynamic relaxation to equilibrium, and its convergence test.
//!
//! Dynamic relaxation: explicit steps with mass-proportional damping `v <- v / (1 + c)`,
//! `c = 2 zeta omega_1`, tuned to the lowest mode of the bonded layer, the thickness-shear
//! quarter wave `omega_1 = (pi / 2) c_s / T` (`zeta` = [`SolverOptions::damping`], 1 for
//! critical). Every mode then decays at least like `exp(-omega_1 t)`. Each solve starts
//! from the previous equilibrium (warm start) with zero velocity, moved on by the secant
//! predictor when the indenters move on along their last path ([`Gel::predict`]: the
//! active particles' last change of position and `F`, scaled by how far along that path
//! they move now; it saves steps on a steady moving press and brings the force nearer a
//! tight solve's; measured: `docs/solvers.md`, "Two solvers and a third"). It stops when
//! the largest out-of-balance nodal force (stress plus contact force left after the
//! constraints, plus the damping force) divided by the force scale is below
//! [`SolverOptions::tolerance`], or after [`Gel::iteration_cap`] steps. The
//! force scale is the largest nodal reaction (bonded nodes, contact load) of this step or
//! of the previous equilibrium (so that unloading is measured against the load it
//! releases), and at least `1e-4 mu dx^2` (a strain of `1e-4`).
//!
//! The force scale also counts the mean contact force per cell of contact area (mean
//! pressure times `dx^2`), and the residual the constraint error `k |g|` of every loaded
//! surface point.
//!
//! The material is chosen once per solve (`solver::relax_frame`, for both relaxations):
//! the relaxation and its steps are generic over the [`ConstitutiveModel`].
//!
//! [`SolverOptions::damping`]: super::SolverOptions::damping
//! [`SolverOptions::tolerance`]: super::SolverOptions::tolerance

use nalgebra::{Matrix3, Vector3};

use super::contact::{self, ContactInput, SlotContact};
use super::indenters::Sweep;
use super::materials::ConstitutiveModel;
use super::solver::{relax_frame, Equilibrium, Frame, Relax};
use super::transfer::{self, P2gInput, Particle};
use super::{Gel, Snapshot, SolveReport, Solver, StateBounds};
use crate::geometry::Sdf;
use crate::state::{self, Io};
use std::sync::Arc;

/// A solve's change (largest particle displacement) must exceed this many times the
/// tolerance times the gel's deformation (largest surface displacement, from the solve
/// before) for the next solve to extrapolate it ([`Gel::predict`]).
const PREDICT_ABOVE: f64 = 10.0;

/// Steps after the sweep over which the residual's progress is judged, for the contact
/// multipliers' gain ([`Gel::iterate`]).
///
/// The multipliers integrate the gap with a gain that falls with the number of cells
/// through the layer ([`contact::multiplier_gain`]), chosen on spheres for speed. A wide
/// flat contact answers a multiplier change through the layer's uniform compression, a
/// stiffer loop, which on a finer grid oscillated until the iteration cap far from
/// equilibrium (measured: `docs/solvers.md`, "A wide flat contact on a finer grid: the
/// multipliers' gain"). Halving the gain whenever a window of steps brings no progress
/// ends the oscillation; a solve whose residual at least halves from one window to the
/// next, or stays within [`STALLED`] times the tolerance, is untouched (and the gain
/// plays no part in the equilibrium).
const GAIN_WINDOW: usize = 500;

/// A window of steps counts as stalled only while its least residual is above this many
/// times the tolerance, above where the relaxation's slow creep sits (measured:
/// `docs/solvers.md`, "A wide flat contact on a finer grid: the multipliers' gain").
const STALLED: f64 = 10.0;

/// The gain is halved at most down to this fraction.
const MIN_GAIN_SCALE: f32 = 1.0 / 16.0;

/// What the convergence test reads after a step.
struct StepOutcome {
    /// Largest out-of-balance force over the force scale.
    residual: f64,
    /// Whether a non-finite value appeared.
    nonfinite: bool,
    /// Smallest `det F` over the active particles.
    det_min: f64,
    /// Largest `det F` over the active particles.
    det_max: f64,
}

/// The updated-Lagrangian dynamic relaxation ([`Solver::Relaxation`]). It moves the gel's
/// own particles; what it keeps of its own is the secant predictor's memory.
#[derive(Clone, Default)]
pub(super) struct Relaxation {
    /// Each particle's change of position and deformation gradient over the last solve
    /// (empty when there is none to use), and the indenters' translations (m) in it.
    pub(super) last_change: Vec<(Vector3<f32>, Matrix3<f32>)>,
    pub(super) last_motion: Vec<Vector3<f64>>,
}

#[cfg(test)]
impl Gel {
    /// The relaxation's state, where the gel runs it.
    pub(super) fn relaxation(&self) -> Option<&Relaxation> {
        self.own_solver::<Relaxation>()
    }
}

impl Equilibrium for Relaxation {
    fn kind(&self) -> Solver {
        Solver::Relaxation
    }

    fn solve(&mut self, gel: &mut Gel, frame: &Frame<'_>, report: &mut SolveReport) {
        relax_frame(self, gel, frame, report);
    }

    fn reset(&mut self) {
        self.last_change.clear();
        self.last_motion.clear();
    }

    /// The secant memory: each particle's change over the last solve, or none.
    fn persist(
        &mut self,
        io: &mut Io<'_>,
        _gel: &Gel,
        bounds: &StateBounds,
        _shapes: &[Arc<dyn Sdf>],
    ) -> bool {
        state::list(
            io,
            &mut self.last_change,
            bounds.particles,
            "the secant memory",
        );
        state::list(
            io,
            &mut self.last_motion,
            bounds.indenters,
            "the secant motion",
        );
        true
    }
}

impl Relax for Relaxation {
    fn relax<M: ConstitutiveModel>(
        &mut self,
        gel: &mut Gel,
        model: &M,
        sweep: &Sweep,
        report: &mut SolveReport,
    ) {
        gel.relax(model, sweep, self, report);
    }
}

impl Relaxation {
    /// Keeps each particle's change over a converged solve, and the indenters' motion in
    /// it, for the next solve's [`Gel::predict`]; forgets them after any other, and when
    /// the change is within [`PREDICT_ABOVE`] times the solve's tolerance of the gel's
    /// deformation: a solve stops that far from the exact equilibrium, so such a change is
    /// mostly that error, and extrapolating it would add to the next one (a body resting
    /// on a coupled gel then jitters).
    fn remember_change(&mut self, gel: &Gel, motion: Vec<Vector3<f64>>, report: &SolveReport) {
        self.last_change.clear();
        self.last_motion.clear();
        if !report.converged || report.nonfinite_recovered {
            return;
        }
        let moved = gel
            .particles
            .iter()
            .zip(&gel.snapshot)
            .map(|(p, s)| (p.x - s.x).norm())
            .fold(0.0f32, f32::max) as f64;
        let deformed = gel.surface_u.iter().map(|u| u.norm()).fold(0.0, f64::max) / gel.layout.dx;
        if moved <= PREDICT_ABOVE * gel.options.tolerance * deformed {
            return;
        }
        self.last_change.extend(
            gel.particles
                .iter()
                .zip(&gel.snapshot)
                .map(|(p, s)| (p.x - s.x, p.f - s.f)),
        );
        self.last_motion = motion;
    }
}

impl Gel {
    /// Dynamic relaxation of the active region from the current state at rest, the
    /// indenters moving as `sweep` says, until the residual is below the tolerance after
    /// the sweep, a non-finite value appears (the gel is then restored, see
    /// [`Gel::recover`]) or [`Gel::iteration_cap`] steps.
    fn relax<M: ConstitutiveModel>(
        &mut self,
        model: &M,
        sweep: &Sweep,
        memory: &mut Relaxation,
        report: &mut SolveReport,
    ) {
        let motion = self.warm_start(sweep, memory);
        self.iterate(&mut (), sweep, report, |g, _| g.step(model), |_, _| {});
        memory.remember_change(self, motion, report);
    }

    /// The explicit steps of a relaxation (`step`: one step on the gel and the solver's
    /// `state`, returning the contact force on the gel) with the indenters moving as
    /// `sweep` says, until the residual is below the tolerance after the sweep, a
    /// non-finite value appears (`restore` and [`Gel::recover`] then bring back the state
    /// at the start) or [`Gel::iteration_cap`] steps.
    pub(super) fn iterate<S>(
        &mut self,
        state: &mut S,
        sweep: &Sweep,
        report: &mut SolveReport,
        mut step: impl FnMut(&mut Gel, &mut S) -> [f64; 3],
        mut restore: impl FnMut(&mut Gel, &mut S),
    ) {
        let tol = self.options.tolerance;
        self.gain_scale = 1.0;
        let (mut window_min, mut last_min) = (f64::INFINITY, f64::INFINITY);
        for it in 0..self.iteration_cap() {
            sweep.place(it, self.layout.dx, &mut self.step_ind);
            let f = step(self, state);
            let out = self.measure(f);
            report.iterations = it + 1;
            if out.nonfinite {
                restore(self, state);
                self.recover();
                report.nonfinite_recovered = true;
                report.converged = false;
                report.residual = f64::INFINITY;
                break;
            }
            report.residual = out.residual;
            report.det_f_min = out.det_min;
            report.det_f_max = out.det_max;
            report.converged = it + 1 >= sweep.steps && out.residual <= tol;
            if report.converged {
                break;
            }
            // A multiplier loop that oscillates: over a window of steps after the sweep
            // the residual never came down to half its least value in the window before,
            // and stays far above the tolerance. Halve the multipliers' gain.
            if it >= sweep.steps {
                window_min = window_min.min(out.residual);
                if (it + 1 - sweep.steps) % GAIN_WINDOW == 0 {
                    if window_min > STALLED * tol
                        && window_min > 0.5 * last_min
                        && self.gain_scale > MIN_GAIN_SCALE
                    {
                        self.gain_scale *= 0.5;
                        report.gain_halvings += 1;
                    }
                    (last_min, window_min) = (window_min, f64::INFINITY);
                }
            }
        }
    }

    /// The secant predictor (as the Newton solver's): when the indenters move on along
    /// the path of the last solve, the active particles are first moved on by the same
    /// multiple of their last change of position and deformation gradient, so that the
    /// relaxation starts near the new equilibrium rather than at the old one. Returns the
    /// indenters' translations in this solve (m). The stencils are the caller's to update.
    fn predict(&mut self, sweep: &Sweep, memory: &Relaxation) -> Vec<Vector3<f64>> {
        let motion = sweep.motion();
        if memory.last_change.len() != self.particles.len() {
            return motion;
        }
        let Some(s) = super::secant_scale(&motion, &memory.last_motion) else {
            return motion;
        };
        let s = s as f32;
        let nzp = self.ctx.column_len;
        let [x0, x1, y0, y1] = self.ctx.region.lattice;
        let nyp = self.layout.lattice[1];
        for ix in x0..x1 {
            for iy in y0..y1 {
                let first = (ix * nyp + iy) * nzp;
                for k in first..first + nzp {
                    let (dx, df) = &memory.last_change[k];
                    let p = &mut self.particles[k];
                    p.x += dx * s;
                    p.f += df * s;
                }
            }
        }
        motion
    }

    /// Records the state the solve starts from (the last equilibrium, for
    /// [`Gel::recover`] and for the change [`Relaxation::remember_change`] keeps), sets every
    /// particle at rest, moves it on by [`Gel::predict`] and computes the stencils once.
    /// Returns the indenters' translations in this solve (m).
    fn warm_start(&mut self, sweep: &Sweep, memory: &Relaxation) -> Vec<Vector3<f64>> {
        for (s, p) in self.snapshot.iter_mut().zip(&mut self.particles) {
            *s = Snapshot::of(p);
            p.v = Vector3::zeros();
            p.c = Matrix3::zeros();
        }
        let motion = self.predict(sweep, memory);
        transfer::compute_stencils(&self.particles, &mut self.stencils);
        self.binned = false;
        motion
    }

    /// This step's contact forces on the top particles' surface points (their
    /// multipliers and stick anchors updated), the multipliers integrating the gap
    /// low-pass filtered with weight `filter` (1: the gap itself).
    pub(super) fn update_contacts(&mut self, filter: f32) {
        let Gel {
            pool,
            layout,
            ctx,
            particles,
            top,
            half_top,
            contacts,
            active,
            step_ind,
            params,
            gain_scale,
            ..
        } = self;
        pool.install(|| {
            let input = ContactInput {
                layout,
                half_top: *half_top,
                particles,
                top,
                indenters: step_ind,
                friction: params.friction as f32,
                gain: contact::multiplier_gain(params.size[2] / layout.dx) * *gain_scale,
                filter,
                region: &ctx.region,
            };
            contact::update_contacts(&input, contacts, active);
        });
    }

    /// One MLS-MPM step: the contact forces of the top particles, then the four parts
    /// (see [`transfer`]): clear the grid and particle-to-grid (binning the particles
    /// first when they changed bins), the contact forces onto the grid, grid update,
    /// grid-to-particle. Returns the total contact force on the gel (internal units).
    fn step<M: ConstitutiveModel>(&mut self, model: &M) -> [f64; 3] {
        self.update_contacts(1.0);
        let Gel {
            pool,
            ctx,
            particles,
            active,
            grid,
            order,
            offsets,
            cursor,
            stencils,
            binned,
            layer_stats,
            chunk_stats,
            ..
        } = self;
        let ctx = &*ctx;
        pool.install(|| {
            if !*binned {
                transfer::bin_particles(ctx, stencils, order, offsets, cursor);
                *binned = true;
            }
            let input = P2gInput {
                particles,
                stencils,
                order,
                offsets,
            };
            transfer::particle_to_grid(ctx, model, &input, grid);
            let f = contact::scatter_contacts(ctx, stencils, active, grid);
            transfer::grid_update(ctx, grid, layer_stats);
            transfer::grid_to_particle(ctx, grid, particles, stencils, chunk_stats);
            f
        })
    }

    /// The convergence test after a step whose contact force on the gel was `f`: the
    /// relative residual, the force on the indenters ([`Gel::force`]), the step's largest
    /// reaction, and the particles' state (non-finite values, `det F` range, whether any
    /// left its bin).
    fn measure(&mut self, f: [f64; 3]) -> StepOutcome {
        let layout = &self.layout;
        let mut residual = 0.0f32;
        let mut reaction = (1e-4 * self.mu).max(self.last_reaction);
        let mut step_reaction = 0.0f32;
        for s in &self.layer_stats {
            residual = residual.max(s.residual);
            step_reaction = step_reaction.max(s.reaction);
        }
        // Contact load scale: the mean contact force per cell of contact area (the
        // mean pressure times dx^2), comparable to a nodal force.
        let mut count = 0usize;
        for a in self.active.iter().flatten() {
            residual = residual.max(a.residual);
            count += 1;
        }
        if count > 0 {
            let area = count as f64 * layout.spacing[0] * layout.spacing[1] / layout.dx.powi(2);
            let load = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt() / area;
            step_reaction = step_reaction.max(load as f32);
        }
        reaction = reaction.max(step_reaction);
        let scale = self.modulus * layout.dx * layout.dx;
        // The gel pushes the indenters with the opposite of the contact forces.
        self.force = -Vector3::from(f) * scale;
        self.reaction = step_reaction;
        let mut nonfinite = !residual.is_finite() || !self.force.iter().all(|v| v.is_finite());
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for s in &self.chunk_stats {
            nonfinite |= s.nonfinite;
            self.binned &= !s.moved;
            lo = lo.min(s.det_min);
            hi = hi.max(s.det_max);
        }
        StepOutcome {
            residual: (residual / reaction) as f64,
            nonfinite,
            det_min: lo as f64,
            det_max: hi as f64,
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
                    c: Matrix3::zeros(),
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

    /// Smallest and largest `det F` over all particles.
    pub(super) fn det_range(&self) -> (f64, f64) {
        self.particles
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                let j = p.f.determinant() as f64;
                (lo.min(j), hi.max(j))
            })
    }
}
