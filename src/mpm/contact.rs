//! Indenter contact on the surface points of the top particles.
//!
//! Each top particle `p` carries a surface point `s_p = x_p + d_p`, `d_p = (s_z / 2) F e_z`
//! (half the vertical particle spacing along the deformed vertical material fibre), the
//! same point that the depth image shows. Contact is a constraint on these points: the
//! signed distance `g_p` from `s_p` to the nearest indenter must not be negative. It is
//! imposed with an augmented Lagrangian (Uzawa) penalty, Simo and Laursen 1992:
//!
//! * normal force `f_n = max(0, lambda_p - k g_p)` along the indenter's outward normal;
//! * multiplier update `lambda_p <- max(0, lambda_p - k_i g_p)` every step, so that at
//!   equilibrium `g_p = 0` wherever `f_n > 0` (exact non-penetration, no penalty error);
//! * Coulomb friction by a tangential spring to a stick anchor fixed in the indenter's
//!   frame (Wriggers, "Computational Contact Mechanics", Sec. 5.2), `f_t = -k (s_p -
//!   A_p)_t`, capped at `mu f_n`; when the cap is reached the anchor slides to keep the
//!   spring at its limit length (return mapping). Anchors and multipliers persist between
//!   solves, so a sliding contact keeps its shear history and the next frame starts from
//!   the previous contact forces (warm start).
//!
//! The force `f_p = f_n n + f_t` acts on the surface point; its nodal forces are the
//! adjoint of the surface point's velocity. With `s_p` advanced by G2P as
//! `x_p + v_p + (I + C_p) d_p`, `v_p = sum w_ip v_i`, `C_p = 4 sum w_ip v_i (x_i - x_p)^T`,
//! `ds_p / dv_i = w_ip (1 + 4 (x_i - x_p) . d_p)`, so node `i` gets
//! `w_ip (1 + 4 (x_i - x_p) . d_p) f_p` (virtual work, so the total force and its moment
//! are exactly those of `f_p` at `s_p`). The force on the indenters is `-sum f_p`.
//!
//! Contact acting on a point of the surface, rather than as a velocity constraint on the
//! grid nodes of the top cells, gives a force that converges under refinement: the nodal
//! constraint pinned every node within the top particles' stencil (1.5 cells deep) to the
//! indenter, a rigid slab one to two cells thick that stiffened the contact.

use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

use super::transfer::{Node, Particle, Region, Stencil, StepCtx};
use super::Layout;
use crate::geometry::{Aabb, Sdf};

/// A surface point farther than this from every indenter (cells) is not queried further
/// (the indenters move at most `sweep_rate` cells per step, far less than this).
pub(crate) const CONTACT_BAND: f32 = 1.0;

/// Penalty stiffness `k` (internal units: `M dx` per cell of penetration). About the
/// stiffness of the elastic half-space under one surface particle; stable with the
/// explicit step, with room to spare (measured: `docs/solvers.md`, "A wide flat contact
/// on a finer grid: the multipliers' gain").
const STIFFNESS: f32 = 1.0;

/// Multiplier gain `k_i / k` of the augmented Lagrangian update on a layer at most
/// [`GAIN_CELLS`] cells thick.
const MULTIPLIER_GAIN: f32 = 0.25;

/// Layer thickness (cells) above which the multiplier gain falls as `1 / cells`.
///
/// The multipliers integrate the penetration, and the penetration answers a change of
/// multiplier through the layer's slowest modes, whose period in steps grows with the
/// number of cells through the layer. An integral gain that is fine on the coarse grid
/// (2.9 cells) drives a slow oscillation of a wide contact patch on the fine grid (13
/// cells), which ends at the iteration cap far from equilibrium. Scaling the gain with
/// the slowest mode's rate keeps the loop as damped at every resolution; at equilibrium
/// the gain plays no part. Too low a gain costs steps instead, so the gain starts to fall
/// only above this thickness (measured: `docs/solvers.md`, "A wide flat contact on a
/// finer grid: the multipliers' gain").
const GAIN_CELLS: f32 = 6.4;

/// The multiplier gain `k_i / k` for a layer `cells` thick.
pub(crate) fn multiplier_gain(cells: f64) -> f32 {
    MULTIPLIER_GAIN * (GAIN_CELLS / cells as f32).min(1.0)
}

