//! The tactile sensor: indenters in, depth image (and other outputs) out.
//!
//! [`TactileSensor`] owns everything one sensor needs in one `mjData`: the validated
//! configuration, the gel's state, and reusable image buffers. It knows nothing of MuJoCo:
//! the caller hands it the indenters posed in the sensor frame.

use std::time::Instant;

use nalgebra::Vector3;

use crate::config::{Config, Output, Physics};
use crate::geometry::{Aabb, PixelGrid, Placed};
use crate::mpm::{Gel, GelParams, Material, SolveReport, SolverOptions};
use crate::rom::{Rom, RomOptions, RomReport};

/// Failure to build a sensor from a valid configuration.
#[derive(Debug, thiserror::Error)]
pub enum SensorError {
    /// The gel simulation refused its parameters.
    #[error("tacrom.tactile sensor '{sensor}': {message}")]
    Physics {
        /// Sensor name.
        sensor: String,
        /// What the solver said.
        message: String,
    },
}

/// Per-stage wall time of the last evaluation (seconds).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Contact test and rigid surface of the indenters.
    pub geometry: f64,
    /// Gel simulation.
    pub physics: f64,
    /// Writing the outputs.
    pub render: f64,
}

/// What one evaluation did, for warnings and benchmarks.
#[derive(Clone, Debug, Default)]
pub struct Evaluation {
    /// Whether any indenter reached the gel.
    pub contact: bool,
    /// The gel solver's report, when it ran.
    pub solve: Option<SolveReport>,
    /// Stage timings.
    pub times: StageTimes,
    /// Messages for the user (the solver hit its iteration cap, ...).
    pub warnings: Vec<String>,
    /// The reduced-order model's report, when it ran (`physics="rom"`).
    pub rom: Option<RomReport>,
}

/// The gel's model.
#[derive(Clone, Debug)]
enum GelModel {
    /// No gel state: the undeformed surface.
    Rigid,
    /// An MPM gel, created on first contact (a scene that never touches costs nothing).
    Mpm {
        params: GelParams,
        options: SolverOptions,
        gel: Option<Box<Gel>>,
        deformed: bool,
        /// The reduced-order model (`physics="rom"`), loaded with the sensor.
        rom: Option<Box<Rom>>,
    },
}

/// One tactile sensor's state in one simulation.
#[derive(Clone, Debug)]
pub struct TactileSensor {
    config: Config,
    grid: PixelGrid,
    gel: GelModel,
    /// Lowest indenter surface per pixel (sensor frame z), +inf where none.
    zmin: Vec<f64>,
    depth: Vec<f64>,
    force: Vector3<f64>,
}

