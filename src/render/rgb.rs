//! The RGB image of a GelSight-type sensor, shaded photometrically from the depth image.
//!
//! A GelSight sensor films the inside of its gel's painted membrane, lit from the sides by
//! coloured lights at a low elevation: the colour of a pixel encodes the slope of the
//! surface there. This module renders that image from a depth image with a built-in
//! optical model ([`Optics`]); it knows nothing of MuJoCo.
//!
//! **Geometry.** Seen from the camera under the gel, a dent of depth `d` is a bump of
//! height `d` towards the camera. Shading works in the camera-side frame: x and y of the
//! sensor frame, z from the surface towards the camera (into the gel). There the unit
//! normal of the membrane is `(-dd/dx, -dd/dy, 1) / sqrt(1 + |grad d|^2)`, the camera looks
//! along -z (orthographic), and a light at azimuth `phi` (from +x towards +y) and elevation
//! `e` (above the surface plane) lies in the direction `(cos e cos phi, cos e sin phi,
//! sin e)`. The slope of a dent's side nearer a light faces that light and shows its colour.
//! The gradient comes from central differences of the depth image in metres (one-sided on
//! the image's border), using the pixel size of the image's [`PixelGrid`]. The image lies
//! pixel for pixel on the depth image: row 0 the +y edge, column 0 the -x edge (the gel
//! seen from the indenter's side; the camera itself sees it mirrored).
//!
//! **Model.** Per channel `k`, the radiance of a surface with normal `n` is
//! `ambient[k] + sum_i colour_i[k] (max(0, n.l_i) + specular max(0, n.h_i)^shininess)`
//! (Lambert plus a Blinn-Phong highlight, `h_i` the half vector of light `i` and the view
//! direction; no highlight from a light behind the surface). The image is the background
//! scaled by the radiance relative to that of the flat surface,
//! `background[k] + background[k] / R0[k] (R[k](n) - R0[k])`: exactly the background where
//! the surface is flat, brighter where it faces a light, darker where it turns away. Values
//! are on the 8-bit scale, floats clamped to `[0, 255]` (a camera saturates).
//!
//! **Non-finite depth.** Where the depth is not finite the surface counts as flat: a pixel
//! whose gradient reads a non-finite depth value shows the background.
//!
//! **Calibrated model.** A lookup from the surface gradient to the colour change over a
//! background image, fitted to a device's own ball presses (Taxim-style;
//! [`super::calibrated`], the `optics` attribute), replaces [`Optics`] through
//! [`render_calibrated`]; [`RgbModel`] is the sensor's choice of the two. The per-pixel
//! gradients are computed here, once, the same way for both, and a model only maps a
//! pixel's gradient to its colour.

use std::sync::Arc;

use nalgebra::Vector3;

use super::calibrated::CalibratedOptics;
use crate::geometry::PixelGrid;

pub use super::{CHANNELS, FULL_SCALE};

/// A light of the sensor: where it shines from and its colour.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// Direction from the surface towards the light, in the camera-side frame (x, y of the
    /// sensor frame, z towards the camera); normalised by [`render`].
    pub direction: Vector3<f64>,
    /// Its contribution to the red, green and blue channels (0 to 1).
    pub colour: [f64; 3],
}

impl Light {
    /// A light at `azimuth` (radians, from +x towards +y of the sensor frame) and
    /// `elevation` (radians above the surface plane, on the camera's side).
    pub fn at(azimuth: f64, elevation: f64, colour: [f64; 3]) -> Light {
        Light {
            direction: Vector3::new(
                elevation.cos() * azimuth.cos(),
                elevation.cos() * azimuth.sin(),
                elevation.sin(),
            ),
            colour,
        }
    }
}

/// The built-in optical model: three lights over a flat background (see the module
/// documentation for the formula).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Optics {
    /// The lights.
    pub lights: [Light; 3],
    /// Colour of the undeformed gel (red, green, blue; 0 to 255).
    pub background: [f64; 3],
    /// Radiance per channel that does not depend on the surface's orientation (light
    /// scattered in the gel), in the lights' units: it bounds how dark a slope turned away
    /// from every light gets (`background * ambient / R0`).
    pub ambient: [f64; 3],
    /// Weight of the specular highlight against the Lambertian term.
    pub specular: f64,
    /// Exponent of the specular highlight (larger: smaller, sharper highlights; a negative
    /// one counts as 0).
    pub shininess: i32,
}

