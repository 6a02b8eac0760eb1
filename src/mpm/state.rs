//! The gel's state as numbers ([`crate::state`]): what its next frame depends on.
//!
//! A frame of the relaxation starts from the particles' positions and deformation
//! gradients (their velocities, stencils, bins and the grid are set afresh by its warm
//! start), the top slots' contact memory and the secant predictor's memory; the linear
//! solver from its friction history. Every frame starts from the last frame's indenter
//! poses (which indenter is which, where each sweep begins), the surface and the flags that
//! decide whether it needs solving at all. What depends on the gel alone (the layout, the
//! compliance's responses) is not state: it is rebuilt, bit for bit, from the parameters.

use std::sync::Arc;

use nalgebra::Vector3;

use super::contact::SlotContact;
use super::pressure::ContactLoad;
use super::solver::Equilibrium;
use super::transfer::Particle;
use super::{build_solver, Gel, Solver};
use crate::geometry::{Placed, Sdf};
use crate::state::{self, Io, Persist};

/// The largest counts the state of one gel holds, from which its size is bounded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StateBounds {
    /// Particles.
    pub particles: usize,
    /// Top-surface slots.
    pub slots: usize,
    /// Points of the linear solver's contact lattice.
    pub points: usize,
    /// Node columns.
    pub columns: usize,
    /// Grid nodes.
    pub nodes: usize,
    /// Points of Newton's contact lattice.
    pub newton_points: usize,
    /// Whether a frame the gel's own solver cannot carry falls back to the linear solver
    /// (else to Newton's method).
    pub linear_fallback: bool,
    /// The most numbers the state of the gel twice as coarse that starts Newton's frames
    /// takes (0 where there is none: a grid of at most
    /// [`COARSE_START_UNKNOWNS`](super::choice::COARSE_START_UNKNOWNS) unknowns).
    pub companion: usize,
    /// Indenters a frame can hold.
    pub indenters: usize,
}

impl StateBounds {
    /// The most numbers [`Gel::persist`] writes for a gel with these counts whose own
    /// solver is `solver`, with the linear fallback where `fallback`.
    pub fn gel_len(&self, solver: Solver, fallback: bool) -> usize {
        let Self {
            particles: n,
            slots: s,
            points: l,
            columns: c,
            nodes: g,
            newton_points: q,
            linear_fallback,
            companion,
            indenters: i,
        } = *self;
        let header = 16;
        // Only a relaxation moves the particles: under the other solvers they stay at rest.
        let particles = if solver.relaxes() { 17 * n } else { 0 };
        let slots = (1 + 1 + 1 + 3 + 1) * s + 3 * s;
        let loads = 1 + 6 * (s + l);
        let prev = 1 + 8 * i;
        // Each solver's own: the secant memory (per particle and per indenter), one
        // linear solver's history (anchors, lagged forces and those of the frame before,
        // the indenters' last motion, the columns' mean displacement, the kept systems'
        // bases: a flag and the columns of each), the total relaxation's nodal displacements and secant memory
        // (per node and per indenter), Newton's nodal displacements and secant memory
        // (at most three unknowns per node), stick anchors, lagged forces and loads (per
        // point of its contact lattice, and one tip point per indenter).
        let solver_len = |kind: Solver| {
            1 + match kind {
                Solver::Relaxation => 2 + 12 * n + 3 * i,
                Solver::Linear => {
                    4 + 5 * l
                        + 4 * l
                        + (1 + 4 * l)
                        + (1 + 3 * i)
                        + 3 * c
                        + (1 + super::linear::LOCAL_SYSTEMS * (2 + c))
                }
                Solver::Total => 1 + 3 * g + (1 + 3 * g) + (1 + 3 * i),
                Solver::Newton => {
                    2 + 3 * g
                        + 2 * (1 + 5 * q)
                        + (1 + 6 * (q + i))
                        + 1
                        + (1 + 3 * g)
                        + (1 + 3 * i)
                        + companion
                }
            }
        };
        let fallback = match (fallback, linear_fallback) {
            (false, _) => 0,
            (true, true) => solver_len(Solver::Linear),
            (true, false) => solver_len(Solver::Newton),
        };
        header + particles + slots + loads + prev + solver_len(solver) + fallback
    }
}

