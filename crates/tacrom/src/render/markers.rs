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
}
