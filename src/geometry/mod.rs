//! Signed distance fields of the rigid indenters.
//!
//! Every shape implements [`Sdf`] in its own local frame (metres, the frame of the MuJoCo
//! geom). [`Placed`] puts a shape into the sensor frame and provides the world-space
//! queries once, through the inverse transform, for every shape.
//!
//! Sign convention: negative inside the solid, positive outside; the gradient is the
//! outward unit normal of the nearest surface point.

use std::fmt::Debug;
use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Vector3};

/// An axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: Point3<f64>,
    /// Upper corner.
    pub max: Point3<f64>,
}

impl Aabb {
    /// The box that holds both corners.
    pub fn new(min: Point3<f64>, max: Point3<f64>) -> Self {
        Self { min, max }
    }

    /// The box of `self` moved by `pose`: the bounds of its eight transformed corners.
    pub fn transformed(&self, pose: &Isometry3<f64>) -> Aabb {
        let mut min = Point3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY);
        let mut max = Point3::new(f64::NEG_INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        for i in 0..8 {
            let c = Point3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            );
            let w = pose * c;
            min = min.inf(&w);
            max = max.sup(&w);
        }
        Aabb { min, max }
    }

    /// Whether the two boxes overlap (touching counts).
    pub fn intersects(&self, other: &Aabb) -> bool {
        self.min.x <= other.max.x
            && other.min.x <= self.max.x
            && self.min.y <= other.max.y
            && other.min.y <= self.max.y
            && self.min.z <= other.max.z
            && other.min.z <= self.max.z
    }

    /// The box grown by `margin` on every side.
    pub fn inflated(&self, margin: f64) -> Aabb {
        let m = Vector3::repeat(margin);
        Aabb {
            min: self.min - m,
            max: self.max + m,
        }
    }
}

/// A regular grid of sample points on the plane z = 0 of the sensor frame: the pixel
/// centres of an image. Row 0 is the +y edge, column 0 the -x edge (the gel seen from the
/// indenter's side, x to the right, y up).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelGrid {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Extent along x covered by the columns (m).
    pub fov_x: f64,
    /// Extent along y covered by the rows (m).
    pub fov_y: f64,
}

impl PixelGrid {
    /// x of the centre of column `col`.
    #[inline]
    pub fn x(&self, col: usize) -> f64 {
        -0.5 * self.fov_x + (col as f64 + 0.5) * self.fov_x / self.width as f64
    }

    /// y of the centre of row `row`.
    #[inline]
    pub fn y(&self, row: usize) -> f64 {
        0.5 * self.fov_y - (row as f64 + 0.5) * self.fov_y / self.height as f64
    }

    /// The column coordinate of `x`: `c` at the centre of column `c`, continuous (the
    /// inverse of [`PixelGrid::x`]).
    #[inline]
    pub fn col_at(&self, x: f64) -> f64 {
        (x + 0.5 * self.fov_x) * self.width as f64 / self.fov_x - 0.5
    }

    /// The row coordinate of `y`: `r` at the centre of row `r`, continuous (the inverse
    /// of [`PixelGrid::y`]).
    #[inline]
    pub fn row_at(&self, y: f64) -> f64 {
        (0.5 * self.fov_y - y) * self.height as f64 / self.fov_y - 0.5
    }

    /// The columns whose centres lie in `[x0, x1]`, as a half-open range.
    pub fn cols_in(&self, x0: f64, x1: f64) -> std::ops::Range<usize> {
        let px = self.fov_x / self.width as f64;
        let lo = ((x0 + 0.5 * self.fov_x) / px - 0.5).ceil().max(0.0);
        let hi = ((x1 + 0.5 * self.fov_x) / px - 0.5).floor() + 1.0;
        clamp_range(lo, hi, self.width)
    }

