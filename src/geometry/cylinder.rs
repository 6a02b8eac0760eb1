//! Solid cylinder along the local z axis (MuJoCo `cylinder`: `size[0]` = radius,
//! `size[1]` = half length).

use nalgebra::{Isometry3, Point3, Vector3};

use super::{check_size, convex_lower_surface, Aabb, Chord, GeometryError, PixelGrid, Sdf};

/// A solid cylinder of radius `radius` whose flat faces lie at `z = +-half_length`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cylinder {
    /// Radius (m).
    pub radius: f64,
    /// Half length along z (m).
    pub half_length: f64,
}

impl Cylinder {
    /// A cylinder of the given radius and half length (m). See [`Cylinder::validate`].
    pub fn new(radius: f64, half_length: f64) -> Self {
        Self {
            radius,
            half_length,
        }
    }

    /// Checks that the sizes are finite and positive.
    pub fn validate(&self) -> Result<(), GeometryError> {
        check_size("cylinder", "radius", self.radius)?;
        check_size("cylinder", "half_length", self.half_length)
    }

    /// Radial and axial excess of `p` over the side and the caps, and the radial unit
    /// vector (x when `p` is on the axis).
    #[inline]
    fn parts(&self, p: &Point3<f64>) -> (f64, f64, Vector3<f64>) {
        let rho = p.x.hypot(p.y);
        let radial = if rho > 0.0 {
            Vector3::new(p.x / rho, p.y / rho, 0.0)
        } else {
            Vector3::x()
        };
        (rho - self.radius, p.z.abs() - self.half_length, radial)
    }
}

impl Sdf for Cylinder {
    /// Exact: the distance to the rim outside both the side and the caps, to the nearer of
    /// side and cap elsewhere.
    fn distance(&self, p: &Point3<f64>) -> f64 {
        let (dr, dz, _) = self.parts(p);
        if dr > 0.0 && dz > 0.0 {
            dr.hypot(dz)
        } else {
            dr.max(dz)
        }
    }

    fn gradient(&self, p: &Point3<f64>) -> Vector3<f64> {
        let (dr, dz, radial) = self.parts(p);
        let axial = Vector3::z() * if p.z >= 0.0 { 1.0 } else { -1.0 };
        if dr > 0.0 && dz > 0.0 {
            (radial * dr + axial * dz) / dr.hypot(dz)
        } else if dr > dz {
            radial
        } else {
            axial
        }
    }

    fn aabb(&self) -> Aabb {
        let (r, h) = (self.radius, self.half_length);
        Aabb::new(Point3::new(-r, -r, -h), Point3::new(r, r, h))
    }