impl Persist for SlotContact {
    fn persist(&mut self, io: &mut Io<'_>) {
        self.lambda.persist(io);
        self.owner.persist(io);
        self.indenter.persist(io);
        self.anchor.persist(io);
        self.gbar.persist(io);
    }
}

impl Default for ContactLoad {
    fn default() -> Self {
        Self {
            at: [0.0; 2],
            z: 0.0,
            force: Vector3::zeros(),
        }
    }
}

impl Persist for ContactLoad {
    fn persist(&mut self, io: &mut Io<'_>) {
        self.at.persist(io);
        self.z.persist(io);
        self.force.persist(io);
    }
}

/// A particle at the start of a frame: its position and deformation gradient (with the
/// rotation and volume ratio kept beside it). Velocities are zero when a frame starts.
impl Persist for Particle {
    fn persist(&mut self, io: &mut Io<'_>) {
        self.x.persist(io);
        self.f.persist(io);
        self.q.persist(io);
        self.jr.persist(io);
        if io.loading() {
            self.v = Vector3::zeros();
            self.c = nalgebra::Matrix3::zeros();
        }
    }
}

/// A lattice box `[x0, x1) x [y0, y1)` of a lattice of `nx` by `ny`.
fn lattice_box(io: &mut Io<'_>, b: &mut Option<[usize; 4]>, [nx, ny]: [usize; 2], what: &str) {
    state::option(io, b, || [0; 4]);
    if let Some([x0, x1, y0, y1]) = *b {
        if io.loading() && !(x0 <= x1 && x1 <= nx && y0 <= y1 && y1 <= ny) {
            io.fail(|| format!("{what} [{x0}, {x1}) x [{y0}, {y1}) lies outside the gel"));
            *b = None;
        }
    }
}

/// The unknowns of Newton's method on a gel of `params`: three per grid node that a
/// particle's quadratic stencil reaches above the fixed base (a box: from the first
/// particle's stencil to the last's along each axis).
pub(super) fn newton_unknowns(params: &super::GelParams, layout: &super::Layout) -> usize {
    let [nx, ny, nz] = layout.lattice;
    let first = layout.rest_position(&params.size, 0, 0, 0).cast::<f64>();
    let last = layout
        .rest_position(&params.size, nx - 1, ny - 1, nz - 1)
        .cast::<f64>();
    let nodes = (0..3)
        .map(|k| {
            let low = (first[k] - 0.5).floor() as i64;
            let low = if k == 2 {
                low.max(super::PAD_BOTTOM as i64 + 1)
            } else {
                low
            };
            let high = (last[k] - 0.5).floor() as i64 + 2;
            (high - low + 1).max(0) as usize
        })
        .product::<usize>();
    3 * nodes
}

impl Gel {
    /// The counts that bound this gel's state with at most `indenters` indenters.
    pub fn state_bounds(&self, indenters: usize) -> StateBounds {
        Self::bounds_of(&self.params, indenters)
    }

    /// The counts that bound the state of a gel of `params`, built or not.
    pub fn bounds_of(params: &super::GelParams, indenters: usize) -> StateBounds {
        let layout = super::Layout::new(params);
        let [nx, ny, nz] = layout.lattice;
        let nodes: usize = layout.dims.iter().product();
        let companion = if newton_unknowns(params, &layout) > super::choice::COARSE_START_UNKNOWNS {
            let coarse = super::GelParams {
                dx: 2.0 * params.dx,
                ..*params
            };
            Self::bounds_of(&coarse, indenters).gel_len(Solver::Newton, false)
        } else {
            0
        };
        StateBounds {
            particles: nx * ny * nz,
            slots: nx * ny,
            points: nx * ny * super::linear::SUBDIVISION.pow(2),
            columns: layout.dims[0] * layout.dims[1],
            nodes,
            companion,
            newton_points: nx * ny * super::newton::CONTACT_SUBDIVISION.pow(2),
            linear_fallback: super::choice::linear_fits(params),
            indenters,
        }
    }

