//! Contacts smaller than the grid resolves: a compliance in series with each patch, and
//! tip points between the contact lattice's points.
//!
//! The gel's surface is the quadratic B-spline field of the grid's nodes, which cannot
//! bend over much less than a cell: under a load on a patch much smaller than that the
//! grid deflects about as it does under a point load, and is too stiff. What it misses is
//! measured once per gel ([`Newton::calibrate_subgrid`]): with the rest stiffness
//! factored, uniform unit loads on the contact lattice points within discs of growing
//! radius `r` near the gel's centre give the grid's mean deflection per unit load
//! `C_g(r)`; the layer's is `C(r) = 16 / (3 pi^2 E* r)` (uniform pressure on a
//! half-space, Johnson 1985) times the bonded layer's first-order stiffening
//! `1 / (1 + beta r / h)` (Dimitriadis et al. 2002; [`crate::mpm::hertz::bonded_layer_slope`]).
//! `C_g` levels off at the point load's value below a cell while `C` grows as `1 / r`;
//! the two meet at the *resolved radius* (0.85 cells on the default coarse gel), beyond
//! which the grid needs nothing. Grids too large for that solve
//! ([`MAX_CALIBRATION_UNKNOWNS`]: finer than about 0.5 mm on the default gel) go without.
//!
//! Each contact patch gets [`SERIES_SHARE`] of `C(a) - C_g(a)` in series with its
//! penalty, shared among its `n` points (each point's spring `n c`): a patch is the
//! indenters' rigid footprint on the surface (the contact lattice points that they reach
//! at the rest height, moved laterally with the gel), points within [`PATCH_REACH`]
//! resolved radii joined, `a = sqrt(n A / pi)` (footprints of a few points measured on a
//! finer sampling); touching points next to a footprint take its patch's factor. The
//! footprint depends on the indenters alone, so the compliance is set once per substep,
//! without iteration: the points in contact, which grow as a patch softens, made a patch
//! measured from them swing between too small and too large. Patches the grid resolves
//! keep their penalty exactly.
//!
//! [`SERIES_SHARE`] is measured, not derived: the grid's response to a curved indenter is
//! softer than to the disc load it is calibrated with, so the full deficit `C - C_g` made
//! small contacts too soft. The share was chosen on the 0.5 mm sphere and holds for the
//! cone, a 2 mm sphere and four placements on the lattice (measured: `docs/solvers.md`,
//! "What the relaxation's answer depends on").
//!
//! A contact too small to reach any lattice point at all (a sharp tip pressed less than
//! the lattice's spacing into the gel) is found by sampling the surface more finely
//! around the lattice point nearest the indenter ([`TIP_SAMPLES`] per lattice spacing and
//! axis): where samples penetrate, one *tip point* at the deepest stands for them, with
//! their share of the top face, and is a patch of its own (with the lattice points near
//! it that it presses onto its indenter). It is added when no lattice point touches its
//! indenter, kept for the rest of the substep (refreshed with the lagged friction), and
//! carries no friction.

use nalgebra::Vector3;

use super::{ContactPoint, Newton, Stencil};

use crate::mpm::contact::StepIndenter;

/// Unknowns of the calibration solve above which a grid goes without the correction.
pub(super) const MAX_CALIBRATION_UNKNOWNS: usize = 60_000;

/// Samples per contact lattice spacing and axis in the search for a tip point.
pub(in crate::mpm) const TIP_SAMPLES: usize = 8;

/// Surface positions [`TIP_SAMPLES`] times finer than a contact lattice of `spacing`
/// (cells) along each axis, over the box from `lo` to `hi` (cells) grown by a spacing, at
/// `lo`'s height; and the face share (in lattice points) that each stands for. Newton's
/// and the linear solver's search for a tip point.
pub(in crate::mpm) fn tip_samples(
    lo: Vector3<f64>,
    hi: Vector3<f64>,
    spacing: [f64; 2],
) -> (Samples, f64) {
    let step = [0, 1].map(|a| spacing[a] / TIP_SAMPLES as f64);
    let counts = [0, 1].map(|a| ((hi[a] - lo[a]) / step[a]).round() as usize + 2 * TIP_SAMPLES);
    let samples = Samples {
        from: Vector3::new(lo.x - spacing[0], lo.y - spacing[1], lo.z),
        step,
        counts,
    };
    (samples, 1.0 / (TIP_SAMPLES * TIP_SAMPLES) as f64)
}

