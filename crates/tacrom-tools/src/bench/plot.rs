//! The report's figures, drawn with `plotters` into an RGB buffer and saved as PNG: error
//! against run time on log axes, error against press depth per mode, and press panels
//! (reference, each mode, error maps, colour bars with units).
//!
//! Text uses DejaVu Sans, embedded by the `dejavu` crate (Bitstream Vera licence), so the
//! figures need no system fonts.

use std::ops::Range;
use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

/// Colours of successive modes in the figures (ten, so that the quick profile's modes
/// each have their own).
pub const PALETTE: &[RGBColor] = &[
    RGBColor(214, 96, 20),
    RGBColor(30, 110, 190),
    RGBColor(40, 150, 60),
    RGBColor(150, 60, 170),
    RGBColor(200, 40, 60),
    RGBColor(110, 110, 20),
    RGBColor(20, 150, 160),
    RGBColor(230, 160, 0),
    RGBColor(130, 80, 40),
    RGBColor(220, 110, 170),
];

/// Mid grey, for secondary lines and text.
const GREY: RGBColor = RGBColor(120, 120, 120);

/// The font family every text of the figures uses.
const FONT: &str = "sans-serif";

/// A figure that could not be drawn or saved.
#[derive(Debug, thiserror::Error)]
pub enum FigureError {
    /// Drawing failed.
    #[error("drawing failed: {0}")]
    Draw(String),
    /// Encoding or writing the PNG failed.
    #[error(transparent)]
    Png(#[from] image::ImageError),
}

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for FigureError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        FigureError::Draw(e.to_string())
    }
}

/// A drawn figure: RGB pixels, row-major.
#[derive(Clone, Debug)]
pub struct Figure {
    /// Width (pixels).
    pub width: u32,
    /// Height (pixels).
    pub height: u32,
    /// Three bytes per pixel.
    pub rgb: Vec<u8>,
}

impl Figure {
    /// A white `width x height` figure drawn by `draw` on its whole area.
    fn draw(
        width: u32,
        height: u32,
        draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), FigureError>,
    ) -> Result<Self, FigureError> {
        register_fonts();
        let mut rgb = vec![255u8; width as usize * height as usize * 3];
        {
            let root = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
            draw(&root)?;
            root.present()?;
        }
        Ok(Self { width, height, rgb })
    }

    /// Writes the figure as a PNG.
    pub fn save_png(&self, path: &Path) -> Result<(), FigureError> {
        image::save_buffer(
            path,
            &self.rgb,
            self.width,
            self.height,
            image::ExtendedColorType::Rgb8,
        )?;
        Ok(())
    }
}

/// Registers the embedded DejaVu Sans as [`FONT`], once per process.
fn register_fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        for (style, bytes) in [
            (FontStyle::Normal, dejavu::sans::regular()),
            (FontStyle::Bold, dejavu::sans::bold()),
        ] {
            if register_font(FONT, style, bytes).is_err() {
                unreachable!("the embedded DejaVu Sans is a valid font");
            }
        }
    });
}

fn text(size: u32) -> TextStyle<'static> {
    (FONT, size).into_font().color(&BLACK)
}

/// The shape of a mode's marker; modes take them in turn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Marker {
    /// A disc.
    Circle,
    /// A square.
    Square,
    /// A triangle, point up.
    Triangle,
    /// A diamond.
    Diamond,
}

impl Marker {
    /// The markers in the order modes take them.
    pub const ALL: [Marker; 4] = [
        Marker::Circle,
        Marker::Square,
        Marker::Triangle,
        Marker::Diamond,
    ];

    /// The outline, as pixel offsets from the centre, for a marker of radius `r`.
    fn outline(self, r: i32) -> Vec<(i32, i32)> {
        let polygon = |n: usize, phase: f64, scale: f64| {
            (0..n)
                .map(|k| {
                    let a = phase + std::f64::consts::TAU * k as f64 / n as f64;
                    let s = scale * f64::from(r);
                    ((s * a.cos()).round() as i32, (-s * a.sin()).round() as i32)
                })
                .collect()
        };
        match self {
            Marker::Circle => polygon(20, 0.0, 1.0),
            Marker::Square => vec![(-r, -r), (r, -r), (r, r), (-r, r)],
            Marker::Triangle => polygon(3, std::f64::consts::FRAC_PI_2, 1.25),
            Marker::Diamond => polygon(4, std::f64::consts::FRAC_PI_2, 1.3),
        }
    }

