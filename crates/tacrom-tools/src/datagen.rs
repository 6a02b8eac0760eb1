//! Paired training data for the reduced-order model: the same quasi-static press solved by
//! the coarse MPM and by a finer reference MPM (`tacrom gen-data`).
//!
//! Each sample is one indenter, pose sequence and material: the indenter is lowered to its
//! depth (and, for some samples, slid a little further: the solver keeps the shear
//! history), then both gels are brought to equilibrium. A sample is written as
//!
//! * `sample-NNNNNN.npy`: float32 `[3, ny, nx]`, metres, on the model's surface lattice
//!   ([`tacrom::rom::features`]): channel 0 the coarse depth (`max(mpm, p)`), 1 the rigid
//!   penetration `p`, 2 the reference depth (`max(mpm, p)`, finer MPM);
//! * `sample-NNNNNN-pressure.npy`: float32 `[2, ny, nx]`, pascals, on the same lattice:
//!   the normal contact pressure of the coarse gel (channel 0) and of the reference
//!   (channel 1), each spread by its own grid's kernel ([`Gel::contact_pressure`]);
//!   absent in data sets written before it was recorded;
//! * `sample-NNNNNN.json`: family, shape parameters, poses, solver reports, timings;
//!   written last (by rename), so a sample counts as done only when both exist.
//!
//! and `dataset.json` records the settings (gel, material, coarse and reference grid
//! spacings, lattice, seed, held-out families; not the sample count, so that a larger
//! `--samples` extends a data set). Sample `i` is drawn from its own random
//! stream seeded by `(seed, i)`, so a run is reproducible whatever the sharding: shard
//! `k/N` does every `N`-th of the selected samples from the `k`-th on (all, or those of
//! `--indices` and `--held-out-only`, so that shards get equal counts), skipping those
//! already on disk (resumable). `--refresh-coarse` instead solves again only the coarse
//! press of the samples on disk and rewrites their coarse channel and report, keeping the
//! reference (a few seconds for a data set, against minutes for its references): for a
//! data set whose coarse solver has changed since it was written.
//! `numpy.load` reads every file; `training/dataset.py` loads a directory.
//!
//! Families: `sphere`, `cylinder` (end-on or lying), `box`, `edge` (a box on one edge),
//! `bumps` (random clusters of small spheres), `ridges` (parallel capsules),
//! `heightfield` (a block with a sinusoidal textured face) and `mesh:<name>`, one per
//! pattern of `../shared/indenters/patterns`, flipped to press with its patterned face,
//! randomly scaled and turned; and, only when `--families` names them, the
//! [`EXTRA_FAMILIES`] `blob`, `stone` and `brick`. Positions over the gel, depths up to
//! 1 mm, tilts up to 8 degrees, slides up to 0.6 mm. [`HELD_OUT`] families are for
//! validation only.
//!
//! **Gels of the family** (`--gel-family`, [`GelFamily`]): each sample's gel is drawn too
//! (12 to 40 mm a side, 1 to 6 mm thick) and solved in the model's units, the model's
//! thickness with sides in thicknesses; the indenter is scaled by a drawn factor and
//! pressed anywhere on the gel. The arrays are then the window of the model's lattice that
//! a sensor on that gel places over the contact (`Rom::serve`; zeros beyond the gel where
//! it is narrower than the window), so that a model trains on exactly what it reads, and
//! the sample's JSON records the gel drawn, the gel simulated and the window's corner.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand_core::{Rng as _, SeedableRng as _};
use rand_xoshiro::SplitMix64;
use serde::{Deserialize, Serialize};

use tacrom::geometry::{Aabb, Capsule, Cuboid, Cylinder, PixelGrid, Placed, Sdf, Sphere, TriMesh};
use tacrom::mpm::{Gel, GelParams, Material, SolveReport, Solver, SolverOptions};
use tacrom::rom::features::{penetration, LatticeSpec, Observation};

use crate::npy;
use crate::progress::Progress;

/// Families drawn only when `--families` names them: `blob` (a sphere whose radius is
/// modulated by a few random waves over its directions), `stone` (a random convex
/// polyhedron, stretched) and `brick` (a toy brick pressed with its studs).
pub const EXTRA_FAMILIES: &[&str] = &["blob", "stone", "brick"];

/// Families kept out of training, for validation (and the held-out test).
pub const HELD_OUT: &[&str] = &[
    "brick",
    "ridges",
    "mesh:dots",
    "mesh:hexagon",
    "mesh:pacman",
    "mesh:torus",
    "mesh:wave1",
];

/// Salt of the random stream that draws a sample's material.
const MATERIAL_STREAM: u64 = 0x6d61_7465_7269_616c;

/// Settings of a data set.
#[derive(Clone, Debug)]
pub struct GenConfig {
    /// Output directory.
    pub out: PathBuf,
    /// Total samples of the data set (all shards).
    pub samples: usize,
    /// This shard and the number of shards.
    pub shard: (usize, usize),
    /// Seed of the data set.
    pub seed: u64,
    /// Coarse grid spacing (m).
    pub coarse_dx: f64,
    /// The coarse solve's equilibrium solver (the reference's is the default one).
    pub coarse_solver: Solver,
    /// Reference grid spacing (m).
    pub fine_dx: f64,
    /// Lattice pitch (m).
    pub pitch: f64,
    /// Solver threads.
    pub threads: usize,
    /// Directory of the pattern meshes (STL, millimetres).
    pub patterns: PathBuf,
    /// Only these families (empty: all).
    pub families: Vec<String>,
    /// Gel parameters (size, material); `dx` is replaced by the two spacings.
    pub gel: GelParams,
    /// Reference solver iteration cap.
    pub fine_max_iterations: usize,
    /// Generate only the samples whose family is held out (a validation set at a costlier
    /// reference resolution, with the same presses as the full set of the same seed).
    pub held_out_only: bool,
    /// Only these sample indices (empty: all); the presses are those of the full set.
    pub indices: Vec<usize>,
    /// Solve again only the coarse press of the samples already on disk, keeping their
    /// reference (see the module docs).
    pub refresh_coarse: bool,
    /// Draw each sample's Poisson's ratio uniformly from this range (the same presses as
    /// with a fixed material; [`GenConfig::gel`]'s otherwise).
    pub poisson_range: Option<[f64; 2]>,
    /// Draw each sample's friction coefficient uniformly from this range.
    pub friction_range: Option<[f64; 2]>,
    /// Draw each sample's gel from the gel family ([`GelFamily`]) and write it in the
    /// model's units, through the window of the model's lattice over the contact.
    pub gel_family: Option<GelFamily>,
}

