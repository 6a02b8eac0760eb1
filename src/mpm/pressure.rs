//! Normal contact pressure on the image grid.
//!
//! Each solve leaves its contact loads: the surface points in contact, where they are
//! (deformed, sensor frame) and the force each carries (the top particles for dynamic
//! relaxation, the points of the finer contact lattice for Newton).
//! [`Gel::contact_pressure`] spreads the normal component of every load over the pixels
//! with the grid's own quadratic B-spline kernel (one cell wide, support three cells: the
//! weights with which MPM hands a particle's force to the grid nodes), integrating it
//! exactly over each pixel, and divides by the pixel area. The kernel integrates to one,
//! so the image integrates to the normal force ([`Gel::force`]`.z`) up to round-off
//! wherever the contact lies inside the image. The grid resolves a pressure on the scale
//! of its cells and no finer: the loads of single surface points vary below that scale
//! (relaxation's per-particle multipliers; the few of Newton's contact points that touch a
//! surface which cannot conform within a cell), and a narrower kernel would draw those
//! points rather than the pressure.

use nalgebra::Vector3;

use super::Gel;
use crate::geometry::PixelGrid;

/// One surface point's contact load after a solve.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ContactLoad {
    /// Deformed position in the gel plane (sensor frame x, y; m).
    pub at: [f64; 2],
    /// Its height (sensor frame z; m).
    pub z: f64,
    /// Force on the indenters (N, sensor frame).
    pub force: Vector3<f64>,
}

/// Fraction of the quadratic B-spline kernel of width `h` centred at 0 that lies below `u`
/// (the kernel is `N(u / h) / h`, `N(t) = 3/4 - t^2` for `|t| <= 1/2` and
/// `(3/2 - |t|)^2 / 2` for `1/2 <= |t| <= 3/2`).
#[inline]
fn kernel_below(u: f64, h: f64) -> f64 {
    let t = u / h;
    if t <= -1.5 {
        0.0
    } else if t <= -0.5 {
        (t + 1.5).powi(3) / 6.0
    } else if t <= 0.5 {
        1.0 / 6.0 + 0.75 * (t + 0.5) - (t.powi(3) + 0.125) / 3.0
    } else if t < 1.5 {
        1.0 - (1.5 - t).powi(3) / 6.0
    } else {
        1.0
    }
}

/// The pixels the kernel of width `h` at `c` reaches along one axis (`n` pixels of size
/// `p`, the first starting at `start` and going in direction `sign`), with the fraction of
/// the kernel in each.
fn spread(c: f64, h: f64, n: usize, start: f64, p: f64, sign: f64, out: &mut Vec<(usize, f64)>) {
    out.clear();
    // Pixel k spans [start + sign k p, start + sign (k + 1) p].
    let centre = (c - start) * sign / p;
    let reach = 1.5 * h / p;
    let lo = (centre - reach).floor().max(0.0) as usize;
    let hi = ((centre + reach).ceil().max(0.0) as usize).min(n);
    for k in lo..hi {
        let (a, b) = (k as f64 * p, (k + 1) as f64 * p);
        let rel = (c - start) * sign;
        let w = kernel_below(b - rel, h) - kernel_below(a - rel, h);
        if w > 0.0 {
            out.push((k, w));
        }
    }
}

/// Spreads normal loads over the pixels of `grid` as pressure (Pa), row-major into `out`
/// (zeroed first): each load `(x, y, fz)` (sensor frame m, N) with the quadratic B-spline
/// kernel of width `h` along each axis, integrated exactly over each pixel, divided by the
/// pixel area. The kernel integrates to one, so the image integrates to the loads' sum
/// wherever they lie a kernel's reach inside the image.
///
/// # Panics
/// If `out` is shorter than `grid.width * grid.height`.
pub fn spread_loads(
    loads: impl IntoIterator<Item = (f64, f64, f64)>,
    h: f64,
    grid: &PixelGrid,
    out: &mut [f64],
) {
    let out = &mut out[..grid.width * grid.height];
    out.fill(0.0);
    let (pw, ph) = (
        grid.fov_x / grid.width as f64,
        grid.fov_y / grid.height as f64,
    );
    let (mut cols, mut rows) = (Vec::new(), Vec::new());
    for (x, y, fz) in loads {
        let value = fz / (pw * ph);
        if value == 0.0 || !value.is_finite() {
            continue;
        }
        spread(x, h, grid.width, -0.5 * grid.fov_x, pw, 1.0, &mut cols);
        spread(y, h, grid.height, 0.5 * grid.fov_y, ph, -1.0, &mut rows);
        for &(r, wr) in &rows {
            let row = &mut out[r * grid.width..(r + 1) * grid.width];
            for &(c, wc) in &cols {
                row[c] += value * wr * wc;
            }
        }
    }
}

