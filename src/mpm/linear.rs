//! Linear elasticity about the undeformed gel, with contact and Coulomb friction solved on
//! its surface compliance ([`super::Solver::Linear`]).
//!
//! # Model
//!
//! The gel's energy is replaced by its second-order expansion at rest, `u^T K u / 2`,
//! with `K` the Hessian of Newton's discretisation at `u = 0` (the same quadrature points,
//! and the same selective reduced integration at high Poisson's ratios): the small-strain
//! elasticity of the gel as bonded and meshed. The indenters load it through vertical
//! forces `f_p >= 0` at the points of a contact lattice [`SUBDIVISION`] times finer than
//! the particles (a 0.4 mm knife edge does not fall between them on the coarse gel). The
//! lattice is coarser than Newton's: on a grid this coarse, points four times finer than
//! the particles hold the surface to the indenter's shape more tightly than its quadratic
//! B-splines can bend, and a small contact came out 1.6 to 5.9 times too stiff (`tacrom mpm
//! --only small`; twice as fine: 0.8 to 1.7 times).
//!
//! Every point of the top surface lies at one height, so a point's stencil is the product
//! of its in-plane quadratic B-spline weights over a 3 x 3 block of node columns and the
//! same three vertical weights. A point's load is then a combination of nine *column
//! loads* (a unit downward force spread over one node column by the vertical weights),
//! and its displacement the same combination of the columns' mean displacements: the
//! compliance is kept per node column, `G_ab` the mean displacement of column `a` under
//! the load of column `b` (one solve with the factor of `K` each). For the points,
//! `C = W G W^T` with `W` their column weights (nine per row).
//!
//! # Contact
//!
//! Non-penetration at every lattice point `p`, in the small-displacement setting of the
//! model (as Hertz's): the point sinks in place, and must sink at least as deep as the
//! indenters' lower surface reaches below its rest position, `s_p >= delta_p`, with
//! `s_p = -u_p.z` and `delta_p` the vertical distance (negative where the indenters are
//! above it; from the primitives' chords along the vertical, [`Sdf::chord`], exactly; for
//! a mesh marched by the signed distance, and bisected on the way out of an indenter).
//! With the contact's own compliance `eps` (Newton's penalty over a
//! point's share of the face, [`PENALTY`]), `H = eps I + W G_zz W^T` is symmetric and
//! positive definite (Maxwell-Betti reciprocity), and the contact is the linear
//! complementarity problem `f >= 0, H f - delta >= 0, f . (H f - delta) = 0`. On the gel
//! there are many more points than node columns, which makes it degenerate on the points;
//! it is solved instead as the penalty problem in the loads of the node columns under the
//! contact ([`penalty_contact`]): the same answer, from a system the size of those columns
//! (25 to 50 on the coarse gel). `delta` does not depend on the answer, so one solve is
//! exact; a second runs only where the surface rose past a point left out as too far from
//! the indenters. Lateral displacement is left out of the contact geometry: a variant that
//! followed it (the points moved sideways before the vertical distance was taken) needed
//! repeated solves, did not settle on a flat face pressed over a whole pad, and was
//! further from the 0.7 mm reference on the benchmark's patterns.
//!
//! # Small contacts
//!
//! The grid's B-splines cannot bend the surface as sharply as a contact of a fraction of a
//! cell asks: under it the grid deflects about as under a point load (alone, a 0.1 mm cone
//! press came out 16 times Sneddon's force), and the lattice points under a sphere or a
//! cone tip lie far above its deepest point. A contact patch more compliant than a point
//! load on the grid (an indenter that reaches below the rest surface between the
//! lattice's points, or a connected set of lattice points inside the indenters) therefore
//! becomes one point, as a *tip point* of Newton's (`subgrid.rs`): the surface over it is
//! sampled [`TIP_SAMPLES`](super::newton::subgrid::TIP_SAMPLES) times finer than the lattice, and
//! one point at the deepest sample (by vertical depth), standing for the penetrating
//! samples' share of the face, joins the contact in place of the patch's lattice points.
//! In series with its penalty it gets the compliance the grid misses: that of the patch on
//! the layer, `1 / (k E* a)` with `a` the radius of the rigid footprint and `k` from the
//! footprint's fullness (its mean depth over its deepest; [`FULLNESS_SLOPE`], exact for a
//! cone, a sphere and a flat punch to 2.5 %, with the bonded layer's first-order
//! stiffening; an elongated footprint, a ridge lying on the gel, stiffer by the elliptical
//! punch's factor and with the layer's stiffening by its semi-major axis, see
//! `patch_compliance`), less the grid's own at the point (`w^T G w`, exact here). Patches
//! that a point load on the grid already covers keep their lattice points. Tip points carry no
//! friction.
//!
//! # Friction
//!
//! With a friction coefficient `mu > 0`, Coulomb friction acts in the plane of the
//! surface, as Newton's (IPC's lagged friction, Li et al. 2020): a point in contact keeps
//! a stick anchor fixed in its indenter's frame (where it was at the start of the frame
//! it touched in), and its lateral offset `y` from the anchor costs `mu f_lag f0(y)`,
//! `f0` quadratic up to [`STICK`] and linear beyond, with `f_lag` its normal force
//! lagged. The responses to the columns' lateral loads are computed as the vertical ones,
//! and the contact becomes one convex problem in the columns' three loads
//! ([`frictional_contact`]), solved with the normal forces lagged until a refresh would
//! change the friction they cap by less than the tolerance ([`refreshed_friction`]; one
//! to three solves; the first lagged ones from a solve
//! without friction, the first frictional one through stick radii 100 and 10 times
//! larger, since a box face sliding over a whole pad did not converge at the final one
//! in 60 Newton steps). After the frame, points that left contact drop their anchors and
//! sliding points drag theirs to the stick radius; the anchors, forces and displacement
//! carry over to the next frame (a reset forgets them). Without friction (`mu = 0`) none
//! of this is built and the answer depends on the poses alone.
//!
//! Newton's method damps every step that changes which points stick: a held grasp that
//! trembles by microns (every point a little past its stick radius at the frame's start)
//! took 20 to 100 steps, a dense factorisation each, as the line search brought the points
//! back to sticking a group at a time. A large warm solve that one Newton step does not
//! finish is therefore *split* first ([`split_start`]: the alternating direction method
//! of multipliers, which settles which points press, stick and slide in iterations of
//! triangular solves with kept factors, one per direction) and finished by Newton's method
//! from there: the same minimum, in two to four steps, each solved by conjugate gradients
//! preconditioned with a factor of the step's lateral and vertical blocks (a third of the
//! whole system's work; the whole system factored in single precision and refined once in
//! double where they do not serve, [`MIXED_UNKNOWNS`]).
//!
//! # Cost
//!
//! Every node column's responses are made with the gel: read from the gel cache
//! ([`gel_cache`], a file per gel keyed by the physics sources and the gel's parameters),
//! or computed with `K` factored once (faer), in fixed tiles of [`TILE`] columns (one
//! multi-column solve each, so a column's bits depend on nothing else), and cached. The
//! sensors of one gel in a process share them. A first contact is then an ordinary frame. A frame then costs dense algebra of the size of
//! the node columns under its contact and a sum over its loaded columns: no pass over the
//! particles or the grid. A contact that moves on by a few columns updates its dense
//! systems from those of the set last made afresh ([`Compliance::updated`]) rather than
//! inverting its compliance again.
//!
//! # What it leaves out
//!
//! * Large deformation: rotations and stretches enter to first order only, so forces
//!   drift from the nonlinear solvers' as the strain under the indenter grows (`tacrom
//!   mpm --solver linear,relaxation` measures by how much).
//! * Sliding geometry: friction acts in the plane of the undeformed surface and the
//!   contact's normal is vertical, as in the small-displacement setting of Hertz and
//!   Cattaneo-Mindlin; a slope of the indenter does not turn its force.

use std::collections::HashMap;

use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix2, Matrix3, Point3, SymmetricEigen, Vector2, Vector3,
};
use rayon::prelude::*;

use super::contact::StepIndenter;
use super::newton::subgrid::{tip_samples, Samples, TIP_SAMPLES};
use super::newton::system::{par, System};
use super::newton::{
    contact_lattice, contains, remap_anchor, smooth_slip, Anchor, Newton, Stencil, PENALTY, STICK,
};
use super::solver::{Equilibrium, Frame};
use super::{
    pressure::ContactLoad, Gel, Linear as LinearSolve, SolveReport, Solver, StateBounds,
    LINEAR_UNKNOWNS,
};
use crate::geometry::{Chord, Sdf};
use crate::scratch::{refill, SortedMap};
use crate::state::{self, Io, Persist};
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt;
use faer::{Conj, MatMut, MatRef, Par};
use std::sync::{Arc, Mutex, Weak};

use super::gel_cache;

/// Steps at most of a march along the vertical ([`Compliance::vertical_gap`]), the
/// smallest step (cells) down through an indenter, the bisections of the way out, and the
/// distance (cells) at which a march up has met the surface.
const MARCH_STEPS: usize = 200;
const MIN_MARCH: f64 = 0.02;
const BISECTIONS: usize = 24;
const GAP_EPS: f64 = 1e-6;

/// The bisections from which the way out of an indenter is found by
/// [`bracketed_root`] to the same width (the full gaps' [`BISECTIONS`]) rather than by
/// bisecting ([`bisected_root`]: the small contacts' [`FOOTPRINT_BISECTIONS`], whose
/// fullness rule was fitted on their midpoints).
const BRACKETED_FROM: usize = 16;

/// Bisections of the way out of an indenter for a small contact's footprint samples,
/// whose depths make its fullness (a ratio wanted to a few per cent). These samples are
/// marched even under a primitive ([`Compliance::marched_gap`]): the fullness rule
/// ([`FULLNESS_SLOPE`]) was fitted on them, and with the chords' exact depths a 0.2 g
/// ball resting on the coupled gel carried 1.12 % more than its weight instead of 0.14 %
/// (`tests/python/test_implicit_coupling.py`; 0.97 % with every gap marched).
const FOOTPRINT_BISECTIONS: usize = 8;

/// Contact lattice points per particle spacing along each axis.
pub(crate) const SUBDIVISION: usize = 2;

/// Margin (cells) around an indenter's box within which lattice points may touch it:
/// the surface moves sideways by much less than a cell.
const NEAR_CELLS: f64 = 0.5;

/// The stiffness `F / delta` of a small contact, in units of `E* a` with `a` the radius
/// of its rigid footprint on the undeformed surface and `delta` its deepest penetration,
/// as a function of its fullness `phi`, the footprint's mean penetration over `delta`:
/// `k = FULLNESS_SLOPE phi + FULLNESS_OFFSET`. The exact values it is fitted to (least
/// squares; each within 2.5 %): a 45-degree cone, `phi = 1 / 3`, `k = 2 / pi = 0.64`
/// (Sneddon: contact radius `2 delta / pi`, footprint `delta`); a sphere pressed
/// shallowly, `phi = 1 / 2`, `k = 4 / (3 sqrt 2) = 0.94` (Hertz: contact radius `sqrt(R
/// delta)`, footprint `sqrt(2 R delta)`); a flat punch, `phi = 1`, `k = 2`. It follows a
/// sphere pressed deep as well (`delta = 0.8 R`: `phi = 0.61`, `k` 1.19 against Hertz's
/// 1.22 on the exact footprint).
const FULLNESS_SLOPE: f64 = 2.06;
const FULLNESS_OFFSET: f64 = -0.067;

/// The least stiffness of a small contact (units of [`FULLNESS_SLOPE`]'s): profiles
/// sharper than a cone's (whose fullness is a third at any angle) are held to it.
const MIN_FULLNESS_STIFFNESS: f64 = 0.3;

/// A cone's fullness (at any angle).
const CONE_FULLNESS: f64 = 1.0 / 3.0;

/// Surface samples at most per axis over a small contact's lattice points.
const FOOTPRINT_SAMPLES: usize = 24;

/// Solves at most per frame (more only where the surface rose past points left out).
const MAX_PASSES: usize = 12;

/// Node columns solved for together, always the same ones: tiles of `TILE x TILE`
/// columns (one block of the multi-column solve each).
const TILE: usize = 4;

/// Points that may touch: those whose required sinking exceeds minus this fraction of the
/// deepest required sinking (the surface around a contact can rise towards an indenter;
/// a point left out that it rises past is taken in and the contact solved again).
const CANDIDATE_FRACTION: f64 = 0.5;

/// A point's in-plane stencil: nine node columns (`ix * ny + iy`) and weights.
type Columns = [(u32, f64); 9];

/// The linear solver's state for one gel.
#[derive(Clone)]
pub(crate) struct Compliance {
    dx: f64,
    origin: Vector3<f64>,
    /// Node columns along y (the column index is `ix * ny + iy`).
    ny: usize,
    /// The node columns of each top slot.
    slots: Vec<Columns>,
    /// The contact lattice: counts, spacing (cells), first point and height (cells).
    lattice: [usize; 2],
    spacing: [f64; 2],
    first: [f64; 2],
    top: f64,
    /// Penetration (cells) per internal force unit a lattice point's contact allows:
    /// Newton's penalty over the point's share of the top face.
    softness: f64,
    /// The layer's plane-strain modulus (internal units), bonded-layer stiffening and
    /// thickness (cells), for the compliance of a tip point's patch.
    layer: [f64; 3],
    /// Per node column, per level of the surface's vertical stencil: the first unknown of
    /// the node (`u32::MAX`: fixed), and the three vertical weights.
    levels: Vec<[u32; 3]>,
    weights: [f64; 3],
    /// Every node column's responses to its loads: shared by the gels of the same
    /// parameters, and kept on disk ([`Responses`]).
    responses: Arc<Responses>,
    /// Node columns whose responses this gel's construction computed (0: read from the
    /// cache or from a live gel of the same parameters).
    pub computed: usize,
    /// Coulomb friction coefficient (the lateral responses exist where it is positive).
    friction: f64,
    /// Friction's history: the stick anchor of each lattice point in contact, its force on
    /// the gel (internal units) and the node columns' mean displacement (cells, 3 per
    /// column; empty: at rest) at the end of the last frame.
    anchors: SortedMap<Anchor>,
    lagged: HashMap<u32, Vector3<f64>>,
    /// The lagged forces of the frame before the last and each indenter's motion (m) over
    /// the last frame: the secant along which a slowly moving contact's next frame starts
    /// ([`SECANT_MOTION`]).
    lagged_before: HashMap<u32, Vector3<f64>>,
    last_motion: Vec<Vector3<f64>>,
    /// The buffer this frame's motion is gathered in (the last's, kept).
    motion: Vec<Vector3<f64>>,
    /// Whether frames start along that secant (tests compare with and without).
    secant: bool,
    last: Vec<f64>,
    /// The dense systems of the node columns under the last contact (at most
    /// [`LOCAL_SYSTEMS`]): a contact that loads the same columns as the frame before (a
    /// grasp held) builds and inverts nothing.
    locals: Vec<Kept>,
    /// Whether a system of [`TRIM_ENTRIES`] or more was built since the last reset.
    built_large: bool,
    /// Unknowns from which a frictional solve may split ([`SPLIT_UNKNOWNS`]; tests
    /// compare with Newton's method alone).
    split_unknowns: usize,
    /// Whether large frictional solves precondition their Newton steps with a kept
    /// factor ([`Problem::precondition`]; tests compare with a factor every step).
    precondition: bool,
    /// Whether a frame that slides as a whole starts from its normal forces found first
    /// ([`vertical_start`]; tests compare with the last frame's loads alone).
    vertical: bool,
    /// The contact solve's vectors, kept between frames.
    buffers: crate::scratch::Kept<ContactBuffers>,
    /// What the dense systems' making reuses between frames ([`Reuse`]).
    reuse: crate::scratch::Kept<Reuse>,
}

/// The vectors of [`Compliance::contact`], kept between frames for their allocations
/// (each cleared and refilled before it is read).
#[derive(Default)]
struct ContactBuffers {
    near: Vec<u32>,
    rest: Vec<Vector3<f64>>,
    clear: Vec<f64>,
    soft: Vec<f64>,
    stencils: Vec<Columns>,
    forces: Vec<Vector3<f64>>,
    u: Vec<Vector3<f64>>,
    delta: Vec<f64>,
    known: Vec<bool>,
    lag: Vec<f64>,
    offsets: Vec<Vector2<f64>>,
    columns: Vec<f64>,
    cand: Vec<usize>,
    chosen: Vec<Columns>,
    local: Vec<u32>,
    rows: Vec<Columns>,
    d: Vec<f64>,
    eps: Vec<f64>,
    present: Vec<(u32, Vector3<f64>)>,
    surface: Vec<Vector3<f64>>,
    /// A frictional solve's forces at the candidates.
    answer: Vec<Vector3<f64>>,
    /// The columns' loads a pass solves for.
    l: DVector<f64>,
    /// The vectors of the passes' Newton steps.
    steps: Mutex<Steps>,
    /// The normal forces [`vertical_start`] found.
    normal: Vec<f64>,
    /// The candidates' friction caps and anchors ([`Compliance::frictions`]).
    caps: Vec<f64>,
    anchors: Vec<Vector2<f64>>,
    /// Points left out that the surface rose above.
    risen: Vec<usize>,
    /// The last [`Contact`]'s points and forces, taken back ([`Compliance::recycle`]).
    points: Vec<Vector3<f64>>,
    loaded: Vec<Vector3<f64>>,
    /// [`Compliance::small_contacts`]'.
    small: SmallScratch,
    /// [`Compliance::column_loads`]' shares and their order.
    order: LoadOrder,
}

/// [`Compliance::column_loads`]' buffers: each node column's sum of its points' shares,
/// and whether it has one.
type LoadOrder = (Vec<Vector3<f64>>, Vec<bool>);

/// A small patch kept as one point ([`Compliance::small_contacts`]): its lattice points'
/// range in [`SmallScratch::flat`], the point's position, clearance and compliance.
type Patch = ((usize, usize), Vector3<f64>, f64, f64);

/// The buffers of [`Compliance::small_contacts`]: the lattice points inside the
/// indenters (by lattice position), which of them a patch has taken, the patches' points
/// one after another, each patch kept as a point (its range there, position, clearance and
/// compliance), and the lattice points they stand for.
#[derive(Default)]
struct SmallScratch {
    inside: Inside,
    seen: Vec<bool>,
    flat: Vec<usize>,
    patches: Vec<Patch>,
    replaced: Vec<u32>,
}

#[cfg(test)]
thread_local! {
    /// Whether [`Compliance::stiff_by_distances`] may settle a patch, and how many it
    /// settled (this thread's, for the tests).
    pub(super) static DISTANCE_BOUND: std::cell::Cell<(bool, usize)> = const { std::cell::Cell::new((true, 0)) };
}

/// Lattice points by position over their box (`[x0, y0, width, height]`, lattice
/// coordinates): each one's index in the list it was filled from, [`Inside::NONE`] where
/// none. A lookup is one read, where a hash map hashed each of a patch's neighbours.
#[derive(Default)]
struct Inside {
    at: Vec<usize>,
    bounds: [i64; 4],
}

impl Inside {
    const NONE: usize = usize::MAX;

    /// The points `near[i]` (lattice indices `x * ny + y`) for which `take(i)`; whether
    /// there are any.
    fn fill(&mut self, near: &[u32], take: impl Fn(usize) -> bool, ny: i64) -> bool {
        let xy = |k: u32| (k as i64 / ny, k as i64 % ny);
        let mut b = [i64::MAX, i64::MAX, i64::MIN, i64::MIN];
        for (i, &k) in near.iter().enumerate() {
            if take(i) {
                let (x, y) = xy(k);
                b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
            }
        }
        if b[0] > b[2] {
            self.bounds = [0; 4];
            return false;
        }
        self.bounds = [b[0], b[1], b[2] - b[0] + 1, b[3] - b[1] + 1];
        refill(
            &mut self.at,
            (self.bounds[2] * self.bounds[3]) as usize,
            Self::NONE,
        );
        for (i, &k) in near.iter().enumerate() {
            if take(i) {
                let (x, y) = xy(k);
                let slot = self.slot(x, y).expect("within the bounds just found");
                self.at[slot] = i;
            }
        }
        true
    }

    fn slot(&self, x: i64, y: i64) -> Option<usize> {
        let [x0, y0, w, h] = self.bounds;
        let (dx, dy) = (x - x0, y - y0);
        (dx >= 0 && dy >= 0 && dx < w && dy < h).then(|| (dx * h + dy) as usize)
    }

    /// The index of lattice point `(x, y)`, where it was filled.
    fn get(&self, x: i64, y: i64) -> Option<usize> {
        self.slot(x, y)
            .map(|s| self.at[s])
            .filter(|&i| i != Self::NONE)
    }
}

/// The dense systems of one set of node columns under a contact.
#[derive(Clone)]
struct LocalSystem {
    /// The node columns (with their lateral loads, 3 per column, where `base.lateral`).
    local: Vec<u32>,
    /// Their compliance ([`Compliance::local_compliance`]) and its inverse (held by these
    /// systems alone).
    g: Arc<DMatrix<f64>>,
    inverse: Arc<DMatrix<f64>>,
    /// `inverse` in single precision, for a frictional solve of [`MIXED_UNKNOWNS`] or
    /// more ([`Problem::stiff_descent`]).
    inverse32: Option<DMatrix<f32>>,
    /// The columns whose systems were made afresh and these updated from
    /// ([`Compliance::updated`]).
    base: Base,
    /// The matrices the contact solves on these columns assemble and factor their
    /// systems in, kept so that a frame's Newton steps do not allocate them.
    scratch: Workspace,
    /// The factor [`split_start`] made for these columns, kept for the next solve.
    split: Option<SplitFactor>,
    /// The inverse of `g`'s vertical block ([`vertical_inverse`]), made where a frame's
    /// start first asks for it ([`vertical_start`]) and kept with these columns.
    vertical: std::sync::OnceLock<Option<DMatrix<f64>>>,
    /// The buffer the next [`vertical_inverse`] of these systems is made in (an earlier
    /// one's, where they were let go and made again for other columns).
    vertical_spare: crate::scratch::Kept<DMatrix<f64>>,
}

impl LocalSystem {
    /// Systems of no columns: buffers for [`Compliance::system`] to fill.
    fn empty() -> Box<LocalSystem> {
        Box::new(LocalSystem {
            local: Vec::new(),
            g: Arc::new(DMatrix::zeros(0, 0)),
            inverse: Arc::new(DMatrix::zeros(0, 0)),
            inverse32: None,
            base: Base::default(),
            scratch: Workspace::default(),
            split: None,
            vertical: Default::default(),
            vertical_spare: Default::default(),
        })
    }

    /// The inverse of `g`'s vertical block, made where first asked for (in the kept
    /// buffer) and kept.
    fn vertical(&self) -> Option<&DMatrix<f64>> {
        self.vertical
            .get_or_init(|| {
                let mut out = self.vertical_spare.take();
                vertical_inverse(&self.g, &mut out).map(|()| out)
            })
            .as_ref()
    }
}

/// What [`Compliance::take_local`] reuses from frame to frame: the last systems let go
/// (their buffers, for the next ones made: a press moving on makes a set's systems at
/// every frame) and [`Compliance::updated`]'s vectors and matrices.
#[derive(Default)]
struct Reuse {
    /// Systems let go, boxed as the kept sets hold them (a box moved back into a set
    /// allocates nothing).
    #[allow(clippy::vec_box)]
    husks: Vec<Box<LocalSystem>>,
    /// Matrices of bases let go, each held here alone.
    matrices: Vec<Arc<DMatrix<f64>>>,
    update: Update,
}

impl Reuse {
    /// Keeps the buffers of `system`, which is let go: the system itself (up to
    /// [`LOCAL_SYSTEMS`] of them), or else its matrices that nothing else holds.
    fn let_go(&mut self, mut system: Box<LocalSystem>) {
        self.let_go_base(&mut system.base);
        if system.g.len() >= TRIM_ENTRIES {
            // A grasp's systems are megabytes each: their memory goes back.
            return;
        }
        if self.husks.len() < LOCAL_SYSTEMS {
            self.husks.push(system);
            return;
        }
        for m in [system.g, system.inverse] {
            self.spare(m);
        }
    }

    /// Keeps `m` for the next systems where nothing else holds it, there is room, and it
    /// is smaller than a grasp's ([`TRIM_ENTRIES`]).
    fn spare(&mut self, m: Arc<DMatrix<f64>>) {
        let fits = m.len() < TRIM_ENTRIES && self.matrices.len() < SPARE_MATRICES;
        if fits && Arc::strong_count(&m) == 1 {
            self.matrices.push(m);
        }
    }
}

impl Reuse {
    /// Keeps the matrices of `base`, which is let go (its columns stay), where nothing
    /// else holds them.
    fn let_go_base(&mut self, base: &mut Base) {
        if let Some((g, inverse)) = base.made.take() {
            self.spare(g);
            self.spare(inverse);
        }
    }
}

impl Update {
    /// Itself, less the matrices of a grasp's size ([`TRIM_ENTRIES`]): their memory goes
    /// back, as a grasp's systems' do.
    fn trimmed(mut self) -> Update {
        let Update {
            p,
            b_rr,
            b_rs,
            g_sn,
            x,
            schur,
            xt,
            s_inv,
            ..
        } = &mut self;
        for m in [p, b_rr, b_rs, g_sn, x, schur, xt, s_inv] {
            if m.len() >= TRIM_ENTRIES {
                *m = DMatrix::zeros(0, 0);
            }
        }
        self
    }
}

