//! Sphere centred at the local origin (MuJoCo `sphere`, `size[0]` = radius).

use nalgebra::{Isometry3, Point3, Vector3};

use super::{check_size, Aabb, Chord, GeometryError, PixelGrid, Sdf};

/// A sphere of radius `radius` centred at the local origin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    /// Radius (m).
    pub radius: f64,
}

impl Sphere {
    /// A sphere of the given radius (m). See [`Sphere::validate`].
    pub fn new(radius: f64) -> Self {
        Self { radius }
    }

    /// Checks that the radius is finite and positive.
    pub fn validate(&self) -> Result<(), GeometryError> {
        check_size("sphere", "radius", self.radius)
    }
}

impl Sdf for Sphere {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        p.coords.norm() - self.radius
    }

    fn gradient(&self, p: &Point3<f64>) -> Vector3<f64> {
        let n = p.coords.norm();
        if n > 0.0 {
            p.coords / n
        } else {
            Vector3::z()
        }
    }

    fn aabb(&self) -> Aabb {
        let r = Vector3::repeat(self.radius);
        Aabb::new(Point3::from(-r), Point3::from(r))
    }

    /// Exact: `|o + t d| = r`, a quadratic in `t`.
    fn chord(&self, o: &Point3<f64>, d: &Vector3<f64>) -> Chord {
        let b = o.coords.dot(d);
        let s = b * b - (o.coords.norm_squared() - self.radius * self.radius);
        Chord::of((s >= 0.0).then(|| (-b - s.sqrt(), -b + s.sqrt())))
    }

    /// Exact: the vertical line at horizontal distance `rho` from the centre enters at
    /// `c_z - sqrt(r^2 - rho^2)`.
    fn lower_surface(
        &self,
        pose: &Isometry3<f64>,
        grid: &PixelGrid,
        z_bottom: f64,
        z_top: f64,
        zmin: &mut [f64],
    ) {
        let c = pose.translation.vector;
        let r = self.radius;
        let r2 = r * r;
        // Only the cap below z_top matters: its footprint is a disc of radius `reach`.
        let below = (c.z - z_top).max(0.0);
        let reach2 = r2 - below * below;
        if reach2.is_nan()
            || reach2 <= 0.0
            || c.z - r >= z_top
            || c.z + r < z_bottom
            || zmin.len() < grid.width * grid.height
        {
            return;
        }
        let reach = reach2.sqrt();
        for row in grid.rows_in(c.y - reach, c.y + reach) {
            let dy = grid.y(row) - c.y;
            let half = (reach2 - dy * dy).max(0.0).sqrt();
            let line = &mut zmin[row * grid.width..(row + 1) * grid.width];
            for col in grid.cols_in(c.x - half, c.x + half) {
                let dx = grid.x(col) - c.x;
                let s = r2 - dx * dx - dy * dy;
                if s >= 0.0 {
                    let h = s.sqrt();
                    // As in `convex_lower_surface`: skip chords wholly below z_bottom.
                    if c.z + h >= z_bottom {
                        let z = (c.z - h).max(z_bottom);
                        if z < z_top && z < line[col] {
                            line[col] = z;
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::test_support::{check_chord, check_gradient, check_lower_surface, Rng};

    /// The exact chord agrees with the signed distance along lines of every direction.
    #[test]
    fn the_chord_is_where_the_line_is_inside() {
        let mut rng = Rng::new(41);
        assert!(check_chord(&Sphere::new(0.003), &mut rng, 400, 1e-10) > 100);
    }

    #[test]
    fn distance_is_norm_minus_radius() {
        let s = Sphere::new(0.003);
        assert_eq!(s.distance(&Point3::origin()), -0.003);
        assert!((s.distance(&Point3::new(0.0, 0.004, 0.0)) - 0.001).abs() < 1e-15);
        assert!(s.distance(&Point3::new(0.003, 0.0, 0.0)).abs() < 1e-15);
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let s = Sphere::new(0.003);
        let mut rng = Rng::new(1);
        for _ in 0..200 {
            let p = rng.point(0.006);
            if p.coords.norm() > 1e-4 {
                assert!(check_gradient(&s, &p, 1e-5));
            }
        }
    }

    #[test]
    fn lower_surface_matches_brute_force() {
        let s = Sphere::new(0.004);
        let mut rng = Rng::new(2);
        for _ in 0..4 {
            let z = rng.uniform(-0.001, 0.004);
            let pose = rng.pose(z);
            assert!(check_lower_surface(&s, &pose, -0.004, 0.01, 1e-9) > 100);
        }
        // Partly below the gel's bottom face: those lines report z_bottom.
        let pose = Isometry3::translation(0.0, 0.0, -0.004);
        assert!(check_lower_surface(&s, &pose, -0.004, 0.01, 1e-9) > 100);
        // Only a cap below z_top = 0: the footprint is cut to the cap's disc.
        let pose = Isometry3::translation(0.001, -0.0005, 0.003);
        assert!(check_lower_surface(&s, &pose, -0.004, 0.0, 1e-9) > 100);
    }

    #[test]
    fn validate_rejects_bad_radius() {
        assert!(Sphere::new(0.01).validate().is_ok());
        assert!(Sphere::new(-1.0).validate().is_err());
        assert!(Sphere::new(f64::NAN).validate().is_err());
    }
}
