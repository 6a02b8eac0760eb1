//! The sensor's configuration: the MJCF `<config key=... value=...>` attributes, parsed
//! into typed values and validated. Pure Rust; the MuJoCo layer only supplies a lookup.
//!
//! Parsing and validation are separate steps: [`RawConfig`] holds the text of each
//! attribute (an empty value means "absent"), [`Config::from_raw`] turns it into numbers
//! and checks every range, with a message that names the sensor, the attribute and the
//! value.

use std::fmt;
use std::path::Path;
use std::sync::Arc;

use crate::attributes::{self, Attribute, Valid};
use crate::mpm::{Choice, GelParams, Material, Solver};
use crate::render::calibrated::CalibratedOptics;
pub use crate::render::refraction::Camera;

/// `sensor`: [`attributes::SENSOR`].
pub const ATTR_SENSOR: &str = attributes::SENSOR.name;
/// `view`: [`attributes::VIEW`].
pub const ATTR_VIEW: &str = attributes::VIEW.name;
/// `physics`: [`attributes::PHYSICS`].
pub const ATTR_PHYSICS: &str = attributes::PHYSICS.name;
/// `outputs`: [`attributes::OUTPUTS`].
pub const ATTR_OUTPUTS: &str = attributes::OUTPUTS.name;
/// `resolution`: [`attributes::RESOLUTION`].
pub const ATTR_RESOLUTION: &str = attributes::RESOLUTION.name;
/// `fov`: [`attributes::FOV`].
pub const ATTR_FOV: &str = attributes::FOV.name;
/// `size`: [`attributes::SIZE`].
pub const ATTR_SIZE: &str = attributes::SIZE.name;
/// `indenters`: [`attributes::INDENTERS`].
pub const ATTR_INDENTERS: &str = attributes::INDENTERS.name;
/// `young`: [`attributes::YOUNG`].
pub const ATTR_YOUNG: &str = attributes::YOUNG.name;
/// `poisson`: [`attributes::POISSON`].
pub const ATTR_POISSON: &str = attributes::POISSON.name;
/// `density`: [`attributes::DENSITY`].
pub const ATTR_DENSITY: &str = attributes::DENSITY.name;
/// `friction`: [`attributes::FRICTION`].
pub const ATTR_FRICTION: &str = attributes::FRICTION.name;
/// `dx`: [`attributes::DX`].
pub const ATTR_DX: &str = attributes::DX.name;
/// `threads`: [`attributes::THREADS`].
pub const ATTR_THREADS: &str = attributes::THREADS.name;
/// `model`: [`attributes::MODEL`].
pub const ATTR_MODEL: &str = attributes::MODEL.name;
/// `refine`: [`attributes::REFINE`].
pub const ATTR_REFINE: &str = attributes::REFINE.name;
/// `material`: [`attributes::MATERIAL`].
pub const ATTR_MATERIAL: &str = attributes::MATERIAL.name;
/// `tolerance`: [`attributes::TOLERANCE`].
pub const ATTR_TOLERANCE: &str = attributes::TOLERANCE.name;
/// `markers`: [`attributes::MARKERS`].
pub const ATTR_MARKERS: &str = attributes::MARKERS.name;
/// `optics`: [`attributes::OPTICS`].
pub const ATTR_OPTICS: &str = attributes::OPTICS.name;
/// `camera`: [`attributes::CAMERA`].
pub const ATTR_CAMERA: &str = attributes::CAMERA.name;
/// `index`: [`attributes::INDEX`].
pub const ATTR_INDEX: &str = attributes::INDEX.name;
/// `solver`: [`attributes::SOLVER`].
pub const ATTR_SOLVER: &str = attributes::SOLVER.name;
/// `coupling`: [`attributes::COUPLING`].
pub const ATTR_COUPLING: &str = attributes::COUPLING.name;
/// `damping`: [`attributes::DAMPING`].
pub const ATTR_DAMPING: &str = attributes::DAMPING.name;
/// `gel_geom`: [`attributes::GEL_GEOM`].
pub const ATTR_GEL_GEOM: &str = attributes::GEL_GEOM.name;
/// `hold`: [`attributes::HOLD`].
pub const ATTR_HOLD: &str = attributes::HOLD.name;

/// Every attribute the plugin declares to MuJoCo, in table order ([`attributes::TABLE`]).
pub const ATTRIBUTES: &[&str] = &attributes::NAMES;

/// The `material` attribute's values ([`Material::NAMED`]: the list in `mpm/materials/`).
pub const MATERIALS: &[(&str, Material)] = Material::NAMED;

/// The `material` attribute's value naming `material`.
pub fn material_name(material: Material) -> &'static str {
    material.name()
}

/// Largest image side accepted (pixels).
pub const MAX_RESOLUTION: usize = attributes::RESOLUTION.valid.integers().1;
/// The `index` attribute's range: from no refraction (a camera in a medium of the gel's
/// index) to well past any gel's (silicone in air: about 1.4).
pub const INDEX_RANGE: [f64; 2] = {
    let r = attributes::INDEX.valid.range();
    [r.lo, r.hi]
};
/// The largest pinhole distance `D` accepted (m) ([`attributes::CAMERA_DISTANCE`]).
pub const MAX_CAMERA_DISTANCE: f64 = attributes::CAMERA_DISTANCE.hi;
/// Most markers along one side of the marker grid.
pub const MAX_MARKERS: usize = attributes::MARKERS.valid.integers().1;
/// Most grid cells of a gel (about 1.6e8 particles, 6 GB of them).
pub const MAX_CELLS: f64 = 2.0e7;
/// Largest thread count accepted.
pub const MAX_THREADS: usize = attributes::THREADS.valid.integers().1;

/// How the gel's surface is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Physics {
    /// Geometric penetration of the undeformed gel: fastest, crudest.
    Rigid,
    /// Coarse MPM (about 1e4 particles) to quasi-static equilibrium.
    Coarse,
    /// Fine MPM (about 1e6 particles): the reference; slow.
    Fine,
    /// Coarse MPM plus the neural decoder restoring fine detail (ONNX, `model`).
    Rom,
}

impl Physics {
    /// Every mode this build offers, by name.
    pub const ALL: &'static [(&'static str, Physics)] = &[
        ("rigid", Physics::Rigid),
        ("coarse", Physics::Coarse),
        ("fine", Physics::Fine),
        ("rom", Physics::Rom),
    ];

    /// The attribute value naming this mode.
    pub fn name(self) -> &'static str {
        Self::ALL
            .iter()
            .find(|(_, p)| *p == self)
            .map(|(n, _)| *n)
            .unwrap_or("?")
    }

    /// Default MPM grid spacing (m) for a gel of thickness `t`; `None` for rigid.
    ///
    /// The coarse grid follows the thickness: [`defaults::COARSE_LAYER`] thicknesses
    /// (the default gel's 2.86 cells through the layer at every thickness), at most
    /// [`defaults::COARSE_DX`] (`coarse`; thicker gels keep the default gel's spacing,
    /// which is more accurate than their own 2.86 cells and costs little). `rom`'s grid
    /// is the same fraction of the thickness without that bound, so that its model sees,
    /// on a gel of its own shape at any thickness, the press it was trained on scaled
    /// (checked against the manifest). Measured: `docs/rom.md`, "A coarse grid that
    /// follows the thickness".
    pub fn default_dx(self, t: f64) -> Option<f64> {
        let layer = defaults::COARSE_LAYER * t;
        match self {
            Physics::Rigid => None,
            Physics::Coarse => Some(defaults::COARSE_DX.min(layer)),
            Physics::Rom => Some(layer),
            Physics::Fine => Some(defaults::FINE_DX.min(t / 4.0)),
        }
    }

    /// Default convergence threshold of the MPM solve (relative out-of-balance force).
    ///
    /// `fine` is the reference and is solved to 1e-3. `coarse` and `rom` stop at 3e-3: about
    /// half the time of 1e-3, with a frictional twist's force within 3 % of it, where 1e-2
    /// let that force stray by up to 25 % (measured: `docs/configuration.md`,
    /// "`tolerance`").
    pub fn default_tolerance(self) -> f64 {
        match self {
            Physics::Fine => 1e-3,
            Physics::Rigid | Physics::Coarse | Physics::Rom => 3e-3,
        }
    }
}

pub use crate::sensor::outputs::{Layout, Output, Seen};

/// The side the images are seen from (`view`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum View {
    /// From the indenter's side: row 0 at +y, column 0 at -x.
    #[default]
    Indenter,
    /// From the camera under the gel: row 0 at +y, column 0 at +x (the indenter's view
    /// mirrored left-right, as a real sensor's camera records it).
    Camera,
}

