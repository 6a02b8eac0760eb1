//! The reduced-order model: the shipped model loads with the manifest's shapes, bad model
//! directories fail clearly, rom beats coarse against the reference on held-out indenter
//! families, the run time of one 320 x 240 evaluation, and `gen-data` round trips.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::Isometry3;
use tacrom::geometry::{PixelGrid, Placed, Sphere};
use tacrom::mpm::{Gel, GelParams, SolverOptions};
use tacrom::render::DepthRule;
use tacrom::rom::features::{LatticeSpec, Observation};
use tacrom::rom::{default_model_dir, Rom, RomError, RomOptions};
use tacrom_tools::datagen::{self, GenConfig};

/// Pooled gate: rom's depth MAE against the reference at most this fraction of coarse's,
/// each held-out family weighted equally (its mean over its pairs), so that the family
/// with the most pairs cannot carry the gate. The target of the reduced-order model; the
/// shipped model measured 0.41 on its 56 held-out presses and 0.48 here. The pairs shipped
/// with the model are held-out presses with the fine 0.3 mm reference (`reference_dx` in
/// their JSON), two or more per held-out family (16 in all; `tacrom gen-data
/// --held-out-only --fine-dx 0.3 --indices ...` regenerates them, their indices are in
/// their JSON).
const HELD_OUT_MARGIN: f64 = 0.5;

/// Per-family gate: on every held-out family rom's MAE at most this fraction of coarse's.
/// The manifest's per-family ratios on all 56 held-out presses are 0.33 (ridges) to 0.56
/// (pacman); with two presses per family a family's ratio moves by about a tenth, so the
/// gate asks for a clear gain on each (a quarter below coarse), not the pooled target.
/// Measured on the shipped pairs: hexagon 0.36, wave1 0.39, ridges 0.40, torus 0.46,
/// pacman 0.53, dots 0.58 (two families above the pooled target).
const FAMILY_MARGIN: f64 = 0.75;

/// Held-out families that must each have at least two pairs in `validation/` (a model may
/// have more).
const HELD_OUT_FAMILIES: [&str; 6] = [
    "mesh:dots",
    "mesh:hexagon",
    "mesh:pacman",
    "mesh:torus",
    "mesh:wave1",
    "ridges",
];

/// Per-gel gate of the family model: on each named gel's six held-out pairs (one of each
/// family), pooled, rom's MAE over the window at most this fraction of its coarse gel's: a
/// clear gain on every gel. Measured on the shipped pairs: 0.61 (18 x 14 x 1.5 mm), 0.58
/// (30 x 30 x 4 mm), 0.53 (40 x 30 x 6 mm), each pool dominated by its ridges press (coarse
/// 31 um, rom 22); over all 19 held-out presses of each set 0.51, 0.49 and 0.46 (the
/// manifest's `validation.gels`; issue 54's target, 0.35, is in the footprint, where they
/// are 0.42, 0.40 and 0.39: docs/rom.md, "One model for the family").
const FAMILY_GEL_MARGIN: f64 = 0.7;

fn model_dir() -> PathBuf {
    default_model_dir().expect("the shipped model models/rom-default")
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("tacrom-rom-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn copy_model(to: &Path) {
    copy_files(&model_dir(), to);
}

/// The files (not the folders) of `from` into `to`.
fn copy_files(from: &Path, to: &Path) {
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        if p.is_file() {
            std::fs::copy(&p, to.join(p.file_name().unwrap())).unwrap();
        }
    }
}

