//! The four parts of one MLS-MPM time step, in internal units (see `mpm/mod.rs`: lengths
//! in cells, `dt = 1`, stresses divided by `lambda + 2 mu`):
//!
//! 1. [`bin_particles`]: counting sort of the particles by the x index of their stencil
//!    base cell (what makes the scatter deterministic and race free); redone only when a
//!    particle changed that cell (G2P reports it), since the sort is then unchanged;
//! 2. [`particle_to_grid`]: clear the grid, scatter mass, APIC momentum and the MLS-MPM
//!    stress force (Hu et al. 2018, "A moving least squares material point method", Eq. 18
//!    and 29); the contact forces of the top particles are added after it
//!    (`super::contact::scatter_contacts`, sequential, in slot order);
//! 3. [`grid_update`]: momentum to velocity, bonded bottom, damping, and the
//!    out-of-balance force that the convergence test reads;
//! 4. [`grid_to_particle`]: velocity and affine `C` (APIC, Jiang et al. 2015), then
//!    `F <- (I + dt C) F`, `x <- x + dt v`, with clamps on `x` and `det F`, the warm-started
//!    rotation extraction, and the [`Stencil`] of the new position.
//!
//! Each particle's stencil (base node, offsets) is computed once per position and shared
//! by P2G, the contact scatter and G2P. The scatter and gather work on whole nodes as
//! eight-lane arrays (see [`Node`]) and, on x86-64 CPUs with AVX2 (detected at run time),
//! run in a copy compiled for it: same operations, same order, same bits.
//!
//! Determinism: the scatter is the only step where several particles write one node. The
//! grid is x-major, and the particles are binned by the x index of their base cell into
//! blocks of [`BLOCK`] cells; a block writes x-layers `[b B, b B + B + 2)`. All even blocks
//! are processed in parallel, then all odd blocks: blocks of one colour write disjoint
//! slices, which `par_chunks_mut` hands out without `unsafe`. Every node therefore sums its
//! contributions in one fixed order (even block, then odd block, each in particle order)
//! whatever the number of threads, and the result is bit for bit the same. Reductions
//! (force, residual) use per-layer or fixed-size-chunk partials summed sequentially.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use rayon::prelude::*;

use super::materials::ConstitutiveModel;
use super::rotation::extract_rotation_lanes;
use super::{J_MAX, J_MIN};

/// Width, in cells along x, of one scatter block. Must be at least 2 (a block writes
/// `BLOCK + 2` layers and blocks of one colour are `2 BLOCK` apart).
pub(crate) const BLOCK: usize = 4;

/// Particles per parallel task in the particle passes (fixed, so that per-chunk reductions
/// do not depend on the thread count).
pub(crate) const CHUNK: usize = 1024;

/// State of one material point (internal units).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Particle {
    /// Position (cells, from the grid origin).
    pub x: Vector3<f32>,
    /// Velocity (cells per step).
    pub v: Vector3<f32>,
    /// APIC affine velocity matrix `C` (per step).
    pub c: Matrix3<f32>,
    /// Deformation gradient.
    pub f: Matrix3<f32>,
    /// Rotation of the polar decomposition of `f` (fixed corotated only).
    pub q: UnitQuaternion<f32>,
    /// Ratio of the kernel-smoothed volume change to the particle's own, `J_bar / J`
    /// (F-bar, against volumetric locking; 1 when disabled).
    pub jr: f32,
}

impl Particle {
    /// An undeformed particle at rest at `x`.
    pub fn at_rest(x: Vector3<f32>) -> Self {
        Self {
            x,
            v: Vector3::zeros(),
            c: Matrix3::zeros(),
            f: Matrix3::identity(),
            q: UnitQuaternion::identity(),
            jr: 1.0,
        }
    }

    /// Whether every component is finite (a sum, summed as a shallow tree: it is on every
    /// particle's path in G2P; a finite overflow to infinity also counts as non-finite).
    #[inline(always)]
    pub(crate) fn is_finite(&self) -> bool {
        let m = self.c + self.f;
        let t = (self.x + self.v) + (m.column(0) + m.column(1) + m.column(2));
        let q = self.q.coords;
        let s = ((t.x + q.x) + (t.y + q.y)) + ((t.z + q.z) + (self.jr + q.w));
        s.is_finite()
    }
}