/// The gels a family data set draws from (`tacrom gen-data --gel-family`), and how they
/// are simulated.
///
/// Elasticity has no length of its own: a gel, its grid and its indenters scaled by `s`
/// are in equilibrium at the same state scaled (the solves are scale-free:
/// `a_scaled_press_is_the_press_scaled`), and a model reads a gel in its own units,
/// through a window of its own lattice over the contact (`Rom::serve`). So a gel of
/// thickness `T` and sides `Lx`, `Ly` is simulated as the model's thickness with sides
/// `Lx / T` and `Ly / T` thicknesses long, which the drawn thickness then only names. A
/// side longer than [`GelFamily::crop`] thicknesses is cut to it: the window the model
/// reads is 7.5 thicknesses across, a bonded layer's response to a press dies out within
/// a few thicknesses of the contact, and the cut keeps the reference's cost that of the
/// default gel's (a 40 x 40 x 1 mm gel would be 160 mm across in the model's units).
/// Every sample's shape is scaled by a factor drawn log-uniformly from
/// [`GelFamily::indenter_scale`], so that the same family of indenters spans sharper and
/// blunter contacts for the thickness; it is pressed anywhere within
/// [`GelFamily::reach`] of the half sides from the centre, edges included.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GelFamily {
    /// Thickness range (m).
    pub thickness: [f64; 2],
    /// Range of each lateral side (m).
    pub side: [f64; 2],
    /// Longest side simulated, in thicknesses.
    pub crop: f64,
    /// Range of the indenter's scale factor (drawn log-uniformly).
    pub indenter_scale: [f64; 2],
    /// How far from the centre the footprint is placed, as a fraction of the half side.
    pub reach: f64,
    /// One gel of the family (sides and thickness, m) for every sample instead of drawn
    /// ones: a validation set of that gel (`--gel-size`). The indenter's scale is drawn
    /// all the same.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gel: Option<[f64; 3]>,
}

impl Default for GelFamily {
    /// Issue 54's family: 12 to 40 mm on each side, 1 to 6 mm thick.
    fn default() -> Self {
        Self {
            thickness: [1e-3, 6e-3],
            side: [12e-3, 40e-3],
            crop: 9.0,
            indenter_scale: [0.5, 2.0],
            reach: 0.96,
            gel: None,
        }
    }
}

/// One sample's gel of a family data set, as recorded in its JSON (lengths in metres).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FamilyGel {
    /// The gel drawn: sides and thickness.
    pub size: [f64; 3],
    /// The gel simulated, in the model's units: the drawn gel scaled to the model's
    /// thickness, each side cut to [`GelFamily::crop`] thicknesses.
    pub simulated: [f64; 3],
    /// Whether a side was cut.
    pub cropped: bool,
    /// The indenter's scale factor.
    pub indenter_scale: f64,
    /// The lattice point `[row, column]` of the simulated gel at the window's first corner
    /// (the sample's arrays are that window); filled in when the sample is solved.
    #[serde(default)]
    pub origin: [isize; 2],
}

/// Salt of the random stream that draws a family sample's gel.
const GEL_STREAM: u64 = 0x6765_6c73_697a_6573;

impl GelFamily {
    /// The family with every sample on `gel` (sides and thickness, m), which must lie in
    /// it: the error names the value and the range.
    pub fn with_gel(mut self, gel: [f64; 3]) -> Result<Self, String> {
        let within = |v: f64, [lo, hi]: [f64; 2]| v.is_finite() && v >= lo && v <= hi;
        let mm = |v: f64| 1e3 * v;
        for (name, v, range) in [
            ("side x", gel[0], self.side),
            ("side y", gel[1], self.side),
            ("thickness", gel[2], self.thickness),
        ] {
            if !within(v, range) {
                return Err(format!(
                    "gel {name} {} mm lies outside the gel family's {} to {} mm",
                    mm(v),
                    mm(range[0]),
                    mm(range[1])
                ));
            }
        }
        self.gel = Some(gel);
        Ok(self)
    }

    /// Sample `index`'s gel, for a model of thickness `model_thickness` (m), from a stream
    /// of its own (the press's own draws stay those of a data set on one gel).
    pub fn draw(&self, seed: u64, index: usize, model_thickness: f64) -> FamilyGel {
        let mut rng = Rng::new(seed ^ GEL_STREAM, index as u64);
        let mut t = rng.uniform(self.thickness[0], self.thickness[1]);
        let mut sides = [
            rng.uniform(self.side[0], self.side[1]),
            rng.uniform(self.side[0], self.side[1]),
        ];
        let [a, b] = self.indenter_scale.map(f64::ln);
        let indenter_scale = rng.uniform(a, b).exp();
        if let Some([x, y, z]) = self.gel {
            (sides, t) = ([x, y], z);
        }
        let simulated = sides.map(|l| model_thickness * (l / t).min(self.crop));
        FamilyGel {
            size: [sides[0], sides[1], t],
            simulated: [simulated[0], simulated[1], model_thickness],
            cropped: sides.iter().any(|&l| l / t > self.crop),
            indenter_scale,
            origin: [0, 0],
        }
    }
}

impl GenConfig {
    /// Sample `index`'s gel: [`GenConfig::gel`], with Poisson's ratio and friction drawn
    /// from their ranges where given, from a stream of their own (so that the presses are
    /// those of a data set with a fixed material).
    pub fn sample_gel(&self, index: usize) -> GelParams {
        let mut rng = Rng::new(self.seed ^ MATERIAL_STREAM, index as u64);
        let mut gel = self.gel;
        if let Some(f) = self.family_gel(index) {
            gel.size = f.simulated;
        }
        if let Some([a, b]) = self.poisson_range {
            gel.poisson = rng.uniform(a, b);
        }
        if let Some([a, b]) = self.friction_range {
            gel.friction = rng.uniform(a, b);
        }
        gel
    }

    /// Sample `index`'s gel, for a family data set.
    pub fn family_gel(&self, index: usize) -> Option<FamilyGel> {
        self.gel_family
            .map(|f| f.draw(self.seed, index, self.gel.size[2]))
    }

    /// Press `index` of the data set: on [`GenConfig::gel`], or on the sample's gel of a
    /// family data set.
    pub fn press(&self, index: usize, meshes: &mut MeshLibrary) -> Result<Press, String> {
        match self.gel_family {
            Some(f) => {
                let g = f.draw(self.seed, index, self.gel.size[2]);
                draw_press_with(
                    self.seed,
                    index as u64,
                    meshes,
                    &self.families,
                    g.simulated,
                    [f.reach; 2],
                    g.indenter_scale,
                )
            }
            None => draw_press(
                self.seed,
                index as u64,
                meshes,
                &self.families,
                self.gel.size,
            ),
        }
    }

    /// The sample indices of this shard, in order: every `N`-th of the selected samples
    /// (all of them, or those of [`GenConfig::indices`] and, with
    /// [`GenConfig::held_out_only`], of held-out families) from the `K`-th on, so that
    /// shards get equal counts whatever the selection.
    fn shard_indices(&self, meshes: &mut MeshLibrary) -> Result<Vec<usize>, String> {
        let mut picked = Vec::new();
        for i in 0..self.samples {
            if !self.indices.is_empty() && !self.indices.contains(&i) {
                continue;
            }
            if self.held_out_only {
                let p = self.press(i, meshes)?;
                if !HELD_OUT.contains(&p.family.as_str()) {
                    continue;
                }
            }
            picked.push(i);
        }
        let (k, n) = self.shard;
        Ok(picked.into_iter().skip(k).step_by(n.max(1)).collect())
    }
}

impl Default for GenConfig {
    fn default() -> Self {
        Self {
            out: PathBuf::from("data/rom"),
            samples: 100,
            shard: (0, 1),
            seed: 1,
            coarse_dx: 1.4e-3,
            coarse_solver: Solver::Relaxation,
            fine_dx: 0.7e-3,
            pitch: 0.3e-3,
            threads: 1,
            patterns: tacrom::checkout_root().join("../shared/indenters/patterns"),
            families: Vec::new(),
            gel: GelParams::default(),
            fine_max_iterations: 6000,
            held_out_only: false,
            indices: Vec::new(),
            refresh_coarse: false,
            poisson_range: None,
            friction_range: None,
            gel_family: None,
        }
    }
}

