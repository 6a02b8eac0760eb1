//! `tacrom eval-rom`: depth error of rigid, coarse and reduced-order models against the
//! reference of a `gen-data` data set, on its held-out indenter families.
//!
//! Every sample holds three lattice images (coarse depth, rigid penetration, reference
//! depth; see [`crate::datagen`]). Each model's encoder, refinement and decoder run on the
//! coarse image and penetration exactly as in the sensor, and the result is compared with
//! the reference over the sensor's default field of view (24 x 18 mm, the centre of the
//! lattice): depth MAE and RMSE, and SSIM with the reference's peak depth as its range
//! (the metrics of the press benchmark). Costs: the median wall time of one inference on
//! the 100 x 100 lattice (one ONNX Runtime thread), and the data set's own solve times of
//! the coarse and the reference press.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::metrics;
use super::BenchError;
use serde::de::DeserializeOwned;
use serde::Deserialize;

use crate::datagen::{self, read_npy, Dataset};
use crate::progress::Progress;
use tacrom::rom::features::{LatticeSpec, Observation};
use tacrom::rom::{Manifest, Rom, RomOptions};

/// Field of view the metrics cover (m), centred on the lattice.
pub const FOV: [f64; 2] = [0.024, 0.018];

/// What `tacrom eval-rom` runs.
#[derive(Clone, Debug)]
pub struct EvalOptions {
    /// Data set folders (`gen-data --out`).
    pub data: Vec<PathBuf>,
    /// Model folders; each gives a row as its manifest says (refinement on or off), the
    /// first also one without refinement.
    pub models: Vec<PathBuf>,
    /// Every model also gives a row with the latent refinement on (`MODEL-refined`): the
    /// refinement's ablation for each seed of a recipe.
    pub refined: bool,
    /// Every sample, not only held-out ones.
    pub all: bool,
    /// Another data set of the same presses (same seed and indices, e.g. the full set
    /// whose held-out presses `data` recomputes at a finer spacing): its reference gets a
    /// row of its own, to measure that reference against this one.
    pub compare: Option<PathBuf>,
    /// Where report.md, results.csv and forces.csv go.
    pub out: PathBuf,
}

/// Error of one method, averaged over the samples.
#[derive(Clone, Debug, Default)]
pub struct MethodRow {
    /// Label (rigid, coarse, a model folder's name, `-norefine` for the ablation).
    pub label: String,
    /// Depth MAE (m).
    pub mae: f64,
    /// Depth RMSE (m).
    pub rmse: f64,
    /// Mean SSIM.
    pub ssim: f64,
    /// Median wall time of one inference (s; 0 for rigid and coarse).
    pub infer_s: f64,
    /// Depth MAE per family (m), in [`EvalResult::families`] order.
    pub per_family: Vec<f64>,
    /// Mean over the presses of the depth MAE over the footprint: the points where the
    /// reference is deeper than 1 um (m).
    pub region_mae: f64,
    /// Per press, in the samples' order: depth MAE and footprint MAE (m).
    pub per_press: Vec<[f64; 2]>,
    /// Mean L-BFGS steps of the latent refinement per press (models only).
    pub steps: f64,
    /// Mean over the presses of how far the decoded surface lay inside the indenters, at
    /// its worst point, before the depth rule raised it (m; models only).
    pub into_indenter: f64,
    /// Mean over the presses of how far the decoded surface sank below the deepest
    /// indenter point before the depth rule capped it (m; models only).
    pub below_reach: f64,
    /// Median and 90th percentile of the relative error, against the reference's, of the
    /// normal force the model reports ([`tacrom::rom::Rom::force_factor_on`]: the coarse
    /// force scaled by the pressure head's force or by the decoded surface's volume for a
    /// model with a head or a `force` factor, the coarse force itself otherwise; models
    /// only, where the samples record forces).
    pub reported_force_error: Option<[f64; 2]>,
    /// Per press with both forces recorded: the press's file, the reference and the
    /// reported normal force (N), and the coarse, decoded and reference displaced volumes
    /// of the lattice (sum of depths, m).
    pub forces: Vec<ForceRow>,
}

