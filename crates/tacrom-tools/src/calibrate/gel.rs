//! The gel behind a device's images, fitted to its ball presses (`tacrom calibrate --gel`).
//!
//! Inside the contact circle every gel shows the ball; what tells gels apart is the
//! imprint around it: a thick or compressible gel sags wide around the ball, a thin one
//! bonded to its window barely moves beside it. Pressed by a rigid body to a given depth, a
//! linear elastic gel's surface does not depend on its Young's modulus, only on its
//! thickness `T` and Poisson's ratio `nu` (and the press): so images alone, without forces,
//! fix `T` and `nu`; the modulus needs forces. Where presses give their normal force
//! (`force_n`), the modulus follows from them once the gel's shape and each press's depth
//! are fitted: at a given depth the force is proportional to the modulus ([`fit_young`]).
//!
//! Each press's depth, unless `presses.json` gives it (`depth_mm`), is fitted from its own
//! imprint, the depth whose image through the optics is closest (mean absolute error over the press's region, [`REGION`]
//! radii of its circle) to the press's image, by a golden-section search over a bracket
//! around the rigid cap's depth. A gel is scored through a table of its own: the depths
//! found through the optics of the contacts alone, the table refitted to the gel's imprints
//! there, the depths found again through that table, and the presses' mean error at them
//! ([`fit_gel`]). The gel is the best of a grid of thicknesses and Poisson's ratios,
//! the thickness refined at every ratio of the grid and the ratio at the best of those, each
//! by a golden-section search between the grid's neighbours.
//!
//! The gel is simulated as the sensor runs it: `physics="coarse"` on the linear solver,
//! every candidate on one grid spacing ([`CELLS_THROUGH`] cells through the thinnest), a
//! gel [`MARGIN`] wider than the image on every side. What it recovers and where it does
//! not: docs/calibration.md.

use std::sync::Arc;

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use serde::Serialize;
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{PixelGrid, Placed, Sdf, Sphere};
use tacrom::render::calibrated::{CalibratedOptics, RgbImage};
use tacrom::render::rgb::CHANNELS;
use tacrom::sensor::TactileSensor;

use super::{Contact, Press};

/// The region a press is scored over: this many contact radii around its centre (the
/// contact and the imprint around it).
pub const REGION: f64 = 1.5;
/// Grid cells through the thinnest gel of a search: its grid spacing is every candidate's,
/// so that the candidates differ in their gel, not in their discretisation (with a spacing
/// that follows the thickness, the score jumps between neighbouring thicknesses by more
/// than their gels differ). Two, the coarse mode's least: finer grids of the GelSight
/// Mini's image exceed the linear solver's unknowns below 1.5 mm, and at 1 mm the real
/// presses' error did not move with 3 or 4 cells (docs/calibration.md).
pub const CELLS_THROUGH: f64 = 2.0;
/// The gel's lateral margin beyond the image on each side (m): several thicknesses, so
/// that its free sides do not shape the imprint.
pub const MARGIN: f64 = 1e-3;
/// The depth search's lower end, as a multiple of the rigid cap's depth `R - sqrt(R^2 -
/// a^2)` of the press's circle: a nearly incompressible thin layer bulges around the ball,
/// so its contact circle is wider than the cap's at the same depth. The upper end is the
/// half-space's ([`half_space_depth`]).
const DEPTH_FLOOR: f64 = 0.4;
/// Golden-section steps of each axis's refinement of the gel: the bracket between the best
/// grid point's neighbours shrinks to 0.618^5 = 9 % of its width.
const REFINE_STEPS: usize = 5;
/// Golden-section steps of the depth search: the bracket shrinks to 0.618^n of its width
/// (to 0.3 % of it after 12).
const DEPTH_STEPS: usize = 12;

/// A gel candidate.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GelShape {
    /// Thickness (m).
    pub thickness: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// The grid spacing it is simulated on (m).
    pub dx: f64,
}

/// The attributes of the sensor that simulates `gel` behind images like `grid`'s: the
/// coarse gel on the linear solver, [`CELLS_THROUGH`] cells through, [`MARGIN`] wider than
/// the image, depth as its output.
pub fn gel_attributes(gel: GelShape, grid: &PixelGrid) -> Vec<(&'static str, String)> {
    let n = |x: f64| format!("{x:.6e}");
    vec![
        ("physics", "coarse".into()),
        ("solver", "linear".into()),
        (
            "size",
            format!(
                "{} {} {}",
                n(grid.fov_x + 2.0 * MARGIN),
                n(grid.fov_y + 2.0 * MARGIN),
                n(gel.thickness)
            ),
        ),
        ("fov", format!("{} {}", n(grid.fov_x), n(grid.fov_y))),
        ("resolution", format!("{} {}", grid.width, grid.height)),
        ("poisson", format!("{}", gel.poisson)),
        ("dx", n(gel.dx)),
    ]
}

