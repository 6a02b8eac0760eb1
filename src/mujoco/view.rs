//! Read-only, bounds-checked views of `mjModel` and `mjData` arrays.
//!
//! Each accessor turns one raw array of the C structs into a slice of the documented
//! length, so the rest of the crate indexes slices (and panics, caught at the FFI edge,
//! rather than reading out of bounds).

use std::ffi::{CStr, CString};

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::sys;

/// Borrowed `mjModel`.
#[derive(Clone, Copy)]
pub struct Model<'a>(pub &'a sys::mjModel);

/// Borrowed `mjData`, read-only.
#[derive(Clone, Copy)]
pub struct Data<'a>(pub &'a sys::mjData);

/// `len` elements of a model or data array; empty when the pointer is null.
///
/// # Safety
/// `ptr` must be null or point to at least `len` initialised elements that outlive `'a`.
unsafe fn slice<'a, T>(ptr: *const T, len: usize) -> &'a [T] {
    if ptr.is_null() || len == 0 {
        &[]
    } else {
        // SAFETY: the caller guarantees `len` valid elements behind `ptr`.
        unsafe { std::slice::from_raw_parts(ptr, len) }
    }
}

fn count(n: i64) -> usize {
    usize::try_from(n).unwrap_or(0)
}

macro_rules! model_array {
    ($(#[$doc:meta] $name:ident: $ty:ty, $field:ident, $n:ident * $k:expr;)*) => {
        impl<'a> Model<'a> {
            $(
                #[$doc]
                pub fn $name(&self) -> &'a [$ty] {
                    // SAFETY: MuJoCo allocates `$field` with `$n * $k` elements for the
                    // lifetime of the model (mjmodel.h documents each size).
                    unsafe { slice(self.0.$field, count(self.0.$n) * $k) }
                }
            )*
        }
    };
}

model_array! {
    /// `body_weldid` (nbody).
    body_weldid: i32, body_weldid, nbody * 1;
    /// `body_mass` (nbody).
    body_mass: f64, body_mass, nbody * 1;
    /// `name_bodyadr` (nbody).
    name_bodyadr: i32, name_bodyadr, nbody * 1;
    /// `geom_type` (ngeom).
    geom_type: i32, geom_type, ngeom * 1;
    /// `geom_bodyid` (ngeom).
    geom_bodyid: i32, geom_bodyid, ngeom * 1;
    /// `geom_dataid` (ngeom).
    geom_dataid: i32, geom_dataid, ngeom * 1;
    /// `geom_size` (ngeom x 3).
    geom_size: f64, geom_size, ngeom * 3;
    /// `geom_rbound` (ngeom).
    geom_rbound: f64, geom_rbound, ngeom * 1;
    /// `geom_condim` (ngeom).
    geom_condim: i32, geom_condim, ngeom * 1;
    /// `geom_priority` (ngeom).
    geom_priority: i32, geom_priority, ngeom * 1;
    /// `geom_contype` (ngeom).
    geom_contype: i32, geom_contype, ngeom * 1;
    /// `geom_conaffinity` (ngeom).
    geom_conaffinity: i32, geom_conaffinity, ngeom * 1;
    /// `name_geomadr` (ngeom).
    name_geomadr: i32, name_geomadr, ngeom * 1;
    /// `site_bodyid` (nsite).
    site_bodyid: i32, site_bodyid, nsite * 1;
    /// `name_siteadr` (nsite).
    name_siteadr: i32, name_siteadr, nsite * 1;
    /// `mesh_vertadr` (nmesh).
    mesh_vertadr: i32, mesh_vertadr, nmesh * 1;
    /// `mesh_vertnum` (nmesh).
    mesh_vertnum: i32, mesh_vertnum, nmesh * 1;
    /// `mesh_faceadr` (nmesh).
    mesh_faceadr: i32, mesh_faceadr, nmesh * 1;
    /// `mesh_facenum` (nmesh).
    mesh_facenum: i32, mesh_facenum, nmesh * 1;
    /// `mesh_vert` (nmeshvert x 3).
    mesh_vert: f32, mesh_vert, nmeshvert * 3;
    /// `mesh_face` (nmeshface x 3).
    mesh_face: i32, mesh_face, nmeshface * 3;
    /// `sensor_objtype` (nsensor).
    sensor_objtype: i32, sensor_objtype, nsensor * 1;
    /// `sensor_objid` (nsensor).
    sensor_objid: i32, sensor_objid, nsensor * 1;
    /// `sensor_adr` (nsensor).
    sensor_adr: i32, sensor_adr, nsensor * 1;
    /// `sensor_dim` (nsensor).
    sensor_dim: i32, sensor_dim, nsensor * 1;
    /// `sensor_plugin` (nsensor).
    sensor_plugin: i32, sensor_plugin, nsensor * 1;
    /// `name_sensoradr` (nsensor).
    name_sensoradr: i32, name_sensoradr, nsensor * 1;
    /// `plugin` (nplugin): the registry slot of each plugin instance.
    plugin: i32, plugin, nplugin * 1;
    /// `plugin_stateadr` (nplugin): where each instance's state starts in `plugin_state`.
    plugin_stateadr: i32, plugin_stateadr, nplugin * 1;
    /// `plugin_statenum` (nplugin): the length of each instance's state.
    plugin_statenum: i32, plugin_statenum, nplugin * 1;
}

