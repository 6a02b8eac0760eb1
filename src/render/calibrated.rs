//! Calibrated optics of the `rgb` output: the colour of a pixel as a lookup from the
//! surface's slope there, over a background image (the method of Taxim, Si and Yuan 2022).
//!
//! A GelSight camera sees the membrane lit from the sides: at a pixel, the colour change
//! against the undeformed gel depends on the surface normal there, hence on the surface
//! gradient `(gx, gy)`, and little else. A calibration measures that dependence with ball
//! presses, where the gradient is known analytically inside the contact (`tacrom
//! calibrate`). The model here renders
//!
//! ```text
//! colour[k] = clamp(background[k](pixel) + table[k](gx, gy), 0, 255)
//! ```
//!
//! with `table` looked up bilinearly between its nodes and clamped to its range, and the
//! background exactly where the surface is flat (`gx = gy = 0`) or its gradient is not
//! finite.
//!
//! **Gradient.** `(gx, gy) = (dd/dx, dd/dy)`, `d` the indentation depth (positive into
//! the gel: the height of the deformed surface towards the camera), x and y of the sensor
//! frame: x towards higher columns, y towards lower rows (row 0 is the +y edge). It is a
//! slope (metres per metre), so a table applies at any pixel size; the renderer takes it
//! from central differences of the depth image, as the built-in model does
//! ([`super::rgb`]).
//!
//! **Background.** An RGB image of the undeformed gel covering the sensor's field of view.
//! The sensor resamples it bilinearly to its own resolution ([`CalibratedOptics::resampled`],
//! pixel centres aligned, edges clamped), once, when the sensor is configured.
//!
//! # File format
//!
//! One JSON file (`optics` attribute) and a PNG beside it:
//!
//! ```json
//! {
//!   "format": "tacrom.optics",
//!   "version": 1,
//!   "background": "optics.background.png",
//!   "bins": [41, 41],
//!   "range": [0.72, 0.72],
//!   "table": [[[-3.1, 5.0, -1.9], "... bins[0] entries ..."], "... bins[1] rows ..."]
//! }
//! ```
//!
//! * `background`: the PNG (8 or 16 bits per channel, grey or colour, alpha ignored), a
//!   path relative to the JSON file's folder;
//! * `bins = [nx, ny]`: nodes of the table along gx and gy, each 2 to [`MAX_BINS`];
//! * `range = [Gx, Gy]`: the nodes span `[-Gx, Gx] x [-Gy, Gy]` evenly, node `(i, j)` at
//!   `gx = -Gx + 2 Gx i / (nx - 1)`, `gy = -Gy + 2 Gy j / (ny - 1)`; positive and finite;
//! * `table[j][i] = [dr, dg, db]`: the colour change at node `(i, j)` on the 0..255 scale,
//!   `ny` rows of `nx` entries, each finite and within +-255;
//! * `blur` (optional, metres, default 0): the standard deviation of a Gaussian blur of
//!   the depth image before its gradient is taken ([`super::rgb::blur_depth`]): what the
//!   camera's focus and the membrane's coating smooth of a real imprint (its contact edge
//!   shows no rim). Finite, from 0 to [`MAX_BLUR`]; the table is fitted through the same
//!   blur (`tacrom calibrate --blur`);
//! * other keys (`calibration`: how the table was made) are ignored.

use std::fmt;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{CHANNELS, FULL_SCALE};

/// The `format` value of an optics file.
pub const FORMAT: &str = "tacrom.optics";
/// The `version` of the format this build reads and writes.
pub const VERSION: u32 = 1;
/// Most nodes of a table along one axis.
pub const MAX_BINS: usize = 1025;
/// Largest background image side accepted (pixels).
pub const MAX_BACKGROUND_SIDE: u32 = 16384;
/// Largest `blur` accepted (m): a millimetre, several times a GelSight's imprint detail.
pub const MAX_BLUR: f64 = 1e-3;

