//! The press benchmark: error against run time for every physics mode (`tacrom bench`).
//!
//! The protocol follows the paper's Tables I and II: each indenter is pressed at a grid of
//! positions through increasing depths (0.1 to 0.5 mm in 0.1 mm steps, then 1.0 mm) as one
//! continuous sequence per indenter and position (the gel warm-starts from press to
//! press); every mode sees the same poses. The reference is the fine MPM mode at a chosen
//! grid spacing (`reference_dx`); its presses are cached on disk ([`cache`]), so a re-run
//! costs only the modes. Each mode runs once per thread count (1 and 2 by default); errors
//! come from the first run, and the others are checked to give the same images.
//!
//! * [`protocol`]: indenters, positions, modes, one press sequence.
//! * [`metrics`]: MAE, RMSE, PSNR, SSIM, Chamfer-L2, quantiles.
//! * [`cache`]: the reference cache.
//! * [`report`]: markdown and CSV; [`plot`]: the figures.
//!
//! **Peak memory** is measured in-process: before each mode's run the kernel's peak
//! resident set (VmHWM) is reset by writing `5` to `/proc/self/clear_refs`, and VmHWM is
//! read after it. The figure therefore includes what the process already held (the loaded
//! meshes and the reference images, reported as the baseline). Where the reset is refused
//! the figure is the process's peak so far, and the report says so.

pub mod cache;
pub mod check;
pub mod heldout;
pub mod metrics;
pub mod mpm;
pub mod plot;
pub mod protocol;
pub mod report;

use std::path::PathBuf;
use std::time::Instant;

use serde::Serialize;

use crate::progress::Progress;
use cache::{digest, Cache, CachedPress};
use protocol::{Frame, Indenter, ModeSpec};
use tacrom::config::RawConfig;
use tacrom::mpm::SolverOptions;

/// The stages of the timing breakdown, in order. The rom stages (encoder, refinement,
/// decoder) are empty for the other modes.
pub const STAGES: [&str; 7] = [
    "scene",
    "SDF",
    "MPM",
    "encoder",
    "refinement",
    "decoder",
    "render",
];

/// Bump when the meaning of a cached reference press changes without the solver's source
/// changing (the format, the protocol's poses).
pub const CACHE_VERSION: &str = "tacrom-bench-cache-3";

