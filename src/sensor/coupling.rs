//! The gel that pushes back (`coupling="on"`): what force and torque the gel applies to
//! each body pressing it, between one sensor evaluation and the next.
//!
//! The gel is a Kelvin-Voigt solid: the wrench applied is the elastic contact wrench `w`
//! of the last solve plus `damping dw/dt`, the rate taken between evaluations. The damping
//! part is capped so that an explicit integrator stays stable, and the gel's stiffness
//! along the motion is estimated so that a time step too long for a body's mass is named
//! in a warning.
//!
//! The gel is passive: it gives a body back at most the work the body did on it. An
//! explicit coupling applies over each step the force of the step's start, so a body
//! pressing into a stiffening gel does less work on it than the force it meets on the way
//! back does on the body, and a heavy ball left with several times the energy it brought
//! (measured: `docs/rl.md`, "The gel that pushes back"). Each geom therefore keeps an
//! account of the work it did on the gel (observed over each step from the force applied
//! and the displacement that followed); the force is scaled down where the work it would
//! do over the next step at the body's present velocity exceeds that account (a
//! time-domain passivity controller). Everything here is plain arithmetic on samples; the
//! MuJoCo layer (`mujoco::plugin`) gathers the samples, looks up the masses and applies
//! the result.

use nalgebra::{Isometry3, UnitQuaternion, Vector3};

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
    /// Per geom in contact: the work it has done on the gel (J) and the force last applied
    /// to it (N, sensor frame), the gel's side of the passivity account.
    accounts: Vec<Account>,
    /// The implicit coupling's (`gel_geom`): per geom, the solve its push-back follows.
    pub base: Vec<Base>,
}

/// The solve one geom's implicit push-back follows until it needs another
/// ([`needs_solve`]): the geom's pose then and the gel's wrench on it (sensor frame). A
/// sensor's evaluation between (its images) leaves it: a new base at every frame would
/// move the force by the solves' own differences at every frame, a jitter that the
/// stiffness followed between them would not settle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Base {
    /// The geom.
    pub geom: usize,
    /// Its pose at the solve (sensor frame).
    pub pose: Isometry3<f64>,
    /// The gel's wrench on it then (N, N m about the sensor origin).
    pub wrench: Wrench,
    /// The gel's normal stiffness measured between this solve and an earlier one
    /// ([`secant`], N/m), where one was.
    pub normal: Option<f64>,
    /// Its tangential stiffness measured likewise ([`tangential_secant`], N/m), where one
    /// was.
    pub tangential: Option<f64>,
    /// How far the contact spread about its centre of pressure then (m^2,
    /// [`crate::mpm::Gel::wrenches_and_spreads`]; zero where not known).
    pub spread: f64,
}

impl Default for Base {
    fn default() -> Self {
        Self {
            geom: 0,
            pose: Isometry3::identity(),
            wrench: Wrench::default(),
            normal: None,
            tangential: None,
            spread: 0.0,
        }
    }
}

/// One geom's passivity account ([`Coupling`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Account {
    /// The geom.
    pub geom: usize,
    /// The work the geom has done on the gel since the contact began, less what the gel
    /// gave back (J).
    pub stored: f64,
    /// The force applied to the geom over the step that follows the last evaluation (N).
    pub applied: Vector3<f64>,
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
        let n = io.len(self.accounts.len(), geoms, "the coupling's accounts");
        if io.loading() {
            self.accounts.resize(n, Account::default());
        }
        for a in &mut self.accounts {
            io.count(&mut a.geom, geoms, "a coupled geom");
            a.stored.persist(io);
            a.applied.persist(io);
        }
        let n = io.len(self.base.len(), geoms, "the implicit coupling's solves");
        if io.loading() {
            self.base.resize(n, Base::default());
        }
        for b in &mut self.base {
            io.count(&mut b.geom, geoms, "a coupled geom");
            b.pose.persist(io);
            b.wrench.persist(io);
            state::option(io, &mut b.normal, || 0.0);
            state::option(io, &mut b.tangential, || 0.0);
            b.spread.persist(io);
        }
    }

    /// The length [`Coupling::persist`] writes at most for `geoms` geoms.
    pub fn state_len(geoms: usize) -> usize {
        4 + 2 * (1 + 10 * geoms) + (1 + 7 * geoms) + (1 + 19 * geoms)
    }

    /// Records the samples `now` at `time` and their rates over the step since the last
    /// evaluation (a geom missing then had no wrench and has no rate); the rates kept when
    /// the time has not moved (the same state evaluated again); zero after a step back in
    /// time.
    pub fn update(&mut self, time: f64, now: Vec<Sample>) -> bool {
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
        let advanced = self.time.is_some_and(|t| time > t);
        self.rates = rates;
        self.time = Some(time);
        self.last = now;
        advanced
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
        let advanced = self.update(time, now);
        let h = self.step;
        let before = std::mem::take(&mut self.accounts);
        let mut accounts = Vec::with_capacity(self.last.len());
        let pushes = self
            .last
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
                let mut wrench = kelvin_voigt(&sample.wrench, rate, tau, mass, h);
                if sample.wrench != Wrench::default() {
                    let account = before.iter().find(|a| a.geom == sample.geom);
                    let mut account = account.copied().unwrap_or(Account {
                        geom: sample.geom,
                        ..Account::default()
                    });
                    if let (true, Some(h)) = (advanced, h) {
                        // The work the body did against the gel's elastic force over the
                        // step just taken: trapezoidal (exact for a linear gel) where the
                        // gel's stiffness along the motion lies within the step's stable
                        // range; beyond it (the gel crushed within the step) the force at
                        // the step's start, which bounds the stored energy from below
                        // for a gel that stiffens as it is pressed.
                        let smooth =
                            stiffness(rate, h).map_or(true, |k| !(k * h * h / mass > STABLE_RATIO));
                        let start = sample.wrench.force - h * rate.wrench.force;
                        let force = if smooth {
                            sample.wrench.force - 0.5 * h * rate.wrench.force
                        } else {
                            start
                        };
                        account.stored -= force.dot(&rate.at) * h;
                    }
                    if let Some(h) = h {
                        wrench = passive(wrench, account.stored, rate.at, h, mass);
                    }
                    account.applied = wrench.force;
                    accounts.push(account);
                }
                Push {
                    geom: sample.geom,
                    wrench,
                    unstable,
                }
            })
            .collect();
        // A geom out of contact closes its account: the gel it left is at rest.
        self.accounts = accounts;
        pushes
    }
}

