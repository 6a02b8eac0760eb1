//! The stability suite: stiff and near-incompressible gels, deep and sharp presses, jumps,
//! presses through the gel, rotating and sliding indenters, and non-finite poses.
//!
//! Every case is a short sequence of sensor evaluations, then a lift and one ordinary
//! press (does the sensor still work?). [`run_case`] checks each frame: all outputs finite,
//! depth within `[0, T]`, the gel's own surface (before the depth rule bounds it) no deeper
//! than the deepest indenter point, `det F` within the solver's clamp bounds, equilibrium
//! reached or a warning that reports the residual, and for `rom` that the model ran rather
//! than fall back to the coarse depth. The final press must equal a fresh sensor's.
//! `tacrom stability` prints the table; the tests in `tests/stability.rs` assert every row.

use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{Cuboid, Placed, Sdf, Sphere, TriMesh};
use tacrom::mpm::{J_MAX, J_MIN};
use tacrom::sensor::TactileSensor;

/// One indenter pose per frame; `None` frames have no indenter.
pub type Sequence = Vec<Vec<Placed>>;

/// A stability case.
#[derive(Clone, Debug)]
pub struct Case {
    /// Short name for the table.
    pub name: String,
    /// Attribute overrides on top of the defaults (physics, young, poisson, ...).
    pub config: Vec<(String, String)>,
    /// The frames.
    pub frames: Sequence,
}

/// The outcome of one case.
#[derive(Clone, Debug)]
pub struct Row {
    /// Case name.
    pub name: String,
    /// Frames evaluated (the final ordinary press included).
    pub frames: usize,
    /// Every output of every frame finite.
    pub finite: bool,
    /// Every depth within `[0, T]`.
    pub depth_in_range: bool,
    /// Deepest pixel seen (m).
    pub max_depth: f64,
    /// How far the model's surface sank below the deepest indenter point before the depth
    /// rule bounded it, the most of any frame (m; [`Evaluation::bound_excess`]).
    ///
    /// [`Evaluation::bound_excess`]: tacrom::sensor::Evaluation
    pub max_excess: f64,
    /// `max_excess` within [`OVERSHOOT`]: a gel pressed by rigid bodies cannot sink below
    /// the deepest of them.
    pub depth_bounded_by_indenter: bool,
    /// Smallest and largest `det F` reported by the solver.
    pub det_f: (f64, f64),
    /// `det F` within `[J_MIN, J_MAX]` in every frame.
    pub det_f_in_bounds: bool,
    /// Frames whose solve converged, of those that ran the solver.
    pub converged: (usize, usize),
    /// Every unconverged frame came with a warning naming the residual.
    pub warned_when_unconverged: bool,
    /// Largest iteration count and largest final residual.
    pub max_iterations: usize,
    /// Largest final residual.
    pub max_residual: f64,
    /// Frames in contact where `physics="rom"` fell back to the coarse depth (its model
    /// failed); always 0 for the other modes.
    pub fallbacks: usize,
    /// After a lift, the final ordinary press gave the outputs of a fresh sensor, bit for
    /// bit (with nothing pressing, the flat gel is the equilibrium: no state survives).
    pub recovered: bool,
    /// The configuration was refused at load (the message), as for a material the
    /// reduced-order model was not trained for; no frame ran.
    pub refused: Option<String>,
    /// Median wall time per frame (ms).
    pub median_ms: f64,
}

impl Row {
    /// Whether every check passed.
    pub fn ok(&self) -> bool {
        self.failures().is_empty()
    }

    /// The names of the checks that failed.
    pub fn failures(&self) -> Vec<&'static str> {
        let checks = [
            (self.finite, "finite"),
            (self.depth_in_range, "depth range"),
            (self.depth_bounded_by_indenter, "overshoot"),
            (self.det_f_in_bounds, "det F"),
            (self.warned_when_unconverged, "silent non-convergence"),
            (self.fallbacks == 0, "rom fell back"),
            (self.recovered, "next press"),
            (self.refused.is_none(), "refused"),
        ];
        checks
            .iter()
            .filter(|(ok, _)| !ok)
            .map(|(_, name)| *name)
            .collect()
    }
}