impl Default for Optics {
    /// A GelSight-Mini-like look, not a calibration of any device: a red, a green and a
    /// blue light at azimuths 90, 210 and 330 degrees (red at the image's top, +y), 30
    /// degrees above the surface, over a neutral grey background of (120, 125, 135), with
    /// ambient 0.3 and a small highlight (weight 0.25, exponent 16). Slopes of up to 60
    /// degrees stay below saturation.
    fn default() -> Self {
        let elevation = 30f64.to_radians();
        let light = |azimuth: f64, colour| Light::at(azimuth.to_radians(), elevation, colour);
        Optics {
            lights: [
                light(90.0, [1.0, 0.0, 0.0]),
                light(210.0, [0.0, 1.0, 0.0]),
                light(330.0, [0.0, 0.0, 1.0]),
            ],
            background: [120.0, 125.0, 135.0],
            ambient: [0.3; 3],
            specular: 0.25,
            shininess: 16,
        }
    }
}

/// Pixels shaded together: the gradients of a span of a row, on the stack, so that the
/// shading loops run over plain arrays (and vectorise).
const SPAN: usize = 64;

/// An [`Optics`] prepared for one image: unit light directions, half vectors and the flat
/// surface's radiance.
struct Shader {
    /// Per light: unit direction, unit half vector with the view direction, colour.
    lights: [(Vector3<f64>, Vector3<f64>, [f64; 3]); 3],
    ambient: [f64; 3],
    specular: f64,
    shininess: i32,
    background: [f64; 3],
    /// Radiance of the flat surface.
    flat: [f64; 3],
    /// `background / flat` per channel (0 for a channel the flat surface leaves dark).
    gain: [f64; 3],
}

impl Shader {
    fn new(optics: &Optics) -> Shader {
        let view = Vector3::z();
        let unit = |v: Vector3<f64>| {
            let n = v.norm();
            if n > 0.0 && n.is_finite() {
                v / n
            } else {
                Vector3::zeros()
            }
        };
        let lights = optics.lights.map(|l| {
            let dir = unit(l.direction);
            (dir, unit(dir + view), l.colour)
        });
        let mut shader = Shader {
            lights,
            ambient: optics.ambient,
            specular: optics.specular,
            shininess: optics.shininess,
            background: optics.background,
            flat: [0.0; 3],
            gain: [0.0; 3],
        };
        let mut flat = [[0.0; SPAN]; CHANNELS];
        shader.radiance(&[0.0], &[0.0], &mut flat);
        for (k, f) in flat.iter().map(|r| r[0]).enumerate() {
            shader.flat[k] = f;
            shader.gain[k] = if f > 0.0 && f.is_finite() {
                optics.background[k] / f
            } else {
                0.0
            };
        }
        shader
    }

    /// Radiance per channel (`radiance[k][i]`) of the surface with depth gradients
    /// `(gx[i], gy[i])`: the model's one definition. A light behind the surface
    /// contributes neither term.
    #[inline(always)]
    fn radiance(&self, gx: &[f64], gy: &[f64], radiance: &mut [[f64; SPAN]; CHANNELS]) {
        let n = gx.len();
        let (gx, gy) = (&gx[..n], &gy[..n]);
        // Unit normal facing the camera.
        let (mut nx, mut ny, mut nz) = ([0.0; SPAN], [0.0; SPAN], [0.0; SPAN]);
        for i in 0..n {
            let inv = (1.0 + gx[i] * gx[i] + gy[i] * gy[i]).sqrt().recip();
            nx[i] = -gx[i] * inv;
            ny[i] = -gy[i] * inv;
            nz[i] = inv;
        }
        for (k, r) in radiance.iter_mut().enumerate() {
            r[..n].fill(self.ambient[k]);
        }
        for (l, h, colour) in &self.lights {
            let (mut diffuse, mut highlight) = ([0.0; SPAN], [0.0; SPAN]);
            for i in 0..n {
                let nl = nx[i] * l.x + ny[i] * l.y + nz[i] * l.z;
                let nh = nx[i] * h.x + ny[i] * h.y + nz[i] * h.z;
                diffuse[i] = nl.max(0.0);
                highlight[i] = if nl > 0.0 { nh.max(0.0) } else { 0.0 };
            }
            pow(&mut highlight[..n], self.shininess);
            for i in 0..n {
                let e = diffuse[i] + self.specular * highlight[i];
                for k in 0..CHANNELS {
                    radiance[k][i] += colour[k] * e;
                }
            }
        }
    }

    /// Writes the colours of the pixels whose depth gradients are `(gx[i], gy[i])` into
    /// `out` (3 values each): the background where the surface is flat or the gradient not
    /// finite.
    #[inline(always)]
    fn shade(&self, gx: &[f64], gy: &[f64], out: &mut [f64]) {
        let n = gx.len();
        if gx.iter().chain(gy).all(|&g| g == 0.0) {
            // A flat span (most of an image): the background.
            for px in out[..CHANNELS * n].chunks_exact_mut(CHANNELS) {
                px.copy_from_slice(&self.background);
            }
            return;
        }
        let mut radiance = [[0.0; SPAN]; CHANNELS];
        self.radiance(gx, gy, &mut radiance);
        for (i, px) in out[..CHANNELS * n].chunks_exact_mut(CHANNELS).enumerate() {
            let flat = (gx[i] == 0.0 && gy[i] == 0.0) || !(gx[i].is_finite() && gy[i].is_finite());
            for k in 0..CHANNELS {
                let v = self.background[k] + self.gain[k] * (radiance[k][i] - self.flat[k]);
                px[k] = if flat {
                    self.background[k]
                } else {
                    v.clamp(0.0, FULL_SCALE)
                };
            }
        }
    }
}