/// The speed (m/s) up to which the coupling may push a body out of the gel beyond its
/// passivity account: a body that crushed the gel within one step leaves it no faster.
pub const CREEP_SPEED: f64 = 1e-3;

/// `wrench` scaled down where its force would do more work than `stored` (J, at least 0)
/// over the next step `h` on a body of (reduced) mass `mass` moving at `velocity`: the gel
/// gives back at most what it took. The body's displacement over the step is predicted as
/// the integrator takes it, `h (v + h f / m)`, so that a force that turns the body round
/// within one step is bounded too (the other forces on the body are left out).
pub fn passive(wrench: Wrench, stored: f64, velocity: Vector3<f64>, h: f64, mass: f64) -> Wrench {
    let f = wrench.force;
    // The work of `s f` over the step: a s^2 + b s.
    let finite = mass.is_finite() && mass > 0.0;
    let a = if finite {
        h * h * f.norm_squared() / mass
    } else {
        0.0
    };
    let b = h * f.dot(&velocity);
    // A body that the account leaves stuck in the gel (it crushed the gel within one
    // step, and the gel holds more than the body gave it) still leaves it, at the creep
    // speed at most.
    let creep = if finite {
        0.5 * mass * (CREEP_SPEED * CREEP_SPEED - velocity.norm_squared())
    } else {
        0.0
    };
    let allowed = stored.max(creep).max(0.0);
    if !(a + b > allowed) {
        return wrench;
    }
    // The largest s in [0, 1] with a s^2 + b s <= allowed (s = 0 does no work).
    let s = if a > 0.0 {
        (-b + (b * b + 4.0 * a * allowed).sqrt()) / (2.0 * a)
    } else {
        allowed / b
    };
    let s = if s.is_finite() {
        s.clamp(0.0, 1.0)
    } else {
        0.0
    };
    Wrench {
        force: f * s,
        torque: wrench.torque * s,
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
/// damper stronger than that overshoots and grows, as it did for a light ball at the
/// default damping (measured: `docs/rl.md`, "The gel that pushes back").
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

/// The normal stiffness of a contact over its force and depth, `dF/dd = n F / d`: 1 for
/// a flat punch, 3/2 for a sphere (Hertz), 2 for a cone. The implicit coupling takes the
/// sphere's: it is at most 1.5 times a flat face's stiffness (more damping, the same
/// equilibrium) and 3/4 of a cone's, and an implicit step stays stable with any stiffness
/// above half the gel's ([`implicit_row`]).
pub const DEPTH_EXPONENT: f64 = 1.5;

/// The depth (m) below which a contact's stiffness is taken at this depth.
pub const SHALLOWEST: f64 = 1e-6;

/// The motion of an indenter (m, of its centre of pressure relative to the gel) since the
/// last solve beyond which the implicit coupling solves the gel again, as a fraction of
/// the contact's depth: the force between solves follows a power law of the depth through
/// the last solve's force and stiffness ([`power_law`]), exact for a Hertzian contact,
/// whose tangent line would leave it by `3/8 (motion / depth)^2` of itself, 1.5 % at this
/// fraction. (The errors measured where the grasps' gels were solved again: [`power_law`].)
pub const RESOLVE_FRACTION: f64 = 0.2;

/// The least motion (m) that makes the implicit coupling solve again.
pub const RESOLVE_FLOOR: f64 = 1e-5;

/// The gel's push-back on one indenter between solves (`gel_geom`): the last solve's
/// force, followed along the indenter's motion since that solve with the contact's
/// stiffness. Sensor frame; +z out of the gel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Linearised {
    /// The force on the indenter now (N).
    pub force: Vector3<f64>,
    /// The stiffness along the gel's normal (N/m).
    pub normal: f64,
    /// The stiffness along the surface (N/m), zero without friction.
    pub tangential: f64,
    /// Where the force acts now: the last solve's centre of pressure moved with the
    /// indenter (m), if known.
    pub centre: Option<Vector3<f64>>,
    /// The last solve's torque about the gel's normal through the centre of pressure
    /// (N m): the twist that a force at the centre does not carry.
    pub twist: f64,
    /// The indenter's rotation since the last solve (sensor frame), which moves each of
    /// its contact points by its own amount about the centre ([`Linearised::at_point`]).
    pub turned: UnitQuaternion<f64>,
    /// How far the last solve's contact spread about its centre of pressure (m^2,
    /// [`crate::mpm::Gel::wrenches_and_spreads`]); zero where not known.
    pub spread: f64,
}

impl Linearised {
    /// The part of the push-back at a contact point `offset` from the centre of pressure
    /// (sensor frame) that the force at the centre leaves out, for a point with `share` of
    /// it and `spread`, the sum of the shares times the squared in-plane offsets over the
    /// indenter's points: the stiffness against the point's own motion by the rotation
    /// since the solve (so that the contact points together resist a turn or a tilt as
    /// the gel does, not only a shift), and the point's part of [`Linearised::twist`].
    /// Both add up to no force over the points whose shares' centre is the centre. The
    /// springs are scaled by the gel's spread over the points' ([`TURN_RANGE`]): MuJoCo's
    /// contacts lie at the corners of a face, where a face's own pressure lies across
    /// it, and the corners of a square alone resist a turn three times as stiffly as the
    /// square under an even pressure.
    pub fn at_point(&self, offset: Vector3<f64>, share: f64, spread: f64) -> Vector3<f64> {
        let moved = offset - self.turned.inverse() * offset;
        let scale = if self.spread > 0.0 && spread > 0.0 {
            (self.spread / spread).clamp(TURN_RANGE[0], TURN_RANGE[1])
        } else {
            1.0
        };
        let spring = -share
            * scale
            * Vector3::new(
                self.tangential * moved.x,
                self.tangential * moved.y,
                self.normal * moved.z,
            );
        let twist = if spread > 0.0 {
            share * self.twist / spread * Vector3::new(-offset.y, offset.x, 0.0)
        } else {
            Vector3::zeros()
        };
        spring + twist
    }
}

/// The ratio of a contact's tangential to its normal stiffness on an elastic half-space
/// (Mindlin): `2 (1 - nu) / (2 - nu)`. On a thin bonded layer the normal stiffness grows
/// more than the tangential, so this overestimates the tangential one: it stands in until
/// two solves measure the gel's own ([`tangential_secant`]), and bounds that from above.
pub fn tangential_ratio(poisson: f64) -> f64 {
    2.0 * (1.0 - poisson) / (2.0 - poisson)
}

/// The centre of pressure of `wrench` (torque about the sensor origin) on the gel's
/// surface plane, or `None` without a normal force.
pub fn centre_of_pressure(wrench: &Wrench) -> Option<Vector3<f64>> {
    let fz = wrench.force.z;
    (fz > 0.0).then(|| Vector3::new(-wrench.torque.y / fz, wrench.torque.x / fz, 0.0))
}

/// The push-back on an indenter whose last solve gave `solved`, whose centre of pressure
/// has moved by `moved` since (sensor frame) and which lies `depth` deep in the gel's
/// rest surface now: the normal force follows `solved` along the power law of the depth
/// ([`power_law`]) whose stiffness at the solve is `measured` (else [`DEPTH_EXPONENT`]` F
/// / d`, `d` the depth at the solve; the stiffness returned is the law's now), the
/// tangential force with
/// [`TANGENTIAL_MARGIN`] times `measured_tangential` (else [`tangential_ratio`] times the
/// normal one at the solve, which also bounds it from above, and
/// [`TANGENTIAL_RANGE`]`[0]` times that from below); it never pulls, and its tangential
/// part stays within the friction cone `friction F_z`.
pub fn linearise(
    solved: &Wrench,
    moved: Vector3<f64>,
    depth: f64,
    measured: Option<f64>,
    measured_tangential: Option<f64>,
    poisson: f64,
    friction: f64,
) -> Linearised {
    let f0 = solved.force;
    // A measured stiffness that is no stiffness (a state from elsewhere) is not one.
    let measured = measured.filter(|k| k.is_finite() && *k > 0.0);
    let finite = f0.iter().chain(solved.torque.iter()).all(|f| f.is_finite());
    if !(f0.z > 0.0) || !finite {
        return Linearised {
            force: Vector3::zeros(),
            normal: 0.0,
            tangential: 0.0,
            centre: None,
            twist: 0.0,
            turned: UnitQuaternion::identity(),
            spread: 0.0,
        };
    }
    // Deeper now by -moved.z: the depth at the solve.
    let at_solve = (depth + moved.z).max(SHALLOWEST);
    let normal = measured.unwrap_or(DEPTH_EXPONENT * f0.z / at_solve);
    let tangential = if friction > 0.0 {
        let most = normal * tangential_ratio(poisson);
        measured_tangential
            .filter(|k| k.is_finite() && *k > 0.0)
            .map_or(most, |k| {
                (TANGENTIAL_MARGIN * k).clamp(TANGENTIAL_RANGE[0] * most, most)
            })
    } else {
        0.0
    };
    let (fz, normal) = power_law(f0.z, normal, at_solve, at_solve - moved.z);
    let mut ft = Vector3::new(f0.x, f0.y, 0.0) - tangential * Vector3::new(moved.x, moved.y, 0.0);
    let cone = friction * fz;
    if ft.norm() > cone {
        ft *= cone / ft.norm();
    }
    let centre = centre_of_pressure(solved);
    let twist = centre.map_or(0.0, |c| solved.torque.z - (c.x * f0.y - c.y * f0.x));
    Linearised {
        force: Vector3::new(ft.x, ft.y, fz),
        normal,
        tangential,
        centre: centre.map(|c| c + moved),
        twist,
        turned: UnitQuaternion::identity(),
        spread: 0.0,
    }
}

/// The normal force (N) and stiffness (N/m) `depth` deep (m) of a contact that pressed
/// with `force` at `at_solve` deep with the stiffness `stiffness` there: the power law
/// `F (d / d0)^n` of the depth whose stiffness at the solve is that one (`n = k d0 / F`),
/// and its stiffness at `depth`; nothing at no depth. A contact whose force is one power
/// law of its depth (a flat punch's, 1; a sphere's, Hertz's 3/2; a cone's, 2) it follows
/// exactly, where the straight line along the stiffness at the solve leaves the sphere's
/// force by about `3/8 (motion / depth)^2` of it and reaches nothing at a third of the
/// depth left. An apparent exponent beyond [`EXPONENT_RANGE`] is a discretised gel's
/// force, which starts where a contact point is reached: the law keeps the exponent's
/// bound and carries the stiffness at the solve with a force that starts at a positive
/// depth (below the range, the straight line). Measured on `tacrom/GripperLift-v1`'s
/// coupled grasps where the pads' gels were solved again within 0.3 of the depth (just
/// past [`RESOLVE_FRACTION`]): the force there was the solve's within 3.9 % (median; 8.7 %
/// at the 90th percentile) into the gel against the line's 6.9 % (14 %), and within 16 %
/// (26 %) out of it against 19 % (54 %) (`docs/rl.md`, "The push-back between solves: a
/// power law of the depth").
pub fn power_law(force: f64, stiffness: f64, at_solve: f64, depth: f64) -> (f64, f64) {
    if !(depth > 0.0 && force > 0.0 && stiffness > 0.0 && at_solve > 0.0) {
        return (0.0, 0.0);
    }
    let n = (stiffness * at_solve / force).clamp(EXPONENT_RANGE[0], EXPONENT_RANGE[1]);
    // The law's scale: the force itself where the exponent is the apparent one.
    let scale = stiffness * at_solve / n;
    let grown = scale * (depth / at_solve).powf(n);
    let f = force - scale + grown;
    if !(f > 0.0 && f.is_finite()) {
        return (0.0, 0.0);
    }
    (f, n * grown / depth)
}

/// The gel's normal stiffness (N/m) between two solves of one indenter, `then` and `now`,
/// between which its centre of pressure moved `dz` along the gel's normal (m, + out of the
/// gel), `depth` deep now: the stiffness now of the power law of the depth through both
/// solves' normal forces ([`power_law`]), where the motion is long enough for the solves'
/// own differences (their tolerance, a few thousandths of the force) not to dominate
/// ([`SECANT_FRACTION`] of the depth) and the force grew into the gel; bounded to
/// [`SECANT_RANGE`] times the Hertz estimate [`DEPTH_EXPONENT`]` F / d`. A discretised
/// gel's force is not Hertz's: it starts where a contact point is reached, so `F / d` can
/// be several times too low, and a stiffness followed between solves at half the gel's or
/// less makes each solve's error as large as the last's, of the other sign.
pub fn secant(then: &Wrench, now: &Wrench, dz: f64, depth: f64) -> Option<f64> {
    let (f0, f1) = (then.force.z, now.force.z);
    let measurable = f0 > 0.0 && f1 > 0.0 && depth > 0.0 && dz.abs() > SECANT_FRACTION * depth;
    if !measurable {
        return None;
    }
    let then_deep = depth + dz;
    if !(then_deep > 0.0) {
        return None;
    }
    let exponent = (f0 / f1).ln() / (then_deep / depth).ln();
    let k = exponent * f1 / depth;
    let hertz = DEPTH_EXPONENT * f1 / depth.max(SHALLOWEST);
    (k > 0.0 && k.is_finite()).then(|| k.clamp(SECANT_RANGE[0] * hertz, SECANT_RANGE[1] * hertz))
}

/// The least motion between two solves, as a fraction of the depth, over which
/// [`secant`] measures the gel's stiffness.
pub const SECANT_FRACTION: f64 = 2e-3;

/// The bounds of [`secant`]'s stiffness, as multiples of the Hertz estimate.
pub const SECANT_RANGE: [f64; 2] = [0.5, 8.0];

/// The exponents of the depth that [`power_law`] follows a contact's force with: a flat
/// punch's and a cone's.
pub const EXPONENT_RANGE: [f64; 2] = [1.0, 2.0];

/// The gel's tangential stiffness (N/m) between two solves of one indenter, `then` and
/// `now`, between which its centre of pressure moved `moved` (m, sensor frame): the change
/// of the tangential force along the motion over the motion along the surface, where both
/// solves hold within their friction cones ([`STICKING`] of `friction F_z`: a sliding
/// contact's force is the cone's, not a stiffness's) and the force changed by more than
/// [`TANGENTIAL_SECANT`] of the normal force (beyond the solves' own differences, their
/// tolerance a few thousandths of the force). [`linearise`] bounds it.
///
/// Why measured: Mindlin's ratio of the normal stiffness holds on a half-space; on a thin
/// bonded layer the normal stiffness grows with the layer's confinement and the tangential
/// one does not (the gripper's pads on a box: a fourth to a sixth of it), and a
/// tangential stiffness followed between solves at several times the gel's holds a
/// loaded object short of where the gel lets it go, so that each solve moves it on by a
/// fraction of the way (measured: `docs/rl.md`, "A coupled grasp").
pub fn tangential_secant(
    then: &Wrench,
    now: &Wrench,
    moved: Vector3<f64>,
    friction: f64,
) -> Option<f64> {
    let sticking =
        |w: &Wrench| w.force.z > 0.0 && w.force.xy().norm() <= STICKING * friction * w.force.z;
    let along = moved.xy();
    let df = now.force.xy() - then.force.xy();
    let measurable = friction > 0.0
        && sticking(then)
        && sticking(now)
        && along.norm() > 0.0
        && df.norm() > TANGENTIAL_SECANT * then.force.z.min(now.force.z);
    if !measurable {
        return None;
    }
    let k = -df.dot(&along) / along.norm_squared();
    (k > 0.0 && k.is_finite()).then_some(k)
}

/// The share of the friction cone within which a solve's tangential force counts as
/// sticking for [`tangential_secant`].
pub const STICKING: f64 = 0.9;

/// The least change of the tangential force between two solves, as a fraction of the
/// normal force, over which [`tangential_secant`] measures the gel's stiffness.
pub const TANGENTIAL_SECANT: f64 = 0.02;

/// The multiple of a measured tangential stiffness that the push-back follows. Each solve
/// moves a loaded object on by `1 - k / k_f` of its error (`k` the gel's stiffness, `k_f`
/// the one followed): below half the gel's, each error is larger than the last, of the
/// other sign, and a held grasp never comes to rest; a secant measured while the contact
/// slips partly lies below the sticking gel's. Twice the measured: an error halved at each
/// solve where the measurement is right, convergence where the gel is up to four times
/// stiffer than measured.
pub const TANGENTIAL_MARGIN: f64 = 2.0;

/// The bounds of the factor on the contact points' resistance to a turn or a tilt since
/// the last solve ([`Linearised::at_point`]): the gel's spread about the centre of
/// pressure over theirs. Below 1: the points' springs never stiffer than the rows that
/// carry them implicitly (a force steeper than its row's stiffness is an explicit one);
/// above a tenth: a contact whose loads the solve lumped together still resists a turn.
pub const TURN_RANGE: [f64; 2] = [0.1, 1.0];

/// The bounds of a measured tangential stiffness, as multiples of Mindlin's estimate
/// ([`tangential_ratio`] times the normal stiffness).
pub const TANGENTIAL_RANGE: [f64; 2] = [0.02, 1.0];

/// Whether an indenter whose centre of pressure moved by `moved` (m) since the last solve,
/// at a contact `depth` deep then, needs the gel solved again ([`RESOLVE_FRACTION`]).
pub fn needs_solve(moved: f64, depth: f64) -> bool {
    !(moved <= (RESOLVE_FRACTION * depth).max(RESOLVE_FLOOR))
}

/// A contact row of MuJoCo's constraint solve that carries the gel's force implicitly:
/// its regularised mass `D` (MuJoCo's `efc_D`, the inverse of `efc_R`) and the offset
/// `F / D` of its reference acceleration, `aref = F / D - v / h` (MuJoCo's `aref = -B v -
/// K I (pos - margin)` with `B = 1 / h`, `K I = 1` and `pos - margin = -F / D`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImplicitRow {
    /// `efc_D` (kg, per unit of the row's acceleration).
    pub mass: f64,
    /// `F / D` (m/s^2).
    pub offset: f64,
}

