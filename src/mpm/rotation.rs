//! The rotation of a deformation gradient's polar decomposition, warm-started per
//! particle: what the fixed corotated material ([`super::materials`]) reads.

use nalgebra::{Matrix3, UnitQuaternion};

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
}
