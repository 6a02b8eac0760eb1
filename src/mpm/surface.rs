//! Depth and shear images of the deformed top surface, and its displacement at a point.
//!
//! The top layer of particles is a regular lattice in reference coordinates `X` (spacing
//! `sx`, `sy`). After each solve the gel stores the displacement `u(X)` of the surface
//! point of each top particle, `x_p + (s_z / 2) F e_z - X`. A pixel at `p = (px, py)` sees
//! the surface point whose deformed position lies above it, `X + u_xy(X) = p`, found by
//! Newton's method on `X + u_xy(X) = p`: its first step from `X = p`, whose samples are
//! separable along a row of pixels, is the answer where its error bound (the step squared
//! times the field's second differences around it) is below a nanometre, as far from a
//! contact; elsewhere Newton's method goes on from that step's root, or from the
//! neighbouring pixel's displacement (the fixed point `X <- p - u_xy(X)` where the map is
//! nearly singular); its depth is `-u_z(X)`, clamped to `[0, T]`, and its shear `u_xy(X)`. `u` is
//! interpolated with Catmull-Rom bicubic splines (C1, exact on the lattice), so the images
//! have no holes or speckle. Pixels outside the lattice box where `|u|` exceeds
//! `DEPTH_EPS` (grown by the interpolation stencil and the largest lateral displacement)
//! are zero without work. Rows are mapped in parallel in the gel's thread pool, each from
//! its own start, so the thread count does not change a bit. A point printed on the surface at `X` (a marker) is at
//! `X + u(X)`: one sample, no inverse map.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::Gel;
use crate::geometry::PixelGrid;
use crate::scratch::refill;

/// A lattice box `[ix0, ix1, iy0, iy1)` that holds nothing yet.
pub(super) const EMPTY_BOX: [usize; 4] = [usize::MAX, 0, usize::MAX, 0];

/// Widens the lattice box `b` to hold slot `(ix, iy)`.
pub(super) fn add_to_box(b: &mut [usize; 4], ix: usize, iy: usize) {
    *b = [
        b[0].min(ix),
        b[1].max(ix + 1),
        b[2].min(iy),
        b[3].max(iy + 1),
    ];
}

/// `b`, or `None` if it is still [`EMPTY_BOX`].
pub(super) fn non_empty(b: [usize; 4]) -> Option<[usize; 4]> {
    (b[0] != usize::MAX).then_some(b)
}

/// Surface displacements below this (m) count as "no deformation".
pub(super) const DEPTH_EPS: f64 = 1e-9;

/// Most iterations for `X + u_xy(X) = p` (it stops when a step moves less than
/// [`INVERSE_MAP_STEP`] lattice spacings).
const FIXED_POINT_ITERATIONS: usize = 8;

/// Newton's step (lattice spacings) below which the inverse map stops. The displacement
/// it returns is the last sample moved on by its derivatives, exact to the step squared:
/// against stopping at 1e-9 spacings, the depth images of a 5 mm sphere pressed 0.5 mm
/// differ by 5e-13 m at most, and take 12 to 15 % less time (`image_time`, 320 x 240).
const INVERSE_MAP_STEP: f64 = 1e-4;

/// Catmull-Rom weights of the samples at `-1, 0, 1, 2` for parameter `t` in `[0, 1)`.
#[inline]
fn catmull_rom(t: f64) -> [f64; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    [
        0.5 * (-t + 2.0 * t2 - t3),
        0.5 * (2.0 - 5.0 * t2 + 3.0 * t3),
        0.5 * (t + 4.0 * t2 - 3.0 * t3),
        0.5 * (-t2 + t3),
    ]
}

/// `c.floor()` for a lattice coordinate already clamped to `[0, n - 1]`: truncation, the
/// same value (and the same for NaN: the cast gives 0, as `NaN.floor() as isize` does, and
/// the cell position `c - 0` stays NaN), without the call to libm's `floor` that the
/// baseline x86-64 target makes for every sample.
#[inline]
fn clamped_floor(c: f64) -> f64 {
    (c as i64) as f64
}

