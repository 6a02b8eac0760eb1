//! Mesh SDFs shared across every `mjData` (and model) that holds the same mesh: the grid
//! is built once per process, not once per `mj_makeData`, and kept in the gel cache's
//! folder ([`crate::mpm::gel_cache`], kind `mesh`) for the next process, which reads it
//! back at load ([`TriMesh::prepare`]) instead of building it at the mesh's first contact.

use std::collections::hash_map::DefaultHasher;
use std::collections::HashMap;
use std::hash::{Hash, Hasher};
use std::sync::{Arc, Mutex, Weak};

use crate::geometry::{GridStore, MeshSdfOptions, Sdf, TriMesh};
use crate::mpm::gel_cache::Store;

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
    let mut mesh = TriMesh::from_flat(verts, faces, 1.0, &MeshSdfOptions::default())
        .map_err(|e| e.to_string())?;
    if let Some(store) = Store::from_env() {
        mesh = mesh.with_store(Arc::new(Meshes(store)));
    }
    let mesh = Arc::new(mesh);
    if let Ok(mut cache) = CACHE.lock() {
        let map = cache.get_or_insert_with(HashMap::new);
        map.retain(|_, w| w.strong_count() > 0);
        map.insert(key, Arc::downgrade(&mesh));
    }
    Ok(mesh)
}

/// The gel cache's folder as a [`GridStore`]: files of kind `mesh`.
struct Meshes(Store);

impl GridStore for Meshes {
    fn read(&self, key: &str) -> Option<Vec<f32>> {
        self.0.read("mesh", key)
    }

    fn write(&self, key: &str, values: &[f32]) {
        // A cache that cannot be written costs the next process the build, no more.
        let _ = self.0.write("mesh", key, values);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    /// The hexagon pattern as MuJoCo holds a mesh: flat vertex (m) and face arrays.
    fn hexagon_flat() -> (Vec<f32>, Vec<i32>) {
        let data = crate::geometry::load_mesh(
            &crate::geometry::test_support::pattern("hexagon.stl"),
            1e-3,
        )
        .expect("hexagon loads");
        let verts = data
            .vertices
            .iter()
            .flat_map(|v| v.iter().map(|&c| c as f32).collect::<Vec<_>>())
            .collect();
        let faces = data.faces.iter().flatten().map(|&i| i as i32).collect();
        (verts, faces)
    }

    /// Through the gel cache's folder: the first mesh writes its grid there, the next
    /// reads it at `prepare` and answers as a mesh without a store does; a file corrupted
    /// there (one byte flipped) is not read: the grid is built again, the same, and the
    /// file written whole again.
    #[test]
    fn the_gel_caches_folder_keeps_a_meshs_grid_and_rejects_a_corrupt_one() {
        let dir = std::env::temp_dir().join(format!("tacrom-mesh-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let (verts, faces) = hexagon_flat();
        let mesh = || {
            TriMesh::from_flat(&verts, &faces, 1.0, &MeshSdfOptions::default())
                .unwrap()
                .with_store(Arc::new(Meshes(Store::new(dir.clone(), 1 << 30))))
        };
        let plain = TriMesh::from_flat(&verts, &faces, 1.0, &MeshSdfOptions::default()).unwrap();
        let points: Vec<Point3<f64>> = (0..200)
            .map(|i| {
                let t = f64::from(i);
                Point3::new(
                    0.013 * (0.7 * t).sin(),
                    0.011 * (0.3 * t).cos(),
                    0.006 * (1.1 * t).sin(),
                )
            })
            .collect();
        let answers = |m: &TriMesh| -> Vec<f64> { points.iter().map(|p| m.distance(p)).collect() };
        let expected = answers(&plain);
        let first = mesh();
        assert!(!first.prepare());
        assert_eq!(answers(&first), expected);
        let files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| {
                p.file_name()
                    .unwrap()
                    .to_string_lossy()
                    .starts_with("mesh-")
            })
            .collect();
        assert_eq!(files.len(), 1, "{files:?}");
        let whole = std::fs::read(&files[0]).unwrap();
        let second = mesh();
        assert!(second.prepare(), "the kept grid was not read");
        assert_eq!(answers(&second), expected);

        let mut bad = whole.clone();
        let middle = bad.len() / 2;
        bad[middle] ^= 0x40;
        std::fs::write(&files[0], &bad).unwrap();
        let third = mesh();
        assert!(!third.prepare(), "a corrupt file was read");
        assert_eq!(answers(&third), expected);
        assert_eq!(
            std::fs::read(&files[0]).unwrap(),
            whole,
            "the file was not written again"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
