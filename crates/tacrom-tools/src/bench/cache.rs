//! On-disk cache of reference presses.
//!
//! One entry per reference press, named by a SHA-256 ([`digest`]) of everything that
//! determines it: the indenter mesh's bytes and scale, the pose, the whole depth sequence
//! up to this press (the gel is warm-started from the previous press), the sensor
//! configuration, the solver options and the physics sources' fingerprint. A re-run finds
//! the entry and skips the simulation; changing any input changes the name, so stale
//! entries are never read (delete the folder to reclaim space).
//!
//! # Files
//!
//! `<key>.npy.gz` holds the depth image, gzip-compressed `.npy` of float32 `[height,
//! width]` in metres (relative precision 6e-8: below 0.1 nm at a 1 mm press; the image
//! is zero outside the contact, so it compresses well: a 320 x 240 press whose contact
//! covers 40 % of the image takes 67 kB instead of 614 kB), and `<key>.json` the rest ([`CachedPress`]: size,
//! force, timings, solver report); the JSON is written last, so an entry exists once its
//! JSON does. With numpy: `np.load(gzip.open(f"{key}.npy.gz"))`.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest as _, Sha256};

use std::io::{Read as _, Write as _};

use crate::npy;

/// The name of a cache entry for `inputs`: the SHA-256 of their JSON, as 64 hexadecimal
/// digits. Numbers enter by their shortest exact decimal form, so any change of a value
/// changes the name; field names and lengths are part of the JSON, so fields cannot run
/// into each other. Not for security: it names files.
pub fn digest<T: Serialize + ?Sized>(inputs: &T) -> String {
    digest_bytes(&serde_json::to_vec(inputs).expect("cache inputs serialise to JSON"))
}

/// The SHA-256 of `bytes` (a mesh file's, say), as 64 hexadecimal digits.
pub fn digest_bytes(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// One reference press as stored: the JSON holds every field but the depth image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CachedPress {
    /// Image width (pixels).
    pub width: usize,
    /// Image height (pixels).
    pub height: usize,
    /// Depth image (m), row-major (in the `.npy` file).
    #[serde(skip)]
    pub depth: Vec<f64>,
    /// Total force (N, sensor frame).
    pub force: [f64; 3],
    /// Wall time of the evaluation when it was computed (s).
    pub seconds: f64,
    /// Per-stage wall times when it was computed (s), in [`super::STAGES`] order; `None`
    /// for stages the mode does not have.
    pub stages: Vec<Option<f64>>,
    /// Solver iterations.
    pub iterations: usize,
    /// Whether the solver converged.
    pub converged: bool,
    /// Peak resident memory of the run that computed it (bytes), if known.
    pub peak_rss: Option<u64>,
}

/// A cache failure: I/O or a malformed file.
#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    /// Reading or writing failed.
    #[error("reference cache {}: {source}", path.display())]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The file is not a cache entry of this version, or is truncated.
    #[error("reference cache {}: malformed entry ({reason}); delete it", path.display())]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

/// A folder of cached reference presses.
#[derive(Clone, Debug)]
pub struct Cache {
    dir: PathBuf,
}

impl Cache {
    /// The cache in `dir` (created on the first store).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The JSON file of entry `key` (its depth image is beside it, `.npy.gz`).
    pub fn path(&self, key: &str) -> PathBuf {
        self.dir.join(format!("{key}.json"))
    }

    /// The entry of `key`: `Ok(None)` when absent.
    pub fn load(&self, key: &str) -> Result<Option<CachedPress>, CacheError> {
        let path = self.path(key);
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(CacheError::Io { path, source }),
        };
        let malformed = |path: &Path, reason: String| CacheError::Malformed {
            path: path.to_path_buf(),
            reason,
        };
        let mut press: CachedPress =
            serde_json::from_str(&text).map_err(|e| malformed(&path, e.to_string()))?;
        let npy_path = path.with_extension("npy.gz");
        let (shape, depth) = read_depth(&npy_path).map_err(|e| malformed(&npy_path, e))?;
        if shape != [press.height, press.width] {
            return Err(malformed(
                &npy_path,
                format!(
                    "shape {shape:?}, expected [{}, {}]",
                    press.height, press.width
                ),
            ));
        }
        press.depth = depth;
        Ok(Some(press))
    }

    /// Copies the entry `old` to `new` where `new` has none and `old` exists (image first,
    /// the JSON last, as [`Cache::store`]); whether it copied. For entries whose inputs
    /// are unchanged under a new key (`tacrom bench --adopt-physics`).
    pub fn adopt(&self, old: &str, new: &str) -> Result<bool, CacheError> {
        let (from, to) = (self.path(old), self.path(new));
        if to.exists() || !from.exists() {
            return Ok(false);
        }
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| CacheError::Io { path, source }
        };
        for (a, b) in [
            (from.with_extension("npy.gz"), to.with_extension("npy.gz")),
            (from.clone(), to.clone()),
        ] {
            let bytes = std::fs::read(&a).map_err(io(&a))?;
            npy::write_atomic(&b, &bytes).map_err(io(&b))?;
        }
        Ok(true)
    }

    /// Stores `press` under `key`: the depth image, then the JSON, each atomically.
    pub fn store(&self, key: &str, press: &CachedPress) -> Result<(), CacheError> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| CacheError::Io { path, source }
        };
        std::fs::create_dir_all(&self.dir).map_err(io(&self.dir))?;
        let path = self.path(key);
        let npy_path = path.with_extension("npy.gz");
        write_depth(&npy_path, press).map_err(io(&npy_path))?;
        let json = serde_json::to_vec_pretty(press).expect("a cached press serialises");
        npy::write_atomic(&path, &json).map_err(io(&path))
    }
}