/// One grid node: what P2G accumulates, and what the grid update leaves for G2P, as eight
/// lanes (so that the scatter and gather run on whole SIMD vectors, and a node never
/// straddles a cache line):
/// * `[MV, MV + 3)`: APIC momentum `sum w (m v + m C (x_i - x_p))`; the velocity after the
///   grid update;
/// * `MJ`: `sum w m J`; the node's smoothed `J` after the grid update;
/// * `[F, F + 3)`: stress force times `dt`: `-sum w V tau M^-1 (x_i - x_p)`;
/// * `M`: mass.
///
/// G2P reads the first four lanes only.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub(crate) struct Node {
    pub a: [f32; 8],
}

impl Node {
    pub const MV: usize = 0;
    pub const MJ: usize = 3;
    pub const F: usize = 4;
    pub const M: usize = 7;
    pub const ZERO: Node = Node { a: [0.0; 8] };

    #[inline(always)]
    fn vec(&self, at: usize) -> Vector3<f32> {
        Vector3::new(self.a[at], self.a[at + 1], self.a[at + 2])
    }

    #[inline(always)]
    fn set_vec(&mut self, at: usize, v: Vector3<f32>) {
        self.a[at] = v.x;
        self.a[at + 1] = v.y;
        self.a[at + 2] = v.z;
    }

    /// Adds `v` to the stress force lanes.
    #[inline(always)]
    pub fn add_f(&mut self, v: Vector3<f32>) {
        self.a[Self::F] += v.x;
        self.a[Self::F + 1] += v.y;
        self.a[Self::F + 2] += v.z;
    }
}

/// Fixed quantities of a step, bundled.
#[derive(Clone, Copy, Debug)]
pub(crate) struct StepCtx {
    /// Nodes per axis.
    pub dims: [usize; 3],
    /// Nodes with `iz <= iz_bottom` are bonded.
    pub iz_bottom: usize,
    /// Particle mass.
    pub pmass: f32,
    /// Particle reference volume.
    pub pvol: f32,
    /// Mass-proportional damping per step, `v <- v / (1 + damping)`.
    pub damping: f32,
    /// Whether to use the smoothed volume ratio (F-bar).
    pub fbar: bool,
    /// Iterations of the rotation extraction per step.
    pub rot_iters: usize,
    /// Particles per lattice row along x (`ny * nz` of the particle lattice): G2P works
    /// on rows.
    pub row_len: usize,
    /// Particles per lattice column (`nz` of the particle lattice).
    pub column_len: usize,
    /// The solve's active region (see [`Region`]).
    pub region: Region,
}

/// The part of the gel a solve moves: the particle lattice box `[ix0, ix1) x [iy0, iy1)`
/// (every z), and the grid nodes that are free to move, `free_x` and `free_y`
/// (`[lo, hi)` node indices). A node with mass outside them has an inactive particle in
/// its support and is held fixed, like a bonded node: the inactive gel is a rigid wall
/// around the active part.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Region {
    pub lattice: [usize; 4],
    pub free_x: [usize; 2],
    pub free_y: [usize; 2],
}

impl Region {
    /// The whole gel: every particle, every node free.
    pub fn whole(lattice: [usize; 3], dims: [usize; 3]) -> Self {
        Self {
            lattice: [0, lattice[0], 0, lattice[1]],
            free_x: [0, dims[0]],
            free_y: [0, dims[1]],
        }
    }

    /// Whether top-surface slot `(ix, iy)` is active.
    #[inline]
    pub fn holds(&self, ix: usize, iy: usize) -> bool {
        (self.lattice[0]..self.lattice[1]).contains(&ix)
            && (self.lattice[2]..self.lattice[3]).contains(&iy)
    }

    /// Number of active particles for columns of `column_len`.
    pub fn particles(&self, column_len: usize) -> usize {
        (self.lattice[1] - self.lattice[0]) * (self.lattice[3] - self.lattice[2]) * column_len
    }
}