/// A benchmark failure, with a message for the user.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// Bad arguments.
    #[error("{0}")]
    Usage(String),
    /// An indenter folder or mesh could not be used.
    #[error("indenter {}: {message}", path.display())]
    Indenter {
        /// The file or folder.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A sensor configuration was rejected.
    #[error("{0}")]
    Config(String),
    /// The reference cache failed.
    #[error(transparent)]
    Cache(#[from] cache::CacheError),
    /// Writing the report failed.
    #[error("cannot write {}: {message}", path.display())]
    Output {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// Where the indenters come from.
#[derive(Clone, Debug)]
pub enum IndenterSource {
    /// Every STL/OBJ mesh of a folder, coordinates times `scale`, flipped or not; `names`
    /// (file stems) selects some, `limit` keeps the first few.
    Folder {
        /// The folder.
        dir: PathBuf,
        /// Coordinate scale (1e-3 for millimetres).
        scale: f64,
        /// Turn each mesh a half turn about x (its top face presses the gel).
        flip: bool,
        /// File stems to keep (all when empty).
        names: Vec<String>,
        /// At most this many.
        limit: Option<usize>,
    },
    /// Given indenters.
    Given(Vec<Indenter>),
}

/// Everything a benchmark run needs.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// Name of the profile, for the report.
    pub profile: String,
    /// Indenters.
    pub indenters: IndenterSource,
    /// Positions per side of the square grid (3: a 3 x 3 grid).
    pub grid: usize,
    /// Spacing of the position grid (m).
    pub spacing: f64,
    /// Depths of each press sequence (m), increasing.
    pub depths: Vec<f64>,
    /// Modes to compare with the reference.
    pub modes: Vec<ModeSpec>,
    /// Grid spacing of the fine reference (m).
    pub reference_dx: f64,
    /// Solver threads of the reference.
    pub reference_threads: usize,
    /// Thread counts each mode runs with.
    pub threads: Vec<usize>,
    /// Image width and height.
    pub resolution: [usize; 2],
    /// Further sensor attributes for every mode and the reference (gel, material).
    pub attrs: Vec<(String, String)>,
    /// Reference cache folder; `None` disables the cache.
    pub cache: Option<PathBuf>,
    /// Report folder.
    pub out: PathBuf,
    /// Number of press panels to draw.
    pub panels: usize,
    /// Show progress on stderr.
    pub progress: bool,
    /// This shard and the number of shards `(K, N)`: only the indenters whose index in the
    /// sorted list is `K` modulo `N` (`(0, 1)`: all).
    pub shard: (usize, usize),
    /// Compute and cache the reference only: no mode runs, no report.
    pub reference_only: bool,
    /// The physics fingerprint of an older build (`tacrom --version`): [`run`] copies the
    /// reference presses it cached to today's keys where today's have none. For a cache
    /// written before a change its presses do not depend on; the caller vouches for that,
    /// best by recomputing a few presses elsewhere and comparing.
    pub adopt_physics: Option<String>,
}

impl BenchOptions {
    /// The full protocol: every pattern, a 3 x 3 grid 2 mm apart, six depths, 320 x 240,
    /// reference at the fine mode's 0.3 mm.
    pub fn full(indenter_dir: PathBuf) -> Self {
        Self {
            profile: "full".to_owned(),
            indenters: IndenterSource::Folder {
                dir: indenter_dir,
                scale: 1e-3,
                flip: true,
                names: Vec::new(),
                limit: None,
            },
            grid: 3,
            spacing: 2e-3,
            depths: vec![0.1e-3, 0.2e-3, 0.3e-3, 0.4e-3, 0.5e-3, 1.0e-3],
            modes: ModeSpec::defaults(),
            reference_dx: 0.3e-3,
            reference_threads: 2,
            threads: vec![1, 2],
            resolution: [320, 240],
            attrs: Vec::new(),
            cache: Some(PathBuf::from("out/bench-cache")),
            out: PathBuf::from("out/bench/full"),
            panels: 4,
            progress: true,
            shard: (0, 1),
            reference_only: false,
            adopt_physics: None,
        }
    }

    /// The quick profile (a few minutes on two cores, cold cache included): two patterns,
    /// the centre position, three depths, 64 x 48 images, a cheaper 0.7 mm reference.
    pub fn quick(indenter_dir: PathBuf) -> Self {
        Self {
            profile: "quick".to_owned(),
            indenters: IndenterSource::Folder {
                dir: indenter_dir,
                scale: 1e-3,
                flip: true,
                names: vec!["hexagon".to_owned(), "moon".to_owned()],
                limit: Some(2),
            },
            grid: 1,
            depths: vec![0.2e-3, 0.5e-3, 1.0e-3],
            reference_dx: 0.7e-3,
            resolution: [64, 48],
            out: PathBuf::from("out/bench/quick"),
            panels: 2,
            ..Self::full(PathBuf::new())
        }
    }

    fn base_config(&self) -> RawConfig {
        let mut raw = RawConfig::default()
            .with(
                "resolution",
                &format!("{} {}", self.resolution[0], self.resolution[1]),
            )
            .with("outputs", "depth force");
        for (k, v) in &self.attrs {
            raw = raw.with(k, v);
        }
        raw
    }

    /// The reference's mode.
    pub fn reference_mode(&self) -> ModeSpec {
        ModeSpec {
            label: "fine-ref".to_owned(),
            attrs: vec![
                ("physics".to_owned(), "fine".to_owned()),
                ("dx".to_owned(), format!("{:e}", self.reference_dx)),
            ],
        }
    }
}

/// Resets the process's peak resident set; false where the kernel refuses.
pub fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Hands the heap's free pages back before a run, so that its resident set at the start
/// holds what the process still uses, not what earlier runs freed.
pub use tacrom::release_free_memory;

/// A field of `/proc/self/status` in bytes (`VmHWM`, `VmRSS`).
pub fn status_bytes(field: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(field))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// A hash of the cache format, the crate version, the fingerprint `physics` of the sources
/// a reference depends on ([`tacrom::config::Config::physics_fingerprint`]: a relaxation
/// reference, the relaxation's alone) and the solver's defaults, so that the cache notices
/// their changes.
fn code_version(physics: &str) -> String {
    digest(&[
        ("version", CACHE_VERSION),
        ("crate", env!("CARGO_PKG_VERSION")),
        ("physics", physics),
        ("solver", &format!("{:?}", SolverOptions::default())),
    ])
}

/// One press of the protocol.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PressId {
    /// Index into the indenters.
    pub indenter: usize,
    /// Index into the positions.
    pub position: usize,
    /// Index into the depths.
    pub depth: usize,
}

/// Errors of one mode against the reference, averaged over presses.
#[derive(Clone, Copy, Debug, Default)]
pub struct Accuracy {
    /// Depth MAE (m).
    pub mae: f64,
    /// Depth RMSE (m).
    pub rmse: f64,
    /// PSNR (dB), each press's capped at [`metrics::PSNR_CAP_DB`].
    pub psnr: f64,
    /// SSIM.
    pub ssim: f64,
    /// Chamfer-L2 of the deformed surfaces (m^2).
    pub chamfer: f64,
    /// Mean norm of the force difference (N).
    pub force_abs: f64,
    /// Sum of force difference norms over the sum of reference force norms.
    pub force_rel: f64,
}

/// One row of the report: a mode at one thread count.
#[derive(Clone, Debug)]
pub struct ModeResult {
    /// Mode label.
    pub label: String,
    /// Solver threads.
    pub threads: usize,
    /// Whether this is the reference.
    pub reference: bool,
    /// Errors against the reference (the reference's own are zero).
    pub accuracy: Accuracy,
    /// The same per depth of the sequences ([`BenchOptions::depths`] order); empty for
    /// the reference.
    pub by_depth: Vec<Accuracy>,
    /// The same per indenter ([`BenchResult::indenters`] order); empty for the reference.
    pub by_indenter: Vec<Accuracy>,
    /// Median time per evaluation (ms).
    pub median_ms: f64,
    /// 90th-percentile time per evaluation (ms).
    pub p90_ms: f64,
    /// Median time of a whole press sequence (one indenter at one position through every
    /// depth; s): the paper's time per interaction.
    pub sequence_s: f64,
    /// Sum of the evaluations' times (s); for the reference, of every press's solve as
    /// recorded when it was computed (cached presses included).
    pub total_s: f64,
    /// Peak resident memory during the run (bytes).
    pub peak_rss: Option<u64>,
    /// Resident memory at the start of the run (bytes).
    pub base_rss: Option<u64>,
    /// The mode's own memory: the peak above the start, less the images the benchmark
    /// keeps of the run (bytes); `None` where the start is unknown (a cached reference).
    pub own_rss: Option<u64>,
    /// Median per-stage times (ms), [`STAGES`] order, `NaN` where absent.
    pub stages_ms: [f64; STAGES.len()],
    /// Evaluations whose solver did not converge.
    pub not_converged: usize,
    /// Evaluations.
    pub evaluations: usize,
    /// For the reference: how many presses came from the cache.
    pub cached: usize,
    /// Largest difference to the first thread count's images (m), for later counts.
    pub thread_diff: Option<f64>,
}

/// The outcome of a run.
#[derive(Clone, Debug)]
pub struct BenchResult {
    /// The options it ran with.
    pub options: BenchOptions,
    /// Indenter names.
    pub indenters: Vec<String>,
    /// Positions (m).
    pub positions: Vec<[f64; 2]>,
    /// Rows: the reference first, then each mode and thread count.
    pub rows: Vec<ModeResult>,
    /// Modes that could not run, with the reason.
    pub unavailable: Vec<(String, String)>,
    /// Whether the peak-memory reset worked.
    pub peak_reset: bool,
    /// Wall time of the whole run (s).
    pub wall_seconds: f64,
    /// The command line that ran it.
    pub command: String,
    /// The machine it ran on ([`machine`]).
    pub machine: String,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// The machine in one line: CPU model, logical cores, operating system.
pub fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_owned())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_owned());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let kernel = std::fs::read_to_string("/proc/sys/kernel/osrelease")
        .map(|k| format!(" {}", k.trim()))
        .unwrap_or_default();
    format!(
        "{cpu}, {cores} logical core(s), {}{kernel}",
        std::env::consts::OS
    )
}

