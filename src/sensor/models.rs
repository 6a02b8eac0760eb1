//! The physics modes behind one trait: each turns the indenters pressing the gel into a
//! surface indentation and a force. A new mode is one [`SurfaceModel`] implementation and
//! one arm of [`build`].

use std::sync::Arc;

use nalgebra::Vector3;

use super::outputs::Field;
use super::{Evaluation, Scene, SensorError};
use crate::config::{material_name, Config, Physics};
use crate::geometry::{PixelGrid, Placed, Sdf};
use crate::mpm::{Gel, GelParams, Solver, SolverOptions, Wrench, MISSED_FRACTION};
use crate::rom::{Rom, RomOptions};
use crate::state::{Io, Persist};

/// A model of the gel's surface.
pub trait SurfaceModel: Send + std::fmt::Debug {
    /// Whether the gel is undeformed, so that a frame without contact costs nothing.
    fn at_rest(&self) -> bool;

    /// Solves the gel under the scene's touching indenters (none: back to rest); warnings
    /// and reports go to `eval`.
    fn solve(&mut self, scene: &Scene<'_>, eval: &mut Evaluation);

    /// The gel's surface indentation on the image grid (m, positive into the gel), before
    /// the depth rule; `+NaN` where the model has none (the rule then gives the rigid
    /// penetration).
    fn depth(&mut self, scene: &Scene<'_>, out: &mut [f64], eval: &mut Evaluation);

    /// The total force of the gel on the indenters after the last solve (N, sensor frame).
    fn force(&self) -> Vector3<f64>;

    /// How deep (m) the last solve's contact pressed the gel, wherever on the gel it lies
    /// (the camera may see less of the gel); 0 for a model without a gel.
    fn pressed_depth(&self) -> f64 {
        0.0
    }

    /// The force and torque (about the sensor origin) of the gel on each of `indenters`
    /// after the last solve (sensor frame); zero for a model without a gel.
    fn wrenches(&self, indenters: &[Placed]) -> Vec<Wrench> {
        vec![Wrench::default(); indenters.len()]
    }

    /// [`SurfaceModel::wrenches`], and how far the gel's contact with each of `indenters`
    /// spreads about its centre of pressure after the last solve (m^2,
    /// [`Gel::wrenches_and_spreads`]; zero for a model without a gel), found together.
    fn wrenches_and_spreads(&self, indenters: &[Placed]) -> (Vec<Wrench>, Vec<f64>) {
        (self.wrenches(indenters), vec![0.0; indenters.len()])
    }

    /// The physical image `field` on `grid` after the last solve ([`Field`]):
    /// [`Field::Pressure`], the normal contact pressure (Pa); [`Field::Shear`], the
    /// in-plane displacement of the gel surface seen at each pixel (`H x W x 2`, m, sensor
    /// frame x then y; the inverse map of the depth image). Zero where the model has none
    /// (the undeformed gel; everywhere for a model without a gel).
    fn field(&self, field: Field, grid: &PixelGrid, out: &mut [f64]) {
        let _ = (field, grid);
        out.fill(0.0);
    }

    /// [`SurfaceModel::depth`] and the [`Field::Shear`] image together (the shear after
    /// the depth); a model whose two come from one inverse map computes it once.
    fn depth_and_shear(
        &mut self,
        scene: &Scene<'_>,
        depth: &mut [f64],
        shear: &mut [f64],
        eval: &mut Evaluation,
    ) {
        self.depth(scene, depth, eval);
        self.field(Field::Shear, scene.grid, shear);
    }

    /// The in-plane displacement (m) of the surface point whose rest position is `rest`
    /// (sensor frame x, y) after the last solve; zero for a model without a gel.
    fn displacement(&self, rest: [f64; 2]) -> [f64; 2];

    /// Whether the force and pressure come from the depth solve (`rom`: scaled by the
    /// decoded surface), so that a sensor computes the depth when it reports either.
    fn force_needs_depth(&self) -> bool {
        false
    }

    /// Back to the undeformed gel.
    fn reset(&mut self);

    /// A copy with the same state (for `mj_copyData`); fails rather than panics when a
    /// resource cannot be duplicated.
    fn try_clone(&self) -> Result<Box<dyn SurfaceModel>, SensorError>;

    /// Writes or reads the state the next frame depends on ([`crate::state`]; `shapes`
    /// names the indenters' shapes by index). Returns whether all of it is kept there.
    /// A model without a gel has none.
    fn persist(&mut self, io: &mut Io<'_>, shapes: &[Arc<dyn Sdf>]) -> bool {
        let _ = (io, shapes);
        true
    }
}

/// The most numbers the state of `config`'s model takes ([`SurfaceModel::persist`]) with
/// at most `indenters` indenters.
pub fn state_len(config: &Config, indenters: usize) -> usize {
    match (config.physics, config.dx) {
        (Physics::Rigid, _) | (_, None) => 0,
        (Physics::Coarse | Physics::Fine | Physics::Rom, Some(dx)) => {
            // The flags of `Mpm` and `Reduced` and the gel's own.
            let (solver, fallback) = config.solver_choice(dx);
            let bounds = Gel::bounds_of(&config.gel_params(dx), indenters);
            8 + bounds.gel_len(solver, fallback)
        }
    }
}

/// The model `config` asks for (validated: a bad combination fails at model load).
pub fn build(config: &Config) -> Result<Box<dyn SurfaceModel>, SensorError> {
    let fail = |message: String| SensorError::Physics {
        sensor: config.name.clone(),
        message,
    };
    match (config.physics, config.dx) {
        (Physics::Rigid, _) | (_, None) => Ok(Box::new(Rigid)),
        (Physics::Coarse | Physics::Fine, Some(dx)) => Ok(Box::new(Mpm::new(config, dx)?)),
        (Physics::Rom, Some(dx)) => {
            let mpm = Mpm::new(config, dx)?;
            let rom = load_rom(config, dx, mpm.options.solver).map_err(fail)?;
            Ok(Box::new(Reduced {
                mpm,
                rom: Box::new(rom),
                force_factor: 1.0,
                decoded: false,
                fell_back: false,
            }))
        }
    }
}

/// The undeformed gel: depth is the indenters' rigid penetration, no force.
#[derive(Clone, Copy, Debug)]
struct Rigid;

impl SurfaceModel for Rigid {
    fn at_rest(&self) -> bool {
        true
    }

    fn solve(&mut self, _: &Scene<'_>, _: &mut Evaluation) {}

    fn depth(&mut self, _: &Scene<'_>, out: &mut [f64], _: &mut Evaluation) {
        out.fill(0.0);
    }

    fn force(&self) -> Vector3<f64> {
        Vector3::zeros()
    }

    fn displacement(&self, _: [f64; 2]) -> [f64; 2] {
        [0.0; 2]
    }

    fn reset(&mut self) {}

    fn try_clone(&self) -> Result<Box<dyn SurfaceModel>, SensorError> {
        Ok(Box::new(*self))
    }
}

/// An MPM gel solved to quasi-static equilibrium (`coarse` and `fine`), created on first
/// contact (a scene that never touches costs nothing), or at load for the linear solver,
/// whose gel holds what its first contact would otherwise stall on.
#[derive(Clone, Debug)]
struct Mpm {
    name: String,
    params: GelParams,
    options: SolverOptions,
    gel: Option<Box<Gel>>,
    deformed: bool,
}

impl Mpm {
    fn new(config: &Config, dx: f64) -> Result<Self, SensorError> {
        let params = config.gel_params(dx);
        // The solver the configuration names, or the gel's own choice (a reduced-order
        // model checks its recipe against this one); a coarse gel (under rom too) whose
        // configuration names no solver does not lose a contact smaller than its particles
        // resolve: the linear solver solves such frames.
        let (solver, fallback) = config.solver_choice(dx);
        let options = SolverOptions {
            threads: config.threads,
            tolerance: config.tolerance,
            solver,
            fallback,
            ..SolverOptions::default()
        };
        Gel::validate(&params, &options).map_err(|e| SensorError::Physics {
            sensor: config.name.clone(),
            message: e.to_string(),
        })?;
        // The linear solver's gel holds what depends on the gel alone (its surface
        // compliance, computed or read from the gel cache): built at load, so that the
        // first contact is an ordinary frame. Other gels have nothing to prepare and are
        // made at their first contact.
        let gel = if solver == Solver::Linear {
            let gel = Gel::new(params, options).map_err(|e| SensorError::Physics {
                sensor: config.name.clone(),
                message: e.to_string(),
            })?;
            Some(Box::new(gel))
        } else {
            None
        };
        Ok(Self {
            name: config.name.clone(),
            params,
            options,
            gel,
            deformed: false,
        })
    }

    /// The solved gel, if any solve has run.
    fn gel(&self) -> Option<&Gel> {
        self.gel.as_deref()
    }
}

impl SurfaceModel for Mpm {
    fn at_rest(&self) -> bool {
        !self.deformed
    }

    fn solve(&mut self, scene: &Scene<'_>, eval: &mut Evaluation) {
        let name = &self.name;
        let gel = match &mut self.gel {
            Some(g) => g,
            None => match Gel::new(self.params, self.options) {
                Ok(g) => self.gel.insert(Box::new(g)),
                Err(e) => {
                    eval.warnings
                        .push(format!("tacrom.tactile sensor '{name}': {e}"));
                    return;
                }
            },
        };
        if scene.indenters.is_empty() {
            // With nothing pressing, the equilibrium is the flat gel.
            gel.reset();
            self.deformed = false;
            return;
        }
        let report = gel.solve(scene.indenters);
        if report.work_bound {
            eval.warnings.push(format!(
                "tacrom.tactile sensor '{name}': gel did not reach equilibrium within its \
                 bound of {} Newton steps a frame (residual {:.3e}); it stops where they took \
                 it, short of the indenters' poses, and the next frame carries on from there \
                 (a lower 'friction' or slower motion per frame converges sooner)",
                report.iterations, report.residual
            ));
        } else if let (false, Some(change)) = (report.converged, report.unsettled_friction) {
            eval.warnings.push(format!(
                "tacrom.tactile sensor '{name}': gel did not reach equilibrium: friction's \
                 lagged normal forces still changed the friction by {change:.1e} of the load \
                 at their last refresh (the tolerance is {:.1e}); the frame keeps that last \
                 answer and the next frame carries on from it (seen where a contact is let go \
                 within a frame; a larger 'tolerance' settles sooner)",
                self.options.tolerance
            ));
        } else if !report.converged {
            eval.warnings.push(format!(
                "tacrom.tactile sensor '{name}': gel did not reach equilibrium in {} \
                 iterations (residual {:.3e})",
                report.iterations, report.residual
            ));
        }
        if report.nonfinite_recovered {
            eval.warnings.push(format!(
                "tacrom.tactile sensor '{name}': non-finite values in the gel; state recovered"
            ));
        }
        let spacing = gel.contact_spacing(self.options.solver);
        let missed = gel.unloaded_penetration(scene.indenters);
        if missed > MISSED_FRACTION * spacing {
            let advice = match self.options.solver {
                Solver::Relaxation | Solver::Total => format!(
                    "solver=\"linear\" (contact points {:.3} mm apart, and contacts smaller \
                     than the grid modelled) or a smaller 'dx'",
                    gel.contact_spacing(Solver::Linear) * 1e3
                ),
                Solver::Linear => format!(
                    "solver=\"newton\" (contact points {:.3} mm apart) or a smaller 'dx'",
                    gel.contact_spacing(Solver::Newton) * 1e3
                ),
                Solver::Newton => "a smaller 'dx'".to_string(),
            };
            eval.warnings.push(format!(
                "tacrom.tactile sensor '{name}': an indenter reaches at least {:.3} mm into the \
                 gel between its contact points ({:.3} mm apart at dx = {:.2} mm, solver \
                 {}) and the gel carries no force: the contact is smaller than this gel \
                 resolves; use {advice}",
                missed * 1e3,
                spacing * 1e3,
                self.params.dx * 1e3,
                self.options.solver.name(),
            ));
        }
        eval.solve = Some(report);
        self.deformed = true;
    }

    fn depth(&mut self, scene: &Scene<'_>, out: &mut [f64], _: &mut Evaluation) {
        match &self.gel {
            Some(gel) => gel.surface_depth(scene.grid, out),
            None => out.fill(f64::NAN),
        }
    }

    fn force(&self) -> Vector3<f64> {
        self.gel().map_or_else(Vector3::zeros, Gel::force)
    }

    fn pressed_depth(&self) -> f64 {
        match self.gel() {
            Some(gel) if self.deformed => gel.deepest_load(),
            _ => 0.0,
        }
    }

    fn wrenches(&self, indenters: &[Placed]) -> Vec<Wrench> {
        match self.gel() {
            Some(gel) if self.deformed => gel.wrenches(indenters),
            _ => vec![Wrench::default(); indenters.len()],
        }
    }

    fn wrenches_and_spreads(&self, indenters: &[Placed]) -> (Vec<Wrench>, Vec<f64>) {
        match self.gel() {
            Some(gel) if self.deformed => gel.wrenches_and_spreads(indenters),
            _ => (
                vec![Wrench::default(); indenters.len()],
                vec![0.0; indenters.len()],
            ),
        }
    }

    fn field(&self, field: Field, grid: &PixelGrid, out: &mut [f64]) {
        match (field, self.gel()) {
            (Field::Pressure, Some(gel)) if self.deformed => gel.contact_pressure(grid, out),
            (Field::Shear, Some(gel)) => gel.surface_shear(grid, out),
            _ => out.fill(0.0),
        }
    }

    fn depth_and_shear(
        &mut self,
        scene: &Scene<'_>,
        depth: &mut [f64],
        shear: &mut [f64],
        _: &mut Evaluation,
    ) {
        match self.gel() {
            Some(gel) => gel.surface_depth_and_shear(scene.grid, depth, shear),
            None => {
                depth.fill(f64::NAN);
                shear.fill(0.0);
            }
        }
    }

    fn displacement(&self, rest: [f64; 2]) -> [f64; 2] {
        self.gel().map_or([0.0; 2], |gel| {
            let u = gel.surface_displacement(rest[0], rest[1]);
            [u.x, u.y]
        })
    }

    fn reset(&mut self) {
        if let Some(gel) = &mut self.gel {
            gel.reset();
        }
        self.deformed = false;
    }

    fn try_clone(&self) -> Result<Box<dyn SurfaceModel>, SensorError> {
        Ok(Box::new(self.clone()))
    }

    /// Whether the gel is deformed and whether it is built (a gel is made at its first
    /// contact), then the gel's own state.
    fn persist(&mut self, io: &mut Io<'_>, shapes: &[Arc<dyn Sdf>]) -> bool {
        self.deformed.persist(io);
        let mut built = self.gel.is_some();
        built.persist(io);
        if io.loading() && io.fault().is_none() && built != self.gel.is_some() {
            self.gel = if built {
                match Gel::new(self.params, self.options) {
                    Ok(g) => Some(Box::new(g)),
                    Err(e) => {
                        io.fail(|| e.to_string());
                        return true;
                    }
                }
            } else {
                None
            };
        }
        self.gel.as_mut().map_or(true, |g| g.persist(io, shapes))
    }
}

/// The coarse MPM gel and the reduced-order model restoring its fine detail
/// (`physics="rom"`); where inference fails, the coarse surface with a warning. The normal
/// force and the pressure are the coarse gel's times [`Rom::force_factor`] (the decoded
/// surface's displaced volume over the coarse one's, for a model whose manifest has a
/// `force` factor), and the coupling's wrenches with them; friction stays the coarse
/// gel's.
#[derive(Debug)]
struct Reduced {
    mpm: Mpm,
    rom: Box<Rom>,
    /// [`Rom::force_factor`] of the last evaluation (1 when the decoder did not run).
    force_factor: f64,
    /// Whether the last evaluation decoded (the pressure head's field is its own).
    decoded: bool,
    /// Whether the last solve was the fallback's (a frame the relaxation missed).
    fell_back: bool,
}

impl Reduced {
    /// The normal force and the torque about the horizontal axes of each of `wrenches`
    /// times [`Rom::force_factor`] of the last evaluation.
    fn scale_wrenches(&self, wrenches: &mut [Wrench]) {
        for w in wrenches {
            w.force.z *= self.force_factor;
            w.torque.x *= self.force_factor;
            w.torque.y *= self.force_factor;
        }
    }
}

impl SurfaceModel for Reduced {
    fn at_rest(&self) -> bool {
        self.mpm.at_rest()
    }

    fn solve(&mut self, scene: &Scene<'_>, eval: &mut Evaluation) {
        self.mpm.solve(scene, eval);
        self.fell_back = eval.solve.as_ref().is_some_and(|r| r.fallback);
    }

    /// From the gel of the last solve (a held frame solves nothing).
    fn depth(&mut self, scene: &Scene<'_>, out: &mut [f64], eval: &mut Evaluation) {
        if let (Some(gel), false) = (self.mpm.gel(), scene.indenters.is_empty()) {
            match self.rom.evaluate(gel, scene.indenters, scene.grid, out) {
                Ok(report) => {
                    // A frame the relaxation missed carries the linear solver's force, which
                    // follows the contact mechanics already; the factor is fitted to the
                    // relaxation's surface.
                    let fallback = self.fell_back;
                    self.decoded = !fallback;
                    self.force_factor = if fallback {
                        1.0
                    } else {
                        self.rom.force_factor()
                    };
                    eval.bound_excess = report.bound_excess;
                    eval.rom = Some(report);
                    return;
                }
                Err(e) => eval.warnings.push(format!(
                    "tacrom.tactile sensor '{}': reduced-order model failed ({e}); coarse \
                     depth used",
                    self.mpm.name
                )),
            }
        }
        self.force_factor = 1.0;
        self.decoded = false;
        self.mpm.depth(scene, out, eval);
    }

    fn force(&self) -> Vector3<f64> {
        let mut f = self.mpm.force();
        f.z *= self.force_factor;
        f
    }

    fn pressed_depth(&self) -> f64 {
        self.mpm.pressed_depth()
    }

    fn force_needs_depth(&self) -> bool {
        self.rom.manifest().force_volume_factor.is_some() || self.rom.lattice_pressure().is_some()
    }

    /// The coarse gel's, with the normal force scaled as [`SurfaceModel::force`] (and the
    /// torque about the horizontal axes with it: the contact lies within a millimetre of
    /// the face, so the normal force makes those), so that the gel pushes back with the
    /// force the sensor reports.
    fn wrenches(&self, indenters: &[Placed]) -> Vec<Wrench> {
        let mut w = self.mpm.wrenches(indenters);
        self.scale_wrenches(&mut w);
        w
    }

    /// The coarse gel's, the wrenches scaled as [`Reduced::wrenches`]: the normal force's
    /// scale leaves its spread as it is.
    fn wrenches_and_spreads(&self, indenters: &[Placed]) -> (Vec<Wrench>, Vec<f64>) {
        let (mut w, spreads) = self.mpm.wrenches_and_spreads(indenters);
        self.scale_wrenches(&mut w);
        (w, spreads)
    }

    /// The pressure: the pressure head's field carrying the reported normal force, where
    /// the head ran on the last decoded evaluation and its correction of the coarse load
    /// lies in range; else the coarse gel's pressure scaled as the normal force. The
    /// decoder restores depth only: shear comes from the coarse gel.
    fn field(&self, field: Field, grid: &PixelGrid, out: &mut [f64]) {
        match field {
            Field::Pressure => {
                if self.decoded
                    && self.rom.last_head_factor().is_some()
                    && self.rom.render_pressure(grid, self.force().z, out)
                {
                    return;
                }
                self.mpm.field(field, grid, out);
                out.iter_mut().for_each(|p| *p *= self.force_factor);
            }
            Field::Shear => self.mpm.field(field, grid, out),
        }
    }

    /// From the coarse gel too.
    fn displacement(&self, rest: [f64; 2]) -> [f64; 2] {
        self.mpm.displacement(rest)
    }

    fn reset(&mut self) {
        self.mpm.reset();
        self.force_factor = 1.0;
        self.decoded = false;
        self.fell_back = false;
    }

    fn try_clone(&self) -> Result<Box<dyn SurfaceModel>, SensorError> {
        let rom = self.rom.try_clone().map_err(|e| SensorError::Physics {
            sensor: self.mpm.name.clone(),
            message: format!("cannot copy the reduced-order model: {e}"),
        })?;
        Ok(Box::new(Reduced {
            mpm: self.mpm.clone(),
            rom: Box::new(rom),
            force_factor: self.force_factor,
            decoded: self.decoded,
            fell_back: self.fell_back,
        }))
    }

    /// The coarse gel's state, the last decoding's force factor and whether the last solve
    /// fell back: the decoder itself keeps nothing between frames.
    fn persist(&mut self, io: &mut Io<'_>, shapes: &[Arc<dyn Sdf>]) -> bool {
        self.force_factor.persist(io);
        self.decoded.persist(io);
        self.fell_back.persist(io);
        self.mpm.persist(io, shapes)
    }
}

/// The directory a `model` value names: the directory itself, or, for a bare name that is
/// no directory here, the shipped model of that name (`rom-default`, `rom-linear`) where
/// there is one.
fn model_dir(value: &std::path::Path) -> std::path::PathBuf {
    let bare = value.components().count() == 1 && !value.is_dir();
    bare.then(|| value.to_str().and_then(crate::rom::shipped_model_dir))
        .flatten()
        .unwrap_or_else(|| value.to_path_buf())
}

/// Loads the reduced-order model of a `physics="rom"` sensor: the `model` directory (or
/// shipped model's name) or the shipped one for its solver, checked against the sensor's
/// gel and coarse solve.
fn load_rom(config: &Config, dx: f64, solver: Solver) -> Result<Rom, String> {
    let attr = crate::config::ATTR_MODEL;
    let shipped = crate::rom::shipped_model(solver.name(), config.size[2]);
    let dir = match &config.model {
        Some(d) => model_dir(d),
        None => crate::rom::shipped_model_dir(shipped).ok_or_else(|| {
            format!(
                "attribute '{attr}': the shipped model models/{shipped} was not found beside \
                 the plugin library; set '{attr}' to a model directory",
            )
        })?,
    };
    let in_dir =
        |e: crate::rom::RomError| format!("attribute '{attr}' = \"{}\": {e}", dir.display());
    // A gel or a solve the model does not serve: the attribute the user set leads, the
    // model after it.
    let served = |e: crate::rom::RomError| match &e {
        crate::rom::RomError::Mismatch { attribute, .. } => format!(
            "attribute '{attribute}': {e}; the reduced-order model is attribute '{attr}' \
             (physics=\"coarse\" serves any gel)"
        ),
        _ => in_dir(e),
    };
    let mut rom = Rom::load(
        &dir,
        RomOptions {
            refine: config.refine,
            threads: config.threads,
            pressure: config
                .outputs
                .iter()
                .any(|o| o.spec().needs.has(Field::Pressure)),
            force: config.coupling || config.outputs.iter().any(|o| o.spec().needs.force),
        },
    )
    .map_err(in_dir)?;
    let m = rom.manifest();
    let scale = m
        .check_gel(config.size, config.poisson, config.friction)
        .map_err(served)?;
    m.check_recipe(
        dx,
        scale,
        material_name(config.material),
        solver.name(),
        config.tolerance,
    )
    .map_err(served)?;
    rom.serve(config.size);
    Ok(rom)
}