/// Quadratic B-spline weights (Steffen et al. 2008) of a particle at coordinate `x` (cells):
/// base node `floor(x - 1/2)`, offset `fx = x - base` in `[0.5, 1.5)`, and
/// `w = [(1.5 - fx)^2 / 2, 3/4 - (fx - 1)^2, (fx - 0.5)^2 / 2]`.
/// Particles are clamped to `x >= 1`, so truncation is the floor (the default x86-64
/// target has no SSE4.1 `roundss`, and `floorf` is a library call).
#[inline(always)]
pub(crate) fn weights(x: f32) -> (usize, f32, [f32; 3]) {
    // `as i32` is one cvttss2si (NaN and overflow saturate); `x` is clamped to the grid.
    let bi = (x - 0.5).max(0.0) as i32;
    let base = bi as f32;
    let fx = x - base;
    let w = [
        0.5 * (1.5 - fx) * (1.5 - fx),
        0.75 - (fx - 1.0) * (fx - 1.0),
        0.5 * (fx - 0.5) * (fx - 0.5),
    ];
    (bi.max(0) as usize, fx, w)
}

/// Stencil of a particle: base node and offset `x - base` per axis (see [`weights`]).
/// Computed once per position (by G2P for the next step, or by [`compute_stencils`] at the
/// start of a solve) and shared by P2G, the contact scatter and G2P; the weights follow
/// from the offsets in a few flops ([`Stencil::weights`], the same values as [`weights`]).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Stencil {
    pub base: [u32; 3],
    pub fx: [f32; 3],
}

impl Stencil {
    #[inline(always)]
    pub fn of(x: &Vector3<f32>) -> Self {
        let (bx, fx, _) = weights(x.x);
        let (by, fy, _) = weights(x.y);
        let (bz, fz, _) = weights(x.z);
        Self {
            base: [bx as u32, by as u32, bz as u32],
            fx: [fx, fy, fz],
        }
    }

    /// Base index and weights along axis `d`, as [`weights`] gives them.
    #[inline(always)]
    pub fn axis(&self, d: usize) -> (usize, f32, [f32; 3]) {
        let fx = self.fx[d];
        let w = [
            0.5 * (1.5 - fx) * (1.5 - fx),
            0.75 - (fx - 1.0) * (fx - 1.0),
            0.5 * (fx - 0.5) * (fx - 0.5),
        ];
        (self.base[d] as usize, fx, w)
    }
}

/// Recomputes every particle's stencil from its position.
pub(crate) fn compute_stencils(particles: &[Particle], stencils: &mut Vec<Stencil>) {
    stencils.resize(particles.len(), Stencil::default());
    stencils
        .par_chunks_mut(CHUNK)
        .zip(particles.par_chunks(CHUNK))
        .for_each(|(s, p)| {
            for (s, p) in s.iter_mut().zip(p) {
                *s = Stencil::of(&p.x);
            }
        });
}

/// Stable counting sort of the active particles' indices ([`StepCtx::region`]) by base x
/// cell: afterwards the particles whose base is `bx` are
/// `order[offsets[bx]..offsets[bx + 1]]`, in increasing index.
pub(crate) fn bin_particles(
    ctx: &StepCtx,
    stencils: &[Stencil],
    order: &mut Vec<u32>,
    offsets: &mut Vec<u32>,
    cursor: &mut Vec<u32>,
) {
    let nx = ctx.dims[0];
    let [ix0, ix1, iy0, iy1] = ctx.region.lattice;
    let active = || {
        (ix0..ix1).flat_map(move |ix| {
            let start = ix * ctx.row_len;
            start + iy0 * ctx.column_len..start + iy1 * ctx.column_len
        })
    };
    offsets.clear();
    offsets.resize(nx + 1, 0);
    for i in active() {
        offsets[(stencils[i].base[0] as usize).min(nx - 1) + 1] += 1;
    }
    for i in 0..nx {
        offsets[i + 1] += offsets[i];
    }
    cursor.clear();
    cursor.extend_from_slice(&offsets[..nx]);
    order.resize(offsets[nx] as usize, 0);
    for i in active() {
        let b = (stencils[i].base[0] as usize).min(nx - 1);
        order[cursor[b] as usize] = i as u32;
        cursor[b] += 1;
    }
}

/// Everything P2G reads, bundled.
pub(crate) struct P2gInput<'a> {
    pub particles: &'a [Particle],
    pub stencils: &'a [Stencil],
    pub order: &'a [u32],
    pub offsets: &'a [u32],
}

