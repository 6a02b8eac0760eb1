//! ONNX Runtime failing a call under a running sensor. The shipped model with its decoder
//! replaced by a graph that loads (its inputs and outputs are the manifest's) but cannot run
//! the frames' inputs: it reshapes its result to 7 rows, so ONNX Runtime returns an error
//! from every call with another number of query points. The sensor must name the failure
//! in a warning, fall back to the coarse surface for that frame, keep its output finite and
//! its force the coarse gel's, and go on working (further frames, a copy, a reset).
//!
//! The graph is written here as ONNX's protobuf, field by field (no ONNX package needed).

use std::sync::Arc;

use nalgebra::Isometry3;
use tacrom::config::{Config, RawConfig, ATTR_MODEL, ATTR_OUTPUTS, ATTR_RESOLUTION};
use tacrom::geometry::{Placed, Sphere};
use tacrom::sensor::TactileSensor;

/// Protobuf's wire format, as much of it as a small ONNX graph needs.
#[derive(Default)]
struct Message(Vec<u8>);

impl Message {
    fn varint(&mut self, mut v: u64) -> &mut Self {
        loop {
            let byte = (v & 0x7f) as u8;
            v >>= 7;
            if v == 0 {
                self.0.push(byte);
                return self;
            }
            self.0.push(byte | 0x80);
        }
    }

    fn int(&mut self, field: u64, v: i64) -> &mut Self {
        self.varint(field << 3).varint(v as u64)
    }

    fn bytes(&mut self, field: u64, data: &[u8]) -> &mut Self {
        self.varint((field << 3) | 2).varint(data.len() as u64);
        self.0.extend_from_slice(data);
        self
    }

    fn text(&mut self, field: u64, s: &str) -> &mut Self {
        self.bytes(field, s.as_bytes())
    }

    fn message(&mut self, field: u64, m: &Message) -> &mut Self {
        self.bytes(field, &m.0)
    }
}

/// A float tensor's `ValueInfoProto`: `dims` with -1 for a symbolic dimension.
fn value_info(name: &str, dims: &[i64]) -> Message {
    let mut shape = Message::default();
    for &d in dims {
        let mut dim = Message::default();
        if d < 0 {
            dim.text(2, "N");
        } else {
            dim.int(1, d);
        }
        shape.message(1, &dim);
    }
    let mut tensor = Message::default();
    tensor.int(1, 1).message(2, &shape); // elem_type FLOAT, shape
    let mut ty = Message::default();
    ty.message(1, &tensor); // tensor_type
    let mut info = Message::default();
    info.text(1, name).message(2, &ty);
    info
}

/// An `int64` initializer of `values` (one dimension).
fn int64_tensor(name: &str, values: &[i64]) -> Message {
    let mut t = Message::default();
    t.int(1, values.len() as i64).int(2, 7).text(8, name); // dims, INT64, name
    let raw: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    t.bytes(9, &raw);
    t
}

fn node(op: &str, inputs: &[&str], output: &str) -> Message {
    let mut n = Message::default();
    for i in inputs {
        n.text(1, i);
    }
    n.text(2, output).text(3, output).text(4, op);
    n
}

/// The decoder's interface (`z` `[1, latent]`, `query` `[N, features]` in, `depth` `[N, 1]`
/// out) over `depth = Reshape(ReduceSum(query, axis 1), [7, 1])`: a run fails unless N is 7.
fn failing_decoder(latent: i64, features: i64) -> Vec<u8> {
    let mut graph = Message::default();
    graph
        .message(1, &node("ReduceSum", &["query", "axes"], "sum"))
        .message(1, &node("Reshape", &["sum", "rows"], "depth"))
        .text(2, "fails-unless-seven-rows")
        .message(5, &int64_tensor("axes", &[1]))
        .message(5, &int64_tensor("rows", &[7, 1]))
        .message(11, &value_info("z", &[1, latent]))
        .message(11, &value_info("query", &[-1, features]))
        .message(12, &value_info("depth", &[-1, 1]));
    let mut opset = Message::default();
    opset.text(1, "").int(2, 17);
    let mut model = Message::default();
    model
        .int(1, 8) // ir_version
        .text(2, "tacrom-tests")
        .message(7, &graph)
        .message(8, &opset);
    model.0
}

