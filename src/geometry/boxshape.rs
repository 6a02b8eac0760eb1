//! Box centred at the local origin (MuJoCo `box`: `size` = half extents).

use nalgebra::{Isometry3, Point3, Vector3};

use super::{check_size, convex_lower_surface, Aabb, Chord, GeometryError, PixelGrid, Sdf};

/// A box `[-h.x, h.x] x [-h.y, h.y] x [-h.z, h.z]` for half extents `h`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cuboid {
    /// Half extents along local x, y, z (m).
    pub half_extents: Vector3<f64>,
}

impl Cuboid {
    /// A box of the given half extents (m). See [`Cuboid::validate`].
    pub fn new(half_extents: Vector3<f64>) -> Self {
        Self { half_extents }
    }

    /// Checks that the half extents are finite and positive.
    pub fn validate(&self) -> Result<(), GeometryError> {
        for (k, name) in ["half_extents.x", "half_extents.y", "half_extents.z"]
            .iter()
            .enumerate()
        {
            check_size("box", name, self.half_extents[k])?;
        }
        Ok(())
    }
}

#[inline]
fn sign(v: f64) -> f64 {
    if v >= 0.0 {
        1.0
    } else {
        -1.0
    }
}

impl Sdf for Cuboid {
    /// Exact: the norm of the excess over the faces outside, minus the distance to the
    /// nearest face inside.
    fn distance(&self, p: &Point3<f64>) -> f64 {
        let q = p.coords.abs() - self.half_extents;
        let outside = q.sup(&Vector3::zeros()).norm();
        outside + q.max().min(0.0)
    }

    fn gradient(&self, p: &Point3<f64>) -> Vector3<f64> {
        let q = p.coords.abs() - self.half_extents;
        let excess = q.sup(&Vector3::zeros());
        let n = excess.norm();
        if n > 0.0 {
            Vector3::new(
                sign(p.x) * excess.x,
                sign(p.y) * excess.y,
                sign(p.z) * excess.z,
            ) / n
        } else {
            let k = q.imax();
            let mut g = Vector3::zeros();
            g[k] = sign(p[k]);
            g
        }
    }

    fn aabb(&self) -> Aabb {
        Aabb::new(
            Point3::from(-self.half_extents),
            Point3::from(self.half_extents),
        )
    }

    /// Exact: the slab method in the local frame.
    fn lower_surface(
        &self,
        pose: &Isometry3<f64>,
        grid: &PixelGrid,
        z_bottom: f64,
        z_top: f64,
        zmin: &mut [f64],
    ) {
        let bounds = self.aabb().transformed(pose);
        let inv = pose.inverse();
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

impl Cuboid {
    /// The interval of `t` where `o + t d` (local frame) lies in the box: the slabs of the
    /// three axes intersected (an axis the line runs parallel to, a containment test).
    fn interval(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<(f64, f64)> {
        let h = self.half_extents;
        let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
        for k in 0..3 {
            if d[k].abs() <= 1e-300 {
                if o[k].abs() > h[k] {
                    return None;
                }
            } else {
                let s0 = (-h[k] - o[k]) / d[k];
                let s1 = (h[k] - o[k]) / d[k];
                t0 = t0.max(s0.min(s1));
                t1 = t1.min(s0.max(s1));
            }
        }
        (t0 <= t1).then_some((t0, t1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::test_support::{check_chord, check_gradient, check_lower_surface, Rng};

    /// The exact chord agrees with the signed distance along lines of every direction.
    #[test]
    fn the_chord_is_where_the_line_is_inside() {
        let mut rng = Rng::new(42);
        assert!(
            check_chord(
                &Cuboid::new(Vector3::new(0.003, 0.002, 0.004)),
                &mut rng,
                400,
                1e-10
            ) > 100
        );
    }

    fn brute(b: &Cuboid, p: &Point3<f64>) -> f64 {
        // Distance to the nearest point of the box, or minus the distance to the nearest face.
        let h = b.half_extents;
        let c = Point3::from(p.coords.zip_map(&h, |v, e| v.clamp(-e, e)));
        let out = (p - c).norm();
        if out > 0.0 {
            out
        } else {
            -(0..3)
                .map(|k| h[k] - p[k].abs())
                .fold(f64::INFINITY, f64::min)
        }
    }

    #[test]
    fn distance_matches_closed_form() {
        let b = Cuboid::new(Vector3::new(0.001, 0.002, 0.003));
        let cases = [
            (Point3::new(0.0, 0.0, 0.0), -0.001),
            (Point3::new(0.002, 0.0, 0.0), 0.001),
            (Point3::new(0.002, 0.003, 0.0), 2f64.sqrt() * 0.001),
            (Point3::new(0.002, 0.003, 0.004), 3f64.sqrt() * 0.001),
            (Point3::new(0.0, -0.0015, 0.0029), -0.0001),
            (Point3::new(0.001, 0.002, 0.003), 0.0),
        ];
        for (p, want) in cases {
            assert!((b.distance(&p) - want).abs() < 1e-15, "{p}");
        }
        let mut rng = Rng::new(9);
        for _ in 0..2000 {
            let p = rng.point(0.005);
            assert!((b.distance(&p) - brute(&b, &p)).abs() < 1e-15);
        }
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let b = Cuboid::new(Vector3::new(0.001, 0.002, 0.003));
        let mut rng = Rng::new(10);
        let mut checked = 0;
        for _ in 0..500 {
            checked += check_gradient(&b, &rng.point(0.005), 1e-5) as usize;
        }
        assert!(checked > 400, "{checked}");
    }

    #[test]
    fn lower_surface_matches_brute_force() {
        let b = Cuboid::new(Vector3::new(0.002, 0.003, 0.0025));
        let mut rng = Rng::new(11);
        for _ in 0..5 {
            let z = rng.uniform(-0.001, 0.005);
            let pose = rng.pose(z);
            assert!(check_lower_surface(&b, &pose, -0.004, 0.01, 1e-9) > 50);
        }
        // Axis-aligned: the line is parallel to two slabs.
        let aligned = Isometry3::translation(0.0005, -0.0003, 0.001);
        assert!(check_lower_surface(&b, &aligned, -0.004, 0.01, 1e-9) > 50);
    }
}