/// One press simulated on one gel.
pub struct PressModel {
    sensor: TactileSensor,
    out: Vec<f64>,
    grid: PixelGrid,
}

impl PressModel {
    /// A sensor simulating `gel` behind images like `grid`'s, on `threads` threads, its
    /// depth image as output.
    pub fn new(gel: GelShape, grid: &PixelGrid, threads: usize) -> Result<Self, String> {
        let mut raw = RawConfig::default()
            .with("outputs", "depth")
            .with("threads", &threads.to_string());
        for (k, v) in gel_attributes(gel, grid) {
            raw = raw.with(k, &v);
        }
        Self::from_raw(&raw, grid)
    }

    /// A sensor simulating `gel` of Young's modulus `young` (Pa) behind images like
    /// `grid`'s, its contact force as output ([`normal_force`] reads the press's).
    pub fn forces(
        gel: GelShape,
        grid: &PixelGrid,
        young: f64,
        threads: usize,
    ) -> Result<Self, String> {
        let mut raw = RawConfig::default()
            .with("outputs", "force")
            .with("young", &format!("{young:e}"))
            .with("threads", &threads.to_string());
        for (k, v) in gel_attributes(gel, grid) {
            raw = raw.with(k, &v);
        }
        Self::from_raw(&raw, grid)
    }

    /// The sensor `raw` configures, its images like `grid`'s.
    pub fn from_raw(raw: &RawConfig, grid: &PixelGrid) -> Result<Self, String> {
        let config = Config::from_raw("calibration", raw).map_err(|e| e.to_string())?;
        if (config.width, config.height) != (grid.width, grid.height) {
            return Err(format!(
                "the sensor's images are {} x {} pixels, the presses' {} x {}",
                config.width, config.height, grid.width, grid.height
            ));
        }
        let out = vec![0.0; config.sensordata_len()];
        let sensor = TactileSensor::new(config).map_err(|e| e.to_string())?;
        Ok(PressModel {
            sensor,
            out,
            grid: *grid,
        })
    }

    /// The sensor's data (its outputs in order) with a ball of `radius` centred over
    /// `contact`'s centre, its lowest point `depth` below the gel's face; each press starts
    /// from the undeformed gel (a new press, not the last one moved).
    pub fn press(&mut self, radius: f64, contact: &Contact, depth: f64) -> &[f64] {
        let px = self.grid.fov_x / self.grid.width as f64;
        let x = -0.5 * self.grid.fov_x + (contact.centre[0] + 0.5) * px;
        let y = 0.5 * self.grid.fov_y - (contact.centre[1] + 0.5) * px;
        let ball: Arc<dyn Sdf> = Arc::new(Sphere::new(radius));
        let placed = [Placed {
            shape: ball,
            pose: Isometry3::from_parts(
                Translation3::new(x, y, radius - depth),
                UnitQuaternion::identity(),
            ),
        }];
        self.sensor.reset();
        self.sensor.evaluate(&placed, &mut self.out);
        &self.out
    }
}

/// The normal force (N) in the sensor data of a [`PressModel::forces`] model: the gel's
/// force on the ball along the gel's outward normal.
pub fn normal_force(data: &[f64]) -> f64 {
    data[2]
}

/// The gel's Young's modulus from the presses' measured normal forces.
#[derive(Clone, Debug, Serialize)]
pub struct YoungFit {
    /// The modulus (Pa).
    pub young: f64,
    /// Every press with a force, fitted or held out.
    pub presses: Vec<ForceFit>,
    /// Mean absolute relative error of the fitted presses' forces at the modulus.
    pub error: f64,
    /// The same of the held-out presses' (`None`: none held out gives a force).
    pub held_out_error: Option<f64>,
}

/// One press's force: measured, and the fitted gel's at the fitted modulus.
#[derive(Clone, Debug, Serialize)]
pub struct ForceFit {
    /// Its image file.
    pub image: String,
    /// Whether it was held out of the fit.
    pub held_out: bool,
    /// The depth it was simulated at (m): given, or fitted from its imprint.
    pub depth: f64,
    /// The measured normal force (N).
    pub measured: f64,
    /// The fitted gel's normal force at its depth (N).
    pub simulated: f64,
}

