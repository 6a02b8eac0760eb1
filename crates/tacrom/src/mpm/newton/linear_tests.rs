//! Tests of the linear solver: its complementarity solve against projected Gauss-Seidel,
//! the compliance's reciprocity, contact without penetration or tension, symmetry, the
//! independence of the path, Hertz, threads, and what it refuses or leaves out.

use super::*;
use crate::geometry::{Placed, Sdf, Sphere};
use crate::mpm::hertz::hertz_bonded;
use crate::mpm::{GelParams, Solver, SolverOptions};
use nalgebra::Isometry3;
use std::sync::Arc;

fn options(threads: usize) -> SolverOptions {
    SolverOptions {
        solver: Solver::Linear,
        threads,
        ..Default::default()
    }
}

/// A 10 x 10 x 2 mm gel at 1 mm.
fn small_gel() -> GelParams {
    GelParams {
        size: [0.01, 0.01, 0.002],
        dx: 1e-3,
        friction: 0.0,
        ..Default::default()
    }
}

fn ball(r: f64) -> Arc<dyn Sdf> {
    Arc::new(Sphere { radius: r })
}

/// A sphere of radius `r` over `(x, y)` pressed `d` into the undeformed surface.
fn at(shape: &Arc<dyn Sdf>, r: f64, x: f64, y: f64, d: f64) -> Placed {
    Placed {
        shape: shape.clone(),
        pose: Isometry3::translation(x, y, r - d),
    }
}

/// Numbers in `[-1, 1)` from a fixed seed (xorshift).
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// On random positive definite problems of up to 30 unknowns, from random starting sets,
/// the pivoting meets the complementarity conditions to round-off and finds the unique
/// solution that projected Gauss-Seidel converges to.
#[test]
fn complementarity_solves_positive_definite_problems() {
    let mut noise = Noise(0x9e37_79b9_7f4a_7c15);
    for trial in 0..60 {
        let m = 1 + trial % 30;
        let a = DMatrix::from_fn(m, m, |_, _| noise.next());
        let c = &a * a.transpose() + DMatrix::identity(m, m) * 0.05;
        let d: Vec<f64> = (0..m).map(|_| noise.next()).collect();
        let mut free: Vec<bool> = (0..m).map(|_| noise.next() > 0.0).collect();
        let mut iterations = 0;
        let f = complementarity(&d, &mut free, &mut iterations, |rows, cols| {
            DMatrix::from_fn(rows.len(), cols.len(), |i, j| c[(rows[i], cols[j])])
        })
        .expect("a positive definite problem has a solution");
        let w = &c * DVector::from_column_slice(&f) - DVector::from_column_slice(&d);
        for i in 0..m {
            assert!(f[i] >= 0.0, "trial {trial}: f[{i}] = {}", f[i]);
            assert!(w[i] >= -1e-10, "trial {trial}: w[{i}] = {}", w[i]);
            assert!(
                (f[i] * w[i]).abs() <= 1e-10,
                "trial {trial}: f w = {}",
                f[i] * w[i]
            );
        }
        let mut g = vec![0.0; m];
        for _ in 0..20_000 {
            for i in 0..m {
                let r: f64 = (0..m).filter(|&j| j != i).map(|j| c[(i, j)] * g[j]).sum();
                g[i] = ((d[i] - r) / c[(i, i)]).max(0.0);
            }
        }
        for i in 0..m {
            assert!(
                (f[i] - g[i]).abs() <= 1e-7,
                "trial {trial}: {} against {}",
                f[i],
                g[i]
            );
        }
    }
}

