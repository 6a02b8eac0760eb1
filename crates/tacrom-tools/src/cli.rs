//! The command line of `tacrom`: one parser for every subcommand.
//!
//! Lengths on the command line are in millimetres everywhere (positions, depths, radii,
//! grid spacings, lattice pitch); the parsers here turn them into the metres that the rest
//! of the code uses. Resolutions are `WxH` in pixels, thread counts and sizes are plain
//! numbers.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand, ValueEnum};

use crate::bench::protocol::ModeSpec;
use crate::calibrate::{self, fit::FitOptions};

/// Said at the end of `tacrom --help` and of every subcommand's help.
const UNITS: &str = "Lengths are in millimetres everywhere (MM in the option lists); \
                     files and reports are in SI units (metres).";

/// `tacrom --version`: the version and the physics' fingerprints, which name the solver in
/// the benchmark's reference cache (`tacrom bench --adopt-physics`).
static LONG_VERSION: std::sync::LazyLock<String> = std::sync::LazyLock::new(|| {
    format!(
        "{}\nphysics {}\nrelaxation {}",
        env!("CARGO_PKG_VERSION"),
        tacrom::PHYSICS_FINGERPRINT,
        tacrom::RELAXATION_FINGERPRINT
    )
});

/// tacrom: tools for the tacrom tactile sensor.
#[derive(Debug, Parser)]
#[command(name = "tacrom", version, long_version = LONG_VERSION.as_str(), after_help = UNITS,
    propagate_version = true)]
pub struct Cli {
    /// The subcommand.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Error against run time of every physics mode, against a cached fine-MPM reference.
    Bench(BenchArgs),
    /// Press one indenter and write its depth image as a PNG with a colour bar.
    Render(RenderArgs),
    /// The stability suite's table per mode; fails if a case fails.
    Stability(StabilityArgs),
    /// Hertz validation of the gel and the MPM solver's cost per grid spacing.
    Mpm(MpmArgs),
    /// Paired coarse / reference presses for training the reduced-order model.
    GenData(GenDataArgs),
    /// Rigid, coarse and reduced-order models against gen-data references.
    EvalRom(EvalRomArgs),
    /// Developer tool: a model's inputs (coarse lattice, encoder input, query features,
    /// region) for fixed presses, for the training side's feature-parity test.
    RomFeatures(RomFeaturesArgs),
    /// Fit the rgb output's optics (gradient-to-colour table and background) to ball
    /// presses, or write a synthetic press set.
    Calibrate(CalibrateArgs),
    /// A sensor file's images against a device's own ball presses: per row (background,
    /// rigid, the sensor file's gel, other gels, other renderers' images) MAE, SSIM and
    /// PSNR over each held-out press's region and its whole image.
    Compare(CompareArgs),
    /// Developer measurements of one solver question each (`tacrom probe --help` lists
    /// them; each probe's module doc says its arguments).
    Probe(ProbeArgs),
    /// Check the README's attribute and output tables against the plugin's (or, with
    /// `--write`, rewrite them).
    DocTables(DocTablesArgs),
}

/// `tacrom doc-tables [--write] [--readme PATH]`.
#[derive(Debug, Args)]
pub struct DocTablesArgs {
    /// Rewrite the tables in place instead of checking them.
    #[arg(long)]
    pub write: bool,
    /// The file holding the tables (default: the checkout's README.md).
    #[arg(long)]
    pub readme: Option<std::path::PathBuf>,
}

/// `tacrom probe NAME [ARGS...]`.
#[derive(Debug, Args)]
pub struct ProbeArgs {
    /// The probe.
    #[arg(value_parser = clap::builder::PossibleValuesParser::new(crate::probe::NAMES))]
    pub name: String,
    /// Its arguments, passed on as they are.
    #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
    pub args: Vec<String>,
}

/// A length in millimetres, finite, as metres.
pub fn mm(s: &str) -> Result<f64, String> {
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .map(|v| v / 1e3)
        .ok_or_else(|| format!("'{s}' is not a length in mm"))
}

/// A positive length in millimetres, as metres.
pub fn positive_mm(s: &str) -> Result<f64, String> {
    match mm(s) {
        Ok(v) if v > 0.0 => Ok(v),
        _ => Err(format!("'{s}' is not a positive length in mm")),
    }
}

