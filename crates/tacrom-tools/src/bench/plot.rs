//! The report's figures: error against run time on log axes, and press panels (reference,
//! each mode, error maps, colour bars).

use std::path::Path;

use super::draw::{
    diverging, sequential, text_width, Canvas, Rgb, BLACK, GLYPH_H, GREY, GRID, WHITE,
};

/// Colours of successive modes in the figures.
pub const PALETTE: &[Rgb] = &[
    [214, 96, 20],
    [30, 110, 190],
    [40, 150, 60],
    [150, 60, 170],
    [200, 40, 60],
    [110, 110, 20],
    [20, 150, 160],
];

/// How a point is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Marker {
    /// A filled disc.
    Disc,
    /// A filled square.
    Square,
}

/// One point of the error-time plot.
#[derive(Clone, Debug)]
pub struct PlotPoint {
    /// Text beside the point.
    pub label: String,
    /// Milliseconds per evaluation.
    pub x: f64,
    /// Error.
    pub y: f64,
    /// Colour.
    pub colour: Rgb,
    /// Marker.
    pub marker: Marker,
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
    /// axis cannot show them) and listed in a note under the plot.
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

/// Tick label of `10^e`: plain digits from 0.001 to 100000, else `1e<e>`.
pub fn decade_label(e: i32) -> String {
    match e {
        -3..=-1 => format!("{}", 10f64.powi(e)),
        0..=5 => format!("{}", 10i64.pow(e as u32)),
        _ => format!("1e{e}"),
    }
}

impl ErrorTimePlot {
    /// Draws the plot (log-log) and writes it as a PNG.
    pub fn render(&self) -> Canvas {
        let (w, h) = (900i64, 620i64);
        let (left, right, top, bottom) = (90i64, 40i64, 50i64, 110i64);
        let mut c = Canvas::new(w as usize, h as usize, WHITE);
        let ok = |p: &&PlotPoint| p.x.is_finite() && p.x > 0.0 && p.y.is_finite() && p.y > 0.0;
        let shown: Vec<&PlotPoint> = self.points.iter().filter(ok).collect();
        let hidden: Vec<&PlotPoint> = self.points.iter().filter(|p| !ok(p)).collect();
        let xs = shown
            .iter()
            .map(|p| p.x)
            .chain(self.reference.iter().map(|r| r.0));
        let (x0, x1) = decades(xs);
        let (y0, y1) = decades(shown.iter().map(|p| p.y));
        let (pw, ph) = (w - left - right, h - top - bottom);
        let px = |x: f64| left + ((x.log10() - x0 as f64) / (x1 - x0) as f64 * pw as f64) as i64;
        let py =
            |y: f64| top + ph - ((y.log10() - y0 as f64) / (y1 - y0) as f64 * ph as f64) as i64;

        // Grid and ticks: a line per decade, minor ticks at 2..9.
        for e in x0..=x1 {
            let x = px(10f64.powi(e));
            c.line(x, top, x, top + ph, 1, GRID);
            let label = decade_label(e);
            c.text(
                x - text_width(&label, 2) as i64 / 2,
                top + ph + 10,
                &label,
                2,
                BLACK,
            );
            if e < x1 {
                for m in 2..10 {
                    let xm = px(m as f64 * 10f64.powi(e));
                    c.line(xm, top + ph - 5, xm, top + ph, 1, GREY);
                }
            }
        }
        for e in y0..=y1 {
            let y = py(10f64.powi(e));
            c.line(left, y, left + pw, y, 1, GRID);
            let label = decade_label(e);
            c.text(
                left - 8 - text_width(&label, 2) as i64,
                y - 7,
                &label,
                2,
                BLACK,
            );
            if e < y1 {
                for m in 2..10 {
                    let ym = py(m as f64 * 10f64.powi(e));
                    c.line(left, ym, left + 5, ym, 1, GREY);
                }
            }
        }
        c.rect(left, top, pw + 1, ph + 1, BLACK);

        // Titles.
        c.text(left, 15, &self.title, 2, BLACK);
        let xl = &self.x_label;
        c.text(
            left + (pw - text_width(xl, 2) as i64) / 2,
            top + ph + 34,
            xl,
            2,
            BLACK,
        );
        let yl = &self.y_label;
        c.text_up(12, top + (ph - text_width(yl, 2) as i64) / 2, yl, 2, BLACK);

        if let Some((x, label)) = &self.reference {
            if x.is_finite() && *x > 0.0 {
                let xr = px(*x);
                c.dashed_line(xr, top, xr, top + ph, 6, GREY);
                c.text_up(xr + 4, top + 4, label, 1, GREY);
            }
        }
        for p in &shown {
            let (x, y) = (px(p.x), py(p.y));
            match p.marker {
                Marker::Disc => c.disc(x, y, 6, p.colour),
                Marker::Square => c.fill_rect(x - 5, y - 5, 11, 11, p.colour),
            }
        }
        // One label per mode (points of one label share a colour), right of its rightmost
        // point unless it would leave the plot; a label that would overlap an earlier one
        // moves down a line.
        let mut placed: Vec<(i64, i64, i64)> = Vec::new();
        let mut labels: Vec<&str> = Vec::new();
        for p in &shown {
            if labels.contains(&p.label.as_str()) {
                continue;
            }
            labels.push(&p.label);
            let same = shown.iter().filter(|q| q.label == p.label);
            let (x, y) = same
                .map(|q| (px(q.x), py(q.y)))
                .max()
                .unwrap_or((px(p.x), py(p.y)));
            let tw = text_width(&p.label, 2) as i64;
            let lx = if x + 12 + tw < left + pw {
                x + 12
            } else {
                x - 12 - tw
            };
            let mut ly = y - 7;
            while placed
                .iter()
                .any(|&(ox, oy, ow)| (ly - oy).abs() < 16 && lx < ox + ow && ox < lx + tw)
            {
                ly += 16;
            }
            placed.push((lx, ly, tw));
            c.text(lx, ly, &p.label, 2, p.colour);
        }
        let mut note_y = top + ph + 62;
        if !hidden.is_empty() {
            let names: Vec<&str> = hidden.iter().map(|p| p.label.as_str()).collect();
            let note = format!("not shown (zero or no value): {}", names.join(", "));
            c.text(left, note_y, &note, 1, GREY);
            note_y += 12;
        }
        c.text(
            left,
            note_y,
            "disc: 1 thread, square: 2 or more threads; log scales",
            1,
            GREY,
        );
        c
    }

