use super::*;

const T: f64 = 4e-3;
/// Pinhole 10 mm below the gel: rays up to 48 degrees from the vertical at the image's
/// corners (index 1), so the camera's parallax is several pixels for a 1 mm press.
const D: f64 = 10e-3;

fn grid() -> PixelGrid {
    PixelGrid {
        width: 320,
        height: 240,
        fov_x: 0.024,
        fov_y: 0.018,
    }
}

/// The orthographic depth image of `h(x, y)` on `grid`.
fn image(grid: &PixelGrid, h: impl Fn(f64, f64) -> f64) -> Vec<f64> {
    (0..grid.height)
        .flat_map(|row| (0..grid.width).map(move |col| (row, col)))
        .map(|(row, col)| h(grid.x(col), grid.y(row)))
        .collect()
}

/// The ray of pixel `(row, col)`: its centre `P` on the top face and its drift `g` (m of
/// horizontal travel towards the axis per m of indentation), from [`snell_slope`], not the
/// library's [`gel_slope`].
fn ray(grid: &PixelGrid, row: usize, col: usize, n: f64) -> ([f64; 2], [f64; 2]) {
    let (x, y) = (grid.x(col), grid.y(row));
    let r = x.hypot(y);
    let s = snell_slope(r, T, D, n);
    ([x, y], [s * x / r, s * y / r])
}