fn read_npy(path: &Path) -> (Vec<usize>, Vec<f32>) {
    datagen::read_npy(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The observation of a `gen-data` pair's `data` (coarse depth, rigid penetration,
/// reference; `spec.points()` values each).
fn pair_observation(spec: &LatticeSpec, data: &[f32]) -> Observation {
    let n = spec.points();
    let pen: Vec<f64> = data[n..2 * n].iter().map(|&v| v as f64).collect();
    Observation {
        coarse: data[..n].iter().map(|&v| v as f64).collect(),
        rule: DepthRule::from_penetration(spec.size[2], &pen),
        pen,
        material: Vec::new(),
        poisson: 0.0,
        ..Observation::default()
    }
}

/// The observation of the pair in `p` for `rom`, with the material inputs of the pair's
/// gel (its JSON's `poisson` and `friction`, else the model's gel).
fn pair_observation_for(rom: &Rom, p: &Path, data: &[f32]) -> Observation {
    let m = rom.manifest();
    let mut obs = pair_observation(&m.lattice, data);
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(p.with_extension("json")).unwrap()).unwrap();
    let value = |key: &str, default: f64| meta[key].as_f64().unwrap_or(default);
    let (poisson, friction) = (
        value("poisson", m.gel.poisson),
        value("friction", m.gel.friction),
    );
    rom.set_material(&mut obs, poisson, friction);
    obs
}

/// The `gen-data` pairs in the `validation/` folder of the model in `dir`, sorted.
fn validation_pairs(dir: &Path) -> Vec<PathBuf> {
    let mut pairs: Vec<PathBuf> = std::fs::read_dir(dir.join("validation"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "npy"))
        .collect();
    pairs.sort();
    pairs
}

#[test]
fn shipped_model_loads_and_outputs_have_the_manifests_shapes() {
    // With the refinement, so that the Jacobian graph is loaded and checked too.
    let refined = RomOptions {
        refine: Some(true),
        ..Default::default()
    };
    let mut rom = Rom::load(&model_dir(), refined).unwrap();
    let m = rom.manifest().clone();
    let spec = m.lattice;
    let obs = Observation {
        coarse: vec![0.0; spec.points()],
        pen: vec![0.0; spec.points()],
        rule: DepthRule::new(spec.size[2], &[]),
        material: Vec::new(),
        poisson: 0.0,
        ..Observation::default()
    };
    let z = rom.encode(&obs).unwrap();
    assert_eq!(z.len(), m.latent);
    let q = vec![0.1f32; 37 * spec.query_len()];
    let d = rom.decode(&z, &q).unwrap();
    assert_eq!(d.len(), 37);
    let (d2, j) = rom.decode_with_jacobian(&z, &q).unwrap();
    assert_eq!(d2.len(), 37);
    assert_eq!(j.len(), 37 * m.latent);
    for (a, b) in d.iter().zip(&d2) {
        assert!(
            (a - b).abs() < 1e-5,
            "decoder and Jacobian graph disagree: {a} {b}"
        );
    }
    // The manifest records the data, the training command and validation metrics.
    assert!(m
        .json
        .get("training")
        .and_then(|t| t.get("command"))
        .is_some());
    assert!(m.json.get("data").and_then(|t| t.get("pairs")).is_some());
    assert!(m
        .json
        .get("validation")
        .and_then(|t| t.get("held_out"))
        .is_some());
    // The default gel matches, at scale 1, and a gel of the family at its thickness
    // over the model's; a gel outside the family is refused with a clear message.
    assert_eq!(m.check_gel([0.03, 0.03, 0.004], 0.43, 0.5).unwrap(), 1.0);
    assert_eq!(m.check_gel([0.02, 0.016, 0.002], 0.43, 0.5).unwrap(), 0.5);
    let e = m.check_gel([0.03, 0.03, 0.007], 0.43, 0.5).unwrap_err();
    assert!(
        matches!(e, RomError::Mismatch { .. }) && e.to_string().contains("gel size"),
        "{e}"
    );
    // Within the materials it was validated on (manifest `materials`), and outside.
    let ranges = m
        .materials
        .expect("the shipped model's validated materials");
    for (nu, mu) in [
        (ranges.poisson[0], ranges.friction[0]),
        (ranges.poisson[1], ranges.friction[1]),
    ] {
        m.check_gel([0.03, 0.03, 0.004], nu, mu).unwrap();
    }
    let e = m.check_gel([0.03, 0.03, 0.004], 0.49, 0.5).unwrap_err();
    assert!(
        e.to_string().contains("Poisson's ratio in [0.3, 0.48]"),
        "{e}"
    );
    let e = m.check_gel([0.03, 0.03, 0.004], 0.43, 1.5).unwrap_err();
    assert!(e.to_string().contains("friction in [0, 1]"), "{e}");
}

/// The pressure head runs only where the pressure image is asked for, leaves the depth
/// and the force as they are (the shipped model's force comes from its volume factor), and
/// gives a compressive field on the deformable region alone whose own force corrects the
/// coarse gel's within the range the sensor accepts. A sphere and a cylinder pressed into
/// the coarse gel; the rom without the head wants the force (so that it maps the whole
/// lattice, as the head's does).
#[test]
fn the_pressure_head_runs_only_when_wanted_and_leaves_the_depth_alone() {
    let dir = model_dir();
    let force = RomOptions {
        force: true,
        ..Default::default()
    };
    let mut plain = Rom::load(&dir, force).unwrap();
    let mut with = Rom::load(
        &dir,
        RomOptions {
            pressure: true,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(
        with.manifest().pressure.is_some(),
        "the shipped model has a pressure head"
    );
    let spec = with.manifest().lattice;
    let params = GelParams {
        dx: with.manifest().gel.coarse_dx,
        ..GelParams::default()
    };
    let mut gel = Gel::new(params, SolverOptions::default()).unwrap();
    let grid = PixelGrid {
        width: 64,
        height: 48,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    let mut out = vec![0.0; 64 * 48];
    let shapes: [(Arc<dyn tacrom::geometry::Sdf>, f64); 2] = [
        (Arc::new(Sphere::new(0.004)), 0.004),
        (
            Arc::new(tacrom::geometry::Cylinder::new(0.002, 0.004)),
            0.004,
        ),
    ];
    for (shape, lowest) in shapes {
        gel.reset();
        let placed = [Placed {
            shape,
            pose: Isometry3::translation(0.0, 0.0, lowest - 0.3e-3),
        }];
        let _ = gel.solve(&placed);
        plain.evaluate(&gel, &placed, &grid, &mut out).unwrap();
        with.evaluate(&gel, &placed, &grid, &mut out).unwrap();
        assert!(plain.lattice_pressure().is_none() && plain.last_head_factor().is_none());
        assert_eq!(plain.lattice_depth(), with.lattice_depth());
        let field = with.lattice_pressure().unwrap();
        assert_eq!(field.len(), spec.points());
        let mut obs = Observation::from_gel(&gel, &placed, &spec);
        with.set_material(&mut obs, 0.43, 0.5);
        let mut region = Vec::new();
        let (eps, grow) = with.manifest().region;
        tacrom::rom::features::region(&obs, &spec, eps, grow, &mut Vec::new(), &mut region);
        for (i, (&v, &inside)) in field.iter().zip(&region).enumerate() {
            assert!(v.is_finite() && v >= 0.0, "point {i}: {v}");
            assert!(inside || v == 0.0, "load outside the region at {i}");
        }
        with.last_head_factor().expect("a correction within range");
        assert_eq!(with.force_factor(), plain.force_factor());
        assert!(with.manifest().force_volume_factor.is_some());
    }
}

#[test]
fn bad_model_directories_give_clear_errors() {
    // Missing directory.
    let e = Rom::load(Path::new("/nonexistent/model"), RomOptions::default()).unwrap_err();
    assert!(e.to_string().contains("/nonexistent/model"), "{e}");

    // Missing ONNX file.
    let d = scratch("missing");
    copy_model(&d);
    std::fs::remove_file(d.join("decoder.onnx")).unwrap();
    let e = Rom::load(&d, RomOptions::default()).unwrap_err();
    assert!(matches!(e, RomError::MissingFile(_)), "{e}");
    assert!(e.to_string().contains("decoder.onnx"), "{e}");

    // The Jacobian graph is loaded only for the latent refinement, which needs it.
    let d = scratch("no-jacobian");
    copy_model(&d);
    std::fs::remove_file(d.join("decoder_jacobian.onnx")).unwrap();
    let refined = RomOptions {
        refine: Some(true),
        ..Default::default()
    };
    let e = Rom::load(&d, refined).unwrap_err();
    assert!(e.to_string().contains("decoder_jacobian.onnx"), "{e}");
    Rom::load(&d, RomOptions::default()).expect("the shipped manifest leaves the refinement off");
    let plain = RomOptions {
        refine: Some(false),
        ..Default::default()
    };
    Rom::load(&d, plain).expect("without the refinement no Jacobian graph is read");

    // The pressure head is loaded only where the force or the pressure is wanted.
    let d = scratch("no-pressure");
    copy_model(&d);
    std::fs::remove_file(d.join("pressure.onnx")).unwrap();
    let wanted = RomOptions {
        pressure: true,
        ..Default::default()
    };
    let e = Rom::load(&d, wanted).unwrap_err();
    assert!(e.to_string().contains("pressure.onnx"), "{e}");
    Rom::load(&d, RomOptions::default()).expect("without the pressure no head is read");
    let force = RomOptions {
        force: true,
        ..Default::default()
    };
    Rom::load(&d, force).expect("the force comes from the volume factor: no head is read");
    // A head whose graph is another's: named with what it lacks.
    std::fs::copy(d.join("decoder.onnx"), d.join("pressure.onnx")).unwrap();
    let e = Rom::load(&d, wanted).unwrap_err();
    assert!(
        e.to_string().contains("pressure.onnx") && e.to_string().contains("pressure"),
        "{e}"
    );

    // Corrupt ONNX file.
    let d = scratch("corrupt");
    copy_model(&d);
    std::fs::write(d.join("encoder.onnx"), b"this is not a protobuf").unwrap();
    let e = Rom::load(&d, RomOptions::default()).unwrap_err();
    assert!(matches!(e, RomError::Graph { .. }), "{e}");
    assert!(
        e.to_string().contains("encoder.onnx") && e.to_string().contains("cannot load"),
        "{e}"
    );

    // A graph with other inputs than the manifest says.
    let d = scratch("swapped");
    copy_model(&d);
    std::fs::copy(d.join("decoder.onnx"), d.join("encoder.onnx")).unwrap();
    let e = Rom::load(&d, RomOptions::default()).unwrap_err();
    assert!(
        e.to_string().contains("encoder.onnx") && e.to_string().contains("observation"),
        "{e}"
    );

    // A graph of other shapes (the latent-16 ablation's encoder in a latent-64 model).
    let l16 = model_dir()
        .parent()
        .unwrap()
        .join("rom-latent16/encoder.onnx");
    if l16.is_file() {
        let d = scratch("shape");
        copy_model(&d);
        std::fs::copy(&l16, d.join("encoder.onnx")).unwrap();
        let e = Rom::load(&d, RomOptions::default()).unwrap_err();
        assert!(e.to_string().contains("shape"), "{e}");
    }

    // Manifest: unreadable, missing a field, wrong format.
    let d = scratch("manifest");
    copy_model(&d);
    let text = std::fs::read_to_string(d.join("manifest.json")).unwrap();
    std::fs::write(d.join("manifest.json"), &text[..text.len() / 2]).unwrap();
    let e = Rom::load(&d, RomOptions::default()).unwrap_err();
    assert!(
        matches!(e, RomError::Manifest { .. }) && e.to_string().contains("invalid JSON"),
        "{e}"
    );
    std::fs::write(
        d.join("manifest.json"),
        text.replace("\"latent\"", "\"latent_size\""),
    )
    .unwrap();
    let e = Rom::load(&d, RomOptions::default()).unwrap_err();
    assert!(e.to_string().contains("`latent`"), "{e}");
    std::fs::write(
        d.join("manifest.json"),
        text.replace("tacrom-rom-1", "tacrom-rom-0"),
    )
    .unwrap();
    let e = Rom::load(&d, RomOptions::default()).unwrap_err();
    assert!(e.to_string().contains("format"), "{e}");
}

#[derive(Default)]
struct Mae {
    coarse: f64,
    rom: f64,
    rom_no_refinement: f64,
    rigid: f64,
}

/// Mean absolute error over the sensor's default field of view (24 x 18 mm) of the lattice.
fn fov_mae(spec: &LatticeSpec, a: &[f64], b: &[f32]) -> f64 {
    let pitch = spec.size[0] / spec.nx as f64;
    let cx = (0.024 / pitch).round() as usize;
    let cy = (0.018 / pitch).round() as usize;
    let (x0, y0) = ((spec.nx - cx) / 2, (spec.ny - cy) / 2);
    let mut s = 0.0;
    for r in y0..y0 + cy {
        for c in x0..x0 + cx {
            let i = r * spec.nx + c;
            s += (a[i] - b[i] as f64).abs();
        }
    }
    s / (cx * cy) as f64
}

#[test]
fn rom_is_closer_to_the_reference_than_coarse_on_held_out_families() {
    held_out_gate(&model_dir(), 0.0003);
}

/// The linear solver's model (`models/rom-linear`) on its own 12 held-out pairs (the
/// linear solver's coarse channel, and the 0.7 mm reference it was trained against: no
/// 0.3 mm presses were made for it) against that solver's coarse depth, with the same
/// gates. Measured: dots 0.42, hexagon 0.37, pacman 0.23, torus 0.37, wave1 0.55, ridges
/// 0.63 (two presses whose coarse error is 0.23 um), pooled 0.37.
#[test]
fn rom_linear_is_closer_to_the_reference_than_its_coarse_gel_on_held_out_families() {
    let dir = tacrom::rom::shipped_model_dir(tacrom::rom::LINEAR_MODEL).expect("models/rom-linear");
    held_out_gate(&dir, 0.0007);
}

/// The same pairs and gates for the linear solver's model with a narrower decoder
/// (`models/rom-linear-narrow`, which shares `models/rom-linear`'s encoder).
#[test]
fn rom_linear_narrow_is_closer_to_the_reference_than_its_coarse_gel_on_held_out_families() {
    let dir = tacrom::rom::shipped_model_dir(tacrom::rom::LINEAR_NARROW_MODEL)
        .expect("models/rom-linear-narrow");
    held_out_gate(&dir, 0.0007);
}

/// `models/rom-linear` decodes densely with an 8-bit copy of its decoder (manifest
/// `files.decoder.quantized`; `training/tacrom_rom/quantize.py`). On the model's held-out
/// pairs its depth stays close to the float original's (the same model directory, its
/// manifest pointed back at `decoder.onnx`): the mean difference over the decoded points
/// under 0.5 um (measured 0.35) and the largest under 8 um (measured 5.0, one point of
/// several thousand; the model before had 0.33 and 3.2). Unrelated to the model's own error
/// against the reference (2.05 um on the 56 held-out presses), a difference of 0.5 um
/// raises it by about 3 % in quadrature (`tacrom eval-rom` measured 2.05 um with either
/// decoder, and the same force errors).
#[test]
fn rom_linear_8_bit_decoder_follows_its_float_original() {
    let dir = tacrom::rom::shipped_model_dir(tacrom::rom::LINEAR_MODEL).expect("models/rom-linear");
    let float = scratch("float-decoder");
    copy_files(&dir, &float);
    let manifest = float.join("manifest.json");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&manifest).unwrap()).unwrap();
    let decoder = &mut json["files"]["decoder"];
    assert_eq!(
        decoder["path"], "decoder_int8.onnx",
        "the shipped decoder is the 8-bit one"
    );
    assert_eq!(decoder["quantized"]["from"], "decoder.onnx");
    decoder["path"] = "decoder.onnx".into();
    std::fs::write(&manifest, serde_json::to_string(&json).unwrap()).unwrap();
    let mut int8 = Rom::load(&dir, RomOptions::default()).unwrap();
    let mut full = Rom::load(&float, RomOptions::default()).unwrap();
    let (mut sum, mut count, mut worst) = (0.0, 0usize, 0.0f64);
    for p in validation_pairs(&dir) {
        let obs = pair_observation_for(&int8, &p, &read_npy(&p).1);
        int8.infer(&obs).unwrap();
        full.infer(&obs).unwrap();
        for ((a, b), c) in int8
            .lattice_depth()
            .iter()
            .zip(full.lattice_depth())
            .zip(&obs.coarse)
        {
            if a != c || b != c {
                sum += (a - b).abs();
                count += 1;
                worst = worst.max((a - b).abs());
            }
        }
    }
    let _ = std::fs::remove_dir_all(&float);
    assert!(count > 0, "no decoded point");
    let mean = sum / count as f64;
    eprintln!(
        "8-bit against float decoder over {count} decoded points: mean {:.3} um, largest {:.3} um",
        mean * 1e6,
        worst * 1e6
    );
    assert!(
        mean < 0.5e-6 && worst < 8e-6,
        "mean {mean:e} m, largest {worst:e} m"
    );
}

/// The gel family's model (`models/rom-family`, trained on presses over the family: `make
/// train-family`) on its validation pairs: the held-out presses of three named gels, a thin
/// 18 x 14 x 1.5 mm one, the default 30 x 30 x 4 mm and a thick 40 x 30 x 6 mm one (`make
/// gen-data-family-validation`: each solved in the model's units and written as the
/// window the sensor reads on that gel, the reference at `T / 8`). Each gel is one the
/// model serves (`check_gel`, what the sensor asks at load); on each, rom's depth MAE over
/// the window is at most [`FAMILY_GEL_MARGIN`] of its coarse gel's, and on each held-out
/// family, pooled over the gels, at most [`FAMILY_MARGIN`]; no depth is NaN. The pairs are
/// one press of each family from each set (`tacrom_rom.validate`).
#[test]
fn rom_family_passes_its_validation_pairs_on_thin_default_and_thick_gels() {
    let dir = tacrom::rom::shipped_model_dir("rom-family").expect("models/rom-family");
    let mut rom = Rom::load(&dir, RomOptions::default()).unwrap();
    let spec = rom.manifest().lattice;
    let n = spec.points();
    let mae = |a: &[f64], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, &y)| (x - y as f64).abs())
            .sum::<f64>()
            / n as f64
    };
    // Per gel (mm, as drawn) and per family: (pairs, coarse MAE sum, rom MAE sum).
    let mut gels: std::collections::BTreeMap<String, (usize, f64, f64)> = Default::default();
    let mut families: std::collections::BTreeMap<String, (usize, f64, f64)> = Default::default();
    for p in validation_pairs(&dir) {
        let meta: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(p.with_extension("json")).unwrap())
                .unwrap();
        assert_eq!(meta["held_out"], true, "{} is not held out", p.display());
        let gel: datagen::FamilyGel = serde_json::from_value(meta["gel"].clone())
            .unwrap_or_else(|e| panic!("{}: no gel of the family: {e}", p.display()));
        let (poisson, friction) = (
            meta["poisson"].as_f64().unwrap(),
            meta["friction"].as_f64().unwrap(),
        );
        rom.manifest()
            .check_gel(gel.size, poisson, friction)
            .unwrap_or_else(|e| panic!("{}: the model refuses its gel: {e}", p.display()));
        let (shape, data) = read_npy(&p);
        assert_eq!(shape, vec![3, spec.ny, spec.nx]);
        let obs = pair_observation_for(&rom, &p, &data);
        rom.infer(&obs).unwrap();
        let depth = rom.lattice_depth();
        assert!(depth.iter().all(|d| d.is_finite()), "{}", p.display());
        let reference = &data[2 * n..];
        let (c, r) = (mae(&obs.coarse, reference), mae(depth, reference));
        let family = meta["family"].as_str().unwrap().to_owned();
        let name = format!(
            "{:.0} x {:.0} x {} mm",
            gel.size[0] * 1e3,
            gel.size[1] * 1e3,
            gel.size[2] * 1e3
        );
        eprintln!(
            "{name:>18} {family:>14}: MAE vs reference (um, model units) coarse {:.2} rom {:.2}",
            c * 1e6,
            r * 1e6
        );
        for (map, key) in [(&mut gels, name), (&mut families, family)] {
            let e = map.entry(key).or_insert((0, 0.0, 0.0));
            *e = (e.0 + 1, e.1 + c, e.2 + r);
        }
    }
    for want in ["18 x 14 x 1.5 mm", "30 x 30 x 4 mm", "40 x 30 x 6 mm"] {
        assert!(
            gels.contains_key(want),
            "no validation pairs on the {want} gel: {gels:?}"
        );
    }
    // The sets hold the held-out families their draws gave (100 draws of another seed: 19
    // presses of six families, each press on all three gels).
    assert!(families.len() >= 5, "{families:?}");
    assert!(families.values().all(|f| f.0 >= 2), "{families:?}");
    let mut failed = Vec::new();
    for (what, map, margin) in [
        ("gel", &gels, FAMILY_GEL_MARGIN),
        ("family", &families, FAMILY_MARGIN),
    ] {
        for (key, (count, c, r)) in map {
            eprintln!(
                "{what} {key}: {count} pairs, mean MAE (um) coarse {:.2} rom {:.2}; rom / coarse {:.2}",
                c / *count as f64 * 1e6,
                r / *count as f64 * 1e6,
                r / c
            );
            if r / c > margin {
                failed.push(format!("{what} {key}: rom / coarse {:.2}", r / c));
            }
        }
    }
    assert!(failed.is_empty(), "{failed:?}");
}

