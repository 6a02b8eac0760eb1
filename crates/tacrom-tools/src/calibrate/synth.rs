//! Synthetic calibration sets: ball presses rendered with the built-in optics, whose
//! surface normals are known exactly, in the folder layout `tacrom calibrate` reads. A
//! calibration from such a set must reproduce the built-in optics.

use std::path::{Path, PathBuf};

use tacrom::geometry::PixelGrid;
use tacrom::render::rgb::{render, Optics, CHANNELS, FULL_SCALE};

use super::{file_error, fit, CalibrateError, Contact, PressEntry, PressList, PRESS_LIST};
use crate::datagen::Rng;

/// What to synthesize.
#[derive(Clone, Debug)]
pub struct SynthOptions {
    /// The folder to write.
    pub out: PathBuf,
    /// Number of presses.
    pub presses: usize,
    /// Image width and height (pixels).
    pub resolution: [usize; 2],
    /// Pixel size (m).
    pub pixel_size: f64,
    /// Seed: press `i` of a seed is the same press whatever the count.
    pub seed: u64,
    /// Write each press's contact into `presses.json` (else it must be detected).
    pub with_contact: bool,
    /// Press this gel (the linear coarse gel of [`super::gel`], each press to the depth of
    /// the rigid cap of its contact circle) instead of rendering the rigid cap: a set whose
    /// gel a calibration must recover.
    pub gel: Option<super::gel::GelShape>,
    /// Write each press's depth into `presses.json` (else the gel fit finds it).
    pub with_depth: bool,
    /// Write each press's normal force on a gel of this Young's modulus (Pa) into
    /// `presses.json` (`force_n`; needs `gel`): a set whose modulus a calibration must
    /// recover.
    pub young: Option<f64>,
    /// Blur each press's depth image by a Gaussian of this standard deviation (m) before
    /// shading it ([`tacrom::render::rgb::blur_depth`]): a set whose optics' blur a
    /// calibration must recover.
    pub blur: f64,
}

impl SynthOptions {
    /// 24 presses of 320 x 240 pixels of 0.075 mm (the default sensor's image), seed 1,
    /// contacts written.
    pub fn new(out: PathBuf) -> Self {
        SynthOptions {
            out,
            presses: 24,
            resolution: [320, 240],
            pixel_size: 0.075e-3,
            seed: 1,
            with_contact: true,
            gel: None,
            with_depth: false,
            young: None,
            blur: 0.0,
        }
    }
}

/// Ball radii of the synthetic presses (m): the 3 to 8 mm balls of calibration sets.
const BALL_RADIUS: [f64; 2] = [1.5e-3, 4e-3];
/// Contact radius as a fraction of the ball radius: slopes at the contact edge from 0.2
/// to 0.75 (11 to 37 degrees), within the built-in lights' unsaturated range.
const CONTACT_FRACTION: [f64; 2] = [0.2, 0.6];

/// The image (`(H, W, 3)`, 0..255, not rounded) of a ball of `ball_radius` pressed to
/// `contact` on `grid`, rendered with `optics` from the rigid cap's depth.
pub fn render_press(
    optics: &Optics,
    grid: &PixelGrid,
    ball_radius: f64,
    contact: &Contact,
) -> Vec<f64> {
    let depth = fit::ball_depth(grid, ball_radius, contact);
    let mut out = vec![0.0; CHANNELS * grid.width * grid.height];
    render(optics, grid, &depth, &mut out);
    out
}

/// Press `index` of a set seeded `seed` on a `w x h` image of `pixel` metres: ball radius
/// (m) and contact (pixels), the contact inside the image with 3 pixels to spare.
pub fn press(seed: u64, index: usize, [w, h]: [usize; 2], pixel: f64) -> (f64, Contact) {
    let mut rng = Rng::new(seed, index as u64);
    let radius = rng.uniform(BALL_RADIUS[0], BALL_RADIUS[1]);
    let fraction = rng.uniform(CONTACT_FRACTION[0], CONTACT_FRACTION[1]);
    let largest = 0.4 * w.min(h) as f64 - 3.0;
    let a = (fraction * radius / pixel)
        .min(largest)
        .max(4.0)
        .min(0.9 * radius / pixel);
    let margin = a + 3.0;
    let centre = [
        rng.uniform(margin, (w as f64 - 1.0 - margin).max(margin)),
        rng.uniform(margin, (h as f64 - 1.0 - margin).max(margin)),
    ];
    (radius, Contact { centre, radius: a })
}

