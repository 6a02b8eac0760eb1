//! The reduced-order neural model (`physics="rom"`): a coarse MPM carries the mechanics; a
//! decoder run through ONNX Runtime restores the detail only a finer simulation resolves.
//!
//! # What the networks see and predict
//!
//! Everything lives on the model's *surface lattice* ([`features::LatticeSpec`]): points
//! `pitch` apart (0.3 mm for the shipped model) over the gel's top face. After the coarse
//! MPM has reached equilibrium:
//!
//! * the **encoder** sees the coarse depth `c` and the rigid penetration `p` of the
//!   indenters on a sub-lattice (every `encoder_stride`-th point, 1.2 mm) and gives the
//!   latent state `z` (64 numbers);
//! * the **decoder** is a field `g(z, x)`: at a surface point `x` it takes `z`, the
//!   normalised position and the local geometry, 5 x 5 windows of `c` and `p` around `x`
//!   (1.2 mm either side), and predicts the depth there, as the coarse depth plus a learnt
//!   correction. Conditioning on the local shape of the indenter is what lets the detail
//!   generalise to objects it never saw; `z` carries the global state of the press.
//!
//! # Latent refinement: the reduced energy (the paper's Eq. 4)
//!
//! `z` from the encoder is refined by L-BFGS (at most 10 iterations) on the reduced energy
//! of the decoded surface `d(z)` (model units, mm), divided by `s^2`, the square of the
//! press's own depth `s` (the deepest indenter point's penetration, at least 1 um), so that
//! the energy, its gradient and the manifest's gradient tolerance mean the same for a
//! 50 um and a 1 mm press:
//!
//! ```text
//! E(z) s^2 = w_in / (2 |A|) sum_{i in A} (d_i(z) - c_i)^2               inertial term
//!          + w_el / (2 |P|) sum_{(i,j) in P} ((d_j(z) - d_i(z)) / h)^2    elastic potential
//!          + w_c  / (2 |C|) sum_{k in C} max(0, p_k - d_k(z))^2           non-penetration
//!          + w_c  / (2 |A+C|) sum_{k in A+C} max(0, d_k(z) - s)^2         deepest point
//! ```
//!
//! * inertial term: a quasi-static step from a predicted state (the `x_pred` of the
//!   incremental-potential form `|x - x_pred|^2_M / 2h^2`), on the sub-lattice `A` (stride
//!   `refinement.stride`) of the deformable region. The prediction `c` is the coarse
//!   solver's depth (manifest `refinement.anchor = "coarse"`) or the encoder's decoded
//!   prediction `d(z0)` (`"encoder"`: the network predicts, the potential corrects);
//! * elastic potential: the membrane energy of the surface, the squared out-of-plane row of
//!   its deformation gradient (depth slopes over `h`, one stride, between neighbours `P`);
//! * contact: a penalty on the surface passing into the indenters, on the points `C`
//!   (stride `refinement.contact_stride`) where the indenters pierce the undeformed gel,
//!   and on the surface sinking below the deepest indenter point anywhere. Both are
//!   violations of the contact problem the indenters pose, which the decoder makes and
//!   the depth rule then removes pointwise (measured: `docs/rom.md`, "Reduced-order model
//!   on held-out families").
//!
//! The gradient is exact: `dE/dz = J^T dE/dd`, with `J = dd/dz` from the exported graph
//! `decoder_jacobian.onnx` (an explicit backward pass of the decoder, checked against
//! autograd in `training/tests`). The weights are the manifest's (`refinement`).
//!
//! # Decoding and the image
//!
//! The decoder is then evaluated densely on the lattice points of the deformable region
//! (the manifest's `files.decoder`: for `rom-linear`, a copy of the float decoder with its
//! two hidden layers in 8-bit integers, `training/tacrom_rom/quantize.py`):
//! where the coarse depth exceeds `region.eps_mm` or the indenters pierce the gel, grown by
//! `region.grow` points (elsewhere the surface is the coarse one). The lattice is the
//! field's resolution, set from the reference simulation's (finer detail is not in the
//! training data); the image's pixels interpolate it by monotone cubic interpolation
//! (continuous slopes, so a pixel finer than the lattice shows no lattice, and no
//! overshoot), and the contact constraint
//! `depth >= p` is applied at every pixel, so the indenter's own sharp edges come through at
//! full image resolution. Depths are clamped to `[0, T]`.
//!
//! # Pressure head
//!
//! A model may carry a contact pressure head (manifest `files.pressure` and `pressure`):
//! a field on the decoder's inputs, `z` and each region point's query, followed by a
//! `patch x patch` window of the coarse gel's contact load ([`features::load_window`]),
//! that predicts the point's share of the normal contact load ([`PRESSURE_UNITS`]), trained
//! against the reference's pressure (`training/tacrom_rom/pressure.py`). It runs after the
//! dense decoding, on the same rows, and only where the pressure image is wanted (or, for
//! a model without a volume factor, the force): [`RomOptions`]. Its field gives `rom`'s
//! pressure image ([`Rom::render_pressure`]); the force is the volume factor's where the
//! model has one ([`Rom::force_factor_on`]).
//!
//! # Model directory
//!
//! `manifest.json` (format `tacrom-rom-1`: gel size and material, lattice, latent size,
//! ONNX files with their named inputs and outputs and shapes, refinement settings, training
//! command, data and validation metrics) and the three ONNX files (four with a pressure
//! head). [`Rom::load`] checks all
//! of it and says what is wrong. Ablations: [`RomOptions::refine`] switches the refinement
//! off ("w/o physics"); latent 16 and "no multi-scale loss" are models of their own
//! (`models/rom-latent16`, `models/rom-no-multiscale`).

pub mod features;
pub mod lbfgs;
pub mod runtime;

use std::path::{Path, PathBuf};
use std::time::Instant;

use ort::value::TensorRef;

use crate::geometry::{PixelGrid, Placed};
use crate::mpm::Gel;
use features::{load_window, query_features, Conditioning, LatticeSpec, Observation};
use lbfgs::{LbfgsOptions, LbfgsReport};
use runtime::{load_graph, Graph};

/// The gel family's thicknesses (m; [`Manifest::check_gel`]).
pub const THICKNESS_RANGE: [f64; 2] = [1e-3, 6e-3];

/// The gel family's lateral sizes (m, each side; [`Manifest::check_gel`]).
pub const LATERAL_RANGE: [f64; 2] = [12e-3, 40e-3];

/// Range of the decoded-over-coarse displaced volume within which [`Rom::force_factor`]
/// uses it: the decoder corrects the coarse surface, it does not replace it.
pub const VOLUME_RATIO: [f64; 2] = [0.25, 4.0];

/// The factor of `rom`'s force from the decoded surface's displaced volume (manifest
/// `force`): `volume_factor`, or, for a model of several Poisson's ratios, its `by_poisson`
/// table interpolated linearly in Poisson's ratio and held beyond its ends (the linear
/// coarse gel's own constant rises with Poisson's ratio; measured: `docs/rom.md`,
/// "Against the held-out families").
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeFactor {
    /// The factor of the training gel (of all presses, for a table).
    pub factor: f64,
    /// `(poisson, factor)` in increasing Poisson's ratio; empty for one factor.
    pub by_poisson: Vec<(f64, f64)>,
}

impl VolumeFactor {
    const RANGE: std::ops::RangeInclusive<f64> = 0.5..=2.0;

    fn new(doc: document::Force) -> Result<Self, String> {
        let check = |name: &str, k: f64| {
            if Self::RANGE.contains(&k) {
                Ok(k)
            } else {
                Err(format!(
                    "'force.{name}' is {k}, expected a factor in [0.5, 2]"
                ))
            }
        };
        let factor = check("volume_factor", doc.volume_factor)?;
        let mut by_poisson = Vec::with_capacity(doc.by_poisson.len());
        for &[nu, k] in &doc.by_poisson {
            check("by_poisson", k)?;
            let last = by_poisson.last().map_or(-1.0, |&(n, _)| n);
            if !(nu > last && nu < 0.5) {
                return Err(format!(
                    "'force.by_poisson' has Poisson's ratio {nu} after {last}, expected \
                     increasing ratios below 0.5"
                ));
            }
            by_poisson.push((nu, k));
        }
        Ok(Self { factor, by_poisson })
    }

    /// The factor for a gel of Poisson's ratio `poisson`.
    pub fn at(&self, poisson: f64) -> f64 {
        let t = &self.by_poisson;
        match t.iter().position(|&(nu, _)| nu >= poisson) {
            None if t.is_empty() => self.factor,
            None => t[t.len() - 1].1,
            Some(0) => t[0].1,
            Some(i) => {
                let ((n0, k0), (n1, k1)) = (t[i - 1], t[i]);
                k0 + (k1 - k0) * (poisson - n0) / (n1 - n0)
            }
        }
    }
}

/// Format tag of the manifests this build reads.
pub const FORMAT: &str = "tacrom-rom-1";
/// Name of the shipped model's directory under `models/` for the relaxation's coarse
/// solve (`solver="relaxation"`; the default before the linear gel's model became it).
pub const DEFAULT_MODEL: &str = "rom-default";
/// Name of the shipped model for the linear solver's coarse solve with the paper's decoder
/// widths [512, 256, 128]: `physics="rom"`'s default on gels thinner than
/// [`NARROW_FROM_THICKNESS`] ([`crate::mpm::Role::ShippedRom`]).
pub const LINEAR_MODEL: &str = "rom-linear";
/// The linear solver's model with [`LINEAR_MODEL`]'s encoder and a decoder of widths [128,
/// 64, 32]: on its own gel more accurate in depth and structure on the full profile at a
/// third of the cost per decoded point, so `physics="rom"`'s default on gels at least
/// [`NARROW_FROM_THICKNESS`] thick; a thinner gel shows the models its presses scaled up,
/// which the wider decoder carries better (`docs/rom.md`, "Which decoder by thickness").
pub const LINEAR_NARROW_MODEL: &str = "rom-linear-narrow";
/// The thinnest gel (m) whose default model on the linear gel is [`LINEAR_NARROW_MODEL`];
/// thinner gels get [`LINEAR_MODEL`]. Measured (`tacrom probe decoder_thickness`): the
/// narrow decoder's summed depth error over three sphere presses is 1.36 to 1.64 times the
/// wide one's on gels of 1 to 2 mm, 1.07 at 3 mm, 0.97 at 3.5 mm, 0.95 at 4 mm and 0.82 at
/// 6 mm.
pub const NARROW_FROM_THICKNESS: f64 = 3.5e-3;
/// The linear solver's model trained on presses over the whole gel family beside the
/// default gel's: closer over the family and at materials away from the default gel's,
/// less close on spheres near it, so not the default (`docs/rom.md`, "One model for the
/// family"). Named, it runs on the linear gel as the default does.
pub const FAMILY_MODEL: &str = "rom-family";

