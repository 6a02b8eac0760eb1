//! `tacrom compare`: a sensor's images against a device's own ball presses (the paper's
//! Table I on real data).
//!
//! For each held-out press of a calibration folder, each row of the table predicts the
//! press's image: the untouched background (no press at all), the sensor of a sensor file
//! with its attributes as they are or with some replaced (`physics="rigid"`, the default
//! gel, ...), or a folder of images another renderer made of the same presses. A sensor
//! row presses a ball of the press's radius at the press's contact centre to the depth
//! whose image is closest to the press's over its region (a golden-section search, as the
//! gel fit does: [`super::gel`]), and its `rgb` output is the prediction. Every row is
//! scored over the whole image and over the press's region ([`super::gel::REGION`] radii of
//! its circle in `presses.json`): mean absolute error and PSNR of the colours, and the mean
//! SSIM of the grey images, colours on a 0..1 scale.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use tacrom::config::RawConfig;
use tacrom::render::calibrated::RgbImage;
use tacrom::render::rgb::FULL_SCALE;

use super::gel::{press_depth, region, PressModel};
use super::metrics::{grey, mae, mean, psnr, ssim_map};
use super::{file_error, mirrored, read_set_detecting, CalibrateError, Press};

/// The gel's attributes, which a row `gel:default` leaves to their defaults (keeping the
/// sensor file's camera, image and optics).
const GEL_ATTRIBUTES: &[&str] = &[
    "physics",
    "size",
    "young",
    "poisson",
    "density",
    "friction",
    "dx",
    "solver",
    "material",
    "model",
    "tolerance",
];

/// How a row predicts a press.
#[derive(Clone, Debug, PartialEq)]
pub enum Source {
    /// The background image of the folder: no press at all.
    Background,
    /// The sensor file's sensor with these attributes replaced (`gel` = `default`: the
    /// gel's attributes left to their defaults).
    Sensor(Vec<(String, String)>),
    /// Images of the same names as the presses' in this folder.
    Images(PathBuf),
}

/// One row of the table.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// Its label.
    pub label: String,
    /// How it predicts.
    pub source: Source,
}

impl Row {
    /// Parses `LABEL=ATTR:VALUE,ATTR:VALUE` (a sensor row; `LABEL=` alone: the sensor file
    /// as it is) or `LABEL=@DIR` (a folder of images).
    pub fn parse(spec: &str) -> Result<Row, String> {
        let (label, rest) = spec
            .split_once('=')
            .ok_or_else(|| format!("row {spec:?}: expected LABEL=ATTR:VALUE,... or LABEL=@DIR"))?;
        let source = if let Some(dir) = rest.strip_prefix('@') {
            Source::Images(PathBuf::from(dir))
        } else {
            let mut pairs = Vec::new();
            for item in rest.split(',').filter(|i| !i.trim().is_empty()) {
                let (k, v) = item
                    .split_once(':')
                    .ok_or_else(|| format!("row {spec:?}: {item:?} is not ATTR:VALUE"))?;
                pairs.push((k.trim().to_owned(), v.trim().to_owned()));
            }
            Source::Sensor(pairs)
        };
        Ok(Row {
            label: label.trim().to_owned(),
            source,
        })
    }

    /// The rows of the table when none are named: the background, the rigid cap, the
    /// sensor file's own sensor, and the coarse and rom gels of the default sensor seen
    /// through the same camera and optics.
    pub fn defaults() -> Vec<Row> {
        let sensor = |label: &str, pairs: &[(&str, &str)]| Row {
            label: label.into(),
            source: Source::Sensor(
                pairs
                    .iter()
                    .map(|(k, v)| ((*k).to_owned(), (*v).to_owned()))
                    .collect(),
            ),
        };
        vec![
            Row {
                label: "background".into(),
                source: Source::Background,
            },
            sensor("rigid", &[("physics", "rigid")]),
            sensor("sensor file", &[]),
            sensor("rom, the sensor file's gel", &[("physics", "rom")]),
            sensor(
                "coarse, default gel",
                &[("gel", "default"), ("physics", "coarse")],
            ),
            sensor(
                "rom, default gel",
                &[("gel", "default"), ("physics", "rom")],
            ),
        ]
    }
}

