//! The quasi-static equilibrium as the minimum of the total potential energy, by Newton's
//! method ([`super::Solver::Newton`]).
//!
//! # Discretisation
//!
//! The unknowns are the displacements `u_i` of the free grid nodes (every node that a
//! quadrature point's stencil reaches, above the bonded bottom plane). As in implicit MPM
//! (Gast et al. 2015) in its total Lagrangian form, each quadrature point keeps the
//! quadratic B-spline weights `w_i(X)` of its rest position `X`, so
//! `F = I + sum_i u_i grad w_i(X)^T` and the displacement of any material point is
//! `sum_i w_i(X) u_i`. The quadrature points are the particles of the lattice (volume
//! `s_x s_y s_z` each). For Poisson's ratios above [`super::FBAR_POISSON`] the part of the
//! volume term beyond that ratio's moves to one point per cell of eight particles
//! (selective reduced integration, Hughes 1980, the energy counterpart of the relaxation's
//! F-bar): the particles keep the first Lame parameter `lambda_c = 2 mu nu_c / (1 - 2
//! nu_c)` of `nu_c = FBAR_POISSON`, the cells take `lambda - lambda_c`. About one volume
//! constraint per node carries the stiff part, so the near-incompressible gel does not
//! lock, and the gel is continuous in Poisson's ratio across the threshold. The whole
//! volume term on the cells alone (as the relaxation's F-bar smooths all of `J`) left the
//! coarse grid far too soft: the cell points miss volume changes that the particles see,
//! and those were held by the shear modulus only. The particles keeping more (the
//! `lambda` of 0.47 or 0.49) locked a small contact (measured: `docs/solvers.md`, "Two
//! solvers and a third").
//!
//! # Energy
//!
//! `E(u) = sum_p V_p psi(F_p) + E_contact + E_friction`:
//! * contact on a lattice of surface points [`CONTACT_SUBDIVISION`] times finer than the
//!   particles, each standing for its share `A` of the top face: a penalty
//!   `k A g^2 / 2` on the signed distance `g < 0` to the nearest indenter
//!   (`k = dx / (PENETRATION T)` per cell, see [`PENETRATION`]; the penetration it leaves
//!   is `p / k`, 1.4 um on the default 4 mm gel at a pressure of `M` on every grid). An indenter that reaches
//!   between particles still meets surface points, and one that reaches between the
//!   lattice's points gets a tip point; a patch smaller than
//!   the grid resolves gets the compliance the grid misses in series with its penalty
//!   (see `subgrid.rs`);
//! * Coulomb friction as a lagged dissipation potential (as IPC does, Li et al. 2020):
//!   each surface point in contact keeps a stick anchor fixed in the indenter's frame; its
//!   tangential offset `y` from the anchor costs `mu f_n f0(y)`, with `f0` quadratic below
//!   [`STICK`] cells and linear beyond (full sliding force `mu f_n`), `f_n` and the normal
//!   lagged (refreshed within the minimisation once it is near equilibrium, and between
//!   minimisations). After a solve the anchors of sliding points move
//!   so that the offset is at most [`STICK`] (return mapping), so a contact keeps its shear
//!   history across frames.
//!
//! # Solve
//!
//! Newton's method: the Hessian assembled from each point's projected stress derivative
//! (see `energy.rs`) plus the Gauss-Newton terms of contact and friction (a sliding
//! point's friction by the quadratic that majorizes it, see [`Newton::contact_term`]),
//! solved by a sparse Cholesky factorisation (faer; the fill-reducing ordering is
//! computed once per region). A factorisation is kept: later steps solve by conjugate
//! gradients preconditioned with it, the Hessian's products taken point by point from the
//! tangents of the evaluation (no assembly), and the matrix is assembled and factored afresh only
//! when that does not converge within [`REUSE_ITERATIONS`] to the step's forcing term
//! (loose while the residual falls slowly, as far from the minimum, where the contact set
//! still changes; [`forcing`]). Regions of more than
//! [`MULTIGRID_UNKNOWNS`] unknowns are not factored: each step is solved by conjugate
//! gradients preconditioned with a two-grid cycle built for it (`multigrid.rs`; see
//! [`super::Linear`]). The points are evaluated in
//! parallel and their forces (and Hessian products) added in parallel in a fixed order,
//! by slabs of points (`slabs.rs`), so threads do not change the result.
//! Then a backtracking line search that accepts a step only if the energy does not
//! increase (Armijo); its trials are evaluated whole, so the accepted one's evaluation
//! starts the next step. It stops when the largest out-of-balance nodal force is below
//! [`super::SolverOptions::tolerance`] times the load scale (the largest nodal contact
//! force, at least a strain of 1e-4 over a cell). With friction the lagged normal forces
//! start from those of the last substep; they are refreshed within the minimisation once
//! its residual is below [`LAG_BELOW`] (see [`Newton::minimise`]), and then (with the tip
//! points) between minimisations until their sum changes by less than the tolerance. Each frame starts from the previous
//! equilibrium, moved on along the gel's last change when the indenters move on along
//! their last path (a secant predictor, kept only if it lowers the energy); an indenter
//! that moves more than [`SUBSTEP_CELLS`] cells (a body smaller than [`SMALL_BODY_CELLS`]
//! in every direction: more than [`SOFT_EXTENT`] of its size; any other body: more than
//! half its smallest extent, though never less than half a cell) is moved in equal
//! substeps, each solved, so friction follows the path.
//!
//! # Coarse start
//!
//! On a gel of more than [`super::SolverOptions::coarse_start_above`] unknowns (by
//! default [`super::COARSE_START_UNKNOWNS`]: the default gel at 0.7 mm and finer), a
//! frame where the secant predictor has nothing to offer (a press from rest, a change of
//! direction; see [`Newton::predict`]) is first solved, substep by substep, on a
//! companion gel twice as coarse (the same parameters and options; the rule applies
//! again there), and its displacement change over each substep, read at this grid's
//! nodes through its B-splines, is the first iterate's change of the same substep here.
//! The companion follows every other frame in one solve, so that its change is at hand
//! when needed. A Newton step sheds or gains contact
//! points about a ring at a time, so a fine press from the previous equilibrium takes
//! many steps to find its contact patch; the coarse gel finds it at an eighth of the
//! cost per step, and the fine one starts within a coarse lattice spacing of it. The
//! answer does not depend on it (it is a start, not a constraint):
//! `the_coarse_start_keeps_the_answer_and_saves_newton_steps`.
//!
//! # Nested solve
//!
//! A gel with a coarse start solves only a small region (global-local analysis, or
//! sub-modelling): the contact footprint grown by [`super::SolverOptions::nested_margin`]
//! thicknesses (0.5 by default) instead of the active margin (1.5), and the nodes outside
//! it take the coarse start's displacement, read through its B-splines, instead of being
//! held where they were: at each substep's end pose that of the coarse gel's solve of the
//! substep (a frame without a secant prediction) or its solve of the frame shared out
//! evenly over the substeps (one with). Away from the contact the field is smooth and
//! the coarse grid resolves it; the fine grid is needed only where the contact is. The
//! region's two-grid cycle is kept however few its unknowns (its Newton steps are those
//! the fine gels are measured on; the factorisation's forcing term took more here).
//! Where the coarse gel's solve does not converge, the nodes outside stay where they
//! were. `a_nested_solve_agrees_with_the_whole_gel`. The coarse gel itself is not nested:
//! nested in its own coarse start, the fine gel's boundary would read that one's field
//! (measured: `docs/solvers.md`, "A nested solve: the fine grid only near the contact").
//!
//! Contact acts on the top surface only: a body pressed deeper than its own radius can
//! take surface points around itself (they are pushed out along the nearest distance,
//! which past its centre points up), so its force drops to zero or below, before the
//! sub-grid compliance as after; bodies pressed less than their radius are not affected
//! (measured: `docs/solvers.md`, "What the relaxation's answer depends on").

pub(in crate::mpm) mod energy;
mod multigrid;
mod slabs;
pub(super) mod subgrid;
pub(super) mod system;
#[cfg(test)]
pub(in crate::mpm) mod tests;

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use rayon::prelude::*;

use super::contact::{StepIndenter, CONTACT_BAND};
use super::indenters::Sweep;
use super::solver::{Equilibrium, Frame};
use super::{
    Gel, GelParams, Layout, Linear, SolveReport, Solver, SolverOptions, StateBounds, FBAR_POISSON,
    J_MAX, J_MIN, MULTIGRID_UNKNOWNS, PAD_BOTTOM,
};
use crate::geometry::{Aabb, Placed, Sdf};
use crate::state::{self, Io, Persist};
use energy::Density;
use multigrid::TwoGrid;
use slabs::Slabs;
use std::sync::Arc;
use system::{conjugate_gradients, System};

/// Surface contact points per particle spacing along each axis.
pub(crate) const CONTACT_SUBDIVISION: usize = 4;

/// Least support (cells of height: a column of points' vertical spacings times their
/// B-spline weights on it; 1 inside the gel) of a layer of nodes that are unknowns; the
/// nodes of a layer below it are held fixed. A gel whose top lies about three quarters of
/// a cell above its top points' stencils otherwise has a layer of nodes its points barely
/// reach: nearly free unknowns that the contact points' stencils weigh a few per cent, so
/// that the surface sank under an indenter with almost no force (a gel 3.75 cells thick
/// pressed 0.3 mm: 12 % of the force of one 3.7 cells thick, and 3.8 cells thick 80 %;
/// `linear_tests.rs`, `a_gel_of_any_thickness_resists_a_press`). The default gel's top
/// layer has 3.4e-3 and stays free.
pub(crate) const MIN_LAYER_SUPPORT: f64 = 2e-3;

/// Contact penalty stiffness of the linear solver (internal units: `M` per cell of
/// penetration).
pub(crate) const PENALTY: f64 = 1e3;

/// The penetration (in gel thicknesses) that Newton's contact penalty leaves under a
/// pressure of the shear modulus `M`, on every grid: its stiffness is `dx / (PENETRATION
/// T)` in internal units (`M` per cell), 1,000 on the default gel's 1.4 mm grid (1.4 um)
/// and 214 at 0.3 mm ([`Newton::penalty`]). A penalty of 1,000 per cell on every grid is
/// physically stiffer the finer the grid, and at 0.3 mm its springs made Newton's contact
/// set chatter and the two-grid cycle weak (see `docs/solvers.md`, "The contact penalty
/// in physical units"). It is a fraction of the thickness, not a length, so that a gel
/// scaled with its grid and indenters gives the same answer scaled (the relaxation's and
/// the linear solver's penalties are set per cell:
/// `a_scaled_press_is_the_press_scaled`); on the default gel it is the 1.4 um it was.
pub(crate) const PENETRATION: f64 = 3.5e-4;

/// Tangential offset (cells) at which friction reaches its sliding value.
pub(crate) const STICK: f64 = 1e-3;

/// Contact lattice points farther than this (cells) from every indenter at the start of a
/// substep are left out of its solve (and checked after it): a substep moves an indenter
/// by at most [`SUBSTEP_CELLS`], and the gel's surface by no more.
const CULL_CELLS: f64 = 2.0 * SUBSTEP_CELLS;

/// Largest indenter motion (cells) solved in one go.
pub(crate) const SUBSTEP_CELLS: f64 = 1.0;

/// Depth up to which a softened contact point's spring acts, as a fraction of its
/// indenter's smallest extent ([`Newton::normal_penalty`]), and the largest motion per
/// substep of a small body ([`SMALL_BODY_CELLS`]) in the same measure.
const SOFT_EXTENT: f64 = 0.25;

/// Bodies whose every extent is below this (cells) move in substeps of at most
/// [`SOFT_EXTENT`] of their smallest extent.
const SMALL_BODY_CELLS: f64 = 2.0;

/// Relative residual below which a Newton step refreshes friction's lagged normal forces.
const LAG_BELOW: f64 = 0.03;

/// Newton steps per minimisation at most.
const MAX_NEWTON: usize = 60;

/// Newton steps per frame at most, over all its substeps, splits and lagged-term
/// refreshes: ten minimisations' worth. A frame that spends them ends where its last
/// minimisation got to (each accepted step lowered the energy), short of the indenters'
/// poses, and says so ([`SolveReport::work_bound`]); the next frame carries on from
/// there. Counted, not timed, so that the answer does not depend on the machine. The
/// stability suite's frames take at most 181 (336 for the press through the gel's
/// bottom, which cannot converge); a box slid and turned across a 37 mm gel at friction
/// 1.85, whose lagged friction forces cycle, took 4,968 in one frame (4.5 minutes)
/// before this bound (measured: `docs/solvers.md`, "A bound on a frame's Newton
/// steps").
const FRAME_NEWTON: usize = 10 * MAX_NEWTON;

/// A substep whose minimisation ends with a relative residual above this many times the
/// tolerance (or in an undefined state) has not found an equilibrium but stalled: it is
/// taken again from its start as two substeps of half the motion, at most
/// [`MAX_SPLITS`] times in a row (so is one whose contact pulls the indenters down,
/// [`Newton::normal_lift`]).
const SPLIT_ABOVE: f64 = 10.0;

/// Halvings of one substep at most (down to an eighth of its motion).
const MAX_SPLITS: usize = 3;

/// Refreshes of the lagged friction at most.
const MAX_OUTER: usize = 6;

/// Relative residual of the preconditioned conjugate gradients (an inexact Newton step;
/// the line search and the next step absorb it): that of the two-grid cycle's solves, and
/// the tightest of those that reuse an earlier factorisation, whose forcing term lies
/// between this and [`LOOSEST_FORCING`] ([`forcing`]). The two-grid cycle is rebuilt at
/// every Newton step, so a looser solve that takes more steps costs more there
/// (measured: `docs/solvers.md`, "Cheaper Newton steps: the forcing term, the line
/// search, the cycle's sweeps").
const FORCING: f64 = 1e-2;

