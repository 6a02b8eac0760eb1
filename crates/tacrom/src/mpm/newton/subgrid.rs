//! Contact patches smaller than the grid resolves: a compliance in series with each.
//!
//! The gel's surface is the quadratic B-spline field of the grid's nodes, which cannot
//! bend over much less than a cell. Under a load concentrated on a patch smaller than
//! that, the grid deflects as a half-space does under a punch of some radius `a_h` (the
//! grid's *resolved radius*), not of the patch's own radius `a`: it is too stiff by about
//! `a_h / a` (a 0.5 mm sphere pressed 0.1 mm into the coarse gel carried 2.2 times the
//! force of a 0.5 mm grid). The incremental stiffness of any frictionless axisymmetric
//! contact on a half-space is `2 E* a` (Pharr, Oliver and Brotzen 1992), so what the grid
//! misses is the compliance
//!
//! ```text
//! c(a) = (1 / a - 1 / a_h) / (2 E*)        (a < a_h; zero for larger patches)
//! ```
//!
//! in series with it. Each contact patch (the touching contact lattice points connected
//! through touching points at most [`PATCH_REACH`] resolved radii apart) of `n` points gets `a = sqrt(n A / pi)` and shares `c(a)`
//! among its points: each point's penalty `k A` gets the spring `n c(a)` in series, so the
//! patch's mean penetration into the grid's surface is its force times `c(a)`. The
//! patches are found after a minimisation and the compliance refreshed, lagged like the
//! friction, until it stops changing ([`super::Newton::substep`]). A patch the grid
//! resolves is left exactly as it was.
//!
//! A contact too small to reach any lattice point at all (a sharp tip pressed less than
//! the lattice's spacing into the gel) is found by sampling the rest surface more finely
//! around the lattice point nearest the indenter ([`TIP_SAMPLES`] per lattice spacing and
//! axis): where samples penetrate, one *tip point* at the deepest stands for them, with
//! their share of the top face; it is a patch of its own for the compliance above, so its
//! force follows the tip's contact size. It exists only while no lattice point touches its
//! indenter, is refreshed with the patches, and carries no friction.
//!
//! `a_h` is measured once per gel ([`super::Newton::calibrate_resolved_radius`]): the
//! deflection `C` of the rest state's surface under a unit normal load on single contact
//! lattice points across a cell near the gel's centre (a linear solve with the rest
//! stiffness), less the bonded layer's first-order stiffening, which any contact on the
//! layer has and `c` must not add back: `1 / a_h = 2 E* C + beta / h`
//! ([`crate::mpm::hertz::bonded_layer_slope`]). Grids too large for that solve
//! ([`MAX_CALIBRATION_UNKNOWNS`]) go without the correction.

use nalgebra::Vector3;

use super::{ContactPoint, Newton, Stencil, PENALTY};

use crate::mpm::contact::StepIndenter;

/// Unknowns of the calibration solve above which a grid goes without the correction.
pub(super) const MAX_CALIBRATION_UNKNOWNS: usize = 60_000;

/// Samples per contact lattice spacing and axis in the search for a tip point.
const TIP_SAMPLES: usize = 8;

/// Distance, in resolved radii, within which touching points belong to one patch: the
/// grid does not tell apart loads closer than it resolves (the rim of a round contact on
/// the square lattice touches in separate clusters around the main patch, and the
/// bumps of a texture finer than a cell load the grid as one contact).
const PATCH_REACH: f64 = 2.0;

/// Cells of the calibration region beyond the layer's thickness on each side of the
/// loaded column.
const CALIBRATION_MARGIN: f64 = 3.0;

impl Newton {
    /// Measures the grid's resolved radius `a_h` (cells; see the module docs), or 0 where
    /// the grid is too large for the solve or the solve fails. Leaves the solver without a
    /// region and with zero displacement, as built.
    pub(super) fn calibrate_resolved_radius(&mut self) -> f64 {
        let half = (self.top + CALIBRATION_MARGIN).ceil() as usize;
        let (cx, cy) = (self.dims[0] / 2, self.dims[1] / 2);
        let bx = [
            cx.saturating_sub(half),
            (cx + half + 1).min(self.dims[0]),
            cy.saturating_sub(half),
            (cy + half + 1).min(self.dims[1]),
        ];
        let columns = (bx[1] - bx[0]) * (bx[3] - bx[2]);
        if 3 * columns * self.dims[2] > MAX_CALIBRATION_UNKNOWNS {
            return 0.0;
        }
        let radius = self.point_compliance(bx).map_or(0.0, |c| {
            // The layer's own stiffening is in `c`, as it is in the compliance of any
            // contact on it: the grid's half-space radius is taken without it.
            let inverse = 2.0 * self.e_star * c + self.layer_slope / self.thickness;
            if c > 0.0 && inverse.is_finite() {
                1.0 / inverse
            } else {
                0.0
            }
        });
        // Back to the state of a new solver: no region, no kept system.
        self.system = None;
        self.region = None;
        self.u.fill(0.0);
        radius
    }