/// Errors of one predicted image, colours on a 0..1 scale.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Scores {
    /// Mean absolute error over the region.
    pub mae_region: f64,
    /// Mean SSIM of the grey images over the region.
    pub ssim_region: f64,
    /// PSNR over the region (dB).
    pub psnr_region: f64,
    /// Mean absolute error over the image.
    pub mae_image: f64,
    /// Mean SSIM over the image.
    pub ssim_image: f64,
    /// PSNR over the image (dB).
    pub psnr_image: f64,
}

impl Scores {
    /// The scores of `predicted` (`(H, W, 3)`, 0..255) against `press`'s image.
    pub fn of(predicted: &[f64], press: &Press) -> Scores {
        let image = &press.image;
        let mask = region(press);
        let ssim = ssim_map(
            &grey(predicted),
            &grey(&image.data),
            image.width,
            image.height,
        );
        Scores {
            mae_region: mae(predicted, &image.data, Some(&mask)) / FULL_SCALE,
            ssim_region: mean(&ssim, Some(&mask)),
            psnr_region: psnr(predicted, &image.data, Some(&mask)),
            mae_image: mae(predicted, &image.data, None) / FULL_SCALE,
            ssim_image: mean(&ssim, None),
            psnr_image: psnr(predicted, &image.data, None),
        }
    }

    /// The mean of `rows` (PSNR averaged in dB).
    pub fn mean(rows: &[Scores]) -> Scores {
        let n = rows.len().max(1) as f64;
        let avg = |f: fn(&Scores) -> f64| rows.iter().map(f).sum::<f64>() / n;
        Scores {
            mae_region: avg(|s| s.mae_region),
            ssim_region: avg(|s| s.ssim_region),
            psnr_region: avg(|s| s.psnr_region),
            mae_image: avg(|s| s.mae_image),
            ssim_image: avg(|s| s.ssim_image),
            psnr_image: avg(|s| s.psnr_image),
        }
    }
}

/// One row's results.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RowResult {
    /// The row's label.
    pub label: String,
    /// What predicted: `background`, `sensor` or `images` (another renderer's).
    pub kind: String,
    /// Per held-out press: its scores and (sensor rows) the depth found (m); `None` where
    /// the row could not predict it.
    pub presses: Vec<Option<(Scores, Option<f64>)>>,
    /// Mean over the presses it predicted.
    pub mean: Option<Scores>,
    /// Why it predicted nothing (a sensor the file's attributes and the row's refuse).
    pub refused: Option<String>,
    /// Median seconds of one evaluation of its sensor.
    pub seconds: Option<f64>,
}

/// The table.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Table {
    /// The held-out presses' images.
    pub presses: Vec<String>,
    /// The rows.
    pub rows: Vec<RowResult>,
}

/// What to compare.
#[derive(Clone, Debug)]
pub struct CompareOptions {
    /// The calibration folder.
    pub input: PathBuf,
    /// The sensor file.
    pub sensor: PathBuf,
    /// Score every `holdout`-th press (the calibration's held-out presses); 0 or 1: all.
    pub holdout: usize,
    /// The images are the camera's: flip them first.
    pub mirror: bool,
    /// Detect every contact from its image (its centre is where the ball presses).
    pub detect: bool,
    /// Contact detection threshold (grey levels).
    pub threshold: f64,
    /// The rows.
    pub rows: Vec<Row>,
    /// Solver threads.
    pub threads: usize,
    /// Keep this many presses' crops (around each region) for a figure.
    pub figure_presses: usize,
}

/// The square around `press`'s region (two region radii on each side), clipped to the
/// image: `[col0, row0, size]`.
fn crop_box(press: &Press) -> [usize; 3] {
    let c = press.given.unwrap_or(press.contact);
    let (w, h) = (press.image.width, press.image.height);
    let half = (2.0 * c.radius).ceil() as usize;
    let size = (2 * half + 1).min(w).min(h);
    let start = |centre: f64, n: usize| {
        ((centre.round() as isize - half as isize).max(0) as usize).min(n - size)
    };
    [start(c.centre[0], w), start(c.centre[1], h), size]
}

/// The pixels of `image` (`(H, W, 3)` of `width` columns) in `b`, as 8-bit RGB rows.
fn crop(image: &[f64], width: usize, b: [usize; 3]) -> Vec<u8> {
    let [c0, r0, n] = b;
    let mut out = Vec::with_capacity(3 * n * n);
    for r in r0..r0 + n {
        for v in &image[3 * (r * width + c0)..3 * (r * width + c0 + n)] {
            out.push(v.round().clamp(0.0, FULL_SCALE) as u8);
        }
    }
    out
}

