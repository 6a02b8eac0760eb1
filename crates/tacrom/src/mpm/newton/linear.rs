//! Linear elasticity about the undeformed gel, with frictionless contact solved exactly
//! ([`super::super::Solver::Linear`]).
//!
//! # Model
//!
//! The gel's energy is replaced by its second-order expansion at rest, `u^T K u / 2`,
//! with `K` the Hessian of Newton's discretisation at `u = 0` (the same quadrature points,
//! and the same selective reduced integration at high Poisson's ratios): the small-strain
//! elasticity of the gel as bonded and meshed. The indenters load it through vertical
//! forces `f_q >= 0` at the top slots (the surface points of the particle lattice, as the
//! relaxation's contact), so the surface displacement is linear in them:
//! `u_p = sum_q f_q r_q(p)`, with `r_q` the surface's response to a unit downward force at
//! `q` (a column of the surface compliance).
//!
//! # Contact
//!
//! Non-penetration `phi(X_p + u_p) >= 0` (`phi` the smallest signed distance to an
//! indenter) at every slot, linearised in the vertical sinking `s_p = -u_p.z` about the
//! current surface: `s_p >= delta_p = s_p0 - phi(X_p + u_p0) / |n_z|`, with `n` the
//! indenter's outward normal there (`|n_z|` at least [`MIN_SLOPE`]). With
//! `C_pq = -r_q(p).z`, symmetric and positive definite (Maxwell-Betti reciprocity), that
//! is the linear complementarity problem `f >= 0, C f - delta >= 0, f . (C f - delta) = 0`,
//! the minimum of the complementary energy `f^T C f / 2 - f^T delta` over `f >= 0`. It is
//! solved exactly by block principal pivoting (Judice and Pires 1994; Murty's single
//! pivots where the blocks stop reducing the infeasibilities, which ends for every
//! positive definite `C`) over the slots that may touch, and the linearisation repeated
//! from the new surface until no slot penetrates an indenter by more than the tolerance
//! times the deepest sinking.
//!
//! # Cost
//!
//! `K` is factored once per gel (faer); the column `r_q` costs one solve with the factor,
//! taken the first time slot `q` carries a force, and kept. A frame then costs a dense
//! solve over its contact slots and the sum of their columns over the surface: no pass
//! over the particles or the grid.
//!
//! # What it leaves out
//!
//! * Large deformation: rotations and stretches enter to first order only, so forces
//!   drift from the nonlinear solvers' as the strain under the indenter grows (`tacrom
//!   mpm --solver linear,relaxation` measures by how much).
//! * Friction: the contact carries normal (vertical) forces only, so a sliding indenter
//!   drags nothing and the surface shears only through Poisson's effect.
//! * History: the answer depends on the current poses alone, not on the path to them.

use std::collections::HashMap;

use nalgebra::{DMatrix, DVector, Vector3};
use rayon::prelude::*;

use super::super::contact::StepIndenter;
use super::super::indenters::Sweep;
use super::super::{
    pressure::ContactLoad, Gel, Linear as LinearSolve, SolveReport, LINEAR_UNKNOWNS,
};
use super::system::System;
use super::{contains, Newton, Stencil, PENALTY};

/// Steps at most of a march along the vertical ([`Compliance::vertical_gap`]), the
/// smallest step (cells) down through an indenter, the bisections of the way out, and the
/// distance (cells) at which a march up has met the surface.
const MARCH_STEPS: usize = 200;
const MIN_MARCH: f64 = 0.02;
const BISECTIONS: usize = 30;
const GAP_EPS: f64 = 1e-6;

/// Linearisations at most per solve.
const MAX_PASSES: usize = 12;

/// Columns computed per batch of solves (bounds the scratch to `n` times this).
const COLUMN_BATCH: usize = 64;

/// Node columns a batch is filled up to with those likely needed next.
const COLUMN_PREFETCH: usize = 64;