/// The text of each attribute, as found in the MJCF; `None` when absent or empty.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RawConfig {
    /// `(attribute, value)` pairs with non-empty values.
    pub values: Vec<(String, String)>,
    /// The sensor file (`sensor`) whose attributes fill those the MJCF does not give, and
    /// the attributes it gave ([`RawConfig::with_sensor_file`]).
    from_file: Option<(std::path::PathBuf, Vec<String>)>,
}

/// Whether a sensor file's `attribute` applies to a sensor of `physics` (the attribute's
/// text): all do but `dx` and `solver` for `rom`, since a file's grid spacing and solver
/// are its coarse gel's, and `rom` runs on its model's grid (a fixed fraction of the
/// thickness) with its model's solver (the shipped GelSight Mini's `solver="linear"`
/// refused `model="rom-default"`, trained on the relaxation). Written in the MJCF, both
/// still apply, and are checked against the model.
pub fn file_attribute_applies(physics: &str, attribute: &str) -> bool {
    !(physics.trim() == Physics::Rom.name() && [ATTR_DX, ATTR_SOLVER].contains(&attribute))
}

impl RawConfig {
    /// Collects the attributes through `lookup`, which returns the configured text of an
    /// attribute or `None`.
    pub fn collect(mut lookup: impl FnMut(&str) -> Option<String>) -> Self {
        let values = ATTRIBUTES
            .iter()
            .filter_map(|&a| {
                lookup(a)
                    .filter(|v| !v.trim().is_empty())
                    .map(|v| (a.to_owned(), v))
            })
            .collect();
        Self {
            values,
            from_file: None,
        }
    }

    /// These attributes over the sensor file `file`'s: each attribute the file gives and
    /// these do not is added, marked as the file's (for messages); its `dx` and `solver`
    /// are left out where the sensor is `rom`, whose grid and solver its model fixes.
    pub fn with_sensor_file(&self, file: &crate::sensor_file::SensorFile) -> RawConfig {
        let mut merged = self.clone();
        let mut given = Vec::new();
        let file_value = |a: &str| file.attributes.iter().find(|(k, _)| k == a);
        let physics = self
            .get(ATTR_PHYSICS)
            .or(file_value(ATTR_PHYSICS).map(|(_, v)| v.as_str()))
            .unwrap_or(defaults::PHYSICS);
        for (a, v) in &file.attributes {
            if self.get(a).is_none() && file_attribute_applies(physics, a) {
                merged.values.push((a.clone(), v.clone()));
                given.push(a.clone());
            }
        }
        merged.from_file = Some((file.path.clone(), given));
        merged
    }

    /// The sensor file that gave `attribute`'s value, if one did.
    pub fn file_of(&self, attribute: &str) -> Option<&std::path::Path> {
        self.from_file
            .as_ref()
            .filter(|(_, given)| given.iter().any(|a| a == attribute))
            .map(|(path, _)| path.as_path())
    }

    /// The text of `attribute`, if given.
    pub fn get(&self, attribute: &str) -> Option<&str> {
        self.values
            .iter()
            .find(|(a, _)| a == attribute)
            .map(|(_, v)| v.as_str())
    }

    /// Builder-style setter, for tests and programmatic use.
    pub fn with(mut self, attribute: &str, value: &str) -> Self {
        self.values.retain(|(a, _)| a != attribute);
        self.values.push((attribute.to_owned(), value.to_owned()));
        self
    }
}

/// An invalid attribute.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("tacrom.tactile sensor '{sensor}': attribute '{attribute}' = \"{value}\": {reason}")]
pub struct ConfigError {
    /// Name of the sensor.
    pub sensor: String,
    /// The attribute at fault.
    pub attribute: String,
    /// Its value as written.
    pub value: String,
    /// What is wrong, and what would be valid.
    pub reason: String,
}

/// A validated sensor configuration, in SI units.
#[derive(Clone, Debug, PartialEq)]
pub struct Config {
    /// Sensor name (for messages).
    pub name: String,
    /// Physics mode.
    pub physics: Physics,
    /// Outputs in sensordata order, each at most once.
    pub outputs: Vec<Output>,
    /// Image width (pixels).
    pub width: usize,
    /// Image height (pixels).
    pub height: usize,
    /// Image extent on the gel, x and y (m).
    pub fov: [f64; 2],
    /// Gel extent Lx, Ly and thickness T (m).
    pub size: [f64; 3],
    /// Bodies whose geoms may press the gel; empty means every other body.
    pub indenters: Vec<String>,
    /// Young's modulus (Pa).
    pub young: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Density (kg/m^3).
    pub density: f64,
    /// Coulomb friction coefficient.
    pub friction: f64,
    /// MPM grid spacing (m); `None` for rigid physics.
    pub dx: Option<f64>,
    /// Solver threads.
    pub threads: usize,
    /// Reduced-order model directory (`physics="rom"`); `None`: the shipped model.
    pub model: Option<std::path::PathBuf>,
    /// Latent refinement on or off (`physics="rom"`); `None`: as the manifest says.
    pub refine: Option<bool>,
    /// Convergence threshold of the MPM solve (relative out-of-balance force).
    pub tolerance: f64,
    /// Constitutive model of the gel.
    pub material: Material,
    /// Markers along x and y (`markers` output).
    pub markers: [usize; 2],
    /// The calibrated optics of the `rgb` output (the `optics` file), read and its
    /// background resampled to the image once, here; `None`: the built-in shading, or
    /// `rgb` not among the outputs (then the file is not read).
    pub optics: Option<Arc<CalibratedOptics>>,
    /// The camera under the gel.
    pub camera: Camera,
    /// The side the images are seen from.
    pub view: View,
    /// The gel's refractive index relative to the camera's medium.
    pub index: f64,
    /// Whether the gel's contact force is applied back to the bodies (`coupling`).
    pub coupling: bool,
    /// Kelvin-Voigt retardation time of the coupling (s).
    pub damping: f64,
    /// The geom standing for the gel in MuJoCo's collision, whose contacts carry the
    /// coupling implicitly (`gel_geom`); `None`: the coupling's force is explicit.
    pub gel_geom: Option<String>,
    /// The indenters' motion since the last solve below which a frame repeats that solve's
    /// outputs (m; `hold`, 0: every frame solves).
    pub hold: f64,
    /// The gel's equilibrium solver; `None` leaves the choice to the gel
    /// ([`crate::mpm::choose`]) or the reduced-order model's recipe.
    pub solver: Option<Solver>,
}

/// The defaults (GelSight Mini-like gel, paper's material), from the attribute table.
pub mod defaults {
    pub use crate::attributes::defaults::*;
    /// The camera: orthographic, the depth straight above each pixel.
    pub const CAMERA: super::Camera = super::Camera::Orthographic;
}

impl Config {
    /// The equilibrium solver of this configuration's gel on a grid of spacing `dx` (m),
    /// and whether frames whose contact its particles cannot resolve fall back to the
    /// linear solver: the solver the configuration names, or the gel's own choice
    /// ([`crate::mpm::choose`]) with the fallback for `coarse` and `rom`.
    pub fn solver_choice(&self, dx: f64) -> (Solver, bool) {
        let c = self.choice(dx);
        (c.solver, c.fallback)
    }

    /// The gel's solver on a grid of spacing `dx` (m) and why ([`crate::mpm::choice`]).
    pub fn choice(&self, dx: f64) -> Choice {
        use crate::mpm::Role;
        // rom's own default model, unnamed or named by its shipped name, or another
        // shipped model of the same coarse solve (the narrow decoder, the gel family's).
        let linear = |m: &std::path::Path| {
            [
                crate::rom::LINEAR_MODEL,
                crate::rom::LINEAR_NARROW_MODEL,
                crate::rom::FAMILY_MODEL,
            ]
            .iter()
            .any(|name| m == std::path::Path::new(name))
        };
        let role = match self.physics {
            Physics::Rom if self.model.as_deref().is_none_or(linear) => Role::ShippedRom,
            Physics::Coarse | Physics::Rom => Role::Coarse,
            Physics::Rigid | Physics::Fine => Role::Reference,
        };
        crate::mpm::choose(&self.gel_params(dx), self.solver, role)
    }

