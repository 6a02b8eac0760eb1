//! `tacrom calibrate` end to end: a calibration from presses rendered with the built-in
//! optics reproduces them through the sensor, contacts are found where they are, and a
//! broken set is refused with a message naming the press.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::Isometry3;
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::{PixelGrid, Placed, Sphere};
use tacrom::render::calibrated::CalibratedOptics;
use tacrom::render::rgb::{render, Optics, CHANNELS};
use tacrom::sensor::TactileSensor;
use tacrom_tools::calibrate::{self as cal, fit, synth, CalibrateError, Contact};

/// A fresh scratch folder of this test process.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("tacrom-calibrate-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A rigid sensor of `w x h` pixels of `pixel` metres, rgb output, with `optics` if given.
fn sensor(w: usize, h: usize, pixel: f64, optics: Option<&Path>) -> TactileSensor {
    let mut raw = RawConfig::default()
        .with("physics", "rigid")
        .with("outputs", "rgb")
        .with("resolution", &format!("{w} {h}"))
        .with("fov", &format!("{} {}", w as f64 * pixel, h as f64 * pixel));
    if let Some(p) = optics {
        raw = raw.with("optics", p.to_str().unwrap());
    }
    TactileSensor::new(Config::from_raw("touch", &raw).unwrap()).unwrap()
}

/// The sensor's rgb image of a ball of `radius` pressed to `contact`: the sphere placed so
/// that it cuts the undeformed face in the contact circle.
fn press_rgb(s: &mut TactileSensor, radius: f64, contact: &Contact, pixel: f64) -> Vec<f64> {
    let (w, h) = (s.config().width, s.config().height);
    let x = (contact.centre[0] + 0.5 - 0.5 * w as f64) * pixel;
    let y = (0.5 * h as f64 - contact.centre[1] - 0.5) * pixel;
    let a = contact.radius * pixel;
    let placed = [Placed {
        shape: Arc::new(Sphere::new(radius)),
        pose: Isometry3::translation(x, y, (radius * radius - a * a).sqrt()),
    }];
    let mut out = vec![0.0; CHANNELS * w * h];
    let _ = s.evaluate(&placed, &mut out);
    out
}

/// The built-in optics' colour at the depth gradient `(gx, gy)`: the centre of a 3 x 3
/// plane of that slope (central differences of a plane are exact).
fn built_in_colour(gx: f64, gy: f64) -> [f64; 3] {
    let grid = PixelGrid {
        width: 3,
        height: 3,
        fov_x: 3e-4,
        fov_y: 3e-4,
    };
    let depth: Vec<f64> = (0..9)
        .map(|i| 1e-3 + gx * grid.x(i % 3) + gy * grid.y(i / 3))
        .collect();
    let mut out = vec![0.0; 27];
    render(&Optics::default(), &grid, &depth, &mut out);
    [out[12], out[13], out[14]]
}

/// The largest per-channel gradient magnitude of the built-in colour response at `(gx,
/// gy)` (grey levels per unit slope), by central differences of step 1e-4.
fn response_slope(gx: f64, gy: f64) -> f64 {
    let d = 1e-4;
    let (x1, x0) = (built_in_colour(gx + d, gy), built_in_colour(gx - d, gy));
    let (y1, y0) = (built_in_colour(gx, gy + d), built_in_colour(gx, gy - d));
    (0..3)
        .map(|k| ((x1[k] - x0[k]) / (2.0 * d)).hypot((y1[k] - y0[k]) / (2.0 * d)))
        .fold(0.0, f64::max)
}