/// Writes the depth image of `press` as a gzip-compressed float32 `.npy`, atomically.
fn write_depth(path: &Path, press: &CachedPress) -> std::io::Result<()> {
    let depth: Vec<f32> = press.depth.iter().map(|&d| d as f32).collect();
    let npy = npy::to_bytes(&[press.height, press.width], &depth)?;
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    gz.write_all(&npy)?;
    npy::write_atomic(path, &gz.finish()?)
}

/// Reads a depth image written by [`write_depth`]: its shape and values (m).
fn read_depth(path: &Path) -> Result<(Vec<usize>, Vec<f64>), String> {
    let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let mut bytes = Vec::new();
    flate2::read::GzDecoder::new(file)
        .read_to_end(&mut bytes)
        .map_err(|e| e.to_string())?;
    let (shape, depth) = npy::from_bytes::<f32>(&bytes)?;
    Ok((shape, depth.into_iter().map(f64::from).collect()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> CachedPress {
        CachedPress {
            width: 3,
            height: 2,
            depth: vec![0.0, 1e-4, 2e-4, 3e-4, 4e-4, 5e-4],
            force: [0.1, -0.2, 1.5],
            seconds: 1.25,
            stages: vec![Some(0.001), None, Some(1.2)],
            iterations: 321,
            converged: true,
            peak_rss: Some(123456789),
        }
    }

    #[test]
    fn keys_depend_on_every_field_and_its_boundaries() {
        let a = digest(&(("mesh", "abc"), ("depth", [1e-4])));
        assert_eq!(a, digest(&(("mesh", "abc"), ("depth", [1e-4]))));
        assert_eq!(a.len(), 64);
        assert_ne!(a, digest(&(("mesh", "ab"), ("cdepth", ""))));
        assert_ne!(a, digest(&(("mesh", "abc"), ("depth", [1.0000001e-4]))));
    }

    /// A 320 x 240 press whose contact covers 40 % of the image is stored in less than a
    /// fifth of its float64 size (614 kB; measured 67 kB).
    #[test]
    fn images_are_stored_compactly() {
        let dir = std::env::temp_dir().join(format!("tacrom-cache-size-{}", std::process::id()));
        let cache = Cache::new(&dir);
        let (w, h) = (320usize, 240usize);
        let depth = (0..w * h)
            .map(|k| {
                let (x, y) = ((k % w) as f64 - 160.0, (k / w) as f64 - 120.0);
                (1e-3 - (x * x + y * y) * 1e-7).max(0.0)
            })
            .collect::<Vec<f64>>();
        assert!(depth.iter().filter(|d| **d > 0.0).count() > w * h * 2 / 5);
        let press = CachedPress {
            width: w,
            height: h,
            depth,
            ..sample()
        };
        let key = digest("size");
        cache.store(&key, &press).unwrap();
        let bytes = std::fs::metadata(cache.path(&key).with_extension("npy.gz"))
            .unwrap()
            .len();
        assert!(bytes < (8 * w * h / 5) as u64, "{bytes} bytes");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// An entry is copied to its new key whole (same image, same fields); an existing entry
    /// under the new key is kept, and a missing old one copies nothing.
    #[test]
    fn an_adopted_entry_is_the_old_one_under_its_new_key() {
        let dir = std::env::temp_dir().join(format!("tacrom-cache-adopt-{}", std::process::id()));
        let cache = Cache::new(&dir);
        let (old, new, other) = (digest("old"), digest("new"), digest("other"));
        assert!(!cache.adopt(&old, &new).unwrap(), "nothing to adopt");
        let press = sample();
        cache.store(&old, &press).unwrap();
        assert!(cache.adopt(&old, &new).unwrap());
        assert_eq!(cache.load(&new).unwrap(), cache.load(&old).unwrap());
        let mut kept = sample();
        kept.force = [9.0; 3];
        cache.store(&other, &kept).unwrap();
        assert!(
            !cache.adopt(&old, &other).unwrap(),
            "an existing entry is not overwritten"
        );
        assert_eq!(cache.load(&other).unwrap().unwrap().force, [9.0; 3]);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn round_trip() {
        let dir = std::env::temp_dir().join(format!("tacrom-cache-test-{}", std::process::id()));
        let cache = Cache::new(&dir);
        let key = digest("x");
        assert!(cache.load(&key).unwrap().is_none());
        let p = sample();
        cache.store(&key, &p).unwrap();
        let mut q = cache.load(&key).unwrap().unwrap();
        // The image is stored in float32: within its relative precision.
        for (a, b) in q.depth.iter().zip(&p.depth) {
            assert!((a - b).abs() <= 6e-8 * b.abs(), "{a} against {b}");
        }
        q.depth.clone_from(&p.depth);
        assert_eq!(q.force, p.force);
        assert_eq!(q.iterations, 321);
        assert!(q.converged);
        assert_eq!(q.peak_rss, Some(123456789));
        assert!(q.stages[1].is_none() && q.stages[2] == Some(1.2));
        assert_eq!(q, p);
        // A truncated file is an error that names it, not a panic; so is a lost image.
        let path = cache.path(&key);
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
        let e = cache.load(&key).unwrap_err().to_string();
        assert!(e.contains("malformed"), "{e}");
        std::fs::write(&path, b"garbage").unwrap();
        assert!(cache.load(&key).is_err());
        cache.store(&key, &p).unwrap();
        std::fs::remove_file(path.with_extension("npy.gz")).unwrap();
        assert!(cache
            .load(&key)
            .unwrap_err()
            .to_string()
            .contains("malformed"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