    /// The marker at `at`: filled, or an outline two pixels wide.
    /// The closed outline of a marker of radius `r`, for a hollow marker.
    fn closed_outline(self, r: i32) -> Vec<(i32, i32)> {
        let mut closed = self.outline(r);
        closed.push(closed[0]);
        closed
    }
}

/// One point of the error-time plot.
#[derive(Clone, Debug)]
pub struct PlotPoint {
    /// The mode, named in the legend.
    pub label: String,
    /// Milliseconds per evaluation.
    pub x: f64,
    /// Error.
    pub y: f64,
    /// Colour of the mode.
    pub colour: RGBColor,
    /// Marker of the mode.
    pub marker: Marker,
    /// Solver threads: one thread is drawn filled, more hollow.
    pub threads: usize,
}

/// What the error-time plot shows.
#[derive(Clone, Debug)]
pub struct ErrorTimePlot {
    /// Title, at the top.
    pub title: String,
    /// Label of the x axis.
    pub x_label: String,
    /// Label of the y axis.
    pub y_label: String,
    /// The points; those with a non-positive or non-finite coordinate are left out (a log
    /// axis cannot show them) and listed in a note beside the plot.
    pub points: Vec<PlotPoint>,
    /// A vertical dashed line with its label (the reference's time), if any.
    pub reference: Option<(f64, String)>,
}

/// Decade range `[lo, hi]` (powers of ten) covering `values`, at least one decade wide.
fn decades(values: impl Iterator<Item = f64>) -> (i32, i32) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite() && *v > 0.0) {
        lo = lo.min(v.log10());
        hi = hi.max(v.log10());
    }
    if !lo.is_finite() {
        return (0, 1);
    }
    let (l, mut h) = (lo.floor() as i32, hi.ceil() as i32);
    if h <= l {
        h = l + 1;
    }
    (l, h)
}

/// Tick label of a log axis: plain digits from 0.001 to below 1e6, else `1e<e>` style.
pub fn tick_label(v: f64) -> String {
    if !(1e-3..1e6).contains(&v) {
        return format!("{v:.0e}");
    }
    let decimals = (-v.log10().floor()).max(0.0) as usize;
    format!("{v:.decimals$}")
}

/// Height of a legend line (pixels).
const LEGEND_LINE: i32 = 26;

/// The legend's bold "modes" heading at the top of `area`; returns the y of its first
/// entry.
fn legend_heading(area: &DrawingArea<BitMapBackend<'_>, Shift>) -> Result<i32, FigureError> {
    let y = 70;
    area.draw_text(
        "modes",
        &(FONT, 17).into_font().style(FontStyle::Bold).color(&BLACK),
        (10, y - 24),
    )?;
    Ok(y)
}

fn range_of((lo, hi): (i32, i32)) -> Range<f64> {
    10f64.powi(lo)..10f64.powi(hi)
}

impl ErrorTimePlot {
    /// Draws the plot: log-log axes on the left, the legend and notes on the right.
    pub fn render(&self) -> Result<Figure, FigureError> {
        Figure::draw(1100, 640, |root| {
            root.fill(&WHITE)?;
            let (plot, side) = root.split_horizontally(800);
            let ok = |p: &&PlotPoint| p.x.is_finite() && p.x > 0.0 && p.y.is_finite() && p.y > 0.0;
            let shown: Vec<&PlotPoint> = self.points.iter().filter(ok).collect();
            let xs = shown
                .iter()
                .map(|p| p.x)
                .chain(self.reference.iter().map(|r| r.0));
            let (xr, yr) = (
                range_of(decades(xs)),
                range_of(decades(shown.iter().map(|p| p.y))),
            );
            let mut chart = ChartBuilder::on(&plot)
                .caption(&self.title, text(20))
                .margin(16)
                .x_label_area_size(56)
                .y_label_area_size(76)
                .build_cartesian_2d(xr.clone().log_scale(), yr.clone().log_scale())?;
            chart
                .configure_mesh()
                .x_desc(&self.x_label)
                .y_desc(&self.y_label)
                .label_style(text(15))
                .axis_desc_style(text(17))
                .x_label_formatter(&|v| tick_label(*v))
                .y_label_formatter(&|v| tick_label(*v))
                .light_line_style(RGBColor(235, 235, 235))
                .bold_line_style(RGBColor(210, 210, 210))
                .draw()?;
            if let Some((x, _)) = self
                .reference
                .as_ref()
                .filter(|r| r.0.is_finite() && r.0 > 0.0)
            {
                chart.draw_series(DashedLineSeries::new(
                    [(*x, yr.start), (*x, yr.end)],
                    8,
                    6,
                    GREY.stroke_width(2),
                ))?;
            }
            // One solver thread filled, more hollow.
            chart.draw_series(shown.iter().filter(|p| p.threads <= 1).map(|p| {
                EmptyElement::at((p.x, p.y)) + Polygon::new(p.marker.outline(6), p.colour.filled())
            }))?;
            chart.draw_series(shown.iter().filter(|p| p.threads > 1).map(|p| {
                EmptyElement::at((p.x, p.y))
                    + PathElement::new(p.marker.closed_outline(6), p.colour.stroke_width(2))
            }))?;
            self.legend(&side)
        })
    }