#[test]
fn a_calibration_from_built_in_presses_reproduces_them_through_the_sensor() {
    let dir = scratch("round-trip");
    let set = dir.join("set");
    // The default sensor's image: 320 x 240 pixels of 0.075 mm, 24 presses, every 4th of
    // them held out (6), the default fit (41 x 41 nodes).
    let (w, h, pixel) = (320, 240, 0.075e-3);
    let presses = synth::synthesize(&synth::SynthOptions::new(set.clone())).unwrap();
    let mut o = cal::CalibrateOptions::new(set);
    o.out = dir.join("optics.json");
    let report = cal::calibrate(&o).unwrap();
    let held = report.held_out.expect("held-out presses");
    // Against the 8-bit PNGs the error is their rounding, uniform in +-0.5: 0.25 on average
    // (measured 0.252 over the held-out contacts, SSIM 0.9996).
    assert!(
        held.mae_contact < 0.3 && held.ssim_contact > 0.999,
        "{held:?}"
    );

    // Through the sensor: the calibrated file (found through the `optics` attribute) and
    // the built-in optics render the same presses, in floats.
    let mut calibrated = sensor(w, h, pixel, Some(&o.out));
    let mut built_in = sensor(w, h, pixel, None);
    assert!(calibrated.config().optics.is_some() && built_in.config().optics.is_none());
    let (mut sum, mut count, mut worst, mut image_sum) = (0.0, 0usize, 0.0f64, 0.0);
    let (mut slope_sum, mut slope_max) = (0.0, 0.0f64);
    let mut held_out = 0;
    for (i, (entry, c)) in presses.iter().enumerate() {
        if (i + 1) % o.holdout != 0 {
            continue;
        }
        held_out += 1;
        let radius = entry.ball_radius_mm * 1e-3;
        let a = press_rgb(&mut calibrated, radius, c, pixel);
        let b = press_rgb(&mut built_in, radius, c, pixel);
        image_sum += tacrom_tools::calibrate::metrics::mae(&a, &b, None);
        for r in 0..h {
            for col in 0..w {
                if c.distance(r, col) > c.radius {
                    continue;
                }
                let (x, y) = fit::offset(c, r, col, pixel);
                let g = fit::ball_gradient(x, y, radius).unwrap();
                let s = response_slope(g[0], g[1]);
                slope_sum += s;
                slope_max = slope_max.max(s);
                for k in 0..CHANNELS {
                    let e =
                        (a[CHANNELS * (r * w + col) + k] - b[CHANNELS * (r * w + col) + k]).abs();
                    sum += e;
                    worst = worst.max(e);
                    count += 1;
                }
            }
        }
    }
    assert_eq!(held_out, 6);
    let mae = sum / count as f64;
    let image_mae = image_sum / held_out as f64;
    let bin = 2.0 * report.fit.range / (report.fit.bins - 1) as f64;
    let slope_mean = slope_sum / (count / CHANNELS) as f64;
    // The bound. A table that gave each bin its samples' average (nearest-node lookup)
    // would err by the response's slope times the distance to the node: on average over a
    // bin h/4 per axis, times the mean response slope over the contacts (here h = 0.0337
    // and 172 levels per unit slope, the steepest channel's: 1.45 levels), and at worst half
    // the bin's diagonal, h / sqrt(2), times the steepest slope (208: 4.9 levels). The fit interpolates
    // bilinearly between least-squares nodes: second order where the response is smooth,
    // first order only near the kinks where a light turns away from the surface (a slope of
    // tan 30 degrees facing away from it), plus the 8-bit rounding of the samples averaged
    // over a node's samples. Measured: MAE 0.043 levels over the held-out contacts (0.0005
    // over the whole image), worst pixel 0.93, both far inside the first-order bound, which
    // a table shifted by half a bin, mirrored or built on the wrong gradient would not be.
    let bound_mean = bin / 4.0 * slope_mean;
    let bound_worst = bin / 2f64.sqrt() * slope_max;
    println!(
        "held-out contact MAE {mae:.4} (bound {bound_mean:.3}), image MAE {image_mae:.5}, worst \
         {worst:.3} (bound {bound_worst:.2}); bin {bin:.4}, response slope mean {slope_mean:.1} \
         max {slope_max:.1}"
    );
    assert!(mae < bound_mean && worst < bound_worst);
    // Yet not the built-in optics themselves: the sensor renders through the table.
    assert!(mae > 0.0);
    // Tighter: a tenth of a grey level on average, under two at worst (measured 0.043 and
    // 0.93).
    assert!(mae < 0.1 && worst < 2.0, "{mae} {worst}");
}

