//! On-disk cache of reference presses.
//!
//! One file per reference press, named by a 128-bit hash of everything that determines it
//! ([`CacheKey`]): the indenter mesh's bytes and scale, the pose, the whole depth sequence
//! up to this press (the gel is warm-started from the previous press), the sensor
//! configuration, the solver options and a code version string. A re-run finds the file
//! and skips the simulation; changing any input changes the name, so stale entries are
//! never read (delete the folder to reclaim space).
//!
//! # File format (`<key>.tref`)
//!
//! Text header lines `name value...`, the first `tacrom-bench-ref 1`, the last `end`, then
//! little-endian `f64` arrays back to back, in the order and shapes the header's `arrays`
//! line gives: `depth` (height x width, m), `force` (3, N), `points` (height*width x 3, m:
//! the deformed surface, pixel centres lowered by their depth). With numpy:
//!
//! ```python
//! raw = open(path, "rb").read()
//! i = raw.index(b"\nend\n") + 5
//! data = np.frombuffer(raw[i:], "<f8")
//! depth = data[: h * w].reshape(h, w)
//! ```

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// First line of every cache file.
const MAGIC: &str = "tacrom-bench-ref 1";

/// An accumulating 128-bit FNV-1a hash of labelled fields (two 64-bit lanes with distinct
/// offset bases). Not cryptographic: it names cache files.
#[derive(Clone, Debug)]
pub struct CacheKey {
    lanes: [u64; 2],
}

impl Default for CacheKey {
    fn default() -> Self {
        Self {
            lanes: [0xcbf2_9ce4_8422_2325, 0x6c62_272e_07bb_0142],
        }
    }
}

impl CacheKey {
    /// An empty key.
    pub fn new() -> Self {
        Self::default()
    }

    fn bytes(&mut self, data: &[u8]) {
        const PRIME: u64 = 0x0000_0100_0000_01b3;
        for (lane, salt) in self.lanes.iter_mut().zip([0u8, 0x5a]) {
            for &b in data {
                *lane ^= u64::from(b ^ salt);
                *lane = lane.wrapping_mul(PRIME);
            }
        }
    }

    /// Adds a labelled byte string (the label and length are hashed too, so fields cannot
    /// run into each other).
    pub fn field(&mut self, label: &str, data: &[u8]) -> &mut Self {
        self.bytes(label.as_bytes());
        self.bytes(&(data.len() as u64).to_le_bytes());
        self.bytes(data);
        self
    }

    /// Adds labelled numbers, by their exact bits.
    pub fn floats(&mut self, label: &str, values: &[f64]) -> &mut Self {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.field(label, &bytes)
    }

    /// The key as 32 hexadecimal digits.
    pub fn hex(&self) -> String {
        format!("{:016x}{:016x}", self.lanes[0], self.lanes[1])
    }
}

/// One reference press as stored.
#[derive(Clone, Debug, PartialEq)]
pub struct CachedPress {
    /// Image width (pixels).
    pub width: usize,
    /// Image height (pixels).
    pub height: usize,
    /// Depth image (m), row-major.
    pub depth: Vec<f64>,
    /// Total force (N, sensor frame).
    pub force: [f64; 3],
    /// Deformed surface points (m, sensor frame).
    pub points: Vec<[f64; 3]>,
    /// Wall time of the evaluation when it was computed (s).
    pub seconds: f64,
    /// Per-stage wall times when it was computed (s), in [`super::STAGES`] order; `NaN`
    /// for stages the mode does not have.
    pub stages: Vec<f64>,
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

    /// The file of `key`.
    pub fn path(&self, key: &CacheKey) -> PathBuf {
        self.dir.join(format!("{}.tref", key.hex()))
    }

    /// The entry of `key`: `Ok(None)` when absent.
    pub fn load(&self, key: &CacheKey) -> Result<Option<CachedPress>, CacheError> {
        let path = self.path(key);
        let bytes = match std::fs::read(&path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(CacheError::Io { path, source }),
        };
        decode(&bytes)
            .map(Some)
            .map_err(|reason| CacheError::Malformed { path, reason })
    }

    /// Stores `press` under `key`, atomically (a temporary file, then a rename).
    pub fn store(&self, key: &CacheKey, press: &CachedPress) -> Result<(), CacheError> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| CacheError::Io { path, source }
        };
        std::fs::create_dir_all(&self.dir).map_err(io(&self.dir))?;
        let path = self.path(key);
        let tmp = path.with_extension(format!("tmp{}", std::process::id()));
        let mut f = std::fs::File::create(&tmp).map_err(io(&tmp))?;
        f.write_all(&encode(key, press)).map_err(io(&tmp))?;
        f.sync_all().map_err(io(&tmp))?;
        drop(f);
        std::fs::rename(&tmp, &path).map_err(io(&path))
    }
}

