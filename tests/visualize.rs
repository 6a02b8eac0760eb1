//! The plugin's `visualize` callback, called as MuJoCo calls it (the registered plugin's
//! function pointer) on a scene buffer owned by the test: what it adds, where, and that it
//! adds nothing without the contact flags, without contact, or beyond `maxgeom`.

mod common;

use std::ffi::CString;

use common::*;
use tacrom::mujoco::sys;

const R: f64 = 0.005;
const FOV: [f64; 2] = [0.024, 0.018];
/// Boxes for a 4:3 field of view within the 400-geom budget.
const TILES: usize = 23 * 17;

/// A scene of `maxgeom` geoms, as `mjv_makeScene` would hold them (only the fields the
/// callback reads or writes matter).
struct Scene {
    scn: sys::mjvScene,
    _geoms: Vec<sys::mjvGeom>,
}

impl Scene {
    fn new(maxgeom: usize) -> Self {
        // SAFETY: mjvGeom and mjvScene are plain C structs of numbers, arrays and raw
        // pointers, for which all-zero bytes are valid values.
        let mut geoms = vec![unsafe { std::mem::zeroed::<sys::mjvGeom>() }; maxgeom];
        // SAFETY: as above.
        let mut scn: sys::mjvScene = unsafe { std::mem::zeroed() };
        scn.maxgeom = maxgeom as i32;
        scn.geoms = geoms.as_mut_ptr();
        Self { scn, _geoms: geoms }
    }

    fn geoms(&self) -> &[sys::mjvGeom] {
        // SAFETY: `geoms` holds maxgeom >= ngeom initialised entries.
        unsafe { std::slice::from_raw_parts(self.scn.geoms, self.scn.ngeom as usize) }
    }
}

fn options(point: bool, force: bool) -> sys::mjvOption {
    // SAFETY: a plain C struct; all zeros is every flag off.
    let mut opt: sys::mjvOption = unsafe { std::mem::zeroed() };
    opt.flags[sys::mjVIS_CONTACTPOINT as usize] = u8::from(point);
    opt.flags[sys::mjVIS_CONTACTFORCE as usize] = u8::from(force);
    opt
}

/// Calls the registered plugin's visualize callback for instance 0.
fn visualize(m: &Model, d: &Data, opt: Option<&sys::mjvOption>, scn: Option<&mut Scene>) {
    let name = CString::new("tacrom.tactile").unwrap();
    let mut slot = -1;
    // SAFETY: a NUL-terminated name; the registry outlives the test.
    let plugin = unsafe { sys::mjp_getPlugin(name.as_ptr(), &mut slot).as_ref() }
        .expect("tacrom.tactile is registered");
    let callback = plugin
        .visualize
        .expect("the plugin has a visualize callback");
    let opt = opt.map_or(std::ptr::null(), |o| o as *const _);
    let scn = scn.map_or(std::ptr::null_mut(), |s| &mut s.scn as *mut _);
    // SAFETY: a valid model and data made from it; null options or scene are allowed by
    // the callback, which draws nothing then.
    unsafe { callback(m.0, d.0, opt, scn, 0) };
}

fn pressed(depth: f64) -> (Model, Data) {
    load_plugin();
    let cfg = config(&[("physics", "rigid"), ("resolution", "320 240")]);
    let m = load_xml(&press_scene(&cfg, &sphere_body(R))).expect("model loads");
    let mut d = m.make_data();
    d.set_qpos(0, depth);
    d.forward(&m);
    (m, d)
}

#[test]
fn contact_points_draw_the_surface_as_boxes_in_the_field_of_view() {
    let (m, d) = pressed(0.5e-3);
    let mut scene = Scene::new(1000);
    visualize(&m, &d, Some(&options(true, false)), Some(&mut scene));
    let geoms = scene.geoms();
    assert_eq!(geoms.len(), TILES);
    for g in geoms {
        assert_eq!(g.type_, sys::mjGEOM_BOX as i32);
        assert_eq!(g.objtype, sys::mjOBJ_SENSOR as i32);
        assert_eq!(g.objid, 0);
        assert_eq!(g.category, sys::mjCAT_DECOR as i32);
        // The site is the world origin, unrotated.
        assert!(g.pos[0].abs() <= 0.5 * FOV[0] as f32 && g.pos[1].abs() <= 0.5 * FOV[1] as f32);
        assert!(g.pos[2] <= 0.0 && g.pos[2] >= -0.004, "{:?}", g.pos);
    }
    // The deepest box is at the centre, as deep as the press (the cap's apex).
    let deepest = geoms
        .iter()
        .min_by(|a, b| a.pos[2].total_cmp(&b.pos[2]))
        .unwrap();
    assert!(deepest.pos[0].abs() < 0.6e-3 && deepest.pos[1].abs() < 0.6e-3);
    let top = deepest.pos[2] + deepest.size[2];
    assert!((top + 0.5e-3).abs() < 1e-5, "top face at {top}");
    // The rigid mode has no force: contact forces add no arrow.
    let mut scene = Scene::new(1000);
    visualize(&m, &d, Some(&options(false, true)), Some(&mut scene));
    assert_eq!(scene.geoms().len(), TILES);
}

#[test]
fn nothing_without_the_flags_or_without_contact() {
    let (m, mut d) = pressed(0.5e-3);
    let mut scene = Scene::new(1000);
    visualize(&m, &d, Some(&options(false, false)), Some(&mut scene));
    assert_eq!(scene.scn.ngeom, 0);
    d.set_qpos(0, -1e-3);
    d.forward(&m);
    visualize(&m, &d, Some(&options(true, true)), Some(&mut scene));
    assert_eq!(scene.scn.ngeom, 0);
    // Null options or scene: nothing, no crash.
    d.set_qpos(0, 0.5e-3);
    d.forward(&m);
    visualize(&m, &d, None, Some(&mut scene));
    visualize(&m, &d, Some(&options(true, true)), None);
    assert_eq!(scene.scn.ngeom, 0);
}

#[test]
fn appends_after_the_scene_and_stops_at_maxgeom() {
    let (m, d) = pressed(0.5e-3);
    // Geoms already in the scene stay; the sensor's follow them.
    let mut scene = Scene::new(1000);
    scene.scn.ngeom = 10;
    visualize(&m, &d, Some(&options(true, true)), Some(&mut scene));
    assert_eq!(scene.scn.ngeom as usize, 10 + TILES);
    assert!(scene.geoms()[..10]
        .iter()
        .all(|g| g.type_ == 0 && g.objid == 0));
    assert!(scene.geoms()[10..]
        .iter()
        .all(|g| g.type_ == sys::mjGEOM_BOX as i32));
    assert_eq!(scene.scn.status, 0);
    // A full scene: filled to maxgeom, then the status MuJoCo uses for that.
    let mut small = Scene::new(7);
    visualize(&m, &d, Some(&options(true, true)), Some(&mut small));
    assert_eq!(small.scn.ngeom, 7);
    assert_eq!(small.scn.status, 1);
    visualize(&m, &d, Some(&options(true, true)), Some(&mut small));
    assert_eq!(small.scn.ngeom, 7);
}
