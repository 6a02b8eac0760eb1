//! Normal contact pressure on the image grid.
//!
//! Each solve leaves its contact loads: the surface points in contact, where they are
//! (deformed, sensor frame) and the force each carries (the top particles for dynamic
//! relaxation, the points of the finer contact lattice for Newton).
//! [`Gel::contact_pressure`] spreads the normal component of every load over the pixels
//! with a tent kernel two particle spacings wide (piecewise-linear interpolation of the
//! pressure on the particle lattice), integrating the kernel exactly over each pixel, and
//! divides by the pixel area. The particle spacing is the finest scale on which the grid's
//! displacement field resolves a pressure: Newton's contact lattice samples the indenter's
//! shape more finely, but the few of its points that touch a surface which cannot conform
//! below that scale carry the load between them, and spreading them any narrower would
//! draw those points, not the pressure. The kernel integrates to one, so the image integrates to the normal force
//! ([`Gel::force`]`.z`) up to round-off wherever the contact lies inside the image.

use nalgebra::Vector3;

use super::Gel;
use crate::geometry::PixelGrid;

/// One surface point's contact load after a solve.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ContactLoad {
    /// Deformed position in the gel plane (sensor frame x, y; m).
    pub at: [f64; 2],
    /// Force on the indenters (N, sensor frame).
    pub force: Vector3<f64>,
}

/// Fraction of a tent kernel of half-width `s` centred at 0 that lies below `u`.
#[inline]
fn tent_below(u: f64, s: f64) -> f64 {
    if u <= -s {
        0.0
    } else if u <= 0.0 {
        (u + s) * (u + s) / (2.0 * s * s)
    } else if u < s {
        1.0 - (s - u) * (s - u) / (2.0 * s * s)
    } else {
        1.0
    }
}

/// The pixels a tent of half-width `s` at `c` reaches along one axis (`n` pixels of size
/// `p`, the first starting at `start` and going in direction `sign`), with the fraction of
/// the tent in each.
fn spread(c: f64, s: f64, n: usize, start: f64, p: f64, sign: f64, out: &mut Vec<(usize, f64)>) {
    out.clear();
    // Pixel k spans [start + sign k p, start + sign (k + 1) p].
    let centre = (c - start) * sign / p;
    let reach = s / p;
    let lo = (centre - reach).floor().max(0.0) as usize;
    let hi = ((centre + reach).ceil().max(0.0) as usize).min(n);
    for k in lo..hi {
        let (a, b) = (k as f64 * p, (k + 1) as f64 * p);
        let rel = (c - start) * sign;
        let w = tent_below(b - rel, s) - tent_below(a - rel, s);
        if w > 0.0 {
            out.push((k, w));
        }
    }
}

impl Gel {
    /// Normal contact pressure (Pa, positive where the indenters press the gel) at each
    /// pixel of `grid`, row-major into `out`, from the last solve's contact loads (see
    /// [`pressure`](self)). Zero without contact.
    ///
    /// # Panics
    /// If `out` is shorter than `grid.width * grid.height`.
    pub fn contact_pressure(&self, grid: &PixelGrid, out: &mut [f64]) {
        let out = &mut out[..grid.width * grid.height];
        out.fill(0.0);
        if self.loads.is_empty() {
            return;
        }
        let (pw, ph) = (
            grid.fov_x / grid.width as f64,
            grid.fov_y / grid.height as f64,
        );
        let [sx, sy] = self.load_spacing;
        let (mut cols, mut rows) = (Vec::new(), Vec::new());
        for load in &self.loads {
            let value = load.force.z / (pw * ph);
            if value == 0.0 || !value.is_finite() {
                continue;
            }
            spread(
                load.at[0],
                sx,
                grid.width,
                -0.5 * grid.fov_x,
                pw,
                1.0,
                &mut cols,
            );
            spread(
                load.at[1],
                sy,
                grid.height,
                0.5 * grid.fov_y,
                ph,
                -1.0,
                &mut rows,
            );
            for &(r, wr) in &rows {
                let row = &mut out[r * grid.width..(r + 1) * grid.width];
                for &(c, wc) in &cols {
                    row[c] += value * wr * wc;
                }
            }
        }
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
    // sums; the tent integrates to one), for both solvers, with and without friction, for
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
    // symmetric under x -> -x and y -> -y and lies within the Hertz contact disc.
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
            // Both stop at an out-of-balance force of 1e-3 of the load. Newton's linear
            // solves leave mirrored loads some 1e-5 apart (measured 4e-6); relaxation's
            // f32 state and explicit sweep leave them some 1e-3 apart (measured 5e-3).
            let tolerance = match solver {
                Solver::Newton => 1e-4,
                Solver::Relaxation => 1e-2,
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
            // Hertz: p ~ sqrt(1 - r^2 / a^2) on the disc r < a = sqrt(R d), whose
            // pressure-weighted mean radius is 3 pi a / 16 = 0.59 a. The tent spreads it
            // by up to a particle spacing (0.5 mm = 0.53 a here).
            let a = (3e-3f64 * 0.3e-3).sqrt();
            let (mut moment, mut total) = (0.0, 0.0);
            for r in 0..h {
                for c in 0..w {
                    let radius = grid.x(c).hypot(grid.y(r));
                    moment += radius * p[r * w + c];
                    total += p[r * w + c];
                }
            }
            let mean = moment / total / a;
            eprintln!("{solver:?}: mean contact radius {mean:.3} a");
            assert!(
                (0.3..1.0).contains(&mean),
                "{solver:?}: mean radius {mean} a"
            );
        }
    }

    // The tent's fractions over any tiling of the line sum to one, and a pixel grid finer
    // than the tent resolves its linear flanks.
    #[test]
    fn the_tent_spreads_all_of_a_load() {
        let mut out = Vec::new();
        for &(c, s, p) in &[(0.013, 0.7, 0.094), (0.0, 0.2, 0.5), (1.234, 0.35, 0.01)] {
            spread(c, s, 1000, -5.0, p, 1.0, &mut out);
            let total: f64 = out.iter().map(|w| w.1).sum();
            assert!((total - 1.0).abs() < 1e-12, "{total}");
        }
        spread(0.0, 1.0, 100, -5.0, 0.1, -1.0, &mut out);
        assert!(out.is_empty(), "a tent outside the image spreads nothing");
    }
}
