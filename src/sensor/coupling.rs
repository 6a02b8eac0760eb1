//! The gel that pushes back (`coupling="on"`): what force and torque the gel applies to
//! each body pressing it, between one sensor evaluation and the next.
//!
//! The gel is a Kelvin-Voigt solid: the wrench applied is the elastic contact wrench `w`
//! of the last solve plus `damping dw/dt`, the rate taken between evaluations. The damping
//! part is capped so that an explicit integrator stays stable, and the gel's stiffness
//! along the motion is estimated so that a time step too long for a body's mass is named
//! in a warning. Everything here is plain arithmetic on samples; the MuJoCo layer
//! (`mujoco::plugin`) gathers the samples, looks up the masses and applies the result.

use nalgebra::Vector3;

use crate::mpm::Wrench;
use crate::state::{self, Io, Persist};

/// Largest `stiffness * timestep^2 / mass` at which the explicit coupling is stable with
/// a margin: the undamped limit of the integration is 4.
pub const STABLE_RATIO: f64 = 2.0;

/// Motion per step (m) beyond which the coupling estimates the gel's stiffness (below it
/// the solver's tolerance dominates the change of force).
pub const MOVED: f64 = 1e-6;

/// One geom's elastic wrench and position (sensor frame), or their rates of change.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sample {
    /// The geom (an id of the caller's).
    pub geom: usize,
    /// The gel's elastic contact wrench on it (N, N m), or its rate.
    pub wrench: Wrench,
    /// Its position (m), or its velocity.
    pub at: Vector3<f64>,
}

/// What the coupling keeps between evaluations for its damping: the time of the last
/// evaluation and the step before it, and, per geom, the last samples and their rates of
/// change. A state evaluated again at the same time keeps the rates and the step (so the
/// damping and its cap stay as they were).
#[derive(Clone, Debug, Default)]
pub struct Coupling {
    time: Option<f64>,
    step: Option<f64>,
    last: Vec<Sample>,
    rates: Vec<Sample>,
}

/// The wrench to apply to one geom's body (sensor frame; the opposite goes to the
/// sensor's body), and the gel's stiffness where the time step is too long for it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Push {
    /// The geom.
    pub geom: usize,
    /// Elastic wrench plus its capped damping.
    pub wrench: Wrench,
    /// Set when `stiffness * step^2 / mass` exceeds [`STABLE_RATIO`].
    pub unstable: Option<Instability>,
}

/// A coupling that may be unstable: the numbers the warning names.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instability {
    /// The gel's stiffness along the motion (N/m).
    pub stiffness: f64,
    /// `stiffness * step^2 / mass`.
    pub ratio: f64,
    /// The time step (s).
    pub step: f64,
    /// The reduced mass of the two bodies (kg).
    pub mass: f64,
}

impl Coupling {
    /// Writes or reads the coupling's memory ([`crate::state`]): geoms below `geoms`, at
    /// most `geoms` samples of each kind.
    pub fn persist(&mut self, io: &mut Io<'_>, geoms: usize) {
        state::option(io, &mut self.time, || 0.0);
        state::option(io, &mut self.step, || 0.0);
        for samples in [&mut self.last, &mut self.rates] {
            let n = io.len(samples.len(), geoms, "the coupling's samples");
            if io.loading() {
                samples.resize(n, Sample::default());
            }
            for s in samples.iter_mut() {
                io.count(&mut s.geom, geoms, "a coupled geom");
                s.wrench.persist(io);
                s.at.persist(io);
            }
        }
    }

    /// Records the samples `now` at `time` and their rates over the step since the last
    /// evaluation (a geom missing then had no wrench and has no rate); the rates kept when
    /// the time has not moved (the same state evaluated again); zero after a step back in
    /// time.
    pub fn update(&mut self, time: f64, now: Vec<Sample>) {
        let zero = |s: &Sample| Sample {
            geom: s.geom,
            ..Sample::default()
        };
        let rates = match self.time {
            Some(t) if time == t => now
                .iter()
                .map(|s| {
                    let kept = self.rates.iter().find(|r| r.geom == s.geom);
                    kept.copied().unwrap_or_else(|| zero(s))
                })
                .collect(),
            Some(t) if time > t => {
                let h = time - t;
                self.step = Some(h);
                now.iter()
                    .map(|s| {
                        let before = self.last.iter().find(|b| b.geom == s.geom);
                        let b = before.copied().unwrap_or_else(|| zero(s));
                        Sample {
                            geom: s.geom,
                            wrench: Wrench {
                                force: (s.wrench.force - b.wrench.force) / h,
                                torque: (s.wrench.torque - b.wrench.torque) / h,
                            },
                            at: if before.is_some() {
                                (s.at - b.at) / h
                            } else {
                                Vector3::zeros()
                            },
                        }
                    })
                    .collect()
            }
            _ => {
                self.step = None;
                now.iter().map(zero).collect()
            }
        };
        self.rates = rates;
        self.time = Some(time);
        self.last = now;
    }

