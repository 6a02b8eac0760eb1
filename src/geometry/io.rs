//! Mesh files: STL (binary and ASCII) and Wavefront OBJ.
//!
//! Coordinates are multiplied by a scale factor on loading (the benchmark meshes are in
//! millimetres: pass `1e-3`). STL stores every triangle's corners separately; bitwise-equal
//! corners are merged into one vertex so that the mesh's triangles share edges.
//!
//! Read here rather than by a mesh crate, because the crates' errors say less: on the same
//! bad files `tobj` 4.0 answers "position parse error" and "face vertex index out of
//! bounds" without a line or a value, and loads a two-corner face or a file without faces
//! as an empty mesh; `stl_io` 0.8 answers "failed to fill whole buffer" for a truncated
//! binary STL and "invalid float literal" without a line. This reader names the file, the
//! line and the value (`bad_files_are_errors_naming_the_problem` below), and its parsers
//! are fuzzed (`fuzz/`).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nalgebra::Point3;

use super::{GeometryError, MeshSdfOptions, TriMesh};

/// Vertices and triangles as read from a file, not yet validated.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshData {
    /// Vertices, scaled.
    pub vertices: Vec<Point3<f64>>,
    /// Triangles, indices into `vertices`.
    pub faces: Vec<[u32; 3]>,
}

impl MeshData {
    /// Validates the data and builds its distance grid with `options`.
    pub fn into_trimesh(self, options: &MeshSdfOptions) -> Result<TriMesh, GeometryError> {
        TriMesh::with_options(self.vertices, self.faces, options)
    }
}

impl TriMesh {
    /// Loads an STL or OBJ file (chosen by extension, `.stl` or `.obj`, any case), scales
    /// it and builds the mesh with the default grid options.
    pub fn from_file(path: impl AsRef<Path>, scale: f64) -> Result<TriMesh, GeometryError> {
        load_mesh(path.as_ref(), scale)?.into_trimesh(&MeshSdfOptions::default())
    }
}

/// Loads an STL or OBJ file, chosen by its extension.
pub fn load_mesh(path: &Path, scale: f64) -> Result<MeshData, GeometryError> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("stl") => load_stl(path, scale),
        Some("obj") => load_obj(path, scale),
        _ => Err(parse_error(
            path,
            None,
            "unknown mesh format: expected a .stl or .obj file",
        )),
    }
}

/// Loads a binary or ASCII STL file.
pub fn load_stl(path: &Path, scale: f64) -> Result<MeshData, GeometryError> {
    let bytes = read(path)?;
    parse_stl_at(&bytes, scale, path)
}

/// Loads a Wavefront OBJ file (`v` and `f` lines; polygons are fan-triangulated).
pub fn load_obj(path: &Path, scale: f64) -> Result<MeshData, GeometryError> {
    let bytes = read(path)?;
    parse_obj_at(&bytes, scale, path)
}

/// Parses STL bytes (binary or ASCII); errors name the file as `<memory>`.
pub fn parse_stl(bytes: &[u8], scale: f64) -> Result<MeshData, GeometryError> {
    parse_stl_at(bytes, scale, Path::new("<memory>"))
}

/// Parses OBJ text; errors name the file as `<memory>`.
pub fn parse_obj(bytes: &[u8], scale: f64) -> Result<MeshData, GeometryError> {
    parse_obj_at(bytes, scale, Path::new("<memory>"))
}