/// The shipped model (its directory's name under `models/`) that is `physics="rom"`'s
/// default for a coarse solve of the solver named `solver` on a gel `thickness` (m) thick.
pub fn shipped_model(solver: &str, thickness: f64) -> &'static str {
    match solver {
        "linear" if thickness >= NARROW_FROM_THICKNESS * (1.0 - 1e-9) => LINEAR_NARROW_MODEL,
        "linear" => LINEAR_MODEL,
        _ => DEFAULT_MODEL,
    }
}

/// Errors of the reduced-order model.
#[derive(Debug, thiserror::Error)]
pub enum RomError {
    /// A file of the model directory is missing.
    #[error("model file missing: {}", .0.display())]
    MissingFile(PathBuf),
    /// The manifest is unreadable or inconsistent.
    #[error("bad model manifest {}: {message}", path.display())]
    Manifest {
        /// The manifest.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An ONNX file does not load or has other inputs or outputs than the manifest says.
    #[error("bad ONNX graph {}: {message}", path.display())]
    Graph {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// ONNX Runtime could not be found or started.
    #[error("{0}")]
    Runtime(String),
    /// The sensor's gel is not the one the model was trained for.
    #[error("the model {} was trained for {expected}, but the sensor has {actual}", model.display())]
    Mismatch {
        /// The model directory.
        model: PathBuf,
        /// The sensor attribute whose value the model does not serve (`size`, `poisson`,
        /// `friction`, `dx`, `material`, `solver`, `tolerance`).
        attribute: &'static str,
        /// What the manifest says.
        expected: String,
        /// What the sensor has.
        actual: String,
    },
    /// Running a graph failed.
    #[error("ONNX Runtime failed running {graph}: {message}")]
    Run {
        /// Which graph.
        graph: &'static str,
        /// The message.
        message: String,
    },
}

/// Refinement settings (manifest `refinement`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Refinement {
    /// Whether the model refines `z` (an ablation may switch it off).
    pub enabled: bool,
    /// L-BFGS settings.
    pub lbfgs: LbfgsOptions,
    /// Sub-lattice stride of the inertial and elastic terms.
    pub stride: usize,
    /// Sub-lattice stride of the contact term.
    pub contact_stride: usize,
    /// Weight of the inertial term.
    pub w_inertia: f64,
    /// Weight of the elastic term.
    pub w_elastic: f64,
    /// Weight of the contact term.
    pub w_contact: f64,
    /// What the inertial term pulls towards: the coarse depth (`false`) or the encoder's
    /// prediction `d(z0)` (`true`, manifest `anchor: "encoder"`).
    pub anchor_encoder: bool,
}

/// The gel a model was trained for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GelSpec {
    /// `[Lx, Ly, T]` (m).
    pub size: [f64; 3],
    /// Young's modulus (Pa).
    pub young: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Friction coefficient.
    pub friction: f64,
    /// Coarse MPM grid spacing the model expects (m).
    pub coarse_dx: f64,
}

/// A model directory's manifest, checked.
#[derive(Clone, Debug)]
pub struct Manifest {
    /// The directory.
    pub dir: PathBuf,
    /// The gel and coarse solver it was trained for.
    pub gel: GelSpec,
    /// Reference grid spacing of the training data (m).
    pub reference_dx: f64,
    /// Surface lattice and features.
    pub lattice: LatticeSpec,
    /// Latent size.
    pub latent: usize,
    /// Deformable region: coarse depth threshold (model units) and growth (points).
    pub region: (f64, usize),
    /// Refinement settings.
    pub refinement: Refinement,
    /// `(path, inputs, outputs)` of encoder, decoder, Jacobian.
    pub files: [GraphFile; 3],
    /// The contact pressure head (manifest `files.pressure` and `pressure.units`; `None`:
    /// `rom`'s force and pressure are the coarse gel's, scaled by
    /// [`Manifest::force_volume_factor`]); see [`Rom::lattice_pressure`].
    pub pressure: Option<GraphFile>,
    /// The coarse solve the model was trained on and accepts.
    pub recipe: Recipe,
    /// The gel materials a conditioned model serves (`None`: the gel's only).
    pub conditioning: Option<Conditioning>,
    /// The gel materials a model was validated on and serves where it has no input for
    /// them (manifest `materials`, with the evaluation that measured it; `None`: the gel's
    /// only): every material of a model without material inputs, the friction of one
    /// conditioned on Poisson's ratio alone (its friction range of one value).
    pub materials: Option<Conditioning>,
    /// The factor of the force from the decoded surface's displaced volume (manifest
    /// `force`; `None`: `rom` reports the coarse gel's force).
    pub force_volume_factor: Option<VolumeFactor>,
    /// The whole document (training, data, validation records).
    pub json: serde_json::Value,
}

/// `(path, inputs, outputs)` of one ONNX graph of a model, as its manifest lists them.
pub type GraphFile = (PathBuf, Vec<(String, Vec<i64>)>, Vec<(String, Vec<i64>)>);

/// What a pressure head's output at a lattice point is (manifest `pressure.units`, the
/// one value this build reads): the point's load (its pressure times its area) over the
/// coarse gel's normal force shared equally among the deformable region's points (of order
/// 1), so that the head corrects the coarse load, which carries the gel's material.
pub const PRESSURE_UNITS: &str = "coarse_force";

/// `manifest.json` as written by the training's export, read with serde; [`Manifest::load`]
/// checks it and turns it into a [`Manifest`].
mod document {
    use std::collections::BTreeMap;

    use serde::Deserialize;

    #[derive(Deserialize)]
    pub(super) struct Document {
        pub format: String,
        pub gel: Gel,
        pub coarse_dx: f64,
        pub reference_dx: f64,
        pub lattice: Lattice,
        pub latent: usize,
        pub encoder_input: usize,
        pub query_features: usize,
        pub region: Region,
        pub refinement: Refinement,
        pub files: BTreeMap<String, File>,
        /// The coarse solve the training data came from (absent in older manifests).
        #[serde(default)]
        pub recipe: Option<super::Recipe>,
        /// The materials a conditioned model serves (absent: the gel's only).
        #[serde(default)]
        pub conditioning: Option<super::Conditioning>,
        /// The materials a model without material inputs was validated on.
        #[serde(default)]
        pub materials: Option<super::Conditioning>,
        /// The force from the decoded surface's displaced volume.
        #[serde(default)]
        pub force: Option<Force>,
        /// The pressure head's record (with `files.pressure`).
        #[serde(default)]
        pub pressure: Option<Pressure>,
    }

    #[derive(Deserialize)]
    pub(super) struct Pressure {
        pub units: String,
    }

    #[derive(Deserialize)]
    pub(super) struct Force {
        pub volume_factor: f64,
        /// `[[poisson, factor], ...]` for a model of several Poisson's ratios.
        #[serde(default)]
        pub by_poisson: Vec<[f64; 2]>,
    }

    #[derive(Deserialize)]
    pub(super) struct Gel {
        pub size: [f64; 3],
        pub young: f64,
        pub poisson: f64,
        pub friction: f64,
    }

    #[derive(Deserialize)]
    pub(super) struct Lattice {
        pub nx: usize,
        pub ny: usize,
        pub encoder_stride: usize,
        pub patch: usize,
        pub patch_step: usize,
        pub depth_scale: f64,
    }

    #[derive(Deserialize)]
    pub(super) struct Region {
        pub eps_mm: f64,
        pub grow: usize,
    }

    #[derive(Deserialize)]
    pub(super) struct Refinement {
        #[serde(default = "yes")]
        pub enabled: bool,
        pub max_iterations: usize,
        pub tolerance: f64,
        pub stride: usize,
        pub contact_stride: usize,
        pub w_inertia: f64,
        pub w_elastic: f64,
        pub w_contact: f64,
        #[serde(default)]
        pub anchor: Option<String>,
    }

    fn yes() -> bool {
        true
    }

    #[derive(Deserialize)]
    pub(super) struct File {
        pub path: String,
        pub inputs: BTreeMap<String, Vec<i64>>,
        pub outputs: BTreeMap<String, Vec<i64>>,
    }
}

/// The loosest run-time coarse tolerance a model accepts unless its manifest says
/// otherwise: the data generator records it in `dataset.json` and the exporter copies it.
pub const MAX_TOLERANCE: f64 = 1e-2;

/// The coarse solve a model's training data came from, and which coarse solves the model
/// accepts at run time (manifest `recipe`). The decoder reads the coarse solution as its
/// input, so a sensor whose coarse solve differs feeds it inputs it never saw.
#[derive(Clone, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct Recipe {
    /// Coarse MPM grid spacing (m).
    pub dx: f64,
    /// Constitutive model (`material` attribute value).
    pub material: String,
    /// Coarse solver ([`crate::mpm::Solver::name`]): a model trained on one solver's coarse
    /// solutions refuses another's.
    pub solver: String,
    /// Convergence tolerance of the coarse solves in the training data.
    pub tolerance: f64,
    /// Loosest tolerance of the run-time coarse solve the model accepts; the sensor's
    /// default for `physics="rom"`.
    pub max_tolerance: f64,
}

