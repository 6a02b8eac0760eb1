//! Constitutive models of the elastomer.
//!
//! The transfer kernels need the Kirchhoff stress `tau = P F^T` of each particle (the
//! MLS-MPM force of Hu et al. 2018, Eq. 18, is `f_i = -sum_p V_p tau_p M_p^-1 (x_i - x_p)
//! w_ip`), so that is what a [`ConstitutiveModel`] returns. Moduli are in the solver's
//! internal stress unit (see `mpm/mod.rs`: stresses are divided by the P-wave modulus
//! `lambda + 2 mu`), so every model here works in f32 at values of order one.

use nalgebra::{Matrix3, UnitQuaternion};

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
    let mut lanes_a = [[0.0f32; 1]; 9];
    for (l, v) in lanes_a.iter_mut().zip(a.as_slice()) {
        l[0] = *v;
    }
    let c = q.as_ref().coords;
    let mut lanes_q = [[c[0]], [c[1]], [c[2]], [c[3]]];
    extract_rotation_lanes(&lanes_a, &mut lanes_q, iterations);
    let [[x], [y], [z], [w]] = lanes_q;
    *q = UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(w, x, y, z));
}

/// [`extract_rotation`] on `N` particles at once, one per lane: `a[k][l]` is entry `k` of
/// particle `l`'s matrix in column-major order (`Matrix3::as_slice`), `q[0..4][l]` its
/// quaternion `x, y, z, w`. Every lane does exactly the scalar operations (no operation
/// mixes lanes), so the bits do not depend on how particles are grouped; written as loops
/// over lanes so that the compiler turns them into vector instructions (eight lanes of
/// AVX2 in the solver's AVX2 copy).
#[inline(always)]
pub(crate) fn extract_rotation_lanes<const N: usize>(
    a: &[[f32; N]; 9],
    q: &mut [[f32; N]; 4],
    iterations: usize,
) {
    for _ in 0..iterations {
        for l in 0..N {
            let (x, y, z, w) = (q[0][l], q[1][l], q[2][l], q[3][l]);
            let (x2, y2, z2) = (x + x, y + y, z + z);
            let (xx, yy, zz) = (x * x2, y * y2, z * z2);
            let (xy, xz, yz) = (x * y2, x * z2, y * z2);
            let (wx, wy, wz) = (w * x2, w * y2, w * z2);
            // Columns of R(q).
            let r = [
                [1.0 - yy - zz, xy + wz, xz - wy],
                [xy - wz, 1.0 - xx - zz, yz + wx],
                [xz + wy, yz - wx, 1.0 - xx - yy],
            ];
            let (mut n0, mut n1, mut n2, mut den) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
            for (k, rk) in r.iter().enumerate() {
                let (a0, a1, a2) = (a[3 * k][l], a[3 * k + 1][l], a[3 * k + 2][l]);
                n0 += rk[1] * a2 - rk[2] * a1;
                n1 += rk[2] * a0 - rk[0] * a2;
                n2 += rk[0] * a1 - rk[1] * a0;
                den += rk[0] * a0 + rk[1] * a1 + rk[2] * a2;
            }
            let s = 0.5 / (den.abs() + 1e-9);
            let (ox, oy, oz) = (n0 * s, n1 * s, n2 * s);
            let w2 = ox * ox + oy * oy + oz * oz;
            // A converged or non-finite lane keeps its rotation.
            let step = w2 > 2.5e-15 && w2.is_finite();
            // q + (0, o) q, then normalised.
            let (nx, ny, nz, nw) = (
                x + w * ox + oy * z - oz * y,
                y + w * oy + oz * x - ox * z,
                z + w * oz + ox * y - oy * x,
                w - (ox * x + oy * y + oz * z),
            );
            let inv = 1.0 / (nx * nx + ny * ny + nz * nz + nw * nw).sqrt();
            q[0][l] = if step { nx * inv } else { x };
            q[1][l] = if step { ny * inv } else { y };
            q[2][l] = if step { nz * inv } else { z };
            q[3][l] = if step { nw * inv } else { w };
        }
    }
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

    // Eight lanes give, lane by lane, the bits of the scalar version (also for a
    // non-finite matrix, which leaves its lane's rotation unchanged).
    #[test]
    fn rotation_lanes_match_scalar_bits() {
        let mut mats = Vec::new();
        let mut quats = Vec::new();
        for i in 0..8 {
            let t = i as f32;
            let rot = UnitQuaternion::from_euler_angles(0.1 * t, -0.05 * t, 0.2 - 0.03 * t);
            let s = Matrix3::new(
                1.0 + 0.02 * t,
                0.01,
                0.0,
                0.01,
                0.95,
                0.03 * t,
                0.0,
                0.03 * t,
                1.05,
            );
            let mut f = rot.to_rotation_matrix().matrix() * s;
            if i == 5 {
                f[(1, 2)] = f32::NAN;
            }
            mats.push(f);
            quats.push(UnitQuaternion::from_euler_angles(0.05 * t, 0.0, 0.1));
        }
        let mut a = [[0.0f32; 8]; 9];
        let mut q = [[0.0f32; 8]; 4];
        for l in 0..8 {
            for (k, v) in mats[l].as_slice().iter().enumerate() {
                a[k][l] = *v;
            }
            for k in 0..4 {
                q[k][l] = quats[l].as_ref().coords[k];
            }
        }
        extract_rotation_lanes(&a, &mut q, 3);
        for l in 0..8 {
            let mut s = quats[l];
            extract_rotation(&mats[l], &mut s, 3);
            for k in 0..4 {
                assert_eq!(
                    s.as_ref().coords[k].to_bits(),
                    q[k][l].to_bits(),
                    "lane {l}"
                );
            }
        }
        assert_eq!(q[3][5].to_bits(), quats[5].as_ref().coords[3].to_bits());
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