/// `WxH` in pixels.
pub fn resolution(s: &str) -> Result<[usize; 2], String> {
    s.split_once(['x', 'X'])
        .and_then(|(w, h)| Some([w.trim().parse().ok()?, h.trim().parse().ok()?]))
        .ok_or_else(|| format!("'{s}' is not WxH"))
}

/// `KEY=VALUE`, both trimmed.
pub fn key_value(s: &str) -> Result<(String, String), String> {
    s.split_once('=')
        .map(|(k, v)| (k.trim().to_owned(), v.trim().to_owned()))
        .ok_or_else(|| format!("'{s}' is not KEY=VALUE"))
}

/// `K/N` with `K < N`.
pub fn shard(s: &str) -> Result<(usize, usize), String> {
    s.split_once('/')
        .and_then(|(k, n)| Some((k.trim().parse().ok()?, n.trim().parse().ok()?)))
        .filter(|&(k, n): &(usize, usize)| n > 0 && k < n)
        .ok_or_else(|| format!("'{s}' is not K/N with K < N"))
}

/// A whole number of at least one.
fn at_least_one(s: &str) -> Result<usize, String> {
    s.trim()
        .parse::<usize>()
        .ok()
        .filter(|&n| n >= 1)
        .ok_or_else(|| format!("'{s}' is not a whole number of at least 1"))
}

/// A solver tolerance in `(0, 1)`.
fn tolerance(s: &str) -> Result<f64, String> {
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|t| *t > 0.0 && *t < 1.0)
        .ok_or_else(|| format!("'{s}' is not a tolerance in (0, 1)"))
}

fn mode_spec(s: &str) -> Result<ModeSpec, String> {
    ModeSpec::parse(s).map_err(|e| e.to_string())
}

/// Options of `tacrom bench`. Options left out take the profile's value.
#[derive(Debug, Args)]
#[command(after_help = UNITS, allow_negative_numbers = true)]
pub struct BenchArgs {
    /// Two patterns, centre only, depths 0.2 0.5 1.0 mm, 64x48, 0.7 mm reference (a few
    /// minutes, cold cache included).
    #[arg(long, conflicts_with = "full")]
    pub quick: bool,
    /// Every pattern, 3x3 grid, depths 0.1..0.5 and 1.0 mm, 320x240, 0.3 mm reference (the
    /// default profile; resumable).
    #[arg(long)]
    pub full: bool,
    /// Folder of STL/OBJ meshes [../shared/indenters/patterns, or the copies in
    /// tests/data when that folder is absent].
    #[arg(long, value_name = "DIR")]
    pub indenters: Option<PathBuf>,
    /// Mesh coordinate scale to metres [0.001].
    #[arg(long, value_name = "S")]
    pub scale: Option<f64>,
    /// Press with the mesh's bottom, not its top face.
    #[arg(long)]
    pub no_flip: bool,
    /// Only these meshes (file stems).
    #[arg(long, value_name = "NAME", value_delimiter = ',')]
    pub only: Vec<String>,
    /// At most N meshes.
    #[arg(long, value_name = "N")]
    pub limit: Option<usize>,
    /// N x N positions [3; quick 1].
    #[arg(long, value_name = "N")]
    pub grid: Option<usize>,
    /// Spacing of the positions [2].
    #[arg(long, value_name = "MM", value_parser = mm)]
    pub spacing: Option<f64>,
    /// Depths of each press sequence, increasing.
    #[arg(long, value_name = "MM", value_delimiter = ',', value_parser = mm)]
    pub depths: Vec<f64>,
    /// A mode to compare (repeatable; replaces the default list): a name (rigid, coarse,
    /// rom, ...) or LABEL:key=value,key=value.
    #[arg(long = "mode", value_name = "SPEC", value_parser = mode_spec)]
    pub modes: Vec<ModeSpec>,
    /// Grid spacing of the fine reference [0.3; quick 0.7].
    #[arg(long, value_name = "MM", value_parser = positive_mm)]
    pub reference_dx: Option<f64>,
    /// Solver threads of the reference [2].
    #[arg(long, value_name = "N")]
    pub reference_threads: Option<usize>,
    /// Thread counts each mode runs with [1,2].
    #[arg(long, value_name = "N", value_delimiter = ',')]
    pub threads: Vec<usize>,
    /// Image size [320x240; quick 64x48].
    #[arg(long, value_name = "WxH", value_parser = resolution)]
    pub resolution: Option<[usize; 2]>,
    /// A sensor attribute for all modes (young, poisson, size, ...); repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE", value_parser = key_value)]
    pub attrs: Vec<(String, String)>,
    /// Reference cache [out/bench-cache].
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
    /// Compute the reference, store nothing.
    #[arg(long, conflicts_with = "cache")]
    pub no_cache: bool,
    /// Report folder [out/bench/<profile>].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Press panels to draw [4; quick 2].
    #[arg(long, value_name = "N")]
    pub panels: Option<usize>,
    /// No progress bar or progress lines.
    #[arg(long)]
    pub quiet: bool,
    /// Compare the accuracy rows with this baseline (see `bench/check.rs`); exit non-zero
    /// when a check fails.
    #[arg(long, value_name = "FILE")]
    pub check: Option<PathBuf>,
    /// Compare each mode's depth MAE over coarse's with the committed full profile FILE
    /// (within the range of its indenters; see `bench/check.rs`); exit non-zero when not.
    #[arg(long, value_name = "FILE")]
    pub check_full: Option<PathBuf>,
    /// Write this run's accuracy rows as the baseline FILE.
    #[arg(long, value_name = "FILE")]
    pub write_baseline: Option<PathBuf>,
    /// Only the indenters whose index in the sorted list is K modulo N (one shard of a
    /// batch job; see --reference-only).
    #[arg(long, value_name = "K/N", default_value = "0/1", value_parser = shard)]
    pub shard: (usize, usize),
    /// Compute and cache the reference presses only (no modes, no report): run the shards
    /// of a batch job with it, then the whole benchmark finds every press in the cache.
    #[arg(long, conflicts_with_all = ["check", "check_full", "write_baseline", "no_cache"])]
    pub reference_only: bool,
    /// Take over the cached reference presses of a build whose physics fingerprint was HEX
    /// (`tacrom --version` prints a build's) under today's keys, where today's have none:
    /// for a cache written before a change its presses do not depend on. Check a few
    /// presses recomputed (--cache elsewhere) against the adopted ones before trusting it.
    #[arg(long, value_name = "HEX", conflicts_with = "no_cache")]
    pub adopt_physics: Option<String>,
}