/// Writes an 8-bit PNG of an `(H, W, 3)` image (values rounded, clamped to 0..255).
pub fn write_png8(
    path: &Path,
    width: usize,
    height: usize,
    rgb: &[f64],
) -> Result<(), CalibrateError> {
    let bytes: Vec<u8> = rgb
        .iter()
        .map(|v| v.round().clamp(0.0, FULL_SCALE) as u8)
        .collect();
    image::save_buffer(
        path,
        &bytes,
        width as u32,
        height as u32,
        image::ExtendedColorType::Rgb8,
    )
    .map_err(|e| file_error(path, e))
}

/// Writes the set of `o`: `background.png`, `press_NNN.png` and `presses.json`; returns
/// each press's entry and its true contact.
pub fn synthesize(o: &SynthOptions) -> Result<Vec<(PressEntry, Contact)>, CalibrateError> {
    let [w, h] = o.resolution;
    if w < 16 || h < 16 || o.presses == 0 || !(o.pixel_size.is_finite() && o.pixel_size > 0.0) {
        return Err(CalibrateError::Usage(format!(
            "a synthetic set needs presses, at least 16 x 16 pixels and a positive pixel size \
             ({} presses, {w} x {h}, {} mm)",
            o.presses,
            o.pixel_size * 1e3
        )));
    }
    std::fs::create_dir_all(&o.out).map_err(|e| file_error(&o.out, e))?;
    let optics = Optics::default();
    let grid = PixelGrid {
        width: w,
        height: h,
        fov_x: w as f64 * o.pixel_size,
        fov_y: h as f64 * o.pixel_size,
    };
    let flat = vec![0.0; w * h];
    let mut background = vec![0.0; CHANNELS * w * h];
    render(&optics, &grid, &flat, &mut background);
    write_png8(&o.out.join("background.png"), w, h, &background)?;
    let mut presses = Vec::with_capacity(o.presses);
    let mut gel = match o.gel {
        Some(g) => Some(super::gel::PressModel::new(g, &grid, 1).map_err(CalibrateError::Usage)?),
        None => None,
    };
    let mut forces = match (o.young, o.gel) {
        (None, _) => None,
        (Some(young), Some(g)) => Some(
            super::gel::PressModel::forces(g, &grid, young, 1).map_err(CalibrateError::Usage)?,
        ),
        (Some(_), None) => {
            return Err(CalibrateError::Usage(
                "a synthetic set's forces need a gel: a rigid cap carries none".into(),
            ))
        }
    };
    for i in 0..o.presses {
        let (radius, contact) = press(o.seed, i, o.resolution, o.pixel_size);
        let name = format!("press_{i:03}.png");
        let a = contact.radius * o.pixel_size;
        let depth = radius - (radius * radius - a * a).sqrt();
        let surface = match &mut gel {
            None => fit::ball_depth(&grid, radius, &contact),
            Some(model) => model.press(radius, &contact, depth).to_vec(),
        };
        let force_n = forces
            .as_mut()
            .map(|model| super::gel::normal_force(model.press(radius, &contact, depth)));
        let mut blurred = Vec::new();
        tacrom::render::rgb::blur_depth(&grid, &surface, o.blur, &mut blurred);
        let mut img = vec![0.0; CHANNELS * w * h];
        render(&optics, &grid, &blurred, &mut img);
        write_png8(&o.out.join(&name), w, h, &img)?;
        let entry = PressEntry {
            image: name,
            ball_radius_mm: radius * 1e3,
            pixel_size_mm: o.pixel_size * 1e3,
            center_px: o.with_contact.then_some(contact.centre),
            contact_radius_px: o.with_contact.then_some(contact.radius),
            depth_mm: o.with_depth.then_some(depth * 1e3),
            force_n,
        };
        presses.push((entry, contact));
    }
    let list = PressList {
        background: "background.png".into(),
        presses: presses.iter().map(|(e, _)| e.clone()).collect(),
    };
    let path = o.out.join(PRESS_LIST);
    let text = serde_json::to_string_pretty(&list).map_err(|e| file_error(&path, e))?;
    std::fs::write(&path, text).map_err(|e| file_error(&path, e))?;
    Ok(presses)
}
