//! `physics="rom"` through the sensor: the default model is found, its output is a sensible
//! depth image, and a gel other than the model's is refused at load with a clear message.

use std::sync::Arc;

use nalgebra::Isometry3;
use tacrom::config::{
    Config, RawConfig, ATTR_FRICTION, ATTR_MATERIAL, ATTR_MODEL, ATTR_OUTPUTS, ATTR_PHYSICS,
    ATTR_POISSON, ATTR_RESOLUTION, ATTR_SIZE, ATTR_SOLVER, ATTR_TOLERANCE, ATTR_YOUNG,
};
use tacrom::geometry::{Placed, Sphere};
use tacrom::mpm::Solver;
use tacrom::sensor::TactileSensor;

#[test]
fn rom_is_the_default_physics_and_presses_a_sphere() {
    let config = Config::from_raw(
        "touch",
        &RawConfig::default().with(ATTR_RESOLUTION, "160 120"),
    )
    .unwrap();
    assert_eq!(config.physics.name(), "rom");
    presses_a_sphere(config);
}

/// A 5 mm sphere pressed 0.5 mm into a 160 x 120 rom sensor of `config`: the model runs,
/// the image is finite and non-negative, and its deepest pixel lies within 50 um of the
/// sphere's deepest point (the depth rule bounds it by that point; the gel reaches it to
/// within a tenth of the press).
fn presses_a_sphere(config: Config) {
    let mut sensor = TactileSensor::new(config).unwrap();
    let placed = [Placed {
        shape: Arc::new(Sphere::new(0.005)),
        pose: Isometry3::translation(0.0, 0.0, 0.005 - 0.5e-3),
    }];
    let mut out = vec![0.0; 160 * 120];
    let eval = sensor.evaluate(&placed, &mut out);
    assert!(eval.rom.is_some(), "{:?}", eval.warnings);
    let peak = out.iter().cloned().fold(0.0, f64::max);
    assert!((peak - 0.5e-3).abs() < 0.05e-3, "peak {peak}");
    assert!(out.iter().all(|d| d.is_finite() && *d >= 0.0));
}

/// The shipped model serves any Young's modulus: the coarse depth it reads does not depend
/// on it (the gel's equilibrium under imposed poses is homogeneous in the moduli), so a
/// gel 20 times softer or stiffer gives the same image bit for bit and the force scaled
/// by the ratio (to round-off).
#[test]
fn rom_serves_any_young_modulus_with_the_force_scaled() {
    let run = |young: &str| {
        let raw = RawConfig::default()
            .with(ATTR_RESOLUTION, "80 60")
            .with(ATTR_OUTPUTS, "depth force")
            .with(ATTR_YOUNG, young);
        let config = Config::from_raw("touch", &raw).unwrap();
        let mut out = vec![0.0; config.sensordata_len()];
        let mut sensor = TactileSensor::new(config).unwrap();
        let ball: Arc<dyn tacrom::geometry::Sdf> = Arc::new(Sphere::new(0.005));
        for (x, d) in [(0.0, 0.3e-3), (0.5e-3, 0.6e-3)] {
            let placed = [Placed {
                shape: ball.clone(),
                pose: Isometry3::translation(x, 0.0, 0.005 - d),
            }];
            let eval = sensor.evaluate(&placed, &mut out);
            assert!(eval.rom.is_some(), "E = {young}: {:?}", eval.warnings);
        }
        out.truncate(80 * 60);
        (out, sensor.force())
    };
    let (image, force) = run("1.19e5");
    assert!(force.z > 0.01, "{force:?}");
    for (young, k) in [("5950", 0.05), ("2.38e6", 20.0)] {
        let (other, f) = run(young);
        assert_eq!(other, image, "E = {young} Pa: the image differs");
        assert!(
            (f / k - force).norm() <= 1e-9 * force.norm(),
            "E = {young} Pa: force {f:?}, expected {:?}",
            force * k
        );
    }
}

/// The shipped model serves the gel materials it was validated on (manifest `materials`:
/// Poisson's ratio 0.3 to 0.49, friction 0 to 1; `make gen-data-linear-material` and
/// `make gen-data-linear-049`): a gel at either corner of those ranges presses a sphere
/// with the image on the indenter, and one just outside is refused at load, naming the
/// sensor, the attribute and both values.
#[test]
fn rom_serves_the_materials_it_was_validated_on_and_refuses_others() {
    for (poisson, friction) in [("0.3", "0"), ("0.49", "1")] {
        let raw = RawConfig::default()
            .with(ATTR_RESOLUTION, "80 60")
            .with(ATTR_POISSON, poisson)
            .with(ATTR_FRICTION, friction);
        let mut sensor = TactileSensor::new(Config::from_raw("touch", &raw).unwrap()).unwrap();
        let placed = [Placed {
            shape: Arc::new(Sphere::new(0.005)),
            pose: Isometry3::translation(0.0, 0.0, 0.005 - 0.5e-3),
        }];
        let mut out = vec![0.0; 80 * 60];
        let eval = sensor.evaluate(&placed, &mut out);
        assert!(
            eval.rom.is_some(),
            "{poisson}, {friction}: {:?}",
            eval.warnings
        );
        let peak = out.iter().cloned().fold(0.0, f64::max);
        assert!(
            (peak - 0.5e-3).abs() < 0.05e-3,
            "{poisson}, {friction}: peak {peak}"
        );
    }
    let raw = RawConfig::default()
        .with(ATTR_PHYSICS, "rom")
        .with(ATTR_POISSON, "0.495");
    let e = load_error(raw);
    assert!(
        e.contains("'touch'")
            && e.contains("'model'")
            && e.contains("Poisson's ratio in [0.3, 0.49]")
            && e.contains("Poisson's ratio 0.495"),
        "{e}"
    );
}

/// Force of a frictionless sphere of radius `r` pressed to each of `depths` in one
/// sequence, by a sensor of `physics` (and `solver`, if named) on a frictionless gel
/// reporting only the force.
fn sphere_forces(physics: &str, solver: Option<&str>, r: f64, depths: &[f64]) -> Vec<f64> {
    let mut raw = RawConfig::default()
        .with(ATTR_PHYSICS, physics)
        .with(ATTR_FRICTION, "0");
    if let Some(solver) = solver {
        raw = raw.with(ATTR_SOLVER, solver);
    }
    sphere_forces_of(raw, r, depths)
}

