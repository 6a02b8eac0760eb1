//! `.npy` arrays (C order, little-endian) through `npyz`, written atomically.

use std::io::Write as _;
use std::path::Path;

use npyz::WriterBuilder as _;

/// Writes `data` as a C-order `.npy` array of `shape` (its product must be `data.len()`),
/// through a temporary file renamed into place.
pub fn write<T: npyz::AutoSerialize>(
    path: &Path,
    shape: &[usize],
    data: &[T],
) -> std::io::Result<()> {
    write_atomic(path, &to_bytes(shape, data)?)
}

/// The bytes of a C-order `.npy` array of `shape` holding `data` (the shape's product
/// must be `data.len()`).
pub fn to_bytes<T: npyz::AutoSerialize>(shape: &[usize], data: &[T]) -> std::io::Result<Vec<u8>> {
    assert_eq!(
        shape.iter().product::<usize>(),
        data.len(),
        "shape and data disagree"
    );
    let shape: Vec<u64> = shape.iter().map(|&d| d as u64).collect();
    let mut bytes = std::io::Cursor::new(Vec::new());
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&shape)
        .writer(&mut bytes)
        .begin_nd()?;
    w.extend(data.iter())?;
    w.finish()?;
    Ok(bytes.into_inner())
}

/// Reads a C-order `.npy` array of `T`: its shape and values.
pub fn read<T: npyz::Deserialize>(path: &Path) -> Result<(Vec<usize>, Vec<T>), String> {
    from_bytes(&std::fs::read(path).map_err(|e| e.to_string())?)
}

/// A C-order `.npy` array of `T` from its bytes: its shape and values.
pub fn from_bytes<T: npyz::Deserialize>(bytes: &[u8]) -> Result<(Vec<usize>, Vec<T>), String> {
    let file = npyz::NpyFile::new(bytes).map_err(|e| e.to_string())?;
    if file.order() != npyz::Order::C {
        return Err("not a C-order array".to_owned());
    }
    let shape = file.shape().iter().map(|&d| d as usize).collect();
    let data = file.into_vec::<T>().map_err(|e| e.to_string())?;
    Ok((shape, data))
}

/// Writes `bytes` to `path` through a temporary file named for this process, so that
/// processes writing into one folder never rename each other's file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = path.with_extension(format!("tmp-{}", std::process::id()));
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)
}

#[cfg(test)]
mod tests {
    #[test]
    fn arrays_round_trip_and_numpy_headers_are_standard() {
        let dir = std::env::temp_dir().join(format!("tacrom-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.npy");
        let v: Vec<f32> = (0..24).map(|i| i as f32 * 0.5).collect();
        super::write(&path, &[2, 3, 4], &v).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let header = String::from_utf8_lossy(&bytes[..128]);
        assert!(
            header.contains("'descr': '<f4'") && header.contains("'shape': (2, 3, 4,"),
            "{header}"
        );
        assert_eq!(super::read::<f32>(&path).unwrap(), (vec![2, 3, 4], v));
        // The wrong element type is an error, not a reinterpretation.
        assert!(super::read::<f64>(&path).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
