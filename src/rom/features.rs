//! What the networks see: the coarse solution and the indenters' geometry sampled on the
//! model's surface lattice, and the per-point query features of the decoder.
//!
//! Shared by data generation (`tacrom-tools`' `datagen.rs`) and inference ([`super::Rom`]), so that
//! training and run time compute the inputs with the same code.
//!
//! * The **lattice** is a [`PixelGrid`] over the whole top face of the gel with the
//!   model's pitch (row 0 the +y edge, column 0 the -x edge, as images).
//! * **Coarse depth** `c`: the coarse MPM's surface indentation at each lattice point,
//!   bounded by the contact problem as the coarse sensor mode does ([`DepthRule`]).
//! * **Rigid penetration** `p`: how far the undeformed gel would be pierced by the
//!   indenters at that point ([`DepthRule::penetration`]).
//! * **Encoder input**: `c` and `p` on the sub-lattice of stride `encoder_stride`
//!   (offset `encoder_stride / 2`), in model units (mm), channel-major.
//! * **Decoder query** at lattice point `(row, col)`: the normalised position
//!   `(x / (Lx/2), y / (Ly/2))`, then a `patch x patch` window of `c` and one of `p`
//!   centred on the point with `patch_step` lattice steps between samples (zero outside
//!   the gel), in model units; see [`query_features`] for the exact order and
//!   [`coarse_centre_feature`] for the coarse depth at the point itself.
//! * **Material** (models conditioned on the gel, manifest `conditioning`): the gel's
//!   Poisson's ratio and friction coefficient, each mapped linearly from the model's range
//!   onto `[-1, 1]` ([`Conditioning::inputs`]), appended to the encoder input and to every
//!   query.
//! * **Deformable region**: the lattice points the decoder is evaluated at ([`region`]).
//! * **Pressure head query** (models with `files.pressure`): the decoder query, then a
//!   `patch x patch` window (the same offsets) of the coarse gel's contact load at each
//!   lattice point in the head's own units ([`load_window`]).
//!
//! `training/tacrom_rom/data.py` computes the same on the training data; the parity test
//! `training/tests/test_feature_parity.py` compares the two on presses written by
//! `tacrom rom-features`.

use crate::geometry::{PixelGrid, Placed};
use crate::mpm::{Gel, Part};
use crate::render::DepthRule;

/// How the model samples the gel's surface: fixed by the model's manifest (serialised
/// with the manifest's `lattice` names).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct LatticeSpec {
    /// Gel extent `[Lx, Ly, T]` (m).
    pub size: [f64; 3],
    /// Lattice columns (along x).
    pub nx: usize,
    /// Lattice rows (along y).
    pub ny: usize,
    /// Stride of the encoder's sub-lattice (lattice steps).
    pub encoder_stride: usize,
    /// Side of the decoder's square geometry windows (odd).
    pub patch: usize,
    /// Lattice steps between window samples.
    pub patch_step: usize,
    /// Depth scale: model units per metre (1000: millimetres).
    pub depth_scale: f64,
    /// The networks' field of view, `[rows, columns]` of lattice points: the lattice of
    /// the gel the model was trained on. The encoder reads a window of this size placed
    /// over the contact ([`Observation::origin`]); on the model's own gel it is the whole
    /// lattice.
    #[serde(skip)]
    pub window: [usize; 2],
    /// Material inputs appended to the encoder input and to each query (0, or 2 for a
    /// model conditioned on the gel's material).
    #[serde(skip)]
    pub material_inputs: usize,
}

/// The gel materials a conditioned model serves (manifest `conditioning`): closed ranges
/// of Poisson's ratio and friction.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Conditioning {
    /// Poisson's ratio, `[lo, hi]`.
    pub poisson: [f64; 2],
    /// Coulomb friction coefficient, `[lo, hi]`.
    pub friction: [f64; 2],
}

impl Conditioning {
    /// Number of material inputs.
    pub const INPUTS: usize = 2;

    /// The network's material inputs for a gel: each value mapped linearly from its range
    /// onto `[-1, 1]` (0 for a range of one value).
    pub fn inputs(&self, poisson: f64, friction: f64) -> [f64; 2] {
        let map = |[lo, hi]: [f64; 2], v: f64| {
            if hi > lo {
                (2.0 * v - lo - hi) / (hi - lo)
            } else {
                0.0
            }
        };
        [map(self.poisson, poisson), map(self.friction, friction)]
    }
}

