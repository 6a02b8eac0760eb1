//! The samples of the ball presses and the table fitted to them.
//!
//! **Samples.** Inside a press's contact circle, at least `edge_margin` pixels from its
//! edge (where the gel leaves the ball, and where the sensor's central differences would
//! straddle the edge), each pixel gives the cap's analytic gradient there and the colour
//! change of the image against the background.
//!
//! **Fit.** The table holds the colour change at `n x n` nodes evenly over `[-G, G]^2`;
//! the sensor interpolates it bilinearly. The fit chooses the node values whose bilinear
//! interpolation best matches the samples in the least-squares sense, plus a light
//! curvature penalty (the thin-plate energy of the table, second differences along gx, gy
//! and mixed, weighted by `smooth` times the mean data weight of a node). The penalty
//! fills the nodes no sample reaches (smoothly continuing the fitted surface) and damps
//! the noise of sparse nodes; where samples are dense it leaves the fit to them. It is the
//! "average per bin, fill the empty bins, smooth lightly" of Taxim's table as one
//! well-posed problem, whose error for a smooth colour response is that of bilinear
//! interpolation, `h^2 / 8` times the response's second derivative (`h` the bin width),
//! not a bin average's `h / 2` times its first. The node at zero slope (there is one: `n`
//! is odd) is held at zero: a flat surface shows the background by definition. The normal
//! equations are solved by faer's conjugate gradients with a Jacobi preconditioner, per
//! channel.

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::matrix_free::conjugate_gradient::{
    conjugate_gradient, conjugate_gradient_scratch, CgParams,
};
use faer::matrix_free::{InitialGuessStatus, LinOp, Precond};
use faer::{MatMut, MatRef, Par};
use serde::Serialize;
use tacrom::geometry::PixelGrid;
use tacrom::render::calibrated::{GradientTable, RgbImage, MAX_BINS};
use tacrom::render::rgb::{CHANNELS, FULL_SCALE};

use super::{Contact, Press};

/// One sample: a surface gradient and the colour change seen there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// `(gx, gy)`, slopes of the indentation depth.
    pub gradient: [f64; 2],
    /// Colour minus background per channel (grey levels).
    pub change: [f64; 3],
}

/// The indentation gradient of a ball of radius `radius` at `(x, y)` (m) from the centre
/// of its contact, inside the ball's footprint: `-(x, y) / sqrt(R^2 - x^2 - y^2)`.
#[inline]
pub fn ball_gradient(x: f64, y: f64, radius: f64) -> Option<[f64; 2]> {
    let h2 = radius * radius - x * x - y * y;
    (h2 > 0.0).then(|| {
        let inv = 1.0 / h2.sqrt();
        [-x * inv, -y * inv]
    })
}

/// The sensor-frame offset `(x, y)` (m) of the centre of pixel `(row, col)` from the
/// contact centre, for pixels of `pixel` metres: x towards higher columns, y towards lower
/// rows.
#[inline]
pub fn offset(contact: &Contact, row: usize, col: usize, pixel: f64) -> (f64, f64) {
    (
        (col as f64 - contact.centre[0]) * pixel,
        (contact.centre[1] - row as f64) * pixel,
    )
}

/// The indentation depth image (m) of a ball of radius `radius` pressed to the contact
/// `contact` on `grid`: the cap `sqrt(R^2 - rho^2) - sqrt(R^2 - a^2)` inside the contact,
/// zero outside (the rigid ball's penetration of the undeformed gel).
pub fn ball_depth(grid: &PixelGrid, radius: f64, contact: &Contact) -> Vec<f64> {
    let pixel = grid.fov_x / grid.width as f64;
    let a = contact.radius * pixel;
    let rim = (radius * radius - a * a).max(0.0).sqrt();
    let mut depth = Vec::with_capacity(grid.width * grid.height);
    for r in 0..grid.height {
        for c in 0..grid.width {
            let (x, y) = offset(contact, r, c, pixel);
            let h2 = radius * radius - x * x - y * y;
            depth.push(if h2 > 0.0 {
                (h2.sqrt() - rim).max(0.0)
            } else {
                0.0
            });
        }
    }
    depth
}