/// The Young's modulus of `gel` that fits the forces of the `fitted` presses (at their
/// `depths`, m) in least squares, and every press's force there (`held_out` presses at
/// theirs, fitted the same way but not fitted to); `None` where no fitted press gives a
/// force.
///
/// Pressed to a given depth, a linear elastic gel's force is proportional to its modulus
/// (its surface does not depend on it): each press is simulated once at a reference
/// modulus `E0`, giving `F0`, and `E = E0 sum(F F0) / sum(F0^2)`, the least-squares factor
/// of the measured forces `F` over the simulated ones.
pub fn fit_young(
    gel: GelShape,
    fitted: &[(&Press, f64)],
    held_out: &[(&Press, f64)],
    threads: usize,
) -> Result<Option<YoungFit>, String> {
    fn given<'a>(set: &[(&'a Press, f64)]) -> Vec<(&'a Press, f64, f64)> {
        set.iter()
            .filter_map(|&(p, d)| p.force.map(|f| (p, d, f)))
            .collect()
    }
    let (fitted, held_out) = (given(fitted), given(held_out));
    let Some(grid) = fitted.first().map(|(p, _, _)| p.grid()) else {
        return Ok(None);
    };
    let reference = tacrom::attributes::defaults::YOUNG;
    let mut model = PressModel::forces(gel, &grid, reference, threads)?;
    let mut simulate = |set: &[(&Press, f64, f64)]| -> Result<Vec<f64>, String> {
        set.iter()
            .map(|(p, depth, _)| {
                if p.grid() != grid {
                    return Err(format!("{}: not the first press's image size", p.name));
                }
                Ok(normal_force(model.press(p.ball_radius, &p.contact, *depth)))
            })
            .collect()
    };
    let (f0, h0) = (simulate(&fitted)?, simulate(&held_out)?);
    let (num, den) = fitted
        .iter()
        .zip(&f0)
        .fold((0.0, 0.0), |(n, d), ((_, _, f), g)| (n + f * g, d + g * g));
    if den.is_nan() || den <= 0.0 {
        return Err(format!(
            "the fitted gel carries no force at the presses' depths (T {:.3} mm, Poisson \
             {:.3}): no modulus fits their force_n",
            gel.thickness * 1e3,
            gel.poisson
        ));
    }
    let scale = num / den;
    let young = reference * scale;
    let rows = |set: &[(&Press, f64, f64)], sim: &[f64], held_out: bool| -> Vec<ForceFit> {
        set.iter()
            .zip(sim)
            .map(|((p, depth, f), g)| ForceFit {
                image: p.name.clone(),
                held_out,
                depth: *depth,
                measured: *f,
                simulated: g * scale,
            })
            .collect()
    };
    let mean_error = |rows: &[ForceFit]| {
        (!rows.is_empty()).then(|| {
            rows.iter()
                .map(|r| (r.simulated / r.measured - 1.0).abs())
                .sum::<f64>()
                / rows.len() as f64
        })
    };
    let (a, b) = (rows(&fitted, &f0, false), rows(&held_out, &h0, true));
    Ok(Some(YoungFit {
        young,
        error: mean_error(&a).unwrap_or(0.0),
        held_out_error: mean_error(&b),
        presses: [a, b].concat(),
    }))
}

/// The pixel size the presses' known depths imply, against the one they give.
#[derive(Clone, Debug, Serialize)]
pub struct PixelCheck {
    /// Presses compared (those giving their depth whose imprint was found in the image and
    /// in its simulation).
    pub presses: usize,
    /// The implied pixel size over the given one: the mean over those presses of the
    /// simulated imprint's radius over the image's (pixels).
    pub ratio: f64,
    /// The ratios' standard deviation.
    pub spread: f64,
}