impl LatticeSpec {
    /// The lattice for a gel of `size` with points `pitch` apart (m), and the default
    /// encoder stride 4, windows 5 x 5 with step 2, millimetre units.
    pub fn with_pitch(size: [f64; 3], pitch: f64) -> Self {
        let nx = ((size[0] / pitch).round() as usize).max(1);
        let ny = ((size[1] / pitch).round() as usize).max(1);
        Self {
            size,
            nx,
            ny,
            encoder_stride: 4,
            patch: 5,
            patch_step: 2,
            depth_scale: 1000.0,
            window: [ny, nx],
            material_inputs: 0,
        }
    }

    /// Whether the window is the whole lattice (the model's own gel, or one of its shape).
    pub fn whole(&self) -> bool {
        self.window == [self.ny, self.nx]
    }

    /// The lattice as a pixel grid covering the gel's top face.
    pub fn grid(&self) -> PixelGrid {
        PixelGrid {
            width: self.nx,
            height: self.ny,
            fov_x: self.size[0],
            fov_y: self.size[1],
        }
    }

    /// Lattice points.
    pub fn points(&self) -> usize {
        self.nx * self.ny
    }

    /// Rows and columns of the encoder's sub-lattice (over the window).
    pub fn encoder_dims(&self) -> [usize; 2] {
        let s = self.encoder_stride;
        let o = s / 2;
        self.window.map(|n| n.saturating_sub(o).div_ceil(s))
    }

    /// Length of the encoder's input vector (two channels, then the material inputs).
    pub fn encoder_len(&self) -> usize {
        let [r, c] = self.encoder_dims();
        2 * r * c + self.material_inputs
    }

    /// Number of decoder query features.
    pub fn query_len(&self) -> usize {
        2 + 2 * self.patch * self.patch + self.material_inputs
    }
}

/// Index of the coarse depth at the query point itself among the query features.
pub fn coarse_centre_feature(spec: &LatticeSpec) -> usize {
    2 + (spec.patch * spec.patch) / 2
}

/// The coarse solution and the rigid penetration on the lattice (m, row-major).
#[derive(Clone, Debug)]
pub struct Observation {
    /// Coarse depth: the coarse gel's indentation under [`Observation::rule`].
    pub coarse: Vec<f64>,
    /// Rigid penetration.
    pub pen: Vec<f64>,
    /// The bounds of the contact problem the indenters pose.
    pub rule: DepthRule,
    /// The material inputs of a conditioned model ([`Conditioning::inputs`]; empty for
    /// others).
    pub material: Vec<f64>,
    /// The gel's Poisson's ratio (for the force's [`super::VolumeFactor`]).
    pub poisson: f64,
    /// The coarse gel's normal contact pressure on the lattice (Pa; empty unless a
    /// pressure head reads it: [`Observation::update_load`]).
    pub pressure: Vec<f64>,
    /// The coarse gel's normal force (N; with `pressure`).
    pub force: f64,
    /// The lattice point `[row, column]` at the window's first corner
    /// ([`LatticeSpec::window`]): over the contact, within the lattice where the window
    /// fits in it, the lattice within the window where it does not; `[0, 0]` where the
    /// window is the whole lattice.
    pub origin: [isize; 2],
    /// Where the coarse depth was mapped, where not everywhere
    /// ([`Observation::update_read`]).
    pub mapped: Option<Mapped>,
}

impl Default for Observation {
    fn default() -> Self {
        Self {
            coarse: Vec::new(),
            pen: Vec::new(),
            rule: DepthRule::new(0.0, &[]),
            material: Vec::new(),
            poisson: 0.0,
            pressure: Vec::new(),
            force: 0.0,
            origin: [0, 0],
            mapped: None,
        }
    }
}

/// Rigid penetration of `indenters` on `grid` (m) under `rule`; `zmin` is scratch space
/// of the grid's size.
pub fn penetration(
    indenters: &[Placed],
    grid: &PixelGrid,
    rule: &DepthRule,
    zmin: &mut Vec<f64>,
    out: &mut Vec<f64>,
) {
    let n = grid.width * grid.height;
    zmin.clear();
    zmin.resize(n, f64::INFINITY);
    for p in indenters {
        p.lower_surface(grid, -rule.thickness(), 0.0, zmin);
    }
    out.clear();
    out.extend(zmin.iter().map(|&z| rule.penetration(z)));
}