/// The random generator of the tools: SplitMix64 (`rand_xoshiro`), with the two draws the
/// data sets are made of. Sample `i` of a data set seeded `s` has its own stream, so the
/// presses do not depend on sharding; the streams and draws are those of the first data
/// sets (`tests/presses.rs` pins them).
#[derive(Clone, Debug)]
pub struct Rng(SplitMix64);

impl Rng {
    /// The stream of sample `index` of a data set seeded `seed`.
    pub fn new(seed: u64, index: u64) -> Self {
        let mut r = Rng(SplitMix64::seed_from_u64(
            seed ^ index.wrapping_mul(0xD1B5_4A32_D192_ED03),
        ));
        let _ = r.next_u64();
        r
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }
    /// Uniform in `[a, b)`, from the top 53 bits of one draw.
    pub fn uniform(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }
    /// Uniform integer in `[0, n)` (the remainder of one draw).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
}

/// A shape scaled uniformly by `scale` about its local origin.
#[derive(Debug)]
pub struct Scaled {
    /// The shape.
    pub inner: Arc<dyn Sdf>,
    /// Scale factor.
    pub scale: f64,
}

impl Sdf for Scaled {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        self.scale * self.inner.distance(&(p / self.scale))
    }
    fn gradient(&self, p: &Point3<f64>) -> Vector3<f64> {
        self.inner.gradient(&(p / self.scale))
    }
    fn aabb(&self) -> Aabb {
        let b = self.inner.aabb();
        Aabb::new(b.min * self.scale, b.max * self.scale)
    }
}

/// The union of shapes, each at its local pose (distance: the minimum).
#[derive(Debug)]
pub struct Union {
    /// Parts and their poses in the union's frame.
    pub parts: Vec<(Arc<dyn Sdf>, Isometry3<f64>)>,
}

impl Sdf for Union {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        self.parts
            .iter()
            .map(|(s, pose)| s.distance(&pose.inverse_transform_point(p)))
            .fold(f64::INFINITY, f64::min)
    }
    fn gradient(&self, p: &Point3<f64>) -> Vector3<f64> {
        let mut best = (f64::INFINITY, Vector3::z());
        for (s, pose) in &self.parts {
            let q = pose.inverse_transform_point(p);
            let d = s.distance(&q);
            if d < best.0 {
                best = (d, pose.rotation * s.gradient(&q));
            }
        }
        best.1
    }
    fn aabb(&self) -> Aabb {
        let mut min = Point3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY);
        let mut max = -min;
        for (s, pose) in &self.parts {
            let b = s.aabb().transformed(pose);
            min = min.inf(&b.min);
            max = max.sup(&b.max);
        }
        Aabb::new(min, max)
    }
}

/// A block `[-hx, hx] x [-hy, hy] x [h(x, y), top]` whose lower face is the textured height
/// field `h = -sum_k a_k (1 + sin(kx_k x + ky_k y + phase_k)) / 2`. The distance is the
/// Lipschitz-bounded `max` of the face, side and top distances: exact sign, a lower bound
/// of the magnitude (enough for sphere tracing and contact).
#[derive(Debug)]
pub struct HeightField {
    /// Half extents in x and y (m).
    pub half: [f64; 2],
    /// Height of the top face (m).
    pub top: f64,
    /// `(amplitude, kx, ky, phase)` of each mode.
    pub modes: Vec<(f64, f64, f64, f64)>,
}

impl HeightField {
    fn height(&self, x: f64, y: f64) -> f64 {
        -self
            .modes
            .iter()
            .map(|&(a, kx, ky, ph)| 0.5 * a * (1.0 + (kx * x + ky * y + ph).sin()))
            .sum::<f64>()
    }
    fn lipschitz(&self) -> f64 {
        let g: f64 = self
            .modes
            .iter()
            .map(|&(a, kx, ky, _)| 0.5 * a * (kx * kx + ky * ky).sqrt())
            .sum();
        (1.0 + g * g).sqrt()
    }
}

impl Sdf for HeightField {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        let face = (self.height(p.x, p.y) - p.z) / self.lipschitz();
        let side = (p.x.abs() - self.half[0]).max(p.y.abs() - self.half[1]);
        let top = p.z - self.top;
        face.max(side).max(top)
    }
    fn aabb(&self) -> Aabb {
        let depth: f64 = self.modes.iter().map(|m| m.0).sum();
        Aabb::new(
            Point3::new(-self.half[0], -self.half[1], -depth),
            Point3::new(self.half[0], self.half[1], self.top),
        )
    }
}

/// A star-shaped blob about its origin: along each direction `u` its radius is
/// `radius (1 + sum a cos(k . u + phase))` over its `modes`. The distance is the radial
/// one divided by its Lipschitz bound near the surface: exact sign, a lower bound of the
/// magnitude (enough for sphere tracing and contact), as [`HeightField`]'s.
#[derive(Debug)]
pub struct Blob {
    /// Mean radius (m).
    pub radius: f64,
    /// `(a, k, phase)` of each mode (`sum a` below 1).
    pub modes: Vec<(f64, Vector3<f64>, f64)>,
}

impl Blob {
    fn swing(&self) -> f64 {
        self.modes.iter().map(|m| m.0).sum()
    }
    fn lipschitz(&self) -> f64 {
        let g: f64 = self.modes.iter().map(|(a, k, _)| a * k.norm()).sum();
        (1.0 + (g / (1.0 - self.swing())).powi(2)).sqrt()
    }
}

impl Sdf for Blob {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        let n = p.coords.norm();
        if n < 1e-12 * self.radius {
            return -self.radius * (1.0 - self.swing());
        }
        let u = p.coords / n;
        let r = self.radius
            * (1.0
                + self
                    .modes
                    .iter()
                    .map(|(a, k, ph)| a * (k.dot(&u) + ph).cos())
                    .sum::<f64>());
        (n - r) / self.lipschitz()
    }
    fn aabb(&self) -> Aabb {
        let r = self.radius * (1.0 + self.swing());
        Aabb::new(Point3::new(-r, -r, -r), Point3::new(r, r, r))
    }
}

/// A convex polyhedron, the intersection of the half-spaces `n . p <= d` (unit `n`): a
/// stone with flat faces, sharp edges and corners. The distance is the largest of the
/// planes': exact inside and on the faces, a lower bound outside.
#[derive(Debug)]
pub struct Polyhedron {
    /// `(n, d)` of each face.
    pub planes: Vec<(Vector3<f64>, f64)>,
    /// Half extent of a cube about the origin that holds it (m).
    pub bound: f64,
}

impl Sdf for Polyhedron {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        self.planes
            .iter()
            .map(|(n, d)| n.dot(&p.coords) - d)
            .fold(f64::NEG_INFINITY, f64::max)
    }
    fn aabb(&self) -> Aabb {
        let b = self.bound;
        Aabb::new(Point3::new(-b, -b, -b), Point3::new(b, b, b))
    }
}

