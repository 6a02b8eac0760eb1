//! The tactile sensor: indenters in, depth image (and other outputs) out.
//!
//! [`TactileSensor`] owns everything one sensor needs in one `mjData`: the validated
//! configuration, the gel's model, and reusable image buffers. It knows nothing of MuJoCo:
//! the caller hands it the indenters posed in the sensor frame. One evaluation is a short
//! pipeline: the scene (which indenters touch, their rigid surface, the depth rule), the
//! physics mode ([`models::SurfaceModel`]), the camera ([`Refraction`], a pinhole camera
//! only), the outputs ([`outputs`]).

use std::sync::Arc;
use std::time::Instant;

use nalgebra::Vector3;

use crate::config::{Camera, Config};
use crate::geometry::{Aabb, PixelGrid, Placed, Sdf};
use crate::mpm::{SolveReport, Wrench};
use crate::render::markers::Markers;
use crate::render::refraction::Refraction;
use crate::render::rgb::RgbModel;
use crate::render::DepthRule;
use crate::rom::RomReport;
use crate::state::{Io, Persist};

pub mod coupling;
pub mod models;
pub mod outputs;

use models::SurfaceModel;
use outputs::{Field, Frame, Needs, Seen, Shape};

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
    /// Gel simulation and its surface (depth, shear and marker displacements).
    pub physics: f64,
    /// The camera (a pinhole's rays through the surface) and writing the outputs.
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
    /// How far the model's surface sank below the deepest indenter point before the depth
    /// rule bounded it (m; 0 when it did not): no elastic gel can, so a value above the
    /// grid's resolution is an error of the model.
    pub bound_excess: f64,
    /// Whether the evaluation may have changed the sensor's state (false for a frame
    /// without contact on the undeformed gel, and for a held one, which do nothing).
    pub changed: bool,
    /// Whether the frame was the last solved one again: its indenters moved less than
    /// `hold` since that solve ([`TactileSensor::evaluate`]).
    pub held: bool,
}

/// What the physics modes see of one frame: the indenters that can touch the gel, the
/// image grid, their rigid surface on it and the depth rule they imply.
#[derive(Clone, Copy, Debug)]
pub struct Scene<'a> {
    /// Indenters whose bounding box meets the gel (sensor frame).
    pub indenters: &'a [Placed],
    /// The image's pixel grid.
    pub grid: &'a PixelGrid,
    /// Lowest indenter surface per pixel (sensor-frame z), `+inf` where none.
    pub zmin: &'a [f64],
    /// The bounds of the contact problem.
    pub rule: DepthRule,
}

/// The depth (m) from which a held frame may move by the whole of `hold`; a shallower
/// contact holds that fraction of it ([`TactileSensor::evaluate`]). A Hertz contact's
/// force moves by 1.5 times the depth's fraction moved, so with the default `hold` (1 um,
/// 0.2 % of this depth) a held frame's force is within 0.3 % of a solve's, below what the
/// gel's own solve leaves (its tolerance, 3e-3 of the load by default), and with a `hold`
/// of 5 um within 1.5 %.
pub const HOLD_DEPTH: f64 = 5e-4;

/// One tactile sensor's state in one simulation.
#[derive(Debug)]
pub struct TactileSensor {
    config: Config,
    grid: PixelGrid,
    model: Box<dyn SurfaceModel>,
    /// What the configured outputs need computed.
    needs: Needs,
    /// Lowest indenter surface per pixel (sensor frame z), +inf where none.
    zmin: Vec<f64>,
    /// Rigid penetration per pixel (m).
    penetration: Vec<f64>,
    /// What the last evaluation computed for the outputs.
    fields: Fields,
    /// The `rgb` output's optical model.
    optics: RgbModel,
    /// The pinhole camera's rays (`None`: orthographic, or no output needs an image).
    refraction: Option<Refraction>,
    /// An image written on the orthographic grid before it is resampled for the pinhole
    /// camera (empty unless an output needs it).
    scratch: Vec<f64>,
    /// The indenters touching the gel at the last solve, as they were posed then (part of
    /// the state): a frame whose indenters are these, moved less than `hold`, is that
    /// solve's frame again.
    solved: Vec<Placed>,
    /// The list a frame gathers its touching indenters in (the last but one frame's,
    /// kept for its allocation).
    spare: Vec<Placed>,
    /// The configuration's `hold` where the model has a state, else 0 (never held).
    hold: f64,
    /// How deep the last solve's indenters reached below the gel's face (m; part of the
    /// state): a frame is held only within `hold` times its fraction of [`HOLD_DEPTH`].
    solved_depth: f64,
    /// Whether `fields` hold the outputs of `solved` (false once a state is read back:
    /// the fields are not part of it, and the next held frame computes them again).
    fresh: bool,
}