/// Checks the presses' pixel size against their known depths (`depth_mm`): each press
/// that gives its depth is simulated on the fitted `gel` at that depth and rendered
/// through the fitted `optics`, and its imprint found in that image as in the press's own
/// ([`super::contact::detect`], `threshold`). At a known depth the imprint's size on the
/// gel is fixed, so a pixel size wrong by a factor `s` shows as an imprint `s` times the
/// simulated one's in pixels: the implied pixel size is the given one times the ratio of
/// the simulated radius to the image's. (Ball presses of unknown depths cannot check it:
/// docs/calibration.md.) `None` where no press gives its depth.
pub fn check_pixel_size(
    gel: GelShape,
    presses: &[&Press],
    background: &RgbImage,
    optics: &CalibratedOptics,
    threshold: f64,
    threads: usize,
) -> Result<Option<PixelCheck>, String> {
    let known: Vec<(&Press, f64)> = presses
        .iter()
        .filter_map(|p| p.depth.map(|d| (*p, d)))
        .collect();
    let Some(grid) = known.first().map(|(p, _)| p.grid()) else {
        return Ok(None);
    };
    let mut model = PressModel::new(gel, &grid, threads)?;
    let mut rendered = RgbImage {
        width: grid.width,
        height: grid.height,
        data: vec![0.0; CHANNELS * grid.width * grid.height],
    };
    let mut ratios = Vec::with_capacity(known.len());
    for (press, depth) in known {
        if press.grid() != grid {
            return Err(format!("{}: not the first press's image size", press.name));
        }
        let surface = model.press(press.ball_radius, &press.contact, depth);
        tacrom::render::rgb::render_calibrated(optics, &grid, surface, &mut rendered.data);
        let real = super::contact::detect(background, &press.image, threshold);
        let simulated = super::contact::detect(background, &rendered, threshold);
        if let (Some(real), Some(simulated)) = (real, simulated) {
            ratios.push(simulated.radius / real.radius);
        }
    }
    if ratios.is_empty() {
        return Ok(None);
    }
    let n = ratios.len() as f64;
    let ratio = ratios.iter().sum::<f64>() / n;
    let spread = (ratios.iter().map(|r| (r - ratio).powi(2)).sum::<f64>() / n).sqrt();
    Ok(Some(PixelCheck {
        presses: ratios.len(),
        ratio,
        spread,
    }))
}

/// The pixels of `press`'s region: [`REGION`] radii of the circle `presses.json` gives (a
/// region that does not depend on what is scored), or of its contact where none is given.
pub fn region(press: &Press) -> Vec<bool> {
    region_of(press, REGION)
}

/// The pixels within `radii` radii of `press`'s circle (as [`region`]).
fn region_of(press: &Press, radii: f64) -> Vec<bool> {
    let circle = press.given.unwrap_or(press.contact);
    let c = Contact {
        radius: radii * circle.radius,
        ..circle
    };
    c.mask(press.image.width, press.image.height)
}

/// The region a gel is fitted over, in radii of the press's circle: the scored [`REGION`].
/// Wider (2.5 radii) measured no better on the synthetic presses of the gel test, with the
/// search of the time (the thickness refined at the grid's best Poisson's ratio only): the
/// gel landed at (2.26 mm, 0.471) against (2.23 mm, 0.423) for the truth (1.8 mm, 0.40).
pub const FIT_REGION: f64 = REGION;

/// Mean absolute colour difference (0..255, all channels) of `optics`' image of `depth`
/// against `press`'s image over the pixels of `mask`.
pub fn region_error(
    optics: &CalibratedOptics,
    grid: &PixelGrid,
    depth: &[f64],
    press: &Press,
    mask: &[bool],
    scratch: &mut Vec<f64>,
) -> f64 {
    scratch.resize(CHANNELS * grid.width * grid.height, 0.0);
    tacrom::render::rgb::render_calibrated(optics, grid, depth, scratch);
    super::metrics::mae(scratch, &press.image.data, Some(mask))
}

/// The press's contact radius (m): the circle `presses.json` draws where it gives one
/// (the annotation of the contact itself), else the detected one (which takes in the
/// imprint's rim around the contact, so is wider).
pub fn contact_radius(press: &Press) -> f64 {
    press.given.unwrap_or(press.contact).radius * press.pixel_size
}

/// The depth of the rigid cap whose contact circle is `press`'s ([`contact_radius`], m).
pub fn cap_depth(press: &Press) -> f64 {
    let a = contact_radius(press);
    let r = press.ball_radius;
    r - (r * r - a * a).max(0.0).sqrt()
}

/// The depth (m) to which a rigid sphere of radius `R` sinks into an elastic half-space
/// when its frictionless contact circle has radius `a`: `a/2 ln((R + a) / (R - a))`
/// (Sneddon's solution for a sphere; Hertz's `a^2 / R` for `a << R`, twice the cap's
/// depth). A gel bonded to its window is confined and sinks less around the ball, so no
/// ball press of that circle lies deeper: the depth search's upper end. The sphere's
/// surface past `a` stays out of the depth: `R` where `a >= R`.
pub fn half_space_depth(press: &Press) -> f64 {
    let (a, r) = (contact_radius(press), press.ball_radius);
    if a >= r {
        return r;
    }
    (0.5 * a * ((r + a) / (r - a)).ln()).min(r)
}