/// A uniformly random unit vector.
fn unit_vector(rng: &mut Rng) -> Vector3<f64> {
    let z = rng.uniform(-1.0, 1.0);
    let a = rng.uniform(0.0, 2.0 * std::f64::consts::PI);
    let s = (1.0 - z * z).sqrt();
    Vector3::new(s * a.cos(), s * a.sin(), z)
}

/// Pattern meshes, loaded once (metres, flipped so the patterned face is lowest).
#[derive(Default)]
pub struct MeshLibrary {
    dir: PathBuf,
    names: Vec<String>,
    cache: HashMap<String, Arc<dyn Sdf>>,
}

impl MeshLibrary {
    /// The `.stl` files of `dir`, sorted by name (none if the directory is missing).
    pub fn new(dir: &Path) -> Self {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .map(|rd| {
                rd.filter_map(|e| e.ok())
                    .filter_map(|e| e.file_name().into_string().ok())
                    .filter(|n| n.to_ascii_lowercase().ends_with(".stl"))
                    .map(|n| n[..n.len() - 4].to_owned())
                    .collect()
            })
            .unwrap_or_default();
        names.sort();
        Self {
            dir: dir.to_owned(),
            names,
            cache: HashMap::new(),
        }
    }

    /// Pattern names.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The mesh `name`, centred in x and y, patterned face down at `z = 0` and the body
    /// above it (m).
    pub fn get(&mut self, name: &str) -> Result<Arc<dyn Sdf>, String> {
        if let Some(s) = self.cache.get(name) {
            return Ok(s.clone());
        }
        let path = self.dir.join(format!("{name}.stl"));
        let data = tacrom::geometry::load_stl(&path, 1e-3).map_err(|e| e.to_string())?;
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for v in &data.vertices {
            lo = lo.inf(&v.coords);
            hi = hi.sup(&v.coords);
        }
        let c = 0.5 * (lo + hi);
        // Flip about x (z -> -z), patterned face (max z) to z = 0.
        let vertices: Vec<Point3<f64>> = data
            .vertices
            .iter()
            .map(|v| Point3::new(v.x - c.x, -(v.y - c.y), hi.z - v.z))
            .collect();
        // A rotation: the triangles keep their winding.
        let mesh =
            TriMesh::new(vertices, data.faces).map_err(|e| format!("{}: {e}", path.display()))?;
        let s: Arc<dyn Sdf> = Arc::new(mesh);
        let _ = self.cache.insert(name.to_owned(), s.clone());
        Ok(s)
    }
}

/// One paired press: an indenter and its poses (the last one is the frame recorded).
#[derive(Clone, Debug)]
pub struct Press {
    /// Family name.
    pub family: String,
    /// The shape.
    pub shape: Arc<dyn Sdf>,
    /// Poses in the sensor frame, solved in order.
    pub poses: Vec<Isometry3<f64>>,
    /// Shape and pose parameters, as recorded in the sample's JSON.
    pub params: PressParams,
}

/// The parameters of a press, as the members of its sample's JSON: the shape's (those of
/// its family; the others are left out) and the pose's. Lengths in metres, angles in
/// radians.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PressParams {
    /// Sphere, cylinder or ridge radius.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// Cylinder half length.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub half_length: Option<f64>,
    /// Whether the cylinder lies on its side.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lying: Option<bool>,
    /// Box half extents.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub half_extents: Option<[f64; 3]>,
    /// Number of bumps or ridges.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub count: Option<usize>,
    /// Half width of the square the bumps are spread over.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spread: Option<f64>,
    /// Distance between ridges.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gap: Option<f64>,
    /// Height field half extents in x and y.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub half: Option<[f64; 2]>,
    /// Number of height field modes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modes: Option<usize>,
    /// Pattern mesh name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<String>,
    /// Pattern mesh scale.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    /// Position of the footprint over the gel.
    pub x: f64,
    /// See `x`.
    pub y: f64,
    /// Depth below first contact.
    pub depth: f64,
    /// Turn about the sensor's z axis.
    pub yaw: f64,
    /// Tilt away from z.
    pub tilt: f64,
    /// In-plane slide after the press (x, y), if any.
    pub slide: Option<[f64; 2]>,
}

impl Press {
    /// The indenter at pose `k`.
    pub fn placed(&self, k: usize) -> Placed {
        Placed {
            shape: self.shape.clone(),
            pose: self.poses[k],
        }
    }
}

/// The family of sample `index` and its weights: every mesh pattern is a family of its own.
fn families(meshes: &MeshLibrary) -> Vec<(String, f64)> {
    let mut f: Vec<(String, f64)> = [
        ("sphere", 1.0),
        ("cylinder", 1.0),
        ("box", 1.0),
        ("edge", 1.0),
        ("bumps", 1.5),
        ("ridges", 1.0),
        ("heightfield", 1.5),
    ]
    .iter()
    .map(|(n, w)| (n.to_string(), *w))
    .collect();
    let per_mesh = if meshes.names().is_empty() {
        0.0
    } else {
        4.0 / meshes.names().len() as f64
    };
    for n in meshes.names() {
        f.push((format!("mesh:{n}"), per_mesh));
    }
    f
}

fn rot_z(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a)
}