    /// Renders and saves the plot.
    pub fn save(&self, path: &Path) -> Result<(), image::ImageError> {
        self.render().save_png(path)
    }
}

/// One image of a panel.
#[derive(Clone, Debug)]
pub struct PanelImage {
    /// Title above the image.
    pub title: String,
    /// Values, row-major, `width x height`.
    pub values: Vec<f64>,
}

/// A press panel: the reference and each mode's depth on the first row (one colour scale),
/// each mode's signed error (mode minus reference) on the second, under its mode (one
/// symmetric colour scale), each row with its colour bar.
#[derive(Clone, Debug)]
pub struct Panel {
    /// Title of the whole panel.
    pub title: String,
    /// Image width (pixels).
    pub width: usize,
    /// Image height (pixels).
    pub height: usize,
    /// Reference depth (m).
    pub reference: PanelImage,
    /// Each mode's depth (m).
    pub modes: Vec<PanelImage>,
}

fn scale_for(width: usize, height: usize) -> usize {
    // Small images are enlarged (nearest neighbour) to about 240 pixels wide.
    (240 / width.max(1)).min(240 / height.max(1)).clamp(1, 8)
}

fn draw_image(
    c: &mut Canvas,
    x: i64,
    y: i64,
    img: &[f64],
    (w, h, s): (usize, usize, usize),
    colour: &dyn Fn(f64) -> Rgb,
) {
    for r in 0..h {
        for col in 0..w {
            let v = img.get(r * w + col).copied().unwrap_or(f64::NAN);
            c.fill_rect(
                x + (col * s) as i64,
                y + (r * s) as i64,
                s as i64,
                s as i64,
                colour(v),
            );
        }
    }
    c.rect(x - 1, y - 1, (w * s) as i64 + 2, (h * s) as i64 + 2, GREY);
}

/// A vertical colour bar of height `h` at `(x, y)` for values `lo..hi`, with three labels.
fn colour_bar(
    c: &mut Canvas,
    (x, y, h): (i64, i64, i64),
    (lo, hi): (f64, f64),
    unit: &str,
    colour: &dyn Fn(f64) -> Rgb,
) {
    for i in 0..h {
        let t = 1.0 - i as f64 / (h - 1).max(1) as f64;
        c.fill_rect(x, y + i, 16, 1, colour(lo + t * (hi - lo)));
    }
    c.rect(x - 1, y - 1, 18, h + 2, GREY);
    for (t, v) in [(0.0, hi), (0.5, 0.5 * (lo + hi)), (1.0, lo)] {
        let yy = y + (t * (h - 1) as f64) as i64;
        c.line(x + 16, yy, x + 20, yy, 1, BLACK);
        c.text(x + 24, yy - 3, &format!("{v:.1}"), 1, BLACK);
    }
    c.text(x, y + h + 6, unit, 1, BLACK);
}

impl Panel {
    /// Draws the panel.
    pub fn render(&self) -> Canvas {
        let (w, h) = (self.width, self.height);
        let s = scale_for(w, h);
        let (iw, ih) = ((w * s) as i64, (h * s) as i64);
        let cols = 1 + self.modes.len() as i64;
        let gap = 16i64;
        let title_h = 14i64;
        let bar_w = 90i64;
        let cw = 10 + cols * (iw + gap) + bar_w;
        let ch = 34 + 2 * (title_h + ih + gap) + 10;
        let mut c = Canvas::new(cw as usize, ch as usize, WHITE);
        c.text(10, 8, &self.title, 2, BLACK);

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
        let y1 = 34i64;
        let images = std::iter::once(&self.reference).chain(&self.modes);
        for (i, img) in images.enumerate() {
            let x = 10 + i as i64 * (iw + gap);
            c.text(x, y1, &img.title, 1, BLACK);
            draw_image(&mut c, x, y1 + title_h, &um(&img.values), (w, h, s), &seq);
        }
        let bx = 10 + cols * (iw + gap);
        colour_bar(
            &mut c,
            (bx, y1 + title_h, ih),
            (0.0, dmax),
            "depth um",
            &seq,
        );

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
        let y2 = y1 + title_h + ih + gap;
        c.text(
            10,
            y2 + title_h + ih / 2 - GLYPH_H as i64,
            "error:",
            1,
            GREY,
        );
        c.text(10, y2 + title_h + ih / 2 + 4, "mode - ref", 1, GREY);
        for (i, (m, e)) in self.modes.iter().zip(&errors).enumerate() {
            let x = 10 + (i as i64 + 1) * (iw + gap);
            c.text(x, y2, &format!("{} - ref", m.title), 1, BLACK);
            draw_image(&mut c, x, y2 + title_h, e, (w, h, s), &div);
        }
        colour_bar(
            &mut c,
            (bx, y2 + title_h, ih),
            (-emax, emax),
            "error um",
            &div,
        );
        c
    }

