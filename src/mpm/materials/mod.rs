//! The gel's materials: one type each, one file each, named once in the list of
//! `materials!` below, which makes [`Material`] and every table that dispatches on it.
//!
//! A material is its energy, an isotropic function of the signed singular values of `F`
//! ([`ConstitutiveModel::principal`], f64, with its gradient, Hessian and pair
//! eigenvalues): Newton's method and the linear solver read that form (`newton/energy.rs`),
//! and the dynamic relaxation's per-particle f32 Kirchhoff stress is derived from it
//! ([`derived_kirchhoff`]: `tau = U diag(s_i dpsi/ds_i) U^T`, one signed SVD per particle and
//! step). A material may also give its stress in closed form
//! ([`ConstitutiveModel::kirchhoff`]; both shipped ones do: the fixed corotated one from the
//! polar rotation the particles track, without an SVD), and a closed form of its energy;
//! tests check, for every material in the list, that the closed stress is the derived one
//! and that both are the energy's gradient.
//!
//! Moduli are in the solver's internal stress unit (see `mpm/mod.rs`: stresses are
//! divided by the P-wave modulus `lambda + 2 mu`), so every model here works at values of
//! order one. Both solvers take the gel's `mu` and `lambda` as they are (Newton casts them
//! to f64 and may split `lambda` between particles and cells, which adds).
//!
//! A new material touches its file here (a type implementing [`ConstitutiveModel`]: its
//! name, the `material` attribute's value, and its principal energy) and two lines below:
//! its `mod` line and its line in the list of `materials!`. The attribute's values, the
//! relaxation's choice of model and Newton's energy follow from the list (the README's
//! attribute table is regenerated from them by `tacrom doc-tables --write`, which a test
//! checks); the tests here and in `newton/energy.rs` run every material in it.

use nalgebra::{Matrix3, Vector3};

pub(crate) mod corotated;
pub(crate) mod neohookean;
pub(crate) mod svd;

pub use corotated::FixedCorotatedModel;
pub use neohookean::NeoHookeanModel;
pub(crate) use svd::SignedSvd;

/// One material: a hyperelastic energy density, in the forms the solvers evaluate.
pub trait ConstitutiveModel: Copy + Send + Sync + 'static {
    /// The `material` attribute's value that names it.
    const NAME: &'static str;

    /// Whether [`ConstitutiveModel::kirchhoff`] needs the rotation `R` of the polar
    /// decomposition `F = R S`; when false the solver neither tracks nor passes it.
    const USES_ROTATION: bool;

    /// Whether the energy is defined only where every signed singular value of `F` is
    /// positive (`J > 0`).
    const NEEDS_POSITIVE_STRETCHES: bool;

    /// The model with shear modulus `mu` and first Lame parameter `lambda` (internal units).
    fn new(mu: f32, lambda: f32) -> Self;

    /// Its `(mu, lambda)`.
    fn moduli(&self) -> (f32, f32);

    /// The energy of the signed singular values `s` (`j` the volume ratio its volume term
    /// reads: their product, or a smoothed value of it) and, with `derivatives`, its
    /// gradient, Hessian and pair eigenvalues, into `out` (zero on entry).
    fn principal(
        mu: f64,
        lambda: f64,
        s: &Vector3<f64>,
        j: f64,
        derivatives: bool,
        out: &mut Principal,
    );

    /// The energy at `f` in closed form (`+inf` where it is not defined), or `None` where
    /// the material has none (the energy then comes from [`ConstitutiveModel::principal`]
    /// at the signed singular values).
    fn closed_energy(_mu: f64, _lambda: f64, _f: &Matrix3<f64>) -> Option<f64> {
        None
    }

    /// Kirchhoff stress `tau = P(F) F^T` at deformation gradient `f`, with `j` the volume
    /// ratio that the volumetric (pressure) term uses (`det f`, or its kernel-smoothed
    /// value against volumetric locking; `j > 0`, clamped by the solver) and rotation `r`
    /// (the polar factor of `f` when [`ConstitutiveModel::USES_ROTATION`], otherwise the
    /// identity). By default derived from the principal energy ([`derived_kirchhoff`]).
    fn kirchhoff(&self, f: &Matrix3<f32>, j: f32, _r: &Matrix3<f32>) -> Matrix3<f32> {
        derived_kirchhoff::<Self>(self.moduli(), f, j)
    }
}