/// One press of [`MethodRow::forces`].
#[derive(Clone, Debug, Default)]
pub struct ForceRow {
    /// The sample's array file.
    pub file: String,
    /// The sample's indenter family.
    pub family: String,
    /// The reference solve's normal force (N).
    pub reference: f64,
    /// The normal force the model reports (N).
    pub reported: f64,
    /// Displaced volumes of the lattice, coarse, decoded and reference (sum of the
    /// depths, m).
    pub volumes: [f64; 3],
}

/// The evaluation's result.
#[derive(Clone, Debug, Default)]
pub struct EvalResult {
    /// Samples evaluated.
    pub samples: usize,
    /// Families, sorted, with their sample counts.
    pub families: Vec<(String, usize)>,
    /// One row per method.
    pub rows: Vec<MethodRow>,
    /// Median solve time of the coarse and of the reference press (s).
    pub solve_s: [f64; 2],
    /// Reference grid spacing of each data set (m).
    pub reference_dx: Vec<f64>,
    /// Every sample was evaluated, not only held-out ones.
    pub all: bool,
    /// Per sample, in order: its file, family and, in a data set over the gel family,
    /// the thickness of the gel drawn (m).
    pub presses: Vec<(String, String, Option<f64>)>,
    /// The coarse solve's normal force against the reference's (which `rom` takes as it
    /// is), over the samples whose JSON records both and whose reference force exceeds
    /// 1 mN: count, median and 90th percentile of the relative error, and the median
    /// signed error.
    pub force_error: Option<(usize, f64, f64, f64)>,
}

struct Sample {
    file: std::ffi::OsString,
    family: String,
    obs: Observation,
    reference: Vec<f64>,
    solve_s: [f64; 2],
    /// Normal force of the coarse and of the reference solve (N), where recorded.
    force: Option<[f64; 2]>,
    /// Poisson's ratio and friction of the sample's gel.
    material: [f64; 2],
    /// The thickness of the gel drawn, in a data set over the gel family (m).
    thickness: Option<f64>,
    /// Whether the whole lattice is scored: a family data set's sample is the window over
    /// its contact, which need not lie in the field of view's middle.
    whole: bool,
}

fn bad(path: &Path, what: impl std::fmt::Display) -> BenchError {
    BenchError::Usage(format!("{}: {what}", path.display()))
}

fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T, BenchError> {
    let text = std::fs::read_to_string(path).map_err(|e| bad(path, e))?;
    serde_json::from_str(&text).map_err(|e| bad(path, e))
}

/// What the evaluation reads of a sample's JSON ([`crate::datagen::SampleMeta`]).
#[derive(Deserialize)]
struct SampleInfo {
    family: String,
    held_out: bool,
    coarse: Timing,
    reference: Timing,
    /// The sample's own material, where the data set draws it per sample.
    #[serde(default)]
    poisson: Option<f64>,
    #[serde(default)]
    friction: Option<f64>,
    /// The gel drawn, in a data set over the gel family.
    #[serde(default)]
    gel: Option<GelInfo>,
}

/// What the evaluation reads of a family sample's gel ([`crate::datagen::FamilyGel`]).
#[derive(Deserialize)]
struct GelInfo {
    size: [f64; 3],
}

/// The wall time of a solve and its force, where recorded.
#[derive(Deserialize)]
struct Timing {
    seconds: f64,
    #[serde(default)]
    force: Option<[f64; 3]>,
}