/// How far the gel's own surface may sink below the deepest indenter point (m) before a
/// case fails. An elastic layer pressed by rigid bodies peaks where it touches them, so
/// the bound is the discretisation's, not the physics': contact holds the surface points
/// on the indenter to within the solve's tolerance, and the image interpolates them with
/// Catmull-Rom splines, which overshoot a kink (a cone tip, a ridge) by a fraction of the
/// depth change across one particle spacing. 50 um is a tenth of the suite's 0.5 mm
/// presses; measured on the cases that pass: at most 3 um for coarse and 38 um for rom.
pub const OVERSHOOT: f64 = 0.05e-3;

/// Resolution of the images in the suite (pixels): enough to see the contact, cheap.
const RES: &str = "64 48";
/// The ordinary press that ends every case: sphere R = 5 mm, 0.3 mm deep, centred.
const CHECK_DEPTH: f64 = 0.3e-3;

fn sphere(r: f64) -> Arc<dyn Sdf> {
    Arc::new(Sphere::new(r))
}

/// A pose with translation `t` and rotation from Euler angles (rad).
fn pose(t: [f64; 3], roll: f64, pitch: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_euler_angles(roll, pitch, yaw),
    )
}

/// A sphere of radius `r` pressed `d` deep at (x, y).
fn sphere_at(r: f64, x: f64, y: f64, d: f64) -> Placed {
    Placed {
        shape: sphere(r),
        pose: pose([x, y, r - d], 0.0, 0.0, 0.0),
    }
}

/// A right circular cone, apex down at the local origin, half-angle `angle`, height `h`,
/// as a closed triangle mesh.
pub fn cone_mesh(angle: f64, h: f64, segments: usize) -> TriMesh {
    let r = h * angle.tan();
    let mut v = vec![
        nalgebra::Point3::origin(),
        nalgebra::Point3::new(0.0, 0.0, h),
    ];
    for i in 0..segments {
        let a = std::f64::consts::TAU * i as f64 / segments as f64;
        v.push(nalgebra::Point3::new(r * a.cos(), r * a.sin(), h));
    }
    let mut f = Vec::new();
    for i in 0..segments as u32 {
        let (a, b) = (2 + i, 2 + (i + 1) % segments as u32);
        f.push([0, b, a]); // side, outward normals
        f.push([1, a, b]); // cap
    }
    TriMesh::new(v, f).expect("a valid cone")
}

