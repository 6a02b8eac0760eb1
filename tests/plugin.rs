//! The real plugin library loaded into the real libmujoco from MJCF: geometric (rigid)
//! depth images against closed-form answers, orientation, state handling and bad input.

mod common;

use common::*;

const R: f64 = 0.005;
const W: usize = 320;
const H: usize = 240;
const FOV: [f64; 2] = [0.024, 0.018];

fn pixel_centre(row: usize, col: usize) -> (f64, f64) {
    let x = -0.5 * FOV[0] + (col as f64 + 0.5) * FOV[0] / W as f64;
    let y = 0.5 * FOV[1] - (row as f64 + 0.5) * FOV[1] / H as f64;
    (x, y)
}

/// Depth of a rigid sphere of radius R pressed `d` into a flat surface, at distance `r`
/// from its axis: the spherical cap, sqrt(R^2 - r^2) - (R - d), where positive.
fn cap_depth(d: f64, r: f64) -> f64 {
    if r >= R {
        return 0.0;
    }
    ((R * R - r * r).sqrt() - (R - d)).max(0.0)
}

fn sphere_model(extra: &[(&str, &str)]) -> Model {
    let mut pairs = vec![("physics", "rigid")];
    pairs.extend_from_slice(extra);
    load_xml(&press_scene(&config(&pairs), &sphere_body(R))).expect("model loads")
}

#[test]
fn sphere_press_gives_the_spherical_cap() {
    let m = sphere_model(&[]);
    let mut d = m.make_data();
    let depth = 0.5e-3;
    d.set_qpos(0, depth);
    d.forward(&m);
    let img = d.sensor(&m, 0);
    assert_eq!(img.len(), W * H);

    // Everywhere: the analytic cap, to rounding.
    let mut worst = 0.0f64;
    for row in 0..H {
        for col in 0..W {
            let (x, y) = pixel_centre(row, col);
            let expect = cap_depth(depth, (x * x + y * y).sqrt());
            worst = worst.max((img[row * W + col] - expect).abs());
        }
    }
    assert!(
        worst < 1e-9,
        "max deviation from the spherical cap {worst:e} m"
    );

    // Centre: the four pixels around the origin are within 1 um of the press depth.
    let centre = img[(H / 2) * W + W / 2];
    assert!((centre - depth).abs() < 1e-6, "centre depth {centre}");

    // Contact radius from the contact area, within one pixel's footprint of sqrt(2Rd - d^2).
    let px = FOV[0] / W as f64;
    let area = img.iter().filter(|&&v| v > 0.0).count() as f64 * px * px;
    let radius = (area / std::f64::consts::PI).sqrt();
    let expect = (2.0 * R * depth - depth * depth).sqrt();
    assert!(
        (radius - expect).abs() < px,
        "contact radius {radius} vs {expect}"
    );
}

#[test]
fn depth_is_zero_before_contact_and_grows_with_press() {
    let m = sphere_model(&[]);
    let mut d = m.make_data();
    let mut last = -1.0;
    for (i, press) in [-0.5e-3, 0.0, 0.1e-3, 0.3e-3, 0.6e-3, 1.0e-3]
        .into_iter()
        .enumerate()
    {
        d.set_qpos(0, press);
        d.forward(&m);
        let max = d.sensor(&m, 0).into_iter().fold(0.0, f64::max);
        if i < 2 {
            assert_eq!(max, 0.0, "press {press}");
        } else {
            assert!(max > last, "press {press}: {max} after {last}");
            assert!((max - press).abs() < 1e-5, "press {press}: peak {max}");
        }
        last = max;
    }
}