/// The samples of `dir` (held-out ones unless `all`), and the data set's reference spacing.
/// Its coarse channel must come from the coarse solver `solver` (the models'): a model fed
/// another solver's coarse surface is not the model a sensor runs.
fn load_samples(
    dir: &Path,
    spec: &LatticeSpec,
    all: bool,
    solver: &str,
) -> Result<(Vec<Sample>, f64), BenchError> {
    let dataset: Dataset = read_json(&dir.join("dataset.json"))?;
    // Data sets written before the recipe was recorded hold the relaxation's solves.
    let theirs = dataset
        .recipe
        .as_ref()
        .map_or("relaxation", |r| r.solver.as_str());
    if theirs != solver {
        return Err(bad(
            dir,
            format!(
                "coarse solves of the \"{theirs}\" solver, the models were trained on the \
                 \"{solver}\" solver's"
            ),
        ));
    }
    let lattice = dataset.lattice;
    if lattice != [spec.ny, spec.nx] {
        return Err(bad(
            dir,
            format!(
                "lattice {lattice:?}, the model's is [{}, {}]",
                spec.ny, spec.nx
            ),
        ));
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| bad(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension().is_some_and(|x| x == "npy")
                && p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with("sample-"))
                && p.with_extension("json").is_file()
        })
        .collect();
    files.sort();
    let n = spec.points();
    let mut out = Vec::new();
    for npy in files {
        let meta: SampleInfo = read_json(&npy.with_extension("json"))?;
        if !all && !meta.held_out {
            continue;
        }
        let (shape, data) = read_npy(&npy).map_err(|e| bad(&npy, e))?;
        if shape != [3, spec.ny, spec.nx] {
            return Err(bad(
                &npy,
                format!("shape {shape:?}, expected [3, {}, {}]", spec.ny, spec.nx),
            ));
        }
        let chan = |k: usize| {
            data[k * n..(k + 1) * n]
                .iter()
                .map(|&v| v as f64)
                .collect::<Vec<_>>()
        };
        out.push(Sample {
            file: npy.file_name().unwrap_or_default().to_owned(),
            family: meta.family,
            obs: {
                let pen = chan(1);
                Observation {
                    coarse: chan(0),
                    rule: tacrom::render::DepthRule::from_penetration(spec.size[2], &pen),
                    pen,
                    material: Vec::new(),
                    poisson: meta.poisson.unwrap_or(dataset.poisson),
                    // The coarse load of a pressure head, where the data set records it.
                    pressure: load_pressure(&npy, n)?,
                    force: meta.coarse.force.map_or(0.0, |f| f[2]),
                    // The data set's lattice is the model's: the window is all of it.
                    origin: [0, 0],
                    mapped: None,
                }
            },
            material: [
                meta.poisson.unwrap_or(dataset.poisson),
                meta.friction.unwrap_or(dataset.friction),
            ],

            reference: chan(2),
            thickness: meta.gel.map(|g| g.size[2]),
            whole: dataset.gel_family.is_some(),
            solve_s: [meta.coarse.seconds, meta.reference.seconds],
            force: meta
                .coarse
                .force
                .zip(meta.reference.force)
                .map(|(c, r)| [c[2], r[2]]),
        });
    }
    Ok((out, dataset.fine_dx))
}

/// Channel 0 (the coarse gel's contact pressure, Pa) of the pressure companion of the
/// sample `npy`, where it has one (`n` lattice points); empty otherwise.
fn load_pressure(npy: &Path, n: usize) -> Result<Vec<f64>, BenchError> {
    let stem = npy.with_extension("");
    let path = datagen::pressure_path(&stem);
    if !path.is_file() {
        return Ok(Vec::new());
    }
    let (shape, data) = read_npy(&path).map_err(|e| bad(&path, e))?;
    if shape.len() != 3 || shape[0] != 2 || shape[1] * shape[2] != n {
        return Err(bad(&path, format!("shape {shape:?}, expected [2, ny, nx]")));
    }
    Ok(data[..n].iter().map(|&v| v as f64).collect())
}

/// The field of view's lattice window: `(x0, y0, width, height)`.
fn window(spec: &LatticeSpec) -> (usize, usize, usize, usize) {
    let pitch = spec.size[0] / spec.nx as f64;
    let w = ((FOV[0] / pitch).round() as usize).min(spec.nx);
    let h = ((FOV[1] / pitch).round() as usize).min(spec.ny);
    ((spec.nx - w) / 2, (spec.ny - h) / 2, w, h)
}

fn crop(spec: &LatticeSpec, img: &[f64]) -> Vec<f64> {
    let (x0, y0, w, h) = window(spec);
    (y0..y0 + h)
        .flat_map(|r| img[r * spec.nx + x0..r * spec.nx + x0 + w].iter().copied())
        .collect()
}

