//! The sparse stiffness matrix of the free grid nodes and its Cholesky factorisation.
//!
//! Two nodes interact when one quadrature point's 3 x 3 x 3 stencil holds both, so at
//! most 2 cells apart along each axis. The matrix keeps the lower triangle in compressed
//! columns (faer's layout), node by node in grid order, three degrees of freedom per node.
//! The pattern (every node pair at most 2 cells apart) and its symbolic factorisation (a
//! fill-reducing ordering) are built once per gel; each Newton step only refills the
//! values and refactors.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{factorize_symbolic_cholesky, LltRef, SymbolicCholesky};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side, Spec};
use nalgebra::Matrix3;

/// The offset of a neighbour `(ox, oy, oz)`, each in `-2..=2`, as an index in `0..125`.
#[inline(always)]
/// faer's parallelism for a factorisation: the threads of the pool it is called in (the
/// gel's), one at a time outside any. One and two threads have given the same bits in
/// every check (`threads_give_identical_results` of both solvers, the gripper's grasp
/// cycle on the linear gel, Newton's method at dx = 0.7 mm).
pub(crate) fn par() -> Par {
    match rayon::current_num_threads() {
        0 | 1 => Par::Seq,
        n => Par::rayon(n),
    }
}

pub(crate) fn offset_slot(o: [i32; 3]) -> usize {
    (((o[0] + 2) * 5 + o[1] + 2) * 5 + o[2] + 2) as usize
}

/// No neighbour at this offset.
const NONE: u8 = u8::MAX;

/// Sparsity pattern, values and factorisation of the stiffness matrix.
#[derive(Clone)]
pub(crate) struct System {
    /// Degrees of freedom (3 per free node).
    pub n: usize,
    col_ptr: Vec<u32>,
    row_idx: Vec<u32>,
    /// Lower-triangle values.
    pub values: Vec<f64>,
    /// Per free node, per offset slot: the position of that neighbour among the node's
    /// column neighbours (the node itself first), or [`NONE`].
    neighbour: Vec<[u8; 125]>,
    symbolic: std::sync::Arc<SymbolicCholesky<u32>>,
    factor: Vec<f64>,
    /// Positions of the diagonal entries.
    diagonal: Vec<usize>,
    /// Whether `factor` holds a factorisation (of this or an earlier matrix).
    pub factored: bool,
}

/// Why a linear solve failed.
#[derive(Debug)]
pub(crate) struct NotPositiveDefinite;

impl System {
    /// The pattern of the free nodes `nodes` (grid indices, ascending) of a grid with
    /// `dims` nodes per axis; `dof[node]` is a node's free index or `u32::MAX`.
    pub fn new(dims: [usize; 3], nodes: &[u32], dof: &[u32]) -> Result<System, String> {
        let coord = |node: usize| {
            let iz = node % dims[2];
            let iy = node / dims[2] % dims[1];
            let ix = node / (dims[1] * dims[2]);
            [ix as i32, iy as i32, iz as i32]
        };
        let mut neighbour = vec![[NONE; 125]; nodes.len()];
        let mut lists: Vec<Vec<u32>> = Vec::with_capacity(nodes.len());
        for (j, &node) in nodes.iter().enumerate() {
            let c = coord(node as usize);
            let mut list = Vec::with_capacity(63);
            for ox in -2..=2i32 {
                for oy in -2..=2i32 {
                    for oz in -2..=2i32 {
                        let p = [c[0] + ox, c[1] + oy, c[2] + oz];
                        if p.iter().zip(&dims).any(|(&v, &d)| v < 0 || v >= d as i32) {
                            continue;
                        }
                        let other =
                            (p[0] as usize * dims[1] + p[1] as usize) * dims[2] + p[2] as usize;
                        let d = dof[other];
                        if d != u32::MAX && d as usize >= j {
                            list.push((d, offset_slot([ox, oy, oz])));
                        }
                    }
                }
            }
            list.sort_unstable();
            for (k, &(_, slot)) in list.iter().enumerate() {
                neighbour[j][slot] = k as u8;
            }
            lists.push(list.into_iter().map(|(d, _)| d).collect());
        }
        let n = 3 * nodes.len();
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        let mut diagonal = Vec::with_capacity(n);
        col_ptr.push(0u32);
        for (j, list) in lists.iter().enumerate() {
            for c in 0..3 {
                diagonal.push(row_idx.len());
                for r in c..3 {
                    row_idx.push((3 * j + r) as u32);
                }
                for &d in &list[1..] {
                    for r in 0..3 {
                        row_idx.push(3 * d + r as u32);
                    }
                }
                col_ptr.push(row_idx.len() as u32);
            }
        }
        if row_idx.len() > u32::MAX as usize / 2 {
            return Err("stiffness matrix too large".into());
        }
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        let symbolic = factorize_symbolic_cholesky(
            pattern,
            Side::Lower,
            Default::default(),
            Default::default(),
        )
        .map_err(|e| format!("symbolic factorisation: {e:?}"))?;
        let factor = vec![0.0; symbolic.len_val()];
        let symbolic = std::sync::Arc::new(symbolic);
        let nnz = row_idx.len();
        Ok(System {
            n,
            col_ptr,
            row_idx,
            values: vec![0.0; nnz],
            neighbour,
            symbolic,
            factor,
            diagonal,
            factored: false,
        })
    }

