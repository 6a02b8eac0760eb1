//! Tests of the MPM gel: Hertz contact on a bonded layer, symmetry, equilibrium,
//! independence from E, stability, recovery and determinism.

use super::*;
use crate::geometry::{Aabb, Sdf, Sphere};
use crate::mpm::hertz::hertz_bonded;
use nalgebra::{Point3, Translation3, UnitQuaternion};
use std::sync::Arc;

const R: f64 = 5e-3;

fn sphere_at(r: f64, x: f64, y: f64, z: f64) -> Placed {
    Placed {
        shape: Arc::new(Sphere { radius: r }),
        pose: Isometry3::translation(x, y, z),
    }
}

/// A sphere of radius `R` centred over (x, y), pressed `d` into the undeformed surface.
/// Every call shares one shape, so that successive solves see the same indenter moving
/// (indenters are matched between solves by shape identity).
fn press(x: f64, y: f64, d: f64) -> Placed {
    static BALL: std::sync::OnceLock<Arc<dyn Sdf>> = std::sync::OnceLock::new();
    Placed {
        shape: BALL.get_or_init(|| Arc::new(Sphere { radius: R })).clone(),
        pose: Isometry3::translation(x, y, R - d),
    }
}

fn gel(params: GelParams, options: SolverOptions) -> Gel {
    Gel::new(params, options).expect("valid gel")
}

fn frictionless(dx: f64) -> GelParams {
    GelParams {
        dx,
        friction: 0.0,
        ..Default::default()
    }
}

/// Relative force errors against Hertz for the given depths, pressing progressively.
fn hertz_errors(dx: f64, depths: &[f64]) -> Vec<(f64, f64, f64)> {
    let p = frictionless(dx);
    let mut g = gel(p, SolverOptions::default());
    depths
        .iter()
        .map(|&d| {
            let rep = g.solve(&[press(0.0, 0.0, d)]);
            assert!(rep.converged, "dx {dx} d {d}: {rep:?}");
            let f = g.force().z;
            let f_ref = hertz_bonded(p.young, p.poisson, R, d, p.size[2]);
            println!(
                "dx {:.2} mm d {:.2} mm: F {:.5} N, Hertz {:.5} N, error {:+.1} %, {} it",
                dx * 1e3,
                d * 1e3,
                f,
                f_ref,
                100.0 * (f / f_ref - 1.0),
                rep.iterations
            );
            (d, f, f / f_ref - 1.0)
        })
        .collect()
}

// The bracket for nu = 0.43 quoted in the issue.
#[test]
fn hertz_reference_matches_quoted_bracket() {
    let (r, d, h, nu): (f64, f64, f64, f64) = (5e-3, 0.3e-3, 4e-3, 0.43);
    let c = (r * d).sqrt() / h;
    let es = 1.19e5 / (1.0 - nu * nu);
    let quoted = 4.0 * es / 3.0
        * r.sqrt()
        * d.powf(1.5)
        * (1.0 + 1.0108 * c + 1.0216 * c * c + 0.4642 * c.powi(3) - 0.2491 * c.powi(4));
    let f = hertz_bonded(1.19e5, nu, r, d, h);
    assert!((f / quoted - 1.0).abs() < 1e-3, "{f} vs {quoted}");
}

// Medium resolution (dx = 1 mm, 4 cells through the layer): within 10 % of Hertz with
// the bonded-layer correction for d in [0.2, 0.5] mm (measured: +2.4, -4.1, -0.7 %).
#[test]
fn hertz_medium_resolution() {
    for (d, _, err) in hertz_errors(1.0e-3, &[0.2e-3, 0.35e-3, 0.5e-3]) {
        assert!(err.abs() < 0.10, "d = {d}: error {err}");
    }
}

// Refinement at a tight tolerance (1e-4, so that the solve's own error is small), over
// three depths, on a thin 16 x 16 x 2 mm gel pressed by a frictionless sphere of radius
// 3 mm (cheap enough for every run). With 2 cells through the layer (dx = 1 mm) the
// contact radius at 0.1 mm is under one cell and the force is 19 % above the bonded-layer
// Hertz solution; from 3 cells (0.67 mm) on every depth is within 3.3 % (measured, at
// 0.67 / 0.5 / 0.4 / 0.3 mm: mean |error| 2.0, 0.8, 1.0, 1.9 %). The error does not fall
// further below that: where it is within the accuracy of the Dimitriadis polynomial and
// of a contact on surface particles it need not be monotone, so the test asserts the
// plateau, not a monotone decrease (which the relaxation solver's tolerance would decide).
#[test]
fn hertz_error_falls_once_the_layer_is_resolved() {
    let r = 3e-3;
    let mean_error = |dx: f64| {
        let p = GelParams {
            size: [0.016, 0.016, 0.002],
            friction: 0.0,
            dx,
            ..Default::default()
        };
        let mut g = gel(
            p,
            SolverOptions {
                tolerance: 1e-4,
                ..Default::default()
            },
        );
        let ball: Arc<dyn Sdf> = Arc::new(Sphere { radius: r });
        let errors: Vec<f64> = [0.1e-3, 0.2e-3, 0.3e-3]
            .iter()
            .map(|&d| {
                let _ = g.solve(&[Placed {
                    shape: ball.clone(),
                    pose: Isometry3::translation(0.0, 0.0, r - d),
                }]);
                g.force().z / hertz_bonded(p.young, p.poisson, r, d, p.size[2]) - 1.0
            })
            .collect();
        println!("dx {:.2} mm: errors {errors:?}", dx * 1e3);
        assert!(
            errors.iter().skip(1).all(|e| e.abs() < 0.05),
            "dx {dx}: {errors:?}"
        );
        errors.iter().map(|e| e.abs()).sum::<f64>() / errors.len() as f64
    };
    let coarse = mean_error(1.0e-3);
    let resolved = [mean_error(0.667e-3), mean_error(0.5e-3)];
    for e in resolved {
        assert!(e < 0.033, "resolved layer: mean |error| {e}");
        assert!(coarse > 2.0 * e, "unresolved {coarse} against resolved {e}");
    }
}

fn depth_image(g: &Gel, grid: &PixelGrid) -> Vec<f64> {
    let mut out = vec![f64::NAN; grid.width * grid.height];
    g.surface_depth(grid, &mut out);
    out
}