/// The loosest forcing term, that of a minimisation's first step.
const LOOSEST_FORCING: f64 = 0.5;

/// Conjugate gradient iterations with an earlier factorisation before the matrix is
/// factored afresh.
const REUSE_ITERATIONS: usize = 8;

/// Stiffness systems of recent regions kept for reuse (their pattern and fill-reducing
/// ordering).
const KEPT_SYSTEMS: usize = 4;

/// Two-grid cycles of earlier regions kept for reuse: one, so that a contact that moves
/// back and forth between two regions builds neither again. A fine press's region
/// changes with every frame, so more kept cycles hold memory for the same Newton steps
/// to the same forces (measured: `docs/solvers.md`, "Which solver a gel gets").
const KEPT_TWO_GRIDS: usize = 1;

/// Fraction of the largest nodal displacement above which a node counts as displaced: the
/// region always covers the displaced nodes, so that where an indenter was, the gel
/// relaxes.
const DEFORMED: f64 = 2e-3;

/// Distance (cells) from an indenter within which a node column's surface point counts
/// as in the contact footprint that the region is grown from.
const FOOTPRINT_CELLS: f64 = 1.5;

/// Line search halvings at most.
const MAX_HALVINGS: usize = 30;

/// Conjugate gradient iterations with the two-grid preconditioner at most.
const MULTIGRID_ITERATIONS: usize = 200;

/// The two-grid cycle's coarse level is factored afresh at a minimisation's first step
/// and after a solve that took more conjugate gradient iterations than this; otherwise
/// only the smoother's contact is refreshed ([`TwoGrid::build`]). A coarse level some
/// steps old costs iterations, not accuracy, and a rule by counts keeps the answer
/// independent of timing and threads; refreshing it at every step did not pay, even
/// smoothed rather than factored (measured: `docs/solvers.md`, "The contact penalty in
/// physical units; the coarse level refactored after slow solves" and "Three levels: the
/// 0.6 mm level smoothed, not factored").
const REFACTOR_COARSE_ABOVE: usize = 12;

/// Quadratic B-spline weights and derivatives along each axis at a point (cells).
#[derive(Clone, Copy, Debug)]
pub(super) struct Stencil {
    pub(in crate::mpm) base: [i32; 3],
    pub(in crate::mpm) w: [[f64; 3]; 3],
    dw: [[f64; 3]; 3],
}

impl Stencil {
    pub(in crate::mpm) fn at(x: &Vector3<f64>) -> Stencil {
        let mut s = Stencil {
            base: [0; 3],
            w: [[0.0; 3]; 3],
            dw: [[0.0; 3]; 3],
        };
        for k in 0..3 {
            let b = (x[k] - 0.5).floor();
            let f = x[k] - b;
            s.base[k] = b as i32;
            s.w[k] = [
                0.5 * (1.5 - f) * (1.5 - f),
                0.75 - (f - 1.0) * (f - 1.0),
                0.5 * (f - 0.5) * (f - 0.5),
            ];
            s.dw[k] = [f - 1.5, -2.0 * (f - 1.0), f - 0.5];
        }
        s
    }

    /// Weight of local node `l = (a * 3 + b) * 3 + c`.
    #[inline(always)]
    fn weight(&self, l: usize) -> f64 {
        self.w[0][l / 9] * self.w[1][l / 3 % 3] * self.w[2][l % 3]
    }

    /// Weight gradient of local node `l`.
    #[inline(always)]
    fn gradient(&self, l: usize) -> Vector3<f64> {
        let (a, b, c) = (l / 9, l / 3 % 3, l % 3);
        Vector3::new(
            self.dw[0][a] * self.w[1][b] * self.w[2][c],
            self.w[0][a] * self.dw[1][b] * self.w[2][c],
            self.w[0][a] * self.w[1][b] * self.dw[2][c],
        )
    }

    /// Grid offset of local node `l` from the base.
    #[inline(always)]
    fn local(l: usize) -> [i32; 3] {
        [(l / 9) as i32, (l / 3 % 3) as i32, (l % 3) as i32]
    }
}

/// An elastic quadrature point.
#[derive(Clone, Copy, Debug)]
struct QPoint {
    stencil: Stencil,
    /// Volume (cells^3).
    vol: f64,
    /// Index of its density in [`Newton::densities`].
    density: u8,
}

/// An elastic point at the last evaluation: its energy and `det F`, and its stress and
/// projected tangent weighted by its volume (the tangent kept for the Hessian's products
/// and its assembly).
#[derive(Clone, Copy, Debug)]
struct PointState {
    energy: f64,
    j: f64,
    /// Whether the density was defined at the point's `F`.
    defined: bool,
    stress: Matrix3<f64>,
    tangent: [[f64; 9]; 9],
}

impl Default for PointState {
    fn default() -> Self {
        Self {
            energy: 0.0,
            j: 1.0,
            defined: true,
            stress: Matrix3::zeros(),
            tangent: [[0.0; 9]; 9],
        }
    }
}

/// A contact point's Gauss-Newton stiffness at the last evaluation, with its stencil's
/// region indices (`usize::MAX`: fixed or held) and weights, looked up once per
/// evaluation for the Hessian's products and its assembly.
#[derive(Clone, Copy, Debug)]
struct ContactStiffness {
    /// The base node of the contact point's stencil.
    base: [i32; 3],
    dofs: [usize; 27],
    w: [f64; 27],
    h: Matrix3<f64>,
}

/// Points summed per chunk in a parallel sum: the chunks, not the threads, fix the order
/// of the additions, so the result does not depend on the thread count.
const CHUNK: usize = 256;

/// A surface contact point considered in the current substep.
#[derive(Clone, Copy, Debug)]
struct ContactPoint {
    /// Index in the contact lattice; at least the lattice's size for a tip point
    /// (see `subgrid.rs`), which has no friction.
    index: u32,
    /// Rest position (cells).
    rest: Vector3<f64>,
    stencil: Stencil,
    /// Lagged normal force (internal units) and normal, for friction.
    lag_force: f64,
    lag_normal: Vector3<f64>,
    /// Factor on the penalty: below 1 where the point's patch is smaller than the grid
    /// resolves (see `subgrid.rs`).
    soft: f64,
    /// The point's share of the top face, in lattice points (1, less for a tip point).
    weight: f64,
    /// Whether it is a tip point.
    tip: bool,
}

/// One contact point's contact and friction terms (see [`Newton::contact_term`]).
struct ContactTerm {
    energy: f64,
    /// Gradient with respect to the point's position: its force on the indenters.
    gradient: Vector3<f64>,
    stiffness: Matrix3<f64>,
}

/// A stick anchor: the indenter and the anchor point in its frame (m).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Anchor {
    pub(in crate::mpm) indenter: usize,
    pub(in crate::mpm) local: Point3<f64>,
}

/// Renumbers the indenters of `anchors` (`matched[i]`: previous index of indenter `i`);
/// anchors of indenters that are gone are dropped.
pub(super) fn remap_anchors(anchors: &mut BTreeMap<u32, Anchor>, matched: &[Option<usize>]) {
    anchors.retain(|_, a| remap_anchor(a, matched));
}

/// Renumbers the indenter of `anchor` ([`remap_anchors`]); false where it is gone.
pub(super) fn remap_anchor(anchor: &mut Anchor, matched: &[Option<usize>]) -> bool {
    // Each previous indenter has one successor at most (a search over the few
    // indenters, where a map of them was made every frame).
    match matched.iter().position(|&m| m == Some(anchor.indenter)) {
        Some(i) => {
            anchor.indenter = i;
            true
        }
        None => false,
    }
}

/// The state of one contact point at a displacement field.
struct Touch {
    /// Penetration depth (cells; the signed distance's negative).
    gap: f64,
    /// The signed distance's derivative (sensor frame): the unit normal for an exact
    /// distance, shorter near a sampled one's sharp features ([`Sdf::distance_and_slope`]).
    slope: Vector3<f64>,
    /// Unit outward normal (sensor frame).
    normal: Vector3<f64>,
    indenter: usize,
}

/// The Newton solver's state for one gel.
#[derive(Clone)]
pub(crate) struct Newton {
    pub(in crate::mpm) dims: [usize; 3],
    pub(in crate::mpm) dx: f64,
    pub(in crate::mpm) origin: Vector3<f64>,
    /// Free index of each grid node (`u32::MAX`: fixed).
    pub(in crate::mpm) dof: Vec<u32>,
    /// Grid index of each free node.
    free_nodes: Vec<u32>,
    points: Vec<QPoint>,
    densities: Vec<Density>,
    /// The region the current solve moves: its node box `[x0, x1, y0, y1)` (every
    /// height), the local index of each free node in it (`u32::MAX`: held), the free
    /// index of each local node, and the quadrature points whose stencil reaches it.
    region: Option<[usize; 4]>,
    local: Vec<u32>,
    region_nodes: Vec<u32>,
    region_points: Vec<u32>,
    /// Per region point, per stencil node: its free index (into `u`; `u32::MAX` where
    /// fixed) and its region index (into `grad`; `u32::MAX` where fixed or held).
    point_free: Vec<[u32; 27]>,
    point_local: Vec<[u32; 27]>,
    /// The region points by slab, for their sums onto the nodes (see `slabs.rs`).
    slabs: Slabs,
    /// Per region point: its state at the last evaluation.
    states: Vec<PointState>,
    /// The contact points with a stiffness at the last evaluation.
    contact_stiffness: Vec<ContactStiffness>,
    /// The stiffness system of the current region, and those of recent regions.
    pub(in crate::mpm) system: Option<System>,
    systems: Vec<([usize; 4], System)>,
    /// How the linear systems are solved, and with [`Linear::Multigrid`] the two-grid
    /// preconditioner of the current region and of recent ones.
    pub(in crate::mpm) linear: Linear,
    two_grid: Option<TwoGrid>,
    two_grids: Vec<([usize; 4], TwoGrid)>,
    /// Active margin (cells) around the contact, see [`super::SolverOptions::active_margin`],
    /// and the margin of a nested solve ([`super::SolverOptions::nested_margin`]).
    margin: f64,
    nested_margin: f64,
    /// Whether this frame's solve is nested in the coarse start's gel: its region has the
    /// nested margin, and the nodes outside it take that gel's displacement
    /// ([`Self::boundary`]).
    nested: bool,
    /// A nested substep's displacements (cells, 3 per free node) of the nodes outside
    /// the region at the substep's start and at its end (read from the gel twice as
    /// coarse; zero at the region's nodes).
    boundary: Option<[Vec<f64>; 2]>,
    /// Nodal displacements (cells), 3 per free node.
    pub u: Vec<f64>,
    grad: Vec<f64>,
    /// The elastic part of `grad` and of the energy at the last evaluation, kept for
    /// [`Self::evaluate_contact`].
    elastic_grad: Vec<f64>,
    elastic_energy: f64,
    /// Nodal contact and friction forces of the last assembly (region numbering, as
    /// `grad` and `direction`).
    load: Vec<f64>,
    direction: Vec<f64>,
    trial: Vec<f64>,
    work: [Vec<f64>; 4],
    /// Contact lattice: counts, spacing (cells), first point (cells), area per point.
    lattice: [usize; 2],
    spacing: [f64; 2],
    first: [f64; 2],
    top: f64,
    area: f64,
    anchors: BTreeMap<u32, Anchor>,
    /// The lagged normal force and normal of each contact lattice point at the end of
    /// the last substep: the next substep's friction starts from them.
    lagged: Vec<(f64, Vector3<f64>)>,
    contact: Vec<ContactPoint>,
    /// The last substep's contact loads: each point's position (cells) and force on the
    /// indenters (internal units).
    pub loads: Vec<(Vector3<f64>, Vector3<f64>)>,
    /// Lattice points under the indenters left out of the current solve (too far away).
    culled: Vec<ContactPoint>,
    friction: f64,
    /// Load scale of the previous equilibrium (so that unloading is measured against it).
    last_scale: f64,
    min_scale: f64,
    /// Newton steps a frame may take ([`FRAME_NEWTON`]) and those left to the current one.
    pub(in crate::mpm) frame_steps: usize,
    steps_left: usize,
    /// Per run of Newton steps with the same lagged terms in the last solve: the energy at
    /// its start and after each accepted step.
    pub history: Vec<Vec<f64>>,
    /// The coarse start's displacement change over the next substep (empty when there
    /// is none; [`NewtonSolver::coarse_start`]), taken by [`Newton::predict`].
    coarse_step: Vec<f64>,
    /// The displacement change over the last substep and the indenters' translations
    /// (cells) in it, for the secant predictor.
    last_change: Vec<f64>,
    last_motion: Vec<Vector3<f64>>,
    /// Plane-strain modulus `E* = 2 mu / (1 - nu)` (internal units).
    pub(in crate::mpm) e_star: f64,
    /// Contact penalty stiffness (internal units: `M` per cell of penetration; see
    /// [`PENETRATION`]).
    penalty: f64,
    /// The gel's thickness (cells) and the first-order stiffening of a bonded layer of its
    /// Poisson's ratio ([`super::hertz::bonded_layer_slope`]).
    pub(in crate::mpm) thickness: f64,
    pub(in crate::mpm) layer_slope: f64,
    /// Per indenter of the current substep: the depth (cells) up to which a softened
    /// contact point's spring acts ([`Self::normal_penalty`]).
    soft_depth: Vec<f64>,
    /// The grid's resolved contact radius (cells; 0: no sub-grid compliance) and its
    /// compliance under loaded discs of growing radius (cells) below it (see
    /// `subgrid.rs`).
    resolved_radius: f64,
    grid_compliance: Vec<(f64, f64)>,
}

