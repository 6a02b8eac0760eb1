//! A two-grid preconditioner for Newton's linear systems on grids too fine to factor.
//!
//! The coarse level is the grid of twice the spacing, placed so that its quadratic
//! B-splines are exact combinations of the fine ones: coarse node `J` sits at fine
//! coordinate `2 J - 1/2`, its knots on fine knots, and
//! `N_J = (N_{2J-2} + 3 N_{2J-1} + 3 N_{2J} + N_{2J+1}) / 4` along each axis (the
//! two-scale relation of the quadratic B-spline). The prolongation `P` is that relation:
//! a coarse displacement field is the same field on the fine grid, except at fine nodes
//! that are fixed (the bonded base) or held (outside the solved region), which get
//! nothing. The coarse operator is the Galerkin product `P^T H P`, assembled point by
//! point: each fine quadrature point's shape-function gradients, mapped through `P`, reach
//! 3 x 3 x 3 coarse nodes, so the coarse matrix has the fine one's pattern and costs an
//! assembly of the fine one's size; contact stiffnesses are mapped the same way. The
//! coarse correction is then the Hessian-orthogonal projection onto the coarse fields.
//! The coarse matrix is factored (faer; an eighth of the fine unknowns) up to
//! `MULTIGRID_UNKNOWNS` unknowns, the fine grid's own rule; above, it is smoothed in turn,
//! and the level of twice its spacing below it, its Galerkin product `P^T A P` taken from
//! its assembled blocks, is factored (three levels; see [`Smoothed`]).
//!
//! The fine level is smoothed by symmetric Gauss-Seidel over patches of 2 x 2 x 2 nodes
//! (the nodes of one coarse cell, 24 unknowns solved together) on the Hessian assembled
//! at the same evaluation. The patches are taken colour by colour (the parities of their
//! coordinates, eight colours): patches of one colour share no neighbours, so each
//! colour's are solved in parallel, with the same bits on any number of threads. One
//! application is a symmetric V-cycle from zero (a forward and a backward sweep, the
//! coarse correction, the same two sweeps), so conjugate gradients stay valid with it, at
//! three sweeps' cost (see [`Smoother::cycle`]). Newton builds it
//! afresh at every step: the gel's part at a minimisation's first, the contact's in the
//! smoother at every step and in the coarse level when the last solve took many
//! iterations (see `REFACTOR_COARSE_ABOVE` in `mod.rs`).
//!
//! Smoothers tried on `the_two_grid_cycle_cuts_the_iterations`: damped Jacobi and
//! Chebyshev on the node blocks did worse than Gauss-Seidel by nodes, and Gauss-Seidel by
//! patches did best (the highest frequencies of quadratic B-splines, which the basis
//! averages out, and nodes whose spline barely reaches into the gel have small eigenvalues
//! that a pointwise smoother does not reach; a patch holds those modes whole). Measured:
//! `docs/solvers.md`, "Newton's linear solves on fine grids".

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::system::{offset_slot, NotPositiveDefinite, System};
use super::{
    add_pairs, add_point, contract, number, ContactStiffness, Newton, Stencil, CHUNK,
    MULTIGRID_UNKNOWNS,
};

/// Neighbour offsets of a node (within two nodes along each axis).
const SLOTS: usize = 125;

/// Unknowns of a smoother patch (2 x 2 x 2 nodes).
const PATCH: usize = 24;

/// Fine points per parallel batch of their gradients, fine and mapped to the coarse grid.
const BATCH: usize = 1 << 14;

/// Along one axis: the two coarse nodes (shifted, see [`TwoGrid`]) that fine node `i`
/// takes part in and its weight in each.
#[inline(always)]
fn axis_parents(i: usize) -> [(usize, f64); 2] {
    let m = i / 2;
    if i % 2 == 0 {
        [(m, 0.75), (m + 1, 0.25)]
    } else {
        [(m, 0.25), (m + 1, 0.75)]
    }
}

/// Grid coordinates of node `node` of a grid with `dims` nodes per axis.
#[inline(always)]
fn coords(node: usize, dims: [usize; 3]) -> [usize; 3] {
    [
        node / (dims[1] * dims[2]),
        node / dims[2] % dims[1],
        node % dims[2],
    ]
}

/// Symmetric Gauss-Seidel by patches of 2 x 2 x 2 nodes on the operator of one grid level,
/// assembled in 3 x 3 blocks per node and neighbour (the nodes within two along each
/// axis), and the cycle of two levels built on it (see [`Smoother::cycle`]).
#[derive(Clone)]
struct Smoother {
    /// Per node, its neighbours at each of the 125 offsets within two nodes (node index,
    /// `u32::MAX`: none) and the 3 x 3 blocks there (rows of the node).
    neighbours: Vec<u32>,
    blocks: Vec<Matrix3<f64>>,
    /// Patches of 2 x 2 x 2 nodes for the block sweep: per node its patch and place, per
    /// patch its nodes (`u32::MAX`: none) and its inverse ([`PATCH`] squared, row-major).
    patch_of: Vec<(u32, u8)>,
    /// Per node, its neighbours in other patches as (slot, node index), those in patches
    /// before its own first: the node's are `[bounds[k][0], bounds[k][1])` and
    /// `[bounds[k][1], bounds[k][2])` of `others`; and their blocks in that order, in
    /// single precision, for the sweeps (see [`Smoother::cycle`]).
    others: Vec<(u8, u32)>,
    bounds: Vec<[u32; 3]>,
    sweep_blocks: Vec<Matrix3<f32>>,
    patch_nodes: Vec<[u32; 8]>,
    patch_inv: Vec<f64>,
    /// The patches are numbered colour by colour (see [`colour`]): colour `c`'s are
    /// `colours[c]..colours[c + 1]`.
    colours: [usize; 9],
    /// Per patch of a colour, its solved unknowns and its nodes' sums over the patches
    /// before it, written back once the colour is swept (see [`Smoother::sweep`]).
    solved: Vec<[f64; 2 * PATCH]>,
}

/// The colour of the patch at patch coordinates `p`: the parities of its coordinates. A
/// node's neighbours (within two nodes along each axis) lie in its own patch or the ones
/// next to it, and two patches of one colour are at least two apart along some axis, so
/// no node of a patch is a neighbour of another patch of its colour.
fn colour(p: [usize; 3]) -> usize {
    (p[0] % 2) * 4 + (p[1] % 2) * 2 + p[2] % 2
}

/// Which sums a sweep's patch solves take (see [`Smoother::sweep`]).
#[derive(Clone, Copy, PartialEq)]
enum Pass {
    /// Forward from `z = 0`: the patches after a patch add nothing.
    FromZero,
    Forward,
    /// Backward after a forward sweep: the sums over the patches before a patch are the
    /// ones the forward sweep kept.
    Backward,
}

