//! Capsule along the local z axis (MuJoCo `capsule`: `size[0]` = radius, `size[1]` = half
//! length of the cylindrical part).

use nalgebra::{Isometry3, Point3, Vector3};

use super::{check_size, convex_lower_surface, Aabb, Chord, GeometryError, PixelGrid, Sdf};

/// The set of points within `radius` of the segment from `(0, 0, -half_length)` to
/// `(0, 0, half_length)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Capsule {
    /// Radius (m).
    pub radius: f64,
    /// Half length of the axis segment (m); the capsule's total length is
    /// `2 * (half_length + radius)`.
    pub half_length: f64,
}

impl Capsule {
    /// A capsule of the given radius and half length (m). See [`Capsule::validate`].
    pub fn new(radius: f64, half_length: f64) -> Self {
        Self {
            radius,
            half_length,
        }
    }

    /// Checks that the sizes are finite and positive (a zero half length is allowed).
    pub fn validate(&self) -> Result<(), GeometryError> {
        check_size("capsule", "radius", self.radius)?;
        if self.half_length.is_finite() && self.half_length >= 0.0 {
            Ok(())
        } else {
            Err(GeometryError::InvalidSize {
                shape: "capsule",
                message: format!(
                    "half_length = {} must be finite and non-negative",
                    self.half_length
                ),
            })
        }
    }

    /// The point of the axis segment nearest to `p`.
    #[inline]
    fn axis_point(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::new(0.0, 0.0, p.z.clamp(-self.half_length, self.half_length))
    }
}

impl Sdf for Capsule {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        (p - self.axis_point(p)).norm() - self.radius
    }

    fn gradient(&self, p: &Point3<f64>) -> Vector3<f64> {
        let v = p - self.axis_point(p);
        let n = v.norm();
        if n > 0.0 {
            v / n
        } else {
            // On the axis: every direction normal to it is as good.
            Vector3::x()
        }
    }

    fn aabb(&self) -> Aabb {
        let r = self.radius;
        let h = self.half_length + r;
        Aabb::new(Point3::new(-r, -r, -h), Point3::new(r, r, h))
    }

    /// Exact: the line's interval in the capsule is the union of its intervals in the two
    /// end spheres and in the finite cylinder between them (all convex, overlapping).
    fn lower_surface(
        &self,
        pose: &Isometry3<f64>,
        grid: &PixelGrid,
        z_bottom: f64,
        z_top: f64,
        zmin: &mut [f64],
    ) {
        let r = self.radius;
        let a = pose * Point3::new(0.0, 0.0, -self.half_length);
        let b = pose * Point3::new(0.0, 0.0, self.half_length);
        let bounds = Aabb::new(a.inf(&b).map(|v| v - r), a.sup(&b).map(|v| v + r));
        let inv = pose.inverse();
        // Local coordinates of the pixel line: o + t d, t the sensor-frame z.
        let ex = inv.rotation * Vector3::x();
        let ey = inv.rotation * Vector3::y();
        let d = inv.rotation * Vector3::z();
        let o0 = inv.translation.vector;
        convex_lower_surface(&bounds, grid, z_bottom, z_top, zmin, |x, y| {
            self.interval(&(o0 + ex * x + ey * y), &d)
        });
    }

    fn chord(&self, o: &Point3<f64>, d: &Vector3<f64>) -> Chord {
        Chord::of(self.interval(&o.coords, d))
    }
}

impl Capsule {
    /// The interval of `t` where `o + t d` (local frame, `d` a unit vector) lies in the
    /// capsule: the union of its intervals in the two end spheres and in the finite
    /// cylinder between them (all convex, overlapping).
    fn interval(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<(f64, f64)> {
        let (r, h) = (self.radius, self.half_length);
        let r2 = r * r;
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        // End spheres, centred at (0, 0, +-h) locally.
        for cz in [-h, h] {
            let oc = Vector3::new(o.x, o.y, o.z - cz);
            let bq = oc.dot(d);
            let s = bq * bq - (oc.norm_squared() - r2);
            if s >= 0.0 {
                let sq = s.sqrt();
                lo = lo.min(-bq - sq);
                hi = hi.max(-bq + sq);
            }
        }
        // Cylindrical part: the finite cylinder's interval.
        if let Some((t0, t1)) = super::Cylinder::new(r, h).interval(o, d) {
            lo = lo.min(t0);
            hi = hi.max(t1);
        }
        (lo <= hi).then_some((lo, hi))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::test_support::{check_chord, check_gradient, check_lower_surface, Rng};

    /// The exact chord agrees with the signed distance along lines of every direction.
    #[test]
    fn the_chord_is_where_the_line_is_inside() {
        let mut rng = Rng::new(44);
        assert!(check_chord(&Capsule::new(0.0015, 0.003), &mut rng, 400, 1e-10) > 100);
    }

    #[test]
    fn distance_matches_closed_form() {
        let c = Capsule::new(0.002, 0.005);
        let cases = [
            (Point3::new(0.0, 0.0, 0.0), -0.002),
            (Point3::new(0.003, 0.0, 0.001), 0.001),
            (Point3::new(0.0, -0.0015, -0.004), -0.0005),
            (Point3::new(0.0, 0.0, 0.008), 0.001),
            (Point3::new(0.0, 0.0, -0.0065), -0.0005),
            (Point3::new(0.003, 0.004, 0.005), 0.003),
            (Point3::new(0.002, 0.0, 0.005), 0.0),
            (Point3::new(0.003, 0.0, 0.009), 0.005 - 0.002),
        ];
        for (p, want) in cases {
            assert!(
                (c.distance(&p) - want).abs() < 1e-15,
                "{p}: {} vs {want}",
                c.distance(&p)
            );
        }
        // Many points: brute force over the segment.
        let mut rng = Rng::new(3);
        for _ in 0..1000 {
            let p = rng.point(0.01);
            let brute = (0..=2000)
                .map(|i| (p - Point3::new(0.0, 0.0, -0.005 + 0.01 * i as f64 / 2000.0)).norm())
                .fold(f64::INFINITY, f64::min)
                - 0.002;
            assert!((c.distance(&p) - brute).abs() < 3e-6);
            assert!(c.distance(&p) <= brute + 1e-15);
        }
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let c = Capsule::new(0.002, 0.005);
        let mut rng = Rng::new(4);
        let mut checked = 0;
        for _ in 0..500 {
            checked += check_gradient(&c, &rng.point(0.01), 1e-5) as usize;
        }
        assert!(checked > 450);
    }

    #[test]
    fn lower_surface_matches_brute_force() {
        let c = Capsule::new(0.002, 0.004);
        let mut rng = Rng::new(5);
        for _ in 0..5 {
            let z = rng.uniform(-0.001, 0.005);
            let pose = rng.pose(z);
            assert!(check_lower_surface(&c, &pose, -0.004, 0.01, 1e-9) > 50);
        }
        // Axis exactly vertical and exactly horizontal.
        let up = Isometry3::translation(0.001, 0.0, 0.002);
        assert!(check_lower_surface(&c, &up, -0.004, 0.01, 1e-9) > 50);
        let flat = Isometry3::new(
            Vector3::new(0.0, 0.001, 0.0),
            Vector3::x() * std::f64::consts::FRAC_PI_2,
        );
        assert!(check_lower_surface(&c, &flat, -0.004, 0.01, 1e-9) > 50);
    }
}