impl Manifest {
    /// Reads and checks `dir/manifest.json`.
    pub fn load(dir: &Path) -> Result<Manifest, RomError> {
        let path = dir.join("manifest.json");
        if !dir.is_dir() {
            return Err(RomError::MissingFile(dir.to_owned()));
        }
        let text =
            std::fs::read_to_string(&path).map_err(|_| RomError::MissingFile(path.clone()))?;
        let bad = |message: String| RomError::Manifest {
            path: path.clone(),
            message,
        };
        let json: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| bad(format!("invalid JSON: {e}")))?;
        match json.get("format").and_then(serde_json::Value::as_str) {
            Some(FORMAT) => {}
            other => {
                return Err(bad(format!(
                    "format {other:?}, this build reads \"{FORMAT}\""
                )))
            }
        }
        let doc: document::Document =
            serde_json::from_value(json.clone()).map_err(|e| bad(e.to_string()))?;
        debug_assert_eq!(doc.format, FORMAT);
        let positive = |what: &str, x: f64| {
            (x.is_finite() && x > 0.0)
                .then_some(x)
                .ok_or_else(|| bad(format!("'{what}' must be a positive number")))
        };
        let count = |what: &str, n: usize| {
            (n >= 1)
                .then_some(n)
                .ok_or_else(|| bad(format!("'{what}' must be a positive integer")))
        };
        let mut size = [0.0; 3];
        for (s, &v) in size.iter_mut().zip(&doc.gel.size) {
            *s = positive("gel.size", v)?;
        }
        let gel = GelSpec {
            size,
            young: positive("gel.young", doc.gel.young)?,
            poisson: doc.gel.poisson,
            friction: doc.gel.friction,
            coarse_dx: positive("coarse_dx", doc.coarse_dx)?,
        };
        let l = &doc.lattice;
        let lattice = LatticeSpec {
            size,
            nx: count("lattice.nx", l.nx)?,
            ny: count("lattice.ny", l.ny)?,
            encoder_stride: count("lattice.encoder_stride", l.encoder_stride)?,
            patch: count("lattice.patch", l.patch)?,
            patch_step: count("lattice.patch_step", l.patch_step)?,
            depth_scale: positive("lattice.depth_scale", l.depth_scale)?,
            window: [count("lattice.ny", l.ny)?, count("lattice.nx", l.nx)?],
            material_inputs: if doc.conditioning.is_some() {
                Conditioning::INPUTS
            } else {
                0
            },
        };
        for (key, ranges) in [
            ("conditioning", &doc.conditioning),
            ("materials", &doc.materials),
        ] {
            let Some(c) = ranges else { continue };
            for (what, [lo, hi]) in [("poisson", c.poisson), ("friction", c.friction)] {
                if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                    return Err(bad(format!(
                        "'{key}.{what}' must be a range [lo, hi] with lo <= hi, got [{lo}, {hi}]"
                    )));
                }
            }
        }
        if lattice.patch % 2 == 0 {
            return Err(bad("'lattice.patch' must be odd".into()));
        }
        let latent = count("latent", doc.latent)?;
        let r = latent as i64;
        let e = lattice.encoder_len() as i64;
        let f = lattice.query_len() as i64;
        if doc.encoder_input as i64 != e || doc.query_features as i64 != f {
            return Err(bad(format!(
                "'encoder_input' / 'query_features' disagree with the lattice ({e} / {f})"
            )));
        }
        let rf = &doc.refinement;
        let refinement = Refinement {
            enabled: rf.enabled,
            lbfgs: LbfgsOptions {
                max_iterations: count("refinement.max_iterations", rf.max_iterations)?.min(10),
                tolerance: rf.tolerance,
                ..LbfgsOptions::default()
            },
            stride: count("refinement.stride", rf.stride)?,
            contact_stride: count("refinement.contact_stride", rf.contact_stride)?,
            w_inertia: rf.w_inertia,
            w_elastic: rf.w_elastic,
            w_contact: rf.w_contact,
            anchor_encoder: match rf.anchor.as_deref() {
                None | Some("coarse") => false,
                Some("encoder") => true,
                Some(other) => {
                    return Err(bad(format!(
                        "'refinement.anchor' is \"{other}\", expected \"coarse\" or \"encoder\""
                    )))
                }
            },
        };
        let region = (doc.region.eps_mm, doc.region.grow);
        // Expected graph signatures, from the lattice and the latent size; the manifest's
        // own listing must agree.
        let want: [(&str, Vec<(&str, Vec<i64>)>, Vec<(&str, Vec<i64>)>); 4] = [
            (
                "encoder",
                vec![("observation", vec![1, e])],
                vec![("z", vec![1, r])],
            ),
            (
                "decoder",
                vec![("z", vec![1, r]), ("query", vec![-1, f])],
                vec![("depth", vec![-1, 1])],
            ),
            (
                "jacobian",
                vec![("z", vec![1, r]), ("query", vec![-1, f])],
                vec![("depth", vec![-1, 1]), ("jacobian", vec![-1, r])],
            ),
            (
                "pressure",
                vec![
                    ("z", vec![1, r]),
                    (
                        "query",
                        vec![-1, f + (lattice.patch * lattice.patch) as i64],
                    ),
                ],
                vec![("pressure", vec![-1, 1])],
            ),
        ];
        let mut files = Vec::new();
        let mut pressure = None;
        for (key, ins, outs) in want {
            let fj = match doc.files.get(key) {
                Some(fj) => fj,
                // The pressure head is optional.
                None if key == "pressure" => continue,
                None => return Err(bad(format!("missing 'files.{key}'"))),
            };
            for (section, listed, wanted) in [
                ("inputs", &fj.inputs, &ins),
                ("outputs", &fj.outputs, &outs),
            ] {
                for (name, shape) in wanted {
                    let got = listed.get(*name);
                    if got != Some(shape) {
                        return Err(bad(format!(
                            "'files.{key}.{section}.{name}' is {got:?}, expected {shape:?} for \
                             latent {latent} and the lattice"
                        )));
                    }
                }
            }
            let own =
                |l: Vec<(&str, Vec<i64>)>| l.into_iter().map(|(n, s)| (n.to_owned(), s)).collect();
            let graph = (dir.join(&fj.path), own(ins), own(outs));
            if key == "pressure" {
                let units = doc.pressure.as_ref().map(|p| p.units.as_str());
                if units != Some(PRESSURE_UNITS) {
                    return Err(bad(format!(
                        "'pressure.units' is {units:?}, expected \"{PRESSURE_UNITS}\" with \
                         'files.pressure'"
                    )));
                }
                pressure = Some(graph);
            } else {
                files.push(graph);
            }
        }
        let files: [_; 3] = files.try_into().expect("three graphs");
        let recipe = doc.recipe.ok_or_else(|| {
            bad("missing 'recipe' (the coarse solve the model was trained on)".into())
        })?;
        if (recipe.dx - gel.coarse_dx).abs() > 1e-12 {
            return Err(bad(format!(
                "'recipe.dx' {} disagrees with 'coarse_dx' {}",
                recipe.dx, gel.coarse_dx
            )));
        }
        Ok(Manifest {
            dir: dir.to_owned(),
            gel,
            reference_dx: positive("reference_dx", doc.reference_dx)?,
            lattice,
            latent,
            region,
            refinement,
            recipe,
            conditioning: doc.conditioning,
            materials: doc.materials,
            force_volume_factor: doc.force.map(VolumeFactor::new).transpose().map_err(bad)?,
            files,
            pressure,
            json,
        })
    }

    /// Checks that a sensor's coarse solve is the one the model was trained on: grid
    /// spacing, material and solver equal to the recipe's, tolerance at most its
    /// `max_tolerance`. Errors name the attribute, the sensor's value and the model's.
    ///
    /// `scale`: the sensor's gel over the model's ([`Manifest::check_gel`]); the grid
    /// spacing is the recipe's scaled by it.
    pub fn check_recipe(
        &self,
        dx: f64,
        scale: f64,
        material: &str,
        solver: &str,
        tolerance: f64,
    ) -> Result<(), RomError> {
        let r = &self.recipe;
        let recipe_dx = r.dx * scale;
        let mismatch = |attribute, expected: String, actual: String| RomError::Mismatch {
            model: self.dir.clone(),
            attribute,
            expected,
            actual,
        };
        if (dx - recipe_dx).abs() > 1e-6 * recipe_dx {
            return Err(mismatch(
                "dx",
                format!(
                    "the coarse grid dx = {} m",
                    crate::attributes::number(recipe_dx)
                ),
                format!("dx = {dx} m"),
            ));
        }
        if material != r.material {
            return Err(mismatch(
                "material",
                format!("material = {}", r.material),
                format!("material = {material}"),
            ));
        }
        if solver != r.solver {
            return Err(mismatch(
                "solver",
                format!("coarse solutions of the \"{}\" solver", r.solver),
                format!("the \"{solver}\" solver"),
            ));
        }
        if tolerance > r.max_tolerance * (1.0 + 1e-9) {
            return Err(mismatch(
                "tolerance",
                format!("a coarse solve tolerance of at most {:e}", r.max_tolerance),
                format!("tolerance = {tolerance:e}"),
            ));
        }
        Ok(())
    }

    /// Checks that a sensor's gel is one the model serves (relative tolerance 1e-6): the
    /// size it was trained for; Poisson's ratio and friction within the ranges of a
    /// conditioned model or those a model was validated on (manifest `conditioning`,
    /// `materials`), else the ones it was trained for; any Young's modulus. The
    /// gel's equilibrium under imposed indenter poses is homogeneous of degree one in the
    /// elastic moduli (the contact penalty and the solver's tolerances scale with them),
    /// so the coarse depth the decoder reads does not depend on Young's modulus (bit for
    /// bit: `depth_does_not_depend_on_young_modulus_and_force_scales_with_it`) and the
    /// forces scale with it; the density does not change the equilibrium either.
    ///
    /// The size may be any of the gel family's ([`THICKNESS_RANGE`], [`LATERAL_RANGE`]),
    /// or the model's shape at a thickness within [`THICKNESS_RANGE`] (its own size
    /// always). A gel's equilibrium under indenters scaled with it is the same scaled, to
    /// rounding, on a grid scaled with it (elasticity has no length of its own, and the
    /// solver's contact stiffness, tolerances and depth rule are set in the grid's and the
    /// gel's units: `a_scaled_press_is_the_press_scaled`), so the model reads a gel in its
    /// own units, in proportion to the thickness, and through a window of its own lattice
    /// over the contact where the gel's lateral size differs ([`Rom::serve`]). Returns the
    /// scale: the sensor's thickness over the model's.
    pub fn check_gel(&self, size: [f64; 3], poisson: f64, friction: f64) -> Result<f64, RomError> {
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * a.abs().max(b.abs()).max(1e-12);
        let g = &self.gel;
        let mismatch = |attribute, what: &str, e: String, a: String| RomError::Mismatch {
            model: self.dir.clone(),
            attribute,
            expected: format!("{what} {e}"),
            actual: format!("{what} {a}"),
        };
        let scale = size[2] / g.size[2];
        let within = |[lo, hi]: [f64; 2], v: f64| v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9);
        let own = (0..3).all(|k| close(size[k], g.size[k]));
        let shape = (0..2).all(|k| close(size[k], g.size[k] * scale));
        let family = (0..2).all(|k| within(LATERAL_RANGE, size[k]));
        if !(own || within(THICKNESS_RANGE, size[2]) && (shape || family)) {
            let [lx, ly, t] = g.size;
            return Err(mismatch(
                "size",
                "gel size",
                format!(
                    "{} to {} m across and {} to {} m thick (the gel family), or {:?} m in \
                     shape ({} x {} thicknesses across) at a thickness in that range",
                    LATERAL_RANGE[0],
                    LATERAL_RANGE[1],
                    THICKNESS_RANGE[0],
                    THICKNESS_RANGE[1],
                    g.size,
                    lx / t,
                    ly / t,
                ),
                format!("{size:?} m"),
            ));
        }
        for (attribute, what, value, pick, trained) in [
            (
                "poisson",
                "Poisson's ratio",
                poisson,
                (|c: &Conditioning| c.poisson) as fn(&Conditioning) -> [f64; 2],
                g.poisson,
            ),
            (
                "friction",
                "friction",
                friction,
                |c: &Conditioning| c.friction,
                g.friction,
            ),
        ] {
            // A range the model reads (its input), else the one it was validated on, else
            // the value it was trained for.
            let input = self
                .conditioning
                .as_ref()
                .map(pick)
                .filter(|[lo, hi]| hi > lo);
            match input.or(self.materials.as_ref().map(pick)) {
                Some([lo, hi]) => {
                    if !(value >= lo - 1e-9 && value <= hi + 1e-9) {
                        return Err(mismatch(
                            attribute,
                            what,
                            format!("in [{lo}, {hi}]"),
                            format!("{value}"),
                        ));
                    }
                }
                None => {
                    let trained = self.conditioning.as_ref().map_or(trained, |c| pick(c)[0]);
                    if !close(value, trained) {
                        return Err(mismatch(
                            attribute,
                            what,
                            format!("{trained}"),
                            format!("{value}"),
                        ));
                    }
                }
            }
        }
        Ok(scale)
    }
}