/// `tau = U diag(s_i dpsi/ds_i) U^T` at `F = U diag(s) V^T` (since `P = U diag(dpsi/ds)
/// V^T`), from the material's principal energy with the volume ratio `j`, evaluated in f64.
/// Where the energy needs positive stretches, an inverted `F` is read as its mirror image
/// (the stretches' magnitudes) and `j` is held at least `J_MIN`, as the closed forms of such
/// materials read `F F^T` and the clamped `J`; a non-finite `F` gives zero stress.
pub fn derived_kirchhoff<M: ConstitutiveModel>(
    (mu, lambda): (f32, f32),
    f: &Matrix3<f32>,
    j: f32,
) -> Matrix3<f32> {
    let Some(mut d) = SignedSvd::of(&f.cast::<f64>()) else {
        return Matrix3::zeros();
    };
    let mut j = f64::from(j);
    if M::NEEDS_POSITIVE_STRETCHES {
        d.s = d.s.map(|x| x.abs().max(1e-150));
        j = j.max(super::J_MIN);
    }
    let mut out = Principal::default();
    M::principal(f64::from(mu), f64::from(lambda), &d.s, j, true, &mut out);
    let diagonal = out.grad.component_mul(&d.s);
    (d.u * Matrix3::from_diagonal(&diagonal) * d.u.transpose()).cast::<f32>()
}

/// `psi_hat`, its gradient, its Hessian, and for each pair `(0,1), (0,2), (1,2)` the
/// symmetric and twist eigenvalues.
#[derive(Clone, Copy, Debug, Default)]
pub struct Principal {
    /// The energy density.
    pub energy: f64,
    /// Its gradient in the signed singular values.
    pub grad: Vector3<f64>,
    /// Its Hessian in them.
    pub hess: Matrix3<f64>,
    /// Each pair's symmetric and twist eigenvalues of `dP/dF`.
    pub pairs: [(f64, f64); 3],
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

/// What runs with a material's model, whichever it is: [`Material::with_model`] calls
/// [`WithModel::run`] with the model of the gel's material.
pub(crate) trait WithModel {
    /// What it gives.
    type Out;
    /// Runs with `model`.
    fn run<M: ConstitutiveModel>(self, model: M) -> Self::Out;
}

/// The list of materials: each line a value of [`Material`] (with its doc) and the type
/// that is the material. Generates the enum and its tables, each an exhaustive `match`.
macro_rules! materials {
    ($($(#[$meta:meta])* $variant:ident => $model:ty,)+) => {
        /// Elastic energy of the gel: the types of `mpm/materials/`, by the `material`
        /// attribute's value.
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
        pub enum Material {
            $($(#[$meta])* $variant,)+
        }

        impl Material {
            /// Every material, with the `material` attribute's value naming it.
            pub const NAMED: &'static [(&'static str, Material)] =
                &[$((<$model as ConstitutiveModel>::NAME, Material::$variant),)+];

            /// The `material` attribute's values.
            pub const NAMES: &'static [&'static str] =
                &[$(<$model as ConstitutiveModel>::NAME,)+];

            /// The `material` attribute's value naming it.
            pub fn name(self) -> &'static str {
                match self {
                    $(Material::$variant => <$model as ConstitutiveModel>::NAME,)+
                }
            }

            /// Runs `what` with this material's model of moduli `mu`, `lambda`.
            pub(crate) fn with_model<W: WithModel>(self, mu: f32, lambda: f32, what: W) -> W::Out {
                match self {
                    $(Material::$variant => what.run(<$model as ConstitutiveModel>::new(mu, lambda)),)+
                }
            }

            /// Whether the relaxation's model reads the polar rotation of `F`
            /// ([`ConstitutiveModel::USES_ROTATION`]), so that the particles track it.
            pub(crate) fn uses_rotation(self) -> bool {
                match self {
                    $(Material::$variant => <$model as ConstitutiveModel>::USES_ROTATION,)+
                }
            }

            /// [`ConstitutiveModel::NEEDS_POSITIVE_STRETCHES`].
            pub(crate) fn needs_positive_stretches(self) -> bool {
                match self {
                    $(Material::$variant => <$model as ConstitutiveModel>::NEEDS_POSITIVE_STRETCHES,)+
                }
            }

            /// [`ConstitutiveModel::closed_energy`].
            pub(crate) fn closed_energy(self, mu: f64, lambda: f64, f: &Matrix3<f64>) -> Option<f64> {
                match self {
                    $(Material::$variant => <$model as ConstitutiveModel>::closed_energy(mu, lambda, f),)+
                }
            }

            /// [`ConstitutiveModel::principal`].
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
                    $(Material::$variant => <$model as ConstitutiveModel>::principal(mu, lambda, s, j, derivatives, out),)+
                }
            }
        }
    };
}

