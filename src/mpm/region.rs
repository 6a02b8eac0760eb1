//! The active region: the part of the gel a solve moves.
//!
//! A contact deforms a bonded layer only near itself: the surface settles within about
//! one thickness of the contact edge. A solve therefore moves only the particles of a
//! lattice box, the contact footprint (top-surface points within half a cell of an
//! indenter at its start or end pose, with contact state, or in contact at the end of the
//! last solve) grown by [`SolverOptions::active_margin`] thicknesses (1.5 by default) on
//! every side and widened to every point indented by more than 1 % of the largest
//! indentation (so that where an indenter was, the gel relaxes). The rest of the gel
//! keeps its state and is not scattered; the grid nodes that have one of its particles
//! in their support are held fixed, a rigid wall around the active box. A solve whose
//! indenters reach no contact point of the undeformed gel does not run: the undeformed
//! gel is its equilibrium ([`Gel::solve`]). Its images and forces stay close to the whole
//! gel's with about half of the particles or fewer (measured: `docs/configuration.md`,
//! "The scene", and `docs/solvers.md`, "Two solvers and a third"). `f64::INFINITY` solves
//! the whole gel every time.
//!
//! [`SolverOptions::active_margin`]: super::SolverOptions::active_margin

use nalgebra::{Isometry3, Point3};

use super::indenters::Sweep;
use super::surface::{add_to_box, non_empty, DEPTH_EPS, EMPTY_BOX};
use super::transfer::Region;
use super::Gel;
use crate::geometry::{Aabb, Placed};

/// Fraction of the largest surface indentation (vertical displacement, up or down) above
/// which a slot counts as deformed: the active region always covers the deformed slots,
/// so that where an indenter was, the gel relaxes.
const DEFORMED: f64 = 1e-2;

/// An indenter's poses at the start and end of the sweep, and the bounds of both,
/// inflated by the reach.
type Reach<'a> = (&'a Placed, [Isometry3<f64>; 2], Aabb);

impl Gel {
    /// The region this solve moves: the lattice box of the top-surface slots that an
    /// indenter reaches (within half a cell of its start or end pose), that hold contact
    /// state or that were in contact at the end of the last solve, grown by
    /// [`SolverOptions::active_margin`](super::SolverOptions::active_margin) thicknesses
    /// on every side, and widened to every slot whose indentation is above [`DEFORMED`]
    /// of the largest (so that a region an indenter leaves relaxes); and the nodes that
    /// stay free within it. Without a slot in contact now or at the end of the last solve,
    /// the whole gel.
    pub(super) fn active_region(&self, sweep: &Sweep) -> Region {
        let layout = &self.layout;
        let whole = Region::whole(layout.lattice, layout.dims);
        let margin = self.options.active_margin * self.params.size[2];
        if !margin.is_finite() {
            return whole;
        }
        let Some(fp) = self.contact_box(sweep) else {
            return whole;
        };
        let [nxp, nyp, _] = layout.lattice;
        let grow = |k: usize| (margin / layout.spacing[k]).ceil() as usize;
        let mut lattice = [
            fp[0].saturating_sub(grow(0)),
            (fp[1] + grow(0)).min(nxp),
            fp[2].saturating_sub(grow(1)),
            (fp[3] + grow(1)).min(nyp),
        ];
        if let Some(zone) = self.deformed_box() {
            lattice = [
                lattice[0].min(zone[0]),
                lattice[1].max(zone[1]),
                lattice[2].min(zone[2]),
                lattice[3].max(zone[3]),
            ];
        }
        Region {
            lattice,
            free_x: self.free_nodes(0, lattice[0], lattice[1]),
            free_y: self.free_nodes(1, lattice[2], lattice[3]),
        }
    }