/// What an evaluation computes for the outputs, one buffer per physical quantity. Each is
/// sized at load for what the configured outputs need (empty otherwise); all of them are
/// copied with the sensor, and cleared together ([`Fields::flatten`]) when the gel is
/// reset and in a frame without contact. A new physical output adds its buffer here, its
/// line in [`Fields::new`] and [`Fields::flatten`], and its field of the writers'
/// [`Frame`].
#[derive(Clone, Debug)]
struct Fields {
    /// The surface's depth straight above each pixel (m), when an output needs it.
    depth: Vec<f64>,
    /// The depth image the pinhole camera sees (m); empty for the orthographic camera.
    seen_depth: Vec<f64>,
    /// Whether the last evaluation's surface was deformed, so that the pinhole's images
    /// differ from the orthographic ones (false: flat, every camera sees alike).
    bent: bool,
    /// Each physical image at its [`Field::index`] (H x W x channels), when an output
    /// needs it; else empty.
    images: [Vec<f64>; Field::ALL.len()],
    /// The gel's force on the indenters (N, sensor frame); zero unless an output needs it.
    force: Vector3<f64>,
    /// The markers, when an output needs them.
    markers: Markers,
}

impl Fields {
    /// The flat gel's fields for outputs that need `needs`, on `grid`; `seen` when a
    /// pinhole camera sees the depth through the gel.
    fn new(needs: Needs, grid: &PixelGrid, markers: [usize; 2], seen: bool) -> Self {
        let pixels = grid.width * grid.height;
        let sized = |wanted: bool, len: usize| if wanted { vec![0.0; len] } else { Vec::new() };
        Self {
            depth: sized(needs.depth, pixels),
            seen_depth: sized(seen, pixels),
            bent: false,
            images: Field::ALL.map(|f| sized(needs.has(f), f.channels() * pixels)),
            force: Vector3::zeros(),
            markers: if needs.markers {
                Markers::new(markers, grid)
            } else {
                Markers::default()
            },
        }
    }

    /// Back to the flat gel's values: no depth, force or physical image, the markers at
    /// rest.
    fn flatten(&mut self) {
        self.depth.fill(0.0);
        self.seen_depth.fill(0.0);
        self.bent = false;
        self.images.iter_mut().for_each(|i| i.fill(0.0));
        self.force = Vector3::zeros();
        self.markers.settle();
    }
}

