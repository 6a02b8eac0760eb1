//! The four parts of one MLS-MPM time step, in internal units (see `mpm/mod.rs`: lengths
//! in cells, `dt = 1`, stresses divided by `lambda + 2 mu`):
//!
//! 1. [`bin_particles`]: counting sort of the particles by the x index of their stencil
//!    base cell (what makes the scatter deterministic and race free);
//! 2. [`particle_to_grid`]: clear the grid, scatter mass, APIC momentum and the MLS-MPM
//!    stress force (Hu et al. 2018, "A moving least squares material point method", Eq. 18
//!    and 29); the contact forces of the top particles are added after it
//!    (`super::contact::scatter_contacts`, sequential, in slot order);
//! 3. [`grid_update`]: momentum to velocity, bonded bottom, damping, and the
//!    out-of-balance force that the convergence test reads;
//! 4. [`grid_to_particle`]: velocity and affine `C` (APIC, Jiang et al. 2015), then
//!    `F <- (I + dt C) F`, `x <- x + dt v`, with clamps on `x` and `det F`.
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

use super::material::{extract_rotation, ConstitutiveModel};
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

    fn is_finite(&self) -> bool {
        let s = self.x.sum() + self.v.sum() + self.c.sum() + self.f.sum() + self.jr;
        s.is_finite() && self.q.coords.sum().is_finite()
    }
}

/// One grid node: what P2G accumulates, and what the grid update leaves for G2P.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Node {
    /// Mass.
    pub m: f32,
    /// APIC momentum `sum w (m v + m C (x_i - x_p))`; the velocity after the grid update.
    pub mv: Vector3<f32>,
    /// Stress force times `dt`: `-sum w V tau M^-1 (x_i - x_p)`.
    pub f: Vector3<f32>,
    /// `sum w m J`; the node's smoothed `J` after the grid update.
    pub mj: f32,
}

impl Node {
    pub const ZERO: Node = Node {
        m: 0.0,
        mv: Vector3::new(0.0, 0.0, 0.0),
        f: Vector3::new(0.0, 0.0, 0.0),
        mj: 0.0,
    };
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
}

/// Quadratic B-spline weights (Steffen et al. 2008) of a particle at coordinate `x` (cells):
/// base node `floor(x - 1/2)`, offset `fx = x - base` in `[0.5, 1.5)`, and
/// `w = [(1.5 - fx)^2 / 2, 3/4 - (fx - 1)^2, (fx - 0.5)^2 / 2]`.
/// Particles are clamped to `x >= 1`, so truncation is the floor (the default x86-64
/// target has no SSE4.1 `roundss`, and `floorf` is a library call).
#[inline(always)]
pub(crate) fn weights(x: f32) -> (usize, f32, [f32; 3]) {
    let base = (x - 0.5).max(0.0) as usize as f32;
    let fx = x - base;
    let w = [
        0.5 * (1.5 - fx) * (1.5 - fx),
        0.75 - (fx - 1.0) * (fx - 1.0),
        0.5 * (fx - 0.5) * (fx - 0.5),
    ];
    (base.max(0.0) as usize, fx, w)
}

/// Stencil base x index of a particle.
#[inline(always)]
fn base_x(x: f32) -> usize {
    (x - 0.5).max(0.0) as usize
}

/// Stable counting sort of particle indices by base x cell: afterwards the particles whose
/// base is `bx` are `order[offsets[bx]..offsets[bx + 1]]`, in increasing index.
pub(crate) fn bin_particles(
    particles: &[Particle],
    nx: usize,
    order: &mut Vec<u32>,
    offsets: &mut Vec<u32>,
    cursor: &mut Vec<u32>,
) {
    offsets.clear();
    offsets.resize(nx + 1, 0);
    for p in particles {
        offsets[base_x(p.x.x).min(nx - 1) + 1] += 1;
    }
    for i in 0..nx {
        offsets[i + 1] += offsets[i];
    }
    cursor.clear();
    cursor.extend_from_slice(&offsets[..nx]);
    order.resize(particles.len(), 0);
    for (i, p) in particles.iter().enumerate() {
        let b = base_x(p.x.x).min(nx - 1);
        order[cursor[b] as usize] = i as u32;
        cursor[b] += 1;
    }
}

/// Everything P2G reads, bundled.
pub(crate) struct P2gInput<'a> {
    pub particles: &'a [Particle],
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
                for &pi in &input.order[range] {
                    scatter_particle(ctx, model, &input.particles[pi as usize], layer0, gc);
                }
            });
    }
}

