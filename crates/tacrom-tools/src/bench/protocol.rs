//! The press protocol: indenters, positions, depths, physics modes, and running one
//! continuous press sequence in one sensor.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use super::cache::{digest, digest_bytes};
use super::{BenchError, STAGES};
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{load_mesh, MeshSdfOptions, Placed, Sdf, Sphere, TriMesh};
use tacrom::sensor::TactileSensor;

/// The physics modes benchmarked by default, by label and configuration attributes. A new
/// mode (or an ablation of one) is one line here; modes the build does not offer (their
/// configuration is rejected) are listed in the report as unavailable, with the reason.
/// The reference (fine MPM) is configured separately.
pub const MODES: &[(&str, &[(&str, &str)])] = &[
    ("rigid", &[("physics", "rigid")]),
    ("coarse", &[("physics", "coarse")]),
    // rom on the relaxation's coarse gel, its shipped model named (`model="rom-default"`:
    // the gel keeps the linear solver for contacts it misses), as `physics="rom"` ran
    // before its default moved to the linear gel; the labels keep their meaning across the
    // committed baselines and reports.
    ("rom", &[("physics", "rom"), ("model", "rom-default")]),
    // The linear solver's coarse gel, and rom on it: `physics="rom"`'s default (on the
    // profile's 4 mm gel `models/rom-linear-narrow`; the committed report's row is
    // `models/rom-linear`'s, measured while it was the default on every gel).
    (
        "coarse-linear",
        &[("physics", "coarse"), ("solver", "linear")],
    ),
    ("rom-linear", &[("physics", "rom"), ("solver", "linear")]),
    // The solver's tolerance around the default 3e-3: the fine mode's 1e-3, and 1e-2.
    (
        "coarse-tol1e-3",
        &[("physics", "coarse"), ("tolerance", "1e-3")],
    ),
    (
        "coarse-tol1e-2",
        &[("physics", "coarse"), ("tolerance", "1e-2")],
    ),
    (
        "rom-tol1e-3",
        &[
            ("physics", "rom"),
            ("model", "rom-default"),
            ("tolerance", "1e-3"),
        ],
    ),
    (
        "rom-tol1e-2",
        &[
            ("physics", "rom"),
            ("model", "rom-default"),
            ("tolerance", "1e-2"),
        ],
    ),
    // Ablations of rom: no latent refinement ("w/o physics"; the shipped models' default,
    // their manifests say why), the refinement on, latent 16, no multi-scale loss.
    (
        "rom-norefine",
        &[
            ("physics", "rom"),
            ("model", "rom-default"),
            ("refine", "false"),
        ],
    ),
    (
        "rom-refine",
        &[
            ("physics", "rom"),
            ("model", "rom-default"),
            ("refine", "true"),
        ],
    ),
    (
        "rom-latent16",
        &[("physics", "rom"), ("model", "models/rom-latent16")],
    ),
    (
        "rom-no-multiscale",
        &[("physics", "rom"), ("model", "models/rom-no-multiscale")],
    ),
];

/// A physics mode to benchmark: a label and the sensor attributes that select it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModeSpec {
    /// Name in the report.
    pub label: String,
    /// Configuration attributes (`physics`, `dx`, ...), applied over the bench's own.
    pub attrs: Vec<(String, String)>,
}

impl ModeSpec {
    /// The default modes ([`MODES`]).
    pub fn defaults() -> Vec<ModeSpec> {
        MODES
            .iter()
            .map(|(label, attrs)| ModeSpec {
                label: (*label).to_owned(),
                attrs: attrs
                    .iter()
                    .map(|(k, v)| ((*k).to_owned(), (*v).to_owned()))
                    .collect(),
            })
            .collect()
    }