/// Slots that may touch: those whose required sinking exceeds minus this fraction of the
/// deepest required sinking (the surface around a contact can rise towards an indenter).
const CANDIDATE_FRACTION: f64 = 0.5;

/// The linear solver's state for one gel.
///
/// Every top slot lies at the same height, so its stencil is the product of its in-plane
/// weights over a 3 x 3 block of node columns and the same three vertical weights: a
/// slot's load is a combination of nine *column loads* (a unit downward force spread over
/// one node column by the vertical weights), and its displacement the same combination of
/// the columns' mean displacements. The compliance is kept per node column: the response
/// of every column to a column load, about a third as many solves as slots and shared by
/// neighbouring slots.
#[derive(Clone)]
pub(crate) struct Compliance {
    system: System,
    /// Penetration (cells) per internal force unit a slot's contact allows: Newton's
    /// penalty over the slot's share of the top face.
    softness: f64,
    dx: f64,
    origin: Vector3<f64>,
    /// Rest position (cells) of each top slot.
    rest: Vec<Vector3<f64>>,
    /// Per slot: its nine node columns (`ix * ny + iy`) and in-plane weights.
    slots: Vec<[(u32, f64); 9]>,
    /// Per node column, per level of the slots' vertical stencil: the first unknown of
    /// the node (`u32::MAX`: fixed), and the three vertical weights.
    levels: Vec<[u32; 3]>,
    weights: [f64; 3],
    /// The response (3 per node column, cells per internal force unit) of every node
    /// column to each column load computed so far, in single precision (7 digits, for a
    /// contact solved to the tolerance's 3).
    columns: HashMap<u32, Box<[f32]>>,
    /// Slots that carried a force in the last solve (where the next one starts).
    last_active: Vec<u32>,
}

/// One solve's answer.
pub(crate) struct Contact {
    /// Slots carrying a force, and their forces (internal units, downward on the gel).
    pub slots: Vec<u32>,
    pub forces: Vec<f64>,
    /// Displacement (cells) of every slot.
    pub surface: Vec<Vector3<f64>>,
    /// Largest penetration left (cells) and linearisations taken.
    pub penetration: f64,
    pub passes: usize,
    /// Whether the penetration left is within the tolerance.
    pub converged: bool,
}