/// Appends the samples of `press` over `background` to `out`: the pixels at least
/// `edge_margin` pixels inside its contact edge.
pub fn press_samples(
    background: &RgbImage,
    press: &Press,
    edge_margin: f64,
    out: &mut Vec<Sample>,
) {
    let c = &press.contact;
    let limit = c.radius - edge_margin;
    if limit < 0.0 {
        return;
    }
    let (w, h) = (press.image.width, press.image.height);
    let rows = (c.centre[1] - limit).floor().max(0.0) as usize
        ..((c.centre[1] + limit).ceil() + 1.0).clamp(0.0, h as f64) as usize;
    for r in rows {
        for col in 0..w {
            if c.distance(r, col) > limit {
                continue;
            }
            let (x, y) = offset(c, r, col, press.pixel_size);
            let Some(gradient) = ball_gradient(x, y, press.ball_radius) else {
                continue;
            };
            let (img, bg) = (press.image.pixel(r, col), background.pixel(r, col));
            out.push(Sample {
                gradient,
                change: [0, 1, 2].map(|k| img[k] - bg[k]),
            });
        }
    }
}

/// Appends the samples a simulated surface gives: each pixel of `mask` (away from the
/// image's border) gives the gradient of the depth image `depth` (m, `press`'s grid) by
/// central differences, as the sensor's renderer takes it, and the colour change of
/// `press`'s image against `background` there. Where the simulated gel matches the real
/// one, these extend the contact's samples to the imprint around it.
pub fn surface_samples(
    background: &RgbImage,
    press: &Press,
    depth: &[f64],
    mask: &[bool],
    out: &mut Vec<Sample>,
) {
    let (w, h) = (press.image.width, press.image.height);
    let step = 0.5 / press.pixel_size;
    for r in 1..h.saturating_sub(1) {
        for c in 1..w.saturating_sub(1) {
            let i = r * w + c;
            if !mask[i] {
                continue;
            }
            // Row r - 1 is towards +y.
            let gradient = [
                (depth[i + 1] - depth[i - 1]) * step,
                (depth[i - w] - depth[i + w]) * step,
            ];
            let (img, bg) = (press.image.pixel(r, c), background.pixel(r, c));
            out.push(Sample {
                gradient,
                change: [0, 1, 2].map(|k| img[k] - bg[k]),
            });
        }
    }
}

/// How to fit the table.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FitOptions {
    /// Nodes along each axis (odd, at least 3).
    pub bins: usize,
    /// Half range `G` of the table's slopes; `None`: the largest `|gx|` or `|gy|` among the
    /// samples.
    pub range: Option<f64>,
    /// Weight of the curvature penalty relative to a node's mean data weight (positive).
    pub smooth: f64,
}

impl Default for FitOptions {
    /// 41 nodes per axis, the samples' own range, smoothing 0.05. Measured on the 24
    /// synthetic presses of 320 x 240 pixels (held-out contact MAE against the built-in
    /// optics through the sensor, and its worst pixel, grey levels): 21 / 41 / 61 / 81
    /// nodes 0.039 / 0.043 / 0.058 / 0.078, worst 1.59 / 0.93 / 0.58 / 0.56 (coarser
    /// bins smooth the 8-bit noise of the samples, finer ones follow the response's kinks);
    /// smoothing 0.01 / 0.05 / 0.2 / 1 gives 0.052 / 0.043 / 0.034 / 0.029, worst 0.80 /
    /// 0.93 / 1.18 / 1.71.
    fn default() -> Self {
        FitOptions {
            bins: 41,
            range: None,
            smooth: 0.05,
        }
    }
}

/// What the fit did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct FitReport {
    /// Nodes along each axis.
    pub bins: usize,
    /// Half range of the slopes.
    pub range: f64,
    /// Samples fitted.
    pub samples: usize,
    /// Fraction of the nodes that some sample weighs on.
    pub nodes_with_data: f64,
    /// The curvature penalty's weight option.
    pub smooth: f64,
    /// Root-mean-square difference of the fitted table from the samples (grey levels, all
    /// channels).
    pub rms_residual: f64,
    /// Conjugate-gradient iterations, the most of the three channels.
    pub iterations: usize,
}

/// The bilinear weights of a gradient on the node grid: the four nodes around it (flat
/// indices) and their weights.
fn weights(g: [f64; 2], n: usize, range: f64) -> ([usize; 4], [f64; 4]) {
    let scale = (n - 1) as f64 / (2.0 * range);
    let locate = |v: f64| {
        let u = ((v + range) * scale).clamp(0.0, (n - 1) as f64);
        let i0 = (u as usize).min(n - 2);
        (i0, u - i0 as f64)
    };
    let (i, fx) = locate(g[0]);
    let (j, fy) = locate(g[1]);
    let at = j * n + i;
    (
        [at, at + 1, at + n, at + n + 1],
        [
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        ],
    )
}

