//! The camera under the gel, and what each of its pixels sees through the refracting gel.
//!
//! Geometry (sensor frame, metres; figure in `docs/camera.md`): the gel fills
//! `z in [-T, 0]`, its undeformed top face at `z = 0`, its flat bottom face at `z = -T`; a
//! surface point at indentation `d` lies at `z = -d`. A pinhole camera sits on the gel's
//! axis at `(0, 0, -T - D)`, in a medium whose refractive index relative to the gel's is
//! `1 / n`. The ray of pixel `(row, col)` is the one that meets the *undeformed* top face at
//! the pixel's orthographic centre `P` ([`PixelGrid::x`], [`PixelGrid::y`]): straight from
//! the pinhole to the bottom face at `B`, bent there by Snell's law (`sin a = n sin b`, `a`
//! and `b` the angles from the vertical outside and inside the gel), straight through the
//! gel to `P`. So with no contact every camera shows the orthographic image, and `fov`
//! keeps its meaning. In the gel the ray drifts towards the axis as it goes down: the point
//! it reaches at indentation `d` is `P - d tan(b) P / |P|`. The pixel's depth is the
//! indentation `d*` at which it meets the deformed surface, the height field `h` of the
//! orthographic depth image (bilinear between pixel centres): the largest root of
//! `d = h(P - d tan(b) P / |P|)`, the first surface point met coming up from the camera.
//!
//! A ray never leaves the image's footprint: it moves towards the axis and, within the
//! gel's thickness, never past it (`|B| >= 0`). Orthographic rays are vertical (`tan b =
//! 0`), so there the camera changes nothing, whatever the index.

use crate::geometry::PixelGrid;

/// The camera under the gel (`camera` attribute).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Camera {
    /// Vertical rays: each pixel sees the surface point straight above its centre.
    Orthographic,
    /// A pinhole on the gel's axis, `distance` (m) below the gel's bottom face, looking up
    /// through the refracting gel.
    Pinhole {
        /// Distance from the pinhole to the gel's bottom face (m).
        distance: f64,
    },
}

/// How an image on the pixel grid is sampled at the surface point a pixel sees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sampling {
    /// Bilinearly between the four surrounding pixel centres (fields: colour, pressure,
    /// displacement).
    Bilinear,
    /// From the nearest pixel centre (masks, whose values are categories).
    Nearest,
}

/// The tan of a pinhole ray's angle from the vertical inside the gel, for the ray that
/// meets the undeformed top face at distance `r` (m) from the axis; the gel is `thickness`
/// (m) thick, the pinhole `distance` (m) below its bottom face, `index` the gel's
/// refractive index relative to the camera's medium.
///
/// Solves Snell's law `sin a = n sin b` for the horizontal run `s = T tan b` of the ray in
/// the gel: `n s / hypot(s, T) = (r - s) / hypot(r - s, D)`, whose two sides cross once on
/// `[0, r]` (the left rises from 0, the right falls to 0). Newton's method from the
/// straight ray (`n = 1`: `s = r T / (T + D)`, exact there), kept inside a bisection
/// bracket; a few iterations to rounding.
pub fn gel_slope(r: f64, thickness: f64, distance: f64, index: f64) -> f64 {
    let (t, dd, n) = (thickness, distance, index);
    if !(r > 0.0 && r.is_finite() && t > 0.0 && dd > 0.0 && n > 0.0) {
        return 0.0;
    }
    // phi(s) = n sin b - sin a, increasing in s, negative at 0 and positive at r.
    let phi = |s: f64| n * s / s.hypot(t) - (r - s) / (r - s).hypot(dd);
    let slope = |s: f64| n * t * t / s.hypot(t).powi(3) + dd * dd / (r - s).hypot(dd).powi(3);
    let (mut lo, mut hi) = (0.0, r);
    let mut s = r * t / (t + dd);
    for _ in 0..100 {
        let f = phi(s);
        if f == 0.0 {
            break;
        }
        if f > 0.0 {
            hi = s;
        } else {
            lo = s;
        }
        let newton = s - f / slope(s);
        let next = if newton > lo && newton < hi {
            newton
        } else {
            0.5 * (lo + hi)
        };
        let done = (next - s).abs() <= 1e-15 * r;
        s = next;
        if done {
            break;
        }
    }
    s.clamp(0.0, r) / t
}