#[test]
fn image_orientation_row0_is_plus_y_col0_is_minus_x() {
    // A small box pressed at (+6 mm, +4 mm): it must appear right of centre and above it,
    // i.e. in columns > W/2 and rows < H/2.
    let body = r#"<body name="block" pos="0.006 0.004 0.001">
      <joint name="press" type="slide" axis="0 0 -1"/>
      <geom type="box" size="0.001 0.0005 0.001" contype="0" conaffinity="0"/>
    </body>"#;
    let m = load_xml(&press_scene(&config(&[("physics", "rigid")]), body)).unwrap();
    let mut d = m.make_data();
    d.set_qpos(0, 0.2e-3);
    d.forward(&m);
    let img = d.sensor(&m, 0);
    let hits: Vec<(usize, usize)> = (0..H * W)
        .filter(|&i| img[i] > 0.0)
        .map(|i| (i / W, i % W))
        .collect();
    assert!(!hits.is_empty());
    for &(row, col) in &hits {
        let (x, y) = pixel_centre(row, col);
        assert!((x - 0.006).abs() <= 0.001 + 1e-9 && (y - 0.004).abs() <= 0.0005 + 1e-9);
    }
    // The footprint is 2 mm along x and 1 mm along y: wider than tall in the image.
    let cols = hits.iter().map(|h| h.1).max().unwrap() - hits.iter().map(|h| h.1).min().unwrap();
    let rows = hits.iter().map(|h| h.0).max().unwrap() - hits.iter().map(|h| h.0).min().unwrap();
    assert!(cols > rows + rows / 2, "cols {cols} rows {rows}");
}

#[test]
fn contact_mask_matches_depth_support() {
    let m = sphere_model(&[("outputs", "depth contact"), ("resolution", "64 48")]);
    let mut d = m.make_data();
    d.set_qpos(0, 0.3e-3);
    d.forward(&m);
    let v = d.sensor(&m, 0);
    let (depth, contact) = v.split_at(64 * 48);
    for (a, c) in depth.iter().zip(contact) {
        assert_eq!(*c, if *a > 0.0 { 1.0 } else { 0.0 });
    }
}