/// A figure of the crops: one row per press, its real image then each row's prediction.
#[derive(Clone, Debug, Default)]
pub struct Figure {
    /// The column labels: `real`, then the rows that predicted.
    pub labels: Vec<String>,
    /// Per press, its crops (8-bit RGB, `size x size`) in the labels' order, and the size.
    pub presses: Vec<(Vec<Vec<u8>>, usize)>,
}

impl Figure {
    /// Writes the figure as one PNG: presses down, columns across, 2 pixels apart, each
    /// crop scaled to `cell` pixels (nearest).
    pub fn write(&self, path: &Path, cell: usize) -> Result<(), CalibrateError> {
        let cols = self.labels.len();
        let gap = 2;
        let (w, h) = (cols * (cell + gap), self.presses.len() * (cell + gap));
        let mut img =
            image::RgbImage::from_pixel(w as u32, h.max(1) as u32, image::Rgb([255, 255, 255]));
        for (pi, (crops, n)) in self.presses.iter().enumerate() {
            for (ci, crop) in crops.iter().enumerate() {
                for y in 0..cell {
                    for x in 0..cell {
                        let (sx, sy) = (x * n / cell, y * n / cell);
                        let k = 3 * (sy * n + sx);
                        img.put_pixel(
                            (ci * (cell + gap) + x) as u32,
                            (pi * (cell + gap) + y) as u32,
                            image::Rgb([crop[k], crop[k + 1], crop[k + 2]]),
                        );
                    }
                }
            }
        }
        img.save(path).map_err(|e| file_error(path, e))
    }
}

/// The sensor of `file` with `row`'s attributes replaced, images seen from the indenter's
/// side (the presses are read in that orientation), depth and rgb as its outputs.
fn row_config(
    file: &Path,
    pairs: &[(String, String)],
    threads: usize,
) -> Result<RawConfig, String> {
    let sensor = tacrom::sensor_file::SensorFile::read(&file.display().to_string())?;
    let default_gel = pairs.iter().any(|(k, v)| k == "gel" && v == "default");
    let mut raw = RawConfig::default();
    let value = |key: &str, pairs: &[(String, String)]| {
        pairs.iter().find(|(k, _)| k == key).map(|(_, v)| v.clone())
    };
    let physics = value("physics", pairs)
        .or_else(|| value("physics", &sensor.attributes).filter(|_| !default_gel))
        .unwrap_or_else(|| tacrom::config::defaults::PHYSICS.to_owned());
    for (k, v) in &sensor.attributes {
        if !(default_gel && GEL_ATTRIBUTES.contains(&k.as_str()))
            && tacrom::config::file_attribute_applies(&physics, k)
        {
            raw = raw.with(k, v);
        }
    }
    for (k, v) in pairs.iter().filter(|(k, _)| k != "gel") {
        raw = raw.with(k, v);
    }
    Ok(raw
        .with("outputs", "depth rgb")
        .with("view", "indenter")
        .with("threads", &threads.to_string()))
}

/// Scores every row on the held-out presses of `o`'s folder.
pub fn compare(o: &CompareOptions) -> Result<Table, CalibrateError> {
    compare_with_figure(o).map(|(t, _)| t)
}