/// [`sphere_forces`] by a sensor of the attributes `raw` (and the force as its only output).
fn sphere_forces_of(raw: RawConfig, r: f64, depths: &[f64]) -> Vec<f64> {
    let raw = raw
        .with(ATTR_OUTPUTS, "force")
        .with(ATTR_RESOLUTION, "32 24");
    let config = Config::from_raw("touch", &raw).unwrap();
    let mut out = vec![0.0; config.sensordata_len()];
    let mut sensor = TactileSensor::new(config).unwrap();
    let ball: Arc<dyn tacrom::geometry::Sdf> = Arc::new(Sphere::new(r));
    depths
        .iter()
        .map(|&d| {
            let placed = [Placed {
                shape: ball.clone(),
                pose: Isometry3::translation(0.0, 0.0, r - d),
            }];
            sensor.evaluate(&placed, &mut out);
            out[2]
        })
        .collect()
}

/// rom's normal force is the coarse gel's times the decoded surface's displaced volume over
/// the coarse one's and the manifest's volume factor (on a bonded layer the force is close
/// to proportional to the displaced volume, whatever the indenter). Spheres of radius 2
/// and 5 mm pressed 0.1 to 0.5 mm, a force-only sensor (which decodes for the force), on
/// gels of Poisson's ratio 0.43 (the trained one), 0.3 and 0.48: against Hertz on the
/// bonded layer (Dimitriadis et al. 2002), rom's mean error must be below that of the
/// coarse gel it decodes (the relaxation, named: a coarse sensor that names no solver may
/// solve a frame by another) and at most 10 % for each radius at 0.43, 12 % at 0.3 and
/// 0.48 (measured in the message: 5.6 to 11.5 %). The model is the relaxation's
/// (`model="rom-default"`, so its gel keeps the fallback); the
/// default rom on the linear gel has its own test below (the linear coarse gel is within
/// 4 to 10 % of Hertz itself on these spheres, so "closer than coarse" is not its claim).
/// At 0.48 the frames of small contacts, which the linear solver takes over, came out
/// 0.48 to 0.82 of Hertz while Newton's discretisation put the whole volume term on the
/// cells (rom's mean error 31 % for the 2 mm sphere; now 9.7 %).
#[test]
fn rom_force_follows_the_decoded_surface_closer_to_hertz_than_coarse() {
    let depths = [0.1e-3, 0.2e-3, 0.3e-3, 0.5e-3];
    let (e, h) = (1.19e5, 0.004);
    let model = "rom-default";
    for (nu, bound) in [(0.43, 0.10), (0.3, 0.12), (0.48, 0.12)] {
        for r in [2e-3f64, 5e-3] {
            let gel = |physics: &str| {
                RawConfig::default()
                    .with(ATTR_PHYSICS, physics)
                    .with(ATTR_FRICTION, "0")
                    .with(ATTR_POISSON, &nu.to_string())
            };
            let rom = sphere_forces_of(gel("rom").with(ATTR_MODEL, model), r, &depths);
            let coarse = gel("coarse").with(ATTR_SOLVER, "relaxation");
            let coarse = sphere_forces_of(coarse, r, &depths);
            let err = |f: &[f64]| {
                f.iter()
                    .zip(&depths)
                    .map(|(&f, &d)| {
                        (f / tacrom::mpm::hertz::hertz_bonded(e, nu, r, d, h) - 1.0).abs()
                    })
                    .sum::<f64>()
                    / depths.len() as f64
            };
            let (er, ec) = (err(&rom), err(&coarse));
            eprintln!(
                "Poisson {nu}, R {} mm: mean force error against Hertz: rom {:.1} %, coarse {:.1} % (rom {rom:?} N, coarse {coarse:?} N)",
                r * 1e3,
                er * 100.0,
                ec * 100.0
            );
            assert!(
                er < ec && er <= bound,
                "Poisson {nu}, R {r}: rom {er:.3}, coarse {ec:.3}"
            );
        }
    }
}

/// A contact the relaxation misses (a 0.5 mm sphere pressed 0.3 mm between the coarse
/// gel's top particles) is carried by rom. Its default runs on the linear gel, whose small
/// contacts follow Hertz (within 10 %: measured 1.04 with the model's force factor); rom
/// on the relaxation's model (`model="rom-default"`, no solver) solves such a frame
/// by the linear solver and reports its force (the decoded surface's volume factor is
/// fitted to the relaxation's surface; measured 1.01 of Hertz), where the relaxation
/// alone reports none.
#[test]
fn rom_carries_a_contact_the_relaxation_misses() {
    let (r, d) = (0.5e-3, 0.3e-3);
    let hertz = tacrom::mpm::hertz::hertz_bonded(1.19e5, 0.43, r, d, 0.004);
    let rom = sphere_forces("rom", None, r, &[d])[0];
    assert!(
        (rom / hertz - 1.0).abs() < 0.1,
        "the default rom: {rom} N against Hertz's {hertz}"
    );
    let named = RawConfig::default()
        .with(ATTR_PHYSICS, "rom")
        .with(ATTR_FRICTION, "0")
        .with(ATTR_MODEL, "rom-default");
    let fallback = sphere_forces_of(named, r, &[d])[0];
    let linear = sphere_forces("coarse", Some("linear"), r, &[d])[0];
    let relaxation = sphere_forces("rom", Some("relaxation"), r, &[d])[0];
    assert_eq!(relaxation, 0.0, "the relaxation alone misses it");
    assert!(
        (fallback - linear).abs() <= 1e-9 * linear,
        "{fallback} against {linear}"
    );
    assert!(
        (fallback / hertz - 1.0).abs() < 0.1,
        "{fallback} N against Hertz's {hertz}"
    );
}