    /// The mean normal deflection (cells per internal force unit) of the rest state's
    /// surface under a unit normal load on each of the contact lattice points along one
    /// cell's diagonal at the centre of `bx`, the rest of the gel held.
    fn point_compliance(&mut self, bx: [usize; 4]) -> Option<f64> {
        self.set_region(bx).ok()?;
        self.u.fill(0.0);
        self.evaluate(&[])?;
        let mut system = self.system.take()?;
        self.fill_matrix(&mut system);
        let factored = system.factor().is_ok();
        let centre = [0.5 * (bx[0] + bx[1]) as f64, 0.5 * (bx[2] + bx[3]) as f64];
        let per_cell = (1.0 / self.spacing[0]).round().max(1.0) as usize;
        let mut total = 0.0;
        let mut rhs = vec![0.0; system.n];
        for k in 0..per_cell {
            let t = k as f64 / per_cell as f64;
            let rest = Vector3::new(centre[0] + t, centre[1] + t, self.top);
            let stencil = Stencil::at(&rest);
            rhs.fill(0.0);
            for l in 0..27 {
                if let Some(d) = self.local_at(&stencil.base, l) {
                    rhs[3 * d + 2] = -stencil.weight(l);
                }
            }
            system.solve(&mut rhs);
            let mut down = 0.0;
            for l in 0..27 {
                if let Some(d) = self.local_at(&stencil.base, l) {
                    down -= stencil.weight(l) * rhs[3 * d + 2];
                }
            }
            total += down;
        }
        self.system = Some(system);
        factored.then_some(total / per_cell as f64)
    }

    /// Replaces the tip points (see the module docs) by those of the current
    /// displacement: one per indenter that penetrates the finely sampled surface near its
    /// nearest contact lattice point while no lattice point touches it. Returns the
    /// largest relative change of a tip's share of the face (1 for a tip that came or
    /// went).
    pub(super) fn update_tips(&mut self, indenters: &[StepIndenter]) -> f64 {
        let mut old: Vec<ContactPoint> = Vec::new();
        let contact = std::mem::take(&mut self.contact);
        for c in contact {
            if c.tip {
                old.push(c);
            } else {
                self.contact.push(c);
            }
        }
        let count = (self.lattice[0] * self.lattice[1]) as u32;
        let mut nearest: Vec<Option<(f64, Vector3<f64>)>> = vec![None; indenters.len()];
        let mut touched = vec![false; indenters.len()];
        for c in &self.contact {
            let x = c.rest + self.displacement(&c.stencil, &self.u);
            for (m, near) in nearest.iter_mut().enumerate() {
                let d = self.distance_to(&x, &indenters[m]);
                touched[m] |= d < 0.0;
                if d.is_finite() && near.map_or(true, |(b, _)| d < b) {
                    *near = Some((d, c.rest));
                }
            }
        }
        let mut change = 0.0f64;
        for (m, near) in nearest.iter().enumerate() {
            let tip = match near {
                Some((_, rest)) if !touched[m] => self.find_tip(rest, &indenters[m]),
                _ => None,
            };
            let before = old.iter().find(|c| c.index == count + m as u32);
            change = change.max(match (before, &tip) {
                (None, None) => 0.0,
                (Some(b), Some(t)) => (t.1 - b.weight).abs() / b.weight,
                _ => 1.0,
            });
            if let Some((rest, weight)) = tip {
                let stencil = Stencil::at(&rest);
                let soft = self.patch_softness(weight);
                self.contact.push(ContactPoint {
                    index: count + m as u32,
                    rest,
                    stencil,
                    lag_force: 0.0,
                    lag_normal: Vector3::z(),
                    soft,
                    weight,
                    tip: true,
                });
            }
        }
        change
    }

    /// The deepest penetrating rest position among the samples of the four lattice
    /// elements around the lattice point at `rest`, and the samples' penetrating share
    /// of one lattice point's face (at least one sample's).
    fn find_tip(
        &self,
        rest: &Vector3<f64>,
        indenter: &StepIndenter,
    ) -> Option<(Vector3<f64>, f64)> {
        let n = 2 * TIP_SAMPLES;
        let mut deepest: Option<(f64, Vector3<f64>)> = None;
        let mut inside = 0usize;
        for i in 0..=n {
            for j in 0..=n {
                let offset = |k: usize, axis: usize| {
                    (k as f64 / TIP_SAMPLES as f64 - 1.0) * self.spacing[axis]
                };
                let at = rest + Vector3::new(offset(i, 0), offset(j, 1), 0.0);
                let x = at + self.displacement(&Stencil::at(&at), &self.u);
                let d = self.distance_to(&x, indenter);
                if d < 0.0 {
                    inside += 1;
                    if deepest.map_or(true, |(b, _)| d < b) {
                        deepest = Some((d, at));
                    }
                }
            }
        }
        let share = (inside as f64 / (TIP_SAMPLES * TIP_SAMPLES) as f64).clamp(0.0, 1.0);
        deepest.map(|(_, at)| (at, share))
    }