/// How a model colours a span of pixels of one row from their depth gradients.
trait SpanShader {
    /// Writes the colours of pixels `start..start + n` of row `row`, whose depth gradients
    /// are `(gx[i], gy[i])` (`n` values each), into `out` (3 values per pixel).
    fn shade_span(&self, row: usize, start: usize, gx: &[f64], gy: &[f64], out: &mut [f64]);
}

impl SpanShader for Shader {
    #[inline(always)]
    fn shade_span(&self, _row: usize, _start: usize, gx: &[f64], gy: &[f64], out: &mut [f64]) {
        self.shade(gx, gy, out);
    }
}

impl SpanShader for CalibratedOptics {
    #[inline(always)]
    fn shade_span(&self, row: usize, start: usize, gx: &[f64], gy: &[f64], out: &mut [f64]) {
        self.shade(row, start, gx, gy, out);
    }
}

/// `x^e` in place, for each `x` in `[0, 1]`, by repeated squaring (`powi` with an exponent
/// known only at run time is a library call per value); 1 for `e <= 0`.
#[inline(always)]
fn pow(x: &mut [f64], e: i32) {
    let mut base = [0.0; SPAN];
    let n = x.len();
    base[..n].copy_from_slice(x);
    x.fill(1.0);
    let mut e = e.max(0) as u32;
    while e > 0 {
        if e & 1 == 1 {
            for i in 0..n {
                x[i] *= base[i];
            }
        }
        for b in &mut base[..n] {
            *b *= *b;
        }
        e >>= 1;
    }
}

/// Renders the RGB image of the depth image `depth` (m, positive into the gel, row-major
/// `(H, W)` on `grid`) seen through `optics` into `out` (row-major `(H, W, 3)`, 0 to 255).
/// Allocates nothing.
///
/// # Panics
/// If `depth` does not hold `H * W` values or `out` `3 * H * W`.
pub fn render(optics: &Optics, grid: &PixelGrid, depth: &[f64], out: &mut [f64]) {
    shade_image(&Shader::new(optics), grid, depth, out);
}

/// Renders the RGB image of the depth image `depth` (as [`render`]) through the calibrated
/// model `optics`: at each pixel its background plus the table's colour change at the
/// pixel's depth gradient (of the depth blurred by the optics' [`CalibratedOptics::blur`]
/// first, [`blur_depth`]), clamped to `[0, 255]`; the background where the surface is flat
/// or the gradient not finite. Allocates nothing, unless the optics blur (then the blurred
/// image).
///
/// # Panics
/// If `depth` does not hold `H * W` values, `out` `3 * H * W`, or the background is not
/// `W x H` pixels (resample it first, [`CalibratedOptics::resampled`]).
pub fn render_calibrated(
    optics: &CalibratedOptics,
    grid: &PixelGrid,
    depth: &[f64],
    out: &mut [f64],
) {
    let b = optics.background();
    assert_eq!(
        (b.width, b.height),
        (grid.width, grid.height),
        "background of the image's size"
    );
    if optics.blur() > 0.0 {
        let mut blurred = Vec::new();
        blur_depth(grid, depth, optics.blur(), &mut blurred);
        shade_image(optics, grid, &blurred, out);
    } else {
        shade_image(optics, grid, depth, out);
    }
}

