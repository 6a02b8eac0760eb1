//! How close a re-rendered press is to its image: the mean absolute colour error and the
//! structural similarity (SSIM, Wang et al. 2004) of the grey images, over the contact
//! circle and over the whole image.

use serde::Serialize;
use tacrom::render::calibrated::RgbImage;
use tacrom::render::rgb::{CHANNELS, FULL_SCALE};

use super::Contact;

/// Errors of one image against another.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ImageErrors {
    /// Mean absolute difference inside the contact circle (grey levels, all channels).
    pub mae_contact: f64,
    /// Mean absolute difference over the image.
    pub mae_image: f64,
    /// Mean SSIM of the grey images inside the contact circle.
    pub ssim_contact: f64,
    /// Mean SSIM over the image.
    pub ssim_image: f64,
}

impl ImageErrors {
    /// The errors of `rendered` (`(H, W, 3)` values) against `image`, `contact` giving the
    /// contact region.
    pub fn of(rendered: &[f64], image: &RgbImage, contact: &Contact) -> Self {
        let (w, h) = (image.width, image.height);
        let mask = contact.mask(w, h);
        let ssim = ssim_map(&grey(rendered), &grey(&image.data), w, h);
        ImageErrors {
            mae_contact: mae(rendered, &image.data, Some(&mask)),
            mae_image: mae(rendered, &image.data, None),
            ssim_contact: mean(&ssim, Some(&mask)),
            ssim_image: mean(&ssim, None),
        }
    }

    /// The mean of `rows`, or `None` when there are none.
    pub fn mean(rows: &[ImageErrors]) -> Option<ImageErrors> {
        if rows.is_empty() {
            return None;
        }
        let n = rows.len() as f64;
        let avg = |f: fn(&ImageErrors) -> f64| rows.iter().map(f).sum::<f64>() / n;
        Some(ImageErrors {
            mae_contact: avg(|e| e.mae_contact),
            mae_image: avg(|e| e.mae_image),
            ssim_contact: avg(|e| e.ssim_contact),
            ssim_image: avg(|e| e.ssim_image),
        })
    }
}

/// The mean of `per_value(a - b)` over every channel of the pixels of two `(H, W, 3)`
/// images where `mask` holds (all of them when `None`); `None` over no pixels.
fn masked_mean(
    a: &[f64],
    b: &[f64],
    mask: Option<&[bool]>,
    per_value: fn(f64) -> f64,
) -> Option<f64> {
    let (mut sum, mut count) = (0.0, 0usize);
    for (i, (pa, pb)) in a
        .chunks_exact(CHANNELS)
        .zip(b.chunks_exact(CHANNELS))
        .enumerate()
    {
        if mask.is_some_and(|m| !m[i]) {
            continue;
        }
        sum += (0..CHANNELS).map(|k| per_value(pa[k] - pb[k])).sum::<f64>();
        count += CHANNELS;
    }
    (count > 0).then(|| sum / count as f64)
}

/// Mean absolute difference of two `(H, W, 3)` images over the pixels where `mask` holds
/// (all of them when `None`); 0 over no pixels.
pub fn mae(a: &[f64], b: &[f64], mask: Option<&[bool]>) -> f64 {
    masked_mean(a, b, mask, f64::abs).unwrap_or(0.0)
}

/// Peak signal-to-noise ratio (dB) of two `(H, W, 3)` images on the 0..255 scale over the
/// pixels where `mask` holds (all when `None`): `10 log10(255^2 / MSE)`; infinite for
/// equal images (and over no pixels).
pub fn psnr(a: &[f64], b: &[f64], mask: Option<&[bool]>) -> f64 {
    let mse = masked_mean(a, b, mask, |d| d * d).unwrap_or(0.0);
    10.0 * (FULL_SCALE * FULL_SCALE / mse).log10()
}

/// The grey image (ITU-R BT.601 luma) of an `(H, W, 3)` image.
pub fn grey(rgb: &[f64]) -> Vec<f64> {
    rgb.chunks_exact(CHANNELS)
        .map(|p| 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2])
        .collect()
}

/// The mean of `values` where `mask` holds (1 over no values: the SSIM of nothing).
pub fn mean(values: &[f64], mask: Option<&[bool]>) -> f64 {
    let (mut sum, mut count) = (0.0, 0usize);
    for (i, v) in values.iter().enumerate() {
        if mask.map_or(true, |m| m[i]) {
            sum += v;
            count += 1;
        }
    }
    if count == 0 {
        1.0
    } else {
        sum / count as f64
    }
}

/// Gaussian window of SSIM: sigma 1.5 pixels, 11 taps.
const SIGMA: f64 = 1.5;
const HALF: usize = 5;