/// An optics file as stored (see the module documentation).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct OpticsFile {
    /// Always [`FORMAT`].
    pub format: String,
    /// Always [`VERSION`].
    pub version: u32,
    /// The background PNG, relative to the JSON file's folder.
    pub background: String,
    /// Nodes along gx and gy.
    pub bins: [usize; 2],
    /// Half extents of the table along gx and gy (slopes).
    pub range: [f64; 2],
    /// `table[j][i]`: colour change at node `(i, j)`.
    pub table: Vec<Vec<[f64; 3]>>,
    /// Standard deviation of the depth image's Gaussian blur before shading (m; 0: none).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub blur: f64,
    /// How the table was made (presses, fit, held-out errors): not read by the sensor.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<serde_json::Value>,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// Why an optics file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum OpticsError {
    /// The file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// Not JSON, or not the format's structure.
    #[error("{} is not an optics file: {source}", path.display())]
    Json {
        /// The file.
        path: PathBuf,
        /// Where and what.
        source: serde_json::Error,
    },
    /// Well-formed, but its values are not valid.
    #[error("{}: {reason}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The background image is missing or not a PNG.
    #[error("background image {}: {reason}", path.display())]
    Background {
        /// The image.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The file or its background could not be written.
    #[error("cannot write {}: {reason}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// What the system said.
        reason: String,
    },
}

impl OpticsError {
    /// What is wrong, without the optics file's own path (for a message that names it
    /// already); the background image's path is kept.
    pub fn reason(&self) -> String {
        match self {
            OpticsError::Read { source, .. } => format!("cannot read it: {source}"),
            OpticsError::Json { source, .. } => match source.classify() {
                serde_json::error::Category::Syntax => format!(
                    "not an optics file: {source} (JSON numbers are finite: no NaN, no \
                     Infinity)"
                ),
                _ => format!("not an optics file: {source}"),
            },
            OpticsError::Invalid { reason, .. } => reason.clone(),
            OpticsError::Background { .. } => self.to_string(),
            OpticsError::Write { reason, .. } => format!("cannot write it: {reason}"),
        }
    }
}

/// An RGB image with values on the 0..255 scale, row-major `(H, W, 3)`.
#[derive(Clone, PartialEq)]
pub struct RgbImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `3 * width * height` values, red, green, blue per pixel.
    pub data: Vec<f64>,
}

impl fmt::Debug for RgbImage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "RgbImage({} x {})", self.width, self.height)
    }
}

impl RgbImage {
    /// An image of one colour.
    pub fn uniform(width: usize, height: usize, colour: [f64; 3]) -> RgbImage {
        RgbImage {
            width,
            height,
            data: colour.repeat(width * height),
        }
    }

    /// The colour of pixel `(row, col)`.
    #[inline]
    pub fn pixel(&self, row: usize, col: usize) -> [f64; 3] {
        let at = CHANNELS * (row * self.width + col);
        [self.data[at], self.data[at + 1], self.data[at + 2]]
    }

    /// Reads a PNG (8 or 16 bits per channel, grey or colour; alpha ignored) on the 0..255
    /// scale (16-bit values divided by 257).
    pub fn read_png(path: &Path) -> Result<RgbImage, String> {
        let mut reader = image::ImageReader::open(path)
            .map_err(|e| e.to_string())?
            .with_guessed_format()
            .map_err(|e| e.to_string())?;
        if reader.format() != Some(image::ImageFormat::Png) {
            return Err("not a PNG file".into());
        }
        let mut limits = image::Limits::default();
        limits.max_image_width = Some(MAX_BACKGROUND_SIDE);
        limits.max_image_height = Some(MAX_BACKGROUND_SIDE);
        reader.limits(limits);
        let img = reader.decode().map_err(|e| e.to_string())?;
        let (w, h) = (img.width(), img.height());
        if w == 0 || h == 0 {
            return Err("an empty image".into());
        }
        let colour = img.color();
        let bytes_per_channel = colour.bytes_per_pixel() / colour.channel_count().max(1);
        let data: Vec<f64> = if bytes_per_channel >= 2 {
            img.to_rgb16()
                .into_raw()
                .into_iter()
                .map(|v| f64::from(v) / 257.0)
                .collect()
        } else {
            img.to_rgb8()
                .into_raw()
                .into_iter()
                .map(f64::from)
                .collect()
        };
        Ok(RgbImage {
            width: w as usize,
            height: h as usize,
            data,
        })
    }

    /// Writes a 16-bit RGB PNG (each value times 257, rounded; clamped to 0..255 first),
    /// which [`RgbImage::read_png`] reads back to within 1/514 of a grey level.
    pub fn write_png16(&self, path: &Path) -> Result<(), String> {
        let words: Vec<u16> = self
            .data
            .iter()
            .map(|v| (v.clamp(0.0, FULL_SCALE) * 257.0).round() as u16)
            .collect();
        let buffer: image::ImageBuffer<image::Rgb<u16>, Vec<u16>> =
            image::ImageBuffer::from_raw(self.width as u32, self.height as u32, words)
                .ok_or("image size does not match its data")?;
        buffer
            .save_with_format(path, image::ImageFormat::Png)
            .map_err(|e| e.to_string())
    }