// A centred sphere gives an image symmetric under x and y mirrors.
#[test]
fn centred_press_is_mirror_symmetric() {
    let mut g = gel(
        frictionless(1.4e-3),
        SolverOptions {
            tolerance: 1e-4,
            ..Default::default()
        },
    );
    let rep = g.solve(&[press(0.0, 0.0, 0.4e-3)]);
    assert!(rep.converged);
    let grid = PixelGrid {
        width: 60,
        height: 40,
        fov_x: 0.024,
        fov_y: 0.016,
    };
    let img = depth_image(&g, &grid);
    let peak = img.iter().cloned().fold(0.0, f64::max);
    assert!(peak > 0.3e-3 && peak < 0.45e-3, "peak {peak}");
    let (w, h) = (grid.width, grid.height);
    let mut worst: f64 = 0.0;
    for r in 0..h {
        for c in 0..w {
            let v = img[r * w + c];
            worst = worst.max((v - img[r * w + (w - 1 - c)]).abs());
            worst = worst.max((v - img[(h - 1 - r) * w + c]).abs());
        }
    }
    assert!(worst < 0.01 * peak, "asymmetry {worst} of peak {peak}");
}

// Moving the sphere by whole cells moves the image by the same number of pixels.
#[test]
fn translation_by_whole_cells_translates_image() {
    // dx = 1.5 mm fits the 30 mm gel exactly, so a 2-cell shift maps the lattice onto itself.
    let p = GelParams {
        dx: 1.5e-3,
        friction: 0.0,
        ..Default::default()
    };
    let o = SolverOptions {
        tolerance: 1e-4,
        ..Default::default()
    };
    let grid = PixelGrid {
        width: 96,
        height: 96,
        fov_x: 0.024,
        fov_y: 0.024,
    }; // 0.25 mm pixels
    let mut a = gel(p, o);
    let mut b = gel(p, o);
    assert!(a.solve(&[press(0.0, 0.0, 0.4e-3)]).converged);
    assert!(b.solve(&[press(3e-3, 0.0, 0.4e-3)]).converged);
    let (ia, ib) = (depth_image(&a, &grid), depth_image(&b, &grid));
    let peak = ia.iter().cloned().fold(0.0, f64::max);
    let shift = 12; // 3 mm / 0.25 mm
    let mut worst: f64 = 0.0;
    for r in 20..76 {
        for c in 20..70 {
            worst = worst.max((ia[r * 96 + c] - ib[r * 96 + c + shift]).abs());
        }
    }
    assert!(worst < 0.02 * peak, "difference {worst} of peak {peak}");
}

