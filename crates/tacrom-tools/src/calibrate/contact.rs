//! Finding a ball's contact circle in a press image.
//!
//! Where the ball presses, the surface slopes and the colour changes; around it the gel is
//! flat and shows the background. The contact is the largest 4-connected blob of pixels
//! whose colour differs from the background by more than a threshold in some channel,
//! with its holes filled (the top of the cap is nearly flat and may look like the
//! background): its centroid is the centre and `sqrt(area / pi)` the radius.
//!
//! The central differences of a rendered image see a sloped neighbour from a pixel just
//! outside a sharp contact edge: in the direction `theta` from the centre, a pixel up to
//! `max(|cos theta|, |sin theta|)` pixels outside has a 4-neighbour inside, 0.9 pixels on
//! average over the directions. So on rendered presses the blob's radius exceeds the
//! contact's by 0.82 pixels on average (measured on the synthetic sets at 0.075, 0.19 and
//! 0.375 mm pixels, where slopes at the edge are too shallow to show a few of those
//! pixels); [`detect`] removes 0.8 pixels. On a real gel the surface also sags around the
//! contact, which widens the blob by more: give the contact in `presses.json` when it is
//! known better.

use serde::{Deserialize, Serialize};
use tacrom::render::calibrated::RgbImage;
use tacrom::render::rgb::CHANNELS;

/// Default detection threshold (grey levels): above the 8-bit rounding (0.5) and a
/// camera's noise of a level or two, below the change of a slope of 0.05 (3 degrees)
/// under the built-in lights (3 to 4 levels).
pub const DEFAULT_THRESHOLD: f64 = 2.5;

/// The pixels by which a sharp contact edge widens the changed region (see the module
/// documentation).
const EDGE_WIDENING: f64 = 0.8;

/// A contact circle in image coordinates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Contact {
    /// Centre `[column, row]` (pixels, `c` at the centre of column `c`).
    pub centre: [f64; 2],
    /// Radius (pixels).
    pub radius: f64,
}

impl Contact {
    /// Distance of the centre of pixel `(row, col)` from the contact centre (pixels).
    #[inline]
    pub fn distance(&self, row: usize, col: usize) -> f64 {
        (col as f64 - self.centre[0]).hypot(row as f64 - self.centre[1])
    }

    /// Per pixel of a `width x height` image: whether its centre lies in the circle.
    pub fn mask(&self, width: usize, height: usize) -> Vec<bool> {
        (0..height)
            .flat_map(|r| (0..width).map(move |c| (r, c)))
            .map(|(r, c)| self.distance(r, c) <= self.radius)
            .collect()
    }
}

/// The contact of the press `image` over `background` (same size), or `None` when no
/// pixel differs by more than `threshold` grey levels in any channel.
pub fn detect(background: &RgbImage, image: &RgbImage, threshold: f64) -> Option<Contact> {
    let (w, h) = (image.width, image.height);
    let changed: Vec<bool> = image
        .data
        .chunks_exact(CHANNELS)
        .zip(background.data.chunks_exact(CHANNELS))
        .map(|(a, b)| (0..CHANNELS).any(|k| (a[k] - b[k]).abs() > threshold))
        .collect();
    let blob = largest_blob(&changed, w, h)?;
    // Fill the holes: every pixel that cannot reach the border without crossing the blob.
    let outside = flood(
        w,
        h,
        |i| !blob[i],
        (0..w * h).filter(|&i| on_border(i, w, h) && !blob[i]),
    );
    let (mut n, mut sc, mut sr) = (0usize, 0.0, 0.0);
    for i in (0..w * h).filter(|&i| !outside[i]) {
        n += 1;
        sc += (i % w) as f64;
        sr += (i / w) as f64;
    }
    let radius = (n as f64 / std::f64::consts::PI).sqrt() - EDGE_WIDENING;
    Some(Contact {
        centre: [sc / n as f64, sr / n as f64],
        radius: radius.max(0.5),
    })
}

fn on_border(i: usize, w: usize, h: usize) -> bool {
    let (r, c) = (i / w, i % w);
    r == 0 || c == 0 || r + 1 == h || c + 1 == w
}

