//! The gel's materials, one file each, both forms side by side: the f32 Kirchhoff stress
//! the dynamic relaxation's particles use ([`ConstitutiveModel`]) and the f64 energy of the
//! signed singular values of `F`, with its gradient, Hessian and pair eigenvalues, that
//! Newton's method and the linear solver use (`principal`, read by `newton/energy.rs`
//! through the tables below). The two forms differ by design (the relaxation's corotated
//! stress reads the polar rotation it tracks per particle; Newton's reads the signed SVD),
//! so each file holds both rather than one generic over the scalar; a test checks that they
//! agree: the f32 stress is the f64 energy's `P F^T`.
//!
//! Moduli are in the solver's internal stress unit (see `mpm/mod.rs`: stresses are
//! divided by the P-wave modulus `lambda + 2 mu`), so every model here works at values of
//! order one. Both solvers take the gel's `mu` and `lambda` as they are (Newton casts them
//! to f64 and may split `lambda` between particles and cells, which adds).
//!
//! A new material touches:
//! 1. its file here, with both forms (the f32 model implementing [`ConstitutiveModel`];
//!    the f64 `principal`, and a closed-form `energy` where it has one), and its `mod` and
//!    `pub use` lines below;
//! 2. its value of [`Material`] (`params.rs`);
//! 3. its name in `config::MATERIALS` and `attributes::MATERIAL` (checked against each
//!    other by a test; the tests here and in `newton/energy.rs` run every material that
//!    `config::MATERIALS` names);
//! 4. one arm in each table: the tables of `impl Material` below, the relaxation's choice
//!    of model (`solver.rs`, `relax_frame`) and the test's (`kirchhoff` here).
//!
//! Every table is an exhaustive `match`, so the compiler names each arm a new material
//! still lacks.

use nalgebra::{Matrix3, Vector3};

use super::Material;

pub(crate) mod corotated;
pub(crate) mod neohookean;

pub use corotated::FixedCorotatedModel;
pub use neohookean::NeoHookeanModel;

/// A hyperelastic energy density as the relaxation evaluates it, per particle, in f32.
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

/// `psi_hat`, its gradient, its Hessian, and for each pair `(0,1), (0,2), (1,2)` the
/// symmetric and twist eigenvalues.
pub(crate) struct Principal {
    pub(crate) energy: f64,
    pub(crate) grad: Vector3<f64>,
    pub(crate) hess: Matrix3<f64>,
    pub(crate) pairs: [(f64, f64); 3],
}

pub(crate) const PAIRS: [(usize, usize, usize); 3] = [(0, 1, 2), (0, 2, 1), (1, 2, 0)];

/// Product of the singular values other than `i`.
pub(crate) fn j_without(s: &Vector3<f64>, i: usize) -> f64 {
    match i {
        0 => s[1] * s[2],
        1 => s[0] * s[2],
        _ => s[0] * s[1],
    }
}

/// The tables: what each material is to the parts of the solver that are not generic over
/// it, one arm per material.
impl Material {
    /// Whether the relaxation's model reads the polar rotation of `F`
    /// ([`ConstitutiveModel::USES_ROTATION`]), so that the particles track it.
    pub(crate) fn uses_rotation(self) -> bool {
        match self {
            Material::FixedCorotated => FixedCorotatedModel::USES_ROTATION,
            Material::NeoHookean => NeoHookeanModel::USES_ROTATION,
        }
    }

    /// Whether the f64 energy is defined only where every signed singular value of `F` is
    /// positive (`J > 0`).
    pub(crate) fn needs_positive_stretches(self) -> bool {
        match self {
            Material::FixedCorotated => false,
            Material::NeoHookean => true,
        }
    }

    /// The f64 energy at `f` in closed form (`+inf` where it is not defined), or `None`
    /// where the material has none (the energy then comes from [`Material::principal`]
    /// at the signed singular values).
    pub(crate) fn closed_energy(self, mu: f64, lambda: f64, f: &Matrix3<f64>) -> Option<f64> {
        match self {
            Material::FixedCorotated => None,
            Material::NeoHookean => Some(neohookean::energy(mu, lambda, f)),
        }
    }