/// Bicubic interpolation of the lattice field `u` (row-major, `nx` columns) at lattice
/// coordinates `(a, b)`, clamped at the lattice edges.
pub(super) fn sample(u: &[Vector3<f64>], nx: usize, ny: usize, a: f64, b: f64) -> Vector3<f64> {
    let a = a.clamp(0.0, (nx - 1) as f64);
    let b = b.clamp(0.0, (ny - 1) as f64);
    let (ia, ib) = (clamped_floor(a), clamped_floor(b));
    let (wa, wb) = (catmull_rom(a - ia), catmull_rom(b - ib));
    let (ia, ib) = (ia as isize, ib as isize);
    let mut acc = Vector3::zeros();
    for (j, &wbj) in wb.iter().enumerate() {
        let y = (ib + j as isize - 1).clamp(0, ny as isize - 1) as usize;
        let mut row = Vector3::zeros();
        for (i, &wai) in wa.iter().enumerate() {
            let x = (ia + i as isize - 1).clamp(0, nx as isize - 1) as usize;
            row += u[y * nx + x] * wai;
        }
        acc += row * wbj;
    }
    acc
}

/// Derivatives of the Catmull-Rom weights with respect to `t`.
#[inline]
fn catmull_rom_slope(t: f64) -> [f64; 4] {
    let t2 = t * t;
    [
        0.5 * (-1.0 + 4.0 * t - 3.0 * t2),
        0.5 * (-10.0 * t + 9.0 * t2),
        0.5 * (1.0 + 8.0 * t - 9.0 * t2),
        0.5 * (-2.0 * t + 3.0 * t2),
    ]
}

/// [`sample`] and its derivatives along `a` and `b` (zero along an axis where the point
/// is clamped to the lattice edge).
fn sample_with_slope(
    u: &[Vector3<f64>],
    nx: usize,
    ny: usize,
    a: f64,
    b: f64,
) -> [Vector3<f64>; 3] {
    let inside_a = (0.0..=(nx - 1) as f64).contains(&a);
    let inside_b = (0.0..=(ny - 1) as f64).contains(&b);
    let a = a.clamp(0.0, (nx - 1) as f64);
    let b = b.clamp(0.0, (ny - 1) as f64);
    let (ia, ib) = (clamped_floor(a), clamped_floor(b));
    let (wa, wb) = (catmull_rom(a - ia), catmull_rom(b - ib));
    let (sa, sb) = (catmull_rom_slope(a - ia), catmull_rom_slope(b - ib));
    let (ia, ib) = (ia as isize, ib as isize);
    let mut acc = [Vector3::zeros(); 3];
    // Away from the lattice's edges no tap is clamped: the same sums, read from four
    // contiguous runs of the field.
    let interior = |i: isize, n: usize| i >= 1 && i + 2 < n as isize;
    if interior(ia, nx) && interior(ib, ny) {
        for j in 0..4 {
            let start = (ib + j as isize - 1) as usize * nx + ia as usize - 1;
            let run = &u[start..start + 4];
            let (mut row, mut row_a) = (Vector3::zeros(), Vector3::zeros());
            for i in 0..4 {
                row += run[i] * wa[i];
                row_a += run[i] * sa[i];
            }
            acc[0] += row * wb[j];
            acc[1] += row_a * wb[j];
            acc[2] += row * sb[j];
        }
        return acc;
    }
    for j in 0..4 {
        let y = (ib + j as isize - 1).clamp(0, ny as isize - 1) as usize;
        let (mut row, mut row_a) = (Vector3::zeros(), Vector3::zeros());
        for i in 0..4 {
            let x = (ia + i as isize - 1).clamp(0, nx as isize - 1) as usize;
            row += u[y * nx + x] * wa[i];
            row_a += u[y * nx + x] * sa[i];
        }
        acc[0] += row * wb[j];
        acc[1] += row_a * wb[j];
        acc[2] += row * sb[j];
    }
    if !inside_a {
        acc[1] = Vector3::zeros();
    }
    if !inside_b {
        acc[2] = Vector3::zeros();
    }
    acc
}

/// Calls `visit(pixel, u)` for each pixel of `grid` (row-major index) that may see the
/// deformed surface, with the displacement `u(X)` of the surface point `X` above it,
/// `X + u_xy(X) = p`; the pixels not visited see the undeformed surface (`|u|` below
/// [`DEPTH_EPS`]). The one inverse map behind the depth and the shear images.
fn for_each_seen(gel: &Gel, grid: &PixelGrid, visit: impl FnMut(usize, Vector3<f64>)) {
    seen_with(gel, grid, true, &[Part::all(grid)], visit)
}

