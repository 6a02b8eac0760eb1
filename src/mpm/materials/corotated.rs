//! Fixed corotated elasticity (Stomakhin et al. 2012), `psi = mu |F - R|^2 +
//! lambda/2 (J - 1)^2`: the relaxation's Kirchhoff stress and Newton's principal energy.

use nalgebra::{Matrix3, Vector3};

use super::{j_without, ConstitutiveModel, Principal, PAIRS};

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
    const NAME: &'static str = "corotated";
    const USES_ROTATION: bool = true;
    const NEEDS_POSITIVE_STRETCHES: bool = false;

    fn new(mu: f32, lambda: f32) -> Self {
        FixedCorotatedModel { mu, lambda }
    }

    fn moduli(&self) -> (f32, f32) {
        (self.mu, self.lambda)
    }

    /// The energy of the signed singular values `s` (`j` their product) and, with
    /// `derivatives`, its gradient, Hessian and pair eigenvalues, into `out` (zero on entry).
    /// The twist eigenvalue's shape term is left out where `s_i + s_k` vanishes.
    fn principal(
        mu: f64,
        lambda: f64,
        s: &Vector3<f64>,
        j: f64,
        derivatives: bool,
        out: &mut Principal,
    ) {
        out.energy =
            mu * s.map(|x| (x - 1.0) * (x - 1.0)).sum() + 0.5 * lambda * (j - 1.0) * (j - 1.0);
        if !derivatives {
            return;
        }
        for i in 0..3 {
            let others = j_without(s, i);
            out.grad[i] = 2.0 * mu * (s[i] - 1.0) + lambda * (j - 1.0) * others;
            out.hess[(i, i)] = 2.0 * mu + lambda * others * others;
        }
        for (n, &(i, k, l)) in PAIRS.iter().enumerate() {
            let h = lambda * s[l] * (2.0 * j - 1.0);
            out.hess[(i, k)] = h;
            out.hess[(k, i)] = h;
            let sum = s[i] + s[k];
            let twist_shape = if sum > 1e-12 {
                2.0 * mu * (1.0 - 2.0 / sum)
            } else {
                0.0
            };
            out.pairs[n] = (
                2.0 * mu - lambda * (j - 1.0) * s[l],
                twist_shape + lambda * (j - 1.0) * s[l],
            );
        }
    }

    /// The closed form, from the tracked polar rotation `r` (no SVD).
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