/// MAE, RMSE and SSIM of `img` against `reference` over the field of view (the whole
/// lattice where `whole`), and the MAE over the footprint: the points where the reference
/// is deeper than 1 um (0 where there are none).
fn score(spec: &LatticeSpec, img: &[f64], reference: &[f64], whole: bool) -> [f64; 4] {
    let (w, h, a, r) = if whole {
        (spec.nx, spec.ny, img.to_vec(), reference.to_vec())
    } else {
        let (_, _, w, h) = window(spec);
        (w, h, crop(spec, img), crop(spec, reference))
    };
    let peak = r.iter().copied().fold(0.0f64, f64::max);
    let (mut sum, mut n) = (0.0, 0usize);
    for (x, y) in img.iter().zip(reference) {
        if *y > 1e-6 {
            sum += (x - y).abs();
            n += 1;
        }
    }
    [
        metrics::mae(&a, &r),
        metrics::rmse(&a, &r),
        metrics::ssim(&a, &r, w, h, peak).unwrap_or(f64::NAN),
        if n > 0 { sum / n as f64 } else { 0.0 },
    ]
}

/// Accumulates one method's scores.
struct Acc {
    row: MethodRow,
    ssim_n: usize,
    times: Vec<f64>,
    family_sum: Vec<f64>,
}

impl Acc {
    fn new(label: &str, families: usize) -> Self {
        Acc {
            row: MethodRow {
                label: label.to_owned(),
                ..Default::default()
            },
            ssim_n: 0,
            times: Vec::new(),
            family_sum: vec![0.0; families],
        }
    }

    fn add(&mut self, s: [f64; 4], family: usize) {
        self.row.mae += s[0];
        self.row.region_mae += s[3];
        self.row.per_press.push([s[0], s[3]]);
        self.row.rmse += s[1];
        if s[2].is_finite() {
            self.row.ssim += s[2];
            self.ssim_n += 1;
        }
        self.family_sum[family] += s[0];
    }

    fn finish(mut self, samples: usize, counts: &[usize]) -> MethodRow {
        let k = samples.max(1) as f64;
        self.row.mae /= k;
        self.row.region_mae /= k;
        self.row.rmse /= k;
        self.row.steps /= k;
        self.row.into_indenter /= k;
        self.row.below_reach /= k;
        self.row.ssim = if self.ssim_n > 0 {
            self.row.ssim / self.ssim_n as f64
        } else {
            f64::NAN
        };
        self.row.infer_s = if self.times.is_empty() {
            0.0
        } else {
            metrics::median(&self.times)
        };
        self.row.per_family = self
            .family_sum
            .iter()
            .zip(counts)
            .map(|(s, &c)| s / c.max(1) as f64)
            .collect();
        self.row
    }
}

fn label_of(dir: &Path) -> String {
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| dir.display().to_string());
    match name.strip_prefix("rom-") {
        Some("default") => "rom".to_owned(),
        Some(rest) => format!("rom-{rest}"),
        None => name,
    }
}