/// This process's command line as a shell would take it (`tacrom` and its arguments).
pub fn command_line() -> String {
    let quote = |a: String| {
        if a.is_empty() || a.contains(|c: char| c.is_whitespace() || "'\"$`\\".contains(c)) {
            format!("'{}'", a.replace('\'', "'\\''"))
        } else {
            a
        }
    };
    std::iter::once("tacrom".to_owned())
        .chain(std::env::args().skip(1).map(quote))
        .collect::<Vec<_>>()
        .join(" ")
}

struct Loaded {
    indenters: Vec<Indenter>,
    positions: Vec<[f64; 2]>,
}

fn load(opts: &BenchOptions) -> Result<Loaded, BenchError> {
    if opts.depths.is_empty()
        || opts
            .depths
            .iter()
            .any(|d| !(d.is_finite() && *d >= 0.0 && *d < 0.05))
    {
        return Err(BenchError::Usage(
            "depths must be given, each finite, non-negative and below 50 mm".to_owned(),
        ));
    }
    if opts.grid == 0 || !(opts.spacing.is_finite() && opts.spacing >= 0.0) {
        return Err(BenchError::Usage(
            "the position grid needs at least one position and a finite spacing".to_owned(),
        ));
    }
    if opts.threads.is_empty() {
        return Err(BenchError::Usage("no thread count given".to_owned()));
    }
    // The shard: the indenters whose index in the sorted list is K modulo N.
    let (k, n) = opts.shard;
    if n == 0 || k >= n {
        return Err(BenchError::Usage(format!(
            "shard {k}/{n} is not K/N with K < N"
        )));
    }
    let indenters: Vec<Indenter> = match &opts.indenters {
        IndenterSource::Given(v) => v
            .iter()
            .enumerate()
            .filter(|(i, _)| i % n == k)
            .map(|(_, ind)| ind.clone())
            .collect(),
        IndenterSource::Folder {
            dir,
            scale,
            flip,
            names,
            limit,
        } => {
            let mut files = protocol::mesh_files(dir)?;
            if !names.is_empty() {
                let stem = |p: &PathBuf| p.file_stem().map(|s| s.to_string_lossy().into_owned());
                for n in names {
                    if !files.iter().any(|f| stem(f).as_deref() == Some(n)) {
                        return Err(BenchError::Indenter {
                            path: dir.join(n),
                            message: "no such mesh (.stl or .obj) in the folder".to_owned(),
                        });
                    }
                }
                files.retain(|f| stem(f).is_some_and(|s| names.contains(&s)));
            }
            if let Some(l) = limit {
                files.truncate(*l);
            }
            // Only this shard's meshes are read.
            files
                .iter()
                .enumerate()
                .filter(|(i, _)| i % n == k)
                .map(|(_, f)| Indenter::from_mesh(f, *scale, *flip))
                .collect::<Result<_, _>>()?
        }
    };
    if indenters.is_empty() {
        return Err(BenchError::Usage(format!("no indenter (shard {k}/{n})")));
    }
    Ok(Loaded {
        indenters,
        positions: protocol::grid_positions(opts.grid, opts.spacing),
    })
}