/// The index lists and matrices of [`Compliance::updated`] (each sized and overwritten
/// before it is read).
#[derive(Default)]
struct Update {
    shared: Vec<usize>,
    shared_old: Vec<usize>,
    added: Vec<usize>,
    removed: Vec<usize>,
    s_new: Vec<usize>,
    s_old: Vec<usize>,
    a_new: Vec<usize>,
    r_old: Vec<usize>,
    p: DMatrix<f64>,
    b_rr: DMatrix<f64>,
    b_rs: DMatrix<f64>,
    g_sn: DMatrix<f64>,
    x: DMatrix<f64>,
    schur: DMatrix<f64>,
    xt: DMatrix<f64>,
    s_inv: DMatrix<f64>,
    column: Vec<f64>,
}

/// A set of node columns whose dense systems were made afresh, from which those of the
/// sets that overlap it are updated ([`Compliance::updated`]): a set's systems are a
/// function of its base and itself, so that the bases alone, in the gel's state, make a
/// gel read back solve as the original bit for bit.
#[derive(Clone, Default)]
struct Base {
    local: Vec<u32>,
    lateral: bool,
    /// Its compliance and inverse, where made (a state read back names the columns).
    made: Option<Shared>,
}

/// A base's compliance and inverse (a set made from it on the same columns holds copies
/// of its own; [`Reuse`] keeps them once nothing else holds them).
type Shared = (Arc<DMatrix<f64>>, Arc<DMatrix<f64>>);

/// A kept set of node columns: its systems, or (read back from a state) its base alone.
#[derive(Clone)]
enum Kept {
    Made(Box<LocalSystem>),
    Named(Base),
}

impl Kept {
    fn base(&self) -> &Base {
        match self {
            Kept::Made(s) => &s.base,
            Kept::Named(b) => b,
        }
    }
}

/// The entries of the compliance of node columns `local` ([`Compliance::entries`]):
/// the responses at them to their loads, three unknowns per column (`+x`, `+y`, down)
/// with `lateral`, else the sinking alone.
struct Entries<'a> {
    responses: &'a Responses,
    local: &'a [u32],
    /// Values per response.
    values: usize,
    lateral: bool,
}

impl Entries<'_> {
    /// Unknowns.
    fn len(&self) -> usize {
        self.local.len() * if self.lateral { 3 } else { 1 }
    }

    /// Unknown `p`'s displacement under a unit load of unknown `q` (cells per internal
    /// force unit; sinking counts positive).
    fn at(&self, p: usize, q: usize) -> f64 {
        if !self.lateral {
            let r = self.responses.down(self.local[q]);
            return -f64::from(r[3 * self.local[p] as usize + 2]);
        }
        let (a, i, b, j) = (p / 3, p % 3, q / 3, q % 3);
        let r = self.response(b, j);
        let u = f64::from(r[3 * self.local[a] as usize + i]);
        if i == 2 {
            -u
        } else {
            u
        }
    }

    /// The response of every node column to local column `b`'s load along `j` (`x`, `y`,
    /// then downward).
    fn response(&self, b: usize, j: usize) -> &[f32] {
        let c = self.local[b];
        match j {
            2 => self.responses.down(c),
            _ => &self.responses.lateral(c)[j * self.values..(j + 1) * self.values],
        }
    }

    /// Column `q` of the entries, `out[p] = self.at(p, q)` for every unknown `p`.
    fn column(&self, q: usize, out: &mut [f64]) {
        if !self.lateral {
            let r = self.responses.down(self.local[q]);
            for (o, &c) in out.iter_mut().zip(self.local) {
                *o = -f64::from(r[3 * c as usize + 2]);
            }
            return;
        }
        let r = self.response(q / 3, q % 3);
        for (o, &c) in out.chunks_exact_mut(3).zip(self.local) {
            let at = &r[3 * c as usize..3 * c as usize + 3];
            o[0] = f64::from(at[0]);
            o[1] = f64::from(at[1]);
            o[2] = -f64::from(at[2]);
        }
    }
}

/// The most columns removed and added, as a fraction of the new set, for which a kept
/// base's dense systems are updated rather than made afresh: beyond a quarter, the
/// update's `k^2 (r + n)` work nears the fresh inverse's `k^3`.
const UPDATE_FRACTION: f64 = 0.25;

/// The factors that [`split_start`] solves with, one per direction: `G^-1_jj + rho W^T W`
/// for the columns' `x`, `y` and vertical loads `j` (`G^-1`'s coupling of one direction
/// with another left out), and the points' rows `W` and `rho` they were made for.
#[derive(Clone)]
struct SplitFactor {
    rows: Vec<Columns>,
    rho: f64,
    /// In single precision: the iterations only start Newton's method, and their
    /// triangular solves, which stream the factors, take half the time.
    factors: [DMatrix<f32>; 3],
}

/// Entries of a system's compliance from which a reset after it was built hands the
/// heap's free pages back to the system ([`crate::release_free_memory`]): 128 Ki entries,
/// 1 MiB. A grasp's dense systems are megabytes each; glibc serves them from its heap once
/// it has raised its mmap threshold to their size, and keeps what they leave as the
/// process's resident memory. (At a reset, not at every system dropped: there it cost the
/// coupled grasp about 4 % of its time, 136.8 against 131.4 ms a step.)
const TRIM_ENTRIES: usize = 1 << 17;

/// Sets of node columns whose dense systems are kept: the frictional problem's and the
/// vertical one of a frame that starts without friction.
pub(super) const LOCAL_SYSTEMS: usize = 2;

/// One solve's answer.
pub(crate) struct Contact {
    /// Lattice points carrying a force: their deformed positions (cells) and forces on
    /// the gel (internal units: +x, +y, downward); for the tests, their indices.
    pub points: Vec<Vector3<f64>>,
    pub forces: Vec<Vector3<f64>>,
    #[cfg(test)]
    pub loaded: Vec<u32>,
    /// For the tests: the lattice points that a small contact's point stood for.
    #[cfg(test)]
    pub replaced: Vec<u32>,
    /// For the tests: the node columns' mean displacement (cells, 3 per column).
    #[cfg(test)]
    pub columns: Vec<f64>,
    /// Displacement (cells) of every top slot.
    pub surface: Vec<Vector3<f64>>,
    /// Largest penetration left (cells), solves and the contact's Newton steps.
    pub penetration: f64,
    pub passes: usize,
    pub iterations: usize,
    /// Whether the penetration left is within the tolerance.
    pub converged: bool,
    /// Where friction's lagged normal forces did not settle ([`MAX_LAGS`] refreshes): the
    /// last refresh's change of the friction they cap, over the load it is tested against.
    pub unsettled: Option<f64>,
}

/// Every node column's response (3 values per node column: its mean displacement, cells
/// per internal force unit) to a unit downward load on one node column, and with
/// friction to unit loads along +x and +y: all of a gel's surface compliance.
///
/// Kept in single precision: solved in double and rounded once, they are read (into the
/// dense systems of the columns under a contact and the surface's displacement) far more
/// than made, and they are a gel's largest data (`9 n^2` numbers for `n` node columns:
/// 25 MB for the default gel, 157 MB for a GelSight Mini's). A rounding of `6e-8` of each
/// entry moves a contact's answer by far less than the solve's tolerance (measured:
/// docs/solvers.md, "The gel's responses in single precision").
pub(crate) struct Responses {
    /// Values per response: 3 per node column.
    len: usize,
    /// Column `c`'s response to its downward load: `down[c * len..][..len]`.
    down: Vec<f32>,
    /// Column `c`'s responses to its +x and +y loads: `lateral[2 * c * len..][..2 * len]`
    /// (empty without friction).
    lateral: Vec<f32>,
}

impl Responses {
    /// The response of every node column to the downward load of column `c`.
    fn down(&self, c: u32) -> &[f32] {
        &self.down[c as usize * self.len..][..self.len]
    }

    /// The responses of every node column to the +x, then the +y load of column `c`.
    fn lateral(&self, c: u32) -> &[f32] {
        &self.lateral[2 * c as usize * self.len..][..2 * self.len]
    }

    /// The numbers a cache file holds: the downward responses, then the lateral ones.
    fn to_flat(&self) -> Vec<f32> {
        [&self.down[..], &self.lateral[..]].concat()
    }

    /// The responses of `columns` node columns from a cache file's numbers, if they are as
    /// many as they must be.
    fn from_flat(mut flat: Vec<f32>, columns: usize, lateral: bool) -> Option<Responses> {
        let len = 3 * columns;
        let down = columns * len;
        if flat.len() != down * if lateral { 3 } else { 1 } {
            return None;
        }
        let lateral = flat.split_off(down);
        Some(Responses {
            len,
            down: flat,
            lateral,
        })
    }
}

/// The responses of the gels alive, by their key ([`Compliance::responses_key`]).
static RESPONSES: Mutex<Vec<(String, Weak<Responses>)>> = Mutex::new(Vec::new());

/// The kind of the responses' cache files ([`gel_cache`]).
const CACHE_KIND: &str = "linear";

/// Tiles solved for together when the responses are computed (one parallel batch: its
/// right-hand sides, about 35 MB on the coarse gel, are the memory it takes).
const TILES_PER_BATCH: usize = 8;

impl Compliance {
    /// The stiffness of `gel` at rest, its top slots, its contact lattice and the
    /// responses of all its node columns: those of a live gel of the same parameters, else
    /// the cache's ([`gel_cache`]), else computed with the factored stiffness (and cached).
    pub fn new(gel: &Gel) -> Result<Compliance, String> {
        let (mut c, newton) = Self::skeleton(gel)?;
        let key = Self::responses_key(gel);
        let mut live = RESPONSES.lock().unwrap_or_else(|e| e.into_inner());
        live.retain(|(_, w)| w.strong_count() > 0);
        if let Some(r) = live
            .iter()
            .find(|(k, _)| *k == key)
            .and_then(|(_, w)| w.upgrade())
        {
            c.responses = r;
            return Ok(c);
        }
        c.fill(newton, gel_cache::Store::from_env().as_ref(), &key)?;
        live.push((key, Arc::downgrade(&c.responses)));
        Ok(c)
    }

    /// Everything of [`Compliance::new`] but the responses (none yet), and the gel's
    /// Newton discretisation, whose stiffness gives them.
    fn skeleton(gel: &Gel) -> Result<(Compliance, Newton), String> {
        let newton = Newton::new(gel)?;
        if newton.u.len() > LINEAR_UNKNOWNS {
            return Err(format!(
                "the grid has {} unknowns, more than the {LINEAR_UNKNOWNS} the linear solver \
                 factors; use a larger dx",
                newton.u.len()
            ));
        }
        let rest: Vec<Vector3<f64>> = gel.top_ref.iter().map(|r| r.cast::<f64>()).collect();
        let [_, ny, nz] = newton.dims;
        let first = Stencil::at(rest.first().ok_or("the gel has no top slots")?);
        if rest
            .iter()
            .any(|x| Stencil::at(x).base[2] != first.base[2] || x.z != rest[0].z)
        {
            return Err("the top slots do not lie at one height".into());
        }
        let levels = (0..newton.dims[0] * ny)
            .map(|c| {
                std::array::from_fn(|k| {
                    let iz = first.base[2] as usize + k;
                    if iz < nz {
                        newton.dof[c * nz + iz]
                    } else {
                        u32::MAX
                    }
                })
            })
            .collect();
        let (lattice, spacing, first_point) = contact_lattice(gel, SUBDIVISION);
        let mut c = Compliance {
            dx: newton.dx,
            origin: newton.origin,
            ny,
            slots: Vec::new(),
            lattice,
            spacing,
            first: first_point,
            top: rest[0].z,
            softness: 1.0 / (PENALTY * spacing[0] * spacing[1]),
            layer: [newton.e_star, newton.layer_slope, newton.thickness],
            levels,
            weights: first.w[2],
            responses: Arc::new(Responses {
                len: 0,
                down: Vec::new(),
                lateral: Vec::new(),
            }),
            computed: 0,
            friction: gel.params.friction,
            anchors: SortedMap::default(),
            lagged: HashMap::new(),
            lagged_before: HashMap::new(),
            last_motion: Vec::new(),
            motion: Vec::new(),
            secant: true,
            last: Vec::new(),
            locals: Vec::new(),
            built_large: false,
            split_unknowns: SPLIT_UNKNOWNS,
            precondition: true,
            vertical: true,
            buffers: Default::default(),
            reuse: Default::default(),
        };
        c.slots = rest.iter().map(|x| c.columns_at(x)).collect();
        Ok((c, newton))
    }

    /// Gives the compliance the responses stored under `key` in `store`, or computes them
    /// with `newton`'s stiffness at rest, factored (and stores them).
    fn fill(
        &mut self,
        mut newton: Newton,
        store: Option<&gel_cache::Store>,
        key: &str,
    ) -> Result<(), String> {
        let lateral = self.friction > 0.0;
        let cached = store
            .and_then(|s| s.read(CACHE_KIND, key))
            .and_then(|flat| Responses::from_flat(flat, self.levels.len(), lateral));
        if let Some(r) = cached {
            self.responses = Arc::new(r);
            self.computed = 0;
            return Ok(());
        }
        newton.linear = LinearSolve::Factor;
        newton.set_region([0, newton.dims[0], 0, newton.dims[1]])?;
        newton
            .evaluate(&[])
            .ok_or("the material is not defined at rest")?;
        let mut system = newton.system.take().ok_or("no stiffness system")?;
        newton.fill_matrix(&mut system);
        system
            .factor()
            .map_err(|_| "the stiffness at rest is not positive definite".to_owned())?;
        let r = self.compute_responses(&system, lateral);
        if let Some(s) = store {
            // A cache that cannot be written costs the next load the solves, no more.
            let _ = s.write(CACHE_KIND, key, &r.to_flat());
        }
        self.responses = Arc::new(r);
        self.computed = self.levels.len();
        Ok(())
    }

    /// What the responses depend on: the physics source (its fingerprint), every gel
    /// parameter to the bit but the friction coefficient, and whether there is friction
    /// (the lateral responses).
    fn responses_key(gel: &Gel) -> String {
        let mut params = gel.params;
        let lateral = params.friction > 0.0;
        params.friction = 0.0;
        format!(
            "linear responses\nphysics {}\n{params:?}\nlateral {lateral}",
            crate::PHYSICS_FINGERPRINT
        )
    }

    /// The node columns and in-plane weights of the surface point at `x` (cells).
    fn columns_at(&self, x: &Vector3<f64>) -> Columns {
        let s = Stencil::at(x);
        std::array::from_fn(|l| {
            let (i, j) = (l / 3, l % 3);
            let (ix, iy) = (s.base[0] + i as i32, s.base[1] + j as i32);
            (
                (ix as usize * self.ny + iy as usize) as u32,
                s.w[0][i] * s.w[1][j],
            )
        })
    }

    /// Rest position (cells) of contact lattice point `k`.
    fn point(&self, k: u32) -> Vector3<f64> {
        let (i, j) = (k as usize / self.lattice[1], k as usize % self.lattice[1]);
        Vector3::new(
            self.first[0] + i as f64 * self.spacing[0],
            self.first[1] + j as f64 * self.spacing[1],
            self.top,
        )
    }