impl Smoother {
    /// The smoother of the nodes at grid coordinates `coords` (in the order of their
    /// index) of a grid with `dims` nodes per axis; `index(node)` is the index of the
    /// node of grid index `node`, `u32::MAX` for none.
    fn new(coords: &[[usize; 3]], dims: [usize; 3], index: impl Fn(usize) -> u32) -> Smoother {
        let mut neighbours = vec![u32::MAX; SLOTS * coords.len()];
        for (k, c) in coords.iter().enumerate() {
            let c = c.map(|v| v as i32);
            for slot in 0..SLOTS {
                let o = [
                    slot as i32 / 25 - 2,
                    slot as i32 / 5 % 5 - 2,
                    slot as i32 % 5 - 2,
                ];
                let p = [c[0] + o[0], c[1] + o[1], c[2] + o[2]];
                if p.iter().zip(&dims).any(|(&v, &d)| v < 0 || v >= d as i32) {
                    continue;
                }
                neighbours[SLOTS * k + slot] =
                    index((p[0] as usize * dims[1] + p[1] as usize) * dims[2] + p[2] as usize);
            }
        }
        // Patches colour by colour, each colour's in the order of their coordinates.
        let mut keys: Vec<(usize, [usize; 3])> = coords
            .iter()
            .map(|c| {
                let p = c.map(|v| v / 2);
                (colour(p), p)
            })
            .collect();
        keys.sort_unstable();
        keys.dedup();
        let mut colours = [keys.len(); 9];
        for c in (0..8).rev() {
            colours[c] = keys.partition_point(|&(k, _)| k < c);
        }
        let mut patch_nodes = vec![[u32::MAX; 8]; keys.len()];
        let mut patch_of = Vec::with_capacity(coords.len());
        for (k, c) in coords.iter().enumerate() {
            let p = c.map(|v| v / 2);
            let b = keys.binary_search(&(colour(p), p)).unwrap();
            let place = (c[0] % 2) * 4 + (c[1] % 2) * 2 + c[2] % 2;
            patch_nodes[b][place] = k as u32;
            patch_of.push((b as u32, place as u8));
        }
        let (mut others, mut bounds) = (Vec::new(), Vec::with_capacity(patch_of.len()));
        for (k, &(b, _)) in patch_of.iter().enumerate() {
            let nb = &neighbours[SLOTS * k..SLOTS * (k + 1)];
            let start = others.len() as u32;
            for before in [true, false] {
                for (slot, &j) in nb.iter().enumerate() {
                    if j == u32::MAX {
                        continue;
                    }
                    let patch = patch_of[j as usize].0;
                    if (before && patch < b) || (!before && patch > b) {
                        others.push((slot as u8, j));
                    }
                }
                if before {
                    bounds.push([start, others.len() as u32, 0]);
                }
            }
            bounds[k][2] = others.len() as u32;
        }
        Smoother {
            patch_inv: vec![0.0; patch_nodes.len() * PATCH * PATCH],
            solved: vec![[0.0; 2 * PATCH]; patch_nodes.len()],
            colours,
            sweep_blocks: vec![Matrix3::zeros(); others.len()],
            others,
            bounds,
            patch_of,
            patch_nodes,
            blocks: vec![Matrix3::zeros(); neighbours.len()],
            neighbours,
        }
    }

    /// Unknowns (3 per node).
    fn len(&self) -> usize {
        3 * self.bounds.len()
    }

    /// The patches' inverses and the sweeps' blocks from the blocks.
    fn prepare(&mut self) {
        self.invert_patches();
        // Each node's run of the sweeps' blocks, filled in parallel.
        let mut runs = Vec::with_capacity(self.bounds.len());
        let mut rest = &mut self.sweep_blocks[..];
        for b in &self.bounds {
            let (run, tail) = std::mem::take(&mut rest).split_at_mut((b[2] - b[0]) as usize);
            runs.push(run);
            rest = tail;
        }
        let (blocks, others, bounds) = (&self.blocks, &self.others, &self.bounds);
        runs.into_par_iter()
            .with_min_len(256)
            .enumerate()
            .for_each(|(k, run)| {
                let from = bounds[k][0] as usize;
                for (i, m) in run.iter_mut().enumerate() {
                    *m = blocks[SLOTS * k + others[from + i].0 as usize].cast::<f32>();
                }
            });
    }

    /// The patches' inverses from the blocks.
    fn invert_patches(&mut self) {
        let (blocks, neighbours, patch_of) = (&self.blocks, &self.neighbours, &self.patch_of);
        let patches = self
            .patch_inv
            .par_chunks_exact_mut(PATCH * PATCH)
            .with_min_len(16);
        patches
            .zip(&self.patch_nodes)
            .enumerate()
            .for_each(|(b, (out, nodes))| {
                let mut m = nalgebra::DMatrix::<f64>::identity(PATCH, PATCH);
                for (p, &k) in nodes.iter().enumerate() {
                    if k == u32::MAX {
                        continue;
                    }
                    let row = &blocks[SLOTS * k as usize..SLOTS * (k as usize + 1)];
                    let nb = &neighbours[SLOTS * k as usize..SLOTS * (k as usize + 1)];
                    for (block, &j) in row.iter().zip(nb) {
                        if j == u32::MAX || patch_of[j as usize].0 as usize != b {
                            continue;
                        }
                        let q = patch_of[j as usize].1 as usize;
                        for a in 0..3 {
                            for c in 0..3 {
                                m[(3 * p + a, 3 * q + c)] = block[(a, c)];
                            }
                        }
                    }
                }
                let inv = m
                    .clone()
                    .cholesky()
                    .map(|c| c.inverse())
                    .unwrap_or_else(|| {
                        m.try_inverse()
                            .unwrap_or_else(|| nalgebra::DMatrix::zeros(PATCH, PATCH))
                    });
                for i in 0..PATCH {
                    for j in 0..PATCH {
                        out[i * PATCH + j] = inv[(i, j)];
                    }
                }
            });
    }

    /// `y = K x` with the assembled blocks.
    #[cfg(test)]
    fn multiply(&self, x: &[f64], y: &mut [f64]) {
        for (k, (row, nb)) in self
            .blocks
            .chunks_exact(SLOTS)
            .zip(self.neighbours.chunks_exact(SLOTS))
            .enumerate()
        {
            let mut v = Vector3::zeros();
            for (m, &j) in row.iter().zip(nb) {
                if j != u32::MAX {
                    let j = 3 * j as usize;
                    v += m * Vector3::new(x[j], x[j + 1], x[j + 2]);
                }
            }
            y[3 * k..3 * k + 3].copy_from_slice(v.as_slice());
        }
    }

    /// `sum_j K_kj z_j` over the neighbours `j` of node `k` whose patch comes before
    /// (`lower`) or after its own in the forward order.
    #[inline(always)]
    fn part_sum(&self, k: usize, z: &[f64], lower: bool) -> Vector3<f64> {
        let [start, middle, end] = self.bounds[k];
        let (from, to) = if lower {
            (start, middle)
        } else {
            (middle, end)
        };
        let (from, to) = (from as usize, to as usize);
        let mut w = Vector3::zeros();
        for (m, &(_, j)) in self.sweep_blocks[from..to]
            .iter()
            .zip(&self.others[from..to])
        {
            let j = 3 * j as usize;
            w += m.cast::<f64>() * Vector3::new(z[j], z[j + 1], z[j + 2]);
        }
        w
    }