    /// The rows whose centres lie in `[y0, y1]`, as a half-open range.
    pub fn rows_in(&self, y0: f64, y1: f64) -> std::ops::Range<usize> {
        let py = self.fov_y / self.height as f64;
        let lo = ((0.5 * self.fov_y - y1) / py - 0.5).ceil().max(0.0);
        let hi = ((0.5 * self.fov_y - y0) / py - 0.5).floor() + 1.0;
        clamp_range(lo, hi, self.height)
    }
}

fn clamp_range(lo: f64, hi: f64, n: usize) -> std::ops::Range<usize> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return 0..0;
    }
    let lo = (lo as usize).min(n);
    let hi = (hi.max(0.0) as usize).min(n);
    lo..hi.max(lo)
}

/// Where a line meets a solid ([`Sdf::chord`]), in the line's parameter (m along it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Chord {
    /// The shape has no closed form for it.
    Unknown,
    /// The line misses the solid.
    Miss,
    /// The line is inside the solid for `t` in `[t_in, t_out]`.
    Span(f64, f64),
}

impl Chord {
    /// The chord of an interval `(t_in, t_out)` found by a primitive, `None` a miss.
    pub(crate) fn of(interval: Option<(f64, f64)>) -> Chord {
        match interval {
            Some((a, b)) if a <= b => Chord::Span(a, b),
            _ => Chord::Miss,
        }
    }
}

/// A rigid shape described by its signed distance, in its local frame.
pub trait Sdf: Send + Sync + Debug {
    /// Makes ready now, where that is cheap, what the first distance query would
    /// otherwise compute (a mesh's distance grid kept by an earlier process), so that a
    /// first contact is an ordinary frame; whether the queries are now ready. The exact
    /// shapes need nothing.
    fn prepare(&self) -> bool {
        true
    }

    /// Signed distance from `p` to the surface (m); negative inside.
    fn distance(&self, p: &Point3<f64>) -> f64;

    /// Gradient of the distance at `p`: the outward unit normal of the nearest surface
    /// point. The default uses central differences of [`Sdf::distance`].
    fn gradient(&self, p: &Point3<f64>) -> Vector3<f64> {
        let h = 1e-6;
        let mut g = Vector3::zeros();
        for k in 0..3 {
            let mut a = *p;
            let mut b = *p;
            a[k] += h;
            b[k] -= h;
            g[k] = (self.distance(&a) - self.distance(&b)) / (2.0 * h);
        }
        let n = g.norm();
        if n > 1e-12 && n.is_finite() {
            g / n
        } else {
            Vector3::z()
        }
    }

    /// The distance at `p` and its derivative with respect to `p`. For an exact signed
    /// distance the derivative is the unit normal ([`Sdf::gradient`], the default); a
    /// sampled one overrides it with the derivative of its interpolant, whose length falls
    /// below one near sharp features. An energy minimisation needs this one: a penalty on
    /// the interpolated distance whose gradient used the unit normal would not be the
    /// gradient of the energy it evaluates, and its line search would stall there.
    fn distance_and_slope(&self, p: &Point3<f64>) -> (f64, Vector3<f64>) {
        (self.distance(p), self.gradient(p))
    }

    /// Bounding box of the solid in the local frame.
    fn aabb(&self) -> Aabb;

    /// Where the line `o + t d` (local frame, `d` a unit vector) lies inside the solid
    /// ([`Chord`]). The convex primitives know it exactly; the default, for shapes without
    /// a closed form, is [`Chord::Unknown`] (callers march the signed distance instead).
    fn chord(&self, _o: &Point3<f64>, _d: &Vector3<f64>) -> Chord {
        Chord::Unknown
    }