    /// The node columns of tile `t`, in index order.
    fn tile_columns(&self, t: u32) -> impl Iterator<Item = u32> + '_ {
        let per_row = self.ny.div_ceil(TILE);
        let (tx, ty) = (t as usize / per_row, t as usize % per_row);
        let nx = self.levels.len() / self.ny;
        (tx * TILE..((tx + 1) * TILE).min(nx)).flat_map(move |ix| {
            (ty * TILE..((ty + 1) * TILE).min(self.ny)).map(move |iy| (ix * self.ny + iy) as u32)
        })
    }

    /// The responses of every node column to the loads of every node column, solved with
    /// `system` (the stiffness at rest, factored): downward, and with `lateral` along +x
    /// and +y. Each tile of [`TILE`] x [`TILE`] columns is one multi-column solve (its
    /// columns' bits depend on nothing else), the tiles of a batch in parallel.
    fn compute_responses(&self, system: &System, lateral: bool) -> Responses {
        let columns = self.levels.len();
        let len = 3 * columns;
        let mut down = vec![0.0f32; columns * len];
        let mut side = vec![0.0f32; if lateral { 2 * columns * len } else { 0 }];
        let nx = columns / self.ny;
        let tiles = (nx.div_ceil(TILE) * self.ny.div_ceil(TILE)) as u32;
        let all: Vec<u32> = (0..tiles).collect();
        for batch in all.chunks(TILES_PER_BATCH) {
            let axes: &[usize] = if lateral { &[2, 0, 1] } else { &[2] };
            for (c, r) in self.solve_tiles(system, batch, axes) {
                let c = c as usize;
                let single = |to: &mut [f32], from: &[f64]| {
                    to.iter_mut().zip(from).for_each(|(a, &b)| *a = b as f32)
                };
                single(&mut down[c * len..][..len], &r[..len]);
                if lateral {
                    single(&mut side[2 * c * len..][..2 * len], &r[len..]);
                }
            }
        }
        Responses {
            len,
            down,
            lateral: side,
        }
    }

    /// The responses of every node column to unit loads on each column of `tiles` along
    /// `axes` (2: downward; 0, 1: +x, +y), 3 per node column and axis, in that order.
    fn solve_tiles(
        &self,
        system: &System,
        tiles: &[u32],
        axes: &[usize],
    ) -> Vec<(u32, Box<[f64]>)> {
        let groups: Vec<Vec<u32>> = tiles
            .iter()
            .map(|&t| self.tile_columns(t).collect())
            .collect();
        let n = system.n;
        let per = axes.len();
        let mut b = vec![0.0; n * per * groups.iter().map(Vec::len).sum::<usize>()];
        let batch: Vec<u32> = groups.iter().flatten().copied().collect();
        for (rhs, &c) in b.chunks_exact_mut(n * per).zip(&batch) {
            for (rhs, &axis) in rhs.chunks_exact_mut(n).zip(axes) {
                let sign = if axis == 2 { -1.0 } else { 1.0 };
                for (&d, &w) in self.levels[c as usize].iter().zip(&self.weights) {
                    if d != u32::MAX {
                        rhs[3 * d as usize + axis] += sign * w;
                    }
                }
            }
        }
        // Each tile one solve, so that its columns' bits do not depend on the others.
        let mut rest: &mut [f64] = &mut b;
        let mut parts = Vec::new();
        for group in &groups {
            let (head, tail) = rest.split_at_mut(n * per * group.len());
            parts.push(head);
            rest = tail;
        }
        parts
            .into_par_iter()
            .for_each(|part| system.solve_block(part));
        let columns: Vec<Box<[f64]>> = b
            .par_chunks_exact(n * per)
            .map(|xs| {
                let mut r = Vec::with_capacity(3 * per * self.levels.len());
                for x in xs.chunks_exact(n) {
                    for level in &self.levels {
                        let mut u = [0.0; 3];
                        for (&d, &w) in level.iter().zip(&self.weights) {
                            if d != u32::MAX {
                                for (k, u) in u.iter_mut().enumerate() {
                                    *u += w * x[3 * d as usize + k];
                                }
                            }
                        }
                        r.extend_from_slice(&u);
                    }
                }
                r.into_boxed_slice()
            })
            .collect();
        batch.into_iter().zip(columns).collect()
    }

    /// The column loads (+x, +y, downward) of forces `forces` on the gel (the same) at
    /// points with columns `stencils`, in column order, each the sum of its points'
    /// shares in the points' order (of `columns` node columns). `order` holds each
    /// column's sum and whether it has one yet (kept: summed in place, where a sort of a
    /// grasp's 30,000 shares by column allocated its scratch at every call and cost more
    /// than the sums).
    fn column_loads(
        stencils: &[Columns],
        forces: &[Vector3<f64>],
        columns: usize,
        loads: &mut Vec<(u32, Vector3<f64>)>,
        order: &mut LoadOrder,
    ) {
        let (sums, touched) = order;
        refill(touched, columns, false);
        if sums.len() != columns {
            refill(sums, columns, Vector3::zeros());
        }
        for (s, &f) in stencils.iter().zip(forces) {
            if f == Vector3::zeros() {
                continue;
            }
            for &(c, w) in s {
                let c = c as usize;
                let share = f * w;
                if std::mem::replace(&mut touched[c], true) {
                    sums[c] += share;
                } else {
                    sums[c] = share;
                }
            }
        }
        loads.clear();
        loads.extend(
            (0..columns)
                .filter(|&c| touched[c])
                .map(|c| (c as u32, sums[c])),
        );
    }

    /// The mean displacement (cells) of every node column under column loads `loads`
    /// (computed), 3 per column, into `u` (its allocation reused). Each load adds its
    /// column's responses (single precision, a few megabytes a frame streamed from
    /// memory) to every column: in a copy compiled for AVX2 where the processor has it
    /// (the same operations, so the same bits).
    fn column_displacements(&self, loads: &[(u32, Vector3<f64>)], u: &mut Vec<f64>) {
        refill(u, 3 * self.levels.len(), 0.0);
        #[cfg(target_arch = "x86_64")]
        if super::transfer::has_avx2() {
            // SAFETY: the processor has AVX2 (checked just above).
            unsafe { add_responses_avx2(&self.responses, loads, u) };
            return;
        }
        add_responses(&self.responses, loads, u);
    }

    /// Displacement (cells) of the surface point with columns `s` from the columns' mean
    /// displacements `columns`.
    fn displacement(s: &Columns, columns: &[f64]) -> Vector3<f64> {
        let mut u = Vector3::zeros();
        for &(c, w) in s {
            let c = 3 * c as usize;
            u += Vector3::new(columns[c], columns[c + 1], columns[c + 2]) * w;
        }
        u
    }

    /// The smallest signed distance (cells) from the point at `x` (cells) to an indenter
    /// whose bounds hold it; `+inf` if none does.
    fn clearance(&self, x: &Vector3<f64>, indenters: &[StepIndenter]) -> f64 {
        let p = nalgebra::Point3::from(self.origin + x * self.dx);
        indenters
            .iter()
            .filter(|ind| contains(&ind.bounds, &p))
            .map(|ind| ind.shape.distance(&ind.now.inverse_transform_point(&p)) / self.dx)
            .filter(|d| !d.is_nan())
            .fold(f64::INFINITY, f64::min)
    }

    /// The vertical distance (cells) from the point at `x` (cells) up to the indenters'
    /// lower surface: positive where it lies below them, negative inside them (how far
    /// down it must move to leave them); `None` where nothing lies above it. From the
    /// indenters' chords where they have them ([`chord_gap`]); otherwise marched by the
    /// signed distance, which never overshoots an exact distance's surface, and the way
    /// out from inside bisected.
    fn vertical_gap(&self, x: &Vector3<f64>, indenters: &[StepIndenter]) -> Option<f64> {
        self.vertical_gap_to(x, indenters, BISECTIONS)
    }

    /// The vertical gap (cells, negative) from the point at `x` (cells, outside every
    /// indenter) down to the lower surface of an indenter that lies below it within the
    /// gel's thickness: how far the point must sink to pass under it. `None` where the
    /// line down meets none. (A body wholly below the undeformed face was swept in from
    /// above through it: the surface it took with it lies under it.)
    fn gap_under(&self, x: &Vector3<f64>, indenters: &[StepIndenter]) -> Option<f64> {
        let at = |t: f64| self.clearance(&(x - Vector3::z() * t), indenters);
        let (mut t, mut phi) = (0.0, at(0.0));
        for _ in 0..MARCH_STEPS {
            if !phi.is_finite() || t > self.layer[2] {
                return None;
            }
            if phi < 0.0 {
                let below = x - Vector3::z() * t;
                return self.vertical_gap(&below, indenters).map(|g| g - t);
            }
            t += phi.max(MIN_MARCH);
            phi = at(t);
        }
        None
    }

    /// [`Self::vertical_gap`] with `bisections` of the way out from inside: exact from the
    /// indenters' chords where they all have one ([`chord_gap`]), marched otherwise.
    fn vertical_gap_to(
        &self,
        x: &Vector3<f64>,
        indenters: &[StepIndenter],
        bisections: usize,
    ) -> Option<f64> {
        let p = Point3::from(self.origin + x * self.dx);
        match chord_gap(&p, indenters) {
            Some(gap) => gap.map(|g| g / self.dx),
            None => self.marched_gap(x, indenters, bisections),
        }
    }

    /// [`Self::vertical_gap_to`] by marching the signed distance. A march up stops past
    /// the layer's thickness with what it has gone (a gap at least that: the surface never
    /// rises that far, and the point is no candidate). Beside a mesh's side face the march
    /// creeps along it by the face's distance a step; such points past the thickness were
    /// half a grasped hexagon's samples.
    fn marched_gap(
        &self,
        x: &Vector3<f64>,
        indenters: &[StepIndenter],
        bisections: usize,
    ) -> Option<f64> {
        let at = |t: f64| self.clearance(&(x + Vector3::z() * t), indenters);
        let mut phi = at(0.0);
        if phi < 0.0 {
            let (mut inside, mut t) = (0.0, 0.0);
            let mut inside_phi = phi;
            for _ in 0..MARCH_STEPS {
                t += (-phi).max(MIN_MARCH);
                phi = at(-t);
                if phi >= 0.0 {
                    let out = |s: f64| at(-s);
                    let way_out = match bisections >= BRACKETED_FROM {
                        true => bracketed_root(out, (inside, inside_phi), (t, phi), bisections),
                        false => bisected_root(out, inside, t, bisections),
                    };
                    return Some(-way_out);
                }
                (inside, inside_phi) = (t, phi);
            }
            return Some(-t);
        }
        let mut t = 0.0;
        for _ in 0..MARCH_STEPS {
            if !phi.is_finite() {
                return None;
            }
            if phi <= GAP_EPS || t > self.layer[2] {
                return Some(t);
            }
            t += phi;
            phi = at(t);
        }
        phi.is_finite().then_some(t)
    }

    /// The contact lattice points under the indenters' own boxes, grown by
    /// [`NEAR_CELLS`] (the only ones that can touch them).
    #[cfg(test)]
    fn near(&self, indenters: &[StepIndenter]) -> Vec<u32> {
        let mut out = Vec::new();
        self.near_into(indenters, &mut out);
        out
    }

    /// [`Self::near`] into `out` (cleared first).
    fn near_into(&self, indenters: &[StepIndenter], out: &mut Vec<u32>) {
        out.clear();
        for ind in indenters {
            let b = ind
                .shape
                .aabb()
                .transformed(&ind.now)
                .inflated(NEAR_CELLS * self.dx);
            let (lo, hi) = (b.min, b.max);
            let range = |k: usize, a: f64, b: f64| {
                let o = if k == 0 { self.origin.x } else { self.origin.y };
                let to = |v: f64| ((v - o) / self.dx - self.first[k]) / self.spacing[k];
                let n = self.lattice[k] as f64;
                let (a, b) = (to(a).ceil().max(0.0), to(b).floor().min(n - 1.0));
                (a as usize, b as usize, a <= b)
            };
            let (i0, i1, ok_x) = range(0, lo.x, hi.x);
            let (j0, j1, ok_y) = range(1, lo.y, hi.y);
            if ok_x && ok_y {
                for i in i0..=i1 {
                    for j in j0..=j1 {
                        out.push((i * self.lattice[1] + j) as u32);
                    }
                }
            }
        }
        // In index order, each once (the indenters' boxes may overlap).
        if indenters.len() > 1 {
            out.sort_unstable();
            out.dedup();
        }
    }

    /// Index of the indenter nearest to the point at `x` (cells), among those whose
    /// bounds hold it.
    fn nearest(&self, x: &Vector3<f64>, indenters: &[StepIndenter]) -> Option<usize> {
        let p = Point3::from(self.origin + x * self.dx);
        indenters
            .iter()
            .enumerate()
            .filter(|(_, ind)| contains(&ind.bounds, &p))
            .map(|(m, ind)| (m, ind.shape.distance(&ind.now.inverse_transform_point(&p))))
            .filter(|(_, d)| !d.is_nan())
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(m, _)| m)
    }

    /// A tip point for `indenter` (see the module docs, "Small contacts"): where it
    /// reaches below the rest surface and no contact lattice point (rest positions
    /// `rest`, clearances `clear`) lies inside it, the deepest of the surface samples
    /// [`TIP_SAMPLES`](super::newton::subgrid::TIP_SAMPLES) times finer around the lattice point nearest to it, with the share
    /// of a lattice point's face that the penetrating samples cover and its clearance.
    fn tip(
        &self,
        indenter: &StepIndenter,
        rest: &[Vector3<f64>],
        clear: &[f64],
    ) -> Option<(Vector3<f64>, f64, f64, f64)> {
        let own = |x: &Vector3<f64>| self.clearance(x, std::slice::from_ref(indenter));
        // Only points within a lattice diagonal can be next to a tip (the clearance is the
        // nearest indenter's, at most this one's).
        let reach = self.spacing[0].hypot(self.spacing[1]);
        let mut nearest: Option<(f64, usize)> = None;
        for (i, x) in rest.iter().enumerate().filter(|&(i, _)| clear[i] < reach) {
            let d = own(x);
            if d < 0.0 {
                return None;
            }
            if nearest.map_or(true, |(b, _)| d < b) {
                nearest = Some((d, i));
            }
        }
        let centre = rest[nearest?.1];
        let one = std::slice::from_ref(indenter);
        let depth = |x: &Vector3<f64>| {
            self.marched_gap(x, one, FOOTPRINT_BISECTIONS)
                .map_or(0.0, |g| -g)
        };
        let face = self.spacing[0] * self.spacing[1];
        let f = footprint(tip_samples(centre, centre, self.spacing), face, own, depth)?;
        Some((f.at, f.share.min(1.0), f.distance, f.fullness))
    }

    /// The grid's own compliance at the surface point `at` (cells): its sinking under a
    /// unit load on it.
    fn point_compliance(&self, at: &Vector3<f64>) -> f64 {
        let stencil = self.columns_at(at);
        stencil
            .iter()
            .map(|&(a, wa)| {
                let response = self.responses.down(a);
                stencil
                    .iter()
                    .map(|&(b, wb)| -wb * f64::from(response[3 * b as usize + 2]))
                    .sum::<f64>()
                    * wa
            })
            .sum()
    }

    /// The compliance `delta / F` on the layer of a small contact whose rigid footprint
    /// covers `share` lattice points' faces with fullness `fullness` (see
    /// [`FULLNESS_SLOPE`]) and is `rho` times as long as it is wide ([`Footprint::aspect`];
    /// about 1 for a compact one). An elongated footprint is stiffer than the disc of its area: on the
    /// half-space by the elliptical punch's factor ([`elliptic_stiffness`]), and the
    /// bonded layer stiffens it by its semi-major axis `a sqrt(rho)` over the thickness
    /// rather than by the disc's radius `a` (measured, not derived: a ridge lying on the
    /// coarse gel came out 0.38 to 0.64 of the 0.7 mm reference's force as a disc; see
    /// docs/solvers.md, "Long narrow contacts on the linear solver").
    fn patch_compliance(&self, share: f64, fullness: f64, rho: f64) -> f64 {
        let radius = (share * self.spacing[0] * self.spacing[1] / std::f64::consts::PI).sqrt();
        let [e_star, slope, thickness] = self.layer;
        let k = (FULLNESS_SLOPE * fullness + FULLNESS_OFFSET).max(MIN_FULLNESS_STIFFNESS);
        let rho = rho.max(1.0);
        let layer = 1.0 + slope * radius * rho.sqrt() / thickness;
        1.0 / (k * elliptic_stiffness(rho) * e_star * radius * layer)
    }

    /// Surface samples over the box from `lo` to `hi` (cells) grown by a lattice spacing,
    /// at `lo`'s height, as [`tip_samples`] does but at most [`FOOTPRINT_SAMPLES`] per
    /// axis; and the face share (in lattice points) that each stands for.
    fn footprint_samples(&self, lo: Vector3<f64>, hi: Vector3<f64>) -> (Samples, f64) {
        let extent = [0, 1].map(|a| hi[a] - lo[a] + 2.0 * self.spacing[a]);
        let steps = [0, 1].map(|a| extent[a] / FOOTPRINT_SAMPLES as f64);
        if (0..2).all(|a| steps[a] <= self.spacing[a] / TIP_SAMPLES as f64) {
            return tip_samples(lo, hi, self.spacing);
        }
        let samples = Samples {
            from: Vector3::new(lo.x - self.spacing[0], lo.y - self.spacing[1], lo.z),
            step: steps,
            counts: [FOOTPRINT_SAMPLES; 2],
        };
        (
            samples,
            steps[0] * steps[1] / (self.spacing[0] * self.spacing[1]),
        )
    }

    /// Contacts smaller than the grid resolves that reach lattice points (see the module
    /// docs, "Small contacts"). A patch is a connected set of lattice points inside the
    /// indenters (clearance `clear` below zero: the rigid footprint on the rest surface).
    /// Under a patch more compliant than a point load on the grid, the grid deflects as
    /// under a point load, and the lattice points, which lie far above the deepest point
    /// under a sphere or a cone tip, sample the indenter too coarsely: such a patch
    /// becomes one point as a tip does, at the deepest of the surface samples over it,
    /// with their share of the face and the patch's compliance less the grid's in series
    /// with its penalty, and its lattice points leave the contact. Larger patches keep
    /// their lattice points. The new points are appended to `near`, `rest`, `clear` and
    /// `soft` (indices from `first`); the lattice points they stand for are left in
    /// `scratch.replaced`.
    #[allow(clippy::too_many_arguments)]
    fn small_contacts(
        &mut self,
        first: u32,
        indenters: &[StepIndenter],
        near: &mut Vec<u32>,
        rest: &mut Vec<Vector3<f64>>,
        clear: &mut Vec<f64>,
        soft: &mut Vec<f64>,
        scratch: &mut SmallScratch,
    ) {
        let SmallScratch {
            inside,
            seen,
            flat,
            patches,
            replaced,
        } = scratch;
        replaced.clear();
        let count = (self.lattice[0] * self.lattice[1]) as u32;
        let lattice = near.partition_point(|&k| k < count);
        let [nx, ny] = self.lattice.map(|n| n as i64);
        if !inside.fill(&near[..lattice], |i| clear[i] < 0.0, ny) {
            return;
        }
        refill(seen, lattice, false);
        flat.clear();
        patches.clear();
        for start in 0..lattice {
            if !(clear[start] < 0.0) || seen[start] {
                continue;
            }
            seen[start] = true;
            // This patch's points: `flat[from..]`.
            let from = flat.len();
            flat.push(start);
            let list = &mut *flat;
            let mut next = from;
            while next < list.len() {
                let k = near[list[next]] as i64;
                next += 1;
                let (ix, iy) = (k / ny, k % ny);
                for x in (ix - 1).max(0)..=(ix + 1).min(nx - 1) {
                    for y in (iy - 1).max(0)..=(iy + 1).min(ny - 1) {
                        if let Some(j) = inside.get(x, y) {
                            if !seen[j] {
                                seen[j] = true;
                                list.push(j);
                            }
                        }
                    }
                }
            }
            // Patches the lattice resolves need no finer look: a cone's footprint of this
            // size, and a footprint two thirds its radius, are stiffer than the grid's
            // point load (the lattice points' count measures a large footprint well).
            let grid = self.point_compliance(&rest[start]);
            let list = &flat[from..];
            let n = list.len() as f64;
            if self.patch_compliance(n / (1.5f64).powi(2), CONE_FULLNESS, 1.0) < grid {
                flat.truncate(from);
                continue;
            }
            let lo = list
                .iter()
                .fold(Vector3::repeat(f64::INFINITY), |m, &i| m.inf(&rest[i]));
            let hi = list
                .iter()
                .fold(Vector3::repeat(f64::NEG_INFINITY), |m, &i| m.sup(&rest[i]));
            let distance = |x: &Vector3<f64>| self.clearance(x, indenters);
            let depth = |x: &Vector3<f64>| {
                self.marched_gap(x, indenters, FOOTPRINT_BISECTIONS)
                    .map_or(0.0, |g| -g)
            };
            let face = self.spacing[0] * self.spacing[1];
            let samples = self.footprint_samples(lo, hi);
            #[cfg(test)]
            let bound = DISTANCE_BOUND.with(|b| b.get().0);
            #[cfg(not(test))]
            let bound = true;
            if bound && self.stiff_by_distances(&samples, indenters, grid) {
                flat.truncate(from);
                continue;
            }
            let Some(f) = footprint(samples, face, distance, depth) else {
                flat.truncate(from);
                continue;
            };
            let missing =
                self.patch_compliance(f.share, f.fullness, f.aspect) - self.point_compliance(&f.at);
            if missing > 0.0 {
                let patch = (from, flat.len());
                patches.push((patch, f.at, f.distance, self.softness / f.share + missing));
            } else {
                flat.truncate(from);
            }
        }
        for (k, &((from, to), at, d, compliance)) in patches.iter().enumerate() {
            for &i in &flat[from..to] {
                clear[i] = f64::INFINITY;
                replaced.push(near[i]);
            }
            near.push(first + k as u32);
            rest.push(at);
            clear.push(d);
            soft.push(compliance);
        }
    }

    /// Whether a patch's footprint, sampled at `samples`, is stiffer than half the grid's
    /// point load `grid` by what its samples' signed distances alone tell: a query each,
    /// where [`footprint`] marches each one's depth. Its share of the face is the
    /// penetrating samples', and its fullness at least their mean distance inside over the
    /// deepest the indenters reach below the face (a point's vertical depth inside is at
    /// least its distance to the surface, and their bounding boxes hold them); the compliance of
    /// that share and fullness, compact, bounds the footprint's from above. Such a patch
    /// keeps its lattice points, as [`footprint`]'s would (its compliance less the grid's
    /// at its deepest sample negative: the grid's varies by about a fifth between points,
    /// so the half leaves room for that). A 5 mm sphere pressed 0.5 to 1 mm into the
    /// default gel on the linear solver (`tacrom probe press_sweep`): its patch of about
    /// 170 lattice points, which the first look (a cone's share, two thirds its radius)
    /// does not settle, is settled so at 250 of 262 solves, and the small contacts' search
    /// took 21 us a solve instead of 99.
    fn stiff_by_distances(
        &self,
        (samples, share): &(Samples, f64),
        indenters: &[StepIndenter],
        grid: f64,
    ) -> bool {
        let lowest = indenters
            .iter()
            .map(|i| (i.shape.aabb().transformed(&i.now).min.z - self.origin.z) / self.dx)
            .fold(f64::INFINITY, f64::min);
        let reach = samples.from.z - lowest;
        if !(reach > 0.0 && grid > 0.0) {
            return false;
        }
        let (mut inside, mut sum) = (0usize, 0.0);
        for x in samples.points() {
            let d = self.clearance(&x, indenters);
            if d < 0.0 {
                inside += 1;
                sum -= d;
            }
        }
        if inside == 0 {
            return false;
        }
        let n = inside as f64;
        let fullness = (sum / (n * reach)).min(1.0);
        let stiff = self.patch_compliance(n * share, fullness, 1.0) < 0.5 * grid;
        #[cfg(test)]
        if stiff {
            DISTANCE_BOUND.with(|b| b.set((b.get().0, b.get().1 + 1)));
        }
        stiff
    }

    /// Where the anchor `a` is now (cells).
    fn anchor_at(&self, a: &Anchor, indenters: &[StepIndenter]) -> Option<Vector3<f64>> {
        let ind = indenters.get(a.indenter)?;
        Some(((ind.now * a.local).coords - self.origin) / self.dx)
    }

    /// The compliance of the node columns `local` (computed) under each other's loads,
    /// symmetrised (reciprocal up to the solves' round-off): their sinking under their
    /// downward loads, or with `lateral` all three components (+x, +y, sinking) under all
    /// three loads (+x, +y, downward), 3 per column.
    /// The node columns that the points of `stencils` load (their responses computed),
    /// less those whose nodes are all fixed (beyond the gel's edge: they do not move, and
    /// their weights are left out with them), and the points' rows of weights over them.
    #[cfg(test)]
    fn columns_under(&self, stencils: &[Columns]) -> (Vec<u32>, Vec<Columns>) {
        let (mut local, mut rows) = (Vec::new(), Vec::new());
        self.columns_under_into(stencils, &mut local, &mut rows);
        (local, rows)
    }

    /// [`Self::columns_under`] into `local` and `rows` (cleared first).
    fn columns_under_into(
        &self,
        stencils: &[Columns],
        local: &mut Vec<u32>,
        rows: &mut Vec<Columns>,
    ) {
        local.clear();
        local.extend(stencils.iter().flat_map(|s| s.map(|(c, _)| c)));
        local.sort_unstable();
        local.dedup();
        local.retain(|&c| self.levels[c as usize].iter().any(|&d| d != u32::MAX));
        rows.clear();
        rows.extend(stencils.iter().map(|s| {
            s.map(|(c, w)| match local.binary_search(&c) {
                Ok(k) => (k as u32, w),
                Err(_) => (0, 0.0),
            })
        }));
    }

    /// The compliance of node columns `local` (three unknowns per column with `lateral`,
    /// else their sinking alone): the columns' responses at each other, made symmetric
    /// (the mean of the two ways, each pair read once for both).
    fn local_compliance(&self, local: &[u32], lateral: bool) -> DMatrix<f64> {
        let mut g = DMatrix::zeros(0, 0);
        self.local_compliance_into(local, lateral, &mut g);
        g
    }

    /// [`Compliance::local_compliance`] into `g` (its allocation reused).
    fn local_compliance_into(&self, local: &[u32], lateral: bool, g: &mut DMatrix<f64>) {
        let entries = self.entries(local, lateral);
        let n = entries.len();
        // Column by column (one response read along its rows), then made symmetric in
        // place: the same values as `symmetric(n, |p, q| entries.at(p, q))`.
        let g = reshaped(g, n, n);
        for q in 0..n {
            entries.column(q, g.column_mut(q).as_mut_slice());
        }
        for q in 0..n {
            for p in q + 1..n {
                let v = (g[(p, q)] + g[(q, p)]) * 0.5;
                g[(p, q)] = v;
                g[(q, p)] = v;
            }
        }
    }

    /// The entries of [`Compliance::local_compliance`], read from the responses.
    fn entries<'a>(&'a self, local: &'a [u32], lateral: bool) -> Entries<'a> {
        Entries {
            responses: &self.responses,
            local,
            values: 3 * self.levels.len(),
            lateral,
        }
    }

    /// The dense systems of node columns `local`: kept from an earlier contact, updated
    /// from the kept base that shares the most columns with them where it shares all but
    /// [`UPDATE_FRACTION`] ([`Compliance::updated`]), or made afresh (and then their own
    /// base); `None` where their compliance is not positive definite. The choice reads the
    /// bases alone, so a gel read back from a state chooses as the original.
    fn take_local(&mut self, local: &[u32], lateral: bool) -> Option<Box<LocalSystem>> {
        let shared = |b: &Base| {
            local
                .iter()
                .filter(|c| b.local.binary_search(c).is_ok())
                .count()
        };
        let nearest = (0..self.locals.len())
            .filter(|&i| self.locals[i].base().lateral == lateral)
            .map(|i| (shared(self.locals[i].base()), i))
            .max();
        let near = nearest.filter(|&(n, i)| {
            let changed = (local.len() - n) + (self.locals[i].base().local.len() - n);
            n > 0 && changed as f64 <= UPDATE_FRACTION * local.len() as f64
        });
        if let Some((_, i)) = near {
            // The kept set's systems, let go here, lend their buffers to the new ones.
            let (mut base, husk) = match self.locals.remove(i) {
                Kept::Made(system) if system.local == local => return Some(system),
                Kept::Made(mut system) => (std::mem::take(&mut system.base), Some(system)),
                Kept::Named(base) => (base, self.reuse.get_mut().husks.pop()),
            };
            let (g, inverse) = match base.made.take() {
                Some(made) => made,
                None => {
                    let g = self.local_compliance(&base.local, lateral);
                    let inverse = spd_inverse(&g)?;
                    (Arc::new(g), Arc::new(inverse))
                }
            };
            base.made = Some((g.clone(), inverse.clone()));
            let mut husk = husk.unwrap_or_else(LocalSystem::empty);
            if base.local == local {
                let spare = &mut self.reuse.get_mut().matrices;
                copy_into(&mut husk.g, &g, spare);
                copy_into(&mut husk.inverse, &inverse, spare);
                return Some(self.system(local, base, husk));
            }
            let reuse = self.reuse.get_mut();
            let mut update = std::mem::take(&mut reuse.update);
            let spare = &mut reuse.matrices;
            let (g, inverse) = (unique(&mut husk.g, spare), unique(&mut husk.inverse, spare));
            let made = self.updated(&base, local, g, inverse, &mut update);
            self.reuse.get_mut().update = update.trimmed();
            if made.is_some() {
                return Some(self.system(local, base, husk));
            }
        }
        // Made afresh, in the buffers of the systems let go last, or else of the oldest
        // kept, which these push out.
        let mut husk = self.reuse.get_mut().husks.pop();
        if husk.is_none() && self.locals.len() >= LOCAL_SYSTEMS {
            if let Kept::Made(oldest) = self.locals.remove(0) {
                husk = Some(oldest);
            }
        }
        let mut husk = husk.unwrap_or_else(LocalSystem::empty);
        let mut columns = std::mem::take(&mut husk.base.local);
        let reuse = self.reuse.get_mut();
        reuse.let_go_base(&mut husk.base);
        let mut update = std::mem::take(&mut reuse.update);
        let spare = &mut reuse.matrices;
        let (g, inverse) = (unique(&mut husk.g, spare), unique(&mut husk.inverse, spare));
        self.local_compliance_into(local, lateral, g);
        let copy = reshaped(&mut update.p, g.nrows(), g.ncols());
        copy.copy_from(g);
        let inverted = spd_inverse_into(copy, inverse);
        self.reuse.get_mut().update = update.trimmed();
        inverted?;
        columns.clear();
        columns.extend_from_slice(local);
        // The base keeps copies of its own: each set's matrices are held by it alone, and
        // go to the spares when it is let go.
        let spare = &mut self.reuse.get_mut().matrices;
        let (mut g, mut inverse) = (spare_matrix(spare), spare_matrix(spare));
        copy_into(&mut g, &husk.g, spare);
        copy_into(&mut inverse, &husk.inverse, spare);
        let base = Base {
            local: columns,
            lateral,
            made: Some((g, inverse)),
        };
        Some(self.system(local, base, husk))
    }

    /// The dense systems of `local` from `base` and their compliance and its inverse,
    /// which `system` holds (its own: a base keeps copies): the rest of its buffers (its
    /// columns, single-precision inverse, workspace and vertical inverse) were a system's
    /// that was let go, and are reused.
    fn system(
        &mut self,
        local: &[u32],
        base: Base,
        mut system: Box<LocalSystem>,
    ) -> Box<LocalSystem> {
        self.built_large |= system.g.len() >= TRIM_ENTRIES;
        system.local.clear();
        system.local.extend_from_slice(local);
        // The frictional solve's Newton steps assemble their systems on it in single
        // precision from [`MIXED_UNKNOWNS`] on.
        let k = system.inverse.nrows();
        let mut single = system
            .inverse32
            .take()
            .unwrap_or_else(|| DMatrix::zeros(0, 0));
        if base.lateral && k >= MIXED_UNKNOWNS {
            let inverse = &*system.inverse;
            reshaped(&mut single, k, k).zip_apply(inverse, |s, x| *s = x as f32);
            system.inverse32 = Some(single);
        }
        system.base = base;
        system.split = None;
        if let Some(Some(vertical)) = system.vertical.take() {
            *system.vertical_spare.get_mut() = vertical;
        }
        system
    }

    /// The compliance of node columns `local` and its inverse from those of `base` (made),
    /// on columns that overlap them: the shared columns' block of the compliance copied, the rest read
    /// from the responses; the inverse by removing `kept`'s columns that are gone (the
    /// shared block's inverse is `B_ss - B_sr B_rr^-1 B_rs` in `kept`'s inverse `B`) and
    /// bordering it with the new ones (their Schur complement `S = G_nn - G_ns P G_sn`, `P`
    /// the shared block's inverse: `[[P + X S^-1 X^T, -X S^-1], [-S^-1 X^T, S^-1]]` with `X
    /// = P G_sn`). Work of `k^2 (r + n)` for `k` unknowns, `r` and `n` removed and new,
    /// against a factorisation and an inverse's `k^3`. `None` where a Schur complement is
    /// not positive definite.
    fn updated(
        &self,
        base: &Base,
        local: &[u32],
        g: &mut DMatrix<f64>,
        inverse: &mut DMatrix<f64>,
        scratch: &mut Update,
    ) -> Option<()> {
        let (kept_g, kept_inverse) = base.made.as_ref()?;
        let per = if base.lateral { 3 } else { 1 };
        let Update {
            shared,
            shared_old,
            added,
            removed,
            s_new,
            s_old,
            a_new,
            r_old,
            p,
            b_rr,
            b_rs,
            g_sn,
            x,
            schur,
            xt,
            s_inv,
            column,
        } = scratch;
        let unknowns = |columns: &[usize], out: &mut Vec<usize>| {
            out.clear();
            out.extend(
                columns
                    .iter()
                    .flat_map(|&c| (0..per).map(move |i| per * c + i)),
            );
        };
        // Positions (in `local`, and in `kept.local`) of the shared columns, the new ones,
        // and the removed ones.
        shared.clear();
        shared_old.clear();
        added.clear();
        for (a, c) in local.iter().enumerate() {
            match base.local.binary_search(c) {
                Ok(b) => {
                    shared.push(a);
                    shared_old.push(b);
                }
                Err(_) => added.push(a),
            }
        }
        removed.clear();
        removed.extend(
            (0..base.local.len()).filter(|b| local.binary_search(&base.local[*b]).is_err()),
        );
        unknowns(shared, s_new);
        unknowns(shared_old, s_old);
        unknowns(added, a_new);
        unknowns(removed, r_old);
        let (ns, na, nr) = (s_new.len(), a_new.len(), r_old.len());
        let b = &**kept_inverse;
        // The shared block's inverse.
        let p = shaped(p, ns, ns);
        fill(p, |i, j| b[(s_old[i], s_old[j])]);
        if nr > 0 {
            let b_rr = shaped(b_rr, nr, nr);
            fill(b_rr, |i, j| b[(r_old[i], r_old[j])]);
            let b_rs = shaped(b_rs, nr, ns);
            fill(b_rs, |i, j| b[(r_old[i], s_old[j])]);
            // `B_rr^-1 B_rs`, solved in place of a copy of `B_rs`.
            let y = shaped(xt, nr, ns);
            y.copy_from(b_rs);
            small_or_faer_solve(b_rr, y)?;
            add_product(p, -1.0, b_rs, true, y, false);
        }
        // The new compliance: the shared block kept, the new columns' rows read.
        let k = ns + na;
        let entries = self.entries(local, base.lateral);
        // (Every entry of `g` and of `inverse` is written below.)
        let g = shaped(g, k, k);
        for j in 0..ns {
            for i in 0..ns {
                g[(s_new[i], s_new[j])] = kept_g[(s_old[i], s_old[j])];
            }
        }
        column.clear();
        column.resize(k, 0.0);
        for &q in a_new.iter() {
            entries.column(q, column);
            for r in 0..k {
                let v = (column[r] + entries.at(q, r)) * 0.5;
                g[(r, q)] = v;
                g[(q, r)] = v;
            }
        }
        let inverse = shaped(inverse, k, k);
        if na == 0 {
            for j in 0..ns {
                for i in 0..ns {
                    inverse[(s_new[i], s_new[j])] = p[(i, j)];
                }
            }
        } else {
            let g_sn = shaped(g_sn, ns, na);
            fill(g_sn, |i, j| g[(s_new[i], a_new[j])]);
            let x = reshaped(x, ns, na);
            add_product(x, 1.0, p, false, g_sn, false);
            let schur = shaped(schur, na, na);
            fill(schur, |i, j| g[(a_new[i], a_new[j])]);
            add_product(schur, -1.0, g_sn, true, x, false);
            // `(X S^-1)^T = S^-1 X^T`, and `S^-1`.
            let xt = shaped(xt, na, ns);
            fill(xt, |i, j| x[(j, i)]);
            let s_inv = reshaped(s_inv, na, na);
            s_inv.fill_with_identity();
            small_or_faer_solve(schur, xt)?;
            // (The factor is kept in `schur`: the identity's solve is the inverse.)
            solve_with_factor(schur, s_inv);
            s_inv.fill_upper_triangle_with_lower_triangle();
            add_product(p, 1.0, xt, true, x, true);
            for j in 0..ns {
                for i in 0..ns {
                    inverse[(s_new[i], s_new[j])] = p[(i, j)];
                }
            }
            for j in 0..na {
                for i in 0..ns {
                    inverse[(s_new[i], a_new[j])] = -xt[(j, i)];
                    inverse[(a_new[j], s_new[i])] = -xt[(j, i)];
                }
                for i in 0..na {
                    inverse[(a_new[i], a_new[j])] = s_inv[(i, j)];
                }
            }
        }
        // The two triangles agree to round-off: the lower one for both, as a fresh inverse.
        inverse.fill_upper_triangle_with_lower_triangle();
        Some(())
    }

    /// Keeps `system` for the next contacts (the oldest kept goes beyond
    /// [`LOCAL_SYSTEMS`]).
    fn put_local(&mut self, system: Box<LocalSystem>) {
        self.locals.push(Kept::Made(system));
        if self.locals.len() > LOCAL_SYSTEMS {
            if let Kept::Made(oldest) = self.locals.remove(0) {
                self.reuse.get_mut().let_go(oldest);
            }
        }
    }

    /// The contact of the gel's surface with `indenters` (which started the frame at
    /// `starts`), to a penetration of at most `tolerance` times the deepest sinking beyond
    /// what the contact's compliance allows; with friction, until a refresh of the lagged
    /// normal forces would change the friction by at most `tolerance` of their sum.
    pub fn contact(
        &mut self,
        indenters: &[StepIndenter],
        starts: &[Isometry3<f64>],
        tolerance: f64,
    ) -> Contact {
        // The frame's vectors, their allocations kept from the frame before.
        let ContactBuffers {
            mut near,
            mut rest,
            mut clear,
            mut soft,
            mut stencils,
            mut forces,
            mut u,
            mut delta,
            mut known,
            mut lag,
            mut offsets,
            mut columns,
            mut cand,
            mut chosen,
            mut local,
            mut rows,
            mut d,
            mut eps,
            mut present,
            mut surface,
            mut answer,
            l: mut loads,
            steps,
            mut normal,
            mut caps,
            mut anchors,
            mut risen,
            mut points,
            loaded: mut loaded_forces,
            mut small,
            mut order,
        } = std::mem::take(self.buffers.get_mut());
        self.near_into(indenters, &mut near);
        rest.clear();
        rest.extend(near.iter().map(|&k| self.point(k)));
        clear.clear();
        clear.extend(rest.iter().map(|x| self.clearance(x, indenters)));
        // Each point's contact compliance; a tip point's, over its share of the face.
        refill(&mut soft, near.len(), self.softness);
        let count = (self.lattice[0] * self.lattice[1]) as u32;
        for (m, indenter) in indenters.iter().enumerate() {
            if let Some((at, share, c, fullness)) = self.tip(indenter, &rest, &clear) {
                // Its penalty over its share of the face, in series with what the grid
                // misses of the patch's compliance. A tip's footprint is sampled around
                // one lattice point only, so its length is unknown: taken as compact.
                let missing =
                    self.patch_compliance(share, fullness, 1.0) - self.point_compliance(&at);
                near.push(count + m as u32);
                rest.push(at);
                clear.push(c);
                soft.push(self.softness / share + missing.max(0.0));
            }
        }
        let first = count + indenters.len() as u32;
        self.small_contacts(
            first, indenters, &mut near, &mut rest, &mut clear, &mut soft, &mut small,
        );
        #[cfg(test)]
        let _replaced = small.replaced.clone();
        stencils.clear();
        stencils.extend(rest.iter().map(|x| self.columns_at(x)));
        refill(&mut forces, near.len(), Vector3::zeros());
        refill(&mut u, near.len(), Vector3::zeros());
        let (mut passes, mut iterations) = (0, 0);
        let mut penetration = 0.0;
        let mut converged = false;
        let mut unsettled = None;
        refill(&mut columns, 3 * self.levels.len(), 0.0);
        let friction = self.friction > 0.0;
        // Each point's constraint in the linear model's small-displacement setting: it
        // sinks at least as deep as the indenters' lower surface reaches below its rest
        // position (the vertical distance, negative where they are above it). Inside an
        // indenter first; outside, only within the candidates' reach (the vertical distance
        // is at least the signed distance).
        let depth = |c: &Self, x: &Vector3<f64>| {
            c.vertical_gap(x, indenters)
                .map_or(f64::NEG_INFINITY, |h| -h)
        };
        refill(&mut delta, near.len(), f64::NEG_INFINITY);
        refill(&mut known, near.len(), false);
        for i in (0..near.len()).filter(|&i| clear[i] < 0.0) {
            (delta[i], known[i]) = (depth(self, &rest[i]), true);
        }
        let mut deepest = delta.iter().copied().fold(0.0, f64::max);
        if deepest <= 0.0 {
            // No point inside an indenter at rest, but one may lie wholly below the face
            // (swept in through it): the points over it sink to its lower surface.
            for i in 0..near.len() {
                if let Some(gap) = self.gap_under(&rest[i], indenters) {
                    (delta[i], known[i]) = (-gap, true);
                }
            }
            deepest = delta.iter().copied().fold(0.0, f64::max);
        }
        let mut reach = CANDIDATE_FRACTION * deepest;
        for i in 0..near.len() {
            if !known[i] && clear[i] < reach {
                (delta[i], known[i]) = (depth(self, &rest[i]), true);
            }
        }
        // With friction, the answer depends on the path: the forces, and the lagged normal
        // forces, start from the last frame's; where the contact moves on slowly along the
        // last frame's motion, extrapolated along the last frame's change of them.
        let along = self.secant_start(indenters, starts);
        for (f, k) in forces.iter_mut().zip(&near) {
            *f = self.lagged.get(k).copied().unwrap_or(Vector3::zeros());
            if let (Some(s), true) = (along, f.z > 0.0) {
                let before = self
                    .lagged_before
                    .get(k)
                    .copied()
                    .unwrap_or(Vector3::zeros());
                let next = *f + (*f - before) * s;
                *f = if next.z > 0.0 { next } else { Vector3::zeros() };
            }
        }
        lag.clear();
        lag.extend(forces.iter().map(|f| f.z));
        // Whether the last frame pressed some of these points: then its normal forces are
        // the first lagged ones and its loads the start (a grasp held, a press moving
        // on), not a solve without friction and the larger stick radii, which in a held
        // grasp took 57 Newton steps a frame to find the frame before's answer again.
        let from_last = friction && lag.iter().any(|&f| f > 0.0);
        refill(&mut offsets, near.len(), Vector2::zeros());

        for pass in 0..MAX_PASSES {
            passes = pass + 1;
            if deepest <= 0.0 && forces.iter().all(|f| f.z == 0.0) {
                converged = true;
                penetration = 0.0;
                break;
            }
            cand.clear();
            cand.extend((0..near.len()).filter(|&i| delta[i] > -reach || forces[i].z > 0.0));
            // The node columns the candidates touch, and their compliance.
            chosen.clear();
            chosen.extend(cand.iter().map(|&i| stencils[i]));
            self.columns_under_into(&chosen, &mut local, &mut rows);
            if local.is_empty() {
                break;
            }
            let Some(mut system) = self.take_local(&local, friction) else {
                break;
            };
            let mut kept = system.split.take();
            d.clear();
            d.extend(cand.iter().map(|&i| delta[i]));
            eps.clear();
            eps.extend(cand.iter().map(|&i| soft[i]));
            let mut solved = true;
            if friction && pass == 0 && !from_last {
                // The normal forces without friction first: the first lagged ones (the
                // last frame's lateral forces kept, to start the lateral loads from).
                // Without friction no column carries a lateral load: the vertical block's
                // problem.
                let l = sized(&mut loads, local.len());
                l.fill(0.0);
                let f = &mut normal;
                let mut solve = |vertical: &LocalSystem| {
                    let problem = Problem {
                        g: &vertical.g,
                        inverse: &vertical.inverse,
                        inverse32: None,
                        scratch: &vertical.scratch,
                        steps: &steps,
                        precondition: false,
                        w: &rows,
                        delta: &d,
                        eps: &eps,
                    };
                    penalty_contact_into(&problem, l, f)
                };
                let answer = self.take_local(&local, false).and_then(|vertical| {
                    let answer = solve(&vertical);
                    self.put_local(vertical);
                    answer
                });
                match answer {
                    Some(steps) => {
                        iterations += steps;
                        for (&i, &fi) in cand.iter().zip(&normal) {
                            (forces[i].z, lag[i]) = (fi, fi);
                        }
                    }
                    None => solved = false,
                }
            }
            system.scratch.new_pass();
            let problem = Problem {
                g: &system.g,
                inverse: &system.inverse,
                inverse32: system.inverse32.as_ref(),
                scratch: &system.scratch,
                steps: &steps,
                precondition: self.precondition,
                w: &rows,
                delta: &d,
                eps: &eps,
            };
            // Start from the columns' present loads.
            Self::column_loads(
                &stencils,
                &forces,
                self.levels.len(),
                &mut present,
                &mut order,
            );
            let load = |c: &u32| {
                present
                    .binary_search_by_key(c, |&(col, _)| col)
                    .map_or(Vector3::zeros(), |i| present[i].1)
            };
            if !solved {
                // The first lagged normal forces failed: the frame ends unconverged (the
                // frictionless solve below is on the vertical block alone).
            } else if friction {
                let l = sized(&mut loads, 3 * local.len());
                for (l, x) in l
                    .iter_mut()
                    .zip(local.iter().flat_map(|c| load(c).data.0[0]))
                {
                    *l = x;
                }
                let mut settled = false;
                // The lagged forces settle once a refresh would change the friction they
                // cap by at most the tolerance ([`refreshed_friction`]), relative to the
                // larger of the frame's load at its start and now: a grasp let go within a
                // frame (a coupled finger opening, its gel solved again between the
                // sensor's evaluations) went from newtons to a touch of a micron, and
                // against that touch's own load its lags never settled.
                let start_total: f64 = cand.iter().map(|&i| lag[i]).sum();
                let mut last_change = f64::INFINITY;
                for lags in 0..MAX_LAGS {
                    // A frame that slides as a whole, from the last frame's answer, on a
                    // contact too small to split: its normal forces first found for the
                    // friction there ([`vertical_start`], in passes), the caps following
                    // them.
                    let may_slide = lags == 0
                        && from_last
                        && self.vertical
                        && 3 * local.len() < self.split_unknowns;
                    let mut vertical: Option<&DMatrix<f64>> = None;
                    let mut pass = 0;
                    loop {
                        self.frictions(
                            &cand,
                            &lag,
                            &near,
                            &rest,
                            &stencils,
                            starts,
                            indenters,
                            &mut offsets,
                            &mut caps,
                            &mut anchors,
                        );
                        if pass == 0
                            && may_slide
                            && StartDemand::at(&problem, &caps, &anchors, l).asks_vertical()
                        {
                            vertical = system.vertical();
                        }
                        let Some(inverse_zz) = vertical.filter(|_| pass < VERTICAL_PASSES) else {
                            break;
                        };
                        if vertical_start(
                            &problem,
                            inverse_zz,
                            self.friction,
                            &caps,
                            &anchors,
                            tolerance,
                            l,
                            &mut normal,
                        )
                        .is_none()
                        {
                            break;
                        }
                        for (&i, &fi) in cand.iter().zip(&normal) {
                            lag[i] = fi;
                        }
                        pass += 1;
                    }
                    // A wide contact's first frame starts as a warm one ([`WIDE_FIRST_FRAME`]).
                    let wide_first = WIDE_FIRST_FRAME && 3 * local.len() >= self.split_unknowns;
                    let friction = Friction {
                        caps: &caps,
                        anchors: &anchors,
                        warm: lags > 0 || from_last || wide_first,
                        residual: (INNER_RESIDUAL * tolerance).max(FRICTION_RESIDUAL),
                        predict_stick: PREDICT_STICK && lags == 0 && from_last,
                        split: self.split_unknowns,
                    };
                    let Some(steps) =
                        frictional_contact(&problem, &friction, &mut kept, l, &mut answer)
                    else {
                        solved = false;
                        break;
                    };
                    iterations += steps;
                    forces.fill(Vector3::zeros());
                    let (mut change, mut total) = (0.0, 0.0);
                    for ((&i, &fi), &cap) in cand.iter().zip(&answer).zip(&caps) {
                        forces[i] = fi;
                        // (Tip points carry no friction.)
                        let mu = if near[i] < count { self.friction } else { 0.0 };
                        change += refreshed_friction(&fi, lag[i], cap, mu);
                        total += fi.z;
                        lag[i] = fi.z;
                    }
                    last_change = change / total.max(start_total);
                    if change <= tolerance * total.max(start_total) {
                        settled = true;
                        break;
                    }
                }
                if solved && !settled {
                    unsettled = Some(last_change);
                }
                solved &= settled;
            } else {
                let l = sized(&mut loads, local.len());
                l.iter_mut().zip(&local).for_each(|(l, c)| *l = load(c).z);
                match penalty_contact_into(&problem, l, &mut normal) {
                    Some(steps) => {
                        iterations += steps;
                        forces.fill(Vector3::zeros());
                        for (&i, &fi) in cand.iter().zip(&normal) {
                            forces[i] = Vector3::new(0.0, 0.0, fi);
                        }
                    }
                    None => solved = false,
                }
            }
            system.split = kept;
            self.put_local(system);
            if !solved {
                break;
            }
            Self::column_loads(
                &stencils,
                &forces,
                self.levels.len(),
                &mut present,
                &mut order,
            );
            self.column_displacements(&present, &mut columns);
            for (u, s) in u.iter_mut().zip(&stencils) {
                *u = Self::displacement(s, &columns);
            }
            let sinking = u.iter().map(|v| -v.z).fold(0.0, f64::max);
            // The constraint's violation beyond what the contact's own compliance allows.
            penetration = (0..near.len())
                .filter(|&i| known[i] && delta[i] > f64::NEG_INFINITY)
                .map(|i| delta[i] + u[i].z - soft[i] * forces[i].z)
                .fold(0.0, f64::max);
            // Points left out that the surface rose above their clearance: in, and again.
            risen.clear();
            risen.extend((0..near.len()).filter(|&i| !known[i] && u[i].z > clear[i]));
            for &i in &risen {
                (delta[i], known[i]) = (depth(self, &rest[i]), true);
                if delta[i] > f64::NEG_INFINITY {
                    reach = reach.max(1e-9 - delta[i]);
                }
            }
            if penetration <= tolerance * sinking.max(1e-6) && risen.is_empty() {
                converged = true;
                break;
            }
        }
        if friction {
            self.slide(&near, &forces, &u, &offsets, &rest, indenters);
        }
        surface.clear();
        surface.extend(self.slots.iter().map(|s| Self::displacement(s, &columns)));
        // The frame's columns kept as the last; the last's allocation kept for the next.
        std::mem::swap(&mut self.last, &mut columns);
        let loaded = || (0..near.len()).filter(|&i| forces[i].z > 0.0);
        points.clear();
        points.extend(loaded().map(|i| rest[i] + u[i]));
        loaded_forces.clear();
        loaded_forces.extend(loaded().map(|i| forces[i]));
        let contact = Contact {
            #[cfg(test)]
            loaded: loaded().map(|i| near[i]).collect(),
            #[cfg(test)]
            replaced: _replaced,
            points,
            forces: loaded_forces,
            #[cfg(test)]
            columns: self.last.clone(),
            surface,
            penetration,
            passes,
            iterations,
            converged,
            unsettled,
        };
        *self.buffers.get_mut() = ContactBuffers {
            near,
            rest,
            clear,
            soft,
            stencils,
            forces,
            u,
            delta,
            known,
            lag,
            offsets,
            columns,
            cand,
            chosen,
            local,
            rows,
            d,
            eps,
            present,
            surface: Vec::new(),
            answer,
            l: loads,
            steps,
            normal,
            caps,
            anchors,
            risen,
            points: Vec::new(),
            loaded: Vec::new(),
            small,
            order,
        };
        contact
    }

    /// Takes back the surface, points and forces of a frame's [`Contact`] once they are
    /// read, for the next frame's (their allocations reused).
    pub fn recycle(&mut self, contact: Contact) {
        let buffers = self.buffers.get_mut();
        buffers.surface = contact.surface;
        buffers.points = contact.points;
        buffers.loaded = contact.forces;
    }

    /// Friction's data for a refresh of the lagged normal forces `lag` on the candidate
    /// points `cand`: each point that carries a lagged normal force without an anchor
    /// sticks where it was at the start of the frame, in its indenter's frame there
    /// (`starts`); the caps (`friction` times the lagged force, where anchored) and the
    /// anchors' lateral offsets from the rest positions (also kept in `offsets`).
    #[allow(clippy::too_many_arguments)]
    fn frictions(
        &mut self,
        cand: &[usize],
        lag: &[f64],
        near: &[u32],
        rest: &[Vector3<f64>],
        stencils: &[Columns],
        starts: &[Isometry3<f64>],
        indenters: &[StepIndenter],
        offsets: &mut [Vector2<f64>],
        caps: &mut Vec<f64>,
        anchors: &mut Vec<Vector2<f64>>,
    ) {
        let count = (self.lattice[0] * self.lattice[1]) as u32;
        for &i in cand {
            // (Tip points, which stand for a patch, carry no friction.)
            if lag[i] > 0.0 && near[i] < count && !self.anchors.contains_key(&near[i]) {
                let x0 = rest[i]
                    + if self.last.is_empty() {
                        Vector3::zeros()
                    } else {
                        Self::displacement(&stencils[i], &self.last)
                    };
                if let Some(m) = self.nearest(&rest[i], indenters) {
                    let p0 = Point3::from(self.origin + x0 * self.dx);
                    let local = starts[m].inverse_transform_point(&p0);
                    self.anchors.insert(near[i], Anchor { indenter: m, local });
                }
            }
        }
        caps.clear();
        caps.extend(
            cand.iter()
                .map(|&i| match self.anchors.contains_key(&near[i]) {
                    true => self.friction * lag[i],
                    false => 0.0,
                }),
        );
        for &i in cand {
            offsets[i] = self
                .anchors
                .get(&near[i])
                .and_then(|a| self.anchor_at(a, indenters))
                .map_or(Vector2::zeros(), |a| (a - rest[i]).xy());
        }
        anchors.clear();
        anchors.extend(cand.iter().map(|&i| offsets[i]));
    }

    /// After a frame with friction (points `near`, their forces on the gel, displacements,
    /// anchors' lateral offsets from the rest positions `rest`): points out of contact
    /// lose their anchors, those sliding drag theirs to the stick radius; the normal
    /// forces are kept to start the next frame's lagged ones.
    fn slide(
        &mut self,
        near: &[u32],
        forces: &[Vector3<f64>],
        u: &[Vector3<f64>],
        offsets: &[Vector2<f64>],
        rest: &[Vector3<f64>],
        indenters: &[StepIndenter],
    ) {
        std::mem::swap(&mut self.lagged, &mut self.lagged_before);
        self.lagged.clear();
        for (i, &k) in near.iter().enumerate() {
            if forces[i].z > 0.0 {
                self.lagged.insert(k, forces[i]);
            }
        }
        // The anchors of the points pressed now (`near` is in index order), each dragged
        // where it slid; the others go. In place: the map's nodes are not made anew.
        let origin = self.origin;
        let dx = self.dx;
        self.anchors.retain(|k, a| {
            let Ok(i) = near.binary_search(k) else {
                return false;
            };
            let Some(ind) = indenters.get(a.indenter) else {
                return false;
            };
            if forces[i].z <= 0.0 {
                return false;
            }
            let at = ((ind.now * a.local).coords - origin) / dx;
            let t = u[i].xy() - offsets[i];
            let y = t.norm();
            if y > STICK {
                let moved = Vector3::new(rest[i].x + offsets[i].x, rest[i].y + offsets[i].y, at.z)
                    + Vector3::new(t.x, t.y, 0.0) * (1.0 - STICK / y);
                let p = Point3::from(origin + moved * dx);
                a.local = ind.now.inverse_transform_point(&p);
            }
            true
        });
    }

    /// Renumbers the anchors' indenters (`matched[i]`: previous index of indenter `i`);
    /// anchors of indenters that are gone are dropped.
    pub fn remap(&mut self, matched: &[Option<usize>]) {
        self.anchors.retain(|_, a| remap_anchor(a, matched));
        // The secant's motions are per indenter: kept only where each is the one it was.
        let same = matched.len() == self.last_motion.len()
            && matched.iter().enumerate().all(|(i, m)| *m == Some(i));
        if !same {
            self.last_motion.clear();
        }
    }

    /// The multiple of the last frame's change of the lagged forces that this frame starts
    /// from (`None`: from the last frame's forces alone), and this frame's motion kept as
    /// the last: where each indenter moved by at most [`SECANT_MOTION`] of a cell since the
    /// last frame and the indenters together moved on along their last motion (the
    /// cosine at least [`SECANT_ALIGNMENT`]), the multiple of [`super::secant_scale`].
    fn secant_start(
        &mut self,
        indenters: &[StepIndenter],
        starts: &[Isometry3<f64>],
    ) -> Option<f64> {
        let mut motion = std::mem::take(&mut self.motion);
        motion.clear();
        if starts.len() == indenters.len() {
            motion.extend(
                indenters
                    .iter()
                    .zip(starts)
                    .map(|(ind, start)| ind.now.translation.vector - start.translation.vector),
            );
        }
        let last = &self.last_motion;
        let along = if !self.secant
            || motion.len() != last.len()
            || self.lagged_before.is_empty()
            || motion
                .iter()
                .any(|m| !(m.norm() <= SECANT_MOTION * self.dx))
        {
            None
        } else {
            let dot: f64 = motion.iter().zip(last).map(|(a, b)| a.dot(b)).sum();
            let norm = |v: &[Vector3<f64>]| v.iter().map(|a| a.norm_squared()).sum::<f64>().sqrt();
            (dot >= SECANT_ALIGNMENT * norm(&motion) * norm(last))
                .then(|| super::secant_scale(&motion, last))
                .flatten()
        };
        // This frame's motion is the next one's last; the last's buffer gathers the next.
        self.motion = std::mem::replace(&mut self.last_motion, motion);
        along
    }

    /// Writes or reads the kept sets' bases ([`Base`]: the sets' systems follow from
    /// them): whether lateral and the node columns of each. Read back, a base that this
    /// compliance keeps already keeps its systems; the others are made where next used.
    fn persist_bases(&mut self, io: &mut Io<'_>) {
        let columns = self.levels.len();
        let mut bases: Vec<(bool, Vec<u32>)> = self
            .locals
            .iter()
            .map(|k| (k.base().lateral, k.base().local.clone()))
            .collect();
        let n = io.len(bases.len(), LOCAL_SYSTEMS, "the kept systems");
        if io.loading() {
            if io.fault().is_some() {
                return;
            }
            bases.resize_with(n, Default::default);
        }
        for (lateral, local) in bases.iter_mut() {
            lateral.persist(io);
            state::list(io, local, columns, "a kept system's node columns");
        }
        if !io.loading() || io.fault().is_some() {
            return;
        }
        let valid = |local: &[u32]| {
            !local.is_empty()
                && local.windows(2).all(|w| w[0] < w[1])
                && local.iter().all(|&c| (c as usize) < columns)
        };
        if !bases.iter().all(|(_, local)| valid(local)) {
            io.fail(|| "a kept system's node columns are not increasing ids of the gel's".into());
            return;
        }
        let mut old = std::mem::take(&mut self.locals);
        self.locals = bases
            .into_iter()
            .map(|(lateral, local)| {
                match old
                    .iter()
                    .position(|k| k.base().lateral == lateral && k.base().local == local)
                {
                    Some(i) => old.remove(i),
                    None => Kept::Named(Base {
                        local,
                        lateral,
                        made: None,
                    }),
                }
            })
            .collect();
    }

    /// Back to the undeformed gel without contact history (the factor and the
    /// responses stay: they depend on the gel alone). The kept dense systems go too: a
    /// fresh gel has none, and an episode's last contact seldom recurs in the next.
    pub fn reset(&mut self) {
        self.anchors.clear();
        self.lagged.clear();
        self.lagged_before.clear();
        self.last_motion.clear();
        self.last.clear();
        if std::mem::take(&mut self.built_large) {
            // A pad's systems: their memory goes back.
            self.locals.clear();
            *self.reuse.get_mut() = Reuse::default();
            crate::release_free_memory();
        } else {
            // The systems go, their buffers are kept for the next contact's.
            let reuse = self.reuse.get_mut();
            for kept in self.locals.drain(..) {
                if let Kept::Made(system) = kept {
                    reuse.let_go(system);
                }
            }
        }
    }
}

