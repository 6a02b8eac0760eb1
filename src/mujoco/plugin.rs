//! The plugin callbacks that the C shim (`include/tacrom_shim.c`) registers or forwards to.
//! Each is declared here alone: `build.rs` writes the shim's header from the `pub unsafe
//! extern "C" fn tacrom_*` signatures and the constants `PLUGIN_NAME`, `OK`, `WARN` and
//! `ERROR`.
//!
//! Every entry point goes through `edge`: panics are caught, errors become a status code
//! and a message in the shim's buffer, and nothing unwinds into C. Rust never calls
//! `mju_error`; the shim does, after these functions have returned.

use std::ffi::{c_char, c_int, c_void, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::sync::OnceLock;

use nalgebra::{Isometry3, Point3, Vector3};

use super::draw;
use super::gel_contacts;
use super::scene::{GatherIssues, SceneSpec};
use super::sys;
use super::view::{pose, Data, Model};
use crate::config::{Config, RawConfig, ATTRIBUTES};
use crate::geometry::{Placed, Sdf};
use crate::mpm::Wrench;
use crate::sensor::coupling::{
    centre_of_pressure, linearise, needs_solve, reduced_mass, secant, tangential_secant, Base,
    Coupling, Linearised, Sample, SHALLOWEST, STABLE_RATIO,
};
use crate::sensor::TactileSensor;
use crate::state::{Io, Persist};
use crate::visual::{self, ArrowStyle, Surface, GEOM_BUDGET};

/// The name the shim registers the plugin under (`TACROM_PLUGIN_NAME` in its header).
const PLUGIN_NAME: &str = "tacrom.tactile";

const OK: c_int = 0;
const WARN: c_int = 1;
const ERROR: c_int = -1;

/// Limits how often a running sensor repeats the same kind of warning.
const MAX_REPEATED_WARNINGS: u32 = 5;

/// Everything one sensor instance owns in one `mjData` (behind `plugin_data`).
#[derive(Debug)]
struct Instance {
    sensor_id: usize,
    scene: SceneSpec,
    sensor: TactileSensor,
    placed: Vec<Placed>,
    /// The geom of each of `placed`.
    geoms: Vec<usize>,
    warnings_given: u32,
    /// Whether an indenter reached the gel in the last evaluation (the viewer draws
    /// nothing otherwise).
    touching: bool,
    /// The coupling's memory (`coupling="on"`).
    coupling: Coupling,
    /// Sensordata written by an evaluation that the passive stage had to run itself.
    scratch: Vec<f64>,
    /// The scene's candidate shapes, by which the state names the indenters' shapes.
    shapes: Vec<Arc<dyn Sdf>>,
    /// The signature of the state this instance last wrote into `plugin_state` or took
    /// from it ([`STATE_HEADER`]; zeros: a fresh gel).
    stamp: [f64; 2],
    /// How much of its `plugin_state` may hold non-zero numbers past the header: what the
    /// last write filled, or all of it after a state was taken from there.
    extent: usize,
    /// The implicit coupling's check of the joints' damping
    /// ([`gel_contacts::damping_taken_after_the_solve`]): the physics step it was made at
    /// and the bodies checked (the sensor's, and those that pressed the gel's geom).
    damping_checked: (f64, Vec<usize>),
}

/// Numbers ahead of an instance's state in `plugin_state`: its signature (a number drawn
/// once per process and the write's serial number; both zero for a fresh gel) and whether
/// the whole state follows (1) or the gel's solver keeps part of it elsewhere (0).
const STATE_HEADER: usize = 3;

/// Serial numbers of the states this process writes.
static STATE_WRITES: AtomicU64 = AtomicU64::new(0);

/// The number this process signs its states with: drawn once, a whole number in
/// `[1, 2^52]`, so that a state written by another process is never taken for one's own.
fn process_mark() -> f64 {
    static MARK: OnceLock<f64> = OnceLock::new();
    *MARK.get_or_init(|| {
        use std::hash::BuildHasher;
        let draw = std::collections::hash_map::RandomState::new().hash_one(std::process::id());
        (draw >> 12) as f64 + 1.0
    })
}

/// The length of the state of a sensor configured as `config` in a model of `ngeom` geoms
/// (every geom a possible indenter): the header, the sensor's own and, with coupling, the
/// coupling's memory and the poses of the last evaluation.
fn state_len(config: &Config, ngeom: usize) -> usize {
    let sensor = TactileSensor::state_len(config, ngeom);
    let coupled = if config.coupling {
        Coupling::state_len(ngeom) + (1 + 8 * ngeom)
    } else {
        0
    };
    if sensor + coupled == 0 {
        // Nothing of the next frame depends on the last (rigid physics, uncoupled).
        0
    } else {
        STATE_HEADER + sensor + coupled
    }
}

impl Instance {
    /// `warnings` as one message, unless this sensor has warned
    /// [`MAX_REPEATED_WARNINGS`] times already.
    fn limit(&mut self, mut warnings: Vec<String>) -> Option<String> {
        if warnings.is_empty() || self.warnings_given >= MAX_REPEATED_WARNINGS {
            return None;
        }
        self.warnings_given += 1;
        if self.warnings_given == MAX_REPEATED_WARNINGS {
            warnings.push("further warnings of this sensor are suppressed".into());
        }
        Some(warnings.join("; "))
    }

    /// A copy with the same gel state, for `mj_copyData`.
    fn try_clone(&self) -> Result<Self, String> {
        Ok(Self {
            sensor_id: self.sensor_id,
            scene: self.scene.clone(),
            sensor: self.sensor.try_clone().map_err(|e| e.to_string())?,
            placed: self.placed.clone(),
            geoms: self.geoms.clone(),
            warnings_given: self.warnings_given,
            touching: self.touching,
            coupling: self.coupling.clone(),
            scratch: Vec::new(),
            shapes: self.shapes.clone(),
            stamp: self.stamp,
            extent: self.extent,
            damping_checked: self.damping_checked.clone(),
        })
    }

    /// Evaluates the sensor for `placed` (the poses of `geoms`) outside its own stage (the
    /// passive stage, where none ran at this state), into the scratch buffer, and keeps
    /// them as the last evaluation's; returns its warnings.
    fn evaluate_here(&mut self, placed: Vec<Placed>, geoms: Vec<usize>) -> Vec<String> {
        let dim = self.sensor.config().sensordata_len();
        self.scratch.resize(dim, 0.0);
        let eval = self.sensor.evaluate(&placed, &mut self.scratch);
        self.touching = eval.contact;
        self.placed = placed;
        self.geoms = geoms;
        eval.warnings
    }

    /// Back to the undeformed gel and a coupling without memory, as `mj_resetData` leaves
    /// the sensor (its warnings keep their count).
    fn fresh(&mut self) {
        self.sensor.reset();
        self.touching = false;
        self.coupling = Coupling::default();
        self.placed.clear();
        self.geoms.clear();
    }

    /// Writes or reads what the next evaluation depends on ([`crate::state`]): the
    /// sensor's state, the coupling's memory and the geoms and poses of the last
    /// evaluation (which the passive stage compares its own with); geoms below `ngeom`.
    fn persist(&mut self, io: &mut Io<'_>, ngeom: usize) -> bool {
        let kept = self.sensor.persist(io, &self.shapes);
        if !self.sensor.config().coupling {
            return kept;
        }
        self.coupling.persist(io, ngeom);
        let mut evaluated: Vec<(usize, Isometry3<f64>)> = self
            .geoms
            .iter()
            .zip(&self.placed)
            .map(|(&g, p)| (g, p.pose))
            .collect();
        let n = io.len(evaluated.len(), ngeom, "the evaluated geoms");
        if io.loading() {
            evaluated.resize(n, (0, Isometry3::identity()));
        }
        for (geom, pose) in &mut evaluated {
            io.count(geom, ngeom, "an evaluated geom");
            pose.persist(io);
        }
        if io.loading() && io.fault().is_none() {
            self.geoms.clear();
            self.placed.clear();
            for (geom, pose) in evaluated {
                let Some(shape) = self.scene.shape_of(geom) else {
                    io.fail(|| format!("geom {geom} cannot press this sensor"));
                    break;
                };
                self.geoms.push(geom);
                self.placed.push(Placed { shape, pose });
            }
        }
        kept
    }

    /// Takes the state in `plugin_state` where it is not the one this instance last wrote
    /// or took (`mj_setState` put another there, or `mj_resetData` cleared it); a state
    /// that cannot be taken leaves the gel undeformed, with the warning returned.
    fn sync(&mut self, state: &[f64], ngeom: usize) -> Option<String> {
        if state.len() < STATE_HEADER || state[..2] == self.stamp {
            return None;
        }
        self.fresh();
        self.stamp = [state[0], state[1]];
        self.extent = state.len() - STATE_HEADER;
        if self.stamp == [0.0; 2] {
            return None;
        }
        let name = self.sensor.config().name.clone();
        if state[2] != 1.0 {
            return Some(format!(
                "tacrom.tactile sensor '{name}': the restored state does not hold the whole \
                 gel (it did not fit in plugin_state when it was written); the gel restarts \
                 undeformed"
            ));
        }
        let mut io = Io::load(&state[STATE_HEADER..]);
        self.persist(&mut io, ngeom);
        let fault = io.fault()?.to_owned();
        self.fresh();
        Some(format!(
            "tacrom.tactile sensor '{name}': the state in plugin_state cannot be restored              ({fault}); the gel restarts undeformed"
        ))
    }

    /// Writes this instance's state into `plugin_state`, signed anew; a warning where it
    /// does not fit (then the header says the state is not whole).
    fn store(&mut self, state: &mut [f64], ngeom: usize) -> Option<String> {
        if state.len() < STATE_HEADER {
            return None;
        }
        let (head, body) = state.split_at_mut(STATE_HEADER);
        let declared = body.len();
        let mut io = Io::save(body);
        let mut kept = self.persist(&mut io, ngeom);
        let mut warning = None;
        if io.overflowed() {
            kept = false;
            warning = Some(format!(
                "tacrom.tactile sensor '{}': its state needs {} numbers and declares {declared};                  mj_getState does not hold it",
                self.sensor.config().name,
                io.position(),
            ));
        }
        // Zeros past the end of this state, where the last one reached further: equal
        // histories give equal states.
        let end = io.position().min(declared);
        body[end..self.extent.clamp(end, declared)].fill(0.0);
        self.extent = end;
        let serial = STATE_WRITES.fetch_add(1, Ordering::Relaxed) + 1;
        self.stamp = [process_mark(), serial as f64];
        head.copy_from_slice(&[self.stamp[0], self.stamp[1], f64::from(u8::from(kept))]);
        warning
    }
}

/// This instance's part of `d`'s `plugin_state` (empty where it has none).
///
/// # Safety
/// `d` must be a valid `mjData` of `m`; nothing else may hold a reference into its
/// `plugin_state` while the slice lives.
unsafe fn plugin_state<'a>(m: Model<'_>, d: *mut sys::mjData, instance: c_int) -> &'a mut [f64] {
    let range = usize::try_from(instance).ok().and_then(|i| {
        let adr = usize::try_from(*m.plugin_stateadr().get(i)?).ok()?;
        let num = usize::try_from(*m.plugin_statenum().get(i)?).ok()?;
        (adr + num <= m.npluginstate()).then_some((adr, num))
    });
    // SAFETY: valid data per the caller.
    let base = unsafe { d.as_ref() }.map_or(std::ptr::null_mut(), |d| d.plugin_state);
    match range {
        Some((adr, num)) if !base.is_null() && num > 0 => {
            // SAFETY: plugin_state holds npluginstate numbers; [adr, adr + num) lies in it.
            unsafe { std::slice::from_raw_parts_mut(base.add(adr), num) }
        }
        _ => &mut [],
    }
}