/// Options of `tacrom render`.
#[derive(Debug, Args)]
#[command(after_help = UNITS, allow_negative_numbers = true)]
pub struct RenderArgs {
    /// STL/OBJ indenter (with --scale, --no-flip).
    #[arg(long, value_name = "FILE")]
    pub mesh: Option<PathBuf>,
    /// Mesh coordinate scale to metres.
    #[arg(long, value_name = "S", default_value_t = 1e-3)]
    pub scale: f64,
    /// Press with the mesh's bottom, not its top face.
    #[arg(long)]
    pub no_flip: bool,
    /// Or a sphere of this radius.
    #[arg(long = "sphere", value_name = "MM", default_value = "5", value_parser = positive_mm)]
    pub radius: f64,
    /// Indentation.
    #[arg(long, value_name = "MM", default_value = "0.5", value_parser = mm)]
    pub depth: f64,
    /// x of the footprint's centre.
    #[arg(long, value_name = "MM", default_value = "0", value_parser = mm)]
    pub x: f64,
    /// y of the footprint's centre.
    #[arg(long, value_name = "MM", default_value = "0", value_parser = mm)]
    pub y: f64,
    /// rigid, coarse, fine, ... [rigid].
    #[arg(long, value_name = "P")]
    pub physics: Option<String>,
    /// Image size [320x240].
    #[arg(long, value_name = "WxH", value_parser = resolution)]
    pub resolution: Option<[usize; 2]>,
    /// Any sensor attribute; repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE", value_parser = key_value)]
    pub attrs: Vec<(String, String)>,
    /// Output PNG.
    #[arg(long, value_name = "FILE", default_value = "out/render.png")]
    pub out: PathBuf,
}