/// Pixels of a grid wanted from an image: the rows and columns in `rows` and `cols`, every
/// `step` from each range's start.
#[derive(Clone, Debug, PartialEq)]
pub struct Part {
    /// Rows, from the first.
    pub rows: std::ops::Range<usize>,
    /// Columns, from the first.
    pub cols: std::ops::Range<usize>,
    /// Rows and columns between two taken (at least 1).
    pub step: usize,
}

impl Part {
    /// Every pixel of `grid`.
    pub fn all(grid: &PixelGrid) -> Part {
        Part {
            rows: 0..grid.height,
            cols: 0..grid.width,
            step: 1,
        }
    }

    /// This part's indices of `range` (of rows or columns, within `within`) into `out`.
    fn taken(
        within: &std::ops::Range<usize>,
        range: std::ops::Range<usize>,
        step: usize,
        out: &mut Vec<usize>,
    ) {
        let step = step.max(1);
        let lo = range.start.max(within.start);
        // The first taken index at or after `lo`.
        let first = within.start + (lo - within.start).div_ceil(step) * step;
        out.clear();
        out.extend((first..range.end.min(within.end)).step_by(step));
    }
}

/// Where one Newton step of the inverse map, started at the pixel itself, is accurate to
/// this (m), it is the answer: its error is at most about the step squared times the
/// field's second derivatives around the pixel ([`Curvature`]). Far from a contact the
/// surface moves sideways by microns and bends slowly, so one separable sample per pixel
/// suffices there; nearer, Newton's method goes on from that step's root to
/// [`INVERSE_MAP_STEP`]. A fraction of the gel's thickness ([`one_step_error`]), so that
/// the map's choices scale with the gel as its solve does (a model reads a gel of its
/// shape at any thickness in its own units): a tenth of a micron on the default 4 mm gel,
/// about a thirty-sixth of the most accurate mode's depth error against the reference
/// (3.6 um on the full profile); there the one-step pixels differ from the solved map by
/// at most 41 nm in the test below. What it costs and saves: `docs/solvers.md`, "The
/// depth image: one separable sample where it suffices".
pub const ONE_STEP_FRACTION: f64 = 2.5e-5;

/// [`ONE_STEP_FRACTION`] of `gel`'s thickness (m).
pub(super) fn one_step_error(gel: &Gel) -> f64 {
    ONE_STEP_FRACTION * gel.params.size[2]
}

