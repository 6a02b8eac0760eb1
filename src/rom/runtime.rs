//! ONNX Runtime: finding its library, the one environment of the process, sessions with
//! their inputs and outputs checked.
//!
//! The library is `libonnxruntime.so*` of the PyPI `onnxruntime` wheel. It is looked for,
//! in order: `ORT_DYLIB_PATH`; a copy already loaded in the process (Python imported
//! `onnxruntime`); beside the loaded MuJoCo (`site-packages/mujoco/libmujoco.so*` ->
//! `site-packages/onnxruntime/capi/`); beside this library (its own path, walking up to a
//! `.venv`); and the source tree's `.venv` (tests and tools run from the checkout).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use ort::session::Session;
use ort::value::ValueType;

use super::RomError;

/// Mapped files of this process (from `/proc/self/maps`), with their address ranges.
fn mapped_files() -> Vec<(usize, usize, PathBuf)> {
    let Ok(maps) = std::fs::read_to_string("/proc/self/maps") else {
        return Vec::new();
    };
    maps.lines()
        .filter_map(|l| {
            let mut f = l.split_whitespace();
            let range = f.next()?;
            let path = f.nth(4)?;
            if !path.starts_with('/') {
                return None;
            }
            let (a, b) = range.split_once('-')?;
            Some((
                usize::from_str_radix(a, 16).ok()?,
                usize::from_str_radix(b, 16).ok()?,
                PathBuf::from(path),
            ))
        })
        .collect()
}

/// The file (shared library or executable) that holds this code.
pub fn own_library_path() -> Option<PathBuf> {
    let addr = own_library_path as *const () as usize;
    mapped_files()
        .into_iter()
        .find(|(a, b, _)| (*a..*b).contains(&addr))
        .map(|(_, _, p)| p)
}

fn ort_in_dir(dir: &Path) -> Option<PathBuf> {
    let mut found: Vec<PathBuf> = std::fs::read_dir(dir)
        .ok()?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("libonnxruntime.so"))
        })
        .collect();
    found.sort();
    found.pop()
}

fn ort_in_venv(venv: &Path) -> Option<PathBuf> {
    let lib = venv.join("lib");
    let rd = std::fs::read_dir(&lib).ok()?;
    for e in rd.filter_map(|e| e.ok()) {
        let d = e.path().join("site-packages/onnxruntime/capi");
        if let Some(p) = ort_in_dir(&d) {
            return Some(p);
        }
    }
    None
}

/// Candidate paths of the ONNX Runtime library, best first (see the module docs).
pub fn library_candidates() -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Some(p) = std::env::var_os("ORT_DYLIB_PATH") {
        out.push(PathBuf::from(p));
        return out;
    }
    let maps = mapped_files();
    for (_, _, p) in &maps {
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if name.starts_with("libonnxruntime.so") {
            out.push(p.clone());
        }
    }
    for (_, _, p) in &maps {
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if name.starts_with("libmujoco.so") {
            if let Some(site) = p.parent().and_then(Path::parent) {
                out.extend(ort_in_dir(&site.join("onnxruntime/capi")));
            }
        }
    }
    if let Some(own) = own_library_path() {
        for dir in own.ancestors().skip(1) {
            out.extend(ort_in_venv(&dir.join(".venv")));
            if dir.file_name().is_some_and(|n| n == "site-packages") {
                out.extend(ort_in_dir(&dir.join("onnxruntime/capi")));
            }
        }
    }
    out.extend(ort_in_venv(&crate::checkout_root().join(".venv")));
    let mut seen = Vec::new();
    out.retain(|p| {
        let keep = !seen.contains(p);
        seen.push(p.clone());
        keep
    });
    out
}

static ENV: OnceLock<Result<ort::environment::Environment, String>> = OnceLock::new();