/// Runs `f` at the FFI edge: its `Err` and any panic become `ERROR` with a message in
/// `msg`; a warning becomes `WARN`. Every exported callback that reports a status goes
/// through it; those without a status go through [`guarded`].
fn edge(msg: *mut c_char, len: c_int, f: impl FnOnce() -> Result<Option<String>, String>) -> c_int {
    let outcome = catch_unwind(AssertUnwindSafe(f))
        .unwrap_or_else(|panic| Err(format!("tacrom.tactile: internal error: {}", what(&*panic))));
    match outcome {
        Ok(None) => OK,
        Ok(Some(warning)) => {
            write_msg(msg, len, &warning);
            WARN
        }
        Err(error) => {
            write_msg(msg, len, &error);
            ERROR
        }
    }
}

/// Runs a callback that cannot report failure: a panic is caught and gives `fallback`, so
/// nothing unwinds into C.
fn guarded<T>(fallback: T, f: impl FnOnce() -> T) -> T {
    catch_unwind(AssertUnwindSafe(f)).unwrap_or(fallback)
}

/// The message of a caught panic.
fn what(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}

fn write_msg(msg: *mut c_char, len: c_int, text: &str) {
    let Ok(len) = usize::try_from(len) else {
        return;
    };
    if msg.is_null() || len == 0 {
        return;
    }
    // Keep it a valid C string: no interior NULs, cut to the buffer.
    let bytes: Vec<u8> = text.bytes().filter(|&b| b != 0).take(len - 1).collect();
    // SAFETY: the shim passes a buffer of `len` bytes; we write at most len - 1 plus NUL.
    unsafe {
        std::ptr::copy_nonoverlapping(bytes.as_ptr(), msg as *mut u8, bytes.len());
        *msg.add(bytes.len()) = 0;
    }
}