    /// Writes or reads the gel's state ([`crate::state`]); `shapes` names the indenters'
    /// shapes by their index (the same table when reading as when writing, in meaning:
    /// the scene's candidate shapes in order). Returns whether the whole state was kept:
    /// false where a solver keeps its state outside it, whose replay then starts from the
    /// undeformed gel (every solver keeps it now; a state written without it says so).
    ///
    /// A read that fails leaves the gel to be reset by the caller.
    pub fn persist(&mut self, io: &mut Io<'_>, shapes: &[Arc<dyn Sdf>]) -> bool {
        let bounds = self.state_bounds(shapes.len());
        let lattice = [self.layout.lattice[0], self.layout.lattice[1]];
        self.relaxed.persist(io);
        if self.relaxed {
            state::each(io, &mut self.particles);
        } else if io.loading() {
            self.restore_rest();
        }
        state::each(io, &mut self.contacts);
        self.persist_prev(io, shapes);
        self.force.persist(io);
        state::each(io, &mut self.surface_u);
        lattice_box(io, &mut self.surface_box, lattice, "the moved surface");
        self.resting.persist(io);
        self.last_reaction.persist(io);
        self.reaction.persist(io);
        self.clamped.persist(io);
        lattice_box(io, &mut self.last_footprint, lattice, "the last footprint");
        state::list(
            io,
            &mut self.loads,
            bounds.slots + bounds.points,
            "the contact loads",
        );
        self.gain_scale.persist(io);
        let own = self.solver.take();
        let mut kept = true;
        if let Some(mut own) = own {
            kept &= self.persist_solver(io, &mut own, &bounds, shapes);
            self.solver = Some(own);
        }
        let mut fallback = self.fallback.as_ref().map(|f| f.kind());
        let mut code = fallback.map_or(0, |k| {
            1 + Solver::ALL.iter().position(|&s| s == k).unwrap_or(0)
        });
        io.count(&mut code, Solver::ALL.len() + 1, "the fallback solver");
        if io.loading() && io.fault().is_none() {
            fallback = code.checked_sub(1).map(|k| Solver::ALL[k]);
            if fallback != self.fallback.as_ref().map(|f| f.kind()) {
                self.fallback = fallback.map(build_solver);
            }
        }
        if let Some(mut f) = self.fallback.take() {
            kept &= self.persist_solver(io, &mut f, &bounds, shapes);
            self.fallback = Some(f);
        }
        kept
    }

    fn persist_solver(
        &mut self,
        io: &mut Io<'_>,
        solver: &mut Box<dyn Equilibrium>,
        bounds: &StateBounds,
        shapes: &[Arc<dyn Sdf>],
    ) -> bool {
        let pool = self.pool;
        let gel = &*self;
        pool.install(|| solver.persist(io, gel, bounds, shapes))
    }

    /// The last frame's indenters: each one's shape (its index in `shapes`) and pose.
    fn persist_prev(&mut self, io: &mut Io<'_>, shapes: &[Arc<dyn Sdf>]) {
        let mut prev: Vec<Placed> = self
            .prev
            .iter()
            .map(|(shape, pose)| Placed {
                shape: shape.clone(),
                pose: *pose,
            })
            .collect();
        state::placed(io, &mut prev, shapes, "the last frame's indenters");
        if io.loading() && io.fault().is_none() {
            self.prev = prev.into_iter().map(|p| (p.shape, p.pose)).collect();
        }
    }
}

