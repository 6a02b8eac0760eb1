//! Markers printed on the gel: a regular grid of dots on its top face that the camera
//! tracks, the way GelSight-style sensors show shear and slip.
//!
//! With `NX x NY` markers over a field of view `fov_x x fov_y`, marker `m = j * NX + i`
//! (the image's reading order: row `j` counted from the +y edge, column `i` from the -x
//! edge) is printed at the centre of cell `(i, j)` of the field of view divided `NX x NY`,
//! `X_m = (-fov_x / 2 + (i + 1/2) fov_x / NX, fov_y / 2 - (j + 1/2) fov_y / NY)` on the
//! undeformed face. It moves with the surface point it is printed on, to `X_m + u(X_m)`,
//! and the camera sees it at the pixel coordinates of `X_m + u_xy(X_m)`.

use crate::geometry::PixelGrid;

/// Radius of a printed marker (m): GelSight-type gels carry dots of about half a
/// millimetre.
pub const DOT_RADIUS: f64 = 0.25e-3;

/// Colour of a marker dot in the `rgb` image (0..255): the dark ink of printed markers.
pub const DOT_COLOUR: [f64; 3] = [25.0, 25.0, 30.0];

/// Sub-samples per pixel side for the dots' coverage (antialiasing).
const SUBSAMPLES: usize = 4;

/// The marker grid of one sensor and where the last evaluation moved each marker.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Markers {
    /// Rest position of each marker on the undeformed face (sensor frame x, y; m).
    rest: Vec<[f64; 2]>,
    /// In-plane displacement of each marker (sensor frame x, y; m).
    shift: Vec<[f64; 2]>,
}

impl Markers {
    /// Values per marker in the `markers` output: column and row of its image position
    /// (pixels), its displacement along x and y (m).
    pub const VALUES: usize = 4;

    /// `counts = [NX, NY]` markers spread over `grid`'s field of view, at rest.
    pub fn new(counts: [usize; 2], grid: &PixelGrid) -> Self {
        let [nx, ny] = counts;
        let rest: Vec<[f64; 2]> = (0..nx * ny)
            .map(|m| {
                let (i, j) = (m % nx, m / nx);
                [
                    -0.5 * grid.fov_x + (i as f64 + 0.5) * grid.fov_x / nx as f64,
                    0.5 * grid.fov_y - (j as f64 + 0.5) * grid.fov_y / ny as f64,
                ]
            })
            .collect();
        let shift = vec![[0.0; 2]; rest.len()];
        Self { rest, shift }
    }

    /// Number of markers.
    pub fn len(&self) -> usize {
        self.rest.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.rest.is_empty()
    }

    /// Rest position of each marker (sensor frame x, y; m).
    pub fn rest(&self) -> &[[f64; 2]] {
        &self.rest
    }

    /// In-plane displacement of each marker after the last update (m).
    pub fn shift(&self) -> &[[f64; 2]] {
        &self.shift
    }

    /// Moves each marker by `displacement([x, y])` of the surface point at its rest
    /// position (m); a non-finite displacement counts as none.
    pub fn update(&mut self, mut displacement: impl FnMut([f64; 2]) -> [f64; 2]) {
        for (s, &x) in self.shift.iter_mut().zip(&self.rest) {
            let d = displacement(x);
            *s = if d.iter().all(|v| v.is_finite()) {
                d
            } else {
                [0.0; 2]
            };
        }
    }

    /// Every marker back at its rest position.
    pub fn settle(&mut self) {
        self.shift.fill([0.0; 2]);
    }

    /// Writes [`Markers::VALUES`] values per marker into `out`: the column and row
    /// coordinates of its image position on `grid` (continuous, `c` at the centre of
    /// column `c`; row 0 at +y, so a move along +y lowers the row) and its displacement
    /// along x and y (m).
    pub fn write(&self, grid: &PixelGrid, out: &mut [f64]) {
        for ((o, x), d) in out
            .chunks_exact_mut(Self::VALUES)
            .zip(&self.rest)
            .zip(&self.shift)
        {
            o[0] = grid.col_at(x[0] + d[0]);
            o[1] = grid.row_at(x[1] + d[1]);
            o[2] = d[0];
            o[3] = d[1];
        }
    }
}