    /// The f64 energy of the signed singular values `s` (`j` their product) and, with
    /// `derivatives`, its gradient, Hessian and pair eigenvalues, into `out` (zero on
    /// entry).
    pub(crate) fn principal(
        self,
        mu: f64,
        lambda: f64,
        s: &Vector3<f64>,
        j: f64,
        derivatives: bool,
        out: &mut Principal,
    ) {
        match self {
            Material::FixedCorotated => corotated::principal(mu, lambda, s, j, derivatives, out),
            Material::NeoHookean => neohookean::principal(mu, lambda, s, j, derivatives, out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mpm::extract_rotation;
    use crate::mpm::newton::energy::{Density, SignedSvd};
    use nalgebra::UnitQuaternion;

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

    /// Deformation gradients near and far from rest, `det F` from 0.45 to 2.5: stretched,
    /// compressed, sheared, twisted, and mixtures of them (a fixed pseudo-random sequence).
    fn deformations() -> Vec<Matrix3<f64>> {
        let mut out = vec![
            Matrix3::from_diagonal(&Vector3::new(1.3, 0.9, 0.8)),
            Matrix3::from_diagonal(&Vector3::new(0.7, 0.8, 0.8)),
            Matrix3::new(1.0, 0.4, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
            Matrix3::new(1.1, 0.0, 0.3, -0.2, 0.95, 0.0, 0.0, 0.25, 1.05),
        ];
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        while out.len() < 64 {
            let f = Matrix3::identity() + Matrix3::from_fn(|_, _| 0.35 * next());
            if f.determinant() > 0.45 && f.determinant() < 2.5 {
                out.push(f);
            }
        }
        out
    }

    /// The relaxation's f32 Kirchhoff stress of `material`, as `solver::relax_frame`
    /// builds its model.
    fn kirchhoff(
        material: Material,
        mu: f32,
        lambda: f32,
        f: &Matrix3<f32>,
        j: f32,
        r: &Matrix3<f32>,
    ) -> Matrix3<f32> {
        match material {
            Material::FixedCorotated => FixedCorotatedModel { mu, lambda }.kirchhoff(f, j, r),
            Material::NeoHookean => NeoHookeanModel { mu, lambda }.kirchhoff(f, j, r),
        }
    }

    // One material, two forms: the relaxation's f32 Kirchhoff stress is the f64 energy's
    // `P F^T` (Newton's side, `P = U diag(grad) V^T`), at every deformation above, for
    // every material the `material` attribute names. Both sides get the same moduli, as
    // the solvers do (the gel's f32 `mu`, `lambda`; Newton casts them to f64). Tolerance:
    // f32 round-off of stresses of order one, a few ulps (1.2e-7 each) over a dozen
    // operations, plus, for the fixed corotated form, the rotation passed to it in f32
    // (1e-7): 2e-5 of the stress's scale `|tau| + mu + lambda`. And the f64 `P` is the
    // central difference of the f64 energy (step 1e-6: truncation about 1e-12, round-off
    // about 1e-16 / 1e-6 = 1e-10 of energies of order one), to 1e-6 of `1 + |P|`.
    #[test]
    fn each_materials_f32_stress_is_its_f64_energys_gradient() {
        let (mu, lambda) = (0.3f32, 0.45f32);
        let (mu64, lambda64) = (mu as f64, lambda as f64);
        for &(name, material) in crate::config::MATERIALS {
            let density = Density {
                material,
                mu: mu64,
                lambda: lambda64,
            };
            let mut worst = 0.0f64;
            for f in deformations() {
                let p = density.evaluate(&f).expect("defined at det F > 0").stress;
                let tau64 = p * f.transpose();
                let d = SignedSvd::of(&f).unwrap();
                let r = (d.u * d.v.transpose()).cast::<f32>();
                let (f32_, j) = (f.cast::<f32>(), f.determinant() as f32);
                let tau32 = kirchhoff(material, mu, lambda, &f32_, j, &r);
                let scale = tau64.norm() + mu64 + lambda64;
                let err = (tau32.cast::<f64>() - tau64).norm() / scale;
                worst = worst.max(err);
                assert!(
                    err < 2e-5,
                    "{name} at F = {f}: f32 {tau32} against f64 {tau64}"
                );
                let h = 1e-6;
                for a in 0..9 {
                    let (mut fp, mut fm) = (f, f);
                    fp[(a / 3, a % 3)] += h;
                    fm[(a / 3, a % 3)] -= h;
                    let fd = (density.energy(&fp) - density.energy(&fm)) / (2.0 * h);
                    let pa = p[(a / 3, a % 3)];
                    assert!(
                        (fd - pa).abs() < 1e-6 * (1.0 + pa.abs()),
                        "{name} at F = {f}, entry {a}: difference {fd}, P {pa}"
                    );
                }
            }
            assert!(worst > 0.0, "{name}: the two forms are computed apart");
        }
    }

    // The f64 forms' energies: the principal form and Neo-Hookean's closed form agree.
    #[test]
    fn the_principal_energy_is_the_closed_form() {
        let (mu, lambda) = (0.3, 0.45);
        for f in deformations() {
            let d = SignedSvd::of(&f).unwrap();
            let j = d.s[0] * d.s[1] * d.s[2];
            let mut out = Principal {
                energy: 0.0,
                grad: Vector3::zeros(),
                hess: Matrix3::zeros(),
                pairs: [(0.0, 0.0); 3],
            };
            neohookean::principal(mu, lambda, &d.s, j, false, &mut out);
            let closed = neohookean::energy(mu, lambda, &f);
            assert!(
                (out.energy - closed).abs() <= 1e-12 * closed.abs().max(1.0),
                "{f}"
            );
            // Fixed corotated: mu |F - R|^2 + lambda/2 (J - 1)^2 with R = U V^T.
            let r = d.u * d.v.transpose();
            let direct = mu * (f - r).norm_squared() + 0.5 * lambda * (j - 1.0).powi(2);
            corotated::principal(mu, lambda, &d.s, j, false, &mut out);
            assert!(
                (out.energy - direct).abs() <= 1e-12 * direct.abs().max(1.0),
                "{f}"
            );
        }
    }
}