/// The curvature penalty's difference stencils over an `n x n` grid: each is a list of
/// (node, coefficient), its square summed into the energy (thin plate: `t_xx^2 + 2 t_xy^2
/// + t_yy^2`, each in node units).
fn curvature_rows(n: usize) -> Vec<Vec<(usize, f64)>> {
    let at = |i: usize, j: usize| j * n + i;
    let mut rows = Vec::new();
    let s2 = std::f64::consts::SQRT_2;
    for j in 0..n {
        for i in 0..n {
            if i >= 1 && i + 1 < n {
                rows.push(vec![
                    (at(i - 1, j), 1.0),
                    (at(i, j), -2.0),
                    (at(i + 1, j), 1.0),
                ]);
            }
            if j >= 1 && j + 1 < n {
                rows.push(vec![
                    (at(i, j - 1), 1.0),
                    (at(i, j), -2.0),
                    (at(i, j + 1), 1.0),
                ]);
            }
            if i + 1 < n && j + 1 < n {
                rows.push(vec![
                    (at(i, j), s2),
                    (at(i + 1, j), -s2),
                    (at(i, j + 1), -s2),
                    (at(i + 1, j + 1), s2),
                ]);
            }
        }
    }
    rows
}

/// The normal equations of the fit: the data term as a 3 x 3 stencil per node (the
/// bilinear weights couple a node with its eight neighbours), the penalty's rows and
/// weight.
struct System {
    n: usize,
    /// `data[node][(dj + 1) * 3 + (di + 1)]`: coupling of `node` with `node + (di, dj)`.
    data: Vec<[f64; 9]>,
    curvature: Vec<Vec<(usize, f64)>>,
    lambda: f64,
    /// The node held at zero, if any.
    pinned: Option<usize>,
}

impl System {
    /// `out = A t`, zero at the pinned node.
    fn apply(&self, t: &[f64], out: &mut [f64]) {
        let n = self.n as isize;
        for (a, row) in self.data.iter().enumerate() {
            let (i, j) = ((a as isize) % n, (a as isize) / n);
            let mut sum = 0.0;
            for dj in -1..=1isize {
                for di in -1..=1isize {
                    let c = row[((dj + 1) * 3 + di + 1) as usize];
                    if c != 0.0 {
                        sum += c * t[((j + dj) * n + i + di) as usize];
                    }
                }
            }
            out[a] = sum;
        }
        for row in &self.curvature {
            let r: f64 = row.iter().map(|&(m, c)| c * t[m]).sum();
            for &(m, c) in row {
                out[m] += self.lambda * c * r;
            }
        }
        if let Some(p) = self.pinned {
            out[p] = 0.0;
        }
    }

    fn diagonal(&self) -> Vec<f64> {
        let mut d: Vec<f64> = self.data.iter().map(|row| row[4]).collect();
        for row in &self.curvature {
            for &(m, c) in row {
                d[m] += self.lambda * c * c;
            }
        }
        d
    }

    /// Solves `A t = b` (b zero at the pinned node) by faer's conjugate gradients with the
    /// Jacobi preconditioner, to a relative residual of 1e-10; returns the iterations taken.
    /// The pinned node's row and column become the identity's (`P A P + e_p e_p^T`, `P`
    /// zeroing the node), so that the operator is positive definite and `t_p = b_p = 0`.
    fn solve(&self, b: &[f64], t: &mut [f64]) -> Result<usize, String> {
        let nodes = b.len();
        let inverse_diagonal: Vec<f64> = self
            .diagonal()
            .iter()
            .enumerate()
            .map(|(m, &d)| match Some(m) == self.pinned || d <= 0.0 {
                true => 1.0,
                false => 1.0 / d,
            })
            .collect();
        let jacobi = Op {
            n: nodes,
            product: |x: &[f64], y: &mut [f64]| {
                for ((y, x), d) in y.iter_mut().zip(x).zip(&inverse_diagonal) {
                    *y = x * d;
                }
            },
        };
        let operator = Op {
            n: nodes,
            product: |x: &[f64], y: &mut [f64]| {
                let mut x = x.to_vec();
                let held = self.pinned.map(|p| std::mem::take(&mut x[p]));
                self.apply(&x, y);
                if let (Some(p), Some(v)) = (self.pinned, held) {
                    y[p] = v;
                }
            },
        };
        let params = CgParams {
            // (faer 0.24 leaves the residual unset for `InitialGuessStatus::Zero`: the
            // guess, zero, is given.)
            initial_guess: InitialGuessStatus::MaybeNonZero,
            abs_tolerance: 0.0,
            rel_tolerance: 1e-10,
            max_iters: 20 * nodes,
            ..Default::default()
        };
        let mut mem = MemBuffer::new(conjugate_gradient_scratch(&jacobi, &operator, 1, Par::Seq));
        t.fill(0.0);
        let out = MatMut::from_column_major_slice_mut(t, nodes, 1);
        let rhs = MatRef::from_column_major_slice(b, nodes, 1);
        conjugate_gradient(
            out,
            &jacobi,
            &operator,
            rhs,
            params,
            |_| {},
            Par::Seq,
            MemStack::new(&mut mem),
        )
        .map(|info| info.iter_count)
        .map_err(|e| format!("the table's normal equations did not solve: {e:?}"))
    }
}

