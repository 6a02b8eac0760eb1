//! ONNX Runtime: finding its library, the one environment of the process, sessions with
//! their inputs and outputs checked.
//!
//! The library is `libonnxruntime.so*` of the PyPI `onnxruntime` wheel. It is looked for,
//! in order: `ORT_DYLIB_PATH`; a copy already loaded in the process (Python imported
//! `onnxruntime`); beside the loaded MuJoCo (`site-packages/mujoco/libmujoco.so*` ->
//! `site-packages/onnxruntime/capi/`); beside this library (its own path, walking up to a
//! `.venv`); and the source tree's `.venv` (tests and tools run from the checkout).

use std::hash::{Hash, Hasher};
use std::mem::ManuallyDrop;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

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

/// One ONNX graph with its named inputs and outputs checked against the manifest. Its
/// session goes back to the process's idle sessions when it is dropped ([`load_graph`]).
pub struct Graph {
    session: ManuallyDrop<Session>,
    key: GraphKey,
}

impl Graph {
    /// The session, to run.
    pub fn session(&mut self) -> &mut Session {
        &mut self.session
    }
}

impl Drop for Graph {
    fn drop(&mut self) {
        // SAFETY: `session` is taken once, here, and the graph is not used after its drop.
        let session = unsafe { ManuallyDrop::take(&mut self.session) };
        give_back(self.key, session);
    }
}

impl std::fmt::Debug for Graph {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Graph").finish_non_exhaustive()
    }
}

/// What makes two loads of a graph interchangeable: the file's bytes (their length and
/// digest, so that a file replaced at the same path, however soon, is another graph) and
/// the session's settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct GraphKey {
    len: usize,
    digest: u64,
    threads: usize,
    memory_pattern: bool,
}

/// Sessions of dropped graphs, oldest first, for the next load of the same bytes with the
/// same settings. Making and dropping an ONNX Runtime session leaves about 2 KiB behind
/// in the process each time (measured: `examples/soak.py --modes rom --cycles 400`, 1.9
/// KiB per model load/free cycle, a model being two to four sessions; docs/benchmarks.md),
/// and costs milliseconds; a sensor made again, an `MjData` copied for a rollout's
/// thread, or a model loaded per episode takes a kept one instead. Each session stays
/// with one graph while it lives, so sensors running at once never share one.
static IDLE: Mutex<Vec<(GraphKey, Session)>> = Mutex::new(Vec::new());

/// At most this many idle sessions are kept (the oldest dropped first): those of the last
/// few models freed (a model is two to four graphs), so that a process that freed its
/// sensors keeps a bounded set of their weights and arenas.
const IDLE_SESSIONS: usize = 12;

fn idle() -> std::sync::MutexGuard<'static, Vec<(GraphKey, Session)>> {
    // A panic elsewhere while holding the lock leaves the list itself whole.
    IDLE.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

fn take_idle(key: GraphKey) -> Option<Session> {
    let mut idle = idle();
    let i = idle.iter().rposition(|(k, _)| *k == key)?;
    Some(idle.remove(i).1)
}

fn give_back(key: GraphKey, session: Session) {
    let evicted = {
        let mut idle = idle();
        idle.push((key, session));
        let over = idle.len().saturating_sub(IDLE_SESSIONS);
        idle.drain(..over).collect::<Vec<_>>()
    };
    // Dropped outside the lock: freeing a session takes time.
    drop(evicted);
}

/// Idle sessions kept for a file of these bytes (any settings): for tests.
#[cfg(test)]
fn idle_sessions_of(bytes: &[u8]) -> usize {
    let (len, digest) = (bytes.len(), digest(bytes));
    idle()
        .iter()
        .filter(|(k, _)| k.len == len && k.digest == digest)
        .count()
}

fn digest(bytes: &[u8]) -> u64 {
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    bytes.hash(&mut hasher);
    hasher.finish()
}

fn shape_ok(actual: &[i64], expected: &[i64]) -> bool {
    actual.len() == expected.len()
        && actual
            .iter()
            .zip(expected)
            .all(|(&a, &e)| e < 0 || a < 0 || a == e)
}