impl Observation {
    /// Samples a solved coarse `gel` and its `indenters` (sensor frame) on the lattice.
    pub fn from_gel(gel: &Gel, indenters: &[Placed], spec: &LatticeSpec) -> Self {
        let mut obs = Observation::default();
        obs.update(gel, indenters, spec, &mut Vec::new());
        obs
    }

    /// As [`Observation::from_gel`], reusing the buffers; `zmin` is scratch space.
    pub fn update(
        &mut self,
        gel: &Gel,
        indenters: &[Placed],
        spec: &LatticeSpec,
        zmin: &mut Vec<f64>,
    ) {
        let grid = spec.grid();
        self.rule = DepthRule::new(spec.size[2], indenters);
        penetration(indenters, &grid, &self.rule, zmin, &mut self.pen);
        self.coarse.clear();
        self.coarse.resize(spec.points(), 0.0);
        gel.surface_depth(&grid, &mut self.coarse);
        let _ = self.rule.apply(&mut self.coarse, &self.pen);
        self.origin = self.window_origin(spec);
        self.mapped = None;
    }

    /// As [`Observation::update`] for an image on `image` of the decoded surface only (no
    /// force from its volume, no pressure head, no refinement; the networks' window the
    /// whole lattice): the coarse depth is mapped where the encoder, the image and the
    /// decoder's region for it read it ([`Mapped`]) and zero elsewhere; the rigid
    /// penetration everywhere. `grow`: the region's growth.
    pub fn update_read(
        &mut self,
        gel: &Gel,
        indenters: &[Placed],
        spec: &LatticeSpec,
        zmin: &mut Vec<f64>,
        image: &PixelGrid,
        grow: usize,
    ) {
        debug_assert!(spec.whole());
        let grid = spec.grid();
        self.rule = DepthRule::new(spec.size[2], indenters);
        penetration(indenters, &grid, &self.rule, zmin, &mut self.pen);
        self.coarse.clear();
        self.coarse.resize(spec.points(), 0.0);
        let mapped = Mapped::new(spec, image, grow);
        let [a, b, c, d] = encoder_around(spec, &mapped.mapped);
        gel.surface_depth_parts(
            &grid,
            &[mapped.mapped.clone(), a, b, c, d],
            &mut self.coarse,
        );
        let _ = self.rule.apply(&mut self.coarse, &self.pen);
        self.origin = [0, 0];
        self.mapped = Some(mapped);
    }

    /// Where the window goes ([`Observation::origin`]): centred on the rigid
    /// penetration's centroid (the coarse depth's where nothing pierces the gel).
    fn window_origin(&self, spec: &LatticeSpec) -> [isize; 2] {
        if spec.whole() {
            return [0, 0];
        }
        let field = if self.pen.iter().any(|&p| p > 0.0) {
            &self.pen
        } else {
            &self.coarse
        };
        let (mut w, mut r, mut c) = (0.0, 0.0, 0.0);
        for (i, &v) in field.iter().enumerate() {
            w += v;
            r += v * (i / spec.nx) as f64;
            c += v * (i % spec.nx) as f64;
        }
        let centre = if w > 0.0 {
            [r / w, c / w]
        } else {
            [0.5 * (spec.ny - 1) as f64, 0.5 * (spec.nx - 1) as f64]
        };
        let place = |centre: f64, n: usize, window: usize| {
            let (n, window) = (n as isize, window as isize);
            let at = (centre - 0.5 * (window - 1) as f64).round() as isize;
            at.clamp((n - window).min(0), (n - window).max(0))
        };
        [
            place(centre[0], spec.ny, spec.window[0]),
            place(centre[1], spec.nx, spec.window[1]),
        ]
    }

    /// `field` at window point `(row, col)` in model units (times the lattice's
    /// `depth_scale`); 0 outside the lattice.
    fn in_window(&self, field: &[f64], spec: &LatticeSpec, row: usize, col: usize) -> f64 {
        let r = self.origin[0] + row as isize;
        let c = self.origin[1] + col as isize;
        if r >= 0 && c >= 0 && (r as usize) < spec.ny && (c as usize) < spec.nx {
            field[r as usize * spec.nx + c as usize] * spec.depth_scale
        } else {
            0.0
        }
    }

    /// Samples the solved coarse `gel`'s contact pressure and normal force, for a pressure
    /// head.
    pub fn update_load(&mut self, gel: &Gel, spec: &LatticeSpec) {
        self.pressure.resize(spec.points(), 0.0);
        gel.contact_pressure(&spec.grid(), &mut self.pressure);
        self.force = gel.force().z;
    }