impl TactileSensor {
    /// A sensor in its undeformed state; loads what its physics mode needs (the ONNX model
    /// for `rom` only).
    pub fn new(config: Config) -> Result<Self, SensorError> {
        let grid = PixelGrid {
            width: config.width,
            height: config.height,
            fov_x: config.fov[0],
            fov_y: config.fov[1],
        };
        let model = models::build(&config)?;
        let mut needs = config
            .outputs
            .iter()
            .fold(Needs::NONE, |n, o| n | o.spec().needs);
        // `rom` scales its force and pressure by the decoded surface: it decodes for them.
        needs.depth |= model.force_needs_depth() && (needs.force || needs.has(Field::Pressure));
        let pixels = config.pixels();
        // Through a pinhole every image is resampled where the rays meet the surface, so
        // the depth image is computed for any of them.
        let resampled: Vec<usize> = config
            .outputs
            .iter()
            .filter(|o| matches!(o.spec().seen, Seen::Resampled(_)))
            .map(|o| o.spec().len(&config.layout()))
            .collect();
        let refraction = match config.camera {
            Camera::Pinhole { distance } if needs.depth || !resampled.is_empty() => {
                needs.depth = true;
                Some(Refraction::new(
                    &grid,
                    config.size[2],
                    distance,
                    config.index,
                ))
            }
            _ => None,
        };
        let scratch_len = match refraction {
            Some(_) => resampled.into_iter().max().unwrap_or(0),
            None => 0,
        };
        let fields = Fields::new(needs, &grid, config.markers, refraction.is_some());
        let optics = match &config.optics {
            Some(calibrated) => RgbModel::Calibrated(Arc::clone(calibrated)),
            None => RgbModel::default(),
        };
        Ok(Self {
            grid,
            model,
            needs,
            zmin: vec![f64::INFINITY; pixels],
            penetration: if needs.depth {
                vec![0.0; pixels]
            } else {
                Vec::new()
            },
            fields,
            optics,
            refraction,
            scratch: vec![0.0; scratch_len],
            solved: Vec::new(),
            spare: Vec::new(),
            solved_depth: 0.0,
            hold: Self::hold_of(&config, models::state_len(&config, 1)),
            fresh: false,
            config,
        })
    }