/// The gates above on the `validation/` pairs of the model in `dir`, whose reference has
/// the spacing `reference_dx` (m).
fn held_out_gate(dir: &Path, reference_dx: f64) {
    let dir = dir.to_path_buf();
    // The refinement is off in the shipped manifests (it changes no error measurably):
    // here it runs, to gate what it does.
    let refined = RomOptions {
        refine: Some(true),
        ..Default::default()
    };
    let mut rom = Rom::load(&dir, refined).unwrap();
    let mut plain = Rom::load(
        &dir,
        RomOptions {
            refine: Some(false),
            ..Default::default()
        },
    )
    .unwrap();
    let spec = rom.manifest().lattice;
    let n = spec.points();
    let pairs = validation_pairs(&dir);
    assert!(!pairs.is_empty(), "no held-out pairs in {}", dir.display());
    let mut families: std::collections::BTreeMap<String, (usize, Mae)> = Default::default();
    // The latent refinement's steps, and the decoder's contact violations before the depth
    // rule (into the indenters and below the deepest point, worst lattice point per pair),
    // with and without it.
    let (mut steps, mut violation) = (0usize, [0.0f64; 2]);
    for p in &pairs {
        let meta = std::fs::read_to_string(p.with_extension("json")).unwrap();
        let meta: serde_json::Value = serde_json::from_str(&meta).unwrap();
        assert_eq!(meta["held_out"], true, "{} is not held out", p.display());
        assert_eq!(
            meta["reference_dx"],
            reference_dx,
            "{}: not the model's reference",
            p.display()
        );
        let (shape, data) = read_npy(p);
        assert_eq!(shape, vec![3, spec.ny, spec.nx]);
        let obs = pair_observation_for(&rom, p, &data);
        let reference = &data[2 * n..];
        let report = rom.infer(&obs).unwrap();
        let m_rom = fov_mae(&spec, rom.lattice_depth(), reference);
        let plain_report = plain.infer(&obs).unwrap();
        steps += report.refinement.map_or(0, |r| r.iterations);
        violation[0] += report.penetration_excess + report.bound_excess;
        violation[1] += plain_report.penetration_excess + plain_report.bound_excess;
        let m_plain = fov_mae(&spec, plain.lattice_depth(), reference);
        let m_coarse = fov_mae(&spec, &obs.coarse, reference);
        let m_rigid = fov_mae(&spec, &obs.pen, reference);
        let family = meta["family"].as_str().unwrap().to_owned();
        eprintln!(
            "{family:>14} {}: MAE vs reference (um) coarse {:.2} rom {:.2} rom w/o refinement \
             {:.2} rigid {:.2}; refinement {:?}",
            p.file_stem().unwrap().to_string_lossy(),
            m_coarse * 1e6,
            m_rom * 1e6,
            m_plain * 1e6,
            m_rigid * 1e6,
            report.refinement.map(|r| (r.iterations, r.initial, r.last))
        );
        let (count, m) = families.entry(family).or_insert((0, Mae::default()));
        *count += 1;
        m.coarse += m_coarse;
        m.rom += m_rom;
        m.rom_no_refinement += m_plain;
        m.rigid += m_rigid;
    }
    // Every held-out family of the default set has pairs; a model trained with more
    // families (rom-linear: `brick`) has theirs too, gated alike.
    for family in HELD_OUT_FAMILIES {
        assert!(
            families.contains_key(family),
            "no held-out pairs of {family}"
        );
    }
    let mut total = Mae::default();
    let mut failed = Vec::new();
    for (family, (count, m)) in &families {
        let ratio = m.rom / m.coarse;
        eprintln!(
            "{family:>14}: {count} pairs, mean MAE (um) coarse {:.2} rom {:.2} rom w/o \
             refinement {:.2} rigid {:.2}; rom / coarse {ratio:.2}",
            m.coarse / *count as f64 * 1e6,
            m.rom / *count as f64 * 1e6,
            m.rom_no_refinement / *count as f64 * 1e6,
            m.rigid / *count as f64 * 1e6,
        );
        assert!(*count >= 2, "{family}: {count} pair(s), at least 2 wanted");
        if ratio > FAMILY_MARGIN {
            failed.push(format!("{family}: rom / coarse {ratio:.2}"));
        }
        let c = *count as f64;
        total.coarse += m.coarse / c;
        total.rom += m.rom / c;
        total.rom_no_refinement += m.rom_no_refinement / c;
        total.rigid += m.rigid / c;
    }
    let k = families.len() as f64;
    eprintln!(
        "mean over {} held-out families (um): coarse {:.2}, rom {:.2}, rom w/o refinement \
         {:.2}, rigid {:.2}; rom / coarse {:.2}",
        families.len(),
        total.coarse / k * 1e6,
        total.rom / k * 1e6,
        total.rom_no_refinement / k * 1e6,
        total.rigid / k * 1e6,
        total.rom / total.coarse
    );
    eprintln!(
        "refinement: {steps} L-BFGS steps over {} pairs; contact violations before the depth \
         rule, summed over the pairs: {:.2} um refined, {:.2} um not",
        pairs.len(),
        violation[0] * 1e6,
        violation[1] * 1e6
    );
    // The refinement's energy penalises these violations on a sub-lattice (with an inertial
    // and a membrane term), and L-BFGS accepts only steps that lower it: it must take
    // steps, and the violations on the whole lattice must not grow (measured on the 16
    // shipped pairs: see the message above; eval-rom on 56 presses: 8.35 -> 8.05 um into
    // the indenters).
    assert!(steps > 0, "the latent refinement took no step on any pair");
    assert!(
        violation[0] <= violation[1],
        "the refinement increased the contact violations: {:e} against {:e} m",
        violation[0],
        violation[1]
    );
    assert!(
        failed.is_empty(),
        "families where rom is not below {FAMILY_MARGIN} x coarse: {failed:?}"
    );
    assert!(
        total.rom <= HELD_OUT_MARGIN * total.coarse,
        "pooled over families: rom MAE {:.3e} is not below {HELD_OUT_MARGIN} x coarse MAE {:.3e}",
        total.rom / k,
        total.coarse / k
    );
}