/// Golden-section minimum of `f` over `[lo, hi]` in `steps` steps: the best point seen
/// and its value.
pub fn golden(mut f: impl FnMut(f64) -> f64, lo: f64, hi: f64, steps: usize) -> (f64, f64) {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut a, mut b) = (lo, hi);
    let mut c = b - g * (b - a);
    let mut d = a + g * (b - a);
    let (mut fc, mut fd) = (f(c), f(d));
    for _ in 0..steps {
        if fc <= fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    if fc <= fd {
        (c, fc)
    } else {
        (d, fd)
    }
}

/// `press`'s depth and `error` there: the depth `presses.json` gives, or else the one of
/// least `error` (m to error), by a golden-section search from [`DEPTH_FLOOR`] times the
/// rigid cap's depth to the half-space's ([`half_space_depth`]): the depths a ball of the
/// press's contact circle can have reached in an elastic gel, so that the fit cannot buy
/// an image's colours with a press no gel would take. The one depth search of the gel fit
/// and of `tacrom compare`.
pub fn press_depth(press: &Press, mut error: impl FnMut(f64) -> f64) -> (f64, f64) {
    match press.depth {
        Some(d) => (d, error(d)),
        None => golden(
            error,
            DEPTH_FLOOR * cap_depth(press),
            half_space_depth(press),
            DEPTH_STEPS,
        ),
    }
}

/// A press's best depth on one gel and its error there.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct PressFit {
    /// The depth (m).
    pub depth: f64,
    /// Region MAE at that depth (0..255).
    pub mae: f64,
}

/// Each press's depth fitted from its imprint on `gel`, with the region error there.
pub fn fit_depths(
    gel: GelShape,
    presses: &[&Press],
    optics: &CalibratedOptics,
    threads: usize,
) -> Result<Vec<PressFit>, String> {
    let Some(first) = presses.first() else {
        return Ok(Vec::new());
    };
    let grid = first.grid();
    let mut model = PressModel::new(gel, &grid, threads)?;
    let mut scratch = Vec::new();
    let mut fits = Vec::with_capacity(presses.len());
    for press in presses {
        if press.grid() != grid {
            return Err(format!("{}: not the first press's image size", press.name));
        }
        let mask = region_of(press, FIT_REGION);
        let (depth, mae) = press_depth(press, |d| {
            let image = model.press(press.ball_radius, &press.contact, d).to_vec();
            region_error(optics, &grid, &image, press, &mask, &mut scratch)
        });
        fits.push(PressFit { depth, mae });
    }
    Ok(fits)
}

/// The optics' table refitted to the imprints of `gel` (each press at its depth in
/// `fits`): every pixel of each press's region gives the simulated surface's gradient and
/// the image's colour change there ([`super::fit::surface_samples`]), so that the table no
/// longer takes the imprint around a contact for the ball's own slopes.
pub fn surface_table(
    presses: &[&Press],
    background: &RgbImage,
    gel: GelShape,
    fits: &[PressFit],
    blur: f64,
    options: &super::fit::FitOptions,
    threads: usize,
) -> Result<
    (
        tacrom::render::calibrated::GradientTable,
        super::fit::FitReport,
    ),
    String,
> {
    let Some(first) = presses.first() else {
        return Err("no presses".into());
    };
    let grid = first.grid();
    let mut model = PressModel::new(gel, &grid, threads)?;
    let mut samples = Vec::new();
    let mut blurred = Vec::new();
    for (press, fit) in presses.iter().zip(fits) {
        let depth = model.press(press.ball_radius, &press.contact, fit.depth);
        tacrom::render::rgb::blur_depth(&grid, depth, blur, &mut blurred);
        let mask = region_of(press, FIT_REGION);
        super::fit::surface_samples(background, press, &blurred, &mask, &mut samples);
    }
    super::fit::fit_table(&samples, options)
}

/// The gels a fit tries.
#[derive(Clone, Debug, PartialEq)]
pub struct GelSearch {
    /// Thicknesses (m), ascending.
    pub thicknesses: Vec<f64>,
    /// Poisson's ratios, ascending.
    pub poissons: Vec<f64>,
    /// Solver threads.
    pub threads: usize,
    /// Grid spacing of every candidate (m); `None`: the thinnest over [`CELLS_THROUGH`].
    pub dx: Option<f64>,
    /// The optics' depth blurs to try with the best gel (m, [`fit_blur`]); none, or only 0:
    /// no blur.
    pub blurs: Vec<f64>,
}