    /// Zeroes the values.
    pub fn clear(&mut self) {
        self.values.fill(0.0);
    }

    /// Adds the 3 x 3 block `k` at rows of free node `i` and columns of free node `j`,
    /// `j <= i`, `offset` the grid offset from `j` to `i`. For `i == j` only the lower
    /// triangle of `k` is read.
    #[inline(always)]
    pub fn add_block(&mut self, i: usize, j: usize, offset: [i32; 3], k: &Matrix3<f64>) {
        let pos = self.neighbour[j][offset_slot(offset)];
        debug_assert!(pos != NONE, "node {i} is not a neighbour of {j}");
        let pos = pos as usize;
        for c in 0..3 {
            let start = self.col_ptr[3 * j + c] as usize;
            if pos == 0 {
                debug_assert_eq!(i, j);
                for r in c..3 {
                    self.values[start + r - c] += k[(r, c)];
                }
            } else {
                let base = start + (3 - c) + 3 * (pos - 1);
                for r in 0..3 {
                    self.values[base + r] += k[(r, c)];
                }
            }
        }
    }

    /// Calls `f(i, j, slot, block)` for every stored block: the rows of node `i`, at
    /// offset `slot` from node `j` (`i >= j`), and the columns of `j`; the diagonal
    /// blocks whole.
    pub fn each_block(&self, mut f: impl FnMut(usize, usize, usize, &Matrix3<f64>)) {
        for (j, nb) in self.neighbour.iter().enumerate() {
            for (slot, &pos) in nb.iter().enumerate() {
                if pos == NONE {
                    continue;
                }
                let pos = pos as usize;
                let (mut k, mut i) = (Matrix3::zeros(), j);
                for c in 0..3 {
                    let start = self.col_ptr[3 * j + c] as usize;
                    if pos == 0 {
                        for r in c..3 {
                            k[(r, c)] = self.values[start + r - c];
                            k[(c, r)] = k[(r, c)];
                        }
                    } else {
                        let base = start + (3 - c) + 3 * (pos - 1);
                        i = self.row_idx[base] as usize / 3;
                        for r in 0..3 {
                            k[(r, c)] = self.values[base + r];
                        }
                    }
                }
                f(i, j, slot, &k);
            }
        }
    }

    /// Largest diagonal entry.
    pub fn max_diagonal(&self) -> f64 {
        self.diagonal
            .iter()
            .map(|&d| self.values[d])
            .fold(0.0, f64::max)
    }

    /// Factors the matrix; if that fails (a pivot lost to round-off), factors it again
    /// with a diagonal shift of `1e-8`, `1e-6`, ... of the largest diagonal entry, which
    /// still gives a descent direction. Small pivots (below `1e-12` of the largest diagonal entry) are
    /// replaced by `1e-8` of it, so a matrix that is only semi-definite still gives a
    /// descent direction.
    pub fn factor(&mut self) -> Result<(), NotPositiveDefinite> {
        let scale = self.max_diagonal().max(f64::MIN_POSITIVE);
        let mut shifted = 0.0;
        for k in 0..5 {
            if self.factor_once().is_ok() {
                self.add_diagonal(-shifted);
                return Ok(());
            }
            let next = scale * 10f64.powi(2 * k - 8);
            self.add_diagonal(next - shifted);
            shifted = next;
        }
        self.add_diagonal(-shifted);
        Err(NotPositiveDefinite)
    }

    fn add_diagonal(&mut self, shift: f64) {
        for &d in &self.diagonal {
            self.values[d] += shift;
        }
    }

    fn factor_once(&mut self) -> Result<(), NotPositiveDefinite> {
        let n = self.n;
        let a = SparseColMatRef::new(
            SymbolicSparseColMatRef::new_checked(n, n, &self.col_ptr, None, &self.row_idx),
            &self.values,
        );
        let scale = self.max_diagonal().max(f64::MIN_POSITIVE);
        let regularization = LltRegularization {
            dynamic_regularization_delta: 1e-8 * scale,
            dynamic_regularization_epsilon: 1e-12 * scale,
        };
        let mut mem = MemBuffer::new(
            self.symbolic
                .factorize_numeric_llt_scratch::<f64>(par(), Spec::default()),
        );
        self.symbolic
            .factorize_numeric_llt(
                &mut self.factor,
                a,
                Side::Lower,
                regularization,
                par(),
                MemStack::new(&mut mem),
                Spec::default(),
            )
            .map(|_| ())
            .map_err(|_| NotPositiveDefinite)?;
        self.factored = true;
        Ok(())
    }