/// The suite's cases. `patterns` adds pressing four of the benchmark meshes in that folder
/// (cone, dots, cross_lines, wave1); a missing or unreadable mesh is an error, so that no
/// case silently disappears.
pub fn cases(patterns: Option<&std::path::Path>) -> Result<Vec<Case>, String> {
    let mut cases = Vec::new();
    let press = |d: f64| vec![vec![sphere_at(0.005, 0.0, 0.0, d)]];
    let ramp = |to: f64, n: usize| -> Sequence {
        (1..=n)
            .map(|i| vec![sphere_at(0.005, 0.0, 0.0, to * i as f64 / n as f64)])
            .collect()
    };
    let cfg = |pairs: &[(&str, &str)]| {
        pairs
            .iter()
            .map(|(a, b)| (a.to_string(), b.to_string()))
            .collect()
    };

    for e in ["1e4", "1.19e5", "1e6", "1e7"] {
        cases.push(Case {
            name: format!("E = {e} Pa, 1 mm"),
            config: cfg(&[("young", e)]),
            frames: press(1e-3),
        });
    }
    for nu in ["0.3", "0.43", "0.49", "0.499"] {
        cases.push(Case {
            name: format!("Poisson {nu}, 1 mm"),
            config: cfg(&[("poisson", nu)]),
            frames: press(1e-3),
        });
    }
    cases.push(Case {
        name: "sphere 2 mm deep".into(),
        config: vec![],
        frames: ramp(2e-3, 4),
    });
    let cone: Arc<dyn Sdf> = Arc::new(cone_mesh(30f64.to_radians(), 0.006, 48));
    cases.push(Case {
        name: "cone tip 1 mm".into(),
        config: vec![],
        frames: vec![vec![Placed {
            shape: cone,
            pose: pose([0.0, 0.0, -1e-3], 0.0, 0.0, 0.0),
        }]],
    });
    // A knife: a thin plate standing on its edge, pressed 0.8 mm.
    let knife: Arc<dyn Sdf> = Arc::new(Cuboid::new(Vector3::new(0.006, 0.0002, 0.004)));
    cases.push(Case {
        name: "knife edge 0.8 mm".into(),
        config: vec![],
        frames: vec![vec![Placed {
            shape: knife,
            pose: pose([0.0, 0.0, 0.004 - 0.8e-3], 0.0, 0.0, 0.3),
        }]],
    });
    cases.push(Case {
        name: "1 mm jump".into(),
        config: vec![],
        frames: vec![
            vec![sphere_at(0.005, 0.0, 0.0, 0.1e-3)],
            vec![sphere_at(0.005, 0.0, 0.0, 1.1e-3)],
        ],
    });
    cases.push(Case {
        name: "through the bottom".into(),
        config: vec![],
        frames: vec![
            vec![sphere_at(0.005, 0.0, 0.0, 1e-3)],
            vec![sphere_at(0.005, 0.0, 0.0, 6e-3)],
        ],
    });
    let slide: Sequence = (0..4)
        .map(|i| vec![sphere_at(0.005, -1.5e-3 + 1e-3 * i as f64, 0.0, 0.5e-3)])
        .collect();
    cases.push(Case {
        name: "sliding sphere".into(),
        config: vec![],
        frames: slide,
    });
    let bar: Arc<dyn Sdf> = Arc::new(Cuboid::new(Vector3::new(0.004, 0.001, 0.002)));
    let rotate: Sequence = (0..4)
        .map(|i| {
            vec![Placed {
                shape: bar.clone(),
                pose: pose([0.0, 0.0, 0.002 - 0.5e-3], 0.0, 0.0, 0.4 * i as f64),
            }]
        })
        .collect();
    cases.push(Case {
        name: "rotating bar".into(),
        config: vec![],
        frames: rotate,
    });
    let nan = |v: f64| {
        vec![Placed {
            shape: sphere(0.005),
            pose: pose([v, 0.0, 0.004], 0.0, 0.0, 0.0),
        }]
    };
    cases.push(Case {
        name: "NaN and inf poses".into(),
        config: vec![],
        frames: vec![
            vec![sphere_at(0.005, 0.0, 0.0, 0.5e-3)],
            nan(f64::NAN),
            nan(f64::INFINITY),
        ],
    });
    if let Some(dir) = patterns {
        for name in ["cone", "dots", "cross_lines", "wave1"] {
            let path = dir.join(format!("{name}.stl"));
            let mesh = tacrom::geometry::load_mesh(&path, 1e-3)
                .map_err(|e| format!("stability case mesh {}: {e}", path.display()))?;
            // Flip the patterned face (z = 20 mm) towards the gel, lowest point at z = 0.
            let v = mesh
                .vertices
                .iter()
                .map(|p| nalgebra::Point3::new(p.x, -p.y, 0.02 - p.z))
                .collect();
            // A rotation by pi about x keeps the winding (outward normals stay outward).
            let f = mesh.faces.clone();
            let mesh = TriMesh::new(v, f).map_err(|e| format!("{}: {e}", path.display()))?;
            let lowest = mesh
                .vertices()
                .iter()
                .map(|p| p.z)
                .fold(f64::INFINITY, f64::min);
            let shape: Arc<dyn Sdf> = Arc::new(mesh);
            cases.push(Case {
                name: format!("pattern {name} 0.5 mm"),
                config: vec![],
                frames: vec![vec![Placed {
                    shape,
                    pose: pose([0.0, 0.0, -lowest - 0.5e-3], 0.0, 0.0, 0.0),
                }]],
            });
        }
    }
    Ok(cases)
}