/// rom's pressure image on the relaxation's model (`models/rom-default`, which carries a
/// pressure head) is the head's field, spread as the gel spreads its loads: it integrates
/// to the reported normal force (the contact lies inside the image; to round-off), is
/// compressive, peaks under the sphere, and is not the coarse gel's pressure scaled
/// (which a model without a head reports).
#[test]
fn rom_pressure_is_the_heads_and_integrates_to_the_force() {
    let (w, h) = (96, 72);
    let raw = RawConfig::default()
        .with(ATTR_SOLVER, "relaxation")
        .with(ATTR_OUTPUTS, "force pressure")
        .with(ATTR_RESOLUTION, &format!("{w} {h}"));
    let config = Config::from_raw("touch", &raw).unwrap();
    let mut out = vec![0.0; config.sensordata_len()];
    let mut sensor = TactileSensor::new(config).unwrap();
    let coarse_raw = RawConfig::default()
        .with(ATTR_PHYSICS, "coarse")
        .with(ATTR_SOLVER, "relaxation")
        .with(ATTR_OUTPUTS, "force pressure")
        .with(ATTR_RESOLUTION, &format!("{w} {h}"));
    let coarse_config = Config::from_raw("touch", &coarse_raw).unwrap();
    let mut coarse_out = vec![0.0; coarse_config.sensordata_len()];
    let mut coarse = TactileSensor::new(coarse_config).unwrap();
    let pixel = (0.024 / w as f64) * (0.018 / h as f64);
    for d in [0.2e-3, 0.5e-3] {
        let placed = [Placed {
            shape: Arc::new(Sphere::new(0.005)),
            pose: Isometry3::translation(0.0, 0.0, 0.005 - d),
        }];
        let eval = sensor.evaluate(&placed, &mut out);
        assert!(eval.rom.is_some(), "{:?}", eval.warnings);
        coarse.evaluate(&placed, &mut coarse_out);
        let (fz, p) = (out[2], &out[3..]);
        let integral: f64 = p.iter().sum::<f64>() * pixel;
        assert!(
            fz > 0.0 && (integral - fz).abs() <= 1e-9 * fz,
            "{integral} against {fz} N"
        );
        assert!(p.iter().all(|v| v.is_finite() && *v >= 0.0));
        let peak = (0..p.len()).max_by(|&a, &b| p[a].total_cmp(&p[b])).unwrap();
        let (r, c) = (peak / w, peak % w);
        assert!(
            (r as f64 - h as f64 / 2.0).abs() <= 4.0 && (c as f64 - w as f64 / 2.0).abs() <= 4.0,
            "peak at ({r}, {c})"
        );
        let k = fz / coarse_out[2];
        let scaled_off = p
            .iter()
            .zip(&coarse_out[3..])
            .map(|(a, b)| (a - k * b).abs())
            .fold(0.0, f64::max);
        assert!(
            scaled_off > 0.05 * p[peak],
            "d = {d}: the coarse pressure scaled ({scaled_off} Pa off at most)"
        );
    }
}

/// The gel pushes back with the force rom reports: its wrenches' normal force sums to the
/// `force` output.
#[test]
fn rom_wrenches_carry_the_reported_force() {
    let raw = RawConfig::default()
        .with(ATTR_OUTPUTS, "depth force")
        .with(ATTR_RESOLUTION, "32 24");
    let config = Config::from_raw("touch", &raw).unwrap();
    let mut out = vec![0.0; config.sensordata_len()];
    let mut sensor = TactileSensor::new(config).unwrap();
    let placed = [Placed {
        shape: Arc::new(Sphere::new(0.002)),
        pose: Isometry3::translation(1e-3, 0.0, 0.002 - 0.3e-3),
    }];
    sensor.evaluate(&placed, &mut out);
    let f = sensor.force();
    let w: f64 = sensor.wrenches(&placed).iter().map(|w| w.force.z).sum();
    assert!(
        f.z > 0.0 && (w - f.z).abs() <= 1e-9 * f.z,
        "wrenches {w}, force {f:?}"
    );
}

#[test]
fn a_gel_other_than_the_models_is_refused() {
    // 50 mm across: outside the family the model serves.
    let raw = RawConfig::default()
        .with(ATTR_PHYSICS, "rom")
        .with(ATTR_SIZE, "0.05 0.03 0.004");
    let e = TactileSensor::new(Config::from_raw("touch", &raw).unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("'touch'") && e.contains("'model'") && e.contains("gel size"),
        "{e}"
    );
    // Regression: the refusal led with `model`, an attribute the configuration never set;
    // the attribute whose value the model does not serve leads now.
    assert!(e.contains("'touch': attribute 'size'"), "{e}");
    let raw = RawConfig::default()
        .with(ATTR_PHYSICS, "rom")
        .with(tacrom::config::ATTR_POISSON, "0");
    let e = TactileSensor::new(Config::from_raw("touch", &raw).unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("attribute 'poisson'") && e.contains("in [0.3, 0.49]"),
        "{e}"
    );
    let raw = RawConfig::default().with(ATTR_MODEL, "/no/such/model");
    let e = TactileSensor::new(Config::from_raw("touch", &raw).unwrap())
        .unwrap_err()
        .to_string();
    assert!(e.contains("/no/such/model"), "{e}");
}