    /// Parses `label` (a default mode, or any physics name) or
    /// `label:key=value,key=value` (for example `coarse-1mm:physics=coarse,dx=1e-3`).
    pub fn parse(spec: &str) -> Result<ModeSpec, BenchError> {
        let bad = |why: &str| BenchError::Usage(format!("mode '{spec}': {why}"));
        let (label, rest) = match spec.split_once(':') {
            Some((l, r)) => (l.trim(), Some(r)),
            None => (spec.trim(), None),
        };
        if label.is_empty() || label.contains(char::is_whitespace) {
            return Err(bad("the label must be one word"));
        }
        let attrs = match rest {
            None => Self::defaults()
                .into_iter()
                .find(|m| m.label == label)
                .map(|m| m.attrs)
                .unwrap_or_else(|| vec![("physics".to_owned(), label.to_owned())]),
            Some(r) => {
                let mut attrs = Vec::new();
                for kv in r.split(',').filter(|s| !s.trim().is_empty()) {
                    let (k, v) = kv
                        .split_once('=')
                        .ok_or_else(|| bad("expected key=value"))?;
                    attrs.push((k.trim().to_owned(), v.trim().to_owned()));
                }
                attrs
            }
        };
        Ok(ModeSpec {
            label: label.to_owned(),
            attrs,
        })
    }

    /// The sensor configuration of this mode over `base`, with `threads` solver threads.
    pub fn config(&self, base: &RawConfig, threads: usize) -> Result<Config, BenchError> {
        let mut raw = base.clone();
        for (k, v) in &self.attrs {
            raw = raw.with(k, v);
        }
        raw = raw.with("threads", &threads.to_string());
        // Rigid penetration has no force model: ask it for the image only (its force
        // error is then that of a zero force).
        if raw.get("physics") == Some("rigid") {
            raw = raw.with("outputs", "depth");
        }
        Config::from_raw(&self.label, &raw).map_err(|e| BenchError::Config(e.to_string()))
    }
}

/// An indenter: a shape, and how to bring its pressing face down onto the gel.
#[derive(Clone, Debug)]
pub struct Indenter {
    /// Name in the report (file stem).
    pub name: String,
    /// The shape, in its own frame.
    pub shape: Arc<dyn Sdf>,
    /// Rotation applied to the shape (a half turn about x when flipped).
    pub rotation: UnitQuaternion<f64>,
    /// Centre of the rotated shape's footprint (x, y) and its lowest z, in the rotated frame.
    pub anchor: Vector3<f64>,
    /// Hash of what determines the shape (file bytes, scale, flip, or the primitive).
    pub fingerprint: String,
}

impl Indenter {
    /// A mesh file (STL or OBJ), coordinates times `scale` (1e-3 for millimetres). With
    /// `flip`, the shape is turned a half turn about x, so that a face at the top of the
    /// file (the patterns' z = 20 mm) presses the gel.
    pub fn from_mesh(path: &Path, scale: f64, flip: bool) -> Result<Indenter, BenchError> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(BenchError::Usage(format!(
                "mesh scale {scale} must be finite and positive"
            )));
        }
        let bytes = std::fs::read(path).map_err(|e| BenchError::Indenter {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let bad = |e: tacrom::geometry::GeometryError| BenchError::Indenter {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let data = load_mesh(path, scale).map_err(bad)?;
        let rotation = if flip {
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
        } else {
            UnitQuaternion::identity()
        };
        let mesh = TriMesh::with_options(data.vertices, data.faces, &MeshSdfOptions::default())
            .map_err(bad)?;
        let anchor = anchor_of(mesh.vertices().iter().map(|p| rotation * p));
        let fingerprint = digest(&[
            ("mesh", digest_bytes(&bytes)),
            ("scale", scale.to_string()),
            ("flip", flip.to_string()),
        ]);
        Ok(Indenter {
            name: path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "mesh".to_owned()),
            shape: Arc::new(mesh),
            rotation,
            anchor,
            fingerprint,
        })
    }

    /// A sphere of `radius` (m).
    pub fn sphere(radius: f64) -> Result<Indenter, BenchError> {
        if !(radius.is_finite() && radius > 0.0) {
            return Err(BenchError::Usage(format!(
                "sphere radius {radius} must be finite and positive"
            )));
        }

        Ok(Indenter {
            name: format!("sphere{:.1}mm", radius * 1e3),
            shape: Arc::new(Sphere::new(radius)),
            rotation: UnitQuaternion::identity(),
            anchor: Vector3::new(0.0, 0.0, -radius),
            fingerprint: digest(&("sphere", radius)),
        })
    }

    /// The pose that puts the footprint's centre at `(x, y)` and the lowest point at
    /// `z = -depth` (m, sensor frame).
    pub fn pose(&self, x: f64, y: f64, depth: f64) -> Isometry3<f64> {
        let t = Vector3::new(x, y, -depth) - self.anchor;
        Isometry3::from_parts(Translation3::from(t), self.rotation)
    }
}