impl Default for GelSearch {
    /// Thickness 1 to 5 mm, Poisson's ratio 0.3 to 0.48 (the linear solver's range), one
    /// thread.
    fn default() -> Self {
        GelSearch {
            thicknesses: vec![1e-3, 1.5e-3, 2e-3, 3e-3, 4e-3, 5e-3],
            poissons: vec![0.3, 0.38, 0.43, 0.46, 0.48],
            threads: 1,
            dx: None,
            blurs: Vec::new(),
        }
    }
}

/// One gel of the search and its score.
#[derive(Clone, Debug, Serialize)]
pub struct GelScore {
    /// The gel.
    pub gel: GelShape,
    /// Mean region MAE of the presses at their best depths through the gel's own table
    /// (0..255).
    pub mae: f64,
}

/// The gel fit: the grid's scores and the best gel, its presses and its table.
#[derive(Clone, Debug, Serialize)]
pub struct GelFit {
    /// Every gel tried, in the order searched (the grid, then the refined gel).
    pub grid: Vec<GelScore>,
    /// The best gel.
    pub best: GelShape,
    /// The best gel's presses.
    pub presses: Vec<PressFit>,
    /// Their mean region MAE.
    pub mae: f64,
    /// Each depth blur tried with the best gel ([`fit_blur`]; empty where none was).
    pub blurs: Vec<BlurScore>,
    /// The blur of the optics (m): the best of `blurs`, or 0.
    pub blur: f64,
    /// The best gel's table (through `blur`).
    #[serde(skip)]
    pub table: Option<(
        tacrom::render::calibrated::GradientTable,
        super::fit::FitReport,
    )>,
}

/// A gel's score, as [`fit_gel`] takes it: each press's depth found through `first` (the
/// optics of the contacts alone), the table refitted to this gel's imprints at those
/// depths ([`surface_table`]), the depths found again through that table, and their mean
/// region MAE.
fn score_gel(
    gel: GelShape,
    presses: &[&Press],
    background: &RgbImage,
    first: &CalibratedOptics,
    options: &super::fit::FitOptions,
    threads: usize,
) -> Result<GelFit, String> {
    let fits = fit_depths(gel, presses, first, threads)?;
    let (table, report) = surface_table(presses, background, gel, &fits, 0.0, options, threads)?;
    let own =
        CalibratedOptics::new(table.clone(), background.clone()).map_err(|e| e.to_string())?;
    let fits = fit_depths(gel, presses, &own, threads)?;
    let mae = fits.iter().map(|f| f.mae).sum::<f64>() / fits.len().max(1) as f64;
    Ok(GelFit {
        grid: Vec::new(),
        best: gel,
        presses: fits,
        mae,
        blurs: Vec::new(),
        blur: 0.0,
        table: Some((table, report)),
    })
}

/// One depth blur of [`fit_blur`] and its scores over the fitted presses.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct BlurScore {
    /// The blur's standard deviation (m).
    pub blur: f64,
    /// Mean region MAE of the presses at their best depths through the blur's own table
    /// (0..255).
    pub mae: f64,
    /// Mean region SSIM of the grey images there ([`super::compare::Scores`]).
    pub ssim: f64,
}