    /// Lowest surface of the solid seen from below: for every pixel of `grid` whose vertical
    /// line (in the sensor frame) meets the solid with `z < z_top`, lower `zmin[pixel]` to the
    /// smallest z of the solid on that line if it is below the current value. `pose` maps
    /// local to sensor coordinates; `z_bottom` is the lowest z of interest (the gel's
    /// bottom face); `zmin` holds `height * width` values, row-major.
    ///
    /// The default sphere-traces each pixel's line upwards from `z_bottom`; shapes with an
    /// exact or faster answer (meshes: rasterisation) override it.
    fn lower_surface(
        &self,
        pose: &Isometry3<f64>,
        grid: &PixelGrid,
        z_bottom: f64,
        z_top: f64,
        zmin: &mut [f64],
    ) {
        sphere_trace_lower_surface(self, pose, grid, z_bottom, z_top, zmin);
    }
}

/// Upward sphere tracing of the lowest surface point on each pixel's vertical line; the
/// default of [`Sdf::lower_surface`]. Only pixels under the shape's footprint are visited.
pub fn sphere_trace_lower_surface<S: Sdf + ?Sized>(
    shape: &S,
    pose: &Isometry3<f64>,
    grid: &PixelGrid,
    z_bottom: f64,
    z_top: f64,
    zmin: &mut [f64],
) {
    let bb = shape.aabb().transformed(pose);
    if bb.min.z >= z_top || bb.max.z < z_bottom {
        return;
    }
    // Distances smaller than this count as a hit: well below a micrometre.
    const HIT: f64 = 1e-8;
    const MAX_STEPS: usize = 256;
    let inv = pose.inverse();
    let z_start = bb.min.z.max(z_bottom);
    for row in grid.rows_in(bb.min.y, bb.max.y) {
        let y = grid.y(row);
        for col in grid.cols_in(bb.min.x, bb.max.x) {
            let x = grid.x(col);
            let dir = inv.rotation * Vector3::z();
            let mut z = z_start;
            let mut p = inv * Point3::new(x, y, z);
            let limit = zmin[row * grid.width + col].min(z_top).min(bb.max.z);
            for _ in 0..MAX_STEPS {
                if z >= limit {
                    break;
                }
                let d = shape.distance(&p);
                if !d.is_finite() {
                    break;
                }
                if d <= HIT {
                    zmin[row * grid.width + col] = z;
                    break;
                }
                z += d;
                p += dir * d;
            }
        }
    }
}

/// A shape placed in the sensor frame.
#[derive(Clone, Debug)]
pub struct Placed {
    /// The shape, in its local frame.
    pub shape: Arc<dyn Sdf>,
    /// Local-to-sensor transform.
    pub pose: Isometry3<f64>,
}

impl Placed {
    /// Signed distance from a sensor-frame point.
    #[inline]
    pub fn distance(&self, p: &Point3<f64>) -> f64 {
        self.shape.distance(&self.pose.inverse_transform_point(p))
    }

    /// Outward unit normal at a sensor-frame point, in the sensor frame.
    #[inline]
    pub fn gradient(&self, p: &Point3<f64>) -> Vector3<f64> {
        self.pose.rotation * self.shape.gradient(&self.pose.inverse_transform_point(p))
    }

    /// Sensor-frame bounding box.
    pub fn aabb(&self) -> Aabb {
        self.shape.aabb().transformed(&self.pose)
    }

    /// See [`Sdf::lower_surface`].
    pub fn lower_surface(&self, grid: &PixelGrid, z_bottom: f64, z_top: f64, zmin: &mut [f64]) {
        self.shape
            .lower_surface(&self.pose, grid, z_bottom, z_top, zmin);
    }
}