impl<'a> Model<'a> {
    /// Number of geoms.
    pub fn ngeom(&self) -> usize {
        count(self.0.ngeom)
    }

    /// Total `plugin_state` length.
    pub fn npluginstate(&self) -> usize {
        count(self.0.npluginstate)
    }

    /// Total sensordata length.
    pub fn nsensordata(&self) -> usize {
        count(self.0.nsensordata)
    }

    /// The name stored at `adr` in the names buffer ("" when out of range).
    pub fn name_at(&self, adr: i32) -> &'a str {
        let len = count(self.0.nnames);
        let Ok(adr) = usize::try_from(adr) else {
            return "";
        };
        if adr >= len {
            return "";
        }
        // SAFETY: `names` holds `nnames` bytes of NUL-terminated strings.
        let bytes = unsafe { slice(self.0.names as *const u8, len) };
        let tail = &bytes[adr..];
        let end = tail.iter().position(|&b| b == 0).unwrap_or(tail.len());
        std::str::from_utf8(&tail[..end]).unwrap_or("")
    }

    /// Name of sensor `id`.
    pub fn sensor_name(&self, id: usize) -> &'a str {
        self.name_sensoradr()
            .get(id)
            .map_or("", |&a| self.name_at(a))
    }

    /// Name of body `id`.
    pub fn body_name(&self, id: usize) -> &'a str {
        self.name_bodyadr().get(id).map_or("", |&a| self.name_at(a))
    }

    /// Name of geom `id`.
    pub fn geom_name(&self, id: usize) -> &'a str {
        self.name_geomadr().get(id).map_or("", |&a| self.name_at(a))
    }

    /// The sensor that plugin `instance` serves, if any.
    pub fn sensor_of_instance(&self, instance: i32) -> Option<usize> {
        self.sensor_plugin().iter().position(|&p| p == instance)
    }

    /// The registered name of the plugin that `instance` is an instance of.
    pub fn plugin_name(&self, instance: i32) -> Option<String> {
        let slot = *self.plugin().get(usize::try_from(instance).ok()?)?;
        // SAFETY: mjp_getPluginAtSlot returns null or a plugin of the global registry,
        // which lives (and is never modified) for the rest of the process.
        let plugin = unsafe { sys::mjp_getPluginAtSlot(slot).as_ref() }?;
        if plugin.name.is_null() {
            return None;
        }
        // SAFETY: a registered plugin's name is a NUL-terminated string the registry owns.
        Some(
            unsafe { CStr::from_ptr(plugin.name) }
                .to_string_lossy()
                .into_owned(),
        )
    }

    /// The configured text of `attribute` for plugin `instance`.
    pub fn plugin_config(&self, instance: i32, attribute: &str) -> Option<String> {
        let key = CString::new(attribute).ok()?;
        // SAFETY: the model is valid; mj_getPluginConfig returns null or a NUL-terminated
        // string owned by the model.
        let value = unsafe { sys::mj_getPluginConfig(self.0, instance, key.as_ptr()) };
        if value.is_null() {
            return None;
        }
        // SAFETY: non-null, NUL-terminated, alive as long as the model.
        let text = unsafe { CStr::from_ptr(value) }
            .to_string_lossy()
            .into_owned();
        Some(text)
    }
}