    /// Patch `b`'s unknowns of `K z = r` solved against `sums` (per node of the patch,
    /// `sum_j K_kj z_j` over the other patches' neighbours), in the order of its nodes.
    #[inline(always)]
    fn solve_patch(&self, b: usize, r: &[f64], sums: &[Vector3<f64>; 8]) -> [f64; PATCH] {
        let nodes = &self.patch_nodes[b];
        let mut v = [0.0; PATCH];
        for (p, &k) in nodes.iter().enumerate() {
            if k != u32::MAX {
                let k = 3 * k as usize;
                for c in 0..3 {
                    v[3 * p + c] = r[k + c] - sums[p][c];
                }
            }
        }
        let inv = &self.patch_inv[b * PATCH * PATCH..(b + 1) * PATCH * PATCH];
        let mut z = [0.0; PATCH];
        for (i, z) in z.iter_mut().enumerate() {
            let row = &inv[i * PATCH..(i + 1) * PATCH];
            *z = row.iter().zip(&v).map(|(a, b)| a * b).sum();
        }
        z
    }

    /// Writes patch `b`'s `values` (3 per place, in the order of its nodes) into `z`.
    #[inline(always)]
    fn set_patch(&self, b: usize, values: &[f64], z: &mut [f64]) {
        for (p, &k) in self.patch_nodes[b].iter().enumerate() {
            if k != u32::MAX {
                let k = 3 * k as usize;
                z[k..k + 3].copy_from_slice(&values[3 * p..3 * p + 3]);
            }
        }
    }

    /// A Gauss-Seidel sweep by patches on `K z = r`, forward or backward (`pass`): each
    /// patch's unknowns solved together against the latest values of the rest. A forward
    /// sweep keeps each node's sum over the patches before its own in `lower` (3 per
    /// node); the backward sweep after it takes those sums (the patches before a patch
    /// still hold the forward sweep's values when it is solved) and sums only the patches
    /// after it (half the blocks of a whole sweep).
    ///
    /// The patches of one colour share no neighbours, so a colour is solved in parallel
    /// from the values of the others, into `solved`, and then written back: the same
    /// values as one patch after the other, bit for bit on any number of threads.
    fn sweep(&mut self, r: &[f64], z: &mut [f64], lower: &mut [f64], pass: Pass) {
        let mut solved = std::mem::take(&mut self.solved);
        for i in 0..8 {
            let c = if pass == Pass::Backward { 7 - i } else { i };
            let (start, end) = (self.colours[c], self.colours[c + 1]);
            let this = &*self;
            let (z_now, lower_now) = (&*z, &*lower);
            solved[..end - start]
                .par_iter_mut()
                .with_min_len(16)
                .enumerate()
                .for_each(|(i, out)| {
                    let b = start + i;
                    let mut sums = [Vector3::zeros(); 8];
                    for (p, &k) in this.patch_nodes[b].iter().enumerate() {
                        if k == u32::MAX {
                            continue;
                        }
                        let k = k as usize;
                        let before = match pass {
                            Pass::Backward => {
                                Vector3::from_column_slice(&lower_now[3 * k..3 * k + 3])
                            }
                            _ => this.part_sum(k, z_now, true),
                        };
                        out[PATCH + 3 * p..PATCH + 3 * p + 3].copy_from_slice(before.as_slice());
                        sums[p] = match pass {
                            Pass::FromZero => before,
                            _ => before + this.part_sum(k, z_now, false),
                        };
                    }
                    out[..PATCH].copy_from_slice(&this.solve_patch(b, r, &sums));
                });
            for (i, out) in solved[..end - start].iter().enumerate() {
                self.set_patch(start + i, &out[..PATCH], z);
                if pass != Pass::Backward {
                    self.set_patch(start + i, &out[PATCH..], lower);
                }
            }
        }
        self.solved = solved;
    }

    /// `z = M^-1 r`: one symmetric V-cycle from zero (a symmetric Gauss-Seidel sweep,
    /// the coarse correction `coarse`, the same sweep), `lower` scratch of `r`'s length.
    /// `coarse(residual, z)` adds the coarse level's correction for `residual` to `z`,
    /// a symmetric map for the cycle to be one.
    ///
    /// The cycle is the same linear map as the four whole sweeps and the product `K z`
    /// it is built from, at three sweeps' cost: the first sweep from zero sums only the
    /// patches before each patch, each backward sweep reuses the forward one's sums, and
    /// the residual after the first symmetric sweep is `r - K z = L_f - L_b` (per patch,
    /// its sums over the patches before it with the forward and the backward sweep's
    /// values: the backward sweep solved each patch against `L_f` and the final values of
    /// the patches after it). The sweeps are bound by reading the blocks, so the blocks
    /// between patches are read in single precision, in the order the sweeps take them
    /// (copied at each [`Self::prepare`]): the cycle is then that of a Hessian rounded off
    /// the patches' diagonal blocks, still symmetric and as good a preconditioner
    /// (measured: `docs/solvers.md`, "Cheaper Newton steps: the forcing term, the line
    /// search, the cycle's sweeps").
    fn cycle(
        &mut self,
        r: &[f64],
        z: &mut [f64],
        lower: &mut [f64],
        coarse: impl FnOnce(&[f64], &mut [f64]),
    ) {
        z.fill(0.0);
        self.sweep(r, z, lower, Pass::FromZero);
        self.sweep(r, z, lower, Pass::Backward);
        // The residual, into `lower`.
        let this = &*self;
        let z_now = &*z;
        lower
            .par_chunks_exact_mut(3)
            .with_min_len(128)
            .enumerate()
            .for_each(|(k, l)| {
                let backward = this.part_sum(k, z_now, true);
                for c in 0..3 {
                    l[c] -= backward[c];
                }
            });
        coarse(lower, z);
        self.sweep(r, z, lower, Pass::Forward);
        self.sweep(r, z, lower, Pass::Backward);
    }
}

/// The prolongation from a grid to the one of twice its spacing (see [`TwoGrid`]): per
/// node of the finer grid, the coarser grid's unknowns it takes part in and its weights.
#[derive(Clone)]
struct Prolongation {
    start: Vec<u32>,
    coarse: Vec<u32>,
    weight: Vec<f64>,
}

impl Prolongation {
    /// The coarse grid of the nodes at grid coordinates `coords` of a grid with `dims`
    /// nodes per axis: its nodes per axis, the index of each coarse node (`u32::MAX`:
    /// none), its nodes (grid indices, ascending) and the prolongation.
    fn new(coords: &[[usize; 3]], dims: [usize; 3]) -> ([usize; 3], Vec<u32>, Vec<u32>, Self) {
        let cdims = dims.map(|d| d / 2 + 2);
        let index = |j: [usize; 3]| (j[0] * cdims[1] + j[1]) * cdims[2] + j[2];
        let mut used = vec![false; cdims.iter().product()];
        for c in coords {
            each_parent(c, |j, _| used[index(j)] = true);
        }
        let (cdof, cnodes) = number(&used);
        let mut p = Prolongation {
            start: vec![0],
            coarse: Vec::new(),
            weight: Vec::new(),
        };
        for c in coords {
            each_parent(c, |j, w| {
                p.coarse.push(cdof[index(j)]);
                p.weight.push(w);
            });
            p.start.push(p.coarse.len() as u32);
        }
        (cdims, cdof, cnodes, p)
    }