/// Run-time options (the benchmark's ablations).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RomOptions {
    /// Overrides the manifest's `refinement.enabled` (`Some(false)`: "w/o physics").
    pub refine: Option<bool>,
    /// ONNX Runtime intra-op threads (default 1).
    pub threads: usize,
    /// Whether the pressure image is wanted (a sensor output): the manifest's pressure
    /// head is loaded and run for it.
    pub pressure: bool,
    /// Whether the force is wanted (a sensor output or the coupling): the pressure head is
    /// loaded and run for it too where the manifest has no `force` factor (the head's
    /// force is then the reported one; see [`Rom::force_factor_on`]).
    pub force: bool,
}

/// What one inference did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RomReport {
    /// The refinement's L-BFGS report (`None` when off or nothing to refine).
    pub refinement: Option<LbfgsReport>,
    /// Lattice points decoded.
    pub decoded: usize,
    /// Energy points of the refinement.
    pub energy_points: usize,
    /// Wall time: observation and encoder (s).
    pub encode_s: f64,
    /// Wall time: refinement (s).
    pub refine_s: f64,
    /// Wall time: dense decoding and image (s).
    pub decode_s: f64,
    /// How far the decoded surface sank below the deepest indenter point before the
    /// depth rule bounded it (m; 0 when it did not).
    pub bound_excess: f64,
    /// How far the decoded surface lay above the indenters' surface (into them) before the
    /// depth rule raised it, at its worst lattice point (m; 0 when nowhere).
    pub penetration_excess: f64,
}

/// One point of the reduced energy (model units).
#[derive(Clone, Copy, Debug, Default)]
struct Term {
    /// Weight of the inertial term.
    inertia: f64,
    /// What the inertial term pulls towards.
    anchor: f64,
    /// Weight of the non-penetration term.
    contact: f64,
    /// Rigid penetration.
    pen: f64,
}

/// Points and weights of the reduced energy.
#[derive(Clone, Debug, Default)]
struct EnergySet {
    /// Query features, `points x F`.
    query: Vec<f32>,
    /// Per point: the inertial and contact terms.
    terms: Vec<Term>,
    /// Elastic pairs (indices into the points) and their weight / h^2.
    pairs: Vec<(usize, usize)>,
    pair_weight: f64,
    /// The deepest indenter point's penetration (model units) and the weight of the bound
    /// `d <= reach` per point.
    reach: f64,
    reach_weight: f64,
    /// `1 / s^2`, with `s` the press's reach: the energy in units of the press.
    scale: f64,
}

/// A loaded model: manifest and ONNX sessions, with reusable buffers. One per sensor
/// state (sessions run with `&mut`).
#[derive(Debug)]
pub struct Rom {
    manifest: Manifest,
    options: RomOptions,
    encoder: Graph,
    decoder: Graph,
    /// The Jacobian graph, loaded only where the latent refinement runs.
    jacobian: Option<Graph>,
    /// The pressure head, loaded only where the model has one and the force or the
    /// pressure is wanted ([`RomOptions::pressure`]).
    pressure: Option<Graph>,
    /// Its output on the lattice after the last inference ([`PRESSURE_UNITS`], at least 0;
    /// 0 outside the deformable region).
    lattice_pressure: Vec<f64>,
    obs: Observation,
    zmin: Vec<f64>,
    enc_in: Vec<f32>,
    query: Vec<f32>,
    /// The decoded lattice points, in the order of the query rows, and their depths
    /// (model units), kept between frames.
    points: Vec<usize>,
    decoded: Vec<f32>,
    region: Vec<bool>,
    /// [`features::region`]'s buffer.
    region_steps: Vec<usize>,
    lattice_depth: Vec<f64>,
    z: Vec<f32>,
    /// The image's interpolation buffers, kept between frames.
    scratch: RenderScratch,
}

/// [`render_lattice`]'s buffers: each image column's lattice cell and position in it, the
/// lattice rows interpolated along x (`ny` rows of the image's width) and which of them
/// this frame has filled, one lattice row's slopes, and the slopes down the lattice at
/// the two rows of the image row's lattice cell (one per image column).
#[derive(Debug, Default)]
struct RenderScratch {
    cols: Vec<(usize, f64)>,
    rows: Vec<f64>,
    filled: Vec<bool>,
    line_slopes: Vec<f64>,
    column_slopes: Vec<[f64; 2]>,
}

/// The directory of the shipped `models/rom-default` (the relaxation's model, [`DEFAULT_MODEL`];
/// `physics="rom"`'s default is [`LINEAR_MODEL`] since), found relative to the plugin
/// library (or this crate's source tree): beside the library, in the Python package's
/// `_lib`, or at the root of the checkout that built it.
pub fn default_model_dir() -> Option<PathBuf> {
    shipped_model_dir(DEFAULT_MODEL)
}

/// The directory of the shipped model `name` (see [`default_model_dir`]).
pub fn shipped_model_dir(name: &str) -> Option<PathBuf> {
    crate::shipped_dir("models", name, "manifest.json")
}

impl Rom {
    /// Loads the model in `dir`: manifest, then its graphs with their inputs and outputs
    /// checked (the Jacobian graph only where the latent refinement runs).
    pub fn load(dir: &Path, options: RomOptions) -> Result<Rom, RomError> {
        let manifest = Manifest::load(dir)?;
        let threads = options.threads.max(1);
        let [enc, dec, jac] = &manifest.files;
        let encoder = load_graph(&enc.0, &enc.1, &enc.2, threads)?;
        let decoder = load_graph(&dec.0, &dec.1, &dec.2, threads)?;
        let jacobian = if options.refine.unwrap_or(manifest.refinement.enabled) {
            Some(load_graph(&jac.0, &jac.1, &jac.2, threads)?)
        } else {
            None
        };
        let head_wanted =
            options.pressure || (options.force && manifest.force_volume_factor.is_none());
        let pressure = match &manifest.pressure {
            Some(p) if head_wanted => Some(load_graph(&p.0, &p.1, &p.2, threads)?),
            _ => None,
        };
        Ok(Rom {
            z: vec![0.0; manifest.latent],
            manifest,
            options,
            encoder,
            decoder,
            jacobian,
            pressure,
            lattice_pressure: Vec::new(),
            obs: Observation::default(),
            zmin: Vec::new(),
            enc_in: Vec::new(),
            query: Vec::new(),
            points: Vec::new(),
            decoded: Vec::new(),
            region: Vec::new(),
            region_steps: Vec::new(),
            lattice_depth: Vec::new(),
            scratch: RenderScratch::default(),
        })
    }