/// Options of `tacrom stability`: stiff and near-incompressible gels, deep, sharp,
/// jumping, rotating, sliding, through-the-gel presses, non-finite poses (see
/// src/stability.rs); one markdown table per mode.
#[derive(Debug, Args)]
#[command(after_help = UNITS)]
pub struct StabilityArgs {
    /// Modes to run.
    #[arg(
        long,
        value_name = "P",
        value_delimiter = ',',
        default_value = "rigid,coarse"
    )]
    pub physics: Vec<String>,
    /// MPM grid spacing [the mode's default].
    #[arg(long, value_name = "MM", value_parser = positive_mm)]
    pub dx: Option<f64>,
    /// Equilibrium solver of the gel modes [the gel's own choice].
    #[arg(long, value_name = "NAME", value_parser = solver_name)]
    pub solver: Option<tacrom::mpm::Solver>,
    /// Reduced-order model directory of `rom` [the shipped one for its solver].
    #[arg(long, value_name = "DIR")]
    pub model: Option<std::path::PathBuf>,
}

/// The part of `tacrom mpm` to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum MpmPart {
    /// Hertz validation only.
    Hertz,
    /// Solver cost only.
    Speed,
    /// Work per frame against Young's modulus and Poisson's ratio only.
    Work,
    /// Small contacts (a 0.5 mm sphere and a cone tip) on the coarse grid only.
    Small,
}

/// Options of `tacrom mpm`: Hertz contact on a bonded layer (frictionless sphere,
/// R = 5 mm, force error per depth and grid spacing) and the solver's cost in a moving
/// press (ms per frame, iterations, particle-steps/s, bytes per particle) per grid spacing
/// and thread count, the work per frame against the material, and small contacts (a 0.5 mm
/// sphere and a cone tip on the coarse grid). Writes report.md, hertz.csv, speed.csv,
/// work.csv and small.csv into --out.
#[derive(Debug, Args)]
#[command(after_help = UNITS)]
pub struct MpmArgs {
    /// Add the fine spacing 0.3 mm (about 1e6 particles; 30-60 min).
    #[arg(long)]
    pub fine: bool,
    /// Spacings of both parts [1.4,1.0,0.7,0.5].
    #[arg(long, value_name = "MM", value_delimiter = ',', value_parser = positive_mm)]
    pub dx: Vec<f64>,
    /// Hertz depths [0.1,0.2,0.3,0.4,0.5].
    #[arg(long, value_name = "MM", value_delimiter = ',', value_parser = positive_mm)]
    pub depths: Vec<f64>,
    /// Thread counts of the cost runs [1,2].
    #[arg(long, value_name = "N", value_delimiter = ',',
          value_parser = at_least_one)]
    pub threads: Vec<usize>,
    /// Measured frames per cost run [12; 3 below 0.5 mm].
    #[arg(long, value_name = "N", value_parser = at_least_one)]
    pub frames: Option<usize>,
    /// Solver tolerances of the cost runs [1e-3,3e-3,1e-2].
    #[arg(long, value_name = "T", value_delimiter = ',', value_parser = tolerance)]
    pub tolerances: Vec<f64>,
    /// Run one part only.
    #[arg(long, value_enum)]
    pub only: Option<MpmPart>,
    /// Equilibrium solvers, each measured on every row, side by side [relaxation].
    #[arg(long, value_name = "NAME", value_delimiter = ',', value_parser = solver_name)]
    pub solver: Vec<tacrom::mpm::Solver>,
    /// The gel's friction coefficient in the cost runs [0.5].
    #[arg(long, value_name = "MU", value_parser = non_negative)]
    pub friction: Option<f64>,
    /// Report folder.
    #[arg(long, value_name = "DIR", default_value = "out/bench/mpm")]
    pub out: PathBuf,
    /// No progress bar or progress lines.
    #[arg(long)]
    pub quiet: bool,
}

