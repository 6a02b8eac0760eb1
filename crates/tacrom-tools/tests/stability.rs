//! The stability suite (see `tacrom_tools::stability`): every case, in rigid, coarse, rom
//! and rom on the linear solver, must keep all outputs finite, depth within [0, T], the gel's own surface no deeper
//! than the deepest indenter point (before the depth rule bounds the image), det F within
//! the clamp bounds, warn whenever equilibrium is not reached, run the reduced-order model
//! rather than fall back, and after a lift give a fresh sensor's press bit for bit.

use tacrom::config::RawConfig;
use tacrom_tools::stability::{cases, run_case, table, Row};

/// Rows that fail today on the surface bound alone, with what was measured (um below the
/// deepest indenter point, against the 50 um bound). They are asserted to fail on that
/// check and no other, and to stay under [`KNOWN_LIMIT`]; fixing one makes the test fail
/// until it is removed from this list.
///
/// * coarse, rotating bar (152) and cross_lines (147): within about 1.5 mm of the end of a
///   flat face, the relaxation solver leaves surface points below the face and out of
///   contact (a bar pressed 0.5 mm from rest: 500 um mid-face, 587 um at 1.55 mm from its
///   end at dx 1.4 mm, 561 um at 0.68 mm from it at dx 0.7 mm). The surface point is
///   extrapolated from each particle's F, which varies fastest at the face's edge (a stress
///   singularity); the error shrinks with the spacing. The Newton solver on the same press
///   keeps them within 14 um (`crates/tacrom-tools/src/probe/overshoot.rs`). The image is bounded by the
///   depth rule, so the sensor's depth stays on the indenter; the gel's force and pressure
///   near those ends do not.
/// * rom, rotating bar (73) and through the bottom (80): the decoder on a coarse input
///   with the defect above, and on a press through the whole layer (outside its training).
///
/// rom on the linear solver sank 50.6 um at the cone pattern's tip with the paper's decoder
/// widths (`models/rom-linear`, the default on this 4 mm gel until the narrow decoder took
/// its place); `models/rom-linear-narrow` sinks 38.3 um there and passes.
const KNOWN_OVERSHOOT: &[(&str, &str)] = &[
    ("coarse", "rotating bar"),
    ("coarse", "pattern cross_lines 0.5 mm"),
    ("rom", "rotating bar"),
    ("rom", "through the bottom"),
];

/// The most a known row may sink below the deepest indenter point (m): twice its
/// measured value, so that it does not grow unnoticed.
const KNOWN_LIMIT: f64 = 0.2e-3;

/// The meshes are the copies in the checkout, so that every case runs on every machine.
fn rows(physics: &str) -> Vec<Row> {
    rows_with(physics, None)
}

/// [`rows`] with the gel's equilibrium solver `solver` (the mode's default if `None`).
fn rows_with(physics: &str, solver: Option<tacrom::mpm::Solver>) -> Vec<Row> {
    let mut mode = RawConfig::default().with("physics", physics);
    if let Some(solver) = solver {
        mode = mode.with("solver", solver.name());
    }
    rows_of(&mode)
}

/// Every case of the suite on a sensor of the attributes `mode`.
fn rows_of(mode: &RawConfig) -> Vec<Row> {
    let physics = mode.get("physics").unwrap_or("rom");
    let dir = tacrom::vendored_patterns();
    let cases = cases(Some(&dir)).expect("the suite's meshes are in the checkout");
    assert_eq!(
        cases.len(),
        20,
        "cases: {:?}",
        cases.iter().map(|c| &c.name).collect::<Vec<_>>()
    );
    let rows: Vec<_> = cases.iter().map(|c| run_case(c, mode)).collect();
    println!("{physics}\n{}", table(&rows));
    rows
}