/// The `n x n` matrix `(A + A^T) / 2` of `a(p, q) = A[p, q]`, each entry of `A` read once:
/// what [`Compliance::local_compliance`] makes column by column.
#[cfg(test)]
fn symmetric(n: usize, a: impl Fn(usize, usize) -> f64) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(n, n);
    for q in 0..n {
        for p in q..n {
            let v = (a(p, q) + a(q, p)) * 0.5;
            out[(p, q)] = v;
            out[(q, p)] = v;
        }
    }
    out
}

/// Adds to `u` (3 per node column) the displacements of every column under column loads
/// `loads`: [`Compliance::column_displacements`].
#[inline(always)]
fn add_responses(responses: &Responses, loads: &[(u32, Vector3<f64>)], u: &mut [f64]) {
    for &(c, f) in loads {
        if f.z != 0.0 {
            for (u, &r) in u.iter_mut().zip(responses.down(c)) {
                *u += f.z * f64::from(r);
            }
        }
        if f.x != 0.0 || f.y != 0.0 {
            let (x, y) = responses.lateral(c).split_at(u.len());
            for ((u, &rx), &ry) in u.iter_mut().zip(x).zip(y) {
                *u += f.x * f64::from(rx) + f.y * f64::from(ry);
            }
        }
    }
}

