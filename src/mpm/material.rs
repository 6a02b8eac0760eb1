//! Constitutive models of the elastomer.
//!
//! The transfer kernels need the Kirchhoff stress `tau = P F^T` of each particle (the
//! MLS-MPM force of Hu et al. 2018, Eq. 18, is `f_i = -sum_p V_p tau_p M_p^-1 (x_i - x_p)
//! w_ip`), so that is what a [`ConstitutiveModel`] returns. Moduli are in the solver's
//! internal stress unit (see `mpm/mod.rs`: stresses are divided by the P-wave modulus
//! `lambda + 2 mu`), so every model here works in f32 at values of order one.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

/// A hyperelastic energy density, evaluated per particle.
pub trait ConstitutiveModel: Send + Sync {
    /// Whether [`ConstitutiveModel::kirchhoff`] needs the rotation `R` of the polar
    /// decomposition `F = R S`; when false the solver neither tracks nor passes it.
    const USES_ROTATION: bool;

    /// Kirchhoff stress `tau = P(F) F^T` at deformation gradient `f`, with `j` the volume
    /// ratio that the volumetric (pressure) term uses (`det f`, or its kernel-smoothed
    /// value against volumetric locking; `j > 0`, clamped by the solver) and rotation `r`
    /// (the polar factor of `f` when [`ConstitutiveModel::USES_ROTATION`], otherwise the
    /// identity).
    fn kirchhoff(&self, f: &Matrix3<f32>, j: f32, r: &Matrix3<f32>) -> Matrix3<f32>;
}

/// Fixed corotated elasticity (Stomakhin et al. 2012, Eq. 2):
/// `psi = mu |F - R|^2 + lambda/2 (J - 1)^2`, so
/// `tau = 2 mu (F - R) F^T + lambda (J - 1) J I`.
#[derive(Clone, Copy, Debug)]
pub struct FixedCorotatedModel {
    /// Shear modulus.
    pub mu: f32,
    /// First Lame parameter.
    pub lambda: f32,
}

impl ConstitutiveModel for FixedCorotatedModel {
    const USES_ROTATION: bool = true;

    #[inline(always)]
    fn kirchhoff(&self, f: &Matrix3<f32>, j: f32, r: &Matrix3<f32>) -> Matrix3<f32> {
        let mut tau = (f - r) * f.transpose() * (2.0 * self.mu);
        let vol = self.lambda * (j - 1.0) * j;
        tau.m11 += vol;
        tau.m22 += vol;
        tau.m33 += vol;
        tau
    }
}

/// Compressible Neo-Hookean elasticity (Bonet and Wood, Eq. 6.28):
/// `psi = mu/2 (tr(F^T F) - 3) - mu ln J + lambda/2 (ln J)^2`, so
/// `tau = mu (F F^T - I) + lambda ln(J) I`.
///
/// Guard: `ln J` diverges as `J -> 0`; the solver clamps `J` to `[J_MIN, J_MAX]`
/// (see [`super::J_MIN`]) before calling, and this model clamps again so that it never
/// sees `J <= 0` whatever the caller does.
#[derive(Clone, Copy, Debug)]
pub struct NeoHookeanModel {
    /// Shear modulus.
    pub mu: f32,
    /// First Lame parameter.
    pub lambda: f32,
}

impl ConstitutiveModel for NeoHookeanModel {
    const USES_ROTATION: bool = false;

    #[inline(always)]
    fn kirchhoff(&self, f: &Matrix3<f32>, j: f32, _r: &Matrix3<f32>) -> Matrix3<f32> {
        let j = j.max(super::J_MIN as f32);
        let mut tau = f * f.transpose() * self.mu;
        let diag = self.lambda * j.ln() - self.mu;
        tau.m11 += diag;
        tau.m22 += diag;
        tau.m33 += diag;
        tau
    }
}