/// Draws the shape of `family` with its local orientation (before yaw, tilt and depth).
fn draw_shape(
    family: &str,
    rng: &mut Rng,
    meshes: &mut MeshLibrary,
    params: &mut PressParams,
) -> Result<(Arc<dyn Sdf>, UnitQuaternion<f64>), String> {
    let mm = 1e-3;
    let half_pi = std::f64::consts::FRAC_PI_2;
    let id = UnitQuaternion::identity();
    Ok(match family {
        "sphere" => {
            let r = rng.uniform(2.0, 8.0) * mm;
            params.radius = Some(r);
            (Arc::new(Sphere::new(r)), id)
        }
        "cylinder" => {
            let r = rng.uniform(1.5, 5.0) * mm;
            let h = rng.uniform(3.0, 8.0) * mm;
            let lying = rng.uniform(0.0, 1.0) < 0.5;
            (params.radius, params.half_length, params.lying) = (Some(r), Some(h), Some(lying));
            let q = if lying {
                UnitQuaternion::from_axis_angle(&Vector3::x_axis(), half_pi)
            } else {
                id
            };
            (Arc::new(Cylinder::new(r, h)), q)
        }
        "box" | "edge" => {
            let he = Vector3::new(rng.uniform(1.0, 6.0), rng.uniform(1.0, 6.0), 3.0) * mm;
            params.half_extents = Some(he.into());
            let q = if family == "edge" {
                UnitQuaternion::from_axis_angle(
                    &Vector3::x_axis(),
                    rng.uniform(0.6, 0.97) * half_pi,
                )
            } else {
                id
            };
            (Arc::new(Cuboid::new(he)), q)
        }
        "bumps" => {
            let n = 3 + rng.below(6);
            let mut parts: Vec<(Arc<dyn Sdf>, Isometry3<f64>)> = Vec::new();
            let spread = rng.uniform(2.0, 5.0) * mm;
            for _ in 0..n {
                let r = rng.uniform(0.5, 2.0) * mm;
                let c = Vector3::new(
                    rng.uniform(-spread, spread),
                    rng.uniform(-spread, spread),
                    rng.uniform(0.0, 0.8) * mm + r,
                );
                parts.push((
                    Arc::new(Sphere::new(r)),
                    Isometry3::from_parts(Translation3::from(c), id),
                ));
            }
            (params.count, params.spread) = (Some(n), Some(spread));
            (Arc::new(Union { parts }), id)
        }
        "ridges" => {
            let n = 2 + rng.below(4);
            let r = rng.uniform(0.4, 1.2) * mm;
            let gap = rng.uniform(1.5, 4.0) * mm;
            let hl = rng.uniform(3.0, 6.0) * mm;
            let mut parts: Vec<(Arc<dyn Sdf>, Isometry3<f64>)> = Vec::new();
            let along_x = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), half_pi);
            for k in 0..n {
                let y = (k as f64 - 0.5 * (n - 1) as f64) * gap;
                let z = r + rng.uniform(0.0, 0.15) * mm;
                parts.push((
                    Arc::new(Capsule::new(r, hl)),
                    Isometry3::from_parts(Translation3::new(0.0, y, z), along_x),
                ));
            }
            (params.count, params.radius, params.gap) = (Some(n), Some(r), Some(gap));
            (Arc::new(Union { parts }), id)
        }
        "heightfield" => {
            let half = [rng.uniform(3.0, 7.0) * mm, rng.uniform(3.0, 7.0) * mm];
            let n = 1 + rng.below(3);
            let mut modes = Vec::new();
            for _ in 0..n {
                let wavelength = rng.uniform(1.0, 5.0) * mm;
                let k = 2.0 * std::f64::consts::PI / wavelength;
                let dir = rng.uniform(0.0, std::f64::consts::PI);
                modes.push((
                    rng.uniform(0.1, 0.5) * mm,
                    k * dir.cos(),
                    k * dir.sin(),
                    rng.uniform(0.0, 6.3),
                ));
            }
            (params.half, params.modes) = (Some(half), Some(n));
            (
                Arc::new(HeightField {
                    half,
                    top: 3.0 * mm,
                    modes,
                }),
                id,
            )
        }
        "blob" => {
            let r = rng.uniform(1.5, 5.0) * mm;
            let n = 2 + rng.below(4);
            let modes = (0..n)
                .map(|_| {
                    let k = unit_vector(rng) * rng.uniform(1.0, 4.0);
                    (rng.uniform(0.02, 0.3 / n as f64), k, rng.uniform(0.0, 6.3))
                })
                .collect();
            (params.radius, params.count) = (Some(r), Some(n));
            (Arc::new(Blob { radius: r, modes }), id)
        }
        "stone" => {
            let r = rng.uniform(1.5, 5.0) * mm;
            let stretch = Vector3::new(
                rng.uniform(0.6, 1.0),
                rng.uniform(0.6, 1.0),
                rng.uniform(0.5, 1.0),
            );
            let n = 8 + rng.below(13);
            // Random faces, and the octahedron's eight at the full radius so that the
            // intersection is bounded; the stretch maps each plane `n . q <= d` of the
            // round stone to `(n / s) . p <= d` of the stretched one.
            let mut faces: Vec<(Vector3<f64>, f64)> = (0..n)
                .map(|_| (unit_vector(rng), r * rng.uniform(0.75, 1.0)))
                .collect();
            for k in 0..8 {
                let sign = |b: usize| if k & b == 0 { 1.0 } else { -1.0 };
                let v = Vector3::new(sign(1), sign(2), sign(4)) / 3f64.sqrt();
                faces.push((v, r));
            }
            let planes = faces
                .into_iter()
                .map(|(n, d)| {
                    let m = n.component_div(&stretch);
                    (m / m.norm(), d / m.norm())
                })
                .collect();
            let bound = r * 3f64.sqrt() * stretch.max();
            (params.radius, params.count) = (Some(r), Some(n));
            (Arc::new(Polyhedron { planes, bound }), id)
        }
        "brick" => {
            // A toy brick pressed with its studs: a block whose lower face carries a grid
            // of short cylinders.
            let he = Vector3::new(rng.uniform(2.0, 6.0), rng.uniform(2.0, 6.0), 2.0) * mm;
            let r = rng.uniform(0.5, 1.0) * mm;
            let hs = rng.uniform(0.25, 0.6) * mm;
            let gap = 2.0 * r + rng.uniform(0.6, 2.0) * mm;
            let count = |h: f64| (((2.0 * h - 2.0 * r) / gap).floor() as usize + 1).max(1);
            let (nx, ny) = (count(he.x), count(he.y));
            let mut parts: Vec<(Arc<dyn Sdf>, Isometry3<f64>)> = vec![(
                Arc::new(Cuboid::new(he)),
                Isometry3::translation(0.0, 0.0, he.z),
            )];
            let stud: Arc<dyn Sdf> = Arc::new(Cylinder::new(r, hs));
            for i in 0..nx {
                for j in 0..ny {
                    let x = (i as f64 - 0.5 * (nx - 1) as f64) * gap;
                    let y = (j as f64 - 0.5 * (ny - 1) as f64) * gap;
                    parts.push((stud.clone(), Isometry3::translation(x, y, -hs)));
                }
            }
            params.half_extents = Some(he.into());
            (params.radius, params.count, params.gap) = (Some(r), Some(nx * ny), Some(gap));
            (Arc::new(Union { parts }), id)
        }
        f if f.starts_with("mesh:") => {
            let name = &f[5..];
            let mesh = meshes.get(name)?;
            let s = rng.uniform(0.4, 0.9);
            (params.mesh, params.scale) = (Some(name.to_owned()), Some(s));
            (
                Arc::new(Scaled {
                    inner: mesh,
                    scale: s,
                }),
                id,
            )
        }
        other => return Err(format!("unknown indenter family '{other}'")),
    })
}

/// Lowest z of `shape` at `pose` over the gel (sampled at 0.1 mm), `None` if it misses.
fn lowest_point(shape: &Arc<dyn Sdf>, pose: &Isometry3<f64>, size: [f64; 3]) -> Option<f64> {
    let grid = PixelGrid {
        width: (size[0] / 1e-4).round() as usize,
        height: (size[1] / 1e-4).round() as usize,
        fov_x: size[0],
        fov_y: size[1],
    };
    let placed = [Placed {
        shape: shape.clone(),
        pose: *pose,
    }];
    let (mut zmin, mut pen) = (Vec::new(), Vec::new());
    // The shape's bounding-box bottom put 0.5 m deep into a gel 1 m thick.
    let lift = placed[0].aabb().min.z + 0.5;
    let mut lowered = placed.clone();
    lowered[0].pose.translation.vector.z -= lift;
    let rule = tacrom::render::DepthRule::new(1.0, &lowered);
    penetration(&lowered, &grid, &rule, &mut zmin, &mut pen);
    let _ = pen;
    let m = zmin.iter().cloned().fold(f64::INFINITY, f64::min);
    m.is_finite().then_some(m + lift)
}

/// Draws press `index` of the data set (deterministic in `(seed, index)`) on a gel of
/// `size`: its footprint within 0.3 and 0.25 of the sides from the centre.
pub fn draw_press(
    seed: u64,
    index: u64,
    meshes: &mut MeshLibrary,
    only: &[String],
    size: [f64; 3],
) -> Result<Press, String> {
    draw_press_with(seed, index, meshes, only, size, [0.6, 0.5], 1.0)
}