/// The pixels reachable from `seeds` through 4-neighbours where `open`.
fn flood(
    w: usize,
    h: usize,
    open: impl Fn(usize) -> bool,
    seeds: impl IntoIterator<Item = usize>,
) -> Vec<bool> {
    let mut seen = vec![false; w * h];
    let mut stack: Vec<usize> = Vec::new();
    for s in seeds {
        if open(s) && !seen[s] {
            seen[s] = true;
            stack.push(s);
        }
    }
    while let Some(i) = stack.pop() {
        let (r, c) = (i / w, i % w);
        let mut visit = |j: usize| {
            if !seen[j] && open(j) {
                seen[j] = true;
                stack.push(j);
            }
        };
        if c > 0 {
            visit(i - 1);
        }
        if c + 1 < w {
            visit(i + 1);
        }
        if r > 0 {
            visit(i - w);
        }
        if r + 1 < h {
            visit(i + w);
        }
    }
    seen
}

/// The largest 4-connected region of `set`, or `None` when it is empty.
fn largest_blob(set: &[bool], w: usize, h: usize) -> Option<Vec<bool>> {
    // Label each region (0: none) and count its pixels, one stack for all.
    let mut label = vec![0u32; w * h];
    let mut sizes = vec![0usize];
    let mut stack = Vec::new();
    for start in 0..w * h {
        if !set[start] || label[start] != 0 {
            continue;
        }
        let id = sizes.len() as u32;
        sizes.push(0);
        label[start] = id;
        stack.push(start);
        while let Some(i) = stack.pop() {
            sizes[id as usize] += 1;
            let (r, c) = (i / w, i % w);
            let neighbours = [
                (c > 0).then(|| i - 1),
                (c + 1 < w).then(|| i + 1),
                (r > 0).then(|| i - w),
                (r + 1 < h).then(|| i + w),
            ];
            for j in neighbours.into_iter().flatten() {
                if set[j] && label[j] == 0 {
                    label[j] = id;
                    stack.push(j);
                }
            }
        }
    }
    let (best, _) = sizes
        .iter()
        .enumerate()
        .skip(1)
        .max_by_key(|&(id, &n)| (n, std::cmp::Reverse(id)))?;
    Some(label.iter().map(|&l| l as usize == best).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w x h` image of `background` changed by `change` where `changed(col, row)`.
    fn image(
        w: usize,
        h: usize,
        background: f64,
        change: f64,
        changed: impl Fn(f64, f64) -> bool,
    ) -> RgbImage {
        let mut data = Vec::with_capacity(3 * w * h);
        for r in 0..h {
            for c in 0..w {
                let v = if changed(c as f64, r as f64) {
                    background + change
                } else {
                    background
                };
                data.extend([background, v, background]);
            }
        }
        RgbImage {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn a_ring_of_change_counts_as_its_whole_disc_and_specks_are_ignored() {
        // A real ball's cap is flat enough near its top to look like the background over
        // several pixels: a ring of change around an unchanged core, radii 12 and 5 px,
        // plus a 3 x 3 speck and a lone noisy pixel elsewhere. The contact is the whole
        // disc: its centroid, and sqrt(area / pi) less the 0.8 px edge correction. The
        // digitised disc's area matches pi r^2 to a fraction of a pixel of radius
        // (measured 0.02 px); without the holes filled the radius comes out 1.1 px short.
        let (cx, cy) = (30.3, 24.6);
        let bg = RgbImage::uniform(60, 50, [100.0; 3]);
        let img = image(60, 50, 100.0, 10.0, |c, r| {
            let d = (c - cx).hypot(r - cy);
            (d > 5.0 && d <= 12.0)
                || (c <= 6.0 && r <= 6.0 && c >= 4.0 && r >= 4.0)
                || (c == 55.0 && r == 45.0)
        });
        let got = detect(&bg, &img, DEFAULT_THRESHOLD).unwrap();
        assert!(
            (got.centre[0] - cx).abs() < 0.1 && (got.centre[1] - cy).abs() < 0.1,
            "{got:?}"
        );
        assert!((got.radius - (12.0 - EDGE_WIDENING)).abs() < 0.1, "{got:?}");
        // Below the threshold: nothing.
        let faint = image(60, 50, 100.0, 2.0, |c, r| (c - cx).hypot(r - cy) <= 12.0);
        assert_eq!(detect(&bg, &faint, DEFAULT_THRESHOLD), None);
    }
}