/// `img` (`w x h`) blurred by the Gaussian window, separably; at the border the window is
/// cut and renormalised.
fn blur(img: &[f64], w: usize, h: usize) -> Vec<f64> {
    let taps: Vec<f64> = (0..=2 * HALF)
        .map(|i| {
            let d = i as f64 - HALF as f64;
            (-0.5 * d * d / (SIGMA * SIGMA)).exp()
        })
        .collect();
    let pass = |src: &[f64], along_rows: bool| {
        let mut out = vec![0.0; w * h];
        for r in 0..h {
            for c in 0..w {
                let (pos, len) = if along_rows { (c, w) } else { (r, h) };
                let (mut sum, mut weight) = (0.0, 0.0);
                for (t, &k) in taps.iter().enumerate() {
                    let Some(q) = (pos + t).checked_sub(HALF).filter(|&q| q < len) else {
                        continue;
                    };
                    let v = if along_rows {
                        src[r * w + q]
                    } else {
                        src[q * w + c]
                    };
                    sum += k * v;
                    weight += k;
                }
                out[r * w + c] = sum / weight;
            }
        }
        out
    };
    pass(&pass(img, true), false)
}

/// The SSIM map of two grey images of `w x h` pixels on the 0..255 scale (Gaussian window,
/// `C1 = (0.01 L)^2`, `C2 = (0.03 L)^2`, `L = 255`): 1 where they agree.
pub fn ssim_map(a: &[f64], b: &[f64], w: usize, h: usize) -> Vec<f64> {
    let c1 = (0.01 * FULL_SCALE).powi(2);
    let c2 = (0.03 * FULL_SCALE).powi(2);
    let product = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(p, q)| p * q).collect::<Vec<_>>();
    let (mu_a, mu_b) = (blur(a, w, h), blur(b, w, h));
    let (aa, bb, ab) = (
        blur(&product(a, a), w, h),
        blur(&product(b, b), w, h),
        blur(&product(a, b), w, h),
    );
    (0..w * h)
        .map(|i| {
            let (ma, mb) = (mu_a[i], mu_b[i]);
            let (va, vb, cov) = (aa[i] - ma * ma, bb[i] - mb * mb, ab[i] - ma * mb);
            ((2.0 * ma * mb + c1) * (2.0 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_have_ssim_one_and_no_error() {
        let (w, h) = (23, 17);
        let img: Vec<f64> = (0..w * h).map(|i| ((i * 37) % 255) as f64).collect();
        let map = ssim_map(&img, &img, w, h);
        assert!(map.iter().all(|&s| (s - 1.0).abs() < 1e-12));
        let rgb: Vec<f64> = img.iter().flat_map(|&v| [v, v, v]).collect();
        assert_eq!(mae(&rgb, &rgb, None), 0.0);
    }

    #[test]
    fn ssim_falls_with_noise_and_ignores_nothing_it_should_not() {
        // A smooth image against itself plus a checkerboard of +-20 levels: the structure
        // differs everywhere, the mean nowhere. SSIM of a smooth field s against s + n,
        // n of variance v uncorrelated with s, is about (2 var_s + C2) / (2 var_s + v + C2)
        // within a window: var_s is small here, so the map drops well below 1.
        let (w, h) = (32, 32);
        let s: Vec<f64> = (0..w * h).map(|i| 100.0 + (i % w) as f64).collect();
        let noisy: Vec<f64> = s
            .iter()
            .enumerate()
            .map(|(i, v)| {
                v + if (i % w + i / w) % 2 == 0 {
                    20.0
                } else {
                    -20.0
                }
            })
            .collect();
        let map = ssim_map(&s, &noisy, w, h);
        let m = map.iter().sum::<f64>() / map.len() as f64;
        assert!(m < 0.3, "{m}");
        // MAE of a uniform offset of 3 levels in one channel of three: 1.
        let a = vec![10.0; 3 * 4];
        let b: Vec<f64> = a
            .iter()
            .enumerate()
            .map(|(i, v)| if i % 3 == 1 { v + 3.0 } else { *v })
            .collect();
        assert!((mae(&a, &b, None) - 1.0).abs() < 1e-12);
        let mask = [true, false, false, false];
        assert!((mae(&a, &b, Some(&mask)) - 1.0).abs() < 1e-12);
        // PSNR of that offset: MSE 3 (9 over three channels), 10 log10(255^2 / 3).
        let expected = 10.0 * (255.0f64 * 255.0 / 3.0).log10();
        assert!((psnr(&a, &b, None) - expected).abs() < 1e-9);
        assert!(psnr(&a, &a, None).is_infinite());
    }
}