/// [`for_each_seen`], with `one_step` whether pixels whose first Newton step is accurate
/// to [`one_step_error`] stop there (see [`ONE_STEP_FRACTION`]); `false` solves every pixel
/// to [`INVERSE_MAP_STEP`].
///
/// The first step starts at the pixel itself, so its samples are separable: per row of
/// pixels the field's rows are combined once by the row's vertical weights, and each
/// pixel then takes 4 + 4 taps of those instead of 16 of the field.
fn seen_with(
    gel: &Gel,
    grid: &PixelGrid,
    one_step: bool,
    parts: &[Part],
    mut visit: impl FnMut(usize, Vector3<f64>),
) {
    let Some([ix0, ix1, iy0, iy1]) = gel.surface_box else {
        return;
    };
    let [nx, ny, _] = gel.layout.lattice;
    let [sx, sy, _] = gel.layout.spacing;
    let (x0, y0) = lattice_origin(gel);
    // Lateral reach of the deformation: the box of moved lattice points, grown by the
    // bicubic stencil (2 spacings) and the largest lateral displacement.
    let umax = gel
        .surface_u
        .iter()
        .fold(0.0f64, |m, u| m.max(u.x.abs()).max(u.y.abs()));
    let xa = x0 + (ix0 as f64 - 2.0) * sx - umax;
    let xb = x0 + (ix1 as f64 + 1.0) * sx + umax;
    let ya = y0 + (iy0 as f64 - 2.0) * sy - umax;
    let yb = y0 + (iy1 as f64 + 1.0) * sy + umax;
    let u = &gel.surface_u;
    let limit = one_step_error(gel);
    // The buffers of the gel's last image, refilled.
    let mut kept = gel.pixels.take();
    let Pixels {
        seen,
        columns,
        cells,
        along,
        rows,
        cols,
    } = &mut kept;
    let mut curvature = None;
    for part in parts {
        Part::taken(&part.rows, grid.rows_in(ya, yb), part.step, rows);
        Part::taken(&part.cols, grid.cols_in(xa, xb), part.step, cols);
        if cols.is_empty() || rows.is_empty() {
            continue;
        }
        columns.clear();
        columns.extend(
            cols.iter()
                .map(|&col| Taps::at((grid.x(col) - x0) / sx, nx)),
        );
        // (Once for all the parts.)
        if one_step && curvature.is_none() {
            curvature = Some(Curvature::of(u, nx, ny, std::mem::take(cells), along));
        }
        let curvature = curvature.as_ref();
        // Rows in parallel in the gel's pool (each row starts afresh, so the threads do not
        // change a bit), then visited in order.
        // Every pixel is written before it is read (a row's guesses read its pixels before
        // them, written this image): the last image's values stay where the length does.
        seen.resize(rows.len() * cols.len(), Vector3::zeros());
        let (rows, cols, columns) = (&*rows, &*cols, &*columns);
        gel.pool.install(|| {
            seen.par_chunks_mut(cols.len())
                .zip(rows.par_iter())
                .for_each(|(line, &row)| {
                    // The row's field mixed by its vertical taps, in this thread's buffer.
                    MIXED.with_borrow_mut(|mixed| {
                        if mixed.len() != nx {
                            refill(mixed, nx, [Vector3::zeros(); 2]);
                        }
                        let pb = (grid.y(row) - y0) / sy;
                        let vertical = Taps::at(pb, ny);
                        if curvature.is_some() {
                            vertical.mix_rows(u, nx, mixed);
                        }
                        for (k, (&col, horizontal)) in cols.iter().zip(columns).enumerate() {
                            let pa = || (grid.x(col) - x0) / sx;
                            let first = curvature.and_then(|c| {
                                one_newton_step(mixed, horizontal, &vertical, sx, sy, c, limit)
                            });
                            line[k] = match first {
                                Some((d, true)) => d,
                                // Newton's method goes on from the first step's root.
                                Some((d, false)) => {
                                    solve_inverse_map(u, nx, ny, pa(), pb, sx, sy, &d)
                                }
                                // From the last finite displacement of the row's pixels
                                // before it: the next pixel's surface point is displaced
                                // nearly as much, so Newton's method starts close to it.
                                None => {
                                    let guess = line[..k]
                                        .iter()
                                        .rev()
                                        .find(|d| d.iter().all(|v| v.is_finite()))
                                        .copied()
                                        .unwrap_or_else(Vector3::zeros);
                                    solve_inverse_map(u, nx, ny, pa(), pb, sx, sy, &guess)
                                }
                            };
                        }
                    })
                })
        });
        for (line, &row) in seen.chunks_exact(cols.len()).zip(rows) {
            for (d, &col) in line.iter().zip(cols) {
                visit(row * grid.width + col, *d);
            }
        }
    }
    if let Some(c) = curvature {
        *cells = c.cells;
    }
    gel.pixels.put(kept);
}