/// Options of `tacrom gen-data`: paired coarse / reference presses for the reduced-order
/// model (see src/datagen.rs). Resumable: samples already in --out are skipped.
#[derive(Debug, Args)]
#[command(after_help = UNITS)]
pub struct GenDataArgs {
    /// Output directory.
    #[arg(long, value_name = "DIR", default_value = "data/rom")]
    pub out: PathBuf,
    /// Total samples of the data set (all shards).
    #[arg(long, value_name = "N", default_value_t = 100)]
    pub samples: usize,
    /// This shard and the number of shards: does every N-th of the selected samples (all,
    /// or those of --indices and --held-out-only) from the K-th on.
    #[arg(long, value_name = "K/N", default_value = "0/1", value_parser = shard)]
    pub shard: (usize, usize),
    /// Seed of the data set.
    #[arg(long, value_name = "S", default_value_t = 1)]
    pub seed: u64,
    /// Reference grid spacing.
    #[arg(long, value_name = "MM", default_value = "0.7", value_parser = positive_mm)]
    pub fine_dx: f64,
    /// Coarse grid spacing.
    #[arg(long, value_name = "MM", default_value = "1.4", value_parser = positive_mm)]
    pub coarse_dx: f64,
    /// The coarse solve's equilibrium solver (relaxation, newton, total, linear): the
    /// one a model trained on the data set serves.
    #[arg(long, value_name = "NAME", default_value = "relaxation", value_parser = solver_name)]
    pub coarse_solver: tacrom::mpm::Solver,
    /// Pitch of the surface lattice.
    #[arg(long, value_name = "MM", default_value = "0.3", value_parser = positive_mm)]
    pub pitch: f64,
    /// Solver threads.
    #[arg(long, value_name = "T", default_value_t = 1,
          value_parser = at_least_one)]
    pub threads: usize,
    /// Directory of the pattern meshes (STL, millimetres) [../shared/indenters/patterns
    /// beside the checkout].
    #[arg(long, value_name = "DIR")]
    pub patterns: Option<PathBuf>,
    /// Only these families (all when absent).
    #[arg(long, value_name = "FAMILY", value_delimiter = ',')]
    pub families: Vec<String>,
    /// Reference solver iteration cap.
    #[arg(long, value_name = "N", default_value_t = 6000,
          value_parser = at_least_one)]
    pub fine_max_iterations: usize,
    /// Only the samples of held-out families (the same presses as a full set of the same
    /// seed), for a validation set at a finer --fine-dx.
    #[arg(long)]
    pub held_out_only: bool,
    /// Only these sample indices (comma-separated) of the full set: the same presses as
    /// the full set of the same seed, for a few chosen samples.
    #[arg(long, value_name = "I", value_delimiter = ',')]
    pub indices: Vec<usize>,
    /// Solve again only the coarse press of the samples already on disk (the same
    /// settings as when written) and rewrite their coarse channel and report, keeping the
    /// reference: for a data set whose coarse solver has changed since.
    #[arg(long)]
    pub refresh_coarse: bool,
    /// Print each sample's press (index, family, depth, slide) without solving anything.
    #[arg(long)]
    pub list: bool,
    /// The gel's Poisson's ratio (both solves), or a range `LO,HI` to draw each sample's
    /// from [the sensor's default, 0.43].
    #[arg(long, value_name = "NU[,NU]", value_delimiter = ',', num_args = 1..=2)]
    pub poisson: Vec<f64>,
    /// The gel's Coulomb friction coefficient (both solves), or a range `LO,HI` to draw
    /// each sample's from [the sensor's default, 0.5].
    #[arg(long, value_name = "MU[,MU]", value_delimiter = ',', num_args = 1..=2)]
    pub friction: Vec<f64>,
    /// Draw each sample's gel from the gel family (12 to 40 mm a side, 1 to 6 mm thick),
    /// its indenter scaled by 0.5 to 2 and pressed anywhere, edges included; solve it in
    /// the model's units (the default gel's thickness; sides beyond 9 thicknesses cut)
    /// and write the window of the model's lattice over the contact. --coarse-dx and
    /// --fine-dx are then in the model's units.
    #[arg(long)]
    pub gel_family: bool,
    /// With --gel-family: every sample on this gel of the family (sides and thickness,
    /// mm) instead of drawn ones; a validation set of one gel.
    #[arg(
        long,
        value_name = "X,Y,T",
        value_delimiter = ',',
        num_args = 1..=3,
        requires = "gel_family"
    )]
    pub gel_size: Vec<f64>,
}

/// Options of `tacrom eval-rom`: depth MAE, RMSE, SSIM over the 24 x 18 mm field of view
/// (a family data set's whole window), the footprint MAE and inference time on the
/// held-out families of gen-data sets. Writes report.md, results.csv, forces.csv and
/// presses.csv (per press) into --out.
#[derive(Debug, Args)]
#[command(after_help = UNITS)]
pub struct EvalRomArgs {
    /// Data sets (gen-data --out).
    #[arg(long, value_name = "DIR", value_delimiter = ',', required = true)]
    pub data: Vec<PathBuf>,
    /// Model folders, each run as its manifest says; the first also runs without
    /// refinement [models/rom-default,models/rom-latent16,models/rom-no-multiscale].
    #[arg(long, value_name = "DIR", value_delimiter = ',')]
    pub models: Vec<PathBuf>,
    /// Every sample, not only held-out families.
    #[arg(long)]
    pub all: bool,
    /// Every model also runs with the latent refinement on (rows MODEL-refined), whatever
    /// its manifest says.
    #[arg(long)]
    pub refined: bool,
    /// A data set of the same presses (same seed and indices) whose reference gets a row,
    /// e.g. the 0.7 mm set against the 0.3 mm one.
    #[arg(long, value_name = "DIR")]
    pub compare: Option<PathBuf>,
    /// Report folder.
    #[arg(long, value_name = "DIR", default_value = "out/bench/eval-rom")]
    pub out: PathBuf,
}