    /// The coarse unknowns and weights of fine node `k`.
    #[inline(always)]
    fn parents(&self, k: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        let (a, b) = (self.start[k] as usize, self.start[k + 1] as usize);
        self.coarse[a..b]
            .iter()
            .zip(&self.weight[a..b])
            .map(|(&c, &w)| (c as usize, w))
    }

    /// `coarse = P^T fine` (3 unknowns per node).
    fn restrict(&self, fine: &[f64], coarse: &mut [f64]) {
        coarse.fill(0.0);
        for (k, f) in fine.chunks_exact(3).enumerate() {
            for (c, w) in self.parents(k) {
                for e in 0..3 {
                    coarse[3 * c + e] += w * f[e];
                }
            }
        }
    }

    /// `fine += P coarse`.
    fn prolong_add(&self, coarse: &[f64], fine: &mut [f64]) {
        for (k, f) in fine.chunks_exact_mut(3).enumerate() {
            for (c, w) in self.parents(k) {
                for e in 0..3 {
                    f[e] += w * coarse[3 * c + e];
                }
            }
        }
    }
}

/// The coarse level's operator smoothed rather than factored, with a factored level of
/// twice its spacing below it; used where the coarse level has more than
/// [`MULTIGRID_UNKNOWNS`] unknowns (the rule of the fine grid's own factorisation): at dx =
/// 0.3 mm the 0.6 mm level's 27,648, whose factorisation was most of a build (measured:
/// `docs/solvers.md`, "Three levels: the 0.6 mm level smoothed, not factored").
#[derive(Clone)]
struct Smoothed {
    smoother: Smoother,
    /// The smoothed level's nodes' grid coordinates.
    coords: Vec<[usize; 3]>,
    to_bottom: Prolongation,
    bdims: [usize; 3],
    bdof: Vec<u32>,
    bottom: System,
    lower: Vec<f64>,
    z: Vec<f64>,
    rhs: Vec<f64>,
}

impl Smoothed {
    /// The level of the nodes `cnodes` (grid indices, ascending) of a grid with `cdims`
    /// nodes per axis, indexed by `cdof`.
    fn new(cdims: [usize; 3], cdof: &[u32], cnodes: &[u32]) -> Result<Smoothed, String> {
        let coords: Vec<[usize; 3]> = cnodes.iter().map(|&c| coords(c as usize, cdims)).collect();
        let smoother = Smoother::new(&coords, cdims, |c| cdof[c]);
        let (bdims, bdof, bnodes, to_bottom) = Prolongation::new(&coords, cdims);
        let bottom = System::new(bdims, &bnodes, &bdof)?;
        let n = smoother.len();
        Ok(Smoothed {
            lower: vec![0.0; n],
            z: vec![0.0; n],
            rhs: vec![0.0; bottom.n],
            smoother,
            coords,
            to_bottom,
            bdims,
            bdof,
            bottom,
        })
    }

    /// Sets the smoother from the operator `a` assembled on this level's nodes, and the
    /// bottom level to the Galerkin product `P^T a P`, factored.
    fn set(&mut self, a: &System) -> Result<(), NotPositiveDefinite> {
        let s = &mut self.smoother;
        s.blocks.fill(Matrix3::zeros());
        a.each_block(|i, j, slot, k| {
            // `k` has the rows of `i`, at offset `slot` from `j`, and the columns of `j`;
            // the mirror block, in the rows of `j`, is its transpose.
            if i == j {
                s.blocks[SLOTS * j + slot] += k;
            } else {
                s.blocks[SLOTS * i + (SLOTS - 1 - slot)] += k;
                s.blocks[SLOTS * j + slot] += k.transpose();
            }
        });
        s.prepare();
        // Per node `i`: `a_ij P_j` summed over its neighbours `j` on the 4 x 4 x 4 bottom
        // nodes they reach (from bottom coordinate `i / 2 - 1` on), then `P_i^T` of that.
        let (bdims, bdof) = (self.bdims, &self.bdof);
        let bottom_dof = |b: [usize; 3]| bdof[(b[0] * bdims[1] + b[1]) * bdims[2] + b[2]];
        self.bottom.clear();
        for (i, ci) in self.coords.iter().enumerate() {
            let base = ci.map(|c| (c / 2) as i32 - 1);
            let mut gathered = [Matrix3::<f64>::zeros(); 64];
            let mut reached = [u32::MAX; 64];
            for slot in 0..SLOTS {
                let j = s.neighbours[SLOTS * i + slot];
                if j == u32::MAX {
                    continue;
                }
                let k = s.blocks[SLOTS * i + slot];
                each_parent(&self.coords[j as usize], |b, w| {
                    let o = [0, 1, 2].map(|a| (b[a] as i32 - base[a]) as usize);
                    let at = (o[0] * 4 + o[1]) * 4 + o[2];
                    reached[at] = bottom_dof(b);
                    gathered[at] += k * w;
                });
            }
            each_parent(ci, |bi, wi| {
                let di = bottom_dof(bi);
                for (at, &dj) in reached.iter().enumerate() {
                    if dj == u32::MAX || dj > di {
                        continue;
                    }
                    let o = [at / 16, at / 4 % 4, at % 4];
                    let offset = [0, 1, 2].map(|a| bi[a] as i32 - (base[a] + o[a] as i32));
                    self.bottom
                        .add_block(di as usize, dj as usize, offset, &(gathered[at] * wi));
                }
            });
        }
        self.bottom.factor()
    }

    /// `rhs` becomes `M^-1 rhs`: the two-level cycle of this level and the bottom one.
    fn solve(&mut self, rhs: &mut [f64]) {
        let Smoothed {
            smoother,
            to_bottom,
            bottom,
            lower,
            z,
            rhs: brhs,
            ..
        } = self;
        smoother.cycle(rhs, z, lower, |residual, z| {
            to_bottom.restrict(residual, brhs);
            bottom.solve(brhs);
            to_bottom.prolong_add(brhs, z);
        });
        rhs.copy_from_slice(z);
    }
}

/// A fine point's (or contact point's) stencil mapped to the coarse grid: the base of the
/// 3 x 3 x 3 coarse nodes its fine nodes take part in.
struct CoarseMap {
    base: [i32; 3],
}

impl CoarseMap {
    fn new(fine: &[i32; 3]) -> CoarseMap {
        CoarseMap {
            base: fine.map(|b| b.div_euclid(2)),
        }
    }