impl Persist for super::newton::Anchor {
    fn persist(&mut self, io: &mut Io<'_>) {
        self.indenter.persist(io);
        self.local.persist(io);
    }
}

impl Persist for super::Wrench {
    fn persist(&mut self, io: &mut Io<'_>) {
        self.force.persist(io);
        self.torque.persist(io);
    }
}

#[cfg(test)]
mod tests {
    use super::super::{GelParams, SolverOptions};
    use super::*;
    use crate::geometry::{Cuboid, Placed, Sphere};
    use nalgebra::Isometry3;

    /// A 12 x 12 x 3 mm gel at 1 mm with friction 0.8: small enough for a test, with
    /// every kind of state (stick anchors, the secant memory, a fallback).
    fn params() -> GelParams {
        GelParams {
            size: [0.012, 0.012, 0.003],
            dx: 1e-3,
            friction: 0.8,
            ..Default::default()
        }
    }

    fn shapes() -> Vec<Arc<dyn Sdf>> {
        vec![
            Arc::new(Sphere { radius: 3e-3 }),
            Arc::new(Cuboid::new(Vector3::new(0.01, 0.01, 1e-3))),
            Arc::new(Sphere { radius: 0.2e-3 }),
        ]
    }

    /// Shape `i` of `shapes` with its lowest point `d` below the undeformed face at (x, y).
    fn at(shapes: &[Arc<dyn Sdf>], i: usize, x: f64, y: f64, d: f64) -> Placed {
        let half_height = [3e-3, 1e-3, 0.2e-3][i];
        Placed {
            shape: shapes[i].clone(),
            pose: Isometry3::translation(x, y, half_height - d),
        }
    }

    /// A frictional press and slide of a sphere, then a second small sphere beside it:
    /// frames that leave anchors, a secant memory and (for the small one, which the
    /// relaxation's contact points miss) the linear fallback's history.
    fn frames(s: &[Arc<dyn Sdf>]) -> Vec<Vec<Placed>> {
        let mut frames = Vec::new();
        for k in 0..4 {
            let x = 0.4e-3 * k as f64;
            frames.push(vec![at(s, 0, x, 0.0, 0.4e-3 + 0.1e-3 * k as f64)]);
        }
        frames.push(vec![at(s, 2, -3e-3, 2e-3, 0.05e-3)]);
        frames.push(vec![at(s, 0, 1.4e-3, 0.3e-3, 0.6e-3)]);
        frames.push(vec![at(s, 0, 1.6e-3, 0.5e-3, 0.5e-3)]);
        frames
    }

    fn save(gel: &mut Gel, shapes: &[Arc<dyn Sdf>]) -> (Vec<f64>, bool) {
        let mut buf = vec![
            0.0;
            gel.state_bounds(shapes.len())
                .gel_len(gel.options.solver, gel.options.fallback,)
        ];
        let mut io = Io::save(&mut buf);
        let kept = gel.persist(&mut io, shapes);
        assert!(!io.overflowed(), "{} > {}", io.position(), buf.len());
        let n = io.position();
        buf.truncate(n);
        (buf, kept)
    }

    fn outcome(gel: &Gel) -> Vec<u64> {
        let f = gel.force();
        let loads = gel
            .loads
            .iter()
            .flat_map(|l| [l.at[0], l.at[1], l.z, l.force.z]);
        let surface = gel.surface_u.iter().flat_map(|u| [u.x, u.y, u.z]);
        f.iter()
            .copied()
            .chain(loads)
            .chain(surface)
            .map(f64::to_bits)
            .collect()
    }

    /// The solvers whose state is kept: the relaxation with its linear fallback, and the
    /// linear solver, each on one thread.
    fn solvers() -> [SolverOptions; 2] {
        [(Solver::Relaxation, true), (Solver::Linear, false)].map(|(solver, fallback)| {
            SolverOptions {
                solver,
                fallback,
                threads: 1,
                ..Default::default()
            }
        })
    }