#[test]
fn contacts_are_detected_within_half_a_pixel() {
    let dir = scratch("detect");
    // The sensor's default pixels (0.075 mm) and five times coarser (0.375 mm: contacts of
    // 4 to 14 pixels); presses.json without the contacts, which read_set then detects.
    for (resolution, pixel) in [([320, 240], 0.075e-3), ([64, 48], 0.375e-3)] {
        let o = synth::SynthOptions {
            resolution,
            pixel_size: pixel,
            with_contact: false,
            ..synth::SynthOptions::new(dir.join(format!("{}", resolution[0])))
        };
        let truth = synth::synthesize(&o).unwrap();
        let set = cal::read_set(&o.out, false, cal::contact::DEFAULT_THRESHOLD).unwrap();
        let (mut centre, mut radius, mut bias) = (0.0f64, 0.0f64, 0.0);
        for (press, (_, c)) in set.presses.iter().zip(&truth) {
            assert!(press.detected);
            let got = press.contact;
            centre = centre.max((got.centre[0] - c.centre[0]).hypot(got.centre[1] - c.centre[1]));
            radius = radius.max((got.radius - c.radius).abs());
            bias += (got.radius - c.radius) / truth.len() as f64;
        }
        println!("{resolution:?}: centre within {centre:.3} px, radius within {radius:.3} px, radius bias {bias:+.3} px");
        // Asked: about a pixel. The centroid of the filled blob is unbiased by symmetry; its
        // error is the pixelation of the blob's edge (measured at most 0.20 px at both
        // sizes). The radius after the 0.8 px edge correction: at most 0.13 px off, mean
        // bias +0.02 and +0.05 px.
        assert!(
            centre < 0.5 && radius < 0.3 && bias.abs() < 0.15,
            "{centre} {radius} {bias}"
        );
    }
    // A calibration with detected contacts reproduces the presses nearly as well as one
    // with the true contacts: held-out contact MAE 0.37 against 0.25 levels (the rounding
    // of the PNGs), SSIM 0.9993; the re-rendered caps are a tenth of a pixel off.
    let mut o = cal::CalibrateOptions::new(dir.join("320"));
    o.out = dir.join("optics.json");
    let report = cal::calibrate(&o).unwrap();
    assert!(report.presses.iter().all(|p| p.detected));
    let held = report.held_out.unwrap();
    assert!(
        held.mae_contact < 0.5 && held.ssim_contact > 0.998,
        "{held:?}"
    );
}

#[test]
fn a_broken_press_set_is_refused_naming_the_fault() {
    let dir = scratch("broken");
    let o = synth::SynthOptions {
        presses: 3,
        resolution: [40, 30],
        pixel_size: 0.3e-3,
        ..synth::SynthOptions::new(dir.join("set"))
    };
    let _ = synth::synthesize(&o).unwrap();
    let list_path = o.out.join(cal::PRESS_LIST);
    let list = std::fs::read_to_string(&list_path).unwrap();
    let json: serde_json::Value = serde_json::from_str(&list).unwrap();
    let with = |edit: &dyn Fn(&mut serde_json::Value)| {
        let mut j = json.clone();
        edit(&mut j);
        std::fs::write(&list_path, j.to_string()).unwrap();
        let e = cal::read_set(&o.out, false, 2.5).unwrap_err();
        e.to_string()
    };
    let e = with(&|j| j["presses"][1]["image"] = "gone.png".into());
    assert!(e.contains("gone.png"), "{e}");
    let e = with(&|j| j["presses"][2]["ball_radius_mm"] = 0.5.into());
    assert!(
        e.contains("press 2") && e.contains("not below the ball radius"),
        "{e}"
    );
    let e = with(&|j| j["presses"][0]["pixel_size_mm"] = (-1.0).into());
    assert!(e.contains("press 0") && e.contains("positive"), "{e}");
    let e = with(&|j| j["presses"][0]["contact_radius"] = 3.0.into());
    assert!(e.contains("unknown field `contact_radius`"), "{e}");
    let e = with(&|j| j["presses"][1]["depth_mm"] = (-0.2).into());
    assert!(e.contains("press 1") && e.contains("depth_mm"), "{e}");
    let e = with(&|j| j["presses"][2]["force_n"] = 0.0.into());
    assert!(e.contains("press 2") && e.contains("force_n = 0"), "{e}");
    let e = with(&|j| j["presses"] = serde_json::json!([]));
    assert!(e.contains("no presses"), "{e}");
    // A press of another size than the background.
    std::fs::write(&list_path, &list).unwrap();
    synth::write_png8(&o.out.join("press_001.png"), 20, 30, &vec![100.0; 3 * 600]).unwrap();
    let e = cal::read_set(&o.out, false, 2.5).unwrap_err().to_string();
    assert!(e.contains("press 1") && e.contains("20 x 30"), "{e}");
    // Nothing to fit: every press held out.
    synth::synthesize(&o).unwrap();
    let mut c = cal::CalibrateOptions::new(o.out.clone());
    c.holdout = 1;
    let e = cal::calibrate(&c).unwrap_err();
    assert!(
        matches!(e, CalibrateError::Usage(_)) && e.to_string().contains("no samples"),
        "{e}"
    );
}