/// A grid of surface samples, generated where read (a frame's search allocates nothing):
/// `from + (i step[0], j step[1], 0)` for `i` in `0..=counts[0]` and `j` in
/// `0..=counts[1]`, `j` fastest.
#[derive(Clone, Copy, Debug)]
pub(in crate::mpm) struct Samples {
    pub from: Vector3<f64>,
    pub step: [f64; 2],
    pub counts: [usize; 2],
}

impl Samples {
    /// The samples, in order.
    pub fn points(self) -> impl Iterator<Item = Vector3<f64>> {
        let Samples { from, step, counts } = self;
        (0..=counts[0]).flat_map(move |i| {
            (0..=counts[1]).map(move |j| {
                Vector3::new(
                    from.x + i as f64 * step[0],
                    from.y + j as f64 * step[1],
                    from.z,
                )
            })
        })
    }
}

/// Distance, in resolved radii, within which touching points belong to one patch: the
/// grid does not tell apart loads closer than it resolves (the rim of a round contact on
/// the square lattice touches in separate clusters around the main patch, and the
/// bumps of a texture finer than a cell load the grid as one contact).
const PATCH_REACH: f64 = 1.0;

/// Footprints of at most this many lattice points are measured finer.
const FINE_FOOTPRINT: usize = 4;

/// Share of the missing compliance put in series with a patch.
const SERIES_SHARE: f64 = 0.5;

/// Cells of the calibration region beyond the layer's thickness on each side of the
/// loaded column.
const CALIBRATION_MARGIN: f64 = 3.0;

impl Newton {
    /// Measures the grid's compliance under small loaded discs (see the module docs) and
    /// keeps it up to the resolved radius, where the grid's compliance reaches the
    /// layer's; nothing where the grid is too large for the solve or the solve fails.
    /// Leaves the solver without a region and with zero displacement, as built.
    pub(super) fn calibrate_subgrid(&mut self) {
        self.grid_compliance.clear();
        self.resolved_radius = 0.0;
        let half = (self.top + CALIBRATION_MARGIN).ceil() as usize;
        let (cx, cy) = (self.dims[0] / 2, self.dims[1] / 2);
        let bx = [
            cx.saturating_sub(half),
            (cx + half + 1).min(self.dims[0]),
            cy.saturating_sub(half),
            (cy + half + 1).min(self.dims[1]),
        ];
        let columns = (bx[1] - bx[0]) * (bx[3] - bx[2]);
        if 3 * columns * self.dims[2] <= MAX_CALIBRATION_UNKNOWNS && self.factor_rest(bx) {
            let table = self.disc_compliances(bx);
            // The first disc the grid resolves ends the table.
            let mut last = None;
            for (k, &(r, c)) in table.iter().enumerate() {
                let missing = self.layer_compliance(r) - c;
                if !(missing > 0.0) {
                    if let Some(&(r0, c0)) = k.checked_sub(1).and_then(|j| table.get(j)) {
                        let m0 = self.layer_compliance(r0) - c0;
                        let t = m0 / (m0 - missing);
                        self.resolved_radius = r0 + t * (r - r0);
                    }
                    last = Some(k);
                    break;
                }
            }
            if let Some(k) = last {
                self.grid_compliance = table[..k].to_vec();
            } else {
                // No disc it resolves within the table: no correction at all.
                self.resolved_radius = 0.0;
            }
        }
        // Back to the state of a new solver: no region, no kept system.
        self.system = None;
        self.region = None;
        self.u.fill(0.0);
    }

    /// The mean deflection per unit load (cells per internal force unit) of a uniform
    /// pressure on a disc of radius `r` (cells) on the layer: `16 / (3 pi^2 E* r)` on a
    /// half-space (Johnson 1985, 3.4), less the bonded layer's first-order stiffening.
    fn layer_compliance(&self, r: f64) -> f64 {
        16.0 / (3.0 * std::f64::consts::PI.powi(2) * self.e_star * r)
            / (1.0 + self.layer_slope * r / self.thickness)
    }

    /// The compliance a patch of contact radius `r` (cells) misses on this grid: the
    /// layer's less the grid's (interpolated in the table; below its smallest disc, of
    /// four lattice points, the grid's is that disc's: it levels off there), zero from the
    /// resolved radius on.
    pub(super) fn missing_compliance(&self, r: f64) -> f64 {
        let table = &self.grid_compliance;
        if table.is_empty() || !(r < self.resolved_radius) || !(r > 0.0) {
            return 0.0;
        }
        let grid = match table.iter().position(|&(t, _)| t >= r) {
            Some(0) => table[0].1,
            Some(k) => {
                let ((r0, c0), (r1, c1)) = (table[k - 1], table[k]);
                c0 + (c1 - c0) * (r - r0) / (r1 - r0)
            }
            None => {
                // Between the last disc and the resolved radius, where the two meet.
                let (r0, c0) = table[table.len() - 1];
                let (r1, c1) = (
                    self.resolved_radius,
                    self.layer_compliance(self.resolved_radius),
                );
                c0 + (c1 - c0) * (r - r0) / (r1 - r0)
            }
        };
        (self.layer_compliance(r) - grid).max(0.0)
    }