/// The process's ONNX Runtime environment, created on first use.
pub fn environment() -> Result<&'static ort::environment::Environment, RomError> {
    ENV.get_or_init(|| {
        let candidates = library_candidates();
        let Some(path) = candidates.iter().find(|p| p.is_file()) else {
            return Err(format!(
                "ONNX Runtime library not found (looked at: {}); install the onnxruntime wheel \
                 beside mujoco or set ORT_DYLIB_PATH",
                if candidates.is_empty() {
                    "nothing".to_owned()
                } else {
                    candidates
                        .iter()
                        .map(|p| p.display().to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            ));
        };
        let builder = ort::init_from(path)
            .map_err(|e| format!("cannot load ONNX Runtime from {}: {e}", path.display()))?;
        builder
            .with_name("tacrom")
            .build()
            .map_err(|e| format!("cannot create the ONNX Runtime environment: {e}"))
    })
    .as_ref()
    .map_err(|e| RomError::Runtime(e.clone()))
}

/// One ONNX graph with its named inputs and outputs checked against the manifest.
pub struct Graph {
    /// The session.
    pub session: Session,
}

impl std::fmt::Debug for Graph {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Graph").finish_non_exhaustive()
    }
}

fn shape_ok(actual: &[i64], expected: &[i64]) -> bool {
    actual.len() == expected.len()
        && actual
            .iter()
            .zip(expected)
            .all(|(&a, &e)| e < 0 || a < 0 || a == e)
}

/// Loads `path` on one intra-op thread and checks that its inputs and outputs are exactly
/// the named float tensors of `inputs` and `outputs` (dimension -1: any).
pub fn load_graph(
    path: &Path,
    inputs: &[(String, Vec<i64>)],
    outputs: &[(String, Vec<i64>)],
    threads: usize,
) -> Result<Graph, RomError> {
    let bad = |message: String| RomError::Graph {
        path: path.to_owned(),
        message,
    };
    if !path.is_file() {
        return Err(RomError::MissingFile(path.to_owned()));
    }
    let env = environment()?;
    let session = Session::builder(env)
        .and_then(|b| b.with_intra_threads(threads.max(1)).map_err(Into::into))
        .and_then(|b| b.with_inter_threads(1).map_err(Into::into))
        // Idle ONNX Runtime workers must not spin: the gel's own threads run between the
        // model's calls (measured, two threads: rom 0.7 to 0.87 times as fast as one
        // thread with spinning workers).
        .and_then(|b| b.with_intra_op_spinning(false).map_err(Into::into))
        .and_then(|b| b.with_inter_op_spinning(false).map_err(Into::into))
        // No memory pattern for a graph with a dimension of any size: it plans the
        // allocations per input shape and keeps every plan, and the decoder's rows (the
        // deformed region's lattice points) change from frame to frame. Measured
        // (`examples/soak.py --modes rom-linear --evaluations 20000`): the resident memory
        // grew 288 and 292 KiB over the walk's second half with it, 4 KiB without. The
        // encoder's one shape keeps its plan.
        .and_then(|b| {
            let varying = inputs.iter().any(|(_, shape)| shape.contains(&-1));
            b.with_memory_pattern(!varying).map_err(Into::into)
        })
        .and_then(|mut b| b.commit_from_file(path))
        .map_err(|e| bad(format!("cannot load: {e}")))?;
    for (kind, have, want) in [
        ("input", session.inputs(), inputs),
        ("output", session.outputs(), outputs),
    ] {
        let names: Vec<&str> = have.iter().map(|o| o.name()).collect();
        if have.len() != want.len() {
            return Err(bad(format!(
                "has {kind}s {names:?}, expected {:?}",
                want.iter().map(|w| &w.0).collect::<Vec<_>>()
            )));
        }
        for (name, shape) in want {
            let Some(o) = have.iter().find(|o| o.name() == name) else {
                return Err(bad(format!("has no {kind} '{name}' (it has {names:?})")));
            };
            match o.dtype() {
                ValueType::Tensor { ty, shape: s, .. } => {
                    if *ty != ort::value::TensorElementType::Float32 {
                        return Err(bad(format!("{kind} '{name}' is {ty:?}, expected float32")));
                    }
                    let dims: Vec<i64> = s.iter().copied().collect();
                    if !shape_ok(&dims, shape) {
                        return Err(bad(format!(
                            "{kind} '{name}' has shape {dims:?}, the manifest says {shape:?}"
                        )));
                    }
                }
                other => {
                    return Err(bad(format!(
                        "{kind} '{name}' is {other:?}, expected a tensor"
                    )))
                }
            }
        }
    }
    Ok(Graph { session })
}
