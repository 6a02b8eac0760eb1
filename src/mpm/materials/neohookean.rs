//! Compressible Neo-Hookean elasticity (Bonet and Wood), `psi = mu/2 (|F|^2 - 3) - mu ln J +
//! lambda/2 (ln J)^2`: the relaxation's Kirchhoff stress and Newton's principal energy.

use nalgebra::{Matrix3, Vector3};

use super::{ConstitutiveModel, Principal, PAIRS};

/// Compressible Neo-Hookean elasticity (Bonet and Wood, Eq. 6.28):
/// `psi = mu/2 (tr(F^T F) - 3) - mu ln J + lambda/2 (ln J)^2`, so
/// `tau = mu (F F^T - I) + lambda ln(J) I`.
///
/// Guard: `ln J` diverges as `J -> 0`; the solver clamps `J` to `[J_MIN, J_MAX]`
/// (see [`crate::mpm::J_MIN`]) before calling, and this model clamps again so that it never
/// sees `J <= 0` whatever the caller does.
#[derive(Clone, Copy, Debug)]
pub struct NeoHookeanModel {
    /// Shear modulus.
    pub mu: f32,
    /// First Lame parameter.
    pub lambda: f32,
}

impl ConstitutiveModel for NeoHookeanModel {
    const NAME: &'static str = "neohookean";
    const USES_ROTATION: bool = false;
    const NEEDS_POSITIVE_STRETCHES: bool = true;

    fn new(mu: f32, lambda: f32) -> Self {
        NeoHookeanModel { mu, lambda }
    }

    fn moduli(&self) -> (f32, f32) {
        (self.mu, self.lambda)
    }

    /// The energy of the signed singular values `s` (all positive; `j` their product) and,
    /// with `derivatives`, its gradient, Hessian and pair eigenvalues, into `out` (zero on
    /// entry).
    fn principal(
        mu: f64,
        lambda: f64,
        s: &Vector3<f64>,
        j: f64,
        derivatives: bool,
        out: &mut Principal,
    ) {
        let lj = j.ln();
        out.energy = 0.5 * mu * (s.norm_squared() - 3.0) - mu * lj + 0.5 * lambda * lj * lj;
        if !derivatives {
            return;
        }
        for i in 0..3 {
            out.grad[i] = mu * s[i] + (lambda * lj - mu) / s[i];
            out.hess[(i, i)] = mu + (mu + lambda * (1.0 - lj)) / (s[i] * s[i]);
        }
        for (n, &(i, k, _)) in PAIRS.iter().enumerate() {
            let h = lambda / (s[i] * s[k]);
            out.hess[(i, k)] = h;
            out.hess[(k, i)] = h;
            let q = (mu - lambda * lj) / (s[i] * s[k]);
            out.pairs[n] = (mu + q, mu - q);
        }
    }

    /// The energy at `f` in closed form (`+inf` where `J <= 0` or not finite).
    fn closed_energy(mu: f64, lambda: f64, f: &Matrix3<f64>) -> Option<f64> {
        let j = f.determinant();
        if j <= 0.0 || !j.is_finite() {
            return Some(f64::INFINITY);
        }
        let lj = j.ln();
        Some(0.5 * mu * (f.norm_squared() - 3.0) - mu * lj + 0.5 * lambda * lj * lj)
    }

    /// The closed form, without an SVD.
    #[inline(always)]
    fn kirchhoff(&self, f: &Matrix3<f32>, j: f32, _r: &Matrix3<f32>) -> Matrix3<f32> {
        let j = j.max(crate::mpm::J_MIN as f32);
        let mut tau = f * f.transpose() * self.mu;
        let diag = self.lambda * j.ln() - self.mu;
        tau.m11 += diag;
        tau.m22 += diag;
        tau.m33 += diag;
        tau
    }
}