/// [`add_responses`] compiled for AVX2 (no FMA contraction: the same bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn add_responses_avx2(responses: &Responses, loads: &[(u32, Vector3<f64>)], u: &mut [f64]) {
    add_responses(responses, loads, u);
}

/// The rigid footprint of a small contact on surface `samples` (positions, and the face
/// share in lattice points that each stands for) under indenters of signed distance
/// `distance` and vertical depth `depth` (below their lower surface, positive inside
/// them): its deepest sample, the penetrating samples' share of the face, the deepest
/// sample's signed distance, the footprint's fullness (its mean depth over the deepest;
/// see [`FULLNESS_SLOPE`]) and its length over its width: from the second moments of the
/// penetrating samples in the plane, each a square of `share` lattice points' faces of
/// `face` (cells^2) whose own moment is added (a strip's are `L^2 / 12` and `W^2 / 12`, a disc's are equal however
/// coarsely it is sampled, and a footprint one sample wide is as wide as a sample). `None`
/// where no sample penetrates.
fn footprint(
    (samples, share): (Samples, f64),
    face: f64,
    distance: impl Fn(&Vector3<f64>) -> f64,
    depth: impl Fn(&Vector3<f64>) -> f64,
) -> Option<Footprint> {
    let (mut inside, mut sum) = (0usize, 0.0);
    let (mut first, mut second) = (Vector2::zeros(), Matrix2::zeros());
    let mut deepest: Option<(f64, f64, Vector3<f64>)> = None;
    for x in samples.points() {
        let d = distance(&x);
        if d < 0.0 {
            let h = depth(&x).max(0.0);
            inside += 1;
            sum += h;
            first += x.xy();
            second += x.xy() * x.xy().transpose();
            if deepest.map_or(true, |(b, _, _)| h > b) {
                deepest = Some((h, d, x));
            }
        }
    }
    let (h, d, at) = deepest?;
    let n = inside as f64;
    let fullness = if h > 0.0 { sum / (n * h) } else { 1.0 };
    let mean = first / n;
    let own = Matrix2::identity() * (share * face / 12.0);
    let moments = SymmetricEigen::new(second / n - mean * mean.transpose() + own).eigenvalues;
    let (long, short) = (moments.max(), moments.min());
    let aspect = if short > 0.0 {
        (long / short).sqrt()
    } else {
        1.0
    };
    Some(Footprint {
        at,
        share: n * share,
        distance: d,
        fullness,
        aspect,
    })
}

/// A small contact's rigid footprint ([`footprint`]).
struct Footprint {
    /// The deepest sample (cells).
    at: Vector3<f64>,
    /// The penetrating samples' share of the face (lattice points).
    share: f64,
    /// The deepest sample's signed distance (cells).
    distance: f64,
    /// Mean depth over the deepest.
    fullness: f64,
    /// Length over width.
    aspect: f64,
}

/// The stiffness of a rigid flat elliptical punch of axis ratio `rho` over that of the disc
/// of its area, on a half-space: `pi E* a / K(e)` (semi-major axis `a`, `K` the complete
/// elliptic integral of the first kind, `e^2 = 1 - 1 / rho^2`) over `2 E* sqrt(a b)`,
/// which is `sqrt(rho) AGM(1, 1 / rho)` (1 for a disc, 1.12 at `rho = 4`).
fn elliptic_stiffness(rho: f64) -> f64 {
    let rho = rho.max(1.0);
    let (mut a, mut g) = (1.0f64, 1.0 / rho);
    for _ in 0..8 {
        (a, g) = (0.5 * (a + g), (a * g).sqrt());
    }
    rho.sqrt() * a
}

/// The inverse of the symmetric positive definite `a` (faer's Cholesky, in the calling
/// thread); `None` if it is not positive definite.
fn spd_inverse(a: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let (mut l, mut out) = (a.clone(), DMatrix::zeros(0, 0));
    spd_inverse_into(&mut l, &mut out)?;
    Some(out)
}

/// [`spd_inverse`] of `a`, factored in place, into `out` (its allocation reused).
fn spd_inverse_into(a: &mut DMatrix<f64>, out: &mut DMatrix<f64>) -> Option<()> {
    cholesky(a)?;
    factor_inverse_into(a, reshaped(out, a.nrows(), a.ncols()));
    Some(())
}

/// The inverse of a symmetric positive definite matrix from its Cholesky factor (the
/// lower triangle of `l`, as [`cholesky`] leaves it), into `out` (its shape): both
/// triangles.
fn factor_inverse_into(l: &DMatrix<f64>, out: &mut DMatrix<f64>) {
    let n = l.nrows();
    let req = llt::inverse::inverse_scratch::<f64>(n, Par::Seq);
    with_stack(req, |stack| {
        llt::inverse::inverse(
            MatMut::from_column_major_slice_mut(out.as_mut_slice(), n, n),
            MatRef::from_column_major_slice(l.as_slice(), n, n),
            Par::Seq,
            stack,
        )
    });
    // The inverse is written to one triangle: mirror it.
    out.fill_upper_triangle_with_lower_triangle();
}

/// `m` as an `r x c` matrix of zeros, its allocation reused.
fn reshaped<T: nalgebra::Scalar + Default>(
    m: &mut DMatrix<T>,
    r: usize,
    c: usize,
) -> &mut DMatrix<T> {
    if m.shape() == (r, c) {
        m.fill(T::default());
    } else {
        let mut data: Vec<T> = std::mem::replace(m, DMatrix::from_vec(0, 0, Vec::new()))
            .data
            .into();
        data.clear();
        data.resize(r * c, T::default());
        *m = DMatrix::from_vec(r, c, data);
    }
    m
}

/// `m` as an `r x c` matrix whose entries the caller overwrites (those of another shape
/// zeroed), its allocation reused.
fn shaped<T: nalgebra::Scalar + Default>(
    m: &mut DMatrix<T>,
    r: usize,
    c: usize,
) -> &mut DMatrix<T> {
    if m.shape() == (r, c) {
        m
    } else {
        reshaped(m, r, c)
    }
}

/// Factors the symmetric positive definite `a` in place and solves `a X = b` for the
/// columns of `b` in place: for the few unknowns of a contact moving on by a column or
/// two, by [`small_cholesky`] and [`small_solve`] (faer's dispatch costs more than their
/// work there), else by faer. `None` where `a` is not positive definite.
fn small_or_faer_solve(a: &mut DMatrix<f64>, b: &mut DMatrix<f64>) -> Option<()> {
    let n = a.nrows();
    if n <= SMALL_FACTOR {
        // A symmetric matrix reads the same row and column major: the factor is `L` row
        // major in the upper triangle.
        small_cholesky(a.as_mut_slice(), n)?;
    } else {
        cholesky(a)?;
    }
    solve_with_factor(a, b);
    Some(())
}

/// Solves `a X = b` in place for the columns of `b` with the factor
/// [`small_or_faer_solve`] left in `a`.
fn solve_with_factor(a: &DMatrix<f64>, b: &mut DMatrix<f64>) {
    let n = a.nrows();
    let columns = b.ncols();
    if n == 0 {
        return;
    }
    if n <= SMALL_FACTOR {
        for column in b.as_mut_slice().chunks_exact_mut(n) {
            small_solve(a.as_slice(), n, column);
        }
    } else {
        cholesky_solve_in(a, b.as_mut_slice(), columns);
    }
}

/// Unknowns up to which [`small_or_faer_solve`] factors by [`small_cholesky`].
const SMALL_FACTOR: usize = 48;

/// Sets every entry of `m` to `f(row, column)`.
fn fill(m: &mut DMatrix<f64>, f: impl Fn(usize, usize) -> f64) {
    let n = m.nrows();
    if n == 0 {
        return;
    }
    // Column by column (column major), without a division per entry.
    for (j, column) in m.as_mut_slice().chunks_exact_mut(n).enumerate() {
        for (i, v) in column.iter_mut().enumerate() {
            *v = f(i, j);
        }
    }
}

/// The matrix behind `m`, made its own (where it was shared, one of `spare`, or a fresh
/// empty one) so that it can be written in place.
fn unique<'m>(
    m: &'m mut Arc<DMatrix<f64>>,
    spare: &mut Vec<Arc<DMatrix<f64>>>,
) -> &'m mut DMatrix<f64> {
    if Arc::get_mut(m).is_none() {
        *m = spare_matrix(spare);
    }
    Arc::make_mut(m)
}

/// One of `spare`, or a fresh empty matrix.
fn spare_matrix(spare: &mut Vec<Arc<DMatrix<f64>>>) -> Arc<DMatrix<f64>> {
    spare
        .pop()
        .unwrap_or_else(|| Arc::new(DMatrix::zeros(0, 0)))
}

/// `m` made its own ([`unique`]) and set to `from`.
fn copy_into(m: &mut Arc<DMatrix<f64>>, from: &DMatrix<f64>, spare: &mut Vec<Arc<DMatrix<f64>>>) {
    let m = unique(m, spare);
    reshaped(m, from.nrows(), from.ncols()).copy_from(from);
}

/// The most matrices [`Reuse`] keeps from the bases let go (each under [`TRIM_ENTRIES`]:
/// with the two kept systems let go, at most a few MiB).
const SPARE_MATRICES: usize = 4;

/// Rows of a dense factorisation below which it runs in the calling thread even in a
/// pool of several: a contact system of tens of pressed points gains nothing from a
/// second thread but its hand-offs. `cargo bench --bench sensor`, two threads, median ms
/// over four alternated runs each (parallel at every size, then below 256 rows in the
/// calling thread): `coarse` with `solver="linear"`, sphere 7.17, 7.30, 7.98, 8.09 ->
/// 4.90, 4.95, 5.63, 6.49; the default `rom`, sphere 4.35, 4.55, 6.29, 4.30 -> 4.25,
/// 4.24, 4.31, 4.94; the cones unchanged within the drift. One thread is untouched (its
/// factorisations were sequential already), and two threads now give the one thread's
/// bits below this size.
const PARALLEL_CHOLESKY_FROM: usize = 256;

/// Overwrites the lower triangle of the symmetric positive definite `a` with its
/// Cholesky factor (faer, in the calling thread's pool; in double or single precision);
/// `None` if it is not positive definite.
fn cholesky<T: faer::traits::RealField + nalgebra::Scalar>(a: &mut DMatrix<T>) -> Option<()> {
    let n = a.nrows();
    let par = if n < PARALLEL_CHOLESKY_FROM {
        Par::Seq
    } else {
        par()
    };
    let req = llt::factor::cholesky_in_place_scratch::<T>(n, par, Default::default());
    let factor = |stack: &mut MemStack| {
        llt::factor::cholesky_in_place(
            MatMut::from_column_major_slice_mut(a.as_mut_slice(), n, n),
            Default::default(),
            par,
            stack,
            Default::default(),
        )
        .ok()
        .map(|_| ())
    };
    with_stack(req, factor)
}

/// Runs `f` on this thread's kept scratch for faer ([`FACTOR_STACK`]), grown to `req`
/// where it is smaller.
fn with_stack<R>(req: StackReq, f: impl FnOnce(&mut MemStack) -> R) -> R {
    FACTOR_STACK.with(|kept| {
        let (mut guard, mut own);
        let mem = match kept.try_borrow_mut() {
            Ok(kept) => {
                guard = kept;
                let (made_for, mem) = &mut *guard;
                // A buffer made for a request serves any it covers (`or`: the larger size
                // and alignment of the two); else one is made for both.
                if made_for.or(req) != *made_for {
                    *made_for = made_for.or(req);
                    *mem = MemBuffer::new(*made_for);
                }
                mem
            }
            // This thread is inside a factorisation already (a parallel one that took up
            // other work while it waited): a buffer of its own.
            Err(_) => {
                own = MemBuffer::new(req);
                &mut own
            }
        };
        f(MemStack::new(mem))
    })
}

thread_local! {
    /// faer's scratch for this thread's dense factorisations ([`cholesky`]), kept at the
    /// largest request so far and the request it was made for: a Newton step does not
    /// allocate it anew. Its contents are never read before faer writes them.
    static FACTOR_STACK: std::cell::RefCell<(StackReq, MemBuffer)> =
        std::cell::RefCell::new((StackReq::EMPTY, MemBuffer::new(StackReq::EMPTY)));
}

/// `a x` (faer's product, in the calling thread): the contact solves' matrix-vector
/// products (with nalgebra's, `tacrom/Press-v1`'s sweep on the linear gel ran about 5 %
/// slower).
fn product<T: faer::traits::RealField + nalgebra::Scalar>(
    a: &DMatrix<T>,
    x: &DVector<T>,
) -> DVector<T> {
    let mut out = DVector::from_element(a.nrows(), T::zero());
    product_in(a, x, out.as_mut_slice());
    out
}

/// [`product`] into `out` (sized to `a`'s rows, its allocation kept).
fn product_into(a: &DMatrix<f64>, x: &DVector<f64>, out: &mut DVector<f64>) {
    product_in(a, x, sized(out, a.nrows()).as_mut_slice());
}

/// `out = a x` (`out` of `a`'s rows).
fn product_in<T: faer::traits::RealField + nalgebra::Scalar>(
    a: &DMatrix<T>,
    x: &DVector<T>,
    out: &mut [T],
) {
    let (n, k) = a.shape();
    faer::linalg::matmul::matmul(
        MatMut::from_column_major_slice_mut(out, n, 1),
        faer::Accum::Replace,
        MatRef::from_column_major_slice(a.as_slice(), n, k),
        MatRef::from_column_major_slice(x.as_slice(), k, 1),
        T::one(),
        Par::Seq,
    );
}

/// `c += alpha a b` with `a` and `b` each transposed where asked (faer, in the calling
/// thread).
fn add_product(
    c: &mut DMatrix<f64>,
    alpha: f64,
    a: &DMatrix<f64>,
    a_transposed: bool,
    b: &DMatrix<f64>,
    b_transposed: bool,
) {
    fn view(m: &DMatrix<f64>, t: bool) -> MatRef<'_, f64> {
        let m = MatRef::from_column_major_slice(m.as_slice(), m.nrows(), m.ncols());
        if t {
            m.transpose()
        } else {
            m
        }
    }
    let (n, k) = c.shape();
    faer::linalg::matmul::matmul(
        MatMut::from_column_major_slice_mut(c.as_mut_slice(), n, k),
        faer::Accum::Add,
        view(a, a_transposed),
        view(b, b_transposed),
        alpha,
        Par::Seq,
    );
}

/// Solves `a x = b` in place, `a` overwritten by [`cholesky`] (either precision).
fn cholesky_solve<T: faer::traits::RealField + nalgebra::Scalar>(
    a: &DMatrix<T>,
    b: &mut DVector<T>,
) {
    cholesky_solve_in(a, b.as_mut_slice(), 1);
}

/// [`cholesky_solve`] for the `columns` right-hand sides of `b` (column-major, `a`'s
/// rows each).
fn cholesky_solve_in<T: faer::traits::RealField + nalgebra::Scalar>(
    a: &DMatrix<T>,
    b: &mut [T],
    columns: usize,
) {
    let n = a.nrows();
    llt::solve::solve_in_place_with_conj(
        MatRef::from_column_major_slice(a.as_slice(), n, n),
        Conj::No,
        MatMut::from_column_major_slice_mut(b, n, columns),
        Par::Seq,
        MemStack::new(&mut MemBuffer::new(StackReq::EMPTY)),
    );
}

/// `A^-1 b` in double precision from `A`'s single-precision Cholesky factor (`factor`'s
/// lower triangle, as [`cholesky`] leaves it), solved in single precision.
fn solve_single(factor: &DMatrix<f32>, b: &DVector<f64>) -> DVector<f64> {
    let mut x = b.map(|x| x as f32);
    cholesky_solve(factor, &mut x);
    x.map(f64::from)
}

/// One contact solve in the loads of the node columns under the contact: their
/// compliance `g` (symmetric, positive definite) and its inverse, the points' rows of
/// column weights `w`, the depths `delta` they must sink and their contact compliances
/// `eps`.
struct Problem<'a> {
    g: &'a DMatrix<f64>,
    inverse: &'a DMatrix<f64>,
    /// `inverse` in single precision, where kept ([`Problem::stiff_descent`]).
    inverse32: Option<&'a DMatrix<f32>>,
    /// The matrices Newton's steps assemble their systems in ([`Problem::system_in`]).
    scratch: &'a Workspace,
    /// The vectors of [`minimise`]'s steps.
    steps: &'a Mutex<Steps>,
    /// Whether the frictional solve's Newton steps from [`MIXED_UNKNOWNS`] on keep their
    /// factor within the pass and solve the next steps' systems by conjugate gradients
    /// preconditioned with it ([`Problem::conjugate_gradients`]), factoring anew only
    /// where that does not converge quickly.
    precondition: bool,
    w: &'a [Columns],
    delta: &'a [f64],
    eps: &'a [f64],
}

impl Problem<'_> {
    /// The Newton step `d` of `(I + W^T Phi'' W G) d = -r` (`Phi''` the points'
    /// stiffness, positive semi-definite, already added to `system = G^-1 + W^T Phi''
    /// W`): `d = G^-1 z` with `system z = -r`, symmetric positive definite; the columns'
    /// sinking along it, `G d = z`; and the energy's slope along it, `(G r) . d = r . z`
    /// (`G` symmetric). Where round-off spoils the Newton direction, the gradient's own
    /// (`-r`, `-G r`).
    fn descent(
        &self,
        system: &mut DMatrix<f64>,
        r: &DVector<f64>,
        out: &mut Descent,
    ) -> Option<()> {
        let z = sized(&mut out.sinking, r.len());
        z.zip_apply(r, |z, r| *z = -r);
        cholesky(system)?;
        cholesky_solve(system, z);
        self.along(r, out);
        Some(())
    }

    /// The kept matrix of `scratch`'s precision, set to `G^-1` (`inverse` in single
    /// precision where kept): the system a Newton step assembles and factors in place,
    /// without allocating it anew at every step.
    fn system_in<'s, T: nalgebra::Scalar + Copy + Default>(
        scratch: &'s mut DMatrix<T>,
        from: &DMatrix<T>,
    ) -> &'s mut DMatrix<T> {
        if scratch.shape() != from.shape() {
            reshaped(scratch, from.nrows(), from.ncols());
        }
        scratch.copy_from(from);
        scratch
    }

    /// `G^-1` in single precision: `inverse32` where kept, else made here.
    fn single_inverse(&self) -> std::borrow::Cow<'_, DMatrix<f32>> {
        match self.inverse32 {
            Some(low) => std::borrow::Cow::Borrowed(low),
            None => std::borrow::Cow::Owned(self.inverse.map(|x| x as f32)),
        }
    }

    /// [`Problem::descent`] with the system `G^-1 + W^T Phi'' W` given by the points'
    /// stiffnesses `stiff` (`(point, Phi''_p)`, the points without one left out). From
    /// [`MIXED_UNKNOWNS`] on it is assembled and factored in single precision, on a copy
    /// of `G^-1` in single precision (`inverse32`, or made here), and the direction
    /// refined once in double with the system's product taken as `G^-1 x` plus the points'
    /// `W^T Phi'' W x`: the double-precision system is never formed.
    fn stiff_descent(
        &self,
        stiff: &[(usize, Matrix3<f64>)],
        r: &DVector<f64>,
        target: f64,
        out: &mut Descent,
    ) -> Option<()> {
        let k = self.inverse.nrows();
        let mut scratch = self.scratch.lock();
        if k < MIXED_UNKNOWNS {
            let system = Self::system_in(&mut scratch.double, self.inverse);
            add_stiffness(system, self.w, stiff, |x| x);
            return self.descent(system, r, out);
        }
        if self.precondition {
            if scratch.factored && self.preconditioned(&mut scratch, stiff, r, target, out) {
                scratch.preconditioned += 1;
                return Some(());
            }
            // The kept factor no longer serves: this step's blocks, a third of a whole
            // factorisation's work, and the whole system's only where they do not.
            if self.block_factor(&mut scratch, stiff).is_some()
                && self.preconditioned(&mut scratch, stiff, r, target, out)
            {
                scratch.preconditioned += 1;
                return Some(());
            }
        }
        *out = self.factored_descent(&mut scratch, stiff, r)?;
        Some(())
    }

    /// [`Problem::stiff_descent`] from a factor of this step's own system, made in single
    /// precision and kept ([`Scratch::factored`]) for the next steps of the pass.
    fn factored_descent(
        &self,
        scratch: &mut Scratch,
        stiff: &[(usize, Matrix3<f64>)],
        r: &DVector<f64>,
    ) -> Option<Descent> {
        scratch.factored = false;
        let inverse32 = self.single_inverse();
        let low = Self::system_in(&mut scratch.single, &inverse32);
        add_stiffness(low, self.w, stiff, |x| x as f32);
        cholesky(low)?;
        scratch.factored = true;
        scratch.blocks = false;
        let solve = |b: &DVector<f64>| solve_single(&scratch.single, b);
        let z = -r;
        let first = solve(&z);
        let mut applied = product(self.inverse, &first);
        self.add_points(stiff, &first, &mut applied);
        let residual = &z - applied;
        let mut d = Descent {
            sinking: first + solve(&residual),
            ..Descent::default()
        };
        self.along(r, &mut d);
        Some(d)
    }

    /// The Newton system `(G^-1 + W^T Phi'' W) z = -r` of [`Problem::stiff_descent`] solved
    /// by conjugate gradients, preconditioned by `factor` (the single-precision Cholesky
    /// factor of an earlier step's system in this pass), until the predicted residual after
    /// the full step, `|r + A z|` (max norm), is at most `target`: the descent, or `None`
    /// where [`PRECONDITIONED_ITERATIONS`] do not get there (the caller then factors this
    /// step's system). The system is applied as `G^-1 p` (in single precision where
    /// `inverse32` is kept) plus the points' `W^T Phi'' W p`, and the step `d = G^-1 z`
    /// is taken once in double precision at the end, so an iteration costs one product
    /// with `G^-1` and one pair of triangular solves with `factor`, against a
    /// factorisation (`k^3 / 3`) for a new factor.
    fn conjugate_gradients(
        &self,
        factor: Preconditioner,
        cg: &mut Cg,
        stiff: &[(usize, Matrix3<f64>)],
        r: &DVector<f64>,
        target: f64,
        out: &mut Descent,
    ) -> bool {
        let k = r.len();
        let Cg {
            res,
            y,
            p,
            q,
            p32,
            q32,
            at,
            lateral,
            vertical,
        } = cg;
        let z = sized(&mut out.sinking, k);
        z.fill(0.0);
        for b in [&mut *res, &mut *y, &mut *p, &mut *q] {
            sized(b, k);
        }
        res.zip_apply(r, |x, r| *x = -r);
        factor.solve_into(res, y, lateral, vertical);
        p.copy_from(y);
        let mut ry = res.dot(y);
        let start = res.amax();
        for it in 0..PRECONDITIONED_ITERATIONS {
            // The system's products in single precision where `G^-1` is kept so (their
            // error, about 1e-7 of the product, lies far below the iterations' target, at
            // least a thousandth of `r`); the step `G^-1 z` once, in double, at the end.
            match self.inverse32 {
                Some(inverse) => {
                    sized(p32, k).zip_apply(p, |a, x| *a = x as f32);
                    q32.resize(inverse.nrows(), 0.0);
                    product_in(inverse, p32, q32);
                    q.iter_mut()
                        .zip(q32.iter())
                        .for_each(|(q, &x)| *q = f64::from(x));
                }
                None => product_into(self.inverse, p, q),
            }
            self.add_points_with(stiff, p, q, at);
            let pq = p.dot(q);
            if !(pq > 0.0 && ry.is_finite()) {
                return false;
            }
            let alpha = ry / pq;
            z.axpy(alpha, p, 1.0);
            res.axpy(-alpha, q, 1.0);
            if res.amax() <= target {
                let slope = r.dot(z);
                if slope < 0.0 {
                    product_into(self.inverse, z, &mut out.step);
                    out.slope = slope;
                    return true;
                }
                return false;
            }
            if it >= 1 {
                // Where the residual's rate so far would not reach the target within the
                // iterations allowed, a factorisation costs less than going on.
                let done = (it + 1) as f64;
                let rate = (res.amax() / start).ln() / done;
                let left = (target / res.amax()).ln() / rate;
                if !(rate < 0.0 && done + left <= PRECONDITIONED_ITERATIONS as f64) {
                    return false;
                }
            }
            factor.solve_into(res, y, lateral, vertical);
            let next = res.dot(y);
            let beta = next / ry;
            p.zip_apply(y, |p, y| *p = y + *p * beta);
            ry = next;
        }
        false
    }

    /// [`Problem::conjugate_gradients`] with the pass's kept factor of `scratch` (the
    /// blocks' or the whole system's: [`Scratch::factored`]) and its vectors.
    fn preconditioned(
        &self,
        scratch: &mut Scratch,
        stiff: &[(usize, Matrix3<f64>)],
        r: &DVector<f64>,
        target: f64,
        out: &mut Descent,
    ) -> bool {
        let Scratch {
            single,
            xy,
            z,
            blocks,
            cg,
            ..
        } = scratch;
        let factor = match blocks {
            true => Preconditioner::Blocks(xy, z),
            false => Preconditioner::Whole(single),
        };
        self.conjugate_gradients(factor, cg, stiff, r, target, out)
    }

    /// Factors the lateral and vertical blocks of this step's system `G^-1 + W^T Phi''
    /// W` in single precision (into `scratch.xy`, the columns' `x` and `y` loads in
    /// column order, and `scratch.z`) and keeps them as the pass's factor: the system
    /// less `G^-1`'s coupling of the lateral loads with the vertical ones (the points'
    /// stiffness has none), at about a third of a whole factorisation's work
    /// (`(2k/3)^3 / 3 + (k/3)^3 / 3` against `k^3 / 3`). `None` (and no factor kept)
    /// where a block is not positive definite.
    fn block_factor(&self, scratch: &mut Scratch, stiff: &[(usize, Matrix3<f64>)]) -> Option<()> {
        scratch.factored = false;
        let k = self.inverse.nrows();
        let n = k / 3;
        let inverse32 = self.single_inverse();
        if scratch.z.nrows() != n {
            scratch.xy = DMatrix::zeros(2 * n, 2 * n);
            scratch.z = DMatrix::zeros(n, n);
        }
        let src = inverse32.as_slice();
        let (xy, z) = (scratch.xy.as_mut_slice(), scratch.z.as_mut_slice());
        // The lower triangles (all the factorisation reads), column by column.
        for b in 0..n {
            for j in 0..2 {
                let from = &src[(3 * b + j) * k..][..k];
                let to = &mut xy[(2 * b + j) * 2 * n..][..2 * n];
                for a in b..n {
                    to[2 * a] = from[3 * a];
                    to[2 * a + 1] = from[3 * a + 1];
                }
            }
            let from = &src[(3 * b + 2) * k..][..k];
            let to = &mut z[b * n..][..n];
            for a in b..n {
                to[a] = from[3 * a + 2];
            }
        }
        for &(i, h) in stiff {
            let row = &self.w[i];
            let vertical = h[(2, 2)] as f32;
            for &(a, wa) in row {
                for &(b, wb) in row.iter().filter(|&&(b, _)| b <= a) {
                    let ww = (wa * wb) as f32;
                    let (a, b) = (a as usize, b as usize);
                    for (r, c) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let v = h[(r, c)] as f32;
                        if v != 0.0 {
                            // Within a diagonal block, its upper entry too (never read).
                            xy[(2 * b + c) * 2 * n + 2 * a + r] += v * ww;
                        }
                    }
                    if vertical != 0.0 {
                        z[b * n + a] += vertical * ww;
                    }
                }
            }
        }
        cholesky(&mut scratch.xy)?;
        cholesky(&mut scratch.z)?;
        scratch.factored = true;
        scratch.blocks = true;
        scratch.block_factors += 1;
        Some(())
    }

    /// Adds the points' part of the Newton system's product, `W^T Phi'' W x`, to `out`
    /// (`stiff` as in [`Problem::stiff_descent`]).
    fn add_points(
        &self,
        stiff: &[(usize, Matrix3<f64>)],
        x: &DVector<f64>,
        out: &mut DVector<f64>,
    ) {
        self.add_points_with(stiff, x, out, &mut Vec::new());
    }

    /// [`Problem::add_points`] with the points' displacements in `at` (overwritten).
    fn add_points_with(
        &self,
        stiff: &[(usize, Matrix3<f64>)],
        x: &DVector<f64>,
        out: &mut DVector<f64>,
        at: &mut Vec<Vector3<f64>>,
    ) {
        at_points_into(self.w, x, at);
        for &(i, h) in stiff {
            let t = h * at[i];
            for &(c, wt) in &self.w[i] {
                let c = 3 * c as usize;
                for j in 0..3 {
                    out[c + j] += wt * t[j];
                }
            }
        }
    }

    /// The descent `d = G^-1 z` for the solution `z` of the Newton system with right-hand
    /// side `-r` (in `out.sinking`), or the gradient's where round-off spoils it.
    fn along(&self, r: &DVector<f64>, out: &mut Descent) {
        let slope = r.dot(&out.sinking);
        if slope < 0.0 {
            product_into(self.inverse, &out.sinking, &mut out.step);
            out.slope = slope;
        } else {
            self.gradient(r, out)
        }
    }

    /// The descent along `-r` (the energy's gradient in the metric of `G^-1`), into `out`.
    fn gradient(&self, r: &DVector<f64>, out: &mut Descent) {
        product_into(self.g, r, &mut out.sinking);
        out.slope = -out.sinking.dot(r);
        out.sinking.neg_mut();
        sized(&mut out.step, r.len()).zip_apply(r, |s, r| *s = -r);
    }
}

