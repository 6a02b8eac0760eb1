//! What the reduced-order model's networks see, written out for the feature-parity test
//! (`tacrom rom-features`, a developer tool).
//!
//! The decoder runs on inputs computed by [`tacrom::rom::features`] at run time and was
//! trained on inputs computed by `training/tacrom_rom/data.py` from `tacrom gen-data`'s
//! arrays. `training/tests/test_feature_parity.py` runs this tool and checks that the two
//! agree. For a few fixed presses of the model's coarse gel it writes, into `--out`,
//!
//! * `dataset.json` and per press `sample-NNNNNN.npy` / `sample-NNNNNN.json`: the press
//!   in `gen-data`'s format (written by [`crate::datagen::sample_array`]), so that
//!   `data.load_dir(..., drop_unconverged=False)` reads it as training reads its data. No
//!   reference is solved: channel 2 repeats the coarse depth and the sample's `reference`
//!   is `null`;
//! * `observation-NNNNNN.npy`: float64 `[2, ny, nx]` (m), the coarse depth and the rigid
//!   penetration exactly as the run-time code holds them (the sample's channels 0 and 1
//!   are these rounded to float32);
//! * `encoder-NNNNNN.npy`: float32 `[encoder_len]`, [`Observation::encoder_input`];
//! * `query-NNNNNN.npy`: float32 `[ny * nx, query_len]`, [`query_features`] at every
//!   lattice point, row-major;
//! * `region-NNNNNN.npy`: uint8 `[ny, nx]`, [`region`] with the manifest's settings;
//! * `pressure-NNNNNN.npy`: float64 `[ny, nx]` (Pa), the coarse gel's contact pressure
//!   ([`Observation::update_load`]), and `load-NNNNNN.npy`: float32
//!   `[ny * nx, patch * patch]`, its [`load_window`] at every lattice point (a pressure
//!   head's window, here in pascals: the head's units scale it alike on both sides);
//! * `features.json`: the model, its lattice and region settings, and the presses
//!   (indenters, poses, coarse solve).
//!
//! The lattice, gel and coarse solve are the model's (its manifest), so the arrays are the
//! inputs that model sees at run time.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;

use tacrom::geometry::{Cuboid, Placed, Sphere};
use tacrom::mpm::{Gel, GelParams, SolverOptions};
use tacrom::rom::features::{load_window, query_features, region, LatticeSpec, Observation};
use tacrom::rom::Manifest;

use crate::datagen::{sample_array, SolveMeta};
use crate::npy;

/// Format tag of `features.json`.
pub const FORMAT: &str = "tacrom-rom-features-1";

/// Settings of `tacrom rom-features`.
#[derive(Clone, Debug)]
pub struct FeaturesConfig {
    /// Output directory.
    pub out: PathBuf,
    /// Model directory whose lattice, gel and coarse solve are used.
    pub model: PathBuf,
    /// Solver threads.
    pub threads: usize,
}

/// One indenter of a press, as recorded in `features.json`.
#[derive(Clone, Debug, Serialize)]
pub struct IndenterMeta {
    /// `sphere` or `box`.
    pub shape: String,
    /// Sphere radius or box half extents (m).
    pub size: Vec<f64>,
    /// Translation of the shape's frame (m, sensor frame: the gel's top face at z = 0).
    pub translation: [f64; 3],
    /// Rotation of the shape's frame, quaternion `[w, x, y, z]`.
    pub rotation: [f64; 4],
}

/// One press, as recorded in `features.json`.
#[derive(Clone, Debug, Serialize)]
pub struct PressMeta {
    /// Index of the press (file stem `NNNNNN`).
    pub index: usize,
    /// What it is.
    pub name: String,
    /// The indenters.
    pub indenters: Vec<IndenterMeta>,
    /// Deepest rigid penetration on the lattice (m).
    pub max_penetration: f64,
    /// Deepest coarse depth on the lattice (m).
    pub max_coarse: f64,
    /// Lattice points in the deformable region.
    pub region_points: usize,
    /// The coarse solve.
    pub coarse: SolveMeta,
}