    /// The encoder's input (model units), appended to `out` after clearing it.
    pub fn encoder_input(&self, spec: &LatticeSpec, out: &mut Vec<f32>) {
        out.clear();
        let s = spec.encoder_stride;
        let o = s / 2;
        let [rows, cols] = spec.window;
        for field in [&self.coarse, &self.pen] {
            for row in (o..rows).step_by(s) {
                for col in (o..cols).step_by(s) {
                    out.push(self.in_window(field, spec, row, col) as f32);
                }
            }
        }
        self.push_material(spec, out);
    }

    /// Appends the `spec.material_inputs` material inputs (zeros where the observation
    /// holds fewer).
    fn push_material(&self, spec: &LatticeSpec, out: &mut Vec<f32>) {
        out.extend(
            (0..spec.material_inputs).map(|k| self.material.get(k).copied().unwrap_or(0.0) as f32),
        );
    }
}

/// The lattice points an image on `image` reads of a depth on the lattice of `spec`: each
/// pixel's lattice cell and the points either side of it (`render_lattice`'s monotone
/// slopes), as rows and columns.
pub fn image_reach(spec: &LatticeSpec, image: &PixelGrid) -> Part {
    let (nx, ny) = (spec.nx, spec.ny);
    let [lx, ly, _] = spec.size;
    // The lattice coordinate of `v` (m from the face's edge) and the points its cell and
    // slopes read, over the first and the last pixel (the coordinate is monotone).
    let span = |first: f64, last: f64, length: f64, n: usize| {
        let at = |v: f64| (v / (length / n as f64) - 0.5).clamp(0.0, n.saturating_sub(1) as f64);
        let (a, b) = (at(first).min(at(last)), at(first).max(at(last)));
        let cell = |f: f64| (f.floor() as usize).min(n.saturating_sub(2));
        cell(a).saturating_sub(1)..(cell(b) + 3).min(n)
    };
    let (w, h) = (image.width.max(1), image.height.max(1));
    Part {
        rows: span(0.5 * ly - image.y(0), 0.5 * ly - image.y(h - 1), ly, ny),
        cols: span(image.x(0) + 0.5 * lx, image.x(w - 1) + 0.5 * lx, lx, nx),
        step: 1,
    }
}

/// The encoder's sub-lattice outside `rect` (a part of step 1): the bands above and
/// below it, and either side of it.
fn encoder_around(spec: &LatticeSpec, rect: &Part) -> [Part; 4] {
    let s = spec.encoder_stride.max(1);
    let o = s / 2;
    // The first sub-lattice index at or after `i`.
    let on = |i: usize| o + i.saturating_sub(o).div_ceil(s) * s;
    let rows = on(rect.rows.start)..rect.rows.end;
    let part = |rows: std::ops::Range<usize>, cols: std::ops::Range<usize>| Part {
        rows,
        cols,
        step: s,
    };
    [
        part(o..rect.rows.start, o..spec.nx),
        part(on(rect.rows.end)..spec.ny, o..spec.nx),
        part(rows.clone(), o..rect.cols.start),
        part(rows, on(rect.cols.end)..spec.nx),
    ]
}

/// Where an observation's coarse depth was mapped, where not on the whole lattice
/// ([`Observation::update_read`]): an image's reach, and what the decoder needs for it.
#[derive(Clone, Debug, PartialEq)]
pub struct Mapped {
    /// The points the image reads ([`image_reach`]): the decoder runs on the region's
    /// points among them only.
    pub read: Part,
    /// `read` grown by the region's growth and the query windows' reach: every seed of a
    /// region point in `read`, and every point of its window. (The encoder's sub-lattice
    /// is mapped too.)
    pub mapped: Part,
}

impl Mapped {
    /// For an image on `image`, a region grown `grow` lattice steps.
    pub fn new(spec: &LatticeSpec, image: &PixelGrid, grow: usize) -> Mapped {
        let read = image_reach(spec, image);
        let reach = grow + (spec.patch / 2) * spec.patch_step;
        let grown = |r: &std::ops::Range<usize>, n: usize| {
            r.start.saturating_sub(reach)..(r.end + reach).min(n)
        };
        let mapped = Part {
            rows: grown(&read.rows, spec.ny),
            cols: grown(&read.cols, spec.nx),
            step: 1,
        };
        Mapped { read, mapped }
    }
}