/// A symmetric operator of faer's (`LinOp`, `Precond`) from its product on one column.
struct Op<F: Fn(&[f64], &mut [f64]) + Sync> {
    n: usize,
    product: F,
}

impl<F: Fn(&[f64], &mut [f64]) + Sync> Op<F> {
    fn apply_to(&self, mut out: MatMut<'_, f64>, rhs: MatRef<'_, f64>) {
        let (mut x, mut y) = (vec![0.0; self.n], vec![0.0; self.n]);
        for j in 0..rhs.ncols() {
            x.iter_mut().enumerate().for_each(|(i, v)| *v = rhs[(i, j)]);
            (self.product)(&x, &mut y);
            y.iter().enumerate().for_each(|(i, &v)| out[(i, j)] = v);
        }
    }
}

impl<F: Fn(&[f64], &mut [f64]) + Sync> std::fmt::Debug for Op<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Op({})", self.n)
    }
}

impl<F: Fn(&[f64], &mut [f64]) + Sync> LinOp<f64> for Op<F> {
    fn apply_scratch(&self, _rhs_ncols: usize, _par: Par) -> StackReq {
        StackReq::EMPTY
    }
    fn nrows(&self) -> usize {
        self.n
    }
    fn ncols(&self) -> usize {
        self.n
    }
    fn apply(&self, out: MatMut<'_, f64>, rhs: MatRef<'_, f64>, _par: Par, _stack: &mut MemStack) {
        self.apply_to(out, rhs);
    }
    fn conj_apply(
        &self,
        out: MatMut<'_, f64>,
        rhs: MatRef<'_, f64>,
        _par: Par,
        _stack: &mut MemStack,
    ) {
        self.apply_to(out, rhs);
    }
}

impl<F: Fn(&[f64], &mut [f64]) + Sync> Precond<f64> for Op<F> {}