/// Footprint centre (x, y) and lowest z of a point set.
fn anchor_of(points: impl Iterator<Item = Point3<f64>>) -> Vector3<f64> {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in points {
        lo = lo.inf(&p.coords);
        hi = hi.sup(&p.coords);
    }
    Vector3::new(0.5 * (lo.x + hi.x), 0.5 * (lo.y + hi.y), lo.z)
}

/// The STL and OBJ files of `dir`, sorted by name; an error when the folder cannot be read
/// or holds none.
pub fn mesh_files(dir: &Path) -> Result<Vec<PathBuf>, BenchError> {
    let entries = std::fs::read_dir(dir).map_err(|e| BenchError::Indenter {
        path: dir.to_path_buf(),
        message: format!("cannot read the indenter folder: {e}"),
    })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.is_file()
                && p.extension()
                    .and_then(|e| e.to_str())
                    .is_some_and(|e| e.eq_ignore_ascii_case("stl") || e.eq_ignore_ascii_case("obj"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(BenchError::Indenter {
            path: dir.to_path_buf(),
            message: "no .stl or .obj file in the indenter folder".to_owned(),
        });
    }
    Ok(files)
}

/// `n x n` positions centred on the origin, `spacing` apart (m); row by row from +y.
pub fn grid_positions(n: usize, spacing: f64) -> Vec<[f64; 2]> {
    let c = (n as f64 - 1.0) / 2.0;
    let mut out = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            out.push([(i as f64 - c) * spacing, (c - j as f64) * spacing]);
        }
    }
    out
}

/// One evaluation of a press sequence.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Depth image (m).
    pub depth: Vec<f64>,
    /// Total force (N).
    pub force: [f64; 3],
    /// Wall time of the evaluation, scene included (s).
    pub seconds: f64,
    /// Per-stage wall times (s), in [`STAGES`] order; `NaN` where the mode has no such
    /// stage.
    pub stages: [f64; STAGES.len()],
    /// Solver iterations (0 without a solver).
    pub iterations: usize,
    /// Whether the solver converged (true without a solver).
    pub converged: bool,
}

