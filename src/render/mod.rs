//! From the solved gel to what the sensor reports. Knows nothing of MuJoCo.
//!
//! [`DepthRule`] is the one definition of how a surface indentation becomes a depth pixel:
//! every physics mode, the reduced-order model's input features and the training data
//! generator go through it, so the contract between the coarse model, the decoder and the
//! data it was trained on lives in one place. [`rgb`] shades the depth image into the
//! colour image of a GelSight-type sensor, with the built-in optics or a calibrated
//! gradient-to-colour table ([`calibrated`]); [`markers`] places the markers printed on the
//! gel and writes where the camera sees them; [`refraction`] is the camera under the gel:
//! which surface point a pinhole camera's pixel sees through the refracting gel, and the
//! images resampled there.

use crate::geometry::Placed;

pub mod calibrated;
pub mod markers;
pub mod refraction;
pub mod rgb;

/// Values per pixel of a colour image (`rgb` and the calibrated optics): red, green,
/// blue.
pub const CHANNELS: usize = 3;

/// The top of the scale of a colour image's values (8-bit: 0 black, 255 full scale).
pub const FULL_SCALE: f64 = 255.0;

/// The contact problem's bounds on the surface indentation of a gel of thickness `T`
/// pressed by a set of indenters, and the rule that applies them.
///
/// * **Below**: the surface cannot pass into an indenter, so where one reaches below the
///   undeformed face the depth is at least its penetration (the rigid geometry is the
///   ground truth in contact).
/// * **Above**: under compressive contact the displacement of an elastic layer peaks in the
///   contact region, where it equals the penetration; no point sinks below the deepest
///   indenter point (bounded conservatively by the lowest corner of its bounding box).
/// * Always within `[0, T]`; a non-finite gel value gives the rigid penetration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthRule {
    thickness: f64,
    reach: f64,
}

impl DepthRule {
    /// The rule for a gel of thickness `thickness` (m) pressed by `indenters` (sensor frame).
    pub fn new(thickness: f64, indenters: &[Placed]) -> Self {
        let reach = indenters
            .iter()
            .map(|p| -p.aabb().min.z)
            .filter(|r| r.is_finite())
            .fold(0.0, f64::max)
            .min(thickness);
        Self { thickness, reach }
    }

    /// The rule for a gel of thickness `thickness` whose deepest indenter point is known
    /// only through the rigid penetrations `penetration` sampled on a lattice (stored
    /// training pairs): their largest value, which can fall short of the true reach by
    /// the lattice's sampling of the indenter's lowest point.
    pub fn from_penetration(thickness: f64, penetration: &[f64]) -> Self {
        let reach = penetration
            .iter()
            .copied()
            .filter(|p| p.is_finite())
            .fold(0.0, f64::max)
            .min(thickness);
        Self { thickness, reach }
    }

    /// The gel's thickness (m).
    pub fn thickness(&self) -> f64 {
        self.thickness
    }

    /// How deep the deepest indenter reaches below the undeformed face (m, in `[0, T]`).
    pub fn reach(&self) -> f64 {
        self.reach
    }

    /// Rigid penetration (m) where the lowest indenter surface is at sensor-frame height
    /// `zmin` (`+inf` where none).
    pub fn penetration(&self, zmin: f64) -> f64 {
        if zmin.is_finite() {
            (-zmin).clamp(0.0, self.thickness)
        } else {
            0.0
        }
    }

    /// The depth of a surface point whose gel indentation is `gel` and rigid penetration
    /// `penetration` (m).
    pub fn depth(&self, gel: f64, penetration: f64) -> f64 {
        let gel = if gel.is_finite() {
            gel.min(self.reach)
        } else {
            0.0
        };
        gel.max(penetration).clamp(0.0, self.thickness)
    }

    /// Applies the rule in place to gel indentations `depth` with rigid penetrations
    /// `penetration`; returns how far the deepest gel value lay below the reach bound
    /// before it was applied (m, 0 when none did): a diagnostic of the model's physics.
    pub fn apply(&self, depth: &mut [f64], penetration: &[f64]) -> f64 {
        let mut excess: f64 = 0.0;
        for (d, &p) in depth.iter_mut().zip(penetration) {
            if d.is_finite() {
                excess = excess.max(*d - self.reach);
            }
            *d = self.depth(*d, p);
        }
        excess
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use nalgebra::Isometry3;

    use super::*;
    use crate::geometry::Sphere;

    fn sphere_at(depth: f64) -> Placed {
        let r = 0.005;
        Placed {
            shape: Arc::new(Sphere::new(r)),
            pose: Isometry3::translation(0.0, 0.0, r - depth),
        }
    }

    #[test]
    fn depth_is_bounded_by_penetration_below_and_reach_above() {
        let rule = DepthRule::new(0.004, &[sphere_at(0.5e-3)]);
        assert!((rule.reach() - 0.5e-3).abs() < 1e-12);
        // The gel sank below the deepest indenter point: capped there.
        assert_eq!(rule.depth(0.7e-3, 0.2e-3), rule.reach());
        // The gel lies above the indenter surface: raised to it.
        assert_eq!(rule.depth(0.1e-3, 0.2e-3), 0.2e-3);
        // In between: the gel's own value.
        assert_eq!(rule.depth(0.3e-3, 0.2e-3), 0.3e-3);
        // Not finite: the rigid penetration; negative: zero.
        assert_eq!(rule.depth(f64::NAN, 0.2e-3), 0.2e-3);
        assert_eq!(rule.depth(-1e-3, 0.0), 0.0);
    }

    #[test]
    fn nothing_pressing_means_a_flat_surface() {
        let rule = DepthRule::new(0.004, &[]);
        assert_eq!(rule.reach(), 0.0);
        assert_eq!(rule.depth(1e-4, 0.0), 0.0);
        let mut d = vec![1e-4, 2e-4];
        let excess = rule.apply(&mut d, &[0.0, 0.0]);
        assert_eq!(d, vec![0.0, 0.0]);
        assert!((excess - 2e-4).abs() < 1e-15);
    }

    #[test]
    fn reach_never_exceeds_the_gel() {
        let rule = DepthRule::new(0.004, &[sphere_at(0.01)]);
        assert_eq!(rule.reach(), 0.004);
        assert_eq!(rule.penetration(-0.02), 0.004);
        assert_eq!(rule.penetration(f64::INFINITY), 0.0);
    }
}