/// A copy of the shipped model in a scratch directory, its manifest edited by `edit`.
fn model_with(name: &str, edit: impl Fn(&mut serde_json::Value)) -> std::path::PathBuf {
    let src = tacrom::rom::default_model_dir().expect("shipped model");
    let dir = std::env::temp_dir().join(format!("tacrom-recipe-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for f in [
        "encoder.onnx",
        "decoder.onnx",
        "decoder_jacobian.onnx",
        "pressure.onnx",
    ] {
        std::fs::copy(src.join(f), dir.join(f)).unwrap();
    }
    let text = std::fs::read_to_string(src.join("manifest.json")).unwrap();
    let mut m: serde_json::Value = serde_json::from_str(&text).unwrap();
    edit(&mut m);
    std::fs::write(dir.join("manifest.json"), m.to_string()).unwrap();
    dir
}

fn load_error(raw: RawConfig) -> String {
    TactileSensor::new(Config::from_raw("touch", &raw).unwrap())
        .unwrap_err()
        .to_string()
}

/// The decoder reads the coarse solve as its input: a sensor whose coarse solve differs
/// from the one the model was trained on (grid, material, solver, a looser tolerance) is
/// refused at load, and the message names the attribute and both values.
#[test]
fn a_coarse_solve_other_than_the_models_recipe_is_refused() {
    let recipe = |key: &'static str, value: serde_json::Value| {
        move |m: &mut serde_json::Value| m["recipe"][key] = value.clone()
    };
    // The model was trained on Neo-Hookean coarse solves; the sensor runs corotated.
    let dir = model_with("material", recipe("material", "neohookean".into()));
    let e = load_error(RawConfig::default().with(ATTR_MODEL, dir.to_str().unwrap()));
    assert!(
        e.contains("'touch'") && e.contains("'model'"),
        "names the sensor and attribute: {e}"
    );
    assert!(e.contains("neohookean") && e.contains("corotated"), "{e}");
    // Another solver.
    let dir = model_with("solver", recipe("solver", "newton".into()));
    let e = load_error(RawConfig::default().with(ATTR_MODEL, dir.to_str().unwrap()));
    assert!(
        e.contains("newton") && e.contains(tacrom::mpm::Solver::Relaxation.name()),
        "{e}"
    );
    // The shipped model (relaxation) under the Newton solver.
    let e = load_error(RawConfig::default().with(ATTR_SOLVER, "newton"));
    assert!(e.contains("newton") && e.contains("relaxation"), "{e}");
    // The shipped model through the material attribute.
    let e = load_error(RawConfig::default().with(ATTR_MATERIAL, "neohookean"));
    assert!(e.contains("neohookean") && e.contains("corotated"), "{e}");
    // A tolerance looser than the model accepts.
    let e = load_error(RawConfig::default().with(ATTR_TOLERANCE, "0.05"));
    assert!(e.contains("5e-2") && e.contains("1e-2"), "{e}");
    // A manifest without a recipe.
    let dir = model_with("none", |m| {
        m.as_object_mut().unwrap().remove("recipe");
    });
    let e = load_error(RawConfig::default().with(ATTR_MODEL, dir.to_str().unwrap()));
    assert!(e.contains("recipe"), "{e}");
}

/// `solver="linear"` gets the shipped models trained on that solver's coarse solve
/// (`models/rom-linear-narrow` on gels of 3.5 mm and more, `models/rom-linear` on thinner
/// ones; their recipes name the solver: a model of another solver is refused, as the
/// default model is when named explicitly), presses a sphere with each, and serves the
/// materials their manifests were validated on.
#[test]
fn the_linear_solver_gets_its_own_shipped_model() {
    use tacrom::rom::{shipped_model, shipped_model_dir, LINEAR_MODEL, LINEAR_NARROW_MODEL};
    assert_eq!(shipped_model("linear", 4e-3), LINEAR_NARROW_MODEL);
    assert_eq!(shipped_model("linear", 3.5e-3), LINEAR_NARROW_MODEL);
    assert_eq!(shipped_model("linear", 6e-3), LINEAR_NARROW_MODEL);
    assert_eq!(shipped_model("linear", 3.4e-3), LINEAR_MODEL);
    assert_eq!(shipped_model("linear", 1.41e-3), LINEAR_MODEL);
    assert_eq!(
        shipped_model("relaxation", 4e-3),
        tacrom::rom::DEFAULT_MODEL
    );
    // rom's default: the linear gel, without the per-frame fallback it does not need; a
    // model of one's own keeps the gel's automatic rule (its recipe names its solver).
    let default = Config::from_raw("touch", &RawConfig::default()).unwrap();
    let choice = default.choice(default.dx.unwrap());
    assert_eq!((choice.solver, choice.fallback), (Solver::Linear, false));
    let choice = |model: &str| {
        let c = Config::from_raw("touch", &RawConfig::default().with(ATTR_MODEL, model)).unwrap();
        let choice = c.choice(c.dx.unwrap());
        (choice.solver, choice.fallback)
    };
    assert_eq!(choice("models/rom-default"), (Solver::Relaxation, true));
    // The shipped models by name: the default's, its encoder with a narrower decoder (on
    // the same gel), and the relaxation's as rom ran before.
    assert_eq!(choice("rom-linear"), (Solver::Linear, false));
    assert_eq!(choice("rom-linear-narrow"), (Solver::Linear, false));
    assert_eq!(choice("rom-default"), (Solver::Relaxation, true));
    for name in ["rom-linear", "rom-linear-narrow", "rom-default"] {
        let raw = RawConfig::default()
            .with(ATTR_RESOLUTION, "32 24")
            .with(ATTR_MODEL, name);
        presses_a_sphere(Config::from_raw("touch", &raw).unwrap());
    }
    let raw = RawConfig::default()
        .with(ATTR_RESOLUTION, "160 120")
        .with(ATTR_SOLVER, "linear");
    presses_a_sphere(Config::from_raw("touch", &raw).unwrap());
    for name in [LINEAR_MODEL, LINEAR_NARROW_MODEL] {
        let text = std::fs::read_to_string(shipped_model_dir(name).unwrap().join("manifest.json"));
        let manifest: serde_json::Value = serde_json::from_str(&text.unwrap()).unwrap();
        assert_eq!(manifest["recipe"]["solver"], "linear", "{name}");
    }
    let default = tacrom::rom::default_model_dir().unwrap();
    let e = load_error(raw.clone().with(ATTR_MODEL, default.to_str().unwrap()));
    assert!(e.contains("linear") && e.contains("relaxation"), "{e}");
    // Its manifest's validated materials: Poisson's ratio 0.3 to 0.49 and friction 0 to 1
    // (a frictionless gel for a cheap grasp), and not a Poisson's ratio beyond.
    for (key, value) in [
        (ATTR_FRICTION, "0"),
        (ATTR_FRICTION, "1"),
        (ATTR_POISSON, "0.3"),
        (ATTR_POISSON, "0.49"),
    ] {
        let raw = raw.clone().with(key, value);
        assert!(TactileSensor::new(Config::from_raw("touch", &raw).unwrap()).is_ok());
    }
    let e = load_error(raw.with(ATTR_POISSON, "0.495"));
    assert!(e.contains("0.495") && e.contains("[0.3, 0.49]"), "{e}");
}