/// The optics' depth blur for `gel`, over the candidates `blurs` (m): each scored as a gel
/// is ([`score_gel`]: the depths found through `first`, the table refitted to the gel's
/// imprints seen through the blur, the depths found again through that table and blur),
/// by the presses' mean region SSIM, the structure of the imprint that a mean error
/// barely weighs (the real imprint has no rim at its contact edge, the simulated one
/// does). Returns every candidate's score and the fit of the best, its table through it.
#[allow(clippy::too_many_arguments)]
pub fn fit_blur(
    gel: GelShape,
    presses: &[&Press],
    background: &RgbImage,
    first: &CalibratedOptics,
    options: &super::fit::FitOptions,
    blurs: &[f64],
    threads: usize,
    mut progress: impl FnMut(&BlurScore),
) -> Result<(Vec<BlurScore>, GelFit), String> {
    let Some(grid) = presses.first().map(|p| p.grid()) else {
        return Err("no presses to fit".into());
    };
    let start = fit_depths(gel, presses, first, threads)?;
    let mut model = PressModel::new(gel, &grid, threads)?;
    let mut scores = Vec::new();
    let mut best: Option<(f64, GelFit)> = None;
    for &blur in blurs {
        let (table, report) =
            surface_table(presses, background, gel, &start, blur, options, threads)?;
        let own = CalibratedOptics::new(table.clone(), background.clone())
            .and_then(|o| o.with_blur(blur))?;
        let fits = fit_depths(gel, presses, &own, threads)?;
        let n = fits.len().max(1) as f64;
        let mae = fits.iter().map(|f| f.mae).sum::<f64>() / n;
        let mut rendered = vec![0.0; CHANNELS * grid.width * grid.height];
        let mut ssim = 0.0;
        for (press, fit) in presses.iter().zip(&fits) {
            let depth = model.press(press.ball_radius, &press.contact, fit.depth);
            tacrom::render::rgb::render_calibrated(&own, &grid, depth, &mut rendered);
            ssim += super::compare::Scores::of(&rendered, press).ssim_region / n;
        }
        let score = BlurScore { blur, mae, ssim };
        progress(&score);
        scores.push(score);
        if best.as_ref().map_or(true, |(s, _)| ssim > *s) {
            let fit = GelFit {
                grid: Vec::new(),
                best: gel,
                presses: fits,
                mae,
                blurs: Vec::new(),
                blur,
                table: Some((table, report)),
            };
            best = Some((ssim, fit));
        }
    }
    let (_, mut fit) = best.ok_or("no blurs to try")?;
    fit.blurs = scores.clone();
    Ok((scores, fit))
}

