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
//!
//! Tracing ([`Refraction::refract`]): the rays' drifts are computed once, at load. Per
//! frame, tiles of 8 x 8 lattice cells hold their largest surface value; a block of 8 x 8
//! rays starts from the largest value over the tiles its rays can cross (shortened to that
//! value and bounded again, a few times), so rays over a flat region cost nothing. Each
//! ray then walks the cells it crosses from that bound up to the top face, and in each
//! solves `d = h(d)` exactly: along a line a cell's bilinear surface is a quadratic in
//! `d`. The first root met is the answer, exact to rounding; most rays cross a single
//! cell. Every other image is resampled at the points the rays meet
//! ([`Refraction::resample`]).

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

/// Cells per side of the tiles whose largest node values bound the surface along a ray,
/// and pixels per side of the blocks of rays bounded together.
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
    /// Tiles of the lattice along x and y; blocks of pixels along x and y are as many
    /// (`TILE` pixels per side, the last block and tile possibly shorter).
    tiles_x: usize,
    tiles_y: usize,
    /// Per block of `TILE x TILE` pixels, the largest `|drift|` along columns and rows of
    /// its rays.
    spread: Vec<[f64; 2]>,
    /// The surface of the frame being traced, within `[0, T]` (workspace).
    surface: Vec<f64>,
    /// Per tile of `TILE x TILE` cells of the pixel-centre lattice, the largest surface
    /// value at its nodes: no bilinear value inside it is larger (workspace).
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
        // A lattice of n nodes has n - 1 cells (one, degenerate, when n = 1); as many
        // blocks of pixels as tiles of cells.
        let cells = |n: usize| n.saturating_sub(1).max(1);
        let tiles_x = cells(w).div_ceil(TILE);
        let tiles_y = cells(h).div_ceil(TILE);
        let mut spread = vec![[0.0f64; 2]; tiles_x * tiles_y];
        for (i, [gu, gv]) in drift.iter().enumerate() {
            let b = (i / w / TILE).min(tiles_y - 1) * tiles_x + (i % w / TILE).min(tiles_x - 1);
            spread[b] = [spread[b][0].max(gu.abs()), spread[b][1].max(gv.abs())];
        }
        Self {
            width: w,
            height: h,
            thickness,
            drift,
            tiles_x,
            tiles_y,
            spread,
            surface: vec![0.0; w * h],
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
    /// and writes the indentation each ray meets into `depth`. Returns whether the surface
    /// is deformed at all (false: it is flat, each pixel sees its own centre at indentation
    /// 0, and every camera shows the same image). Never writes NaN; each ray costs at most
    /// `W + H + 4` cells.
    ///
    /// # Panics
    /// If `surface` or `depth` does not hold one value per pixel.
    pub fn refract(&mut self, surface: &[f64], depth: &mut [f64]) -> bool {
        let (w, h) = (self.width, self.height);
        assert_eq!(surface.len(), w * h, "surface image of {w} x {h} pixels");
        assert_eq!(depth.len(), w * h, "depth image of {w} x {h} pixels");
        let top = self.load(surface);
        if top <= 0.0 {
            depth.fill(0.0);
            return false;
        }
        for by in 0..self.tiles_y {
            let rows = by * TILE..if by + 1 == self.tiles_y {
                h
            } else {
                (by + 1) * TILE
            };
            for bx in 0..self.tiles_x {
                let cols = bx * TILE..if bx + 1 == self.tiles_x {
                    w
                } else {
                    (bx + 1) * TILE
                };
                // Deeper than the surface's largest value along its rays, every ray of the
                // block is still in the gel; tighten that bound with the tiles the
                // shortened rays can cross.
                let [su, sv] = self.spread[by * self.tiles_x + bx];
                let mut hi = top;
                for _ in 0..4 {
                    let (eu, ev) = (hi * su, hi * sv);
                    let m = self.bound(
                        [cols.start as f64 - eu, (cols.end - 1) as f64 + eu],
                        [rows.start as f64 - ev, (rows.end - 1) as f64 + ev],
                    );
                    if m >= hi {
                        break;
                    }
                    hi = m;
                }
                for r in rows.clone() {
                    let line = &mut depth[r * w + cols.start..r * w + cols.end];
                    if hi <= 0.0 {
                        line.fill(0.0);
                        continue;
                    }
                    for (c, d) in cols.clone().zip(line) {
                        *d = self.trace(c, r, hi);
                    }
                }
            }
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
        // Monomorphised for the usual channel counts, so that the per-pixel loops unroll.
        match channels {
            1 => self.resample_with::<1>(depth, 1, sampling, image, out),
            2 => self.resample_with::<2>(depth, 2, sampling, image, out),
            3 => self.resample_with::<3>(depth, 3, sampling, image, out),
            _ => self.resample_with::<0>(depth, channels, sampling, image, out),
        }
    }

    /// [`Refraction::resample`] for `C` channels (`C = 0`: `channels`, as given).
    fn resample_with<const C: usize>(
        &self,
        depth: &[f64],
        channels: usize,
        sampling: Sampling,
        image: &[f64],
        out: &mut [f64],
    ) {
        let ch = if C == 0 { channels } else { C };
        let (w, h) = (self.width, self.height);
        for r in 0..h {
            let line = r * w..(r + 1) * w;
            let (depth, drift) = (&depth[line.clone()], &self.drift[line]);
            let out = &mut out[ch * r * w..ch * (r + 1) * w];
            for (c, ((&d, &[gu, gv]), px)) in depth
                .iter()
                .zip(drift)
                .zip(out.chunks_exact_mut(ch))
                .enumerate()
            {
                let copy = |px: &mut [f64], at: usize| {
                    px.copy_from_slice(&image[at..at + ch]);
                };
                if d == 0.0 {
                    copy(px, ch * (r * w + c));
                    continue;
                }
                let (u, v) = (c as f64 - d * gu, r as f64 - d * gv);
                match sampling {
                    Sampling::Nearest => copy(px, ch * (nearest(v, h) * w + nearest(u, w))),
                    Sampling::Bilinear => {
                        let (c0, c1, fx) = bracket(u, w);
                        let (r0, r1, fy) = bracket(v, h);
                        let at = |r: usize, c: usize| &image[ch * (r * w + c)..][..ch];
                        let (a, b) = (at(r0, c0), at(r0, c1));
                        let (c, d) = (at(r1, c0), at(r1, c1));
                        for (k, o) in px.iter_mut().enumerate() {
                            *o = lerp(lerp(a[k], b[k], fx), lerp(c[k], d[k], fx), fy);
                        }
                    }
                }
            }
        }
    }

    /// Copies `surface` into the workspace within `[0, T]` (non-finite: 0) and fills the
    /// tile maxima, row by row; returns the largest value of all.
    fn load(&mut self, surface: &[f64]) -> f64 {
        let (w, h, t) = (self.width, self.height, self.thickness);
        let (tiles_x, tiles_y) = (self.tiles_x, self.tiles_y);
        // Comparisons rather than f64::max, so that the loops vectorise: NaN fails both
        // tests and becomes 0, +inf becomes T.
        let bigger = |m: f64, v: f64| if v > m { v } else { m };
        self.tiles.fill(0.0);
        for r in 0..h {
            let row = &mut self.surface[r * w..(r + 1) * w];
            for (a, &b) in row.iter_mut().zip(&surface[r * w..(r + 1) * w]) {
                let v = if b > 0.0 { b } else { 0.0 };
                *a = if v < t { v } else { t };
            }
            // Tile row ty spans lattice rows 8 ty to 8 ty + 8: a row on a tile boundary
            // belongs to the tiles on both sides.
            let below = (r / TILE < tiles_y).then_some(r / TILE);
            let above = (r % TILE == 0 && r > 0).then(|| r / TILE - 1);
            for tx in 0..tiles_x {
                let cols = tx * TILE..((tx + 1) * TILE).min(w - 1) + 1;
                let m = row[cols].iter().fold(0.0, |m, &v| bigger(m, v));
                for ty in below.into_iter().chain(above) {
                    let tile = &mut self.tiles[ty * tiles_x + tx];
                    *tile = bigger(*tile, m);
                }
            }
        }
        self.tiles.iter().fold(0.0, |m, &v| bigger(m, v))
    }

    /// The largest surface value over the cells that meet the box `u in [u0, u1]`,
    /// `v in [v0, v1]` (pixel coordinates, clamped to the grid): a bound on the surface
    /// there.
    #[inline]
    fn bound(&self, [u0, u1]: [f64; 2], [v0, v1]: [f64; 2]) -> f64 {
        // Truncation is the floor for the non-negative coordinates left by max(0).
        let tile = |a: f64, n: usize, tiles: usize| {
            let cell = (a.max(0.0) as usize).min(n.saturating_sub(2));
            (cell / TILE).min(tiles - 1)
        };
        let (ta, tb) = (
            tile(u0, self.width, self.tiles_x),
            tile(u1, self.width, self.tiles_x),
        );
        let (sa, sb) = (
            tile(v0, self.height, self.tiles_y),
            tile(v1, self.height, self.tiles_y),
        );
        let mut m: f64 = 0.0;
        for ty in sa..=sb {
            for &v in &self.tiles[ty * self.tiles_x + ta..=ty * self.tiles_x + tb] {
                m = m.max(v);
            }
        }
        m
    }

    /// The indentation at which the ray of pixel `(row, col)` meets the loaded surface, no
    /// deeper than `hi`, a bound on the surface along the ray.
    #[inline]
    fn trace(&self, col: usize, row: usize, mut hi: f64) -> f64 {
        let (w, h) = (self.width, self.height);
        let surface = &self.surface;
        let index = row * w + col;
        let [gu, gv] = self.drift[index];
        let (u0, v0) = (col as f64, row as f64);

        // Most rays cross less than a cell above `hi` (the surface is shallow where it is
        // gentle): they stay in the one cell their pixel's centre is a corner of, on the
        // side they drift to, and one solve is all.
        if hi * gu.abs() <= 1.0 && hi * gv.abs() <= 1.0 {
            let corner = |k: usize, g: f64, n: usize| {
                if g > 0.0 {
                    k.saturating_sub(1)
                } else {
                    k.min(n.saturating_sub(2))
                }
            };
            let (ic, jc) = (corner(col, gu, w), corner(row, gv, h));
            if let Some(d) = self.solve_cell(ic, jc, [u0, v0], [gu, gv], 0.0, hi) {
                return d;
            }
        }

        // Walk the lattice's cells from indentation `hi` up to the top face (the camera's
        // ray, coming up through the gel), solving d = h(d) exactly in each: along a line,
        // the bilinear surface of one cell is a quadratic in d. A cell is entered through
        // the side the ray crosses towards d = 0, so on a boundary the cell ahead is taken.
        let cell = |a: f64, g: f64| {
            if g < 0.0 {
                ceil_i(a) - 1
            } else {
                floor_i(a)
            }
        };
        // Metres of indentation per column and per row crossed (infinite if vertical).
        let (pu, pv) = (1.0 / gu, 1.0 / gv);
        let mut i = cell(u0 - hi * gu, gu);
        let mut j = cell(v0 - hi * gv, gv);
        let (step_i, step_j) = (sign(gu), sign(gv));
        // Where the ray leaves cell k (pixel coordinate a0 at d = 0, drift g, pace 1 / g),
        // moving towards d = 0.
        let exit = |k: i64, g: f64, pace: f64, a0: f64| {
            if g > 0.0 {
                (a0 - (k + 1) as f64) * pace
            } else if g < 0.0 {
                (a0 - k as f64) * pace
            } else {
                f64::NEG_INFINITY
            }
        };
        for _ in 0..w + h + 4 {
            let (du, dv) = (exit(i, gu, pu, u0), exit(j, gv, pv, v0));
            let lo = du.max(dv).max(0.0).min(hi);
            let ic = (i.max(0) as usize).min(w.saturating_sub(2));
            let jc = (j.max(0) as usize).min(h.saturating_sub(2));
            if let Some(d) = self.solve_cell(ic, jc, [u0, v0], [gu, gv], lo, hi) {
                return d;
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
        surface[index]
    }
}

impl Refraction {
    /// The largest indentation in `[lo, hi]` at which the ray from pixel coordinates
    /// `p = (u0, v0)` with drift `g` meets the loaded surface inside the lattice cell with
    /// corner `(ic, jc)`; `None` if it does not there. Along a line the cell's bilinear
    /// surface is a quadratic in d, so the answer is exact to rounding.
    #[inline]
    fn solve_cell(
        &self,
        ic: usize,
        jc: usize,
        [u0, v0]: [f64; 2],
        [gu, gv]: [f64; 2],
        lo: f64,
        hi: f64,
    ) -> Option<f64> {
        let (w, h) = (self.width, self.height);
        let surface = &self.surface;
        let (i1, j1) = ((ic + 1).min(w - 1), (jc + 1).min(h - 1));
        let h00 = surface[jc * w + ic];
        let h10 = surface[jc * w + i1];
        let h01 = surface[j1 * w + ic];
        let h11 = surface[j1 * w + i1];
        let (b, c, e) = (h10 - h00, h01 - h00, h11 - h10 - h01 + h00);
        let (fx0, fy0) = (u0 - ic as f64, v0 - jc as f64);
        // h(d) = k0 + k1 d + k2 d^2 with fx = fx0 - d gu, fy = fy0 - d gv; F = d - h.
        let k0 = h00 + b * fx0 + c * fy0 + e * fx0 * fy0;
        let k1 = -(b * gu + c * gv + e * (fx0 * gv + fy0 * gu));
        let k2 = e * gu * gv;
        // Where the cell is gentle along the ray, |h'(d)| <= rho on [-2 hi, 2 hi] with rho
        // small, F = d - h rises all through [lo, hi] and has one root at most: none if
        // F(lo) > 0 (F(hi) >= 0 is given), else the fixed point of d = h(d), which the
        // iteration from h(0) (within rho hi of it) reaches to rho^4 hi: below 1e-12 hi.
        // No division: the common case, cheap.
        let rho = k1.abs() + 4.0 * k2.abs() * hi;
        if rho <= 1e-3 {
            let height = |d: f64| k0 + d * (k1 + k2 * d);
            if lo > height(lo) {
                return None;
            }
            let mut d = k0;
            for _ in 0..3 {
                d = height(d);
            }
            return Some(d.clamp(lo, hi).min(self.thickness));
        }
        largest_root([-k0, 1.0 - k1, -k2], lo, hi).map(|d| d.clamp(0.0, self.thickness))
    }
}

/// The floor of `a` as an integer, without a libm call (out of range: saturated).
#[inline]
fn floor_i(a: f64) -> i64 {
    let t = a as i64;
    if (t as f64) > a {
        t - 1
    } else {
        t
    }
}

/// The ceiling of `a` as an integer, without a libm call (out of range: saturated).
#[inline]
fn ceil_i(a: f64) -> i64 {
    let t = a as i64;
    if (t as f64) < a {
        t + 1
    } else {
        t
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
    // NaN fails the first test and becomes 0.
    let a = if a > 0.0 { a } else { 0.0 };
    let a = if a < top { a } else { top };
    // Truncation is the floor for a >= 0 (and needs no libm call).
    let k = (a as usize).min(n.saturating_sub(2));
    let f = if n > 1 { a - k as f64 } else { 0.0 };
    (k, (k + 1).min(n - 1), f)
}

/// The node nearest continuous coordinate `a` on `n` nodes, clamped.
#[inline]
fn nearest(a: f64, n: usize) -> usize {
    if a.is_finite() {
        // Half up, by truncation of a non-negative number.
        ((a.max(0.0) + 0.5) as usize).min(n - 1)
    } else {
        0
    }
}

/// The largest root in `[lo, hi]` of `F(d) = c0 + c1 d + c2 d^2`, given `F(hi) >= 0` (the
/// ray is in the gel where it enters the cell); `None` when `F > 0` all through.
#[inline]
fn largest_root(c: [f64; 3], lo: f64, hi: f64) -> Option<f64> {
    let f = |d: f64| c[0] + d * (c[1] + d * c[2]);
    let at_hi = f(hi);
    if at_hi <= 0.0 || at_hi.is_nan() {
        // On the surface where the ray enters (or not a number: stop there).
        return Some(hi);
    }
    if f(lo) <= 0.0 {
        // A sign change: a quadratic crosses zero once in between.
        return Some(root_between(c, lo, hi));
    }
    // Positive at both ends: two roots in between or none. Two need a convex F whose
    // vertex lies inside and is not above zero: F' < 0 at lo, F' > 0 at hi, and a real
    // pair of roots (4 c0 c2 <= c1^2); the larger is the one met first coming up.
    let slope = |d: f64| c[1] + 2.0 * c[2] * d;
    let disc = c[1] * c[1] - 4.0 * c[0] * c[2];
    if c[2] > 0.0 && slope(lo) < 0.0 && slope(hi) > 0.0 && disc >= 0.0 {
        let larger = (-c[1] + disc.sqrt()) / (2.0 * c[2]);
        let vertex = -c[1] / (2.0 * c[2]);
        return Some(if larger.is_finite() {
            larger.clamp(vertex.max(lo), hi)
        } else {
            hi
        });
    }
    None
}

/// The one root of the quadratic `c` in `[a, b]`, where `F(a) <= 0 < F(b)`: the closed
/// form (in the form that keeps its precision, the nearer root first), clamped into the
/// bracket; the secant if rounding put it outside.
#[inline]
fn root_between(c: [f64; 3], a: f64, b: f64) -> f64 {
    let slack = 1e-9 * (b - a);
    let inside = |r: f64| r.is_finite() && r >= a - slack && r <= b + slack;
    // Nearly linear (the common case: a short stretch of a gently curved cell): the root
    // near -c0 / c1 is -c0 / c1 times the Catalan series 1 + x + 2 x^2 + 5 x^3 + ... of
    // x = c0 c2 / c1^2; cut after x^3 it errs by 14 x^4 relative (below 1.4e-11 for
    // |x| < 1e-3), without a square root.
    let inv = 1.0 / c[1];
    let x = c[0] * c[2] * inv * inv;
    if x.abs() < 1e-3 {
        let root = -c[0] * inv * (1.0 + x * (1.0 + x * (2.0 + 5.0 * x)));
        if inside(root) {
            return root.clamp(a, b);
        }
    }
    let disc = (c[1] * c[1] - 4.0 * c[0] * c[2]).max(0.0);
    let q = -0.5 * (c[1] + disc.sqrt().copysign(c[1]));
    // c0 / q is the root near -c0 / c1 (the linear one); q / c2 lies beyond it.
    let near = c[0] / q;
    if inside(near) {
        return near.clamp(a, b);
    }
    let far = q / c[2];
    if inside(far) {
        return far.clamp(a, b);
    }
    let f = |d: f64| c[0] + d * (c[1] + d * c[2]);
    let (fa, fb) = (f(a), f(b));
    let t = fa / (fa - fb);
    if t.is_finite() {
        a + (b - a) * t.clamp(0.0, 1.0)
    } else {
        a
    }
}

#[cfg(test)]
mod tests;