impl Compliance {
    /// The stiffness of `gel` at rest, factored, and its top slots.
    pub fn new(gel: &Gel) -> Result<Compliance, String> {
        let mut newton = Newton::new(gel)?;
        if newton.u.len() > LINEAR_UNKNOWNS {
            return Err(format!(
                "the grid has {} unknowns, more than the {LINEAR_UNKNOWNS} the linear solver \
                 factors; use a larger dx",
                newton.u.len()
            ));
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
        let rest: Vec<Vector3<f64>> = gel.top_ref.iter().map(|r| r.cast::<f64>()).collect();
        let [_, ny, nz] = newton.dims;
        let first = Stencil::at(rest.first().ok_or("the gel has no top slots")?);
        let slots = rest
            .iter()
            .map(|x| {
                let s = Stencil::at(x);
                std::array::from_fn(|l| {
                    let (i, j) = (l / 3, l % 3);
                    let (ix, iy) = (s.base[0] + i as i32, s.base[1] + j as i32);
                    (
                        (ix as usize * ny + iy as usize) as u32,
                        s.w[0][i] * s.w[1][j],
                    )
                })
            })
            .collect();
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
        let area = gel.layout.spacing[0] * gel.layout.spacing[1] / (newton.dx * newton.dx);
        Ok(Compliance {
            system,
            softness: 1.0 / (PENALTY * area),
            dx: newton.dx,
            origin: newton.origin,
            rest,
            slots,
            levels,
            weights: first.w[2],
            columns: HashMap::new(),
            last_active: Vec::new(),
        })
    }

    /// Node columns whose response has been computed.
    pub fn columns(&self) -> usize {
        self.columns.len()
    }

    /// Computes the responses to the node columns of `slots` not computed yet and, where
    /// some are missing, to those of `likely` too, up to [`COLUMN_PREFETCH`] in all: a
    /// batch of solves costs little more than one, since each reads the whole factor.
    fn ensure(&mut self, slots: impl IntoIterator<Item = u32>, likely: &[u32]) {
        let mut missing: Vec<u32> = slots
            .into_iter()
            .flat_map(|p| self.slots[p as usize].map(|(c, _)| c))
            .filter(|c| !self.columns.contains_key(c))
            .collect();
        missing.sort_unstable();
        missing.dedup();
        if missing.is_empty() {
            return;
        }
        for &p in likely {
            for (c, _) in self.slots[p as usize] {
                if missing.len() < COLUMN_PREFETCH
                    && !self.columns.contains_key(&c)
                    && !missing.contains(&c)
                {
                    missing.push(c);
                }
            }
        }
        let n = self.system.n;
        for batch in missing.chunks(COLUMN_BATCH) {
            let mut b = vec![0.0; n * batch.len()];
            for (rhs, &c) in b.chunks_exact_mut(n).zip(batch) {
                for (&d, &w) in self.levels[c as usize].iter().zip(&self.weights) {
                    if d != u32::MAX {
                        rhs[3 * d as usize + 2] -= w;
                    }
                }
            }
            self.system.solve_columns(&mut b);
            let columns: Vec<Box<[f32]>> = b
                .par_chunks_exact(n)
                .map(|x| {
                    let mut r = Vec::with_capacity(3 * self.levels.len());
                    for level in &self.levels {
                        let mut u = [0.0; 3];
                        for (&d, &w) in level.iter().zip(&self.weights) {
                            if d != u32::MAX {
                                for (k, u) in u.iter_mut().enumerate() {
                                    *u += w * x[3 * d as usize + k];
                                }
                            }
                        }
                        r.extend(u.map(|v| v as f32));
                    }
                    r.into_boxed_slice()
                })
                .collect();
            for (&c, r) in batch.iter().zip(columns) {
                self.columns.insert(c, r);
            }
        }
    }

    /// The column loads of downward forces `forces` at `slots`.
    fn column_loads(&self, slots: &[u32], forces: &[f64]) -> Vec<(u32, f64)> {
        let mut loads: Vec<(u32, f64)> = slots
            .iter()
            .zip(forces)
            .flat_map(|(&p, &f)| self.slots[p as usize].map(|(c, w)| (c, w * f)))
            .collect();
        loads.sort_by_key(|&(c, _)| c);
        loads.dedup_by(|b, a| {
            if a.0 == b.0 {
                a.1 += b.1;
                true
            } else {
                false
            }
        });
        loads
    }

    /// The mean displacement (cells) of every node column under column loads `loads`
    /// (computed), 3 per column.
    fn column_displacements(&self, loads: &[(u32, f64)]) -> Vec<f64> {
        let mut u = vec![0.0; 3 * self.levels.len()];
        for &(c, f) in loads {
            for (u, &r) in u.iter_mut().zip(self.columns[&c].iter()) {
                *u += f * r as f64;
            }
        }
        u
    }

    /// Displacement (cells) of slot `p` from the columns' mean displacements `columns`.
    fn slot_displacement(&self, p: usize, columns: &[f64]) -> Vector3<f64> {
        let mut u = Vector3::zeros();
        for (c, w) in self.slots[p] {
            let c = 3 * c as usize;
            u += Vector3::new(columns[c], columns[c + 1], columns[c + 2]) * w;
        }
        u
    }

    /// The sinking (cells) of the node columns under a unit downward force at slot `q`
    /// (its columns computed).
    fn slot_sinking(&self, q: u32) -> Vec<f64> {
        let mut s = vec![0.0; self.levels.len()];
        for (c, w) in self.slots[q as usize] {
            for (s, r) in s.iter_mut().zip(self.columns[&c].chunks_exact(3)) {
                *s -= w * r[2] as f64;
            }
        }
        s
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
    /// down it must move to leave them); `None` where nothing lies above it. Marched by
    /// the signed distance, which never overshoots an exact distance's surface, and the
    /// way out from inside bisected.
    fn vertical_gap(&self, x: &Vector3<f64>, indenters: &[StepIndenter]) -> Option<f64> {
        let at = |t: f64| self.clearance(&(x + Vector3::z() * t), indenters);
        let mut phi = at(0.0);
        if phi < 0.0 {
            let (mut inside, mut t) = (0.0, 0.0);
            for _ in 0..MARCH_STEPS {
                t += (-phi).max(MIN_MARCH);
                phi = at(-t);
                if phi >= 0.0 {
                    let mut outside = t;
                    for _ in 0..BISECTIONS {
                        let mid = 0.5 * (inside + outside);
                        if at(-mid) < 0.0 {
                            inside = mid;
                        } else {
                            outside = mid;
                        }
                    }
                    return Some(-0.5 * (inside + outside));
                }
                inside = t;
            }
            return Some(-t);
        }
        let mut t = 0.0;
        for _ in 0..MARCH_STEPS {
            if !phi.is_finite() {
                return None;
            }
            if phi <= GAP_EPS {
                return Some(t);
            }
            t += phi;
            phi = at(t);
        }
        phi.is_finite().then_some(t)
    }

    /// The frictionless contact of the gel's surface with `indenters`, to a penetration of
    /// at most `tolerance` times the deepest sinking.
    pub fn contact(&mut self, indenters: &[StepIndenter], tolerance: f64) -> Contact {
        // Slots under an indenter's bounds: the only ones that can touch it.
        let near: Vec<u32> = (0..self.rest.len() as u32)
            .filter(|&p| {
                let x = self.origin + self.rest[p as usize] * self.dx;
                indenters.iter().any(|ind| {
                    let (lo, hi) = (ind.bounds.min, ind.bounds.max);
                    x.x >= lo.x && x.x <= hi.x && x.y >= lo.y && x.y <= hi.y
                })
            })
            .collect();
        let mut free: Vec<bool> = vec![false; near.len()];
        for (i, p) in near.iter().enumerate() {
            free[i] = self.last_active.binary_search(p).is_ok();
        }
        let mut forces = vec![0.0; near.len()];
        let mut u: Vec<Vector3<f64>> = vec![Vector3::zeros(); near.len()];
        let (mut passes, mut iterations) = (0, 0);
        let mut penetration = 0.0;
        let mut converged = false;
        let mut delta = vec![f64::NEG_INFINITY; near.len()];
        for pass in 0..MAX_PASSES {
            passes = pass + 1;
            // Each slot's constraint about the current surface: the sinking that brings it
            // to the indenters' lower surface above (or below) it. Inside an indenter
            // first; outside, only within the candidates' reach of it (the gap is at
            // least the distance).
            let points: Vec<Vector3<f64>> = near
                .iter()
                .zip(&u)
                .map(|(&p, v)| self.rest[p as usize] + v)
                .collect();
            let clear: Vec<f64> = points
                .iter()
                .map(|x| self.clearance(x, indenters))
                .collect();
            for i in 0..near.len() {
                delta[i] = if clear[i] < 0.0 {
                    self.vertical_gap(&points[i], indenters)
                        .map_or(f64::NEG_INFINITY, |h| -u[i].z - h)
                } else {
                    f64::NEG_INFINITY
                };
            }
            let deepest = delta.iter().copied().fold(0.0, f64::max);
            let reach = CANDIDATE_FRACTION * deepest;
            for i in 0..near.len() {
                if clear[i] >= 0.0 && clear[i] < reach {
                    delta[i] = self
                        .vertical_gap(&points[i], indenters)
                        .map_or(f64::NEG_INFINITY, |h| -u[i].z - h);
                }
            }
            if deepest <= 0.0 && forces.iter().all(|&f| f == 0.0) {
                converged = true;
                penetration = 0.0;
                break;
            }
            let cand: Vec<usize> = (0..near.len())
                .filter(|&i| delta[i] > -CANDIDATE_FRACTION * deepest || forces[i] > 0.0)
                .collect();
            let d: Vec<f64> = cand.iter().map(|&i| delta[i]).collect();
            // The candidates most deeply pressed first: the likeliest to carry a force.
            let mut likely: Vec<usize> = (0..cand.len()).collect();
            likely.sort_by(|&a, &b| d[b].total_cmp(&d[a]));
            let likely: Vec<u32> = likely.into_iter().map(|j| near[cand[j]]).collect();
            let mut cand_free: Vec<bool> = cand.iter().map(|&i| free[i]).collect();
            let solved = {
                let near = &near;
                let this = &mut *self;
                // Each free slot's sinking at every candidate, built once per pass.
                let mut sinkings: HashMap<usize, Vec<f64>> = HashMap::new();
                complementarity(&d, &mut cand_free, &mut iterations, |rows, cols| {
                    this.ensure(cols.iter().map(|&j| near[cand[j]]), &likely);
                    for &j in cols {
                        sinkings.entry(j).or_insert_with(|| {
                            let s = this.slot_sinking(near[cand[j]]);
                            cand.iter()
                                .map(|&i| {
                                    this.slots[near[i] as usize]
                                        .iter()
                                        .map(|&(c, w)| w * s[c as usize])
                                        .sum()
                                })
                                .collect()
                        });
                    }
                    DMatrix::from_fn(rows.len(), cols.len(), |a, b| {
                        let soft = if rows[a] == cols[b] {
                            this.softness
                        } else {
                            0.0
                        };
                        soft + sinkings[&cols[b]][rows[a]]
                    })
                })
            };
            let Some(f) = solved else {
                break;
            };
            forces.fill(0.0);
            free.fill(false);
            for ((&i, &fi), &fr) in cand.iter().zip(&f).zip(&cand_free) {
                forces[i] = fi;
                free[i] = fr;
            }
            let (slots, loads): (Vec<u32>, Vec<f64>) = near
                .iter()
                .zip(&forces)
                .filter(|(_, &f)| f > 0.0)
                .map(|(&p, &f)| (p, f))
                .unzip();
            let columns = self.column_displacements(&self.column_loads(&slots, &loads));
            for (i, &p) in near.iter().enumerate() {
                u[i] = self.slot_displacement(p as usize, &columns);
            }
            let sinking = u.iter().map(|v| -v.z).fold(0.0, f64::max);
            // The penetration beyond what the contact's own compliance allows.
            penetration = near
                .iter()
                .zip(&u)
                .zip(&forces)
                .filter_map(|((&p, v), &f)| {
                    let x = self.rest[p as usize] + v;
                    if self.clearance(&x, indenters) >= 0.0 {
                        return None;
                    }
                    Some(-self.vertical_gap(&x, indenters)? - self.softness * f)
                })
                .fold(0.0, f64::max);
            if penetration <= tolerance * sinking.max(1e-6) {
                converged = true;
                break;
            }
        }
        let (slots, forces): (Vec<u32>, Vec<f64>) = near
            .iter()
            .zip(&forces)
            .filter(|(_, &f)| f > 0.0)
            .map(|(&p, &f)| (p, f))
            .unzip();
        let columns = self.column_displacements(&self.column_loads(&slots, &forces));
        let surface = (0..self.rest.len())
            .map(|p| self.slot_displacement(p, &columns))
            .collect();
        self.last_active = slots.clone();
        Contact {
            slots,
            forces,
            surface,
            penetration,
            passes,
            converged,
        }
    }
}

/// Projected Newton iterations at most.
const MAX_NEWTON: usize = 60;

/// Line search halvings at most per iteration.
const MAX_HALVINGS: usize = 40;

/// Solves the linear complementarity problem `f >= 0, w = H f - d >= 0, f . w = 0` for a
/// symmetric positive definite `H` (its blocks given by `block(rows, cols)`): the minimum
/// of `f^T H f / 2 - d^T f` over `f >= 0`, by Bertsekas' projected Newton method (1982):
/// the unknowns at (or within a shrinking margin of) zero whose gradient pushes them down
/// are held, a Newton step is taken on the rest, and a projected Armijo search keeps the
/// energy decreasing, so it cannot cycle; once the held set is the answer's, one step
/// solves it exactly. Starts from the Newton step on the free set `free` (updated to the
/// answer's) and counts the iterations in `iterations`. Blocks are asked for only with
/// columns that carry a force or may take one. `None` if a block is not positive
/// definite or the iterations run out.
fn complementarity(
    d: &[f64],
    free: &mut [bool],
    iterations: &mut usize,
    mut block: impl FnMut(&[usize], &[usize]) -> DMatrix<f64>,
) -> Option<Vec<f64>> {
    let m = d.len();
    let all: Vec<usize> = (0..m).collect();
    let scale = d.iter().fold(0.0f64, |a, &v| a.max(v.abs()));
    if scale == 0.0 {
        free.fill(false);
        return Some(vec![0.0; m]);
    }
    // The gradient `H f - d` (from the columns where `f > 0`) and the energy.
    let gradient = |f: &[f64], block: &mut dyn FnMut(&[usize], &[usize]) -> DMatrix<f64>| {
        let support: Vec<usize> = (0..m).filter(|&i| f[i] > 0.0).collect();
        let mut g: Vec<f64> = d.iter().map(|v| -v).collect();
        if !support.is_empty() {
            let h = block(&all, &support);
            for (c, &j) in support.iter().enumerate() {
                for (i, g) in g.iter_mut().enumerate() {
                    *g += h[(i, c)] * f[j];
                }
            }
        }
        g
    };
    let energy = |f: &[f64], g: &[f64]| -> f64 {
        f.iter()
            .zip(g)
            .zip(d)
            .map(|((f, g), d)| 0.5 * f * (g - d))
            .sum()
    };
    let mut f = vec![0.0; m];
    let start: Vec<usize> = (0..m).filter(|&i| free[i]).collect();
    if !start.is_empty() {
        let h = block(&start, &start);
        let b = DVector::from_iterator(start.len(), start.iter().map(|&i| d[i]));
        let x = h.cholesky()?.solve(&b);
        for (&i, &v) in start.iter().zip(x.iter()) {
            f[i] = v.max(0.0);
        }
    }
    let mut g = gradient(&f, &mut block);
    let mut e = energy(&f, &g);
    for _ in 0..MAX_NEWTON {
        // Optimality: the projected gradient vanishes.
        let projected = (0..m)
            .map(|i| {
                if f[i] > 0.0 {
                    g[i].abs()
                } else {
                    (-g[i]).max(0.0)
                }
            })
            .fold(0.0, f64::max);
        if projected <= 1e-12 * scale {
            break;
        }
        *iterations += 1;
        let margin = (0..m)
            .map(|i| (f[i] - (f[i] - g[i]).max(0.0)).abs())
            .fold(0.0, f64::max)
            .min(1e-3 * scale);
        let held: Vec<bool> = (0..m).map(|i| f[i] <= margin && g[i] > 0.0).collect();
        let set: Vec<usize> = (0..m).filter(|&i| !held[i]).collect();
        let mut step = vec![0.0; m];
        if !set.is_empty() {
            let h = block(&set, &set);
            let b = DVector::from_iterator(set.len(), set.iter().map(|&i| -g[i]));
            let x = h.cholesky()?.solve(&b);
            for (&i, &v) in set.iter().zip(x.iter()) {
                step[i] = v;
            }
        }
        // Held unknowns that carry a force go down their gradient, scaled by the
        // diagonal (1 where they carry none: they stay at zero).
        let held_moving: Vec<usize> = (0..m).filter(|&i| held[i] && f[i] > 0.0).collect();
        if !held_moving.is_empty() {
            let h = block(&held_moving, &held_moving);
            for (k, &i) in held_moving.iter().enumerate() {
                step[i] = -g[i] / h[(k, k)];
            }
        }
        let mut alpha = 1.0;
        let mut accepted = false;
        for _ in 0..MAX_HALVINGS {
            let trial: Vec<f64> = (0..m).map(|i| (f[i] + alpha * step[i]).max(0.0)).collect();
            let decrease: f64 = (0..m)
                .map(|i| {
                    if held[i] {
                        g[i] * (f[i] - trial[i])
                    } else {
                        -alpha * g[i] * step[i]
                    }
                })
                .sum();
            let gt = gradient(&trial, &mut block);
            let et = energy(&trial, &gt);
            if et <= e - 1e-4 * decrease {
                (f, g, e) = (trial, gt, et);
                accepted = true;
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            // No decrease left to find: round-off bounds the energy.
            break;
        }
    }
    let projected = (0..m)
        .map(|i| {
            if f[i] > 0.0 {
                g[i].abs()
            } else {
                (-g[i]).max(0.0)
            }
        })
        .fold(0.0, f64::max);
    if projected > 1e-9 * scale {
        return None;
    }
    for (fr, &v) in free.iter_mut().zip(&f) {
        *fr = v > 0.0;
    }
    Some(f)
}

impl Gel {
    /// The linear solver's frame: the frictionless contact of the small-strain gel with
    /// the indenters at the end of `sweep`.
    pub(in crate::mpm) fn solve_linear(&mut self, sweep: &Sweep, report: &mut SolveReport) {
        let dx = self.layout.dx;
        let mut placed = Vec::new();
        sweep.place(sweep.steps.max(1) - 1, dx, &mut placed);
        let touches = self.top_ref.iter().any(|r| {
            let x = nalgebra::Point3::from(self.layout.origin + r.cast::<f64>() * dx);
            placed.iter().any(|ind| {
                contains(&ind.bounds, &x)
                    && ind.shape.distance(&ind.now.inverse_transform_point(&x)) < 0.0
            })
        });
        if !touches {
            // No slot inside an indenter: the undeformed gel is the answer.
            if let Some(linear) = self.linear.as_mut() {
                linear.last_active.clear();
            }
            self.force = Vector3::zeros();
            self.loads.clear();
            self.set_surface(|_| Vector3::zeros());
            return;
        }
        if self.linear.is_none() {
            match Compliance::new(self) {
                Ok(c) => {
                    self.linear = Some(Box::new(c));
                    report.factorisations = 1;
                }
                Err(_) => {
                    report.converged = false;
                    report.residual = f64::INFINITY;
                    return;
                }
            }
        }
        let mut linear = self.linear.take().expect("built above");
        let before = linear.columns();
        let contact = linear.contact(&placed, self.options.tolerance);
        report.columns = linear.columns() - before;
        report.iterations = contact.passes;
        report.sweep_steps = 1;
        report.active_particles = contact.slots.len();
        report.converged = contact.converged;
        let sinking = contact.surface.iter().map(|v| -v.z).fold(0.0, f64::max);
        report.residual = if sinking > 0.0 {
            contact.penetration / sinking
        } else {
            0.0
        };
        let scale = self.modulus * dx * dx;
        let total: f64 = contact.forces.iter().sum();
        self.force = Vector3::new(0.0, 0.0, total * scale);
        self.loads = contact
            .slots
            .iter()
            .zip(&contact.forces)
            .map(|(&p, &f)| {
                let x = self.layout.origin
                    + (linear.rest[p as usize] + contact.surface[p as usize]) * dx;
                ContactLoad {
                    at: [x.x, x.y],
                    z: x.z,
                    force: Vector3::new(0.0, 0.0, f * scale),
                }
            })
            .collect();
        self.set_surface(|slot| contact.surface[slot] * dx);
        self.linear = Some(linear);
    }
}

#[cfg(test)]
#[path = "linear_tests.rs"]
mod tests;