    /// Lattice box of the slots indented by more than [`DEFORMED`] of the largest
    /// indentation.
    fn deformed_box(&self) -> Option<[usize; 4]> {
        let nxp = self.layout.lattice[0];
        let umax = self.surface_u.iter().map(|u| u.z.abs()).fold(0.0, f64::max);
        let deformed = (DEFORMED * umax).max(DEPTH_EPS);
        let mut zone = EMPTY_BOX;
        for (slot, u) in self.surface_u.iter().enumerate() {
            if u.z.abs() > deformed {
                add_to_box(&mut zone, slot % nxp, slot / nxp);
            }
        }
        non_empty(zone)
    }

    /// Lattice box of the slots in the last solve's footprint, with contact state, or
    /// within reach of an indenter of `sweep` at its start or end pose.
    fn contact_box(&self, sweep: &Sweep) -> Option<[usize; 4]> {
        let reach = 0.5 * self.layout.dx;
        let poses: Vec<Reach> = sweep
            .indenters
            .iter()
            .zip(&sweep.starts)
            .map(|(p, s)| {
                let a = p.shape.aabb().transformed(s);
                let b = p.shape.aabb().transformed(&p.pose);
                let bounds = Aabb::new(a.min.inf(&b.min), a.max.sup(&b.max)).inflated(reach);
                (*p, [*s, p.pose], bounds)
            })
            .collect();
        let nxp = self.layout.lattice[0];
        let last = self.last_footprint.unwrap_or([0; 4]);
        let mut fp = EMPTY_BOX;
        for (slot, c) in self.contacts.iter().enumerate() {
            let (ix, iy) = (slot % nxp, slot / nxp);
            let hit = (last[0]..last[1]).contains(&ix) && (last[2]..last[3]).contains(&iy)
                || c.lambda > 0.0
                || c.indenter != u32::MAX
                || self.slot_reached(slot, &poses, reach);
            if hit {
                add_to_box(&mut fp, ix, iy);
            }
        }
        non_empty(fp)
    }

    /// Whether the surface point of top slot `slot` lies within `reach` of an indenter
    /// at one of its `poses`.
    fn slot_reached(&self, slot: usize, poses: &[Reach], reach: f64) -> bool {
        let p = &self.particles[self.top[slot] as usize];
        let sp = (p.x + p.f.column(2) * self.half_top).cast::<f64>();
        let sp = Point3::from(self.layout.origin + sp * self.layout.dx);
        poses.iter().any(|(placed, pose, bounds)| {
            (0..3).all(|k| sp[k] >= bounds.min[k] && sp[k] <= bounds.max[k])
                && pose.iter().any(|q| {
                    let d = placed.shape.distance(&q.inverse_transform_point(&sp));
                    !d.is_finite() || d < reach
                })
        })
    }

    /// The free node range `[lo, hi)` along axis `k` for the active lattice range
    /// `[lo, hi)` along it: a node is free when no inactive particle lies within its
    /// support (1.5 cells), with a quarter cell to spare for the particles' motion.
    fn free_nodes(&self, k: usize, lo: usize, hi: usize) -> [usize; 2] {
        let layout = &self.layout;
        let at = |i: usize| {
            let mut idx = [0usize; 3];
            idx[k] = i;
            layout.rest_position(&self.params.size, idx[0], idx[1], idx[2])[k] as f64
        };
        let a = if lo > 0 {
            (at(lo - 1) + 1.75).floor() as usize + 1
        } else {
            0
        };
        let b = if hi < layout.lattice[k] {
            ((at(hi) - 1.75).ceil().max(0.0) as usize).min(layout.dims[k])
        } else {
            layout.dims[k]
        };
        [a.min(b), b]
    }

    /// Lattice box of the top slots with a contact force at the last step or a positive
    /// multiplier.
    pub(super) fn footprint(&self) -> Option<[usize; 4]> {
        let nxp = self.layout.lattice[0];
        let mut bx = EMPTY_BOX;
        for (slot, (a, c)) in self.active.iter().zip(&self.contacts).enumerate() {
            if a.is_some() || c.lambda > 0.0 {
                add_to_box(&mut bx, slot % nxp, slot / nxp);
            }
        }
        non_empty(bx)
    }
}