    /// The image resampled to `width x height` pixels covering the same extent: bilinear,
    /// pixel centres aligned (output pixel `c` samples input coordinate
    /// `(c + 1/2) W_in / W - 1/2`, `c` at the centre of pixel `c`), clamped at the edges.
    /// The same size gives the image itself.
    pub fn resampled(&self, width: usize, height: usize) -> RgbImage {
        if (width, height) == (self.width, self.height) {
            return self.clone();
        }
        // Per output index along an axis: the lower input index and the weight of the upper.
        let taps = |n_out: usize, n_in: usize| -> Vec<(usize, f64)> {
            (0..n_out)
                .map(|o| {
                    if n_in < 2 {
                        return (0, 0.0);
                    }
                    let u = ((o as f64 + 0.5) * n_in as f64 / n_out as f64 - 0.5)
                        .clamp(0.0, (n_in - 1) as f64);
                    let i0 = (u.floor() as usize).min(n_in - 2);
                    (i0, u - i0 as f64)
                })
                .collect()
        };
        let (xs, ys) = (taps(width, self.width), taps(height, self.height));
        let mut data = Vec::with_capacity(CHANNELS * width * height);
        let next = |i: usize, n: usize| (i + 1).min(n - 1);
        for &(r0, fy) in &ys {
            let r1 = next(r0, self.height);
            for &(c0, fx) in &xs {
                let c1 = next(c0, self.width);
                let (a, b) = (self.pixel(r0, c0), self.pixel(r0, c1));
                let (c, d) = (self.pixel(r1, c0), self.pixel(r1, c1));
                for k in 0..CHANNELS {
                    let top = a[k] + fx * (b[k] - a[k]);
                    let bottom = c[k] + fx * (d[k] - c[k]);
                    data.push(top + fy * (bottom - top));
                }
            }
        }
        RgbImage {
            width,
            height,
            data,
        }
    }
}

/// The colour change per channel as a function of the surface gradient, on a regular grid
/// of nodes over `[-Gx, Gx] x [-Gy, Gy]`.
#[derive(Clone, PartialEq)]
pub struct GradientTable {
    bins: [usize; 2],
    range: [f64; 2],
    /// `values[CHANNELS * (j * nx + i) + k]`: channel `k` at node `(i, j)`.
    values: Vec<f64>,
    /// `(n - 1) / (2 G)` along gx and gy: nodes per unit slope.
    scale: [f64; 2],
}

impl fmt::Debug for GradientTable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "GradientTable({} x {} nodes over +-{} x +-{})",
            self.bins[0], self.bins[1], self.range[0], self.range[1]
        )
    }
}

impl GradientTable {
    /// A table of `bins = [nx, ny]` nodes over `[-range[0], range[0]] x [-range[1],
    /// range[1]]`, `values[3 * (j * nx + i) + k]` the change of channel `k` at node
    /// `(i, j)`; checked as the file's are.
    pub fn new(bins: [usize; 2], range: [f64; 2], values: Vec<f64>) -> Result<Self, String> {
        for (axis, (&n, &g)) in ["gx", "gy"].iter().zip(bins.iter().zip(&range)) {
            if !(2..=MAX_BINS).contains(&n) {
                return Err(format!(
                    "bins along {axis} = {n}; must be in 2..={MAX_BINS}"
                ));
            }
            if !(g.is_finite() && g > 0.0) {
                return Err(format!(
                    "range along {axis} = {g}; must be positive and finite"
                ));
            }
        }
        let expected = CHANNELS * bins[0] * bins[1];
        if values.len() != expected {
            return Err(format!(
                "{} table values for {} x {} nodes of {CHANNELS} channels; expected {expected}",
                values.len(),
                bins[0],
                bins[1]
            ));
        }
        if let Some(at) = values
            .iter()
            .position(|v| !(v.is_finite() && v.abs() <= FULL_SCALE))
        {
            let node = at / CHANNELS;
            return Err(format!(
                "table[{}][{}][{}] = {}; must be finite and within +-{FULL_SCALE}",
                node / bins[0],
                node % bins[0],
                at % CHANNELS,
                values[at]
            ));
        }
        let scale = [0, 1].map(|a| (bins[a] - 1) as f64 / (2.0 * range[a]));
        Ok(GradientTable {
            bins,
            range,
            values,
            scale,
        })
    }

