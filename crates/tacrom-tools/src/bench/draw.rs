//! A tiny raster canvas for the report's figures: filled rectangles, thick lines, markers,
//! a 5 x 7 bitmap font (drawn at integer scales, horizontal or rotated a quarter turn) and
//! two colour maps. Saved as PNG through the `image` crate.

use std::path::Path;

/// An RGB colour.
pub type Rgb = [u8; 3];

/// White.
pub const WHITE: Rgb = [255, 255, 255];
/// Black.
pub const BLACK: Rgb = [0, 0, 0];
/// Light grey, for grid lines.
pub const GRID: Rgb = [225, 225, 225];
/// Mid grey, for minor ticks and secondary text.
pub const GREY: Rgb = [120, 120, 120];

/// Glyph width and height of the font, in font pixels (plus one column of spacing).
pub const GLYPH_W: usize = 5;
/// See [`GLYPH_W`].
pub const GLYPH_H: usize = 7;

/// The font: each glyph is seven rows of five bits, bit 4 the leftmost column.
const FONT: &[(char, [u8; 7])] = &[
    (' ', [0, 0, 0, 0, 0, 0, 0]),
    ('0', [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E]),
    ('1', [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E]),
    ('2', [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F]),
    ('3', [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E]),
    ('4', [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02]),
    ('5', [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E]),
    ('6', [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E]),
    ('7', [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08]),
    ('8', [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E]),
    ('9', [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C]),
    ('A', [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11]),
    ('B', [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E]),
    ('C', [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E]),
    ('D', [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C]),
    ('E', [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F]),
    ('F', [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10]),
    ('G', [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F]),
    ('H', [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11]),
    ('I', [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E]),
    ('J', [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C]),
    ('K', [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11]),
    ('L', [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F]),
    ('M', [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11]),
    ('N', [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11]),
    ('O', [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E]),
    ('P', [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10]),
    ('Q', [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D]),
    ('R', [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11]),
    ('S', [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E]),
    ('T', [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04]),
    ('U', [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E]),
    ('V', [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04]),
    ('W', [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A]),
    ('X', [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11]),
    ('Y', [0x11, 0x11, 0x0A, 0x04, 0x04, 0x04, 0x04]),
    ('Z', [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F]),
    ('a', [0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F]),
    ('b', [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E]),
    ('c', [0x00, 0x00, 0x0E, 0x10, 0x10, 0x11, 0x0E]),
    ('d', [0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F]),
    ('e', [0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E]),
    ('f', [0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08]),
    ('g', [0x00, 0x0F, 0x11, 0x11, 0x0F, 0x01, 0x0E]),
    ('h', [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11]),
    ('i', [0x04, 0x00, 0x0C, 0x04, 0x04, 0x04, 0x0E]),
    ('j', [0x02, 0x00, 0x06, 0x02, 0x02, 0x12, 0x0C]),
    ('k', [0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12]),
    ('l', [0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E]),
    ('m', [0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11]),
    ('n', [0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11]),
    ('o', [0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E]),
    ('p', [0x00, 0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10]),
    ('q', [0x00, 0x0F, 0x11, 0x11, 0x0F, 0x01, 0x01]),
    ('r', [0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10]),
    ('s', [0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E]),
    ('t', [0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06]),
    ('u', [0x00, 0x00, 0x11, 0x11, 0x11, 0x13, 0x0D]),
    ('v', [0x00, 0x00, 0x11, 0x11, 0x11, 0x0A, 0x04]),
    ('w', [0x00, 0x00, 0x11, 0x11, 0x15, 0x15, 0x0A]),
    ('x', [0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11]),
    ('y', [0x00, 0x00, 0x11, 0x11, 0x0F, 0x01, 0x0E]),
    ('z', [0x00, 0x00, 0x1F, 0x02, 0x04, 0x08, 0x1F]),
    ('.', [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C]),
    (',', [0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08]),
    ('-', [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00]),
    ('+', [0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00]),
    ('(', [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02]),
    (')', [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08]),
    ('[', [0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E]),
    (']', [0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E]),
    ('/', [0x01, 0x01, 0x02, 0x04, 0x08, 0x10, 0x10]),
    (':', [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00]),
    ('%', [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03]),
    (';', [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x04, 0x08]),
    ('=', [0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00]),
    ('_', [0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F]),
    ('^', [0x04, 0x0A, 0x11, 0x00, 0x00, 0x00, 0x00]),
    ('|', [0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04]),
    ('?', [0x0E, 0x11, 0x01, 0x02, 0x04, 0x00, 0x04]),
];