/// Cells per side of the tiles whose largest node values bound the surface along a ray.
const TILE: usize = 8;

/// A pinhole camera under a refracting gel, on one pixel grid: each pixel's ray, computed
/// once for the configuration, and the tracing of the rays through a surface.
#[derive(Clone, Debug, PartialEq)]
pub struct Refraction {
    width: usize,
    height: usize,
    thickness: f64,
    /// Per pixel (row-major), how far its ray moves across the image per metre of
    /// indentation, in columns and rows: at indentation `d` it is at
    /// `(col - d drift[0], row - d drift[1])` (continuous pixel coordinates, `c` at the
    /// centre of column `c`).
    drift: Vec<[f64; 2]>,
    /// Tiles along x and y.
    tiles_x: usize,
    tiles_y: usize,
    /// Per tile of `TILE x TILE` cells of the pixel-centre lattice, the largest surface
    /// value at its nodes: no bilinear value inside it is larger (one frame's workspace).
    tiles: Vec<f64>,
}

impl Refraction {
    /// The rays of a pinhole `distance` (m) below the bottom face of a gel `thickness` (m)
    /// thick with refractive index `index` relative to the camera's medium, one per pixel
    /// of `grid`.
    pub fn new(grid: &PixelGrid, thickness: f64, distance: f64, index: f64) -> Self {
        let (w, h) = (grid.width, grid.height);
        let (px, py) = (grid.fov_x / w as f64, grid.fov_y / h as f64);
        let mut drift = Vec::with_capacity(w * h);
        for row in 0..h {
            let y = grid.y(row);
            for col in 0..w {
                let x = grid.x(col);
                let r = x.hypot(y);
                let g = if r > 0.0 {
                    gel_slope(r, thickness, distance, index) / r
                } else {
                    0.0
                };
                // x grows with the column, y falls with the row.
                drift.push([g * x / px, -g * y / py]);
            }
        }
        let cells = |n: usize| n.saturating_sub(1).max(1);
        let tiles_x = cells(w).div_ceil(TILE);
        let tiles_y = cells(h).div_ceil(TILE);
        Self {
            width: w,
            height: h,
            thickness,
            drift,
            tiles_x,
            tiles_y,
            tiles: vec![0.0; tiles_x * tiles_y],
        }
    }

    /// The ray drift of pixel `(row, col)`: columns and rows per metre of indentation.
    pub fn drift(&self, row: usize, col: usize) -> [f64; 2] {
        self.drift[row * self.width + col]
    }

    /// The continuous pixel coordinates (column, row) of the surface point that pixel
    /// `index` (row-major) sees at indentation `depth` (m).
    #[inline]
    pub fn seen(&self, index: usize, depth: f64) -> [f64; 2] {
        let [gu, gv] = self.drift[index];
        let (col, row) = ((index % self.width) as f64, (index / self.width) as f64);
        [col - depth * gu, row - depth * gv]
    }

    /// Traces every pixel's ray through the surface whose orthographic depth image is
    /// `surface` (m, positive into the gel, row-major on the grid; the depth rule's values,
    /// within `[0, T]`; others are taken as the nearest such value, non-finite ones as 0)
    /// and writes the indentation each ray meets into `depth`. Returns whether any pixel
    /// sees a point other than its own centre (false for a flat surface, whose image every
    /// camera shows alike). Never writes NaN; each ray costs at most `W + H + 4` cells.
    ///
    /// # Panics
    /// If `surface` or `depth` does not hold one value per pixel.
    pub fn refract(&mut self, surface: &[f64], depth: &mut [f64]) -> bool {
        let n = self.width * self.height;
        assert_eq!(surface.len(), n, "surface image of {n} pixels");
        assert_eq!(depth.len(), n, "depth image of {n} pixels");
        let top = self.fill_tiles(surface);
        if top <= 0.0 {
            depth.fill(0.0);
            return false;
        }
        for (i, d) in depth.iter_mut().enumerate() {
            *d = self.trace(surface, i, top);
        }
        true
    }