impl Newton {
    /// The solver state of a gel with `layout`, material, Poisson's ratio, moduli and
    /// friction coefficient.
    pub(super) fn new(gel: &Gel) -> Result<Newton, String> {
        let layout: &Layout = &gel.layout;
        let params = &gel.params;
        let material = params.material;
        let (mu, lambda) = (gel.mu as f64, gel.lambda as f64);
        let selective = params.poisson > FBAR_POISSON;
        let densities = if selective {
            // The particles keep the first Lame parameter of Poisson's ratio
            // FBAR_POISSON (with the gel's shear modulus); the rest moves to the cells.
            let kept = (2.0 * mu * FBAR_POISSON / (1.0 - 2.0 * FBAR_POISSON)).min(lambda);
            vec![
                Density {
                    material,
                    mu,
                    lambda: kept,
                },
                Density {
                    material,
                    mu: 0.0,
                    lambda: lambda - kept,
                },
            ]
        } else {
            vec![Density {
                material,
                mu,
                lambda,
            }]
        };
        let dx = layout.dx;
        let [nx, ny, nz] = layout.lattice;
        let pvol: f64 = layout.spacing.iter().map(|s| s / dx).product();
        let mut points = Vec::with_capacity(nx * ny * nz);
        for ix in 0..nx {
            for iy in 0..ny {
                for iz in 0..nz {
                    let x = layout.rest_position(&params.size, ix, iy, iz).cast::<f64>();
                    points.push(QPoint {
                        stencil: Stencil::at(&x),
                        vol: pvol,
                        density: 0,
                    });
                }
            }
        }
        if selective {
            for cx in 0..nx / 2 {
                for cy in 0..ny / 2 {
                    for cz in 0..nz / 2 {
                        let a = layout.rest_position(&params.size, 2 * cx, 2 * cy, 2 * cz);
                        let b =
                            layout.rest_position(&params.size, 2 * cx + 1, 2 * cy + 1, 2 * cz + 1);
                        let x = ((a + b) * 0.5).cast::<f64>();
                        points.push(QPoint {
                            stencil: Stencil::at(&x),
                            vol: 8.0 * pvol,
                            density: 1,
                        });
                    }
                }
            }
        }
        let dims = layout.dims;
        let node_index =
            |p: [i32; 3]| (p[0] as usize * dims[1] + p[1] as usize) * dims[2] + p[2] as usize;
        // A node layer whose points barely reach it (a gel's top a fraction of a cell
        // above its top points' stencils) is held fixed ([`MIN_LAYER_SUPPORT`]).
        let mut support = vec![0.0; dims[2]];
        for iz in 0..nz {
            let z = layout.rest_position(&params.size, 0, 0, iz).cast::<f64>();
            let s = Stencil::at(&z);
            for (c, w) in s.w[2].iter().enumerate() {
                support[s.base[2] as usize + c] += w * layout.spacing[2] / dx;
            }
        }
        let mut used = vec![false; dims.iter().product()];
        for q in &points {
            for l in 0..27 {
                let o = Stencil::local(l);
                let p = [
                    q.stencil.base[0] + o[0],
                    q.stencil.base[1] + o[1],
                    q.stencil.base[2] + o[2],
                ];
                if p[2] as usize > PAD_BOTTOM && support[p[2] as usize] >= MIN_LAYER_SUPPORT {
                    used[node_index(p)] = true;
                }
            }
        }
        let (dof, nodes) = number(&used);
        let n = 3 * nodes.len();
        let t = params.size[2];
        let margin = gel.options.active_margin * t / layout.dx;
        let nested_margin = gel.options.nested_margin * t / layout.dx;
        let (lattice, spacing, first) = contact_lattice(gel, CONTACT_SUBDIVISION);
        let origin = layout.origin;
        Ok(Newton {
            dims,
            dx,
            origin,
            dof,
            free_nodes: nodes,
            points,
            densities,
            region: None,
            local: Vec::new(),
            region_nodes: Vec::new(),
            region_points: Vec::new(),
            point_free: Vec::new(),
            point_local: Vec::new(),
            slabs: Slabs::default(),
            states: Vec::new(),
            contact_stiffness: Vec::new(),
            system: None,
            systems: Vec::new(),
            linear: gel.options.linear,
            two_grid: None,
            two_grids: Vec::new(),
            margin,
            nested_margin,
            nested: false,
            boundary: None,
            u: vec![0.0; n],
            grad: Vec::new(),
            elastic_grad: Vec::new(),
            elastic_energy: 0.0,
            load: Vec::new(),
            direction: Vec::new(),
            trial: vec![0.0; n],
            work: Default::default(),
            lattice,
            spacing,
            first,
            top: -origin.z / dx,
            area: spacing[0] * spacing[1],
            anchors: BTreeMap::new(),
            lagged: vec![(0.0, Vector3::z()); lattice[0] * lattice[1]],
            contact: Vec::new(),
            culled: Vec::new(),
            loads: Vec::new(),
            friction: params.friction,
            last_scale: 0.0,
            min_scale: 1e-4 * mu,
            frame_steps: FRAME_NEWTON,
            steps_left: FRAME_NEWTON,
            history: Vec::new(),
            coarse_step: Vec::new(),
            last_change: Vec::new(),
            last_motion: Vec::new(),
            e_star: 2.0 * mu / (1.0 - params.poisson),
            penalty: dx / (PENETRATION * t),
            thickness: t / dx,
            layer_slope: super::hertz::bonded_layer_slope(params.poisson),
            resolved_radius: 0.0,
            grid_compliance: Vec::new(),
            soft_depth: Vec::new(),
        })
    }

    /// Back to the undeformed gel, if no contact point at rest touches `indenters`.
    fn release_if_free(&mut self, indenters: &[StepIndenter]) {
        let free = self
            .contact
            .iter()
            .chain(&self.culled)
            .all(|c| self.touch(&c.rest, indenters).is_none());
        if free {
            self.reset();
        }
    }

    /// Back to the undeformed gel without contact history.
    pub(super) fn reset(&mut self) {
        self.u.fill(0.0);
        self.anchors.clear();
        self.lagged.fill((0.0, Vector3::z()));
        self.loads.clear();
        self.last_scale = 0.0;
        self.last_change.clear();
        self.last_motion.clear();
        self.forget_factors();
    }

    /// Forgets the factorisations kept from earlier frames (the patterns and orderings
    /// stay: they depend on the region alone). A frame then factors at its first Newton
    /// step, as a fresh gel's does, so that its answer depends on the state
    /// [`NewtonSolver`] keeps in MuJoCo's and not on which frames came before: a restored
    /// state replays the frames bit for bit.
    fn forget_factors(&mut self) {
        for s in self
            .system
            .iter_mut()
            .chain(self.systems.iter_mut().map(|(_, s)| s))
        {
            s.factored = false;
        }
    }

    /// Writes or reads what the next frame starts from ([`crate::state`]): the nodal
    /// displacements, the stick anchors, the lagged normal forces (the points that carry
    /// one), the contact loads, the load scale of the last equilibrium and the secant
    /// memory. The rest is rebuilt from the gel, or within the frame.
    fn persist(&mut self, io: &mut Io<'_>, bounds: &StateBounds) {
        let points = self.lagged.len();
        state::each(io, &mut self.u);
        let mut anchors: Vec<(u32, Anchor)> =
            std::mem::take(&mut self.anchors).into_iter().collect();
        let n = io.len(anchors.len(), points, "Newton's stick anchors");
        if io.loading() {
            anchors.resize(n, (0, Anchor::default()));
        }
        for (k, a) in &mut anchors {
            let mut i = *k as usize;
            io.count(&mut i, points, "a stick anchor's point");
            *k = i as u32;
            io.count(
                &mut a.indenter,
                bounds.indenters,
                "a stick anchor's indenter",
            );
            a.local.persist(io);
        }
        self.anchors = anchors.into_iter().collect();
        let rest = (0.0, Vector3::z());
        let mut lagged: Vec<(usize, (f64, Vector3<f64>))> = self
            .lagged
            .iter()
            .enumerate()
            .filter(|(_, l)| **l != rest)
            .map(|(i, l)| (i, *l))
            .collect();
        let n = io.len(lagged.len(), points, "Newton's lagged forces");
        if io.loading() {
            lagged.resize(n, (0, rest));
        }
        for (i, l) in &mut lagged {
            io.count(i, points, "a lagged force's point");
            l.persist(io);
        }
        if io.loading() && io.fault().is_none() {
            self.lagged.fill(rest);
            for (i, l) in lagged {
                self.lagged[i] = l;
            }
        }
        state::list(
            io,
            &mut self.loads,
            points + bounds.indenters,
            "Newton's contact loads",
        );
        self.last_scale.persist(io);
        state::secant(
            io,
            &mut self.last_change,
            &mut self.last_motion,
            self.u.len(),
            bounds.indenters,
            "Newton's",
        );
    }

    /// Renumbers the anchors' indenters (`matched[i]`: previous index of indenter `i`);
    /// anchors of indenters that are gone are dropped.
    pub(super) fn remap(&mut self, matched: &[Option<usize>]) {
        if matched.len() != self.last_motion.len()
            || matched.iter().enumerate().any(|(i, m)| *m != Some(i))
        {
            self.last_motion.clear();
        }
        remap_anchors(&mut self.anchors, matched);
    }

    /// Free index of the node at grid coordinates `p`, if free.
    #[inline(always)]
    fn dof_at(&self, base: &[i32; 3], l: usize) -> Option<usize> {
        let o = Stencil::local(l);
        let (x, y, z) = (base[0] + o[0], base[1] + o[1], base[2] + o[2]);
        if x < 0 || y < 0 || z < 0 {
            return None;
        }
        let (x, y, z) = (x as usize, y as usize, z as usize);
        if x >= self.dims[0] || y >= self.dims[1] || z >= self.dims[2] {
            return None;
        }
        let d = self.dof[(x * self.dims[1] + y) * self.dims[2] + z];
        (d != u32::MAX).then_some(d as usize)
    }

    /// Local index (in the current region) of local node `l` of the stencil at `base`,
    /// if that node is free and in the region.
    #[inline(always)]
    fn local_at(&self, base: &[i32; 3], l: usize) -> Option<usize> {
        let d = self.dof_at(base, l)?;
        let k = self.local[d];
        (k != u32::MAX).then_some(k as usize)
    }