/// Fits the table to `samples` (see the module documentation).
pub fn fit_table(samples: &[Sample], o: &FitOptions) -> Result<(GradientTable, FitReport), String> {
    let n = o.bins;
    if n < 3 || n % 2 == 0 || n > MAX_BINS {
        return Err(format!("bins = {n}: must be odd, in 3..={MAX_BINS}"));
    }
    if !(o.smooth.is_finite() && o.smooth > 0.0) {
        return Err(format!("smooth = {}: must be positive", o.smooth));
    }
    if samples.is_empty() {
        return Err("no samples".into());
    }
    let range = match o.range {
        Some(g) if g.is_finite() && g > 0.0 => g,
        Some(g) => return Err(format!("range = {g}: must be positive")),
        None => samples
            .iter()
            .flat_map(|s| s.gradient.map(f64::abs))
            .fold(0.0, f64::max),
    };
    if !(range.is_finite() && range > 0.0) {
        return Err("every sample has zero slope: no range to fit".into());
    }
    let nodes = n * n;
    let mut data = vec![[0.0; 9]; nodes];
    let mut rhs = vec![[0.0; 3]; nodes];
    for s in samples {
        let (at, w) = weights(s.gradient, n, range);
        for (a, wa) in at.iter().zip(&w) {
            for (b, wb) in at.iter().zip(&w) {
                let (di, dj) = (
                    (b % n) as isize - (a % n) as isize,
                    (b / n) as isize - (a / n) as isize,
                );
                data[*a][((dj + 1) * 3 + di + 1) as usize] += wa * wb;
            }
            for (r, c) in rhs[*a].iter_mut().zip(&s.change) {
                *r += wa * c;
            }
        }
    }
    let weighted: Vec<f64> = data.iter().map(|row| row[4]).filter(|&d| d > 0.0).collect();
    let mean_weight = weighted.iter().sum::<f64>() / weighted.len() as f64;
    let pinned = Some(nodes / 2);
    let system = System {
        n,
        data,
        curvature: curvature_rows(n),
        lambda: o.smooth * mean_weight,
        pinned,
    };
    let mut values = vec![0.0; CHANNELS * nodes];
    let mut iterations = 0;
    let mut t = vec![0.0; nodes];
    for k in 0..CHANNELS {
        let mut b: Vec<f64> = rhs.iter().map(|r| r[k]).collect();
        if let Some(p) = pinned {
            b[p] = 0.0;
        }
        iterations = iterations.max(system.solve(&b, &mut t)?);
        for (m, v) in t.iter().enumerate() {
            values[CHANNELS * m + k] = v.clamp(-FULL_SCALE, FULL_SCALE);
        }
    }
    let table = GradientTable::new([n, n], [range, range], values)?;
    let sq: f64 = samples
        .iter()
        .map(|s| {
            let fit = table.lookup(s.gradient[0], s.gradient[1]);
            (0..CHANNELS)
                .map(|k| (fit[k] - s.change[k]).powi(2))
                .sum::<f64>()
        })
        .sum();
    let report = FitReport {
        bins: n,
        range,
        samples: samples.len(),
        nodes_with_data: weighted.len() as f64 / nodes as f64,
        smooth: o.smooth,
        rms_residual: (sq / (CHANNELS * samples.len()) as f64).sqrt(),
        iterations,
    };
    Ok((table, report))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples of `f` on a scattered set of gradients inside the disc of radius `reach`.
    fn samples_of(f: impl Fn(f64, f64) -> [f64; 3], reach: f64) -> Vec<Sample> {
        let mut out = Vec::new();
        // A golden-angle spiral: dense, even, no two at the same radius.
        let count = 20_000;
        for i in 0..count {
            let r = reach * ((i as f64 + 0.5) / count as f64).sqrt();
            let phi = i as f64 * 2.399_963_229_728_653;
            let g = [r * phi.cos(), r * phi.sin()];
            out.push(Sample {
                gradient: g,
                change: f(g[0], g[1]),
            });
        }
        out
    }

    #[test]
    fn a_linear_response_is_fitted_exactly_and_the_zero_node_is_zero() {
        // Linear in (gx, gy) with no constant term: the table represents it exactly and the
        // curvature penalty (second differences) vanishes on it, so the fit recovers it to
        // the solver's tolerance (measured 1.4e-9 levels).
        let f = |x: f64, y: f64| [40.0 * x, -30.0 * y, 25.0 * x + 10.0 * y];
        let samples = samples_of(f, 0.8);
        let (table, report) = fit_table(&samples, &FitOptions::default()).unwrap();
        assert!((report.range - 0.8).abs() < 1e-3, "{report:?}");
        for (gx, gy) in [(0.1, 0.2), (-0.5, 0.3), (0.0, -0.6), (0.33, -0.41)] {
            let (got, want) = (table.lookup(gx, gy), f(gx, gy));
            for k in 0..3 {
                assert!(
                    (got[k] - want[k]).abs() < 1e-6,
                    "({gx}, {gy}): {got:?} {want:?}"
                );
            }
        }
        assert_eq!(table.lookup(0.0, 0.0), [0.0; 3]);
        assert!(report.rms_residual < 1e-6, "{report:?}");
    }

    #[test]
    fn nodes_without_samples_continue_the_fitted_surface() {
        // Samples only inside |g| < 0.6 of a table over +-1: the corners (|g| up to 1.41)
        // have none (68 % of the nodes). The thin-plate penalty continues a linear response
        // linearly, to the solver's tolerance (measured 2.3e-6 levels at (0.95, -0.95)); a
        // membrane penalty or nearest-neighbour filling would flatten it there.
        let f = |x: f64, y: f64| [50.0 * x, 50.0 * y, 0.0];
        let samples = samples_of(f, 0.6);
        let o = FitOptions {
            range: Some(1.0),
            ..FitOptions::default()
        };
        let (table, report) = fit_table(&samples, &o).unwrap();
        assert!(report.nodes_with_data < 0.5, "{report:?}");
        let corner = table.lookup(0.95, -0.95);
        assert!(
            (corner[0] - 47.5).abs() < 1e-3 && (corner[1] + 47.5).abs() < 1e-3,
            "{corner:?}"
        );
    }

    #[test]
    fn bad_fit_options_are_refused() {
        let s = samples_of(|x, _| [x, 0.0, 0.0], 0.5);
        for o in [
            FitOptions {
                bins: 40,
                ..FitOptions::default()
            },
            FitOptions {
                bins: 1,
                ..FitOptions::default()
            },
            FitOptions {
                smooth: 0.0,
                ..FitOptions::default()
            },
            FitOptions {
                range: Some(-1.0),
                ..FitOptions::default()
            },
        ] {
            assert!(fit_table(&s, &o).is_err(), "{o:?}");
        }
        assert!(fit_table(&[], &FitOptions::default()).is_err());
    }
}
