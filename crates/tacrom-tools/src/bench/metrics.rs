//! Error metrics between a mode's output and the reference's, and timing statistics.
//!
//! Images are row-major depth images in metres, all of one size. The choices that change
//! the numbers are stated here once, and repeated in the report:
//!
//! * **PSNR** uses as its peak the largest depth of the *reference* image of the press
//!   (its data range; a flat reference has no range and no PSNR). Identical images give
//!   `+inf`, which aggregates clip to [`PSNR_CAP_DB`].
//! * **SSIM** (Wang et al., 2004) uses an 11 x 11 Gaussian window of sigma 1.5 (shrunk to
//!   the image when smaller), `K1 = 0.01`, `K2 = 0.03`, the same peak as PSNR as the dynamic
//!   range `L`, and averages over every window that lies wholly inside the image.
//! * **Chamfer-L2** is `mean_a min_b |a - b|^2 + mean_b min_a |a - b|^2` (the sum of the two
//!   directed means of squared nearest-neighbour distances).

/// Largest PSNR reported when averaging (identical images have an infinite PSNR).
pub const PSNR_CAP_DB: f64 = 100.0;
/// SSIM window side (pixels).
pub const SSIM_WINDOW: usize = 11;
/// SSIM Gaussian window's standard deviation (pixels).
pub const SSIM_SIGMA: f64 = 1.5;
/// SSIM stabilising constant for the means.
pub const SSIM_K1: f64 = 0.01;
/// SSIM stabilising constant for the variances.
pub const SSIM_K2: f64 = 0.03;

/// Mean absolute difference.
pub fn mae(a: &[f64], b: &[f64]) -> f64 {
    debug_assert_eq!(a.len(), b.len());
    if a.is_empty() {
        return 0.0;
    }
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>() / a.len() as f64
}

/// Mean squared difference.
pub fn mse(a: &[f64], b: &[f64]) -> f64 {
    debug_assert_eq!(a.len(), b.len());
    if a.is_empty() {
        return 0.0;
    }
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len() as f64
}

/// Root mean squared difference.
pub fn rmse(a: &[f64], b: &[f64]) -> f64 {
    mse(a, b).sqrt()
}

/// Peak signal-to-noise ratio (dB) of `a` against `b` for the peak value `peak`:
/// `10 log10(peak^2 / MSE)`; `+inf` for identical images, `None` when `peak` is not
/// positive and finite.
pub fn psnr(a: &[f64], b: &[f64], peak: f64) -> Option<f64> {
    if !(peak > 0.0 && peak.is_finite()) {
        return None;
    }
    let m = mse(a, b);
    Some(if m == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (peak * peak / m).log10()
    })
}