fn glyph(c: char) -> &'static [u8; 7] {
    FONT.iter()
        .find(|(g, _)| *g == c)
        .or_else(|| FONT.iter().find(|(g, _)| *g == '?'))
        .map(|(_, bits)| bits)
        .expect("the font has '?'")
}

/// Width in canvas pixels of `text` drawn at `scale`.
pub fn text_width(text: &str, scale: usize) -> usize {
    let n = text.chars().count();
    if n == 0 {
        0
    } else {
        (n * (GLYPH_W + 1) - 1) * scale
    }
}

/// An RGB raster, row-major, origin top-left.
#[derive(Clone, Debug)]
pub struct Canvas {
    /// Width (pixels).
    pub width: usize,
    /// Height (pixels).
    pub height: usize,
    pixels: Vec<Rgb>,
}

impl Canvas {
    /// A canvas filled with `background`.
    pub fn new(width: usize, height: usize, background: Rgb) -> Self {
        Self {
            width,
            height,
            pixels: vec![background; width * height],
        }
    }

    /// Sets one pixel; coordinates off the canvas are ignored.
    pub fn set(&mut self, x: i64, y: i64, c: Rgb) {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            self.pixels[y as usize * self.width + x as usize] = c;
        }
    }

    /// The pixel at `(x, y)`.
    pub fn get(&self, x: usize, y: usize) -> Rgb {
        self.pixels[y * self.width + x]
    }

    /// Fills the rectangle of corner `(x, y)` and size `w x h`.
    pub fn fill_rect(&mut self, x: i64, y: i64, w: i64, h: i64, c: Rgb) {
        for yy in y..y + h {
            for xx in x..x + w {
                self.set(xx, yy, c);
            }
        }
    }

    /// The outline of a rectangle, one pixel wide.
    pub fn rect(&mut self, x: i64, y: i64, w: i64, h: i64, c: Rgb) {
        self.line(x, y, x + w - 1, y, 1, c);
        self.line(x, y + h - 1, x + w - 1, y + h - 1, 1, c);
        self.line(x, y, x, y + h - 1, 1, c);
        self.line(x + w - 1, y, x + w - 1, y + h - 1, 1, c);
    }

    /// A line from `(x0, y0)` to `(x1, y1)`, `thickness` pixels wide (Bresenham, with a
    /// square brush).
    pub fn line(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, thickness: i64, c: Rgb) {
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        let lo = -(thickness - 1) / 2;
        loop {
            self.fill_rect(x + lo, y + lo, thickness.max(1), thickness.max(1), c);
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// A dashed line (dashes of `dash` pixels).
    pub fn dashed_line(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, dash: i64, c: Rgb) {
        let n = (x1 - x0).abs().max((y1 - y0).abs()).max(1);
        for i in 0..=n {
            if (i / dash.max(1)) % 2 == 0 {
                self.set(x0 + (x1 - x0) * i / n, y0 + (y1 - y0) * i / n, c);
            }
        }
    }

    /// A filled disc of radius `r` centred at `(x, y)`.
    pub fn disc(&mut self, x: i64, y: i64, r: i64, c: Rgb) {
        for yy in -r..=r {
            for xx in -r..=r {
                if xx * xx + yy * yy <= r * r + r / 2 {
                    self.set(x + xx, y + yy, c);
                }
            }
        }
    }

    /// `text` with its top-left corner at `(x, y)`, each font pixel `scale` pixels square.
    pub fn text(&mut self, x: i64, y: i64, text: &str, scale: usize, c: Rgb) {
        let s = scale as i64;
        for (i, ch) in text.chars().enumerate() {
            let gx = x + i as i64 * (GLYPH_W as i64 + 1) * s;
            for (row, bits) in glyph(ch).iter().enumerate() {
                for col in 0..GLYPH_W {
                    if bits & (0x10 >> col) != 0 {
                        self.fill_rect(gx + col as i64 * s, y + row as i64 * s, s, s, c);
                    }
                }
            }
        }
    }

    /// `text` rotated a quarter turn counter-clockwise (reading bottom to top), its
    /// bounding box's top-left corner at `(x, y)`.
    pub fn text_up(&mut self, x: i64, y: i64, text: &str, scale: usize, c: Rgb) {
        let w = text_width(text, scale);
        let h = GLYPH_H * scale;
        let mut tmp = Canvas::new(w, h, WHITE);
        tmp.text(0, 0, text, scale, BLACK);
        for ty in 0..h {
            for tx in 0..w {
                if tmp.get(tx, ty) == BLACK {
                    // (tx, ty) -> (ty, w - 1 - tx)
                    self.set(x + ty as i64, y + (w - 1 - tx) as i64, c);
                }
            }
        }
    }

    /// Copies `src` with its top-left corner at `(x, y)`.
    pub fn blit(&mut self, src: &Canvas, x: i64, y: i64) {
        for sy in 0..src.height {
            for sx in 0..src.width {
                self.set(x + sx as i64, y + sy as i64, src.get(sx, sy));
            }
        }
    }

    /// Writes the canvas as an 8-bit RGB PNG.
    pub fn save_png(&self, path: &Path) -> Result<(), image::ImageError> {
        let mut buf = Vec::with_capacity(self.pixels.len() * 3);
        for p in &self.pixels {
            buf.extend_from_slice(p);
        }
        image::save_buffer(
            path,
            &buf,
            self.width as u32,
            self.height as u32,
            image::ExtendedColorType::Rgb8,
        )
    }
}

fn lerp_stops(stops: &[(f64, Rgb)], t: f64) -> Rgb {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    for w in stops.windows(2) {
        let ((t0, c0), (t1, c1)) = (w[0], w[1]);
        if t <= t1 {
            let u = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
            let mut c = [0u8; 3];
            for k in 0..3 {
                c[k] = (c0[k] as f64 + u * (c1[k] as f64 - c0[k] as f64)).round() as u8;
            }
            return c;
        }
    }
    stops[stops.len() - 1].1
}

/// Sequential map for depth, `t` in [0, 1]: dark blue through teal and green to yellow.
pub fn sequential(t: f64) -> Rgb {
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
pub fn diverging(t: f64) -> Rgb {
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
    fn every_glyph_fits_five_columns_and_is_unique() {
        for (c, bits) in FONT {
            assert!(bits.iter().all(|b| *b < 32), "{c}");
            assert_eq!(FONT.iter().filter(|(d, _)| d == c).count(), 1, "{c}");
        }
        assert_eq!(glyph('\u{1F600}'), glyph('?'));
    }

    #[test]
    fn text_and_lines_stay_on_the_canvas() {
        let mut c = Canvas::new(20, 10, WHITE);
        c.text(-5, -3, "Ab9%", 2, BLACK);
        c.text_up(15, 0, "long text", 1, BLACK);
        c.line(-10, -10, 30, 30, 3, BLACK);
        c.disc(19, 9, 4, BLACK);
        assert_eq!(text_width("ab", 2), 22);
        assert_eq!(c.get(0, 0), BLACK);
    }

    #[test]
    fn colour_maps_hit_their_ends() {
        assert_eq!(sequential(0.0), [30, 20, 80]);
        assert_eq!(sequential(2.0), [250, 230, 40]);
        assert_eq!(diverging(0.0), [250, 250, 250]);
        assert_eq!(diverging(f64::NAN), diverging(-1.0));
    }
}