    /// The node box `[x0, x1, y0, y1)` a solve of indenters through `poses` (each
    /// indenter at the start and at the end of each substep) moves: the node columns
    /// whose surface point comes within [`FOOTPRINT_CELLS`] of an indenter at one of
    /// those poses and the stick anchors, grown by the margin (the nested one in a nested
    /// solve) and the stencil's reach, and (unless nested) every node displaced by more
    /// than [`DEFORMED`] of the largest displacement. `None` if no indenter reaches the
    /// surface and no anchor is left: then the rest state is the minimum.
    fn region_box(&self, poses: &[(Arc<dyn Sdf>, Isometry3<f64>)]) -> Option<[usize; 4]> {
        let whole = [0, self.dims[0], 0, self.dims[1]];
        let mut bx = [
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        let add = |bx: &mut [f64; 4], x: f64, y: f64| {
            *bx = [bx[0].min(x), bx[1].max(x), bx[2].min(y), bx[3].max(y)];
        };
        let umax = Self::max_node_norm(&self.u);
        let lift = self.u.chunks_exact(3).map(|c| c[2]).fold(0.0, f64::max);
        // Columns whose surface point comes within FOOTPRINT_CELLS of an indenter at one
        // of its poses.
        for (shape, pose) in poses {
            let b = shape.aabb().transformed(pose);
            let cells = |v: &Point3<f64>| (v.coords - self.origin) / self.dx;
            let (lo, hi) = (cells(&b.min), cells(&b.max));
            if !lo.iter().chain(hi.iter()).all(|v| v.is_finite()) {
                continue;
            }
            if lo.z > self.top + lift + FOOTPRINT_CELLS {
                continue;
            }
            let range = |k: usize| {
                let a = (lo[k] - FOOTPRINT_CELLS - 1.0).floor().max(0.0) as usize;
                let b =
                    ((hi[k] + FOOTPRINT_CELLS + 1.0).ceil().max(0.0) as usize).min(self.dims[k]);
                a..b
            };
            for ix in range(0) {
                for iy in range(1) {
                    let rest = Vector3::new(ix as f64, iy as f64, self.top);
                    let x = rest + self.displacement(&Stencil::at(&rest), &self.u);
                    let w = Point3::from(self.origin + x * self.dx);
                    let d = shape.distance(&pose.inverse_transform_point(&w)) / self.dx;
                    if !d.is_finite() || d < FOOTPRINT_CELLS {
                        add(&mut bx, ix as f64, iy as f64);
                    }
                }
            }
        }
        for (&index, _) in self.anchors.iter() {
            let (ix, iy) = (
                index as usize % self.lattice[0],
                index as usize / self.lattice[0],
            );
            add(
                &mut bx,
                self.first[0] + ix as f64 * self.spacing[0],
                self.first[1] + iy as f64 * self.spacing[1],
            );
        }
        if !(bx[0] <= bx[1] && bx[2] <= bx[3]) {
            return None;
        }
        let margin = if self.nested {
            self.nested_margin
        } else {
            self.margin
        };
        if !margin.is_finite() {
            return Some(whole);
        }
        // The stencil of a point at x reaches nodes floor(x - 0.5) .. + 2.
        let grow = margin + 2.0;
        let mut bx = [
            bx[0] - grow,
            bx[1] + grow + 1.0,
            bx[2] - grow,
            bx[3] + grow + 1.0,
        ];
        // Where an indenter was, the gel relaxes: the displaced nodes join the region,
        // unless the solve is nested, where the gel twice as coarse moves the nodes
        // outside it.
        if umax > 0.0 && !self.nested {
            for (k, c) in self.u.chunks_exact(3).enumerate() {
                if (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() > DEFORMED * umax {
                    let node = self.free_nodes[k] as usize;
                    let (ix, iy) = (
                        node / (self.dims[1] * self.dims[2]),
                        node / self.dims[2] % self.dims[1],
                    );
                    add(&mut bx, ix as f64, iy as f64 + 1.0);
                    add(&mut bx, ix as f64 + 1.0, iy as f64);
                }
            }
        }
        let clamp = |v: f64, n: usize| v.clamp(0.0, n as f64) as usize;
        Some([
            clamp(bx[0].floor(), self.dims[0]),
            clamp(bx[1].ceil(), self.dims[0]),
            clamp(bx[2].floor(), self.dims[1]),
            clamp(bx[3].ceil(), self.dims[1]),
        ])
    }

    /// Makes `bx` the region the next minimisations move: its node numbering, its
    /// quadrature points and its stiffness system (built, or kept from a recent solve
    /// over the same box).
    pub(in crate::mpm) fn set_region(&mut self, bx: [usize; 4]) -> Result<(), String> {
        if self.region == Some(bx) && (self.system.is_some() || self.two_grid.is_some()) {
            return Ok(());
        }
        let [x0, x1, y0, y1] = bx;
        let (ny, nz) = (self.dims[1], self.dims[2]);
        let inside = |node: usize| {
            let (ix, iy) = (node / (ny * nz), node / nz % ny);
            (x0..x1).contains(&ix) && (y0..y1).contains(&iy)
        };
        self.local = vec![u32::MAX; self.free_nodes.len()];
        self.region_nodes.clear();
        let mut grid_dof = vec![u32::MAX; self.dof.len()];
        let mut grid_nodes = Vec::new();
        for (k, &node) in self.free_nodes.iter().enumerate() {
            if inside(node as usize) {
                self.local[k] = self.region_nodes.len() as u32;
                grid_dof[node as usize] = self.region_nodes.len() as u32;
                self.region_nodes.push(k as u32);
                grid_nodes.push(node);
            }
        }
        let reaches = |base: i32, lo: usize, hi: usize| base + 2 >= lo as i32 && base < hi as i32;
        self.region_points = (0..self.points.len() as u32)
            .filter(|&i| {
                let b = self.points[i as usize].stencil.base;
                reaches(b[0], x0, x1) && reaches(b[1], y0, y1)
            })
            .collect();
        if let Some(r) = self.region {
            if let Some(old) = self.system.take() {
                self.systems.insert(0, (r, old));
                self.systems.truncate(KEPT_SYSTEMS);
            }
            if let Some(old) = self.two_grid.take() {
                self.two_grids.insert(0, (r, old));
                self.two_grids.truncate(KEPT_TWO_GRIDS);
            }
        }
        // A nested region is small, but its gel is fine: the two-grid cycle's Newton steps
        // (its fixed forcing term) are what such a gel is measured on.
        let multigrid =
            super::choice::newton_multigrid(self.linear, 3 * self.region_nodes.len(), self.nested);
        if !multigrid {
            self.system = match self.systems.iter().position(|(r, _)| *r == bx) {
                Some(i) => Some(self.systems.remove(i).1),
                None => Some(System::new(self.dims, &grid_nodes, &grid_dof)?),
            };
        }
        self.region = Some(bx);
        let (mut free, mut local) = (Vec::new(), Vec::new());
        for &i in &self.region_points {
            let base = self.points[i as usize].stencil.base;
            let f: [u32; 27] =
                std::array::from_fn(|l| self.dof_at(&base, l).map_or(u32::MAX, |d| d as u32));
            local.push(f.map(|d| {
                if d == u32::MAX {
                    d
                } else {
                    self.local[d as usize]
                }
            }));
            free.push(f);
        }
        self.point_free = free;
        self.point_local = local;
        let base_x: Vec<i32> = self
            .region_points
            .iter()
            .map(|&i| self.points[i as usize].stencil.base[0])
            .collect();
        let node_x: Vec<i32> = grid_nodes
            .iter()
            .map(|&n| (n as usize / (ny * nz)) as i32)
            .collect();
        self.slabs = Slabs::new(&base_x, &node_x);
        self.states
            .resize(self.region_points.len(), PointState::default());
        let n = 3 * self.region_nodes.len();
        for v in [
            &mut self.grad,
            &mut self.elastic_grad,
            &mut self.load,
            &mut self.direction,
        ] {
            v.clear();
            v.resize(n, 0.0);
        }
        if multigrid {
            self.two_grid = match self.two_grids.iter().position(|(r, _)| *r == bx) {
                Some(i) => Some(self.two_grids.remove(i).1),
                None => Some(TwoGrid::new(self)?),
            };
        }
        Ok(())
    }

    /// Displacement (cells) of the material point with stencil `s` under `u`.
    fn displacement(&self, s: &Stencil, u: &[f64]) -> Vector3<f64> {
        let mut d = Vector3::zeros();
        for l in 0..27 {
            if let Some(k) = self.dof_at(&s.base, l) {
                d += Vector3::new(u[3 * k], u[3 * k + 1], u[3 * k + 2]) * s.weight(l);
            }
        }
        d
    }

    /// Where this (coarser) grid reads the displacement of free node `k` of `fine`, in its
    /// cells: the node's position, or the nearest point of the gel (`size`: its width,
    /// length and thickness, centred in x and y, the top at z = 0) for a node outside it.
    /// Outside the gel the field comes from nodes that only the edge's particles reach,
    /// which the minimum leaves loosely set; read at the gel's edge, a nested solve's
    /// surface is off by the coarse gel's own error at its free edge (measured:
    /// `docs/solvers.md`, "A nested solve: the fine grid only near the contact").
    fn at_node(&self, fine: &Newton, k: u32, size: &[f64; 3]) -> Vector3<f64> {
        let [_, d1, d2] = fine.dims;
        let node = fine.free_nodes[k as usize] as usize;
        let grid = Vector3::new(
            (node / (d1 * d2)) as f64,
            ((node / d2) % d1) as f64,
            (node % d2) as f64,
        );
        let at = fine.origin + grid * fine.dx;
        let (hx, hy) = (0.5 * size[0], 0.5 * size[1]);
        let at = Vector3::new(
            at.x.clamp(-hx, hx),
            at.y.clamp(-hy, hy),
            at.z.clamp(-size[2], 0.0),
        );
        (at - self.origin) / self.dx
    }

    /// Displacement (m) of the surface point at rest position `rest` (cells).
    pub(super) fn surface_displacement(&self, rest: &Vector3<f64>) -> Vector3<f64> {
        self.displacement(&Stencil::at(rest), &self.u) * self.dx
    }

    /// The nearest indenter to the point at `x` (cells) that it penetrates, if any.
    fn touch(&self, x: &Vector3<f64>, indenters: &[StepIndenter]) -> Option<Touch> {
        let p = Point3::from(self.origin + x * self.dx);
        let mut best: Option<Touch> = None;
        for (m, ind) in indenters.iter().enumerate() {
            if !contains(&ind.bounds, &p) {
                continue;
            }
            let local = ind.now.inverse_transform_point(&p);
            let (dist, slope) = ind.shape.distance_and_slope(&local);
            let dist = dist / self.dx;
            if !(dist < 0.0) {
                continue;
            }
            if best.as_ref().map_or(true, |b| -dist > b.gap) {
                let slope = ind.now.rotation * slope;
                let length = slope.norm();
                if !(length > 1e-12 && length.is_finite()) {
                    continue;
                }
                best = Some(Touch {
                    gap: -dist,
                    slope,
                    normal: slope / length,
                    indenter: m,
                });
            }
        }
        best
    }

    /// The contact lattice points under the indenters' bounds, grown by the largest
    /// lateral displacement and a cell.
    fn gather_contact_points(&mut self, indenters: &[StepIndenter]) {
        let mut reach = 1.0f64;
        for k in (0..self.u.len()).step_by(3) {
            reach = reach.max(self.u[k].abs()).max(self.u[k + 1].abs());
        }
        let mut ranges: Vec<[usize; 4]> = Vec::new();
        for ind in indenters {
            let b = &ind.bounds;
            if b.min.z > (self.top + reach) * self.dx + self.origin.z {
                continue;
            }
            let range = |lo: f64, hi: f64, axis: usize| {
                let to = |v: f64| (v - self.origin[axis]) / self.dx;
                let a = ((to(lo) - reach - self.first[axis]) / self.spacing[axis]).floor();
                let b = ((to(hi) + reach - self.first[axis]) / self.spacing[axis]).ceil();
                let n = self.lattice[axis] as f64;
                (a.clamp(0.0, n) as usize, (b + 1.0).clamp(0.0, n) as usize)
            };
            let (x0, x1) = range(b.min.x, b.max.x, 0);
            let (y0, y1) = range(b.min.y, b.max.y, 1);
            if x0 < x1 && y0 < y1 {
                ranges.push([x0, x1, y0, y1]);
            }
        }
        let mut indices: Vec<u32> = Vec::new();
        for r in &ranges {
            for iy in r[2]..r[3] {
                for ix in r[0]..r[1] {
                    indices.push((iy * self.lattice[0] + ix) as u32);
                }
            }
        }
        // Points with an anchor stay considered while their indenter does.
        indices.extend(self.anchors.keys().copied());
        indices.sort_unstable();
        indices.dedup();
        self.contact = indices
            .into_iter()
            .map(|index| {
                let (ix, iy) = (
                    index as usize % self.lattice[0],
                    index as usize / self.lattice[0],
                );
                let rest = Vector3::new(
                    self.first[0] + ix as f64 * self.spacing[0],
                    self.first[1] + iy as f64 * self.spacing[1],
                    self.top,
                );
                let (lag_force, lag_normal) = self.lagged[index as usize];
                ContactPoint {
                    index,
                    rest,
                    stencil: Stencil::at(&rest),
                    lag_force,
                    lag_normal,
                    soft: 1.0,
                    weight: 1.0,
                    tip: false,
                }
            })
            .collect();
        // Points farther from every indenter than the solve can move them stay out of it;
        // `culled` keeps them for the check after the solve.
        self.culled.clear();
        let contact = std::mem::take(&mut self.contact);
        for c in contact {
            let x = c.rest + self.displacement(&c.stencil, &self.u);
            if self.anchors.contains_key(&c.index) || self.clearance(&x, indenters) < CULL_CELLS {
                self.contact.push(c);
            } else {
                self.culled.push(c);
            }
        }
    }

    /// Whether a point left out of the solve by [`Self::gather_contact_points`] penetrates
    /// an indenter now; if so, every point is taken back into the contact set.
    fn restore_culled(&mut self, indenters: &[StepIndenter]) -> bool {
        let missed = self.culled.iter().any(|c| {
            let x = c.rest + self.displacement(&c.stencil, &self.u);
            self.touch(&x, indenters).is_some()
        });
        if missed {
            let culled = std::mem::take(&mut self.culled);
            self.contact.extend(culled);
            self.contact.sort_unstable_by_key(|c| c.index);
        }
        missed
    }

    /// The smallest signed distance (cells) from the point at `x` (cells) to an indenter
    /// whose bounds hold it; `+inf` if none does.
    fn clearance(&self, x: &Vector3<f64>, indenters: &[StepIndenter]) -> f64 {
        let p = Point3::from(self.origin + x * self.dx);
        indenters
            .iter()
            .filter(|ind| contains(&ind.bounds, &p))
            .map(|ind| ind.shape.distance(&ind.now.inverse_transform_point(&p)) / self.dx)
            .fold(f64::INFINITY, f64::min)
    }

    /// The energy at `u` (elastic, contact, friction with the lagged forces); `+inf` where
    /// the material is not defined or a point's `det F` leaves `[J_MIN, J_MAX]`.
    fn energy(&self, u: &[f64], indenters: &[StepIndenter]) -> f64 {
        let (points, densities) = (&self.points, &self.densities);
        let chunks: Vec<f64> = self
            .region_points
            .par_chunks(CHUNK)
            .zip(self.point_free.par_chunks(CHUNK))
            .map(|(ids, free)| {
                let mut e = 0.0;
                for (&i, dofs) in ids.iter().zip(free) {
                    let q = &points[i as usize];
                    let f = deformation(&q.stencil, dofs, u);
                    // The gel's admissible states keep `det F` within the bounds the
                    // relaxation clamps to: the line search does not step out of them (an
                    // indenter driven through the gel to its base would otherwise invert
                    // it).
                    let j = f.determinant();
                    if !((J_MIN..=J_MAX).contains(&j)) {
                        return f64::INFINITY;
                    }
                    e += q.vol * densities[q.density as usize].energy(&f);
                }
                e
            })
            .collect();
        let mut e: f64 = chunks.iter().sum();
        if !e.is_finite() {
            return f64::INFINITY;
        }
        for c in &self.contact {
            let x = c.rest + self.displacement(&c.stencil, u);
            e += self.contact_term(c, &x, indenters).energy;
        }
        e
    }

    /// The contact and friction energy of contact point `c` at `x` (cells), its gradient
    /// with respect to `x` (the point's force on the indenters) and its Gauss-Newton
    /// stiffness. A sliding point's friction stiffness is that of the quadratic that
    /// majorizes `|t|` at its offset `y` (`|t|^2 / (2 y) + y / 2`): `mu f_n / y` in every
    /// direction of the tangent plane, the exact Hessian's `mu f_n / y` across the slip
    /// and also along it, where the exact one is zero. The exact model is linear along
    /// the slip, so a step that took a point back towards its anchor carried it past the
    /// anchor as far as the gel's pull reached, and the line search halved the whole step
    /// for it (measured: `docs/solvers.md`, "Friction's sliding points: a majorizing
    /// stiffness; the two-grid cycle from 0.6 mm"). The energy and its gradient are exact,
    /// so the minimum is the same.
    fn contact_term(
        &self,
        c: &ContactPoint,
        x: &Vector3<f64>,
        indenters: &[StepIndenter],
    ) -> ContactTerm {
        let mut term = ContactTerm {
            energy: 0.0,
            gradient: Vector3::zeros(),
            stiffness: Matrix3::zeros(),
        };
        if let Some(t) = self.touch(x, indenters) {
            let (e, f, k) = self.normal_penalty(c, &t);
            let a = self.area * c.weight;
            term.energy += a * e;
            term.gradient -= t.slope * (a * f);
            term.stiffness += t.slope * t.slope.transpose() * (a * k);
        }
        if let Some((y, d)) = self.slip(c, x, indenters) {
            let scale = self.friction * c.lag_force;
            term.energy += scale * smooth_slip(y, STICK);
            let n = c.lag_normal;
            let tangent = Matrix3::identity() - n * n.transpose();
            // Sticking: the quadratic's own gradient and stiffness; sliding: the
            // majorizer's at the offset.
            let radius = y.max(STICK);
            term.gradient += d * (scale / radius);
            term.stiffness += tangent * (scale / radius);
        }
        term
    }

    /// The penalty's energy, force and stiffness per unit area of contact point `c` at
    /// `t`: [`penalty`] times the point's factor, which a patch smaller than the grid
    /// resolves sets below 1 (see `subgrid.rs`). Its softer spring stands for the surface
    /// deflection the grid misses, not for a penetration, so it acts only up to
    /// [`SOFT_EXTENT`] of the indenter's smallest extent; deeper, the full penalty
    /// holds the point (a small body pressed past its radius would otherwise take the
    /// surface points past its centre, and the distance push them out through its far
    /// side).
    fn normal_penalty(&self, c: &ContactPoint, t: &Touch) -> (f64, f64, f64) {
        if c.soft >= 1.0 {
            return penalty(t.gap, self.penalty);
        }
        let s = c.soft;
        let cap = self
            .soft_depth
            .get(t.indenter)
            .copied()
            .unwrap_or(f64::INFINITY);
        if t.gap <= cap {
            let (e, f, k) = penalty(t.gap, self.penalty);
            (s * e, s * f, s * k)
        } else {
            let h = t.gap - cap;
            let (e, f, _) = penalty(cap, self.penalty);
            let (eh, fh, k) = penalty(h, self.penalty);
            (s * (e + f * h) + eh, s * f + fh, k)
        }
    }

    /// The tangential offset from a point at `x` to its anchor (its length and the offset),
    /// for a point that carries a lagged normal force and an anchor.
    fn slip(
        &self,
        c: &ContactPoint,
        x: &Vector3<f64>,
        indenters: &[StepIndenter],
    ) -> Option<(f64, Vector3<f64>)> {
        if self.friction <= 0.0 || c.lag_force <= 0.0 {
            return None;
        }
        let a = self.anchors.get(&c.index)?;
        let ind = indenters.get(a.indenter)?;
        let anchor = ((ind.now * a.local).coords - self.origin) / self.dx;
        let d = x - anchor;
        let n = c.lag_normal;
        let t = d - n * n.dot(&d);
        Some((t.norm(), t))
    }

    /// Energy, gradient (into `grad`) and contact load (into `load`) at `u`, keeping each
    /// point's stress and tangent and each contact point's stiffness for the Hessian
    /// ([`Self::hessian_product`], [`Self::fill_matrix`]); also the smallest and largest
    /// `det F`. `None` where the material is not defined.
    pub(in crate::mpm) fn evaluate(
        &mut self,
        indenters: &[StepIndenter],
    ) -> Option<(f64, f64, f64)> {
        self.grad.fill(0.0);
        let (points, densities, u) = (&self.points, &self.densities, &self.u);
        self.states
            .par_iter_mut()
            .zip(self.region_points.par_iter())
            .zip(self.point_free.par_iter())
            .with_min_len(CHUNK)
            .for_each(|((state, &i), dofs)| {
                let q = &points[i as usize];
                let f = deformation(&q.stencil, dofs, u);
                state.j = f.determinant();
                match densities[q.density as usize].evaluate(&f) {
                    Some(ev) => {
                        state.defined = true;
                        state.energy = q.vol * ev.energy;
                        state.stress = ev.stress * q.vol;
                        for (t, e) in state.tangent.iter_mut().zip(&ev.tangent) {
                            for (t, e) in t.iter_mut().zip(e) {
                                *t = q.vol * e;
                            }
                        }
                    }
                    None => state.defined = false,
                }
            });
        let mut energy = 0.0;
        let (mut jmin, mut jmax) = (f64::INFINITY, f64::NEG_INFINITY);
        for state in &self.states {
            if !state.defined {
                return None;
            }
            jmin = jmin.min(state.j);
            jmax = jmax.max(state.j);
            energy += state.energy;
        }
        let (states, region_points, point_local) =
            (&self.states, &self.region_points, &self.point_local);
        self.slabs.add(&mut self.grad, 3, |slab, rows, first| {
            for &r in slab {
                let r = r as usize;
                let stencil = &points[region_points[r] as usize].stencil;
                add_forces(stencil, &point_local[r], &states[r].stress, rows, first);
            }
        });
        self.elastic_energy = energy;
        self.elastic_grad.copy_from_slice(&self.grad);
        Some((energy + self.evaluate_contact(indenters), jmin, jmax))
    }

    /// The contact and friction part of [`Self::evaluate`] at the same `u`, again (after
    /// the lagged normal forces changed): their energy, with the gradient, load and
    /// contact stiffness refreshed.
    fn evaluate_contact(&mut self, indenters: &[StepIndenter]) -> f64 {
        self.grad.copy_from_slice(&self.elastic_grad);
        self.load.fill(0.0);
        let mut energy = 0.0;
        self.contact_stiffness.clear();
        let contact = std::mem::take(&mut self.contact);
        for c in &contact {
            let x = c.rest + self.displacement(&c.stencil, &self.u);
            let term = self.contact_term(c, &x, indenters);
            energy += term.energy;
            if term.gradient != Vector3::zeros() {
                let mut stiff = ContactStiffness {
                    base: c.stencil.base,
                    dofs: [usize::MAX; 27],
                    w: [0.0; 27],
                    h: term.stiffness,
                };
                for l in 0..27 {
                    if let Some(d) = self.local_at(&c.stencil.base, l) {
                        let w = c.stencil.weight(l);
                        (stiff.dofs[l], stiff.w[l]) = (d, w);
                        for k in 0..3 {
                            self.grad[3 * d + k] += w * term.gradient[k];
                            self.load[3 * d + k] += w * term.gradient[k];
                        }
                    }
                }
                self.contact_stiffness.push(stiff);
            }
        }
        self.contact = contact;
        energy
    }

    /// `y = H x` with the Hessian of the last evaluation, without assembling it (region
    /// numbering).
    fn hessian_product(&self, x: &[f64], y: &mut [f64]) {
        let points = &self.points;
        // Each point's stress change `dP = T dF(x)`, added to its nodes by slabs; a slab's
        // changes first, then their sums (in one loop the product took half as long again).
        y.fill(0.0);
        self.slabs.add(y, 3, |slab, rows, first| {
            let changes: Vec<Matrix3<f64>> = slab
                .iter()
                .map(|&r| {
                    let r = r as usize;
                    let (state, dofs) = (&self.states[r], &self.point_local[r]);
                    let stencil = &points[self.region_points[r] as usize].stencil;
                    let df = deformation(stencil, dofs, x) - Matrix3::identity();
                    let v: [f64; 9] = std::array::from_fn(|e| df[(e / 3, e % 3)]);
                    Matrix3::from_fn(|a, b| {
                        let row = &state.tangent[3 * a + b];
                        row.iter().zip(&v).map(|(t, v)| t * v).sum::<f64>()
                    })
                })
                .collect();
            for (&r, dp) in slab.iter().zip(&changes) {
                let r = r as usize;
                let stencil = &points[self.region_points[r] as usize].stencil;
                add_forces(stencil, &self.point_local[r], dp, rows, first);
            }
        });
        for k in &self.contact_stiffness {
            let mut v = Vector3::zeros();
            for (&d, &w) in k.dofs.iter().zip(&k.w) {
                if d != usize::MAX {
                    v += Vector3::new(x[3 * d], x[3 * d + 1], x[3 * d + 2]) * w;
                }
            }
            let hv = k.h * v;
            for (&d, &w) in k.dofs.iter().zip(&k.w) {
                if d != usize::MAX {
                    for c in 0..3 {
                        y[3 * d + c] += w * hv[c];
                    }
                }
            }
        }
    }

    /// Assembles the Hessian of the last evaluation into `system`.
    pub(in crate::mpm) fn fill_matrix(&self, system: &mut System) {
        system.clear();
        for ((state, &i), local) in self
            .states
            .iter()
            .zip(&self.region_points)
            .zip(&self.point_local)
        {
            let dofs: [usize; 27] = local.map(|d| {
                if d == u32::MAX {
                    usize::MAX
                } else {
                    d as usize
                }
            });
            let stencil = &self.points[i as usize].stencil;
            let grads = std::array::from_fn(|l| stencil.gradient(l));
            add_point(system, &dofs, &grads, &state.tangent);
        }
        for k in &self.contact_stiffness {
            add_pairs(system, &k.dofs, |l1, l2| k.h * (k.w[l1] * k.w[l2]));
        }
    }

    /// Largest nodal norm of `v`.
    fn max_node_norm(v: &[f64]) -> f64 {
        v.chunks_exact(3)
            .map(|c| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt())
            .fold(0.0, f64::max)
    }

    /// Minimises the energy by Newton's method. Once a step's relative residual is below
    /// [`LAG_BELOW`], friction's lagged normal forces are refreshed at the state it reaches
    /// (`starts`, `start`: the substep's start, for the anchors of new contacts), and the
    /// minimisation goes on with them, as long as each refresh changes them less than the
    /// one before (and at most [`MAX_OUTER`] times; never on a near-incompressible gel,
    /// see below); otherwise they stay as they are, for the outer loop of
    /// [`Self::substep`]. So the lag converges with the minimisation, not after it: a
    /// whole minimisation to a state that the first refresh then moved far, and several
    /// more after it, took more Newton steps a frame (measured: `docs/solvers.md`, "Fewer
    /// Newton steps: friction lagged within the minimisation, and the coarse start"). A
    /// refresh from a state farther from equilibrium (residual 0.3) meets penalty forces
    /// of a transient penetration and diverges on a slide. Each run of steps with one lag
    /// is one entry of `history`, its energy non-increasing. Returns the final relative
    /// residual, or `None` if the state became undefined.
    fn minimise(
        &mut self,
        indenters: &[StepIndenter],
        tolerance: f64,
        starts: &[Isometry3<f64>],
        start: &[f64],
        report: &mut SolveReport,
    ) -> Option<f64> {
        let mut residual = f64::INFINITY;
        // Held nodes keep their displacement in every trial state.
        self.trial.copy_from_slice(&self.u);
        let mut first = true;
        let (mut last_residual, mut eta) = (f64::NAN, LOOSEST_FORCING);
        // The evaluation of the state the line search accepted, if it was evaluated whole.
        let mut evaluated = None;
        // Not on a near-incompressible gel (its volume term on the cells): there the
        // lagged forces do not settle (at Poisson 0.499 each refresh changed them by 0.81
        // to 0.84 of their sum), and refreshes within the minimisation only moved where
        // the oscillation stops, onto a path on which a 1 mm press of the stability suite
        // no longer converged.
        let mut lagging = self.friction > 0.0 && self.densities.len() == 1;
        let (mut last_lag, mut refreshes) = (f64::INFINITY, 0);
        // Conjugate gradient iterations of the last two-grid solve.
        let mut last_iterations = 0;
        for step in 0..MAX_NEWTON {
            let (energy, jmin, jmax) = match evaluated.take() {
                Some(e) => e,
                None => self.evaluate(indenters)?,
            };
            report.det_f_min = jmin;
            report.det_f_max = jmax;
            let scale = Self::max_node_norm(&self.load)
                .max(self.last_scale)
                .max(self.min_scale);
            residual = Self::max_node_norm(&self.grad) / scale;
            if first {
                self.history.push(vec![energy]);
                first = false;
            }
            if residual <= tolerance {
                self.last_scale = Self::max_node_norm(&self.load);
                return Some(residual);
            }
            if self.steps_left == 0 {
                report.work_bound = true;
                return Some(residual);
            }
            if last_residual.is_finite() {
                eta = forcing(residual / last_residual, eta);
            }
            last_residual = residual;
            report.iterations += 1;
            self.steps_left -= 1;
            let mut work = std::mem::take(&mut self.work);
            let mut direction = std::mem::take(&mut self.direction);
            let [rhs, scratch @ ..] = &mut work;
            rhs.clear();
            rhs.extend(self.grad.iter().map(|g| -g));
            let mut failed = false;
            if let Some(mut grid) = self.two_grid.take() {
                // The contact's part is built afresh every step in the smoother (the
                // previous step's whole cycle converged within four iterations in none of
                // 35 steps at dx = 0.7 mm: points enter and leave the contact), in the
                // coarse level after a slow solve, the gel's at a minimisation's first.
                report.factorisations += 1;
                let coarse = last_iterations > REFACTOR_COARSE_ABOVE;
                if grid.build(self, step == 0, coarse).is_err() {
                    failed = true;
                } else {
                    // The last iterate is a descent direction even short of the forcing
                    // tolerance.
                    let (_, steps) = conjugate_gradients(
                        rhs,
                        &mut direction,
                        FORCING,
                        MULTIGRID_ITERATIONS,
                        scratch,
                        |x, y| self.hessian_product(x, y),
                        |r, z| grid.apply(r, z),
                    );
                    report.cg_iterations += steps;
                    last_iterations = steps;
                }
                self.two_grid = Some(grid);
            } else {
                let mut system = self.system.take().expect("region set");
                let (reused, steps) = if system.factored {
                    system.solve_preconditioned(
                        rhs,
                        &mut direction,
                        eta,
                        REUSE_ITERATIONS,
                        scratch,
                        |x, y| self.hessian_product(x, y),
                    )
                } else {
                    (false, 0)
                };
                report.cg_iterations += steps;
                if reused {
                    report.reused += 1;
                } else {
                    report.factorisations += 1;
                    self.fill_matrix(&mut system);
                    if system.factor().is_err() {
                        failed = true;
                    } else {
                        direction.copy_from_slice(rhs);
                        system.solve(&mut direction);
                    }
                }
                self.system = Some(system);
            }
            self.work = work;
            self.direction = direction;
            if failed {
                return Some(residual);
            }
            let slope: f64 = self
                .direction
                .iter()
                .zip(&self.grad)
                .map(|(p, g)| p * g)
                .sum();
            if !(slope < 0.0) {
                // Not a descent direction (a factorisation in trouble): steepest descent.
                for (p, g) in self.direction.iter_mut().zip(&self.grad) {
                    *p = -g;
                }
            }
            let slope: f64 = self
                .direction
                .iter()
                .zip(&self.grad)
                .map(|(p, g)| p * g)
                .sum();
            let mut alpha = 1.0;
            let mut accepted = false;
            for _ in 0..MAX_HALVINGS {
                for (k, &g) in self.region_nodes.iter().enumerate() {
                    for c in 0..3 {
                        let i = 3 * g as usize + c;
                        self.trial[i] = self.u[i] + alpha * self.direction[3 * k + c];
                    }
                }
                // The trial is evaluated whole (stress and tangent with the energy): most
                // steps take the first trial, whose evaluation then starts the next step.
                std::mem::swap(&mut self.u, &mut self.trial);
                let trial = self
                    .evaluate(indenters)
                    .filter(|&(_, jmin, jmax)| jmin >= J_MIN && jmax <= J_MAX);
                match trial {
                    Some((e, jmin, jmax))
                        if e.is_finite() && e <= energy + 1e-4 * alpha * slope =>
                    {
                        self.trial.copy_from_slice(&self.u);
                        if let Some(h) = self.history.last_mut() {
                            h.push(e);
                        }
                        evaluated = Some((e, jmin, jmax));
                        accepted = true;
                        break;
                    }
                    _ => std::mem::swap(&mut self.u, &mut self.trial),
                }
                alpha *= 0.5;
            }
            if !accepted {
                // No decrease to be had at this precision: the minimum up to round-off.
                return Some(residual);
            }
            if lagging && residual < LAG_BELOW {
                let change = self.lag_friction(indenters, starts, start);
                refreshes += 1;
                lagging = change < last_lag && refreshes < MAX_OUTER;
                last_lag = change;
                if change > 0.0 {
                    if let Some((_, jmin, jmax)) = evaluated {
                        let e = self.elastic_energy + self.evaluate_contact(indenters);
                        evaluated = Some((e, jmin, jmax));
                    }
                    first = true;
                }
            }
        }
        Some(residual)
    }

    /// Refreshes the lagged normal forces and normals of the contact points, creating the
    /// anchors of new contacts at their position at the start of the substep mapped into
    /// their indenter's frame there (`start`: displacement at the start). Returns the
    /// summed change of the lagged forces relative to their sum (the relative change of
    /// the friction the contact can carry).
    fn lag_friction(
        &mut self,
        indenters: &[StepIndenter],
        starts: &[Isometry3<f64>],
        start: &[f64],
    ) -> f64 {
        let mut change = 0.0f64;
        let mut largest = 0.0f64;
        let contact = std::mem::take(&mut self.contact);
        let mut updated = contact.clone();
        for c in updated.iter_mut().filter(|c| !c.tip) {
            let x = c.rest + self.displacement(&c.stencil, &self.u);
            let (force, normal) = match self.touch(&x, indenters) {
                Some(t) => {
                    if !self.anchors.contains_key(&c.index) {
                        let x0 = c.rest + self.displacement(&c.stencil, start);
                        let p0 = Point3::from(self.origin + x0 * self.dx);
                        let local = starts[t.indenter].inverse_transform_point(&p0);
                        self.anchors.insert(
                            c.index,
                            Anchor {
                                indenter: t.indenter,
                                local,
                            },
                        );
                    }
                    (
                        self.area * c.weight * self.normal_penalty(c, &t).1,
                        t.normal,
                    )
                }
                None => (0.0, c.lag_normal),
            };
            change += (force - c.lag_force).abs();
            largest += force;
            c.lag_force = force;
            c.lag_normal = normal;
        }
        self.contact = updated;
        if largest > 0.0 {
            change / largest
        } else {
            0.0
        }
    }

    /// After a substep: anchors of points out of contact are dropped, those of sliding
    /// points follow them to the stick radius.
    fn return_mapping(&mut self, indenters: &[StepIndenter]) {
        let contact = std::mem::take(&mut self.contact);
        for c in contact.iter().filter(|c| !c.tip) {
            let x = c.rest + self.displacement(&c.stencil, &self.u);
            if self.touch(&x, indenters).is_none() {
                self.anchors.remove(&c.index);
                continue;
            }
            let Some(a) = self.anchors.get(&c.index).copied() else {
                continue;
            };
            let Some(ind) = indenters.get(a.indenter) else {
                self.anchors.remove(&c.index);
                continue;
            };
            let anchor = ((ind.now * a.local).coords - self.origin) / self.dx;
            let d = x - anchor;
            let n = c.lag_normal;
            let t = d - n * n.dot(&d);
            let y = t.norm();
            if y > STICK {
                let moved = anchor + t * (1.0 - STICK / y);
                let p = Point3::from(self.origin + moved * self.dx);
                self.anchors.insert(
                    c.index,
                    Anchor {
                        indenter: a.indenter,
                        local: ind.now.inverse_transform_point(&p),
                    },
                );
            }
        }
        self.contact = contact;
    }

    /// The force of each contact point on the indenters (internal units) and where the
    /// point is (cells), for the points that carry one.
    fn contact_loads(&self, indenters: &[StepIndenter]) -> Vec<(Vector3<f64>, Vector3<f64>)> {
        let mut loads = Vec::new();
        for c in &self.contact {
            let x = c.rest + self.displacement(&c.stencil, &self.u);
            let f = self.contact_term(c, &x, indenters).gradient;
            if f != Vector3::zeros() {
                loads.push((x, f));
            }
        }
        loads
    }

    /// The vertical part of the contact points' normal forces on the indenters (internal
    /// units): positive, the gel pushing them up, for any press of the top face. A
    /// negative sum means that surface points were carried past the middle of a body,
    /// where the distance pushes them out through its upper side and they pull it down.
    fn normal_lift(&self, indenters: &[StepIndenter]) -> f64 {
        let mut lift = 0.0;
        for c in &self.contact {
            let x = c.rest + self.displacement(&c.stencil, &self.u);
            if let Some(t) = self.touch(&x, indenters) {
                let (_, f, _) = self.normal_penalty(c, &t);
                lift -= t.slope.z * self.area * c.weight * f;
            }
        }
        lift
    }

    /// Solves one substep with the indenters at `indenters` (moved from `starts`), from the
    /// displacements `start` (the current ones, as [`Checkpoint`] keeps them); in a nested
    /// solve the nodes outside the region first go where [`Self::boundary`] has them
    /// `reach` of the way through it (below 1 in the first half of a split). Returns the
    /// force on the indenters (internal units) and the final relative residual, or `None`
    /// if the state became undefined.
    fn substep(
        &mut self,
        indenters: &[StepIndenter],
        starts: &[Isometry3<f64>],
        start: &[f64],
        reach: f64,
        tolerance: f64,
        report: &mut SolveReport,
    ) -> Option<(Vector3<f64>, f64)> {
        if let Some([from, to]) = &self.boundary {
            // Nested: the nodes outside the region where the gel twice as coarse has
            // them when the indenters have come `reach` of the way.
            for (k, &l) in self.local.iter().enumerate() {
                if l == u32::MAX {
                    for c in 3 * k..3 * k + 3 {
                        self.u[c] = from[c] + reach * (to[c] - from[c]);
                    }
                }
            }
        }
        self.gather_contact_points(indenters);
        let motion: Vec<Vector3<f64>> = indenters
            .iter()
            .zip(starts)
            .map(|(i, s)| (i.now.translation.vector - s.translation.vector) / self.dx)
            .collect();
        self.predict(&motion, indenters);
        self.soft_depth = indenters
            .iter()
            .map(|i| SOFT_EXTENT * extent_cells(i.shape.as_ref(), self.dx).min())
            .collect();
        self.update_patches(indenters);
        let mut residual = self.minimise(indenters, tolerance, starts, start, report)?;
        if self.restore_culled(indenters) {
            self.update_patches(indenters);
            residual = self.minimise(indenters, tolerance, starts, start, report)?;
        }
        // The lagged terms (friction's normal forces, tip points) are refreshed and the
        // minimisation repeated until they settle, and only while they do: not once the
        // friction's change stops falling (a high friction's lagged forces can cycle, and
        // each round is a minimisation), nor once the frame's Newton steps are spent.
        let mut last_friction = f64::INFINITY;
        for _ in 0..MAX_OUTER {
            if self.steps_left == 0 {
                break;
            }
            let tips = self.update_tips(indenters);
            let friction = if self.friction > 0.0 {
                self.lag_friction(indenters, starts, start)
            } else {
                0.0
            };
            if tips <= tolerance && (friction <= tolerance || friction >= last_friction) {
                break;
            }
            last_friction = friction;
            residual = self.minimise(indenters, tolerance, starts, start, report)?;
        }
        report.residual = report.residual.max(residual);
        report.converged &= residual <= tolerance;
        self.loads = self.contact_loads(indenters);
        let force = self.loads.iter().map(|l| l.1).sum();
        if self.friction > 0.0 {
            self.return_mapping(indenters);
            for l in self.lagged.iter_mut() {
                *l = (0.0, Vector3::z());
            }
            for c in self.contact.iter().filter(|c| !c.tip) {
                self.lagged[c.index as usize] = (c.lag_force, c.lag_normal);
            }
        }
        self.last_change.clear();
        self.last_change
            .extend(self.u.iter().zip(start).map(|(u, s)| u - s));
        self.last_motion = motion;
        Some((force, residual))
    }

    /// [`Newton::substep`] from the indenters' poses `starts` to `indenters`, taken again
    /// as two halves (each split in turn, up to `splits` times) when it stalls far from
    /// equilibrium: a press of a ridged mesh deep into the coarse gel in one substep
    /// carried its lattice points deep into the ridges, where the distance pushes them
    /// out sideways, and ended far from the relaxation's force with `det F` at its clamp.
    /// A tried substep's work stays counted in `report`; its state and its verdict on
    /// convergence are undone. `span`: the share of the substep's motion at its start and
    /// end (`[0, 1]`; the halves of a split take their halves of it).
    ///
    /// `Err(residual)` when a substep stalls at the last split: the state is then that of
    /// its start, the last equilibrium found, and the caller goes no further (a grid
    /// crushed under a ridged mesh had ended at a force no gel carries). Measured:
    /// `docs/solvers.md`, "A Newton substep that stalls". Also when the frame's Newton
    /// steps are spent ([`FRAME_NEWTON`]): the state is then the one the minimisation
    /// reached, short of equilibrium, for the next frame to carry on from.
    fn substep_split(
        &mut self,
        indenters: &[StepIndenter],
        starts: &[Isometry3<f64>],
        span: [f64; 2],
        tolerance: f64,
        splits: usize,
        report: &mut SolveReport,
    ) -> Result<Vector3<f64>, f64> {
        let saved = Checkpoint::of(self, report);
        // A pull on the indenters asks for a split but does not stall a substep at the last
        // one: a body pressed deeper than its own size (a 0.2 mm sphere 0.6 mm deep) has
        // the top surface closing over it, and no split changes that.
        let got = self.substep(indenters, starts, &saved.u, span[1], tolerance, report);
        if report.work_bound {
            // The frame's Newton steps are spent: the state the minimisation reached (each
            // accepted step lowered the energy) is kept, so that the next frame carries on
            // from it, and the frame ends here.
            return Err(got.map_or(f64::INFINITY, |(_, residual)| residual));
        }
        let stalled = match got {
            Some((force, residual))
                if residual <= SPLIT_ABOVE * tolerance
                    && (splits == 0 || self.normal_lift(indenters) >= 0.0) =>
            {
                return Ok(force)
            }
            Some((_, residual)) => residual,
            None => f64::INFINITY,
        };
        saved.restore(self, report);
        if splits == 0 {
            return Err(stalled);
        }
        report.substep_splits += 1;
        let half: Vec<StepIndenter> = indenters
            .iter()
            .zip(starts)
            .map(|(p, start)| {
                let now = start.try_lerp_slerp(&p.now, 0.5, 1e-9).unwrap_or(p.now);
                let (b0, b1) = (
                    p.shape.aabb().transformed(&now),
                    p.shape.aabb().transformed(start),
                );
                let bounds = Aabb::new(b0.min.inf(&b1.min), b0.max.sup(&b1.max))
                    .inflated((CONTACT_BAND as f64 + 1.0) * self.dx);
                StepIndenter {
                    shape: p.shape.clone(),
                    now,
                    bounds,
                }
            })
            .collect();
        let mid = 0.5 * (span[0] + span[1]);
        self.substep_split(&half, starts, [span[0], mid], tolerance, splits - 1, report)?;
        let middle: Vec<Isometry3<f64>> = half.iter().map(|p| p.now).collect();
        let mut rest = indenters.to_vec();
        for (p, h) in rest.iter_mut().zip(&half) {
            let b = p.shape.aabb().transformed(&h.now);
            p.bounds = Aabb::new(b.min.inf(&p.bounds.min), b.max.sup(&p.bounds.max));
        }
        self.substep_split(
            &rest,
            &middle,
            [mid, span[1]],
            tolerance,
            splits - 1,
            report,
        )
    }

    /// The secant predictor's multiple of the last substep's change for indenters moving
    /// by `motion` (cells): `None` unless they move on along their last path.
    fn secant(&self, motion: &[Vector3<f64>]) -> Option<f64> {
        (self.last_change.len() == self.u.len())
            .then(|| super::secant_scale(motion, &self.last_motion))
            .flatten()
    }

    /// The predictor: the coarse start's change over this substep where there is one (a
    /// frame that does not move on along the last one's path, see [`NewtonSolver::solve_frame`]);
    /// elsewhere, where the indenters move on along their last path, the secant one (the
    /// gel moved on by the same multiple of its last change). Kept only if that lowers
    /// the energy (friction left out). A warm start from the last equilibrium alone meets
    /// the indenters deeper than the solution does, over a wider patch than the one in
    /// contact at the solution, and Newton's method then sheds the extra contact points
    /// a ring per step; a prediction starts it near the solution's contact patch. On a
    /// steady moving press the secant prediction is the better one, though the coarse
    /// start's has the lower energy (measured: `docs/solvers.md`, "Fewer Newton steps:
    /// friction lagged within the minimisation, and the coarse start").
    fn predict(&mut self, motion: &[Vector3<f64>], indenters: &[StepIndenter]) {
        let coarse = std::mem::take(&mut self.coarse_step);
        let (s, change) = if coarse.len() == self.u.len() {
            (1.0, &coarse)
        } else {
            match self.secant(motion) {
                Some(s) => (s, &self.last_change),
                None => return,
            }
        };
        // The region's nodes only: the others are held (or, nested, set from the gel
        // twice as coarse).
        self.trial.copy_from_slice(&self.u);
        for &k in &self.region_nodes {
            let i = 3 * k as usize;
            for c in i..i + 3 {
                self.trial[c] = self.u[c] + s * change[c];
            }
        }
        let no_friction = self.friction;
        self.friction = 0.0;
        let predicted = self.energy(&self.trial, indenters);
        let kept = self.energy(&self.u, indenters);
        self.friction = no_friction;
        if predicted < kept {
            std::mem::swap(&mut self.u, &mut self.trial);
        }
    }
}

/// What a substep changes of the solver's state and of the report's verdict, kept to take
/// the substep again ([`Newton::substep_split`]).
struct Checkpoint {
    u: Vec<f64>,
    anchors: BTreeMap<u32, Anchor>,
    lagged: Vec<(f64, Vector3<f64>)>,
    loads: Vec<(Vector3<f64>, Vector3<f64>)>,
    last_change: Vec<f64>,
    last_motion: Vec<Vector3<f64>>,
    last_scale: f64,
    history: usize,
    residual: f64,
    converged: bool,
}

impl Checkpoint {
    fn of(n: &Newton, report: &SolveReport) -> Self {
        Self {
            u: n.u.clone(),
            anchors: n.anchors.clone(),
            lagged: n.lagged.clone(),
            loads: n.loads.clone(),
            last_change: n.last_change.clone(),
            last_motion: n.last_motion.clone(),
            last_scale: n.last_scale,
            history: n.history.len(),
            residual: report.residual,
            converged: report.converged,
        }
    }

    fn restore(self, n: &mut Newton, report: &mut SolveReport) {
        n.u = self.u;
        n.trial.copy_from_slice(&n.u);
        n.anchors = self.anchors;
        n.lagged = self.lagged;
        n.loads = self.loads;
        n.last_change = self.last_change;
        n.last_motion = self.last_motion;
        n.last_scale = self.last_scale;
        n.history.truncate(self.history);
        report.residual = self.residual;
        report.converged = self.converged;
    }
}

/// `I + sum_l u_l grad w_l^T` at a point with `stencil` whose nodes have the indices
/// `dofs` into `u` (`u32::MAX`: no displacement).
#[inline]
fn deformation(stencil: &Stencil, dofs: &[u32; 27], u: &[f64]) -> Matrix3<f64> {
    // Axis by axis: the node values summed over z with the weights and their derivatives,
    // then over y, then over x (270 multiply-adds where node by node takes 405).
    let [w0, w1, w2] = &stencil.w;
    let [d0, d1, d2] = &stencil.dw;
    let mut f = Matrix3::identity();
    for a in 0..3 {
        let (mut ss, mut sd, mut ds) = (Vector3::zeros(), Vector3::zeros(), Vector3::zeros());
        for b in 0..3 {
            let (mut s, mut d) = (Vector3::zeros(), Vector3::zeros());
            for c in 0..3 {
                let n = dofs[9 * a + 3 * b + c];
                if n != u32::MAX {
                    let n = 3 * n as usize;
                    let v = Vector3::new(u[n], u[n + 1], u[n + 2]);
                    s += v * w2[c];
                    d += v * d2[c];
                }
            }
            ss += s * w1[b];
            sd += s * d1[b];
            ds += d * w1[b];
        }
        f.column_mut(0).axpy(d0[a], &ss, 1.0);
        f.column_mut(1).axpy(w0[a], &sd, 1.0);
        f.column_mut(2).axpy(w0[a], &ds, 1.0);
    }
    f
}

/// Adds the nodal forces `P grad w_l` of a point's stress `p` to `rows` (3 per node, from
/// region node `first` on) at its stencil's nodes `dofs` (region indices, `u32::MAX`:
/// none), axis by axis as [`deformation`] sums.
#[inline(always)]
fn add_forces(
    stencil: &Stencil,
    dofs: &[u32; 27],
    p: &Matrix3<f64>,
    rows: &mut [f64],
    first: usize,
) {
    let [w0, w1, w2] = &stencil.w;
    let [d0, d1, d2] = &stencil.dw;
    let (p0, p1, p2) = (p.column(0), p.column(1), p.column(2));
    for a in 0..3 {
        let (a0, a1, a2) = (p0 * d0[a], p1 * w0[a], p2 * w0[a]);
        for b in 0..3 {
            let s = a0 * w1[b] + a1 * d1[b];
            let d = a2 * w1[b];
            for c in 0..3 {
                let n = dofs[9 * a + 3 * b + c];
                if n != u32::MAX {
                    let f = s * w2[c] + d * d2[c];
                    let at = 3 * (n as usize - first);
                    for k in 0..3 {
                        rows[at + k] += f[k];
                    }
                }
            }
        }
    }
}

/// A contact lattice `subdivision` times finer than the top particles along each axis:
/// its counts, spacing (cells) and first point (cells, in-plane).
pub(super) fn contact_lattice(gel: &Gel, subdivision: usize) -> ([usize; 2], [f64; 2], [f64; 2]) {
    let [nx, ny, _] = gel.layout.lattice;
    let [lx, ly, _] = gel.params.size;
    let (dx, origin) = (gel.layout.dx, gel.layout.origin);
    let lattice = [nx * subdivision, ny * subdivision];
    let spacing = [lx / lattice[0] as f64 / dx, ly / lattice[1] as f64 / dx];
    let first = [
        (-0.5 * lx - origin.x) / dx + 0.5 * spacing[0],
        (-0.5 * ly - origin.y) / dx + 0.5 * spacing[1],
    ];
    (lattice, spacing, first)
}

/// The indices `used` marks, numbered in order: each one's number (`u32::MAX` where not
/// used) and the used indices.
fn number(used: &[bool]) -> (Vec<u32>, Vec<u32>) {
    let mut number = vec![u32::MAX; used.len()];
    let mut used_indices = Vec::new();
    for (i, &u) in used.iter().enumerate() {
        if u {
            number[i] = used_indices.len() as u32;
            used_indices.push(i as u32);
        }
    }
    (number, used_indices)
}

/// `T_l[a][3 c + d] = sum_b g_l[b] H[3 a + b][3 c + d]` for the stencil nodes `l` that
/// are `used` (`H` a point's tangent, `g_l` its nodes' shape-function gradients): the
/// Hessian block of nodes `l1` and `l2` is then `T_l1[a][3 c + d] g_l2[d]`.
fn contract(
    grads: &[Vector3<f64>; 27],
    tangent: &[[f64; 9]; 9],
    used: impl Fn(usize) -> bool,
) -> [[[f64; 9]; 3]; 27] {
    let mut tl = [[[0.0f64; 9]; 3]; 27];
    for l in 0..27 {
        if !used(l) {
            continue;
        }
        let g = grads[l];
        for a in 0..3 {
            for e in 0..9 {
                tl[l][a][e] = g[0] * tangent[3 * a][e]
                    + g[1] * tangent[3 * a + 1][e]
                    + g[2] * tangent[3 * a + 2][e];
            }
        }
    }
    tl
}

/// Adds the Hessian of a quadrature point with volume-weighted `tangent` to `system`:
/// `grads` the gradients of its 3 x 3 x 3 nodes' shape functions, `dofs` their unknowns
/// (`usize::MAX`: none).
fn add_point(
    system: &mut System,
    dofs: &[usize; 27],
    grads: &[Vector3<f64>; 27],
    tangent: &[[f64; 9]; 9],
) {
    let tl = contract(grads, tangent, |l| dofs[l] != usize::MAX);
    add_pairs(system, dofs, |l1, l2| {
        let g2 = &grads[l2];
        Matrix3::from_fn(|a, c| {
            tl[l1][a][3 * c] * g2[0] + tl[l1][a][3 * c + 1] * g2[1] + tl[l1][a][3 * c + 2] * g2[2]
        })
    });
}

/// Adds `block(l1, l2)` for every pair of a stencil's free local nodes (`dofs[l]`: free
/// index or `usize::MAX`), lower triangle only (`dofs[l2] <= dofs[l1]`).
fn add_pairs(
    system: &mut System,
    dofs: &[usize; 27],
    block: impl Fn(usize, usize) -> Matrix3<f64>,
) {
    for l1 in 0..27 {
        if dofs[l1] == usize::MAX {
            continue;
        }
        for l2 in 0..27 {
            if dofs[l2] == usize::MAX || dofs[l2] > dofs[l1] {
                continue;
            }
            let (o1, o2) = (Stencil::local(l1), Stencil::local(l2));
            let offset = [o1[0] - o2[0], o1[1] - o2[1], o1[2] - o2[2]];
            system.add_block(dofs[l1], dofs[l2], offset, &block(l1, l2));
        }
    }
}

/// Whether `p` lies in `b`.
pub(super) fn contains(b: &Aabb, p: &Point3<f64>) -> bool {
    (0..3).all(|k| p[k] >= b.min[k] && p[k] <= b.max[k])
}

/// The contact penalty's energy per unit area, pressure and stiffness at penetration `g`
/// (cells).
#[inline]
/// The extents of `shape`'s bounding box (cells of `dx`).
fn extent_cells(shape: &dyn Sdf, dx: f64) -> Vector3<f64> {
    let b = shape.aabb();
    (b.max - b.min) / dx
}

/// The penalty's energy, force and stiffness per unit area at penetration `g` (cells),
/// with stiffness `k`.
fn penalty(g: f64, k: f64) -> (f64, f64, f64) {
    (0.5 * k * g * g, k * g, k)
}

/// The forcing term of a Newton step whose residual is `ratio` times the last step's,
/// which had the forcing term `last`: Eisenstat and Walker's second choice (1996,
/// `0.9 ratio^2`, not below `0.9 last^2` where that exceeds 0.1) within [`FORCING`] and
/// [`LOOSEST_FORCING`]. A linear solve far from the minimum, where the contact set is
/// still changing, is solved loosely; near it, as tightly as before.
fn forcing(ratio: f64, last: f64) -> f64 {
    let mut eta = 0.9 * ratio * ratio;
    let safeguard = 0.9 * last * last;
    if safeguard > 0.1 {
        eta = eta.max(safeguard);
    }
    if eta.is_nan() {
        eta = LOOSEST_FORCING;
    }
    eta.clamp(FORCING, LOOSEST_FORCING)
}

/// The smoothed slip magnitude at offset `y` with stick radius `r` (cells): `y^2 / (2 r)`
/// below `r`, `y - r / 2` beyond ([`STICK`] for Newton's).
pub(super) fn smooth_slip(y: f64, r: f64) -> f64 {
    if y < r {
        0.5 * y * y / r
    } else {
        y - 0.5 * r
    }
}

/// Newton's method on the gel's total potential energy ([`Solver::Newton`]): its state,
/// and the gel twice as coarse whose solve starts it on a fine grid.
#[derive(Clone, Default)]
pub(in crate::mpm) struct NewtonSolver {
    /// The region, its displacements, contact anchors and kept factors, built at the
    /// first frame.
    pub(in crate::mpm) state: Option<Box<Newton>>,
    /// The gel on a grid twice as coarse whose solve starts Newton's on this one
    /// ([`SolverOptions::coarse_start_above`]), built at the first solve that needs it.
    companion: Option<Box<Gel>>,
}

impl Equilibrium for NewtonSolver {
    fn kind(&self) -> Solver {
        Solver::Newton
    }

    fn solve(&mut self, gel: &mut Gel, frame: &Frame<'_>, report: &mut SolveReport) {
        self.solve_frame(gel, frame.indenters, frame.sweep, frame.matched, report);
    }

    fn reset(&mut self) {
        if let Some(n) = self.state.as_mut() {
            n.reset();
        }
        if let Some(c) = self.companion.as_mut() {
            c.reset();
        }
    }

    /// Newton's state: whether it is built and, where it is, [`Newton::persist`]'s; then
    /// whether the gel twice as coarse that starts its frames is built and, where it is,
    /// that gel's whole state (its own coarse start's included).
    fn persist(
        &mut self,
        io: &mut Io<'_>,
        gel: &Gel,
        bounds: &StateBounds,
        shapes: &[Arc<dyn Sdf>],
    ) -> bool {
        state::presence(io, &mut self.state, || {
            let mut n =
                Newton::new(gel).map_err(|e| format!("Newton's method cannot be built: {e}"))?;
            n.calibrate_subgrid();
            Ok(Box::new(n))
        });
        if let Some(n) = self.state.as_mut() {
            n.persist(io, bounds);
        }
        state::presence(io, &mut self.companion, || {
            companion_of(gel)
                .map(Box::new)
                .map_err(|e| format!("the coarse start's gel cannot be built: {e}"))
        });
        match self.companion.as_mut() {
            Some(c) if io.fault().is_none() => c.persist(io, shapes),
            _ => true,
        }
    }
}

/// The gel twice as coarse that starts the frames of `gel`'s Newton solves
/// ([`SolverOptions::coarse_start_above`]). Not nested itself (it may have a coarse start
/// of its own): `gel`'s nodes outside its region read the companion's own solve. At 0.3 mm
/// (frictionless, 0.1 and 0.2 mm) the whole gel gives 0.01634 and 0.05052 N; a companion
/// walled at the active margin 0.01632 and 0.05052 N, one nested in its own 1.2 mm
/// companion 0.01632 and 0.05040 N (0.01631 and 0.05044 N with twice the margin), in the
/// same time.
fn companion_of(gel: &Gel) -> Result<Gel, String> {
    let params = GelParams {
        dx: 2.0 * gel.params.dx,
        ..gel.params
    };
    let options = SolverOptions {
        solver: Solver::Newton,
        fallback: false,
        nested_margin: f64::INFINITY,
        ..gel.options
    };
    Gel::new(params, options).map_err(|e| e.to_string())
}

impl Gel {
    /// The Newton solver's state, where the gel runs Newton's method and has solved a
    /// frame.
    pub(in crate::mpm) fn newton(&self) -> Option<&Newton> {
        self.own_solver::<NewtonSolver>()?.state.as_deref()
    }

    /// The Newton solver itself, where the gel runs Newton's method.
    #[cfg(test)]
    pub(in crate::mpm) fn newton_solver(&mut self) -> Option<&mut NewtonSolver> {
        self.own_solver_mut::<NewtonSolver>()
    }
}

impl NewtonSolver {
    /// The coarse start of a Newton solve on `gel`
    /// ([`SolverOptions::coarse_start_above`]):
    /// the gel twice as coarse solves for `indenters` (a frame's poses or a substep's),
    /// and the change of its displacement field over that solve, at each node of
    /// `fine`'s region (cells of this grid; zero elsewhere), is returned. `None` where the
    /// grid is small enough to go without, or the coarse solve did not converge.
    fn coarse_start(
        &mut self,
        gel: &mut Gel,
        indenters: &[Placed],
        fine: &Newton,
        report: &mut SolveReport,
    ) -> Option<Vec<f64>> {
        if !self.has_companion(gel, fine.u.len()) {
            return None;
        }
        let coarse_gel = self.companion.as_mut()?;
        let before = coarse_gel.newton().map(|n| n.u.clone());
        let solved = coarse_gel.solve(indenters);
        report.coarse_iterations += solved.iterations + solved.coarse_iterations;
        if !solved.converged {
            return None;
        }
        let coarse = coarse_gel.newton()?;
        let mut step = vec![0.0; fine.u.len()];
        for &g in &fine.region_nodes {
            let x = coarse.at_node(fine, g, &gel.params.size);
            let s = Stencil::at(&x);
            let mut d = coarse.displacement(&s, &coarse.u);
            if let Some(b) = &before {
                d -= coarse.displacement(&s, b);
            }
            let d = d * (coarse.dx / fine.dx);
            let g = 3 * g as usize;
            step[g..g + 3].copy_from_slice(d.as_slice());
        }
        Some(step)
    }

    /// The coarse start's displacement at the nodes of `fine` outside its region (cells of
    /// `fine`'s grid, 3 per free node; zero at the region's nodes), for a nested solve of
    /// a gel of `size`.
    fn companion_field(&self, size: &[f64; 3], fine: &Newton) -> Option<Vec<f64>> {
        let mut field = vec![0.0; fine.u.len()];
        let Some(coarse) = self.companion.as_ref()?.newton() else {
            // Not solved yet: at rest.
            return Some(field);
        };
        field
            .par_chunks_mut(3 * CHUNK)
            .enumerate()
            .for_each(|(chunk, out)| {
                for (j, v) in out.chunks_exact_mut(3).enumerate() {
                    let k = chunk * CHUNK + j;
                    if fine.local[k] == u32::MAX {
                        let x = coarse.at_node(fine, k as u32, size);
                        let d = coarse.displacement(&Stencil::at(&x), &coarse.u)
                            * (coarse.dx / fine.dx);
                        v.copy_from_slice(d.as_slice());
                    }
                }
            });
        Some(field)
    }

    /// Whether a Newton solve of `unknowns` on `gel` takes a coarse start; builds the gel
    /// twice as coarse at the first that does.
    fn has_companion(&mut self, gel: &mut Gel, unknowns: usize) -> bool {
        if unknowns <= gel.options.coarse_start_above {
            return false;
        }
        if self.companion.is_none() {
            match companion_of(gel) {
                Ok(coarse) => self.companion = Some(Box::new(coarse)),
                Err(_) => {
                    // A gel too thin for the doubled spacing: no coarse start, and no
                    // new attempt at every frame.
                    gel.options.coarse_start_above = usize::MAX;
                    return false;
                }
            }
        }
        true
    }

    /// The Newton solve of `sweep` on `gel` (see the module docs); fills `report`.
    fn solve_frame(
        &mut self,
        gel: &mut Gel,
        indenters: &[Placed],
        sweep: &Sweep,
        matched: &[Option<usize>],
        report: &mut SolveReport,
    ) {
        if self.state.is_none() {
            match Newton::new(gel) {
                Ok(mut n) => {
                    n.calibrate_subgrid();
                    self.state = Some(Box::new(n));
                }
                Err(_) => {
                    report.converged = false;
                    report.residual = f64::INFINITY;
                    return;
                }
            }
        }
        let dx = gel.layout.dx;
        let tolerance = gel.options.tolerance;
        let mut newton = self.state.take().expect("built above");
        newton.forget_factors();
        newton.remap(matched);
        newton.history.clear();
        newton.steps_left = newton.frame_steps;
        let motion = sweep.steps as f64 * gel.options.sweep_rate;
        // A body smaller than a couple of cells in every direction moves by at most
        // [`SOFT_EXTENT`] of its size per substep: moved past its radius in one go, it
        // would carry the surface points it met past its centre, where the distance
        // pushes them out through its far side. A larger body but a thin one (a standing
        // capsule, a pin) moves by at most half its smallest extent, its radius, for the
        // same reason (past its end cap the distance pushes the points out sideways);
        // never by less than half a cell, which a thin plate on its edge (the stability
        // suite's knife) does not need.
        let step = sweep
            .indenters
            .iter()
            .map(|p| {
                let extent = extent_cells(p.shape.as_ref(), dx);
                if extent.max() < SMALL_BODY_CELLS {
                    SOFT_EXTENT * extent.min()
                } else {
                    (0.5 * extent.min()).clamp(0.5 * SUBSTEP_CELLS, SUBSTEP_CELLS)
                }
            })
            .fold(SUBSTEP_CELLS, f64::min);
        let substeps = if step > 0.0 {
            ((motion / step).ceil() as usize).clamp(1, 64)
        } else {
            1
        };
        let plan = Sweep {
            indenters: sweep.indenters.clone(),
            starts: sweep.starts.clone(),
            steps: substeps,
        };
        let mut poses: Vec<(Arc<dyn Sdf>, Isometry3<f64>)> = sweep
            .indenters
            .iter()
            .zip(&sweep.starts)
            .map(|(p, s)| (p.shape.clone(), *s))
            .collect();
        let mut placed = Vec::new();
        for s in 0..substeps {
            plan.place(s, dx, &mut placed);
            poses.extend(placed.iter().map(|p| (p.shape.clone(), p.now)));
        }
        newton.nested = gel.options.nested_margin < gel.options.active_margin
            && self.has_companion(gel, newton.u.len());
        newton.boundary = None;
        let Some(bx) = newton.region_box(&poses) else {
            // Nothing reaches the gel: without a load the undeformed gel is the minimum.
            newton.reset();
            if let Some(c) = self.companion.as_mut() {
                c.reset();
            }
            report.sweep_steps = 0;
            report.residual = 0.0;
            gel.force = Vector3::zeros();
            gel.loads.clear();
            gel.set_surface(|_| Vector3::zeros());
            self.state = Some(newton);
            return;
        };
        if newton.set_region(bx).is_err() {
            report.converged = false;
            report.residual = f64::INFINITY;
            self.state = Some(newton);
            return;
        }
        report.active_particles = newton.region_points.len();
        // A frame that moves on along the last one's path is predicted by the secant.
        // Any other (a press from rest, a change of direction) solves the coarse start's
        // gel through the same substeps, and each substep starts from its change over
        // that substep: a deep press from rest took 31 and 39 Newton steps in its two
        // substeps at 0.5 mm when the first started from half the coarse gel's change
        // over the whole frame and the second from the secant, 27 and 34 so.
        plan.place(0, dx, &mut placed);
        let motion: Vec<Vector3<f64>> = placed
            .iter()
            .zip(&sweep.starts)
            .map(|(p, s)| (p.now.translation.vector - s.translation.vector) / dx)
            .collect();
        let steady = newton.secant(&motion).is_some();
        // A nested solve's nodes outside its region: the coarse gel's displacement before
        // and after its solve (of the frame, or of each substep).
        let nested = newton.nested;
        let size = gel.params.size;
        let field = |s: &NewtonSolver, newton: &Newton| {
            nested.then(|| s.companion_field(&size, newton)).flatten()
        };
        let mut frame_field = None;
        if steady {
            // The coarse gel follows every frame, so that its change is at hand when
            // needed.
            let before = field(self, &newton);
            let solved = self.coarse_start(gel, indenters, &newton, report).is_some();
            frame_field = before.zip(field(self, &newton)).filter(|_| solved);
        }
        let saved = newton.u.clone();
        report.sweep_steps = substeps;
        report.residual = 0.0;
        let mut placed = Vec::new();
        let mut starts = sweep.starts.clone();
        let mut force = Some(Vector3::zeros());
        for s in 0..substeps {
            plan.place(s, dx, &mut placed);
            if !steady {
                let poses: Vec<Placed> = placed
                    .iter()
                    .map(|p| Placed {
                        shape: p.shape.clone(),
                        pose: p.now,
                    })
                    .collect();
                // The coarse gel is where the last substep's solve left it.
                let before = match newton.boundary.take() {
                    Some([_, end]) => Some(end),
                    None => field(self, &newton),
                };
                newton.coarse_step = self
                    .coarse_start(gel, &poses, &newton, report)
                    .unwrap_or_default();
                let solved = !newton.coarse_step.is_empty();
                newton.boundary = before
                    .zip(field(self, &newton))
                    .filter(|_| solved)
                    .map(|(a, b)| [a, b]);
            } else if let Some((a, b)) = &frame_field {
                // The frame's change shared out evenly over its substeps.
                let share = |r: f64| a.iter().zip(b).map(|(a, b)| a + r * (b - a)).collect();
                let n = substeps as f64;
                newton.boundary = Some([share(s as f64 / n), share((s + 1) as f64 / n)]);
            }
            match newton.substep_split(&placed, &starts, [0.0, 1.0], tolerance, MAX_SPLITS, report)
            {
                Ok(f) => force = Some(f),
                Err(residual) if residual.is_finite() => {
                    // Stalled: the gel stays at the last equilibrium it found (or, its
                    // Newton steps spent, where they took it), short of the indenters'
                    // pose, and the report says so.
                    report.converged = false;
                    report.residual = report.residual.max(residual);
                    force = Some(newton.loads.iter().map(|l| l.1).sum());
                    break;
                }
                Err(_) => {
                    force = None;
                    break;
                }
            }
            starts = placed.iter().map(|p| p.now).collect();
        }
        if force.is_some() && newton.loads.is_empty() && newton.anchors.is_empty() {
            // No contact force at the equilibrium: it is the undeformed gel, up to the
            // tolerance; take it exactly unless an indenter reaches the undeformed gel.
            newton.release_if_free(&placed);
        }
        match force {
            Some(f) if newton.u.iter().all(|v| v.is_finite()) => {
                let scale = gel.modulus * dx * dx;
                gel.force = f * scale;
                gel.loads = newton
                    .loads
                    .iter()
                    .map(|(x, f)| {
                        let at = gel.layout.origin + x * dx;
                        super::pressure::ContactLoad {
                            at: [at.x, at.y],
                            z: at.z,
                            force: f * scale,
                        }
                    })
                    .collect();
            }
            _ => {
                newton.u = saved;
                newton.anchors.clear();
                report.nonfinite_recovered = true;
                report.converged = false;
                report.residual = f64::INFINITY;
                gel.force = Vector3::zeros();
                gel.loads.clear();
            }
        }
        let rests: Vec<Vector3<f64>> = gel.top_ref.iter().map(|r| r.cast::<f64>()).collect();
        gel.set_surface(|slot| newton.surface_displacement(&rests[slot]));
        self.state = Some(newton);
    }
}