    /// The legend (one entry per mode, the thread markers, the reference line) and the
    /// notes, one line each, top to bottom.
    fn legend(&self, area: &DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), FigureError> {
        let mut modes: Vec<&PlotPoint> = Vec::new();
        for p in &self.points {
            if !modes.iter().any(|m| m.label == p.label) {
                modes.push(p);
            }
        }
        let line = LEGEND_LINE;
        let mut y = legend_heading(area)?;
        for m in &modes {
            area.draw(
                &(EmptyElement::at((22, y + 8))
                    + Polygon::new(m.marker.outline(6), m.colour.filled())),
            )?;
            area.draw_text(&m.label, &text(16), (40, y))?;
            y += line;
        }
        y += line / 2;
        for (filled, what) in [(true, "1 thread"), (false, "2 or more threads")] {
            let at = EmptyElement::at((22, y + 8));
            if filled {
                area.draw(&(at + Polygon::new(Marker::Circle.outline(6), GREY.filled())))?;
            } else {
                area.draw(
                    &(at + PathElement::new(
                        Marker::Circle.closed_outline(6),
                        GREY.stroke_width(2),
                    )),
                )?;
            }
            area.draw_text(what, &text(16), (40, y))?;
            y += line;
        }
        if let Some((x, label)) = &self.reference {
            y += line / 2;
            area.draw(&PathElement::new(
                [(14, y + 8), (20, y + 8)],
                GREY.stroke_width(2),
            ))?;
            area.draw(&PathElement::new(
                [(25, y + 8), (31, y + 8)],
                GREY.stroke_width(2),
            ))?;
            area.draw_text(label, &text(14), (40, y))?;
            area.draw_text(&format!("{x:.0} ms"), &text(14), (40, y + 18))?;
            y += line + 18;
        }
        let hidden: Vec<&str> = self
            .points
            .iter()
            .filter(|p| !(p.x.is_finite() && p.x > 0.0 && p.y.is_finite() && p.y > 0.0))
            .map(|p| p.label.as_str())
            .collect();
        y += line / 2;
        if !hidden.is_empty() {
            area.draw_text(
                "not shown (zero or no value):",
                &text(14).color(&GREY),
                (10, y),
            )?;
            y += 18;
            area.draw_text(&hidden.join(", "), &text(14).color(&GREY), (10, y))?;
            y += 18;
        }
        area.draw_text("log scales", &text(14).color(&GREY), (10, y))?;
        Ok(())
    }

    /// Renders and saves the plot.
    pub fn save(&self, path: &Path) -> Result<(), FigureError> {
        self.render()?.save_png(path)
    }
}

/// One mode's curve in [`DepthPlot`].
#[derive(Clone, Debug)]
pub struct DepthSeries {
    /// The mode, named in the legend.
    pub label: String,
    /// `(depth, error)` per depth, in depth order.
    pub points: Vec<(f64, f64)>,
    /// Colour of the mode.
    pub colour: RGBColor,
    /// Marker of the mode.
    pub marker: Marker,
}

/// Error against press depth, one curve per mode: linear depth, log error.
#[derive(Clone, Debug)]
pub struct DepthPlot {
    /// Title, at the top.
    pub title: String,
    /// Label of the x axis.
    pub x_label: String,
    /// Label of the y axis.
    pub y_label: String,
    /// The curves; points with a non-positive or non-finite error are left out.
    pub series: Vec<DepthSeries>,
}