/// Clears the grid and scatters every particle to it (see the module docs for the
/// colouring that makes this deterministic). Per particle, with `dt = 1` and
/// `M_p^-1 = 4 / dx^2 = 4` (Hu et al. 2018, Eq. 29):
/// `m_i += w m`, `(m v)_i += w m (v + C (x_i - x_p))`, `f_i -= w 4 V tau (x_i - x_p)`.
pub(crate) fn particle_to_grid<M: ConstitutiveModel>(
    ctx: &StepCtx,
    model: &M,
    input: &P2gInput<'_>,
    grid: &mut [Node],
) {
    let [_, ny, nz] = ctx.dims;
    let nyz = ny * nz;
    let nbx = input.offsets.len() - 1;
    let avx2 = has_avx2();
    grid.par_chunks_mut(nyz * 8)
        .for_each(|c| c.fill(Node::ZERO));
    for parity in 0..2 {
        let start = parity * BLOCK;
        if start * nyz >= grid.len() {
            continue;
        }
        let g = &mut grid[start * nyz..];
        g.par_chunks_mut(2 * BLOCK * nyz)
            .enumerate()
            .for_each(|(k, gc)| {
                let block = 2 * k + parity;
                let layer0 = block * BLOCK;
                let bx0 = layer0.min(nbx);
                let bx1 = (layer0 + BLOCK).min(nbx);
                let range = input.offsets[bx0] as usize..input.offsets[bx1] as usize;
                let order = &input.order[range];
                #[cfg(target_arch = "x86_64")]
                if avx2 {
                    // SAFETY: the CPU supports AVX2 (detected at run time above).
                    unsafe { scatter_block_avx2(ctx, model, input, order, layer0, gc) };
                    return;
                }
                scatter_block(ctx, model, input, order, layer0, gc);
            });
    }
}

/// Whether the running CPU has AVX2: the hot kernels then run in a copy compiled for it
/// (wider vectors, no FMA contraction, so the same IEEE operations in the same order and
/// bit-identical results).
#[inline]
pub(super) fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[inline(always)]
fn scatter_block<M: ConstitutiveModel>(
    ctx: &StepCtx,
    model: &M,
    input: &P2gInput<'_>,
    order: &[u32],
    layer0: usize,
    gc: &mut [Node],
) {
    for &pi in order {
        let pi = pi as usize;
        scatter_particle(
            ctx,
            model,
            &input.particles[pi],
            &input.stencils[pi],
            layer0,
            gc,
        );
    }
}

/// [`scatter_block`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn scatter_block_avx2<M: ConstitutiveModel>(
    ctx: &StepCtx,
    model: &M,
    input: &P2gInput<'_>,
    order: &[u32],
    layer0: usize,
    gc: &mut [Node],
) {
    scatter_block(ctx, model, input, order, layer0, gc);
}

#[inline(always)]
fn scatter_particle<M: ConstitutiveModel>(
    ctx: &StepCtx,
    model: &M,
    p: &Particle,
    st: &Stencil,
    layer0: usize,
    g: &mut [Node],
) {
    let [_, ny, nz] = ctx.dims;
    let (bx, fx, wx) = st.axis(0);
    let (by, fy, wy) = st.axis(1);
    let (bz, fz, wz) = st.axis(2);
    let j = p.f.determinant();
    // Volume smoothing: the volumetric (pressure) term sees the kernel-smoothed J.
    let jb = if ctx.fbar { j * p.jr } else { j };
    let r = if M::USES_ROTATION {
        *p.q.to_rotation_matrix().matrix()
    } else {
        Matrix3::identity()
    };
    let tau = model.kirchhoff(&p.f, jb, &r);
    let stress = tau * (-4.0 * ctx.pvol);
    let affine = p.c * ctx.pmass;
    let mv = p.v * ctx.pmass;
    let m = ctx.pmass;
    // The node's contribution is `w (p0 + sum_d pc[d] (x_i - x_p)_d)`, lanes as in `Node`.
    let p0 = [mv.x, mv.y, mv.z, m * j, 0.0, 0.0, 0.0, m];
    let pc: [[f32; 8]; 3] = std::array::from_fn(|d| {
        let (a, s) = (affine.column(d), stress.column(d));
        [a.x, a.y, a.z, 0.0, s.x, s.y, s.z, 0.0]
    });
    // z terms per stencil node, the same for every row.
    let qz: [[f32; 8]; 3] = std::array::from_fn(|k| {
        let dzk = k as f32 - fz;
        std::array::from_fn(|l| pc[2][l] * dzk)
    });
    let first = (bx - layer0) * ny * nz + by * nz + bz;
    scatter_stencil(g, first, ny * nz, nz, [fx, fy], [wx, wy, wz], &p0, &pc, &qz);
}