/// Runs the evaluation and writes report.md, results.csv, forces.csv (per press with
/// both forces recorded: reference and reported force, displaced volumes) and presses.csv
/// (per press and method: depth MAE, footprint MAE) into `options.out`.
pub fn run(options: &EvalOptions) -> Result<EvalResult, BenchError> {
    let Some(first) = options.models.first() else {
        return Err(BenchError::Usage("eval-rom: no model given".to_owned()));
    };
    let load = |dir: &Path, refine: Option<bool>| {
        Rom::load(
            dir,
            RomOptions {
                refine,
                threads: 1,
                // The force each model reports; no pressure image.
                pressure: false,
                force: true,
            },
        )
        .map_err(|e| BenchError::Config(e.to_string()))
    };
    let manifests = options
        .models
        .iter()
        .map(|m| Manifest::load(m).map_err(|e| BenchError::Config(e.to_string())))
        .collect::<Result<Vec<_>, _>>()?;
    let solver = manifests[0].recipe.solver.clone();
    if let Some(m) = manifests.iter().find(|m| m.recipe.solver != solver) {
        return Err(BenchError::Usage(format!(
            "eval-rom: the models were trained on different coarse solvers (\"{solver}\" and \
             \"{}\"); compare models of one solver on its data",
            m.recipe.solver
        )));
    }
    let spec = manifests[0].lattice;
    let mut samples = Vec::new();
    let mut result = EvalResult::default();
    for dir in &options.data {
        let (s, dx) = load_samples(dir, &spec, options.all, &solver)?;
        samples.extend(s);
        result.reference_dx.push(dx);
    }
    if samples.is_empty() {
        return Err(BenchError::Usage(format!(
            "eval-rom: no {}samples in {:?}",
            if options.all { "" } else { "held-out " },
            options.data
        )));
    }
    let mut names: Vec<String> = samples.iter().map(|s| s.family.clone()).collect();
    names.sort();
    names.dedup();
    let fam: Vec<usize> = samples
        .iter()
        .map(|s| names.binary_search(&s.family).unwrap_or(0))
        .collect();
    let mut counts = vec![0usize; names.len()];
    for &f in &fam {
        counts[f] += 1;
    }

    let mut rigid = Acc::new("rigid", names.len());
    let mut coarse = Acc::new("coarse", names.len());
    for (s, &f) in samples.iter().zip(&fam) {
        rigid.add(score(&spec, &s.obs.pen, &s.reference, s.whole), f);
        coarse.add(score(&spec, &s.obs.coarse, &s.reference, s.whole), f);
    }
    result.rows.push(rigid.finish(samples.len(), &counts));
    result.rows.push(coarse.finish(samples.len(), &counts));
    if let Some(dir) = &options.compare {
        let dx = read_json::<Dataset>(&dir.join("dataset.json"))?.fine_dx;
        let mut other = Acc::new(&format!("reference-{:.1}mm", dx * 1e3), names.len());
        for (s, &f) in samples.iter().zip(&fam) {
            let path = dir.join(&s.file);
            let (shape, data) = read_npy(&path).map_err(|e| bad(&path, e))?;
            if shape != [3, spec.ny, spec.nx] {
                return Err(bad(&path, format!("shape {shape:?}")));
            }
            let n = spec.points();
            let r: Vec<f64> = data[2 * n..].iter().map(|&v| v as f64).collect();
            other.add(score(&spec, &r, &s.reference, s.whole), f);
        }
        result.rows.push(other.finish(samples.len(), &counts));
    }
    let mut runs: Vec<(String, &PathBuf, Option<bool>)> = options
        .models
        .iter()
        .map(|m| (label_of(m), m, None))
        .collect();
    runs.insert(
        1.min(runs.len()),
        (format!("{}-norefine", label_of(first)), first, Some(false)),
    );
    if options.refined {
        runs.extend(
            options
                .models
                .iter()
                .map(|m| (format!("{}-refined", label_of(m)), m, Some(true))),
        );
    }
    let bar = Progress::new(runs.len() * samples.len(), true);
    for (label, dir, refine) in runs {
        bar.message(label.clone());
        let mut rom = load(dir, refine)?;
        // The same lattice; the material inputs may differ (a conditioned model has them).
        let lattice = LatticeSpec {
            material_inputs: spec.material_inputs,
            ..rom.manifest().lattice
        };
        if lattice != spec {
            return Err(bad(dir, "its lattice differs from the first model's"));
        }
        let mut acc = Acc::new(&label, names.len());
        let mut force_errors = Vec::new();
        let mut forces = Vec::new();
        for (s, &f) in samples.iter_mut().zip(&fam) {
            rom.set_material(&mut s.obs, s.material[0], s.material[1]);
            let t0 = Instant::now();
            let report = rom
                .infer(&s.obs)
                .map_err(|e| BenchError::Config(e.to_string()))?;
            acc.times.push(t0.elapsed().as_secs_f64());
            acc.row.steps += report.refinement.map_or(0, |r| r.iterations) as f64;
            acc.row.into_indenter += report.penetration_excess;
            acc.row.below_reach += report.bound_excess.max(0.0);
            if let Some([fc, fr]) = s.force.filter(|f| f[1] > 1e-3) {
                let reported = fc * rom.force_factor_on(&s.obs);
                force_errors.push((reported / fr - 1.0).abs());
                forces.push(ForceRow {
                    file: s.file.to_string_lossy().into_owned(),
                    family: s.family.clone(),
                    reference: fr,
                    reported,
                    volumes: [
                        s.obs.coarse.iter().sum(),
                        rom.lattice_depth().iter().sum(),
                        s.reference.iter().sum(),
                    ],
                });
            }
            acc.add(score(&spec, rom.lattice_depth(), &s.reference, s.whole), f);
            bar.advance(1);
        }
        let mut row = acc.finish(samples.len(), &counts);
        row.forces = forces;
        row.reported_force_error = (!force_errors.is_empty()).then(|| {
            force_errors.sort_by(f64::total_cmp);
            let n = force_errors.len();
            let p90 = force_errors[((n as f64 * 0.9).ceil() as usize).clamp(1, n) - 1];
            [metrics::median(&force_errors), p90]
        });
        result.rows.push(row);
    }
    bar.finish();
    let median_of = |k: usize| {
        let v: Vec<f64> = samples
            .iter()
            .map(|s| s.solve_s[k])
            .filter(|t| t.is_finite())
            .collect();
        metrics::median(&v)
    };
    result.solve_s = [median_of(0), median_of(1)];
    let mut errors: Vec<f64> = samples
        .iter()
        .filter_map(|s| s.force)
        .filter(|f| f[1] > 1e-3)
        .map(|f| f[0] / f[1] - 1.0)
        .collect();
    if !errors.is_empty() {
        let median_signed = metrics::median(&errors);
        for e in &mut errors {
            *e = e.abs();
        }
        errors.sort_by(f64::total_cmp);
        let p90 = errors[((errors.len() as f64 * 0.9).ceil() as usize).clamp(1, errors.len()) - 1];
        result.force_error = Some((errors.len(), metrics::median(&errors), p90, median_signed));
    }
    result.samples = samples.len();
    result.all = options.all;
    result.presses = samples
        .iter()
        .map(|s| {
            (
                s.file.to_string_lossy().into_owned(),
                s.family.clone(),
                s.thickness,
            )
        })
        .collect();
    result.families = names.into_iter().zip(counts).collect();
    write(options, &result)?;
    Ok(result)
}