    /// Records `now` at `time` ([`Coupling::update`]) and returns what to apply to each
    /// geom: its wrench plus `tau` times the wrench's rate ([`kelvin_voigt`]), with
    /// `reduced_mass(geom)` the reduced mass of the geom's body and the sensor's body
    /// (infinite when both are fixed).
    pub fn push(
        &mut self,
        time: f64,
        now: Vec<Sample>,
        tau: f64,
        reduced_mass: impl Fn(usize) -> f64,
    ) -> Vec<Push> {
        self.update(time, now);
        let h = self.step;
        self.last
            .iter()
            .zip(&self.rates)
            .map(|(sample, rate)| {
                let mass = reduced_mass(sample.geom);
                let unstable = h
                    .filter(|_| mass.is_finite())
                    .and_then(|h| stiffness(rate, h).map(|k| (h, k)))
                    .map(|(step, stiffness)| Instability {
                        stiffness,
                        ratio: stiffness * step * step / mass,
                        step,
                        mass,
                    })
                    .filter(|i| i.ratio > STABLE_RATIO);
                Push {
                    geom: sample.geom,
                    wrench: kelvin_voigt(&sample.wrench, rate, tau, mass, h),
                    unstable,
                }
            })
            .collect()
    }
}

/// The reduced mass of two bodies of masses `m1` and `m2` (kg; infinite for a body fixed
/// to the world): the other's where one is fixed.
pub fn reduced_mass(m1: f64, m2: f64) -> f64 {
    if m1.is_infinite() {
        m2
    } else if m2.is_infinite() {
        m1
    } else {
        m1 * m2 / (m1 + m2)
    }
}

/// The gel's stiffness along the motion seen in `rate` over a step `h` (N/m): the rate of
/// the elastic force along the relative velocity over the speed, once the body moves by
/// more than [`MOVED`] per step.
pub fn stiffness(rate: &Sample, h: f64) -> Option<f64> {
    let speed = rate.at.norm();
    (speed * h > MOVED).then(|| (-rate.wrench.force.dot(&rate.at) / (speed * speed)).abs())
}