/// The shipped default model with the failing decoder, in a folder of its own.
fn model_with_failing_decoder() -> std::path::PathBuf {
    let src = tacrom::rom::default_model_dir().expect("shipped model");
    let dir = std::env::temp_dir().join(format!("tacrom-failing-decoder-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for f in [
        "encoder.onnx",
        "decoder_jacobian.onnx",
        "pressure.onnx",
        "manifest.json",
    ] {
        std::fs::copy(src.join(f), dir.join(f)).unwrap();
    }
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(src.join("manifest.json")).unwrap()).unwrap();
    let latent = m["latent"].as_i64().unwrap();
    let features = m["query_features"].as_i64().unwrap();
    assert_eq!(m["files"]["decoder"]["path"], "decoder.onnx");
    std::fs::write(dir.join("decoder.onnx"), failing_decoder(latent, features)).unwrap();
    dir
}

#[test]
fn a_decoder_that_fails_at_run_time_leaves_the_coarse_surface_and_a_warning() {
    let dir = model_with_failing_decoder();
    let raw = RawConfig::default()
        .with(ATTR_MODEL, dir.to_str().unwrap())
        .with(ATTR_RESOLUTION, "64 48")
        .with(ATTR_OUTPUTS, "depth force");
    let config = Config::from_raw("touch", &raw).unwrap();
    // It loads: the graph's interface is the manifest's.
    let mut sensor = TactileSensor::new(config.clone()).expect("the model loads");
    // The same gel without a model, for the coarse surface and force it falls back to.
    let coarse_raw = RawConfig::default()
        .with("physics", "coarse")
        .with(ATTR_RESOLUTION, "64 48")
        .with(ATTR_OUTPUTS, "depth force");
    let mut coarse = TactileSensor::new(Config::from_raw("plain", &coarse_raw).unwrap()).unwrap();
    let ball: Arc<dyn tacrom::geometry::Sdf> = Arc::new(Sphere::new(0.005));
    let at = |d: f64, x: f64| {
        [Placed {
            shape: ball.clone(),
            pose: Isometry3::translation(x, 0.0, 0.005 - d),
        }]
    };
    let n = config.sensordata_len();
    let (mut out, mut plain) = (vec![0.0; n], vec![0.0; n]);
    for (k, (d, x)) in [(0.2e-3, 0.0), (0.5e-3, 0.0), (0.5e-3, 1e-3)]
        .into_iter()
        .enumerate()
    {
        let eval = sensor.evaluate(&at(d, x), &mut out);
        coarse.evaluate(&at(d, x), &mut plain);
        assert!(eval.rom.is_none(), "frame {k}: the decoder ran");
        assert!(
            eval.warnings.iter().any(|w| w.contains("'touch'")
                && w.contains("decoder")
                && w.contains("coarse depth used")),
            "frame {k}: {:?}",
            eval.warnings
        );
        assert!(out.iter().all(|v| v.is_finite()), "frame {k}");
        assert!(
            out[..64 * 48].iter().any(|&v| v > 0.0),
            "frame {k}: no imprint"
        );
        assert_eq!(out, plain, "frame {k}: not the coarse surface and force");
    }
    // A copy and a reset keep working, and fail the same way.
    let mut copy = sensor.try_clone().expect("a copy");
    let eval = copy.evaluate(&at(0.3e-3, 0.0), &mut out);
    assert!(eval.rom.is_none() && out.iter().all(|v| v.is_finite()));
    sensor.reset();
    let eval = sensor.evaluate(&[], &mut out);
    assert!(eval.warnings.is_empty(), "{:?}", eval.warnings);
    assert!(out.iter().all(|&v| v == 0.0));
}