    /// The manifest; its `lattice` is the one on the gel served ([`Rom::serve`]).
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// Serves a gel of `size` (m) whose thickness is `scale` times the model's
    /// ([`Manifest::check_gel`]): lengths are read in the model's units (`depth_scale`
    /// divided by `scale`), the lattice covers the gel with points the model's pitch
    /// times `scale` apart, and the encoder reads a window of the model's own lattice over
    /// the contact ([`LatticeSpec::window`]). On a gel of the model's shape the networks
    /// see the press they were trained on, scaled, and give its depths scaled back.
    pub fn serve(&mut self, size: [f64; 3]) {
        let scale = size[2] / self.manifest.gel.size[2];
        let lattice = &mut self.manifest.lattice;
        let served = lattice.size[2] / self.manifest.gel.size[2];
        let [rows, cols] = lattice.window;
        let pitch = [
            self.manifest.gel.size[0] / cols as f64,
            self.manifest.gel.size[1] / rows as f64,
        ];
        lattice.nx = ((size[0] / (pitch[0] * scale)).round() as usize).max(1);
        lattice.ny = ((size[1] / (pitch[1] * scale)).round() as usize).max(1);
        lattice.size = size;
        lattice.depth_scale *= served / scale;
    }

    /// Sets the material inputs of `obs` for a gel of Poisson's ratio `poisson` and
    /// friction `friction` (none for a model that is not conditioned on the material).
    pub fn set_material(&self, obs: &mut Observation, poisson: f64, friction: f64) {
        obs.material.clear();
        obs.poisson = poisson;
        if let Some(c) = &self.manifest.conditioning {
            obs.material.extend(c.inputs(poisson, friction));
        }
    }

    /// The latent state of the last inference.
    pub fn latent(&self) -> &[f32] {
        &self.z
    }

    /// The depth on the lattice of the last inference (m, row-major `ny x nx`).
    pub fn lattice_depth(&self) -> &[f64] {
        &self.lattice_depth
    }

    /// The factor of the coarse gel's normal force for the last inference, on the
    /// observation `obs` (the last [`Rom::evaluate`]'s for [`Rom::force_factor`]):
    ///
    /// * for a model with a `force` factor: the decoded surface's displaced volume over
    ///   the coarse one's (on the lattice, over the whole face) times the manifest's
    ///   [`VolumeFactor`] at the gel's Poisson's ratio. On a bonded layer the total normal
    ///   force is close to proportional to the surface's displaced volume, with a constant
    ///   of the gel and its grid that barely depends on the indenter (`F = (M / h) V / r`;
    ///   measured: `docs/rom.md`, "Force"); the manifest's factor, measured on the
    ///   training presses, takes out the coarse grid's own constant. A pressure head then
    ///   shapes the pressure image only: on the held-out presses its own force was no
    ///   closer to the reference's in the median, and further from Hertz on the spheres
    ///   (`docs/rom.md`, "Force and pressure: the pressure head");
    /// * else for a model with a pressure head that ran ([`Rom::lattice_pressure`]): the
    ///   head's force ([`Rom::pressure_force`]) over the coarse one ([`Rom::head_factor`]);
    /// * 1 for a model with neither, or where the ratio falls outside [`VOLUME_RATIO`]: the
    ///   decoder corrects the coarse solution, it does not replace it;
    /// * 1 for an observation mapped only where an image reads it
    ///   ([`Observation::update_read`]: a rom that wants no force).
    pub fn force_factor_on(&self, obs: &Observation) -> f64 {
        if obs.mapped.is_some() {
            return 1.0;
        }
        let Some(k) = &self.manifest.force_volume_factor else {
            return match self.lattice_pressure() {
                Some(_) => self.head_factor(obs).unwrap_or(1.0),
                None => 1.0,
            };
        };
        let decoded: f64 = self.lattice_depth.iter().sum();
        let coarse: f64 = obs.coarse.iter().sum();
        let ratio = decoded / coarse;
        if coarse > 0.0 && ratio.is_finite() && (VOLUME_RATIO[0]..=VOLUME_RATIO[1]).contains(&ratio)
        {
            ratio * k.at(obs.poisson)
        } else {
            1.0
        }
    }

    /// The pressure head's normal force over the coarse gel's (`obs.force`), where the head
    /// ran on `obs` and the ratio lies within [`VOLUME_RATIO`] (the head corrects the coarse
    /// load, it does not replace it).
    pub fn head_factor(&self, obs: &Observation) -> Option<f64> {
        let ratio = self.pressure_force(obs)? / obs.force;
        (ratio.is_finite() && (VOLUME_RATIO[0]..=VOLUME_RATIO[1]).contains(&ratio)).then_some(ratio)
    }

    /// [`Rom::force_factor_on`] the last [`Rom::evaluate`]'s observation.
    pub fn force_factor(&self) -> f64 {
        self.force_factor_on(&self.obs)
    }

    /// [`Rom::head_factor`] on the last [`Rom::evaluate`]'s observation.
    pub fn last_head_factor(&self) -> Option<f64> {
        self.head_factor(&self.obs)
    }

    /// Whether an evaluation maps the coarse depth only where its image reads the decoded
    /// surface ([`Observation::update_read`]): where no force is wanted (the decoded
    /// volume's ratio sums the whole lattice), no pressure head runs, no refinement reads
    /// the lattice's energy terms, and the networks' window is the whole lattice.
    fn reads_part(&self) -> bool {
        // (The pressure head loads only where force or pressure is wanted.)
        !self.options.force
            && !self.options.pressure
            && !self.refine_enabled()
            && self.manifest.lattice.whole()
    }

    fn refine_enabled(&self) -> bool {
        self.options
            .refine
            .unwrap_or(self.manifest.refinement.enabled)
    }

    /// Runs the encoder on an observation: `z` (`latent` values).
    pub fn encode(&mut self, obs: &Observation) -> Result<Vec<f32>, RomError> {
        let mut z = Vec::new();
        self.encode_into(obs, &mut z)?;
        Ok(z)
    }

    /// [`Rom::encode`] into `z` (its allocation kept).
    fn encode_into(&mut self, obs: &Observation, z_out: &mut Vec<f32>) -> Result<(), RomError> {
        let spec = self.manifest.lattice;
        obs.encoder_input(&spec, &mut self.enc_in);
        let e = self.enc_in.len();
        let input = TensorRef::from_array_view(([1usize, e], &self.enc_in[..]))
            .map_err(|e| run_err("encoder", e))?;
        let out = self
            .encoder
            .session()
            .run(ort::inputs!["observation" => input])
            .map_err(|e| run_err("encoder", e))?;
        let (_, z) = out["z"]
            .try_extract_tensor::<f32>()
            .map_err(|e| run_err("encoder", e))?;
        z_out.clear();
        z_out.extend_from_slice(z);
        Ok(())
    }

    /// Runs the decoder at `points` query rows of `query`: depth (model units).
    pub fn decode(&mut self, z: &[f32], query: &[f32]) -> Result<Vec<f32>, RomError> {
        let f = self.manifest.lattice.query_len();
        let n = query.len() / f;
        if n == 0 {
            return Ok(Vec::new());
        }
        run_field(&mut self.decoder, "decoder", "depth", z, query, n, f)
    }

    /// Runs the Jacobian graph: depth (`N` values) and d depth / dz (`N x latent`). An
    /// error where the refinement is off (the graph is not loaded).
    pub fn decode_with_jacobian(
        &mut self,
        z: &[f32],
        query: &[f32],
    ) -> Result<(Vec<f32>, Vec<f32>), RomError> {
        let jacobian = self
            .jacobian
            .as_mut()
            .ok_or_else(|| run_err("jacobian", "not loaded: the latent refinement is off"))?;
        let f = self.manifest.lattice.query_len();
        let n = query.len() / f;
        let zt = TensorRef::from_array_view(([1usize, z.len()], z))
            .map_err(|e| run_err("jacobian", e))?;
        let qt = TensorRef::from_array_view(([n, f], query)).map_err(|e| run_err("jacobian", e))?;
        let out = jacobian
            .session()
            .run(ort::inputs!["z" => zt, "query" => qt])
            .map_err(|e| run_err("jacobian", e))?;
        let (_, d) = out["depth"]
            .try_extract_tensor::<f32>()
            .map_err(|e| run_err("jacobian", e))?;
        let (_, j) = out["jacobian"]
            .try_extract_tensor::<f32>()
            .map_err(|e| run_err("jacobian", e))?;
        Ok((d.to_vec(), j.to_vec()))
    }

    /// The deformable region of an observation (see the module docs).
    fn compute_region(&mut self, obs: &Observation) {
        let (eps, grow) = self.manifest.region;
        let (spec, steps) = (&self.manifest.lattice, &mut self.region_steps);
        features::region(obs, spec, eps, grow, steps, &mut self.region);
        // Where only part of the lattice was mapped, the decoder runs where it is read.
        if let Some(m) = &obs.mapped {
            for (row, line) in self.region.chunks_exact_mut(spec.nx).enumerate() {
                for (col, inside) in line.iter_mut().enumerate() {
                    *inside &= m.read.rows.contains(&row) && m.read.cols.contains(&col);
                }
            }
        }
    }

