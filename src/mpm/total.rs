//! Total-Lagrangian dynamic relaxation ([`Solver::Total`], experimental).
//!
//! The relaxation of `relax.rs` is updated-Lagrangian: each particle advances its own `F`
//! by the grid's velocity gradient, so a converged state's `F` keeps a memory of the path
//! the explicit steps took, and its equilibrium depends on that path (docs/solvers.md, "What the
//! relaxation's answer depends on"). Here the unknowns are the grid nodes' displacements
//! `u_i` from the undeformed gel, and every particle is a fixed quadrature point at its
//! rest position `X_p`:
//!
//! * `F_p = I + 4 sum_i w_ip u_i (X_i - X_p)^T` (cells; the MLS gradient of the weights,
//!   as the updated-Lagrangian step uses), `x_p = X_p + sum_i w_ip u_i`;
//! * nodal force `f_i = -4 sum_p V_p P_p (X_i - X_p) w_ip` with the first Piola stress
//!   `P = tau F^-T`, exactly `-dE/du_i` of the elastic energy `sum_p V_p psi(F_p)`;
//! * the contacts as in `contact.rs`, on the top particles' surface points, their nodal
//!   forces through the rest stencils, the multipliers integrating a low-pass filtered
//!   gap ([`GAP_FILTER`]);
//! * the secant predictor on the nodal displacements;
//! * damped explicit steps on the nodes, `v <- (v + f / m) / (1 + c)`, `u <- u + v`, with
//!   the lumped mass, the mass scaling and the damping of the relaxation.
//!
//! Its equilibrium is the minimum of one energy (for frictionless contact), whatever the
//! path. The weights never change, so there is no binning and no stencil update; the
//! nodal forces are summed node layer by node layer in a fixed order (the same bits for
//! any thread count). F-bar is not implemented.
//!
//! [`Solver::Total`]: super::Solver::Total

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::contact;
use super::indenters::Sweep;
use super::materials::ConstitutiveModel;
use super::solver::{relax_frame, Equilibrium, Frame, Relax};
use super::transfer::{self, ChunkStats, LayerStats, Node, Stencil};
use super::{Gel, Snapshot, SolveReport, Solver, StateBounds, J_MAX, J_MIN};
use crate::geometry::Sdf;
use crate::state::{self, Io};
use std::sync::Arc;

/// A solve's change must exceed this many times the tolerance times the deformation for
/// the next solve to extrapolate it (as the relaxation's `PREDICT_ABOVE`).
const PREDICT_ABOVE: f64 = 10.0;

/// Weight of each step's gap in the low-pass filtered gap the contact multipliers
/// integrate (`ContactInput::filter`). The multiplier loop is less damped here than in the
/// updated-Lagrangian relaxation (no APIC transfer smooths the nodal velocities): on the
/// raw gap it oscillated with growing amplitude at the relaxation's gain, and half that
/// gain cost steps. Filtering the gap keeps the loop stable at the relaxation's gain
/// (measured: `docs/solvers.md`, "What the relaxation's answer depends on").
const GAP_FILTER: f32 = 0.3;

/// The nodal state of the total-Lagrangian relaxation.
#[derive(Clone)]
pub(super) struct Total {
    /// Displacement of each grid node from the undeformed gel (cells).
    u: Vec<Vector3<f32>>,
    /// Velocity of each grid node (cells per step).
    v: Vec<Vector3<f32>>,
    /// Lumped mass of each grid node.
    mass: Vec<f32>,
    /// Each particle's stencil at its rest position.
    rest: Vec<Stencil>,
    /// Each particle's rest position (cells).
    rest_x: Vec<Vector3<f32>>,
    /// `u` at the start of the solve, for a recovery.
    saved: Vec<Vector3<f32>>,
    /// Base node along x of each particle lattice row's stencils.
    row_base: Vec<usize>,
    /// Scratch: `-4 V P` of each active particle.
    stress: Vec<Matrix3<f32>>,
    /// The change of `u` over the last converged solve and the indenters' translations
    /// (m) in it, for the next solve's prediction (empty when there is none).
    last_du: Vec<Vector3<f32>>,
    last_motion: Vec<Vector3<f64>>,
}