    /// Nodes along gx and gy.
    pub fn bins(&self) -> [usize; 2] {
        self.bins
    }

    /// Half extents along gx and gy.
    pub fn range(&self) -> [f64; 2] {
        self.range
    }

    /// The node values, `values[3 * (j * nx + i) + k]`.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// The gradient `(gx, gy)` at node `(i, j)`.
    pub fn node_gradient(&self, i: usize, j: usize) -> [f64; 2] {
        [
            -self.range[0] + i as f64 / self.scale[0],
            -self.range[1] + j as f64 / self.scale[1],
        ]
    }

    /// The colour change at gradient `(gx, gy)`: bilinear between the four nodes around
    /// it, the gradient clamped to the table's range first.
    #[inline]
    pub fn lookup(&self, gx: f64, gy: f64) -> [f64; 3] {
        let [nx, ny] = self.bins;
        let locate = |g: f64, a: usize, n: usize| {
            let u = ((g + self.range[a]) * self.scale[a]).clamp(0.0, (n - 1) as f64);
            let i0 = (u as usize).min(n - 2);
            (i0, u - i0 as f64)
        };
        let (i0, fx) = locate(gx, 0, nx);
        let (j0, fy) = locate(gy, 1, ny);
        let at = CHANNELS * (j0 * nx + i0);
        let (a, b) = (&self.values[at..at + 6], &self.values[at + CHANNELS * nx..]);
        let mut out = [0.0; 3];
        for k in 0..CHANNELS {
            let low = a[k] + fx * (a[k + CHANNELS] - a[k]);
            let high = b[k] + fx * (b[k + CHANNELS] - b[k]);
            out[k] = low + fy * (high - low);
        }
        out
    }
}

/// A calibrated optical model: a [`GradientTable`] over a background image.
#[derive(Clone, PartialEq)]
pub struct CalibratedOptics {
    table: GradientTable,
    background: RgbImage,
    /// The depth image's blur before shading (m; 0: none).
    blur: f64,
    /// The file it was read from, for messages.
    source: Option<PathBuf>,
}

impl fmt::Debug for CalibratedOptics {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("CalibratedOptics")
            .field("table", &self.table)
            .field("background", &self.background)
            .field("blur", &self.blur)
            .field("source", &self.source)
            .finish()
    }
}

impl CalibratedOptics {
    /// The model of `table` over `background` (values finite, within 0..255).
    pub fn new(table: GradientTable, background: RgbImage) -> Result<Self, String> {
        let n = CHANNELS * background.width * background.height;
        if background.width == 0 || background.height == 0 || background.data.len() != n {
            return Err(format!(
                "background of {} x {} pixels with {} values",
                background.width,
                background.height,
                background.data.len()
            ));
        }
        if let Some(v) = background
            .data
            .iter()
            .find(|v| !(v.is_finite() && (0.0..=FULL_SCALE).contains(*v)))
        {
            return Err(format!("background value {v}; must be within 0..255"));
        }
        Ok(CalibratedOptics {
            table,
            background,
            blur: 0.0,
            source: None,
        })
    }

    /// The same model with the depth image blurred by a Gaussian of standard deviation
    /// `blur` (m) before shading; an error unless it is finite and within 0 to [`MAX_BLUR`].
    pub fn with_blur(self, blur: f64) -> Result<Self, String> {
        if !(blur.is_finite() && (0.0..=MAX_BLUR).contains(&blur)) {
            return Err(format!(
                "blur = {blur} m; must be finite and within 0 to {MAX_BLUR} m"
            ));
        }
        Ok(CalibratedOptics { blur, ..self })
    }

    /// The depth image's blur before shading (m; 0: none).
    pub fn blur(&self) -> f64 {
        self.blur
    }

