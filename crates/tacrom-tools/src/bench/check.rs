//! The benchmark as a regression guard (`tacrom bench --check FILE`): each mode's accuracy
//! against a committed baseline of the same profile, and the ordering the modes exist for.
//!
//! The checks, each a failure when broken:
//! * **Ordering**: rom's depth MAE below coarse's, coarse's below rigid's (the decoder must
//!   add detail the coarse gel lacks; the gel must beat the rigid penetration); the same
//!   for the linear solver's rows (`rom-linear`, `coarse-linear`) where the run has them.
//! * **Drift**: per mode in the baseline, depth MAE at most `1 + RELATIVE` times the
//!   baseline's plus [`ABSOLUTE_MAE`], SSIM at least the baseline's minus [`SSIM_DROP`], the
//!   relative force error at most the baseline's plus [`FORCE_POINTS`] percentage points.
//!   The profile is deterministic (bit-identical across thread counts and runs on one
//!   machine), so what moves these rows is a change of code; the margins admit another
//!   CPU's floating-point rounding in ONNX Runtime and the solver, and stop a loss of a
//!   tenth of the accuracy. An improvement beyond the margins is reported, not failed:
//!   rewrite the baseline with `--write-baseline` in the same commit.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{BenchError, BenchResult};

/// Relative MAE drift allowed.
pub const RELATIVE: f64 = 0.10;
/// Absolute MAE drift allowed (m): a tenth of a micrometre of depth per pixel on average
/// is below anything an image shows.
pub const ABSOLUTE_MAE: f64 = 0.1e-6;
/// SSIM loss allowed.
pub const SSIM_DROP: f64 = 0.01;
/// Force error increase allowed (percentage points of the reference force).
pub const FORCE_POINTS: f64 = 1.0;

/// One mode's accuracy row in a baseline.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct BaselineRow {
    /// Depth MAE (um).
    pub mae_um: f64,
    /// SSIM.
    pub ssim: f64,
    /// Force error (% of the reference force).
    pub force_err_pct: f64,
    /// Over the indenters of the run: the median, least and largest of this mode's depth
    /// MAE over coarse's on the same indenter (written where the run has coarse and more
    /// than one indenter; the full profile's are what [`check_against_full`] reads).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ratio_to_coarse: Option<[f64; 3]>,
}

/// A committed baseline.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Baseline {
    /// The profile it was taken with.
    pub profile: String,
    /// How it was produced.
    pub command: String,
    /// Mode label -> its row (first thread count).
    pub modes: std::collections::BTreeMap<String, BaselineRow>,
}

fn rows(result: &BenchResult) -> std::collections::BTreeMap<String, BaselineRow> {
    let first = result
        .rows
        .iter()
        .filter(|r| !r.reference)
        .map(|r| r.threads)
        .min();
    result
        .rows
        .iter()
        .filter(|r| !r.reference && Some(r.threads) == first)
        .map(|r| {
            (
                r.label.clone(),
                BaselineRow {
                    mae_um: r.accuracy.mae * 1e6,
                    ssim: r.accuracy.ssim,
                    force_err_pct: r.accuracy.force_rel * 100.0,
                    ratio_to_coarse: ratio_spread(result, r),
                },
            )
        })
        .collect()
}

/// The median, least and largest per-indenter ratio of `row`'s depth MAE to coarse's.
fn ratio_spread(result: &BenchResult, row: &super::ModeResult) -> Option<[f64; 3]> {
    let coarse = result
        .rows
        .iter()
        .find(|m| !m.reference && m.label == "coarse" && m.threads == row.threads)?;
    let ratios: Vec<f64> = row
        .by_indenter
        .iter()
        .zip(&coarse.by_indenter)
        .filter(|(_, c)| c.mae > 0.0)
        .map(|(m, c)| m.mae / c.mae)
        .collect();
    (ratios.len() > 1).then(|| {
        [
            super::metrics::median(&ratios),
            ratios.iter().copied().fold(f64::INFINITY, f64::min),
            ratios.iter().copied().fold(0.0, f64::max),
        ]
    })
}

/// Checks `result` (any profile) against the committed full profile at `path`: for each
/// mode in both, its depth MAE over coarse's must lie within the range the full profile
/// measured across its indenters, widened by [`RELATIVE`]. The profiles differ in
/// resolution, positions and reference, so their absolute errors differ; the ratio to
/// coarse on the same run is what carries over, and a ratio outside every indenter's of
/// the full profile means the run no longer measures what the committed report says.
pub fn check_against_full(
    result: &BenchResult,
    path: &Path,
) -> Result<(Vec<String>, bool), BenchError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| BenchError::Usage(format!("full profile {}: {e}", path.display())))?;
    let full: Baseline = serde_json::from_str(&text)
        .map_err(|e| BenchError::Usage(format!("full profile {}: {e}", path.display())))?;
    if full.profile != "full" {
        return Err(BenchError::Usage(format!(
            "{} is of the {} profile, not the full one",
            path.display(),
            full.profile
        )));
    }
    Ok(compare_ratios(&full, &rows(result)))
}