/// The report as markdown.
pub fn markdown(r: &EvalResult) -> String {
    let mut s = String::new();
    let dx: Vec<String> = r
        .reference_dx
        .iter()
        .map(|d| format!("{:.2} mm", d * 1e3))
        .collect();
    let _ = writeln!(
        s,
        "## Reduced-order model on {}\n\n{} samples, reference dx {}; \
         field of view {} x {} mm. Solve times (median, from the data set): coarse {:.2} s, \
         reference {:.1} s per press from rest.\n",
        if r.all {
            "all families"
        } else {
            "held-out families"
        },
        r.samples,
        dx.join(", "),
        FOV[0] * 1e3,
        FOV[1] * 1e3,
        r.solve_s[0],
        r.solve_s[1]
    );
    let _ = writeln!(
        s,
        "| method | MAE um | RMSE um | SSIM | MAE / coarse | footprint MAE um | inference ms | \
         refinement steps | into the indenter um | below the deepest point um |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|");
    let coarse = r
        .rows
        .iter()
        .find(|m| m.label == "coarse")
        .map_or(f64::NAN, |m| m.mae);
    for m in &r.rows {
        let _ = writeln!(
            s,
            "| {} | {:.2} | {:.2} | {:.4} | {:.2} | {:.2} | {:.1} | {} |",
            m.label,
            m.mae * 1e6,
            m.rmse * 1e6,
            m.ssim,
            m.mae / coarse,
            m.region_mae * 1e6,
            m.infer_s * 1e3,
            if m.infer_s > 0.0 {
                format!(
                    "{:.1} | {:.2} | {:.2}",
                    m.steps,
                    m.into_indenter * 1e6,
                    m.below_reach * 1e6
                )
            } else {
                "- | - | -".to_owned()
            }
        );
    }
    if let Some((n, median, p90, signed)) = r.force_error {
        let _ = writeln!(
            s,
            "\nNormal force of the coarse solve against the reference's, \
             over the {n} presses with more than 1 mN: median error {:.1} %, 90th percentile \
             {:.1} %, median signed error {:+.1} %.",
            median * 100.0,
            p90 * 100.0,
            signed * 100.0
        );
        for m in r.rows.iter().filter(|m| m.reported_force_error.is_some()) {
            let _ = writeln!(
                s,
                "- {}: the normal force the model reports: median error {:.1} %, 90th percentile \
                 {:.1} %",
                m.label,
                m.reported_force_error.map_or(f64::NAN, |e| e[0]) * 100.0,
                m.reported_force_error.map_or(f64::NAN, |e| e[1]) * 100.0
            );
        }
    }
    let _ = write!(s, "\nMAE um per family:\n\n");
    method_columns(r, "family", &mut s);
    for (i, (name, count)) in r.families.iter().enumerate() {
        let _ = write!(s, "| {name} | {count} |");
        for m in &r.rows {
            let _ = write!(s, " {:.2} |", m.per_family[i] * 1e6);
        }
        s.push('\n');
    }
    by_thickness(r, &mut s);
    s
}