/// A factored approximation of a Newton system that [`Problem::conjugate_gradients`]
/// preconditions with: a whole system's single-precision factor, or its lateral and
/// vertical blocks' ([`Problem::block_factor`]).
#[derive(Clone, Copy)]
enum Preconditioner<'a> {
    Whole(&'a DMatrix<f32>),
    Blocks(&'a DMatrix<f32>, &'a DMatrix<f32>),
}

impl Preconditioner<'_> {
    /// The approximation's solution for `b` (three unknowns per column), in double
    /// precision, into `out`, with `lateral` and `vertical` for the single-precision
    /// right-hand sides (each overwritten).
    fn solve_into(
        &self,
        b: &DVector<f64>,
        out: &mut DVector<f64>,
        lateral: &mut DVector<f32>,
        vertical: &mut DVector<f32>,
    ) {
        match *self {
            Preconditioner::Whole(factor) => {
                let x = sized(lateral, b.len());
                x.zip_apply(b, |x, b| *x = b as f32);
                cholesky_solve(factor, x);
                sized(out, b.len()).zip_apply(x, |o, x| *o = f64::from(x));
            }
            Preconditioner::Blocks(xy, z) => {
                let n = z.nrows();
                let lateral = sized(lateral, 2 * n);
                for (i, x) in lateral.iter_mut().enumerate() {
                    *x = b[3 * (i / 2) + i % 2] as f32;
                }
                let vertical = sized(vertical, n);
                for (i, x) in vertical.iter_mut().enumerate() {
                    *x = b[3 * i + 2] as f32;
                }
                cholesky_solve(xy, lateral);
                cholesky_solve(z, vertical);
                for (i, o) in sized(out, 3 * n).iter_mut().enumerate() {
                    *o = match i % 3 {
                        2 => f64::from(vertical[i / 3]),
                        j => f64::from(lateral[2 * (i / 3) + j]),
                    };
                }
            }
        }
    }
}

/// Adds each point's stiffness `Phi''_p` of `stiff` (`(point, Phi''_p)`) to `system` on its
/// columns (rows `w`, three unknowns per column): `system += W_p^T Phi''_p W_p`, in the
/// precision `cast` gives, on the **lower triangle only** (the blocks of column pairs
/// `a >= b`; the factorisation reads nothing else). A point's `Phi''_p` couples x and y
/// (friction) and z (its penalty) but never a lateral with the vertical: its four lateral
/// entries and its vertical one are added, each only where it is not zero. Each entry
/// of the lower triangle receives the same terms in the same order as the whole `3 x 3`
/// blocks did, so the system is the same to the bit, at less of the work (its share of
/// `tacrom/Press-v1`'s sweep profile 6.24 % before, 4.20 % after: `docs/solvers.md`).
fn add_stiffness<T: nalgebra::RealField + Copy>(
    system: &mut DMatrix<T>,
    w: &[Columns],
    stiff: &[(usize, Matrix3<f64>)],
    cast: impl Fn(f64) -> T,
) {
    let k = system.nrows();
    let s = system.as_mut_slice();
    for &(i, h) in stiff {
        debug_assert!(
            [(0, 2), (1, 2), (2, 0), (2, 1)]
                .iter()
                .all(|&e| h[e] == 0.0),
            "a point's stiffness couples lateral and vertical: {h}"
        );
        let row = &w[i];
        let mut lateral = [(0, 0, T::zero()); 4];
        let mut n = 0;
        for (r, c) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let v = cast(h[(r, c)]);
            if v != T::zero() {
                lateral[n] = (r, c, v);
                n += 1;
            }
        }
        let lateral = &lateral[..n];
        let vertical = cast(h[(2, 2)]);
        for &(a, wa) in row {
            for &(b, wb) in row {
                if b > a {
                    continue;
                }
                let ww = cast(wa * wb);
                let (r0, c0) = (3 * a as usize, 3 * b as usize);
                for &(r, c, v) in lateral {
                    // Within a diagonal block, its upper entry too (it is never read).
                    s[(c0 + c) * k + r0 + r] += v * ww;
                }
                if vertical != T::zero() {
                    s[(c0 + 2) * k + r0 + 2] += vertical * ww;
                }
            }
        }
    }
}

/// The matrices a contact solve's Newton steps assemble and factor their systems in, in
/// double and single precision (empty until first used).
#[derive(Default)]
pub(super) struct Scratch {
    double: DMatrix<f64>,
    single: DMatrix<f32>,
    /// Whether `single` holds the factor of a system of the present contact pass (the
    /// preconditioner of [`Problem::stiff_descent`]'s conjugate gradients). Cleared when
    /// a pass poses its problem ([`Workspace::new_pass`]), so that no factor outlives the
    /// pass that made it: a frame's path depends on the frame alone.
    factored: bool,
    /// The factors of a system's lateral block (the columns' `x` and `y` loads, in
    /// column order) and vertical block ([`Problem::block_factor`]), and whether they are
    /// the kept factor rather than `single`.
    xy: DMatrix<f32>,
    z: DMatrix<f32>,
    blocks: bool,
    /// Block factors made so far ([`Problem::block_factor`]; tests check that the path
    /// they compare ran).
    block_factors: usize,
    /// Newton steps solved by [`Problem::conjugate_gradients`] so far (tests check
    /// that the path they compare ran).
    preconditioned: usize,
    /// The vectors of [`Problem::conjugate_gradients`].
    cg: Cg,
}

/// The vectors of [`Problem::conjugate_gradients`] (each sized and overwritten before it
/// is read): the residual, the preconditioned residual, the direction and the system's
/// product with it, the direction and product in single precision, the points'
/// displacements, and the preconditioner's single-precision right-hand sides.
#[derive(Default)]
struct Cg {
    res: DVector<f64>,
    y: DVector<f64>,
    p: DVector<f64>,
    q: DVector<f64>,
    p32: DVector<f32>,
    q32: Vec<f32>,
    at: Vec<Vector3<f64>>,
    lateral: DVector<f32>,
    vertical: DVector<f32>,
}

/// A [`Scratch`] kept with a set of columns' systems. Its contents are overwritten before
/// every use, so a copy of the gel starts with an empty one.
#[derive(Default)]
pub(super) struct Workspace(Mutex<Scratch>);

/// The vectors of [`minimise`]: its loads' state and trials, the points' displacements,
/// forces and stiffnesses, and the direction of its step ([`Problem::stiff_descent`]),
/// kept with the contact's buffers (not a set of columns': a press moving on makes new
/// ones) so that a frame's Newton steps allocate none of them (each is sized and
/// overwritten before it is read: [`sized`]).
#[derive(Default)]
struct Steps {
    v: DVector<f64>,
    wf: DVector<f64>,
    r: DVector<f64>,
    trial: DVector<f64>,
    vt: DVector<f64>,
    wt: DVector<f64>,
    rhs: DVector<f64>,
    s: Vec<Vector3<f64>>,
    f: Vec<Vector3<f64>>,
    st: Vec<Vector3<f64>>,
    ft: Vec<Vector3<f64>>,
    stuck: Vec<Vector3<f64>>,
    stiff: Vec<(usize, Matrix3<f64>)>,
    direction: Descent,
    /// [`penalty_contact_into`]'s.
    penalty: Penalty,
    /// [`vertical_start`]'s.
    vertical: Vertical,
    /// [`frictional_contact`]'s loads at its start.
    start: DVector<f64>,
    /// [`split_start`]'s.
    split: Split,
}

/// `v` with `n` entries, its allocation kept (nalgebra's own resizing shrinks it to fit):
/// unchanged where it has `n` already, else zeros. Its entries are the caller's to
/// overwrite.
fn sized<T: nalgebra::Scalar + Default>(v: &mut DVector<T>, n: usize) -> &mut DVector<T> {
    if v.len() != n {
        let empty = DVector::from_vec(Vec::new());
        let mut data: Vec<T> = std::mem::replace(v, empty).data.into();
        data.clear();
        data.resize(n, T::default());
        *v = DVector::from_vec(data);
    }
    v
}

impl Workspace {
    fn lock(&self) -> std::sync::MutexGuard<'_, Scratch> {
        // A poisoned lock left matrices that are overwritten before use anyway.
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Forgets the factor a past pass left ([`Scratch::factored`]).
    fn new_pass(&self) {
        self.lock().factored = false;
    }
}

impl Clone for Workspace {
    fn clone(&self) -> Self {
        Self::default()
    }
}

/// A descent direction of the columns' loads: the step `d`, the columns' sinking along it
/// `G d` (so that a trial along it needs no product with `G`), and the energy's slope.
struct Descent {
    step: DVector<f64>,
    sinking: DVector<f64>,
    slope: f64,
}

impl Default for Descent {
    fn default() -> Self {
        Self {
            step: DVector::zeros(0),
            sinking: DVector::zeros(0),
            slope: 0.0,
        }
    }
}

/// Newton iterations at most per contact solve.
const MAX_NEWTON: usize = 60;

/// Unknowns from which a Newton step of the frictional contact solve factors its system
/// in single precision and refines the direction once in double (a product with the
/// system and two more triangular solves): the direction to about 1e-8 (the single
/// precision's 1e-4, squared), which Newton's method does not tell from the exact one,
/// and the factorisation, the step's largest cost, at twice the speed. (The frictionless
/// solve keeps double precision: its last step is exact on its pressed set.) Measured:
/// `docs/solvers.md`, "A held grasp split first".
const MIXED_UNKNOWNS: usize = SPLIT_UNKNOWNS;

/// Conjugate-gradient iterations with a kept factor at most before a Newton step
/// factors its own system instead ([`Problem::conjugate_gradients`]); fewer where the
/// residual's rate so far says they will not suffice. An iteration costs about a
/// twentieth of a factorisation and its solves on a pad's 1,300 unknowns.
const PRECONDITIONED_ITERATIONS: usize = 20;

/// How closely a Newton step's conjugate gradients solve its system at the least: the
/// residual after the full step at most this fraction of the present one (the forcing
/// term of an inexact Newton method; a tighter one, 1e-3, took more iterations and no
/// fewer Newton steps), and at most [`STEP_RESIDUAL`] of the solve's stopping residual.
const STEP_FORCING: f64 = 1e-2;

/// The predicted residual after a Newton step's full step, relative to the solve's
/// stopping residual, at which its conjugate gradients stop.
const STEP_RESIDUAL: f64 = 0.1;

/// Newton steps of a warm frictional solve before it starts again through the larger
/// stick radii, and the residual (relative to the loads) at which those stages stop. A
/// warm solve that runs long is still cheaper than the stages (about 40 steps; measured:
/// `docs/solvers.md`, "A held grasp split first").
const WARM_NEWTON: usize = MAX_NEWTON;
const STAGE_RESIDUAL: f64 = 1e-4;

/// Whether a frame's first frictional solve starts with a step that assumes every point
/// sticks ([`Friction::predict_stick`]): a sliding face's Newton steps a frame fall by
/// three or four times (measured: `docs/solvers.md`, "A sliding face: the first step
/// assumes the points stick").
const PREDICT_STICK: bool = true;

/// Refreshes of friction's lagged normal forces at most per solve.
const MAX_LAGS: usize = 12;

/// Motion of an indenter over a frame (cells) up to which the frame's forces and first
/// lagged normal forces start extrapolated along the last frame's change of them
/// ([`Compliance::secant_start`]), where the indenters move on along their last motion
/// (the cosine of the two at least [`SECANT_ALIGNMENT`]). Over a tenth of a cell a lattice
/// point's force changes smoothly from frame to frame, so the line through the last two
/// frames' forces lies close to the next: on the moving press of `cargo bench --bench
/// sensor` (34 to 70 um a frame, a fortieth to a twentieth of the default gel's 1.4 mm
/// cell) the Newton steps fell by a third (287 -> 186 under the sphere at 320 x 240, 549
/// -> 371 at 64 x 48). Beyond it a point's force does not follow a line: at up to a
/// third of a cell, Press-v1's sweep (up to 0.78 mm a step) took 7 % more (3,708 -> 3,963
/// over 600 steps; measured: `docs/solvers.md`, "A slowly moving contact starts along its
/// secant").
const SECANT_MOTION: f64 = 0.1;
const SECANT_ALIGNMENT: f64 = 0.9;

/// Whether the first frame of a contact of at least [`SPLIT_UNKNOWNS`] (no last frame's
/// answer to start from) solves its friction as a warm frame does (one Newton step, then
/// [`split_start`], then Newton's method; the stages through the larger stick radii only
/// where that fails), from its frictionless solve's loads: split, its points find their
/// stick set in tens of iterations of a few triangular solves each, where Newton's method
/// through the larger stick radii took 50 to 60 steps of a factorisation each. Measured on
/// `tacrom/GripperLift-v1`'s first touch of the box (the pads' wide faces, about 320 node
/// columns each): 210 and 208 ms -> 123 and 118 ms a gel, 59 and 52 Newton steps -> 28
/// and 21 (`docs/solvers.md`, "A wide contact's first frame split too").
const WIDE_FIRST_FRAME: bool = true;

/// Residual (relative to the loads) at which a frictional contact solve stops at the
/// tightest.
const FRICTION_RESIDUAL: f64 = 1e-10;

/// A frame's frictional solves stop at this fraction of the frame's tolerance (as a
/// residual relative to the loads, [`FRICTION_RESIDUAL`] at the least): each refresh of
/// the lagged normal forces poses a new problem, and solving each to round-off before
/// the next bought nothing. The loads then balance the forces to a thousandth of what
/// the frame's own convergence test allows (measured: `docs/solvers.md`, "A sliding face:
/// the first step assumes the points stick").
const INNER_RESIDUAL: f64 = 1e-3;

/// Line search halvings at most per iteration.
const MAX_HALVINGS: usize = 40;

/// Whether a line search takes a trial point of energy `trial` at `alpha` along a step of
/// slope `slope` from energy `e`: on Armijo's decrease, or, where the energy's change is
/// below its round-off (near the answer, where it changes by the residual squared), when
/// `lowers` finds the residual smaller there. (By the energy alone such a step is taken or
/// refused by the round-off: a pad pressed by a box face refused its exact last step by a
/// unit in the last place, took steps of 2^-26 that changed nothing, and ran out of
/// iterations.)
fn takes(e: f64, trial: f64, alpha: f64, slope: f64, lowers: impl FnOnce() -> bool) -> bool {
    let unresolved = (trial - e).abs() <= 16.0 * f64::EPSILON * e.abs();
    trial <= e + 1e-4 * alpha * slope || (unresolved && lowers())
}

/// [`penalty_contact_into`], returning the forces.
#[cfg(test)]
fn penalty_contact(p: &Problem, l: &mut DVector<f64>) -> Option<(Vec<f64>, usize)> {
    let mut f = Vec::new();
    let iterations = penalty_contact_into(p, l, &mut f)?;
    Some((f, iterations))
}

/// The penalty contact in the node columns' loads `l`: the columns sink `v = G l` (`G`
/// their sinking under their loads: symmetric, positive definite), the points `s = W v`
/// (`W` their column weights, rows of `(column, weight)`), and press with forces
/// `f = max(0, delta - s) / eps`; equilibrium is `l = W^T f`. It is the minimum of the
/// energy `E(l) = l^T G l / 2 + eps |f|^2 / 2` (the gel's, plus the penalty's), convex
/// and piecewise quadratic, whose gradient is `G (l - W^T f)`, and the same answer as the
/// complementarity problem `f >= 0, eps f + W G W^T f - delta >= 0, f . (...) = 0` on the
/// points. On a fixed set `A` of pressed points the Newton step solves
/// `(I + W_A^T W_A G / eps) d = W^T f - l`: a system the size of the columns, however many
/// points there are (here many more points than columns, which makes the problem on the
/// points degenerate). Armijo's backtracking on `E` keeps it descending (Newton's method
/// on a convex piecewise quadratic: the primal-dual active set method with a line
/// search, Hintermueller, Ito and Kunisch 2002); once the pressed set repeats after a full
/// step, the answer is exact. Starts from `l` (updated); leaves the forces in `out` (its
/// allocation kept; the vectors kept in the problem's [`Steps`]: a frame allocates nothing
/// once they are sized); returns the iterations, or `None` if they run out or a solve
/// fails.
fn penalty_contact_into(p: &Problem, l: &mut DVector<f64>, out: &mut Vec<f64>) -> Option<usize> {
    let Problem {
        g,
        inverse,
        w,
        delta,
        eps,
        ..
    } = *p;
    let k = g.nrows();
    let mut kept = p.steps.lock().unwrap_or_else(|e| e.into_inner());
    let Penalty {
        v,
        ft,
        wf,
        wt,
        r,
        trial,
        before,
        direction,
    } = &mut kept.penalty;
    let f = out;
    // The forces at `l` into `f` and the energy there, from one product `G l`.
    let evaluate = |l: &DVector<f64>, v: &mut DVector<f64>, f: &mut Vec<f64>| -> f64 {
        product_into(g, l, v);
        f.clear();
        f.extend(w.iter().zip(delta).zip(eps).map(|((row, &d), &eps)| {
            let s: f64 = row.iter().map(|&(c, wt)| wt * v[c as usize]).sum();
            ((d - s) / eps).max(0.0)
        }));
        0.5 * l.dot(v) + 0.5 * f.iter().zip(eps).map(|(f, eps)| eps * f * f).sum::<f64>()
    };
    // `W^T f` into `out`.
    let loads = |f: &[f64], out: &mut DVector<f64>| {
        sized(out, k).fill(0.0);
        for (row, &f) in w.iter().zip(f) {
            if f > 0.0 {
                for &(c, wt) in row {
                    out[c as usize] += wt * f;
                }
            }
        }
    };
    let mut e = evaluate(l, v, f);
    for it in 0..MAX_NEWTON {
        loads(f, wf);
        sized(r, k).copy_from(l);
        *r -= &*wf;
        let scale = l.amax().max(wf.amax());
        if r.amax() <= 1e-12 * scale || scale == 0.0 {
            return Some(it);
        }
        let mut scratch = p.scratch.lock();
        let system = Problem::system_in(&mut scratch.double, inverse);
        for ((row, _), eps) in w
            .iter()
            .zip(f.iter())
            .zip(eps)
            .filter(|((_, &f), _)| f > 0.0)
        {
            for &(a, wa) in row {
                for &(b, wb) in row {
                    system[(a as usize, b as usize)] += wa * wb / eps;
                }
            }
        }
        p.descent(system, r, direction)?;
        let (step, slope) = (&direction.step, direction.slope);
        drop(scratch);
        before.clear();
        before.extend(f.iter().map(|&f| f > 0.0));
        let mut alpha = 1.0;
        let mut accepted = false;
        for _ in 0..MAX_HALVINGS {
            sized(trial, k).zip_zip_apply(l, step, |t, l, s| *t = l + s * alpha);
            let et = evaluate(trial, v, ft);
            if takes(e, et, alpha, slope, || {
                loads(ft, wt);
                trial
                    .iter()
                    .zip(wt.iter())
                    .fold(0.0, |m: f64, (t, w)| m.max((t - w).abs()))
                    < r.amax()
            }) {
                l.copy_from(trial);
                std::mem::swap(f, ft);
                e = et;
                accepted = true;
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            // No decrease left to find: the energy is at its minimum to round-off.
            return Some(it + 1);
        }
        if alpha == 1.0 && f.iter().map(|&f| f > 0.0).eq(before.iter().copied()) {
            // A full step on a pressed set that it keeps: the exact answer on that set.
            return Some(it + 1);
        }
    }
    None
}

/// The vectors of [`penalty_contact_into`] (each sized and overwritten before it is
/// read): the columns' sinking, a trial's forces, the loads of the forces and of a
/// trial's, the residual, the trial loads, the pressed set before a step, and the step.
#[derive(Default)]
struct Penalty {
    v: DVector<f64>,
    ft: Vec<f64>,
    wf: DVector<f64>,
    wt: DVector<f64>,
    r: DVector<f64>,
    trial: DVector<f64>,
    before: Vec<bool>,
    direction: Descent,
}

/// Friction's data per point of [`frictional_contact`]: the cap of its force (`mu` times
/// its lagged normal force) and its anchor's lateral offset from its rest position
/// (cells).
struct Friction<'a> {
    caps: &'a [f64],
    anchors: &'a [Vector2<f64>],
    /// Whether the start is the answer to a nearby problem (the last lagged forces', or a
    /// wide contact's frictionless solve: [`WIDE_FIRST_FRAME`]): then Newton's method goes
    /// straight at the stick radius, and only if that takes more than [`WARM_NEWTON`]
    /// steps through the larger radii.
    warm: bool,
    /// The residual (relative to the loads) at which the solve stops: within a frame,
    /// [`INNER_RESIDUAL`] of the frame's tolerance ([`FRICTION_RESIDUAL`] at the least).
    residual: f64,
    /// Whether the first Newton step assumes that every point with a cap sticks (its
    /// friction a spring of the stick stiffness to its anchor, uncapped): the frame's
    /// first solve, started from the last frame's answer. The anchors move with the
    /// indenter, so a face that slid or crept a few microns starts with every point
    /// further from its anchor than the stick radius, sliding; Newton's method then
    /// found the points that stick a few hundred per step, each step damped by the
    /// line search. See [`PREDICT_STICK`].
    predict_stick: bool,
    /// Unknowns from which a warm solve that Newton's method does not finish in
    /// [`SPLIT_AFTER`] steps is split ([`split_start`]).
    split: usize,
}