/// Adds `w (p0 + pc[0] dx + pc[1] dy + qz[k])` to the 27 stencil nodes (first node
/// `first`, x and y strides `sx`, `sy`), in a fixed order, each lane as
/// `n += w * ((p0 + pc[0] dx + pc[1] dy) + qz[k])` (the compiler vectorises this one
/// well, eight lanes at a time in the AVX2 copy).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn scatter_stencil(
    g: &mut [Node],
    first: usize,
    sx: usize,
    sy: usize,
    f: [f32; 2],
    w: [[f32; 3]; 3],
    p0: &[f32; 8],
    pc: &[[f32; 8]; 3],
    qz: &[[f32; 8]; 3],
) {
    let [fx, fy] = f;
    let [wx, wy, wz] = w;
    for (i, &wxi) in wx.iter().enumerate() {
        let dxi = i as f32 - fx;
        let rx: [f32; 8] = std::array::from_fn(|l| p0[l] + pc[0][l] * dxi);
        for (jy, &wyj) in wy.iter().enumerate() {
            let dyj = jy as f32 - fy;
            let wxy = wxi * wyj;
            let row = first + i * sx + jy * sy;
            let r: [f32; 8] = std::array::from_fn(|l| rx[l] + pc[1][l] * dyj);
            let line = &mut g[row..row + 3];
            for ((n, &wzk), q) in line.iter_mut().zip(wz.iter()).zip(qz.iter()) {
                let w = wxy * wzk;
                for l in 0..8 {
                    n.a[l] += w * (r[l] + q[l]);
                }
            }
        }
    }
}

/// Per x-layer results of the grid update.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct LayerStats {
    /// Largest out-of-balance force on a free node.
    pub residual: f32,
    /// Largest reaction on a bonded node.
    pub reaction: f32,
}

/// Grid update, per node with mass (internal units, `dt = 1`):
/// `v* = (m v)_i / m_i + f_i / m_i` (the stress force and the contact forces of
/// `super::contact`); bonded nodes (`iz <= iz_bottom`) and the outermost layer get
/// `v = 0`; then the mass-proportional damping `v <- v / (1 + c)`.
///
/// The out-of-balance force is `|m (v* - v_apic)| + c m |v*|`: the stress plus contact
/// force, plus the damping force; both vanish at equilibrium.
pub(crate) fn grid_update(ctx: &StepCtx, grid: &mut [Node], stats: &mut Vec<LayerStats>) {
    let [nx, ny, nz] = ctx.dims;
    let nyz = ny * nz;
    let c = ctx.damping;
    let [fx0, fx1] = ctx.region.free_x;
    let [fy0, fy1] = ctx.region.free_y;
    grid.par_chunks_mut(nyz)
        .enumerate()
        .map(|(ix, g)| {
            let mut st = LayerStats::default();
            let wall_x = ix == 0 || ix + 1 == nx || ix < fx0 || ix >= fx1;
            for (iy, gc) in g.chunks_exact_mut(nz).enumerate() {
                let wall_y = wall_x || iy == 0 || iy + 1 == ny || iy < fy0 || iy >= fy1;
                for (iz, n) in gc.iter_mut().enumerate() {
                    let m = n.a[Node::M];
                    if m <= 0.0 {
                        n.set_vec(Node::MV, Vector3::zeros());
                        n.a[Node::MJ] = 1.0;
                        continue;
                    }
                    let inv = 1.0 / m;
                    let v_apic = n.vec(Node::MV) * inv;
                    let v = v_apic + n.vec(Node::F) * inv;
                    n.a[Node::MJ] *= inv;
                    if iz <= ctx.iz_bottom || wall_y || iz + 1 == nz {
                        st.reaction = st.reaction.max(m * v.norm());
                        n.set_vec(Node::MV, Vector3::zeros());
                        continue;
                    }
                    let r = ((v - v_apic).norm() + c * v.norm()) * m;
                    st.residual = st.residual.max(r);
                    n.set_vec(Node::MV, v / (1.0 + c));
                }
            }
            st
        })
        .collect_into_vec(stats);
}

/// Smallest and largest singular value that [`guard_det`] keeps.
const SIGMA_RANGE: (f32, f32) = (0.05, 20.0);