/// The header of a table with a column per method: `first`, the samples, the methods.
fn method_columns(r: &EvalResult, first: &str, s: &mut String) {
    let _ = write!(s, "| {first} | samples |");
    for m in &r.rows {
        let _ = write!(s, " {} |", m.label);
    }
    let _ = write!(s, "\n|---|---|");
    for _ in &r.rows {
        let _ = write!(s, "---|");
    }
    s.push('\n');
}

/// Bins of the gel's thickness (m) of [`by_thickness`], with their names.
const THICKNESS_BINS: [(&str, f64, f64); 3] = [
    ("thin, 1 to 2 mm", 0.0, 2e-3),
    ("2 to 5 mm", 2e-3, 5e-3),
    ("thick, 5 to 6 mm", 5e-3, f64::INFINITY),
];

/// The footprint MAE per bin of the gel's thickness, each method's and its ratio to
/// coarse's, for a data set over the gel family (nothing otherwise).
fn by_thickness(r: &EvalResult, s: &mut String) {
    if r.presses.iter().all(|p| p.2.is_none()) {
        return;
    }
    let _ = write!(
        s,
        "\nFootprint MAE um by the gel's thickness (and over coarse's):\n\n"
    );
    method_columns(r, "gel", s);
    let coarse = r.rows.iter().position(|m| m.label == "coarse");
    for (name, lo, hi) in THICKNESS_BINS {
        let inside: Vec<usize> = (0..r.presses.len())
            .filter(|&i| r.presses[i].2.is_some_and(|t| t > lo && t <= hi))
            .collect();
        if inside.is_empty() {
            continue;
        }
        let mean = |m: &MethodRow| {
            inside.iter().map(|&i| m.per_press[i][1]).sum::<f64>() / inside.len() as f64
        };
        let _ = write!(s, "| {name} | {} |", inside.len());
        let c = coarse.map_or(f64::NAN, |k| mean(&r.rows[k]));
        for m in &r.rows {
            let v = mean(m);
            let _ = write!(s, " {:.2} ({:.2}) |", v * 1e6, v / c);
        }
        s.push('\n');
    }
}

fn write(options: &EvalOptions, r: &EvalResult) -> Result<(), BenchError> {
    let out = &options.out;
    let fail = |p: &Path, e: std::io::Error| BenchError::Output {
        path: p.to_owned(),
        message: e.to_string(),
    };
    std::fs::create_dir_all(out).map_err(|e| fail(out, e))?;
    let md = out.join("report.md");
    std::fs::write(&md, markdown(r)).map_err(|e| fail(&md, e))?;
    let mut csv = String::from("method,mae_m,rmse_m,ssim,inference_s\n");
    for m in &r.rows {
        let _ = writeln!(
            csv,
            "{},{:e},{:e},{},{:e}",
            m.label, m.mae, m.rmse, m.ssim, m.infer_s
        );
    }
    let path = out.join("results.csv");
    std::fs::write(&path, csv).map_err(|e| fail(&path, e))?;
    let mut csv = String::from(
        "method,sample,family,force_reference_n,force_reported_n,volume_coarse_m,volume_decoded_m,volume_reference_m\n",
    );
    for m in &r.rows {
        for f in &m.forces {
            let _ = writeln!(
                csv,
                "{},{},{},{:e},{:e},{:e},{:e},{:e}",
                m.label,
                f.file,
                f.family,
                f.reference,
                f.reported,
                f.volumes[0],
                f.volumes[1],
                f.volumes[2]
            );
        }
    }
    let path = out.join("forces.csv");
    std::fs::write(&path, csv).map_err(|e| fail(&path, e))?;
    let mut csv = String::from("method,sample,family,thickness_m,mae_m,footprint_mae_m\n");
    for m in &r.rows {
        for ((file, family, t), e) in r.presses.iter().zip(&m.per_press) {
            let t = t.map_or(String::new(), |t| format!("{t:e}"));
            let _ = writeln!(csv, "{},{file},{family},{t},{:e},{:e}", m.label, e[0], e[1]);
        }
    }
    let path = out.join("presses.csv");
    std::fs::write(&path, csv).map_err(|e| fail(&path, e))
}