impl DepthPlot {
    /// Draws the plot: the curves on the left, the legend on the right.
    pub fn render(&self) -> Result<Figure, FigureError> {
        Figure::draw(1000, 560, |root| {
            root.fill(&WHITE)?;
            let (plot, side) = root.split_horizontally(760);
            let ok = |p: &&(f64, f64)| p.0.is_finite() && p.1.is_finite() && p.1 > 0.0;
            let all = || self.series.iter().flat_map(|s| s.points.iter().filter(ok));
            let (mut x0, mut x1) = (f64::INFINITY, f64::NEG_INFINITY);
            for p in all() {
                x0 = x0.min(p.0);
                x1 = x1.max(p.0);
            }
            if !x0.is_finite() {
                (x0, x1) = (0.0, 1.0);
            }
            let pad = 0.05 * (x1 - x0).max(1e-9);
            let xr = (x0 - pad).max(0.0)..x1 + pad;
            let yr = range_of(decades(all().map(|p| p.1)));
            let mut chart = ChartBuilder::on(&plot)
                .caption(&self.title, text(20))
                .margin(16)
                .x_label_area_size(56)
                .y_label_area_size(76)
                .build_cartesian_2d(xr, yr.log_scale())?;
            chart
                .configure_mesh()
                .x_desc(&self.x_label)
                .y_desc(&self.y_label)
                .label_style(text(15))
                .axis_desc_style(text(17))
                .x_label_formatter(&|v| format!("{v:.1}"))
                .y_label_formatter(&|v| tick_label(*v))
                .light_line_style(RGBColor(235, 235, 235))
                .bold_line_style(RGBColor(210, 210, 210))
                .draw()?;
            for s in &self.series {
                let shown: Vec<(f64, f64)> = s.points.iter().filter(ok).copied().collect();
                chart.draw_series(LineSeries::new(shown.clone(), s.colour.stroke_width(2)))?;
                chart.draw_series(shown.iter().map(|&(x, y)| {
                    EmptyElement::at((x, y)) + Polygon::new(s.marker.outline(6), s.colour.filled())
                }))?;
            }
            let line = LEGEND_LINE;
            let mut y = legend_heading(&side)?;
            for s in &self.series {
                side.draw(&PathElement::new(
                    [(8, y + 8), (36, y + 8)],
                    s.colour.stroke_width(2),
                ))?;
                side.draw(
                    &(EmptyElement::at((22, y + 8))
                        + Polygon::new(s.marker.outline(6), s.colour.filled())),
                )?;
                side.draw_text(&s.label, &text(16), (44, y))?;
                y += line;
            }
            side.draw_text(
                "log error scale",
                &text(14).color(&GREY),
                (10, y + line / 2),
            )?;
            Ok(())
        })
    }

    /// Renders and saves the plot.
    pub fn save(&self, path: &Path) -> Result<(), FigureError> {
        self.render()?.save_png(path)
    }
}

/// One image of a panel.
#[derive(Clone, Debug)]
pub struct PanelImage {
    /// Title above the image.
    pub title: String,
    /// Values, row-major, `width x height`, row 0 at +y.
    pub values: Vec<f64>,
}

/// A press panel: the reference and each mode's depth on the first row (one colour scale),
/// each mode's signed error (mode minus reference) on the second, under its mode (one
/// symmetric colour scale), each row with its colour bar, and on the third the RGB image a
/// GelSight-type camera would see of each depth (the sensor's default optics,
/// [`tacrom::render::rgb::Optics`]).
#[derive(Clone, Debug)]
pub struct Panel {
    /// Title of the whole panel.
    pub title: String,
    /// Image width (pixels).
    pub width: usize,
    /// Image height (pixels).
    pub height: usize,
    /// Field of view (m, x and y).
    pub fov: [f64; 2],
    /// Reference depth (m).
    pub reference: PanelImage,
    /// Each mode's depth (m).
    pub modes: Vec<PanelImage>,
}

/// Width of an image cell of the panels (pixels).
const CELL_W: u32 = 300;
/// Width of the colour bar column (pixels).
const BAR_W: u32 = 120;