    /// Samples `image` (`channels` values per pixel, row-major on the grid) at the surface
    /// point each pixel sees at its traced indentation `depth` (from
    /// [`Refraction::refract`]), clamped to the grid, into `out`. A pixel whose ray meets
    /// the surface at indentation 0 sees its own centre and gets its own value, bit for
    /// bit.
    ///
    /// # Panics
    /// If the slices do not hold one value (`depth`) or `channels` values per pixel.
    pub fn resample(
        &self,
        depth: &[f64],
        channels: usize,
        sampling: Sampling,
        image: &[f64],
        out: &mut [f64],
    ) {
        let n = self.width * self.height;
        assert_eq!(depth.len(), n, "depth image of {n} pixels");
        assert_eq!(
            image.len(),
            channels * n,
            "image of {n} x {channels} values"
        );
        assert_eq!(out.len(), channels * n, "image of {n} x {channels} values");
        for (i, (&d, px)) in depth.iter().zip(out.chunks_exact_mut(channels)).enumerate() {
            if d == 0.0 {
                px.copy_from_slice(&image[channels * i..channels * (i + 1)]);
                continue;
            }
            let [u, v] = self.seen(i, d);
            match sampling {
                Sampling::Nearest => {
                    let c = nearest(u, self.width);
                    let r = nearest(v, self.height);
                    let at = channels * (r * self.width + c);
                    px.copy_from_slice(&image[at..at + channels]);
                }
                Sampling::Bilinear => {
                    let (c0, c1, fx) = bracket(u, self.width);
                    let (r0, r1, fy) = bracket(v, self.height);
                    let w = self.width;
                    for (k, o) in px.iter_mut().enumerate() {
                        let at = |r: usize, c: usize| image[channels * (r * w + c) + k];
                        let top = lerp(at(r0, c0), at(r0, c1), fx);
                        let bottom = lerp(at(r1, c0), at(r1, c1), fx);
                        *o = lerp(top, bottom, fy);
                    }
                }
            }
        }
    }

    /// The surface value at node `(col, row)`, within `[0, T]` (non-finite: 0).
    #[inline]
    fn node(&self, surface: &[f64], col: usize, row: usize) -> f64 {
        // f64::max returns the number when one side is NaN.
        surface[row * self.width + col].max(0.0).min(self.thickness)
    }

    /// Fills the tile maxima of `surface`; returns the largest value of all.
    fn fill_tiles(&mut self, surface: &[f64]) -> f64 {
        let (w, h) = (self.width, self.height);
        let mut top: f64 = 0.0;
        for ty in 0..self.tiles_y {
            let rows = ty * TILE..((ty + 1) * TILE).min(h - 1) + 1;
            for tx in 0..self.tiles_x {
                let cols = tx * TILE..((tx + 1) * TILE).min(w - 1) + 1;
                let mut m: f64 = 0.0;
                for r in rows.clone() {
                    for c in cols.clone() {
                        m = m.max(self.node(surface, c, r));
                    }
                }
                self.tiles[ty * self.tiles_x + tx] = m;
                top = top.max(m);
            }
        }
        top
    }