    /// `y = K x` (the symmetric matrix from its lower triangle).
    #[cfg(test)]
    pub fn multiply(&self, x: &[f64], y: &mut [f64]) {
        y.fill(0.0);
        for col in 0..self.n {
            let (a, b) = (self.col_ptr[col] as usize, self.col_ptr[col + 1] as usize);
            let xc = x[col];
            let mut acc = 0.0;
            for k in a..b {
                let row = self.row_idx[k] as usize;
                let v = self.values[k];
                y[row] += v * xc;
                if row != col {
                    acc += v * x[row];
                }
            }
            y[col] += acc;
        }
    }

    /// Solves `K x = b`, `K` given by its product `multiply(x, y)` (`y = K x`), by
    /// conjugate gradients preconditioned with the last factorisation (of an earlier,
    /// nearby matrix), to a residual of `rtol |b|` in at most `max_iter` iterations. `x`
    /// gets the solution; returns whether it converged. `work` holds three vectors of
    /// scratch.
    pub fn solve_preconditioned(
        &self,
        b: &[f64],
        x: &mut [f64],
        rtol: f64,
        max_iter: usize,
        work: &mut [Vec<f64>; 3],
        multiply: impl FnMut(&[f64], &mut [f64]),
    ) -> (bool, usize) {
        conjugate_gradients(b, x, rtol, max_iter, work, multiply, |r, z| {
            z.copy_from_slice(r);
            self.solve(z);
        })
    }

    /// Solves `K X = B` in place with the last factorisation for the `B.len() / n`
    /// right-hand sides in `b`, as one block.
    pub fn solve_block(&self, b: &mut [f64]) {
        let n = self.n;
        let k = b.len() / n.max(1);
        let mut mem = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(k, Par::Seq));
        let rhs = MatMut::from_column_major_slice_mut(b, n, k);
        LltRef::new(&self.symbolic, &self.factor).solve_in_place_with_conj(
            Conj::No,
            rhs,
            Par::Seq,
            MemStack::new(&mut mem),
        );
    }

    /// Solves `K x = b` in place with the last factorisation (`b` of length `n`).
    pub fn solve(&self, b: &mut [f64]) {
        debug_assert_eq!(b.len(), self.n);
        self.solve_block(b);
    }
}

/// Solves `K x = b`, `K` given by its product `multiply(x, y)` (`y = K x`), by conjugate
/// gradients preconditioned with `precondition(r, z)` (`z = M^-1 r`, `M` symmetric
/// positive definite), from `x = 0` to a residual of `rtol |b|` in at most `max_iter`
/// iterations. `x` gets the last iterate (a descent direction of the quadratic model even
/// when it did not converge); returns whether it converged and the iterations taken.
/// `work` holds three vectors of scratch.
///
/// Newton's method keeps this one rather than faer's (which the optics fit uses,
/// `tacrom calibrate`): its product is the gel's matrix-free stiffness, a closure over the
/// solver's scratch summed node by node in a fixed order so that no sum depends on the
/// thread count (faer's operators are applied through `&self` and summed in faer's own
/// order), and an unconverged solve's last iterate is still the step's direction.
pub(crate) fn conjugate_gradients(
    b: &[f64],
    x: &mut [f64],
    rtol: f64,
    max_iter: usize,
    work: &mut [Vec<f64>; 3],
    mut multiply: impl FnMut(&[f64], &mut [f64]),
    mut precondition: impl FnMut(&[f64], &mut [f64]),
) -> (bool, usize) {
    let n = b.len();
    let [r, z, q] = work;
    r.resize(n, 0.0);
    z.resize(n, 0.0);
    q.resize(n, 0.0);
    x.fill(0.0);
    r.copy_from_slice(b);
    let target = rtol * dot(b, b).sqrt();
    precondition(r, z);
    let mut p = z.clone();
    let mut rz = dot(r, z);
    for k in 0..max_iter {
        multiply(&p, q);
        let pq = dot(&p, q);
        if !(pq > 0.0) {
            return (false, k);
        }
        let alpha = rz / pq;
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * q[i];
        }
        if dot(r, r).sqrt() <= target {
            return (true, k + 1);
        }
        precondition(r, z);
        let rz_new = dot(r, z);
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            p[i] = z[i] + beta * p[i];
        }
    }
    (false, max_iter)
}

pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