    /// Calls `f(coarse local index, weight)` for each coarse node fine local node `l`
    /// (of a stencil at `fine`) takes part in.
    #[inline(always)]
    fn each(&self, fine: &[i32; 3], l: usize, mut f: impl FnMut(usize, f64)) {
        let o = Stencil::local(l);
        let parents: [[(usize, f64); 2]; 3] =
            std::array::from_fn(|k| axis_parents((fine[k] + o[k]) as usize));
        for (jx, wx) in parents[0] {
            for (jy, wy) in parents[1] {
                for (jz, wz) in parents[2] {
                    let a = [
                        jx as i32 - self.base[0],
                        jy as i32 - self.base[1],
                        jz as i32 - self.base[2],
                    ];
                    f(((a[0] * 3 + a[1]) * 3 + a[2]) as usize, wx * wy * wz);
                }
            }
        }
    }
}

/// Calls `f(coarse node's grid coordinates, weight)` for the 2 x 2 x 2 nodes of the grid
/// of twice the spacing that the node at `c` takes part in.
#[inline(always)]
fn each_parent(c: &[usize; 3], mut f: impl FnMut([usize; 3], f64)) {
    let p: [[(usize, f64); 2]; 3] = std::array::from_fn(|k| axis_parents(c[k]));
    for (jx, wx) in p[0] {
        for (jy, wy) in p[1] {
            for (jz, wz) in p[2] {
                f([jx, jy, jz], wx * wy * wz);
            }
        }
    }
}

/// The coarse level of one region and the fine smoother.
#[derive(Clone)]
pub(super) struct TwoGrid {
    /// Coarse grid: nodes per axis (node `J` at fine coordinate `2 J - 1/2`) and the
    /// coarse unknown of each node (`u32::MAX`: none).
    cdims: [usize; 3],
    cdof: Vec<u32>,
    to_coarse: Prolongation,
    /// The coarse operator, assembled; factored unless `smoothed`.
    coarse: System,
    smoothed: Option<Smoothed>,
    /// The fine Hessian assembled for the smoother (region nodes).
    fine: Smoother,
    product: Vec<f64>,
    coarse_rhs: Vec<f64>,
    /// The contact terms in the fine blocks (taken out again when only the contact is
    /// refreshed, see [`TwoGrid::build`]).
    contact: Vec<ContactStiffness>,
    /// The contact terms in `coarse`, which may be those of an earlier build than the
    /// fine blocks' (see [`TwoGrid::build`]).
    coarse_contact: Vec<ContactStiffness>,
}

impl TwoGrid {
    /// The coarse level of the current region of `newton`.
    pub fn new(newton: &Newton) -> Result<TwoGrid, String> {
        let dims = newton.dims;
        let fine_coords: Vec<[usize; 3]> = newton
            .region_nodes
            .iter()
            .map(|&g| coords(newton.free_nodes[g as usize] as usize, dims))
            .collect();
        let (cdims, cdof, cnodes, to_coarse) = Prolongation::new(&fine_coords, dims);
        let coarse = System::new(cdims, &cnodes, &cdof)?;
        let smoothed = if coarse.n > MULTIGRID_UNKNOWNS {
            Some(Smoothed::new(cdims, &cdof, &cnodes)?)
        } else {
            None
        };
        let fine = Smoother::new(&fine_coords, dims, |node| match newton.dof[node] {
            u32::MAX => u32::MAX,
            d => newton.local[d as usize],
        });
        Ok(TwoGrid {
            product: vec![0.0; fine.len()],
            coarse_rhs: vec![0.0; coarse.n],
            fine,
            cdims,
            cdof,
            to_coarse,
            coarse,
            smoothed,
            contact: Vec::new(),
            coarse_contact: Vec::new(),
        })
    }

    /// The coarse unknowns of the coarse nodes around `map`'s base (`usize::MAX`: none).
    fn coarse_dofs(&self, map: &CoarseMap) -> [usize; 27] {
        std::array::from_fn(|a| {
            let o = Stencil::local(a);
            let p = [map.base[0] + o[0], map.base[1] + o[1], map.base[2] + o[2]];
            if p.iter()
                .zip(&self.cdims)
                .any(|(&v, &d)| v < 0 || v >= d as i32)
            {
                return usize::MAX;
            }
            let d = self.cdof
                [(p[0] as usize * self.cdims[1] + p[1] as usize) * self.cdims[2] + p[2] as usize];
            if d == u32::MAX {
                usize::MAX
            } else {
                d as usize
            }
        })
    }

    /// Sets the coarse operator and the smoother from `newton`'s last evaluation: the
    /// gel's part afresh when `elastic`, else only the contact's (its last terms taken out,
    /// the present ones put in; the gel's part stays that of an earlier evaluation).
    ///
    /// The cycle is only the preconditioner of conjugate gradients, whose products are the
    /// present Hessian's, so a gel's part a few Newton steps old costs iterations, not
    /// accuracy; the contact changes far more from step to step (points enter and leave,
    /// with the penalty's stiffness). The gel's part is most of the work. With `coarse`
    /// false (and not `elastic`) only the smoother's contact is refreshed, and the coarse
    /// operator and its factorisation stay those of the last build that refreshed them,
    /// the larger part of a build on a fine grid (measured: `docs/solvers.md`, "Newton's
    /// linear solves on fine grids" and "The contact penalty in physical units; the
    /// coarse level refactored after slow solves").
    pub fn build(
        &mut self,
        newton: &Newton,
        elastic: bool,
        coarse: bool,
    ) -> Result<(), NotPositiveDefinite> {
        let coarse = coarse || elastic;
        if elastic {
            self.build_elastic(newton);
        } else {
            for k in std::mem::take(&mut self.contact) {
                self.add_fine_contact(&k, -1.0);
            }
            if coarse {
                for k in std::mem::take(&mut self.coarse_contact) {
                    self.add_coarse_contact(&k, -1.0);
                }
            }
        }
        for k in &newton.contact_stiffness {
            self.add_fine_contact(k, 1.0);
            if coarse {
                self.add_coarse_contact(k, 1.0);
            }
        }
        self.contact.clone_from(&newton.contact_stiffness);
        if coarse {
            self.coarse_contact.clone_from(&newton.contact_stiffness);
            match self.smoothed.as_mut() {
                Some(level) => level.set(&self.coarse)?,
                None => self.coarse.factor()?,
            }
        }
        self.fine.prepare();
        Ok(())
    }