/// Height of an image cell for images of `width x height` pixels.
fn cell_height(width: usize, height: usize) -> u32 {
    let image_w = f64::from(CELL_W - 60);
    (image_w * height.max(1) as f64 / width.max(1) as f64) as u32 + 80
}

/// One image in `area`, with its title and axes in millimetres; `colour` maps a value.
fn draw_image(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    title: &str,
    geometry: (usize, usize, [f64; 2]),
    values: &[f64],
    colour: &dyn Fn(f64) -> RGBColor,
) -> Result<(), FigureError> {
    let at = |k: usize| colour(values.get(k).copied().unwrap_or(f64::NAN));
    draw_pixels(area, title, geometry, &at)
}

/// One RGB image (`3 x width x height` values on the 8-bit scale, row-major) in `area`,
/// with its title and axes in millimetres.
fn draw_rgb(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    title: &str,
    geometry: (usize, usize, [f64; 2]),
    rgb: &[f64],
) -> Result<(), FigureError> {
    let byte = |k: usize| rgb.get(k).map_or(0, |v| v.clamp(0.0, 255.0).round() as u8);
    let at = |k: usize| RGBColor(byte(3 * k), byte(3 * k + 1), byte(3 * k + 2));
    draw_pixels(area, title, geometry, &at)
}

/// The pixels of a `w x h` image (row 0 at +y) in `area`, pixel `k` (row-major) in colour
/// `at(k)`, with a title and axes in millimetres.
fn draw_pixels(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    title: &str,
    (w, h, fov): (usize, usize, [f64; 2]),
    at: &dyn Fn(usize) -> RGBColor,
) -> Result<(), FigureError> {
    let (fx, fy) = (fov[0] * 1e3, fov[1] * 1e3);
    let mut chart = ChartBuilder::on(area)
        .caption(title, text(15))
        .margin(6)
        .x_label_area_size(34)
        .y_label_area_size(40)
        .build_cartesian_2d(-fx / 2.0..fx / 2.0, -fy / 2.0..fy / 2.0)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_labels(5)
        .y_labels(5)
        .label_style(text(12))
        .x_desc("x (mm)")
        .axis_desc_style(text(12))
        .draw()?;
    let (px, py) = (fx / w.max(1) as f64, fy / h.max(1) as f64);
    chart.draw_series((0..h).flat_map(|r| {
        (0..w).map(move |c| {
            let (x0, y1) = (-fx / 2.0 + c as f64 * px, fy / 2.0 - r as f64 * py);
            Rectangle::new([(x0, y1 - py), (x0 + px, y1)], at(r * w + c).filled())
        })
    }))?;
    Ok(())
}

/// A vertical colour bar in `area` for values `lo..hi`, its axis labelled `unit`.
fn colour_bar(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    (lo, hi): (f64, f64),
    unit: &str,
    colour: &dyn Fn(f64) -> RGBColor,
) -> Result<(), FigureError> {
    let mut chart = ChartBuilder::on(area)
        .margin_top(30)
        .margin_bottom(40)
        .margin_left(8)
        .right_y_label_area_size(70)
        .build_cartesian_2d(0.0..1.0, lo..hi)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_labels(5)
        .label_style(text(12))
        .y_desc(unit)
        .axis_desc_style(text(13))
        .draw()?;
    let steps = 100;
    let dv = (hi - lo) / steps as f64;
    chart.draw_series((0..steps).map(|i| {
        let v = lo + i as f64 * dv;
        Rectangle::new([(0.0, v), (1.0, v + dv)], colour(v + 0.5 * dv).filled())
    }))?;
    Ok(())
}