    /// The largest surface value over the cells that the segment from `(u0, v0)` to
    /// `(u1, v1)` (pixel coordinates) can cross: a bound on the surface along it.
    #[inline]
    fn bound(&self, u0: f64, v0: f64, u1: f64, v1: f64) -> f64 {
        let tile = |a: f64, n: usize, tiles: usize| {
            let cell = (a.floor().max(0.0) as usize).min(n.saturating_sub(2));
            (cell / TILE).min(tiles - 1)
        };
        let (ta, tb) = (
            tile(u0.min(u1), self.width, self.tiles_x),
            tile(u0.max(u1), self.width, self.tiles_x),
        );
        let (sa, sb) = (
            tile(v0.min(v1), self.height, self.tiles_y),
            tile(v0.max(v1), self.height, self.tiles_y),
        );
        let mut m: f64 = 0.0;
        for ty in sa..=sb {
            for tx in ta..=tb {
                m = m.max(self.tiles[ty * self.tiles_x + tx]);
            }
        }
        m
    }

    /// The indentation at which pixel `index`'s ray meets the surface, `top` the surface's
    /// largest value.
    fn trace(&self, surface: &[f64], index: usize, top: f64) -> f64 {
        let (w, h) = (self.width, self.height);
        let [gu, gv] = self.drift[index];
        let (u0, v0) = ((index % w) as f64, (index / w) as f64);

        // Above the surface's largest value along the ray the ray is still in the gel;
        // tighten that bound with the tiles the shortened ray crosses.
        let mut hi = top;
        for _ in 0..4 {
            let m = self.bound(u0, v0, u0 - hi * gu, v0 - hi * gv);
            if m >= hi {
                break;
            }
            hi = m;
        }
        if hi <= 0.0 {
            return 0.0;
        }

        // Walk the lattice's cells from indentation `hi` up to the top face (the camera's
        // ray, coming up through the gel), solving d = h(d) exactly in each: along a line,
        // the bilinear surface of one cell is a quadratic in d.
        let cell = |a: f64, g: f64| {
            if g < 0.0 {
                a.ceil() as i64 - 1
            } else {
                a.floor() as i64
            }
        };
        let mut i = cell(u0 - hi * gu, gu);
        let mut j = cell(v0 - hi * gv, gv);
        let (step_i, step_j) = (sign(gu), sign(gv));
        for _ in 0..w + h + 4 {
            // Where the ray leaves cell (i, j), moving towards d = 0.
            let exit = |k: i64, g: f64, a0: f64| {
                if g > 0.0 {
                    (a0 - (k + 1) as f64) / g
                } else if g < 0.0 {
                    (a0 - k as f64) / g
                } else {
                    f64::NEG_INFINITY
                }
            };
            let (du, dv) = (exit(i, gu, u0), exit(j, gv, v0));
            let lo = du.max(dv).max(0.0);
            let lo = lo.min(hi);
            let ic = (i.max(0) as usize).min(w.saturating_sub(2));
            let jc = (j.max(0) as usize).min(h.saturating_sub(2));
            let (i1, j1) = ((ic + 1).min(w - 1), (jc + 1).min(h - 1));
            let h00 = self.node(surface, ic, jc);
            let h10 = self.node(surface, i1, jc);
            let h01 = self.node(surface, ic, j1);
            let h11 = self.node(surface, i1, j1);
            let (b, c, e) = (h10 - h00, h01 - h00, h11 - h10 - h01 + h00);
            let (fx0, fy0) = (u0 - ic as f64, v0 - jc as f64);
            // h(d) = k0 + k1 d + k2 d^2 with fx = fx0 - d gu, fy = fy0 - d gv.
            let k0 = h00 + b * fx0 + c * fy0 + e * fx0 * fy0;
            let k1 = -(b * gu + c * gv + e * (fx0 * gv + fy0 * gu));
            let k2 = e * gu * gv;
            if let Some(d) = largest_root([-k0, 1.0 - k1, -k2], lo, hi) {
                return d.clamp(0.0, self.thickness);
            }
            if lo <= 0.0 {
                break;
            }
            if du >= dv {
                i += step_i;
            }
            if dv >= du {
                j += step_j;
            }
            hi = lo;
        }
        // Not reached for a surface within [0, T] (F(0) = -h(P) <= 0 ends the walk): the
        // orthographic value.
        self.node(surface, index % w, index / w)
    }
}

