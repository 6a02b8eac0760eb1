//! Entry points for the coverage-guided fuzzers (`fuzz/`, run with `cargo +nightly fuzz run
//! TARGET`) and for the replay of their corpora in `make test` (`tests/fuzz_corpus.rs`).
//!
//! Each target takes arbitrary bytes and runs one parser or loader the way the plugin runs
//! it on a user's input: the MJCF attributes, an OBJ or STL mesh, an optics file and its
//! background PNG, a reduced-order model's manifest and an ONNX graph it names, a state
//! given to `mj_setState`. A parser may refuse its input; a panic, an abort, a hang or a
//! non-finite value where the parser accepted its input is a finding.

use std::path::PathBuf;
use std::sync::{Arc, Mutex, OnceLock};

use nalgebra::Isometry3;

use crate::config::{Config, RawConfig};
use crate::geometry::{parse_obj, parse_stl, MeshSdfOptions, Placed, Sdf, Sphere};
use crate::mpm::{Gel, GelParams, Solver, SolverOptions};
use crate::render::calibrated::CalibratedOptics;
use crate::rom::Manifest;
use crate::sensor::TactileSensor;
use crate::state::Io;

/// A fuzz target: arbitrary bytes in, a panic on a finding.
pub type Target = fn(&[u8]);

/// Every target by name (the names of `fuzz/fuzz_targets/*.rs` and of the corpus folders).
pub const TARGETS: &[(&str, Target)] = &[
    ("config", config),
    ("mesh", mesh),
    ("optics", optics),
    ("manifest", manifest),
    ("graph", graph),
    ("state", state),
];

/// Attributes whose values name files: left out of the configuration target, which must
/// not read whatever path the fuzzer writes (the loaders of those files have their own
/// targets).
const FILE_ATTRIBUTES: [&str; 2] = ["model", "optics"];

/// The MJCF attributes: one `name=value` per line (a line without `=` is a name with an
/// empty value). Parsed as at compile time, then as at `init`, and a valid configuration's
/// sizes (sensordata, plugin state, the layout the Python package reads) computed.
pub fn config(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let mut raw = RawConfig::default();
    for line in text.lines() {
        let (name, value) = line.split_once('=').unwrap_or((line, ""));
        if !value.trim().is_empty() && !FILE_ATTRIBUTES.contains(&name) {
            raw = raw.with(name, value);
        }
    }
    let Ok(config) = Config::without_files("fuzz", &raw) else {
        return;
    };
    let _ = config.sensordata_len();
    let _ = crate::config::layout_json(&config);
    let _ = TactileSensor::state_len(&config, 8);
    let full = Config::from_raw("fuzz", &raw).expect("a configuration without files parses");
    assert_eq!(full.sensordata_len(), config.sensordata_len());
}

/// An OBJ file (first byte even) or an STL file (odd), the rest of the bytes its content,
/// parsed at millimetre scale and, where it parses, turned into the signed distance field
/// the indenter uses, on a grid of at most 4096 nodes (the plugin's holds up to 8 million:
/// the same code, at a size that lets the fuzzer run thousands of inputs a second).
pub fn mesh(data: &[u8]) {
    let Some((&kind, bytes)) = data.split_first() else {
        return;
    };
    let parsed = if kind % 2 == 0 {
        parse_obj(bytes, 1e-3)
    } else {
        parse_stl(bytes, 1e-3)
    };
    if let Ok(mesh) = parsed {
        let options = MeshSdfOptions {
            cells_per_extent: 8,
            max_nodes: 4096,
            ..MeshSdfOptions::default()
        };
        if let Ok(sdf) = mesh.into_trimesh(&options) {
            let d = sdf.distance(&nalgebra::Point3::origin());
            assert!(!d.is_nan(), "a mesh that loads gives a distance");
        }
    }
}

/// An optics file: the first byte says which part the fuzzer writes (even: the JSON, with
/// a valid background; odd: the background PNG, with a valid JSON naming it), the rest is
/// its content.
pub fn optics(data: &[u8]) {
    let Some((&kind, bytes)) = data.split_first() else {
        return;
    };
    let dir = scratch("optics");
    let json = dir.join("optics.json");
    let png = dir.join("background.png");
    if kind % 2 == 0 {
        std::fs::write(&json, bytes).expect("scratch file");
        std::fs::write(&png, valid_png()).expect("scratch file");
    } else {
        std::fs::write(&json, VALID_OPTICS).expect("scratch file");
        std::fs::write(&png, bytes).expect("scratch file");
    }
    let _ = CalibratedOptics::load(&json);
}