    /// Reads an optics file and its background (see the module documentation), checking
    /// every value.
    pub fn load(path: &Path) -> Result<Self, OpticsError> {
        let text = std::fs::read_to_string(path).map_err(|source| OpticsError::Read {
            path: path.to_owned(),
            source,
        })?;
        let file: OpticsFile = serde_json::from_str(&text).map_err(|source| OpticsError::Json {
            path: path.to_owned(),
            source,
        })?;
        let invalid = |reason: String| OpticsError::Invalid {
            path: path.to_owned(),
            reason,
        };
        if file.format != FORMAT || file.version != VERSION {
            return Err(invalid(format!(
                "format \"{}\" version {}; this build reads \"{FORMAT}\" version {VERSION}",
                file.format, file.version
            )));
        }
        let [nx, ny] = file.bins;
        if let Some(n) = file.bins.iter().find(|n| !(2..=MAX_BINS).contains(*n)) {
            return Err(invalid(format!(
                "bins = [{nx}, {ny}]: {n} nodes along an axis; each must be in 2..={MAX_BINS}"
            )));
        }
        if file.table.len() != ny {
            return Err(invalid(format!(
                "table has {} rows; bins = [{nx}, {ny}] needs {ny} rows (one per gy node)",
                file.table.len()
            )));
        }
        if let Some((j, row)) = file.table.iter().enumerate().find(|(_, r)| r.len() != nx) {
            return Err(invalid(format!(
                "table row {j} has {} entries; bins = [{nx}, {ny}] needs {nx} (one per gx \
                 node)",
                row.len()
            )));
        }
        let values = file.table.iter().flatten().flatten().copied().collect();
        let table = GradientTable::new(file.bins, file.range, values).map_err(invalid)?;
        let folder = path.parent().unwrap_or(Path::new(""));
        let background_path = folder.join(&file.background);
        let background =
            RgbImage::read_png(&background_path).map_err(|reason| OpticsError::Background {
                path: background_path.clone(),
                reason,
            })?;
        let mut optics = CalibratedOptics::new(table, background)
            .and_then(|o| o.with_blur(file.blur))
            .map_err(invalid)?;
        optics.source = Some(path.to_owned());
        Ok(optics)
    }