    fn energy_set(&self, obs: &Observation) -> EnergySet {
        let spec = &self.manifest.lattice;
        let rf = &self.manifest.refinement;
        let (nx, ny) = (spec.nx, spec.ny);
        let ds = spec.depth_scale;
        let mut set = EnergySet::default();
        let mut index = vec![usize::MAX; nx * ny];
        let add = |set: &mut EnergySet,
                   index: &mut [usize],
                   r: usize,
                   c: usize,
                   inertia: f64,
                   contact: f64| {
            let i = r * nx + c;
            if index[i] == usize::MAX {
                index[i] = set.terms.len();
                set.terms.push(Term {
                    inertia,
                    anchor: obs.coarse[i] * ds,
                    contact,
                    pen: obs.pen[i] * ds,
                });
                query_features(obs, spec, r, c, &mut set.query);
            } else {
                let t = &mut set.terms[index[i]];
                t.inertia += inertia;
                t.contact += contact;
            }
        };
        let s = rf.stride;
        let mut a_count = 0usize;
        for r in (s / 2..ny).step_by(s) {
            for c in (s / 2..nx).step_by(s) {
                if self.region[r * nx + c] {
                    add(&mut set, &mut index, r, c, 1.0, 0.0);
                    a_count += 1;
                }
            }
        }
        for r in (s / 2..ny).step_by(s) {
            for c in (s / 2..nx).step_by(s) {
                let i = r * nx + c;
                if !self.region[i] {
                    continue;
                }
                if c + s < nx && self.region[i + s] {
                    set.pairs.push((index[i], index[i + s]));
                }
                if r + s < ny && self.region[i + s * nx] {
                    set.pairs.push((index[i], index[i + s * nx]));
                }
            }
        }
        let cs = rf.contact_stride;
        let mut c_count = 0usize;
        for r in (cs / 2..ny).step_by(cs) {
            for c in (cs / 2..nx).step_by(cs) {
                if obs.pen[r * nx + c] > 0.0 {
                    add(&mut set, &mut index, r, c, 0.0, 1.0);
                    c_count += 1;
                }
            }
        }
        let wa = if a_count > 0 {
            rf.w_inertia / a_count as f64
        } else {
            0.0
        };
        let wc = if c_count > 0 {
            rf.w_contact / c_count as f64
        } else {
            0.0
        };
        for t in &mut set.terms {
            t.inertia *= wa;
            t.contact *= wc;
        }
        let h = s as f64 * spec.size[0] / nx as f64 * ds;
        set.pair_weight = if set.pairs.is_empty() {
            0.0
        } else {
            rf.w_elastic / (set.pairs.len() as f64 * h * h)
        };
        set.reach = obs.rule.reach() * ds;
        set.reach_weight = if set.terms.is_empty() {
            0.0
        } else {
            rf.w_contact / set.terms.len() as f64
        };
        // Lengths in units of the press: the deepest indenter point's penetration, or a
        // micrometre where nothing pierces the gel.
        let unit = set.reach.max(1e-3);
        set.scale = 1.0 / (unit * unit);
        set
    }

    /// The reduced energy at depths `d` and its derivative with respect to `d`.
    fn energy(set: &EnergySet, d: &[f32], dd: &mut [f64]) -> f64 {
        let mut e = 0.0;
        for (k, (t, &di)) in set.terms.iter().zip(d).enumerate() {
            let di = di as f64;
            let r = di - t.anchor;
            let gap = (t.pen - di).max(0.0);
            let over = (di - set.reach).max(0.0);
            e += 0.5 * (t.inertia * r * r + t.contact * gap * gap + set.reach_weight * over * over);
            dd[k] = t.inertia * r - t.contact * gap + set.reach_weight * over;
        }
        for &(i, j) in &set.pairs {
            let s = d[j] as f64 - d[i] as f64;
            e += 0.5 * set.pair_weight * s * s;
            dd[j] += set.pair_weight * s;
            dd[i] -= set.pair_weight * s;
        }
        dd.iter_mut().for_each(|g| *g *= set.scale);
        e * set.scale
    }

    /// Encoder, refinement and dense decoding for an observation; fills the lattice depth
    /// (m). The observation is kept for [`Rom::render`].
    pub fn infer(&mut self, obs: &Observation) -> Result<RomReport, RomError> {
        let mut report = RomReport::default();
        let t0 = Instant::now();
        let mut z = std::mem::take(&mut self.z);
        let encoded = self.encode_into(obs, &mut z);
        self.z = z;
        encoded?;
        self.compute_region(obs);
        report.encode_s = t0.elapsed().as_secs_f64();
        if self.refine_enabled() {
            self.refine(obs, &mut report)?;
        }
        self.decode_region(obs, &mut report)?;
        if self.pressure.is_some() {
            let t = Instant::now();
            let points = std::mem::take(&mut self.points);
            let pressure = self.infer_pressure(obs, &points);
            self.points = points;
            pressure?;
            report.decode_s += t.elapsed().as_secs_f64();
        }
        Ok(report)
    }

    /// The latent refinement: L-BFGS on the reduced energy from the encoder's `z`
    /// (updated where it lowered the energy).
    fn refine(&mut self, obs: &Observation, report: &mut RomReport) -> Result<(), RomError> {
        let t1 = Instant::now();
        let mut set = self.energy_set(obs);
        report.energy_points = set.terms.len();
        // The Jacobian graph at `z0`, kept for the refinement's first evaluation there.
        let mut at_z0 = None;
        if self.manifest.refinement.anchor_encoder && !set.terms.is_empty() {
            // From the graph the refinement differentiates, so that `z0` is where the
            // prediction term is zero for it (the dense decoder may be quantized).
            let z0 = self.z.clone();
            let (d0, j0) = self.decode_with_jacobian(&z0, &set.query)?;
            for (t, &d) in set.terms.iter_mut().zip(&d0) {
                t.anchor = d as f64;
            }
            at_z0 = Some((z0, (d0, j0)));
        }
        if !set.terms.is_empty() {
            let r = self.manifest.latent;
            let mut zf: Vec<f64> = self.z.iter().map(|&v| v as f64).collect();
            let mut dd = vec![0.0; set.terms.len()];
            let mut z32 = vec![0.0f32; r];
            let options = self.manifest.refinement.lbfgs;
            let lb = lbfgs::minimize(&mut zf, &options, |z, grad| {
                for (a, &b) in z32.iter_mut().zip(z) {
                    *a = b as f32;
                }
                let (d, jac) = match at_z0.take() {
                    Some((z0, known)) if z0 == z32 => known,
                    _ => self.decode_with_jacobian(&z32, &set.query)?,
                };
                let e = Self::energy(&set, &d, &mut dd);
                grad.iter_mut().for_each(|g| *g = 0.0);
                for (k, &w) in dd.iter().enumerate() {
                    if w != 0.0 {
                        for (g, &j) in grad.iter_mut().zip(&jac[k * r..(k + 1) * r]) {
                            *g += w * j as f64;
                        }
                    }
                }
                Ok::<f64, RomError>(e)
            })?;
            if lb.last.is_finite() && lb.last <= lb.initial {
                self.z = zf.iter().map(|&v| v as f32).collect();
            }
            report.refinement = Some(lb);
        }
        report.refine_s += t1.elapsed().as_secs_f64();
        Ok(())
    }

    /// Dense decoding of the deformable region at the current `z` into the lattice depth,
    /// bounded by the depth rule (the report's excesses and decoded points are this
    /// decoding's); leaves the decoded lattice points in `self.points`, in the order of
    /// the query rows.
    fn decode_region(&mut self, obs: &Observation, report: &mut RomReport) -> Result<(), RomError> {
        let t2 = Instant::now();
        let spec = self.manifest.lattice;
        self.query.clear();
        self.points.clear();
        for (i, &inside) in self.region.iter().enumerate() {
            if inside {
                query_features(obs, &spec, i / spec.nx, i % spec.nx, &mut self.query);
                self.points.push(i);
            }
        }
        self.lattice_depth.clear();
        self.lattice_depth.extend_from_slice(&obs.coarse);
        let f = spec.query_len();
        let n = self.query.len() / f;
        if n > 0 {
            run_field_into(
                &mut self.decoder,
                "decoder",
                "depth",
                &self.z,
                &self.query,
                n,
                f,
                &mut self.decoded,
            )?;
        } else {
            self.decoded.clear();
        }
        let (points, d) = (&self.points, &self.decoded);
        for (&i, &v) in points.iter().zip(d) {
            let v = v as f64 / spec.depth_scale;
            self.lattice_depth[i] = if v.is_finite() { v } else { obs.coarse[i] };
        }
        // (Where only part of the lattice was mapped, over the points read.)
        let excess = |rows: std::ops::Range<usize>, cols: std::ops::Range<usize>| {
            rows.flat_map(|r| cols.clone().map(move |c| r * spec.nx + c))
                .fold(0.0f64, |m, i| m.max(obs.pen[i] - self.lattice_depth[i]))
        };
        report.penetration_excess = match &obs.mapped {
            None => excess(0..spec.ny, 0..spec.nx),
            Some(m) => excess(m.read.rows.clone(), m.read.cols.clone()),
        };
        // (Points not mapped hold no depth: none exceeds the bound.)
        report.bound_excess = obs.rule.apply(&mut self.lattice_depth, &obs.pen);
        report.decoded = self.points.len();
        report.decode_s += t2.elapsed().as_secs_f64();
        Ok(())
    }

    /// Runs the pressure head at the lattice points `points` (the region's, in the order of
    /// the decoder's query rows in `self.query`), each row followed by its window of the
    /// coarse load of `obs` in the head's units: [`Rom::lattice_pressure`].
    fn infer_pressure(&mut self, obs: &Observation, points: &[usize]) -> Result<(), RomError> {
        if self.pressure.is_none() {
            return Ok(());
        }
        let n = self.lattice_depth.len();
        self.lattice_pressure.clear();
        self.lattice_pressure.resize(n, 0.0);
        if points.is_empty() || obs.pressure.len() != n {
            return Ok(());
        }
        let spec = self.manifest.lattice;
        let f = spec.query_len();
        let g = f + spec.patch * spec.patch;
        let area = spec.size[0] / spec.nx as f64 * spec.size[1] / spec.ny as f64;
        let per_unit = area / self.pressure_unit(obs);
        let load: Vec<f64> = obs
            .pressure
            .iter()
            .map(|&p| {
                if per_unit.is_finite() {
                    p * per_unit
                } else {
                    0.0
                }
            })
            .collect();
        let mut query = Vec::with_capacity(points.len() * g);
        for (k, &i) in points.iter().enumerate() {
            query.extend_from_slice(&self.query[k * f..(k + 1) * f]);
            load_window(&load, &spec, i / spec.nx, i % spec.nx, &mut query);
        }
        let graph = self.pressure.as_mut().expect("checked above");
        let p = run_field(
            graph,
            "pressure",
            "pressure",
            &self.z,
            &query,
            points.len(),
            g,
        )?;
        for (&i, &v) in points.iter().zip(&p) {
            // No tension in a contact; a non-finite output carries no load.
            self.lattice_pressure[i] = if v.is_finite() {
                (v as f64).max(0.0)
            } else {
                0.0
            };
        }
        Ok(())
    }