    /// A copy with the same state, for `mj_copyData`; fails (rather than panics) when the
    /// model's resources cannot be duplicated.
    pub fn try_clone(&self) -> Result<Self, SensorError> {
        Ok(Self {
            config: self.config.clone(),
            grid: self.grid,
            model: self.model.try_clone()?,
            needs: self.needs,
            zmin: self.zmin.clone(),
            penetration: self.penetration.clone(),
            fields: self.fields.clone(),
            optics: self.optics.clone(),
            refraction: self.refraction.clone(),
            scratch: self.scratch.clone(),
            solved: self.solved.clone(),
            spare: Vec::new(),
            solved_depth: self.solved_depth,
            hold: self.hold,
            fresh: self.fresh,
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

    /// The depth image of the last evaluation as the camera sees it (H x W, row-major, m;
    /// the `depth` output); empty when no configured output needs it.
    pub fn depth(&self) -> &[f64] {
        if self.refraction.is_some() {
            &self.fields.seen_depth
        } else {
            &self.fields.depth
        }
    }

    /// The depth of the surface straight above each pixel centre in the last evaluation
    /// (H x W, row-major, m): the orthographic image, whatever the camera; empty when no
    /// configured output needs it.
    pub fn surface_depth(&self) -> &[f64] {
        &self.fields.depth
    }

    /// The force of the last evaluation (N, sensor frame); zero when not asked for.
    pub fn force(&self) -> Vector3<f64> {
        self.fields.force
    }

    /// The shear image of the last evaluation (H x W x 2, row-major, m); empty when no
    /// configured output needs it.
    pub fn shear(&self) -> &[f64] {
        &self.fields.images[Field::Shear.index()]
    }

    /// The markers and their displacements after the last evaluation; none when no
    /// configured output needs them.
    pub fn markers(&self) -> &Markers {
        &self.fields.markers
    }

    /// The force and torque (about the sensor origin; sensor frame) of the gel on each of
    /// `indenters` after the last evaluation, whatever the outputs: each contact load
    /// goes to the indenter nearest to where it acts. Zero for rigid physics.
    pub fn wrenches(&self, indenters: &[Placed]) -> Vec<Wrench> {
        self.model.wrenches(indenters)
    }

    /// [`TactileSensor::wrenches`], and how far the gel's contact with each of `indenters`
    /// spreads about its centre of pressure after the last evaluation (m^2,
    /// [`crate::mpm::Gel::wrenches_and_spreads`]; zero for rigid physics), found together.
    pub fn wrenches_and_spreads(&self, indenters: &[Placed]) -> (Vec<Wrench>, Vec<f64>) {
        self.model.wrenches_and_spreads(indenters)
    }

    /// Writes or reads the state the next evaluation depends on ([`crate::state`]): the
    /// indenters of the last solve and the gel's state, where there is one (the images
    /// are not part of it: a held frame after a read computes them again from it).
    /// `shapes` names the indenters' shapes by index, the same table in meaning when
    /// reading as when writing. Returns whether all of it is kept (see
    /// [`crate::mpm::Gel::persist`]). A failed read leaves the sensor to be reset.
    pub fn persist(&mut self, io: &mut Io<'_>, shapes: &[Arc<dyn Sdf>]) -> bool {
        if self.hold == 0.0 {
            return self.model.persist(io, shapes);
        }
        crate::state::placed(io, &mut self.solved, shapes, "the last solve's indenters");
        self.solved_depth.persist(io);
        if io.loading() {
            self.fresh = false;
        }
        self.model.persist(io, shapes)
    }

    /// The most numbers [`TactileSensor::persist`] writes for `config` with at most
    /// `indenters` indenters.
    pub fn state_len(config: &Config, indenters: usize) -> usize {
        let model = models::state_len(config, indenters);
        if Self::hold_of(config, model) == 0.0 {
            model
        } else {
            crate::state::placed_len(indenters) + 1 + model
        }
    }

    /// The `hold` a sensor of `config` keeps, whose model's state takes `model_len`
    /// numbers: none (0) for a model without state (rigid), whose frames cost less than
    /// remembering them, and for the explicit coupling (`coupling="on"` without
    /// `gel_geom`), whose force is the last evaluation's and must follow every motion (a
    /// held force is a dead band that the pressing body crosses back and forth).
    fn hold_of(config: &Config, model_len: usize) -> f64 {
        let explicit = config.coupling && config.gel_geom.is_none();
        if model_len == 0 || explicit {
            0.0
        } else {
            config.hold
        }
    }

    /// Back to the undeformed gel.
    pub fn reset(&mut self) {
        self.model.reset();
        self.fields.flatten();
        self.solved.clear();
        self.solved_depth = 0.0;
        self.fresh = false;
    }

    /// Whether the last solve was of `indenters` where the last evaluation was of them (those
    /// touching the gel, as posed now), not of an earlier pose that a held frame repeated.
    pub fn solved_at(&self, indenters: &[Placed]) -> bool {
        if self.hold == 0.0 {
            // Nothing is held: the last evaluation solved its indenters.
            return true;
        }
        let touching: Vec<&Placed> = self.touching(indenters).collect();
        touching.len() == self.solved.len()
            && touching
                .iter()
                .zip(&self.solved)
                .all(|(a, b)| Arc::ptr_eq(&a.shape, &b.shape) && a.pose == b.pose)
    }

    /// The indenters of `indenters` whose bounding box meets the gel.
    fn touching<'a>(&self, indenters: &'a [Placed]) -> impl Iterator<Item = &'a Placed> {
        let gel = self.gel_box();
        indenters.iter().filter(move |p| p.aabb().intersects(&gel))
    }

    /// Whether `touching` are the last solve's indenters, each moved less than `hold` (that
    /// fraction of it where the depth they reached then is a fraction of [`HOLD_DEPTH`]),
    /// at every point of the gel's box that its bounding box then reached. A rigid motion
    /// moves points by an affine map, whose length is largest at a corner of that box.
    fn holds(&self, touching: &[Placed]) -> bool {
        let hold = self.hold * (self.solved_depth / HOLD_DEPTH).min(1.0);
        let gel = self.gel_box();
        hold > 0.0
            && !touching.is_empty()
            && touching.len() == self.solved.len()
            && touching.iter().zip(&self.solved).all(|(now, then)| {
                if !Arc::ptr_eq(&now.shape, &then.shape) {
                    return false;
                }
                let reach = then.aabb();
                let lo = reach.min.coords.sup(&gel.min.coords);
                let hi = reach.max.coords.inf(&gel.max.coords);
                let delta = now.pose * then.pose.inverse();
                (0..8).all(|k| {
                    let corner = nalgebra::Point3::new(
                        if k & 1 == 0 { lo.x } else { hi.x },
                        if k & 2 == 0 { lo.y } else { hi.y },
                        if k & 4 == 0 { lo.z } else { hi.z },
                    );
                    (delta * corner - corner).norm() < hold
                })
            })
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
        let mut touching = std::mem::take(&mut self.spare);
        touching.clear();
        touching.extend(self.touching(indenters).cloned());
        eval.contact = !touching.is_empty();
        eval.held = self.holds(&touching);
        if eval.held {
            // The last solved frame again: its outputs where the fields still hold them,
            // else computed again from the state (the gel as that solve left it, the
            // indenters as they were posed then), so that a state read back gives the
            // frames it gave before, bit for bit.
            if self.fresh {
                eval.times.geometry = t0.elapsed().as_secs_f64();
                let t1 = Instant::now();
                self.write_outputs(out);
                eval.times.render = t1.elapsed().as_secs_f64();
                self.spare = touching;
                return eval;
            }
            touching.clone_from(&self.solved);
        }
        eval.changed = !eval.held && (eval.contact || !self.model.at_rest());
        if !eval.contact && !eval.changed {
            // No contact and a flat gel: the outputs of the flat surface, nothing else
            // (every camera sees it alike).
            self.solved.clear();
            self.fresh = true;
            self.fields.flatten();
            self.zmin.fill(f64::INFINITY);
            eval.times.geometry = t0.elapsed().as_secs_f64();
            let t1 = Instant::now();
            self.write_outputs(out);
            eval.times.render = t1.elapsed().as_secs_f64();
            self.spare = touching;
            return eval;
        }
        let t = self.config.size[2];
        self.zmin.fill(f64::INFINITY);
        for p in &touching {
            p.lower_surface(&self.grid, -t, 0.0, &mut self.zmin);
        }
        if self.zmin.iter().any(|&z| z <= -t) {
            // A gel that pushes back is driven through by a physics step longer than its
            // contact follows, too, and by a light body whose joint damping the integrator
            // takes after the contact solve: a grasp's fingers then bounce the object
            // between the gels (docs/rl.md, "A long physics step: the fingers' damping,
            // taken after the solve").
            let step = if self.config.coupling {
                "; with the coupling, a physics step too long for the gel's contact drives \
                 it there too, as does a light body whose joint damping MuJoCo's integrator \
                 takes after the contact solve: try a smaller timestep, or give that joint \
                 armature (tacrom/GripperLift-v1's coupled grasp holds still up to 10 ms)"
            } else {
                ""
            };
            eval.warnings.push(format!(
                "tacrom.tactile sensor '{}': an indenter reaches the gel's base ({:.1} mm \
                 below its face): no gel holds it there; give the sensor's body a collision \
                 geom under the gel, or the indenter a lighter load{step}",
                self.config.name,
                t * 1e3
            ));
        }
        let scene = Scene {
            indenters: &touching,
            grid: &self.grid,
            zmin: &self.zmin,
            rule: DepthRule::new(t, &touching),
        };
        let t1 = Instant::now();
        eval.times.geometry = (t1 - t0).as_secs_f64();

        if !eval.held {
            self.model.solve(&scene, &mut eval);
        }
        // Shear is the depth image's inverse map: computed with it when both are needed.
        let with_depth = self.needs.depth && self.needs.has(Field::Shear);
        if self.needs.depth {
            if with_depth {
                self.model.depth_and_shear(
                    &scene,
                    &mut self.fields.depth,
                    &mut self.fields.images[Field::Shear.index()],
                    &mut eval,
                );
            } else {
                self.model.depth(&scene, &mut self.fields.depth, &mut eval);
            }
            for (p, &z) in self.penetration.iter_mut().zip(scene.zmin) {
                *p = scene.rule.penetration(z);
            }
            let excess = scene.rule.apply(&mut self.fields.depth, &self.penetration);
            eval.bound_excess = eval.bound_excess.max(excess);
        }
        let force = if self.needs.force {
            self.model.force()
        } else {
            Vector3::zeros()
        };
        self.fields.force = if force.iter().all(|f| f.is_finite()) {
            force
        } else {
            Vector3::zeros()
        };
        for field in Field::ALL {
            if !self.needs.has(field) || (field == Field::Shear && with_depth) {
                continue;
            }
            let image = &mut self.fields.images[field.index()];
            self.model.field(field, scene.grid, image);
            if !image.iter().all(|v| v.is_finite()) {
                image.fill(0.0);
            }
        }
        if self.needs.markers {
            let model = &self.model;
            self.fields.markers.update(|x| model.displacement(x));
        }
        let t2 = Instant::now();
        eval.times.physics = (t2 - t1).as_secs_f64();
        // The pinhole's rays through the bounded surface: each depth is the bilinear value
        // of bounded pixels, so it keeps the rule's bounds (within [0, reach]).
        if let Some(refraction) = &mut self.refraction {
            self.fields.bent = refraction.refract(&self.fields.depth, &mut self.fields.seen_depth);
        }
        self.write_outputs(out);
        eval.times.render = t2.elapsed().as_secs_f64();
        if !eval.held && self.hold > 0.0 {
            // A solve that stopped short of equilibrium is not held: the next frame carries
            // it on.
            let settled = eval.solve.as_ref().map_or(true, |r| r.converged);
            if settled {
                std::mem::swap(&mut self.solved, &mut touching);
            } else {
                self.solved.clear();
            }
            // How deep the indenters reached: in the image, or wherever the gel took their
            // load (a contact outside the camera's view holds by its own depth too).
            let seen = -self.zmin.iter().copied().fold(0.0, f64::min);
            self.solved_depth = seen.max(self.model.pressed_depth());
        }
        self.spare = touching;
        self.fresh = true;
        eval
    }

    fn write_outputs(&mut self, out: &mut [f64]) {
        let frame = Frame {
            depth: if self.refraction.is_some() {
                &self.fields.seen_depth
            } else {
                &self.fields.depth
            },
            surface: &self.fields.depth,
            zmin: &self.zmin,
            force: self.fields.force,
            fields: self.fields.images.each_ref().map(Vec::as_slice),
            grid: &self.grid,
            markers: &self.fields.markers,
            optics: &self.optics,
        };
        let view = self.refraction.as_ref().filter(|_| self.fields.bent);
        let mut at = 0;
        for o in &self.config.outputs {
            let spec = o.spec();
            let n = spec.len(&self.config.layout());
            let slot = &mut out[at..at + n];
            match (view, spec.seen, spec.shape) {
                // Written on the orthographic grid, then sampled where each pixel's ray
                // meets the surface.
                (Some(view), Seen::Resampled(sampling), Shape::Image { channels }) => {
                    let image = &mut self.scratch[..n];
                    (spec.write)(&frame, image);
                    view.resample(frame.depth, channels, sampling, image, slot);
                }
                _ => (spec.write)(&frame, slot),
            }
            if self.config.view == crate::config::View::Camera {
                match spec.shape {
                    Shape::Image { channels } => mirror_columns(slot, self.config.width, channels),
                    Shape::PerMarker(values) => {
                        // The marker's column, as the mirrored image shows it.
                        let last = self.config.width as f64 - 1.0;
                        slot.chunks_exact_mut(values)
                            .for_each(|m| m[0] = last - m[0]);
                    }
                    _ => {}
                }
            }
            at += n;
        }
    }
}

/// Mirrors an image (rows of `width` pixels of `channels` values) left-right in place: the
/// indenter's view as the camera under the gel sees it (`view="camera"`).
fn mirror_columns(image: &mut [f64], width: usize, channels: usize) {
    for row in image.chunks_exact_mut(width * channels) {
        for c in 0..width / 2 {
            let (a, b) = (c * channels, (width - 1 - c) * channels);
            for k in 0..channels {
                row.swap(a + k, b + k);
            }
        }
    }
}