/// Relative margin inside `[J_MIN, J_MAX]` that [`guard_det`] aims for, so that the
/// rounding of `U S V^T` and of its determinant (about 1e-6 relative) stays in bounds.
const GUARD_MARGIN: f32 = 1.0 + 1e-4;

/// Repairs a particle whose `det F` left `[J_MIN, J_MAX]`, inverted (`det F <= 0`) included,
/// through the SVD `F = U S V^T` (Irving et al. 2004, "Invertible finite elements", Sec. 5):
/// with `U`, `V` made proper rotations the smallest singular value takes the sign of
/// `det F`; every singular value is then clamped to [`SIGMA_RANGE`] (an inverted or
/// collapsed direction becomes the smallest allowed stretch) and all are scaled by
/// `(J_MIN / prod S)^(1/3)` (times [`GUARD_MARGIN`]), so that `det F` lies just inside
/// `[J_MIN, J_MAX]`. A uniform scaling of
/// `F` alone cannot change the sign of `det F`, and for a nearly singular or hugely sheared
/// `F` it leaves a `det F` dominated by rounding. The polar rotation `U V^T`
/// replaces `q`.
pub(crate) fn guard_det(f: &mut Matrix3<f32>, q: &mut UnitQuaternion<f32>) {
    let svd = f.svd(true, true);
    let (Some(mut u), Some(mut v_t)) = (svd.u, svd.v_t) else {
        return;
    };
    let mut s = svd.singular_values;
    // Proper rotations: move each reflection into the smallest singular value.
    let k = s.imin();
    if u.determinant() < 0.0 {
        u.column_mut(k).neg_mut();
        s[k] = -s[k];
    }
    if v_t.determinant() < 0.0 {
        v_t.row_mut(k).neg_mut();
        s[k] = -s[k];
    }
    let s = s.map(|x| x.clamp(SIGMA_RANGE.0, SIGMA_RANGE.1));
    let prod = s.x * s.y * s.z;
    let target = prod.clamp(J_MIN as f32 * GUARD_MARGIN, J_MAX as f32 / GUARD_MARGIN);
    let s = s * (target / prod).cbrt();
    *f = u * Matrix3::from_diagonal(&s) * v_t;
    let r = u * v_t;
    if r.iter().all(|x| x.is_finite()) {
        *q = UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(r));
    }
}

/// Per-chunk results of G2P.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ChunkStats {
    pub det_min: f32,
    pub det_max: f32,
    pub nonfinite: bool,
    /// Whether a particle changed its base x cell (the binning must be redone).
    pub moved: bool,
}

impl ChunkStats {
    /// Nothing seen (an inactive row).
    pub const EMPTY: ChunkStats = ChunkStats {
        det_min: f32::INFINITY,
        det_max: f32::NEG_INFINITY,
        nonfinite: false,
        moved: false,
    };
}

/// Grid to particle: `v_p = sum w v_i`, `C_p = 4 sum w v_i (x_i - x_p)^T` (APIC with
/// `D^-1 = 4/dx^2`), `F <- (I + C) F`, `x <- x + v`; then `x` is clamped to the grid
/// interior (`[1, n - 2]` cells, so the stencil never leaves the grid) and `det F` to
/// `[J_MIN, J_MAX]` by [`guard_det`] (inverted included). The smoothed volume ratio `J_bar / J` of
/// the F-bar scheme is gathered from the nodes' `J` here too.
pub(crate) fn grid_to_particle(
    ctx: &StepCtx,
    grid: &[Node],
    particles: &mut [Particle],
    stencils: &mut [Stencil],
    stats: &mut Vec<ChunkStats>,
) {
    let [nx, ny, nz] = ctx.dims;
    let hi = Vector3::new(nx as f32 - 2.0, ny as f32 - 2.0, nz as f32 - 2.0);
    let avx2 = has_avx2();
    let [ix0, ix1, iy0, iy1] = ctx.region.lattice;
    let (a, b) = (iy0 * ctx.column_len, iy1 * ctx.column_len);
    particles
        .par_chunks_mut(ctx.row_len)
        .zip(stencils.par_chunks_mut(ctx.row_len))
        .enumerate()
        .map(|(ix, (row, sten))| {
            if !(ix0..ix1).contains(&ix) {
                return ChunkStats::EMPTY;
            }
            let (chunk, sten) = (&mut row[a..b], &mut sten[a..b]);
            #[cfg(target_arch = "x86_64")]
            if avx2 {
                // SAFETY: the CPU supports AVX2 (detected at run time above).
                return unsafe { gather_chunk_avx2(ctx, grid, chunk, sten, &hi) };
            }
            gather_chunk(ctx, grid, chunk, sten, &hi)
        })
        .collect_into_vec(stats);
}