/// [`frictional_contact`]'s warm start: Newton's method from `l` (a held grasp, a press
/// moving on: one to three steps); if it is still changing which points stick, split,
/// and finished with it. `None` (`l` spoilt) where that does not converge within
/// [`WARM_NEWTON`] steps.
fn warm_contact(
    p: &Problem,
    friction: &Friction,
    kept: &mut Option<SplitFactor>,
    l: &mut DVector<f64>,
    forces: &mut Vec<Vector3<f64>>,
) -> Option<usize> {
    let budget = WARM_NEWTON;
    let split = l.len() >= friction.split;
    let first = if split { SPLIT_AFTER } else { budget };
    if let Some(answer) = minimise(p, friction, STICK, friction.residual, first, l, forces) {
        return Some(answer);
    }
    if !split {
        return None;
    }
    // (Where the start is already the answer, it is left to Newton's method as it came.)
    let moved = split_start(p, friction, STICK, kept, l) > 0;
    let friction = &Friction {
        predict_stick: friction.predict_stick && !moved,
        ..*friction
    };
    minimise(
        p,
        friction,
        STICK,
        friction.residual,
        budget - first,
        l,
        forces,
    )
    .map(|steps| steps + first)
}

/// The penalty contact with friction, in the node columns' loads `l` (+x, +y and
/// downward per column): the columns move `v = G l` (+x, +y and sinking; `G` symmetric,
/// positive definite), the points `s = W v`; each presses with `f = max(0, delta - s_z) /
/// eps` and, where it carries a lagged normal force, `caps = mu f_lagged`, is held towards
/// its anchor (lateral offset `anchors` from its rest position) by Coulomb friction
/// smoothed as Newton's: the lateral offset `y = |s_xy - anchor|` costs `cap f0(y)`, `f0`
/// quadratic up to [`STICK`] and linear beyond (the full sliding force `cap`). The energy
/// `E(l) = l^T G l / 2 + sum_p (eps f_p^2 / 2 + cap_p f0(y_p))` is convex, its gradient
/// `G (l - W^T F)` with `F` the points' forces on the gel; Newton's method with its
/// Hessian (the points' contact and friction stiffness, per 3 x 3 block) and Armijo's
/// backtracking, as [`penalty_contact`], to a residual of `friction.residual` of the
/// loads. Starts from `l` (updated); returns the forces on the gel (+x, +y, downward) and
/// the iterations, or `None` if they run out or a solve fails.
fn frictional_contact(
    p: &Problem,
    friction: &Friction,
    kept: &mut Option<SplitFactor>,
    l: &mut DVector<f64>,
    forces: &mut Vec<Vector3<f64>>,
) -> Option<usize> {
    let mut total = 0;
    if friction.warm {
        // The start kept in the steps' vectors (a poisoned lock's are overwritten anyway).
        let steps = || p.steps.lock().unwrap_or_else(|e| e.into_inner());
        let mut start = std::mem::take(&mut steps().start);
        sized(&mut start, l.len()).copy_from(l);
        let answer = warm_contact(p, friction, kept, l, forces);
        if answer.is_none() {
            l.copy_from(&start);
            total = WARM_NEWTON;
        }
        steps().start = start;
        if answer.is_some() {
            return answer;
        }
    }
    let stages = [STICK * 100.0, STICK * 10.0, STICK];
    for (n, &radius) in stages.iter().enumerate() {
        let last = n + 1 == stages.len();
        let tolerance = if last {
            friction.residual
        } else {
            STAGE_RESIDUAL.max(friction.residual)
        };
        total += minimise(p, friction, radius, tolerance, MAX_NEWTON, l, forces)?;
        if last {
            return Some(total);
        }
    }
    None
}

/// How much a refresh of a point's lagged normal force `lagged` would change its
/// friction force at its present displacement: `force` its force on the gel now, `cap`
/// the friction it was capped at (`mu` times `lagged`, 0 where it carried none). The
/// smoothed Coulomb force is the cap times a function of the point's offset from its
/// anchor, so a refresh scales a capped point's friction by the ratio of its normal
/// forces, sticking or sliding; a point pressed now that had no normal force lagged takes
/// a cap of `mu` times its normal force (`mu` 0 where it can carry no friction).
fn refreshed_friction(force: &Vector3<f64>, lagged: f64, cap: f64, mu: f64) -> f64 {
    if cap > 0.0 {
        force.xy().norm() * (force.z - lagged).abs() / lagged
    } else if lagged == 0.0 {
        mu * force.z
    } else {
        0.0
    }
}

/// Most iterations of [`vertical_start`]'s active-set search.
const VERTICAL_ITERATIONS: usize = 50;

/// [`vertical_start`]s a frame takes at most, each from the last one's normal forces: the
/// points it finds pressed that had no anchor take theirs before the next (they slide
/// from where they were at the frame's start), so the second one sees their friction.
const VERTICAL_PASSES: usize = 2;

/// The [`StartDemand::slip`] above which a frame's first frictional solve starts from
/// [`vertical_start`] rather than from the last frame's loads alone. A face held, slid or
/// shaken by microns asks its points for 0 to 0.07 of what friction can move the gel
/// (its first Newton step, which assumes every point sticks, is what it needs); the
/// 5 mm sphere of `tacrom/Press-v1`'s sweep, 0.07 to 1.25. Measured: `docs/solvers.md`,
/// "The sliding sphere's frame: the normal forces found first".
const GROSS_SLIP: f64 = 0.15;

/// The inverse of the vertical block `G_zz` of the columns' compliance `g` (three
/// unknowns per column, the vertical last): [`vertical_start`]'s system.
fn vertical_inverse(g: &DMatrix<f64>, out: &mut DMatrix<f64>) -> Option<()> {
    let cols = g.nrows() / 3;
    let mut invert = |block: &mut DMatrix<f64>| {
        fill(reshaped(block, cols, cols), |a, b| {
            g[(3 * a + 2, 3 * b + 2)]
        });
        spd_inverse_into(block, out)
    };
    VERTICAL_BLOCK.with(|kept| match kept.try_borrow_mut() {
        Ok(mut block) => invert(&mut block),
        // This thread is inside another's factorisation (a parallel one that took up
        // other work while it waited): a block of its own.
        Err(_) => invert(&mut DMatrix::zeros(0, 0)),
    })
}

thread_local! {
    /// [`vertical_inverse`]'s copy of the vertical block, factored in place.
    static VERTICAL_BLOCK: std::cell::RefCell<DMatrix<f64>> =
        std::cell::RefCell::new(DMatrix::zeros(0, 0));
}

/// A start for a frame's first frictional solve whose pressed set is already nearly the
/// answer's. Each anchored point's friction (cap `mu` times its normal force, where
/// `caps` gives it one) is held in the direction and share of its cap it has at `l`, and
/// the normal forces are solved for it by the primal-dual active set method without a
/// line search on the vertical block of the columns' compliance: on the pressed set `S`
/// the columns' sinking `y` under the normal forces solves `(G_zz^-1 + W_S^T E_S^-1 W_S)
/// y = W_S^T E_S^-1 (delta_S - c_S)` (`c` the points' sinking under the friction forces,
/// `E` their contact compliances; `inverse_zz` is `G_zz^-1`), a system of the columns
/// alone (a third of the frictional solve's unknowns); the next set is the points that
/// sink less than their depths, and the friction forces follow the new normal forces.
/// Where the set repeats and the normal forces move by at most `settled` of their sum
/// (the frame's tolerance, as the lagged forces' refresh), `l` becomes the loads of those
/// forces and the normal forces are returned; `None` (and `l` unchanged) where that does
/// not happen within [`VERTICAL_ITERATIONS`] or a solve fails.
#[allow(clippy::too_many_arguments)]
fn vertical_start(
    p: &Problem,
    inverse_zz: &DMatrix<f64>,
    mu: f64,
    caps: &[f64],
    anchors: &[Vector2<f64>],
    settled: f64,
    l: &mut DVector<f64>,
    normal: &mut Vec<f64>,
) -> Option<()> {
    let Problem {
        g, w, delta, eps, ..
    } = *p;
    let k = g.nrows();
    let cols = k / 3;
    let n = w.len();
    // (A poisoned lock's vectors are overwritten before use anyway.)
    let mut kept = p.steps.lock().unwrap_or_else(|e| e.into_inner());
    let Vertical {
        v,
        at,
        unit,
        lifted_points,
        sinks,
        set,
        follow,
        system,
        factored,
        next,
        lifted,
        need,
        y,
        column,
        added,
        removed,
        forces,
        lateral,
    } = &mut kept.vertical;
    product_into(g, l, v);
    at_points_into(w, v, at);
    let sink_at =
        |y: &[f64], i: usize| -> f64 { w[i].iter().map(|&(c, wt)| wt * y[c as usize]).sum() };
    // Each anchored point's friction per unit normal force, as it is at `l`, and the
    // columns' sinking under it.
    refill(unit, n, Vector2::zeros());
    // The anchored points, and their columns' sinking one after another (`cols` each).
    lifted_points.clear();
    lifted_points.extend((0..n).filter(|&i| caps[i] > 0.0));
    refill(sinks, lifted_points.len() * cols, 0.0);
    // The columns' sinking under each lateral unknown's unit load (`G`'s vertical rows of
    // its column), one after another: read contiguously below, once per point's weight.
    lateral.clear();
    if !lifted_points.is_empty() {
        for k in (0..cols).flat_map(|c| [3 * c, 3 * c + 1]) {
            let col = g.column(k);
            lateral.extend((0..cols).map(|j| col[3 * j + 2]));
        }
    }
    for (&i, sink) in lifted_points
        .iter()
        .zip(sinks.chunks_exact_mut(cols.max(1)))
    {
        let (f, _, _) = point_force(&at[i], delta[i], eps[i], mu, &anchors[i], STICK);
        unit[i] = f.xy();
        for &(c, wt) in &w[i] {
            for (axis, t) in [(0, f.x), (1, f.y)] {
                let from = (2 * c as usize + axis) * cols;
                let t = t * wt;
                for (s, &g) in sink.iter_mut().zip(&lateral[from..from + cols]) {
                    *s += t * g;
                }
            }
        }
    }
    // The pressed set starts from the points the last frame pressed (those with a cap),
    // else from those the start's loads leave inside: a set that slid on with its
    // indenter, which the active set method reaches from in fewer changes (a sliding
    // sphere: 9.1 iterations a start against 11.2, 6.0 factorisations against 8.1).
    // Each list of points at most `n` long: room for that in each (they swap roles).
    for list in [
        &mut *set,
        &mut *next,
        &mut *factored,
        &mut *added,
        &mut *removed,
    ] {
        list.clear();
        list.reserve(n);
    }
    if caps.iter().any(|&c| c > 0.0) {
        set.extend((0..n).filter(|&i| caps[i] > 0.0));
    } else {
        set.extend((0..n).filter(|&i| delta[i] - at[i].z > 0.0));
    }
    // The normal forces the friction follows (at first the lagged ones), changed only
    // once the pressed set repeats.
    follow.clear();
    follow.extend((0..n).map(|i| if mu > 0.0 { caps[i] / mu } else { 0.0 }));
    refill(normal, n, 0.0);
    refill(system, cols * cols, 0.0);
    // The pressed set `system` holds the factor of, once it holds one.
    let mut has_factor = false;
    factored.clear();
    next.clear();
    refill(lifted, cols, 0.0);
    refill(need, n, 0.0);
    refill(y, cols, 0.0);
    let mut followed = false;
    refill(column, cols, 0.0);
    for _ in 0..VERTICAL_ITERATIONS {
        if !followed {
            // The columns' sinking under the friction forces, and what is left to sink.
            lifted.fill(0.0);
            for (&i, sink) in lifted_points.iter().zip(sinks.chunks_exact(cols.max(1))) {
                for (to, s) in lifted.iter_mut().zip(sink) {
                    *to += follow[i] * s;
                }
            }
            for i in 0..n {
                need[i] = delta[i] - sink_at(lifted, i);
            }
            followed = true;
        }
        if !has_factor || factored != set {
            // A few points in or out: the last factor updated by their rank-one terms
            // (`cols^2` each, against the factorisation's `cols^3 / 3`); else, or where a
            // removal leaves it indefinite in round-off, factored afresh.
            let updated = has_factor && {
                set_changes(factored, set, added, removed);
                (added.len() + removed.len()) * RANK_ONE_COST <= cols
                    && added
                        .iter()
                        .map(|&i| (i, false))
                        .chain(removed.iter().map(|&i| (i, true)))
                        .all(|(i, remove)| {
                            column.fill(0.0);
                            let e = (1.0 / eps[i]).sqrt();
                            for &(a, wa) in &w[i] {
                                column[a as usize] += wa * e;
                            }
                            small_rank_one(system, cols, column, remove).is_some()
                        })
            };
            if !updated {
                system.copy_from_slice(inverse_zz.as_slice());
                for &i in set.iter() {
                    let e = 1.0 / eps[i];
                    for &(a, wa) in &w[i] {
                        let a = a as usize;
                        for &(b, wb) in &w[i] {
                            if (b as usize) <= a {
                                system[a * cols + b as usize] += wa * wb * e;
                            }
                        }
                    }
                }
                small_cholesky(system, cols)?;
            }
            factored.clone_from(set);
            has_factor = true;
        }
        y.fill(0.0);
        for &i in set.iter() {
            let e = need[i] / eps[i];
            for &(a, wa) in &w[i] {
                y[a as usize] += wa * e;
            }
        }
        small_solve(system, cols, y);
        next.clear();
        for i in 0..n {
            normal[i] = ((need[i] - sink_at(y, i)) / eps[i]).max(0.0);
            if normal[i] > 0.0 {
                next.push(i);
            }
        }
        if next == set {
            let (change, total) = normal
                .iter()
                .zip(follow.iter())
                .fold((0.0, 0.0), |(c, t), (a, b)| (c + (a - b).abs(), t + a));
            if change <= settled * total || lifted_points.is_empty() {
                forces.clear();
                forces.extend((0..n).map(|i| {
                    Vector3::new(unit[i].x * normal[i], unit[i].y * normal[i], normal[i])
                }));
                on_columns_into(w, forces, sized(l, k));
                return Some(());
            }
            follow.copy_from_slice(normal);
            followed = false;
        }
        std::mem::swap(set, next);
    }
    None
}

/// The vectors of [`vertical_start`], kept with [`Steps`] (each sized and overwritten
/// before it is read).
#[derive(Default)]
struct Vertical {
    v: DVector<f64>,
    at: Vec<Vector3<f64>>,
    unit: Vec<Vector2<f64>>,
    lifted_points: Vec<usize>,
    sinks: Vec<f64>,
    set: Vec<usize>,
    follow: Vec<f64>,
    system: Vec<f64>,
    factored: Vec<usize>,
    next: Vec<usize>,
    lifted: Vec<f64>,
    need: Vec<f64>,
    y: Vec<f64>,
    column: Vec<f64>,
    added: Vec<usize>,
    removed: Vec<usize>,
    forces: Vec<Vector3<f64>>,
    lateral: Vec<f64>,
}

/// `a . b`, summed in four lanes (a reduction the compiler vectorises).
fn lanes_dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for j in 0..4 {
            acc[j] += x[j] * y[j];
        }
    }
    let tail: f64 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// The Cholesky factor of the symmetric positive definite `n x n` matrix `a` (row major;
/// its lower triangle read and overwritten), in place: for the small systems of
/// [`vertical_start`], where a library's dispatch costs more than the arithmetic. `None`
/// where a pivot is not positive.
fn small_cholesky(a: &mut [f64], n: usize) -> Option<()> {
    for j in 0..n {
        let row_j = &mut a[j * n..j * n + j + 1];
        let d = row_j[j] - lanes_dot(&row_j[..j], &row_j[..j]);
        if !(d > 0.0) {
            return None;
        }
        row_j[j] = d.sqrt();
        let (upper, lower) = a.split_at_mut((j + 1) * n);
        let row_j = &upper[j * n..j * n + j + 1];
        for row_i in lower.chunks_exact_mut(n) {
            row_i[j] = (row_i[j] - lanes_dot(&row_i[..j], &row_j[..j])) / row_j[j];
        }
    }
    Some(())
}

/// Solves `a x = b` in place from [`small_cholesky`]'s factor (`L L^T`, `L` row major).
fn small_solve(a: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        let row = &a[i * n..i * n + i];
        let s = b[i] - lanes_dot(row, &b[..i]);
        b[i] = s / a[i * n + i];
    }
    for i in (0..n).rev() {
        let s = b[i] / a[i * n + i];
        b[i] = s;
        for k in 0..i {
            b[k] -= a[i * n + k] * s;
        }
    }
}

/// [`vertical_start`]'s factor of `cols` columns is updated where at most `cols /
/// RANK_ONE_COST` points went in or out of the pressed set, else made afresh: a rank-one
/// update costs at most `cols^2` multiplications (half that on average: it starts at the
/// point's first column), the factorisation `cols^3 / 3` and its assembly more.
const RANK_ONE_COST: usize = 3;

/// The points of the sorted set `now` that the sorted set `last` lacks, and those it has
/// that `now` lacks.
fn set_changes(last: &[usize], now: &[usize], added: &mut Vec<usize>, removed: &mut Vec<usize>) {
    added.clear();
    removed.clear();
    let (mut a, mut b) = (0, 0);
    while a < last.len() && b < now.len() {
        if last[a] == now[b] {
            (a, b) = (a + 1, b + 1);
        } else if last[a] < now[b] {
            removed.push(last[a]);
            a += 1;
        } else {
            added.push(now[b]);
            b += 1;
        }
    }
    removed.extend_from_slice(&last[a..]);
    added.extend_from_slice(&now[b..]);
}

/// [`small_cholesky`]'s factor `L` of `A` (row major, lower triangle) made the factor of
/// `A + x x^T`, or of `A - x x^T` where `remove`, in place (`x` is overwritten): the
/// classical sweep of plane rotations from `x`'s first non-zero on. `None` where a
/// removal leaves a pivot below a millionth of its square (then `L` is spoilt: factor
/// afresh).
fn small_rank_one(a: &mut [f64], n: usize, x: &mut [f64], remove: bool) -> Option<()> {
    let sign = if remove { -1.0 } else { 1.0 };
    let Some(first) = x.iter().position(|&v| v != 0.0) else {
        return Some(());
    };
    for k in first..n {
        let xk = x[k];
        if xk == 0.0 {
            continue;
        }
        let lkk = a[k * n + k];
        let r2 = lkk * lkk + sign * xk * xk;
        if !(r2 > 1e-6 * lkk * lkk) {
            return None;
        }
        let r = r2.sqrt();
        let (c, s) = (r / lkk, xk / lkk);
        a[k * n + k] = r;
        for i in k + 1..n {
            let lik = (a[i * n + k] + sign * s * x[i]) / c;
            x[i] = c * x[i] - s * lik;
            a[i * n + k] = lik;
        }
    }
    Some(())
}

/// The [`StartDemand::imbalance`] above which a frame's first frictional solve starts from
/// [`vertical_start`] whatever its slip: the face moved into or out of the gel since the
/// last frame, so the last frame's normal forces no longer balance the points' penalty
/// there. Its values are nearly two-valued: a face held or slid along the gel gives 0 to
/// 1.3e-3 (the start already balances its normal forces, and its first Newton step,
/// which assumes every point sticks, is what it needs), a press deepening, a face shaken
/// into the gel by a micron or a coupled object moving in a grasp 0.49 to 1 (a micron
/// deeper changes a penalty force by about as much as the force). Measured:
/// `docs/solvers.md`, "A face moved into the gel: the normal forces found first too".
const NORMAL_IMBALANCE: f64 = 0.1;

/// What a frame's start, the last frame's loads `l`, asks of its frictional solve: the
/// gate of [`vertical_start`].
struct StartDemand {
    /// How far the anchored points are asked to slide (the cap-weighted mean of their
    /// lateral offsets from their anchors) over how far the gel's surface under them
    /// moves when every one pulls with its whole cap along that mean: above one, friction
    /// cannot hold them all, and the contact slides as a whole.
    slip: f64,
    /// The largest vertical residual of the columns, `|l_z - (W^T f)_z|` (`f` the points'
    /// forces at the displacements `G l`), over the largest vertical load of either: how
    /// far the normal forces at the start are from balancing the loads.
    imbalance: f64,
}

impl StartDemand {
    /// The demand of loads `l` on problem `p` with friction caps `caps` and anchors
    /// `anchors`: two products with the compliance (the start's displacements, and the
    /// surface's under the caps' pull).
    fn at(p: &Problem, caps: &[f64], anchors: &[Vector2<f64>], l: &DVector<f64>) -> StartDemand {
        let Problem {
            g, w, delta, eps, ..
        } = *p;
        let k = g.nrows();
        // (A poisoned lock's vectors are overwritten before use anyway.)
        let mut kept = p.steps.lock().unwrap_or_else(|e| e.into_inner());
        let Steps {
            v,
            wf,
            s: at,
            f: forces,
            ..
        } = &mut *kept;
        product_into(g, l, v);
        at_points_into(w, v, at);
        forces.clear();
        forces.extend(
            (0..w.len())
                .map(|i| point_force(&at[i], delta[i], eps[i], caps[i], &anchors[i], STICK).0),
        );
        on_columns_into(w, forces, sized(wf, k));
        let (mut residual, mut scale) = (0.0f64, 0.0f64);
        for c in (2..k).step_by(3) {
            residual = residual.max((l[c] - wf[c]).abs());
            scale = scale.max(l[c].abs()).max(wf[c].abs());
        }
        let imbalance = if scale > 0.0 { residual / scale } else { 0.0 };
        let Steps {
            v,
            wf,
            s: at,
            f: pulls,
            st: moved,
            ..
        } = &mut *kept;
        StartDemand {
            slip: Self::slip(p, caps, anchors, at, [v, wf], pulls, moved),
            imbalance,
        }
    }

    /// [`StartDemand::slip`] from the points' displacements `at` at the start (`columns`,
    /// `pulls` and `moved` its vectors, overwritten).
    fn slip(
        p: &Problem,
        caps: &[f64],
        anchors: &[Vector2<f64>],
        at: &[Vector3<f64>],
        columns: [&mut DVector<f64>; 2],
        pulls: &mut Vec<Vector3<f64>>,
        moved: &mut Vec<Vector3<f64>>,
    ) -> f64 {
        let Problem { g, w, .. } = *p;
        let k = g.nrows();
        let (mut demand, mut weight) = (Vector2::zeros(), 0.0);
        for i in (0..w.len()).filter(|&i| caps[i] > 0.0) {
            demand += (at[i].xy() - anchors[i]) * caps[i];
            weight += caps[i];
        }
        if !(weight > 0.0) {
            return 0.0;
        }
        let demand = demand / weight;
        let Some(towards) = (-demand).try_normalize(0.0) else {
            return 0.0;
        };
        pulls.clear();
        pulls.extend((0..w.len()).map(|i| Vector3::new(towards.x, towards.y, 0.0) * caps[i]));
        let [loads, sinking] = columns;
        on_columns_into(w, pulls, sized(loads, k));
        product_into(g, loads, sinking);
        at_points_into(w, sinking, moved);
        let follow: f64 = (0..w.len())
            .filter(|&i| caps[i] > 0.0)
            .map(|i| moved[i].xy().dot(&towards) * caps[i])
            .sum::<f64>()
            / weight;
        match follow > 0.0 {
            true => demand.norm() / follow,
            false => 0.0,
        }
    }

    /// Whether the frame starts from [`vertical_start`]: its contact slides as a whole
    /// ([`GROSS_SLIP`]) or its face moved into or out of the gel ([`NORMAL_IMBALANCE`]).
    fn asks_vertical(&self) -> bool {
        self.slip > GROSS_SLIP || self.imbalance > NORMAL_IMBALANCE
    }
}