impl Total {
    /// The undeformed gel's nodal state.
    fn new(gel: &Gel) -> Total {
        let [_, nyp, nzp] = gel.layout.lattice;
        let rest_x: Vec<Vector3<f32>> = (0..gel.particles.len())
            .map(|i| {
                gel.layout
                    .rest_position(&gel.params.size, i / (nyp * nzp), i / nzp % nyp, i % nzp)
            })
            .collect();
        let rest: Vec<Stencil> = rest_x.iter().map(Stencil::of).collect();
        let [_, ny, nz] = gel.layout.dims;
        let nodes = gel.grid.len();
        let mut mass = vec![0.0f32; nodes];
        for s in &rest {
            let (bx, _, wx) = s.axis(0);
            let (by, _, wy) = s.axis(1);
            let (bz, _, wz) = s.axis(2);
            for (i, a) in wx.iter().enumerate() {
                for (j, b) in wy.iter().enumerate() {
                    for (k, c) in wz.iter().enumerate() {
                        mass[((bx + i) * ny + by + j) * nz + bz + k] += gel.ctx.pmass * a * b * c;
                    }
                }
            }
        }
        let row_len = nyp * nzp;
        let row_base = (0..gel.layout.lattice[0])
            .map(|px| rest[px * row_len].base[0] as usize)
            .collect();
        Total {
            row_base,
            stress: Vec::new(),
            last_du: Vec::new(),
            last_motion: Vec::new(),
            u: vec![Vector3::zeros(); nodes],
            v: vec![Vector3::zeros(); nodes],
            mass,
            rest,
            rest_x,
            saved: Vec::new(),
        }
    }
}

/// The total-Lagrangian relaxation ([`Solver::Total`]): the particles follow the nodal
/// displacements it owns.
#[derive(Clone, Default)]
pub(super) struct TotalRelaxation {
    /// The nodal state, built at the first frame (and again after a restart).
    total: Option<Box<Total>>,
}

impl Equilibrium for TotalRelaxation {
    fn kind(&self) -> Solver {
        Solver::Total
    }

    fn solve(&mut self, gel: &mut Gel, frame: &Frame<'_>, report: &mut SolveReport) {
        if report.restarted || self.total.is_none() {
            self.total = Some(Box::new(Total::new(gel)));
        }
        relax_frame(self, gel, frame, report);
    }

    fn reset(&mut self) {
        self.total = None;
    }

    /// Whether the nodal state is built, and where it is: the nodal displacements (the
    /// velocities start every frame at zero) and the secant memory. What depends on the
    /// gel alone (masses, rest stencils) is built again from it.
    fn persist(
        &mut self,
        io: &mut Io<'_>,
        gel: &Gel,
        bounds: &StateBounds,
        _shapes: &[Arc<dyn Sdf>],
    ) -> bool {
        state::presence(io, &mut self.total, || Ok(Box::new(Total::new(gel))));
        if let Some(total) = self.total.as_mut() {
            state::each(io, &mut total.u);
            let nodes = total.u.len();
            state::secant(
                io,
                &mut total.last_du,
                &mut total.last_motion,
                nodes,
                bounds.indenters,
                "the total relaxation's",
            );
        }
        true
    }
}

impl Relax for TotalRelaxation {
    fn relax<M: ConstitutiveModel>(
        &mut self,
        gel: &mut Gel,
        model: &M,
        sweep: &Sweep,
        report: &mut SolveReport,
    ) {
        let total = self.total.as_mut().expect("built by solve");
        gel.relax_total(model, sweep, total, report);
    }
}

