//! Mesh SDFs shared across every `mjData` (and model) that holds the same mesh: the grid
//! is built once per process, not once per `mj_makeData`.

use std::collections::hash_map::DefaultHasher;
use std::collections::HashMap;
use std::hash::{Hash, Hasher};
use std::sync::{Arc, Mutex, Weak};

use crate::geometry::{MeshSdfOptions, Sdf, TriMesh};

type Key = (u64, usize, usize);

/// The SDF of the mesh with these MuJoCo vertices (x, y, z per vertex) and faces (three
/// vertex indices each), from the cache when an identical mesh is alive.
pub fn get_or_build(verts: &[f32], faces: &[i32]) -> Result<Arc<dyn Sdf>, String> {
    static CACHE: Mutex<Option<HashMap<Key, Weak<TriMesh>>>> = Mutex::new(None);
    let mut h = DefaultHasher::new();
    for v in verts {
        v.to_bits().hash(&mut h);
    }
    faces.hash(&mut h);
    let key = (h.finish(), verts.len(), faces.len());

    if let Some(mesh) = CACHE
        .lock()
        .ok()
        .and_then(|c| c.as_ref().and_then(|m| m.get(&key)).and_then(Weak::upgrade))
    {
        return Ok(mesh);
    }
    let mesh = Arc::new(
        TriMesh::from_flat(verts, faces, 1.0, &MeshSdfOptions::default())
            .map_err(|e| e.to_string())?,
    );
    if let Ok(mut cache) = CACHE.lock() {
        let map = cache.get_or_insert_with(HashMap::new);
        map.retain(|_, w| w.strong_count() > 0);
        map.insert(key, Arc::downgrade(&mesh));
    }
    Ok(mesh)
}