/// The depth image `depth` on `grid` (row-major) blurred by a Gaussian of standard
/// deviation `sigma` (m) into `out` (resized): separable, each axis in its own pixel
/// pitch, truncated at three standard deviations, its weights renormalised over the
/// pixels inside the image with a finite depth (so a flat image stays flat and the edges
/// are not darkened); non-finite pixels count as missing. A blur of under a hundredth of
/// a pixel along an axis leaves that axis as it is.
pub fn blur_depth(grid: &PixelGrid, depth: &[f64], sigma: f64, out: &mut Vec<f64>) {
    let (w, h) = (grid.width, grid.height);
    assert_eq!(depth.len(), w * h, "depth image of {w} x {h} pixels");
    // The kernel along an axis of `n` pixels over `fov`: its taps from -reach to reach.
    let kernel = |fov: f64, n: usize| -> Vec<f64> {
        let s = sigma / (fov / n.max(1) as f64);
        if !(s >= 0.01) {
            return vec![1.0];
        }
        let reach = (3.0 * s).ceil() as usize;
        (0..=2 * reach)
            .map(|k| (-0.5 * ((k as f64 - reach as f64) / s).powi(2)).exp())
            .collect()
    };
    let (kx, ky) = (kernel(grid.fov_x, w), kernel(grid.fov_y, h));
    // Each position's taps inside the line of `n` (`lo..=hi` of the kernel) and its
    // weights' reciprocal sum there.
    let taps = |k: &[f64], n: usize| -> Vec<(usize, usize, f64)> {
        let reach = k.len() / 2;
        (0..n)
            .map(|i| {
                let lo = reach.saturating_sub(i);
                let hi = (reach + (n - 1 - i)).min(k.len() - 1);
                (lo, hi, 1.0 / k[lo..=hi].iter().sum::<f64>())
            })
            .collect()
    };
    out.clear();
    out.resize(w * h, 0.0);
    if !depth.iter().all(|v| v.is_finite()) {
        blur_missing(depth, w, h, &kx, &ky, out);
        return;
    }
    // Along the rows, then down the columns a whole row at a time.
    let mut rows = vec![0.0; w * h];
    let (tx, ty) = (taps(&kx, w), taps(&ky, h));
    let (rx, ry) = (kx.len() / 2, ky.len() / 2);
    for (line, to) in depth.chunks_exact(w).zip(rows.chunks_exact_mut(w)) {
        for (i, (v, &(lo, hi, norm))) in to.iter_mut().zip(&tx).enumerate() {
            let from = &line[i + lo - rx..=i + hi - rx];
            *v = kx[lo..=hi]
                .iter()
                .zip(from)
                .map(|(k, d)| k * d)
                .sum::<f64>()
                * norm;
        }
    }
    for (r, (to, &(lo, hi, norm))) in out.chunks_exact_mut(w).zip(&ty).enumerate() {
        for k in lo..=hi {
            let from = &rows[(r + k - ry) * w..(r + k - ry + 1) * w];
            let wk = ky[k] * norm;
            for (v, d) in to.iter_mut().zip(from) {
                *v += wk * d;
            }
        }
    }
}

/// [`blur_depth`] of an image with non-finite pixels: they count as missing (each
/// pixel's weights renormalised over the finite ones; a pixel with none is NaN).
fn blur_missing(depth: &[f64], w: usize, h: usize, kx: &[f64], ky: &[f64], out: &mut [f64]) {
    // One pass along rows (`stride` 1) or columns (`stride` w) from `from` into `to`.
    let pass = |from: &[f64], to: &mut [f64], k: &[f64], along: usize, stride: usize| {
        let reach = (k.len() / 2) as isize;
        let lines = from.len() / along.max(1);
        for line in 0..lines {
            let at = |i: usize| {
                if stride == 1 {
                    line * along + i
                } else {
                    i * stride + line
                }
            };
            for i in 0..along {
                let (mut sum, mut weight) = (0.0, 0.0);
                let lo = (i as isize - reach).max(0) as usize;
                let hi = ((i as isize + reach) as usize).min(along - 1);
                for j in lo..=hi {
                    let v = from[at(j)];
                    if v.is_finite() {
                        let wk = k[(j as isize - i as isize + reach) as usize];
                        sum += wk * v;
                        weight += wk;
                    }
                }
                to[at(i)] = if weight > 0.0 { sum / weight } else { f64::NAN };
            }
        }
    };
    let mut rows = vec![0.0; w * h];
    pass(depth, &mut rows, kx, w, 1);
    pass(&rows, out, ky, h, w);
}

/// The optical model of a sensor's `rgb` output: the built-in shading, or a calibration
/// (the `optics` attribute) loaded and resampled to the sensor's image when it was
/// configured.
#[derive(Clone, Debug, PartialEq)]
pub enum RgbModel {
    /// The built-in three-light shading.
    BuiltIn(Optics),
    /// A calibrated gradient-to-colour table over a background of the image's size.
    Calibrated(Arc<CalibratedOptics>),
}

impl Default for RgbModel {
    fn default() -> Self {
        RgbModel::BuiltIn(Optics::default())
    }
}

impl RgbModel {
    /// Renders the RGB image of `depth` on `grid` into `out` ([`render`],
    /// [`render_calibrated`]).
    pub fn render(&self, grid: &PixelGrid, depth: &[f64], out: &mut [f64]) {
        match self {
            RgbModel::BuiltIn(optics) => render(optics, grid, depth, out),
            RgbModel::Calibrated(optics) => render_calibrated(optics, grid, depth, out),
        }
    }
}