/// The least `efc_D` of a row: a row without force or stiffness carries nothing.
pub const ROW_FLOOR: f64 = 1e-12;

/// The row that makes MuJoCo's solve give the force `force` (N, along the row) less what
/// the gel's stiffness `stiffness` (N/m) and its damping `tau` (s) take away over the step
/// `h`: MuJoCo's solve gives a row the force `D (aref - a)` at the row's acceleration `a`,
/// which with this row is `F - k (h + tau) (v + h a)`, the gel's force at the end of the
/// step (`v + h a` the row's velocity then, as MuJoCo's Euler step integrates it) plus its
/// Kelvin-Voigt damping there: backward Euler on the gel's stiffness, taken together with
/// every other force and constraint of the scene, stable at any stiffness and mass.
pub fn implicit_row(force: f64, stiffness: f64, h: f64, tau: f64) -> ImplicitRow {
    let mass = stiffness * h * (h + tau);
    if !(mass > ROW_FLOOR) || !force.is_finite() {
        return ImplicitRow {
            mass: ROW_FLOOR,
            offset: 0.0,
        };
    }
    ImplicitRow {
        mass,
        offset: force / mass,
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
    fn the_gel_gives_back_at_most_what_it_holds() {
        let w = |fz: f64| Wrench {
            force: Vector3::new(0.0, 0.0, fz),
            torque: Vector3::new(0.0, 0.01 * fz, 0.0),
        };
        let (h, m) = (2e-3, 0.5);
        // Pressing in (moving against the force): no work given, nothing bounded.
        let down = Vector3::new(0.0, 0.0, -0.1);
        assert_eq!(passive(w(10.0), 0.0, down, h, m), w(10.0));
        // Moving out with little stored: the force scaled so that its predicted work,
        // h f (v + h f / m), is what is stored; the torque with it.
        let up = Vector3::new(0.0, 0.0, 0.1);
        let stored = 1e-3;
        let out = passive(w(100.0), stored, up, h, m);
        let f = out.force.z;
        let work = h * f * (up.z + h * f / m);
        assert!(
            (work - stored).abs() < 1e-12 * stored.max(1.0),
            "{work} vs {stored}"
        );
        assert!(f > 0.0 && f < 100.0);
        assert!((out.torque.y - 0.01 * f).abs() < 1e-12);
        // Enough stored: unchanged. Nothing stored (or a deficit) for a body moving
        // faster than the creep speed: no push at all.
        assert_eq!(passive(w(100.0), 10.0, up, h, m), w(100.0));
        assert_eq!(passive(w(100.0), -1.0, up, h, m).force, Vector3::zeros());
        // A body at rest is turned round within the step by a large force: bounded too.
        let still = Vector3::zeros();
        let out = passive(w(1000.0), stored, still, h, m);
        let f = out.force.z;
        assert!((h * h * f * f / m - stored).abs() < 1e-12, "{f}");
        // With nothing stored, a body at rest leaves below the creep speed (the step's
        // work h^2 f^2 / m, twice the kinetic energy it gives, is bounded by that of the
        // creep speed).
        let f = passive(w(1000.0), 0.0, still, h, m).force.z;
        assert!((h * f / m - CREEP_SPEED / 2f64.sqrt()).abs() < 1e-12, "{f}");
        // A fixed body (infinite mass) at rest: the force does no work and is kept.
        assert_eq!(passive(w(1000.0), 0.0, still, h, f64::INFINITY), w(1000.0));
    }

    #[test]
    fn a_press_and_release_returns_no_more_than_it_took() {
        // A body pressing a gel that stiffens sharply (force ~ depth^3), stepped as
        // MuJoCo's semi-implicit Euler steps it with the coupling's forces: its energy
        // never rises above its start.
        let (h, m, k) = (2e-3, 0.5, 5e12);
        let (mut x, mut v) = (0.0f64, -0.6f64);
        let start = 0.5 * m * v * v;
        let mut c = Coupling::default();
        let mut most: f64 = 0.0;
        let mut deepest: f64 = 0.0;
        for n in 0..2000 {
            let depth = (-x).max(0.0);
            let s = sample(0, k * depth.powi(3), x);
            let push = c.push(n as f64 * h, vec![s], 0.0, |_| m);
            v += h * push[0].wrench.force.z / m;
            x += h * v;
            deepest = deepest.max(-x);
            // The body's energy: all it can have is what it brought.
            most = most.max(0.5 * m * v * v);
        }
        // It crushed the gel within a step, and leaves it at the creep speed.
        let creep = 0.5 * m * CREEP_SPEED * CREEP_SPEED;
        assert!(most <= start * 1.0001, "{most} > {start}");
        assert!(0.5 * m * v * v <= creep * 1.0001, "{v}");
        assert!(
            v > 0.0 && x > 0.0,
            "the gel pushed the body back out: x {x} v {v} most {most} start {start}"
        );
        assert!(deepest > 0.5e-3, "the body pressed the gel {deepest}");
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
        // No damping: the elastic wrench for the heavy body; for the light one, whose
        // whole energy it would turn round within the step, the passivity bound.
        assert_eq!(run(1.0)[0].wrench.force.z, 0.02, "the elastic wrench");
        let f = light[0].wrench.force.z;
        assert!(f > 0.0 && f < 0.02, "{f}");
    }

    /// MuJoCo's solve of one row of an isolated body (mass `m`, other forces `g`): the
    /// row's force `f = D (aref - a)` with `a = (f + g) / m`, so `f = D (aref - g / m) /
    /// (1 + D / m)`; then the Euler step.
    fn row_step(x: &mut f64, v: &mut f64, m: f64, g: f64, k: f64, h: f64, tau: f64, rest: f64) {
        // The gel's force on the body, pushing +x, from its depth `rest - x`.
        let force = k * (rest - *x);
        let row = implicit_row(force, k, h, tau);
        let aref = row.offset - *v / h;
        let f = row.mass * (aref - g / m) / (1.0 + row.mass / m);
        *v += h * (f + g) / m;
        *x += h * *v;
    }

    #[test]
    fn an_implicit_row_is_backward_euler_and_stable_at_any_stiffness() {
        let (h, m, g) = (2e-3, 0.05, -0.05 * 9.81);
        // One step against backward Euler on the linear spring, taken with the other
        // force: v1 = v + h (k (rest - x - h v1) - k tau v1 + g) / m.
        let (k, tau, rest) = (3e4, 0.01, 0.0);
        let (mut x, mut v) = (-1e-4, 0.02);
        let expect_v = (v + h * (k * (rest - x) + g) / m) / (1.0 + h * k * (h + tau) / m);
        row_step(&mut x, &mut v, m, g, k, h, tau, rest);
        assert!(
            (v - expect_v).abs() < 1e-12 * expect_v.abs().max(1.0),
            "{v} {expect_v}"
        );
        // k h^2 / m from 0.1 to 1e5 (an explicit force is unstable from 4), damped or
        // not: the body comes to rest where the spring carries the other force, exactly.
        for k in [1.25e3, 3e4, 1e6, 1.25e9] {
            for tau in [0.0, 0.01] {
                let (mut x, mut v) = (0.0, -0.1);
                let mut largest: f64 = 0.0;
                for _ in 0..20_000 {
                    row_step(&mut x, &mut v, m, g, k, h, tau, rest);
                    largest = largest.max(x.abs());
                }
                let at_rest = g / k;
                assert!(
                    (x - at_rest).abs() <= 1e-9 * at_rest.abs().max(1e-12) + 1e-15,
                    "k {k} tau {tau}: x {x} vs {at_rest}"
                );
                // Never beyond the undamped spring's own amplitude about its rest,
                // `|v0| / omega`, from the start 2 |g| / k away at most: no energy gained.
                let amplitude = 0.1 / (k / m).sqrt() + 2.0 * (g / k).abs();
                assert!(largest <= amplitude, "k {k}: {largest} > {amplitude}");
            }
        }
        // No stiffness, no force: the row carries nothing.
        let row = implicit_row(0.0, 0.0, h, 0.01);
        assert_eq!(
            row,
            ImplicitRow {
                mass: ROW_FLOOR,
                offset: 0.0
            }
        );
    }

    #[test]
    fn the_linearised_force_follows_the_stiffness_and_keeps_to_the_cone() {
        let w = Wrench {
            force: Vector3::new(0.1, 0.0, 2.0),
            torque: Vector3::zeros(),
        };
        // Unmoved: the solve's force; the stiffness 1.5 F / d.
        let l = linearise(&w, Vector3::zeros(), 4e-4, None, None, 0.43, 1.0);
        assert_eq!(l.force, w.force);
        assert!((l.normal - 1.5 * 2.0 / 4e-4).abs() < 1e-9);
        assert!((l.tangential - l.normal * tangential_ratio(0.43)).abs() < 1e-9);
        // 10 um deeper (and 10 um deeper in MuJoCo's contact too): the depth at the solve
        // was 4e-4, the force follows Hertz's power law, and the stiffness is its own now.
        let deeper = Vector3::new(0.0, 0.0, -1e-5);
        let l = linearise(&w, deeper, 4.1e-4, None, None, 0.43, 1.0);
        let hertz = 2.0 * (4.1f64 / 4.0).powf(1.5);
        assert!((l.force.z - hertz).abs() < 1e-12, "{}", l.force.z);
        assert!((l.normal - 1.5 * hertz / 4.1e-4).abs() < 1e-9 * l.normal);
        // Out of the gel: never a pull.
        let out = linearise(&w, Vector3::new(0.0, 0.0, 1e-3), 0.0, None, None, 0.43, 1.0);
        assert_eq!(out.force, Vector3::zeros());
        // Sliding far: the tangential force stops at the cone; without friction there is
        // no tangential stiffness.
        let slid = linearise(
            &w,
            Vector3::new(-1e-3, 0.0, 0.0),
            4e-4,
            None,
            None,
            0.43,
            0.5,
        );
        assert!((slid.force.x - 0.5 * 2.0).abs() < 1e-12, "{}", slid.force.x);
        assert_eq!(
            linearise(&w, Vector3::zeros(), 4e-4, None, None, 0.43, 0.0).tangential,
            0.0
        );
        // No force at the solve: nothing now.
        let none = Wrench::default();
        assert_eq!(
            linearise(&none, deeper, 1e-4, None, None, 0.43, 1.0).normal,
            0.0
        );
    }

    #[test]
    fn the_gel_is_solved_again_past_a_fifth_of_the_depth() {
        assert!(!needs_solve(0.0, 0.0));
        assert!(!needs_solve(RESOLVE_FLOOR, 0.0));
        assert!(needs_solve(1.01 * RESOLVE_FLOOR, 0.0));
        assert!(!needs_solve(0.19e-3, 1e-3));
        assert!(needs_solve(0.21e-3, 1e-3));
        assert!(needs_solve(f64::NAN, 1e-3));
        // The centre of pressure: where the torque puts the normal force.
        let w = Wrench {
            force: Vector3::new(0.0, 0.0, 2.0),
            torque: Vector3::new(2.0 * 0.003, -2.0 * 0.001, 0.0),
        };
        let c = centre_of_pressure(&w).unwrap();
        assert!((c - Vector3::new(0.001, 0.003, 0.0)).norm() < 1e-15, "{c}");
        assert!(centre_of_pressure(&Wrench::default()).is_none());
    }

    #[test]
    fn the_tangential_stiffness_is_measured_where_both_solves_stick() {
        let w = |fx: f64, fy: f64, fz: f64| Wrench {
            force: Vector3::new(fx, fy, fz),
            torque: Vector3::zeros(),
        };
        // Moved 0.1 mm along x and y: the force along the motion fell by k times it.
        let k = 4e3;
        let moved = Vector3::new(0.6e-4, 0.8e-4, -1e-6);
        let then = w(0.1, -0.2, 2.0);
        let now = w(0.1 - k * 0.6e-4, -0.2 - k * 0.8e-4, 2.0);
        let got = tangential_secant(&then, &now, moved, 0.5).unwrap();
        assert!((got - k).abs() < 1e-9 * k, "{got}");
        // Not measured: without friction; with a solve at its cone (sliding: the cone's
        // force, not a stiffness's); a change within the solves' tolerance; a force that
        // grew along the motion; no motion along the surface; a NaN.
        assert!(tangential_secant(&then, &now, moved, 0.0).is_none());
        let sliding = w(0.95, 0.0, 2.0);
        assert!(tangential_secant(&sliding, &now, moved, 0.5).is_none());
        assert!(tangential_secant(&then, &w(0.1 - 0.01, -0.2, 2.0), moved, 0.5).is_none());
        assert!(tangential_secant(&now, &then, moved, 0.5).is_none());
        assert!(tangential_secant(&then, &now, Vector3::new(0.0, 0.0, 1e-4), 0.5).is_none());
        assert!(tangential_secant(&then, &now, Vector3::new(f64::NAN, 0.0, 0.0), 0.5).is_none());
        // Followed between solves at twice the measured, within Mindlin's estimate above
        // (here 5.4e3) and a fiftieth of it below.
        let l = linearise(&then, Vector3::zeros(), 4e-4, None, Some(1e3), 0.43, 0.5);
        assert_eq!(l.tangential, TANGENTIAL_MARGIN * 1e3);
        let most = l.normal * tangential_ratio(0.43);
        let stiff = linearise(&then, Vector3::zeros(), 4e-4, None, Some(1e12), 0.43, 0.5);
        assert_eq!(stiff.tangential, most);
        let soft = linearise(&then, Vector3::zeros(), 4e-4, None, Some(1e-3), 0.43, 0.5);
        assert!((soft.tangential - TANGENTIAL_RANGE[0] * most).abs() < 1e-9 * most);
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let l = linearise(&then, Vector3::zeros(), 4e-4, None, Some(bad), 0.43, 0.5);
            assert_eq!(l.tangential, most);
        }
        // Without friction, no tangential stiffness.
        let l = linearise(&then, Vector3::zeros(), 4e-4, None, Some(k), 0.43, 0.0);
        assert_eq!(l.tangential, 0.0);
    }

    #[test]
    fn the_reduced_mass_follows_a_fixed_body() {
        assert_eq!(reduced_mass(f64::INFINITY, 2.0), 2.0);
        assert_eq!(reduced_mass(3.0, f64::INFINITY), 3.0);
        assert!((reduced_mass(2.0, 2.0) - 1.0).abs() < 1e-15);
        assert!(reduced_mass(f64::INFINITY, f64::INFINITY).is_infinite());
    }

    /// A contact whose force is a power law of its depth (a flat punch's, a sphere's, a
    /// cone's) is followed exactly between solves, deeper or shallower, however far: the
    /// straight line along its stiffness at the solve is not (a sphere's force left by
    /// about `3/8 (motion / depth)^2` of itself).
    #[test]
    fn a_power_law_contact_is_followed_exactly_between_solves() {
        let (d0, c) = (4e-4, 3.0);
        for n in [1.0, 1.5, 2.0] {
            let law = |d: f64| c * (d / d0).powf(n);
            let solved = Wrench {
                force: Vector3::new(0.0, 0.0, law(d0)),
                torque: Vector3::zeros(),
            };
            let k0 = n * law(d0) / d0;
            for d in [0.2e-3, 0.36e-3, 0.48e-3, 0.8e-3] {
                let moved = Vector3::new(0.0, 0.0, d0 - d);
                let l = linearise(&solved, moved, d, Some(k0), None, 0.43, 0.0);
                assert!(
                    (l.force.z - law(d)).abs() < 1e-12 * law(d),
                    "n {n}, {d}: {}",
                    l.force.z
                );
                assert!(
                    (l.normal - n * law(d) / d).abs() < 1e-9 * l.normal,
                    "n {n}, {d}"
                );
                let line = (law(d0) - k0 * (d0 - d)).max(0.0);
                if n > 1.0 {
                    // (Its leading term: n (n - 1) / 2 (motion / depth)^2, 0.4 % and more here.)
                    let off = (line - law(d)).abs() / law(d);
                    assert!(off > 1e-3, "n {n}, {d}: {off}");
                }
            }
            // Out of the gel: nothing, and no stiffness.
            let out = linearise(
                &solved,
                Vector3::new(0.0, 0.0, d0),
                0.0,
                Some(k0),
                None,
                0.43,
                0.0,
            );
            assert_eq!((out.force.z, out.normal), (0.0, 0.0));
        }
        // An apparent exponent of 4 (a discretised gel's force, started where a contact
        // point was reached): the cone's law, carrying the stiffness at the solve, with a
        // force that starts at a positive depth (here where (d / d0)^2 = 1/2).
        let (f0, k0) = (3.0, 4.0 * 3.0 / d0);
        let at = |d: f64| power_law(f0, k0, d0, d);
        assert_eq!(at(d0).0, f0);
        let h = 1e-9;
        let slope = (at(d0 + h).0 - at(d0 - h).0) / (2.0 * h);
        assert!((slope - k0).abs() < 1e-5 * k0, "{slope}");
        assert!((at(d0 + h).1 - k0).abs() < 1e-5 * k0);
        let start = d0 * 0.5f64.sqrt();
        assert!(at(start * (1.0 + 1e-9)).0 > 0.0 && at(start * (1.0 - 1e-9)).0 == 0.0);
        assert_eq!(power_law(1.0, 1e3, 4e-4, -1e-6), (0.0, 0.0));
        assert_eq!(power_law(f64::NAN, 1e3, 4e-4, 1e-4), (0.0, 0.0));
    }

    /// The secant is the stiffness now of the power law of the depth through both solves'
    /// normal forces (into the gel: the force grows as the centre sinks), within its
    /// bounds of the Hertz estimate; a motion within the solves' own differences, or a
    /// force that fell into the gel, measures nothing.
    #[test]
    fn the_secant_measures_the_gels_stiffness_between_solves() {
        let w = |fz: f64| Wrench {
            force: Vector3::new(0.0, 0.0, fz),
            torque: Vector3::zeros(),
        };
        // A flat punch's, a sphere's and a cone's force, 10 um into the gel or out of it.
        for n in [1.0, 1.5, 2.0] {
            let law = |d: f64| (d / 4e-4).powf(n);
            for dz in [-1e-5, 1e-5] {
                let k = secant(&w(law(4e-4 + dz)), &w(1.0), dz, 4e-4).unwrap();
                let expect = n / 4e-4;
                assert!((k - expect).abs() < 1e-9 * expect, "n {n}, dz {dz}: {k}");
            }
        }
        // Shorter than 0.2 % of the depth (0.8 um): nothing.
        assert!(secant(&w(1.0), &w(1.05), -0.7e-6, 4e-4).is_none());
        assert!(secant(&w(1.0), &w(0.9), -1e-5, 4e-4).is_none());
        assert!(secant(&w(0.0), &w(1.0), -1e-5, 4e-4).is_none());
        assert!(secant(&w(1.0), &w(1.05), f64::NAN, 4e-4).is_none());
        // Bounded: 8 times Hertz's 1.5 F / d at most, half of it at least.
        let hertz = DEPTH_EXPONENT * 2.0 / 4e-4;
        let stiff = secant(&w(1.0), &w(2.0), -1e-6, 4e-4).unwrap();
        assert!(
            (stiff - SECANT_RANGE[1] * hertz).abs() < 1e-9 * hertz,
            "{stiff}"
        );
        let soft = secant(&w(1.0), &w(1.001), -1e-5, 4e-4).unwrap();
        assert!(
            (soft - SECANT_RANGE[0] * DEPTH_EXPONENT * 1.001 / 4e-4).abs() < 1e-6,
            "{soft}"
        );
        // Used in place of the Hertz estimate; one that is no stiffness is not.
        let l = linearise(&w(1.0), Vector3::zeros(), 4e-4, Some(5e3), None, 0.43, 1.0);
        assert_eq!(l.normal, 5e3);
        assert_eq!(l.tangential, 5e3 * tangential_ratio(0.43));
        for bad in [f64::NAN, -1.0, 0.0, f64::INFINITY] {
            let l = linearise(&w(1.0), Vector3::zeros(), 4e-4, Some(bad), None, 0.43, 1.0);
            assert_eq!(l.normal, DEPTH_EXPONENT / 4e-4, "{bad}");
        }
        // Nor is a wrench that is not finite: no push.
        let broken = Wrench {
            force: Vector3::new(f64::NAN, 0.0, 1.0),
            torque: Vector3::zeros(),
        };
        let l = linearise(&broken, Vector3::zeros(), 4e-4, None, None, 0.43, 1.0);
        assert_eq!(l.force, Vector3::zeros());
        let twisted = Wrench {
            force: Vector3::new(0.0, 0.0, 1.0),
            torque: Vector3::new(0.0, 0.0, f64::INFINITY),
        };
        let l = linearise(&twisted, Vector3::zeros(), 4e-4, None, None, 0.43, 1.0);
        assert_eq!((l.force, l.twist), (Vector3::zeros(), 0.0));
    }

    /// Four contact points at the corners of a 30 x 20 mm face, even shares: a turn about
    /// the normal meets the points' tangential springs and a tilt their normal ones, each
    /// with the torque of springs at the points (to first order in the angle), the
    /// solve's twist is carried whole, and none of it is a net force.
    #[test]
    fn contact_points_resist_a_turn_and_carry_the_twist() {
        let points = [
            (0.015, 0.01),
            (-0.015, 0.01),
            (-0.015, -0.01),
            (0.015, -0.01),
        ];
        let offsets: Vec<Vector3<f64>> = points
            .iter()
            .map(|&(x, y)| Vector3::new(x, y, 0.0))
            .collect();
        let share = 0.25;
        let spread: f64 = offsets.iter().map(|r| share * r.xy().norm_squared()).sum();
        let (kt, kn, twist, angle) = (2e3, 5e3, 0.01, 1e-5);
        let totals_with = |turned: UnitQuaternion<f64>, gels: f64| {
            let l = Linearised {
                force: Vector3::zeros(),
                normal: kn,
                tangential: kt,
                centre: Some(Vector3::zeros()),
                twist,
                turned,
                spread: gels,
            };
            offsets
                .iter()
                .fold((Vector3::zeros(), Vector3::zeros()), |(f, t), r| {
                    let p = l.at_point(*r, share, spread);
                    (f + p, t + r.cross(&p))
                })
        };
        let totals = |turned: UnitQuaternion<f64>| totals_with(turned, 0.0);
        // Unturned: the twist alone.
        let (f, t) = totals(UnitQuaternion::identity());
        assert!(f.norm() < 1e-15, "{f}");
        assert!((t - Vector3::new(0.0, 0.0, twist)).norm() < 1e-15, "{t}");
        // Turned about the normal: the tangential springs' torque against it.
        let (f, t) = totals(UnitQuaternion::from_axis_angle(&Vector3::z_axis(), angle));
        assert!(f.norm() < 1e-12, "{f}");
        let expected = twist - kt * angle * spread;
        assert!((t.z - expected).abs() < 1e-6 * twist, "{} {expected}", t.z);
        // Tilted about x: the normal springs' torque against it.
        let (f, t) = totals(UnitQuaternion::from_axis_angle(&Vector3::x_axis(), angle));
        assert!(f.norm() < 1e-12, "{f}");
        let lever: f64 = offsets.iter().map(|r| share * r.y * r.y).sum();
        assert!(
            (t.x + kn * angle * lever).abs() < 1e-4 * kn * angle * lever,
            "{}",
            t.x
        );
        // The gel's contact spread a third as far as the corners: a third of their springs'
        // torque against the turn and the tilt; spread further, or lumped to next to
        // nothing, within [`TURN_RANGE`]; the twist as it was.
        for (gels, scale) in [
            (spread / 3.0, 1.0 / 3.0),
            (5.0 * spread, TURN_RANGE[1]),
            (1e-3 * spread, TURN_RANGE[0]),
        ] {
            let z = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), angle);
            let (f, t) = totals_with(z, gels);
            assert!(f.norm() < 1e-12, "{f}");
            let expected = twist - scale * kt * angle * spread;
            assert!((t.z - expected).abs() < 1e-6 * twist, "{} {expected}", t.z);
            let x = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), angle);
            let (_, t) = totals_with(x, gels);
            let expected = -scale * kn * angle * lever;
            assert!(
                (t.x - expected).abs() < 1e-4 * expected.abs(),
                "{} {expected}",
                t.x
            );
        }
    }
}