/// rom on the linear solver (`models/rom-linear`) reports the force of its decoded surface
/// with the volume factor of the gel's Poisson's ratio (manifest `force.by_poisson`): for
/// frictionless spheres of radius 2 and 5 mm pressed 0.1 to 0.5 mm on gels of Poisson's
/// ratio 0.3, 0.43, 0.48 and 0.49 (the range it serves) and friction 0 and 1, its mean
/// error against Hertz on the bonded layer is at most 12 % for each (measured 0.5 to 7.6 %
/// with the factor fitted to the model's decoded volumes; with the factor from the
/// reference's volumes up to 11.6 %, at 0.48). One factor for every Poisson's ratio left
/// the force 22 % low at 0.48 on the gel before its volume term was mended.
#[test]
fn rom_linear_force_follows_hertz_at_every_poisson_it_serves() {
    let depths = [0.1e-3, 0.2e-3, 0.3e-3, 0.5e-3];
    for nu in [0.3, 0.43, 0.48, 0.49] {
        for friction in ["0", "1"] {
            for r in [2e-3f64, 5e-3] {
                let raw = RawConfig::default()
                    .with(ATTR_PHYSICS, "rom")
                    .with(ATTR_SOLVER, "linear")
                    .with(ATTR_FRICTION, friction)
                    .with(ATTR_POISSON, &nu.to_string());
                let ratios: Vec<f64> = sphere_forces_of(raw, r, &depths)
                    .iter()
                    .zip(&depths)
                    .map(|(f, &d)| f / tacrom::mpm::hertz::hertz_bonded(1.19e5, nu, r, d, 0.004))
                    .collect();
                let err = ratios.iter().map(|q| (q - 1.0).abs()).sum::<f64>() / ratios.len() as f64;
                eprintln!(
                    "Poisson {nu}, friction {friction}, R {} mm: force / Hertz {ratios:.3?}, mean error {:.1} %",
                    r * 1e3,
                    err * 100.0
                );
                assert!(
                    err <= 0.12,
                    "Poisson {nu}, friction {friction}, R {r}: {ratios:?}"
                );
            }
        }
    }
}

/// The materials a model serves: the range of each material input it has, else the range
/// its manifest was validated on (`materials`), else the value it was trained for. A model
/// conditioned on Poisson's ratio alone (its friction input held at 0 by a range of one
/// value) serves the friction of its `materials`, and the Poisson's ratios of its input.
#[test]
fn a_model_serves_its_inputs_ranges_then_its_validated_ones() {
    let served =
        |name: &str, edit: &dyn Fn(&mut serde_json::Value), poisson: f64, friction: f64| {
            let dir = model_with(name, edit);
            let manifest = tacrom::rom::Manifest::load(&dir).unwrap();
            manifest
                .check_gel([0.03, 0.03, 0.004], poisson, friction)
                .map_err(|e| e.to_string())
        };
    let poisson_only = |m: &mut serde_json::Value| {
        m["conditioning"] = serde_json::json!({"poisson": [0.3, 0.48], "friction": [0.5, 0.5]});
        for key in ["encoder_input", "query_features"] {
            m[key] = (m[key].as_u64().unwrap() + 2).into();
        }
        // The graphs' declared inputs (the files are not read here).
        let files = &mut m["files"];
        for (graph, input) in [
            ("encoder", "observation"),
            ("decoder", "query"),
            ("jacobian", "query"),
            ("pressure", "query"),
        ] {
            let shape = &mut files[graph]["inputs"][input];
            shape[1] = (shape[1].as_i64().unwrap() + 2).into();
        }
    };
    let validated = |m: &mut serde_json::Value| {
        m["materials"] = serde_json::json!({"poisson": [0.3, 0.48], "friction": [0.0, 1.0]});
    };
    let poisson_only_validated = |m: &mut serde_json::Value| {
        poisson_only(m);
        validated(m);
    };
    // Its inputs' Poisson range and its validated friction range.
    let ok = |edit: &dyn Fn(&mut serde_json::Value), p, f| served("served-ok", edit, p, f).is_ok();
    assert!(ok(&poisson_only_validated, 0.3, 0.0));
    assert!(ok(&poisson_only_validated, 0.48, 1.0));
    let e = served("served-a", &poisson_only_validated, 0.49, 0.5).unwrap_err();
    assert!(e.contains("in [0.3, 0.48]") && e.contains("0.49"), "{e}");
    // Without `materials`, the friction it was trained for alone.
    let bare = |m: &mut serde_json::Value| {
        poisson_only(m);
        m.as_object_mut().unwrap().remove("materials");
    };
    assert!(ok(&bare, 0.4, 0.5));
    let e = served("served-b", &bare, 0.4, 1.0).unwrap_err();
    assert!(
        e.contains("friction 0.5") && e.contains("friction 1"),
        "{e}"
    );
    // A model without inputs: its validated ranges.
    assert!(ok(&validated, 0.3, 1.0));
    let e = served("served-c", &validated, 0.29, 0.5).unwrap_err();
    assert!(e.contains("in [0.3, 0.48]"), "{e}");
}