/// What a reference press depends on: its cache key is the [`digest`] of this.
#[derive(Serialize)]
struct ReferenceInputs<'a> {
    /// [`code_version`].
    code: &'a str,
    /// The sensor configuration but its thread count.
    config: &'a str,
    /// The indenter mesh's fingerprint (bytes and scale).
    indenter: &'a str,
    /// Position of the press (m).
    position: [f64; 2],
    /// The depth sequence up to this press (m).
    depths: &'a [f64],
}

/// Key of the reference press `depths[..=k]` of `indenter` at `position`.
fn reference_key(
    code: &str,
    config: &str,
    indenter: &Indenter,
    position: [f64; 2],
    depths: &[f64],
) -> String {
    digest(&ReferenceInputs {
        code,
        config,
        indenter: &indenter.fingerprint,
        position,
        depths,
    })
}

fn frame_from_cache(c: CachedPress) -> Frame {
    let mut stages = [f64::NAN; STAGES.len()];
    for (s, v) in stages.iter_mut().zip(&c.stages) {
        *s = v.unwrap_or(f64::NAN);
    }
    Frame {
        depth: c.depth,
        force: c.force,
        seconds: c.seconds,
        stages,
        iterations: c.iterations,
        converged: c.converged,
    }
}

/// Frames of one mode run, sequence by sequence (`[indenter][position][depth]`).
pub type Frames = Vec<Vec<Vec<Frame>>>;

struct Timed {
    frames: Frames,
    peak_rss: Option<u64>,
    base_rss: Option<u64>,
}

fn median_stage(frames: &Frames, s: usize) -> f64 {
    let v: Vec<f64> = frames
        .iter()
        .flatten()
        .flatten()
        .map(|f| f.stages[s])
        .filter(|v| v.is_finite())
        .collect();
    metrics::median(&v) * 1e3
}