/// [`compare`], with the crops of the first [`CompareOptions::figure_presses`] presses.
pub fn compare_with_figure(o: &CompareOptions) -> Result<(Table, Figure), CalibrateError> {
    let set = read_set_detecting(&o.input, o.mirror, o.threshold, o.detect)?;
    let scored: Vec<&Press> = set
        .presses
        .iter()
        .enumerate()
        .filter(|(i, _)| o.holdout <= 1 || (i + 1) % o.holdout == 0)
        .map(|(_, p)| p)
        .collect();
    let grid = scored
        .first()
        .ok_or_else(|| CalibrateError::Usage("no presses to score".into()))?
        .grid();
    let shown = o.figure_presses.min(scored.len());
    let boxes: Vec<[usize; 3]> = scored[..shown].iter().map(|p| crop_box(p)).collect();
    let mut figure = Figure {
        labels: vec!["real".into()],
        presses: scored[..shown]
            .iter()
            .zip(&boxes)
            .map(|(p, &b)| (vec![crop(&p.image.data, p.image.width, b)], b[2]))
            .collect(),
    };
    let keep = |figure: &mut Figure, i: usize, image: &[f64]| {
        if i < shown {
            figure.presses[i].0.push(crop(image, grid.width, boxes[i]));
        }
    };
    let mut rows = Vec::new();
    for row in &o.rows {
        let mut result = RowResult {
            label: row.label.clone(),
            kind: match row.source {
                Source::Background => "background",
                Source::Sensor(_) => "sensor",
                Source::Images(_) => "images",
            }
            .into(),
            presses: Vec::new(),
            mean: None,
            refused: None,
            seconds: None,
        };
        match &row.source {
            Source::Background => {
                for (i, p) in scored.iter().enumerate() {
                    keep(&mut figure, i, &set.background.data);
                    result
                        .presses
                        .push(Some((Scores::of(&set.background.data, p), None)));
                }
            }
            Source::Images(dir) => {
                for (i, p) in scored.iter().enumerate() {
                    let path = dir.join(&p.name);
                    let image = RgbImage::read_png(&path).map_err(|e| file_error(&path, e))?;
                    let image = if o.mirror { mirrored(&image) } else { image };
                    if (image.width, image.height) != (p.image.width, p.image.height) {
                        return Err(file_error(&path, "not the press's image size"));
                    }
                    keep(&mut figure, i, &image.data);
                    result
                        .presses
                        .push(Some((Scores::of(&image.data, p), None)));
                }
            }
            Source::Sensor(pairs) => {
                let model = row_config(&o.sensor, pairs, o.threads)
                    .and_then(|raw| PressModel::from_raw(&raw, &grid));
                let mut model = match model {
                    Ok(m) => m,
                    Err(e) => {
                        // Paths of the checkout as the user sees them, not this machine's.
                        let root = format!("{}/", tacrom::checkout_root().display());
                        result.refused = Some(e.replace(&root, ""));
                        rows.push(result);
                        continue;
                    }
                };
                let pixels = grid.width * grid.height;
                let mut times = Vec::new();
                for (i, p) in scored.iter().enumerate() {
                    let mask = region(p);
                    let (depth, _) = press_depth(p, |d| {
                        let t = std::time::Instant::now();
                        let rgb = &model.press(p.ball_radius, &p.contact, d)[pixels..];
                        times.push(t.elapsed().as_secs_f64());
                        mae(rgb, &p.image.data, Some(&mask))
                    });
                    let rgb = model.press(p.ball_radius, &p.contact, depth)[pixels..].to_vec();
                    keep(&mut figure, i, &rgb);
                    result
                        .presses
                        .push(Some((Scores::of(&rgb, p), Some(depth))));
                }
                times.sort_by(f64::total_cmp);
                result.seconds = times.get(times.len() / 2).copied();
            }
        }
        if result.refused.is_none() {
            figure.labels.push(row.label.clone());
        }
        let done: Vec<Scores> = result.presses.iter().flatten().map(|(s, _)| *s).collect();
        result.mean = (!done.is_empty()).then(|| Scores::mean(&done));
        rows.push(result);
    }
    let table = Table {
        presses: scored.iter().map(|p| p.name.clone()).collect(),
        rows,
    };
    Ok((table, figure))
}

/// The table as markdown: the means per row, then the region MAE and SSIM per press.
pub fn markdown(t: &Table) -> String {
    let mut s = String::from(
        "| row | MAE region | SSIM region | PSNR region | MAE image | SSIM image | PSNR image | ms per evaluation |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in &t.rows {
        match (&r.mean, &r.refused) {
            (Some(m), _) => s.push_str(&format!(
                "| {} | {:.4} | {:.4} | {:.2} | {:.4} | {:.4} | {:.2} | {} |\n",
                r.label,
                m.mae_region,
                m.ssim_region,
                m.psnr_region,
                m.mae_image,
                m.ssim_image,
                m.psnr_image,
                r.seconds.map_or("".into(), |t| format!("{:.1}", t * 1e3))
            )),
            (None, Some(why)) => s.push_str(&format!("| {} | refused: {why} |||||||\n", r.label)),
            (None, None) => s.push_str(&format!("| {} | no presses |||||||\n", r.label)),
        }
    }
    s.push_str("\nPer press, region MAE / SSIM:\n\n| row |");
    for p in &t.presses {
        s.push_str(&format!(" {p} |"));
    }
    s.push_str("\n|---|");
    s.push_str(&"---:|".repeat(t.presses.len()));
    s.push('\n');
    for r in t.rows.iter().filter(|r| r.mean.is_some()) {
        s.push_str(&format!("| {} |", r.label));
        for p in &r.presses {
            match p {
                Some((sc, _)) => {
                    s.push_str(&format!(" {:.3} / {:.3} |", sc.mae_region, sc.ssim_region))
                }
                None => s.push_str(" |"),
            }
        }
        s.push('\n');
    }
    s
}