impl Gel {
    /// The total-Lagrangian relaxation of `sweep` with the constitutive model `model`,
    /// from the nodal state `total`.
    fn relax_total<M: ConstitutiveModel>(
        &mut self,
        model: &M,
        sweep: &Sweep,
        total: &mut Total,
        report: &mut SolveReport,
    ) {
        for (s, p) in self.snapshot.iter_mut().zip(&self.particles) {
            *s = Snapshot::of(p);
        }
        let motion = sweep.motion();
        let (region, bottom) = (self.ctx.region, self.ctx.iz_bottom);
        let [_, ny, nz] = self.layout.dims;
        total.saved.clone_from(&total.u);
        total.v.iter_mut().for_each(|v| *v = Vector3::zeros());
        // The secant predictor (as the relaxation's, on the nodal displacements).
        if let Some(s) = super::secant_scale(&motion, &total.last_motion) {
            let s = s as f32;
            for ix in region.free_x[0]..region.free_x[1] {
                for iy in region.free_y[0]..region.free_y[1] {
                    let first = (ix * ny + iy) * nz;
                    for k in first + bottom + 1..first + nz {
                        total.u[k] += total.last_du[k] * s;
                    }
                }
            }
        }
        self.iterate(
            total,
            sweep,
            report,
            |g, t| g.total_step(model, t),
            |_, t| t.u.clone_from(&t.saved),
        );
        // Keep this solve's change for the next one's prediction, unless it is within a
        // few tolerances of the deformation (mostly the solve's own error).
        let tol = self.options.tolerance;
        total.last_motion.clear();
        total.last_du.clear();
        if report.converged && !report.nonfinite_recovered {
            let moved = total
                .u
                .iter()
                .zip(&total.saved)
                .map(|(a, b)| (a - b).norm())
                .fold(0.0f32, f32::max) as f64;
            let deformed = total.u.iter().map(|u| u.norm()).fold(0.0f32, f32::max) as f64;
            if moved > PREDICT_ABOVE * tol * deformed {
                total
                    .last_du
                    .extend(total.u.iter().zip(&total.saved).map(|(a, b)| a - b));
                total.last_motion = motion;
            }
        }
    }

    /// One step: the particles' `F` and position from the nodal displacements, the
    /// contacts, the nodal forces, the nodes' update. Returns the total contact force on
    /// the gel (internal units).
    /// The first part of a total-Lagrangian step: `F` and the position of every active
    /// particle from the nodal displacements (and the rotation of `F`, when the model
    /// uses it), with their `det F` range into the chunk statistics.
    fn gather_total<M: ConstitutiveModel>(&mut self, total: &Total) {
        let Gel {
            pool,
            ctx,
            particles,
            chunk_stats,
            ..
        } = self;
        let ctx = &*ctx;
        pool.install(|| {
            let [_, ny, nz] = ctx.dims;
            let [ix0, ix1, iy0, iy1] = ctx.region.lattice;
            let (a, b) = (iy0 * ctx.column_len, iy1 * ctx.column_len);
            let (u, rest, rest_x) = (&total.u, &total.rest, &total.rest_x);
            // Gather: F and x of every active particle.
            particles
                .par_chunks_mut(ctx.row_len)
                .enumerate()
                .map(|(ix, row)| {
                    let mut st = ChunkStats::EMPTY;
                    if !(ix0..ix1).contains(&ix) {
                        return st;
                    }
                    let first = ix * ctx.row_len;
                    for (k, p) in row[a..b].iter_mut().enumerate() {
                        let i = first + a + k;
                        let s = &rest[i];
                        let (bx, fx, wx) = s.axis(0);
                        let (by, fy, wy) = s.axis(1);
                        let (bz, fz, wz) = s.axis(2);
                        // `sum w u` and `4 sum w u d^T`, summed along z first.
                        let mut up = Vector3::zeros();
                        let mut cols = [Vector3::zeros(); 3];
                        for (ii, wa) in wx.iter().enumerate() {
                            for (jj, wb) in wy.iter().enumerate() {
                                let row = ((bx + ii) * ny + by + jj) * nz + bz;
                                let (mut za, mut zb) = (Vector3::zeros(), Vector3::zeros());
                                for (kk, wc) in wz.iter().enumerate() {
                                    let ui = u[row + kk];
                                    za += ui * *wc;
                                    zb += ui * (*wc * (kk as f32 - fz));
                                }
                                let w = wa * wb;
                                up += za * w;
                                cols[0] += za * (w * (ii as f32 - fx));
                                cols[1] += za * (w * (jj as f32 - fy));
                                cols[2] += zb * w;
                            }
                        }
                        p.x = rest_x[i] + up;
                        p.f = Matrix3::identity() + Matrix3::from_columns(&cols) * 4.0;
                        let j = p.f.determinant();
                        if !p.is_finite() {
                            st.nonfinite = true;
                            continue;
                        }
                        st.det_min = st.det_min.min(j);
                        st.det_max = st.det_max.max(j);
                    }
                    if M::USES_ROTATION {
                        transfer::extract_rotations(&mut row[a..b], ctx.rot_iters.max(1));
                    }
                    st
                })
                .collect_into_vec(chunk_stats);
        });
    }