impl Panel {
    /// Draws the panel.
    pub fn render(&self) -> Result<Figure, FigureError> {
        let (w, h) = (self.width, self.height);
        let cols = 1 + self.modes.len();
        let cell_h = cell_height(w, h);
        let width = cols as u32 * CELL_W + BAR_W;
        let height = 44 + 3 * cell_h;
        let geometry = (w, h, self.fov);
        Figure::draw(width, height, |root| {
            root.fill(&WHITE)?;
            let (title, body) = root.split_vertically(44);
            title.draw_text(&self.title, &text(20), (12, 12))?;
            let (grid, bars) = body.split_horizontally(cols as u32 * CELL_W);
            let cells = grid.split_evenly((3, cols));

            // Depth in micrometres, one scale for the row.
            let um = |v: &[f64]| v.iter().map(|d| d * 1e6).collect::<Vec<_>>();
            let dmax = self
                .reference
                .values
                .iter()
                .chain(self.modes.iter().flat_map(|m| &m.values))
                .filter(|v| v.is_finite())
                .fold(0.0f64, |a, &b| a.max(b * 1e6))
                .max(1e-3);
            let seq = move |v: f64| sequential(v / dmax);
            let images = std::iter::once(&self.reference).chain(&self.modes);
            for (cell, img) in cells.iter().zip(images) {
                draw_image(cell, &img.title, geometry, &um(&img.values), &seq)?;
            }

            // Signed errors, under their modes.
            let errors: Vec<Vec<f64>> = self
                .modes
                .iter()
                .map(|m| {
                    m.values
                        .iter()
                        .zip(&self.reference.values)
                        .map(|(a, b)| (a - b) * 1e6)
                        .collect()
                })
                .collect();
            let emax = errors
                .iter()
                .flatten()
                .filter(|v| v.is_finite())
                .fold(0.0f64, |a, &b| a.max(b.abs()))
                .max(1e-3);
            let div = move |v: f64| diverging(v / emax);
            let note = &cells[cols];
            let middle = cell_h as i32 / 2;
            note.draw_text("error:", &text(15).color(&GREY), (20, middle - 20))?;
            note.draw_text("mode − reference", &text(15).color(&GREY), (20, middle))?;
            for ((cell, m), e) in cells[cols + 1..].iter().zip(&self.modes).zip(&errors) {
                draw_image(cell, &format!("{} − ref", m.title), geometry, e, &div)?;
            }

            // The RGB images, each shaded from its own depth.
            let pixels = tacrom::geometry::PixelGrid {
                width: w,
                height: h,
                fov_x: self.fov[0],
                fov_y: self.fov[1],
            };
            let optics = tacrom::render::rgb::Optics::default();
            let mut rgb = vec![0.0; 3 * w * h];
            let images = std::iter::once(&self.reference).chain(&self.modes);
            for (cell, img) in cells[2 * cols..].iter().zip(images) {
                if img.values.len() != w * h {
                    continue;
                }
                tacrom::render::rgb::render(&optics, &pixels, &img.values, &mut rgb);
                draw_rgb(cell, &format!("{} (RGB)", img.title), geometry, &rgb)?;
            }

            let bar_cells = bars.split_evenly((3, 1));
            colour_bar(&bar_cells[0], (0.0, dmax), "depth (µm)", &seq)?;
            colour_bar(&bar_cells[1], (-emax, emax), "error (µm)", &div)?;
            Ok(())
        })
    }

    /// Renders and saves the panel.
    pub fn save(&self, path: &Path) -> Result<(), FigureError> {
        self.render()?.save_png(path)
    }
}

/// One depth image (m) in the sequential colour map, with a title, axes in millimetres
/// and a colour bar in micrometres: what `tacrom render` writes.
pub fn depth_image(
    title: &str,
    (width, height): (usize, usize),
    fov: [f64; 2],
    depth: &[f64],
) -> Result<Figure, FigureError> {
    let image_w = 480u32;
    let image_h = (f64::from(image_w) * height.max(1) as f64 / width.max(1) as f64) as u32;
    Figure::draw(image_w + 80 + BAR_W, image_h + 120, |root| {
        root.fill(&WHITE)?;
        let (top, body) = root.split_vertically(40);
        top.draw_text(title, &text(16), (12, 12))?;
        let (left, bar) = body.split_horizontally(image_w + 80);
        let um: Vec<f64> = depth.iter().map(|d| d * 1e6).collect();
        let dmax = um
            .iter()
            .filter(|v| v.is_finite())
            .fold(0.0f64, |a, &b| a.max(b))
            .max(1e-3);
        let seq = move |v: f64| sequential(v / dmax);
        draw_image(&left, "depth", (width, height, fov), &um, &seq)?;
        colour_bar(&bar, (0.0, dmax), "depth (µm)", &seq)
    })
}