/// Every row passes, or fails only as a known overshoot of `label` (the mode) allows.
fn assert_all_ok(label: &str, rows: &[Row]) {
    let mut failed = Vec::new();
    for r in rows {
        let known = KNOWN_OVERSHOOT.contains(&(label, r.name.as_str()));
        if known {
            if r.failures() != ["overshoot"] || r.max_excess > KNOWN_LIMIT {
                failed.push(format!(
                    "{} (known overshoot; now {:?}, {:.1} um)",
                    r.name,
                    r.failures(),
                    r.max_excess * 1e6
                ));
            }
        } else if !r.ok() {
            failed.push(format!("{}: {:?}", r.name, r.failures()));
        }
    }
    assert!(
        failed.is_empty(),
        "{label}: failing cases {failed:?}\n{}",
        table(rows)
    );
}

#[test]
fn rigid_survives_every_case() {
    assert_all_ok("rigid", &rows("rigid"));
}

/// Every case passes; the near-incompressible gels, where the default solver is Newton's
/// method (`mpm::choose`), reach equilibrium in every frame (dynamic relaxation
/// stopped at its iteration cap there).
#[test]
fn coarse_survives_every_case() {
    let rows = rows("coarse");
    assert_all_ok("coarse", &rows);
    for name in ["Poisson 0.49, 1 mm", "Poisson 0.499, 1 mm"] {
        let r = rows.iter().find(|r| r.name == name).expect("the case runs");
        assert!(
            r.converged.1 > 0 && r.converged.0 == r.converged.1,
            "{name}: {:?} frames converged",
            r.converged
        );
    }
}

/// The relaxation's shipped model (`model="rom-default"`, so that its gel runs the
/// relaxation with the linear solver for contacts it misses) serves any
/// Young's modulus (the coarse depth it reads does not depend on it) and the Poisson's
/// ratios it was validated on, 0.3 to 0.48 (manifest `materials`): the cases at 0.49 and
/// 0.499 must be refused at load with both values named; every other case, Young's
/// modulus 1e4 to 1e7 Pa and Poisson 0.3 included, must pass.
#[test]
fn rom_survives_every_case_and_refuses_other_materials() {
    let mode = RawConfig::default()
        .with("physics", "rom")
        .with("model", "rom-default");
    let ran = refuses_exactly(
        rows_of(&mode),
        &["Poisson 0.49, 1 mm", "Poisson 0.499, 1 mm"],
        "[0.3, 0.48]",
    );
    assert_eq!(ran.len(), 18);
    assert_all_ok("rom", &ran);
}

/// rom on the linear solver (`physics="rom"`'s default; on the suite's 4 mm gel
/// `models/rom-linear-narrow`, validated at Poisson's ratio 0.3 to 0.49): Poisson 0.499 is
/// refused at load with both values named, and every case it serves passes, Poisson 0.3,
/// 0.49, the cone's tip and the rotating bar included (measured 38.3 um below the cone's
/// tip and 27.4 um below the bar; the linear coarse gel alone sinks 153 um there).
#[test]
fn rom_on_the_linear_solver_survives_every_case_and_refuses_other_materials() {
    let ran = refuses_exactly(
        rows_with("rom", Some(tacrom::mpm::Solver::Linear)),
        &["Poisson 0.499, 1 mm"],
        "[0.3, 0.49]",
    );
    assert_eq!(ran.len(), 19);
    // Its own label: rom's known overshoots are not known here.
    assert_all_ok("rom-linear", &ran);
}

/// Asserts that exactly the cases `names` were refused at load, each naming itself and the
/// model's Poisson range `range`; returns the rows that ran.
fn refuses_exactly(rows: Vec<Row>, names: &[&str], range: &str) -> Vec<Row> {
    let (refused, ran): (Vec<Row>, Vec<Row>) = rows.into_iter().partition(|r| r.refused.is_some());
    let got: Vec<_> = refused.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(got, names);
    for r in &refused {
        let e = r.refused.as_deref().unwrap();
        assert!(
            e.contains(&format!("trained for Poisson's ratio in {range}")) && e.contains(&r.name),
            "{}: {e}",
            r.name
        );
    }
    ran
}