/// Updates `q` towards the rotation of the polar decomposition of `a`, by the iteration of
/// Mueller et al. 2016 ("A robust method to extract the rotational part of deformations",
/// Eq. 7): `omega = sum_i r_i x a_i / (|sum_i r_i . a_i| + eps)`, `q <- exp(omega) q`,
/// where `r_i`, `a_i` are the columns of `R(q)` and `a`. Warm-started from the previous
/// step's rotation, one or two iterations per time step suffice because `F` changes by
/// `dt C F` only. Non-finite input leaves `q` unchanged.
///
/// The exponential is taken to first order, `exp(omega) ~ normalize(1, omega / 2)` (a
/// rotation by `2 atan(|omega| / 2)` about `omega`): no trigonometry, the same fixed point
/// (`omega = 0`), and for the small `omega` of a warm start the same step to third order.
#[inline]
pub fn extract_rotation(a: &Matrix3<f32>, q: &mut UnitQuaternion<f32>, iterations: usize) {
    let c = q.as_ref().coords;
    let (mut x, mut y, mut z, mut w) = (c[0], c[1], c[2], c[3]);
    for _ in 0..iterations {
        let (x2, y2, z2) = (x + x, y + y, z + z);
        let (xx, yy, zz) = (x * x2, y * y2, z * z2);
        let (xy, xz, yz) = (x * y2, x * z2, y * z2);
        let (wx, wy, wz) = (w * x2, w * y2, w * z2);
        let r = [
            Vector3::new(1.0 - yy - zz, xy + wz, xz - wy),
            Vector3::new(xy - wz, 1.0 - xx - zz, yz + wx),
            Vector3::new(xz + wy, yz - wx, 1.0 - xx - yy),
        ];
        let mut num = Vector3::zeros();
        let mut den = 0.0f32;
        for (k, rk) in r.iter().enumerate() {
            let ak = a.column(k);
            num += rk.cross(&ak);
            den += rk.dot(&ak);
        }
        let o = num * (0.5 / (den.abs() + 1e-9));
        let w2 = o.norm_squared();
        if !(w2 > 2.5e-15 && w2.is_finite()) {
            break;
        }
        // q + (0, o) q, then normalised.
        let (nx, ny, nz, nw) = (
            x + w * o.x + o.y * z - o.z * y,
            y + w * o.y + o.z * x - o.x * z,
            z + w * o.z + o.x * y - o.y * x,
            w - (o.x * x + o.y * y + o.z * z),
        );
        let inv = 1.0 / (nx * nx + ny * ny + nz * nz + nw * nw).sqrt();
        (x, y, z, w) = (nx * inv, ny * inv, nz * inv, nw * inv);
    }
    *q = UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(w, x, y, z));
}

#[cfg(test)]
mod tests {
    use super::*;

    // The polar rotation of a rotated stretch is the rotation, from a cold start.
    #[test]
    fn rotation_extraction_recovers_rotation() {
        let rot = UnitQuaternion::from_euler_angles(0.3f32, -0.2, 0.5);
        let s = Matrix3::new(1.1f32, 0.05, 0.0, 0.05, 0.9, 0.02, 0.0, 0.02, 1.05);
        let f = rot.to_rotation_matrix().matrix() * s;
        let mut q = UnitQuaternion::identity();
        extract_rotation(&f, &mut q, 30);
        assert!(q.angle_to(&rot) < 1e-4, "angle {}", q.angle_to(&rot));
    }

    // Both models are stress free at rest and agree to first order (same mu, lambda).
    #[test]
    fn models_agree_for_small_strain() {
        let co = FixedCorotatedModel {
            mu: 0.3,
            lambda: 0.4,
        };
        let nh = NeoHookeanModel {
            mu: 0.3,
            lambda: 0.4,
        };
        let i = Matrix3::identity();
        assert!(co.kirchhoff(&i, 1.0, &i).norm() < 1e-7);
        assert!(nh.kirchhoff(&i, 1.0, &i).norm() < 1e-7);
        let e = 1e-3f32;
        let f = Matrix3::new(
            1.0 + e,
            0.5 * e,
            0.0,
            0.5 * e,
            1.0,
            0.0,
            0.0,
            0.0,
            1.0 - 0.3 * e,
        );
        let mut q = UnitQuaternion::identity();
        extract_rotation(&f, &mut q, 20);
        let r = *q.to_rotation_matrix().matrix();
        let j = f.determinant();
        let d = co.kirchhoff(&f, j, &r) - nh.kirchhoff(&f, j, &r);
        assert!(d.norm() < 1e-2 * e, "difference {}", d.norm());
    }
}