impl<'a> Data<'a> {
    fn ngeom(m: &Model<'_>) -> usize {
        m.ngeom()
    }

    /// `geom_xpos` (ngeom x 3).
    pub fn geom_xpos(&self, m: &Model<'_>) -> &'a [f64] {
        // SAFETY: sized by the model this data was made from.
        unsafe { slice(self.0.geom_xpos, Self::ngeom(m) * 3) }
    }

    /// `geom_xmat` (ngeom x 9).
    pub fn geom_xmat(&self, m: &Model<'_>) -> &'a [f64] {
        // SAFETY: sized by the model this data was made from.
        unsafe { slice(self.0.geom_xmat, Self::ngeom(m) * 9) }
    }

    /// `site_xpos` (nsite x 3).
    pub fn site_xpos(&self, m: &Model<'_>) -> &'a [f64] {
        // SAFETY: sized by the model this data was made from.
        unsafe { slice(self.0.site_xpos, count(m.0.nsite) * 3) }
    }

    /// `site_xmat` (nsite x 9).
    pub fn site_xmat(&self, m: &Model<'_>) -> &'a [f64] {
        // SAFETY: sized by the model this data was made from.
        unsafe { slice(self.0.site_xmat, count(m.0.nsite) * 9) }
    }
}

/// A rigid pose from MuJoCo's position and row-major rotation matrix; `None` when any
/// number is not finite.
pub fn pose(pos: &[f64], mat: &[f64]) -> Option<Isometry3<f64>> {
    if pos.len() < 3 || mat.len() < 9 || !pos[..3].iter().chain(&mat[..9]).all(|x| x.is_finite()) {
        return None;
    }
    let r = Matrix3::from_row_slice(&mat[..9]);
    // MuJoCo's matrices are orthonormal to rounding: Shepperd's method on the matrix as
    // given, then normalising the quaternion, is exact to rounding and never iterates.
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let n = q.quaternion().norm();
    if !(n.is_finite() && n > 1e-6) {
        return None;
    }
    let q = UnitQuaternion::new_normalize(*q.quaternion());
    if !q.coords.iter().all(|x| x.is_finite()) {
        return None;
    }
    Some(Isometry3::from_parts(
        Translation3::from(Vector3::new(pos[0], pos[1], pos[2])),
        q,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_from_mujoco_arrays() {
        // 90 degrees about z, row-major.
        let mat = [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let p = pose(&[1.0, 2.0, 3.0], &mat).unwrap();
        let v = p * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!((v - nalgebra::Point3::new(1.0, 3.0, 3.0)).norm() < 1e-12);
    }

    #[test]
    fn bad_pose_arrays_never_stall_or_give_nan() {
        assert!(pose(
            &[f64::NAN, 0.0, 0.0],
            &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        )
        .is_none());
        assert!(pose(&[0.0; 3], &[f64::INFINITY; 9]).is_none());
        assert!(pose(&[0.0; 2], &[0.0; 9]).is_none());
        // A degenerate (zero) matrix: bounded work, and a finite pose or none.
        if let Some(p) = pose(&[0.0; 3], &[0.0; 9]) {
            assert!(p.rotation.coords.iter().all(|x| x.is_finite()));
        }
    }
}