/// The gradient pass both models share: central differences of the depth image (one-sided
/// on its border), handed to `shader` a span of a row at a time.
fn shade_image<S: SpanShader>(shader: &S, grid: &PixelGrid, depth: &[f64], out: &mut [f64]) {
    let (w, h) = (grid.width, grid.height);
    assert_eq!(depth.len(), w * h, "depth image of {w} x {h} pixels");
    assert_eq!(out.len(), CHANNELS * w * h, "rgb image of {w} x {h} pixels");
    if w == 0 || h == 0 {
        return;
    }
    // Reciprocal spacings of central and one-sided differences (0 along an axis of one
    // pixel: no slope can be seen along it).
    let spacing = |fov: f64, n: usize| {
        let p = fov / n as f64;
        match n {
            1 => (0.0, 0.0),
            2 => (0.0, 1.0 / p),
            _ => (0.5 / p, 1.0 / p),
        }
    };
    let (cx, ox) = spacing(grid.fov_x, w);
    let (cy, oy) = spacing(grid.fov_y, h);
    let (mut gx, mut gy) = ([0.0; SPAN], [0.0; SPAN]);
    for r in 0..h {
        // Row r - 1 is towards +y.
        let (above, below, sy) = match (r > 0, r + 1 < h) {
            (true, true) => (r - 1, r + 1, cy),
            (false, true) => (r, r + 1, oy),
            (true, false) => (r - 1, r, oy),
            (false, false) => (r, r, 0.0),
        };
        let row = &depth[r * w..(r + 1) * w];
        let up = &depth[above * w..(above + 1) * w];
        let down = &depth[below * w..(below + 1) * w];
        let pixels = &mut out[CHANNELS * r * w..CHANNELS * (r + 1) * w];
        for start in (0..w).step_by(SPAN) {
            let end = (start + SPAN).min(w);
            let n = end - start;
            for (g, (u, d)) in gy
                .iter_mut()
                .zip(up[start..end].iter().zip(&down[start..end]))
            {
                *g = (u - d) * sy;
            }
            // Central differences inside the row, one-sided at its ends.
            let (lo, hi) = (start.max(1), end.min(w - 1));
            for c in lo..hi {
                gx[c - start] = (row[c + 1] - row[c - 1]) * cx;
            }
            if w == 1 {
                gx[0] = 0.0;
            } else {
                if start == 0 {
                    gx[0] = (row[1] - row[0]) * ox;
                }
                if end == w {
                    gx[n - 1] = (row[w - 1] - row[w - 2]) * ox;
                }
            }
            shader.shade_span(
                r,
                start,
                &gx[..n],
                &gy[..n],
                &mut pixels[CHANNELS * start..CHANNELS * (start + n)],
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use super::*;

    /// A square image of `n` x `n` pixels of `pixel` metres, centred on the sensor origin.
    fn grid(n: usize, pixel: f64) -> PixelGrid {
        PixelGrid {
            width: n,
            height: n,
            fov_x: n as f64 * pixel,
            fov_y: n as f64 * pixel,
        }
    }

    /// The depth image of `f(x, y)` on `g`.
    fn image(g: &PixelGrid, f: impl Fn(f64, f64) -> f64) -> Vec<f64> {
        let mut d = Vec::with_capacity(g.width * g.height);
        for r in 0..g.height {
            for c in 0..g.width {
                d.push(f(g.x(c), g.y(r)));
            }
        }
        d
    }

    fn rgb(optics: &Optics, g: &PixelGrid, depth: &[f64]) -> Vec<f64> {
        let mut out = vec![f64::NAN; CHANNELS * depth.len()];
        render(optics, g, depth, &mut out);
        out
    }

    /// Surface displacement of an elastic half-space pressed `a^2 / radius` deep by a
    /// sphere of `radius` with contact radius `a`, centred at `(x0, y0)` (Hertz; Johnson,
    /// Contact Mechanics, eq. 3.42): a spherical cap inside the contact, a smooth sag
    /// outside, with a continuous slope.
    fn hertz(radius: f64, a: f64, x0: f64, y0: f64) -> impl Fn(f64, f64) -> f64 {
        move |x, y| {
            let r = (x - x0).hypot(y - y0);
            if r <= a {
                a * a / radius - r * r / (2.0 * radius)
            } else {
                ((2.0 * a * a - r * r) * (a / r).asin() + a * (r * r - a * a).sqrt())
                    / (PI * radius)
            }
        }
    }

    /// Bilinear sample of channel `k` of `img` on `g` at the sensor-frame point `(x, y)`;
    /// `None` outside the pixel centres.
    fn sample(img: &[f64], g: &PixelGrid, x: f64, y: f64, k: usize) -> Option<f64> {
        let px = g.fov_x / g.width as f64;
        let py = g.fov_y / g.height as f64;
        let c = (x + 0.5 * g.fov_x) / px - 0.5;
        let r = (0.5 * g.fov_y - y) / py - 0.5;
        if c < 0.0 || r < 0.0 || c > (g.width - 1) as f64 || r > (g.height - 1) as f64 {
            return None;
        }
        let (c0, r0) = (
            (c.floor() as usize).min(g.width - 2),
            (r.floor() as usize).min(g.height - 2),
        );
        let (fc, fr) = (c - c0 as f64, r - r0 as f64);
        let at = |r: usize, c: usize| img[CHANNELS * (r * g.width + c) + k];
        Some(
            (1.0 - fr) * ((1.0 - fc) * at(r0, c0) + fc * at(r0, c0 + 1))
                + fr * ((1.0 - fc) * at(r0 + 1, c0) + fc * at(r0 + 1, c0 + 1)),
        )
    }

    /// Largest colour change from the background over the image.
    fn largest_change(img: &[f64], background: [f64; 3]) -> f64 {
        img.iter()
            .enumerate()
            .map(|(i, v)| (v - background[i % CHANNELS]).abs())
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_flat_gel_renders_exactly_the_background() {
        let optics = Optics::default();
        let g = grid(17, 1e-4);
        // Undeformed, and pressed uniformly (a flat surface at any depth).
        for level in [0.0, 0.7e-3] {
            let img = rgb(&optics, &g, &vec![level; 17 * 17]);
            for px in img.chunks(CHANNELS) {
                assert_eq!(px, optics.background);
            }
        }
        // Images of one row, one column and one pixel.
        for (w, h) in [(5, 1), (1, 5), (1, 1), (2, 2)] {
            let g = PixelGrid {
                width: w,
                height: h,
                fov_x: 1e-3,
                fov_y: 1e-3,
            };
            let img = rgb(&optics, &g, &vec![1e-4; w * h]);
            assert!(img.chunks(CHANNELS).all(|px| px == optics.background));
        }
    }

    #[test]
    fn a_dent_is_lit_on_the_side_nearer_each_light() {
        // Default: red at +y (the image's top), green at 210 degrees, blue at 330.
        let optics = Optics::default();
        let g = grid(81, 0.05e-3);
        let img = rgb(&optics, &g, &image(&g, hertz(5e-3, 1e-3, 0.0, 0.0)));
        let bg = optics.background;
        for (k, light) in optics.lights.iter().enumerate() {
            let (dx, dy) = (light.direction.x, light.direction.y);
            let s = 0.8e-3 / dx.hypot(dy);
            let near = sample(&img, &g, s * dx, s * dy, k).unwrap();
            let far = sample(&img, &g, -s * dx, -s * dy, k).unwrap();
            assert!(near > bg[k] + 5.0, "channel {k}: {near} near its light");
            assert!(far < bg[k] - 5.0, "channel {k}: {far} away from its light");
        }
    }

    /// Compares `img` at every pixel with `other` sampled at the pixel's centre rotated by
    /// `angle` about the origin, channel `k` of `img` against channel `map[k]` of `other`;
    /// returns the largest difference.
    fn rotation_error(
        g: &PixelGrid,
        img: &[f64],
        other: &[f64],
        angle: f64,
        map: [usize; 3],
        skip: impl Fn(f64) -> bool,
    ) -> f64 {
        let (s, c) = angle.sin_cos();
        let mut worst: f64 = 0.0;
        let mut compared = 0;
        for r in 0..g.height {
            for col in 0..g.width {
                let (x, y) = (g.x(col), g.y(r));
                if skip(x.hypot(y)) {
                    continue;
                }
                for k in 0..CHANNELS {
                    if let Some(v) = sample(other, g, c * x - s * y, s * x + c * y, map[k]) {
                        worst = worst.max((img[CHANNELS * (r * g.width + col) + k] - v).abs());
                        compared += 1;
                    }
                }
            }
        }
        assert!(compared > g.width * g.height, "{compared} samples compared");
        worst
    }

    #[test]
    fn a_spherical_dent_under_rotationally_symmetric_lights_is_rotationally_symmetric() {
        // A sphere's dent (contact radius 1.2 mm, 24 pixels of 0.05 mm; slopes up to 0.24).
        let (a, pixel) = (1.2e-3, 0.05e-3);
        let g = grid(121, pixel);
        let depth = image(&g, hertz(5e-3, a, 0.0, 0.0));
        // The surface's curvature is singular at the contact edge (the slope goes as
        // sqrt(r - a) outside it), where central differences and the bilinear sample of the
        // rotated point are not second-order accurate: pixels within 3 of it are not
        // compared. Elsewhere both errors are O(h^2) times the image's curvature: measured
        // 0.5 % (white lights) and 0.4 % (coloured) of the largest colour change. Light sets
        // that are not symmetric fail by far more: one light 5 degrees off in azimuth by
        // 94 % (white) and 7 % (coloured), 2 degrees lower by 16 % (white), a tenth dimmer
        // by 3.5 % (coloured).
        let compare = |optics: &Optics, angle: f64, map: [usize; 3]| {
            let img = rgb(optics, &g, &depth);
            let change = largest_change(&img, optics.background);
            let err = rotation_error(&g, &img, &img, angle, map, |r| (r - a).abs() < 3.0 * pixel);
            (err, change)
        };
        // Three white lights 120 degrees apart: a 120-degree rotation maps the light set
        // onto itself, so it must map the image of a centred dent onto itself.
        let e = 30f64.to_radians();
        let white = Optics {
            lights: [0.3, 0.3 + 2.0 * PI / 3.0, 0.3 + 4.0 * PI / 3.0]
                .map(|az| Light::at(az, e, [1.0 / 3.0; 3])),
            background: [128.0; 3],
            ..Optics::default()
        };
        for angle in [2.0 * PI / 3.0, -2.0 * PI / 3.0] {
            let (err, change) = compare(&white, angle, [0, 1, 2]);
            assert!(
                err < 0.015 * change,
                "white, {angle:.2} rad: {err} of {change}"
            );
        }
        // The default red, green and blue lights over an equal background: a rotation by
        // 120 degrees turns each light into the next (red at 90 degrees onto green at 210,
        // green onto blue at 330, blue onto red), so the green image at p is the red image
        // at p rotated by -120 degrees: it permutes the channels.
        let coloured = Optics {
            background: [128.0; 3],
            ..Optics::default()
        };
        let (err, change) = compare(&coloured, -2.0 * PI / 3.0, [2, 0, 1]);
        assert!(err < 0.015 * change, "coloured: {err} of {change}");
        let (unpermuted, _) = compare(&coloured, -2.0 * PI / 3.0, [0, 1, 2]);
        assert!(unpermuted > 0.5 * change, "{unpermuted} of {change}");
    }

    #[test]
    fn a_mirrored_light_set_gives_the_mirrored_image() {
        let optics = Optics::default();
        // Wider than one span of pixels shaded together, not a multiple of it.
        let n = SPAN + 6;
        let g = grid(n, 0.06e-3);
        // An asymmetric surface: an off-centre dent and a tilt.
        let dent = hertz(4e-3, 0.8e-3, 0.4e-3, -0.25e-3);
        let depth = image(&g, |x, y| dent(x, y) + 0.05 * x.max(0.0) + 0.02 * y);
        let img = rgb(&optics, &g, &depth);
        let at = |img: &[f64], r: usize, c: usize, k: usize| img[CHANNELS * (r * n + c) + k];
        // Mirror x -> -x (columns reversed) and y -> -y (rows reversed).
        for (flip_x, flip_y) in [(true, false), (false, true)] {
            let mut mirrored = optics;
            for l in &mut mirrored.lights {
                if flip_x {
                    l.direction.x = -l.direction.x;
                }
                if flip_y {
                    l.direction.y = -l.direction.y;
                }
            }
            let src = |r: usize, c: usize| {
                (
                    if flip_y { n - 1 - r } else { r },
                    if flip_x { n - 1 - c } else { c },
                )
            };
            let mut flipped = vec![0.0; n * n];
            for r in 0..n {
                for c in 0..n {
                    let (sr, sc) = src(r, c);
                    flipped[r * n + c] = depth[sr * n + sc];
                }
            }
            let out = rgb(&mirrored, &g, &flipped);
            assert!(largest_change(&out, optics.background) > 10.0);
            for r in 0..n {
                for c in 0..n {
                    let (sr, sc) = src(r, c);
                    for k in 0..CHANNELS {
                        let (a, b) = (at(&out, r, c, k), at(&img, sr, sc, k));
                        assert!((a - b).abs() < 1e-9, "({r}, {c}) channel {k}: {a} vs {b}");
                    }
                }
            }
        }
    }

    #[test]
    fn the_colour_change_grows_with_the_slope() {
        let optics = Optics::default();
        let g = grid(9, 0.1e-3);
        let centre = CHANNELS * (4 * 9 + 4);
        for step in 0..24 {
            let azimuth = step as f64 * PI / 12.0;
            let (s, c) = azimuth.sin_cos();
            let mut last = 0.0;
            // Slopes up to 0.55 (29 degrees), below the lights' elevation of 30 degrees.
            for i in 1..=11 {
                let slope = 0.05 * i as f64;
                let img = rgb(&optics, &g, &image(&g, |x, y| slope * (c * x + s * y)));
                let change = (0..CHANNELS)
                    .map(|k| (img[centre + k] - optics.background[k]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                assert!(
                    change > last,
                    "azimuth {azimuth:.2}: slope {slope} changes the colour by {change}, \
                     less than {last} at a gentler slope"
                );
                if i == 1 {
                    // A slope of 0.05 (3 degrees) is visible: several grey levels.
                    assert!(change > 3.0, "azimuth {azimuth:.2}: {change} at slope 0.05");
                }
                last = change;
            }
        }
    }

    /// The depth blur: no blur leaves the image as it is; a flat image stays flat to
    /// round-off, edges included; a Gaussian bump of standard deviation `s0` blurred by
    /// `s` is the Gaussian of variance `s0^2 + s^2` holding the same volume (its peak
    /// `s0^2 / (s0^2 + s^2)` of the bump's), to the sampling's error; pixels of another
    /// pitch along y take the blur in their own pitch.
    #[test]
    fn the_depth_blur_is_a_gaussian_in_metres() {
        let g = PixelGrid {
            width: 120,
            height: 60,
            fov_x: 12e-3,
            fov_y: 12e-3,
        };
        let (px, py) = (g.fov_x / 120.0, g.fov_y / 60.0);
        let mut out = Vec::new();
        let ramp: Vec<f64> = (0..g.width * g.height).map(|i| i as f64 * 1e-7).collect();
        blur_depth(&g, &ramp, 0.0, &mut out);
        assert_eq!(out, ramp);
        let flat = vec![3e-4; g.width * g.height];
        blur_depth(&g, &flat, 0.5e-3, &mut out);
        assert!(
            out.iter().all(|v| (v - 3e-4).abs() < 1e-18),
            "a flat image moved"
        );
        let (s0, s) = (0.4e-3, 0.3e-3);
        let bump = image(&g, |x, y| 1e-4 * (-(x * x + y * y) / (2.0 * s0 * s0)).exp());
        blur_depth(&g, &bump, s, &mut out);
        let peak = out.iter().copied().fold(0.0, f64::max);
        // (The pixels nearest the centre lie half a pixel from it along each axis.)
        let sd = (s0 * s0 + s * s).sqrt();
        let off = (0.25 * (px * px + py * py)) / (2.0 * sd * sd);
        let expected = 1e-4 * s0 * s0 / (sd * sd) * (-off).exp();
        assert!(
            (peak / expected - 1.0).abs() < 0.01,
            "peak {peak} against {expected}"
        );
        let volume = |v: &[f64]| v.iter().sum::<f64>() * px * py;
        assert!((volume(&out) / volume(&bump) - 1.0).abs() < 1e-9);
        // A non-finite pixel counts as missing: its neighbours stay finite, and elsewhere
        // the image is what the finite image's blur gives.
        let mut holed = bump.clone();
        holed[5 * g.width + 7] = f64::NAN;
        let mut around = Vec::new();
        blur_depth(&g, &holed, s, &mut around);
        assert!(around.iter().all(|v| v.is_finite()));
        let far = out
            .iter()
            .zip(&around)
            .enumerate()
            .filter(|(i, _)| i / g.width > 20)
            .map(|(_, (a, b))| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(far < 1e-18, "{far}");
        // Across the blurred bump's centre, along x and along y, its width in metres.
        let (r0, c0) = (g.height / 2, g.width / 2);
        for (k, step) in [(1usize, px), (g.width, py)] {
            let centre = r0 * g.width + c0;
            let n = (sd / step).round() as usize;
            let measured = out[centre - n * k] / out[centre];
            let d = n as f64 * step;
            // Pixel centres sit half a pixel from the bump's centre along each axis.
            let predicted = (-(d * d - d * step) / (2.0 * sd * sd)).exp();
            assert!(
                (measured / predicted - 1.0).abs() < 0.02,
                "stride {k}: {measured} against {predicted}"
            );
        }
    }

    #[test]
    fn non_finite_depth_counts_as_flat_and_never_leaks() {
        let optics = Optics::default();
        let n = 41;
        let g = grid(n, 0.05e-3);
        let mut depth = image(&g, hertz(5e-3, 0.7e-3, 0.0, 0.0));
        let clean = rgb(&optics, &g, &depth);
        assert!(clean
            .iter()
            .all(|v| v.is_finite() && (0.0..=FULL_SCALE).contains(v)));
        // One bad pixel on the dent's slope: its four neighbours read it and show the
        // background; every other pixel is unchanged.
        let (r0, c0) = (20, 28);
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            depth[r0 * n + c0] = bad;
            let img = rgb(&optics, &g, &depth);
            for r in 0..n {
                for c in 0..n {
                    let px = &img[CHANNELS * (r * n + c)..CHANNELS * (r * n + c + 1)];
                    if r.abs_diff(r0) + c.abs_diff(c0) == 1 {
                        assert_eq!(px, optics.background, "({r}, {c}) next to {bad}");
                    } else {
                        assert_eq!(
                            px,
                            &clean[CHANNELS * (r * n + c)..CHANNELS * (r * n + c + 1)]
                        );
                    }
                }
            }
        }
        // Nothing finite at all: the background everywhere.
        let img = rgb(&optics, &g, &vec![f64::NAN; n * n]);
        assert!(img.chunks(CHANNELS).all(|px| px == optics.background));
    }
}
