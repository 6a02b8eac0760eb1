//! Writes the geoms of [`crate::visual`] into a MuJoCo scene (`mjvScene`).

use super::sys;
use crate::visual::{Kind, VisualGeom};

/// Appends `geoms` to `scn` as decoration of sensor `sensor_id`, each filled in by
/// `mjv_initGeom`, until the scene is full: then it stops quietly, marking the scene's
/// `status` as MuJoCo does when its own geoms run out. Returns how many it added.
pub fn add_to_scene(scn: &mut sys::mjvScene, geoms: &[VisualGeom], sensor_id: usize) -> usize {
    let mut added = 0;
    for g in geoms {
        if scn.geoms.is_null() || scn.ngeom < 0 || scn.ngeom >= scn.maxgeom {
            scn.status = 1;
            break;
        }
        let kind = match g.kind {
            Kind::Tile => sys::mjGEOM_BOX,
            Kind::Arrow => sys::mjGEOM_ARROW,
        };
        // SAFETY: `geoms` holds `maxgeom` entries and 0 <= ngeom < maxgeom, so the slot is
        // inside the buffer; no other reference to it exists while the callback runs.
        let slot = unsafe { &mut *scn.geoms.add(scn.ngeom as usize) };
        // SAFETY: `slot` is a valid geom; size, pos and mat point to 3, 3 and 9 numbers
        // and rgba to 4 floats, as mjv_initGeom reads; it never raises an error.
        unsafe {
            sys::mjv_initGeom(
                slot,
                kind as i32,
                g.size.as_ptr(),
                g.pos.as_ptr(),
                g.mat.as_ptr(),
                g.rgba.as_ptr(),
            );
        }
        slot.objtype = sys::mjOBJ_SENSOR as i32;
        slot.objid = i32::try_from(sensor_id).unwrap_or(-1);
        slot.category = sys::mjCAT_DECOR as i32;
        slot.segid = scn.ngeom;
        scn.ngeom += 1;
        added += 1;
    }
    added
}