/// Runs `case` on a sensor of the attributes `mode` (`physics`, and `dx`, `solver` or
/// `model` where given) and checks every frame.
pub fn run_case(case: &Case, mode: &RawConfig) -> Row {
    let physics = mode
        .get("physics")
        .unwrap_or(tacrom::config::defaults::PHYSICS);
    let mut raw = mode.clone().with("resolution", RES);
    for (a, v) in &case.config {
        raw = raw.with(a, v);
    }
    let mut row = Row {
        name: case.name.clone(),
        frames: 0,
        finite: true,
        depth_in_range: true,
        max_depth: 0.0,
        max_excess: 0.0,
        depth_bounded_by_indenter: true,
        det_f: (1.0, 1.0),
        det_f_in_bounds: true,
        converged: (0, 0),
        warned_when_unconverged: true,
        max_iterations: 0,
        max_residual: 0.0,
        fallbacks: 0,
        recovered: false,
        refused: None,
        median_ms: 0.0,
    };
    let sensor = Config::from_raw(&case.name, &raw)
        .map_err(|e| e.to_string())
        .and_then(|c| TactileSensor::new(c).map_err(|e| e.to_string()));
    let mut sensor = match sensor {
        Ok(s) => s,
        Err(e) => {
            row.refused = Some(e);
            return row;
        }
    };
    let config = sensor.config().clone();
    let t = config.size[2];
    let mut out = vec![0.0; config.sensordata_len()];
    let mut times = Vec::new();
    let check = vec![sphere_at(0.005, 0.0, 0.0, CHECK_DEPTH)];
    let lift = Vec::new();
    let frames = case.frames.iter().chain([&lift, &check]);
    let n = case.frames.len() + 2;
    for (i, placed) in frames.enumerate() {
        let t0 = Instant::now();
        let eval = sensor.evaluate(placed, &mut out);
        times.push(t0.elapsed().as_secs_f64() * 1e3);
        row.frames += 1;
        row.finite &= out.iter().all(|x| x.is_finite());
        row.depth_in_range &= out.iter().all(|&x| (0.0..=t).contains(&x));
        let peak = out.iter().cloned().fold(0.0, f64::max);
        row.max_depth = row.max_depth.max(peak);
        row.max_excess = row.max_excess.max(eval.bound_excess);
        row.depth_bounded_by_indenter &= eval.bound_excess <= OVERSHOOT;
        if physics == "rom" && eval.contact && eval.rom.is_none() {
            row.fallbacks += 1;
        }
        if let Some(s) = eval.solve {
            row.det_f = (row.det_f.0.min(s.det_f_min), row.det_f.1.max(s.det_f_max));
            row.det_f_in_bounds &= s.det_f_min >= J_MIN - 1e-6 && s.det_f_max <= J_MAX + 1e-6;
            row.converged.1 += 1;
            if s.converged {
                row.converged.0 += 1;
            } else {
                row.warned_when_unconverged &= eval
                    .warnings
                    .iter()
                    .any(|w| w.contains("residual") && w.contains("did not reach"));
            }
            row.max_iterations = row.max_iterations.max(s.iterations);
            row.max_residual = row.max_residual.max(s.residual);
        }
        if i == n - 1 {
            let mut fresh = TactileSensor::new(config.clone()).expect("built once already");
            let mut expected = vec![0.0; out.len()];
            fresh.evaluate(&check, &mut expected);
            row.recovered = out == expected;
        }
    }
    times.sort_by(f64::total_cmp);
    row.median_ms = times[times.len() / 2];
    row
}

/// A markdown table of `rows`.
pub fn table(rows: &[Row]) -> String {
    let mut s = String::from(
        "| case | frames | finite | depth in [0,T] | max depth (mm) | below indenter (um) | det F range | converged | max iter | max residual | next press ok | median ms | verdict |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let yn = |b: bool| if b { "yes" } else { "NO" };
    for r in rows {
        if let Some(e) = &r.refused {
            s += &format!("| {} | refused at load: {e} |||||||||||\n", r.name);
            continue;
        }
        s += &format!(
            "| {} | {} | {} | {} | {:.3} | {:.1} | {:.3}..{:.3} | {}/{} | {} | {:.1e} | {} | {:.1} | {} |\n",
            r.name,
            r.frames,
            yn(r.finite),
            yn(r.depth_in_range),
            r.max_depth * 1e3,
            r.max_excess * 1e6,
            r.det_f.0,
            r.det_f.1,
            r.converged.0,
            r.converged.1,
            r.max_iterations,
            r.max_residual,
            yn(r.recovered),
            r.median_ms,
            if r.ok() { "ok".to_owned() } else { format!("FAIL: {}", r.failures().join(", ")) },
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn cone_mesh_is_closed_with_outward_normals() {
        let cone = cone_mesh(30f64.to_radians(), 0.006, 48);
        assert!(cone.is_closed());
        assert!(cone.distance(&Point3::new(0.0, 0.0, 0.003)) < 0.0);
        assert!(cone.distance(&Point3::new(0.0, 0.0, -0.001)) > 0.0);
        assert!(cone.distance(&Point3::new(0.003, 0.0, 0.001)) > 0.0);
    }
}