    /// Exact: the line's radial interval intersected with its axial slab.
    fn lower_surface(
        &self,
        pose: &Isometry3<f64>,
        grid: &PixelGrid,
        z_bottom: f64,
        z_top: f64,
        zmin: &mut [f64],
    ) {
        let (r, h) = (self.radius, self.half_length);
        let axis = pose.rotation * Vector3::z();
        let a = pose * Point3::new(0.0, 0.0, -h);
        let b = pose * Point3::new(0.0, 0.0, h);
        // A disc of radius r normal to the axis reaches r * sqrt(1 - axis_k^2) along k.
        let ext = axis.map(|v| r * (1.0 - v * v).max(0.0).sqrt());
        let bounds = Aabb::new(a.inf(&b) - ext, a.sup(&b) + ext);
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

impl Cylinder {
    /// The interval of `t` where `o + t d` (local frame) lies in the cylinder: the radial
    /// quadratic's interval intersected with the axial slab.
    pub(super) fn interval(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<(f64, f64)> {
        let (r, h) = (self.radius, self.half_length);
        let qa = d.x * d.x + d.y * d.y;
        let qc = o.x * o.x + o.y * o.y - r * r;
        let (mut t0, mut t1) = if qa <= 1e-300 {
            if qc > 0.0 {
                return None;
            }
            (f64::NEG_INFINITY, f64::INFINITY)
        } else {
            let qb = o.x * d.x + o.y * d.y;
            let s = qb * qb - qa * qc;
            if s < 0.0 {
                return None;
            }
            let sq = s.sqrt();
            ((-qb - sq) / qa, (-qb + sq) / qa)
        };
        if d.z.abs() <= 1e-300 {
            if o.z.abs() > h {
                return None;
            }
        } else {
            let (s0, s1) = ((-h - o.z) / d.z, (h - o.z) / d.z);
            t0 = t0.max(s0.min(s1));
            t1 = t1.min(s0.max(s1));
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
        let mut rng = Rng::new(43);
        assert!(check_chord(&Cylinder::new(0.002, 0.004), &mut rng, 400, 1e-10) > 100);
    }

    #[test]
    fn distance_matches_closed_form() {
        let c = Cylinder::new(0.002, 0.005);
        let cases = [
            (Point3::new(0.0, 0.0, 0.0), -0.002),
            (Point3::new(0.0, 0.0, 0.0045), -0.0005),
            (Point3::new(0.003, 0.0, 0.001), 0.001),
            (Point3::new(0.0, 0.0, -0.007), 0.002),
            (Point3::new(0.0, 0.001, 0.006), 0.001),
            (Point3::new(0.005, 0.0, 0.009), 0.005),
            (Point3::new(0.0, -0.002, -0.005), 0.0),
            (Point3::new(0.0, 0.0019, 0.0049), -0.0001),
        ];
        for (p, want) in cases {
            assert!(
                (c.distance(&p) - want).abs() < 1e-15,
                "{p}: {} vs {want}",
                c.distance(&p)
            );
        }
        // Against the distance to a dense sampling of the surface (side, caps, rim).
        let mut rng = Rng::new(6);
        let mut surface = Vec::new();
        for i in 0..=60 {
            let z = -0.005 + 0.01 * i as f64 / 60.0;
            for k in 0..120 {
                let a = std::f64::consts::TAU * k as f64 / 120.0;
                surface.push(Point3::new(0.002 * a.cos(), 0.002 * a.sin(), z));
            }
        }
        for i in 0..=20 {
            let rr = 0.002 * i as f64 / 20.0;
            for k in 0..120 {
                let a = std::f64::consts::TAU * k as f64 / 120.0;
                surface.push(Point3::new(rr * a.cos(), rr * a.sin(), 0.005));
                surface.push(Point3::new(rr * a.cos(), rr * a.sin(), -0.005));
            }
        }
        for _ in 0..300 {
            let p = rng.point(0.009);
            let brute = surface
                .iter()
                .map(|s| (p - s).norm())
                .fold(f64::INFINITY, f64::min);
            let got = c.distance(&p);
            // Sampling spacing is 1.7e-4 m: the brute force overestimates by at most ~1e-4.
            assert!(
                got.abs() <= brute + 1e-12 && brute - got.abs() < 1.2e-4,
                "{p}: {got} vs {brute}"
            );
            let inside = p.x.hypot(p.y) < 0.002 && p.z.abs() < 0.005;
            assert_eq!(got < 0.0, inside);
        }
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let c = Cylinder::new(0.002, 0.005);
        let mut rng = Rng::new(7);
        let mut checked = 0;
        for _ in 0..500 {
            checked += check_gradient(&c, &rng.point(0.009), 1e-5) as usize;
        }
        assert!(checked > 400, "{checked}");
    }

    #[test]
    fn lower_surface_matches_brute_force() {
        let c = Cylinder::new(0.003, 0.003);
        let mut rng = Rng::new(8);
        for _ in 0..5 {
            let z = rng.uniform(-0.001, 0.005);
            let pose = rng.pose(z);
            assert!(check_lower_surface(&c, &pose, -0.004, 0.01, 1e-9) > 50);
        }
        let up = Isometry3::translation(0.001, 0.0, 0.002);
        assert!(check_lower_surface(&c, &up, -0.004, 0.01, 1e-9) > 50);
        let flat = Isometry3::new(
            Vector3::new(0.0, 0.001, 0.0),
            Vector3::y() * std::f64::consts::FRAC_PI_2,
        );
        assert!(check_lower_surface(&c, &flat, -0.004, 0.01, 1e-9) > 50);
    }
}