impl Markers {
    /// Draws each marker as a dot of radius [`DOT_RADIUS`] at its image position into the
    /// `rgb` image `out` (H x W x 3, 0..255), blended by the fraction of each pixel it
    /// covers; nothing when there are no markers.
    pub fn draw(&self, grid: &PixelGrid, out: &mut [f64]) {
        let (w, h) = (grid.width, grid.height);
        if self.is_empty() || w == 0 || h == 0 {
            return;
        }
        let (pw, ph) = (grid.fov_x / w as f64, grid.fov_y / h as f64);
        let (rc, rr) = (DOT_RADIUS / pw, DOT_RADIUS / ph);
        let step = 1.0 / SUBSAMPLES as f64;
        for (x, d) in self.rest.iter().zip(&self.shift) {
            let (c, r) = (grid.col_at(x[0] + d[0]), grid.row_at(x[1] + d[1]));
            if !(c.is_finite() && r.is_finite()) {
                continue;
            }
            let c0 = (c - rc - 0.5).floor().max(0.0) as usize;
            let c1 = ((c + rc + 0.5).ceil().max(0.0) as usize).min(w);
            let r0 = (r - rr - 0.5).floor().max(0.0) as usize;
            let r1 = ((r + rr + 0.5).ceil().max(0.0) as usize).min(h);
            for row in r0..r1 {
                for col in c0..c1 {
                    let mut inside = 0usize;
                    for a in 0..SUBSAMPLES {
                        for b in 0..SUBSAMPLES {
                            // Pixel (row, col) spans [col - 1/2, col + 1/2] in the
                            // continuous coordinates of `col_at`.
                            let u = (col as f64 - 0.5 + (a as f64 + 0.5) * step - c) / rc;
                            let v = (row as f64 - 0.5 + (b as f64 + 0.5) * step - r) / rr;
                            inside += usize::from(u * u + v * v <= 1.0);
                        }
                    }
                    if inside > 0 {
                        let alpha = inside as f64 / (SUBSAMPLES * SUBSAMPLES) as f64;
                        let px = &mut out[3 * (row * w + col)..3 * (row * w + col) + 3];
                        for (v, dark) in px.iter_mut().zip(DOT_COLOUR) {
                            *v += alpha * (dark - *v);
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GRID: PixelGrid = PixelGrid {
        width: 320,
        height: 240,
        fov_x: 0.024,
        fov_y: 0.018,
    };

    #[test]
    fn markers_at_rest_sit_on_a_regular_grid_in_reading_order() {
        let m = Markers::new([4, 3], &GRID);
        let mut out = vec![f64::NAN; m.len() * Markers::VALUES];
        m.write(&GRID, &mut out);
        let at = |k: usize| &out[k * Markers::VALUES..(k + 1) * Markers::VALUES];
        // First marker: top-left cell's centre (320 / 4 / 2 - 0.5, 240 / 3 / 2 - 0.5).
        assert!((at(0)[0] - 39.5).abs() < 1e-9 && (at(0)[1] - 39.5).abs() < 1e-9);
        // Next along the row: +80 columns; next row: +80 rows; no displacement.
        assert!((at(1)[0] - at(0)[0] - 80.0).abs() < 1e-9 && at(1)[1] == at(0)[1]);
        assert!((at(4)[1] - at(0)[1] - 80.0).abs() < 1e-9 && at(4)[0] == at(0)[0]);
        assert!(out.chunks(4).all(|o| o[2] == 0.0 && o[3] == 0.0));
        // The grid is centred: the rest positions sum to zero.
        let sum = m
            .rest()
            .iter()
            .fold([0.0, 0.0], |s, x| [s[0] + x[0], s[1] + x[1]]);
        assert!(sum[0].abs() < 1e-15 && sum[1].abs() < 1e-15, "{sum:?}");
    }

    #[test]
    fn a_displaced_marker_moves_in_the_image_orientation() {
        let mut m = Markers::new([1, 1], &GRID);
        let px = GRID.fov_x / GRID.width as f64;
        // +x by two pixels, +y by one: two columns right, one row up.
        m.update(|_| [2.0 * px, px]);
        let mut out = [0.0; 4];
        m.write(&GRID, &mut out);
        assert!((out[0] - 161.5).abs() < 1e-9, "{out:?}");
        assert!((out[1] - 118.5).abs() < 1e-9, "{out:?}");
        assert_eq!(out[2..], [2.0 * px, px]);
        // Non-finite displacements count as none.
        m.update(|_| [f64::NAN, 1.0]);
        assert_eq!(m.shift(), &[[0.0, 0.0]]);
    }

    // A dot darkens the pixels it covers, fully at its centre, partly at its rim, and
    // follows its marker; pixels away from every dot keep their colour.
    #[test]
    fn dots_are_drawn_where_the_markers_are() {
        let grid = PixelGrid {
            width: 64,
            height: 48,
            fov_x: 0.024,
            fov_y: 0.018,
        };
        let mut m = Markers::new([1, 1], &grid);
        let background = vec![128.0; 64 * 48 * 3];
        let mut img = background.clone();
        m.draw(&grid, &mut img);
        let px = |img: &[f64], r: usize, c: usize| img[3 * (r * 64 + c)];
        // The marker sits at column 31.5, row 23.5, the corner of four pixels (0.375 mm):
        // a 0.25 mm dot covers a quarter disc of each, pi (0.667 px)^2 / 4 = 0.35 of it.
        for (r, c) in [(23, 31), (23, 32), (24, 31), (24, 32)] {
            let alpha = (128.0 - px(&img, r, c)) / (128.0 - DOT_COLOUR[0]);
            assert!((alpha - 0.35).abs() < 0.05, "({r}, {c}): {alpha}");
        }
        // The ink over the whole image is the dot's area, pi r^2, within the 4 x 4
        // sub-sampling's error.
        let ink: f64 = (0..48)
            .flat_map(|r| (0..64).map(move |c| (r, c)))
            .map(|(r, c)| (128.0 - px(&img, r, c)) / (128.0 - DOT_COLOUR[0]))
            .sum();
        let area = std::f64::consts::PI * (DOT_RADIUS / 0.375e-3).powi(2);
        assert!((ink / area - 1.0).abs() < 0.1, "{ink} px against {area} px");
        assert_eq!(px(&img, 10, 10), 128.0);
        let changed = img.iter().zip(&background).filter(|(a, b)| a != b).count();
        assert!(changed > 0 && changed <= 3 * 16, "{changed}");
        // Moved 3 mm along +x: 8 columns right.
        m.update(|_| [3e-3, 0.0]);
        let mut moved = background.clone();
        m.draw(&grid, &mut moved);
        assert!(px(&moved, 23, 39) < 100.0 && px(&moved, 23, 31) == 128.0);
        // No markers: nothing drawn.
        let mut none = background.clone();
        Markers::default().draw(&grid, &mut none);
        assert_eq!(none, background);
    }
}
