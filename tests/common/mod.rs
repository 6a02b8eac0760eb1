//! Shared helpers of the integration tests: the real libmujoco (linked through the rlib's
//! bindings) loading the real plugin library built by cargo next to the test binary.
#![allow(dead_code)]

use std::ffi::{CStr, CString};
use std::path::PathBuf;
use std::sync::Once;

use tacrom::mujoco::sys;

/// The cdylib built with this test binary: `target/<profile>/deps/libtacrom.so`, which
/// `cargo test` rebuilds from the current source. The copy in `target/<profile>/` is only
/// refreshed by `cargo build`, so after a `cargo test` alone it can be an older build.
pub fn plugin_path() -> PathBuf {
    let exe = std::env::current_exe().expect("test binary path");
    let deps = exe.parent().expect("target/<profile>/deps");
    let fresh = deps.join("libtacrom.so");
    if fresh.is_file() {
        return fresh;
    }
    deps.parent()
        .expect("target/<profile>")
        .join("libtacrom.so")
}

/// Registers the plugin with MuJoCo, once per process.
pub fn load_plugin() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let path = plugin_path();
        assert!(
            path.is_file(),
            "plugin library missing at {}",
            path.display()
        );
        let c = CString::new(path.to_str().unwrap()).unwrap();
        // SAFETY: a valid path; MuJoCo dlopens it and its constructor registers the plugin.
        unsafe { sys::mj_loadPluginLibrary(c.as_ptr()) };
    });
}

/// An owned mjModel.
pub struct Model(pub *mut sys::mjModel);
/// An owned mjData.
pub struct Data(pub *mut sys::mjData);

// SAFETY: MuJoCo models are immutable after compilation and may be shared across threads.
unsafe impl Send for Model {}
// SAFETY: as above.
unsafe impl Sync for Model {}
// SAFETY: an mjData is used by one thread at a time.
unsafe impl Send for Data {}

impl Drop for Model {
    fn drop(&mut self) {
        // SAFETY: owned pointer from mj_loadXML.
        unsafe { sys::mj_deleteModel(self.0) }
    }
}

impl Drop for Data {
    fn drop(&mut self) {
        // SAFETY: owned pointer from mj_makeData / mj_copyData.
        unsafe { sys::mj_deleteData(self.0) }
    }
}

/// Compiles an MJCF string; `Err` holds MuJoCo's message.
pub fn load_xml(xml: &str) -> Result<Model, String> {
    load_plugin();
    let dir = std::env::temp_dir().join(format!("tacrom-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    static COUNTER: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let path = dir.join(format!("model{n}.xml"));
    std::fs::write(&path, xml).unwrap();
    let cpath = CString::new(path.to_str().unwrap()).unwrap();
    let mut err = vec![0 as std::ffi::c_char; 2000];
    // SAFETY: valid path and error buffer.
    let m = unsafe { sys::mj_loadXML(cpath.as_ptr(), std::ptr::null(), err.as_mut_ptr(), 2000) };
    let _ = std::fs::remove_file(&path);
    if m.is_null() {
        // SAFETY: MuJoCo writes a NUL-terminated message.
        Err(unsafe { CStr::from_ptr(err.as_ptr()) }
            .to_string_lossy()
            .into_owned())
    } else {
        Ok(Model(m))
    }
}

impl Model {
    /// A new mjData.
    pub fn make_data(&self) -> Data {
        // SAFETY: valid model.
        Data(unsafe { sys::mj_makeData(self.0) })
    }

    /// The model struct.
    pub fn raw(&self) -> &sys::mjModel {
        // SAFETY: valid for self's lifetime.
        unsafe { &*self.0 }
    }
}

impl Data {
    /// Sets qpos[i].
    pub fn set_qpos(&mut self, i: usize, v: f64) {
        // SAFETY: the caller uses valid indices of this model's qpos.
        unsafe { *(*self.0).qpos.add(i) = v };
    }

    /// Runs mj_forward.
    pub fn forward(&mut self, m: &Model) {
        // SAFETY: valid model and data made from it.
        unsafe { sys::mj_forward(m.0, self.0) }
    }

    /// Resets to the model's defaults.
    pub fn reset(&mut self, m: &Model) {
        // SAFETY: valid model and data.
        unsafe { sys::mj_resetData(m.0, self.0) }
    }

    /// A copy made by mj_copyData.
    pub fn copy(&self, m: &Model) -> Data {
        let dest = m.make_data();
        // SAFETY: valid model, source and destination made from it.
        unsafe { sys::mj_copyData(dest.0, m.0, self.0) };
        dest
    }

    /// The sensordata of sensor `id`.
    pub fn sensor(&self, m: &Model, id: usize) -> Vec<f64> {
        let mr = m.raw();
        // SAFETY: sensor arrays sized nsensor; sensordata sized nsensordata.
        unsafe {
            let adr = *mr.sensor_adr.add(id) as usize;
            let dim = *mr.sensor_dim.add(id) as usize;
            std::slice::from_raw_parts((*self.0).sensordata.add(adr), dim).to_vec()
        }
    }
}

/// A fixed sensor at the world origin (site `gel`, top face at z = 0) and `indenter` XML
/// inside a body on a vertical slide joint (qpos[0] = press depth, positive down).
pub fn press_scene(config: &str, indenter_body: &str) -> String {
    format!(
        r#"<mujoco>
  <extension><plugin plugin="tacrom.tactile"/></extension>
  <option gravity="0 0 0"/>
  <asset>{assets}</asset>
  <worldbody>
    <body name="sensor">
      <geom name="pad" type="box" size="0.015 0.015 0.002" pos="0 0 -0.006"/>
      <site name="gel"/>
    </body>
    {indenter_body}
  </worldbody>
  <sensor>
    <plugin name="touch" plugin="tacrom.tactile" objtype="site" objname="gel">
      {config}
    </plugin>
  </sensor>
</mujoco>"#,
        assets = ""
    )
}

/// `<config key=.. value=../>` lines.
pub fn config(pairs: &[(&str, &str)]) -> String {
    pairs
        .iter()
        .map(|(k, v)| format!(r#"<config key="{k}" value="{v}"/>"#))
        .collect()
}

/// A sphere of radius `r` whose lowest point is at z = 0 when qpos[0] = 0; qpos[0] presses
/// it down.
pub fn sphere_body(r: f64) -> String {
    format!(
        r#"<body name="ball" pos="0 0 {r}">
      <joint name="press" type="slide" axis="0 0 -1"/>
      <geom name="ball" type="sphere" size="{r}" contype="0" conaffinity="0"/>
    </body>"#
    )
}

/// The tan of a pinhole ray's angle from the vertical in the gel, for the ray that meets
/// the undeformed top face at `r` from the axis (gel `t` thick, pinhole `d` below it, index
/// `n`): found independently of the library, by bisection on the outside angle `a`, where
/// `D tan a + T tan b = r` with `sin b = sin a / n` (the left side rises with `a`).
pub fn snell_slope(r: f64, t: f64, d: f64, n: f64) -> f64 {
    let run = |a: f64| {
        let b = (a.sin() / n).asin();
        d * a.tan() + t * b.tan()
    };
    let (mut lo, mut hi) = (0.0, (r / d).atan());
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if run(mid) < r {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    ((0.5 * (lo + hi)).sin() / n).asin().tan()
}
