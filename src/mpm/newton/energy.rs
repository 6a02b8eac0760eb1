//! Strain energy densities as functions of the signed singular values of `F`, with their
//! first Piola-Kirchhoff stress and a positive semi-definite stress derivative.
//!
//! An isotropic density `psi(F) = psi_hat(sigma)` with `F = U diag(sigma) V^T` (`U`, `V`
//! rotations, the smallest singular value negative for an inverted `F`) has
//! `P = U diag(dpsi_hat) V^T`, and its derivative `dP/dF` splits, in the basis rotated by
//! `U` and `V`, into the 3 x 3 Hessian of `psi_hat` on the diagonal entries and one 2 x 2
//! block per pair `(i, j)` on `(dF_ij, dF_ji)`, whose eigenvalues are
//! `(psi_i - psi_j) / (sigma_i - sigma_j)` (symmetric mode) and
//! `(psi_i + psi_j) / (sigma_i + sigma_j)` (antisymmetric, twist mode) (Teran et al. 2005,
//! "Robust quasistatic finite elements and flesh simulation"). Clamping each eigenvalue at
//! zero gives the closest positive semi-definite derivative, which keeps Newton's
//! direction one of descent. The pair eigenvalues are written in closed form for each
//! density, so that they stay exact when two singular values coincide (at rest).

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use super::super::materials::{Principal, SignedSvd, PAIRS};
use super::super::Material;

/// A material, or a part of one (selective integration against locking evaluates the
/// stiff part of the volume term on other points than the rest).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Density {
    /// Which energy (its f64 form in `mpm/materials/`).
    pub material: Material,
    /// Shear modulus (internal units; 0 leaves the shape term out).
    pub mu: f64,
    /// First Lame parameter (0 leaves the volume term out).
    pub lambda: f64,
}

/// What a density gives at one `F`.
pub(crate) struct Evaluated {
    pub energy: f64,
    /// First Piola-Kirchhoff stress.
    pub stress: Matrix3<f64>,
    /// Projected `dP/dF` as a 9 x 9 matrix on `F` entries in row-major order (`3 a + b`).
    pub tangent: [[f64; 9]; 9],
}

impl Density {
    /// Energy only (`+inf` where the density is not defined, `J <= 0` for Neo-Hookean):
    /// the material's closed form where it has one, else its principal form.
    pub fn energy(&self, f: &Matrix3<f64>) -> f64 {
        match self.material.closed_energy(self.mu, self.lambda, f) {
            Some(e) => e,
            None => match SignedSvd::of(f) {
                Some(d) => self.principal(&d.s, false).energy,
                None => f64::INFINITY,
            },
        }
    }

    /// Energy, stress and projected tangent at `f`; `None` where the density is not
    /// defined.
    pub fn evaluate(&self, f: &Matrix3<f64>) -> Option<Evaluated> {
        let d = SignedSvd::of(f)?;
        if self.material.needs_positive_stretches() && d.s.iter().any(|&x| x <= 0.0) {
            return None;
        }
        let p = self.principal(&d.s, true);
        if !p.energy.is_finite() {
            return None;
        }
        let stress = d.u * Matrix3::from_diagonal(&p.grad) * d.v.transpose();
        let mut tangent = [[0.0; 9]; 9];
        fn add(tangent: &mut [[f64; 9]; 9], lambda: f64, m: &Matrix3<f64>) {
            if lambda <= 0.0 {
                return;
            }
            let v: [f64; 9] = std::array::from_fn(|k| m[(k / 3, k % 3)]);
            for a in 0..9 {
                let la = lambda * v[a];
                for b in 0..9 {
                    tangent[a][b] += la * v[b];
                }
            }
        }
        if p.hess.cholesky().is_some() {
            // Positive definite already (the common case; at rest `2 mu I + lambda 1 1^T`):
            // the block as it is, `sum_ab hess_ab vec(u_a v_a^T) vec(u_b v_b^T)^T`, without
            // an eigendecomposition.
            let m: [[f64; 9]; 3] = std::array::from_fn(|k| {
                let d = d.u.column(k) * d.v.column(k).transpose();
                std::array::from_fn(|e| d[(e / 3, e % 3)])
            });
            for a in 0..3 {
                for b in 0..3 {
                    let h = p.hess[(a, b)];
                    for (row, &ma) in tangent.iter_mut().zip(&m[a]) {
                        let hm = h * ma;
                        for (t, &mb) in row.iter_mut().zip(&m[b]) {
                            *t += hm * mb;
                        }
                    }
                }
            }
        } else {
            let eig = SymmetricEigen::new(p.hess);
            for k in 0..3 {
                let e = eig.eigenvectors.column(k);
                let m =
                    d.u * Matrix3::from_diagonal(&Vector3::new(e[0], e[1], e[2])) * d.v.transpose();
                add(&mut tangent, eig.eigenvalues[k], &m);
            }
        }
        let h = std::f64::consts::FRAC_1_SQRT_2;
        for (&(i, j, _), &(sym, twist)) in PAIRS.iter().zip(&p.pairs) {
            let a = d.u.column(i) * d.v.column(j).transpose();
            let b = d.u.column(j) * d.v.column(i).transpose();
            add(&mut tangent, sym, &((a + b) * h));
            add(&mut tangent, twist, &((a - b) * h));
        }
        Some(Evaluated {
            energy: p.energy,
            stress,
            tangent,
        })
    }