/// A reduced-order model's `manifest.json` (the ONNX graphs it names are not there: the
/// manifest is checked before they are read).
pub fn manifest(data: &[u8]) {
    let dir = scratch("manifest");
    std::fs::write(dir.join("manifest.json"), data).expect("scratch file");
    let _ = Manifest::load(&dir);
}

/// An ONNX graph file as a model directory names it, with a small decoder's interface
/// (`z` `[1, 4]` and `query` `[N, 3]` in, `depth` `[N, 1]` out): loaded by ONNX Runtime and
/// checked against the interface as a model's graphs are; one that loads is run once, on
/// three query rows, as a frame runs the decoder. Either may fail with an error; neither
/// may panic or abort the process.
pub fn graph(data: &[u8]) {
    let path = scratch("graph").join("graph.onnx");
    std::fs::write(&path, data).expect("scratch file");
    let inputs = [
        ("z".to_owned(), vec![1, 4]),
        ("query".to_owned(), vec![-1, 3]),
    ];
    let outputs = [("depth".to_owned(), vec![-1, 1])];
    let Ok(mut graph) = crate::rom::runtime::load_graph(&path, &inputs, &outputs, 1) else {
        return;
    };
    let (z, query) = ([0.1f32, -0.2, 0.3, 0.0], [0.5f32; 9]);
    let _ = crate::rom::run_field(&mut graph, "decoder", "depth", &z, &query, 3, 3);
}

/// A state given to `mj_setState`: the bytes as little-endian `f64` (or, for an odd first
/// byte, written over the start of a real state), read into a small frictional gel
/// (relaxation with the linear fallback). A state it
/// reads must leave a gel that solves the next frame to finite values; one it refuses
/// leaves the gel to be reset.
pub fn state(data: &[u8]) {
    /// The gel the states are read into, and a real state of it after a press.
    static GEL: OnceLock<Mutex<(Gel, Vec<f64>)>> = OnceLock::new();
    let shapes: &[Arc<dyn Sdf>] = shapes();
    let gel = GEL.get_or_init(|| {
        // 4 x 4 x 2 mm at 1 mm (256 particles): small, so that thousands of states a
        // second are read and solved.
        let params = GelParams {
            size: [0.004, 0.004, 0.002],
            dx: 1e-3,
            friction: 0.5,
            ..Default::default()
        };
        let options = SolverOptions {
            solver: Solver::Relaxation,
            fallback: true,
            threads: 1,
            max_iterations: 20,
            ..Default::default()
        };
        let mut pressed = Gel::new(params, options).expect("a valid gel");
        pressed.solve(&[press(shapes, 0.3e-3)]);
        let mut real = vec![0.0; 1 << 16];
        let mut io = Io::save(&mut real);
        pressed.persist(&mut io, shapes);
        let written = io.position();
        real.truncate(written);
        let fresh = Gel::new(params, options).expect("a valid gel");
        Mutex::new((fresh, real))
    });
    let mut gel = gel.lock().unwrap_or_else(|e| e.into_inner());
    let (gel, real) = &mut *gel;
    let numbers: Vec<f64> = data
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
        .collect();
    // Half the inputs start from a real state with the fuzzer's numbers written over its
    // start, so that reads get past the first fields.
    let buffer = if data.first().is_some_and(|b| b % 2 == 1) {
        let mut buffer = real.clone();
        let n = numbers.len().min(buffer.len());
        buffer[..n].copy_from_slice(&numbers[..n]);
        buffer
    } else {
        numbers
    };
    let mut io = Io::load(&buffer);
    gel.persist(&mut io, shapes);
    if io.fault().is_some() {
        gel.reset();
        return;
    }
    gel.solve(&[press(shapes, 0.25e-3)]);
    let force = gel.force();
    assert!(force.iter().all(|f| f.is_finite()), "force {force:?}");
    gel.reset();
}