/// An indenter during one step: pose now and one step earlier, bounding box of both.
#[derive(Clone, Debug)]
pub(crate) struct StepIndenter {
    pub shape: Arc<dyn Sdf>,
    pub now: Isometry3<f64>,
    pub bounds: Aabb,
}

/// Contact memory of one top particle, kept between steps and solves.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SlotContact {
    /// Normal multiplier `lambda_p` (internal force units).
    pub lambda: f32,
    /// Indenter that `lambda` belongs to, the nearest at the last update (`u32::MAX`:
    /// none); lets [`super::Gel::solve`] release it when that indenter leaves.
    pub owner: u32,
    /// Indenter holding the stick anchor (`u32::MAX`: none).
    pub indenter: u32,
    /// Stick anchor in that indenter's frame (m).
    pub anchor: Point3<f64>,
    /// Low-pass filtered gap (cells) the multiplier integrates, where
    /// [`ContactInput::filter`] is below 1.
    pub gbar: f32,
}

impl SlotContact {
    pub const NONE: SlotContact = SlotContact {
        lambda: 0.0,
        owner: u32::MAX,
        indenter: u32::MAX,
        anchor: Point3::new(0.0, 0.0, 0.0),
        gbar: 0.0,
    };
}

/// Force of this step on one top particle's surface point.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ActiveContact {
    /// Particle index.
    pub particle: u32,
    /// Force on the gel (internal units, impulse per step).
    pub f: Vector3<f32>,
    /// `d_p`, particle to surface point (cells).
    pub d: Vector3<f32>,
    /// Residual of the constraint, `k |g|`.
    pub residual: f32,
}

/// Everything the contact update reads, bundled.
pub(crate) struct ContactInput<'a> {
    pub layout: &'a Layout,
    pub half_top: f32,
    pub particles: &'a [Particle],
    pub top: &'a [u32],
    pub indenters: &'a [StepIndenter],
    pub friction: f32,
    /// Multiplier gain `k_i / k` ([`multiplier_gain`]).
    pub gain: f32,
    /// Weight of the new gap in the filtered gap the multiplier integrates (1: none).
    pub filter: f32,
    /// The solve's active region: slots outside it keep their state and get no force.
    pub region: &'a Region,
}

/// Updates every top particle's contact (multiplier, anchor) against `indenters` and
/// writes the forces of this step into `out[slot]` (`None` where there is no force).
pub(crate) fn update_contacts(
    input: &ContactInput<'_>,
    state: &mut [SlotContact],
    out: &mut [Option<ActiveContact>],
) {
    let nxp = input.layout.lattice[0];
    state
        .par_chunks_mut(256)
        .zip(out.par_chunks_mut(256))
        .enumerate()
        .for_each(|(ci, (st, o))| {
            for (j, (c, out)) in st.iter_mut().zip(o.iter_mut()).enumerate() {
                let slot = ci * 256 + j;
                *out = if input.region.holds(slot % nxp, slot / nxp) {
                    slot_contact(input, slot, c)
                } else {
                    None
                };
            }
        });
}

/// The contact of top slot `slot` in this step: updates its memory `c` (multiplier,
/// owner, stick anchor) and returns the force on its surface point, if any.
fn slot_contact(
    input: &ContactInput<'_>,
    slot: usize,
    c: &mut SlotContact,
) -> Option<ActiveContact> {
    let layout = input.layout;
    let dx = layout.dx;
    let k = STIFFNESS;
    let ki = STIFFNESS * input.gain;
    let pi = input.top[slot];
    let p = &input.particles[pi as usize];
    let d = p.f.column(2) * input.half_top;
    let s = (p.x + d).cast::<f64>();
    let s = Point3::from(layout.origin + s * dx);
    let Some((i, dist, local)) = nearest(input.indenters, &s) else {
        *c = SlotContact::NONE;
        return None;
    };
    let g = (dist * (1.0 / dx)) as f32;
    if g >= CONTACT_BAND && c.lambda <= 0.0 {
        *c = SlotContact::NONE;
        return None;
    }
    let ind = &input.indenters[i];
    let n = (ind.now.rotation * ind.shape.gradient(&local)).cast::<f32>();
    if !n.iter().all(|v| v.is_finite()) {
        *c = SlotContact::NONE;
        return None;
    }
    // Augmented Lagrangian normal force and multiplier update.
    let fn_ = (c.lambda - k * g).max(0.0);
    let ga = if input.filter < 1.0 {
        c.gbar += input.filter * (g - c.gbar);
        c.gbar
    } else {
        g
    };
    c.lambda = (c.lambda - ki * ga).max(0.0);
    c.owner = i as u32;
    if fn_ <= 0.0 {
        c.indenter = u32::MAX;
        return None;
    }
    let mut f = n * fn_;
    let mu = input.friction;
    if mu > 0.0 {
        if c.indenter != i as u32 {
            c.indenter = i as u32;
            c.anchor = local;
        }
        f += stick_force(c, ind, &s, &n, mu * fn_, dx);
    }
    Some(ActiveContact {
        particle: pi,
        f,
        d,
        residual: k * g.abs(),
    })
}