/// A rom that wants no force (the default sensor's depth image alone: `tacrom/Press-v1`)
/// maps the coarse depth only where its encoder, its image and the decoder's region for the
/// image read it, and decodes only the region's points the image reads: its image is a
/// rom's that maps the whole lattice (one that wants the force), to the decoder's
/// single-precision round-off of a batch of another size (1 nm; bit for bit where the
/// batches are the same). Presses centred, across the image's edge, beside it, and two at
/// once; at Press-v1's 64 x 48 and at a small image that leaves most of the gel unseen.
#[test]
fn a_rom_without_force_maps_and_decodes_only_what_its_image_reads() {
    let dir =
        tacrom::rom::shipped_model_dir("rom-linear-narrow").expect("models/rom-linear-narrow");
    let mut part = Rom::load(&dir, RomOptions::default()).unwrap();
    let wants_force = RomOptions {
        force: true,
        ..Default::default()
    };
    let mut whole = Rom::load(&dir, wants_force).unwrap();
    let params = GelParams {
        dx: part.manifest().gel.coarse_dx,
        ..GelParams::default()
    };
    let options = SolverOptions {
        solver: tacrom::mpm::Solver::Linear,
        ..Default::default()
    };
    let mut gel = Gel::new(params, options).unwrap();
    let sphere: Arc<dyn tacrom::geometry::Sdf> = Arc::new(Sphere::new(0.005));
    let cylinder: Arc<dyn tacrom::geometry::Sdf> =
        Arc::new(tacrom::geometry::Cylinder::new(0.002, 0.004));
    let at = |shape: &Arc<dyn tacrom::geometry::Sdf>, x: f64, y: f64, z: f64| Placed {
        shape: shape.clone(),
        pose: Isometry3::translation(x, y, z),
    };
    let presses = [
        vec![at(&sphere, 0.0, 0.0, 0.005 - 0.8e-3)],
        vec![at(&sphere, 0.011, 0.002, 0.005 - 0.6e-3)],
        vec![at(&cylinder, -0.012, -0.008, 0.004 - 0.3e-3)],
        vec![
            at(&sphere, -0.004, 0.0, 0.005 - 0.5e-3),
            at(&sphere, 0.005, 0.004, 0.005 - 0.7e-3),
        ],
    ];
    let grids = [
        PixelGrid {
            width: 64,
            height: 48,
            fov_x: 0.024,
            fov_y: 0.018,
        },
        PixelGrid {
            width: 40,
            height: 30,
            fov_x: 0.008,
            fov_y: 0.006,
        },
    ];
    let mut fewer = 0;
    for grid in &grids {
        let n = grid.width * grid.height;
        let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
        for (k, placed) in presses.iter().enumerate() {
            gel.reset();
            let _ = gel.solve(placed);
            let read = part.evaluate(&gel, placed, grid, &mut a).unwrap();
            let all = whole.evaluate(&gel, placed, grid, &mut b).unwrap();
            let worst = a
                .iter()
                .zip(&b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max);
            assert!(
                worst <= 1e-9,
                "press {k} at {}x{}: the images differ by {worst:e} m",
                grid.width,
                grid.height
            );
            if read.decoded == all.decoded {
                assert_eq!(a, b, "press {k}: the same batch, other bits");
            }
            assert!(read.decoded <= all.decoded, "press {k}: {read:?} {all:?}");
            fewer += usize::from(read.decoded < all.decoded);
            // The part's observation holds the coarse depth where it was read only.
            let mapped = part.lattice_depth().iter().filter(|&&d| d != 0.0).count();
            let everywhere = whole.lattice_depth().iter().filter(|&&d| d != 0.0).count();
            assert!(
                mapped < everywhere,
                "press {k}: {mapped} of {everywhere} mapped"
            );
            assert_eq!(part.force_factor(), 1.0);
        }
    }
    // The presses across and beside the image's edge decode less than the whole region.
    assert!(fewer >= 3, "{fewer} evaluations decoded fewer points");
}