    /// Makes `bx` the region, at rest, and factors its stiffness; whether that worked.
    fn factor_rest(&mut self, bx: [usize; 4]) -> bool {
        if self.set_region(bx).is_err() {
            return false;
        }
        self.u.fill(0.0);
        if self.evaluate(&[]).is_none() {
            return false;
        }
        let Some(mut system) = self.system.take() else {
            return false;
        };
        self.fill_matrix(&mut system);
        let factored = system.factor().is_ok();
        self.system = Some(system);
        factored
    }

    /// The grid's compliance (mean deflection under a unit total load, cells per internal
    /// force unit) for uniform loads on the contact lattice points within discs of
    /// growing radius around the centre of `bx`, with each disc's area radius
    /// `sqrt(n A / pi)` (cells). Needs the factored system of `bx` (as left by
    /// [`Self::factor_rest`]).
    fn disc_compliances(&mut self, bx: [usize; 4]) -> Vec<(f64, f64)> {
        let Some(system) = self.system.take() else {
            return Vec::new();
        };
        let centre = [0.5 * (bx[0] + bx[1]) as f64, 0.5 * (bx[2] + bx[3]) as f64];
        // Lattice points around a point near the centre, nearest first: the discs are
        // rings of whole lattice points.
        let [sx, sy] = self.spacing;
        let first = [
            self.first[0] + ((centre[0] - self.first[0]) / sx).floor() * sx,
            self.first[1] + ((centre[1] - self.first[1]) / sy).floor() * sy,
        ];
        let reach = (3.0 / sx.min(sy)).ceil() as i64;
        let mut points: Vec<(f64, Vector3<f64>)> = Vec::new();
        for i in -reach..=reach {
            for j in -reach..=reach {
                let p = Vector3::new(first[0] + i as f64 * sx, first[1] + j as f64 * sy, self.top);
                let r = ((p.x - centre[0] - 0.5 * sx).powi(2)
                    + (p.y - centre[1] - 0.5 * sy).powi(2))
                .sqrt();
                points.push((r, p));
            }
        }
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut table = Vec::new();
        let mut rhs = vec![0.0; system.n];
        let mut count = 4;
        while count <= points.len() && points[count - 1].0 < 2.5 {
            // Whole rings only.
            while count < points.len() && points[count].0 - points[count - 1].0 < 1e-9 {
                count += 1;
            }
            rhs.fill(0.0);
            let share = 1.0 / count as f64;
            let stencils: Vec<Stencil> =
                points[..count].iter().map(|p| Stencil::at(&p.1)).collect();
            for st in &stencils {
                for l in 0..27 {
                    if let Some(d) = self.local_at(&st.base, l) {
                        rhs[3 * d + 2] -= share * st.weight(l);
                    }
                }
            }
            system.solve(&mut rhs);
            let mut down = 0.0;
            for st in &stencils {
                for l in 0..27 {
                    if let Some(d) = self.local_at(&st.base, l) {
                        down -= share * st.weight(l) * rhs[3 * d + 2];
                    }
                }
            }
            let radius = (count as f64 * self.area / std::f64::consts::PI).sqrt();
            table.push((radius, down));
            count = ((count as f64 * 1.3).ceil() as usize).max(count + 1);
        }
        self.system = Some(system);
        table
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
        let had_tip = |m: usize| old.iter().any(|c| c.index == count + m as u32);
        // An indenter that a lattice point touches needs no search (the common case: any
        // contact the lattice resolves), unless it has a tip already.
        let touched: Vec<bool> = indenters
            .iter()
            .map(|ind| {
                self.contact.iter().any(|c| {
                    let x = c.rest + self.displacement(&c.stencil, &self.u);
                    self.distance_to(&x, ind) < 0.0
                })
            })
            .collect();
        if old.is_empty() && touched.iter().all(|&t| t) {
            return 0.0;
        }
        let positions: Vec<Vector3<f64>> = self
            .contact
            .iter()
            .map(|c| c.rest + self.displacement(&c.stencil, &self.u))
            .collect();
        let mut nearest: Vec<Option<(f64, Vector3<f64>)>> = vec![None; indenters.len()];
        for (m, near) in nearest.iter_mut().enumerate() {
            if touched[m] && !had_tip(m) {
                continue;
            }
            for (c, x) in self.contact.iter().zip(&positions) {
                let d = self.distance_to(x, &indenters[m]);
                if d.is_finite() && near.map_or(true, |(b, _)| d < b) {
                    *near = Some((d, c.rest));
                }
            }
        }
        let mut change = 0.0f64;
        for (m, near) in nearest.iter().enumerate() {
            // A tip stays for the rest of the substep once there, even where it has
            // pressed the gel onto a lattice point (which would otherwise let the tip go,
            // the gel spring back off the point, and the tip come back).
            let before = old.iter().find(|c| c.index == count + m as u32);
            let tip = match near {
                Some((_, rest)) if !touched[m] || before.is_some() => {
                    self.find_tip(rest, &indenters[m])
                }
                _ => None,
            };
            change = change.max(match (before, &tip) {
                (None, None) => 0.0,
                (Some(b), Some(t)) => (t.1 - b.weight).abs() / b.weight,
                _ => 1.0,
            });
            if let Some((rest, weight)) = tip {
                let stencil = Stencil::at(&rest);
                // Lattice points near the tip that it has pressed onto its indenter share
                // its patch (its samples cover them already).
                let reach = PATCH_REACH * self.resolved_radius;
                let shared: Vec<usize> = (0..positions.len())
                    .filter(|&k| {
                        (self.contact[k].rest - rest).norm() <= reach
                            && self.distance_to(&positions[k], &indenters[m]) < 0.0
                    })
                    .collect();
                let soft = self.patch_softness(weight, weight + shared.len() as f64);
                for k in shared {
                    let c = &mut self.contact[k];
                    change = change.max((soft - c.soft).abs() / c.soft);
                    c.soft = soft;
                }
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
    /// elements around the lattice point at `rest` (each displaced with the gel), and the
    /// samples' penetrating share of one lattice point's face.
    fn find_tip(
        &self,
        rest: &Vector3<f64>,
        indenter: &StepIndenter,
    ) -> Option<(Vector3<f64>, f64)> {
        let (samples, share) = tip_samples(*rest, *rest, self.spacing);
        let mut deepest: Option<(f64, Vector3<f64>)> = None;
        let mut inside = 0usize;
        for at in samples.points() {
            let x = at + self.displacement(&Stencil::at(&at), &self.u);
            let d = self.distance_to(&x, indenter);
            if d < 0.0 {
                inside += 1;
                if deepest.map_or(true, |(b, _)| d < b) {
                    deepest = Some((d, at));
                }
            }
        }
        deepest.map(|(_, at)| (at, (inside as f64 * share).min(1.0)))
    }

    /// The rigid footprint (in lattice points' shares of the face) over the lattice
    /// elements around the contact points `members`, sampled at the rest height, moved
    /// laterally with the gel (at least one sample's share).
    fn fine_footprint(&self, members: &[usize], indenters: &[StepIndenter]) -> f64 {
        let mut lo = Vector3::repeat(f64::INFINITY);
        let mut hi = Vector3::repeat(f64::NEG_INFINITY);
        for &k in members {
            let c = &self.contact[k];
            let d = self.displacement(&c.stencil, &self.u);
            let x = c.rest + Vector3::new(d.x, d.y, 0.0);
            lo = lo.inf(&x);
            hi = hi.sup(&x);
        }
        let (samples, share) = tip_samples(lo, hi, self.spacing);
        let inside = samples
            .points()
            .filter(|x| self.clearance(x, indenters) < 0.0)
            .count();
        (inside as f64 * share).max(share)
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
            let n = list.len() as f64;
            // A footprint of a few lattice points is measured finer: one lattice point
            // stands for the whole of its share however little of it the indenter
            // covers.
            let area = if list.len() <= FINE_FOOTPRINT {
                self.fine_footprint(&list, indenters)
            } else {
                n
            };
            softs.push(self.patch_softness(area, n));
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
        }
    }

    /// The penalty factor of the points of a contact patch whose rigid footprint covers
    /// `n` lattice points' shares of the face, shared among points of `share` lattice
    /// points' shares.
    pub(super) fn patch_softness(&self, n: f64, share: f64) -> f64 {
        let radius = (n * self.area / std::f64::consts::PI).sqrt();
        let compliance = SERIES_SHARE * self.missing_compliance(radius);
        1.0 / (1.0 + self.penalty * self.area * share * compliance)
    }
}