    /// The fingerprint of the sources this configuration's results depend on: the
    /// relaxation's ([`crate::RELAXATION_FINGERPRINT`]) for a gel that dynamic relaxation
    /// alone solves, all of the physics ([`crate::PHYSICS_FINGERPRINT`]) otherwise.
    pub fn physics_fingerprint(&self) -> &'static str {
        match self.dx.map(|dx| self.solver_choice(dx)) {
            Some((Solver::Relaxation, false)) => crate::RELAXATION_FINGERPRINT,
            _ => crate::PHYSICS_FINGERPRINT,
        }
    }

    /// The gel of this configuration on a grid of spacing `dx` (m).
    pub fn gel_params(&self, dx: f64) -> GelParams {
        GelParams {
            size: self.size,
            young: self.young,
            poisson: self.poisson,
            density: self.density,
            friction: self.friction,
            dx,
            material: self.material,
        }
    }

    /// Validates `raw` for the sensor called `name`, reading the files it names (the
    /// `optics` file, when `rgb` is among the outputs).
    pub fn from_raw(name: &str, raw: &RawConfig) -> Result<Config, ConfigError> {
        Self::parse(name, raw, true)
    }

    /// Validates `raw` as [`Config::from_raw`] does, without reading the files it names:
    /// everything the sensordata's size depends on, for MuJoCo's `nstate` and
    /// `nsensordata` at compile time (the sensor's `init`, which follows, reads them once).
    ///
    /// MuJoCo gives those callbacks and `init` no storage per model between them, so the
    /// attributes' parses are kept for the process, keyed by the sensor's name, its
    /// attributes and its sensor file's (read at every call: a rewritten file is a new
    /// key): a model's sensor is parsed once, however many callbacks and `MjData` ask.
    pub fn without_files(name: &str, raw: &RawConfig) -> Result<Config, ConfigError> {
        Self::parse(name, raw, false)
    }

    fn parse(name: &str, raw: &RawConfig, read_files: bool) -> Result<Config, ConfigError> {
        // A sensor file gives the attributes the MJCF leaves out (read at compile time
        // too: it may set the resolution or the outputs, and so the sensordata's size).
        let merged;
        let raw = match raw.get(ATTR_SENSOR) {
            None => raw,
            Some(value) => {
                let file = crate::sensor_file::SensorFile::read(value)
                    .map_err(|e| Parser { name, raw }.error(ATTR_SENSOR, e))?;
                merged = raw.with_sensor_file(&file);
                &merged
            }
        };
        let p = Parser { name, raw };
        let mut config = parsed::recall(name, raw).map_or_else(
            || {
                let config = Self::parse_attributes(&p)?;
                parsed::keep(name, raw, &config);
                Ok::<_, ConfigError>(config)
            },
            Ok,
        )?;
        if read_files {
            config.optics = p.optics(&config.outputs, config.width, config.height)?;
        }
        Ok(config)
    }

    /// The configuration the attributes of `p` give, the files they name unread.
    fn parse_attributes(p: &Parser<'_>) -> Result<Config, ConfigError> {
        #[cfg(test)]
        parsed::PARSES.with(|n| n.set(n.get() + 1));
        let (name, raw) = (p.name, p.raw);

        let physics = p.physics()?;
        let outputs = p.outputs()?;
        if let Some(o) = outputs
            .iter()
            .find(|o| physics == Physics::Rigid && o.spec().needs_gel)
        {
            return Err(p.error(
                ATTR_OUTPUTS,
                format!(
                    "output '{}' needs a gel model: set physics to coarse, fine or rom (rigid \
                     penetration has no stiffness)",
                    o.name()
                ),
            ));
        }
        let [width, height] = p.resolution()?;
        let markers = p.markers()?;
        let size = p.ranged::<3>(&attributes::SIZE, defaults::SIZE)?;
        let fov = p.fov(&size)?;
        let young = p.ranged::<1>(&attributes::YOUNG, [defaults::YOUNG])?[0];
        let poisson = p.ranged::<1>(&attributes::POISSON, [defaults::POISSON])?[0];
        let density = p.ranged::<1>(&attributes::DENSITY, [defaults::DENSITY])?[0];
        let friction = p.ranged::<1>(&attributes::FRICTION, [defaults::FRICTION])?[0];
        let dx = match raw.get(ATTR_DX) {
            None => physics.default_dx(size[2]),
            Some(_) => {
                let t = size[2];
                let dx = p.float(ATTR_DX, 0.0, |x| {
                    (x > 0.0 && x <= t / 2.0)
                        .then_some(())
                        .ok_or_else(|| "must be positive and at most half the gel thickness".into())
                })?;
                (physics != Physics::Rigid).then_some(dx)
            }
        };
        if let Some(dx) = dx {
            let cells = (size[0] / dx) * (size[1] / dx) * (size[2] / dx);
            if cells > MAX_CELLS {
                // The attribute at fault: the spacing the configuration gives, or else the
                // gel's size at the mode's own spacing.
                return Err(match raw.get(ATTR_DX) {
                    Some(_) => p.error(ATTR_DX, "gives more than 2e7 grid cells: too fine"),
                    None => p.error(
                        ATTR_SIZE,
                        format!(
                            "gives {cells:.1e} grid cells at the {} mode's spacing dx = {} m, \
                             more than 2e7: a smaller gel (metres, not millimetres?) or a \
                             larger 'dx'",
                            physics.name(),
                            attributes::number(dx)
                        ),
                    ),
                });
            }
        }
        let threads = p.int(ATTR_THREADS, defaults::THREADS, 1, MAX_THREADS)?;
        let tolerance = p.ranged::<1>(&attributes::TOLERANCE, [physics.default_tolerance()])?[0];
        let model = raw
            .get(ATTR_MODEL)
            .map(|v| std::path::PathBuf::from(v.trim()));
        let refine = match raw.get(ATTR_REFINE).map(str::trim) {
            None => None,
            Some("true") => Some(true),
            Some("false") => Some(false),
            Some(_) => return Err(p.error(ATTR_REFINE, "expected true or false")),
        };
        let material = match raw.get(ATTR_MATERIAL).map(str::trim) {
            None => Material::FixedCorotated,
            Some(v) => MATERIALS
                .iter()
                .find(|(n, _)| *n == v)
                .map(|(_, m)| *m)
                .ok_or_else(|| {
                    let valid: Vec<_> = MATERIALS.iter().map(|(n, _)| *n).collect();
                    p.error(
                        ATTR_MATERIAL,
                        format!("unknown material; valid values: {}", valid.join(", ")),
                    )
                })?,
        };
        let optics = None;
        let camera = p.camera()?;
        if let Some(o) = outputs
            .iter()
            .find(|o| camera != Camera::Orthographic && o.spec().seen == Seen::Refused)
        {
            return Err(p.error(
                ATTR_CAMERA,
                format!(
                    "output '{}' is only defined for the orthographic camera; use \
                     camera=\"orthographic\" or leave '{}' out of the outputs",
                    o.name(),
                    o.name()
                ),
            ));
        }
        let index = p.ranged::<1>(&attributes::INDEX, [defaults::INDEX])?[0];
        let view = match raw.get(ATTR_VIEW).map(str::trim) {
            None | Some("indenter") => View::Indenter,
            Some("camera") => View::Camera,
            Some(_) => return Err(p.error(ATTR_VIEW, "expected indenter or camera")),
        };
        let coupling = match raw.get(ATTR_COUPLING).map(str::trim) {
            None | Some("off") => false,
            Some("on") => true,
            Some(_) => return Err(p.error(ATTR_COUPLING, "expected on or off")),
        };
        if coupling && physics == Physics::Rigid {
            return Err(p.error(
                ATTR_COUPLING,
                "needs a gel model to push back: set physics to coarse, fine or rom (rigid \
                 has no contact force)",
            ));
        }
        let damping = p.ranged::<1>(&attributes::DAMPING, [defaults::DAMPING])?[0];
        let gel_geom = match raw.get(ATTR_GEL_GEOM).map(str::trim) {
            None => None,
            Some("") => {
                return Err(p.error(ATTR_GEL_GEOM, "empty: name a geom of the sensor's body"))
            }
            Some(_) if !coupling => {
                return Err(p.error(
                    ATTR_GEL_GEOM,
                    "needs coupling=\"on\" (the geom carries the gel's push-back)",
                ))
            }
            Some(name) => Some(name.to_owned()),
        };
        let hold = p.ranged::<1>(&attributes::HOLD, [defaults::HOLD])?[0];
        let solver = match raw.get(ATTR_SOLVER).map(str::trim) {
            None => None,
            Some(v) => Some(Solver::named(v).ok_or_else(|| {
                let valid: Vec<_> = Solver::ALL.iter().map(|s| s.name()).collect();
                p.error(
                    ATTR_SOLVER,
                    format!("unknown solver; valid values: {}", valid.join(", ")),
                )
            })?),
        };
        if let (Some(Solver::Linear), Some(dx)) = (solver, dx) {
            // The linear solver factors its whole grid: refused here, naming the attribute
            // that made the grid too fine, not later by the gel in its own words.
            let params = GelParams {
                size,
                dx,
                ..GelParams::default()
            };
            if !crate::mpm::choice::linear_fits(&params) {
                let at = if raw.get(ATTR_DX).is_some() {
                    ATTR_DX
                } else {
                    ATTR_SIZE
                };
                return Err(p.error(
                    at,
                    format!(
                        "gives a grid of more than the {} unknowns that solver=\"linear\" \
                         factors: a larger 'dx' or solver=\"newton\"",
                        crate::mpm::choice::LINEAR_UNKNOWNS
                    ),
                ));
            }
        }
        let indenters = raw
            .get(ATTR_INDENTERS)
            .map(|v| v.split_whitespace().map(str::to_owned).collect())
            .unwrap_or_default();

        Ok(Config {
            name: name.to_owned(),
            physics,
            outputs,
            width,
            height,
            fov,
            size,
            indenters,
            young,
            poisson,
            density,
            friction,
            dx,
            threads,
            model,
            refine,
            tolerance,
            material,
            markers,
            optics,
            camera,
            view,
            index,
            coupling,
            damping,
            gel_geom,
            hold,
            solver,
        })
    }

    /// Number of pixels of one image.
    pub fn pixels(&self) -> usize {
        self.width * self.height
    }

    /// What the outputs' sizes depend on.
    pub fn layout(&self) -> Layout {
        Layout {
            width: self.width,
            height: self.height,
            markers: self.markers,
        }
    }

    /// Total sensordata length: the outputs' lengths added up.
    pub fn sensordata_len(&self) -> usize {
        let layout = self.layout();
        self.outputs.iter().map(|o| o.spec().len(&layout)).sum()
    }

    /// Whether `output` was asked for.
    pub fn wants(&self, output: Output) -> bool {
        self.outputs.contains(&output)
    }
}