impl Gel {
    /// Normal contact pressure (Pa, positive where the indenters press the gel) at each
    /// pixel of `grid`, row-major into `out`, from the last solve's contact loads (see
    /// `pressure.rs`), spread with the grid's own kernel ([`spread_loads`]). Zero without
    /// contact.
    ///
    /// # Panics
    /// If `out` is shorter than `grid.width * grid.height`.
    pub fn contact_pressure(&self, grid: &PixelGrid, out: &mut [f64]) {
        let loads = self.loads.iter().map(|l| (l.at[0], l.at[1], l.force.z));
        spread_loads(loads, self.layout.dx, grid, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Placed, Sphere};
    use crate::mpm::{GelParams, Solver, SolverOptions};
    use nalgebra::Isometry3;
    use std::sync::Arc;

    /// A 10 x 10 x 2 mm gel at 1 mm, and an image covering it at 0.125 mm pixels.
    fn gel(solver: Solver, friction: f64) -> (Gel, PixelGrid) {
        let params = GelParams {
            size: [0.01, 0.01, 0.002],
            dx: 1e-3,
            friction,
            ..Default::default()
        };
        let options = SolverOptions {
            solver,
            ..Default::default()
        };
        let grid = PixelGrid {
            width: 80,
            height: 80,
            fov_x: 0.01,
            fov_y: 0.01,
        };
        (Gel::new(params, options).unwrap(), grid)
    }

    fn sphere_at(x: f64, y: f64, depth: f64) -> Placed {
        let r = 3e-3;
        Placed {
            shape: Arc::new(Sphere { radius: r }),
            pose: Isometry3::translation(x, y, r - depth),
        }
    }

    // The pressure image integrates to the normal force (the loads are the ones the force
    // sums; the kernel integrates to one), for both solvers, with and without friction, for
    // a press off the lattice's symmetry lines; without contact it is zero.
    #[test]
    fn pressure_integrates_to_the_normal_force() {
        for solver in Solver::ALL {
            for friction in [0.0, 0.5] {
                let (mut g, grid) = gel(solver, friction);
                let mut p = vec![f64::NAN; grid.width * grid.height];
                let pixel = grid.fov_x * grid.fov_y / (grid.width * grid.height) as f64;
                for depth in [0.2e-3, 0.4e-3] {
                    g.solve(&[sphere_at(0.37e-3, -0.21e-3, depth)]);
                    g.contact_pressure(&grid, &mut p);
                    let integral: f64 = p.iter().sum::<f64>() * pixel;
                    let fz = g.force().z;
                    assert!(fz > 0.0, "{solver:?}: no force");
                    assert!(
                        (integral - fz).abs() <= 1e-9 * fz,
                        "{solver:?} friction {friction}: {integral} N against {fz} N"
                    );
                    assert!(p.iter().all(|v| v.is_finite() && *v >= -1e-9 * fz / pixel));
                }
                g.solve(&[]);
                g.contact_pressure(&grid, &mut p);
                assert!(
                    p.iter().all(|&v| v == 0.0),
                    "{solver:?}: pressure after lifting"
                );
            }
        }
    }

    // A frictionless sphere at the centre of a symmetric gel presses a pattern that is
    // symmetric under x -> -x and y -> -y, lies within the kernel's reach of the Hertz
    // contact disc and peaks near the centre.
    #[test]
    fn a_centred_press_gives_a_symmetric_pressure_on_the_contact_disc() {
        for solver in Solver::ALL {
            let (mut g, grid) = gel(solver, 0.0);
            g.solve(&[sphere_at(0.0, 0.0, 0.3e-3)]);
            let mut p = vec![0.0; grid.width * grid.height];
            g.contact_pressure(&grid, &mut p);
            let (w, h) = (grid.width, grid.height);
            let peak = p.iter().copied().fold(0.0, f64::max);
            assert!(peak > 0.0);
            // Both stop at an out-of-balance force of 1e-3 of the load, which bounds how
            // far mirrored pressures may lie apart. Newton's contact penalty on this 2 mm
            // layer leaves 0.7 um under a pressure of `M` (a fraction of the thickness,
            // `PENETRATION`): its mirrored pressures lie 5.5e-4 of the peak apart
            // (measured; 9e-7 with the 1.4 um of the default gel, twice as soft here);
            // relaxation's f32 state and explicit sweep some 1e-4 (measured 3e-4). The
            // linear solver's complementarity solve is exact up to round-off.
            let tolerance = match solver {
                Solver::Linear => 1e-5,
                Solver::Newton => 1e-3,
                Solver::Relaxation | Solver::Total => 3e-3,
            };
            let mut worst = 0.0f64;
            for r in 0..h {
                for c in 0..w {
                    let v = p[r * w + c];
                    for m in [p[r * w + (w - 1 - c)], p[(h - 1 - r) * w + c]] {
                        worst = worst.max((v - m).abs() / peak);
                    }
                }
            }
            eprintln!("{solver:?}: asymmetry {worst:e} of the peak {peak} Pa");
            assert!(
                worst <= tolerance,
                "{solver:?}: asymmetry {worst} of the peak"
            );
            // Hertz: the contact disc has radius a = sqrt(R d) (a discrete contact patch a
            // little more); the kernel reaches 1.5 cells beyond it, and no farther.
            let a = (3e-3f64 * 0.3e-3).sqrt();
            let reach = 1.25 * a + 1.5 * 1e-3;
            for r in 0..h {
                for c in 0..w {
                    if grid.x(c).abs().max(grid.y(r).abs()) > reach {
                        assert!(
                            p[r * w + c] == 0.0,
                            "{solver:?}: pressure outside the contact"
                        );
                    }
                }
            }
            // A smooth dome: the largest pressure within a cell of the centre.
            let (mut best, mut at) = (0.0, (0.0, 0.0));
            for r in 0..h {
                for c in 0..w {
                    if p[r * w + c] > best {
                        best = p[r * w + c];
                        at = (grid.x(c), grid.y(r));
                    }
                }
            }
            assert!(at.0.hypot(at.1) < 1e-3, "{solver:?}: peak at {at:?}");
        }
    }

    // The kernel's fractions over any tiling of the line sum to one, its distribution
    // function is continuous at the knots and its density is the B-spline's.
    #[test]
    fn the_kernel_spreads_all_of_a_load() {
        for t in [-0.5, 0.5] {
            let (a, b) = (kernel_below(t - 1e-12, 1.0), kernel_below(t + 1e-12, 1.0));
            assert!((a - b).abs() < 1e-10, "{t}: {a} {b}");
        }
        for t in [-1.2, -0.7, -0.2, 0.0, 0.3, 0.9, 1.4] {
            let density = (kernel_below(t + 1e-6, 1.0) - kernel_below(t - 1e-6, 1.0)) / 2e-6;
            let n = if f64::abs(t) <= 0.5 {
                0.75 - t * t
            } else {
                0.5 * (1.5 - f64::abs(t)).powi(2)
            };
            assert!((density - n).abs() < 1e-6, "{t}: {density} {n}");
        }
        let mut out = Vec::new();
        for &(c, s, p) in &[(0.013, 0.7, 0.094), (0.0, 0.2, 0.5), (1.234, 0.35, 0.01)] {
            spread(c, s, 1000, -5.0, p, 1.0, &mut out);
            let total: f64 = out.iter().map(|w| w.1).sum();
            assert!((total - 1.0).abs() < 1e-12, "{total}");
        }
        spread(0.0, 1.0, 100, -5.0, 0.1, -1.0, &mut out);
        assert!(out.is_empty(), "a kernel outside the image spreads nothing");
    }
}