/// Options of `tacrom rom-features` (a developer tool): solves fixed presses (an
/// off-centre sphere, a box at a corner) on a model's coarse gel and writes what its
/// networks see, computed by the run-time code, as .npy files with features.json, in
/// gen-data's format where they overlap (see src/rom_features.rs).
/// `training/tests/test_feature_parity.py` compares them with the training code's.
#[derive(Debug, Args)]
#[command(after_help = UNITS)]
pub struct RomFeaturesArgs {
    /// Output directory.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Model whose lattice, gel and coarse solve to use [the shipped models/rom-default].
    #[arg(long, value_name = "DIR")]
    pub model: Option<PathBuf>,
    /// Solver threads.
    #[arg(long, value_name = "T", default_value_t = 1,
          value_parser = at_least_one)]
    pub threads: usize,
}

/// A solver name (`relaxation`, `newton`).
fn solver_name(s: &str) -> Result<tacrom::mpm::Solver, String> {
    tacrom::mpm::Solver::named(s).ok_or_else(|| {
        let names: Vec<_> = tacrom::mpm::Solver::ALL.iter().map(|s| s.name()).collect();
        format!("unknown solver `{s}`; one of {}", names.join(", "))
    })
}

/// A whole number of at least 3, odd.
fn odd_bins(s: &str) -> Result<usize, String> {
    s.trim()
        .parse::<usize>()
        .ok()
        .filter(|&n| n >= 3 && n % 2 == 1)
        .ok_or_else(|| format!("'{s}' is not an odd whole number of at least 3"))
}

/// A finite number above zero.
fn positive(s: &str) -> Result<f64, String> {
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v > 0.0)
        .ok_or_else(|| format!("'{s}' is not a positive number"))
}

/// A finite number of at least zero.
fn non_negative(s: &str) -> Result<f64, String> {
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v >= 0.0)
        .ok_or_else(|| format!("'{s}' is not a number of at least 0"))
}