/// The rows of `table` whose region or image MAE or SSIM is worse than `baseline`'s row of
/// the same label by more than `tolerance`, in words; rows the baseline lacks are not
/// checked, and neither are its rows of other renderers' images (`images`) that the table
/// lacks (their images are made outside the project); any other row it has that the table
/// lacks is reported.
pub fn regressions(table: &Table, baseline: &Table, tolerance: f64) -> Vec<String> {
    let mut out = Vec::new();
    for b in &baseline.rows {
        let Some(bm) = &b.mean else { continue };
        let Some(r) = table.rows.iter().find(|r| r.label == b.label) else {
            if b.kind != "images" {
                out.push(format!("{}: missing", b.label));
            }
            continue;
        };
        let Some(m) = &r.mean else {
            out.push(format!("{}: no scores ({:?})", b.label, r.refused));
            continue;
        };
        let checks = [
            ("region MAE", m.mae_region - bm.mae_region),
            ("image MAE", m.mae_image - bm.mae_image),
            ("region SSIM", bm.ssim_region - m.ssim_region),
            ("image SSIM", bm.ssim_image - m.ssim_image),
        ];
        for (what, worse) in checks {
            if !(worse <= tolerance) {
                out.push(format!(
                    "{}: {what} worse by {worse:.4} (more than {tolerance})",
                    b.label
                ));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_parse_as_sensors_or_image_folders() {
        let r = Row::parse("rigid=physics:rigid, dx : 1e-3").unwrap();
        assert_eq!(r.label, "rigid");
        let pairs = vec![
            ("physics".into(), "rigid".into()),
            ("dx".into(), "1e-3".into()),
        ];
        assert_eq!(r.source, Source::Sensor(pairs));
        assert_eq!(Row::parse("as is=").unwrap().source, Source::Sensor(vec![]));
        let r = Row::parse("taxim=@out/taxim").unwrap();
        assert_eq!(r.source, Source::Images(PathBuf::from("out/taxim")));
        assert!(Row::parse("no equals").is_err());
        assert!(Row::parse("x=physics").is_err());
    }

    fn table(rows: &[(&str, &str, f64, f64)]) -> Table {
        Table {
            presses: vec!["p".into()],
            rows: rows
                .iter()
                .map(|&(label, kind, mae, ssim)| {
                    let s = Scores {
                        mae_region: mae,
                        ssim_region: ssim,
                        mae_image: mae / 10.0,
                        ssim_image: 0.99,
                        ..Default::default()
                    };
                    RowResult {
                        label: label.into(),
                        kind: kind.into(),
                        presses: vec![Some((s, None))],
                        mean: Some(s),
                        refused: None,
                        seconds: None,
                    }
                })
                .collect(),
        }
    }

    /// A row worse than the baseline by more than the tolerance in MAE or SSIM is named;
    /// within it, or better, passes; a missing sensor row fails, a missing renderer's
    /// row does not.
    #[test]
    fn regressions_name_the_rows_that_got_worse() {
        let base = table(&[("a", "sensor", 0.02, 0.95), ("t", "images", 0.08, 0.96)]);
        assert!(regressions(&table(&[("a", "sensor", 0.024, 0.947)]), &base, 0.005).is_empty());
        assert!(regressions(&table(&[("a", "sensor", 0.01, 0.99)]), &base, 0.005).is_empty());
        let worse = regressions(&table(&[("a", "sensor", 0.026, 0.95)]), &base, 0.005);
        assert_eq!(worse.len(), 1, "{worse:?}");
        assert!(worse[0].contains("region MAE"), "{worse:?}");
        let worse = regressions(&table(&[("a", "sensor", 0.02, 0.94)]), &base, 0.005);
        assert!(worse[0].contains("region SSIM"), "{worse:?}");
        let missing = regressions(&table(&[("b", "sensor", 0.02, 0.95)]), &base, 0.005);
        assert_eq!(missing, vec!["a: missing".to_string()]);
    }
}