#[test]
fn rom_moving_press_320x240_stays_bounded_and_tracks_depth() {
    let mut rom = Rom::load(&model_dir(), RomOptions::default()).unwrap();
    let params = GelParams {
        dx: rom.manifest().gel.coarse_dx,
        ..GelParams::default()
    };
    let mut gel = Gel::new(params, SolverOptions::default()).unwrap();
    let grid = PixelGrid {
        width: 320,
        height: 240,
        fov_x: 0.024,
        fov_y: 0.018,
    };
    let sphere = Arc::new(Sphere::new(0.005));
    let mut out = vec![0.0; 320 * 240];
    let mut zmin = vec![f64::INFINITY; 320 * 240];
    let mut worst_excess: f64 = 0.0;
    for k in 0..6 {
        // A moving press: 0.4 to 0.65 mm deep, sliding along x.
        let depth = 0.4e-3 + 0.05e-3 * k as f64;
        let placed = [Placed {
            shape: sphere.clone(),
            pose: Isometry3::translation(1e-4 * k as f64, 0.0, 0.005 - depth),
        }];
        let _ = gel.solve(&placed);
        zmin.fill(f64::INFINITY);
        placed[0].lower_surface(&grid, -0.004, 0.0, &mut zmin);
        let report = rom.evaluate(&gel, &placed, &grid, &mut out).unwrap();
        let rule = DepthRule::new(0.004, &placed);
        let pen: Vec<f64> = zmin.iter().map(|&z| rule.penetration(z)).collect();
        worst_excess = worst_excess.max(rule.apply(&mut out, &pen));
        assert!(out
            .iter()
            .all(|d| d.is_finite() && (0.0..=0.004).contains(d)));
        let peak = out.iter().cloned().fold(0.0, f64::max);
        assert!(
            (peak - depth).abs() < 0.1e-3,
            "peak {peak} for depth {depth}"
        );
        if k == 5 {
            eprintln!("last evaluation: {report:?}");
        }
    }
    eprintln!("deepest decoded point below the sphere's apex: {worst_excess:e} m");
    // Its cost is measured by `cargo bench --bench sensor` and `tacrom bench`, not here.
}