fn row_of(label: &str, threads: usize, t: &Timed) -> ModeResult {
    let all: Vec<&Frame> = t.frames.iter().flatten().flatten().collect();
    let secs: Vec<f64> = all.iter().map(|f| f.seconds).collect();
    let sequences: Vec<f64> = t
        .frames
        .iter()
        .flatten()
        .map(|seq| seq.iter().map(|f| f.seconds).sum())
        .collect();
    let mut stages_ms = [f64::NAN; STAGES.len()];
    for (s, v) in stages_ms.iter_mut().enumerate() {
        *v = median_stage(&t.frames, s);
    }
    ModeResult {
        label: label.to_owned(),
        threads,
        reference: false,
        accuracy: Accuracy::default(),
        by_depth: Vec::new(),
        by_indenter: Vec::new(),
        median_ms: metrics::median(&secs) * 1e3,
        p90_ms: metrics::quantile(&secs, 0.9) * 1e3,
        sequence_s: metrics::median(&sequences),
        total_s: secs.iter().sum(),
        peak_rss: t.peak_rss,
        base_rss: t.base_rss,
        own_rss: t.peak_rss.zip(t.base_rss).map(|(peak, base)| {
            let kept: usize = all.iter().map(|f| f.depth.capacity()).sum();
            peak.saturating_sub(base + (kept * std::mem::size_of::<f64>()) as u64)
        }),
        stages_ms,
        not_converged: all.iter().filter(|f| !f.converged).count(),
        evaluations: all.len(),
        cached: 0,
        thread_diff: None,
    }
}

/// The errors of one press against the reference's.
#[derive(Clone, Copy, Debug)]
struct PressError {
    id: PressId,
    mae: f64,
    rmse: f64,
    psnr: Option<f64>,
    ssim: Option<f64>,
    chamfer: f64,
    /// Norm of the force difference and of the reference's force (N).
    force: f64,
    force_ref: f64,
}

/// Each press's errors against the reference, computed once for every grouping.
fn press_errors(
    frames: &Frames,
    reference: &Frames,
    grid: &tacrom::geometry::PixelGrid,
) -> Vec<PressError> {
    let mut out = Vec::new();
    for (i, (seqs, ref_seqs)) in frames.iter().zip(reference).enumerate() {
        for (p, (seq, ref_seq)) in seqs.iter().zip(ref_seqs).enumerate() {
            for (d, (a, r)) in seq.iter().zip(ref_seq).enumerate() {
                let peak = r.depth.iter().copied().fold(0.0f64, f64::max);
                let norm = |v: &[f64; 3]| v.iter().map(|f| f * f).sum::<f64>().sqrt();
                let diff: [f64; 3] = std::array::from_fn(|k| a.force[k] - r.force[k]);
                out.push(PressError {
                    id: PressId {
                        indenter: i,
                        position: p,
                        depth: d,
                    },
                    mae: metrics::mae(&a.depth, &r.depth),
                    rmse: metrics::rmse(&a.depth, &r.depth),
                    psnr: metrics::psnr(&a.depth, &r.depth, peak)
                        .map(|v| v.min(metrics::PSNR_CAP_DB)),
                    ssim: metrics::ssim(&a.depth, &r.depth, grid.width, grid.height, peak),
                    chamfer: metrics::chamfer_l2(
                        &metrics::surface_points(grid, &a.depth),
                        &metrics::surface_points(grid, &r.depth),
                    ),
                    force: norm(&diff),
                    force_ref: norm(&r.force),
                });
            }
        }
    }
    out
}

/// The mean errors over `errors` (PSNR and SSIM over the presses that have one; the
/// relative force error as the sum of differences over the sum of reference forces).
fn accuracy<'a>(errors: impl Iterator<Item = &'a PressError>) -> Accuracy {
    let mut acc = Accuracy::default();
    let (mut n, mut psnr_n, mut ssim_n) = (0usize, 0usize, 0usize);
    let mut force_ref = 0.0;
    for e in errors {
        acc.mae += e.mae;
        acc.rmse += e.rmse;
        acc.chamfer += e.chamfer;
        if let Some(p) = e.psnr {
            acc.psnr += p;
            psnr_n += 1;
        }
        if let Some(s) = e.ssim {
            acc.ssim += s;
            ssim_n += 1;
        }
        acc.force_abs += e.force;
        force_ref += e.force_ref;
        n += 1;
    }
    let fsum = acc.force_abs;
    let n = n.max(1) as f64;
    acc.mae /= n;
    acc.rmse /= n;
    acc.chamfer /= n;
    acc.psnr = if psnr_n > 0 {
        acc.psnr / psnr_n as f64
    } else {
        f64::NAN
    };
    acc.ssim = if ssim_n > 0 {
        acc.ssim / ssim_n as f64
    } else {
        f64::NAN
    };
    acc.force_abs = fsum / n;
    acc.force_rel = if force_ref > 0.0 {
        fsum / force_ref
    } else {
        f64::NAN
    };
    acc
}