    fn principal(&self, s: &Vector3<f64>, derivatives: bool) -> Principal {
        let j = s[0] * s[1] * s[2];
        let mut out = Principal {
            energy: 0.0,
            grad: Vector3::zeros(),
            hess: Matrix3::zeros(),
            pairs: [(0.0, 0.0); 3],
        };
        self.material
            .principal(self.mu, self.lambda, s, j, derivatives, &mut out);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mpm::materials::svd::sample_f;

    fn densities() -> Vec<Density> {
        let mut out = Vec::new();
        for &(_, material) in crate::config::MATERIALS {
            for (mu, lambda) in [(0.3, 0.4), (0.3, 0.0), (0.0, 5.0)] {
                out.push(Density {
                    material,
                    mu,
                    lambda,
                });
            }
        }
        out
    }

    /// The stress is the derivative of the energy (central differences, relative 1e-6).
    #[test]
    fn stress_is_the_energy_gradient() {
        for d in densities() {
            for k in 0..4 {
                let f = sample_f(k);
                let e = d.evaluate(&f).unwrap();
                for a in 0..9 {
                    let h = 1e-6;
                    let (mut fp, mut fm) = (f, f);
                    fp[(a / 3, a % 3)] += h;
                    fm[(a / 3, a % 3)] -= h;
                    let fd = (d.energy(&fp) - d.energy(&fm)) / (2.0 * h);
                    let p = e.stress[(a / 3, a % 3)];
                    assert!(
                        (fd - p).abs() < 1e-6 * (1.0 + p.abs()),
                        "{d:?} {a}: {fd} {p}"
                    );
                }
            }
        }
    }

    /// Where the exact derivative is positive semi-definite the projection leaves it
    /// alone: the tangent equals the central difference of the stress (relative 1e-5), at
    /// rest for every density and under a moderate stretch for those with a shape term (a
    /// volume term alone is indefinite away from `J = 1`).
    #[test]
    fn tangent_is_the_stress_derivative_where_convex() {
        let rest = Matrix3::identity();
        let stretched = Matrix3::new(1.1, 0.02, 0.0, 0.0, 1.2, 0.03, 0.01, 0.0, 1.3);
        for d in densities() {
            let states: &[Matrix3<f64>] = if d.mu > 0.0 {
                &[rest, stretched]
            } else {
                &[rest]
            };
            for &f in states {
                let e = d.evaluate(&f).unwrap();
                for b in 0..9 {
                    let h = 1e-6;
                    let (mut fp, mut fm) = (f, f);
                    fp[(b / 3, b % 3)] += h;
                    fm[(b / 3, b % 3)] -= h;
                    let (sp, sm) = (d.evaluate(&fp).unwrap(), d.evaluate(&fm).unwrap());
                    for a in 0..9 {
                        let fd =
                            (sp.stress[(a / 3, a % 3)] - sm.stress[(a / 3, a % 3)]) / (2.0 * h);
                        let t = e.tangent[a][b];
                        assert!(
                            (fd - t).abs() < 1e-5 * (1.0 + t.abs()),
                            "{d:?} {f} ({a},{b}): {fd} {t}"
                        );
                    }
                }
            }
        }
    }

    /// Under compression the twist modes of the corotated shape term are negative: the
    /// projection keeps the tangent positive semi-definite (x^T T x >= 0 for random x).
    #[test]
    fn tangent_is_positive_semi_definite_under_compression() {
        let f = Matrix3::new(0.6, 0.1, 0.0, -0.1, 0.5, 0.05, 0.0, 0.0, 0.7);
        for d in densities() {
            let e = d.evaluate(&f).unwrap();
            let mut state = 12345u64;
            for _ in 0..200 {
                let x: [f64; 9] = std::array::from_fn(|_| {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                });
                let q: f64 = (0..9)
                    .map(|a| (0..9).map(|b| x[a] * e.tangent[a][b] * x[b]).sum::<f64>())
                    .sum();
                assert!(q >= -1e-12, "{d:?}: {q}");
            }
        }
    }
}