fn lerp_stops(stops: &[(f64, [u8; 3])], t: f64) -> RGBColor {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    for w in stops.windows(2) {
        let ((t0, c0), (t1, c1)) = (w[0], w[1]);
        if t <= t1 {
            let u = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
            let mix = |k: usize| {
                (f64::from(c0[k]) + u * (f64::from(c1[k]) - f64::from(c0[k]))).round() as u8
            };
            return RGBColor(mix(0), mix(1), mix(2));
        }
    }
    let [r, g, b] = stops[stops.len() - 1].1;
    RGBColor(r, g, b)
}

/// Sequential map for depth, `t` in [0, 1]: dark blue through teal and green to yellow.
pub fn sequential(t: f64) -> RGBColor {
    lerp_stops(
        &[
            (0.0, [30, 20, 80]),
            (0.25, [50, 90, 150]),
            (0.5, [40, 150, 140]),
            (0.75, [120, 200, 80]),
            (1.0, [250, 230, 40]),
        ],
        t,
    )
}

/// Diverging map for signed errors, `t` in [-1, 1]: blue, white at 0, red.
pub fn diverging(t: f64) -> RGBColor {
    lerp_stops(
        &[
            (0.0, [40, 60, 160]),
            (0.5, [250, 250, 250]),
            (1.0, [180, 30, 40]),
        ],
        0.5 * (t + 1.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decade_ranges_and_labels() {
        assert_eq!(decades([0.5, 30.0].into_iter()), (-1, 2));
        assert_eq!(decades([10.0].into_iter()), (1, 2));
        assert_eq!(decades([f64::NAN, -1.0].into_iter()), (0, 1));
        assert_eq!(tick_label(0.01), "0.01");
        assert_eq!(tick_label(0.02), "0.02");
        assert_eq!(tick_label(1000.0), "1000");
        assert_eq!(tick_label(1e7), "1e7");
    }

    #[test]
    fn colour_maps_hit_their_ends() {
        assert_eq!(sequential(0.0), RGBColor(30, 20, 80));
        assert_eq!(sequential(2.0), RGBColor(250, 230, 40));
        assert_eq!(diverging(0.0), RGBColor(250, 250, 250));
        assert_eq!(diverging(f64::NAN), diverging(-1.0));
    }

    #[test]
    fn plot_and_panel_render_without_panicking_on_odd_values() {
        let plot = ErrorTimePlot {
            title: "t".into(),
            x_label: "ms".into(),
            y_label: "um".into(),
            points: vec![
                PlotPoint {
                    label: "a".into(),
                    x: 1.0,
                    y: 2.0,
                    colour: PALETTE[0],
                    marker: Marker::Circle,
                    threads: 1,
                },
                PlotPoint {
                    label: "b".into(),
                    x: f64::NAN,
                    y: 0.0,
                    colour: PALETTE[1],
                    marker: Marker::Square,
                    threads: 2,
                },
            ],
            reference: Some((1e4, "fine".into())),
        };
        let c = plot.render().unwrap();
        assert!(c.width > 0);
        // Text is drawn: the figure holds dark pixels besides the white background.
        assert!(c.rgb.chunks(3).any(|p| p.iter().all(|&v| v < 60)));
        let panel = Panel {
            title: "p".into(),
            width: 4,
            height: 3,
            fov: [0.024, 0.018],
            reference: PanelImage {
                title: "ref".into(),
                values: vec![0.0; 12],
            },
            modes: vec![PanelImage {
                title: "m".into(),
                values: vec![f64::NAN; 12],
            }],
        };
        let c = panel.render().unwrap();
        assert!(c.height > 0);
        // The RGB row: the flat reference shows the default optics' grey background.
        let grey = [120u8, 125, 135];
        assert!(
            c.rgb.chunks(3).any(|p| p == grey),
            "no background-grey pixel in the RGB row"
        );
        let depth = DepthPlot {
            title: "t".into(),
            x_label: "mm".into(),
            y_label: "um".into(),
            series: vec![
                DepthSeries {
                    label: "a".into(),
                    points: vec![(0.2, 1.0), (0.5, f64::NAN), (1.0, 0.0)],
                    colour: PALETTE[0],
                    marker: Marker::Circle,
                },
                DepthSeries {
                    label: "b".into(),
                    points: Vec::new(),
                    colour: PALETTE[1],
                    marker: Marker::Square,
                },
            ],
        };
        let c = depth.render().unwrap();
        assert!(c.rgb.chunks(3).any(|p| p.iter().all(|&v| v < 60)));
    }
}