/// As [`draw_press`], the footprint within `reach` of the half sides from the centre, the
/// shape scaled by `scale` about its own origin (the same random draws).
pub fn draw_press_with(
    seed: u64,
    index: u64,
    meshes: &mut MeshLibrary,
    only: &[String],
    size: [f64; 3],
    reach: [f64; 2],
    scale: f64,
) -> Result<Press, String> {
    let mut rng = Rng::new(seed, index);
    let mut fams = families(meshes);
    // Families outside the default set join only when named (the presses of a seed
    // without them stay what they were).
    for extra in EXTRA_FAMILIES {
        if only.iter().any(|o| o == extra) {
            fams.push((extra.to_string(), 1.0));
        }
    }
    if !only.is_empty() {
        fams.retain(|(n, _)| {
            only.iter()
                .any(|o| o == n || (o == "mesh" && n.starts_with("mesh:")))
        });
        if fams.is_empty() {
            return Err(format!("no family matches {only:?}"));
        }
    }
    let total: f64 = fams.iter().map(|f| f.1).sum();
    let mut u = rng.uniform(0.0, total);
    let mut family = fams[fams.len() - 1].0.clone();
    for (n, w) in &fams {
        if u < *w {
            family = n.clone();
            break;
        }
        u -= w;
    }
    let mut params = PressParams::default();
    let (mut shape, local) = draw_shape(&family, &mut rng, meshes, &mut params)?;
    if scale != 1.0 {
        shape = Arc::new(Scaled {
            inner: shape,
            scale,
        });
    }
    let yaw = rng.uniform(0.0, 2.0 * std::f64::consts::PI);
    let tilt_axis = rng.uniform(0.0, 2.0 * std::f64::consts::PI);
    let tilt = rng.uniform(0.0, 8f64.to_radians());
    let tilt_q = UnitQuaternion::from_axis_angle(
        &nalgebra::Unit::new_normalize(Vector3::new(tilt_axis.cos(), tilt_axis.sin(), 0.0)),
        tilt,
    );
    let rot = tilt_q * rot_z(yaw) * local;
    let x = 0.5 * rng.uniform(-reach[0], reach[0]) * size[0];
    let y = 0.5 * rng.uniform(-reach[1], reach[1]) * size[1];
    // Depths 0 to 1 mm, more of them shallow.
    let depth = 1e-3 * rng.uniform(0.05, 1.0).powf(1.3).min(1.0);
    let slide = if rng.uniform(0.0, 1.0) < 0.3 {
        let a = rng.uniform(0.0, 2.0 * std::f64::consts::PI);
        let d = rng.uniform(0.1, 0.6) * 1e-3;
        Some(Vector3::new(d * a.cos(), d * a.sin(), 0.0))
    } else {
        None
    };
    let mut pose = Isometry3::from_parts(Translation3::new(x, y, 0.0), rot);
    let low =
        lowest_point(&shape, &pose, size).ok_or_else(|| format!("{family}: misses the gel"))?;
    pose.translation.vector.z -= low + depth;
    let mut poses = vec![pose];
    if let Some(s) = slide {
        let mut p2 = pose;
        p2.translation.vector += s;
        poses.push(p2);
    }
    (params.x, params.y, params.depth) = (x, y, depth);
    (params.yaw, params.tilt) = (yaw, tilt);
    params.slide = slide.map(|s| [s.x, s.y]);
    Ok(Press {
        family,
        shape,
        poses,
        params,
    })
}

/// Solves `press` on `gel` from the undeformed state, pose by pose.
pub fn solve_press(gel: &mut Gel, press: &Press) -> (SolveReport, f64) {
    gel.reset();
    let t0 = Instant::now();
    let mut report = None;
    for k in 0..press.poses.len() {
        report = Some(gel.solve(&[press.placed(k)]));
    }
    (
        report.expect("a press has a pose"),
        t0.elapsed().as_secs_f64(),
    )
}

/// A sample's array, float32 `[3, ny, nx]` (m), row-major: the observation's coarse depth
/// and rigid penetration, then the `reference` surface depth under the observation's depth
/// rule.
pub fn sample_array(obs: &Observation, reference: &[f64]) -> Vec<f32> {
    let mut data: Vec<f32> = Vec::with_capacity(3 * obs.coarse.len());
    data.extend(obs.coarse.iter().map(|&v| v as f32));
    data.extend(obs.pen.iter().map(|&v| v as f32));
    data.extend(
        reference
            .iter()
            .zip(&obs.pen)
            .map(|(&r, &p)| obs.rule.depth(r, p) as f32),
    );
    data
}

/// The pressure companion of the sample whose files share `stem` (`sample-NNNNNN`).
pub fn pressure_path(stem: &Path) -> PathBuf {
    let mut name = stem.file_name().unwrap_or_default().to_os_string();
    name.push("-pressure.npy");
    stem.with_file_name(name)
}

/// A sample's pressure array, float32 `[2, ny, nx]` (Pa), row-major: the normal contact
/// pressure of the solved `coarse` gel, then of the solved `reference` gel, on `lattice`.
pub fn pressure_array(coarse: &Gel, reference: &Gel, lattice: &PixelGrid) -> Vec<f32> {
    let n = lattice.width * lattice.height;
    let mut p = vec![0.0; n];
    let mut data = Vec::with_capacity(2 * n);
    for gel in [coarse, reference] {
        gel.contact_pressure(lattice, &mut p);
        data.extend(p.iter().map(|&v| v as f32));
    }
    data
}

/// Writes a float32 array as `.npy` (C order), atomically.
pub fn write_npy(path: &Path, shape: &[usize], data: &[f32]) -> std::io::Result<()> {
    npy::write(path, shape, data)
}

/// Reads a float32 C-order `.npy` file as written by [`write_npy`]: shape and values.
pub fn read_npy(path: &Path) -> Result<(Vec<usize>, Vec<f32>), String> {
    npy::read(path)
}

/// `dataset.json`: the settings of a data set (all lengths in metres). Read by
/// `training/tacrom_rom/data.py` and by `tacrom eval-rom`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Dataset {
    /// `tacrom-rom-pairs-1`.
    pub format: String,
    /// Names of the channels of each sample's array.
    pub channels: Vec<String>,
    /// Unit of the arrays and lengths (`m`).
    pub units: String,
    /// Gel size (x, y, thickness).
    pub size: [f64; 3],
    /// Young's modulus (Pa).
    pub young: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Density (kg/m^3).
    pub density: f64,
    /// Coulomb friction coefficient.
    pub friction: f64,
    /// Constitutive model.
    pub material: String,
    /// Coarse grid spacing.
    pub coarse_dx: f64,
    /// Reference grid spacing.
    pub fine_dx: f64,
    /// Lattice pitch.
    pub pitch: f64,
    /// Lattice rows and columns (`ny`, `nx`).
    pub lattice: [usize; 2],
    /// Seed of the presses.
    pub seed: u64,
    /// Families kept out of training.
    pub held_out: Vec<String>,
    /// Reference solver iteration cap.
    pub fine_max_iterations: usize,
    /// The coarse solve of the `coarse` channel, copied into a model's manifest by the
    /// exporter and checked by the sensor when it loads the model. Absent in data sets
    /// written before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recipe: Option<tacrom::rom::Recipe>,
    /// The range each sample's Poisson's ratio is drawn from (absent: `poisson` for all).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poisson_range: Option<[f64; 2]>,
    /// The range each sample's friction coefficient is drawn from (absent: `friction`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction_range: Option<[f64; 2]>,
    /// The gel family each sample's gel is drawn from; `size` is then the model's gel,
    /// whose lattice each sample's window is ([`GelFamily`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gel_family: Option<GelFamily>,
}