/// Sums over the 27 stencil nodes (first node `base`, x and y strides `sx`, `sy`) of the
/// first four lanes of each node (velocity, smoothed J): `acc[0] = sum w n`,
/// `acc[1 + d] = sum w (x_i - x_p)_d n`. Summed along z first, then y, then x, each row in a
/// fixed order, so every implementation gives the same bits.
#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn gather_stencil(
    grid: &[Node],
    base: usize,
    sx: usize,
    sy: usize,
    f: [f32; 3],
    w: [[f32; 3]; 3],
) -> [[f32; 4]; 4] {
    let [fx, fy, fz] = f;
    let [wx, wy, wz] = w;
    let mut acc = [[0.0f32; 4]; 4];
    let wzd: [f32; 3] = std::array::from_fn(|k| wz[k] * (k as f32 - fz));
    for (i, &wxi) in wx.iter().enumerate() {
        let dxi = i as f32 - fx;
        for (jy, &wyj) in wy.iter().enumerate() {
            let dyj = jy as f32 - fy;
            let wxy = wxi * wyj;
            let row = base + i * sx + jy * sy;
            let line = &grid[row..row + 3];
            let mut s0 = [0.0f32; 4];
            let mut s1 = [0.0f32; 4];
            for ((n, &wk), &wdk) in line.iter().zip(wz.iter()).zip(wzd.iter()) {
                for l in 0..4 {
                    s0[l] += wk * n.a[l];
                    s1[l] += wdk * n.a[l];
                }
            }
            let (wx0, wx1) = (wxy * dxi, wxy * dyj);
            for l in 0..4 {
                acc[0][l] += wxy * s0[l];
                acc[1][l] += wx0 * s0[l];
                acc[2][l] += wx1 * s0[l];
                acc[3][l] += wxy * s1[l];
            }
        }
    }
    acc
}

/// See the portable version; the same operations in the same order on SSE vectors (the
/// compiler's own vectorisation of it spilled most of the accumulators).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn gather_stencil(
    grid: &[Node],
    base: usize,
    sx: usize,
    sy: usize,
    f: [f32; 3],
    w: [[f32; 3]; 3],
) -> [[f32; 4]; 4] {
    use std::arch::x86_64::*;
    let [fx, fy, fz] = f;
    let [wx, wy, wz] = w;
    let wzd: [f32; 3] = std::array::from_fn(|k| wz[k] * (k as f32 - fz));
    let mut out = [[0.0f32; 4]; 4];
    // SAFETY: SSE is part of the x86-64 baseline, so the intrinsics are available; every
    // load reads the first four lanes of a `Node` taken from a bounds-checked slice (32-byte
    // aligned, so `_mm_load_ps` is aligned), every store writes four f32 of `out`.
    unsafe {
        let wk = [_mm_set1_ps(wz[0]), _mm_set1_ps(wz[1]), _mm_set1_ps(wz[2])];
        let wdk = [
            _mm_set1_ps(wzd[0]),
            _mm_set1_ps(wzd[1]),
            _mm_set1_ps(wzd[2]),
        ];
        let zero = _mm_setzero_ps();
        let mut acc = [zero; 4];
        for (i, &wxi) in wx.iter().enumerate() {
            let dxi = i as f32 - fx;
            for (jy, &wyj) in wy.iter().enumerate() {
                let dyj = jy as f32 - fy;
                let wxy = wxi * wyj;
                let row = base + i * sx + jy * sy;
                let line = &grid[row..row + 3];
                let mut s0 = zero;
                let mut s1 = zero;
                for (n, (&a, &b)) in line.iter().zip(wk.iter().zip(wdk.iter())) {
                    let n = _mm_load_ps(n.a.as_ptr());
                    s0 = _mm_add_ps(s0, _mm_mul_ps(a, n));
                    s1 = _mm_add_ps(s1, _mm_mul_ps(b, n));
                }
                let (wx0, wx1) = (wxy * dxi, wxy * dyj);
                let (vxy, v0, v1) = (_mm_set1_ps(wxy), _mm_set1_ps(wx0), _mm_set1_ps(wx1));
                acc[0] = _mm_add_ps(acc[0], _mm_mul_ps(vxy, s0));
                acc[1] = _mm_add_ps(acc[1], _mm_mul_ps(v0, s0));
                acc[2] = _mm_add_ps(acc[2], _mm_mul_ps(v1, s0));
                acc[3] = _mm_add_ps(acc[3], _mm_mul_ps(vxy, s1));
            }
        }
        for (o, a) in out.iter_mut().zip(acc) {
            _mm_storeu_ps(o.as_mut_ptr(), a);
        }
    }
    out
}