/// The check of [`check_against_full`] on `now` against the full profile's rows.
pub fn compare_ratios(
    full: &Baseline,
    now: &std::collections::BTreeMap<String, BaselineRow>,
) -> (Vec<String>, bool) {
    let mut lines = Vec::new();
    let mut ok = true;
    let Some(coarse) = now.get("coarse").map(|r| r.mae_um).filter(|c| *c > 0.0) else {
        return (
            vec!["FAIL coarse in the run, with a depth error".to_owned()],
            false,
        );
    };
    let mut compared = 0;
    for (mode, f) in &full.modes {
        let (Some(r), Some([median, lo, hi])) = (now.get(mode), f.ratio_to_coarse) else {
            continue;
        };
        if mode == "coarse" {
            continue;
        }
        compared += 1;
        let ratio = r.mae_um / coarse;
        let (min, max) = (lo / (1.0 + RELATIVE), hi * (1.0 + RELATIVE));
        let pass = ratio >= min && ratio <= max;
        ok &= pass;
        lines.push(format!(
            "{} {mode}: depth MAE / coarse's {ratio:.3} within [{min:.3}, {max:.3}] (full \
             profile: median {median:.3} over its indenters, {lo:.3} to {hi:.3})",
            if pass { "ok  " } else { "FAIL" }
        ));
    }
    if compared == 0 {
        ok = false;
        lines.push("FAIL no mode of the full profile with its ratios in the run".to_owned());
    }
    (lines, ok)
}

/// Writes `result`'s accuracy rows as the baseline at `path`.
pub fn write_baseline(result: &BenchResult, path: &Path) -> Result<(), BenchError> {
    let baseline = Baseline {
        profile: result.options.profile.clone(),
        command: result.command.clone(),
        modes: rows(result),
    };
    let mut text =
        serde_json::to_string_pretty(&baseline).map_err(|e| BenchError::Usage(e.to_string()))?;
    text.push('\n');
    std::fs::write(path, text).map_err(|e| BenchError::Usage(format!("{}: {e}", path.display())))
}

/// Checks `result` against the baseline at `path`: the report's lines and whether every
/// check passed.
pub fn check(result: &BenchResult, path: &Path) -> Result<(Vec<String>, bool), BenchError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| BenchError::Usage(format!("baseline {}: {e}", path.display())))?;
    let baseline: Baseline = serde_json::from_str(&text)
        .map_err(|e| BenchError::Usage(format!("baseline {}: {e}", path.display())))?;
    if baseline.profile != result.options.profile {
        return Err(BenchError::Usage(format!(
            "baseline {} is of the {} profile, this run is {}",
            path.display(),
            baseline.profile,
            result.options.profile
        )));
    }
    Ok(compare(&baseline, &rows(result)))
}