/// A solver's report on one press, in a sample's JSON.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveMeta {
    /// Iterations of the last pose.
    pub iterations: usize,
    /// Whether the last pose converged.
    pub converged: bool,
    /// Final residual (`null` when not finite).
    pub residual: Option<f64>,
    /// Wall time of the whole press (s).
    pub seconds: f64,
    /// Total force of the gel on the indenter at the last pose (N, sensor frame; absent
    /// in data sets written before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force: Option<[f64; 3]>,
}

impl SolveMeta {
    /// The report `r` of a press solved in `seconds`.
    pub fn new(r: &SolveReport, seconds: f64) -> Self {
        Self {
            iterations: r.iterations,
            converged: r.converged,
            residual: r.residual.is_finite().then_some(r.residual),
            seconds,
            force: None,
        }
    }
}

/// `sample-NNNNNN.json`: what one sample holds besides its array.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleMeta {
    /// Index of the sample in the data set.
    pub index: usize,
    /// Indenter family.
    pub family: String,
    /// Whether the family is held out of training.
    pub held_out: bool,
    /// Shape and pose.
    #[serde(flatten)]
    pub params: PressParams,
    /// The coarse solve.
    pub coarse: SolveMeta,
    /// The reference solve.
    pub reference: SolveMeta,
    /// This sample's Poisson's ratio, where the data set draws it per sample.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poisson: Option<f64>,
    /// This sample's friction coefficient, where the data set draws it per sample.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction: Option<f64>,
    /// This sample's gel, in a family data set.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gel: Option<FamilyGel>,
}

/// `field` on `spec`'s lattice (row-major), cut to the window of `spec.window` points
/// whose first corner is lattice point `origin`; 0 beyond the lattice.
pub fn cut_window<T: Copy + Default>(
    field: &[T],
    spec: &LatticeSpec,
    origin: [isize; 2],
) -> Vec<T> {
    let [rows, cols] = spec.window;
    let mut out = Vec::with_capacity(rows * cols);
    for row in 0..rows as isize {
        for col in 0..cols as isize {
            let (r, c) = (origin[0] + row, origin[1] + col);
            let inside = r >= 0 && c >= 0 && (r as usize) < spec.ny && (c as usize) < spec.nx;
            out.push(if inside {
                field[r as usize * spec.nx + c as usize]
            } else {
                T::default()
            });
        }
    }
    out
}

/// `obs` (on `spec`'s lattice, its window placed) cut to its window: the observation of
/// the model's own gel that the encoder reads.
fn windowed(obs: &Observation, spec: &LatticeSpec) -> Observation {
    Observation {
        coarse: cut_window(&obs.coarse, spec, obs.origin),
        pen: cut_window(&obs.pen, spec, obs.origin),
        origin: [0, 0],
        ..obs.clone()
    }
}

/// Rewrites the coarse channel of the sample `npy` and the coarse report of its `json` from
/// a coarse press just solved (`obs` of `coarse`, report `rc`, `seconds`), keeping the
/// reference channel and report.
fn refresh_coarse(
    npy: &Path,
    json: &Path,
    obs: &Observation,
    spec: &LatticeSpec,
    coarse: &Gel,
    rc: &SolveReport,
    seconds: f64,
) -> Result<(), String> {
    let (shape, data) = read_npy(npy)?;
    let n = spec.points();
    if shape != [3, spec.ny, spec.nx] || data.len() != 3 * n {
        return Err(format!(
            "{}: shape {shape:?}, expected [3, {}, {}]",
            npy.display(),
            spec.ny,
            spec.nx
        ));
    }
    let reference: Vec<f64> = data[2 * n..].iter().map(|&v| f64::from(v)).collect();
    let text = std::fs::read_to_string(json).map_err(|e| format!("{}: {e}", json.display()))?;
    let mut meta: SampleMeta =
        serde_json::from_str(&text).map_err(|e| format!("{}: {e}", json.display()))?;
    meta.coarse = SolveMeta {
        force: Some(coarse.force().into()),
        ..SolveMeta::new(rc, seconds)
    };
    write_npy(npy, &shape, &sample_array(obs, &reference))
        .map_err(|e| format!("{}: {e}", npy.display()))?;
    let mut text = serde_json::to_string_pretty(&meta).map_err(|e| e.to_string())?;
    text.push('\n');
    npy::write_atomic(json, text.as_bytes()).map_err(|e| format!("{}: {e}", json.display()))
}

/// Sample `index`'s gel parameters at grid spacing `dx`.
fn gel_params(config: &GenConfig, index: usize, dx: f64) -> GelParams {
    GelParams {
        dx,
        material: Material::FixedCorotated,
        ..config.sample_gel(index)
    }
}

/// One line per sample of this shard: index, family, whether held out, depth and slide
/// (mm), drawn exactly as [`generate`] draws them, without solving.
pub fn list(config: &GenConfig) -> Result<Vec<String>, String> {
    let mut meshes = MeshLibrary::new(&config.patterns);
    let mut lines = Vec::new();
    for index in config.shard_indices(&mut meshes)? {
        let p = config.press(index, &mut meshes)?;
        let held_out = HELD_OUT.contains(&p.family.as_str());
        if config.held_out_only && !held_out {
            continue;
        }
        let slide = p.params.slide.map_or(0.0, |s| s[0].hypot(s[1]));
        let gel = config.sample_gel(index);
        let mut line = format!(
            "{index} {} held_out={held_out} depth_mm={:.3} slide_mm={:.3} poisson={:.4} \
             friction={:.4}",
            p.family,
            p.params.depth * 1e3,
            slide * 1e3,
            gel.poisson,
            gel.friction
        );
        if let Some(f) = config.family_gel(index) {
            let mm = f.size.map(|v| v * 1e3);
            line.push_str(&format!(
                " gel_mm={:.1}x{:.1}x{:.2} indenter_scale={:.2}",
                mm[0], mm[1], mm[2], f.indenter_scale
            ));
        }
        lines.push(line);
    }
    Ok(lines)
}

