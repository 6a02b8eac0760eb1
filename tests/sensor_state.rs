//! Sensor state and frames through the real plugin in the real libmujoco: what
//! `mj_resetData` and `mj_copyData` do to a gel with history, `rom` in several threads,
//! invariance of the outputs under a rigid motion of the whole scene, and the image and
//! force orientation of an off-centre press.
//!
//! Every scene is cheap: 32 x 24 images, the coarse grid, presses of at most 1 mm.

mod common;

use common::*;

const W: usize = 32;
const H: usize = 24;
const FOV: [f64; 2] = [0.024, 0.018];
const N: usize = W * H;

/// Joint order of [`scene`]: qpos = [x, y, press].
#[derive(Clone, Copy, Debug)]
struct Pose {
    x: f64,
    y: f64,
    press: f64,
}

const fn at(x: f64, y: f64, press: f64) -> Pose {
    Pose { x, y, press }
}

/// A sensor (site `gel`, top face at the frame's origin) and one indenter body on three
/// slide joints (qpos = [x, y, press], press positive into the gel), both inside a static
/// body `frame` whose attributes are `frame` (empty: the world origin). `lift` is the
/// indenter body's height above the gel, `geom` its geom.
fn scene(config: &str, frame: &str, lift: f64, geom: &str) -> String {
    format!(
        r#"<mujoco>
  <extension><plugin plugin="tacrom.tactile"/></extension>
  <option gravity="0 0 0"/>
  <worldbody>
    <body name="frame" {frame}>
      <body name="sensor">
        <geom name="pad" type="box" size="0.015 0.015 0.002" pos="0 0 -0.006"/>
        <site name="gel"/>
      </body>
      <body name="indenter" pos="0 0 {lift}">
        <joint name="x" type="slide" axis="1 0 0"/>
        <joint name="y" type="slide" axis="0 1 0"/>
        <joint name="press" type="slide" axis="0 0 -1"/>
        {geom}
      </body>
    </body>
  </worldbody>
  <sensor>
    <plugin name="touch" plugin="tacrom.tactile" objtype="site" objname="gel">
      {config}
    </plugin>
  </sensor>
</mujoco>"#
    )
}