// After convergence the residual is below the tolerance; unloading returns the gel flat.
#[test]
fn equilibrium_and_unloading() {
    let o = SolverOptions {
        tolerance: 1e-3,
        ..Default::default()
    };
    let mut g = gel(GelParams::default(), o);
    let rep = g.solve(&[press(0.0, 0.0, 0.5e-3)]);
    assert!(rep.converged && rep.residual <= o.tolerance, "{rep:?}");
    assert!(g.force().z > 0.0);
    let grid = PixelGrid {
        width: 64,
        height: 48,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    let loaded = depth_image(&g, &grid).iter().cloned().fold(0.0, f64::max);
    assert!(loaded > 0.3e-3, "loaded depth {loaded}");
    let rep = g.solve(&[]);
    assert!(rep.converged && rep.residual <= o.tolerance, "{rep:?}");
    let flat = depth_image(&g, &grid).iter().cloned().fold(0.0, f64::max);
    assert!(flat < 5e-6, "residual depth {flat}");
    assert!(g.force().norm() < 1e-9);
}

// A press lifted just clear of the gel, its bounding box still within reach of the
// surface: no contact point of the undeformed gel lies inside the sphere, so the
// undeformed gel is the equilibrium, and the solve returns it exactly, without a step.
// The relaxation used to relax towards it from the press, judged against the vanishing
// load: in random press sequences such frames ran to the iteration cap.
#[test]
fn a_press_lifted_clear_returns_the_undeformed_gel_without_a_step() {
    let grid = PixelGrid {
        width: 64,
        height: 48,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    for friction in [0.0, 0.5] {
        let p = GelParams {
            friction,
            ..Default::default()
        };
        let mut g = gel(p, SolverOptions::default());
        let rep = g.solve(&[press(0.0, 0.0, 0.4e-3)]);
        assert!(rep.converged && g.force().z > 0.0, "{rep:?}");
        for lifted in [press(0.3e-3, 0.0, -0.05e-3), press(0.6e-3, 0.0, -0.01e-3)] {
            let rep = g.solve(&[lifted]);
            assert!(rep.converged && rep.iterations == 0, "{rep:?}");
            assert_eq!(g.force(), Vector3::zeros());
            let deepest = depth_image(&g, &grid).iter().cloned().fold(0.0, f64::max);
            assert_eq!(deepest, 0.0, "friction {friction}");
        }
        // Pressed again, it carries the press as before.
        let rep = g.solve(&[press(0.0, 0.0, 0.4e-3)]);
        assert!(rep.converged && g.force().z > 0.0, "{rep:?}");
    }
}

/// Depth images of two gels driven through the same presses, one solving only its active
/// region (the default margin) and one the whole gel: (largest image difference over the
/// peak depth, force ratio, active particles of the last solve).
fn region_against_whole(presses: &[Placed]) -> (f64, f64, usize) {
    let p = frictionless(GelParams::default().dx);
    let whole = SolverOptions {
        active_margin: f64::INFINITY,
        ..Default::default()
    };
    let mut a = gel(p, SolverOptions::default());
    let mut b = gel(p, whole);
    let mut active = 0;
    for press in presses {
        let ra = a.solve(std::slice::from_ref(press));
        let rb = b.solve(std::slice::from_ref(press));
        assert!(ra.converged && rb.converged, "{ra:?} {rb:?}");
        assert_eq!(rb.active_particles, b.num_particles());
        active = ra.active_particles;
    }
    let grid = PixelGrid {
        width: 96,
        height: 72,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    let (ia, ib) = (depth_image(&a, &grid), depth_image(&b, &grid));
    let peak = ib.iter().cloned().fold(0.0, f64::max);
    let diff = ia
        .iter()
        .zip(&ib)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    (diff / peak, a.force().z / b.force().z, active)
}

// Solving only the active region (the contact footprint grown by 1.5 gel thicknesses,
// walled in by the still gel) gives the whole gel's image and force: the surface of the
// bonded layer settles within about one thickness of the contact. Bounds: the image
// within 2 % of the peak depth, the force within 3 % (the wall stiffens the layer
// slightly; measured at dx = 0.7 mm, +0.3 to +0.9 points of Hertz error).
#[test]
fn active_region_agrees_with_the_whole_gel() {
    for (x, y) in [(0.0, 0.0), (-5e-3, 3e-3)] {
        let (diff, ratio, active) = region_against_whole(&[press(x, y, 0.4e-3)]);
        let total = gel(GelParams::default(), SolverOptions::default()).num_particles();
        println!("press at ({x}, {y}): image {diff:.4} of peak, force ratio {ratio:.4}, {active} of {total} active");
        assert!(active < total / 2, "{active} of {total}");
        assert!(diff < 0.02, "image differs by {diff} of the peak");
        assert!((ratio - 1.0).abs() < 0.03, "force ratio {ratio}");
    }
}

// When the indenter jumps across the gel, the region it leaves relaxes (it was deformed,
// so it stays active for one more solve) and the image matches the whole gel's.
#[test]
fn region_an_indenter_leaves_relaxes() {
    let (diff, ratio, _) =
        region_against_whole(&[press(-6e-3, 0.0, 0.4e-3), press(6e-3, 0.0, 0.4e-3)]);
    println!("after the jump: image {diff:.4} of peak, force ratio {ratio:.4}");
    assert!(diff < 0.02, "image differs by {diff} of the peak");
    assert!((ratio - 1.0).abs() < 0.03, "force ratio {ratio}");
}

// The coarse and rom modes' default tolerance keeps a frictional twist on course: a bar
// pressed 0.5 mm and turned 0.4 rad per frame with friction 0.5 gives, frame by frame,
// forces within 5 % of the solve to 1e-3, with the active region and with the whole gel
// (at 1e-2 the whole gel's were up to 25 % off: stick and slip settle elsewhere when the
// solve stops early).
#[test]
fn default_tolerance_follows_a_frictional_twist() {
    use crate::geometry::Cuboid;
    let bar: Arc<dyn Sdf> = Arc::new(Cuboid::new(Vector3::new(0.004, 0.001, 0.002)));
    let run = |tolerance: f64, active_margin: f64| {
        let o = SolverOptions {
            tolerance,
            active_margin,
            ..Default::default()
        };
        let mut g = gel(GelParams::default(), o);
        (0..4)
            .map(|i| {
                let pose = Isometry3::from_parts(
                    nalgebra::Translation3::new(0.0, 0.0, 0.0015),
                    nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, 0.4 * i as f64),
                );
                let rep = g.solve(&[Placed {
                    shape: bar.clone(),
                    pose,
                }]);
                assert!(rep.converged, "{rep:?}");
                g.force().z
            })
            .collect::<Vec<f64>>()
    };
    let tight = run(1e-3, f64::INFINITY);
    let tol = crate::config::Physics::Coarse.default_tolerance();
    for margin in [ACTIVE_MARGIN, f64::INFINITY] {
        let forces = run(tol, margin);
        println!("twist forces: 1e-3 {tight:?}, {tol:e} (margin {margin}) {forces:?}");
        for (a, b) in forces.iter().zip(&tight) {
            assert!((a / b - 1.0).abs() < 0.05, "{forces:?} vs {tight:?}");
        }
    }
}

// Mass scaling: iteration counts do not grow with Young's modulus.
#[test]
fn iterations_do_not_grow_with_young_modulus() {
    let counts: Vec<usize> = [1e4, 1e5, 1e6, 1e7]
        .iter()
        .map(|&e| {
            let mut g = gel(
                GelParams {
                    young: e,
                    ..Default::default()
                },
                SolverOptions::default(),
            );
            let a = g.solve(&[press(0.0, 0.0, 0.3e-3)]);
            let b = g.solve(&[press(0.2e-3, 0.0, 0.35e-3)]);
            assert!(a.converged && b.converged);
            a.iterations + b.iterations
        })
        .collect();
    println!("iterations vs E: {counts:?}");
    let (lo, hi) = (*counts.iter().min().unwrap(), *counts.iter().max().unwrap());
    assert!(hi as f64 <= 1.25 * lo as f64, "{counts:?}");
}

fn assert_sane(g: &Gel, rep: &SolveReport) {
    let t = g.params.size[2];
    assert!(
        rep.det_f_min >= J_MIN - 1e-4 && rep.det_f_max <= J_MAX + 1e-4,
        "{rep:?}"
    );
    assert!(g.force().iter().all(|v| v.is_finite()));
    let grid = PixelGrid {
        width: 48,
        height: 36,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    for v in depth_image(g, &grid) {
        assert!(v.is_finite() && (0.0..=t).contains(&v), "depth {v}");
    }
    for p in &g.particles {
        assert!(p.x.iter().all(|v| v.is_finite()) && p.f.iter().all(|v| v.is_finite()));
    }
}

// Near-incompressible gels pressed 2 mm stay finite with det F in bounds.
#[test]
fn near_incompressible_deep_press_is_stable() {
    for nu in [0.49, 0.499] {
        let o = SolverOptions {
            max_iterations: 800,
            ..Default::default()
        };
        let mut g = gel(
            GelParams {
                poisson: nu,
                dx: 2e-3,
                ..Default::default()
            },
            o,
        );
        let rep = g.solve(&[press(0.0, 0.0, 2e-3)]);
        println!("nu {nu}: {rep:?}, force {:?}", g.force());
        assert_sane(&g, &rep);
        assert!(g.force().z > 0.0);
        let rep = g.solve(&[press(0.5e-3, 0.0, 1.5e-3)]);
        assert_sane(&g, &rep);
    }
}

// A 1 mm jump between evaluations and an indenter through the bottom of the gel.
#[test]
fn jumps_and_deep_indenters_are_stable() {
    let o = SolverOptions {
        max_iterations: 600,
        ..Default::default()
    };
    let mut g = gel(GelParams::default(), o);
    let rep = g.solve(&[press(0.0, 0.0, 0.3e-3)]);
    assert_sane(&g, &rep);
    let rep = g.solve(&[press(1e-3, 0.0, 1.3e-3)]);
    assert_sane(&g, &rep);
    assert!(rep.converged, "{rep:?}");
    // Through the bottom: the sphere reaches 1 mm below the bonded face.
    let rep = g.solve(&[press(1e-3, 0.0, 5e-3)]);
    assert_sane(&g, &rep);
    assert!(rep.det_f_min < 0.5, "{rep:?}");
    // The next solve starts again from the undeformed gel and works.
    let rep = g.solve(&[press(0.0, 0.0, 0.3e-3)]);
    assert_sane(&g, &rep);
    assert!(
        rep.restarted && rep.converged && g.force().z > 0.0,
        "{rep:?}"
    );
}

// A NaN injected into a particle is detected, reported and repaired; the next solve works.
#[test]
fn nan_in_a_particle_is_recovered() {
    let mut g = gel(GelParams::default(), SolverOptions::default());
    let rep = g.solve(&[press(0.0, 0.0, 0.3e-3)]);
    assert!(rep.converged);
    let f_good = g.force();
    let i = g.top[g.top.len() / 2] as usize;
    g.particles[i].f[(0, 0)] = f32::NAN;
    g.particles[i].v.x = f32::NAN;
    let rep = g.solve(&[press(0.0, 0.0, 0.3e-3)]);
    assert!(rep.nonfinite_recovered, "{rep:?}");
    assert_sane(&g, &rep);
    let rep = g.solve(&[press(0.0, 0.0, 0.3e-3)]);
    assert!(rep.converged && !rep.nonfinite_recovered, "{rep:?}");
    assert!((g.force().z / f_good.z - 1.0).abs() < 0.02);
    // NaN poses are skipped.
    let mut bad = press(0.0, 0.0, 0.3e-3);
    bad.pose.translation.vector.x = f64::NAN;
    let rep = g.solve(&[bad, press(0.0, 0.0, 0.3e-3)]);
    assert_eq!(rep.indenters, 1);
    assert_sane(&g, &rep);
}

// One and two threads give bit-identical depth images and forces, with friction and a
// sliding indenter.
#[test]
fn thread_count_does_not_change_results() {
    for solver in [Solver::Relaxation, Solver::Total] {
        threads_agree(solver);
    }
}

fn threads_agree(solver: Solver) {
    let run = |threads: usize| {
        let mut g = gel(
            GelParams::default(),
            SolverOptions {
                threads,
                solver,
                ..Default::default()
            },
        );
        let _ = g.solve(&[press(-0.5e-3, 0.2e-3, 0.4e-3)]);
        let rep = g.solve(&[press(0.3e-3, 0.2e-3, 0.45e-3)]);
        let grid = PixelGrid {
            width: 80,
            height: 60,
            fov_x: 0.024,
            fov_y: 0.018,
        };
        (depth_image(&g, &grid), g.force(), rep.iterations)
    };
    let (a, fa, ia) = run(1);
    let (b, fb, ib) = run(2);
    assert_eq!(ia, ib);
    assert_eq!(fa.map(f64::to_bits), fb.map(f64::to_bits));
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}

// Friction resists sliding, within Coulomb's law: a sphere pressed 0.4 mm and dragged
// 3 mm along +x (1.5 contact radii past gross slip) is pushed back along -x, never by more
// than mu times the normal force, and by a substantial part of it. In steady sliding the
// ratio should be mu itself; the relaxation solver reaches 0.75 mu here at its default
// tolerance and 0.64 mu at 1e-4 (measured with mu = 0.5 and 1.0): the friction does not
// saturate fully, a gap the energy-minimising solver is to close. The lower bound, half of
// mu, fails for friction that does not act; the upper bound for friction beyond Coulomb.
// Without friction the same press has no lateral force beyond the solve's tolerance.
#[test]
fn friction_resists_sliding_within_the_coulomb_limit() {
    let mu = 0.5;
    let mut g = gel(
        GelParams {
            friction: mu,
            ..Default::default()
        },
        SolverOptions::default(),
    );
    let _ = g.solve(&[press(-1.5e-3, 0.0, 0.4e-3)]);
    for k in 1..=12 {
        let _ = g.solve(&[press(-1.5e-3 + k as f64 * 0.25e-3, 0.0, 0.4e-3)]);
        let f = g.force();
        assert!(f.x <= 0.0, "slide {k}: the gel must push back: {f:?}");
        assert!(-f.x <= mu * f.z * 1.02, "slide {k}: beyond Coulomb: {f:?}");
    }
    let f = g.force();
    assert!(-f.x >= 0.5 * mu * f.z, "after sliding 3 mm: {f:?}");
    assert!(f.y.abs() < 0.01 * f.z, "no sideways force: {f:?}");
    let mut h = gel(frictionless(1.4e-3), SolverOptions::default());
    let _ = h.solve(&[press(0.0, 0.0, 0.4e-3)]);
    assert!(
        h.force().x.abs() < 0.02 * h.force().z,
        "frictionless {:?}",
        h.force()
    );
}

// Invalid parameters are errors, not panics.
#[test]
fn invalid_parameters_are_rejected() {
    let bad = [
        GelParams {
            poisson: 0.5,
            ..Default::default()
        },
        GelParams {
            young: f64::NAN,
            ..Default::default()
        },
        GelParams {
            dx: 0.0,
            ..Default::default()
        },
        GelParams {
            size: [0.03, -0.03, 0.004],
            ..Default::default()
        },
        GelParams {
            friction: -1.0,
            ..Default::default()
        },
    ];
    for p in bad {
        assert!(Gel::new(p, SolverOptions::default()).is_err(), "{p:?}");
    }
    assert!(Gel::new(
        GelParams::default(),
        SolverOptions {
            threads: 0,
            ..Default::default()
        }
    )
    .is_err());
    assert!(Gel::new(
        GelParams::default(),
        SolverOptions {
            cfl: 1.5,
            ..Default::default()
        }
    )
    .is_err());
    for margin in [0.0, -1.0, f64::NAN] {
        let o = SolverOptions {
            active_margin: margin,
            ..Default::default()
        };
        assert!(Gel::new(GelParams::default(), o).is_err(), "{margin}");
    }
}

// The coarse default gel has about 1e4 particles, 8 per cell, of volume dx^3 / 8.
#[test]
fn default_gel_layout() {
    let g = gel(GelParams::default(), SolverOptions::default());
    assert_eq!(g.num_particles(), 42 * 42 * 6);
    let total = g.ctx.pvol as f64 * g.num_particles() as f64 * g.layout.dx.powi(3);
    assert!((total / (0.03 * 0.03 * 0.004) - 1.0).abs() < 1e-5);
}

fn peak(g: &Gel) -> f64 {
    let grid = PixelGrid {
        width: 64,
        height: 48,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    depth_image(g, &grid).iter().cloned().fold(0.0, f64::max)
}

// Regression: indenters were matched to those of the previous solve by slice index, so a
// sphere pressed right after a bar was removed was swept from the bar's pose and inherited
// its contact state (the stability suite's "rotating bar" follow-up press missed its depth:
// peak 2.4 mm for 0.3 mm). Without friction the equilibrium is unique and must match a
// fresh gel's; with friction it depends on the path (the released surface springs back
// against the arriving sphere), so only the depth is checked.
#[test]
fn replaced_indenter_is_not_matched_by_index() {
    use crate::geometry::Cuboid;
    use nalgebra::{Translation3, UnitQuaternion};
    let bar: Arc<dyn Sdf> = Arc::new(Cuboid::new(Vector3::new(0.004, 0.001, 0.002)));
    for friction in [0.0, 0.5] {
        let p = GelParams {
            friction,
            ..Default::default()
        };
        let mut g = gel(p, SolverOptions::default());
        for k in 0..3 {
            let pose = Isometry3::from_parts(
                Translation3::new(0.0, 0.0, 0.002 - 0.5e-3),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.4 * k as f64),
            );
            let rep = g.solve(&[Placed {
                shape: bar.clone(),
                pose,
            }]);
            assert!(rep.converged, "{rep:?}");
        }
        let rep = g.solve(&[press(0.0, 0.0, 0.3e-3)]);
        assert!(rep.converged, "{rep:?}");
        let mut fresh = gel(p, SolverOptions::default());
        assert!(fresh.solve(&[press(0.0, 0.0, 0.3e-3)]).converged);
        let (a, b) = (peak(&g), peak(&fresh));
        let (fa, fb) = (g.force().z, fresh.force().z);
        println!("friction {friction}: peak {a} vs fresh {b}, force {fa} vs fresh {fb}");
        assert!((a - 0.3e-3).abs() < 0.1e-3, "peak {a}");
        if friction == 0.0 {
            assert!((a - b).abs() < 0.03 * b, "peak {a} vs fresh {b}");
            assert!((fa / fb - 1.0).abs() < 0.03, "force {fa} vs fresh {fb}");
        }
    }
}

// Two indenters sharing one shape keep their identities when their order in the slice
// changes: each is matched to its nearest previous pose.
#[test]
fn indenters_sharing_a_shape_are_matched_by_pose() {
    let ball: Arc<dyn Sdf> = Arc::new(Sphere { radius: R });
    let at = |x: f64| Placed {
        shape: ball.clone(),
        pose: Isometry3::translation(x, 0.0, R - 0.4e-3),
    };
    let mut a = gel(GelParams::default(), SolverOptions::default());
    let mut b = gel(GelParams::default(), SolverOptions::default());
    let _ = a.solve(&[at(-4e-3), at(4e-3)]);
    let _ = b.solve(&[at(-4e-3), at(4e-3)]);
    let ra = a.solve(&[at(-3.9e-3), at(4.1e-3)]);
    let rb = b.solve(&[at(4.1e-3), at(-3.9e-3)]);
    assert!(ra.converged && rb.converged, "{ra:?} {rb:?}");
    assert_eq!(ra.sweep_steps, rb.sweep_steps);
    let (fa, fb) = (a.force(), b.force());
    assert!((fa - fb).norm() < 1e-3 * fa.norm(), "{fa:?} vs {fb:?}");
}

/// A sphere turned inside out: solid outside the ball, normals pointing into it.
#[derive(Debug)]
struct InsideOut(Sphere);

impl Sdf for InsideOut {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        -self.0.distance(p)
    }
    fn aabb(&self) -> Aabb {
        self.0.aabb()
    }
}

// Regression: an inside-out indenter SDF drove det F to -221 although it is documented
// to stay in [J_MIN, J_MAX]; a uniform scaling cannot repair a negative determinant.
#[test]
fn inverted_indenter_keeps_det_f_in_bounds() {
    let o = SolverOptions {
        max_iterations: 400,
        ..Default::default()
    };
    // Negative everywhere in the gel: a huge sphere containing it.
    let mut g = gel(GelParams::default(), o);
    let rep = g.solve(&[sphere_at(0.1, 0.0, 0.0, 0.05)]);
    println!("huge sphere: {rep:?}");
    assert_sane(&g, &rep);
    let rep = g.solve(&[press(0.0, 0.0, 0.3e-3)]);
    assert_sane(&g, &rep);
    // An inside-out sphere pressed 1 mm and moved.
    let mut g = gel(GelParams::default(), o);
    for k in 0..3 {
        let rep = g.solve(&[Placed {
            shape: Arc::new(InsideOut(Sphere { radius: R })),
            pose: Isometry3::translation(0.5e-3 * k as f64, 0.0, R - 1e-3),
        }]);
        println!("inside out: {rep:?}");
        assert_sane(&g, &rep);
    }
}

// The det F guard brings arbitrary finite matrices, inverted, singular or huge, into
// [J_MIN, J_MAX] with a proper rotation.
#[test]
fn det_guard_handles_inverted_and_huge_matrices() {
    let mut seed = 12345u64;
    let mut rnd = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    };
    for scale in [1e-6f32, 0.1, 1.0, 10.0, 1e4, 1e12] {
        for _ in 0..200 {
            let mut f = nalgebra::Matrix3::from_fn(|_, _| rnd() * scale);
            let mut q = nalgebra::UnitQuaternion::identity();
            transfer::guard_det(&mut f, &mut q);
            let j = f.determinant() as f64;
            assert!(
                (J_MIN - 1e-6..=J_MAX + 1e-6).contains(&j),
                "scale {scale}: det {j}"
            );
            assert!(q.coords.iter().all(|c| c.is_finite()));
        }
    }
}

// A shallow press with the Neo-Hookean energy converges and gives the fixed corotated
// force. Both energies share the Lame parameters and agree to first order in the strain,
// so their stresses differ at second order and the relative force difference grows like
// the strain, whose scale under a sphere is a / R = sqrt(d / R). Measured on this grid
// (12 x 12 x 4 mm, dx = 1.4 mm, frictionless): +1.0 % at d = 0.1 mm (sqrt(d / R) = 0.14),
// +2.8 % at 0.4 mm (0.28), +5.0 % at 0.8 mm (0.40), Neo-Hookean stiffer: 0.07 to
// 0.13 sqrt(d / R). The bound is 0.25 sqrt(d / R): 3.5 % and 7.1 % at the two depths.
#[test]
fn neo_hookean_press_agrees_with_fixed_corotated() {
    let press_force = |material: Material, d: f64| {
        let params = GelParams {
            size: [0.012, 0.012, 0.004],
            material,
            ..frictionless(1.4e-3)
        };
        let mut g = gel(params, SolverOptions::default());
        let rep = g.solve(&[press(0.0, 0.0, d)]);
        assert!(rep.converged, "{material:?} d {d}: {rep:?}");
        g.force().z
    };
    for d in [0.1e-3, 0.4e-3] {
        let fc = press_force(Material::FixedCorotated, d);
        let nh = press_force(Material::NeoHookean, d);
        let rel = nh / fc - 1.0;
        println!(
            "d {:.1} mm: fixed corotated {fc:.5} N, Neo-Hookean {nh:.5} N, {:+.2} %",
            d * 1e3,
            100.0 * rel
        );
        assert!(
            fc > 0.0 && rel.abs() < 0.25 * (d / R).sqrt(),
            "d {d}: {fc} vs {nh}"
        );
    }
}

/// A gel with friction after a press off the centre and a slide along x.
fn slid_gel() -> Gel {
    let mut g = gel(GelParams::default(), SolverOptions::default());
    for k in 0..4 {
        let rep = g.solve(&[press(0.3e-3 + 0.2e-3 * k as f64, 0.7e-3, 0.6e-3)]);
        assert!(rep.converged, "{rep:?}");
    }
    g
}

// The surface displacement at a top particle's rest position is that particle's surface
// point's own displacement, x_p + (s_z / 2) F e_z - X, from the particles themselves.
#[test]
fn surface_displacement_at_a_lattice_point_is_its_particles() {
    let g = slid_gel();
    let dx = g.layout.dx;
    let [nx, _, _] = g.layout.lattice;
    let [sx, sy, _] = g.layout.spacing;
    let [lx, ly, _] = g.params.size;
    let mut largest = 0.0f64;
    for (slot, &i) in g.top.iter().enumerate() {
        let p = &g.particles[i as usize];
        let (ix, iy) = (slot % nx, slot / nx);
        let rest = [
            -0.5 * lx + (ix as f64 + 0.5) * sx,
            -0.5 * ly + (iy as f64 + 0.5) * sy,
        ];
        let own = (p.x + p.f.column(2) * g.half_top - g.top_ref[slot]).cast::<f64>() * dx;
        let sampled = g.surface_displacement(rest[0], rest[1]);
        assert!(
            (sampled - own).amax() < 1e-15,
            "slot {slot}: {sampled:?} against {own:?}"
        );
        largest = largest.max(own.amax());
    }
    assert!(largest > 0.5e-3, "largest displacement {largest}");
}

// Each pixel's shear and depth are the displacement of the surface point X = p - shear
// it sees: sampled there, u is (shear, -depth), to the inverse map's accuracy (its
// one-step pixels' bound, `one_step_error`); and the depth and shear computed together
// equal each computed alone.
#[test]
fn shear_and_depth_are_the_displacement_of_the_point_seen() {
    let g = slid_gel();
    let grid = PixelGrid {
        width: 96,
        height: 72,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    let n = grid.width * grid.height;
    let (mut depth, mut shear) = (vec![f64::NAN; n], vec![f64::NAN; 2 * n]);
    g.surface_depth_and_shear(&grid, &mut depth, &mut shear);
    assert_eq!(depth, depth_image(&g, &grid));
    let mut alone = vec![f64::NAN; 2 * n];
    g.surface_shear(&grid, &mut alone);
    assert_eq!(shear, alone);
    let peak = shear.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(peak > 50e-6, "peak shear {peak}");
    let mut worst = 0.0f64;
    for row in 0..grid.height {
        for col in 0..grid.width {
            let k = row * grid.width + col;
            let s = [shear[2 * k], shear[2 * k + 1]];
            let u = g.surface_displacement(grid.x(col) - s[0], grid.y(row) - s[1]);
            worst = worst.max((u.x - s[0]).abs()).max((u.y - s[1]).abs());
            if depth[k] > 0.0 {
                worst = worst.max((-u.z - depth[k]).abs());
            }
        }
    }
    assert!(
        worst < super::surface::one_step_error(&g),
        "worst {worst} (peak shear {peak})"
    );
}

/// Two spheres pressed 0.3 mm at x = -6 and +6 mm on the coarse gel, with friction and
/// each solver: each load goes to its own sphere, so the two wrenches mirror each other
/// (force z within 1 %, opposite torques about y), add up to the total force, and each
/// torque about the sensor origin is the lever of its force, `-x F_z` about y, to within
/// 5 % (the patch's centre and the friction's own lever move it by 2 %).
#[test]
fn wrenches_split_the_force_between_indenters() {
    for solver in Solver::ALL {
        let mut g = gel(
            GelParams::default(),
            SolverOptions {
                solver,
                ..Default::default()
            },
        );
        let x = 6e-3;
        let pair = [
            sphere_at(R, -x, 0.0, R - 0.3e-3),
            sphere_at(R, x, 0.0, R - 0.3e-3),
        ];
        let rep = g.solve(&pair);
        assert!(rep.converged, "{solver:?}: {rep:?}");
        let w = g.wrenches(&pair);
        let sum = w[0].force + w[1].force;
        assert!(
            (sum - g.force()).norm() <= 1e-9 * g.force().norm(),
            "{solver:?}"
        );
        let (a, b) = (w[0].force.z, w[1].force.z);
        assert!(a > 0.0 && (a - b).abs() <= 1e-2 * a, "{solver:?}: {a} {b}");
        for (k, xc) in [(0, -x), (1, x)] {
            let lever = -xc * w[k].force.z;
            assert!(
                (w[k].torque.y - lever).abs() <= 5e-2 * lever.abs(),
                "{solver:?}: torque {} against {lever}",
                w[k].torque.y
            );
        }
    }
}

/// The relaxation's secant predictor remembers the whole change of a converged solve (each
/// particle's position and `F`, from the equilibrium before to the one after) and the
/// indenter's translation; a change within the tolerance's noise of the deformation (a
/// press moved by 0.1 um) is not kept, so it is not extrapolated.
#[test]
fn the_relaxation_predictor_remembers_the_whole_change_and_not_the_noise() {
    let mut g = gel(GelParams::default(), SolverOptions::default());
    let mut before = Vec::new();
    for d in [0.1e-3, 0.15e-3, 0.2e-3] {
        before = g.particles.iter().map(|p| (p.x, p.f)).collect();
        let rep = g.solve(&[press(0.0, 0.0, d)]);
        assert!(rep.converged, "{rep:?}");
    }
    let memory = g.relaxation().unwrap();
    assert_eq!(memory.last_change.len(), g.particles.len());
    let largest = memory
        .last_change
        .iter()
        .map(|c| c.0.norm())
        .fold(0.0f32, f32::max);
    assert!(largest > 0.0);
    for ((p, b), c) in g.particles.iter().zip(&before).zip(&memory.last_change) {
        assert!((p.x - b.0 - c.0).norm() <= 1e-6 * largest, "{c:?}");
        assert!((p.f - b.1 - c.1).norm() <= 1e-6, "{c:?}");
    }
    assert_eq!(memory.last_motion.len(), 1);
    assert!((memory.last_motion[0] - Vector3::new(0.0, 0.0, -0.05e-3)).norm() < 1e-12);
    let rep = g.solve(&[press(0.0, 0.0, 0.2e-3 + 1e-7)]);
    assert!(rep.converged, "{rep:?}");
    let memory = g.relaxation().unwrap();
    assert!(memory.last_change.is_empty() && memory.last_motion.is_empty());
}

// Quasi-static equilibrium under imposed indenter poses is homogeneous of degree one in the
// elastic moduli (the contact penalty and the tolerances are scaled by them): the
// displacement field cannot depend on Young's modulus, and every force scales with it.
#[test]
fn depth_does_not_depend_on_young_modulus_and_force_scales_with_it() {
    let grid = PixelGrid {
        width: 64,
        height: 48,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    let run = |young: f64| {
        let mut g = gel(
            GelParams {
                young,
                ..Default::default()
            },
            SolverOptions::default(),
        );
        for (x, d) in [(0.0, 0.3e-3), (0.2e-3, 0.5e-3)] {
            assert!(g.solve(&[press(x, 0.0, d)]).converged);
        }
        (depth_image(&g, &grid), g.force())
    };
    let (d0, f0) = run(1.19e5);
    for k in [0.1, 10.0] {
        let (d1, f1) = run(1.19e5 * k);
        let peak = d0.iter().fold(0.0f64, |m, v| m.max(*v));
        let worst = d0
            .iter()
            .zip(&d1)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        println!(
            "E x {k}: depth differs by {:.3e} of the peak; force ratio {:?}",
            worst / peak,
            f1 / k - f0
        );
        assert!(
            worst <= 1e-6 * peak,
            "E x {k}: depth differs by {worst:e} m"
        );
        assert!(
            (f1 / k - f0).norm() <= 1e-6 * f0.norm(),
            "E x {k}: {f1:?} vs {f0:?}"
        );
    }
}

/// The force and the surface displacements after pressing a 3 mm sphere along `path`
/// (depths, m) into a 10 x 10 x 2 mm frictionless gel at dx 1 mm with `solver` at
/// tolerance 1e-5.
fn along_path(solver: Solver, path: &[f64]) -> (Vector3<f64>, Vec<Vector3<f64>>) {
    let params = GelParams {
        size: [0.01, 0.01, 0.002],
        dx: 1e-3,
        friction: 0.0,
        ..Default::default()
    };
    let options = SolverOptions {
        solver,
        tolerance: 1e-5,
        max_iterations: 20_000,
        ..Default::default()
    };
    let mut g = gel(params, options);
    for &d in path {
        let rep = g.solve(&[sphere_at(3e-3, 0.0, 0.0, 3e-3 - d)]);
        assert!(rep.converged, "{solver:?} {path:?}: {rep:?}");
    }
    (g.force(), g.surface_u.clone())
}

/// Each path's force and surface against the first path's: (largest relative force
/// difference, largest surface difference over the deepest point).
fn path_spread(solver: Solver) -> (f64, f64) {
    let paths: [&[f64]; 3] = [&[0.3e-3], &[0.1e-3, 0.2e-3, 0.3e-3], &[0.8e-3, 0.3e-3]];
    let (f0, u0) = along_path(solver, paths[0]);
    let peak = u0.iter().map(|u| u.z.abs()).fold(0.0, f64::max);
    let mut worst = (0.0f64, 0.0f64);
    for path in &paths[1..] {
        let (f, u) = along_path(solver, path);
        let du = u
            .iter()
            .zip(&u0)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        worst.0 = worst.0.max((f - f0).norm() / f0.norm());
        worst.1 = worst.1.max(du / peak);
    }
    worst
}

/// A frictionless elastic equilibrium is unique: the total-Lagrangian relaxation reaches
/// the same one pressed straight to 0.3 mm, in steps, or back up from 0.8 mm (measured:
/// force within 1.3e-4, surface within 1.3e-3 of the deepest point). The
/// updated-Lagrangian relaxation's `F` remembers the path: on the same paths it spreads by
/// 6.6 % in force and 17 % of the deepest point in the surface, and from 0.8 mm does not
/// reach the tolerance in 20,000 steps.
#[test]
fn the_total_lagrangian_relaxation_does_not_depend_on_the_loading_path() {
    let (force, surface) = path_spread(Solver::Total);
    assert!(
        force <= 2e-3 && surface <= 5e-3,
        "force {force}, surface {surface}"
    );
}

/// A frame the relaxation cannot carry (the 5 mm sphere 0.05 mm deep: a footprint of at
/// most 4 of its surface points) is solved by the fallback alone: the relaxation does not
/// run, and its particles stay at rest (they would sink under the contact if it ran). When
/// the press deepens to 0.5 mm (about 16 points) the relaxation carries the frame again,
/// starting afresh from rest: the same force as the same press solved from rest by a
/// fresh gel, within its tolerance's spread between two starts (1 %).
#[test]
fn a_fallback_frame_leaves_the_relaxation_at_rest() {
    let options = SolverOptions {
        fallback: true,
        ..Default::default()
    };
    let params = frictionless(GelParams::default().dx);
    let mut g = gel(params, options);
    let rest: Vec<Vector3<f32>> = g.particles.iter().map(|p| p.x).collect();
    let rep = g.solve(&[press(0.0, 0.0, 0.05e-3)]);
    assert!(
        rep.fallback && rep.converged && g.force().z > 0.0,
        "{rep:?}"
    );
    let moved = g
        .particles
        .iter()
        .zip(&rest)
        .filter(|(p, r)| p.x != **r)
        .count();
    assert_eq!(moved, 0, "the relaxation ran in a fallback frame");
    let rep = g.solve(&[press(0.0, 0.0, 0.5e-3)]);
    assert!(!rep.fallback && rep.converged, "{rep:?}");
    let mut fresh = gel(params, options);
    fresh.solve(&[press(0.0, 0.0, 0.5e-3)]);
    let (a, b) = (g.force().z, fresh.force().z);
    assert!(
        (a / b - 1.0).abs() < 0.01,
        "after the fallback {a} N, from rest {b} N"
    );
}

/// A small sphere pressed down through the face keeps loading the gel once it lies wholly
/// below it: its footprint in the face's rest points is empty, so the fallback carries it,
/// whose points over the sphere sink to its lower surface. A sphere of radius 0.5 mm, each
/// press from rest: half in (0.5 mm), then with its top 0, 0.1, 0.2 and 0.4 mm below the
/// face (pressed 1.0 to 1.4 mm): every press converges, and the buried ones carry more than
/// the half-in press and more the deeper they go. They had carried no force at all (the
/// relaxation, at its iteration cap). (Between, from 0.8 to 0.9 mm, the fallback's
/// small-contact compliance, taken from the shrinking circle the sphere cuts in the face,
/// gives 0.091 and 0.080 N, below the 0.164 N at 1.0 mm: not asserted.)
#[test]
fn a_sphere_pressed_below_the_face_still_loads_the_gel() {
    let options = SolverOptions {
        fallback: true,
        ..Default::default()
    };
    let params = frictionless(GelParams::default().dx);
    let r = 0.5e-3;
    let ball: Arc<dyn Sdf> = Arc::new(Sphere::new(r));
    let press = |d: f64| {
        let mut g = gel(params, options);
        let rep = g.solve(&[Placed {
            shape: ball.clone(),
            pose: Isometry3::translation(0.2e-3, -0.1e-3, r - d),
        }]);
        assert!(rep.converged && g.force().z.is_finite(), "{d}: {rep:?}");
        g.force().z
    };
    let mut last = press(r);
    assert!(last > 0.0);
    for d in [1.0e-3, 1.1e-3, 1.2e-3, 1.4e-3] {
        let f = press(d);
        assert!(f > last, "{d}: {f} N after {last} N");
        last = f;
    }
}

/// After the fallback carried a deep press, the relaxation's first frame starts from the
/// gel at rest with its indenters coming in from above, as a fresh gel's does: a standing
/// capsule (radius 1 mm, tilted 0.13 rad) pressed 0.3 and then 1.3 mm deep (footprints the
/// fallback carries), then slid 0.6 mm at that depth (the relaxation's frame), gives the
/// fresh gel's force within 1 %. Swept from the fallback's last pose, the relaxation
/// started with the capsule 1.3 mm inside the undeformed gel, stopped at its iteration cap
/// and reported no vertical force (-0.002 N against 0.35 N).
#[test]
fn the_relaxation_after_a_deep_fallback_press_starts_as_a_fresh_gel() {
    let options = SolverOptions {
        fallback: true,
        ..Default::default()
    };
    let params = frictionless(GelParams::default().dx);
    let capsule: Arc<dyn Sdf> = Arc::new(crate::geometry::Capsule::new(1e-3, 6e-3));
    let tilt = UnitQuaternion::from_euler_angles(0.008, -0.131, -1.24);
    // The capsule's lowest point lies its radius below its lower end's centre.
    let low = (tilt * Vector3::new(0.0, 0.0, -6e-3)).z - 1e-3;
    let at = |x: f64, y: f64, d: f64| Placed {
        shape: capsule.clone(),
        pose: Isometry3::from_parts(Translation3::new(x, y, -low - d), tilt),
    };
    let mut g = gel(params, options);
    for d in [0.3e-3, 1.3e-3] {
        let rep = g.solve(&[at(-10.9e-3, 7.2e-3, d)]);
        assert!(rep.fallback && rep.converged, "{d}: {rep:?}");
    }
    let slid = at(-10.7e-3, 7.8e-3, 1.3e-3);
    let rep = g.solve(&[slid.clone()]);
    assert!(!rep.fallback && rep.converged, "{rep:?}");
    let mut fresh = gel(params, options);
    fresh.solve(&[slid]);
    let (a, b) = (g.force().z, fresh.force().z);
    assert!(
        b > 0.1 && (a / b - 1.0).abs() < 0.01,
        "after the fallback {a} N, from rest {b} N"
    );
}

/// A flat square punch 16 mm wide (four layer thicknesses, as the pattern `flat_slab`)
/// pressed 0.1 mm into the default gel at dx = 0.7 mm (5.7 cells through the layer): with
/// the multipliers' gain chosen on spheres their loop oscillated (the residual stayed
/// between 0.2 and 0.9 until the iteration cap, 0.38 at the end); halving the gain when a
/// window of steps makes no progress ends it. The force agrees with the same press on the
/// 1.0 mm grid (which converges at the full gain) within 5 % (convergence under
/// refinement: the two grids' forces on `flat_slab` are 2 % apart).
#[test]
fn a_wide_flat_punch_converges_on_a_finer_grid() {
    let punch: Arc<dyn Sdf> =
        Arc::new(crate::geometry::Cuboid::new(Vector3::new(8e-3, 8e-3, 2e-3)));
    let force = |dx: f64| {
        let mut g = gel(frictionless(dx), SolverOptions::default());
        let rep = g.solve(&[Placed {
            shape: punch.clone(),
            pose: Isometry3::translation(0.0, 0.0, 2e-3 - 0.1e-3),
        }]);
        assert!(rep.converged, "dx {dx}: {rep:?}");
        (g.force().z, rep)
    };
    let (fine, rep) = force(0.7e-3);
    let (coarse, _) = force(1.0e-3);
    assert!(
        (fine - coarse).abs() <= 0.05 * coarse,
        "{fine} N against {coarse} N; {rep:?}"
    );
}

// Elasticity has no length of its own: a gel, its grid and its indenter scaled by `s`
// give the same equilibrium scaled (depths times `s`, forces times `s^2` at the same
// Young's modulus), to rounding, for every solver. The contact stiffness, tolerances and
// depth rule are set in the grid's and the gel's units; an absolute length anywhere in
// the solve would break this. It is what lets a reduced-order model read a gel of its
// shape at any thickness in its own units (`Rom::serve`). Spacings scaled by powers of
// two are exact in floating point; 1.5 rounds.
#[test]
fn a_scaled_press_is_the_press_scaled() {
    let solve = |solver: Solver, s: f64| {
        let base = GelParams::default();
        let params = GelParams {
            size: base.size.map(|v| v * s),
            dx: base.dx * s,
            ..base
        };
        let mut g = gel(
            params,
            SolverOptions {
                solver,
                ..Default::default()
            },
        );
        let rep = g.solve(&[sphere_at(R * s, 3e-3 * s, -2e-3 * s, (R - 0.5e-3) * s)]);
        assert_sane(&g, &rep);
        assert!(rep.converged, "{solver:?} at scale {s}: {rep:?}");
        let grid = PixelGrid {
            width: 60,
            height: 60,
            fov_x: 0.024 * s,
            fov_y: 0.024 * s,
        };
        (depth_image(&g, &grid), g.force())
    };
    for solver in [Solver::Relaxation, Solver::Linear, Solver::Newton] {
        let (d1, f1) = solve(solver, 1.0);
        let peak = d1.iter().cloned().fold(0.0, f64::max);
        assert!(peak > 0.3e-3, "{solver:?}: peak {peak}");
        for s in [0.5, 0.25, 1.5] {
            let (ds, fs) = solve(solver, s);
            let worst = d1
                .iter()
                .zip(&ds)
                .map(|(a, b)| (a - b / s).abs())
                .fold(0.0, f64::max);
            let force = (fs / (s * s) - f1).norm() / f1.norm();
            println!(
                "{solver:?} s {s}: worst depth {worst:.2e} m of {peak:.2e}, force {force:.1e}"
            );
            // The image's inverse map too stops in the gel's units (its one-step bound a
            // fraction of the thickness, `ONE_STEP_FRACTION`): a scale by a power of two
            // gives the image scaled (the same bits, measured). A scale that rounds may
            // stop the iterations a step apart: the two answers then agree to the
            // solve's own tolerance.
            let (depth_bound, force_bound) = if s.log2().fract() == 0.0 {
                (1e-12 * peak, 1e-12)
            } else {
                let tolerance = SolverOptions::default().tolerance;
                (tolerance * peak, tolerance)
            };
            assert!(worst <= depth_bound, "{solver:?} s {s}: {worst} of {peak}");
            assert!(force <= force_bound, "{solver:?} s {s}: force {force}");
        }
    }
}