impl TactileSensor {
    /// A sensor in its undeformed state.
    pub fn new(config: Config) -> Result<Self, SensorError> {
        let grid = PixelGrid {
            width: config.width,
            height: config.height,
            fov_x: config.fov[0],
            fov_y: config.fov[1],
        };
        let gel = match (config.physics, config.dx) {
            (Physics::Rigid, _) | (_, None) => GelModel::Rigid,
            (Physics::Coarse | Physics::Fine | Physics::Rom, Some(dx)) => {
                let params = GelParams {
                    size: config.size,
                    young: config.young,
                    poisson: config.poisson,
                    density: config.density,
                    friction: config.friction,
                    dx,
                    material: Material::FixedCorotated,
                };
                let options = SolverOptions {
                    threads: config.threads,
                    tolerance: config.tolerance,
                    ..SolverOptions::default()
                };
                // Validate now, so a bad combination fails at model load; the gel itself is
                // built on first contact.
                Gel::validate(&params, &options).map_err(|e| SensorError::Physics {
                    sensor: config.name.clone(),
                    message: e.to_string(),
                })?;
                let rom = if config.physics == Physics::Rom {
                    Some(Box::new(load_rom(&config, dx)?))
                } else {
                    None
                };
                GelModel::Mpm {
                    params,
                    options,
                    gel: None,
                    deformed: false,
                    rom,
                }
            }
        };
        let pixels = config.pixels();
        Ok(Self {
            config,
            grid,
            gel,
            zmin: vec![f64::INFINITY; pixels],
            depth: vec![0.0; pixels],
            force: Vector3::zeros(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The image's pixel grid.
    pub fn grid(&self) -> &PixelGrid {
        &self.grid
    }

    /// The depth image of the last evaluation (H x W, row-major, m).
    pub fn depth(&self) -> &[f64] {
        &self.depth
    }

    /// The force of the last evaluation (N, sensor frame).
    pub fn force(&self) -> Vector3<f64> {
        self.force
    }

    /// Back to the undeformed gel.
    pub fn reset(&mut self) {
        if let GelModel::Mpm {
            gel: Some(gel),
            deformed,
            ..
        } = &mut self.gel
        {
            gel.reset();
            *deformed = false;
        }
        self.depth.fill(0.0);
        self.force = Vector3::zeros();
    }

    /// The gel's bounding box in the sensor frame.
    pub fn gel_box(&self) -> Aabb {
        let [lx, ly, t] = self.config.size;
        Aabb::new(
            [-0.5 * lx, -0.5 * ly, -t].into(),
            [0.5 * lx, 0.5 * ly, 0.0].into(),
        )
    }

    /// Evaluates the sensor for `indenters` (posed in the sensor frame) and writes the
    /// configured outputs, concatenated in order, into `out`
    /// (`out.len() == config.sensordata_len()`).
    pub fn evaluate(&mut self, indenters: &[Placed], out: &mut [f64]) -> Evaluation {
        let mut eval = Evaluation::default();
        let t0 = Instant::now();
        let gel_box = self.gel_box();
        let touching: Vec<Placed> = indenters
            .iter()
            .filter(|p| p.aabb().intersects(&gel_box))
            .cloned()
            .collect();
        eval.contact = !touching.is_empty();

        let mpm_idle = match &self.gel {
            GelModel::Rigid => true,
            GelModel::Mpm { deformed, .. } => !deformed,
        };
        if !eval.contact && mpm_idle {
            // No contact and a flat gel: zeros, nothing else.
            self.depth.fill(0.0);
            self.force = Vector3::zeros();
            out.fill(0.0);
            eval.times.geometry = t0.elapsed().as_secs_f64();
            return eval;
        }

        // Rigid surface of the indenters, the ground truth where they touch.
        self.zmin.fill(f64::INFINITY);
        let t = self.config.size[2];
        for p in &touching {
            p.lower_surface(&self.grid, -t, 0.0, &mut self.zmin);
        }
        let t1 = Instant::now();
        eval.times.geometry = (t1 - t0).as_secs_f64();

        match &mut self.gel {
            GelModel::Rigid => {
                for (d, &z) in self.depth.iter_mut().zip(&self.zmin) {
                    *d = if z.is_finite() {
                        (-z).clamp(0.0, t)
                    } else {
                        0.0
                    };
                }
                self.force = Vector3::zeros();
            }
            GelModel::Mpm {
                params,
                options,
                gel,
                deformed,
                rom,
            } => {
                let gel = match gel {
                    Some(g) => g,
                    None => match Gel::new(*params, *options) {
                        Ok(g) => gel.insert(Box::new(g)),
                        Err(e) => {
                            eval.warnings
                                .push(format!("tacrom.tactile sensor '{}': {e}", self.config.name));
                            out.fill(0.0);
                            return eval;
                        }
                    },
                };
                if eval.contact {
                    let report = gel.solve(&touching);
                    if !report.converged {
                        eval.warnings.push(format!(
                            "tacrom.tactile sensor '{}': gel did not reach equilibrium in {} \
                             iterations (residual {:.3e})",
                            self.config.name, report.iterations, report.residual
                        ));
                    }
                    if report.nonfinite_recovered {
                        eval.warnings.push(format!(
                            "tacrom.tactile sensor '{}': non-finite values in the gel; state \
                             recovered",
                            self.config.name
                        ));
                    }
                    eval.solve = Some(report);
                    *deformed = true;
                } else {
                    // With nothing pressing, the equilibrium is the flat gel.
                    gel.reset();
                    *deformed = false;
                }
                // The surface is interpolated only when the image is asked for.
                // rom: encoder, latent refinement, decoder (coarse depth if it fails).
                let mut rom_done = false;
                if let (Some(rom), true, true) =
                    (rom, eval.contact, self.config.wants(Output::Depth))
                {
                    match rom.evaluate(gel, &touching, &self.grid, &self.zmin, &mut self.depth) {
                        Ok(report) => {
                            eval.rom = Some(report);
                            rom_done = true;
                        }
                        Err(e) => eval.warnings.push(format!(
                            "tacrom.tactile sensor '{}': reduced-order model failed ({e}); \
                             coarse depth used",
                            self.config.name
                        )),
                    }
                }
                if self.config.wants(Output::Depth) && !rom_done {
                    gel.surface_depth(&self.grid, &mut self.depth);
                    // Two bounds from the contact problem itself. Below: the surface cannot
                    // pass into an indenter, so where one reaches below the undeformed face
                    // the depth is at least its penetration (the rigid geometry is the
                    // ground truth in contact). Above: under compressive contact the
                    // displacement of an elastic layer peaks in the contact region, where
                    // it equals the penetration; no point sinks below the deepest indenter
                    // (a conservative bound: the lowest corner of its bounding box). The
                    // coarse grid can sink surface points a little below a flat feature
                    // narrower than two cells (about 0.15 mm at dx = 1.4 mm); this bound
                    // keeps that artefact out of the image.
                    let reach = touching
                        .iter()
                        .map(|p| -p.aabb().min.z)
                        .fold(0.0, f64::max)
                        .min(t);
                    for (d, &z) in self.depth.iter_mut().zip(&self.zmin) {
                        let rigid = if z.is_finite() { -z } else { 0.0 };
                        let gel = if d.is_finite() { d.min(reach) } else { 0.0 };
                        *d = gel.max(rigid).clamp(0.0, t);
                    }
                }
                self.force = if self.config.wants(Output::Force) {
                    gel.force()
                } else {
                    Vector3::zeros()
                };
                if !self.force.iter().all(|f| f.is_finite()) {
                    self.force = Vector3::zeros();
                }
            }
        }
        let t2 = Instant::now();
        eval.times.physics = (t2 - t1).as_secs_f64();
        self.write_outputs(out);
        eval.times.render = t2.elapsed().as_secs_f64();
        eval
    }

    fn write_outputs(&self, out: &mut [f64]) {
        let pixels = self.config.pixels();
        let mut at = 0;
        for &o in &self.config.outputs {
            let n = o.len(pixels);
            let dst = &mut out[at..at + n];
            match o {
                Output::Depth => dst.copy_from_slice(&self.depth),
                Output::Force => dst.copy_from_slice(self.force.as_slice()),
                Output::Contact => {
                    for (c, &z) in dst.iter_mut().zip(&self.zmin) {
                        *c = if z.is_finite() && z < 0.0 { 1.0 } else { 0.0 };
                    }
                }
            }
            at += n;
        }
    }
}

/// Loads the reduced-order model of a `physics="rom"` sensor: the `model` directory or the
/// shipped one, checked against the sensor's gel and coarse grid.
fn load_rom(config: &Config, dx: f64) -> Result<Rom, SensorError> {
    let attr = crate::config::ATTR_MODEL;
    let fail = |message: String| SensorError::Physics {
        sensor: config.name.clone(),
        message,
    };
    let dir = match &config.model {
        Some(d) => d.clone(),
        None => crate::rom::default_model_dir().ok_or_else(|| {
            fail(format!(
                "attribute '{attr}': the shipped model models/{} was not found beside the \
                 plugin library; set '{attr}' to a model directory",
                crate::rom::DEFAULT_MODEL
            ))
        })?,
    };
    let in_dir =
        |e: crate::rom::RomError| fail(format!("attribute '{attr}' = \"{}\": {e}", dir.display()));
    let rom = Rom::load(
        &dir,
        RomOptions {
            refine: config.refine,
            threads: config.threads,
        },
    )
    .map_err(in_dir)?;
    let m = rom.manifest();
    m.check_gel(config.size, config.young, config.poisson, config.friction)
        .map_err(in_dir)?;
    if (dx - m.gel.coarse_dx).abs() > 1e-9 {
        return Err(fail(format!(
            "attribute 'dx' = {dx}: the model {} expects the coarse grid dx = {}",
            dir.display(),
            m.gel.coarse_dx
        )));
    }
    Ok(rom)
}
