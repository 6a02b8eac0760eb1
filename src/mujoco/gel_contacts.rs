//! The implicit coupling's side in MuJoCo (`gel_geom`): MuJoCo's contacts between the geom
//! that stands for the gel and the indenters, and the constraint rows through which they
//! carry the gel's push-back.
//!
//! MuJoCo builds a contact's constraint rows in its position stage and their reference
//! accelerations from `efc_KBIP`, `efc_pos` and `efc_margin` right after the passive
//! stage, where the coupling runs. The coupling rewrites those rows ([`implicit_row`]):
//! MuJoCo's constraint solve then gives each of them the gel's force at the end of the
//! step, solved together with everything else that acts on the bodies (gravity, the
//! actuators, the other gel, the table), and its elliptic cone keeps the friction within
//! the gel's Coulomb cone. The rows' island copies (`iefc_D`, `iefc_R`), made in the
//! position stage, are rewritten with them.

use nalgebra::{Isometry3, Vector3};

use super::sys;
use crate::sensor::coupling::{implicit_row, ImplicitRow, Linearised};

/// One of MuJoCo's contacts between the gel's geom and a geom that may press the gel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GelContact {
    /// Its index in `mjData.contact`.
    pub index: usize,
    /// The pressing geom.
    pub geom: usize,
    /// +1 where the pressing geom is the contact's second (its normal points from the gel
    /// at it), -1 where it is the first.
    pub sign: f64,
    /// How deep the pressing geom reaches into the gel's geom (m, at least 0).
    pub depth: f64,
}

/// The contacts of `d` between geom `gel` and the geoms `presses` accepts, that have
/// constraint rows.
///
/// # Safety
/// `d` must be a valid `mjData` after MuJoCo's position stage.
pub unsafe fn gel_contacts(
    d: &sys::mjData,
    gel: usize,
    presses: impl Fn(usize) -> bool,
) -> Vec<GelContact> {
    let n = usize::try_from(d.ncon).unwrap_or(0);
    if n == 0 || d.contact.is_null() {
        return Vec::new();
    }
    // SAFETY: MuJoCo holds `ncon` contacts behind `contact` (the caller's data).
    let contacts = unsafe { std::slice::from_raw_parts(d.contact, n) };
    let gel = gel as i32;
    let mut out = Vec::new();
    for (index, c) in contacts.iter().enumerate() {
        if c.efc_address < 0 || c.exclude != 0 {
            continue;
        }
        let (other, sign) = match c.geom {
            [g, o] if g == gel => (o, 1.0),
            [o, g] if g == gel => (o, -1.0),
            _ => continue,
        };
        let Ok(geom) = usize::try_from(other) else {
            continue;
        };
        if !presses(geom) {
            continue;
        }
        out.push(GelContact {
            index,
            geom,
            sign,
            depth: if c.dist.is_finite() {
                (-c.dist).max(0.0)
            } else {
                0.0
            },
        });
    }
    out
}