#[test]
fn gen_data_writes_numpy_pairs_and_resumes() {
    let out = scratch("gendata");
    let config = GenConfig {
        out: out.clone(),
        samples: 2,
        shard: (1, 2),
        coarse_dx: 2e-3,
        fine_dx: 2e-3,
        pitch: 1e-3,
        families: vec!["sphere".into()],
        ..GenConfig::default()
    };
    let mut lines = Vec::new();
    datagen::generate(&config, |l| lines.push(l.to_owned())).unwrap();
    // Shard 1/2 of two samples: sample 1 only.
    assert_eq!(lines.len(), 1, "{lines:?}");
    assert!(!out.join("sample-000000.npy").exists());
    let (shape, data) = read_npy(&out.join("sample-000001.npy"));
    assert_eq!(shape, vec![3, 30, 30]);
    assert!(data
        .iter()
        .all(|v| v.is_finite() && *v >= 0.0 && *v <= 0.004));
    assert!(data.iter().any(|&v| v > 1e-5), "the press left no mark");
    let meta = std::fs::read_to_string(out.join("sample-000001.json")).unwrap();
    assert!(meta.contains("\"family\": \"sphere\""), "{meta}");
    // Both solves' forces are recorded: a sphere pressed into the gel pushes it down.
    let meta: serde_json::Value = serde_json::from_str(&meta).unwrap();
    // The pressure companion holds both solves' normal contact pressure, which integrates
    // over the lattice (1 mm pitch) to the solve's normal force: the kernel integrates to
    // one and the contact lies inside the lattice, so up to float32 round-off.
    let (shape, pressure) = read_npy(&out.join("sample-000001-pressure.npy"));
    assert_eq!(shape, vec![2, 30, 30]);
    for (k, solve) in ["coarse", "reference"].into_iter().enumerate() {
        let fz = meta[solve]["force"][2].as_f64().unwrap();
        assert!(fz > 0.0 && fz.is_finite(), "{solve}: {meta}");
        let channel = &pressure[k * 900..(k + 1) * 900];
        assert!(channel.iter().all(|p| p.is_finite() && *p >= 0.0));
        let integral: f64 = channel.iter().map(|&p| p as f64 * 1e-6).sum();
        assert!(
            (integral - fz).abs() <= 1e-5 * fz,
            "{solve}: pressure integrates to {integral} N, force {fz} N"
        );
    }
    // Resumable: nothing left to do.
    let summary = datagen::generate(&config, |_| {}).unwrap();
    assert!(
        summary.contains("0 samples written, 1 already present"),
        "{summary}"
    );
    // Draws depend on (seed, index) only, not on the sharding.
    let a = datagen::draw_press(
        1,
        1,
        &mut datagen::MeshLibrary::default(),
        &config.families,
        [0.03, 0.03, 0.004],
    )
    .unwrap();
    assert_eq!(a.family, "sphere");
    assert!(a.poses[0].translation.vector.iter().all(|v| v.is_finite()));
    let _ = std::fs::remove_dir_all(&out);
}

/// A data set of gel materials drawn per sample: each sample's Poisson's ratio and
/// friction lie in their ranges, are recorded in its JSON and in the gel it was solved on
/// (the same press on a gel of the fixed default material gives another coarse depth), the
/// presses are those of the fixed-material set, and `dataset.json` records the ranges.
#[test]
fn gen_data_draws_each_samples_material_from_its_ranges() {
    let out = scratch("gendata-material");
    let base = GenConfig {
        out: out.clone(),
        samples: 3,
        coarse_dx: 2e-3,
        fine_dx: 2e-3,
        pitch: 1e-3,
        families: vec!["sphere".into()],
        ..GenConfig::default()
    };
    let config = GenConfig {
        poisson_range: Some([0.3, 0.48]),
        friction_range: Some([0.0, 1.0]),
        ..base.clone()
    };
    datagen::generate(&config, |_| {}).unwrap();
    let dataset: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(dataset["poisson_range"], serde_json::json!([0.3, 0.48]));
    assert_eq!(dataset["friction_range"], serde_json::json!([0.0, 1.0]));
    let fixed_out = scratch("gendata-material-fixed");
    datagen::generate(
        &GenConfig {
            out: fixed_out.clone(),
            ..base
        },
        |_| {},
    )
    .unwrap();
    let mut materials = Vec::new();
    for i in 0..3 {
        let name = format!("sample-{i:06}");
        let meta: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join(format!("{name}.json"))).unwrap(),
        )
        .unwrap();
        let fixed: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(fixed_out.join(format!("{name}.json"))).unwrap(),
        )
        .unwrap();
        let (nu, mu) = (
            meta["poisson"].as_f64().unwrap(),
            meta["friction"].as_f64().unwrap(),
        );
        assert!(
            (0.3..=0.48).contains(&nu) && (0.0..=1.0).contains(&mu),
            "{nu} {mu}"
        );
        // (serde_json parses floats to within one unit in the last place.)
        assert!((config.sample_gel(i).poisson - nu).abs() < 1e-15, "{nu}");
        assert!((config.sample_gel(i).friction - mu).abs() < 1e-15, "{mu}");
        assert!(fixed.get("poisson").is_none(), "{fixed}");
        // The same press (shape and poses), another gel: another coarse depth.
        for key in ["family", "radius", "x", "y", "depth", "slide"] {
            assert_eq!(meta[key], fixed[key], "{name}: {key}");
        }
        let (_, a) = read_npy(&out.join(format!("{name}.npy")));
        let (_, b) = read_npy(&fixed_out.join(format!("{name}.npy")));
        let n = a.len() / 3;
        if a[n..2 * n].iter().any(|&p| p > 0.0) {
            assert_ne!(a[..n], b[..n], "{name}: the material changed nothing");
        }
        materials.push((nu, mu));
    }
    assert!(materials.windows(2).all(|w| w[0] != w[1]), "{materials:?}");
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_dir_all(&fixed_out);
}

