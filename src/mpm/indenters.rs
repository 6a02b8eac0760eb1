//! The indenters of a solve: which ones are usable, which previous indenter each one is,
//! where each starts from, and how it moves during the first steps.
//!
//! Each indenter is a rigid signed distance field. Contact acts on the surface point of
//! each top particle (`x_p + (s_z / 2) F e_z`, the point the depth image shows), with an
//! augmented Lagrangian normal force and a Coulomb-capped stick spring (see
//! [`contact`](super::contact)); the contact forces enter the grid as nodal forces, so the
//! force on the indenters is their sum, exact at equilibrium. (An earlier velocity
//! constraint on every grid node within 1.5 cells below the surface acted as a rigid slab
//! and gave forces 12-18 % above Hertz that did not converge under refinement.)
//!
//! Indenters are matched to those of the previous call by identity: the same shape
//! (`Arc::ptr_eq` of [`Placed::shape`]), and among several sharing one shape, the nearest
//! previous pose; an indenter without a match is new, and the contact state (multipliers,
//! stick anchors) of a previous indenter without a successor is released. During the
//! first steps of a solve, each indenter moves from its previous pose to the current one
//! (linear in translation, slerp in rotation) at most [`SolverOptions::sweep_rate`] cells
//! per step; a new indenter starts lifted just clear of the surface. Stick anchors are
//! fixed in the indenter's frame and persist between solves, so friction drags the surface
//! along while the indenter slides and holds it afterwards: the shear history of a sliding
//! contact is kept.
//!
//! [`SolverOptions::sweep_rate`]: super::SolverOptions::sweep_rate

use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Vector3};

use super::contact::{self, SlotContact, StepIndenter};
use super::Gel;
use crate::geometry::{Aabb, Placed, Sdf};
use crate::scratch::refill;

/// Height of the undeformed top face in the sensor frame (m).
const TOP_Z: f64 = 0.0;

/// The indenters with finite poses, in slice order; contact state refers to indenters by
/// their index in this list.
pub(super) fn usable(indenters: &[Placed]) -> impl Iterator<Item = &Placed> + Clone {
    indenters.iter().filter(|p| {
        p.pose.translation.vector.iter().all(|v| v.is_finite())
            && p.pose.rotation.coords.iter().all(|v| v.is_finite())
    })
}

/// The vectors of a solve's indenters, kept between solves so that a frame does not
/// allocate them: the usable indenters (empty between solves), the matching's pairs,
/// its result and what it took, the sweep's starts, and the indices' renumbering.
#[derive(Default)]
pub(super) struct Buffers {
    pub used: Vec<&'static Placed>,
    pub pairs: Vec<(f64, usize, usize)>,
    pub matched: Vec<Option<usize>>,
    pub taken: Vec<bool>,
    pub starts: Vec<Isometry3<f64>>,
    pub index: Vec<u32>,
    pub current: Vec<(Arc<dyn Sdf>, Isometry3<f64>)>,
    pub none: Vec<Option<usize>>,
}

/// Largest displacement (m) of a corner of `shape`'s bounding box between poses `a` and
/// `b`; 0 if not finite.
fn corner_motion(shape: &dyn Sdf, a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    let bb = shape.aabb();
    (0..8)
        .map(|i| {
            let c = Point3::new(
                if i & 1 == 0 { bb.min.x } else { bb.max.x },
                if i & 2 == 0 { bb.min.y } else { bb.max.y },
                if i & 4 == 0 { bb.min.z } else { bb.max.z },
            );
            let d = (a * c - b * c).norm();
            if d.is_finite() {
                d
            } else {
                0.0
            }
        })
        .fold(0.0, f64::max)
}

/// Matches the indenters of this solve to those of the previous one: same shape (the
/// same `Arc`), and among several sharing a shape, nearest pose first (greedy on the
/// largest bounding-box corner motion, ties in index order). Returns, for each current
/// indenter, the index of its previous self, or `None` for a new one.
pub(super) fn match_indenters(
    prev: &[(Arc<dyn Sdf>, Isometry3<f64>)],
    now: &[&Placed],
    kept: &mut Buffers,
) {
    let Buffers {
        pairs,
        matched,
        taken,
        ..
    } = kept;
    pairs.clear();
    for (i, p) in now.iter().enumerate() {
        for (j, (shape, pose)) in prev.iter().enumerate() {
            if Arc::ptr_eq(shape, &p.shape) {
                pairs.push((corner_motion(p.shape.as_ref(), pose, &p.pose), i, j));
            }
        }
    }
    pairs.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    refill(matched, now.len(), None);
    refill(taken, prev.len(), false);
    for &(_, i, j) in pairs.iter() {
        if matched[i].is_none() && !taken[j] {
            matched[i] = Some(j);
            taken[j] = true;
        }
    }
}