    /// The pressure head's output on the lattice after the last inference (row-major
    /// `ny x nx`, at least 0, 0 outside the deformable region), in [`PRESSURE_UNITS`];
    /// `None` where the head did not run (no head in the model, or
    /// [`RomOptions::pressure`] off).
    pub fn lattice_pressure(&self) -> Option<&[f64]> {
        self.pressure.as_ref().map(|_| &self.lattice_pressure[..])
    }

    /// Newtons per unit of the head's output (and of its load window) at one lattice point
    /// of the observation `obs`: its coarse force shared among the region's points.
    fn pressure_unit(&self, obs: &Observation) -> f64 {
        let points = self.region.iter().filter(|&&inside| inside).count();
        obs.force / points.max(1) as f64
    }

    /// The normal force (N) of the pressure head's field on the observation `obs` of its
    /// last inference; `None` where the head did not run.
    pub fn pressure_force(&self, obs: &Observation) -> Option<f64> {
        let unit = self.pressure_unit(obs);
        self.lattice_pressure()
            .map(|p| unit * p.iter().sum::<f64>())
    }

    /// The pressure head's field of the last [`Rom::evaluate`] on `grid` (Pa), carrying
    /// the normal force `force` (N): each lattice point's share of it spread with the
    /// quadratic B-spline kernel one lattice pitch wide ([`crate::mpm::spread_loads`], as
    /// the gel spreads its contact loads), so that the image integrates to `force` wherever
    /// the contact lies inside it. `false` (and `out` untouched) where the head did not run
    /// or found no load.
    pub fn render_pressure(&self, grid: &PixelGrid, force: f64, out: &mut [f64]) -> bool {
        let Some(p) = self.lattice_pressure() else {
            return false;
        };
        let total: f64 = p.iter().sum();
        if !(total > 0.0 && force.is_finite()) {
            return false;
        }
        let spec = &self.manifest.lattice;
        let lattice = spec.grid();
        let unit = force / total;
        let pitch = (spec.size[0] / spec.nx as f64).max(spec.size[1] / spec.ny as f64);
        let loads = p
            .iter()
            .enumerate()
            .filter(|(_, &v)| v > 0.0)
            .map(|(i, &v)| {
                let (row, col) = (i / spec.nx, i % spec.nx);
                (lattice.x(col), lattice.y(row), v * unit)
            });
        crate::mpm::spread_loads(loads, pitch, grid, out);
        true
    }

    /// Renders the last inference's lattice onto `grid` by monotone cubic interpolation
    /// ([`render_lattice`]); the caller applies the depth rule with the full-resolution
    /// rigid surface.
    pub fn render(&mut self, grid: &PixelGrid, out: &mut [f64]) {
        let lattice = &self.manifest.lattice;
        render_lattice(lattice, &self.lattice_depth, grid, out, &mut self.scratch);
    }

    /// One sensor evaluation: observation of the solved coarse `gel` under `indenters`,
    /// inference, and the surface on `grid` as in [`Rom::render`].
    pub fn evaluate(
        &mut self,
        gel: &Gel,
        indenters: &[Placed],
        grid: &PixelGrid,
        out: &mut [f64],
    ) -> Result<RomReport, RomError> {
        let t0 = Instant::now();
        let mut obs = std::mem::take(&mut self.obs);
        let spec = self.manifest.lattice;
        if self.reads_part() {
            let grow = self.manifest.region.1;
            obs.update_read(gel, indenters, &spec, &mut self.zmin, grid, grow);
        } else {
            obs.update(gel, indenters, &spec, &mut self.zmin);
        }
        if self.pressure.is_some() {
            obs.update_load(gel, &spec);
        }
        self.set_material(&mut obs, gel.params().poisson, gel.params().friction);
        let observe_s = t0.elapsed().as_secs_f64();
        let result = self.infer(&obs);
        self.obs = obs;
        let mut report = result?;
        report.encode_s += observe_s;
        let t1 = Instant::now();
        self.render(grid, out);
        report.decode_s += t1.elapsed().as_secs_f64();
        Ok(report)
    }
}

impl Rom {
    /// A copy with sessions of its own (ONNX Runtime sessions run with `&mut`), loaded again
    /// from the model directory (kept idle sessions where there are: [`runtime::load_graph`]):
    /// for `mj_copyData`.
    pub fn try_clone(&self) -> Result<Self, RomError> {
        let mut copy = Rom::load(&self.manifest.dir, self.options)?;
        copy.serve(self.manifest.lattice.size);
        copy.z.clone_from(&self.z);
        copy.lattice_depth.clone_from(&self.lattice_depth);
        copy.lattice_pressure.clone_from(&self.lattice_pressure);
        copy.region.clone_from(&self.region);
        copy.obs.clone_from(&self.obs);
        Ok(copy)
    }
}

const _: fn() = || {
    fn assert_send<T: Send>() {}
    assert_send::<Rom>();
};

/// The lattice field `lat` (row-major `ny x nx`) on `grid`: monotone cubic Hermite
/// interpolation (Fritsch and Carlson) in x then y. It passes through the lattice values,
/// its slope is continuous across the lattice lines, and between two points it stays
/// within their values (no overshoot at a contact's edge). At a pixel finer than the
/// lattice the surface's slope changes then show no preference for the lines, where
/// bilinear interpolation kept the slope within a lattice cell and changed it at the lines
/// (the rgb image showed the lattice as blocks; `tests/lattice_pattern.rs`). Beyond the
/// outer lattice points the edge values repeat.
fn render_lattice(
    spec: &LatticeSpec,
    lat: &[f64],
    grid: &PixelGrid,
    out: &mut [f64],
    scratch: &mut RenderScratch,
) {
    let (nx, ny, w) = (spec.nx, spec.ny, grid.width);
    let [lx, ly, _] = spec.size;
    let (px, py) = (lx / nx as f64, ly / ny as f64);
    let RenderScratch {
        cols,
        rows,
        filled,
        line_slopes,
        column_slopes,
    } = scratch;
    cols.clear();
    cols.extend((0..w).map(|col| cell((grid.x(col) + 0.5 * lx) / px - 0.5, nx)));
    rows.resize(ny * w, 0.0);
    filled.clear();
    filled.resize(ny, false);
    column_slopes.resize(w, [0.0; 2]);
    // The lattice cell whose slopes `column_slopes` holds.
    let mut slopes_of = None;
    for row in 0..grid.height {
        let (r, t) = cell((0.5 * ly - grid.y(row)) / py - 0.5, ny);
        let used = r.saturating_sub(1)..(r + 3).min(ny);
        // Each lattice row the image reads, interpolated along x once, from the row's
        // slopes computed once.
        for k in used.clone() {
            if !std::mem::replace(&mut filled[k], true) {
                let line = &lat[k * nx..(k + 1) * nx];
                line_slopes.clear();
                line_slopes.extend((0..nx).map(|i| monotone_slope(line, i)));
                for (v, &(c, t)) in rows[k * w..(k + 1) * w].iter_mut().zip(cols.iter()) {
                    *v = hermite_with(line, line_slopes, c, t);
                }
            }
        }
        // Down the lattice: per image column, the slopes at the cell's two rows, the same
        // for every image row in the cell.
        let j = (r + 1).min(ny - 1);
        if slopes_of != Some(r) {
            slopes_of = Some(r);
            let mut column = [0.0; 4];
            for (col, m) in column_slopes.iter_mut().enumerate() {
                let base = r.saturating_sub(1);
                for (k, v) in used.clone().zip(column.iter_mut()) {
                    *v = rows[k * w + col];
                }
                // (The window holds the samples either side of `r` and `j` that exist.)
                let window = &column[..used.len()];
                *m = [
                    monotone_slope(window, r - base),
                    monotone_slope(window, j - base),
                ];
            }
        }
        for (col, v) in out[row * w..(row + 1) * w].iter_mut().enumerate() {
            let at = |k: usize| rows[k * w + col];
            let [m0, m1] = column_slopes[col];
            *v = if ny < 2 {
                at(0)
            } else {
                hermite_step(at(r), at(j) - at(r), m0, m1, t)
            };
        }
    }
}

/// The lattice cell `[i, i + 1]` of the continuous lattice coordinate `f` (0 at the first
/// point; clamped to the lattice) and the position `t` in it.
fn cell(f: f64, n: usize) -> (usize, f64) {
    let f = f.clamp(0.0, n.saturating_sub(1) as f64);
    let i = (f.floor() as usize).min(n.saturating_sub(2));
    (i, f - i as f64)
}

/// The slope of the monotone cubic Hermite interpolant of the samples `v` at sample `k`:
/// the weighted harmonic mean of its two secants, zero where they differ in sign (Fritsch
/// and Carlson; one-sided at the ends).
fn monotone_slope(v: &[f64], k: usize) -> f64 {
    let secant = |a: usize| v[a + 1] - v[a];
    let left = (k > 0).then(|| secant(k - 1));
    let right = (k + 1 < v.len()).then(|| secant(k));
    match (left, right) {
        (Some(a), Some(b)) if a * b > 0.0 => 2.0 * a * b / (a + b),
        (Some(_), Some(_)) => 0.0,
        (Some(a), None) | (None, Some(a)) => a,
        (None, None) => 0.0,
    }
}