/// The checks of the module docs on `now` against `baseline`.
pub fn compare(
    baseline: &Baseline,
    now: &std::collections::BTreeMap<String, BaselineRow>,
) -> (Vec<String>, bool) {
    let lines = std::cell::RefCell::new(Vec::new());
    let mut ok = true;
    let mut verdict = |pass: bool, line: String| {
        ok &= pass;
        lines
            .borrow_mut()
            .push(format!("{} {line}", if pass { "ok  " } else { "FAIL" }));
    };
    let verdict_note = |line: String| lines.borrow_mut().push(line);
    let mae = |m: &str| now.get(m).map(|r| r.mae_um);
    let orders = [
        ("rom", "coarse", true),
        ("coarse", "rigid", true),
        ("rom-linear", "coarse-linear", false),
        ("coarse-linear", "rigid", false),
    ];
    for (better, worse, required) in orders {
        match (mae(better), mae(worse)) {
            (Some(b), Some(w)) => verdict(
                b < w,
                format!("{better} depth MAE {b:.2} um below {worse}'s {w:.2} um"),
            ),
            (None, _) if !required => {}
            _ => verdict(false, format!("{better} and {worse} both in the run")),
        }
    }
    for (mode, base) in &baseline.modes {
        let Some(r) = now.get(mode) else {
            verdict(
                false,
                format!("{mode}: in the baseline, missing from the run"),
            );
            continue;
        };
        let mae_limit = base.mae_um * (1.0 + RELATIVE) + ABSOLUTE_MAE * 1e6;
        verdict(
            r.mae_um <= mae_limit,
            format!(
                "{mode}: depth MAE {:.2} um <= {mae_limit:.2} (baseline {:.2})",
                r.mae_um, base.mae_um
            ),
        );
        verdict(
            r.ssim >= base.ssim - SSIM_DROP,
            format!(
                "{mode}: SSIM {:.4} >= {:.4} (baseline {:.4})",
                r.ssim,
                base.ssim - SSIM_DROP,
                base.ssim
            ),
        );
        let force_limit = base.force_err_pct + FORCE_POINTS;
        verdict(
            r.force_err_pct <= force_limit,
            format!(
                "{mode}: force error {:.2} % <= {force_limit:.2} (baseline {:.2})",
                r.force_err_pct, base.force_err_pct
            ),
        );
        if r.mae_um < base.mae_um * (1.0 - RELATIVE) - ABSOLUTE_MAE * 1e6 {
            verdict_note(format!(
                "note {mode}: depth MAE {:.2} um improved beyond the margin on the baseline's {:.2}: \
                 rewrite the baseline (--write-baseline)",
                r.mae_um, base.mae_um
            ));
        }
    }
    (lines.into_inner(), ok)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(mae_um: f64) -> BaselineRow {
        BaselineRow {
            mae_um,
            ssim: 0.95,
            force_err_pct: 5.0,
            ratio_to_coarse: None,
        }
    }

    #[test]
    fn a_ratio_outside_the_full_profiles_range_fails() {
        let mut full = baseline();
        full.profile = "full".into();
        full.modes.get_mut("rom").unwrap().ratio_to_coarse = Some([0.5, 0.3, 0.7]);
        full.modes.get_mut("rigid").unwrap().ratio_to_coarse = Some([3.0, 2.0, 5.0]);
        let now = |rom: f64, rigid: f64| {
            [("coarse", 4.0), ("rom", rom), ("rigid", rigid)]
                .into_iter()
                .map(|(m, e)| (m.to_owned(), row(e)))
                .collect()
        };
        let (lines, ok) = compare_ratios(&full, &now(2.0, 12.0));
        assert!(ok && lines.len() == 2, "{lines:?}");
        // rom at 0.8 of coarse: above 0.7 * 1.1.
        let (lines, ok) = compare_ratios(&full, &now(3.2, 12.0));
        assert!(
            !ok && lines.iter().any(|l| l.starts_with("FAIL rom")),
            "{lines:?}"
        );
        // Within the widening: 0.75 passes.
        assert!(compare_ratios(&full, &now(3.0, 12.0)).1);
        // rigid at 1.5 of coarse: below 2 / 1.1.
        assert!(!compare_ratios(&full, &now(2.0, 6.0)).1);
        // Nothing to compare is a failure, not a pass.
        assert!(!compare_ratios(&baseline(), &now(2.0, 12.0)).1);
    }

    fn baseline() -> Baseline {
        Baseline {
            profile: "quick".into(),
            command: String::new(),
            modes: [("rigid", 15.0), ("coarse", 5.0), ("rom", 2.5)]
                .into_iter()
                .map(|(m, e)| (m.to_owned(), row(e)))
                .collect(),
        }
    }

    #[test]
    fn the_baseline_itself_passes_and_each_kind_of_regression_fails() {
        let b = baseline();
        assert!(compare(&b, &b.modes).1);
        let mut worse = b.modes.clone();
        worse.get_mut("rom").unwrap().mae_um = 2.5 * 1.1 + 0.2;
        assert!(!compare(&b, &worse).1, "MAE drift");
        let mut worse = b.modes.clone();
        worse.get_mut("coarse").unwrap().ssim = 0.93;
        assert!(!compare(&b, &worse).1, "SSIM drop");
        let mut worse = b.modes.clone();
        worse.get_mut("coarse").unwrap().force_err_pct = 6.5;
        assert!(!compare(&b, &worse).1, "force error");
        let mut swapped = b.modes.clone();
        swapped.get_mut("rom").unwrap().mae_um = 5.5;
        swapped.get_mut("coarse").unwrap().mae_um = 5.4;
        let (lines, ok) = compare(&b, &swapped);
        assert!(
            !ok && lines.iter().any(|l| l.starts_with("FAIL rom depth MAE")),
            "{lines:?}"
        );
        // The linear solver's rows are ordered the same way where the run has them.
        let mut linear = b.modes.clone();
        linear.insert("coarse-linear".into(), row(6.0));
        linear.insert("rom-linear".into(), row(3.0));
        assert!(compare(&b, &linear).1);
        linear.get_mut("rom-linear").unwrap().mae_um = 6.5;
        let (lines, ok) = compare(&b, &linear);
        assert!(
            !ok && lines
                .iter()
                .any(|l| l.starts_with("FAIL rom-linear depth MAE")),
            "{lines:?}"
        );
        let mut missing = b.modes.clone();
        missing.remove("rom");
        assert!(!compare(&b, &missing).1, "a mode missing");
        let mut better = b.modes.clone();
        better.get_mut("coarse").unwrap().mae_um = 3.0;
        let (lines, ok) = compare(&b, &better);
        assert!(
            ok && lines.iter().any(|l| l.starts_with("note coarse")),
            "{lines:?}"
        );
    }
}