/// Loads `path` on `threads` intra-op threads (a session kept from a dropped graph of
/// the same bytes and settings where there is one: [`IDLE`]) and checks that its inputs
/// and outputs are exactly the named float tensors of `inputs` and `outputs` (dimension
/// -1: any).
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
    let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot read: {e}")))?;
    // No memory pattern for a graph with a dimension of any size: it plans the
    // allocations per input shape and keeps every plan, and the decoder's rows (the
    // deformed region's lattice points) change from frame to frame. Measured
    // (`examples/soak.py --modes rom-linear --evaluations 20000`): the resident memory
    // grew 288 and 292 KiB over the walk's second half with it, 4 KiB without. The
    // encoder's one shape keeps its plan.
    let varying = inputs.iter().any(|(_, shape)| shape.contains(&-1));
    let key = GraphKey {
        len: bytes.len(),
        digest: digest(&bytes),
        threads: threads.max(1),
        memory_pattern: !varying,
    };
    let session = match take_idle(key) {
        Some(session) => session,
        None => {
            let env = environment()?;
            Session::builder(env)
                .and_then(|b| b.with_intra_threads(key.threads).map_err(Into::into))
                .and_then(|b| b.with_inter_threads(1).map_err(Into::into))
                // Idle ONNX Runtime workers must not spin: the gel's own threads run
                // between the model's calls (measured, two threads: rom 0.7 to 0.87 times
                // as fast as one thread with spinning workers).
                .and_then(|b| b.with_intra_op_spinning(false).map_err(Into::into))
                .and_then(|b| b.with_inter_op_spinning(false).map_err(Into::into))
                .and_then(|b| {
                    b.with_memory_pattern(key.memory_pattern)
                        .map_err(Into::into)
                })
                .and_then(|mut b| b.commit_from_memory(&bytes))
                .map_err(|e| bad(format!("cannot load: {e}")))?
        }
    };
    let graph = Graph {
        session: ManuallyDrop::new(session),
        key,
    };
    let session = &graph.session;
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
    Ok(graph)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seed graph of the fuzz corpus with `tag` as its doc string (ONNX `ModelProto`
    /// field 6, appended), so that its bytes are this test's alone.
    fn tagged(seed: &str, tag: &str) -> Vec<u8> {
        let path = crate::checkout_root().join("fuzz/corpus/graph").join(seed);
        let mut bytes = std::fs::read(path).unwrap();
        bytes.extend([0x32, tag.len() as u8]);
        bytes.extend(tag.as_bytes());
        bytes
    }

    /// A dropped graph's session is kept and given to the next load of the same bytes,
    /// which runs as the fresh one did; a file replaced at the same path by other bytes of
    /// the same length, at once, is loaded afresh and judged on its own (here: refused for
    /// its integer output by ONNX Runtime), not served the kept session of the old bytes.
    #[test]
    fn kept_sessions_follow_the_bytes_not_the_path() {
        let dir = std::env::temp_dir().join(format!("tacrom-idle-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("graph.onnx");
        let sum = tagged("seed-sum", "kept sessions");
        let int = tagged("seed-int-output", "kept sessions");
        assert_eq!(sum.len(), int.len());
        let inputs = [
            ("z".to_owned(), vec![1, 4]),
            ("query".to_owned(), vec![-1, 3]),
        ];
        let outputs = [("depth".to_owned(), vec![-1, 1])];
        let (z, query) = ([0.1f32, -0.2, 0.3, 0.0], [1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let run =
            |graph: &mut Graph| crate::rom::run_field(graph, "decoder", "depth", &z, &query, 2, 3);

        std::fs::write(&path, &sum).unwrap();
        let mut fresh = load_graph(&path, &inputs, &outputs, 1).unwrap();
        assert_eq!(run(&mut fresh).unwrap(), [6.0, 15.0]);
        assert_eq!(idle_sessions_of(&sum), 0);
        drop(fresh);
        assert_eq!(
            idle_sessions_of(&sum),
            1,
            "the dropped graph's session is kept"
        );
        let mut again = load_graph(&path, &inputs, &outputs, 1).unwrap();
        assert_eq!(idle_sessions_of(&sum), 0, "the next load takes it");
        assert_eq!(run(&mut again).unwrap(), [6.0, 15.0]);
        drop(again);

        std::fs::write(&path, &int).unwrap();
        let err = load_graph(&path, &inputs, &outputs, 1).unwrap_err();
        assert!(err.to_string().contains("cannot load"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