/// The tan of a pinhole ray's angle from the vertical in the gel, for the ray that meets
/// the undeformed top face at `r` from the axis (gel `t` thick, pinhole `d` below it, index
/// `n`): found independently of the library, by bisection on the outside angle `a`, where
/// `D tan a + T tan b = r` with `sin b = sin a / n` (the left side rises with `a`).
fn snell_slope(r: f64, t: f64, d: f64, n: f64) -> f64 {
    let run = |a: f64| {
        let b = (a.sin() / n).asin();
        d * a.tan() + t * b.tan()
    };
    let (mut lo, mut hi) = (0.0, (r / d).atan());
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if run(mid) < r {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    ((0.5 * (lo + hi)).sin() / n).asin().tan()
}

#[test]
fn index_one_gives_the_straight_ray_and_snell_holds_otherwise() {
    for r in [1e-4, 3e-3, 12e-3, 15e-3] {
        // Index 1: the straight line from the pinhole at depth T + D below the face.
        let straight = gel_slope(r, T, D, 1.0);
        assert!((straight - r / (T + D)).abs() < 1e-15, "{r}: {straight}");
        for n in [1.2, 1.4, 3.0] {
            let tb = gel_slope(r, T, D, n);
            // The ray leaves the bottom face at r_B = r - T tan b; outside, tan a = r_B / D.
            let rb = r - T * tb;
            let (sin_a, sin_b) = (rb / rb.hypot(D), tb / tb.hypot(1.0));
            assert!((sin_a - n * sin_b).abs() < 1e-14, "{r} {n}");
            // The independent bisection agrees (to its own rounding of the angle).
            assert!((tb - snell_slope(r, T, D, n)).abs() < 1e-12, "{r} {n}");
            // Refraction bends the ray towards the vertical.
            assert!(tb < straight && tb > 0.0, "{r} {n}: {tb}");
        }
    }
    assert_eq!(gel_slope(0.0, T, D, 1.4), 0.0);
    assert_eq!(gel_slope(f64::NAN, T, D, 1.4), 0.0);
}

#[test]
fn a_flat_surface_looks_the_same_to_every_camera() {
    let g = grid();
    let mut cam = Refraction::new(&g, T, D, 1.4);
    let flat = vec![0.0; g.width * g.height];
    let mut depth = vec![1.0; flat.len()];
    assert!(!cam.refract(&flat, &mut depth));
    assert!(depth.iter().all(|&d| d == 0.0));
    // Zero depth: each pixel sees its own centre, so resampling is the identity.
    let rgb: Vec<f64> = (0..3 * flat.len()).map(|i| (i % 997) as f64).collect();
    let mut out = vec![0.0; rgb.len()];
    for s in [Sampling::Bilinear, Sampling::Nearest] {
        cam.resample(&depth, 3, s, &rgb, &mut out);
        assert_eq!(out, rgb);
    }
}

/// Closed form: the indentation at which the refracted ray of `(row, col)` meets the
/// surface `max(0, sphere)` of a rigid sphere of radius `r` whose lowest point is `delta`
/// below the face at `(cx, cy)`: the larger root of
/// `|P - d g - c|^2 + (d + R - delta)^2 = R^2` (the ray enters the sphere from below
/// there), where positive; else the flat face, 0.
fn sphere_hit(p: [f64; 2], g: [f64; 2], c: [f64; 2], r: f64, delta: f64) -> f64 {
    let q = [p[0] - c[0], p[1] - c[1]];
    let zc = r - delta;
    let a = g[0] * g[0] + g[1] * g[1] + 1.0;
    let b = 2.0 * (zc - (q[0] * g[0] + q[1] * g[1]));
    let cc = q[0] * q[0] + q[1] * q[1] + zc * zc - r * r;
    let disc = b * b - 4.0 * a * cc;
    if disc < 0.0 {
        return 0.0;
    }
    ((-b + disc.sqrt()) / (2.0 * a)).max(0.0)
}

#[test]
fn sphere_press_matches_the_closed_form_ray_sphere_intersection() {
    let g = grid();
    let (px, py) = (g.fov_x / g.width as f64, g.fov_y / g.height as f64);
    // Off the axis, so that the rays cross the cap obliquely and not along its radii.
    let (r, delta, c) = (5e-3, 0.6e-3, [3e-3, 2e-3]);
    let cap = |x: f64, y: f64| {
        let s2 = (x - c[0]).powi(2) + (y - c[1]).powi(2);
        if s2 >= r * r {
            0.0
        } else {
            ((r * r - s2).sqrt() - (r - delta)).max(0.0)
        }
    };
    let surface = image(&g, cap);
    let contact = (2.0 * r * delta - delta * delta).sqrt();
    // Tolerances. Inside the contact the cap's curvature is at most R^2 / (R - delta)^3
    // (radial, at its rim), so bilinear interpolation between pixel centres errs by at
    // most (px^2 + py^2) / 8 times that (0.41 um here). Across the rim the surface
    // max(0, cap) has a kink: the concave cap lies below its tangent plane l, and the
    // bilinear mean of max(0, l) exceeds max(0, l) by at most half the mean |l_k - l|,
    // s (px + py) / 4 for the steepest slope s = contact / (R - delta) (20 um here); from
    // below it errs by no more than the cap does. The traced indentation errs by the
    // height error over dF/dd = 1 + grad h . g >= 1 - s |g|, the ray's rate of climbing
    // through the surface. (Measured: 0.42 and 0.39 um inside the cap, 0.3 um at the rim,
    // where the rays meet the surface near their own pixel centres.)
    let curvature = r * r / (r - delta).powi(3);
    let smooth = (px * px + py * py) / 8.0 * curvature;
    let slope = contact / (r - delta);
    let kink = slope * (px + py) / 4.0;
    for n in [1.0, 1.4] {
        let mut cam = Refraction::new(&g, T, D, n);
        let mut depth = vec![0.0; surface.len()];
        assert!(cam.refract(&surface, &mut depth));
        // The steepest ray among those that can reach the cap: their pixels lie within
        // the contact radius plus delta |g| (|g| < 1.1 anywhere in this image) of its
        // centre; elsewhere the ray meets the flat face at a right climb of 1.
        let gmax = (0..g.height)
            .flat_map(|row| (0..g.width).map(move |col| (row, col)))
            .filter(|&(row, col)| {
                (g.x(col) - c[0]).hypot(g.y(row) - c[1]) <= contact + 1.1 * delta + 2.0 * px
            })
            .map(|(row, col)| {
                let (_, gg) = ray(&g, row, col, n);
                gg[0].hypot(gg[1])
            })
            .fold(0.0, f64::max);
        let climb = 1.0 - slope * gmax;
        assert!(climb > 0.5, "{climb}");
        let (mut inner, mut worst_inner, mut worst_rim, mut moved) = (0, 0.0f64, 0.0f64, 0.0f64);
        for row in 0..g.height {
            for col in 0..g.width {
                let i = row * g.width + col;
                let (p, gg) = ray(&g, row, col, n);
                let expect = sphere_hit(p, gg, c, r, delta);
                let err = (depth[i] - expect).abs();
                // The cell of the seen point: all four corners in contact, none, or both.
                let [u, v] = cam.seen(i, depth[i]);
                let (c0, r0) = (
                    (u.floor() as usize).min(g.width - 2),
                    (v.floor() as usize).min(g.height - 2),
                );
                let inside = [(c0, r0), (c0 + 1, r0), (c0, r0 + 1), (c0 + 1, r0 + 1)]
                    .map(|(cc, rr)| cap(g.x(cc), g.y(rr)) > 0.0);
                if inside.iter().all(|&b| b) {
                    inner += 1;
                    worst_inner = worst_inner.max(err);
                    assert!(
                        err <= smooth / climb + 1e-12,
                        "n {n} ({row}, {col}): {} vs {expect}",
                        depth[i]
                    );
                } else if inside.iter().all(|&b| !b) {
                    assert_eq!(depth[i], expect, "n {n} ({row}, {col})");
                } else {
                    worst_rim = worst_rim.max(err);
                    assert!(
                        err <= kink.max(smooth) / climb,
                        "n {n} ({row}, {col}): {err}"
                    );
                }
                moved = moved.max((surface[i] - depth[i]).abs());
            }
        }
        // Most of the contact is checked to the tight tolerance.
        let disc = std::f64::consts::PI * contact * contact / (px * py);
        assert!(inner as f64 > 0.8 * disc, "n {n}: {inner} of {disc}");
        // The camera's parallax is far above the tolerance: the test sees it.
        assert!(moved > 50.0 * smooth, "n {n}: largest change {moved:e} m");
        eprintln!(
            "n {n}: contact pixels in cells inside the cap {inner}, worst error {worst_inner:.3e} m \
             (bound {:.3e}); on the rim {worst_rim:.3e} m (bound {:.3e}); largest change from \
             orthographic {moved:.3e} m",
            smooth / climb,
            kink / climb
        );
    }
}

/// Pixels along the row just above the axis, from the centre out to +x, whose depth is at
/// least half the punch's `delta`: where the punch's edge appears.
fn edge_column(g: &PixelGrid, depth: &[f64], delta: f64) -> usize {
    let row = g.height / 2 - 1;
    (g.width / 2..g.width)
        .find(|&col| depth[row * g.width + col] < 0.5 * delta)
        .expect("the punch ends inside the image")
}

#[test]
fn flat_punch_edge_lands_where_the_ray_through_it_does() {
    let g = grid();
    let (px, py) = (g.fov_x / g.width as f64, g.fov_y / g.height as f64);
    let diag = px.hypot(py);
    // A flat cylindrical punch of radius a, pressed delta, centred on the axis.
    let (a, delta) = (6e-3, 1e-3);
    let surface = image(&g, |x, y| if x.hypot(y) < a { delta } else { 0.0 });
    let mut edges = Vec::new();
    for n in [1.0, 1.4] {
        let mut cam = Refraction::new(&g, T, D, n);
        let mut depth = vec![0.0; surface.len()];
        assert!(cam.refract(&surface, &mut depth));
        for row in 0..g.height {
            for col in 0..g.width {
                let i = row * g.width + col;
                // Closed form: the ray meets the punch's face where, at indentation delta,
                // it lies within the punch (radius |P| - delta tan b; the ray is radial).
                let (p, gg) = ray(&g, row, col, n);
                let at_face = p[0].hypot(p[1]) - delta * gg[0].hypot(gg[1]);
                if at_face < a - diag {
                    // Every cell the ray can meet at delta has all corners on the face.
                    assert_eq!(depth[i], delta, "n {n} ({row}, {col})");
                } else if at_face > a + diag {
                    // Every cell along the whole ray has all corners off the punch.
                    assert_eq!(depth[i], 0.0, "n {n} ({row}, {col})");
                }
            }
        }
        // Along the row above the axis: the first column whose ray misses the face,
        // against the one the pixel grid shows.
        let row = g.height / 2 - 1;
        let predicted = (g.width / 2..g.width)
            .find(|&col| {
                let (p, gg) = ray(&g, row, col, n);
                p[0].hypot(p[1]) - delta * gg[0].hypot(gg[1]) >= a
            })
            .unwrap();
        let seen = edge_column(&g, &depth, delta);
        assert!(
            seen.abs_diff(predicted) <= 1,
            "n {n}: edge at column {seen}, closed form {predicted}"
        );
        edges.push(seen);
    }
    // Orthographic: the edge where the punch is.
    let ortho = edge_column(&g, &surface, delta);
    let direct = (g.width / 2..g.width)
        .find(|&col| g.x(col).hypot(g.y(g.height / 2 - 1)) >= a)
        .unwrap();
    assert_eq!(ortho, direct);
    // Parallax pushes the edge outward (rays reach in under the punch); the denser gel
    // bends the rays towards the vertical and brings it back towards the orthographic
    // edge: ortho < n = 1.4 < n = 1, by several pixels here (closed form 0, 4.5, 6.2).
    assert!(
        ortho + 3 <= edges[1] && edges[1] < edges[0],
        "edge columns: orthographic {ortho}, n 1.4 {}, n 1 {}",
        edges[1],
        edges[0]
    );
}

/// A bumpy surface: two sharp cones, a ridge and a noise field, all within [0, T].
fn rough(x: f64, y: f64) -> f64 {
    let cone = |cx: f64, cy: f64, h: f64, s: f64| (h - s * (x - cx).hypot(y - cy)).max(0.0);
    let ridge = (0.4e-3 - 3.0 * (x + 0.4 * y - 2e-3).abs()).max(0.0);
    let noise = 0.05e-3 * ((x * 9e3).sin() * (y * 7e3).cos()).max(0.0);
    cone(-4e-3, 3e-3, 1.2e-3, 2.0)
        .max(cone(5e-3, -2e-3, 0.8e-3, 0.7))
        .max(ridge)
        .max(noise)
}

#[test]
fn each_ray_stops_at_the_first_surface_point_it_meets_from_below() {
    let g = PixelGrid {
        width: 96,
        height: 72,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    let surface = image(&g, rough);
    let mut cam = Refraction::new(&g, T, 6e-3, 1.3);
    let mut depth = vec![0.0; surface.len()];
    assert!(cam.refract(&surface, &mut depth));
    // The height field along a ray, bilinear between pixel centres and clamped.
    let h = |u: f64, v: f64| {
        let (c0, c1, fx) = bracket(u, g.width);
        let (r0, r1, fy) = bracket(v, g.height);
        let at = |r: usize, c: usize| surface[r * g.width + c];
        lerp(
            lerp(at(r0, c0), at(r0, c1), fx),
            lerp(at(r1, c0), at(r1, c1), fx),
            fy,
        )
    };
    let mut oblique = 0;
    for i in 0..surface.len() {
        let d = depth[i];
        assert!(d.is_finite() && (0.0..=T).contains(&d));
        // A root: the depth is the surface's at the point seen.
        let [u, v] = cam.seen(i, d);
        assert!((d - h(u, v)).abs() < 1e-12, "pixel {i}: {d} vs {}", h(u, v));
        // The first one from below: deeper along the ray, the ray is inside the gel
        // (below the surface), sampled every 1/50 of a pixel's travel.
        let [gu, gv] = cam.drift(i / g.width, i % g.width);
        let step = 0.02 / gu.hypot(gv).max(1.0);
        let mut s = d + step;
        while s <= 1.5e-3 {
            let [u, v] = cam.seen(i, s);
            assert!(
                s - h(u, v) > -1e-12,
                "pixel {i}: ray at {s} above the surface {} (seen {d})",
                h(u, v)
            );
            s += step;
        }
        if (d - surface[i]).abs() > 1e-6 {
            oblique += 1;
        }
    }
    assert!(oblique > 100, "{oblique}");
}

#[test]
fn bad_surface_values_give_bounded_finite_depths() {
    let g = PixelGrid {
        width: 16,
        height: 12,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    let mut surface = image(&g, rough);
    surface[20] = f64::NAN;
    surface[21] = f64::INFINITY;
    surface[40] = -1.0;
    surface[41] = f64::NEG_INFINITY;
    let mut cam = Refraction::new(&g, T, D, 1.4);
    let mut depth = vec![0.0; surface.len()];
    let _ = cam.refract(&surface, &mut depth);
    assert!(depth.iter().all(|d| d.is_finite() && (0.0..=T).contains(d)));
}

#[test]
fn tiny_images_trace() {
    // One pixel (on the axis: a vertical ray), one row, one column.
    for (w, h) in [(1, 1), (5, 1), (1, 4), (2, 2)] {
        let g = PixelGrid {
            width: w,
            height: h,
            fov_x: 0.024,
            fov_y: 0.018,
        };
        let surface = image(&g, |x, y| (1e-3 - 0.1 * x.hypot(y)).max(0.0));
        let mut cam = Refraction::new(&g, T, D, 1.4);
        let mut depth = vec![0.0; surface.len()];
        let _ = cam.refract(&surface, &mut depth);
        for (i, &d) in depth.iter().enumerate() {
            assert!(
                d.is_finite() && (0.0..=1e-3).contains(&d),
                "{w} x {h}: {i} {d}"
            );
        }
        let mut out = vec![0.0; surface.len()];
        cam.resample(&depth, 1, Sampling::Bilinear, &surface, &mut out);
        assert!(out.iter().all(|v| v.is_finite()));
    }
}

#[test]
fn resampling_follows_the_seen_points() {
    let g = grid();
    let surface = image(&g, rough);
    let mut cam = Refraction::new(&g, T, D, 1.4);
    let mut depth = vec![0.0; surface.len()];
    assert!(cam.refract(&surface, &mut depth));
    // A field linear in the pixel coordinates is interpolated exactly: channel 0 is the
    // column, channel 1 the row, so the resampled image is the seen point itself.
    let n = surface.len();
    let coords: Vec<f64> = (0..n)
        .flat_map(|i| [(i % g.width) as f64, (i / g.width) as f64])
        .collect();
    let mut out = vec![0.0; 2 * n];
    cam.resample(&depth, 2, Sampling::Bilinear, &coords, &mut out);
    let mut nearest = vec![0.0; 2 * n];
    cam.resample(&depth, 2, Sampling::Nearest, &coords, &mut nearest);
    for i in 0..n {
        let [u, v] = cam.seen(i, depth[i]);
        assert!((out[2 * i] - u).abs() < 1e-9 && (out[2 * i + 1] - v).abs() < 1e-9);
        assert_eq!([nearest[2 * i], nearest[2 * i + 1]], [u.round(), v.round()]);
    }
    // The surface itself, resampled, is the traced depth: the ray meets it there.
    let mut again = vec![0.0; n];
    cam.resample(&depth, 1, Sampling::Bilinear, &surface, &mut again);
    for i in 0..n {
        assert!((again[i] - depth[i]).abs() < 1e-12, "{i}");
    }
}