    /// The gel's part of the coarse operator and of the fine blocks, from `newton`'s last
    /// evaluation (the contact's left out).
    fn build_elastic(&mut self, newton: &Newton) {
        self.coarse.clear();
        self.contact.clear();
        self.coarse_contact.clear();
        let mut blocks = std::mem::take(&mut self.fine.blocks);
        blocks.fill(Matrix3::zeros());
        newton.slabs.add(&mut blocks, SLOTS, |slab, rows, first| {
            for &r in slab {
                let r = r as usize;
                let stencil = &newton.points[newton.region_points[r] as usize].stencil;
                let local = &newton.point_local[r];
                let fine: [Vector3<f64>; 27] = std::array::from_fn(|l| stencil.gradient(l));
                let tl = contract(&fine, &newton.states[r].tangent, |l| local[l] != u32::MAX);
                add_fine(rows, first, local, |l1, l2| {
                    let g2 = &fine[l2];
                    Matrix3::from_fn(|a, c| {
                        tl[l1][a][3 * c] * g2[0]
                            + tl[l1][a][3 * c + 1] * g2[1]
                            + tl[l1][a][3 * c + 2] * g2[2]
                    })
                });
            }
        });
        self.fine.blocks = blocks;
        let count = newton.states.len();
        for start in (0..count).step_by(BATCH) {
            let end = (start + BATCH).min(count);
            // Per point: its gradients mapped to the coarse grid.
            let mapped: Vec<[Vector3<f64>; 27]> = (start..end)
                .into_par_iter()
                .with_min_len(CHUNK)
                .map(|r| {
                    let stencil = &newton.points[newton.region_points[r] as usize].stencil;
                    let map = CoarseMap::new(&stencil.base);
                    let mut coarse = [Vector3::zeros(); 27];
                    for (l, &d) in newton.point_local[r].iter().enumerate() {
                        if d != u32::MAX {
                            let g = stencil.gradient(l);
                            map.each(&stencil.base, l, |a, w| coarse[a] += g * w);
                        }
                    }
                    coarse
                })
                .collect();
            for (r, grads) in (start..end).zip(&mapped) {
                let stencil = &newton.points[newton.region_points[r] as usize].stencil;
                let dofs = self.coarse_dofs(&CoarseMap::new(&stencil.base));
                add_point(&mut self.coarse, &dofs, grads, &newton.states[r].tangent);
            }
        }
    }

    /// Adds `sign` times a contact point's stiffness to the coarse operator.
    fn add_coarse_contact(&mut self, k: &ContactStiffness, sign: f64) {
        let base = k.base;
        let map = CoarseMap::new(&base);
        let mut w = [0.0; 27];
        for (l, (&d, &wl)) in k.dofs.iter().zip(&k.w).enumerate() {
            if d != usize::MAX {
                map.each(&base, l, |a, s| w[a] += wl * s);
            }
        }
        let h = k.h * sign;
        let dofs = self.coarse_dofs(&map);
        add_pairs(&mut self.coarse, &dofs, |a, b| h * (w[a] * w[b]));
    }

    /// Adds `sign` times a contact point's stiffness to the fine blocks.
    fn add_fine_contact(&mut self, k: &ContactStiffness, sign: f64) {
        let h = k.h * sign;
        let local = k
            .dofs
            .map(|d| if d == usize::MAX { u32::MAX } else { d as u32 });
        add_fine(&mut self.fine.blocks, 0, &local, |l1, l2| {
            h * (k.w[l1] * k.w[l2])
        });
    }

    /// `z = M^-1 r`: one symmetric V-cycle from zero on the fine level
    /// ([`Smoother::cycle`]), whose coarse correction solves the coarse level with its
    /// factorisation or, where it is `smoothed`, with the same cycle of its own.
    pub fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        let mut lower = std::mem::take(&mut self.product);
        let TwoGrid {
            fine,
            to_coarse,
            coarse,
            smoothed,
            coarse_rhs,
            ..
        } = self;
        fine.cycle(r, z, &mut lower, |residual, z| {
            to_coarse.restrict(residual, coarse_rhs);
            match smoothed {
                Some(level) => level.solve(coarse_rhs),
                None => coarse.solve(coarse_rhs),
            }
            to_coarse.prolong_add(coarse_rhs, z);
        });
        self.product = lower;
    }
}

