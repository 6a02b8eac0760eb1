//! Helpers shared by the geometry unit tests: a small deterministic random generator,
//! brute-force references and the location of the shared test data.

use std::path::PathBuf;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use super::{PixelGrid, Sdf, TriMesh};

/// `/work/shared` as seen from the crate: `../shared` beside the checkout when it exists
/// (the main crate), `/work/shared` otherwise (scratch crates elsewhere).
pub fn shared_dir() -> PathBuf {
    let beside = crate::checkout_root().join("../shared");
    if beside.is_dir() {
        beside
    } else {
        PathBuf::from("/work/shared")
    }
}

/// A pattern mesh of the benchmark (millimetres).
pub fn pattern(name: &str) -> PathBuf {
    shared_dir().join("indenters/patterns").join(name)
}

/// xorshift64*: deterministic, good enough for test points.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    pub fn next_f64(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let v = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        (v >> 11) as f64 / (1u64 << 53) as f64
    }

    pub fn uniform(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.next_f64()
    }

    pub fn point(&mut self, half: f64) -> Point3<f64> {
        Point3::new(
            self.uniform(-half, half),
            self.uniform(-half, half),
            self.uniform(-half, half),
        )
    }

    pub fn rotation(&mut self) -> UnitQuaternion<f64> {
        let axis = Vector3::new(
            self.uniform(-1.0, 1.0),
            self.uniform(-1.0, 1.0),
            self.uniform(-1.0, 1.0),
        );
        let angle = self.uniform(-std::f64::consts::PI, std::f64::consts::PI);
        UnitQuaternion::from_scaled_axis(axis.normalize() * angle)
    }

    pub fn pose(&mut self, z: f64) -> Isometry3<f64> {
        let rot = self.rotation();
        Isometry3::from_parts(
            Translation3::new(self.uniform(-0.004, 0.004), self.uniform(-0.003, 0.003), z),
            rot,
        )
    }
}

/// The image used by the `lower_surface` tests: coarser than the sensor's for speed.
pub const TEST_GRID: PixelGrid = PixelGrid {
    width: 80,
    height: 60,
    fov_x: 0.024,
    fov_y: 0.018,
};

/// Brute-force lowest point of `shape` (placed by `pose`) on the vertical line through
/// `(x, y)`, between `z_bottom` and `z_top`: sampling of the distance, then bisection.
/// Samples are `step` apart where the shape is nearer than `step`, and half the distance
/// apart further out: the shapes' distances are exact (each shape's own tests), so no
/// crossing lies within it, and the half leaves a margin for rounding.
pub fn brute_lowest(
    shape: &dyn Sdf,
    pose: &Isometry3<f64>,
    x: f64,
    y: f64,
    z_bottom: f64,
    z_top: f64,
    step: f64,
) -> Option<f64> {
    let d = |z: f64| shape.distance(&pose.inverse_transform_point(&Point3::new(x, y, z)));
    let mut z0 = z_bottom;
    let mut d0 = d(z0);
    if d0 <= 0.0 {
        return Some(z_bottom);
    }
    while z0 < z_top {
        let z1 = (z0 + step.max(0.5 * d0)).min(z_top);
        let d1 = d(z1);
        if d1 <= 0.0 {
            let (mut a, mut b) = (z0, z1);
            for _ in 0..60 {
                let m = 0.5 * (a + b);
                if d(m) <= 0.0 {
                    b = m;
                } else {
                    a = m;
                }
            }
            return Some(b);
        }
        (z0, d0) = (z1, d1);
    }
    None
}

/// Compares `shape.lower_surface` with [`brute_lowest`] on [`TEST_GRID`] for `pose`;
/// returns the number of pixels hit. Lines that graze the solid (a chord shorter than the
/// sampling step) may be seen only by the exact method; they must then lie on the surface.
pub fn check_lower_surface(
    shape: &dyn Sdf,
    pose: &Isometry3<f64>,
    z_bottom: f64,
    z_top: f64,
    tol: f64,
) -> usize {
    let grid = TEST_GRID;
    let mut zmin = vec![f64::INFINITY; grid.width * grid.height];
    shape.lower_surface(pose, &grid, z_bottom, z_top, &mut zmin);
    let step = 2e-5;
    let mut hits = 0;
    for row in 0..grid.height {
        for col in 0..grid.width {
            let (x, y) = (grid.x(col), grid.y(row));
            let got = zmin[row * grid.width + col];
            let want = brute_lowest(shape, pose, x, y, z_bottom, z_top, step);
            match want {
                Some(w) => {
                    hits += 1;
                    assert!(
                        (got - w).abs() <= tol,
                        "{shape:?} pose {pose:?}: pixel ({row},{col}) got {got}, brute force {w}"
                    );
                }
                None => {
                    if got.is_finite() {
                        let d =
                            shape.distance(&pose.inverse_transform_point(&Point3::new(x, y, got)));
                        assert!(
                            d.abs() < 1e-6 && got < z_top,
                            "{shape:?}: pixel ({row},{col}) got {got} (distance {d}) where brute force saw nothing"
                        );
                    }
                }
            }
        }
    }
    hits
}