/// Options of `tacrom calibrate`: fits the `rgb` output's calibrated optics (the `optics`
/// attribute's file) to ball presses, Taxim-style, and reports the colour MAE and SSIM of
/// the held-out presses re-rendered through it. The folder holds `background.png`, one
/// PNG per press and `presses.json` (docs/calibration.md; crates/tacrom-tools/src/calibrate/mod.rs).
/// With --synthesize DIR it writes such a folder instead, rendered with the built-in optics.
#[derive(Debug, Args)]
#[command(after_help = UNITS)]
pub struct CalibrateArgs {
    /// The calibration folder.
    #[arg(value_name = "DIR", required_unless_present = "synthesize")]
    pub input: Option<PathBuf>,
    /// Optics file to write (JSON; its background PNG goes beside it) [DIR/optics.json].
    #[arg(long, value_name = "FILE", conflicts_with = "synthesize")]
    pub out: Option<PathBuf>,
    /// Table nodes along each gradient axis (odd: one node at zero slope).
    #[arg(long, value_name = "N", default_value_t = FitOptions::default().bins,
          value_parser = odd_bins)]
    pub bins: usize,
    /// Half range G of the table's slopes, gx and gy in [-G, G] [the largest sample slope].
    #[arg(long, value_name = "G", value_parser = positive)]
    pub range: Option<f64>,
    /// Weight of the table's curvature penalty against the samples.
    #[arg(long, value_name = "S", default_value_t = FitOptions::default().smooth,
          value_parser = positive)]
    pub smooth: f64,
    /// Hold out every K-th press of the list from the fit, for the report; 0: none.
    #[arg(long, value_name = "K", default_value_t = calibrate::DEFAULT_HOLDOUT)]
    pub holdout: usize,
    /// Leave out the pixels this close to a contact's edge (pixels).
    #[arg(long, value_name = "PX", default_value_t = calibrate::DEFAULT_EDGE_MARGIN,
          value_parser = non_negative)]
    pub edge_margin: f64,
    /// Contact detection: a pixel differs from the background by more than this in some
    /// channel (grey levels).
    #[arg(long, value_name = "LEVELS", default_value_t = calibrate::contact::DEFAULT_THRESHOLD,
          value_parser = positive)]
    pub threshold: f64,
    /// The images are as the camera sees them, mirrored left-right against the sensor's
    /// image: flip them (and given centres) first.
    #[arg(long)]
    pub mirror: bool,
    /// Detect every contact from its image, even where presses.json gives one (hand-drawn
    /// circles on real images can be off by a fifth of their radius).
    #[arg(long, conflicts_with = "synthesize")]
    pub detect: bool,
    /// Fit the gel too (thickness and Poisson's ratio, from the imprint around each
    /// contact; Young's modulus where presses give force_n; the pixel size checked where
    /// they give depth_mm) and write a sensor file,
    /// sensor.json, beside the optics.
    #[arg(long, conflicts_with = "synthesize")]
    pub gel: bool,
    /// The gel thicknesses to try (mm, ascending) [1,1.5,2,3,4,5].
    #[arg(long, value_name = "MM,...", value_delimiter = ',', requires = "gel",
          value_parser = positive)]
    pub thickness: Vec<f64>,
    /// The Poisson's ratios to try (ascending) [0.3,0.38,0.43,0.46,0.48].
    #[arg(long, value_name = "NU,...", value_delimiter = ',', requires = "gel",
          value_parser = non_negative)]
    pub poisson: Vec<f64>,
    /// Depth blurs of the optics to try with the fitted gel (mm, standard deviations; 0:
    /// none): the one whose images match the presses' imprints best (region SSIM) is
    /// written into the optics, its table fitted through it [no blur].
    #[arg(long, value_name = "MM,...", value_delimiter = ',', requires = "gel",
          value_parser = non_negative)]
    pub blur: Vec<f64>,
    /// The gel fit's grid spacing, every candidate's (mm) [the thinnest over 2].
    #[arg(long, value_name = "MM", requires = "gel", value_parser = positive)]
    pub dx: Option<f64>,
    /// Solver threads of the gel fit.
    #[arg(long, value_name = "N", default_value_t = 1, requires = "gel",
          value_parser = at_least_one)]
    pub threads: usize,
    /// Write a synthetic press set into DIR instead (built-in optics, rigid ball caps).
    #[arg(long, value_name = "DIR")]
    pub synthesize: Option<PathBuf>,
    /// Synthetic presses.
    #[arg(long, value_name = "N", default_value_t = 24, requires = "synthesize",
          value_parser = at_least_one)]
    pub presses: usize,
    /// Synthetic image size.
    #[arg(long, value_name = "WxH", default_value = "320x240", requires = "synthesize",
          value_parser = resolution)]
    pub resolution: [usize; 2],
    /// Synthetic pixel size.
    #[arg(long, value_name = "MM", default_value = "0.075", requires = "synthesize",
          value_parser = positive_mm)]
    pub pixel_size: f64,
    /// Seed of the synthetic presses.
    #[arg(long, value_name = "S", default_value_t = 1, requires = "synthesize")]
    pub seed: u64,
    /// Leave the contacts out of the synthetic presses.json (calibrate detects them).
    #[arg(long, requires = "synthesize")]
    pub no_contact: bool,
}

