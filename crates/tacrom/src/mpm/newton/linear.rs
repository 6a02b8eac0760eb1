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

/// Smallest `|n_z|` a slot's constraint is linearised with: where an indenter's side is
/// steeper, vertical sinking frees the slot only slowly, and the next pass corrects it.
const MIN_SLOPE: f64 = 0.3;

/// Linearisations at most per solve.
const MAX_PASSES: usize = 12;

/// Columns computed per batch of solves (bounds the scratch to `n` times this).
const COLUMN_BATCH: usize = 64;

/// Columns a batch is filled up to with those likely needed next.
const COLUMN_PREFETCH: usize = 16;

/// Slots that may touch: those whose required sinking exceeds minus this fraction of the
/// deepest required sinking (the surface around a contact can rise towards an indenter).
const CANDIDATE_FRACTION: f64 = 0.5;

/// The linear solver's state for one gel.
#[derive(Clone)]
pub(crate) struct Compliance {
    system: System,
    dx: f64,
    origin: Vector3<f64>,
    /// Penetration (cells) per internal force unit a slot's contact allows: Newton's
    /// penalty over the slot's share of the top face.
    softness: f64,
    /// Rest position (cells) of each top slot.
    rest: Vec<Vector3<f64>>,
    /// Per slot: the unknowns (first of three; `u32::MAX`: fixed) and weights of its stencil.
    stencils: Vec<([u32; 27], [f64; 27])>,
    /// The surface's response (3 per slot, cells per internal force unit) to a unit
    /// downward force at each slot computed so far.
    columns: HashMap<u32, Box<[f64]>>,
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
        let stencils = rest
            .iter()
            .map(|x| {
                let s = Stencil::at(x);
                let mut dofs = [u32::MAX; 27];
                let mut w = [0.0; 27];
                for l in 0..27 {
                    if let Some(d) = newton.dof_at(&s.base, l) {
                        (dofs[l], w[l]) = (d as u32, s.weight(l));
                    }
                }
                (dofs, w)
            })
            .collect();
        let area = gel.layout.spacing[0] * gel.layout.spacing[1] / (newton.dx * newton.dx);
        Ok(Compliance {
            system,
            softness: 1.0 / (PENALTY * area),
            dx: newton.dx,
            origin: newton.origin,
            rest,
            stencils,
            columns: HashMap::new(),
            last_active: Vec::new(),
        })
    }

    /// Columns computed so far.
    pub fn columns(&self) -> usize {
        self.columns.len()
    }

    /// Computes the columns of `slots` not computed yet and, where some are missing, those
    /// of the first of `likely` too, up to [`COLUMN_PREFETCH`] in all: a batch of solves
    /// costs little more than one, since each reads the whole factor.
    fn ensure(&mut self, slots: impl IntoIterator<Item = u32>, likely: &[u32]) {
        let mut missing: Vec<u32> = slots
            .into_iter()
            .filter(|q| !self.columns.contains_key(q))
            .collect();
        missing.sort_unstable();
        missing.dedup();
        if missing.is_empty() {
            return;
        }
        for &q in likely {
            if missing.len() >= COLUMN_PREFETCH {
                break;
            }
            if !self.columns.contains_key(&q) && !missing.contains(&q) {
                missing.push(q);
            }
        }
        let n = self.system.n;
        for batch in missing.chunks(COLUMN_BATCH) {
            let mut b = vec![0.0; n * batch.len()];
            for (rhs, &q) in b.chunks_exact_mut(n).zip(batch) {
                let (dofs, w) = &self.stencils[q as usize];
                for (&d, &w) in dofs.iter().zip(w) {
                    if d != u32::MAX {
                        rhs[3 * d as usize + 2] -= w;
                    }
                }
            }
            self.system.solve_columns(&mut b);
            let columns: Vec<Box<[f64]>> = b
                .par_chunks_exact(n)
                .map(|x| {
                    let mut r = Vec::with_capacity(3 * self.stencils.len());
                    for (dofs, w) in &self.stencils {
                        let mut u = [0.0; 3];
                        for (&d, &w) in dofs.iter().zip(w) {
                            if d != u32::MAX {
                                for (k, u) in u.iter_mut().enumerate() {
                                    *u += w * x[3 * d as usize + k];
                                }
                            }
                        }
                        r.extend_from_slice(&u);
                    }
                    r.into_boxed_slice()
                })
                .collect();
            for (&q, c) in batch.iter().zip(columns) {
                self.columns.insert(q, c);
            }
        }
    }

    /// Displacement (cells) of slot `p` under the forces `forces` at `slots`.
    fn displacement(&self, p: usize, slots: &[u32], forces: &[f64]) -> Vector3<f64> {
        let mut u = Vector3::zeros();
        for (q, f) in slots.iter().zip(forces) {
            let c = &self.columns[q][3 * p..3 * p + 3];
            u += Vector3::new(c[0], c[1], c[2]) * *f;
        }
        u
    }

    /// The smallest signed distance (cells) from the point at `x` (cells) to an indenter
    /// whose bounds hold it, with that indenter's outward normal there.
    fn nearest(&self, x: &Vector3<f64>, indenters: &[StepIndenter]) -> Option<(f64, Vector3<f64>)> {
        let p = nalgebra::Point3::from(self.origin + x * self.dx);
        let mut best: Option<(f64, Vector3<f64>)> = None;
        for ind in indenters.iter().filter(|ind| contains(&ind.bounds, &p)) {
            let (dist, slope) = ind
                .shape
                .distance_and_slope(&ind.now.inverse_transform_point(&p));
            let dist = dist / self.dx;
            let slope = ind.now.rotation * slope;
            let length = slope.norm();
            if !(dist.is_finite() && length > 1e-12 && length.is_finite()) {
                continue;
            }
            if best.map_or(true, |(d, _)| dist < d) {
                best = Some((dist, slope / length));
            }
        }
        best
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
        let (mut passes, mut pivots) = (0, 0);
        let mut penetration = 0.0;
        let mut converged = false;
        let mut delta = vec![f64::NEG_INFINITY; near.len()];
        for pass in 0..MAX_PASSES {
            passes = pass + 1;
            // Linearise each slot's constraint about the current surface.
            for (i, &p) in near.iter().enumerate() {
                let x = self.rest[p as usize] + u[i];
                delta[i] = match self.nearest(&x, indenters) {
                    Some((phi, n)) => -u[i].z - phi / (-n.z).max(MIN_SLOPE),
                    None => f64::NEG_INFINITY,
                };
            }
            let deepest = delta.iter().copied().fold(0.0, f64::max);
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
                complementarity(&d, &mut cand_free, &mut pivots, |rows, cols| {
                    this.ensure(cols.iter().map(|&j| near[cand[j]]), &likely);
                    DMatrix::from_fn(rows.len(), cols.len(), |a, b| {
                        let column = &this.columns[&near[cand[cols[b]]]];
                        let soft = if rows[a] == cols[b] {
                            this.softness
                        } else {
                            0.0
                        };
                        soft - column[3 * near[cand[rows[a]]] as usize + 2]
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
            for (i, &p) in near.iter().enumerate() {
                u[i] = self.displacement(p as usize, &slots, &loads);
            }
            let sinking = u.iter().map(|v| -v.z).fold(0.0, f64::max);
            // The penetration beyond what the contact's own compliance allows.
            penetration = near
                .iter()
                .zip(&u)
                .zip(&forces)
                .filter_map(|((&p, v), &f)| {
                    let (phi, n) = self.nearest(&(self.rest[p as usize] + v), indenters)?;
                    Some(-phi - self.softness * f * (-n.z).max(MIN_SLOPE))
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
        let surface = (0..self.rest.len())
            .into_par_iter()
            .map(|p| self.displacement(p, &slots, &forces))
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

/// Block principal pivots at most, per unknown.
const PIVOTS_PER_UNKNOWN: usize = 10;

/// Solves the linear complementarity problem `f >= 0, w = C f - d >= 0, f . w = 0` for a
/// symmetric positive definite `C` (its blocks given by `block(rows, cols)`) by block
/// principal pivoting from the free set `free` (updated to the answer's), counting the
/// pivots in `pivots`. `None` if a block of `C` is not positive definite or the pivots run
/// out.
fn complementarity(
    d: &[f64],
    free: &mut [bool],
    pivots: &mut usize,
    mut block: impl FnMut(&[usize], &[usize]) -> DMatrix<f64>,
) -> Option<Vec<f64>> {
    let m = d.len();
    let scale = d
        .iter()
        .fold(0.0f64, |a, &v| a.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    let (mut best, mut budget) = (m + 1, 3);
    for _ in 0..PIVOTS_PER_UNKNOWN * m + 10 {
        let f_set: Vec<usize> = (0..m).filter(|&i| free[i]).collect();
        let g_set: Vec<usize> = (0..m).filter(|&i| !free[i]).collect();
        let mut f = vec![0.0; m];
        if !f_set.is_empty() {
            let cff = block(&f_set, &f_set);
            let rhs = DVector::from_iterator(f_set.len(), f_set.iter().map(|&i| d[i]));
            let sol = cff.cholesky()?.solve(&rhs);
            for (&i, &v) in f_set.iter().zip(sol.iter()) {
                f[i] = v;
            }
        }
        let w_g: Vec<f64> = if f_set.is_empty() || g_set.is_empty() {
            g_set.iter().map(|&i| -d[i]).collect()
        } else {
            let cgf = block(&g_set, &f_set);
            let ff = DVector::from_iterator(f_set.len(), f_set.iter().map(|&i| f[i]));
            let w = cgf * ff;
            g_set
                .iter()
                .zip(w.iter())
                .map(|(&i, &w)| w - d[i])
                .collect()
        };
        let fmax = f.iter().fold(0.0f64, |a, &v| a.max(v.abs()));
        let mut bad: Vec<usize> = f_set
            .iter()
            .copied()
            .filter(|&i| f[i] < -1e-12 * fmax)
            .collect();
        bad.extend(
            g_set
                .iter()
                .zip(&w_g)
                .filter(|(_, &w)| w < -1e-12 * scale)
                .map(|(&i, _)| i),
        );
        if bad.is_empty() {
            for v in &mut f {
                *v = v.max(0.0);
            }
            return Some(f);
        }
        *pivots += 1;
        if bad.len() < best {
            (best, budget) = (bad.len(), 3);
        } else if budget > 0 {
            budget -= 1;
        } else {
            // Murty's rule: flip the largest infeasible index alone.
            bad = vec![*bad.iter().max().expect("not empty")];
        }
        for i in bad {
            free[i] = !free[i];
        }
    }
    None
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