    /// Signed distance (cells) from the point at `x` (cells) to `indenter`; `+inf` outside
    /// its bounds.
    fn distance_to(&self, x: &Vector3<f64>, indenter: &StepIndenter) -> f64 {
        let p = nalgebra::Point3::from(self.origin + x * self.dx);
        if !super::contains(&indenter.bounds, &p) {
            return f64::INFINITY;
        }
        indenter
            .shape
            .distance(&indenter.now.inverse_transform_point(&p))
            / self.dx
    }

    /// Gives each contact point the penalty factor of its contact patch (see the module
    /// docs), from the indenters' rigid footprint on the surface: the lattice points that
    /// the indenters reach at the rest height, moved laterally with the gel. The
    /// footprint does not depend on the patch's compliance, so it needs no refreshing
    /// within a substep (the points that sink in under a soft patch would otherwise make
    /// it larger, and the update swing).
    pub(super) fn update_patches(&mut self, indenters: &[StepIndenter]) {
        if !(self.resolved_radius > 0.0) {
            return;
        }
        let [nx, _] = self.lattice;
        let lateral = |c: &ContactPoint| {
            let d = self.displacement(&c.stencil, &self.u);
            c.rest + Vector3::new(d.x, d.y, 0.0)
        };
        let inside: Vec<bool> = self
            .contact
            .iter()
            .map(|c| !c.tip && self.clearance(&lateral(c), indenters) < 0.0)
            .collect();
        // The contact points by lattice position, over the box that holds them.
        let mut bounds = [usize::MAX, 0, usize::MAX, 0];
        for c in self.contact.iter().filter(|c| !c.tip) {
            let (ix, iy) = (c.index as usize % nx, c.index as usize / nx);
            bounds = [
                bounds[0].min(ix),
                bounds[1].max(ix + 1),
                bounds[2].min(iy),
                bounds[3].max(iy + 1),
            ];
        }
        let width = bounds[1].saturating_sub(bounds[0]);
        let mut at = vec![usize::MAX; width * bounds[3].saturating_sub(bounds[2])];
        let cell = |index: u32| {
            let (ix, iy) = (index as usize % nx, index as usize / nx);
            (iy - bounds[2]) * width + ix - bounds[0]
        };
        for (k, c) in self.contact.iter().enumerate() {
            if !c.tip {
                at[cell(c.index)] = k;
            }
        }
        let reach = [0, 1].map(|a| {
            ((PATCH_REACH * self.resolved_radius / self.spacing[a]).ceil() as usize).max(1)
        });
        let window = |index: u32| {
            let (ix, iy) = (index as usize % nx, index as usize / nx);
            let xs = ix.saturating_sub(reach[0]).max(bounds[0])..(ix + reach[0] + 1).min(bounds[1]);
            let ys = iy.saturating_sub(reach[1]).max(bounds[2])..(iy + reach[1] + 1).min(bounds[3]);
            ys.flat_map(move |jy| xs.clone().map(move |jx| jy * nx + jx))
        };
        // Patches: footprint points connected through footprint points within reach.
        let mut patch = vec![usize::MAX; self.contact.len()];
        let mut softs: Vec<f64> = Vec::new();
        for start in 0..self.contact.len() {
            if !inside[start] || patch[start] != usize::MAX {
                continue;
            }
            let id = softs.len();
            let mut list = vec![start];
            patch[start] = id;
            let mut next = 0;
            while next < list.len() {
                let index = self.contact[list[next]].index;
                next += 1;
                for n in window(index) {
                    let k = at[cell(n as u32)];
                    if k != usize::MAX && inside[k] && patch[k] == usize::MAX {
                        patch[k] = id;
                        list.push(k);
                    }
                }
            }
            softs.push(self.patch_softness(list.len() as f64));
        }
        // Every point takes its patch's factor, or that of a patch within reach (a point
        // just outside the footprint, where the gel bulges against the indenter).
        for k in 0..self.contact.len() {
            let c = &self.contact[k];
            if c.tip {
                continue;
            }
            let soft = if patch[k] != usize::MAX {
                softs[patch[k]]
            } else {
                window(c.index)
                    .map(|n| at[cell(n as u32)])
                    .find(|&j| j != usize::MAX && patch[j] != usize::MAX)
                    .map_or(1.0, |j| softs[patch[j]])
            };
            self.contact[k].soft = soft;
            self.softness[self.contact[k].index as usize] = soft;
        }
    }

    /// The penalty factor of the points of a contact patch whose rigid footprint covers
    /// `n` lattice points' shares of the face.
    pub(super) fn patch_softness(&self, n: f64) -> f64 {
        if !(self.resolved_radius > 0.0) {
            return 1.0;
        }
        let radius = (n * self.area / std::f64::consts::PI).sqrt();
        let compliance = (1.0 / radius - 1.0 / self.resolved_radius).max(0.0) / (2.0 * self.e_star);
        1.0 / (1.0 + PENALTY * self.area * n * compliance)
    }
}