materials! {
    /// Fixed corotated (Stomakhin et al. 2012); the usual MPM choice for soft solids.
    #[default]
    FixedCorotated => FixedCorotatedModel,
    /// Compressible Neo-Hookean, with `det F` guarded (see [`NeoHookeanModel`]).
    NeoHookean => NeoHookeanModel,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mpm::extract_rotation;
    use crate::mpm::newton::energy::Density;
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
    /// builds its model: its closed form, or with `derived` the one derived from its
    /// principal energy ([`derived_kirchhoff`]).
    fn kirchhoff(
        material: Material,
        derived: bool,
        (mu, lambda): (f32, f32),
        f: &Matrix3<f32>,
        j: f32,
        r: &Matrix3<f32>,
    ) -> Matrix3<f32> {
        struct Stress<'a> {
            derived: bool,
            f: &'a Matrix3<f32>,
            j: f32,
            r: &'a Matrix3<f32>,
        }
        impl WithModel for Stress<'_> {
            type Out = Matrix3<f32>;
            fn run<M: ConstitutiveModel>(self, model: M) -> Matrix3<f32> {
                if self.derived {
                    derived_kirchhoff::<M>(model.moduli(), self.f, self.j)
                } else {
                    model.kirchhoff(self.f, self.j, self.r)
                }
            }
        }
        material.with_model(mu, lambda, Stress { derived, f, j, r })
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
                let tau32 = kirchhoff(material, false, (mu, lambda), &f32_, j, &r);
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
            let mut out = Principal::default();
            NeoHookeanModel::principal(mu, lambda, &d.s, j, false, &mut out);
            let closed = NeoHookeanModel::closed_energy(mu, lambda, &f).unwrap();
            assert!(
                (out.energy - closed).abs() <= 1e-12 * closed.abs().max(1.0),
                "{f}"
            );
            // Fixed corotated: mu |F - R|^2 + lambda/2 (J - 1)^2 with R = U V^T.
            let r = d.u * d.v.transpose();
            let direct = mu * (f - r).norm_squared() + 0.5 * lambda * (j - 1.0).powi(2);
            FixedCorotatedModel::principal(mu, lambda, &d.s, j, false, &mut out);
            assert!(
                (out.energy - direct).abs() <= 1e-12 * direct.abs().max(1.0),
                "{f}"
            );
        }
    }

    // A material needs only its principal energy: the stress derived from it is the closed
    // form, for every material in the list, at every deformation above (`j = det F`, as
    // the closed forms are written; the volume term of a derived stress reads `j` where
    // the material's principal form does), and at an inverted `F` for a material defined
    // there. Tolerance: the derived stress goes through an f64 SVD of the f32 `F` and one
    // cast to f32, the closed one through a dozen f32 operations and, for the corotated
    // form, the rotation in f32 (as above): 2e-5 of the stress's scale. An inverted `F`
    // gives a finite stress for every material (one defined only at positive stretches
    // reads its mirror image).
    #[test]
    fn the_stress_derived_from_the_energy_is_the_closed_form() {
        let moduli = (0.3f32, 0.45f32);
        let scale0 = f64::from(moduli.0 + moduli.1);
        let inverted = Matrix3::new(0.8, 0.1, 0.0, 0.0, 0.9, 0.05, 0.0, 0.0, -0.1);
        for &(name, material) in Material::NAMED {
            let mut cases = deformations();
            if !material.needs_positive_stretches() {
                cases.push(inverted);
            }
            for f in cases {
                let d = SignedSvd::of(&f).unwrap();
                let r = (d.u * d.v.transpose()).cast::<f32>();
                let (f, j) = (f.cast::<f32>(), f.determinant() as f32);
                let closed = kirchhoff(material, false, moduli, &f, j, &r);
                let derived = kirchhoff(material, true, moduli, &f, j, &r);
                let err =
                    (closed - derived).cast::<f64>().norm() / (f64::from(closed.norm()) + scale0);
                assert!(
                    err < 2e-5,
                    "{name} at F = {f}: closed {closed}, derived {derived}"
                );
            }
            let f = inverted.cast::<f32>();
            let tau = kirchhoff(material, true, moduli, &f, 0.05, &Matrix3::identity());
            assert!(tau.iter().all(|x| x.is_finite()), "{name}: {tau}");
        }
    }
}