    /// Renders and saves the panel.
    pub fn save(&self, path: &Path) -> Result<(), image::ImageError> {
        self.render().save_png(path)
    }
}

/// One depth image (m) in the sequential colour map, enlarged when small, with a title and
/// a colour bar in micrometres: what `tacrom render` writes.
pub fn depth_image(title: &str, width: usize, height: usize, depth: &[f64]) -> Canvas {
    let s = scale_for(width, height);
    let (iw, ih) = ((width * s) as i64, (height * s) as i64);
    let mut c = Canvas::new((iw + 110).max(300) as usize, (ih + 60) as usize, WHITE);
    c.text(10, 8, title, 1, BLACK);
    let um: Vec<f64> = depth.iter().map(|d| d * 1e6).collect();
    let dmax = um
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f64, |a, &b| a.max(b))
        .max(1e-3);
    let seq = move |v: f64| sequential(v / dmax);
    draw_image(&mut c, 10, 28, &um, (width, height, s), &seq);
    colour_bar(&mut c, (iw + 24, 28, ih), (0.0, dmax), "depth um", &seq);
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decade_ranges_and_labels() {
        assert_eq!(decades([0.5, 30.0].into_iter()), (-1, 2));
        assert_eq!(decades([10.0].into_iter()), (1, 2));
        assert_eq!(decades([f64::NAN, -1.0].into_iter()), (0, 1));
        assert_eq!(decade_label(-2), "0.01");
        assert_eq!(decade_label(3), "1000");
        assert_eq!(decade_label(7), "1e7");
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
                    marker: Marker::Disc,
                },
                PlotPoint {
                    label: "b".into(),
                    x: f64::NAN,
                    y: 0.0,
                    colour: PALETTE[1],
                    marker: Marker::Square,
                },
            ],
            reference: Some((1e4, "fine".into())),
        };
        let c = plot.render();
        assert!(c.width > 0);
        let panel = Panel {
            title: "p".into(),
            width: 4,
            height: 3,
            reference: PanelImage {
                title: "ref".into(),
                values: vec![0.0; 12],
            },
            modes: vec![PanelImage {
                title: "m".into(),
                values: vec![f64::NAN; 12],
            }],
        };
        let c = panel.render();
        assert!(c.height > 0);
    }
}