/// One press done: the bar says which; the last press of a sequence also gets a line.
fn step(progress: &Progress, who: &str, (indenter, pos, depth): (&str, [f64; 2], f64), last: bool) {
    let what = format!(
        "{who} {indenter} @({:.1},{:.1}) mm {:.1} mm",
        pos[0] * 1e3,
        pos[1] * 1e3,
        depth * 1e3
    );
    progress.advance(1);
    if last {
        progress.line(&what);
    }
    progress.message(what);
}

/// Runs the benchmark and writes its report into `options.out`.
pub fn run(options: &BenchOptions) -> Result<BenchResult, BenchError> {
    let wall = Instant::now();
    let opts = options;
    let Loaded {
        indenters,
        positions,
    } = load(opts)?;
    let base = opts.base_config();
    let ref_mode = opts.reference_mode();
    let ref_config = ref_mode.config(&base, opts.reference_threads)?;
    let grid = tacrom::geometry::PixelGrid {
        width: ref_config.width,
        height: ref_config.height,
        fov_x: ref_config.fov[0],
        fov_y: ref_config.fov[1],
    };
    let version = code_version(ref_config.physics_fingerprint());
    let adopted_version = opts.adopt_physics.as_deref().map(code_version);
    // Everything of the configuration but the thread count (results do not depend on it).
    let config_text = {
        let mut c = ref_config.clone();
        c.threads = 1;
        format!("{c:?}")
    };
    let cache = opts.cache.as_ref().map(Cache::new);

    // Which reference sequences need computing.
    let n_seq = indenters.len() * positions.len();
    let nd = opts.depths.len();
    let mut ref_frames: Frames = vec![vec![Vec::new(); positions.len()]; indenters.len()];
    let mut todo = Vec::new();
    let mut cached = 0;
    let mut cached_peak: Option<u64> = None;
    let mut adopted = 0;
    for (i, ind) in indenters.iter().enumerate() {
        for (p, &pos) in positions.iter().enumerate() {
            let mut frames = Vec::new();
            if let Some(cache) = &cache {
                for k in 0..nd {
                    let key = reference_key(&version, &config_text, ind, pos, &opts.depths[..=k]);
                    if let Some(old) = &adopted_version {
                        let old = reference_key(old, &config_text, ind, pos, &opts.depths[..=k]);
                        adopted += usize::from(cache.adopt(&old, &key)?);
                    }
                    match cache.load(&key)? {
                        Some(c) => {
                            cached_peak = cached_peak.max(c.peak_rss);
                            frames.push(frame_from_cache(c));
                        }
                        None => break,
                    }
                }
            }
            if frames.len() == nd {
                cached += nd;
                ref_frames[i][p] = frames;
            } else {
                todo.push((i, p));
            }
        }
    }
    if let (Some(hex), true) = (&opts.adopt_physics, opts.progress) {
        eprintln!("reference presses adopted from physics {hex}: {adopted}");
    }
    // A reference-only run (one shard of a batch job, say) runs no mode.
    let modes: &[ModeSpec] = if opts.reference_only {
        &[]
    } else {
        &opts.modes
    };
    let modes_work = modes.len() * opts.threads.len() * n_seq * nd;
    let progress = Progress::new(todo.len() * nd + modes_work, opts.progress);

    // The modes first, the reference last: each run's peak memory then includes little
    // of the runs before it (the allocator may keep what they freed).
    let mut rows = Vec::new();
    let mut unavailable = Vec::new();
    let mut mode_frames: Vec<(String, Frames)> = Vec::new();
    if !modes.is_empty() {
        // The indenters are the scene, shared by every mode: a mesh builds its distance
        // grid on the first query, which would otherwise count as the first mode's memory.
        for ind in &indenters {
            let _ = ind.shape.distance(&nalgebra::Point3::origin());
        }
    }
    for mode in modes {
        let mut first: Option<Frames> = None;
        for &threads in &opts.threads {
            let config = match mode.config(&base, threads) {
                Ok(c) => c,
                Err(e) => {
                    unavailable.push((mode.label.clone(), e.to_string()));
                    progress.advance(n_seq * nd * opts.threads.len());
                    break;
                }
            };
            release_free_memory();
            let _ = reset_peak_rss();
            let base_rss = status_bytes("VmRSS");
            let mut frames: Frames = Vec::new();
            for ind in &indenters {
                let mut per_pos = Vec::new();
                for &pos in &positions {
                    let f = protocol::run_sequence(&config, ind, pos, &opts.depths, |k, _| {
                        step(
                            &progress,
                            &format!("{} x{threads}", mode.label),
                            (&ind.name, pos, opts.depths[k]),
                            k + 1 == nd,
                        );
                    })?;
                    per_pos.push(f);
                }
                frames.push(per_pos);
            }
            let timed = Timed {
                frames,
                peak_rss: status_bytes("VmHWM"),
                base_rss,
            };
            let mut row = row_of(&mode.label, threads, &timed);
            match &first {
                None => first = Some(timed.frames),
                Some(f0) => {
                    let diff = f0
                        .iter()
                        .flatten()
                        .flatten()
                        .zip(timed.frames.iter().flatten().flatten())
                        .flat_map(|(a, b)| a.depth.iter().zip(&b.depth).map(|(x, y)| (x - y).abs()))
                        .fold(0.0f64, f64::max);
                    row.thread_diff = Some(diff);
                }
            }
            rows.push(row);
        }
        if let Some(f) = first {
            // The first run's frames, for the panels.
            mode_frames.push((mode.label.clone(), f));
        }
    }
    // The reference.
    release_free_memory();
    let peak_reset = reset_peak_rss();
    let ref_base = status_bytes("VmRSS");
    for &(i, p) in &todo {
        let ind = &indenters[i];
        let pos = positions[p];
        // Each press is stored as soon as it is solved, so that a run cut short (a batch
        // job's time limit) keeps every press it finished.
        let mut stored: Result<(), cache::CacheError> = Ok(());
        let frames = protocol::run_sequence(&ref_config, ind, pos, &opts.depths, |k, f| {
            step(
                &progress,
                "reference",
                (&ind.name, pos, opts.depths[k]),
                k + 1 == nd,
            );
            if let (Some(cache), Ok(())) = (&cache, &stored) {
                let key = reference_key(&version, &config_text, ind, pos, &opts.depths[..=k]);
                stored = cache.store(
                    &key,
                    &CachedPress {
                        width: grid.width,
                        height: grid.height,
                        depth: f.depth.clone(),
                        force: f.force,
                        seconds: f.seconds,
                        stages: f
                            .stages
                            .iter()
                            .map(|s| s.is_finite().then_some(*s))
                            .collect(),
                        iterations: f.iterations,
                        converged: f.converged,
                        peak_rss: status_bytes("VmHWM"),
                    },
                );
            }
        })?;
        stored?;
        ref_frames[i][p] = frames;
    }
    let ref_timed = Timed {
        frames: ref_frames,
        // From the cache: the peak of the runs that computed it.
        peak_rss: if todo.is_empty() {
            cached_peak
        } else {
            status_bytes("VmHWM").max(cached_peak)
        },
        base_rss: if todo.is_empty() { None } else { ref_base },
    };
    let mut ref_row = row_of(&ref_mode.label, opts.reference_threads, &ref_timed);
    ref_row.reference = true;
    ref_row.cached = cached;
    rows.insert(0, ref_row);

    // Errors, from each mode's first thread count: over all presses, per depth of the
    // sequences and per indenter.
    for (label, frames) in &mode_frames {
        let errors = press_errors(frames, &ref_timed.frames, &grid);
        let acc = accuracy(errors.iter());
        let by_depth: Vec<Accuracy> = (0..opts.depths.len())
            .map(|d| accuracy(errors.iter().filter(|e| e.id.depth == d)))
            .collect();
        let by_indenter: Vec<Accuracy> = (0..indenters.len())
            .map(|i| accuracy(errors.iter().filter(|e| e.id.indenter == i)))
            .collect();
        for row in rows.iter_mut().filter(|r| &r.label == label) {
            row.accuracy = acc;
            row.by_depth.clone_from(&by_depth);
            row.by_indenter.clone_from(&by_indenter);
        }
    }

    progress.finish();
    let mut result = BenchResult {
        options: opts.clone(),
        indenters: indenters.iter().map(|i| i.name.clone()).collect(),
        positions,
        rows,
        unavailable,
        peak_reset,
        wall_seconds: 0.0,
        command: command_line(),
        machine: machine(),
        files: Vec::new(),
    };
    if opts.reference_only {
        // No mode ran: nothing to compare or draw.
        result.wall_seconds = wall.elapsed().as_secs_f64();
        return Ok(result);
    }
    let figures = report::Figures {
        grid: &grid,
        reference: &ref_timed.frames,
        modes: &mode_frames,
    };
    result.wall_seconds = wall.elapsed().as_secs_f64();
    result.files = report::write(&result, &figures)?;
    Ok(result)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(depth: f64, force: f64) -> Frame {
        Frame {
            depth: vec![depth; 12],
            force: [0.0, 0.0, force],
            seconds: 0.0,
            stages: [f64::NAN; STAGES.len()],
            iterations: 0,
            converged: true,
        }
    }

    /// A batch job's shards fill the cache for the whole run: `--reference-only --shard
    /// K/2` each compute their own indenters' reference presses (every second one of the
    /// sorted list) and run no mode; the whole benchmark afterwards takes every press from
    /// the cache. Two meshes, one position, one depth, a 16 x 12 image and a coarse
    /// reference, so that it runs in seconds.
    #[test]
    fn reference_shards_fill_the_cache_for_the_whole_run() {
        let tmp = std::env::temp_dir().join(format!("tacrom-shards-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&tmp);
        let mut opts = BenchOptions::quick(tacrom::pattern_dir());
        if let IndenterSource::Folder { names, limit, .. } = &mut opts.indenters {
            *names = vec!["hexagon".to_owned(), "moon".to_owned()];
            *limit = None;
        }
        opts.depths = vec![0.2e-3];
        opts.resolution = [16, 12];
        opts.reference_dx = 1.4e-3;
        opts.reference_threads = 1;
        opts.modes = vec![ModeSpec::parse("rigid").unwrap()];
        opts.threads = vec![1];
        opts.cache = Some(tmp.join("cache"));
        opts.out = tmp.join("report");
        opts.progress = false;
        opts.panels = 0;
        let shard = |k: usize| {
            let o = BenchOptions {
                shard: (k, 2),
                reference_only: true,
                ..opts.clone()
            };
            run(&o).unwrap()
        };
        for (k, name) in ["hexagon", "moon"].into_iter().enumerate() {
            let r = shard(k);
            assert_eq!(r.indenters, [name]);
            assert_eq!(r.rows.len(), 1, "no mode runs");
            assert_eq!((r.rows[0].evaluations, r.rows[0].cached), (1, 0));
            assert!(r.files.is_empty() && !opts.out.exists(), "no report");
        }
        let whole = run(&opts).unwrap();
        assert_eq!(whole.indenters, ["hexagon", "moon"]);
        let reference = &whole.rows[0];
        assert!(reference.reference);
        assert_eq!((reference.evaluations, reference.cached), (2, 2));
        // The report opens with the headline and the per-interaction tables.
        let md = report::markdown(&whole);
        let headline = md.split("## Headline").nth(1).expect("a headline table");
        let rigid = headline
            .lines()
            .find(|l| l.starts_with("| rigid |"))
            .expect("rigid row");
        assert_eq!(rigid.matches('|').count(), 9, "{rigid}");
        assert!(md.contains("## Per interaction"), "{md}");
        assert!(run(&BenchOptions {
            shard: (2, 2),
            ..opts.clone()
        })
        .is_err());
        let _ = std::fs::remove_dir_all(&tmp);
    }

    /// Errors grouped per depth and per indenter: each group averages its own presses, the
    /// whole is the mean over all of them, and the relative force error sums differences
    /// over reference forces. Two indenters, one position, two depths; the mode is off by
    /// 1, 2, 3 and 4 um (indenter-major), its forces by 0.1 N on reference forces of 1 and
    /// 3 N.
    #[test]
    fn errors_group_per_depth_and_per_indenter() {
        let grid = tacrom::geometry::PixelGrid {
            width: 4,
            height: 3,
            fov_x: 0.004,
            fov_y: 0.003,
        };
        let reference: Frames = vec![
            vec![vec![frame(1e-4, 1.0), frame(2e-4, 3.0)]],
            vec![vec![frame(1e-4, 1.0), frame(2e-4, 3.0)]],
        ];
        let mode: Frames = vec![
            vec![vec![frame(1e-4 + 1e-6, 1.1), frame(2e-4 + 2e-6, 3.1)]],
            vec![vec![frame(1e-4 + 3e-6, 1.1), frame(2e-4 + 4e-6, 3.1)]],
        ];
        let errors = press_errors(&mode, &reference, &grid);
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        let all = accuracy(errors.iter());
        assert!(close(all.mae, 2.5e-6), "{}", all.mae);
        assert!(close(all.force_rel, 0.4 / 8.0), "{}", all.force_rel);
        let first_depth = accuracy(errors.iter().filter(|e| e.id.depth == 0));
        assert!(close(first_depth.mae, 2e-6), "{}", first_depth.mae);
        assert!(
            close(first_depth.force_rel, 0.1),
            "{}",
            first_depth.force_rel
        );
        let second_indenter = accuracy(errors.iter().filter(|e| e.id.indenter == 1));
        assert!(
            close(second_indenter.mae, 3.5e-6),
            "{}",
            second_indenter.mae
        );
        assert!(
            close(second_indenter.force_abs, 0.1),
            "{}",
            second_indenter.force_abs
        );
    }
}