thread_local! {
    /// A row's field mixed by its vertical taps ([`Taps::mix_rows`]), one per thread of
    /// [`seen_with`]'s pool, kept between images.
    static MIXED: std::cell::RefCell<Vec<[Vector3<f64>; 2]>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The buffers of [`seen_with`], kept with the gel between images
/// ([`crate::scratch::Kept`]): the pixels' displacements, the image columns' taps and
/// [`Curvature`]'s two fields, and the image's rows and columns mapped.
#[derive(Default)]
pub(super) struct Pixels {
    seen: Vec<Vector3<f64>>,
    columns: Vec<Taps>,
    cells: Vec<f64>,
    along: Vec<f64>,
    rows: Vec<usize>,
    cols: Vec<usize>,
}

/// The Catmull-Rom taps of one lattice coordinate: the four samples (clamped at the
/// lattice's edges), their weights and the weights' slopes (zero outside the lattice, as
/// [`sample_with_slope`]), and the cell.
struct Taps {
    index: [usize; 4],
    weight: [f64; 4],
    slope: [f64; 4],
    cell: usize,
}

impl Taps {
    fn at(p: f64, n: usize) -> Taps {
        let inside = (0.0..=(n - 1) as f64).contains(&p);
        let c = p.clamp(0.0, (n - 1) as f64);
        let i = clamped_floor(c);
        let t = c - i;
        let i = i as isize;
        Taps {
            index: std::array::from_fn(|k| (i + k as isize - 1).clamp(0, n as isize - 1) as usize),
            weight: catmull_rom(t),
            slope: if inside {
                catmull_rom_slope(t)
            } else {
                [0.0; 4]
            },
            cell: (i as usize).min(n.saturating_sub(2)),
        }
    }

    /// Per lattice column, the field's rows combined by these (vertical) taps: the value
    /// and its slope along the rows.
    fn mix_rows(&self, u: &[Vector3<f64>], nx: usize, out: &mut [[Vector3<f64>; 2]]) {
        for (x, o) in out.iter_mut().enumerate() {
            let mut v = [Vector3::zeros(); 2];
            for k in 0..4 {
                let s = u[self.index[k] * nx + x];
                v[0] += s * self.weight[k];
                v[1] += s * self.slope[k];
            }
            *o = v;
        }
    }
}

/// The largest second difference of the field (m per spacing squared: along each axis
/// and mixed, over the three components) around each lattice cell, over the cell's 4 x 4
/// stencil: a bound, up to a small factor, on the bicubic's second derivatives there.
struct Curvature {
    nx: usize,
    cells: Vec<f64>,
}

impl Curvature {
    /// The bound of field `u`, in `cells` (its allocation reused) with `along` for the
    /// rows' maxima.
    fn of(
        u: &[Vector3<f64>],
        nx: usize,
        ny: usize,
        mut cells: Vec<f64>,
        along: &mut Vec<f64>,
    ) -> Curvature {
        let at = |x: isize, y: isize| {
            u[(y.clamp(0, ny as isize - 1) as usize) * nx + x.clamp(0, nx as isize - 1) as usize]
        };
        // Per node: its largest second difference (in `cells`, which the cells' maxima
        // overwrite once the rows' maxima no longer need it).
        let node = &mut cells;
        node.clear();
        for y in 0..ny as isize {
            node.extend((0..nx as isize).map(|x| {
                let c = at(x, y);
                let xx = at(x - 1, y) - c * 2.0 + at(x + 1, y);
                let yy = at(x, y - 1) - c * 2.0 + at(x, y + 1);
                let xy = (at(x + 1, y + 1) - at(x + 1, y - 1) - at(x - 1, y + 1)
                    + at(x - 1, y - 1))
                    * 0.25;
                xx.amax().max(yy.amax()).max(xy.amax())
            }));
        }
        // The largest over each cell's 4 x 4 stencil (offsets -1 to 2, clamped at the
        // edges), along the rows and then down the columns: the same maxima.
        let clamp = |k: isize, n: usize| k.clamp(0, n as isize - 1) as usize;
        let stencil_max = |at: &dyn Fn(usize) -> f64, k: usize, n: usize| {
            (-1..=2).fold(0.0f64, |m, o| m.max(at(clamp(k as isize + o, n))))
        };
        // (Every entry written below before it is read.)
        along.resize(nx * ny, 0.0);
        for y in 0..ny {
            let line = &node[y * nx..(y + 1) * nx];
            for x in 0..nx {
                along[y * nx + x] = stencil_max(&|i| line[i], x, nx);
            }
        }
        for y in 0..ny {
            for x in 0..nx {
                cells[y * nx + x] = stencil_max(&|j| along[j * nx + x], y, ny);
            }
        }
        Curvature { nx, cells }
    }

    fn around(&self, a: &Taps, b: &Taps) -> f64 {
        self.cells[b.cell * self.nx + a.cell]
    }
}

/// The inverse map's first Newton step from the pixel itself, from the row's mixed field
/// (`mixed`, [`Taps::mix_rows`]) and the pixel's column taps: the displacement at its
/// root, the sample moved on by its derivatives, and whether that is accurate to
/// `limit` (m, [`one_step_error`]; `None` where the step is not Newton's).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn one_newton_step(
    mixed: &[[Vector3<f64>; 2]],
    a: &Taps,
    b: &Taps,
    sx: f64,
    sy: f64,
    curvature: &Curvature,
    limit: f64,
) -> Option<(Vector3<f64>, bool)> {
    let (mut d, mut da, mut db) = (Vector3::zeros(), Vector3::zeros(), Vector3::zeros());
    for k in 0..4 {
        let [v, vb] = mixed[a.index[k]];
        d += v * a.weight[k];
        da += v * a.slope[k];
        db += vb * a.weight[k];
    }
    // Started at the pixel: the residual of `X + u_xy(X) / s = p` is `u_xy / s`.
    let (ga, gb) = (d.x / sx, d.y / sy);
    let (j11, j12, j21, j22) = (1.0 + da.x / sx, db.x / sx, da.y / sy, 1.0 + db.y / sy);
    let det = j11 * j22 - j12 * j21;
    if !(det > 0.1 && det.is_finite()) {
        return None;
    }
    let (step_a, step_b) = ((j22 * ga - j12 * gb) / det, (j11 * gb - j21 * ga) / det);
    let step = step_a.abs() + step_b.abs();
    // The first-order move's error and the root's, each at most about the step squared
    // times the second derivatives (a factor 2 for the bicubic's own over the lattice's
    // second differences).
    if !step.is_finite() {
        return None;
    }
    let bound = 2.0 * step * step * curvature.around(a, b);
    Some((d - da * step_a - db * step_b, bound <= limit))
}