    /// Writes the model to `path` (JSON) and its background beside it, as
    /// `<stem>.background.png` (16 bits per channel), with `calibration` recorded as how it
    /// was made.
    pub fn save(
        &self,
        path: &Path,
        calibration: Option<serde_json::Value>,
    ) -> Result<(), OpticsError> {
        let write_error = |p: &Path, reason: String| OpticsError::Write {
            path: p.to_owned(),
            reason,
        };
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "optics".into());
        let background_name = format!("{stem}.background.png");
        let background_path = path
            .parent()
            .unwrap_or(Path::new(""))
            .join(&background_name);
        self.background
            .write_png16(&background_path)
            .map_err(|e| write_error(&background_path, e))?;
        let [nx, ny] = self.table.bins;
        let table = (0..ny)
            .map(|j| {
                (0..nx)
                    .map(|i| {
                        let at = CHANNELS * (j * nx + i);
                        [0, 1, 2].map(|k| self.table.values[at + k])
                    })
                    .collect()
            })
            .collect();
        let file = OpticsFile {
            format: FORMAT.into(),
            version: VERSION,
            background: background_name,
            bins: self.table.bins,
            range: self.table.range,
            table,
            blur: self.blur,
            calibration,
        };
        let text =
            serde_json::to_string_pretty(&file).map_err(|e| write_error(path, e.to_string()))?;
        std::fs::write(path, text).map_err(|e| write_error(path, e.to_string()))
    }

    /// The same table over the background resampled to `width x height`
    /// ([`RgbImage::resampled`]).
    pub fn resampled(&self, width: usize, height: usize) -> Self {
        CalibratedOptics {
            table: self.table.clone(),
            background: self.background.resampled(width, height),
            blur: self.blur,
            source: self.source.clone(),
        }
    }

    /// The gradient table.
    pub fn table(&self) -> &GradientTable {
        &self.table
    }

    /// The background image.
    pub fn background(&self) -> &RgbImage {
        &self.background
    }

    /// The file it was read from, if any.
    pub fn source(&self) -> Option<&Path> {
        self.source.as_deref()
    }

    /// Writes the colours of the pixels `start..start + n` of row `row`, whose depth
    /// gradients are `(gx[i], gy[i])`, into `out` (3 values each): the background plus
    /// the table's change, clamped to 0..255; the background itself where the surface is
    /// flat or the gradient not finite.
    #[inline]
    pub(crate) fn shade(&self, row: usize, start: usize, gx: &[f64], gy: &[f64], out: &mut [f64]) {
        let n = gx.len();
        let at = CHANNELS * (row * self.background.width + start);
        let background = &self.background.data[at..at + CHANNELS * n];
        let out = &mut out[..CHANNELS * n];
        if gx.iter().chain(gy).all(|&g| g == 0.0) {
            out.copy_from_slice(background);
            return;
        }
        for (i, (px, bg)) in out
            .chunks_exact_mut(CHANNELS)
            .zip(background.chunks_exact(CHANNELS))
            .enumerate()
        {
            let (x, y) = (gx[i], gy[i]);
            if (x == 0.0 && y == 0.0) || !(x.is_finite() && y.is_finite()) {
                px.copy_from_slice(bg);
                continue;
            }
            let change = self.table.lookup(x, y);
            for k in 0..CHANNELS {
                px[k] = (bg[k] + change[k]).clamp(0.0, FULL_SCALE);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table whose change is `f(gx, gy)` at every node.
    fn table_of(
        bins: [usize; 2],
        range: [f64; 2],
        f: impl Fn(f64, f64) -> [f64; 3],
    ) -> GradientTable {
        let mut values = Vec::new();
        for j in 0..bins[1] {
            for i in 0..bins[0] {
                let gx = -range[0] + 2.0 * range[0] * i as f64 / (bins[0] - 1) as f64;
                let gy = -range[1] + 2.0 * range[1] * j as f64 / (bins[1] - 1) as f64;
                values.extend(f(gx, gy));
            }
        }
        GradientTable::new(bins, range, values).unwrap()
    }

    /// A scratch folder of this test process.
    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("tacrom-optics-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn the_lookup_is_exact_for_a_bilinear_change_and_clamps_outside_the_range() {
        // Bilinear in (gx, gy) per channel: the interpolation reproduces it to rounding.
        let f = |gx: f64, gy: f64| [10.0 * gx, -7.0 * gy + 3.0, 40.0 * gx * gy];
        let t = table_of([7, 5], [0.6, 0.4], f);
        for (gx, gy) in [
            (0.0, 0.0),
            (0.13, -0.37),
            (-0.6, 0.4),
            (0.5999, -0.1),
            (0.21, 0.33),
        ] {
            let (got, want) = (t.lookup(gx, gy), f(gx, gy));
            for k in 0..3 {
                assert!(
                    (got[k] - want[k]).abs() < 1e-12,
                    "({gx}, {gy}): {got:?} vs {want:?}"
                );
            }
        }
        // Beyond the range: the value at the nearest point of the range's edge.
        assert_eq!(t.lookup(5.0, -9.0), t.lookup(0.6, -0.4));
        assert_eq!(t.lookup(-1.0, 0.1), t.lookup(-0.6, 0.1));
        // Nodes where they should be.
        assert_eq!(t.node_gradient(0, 0), [-0.6, -0.4]);
        let top = t.node_gradient(6, 4);
        assert!((top[0] - 0.6).abs() < 1e-15 && (top[1] - 0.4).abs() < 1e-15);
    }

    #[test]
    fn tables_with_bad_sizes_or_values_are_refused() {
        let ok = |bins: [usize; 2]| vec![0.0; 3 * bins[0] * bins[1]];
        assert!(GradientTable::new([1, 5], [0.5, 0.5], ok([1, 5])).is_err());
        assert!(GradientTable::new([5, 5], [0.0, 0.5], ok([5, 5])).is_err());
        assert!(GradientTable::new([5, 5], [0.5, f64::INFINITY], ok([5, 5])).is_err());
        assert!(GradientTable::new([5, 5], [0.5, 0.5], ok([5, 4])).is_err());
        let mut v = ok([5, 5]);
        v[3 * (2 * 5 + 1) + 2] = f64::NAN;
        let e = GradientTable::new([5, 5], [0.5, 0.5], v).unwrap_err();
        assert!(e.contains("table[2][1][2]") && e.contains("NaN"), "{e}");
    }

    #[test]
    fn resampling_keeps_the_image_at_its_size_and_a_linear_ramp_exactly() {
        // A ramp in both directions, each channel its own.
        let (w, h) = (40, 30);
        let mut data = Vec::new();
        for r in 0..h {
            for c in 0..w {
                let (x, y) = (c as f64, r as f64);
                data.extend([2.0 * x + y, 200.0 - 3.0 * y, 50.0 + x + 0.5 * y]);
            }
        }
        let img = RgbImage {
            width: w,
            height: h,
            data,
        };
        assert_eq!(img.resampled(w, h), img);
        // Bilinear interpolation of a function linear in each axis is exact wherever the
        // sample point lies between pixel centres (not clamped at the edges).
        for (w2, h2) in [(20, 15), (64, 48), (41, 29)] {
            let out = img.resampled(w2, h2);
            let (sx, sy) = (w as f64 / w2 as f64, h as f64 / h2 as f64);
            for r in 0..h2 {
                for c in 0..w2 {
                    let x = (c as f64 + 0.5) * sx - 0.5;
                    let y = (r as f64 + 0.5) * sy - 0.5;
                    if !(0.0..=(w - 1) as f64).contains(&x) || !(0.0..=(h - 1) as f64).contains(&y)
                    {
                        continue;
                    }
                    let want = [2.0 * x + y, 200.0 - 3.0 * y, 50.0 + x + 0.5 * y];
                    let got = out.pixel(r, c);
                    for k in 0..3 {
                        assert!((got[k] - want[k]).abs() < 1e-9, "{w2}x{h2} ({r}, {c})");
                    }
                }
            }
        }
        // One colour stays that colour at any size.
        let flat = RgbImage::uniform(7, 5, [12.0, 34.0, 56.0]);
        assert_eq!(
            flat.resampled(13, 3),
            RgbImage::uniform(13, 3, [12.0, 34.0, 56.0])
        );
    }

    #[test]
    fn a_saved_model_loads_back() {
        let dir = scratch("roundtrip");
        let table = table_of([9, 11], [0.7, 0.5], |gx, gy| {
            [30.0 * gx, -20.0 * gy, 5.0 * gx * gy]
        });
        let mut data = Vec::new();
        for r in 0..6 {
            for c in 0..8 {
                data.extend([c as f64 * 30.0 + 0.25, r as f64 * 50.0, 128.0]);
            }
        }
        let background = RgbImage {
            width: 8,
            height: 6,
            data,
        };
        let optics = CalibratedOptics::new(table.clone(), background.clone()).unwrap();
        let path = dir.join("optics.json");
        optics
            .save(&path, Some(serde_json::json!({"note": "test"})))
            .unwrap();
        assert!(dir.join("optics.background.png").is_file());
        let back = CalibratedOptics::load(&path).unwrap();
        assert_eq!(back.source(), Some(path.as_path()));
        // The table's values go through JSON's shortest round-trip decimal form, which
        // serde_json parses back to within one unit in the last place (it does not round
        // correctly in every case without its float_roundtrip feature).
        assert_eq!(
            (back.table().bins(), back.table().range()),
            (table.bins(), table.range())
        );
        for (a, b) in back.table().values().iter().zip(table.values()) {
            assert!((a - b).abs() <= 1e-14 * b.abs().max(1.0), "{a} vs {b}");
        }
        // 16 bits per channel: within 1/514 of a grey level.
        for (a, b) in back.background().data.iter().zip(&background.data) {
            assert!((a - b).abs() <= 0.5 / 257.0 + 1e-12, "{a} vs {b}");
        }
        assert_eq!(back.blur(), 0.0);
        // A blur is saved and read back; a file without one reads as none (above).
        let blurred = optics.with_blur(1.5e-4).unwrap();
        blurred.save(&path, None).unwrap();
        assert_eq!(CalibratedOptics::load(&path).unwrap().blur(), 1.5e-4);
    }

    /// A blur that is negative, not finite or above [`MAX_BLUR`] is refused, by the model
    /// and in a file (naming the file and the key).
    #[test]
    fn a_bad_blur_is_refused() {
        let table = table_of([3, 3], [0.5, 0.5], |_, _| [1.0, 2.0, 3.0]);
        let background = RgbImage::uniform(4, 3, [100.0, 110.0, 120.0]);
        let optics = CalibratedOptics::new(table, background).unwrap();
        for bad in [-1e-6, f64::NAN, f64::INFINITY, 2.0 * MAX_BLUR] {
            assert!(optics.clone().with_blur(bad).is_err(), "{bad}");
        }
        assert!(optics.clone().with_blur(MAX_BLUR).is_ok());
        let dir = scratch("badblur");
        let path = dir.join("optics.json");
        optics.save(&path, None).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
        json["blur"] = serde_json::json!(-0.001);
        std::fs::write(&path, json.to_string()).unwrap();
        let e = CalibratedOptics::load(&path).unwrap_err().to_string();
        assert!(
            e.contains("optics.json") && e.contains("blur = -0.001"),
            "{e}"
        );
    }
}