/// `features.json`.
#[derive(Clone, Debug, Serialize)]
pub struct FeaturesMeta {
    /// [`FORMAT`].
    pub format: String,
    /// The model directory.
    pub model: String,
    /// Gel size `[Lx, Ly, T]` (m).
    pub size: [f64; 3],
    /// Coarse grid spacing (m).
    pub coarse_dx: f64,
    /// The lattice and feature settings ([`LatticeSpec`]).
    pub lattice: LatticeSpec,
    /// Encoder input length.
    pub encoder_len: usize,
    /// Decoder query feature count.
    pub query_len: usize,
    /// Region settings: coarse depth threshold (model units) and growth (points).
    pub region: RegionMeta,
    /// The presses.
    pub presses: Vec<PressMeta>,
}

/// Region settings in `features.json`, named as in a manifest's `region`.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct RegionMeta {
    /// Coarse depth threshold (model units).
    pub eps_mm: f64,
    /// Growth (lattice points).
    pub grow: usize,
}

/// The presses on a gel of `size`: an off-centre sphere (not symmetric in x, y or their
/// swap), and a tilted, turned box at the (-x, +y) corner whose contact reaches both edges,
/// so that windows there cross them.
fn presses(size: [f64; 3]) -> Vec<(&'static str, Vec<(Placed, IndenterMeta)>)> {
    let sphere = {
        let r = 4e-3;
        let (x, y, depth) = (4.1e-3, -2.7e-3, 0.8e-3);
        let pose = Isometry3::translation(x, y, r - depth);
        placed("sphere", vec![r], Arc::new(Sphere::new(r)), pose)
    };
    let boxed = {
        let h = Vector3::new(3e-3, 1.5e-3, 2e-3);
        let rot = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 5f64.to_radians())
            * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 30f64.to_radians());
        let low = (0..8)
            .map(|k| {
                let s = |b: usize| if k & b == 0 { -1.0 } else { 1.0 };
                (rot * Point3::new(s(1) * h.x, s(2) * h.y, s(4) * h.z)).z
            })
            .fold(f64::INFINITY, f64::min);
        let (x, y, depth) = (-0.5 * size[0] + 2.4e-3, 0.5 * size[1] - 2.6e-3, 0.6e-3);
        let pose = Isometry3::from_parts(Translation3::new(x, y, -depth - low), rot);
        placed("box", vec![h.x, h.y, h.z], Arc::new(Cuboid::new(h)), pose)
    };
    vec![
        ("sphere off centre", vec![sphere]),
        ("box at a corner", vec![boxed]),
    ]
}

fn placed(
    shape: &str,
    size: Vec<f64>,
    sdf: Arc<dyn tacrom::geometry::Sdf>,
    pose: Isometry3<f64>,
) -> (Placed, IndenterMeta) {
    let t = pose.translation.vector;
    let q = pose.rotation.quaternion();
    let meta = IndenterMeta {
        shape: shape.to_owned(),
        size,
        translation: [t.x, t.y, t.z],
        rotation: [q.w, q.i, q.j, q.k],
    };
    (Placed { shape: sdf, pose }, meta)
}

fn write_json(path: &Path, value: &impl Serialize) -> Result<(), String> {
    let mut text = serde_json::to_string_pretty(value).map_err(|e| e.to_string())?;
    text.push('\n');
    npy::write_atomic(path, text.as_bytes()).map_err(|e| format!("{}: {e}", path.display()))
}

fn write_array<T: npyz::AutoSerialize>(
    path: &Path,
    shape: &[usize],
    data: &[T],
) -> Result<(), String> {
    npy::write(path, shape, data).map_err(|e| format!("{}: {e}", path.display()))
}

