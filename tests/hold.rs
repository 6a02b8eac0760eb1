//! Held frames through the sensor (no MuJoCo): a frame whose indenters moved less than
//! `hold` (that fraction of it where the depth they reached is a fraction of 0.5 mm) since
//! the last solve is that solve's frame again, bit for bit and without a solve; a longer
//! motion, a turn whose corners move further, a shallower contact or `hold="0"` solves.
//!
//! The scene: the default coarse gel on the linear solver (30 x 30 x 4 mm), 32 x 24 images,
//! a 20 x 20 mm box face pressed 0.4 mm (so the default `hold` of 1 um holds 0.8 um).

use std::sync::{Arc, OnceLock};

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use tacrom::config::{
    Config, RawConfig, ATTR_HOLD, ATTR_OUTPUTS, ATTR_PHYSICS, ATTR_RESOLUTION, ATTR_SOLVER,
};
use tacrom::geometry::{Cuboid, Placed, Sdf};
use tacrom::sensor::TactileSensor;

/// Half the box's edge (m).
const HALF: f64 = 0.01;

/// The box face centred over the gel, pressed `depth`, turned `angle` about the gel's
/// normal through its centre and shifted `shift` along x. One shape for every pose.
fn face(depth: f64, angle: f64, shift: f64) -> Placed {
    static BOX: OnceLock<Arc<dyn Sdf>> = OnceLock::new();
    let shape = BOX
        .get_or_init(|| Arc::new(Cuboid::new(Vector3::new(HALF, HALF, HALF))))
        .clone();
    let pose = Isometry3::from_parts(
        Translation3::new(shift, 0.0, HALF - depth),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), angle),
    );
    Placed { shape, pose }
}

fn sensor(extra: &[(&str, &str)]) -> TactileSensor {
    let raw = extra.iter().fold(
        RawConfig::default()
            .with(ATTR_PHYSICS, "coarse")
            .with(ATTR_SOLVER, "linear")
            .with(ATTR_OUTPUTS, "depth force")
            .with(ATTR_RESOLUTION, "32 24"),
        |r, (a, v)| r.with(a, v),
    );
    TactileSensor::new(Config::from_raw("touch", &raw).expect("valid configuration"))
        .expect("sensor")
}

/// Evaluates `p`; returns the sensordata and whether the frame was held.
fn frame(s: &mut TactileSensor, p: Placed) -> (Vec<f64>, bool) {
    let mut out = vec![f64::NAN; s.config().sensordata_len()];
    let eval = s.evaluate(&[p], &mut out);
    assert_eq!(
        eval.held,
        eval.solve.is_none(),
        "a held frame solves nothing"
    );
    (out, eval.held)
}