fn encode(key: &CacheKey, p: &CachedPress) -> Vec<u8> {
    let mut h = String::new();
    let stages: Vec<String> = p.stages.iter().map(|s| format!("{s:e}")).collect();
    let _ = writeln!(h, "{MAGIC}");
    let _ = writeln!(h, "key {}", key.hex());
    let _ = writeln!(h, "size {} {}", p.width, p.height);
    let _ = writeln!(h, "seconds {:e}", p.seconds);
    let _ = writeln!(h, "stages {}", stages.join(" "));
    let _ = writeln!(h, "iterations {}", p.iterations);
    let _ = writeln!(h, "converged {}", u8::from(p.converged));
    let _ = writeln!(h, "peak_rss {}", p.peak_rss.map_or(-1, |v| v as i64));
    let _ = writeln!(
        h,
        "arrays depth {}x{} force 3 points {}x3",
        p.height,
        p.width,
        p.points.len()
    );
    h.push_str("end\n");
    let mut out = h.into_bytes();
    let values = p
        .depth
        .iter()
        .chain(&p.force)
        .chain(p.points.iter().flatten());
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

fn decode(bytes: &[u8]) -> Result<CachedPress, String> {
    let end = bytes
        .windows(5)
        .position(|w| w == b"\nend\n")
        .ok_or("no header end")?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "header is not text")?;
    let mut lines = header.lines();
    if lines.next() != Some(MAGIC) {
        return Err("not a tacrom-bench-ref 1 file".into());
    }
    let mut p = CachedPress {
        width: 0,
        height: 0,
        depth: Vec::new(),
        force: [0.0; 3],
        points: Vec::new(),
        seconds: f64::NAN,
        stages: Vec::new(),
        iterations: 0,
        converged: false,
        peak_rss: None,
    };
    let mut npoints = 0usize;
    for line in lines {
        let mut w = line.split_whitespace();
        let name = w.next().unwrap_or("");
        let rest: Vec<&str> = w.collect();
        let num = |i: usize| -> Result<f64, String> {
            rest.get(i)
                .and_then(|s| s.parse::<f64>().ok())
                .ok_or_else(|| format!("bad '{name}' line"))
        };
        match name {
            "size" => {
                p.width = num(0)? as usize;
                p.height = num(1)? as usize;
            }
            "seconds" => p.seconds = num(0)?,
            "stages" => {
                p.stages = (0..rest.len()).map(num).collect::<Result<_, _>>()?;
            }
            "iterations" => p.iterations = num(0)? as usize,
            "converged" => p.converged = num(0)? != 0.0,
            "peak_rss" => p.peak_rss = u64::try_from(num(0)? as i64).ok(),
            "arrays" => {
                npoints = rest
                    .get(5)
                    .and_then(|s| s.strip_suffix("x3"))
                    .and_then(|s| s.parse().ok())
                    .ok_or("bad 'arrays' line")?;
            }
            _ => {}
        }
    }
    let pixels = p.width * p.height;
    let data = &bytes[end + 5..];
    let count = pixels + 3 + 3 * npoints;
    if data.len() != 8 * count {
        return Err(format!("{} data bytes, expected {}", data.len(), 8 * count));
    }
    let mut v = data
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("chunks of 8")));
    p.depth = v.by_ref().take(pixels).collect();
    for f in &mut p.force {
        *f = v.next().unwrap_or(f64::NAN);
    }
    p.points = (0..npoints)
        .map(|_| {
            let mut q = [0.0; 3];
            for c in &mut q {
                *c = v.next().unwrap_or(f64::NAN);
            }
            q
        })
        .collect();
    Ok(p)
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
            points: vec![[0.0, 1.0, -2.0], [3.0, 4.0, 5.0]],
            seconds: 1.25,
            stages: vec![0.001, f64::NAN, 1.2],
            iterations: 321,
            converged: true,
            peak_rss: Some(123456789),
        }
    }

    #[test]
    fn keys_depend_on_every_field_and_its_boundaries() {
        let mut a = CacheKey::new();
        let _ = a.field("mesh", b"abc").floats("depth", &[1e-4]);
        let mut b = CacheKey::new();
        let _ = b.field("mesh", b"abc").floats("depth", &[1e-4]);
        assert_eq!(a.hex(), b.hex());
        assert_eq!(a.hex().len(), 32);
        let mut c = CacheKey::new();
        let _ = c.field("mesh", b"ab").field("cdepth", b"");
        assert_ne!(a.hex(), c.hex());
        let mut d = CacheKey::new();
        let _ = d.field("mesh", b"abc").floats("depth", &[1.0000001e-4]);
        assert_ne!(a.hex(), d.hex());
    }

    #[test]
    fn round_trip() {
        let dir = std::env::temp_dir().join(format!("tacrom-cache-test-{}", std::process::id()));
        let cache = Cache::new(&dir);
        let mut key = CacheKey::new();
        let _ = key.field("x", b"1");
        assert!(cache.load(&key).unwrap().is_none());
        let p = sample();
        cache.store(&key, &p).unwrap();
        let q = cache.load(&key).unwrap().unwrap();
        assert_eq!(q.depth, p.depth);
        assert_eq!(q.force, p.force);
        assert_eq!(q.points, p.points);
        assert_eq!(q.iterations, 321);
        assert!(q.converged);
        assert_eq!(q.peak_rss, Some(123456789));
        assert!(q.stages[1].is_nan() && q.stages[2] == 1.2);
        // A truncated file is an error that names it, not a panic.
        let path = cache.path(&key);
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
        let e = cache.load(&key).unwrap_err().to_string();
        assert!(e.contains("malformed"), "{e}");
        std::fs::write(&path, b"garbage").unwrap();
        assert!(cache.load(&key).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