/// [`frictional_contact`] with stick radius `radius` (cells), to a residual of
/// `tolerance` of the loads, in at most `budget` Newton steps.
fn minimise(
    p: &Problem,
    friction: &Friction,
    radius: f64,
    tolerance: f64,
    budget: usize,
    l: &mut DVector<f64>,
    forces: &mut Vec<Vector3<f64>>,
) -> Option<usize> {
    let Problem {
        g, w, delta, eps, ..
    } = *p;
    let Friction { caps, anchors, .. } = *friction;
    let k = g.nrows();
    // (A poisoned lock's vectors are overwritten before use anyway.)
    let mut kept = p.steps.lock().unwrap_or_else(|e| e.into_inner());
    let Steps {
        v,
        wf,
        r,
        trial,
        vt,
        wt,
        rhs,
        s,
        f,
        st,
        ft,
        stuck,
        stiff,
        direction,
        ..
    } = &mut *kept;
    // The points' displacements (into `at`) and forces (into `out`) at loads `l` whose
    // columns sink `v = G l`, and the energy there.
    let evaluate = |l: &DVector<f64>,
                    v: &DVector<f64>,
                    at: &mut Vec<Vector3<f64>>,
                    out: &mut Vec<Vector3<f64>>| {
        let mut e = 0.5 * l.dot(v);
        at_points_into(w, v, at);
        out.clear();
        for (i, s) in at.iter().enumerate() {
            let (f, pressed, slipped) =
                point_force(s, delta[i], eps[i], caps[i], &anchors[i], radius);
            e += pressed;
            e += slipped;
            out.push(f);
        }
        e
    };
    // The columns' sinking, carried along each step's own (`G d`, from the descent): one
    // product with `G` a solve, not one a trial.
    product_into(g, l, v);
    let mut e = evaluate(l, v, s, f);
    for b in [&mut *wf, &mut *r, &mut *trial, &mut *vt, &mut *wt] {
        sized(b, k);
    }
    // The answer's forces, and how many Newton steps found it.
    let done = |f: &[Vector3<f64>], forces: &mut Vec<Vector3<f64>>, steps: usize| {
        forces.clear();
        forces.extend_from_slice(f);
        Some(steps)
    };
    for it in 0..budget {
        on_columns_into(w, f, wf);
        r.zip_zip_apply(l, wf, |r, l, wf| *r = l - wf);
        let scale = l.amax().max(wf.amax());
        if r.amax() <= tolerance * scale || scale == 0.0 {
            return done(f, forces, it);
        }
        // The frame's first step assumes every point with a cap stuck (see
        // [`Friction::predict_stick`]).
        let predict = it == 0 && friction.predict_stick;
        // How closely a step's conjugate gradients solve its system: to a tenth of the
        // residual the solve stops at, or a hundredth of the present one if larger.
        let target = (STEP_RESIDUAL * tolerance * scale).max(STEP_FORCING * r.amax());
        // Each point's stiffness (penalty where it presses, friction's where it carries a
        // cap), for the system `G^-1 + W^T Phi'' W`: symmetric positive definite.
        stiff.clear();
        for i in 0..w.len() {
            let mut h = Matrix3::zeros();
            if f[i].z > 0.0 {
                h[(2, 2)] = 1.0 / eps[i];
            }
            if caps[i] > 0.0 {
                let d = s[i].xy() - anchors[i];
                let y = d.norm();
                let t = if y < radius || predict {
                    Matrix2::identity() * (caps[i] / radius)
                } else {
                    let n = d / y;
                    (Matrix2::identity() - n * n.transpose()) * (caps[i] / y)
                };
                h.fixed_view_mut::<2, 2>(0, 0).copy_from(&t);
            }
            if h != Matrix3::zeros() {
                stiff.push((i, h));
            }
        }
        if predict {
            // Each capped point's friction a spring of the stick stiffness to its anchor,
            // uncapped: the step to where they all stick, taken where it descends the
            // energy (else the gradient's own).
            stuck.clear();
            stuck.extend((0..w.len()).map(|i| match caps[i] > 0.0 {
                true => {
                    let t = -(s[i].xy() - anchors[i]) * (caps[i] / radius);
                    Vector3::new(t.x, t.y, f[i].z)
                }
                false => f[i],
            }));
            on_columns_into(w, stuck, sized(rhs, k));
            rhs.zip_apply(&*l, |x, l| *x = l - *x);
            // Its slope on this frame's energy: `(G r) . d = r . G d`.
            p.stiff_descent(stiff, rhs, target, direction)?;
            match r.dot(&direction.sinking) {
                slope if slope < 0.0 => direction.slope = slope,
                _ => p.gradient(r, direction),
            }
        } else {
            p.stiff_descent(stiff, r, target, direction)?
        };
        let Descent {
            step,
            sinking,
            slope,
        } = &*direction;
        let mut alpha = 1.0;
        let mut accepted = false;
        for _ in 0..MAX_HALVINGS {
            trial.zip_zip_apply(l, step, |t, l, d| *t = l + d * alpha);
            vt.zip_zip_apply(v, sinking, |t, v, d| *t = v + d * alpha);
            let et = evaluate(trial, vt, st, ft);
            if takes(e, et, alpha, *slope, || {
                on_columns_into(w, ft, wt);
                wt.zip_apply(trial, |w, t| *w = t - *w);
                wt.amax() < r.amax()
            }) {
                e = et;
                std::mem::swap(l, trial);
                std::mem::swap(v, vt);
                std::mem::swap(s, st);
                std::mem::swap(f, ft);
                accepted = true;
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            // No decrease left to find: the energy is at its minimum to round-off.
            return done(f, forces, it + 1);
        }
    }
    None
}

/// The root of `f` (negative at `inside`, not negative at `outside > inside`) that
/// `bisections` halvings of the bracket find: the midpoint of a bracket `2^-bisections` of
/// the first one wide.
fn bisected_root(
    f: impl Fn(f64) -> f64,
    mut inside: f64,
    mut outside: f64,
    bisections: usize,
) -> f64 {
    for _ in 0..bisections {
        let mid = 0.5 * (inside + outside);
        if f(mid) < 0.0 {
            inside = mid;
        } else {
            outside = mid;
        }
    }
    0.5 * (inside + outside)
}

/// [`bisected_root`]'s answer to the same width (the midpoint of a bracket at most
/// `2^-bisections` of the first one wide, or a point where `f` is zero) by the Illinois
/// method: regula falsi, halving the value kept at an end that stays twice running. A
/// signed distance along a line is nearly linear within a cell (a mesh's trilinear
/// interpolant is piecewise cubic along an oblique line, linear along an axis), so where
/// bisection evaluates `f` 24 times this takes two to nine. After [`SECANT_STEPS`] it
/// bisects, so that it ends however `f` bends.
fn bracketed_root(
    f: impl Fn(f64) -> f64,
    (mut a, mut fa): (f64, f64),
    (mut b, mut fb): (f64, f64),
    bisections: usize,
) -> f64 {
    let width = (b - a) * 0.5f64.powi(bisections as i32);
    let mut kept = 0i8;
    for step in 0..SECANT_STEPS + bisections {
        if fb == 0.0 {
            return b;
        }
        if b - a <= width {
            break;
        }
        // The secant's point, at least half the width from either end: an end that has
        // reached the root is then closed on from the other side by the next sample.
        let secant = b - fb * (b - a) / (fb - fa);
        let c = match step < SECANT_STEPS && secant.is_finite() {
            // (Not `clamp`, which panics where rounding crosses its ends.)
            true => secant.max(a + 0.5 * width).min(b - 0.5 * width),
            false => 0.5 * (a + b),
        };
        let fc = f(c);
        if fc < 0.0 {
            (a, fa) = (c, fc);
            if kept == 1 {
                fb *= 0.5;
            }
            kept = 1;
        } else {
            (b, fb) = (c, fc);
            if kept == -1 {
                fa *= 0.5;
            }
            kept = -1;
        }
    }
    0.5 * (a + b)
}

/// The steps of [`bracketed_root`] by regula falsi before it bisects.
const SECANT_STEPS: usize = 8;

/// The vertical gap (m) of [`Compliance::vertical_gap`] at the point `p` (sensor frame)
/// from the indenters' chords along the vertical ([`Sdf::chord`]): outside them, how far up
/// the first one begins; inside, minus how far down the point leaves them all (through
/// overlapping ones in turn). As the march it replaces, `Some(None)` where no indenter's
/// bounds hold `p` or nothing lies above it; `None` where an indenter has no closed form
/// (then the march runs). Exact where the march stops within its tolerance and bisects
/// its way out (`docs/solvers.md`, "The contact's vertical gaps from the primitives'
/// chords").
fn chord_gap(p: &Point3<f64>, indenters: &[StepIndenter]) -> Option<Option<f64>> {
    if !indenters.iter().any(|ind| contains(&ind.bounds, p)) {
        return Some(None);
    }
    let chord = |ind: &StepIndenter| {
        let o = ind.now.inverse_transform_point(p);
        let d = ind.now.inverse_transform_vector(&Vector3::z());
        ind.shape.chord(&o, &d)
    };
    let mut up = f64::INFINITY;
    let mut down = 0.0;
    for ind in indenters {
        match chord(ind) {
            Chord::Unknown => return None,
            Chord::Miss => {}
            Chord::Span(a, b) if a < 0.0 && b > 0.0 => down = f64::min(down, a),
            Chord::Span(a, _) if a >= 0.0 => up = up.min(a),
            Chord::Span(..) => {}
        }
    }
    if down == 0.0 {
        return Some(up.is_finite().then_some(up));
    }
    // Inside: down through every indenter that holds the point on the way, until none does.
    for _ in 0..indenters.len() {
        let deeper = indenters
            .iter()
            .filter_map(|ind| match chord(ind) {
                Chord::Span(a, b) if a < down && b > down => Some(a),
                _ => None,
            })
            .fold(down, f64::min);
        if deeper == down {
            break;
        }
        down = deeper;
    }
    Some(Some(down))
}

/// The points' displacements `W v` from the columns' (three per column, rows `w`), into
/// `at` (cleared first).
fn at_points_into(w: &[Columns], v: &DVector<f64>, at: &mut Vec<Vector3<f64>>) {
    // The column's three unknowns as one slice: one bounds check a weight, not three.
    let v = v.as_slice();
    at.clear();
    at.extend(w.iter().map(|row| {
        let mut s = Vector3::zeros();
        for &(c, wt) in row {
            let c = 3 * c as usize;
            let x = &v[c..c + 3];
            s += Vector3::new(x[0], x[1], x[2]) * wt;
        }
        s
    }));
}

/// A point's force on the gel (+x, +y, downward) at displacement `s` (+x, +y, sinking)
/// in [`minimise`]'s problem (depth `delta`, contact compliance `eps`, friction's `cap`
/// and `anchor`, stick radius `radius`), and its penalty's and friction's energies.
fn point_force(
    s: &Vector3<f64>,
    delta: f64,
    eps: f64,
    cap: f64,
    anchor: &Vector2<f64>,
    radius: f64,
) -> (Vector3<f64>, f64, f64) {
    let f = ((delta - s.z) / eps).max(0.0);
    let mut t = Vector2::zeros();
    let mut slipped = 0.0;
    if cap > 0.0 {
        let d = s.xy() - anchor;
        let y = d.norm();
        slipped = cap * smooth_slip(y, radius);
        t = -d * (cap / y.max(radius));
    }
    (Vector3::new(t.x, t.y, f), 0.5 * eps * f * f, slipped)
}

/// The columns' loads `W^T f` from the points' forces, into `out` (its length the
/// unknowns; zeroed first).
fn on_columns_into(w: &[Columns], f: &[Vector3<f64>], out: &mut DVector<f64>) {
    out.fill(0.0);
    let out = out.as_mut_slice();
    for (row, f) in w.iter().zip(f) {
        for &(c, wt) in row {
            let c = 3 * c as usize;
            let o = &mut out[c..c + 3];
            for j in 0..3 {
                o[j] += wt * f[j];
            }
        }
    }
}

/// Unknowns (three per node column) from which a warm frictional solve that Newton's
/// method does not finish in [`SPLIT_AFTER`] steps is split ([`split_start`]): 100 node
/// columns, where a Newton step's dense factorisation costs about half a millisecond and a
/// held grasp's unsplit solve took 10 to 20 of them (on smaller contacts Newton's steps
/// are cheap, and it runs as before; `tacrom/Press-v1`'s sphere loads 20 to 60 columns;
/// measured: `docs/solvers.md`, "A held grasp split first").
const SPLIT_UNKNOWNS: usize = 3 * 100;

/// Newton steps of a warm frictional solve before it splits: one step finishes a grasp
/// held still. (A split at once where the same points split in the solve before, from
/// its kept factor, would make the path depend on what MuJoCo's state does not carry.)
/// Measured: `docs/solvers.md`, "A held grasp split first".
const SPLIT_AFTER: usize = 1;

/// Iterations at most of [`split_start`]; the residual (relative to the points'
/// displacements) at which it stops; the iterations in a row with at most
/// [`SPLIT_CHANGES`] of the points (and at least [`MIN_SPLIT_CHANGES`] points) changing
/// between pressing or not, sticking or sliding, after which it hands over to Newton's
/// method (fewer iterations leave Newton's method more steps; measured:
/// `docs/solvers.md`, "A held grasp split first" and "The split's hand-over and the
/// lagged forces' refresh, in proportion").
const SPLIT_ITERATIONS: usize = 100;
const SPLIT_RESIDUAL: f64 = 1e-5;
const SPLIT_SETTLED: usize = 10;
const SPLIT_CHANGES: f64 = 1.0 / 200.0;
const MIN_SPLIT_CHANGES: usize = 2;

/// The stiffness of the springs that hold each point's copy to the gel in [`split_start`],
/// in units of the gel's own stiffness at a point (measured: `docs/solvers.md`, "A held
/// grasp split first").
const SPLIT_STIFFNESS: f64 = 10.0;

/// Over-relaxation of [`split_start`]'s iterations (1.5 to 1.8 is the usual range).
const SPLIT_RELAXATION: f64 = 1.6;

/// Starts [`minimise`]'s problem (stick radius `radius`) near its answer by the
/// alternating direction method of multipliers, one factorisation for every iteration:
/// the columns' displacements `v` (`v = G l`) and a copy `z_p` of each point's
/// displacement, bound by `z_p = W_p v`. The gel's part (`v^T G^-1 v / 2` with the copies
/// held by springs of stiffness `rho`) is one solve with the factors of `G^-1 + rho W^T W`
/// per direction ([`SplitFactor`]: the coupling of the lateral loads with the vertical
/// ones, and of `x` with `y`, kept at the start's displacements, so that an iteration
/// streams a third of the whole system's factor); each point's part (its penalty and its
/// friction, with the springs) is in closed form.
/// Newton's method on this problem damps every step that changes which points stick, so
/// a frame whose points start sliding (a held grasp trembling by microns) took 20 to 100
/// steps, a factorisation each; here those choices cost an iteration of two triangular
/// solves each. Updates `l`; returns the iterations (0: `l` is the answer already, to
/// the iterations' precision, and left as it is).
fn split_start(
    p: &Problem,
    friction: &Friction,
    radius: f64,
    kept: &mut Option<SplitFactor>,
    l: &mut DVector<f64>,
) -> usize {
    let Problem {
        g,
        inverse,
        w,
        delta,
        eps,
        ..
    } = *p;
    let Friction { caps, anchors, .. } = *friction;
    let k = g.nrows();
    let n = w.len();
    // (A poisoned lock's vectors are overwritten before use anyway.)
    let mut vectors = p.steps.lock().unwrap_or_else(|e| e.into_inner());
    let Split {
        weight,
        states,
        start,
        v,
        base,
        rhs,
        solved,
        x,
        z,
        u,
        target,
        s,
    } = &mut vectors.split;
    // The springs' stiffness: about the gel's own at a point (its columns' stiffness
    // shared among the points on them).
    refill(weight, k / 3, 0.0);
    for row in w {
        for &(c, wt) in row {
            weight[c as usize] += wt * wt;
        }
    }
    let diagonal = (0..k).map(|i| inverse[(i, i)]).sum::<f64>() / k as f64;
    let share =
        weight.iter().sum::<f64>() / weight.iter().filter(|&&x| x > 0.0).count().max(1) as f64;
    let rho = SPLIT_STIFFNESS * diagonal / share.max(1e-12);
    let cols = k / 3;
    if !kept.as_ref().is_some_and(|k| k.rho == rho && k.rows == w) {
        *kept = None;
        // Lower triangles (all the factorisation reads).
        let mut springs = DMatrix::<f64>::zeros(cols, cols);
        for row in w {
            for &(a, wa) in row {
                for &(b, wb) in row.iter().filter(|&&(b, _)| b <= a) {
                    springs[(a as usize, b as usize)] += rho * wa * wb;
                }
            }
        }
        let mut factors = Vec::with_capacity(3);
        for j in 0..3 {
            let mut factor = DMatrix::from_fn(cols, cols, |a, b| match a >= b {
                true => inverse[(3 * a + j, 3 * b + j)] + springs[(a, b)],
                false => 0.0,
            });
            if cholesky(&mut factor).is_none() {
                return 0;
            }
            factors.push(factor.map(|x| x as f32));
        }
        *kept = Some(SplitFactor {
            rows: w.to_vec(),
            rho,
            factors: factors.try_into().expect("three directions"),
        });
    }
    let factors = &kept.as_ref().expect("made above").factors;
    // `b` solved with each direction's factor: the system less `G^-1`'s coupling of one
    // direction's loads with another's.
    let solve = |b: &DVector<f64>, out: &mut DVector<f64>, x: &mut DVector<f32>| {
        let out = sized(out, k);
        let x = sized(x, cols);
        for (j, factor) in factors.iter().enumerate() {
            for i in 0..cols {
                x[i] = b[3 * i + j] as f32;
            }
            cholesky_solve(factor, x);
            for i in 0..cols {
                out[3 * i + j] = f64::from(x[i]);
            }
        }
    };
    // Each point's part: its displacement `z` nearest `q` against its penalty and friction.
    // Also its state: pressed (1), sticking (2).
    let prox = |i: usize, q: Vector3<f64>| -> (Vector3<f64>, u8) {
        let mut z = q;
        let mut state = 0;
        if q.z < delta[i] {
            z.z = (delta[i] / eps[i] + rho * q.z) / (1.0 / eps[i] + rho);
            state |= 1;
        }
        if caps[i] > 0.0 {
            let d = q.xy() - anchors[i];
            let m = d.norm();
            let xy = if m <= radius + caps[i] / rho {
                state |= 2;
                anchors[i] + d * (rho / (rho + caps[i] / radius))
            } else {
                anchors[i] + d * (1.0 - caps[i] / (rho * m))
            };
            z.x = xy.x;
            z.y = xy.y;
        }
        (z, state)
    };
    refill(states, n, 0u8);
    let mut settled = 0;
    let changes = ((n as f64 * SPLIT_CHANGES) as usize).max(MIN_SPLIT_CHANGES);
    // Warm: the copies at the start's displacements, the multipliers its forces on the
    // gel (scaled by `-1 / rho`), a fixed point where the start is the answer.
    product_into(g, l, start);
    sized(v, k).copy_from(start);
    at_points_into(w, v, z);
    u.clear();
    u.extend(
        (0..n).map(|i| -point_force(&z[i], delta[i], eps[i], caps[i], &anchors[i], radius).0 / rho),
    );
    // `(G^-1 + rho W^T W) v0`.
    on_columns_into(w, z, sized(base, k));
    base.zip_apply(&*l, |b, l| *b = l + *b * rho);
    let mut iterations = 0;
    for it in 0..SPLIT_ITERATIONS {
        iterations = it + 1;
        target.clear();
        target.extend(z.iter().zip(u.iter()).map(|(z, u)| z - u));
        // In single precision, the change from the start only (`G^-1 v0 = l`): its
        // error is a fraction of the change, not of the displacements (a start at the
        // answer stays there).
        on_columns_into(w, target, sized(rhs, k));
        rhs.zip_apply(base, |r, b| *r = *r * rho - b);
        solve(rhs, solved, x);
        v.zip_zip_apply(start, solved, |v, a, b| *v = a + b);
        at_points_into(w, v, s);
        let mut primal: f64 = 0.0;
        let mut dual: f64 = 0.0;
        let mut scale: f64 = 0.0;
        let mut changed = 0;
        for i in 0..n {
            let relaxed = s[i] * SPLIT_RELAXATION + z[i] * (1.0 - SPLIT_RELAXATION);
            let (next, state) = prox(i, relaxed + u[i]);
            changed += (state != states[i]) as usize;
            states[i] = state;
            u[i] += relaxed - next;
            primal = primal.max((s[i] - next).amax());
            dual = dual.max((next - z[i]).amax());
            scale = scale.max(s[i].amax());
            z[i] = next;
        }
        if primal <= SPLIT_RESIDUAL * scale && dual <= SPLIT_RESIDUAL * scale {
            if it == 0 {
                // The start is the answer (to the iterations' precision): kept as it is.
                return 0;
            }
            break;
        }
        settled = if changed <= changes { settled + 1 } else { 0 };
        if settled >= SPLIT_SETTLED {
            break;
        }
    }
    v.zip_apply(start, |v, a| *v -= a);
    product_into(inverse, v, solved);
    *l += &*solved;
    iterations
}

/// The vectors of [`split_start`] (each sized and overwritten before it is read): the
/// columns' weights, the points' states, the start's and the iterate's displacements of
/// the columns, the system's fixed part and right-hand side, its solution (and in
/// single precision), and the points' copies, multipliers, targets and displacements.
#[derive(Default)]
struct Split {
    weight: Vec<f64>,
    states: Vec<u8>,
    start: DVector<f64>,
    v: DVector<f64>,
    base: DVector<f64>,
    rhs: DVector<f64>,
    solved: DVector<f64>,
    x: DVector<f32>,
    z: Vec<Vector3<f64>>,
    u: Vec<Vector3<f64>>,
    target: Vec<Vector3<f64>>,
    s: Vec<Vector3<f64>>,
}

/// The linear solver ([`Solver::Linear`]): the surface compliance of the small-strain gel
/// and the contact state of its last frame.
#[derive(Clone, Default)]
pub(super) struct LinearSolver {
    /// The compliance, built when the gel is made ([`Equilibrium::prepare`]) or, where
    /// that failed or the solver came later (a fallback), at the first frame that
    /// presses the undeformed gel.
    compliance: Option<Box<Compliance>>,
    /// The indenters of the last frame's sweep end (empty between frames: the vector
    /// kept).
    placed: Vec<StepIndenter>,
}

impl LinearSolver {
    /// [`Equilibrium::solve`] for the indenters `placed` at the sweep's end.
    fn solve_placed(
        &mut self,
        gel: &mut Gel,
        frame: &Frame<'_>,
        placed: &[StepIndenter],
        report: &mut SolveReport,
    ) {
        let sweep = frame.sweep;
        let dx = gel.layout.dx;
        if self.compliance.is_none() {
            if gel.reached_depth(sweep.indenters.iter().copied()) <= 0.0 {
                // Nothing inside the undeformed top face yet: the undeformed gel is the
                // answer, and nothing is built (once built, the contact solve finds this).
                gel.force = Vector3::zeros();
                gel.loads.clear();
                gel.set_surface(|_| Vector3::zeros());
                return;
            }
            match Compliance::new(gel) {
                Ok(c) => {
                    report.factorisations = usize::from(c.computed > 0);
                    report.columns = c.computed;
                    self.compliance = Some(Box::new(c));
                }
                Err(_) => {
                    report.converged = false;
                    report.residual = f64::INFINITY;
                    return;
                }
            }
        }
        let linear = self.compliance.as_mut().expect("built above");
        linear.remap(frame.matched);
        let contact = linear.contact(placed, &sweep.starts, gel.options.tolerance);
        report.iterations = contact.passes;
        report.cg_iterations = contact.iterations;
        report.sweep_steps = 1;
        report.active_particles = contact.points.len();
        report.converged = contact.converged;
        report.unsettled_friction = contact.unsettled;
        let sinking = contact.surface.iter().map(|v| -v.z).fold(0.0, f64::max);
        report.residual = if sinking > 0.0 {
            contact.penetration / sinking
        } else {
            0.0
        };
        let scale = gel.modulus * dx * dx;
        // The gel's force on the indenters: the reverse of theirs on it (+x, +y, downward).
        let on_indenters = |f: &Vector3<f64>| Vector3::new(-f.x, -f.y, f.z) * scale;
        gel.force = contact.forces.iter().map(on_indenters).sum();
        gel.loads.clear();
        gel.loads
            .extend(contact.points.iter().zip(&contact.forces).map(|(x, f)| {
                let x = gel.layout.origin + x * dx;
                ContactLoad {
                    at: [x.x, x.y],
                    z: x.z,
                    force: on_indenters(f),
                }
            }));
        gel.set_surface(|slot| contact.surface[slot] * dx);
        linear.recycle(contact);
    }
}

#[cfg(test)]
impl Gel {
    /// The linear solver's compliance, where the gel runs it and has built it.
    fn compliance(&self) -> Option<&Compliance> {
        self.own_solver::<LinearSolver>()?.compliance.as_deref()
    }
}

impl Equilibrium for LinearSolver {
    fn kind(&self) -> Solver {
        Solver::Linear
    }

    fn prepare(&mut self, gel: &Gel) {
        if self.compliance.is_none() {
            self.compliance = Compliance::new(gel).ok().map(Box::new);
        }
    }

    /// The contact of the small-strain gel with the indenters at the end of the frame's
    /// sweep.
    fn solve(&mut self, gel: &mut Gel, frame: &Frame<'_>, report: &mut SolveReport) {
        // The indenters at the sweep's end, in the vector of the frame before.
        let mut placed = std::mem::take(&mut self.placed);
        let sweep = frame.sweep;
        sweep.place(sweep.steps.max(1) - 1, gel.layout.dx, &mut placed);
        self.solve_placed(gel, frame, &placed, report);
        placed.clear();
        self.placed = placed;
    }

    fn reset(&mut self) {
        if let Some(c) = self.compliance.as_mut() {
            c.reset();
        }
    }

    /// Whether the compliance is built (it is rebuilt from the gel, or read from the gel
    /// cache, where a read state has one) and friction's history.
    fn persist(
        &mut self,
        io: &mut Io<'_>,
        gel: &Gel,
        bounds: &StateBounds,
        _shapes: &[Arc<dyn Sdf>],
    ) -> bool {
        let mut built = self.compliance.is_some();
        built.persist(io);
        if io.loading() && io.fault().is_none() && built != self.compliance.is_some() {
            self.compliance = if built {
                match Compliance::new(gel) {
                    Ok(c) => Some(Box::new(c)),
                    Err(e) => {
                        io.fail(|| format!("the linear solver's compliance: {e}"));
                        return true;
                    }
                }
            } else {
                None
            };
        }
        if let Some(c) = self.compliance.as_mut() {
            state::sorted(io, &mut c.anchors, bounds.points, "the friction anchors");
            state::hash(io, &mut c.lagged, bounds.points, "the lagged forces");
            state::hash(
                io,
                &mut c.lagged_before,
                bounds.points,
                "the lagged forces before",
            );
            state::list(
                io,
                &mut c.last_motion,
                bounds.indenters,
                "the indenters' last motion",
            );
            let columns = 3 * c.levels.len();
            state::list(io, &mut c.last, columns, "the columns' displacement");
            if io.loading() && !(c.last.is_empty() || c.last.len() == columns) {
                let n = c.last.len();
                io.fail(|| format!("the columns' displacement has {n} values, not {columns}"));
                c.last.clear();
            }
            c.persist_bases(io);
        }
        true
    }
}

#[cfg(test)]
#[path = "linear_tests.rs"]
mod tests;
