//! The signed singular value decomposition of a deformation gradient, `F = U diag(s) V^T`
//! with `U` and `V` rotations and the last value negative for an inverted `F`: what an
//! isotropic energy's principal form is evaluated at (Newton's method's stresses and
//! tangents, and the relaxation's stress of a material without a closed form).

use nalgebra::{Matrix3, Vector3};

/// `F = U diag(s) V^T` with `U`, `V` proper rotations.
pub(crate) struct SignedSvd {
    pub u: Matrix3<f64>,
    pub s: Vector3<f64>,
    pub v: Matrix3<f64>,
}

impl SignedSvd {
    /// The signed SVD of `f`, with singular values in decreasing order of magnitude (the
    /// last one negative for an inverted `f`): `V` from the symmetric eigenproblem of
    /// `F^T F` by cyclic Jacobi rotations, then `F V = U R` by Givens rotations, so that
    /// `U` and `V` are rotations by construction and `R` is diagonal to round-off
    /// (McAdams et al. 2011 take the same route). `None` when `f` is not finite.
    pub fn of(f: &Matrix3<f64>) -> Option<SignedSvd> {
        if !f.iter().all(|x| x.is_finite()) {
            return None;
        }
        // Far from order one (never in a solve; a guard): the SVD of the scaled matrix.
        let scale = f.amax();
        if !(1e-100..=1e100).contains(&scale) {
            if scale == 0.0 {
                return Some(SignedSvd {
                    u: Matrix3::identity(),
                    s: Vector3::zeros(),
                    v: Matrix3::identity(),
                });
            }
            let mut d = SignedSvd::of(&(f / scale))?;
            d.s *= scale;
            return Some(d);
        }
        let (lambda, mut v) = jacobi_eigen(f.transpose() * f);
        // Decreasing eigenvalues, V a proper rotation.
        let mut order = [0usize, 1, 2];
        for (a, b) in [(0, 1), (1, 2), (0, 1)] {
            if lambda[order[a]] < lambda[order[b]] {
                order.swap(a, b);
            }
        }
        v = Matrix3::from_columns(&[v.column(order[0]), v.column(order[1]), v.column(order[2])]);
        if v.determinant() < 0.0 {
            v.column_mut(2).neg_mut();
        }
        let (u, r) = givens_qr(f * v);
        let mut s = Vector3::new(r[(0, 0)], r[(1, 1)], r[(2, 2)]);
        let mut u = u;
        // Non-negative first two values; the sign of det F on the last. Flipping two
        // columns of U (and the matching values) keeps it a rotation.
        for k in 0..2 {
            if s[k] < 0.0 {
                s[k] = -s[k];
                s[2] = -s[2];
                u.column_mut(k).neg_mut();
                u.column_mut(2).neg_mut();
            }
        }
        Some(SignedSvd { u, s, v })
    }
}

/// Eigenvalues and eigenvectors (columns) of the symmetric `a` by cyclic Jacobi rotations,
/// until the off-diagonal part is below round-off of the diagonal.
fn jacobi_eigen(mut a: Matrix3<f64>) -> (Vector3<f64>, Matrix3<f64>) {
    let mut v = Matrix3::identity();
    for _ in 0..16 {
        let off = a[(0, 1)].powi(2) + a[(0, 2)].powi(2) + a[(1, 2)].powi(2);
        let diag = a[(0, 0)].powi(2) + a[(1, 1)].powi(2) + a[(2, 2)].powi(2);
        if off <= 1e-32 * diag || off == 0.0 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            let apq = a[(p, q)];
            if apq == 0.0 {
                continue;
            }
            let theta = (a[(q, q)] - a[(p, p)]) / (2.0 * apq);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // A <- J^T A J, V <- V J with J the rotation in the (p, q) plane.
            for k in 0..3 {
                let (akp, akq) = (a[(k, p)], a[(k, q)]);
                a[(k, p)] = c * akp - s * akq;
                a[(k, q)] = s * akp + c * akq;
            }
            for k in 0..3 {
                let (apk, aqk) = (a[(p, k)], a[(q, k)]);
                a[(p, k)] = c * apk - s * aqk;
                a[(q, k)] = s * apk + c * aqk;
            }
            for k in 0..3 {
                let (vkp, vkq) = (v[(k, p)], v[(k, q)]);
                v[(k, p)] = c * vkp - s * vkq;
                v[(k, q)] = s * vkp + c * vkq;
            }
        }
    }
    (Vector3::new(a[(0, 0)], a[(1, 1)], a[(2, 2)]), v)
}