/// Appends the decoder query features of lattice point `(row, col)` to `out`:
/// `[x / (Lx/2), y / (Ly/2)]`, then the `patch x patch` window of coarse depth, then the
/// window of rigid penetration (row-major windows, row offset outer, zero outside the gel),
/// in model units.
pub fn query_features(
    obs: &Observation,
    spec: &LatticeSpec,
    row: usize,
    col: usize,
    out: &mut Vec<f32>,
) {
    if spec.whole() {
        let grid = spec.grid();
        out.push((grid.x(col) / (0.5 * spec.size[0])) as f32);
        out.push((grid.y(row) / (0.5 * spec.size[1])) as f32);
    } else {
        // The position in the window, as the same point of the model's own gel.
        let [h, w] = spec.window.map(|n| 0.5 * n as f64);
        let c = col as f64 - obs.origin[1] as f64 + 0.5;
        let r = row as f64 - obs.origin[0] as f64 + 0.5;
        out.push(((c - w) / w) as f32);
        out.push(((h - r) / h) as f32);
    }
    for field in [&obs.coarse, &obs.pen] {
        window(field, spec.depth_scale, spec, row, col, out);
    }
    obs.push_material(spec, out);
}

/// Appends the `patch x patch` window of `field` (row-major `ny x nx`) times `scale` at
/// lattice point `(row, col)` to `out`: `patch_step` lattice steps between samples, row
/// offset outer, zero outside the gel.
fn window(
    field: &[f64],
    scale: f64,
    spec: &LatticeSpec,
    row: usize,
    col: usize,
    out: &mut Vec<f32>,
) {
    let h = (spec.patch / 2) as isize;
    let step = spec.patch_step as isize;
    let reach = (h * step) as usize;
    if row >= reach && col >= reach && row + reach < spec.ny && col + reach < spec.nx {
        // The whole window on the gel (the common case): the same values, read without
        // a bounds test per sample.
        let (nx, step) = (spec.nx, step as usize);
        for r in (row - reach..=row + reach).step_by(step) {
            let line = &field[r * nx + col - reach..=r * nx + col + reach];
            out.extend(line.iter().step_by(step).map(|&v| (v * scale) as f32));
        }
        return;
    }
    window_checked(field, scale, spec, row, col, out);
}

/// [`window`] with each sample tested against the lattice's bounds (zero outside).
fn window_checked(
    field: &[f64],
    scale: f64,
    spec: &LatticeSpec,
    row: usize,
    col: usize,
    out: &mut Vec<f32>,
) {
    let h = (spec.patch / 2) as isize;
    let step = spec.patch_step as isize;
    for dr in -h..=h {
        for dc in -h..=h {
            let r = row as isize + dr * step;
            let c = col as isize + dc * step;
            let v = if r >= 0 && c >= 0 && (r as usize) < spec.ny && (c as usize) < spec.nx {
                field[r as usize * spec.nx + c as usize] * scale
            } else {
                0.0
            };
            out.push(v as f32);
        }
    }
}

/// Appends the pressure head's window at lattice point `(row, col)` to `out`: the
/// `patch x patch` window of `load` (row-major `ny x nx`; row offset outer, zero outside the
/// gel) with the decoder's window offsets, as `f32`.
pub fn load_window(load: &[f64], spec: &LatticeSpec, row: usize, col: usize, out: &mut Vec<f32>) {
    window(load, 1.0, spec, row, col, out);
}