    fn total_step<M: ConstitutiveModel>(&mut self, model: &M, total: &mut Total) -> [f64; 3] {
        self.gather_total::<M>(total);
        self.update_contacts(GAP_FILTER);
        let Gel {
            pool,
            ctx,
            particles,
            active,
            grid,
            layer_stats,
            ..
        } = self;
        let ctx = &*ctx;
        pool.install(|| {
            let [nx, ny, nz] = ctx.dims;
            let [ix0, ix1, iy0, iy1] = ctx.region.lattice;
            let (a, b) = (iy0 * ctx.column_len, iy1 * ctx.column_len);
            let rest = &total.rest;
            grid.iter_mut().for_each(|n| *n = Node::ZERO);
            let f = contact::scatter_contacts(ctx, rest, active, grid);
            // First Piola stresses (times -4 V) of the active particles.
            let nzp = ctx.column_len;
            let nyp = ctx.row_len / nzp;
            let rows = ix1 - ix0;
            total.stress.resize(rows * (b - a), Matrix3::zeros());
            total
                .stress
                .par_chunks_mut(b - a)
                .zip(particles[ix0 * ctx.row_len..ix1 * ctx.row_len].par_chunks(ctx.row_len))
                .for_each(|(out, row)| {
                    for (o, p) in out.iter_mut().zip(&row[a..b]) {
                        let j = p.f.determinant().clamp(J_MIN as f32, J_MAX as f32);
                        let r = if M::USES_ROTATION {
                            *p.q.to_rotation_matrix().matrix()
                        } else {
                            Matrix3::identity()
                        };
                        let tau = model.kirchhoff(&p.f, j, &r);
                        *o = match p.f.try_inverse() {
                            Some(finv) => tau * finv.transpose() * (-4.0 * ctx.pvol),
                            None => Matrix3::zeros(),
                        };
                    }
                });
            // Elastic nodal forces, node layer by node layer: each layer sums the particle
            // rows whose stencils reach it, rows and particles in index order (the same
            // sums for any thread count).
            let (rest, stress, row_base) = (&total.rest, &total.stress, &total.row_base);
            grid.par_chunks_mut(ny * nz)
                .enumerate()
                .for_each(|(layer, g)| {
                    for px in ix0..ix1 {
                        let bx = row_base[px];
                        if layer < bx || layer > bx + 2 {
                            continue;
                        }
                        let ii = layer - bx;
                        for iy in iy0..iy1 {
                            for iz in 0..nzp {
                                let i = (px * nyp + iy) * nzp + iz;
                                let piola = &stress[(px - ix0) * (b - a) + (iy - iy0) * nzp + iz];
                                let s = &rest[i];
                                let (_, fx, wx) = s.axis(0);
                                let (by, fy, wy) = s.axis(1);
                                let (bz, fz, wz) = s.axis(2);
                                // `P d w` with `d = (ii - fx, jj - fy, kk - fz)`, summed
                                // axis by axis.
                                let wa = wx[ii];
                                let c0 = piola.column(0) * (wa * (ii as f32 - fx));
                                let (c1, c2) = (piola.column(1) * wa, piola.column(2) * wa);
                                for (jj, wb) in wy.iter().enumerate() {
                                    let q = (c0 + c1 * (jj as f32 - fy)) * *wb;
                                    let r = c2 * *wb;
                                    let row = (by + jj) * nz + bz;
                                    for (kk, wc) in wz.iter().enumerate() {
                                        g[row + kk].add_f((q + r * (kk as f32 - fz)) * *wc);
                                    }
                                }
                            }
                        }
                    }
                });
            // Nodes: damped explicit step on the free ones.
            let c = ctx.damping;
            let [fx0, fx1] = ctx.region.free_x;
            let [fy0, fy1] = ctx.region.free_y;
            let mass = &total.mass;
            let nyz = ny * nz;
            grid.par_chunks(nyz)
                .zip(total.u.par_chunks_mut(nyz))
                .zip(total.v.par_chunks_mut(nyz))
                .zip(mass.par_chunks(nyz))
                .enumerate()
                .map(|(ix, (((g, u), v), m))| {
                    let mut st = LayerStats::default();
                    let wall_x = ix == 0 || ix + 1 == nx || ix < fx0 || ix >= fx1;
                    for (k, n) in g.iter().enumerate() {
                        let (iy, iz) = (k / nz, k % nz);
                        if m[k] <= 0.0 {
                            continue;
                        }
                        let force = Vector3::new(n.a[Node::F], n.a[Node::F + 1], n.a[Node::F + 2]);
                        let wall = wall_x || iy == 0 || iy + 1 == ny || iy < fy0 || iy >= fy1;
                        if iz <= ctx.iz_bottom || wall || iz + 1 == nz {
                            st.reaction = st.reaction.max(force.norm());
                            v[k] = Vector3::zeros();
                            continue;
                        }
                        let vs = v[k] + force / m[k];
                        st.residual = st.residual.max(force.norm() + c * m[k] * vs.norm());
                        v[k] = vs / (1.0 + c);
                        u[k] += v[k];
                    }
                    st
                })
                .collect_into_vec(layer_stats);
            f
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Placed, Sdf, Sphere};
    use crate::mpm::{GelParams, SolverOptions};
    use nalgebra::Isometry3;
    use std::sync::Arc;

    fn gel() -> Gel {
        let options = SolverOptions {
            solver: Solver::Total,
            ..Default::default()
        };
        Gel::new(GelParams::default(), options).expect("gel")
    }

    fn press(gel: &mut Gel, ball: &Arc<dyn Sdf>, x: f64, depth: f64) {
        gel.solve(&[Placed {
            shape: ball.clone(),
            pose: Isometry3::translation(x, 0.0, 5e-3 - depth),
        }]);
    }

    /// The gel's state written after a press and a slide, read into a fresh gel of the
    /// total relaxation: the next frame is the original's, bit for bit, where a fresh gel's
    /// is not (the nodal displacements and the secant memory are what it starts from).
    #[test]
    fn a_restored_total_relaxation_replays_its_next_frame_bit_for_bit() {
        let ball: Arc<dyn Sdf> = Arc::new(Sphere::new(5e-3));
        let shapes = [ball.clone()];
        let mut original = gel();
        press(&mut original, &ball, 0.0, 0.3e-3);
        press(&mut original, &ball, 0.3e-3, 0.4e-3);
        let bounds = original.state_bounds(1);
        let mut buf = vec![0.0; bounds.gel_len(Solver::Total, false)];
        let mut io = Io::save(&mut buf);
        assert!(original.persist(&mut io, &shapes), "the state is kept");
        assert!(!io.overflowed(), "the declared size holds the state");
        let mut restored = gel();
        let mut io = Io::load(&buf);
        assert!(restored.persist(&mut io, &shapes));
        assert_eq!(io.fault(), None);
        let mut fresh = gel();
        for g in [&mut original, &mut restored, &mut fresh] {
            press(g, &ball, 0.6e-3, 0.4e-3);
        }
        let bits = |g: &Gel| -> Vec<u64> {
            g.surface_u
                .iter()
                .flat_map(|u| u.iter().map(|v| v.to_bits()).collect::<Vec<_>>())
                .collect()
        };
        assert_eq!(bits(&original), bits(&restored));
        assert_ne!(bits(&original), bits(&fresh));
    }

    /// A secant memory that does not cover every node (a state written by hand) is
    /// refused, naming it, rather than indexed past its end at the next frame.
    #[test]
    fn a_secant_memory_of_the_wrong_length_is_refused() {
        let g = gel();
        let bounds = g.state_bounds(1);
        let mut solver = TotalRelaxation {
            total: Some(Box::new(Total::new(&g))),
        };
        if let Some(t) = solver.total.as_mut() {
            t.last_du = vec![Vector3::zeros(); 5];
        }
        let mut buf = vec![0.0; bounds.gel_len(Solver::Total, false)];
        let mut io = Io::save(&mut buf);
        solver.persist(&mut io, &g, &bounds, &[]);
        let mut other = TotalRelaxation::default();
        let mut io = Io::load(&buf);
        other.persist(&mut io, &g, &bounds, &[]);
        let fault = io.fault().expect("refused");
        assert!(fault.contains("secant memory holds 5 of"), "{fault}");
    }
}