/// The shipped models serve their gel's shape at any thickness of the gel family (1 to
/// 6 mm): the coarse grid is the same fraction of the thickness (`dx = 0.35 T`), the
/// model reads lengths in its own units, and the gel's equilibrium scaled with the gel is
/// the press scaled (`a_scaled_press_is_the_press_scaled`). A sphere and its press scaled
/// by a half or a quarter (15 x 15 x 2 and 7.5 x 7.5 x 1 mm) give the default gel's image
/// scaled and its force times the scale squared, to round-off (the images' inverse map
/// stops within a fixed fraction of the gel's thickness, the same in each gel's units).
/// Each linear model is named: the default
/// on the linear gel is the narrow decoder from 3.5 mm and the wide one below
/// ([`tacrom::rom::NARROW_FROM_THICKNESS`]), so the default itself changes model between
/// these thicknesses. A gel
/// outside the family (12 to 40 mm across, 1 to 6 mm thick) that is not the model's shape
/// at a family thickness is refused, naming the size and both.
#[test]
fn rom_serves_its_gel_at_any_thickness_scaled() {
    let run = |(solver, model): (&str, &str), s: f64| {
        let raw = RawConfig::default()
            .with(ATTR_MODEL, model)
            .with(ATTR_RESOLUTION, "80 60")
            .with(ATTR_OUTPUTS, "depth force")
            .with(ATTR_SOLVER, solver)
            .with(
                ATTR_SIZE,
                &format!("{} {} {}", 0.03 * s, 0.03 * s, 0.004 * s),
            )
            .with(
                tacrom::config::ATTR_FOV,
                &format!("{} {}", 0.024 * s, 0.018 * s),
            );
        let config = Config::from_raw("touch", &raw).unwrap();
        assert_eq!(config.dx, Some(0.35 * 0.004 * s));
        let mut out = vec![0.0; config.sensordata_len()];
        let mut sensor = TactileSensor::new(config).unwrap();
        let ball: Arc<dyn tacrom::geometry::Sdf> = Arc::new(Sphere::new(0.005 * s));
        for (x, d) in [(0.0, 0.3e-3), (1.5e-3, 0.6e-3)] {
            let placed = [Placed {
                shape: ball.clone(),
                pose: Isometry3::translation(x * s, -0.5e-3 * s, (0.005 - d) * s),
            }];
            let eval = sensor.evaluate(&placed, &mut out);
            assert!(eval.rom.is_some(), "scale {s}: {:?}", eval.warnings);
            assert!(eval.warnings.is_empty(), "scale {s}: {:?}", eval.warnings);
        }
        out.truncate(80 * 60);
        (out, sensor.force())
    };
    for (solver, model) in [
        ("relaxation", tacrom::rom::DEFAULT_MODEL),
        ("linear", tacrom::rom::LINEAR_MODEL),
        ("linear", tacrom::rom::LINEAR_NARROW_MODEL),
    ] {
        let (image, force) = run((solver, model), 1.0);
        let peak = image.iter().cloned().fold(0.0, f64::max);
        assert!(peak > 0.5e-3, "{solver}: peak {peak}");
        for s in [0.5, 0.25] {
            let (other, f) = run((solver, model), s);
            let worst = image
                .iter()
                .zip(&other)
                .map(|(a, b)| (a - b / s).abs())
                .fold(0.0, f64::max);
            let df = (f / (s * s) - force).norm() / force.norm();
            eprintln!(
                "{model}, scale {s}: worst depth {worst:.2e} m of {peak:.2e}, force {df:.1e}"
            );
            // Scaled by a power of two, the gel, its image's inverse map (its one-step
            // bound a fraction of the thickness) and the model's inputs are the same
            // numbers scaled: the same bits come out (measured), even through the wide
            // decoder's 8 bits, whose activations are quantised on a scale set per run
            // (inputs that differed by nanometres there once moved an activation to the
            // next of its 255 levels: 0.3 um of depth).
            let (depth_bound, force_bound) = (1e-12 * peak, 1e-12);
            assert!(worst <= depth_bound, "{model}, scale {s}: {worst} m");
            assert!(
                df <= force_bound,
                "{model}, scale {s}: force {f:?} against {force:?}"
            );
        }
    }
    for (size, why) in [
        (
            "0.06 0.06 0.008",
            "8 mm: the model's shape, thicker than the family",
        ),
        ("0.05 0.03 0.004", "50 mm across: wider than the family"),
        ("0.02 0.02 0.0008", "0.8 mm: thinner than the family"),
    ] {
        let e = load_error(
            RawConfig::default()
                .with(ATTR_PHYSICS, "rom")
                .with(ATTR_SIZE, size),
        );
        assert!(
            e.contains("'touch': attribute 'size'")
                && e.contains("0.012 to 0.04 m across and 0.001 to 0.006 m thick")
                && e.contains("7.5 x 7.5 thicknesses"),
            "{why}: {e}"
        );
    }
}

/// The default `rom` on gels of the family other than its own shape: the encoder reads a
/// window of the model's lattice over the contact. A 2 mm sphere pressed 0.1 mm into a
/// 12 x 12 x 1 mm gel (Poisson 0.45), the gel 12 thicknesses across against the model's
/// 7.5: against the relaxation at `T / 8` (0.125 mm; 0.23 um from the finest solve at
/// `0.075 T` on this press, `docs/rom.md`), rom's depth error is at most half its coarse
/// gel's (measured 0.68 against 2.79 um against the finest solve) and its force within 5 %
/// where the coarse gel's is 12 % off. A GelSight Mini-sized gel (20.9 x 16.2 x 1.41 mm)
/// loads and presses a sphere, its image peak at the sphere's deepest point within a
/// tenth of the press.
#[test]
fn rom_serves_the_gel_family_through_a_window_over_the_contact() {
    use tacrom::config::ATTR_FOV;
    use tacrom::geometry::PixelGrid;
    let size = [0.012, 0.012, 0.001];
    let (r, d, x) = (2e-3, 0.1e-3, 0.4e-3);
    let ball: Arc<dyn tacrom::geometry::Sdf> = Arc::new(Sphere::new(r));
    let placed = [Placed {
        shape: ball.clone(),
        pose: Isometry3::translation(x, 0.0, r - d),
    }];
    let grid = PixelGrid {
        width: 96,
        height: 96,
        fov_x: 0.006,
        fov_y: 0.006,
    };
    let (reference, reference_force) = fine_reference(size, 0.45, None, &placed, &grid);
    let run = |physics: &str| {
        let raw = RawConfig::default()
            .with(ATTR_PHYSICS, physics)
            .with(ATTR_SOLVER, "linear")
            .with(ATTR_POISSON, "0.45")
            .with(ATTR_SIZE, "0.012 0.012 0.001")
            .with(ATTR_FOV, "0.006 0.006")
            .with(ATTR_RESOLUTION, "96 96")
            .with(ATTR_OUTPUTS, "depth force");
        let config = Config::from_raw("touch", &raw).unwrap();
        assert_eq!(config.dx, Some(0.35e-3), "{physics}");
        against_reference(config, &placed, d, &reference, reference_force)
    };
    let (coarse, coarse_force) = run("coarse");
    let (rom, rom_force) = run("rom");
    eprintln!(
        "against T/8: coarse {:.2} um, force {:+.1} %; rom {:.2} um, force {:+.1} %",
        coarse * 1e6,
        coarse_force * 100.0,
        rom * 1e6,
        rom_force * 100.0
    );
    assert!(rom <= 0.5 * coarse, "rom {rom} against coarse {coarse}");
    assert!(rom_force.abs() <= 0.05, "rom force {rom_force}");

    let raw = RawConfig::default()
        .with(ATTR_SIZE, "0.0209 0.0162 0.00141")
        .with(ATTR_POISSON, "0.47")
        .with(ATTR_FOV, "0.0188 0.0141")
        .with(ATTR_RESOLUTION, "160 120");
    let config = Config::from_raw("touch", &raw).unwrap();
    let mut sensor = TactileSensor::new(config).unwrap();
    let mut out = vec![0.0; 160 * 120];
    let d = 0.2e-3;
    let placed = [Placed {
        shape: ball,
        pose: Isometry3::translation(2e-3, -1e-3, r - d),
    }];
    let eval = sensor.evaluate(&placed, &mut out);
    assert!(
        eval.rom.is_some() && eval.warnings.is_empty(),
        "{:?}",
        eval.warnings
    );
    let peak = out.iter().cloned().fold(0.0, f64::max);
    assert!((peak - d).abs() <= 0.1 * d, "peak {peak}");
    assert!(out.iter().all(|v| v.is_finite() && *v >= 0.0));
}