/// The deformable region of `obs` (row-major into `out`, cleared first): the lattice points
/// where the coarse depth exceeds `eps` (model units) or the indenters pierce the gel,
/// grown `grow` times by the four lattice neighbours: the points within `grow` lattice
/// steps (city-block) of one of those, found by one pass forward and one back over the
/// lattice (`steps`: their buffer, its allocation reused).
pub fn region(
    obs: &Observation,
    spec: &LatticeSpec,
    eps: f64,
    grow: usize,
    steps: &mut Vec<usize>,
    out: &mut Vec<bool>,
) {
    let eps_m = eps / spec.depth_scale;
    let (nx, ny) = (spec.nx, spec.ny);
    // City-block steps to the nearest seed, capped past `grow`.
    let far = grow.saturating_add(1);
    steps.clear();
    steps.extend(
        obs.coarse
            .iter()
            .zip(&obs.pen)
            .map(|(&c, &p)| if c > eps_m || p > 0.0 { 0 } else { far }),
    );
    for r in 0..ny {
        for c in 0..nx {
            let i = r * nx + c;
            let mut s = steps[i];
            if r > 0 {
                s = s.min(steps[i - nx] + 1);
            }
            if c > 0 {
                s = s.min(steps[i - 1] + 1);
            }
            steps[i] = s.min(far);
        }
    }
    for r in (0..ny).rev() {
        for c in (0..nx).rev() {
            let i = r * nx + c;
            let mut s = steps[i];
            if r + 1 < ny {
                s = s.min(steps[i + nx] + 1);
            }
            if c + 1 < nx {
                s = s.min(steps[i + 1] + 1);
            }
            steps[i] = s.min(far);
        }
    }
    out.clear();
    out.extend(steps.iter().map(|&s| s <= grow));
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The window read without bounds tests where it lies on the gel is the one read with
    /// them, at every lattice point (edges, corners and interior), for odd patches and
    /// steps of one and two.
    #[test]
    fn the_unchecked_window_is_the_checked_one() {
        for (patch, patch_step) in [(5, 2), (3, 1), (5, 1), (1, 3)] {
            let spec = LatticeSpec {
                nx: 13,
                ny: 11,
                patch,
                patch_step,
                window: [11, 13],
                ..LatticeSpec::with_pitch([0.03, 0.03, 0.004], 0.003)
            };
            let field: Vec<f64> = (0..spec.nx * spec.ny)
                .map(|i| 2.0 + (i as f64 * 0.37).sin())
                .collect();
            let (mut fast, mut checked) = (Vec::new(), Vec::new());
            for row in 0..spec.ny {
                for col in 0..spec.nx {
                    window(&field, 3.0, &spec, row, col, &mut fast);
                    window_checked(&field, 3.0, &spec, row, col, &mut checked);
                }
            }
            assert_eq!(fast.len(), spec.nx * spec.ny * patch * patch);
            assert!(fast
                .iter()
                .zip(&checked)
                .all(|(a, b)| a.to_bits() == b.to_bits()));
            assert!(fast.iter().any(|&v| v == 0.0) == (patch > 1));
        }
    }

    /// The region by its definition: the seeds grown `grow` times by the four neighbours.
    fn grown_by_definition(seeds: &[bool], nx: usize, ny: usize, grow: usize) -> Vec<bool> {
        let mut out = seeds.to_vec();
        for _ in 0..grow {
            let last = out.clone();
            for r in 0..ny {
                for c in 0..nx {
                    let i = r * nx + c;
                    out[i] = last[i]
                        || (r > 0 && last[i - nx])
                        || (r + 1 < ny && last[i + nx])
                        || (c > 0 && last[i - 1])
                        || (c + 1 < nx && last[i + 1]);
                }
            }
        }
        out
    }

    /// The two passes over the lattice give the region the repeated growth gives: on
    /// lattices of 1 to 23 points a side, with no seed, one, scattered and dense seeds
    /// (from the coarse depth and from the penetration), grown 0 to 6 times.
    #[test]
    fn the_region_is_its_seeds_grown_by_the_four_neighbours() {
        let mut random = crate::test_uniform(7);
        for (nx, ny) in [(1, 1), (1, 9), (9, 1), (5, 7), (23, 17)] {
            for density in [0.0, 0.01, 0.1, 0.5] {
                let spec = LatticeSpec {
                    nx,
                    ny,
                    window: [ny, nx],
                    ..LatticeSpec::with_pitch([0.03, 0.03, 0.004], 0.003)
                };
                let mut obs = Observation::default();
                for _ in 0..nx * ny {
                    let (a, b) = (random(), random());
                    obs.coarse.push(if a < density { 2e-5 } else { 5e-6 });
                    obs.pen.push(if b < 0.3 * density { 1e-6 } else { 0.0 });
                }
                let seeds: Vec<bool> = obs
                    .coarse
                    .iter()
                    .zip(&obs.pen)
                    .map(|(&c, &p)| c > 1e-5 || p > 0.0)
                    .collect();
                for grow in 0..=6 {
                    let mut out = Vec::new();
                    region(&obs, &spec, 0.01, grow, &mut Vec::new(), &mut out);
                    assert_eq!(
                        out,
                        grown_by_definition(&seeds, nx, ny, grow),
                        "{nx}x{ny}, density {density}, grown {grow}"
                    );
                }
            }
        }
    }
}
