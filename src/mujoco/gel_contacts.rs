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
//! position stage, are rewritten with them. Where MuJoCo's contact points do not surround
//! the gel's centre of pressure, their rows' Jacobians are moved there ([`shift_rows`]),
//! so that the solve takes the force's moment about the body implicitly, as it takes the
//! force.

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

/// How far from the gel's normal (the cosine of the angle) a contact's normal may lie for
/// it to carry the gel's push-back: contacts on the gel geom's other faces (an object
/// against the pad's side, which the gel's model does not see) stay MuJoCo's own.
pub const FACING: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// The contacts of `d` between geom `gel` and the geoms `presses` accepts, that have
/// constraint rows and whose normal lies within [`FACING`] of the gel's `normal` (world).
///
/// # Safety
/// `d` must be a valid `mjData` after MuJoCo's position stage.
pub unsafe fn gel_contacts(
    d: &sys::mjData,
    gel: usize,
    normal: &Vector3<f64>,
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
        let n = Vector3::new(c.frame[0], c.frame[1], c.frame[2]);
        if !presses(geom) || !(n.dot(normal).abs() >= FACING) {
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

/// How a pressing geom's push-back is shared among its contacts at `points` (world, on the
/// gel's face, whose in-plane axes are `axes`): weights adding up to one whose weighted
/// centre is the gel's centre of pressure `centre` where that lies within the points'
/// reach (the least change from an even share that puts it there, along the line where the
/// points lie in one), so that the contacts' torque is the gel's; none negative (clipped,
/// and shared anew), adding up to one. Even without a centre, with one point, or with
/// points that lie within [`COINCIDENT`] of one place.
pub fn shares(
    points: &[Vector3<f64>],
    centre: Option<Vector3<f64>>,
    axes: [Vector3<f64>; 2],
) -> Vec<f64> {
    let n = points.len();
    let even = vec![1.0 / n.max(1) as f64; n];
    let Some(centre) = centre.filter(|_| n > 1) else {
        return even;
    };
    let mean = points.iter().sum::<Vector3<f64>>() / n as f64;
    // In-plane offsets of the points from their mean, and of the centre.
    let a: Vec<nalgebra::Vector2<f64>> = points
        .iter()
        .map(|p| nalgebra::Vector2::new((p - mean).dot(&axes[0]), (p - mean).dot(&axes[1])))
        .collect();
    let target =
        nalgebra::Vector2::new((centre - mean).dot(&axes[0]), (centre - mean).dot(&axes[1]));
    // w = 1/n + A^T y with A A^T y = target (A: 2 x n): the least change from the even
    // share, which keeps the sum since the offsets sum to zero.
    // The pseudo-inverse: points in a line (a cylinder lying on the gel) move the centre
    // along the line only.
    let aat = a
        .iter()
        .fold(nalgebra::Matrix2::zeros(), |m, v| m + v * v.transpose());
    let eigen = nalgebra::SymmetricEigen::new(aat);
    let largest = eigen.eigenvalues.amax();
    // A spread of a few units in the last place of the points' coordinates is no line to
    // move the centre along: its inverse, times the centre's offset, gave one of two
    // MuJoCo contacts at one place a share of 6e14 (and the object a couple of 5e10 N m).
    let floor = n as f64 * COINCIDENT * COINCIDENT;
    if !(largest > floor) {
        return even;
    }
    let mut y = nalgebra::Vector2::zeros();
    for (k, &lambda) in eigen.eigenvalues.iter().enumerate() {
        if lambda > (1e-9 * largest).max(floor) {
            let e = eigen.eigenvectors.column(k);
            y += e * (e.dot(&target) / lambda);
        }
    }
    let mut w: Vec<f64> = a.iter().map(|v| 1.0 / n as f64 + v.dot(&y)).collect();
    if w.iter().any(|x| !x.is_finite()) {
        return even;
    }
    // Outside the points' hull: clipped to it, and shared anew (within it the shares add
    // up to one but for round-off, taken out alike).
    for x in &mut w {
        *x = x.max(0.0);
    }
    let total: f64 = w.iter().sum();
    if !(total > 0.0 && total.is_finite()) {
        return even;
    }
    for x in &mut w {
        *x /= total;
    }
    w
}

/// How close (m) contact points lie to count as one place for [`shares`]: far below any
/// contact's size, far above the round-off of positions a metre from the origin.
pub const COINCIDENT: f64 = 1e-9;

/// Rewrites the constraint rows of `contacts` so that MuJoCo's solve gives each the gel's
/// force implicitly: `push(geom)` is the push-back on a pressing geom (sensor frame,
/// [`Linearised`]; `None`: none), shared by its contacts so that their centre is the
/// gel's centre of pressure ([`shares`]); `site` the sensor's pose,
/// `tau` the gel's Kelvin-Voigt retardation time, `friction` its Coulomb coefficient (the
/// elliptic cone's, set on the contact with the cone's parameter `mu` remade from the new
/// rows as MuJoCo makes it). An elliptic cone (or a frictionless contact) takes
/// the force along the normal and both tangents; a pyramidal one along the normal only,
/// on each of its edges alike. Torsional and rolling rows stay MuJoCo's.
///
/// Returns, for each pressing geom, the couple (world, N m) that its rows leave out
/// ([`Couple`]).
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
) -> Vec<Couple> {
    let mut couples = Vec::new();
    let h = m.opt.timestep;
    if !(h > 0.0) || contacts.is_empty() {
        return couples;
    }
    let elliptic = m.opt.cone == sys::mjCONE_ELLIPTIC as i32;
    let islands = m.opt.disableflags & sys::mjDSBL_ISLAND as i32 == 0;
    // SAFETY: valid data per the caller; no other reference into it lives here.
    let d = unsafe { &mut *d };
    let nefc = usize::try_from(d.nefc).unwrap_or(0);
    // How each pressing geom's push-back is carried by its contacts ([`carry`]).
    let mut carried = vec![(0, 0); contacts.len()];
    // The bodies' turning Jacobians, made once for a geom's contacts ([`shift_rows`]).
    let mut turns = Turns::default();
    let mut ways: Vec<(Option<Linearised>, Carried)> = Vec::new();
    for (k, c) in contacts.iter().enumerate() {
        if contacts[..k].iter().any(|e| e.geom == c.geom) {
            continue;
        }
        let mine: Vec<usize> = (k..contacts.len())
            .filter(|&j| contacts[j].geom == c.geom)
            .collect();
        // SAFETY: indices < ncon (gel_contacts).
        let points: Vec<Vector3<f64>> = mine
            .iter()
            .map(|&j| Vector3::from(unsafe { (*d.contact.add(contacts[j].index)).pos }))
            .collect();
        let p = push(c.geom);
        let way = carry(&points, p.as_ref(), site);
        if let Some(torque) = way.couple {
            couples.push(Couple {
                geom: c.geom,
                torque,
            });
        }
        for (i, &j) in mine.iter().enumerate() {
            carried[j] = (ways.len(), i);
        }
        ways.push((p, way));
    }
    for (c, &(g, i)) in contacts.iter().zip(&carried) {
        // SAFETY: `c.index` < ncon (gel_contacts).
        let con = unsafe { &mut *d.contact.add(c.index) };
        let dim = usize::try_from(con.dim).unwrap_or(0).max(1);
        let Ok(efc) = usize::try_from(con.efc_address) else {
            continue;
        };
        let (p, way) = &ways[g];
        let (p, n) = (*p, way.shares[i]);
        if way.shift != Vector3::zeros() {
            // SAFETY: valid model and data per the caller; `con` is one of its contacts,
            // its rows from `efc`.
            unsafe { shift_rows(m, d, con, efc, elliptic, &way.shift, &mut turns) };
        }
        // The force (world) and the stiffness along a world axis, this contact's share.
        let force = p.map_or_else(Vector3::zeros, |p| way.force(&p, i, site));
        let stiffness = |axis: &Vector3<f64>| {
            p.map_or(0.0, |p| {
                let a = site.rotation.inverse() * axis;
                (p.tangential * (a.x * a.x + a.y * a.y) + p.normal * a.z * a.z) * n
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
    couples
}

/// Moves the constraint rows of contact `con` (from row `efc`) from its point `x` to `x +
/// shift` (world, m), on both bodies: a row's Jacobian `a^T (J_p(b2, x) - J_p(b1, x))`
/// (`a` the row's direction, `b1` and `b2` the bodies of the contact's first and second
/// geom) becomes `a^T (J_p(b2, x + s) - J_p(b1, x + s))`, which adds `(s x a)^T (J_r(b2) -
/// J_r(b1))` (a point `s` further on a body turning at `w` moves `w x s` faster). The
/// rows' forces then act where the gel presses, and MuJoCo's solve takes the torque of
/// their force about the body implicitly with the force itself (as a couple applied on
/// the side, the lever's part of it was explicit, and a light body turned within one step
/// by many times what the gel allowed). Torsional and rolling rows turn the bodies alike
/// wherever the point: they stay. The rows' sparsity stays: the moved point is on the
/// same bodies.
///
/// `turns` keeps the bodies' turning Jacobians between calls for the same pair of bodies
/// (a geom's contacts, one after another).
///
/// # Safety
/// `m` and `d` must be a valid model and data after MuJoCo's position stage; `con` one of
/// `d`'s contacts with its rows from `efc`, between two geoms; `turns` used with this `d`
/// in this stage only.
pub unsafe fn shift_rows(
    m: &sys::mjModel,
    d: &mut sys::mjData,
    con: &sys::mjContact,
    efc: usize,
    elliptic: bool,
    shift: &Vector3<f64>,
    turns: &mut Turns,
) {
    let nv = usize::try_from(m.nv).unwrap_or(0);
    let nefc = usize::try_from(d.nefc).unwrap_or(0);
    let dim = usize::try_from(con.dim).unwrap_or(0).max(1);
    let (Ok(g1), Ok(g2)) = (usize::try_from(con.geom[0]), usize::try_from(con.geom[1])) else {
        return;
    };
    if nv == 0 || !shift.iter().all(|v| v.is_finite()) {
        return;
    }
    let axis =
        |j: usize| Vector3::new(con.frame[3 * j], con.frame[3 * j + 1], con.frame[3 * j + 2]);
    // Each row and its direction (the translational part of a pyramid's edge: the normal
    // plus or minus the friction's tangent, or the normal alone for a torsional or
    // rolling edge, as MuJoCo's position stage makes them).
    let mut rows: Vec<(usize, Vector3<f64>)> = Vec::with_capacity(2 * dim);
    if elliptic || dim == 1 {
        rows.extend((0..dim.min(3)).map(|j| (efc + j, axis(j))));
    } else {
        for k in 1..dim {
            let t = if k <= 2 {
                axis(k) * con.friction[k - 1]
            } else {
                Vector3::zeros()
            };
            rows.push((efc + 2 * (k - 1), axis(0) + t));
            rows.push((efc + 2 * (k - 1) + 1, axis(0) - t));
        }
    }
    // SAFETY: valid model per the caller; both geoms are ids of it.
    let bodies = unsafe { [*m.geom_bodyid.add(g1), *m.geom_bodyid.add(g2)] };
    if turns.bodies != Some(bodies) {
        turns.bodies = Some(bodies);
        for (jac, &body) in turns.jacobians.iter_mut().zip(&bodies) {
            jac.clear();
            jac.resize(3 * nv, 0.0);
            // SAFETY: valid model and data; `jac` holds 3 x nv numbers.
            unsafe { sys::mj_jacBody(m, d, std::ptr::null_mut(), jac.as_mut_ptr(), body) };
        }
    }
    let turn = &turns.jacobians;
    // SAFETY: valid model per the caller.
    let sparse = unsafe { sys::mj_isSparse(m) } != 0;
    let mut delta = vec![0.0; nv];
    for (r, a) in rows {
        if r >= nefc {
            continue;
        }
        let c = shift.cross(&a);
        for (col, x) in delta.iter_mut().enumerate() {
            *x = (0..3)
                .map(|i| c[i] * (turn[1][i * nv + col] - turn[0][i * nv + col]))
                .sum();
        }
        // SAFETY: r < nefc; MuJoCo holds row r's entries at `rowadr[r]..+rownnz[r]` with
        // their columns in `colind` (sparse), or at `r * nv..(r + 1) * nv` (dense).
        unsafe {
            if sparse {
                let adr = usize::try_from(*d.efc_J_rowadr.add(r)).unwrap_or(0);
                let nnz = usize::try_from(*d.efc_J_rownnz.add(r)).unwrap_or(0);
                for k in adr..adr + nnz {
                    if let Some(x) = usize::try_from(*d.efc_J_colind.add(k))
                        .ok()
                        .and_then(|col| delta.get(col))
                    {
                        *d.efc_J.add(k) += x;
                    }
                }
            } else {
                for (col, x) in delta.iter().enumerate() {
                    *d.efc_J.add(r * nv + col) += x;
                }
            }
        }
    }
}

/// The turning Jacobians (3 x nv each) of the last pair of bodies [`shift_rows`] moved a
/// contact's rows between.
#[derive(Clone, Debug, Default)]
pub struct Turns {
    bodies: Option<[i32; 2]>,
    jacobians: [Vec<f64>; 2],
}

/// How a pressing geom's push-back is carried by its contacts ([`carry`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Carried {
    /// Each contact's share of the push-back ([`shares`]).
    pub shares: Vec<f64>,
    /// Each contact's offset (sensor frame) from the shares' centre.
    pub offsets: Vec<Vector3<f64>>,
    /// The sum of the shares times the squared in-plane offsets
    /// ([`Linearised::at_point`]).
    pub spread: f64,
    /// How far the rows' points are moved (world, m): from the shares' centre to the
    /// gel's centre of pressure along the gel's face, where the push has one
    /// ([`shift_rows`]).
    pub shift: Vector3<f64>,
    /// The couple (world, N m) that the contacts leave out ([`Couple`]): the twist where
    /// the points have no spread to carry it.
    pub couple: Option<Vector3<f64>>,
}

impl Carried {
    /// The force (world) on contact `k`: its share of the push-back's force and its part
    /// of the turn and the twist about the shares' centre.
    pub fn force(&self, p: &Linearised, k: usize, site: &Isometry3<f64>) -> Vector3<f64> {
        let n = self.shares[k];
        site.rotation * (p.force * n + p.at_point(self.offsets[k], n, self.spread))
    }
}

/// How a push-back `p` (sensor frame, [`Linearised`]) is carried by a pressing geom's
/// contacts at `points` (world), the sensor at `site`: shares that put their centre on the
/// gel's centre of pressure where the points reach it ([`shares`]), the offsets from the
/// shares' own centre (so that the turn's and the twist's parts add up to no force,
/// whatever the points), the shift along the gel's face that moves the points, rows and
/// all, so that their centre is the gel's centre of pressure where they do not reach it,
/// and the couple that makes up the twist where the points have no spread to carry it.
/// Together, the gel's wrench, all of it but that couple carried by the rows (implicitly,
/// in MuJoCo's solve).
pub fn carry(points: &[Vector3<f64>], p: Option<&Linearised>, site: &Isometry3<f64>) -> Carried {
    let axes = [site.rotation * Vector3::x(), site.rotation * Vector3::y()];
    let gels = p
        .and_then(|p| p.centre)
        .map(|x| (site * nalgebra::Point3::from(x)).coords);
    let shares = shares(points, gels, axes);
    let (Some(p), Some(gels)) = (p, gels) else {
        return Carried {
            offsets: vec![Vector3::zeros(); points.len()],
            shares,
            spread: 0.0,
            shift: Vector3::zeros(),
            couple: None,
        };
    };
    let centre: Vector3<f64> = points.iter().zip(&shares).map(|(q, &w)| q * w).sum();
    let offsets: Vec<Vector3<f64>> = points
        .iter()
        .map(|q| site.rotation.inverse() * (q - centre))
        .collect();
    // Points within [`COINCIDENT`] of one place have no spread to carry the twist by (its
    // part at each point is the twist over the spread times the point's offset: with
    // MuJoCo's two contacts at one place, 2e-38 m^2 and 1e-19 m, a row of 2.5e11 N).
    let spread = offsets
        .iter()
        .zip(&shares)
        .map(|(o, w)| w * o.xy().norm_squared())
        .sum::<f64>();
    let spread = if spread > COINCIDENT * COINCIDENT {
        spread
    } else {
        0.0
    };
    // Along the gel's face only: MuJoCo's points lie halfway through the geoms' overlap and
    // the gel's centre on its rest surface moved with the indenter, so that the normal part
    // of their distance is no lever of the gel's (a tumbling box left the solve's centre
    // 8 mm out along the normal, and its friction rows moved there tipped it further).
    // (Where the shares reach the centre, what is left is round-off: nothing is moved.)
    let normal = site.rotation * Vector3::z();
    let shift = (gels - centre) - normal * normal.dot(&(gels - centre));
    let shift = if shift.norm() > COINCIDENT && shift.norm().is_finite() {
        shift
    } else {
        Vector3::zeros()
    };
    let couple = (spread == 0.0 && p.twist != 0.0).then(|| normal * p.twist);
    Carried {
        shares,
        offsets,
        spread,
        shift,
        couple,
    }
}

/// The part of a pressing geom's push-back that its contact rows cannot carry: a couple
/// (world, N m, on the pressing geom; the gel's body takes the opposite), the gel's twist
/// about its normal where the geom's contacts lie at one point and have no spread to
/// carry it. The force's moment needs none: the rows act at their points moved so that
/// their weighted centre is the gel's centre of pressure ([`carry`], [`shift_rows`]),
/// wherever MuJoCo's contacts lie (a mesh's contacts on a face come and go from step to
/// step, and two of them on one edge form a line: a 6 N grasp whose contacts fell to one
/// edge of its face lost 0.09 N m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Couple {
    /// The pressing geom.
    pub geom: usize,
    /// The couple on it (world, N m).
    pub torque: Vector3<f64>,
}

/// `h B / m` beyond which a joint's damping outweighs its inertia enough for a grasp on a
/// gel that pushes back to bounce ([`damping_taken_after_the_solve`]). Measured on
/// `tacrom/GripperLift-v1`'s fingers, five seeds and three objects each (docs/rl.md, "A
/// long physics step: the fingers' damping, taken after the solve"): every hold still at
/// 1.6 and 3.1 (2 and 4 ms), 14 of 15 at 4.7 (6 ms), 7 at 6.3 (8 ms), none at 7.8 (10 ms);
/// with the drives' inertia on the joints, every hold still at 1.3 and 1.6 (8 and 10 ms).
pub const DAMPING_OUTWEIGHS: f64 = 4.0;

/// A joint whose damping outweighs its inertia over one physics step.
#[derive(Clone, Debug, PartialEq)]
pub struct Outweighed {
    /// The joint's name (its id where it has none).
    pub joint: String,
    /// Its damping (MuJoCo's `damping`, with its actuators').
    pub damping: f64,
    /// The inertia along it: one over the diagonal of `M^-1` (with its armature).
    pub inertia: f64,
    /// `h damping / inertia`.
    pub ratio: f64,
}

/// Among the joints that carry `bodies` (each body's own, and those of the bodies it hangs
/// from), the one whose damping most outweighs its inertia over MuJoCo's physics step `h`,
/// where `h B / m` exceeds [`DAMPING_OUTWEIGHS`] and the integrator takes that damping
/// after its constraint solve (Euler unless `eulerdamp` or the dampers are disabled, and
/// the implicit integrators): the solve, which the gel's rows are made for, takes such a
/// joint for as free as its inertia makes it, and the step then moves it by a fraction of
/// what the solve meant (`m / (m + h B)`). `m` is the inertia a force on the joint alone
/// meets, one over the joint's diagonal of `M^-1`; `B` its `damping` and that of the
/// actuators that drive it (times their gear squared), as MuJoCo's Euler step adds them.
///
/// # Safety
/// `m` and `d` must be a valid model and data after MuJoCo's position stage (its factor of
/// `M`); nothing else may hold a reference into `d`.
pub unsafe fn damping_taken_after_the_solve(
    m: &sys::mjModel,
    d: *mut sys::mjData,
    bodies: &[usize],
) -> Option<Outweighed> {
    let flags = m.opt.disableflags;
    let after = match m.opt.integrator as u32 {
        sys::mjINT_EULER => flags & (sys::mjDSBL_EULERDAMP | sys::mjDSBL_DAMPER) as i32 == 0,
        sys::mjINT_IMPLICIT | sys::mjINT_IMPLICITFAST => flags & sys::mjDSBL_DAMPER as i32 == 0,
        _ => false,
    };
    let (nv, nbody) = (
        usize::try_from(m.nv).unwrap_or(0),
        usize::try_from(m.nbody).unwrap_or(0),
    );
    let h = m.opt.timestep;
    if !after || nv == 0 || !(h > 0.0) {
        return None;
    }
    // The degrees of freedom that carry the bodies, each once.
    let mut dofs = Vec::new();
    for &body in bodies {
        let mut b = body;
        let mut hops = 0;
        while b > 0 && b < nbody && hops < nbody {
            // SAFETY: b < nbody; MuJoCo holds nbody entries of each body array.
            let (adr, num, parent) = unsafe {
                (
                    *m.body_dofadr.add(b),
                    *m.body_dofnum.add(b),
                    *m.body_parentid.add(b),
                )
            };
            if let (Ok(adr), Ok(num)) = (usize::try_from(adr), usize::try_from(num)) {
                dofs.extend((adr..adr + num).filter(|&i| i < nv));
            }
            b = usize::try_from(parent).unwrap_or(0);
            hops += 1;
        }
    }
    dofs.sort_unstable();
    dofs.dedup();
    let (mut unit, mut column) = (vec![0.0; nv], vec![0.0; nv]);
    let mut worst: Option<Outweighed> = None;
    for i in dofs {
        // SAFETY: i < nv; the joint and actuator ids are MuJoCo's own.
        let (damping, joint) = unsafe { (joint_damping(m, i), *m.dof_jntid.add(i)) };
        if !(damping > 0.0) {
            continue;
        }
        unit.fill(0.0);
        unit[i] = 1.0;
        // SAFETY: valid model and data; both vectors hold nv numbers.
        unsafe { sys::mj_solveM(m, d, column.as_mut_ptr(), unit.as_ptr(), 1) };
        let inertia = 1.0 / column[i];
        let ratio = h * damping / inertia;
        if !(inertia > 0.0 && ratio.is_finite() && ratio > DAMPING_OUTWEIGHS) {
            continue;
        }
        if worst.as_ref().is_some_and(|w| w.ratio >= ratio) {
            continue;
        }
        // SAFETY: valid model; the name is looked up by MuJoCo (null where none).
        let name = unsafe { sys::mj_id2name(m, sys::mjOBJ_JOINT as i32, joint) };
        let joint = if name.is_null() {
            format!("#{joint}")
        } else {
            // SAFETY: MuJoCo's names are NUL-terminated within its names buffer.
            unsafe { std::ffi::CStr::from_ptr(name) }
                .to_string_lossy()
                .into_owned()
        };
        worst = Some(Outweighed {
            joint,
            damping,
            inertia,
            ratio,
        });
    }
    worst
}

/// The linear damping MuJoCo's Euler step takes implicitly on degree of freedom `i`: the
/// joint's `damping` and that of the actuators that drive the joint, times their gear
/// squared.
///
/// # Safety
/// `m` must be a valid model, `i` one of its degrees of freedom.
unsafe fn joint_damping(m: &sys::mjModel, i: usize) -> f64 {
    // SAFETY: per the caller; the ids read are MuJoCo's own, within their arrays.
    unsafe {
        let mut damping = *m.dof_damping.add(i);
        let joint = *m.dof_jntid.add(i);
        let nu = usize::try_from(m.nactuator).unwrap_or(0);
        let driven = |u: usize| {
            let out = usize::try_from(*m.actuator_outadr.add(u)).unwrap_or(u);
            let gear = *m.actuator_gear.add(6 * out);
            *m.actuator_damping.add(u) * gear * gear
        };
        if let Ok(j) = usize::try_from(joint) {
            let actuator = *m.jnt_actuatorid.add(j);
            if let Ok(u) = usize::try_from(actuator) {
                if u < nu {
                    damping += driven(u);
                }
            } else if actuator < -1 {
                for u in 0..nu {
                    let trn = *m.actuator_trntype.add(u) as u32;
                    let on_joint = trn == sys::mjTRN_JOINT || trn == sys::mjTRN_JOINTINPARENT;
                    if on_joint && *m.actuator_trnid.add(2 * u) == joint {
                        damping += driven(u);
                    }
                }
            }
        }
        damping
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn centre_of(points: &[Vector3<f64>], w: &[f64]) -> Vector3<f64> {
        points.iter().zip(w).map(|(p, w)| p * *w).sum()
    }

    /// The contacts' forces at their shifted points and the couple together are the gel's
    /// wrench (its force at its centre of pressure and its twist about the normal) whatever
    /// MuJoCo's points: around the centre (the contacts carry it all, unmoved), on one edge
    /// of the face, at one point (a couple for the twist alone), at one place twice; and a
    /// turn since the solve adds no force.
    #[test]
    fn the_contacts_and_their_couple_carry_the_gels_wrench() {
        use nalgebra::UnitQuaternion;
        let site = Isometry3::new(
            Vector3::new(0.01, -0.02, 0.05),
            Vector3::new(0.3, -0.2, 0.5),
        );
        let mut p = Linearised {
            force: Vector3::new(0.4, -0.7, 5.9),
            normal: 3e4,
            tangential: 5e3,
            centre: Some(Vector3::new(1e-3, 2e-3, 0.0)),
            twist: 2e-3,
            turned: UnitQuaternion::identity(),
            spread: 0.0,
        };
        let local = |xy: &[(f64, f64)]| -> Vec<Vector3<f64>> {
            xy.iter()
                .map(|&(x, y)| (site * nalgebra::Point3::new(x * 1e-3, y * 1e-3, -2e-4)).coords)
                .collect()
        };
        let square = local(&[(-5.0, -5.0), (5.0, -5.0), (5.0, 5.0), (-5.0, 5.0)]);
        let edge = local(&[(-5.0, -15.0), (5.0, -15.0), (5.0, -15.0)]);
        let one = local(&[(4.0, -3.0)]);
        // Two of MuJoCo's contacts at one place but for round-off.
        let twice = local(&[(4.0, -3.0), (4.0, -3.0 + 2e-14)]);
        let gel_force = site.rotation * p.force;
        // The gel's centre of pressure where the points lie along the normal (their
        // distance along it, half the geoms' overlap against the gel's rest surface, is no
        // lever of the gel's).
        let c = p.centre.unwrap();
        let gel_centre = (site * nalgebra::Point3::new(c.x, c.y, -2e-4)).coords;
        let gel_torque = gel_centre.cross(&gel_force) + site.rotation * Vector3::z() * p.twist;
        let cases = [
            ("square", &square),
            ("edge", &edge),
            ("one", &one),
            ("twice", &twice),
        ];
        for (name, points) in cases {
            let way = carry(points, Some(&p), &site);
            let forces: Vec<Vector3<f64>> =
                (0..points.len()).map(|k| way.force(&p, k, &site)).collect();
            // No contact takes more than the gel's force (a round-off spread once gave
            // one 2.5e11 N).
            assert!(
                forces.iter().all(|f| f.norm() <= 1.01 * gel_force.norm()),
                "{name}: {forces:?}"
            );
            let force: Vector3<f64> = forces.iter().sum();
            let couple = way.couple.unwrap_or_default();
            let torque: Vector3<f64> = points
                .iter()
                .zip(&forces)
                .map(|(q, f)| (q + way.shift).cross(f))
                .sum::<Vector3<f64>>()
                + couple;
            assert!(
                (force - gel_force).norm() < 1e-12,
                "{name}: {force} {gel_force}"
            );
            assert!(
                (torque - gel_torque).norm() < 1e-13,
                "{name}: {torque} {gel_torque}"
            );
            // The shares' centre, shifted, is the gel's centre of pressure.
            let centre: Vector3<f64> = centre_of(points, &way.shares) + way.shift;
            assert!((centre - gel_centre).norm() < 1e-15, "{name}: {centre}");
            if name == "square" {
                // Around the centre: the shares carry it, nothing is moved.
                assert!(way.shift.norm() < 1e-15, "{}", way.shift);
            } else {
                assert!(way.shift.norm() > 1e-3, "{name}: {}", way.shift);
            }
            // Only points without spread leave the twist to a couple.
            assert_eq!(way.couple.is_some(), way.spread == 0.0, "{name}");
        }
        p.turned = UnitQuaternion::from_euler_angles(0.01, -0.02, 0.03);
        let way = carry(&square, Some(&p), &site);
        let force: Vector3<f64> = (0..4).map(|k| way.force(&p, k, &site)).sum();
        assert!((force - gel_force).norm() < 1e-12, "{force} {gel_force}");
    }

    #[test]
    fn the_shares_put_the_contacts_centre_on_the_gels() {
        let axes = [Vector3::x(), Vector3::y()];
        let square: Vec<Vector3<f64>> = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
            .iter()
            .map(|&(x, y)| Vector3::new(x, y, 0.0) * 1e-3)
            .collect();
        // No centre, one point, or the centre at the points' own: even.
        assert_eq!(shares(&square, None, axes), vec![0.25; 4]);
        assert_eq!(shares(&square[..1], Some(Vector3::x()), axes), vec![1.0]);
        let even = shares(&square, Some(Vector3::zeros()), axes);
        assert!(even.iter().all(|w| (w - 0.25).abs() < 1e-15), "{even:?}");
        // Within the square: the weighted centre is the gel's, the weights add up to one.
        let c = Vector3::new(0.3e-3, -0.5e-3, 0.0);
        let w = shares(&square, Some(c), axes);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(w.iter().all(|&x| x >= 0.0));
        assert!((centre_of(&square, &w) - c).norm() < 1e-15, "{w:?}");
        // Outside it: none negative, adding up to one, the centre pulled towards it.
        let far = Vector3::new(5e-3, 0.0, 0.0);
        let w = shares(&square, Some(far), axes);
        assert!(w.iter().all(|&x| x >= 0.0) && (w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(centre_of(&square, &w).x > 0.9e-3, "{w:?}");
        // Points in a line (a cylinder lying on the gel): along the line only.
        let line: Vec<Vector3<f64>> = (0..3)
            .map(|k| Vector3::new(0.0, (k as f64 - 1.0) * 1e-3, 0.0))
            .collect();
        let w = shares(&line, Some(Vector3::new(0.2e-3, 0.4e-3, 0.0)), axes);
        assert!((centre_of(&line, &w).y - 0.4e-3).abs() < 1e-15, "{w:?}");
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }

    /// Points at one place, or a round-off apart (two of MuJoCo's contacts between a
    /// cylinder and a pad, 1.7e-18 m apart in y, with the gel's centre 2 cm away: their
    /// shares were 0.5 and 6e14), share evenly; points a micrometre apart still move the
    /// centre along their line as far as their hull reaches. Whatever the points, no share
    /// is negative and they add up to one: over random clouds, lines and pairs, some a
    /// round-off apart, with centres near and far.
    #[test]
    fn the_shares_of_points_at_one_place_are_even_and_always_add_up_to_one() {
        let axes = [Vector3::x(), Vector3::y()];
        let p = Vector3::new(
            -0.012000497528549346,
            0.007383626903344661,
            0.033113932789578845,
        );
        let q = Vector3::new(p.x, p.y, 0.03311393278957885);
        let centre = Vector3::new(0.0079, -0.0107, 0.0331);
        assert_eq!(shares(&[p, q], Some(centre), axes), vec![0.5, 0.5]);
        let r = p + Vector3::new(0.0, 1e-17, 0.0);
        assert_eq!(shares(&[p, r, p], Some(centre), axes), vec![1.0 / 3.0; 3]);
        // A micrometre apart: the share goes to the point nearer the centre.
        let s = p + Vector3::new(0.0, -1e-6, 0.0);
        assert_eq!(shares(&[p, s], Some(centre), axes), vec![0.0, 1.0]);
        let mut seed = 17u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for case in 0..2000 {
            let n = 2 + case % 5;
            let origin = Vector3::new(next(), next(), next()) * 0.2;
            let size = [1e-2, 1e-6, 1e-12, 1e-17][case % 4];
            let along = Vector3::new(next(), next(), 0.0);
            let points: Vec<Vector3<f64>> = (0..n)
                .map(|_| {
                    let step = match case % 3 {
                        0 => Vector3::new(next(), next(), next()),
                        _ => along * next(),
                    };
                    origin + step * size
                })
                .collect();
            let centre = origin + Vector3::new(next(), next(), 0.0) * [1e-3, 0.1][case % 2];
            let w = shares(&points, Some(centre), axes);
            assert!(
                w.iter().all(|&x| (0.0..=1.0).contains(&x))
                    && (w.iter().sum::<f64>() - 1.0).abs() < 1e-12,
                "case {case}: {w:?} for {points:?}"
            );
        }
    }
}