/// Generates this shard's missing samples; `progress` gets one line per sample. Returns
/// a summary line.
pub fn generate(config: &GenConfig, mut progress: impl FnMut(&str)) -> Result<String, String> {
    std::fs::create_dir_all(&config.out).map_err(|e| format!("{}: {e}", config.out.display()))?;
    let spec = LatticeSpec::with_pitch(config.gel.size, config.pitch);
    let mut meshes = MeshLibrary::new(&config.patterns);
    if meshes.names().is_empty() {
        progress(&format!(
            "warning: no STL patterns in {}; mesh families skipped",
            config.patterns.display()
        ));
    }
    let g = &config.gel;
    let dataset = Dataset {
        format: "tacrom-rom-pairs-1".to_owned(),
        channels: ["coarse", "penetration", "reference"]
            .map(str::to_owned)
            .to_vec(),
        units: "m".to_owned(),
        size: g.size,
        young: g.young,
        poisson: g.poisson,
        density: g.density,
        friction: g.friction,
        material: "fixed_corotated".to_owned(),
        coarse_dx: config.coarse_dx,
        fine_dx: config.fine_dx,
        pitch: config.pitch,
        lattice: [spec.ny, spec.nx],
        seed: config.seed,
        held_out: HELD_OUT.iter().map(|s| s.to_string()).collect(),
        fine_max_iterations: config.fine_max_iterations,
        recipe: Some(tacrom::rom::Recipe {
            dx: config.coarse_dx,
            material: tacrom::config::material_name(Material::FixedCorotated).to_owned(),
            solver: config.coarse_solver.name().to_owned(),
            tolerance: SolverOptions::default().tolerance,
            max_tolerance: tacrom::rom::MAX_TOLERANCE,
        }),
        poisson_range: config.poisson_range,
        friction_range: config.friction_range,
        gel_family: config.gel_family,
    };
    let ds_path = config.out.join("dataset.json");
    match std::fs::read_to_string(&ds_path) {
        Ok(text) => {
            let existing: Dataset =
                serde_json::from_str(&text).map_err(|e| format!("{}: {e}", ds_path.display()))?;
            if existing != dataset {
                return Err(format!(
                    "{} holds a data set with other settings; use another --out",
                    ds_path.display()
                ));
            }
        }
        Err(_) => {
            let mut text = serde_json::to_string_pretty(&dataset).map_err(|e| e.to_string())?;
            text.push('\n');
            npy::write_atomic(&ds_path, text.as_bytes()).map_err(|e| e.to_string())?
        }
    }
    let options = SolverOptions {
        threads: config.threads,
        ..SolverOptions::default()
    };
    let fine_options = SolverOptions {
        max_iterations: config.fine_max_iterations,
        ..options
    };
    let new_gel = |index: usize, dx: f64, options: SolverOptions| {
        Gel::new(gel_params(config, index, dx), options).map_err(|e| e.to_string())
    };
    let indices = config.shard_indices(&mut meshes)?;
    let first = indices.first().copied().unwrap_or(0);
    let coarse_options = SolverOptions {
        solver: config.coarse_solver,
        ..options
    };
    let mut coarse = new_gel(first, config.coarse_dx, coarse_options)?;
    // A refresh keeps the references: no fine gel.
    let fine_gel = |index: usize| {
        (!config.refresh_coarse)
            .then(|| new_gel(index, config.fine_dx, fine_options))
            .transpose()
    };
    let mut fine = fine_gel(first)?;
    let (k, n) = config.shard;
    let (mut done, mut skipped) = (0usize, 0usize);
    let (mut t_coarse, mut t_fine) = (0.0, 0.0);
    let mut obs = Observation::default();
    let mut zmin = Vec::new();
    let bar = Progress::new(indices.len(), true);
    for index in indices {
        bar.advance(1);
        let stem = config.out.join(format!("sample-{index:06}"));
        let (npy, json) = (stem.with_extension("npy"), stem.with_extension("json"));
        let present = npy.is_file() && json.is_file();
        if present != config.refresh_coarse {
            skipped += 1;
            continue;
        }
        let press = config.press(index, &mut meshes)?;
        let held_out = HELD_OUT.contains(&press.family.as_str());
        if config.held_out_only && !held_out {
            continue;
        }
        bar.message(format!("sample {index}: {}", press.family));
        if *coarse.params() != gel_params(config, index, config.coarse_dx) {
            coarse = new_gel(index, config.coarse_dx, coarse_options)?;
            fine = fine_gel(index)?;
        }
        let last = press.poses.len() - 1;
        let placed = [press.placed(last)];
        let (rc, sc) = solve_press(&mut coarse, &press);
        // A family sample's gel has a lattice of its own; the sample is the window of the
        // model's lattice over the contact, as `Rom::serve` reads it.
        let mut family = config.family_gel(index);
        let gel_spec = match family {
            Some(f) => LatticeSpec {
                window: [spec.ny, spec.nx],
                ..LatticeSpec::with_pitch(f.simulated, config.pitch)
            },
            None => spec,
        };
        obs.update(&coarse, &placed, &gel_spec, &mut zmin);
        if let Some(f) = family.as_mut() {
            f.origin = obs.origin;
            obs = windowed(&obs, &gel_spec);
        }
        if config.refresh_coarse {
            refresh_coarse(&npy, &json, &obs, &spec, &coarse, &rc, sc)?;
            done += 1;
            t_coarse += sc;
            bar.suspend(|| progress(&format!("sample {index}: {} coarse {sc:.2}s", press.family)));
            continue;
        }
        let fine = fine.as_mut().ok_or("no fine gel")?;
        let (rf, sf) = solve_press(fine, &press);
        let mut reference = vec![0.0; gel_spec.points()];
        fine.surface_depth(&gel_spec.grid(), &mut reference);
        let mut pressure = pressure_array(&coarse, fine, &gel_spec.grid());
        if let Some(f) = family {
            reference = cut_window(&reference, &gel_spec, f.origin);
            let n = gel_spec.points();
            pressure = pressure
                .chunks(n)
                .flat_map(|p| cut_window(p, &gel_spec, f.origin))
                .collect();
        }
        let data = sample_array(&obs, &reference);
        write_npy(&npy, &[3, spec.ny, spec.nx], &data)
            .map_err(|e| format!("{}: {e}", npy.display()))?;
        let pressure_npy = pressure_path(&stem);
        write_npy(&pressure_npy, &[2, spec.ny, spec.nx], &pressure)
            .map_err(|e| format!("{}: {e}", pressure_npy.display()))?;
        let meta = SampleMeta {
            index,
            family: press.family.clone(),
            held_out,
            params: press.params,
            coarse: SolveMeta {
                force: Some(coarse.force().into()),
                ..SolveMeta::new(&rc, sc)
            },
            reference: SolveMeta {
                force: Some(fine.force().into()),
                ..SolveMeta::new(&rf, sf)
            },
            poisson: config.poisson_range.map(|_| coarse.params().poisson),
            friction: config.friction_range.map(|_| coarse.params().friction),
            gel: family,
        };
        let mut text = serde_json::to_string_pretty(&meta).map_err(|e| e.to_string())?;
        text.push('\n');
        npy::write_atomic(&json, text.as_bytes())
            .map_err(|e| format!("{}: {e}", json.display()))?;
        done += 1;
        t_coarse += sc;
        t_fine += sf;
        let line = format!(
            "sample {index}: {} coarse {:.2}s ({} it) reference {:.2}s ({} it{})",
            press.family,
            sc,
            rc.iterations,
            sf,
            rf.iterations,
            if rf.converged { "" } else { ", NOT converged" }
        );
        bar.suspend(|| progress(&line));
    }
    bar.finish();
    let per = |t: f64| if done > 0 { t / done as f64 } else { 0.0 };
    if config.refresh_coarse {
        return Ok(format!(
            "shard {k}/{n}: {done} samples' coarse channel refreshed, {skipped} not on disk; \
             mean coarse {:.3}s per sample (dx {:e} m, {} threads)",
            per(t_coarse),
            config.coarse_dx,
            config.threads
        ));
    }
    Ok(format!(
        "shard {k}/{n}: {done} samples written, {skipped} already present; mean coarse {:.3}s, \
         reference {:.3}s per sample (dx {:e} / {:e} m, {} threads)",
        per(t_coarse),
        per(t_fine),
        config.coarse_dx,
        config.fine_dx,
        config.threads
    ))
}