fn sign(g: f64) -> i64 {
    if g > 0.0 {
        1
    } else if g < 0.0 {
        -1
    } else {
        0
    }
}

/// `a` to `b` by `t`, exactly `a` at `t = 0`.
#[inline]
fn lerp(a: f64, b: f64, t: f64) -> f64 {
    if t == 0.0 {
        a
    } else {
        a + t * (b - a)
    }
}

/// The nodes below and above continuous coordinate `a` on `n` nodes, clamped, and the
/// fraction of the way from the first to the second.
#[inline]
fn bracket(a: f64, n: usize) -> (usize, usize, f64) {
    let top = (n - 1) as f64;
    let a = if a.is_finite() {
        a.clamp(0.0, top)
    } else {
        0.0
    };
    let k = (a.floor() as usize).min(n.saturating_sub(2));
    (
        (k),
        (k + 1).min(n - 1),
        if n > 1 { a - k as f64 } else { 0.0 },
    )
}

/// The node nearest continuous coordinate `a` on `n` nodes, clamped.
#[inline]
fn nearest(a: f64, n: usize) -> usize {
    if a.is_finite() {
        (a.round().max(0.0) as usize).min(n - 1)
    } else {
        0
    }
}

/// The largest root in `[lo, hi]` of `F(d) = c0 + c1 d + c2 d^2`, given `F(hi) >= 0` (the
/// ray is in the gel where it enters the cell); `None` when `F > 0` all through.
fn largest_root(c: [f64; 3], lo: f64, hi: f64) -> Option<f64> {
    let f = |d: f64| c[0] + d * (c[1] + d * c[2]);
    let (mut top, f_hi) = (hi, f(hi));
    if !(f_hi > 0.0) {
        return Some(hi);
    }
    // F is monotone on each side of its vertex: look above the vertex first.
    if c[2] != 0.0 {
        let vertex = -c[1] / (2.0 * c[2]);
        if vertex > lo && vertex < hi {
            if f(vertex) <= 0.0 {
                return Some(root_between(c, vertex, top));
            }
            top = vertex;
        }
    }
    if f(lo) <= 0.0 {
        return Some(root_between(c, lo, top));
    }
    None
}

/// The root of the quadratic `c` in `[a, b]`, where it is monotone with `F(a) <= 0 <
/// F(b)`: the closed form, clamped into the bracket; the secant if rounding put it outside.
fn root_between(c: [f64; 3], a: f64, b: f64) -> f64 {
    let f = |d: f64| c[0] + d * (c[1] + d * c[2]);
    let (fa, fb) = (f(a), f(b));
    let secant = || {
        let t = fa / (fa - fb);
        if t.is_finite() {
            a + (b - a) * t.clamp(0.0, 1.0)
        } else {
            a
        }
    };
    let slack = 1e-9 * (b - a);
    let inside = |r: f64| r.is_finite() && r >= a - slack && r <= b + slack;
    let root = if c[2].abs() * (b - a) <= 1e-12 * c[1].abs() {
        // Linear to rounding.
        -c[0] / c[1]
    } else {
        let disc = (c[1] * c[1] - 4.0 * c[0] * c[2]).max(0.0);
        let q = -0.5 * (c[1] + disc.sqrt().copysign(c[1]));
        let (r1, r2) = (q / c[2], c[0] / q);
        match (inside(r1), inside(r2)) {
            (true, true) => r1.max(r2),
            (true, false) => r1,
            (false, true) => r2,
            (false, false) => f64::NAN,
        }
    };
    if inside(root) {
        root.clamp(a, b)
    } else {
        secant()
    }
}

#[cfg(test)]
mod tests;