/// Adds the pairs of a point's stencil nodes (region indices `local`, `u32::MAX`: none)
/// to the assembled fine blocks: `block(l1, l2)` their 3 x 3 Hessian block, evaluated for
/// `l2 <= l1` and mirrored.
fn add_fine(
    blocks: &mut [Matrix3<f64>],
    first: usize,
    local: &[u32; 27],
    block: impl Fn(usize, usize) -> Matrix3<f64>,
) {
    for l1 in 0..27 {
        if local[l1] == u32::MAX {
            continue;
        }
        let o1 = Stencil::local(l1);
        for l2 in 0..=l1 {
            if local[l2] == u32::MAX {
                continue;
            }
            let o2 = Stencil::local(l2);
            let o = [o2[0] - o1[0], o2[1] - o1[1], o2[2] - o1[2]];
            let k = block(l1, l2);
            blocks[SLOTS * (local[l1] as usize - first) + offset_slot(o)] += k;
            if l2 != l1 {
                blocks[SLOTS * (local[l2] as usize - first) + offset_slot(o.map(|v| -v))] +=
                    k.transpose();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::{Gel, GelParams, Linear, Placed, Solver, SolverOptions};
    use super::super::system::{conjugate_gradients, dot};
    use super::*;
    use crate::geometry::{Sdf, Sphere};
    use nalgebra::Isometry3;
    use std::sync::Arc;

    /// A deterministic scatter of values in `[-0.5, 0.5)`.
    fn scatter(n: usize, seed: f64) -> Vec<f64> {
        (0..n)
            .map(|i| ((i as f64 + seed) * 0.754_877_666_2).fract() - 0.5)
            .collect()
    }

    /// The two-scale relation: a coarse B-spline field equals, everywhere, the fine
    /// B-spline field of its prolongation (so `P` loses nothing and the Galerkin coarse
    /// operator is the Hessian on the coarse fields).
    #[test]
    fn coarse_splines_are_combinations_of_fine_ones() {
        let coarse = scatter(16, 0.3);
        for k in 0..200 {
            let x = 3.0 + 20.0 * k as f64 / 200.0 + 0.0137;
            let c = Stencil::at(&Vector3::repeat((x + 0.5) / 2.0));
            let from_coarse: f64 = (0..3)
                .map(|a| c.w[0][a] * coarse[(c.base[0] + a as i32) as usize])
                .sum();
            let f = Stencil::at(&Vector3::repeat(x));
            let from_fine: f64 = (0..3)
                .map(|l| {
                    let i = (f.base[0] + l as i32) as usize;
                    let v: f64 = axis_parents(i).iter().map(|&(j, w)| w * coarse[j]).sum();
                    f.w[0][l] * v
                })
                .sum();
            assert!(
                (from_coarse - from_fine).abs() < 1e-12,
                "x {x}: {from_coarse} against {from_fine}"
            );
        }
    }

    /// A gel pressed by a sphere, evaluated, with its two-grid preconditioner built.
    fn pressed(dx: f64) -> (Newton, TwoGrid) {
        let params = GelParams {
            size: [0.012, 0.012, 0.003],
            dx,
            ..Default::default()
        };
        let options = SolverOptions {
            solver: Solver::Newton,
            linear: Linear::Multigrid,
            ..Default::default()
        };
        let mut gel = Gel::new(params, options).unwrap();
        let ball: Arc<dyn Sdf> = Arc::new(Sphere { radius: 3e-3 });
        gel.solve(&[Placed {
            shape: ball,
            pose: Isometry3::translation(0.0, 0.0, 3e-3 - 0.3e-3),
        }]);
        // The solver keeps the tangents and contact stiffnesses of its last evaluation.
        let mut n = *gel.newton_solver().unwrap().state.take().unwrap();
        let mut grid = n.two_grid.take().unwrap();
        grid.build(&n, true, true).unwrap();
        (n, grid)
    }

    /// The coarse matrix is `P^T H P`: the energy of any coarse field equals that of its
    /// prolongation (elastic points and contact, held and fixed nodes included).
    #[test]
    fn the_coarse_operator_is_the_galerkin_product() {
        let (n, grid) = pressed(1e-3);
        let nc = grid.coarse.n;
        let nf = grid.product.len();
        assert_galerkin(
            (nf, nc),
            &grid.to_coarse,
            |x, y| n.hessian_product(x, y),
            |x, y| grid.coarse.multiply(x, y),
        );
    }

    /// The energy of any coarse field (`counts.1` unknowns) on `coarse` equals that of its
    /// prolongation `p` (to `counts.0` unknowns) on `fine`, to 1e-10.
    fn assert_galerkin(
        counts: (usize, usize),
        p: &Prolongation,
        fine: impl Fn(&[f64], &mut [f64]),
        coarse: impl Fn(&[f64], &mut [f64]),
    ) {
        let (nf, nc) = counts;
        for seed in [0.1, 0.7, 2.3] {
            let u = scatter(nc, seed);
            let mut pu = vec![0.0; nf];
            p.prolong_add(&u, &mut pu);
            let (mut fpu, mut cu) = (vec![0.0; nf], vec![0.0; nc]);
            fine(&pu, &mut fpu);
            coarse(&u, &mut cu);
            let (f, c) = (dot(&pu, &fpu), dot(&u, &cu));
            assert!((f - c).abs() <= 1e-10 * f.abs(), "{f} against {c}");
        }
    }

    /// The smoother's assembled blocks are the Hessian: their product equals the
    /// matrix-free one.
    #[test]
    fn the_assembled_blocks_are_the_hessian() {
        let (n, grid) = pressed(1e-3);
        let nf = grid.product.len();
        let x = scatter(nf, 0.9);
        let (mut kx, mut hx) = (vec![0.0; nf], vec![0.0; nf]);
        grid.fine.multiply(&x, &mut kx);
        n.hessian_product(&x, &mut hx);
        let difference: f64 = kx.iter().zip(&hx).map(|(k, h)| (k - h) * (k - h)).sum();
        assert!(
            difference.sqrt() <= 1e-12 * dot(&hx, &hx).sqrt(),
            "{difference}"
        );
    }

    /// A refresh of the contact alone takes the last contact's terms out and puts the
    /// present ones in: with the gel's part unchanged it gives the operators a build from
    /// scratch gives, to round-off (here from the press's contact to every other point of
    /// it, and on to all of it again).
    #[test]
    fn refreshing_the_contact_alone_matches_a_whole_build() {
        let (mut n, mut grid) = pressed(1e-3);
        let all = n.contact_stiffness.clone();
        assert!(all.len() > 10);
        let half: Vec<ContactStiffness> = all.iter().step_by(2).copied().collect();
        for contact in [half, all] {
            n.contact_stiffness = contact;
            grid.build(&n, false, true).unwrap();
            let mut whole = grid.clone();
            whole.build(&n, true, true).unwrap();
            assert_close(&grid.coarse.values, &whole.coarse.values, 1e-12);
            assert_close(&flat(&grid.fine.blocks), &flat(&whole.fine.blocks), 1e-12);
            // The patches' inverses, through their conditioning.
            assert_close(&grid.fine.patch_inv, &whole.fine.patch_inv, 1e-8);
        }
    }

    /// The largest difference between `a` and `b`, and `b`'s largest magnitude.
    fn difference(a: &[f64], b: &[f64]) -> (f64, f64) {
        let largest = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let worst = a
            .iter()
            .zip(b)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        (worst, largest)
    }

    /// `a` within `rel` of `b`'s largest magnitude everywhere.
    fn assert_close(a: &[f64], b: &[f64], rel: f64) {
        let (worst, largest) = difference(a, b);
        assert!(worst <= rel * largest, "{worst} against {largest}");
    }

    fn flat(b: &[Matrix3<f64>]) -> Vec<f64> {
        b.iter().flat_map(|m| m.iter().copied()).collect()
    }

    /// A refresh of the smoother alone leaves the coarse operator bit for bit as the last
    /// build that refreshed it (here the whole press's contact) and the fine blocks as a
    /// whole build of the present contact gives them (every other point of it); the next
    /// refresh of the coarse level takes out the terms of the last one that reached it.
    #[test]
    fn the_smoother_s_contact_is_refreshed_without_the_coarse_level() {
        let (mut n, mut grid) = pressed(1e-3);
        let coarse_all = grid.coarse.values.clone();
        n.contact_stiffness = n.contact_stiffness.iter().step_by(2).copied().collect();
        grid.build(&n, false, false).unwrap();
        assert_eq!(grid.coarse.values, coarse_all);
        let mut whole = grid.clone();
        whole.build(&n, true, true).unwrap();
        assert_close(&flat(&grid.fine.blocks), &flat(&whole.fine.blocks), 1e-12);
        assert_close(&grid.fine.patch_inv, &whole.fine.patch_inv, 1e-8);
        // Half the contact's penalty is a change the coarse operator shows.
        let (worst, largest) = difference(&coarse_all, &whole.coarse.values);
        assert!(worst > 1e-3 * largest, "{worst} against {largest}");
        grid.build(&n, false, true).unwrap();
        assert_close(&grid.coarse.values, &whole.coarse.values, 1e-12);
    }

    /// The cycle at three sweeps' cost is the textbook one: four whole Gauss-Seidel sweeps
    /// by patches (every neighbour summed with its latest value) and the product `K z`
    /// for the residual, on the same blocks, to round-off.
    #[test]
    fn the_cycle_is_the_textbook_symmetric_v_cycle() {
        let (_, mut grid) = pressed(1e-3);
        let nf = grid.product.len();
        let sweep = |grid: &TwoGrid, r: &[f64], z: &mut [f64], forward: bool| {
            let n = grid.fine.patch_nodes.len();
            for i in 0..n {
                let b = if forward { i } else { n - 1 - i };
                let mut sums = [Vector3::zeros(); 8];
                for (p, &k) in grid.fine.patch_nodes[b].iter().enumerate() {
                    if k != u32::MAX {
                        let k = k as usize;
                        sums[p] = grid.fine.part_sum(k, z, true) + grid.fine.part_sum(k, z, false);
                    }
                }
                let solved = grid.fine.solve_patch(b, r, &sums);
                grid.fine.set_patch(b, &solved, z);
            }
        };
        for seed in [0.3, 1.1] {
            let r = scatter(nf, seed);
            let mut z = vec![0.0; nf];
            grid.apply(&r, &mut z);
            let mut y = vec![0.0; nf];
            sweep(&grid, &r, &mut y, true);
            sweep(&grid, &r, &mut y, false);
            // `K y` with the sweeps' blocks: the patch's own in double precision, the rest
            // in single.
            let mut ky = vec![0.0; nf];
            for (b, nodes) in grid.fine.patch_nodes.iter().enumerate() {
                for &k in nodes.iter().filter(|&&k| k != u32::MAX) {
                    let k = k as usize;
                    let mut v = grid.fine.part_sum(k, &y, true) + grid.fine.part_sum(k, &y, false);
                    for slot in 0..SLOTS {
                        let j = grid.fine.neighbours[SLOTS * k + slot];
                        if j != u32::MAX && grid.fine.patch_of[j as usize].0 as usize == b {
                            let j = 3 * j as usize;
                            v += grid.fine.blocks[SLOTS * k + slot]
                                * Vector3::new(y[j], y[j + 1], y[j + 2]);
                        }
                    }
                    ky[3 * k..3 * k + 3].copy_from_slice(v.as_slice());
                }
            }
            let residual: Vec<f64> = r.iter().zip(&ky).map(|(r, k)| r - k).collect();
            let mut rhs = vec![0.0; grid.coarse.n];
            grid.to_coarse.restrict(&residual, &mut rhs);
            grid.coarse.solve(&mut rhs);
            grid.to_coarse.prolong_add(&rhs, &mut y);
            sweep(&grid, &r, &mut y, true);
            sweep(&grid, &r, &mut y, false);
            let difference: f64 = z.iter().zip(&y).map(|(a, b)| (a - b) * (a - b)).sum();
            assert!(
                difference.sqrt() <= 1e-10 * dot(&y, &y).sqrt(),
                "{} against {}",
                difference.sqrt(),
                dot(&y, &y).sqrt()
            );
        }
    }

    /// No node of a patch is a neighbour of another patch of its colour, on the fine
    /// level and on a smoothed coarse one, so a colour's patches can be solved at once;
    /// and every colour holds patches.
    #[test]
    fn patches_of_one_colour_share_no_neighbours() {
        let (n, mut grid) = pressed(1e-3);
        smooth(&mut grid);
        grid.build(&n, true, true).unwrap();
        for s in [&grid.fine, &grid.smoothed.as_ref().unwrap().smoother] {
            let colour_of = |b: u32| s.colours.partition_point(|&start| start <= b as usize) - 1;
            assert!(s.colours.windows(2).all(|w| w[0] < w[1]), "{:?}", s.colours);
            let mut pairs = 0;
            for (k, nb) in s.neighbours.chunks_exact(SLOTS).enumerate() {
                let own = s.patch_of[k].0;
                for &j in nb.iter().filter(|&&j| j != u32::MAX) {
                    let other = s.patch_of[j as usize].0;
                    if other != own {
                        pairs += 1;
                        assert_ne!(colour_of(own), colour_of(other), "nodes {k} and {j}");
                    }
                }
            }
            assert!(pairs > 0);
        }
    }

    /// The cycle of two and of three levels gives the same bits on one, two and three
    /// threads (the patches of a colour are solved in parallel).
    #[test]
    fn the_cycle_gives_the_same_bits_on_any_number_of_threads() {
        let (n, mut grid) = pressed(1e-3);
        let r = scatter(grid.product.len(), 0.7);
        for three_levels in [false, true] {
            if three_levels {
                smooth(&mut grid);
                grid.build(&n, true, true).unwrap();
            }
            let cycles: Vec<Vec<f64>> = [1, 2, 3]
                .iter()
                .map(|&threads| {
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap();
                    let mut z = vec![0.0; r.len()];
                    pool.install(|| grid.apply(&r, &mut z));
                    z
                })
                .collect();
            assert!(dot(&cycles[0], &cycles[0]) > 0.0);
            for z in &cycles[1..] {
                let same = z
                    .iter()
                    .zip(&cycles[0])
                    .all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "three levels: {three_levels}");
            }
        }
    }

    /// The coarse level smoothed rather than factored, whatever its size.
    fn smooth(grid: &mut TwoGrid) {
        let cnodes: Vec<u32> = (0..grid.cdof.len() as u32)
            .filter(|&c| grid.cdof[c as usize] != u32::MAX)
            .collect();
        grid.smoothed = Some(Smoothed::new(grid.cdims, &grid.cdof, &cnodes).unwrap());
    }

    /// A smoothed coarse level's blocks are the coarse operator (their products agree),
    /// and the level below it is the Galerkin product: the energy of any bottom field
    /// equals that of its prolongation on the coarse operator.
    #[test]
    fn the_smoothed_level_holds_the_coarse_operator_and_its_galerkin_product() {
        let (n, mut grid) = pressed(1e-3);
        smooth(&mut grid);
        grid.build(&n, true, true).unwrap();
        let level = grid.smoothed.as_ref().unwrap();
        let nc = grid.coarse.n;
        let u = scatter(nc, 0.2);
        let (mut ku, mut au) = (vec![0.0; nc], vec![0.0; nc]);
        level.smoother.multiply(&u, &mut ku);
        grid.coarse.multiply(&u, &mut au);
        assert_close(&ku, &au, 1e-12);
        assert_galerkin(
            (nc, level.bottom.n),
            &level.to_bottom,
            |x, y| grid.coarse.multiply(x, y),
            |x, y| level.bottom.multiply(x, y),
        );
    }

    /// Conjugate gradients preconditioned with the two-grid cycle need at most a fifth of
    /// the iterations they need with the Hessian's block diagonal (measured: 24 against
    /// 302; 22 against 326 with the patches in the order of their nodes rather than
    /// colour by colour), for a right-hand side whose solution is of order one at every
    /// node; with three levels (the coarse one smoothed, the one below it factored) at
    /// most a quarter more than with two (measured: 23).
    #[test]
    fn the_two_grid_cycle_cuts_the_iterations() {
        let (n, mut grid) = pressed(0.5e-3);
        let nf = grid.product.len();
        let mut b = vec![0.0; nf];
        n.hessian_product(&scatter(nf, 0.4), &mut b);
        let mut x = vec![0.0; nf];
        let mut work: [Vec<f64>; 3] = Default::default();
        let mut solve = |precondition: &mut dyn FnMut(&[f64], &mut [f64])| {
            let (ok, iterations) = conjugate_gradients(
                &b,
                &mut x,
                1e-6,
                5000,
                &mut work,
                |x, y| n.hessian_product(x, y),
                precondition,
            );
            assert!(ok);
            iterations
        };
        let two_grid = solve(&mut |r, z| grid.apply(r, z));
        let inverses: Vec<Matrix3<f64>> = grid
            .fine
            .blocks
            .chunks_exact(SLOTS)
            .map(|row| row[offset_slot([0, 0, 0])].try_inverse().unwrap())
            .collect();
        let diagonal = solve(&mut |r, z| {
            for ((inv, r), z) in inverses
                .iter()
                .zip(r.chunks_exact(3))
                .zip(z.chunks_exact_mut(3))
            {
                z.copy_from_slice((inv * Vector3::new(r[0], r[1], r[2])).as_slice());
            }
        });
        assert!(
            5 * two_grid <= diagonal,
            "two-grid {two_grid}, block diagonal {diagonal}"
        );
        smooth(&mut grid);
        grid.build(&n, true, true).unwrap();
        let three = solve(&mut |r, z| grid.apply(r, z));
        assert!(
            4 * three <= 5 * two_grid,
            "three levels {three}, two {two_grid}"
        );
    }
}