/// Errors raised while building or loading a shape.
#[derive(Debug, thiserror::Error)]
pub enum GeometryError {
    /// A primitive's size is not finite and positive.
    #[error("invalid {shape} size: {message}")]
    InvalidSize {
        /// The kind of shape ("capsule", "box", ...).
        shape: &'static str,
        /// What is wrong.
        message: String,
    },
    /// A mesh vertex has a NaN or infinite coordinate.
    #[error("mesh vertex {index} is not finite: ({x}, {y}, {z})")]
    NonFiniteVertex {
        /// Index of the vertex.
        index: usize,
        /// x coordinate.
        x: f64,
        /// y coordinate.
        y: f64,
        /// z coordinate.
        z: f64,
    },
    /// A face refers to a vertex that does not exist.
    #[error("mesh face {face} refers to vertex {index}, but the mesh has {count} vertices")]
    FaceIndexOutOfRange {
        /// Index of the face.
        face: usize,
        /// The offending vertex index, as given.
        index: i64,
        /// Number of vertices.
        count: usize,
    },
    /// The face array's length is not a multiple of three, or a vertex array's of three.
    #[error("mesh {what} array has {len} entries, not a multiple of 3")]
    BadArrayLength {
        /// "vertex" or "face".
        what: &'static str,
        /// The length given.
        len: usize,
    },
    /// The mesh has no triangle.
    #[error("mesh has no triangles")]
    NoTriangles,
    /// The mesh's bounding box has no volume, or the grid cannot be built.
    #[error("mesh is degenerate: {0}")]
    Degenerate(String),
    /// A mesh file could not be read.
    #[error("cannot read mesh file {}: {source}", path.display())]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A mesh file could be read but not parsed.
    #[error("bad mesh file {}{}: {message}", path.display(), line.map(|l| format!(" (line {l})")).unwrap_or_default())]
    Parse {
        /// The file (`<memory>` for bytes parsed directly).
        path: std::path::PathBuf,
        /// The 1-based line, for text formats.
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
}

/// The lowest point of a convex solid on every pixel's vertical line, given the solid's
/// sensor-frame bounds and a function from a pixel centre `(x, y)` to the interval
/// `[z_in, z_out]` of its vertical line inside the solid (`None` when it misses). Shared by
/// the primitives' [`Sdf::lower_surface`]; see there for the meaning of the arguments.
///
/// A line whose interval lies wholly below `z_bottom` is left alone; one that enters below
/// `z_bottom` and leaves above reports `z_bottom`. Non-finite bounds or intervals change
/// nothing.
pub(crate) fn convex_lower_surface<F>(
    bounds: &Aabb,
    grid: &PixelGrid,
    z_bottom: f64,
    z_top: f64,
    zmin: &mut [f64],
    mut interval: F,
) where
    F: FnMut(f64, f64) -> Option<(f64, f64)>,
{
    let finite = bounds
        .min
        .coords
        .iter()
        .chain(bounds.max.coords.iter())
        .all(|v| v.is_finite());
    if !finite || bounds.min.z >= z_top || bounds.max.z < z_bottom {
        return;
    }
    if zmin.len() < grid.width * grid.height {
        return;
    }
    let px = grid.fov_x / grid.width as f64;
    let x0 = -0.5 * grid.fov_x + 0.5 * px;
    let cols = grid.cols_in(bounds.min.x, bounds.max.x);
    for row in grid.rows_in(bounds.min.y, bounds.max.y) {
        let y = grid.y(row);
        let line = &mut zmin[row * grid.width..(row + 1) * grid.width];
        for col in cols.clone() {
            if let Some((z_in, z_out)) = interval(x0 + col as f64 * px, y) {
                // NaN fails every comparison below and leaves the pixel alone.
                if z_out >= z_bottom {
                    let z = z_in.max(z_bottom);
                    if z < z_top && z < line[col] {
                        line[col] = z;
                    }
                }
            }
        }
    }
}

/// Checks that a primitive's size is finite and positive.
pub(crate) fn check_size(shape: &'static str, name: &str, v: f64) -> Result<(), GeometryError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(GeometryError::InvalidSize {
            shape,
            message: format!("{name} = {v} must be finite and positive"),
        })
    }
}

mod boxshape;
mod capsule;
mod cylinder;
mod ellipsoid;
pub mod io;
mod mesh;
mod sphere;

