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
    let a0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu * nu) / (1.0 - nu);
    let b0 = (0.6387 - 1.0277 * nu + 1.5164 * nu * nu) / (1.0 - nu);
    let c = (r * d).sqrt() / h;
    let bracket = 1.0 - 2.0 * a0 / PI * c + 4.0 * a0 * a0 / (PI * PI) * c * c
        - 8.0 / PI.powi(3) * (a0.powi(3) + 4.0 * PI * PI * b0 / 15.0) * c.powi(3)
        + 16.0 * a0 / PI.powi(4) * (a0.powi(3) + 3.0 * PI * PI * b0 / 5.0) * c.powi(4);
    4.0 * es / 3.0 * r.sqrt() * d.powf(1.5) * bracket
}