/// Fits the gel over `search`'s grid to `presses` over `background`; `first`: optics
/// fitted to the contacts alone, which find each press's depth before a gel's own table
/// does; `progress` sees each gel's score.
///
/// Each gel is scored through a table fitted to its own imprints, never through another
/// gel's: a table fitted to one gel's imprints favours that gel (alternating the two fits
/// stays where it starts), while through its own table the gel whose imprints make colour
/// a single function of slope scores best. At each Poisson's ratio of the grid the best
/// thickness is refined by a golden-section search between its neighbours; the ratio is
/// then refined the same way at the best of those; the best gel scored is the fit.
pub fn fit_gel(
    presses: &[&Press],
    background: &RgbImage,
    first: &CalibratedOptics,
    options: &super::fit::FitOptions,
    search: &GelSearch,
    mut progress: impl FnMut(&GelScore),
) -> Result<GelFit, String> {
    let (thicknesses, poissons, threads) = (&search.thicknesses, &search.poissons, search.threads);
    if thicknesses.is_empty() || poissons.is_empty() || presses.is_empty() {
        return Err("no gels or no presses to fit".into());
    }
    let dx = search
        .dx
        .unwrap_or(thicknesses.iter().copied().fold(f64::INFINITY, f64::min) / CELLS_THROUGH);
    let mut scores = Vec::new();
    let mut grid = vec![vec![f64::INFINITY; poissons.len()]; thicknesses.len()];
    let mut best: Option<GelFit> = None;
    let mut consider = |fit: GelFit, scores: &mut Vec<GelScore>| {
        let score = GelScore {
            gel: fit.best,
            mae: fit.mae,
        };
        progress(&score);
        scores.push(score);
        if best.as_ref().is_none_or(|b| fit.mae < b.mae) {
            best = Some(fit);
        }
    };
    for (i, &thickness) in thicknesses.iter().enumerate() {
        for (j, &poisson) in poissons.iter().enumerate() {
            let gel = GelShape {
                thickness,
                poisson,
                dx,
            };
            let fit = score_gel(gel, presses, background, first, options, threads)?;
            grid[i][j] = fit.mae;
            consider(fit, &mut scores);
        }
    }
    // The score's valley runs across the grid (a thicker gel of higher Poisson's ratio
    // sags much as a thinner one of lower ratio) and is bumpy along it (the gel's top moves
    // through the grid's cells as its thickness changes): a search along the valley from
    // the grid's best stops in a bump. So the thickness is refined at every Poisson's ratio
    // of the grid, by a golden-section search between the neighbours of that ratio's best
    // thickness, and the ratio then refined at the best of those, between its neighbours.
    let bracket = |values: &[f64], k: usize| {
        (
            values[k.saturating_sub(1)],
            values[(k + 1).min(values.len() - 1)],
        )
    };
    let mut refine = |at: GelShape, thickness_axis: bool, (lo, hi): (f64, f64)| {
        if hi <= lo {
            return Ok(None);
        }
        let mut failure = None;
        let found = golden(
            |x| {
                let gel = match thickness_axis {
                    true => GelShape { thickness: x, ..at },
                    false => GelShape { poisson: x, ..at },
                };
                match score_gel(gel, presses, background, first, options, threads) {
                    Ok(fit) => {
                        let mae = fit.mae;
                        consider(fit, &mut scores);
                        mae
                    }
                    Err(e) => {
                        failure = Some(e);
                        f64::INFINITY
                    }
                }
            },
            lo,
            hi,
            REFINE_STEPS,
        );
        failure.map_or(Ok(Some(found)), Err)
    };
    // Per Poisson's ratio: its best thickness, refined, and the score there.
    let mut rows = Vec::with_capacity(poissons.len());
    for (j, &poisson) in poissons.iter().enumerate() {
        let i = (0..thicknesses.len())
            .min_by(|&a, &b| grid[a][j].total_cmp(&grid[b][j]))
            .expect("a non-empty grid");
        let at = GelShape {
            thickness: thicknesses[i],
            poisson,
            dx,
        };
        let row = match refine(at, true, bracket(thicknesses, i))? {
            Some((t, mae)) if mae < grid[i][j] => (mae, GelShape { thickness: t, ..at }, j),
            _ => (grid[i][j], at, j),
        };
        rows.push(row);
    }
    let (_, at, j) = rows
        .into_iter()
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .expect("a non-empty grid");
    refine(at, false, bracket(poissons, j))?;
    let mut fit = best.expect("a non-empty grid");
    fit.grid = scores;
    if search.blurs.iter().any(|&b| b != 0.0) {
        let progress = |b: &BlurScore| {
            eprintln!(
                "blur {:.3} mm: region MAE {:.3}, SSIM {:.4}",
                b.blur * 1e3,
                b.mae,
                b.ssim
            )
        };
        let (_, blurred) = fit_blur(
            fit.best,
            presses,
            background,
            first,
            options,
            &search.blurs,
            threads,
            progress,
        )?;
        fit = GelFit {
            grid: fit.grid,
            ..blurred
        };
    }
    Ok(fit)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A press of a ball of radius 2 mm whose drawn circle has `a` pixels of 0.01 mm, its
    /// detected circle 1.5 times wider.
    fn press(a: f64) -> Press {
        let circle = |radius| Contact {
            centre: [10.0, 10.0],
            radius,
        };
        Press {
            name: "p".into(),
            image: RgbImage {
                width: 1,
                height: 1,
                data: vec![0.0; CHANNELS],
            },
            ball_radius: 2e-3,
            pixel_size: 1e-5,
            contact: circle(1.5 * a),
            given: Some(circle(a)),
            depth: None,
            force: None,
            detected: true,
        }
    }

    /// The depth search's upper end is the half-space's depth for the drawn circle:
    /// Hertz's `a^2 / R` (twice the cap's depth) for a small circle, more than twice the
    /// cap's for a wide one (Sneddon's sphere), never the ball's radius; and a press whose
    /// images match best at 1.9 times the cap's depth (a soft gel's, beyond the 1.6 times
    /// the search stopped at before) is found there.
    #[test]
    fn the_depth_search_reaches_the_half_spaces_depth() {
        let small = press(10.0);
        let (a, r) = (1e-4, 2e-3);
        assert_eq!(
            contact_radius(&small),
            a,
            "the drawn circle, not the detected one"
        );
        let hertz = a * a / r;
        assert!((half_space_depth(&small) / hertz - 1.0).abs() < 1e-3);
        assert!((half_space_depth(&small) / cap_depth(&small) - 2.0).abs() < 2e-3);
        for a in [50.0, 100.0, 150.0] {
            let p = press(a);
            let (cap, deep) = (cap_depth(&p), half_space_depth(&p));
            assert!(
                deep > 2.0 * cap && deep < p.ball_radius,
                "{a}: {cap} {deep}"
            );
        }
        let p = press(100.0);
        let target = 1.9 * cap_depth(&p);
        let (found, _) = press_depth(&p, |d| (d - target).abs());
        assert!(
            (found / target - 1.0).abs() < 0.01,
            "{found} against {target}"
        );
    }

    /// The golden section finds a parabola's minimum to its bracket's final width.
    #[test]
    fn golden_section_finds_a_minimum() {
        let (x, fx) = golden(|x| (x - 0.3).powi(2) + 1.0, 0.0, 1.0, 30);
        assert!((x - 0.3).abs() < 1e-6, "{x}");
        assert!((fx - 1.0).abs() < 1e-12);
    }
}