/// Rewrites the constraint rows of `contacts` so that MuJoCo's solve gives each the gel's
/// force implicitly: `push(geom)` is the push-back on a pressing geom (sensor frame,
/// [`Linearised`]; `None`: none), shared evenly by its contacts; `site` the sensor's pose,
/// `tau` the gel's Kelvin-Voigt retardation time, `friction` its Coulomb coefficient (the
/// elliptic cone's, set on the contact with the cone's parameter `mu` remade from the new
/// rows as MuJoCo makes it). An elliptic cone (or a frictionless contact) takes
/// the force along the normal and both tangents; a pyramidal one along the normal only,
/// on each of its edges alike. Torsional and rolling rows stay MuJoCo's.
///
/// # Safety
/// `m` and `d` must be a valid model and data after MuJoCo's position stage and before its
/// constraint solve; `contacts` must be [`gel_contacts`] of this `d`.
pub unsafe fn write_rows(
    m: &sys::mjModel,
    d: *mut sys::mjData,
    contacts: &[GelContact],
    site: &Isometry3<f64>,
    tau: f64,
    friction: f64,
    push: impl Fn(usize) -> Option<Linearised>,
) {
    let h = m.opt.timestep;
    if !(h > 0.0) || contacts.is_empty() {
        return;
    }
    let elliptic = m.opt.cone == sys::mjCONE_ELLIPTIC as i32;
    let islands = m.opt.disableflags & sys::mjDSBL_ISLAND as i32 == 0;
    // SAFETY: valid data per the caller; no other reference into it lives here.
    let d = unsafe { &mut *d };
    let nefc = usize::try_from(d.nefc).unwrap_or(0);
    let share = |geom: usize| contacts.iter().filter(|c| c.geom == geom).count() as f64;
    for c in contacts {
        // SAFETY: `c.index` < ncon (gel_contacts).
        let con = unsafe { &mut *d.contact.add(c.index) };
        let dim = usize::try_from(con.dim).unwrap_or(0).max(1);
        let Ok(efc) = usize::try_from(con.efc_address) else {
            continue;
        };
        let p = push(c.geom);
        let n = share(c.geom);
        // The force (world) and the stiffness along a world axis, this contact's share.
        let force = p.map_or_else(Vector3::zeros, |p| site.rotation * p.force) / n;
        let stiffness = |axis: &Vector3<f64>| {
            p.map_or(0.0, |p| {
                let a = site.rotation.inverse() * axis;
                (p.tangential * (a.x * a.x + a.y * a.y) + p.normal * a.z * a.z) / n
            })
        };
        let axis =
            |j: usize| Vector3::new(con.frame[3 * j], con.frame[3 * j + 1], con.frame[3 * j + 2]);
        let rows: Vec<(usize, ImplicitRow)> = if elliptic || dim == 1 {
            (0..dim.min(3))
                .map(|j| {
                    let a = axis(j);
                    (
                        efc + j,
                        implicit_row(c.sign * force.dot(&a), stiffness(&a), h, tau),
                    )
                })
                .collect()
        } else {
            let edges = 2 * (dim - 1);
            let a = axis(0);
            let k = edges as f64;
            let row = implicit_row(c.sign * force.dot(&a) / k, stiffness(&a) / k, h, tau);
            (efc..efc + edges).map(|r| (r, row)).collect()
        };
        for (r, row) in rows {
            if r >= nefc {
                continue;
            }
            // SAFETY: r < nefc; MuJoCo allocates these arrays with nefc rows (KBIP with 4
            // numbers a row) and map_efc2iefc with nefc entries.
            unsafe {
                let kbip = d.efc_KBIP.add(4 * r);
                *kbip = 1.0;
                *kbip.add(1) = 1.0 / h;
                *kbip.add(2) = 1.0;
                *kbip.add(3) = 0.0;
                *d.efc_pos.add(r) = *d.efc_margin.add(r) - row.offset;
                *d.efc_D.add(r) = row.mass;
                *d.efc_R.add(r) = 1.0 / row.mass;
                if islands && d.nisland > 0 && !d.map_efc2iefc.is_null() {
                    if let Ok(i) = usize::try_from(*d.map_efc2iefc.add(r)) {
                        if i < nefc {
                            *d.iefc_D.add(i) = row.mass;
                            *d.iefc_R.add(i) = 1.0 / row.mass;
                        }
                    }
                }
            }
        }
        if elliptic && dim >= 3 {
            // The cone's parameter as MuJoCo's position stage makes it from the rows'
            // regularisers, `friction sqrt(R_t / R_n)`, with the rows' new ones and the
            // gel's friction.
            if friction > 0.0 {
                con.friction[0] = friction;
                con.friction[1] = friction;
            }
            if efc + 1 < nefc {
                // SAFETY: both rows < nefc.
                let (dn, dt) = unsafe { (*d.efc_D.add(efc), *d.efc_D.add(efc + 1)) };
                con.mu = con.friction[0] * (dn / dt).sqrt();
            }
        }
    }
}