/// [`gather_chunk`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn gather_chunk_avx2(
    ctx: &StepCtx,
    grid: &[Node],
    chunk: &mut [Particle],
    sten: &mut [Stencil],
    hi: &Vector3<f32>,
) -> ChunkStats {
    gather_chunk(ctx, grid, chunk, sten, hi)
}

/// G2P of one chunk of particles (see [`grid_to_particle`]).
#[inline(always)]
fn gather_chunk(
    ctx: &StepCtx,
    grid: &[Node],
    chunk: &mut [Particle],
    sten: &mut [Stencil],
    hi: &Vector3<f32>,
) -> ChunkStats {
    let [_, ny, nz] = ctx.dims;
    let rot_iters = ctx.rot_iters;
    let mut st = ChunkStats::EMPTY;
    for (p, sp) in chunk.iter_mut().zip(sten.iter_mut()) {
        let (bx, fx, wx) = sp.axis(0);
        let (by, fy, wy) = sp.axis(1);
        let (bz, fz, wz) = sp.axis(2);
        // acc[0] = sum w n, acc[1 + d] = sum w (x_i - x_p)_d n over the first four
        // lanes of each node (velocity, smoothed J).
        let base = (bx * ny + by) * nz + bz;
        let acc = gather_stencil(grid, base, ny * nz, nz, [fx, fy, fz], [wx, wy, wz]);
        let v = Vector3::new(acc[0][0], acc[0][1], acc[0][2]);
        let jbar = acc[0][3];
        let b = Matrix3::from_fn(|r, c| acc[1 + c][r]);
        let j_old = p.f.determinant();
        p.jr = if ctx.fbar {
            (jbar / j_old).clamp(0.25, 4.0)
        } else {
            1.0
        };
        p.v = v;
        p.c = b * 4.0;
        p.x = (p.x + v).sup(&Vector3::repeat(1.0)).inf(hi);
        let ns = Stencil::of(&p.x);
        st.moved |= ns.base[0] != sp.base[0];
        *sp = ns;
        p.f = (Matrix3::identity() + p.c) * p.f;
        let mut j = p.f.determinant();
        if !(J_MIN as f32..=J_MAX as f32).contains(&j) && p.f.iter().all(|x| x.is_finite()) {
            guard_det(&mut p.f, &mut p.q);
            j = p.f.determinant();
        }
        if !p.is_finite() {
            st.nonfinite = true;
            continue;
        }
        st.det_min = st.det_min.min(j);
        st.det_max = st.det_max.max(j);
    }
    if rot_iters > 0 {
        extract_rotations(chunk, rot_iters);
    }
    st
}

/// Particles per group of the vectorised rotation extraction.
const ROT_LANES: usize = 8;

/// The rotation of each particle's `F` (warm-started from its own, `iterations` steps),
/// eight particles at a time (a finite `F` gives a finite rotation, a non-finite one
/// leaves it as it was).
pub(crate) fn extract_rotations(chunk: &mut [Particle], rot_iters: usize) {
    for group in chunk.chunks_mut(ROT_LANES) {
        let mut a = [[0.0f32; ROT_LANES]; 9];
        let mut q = [[0.0f32; ROT_LANES]; 4];
        q[3] = [1.0; ROT_LANES];
        for (l, p) in group.iter().enumerate() {
            for (k, v) in p.f.as_slice().iter().enumerate() {
                a[k][l] = *v;
            }
            for (k, v) in p.q.as_ref().coords.iter().enumerate() {
                q[k][l] = *v;
            }
        }
        extract_rotation_lanes(&a, &mut q, rot_iters);
        for (l, p) in group.iter_mut().enumerate() {
            p.q = UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(
                q[3][l], q[0][l], q[1][l], q[2][l],
            ));
        }
    }
}