/// The lattice coordinates `X` of the surface point seen at lattice coordinates `(pa, pb)`:
/// the root of `X + u_xy(X) / s = p`, by Newton's method from `p - guess_xy / s` (the
/// Jacobian `I + grad u_xy / s` from the bicubic's derivatives), falling back to the
/// fixed point `X <- p - u_xy(X) / s` (a contraction while `|grad u_xy| < 1`) where the
/// Jacobian is nearly singular. Stops when a Newton step moves less than
/// [`INVERSE_MAP_STEP`] spacings (a fixed-point step: 1e-9). Returns the displacement `u(X)`: after a converged Newton step, the last
/// sample moved on by its derivatives (exact to the step squared).
#[allow(clippy::too_many_arguments)]
fn solve_inverse_map(
    u: &[Vector3<f64>],
    nx: usize,
    ny: usize,
    pa: f64,
    pb: f64,
    sx: f64,
    sy: f64,
    guess: &Vector3<f64>,
) -> Vector3<f64> {
    let (mut a, mut b) = (pa - guess.x / sx, pb - guess.y / sy);
    for _ in 0..FIXED_POINT_ITERATIONS {
        let [d, da, db] = sample_with_slope(u, nx, ny, a, b);
        let (ga, gb) = (a + d.x / sx - pa, b + d.y / sy - pb);
        let (j11, j12, j21, j22) = (1.0 + da.x / sx, db.x / sx, da.y / sy, 1.0 + db.y / sy);
        let det = j11 * j22 - j12 * j21;
        let newton = det > 0.1 && det.is_finite();
        let (step_a, step_b) = if newton {
            ((j22 * ga - j12 * gb) / det, (j11 * gb - j21 * ga) / det)
        } else {
            (ga, gb)
        };
        if !(step_a.is_finite() && step_b.is_finite()) {
            return sample(u, nx, ny, pa, pb);
        }
        a -= step_a;
        b -= step_b;
        // A fixed-point step converges only linearly: it stops at the strict tolerance.
        let stop = if newton { INVERSE_MAP_STEP } else { 1e-9 };
        if step_a.abs() + step_b.abs() < stop {
            return d - da * step_a - db * step_b;
        }
    }
    sample(u, nx, ny, a, b)
}

/// Reference x and y (m) of lattice column 0 and row 0 of the top surface.
fn lattice_origin(gel: &Gel) -> (f64, f64) {
    let [sx, sy, _] = gel.layout.spacing;
    let [lx, ly, _] = gel.params.size;
    (-0.5 * lx + 0.5 * sx, -0.5 * ly + 0.5 * sy)
}

/// The first `per_pixel` values per pixel of `out`, zeroed; panics naming `what` if `out`
/// is too short.
fn image<'a>(out: &'a mut [f64], grid: &PixelGrid, per_pixel: usize, what: &str) -> &'a mut [f64] {
    let n = grid.width * grid.height * per_pixel;
    assert!(
        out.len() >= n,
        "{what} buffer holds {} values, the grid needs {n}",
        out.len()
    );
    let out = &mut out[..n];
    out.fill(0.0);
    out
}

/// The depth pixel of a surface point displaced by `d` in a gel of thickness `t`.
#[inline]
fn depth_of(d: &Vector3<f64>, t: f64) -> f64 {
    let depth = -d.z;
    if depth.is_finite() {
        depth.clamp(0.0, t)
    } else {
        0.0
    }
}