#[test]
fn mirror_flips_camera_images_back_to_the_sensors_orientation() {
    // The same presses as a camera sees them (left-right mirrored, centres with them),
    // calibrated with --mirror, give the table of the originals: the flipped images are
    // the originals pixel for pixel; the centres come back to within rounding. Without
    // --mirror the table is the mirror image, far from it.
    let dir = scratch("mirror");
    let o = synth::SynthOptions {
        presses: 8,
        resolution: [96, 72],
        pixel_size: 0.25e-3,
        ..synth::SynthOptions::new(dir.join("set"))
    };
    let presses = synth::synthesize(&o).unwrap();
    let camera = dir.join("camera");
    std::fs::create_dir_all(&camera).unwrap();
    let flip = |name: &str| {
        let img = tacrom::render::calibrated::RgbImage::read_png(&o.out.join(name)).unwrap();
        let mut data = Vec::new();
        for r in 0..img.height {
            for c in (0..img.width).rev() {
                data.extend(img.pixel(r, c));
            }
        }
        synth::write_png8(&camera.join(name), img.width, img.height, &data).unwrap();
    };
    flip("background.png");
    let mut list: cal::PressList =
        serde_json::from_str(&std::fs::read_to_string(o.out.join(cal::PRESS_LIST)).unwrap())
            .unwrap();
    for (entry, _) in &presses {
        flip(&entry.image);
    }
    for e in &mut list.presses {
        let [c, r] = e.center_px.unwrap();
        e.center_px = Some([95.0 - c, r]);
    }
    std::fs::write(
        camera.join(cal::PRESS_LIST),
        serde_json::to_string(&list).unwrap(),
    )
    .unwrap();
    let table = |input: &Path, mirror: bool| {
        let mut c = cal::CalibrateOptions::new(input.to_owned());
        c.out = dir.join(format!("optics-{mirror}.json"));
        c.mirror = mirror;
        let _ = cal::calibrate(&c).unwrap();
        let optics = tacrom::render::calibrated::CalibratedOptics::load(&c.out).unwrap();
        optics.table().values().to_vec()
    };
    let original = table(&o.out, false);
    let largest = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
    };
    assert!(largest(&table(&camera, true), &original) < 1e-6);
    assert!(largest(&table(&camera, false), &original) > 10.0);
}

/// The gel behind a set of presses is recovered from the images alone: presses of a known
/// gel (1.8 mm thick, Poisson's ratio 0.4, neither on the searched grid) rendered with the
/// built-in optics, calibrated with `--gel`, give a gel whose images match theirs, its
/// thickness and Poisson's ratio each within 10 %, and a sensor file that loads and names
/// the gel. The presses are made on the fit's own grid spacing: on a finer one
/// (0.4 mm against 0.5) the coarse gel's discretisation error (about 2 grey levels) is
/// larger than what the thickness changes, and the fit does not find it
/// (docs/calibration.md).
#[test]
fn a_gel_fit_recovers_the_thickness_and_poissons_ratio_of_synthetic_presses() {
    use cal::gel::{GelSearch, GelShape};
    // Synthesized on the fit's own grid spacing (above).
    let truth = GelShape {
        thickness: 1.8e-3,
        poisson: 0.4,
        dx: 0.5e-3,
    };
    let search = GelSearch {
        thicknesses: vec![1e-3, 1.5e-3, 2.5e-3],
        poissons: vec![0.3, 0.4, 0.48],
        // The longest test of the suite: two solver threads take the core the others
        // leave once they are done.
        threads: 2,
        dx: Some(0.5e-3),
        blurs: Vec::new(),
    };
    let (report, _) = calibrate_synthetic_gel("gel-fit", truth, 0.1e-3, 3, 0.0, search);
    let cal::GelReport {
        fit,
        sensor_file: path,
        ..
    } = report.gel.expect("a gel fit");
    // The fitted gel's images match the presses' to their 8-bit rounding (a quarter of a
    // grey level on average over the regions; the grid's worst gel: several levels).
    let worst = fit.grid.iter().map(|g| g.mae).fold(0.0, f64::max);
    assert!(
        fit.mae < 0.4 && worst > 4.0 * fit.mae,
        "{} against {worst}",
        fit.mae
    );
    // Each within 10 %. (Refined along the score's valley from the grid's best alone, the
    // fit stopped in a bump of it at (2.23 mm, 0.423), 24 % thick: docs/calibration.md,
    // "What the gel fit recovers".)
    let t_err = (fit.best.thickness - truth.thickness).abs() / truth.thickness;
    let nu_err = (fit.best.poisson - truth.poisson).abs() / truth.poisson;
    println!(
        "fitted {:?} ({t_err:.3}, {nu_err:.3}); {} gels scored",
        fit.best,
        fit.grid.len()
    );
    assert!(
        t_err < 0.1 && nu_err < 0.1,
        "fitted {:?} against {truth:?}",
        fit.best
    );
    // The sensor file it wrote loads, with that gel.
    let raw = RawConfig::default()
        .with("sensor", path.to_str().unwrap())
        .with("outputs", "depth rgb");
    let config = Config::from_raw("touch", &raw).unwrap();
    assert!((config.size[2] - fit.best.thickness).abs() < 1e-9);
    assert!((config.poisson - fit.best.poisson).abs() < 1e-9);
    assert!(config.optics.is_some());
}