/// A data set over the gel family: each sample's gel lies in the family, is simulated in
/// the model's units (the model's thickness, sides in thicknesses, cut at the crop), and
/// its arrays are the window of the model's lattice over the contact that the sensor's
/// encoder reads on that gel: the same encoder input, and the same decoder queries
/// wherever a query's window lies within the window. And the simulated press is the drawn
/// gel's own scaled: the press at the drawn thickness, its grid and indenter scaled with
/// it, gives the sample's coarse channel times the scale (elasticity has no length of its
/// own; the solves are scale-free to their rounding, `a_scaled_press_is_the_press_scaled`:
/// 3e-8 m on a 0.5 mm press, here allowed 1e-3 of the deepest point).
#[test]
fn gen_data_draws_gels_from_the_family_in_the_models_units() {
    use tacrom::rom::features::query_features;
    let out = scratch("gendata-family");
    let family = datagen::GelFamily::default();
    let config = GenConfig {
        out: out.clone(),
        samples: 4,
        coarse_dx: 2e-3,
        fine_dx: 2e-3,
        pitch: 1e-3,
        families: vec!["sphere".into(), "box".into()],
        poisson_range: Some([0.3, 0.49]),
        friction_range: Some([0.0, 1.0]),
        gel_family: Some(family),
        ..GenConfig::default()
    };
    datagen::generate(&config, |_| {}).unwrap();
    let model = LatticeSpec::with_pitch(config.gel.size, config.pitch);
    let t_model = config.gel.size[2];
    let (mut cropped, mut narrow) = (0, 0);
    for i in 0..config.samples {
        let stem = out.join(format!("sample-{i:06}"));
        let meta: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(stem.with_extension("json")).unwrap())
                .unwrap();
        let gel: datagen::FamilyGel = serde_json::from_value(meta["gel"].clone()).unwrap();
        let [lx, ly, t] = gel.size;
        assert!(
            (family.thickness[0]..=family.thickness[1]).contains(&t),
            "{gel:?}"
        );
        for (l, sim) in [(lx, gel.simulated[0]), (ly, gel.simulated[1])] {
            assert!((family.side[0]..=family.side[1]).contains(&l), "{gel:?}");
            let want = t_model * (l / t).min(family.crop);
            assert!((sim - want).abs() <= 1e-12, "{gel:?}");
        }
        assert_eq!(gel.simulated[2], t_model);
        assert_eq!(gel.cropped, lx / t > family.crop || ly / t > family.crop);
        cropped += usize::from(gel.cropped);
        narrow += usize::from(gel.simulated[0].min(gel.simulated[1]) < config.gel.size[0]);
        let [a, b] = family.indenter_scale;
        assert!((a..=b).contains(&gel.indenter_scale), "{gel:?}");
        let (shape, data) = read_npy(&stem.with_extension("npy"));
        assert_eq!(shape, vec![3, model.ny, model.nx]);
        assert!(data
            .iter()
            .all(|v| v.is_finite() && (0.0..=t_model as f32).contains(v)));

        // What the sensor reads on this gel.
        let press = config
            .press(i, &mut datagen::MeshLibrary::default())
            .unwrap();
        let params = GelParams {
            dx: config.coarse_dx,
            material: tacrom::mpm::Material::FixedCorotated,
            ..config.sample_gel(i)
        };
        let mut coarse = Gel::new(params, SolverOptions::default()).unwrap();
        let _ = datagen::solve_press(&mut coarse, &press);
        let spec = LatticeSpec {
            window: [model.ny, model.nx],
            ..LatticeSpec::with_pitch(gel.simulated, config.pitch)
        };
        let last = [press.placed(press.poses.len() - 1)];
        let sensor = Observation::from_gel(&coarse, &last, &spec);
        assert_eq!(sensor.origin, gel.origin, "sample {i}");
        let sample = pair_observation(&model, &data);
        let (mut e_sensor, mut e_sample) = (Vec::new(), Vec::new());
        sensor.encoder_input(&spec, &mut e_sensor);
        sample.encoder_input(&model, &mut e_sample);
        assert_eq!(e_sensor.len(), e_sample.len());
        // (The sample holds metres in float32; the sensor rounds millimetres to it.)
        let close = |a: f32, b: f32| (a - b).abs() <= 1e-6 * a.abs().max(1.0);
        for (k, (a, b)) in e_sensor.iter().zip(&e_sample).enumerate() {
            assert!(
                close(*a, *b),
                "sample {i}: encoder input {k}: {a} against {b}"
            );
        }
        // The query features read the coarse depth through the inverse map, whose pixels
        // may stop after one step within its bound (a fraction of the thickness, mm
        // here). The data set's observation and the sensor's are mapped apart and may
        // stop a pixel a step apart; with every pixel solved they agree to the float's
        // rounding (measured).
        let map = tacrom::mpm::ONE_STEP_FRACTION * t_model * 1e3;
        let close_mapped =
            |a: f32, b: f32| (a - b).abs() as f64 <= 1e-6 * a.abs().max(1.0) as f64 + map;
        let reach = (model.patch / 2 * model.patch_step) as isize;
        let (mut q_sensor, mut q_sample) = (Vec::new(), Vec::new());
        let mut compared = 0;
        for row in reach..model.ny as isize - reach {
            for col in reach..model.nx as isize - reach {
                let (r, c) = (row + gel.origin[0], col + gel.origin[1]);
                if r < 0 || c < 0 || r >= spec.ny as isize || c >= spec.nx as isize {
                    continue;
                }
                q_sensor.clear();
                q_sample.clear();
                query_features(&sensor, &spec, r as usize, c as usize, &mut q_sensor);
                query_features(&sample, &model, row as usize, col as usize, &mut q_sample);
                for (a, b) in q_sensor.iter().zip(&q_sample) {
                    assert!(
                        close_mapped(*a, *b),
                        "sample {i} at {row},{col}: {a} against {b}"
                    );
                }
                compared += 1;
            }
        }
        assert!(compared > 0, "sample {i}");

        // The drawn gel's own press, at its thickness.
        let s = t / t_model;
        let physical = GelParams {
            size: gel.simulated.map(|v| v * s),
            dx: config.coarse_dx * s,
            ..params
        };
        let scaled = datagen::Press {
            shape: Arc::new(datagen::Scaled {
                inner: press.shape.clone(),
                scale: s,
            }),
            poses: press
                .poses
                .iter()
                .map(|p| Isometry3::from_parts((p.translation.vector * s).into(), p.rotation))
                .collect(),
            ..press.clone()
        };
        let mut gel_s = Gel::new(physical, SolverOptions::default()).unwrap();
        let _ = datagen::solve_press(&mut gel_s, &scaled);
        let spec_s = LatticeSpec {
            size: physical.size,
            ..spec
        };
        assert_eq!((spec_s.nx, spec_s.ny), (spec.nx, spec.ny));
        let last = [scaled.placed(scaled.poses.len() - 1)];
        let obs_s = Observation::from_gel(&gel_s, &last, &spec_s);
        assert_eq!(obs_s.origin, gel.origin, "sample {i}");
        let window = datagen::cut_window(&obs_s.coarse, &spec_s, obs_s.origin);
        let n = model.points();
        let deepest = data[..n].iter().fold(0f32, |m, &v| m.max(v)) as f64;
        assert!(deepest > 1e-6, "sample {i}: no mark");
        for (k, (&a, &b)) in window.iter().zip(&data[..n]).enumerate() {
            assert!(
                (a / s - b as f64).abs() <= 1e-3 * deepest,
                "sample {i} point {k}: {} against {b} m",
                a / s
            );
        }
    }
    // The four draws include a side cut at the crop and a gel narrower than the window.
    assert!(cropped > 0 && narrow > 0, "{cropped} {narrow}");
    let dataset: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(
        dataset["gel_family"]["crop"],
        serde_json::json!(family.crop)
    );
    let _ = std::fs::remove_dir_all(&out);
}

/// A family data set of one gel (`gen-data --gel-family --gel-size`, the validation sets of
/// a named gel): every sample's gel is that gel, simulated by the family's rule, with the
/// indenter scales of the drawn set (the same random stream); a gel outside the family is
/// refused naming the side and the range.
#[test]
fn a_family_set_of_one_gel_holds_that_gel() {
    let family = datagen::GelFamily::default();
    let one = family.with_gel([18e-3, 14e-3, 1.5e-3]).unwrap();
    for i in 0..20 {
        let (drawn, fixed) = (family.draw(5, i, 4e-3), one.draw(5, i, 4e-3));
        assert_eq!(fixed.size, [18e-3, 14e-3, 1.5e-3]);
        // 12 and 9.3 thicknesses: both sides cut to the family's 9.
        assert!((fixed.simulated[0] - 36e-3).abs() < 1e-12, "{fixed:?}");
        assert!((fixed.simulated[1] - 36e-3).abs() < 1e-12, "{fixed:?}");
        assert!(fixed.cropped);
        assert_eq!(fixed.indenter_scale, drawn.indenter_scale);
    }
    let thick = family
        .with_gel([40e-3, 30e-3, 6e-3])
        .unwrap()
        .draw(5, 0, 4e-3);
    assert!(
        (thick.simulated[0] - 4e-3 * 40.0 / 6.0).abs() < 1e-12,
        "{thick:?}"
    );
    assert!((thick.simulated[1] - 20e-3).abs() < 1e-12, "{thick:?}");
    assert!(!thick.cropped);
    let err = family.with_gel([18e-3, 14e-3, 0.8e-3]).unwrap_err();
    assert!(
        err.contains("thickness 0.8 mm") && err.contains("1 to 6 mm"),
        "{err}"
    );
    let err = family.with_gel([50e-3, 14e-3, 2e-3]).unwrap_err();
    assert!(
        err.contains("side x 50 mm") && err.contains("12 to 40 mm"),
        "{err}"
    );
}

/// Shards of a selection (held-out presses only) get equal counts, and together they are
/// the selection, each press once: a many-core machine or a batch array keeps every worker
/// busy (by index modulo N, 56 held-out presses of 300 fell 0 to 8 per shard of 16).
#[test]
fn shards_of_a_selection_are_balanced_and_cover_it() {
    let families: Vec<String> = vec!["sphere".into(), "ridges".into(), "box".into()];
    let config = |shard: (usize, usize)| GenConfig {
        samples: 60,
        shard,
        families: families.clone(),
        held_out_only: true,
        ..GenConfig::default()
    };
    let all = datagen::list(&config((0, 1))).unwrap();
    assert!(
        all.len() > 8 && all.len() < 60,
        "{} held-out presses",
        all.len()
    );
    let mut union = Vec::new();
    let mut counts = Vec::new();
    for k in 0..7 {
        let lines = datagen::list(&config((k, 7))).unwrap();
        counts.push(lines.len());
        union.extend(lines);
    }
    let (lo, hi) = (counts.iter().min().unwrap(), counts.iter().max().unwrap());
    assert!(hi - lo <= 1, "{counts:?}");
    union.sort();
    let mut all = all;
    all.sort();
    assert_eq!(union, all);
}