/// Parses and validates the configuration of plugin `instance`, serving `sensor_id`,
/// reading the files it names.
fn config_of(m: Model<'_>, instance: c_int, sensor_id: usize) -> Result<Config, String> {
    config_with(m, instance, sensor_id, Config::from_raw)
}

/// The configuration of plugin `instance` through `parse` ([`Config::from_raw`], or
/// [`Config::without_files`] where only the sensordata's size is wanted).
fn config_with(
    m: Model<'_>,
    instance: c_int,
    sensor_id: usize,
    parse: fn(&str, &RawConfig) -> Result<Config, crate::config::ConfigError>,
) -> Result<Config, String> {
    let name = m.sensor_name(sensor_id);
    let name = if name.is_empty() {
        format!("#{sensor_id}")
    } else {
        name.to_owned()
    };
    let raw = RawConfig::collect(|a| m.plugin_config(instance, a));
    parse(&name, &raw).map_err(|e| e.to_string())
}

/// The site the sensor is attached to, validated.
fn site_of(m: Model<'_>, sensor_id: usize, config: &Config) -> Result<usize, String> {
    let objtype = m.sensor_objtype()[sensor_id];
    let objid = m.sensor_objid()[sensor_id];
    let nsite = m.site_bodyid().len();
    if objtype as u32 != sys::mjOBJ_SITE || objid < 0 || objid as usize >= nsite {
        return Err(format!(
            "tacrom.tactile sensor '{}': must be attached to a site (objtype=\"site\" \
             objname=\"...\")",
            config.name
        ));
    }
    Ok(objid as usize)
}