/// The shipped GelSight Mini (`sensor="gelsight-mini"`, a 1.41 mm gel on the linear
/// solver at the 0.5 mm its calibration used) made `rom`: the file's grid spacing is its
/// coarse gel's and is left out, so the sensor runs on the model's grid, `0.35 T`, and
/// presses a sphere with its image peak at the sphere's deepest point; `dx` written beside
/// the file is still checked against the model. The file's solver is its coarse gel's
/// too: with `model="rom-default"` (trained on the relaxation) the preset runs that
/// model on its own solver, and `solver="linear"` written beside the file is refused by
/// name.
#[test]
fn the_gelsight_mini_preset_runs_rom_on_the_models_grid() {
    let raw = RawConfig::default()
        .with(tacrom::config::ATTR_SENSOR, "gelsight-mini")
        .with(ATTR_PHYSICS, "rom")
        .with(ATTR_RESOLUTION, "160 120");
    let config = Config::from_raw("mini", &raw).unwrap();
    let t = config.size[2];
    assert!(
        (config.dx.unwrap() - 0.35 * t).abs() < 1e-12,
        "{:?}",
        config.dx
    );
    let (r, d) = (2e-3, 0.15e-3);
    let placed = [Placed {
        shape: Arc::new(Sphere::new(r)),
        pose: Isometry3::translation(1e-3, 0.0, r - d),
    }];
    // A press of the sensor, its image's peak within a tenth of the sphere's depth.
    let presses = |config: Config, what: &str| {
        let mut sensor = TactileSensor::new(config).unwrap();
        let mut out = vec![0.0; sensor.config().sensordata_len()];
        let eval = sensor.evaluate(&placed, &mut out);
        assert!(
            eval.rom.is_some() && eval.warnings.is_empty(),
            "{what}: {:?}",
            eval.warnings
        );
        let peak = out[..160 * 120].iter().cloned().fold(0.0, f64::max);
        assert!((peak - d).abs() <= 0.1 * d, "{what}: peak {peak}");
    };
    presses(config, "rom");
    let e = load_error(raw.clone().with(tacrom::config::ATTR_DX, "5e-4"));
    assert!(e.contains("attribute 'dx'"), "{e}");
    let relaxed = raw.with(tacrom::config::ATTR_MODEL, "rom-default");
    presses(Config::from_raw("mini", &relaxed).unwrap(), "rom-default");
    let e = load_error(relaxed.with(tacrom::config::ATTR_SOLVER, "linear"));
    assert!(e.contains("attribute 'solver'"), "{e}");
}

/// The default rom's force on gels of the family against Hertz on the bonded layer
/// (Dimitriadis et al. 2002), where it holds (`sqrt(R d) / T` below 1): spheres of radius
/// 2 and 5 mm pressed 0.1 mm, `T / 8` and `T / 4` into gels 1, 1.5 and 6 mm thick
/// (frictionless, Poisson 0.43). The bound is the default gel's (12 % mean per radius,
/// `rom_linear_force_follows_hertz_at_every_poisson_it_serves`); measured: mean 4.2 to
/// 10.1 %, worst press +11.5 % (the 5 mm sphere 0.125 mm into the 1 mm gel), rom above
/// Hertz on the thin gels where its coarse gel lies below. The gel family's model
/// (`model="rom-family"`) under the same bound.
#[test]
fn rom_force_follows_hertz_on_thin_and_thick_gels() {
    for (size, t) in [
        ("0.012 0.012 0.001", 1e-3f64),
        ("0.018 0.014 0.0015", 1.5e-3),
        ("0.04 0.03 0.006", 6e-3),
    ] {
        for (r, model) in [2e-3f64, 5e-3]
            .into_iter()
            .flat_map(|r| [(r, None), (r, Some(tacrom::rom::FAMILY_MODEL))])
        {
            let depths: Vec<f64> = [0.1e-3, t / 8.0, t / 4.0]
                .into_iter()
                .filter(|&d| (r * d).sqrt() / t < 1.0)
                .collect();
            let mut raw = RawConfig::default()
                .with(ATTR_FRICTION, "0")
                .with(ATTR_SIZE, size);
            if let Some(m) = model {
                raw = raw.with(ATTR_MODEL, m);
            }
            let ratios: Vec<f64> = sphere_forces_of(raw, r, &depths)
                .iter()
                .zip(&depths)
                .map(|(f, &d)| f / tacrom::mpm::hertz::hertz_bonded(1.19e5, 0.43, r, d, t))
                .collect();
            let mean = ratios.iter().map(|q| (q - 1.0).abs()).sum::<f64>() / ratios.len() as f64;
            eprintln!(
                "T {} mm, R {} mm, {}: force / Hertz {ratios:.3?}, mean error {:.1} %",
                t * 1e3,
                r * 1e3,
                model.unwrap_or("rom-linear"),
                mean * 100.0
            );
            assert!(mean <= 0.12, "T {t}, R {r}, {model:?}: {ratios:?}");
        }
    }
}