/// Options of `tacrom compare` (crates/tacrom-tools/src/calibrate/compare.rs).
#[derive(Debug, Args)]
pub struct CompareArgs {
    /// The calibration folder (presses.json, background.png, the press images).
    #[arg(value_name = "DIR")]
    pub input: PathBuf,
    /// The sensor file (or its folder, or a shipped sensor's name).
    #[arg(long, value_name = "FILE")]
    pub sensor: String,
    /// Score every K-th press (those `tacrom calibrate --holdout K` held out); 0 or 1: all.
    #[arg(long, value_name = "K", default_value_t = calibrate::DEFAULT_HOLDOUT)]
    pub holdout: usize,
    /// The images are as the camera sees them: flip them first.
    #[arg(long)]
    pub mirror: bool,
    /// Detect every contact from its image, even where presses.json gives one.
    #[arg(long)]
    pub detect: bool,
    /// Contact detection threshold (grey levels).
    #[arg(long, value_name = "LEVELS", default_value_t = calibrate::contact::DEFAULT_THRESHOLD,
          value_parser = positive)]
    pub threshold: f64,
    /// A row: LABEL=ATTR:VALUE,... (the sensor file's sensor with these attributes;
    /// gel:default leaves its gel to the defaults) or LABEL=@DIR (another renderer's images
    /// of the same names) [background, rigid, the sensor file, coarse and rom on the
    /// default gel].
    #[arg(long = "row", value_name = "SPEC")]
    pub rows: Vec<String>,
    /// Add the default rows before the --row ones.
    #[arg(long)]
    pub with_defaults: bool,
    /// Solver threads.
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = at_least_one)]
    pub threads: usize,
    /// Write the table as JSON here too.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Write a figure here (PNG): for the first --figure-presses presses, the real image
    /// beside each row's, cropped around the press.
    #[arg(long, value_name = "FILE")]
    pub figure: Option<PathBuf>,
    /// Presses in the figure.
    #[arg(long, value_name = "N", default_value_t = 3)]
    pub figure_presses: usize,
    /// Fail when a row is worse than this table (JSON of --json) by more than --tolerance
    /// in MAE or SSIM (region or image).
    #[arg(long, value_name = "FILE")]
    pub baseline: Option<PathBuf>,
    /// The regression --baseline tolerates.
    #[arg(long, value_name = "X", default_value_t = 0.005, value_parser = non_negative)]
    pub tolerance: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    fn parse(args: &[&str]) -> Command {
        Cli::try_parse_from(std::iter::once("tacrom").chain(args.iter().copied()))
            .unwrap_or_else(|e| panic!("{args:?}: {e}"))
            .command
    }

    #[test]
    fn the_parser_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn lengths_are_millimetres_in_every_subcommand() {
        let Command::GenData(g) = parse(&["gen-data", "--fine-dx", "0.3"]) else {
            panic!()
        };
        assert_eq!((g.fine_dx, g.coarse_dx, g.pitch), (0.3e-3, 1.4e-3, 0.3e-3));
        let Command::Bench(b) = parse(&["bench", "--quick", "--depths", "0.2,1"]) else {
            panic!()
        };
        assert_eq!(b.depths, [0.2e-3, 1e-3]);
        let Command::Render(r) = parse(&["render", "--x", "-1.5", "--sphere", "2"]) else {
            panic!()
        };
        assert_eq!((r.x, r.radius, r.depth), (-1.5e-3, 2e-3, 0.5e-3));
        let Command::Mpm(m) = parse(&["mpm", "--dx", "1.4,0.7", "--only", "speed"]) else {
            panic!()
        };
        assert_eq!((m.dx, m.only), (vec![1.4e-3, 0.7e-3], Some(MpmPart::Speed)));
        let Command::Stability(s) = parse(&["stability", "--dx", "1"]) else {
            panic!()
        };
        assert_eq!(
            (s.physics, s.dx),
            (vec!["rigid".into(), "coarse".into()], Some(1e-3))
        );
        let Command::Calibrate(c) =
            parse(&["calibrate", "--synthesize", "x", "--pixel-size", "0.1"])
        else {
            panic!()
        };
        assert_eq!((c.pixel_size, c.resolution), (0.1e-3, [320, 240]));
    }

    #[test]
    fn bad_values_are_refused() {
        for args in [
            &["gen-data", "--fine-dx", "0"][..],
            &["gen-data", "--shard", "2/2"],
            &["bench", "--quick", "--full"],
            &["bench", "--resolution", "64"],
            &["mpm", "--tolerances", "1.5"],
            &["mpm", "--threads", "0"],
            &["eval-rom"],
            &["rom-features"],
            &["rom-features", "--out", "x", "--threads", "0"],
            &["calibrate"],
            &["calibrate", "set", "--bins", "40"],
            &["calibrate", "set", "--smooth", "0"],
            &["calibrate", "set", "--presses", "3"],
            &["calibrate", "--synthesize", "x", "--pixel-size", "0"],
            &["calibrate", "--synthesize", "x", "--out", "y.json"],
        ] {
            let argv = std::iter::once("tacrom").chain(args.iter().copied());
            assert!(Cli::try_parse_from(argv).is_err(), "{args:?}");
        }
    }
}