/// Maxwell-Betti: the sinking at slot `p` under a unit force at `q` equals the sinking at
/// `q` under a unit force at `p`, and a downward force sinks the surface under it.
#[test]
fn the_compliance_is_reciprocal() {
    let g = Gel::new(small_gel(), options(1)).unwrap();
    let mut c = Compliance::new(&g).unwrap();
    let n = c.rest.len() as u32;
    let slots: Vec<u32> = (0..n).step_by(7).collect();
    c.ensure(slots.iter().copied(), &[]);
    let sink = |c: &Compliance, p: u32, q: u32| {
        let s = c.slot_sinking(q);
        c.slots[p as usize]
            .iter()
            .map(|&(col, w)| w * s[col as usize])
            .sum::<f64>()
    };
    let peak = slots.iter().map(|&q| sink(&c, q, q)).fold(0.0, f64::max);
    for &p in &slots {
        assert!(sink(&c, p, p) > 0.0, "slot {p} rises under its own load");
        for &q in &slots {
            let (a, b) = (sink(&c, p, q), sink(&c, q, p));
            // Kept in single precision: equal to its rounding.
            assert!((a - b).abs() <= 1e-6 * peak, "{p} {q}: {a} against {b}");
        }
    }
}

/// After a press of two spheres, every slot's force pushes (no tension), and no slot's
/// surface point lies inside an indenter by more than the tolerance of the deepest
/// sinking plus what its own contact compliance allows.
#[test]
fn contact_neither_penetrates_nor_pulls() {
    let mut g = Gel::new(small_gel(), options(1)).unwrap();
    let (a, b) = (ball(2e-3), ball(1e-3));
    let placed = [
        at(&a, 2e-3, -2e-3, 0.0, 0.3e-3),
        at(&b, 1e-3, 2e-3, 1e-3, 0.15e-3),
    ];
    let rep = g.solve(&placed);
    assert!(rep.converged, "{rep:?}");
    let c = g.linear.as_ref().unwrap();
    assert!(c.last_active.len() >= 2, "{:?}", c.last_active);
    for l in &g.loads {
        assert!(
            l.force.z > 0.0 && l.force.x == 0.0 && l.force.y == 0.0,
            "{:?}",
            l.force
        );
    }
    let sinking = g.surface_u.iter().map(|u| -u.z).fold(0.0, f64::max) / g.layout.dx;
    let scale = g.modulus * g.layout.dx * g.layout.dx;
    let load_at = |p: usize| {
        let x = g.layout.origin + (c.rest[p] + g.surface_u[p] / g.layout.dx) * g.layout.dx;
        g.loads
            .iter()
            .find(|l| (l.at[0] - x.x).abs() < 1e-12 && (l.at[1] - x.y).abs() < 1e-12)
            .map_or(0.0, |l| l.force.z / scale)
    };
    let mut worst: f64 = 0.0;
    for p in 0..c.rest.len() {
        let x = (c.rest[p] * g.layout.dx + g.surface_u[p] + g.layout.origin) / g.layout.dx;
        let phi = placed
            .iter()
            .map(|s| {
                let local = s
                    .pose
                    .inverse_transform_point(&nalgebra::Point3::from(x * g.layout.dx));
                s.shape.distance(&local) / g.layout.dx
            })
            .fold(f64::INFINITY, f64::min);
        let allowed = 1e-3 * sinking + c.softness * load_at(p) + 1e-9;
        worst = worst.max(-phi - allowed);
    }
    assert!(
        worst <= 0.0,
        "a slot penetrates by {worst} cells more than allowed"
    );
}

/// A sphere over the gel's centre sinks the surface symmetrically about both axes and
/// both diagonals (the slots and the grid are symmetric about the centre).
#[test]
fn a_centred_press_is_symmetric() {
    let mut g = Gel::new(small_gel(), options(1)).unwrap();
    let s = ball(3e-3);
    assert!(g.solve(&[at(&s, 3e-3, 0.0, 0.0, 0.3e-3)]).converged);
    let peak = -g.surface_displacement(0.0, 0.0).z;
    assert!(peak > 0.2e-3, "peak sinking {peak}");
    for (x, y) in [
        (0.3e-3, 0.0),
        (1.2e-3, 0.7e-3),
        (2.1e-3, -1.6e-3),
        (0.0, 2.9e-3),
    ] {
        let z = g.surface_displacement(x, y).z;
        for (a, b) in [(-x, y), (x, -y), (-x, -y), (y, x)] {
            let other = g.surface_displacement(a, b).z;
            assert!(
                (z - other).abs() <= 1e-9 * peak,
                "({x}, {y}) {z} against ({a}, {b}) {other}"
            );
        }
    }
}