/// Presses `indenter` at `position` through `depths` (m, in order) in one sensor, the gel
/// warm-started from press to press. `on_frame` sees each frame as it is made.
pub fn run_sequence(
    config: &Config,
    indenter: &Indenter,
    position: [f64; 2],
    depths: &[f64],
    mut on_frame: impl FnMut(usize, &Frame),
) -> Result<Vec<Frame>, BenchError> {
    let mut sensor =
        TactileSensor::new(config.clone()).map_err(|e| BenchError::Config(e.to_string()))?;
    let mut out = vec![0.0; config.sensordata_len()];
    let mut frames = Vec::with_capacity(depths.len());
    for (k, &d) in depths.iter().enumerate() {
        // Scene: the indenter posed in the sensor frame (what the MuJoCo layer does).
        let t0 = Instant::now();
        let placed = [Placed {
            shape: indenter.shape.clone(),
            pose: indenter.pose(position[0], position[1], d),
        }];
        let scene = t0.elapsed().as_secs_f64();
        let eval = sensor.evaluate(&placed, &mut out);
        let seconds = t0.elapsed().as_secs_f64();
        let f = sensor.force();
        // scene, SDF, MPM, encoder, refinement, decoder, render; the rom stages are part of
        // the sensor's physics time, so MPM is what remains of it.
        let (encoder, refinement, decoder) = match &eval.rom {
            Some(r) => (r.encode_s, r.refine_s, r.decode_s),
            None => (f64::NAN, f64::NAN, f64::NAN),
        };
        let rom_total = [encoder, refinement, decoder]
            .iter()
            .filter(|t| t.is_finite())
            .sum::<f64>();
        let stages = [
            scene,
            eval.times.geometry,
            eval.times.physics - rom_total,
            encoder,
            refinement,
            decoder,
            eval.times.render,
        ];
        let frame = Frame {
            depth: sensor.depth().to_vec(),
            force: [f[0], f[1], f[2]],
            seconds,
            stages,
            iterations: eval.solve.map_or(0, |s| s.iterations),
            converged: eval.solve.map_or(true, |s| s.converged),
        };
        on_frame(k, &frame);
        frames.push(frame);
    }
    Ok(frames)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_parse() {
        let m = ModeSpec::parse("coarse").unwrap();
        assert_eq!(m.attrs, vec![("physics".to_owned(), "coarse".to_owned())]);
        let m = ModeSpec::parse("c1:physics=coarse, dx=1e-3").unwrap();
        assert_eq!(m.label, "c1");
        assert_eq!(m.attrs[1], ("dx".to_owned(), "1e-3".to_owned()));
        assert!(ModeSpec::parse("x:physics").is_err());
        assert!(ModeSpec::parse(":physics=rigid").is_err());
        // An unknown physics is rejected by the configuration, with its message.
        let e = ModeSpec::parse("warp")
            .unwrap()
            .config(&RawConfig::default(), 1)
            .unwrap_err();
        assert!(e.to_string().contains("physics"), "{e}");
    }

    #[test]
    fn positions_are_centred_and_row_major_from_plus_y() {
        let p = grid_positions(3, 2e-3);
        assert_eq!(p.len(), 9);
        assert_eq!(p[4], [0.0, 0.0]);
        assert_eq!(p[0], [-2e-3, 2e-3]);
        assert_eq!(p[8], [2e-3, -2e-3]);
    }

    #[test]
    fn a_sphere_touches_at_the_requested_depth() {
        let s = Indenter::sphere(5e-3).unwrap();
        let pose = s.pose(1e-3, -2e-3, 0.3e-3);
        let lowest = pose * Point3::new(0.0, 0.0, -5e-3);
        assert!((lowest - Point3::new(1e-3, -2e-3, -0.3e-3)).norm() < 1e-15);
        assert!(Indenter::sphere(-1.0).is_err());
    }

    #[test]
    fn bad_folders_and_meshes_are_errors() {
        let e = mesh_files(Path::new("/nonexistent/folder")).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/folder"), "{e}");
        let dir = std::env::temp_dir().join(format!("tacrom-bench-mesh-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert!(mesh_files(&dir).is_err());
        let bad = dir.join("bad.obj");
        std::fs::write(&bad, "v 0 0 0\nf 1 2 3\n").unwrap();
        let e = Indenter::from_mesh(&bad, 1e-3, true).unwrap_err();
        assert!(e.to_string().contains("bad.obj"), "{e}");
        assert!(Indenter::from_mesh(&bad, 0.0, true).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_flipped_mesh_presses_with_its_top_face() {
        // A tetrahedron with its apex at the top (z = 2): flipped, the apex is lowest.
        let dir = std::env::temp_dir().join(format!("tacrom-bench-tet-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("tet.obj");
        std::fs::write(
            &path,
            "v 0 0 0\nv 2 0 0\nv 0 2 0\nv 0 0 2\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n",
        )
        .unwrap();
        let t = Indenter::from_mesh(&path, 1e-3, true).unwrap();
        let pose = t.pose(0.0, 0.0, 0.5e-3);
        let apex = pose * (Point3::new(0.0, 0.0, 2e-3));
        assert!((apex.z + 0.5e-3).abs() < 1e-12, "{apex}");
        // The apex is inside-or-on the solid, a point just below is outside.
        let placed = Placed {
            shape: t.shape.clone(),
            pose,
        };
        assert!(placed.distance(&Point3::new(apex.x, apex.y, apex.z - 1e-4)) > 0.0);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