/// Presses that give their normal force fix the gel's Young's modulus. Six presses of a
/// gel three times as stiff as the default, every third held out: with each press's depth
/// given, the force is the same simulation's at the reference modulus times the ratio, so
/// the fit returns the modulus to rounding and every force with it; with the depths fitted
/// from the imprints, each depth is found to the search's final bracket (0.4 % of the
/// rigid cap's depth), and a sphere's force on a bonded layer goes as the depth to a power
/// from 1.5 (a half-space) to 3 (a wide contact on a thin incompressible layer): each force
/// within 1.2 % (bound 1.5 %), the modulus, their least-squares ratio, within 1 %
/// (measured 0.6 %). The sensor file carries the modulus.
#[test]
fn a_modulus_fit_recovers_the_youngs_modulus_from_the_presses_forces() {
    let (gel, search) = one_gel(Vec::new());
    let young = 3.0 * tacrom::attributes::defaults::YOUNG;
    for with_depth in [true, false] {
        let name = if with_depth {
            "young-depths"
        } else {
            "young-imprints"
        };
        let o = synth::SynthOptions {
            with_depth,
            young: Some(young),
            ..gel_set(name, gel, 0.1e-3, 3)
        };
        synth::synthesize(&o).unwrap();
        let report = calibrate_held_out(&o.out, search.clone());
        let g = report.gel.expect("a gel fit");
        let y = g.young.expect("a modulus fit");
        let (bound, force_bound) = if with_depth {
            (1e-9, 1e-9)
        } else {
            (0.01, 0.015)
        };
        println!(
            "depths given {with_depth}: E {:.5e} against {young:.5e}, force error {:.2e} \
             fitted, {:?} held out",
            y.young, y.error, y.held_out_error
        );
        assert!(
            (y.young / young - 1.0).abs() < bound,
            "{} against {young}",
            y.young
        );
        assert_eq!(y.presses.len(), 6);
        assert_eq!(y.presses.iter().filter(|p| p.held_out).count(), 2);
        for p in &y.presses {
            assert!(p.measured > 0.0, "{p:?}");
            assert!(
                (p.simulated / p.measured - 1.0).abs() < force_bound,
                "{p:?}"
            );
        }
        let raw = RawConfig::default()
            .with("sensor", g.sensor_file.to_str().unwrap())
            .with("outputs", "depth");
        let config = Config::from_raw("touch", &raw).unwrap();
        assert!(
            (config.young / y.young - 1.0).abs() < 1e-6,
            "{}",
            config.young
        );
    }
}