/// How the indenters move during a solve: each from its start pose to its current pose,
/// in `steps` equal parts.
pub(super) struct Sweep<'a> {
    /// The usable indenters (see [`usable`]).
    pub indenters: Vec<&'a Placed>,
    /// The pose each indenter starts from.
    pub starts: Vec<Isometry3<f64>>,
    /// Steps the motion takes (at least 1).
    pub steps: usize,
}

impl Sweep<'_> {
    /// Each indenter's translation over the sweep (m), what the secant predictors compare
    /// with the last solve's.
    pub fn motion(&self) -> Vec<Vector3<f64>> {
        self.indenters
            .iter()
            .zip(&self.starts)
            .map(|(p, s)| p.pose.translation.vector - s.translation.vector)
            .collect()
    }

    /// Writes into `out` the indenters of step `it` (from 0): their poses at the end of
    /// the step and their bounds over it, inflated by the contact band and a cell (`dx`).
    pub fn place(&self, it: usize, dx: f64, out: &mut Vec<StepIndenter>) {
        let interp = |a: &Isometry3<f64>, b: &Isometry3<f64>, s: f64| {
            a.try_lerp_slerp(b, s, 1e-9).unwrap_or(*b)
        };
        let s_now = ((it + 1) as f64 / self.steps as f64).min(1.0);
        let s_before = (it as f64 / self.steps as f64).min(1.0);
        out.clear();
        for (p, start) in self.indenters.iter().zip(&self.starts) {
            let now = interp(start, &p.pose, s_now);
            let before = interp(start, &p.pose, s_before);
            let b0 = p.shape.aabb().transformed(&now);
            let b1 = p.shape.aabb().transformed(&before);
            let bounds = Aabb::new(b0.min.inf(&b1.min), b0.max.sup(&b1.max))
                .inflated((contact::CONTACT_BAND as f64 + 1.0) * dx);
            out.push(StepIndenter {
                shape: p.shape.clone(),
                now,
                bounds,
            });
        }
    }
}

impl Gel {
    /// Whether the bounding box of `p` comes within two cells of the gel's height range.
    pub(super) fn reaches(&self, p: &Placed) -> bool {
        let dx = self.layout.dx;
        let b = p.aabb();
        b.min.z <= TOP_Z + 2.0 * dx && b.max.z >= -self.params.size[2] - 2.0 * dx
    }

    /// The sweep of `indenters` (`matched[i]`: the previous index of indenter `i`): a
    /// matched indenter starts from its previous pose, a new one lifted clear of the
    /// surface; the motion takes one step per [`SolverOptions::sweep_rate`] cells of the
    /// largest bounding-box corner displacement, at most half the iteration cap.
    ///
    /// [`SolverOptions::sweep_rate`]: super::SolverOptions::sweep_rate
    pub(super) fn plan_sweep<'a>(
        &self,
        indenters: Vec<&'a Placed>,
        matched: &[Option<usize>],
        mut starts: Vec<Isometry3<f64>>,
    ) -> Sweep<'a> {
        let dx = self.layout.dx;
        starts.clear();
        starts.extend(indenters.iter().zip(matched).map(|(p, m)| match *m {
            Some(j) => self.prev[j].1,
            None => self.lifted(p),
        }));
        let disp = indenters
            .iter()
            .zip(&starts)
            .map(|(p, start)| corner_motion(p.shape.as_ref(), start, &p.pose))
            .fold(0.0, f64::max);
        let cap = (self.iteration_cap() / 2).max(1);
        let steps = ((disp / (self.options.sweep_rate * dx)).ceil() as usize).clamp(1, cap);
        Sweep {
            indenters,
            starts,
            steps,
        }
    }

    /// The start pose of a new indenter: its pose raised until its bounding box clears the
    /// top face (by at most the gel's thickness and four cells).
    fn lifted(&self, p: &Placed) -> Isometry3<f64> {
        let lift = TOP_Z - p.aabb().min.z;
        let lift = if lift.is_finite() {
            lift.clamp(0.0, self.params.size[2] + 4.0 * self.layout.dx)
        } else {
            0.0
        };
        let mut s = p.pose;
        s.translation.vector.z += lift;
        s
    }

    /// Renumbers the indenter indices of the contact state from the previous solve's list
    /// to this one's (`matched[i]`: the previous index of indenter `i`); the state held
    /// by a previous indenter that has no successor is released.
    pub(super) fn remap_contacts(&mut self, matched: &[Option<usize>], new_index: &mut Vec<u32>) {
        refill(new_index, self.prev.len(), u32::MAX);
        for (i, m) in matched.iter().enumerate() {
            if let Some(j) = *m {
                new_index[j] = i as u32;
            }
        }
        let map = |k: u32| new_index.get(k as usize).copied().unwrap_or(u32::MAX);
        for c in &mut self.contacts {
            if c.owner == u32::MAX && c.indenter == u32::MAX {
                continue;
            }
            let owner = map(c.owner);
            if owner == u32::MAX {
                *c = SlotContact::NONE;
                continue;
            }
            c.owner = owner;
            c.indenter = map(c.indenter);
        }
    }
}