/// The nearest indenter whose (inflated) box holds the surface point `s` (m): its
/// index, the signed distance and `s` in its frame.
fn nearest(indenters: &[StepIndenter], s: &Point3<f64>) -> Option<(usize, f64, Point3<f64>)> {
    let mut best: Option<(usize, f64, Point3<f64>)> = None;
    for (i, ind) in indenters.iter().enumerate() {
        let b = &ind.bounds;
        let inside = (0..3).all(|k| s[k] >= b.min[k] && s[k] <= b.max[k]);
        if !inside {
            continue;
        }
        let local = ind.now.inverse_transform_point(s);
        let dist = ind.shape.distance(&local);
        if dist.is_finite() && best.map_or(true, |b| dist < b.1) {
            best = Some((i, dist, local));
        }
    }
    best
}

/// Tangential force of the stick spring from the surface point `s` (m) to the anchor of
/// `c` on indenter `ind`, normal `n`, capped at `cap` (Coulomb); past the cap the anchor
/// slides so that the spring sits at its limit length.
fn stick_force(
    c: &mut SlotContact,
    ind: &StepIndenter,
    s: &Point3<f64>,
    n: &Vector3<f32>,
    cap: f32,
    dx: f64,
) -> Vector3<f32> {
    let a = ind.now * c.anchor;
    let del = ((s - a) * (1.0 / dx)).cast::<f32>();
    let del_t = del - n * n.dot(&del);
    let ft = del_t * -STIFFNESS;
    let t = ft.norm();
    if t > cap {
        let scale = cap / t;
        let back = (del_t * scale).cast::<f64>() * dx;
        c.anchor = ind.now.inverse_transform_point(&(s - back));
        ft * scale
    } else {
        ft
    }
}

/// Adds the nodal forces of the contact forces to the grid's stress force (see the module
/// docs), in slot order (deterministic). Returns the total force on the gel.
pub(crate) fn scatter_contacts(
    ctx: &StepCtx,
    stencils: &[Stencil],
    active: &[Option<ActiveContact>],
    grid: &mut [Node],
) -> [f64; 3] {
    let [_, ny, nz] = ctx.dims;
    let mut total = [0.0f64; 3];
    for a in active.iter().flatten() {
        let st = &stencils[a.particle as usize];
        let (bx, fx, wx) = st.axis(0);
        let (by, fy, wy) = st.axis(1);
        let (bz, fz, wz) = st.axis(2);
        for (i, &wxi) in wx.iter().enumerate() {
            let ax = 4.0 * a.d.x * (i as f32 - fx);
            for (jy, &wyj) in wy.iter().enumerate() {
                let axy = ax + 4.0 * a.d.y * (jy as f32 - fy);
                let row = ((bx + i) * ny + by + jy) * nz + bz;
                for (kz, &wzk) in wz.iter().enumerate() {
                    let s = wxi * wyj * wzk * (1.0 + axy + 4.0 * a.d.z * (kz as f32 - fz));
                    grid[row + kz].add_f(a.f * s);
                }
            }
        }
        for (t, fk) in total.iter_mut().zip(a.f.iter()) {
            *t += *fk as f64;
        }
    }
    total
}