/// The monotone cubic Hermite interpolant of the samples `v` with slopes `m` at `i + t`
/// (`t` in [0, 1]).
fn hermite_with(v: &[f64], m: &[f64], i: usize, t: f64) -> f64 {
    match v.len() {
        0 => 0.0,
        1 => v[0],
        _ => hermite_step(v[i], v[i + 1] - v[i], m[i], m[i + 1], t),
    }
}

/// The cubic Hermite segment from `v` rising by `d` with end slopes `m0`, `m1`, at `t`.
#[inline]
fn hermite_step(v: f64, d: f64, m0: f64, m1: f64, t: f64) -> f64 {
    let (t2, t3) = (t * t, t * t * t);
    let h00 = 2.0 * t3 - 3.0 * t2 + 1.0;
    let h10 = t3 - 2.0 * t2 + t;
    let h01 = -2.0 * t3 + 3.0 * t2;
    let h11 = t3 - t2;
    h00 * v + h10 * m0 + h01 * (v + d) + h11 * m1
}

/// Runs a field graph (`z [1, r]`, `query [n, f]` -> `output [n, 1]`) of the model: the
/// decoder or the pressure head.
pub(crate) fn run_field(
    graph: &mut Graph,
    name: &'static str,
    output: &str,
    z: &[f32],
    query: &[f32],
    n: usize,
    f: usize,
) -> Result<Vec<f32>, RomError> {
    let mut values = Vec::with_capacity(n);
    run_field_into(graph, name, output, z, query, n, f, &mut values)?;
    Ok(values)
}

/// [`run_field`] into `values` (cleared first, its allocation kept).
#[allow(clippy::too_many_arguments)]
pub(crate) fn run_field_into(
    graph: &mut Graph,
    name: &'static str,
    output: &str,
    z: &[f32],
    query: &[f32],
    n: usize,
    f: usize,
    values: &mut Vec<f32>,
) -> Result<(), RomError> {
    values.clear();
    for start in (0..n).step_by(FIELD_ROWS) {
        let rows = FIELD_ROWS.min(n - start);
        let zt =
            TensorRef::from_array_view(([1usize, z.len()], z)).map_err(|e| run_err(name, e))?;
        let qt = TensorRef::from_array_view(([rows, f], &query[start * f..(start + rows) * f]))
            .map_err(|e| run_err(name, e))?;
        let out = graph
            .session()
            .run(ort::inputs!["z" => zt, "query" => qt])
            .map_err(|e| run_err(name, e))?;
        let (_, v) = out[output]
            .try_extract_tensor::<f32>()
            .map_err(|e| run_err(name, e))?;
        values.extend_from_slice(v);
    }
    Ok(())
}

/// Rows of one run of a field graph ([`run_field`]): more are run in parts. ONNX
/// Runtime's memory arena keeps what its largest run asked for (a grasp's pad may decode
/// its whole 100 x 100 lattice: 80 to 100 MB of arena over a grasp soak, never
/// returned); in parts of 2,048 it stays bounded, and a press under a 5 mm sphere (800 to
/// 1,300 rows) runs in one part as before. (The 8-bit decoder scales its activations per
/// run, so a larger region decodes to within that quantisation of one run's answer.)
/// Measured: `docs/rl.md`, the coupled grasp's soak.
const FIELD_ROWS: usize = 2048;

fn run_err(graph: &'static str, e: impl std::fmt::Display) -> RomError {
    RomError::Run {
        graph,
        message: e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A decoding of more rows than one run takes ([`FIELD_ROWS`]) puts every row where
    /// it belongs: each equals the same row decoded in a run that starts elsewhere (the
    /// float decoder of `models/rom-default`; a row's depth does not depend on the other
    /// rows, so the two agree to single precision's round-off, while a row out of place
    /// would carry another query's depth).
    #[test]
    fn rows_beyond_one_run_are_decoded_in_place() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/rom-default");
        let mut rom = Rom::load(&dir, RomOptions::default()).expect("shipped model");
        let f = rom.manifest.lattice.query_len();
        let n = 2 * FIELD_ROWS + 7;
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        let z: Vec<f32> = (0..64).map(|_| next() - 0.5).collect();
        let query: Vec<f32> = (0..n * f).map(|_| next()).collect();
        let all = rom.decode(&z, &query).unwrap();
        let shift = FIELD_ROWS / 2 + 3;
        let later = rom.decode(&z, &query[shift * f..]).unwrap();
        assert_eq!((all.len(), later.len()), (n, n - shift));
        let spread = all.iter().fold(0f32, |m, &v| m.max((v - all[0]).abs()));
        assert!(spread > 1e-3, "the rows' depths differ: {spread}");
        for (i, (a, b)) in all[shift..].iter().zip(&later).enumerate() {
            assert!(
                (a - b).abs() <= 1e-5 * (1.0 + a.abs()),
                "row {}: {a} against {b}",
                i + shift
            );
        }
    }

    fn factor(by_poisson: Vec<[f64; 2]>) -> Result<VolumeFactor, String> {
        VolumeFactor::new(document::Force {
            volume_factor: 1.1,
            by_poisson,
        })
    }

    /// The monotone cubic Hermite interpolant at `i + t` of the samples `v`, every slope
    /// computed where it is used: the image's definition, which [`render_lattice`]
    /// evaluates with each slope computed once.
    fn hermite_by_definition(v: &[f64], i: usize, t: f64) -> f64 {
        match v.len() {
            0 => 0.0,
            1 => v[0],
            _ => hermite_step(
                v[i],
                v[i + 1] - v[i],
                monotone_slope(v, i),
                monotone_slope(v, i + 1),
                t,
            ),
        }
    }

    /// The image of a lattice by definition: each pixel interpolated along x on every
    /// lattice row, then down the lattice.
    fn render_by_definition(spec: &LatticeSpec, lat: &[f64], grid: &PixelGrid) -> Vec<f64> {
        let (nx, ny) = (spec.nx, spec.ny);
        let [lx, ly, _] = spec.size;
        let (px, py) = (lx / nx as f64, ly / ny as f64);
        let mut out = vec![0.0; grid.width * grid.height];
        for row in 0..grid.height {
            let (r, t) = cell((0.5 * ly - grid.y(row)) / py - 0.5, ny);
            for col in 0..grid.width {
                let (c, u) = cell((grid.x(col) + 0.5 * lx) / px - 0.5, nx);
                let column: Vec<f64> = (0..ny)
                    .map(|k| hermite_by_definition(&lat[k * nx..(k + 1) * nx], c, u))
                    .collect();
                out[row * grid.width + col] = hermite_by_definition(&column, r, t);
            }
        }
        out
    }

    /// The image's slopes computed once per lattice point and once per lattice cell and
    /// image column give the definition's pixels to the last bit: on lattices of 1 to 9
    /// points a side with steps, plateaus and sign changes, on images finer and coarser
    /// than the lattice, covering part of it or all.
    #[test]
    fn the_lattice_image_equals_its_definition_bit_for_bit() {
        let mut random = crate::test_uniform(12345);
        for (nx, ny) in [(1, 1), (1, 5), (5, 1), (2, 2), (7, 4), (9, 9)] {
            let spec = LatticeSpec::with_pitch(
                [0.03, 0.03 * ny as f64 / nx as f64, 0.004],
                0.03 / nx as f64,
            );
            assert_eq!((spec.nx, spec.ny), (nx, ny));
            let lat: Vec<f64> = (0..nx * ny)
                .map(|_| match (random() * 4.0) as u32 {
                    0 => 0.0,
                    1 => 1e-4,
                    _ => random() * 1e-3 - 2e-4,
                })
                .collect();
            for (width, height, fov) in [(1, 1, 1.0), (3, 2, 0.5), (64, 48, 0.8), (33, 17, 1.0)] {
                let grid = PixelGrid {
                    width,
                    height,
                    fov_x: spec.size[0] * fov,
                    fov_y: spec.size[1] * fov,
                };
                let mut out = vec![f64::NAN; width * height];
                render_lattice(&spec, &lat, &grid, &mut out, &mut RenderScratch::default());
                let expected = render_by_definition(&spec, &lat, &grid);
                for (k, (a, b)) in out.iter().zip(&expected).enumerate() {
                    assert_eq!(
                        a.to_bits(),
                        b.to_bits(),
                        "{nx}x{ny} lattice, {width}x{height} image, pixel {k}: {a} against {b}"
                    );
                }
            }
        }
    }

    /// One factor for every gel without a table; with one, linear between its points and
    /// held beyond its ends.
    #[test]
    fn the_volume_factor_follows_its_poisson_table() {
        let one = factor(vec![]).unwrap();
        assert_eq!((one.at(0.3), one.at(0.48)), (1.1, 1.1));
        let t = factor(vec![[0.3, 1.0], [0.4, 1.2], [0.46, 1.5]]).unwrap();
        for (nu, k) in [
            (0.2, 1.0),
            (0.3, 1.0),
            (0.35, 1.1),
            (0.4, 1.2),
            (0.43, 1.35),
            (0.46, 1.5),
            (0.49, 1.5),
        ] {
            assert!(
                (t.at(nu) - k).abs() < 1e-12,
                "{nu}: {} against {k}",
                t.at(nu)
            );
        }
    }

    /// A table out of order, beyond Poisson 0.5 or with a factor outside [0.5, 2] is
    /// refused, naming the value.
    #[test]
    fn a_bad_poisson_table_is_refused() {
        for (table, named) in [
            (vec![[0.4, 1.0], [0.3, 1.1]], "0.3"),
            (vec![[0.3, 1.0], [0.5, 1.1]], "0.5"),
            (vec![[0.3, 1.0], [0.4, 2.5]], "2.5"),
        ] {
            let e = factor(table).unwrap_err();
            assert!(e.contains("by_poisson") && e.contains(named), "{e}");
        }
    }
}