fn read(path: &Path) -> Result<Vec<u8>, GeometryError> {
    std::fs::read(path).map_err(|source| GeometryError::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn parse_error(path: &Path, line: Option<usize>, message: impl Into<String>) -> GeometryError {
    GeometryError::Parse {
        path: PathBuf::from(path),
        line,
        message: message.into(),
    }
}

fn check_scale(path: &Path, scale: f64) -> Result<(), GeometryError> {
    if scale.is_finite() && scale > 0.0 {
        Ok(())
    } else {
        Err(parse_error(
            path,
            None,
            format!("scale {scale} must be finite and positive"),
        ))
    }
}

/// Collects corners, merging bitwise-equal ones.
struct Welder {
    ids: HashMap<[u32; 3], u32>,
    data: MeshData,
    scale: f64,
}

impl Welder {
    fn new(scale: f64) -> Self {
        Self {
            ids: HashMap::new(),
            data: MeshData::default(),
            scale,
        }
    }

    fn vertex(&mut self, v: [f32; 3]) -> u32 {
        // -0.0 and 0.0 are one point.
        let key = v.map(|c| (c + 0.0).to_bits());
        let next = self.data.vertices.len() as u32;
        let scale = self.scale;
        let vertices = &mut self.data.vertices;
        *self.ids.entry(key).or_insert_with(|| {
            vertices.push(Point3::new(
                v[0] as f64 * scale,
                v[1] as f64 * scale,
                v[2] as f64 * scale,
            ));
            next
        })
    }
}

fn parse_stl_at(bytes: &[u8], scale: f64, path: &Path) -> Result<MeshData, GeometryError> {
    check_scale(path, scale)?;
    if bytes.is_empty() {
        return Err(parse_error(path, None, "empty file"));
    }
    // A binary file's size is fixed by its triangle count; ASCII files start with "solid"
    // (binary headers sometimes do too, so the size is checked first).
    if bytes.len() >= 84 {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64;
        if 84 + 50 * n == bytes.len() as u64 {
            return parse_binary_stl(bytes, n as usize, scale, path);
        }
    }
    let text_start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    if bytes[text_start..].starts_with(b"solid") {
        return parse_ascii_stl(bytes, scale, path);
    }
    if bytes.len() < 84 {
        return Err(parse_error(
            path,
            None,
            format!(
                "truncated binary STL: {} bytes, the header alone needs 84",
                bytes.len()
            ),
        ));
    }
    let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64;
    Err(parse_error(
        path,
        None,
        format!(
            "binary STL header announces {n} triangles ({} bytes) but the file has {} bytes",
            84 + 50 * n,
            bytes.len()
        ),
    ))
}

fn parse_binary_stl(
    bytes: &[u8],
    n: usize,
    scale: f64,
    path: &Path,
) -> Result<MeshData, GeometryError> {
    if n == 0 {
        return Err(parse_error(path, None, "binary STL has no triangles"));
    }
    let mut w = Welder::new(scale);
    w.data.faces.reserve(n);
    let f32_at =
        |o: usize| f32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    for t in 0..n {
        // 12 bytes of normal (ignored), three corners, 2 bytes of attributes.
        let base = 84 + 50 * t + 12;
        let mut face = [0u32; 3];
        for (k, id) in face.iter_mut().enumerate() {
            let o = base + 12 * k;
            let v = [f32_at(o), f32_at(o + 4), f32_at(o + 8)];
            if !v.iter().all(|c| c.is_finite()) {
                return Err(parse_error(
                    path,
                    None,
                    format!("triangle {t} has a non-finite corner {v:?}"),
                ));
            }
            *id = w.vertex(v);
        }
        w.data.faces.push(face);
    }
    Ok(w.data)
}

fn parse_ascii_stl(bytes: &[u8], scale: f64, path: &Path) -> Result<MeshData, GeometryError> {
    let text = std::str::from_utf8(bytes)
        .map_err(|e| parse_error(path, None, format!("ASCII STL is not UTF-8: {e}")))?;
    let mut w = Welder::new(scale);
    let mut corners: Vec<u32> = Vec::with_capacity(3);
    let mut in_loop = false;
    for (n, line) in text.lines().enumerate() {
        let lineno = Some(n + 1);
        let mut tokens = line.split_whitespace();
        match tokens.next() {
            Some("outer") => {
                in_loop = true;
                corners.clear();
            }
            Some("vertex") => {
                if !in_loop {
                    return Err(parse_error(path, lineno, "vertex outside an 'outer loop'"));
                }
                let mut v = [0f32; 3];
                for c in &mut v {
                    let tok = tokens.next().ok_or_else(|| {
                        parse_error(path, lineno, "vertex needs three coordinates")
                    })?;
                    *c = tok
                        .parse::<f32>()
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| {
                            parse_error(path, lineno, format!("bad coordinate '{tok}'"))
                        })?;
                }
                corners.push(w.vertex(v));
            }
            Some("endloop") => {
                if corners.len() < 3 {
                    return Err(parse_error(
                        path,
                        lineno,
                        format!("facet with {} corners", corners.len()),
                    ));
                }
                for k in 1..corners.len() - 1 {
                    w.data.faces.push([corners[0], corners[k], corners[k + 1]]);
                }
                in_loop = false;
            }
            _ => {}
        }
    }
    if in_loop {
        return Err(parse_error(
            path,
            None,
            "truncated ASCII STL: a facet is not closed by 'endloop'",
        ));
    }
    if w.data.faces.is_empty() {
        return Err(parse_error(path, None, "ASCII STL has no facets"));
    }
    Ok(w.data)
}

fn parse_obj_at(bytes: &[u8], scale: f64, path: &Path) -> Result<MeshData, GeometryError> {
    check_scale(path, scale)?;
    let text = std::str::from_utf8(bytes)
        .map_err(|e| parse_error(path, None, format!("OBJ is not UTF-8: {e}")))?;
    let mut data = MeshData::default();
    let mut polygon: Vec<u32> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let lineno = Some(n + 1);
        let mut tokens = line.split_whitespace();
        match tokens.next() {
            Some("v") => {
                let mut v = [0f64; 3];
                for c in &mut v {
                    let tok = tokens.next().ok_or_else(|| {
                        parse_error(path, lineno, "vertex needs three coordinates")
                    })?;
                    *c = tok
                        .parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| {
                            parse_error(path, lineno, format!("bad coordinate '{tok}'"))
                        })?;
                }
                data.vertices
                    .push(Point3::new(v[0] * scale, v[1] * scale, v[2] * scale));
            }
            Some("f") => {
                polygon.clear();
                for tok in tokens {
                    // "i", "i/t", "i//n" or "i/t/n"; negative indices count from the end.
                    let first = tok.split('/').next().unwrap_or("");
                    let i: i64 = first.parse().map_err(|_| {
                        parse_error(path, lineno, format!("bad face index '{tok}'"))
                    })?;
                    let count = data.vertices.len() as i64;
                    let idx = if i > 0 { i - 1 } else { count + i };
                    if i == 0 || idx < 0 || idx >= count {
                        return Err(parse_error(
                            path,
                            lineno,
                            format!("face index {i} out of range: {count} vertices defined so far"),
                        ));
                    }
                    polygon.push(idx as u32);
                }
                if polygon.len() < 3 {
                    return Err(parse_error(
                        path,
                        lineno,
                        format!("face with {} corners", polygon.len()),
                    ));
                }
                for k in 1..polygon.len() - 1 {
                    data.faces.push([polygon[0], polygon[k], polygon[k + 1]]);
                }
            }
            _ => {}
        }
    }
    if data.faces.is_empty() {
        return Err(parse_error(path, None, "OBJ has no faces"));
    }
    Ok(data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::test_support::pattern;
    use crate::geometry::Sdf;

    #[test]
    fn loads_binary_pattern_and_merges_vertices() {
        let m = load_stl(&pattern("cone.stl"), 1e-3).unwrap();
        let bytes = std::fs::read(pattern("cone.stl")).unwrap();
        assert_eq!(m.faces.len(), (bytes.len() - 84) / 50);
        // A closed triangle mesh has V - E + F = 2 (genus 0): E = 3F/2, so V = F/2 + 2.
        assert_eq!(m.vertices.len(), m.faces.len() / 2 + 2);
        let mesh = m.into_trimesh(&MeshSdfOptions::default()).unwrap();
        assert!(mesh.is_closed());
        let bb = mesh.aabb();
        let ext = bb.max - bb.min;
        assert!(
            (ext.x - 0.016).abs() < 1e-6
                && (ext.y - 0.016).abs() < 1e-6
                && (ext.z - 0.020).abs() < 1e-6,
            "{ext}"
        );
    }

    #[test]
    fn ascii_stl_and_obj_agree_with_binary() {
        let bin = load_stl(&pattern("prism.stl"), 1e-3).unwrap();
        let mut ascii = String::from("solid prism\n");
        let mut obj = String::new();
        for v in &bin.vertices {
            obj += &format!("v {} {} {}\n", v.x * 1e3, v.y * 1e3, v.z * 1e3);
        }
        for f in &bin.faces {
            ascii += "  facet normal 0 0 0\n    outer loop\n";
            for &i in f {
                let v = bin.vertices[i as usize] * 1e3;
                ascii += &format!(
                    "      vertex {} {} {}\n",
                    v.x as f32, v.y as f32, v.z as f32
                );
            }
            ascii += "    endloop\n  endfacet\n";
            obj += &format!(
                "f {}/1/1 {} -{}\n",
                f[0] + 1,
                f[1] + 1,
                bin.vertices.len() as u32 - f[2]
            );
        }
        ascii += "endsolid prism\n";
        let a = parse_stl(ascii.as_bytes(), 1e-3).unwrap();
        let o = parse_obj(obj.as_bytes(), 1e-3).unwrap();
        assert_eq!(a.faces.len(), bin.faces.len());
        assert_eq!(a.vertices.len(), bin.vertices.len());
        assert_eq!(o.faces, bin.faces);
        for (x, y) in o.vertices.iter().zip(&bin.vertices) {
            assert!((x - y).norm() < 1e-9);
        }
        // A quad is split into two triangles.
        let quad = parse_obj(b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n", 1.0).unwrap();
        assert_eq!(quad.faces, vec![[0, 1, 2], [0, 2, 3]]);
    }

    #[test]
    fn bad_files_are_errors_naming_the_problem() {
        let dir = std::env::temp_dir().join(format!("tacrom-geom-io-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let bytes = std::fs::read(pattern("cone.stl")).unwrap();
        let cut = dir.join("truncated.stl");
        std::fs::write(&cut, &bytes[..bytes.len() - 30]).unwrap();
        let e = load_stl(&cut, 1e-3).unwrap_err().to_string();
        assert!(
            e.contains("truncated.stl") && e.contains("announces"),
            "{e}"
        );
        let empty = dir.join("empty.stl");
        std::fs::write(&empty, b"").unwrap();
        let e = load_stl(&empty, 1e-3).unwrap_err().to_string();
        assert!(e.contains("empty.stl") && e.contains("empty file"), "{e}");
        let e = load_mesh(&dir.join("missing.obj"), 1.0).unwrap_err();
        assert!(
            matches!(e, GeometryError::Io { .. }) && e.to_string().contains("missing.obj"),
            "{e}"
        );
        let e = load_mesh(&dir.join("mesh.ply"), 1.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("mesh.ply"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();

        let e = parse_obj(b"v 0 0 0\nv 1 0 0\nf 1 2 3\n", 1.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 3") && e.contains("out of range"), "{e}");
        let e = parse_obj(b"v 0 0 nan\n", 1.0).unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("nan"), "{e}");
        assert!(parse_obj(b"v 0 0 0\n", 1.0).is_err());
        let e = parse_stl(
            b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0",
            1.0,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("line 5"), "{e}");
        let e = parse_stl(
            b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n",
            1.0,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("truncated"), "{e}");
        assert!(parse_stl(&[0u8; 40], 1.0)
            .unwrap_err()
            .to_string()
            .contains("truncated"));
        let mut zero = vec![0u8; 84];
        zero[..5].copy_from_slice(b"solid");
        assert!(parse_stl(&zero, 1.0).is_err());
        assert!(parse_stl(&bytes, f64::NAN).is_err());
        let mut nan = bytes.clone();
        nan[84 + 12..84 + 16].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(parse_stl(&nan, 1.0)
            .unwrap_err()
            .to_string()
            .contains("non-finite"));
    }
}
