//! The analytic contact force that validates the gel: a rigid sphere on a bonded elastic
//! layer.

/// Force (N) of a frictionless rigid sphere of radius `r` pressed `d` into an elastic layer
/// of thickness `h`, Young's modulus `e` and Poisson's ratio `nu`, bonded to a rigid base:
/// Hertz's `(4 E* / 3) R^(1/2) d^(3/2)`, `E* = E / (1 - nu^2)`, times the bonded-layer
/// correction of Dimitriadis et al. 2002 (Biophys. J. 82, Eq. 12), a polynomial in
/// `c = sqrt(R d) / h`. For `nu = 0.43` the bracket is
/// `1 + 1.0108 c + 1.0216 c^2 + 0.4642 c^3 - 0.2491 c^4`; on the 4 mm gel the layer is 1.2
/// to 1.6 times stiffer than a half-space for `d` in `[0.1, 0.5]` mm.
pub fn hertz_bonded(e: f64, nu: f64, r: f64, d: f64, h: f64) -> f64 {
    use std::f64::consts::PI;
    let es = e / (1.0 - nu * nu);
    let a0 = bonded_a0(nu);
    let b0 = (0.6387 - 1.0277 * nu + 1.5164 * nu * nu) / (1.0 - nu);
    let c = (r * d).sqrt() / h;
    let bracket = 1.0 - 2.0 * a0 / PI * c + 4.0 * a0 * a0 / (PI * PI) * c * c
        - 8.0 / PI.powi(3) * (a0.powi(3) + 4.0 * PI * PI * b0 / 15.0) * c.powi(3)
        + 16.0 * a0 / PI.powi(4) * (a0.powi(3) + 3.0 * PI * PI * b0 / 5.0) * c.powi(4);
    4.0 * es / 3.0 * r.sqrt() * d.powf(1.5) * bracket
}

/// Dimitriadis et al.'s `alpha_0` of a layer bonded to its base with Poisson's ratio `nu`.
fn bonded_a0(nu: f64) -> f64 {
    -(1.2876 - 1.4678 * nu + 1.3442 * nu * nu) / (1.0 - nu)
}

/// The first-order coefficient `beta` of the bonded layer's stiffening, `1 + beta a / h`
/// for a contact of radius `a` on a layer of thickness `h` (`beta = -2 alpha_0 / pi`
/// of Dimitriadis et al. 2002; 1.01 at `nu = 0.43`): to first order the layer takes
/// `beta / (2 E* h)` off a small contact's half-space compliance `1 / (2 E* a)`.
pub fn bonded_layer_slope(nu: f64) -> f64 {
    -2.0 * bonded_a0(nu) / std::f64::consts::PI
}

/// Force (N) of a frictionless rigid cone of semi-vertical angle `alpha` (rad, axis to
/// flank) pressed `d` into an elastic half-space of Young's modulus `e` and Poisson's
/// ratio `nu` (Sneddon 1965): `(2 / pi) E* tan(alpha) d^2`, contact radius
/// `(2 / pi) tan(alpha) d`. No layer correction: on the 4 mm gel a 45-degree cone pressed
/// 0.4 mm has a contact radius of 0.25 mm, and a bonded layer of 16 contact radii
/// stiffens it by a few per cent (the sphere's correction at that ratio is 6 %).
pub fn sneddon_cone(e: f64, nu: f64, alpha: f64, d: f64) -> f64 {
    let es = e / (1.0 - nu * nu);
    2.0 / std::f64::consts::PI * es * alpha.tan() * d * d
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sneddon's cone against its own contact-radius form, `P = (pi / 2) E* a^2 cot(alpha)`
    /// with `a = (2 / pi) tan(alpha) d`, and the scaling `P ~ d^2`.
    #[test]
    fn sneddon_cone_agrees_with_its_contact_radius_form() {
        use std::f64::consts::PI;
        let (e, nu, alpha, d): (f64, f64, f64, f64) = (1.19e5, 0.43, 0.6, 0.3e-3);
        let es = e / (1.0 - nu * nu);
        let a = 2.0 / PI * alpha.tan() * d;
        let p = PI / 2.0 * es * a * a / alpha.tan();
        assert!((sneddon_cone(e, nu, alpha, d) / p - 1.0).abs() < 1e-12);
        let ratio = sneddon_cone(e, nu, alpha, 2.0 * d) / sneddon_cone(e, nu, alpha, d);
        assert!((ratio - 4.0).abs() < 1e-12);
    }
}