/// Checks that `shape.gradient` is a unit vector and matches central differences of
/// `shape.distance` at `p`. Returns false (without failing) where the distance is not
/// differentiable (the finite-difference gradient is not of unit length).
pub fn check_gradient(shape: &dyn Sdf, p: &Point3<f64>, tol: f64) -> bool {
    let g = shape.gradient(p);
    assert!(
        (g.norm() - 1.0).abs() < 1e-9,
        "{shape:?}: gradient {g} at {p} is not unit"
    );
    let h = 1e-7;
    let mut fd = Vector3::zeros();
    for k in 0..3 {
        let (mut a, mut b) = (*p, *p);
        a[k] += h;
        b[k] -= h;
        fd[k] = (shape.distance(&a) - shape.distance(&b)) / (2.0 * h);
    }
    if (fd.norm() - 1.0).abs() > 1e-4 {
        return false;
    }
    assert!(
        (g - fd).norm() < tol,
        "{shape:?}: gradient {g} at {p}, finite differences {fd}"
    );
    true
}

/// Checks `shape.chord` on `lines` random lines through the neighbourhood of the solid
/// (origins in its box grown by half, directions uniform, and the axes' own directions,
/// which the primitives treat apart): the chord's ends lie on the surface (the exact
/// signed distance within `tol`), samples of the line inside the chord are inside the
/// solid and samples outside it outside (each by more than `tol` from its ends), and a
/// line reported missing has no sample inside. Returns the number of lines that met it.
pub fn check_chord(shape: &dyn Sdf, rng: &mut Rng, lines: usize, tol: f64) -> usize {
    let b = shape.aabb();
    let half = (b.max - b.min) * 0.75;
    let centre = nalgebra::center(&b.min, &b.max);
    let reach = 2.0 * half.norm();
    let mut met = 0;
    for n in 0..lines {
        let o = centre + Vector3::from_fn(|k, _| rng.uniform(-half[k], half[k]));
        let d = match n % 4 {
            0 => Vector3::ith(n / 4 % 3, 1.0),
            _ => rng.rotation() * Vector3::z(),
        };
        let at = |t: f64| shape.distance(&(o + d * t));
        let span = match shape.chord(&o, &d) {
            super::Chord::Span(a, b) => Some((a, b)),
            super::Chord::Miss => None,
            super::Chord::Unknown => panic!("{shape:?} has no chord"),
        };
        if let Some((a, b)) = span {
            met += 1;
            assert!(
                at(a).abs() <= tol && at(b).abs() <= tol,
                "{shape:?}: ends {a} {b}"
            );
        }
        for k in 0..=400 {
            let t = -reach + 2.0 * reach * k as f64 / 400.0;
            let d = at(t);
            match span {
                Some((a, b)) if t > a + tol && t < b - tol => {
                    assert!(d <= tol, "{shape:?}: t {t} in ({a}, {b}) at distance {d}")
                }
                Some((a, b)) if t < a - tol || t > b + tol => {
                    assert!(
                        d >= -tol,
                        "{shape:?}: t {t} out of ({a}, {b}) at distance {d}"
                    )
                }
                Some(_) => {}
                None => assert!(d >= -tol, "{shape:?}: a miss with t {t} inside ({d})"),
            }
        }
    }
    met
}

/// A closed box mesh of half-extents `h` (m), 12 triangles wound outwards.
pub fn box_mesh(h: Vector3<f64>) -> TriMesh {
    let v: Vec<Point3<f64>> = (0..8)
        .map(|i| {
            Point3::new(
                if i & 1 == 0 { -h.x } else { h.x },
                if i & 2 == 0 { -h.y } else { h.y },
                if i & 4 == 0 { -h.z } else { h.z },
            )
        })
        .collect();
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let faces = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    TriMesh::new(v, faces).unwrap()
}
