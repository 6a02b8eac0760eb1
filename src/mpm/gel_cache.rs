//! What depends only on a gel's parameters, kept on disk between processes.
//!
//! The linear solver's surface compliance (every node column's response, seconds of
//! solves with the factored stiffness) is the same for every sensor of the same gel, so
//! it is computed once per machine and read back at the next load. One file per gel:
//! `linear-<hash>.bin`, `<hash>` the FNV-1a hash of its key (the data's kind, the physics
//! source's fingerprint and every gel parameter to the bit).
//!
//! * **Where**: `$TACROM_CACHE` (`off` turns caching off), else `$XDG_CACHE_HOME/tacrom`,
//!   else `~/.cache/tacrom`.
//! * **Foreign or corrupt files**: a file holds its full key and a checksum of its bytes;
//!   one whose key differs (a hash collision, another build) or whose length or checksum
//!   does not match is ignored and rewritten.
//! * **Concurrent writers**: a file is written beside its name and renamed into place, so a
//!   reader sees a whole file or none; two writers of one key write the same bytes.
//! * **Size**: after a write, the oldest files (by modification time) go until the folder
//!   holds at most `$TACROM_CACHE_MB` MiB ([`DEFAULT_CAP_MB`] unset).

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// First bytes of a cache file (and its format's version).
const MAGIC: &[u8; 8] = b"TACROMC2";

/// The folder's size cap (MiB) when `$TACROM_CACHE_MB` is not set.
pub(crate) const DEFAULT_CAP_MB: u64 = 512;