/// Normalised 1-D Gaussian of `n` taps and standard deviation `sigma`.
fn gaussian(n: usize, sigma: f64) -> Vec<f64> {
    let c = (n as f64 - 1.0) / 2.0;
    let w: Vec<f64> = (0..n)
        .map(|i| (-(i as f64 - c).powi(2) / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = w.iter().sum();
    w.into_iter().map(|v| v / s).collect()
}

/// Separable "valid" filtering of a `width x height` image with the kernel `k` along both
/// axes; the result is `(width - n + 1) x (height - n + 1)`.
fn filter_valid(img: &[f64], width: usize, height: usize, k: &[f64]) -> Vec<f64> {
    let n = k.len();
    let (ow, oh) = (width + 1 - n, height + 1 - n);
    let mut rows = vec![0.0; ow * height];
    for r in 0..height {
        let line = &img[r * width..(r + 1) * width];
        for c in 0..ow {
            rows[r * ow + c] = k.iter().zip(&line[c..c + n]).map(|(w, v)| w * v).sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for r in 0..oh {
        for c in 0..ow {
            out[r * ow + c] = k
                .iter()
                .enumerate()
                .map(|(i, w)| w * rows[(r + i) * ow + c])
                .sum();
        }
    }
    out
}

/// Mean structural similarity of `a` and `b` (`width x height`, row-major) for the dynamic
/// range `range` (see the module's documentation for the window and constants). `None`
/// when the range is not positive and finite or the image is empty.
pub fn ssim(a: &[f64], b: &[f64], width: usize, height: usize, range: f64) -> Option<f64> {
    if !(range > 0.0 && range.is_finite()) || width == 0 || height == 0 {
        return None;
    }
    if a.len() != width * height || b.len() != width * height {
        return None;
    }
    let n = SSIM_WINDOW.min(width).min(height);
    let k = gaussian(n, SSIM_SIGMA);
    let prod = |f: &dyn Fn(f64, f64) -> f64| -> Vec<f64> {
        a.iter().zip(b).map(|(&x, &y)| f(x, y)).collect()
    };
    let mu_a = filter_valid(a, width, height, &k);
    let mu_b = filter_valid(b, width, height, &k);
    let aa = filter_valid(&prod(&|x, _| x * x), width, height, &k);
    let bb = filter_valid(&prod(&|_, y| y * y), width, height, &k);
    let ab = filter_valid(&prod(&|x, y| x * y), width, height, &k);
    let c1 = (SSIM_K1 * range).powi(2);
    let c2 = (SSIM_K2 * range).powi(2);
    let total: f64 = (0..mu_a.len())
        .map(|i| {
            let (ma, mb) = (mu_a[i], mu_b[i]);
            let va = aa[i] - ma * ma;
            let vb = bb[i] - mb * mb;
            let cov = ab[i] - ma * mb;
            ((2.0 * ma * mb + c1) * (2.0 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))
        })
        .sum();
    Some(total / mu_a.len() as f64)
}

/// Nearest-neighbour queries on a point set, bucketed on a uniform grid in x and y. The
/// horizontal distance to a bucket bounds the 3-D distance from below, so the search is
/// exact for any points; it is fast for height fields (surfaces seen from below).
struct PointIndex<'a> {
    points: &'a [[f64; 3]],
    origin: [f64; 2],
    cell: f64,
    dims: [usize; 2],
    /// Start of each bucket in `order`, plus one end.
    starts: Vec<usize>,
    order: Vec<usize>,
}

impl<'a> PointIndex<'a> {
    fn new(points: &'a [[f64; 3]]) -> Self {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for p in points {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let ext = [(hi[0] - lo[0]).max(0.0), (hi[1] - lo[1]).max(0.0)];
        // About one point per bucket.
        let area = (ext[0] * ext[1]).max(1e-300);
        let mut cell = (area / points.len().max(1) as f64).sqrt();
        if !(cell.is_finite() && cell > 0.0) {
            cell = ext[0].max(ext[1]).max(1e-12);
        }
        let dims = [
            ((ext[0] / cell) as usize + 1).min(1 << 12),
            ((ext[1] / cell) as usize + 1).min(1 << 12),
        ];
        let cell = cell
            .max(ext[0] / dims[0] as f64)
            .max(ext[1] / dims[1] as f64);
        let bucket = |p: &[f64; 3]| {
            let i = (((p[0] - lo[0]) / cell) as usize).min(dims[0] - 1);
            let j = (((p[1] - lo[1]) / cell) as usize).min(dims[1] - 1);
            j * dims[0] + i
        };
        let mut counts = vec![0usize; dims[0] * dims[1] + 1];
        for p in points {
            counts[bucket(p) + 1] += 1;
        }
        for i in 1..counts.len() {
            counts[i] += counts[i - 1];
        }
        let mut fill = counts.clone();
        let mut order = vec![0; points.len()];
        for (n, p) in points.iter().enumerate() {
            let b = bucket(p);
            order[fill[b]] = n;
            fill[b] += 1;
        }
        Self {
            points,
            origin: lo,
            cell,
            dims,
            starts: counts,
            order,
        }
    }

    /// Squared distance from `q` to the nearest point.
    fn nearest_sq(&self, q: &[f64; 3]) -> f64 {
        let ci = ((q[0] - self.origin[0]) / self.cell).floor();
        let cj = ((q[1] - self.origin[1]) / self.cell).floor();
        let mut best = f64::INFINITY;
        let max_ring = self.dims[0].max(self.dims[1]) as i64 + 1;
        let (ci, cj) = (
            ci.clamp(-1.0, self.dims[0] as f64) as i64,
            cj.clamp(-1.0, self.dims[1] as f64) as i64,
        );
        for ring in 0..=max_ring {
            // Every bucket of this ring is at least (ring - 1) cells away horizontally.
            let bound = ((ring - 1).max(0) as f64 * self.cell).powi(2);
            if bound > best {
                break;
            }
            for j in cj - ring..=cj + ring {
                for i in ci - ring..=ci + ring {
                    let on_ring = (j - cj).abs() == ring || (i - ci).abs() == ring;
                    if !on_ring
                        || i < 0
                        || j < 0
                        || i >= self.dims[0] as i64
                        || j >= self.dims[1] as i64
                    {
                        continue;
                    }
                    let b = j as usize * self.dims[0] + i as usize;
                    for &n in &self.order[self.starts[b]..self.starts[b + 1]] {
                        let p = &self.points[n];
                        let d =
                            (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
                        best = best.min(d);
                    }
                }
            }
        }
        best
    }
}

/// Chamfer-L2 distance: the mean squared distance from each point of `a` to its nearest
/// point of `b`, plus the same from `b` to `a` (units squared). Zero for two empty sets;
/// `inf` when only one is empty.
pub fn chamfer_l2(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    match (a.is_empty(), b.is_empty()) {
        (true, true) => return 0.0,
        (true, false) | (false, true) => return f64::INFINITY,
        _ => {}
    }
    let directed = |from: &[[f64; 3]], to: &[[f64; 3]]| {
        let index = PointIndex::new(to);
        from.iter().map(|q| index.nearest_sq(q)).sum::<f64>() / from.len() as f64
    };
    directed(a, b) + directed(b, a)
}

/// The deformed surface seen by the camera as points: each pixel centre of `grid`, lowered
/// to `z = -depth`.
pub fn surface_points(grid: &tacrom::geometry::PixelGrid, depth: &[f64]) -> Vec<[f64; 3]> {
    let mut pts = Vec::with_capacity(grid.width * grid.height);
    for row in 0..grid.height {
        for col in 0..grid.width {
            pts.push([grid.x(col), grid.y(row), -depth[row * grid.width + col]]);
        }
    }
    pts
}

/// The `q`-quantile (0..=1) of `values` by the nearest rank; `NaN` for none.
pub fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let i = ((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    v[i]
}

/// Median of `values`; `NaN` for none.
pub fn median(values: &[f64]) -> f64 {
    quantile(values, 0.5)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: usize, h: usize) -> Vec<f64> {
        (0..w * h)
            .map(|i| ((i % w) as f64 * 0.3 + (i / w) as f64 * 0.7).sin() + 1.0)
            .collect()
    }

    #[test]
    fn mae_rmse_of_a_constant_offset() {
        let a = vec![1.0, 2.0, 3.0, 4.0];
        let b: Vec<f64> = a.iter().map(|v| v + 0.5).collect();
        assert!((mae(&a, &b) - 0.5).abs() < 1e-15);
        assert!((rmse(&a, &b) - 0.5).abs() < 1e-15);
        // One error of 2 among four pixels: MAE 0.5, RMSE 1.
        let c = vec![1.0, 2.0, 3.0, 6.0];
        assert!((mae(&a, &c) - 0.5).abs() < 1e-15);
        assert!((rmse(&a, &c) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn psnr_of_a_known_mse() {
        let a = vec![0.0; 100];
        let b = vec![0.1; 100]; // MSE 0.01, peak 1: 20 dB.
        assert!((psnr(&a, &b, 1.0).unwrap() - 20.0).abs() < 1e-9);
        assert_eq!(psnr(&a, &a, 1.0), Some(f64::INFINITY));
        assert_eq!(psnr(&a, &b, 0.0), None);
        assert_eq!(psnr(&a, &b, f64::NAN), None);
    }

    #[test]
    fn ssim_of_identical_images_is_one() {
        let a = ramp(32, 24);
        let s = ssim(&a, &a, 32, 24, 2.0).unwrap();
        assert!((s - 1.0).abs() < 1e-12, "{s}");
        // Smaller than the window: the window shrinks.
        let small = ramp(5, 4);
        assert!((ssim(&small, &small, 5, 4, 2.0).unwrap() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn ssim_drops_with_noise_and_is_symmetric() {
        let a = ramp(32, 24);
        let b: Vec<f64> = a
            .iter()
            .enumerate()
            .map(|(i, v)| v + if i % 2 == 0 { 0.2 } else { -0.2 })
            .collect();
        let s = ssim(&a, &b, 32, 24, 2.0).unwrap();
        assert!(s < 0.95 && s > 0.0, "{s}");
        assert!((s - ssim(&b, &a, 32, 24, 2.0).unwrap()).abs() < 1e-12);
        assert_eq!(ssim(&a, &b, 32, 24, 0.0), None);
        assert_eq!(ssim(&a, &b[..10], 32, 24, 1.0), None);
    }

    #[test]
    fn ssim_of_a_constant_offset_matches_the_luminance_term() {
        // Flat images: SSIM = (2 m1 m2 + C1) / (m1^2 + m2^2 + C1).
        let (w, h) = (16, 16);
        let a = vec![0.5; w * h];
        let b = vec![0.7; w * h];
        let c1 = (SSIM_K1 * 1.0_f64).powi(2);
        let expect = (2.0 * 0.5 * 0.7 + c1) / (0.25 + 0.49 + c1);
        assert!((ssim(&a, &b, w, h, 1.0).unwrap() - expect).abs() < 1e-12);
    }

    #[test]
    fn chamfer_of_shifted_point_sets() {
        // A 10 x 10 lattice of pitch 1 and its copy lowered by 0.3: every nearest distance
        // is 0.3, so the Chamfer-L2 is 2 * 0.09.
        let a: Vec<[f64; 3]> = (0..100)
            .map(|i| [(i % 10) as f64, (i / 10) as f64, 0.0])
            .collect();
        let b: Vec<[f64; 3]> = a.iter().map(|p| [p[0], p[1], p[2] - 0.3]).collect();
        assert!((chamfer_l2(&a, &b) - 0.18).abs() < 1e-12);
        assert_eq!(chamfer_l2(&a, &a), 0.0);
        // A shift by half the pitch along x: distances 0.5, except the last column of b,
        // which is 0.5 past the lattice as well.
        let c: Vec<[f64; 3]> = a.iter().map(|p| [p[0] + 0.5, p[1], p[2]]).collect();
        assert!((chamfer_l2(&a, &c) - 0.5).abs() < 1e-12);
        assert_eq!(chamfer_l2(&a, &[]), f64::INFINITY);
        assert_eq!(chamfer_l2(&[], &[]), 0.0);
    }

    #[test]
    fn chamfer_matches_brute_force_on_scattered_points() {
        let mut rng = crate::datagen::Rng::new(12345, 0);
        let mut rnd = || rng.uniform(0.0, 1.0);
        let a: Vec<[f64; 3]> = (0..300).map(|_| [rnd(), rnd() * 2.0, rnd()]).collect();
        let b: Vec<[f64; 3]> = (0..200)
            .map(|_| [rnd() * 1.5, rnd(), rnd() * 0.1])
            .collect();
        let brute = |f: &[[f64; 3]], t: &[[f64; 3]]| {
            f.iter()
                .map(|p| {
                    t.iter()
                        .map(|q| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>())
                        .fold(f64::INFINITY, f64::min)
                })
                .sum::<f64>()
                / f.len() as f64
        };
        let expect = brute(&a, &b) + brute(&b, &a);
        assert!((chamfer_l2(&a, &b) - expect).abs() < 1e-12);
    }

    #[test]
    fn quantiles() {
        let v = [5.0, 1.0, 3.0, 2.0, 4.0];
        assert_eq!(median(&v), 3.0);
        assert_eq!(quantile(&v, 0.9), 5.0);
        assert_eq!(quantile(&v, 0.0), 1.0);
        assert!(median(&[]).is_nan());
    }
}