/// The gel family's model (`model="rom-family"`, trained on presses over the family) on the
/// thin and thick gels issue 54 names, through the whole sensor: a sphere pressed off
/// centre into an 18 x 14 x 1.5 mm gel and a 40 x 30 x 6 mm one, near the default gel's
/// material (Poisson 0.45, friction 0.5) and away from it (Poisson 0.32, friction 0.1), against
/// the relaxation at `T / 8` (the reference its data were solved with), beside the default
/// rom (`rom-linear`, trained on the default gel at Poisson 0.43, friction 0.5). The sensor
/// loads it on both gels and materials without a warning; no pixel is NaN or deeper than
/// the sphere reaches; its force is within FORCE of the reference's; on the thin gel its
/// depth error over the deformed pixels is at most THIN of its coarse gel's. On the thick
/// gel a 5 mm sphere 0.5 mm deep is already close in the coarse gel (4.5 to 9.5 um) and no
/// model gains much (0.68 and 0.97 of it; `rom-linear` 0.57 and 1.30), so it has no depth
/// gate there: docs/rom.md, "One model for the family".
#[test]
fn the_family_model_serves_thin_and_thick_gels_through_the_sensor() {
    use tacrom::config::ATTR_FOV;
    use tacrom::geometry::PixelGrid;
    // Issue 54's force target; measured +0.2 to +2.4 %.
    const FORCE: f64 = 0.05;
    // Half the coarse gel's error; measured 0.37 and 0.41.
    const THIN: f64 = 0.5;
    let mut failed = Vec::new();
    for (poisson, friction) in [(0.45, 0.5), (0.32, 0.1)] {
        for (size, r, d, [x, y], fov) in [
            (
                [0.018, 0.014, 0.0015],
                2e-3,
                0.15e-3,
                [1e-3, -0.6e-3],
                0.008,
            ),
            ([0.040, 0.030, 0.006], 5e-3, 0.5e-3, [3e-3, -2e-3], 0.024),
        ] {
            let ball: Arc<dyn tacrom::geometry::Sdf> = Arc::new(Sphere::new(r));
            let placed = [Placed {
                shape: ball,
                pose: Isometry3::translation(x, y, r - d),
            }];
            let grid = PixelGrid {
                width: 96,
                height: 96,
                fov_x: fov,
                fov_y: fov,
            };
            let (reference, reference_force) =
                fine_reference(size, poisson, Some(friction), &placed, &grid);
            let run = |physics: &str, model: Option<&str>| {
                let mut raw = RawConfig::default()
                    .with(ATTR_PHYSICS, physics)
                    .with(ATTR_SOLVER, "linear")
                    .with(ATTR_POISSON, &poisson.to_string())
                    .with(ATTR_FRICTION, &friction.to_string())
                    .with(ATTR_SIZE, &format!("{} {} {}", size[0], size[1], size[2]))
                    .with(ATTR_FOV, &format!("{fov} {fov}"))
                    .with(ATTR_RESOLUTION, "96 96")
                    .with(ATTR_OUTPUTS, "depth force");
                if let Some(m) = model {
                    raw = raw.with(ATTR_MODEL, m);
                }
                let config = Config::from_raw("touch", &raw).unwrap();
                against_reference(config, &placed, d, &reference, reference_force)
            };
            let (coarse, coarse_force) = run("coarse", None);
            let (rom, rom_force) = run("rom", None);
            let (family, family_force) = run("rom", Some(tacrom::rom::FAMILY_MODEL));
            let case = format!("{size:?}, Poisson {poisson}, friction {friction}");
            eprintln!(
                "{case} against T/8: coarse {:.2} um, force {:+.1} %; rom {:.2} um, {:+.1} %; \
                 rom-family {:.2} um ({:.2} of coarse), {:+.1} %",
                coarse * 1e6,
                coarse_force * 100.0,
                rom * 1e6,
                rom_force * 100.0,
                family * 1e6,
                family / coarse,
                family_force * 100.0
            );
            if family_force.abs() > FORCE {
                failed.push(format!("{case}: force {family_force:+.3}"));
            }
            if size[2] < 2e-3 && family > THIN * coarse {
                failed.push(format!("{case}: depth {:.2} of coarse", family / coarse));
            }
        }
    }
    assert!(failed.is_empty(), "{failed:?}");
}

/// The relaxation at `T / 8` of `placed` pressed into a gel of `size` (Poisson's ratio
/// `poisson`, friction `friction` or the default): its depth image on `grid` and its
/// normal force.
fn fine_reference(
    size: [f64; 3],
    poisson: f64,
    friction: Option<f64>,
    placed: &[Placed],
    grid: &tacrom::geometry::PixelGrid,
) -> (Vec<f64>, f64) {
    use tacrom::mpm::{Gel, GelParams, SolverOptions};
    let defaults = GelParams::default();
    let gel = GelParams {
        size,
        poisson,
        friction: friction.unwrap_or(defaults.friction),
        dx: size[2] / 8.0,
        ..defaults
    };
    let mut fine = Gel::new(gel, SolverOptions::default()).unwrap();
    let report = fine.solve(placed);
    assert!(report.converged, "{size:?}: {report:?}");
    let mut depth = vec![0.0; grid.width * grid.height];
    fine.surface_depth(grid, &mut depth);
    (depth, fine.force().z)
}

/// A sensor of `config` (depth, then force) pressed by `placed` once, against a
/// reference: the depth image's mean absolute error over the pixels deeper than 1 um in
/// either, and its normal force's relative error. Every pixel is finite and no deeper than
/// `deepest`, the indenter's deepest reach into the gel; a warning fails.
fn against_reference(
    config: Config,
    placed: &[Placed],
    deepest: f64,
    reference: &[f64],
    reference_force: f64,
) -> (f64, f64) {
    let physics = config.physics;
    let mut out = vec![0.0; config.sensordata_len()];
    let mut sensor = TactileSensor::new(config).unwrap();
    let eval = sensor.evaluate(placed, &mut out);
    assert!(eval.warnings.is_empty(), "{physics:?}: {:?}", eval.warnings);
    let (mut sum, mut n) = (0.0, 0);
    for (a, b) in out[..reference.len()].iter().zip(reference) {
        assert!(a.is_finite() && *a <= deepest + 1e-9, "{physics:?}: {a}");
        if a.max(*b) > 1e-6 {
            sum += (a - b).abs();
            n += 1;
        }
    }
    (sum / n as f64, sensor.force().z / reference_force - 1.0)
}