    #[test]
    fn a_gel_read_back_replays_the_original_bit_for_bit() {
        for options in solvers() {
            let (solver, fallback) = (options.solver, options.fallback);
            let s = shapes();
            let frames = frames(&s);
            let (head, tail) = frames.split_at(3);
            let mut original = Gel::new(params(), options).unwrap();
            for f in head {
                original.solve(f);
            }
            let (state, kept) = save(&mut original, &s);
            assert!(kept, "{solver:?}");
            // Read into a fresh gel, with its own copies of the shapes (another mjData's):
            // the shapes are named by index.
            let other: Vec<Arc<dyn Sdf>> = shapes();
            let mut restored = Gel::new(params(), options).unwrap();
            let mut io = Io::load(&state);
            assert!(restored.persist(&mut io, &other));
            assert_eq!(io.fault(), None);
            assert_eq!(io.position(), state.len());
            assert_eq!(
                save(&mut restored, &other).0,
                state,
                "{solver:?}: read, written"
            );
            let mut fresh = Gel::new(params(), options).unwrap();
            let (mut fallbacks, mut history) = (0, false);
            for (k, f) in tail.iter().enumerate() {
                let a = original.solve(f);
                let placed: Vec<Placed> = f
                    .iter()
                    .map(|p| {
                        let i = s.iter().position(|x| Arc::ptr_eq(x, &p.shape)).unwrap();
                        Placed {
                            shape: other[i].clone(),
                            pose: p.pose,
                        }
                    })
                    .collect();
                let b = restored.solve(&placed);
                fresh.solve(f);
                fallbacks += usize::from(a.fallback);
                assert_eq!(a.fallback, b.fallback);
                let same = outcome(&original) == outcome(&restored);
                assert!(same, "{solver:?}, frame {k}: the replay differs");
                history |= outcome(&original) != outcome(&fresh);
            }
            if fallback {
                assert!(fallbacks > 0, "the frames exercise the linear fallback");
            }
            assert!(history, "{solver:?}: a fresh gel gives the same frames");
        }
    }

    #[test]
    fn the_declared_length_holds_the_largest_state() {
        // A box pressing the whole face with friction and dragged (an anchor and a load
        // at every contact point), beside spheres: each list at its largest.
        for options in solvers() {
            let (solver, fallback) = (options.solver, options.fallback);
            let s = shapes();
            let mut gel = Gel::new(params(), options).unwrap();
            for k in 0..3 {
                let x = 0.1e-3 * k as f64;
                gel.solve(&[
                    at(&s, 1, x, 0.0, 0.2e-3),
                    at(&s, 0, 2e-3, x, 0.3e-3),
                    at(&s, 2, -4e-3, 4e-3, 0.1e-3),
                ]);
            }
            let bounds = gel.state_bounds(s.len());
            assert_eq!(
                bounds,
                Gel::bounds_of(&params(), s.len()),
                "bounds of a built gel and of its parameters"
            );
            let (state, _) = save(&mut gel, &s);
            let declared = bounds.gel_len(solver, fallback);
            assert!(
                state.len() <= declared,
                "{solver:?}: {} > {declared}",
                state.len()
            );
        }
    }

    #[test]
    fn a_state_with_an_index_out_of_range_is_refused() {
        let s = shapes();
        let options = SolverOptions {
            threads: 1,
            ..Default::default()
        };
        let mut gel = Gel::new(params(), options).unwrap();
        gel.solve(&[at(&s, 0, 0.0, 0.0, 0.4e-3)]);
        let (state, _) = save(&mut gel, &s);
        // The same state read with a table of one shape: the sphere's index is 0, so it
        // reads; with no shapes it names the indenters' list.
        let mut io = Io::load(&state);
        Gel::new(params(), options).unwrap().persist(&mut io, &[]);
        let fault = io.fault().expect("refused");
        assert!(fault.contains("the last frame's indenters"), "{fault}");
    }
}