/// The state target's indenter shapes.
fn shapes() -> &'static [Arc<dyn Sdf>] {
    static SHAPES: OnceLock<Vec<Arc<dyn Sdf>>> = OnceLock::new();
    SHAPES.get_or_init(|| vec![Arc::new(Sphere::new(2e-3)), Arc::new(Sphere::new(0.3e-3))])
}

/// Runs every file of the committed corpus `fuzz/corpus/NAME` through `target` (on the
/// stable toolchain, as `make test` replays the corpora), panicking with the name of the
/// first file it panics on.
pub fn replay_corpus(name: &str, target: Target) {
    let dir = crate::checkout_root().join("fuzz/corpus").join(name);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("a corpus entry").path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no corpus for target {name}");
    for file in files {
        let data = std::fs::read(&file).expect("a corpus file");
        let run = std::panic::catch_unwind(|| target(&data));
        assert!(run.is_ok(), "target {name} panics on {}", file.display());
    }
}

/// The state target's press: the larger sphere `depth` into the gel's centre.
fn press(shapes: &[Arc<dyn Sdf>], depth: f64) -> Placed {
    Placed {
        shape: shapes[0].clone(),
        pose: Isometry3::translation(0.3e-3, 0.0, 2e-3 - depth),
    }
}

/// This process's and thread's scratch folder for `target` (the command's targets use it
/// too).
pub fn scratch(target: &str) -> PathBuf {
    let thread = format!("{:?}", std::thread::current().id());
    let thread: String = thread.chars().filter(char::is_ascii_digit).collect();
    let dir = std::env::temp_dir().join(format!(
        "tacrom-fuzz-{}-{thread}-{target}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).expect("scratch folder");
    dir
}

/// An optics file that loads, naming `background.png`.
const VALID_OPTICS: &str = r#"{"format": "tacrom.optics", "version": 1, "bins": [2, 2],
"range": [1.0, 1.0], "table": [[[0,0,0],[1,1,1]],[[2,2,2],[3,3,3]]],
"background": "background.png"}"#;

/// A 2 x 2 RGB PNG.
fn valid_png() -> &'static [u8] {
    static PNG: OnceLock<Vec<u8>> = OnceLock::new();
    PNG.get_or_init(|| {
        let img = image::RgbImage::from_pixel(2, 2, image::Rgb([120, 125, 135]));
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Png)
            .expect("a PNG in memory");
        out.into_inner()
    })
}

#[cfg(test)]
mod tests {
    use crate::rom::runtime::load_graph;

    /// The graph target's seeds are what they say: the two small decoders load with the
    /// interface and run (`seed-sum`: each query row's sum; `seed-matmul`: `query w` plus
    /// the latent's sum), the one that reshapes to seven rows loads and fails at run time
    /// with an error, and the ones with another output's name or type, an input no node
    /// makes, an unknown operator or no graph at all are refused at load with an error.
    #[test]
    fn the_graph_seeds_load_run_or_fail_as_named() {
        let dir = crate::checkout_root().join("fuzz/corpus/graph");
        let inputs = [
            ("z".to_owned(), vec![1, 4]),
            ("query".to_owned(), vec![-1, 3]),
        ];
        let outputs = [("depth".to_owned(), vec![-1, 1])];
        let load = |name: &str| load_graph(&dir.join(name), &inputs, &outputs, 1);
        let z = [0.1f32, -0.2, 0.3, 0.0];
        let query = [1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0, 0.5, 0.5, 0.5];
        let run = |name: &str| {
            let mut graph = load(name).unwrap_or_else(|e| panic!("{name}: {e}"));
            crate::rom::run_field(&mut graph, "decoder", "depth", &z, &query, 3, 3)
        };
        assert_eq!(run("seed-sum").unwrap(), [6.0, 15.0, 1.5]);
        let zsum: f32 = z.iter().sum();
        let expected = [4.5 + zsum, 9.0 + zsum, 0.75 + zsum];
        let got = run("seed-matmul").unwrap();
        assert!(
            got.iter().zip(expected).all(|(a, b)| (a - b).abs() < 1e-6),
            "{got:?}"
        );
        assert!(run("seed-seven-rows").is_err());
        for name in [
            "seed-wrong-output-name",
            "seed-int-output",
            "seed-missing-node-input",
            "seed-unknown-op",
            "seed-empty",
            "seed-text",
        ] {
            assert!(load(name).is_err(), "{name} loaded");
        }
    }
}