pub use boxshape::Cuboid;
pub use capsule::Capsule;
pub use cylinder::Cylinder;
pub use ellipsoid::Ellipsoid;
pub use io::{load_mesh, load_obj, load_stl, parse_obj, parse_stl, MeshData};
pub use mesh::{GridStore, MeshSdfOptions, TriMesh};
pub use sphere::Sphere;

#[cfg(test)]
pub(crate) mod test_support;

#[cfg(test)]
mod tests {
    use super::test_support::TEST_GRID;
    use super::*;

    #[test]
    fn pixel_coordinates_invert_pixel_centres() {
        let g = PixelGrid {
            width: 320,
            height: 240,
            fov_x: 0.024,
            fov_y: 0.018,
        };
        for (col, row) in [(0, 0), (319, 239), (17, 200)] {
            assert!((g.col_at(g.x(col)) - col as f64).abs() < 1e-9);
            assert!((g.row_at(g.y(row)) - row as f64).abs() < 1e-9);
        }
        // Row 0 is the +y edge: a point above (larger y) has a smaller row coordinate.
        assert!(g.row_at(0.001) < g.row_at(0.0));
        assert!(g.col_at(0.001) > g.col_at(0.0));
    }

    /// Regression guard: a NaN pose (from a diverged simulation upstream) or a NaN query
    /// point must not panic, and must leave the image untouched or finite.
    #[test]
    fn nan_pose_or_point_does_not_panic_or_poison() {
        let shapes: Vec<Arc<dyn Sdf>> = vec![
            Arc::new(Sphere::new(0.004)),
            Arc::new(Capsule::new(0.002, 0.003)),
            Arc::new(Cylinder::new(0.003, 0.002)),
            Arc::new(Cuboid::new(Vector3::new(0.002, 0.003, 0.001))),
            Arc::new(Ellipsoid::new(Vector3::new(0.004, 0.002, 0.001))),
        ];
        let nan = f64::NAN;
        let poses = [
            Isometry3::translation(nan, 0.0, 0.0),
            Isometry3::translation(0.0, 0.0, nan),
            Isometry3::new(Vector3::zeros(), Vector3::new(nan, 0.0, 0.0)),
            Isometry3::translation(f64::INFINITY, 0.0, 0.0),
        ];
        for shape in &shapes {
            for p in [
                Point3::new(nan, 0.0, 0.0),
                Point3::new(0.0, f64::INFINITY, nan),
            ] {
                let _ = shape.distance(&p);
                let _ = shape.gradient(&p);
            }
            for pose in &poses {
                let mut zmin = vec![1.0; TEST_GRID.width * TEST_GRID.height];
                shape.lower_surface(pose, &TEST_GRID, -0.004, 0.01, &mut zmin);
                assert!(zmin.iter().all(|z| z.is_finite()), "{shape:?} {pose:?}");
                let placed = Placed {
                    shape: shape.clone(),
                    pose: *pose,
                };
                placed.lower_surface(&TEST_GRID, -0.004, 0.01, &mut zmin);
                assert!(zmin.iter().all(|z| z.is_finite()));
            }
            // A short image buffer is ignored, not indexed out of bounds.
            let mut short = vec![1.0; 10];
            shape.lower_surface(&Isometry3::identity(), &TEST_GRID, -0.004, 0.01, &mut short);
        }
    }

    #[test]
    fn invalid_sizes_are_rejected() {
        assert!(Capsule::new(0.001, 0.0).validate().is_ok());
        assert!(Capsule::new(0.0, 0.01).validate().is_err());
        assert!(Cylinder::new(0.01, f64::INFINITY).validate().is_err());
        assert!(Cuboid::new(Vector3::new(0.01, -0.01, 0.01))
            .validate()
            .is_err());
        let e = Ellipsoid::new(Vector3::new(0.01, 0.01, f64::NAN))
            .validate()
            .unwrap_err();
        assert!(e.to_string().contains("semi_axes.z"), "{e}");
    }
}