/// The wrench the coupling applies for elastic wrench `w` changing at `rate.wrench`, with
/// retardation time `tau` (Kelvin-Voigt: `w + tau dw/dt`). The damping part is scaled
/// down where it would make the gel pull the body towards it (a gel pushes only), and
/// where it exceeds `mass * |v| / h`, the force that stops the relative velocity
/// `v = rate.at` of the bodies (reduced mass `mass`) within the step `h`: an explicit
/// damper stronger than that overshoots and grows (measured: a 2 g ball with 10 ms
/// blows up at 2 ms steps without this cap).
pub fn kelvin_voigt(w: &Wrench, rate: &Sample, tau: f64, mass: f64, h: Option<f64>) -> Wrench {
    let (df, dt) = (rate.wrench.force * tau, rate.wrench.torque * tau);
    let mut s = 1.0f64;
    if w.force.z + df.z < 0.0 && df.z < 0.0 {
        s = s.min((w.force.z.max(0.0) / -df.z).clamp(0.0, 1.0));
    }
    if let Some(h) = h {
        let stop = mass * rate.at.norm() / h;
        if df.norm() > stop {
            s = s.min(stop / df.norm());
        }
    }
    Wrench {
        force: w.force + df * s,
        torque: w.torque + dt * s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(geom: usize, fz: f64, z: f64) -> Sample {
        Sample {
            geom,
            wrench: Wrench {
                force: Vector3::new(0.0, 0.0, fz),
                torque: Vector3::zeros(),
            },
            at: Vector3::new(0.0, 0.0, z),
        }
    }

    #[test]
    fn rates_are_differences_over_the_step_and_kept_for_the_same_time() {
        let mut c = Coupling::default();
        c.update(0.0, vec![sample(3, 1.0, 0.0)]);
        assert_eq!(
            c.rates[0],
            Sample {
                geom: 3,
                ..Sample::default()
            }
        );
        c.update(0.002, vec![sample(3, 1.5, -1e-5)]);
        assert!((c.rates[0].wrench.force.z - 250.0).abs() < 1e-9);
        assert!((c.rates[0].at.z + 5e-3).abs() < 1e-12);
        assert_eq!(c.step, Some(0.002));
        // The same state again: the rates and the step stay.
        let before = c.rates.clone();
        c.update(0.002, vec![sample(3, 1.5, -1e-5)]);
        assert_eq!(c.rates, before);
        // A step back in time (a reset or a restored state): no rate, no step.
        c.update(0.0, vec![sample(3, 1.5, -1e-5)]);
        assert_eq!(
            c.rates[0],
            Sample {
                geom: 3,
                ..Sample::default()
            }
        );
        assert_eq!(c.step, None);
    }

    #[test]
    fn a_new_geom_has_its_wrench_as_rate_and_no_velocity() {
        let mut c = Coupling::default();
        c.update(0.0, vec![]);
        c.update(0.001, vec![sample(1, 0.2, 0.5)]);
        assert!((c.rates[0].wrench.force.z - 200.0).abs() < 1e-9);
        assert_eq!(c.rates[0].at, Vector3::zeros());
    }

    #[test]
    fn the_damping_never_pulls_and_never_stops_the_body_past_rest() {
        let w = Wrench {
            force: Vector3::new(0.0, 0.0, 1.0),
            torque: Vector3::zeros(),
        };
        // Unloading fast: the damped force would be negative (a pull); it stops at zero.
        let rate = sample(0, -1e4, 0.0);
        let f = kelvin_voigt(&w, &rate, 0.01, f64::INFINITY, None);
        assert!(f.force.z.abs() < 1e-12, "{}", f.force.z);
        // Loading: the damping adds, capped at what stops a 2 g body within the step.
        let mut rate = sample(0, 1e3, 0.0);
        rate.at = Vector3::new(0.0, 0.0, -0.01);
        let f = kelvin_voigt(&w, &rate, 0.01, 0.002, Some(0.002));
        let stop = 0.002 * 0.01 / 0.002;
        assert!((f.force.z - (1.0 + stop)).abs() < 1e-12, "{}", f.force.z);
        // A heavy body takes the whole damping, w + tau dw/dt.
        let f = kelvin_voigt(&w, &rate, 0.01, 100.0, Some(0.002));
        assert!((f.force.z - 11.0).abs() < 1e-12);
    }

    #[test]
    fn a_stiff_gel_under_a_light_body_is_named_unstable() {
        // 1e4 N/m: the force grows by 10 N/s while the body moves down at 1 mm/s.
        let run = |mass: f64| {
            let mut c = Coupling::default();
            c.push(0.0, vec![sample(0, 0.0, 0.0)], 0.0, |_| mass);
            c.push(0.002, vec![sample(0, 0.02, -2e-6)], 0.0, |_| mass)
        };
        let light = run(1e-4);
        let i = light[0]
            .unstable
            .expect("k h^2 / m = 0.4 / 1e-4 * 1e-2 > 2");
        assert!((i.stiffness - 1e4).abs() < 1e-6, "{}", i.stiffness);
        assert!((i.ratio - 1e4 * 4e-6 / 1e-4).abs() < 1e-9);
        assert!(run(1.0)[0].unstable.is_none());
        assert!(run(f64::INFINITY)[0].unstable.is_none());
        assert_eq!(
            light[0].wrench.force.z, 0.02,
            "no damping: the elastic wrench"
        );
    }

    #[test]
    fn the_reduced_mass_follows_a_fixed_body() {
        assert_eq!(reduced_mass(f64::INFINITY, 2.0), 2.0);
        assert_eq!(reduced_mass(3.0, f64::INFINITY), 3.0);
        assert!((reduced_mass(2.0, 2.0) - 1.0).abs() < 1e-15);
        assert!(reduced_mass(f64::INFINITY, f64::INFINITY).is_infinite());
    }
}