/// Stores the shear pixel `pixel` of a surface point displaced by `d` (zero if not finite).
#[inline]
fn set_shear(out: &mut [f64], pixel: usize, d: &Vector3<f64>) {
    if d.x.is_finite() && d.y.is_finite() {
        out[2 * pixel] = d.x;
        out[2 * pixel + 1] = d.y;
    }
}

/// See [`Gel::surface_depth`].
pub(super) fn surface_depth(gel: &Gel, grid: &PixelGrid, out: &mut [f64]) {
    let out = image(out, grid, 1, "depth");
    let t = gel.params.size[2];
    for_each_seen(gel, grid, |pixel, d| out[pixel] = depth_of(&d, t));
}

/// See [`Gel::surface_depth_parts`].
pub(super) fn surface_depth_parts(gel: &Gel, grid: &PixelGrid, parts: &[Part], out: &mut [f64]) {
    let out = image(out, grid, 1, "depth");
    let t = gel.params.size[2];
    seen_with(gel, grid, true, parts, |pixel, d| {
        out[pixel] = depth_of(&d, t)
    });
}

/// See [`Gel::surface_shear`].
pub(super) fn surface_shear(gel: &Gel, grid: &PixelGrid, out: &mut [f64]) {
    let out = image(out, grid, 2, "shear");
    for_each_seen(gel, grid, |pixel, d| set_shear(out, pixel, &d));
}

/// See [`Gel::surface_depth_and_shear`].
pub(super) fn surface_depth_and_shear(
    gel: &Gel,
    grid: &PixelGrid,
    depth: &mut [f64],
    shear: &mut [f64],
) {
    let depth = image(depth, grid, 1, "depth");
    let shear = image(shear, grid, 2, "shear");
    let t = gel.params.size[2];
    for_each_seen(gel, grid, |pixel, d| {
        depth[pixel] = depth_of(&d, t);
        set_shear(shear, pixel, &d);
    });
}

/// See [`Gel::surface_displacement`].
pub(super) fn surface_displacement(gel: &Gel, x: f64, y: f64) -> Vector3<f64> {
    if gel.surface_box.is_none() {
        return Vector3::zeros();
    }
    let [nx, ny, _] = gel.layout.lattice;
    let [sx, sy, _] = gel.layout.spacing;
    let (x0, y0) = lattice_origin(gel);
    let d = sample(&gel.surface_u, nx, ny, (x - x0) / sx, (y - y0) / sy);
    if d.iter().all(|v| v.is_finite()) {
        d
    } else {
        Vector3::zeros()
    }
}

impl Gel {
    /// Recomputes the top-surface displacement field from the particles and the box where
    /// it is non-zero.
    pub(super) fn update_surface(&mut self) {
        let dx = self.layout.dx;
        let moved: Vec<Vector3<f64>> = (0..self.top.len())
            .map(|slot| {
                let p = &self.particles[self.top[slot] as usize];
                let s = p.x + p.f.column(2) * self.half_top;
                (s - self.top_ref[slot]).cast::<f64>() * dx
            })
            .collect();
        self.set_surface(|slot| moved[slot]);
    }

    /// Sets the top-surface displacement of each slot (m; non-finite values count as
    /// zero) and the box where it is non-zero.
    pub(super) fn set_surface(&mut self, displacement: impl Fn(usize) -> Vector3<f64>) {
        let [nxp, nyp, _] = self.layout.lattice;
        let mut bx = EMPTY_BOX;
        for (slot, u) in self.surface_u.iter_mut().enumerate() {
            let d = displacement(slot);
            *u = if d.iter().all(|v| v.is_finite()) {
                d
            } else {
                Vector3::zeros()
            };
            if u.amax() > DEPTH_EPS {
                add_to_box(&mut bx, slot % nxp, slot / nxp);
            }
        }
        self.surface_box = non_empty(bx);
        debug_assert!(bx[1] <= nxp && bx[3] <= nyp || bx[0] == usize::MAX);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Placed, Sdf, Sphere};
    use crate::mpm::{GelParams, Solver, SolverOptions};
    use nalgebra::Isometry3;
    use std::sync::Arc;

    /// Each pixel's displacement, every pixel solved to the inverse map's step (`exact`)
    /// or with the one-step pixels of [`seen_with`].
    fn seen(gel: &Gel, grid: &PixelGrid, one_step: bool) -> Vec<Vector3<f64>> {
        let mut out = vec![Vector3::zeros(); grid.width * grid.height];
        seen_with(gel, grid, one_step, &[Part::all(grid)], |p, d| out[p] = d);
        out
    }