/// The file-free parses of this process ([`Config::without_files`]).
mod parsed {
    use super::{Config, RawConfig};
    use std::collections::VecDeque;
    use std::sync::Mutex;

    /// Parses kept, the newest.
    const KEPT: usize = 64;

    static KEPT_PARSES: Mutex<VecDeque<(String, Config)>> = Mutex::new(VecDeque::new());

    #[cfg(test)]
    thread_local! {
        /// Attribute parses made on this thread.
        pub(super) static PARSES: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
    }

    fn key(name: &str, raw: &RawConfig) -> String {
        format!("{name}\u{0}{:?}\u{0}{:?}", raw.values, raw.from_file)
    }

    /// The kept parse of `raw` for the sensor `name`, if any.
    pub(super) fn recall(name: &str, raw: &RawConfig) -> Option<Config> {
        let key = key(name, raw);
        let kept = KEPT_PARSES.lock().unwrap_or_else(|e| e.into_inner());
        kept.iter()
            .rev()
            .find(|(k, _)| *k == key)
            .map(|(_, c)| c.clone())
    }

    /// Keeps `config`, the parse of `raw` for the sensor `name`.
    pub(super) fn keep(name: &str, raw: &RawConfig, config: &Config) {
        let mut kept = KEPT_PARSES.lock().unwrap_or_else(|e| e.into_inner());
        if kept.len() >= KEPT {
            kept.pop_front();
        }
        kept.push_back((key(name, raw), config.clone()));
    }
}

struct Parser<'a> {
    name: &'a str,
    raw: &'a RawConfig,
}

impl Parser<'_> {
    fn error(&self, attribute: &str, reason: impl fmt::Display) -> ConfigError {
        let reason = match self.raw.file_of(attribute) {
            Some(file) => format!("{reason} (the value of the sensor file {})", file.display()),
            None => reason.to_string(),
        };
        ConfigError {
            sensor: self.name.to_owned(),
            attribute: attribute.to_owned(),
            value: self.raw.get(attribute).unwrap_or("").to_owned(),
            reason,
        }
    }

    fn physics(&self) -> Result<Physics, ConfigError> {
        let value = self
            .raw
            .get(ATTR_PHYSICS)
            .unwrap_or(defaults::PHYSICS)
            .trim();
        Physics::ALL
            .iter()
            .find(|(n, _)| *n == value)
            .map(|(_, p)| *p)
            .ok_or_else(|| {
                let valid: Vec<_> = Physics::ALL.iter().map(|(n, _)| *n).collect();
                self.error(
                    ATTR_PHYSICS,
                    format!("unknown physics; valid values: {}", valid.join(", ")),
                )
            })
    }

    fn outputs(&self) -> Result<Vec<Output>, ConfigError> {
        let value = self.raw.get(ATTR_OUTPUTS).unwrap_or(defaults::OUTPUTS);
        let valid: Vec<_> = crate::sensor::outputs::TABLE
            .iter()
            .map(|o| o.name())
            .collect();
        let mut outputs = Vec::new();
        for word in value.split_whitespace() {
            let out = Output::named(word).ok_or_else(|| {
                self.error(
                    ATTR_OUTPUTS,
                    format!(
                        "unknown output '{word}'; valid values: {}",
                        valid.join(", ")
                    ),
                )
            })?;
            if outputs.contains(&out) {
                return Err(self.error(ATTR_OUTPUTS, format!("output '{word}' listed twice")));
            }
            outputs.push(out);
        }
        if outputs.is_empty() {
            return Err(self.error(ATTR_OUTPUTS, "no output listed"));
        }
        Ok(outputs)
    }

    fn resolution(&self) -> Result<[usize; 2], ConfigError> {
        let Some(text) = self.raw.get(ATTR_RESOLUTION) else {
            return Ok(defaults::RESOLUTION);
        };
        let words: Vec<_> = text.split_whitespace().collect();
        let reason = format!("expected two integers 'W H', each in 1..={MAX_RESOLUTION}");
        if words.len() != 2 {
            return Err(self.error(ATTR_RESOLUTION, reason));
        }
        let mut wh = [0usize; 2];
        for (slot, word) in wh.iter_mut().zip(&words) {
            *slot = word
                .parse::<usize>()
                .ok()
                .filter(|n| (1..=MAX_RESOLUTION).contains(n))
                .ok_or_else(|| self.error(ATTR_RESOLUTION, &reason))?;
        }
        Ok(wh)
    }

    fn markers(&self) -> Result<[usize; 2], ConfigError> {
        let Some(text) = self.raw.get(ATTR_MARKERS) else {
            return Ok(defaults::MARKERS);
        };
        let reason = format!("expected two integers 'NX NY', each in 1..={MAX_MARKERS}");
        let counts: Vec<usize> = text
            .split_whitespace()
            .map(|w| {
                w.parse::<usize>()
                    .ok()
                    .filter(|n| (1..=MAX_MARKERS).contains(n))
            })
            .collect::<Option<_>>()
            .ok_or_else(|| self.error(ATTR_MARKERS, &reason))?;
        counts
            .try_into()
            .map_err(|_| self.error(ATTR_MARKERS, &reason))
    }

    /// The `optics` file, read and resampled to `width x height`, when `rgb` is among
    /// `outputs`; a relative path is relative to the working directory.
    fn optics(
        &self,
        outputs: &[Output],
        width: usize,
        height: usize,
    ) -> Result<Option<Arc<CalibratedOptics>>, ConfigError> {
        let Some(path) = self.raw.get(ATTR_OPTICS).map(str::trim) else {
            return Ok(None);
        };
        if !outputs.contains(&Output::RGB) {
            return Ok(None);
        }
        let optics = CalibratedOptics::load(Path::new(path))
            .map_err(|e| self.error(ATTR_OPTICS, e.reason()))?;
        Ok(Some(Arc::new(optics.resampled(width, height))))
    }

    /// The `camera` attribute.
    fn camera(&self) -> Result<Camera, ConfigError> {
        let Some(text) = self.raw.get(ATTR_CAMERA) else {
            return Ok(defaults::CAMERA);
        };
        let words: Vec<_> = text.split_whitespace().collect();
        let reason = format!(
            "expected 'orthographic' or 'pinhole D', D the distance from the pinhole to the \
             gel's bottom face in metres, in (0, {MAX_CAMERA_DISTANCE}]"
        );
        match words.as_slice() {
            ["orthographic"] => Ok(Camera::Orthographic),
            ["pinhole", d] => d
                .parse::<f64>()
                .ok()
                .filter(|d| *d > 0.0 && *d <= MAX_CAMERA_DISTANCE)
                .map(|distance| Camera::Pinhole { distance })
                .ok_or_else(|| self.error(ATTR_CAMERA, &reason)),
            _ => Err(self.error(ATTR_CAMERA, &reason)),
        }
    }

    fn fov(&self, size: &[f64; 3]) -> Result<[f64; 2], ConfigError> {
        let Some(text) = self.raw.get(ATTR_FOV) else {
            return Ok([defaults::FOV[0].min(size[0]), defaults::FOV[1].min(size[1])]);
        };
        let v = parse_floats(text)
            .filter(|v| v.len() == 1 || v.len() == 2)
            .ok_or_else(|| self.error(ATTR_FOV, "expected one or two numbers (m)"))?;
        let fov = [v[0], *v.get(1).unwrap_or(&v[0])];
        if !(fov[0] > 0.0 && fov[1] > 0.0 && fov[0] <= size[0] && fov[1] <= size[1]) {
            return Err(self.error(
                ATTR_FOV,
                format!(
                    "must be positive and within the gel size ({} x {} m)",
                    size[0], size[1]
                ),
            ));
        }
        Ok(fov)
    }

    fn floats<const N: usize>(
        &self,
        attribute: &str,
        default: [f64; N],
        check: impl Fn(&[f64; N]) -> Result<(), String>,
    ) -> Result<[f64; N], ConfigError> {
        let Some(text) = self.raw.get(attribute) else {
            return Ok(default);
        };
        let v: [f64; N] = parse_floats(text)
            .and_then(|v| v.try_into().ok())
            .ok_or_else(|| self.error(attribute, format!("expected {N} finite numbers")))?;
        check(&v).map_err(|r| self.error(attribute, r))?;
        Ok(v)
    }

    /// The `N` numbers of `attribute` (`default` when absent), each checked against the
    /// attribute's range in the table.
    fn ranged<const N: usize>(
        &self,
        attribute: &Attribute,
        default: [f64; N],
    ) -> Result<[f64; N], ConfigError> {
        let Valid::Range(range) = attribute.valid else {
            unreachable!("{} has no numeric range", attribute.name)
        };
        let unit = if attribute.unit.is_empty() {
            String::new()
        } else {
            format!(" {}", attribute.unit)
        };
        let reason = if N == 1 {
            format!("must be in {range}{unit}")
        } else {
            format!("each of its {N} numbers must be in {range}{unit}")
        };
        self.floats::<N>(attribute.name, default, |v| {
            v.iter()
                .all(|&x| range.contains(x))
                .then_some(())
                .ok_or_else(|| reason.clone())
        })
    }

    fn float(
        &self,
        attribute: &str,
        default: f64,
        check: impl Fn(f64) -> Result<(), String>,
    ) -> Result<f64, ConfigError> {
        self.floats::<1>(attribute, [default], |v| check(v[0]))
            .map(|v| v[0])
    }

    fn int(
        &self,
        attribute: &str,
        default: usize,
        lo: usize,
        hi: usize,
    ) -> Result<usize, ConfigError> {
        let Some(text) = self.raw.get(attribute) else {
            return Ok(default);
        };
        text.trim()
            .parse::<usize>()
            .ok()
            .filter(|n| (lo..=hi).contains(n))
            .ok_or_else(|| self.error(attribute, format!("expected an integer in {lo}..={hi}")))
    }
}