/// FNV-1a (64 bit) of `bytes`, continuing from `h` ([`FNV_START`] to begin).
pub(crate) fn fnv(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// A file's checksum: FNV-1a's step taken on 8-byte little-endian words (the last one
/// zero-padded) and then on the length, eight times faster than byte by byte on the tens of
/// MB a gel's compliance takes. Any one changed byte changes it.
fn checksum(bytes: &[u8]) -> u64 {
    let mut h = FNV_START;
    let mut words = bytes.chunks_exact(8);
    for w in &mut words {
        h ^= u64::from_le_bytes(w.try_into().expect("8 bytes"));
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    let mut last = [0u8; 8];
    last[..words.remainder().len()].copy_from_slice(words.remainder());
    for w in [u64::from_le_bytes(last), bytes.len() as u64] {
        h ^= w;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// FNV-1a's offset basis: where [`fnv`] starts.
pub(crate) const FNV_START: u64 = 0xcbf2_9ce4_8422_2325;

/// A cache folder.
#[derive(Clone, Debug)]
pub(crate) struct Store {
    dir: PathBuf,
    cap_bytes: u64,
}

impl Store {
    /// The folder the environment names (see the module's documentation); `None` where
    /// caching is off or no folder is known.
    pub fn from_env() -> Option<Store> {
        let dir = match std::env::var_os("TACROM_CACHE") {
            Some(v) if v == "off" || v.is_empty() => return None,
            Some(v) => PathBuf::from(v),
            None => match std::env::var_os("XDG_CACHE_HOME").filter(|v| !v.is_empty()) {
                Some(x) => PathBuf::from(x).join("tacrom"),
                None => PathBuf::from(std::env::var_os("HOME")?).join(".cache/tacrom"),
            },
        };
        let cap_mb = std::env::var("TACROM_CACHE_MB")
            .ok()
            .and_then(|s| s.trim().parse::<u64>().ok())
            .unwrap_or(DEFAULT_CAP_MB);
        Some(Store::new(dir, cap_mb << 20))
    }

    /// The folder `dir`, holding at most `cap_bytes`.
    pub fn new(dir: PathBuf, cap_bytes: u64) -> Store {
        Store { dir, cap_bytes }
    }

    /// The file of `key` of kind `kind` (a word).
    pub fn path(&self, kind: &str, key: &str) -> PathBuf {
        let h = fnv(FNV_START, key.as_bytes());
        self.dir.join(format!("{kind}-{h:016x}.bin"))
    }

    /// The numbers stored under `key`, if a whole file of that key is there.
    pub fn read(&self, kind: &str, key: &str) -> Option<Vec<f32>> {
        decode(&fs::read(self.path(kind, key)).ok()?, key)
    }

    /// Stores `data` under `key` (then trims the folder to its cap).
    pub fn write(&self, kind: &str, key: &str, data: &[f32]) -> std::io::Result<()> {
        fs::create_dir_all(&self.dir)?;
        let path = self.path(kind, key);
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        static WRITES: AtomicU64 = AtomicU64::new(0);
        let tmp = self.dir.join(format!(
            ".{}.{}.{}.{nanos}.tmp",
            path.file_name().and_then(|n| n.to_str()).unwrap_or("entry"),
            std::process::id(),
            WRITES.fetch_add(1, Ordering::Relaxed)
        ));
        let bytes = encode(key, data);
        let written = fs::File::create(&tmp)
            .and_then(|mut f| f.write_all(&bytes).and_then(|()| f.sync_all()))
            .and_then(|()| fs::rename(&tmp, &path));
        if written.is_err() {
            let _ = fs::remove_file(&tmp);
        }
        written?;
        self.trim(&path);
        Ok(())
    }

    /// Removes the oldest cache files until the folder holds at most the cap, never
    /// `keep` (the file just written).
    fn trim(&self, keep: &Path) {
        let Ok(entries) = fs::read_dir(&self.dir) else {
            return;
        };
        let mut files: Vec<(std::time::SystemTime, u64, PathBuf)> = entries
            .flatten()
            .filter_map(|e| {
                let p = e.path();
                let name = p.file_name()?.to_str()?;
                if !name.ends_with(".bin") || name.starts_with('.') {
                    return None;
                }
                let m = e.metadata().ok()?;
                Some((m.modified().ok()?, m.len(), p))
            })
            .collect();
        let mut total: u64 = files.iter().map(|f| f.1).sum();
        files.sort();
        for (_, len, p) in files {
            if total <= self.cap_bytes {
                break;
            }
            if p != keep && fs::remove_file(&p).is_ok() {
                total -= len;
            }
        }
    }
}

/// A file's bytes: [`MAGIC`], the key's length (u64) and bytes, the count of numbers
/// (u64) and the numbers (f32), all little-endian, then the [`checksum`] of all before it.
fn encode(key: &str, data: &[f32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(32 + key.len() + 4 * data.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&(key.len() as u64).to_le_bytes());
    out.extend_from_slice(key.as_bytes());
    out.extend_from_slice(&(data.len() as u64).to_le_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let h = checksum(&out);
    out.extend_from_slice(&h.to_le_bytes());
    out
}

/// The numbers of a file's `bytes` if they are a whole file of `key`.
fn decode(bytes: &[u8], key: &str) -> Option<Vec<f32>> {
    let (body, sum) = bytes.split_at_checked(bytes.len().checked_sub(8)?)?;
    if checksum(body) != u64::from_le_bytes(sum.try_into().ok()?) {
        return None;
    }
    let rest = body.strip_prefix(MAGIC.as_slice())?;
    let (len, rest) = rest.split_at_checked(8)?;
    let len = usize::try_from(u64::from_le_bytes(len.try_into().ok()?)).ok()?;
    let (stored, rest) = rest.split_at_checked(len)?;
    if stored != key.as_bytes() {
        return None;
    }
    let (count, rest) = rest.split_at_checked(8)?;
    let count = usize::try_from(u64::from_le_bytes(count.try_into().ok()?)).ok()?;
    if rest.len() != count.checked_mul(4)? {
        return None;
    }
    Some(
        rest.chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")))
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn store(name: &str, cap: u64) -> Store {
        let dir = std::env::temp_dir().join(format!("tacrom-cache-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        Store::new(dir, cap)
    }

    #[test]
    fn numbers_come_back_bit_for_bit() {
        let s = store("bits", 1 << 20);
        let data = [0.0, -0.0, 1.5e-40, f32::MIN_POSITIVE, -3.25, 1.0 / 3.0];
        s.write("t", "gel a", &data).unwrap();
        let back = s.read("t", "gel a").unwrap();
        assert_eq!(back.len(), data.len());
        for (a, b) in back.iter().zip(&data) {
            assert_eq!(a.to_bits(), b.to_bits());
        }
        assert!(s.read("t", "gel b").is_none());
        let _ = fs::remove_dir_all(&s.dir);
    }

    #[test]
    fn corrupt_truncated_and_foreign_files_are_rejected() {
        let s = store("bad", 1 << 20);
        s.write("t", "key", &[1.0, 2.0, 3.0]).unwrap();
        let path = s.path("t", "key");
        let good = fs::read(&path).unwrap();
        // One bit flipped in a number.
        let mut flipped = good.clone();
        flipped[good.len() - 10] ^= 1;
        assert!(decode(&flipped, "key").is_none());
        // Cut short, or empty.
        assert!(decode(&good[..good.len() - 3], "key").is_none());
        assert!(decode(&[], "key").is_none());
        // Another key's file under this name (a hash collision).
        assert!(decode(&encode("other key", &[1.0, 2.0, 3.0]), "key").is_none());
        // Not a cache file at all.
        fs::write(&path, b"not a cache file, but long enough to parse").unwrap();
        assert!(s.read("t", "key").is_none());
        // Rewritten, it reads again.
        s.write("t", "key", &[4.0]).unwrap();
        assert_eq!(s.read("t", "key"), Some(vec![4.0]));
        let _ = fs::remove_dir_all(&s.dir);
    }

    #[test]
    fn the_folder_keeps_to_its_cap_and_the_newest_file() {
        // Each file: 8 + 8 + 5 + 8 + 4 * 100 + 8 = 437 bytes; the cap holds two.
        let s = store("cap", 900);
        for (i, key) in ["key 1", "key 2", "key 3"].iter().enumerate() {
            s.write("t", key, &[i as f32; 100]).unwrap();
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        assert!(s.read("t", "key 1").is_none(), "the oldest went");
        assert!(s.read("t", "key 2").is_some());
        assert!(s.read("t", "key 3").is_some());
        // A cap below one file still keeps the one just written.
        let tiny = Store::new(s.dir.clone(), 10);
        tiny.write("t", "key 4", &[1.0; 100]).unwrap();
        assert!(tiny.read("t", "key 4").is_some());
        let _ = fs::remove_dir_all(&s.dir);
    }

    /// A folder that cannot be made (its parent is a file) is no cache: writes fail with
    /// an error the caller may ignore, reads find nothing.
    #[test]
    fn an_unwritable_folder_is_no_cache() {
        let file = std::env::temp_dir().join(format!("tacrom-cache-file-{}", std::process::id()));
        fs::write(&file, b"a file, not a folder").unwrap();
        let s = Store::new(file.join("cache"), 1 << 20);
        assert!(s.write("t", "key", &[1.0]).is_err());
        assert!(s.read("t", "key").is_none());
        let _ = fs::remove_file(&file);
    }

    #[test]
    fn concurrent_writers_of_one_key_leave_a_whole_file() {
        let s = store("race", 1 << 24);
        let data: Vec<f32> = (0..20_000).map(|i| i as f32 * 0.5).collect();
        std::thread::scope(|scope| {
            for _ in 0..4 {
                scope.spawn(|| {
                    for _ in 0..5 {
                        s.write("t", "shared", &data).unwrap();
                        if let Some(back) = s.read("t", "shared") {
                            assert_eq!(back, data);
                        }
                    }
                });
            }
        });
        assert_eq!(s.read("t", "shared").unwrap(), data);
        let leftovers = fs::read_dir(&s.dir)
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
            .count();
        assert_eq!(leftovers, 0);
        let _ = fs::remove_dir_all(&s.dir);
    }
}