/// Solves the presses on the model's coarse gel and writes their features (see the module
/// docs). Returns a summary line.
pub fn write(config: &FeaturesConfig) -> Result<String, String> {
    let manifest = Manifest::load(&config.model).map_err(|e| e.to_string())?;
    let spec = manifest.lattice;
    let g = &manifest.gel;
    let recipe = &manifest.recipe;
    let params = GelParams {
        size: g.size,
        young: g.young,
        poisson: g.poisson,
        friction: g.friction,
        dx: recipe.dx,
        ..GelParams::default()
    };
    let material = tacrom::config::material_name(params.material);
    if material != recipe.material {
        return Err(format!(
            "{}: the model's coarse material is \"{}\", this tool solves \"{material}\"",
            config.model.display(),
            recipe.material
        ));
    }
    let options = SolverOptions {
        threads: config.threads,
        tolerance: recipe.tolerance,
        ..SolverOptions::default()
    };
    let mut gel = Gel::new(params, options).map_err(|e| e.to_string())?;
    std::fs::create_dir_all(&config.out).map_err(|e| format!("{}: {e}", config.out.display()))?;
    // What `data.load_dir` reads of a gen-data `dataset.json`, and what it is.
    let mut dataset = serde_json::json!({
        "format": "tacrom-rom-pairs-1",
        "channels": ["coarse", "penetration", "coarse (no reference solved)"],
        "units": "m",
        "size": g.size,
        "young": g.young,
        "poisson": g.poisson,
        "friction": g.friction,
        "material": recipe.material,
        "coarse_dx": recipe.dx,
        "pitch": spec.size[0] / spec.nx as f64,
        "lattice": [spec.ny, spec.nx],
        "written_by": "tacrom rom-features",
    });
    if let Some(c) = &manifest.conditioning {
        dataset["poisson_range"] = serde_json::json!(c.poisson);
        dataset["friction_range"] = serde_json::json!(c.friction);
    }
    write_json(&config.out.join("dataset.json"), &dataset)?;
    let (eps, grow) = manifest.region;
    let mut meta = FeaturesMeta {
        format: FORMAT.to_owned(),
        model: config.model.display().to_string(),
        size: g.size,
        coarse_dx: recipe.dx,
        lattice: spec,
        encoder_len: spec.encoder_len(),
        query_len: spec.query_len(),
        region: RegionMeta { eps_mm: eps, grow },
        presses: Vec::new(),
    };
    let (ny, nx) = (spec.ny, spec.nx);
    let mut obs = Observation::default();
    let (mut zmin, mut enc, mut query, mut mask) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut load = Vec::new();
    for (index, (name, indenters)) in presses(g.size).into_iter().enumerate() {
        let (placed, imeta): (Vec<Placed>, Vec<IndenterMeta>) = indenters.into_iter().unzip();
        gel.reset();
        let t0 = Instant::now();
        let report = gel.solve(&placed);
        let seconds = t0.elapsed().as_secs_f64();
        obs.update(&gel, &placed, &spec, &mut zmin);
        if let Some(c) = &manifest.conditioning {
            obs.material = c.inputs(params.poisson, params.friction).to_vec();
        }
        obs.encoder_input(&spec, &mut enc);
        obs.update_load(&gel, &spec);
        query.clear();
        load.clear();
        for row in 0..ny {
            for col in 0..nx {
                query_features(&obs, &spec, row, col, &mut query);
                load_window(&obs.pressure, &spec, row, col, &mut load);
            }
        }
        region(&obs, &spec, eps, grow, &mut Vec::new(), &mut mask);
        let stem = |what: &str| config.out.join(format!("{what}-{index:06}.npy"));
        write_array(
            &stem("sample"),
            &[3, ny, nx],
            &sample_array(&obs, &obs.coarse),
        )?;
        let exact: Vec<f64> = obs.coarse.iter().chain(&obs.pen).copied().collect();
        write_array(&stem("observation"), &[2, ny, nx], &exact)?;
        write_array(&stem("encoder"), &[enc.len()], &enc)?;
        write_array(&stem("query"), &[ny * nx, spec.query_len()], &query)?;
        write_array(&stem("pressure"), &[ny, nx], &obs.pressure)?;
        write_array(&stem("load"), &[ny * nx, spec.patch * spec.patch], &load)?;
        let mask_u8: Vec<u8> = mask.iter().map(|&b| u8::from(b)).collect();
        write_array(&stem("region"), &[ny, nx], &mask_u8)?;
        let coarse = SolveMeta::new(&report, seconds);
        write_json(
            &config.out.join(format!("sample-{index:06}.json")),
            &serde_json::json!({
                "index": index,
                "family": name,
                "held_out": false,
                "coarse": coarse,
                "reference": null,
            }),
        )?;
        let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
        meta.presses.push(PressMeta {
            index,
            name: name.to_owned(),
            indenters: imeta,
            max_penetration: max(&obs.pen),
            max_coarse: max(&obs.coarse),
            region_points: mask.iter().filter(|&&b| b).count(),
            coarse,
        });
    }
    write_json(&config.out.join("features.json"), &meta)?;
    Ok(format!(
        "{} presses on the {}x{} lattice of {} written to {}",
        meta.presses.len(),
        nx,
        ny,
        config.model.display(),
        config.out.display()
    ))
}