    /// A 5 mm sphere pressed `depth` at the centre and slid 0.5 mm along x (friction 0.5).
    fn slid(solver: Solver, depth: f64) -> Gel {
        let mut gel = Gel::new(
            GelParams::default(),
            SolverOptions {
                solver,
                ..Default::default()
            },
        )
        .unwrap();
        let ball: Arc<dyn Sdf> = Arc::new(Sphere::new(5e-3));
        for k in 0..=5 {
            gel.solve(&[Placed {
                shape: ball.clone(),
                pose: Isometry3::translation(1e-4 * k as f64, 0.0, 5e-3 - depth),
            }]);
        }
        gel
    }

    /// The pixels that stop after one Newton step agree with the inverse map solved to its
    /// step everywhere within their bound, [`one_step_error`] (the solved map itself is
    /// exact to about 1e-13 m), on the linear and the relaxed
    /// gel, pressed 0.2 and 1 mm and slid 0.5 mm, at pixel sizes from 0.03 to 0.3 mm.
    #[test]
    fn one_step_pixels_agree_with_the_solved_inverse_map() {
        for solver in [Solver::Linear, Solver::Relaxation] {
            for depth in [0.2e-3, 1.0e-3] {
                let gel = slid(solver, depth);
                for pixel in [0.03e-3, 0.1e-3, 0.3e-3] {
                    let grid = PixelGrid {
                        width: (0.024 / pixel) as usize,
                        height: (0.018 / pixel) as usize,
                        fov_x: 0.024,
                        fov_y: 0.018,
                    };
                    let (fast, exact) = (seen(&gel, &grid, true), seen(&gel, &grid, false));
                    let worst = fast
                        .iter()
                        .zip(&exact)
                        .map(|(a, b)| (a - b).amax())
                        .fold(0.0f64, f64::max);
                    let peak = exact.iter().map(|d| d.amax()).fold(0.0f64, f64::max);
                    assert!(peak > 0.5 * depth, "{solver:?} {depth}: peak {peak}");
                    assert!(
                        worst <= one_step_error(&gel),
                        "{solver:?} {depth} {pixel}: worst {worst}"
                    );
                }
            }
        }
    }

    /// An image mapped at parts of its grid (overlapping, strided, empty, beyond the grid)
    /// holds the whole image's depth at each pixel of a part, bit for bit, and zero at the
    /// others; the parts' indices are those each range starts its steps from.
    #[test]
    fn an_image_in_parts_is_the_whole_one_where_mapped() {
        let gel = slid(Solver::Linear, 0.8e-3);
        let grid = PixelGrid {
            width: 100,
            height: 100,
            fov_x: 0.03,
            fov_y: 0.03,
        };
        let n = grid.width * grid.height;
        let mut whole = vec![0.0; n];
        gel.surface_depth(&grid, &mut whole);
        let part = |rows: std::ops::Range<usize>, cols: std::ops::Range<usize>, step| Part {
            rows,
            cols,
            step,
        };
        let sets = [
            vec![part(20..70, 10..90, 1)],
            vec![part(2..100, 2..100, 4)],
            vec![
                part(30..60, 30..60, 1),
                part(2..100, 2..100, 4),
                part(45..200, 0..7, 3),
            ],
            vec![part(50..50, 0..100, 1), part(0..100, 99..100, 1)],
        ];
        for parts in &sets {
            let mut out = vec![f64::NAN; n];
            gel.surface_depth_parts(&grid, parts, &mut out);
            for row in 0..grid.height {
                for col in 0..grid.width {
                    let i = row * grid.width + col;
                    let taken = parts.iter().any(|p| {
                        let on = |r: &std::ops::Range<usize>, k: usize| {
                            r.contains(&k) && (k - r.start) % p.step == 0
                        };
                        on(&p.rows, row) && on(&p.cols, col)
                    });
                    let want = if taken { whole[i] } else { 0.0 };
                    assert_eq!(
                        out[i].to_bits(),
                        want.to_bits(),
                        "{parts:?}: pixel ({row}, {col})"
                    );
                }
            }
            assert!(
                out.iter().any(|&d| d > 0.0),
                "{parts:?}: a part sees the press"
            );
        }
    }
}