/// Presses that give their depth check the pixel size: simulated at their depths on the
/// fitted gel, their imprints are as large in pixels as the images' where the given pixel
/// size is right (measured: to 0.1 %; bound 0.5 %), and 1 / 1.05 of them where it is given
/// 5 % too large (measured: the true size to 0.9 %, bound 2 %: the optics fitted through
/// the wrong size render each imprint's faint edge a little off, and the presses' ratios
/// spread by 3 % against 0.2 %), which the report flags.
#[test]
fn a_pixel_size_check_finds_a_wrong_pixel_size() {
    let (gel, search) = one_gel(Vec::new());
    for claimed in [1.0, 1.05] {
        let o = synth::SynthOptions {
            with_depth: true,
            ..gel_set(&format!("pixel-{claimed}"), gel, 0.1e-3, 3)
        };
        synth::synthesize(&o).unwrap();
        let list_path = o.out.join(cal::PRESS_LIST);
        let mut list: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&list_path).unwrap()).unwrap();
        for p in list["presses"].as_array_mut().unwrap() {
            p["pixel_size_mm"] = (0.1 * claimed).into();
        }
        std::fs::write(&list_path, list.to_string()).unwrap();
        let report = calibrate_held_out(&o.out, search.clone());
        let check = report.gel.unwrap().pixel.expect("a pixel size check");
        println!("given {claimed}: {check:?}");
        assert_eq!(check.presses, 6);
        let bound = if claimed == 1.0 { 0.005 } else { 0.02 };
        assert!(
            (check.ratio * claimed - 1.0).abs() < bound,
            "given {claimed} times the true pixel: {check:?}"
        );
        let flagged = (check.ratio - 1.0).abs() > cal::PIXEL_WARNING;
        assert_eq!(flagged, claimed != 1.0, "{check:?}");
    }
}

/// Six synthetic presses (120 x 90 pixels of `pixel_size`, seed `seed`) into `gel`, in
/// scratch folder `name`: the options to synthesize them with.
fn gel_set(name: &str, gel: cal::gel::GelShape, pixel_size: f64, seed: u64) -> synth::SynthOptions {
    synth::SynthOptions {
        presses: 6,
        resolution: [120, 90],
        pixel_size,
        seed,
        gel: Some(gel),
        ..synth::SynthOptions::new(scratch(name))
    }
}

/// A gel 2 mm thick of Poisson's ratio 0.43 on the fit's 0.5 mm grid, and a search of that
/// gel alone with the depth blurs `blurs`.
fn one_gel(blurs: Vec<f64>) -> (cal::gel::GelShape, cal::gel::GelSearch) {
    let gel = cal::gel::GelShape {
        thickness: 2e-3,
        poisson: 0.43,
        dx: 0.5e-3,
    };
    let search = cal::gel::GelSearch {
        thicknesses: vec![gel.thickness],
        poissons: vec![gel.poisson],
        threads: 1,
        dx: Some(gel.dx),
        blurs,
    };
    (gel, search)
}

/// Calibrates the set in `dir` over the gels and blurs of `search`, every third press held
/// out.
fn calibrate_held_out(dir: &Path, search: cal::gel::GelSearch) -> cal::CalibrationReport {
    let mut c = cal::CalibrateOptions::new(dir.to_path_buf());
    c.holdout = 3;
    c.gel = Some(search);
    cal::calibrate(&c).unwrap()
}

/// Calibrates, over the gels and blurs of `search` with every third press held out, six
/// synthetic presses (120 x 90 pixels of `pixel_size`, seed `seed`) into `gel`, each depth
/// image blurred by `blur` (m) before its built-in shading; returns the report and the
/// set's folder (scratch `name`).
fn calibrate_synthetic_gel(
    name: &str,
    gel: cal::gel::GelShape,
    pixel_size: f64,
    seed: u64,
    blur: f64,
    search: cal::gel::GelSearch,
) -> (cal::CalibrationReport, PathBuf) {
    let o = synth::SynthOptions {
        blur,
        ..gel_set(name, gel, pixel_size, seed)
    };
    synth::synthesize(&o).unwrap();
    (calibrate_held_out(&o.out, search), o.out)
}

/// Presses whose depth images were blurred before shading (0.2 mm, four pixels) give their
/// blur back: of the candidates 0, 0.1, 0.2 and 0.4 mm the fit picks 0.2 (its images match
/// the presses' structure best, region SSIM), writes it into the optics, and its table,
/// fitted through it, renders the presses to their 8-bit rounding.
#[test]
fn a_blur_fit_recovers_the_blur_of_synthetic_presses() {
    let (gel, search) = one_gel(vec![0.0, 0.1e-3, 0.2e-3, 0.4e-3]);
    let (report, dir) = calibrate_synthetic_gel("blur-fit", gel, 0.05e-3, 5, 0.2e-3, search);
    let fit = report.gel.expect("a gel fit").fit;
    let ssim: Vec<f64> = fit.blurs.iter().map(|b| b.ssim).collect();
    assert_eq!(fit.blur, 0.2e-3, "region SSIM per blur {ssim:?}");
    assert!(fit.mae < 0.5, "region MAE {}", fit.mae);
    let optics = CalibratedOptics::load(&dir.join("optics.json")).unwrap();
    assert_eq!(optics.blur(), 0.2e-3);
}