/// Whitespace-separated finite numbers, or `None` if any word is not one.
fn parse_floats(text: &str) -> Option<Vec<f64>> {
    text.split_whitespace()
        .map(|w| w.parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect()
}

/// The sensordata layout of `config`, as JSON for the Python package: image size and, per
/// output in sensordata order, its name, offset, shape and unit; the marker grid `[NX, NY]`;
/// for a gel, its solver and why it runs it ([`Config::choice`]: `null` for `rigid`).
pub fn layout_json(config: &Config) -> String {
    let layout = config.layout();
    let mut offset = 0;
    let outputs: Vec<serde_json::Value> = config
        .outputs
        .iter()
        .map(|o| {
            let spec = o.spec();
            let entry = serde_json::json!({
                "name": spec.name,
                "offset": offset,
                "shape": spec.dims(&layout),
                "unit": spec.unit,
            });
            offset += spec.len(&layout);
            entry
        })
        .collect();
    serde_json::json!({
        "sensor": config.name,
        "physics": config.physics.name(),
        "solver": config.dx.map(|dx| {
            let c = config.choice(dx);
            serde_json::json!({"name": c.solver.name(), "fallback": c.fallback, "why": c.why})
        }),
        "width": config.width,
        "height": config.height,
        "markers": config.markers,
        "size": offset,
        "outputs": outputs,
    })
    .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(pairs: &[(&str, &str)]) -> Result<Config, ConfigError> {
        let raw = pairs
            .iter()
            .fold(RawConfig::default(), |r, (a, v)| r.with(a, v));
        Config::from_raw("touch", &raw)
    }

    fn err(pairs: &[(&str, &str)]) -> ConfigError {
        parse(pairs).expect_err("configuration should be rejected")
    }

    #[test]
    fn defaults_match_design() {
        let c = parse(&[]).unwrap();
        assert_eq!(c.physics, Physics::Rom);
        assert_eq!(c.outputs, vec![Output::DEPTH]);
        assert_eq!((c.width, c.height), (320, 240));
        assert_eq!(c.fov, [0.024, 0.018]);
        assert_eq!(c.size, [0.03, 0.03, 0.004]);
        assert_eq!(c.young, 1.19e5);
        assert_eq!(c.poisson, 0.43);
        assert_eq!(c.density, 1050.0);
        assert_eq!(c.threads, 1);
        assert_eq!(c.dx, Some(1.4e-3));
        assert_eq!(c.model, None);
        assert_eq!(c.tolerance, 3e-3);
        assert_eq!(c.markers, [9, 7]);
        assert_eq!(c.camera, Camera::Orthographic);
        assert_eq!(c.index, 1.0);
        let fine = parse(&[(ATTR_PHYSICS, "fine")]).unwrap();
        assert_eq!(fine.tolerance, 1e-3);
        assert_eq!(c.sensordata_len(), 320 * 240);
    }

    #[test]
    fn full_configuration_parses() {
        let c = parse(&[
            (ATTR_PHYSICS, "coarse"),
            (ATTR_OUTPUTS, "force  depth contact rgb"),
            (ATTR_RESOLUTION, "64 48"),
            (ATTR_FOV, "0.02"),
            (ATTR_SIZE, "0.025 0.02 0.003"),
            (ATTR_INDENTERS, "ball  finger"),
            (ATTR_YOUNG, "2e5"),
            (ATTR_POISSON, "0.49"),
            (ATTR_DENSITY, "1100"),
            (ATTR_FRICTION, "0"),
            (ATTR_DX, "0.001"),
            (ATTR_THREADS, "2"),
            (ATTR_TOLERANCE, "0.01"),
            (ATTR_MARKERS, " 5  4 "),
        ])
        .unwrap();
        assert_eq!(c.tolerance, 0.01);
        assert_eq!(c.markers, [5, 4]);
        assert_eq!(
            c.outputs,
            vec![Output::FORCE, Output::DEPTH, Output::CONTACT, Output::RGB]
        );
        assert_eq!(c.sensordata_len(), 3 + 2 * 64 * 48 + 3 * 64 * 48);
        assert_eq!(c.fov, [0.02, 0.02]);
        assert_eq!(c.indenters, vec!["ball".to_owned(), "finger".to_owned()]);
        assert_eq!(c.dx, Some(0.001));
        assert_eq!(c.threads, 2);
    }

    #[test]
    fn rigid_physics_renders_rgb_from_its_depth() {
        let c = parse(&[(ATTR_PHYSICS, "rigid"), (ATTR_OUTPUTS, "rgb depth")]).unwrap();
        assert_eq!(c.outputs, vec![Output::RGB, Output::DEPTH]);
        assert_eq!(c.sensordata_len(), 4 * 320 * 240);
        assert!(Output::RGB.spec().needs.depth);
    }

    #[test]
    fn mode_default_dx_gives_the_designed_particle_counts() {
        let coarse = parse(&[(ATTR_PHYSICS, "coarse")]).unwrap().dx.unwrap();
        let fine = parse(&[(ATTR_PHYSICS, "fine")]).unwrap().dx.unwrap();
        let particles = |dx: f64| 8.0 * (0.03 / dx) * (0.03 / dx) * (0.004 / dx);
        assert!(
            (5e3..3e4).contains(&particles(coarse)),
            "{}",
            particles(coarse)
        );
        assert!((5e5..2e6).contains(&particles(fine)), "{}", particles(fine));
    }

    #[test]
    fn material_attribute_selects_the_constitutive_model() {
        assert_eq!(parse(&[]).unwrap().material, Material::FixedCorotated);
        for &(name, m) in MATERIALS {
            assert_eq!(parse(&[(ATTR_MATERIAL, name)]).unwrap().material, m);
            assert_eq!(material_name(m), name);
        }
    }

    #[test]
    fn every_error_names_sensor_attribute_and_value() {
        let cases: &[(&str, &str)] = &[
            (ATTR_PHYSICS, "magic"),
            (ATTR_OUTPUTS, "depth heat"),
            (ATTR_OUTPUTS, "depth depth"),
            (ATTR_OUTPUTS, "depth force"),
            (ATTR_OUTPUTS, "depth shear"),
            (ATTR_OUTPUTS, "markers"),
            (ATTR_RESOLUTION, "0 240"),
            (ATTR_RESOLUTION, "320"),
            (ATTR_RESOLUTION, "320 -1"),
            (ATTR_RESOLUTION, "320 240.5"),
            (ATTR_RESOLUTION, "99999 2"),
            (ATTR_FOV, "0.5 0.5"),
            (ATTR_FOV, "-0.01"),
            (ATTR_FOV, "a b"),
            (ATTR_SIZE, "-0.03 0.03 0.004"),
            (ATTR_SIZE, "0.03 0.03"),
            (ATTR_SIZE, "0.03 nan 0.004"),
            (ATTR_SIZE, "0.03 0.03 inf"),
            (ATTR_YOUNG, "0"),
            (ATTR_YOUNG, "soft"),
            (ATTR_POISSON, "0.5"),
            (ATTR_POISSON, "-0.1"),
            (ATTR_DENSITY, "0"),
            (ATTR_FRICTION, "-1"),
            (ATTR_DX, "0"),
            (ATTR_DX, "0.003"),
            (ATTR_THREADS, "0"),
            (ATTR_THREADS, "two"),
            (ATTR_REFINE, "maybe"),
            (ATTR_TOLERANCE, "0"),
            (ATTR_TOLERANCE, "1"),
            (ATTR_TOLERANCE, "nan"),
            (ATTR_MATERIAL, "rubber"),
            (ATTR_MARKERS, "9"),
            (ATTR_MARKERS, "0 7"),
            (ATTR_MARKERS, "9 7 2"),
            (ATTR_MARKERS, "9 -7"),
            (ATTR_MARKERS, "9.5 7"),
            (ATTR_MARKERS, "1000 7"),
            (ATTR_CAMERA, "fisheye"),
            (ATTR_CAMERA, "pinhole"),
            (ATTR_CAMERA, "pinhole 0"),
            (ATTR_CAMERA, "pinhole -0.02"),
            (ATTR_CAMERA, "pinhole nan"),
            (ATTR_CAMERA, "pinhole inf"),
            (ATTR_CAMERA, "pinhole 20"),
            (ATTR_CAMERA, "pinhole 0.02 0.03"),
            (ATTR_CAMERA, "pinhole two"),
            (ATTR_CAMERA, "orthographic 0.02"),
            (ATTR_INDEX, "0.9"),
            (ATTR_INDEX, "3.5"),
            (ATTR_INDEX, "nan"),
            (ATTR_INDEX, "glass"),
            (ATTR_INDEX, "1.4 1.5"),
        ];
        for &(attribute, value) in cases {
            let mut pairs = vec![(attribute, value)];
            if attribute == ATTR_DX {
                pairs.push((ATTR_PHYSICS, "coarse"));
            }
            if ["depth force", "depth shear", "markers"].contains(&value) {
                // Force, shear or markers without a gel model.
                pairs.push((ATTR_PHYSICS, "rigid"));
            }
            let e = err(&pairs);
            assert_eq!(e.attribute, attribute, "{value}");
            let msg = e.to_string();
            assert!(msg.contains("'touch'"), "{msg}");
            assert!(msg.contains(&format!("'{attribute}'")), "{msg}");
            assert!(msg.contains(value), "{msg}");
        }
    }

    #[test]
    fn camera_and_index_parse() {
        let c = parse(&[(ATTR_CAMERA, " pinhole   0.02 "), (ATTR_INDEX, "1.41")]).unwrap();
        assert_eq!(c.camera, Camera::Pinhole { distance: 0.02 });
        assert_eq!(c.index, 1.41);
        let c = parse(&[(ATTR_CAMERA, "orthographic"), (ATTR_INDEX, "3")]).unwrap();
        assert_eq!(c.camera, Camera::Orthographic);
        assert_eq!(c.index, 3.0);
        assert_eq!(parse(&[(ATTR_CAMERA, "pinhole 1")]).unwrap().index, 1.0);
        // Every output a pinhole camera can show, beside depth.
        let c = parse(&[
            (ATTR_PHYSICS, "coarse"),
            (ATTR_CAMERA, "pinhole 0.02"),
            (ATTR_OUTPUTS, "depth force contact rgb pressure shear"),
        ])
        .unwrap();
        assert_eq!(c.outputs.len(), 6);
    }

    #[test]
    fn pinhole_camera_refuses_the_markers_output() {
        for outputs in ["markers", "depth markers", "rgb markers"] {
            let e = err(&[
                (ATTR_PHYSICS, "coarse"),
                (ATTR_CAMERA, "pinhole 0.02"),
                (ATTR_OUTPUTS, outputs),
            ]);
            assert_eq!(e.attribute, ATTR_CAMERA, "{outputs}");
            let msg = e.to_string();
            assert!(
                msg.contains("'touch'")
                    && msg.contains("pinhole 0.02")
                    && msg.contains("'markers'")
                    && msg.contains("orthographic"),
                "{msg}"
            );
        }
        let ok = parse(&[
            (ATTR_PHYSICS, "coarse"),
            (ATTR_CAMERA, "orthographic"),
            (ATTR_OUTPUTS, "markers"),
        ]);
        assert!(ok.is_ok());
    }

    #[test]
    fn unknown_physics_lists_the_valid_ones() {
        let msg = err(&[(ATTR_PHYSICS, "magic")]).to_string();
        for (name, _) in Physics::ALL {
            assert!(msg.contains(name), "{msg}");
        }
    }

    #[test]
    fn solver_is_parsed_and_an_unknown_one_lists_the_valid_ones() {
        let c = parse(&[(ATTR_PHYSICS, "coarse"), (ATTR_SOLVER, "newton")]).unwrap();
        assert_eq!(c.solver, Some(Solver::Newton));
        assert_eq!(parse(&[]).unwrap().solver, None);
        let msg = err(&[(ATTR_SOLVER, "magic")]).to_string();
        assert!(msg.contains("'solver'") && msg.contains("magic"), "{msg}");
        for s in Solver::ALL {
            assert!(msg.contains(s.name()), "{msg}");
        }
    }

    /// Unset, the solver is Newton's method exactly where relaxation does not converge
    /// (Poisson's ratio 0.49 and more), on every grid; relaxation elsewhere, the fine
    /// mode's grid included; for rom's shipped models the linear gel where it factors.
    #[test]
    fn the_automatic_solver_follows_the_material() {
        use crate::mpm::GelParams;
        let gel = |poisson: f64, dx: f64| GelParams {
            poisson,
            dx,
            ..GelParams::default()
        };
        for dx in [1.4e-3, 0.7e-3, 0.5e-3, 0.3e-3] {
            let auto =
                |g: &GelParams| crate::mpm::choose(g, None, crate::mpm::Role::Reference).solver;
            assert_eq!(auto(&gel(0.43, dx)), Solver::Relaxation);
            assert_eq!(auto(&gel(0.48, dx)), Solver::Relaxation);
            assert_eq!(auto(&gel(0.49, dx)), Solver::Newton);
            assert_eq!(auto(&gel(0.499, dx)), Solver::Newton);
        }
        // rom's shipped models: the linear gel wherever it factors, near-incompressible
        // gels included (its model serves Poisson 0.3 to 0.49); Newton's method from 0.49
        // on a grid too fine to factor.
        let rom = |g: &GelParams| crate::mpm::choose(g, None, crate::mpm::Role::ShippedRom).solver;
        for poisson in [0.3, 0.43, 0.49, 0.499] {
            assert_eq!(rom(&gel(poisson, 1.4e-3)), Solver::Linear);
        }
        assert_eq!(rom(&gel(0.43, 0.3e-3)), Solver::Relaxation);
        assert_eq!(rom(&gel(0.49, 0.3e-3)), Solver::Newton);
    }

    /// A gel that dynamic relaxation alone solves (the fine reference) is named by the
    /// relaxation's sources; one that runs another solver, named or automatic, or falls
    /// back to the linear solver, by all of the physics. The two differ: the other solvers'
    /// sources are left out of the first.
    #[test]
    fn a_configuration_is_fingerprinted_by_the_sources_it_runs() {
        use crate::{PHYSICS_FINGERPRINT as ALL, RELAXATION_FINGERPRINT as RELAXATION};
        assert_ne!(ALL, RELAXATION);
        let print = |pairs: &[(&str, &str)]| parse(pairs).unwrap().physics_fingerprint();
        assert_eq!(print(&[(ATTR_PHYSICS, "fine")]), RELAXATION);
        assert_eq!(
            print(&[(ATTR_PHYSICS, "coarse"), (ATTR_SOLVER, "relaxation")]),
            RELAXATION
        );
        // The automatic fallback of coarse and rom to the linear solver.
        assert_eq!(print(&[(ATTR_PHYSICS, "coarse")]), ALL);
        assert_eq!(
            print(&[(ATTR_PHYSICS, "fine"), (ATTR_SOLVER, "newton")]),
            ALL
        );
        assert_eq!(
            print(&[(ATTR_PHYSICS, "coarse"), (ATTR_SOLVER, "linear")]),
            ALL
        );
        // Newton's method chosen for a near-incompressible gel.
        let auto_newton = parse(&[(ATTR_PHYSICS, "coarse"), (ATTR_POISSON, "0.49")]).unwrap();
        assert_eq!(auto_newton.solver_choice(1.4e-3), (Solver::Newton, true));
        assert_eq!(auto_newton.physics_fingerprint(), ALL);
    }

    #[test]
    fn empty_value_means_absent() {
        let c = parse(&[(ATTR_RESOLUTION, "  "), (ATTR_PHYSICS, "")]);
        // RawConfig::with keeps empty strings; collect() drops them. Check collect().
        assert!(c.is_err());
        let raw = RawConfig::collect(|a| (a == ATTR_RESOLUTION).then(|| " ".to_owned()));
        assert_eq!(Config::from_raw("touch", &raw).unwrap().width, 320);
    }

    /// A valid optics file (3 x 3 table, 4 x 2 background) in a scratch folder of this
    /// test process, with its JSON as a value for editing into bad ones.
    fn optics_file(name: &str) -> (std::path::PathBuf, serde_json::Value) {
        use crate::render::calibrated::{GradientTable, RgbImage};
        let dir = std::env::temp_dir().join(format!("tacrom-config-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let table =
            GradientTable::new([3, 3], [0.5, 0.5], (0..27).map(f64::from).collect()).unwrap();
        let background = RgbImage::uniform(4, 2, [100.0, 110.0, 120.0]);
        let path = dir.join("optics.json");
        CalibratedOptics::new(table, background)
            .unwrap()
            .save(&path, None)
            .unwrap();
        let json = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        (path, json)
    }

    /// A sensor file beside its optics, in a scratch folder of this test process.
    fn sensor_file(name: &str, attributes: serde_json::Value) -> std::path::PathBuf {
        let (optics, _) = optics_file(name);
        let path = optics.parent().unwrap().join(crate::sensor_file::FILE_NAME);
        let text =
            serde_json::json!({"format": crate::sensor_file::FORMAT, "attributes": attributes});
        std::fs::write(&path, text.to_string()).unwrap();
        path
    }

    /// The file's attributes are the defaults; the MJCF's override them; its optics path is
    /// the file's folder's; its folder names it as well as the file.
    #[test]
    fn a_sensor_file_gives_the_defaults_that_the_mjcf_overrides() {
        let path = sensor_file(
            "sensor-file",
            serde_json::json!({"size": [0.02, 0.015, 0.002], "poisson": 0.45,
                               "resolution": "40 30", "outputs": "depth rgb",
                               "optics": "optics.json", "view": "camera"}),
        );
        let file = path.to_str().unwrap();
        let c = parse(&[(ATTR_SENSOR, file), (ATTR_POISSON, "0.3")]).unwrap();
        assert_eq!(c.size, [0.02, 0.015, 0.002]);
        assert_eq!(c.poisson, 0.3);
        assert_eq!((c.width, c.height), (40, 30));
        assert_eq!(c.view, View::Camera);
        assert!(c.optics.is_some());
        let folder = path.parent().unwrap().to_str().unwrap();
        assert_eq!(parse(&[(ATTR_SENSOR, folder)]).unwrap().poisson, 0.45);
        // The same sizes at compile time, without reading the optics.
        let raw = RawConfig::default().with(ATTR_SENSOR, file);
        let early = Config::without_files("touch", &raw).unwrap();
        assert_eq!(early.sensordata_len(), c.sensordata_len());
    }

    /// A sensor's attributes are parsed once for the callbacks MuJoCo makes at compile
    /// time and every `init` after them (only `init` reads the optics); a rewritten
    /// sensor file is parsed anew.
    #[test]
    fn a_sensor_is_parsed_once_however_many_callbacks_ask() {
        let path = sensor_file(
            "parsed-once",
            serde_json::json!({"poisson": 0.45, "outputs": "depth rgb", "optics": "optics.json"}),
        );
        let raw = RawConfig::default().with(ATTR_SENSOR, path.to_str().unwrap());
        let parses = || parsed::PARSES.with(|n| n.get());
        let before = parses();
        let nstate = Config::without_files("parsed-once", &raw).unwrap();
        let nsensordata = Config::without_files("parsed-once", &raw).unwrap();
        let init = Config::from_raw("parsed-once", &raw).unwrap();
        let second_init = Config::from_raw("parsed-once", &raw).unwrap();
        assert_eq!(parses() - before, 1);
        assert_eq!(nstate, nsensordata);
        assert!(nstate.optics.is_none() && init.optics.is_some());
        assert_eq!(init, second_init);
        assert_eq!(
            Config {
                optics: None,
                ..init
            },
            nstate
        );
        // Another sensor name (its messages) or other attributes: another parse.
        Config::without_files("another", &raw).unwrap();
        assert_eq!(parses() - before, 2);
        // The file rewritten: parsed again, with its new value.
        sensor_file("parsed-once", serde_json::json!({"poisson": 0.3}));
        let rewritten = Config::without_files("parsed-once", &raw).unwrap();
        assert_eq!((parses() - before, rewritten.poisson), (3, 0.3));
    }

    /// A bad value in a sensor file is refused naming the attribute, the value and the
    /// file; a missing or malformed file names `sensor`.
    #[test]
    fn a_bad_sensor_file_names_the_sensor_the_attribute_and_the_fault() {
        let path = sensor_file("sensor-bad", serde_json::json!({"poisson": 0.7}));
        let e = parse(&[(ATTR_SENSOR, path.to_str().unwrap())]).unwrap_err();
        assert_eq!(
            (e.sensor.as_str(), e.attribute.as_str(), e.value.as_str()),
            ("touch", ATTR_POISSON, "0.7")
        );
        assert!(e.reason.contains(path.to_str().unwrap()), "{e}");
        // Given beside the file, the same value is the MJCF's, not the file's.
        let e = parse(&[(ATTR_SENSOR, path.to_str().unwrap()), (ATTR_POISSON, "0.8")]).unwrap_err();
        assert!(!e.reason.contains("sensor file"), "{e}");
        let e = parse(&[(ATTR_SENSOR, "/no/such/file.json")]).unwrap_err();
        assert_eq!(e.attribute, ATTR_SENSOR);
        std::fs::write(
            &path,
            "{\"format\": \"tacrom-sensor-1\", \"attributes\": {\"yung\": 1}}",
        )
        .unwrap();
        let e = parse(&[(ATTR_SENSOR, path.to_str().unwrap())]).unwrap_err();
        assert_eq!(e.attribute, ATTR_SENSOR);
        assert!(e.reason.contains("yung"), "{e}");
    }

    /// The shipped sensors load by name.
    #[test]
    fn the_shipped_sensors_load_by_name() {
        for name in crate::sensor_file::SHIPPED {
            let c = parse(&[(ATTR_SENSOR, name), (ATTR_OUTPUTS, "depth rgb")]);
            assert!(c.is_ok(), "{name}: {c:?}");
        }
    }

    #[test]
    fn optics_is_read_only_for_rgb_and_resampled_to_the_image() {
        let (path, _) = optics_file("good");
        let file = path.to_str().unwrap();
        let c = parse(&[
            (ATTR_OUTPUTS, "depth rgb"),
            (ATTR_RESOLUTION, "8 6"),
            (ATTR_OPTICS, file),
        ])
        .unwrap();
        let optics = c.optics.expect("calibrated optics");
        let b = optics.background();
        assert_eq!((b.width, b.height), (8, 6));
        assert!(b.data.chunks(3).all(|px| px == [100.0, 110.0, 120.0]));
        assert_eq!(optics.table().bins(), [3, 3]);
        // Without rgb the file is not read: a missing one is no error, and none is loaded.
        let c = parse(&[
            (ATTR_OUTPUTS, "depth"),
            (ATTR_OPTICS, "/no/such/optics.json"),
        ])
        .unwrap();
        assert!(c.optics.is_none());
        assert!(parse(&[(ATTR_OUTPUTS, "rgb")]).unwrap().optics.is_none());
    }

    #[test]
    fn a_bad_optics_file_is_refused_naming_sensor_attribute_value_and_fault() {
        let (good, json) = optics_file("bad");
        let dir = good.parent().unwrap().to_owned();
        // (file name, its text, words the message must hold)
        let edited = |edit: &dyn Fn(&mut serde_json::Value)| {
            let mut j = json.clone();
            edit(&mut j);
            j.to_string()
        };
        let text = json.to_string();
        let cases: Vec<(&str, String, &[&str])> = vec![
            (
                "truncated.json",
                text[..text.len() / 2].to_owned(),
                &["not an optics file", "EOF"],
            ),
            (
                "nan.json",
                text.replacen("0.0", "NaN", 1),
                &["not an optics file"],
            ),
            (
                "null.json",
                edited(&|j| j["table"][1][1][0] = serde_json::Value::Null),
                &["null"],
            ),
            (
                "huge.json",
                text.replacen("0.0", "1e999", 1),
                &["not an optics file"],
            ),
            (
                "two_channels.json",
                edited(&|j| j["table"][0][2] = serde_json::json!([1.0, 2.0])),
                &["length 2"],
            ),
            (
                "rows.json",
                edited(&|j| {
                    j["table"].as_array_mut().unwrap().pop();
                }),
                &["2 rows", "[3, 3]"],
            ),
            (
                "row_length.json",
                edited(&|j| {
                    j["table"][2]
                        .as_array_mut()
                        .unwrap()
                        .push(serde_json::json!([0, 0, 0]));
                }),
                &["row 2 has 4 entries"],
            ),
            (
                "bins.json",
                edited(&|j| j["bins"] = serde_json::json!([3, 1])),
                &["bins = [3, 1]"],
            ),
            (
                "range.json",
                edited(&|j| j["range"] = serde_json::json!([0.5, -0.5])),
                &["range along gy"],
            ),
            (
                "value.json",
                edited(&|j| j["table"][0][1][2] = serde_json::json!(300.0)),
                &["table[0][1][2] = 300"],
            ),
            (
                "format.json",
                edited(&|j| j["version"] = serde_json::json!(7)),
                &["version 7"],
            ),
            (
                "no_background.json",
                edited(&|j| j["background"] = "missing.png".into()),
                &["background image", "missing.png"],
            ),
            (
                "text_background.json",
                edited(&|j| j["background"] = "optics.json".into()),
                &["background image", "not a PNG"],
            ),
        ];
        let mut paths = vec![(
            "/no/such/optics.json".to_owned(),
            vec!["cannot read", "No such file"],
        )];
        for (name, text, words) in &cases {
            let p = dir.join(name);
            std::fs::write(&p, text).unwrap();
            paths.push((p.to_str().unwrap().to_owned(), words.to_vec()));
        }
        for (path, words) in paths {
            let e = err(&[(ATTR_OUTPUTS, "rgb"), (ATTR_OPTICS, &path)]);
            assert_eq!(e.attribute, ATTR_OPTICS);
            let msg = e.to_string();
            assert!(msg.contains("'touch'") && msg.contains("'optics'"), "{msg}");
            assert!(msg.contains(&format!("\"{path}\"")), "{msg}");
            for w in words {
                assert!(msg.contains(w), "{path}: '{w}' not in: {msg}");
            }
        }
    }

    #[test]
    fn fine_dx_refuses_absurd_grids() {
        let e = err(&[
            (ATTR_PHYSICS, "fine"),
            (ATTR_SIZE, "1 1 0.004"),
            (ATTR_DX, "0.0001"),
        ]);
        assert_eq!(e.attribute, ATTR_DX);
    }

    #[test]
    fn the_attribute_table_names_the_values_the_parser_accepts() {
        let words = |a: &Attribute| match a.valid {
            Valid::Words { words, .. } => words.to_vec(),
            _ => panic!("{} lists no words", a.name),
        };
        let physics: Vec<_> = Physics::ALL.iter().map(|(n, _)| *n).collect();
        assert_eq!(words(&attributes::PHYSICS), physics);
        let outputs: Vec<_> = crate::sensor::outputs::TABLE
            .iter()
            .map(|o| o.name())
            .collect();
        assert_eq!(words(&attributes::OUTPUTS), outputs);
        let materials: Vec<_> = MATERIALS.iter().map(|(n, _)| *n).collect();
        assert_eq!(words(&attributes::MATERIAL), materials);
        let solvers: Vec<_> = Solver::ALL.iter().map(|s| s.name()).collect();
        assert_eq!(words(&attributes::SOLVER), solvers);
        // Every default parses, and each numeric one is the value an unset attribute gets.
        let c = parse(&[]).unwrap();
        assert_eq!(c.physics.name(), defaults::PHYSICS);
        assert_eq!(c.young, defaults::YOUNG);
        assert_eq!(c.size, defaults::SIZE);
        assert_eq!([c.width, c.height], defaults::RESOLUTION);
        assert_eq!(crate::mpm::GelParams::default().young, c.young);
        for a in attributes::TABLE {
            if let attributes::Default::Depends(_) = a.default {
                continue;
            }
            let written = parse(&[(a.name, &a.default.to_text())])
                .unwrap_or_else(|e| panic!("{}: default does not parse: {e}", a.name));
            assert_eq!(
                written, c,
                "{}: the written default differs from the unset one",
                a.name
            );
        }
    }

    #[test]
    fn a_range_violation_names_the_tables_range() {
        for (attr, value, range) in [
            ("young", "50", "[100, 1e10] Pa"),
            ("poisson", "0.5", "[0, 0.4999]"),
            ("tolerance", "1", "[1e-6, 0.5]"),
            ("size", "0.03 0 0.004", "(0, 1] m"),
        ] {
            let msg = err(&[(attr, value)]).to_string();
            assert!(
                msg.contains(&format!("'{attr}'")) && msg.contains(range),
                "{msg}"
            );
        }
    }

    // Regression: a gel given in millimetres (`size="30 30 4"`) at the default spacing was
    // refused as "invalid gel parameter `dx`", an attribute the configuration never set.
    #[test]
    fn a_gel_too_large_for_the_default_spacing_blames_its_size() {
        let e = err(&[("physics", "coarse"), ("size", "1 1 1")]);
        assert_eq!(e.attribute, "size", "{e}");
        assert!(e.reason.contains("dx = 0.0014"), "{e}");
        let e = err(&[
            ("physics", "coarse"),
            ("size", "0.3 0.3 0.04"),
            ("dx", "1e-4"),
        ]);
        assert_eq!(e.attribute, "dx", "{e}");
        assert!(parse(&[("physics", "rigid"), ("size", "1 1 1")]).is_ok());
    }

    // Regression: `solver="linear"` on a grid finer than it factors was refused by the gel
    // at load ("invalid gel parameter `dx`"), not by the configuration with the attribute.
    #[test]
    fn a_grid_too_fine_for_the_linear_solver_blames_its_spacing_or_size() {
        let e = err(&[
            ("physics", "coarse"),
            ("solver", "linear"),
            ("dx", "0.00038"),
        ]);
        assert_eq!(e.attribute, "dx", "{e}");
        assert!(
            e.reason.contains("30000") && e.reason.contains("newton"),
            "{e}"
        );
        let e = err(&[
            ("physics", "coarse"),
            ("solver", "linear"),
            ("size", "0.2 0.2 0.004"),
        ]);
        assert_eq!(e.attribute, "size", "{e}");
        for solver in ["linear", "newton"] {
            let ok = [("physics", "coarse"), ("solver", solver)];
            assert!(parse(&ok).is_ok(), "{solver}");
        }
        assert!(parse(&[
            ("physics", "coarse"),
            ("solver", "newton"),
            ("dx", "0.00038")
        ])
        .is_ok());
    }
}