/// The answer depends on the poses alone: a press reached through another gives the
/// force and surface of the same press from rest.
#[test]
fn the_answer_depends_on_the_pose_alone() {
    let s = ball(3e-3);
    let end = at(&s, 3e-3, 0.5e-3, 0.0, 0.25e-3);
    let mut direct = Gel::new(small_gel(), options(1)).unwrap();
    direct.solve(&[end.clone()]);
    let mut path = Gel::new(small_gel(), options(1)).unwrap();
    for (x, d) in [
        (0.0, 0.1e-3),
        (-1e-3, 0.4e-3),
        (1e-3, 0.3e-3),
        (0.5e-3, 0.25e-3),
    ] {
        assert!(path.solve(&[at(&s, 3e-3, x, 0.0, d)]).converged);
    }
    let (a, b) = (direct.force().z, path.force().z);
    assert!((a - b).abs() <= 1e-9 * a, "{a} against {b}");
    for (u, v) in direct.surface_u.iter().zip(&path.surface_u) {
        assert!((u - v).norm() <= 1e-9 * 0.25e-3, "{u} against {v}");
    }
}

/// On a layer resolved by 4 cells (16 x 16 x 2 mm, dx 0.5 mm) a 3 mm sphere pressed
/// 0.1 and 0.2 mm gives the bonded-layer Hertz force (Dimitriadis et al. 2002, itself a
/// small-strain solution) within 5 %, the bound Newton's method meets on the same layer.
#[test]
fn hertz_on_a_resolved_layer() {
    let p = GelParams {
        size: [0.016, 0.016, 0.002],
        friction: 0.0,
        dx: 0.5e-3,
        ..Default::default()
    };
    let r = 3e-3;
    let mut g = Gel::new(p, options(1)).unwrap();
    for d in [0.1e-3, 0.2e-3] {
        let rep = g.solve(&[at(&ball(r), r, 0.0, 0.0, d)]);
        assert!(rep.converged, "{rep:?}");
        let e = g.force().z / hertz_bonded(p.young, p.poisson, r, d, p.size[2]) - 1.0;
        eprintln!("depth {d}: error {e:+.4}");
        assert!(e.abs() < 0.05, "depth {d}: error {e}");
    }
}

/// One and two threads give the same bits through a moving press.
#[test]
fn threads_give_identical_results() {
    let s = ball(2e-3);
    let run = |threads: usize| {
        let mut g = Gel::new(small_gel(), options(threads)).unwrap();
        let mut out = Vec::new();
        for k in 0..4 {
            let x = -1e-3 + 0.6e-3 * k as f64;
            g.solve(&[at(&s, 2e-3, x, 0.3e-3, 0.1e-3 + 0.05e-3 * k as f64)]);
            out.push((g.force(), g.surface_u.clone()));
        }
        out
    };
    assert!(run(1) == run(2));
}

/// A scene that never touches the gel builds nothing; a grid too fine to factor is
/// refused when the gel is made, naming `dx`.
#[test]
fn nothing_is_built_without_contact_and_fine_grids_are_refused() {
    let mut g = Gel::new(small_gel(), options(1)).unwrap();
    let s = ball(2e-3);
    let rep = g.solve(&[at(&s, 2e-3, 0.0, 0.0, -1e-3)]);
    assert!(rep.converged && g.linear.is_none() && g.force() == Vector3::zeros());
    let fine = GelParams {
        dx: 0.2e-3,
        ..GelParams::default()
    };
    let e = Gel::new(fine, options(1)).unwrap_err().to_string();
    assert!(e.contains("dx") && e.contains("linear"), "{e}");
}