#[inline(always)]
fn scatter_particle<M: ConstitutiveModel>(
    ctx: &StepCtx,
    model: &M,
    p: &Particle,
    layer0: usize,
    g: &mut [Node],
) {
    let [_, ny, nz] = ctx.dims;
    let (bx, fx, wx) = weights(p.x.x);
    let (by, fy, wy) = weights(p.x.y);
    let (bz, fz, wz) = weights(p.x.z);
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
    let mj = m * j;
    for (i, &wxi) in wx.iter().enumerate() {
        let dxi = i as f32 - fx;
        let lx = bx + i - layer0;
        for (jy, &wyj) in wy.iter().enumerate() {
            let dyj = jy as f32 - fy;
            let wxy = wxi * wyj;
            let row = (lx * ny + by + jy) * nz + bz;
            let a_xy = affine.column(0) * dxi + affine.column(1) * dyj;
            let s_xy = stress.column(0) * dxi + stress.column(1) * dyj;
            for (k, &wzk) in wz.iter().enumerate() {
                let dzk = k as f32 - fz;
                let w = wxy * wzk;
                let n = &mut g[row + k];
                n.m += w * m;
                n.mv += (mv + a_xy + affine.column(2) * dzk) * w;
                n.f += (s_xy + stress.column(2) * dzk) * w;
                n.mj += w * mj;
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
    grid.par_chunks_mut(nyz)
        .enumerate()
        .map(|(ix, g)| {
            let mut st = LayerStats::default();
            let wall_x = ix == 0 || ix + 1 == nx;
            for (iy, gc) in g.chunks_exact_mut(nz).enumerate() {
                let wall_y = wall_x || iy == 0 || iy + 1 == ny;
                for (iz, n) in gc.iter_mut().enumerate() {
                    if n.m <= 0.0 {
                        n.mv = Vector3::zeros();
                        n.mj = 1.0;
                        continue;
                    }
                    let inv = 1.0 / n.m;
                    let v_apic = n.mv * inv;
                    let v = v_apic + n.f * inv;
                    n.mj *= inv;
                    if iz <= ctx.iz_bottom || wall_y || iz + 1 == nz {
                        st.reaction = st.reaction.max(n.m * v.norm());
                        n.mv = Vector3::zeros();
                        continue;
                    }
                    let r = ((v - v_apic).norm() + c * v.norm()) * n.m;
                    st.residual = st.residual.max(r);
                    n.mv = v / (1.0 + c);
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
    stats: &mut Vec<ChunkStats>,
) {
    let [nx, ny, nz] = ctx.dims;
    let hi = Vector3::new(nx as f32 - 2.0, ny as f32 - 2.0, nz as f32 - 2.0);
    let rot_iters = ctx.rot_iters;
    particles
        .par_chunks_mut(CHUNK)
        .map(|chunk| {
            let mut st = ChunkStats {
                det_min: f32::INFINITY,
                det_max: f32::NEG_INFINITY,
                nonfinite: false,
            };
            for p in chunk.iter_mut() {
                let (bx, fx, wx) = weights(p.x.x);
                let (by, fy, wy) = weights(p.x.y);
                let (bz, fz, wz) = weights(p.x.z);
                let mut v = Vector3::zeros();
                let mut b = Matrix3::zeros();
                let mut jbar = 0.0f32;
                for (i, &wxi) in wx.iter().enumerate() {
                    let dxi = i as f32 - fx;
                    for (jy, &wyj) in wy.iter().enumerate() {
                        let dyj = jy as f32 - fy;
                        let wxy = wxi * wyj;
                        let row = ((bx + i) * ny + by + jy) * nz + bz;
                        for (k, &wzk) in wz.iter().enumerate() {
                            let n = &grid[row + k];
                            let w = wxy * wzk;
                            let wv = n.mv * w;
                            v += wv;
                            b += wv * Vector3::new(dxi, dyj, k as f32 - fz).transpose();
                            jbar += w * n.mj;
                        }
                    }
                }
                let j_old = p.f.determinant();
                p.jr = if ctx.fbar {
                    (jbar / j_old).clamp(0.25, 4.0)
                } else {
                    1.0
                };
                p.v = v;
                p.c = b * 4.0;
                p.x = (p.x + v).sup(&Vector3::repeat(1.0)).inf(&hi);
                p.f = (Matrix3::identity() + p.c) * p.f;
                let mut j = p.f.determinant();
                if !(J_MIN as f32..=J_MAX as f32).contains(&j) && p.f.iter().all(|x| x.is_finite())
                {
                    guard_det(&mut p.f, &mut p.q);
                }
                if rot_iters > 0 {
                    extract_rotation(&p.f, &mut p.q, rot_iters);
                }
                if !p.is_finite() {
                    st.nonfinite = true;
                    continue;
                }
                j = p.f.determinant();
                st.det_min = st.det_min.min(j);
                st.det_max = st.det_max.max(j);
            }
            st
        })
        .collect_into_vec(stats);
}