#[test]
fn held_out_only_sets_hold_the_full_sets_presses_and_eval_rom_scores_them() {
    let out = scratch("heldout");
    let families: Vec<String> = vec!["sphere".into(), "ridges".into()];
    let config = GenConfig {
        out: out.clone(),
        samples: 6,
        coarse_dx: 2e-3,
        fine_dx: 2e-3,
        pitch: 3e-4,
        families: families.clone(),
        held_out_only: true,
        ..GenConfig::default()
    };
    datagen::generate(&config, |_| {}).unwrap();
    // Exactly the held-out presses of the full set of the same seed.
    let mut expected = Vec::new();
    for i in 0..6u64 {
        let p = datagen::draw_press(
            1,
            i,
            &mut datagen::MeshLibrary::default(),
            &families,
            [0.03, 0.03, 0.004],
        )
        .unwrap();
        let written = out.join(format!("sample-{i:06}.npy")).is_file();
        assert_eq!(written, p.family == "ridges", "sample {i}: {}", p.family);
        if written {
            expected.push(i);
        }
    }
    assert!(!expected.is_empty(), "no ridges among six draws");
    // The coarse and the reference spacing are equal here, so coarse matches the
    // reference exactly: the evaluation compares the right channels.
    let options = tacrom_tools::bench::heldout::EvalOptions {
        data: vec![out.clone()],
        models: vec![model_dir()],
        all: false,
        refined: true,
        compare: Some(out.clone()),
        out: out.join("report"),
    };
    let r = tacrom_tools::bench::heldout::run(&options).unwrap();
    assert_eq!(r.samples, expected.len());
    let row = |l: &str| r.rows.iter().find(|m| m.label == l).unwrap();
    assert_eq!(row("coarse").mae, 0.0);
    assert_eq!(row("coarse").region_mae, 0.0);
    // The footprint MAE averages the per-press figures, each over the reference's
    // footprint only: at least the MAE over the whole field of view where anything differs.
    for m in &r.rows {
        assert_eq!(m.per_press.len(), r.samples);
        let mean = m.per_press.iter().map(|e| e[1]).sum::<f64>() / r.samples as f64;
        assert!(
            (mean - m.region_mae).abs() <= 1e-12 * mean.max(1e-9),
            "{m:?}"
        );
    }
    assert!(
        row("rigid").region_mae > row("rigid").mae,
        "{:?}",
        row("rigid")
    );
    let presses = std::fs::read_to_string(out.join("report/presses.csv")).unwrap();
    assert_eq!(
        presses.lines().count(),
        1 + r.rows.len() * r.samples,
        "{presses}"
    );
    // The data set compared with itself.
    assert_eq!(row("reference-2.0mm").mae, 0.0);
    assert!((row("coarse").ssim - 1.0).abs() < 1e-9);
    assert!(row("rigid").mae > 1e-7, "rigid MAE {}", row("rigid").mae);
    for l in ["rom", "rom-norefine", "rom-refined"] {
        let m = row(l);
        assert!(
            m.mae.is_finite() && m.rmse >= m.mae && m.ssim <= 1.0,
            "{l}: {m:?}"
        );
    }
    // The shipped manifest leaves the refinement off; `refined` adds a row with it on.
    assert_eq!(row("rom").steps, 0.0);
    assert!(out.join("report/report.md").is_file());
    // A data set on another lattice is refused with the folder in the message.
    let other = scratch("heldout-lattice");
    datagen::generate(
        &GenConfig {
            out: other.clone(),
            samples: 1,
            pitch: 1e-3,
            coarse_dx: 2e-3,
            fine_dx: 2e-3,
            families: vec!["sphere".into()],
            ..GenConfig::default()
        },
        |_| {},
    )
    .unwrap();
    // eval-rom's error on every sample of the data set in `dir`.
    let refused = |dir: &Path| {
        tacrom_tools::bench::heldout::run(&tacrom_tools::bench::heldout::EvalOptions {
            data: vec![dir.to_path_buf()],
            all: true,
            compare: None,
            ..options.clone()
        })
        .unwrap_err()
        .to_string()
    };
    let e = refused(&other);
    assert!(
        e.contains("lattice") && e.contains("heldout-lattice"),
        "{e}"
    );
    // So is a data set whose coarse channel another solver wrote (the model reads the
    // relaxation's), with both solvers and the folder named.
    let linear = scratch("heldout-linear");
    datagen::generate(
        &GenConfig {
            out: linear.clone(),
            samples: 1,
            coarse_solver: tacrom::mpm::Solver::Linear,
            held_out_only: false,
            ..config.clone()
        },
        |_| {},
    )
    .unwrap();
    let e = refused(&linear);
    assert!(
        e.contains("\"linear\"") && e.contains("\"relaxation\"") && e.contains("heldout-linear"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_dir_all(&other);
    let _ = std::fs::remove_dir_all(&linear);
}

/// `--refresh-coarse` solves the coarse presses of a data set again and rewrites only their
/// coarse channel and report: a data set whose coarse channel was spoiled gets back the
/// bits a fresh run writes, its reference channel and report untouched, and a sample not
/// on disk is not written.
#[test]
fn a_refresh_rewrites_the_coarse_channel_and_keeps_the_reference() {
    let out = scratch("refresh");
    let config = GenConfig {
        out: out.clone(),
        samples: 2,
        coarse_dx: 2e-3,
        fine_dx: 2e-3,
        pitch: 5e-4,
        families: vec!["sphere".into()],
        ..GenConfig::default()
    };
    datagen::generate(&config, |_| {}).unwrap();
    let (npy, json) = (
        out.join("sample-000000.npy"),
        out.join("sample-000000.json"),
    );
    let (shape, fresh) = datagen::read_npy(&npy).unwrap();
    let fresh_meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let n = fresh.len() / 3;
    assert!(fresh[..n].iter().any(|&v| v != 0.0), "an untouched gel");
    // Spoil the coarse channel and report, and mark the reference.
    let mut spoiled = fresh.clone();
    spoiled[..n].iter_mut().for_each(|v| *v = 0.0);
    spoiled[2 * n] += 1e-3;
    datagen::write_npy(&npy, &shape, &spoiled).unwrap();
    let mut meta = fresh_meta.clone();
    meta["coarse"]["force"] = serde_json::json!([0.0, 0.0, 0.0]);
    meta["reference"]["iterations"] = serde_json::json!(7);
    std::fs::write(&json, serde_json::to_string(&meta).unwrap()).unwrap();
    std::fs::remove_file(out.join("sample-000001.json")).unwrap();
    datagen::generate(
        &GenConfig {
            refresh_coarse: true,
            ..config
        },
        |_| {},
    )
    .unwrap();
    let (_, refreshed) = datagen::read_npy(&npy).unwrap();
    assert_eq!(refreshed[..n], fresh[..n], "the coarse channel");
    assert_eq!(refreshed[n..2 * n], fresh[n..2 * n], "the penetration");
    assert_eq!(
        refreshed[2 * n..],
        spoiled[2 * n..],
        "the reference was rewritten"
    );
    let after: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(after["coarse"]["force"], fresh_meta["coarse"]["force"]);
    assert_eq!(after["reference"]["iterations"], 7);
    assert!(!out.join("sample-000001.json").is_file());
    let _ = std::fs::remove_dir_all(&out);
}