/// `b = Q R` with `Q` a rotation (a product of Givens rotations) and `R` upper triangular.
fn givens_qr(b: Matrix3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let mut r = b;
    let mut q = Matrix3::identity();
    for (col, row_a, row_b) in [(0, 0, 1), (0, 0, 2), (1, 1, 2)] {
        let (x, y) = (r[(row_a, col)], r[(row_b, col)]);
        if y == 0.0 {
            continue;
        }
        // Entries within 1e+-100 here (`SignedSvd::of` scales others): no overflow.
        let h = (x * x + y * y).sqrt();
        let (c, s) = (x / h, y / h);
        // Rows row_a, row_b of R <- G R; Q <- Q G^T.
        for k in 0..3 {
            let (ra, rb) = (r[(row_a, k)], r[(row_b, k)]);
            r[(row_a, k)] = c * ra + s * rb;
            r[(row_b, k)] = -s * ra + c * rb;
            let (qa, qb) = (q[(k, row_a)], q[(k, row_b)]);
            q[(k, row_a)] = c * qa + s * qb;
            q[(k, row_b)] = -s * qa + c * qb;
        }
    }
    (q, r)
}

/// Sheared and stretched deformation gradients, `k` growing the shear and twist (the
/// tests' samples here and in `newton/energy.rs`).
#[cfg(test)]
pub(crate) fn sample_f(k: usize) -> Matrix3<f64> {
    let t = k as f64;
    Matrix3::new(
        1.1 + 0.05 * t,
        0.2,
        -0.1,
        0.05 * t,
        0.9,
        0.15,
        -0.2,
        0.1 * t,
        1.05,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The signed SVD reconstructs `F` to round-off with rotations `U`, `V`, values in
    /// decreasing magnitude, only the last negative and only when `det F < 0`, and agrees
    /// with nalgebra's singular values: at rest, for repeated values, rotations, shears,
    /// inversions, a singular `F` and random ones.
    #[test]
    fn signed_svd_reconstructs_f_with_rotations() {
        let mut cases = vec![
            Matrix3::identity(),
            Matrix3::from_diagonal(&Vector3::new(2.0, 2.0, 0.5)),
            Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, 1.0)),
            Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
            Matrix3::new(1.0, 0.3, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
            Matrix3::new(1.0, 2.0, 3.0, 2.0, 4.0, 6.0, 0.5, 0.1, 0.2),
            Matrix3::new(1.0 + 1e-9, 0.0, 0.0, 0.0, 1.0, 1e-12, 0.0, 0.0, 1.0 - 1e-9),
            -Matrix3::identity(),
            Matrix3::new(1e160, 2e159, 0.0, 0.0, 3e158, 0.0, 1e150, 0.0, -1e159),
            Matrix3::new(1e-160, 0.0, 0.0, 0.0, 3e-161, 0.0, 0.0, 1e-170, 2e-161),
            Matrix3::zeros(),
        ];
        let mut state = 99u64;
        for _ in 0..200 {
            cases.push(Matrix3::from_fn(|_, _| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                2.0 * ((state >> 11) as f64 / (1u64 << 53) as f64) - 1.0
            }));
        }
        for k in 0..4 {
            cases.push(sample_f(k));
        }
        for f in cases {
            let d = SignedSvd::of(&f).unwrap();
            let back = d.u * Matrix3::from_diagonal(&d.s) * d.v.transpose();
            let scale = f.norm().max(1e-300);
            assert!((back - f).norm() <= 1e-13 * scale, "{f}: {back}");
            for m in [d.u, d.v] {
                assert!(
                    (m.transpose() * m - Matrix3::identity()).norm() < 1e-13,
                    "{m}"
                );
                assert!((m.determinant() - 1.0).abs() < 1e-13, "{m}");
            }
            assert!(
                d.s[0] >= d.s[1] && d.s[1] >= d.s[2].abs() - 1e-13 * scale,
                "{:?}",
                d.s
            );
            assert!(d.s[0] >= 0.0 && d.s[1] >= 0.0);
            // The determinant and nalgebra's values of the matrix scaled to order one (the
            // huge and tiny cases over- and underflow unscaled).
            let amax = f.amax().max(1e-300);
            if d.s[2] < -1e-13 * scale {
                assert!((f / amax).determinant() < 0.0, "{f}: {:?}", d.s);
            }
            let mut reference = nalgebra::SVD::new(f / amax, false, false).singular_values * amax;
            reference.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
            let abs = d.s.map(f64::abs);
            assert!(
                (abs - reference).norm() <= 1e-12 * scale,
                "{abs} {reference}"
            );
        }
    }
}