#[test]
fn many_data_in_threads_match_sequential() {
    let m = sphere_model(&[("resolution", "80 60")]);
    let presses = [0.1e-3, 0.25e-3, 0.4e-3, 0.7e-3];
    let sequential: Vec<Vec<f64>> = presses
        .iter()
        .map(|&p| {
            let mut d = m.make_data();
            d.set_qpos(0, p);
            d.forward(&m);
            d.sensor(&m, 0)
        })
        .collect();
    let parallel: Vec<Vec<f64>> = std::thread::scope(|s| {
        let handles: Vec<_> = presses
            .iter()
            .map(|&p| {
                let m = &m;
                s.spawn(move || {
                    let mut d = m.make_data();
                    d.set_qpos(0, p);
                    d.forward(m);
                    d.sensor(m, 0)
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert_eq!(sequential, parallel);
}

#[test]
fn bad_configuration_fails_at_load_naming_the_attribute() {
    let cases = [
        ("physics", "magic"),
        ("size", "-0.03 0.03 0.004"),
        ("resolution", "0 240"),
        ("resolution", "garbage"),
        ("young", "soft"),
        ("outputs", "depth smell"),
        ("indenters", "no_such_body"),
        ("camera", "pinhole"),
        ("camera", "pinhole -0.01"),
        ("camera", "pinhole 20"),
        ("camera", "telecentric"),
        ("index", "0.5"),
        ("index", "water"),
    ];
    for (key, value) in cases {
        let xml = press_scene(&config(&[(key, value)]), &sphere_body(R));
        let err = load_xml(&xml)
            .err()
            .unwrap_or_else(|| panic!("{key}={value} accepted"));
        assert!(err.contains(&format!("'{key}'")), "{key}={value}: {err}");
        assert!(err.contains("'touch'"), "{key}={value}: {err}");
        assert!(err.contains(value), "{key}={value}: {err}");
    }
}

#[test]
fn pinhole_camera_sees_the_sphere_along_refracted_rays() {
    // The sphere off the axis, over (4, 2) mm, where the rays are oblique.
    let centre = [0.004, 0.002];
    let body = format!(
        r#"<body name="ball" pos="{} {} {R}">
      <joint name="press" type="slide" axis="0 0 -1"/>
      <geom name="ball" type="sphere" size="{R}" contype="0" conaffinity="0"/>
    </body>"#,
        centre[0], centre[1]
    );
    let depth = 0.5e-3;
    let image = |extra: &[(&str, &str)]| {
        let mut pairs = vec![("physics", "rigid")];
        pairs.extend_from_slice(extra);
        let m = load_xml(&press_scene(&config(&pairs), &body)).expect("model loads");
        let mut d = m.make_data();
        d.set_qpos(0, depth);
        d.forward(&m);
        d.sensor(&m, 0)
    };
    // Orthographic, whatever the index: today's image, bit for bit.
    let plain = image(&[]);
    let same = image(&[("camera", "orthographic"), ("index", "1.4")]);
    let differ = same.iter().zip(&plain).filter(|(a, b)| a != b).count();
    assert!(
        differ == 0 && plain.iter().any(|&d| d > 0.0),
        "{differ} pixels differ; largest {:e} and {:e}",
        same.iter().cloned().fold(0.0, f64::max),
        plain.iter().cloned().fold(0.0, f64::max)
    );
    let pinhole = image(&[("camera", "pinhole 0.01"), ("index", "1.4")]);

    // The pinhole 10 mm below the 4 mm gel, index 1.4: each pixel's refracted ray against
    // the sphere, the larger root of |P - d g - c|^2 + (d + R - depth)^2 = R^2, where
    // positive. Tolerance: the bilinear interpolation of the orthographic cap between pixel
    // centres, (px^2 + py^2) / 8 times its largest curvature R^2 / (R - depth)^3 (0.36 um),
    // over the ray's slowest climb through the surface 1 - s |g| (s = 0.49, the cap's
    // steepest slope; |g| < 0.6 for rays that reach it: above 0.7), inside the cap; at its
    // rim, where the surface has a kink, s (px + py) / 4 over the same; plus the sphere
    // tracing's 1e-8 m.
    let px = FOV[0] / W as f64;
    let contact = (2.0 * R * depth - depth * depth).sqrt();
    let s = contact / (R - depth);
    let climb = 1.0 - s * 0.6;
    let tight = 2.0 * px * px / 8.0 * R * R / (R - depth).powi(3) / climb + 2e-8;
    let loose = s * 2.0 * px / 4.0 / climb + 2e-8;
    let (mut worst, mut changed) = (0.0f64, 0.0f64);
    for row in 0..H {
        for col in 0..W {
            let (x, y) = pixel_centre(row, col);
            let r = x.hypot(y);
            let tb = snell_slope(r, 0.004, 0.01, 1.4);
            let g = [tb * x / r, tb * y / r];
            let q = [x - centre[0], y - centre[1]];
            if q[0].hypot(q[1]) < contact + 1e-3 {
                assert!(tb < 0.6, "{tb}");
            }
            let zc = R - depth;
            let a = g[0] * g[0] + g[1] * g[1] + 1.0;
            let b = 2.0 * (zc - (q[0] * g[0] + q[1] * g[1]));
            let c = q[0] * q[0] + q[1] * q[1] + zc * zc - R * R;
            let disc = b * b - 4.0 * a * c;
            let expect = if disc < 0.0 {
                0.0
            } else {
                ((-b + disc.sqrt()) / (2.0 * a)).max(0.0)
            };
            let got = pinhole[row * W + col];
            let err = (got - expect).abs();
            // Seen more than a cell diagonal inside the rim: a smooth cell.
            let seen = (q[0] - got * g[0]).hypot(q[1] - got * g[1]);
            if seen < contact - px * 2f64.sqrt() {
                worst = worst.max(err);
                assert!(err <= tight, "({row}, {col}): {got} vs {expect}");
            } else {
                assert!(err <= loose, "({row}, {col}): {got} vs {expect}");
            }
            changed = changed.max((got - plain[row * W + col]).abs());
        }
    }
    // The camera's parallax is far beyond the tolerance.
    assert!(changed > 20.0 * tight, "{changed}");
    eprintln!("pinhole sphere: worst {worst:.3e} m (bound {tight:.3e}), parallax {changed:.3e} m");
}

#[test]
fn sensor_not_on_a_site_is_refused() {
    let xml = press_scene("", &sphere_body(R)).replace(
        r#"objtype="site" objname="gel""#,
        r#"objtype="body" objname="sensor""#,
    );
    let err = load_xml(&xml)
        .err()
        .expect("a body-attached sensor must be refused");
    assert!(err.contains("site"), "{err}");
}

#[test]
fn nan_pose_gives_zeros_not_nan() {
    let m = sphere_model(&[]);
    let mut d = m.make_data();
    d.set_qpos(0, f64::NAN);
    d.forward(&m);
    let img = d.sensor(&m, 0);
    assert!(img.iter().all(|v| v.is_finite()));
    // And the sensor keeps working.
    d.set_qpos(0, 0.3e-3);
    d.forward(&m);
    let max = d.sensor(&m, 0).into_iter().fold(0.0, f64::max);
    assert!((max - 0.3e-3).abs() < 1e-5);
}

/// The box's eight corners as an MJCF mesh, and the same box as a primitive: the mesh's
/// rasterised lower surface must match the analytic one.
#[test]
fn mesh_indenter_matches_the_same_primitive() {
    let (a, b, c) = (0.003, 0.002, 0.001);
    let mut verts = String::new();
    for i in 0..8 {
        let s = |bit: usize, h: f64| if i & bit == 0 { -h } else { h };
        verts += &format!("{} {} {} ", s(1, a), s(2, b), s(4, c));
    }
    let pose = r#"pos="0.001 -0.002 0.0016" euler="10 5 30""#;
    let scene = |geom: String| {
        let body = format!(
            r#"<body name="block" {pose}>
      <joint name="press" type="slide" axis="0 0 -1"/>
      {geom}
    </body>"#
        );
        press_scene(&config(&[("physics", "rigid")]), &body).replace(
            "<asset></asset>",
            &format!(r#"<asset><mesh name="boxmesh" vertex="{verts}"/></asset>"#),
        )
    };
    let mesh = load_xml(&scene(
        r#"<geom type="mesh" mesh="boxmesh" contype="0" conaffinity="0"/>"#.into(),
    ))
    .expect("mesh model");
    let prim = load_xml(&scene(format!(
        r#"<geom type="box" size="{a} {b} {c}" contype="0" conaffinity="0"/>"#
    )))
    .expect("box model");
    let image = |m: &Model| {
        let mut d = m.make_data();
        d.set_qpos(0, 0.4e-3);
        d.forward(m);
        d.sensor(m, 0)
    };
    let (im_mesh, im_prim) = (image(&mesh), image(&prim));
    let touched = im_prim.iter().filter(|&&v| v > 0.0).count();
    assert!(touched > 300, "the tilted box must touch: {touched} pixels");
    // Pixel centres exactly on an edge may fall either way; everything else agrees to
    // rounding.
    let differ = im_mesh
        .iter()
        .zip(&im_prim)
        .filter(|(x, y)| (*x - *y).abs() > 1e-9)
        .count();
    assert!(
        differ * 100 < touched,
        "{differ} of {touched} pixels differ"
    );
    let worst_inside = im_mesh
        .iter()
        .zip(&im_prim)
        .filter(|(x, y)| **x > 0.0 && **y > 0.0)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    assert!(worst_inside < 1e-9, "{worst_inside}");
}

/// Benchmark meshes load from STL through MuJoCo, and their images stay finite and within
/// [0, T] when pressed far through the gel.
#[test]
fn pattern_meshes_render_within_bounds() {
    let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    for name in ["hexagon", "moon"] {
        let file = data.join(format!("{name}.stl"));
        // MuJoCo recentres the mesh: with this pose its lowest point (the patterned face,
        // flipped towards the gel) is at z = 0 when qpos = 0.
        let body = r#"<body name="pattern" pos="0 0 0.020" euler="180 0 0">
      <joint name="press" type="slide" axis="0 0 1"/>
      <geom type="mesh" mesh="pattern" contype="0" conaffinity="0"/>
    </body>"#;
        let xml = press_scene(&config(&[("physics", "rigid")]), body).replace(
            "<asset></asset>",
            &format!(
                r#"<asset><mesh name="pattern" file="{}" scale="0.001 0.001 0.001"/></asset>"#,
                file.display()
            ),
        );
        let m = load_xml(&xml).unwrap_or_else(|e| panic!("{name}: {e}"));
        let mut d = m.make_data();
        let mut peak = 0.0;
        for press in [0.0, 0.0002, 0.001, 0.003, 0.008] {
            d.set_qpos(0, press);
            d.forward(&m);
            let img = d.sensor(&m, 0);
            assert!(
                img.iter()
                    .all(|v| v.is_finite() && (0.0..=0.004).contains(v)),
                "{name}"
            );
            let max = img.iter().cloned().fold(0.0, f64::max);
            assert!(max >= peak, "{name}: depth must grow with the press");
            assert!(
                press > 0.0 || max < 1e-8,
                "{name}: touching is not pressing ({max})"
            );
            peak = max;
        }
        assert_eq!(
            peak, 0.004,
            "{name}: a press through the gel saturates at T"
        );
    }
}

/// The coarse MPM gel through the plugin: a frictionless sphere's force against the
/// bonded-layer Hertz solution (the gel's own physics; the image's peak is bounded by the
/// depth rule and says nothing), the sag around the contact (depth outside the rigid
/// footprint), and a flat gel again after release.
#[test]
fn coarse_gel_press_and_release() {
    let m = load_xml(&press_scene(
        &config(&[
            ("physics", "coarse"),
            ("outputs", "depth force contact"),
            ("resolution", "96 72"),
            ("friction", "0"),
        ]),
        &sphere_body(R),
    ))
    .expect("model loads");
    let n = 96 * 72;
    let (young, poisson, thickness) = (1.19e5, 0.43, 0.004);
    let mut d = m.make_data();
    let mut last_fz = 0.0;
    for press in [0.2e-3, 0.4e-3] {
        d.set_qpos(0, press);
        d.forward(&m);
        let v = d.sensor(&m, 0);
        let (depth, rest) = v.split_at(n);
        let (force, contact) = rest.split_at(3);
        assert!(v.iter().all(|x| x.is_finite()));
        assert!(depth.iter().all(|&x| (0.0..=0.004).contains(&x)));
        // From 0.2 mm the contact radius sqrt(2 R d) is at least one coarse cell; there the
        // coarse grid's force is +4 to +12 % above Hertz (docs/solvers.md, tolerance 3e-3),
        // within the 15 % asserted (tests/python/test_gel.py asserts the same at 4 depths).
        let hertz = tacrom::mpm::hertz::hertz_bonded(young, poisson, R, press, thickness);
        assert!(
            (force[2] / hertz - 1.0).abs() < 0.15,
            "fz {} against Hertz {hertz} at press {press}",
            force[2]
        );
        let sag = depth
            .iter()
            .zip(contact)
            .filter(|(x, c)| **c == 0.0 && **x > 1e-6)
            .count();
        assert!(sag > 0, "the gel must sag outside the contact");
        // The gel pushes the sphere up (+z) with a force that grows with the press.
        assert!(force[2] > last_fz, "fz {} after {last_fz}", force[2]);
        assert!(force[0].abs() < 0.05 * force[2] && force[1].abs() < 0.05 * force[2]);
        last_fz = force[2];
    }
    d.set_qpos(0, -1e-3);
    d.forward(&m);
    assert!(
        d.sensor(&m, 0).iter().all(|&x| x == 0.0),
        "released gel must be flat"
    );
}