/// The attribute table, built once from [`ATTRIBUTES`].
///
/// # Safety
/// Called by MuJoCo (through the C shim) with valid pointers for this plugin instance.
#[no_mangle]
pub unsafe extern "C" fn tacrom_attributes(count: *mut c_int) -> *const *const c_char {
    /// Owns the names (field 0) that the pointers (field 1) point into.
    struct Table(#[allow(dead_code)] Vec<CString>, Vec<*const c_char>);
    // SAFETY: the table is immutable after construction; the pointers point into the
    // CStrings it owns, which live for the whole process.
    unsafe impl Send for Table {}
    // SAFETY: as above, read-only after construction.
    unsafe impl Sync for Table {}
    static TABLE: OnceLock<Table> = OnceLock::new();
    guarded(std::ptr::null(), || {
        let table = TABLE.get_or_init(|| {
            let names: Vec<CString> = ATTRIBUTES
                .iter()
                .map(|a| CString::new(*a).expect("attribute names have no NUL"))
                .collect();
            let ptrs = names.iter().map(|c| c.as_ptr()).collect();
            Table(names, ptrs)
        });
        if !count.is_null() {
            // SAFETY: the shim passes a valid int pointer.
            unsafe { *count = table.1.len() as c_int };
        }
        table.1.as_ptr()
    })
}

/// The length of the sensor's state in `plugin_state` ([`state_len`]); 0 for a
/// configuration that does not parse (`nsensordata` reports why).
///
/// # Safety
/// Called by MuJoCo (through the C shim) with valid pointers for this plugin instance.
#[no_mangle]
pub unsafe extern "C" fn tacrom_nstate(m: *const sys::mjModel, instance: c_int) -> c_int {
    guarded(0, || {
        // SAFETY: MuJoCo passes a valid model (or null).
        let Some(m) = (unsafe { m.as_ref() }).map(Model) else {
            return 0;
        };
        let len = m.sensor_of_instance(instance).and_then(|sensor_id| {
            let config = config_with(m, instance, sensor_id, Config::without_files).ok()?;
            c_int::try_from(state_len(&config, m.ngeom())).ok()
        });
        len.unwrap_or(0)
    })
}

/// The sensor's dimension; called at compile time, before `init`, so it validates the
/// whole configuration itself.
///
/// # Safety
/// Called by MuJoCo (through the C shim) with valid pointers for this plugin instance.
#[no_mangle]
pub unsafe extern "C" fn tacrom_nsensordata(
    m: *const sys::mjModel,
    instance: c_int,
    sensor_id: c_int,
    msg: *mut c_char,
    len: c_int,
) -> c_int {
    let mut n = 0;
    let status = edge(msg, len, || {
        // SAFETY: MuJoCo passes a valid model.
        let m = Model(unsafe { m.as_ref() }.ok_or("null model")?);
        let sensor_id = usize::try_from(sensor_id).map_err(|_| "bad sensor id")?;
        // The files the configuration names are read once, by `init`.
        let config = config_with(m, instance, sensor_id, Config::without_files)?;
        n = c_int::try_from(config.sensordata_len()).map_err(|_| "sensordata too large")?;
        Ok(None)
    });
    if status == ERROR {
        ERROR
    } else {
        n
    }
}

/// Builds the instance's state for a new `mjData`.
///
/// # Safety
/// Called by MuJoCo (through the C shim) with valid pointers for this plugin instance.
#[no_mangle]
pub unsafe extern "C" fn tacrom_init(
    m: *const sys::mjModel,
    d: *mut sys::mjData,
    instance: c_int,
    msg: *mut c_char,
    len: c_int,
) -> c_int {
    edge(msg, len, || {
        // SAFETY: MuJoCo passes valid model and data.
        let (mr, dr) = unsafe {
            (
                m.as_ref().ok_or("null model")?,
                d.as_mut().ok_or("null data")?,
            )
        };
        let m = Model(mr);
        let sensor_id = m
            .sensor_of_instance(instance)
            .ok_or_else(|| format!("tacrom.tactile: plugin instance {instance} has no sensor"))?;
        let config = config_of(m, instance, sensor_id)?;
        let site = site_of(m, sensor_id, &config)?;
        let (scene, warnings) = SceneSpec::build(m, site, &config)?;
        let sensor = TactileSensor::new(config).map_err(|e| e.to_string())?;
        let shapes = scene.shapes();
        let state = Box::new(Instance {
            sensor_id,
            scene,
            sensor,
            placed: Vec::new(),
            geoms: Vec::new(),
            warnings_given: 0,
            touching: false,
            coupling: Coupling::default(),
            scratch: Vec::new(),
            shapes,
            stamp: [0.0; 2],
            // Until `mj_resetData` clears it, plugin_state holds what the allocator left.
            extent: usize::MAX,
            damping_checked: (0.0, Vec::new()),
        });
        let slot = plugin_slot(dr, instance)?;
        *slot = Box::into_raw(state) as usize;
        Ok((!warnings.is_empty()).then(|| warnings.join("; ")))
    })
}

fn plugin_slot(d: &mut sys::mjData, instance: c_int) -> Result<&mut usize, String> {
    let i = usize::try_from(instance).map_err(|_| "bad plugin instance")?;
    let n = usize::try_from(d.nplugin).unwrap_or(0);
    if d.plugin_data.is_null() || i >= n {
        return Err(format!(
            "tacrom.tactile: plugin instance {instance} out of range"
        ));
    }
    // SAFETY: plugin_data has nplugin entries, i < nplugin.
    Ok(unsafe { &mut *d.plugin_data.add(i) })
}

/// The instance behind `plugin_data[instance]`, if any.
///
/// # Safety
/// `d` must be a valid mjData whose slot holds null or a pointer made by `tacrom_init`.
unsafe fn instance_mut<'a>(d: *mut sys::mjData, instance: c_int) -> Option<&'a mut Instance> {
    // SAFETY: valid data per the caller.
    let d = unsafe { d.as_mut()? };
    let slot = plugin_slot(d, instance).ok()?;
    // SAFETY: the slot holds null or a live Box<Instance> from tacrom_init.
    unsafe { (*slot as *mut Instance).as_mut() }
}

/// Frees the instance's state.
///
/// # Safety
/// Called by MuJoCo (through the C shim) with valid pointers for this plugin instance.
#[no_mangle]
pub unsafe extern "C" fn tacrom_destroy(d: *mut sys::mjData, instance: c_int) {
    guarded((), || {
        // SAFETY: MuJoCo passes valid data.
        let Some(d) = (unsafe { d.as_mut() }) else {
            return;
        };
        if let Ok(slot) = plugin_slot(d, instance) {
            let ptr = std::mem::replace(slot, 0) as *mut Instance;
            if !ptr.is_null() {
                // SAFETY: made by Box::into_raw in tacrom_init or tacrom_copy; the slot is
                // cleared so it cannot be freed twice.
                drop(unsafe { Box::from_raw(ptr) });
            }
        }
    });
}

/// Copies the source's state into the destination (for `mj_copyData`).
///
/// # Safety
/// Called by MuJoCo (through the C shim) with valid pointers for this plugin instance.
#[no_mangle]
pub unsafe extern "C" fn tacrom_copy(
    dest: *mut sys::mjData,
    _m: *const sys::mjModel,
    src: *const sys::mjData,
    instance: c_int,
    msg: *mut c_char,
    len: c_int,
) -> c_int {
    edge(msg, len, || {
        // SAFETY: MuJoCo passes valid data; the source is only read.
        let Some(source) = (unsafe { instance_mut(src as *mut sys::mjData, instance) }) else {
            return Ok(None);
        };
        let copy = Box::new(source.try_clone()?);
        // SAFETY: valid destination data.
        let d = unsafe { dest.as_mut() }.ok_or("null data")?;
        let slot = plugin_slot(d, instance)?;
        let old = std::mem::replace(slot, Box::into_raw(copy) as usize) as *mut Instance;
        if !old.is_null() && !std::ptr::eq(old, source) {
            // SAFETY: the destination's previous state, made by Box::into_raw.
            drop(unsafe { Box::from_raw(old) });
        }
        Ok(None)
    })
}

/// Restores the undeformed gel, and marks the state in `plugin_state` as a fresh gel's.
///
/// # Safety
/// Called by MuJoCo (through the C shim) with valid pointers for this plugin instance.
#[no_mangle]
pub unsafe extern "C" fn tacrom_reset(
    m: *const sys::mjModel,
    plugin_state: *mut f64,
    plugin_data: *mut c_void,
    instance: c_int,
) {
    guarded((), || {
        // SAFETY: MuJoCo passes a valid model (or null).
        let declared = unsafe { m.as_ref() }.map_or(0, |m| {
            let i = usize::try_from(instance).ok();
            let num = i.and_then(|i| Model(m).plugin_statenum().get(i).copied());
            num.and_then(|n| usize::try_from(n).ok()).unwrap_or(0)
        });
        if declared >= STATE_HEADER && !plugin_state.is_null() {
            // SAFETY: MuJoCo passes this instance's part of plugin_state, `declared` long.
            let state = unsafe { std::slice::from_raw_parts_mut(plugin_state, declared) };
            // MuJoCo leaves plugin_state as the allocator gave it: the fresh gel's state
            // is zeros, its header saying so.
            state.fill(0.0);
            state[..STATE_HEADER].copy_from_slice(&[0.0, 0.0, 1.0]);
        }
        // SAFETY: `plugin_data` is this instance's pointer from tacrom_init (or null).
        if let Some(inst) = unsafe { (plugin_data as *mut Instance).as_mut() } {
            inst.fresh();
            inst.warnings_given = 0;
            inst.stamp = [0.0; 2];
            inst.extent = 0;
        }
    });
}

/// Evaluates the sensor and writes its sensordata. Failures write zeros and warn.
///
/// # Safety
/// Called by MuJoCo (through the C shim) with valid pointers for this plugin instance.
#[no_mangle]
pub unsafe extern "C" fn tacrom_compute(
    m: *const sys::mjModel,
    d: *mut sys::mjData,
    instance: c_int,
    msg: *mut c_char,
    len: c_int,
) -> c_int {
    let mut out_ptr: Option<(*mut f64, usize)> = None;
    let status = edge(msg, len, || {
        // SAFETY: MuJoCo passes valid model and data.
        let m = Model(unsafe { m.as_ref() }.ok_or("null model")?);
        // SAFETY: valid data; the instance was made by tacrom_init.
        let inst = unsafe { instance_mut(d, instance) }.ok_or("tacrom.tactile: no state")?;
        // Set again once the evaluation ran: a failed one leaves nothing to draw.
        inst.touching = false;
        // SAFETY: valid data, read-only view for the poses.
        let data = Data(unsafe { &*d });
        let adr = m.sensor_adr()[inst.sensor_id] as usize;
        let dim = inst.sensor.config().sensordata_len();
        if adr + dim > m.nsensordata() {
            return Err("tacrom.tactile: sensordata out of range".into());
        }
        // SAFETY: sensordata has nsensordata entries; [adr, adr + dim) is this sensor's.
        let out = unsafe { std::slice::from_raw_parts_mut(data.0.sensordata.add(adr), dim) };
        out_ptr = Some((out.as_mut_ptr(), dim));

        // SAFETY: valid data of this model; no other reference into plugin_state lives.
        let state = unsafe { plugin_state(m, d, instance) };
        let restored = inst.sync(state, m.ngeom());
        let issues = inst
            .scene
            .gather(m, data, &mut inst.placed, &mut inst.geoms);
        let eval = if issues.nonfinite_site {
            out.fill(0.0);
            None
        } else {
            Some(inst.sensor.evaluate(&inst.placed, out))
        };
        // Kept after an evaluation that may have changed the gel; with coupling, after
        // every one (the passive stage compares its poses with the ones just gathered).
        let coupled = inst.sensor.config().coupling;
        let stored = eval
            .as_ref()
            .filter(|e| e.changed || coupled)
            .and_then(|_| inst.store(state, m.ngeom()));
        // Never hand non-finite numbers to MuJoCo.
        if !out.iter().all(|x| x.is_finite()) {
            out.fill(0.0);
        }
        inst.touching = eval.as_ref().is_some_and(|e| e.contact);
        let mut warnings = describe(&issues, inst.sensor.config());
        warnings.extend(restored);
        if let Some(e) = eval {
            warnings.extend(e.warnings);
        }
        warnings.extend(stored);
        Ok(inst.limit(warnings))
    });
    if status == ERROR {
        if let Some((ptr, dim)) = out_ptr {
            // SAFETY: the same sensordata range as above.
            unsafe { std::slice::from_raw_parts_mut(ptr, dim) }.fill(0.0);
        }
    }
    status
}

/// The implicit coupling (`gel_geom`), in MuJoCo's passive stage: the gel's push-back on
/// each indenter that MuJoCo's collision finds pressing the gel's geom, carried by those
/// contacts' constraint rows ([`gel_contacts`]). The force follows the last solve along
/// the indenter's motion since ([`linearise`]); the gel is solved again where no sensor
/// evaluation solved it at this state and an indenter moved further than
/// [`needs_solve`] allows, or presses the gel's geom without a force from the last solve.
/// The rows act where the gel presses: where MuJoCo's contact points do not surround the
/// gel's centre of pressure, they are moved along the gel's face so that their centre is
/// it ([`gel_contacts::shift_rows`]); only a twist that points without spread cannot carry
/// goes into `qfrc_passive` as a couple ([`gel_contacts::Couple`]). Also returns whether the coupling's state changed (a new
/// base, a solve).
///
/// # Safety
/// `m` and `d` must be a valid model and data of this instance after MuJoCo's position
/// stage; nothing else may hold a reference into `d`.
#[allow(clippy::too_many_arguments)]
unsafe fn implicit(
    inst: &mut Instance,
    m: &sys::mjModel,
    d: *mut sys::mjData,
    gel: usize,
    placed: Vec<Placed>,
    geoms: Vec<usize>,
    evaluated: bool,
    site: &Isometry3<f64>,
) -> (Vec<String>, bool) {
    let mut warnings = Vec::new();
    let config = inst.sensor.config();
    let (name, poisson, friction, tau) = (
        config.name.clone(),
        config.poisson,
        config.friction,
        config.damping,
    );
    if m.opt.solver == sys::mjSOL_PGS as i32 {
        warnings.push(format!(
            "tacrom.tactile sensor '{name}': attribute 'gel_geom': the implicit coupling needs \
             MuJoCo's Newton or CG solver (the model uses PGS); the gel's geom acts as a rigid \
             contact"
        ));
        return (warnings, false);
    }
    if m.opt.integrator == sys::mjINT_DISCRETE as i32 {
        // The discrete integrator makes the rows' reference and regulariser itself after
        // this stage, from the contact's solref and solimp, and keeps the position written
        // below: the offset that carries the gel's force becomes a penetration of MuJoCo's
        // own spring (a ball resting on the gel was thrown 4 m up within 0.6 s).
        warnings.push(format!(
            "tacrom.tactile sensor '{name}': attribute 'gel_geom': the implicit coupling does \
             not support MuJoCo's discrete integrator (it remakes the contact rows from the \
             contact's own solref and solimp, and the gel's force written into them threw \
             the bodies off); the gel's geom acts as a rigid contact: use the Euler, \
             implicitfast, implicit or RK4 integrator"
        ));
        return (warnings, false);
    }
    let normal = site.rotation * Vector3::z();
    // SAFETY: valid data per the caller.
    let contacts = unsafe {
        gel_contacts::gel_contacts(&*d, gel, &normal, |g| inst.scene.shape_of(g).is_some())
    };
    // The joints that carry the sensor's body and each body newly pressing the gel's geom:
    // one damped past its inertia within a step moves by a fraction of what MuJoCo's solve
    // (and the gel's rows) meant.
    if inst.damping_checked.0 != m.opt.timestep {
        inst.damping_checked = (m.opt.timestep, Vec::new());
    }
    let model = Model(m);
    let sensor_body = model.site_bodyid().get(inst.scene.site()).copied();
    // Vec::new allocates nothing: a step whose bodies were all checked costs the lookups.
    let mut fresh: Vec<usize> = Vec::new();
    let pressing = contacts
        .iter()
        .filter_map(|c| model.geom_bodyid().get(c.geom).copied());
    for b in sensor_body.into_iter().chain(pressing) {
        let Ok(b) = usize::try_from(b) else { continue };
        if !inst.damping_checked.1.contains(&b) && !fresh.contains(&b) {
            fresh.push(b);
        }
    }
    if !fresh.is_empty() {
        inst.damping_checked.1.extend(&fresh);
        // SAFETY: valid model and data past the position stage, per the caller.
        if let Some(w) = unsafe { gel_contacts::damping_taken_after_the_solve(m, d, &fresh) } {
            warnings.push(format!(
                "tacrom.tactile sensor '{name}': attribute 'gel_geom': joint '{}' is damped \
                 {:.1} times its inertia over the {:.1} ms physics step (damping {:.3}, \
                 inertia {:.4} along it); MuJoCo's integrator takes that damping after its \
                 constraint solve, which the gel's push-back is made for, and a held object \
                 can bounce between gels: give the joint armature (its drive's inertia) or \
                 take a shorter timestep (docs/rl.md, \"A long physics step: the fingers' \
                 damping, taken after the solve\")",
                w.joint,
                w.ratio,
                m.opt.timestep * 1e3,
                w.damping,
                w.inertia
            ));
        }
    }
    let deepest = |geom: usize| {
        contacts
            .iter()
            .filter(|c| c.geom == geom)
            .map(|c| c.depth)
            .fold(0.0, f64::max)
    };
    // Each indenter's motion since the solve its push-back follows: that of its centre of
    // pressure then.
    let now = |geom: usize| {
        geoms
            .iter()
            .position(|&g| g == geom)
            .map(|k| placed[k].pose)
    };
    let motion = |base: &Base| -> Option<Vector3<f64>> {
        let c: Point3<f64> = Point3::from(centre_of_pressure(&base.wrench)?);
        let pose: Isometry3<f64> = now(base.geom)?;
        let then: Point3<f64> = base.pose.inverse_transform_point(&c);
        Some(pose.transform_point(&then) - c)
    };
    let base_of = |inst: &Instance, geom: usize| -> Option<Base> {
        inst.coupling.base.iter().find(|b| b.geom == geom).copied()
    };
    let stale = contacts
        .iter()
        .any(|c| match base_of(inst, c.geom).as_ref().and_then(&motion) {
            None => c.depth > SHALLOWEST,
            Some(moved) => needs_solve(moved.norm(), deepest(c.geom) + moved.z),
        });
    // A new base for every geom where an indenter moved too far (this state's evaluation
    // where the sensor stage ran one, else one here), or where the sensor stage solved
    // this state (for its images). Each keeps the normal and tangential stiffness measured
    // between its last two solves ([`secant`], [`tangential_secant`]).
    let solved_here = evaluated && inst.sensor.solved_at(&inst.placed);
    let changed = stale || solved_here;
    if changed {
        if !evaluated {
            warnings.extend(inst.evaluate_here(placed.clone(), geoms.clone()));
        }
        let (wrenches, spreads) = inst.sensor.wrenches_and_spreads(&inst.placed);
        let mut bases = Vec::with_capacity(inst.geoms.len());
        for (((&geom, p), wrench), spread) in inst
            .geoms
            .iter()
            .zip(&inst.placed)
            .zip(wrenches)
            .zip(spreads)
        {
            let before = base_of(inst, geom);
            let moved = before.as_ref().and_then(&motion);
            let normal = before
                .and_then(|b| secant(&b.wrench, &wrench, moved?.z, deepest(geom)).or(b.normal));
            let tangential = before.and_then(|b| {
                tangential_secant(&b.wrench, &wrench, moved?, friction).or(b.tangential)
            });
            bases.push(Base {
                geom,
                pose: p.pose,
                wrench,
                normal,
                tangential,
                spread,
            });
        }
        inst.coupling.base = bases;
    }
    let push = |geom: usize| {
        let base = base_of(inst, geom)?;
        let moved = motion(&base)?;
        Some(Linearised {
            turned: now(geom)?.rotation * base.pose.rotation.inverse(),
            spread: base.spread,
            ..linearise(
                &base.wrench,
                moved,
                deepest(geom),
                base.normal,
                base.tangential,
                poisson,
                friction,
            )
        })
    };
    // SAFETY: valid model and data per the caller; `contacts` are this data's.
    let couples = unsafe { gel_contacts::write_rows(m, d, &contacts, site, tau, friction, push) };
    let model = Model(m);
    let bodies = model.geom_bodyid();
    let sensor_body = model.site_bodyid()[inst.scene.site()];
    for c in couples {
        let zero = Vector3::zeros();
        // SAFETY: valid model and data per the caller; both bodies are ids of this model.
        unsafe {
            apply_between(
                m,
                d,
                &zero,
                &c.torque,
                &site.translation.vector,
                bodies[c.geom],
                sensor_body,
            )
        };
    }
    (warnings, changed)
}

/// Applies `force` and `torque` (world; the force at `point`) to `body` and their
/// opposites to `sensor_body`, into `qfrc_passive`; nothing where a number is not finite.
///
/// # Safety
/// `m` and `d` must be a valid model and data; both bodies ids of `m`.
unsafe fn apply_between(
    m: &sys::mjModel,
    d: *mut sys::mjData,
    force: &Vector3<f64>,
    torque: &Vector3<f64>,
    point: &Vector3<f64>,
    body: i32,
    sensor_body: i32,
) {
    if !(force.iter().chain(torque.iter()).all(|v| v.is_finite())) {
        return;
    }
    let (nf, nt) = (-force, -torque);
    // SAFETY: valid model and data per the caller; the vectors hold three numbers each;
    // qfrc_passive has nv entries.
    unsafe {
        let qfrc = (*d).qfrc_passive;
        sys::mj_applyFT(
            m,
            d,
            force.as_ptr(),
            torque.as_ptr(),
            point.as_ptr(),
            body,
            qfrc,
        );
        sys::mj_applyFT(
            m,
            d,
            nf.as_ptr(),
            nt.as_ptr(),
            point.as_ptr(),
            sensor_body,
            qfrc,
        );
    }
}

/// The coupling (`coupling="on"`), called in MuJoCo's passive-force stage: applies the
/// gel's contact force and torque on each geom pressing it, plus its Kelvin-Voigt damping
/// (`damping` times the wrench's rate of change between evaluations), to the geom's body,
/// and the opposite to the sensor's body, into `qfrc_passive`. The wrenches come from the
/// solve of this state's sensor evaluation, which runs earlier in the same `mj_forward`;
/// where none ran (sensors disabled, or a Runge-Kutta stage that skips them) it solves
/// here. Without coupling it returns at once.
///
/// # Safety
/// Called by MuJoCo (through the C shim) with valid pointers for this plugin instance.
#[no_mangle]
pub unsafe extern "C" fn tacrom_passive(
    m: *const sys::mjModel,
    d: *mut sys::mjData,
    instance: c_int,
    msg: *mut c_char,
    len: c_int,
) -> c_int {
    edge(msg, len, || {
        // SAFETY: MuJoCo passes valid model and data.
        let mr = unsafe { m.as_ref() }.ok_or("null model")?;
        let m = Model(mr);
        // SAFETY: valid data; the instance was made by tacrom_init.
        let inst = unsafe { instance_mut(d, instance) }.ok_or("tacrom.tactile: no state")?;
        if !inst.sensor.config().coupling {
            return Ok(None);
        }
        // SAFETY: valid data, a read-only view for the time and the poses; its last use is
        // before mj_applyFT writes through `d` below.
        let data = Data(unsafe { &*d });
        let time = data.0.time;
        // SAFETY: valid data of this model; no other reference into plugin_state lives.
        let state = unsafe { plugin_state(m, d, instance) };
        let mut warnings: Vec<String> = inst.sync(state, m.ngeom()).into_iter().collect();
        let mut placed = Vec::new();
        let mut geoms = Vec::new();
        let issues = inst.scene.gather(m, data, &mut placed, &mut geoms);
        let s = inst.scene.site();
        let site = pose(
            data.site_xpos(&m).get(3 * s..3 * s + 3).unwrap_or(&[]),
            data.site_xmat(&m).get(9 * s..9 * s + 9).unwrap_or(&[]),
        );
        let Some(site) = site.filter(|_| !issues.nonfinite_site) else {
            return Ok(inst.limit(warnings));
        };
        let evaluated = geoms == inst.geoms
            && placed
                .iter()
                .zip(&inst.placed)
                .all(|(a, b)| Arc::ptr_eq(&a.shape, &b.shape) && a.pose == b.pose);
        if let Some(gel) = inst.scene.gel_geom() {
            // SAFETY: valid model and data, past the position stage; `data` is not used
            // after this.
            let (said, changed) =
                unsafe { implicit(inst, mr, d, gel, placed, geoms, evaluated, &site) };
            warnings.extend(said);
            // Between solves nothing of the state changes: `plugin_state` holds it already.
            if changed {
                warnings.extend(inst.store(state, m.ngeom()));
            }
            return Ok(inst.limit(warnings));
        }
        if !evaluated {
            warnings.extend(inst.evaluate_here(placed, geoms));
        }
        let wrenches = inst.sensor.wrenches(&inst.placed);
        let samples: Vec<Sample> = inst
            .geoms
            .iter()
            .zip(&inst.placed)
            .zip(wrenches)
            .map(|((&geom, p), wrench)| Sample {
                geom,
                wrench,
                at: p.pose.translation.vector,
            })
            .collect();
        let bodies = m.geom_bodyid();
        let sensor_body = m.site_bodyid()[s];
        let mass = |b: i32| {
            let welded = m.body_weldid().get(b as usize).map_or(true, |&w| w == 0);
            let mass = m.body_mass().get(b as usize).copied();
            mass.filter(|_| !welded).unwrap_or(f64::INFINITY)
        };
        let reduced = |geom: usize| reduced_mass(mass(bodies[geom]), mass(sensor_body));
        let tau = inst.sensor.config().damping;
        let pushes = inst.coupling.push(time, samples, tau, reduced);
        let point = site.translation.vector;
        for push in pushes {
            let body = bodies[push.geom];
            if let Some(i) = push.unstable {
                warnings.push(format!(
                    "tacrom.tactile sensor '{}': the coupling may be unstable: the gel's \
                     stiffness on body '{}' is about {:.3e} N/m, and stiffness * \
                     timestep^2 / mass = {:.2} exceeds {STABLE_RATIO} (timestep \
                     {:.3e} s, mass {:.3e} kg); use a smaller timestep or a \
                     heavier body",
                    inst.sensor.config().name,
                    m.body_name(body as usize),
                    i.stiffness,
                    i.ratio,
                    i.step,
                    i.mass,
                ));
            }
            if push.wrench == Wrench::default() {
                continue;
            }
            let (f, t) = (
                site.rotation * push.wrench.force,
                site.rotation * push.wrench.torque,
            );
            // SAFETY: valid model and data; the bodies are ids of this model.
            unsafe { apply_between(mr, d, &f, &t, &point, body, sensor_body) };
        }
        warnings.extend(inst.store(state, m.ngeom()));
        Ok(inst.limit(warnings))
    })
}

/// Draws the sensor into MuJoCo's scene, as [`crate::visual`] lays it out: the deformed
/// gel surface (at most [`GEOM_BUDGET`] - 1 tiles) when the scene shows contact points or
/// contact forces, and the total force as an arrow at the contact centroid, scaled like
/// MuJoCo's own contact forces, when it shows contact forces. Nothing without contact in
/// the last evaluation, nothing beyond the scene's `maxgeom`.
///
/// # Safety
/// Called by MuJoCo (through the C shim) with valid pointers for this plugin instance.
#[no_mangle]
pub unsafe extern "C" fn tacrom_visualize(
    m: *const sys::mjModel,
    d: *mut sys::mjData,
    opt: *const sys::mjvOption,
    scn: *mut sys::mjvScene,
    instance: c_int,
) {
    guarded((), || {
        // SAFETY: MuJoCo passes a valid model, options and scene (or null).
        let (Some(mr), Some(opt), Some(scn)) =
            (unsafe { (m.as_ref(), opt.as_ref(), scn.as_mut()) })
        else {
            return;
        };
        let shown = |flag: sys::mjtVisFlag| opt.flags.get(flag as usize).is_some_and(|&v| v != 0);
        let arrow = shown(sys::mjVIS_CONTACTFORCE);
        if !(arrow || shown(sys::mjVIS_CONTACTPOINT)) {
            return;
        }
        // SAFETY: valid data; the instance was made by tacrom_init (or copied).
        let Some(inst) = (unsafe { instance_mut(d, instance) }) else {
            return;
        };
        if !inst.touching {
            return;
        }
        let m = Model(mr);
        // SAFETY: valid data, read-only view for the site's pose.
        let data = Data(unsafe { &*d });
        let s = inst.scene.site();
        let Some(site) = pose(
            data.site_xpos(&m).get(3 * s..3 * s + 3).unwrap_or(&[]),
            data.site_xmat(&m).get(9 * s..9 * s + 9).unwrap_or(&[]),
        ) else {
            return;
        };
        let sensor = &inst.sensor;
        let surface = Surface {
            depth: sensor.depth(),
            grid: sensor.grid(),
            thickness: sensor.config().size[2],
        };
        // MuJoCo's own contact forces: vis.map.force per unit of mean body mass, the
        // force width relative to the mean body size, the contact-force colour.
        let style = ArrowStyle {
            scale: f64::from(mr.vis.map.force) / mr.stat.meanmass,
            width: f64::from(mr.vis.scale.forcewidth) * mr.stat.meansize,
            rgba: mr.vis.rgba.contactforce,
        };
        let force = sensor.force();
        let mut geoms = Vec::with_capacity(GEOM_BUDGET);
        visual::sensor_geoms(
            &surface,
            &site,
            GEOM_BUDGET,
            arrow.then_some((&force, &style)),
            &mut geoms,
        );
        draw::add_to_scene(scn, &geoms, inst.sensor_id);
    });
}

fn describe(issues: &GatherIssues, config: &Config) -> Vec<String> {
    let mut w = Vec::new();
    if issues.nonfinite_site {
        w.push(format!(
            "tacrom.tactile sensor '{}': the sensor site's pose is not finite; output set to zero",
            config.name
        ));
    }
    if !issues.nonfinite_geoms.is_empty() {
        w.push(format!(
            "tacrom.tactile sensor '{}': geoms {:?} have non-finite poses and were ignored",
            config.name, issues.nonfinite_geoms
        ));
    }
    w
}

/// The sensordata layout of sensor `sensor_id`, for the Python package: a JSON object with
/// the image size and, per output in sensordata order, its name, offset, shape and unit
/// (from the output table, [`crate::sensor::outputs`]). Writes it NUL-terminated into
/// `buf` when it fits in `len` bytes; returns its length without the NUL (call again with
/// a larger buffer when that is `>= len`), or -1 with the reason in `buf` when the sensor
/// is not a valid tacrom sensor.
///
/// # Safety
/// `m` must be a live model (Python's `MjModel._address`) and `buf` hold `len` bytes.
#[no_mangle]
pub unsafe extern "C" fn tacrom_sensor_outputs(
    m: *const sys::mjModel,
    sensor_id: c_int,
    buf: *mut c_char,
    len: c_int,
) -> c_int {
    let mut size = 0;
    let status = edge(buf, len, || {
        // SAFETY: the caller passes a live model.
        let m = Model(unsafe { m.as_ref() }.ok_or("null model")?);
        let sid = usize::try_from(sensor_id).map_err(|_| "bad sensor id")?;
        let instance = *m
            .sensor_plugin()
            .get(sid)
            .ok_or_else(|| format!("no sensor {sensor_id}"))?;
        if instance < 0 {
            return Err(format!("sensor {sensor_id} is not a plugin sensor"));
        }
        // Another plugin's sensor would read as a tacrom sensor with every attribute at
        // its default (MuJoCo finds none of ours in its configuration).
        let plugin = m.plugin_name(instance).unwrap_or_default();
        if plugin != PLUGIN_NAME {
            return Err(format!(
                "sensor {sensor_id} is a '{plugin}' sensor, not {PLUGIN_NAME}"
            ));
        }
        let config = config_with(m, instance, sid, Config::without_files)?;
        let json = crate::config::layout_json(&config);
        size = c_int::try_from(json.len()).map_err(|_| "layout too large")?;
        if json.len() < usize::try_from(len).unwrap_or(0) {
            write_msg(buf, len, &json);
        }
        Ok(None)
    });
    if status == ERROR {
        ERROR
    } else {
        size
    }
}

/// The output table as JSON (see [`crate::sensor::outputs::table_json`]), written
/// NUL-terminated into `buf` when it fits in `len` bytes; returns its length without the
/// NUL (call again with a larger buffer when that is `>= len`).
///
/// # Safety
/// `buf` must hold `len` bytes.
#[no_mangle]
pub unsafe extern "C" fn tacrom_output_table(buf: *mut c_char, len: c_int) -> c_int {
    guarded(ERROR, || {
        json_into(buf, len, &crate::sensor::outputs::table_json())
    })
}

/// The attribute table as JSON (see [`crate::attributes::table_json`]), written as
/// [`tacrom_output_table`] writes the output table.
///
/// # Safety
/// `buf` must hold `len` bytes.
#[no_mangle]
pub unsafe extern "C" fn tacrom_attribute_table(buf: *mut c_char, len: c_int) -> c_int {
    guarded(ERROR, || {
        json_into(buf, len, &crate::attributes::table_json())
    })
}

/// The attributes of the sensor file that the `sensor` attribute's value `value` names
/// ([`crate::sensor_file`]), as a JSON object of MJCF text (paths relative to the working
/// directory) with the file's path under `"path"`, written as [`tacrom_output_table`]
/// writes the output table; on a missing or bad file, the reason, NUL-terminated, and -1.
///
/// # Safety
/// `value` must be a NUL-terminated string; `buf` must hold `len` bytes.
#[no_mangle]
pub unsafe extern "C" fn tacrom_sensor_file(
    value: *const c_char,
    buf: *mut c_char,
    len: c_int,
) -> c_int {
    guarded(ERROR, || {
        if value.is_null() {
            write_msg(buf, len, "no sensor file named");
            return ERROR;
        }
        // SAFETY: the caller passes a NUL-terminated string.
        let value = unsafe { std::ffi::CStr::from_ptr(value) }.to_string_lossy();
        match crate::sensor_file::SensorFile::read(&value) {
            Ok(file) => {
                let mut a: serde_json::Map<String, serde_json::Value> = file
                    .attributes
                    .into_iter()
                    .map(|(k, v)| (k, serde_json::Value::String(v)))
                    .collect();
                a.insert("path".into(), file.path.display().to_string().into());
                json_into(buf, len, &serde_json::Value::Object(a).to_string())
            }
            Err(e) => {
                write_msg(buf, len, &e);
                ERROR
            }
        }
    })
}

/// Writes `json` NUL-terminated into `buf` when it fits in `len` bytes; returns its
/// length without the NUL.
fn json_into(buf: *mut c_char, len: c_int, json: &str) -> c_int {
    if json.len() < usize::try_from(len).unwrap_or(0) {
        write_msg(buf, len, json);
    }
    c_int::try_from(json.len()).unwrap_or(ERROR)
}