/// Catches: a hold that solves anyway, gives other outputs than the last solve's, holds a
/// motion past `hold` or past its share at a shallower depth than 0.5 mm, does not scale
/// with `hold`, or measures a turn at the indenter's centre (where it moves nothing)
/// instead of the corners of the box it reaches.
///
/// Tolerance: none for the held frames (they are the last solve's outputs, written
/// again). The motions sit on both sides of the bound: 0.5 um held and 0.9 um not (the
/// bound 0.8 um at 0.4 mm deep); the turn moves the corners of the box's reach (14.1 mm
/// from the centre) 0.5 um, then 1.4 um.
#[test]
fn a_frame_moved_less_than_hold_is_the_last_solve_again() {
    let mut s = sensor(&[]);
    let (first, held) = frame(&mut s, face(4e-4, 0.0, 0.0));
    assert!(!held);
    assert!(
        first[first.len() - 1] > 0.1,
        "pressed: {}",
        first[first.len() - 1]
    );
    let (again, held) = frame(&mut s, face(4e-4, 0.0, 0.0));
    assert!(held);
    assert_eq!(again, first);
    let (shifted, held) = frame(&mut s, face(4e-4, 0.0, 0.5e-6));
    assert!(held);
    assert_eq!(shifted, first);
    let corner = HALF * 2f64.sqrt();
    let (turned, held) = frame(&mut s, face(4e-4, 0.5e-6 / corner, 0.0));
    assert!(held);
    assert_eq!(turned, first);
    // Past the bound: solved, and each later frame is measured from that solve.
    let (moved, held) = frame(&mut s, face(4e-4, 0.0, 0.9e-6));
    assert!(!held);
    assert_ne!(moved, first);
    let (_, held) = frame(&mut s, face(4e-4, 0.0, 0.9e-6 + 0.5e-6));
    assert!(held);
    let (_, held) = frame(&mut s, face(4e-4, 1.4e-6 / corner, 0.9e-6));
    assert!(!held);

    // A contact 0.1 mm deep holds 0.2 um, not 0.5.
    let mut shallow = sensor(&[]);
    assert!(!frame(&mut shallow, face(1e-4, 0.0, 0.0)).1);
    assert!(frame(&mut shallow, face(1e-4, 0.0, 0.1e-6)).1);
    assert!(!frame(&mut shallow, face(1e-4, 0.0, 0.5e-6)).1);

    // hold="5e-6" holds five times as far: 4 um at 0.4 mm deep, 1 um at 0.1 mm.
    let mut loose = sensor(&[(ATTR_HOLD, "5e-6")]);
    assert!(!frame(&mut loose, face(4e-4, 0.0, 0.0)).1);
    assert!(frame(&mut loose, face(4e-4, 0.0, 3.5e-6)).1);
    assert!(!frame(&mut loose, face(4e-4, 0.0, 4.5e-6)).1);
    let mut loose = sensor(&[(ATTR_HOLD, "5e-6")]);
    assert!(!frame(&mut loose, face(1e-4, 0.0, 0.0)).1);
    assert!(frame(&mut loose, face(1e-4, 0.0, 0.9e-6)).1);
    assert!(!frame(&mut loose, face(1e-4, 0.0, 1.1e-6)).1);

    // hold="0" solves every frame, the same pose too.
    let mut every = sensor(&[(ATTR_HOLD, "0")]);
    assert!(!frame(&mut every, face(4e-4, 0.0, 0.0)).1);
    assert!(!frame(&mut every, face(4e-4, 0.0, 0.0)).1);

    // A reset forgets the last solve.
    s.reset();
    assert!(!frame(&mut s, face(4e-4, 0.0, 0.0)).1);
}

/// Catches: a contact the camera does not see (the gel is wider than its view) taken as no
/// depth at all, so that the sensor never holds it and solves at every frame. The hold is
/// measured by the depth the gel took the load at, wherever on the gel.
///
/// Scene: a 5 mm box face pressed 0.4 mm beside the view (its near edge 0.5 mm past it),
/// moved 0.5 um (held: the bound is 0.8 um at 0.4 mm, as above) and then 0.9 um (solved).
/// The view's pixels sink by 0.12 mm at most there (the bound asserted: half the box's
/// depth), so the image alone would give the contact no depth.
#[test]
fn a_contact_outside_the_cameras_view_is_held_by_its_own_depth() {
    const SMALL: f64 = 0.0025;
    let shape: Arc<dyn Sdf> = Arc::new(Cuboid::new(Vector3::new(SMALL, SMALL, SMALL)));
    let mut s = sensor(&[]);
    let [_, view_y] = s.config().fov;
    let [_, gel_y, _] = s.config().size;
    let y = 0.5 * view_y + SMALL + 5e-4;
    assert!(y + SMALL < 0.5 * gel_y, "the box lies on the gel");
    let at = |shift: f64| Placed {
        shape: shape.clone(),
        pose: Isometry3::translation(shift, y, SMALL - 4e-4),
    };
    let (first, held) = frame(&mut s, at(0.0));
    assert!(!held);
    let force = first[first.len() - 1];
    assert!(force > 0.1, "the gel carries the box: {force} N");
    let depth = &first[..first.len() - 3];
    assert!(
        depth.iter().all(|&d| d < 2e-4),
        "the view sees the gel sink beside the box (0.12 mm at most), not the box's 0.4 mm: {}",
        depth.iter().copied().fold(0.0, f64::max)
    );
    let (again, held) = frame(&mut s, at(0.5e-6));
    assert!(held, "0.5 um at 0.4 mm deep is held");
    assert_eq!(again, first);
    assert!(!frame(&mut s, at(0.9e-6)).1, "0.9 um is not");
}