/// Sphere of radius 5 mm touching the gel at qpos = 0, centred over the gel.
const SPHERE_R: f64 = 0.005;
fn sphere_geom() -> String {
    format!(r#"<geom type="sphere" size="{SPHERE_R}" contype="0" conaffinity="0"/>"#)
}

fn sensor_config(physics: &str, outputs: &str, extra: &[(&str, &str)]) -> String {
    let res = format!("{W} {H}");
    let mut pairs = vec![
        ("physics", physics),
        ("outputs", outputs),
        ("resolution", res.as_str()),
    ];
    pairs.extend_from_slice(extra);
    config(&pairs)
}

fn sphere_model(physics: &str, extra: &[(&str, &str)]) -> Model {
    load_xml(&scene(
        &sensor_config(physics, "depth force", extra),
        "",
        SPHERE_R,
        &sphere_geom(),
    ))
    .expect("model loads")
}

/// Poses the indenter, runs `mj_forward` and returns the sensordata (depth, then force).
fn eval(m: &Model, d: &mut Data, p: Pose) -> Vec<f64> {
    d.set_qpos(0, p.x);
    d.set_qpos(1, p.y);
    d.set_qpos(2, p.press);
    d.forward(m);
    d.sensor(m, 0)
}

fn force(v: &[f64]) -> [f64; 3] {
    [v[N], v[N + 1], v[N + 2]]
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// A deep frictional press slid 1.5 mm sideways: a gel with history (sheared, stuck
/// contact) that a shallow press from rest never reaches.
const HISTORY: [Pose; 6] = [
    at(0.0, 0.0, 0.5e-3),
    at(0.0, 0.0, 1.0e-3),
    at(0.5e-3, 0.0, 1.0e-3),
    at(1.0e-3, 0.0, 1.0e-3),
    at(1.5e-3, 0.0, 1.0e-3),
    at(1.5e-3, 0.2e-3, 0.9e-3),
];
/// The shallow press evaluated after the history (or on a fresh gel): under the slid
/// sphere, so without a reset the gel is still in contact and keeps its shear.
const SHALLOW: Pose = at(1.5e-3, 0.2e-3, 0.2e-3);

/// Catches: `mj_resetData` not restoring the undeformed gel (a no-op or partial
/// `TactileSensor::reset` / `Gel::reset`, the plugin's reset callback not wired). After a
/// deep frictional slide and a reset, one shallow press must give exactly what a fresh
/// `mjData` gives for that press.
///
/// Tolerance: none (bit for bit). The reset gel and the fresh gel are the same
/// deterministic computation on the same inputs with the same thread count; any
/// difference is state that survived the reset. The test has teeth: the same press
/// without the reset differs by more than 10 % of the press depth or of the force.
#[test]
fn reset_after_frictional_slide_equals_a_fresh_gel() {
    let m = sphere_model("coarse", &[("friction", "1.0")]);
    let mut d = m.make_data();
    for p in HISTORY {
        eval(&m, &mut d, p);
    }
    // Without a reset: the history shows (the copy keeps it; the original is reset below).
    let mut kept = d.copy(&m);
    let with_history = eval(&m, &mut kept, SHALLOW);

    d.reset(&m);
    let after_reset = eval(&m, &mut d, SHALLOW);
    let fresh = eval(&m, &mut m.make_data(), SHALLOW);

    let fz = force(&fresh)[2];
    assert!(fz > 0.0, "the shallow press must load the gel: fz {fz}");
    assert_eq!(after_reset, fresh, "reset gel differs from a fresh gel");

    let ddepth = max_abs_diff(&with_history[..N], &fresh[..N]);
    let dforce = max_abs_diff(&with_history[N..], &fresh[N..]);
    assert!(
        ddepth > 0.1 * SHALLOW.press || dforce > 0.1 * fz,
        "history does not show: depth differs by {ddepth:e} m, force by {dforce:e} N \
         (fz {fz:e})"
    );
}

/// The trajectory of the copy test: a frictional press slid sideways, copied after
/// `COPY_AT` frames, then slid on, lifted part way and slid back.
const TRAJECTORY: [Pose; 7] = [
    at(0.0, 0.0, 0.4e-3),
    at(0.0, 0.0, 0.8e-3),
    at(0.5e-3, 0.0, 0.8e-3),
    at(1.0e-3, 0.0, 0.8e-3),
    at(1.5e-3, 0.3e-3, 0.8e-3),
    at(1.5e-3, 0.3e-3, 0.5e-3),
    at(1.2e-3, 0.3e-3, 0.4e-3),
];
const COPY_AT: usize = 4;

/// Catches: `mj_copyData` not carrying the sensor's state (the copy callback building a
/// fresh sensor, a shallow copy sharing the gel or the reduced-order model's sessions,
/// part of the state left behind). Original and copy continue the same trajectory and
/// must agree exactly every frame; and the copy's last frame must differ from a fresh gel
/// pressed straight to the final pose, so the state it carried mattered.
///
/// Tolerance: none (bit for bit) between original and copy: the same deterministic
/// computation from the same state. The history check asks for a difference above 5 % of
/// the final press depth or of the final normal force.
fn copy_continues_identically(physics: &str, extra: &[(&str, &str)]) {
    let m = sphere_model(physics, extra);
    let mut original = m.make_data();
    for &p in &TRAJECTORY[..COPY_AT] {
        eval(&m, &mut original, p);
    }
    let mut copy = original.copy(&m);
    assert_eq!(copy.sensor(&m, 0), original.sensor(&m, 0));
    let mut last = Vec::new();
    for (i, &p) in TRAJECTORY[COPY_AT..].iter().enumerate() {
        let a = eval(&m, &mut original, p);
        let b = eval(&m, &mut copy, p);
        assert!(a[..N].iter().any(|&v| v > 0.0), "frame {i}: no contact");
        assert_eq!(a, b, "{physics}: frame {i} after the copy differs");
        last = b;
    }
    let final_pose = *TRAJECTORY.last().unwrap();
    let fresh = eval(&m, &mut m.make_data(), final_pose);
    let fz = force(&fresh)[2];
    assert!(fz > 0.0, "{physics}: fz {fz}");
    let ddepth = max_abs_diff(&last[..N], &fresh[..N]);
    let dforce = max_abs_diff(&last[N..], &fresh[N..]);
    assert!(
        ddepth > 0.05 * final_pose.press || dforce > 0.05 * fz,
        "{physics}: history does not show: depth differs by {ddepth:e} m, force by \
         {dforce:e} N (fz {fz:e})"
    );
}

#[test]
fn copy_of_coarse_gel_continues_identically_and_keeps_history() {
    copy_continues_identically("coarse", &[("friction", "1.0")]);
}

/// `rom` needs the shipped model's gel: default size, material and friction (0.5).
#[test]
fn copy_of_rom_sensor_continues_identically_and_keeps_history() {
    copy_continues_identically("rom", &[]);
}

/// Catches: state shared between the `mjData` of one `rom` model (a global session, a
/// shared latent or warm start, a data race in ONNX Runtime or the MPM pool). Two `mjData`
/// run the same frictional press sequence, once one after the other and once on two
/// threads started together; every frame must agree bit for bit.
///
/// Tolerance: none. Each `mjData` owns its gel and its ONNX sessions, and the results do
/// not depend on thread count or timing (docs/configuration.md), so any difference is shared state.
#[test]
fn rom_in_two_threads_matches_serial_bit_for_bit() {
    let m = sphere_model("rom", &[]);
    let presses = &TRAJECTORY[..5];
    let run = |m: &Model| -> Vec<Vec<f64>> {
        let mut d = m.make_data();
        presses.iter().map(|&p| eval(m, &mut d, p)).collect()
    };
    let serial = [run(&m), run(&m)];
    assert_eq!(serial[0], serial[1], "two serial runs differ");
    assert!(serial[0].iter().all(|v| v[..N].iter().any(|&x| x > 0.0)));
    let barrier = std::sync::Barrier::new(2);
    let parallel: Vec<Vec<Vec<f64>>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..2)
            .map(|_| {
                let (m, barrier) = (&m, &barrier);
                s.spawn(move || {
                    let mut d = m.make_data();
                    barrier.wait();
                    presses.iter().map(|&p| eval(m, &mut d, p)).collect()
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for (t, run) in parallel.iter().enumerate() {
        for (i, (a, b)) in run.iter().zip(&serial[t]).enumerate() {
            assert_eq!(a, b, "thread {t}, frame {i} differs from the serial run");
        }
    }
}

/// An asymmetric indenter off the gel's centre: a box 4 x 1.6 x 2 mm, turned 25 degrees
/// about z and tilted 6 degrees about x, its centre over (+3, +2) mm.
const TILTED_BOX: &str = r#"<geom type="box" size="0.002 0.0008 0.001" pos="0.003 0.002 0.001"
        euler="6 0 25" contype="0" conaffinity="0"/>"#;
/// The press sequence of the invariance test: down, then slid with friction.
const INVARIANCE_PRESSES: [Pose; 3] = [
    at(0.0, 0.0, 0.3e-3),
    at(0.0, 0.0, 0.5e-3),
    at(0.4e-3, -0.2e-3, 0.5e-3),
];
/// Where the whole scene goes: 0.9 m from the origin, turned 37 degrees about a
/// non-vertical axis.
const MOVED_FRAME: &str = r#"pos="0.4 -0.25 0.76" axisangle="1 2 0.5 37""#;
const MOVED_DISTANCE: f64 = 0.9125; // |(0.4, -0.25, 0.76)|, rounded up

/// Catches: a sensor frame built wrongly from the site (rotation transposed, poses
/// composed in the wrong order, the force or an image axis left in world coordinates).
/// The same scene at the origin and moved rigidly in the world must give the same depth
/// images and the same force in the sensor frame.
///
/// Tolerance: the moved scene's relative pose carries the round-off of MuJoCo's forward
/// kinematics and of `site^-1 * geom`: a few operations of relative error eps = 2.2e-16 on
/// world coordinates of size 0.91 m, so about 1e-15 m. Rigid depth is the indenter's
/// height at a pixel, linear in that pose error; we allow 64 eps x 0.91 m = 1.3e-14 m, and
/// the contact masks must be equal. Coarse: the MPM gel computes in f32 (eps 1.2e-7), so
/// the 1e-15 m perturbation flips last bits of its state, and the iterative solve carries
/// those flips on; with round-off accumulating at most linearly, each iteration adds at
/// most about eps relative error, and a frame runs at most the solver's iteration cap
/// (3000 steps on this gel). The bound is frames x 3000 x eps(f32), relative to the peak
/// depth and to the force's magnitude: 1.1e-3 after the third frame (measured: 1.3e-5 in
/// depth, 6e-6 in force). A transposed rotation or a world-frame force is off by order 1.
fn invariance(physics: &str, tolerance: impl Fn(usize, f64) -> (f64, f64)) {
    // Rigid penetration has no force: its second output is the contact mask instead.
    let outputs = if physics == "rigid" {
        "depth contact"
    } else {
        "depth force"
    };
    let cfg = sensor_config(physics, outputs, &[("friction", "1.0")]);
    let origin = load_xml(&scene(&cfg, "", 0.0, TILTED_BOX)).expect("origin scene");
    let moved = load_xml(&scene(&cfg, MOVED_FRAME, 0.0, TILTED_BOX)).expect("moved scene");
    let (mut d0, mut d1) = (origin.make_data(), moved.make_data());
    for (i, &p) in INVARIANCE_PRESSES.iter().enumerate() {
        let a = eval(&origin, &mut d0, p);
        let b = eval(&moved, &mut d1, p);
        let touched = a[..N].iter().filter(|&&v| v > 0.0).count();
        assert!(touched > 4, "{physics} frame {i}: {touched} pixels touched");
        let dd = max_abs_diff(&a[..N], &b[..N]);
        let peak = a[..N].iter().cloned().fold(0.0, f64::max);
        let (depth_tol, force_rel_tol) = tolerance(i + 1, peak);
        if physics == "rigid" {
            assert!(
                dd <= depth_tol,
                "{physics} frame {i}: depth differs by {dd:e} m"
            );
            assert_eq!(a[N..], b[N..], "{physics} frame {i}: contact masks differ");
            continue;
        }
        let (fa, fb) = (force(&a), force(&b));
        let fnorm = fa.iter().map(|f| f * f).sum::<f64>().sqrt();
        let df = max_abs_diff(&fa, &fb);
        eprintln!("{physics} frame {i}: depth diff {dd:e} m, force diff {df:e} N of {fnorm:e}");
        assert!(
            dd <= depth_tol,
            "{physics} frame {i}: depth differs by {dd:e} m"
        );
        assert!(
            df <= force_rel_tol * fnorm,
            "{physics} frame {i}: force {fa:?} at the origin, {fb:?} moved"
        );
    }
}

#[test]
fn rigid_outputs_are_invariant_under_a_rigid_motion_of_the_scene() {
    invariance("rigid", |_, _| (64.0 * f64::EPSILON * MOVED_DISTANCE, 0.0));
}

#[test]
fn coarse_outputs_are_invariant_under_a_rigid_motion_of_the_scene() {
    const ITERATION_CAP: f64 = 3000.0;
    invariance("coarse", |frames, peak| {
        let rel = frames as f64 * ITERATION_CAP * f32::EPSILON as f64;
        (rel * peak, rel)
    });
}

/// rom: the coarse gel's bound, carried through the encoder and decoder, which move their
/// output by their input's change times their gain; 10 x the coarse bound allows a gain of
/// 10 (measured: rom's depth differs by 9.7e-9 m after three frames where coarse's differs
/// by 7.8e-9 m, a gain of 1.25). A transposed rotation or a world-frame force is still off
/// by order 1, a thousand times this bound.
#[test]
fn rom_outputs_are_invariant_under_a_rigid_motion_of_the_scene() {
    const ITERATION_CAP: f64 = 3000.0;
    invariance("rom", |frames, peak| {
        let rel = 10.0 * frames as f64 * ITERATION_CAP * f32::EPSILON as f64;
        (rel * peak, rel)
    });
}

/// Pixel centre (x, y) in the sensor frame, as docs/configuration.md documents the layout.
fn pixel_centre(row: usize, col: usize) -> (f64, f64) {
    let x = -0.5 * FOV[0] + (col as f64 + 0.5) * FOV[0] / W as f64;
    let y = 0.5 * FOV[1] - (row as f64 + 0.5) * FOV[1] / H as f64;
    (x, y)
}

/// Centroid and second moments (x, y) of an image's depth, with pixel positions from the
/// documented layout.
fn moments(depth: &[f64]) -> ([f64; 2], [f64; 2]) {
    let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (i, &v) in depth.iter().enumerate() {
        let (x, y) = pixel_centre(i / W, i % W);
        s += v;
        sx += v * x;
        sy += v * y;
    }
    let c = [sx / s, sy / s];
    let (mut vx, mut vy) = (0.0, 0.0);
    for (i, &v) in depth.iter().enumerate() {
        let (x, y) = pixel_centre(i / W, i % W);
        vx += v * (x - c[0]).powi(2);
        vy += v * (y - c[1]).powi(2);
    }
    (c, [vx / s, vy / s])
}

/// The orientation press: a box 6 x 2 mm (long along x) centred at (+5, +3) mm.
const ORIENTATION_BOX: &str = r#"<geom type="box" size="0.003 0.001 0.001" pos="0.005 0.003 0.001"
        contype="0" conaffinity="0"/>"#;

/// Catches: a mirrored or transposed image (row order, column order, an axis flipped in
/// the scene transform). A box long along x pressed at (+5, +3) mm must appear right of
/// the centre column and above the centre row, at its documented pixel position
/// (docs/configuration.md: row 0 is the +y edge, column 0 the -x edge, pixel centres at
/// x = -fov_x/2 + (col + 0.5) fov_x / W, y = fov_y/2 - (row + 0.5) fov_y / H), and wider
/// than tall.
///
/// Tolerance: the depth-weighted centroid within one pixel (0.75 mm) of the box centre.
/// The footprint is symmetric about the box centre (a flat box pressed straight; the gel's
/// sag is symmetric to within the gel edge's pull, 10 mm away), and the sampling of its
/// edges on the 0.75 mm pixel grid shifts the centroid by less than a pixel. A flipped
/// axis moves it by 10 or 6 mm.
fn orientation(physics: &str) {
    let cfg = sensor_config(physics, "depth", &[]);
    let m = load_xml(&scene(&cfg, "", 0.0, ORIENTATION_BOX)).expect("model loads");
    let mut d = m.make_data();
    let out = eval(&m, &mut d, at(0.0, 0.0, 0.3e-3));
    let depth = &out[..N];
    let peak = (0..N)
        .max_by(|&a, &b| depth[a].total_cmp(&depth[b]))
        .unwrap();
    let (row, col) = (peak / W, peak % W);
    assert!(depth[peak] > 0.2e-3, "{physics}: peak {}", depth[peak]);
    assert!(
        col >= W / 2 && row < H / 2,
        "{physics}: deepest pixel at row {row}, col {col}: expected right of and above the \
         centre"
    );
    let (c, var) = moments(depth);
    let pixel = FOV[0] / W as f64;
    assert!(
        (c[0] - 0.005).abs() < pixel && (c[1] - 0.003).abs() < pixel,
        "{physics}: depth centroid at ({:.2}, {:.2}) mm, box at (5, 3) mm",
        c[0] * 1e3,
        c[1] * 1e3
    );
    assert!(
        var[0] > 2.0 * var[1],
        "{physics}: footprint must be long along x: second moments {var:?}"
    );
}

#[test]
fn rigid_image_orientation_off_centre_box() {
    orientation("rigid");
}

#[test]
fn coarse_image_orientation_off_centre_box() {
    orientation("coarse");
}

#[test]
fn rom_image_orientation_off_centre_box() {
    orientation("rom");
}

/// Catches: a force with the wrong sign or axes (reported on the gel instead of on the
/// indenter, an axis flipped in the scene transform, world instead of sensor frame). The
/// documented force is that of the gel on the indenters in the sensor frame: a sphere
/// pressed into the gel is pushed out, +z; slid along +x (then +y) with friction, the gel
/// drags it back, so the force's x (then y) component is negative, and a sizeable part of
/// the normal force (Coulomb, friction 1.0: the sliding bound is fz; the test asks for
/// 10 % of fz, well inside the stick-slip range of a 0.6 mm slide at 0.6 mm depth). The
/// other lateral component stays below it (symmetry of the sphere about the slide plane,
/// up to the coarse grid: under half the dragging component).
fn slide_force(physics: &str, friction: &str) {
    let m = sphere_model(physics, &[("friction", friction)]);
    for axis in 0..2 {
        let mut d = m.make_data();
        let mut f = [0.0; 3];
        for step in 0..4 {
            let s = 0.2e-3 * step as f64;
            let p = if axis == 0 {
                at(s, 0.0, 0.6e-3)
            } else {
                at(0.0, s, 0.6e-3)
            };
            f = force(&eval(&m, &mut d, p));
            assert!(
                f[2] > 0.0,
                "{physics}: the gel must push the sphere out: {f:?}"
            );
        }
        let (along, across) = (f[axis], f[1 - axis]);
        assert!(
            along < -0.1 * f[2],
            "{physics}: sliding along +{} the gel must drag back (negative): {f:?}",
            ["x", "y"][axis]
        );
        assert!(across.abs() < 0.5 * along.abs(), "{physics}: {f:?}");
    }
}

#[test]
fn coarse_slide_force_opposes_motion_in_sensor_frame() {
    slide_force("coarse", "1.0");
}

#[test]
fn rom_slide_force_opposes_motion_in_sensor_frame() {
    slide_force("rom", "0.5");
}
