//! The command's own fuzz target: the calibration input of `tacrom calibrate` (a folder of
//! `presses.json`, `background.png` and the press images), run with `cargo +nightly fuzz run
//! presses` from `fuzz/` and replayed from its corpus in `make test`
//! (`crates/tacrom-tools/tests/fuzz_corpus.rs`). The plugin's targets are `tacrom::fuzzing`.
//!
//! The input is one selector byte and the bytes of one file of a small, valid calibration
//! set (three synthetic presses of 32 x 24 pixels, with their contacts for the first press
//! only, so that the others are detected): an even selector writes the bytes as
//! `presses.json`, an odd one as the first press's image (its bit 1 also flips the images
//! left-right, `--mirror`). The whole calibration then runs: the set is read, the contacts
//! detected, the table fitted (9 x 9 nodes), the optics written and every press rendered again. It may
//! refuse its input; a panic, a hang, an optics file that does not load back or a
//! non-finite score of a calibration it accepted is a finding.
//!
//! `presses.json` names its images by path. The target reads only files of its scratch
//! folder (a name with a path separator or a leading dot is left out): it explores the
//! list's contents, not the machine's file system.

use std::sync::OnceLock;

use crate::calibrate::fit::FitOptions;
use crate::calibrate::synth::{synthesize, SynthOptions};
use crate::calibrate::{calibrate, CalibrateOptions, PressList, PRESS_LIST};
use tacrom::fuzzing::scratch;
use tacrom::render::calibrated::CalibratedOptics;

/// The fuzz targets of the command by name (the names of `fuzz/fuzz_targets/*.rs` and of
/// the corpus folders).
pub const TARGETS: &[(&str, tacrom::fuzzing::Target)] = &[("presses", presses)];

/// A file of the calibration folder: its name and contents.
pub type File = (String, Vec<u8>);

/// The valid set's files: `presses.json` and each image, by name (the seeds of the corpus
/// are made from them).
pub fn valid_set() -> &'static [File] {
    static SET: OnceLock<Vec<File>> = OnceLock::new();
    SET.get_or_init(|| {
        let dir = scratch("presses-valid");
        let mut o = SynthOptions::new(dir.clone());
        (o.presses, o.resolution, o.pixel_size) = (3, [32, 24], 0.3e-3);
        let entries = synthesize(&o).expect("a synthetic calibration set");
        // The first press's contact given, the others' detected.
        let mut list: PressList =
            serde_json::from_slice(&std::fs::read(dir.join(PRESS_LIST)).expect("written"))
                .expect("a press list");
        for p in list.presses.iter_mut().skip(1) {
            (p.center_px, p.contact_radius_px) = (None, None);
        }
        let json = serde_json::to_vec_pretty(&list).expect("a press list");
        let mut files = vec![(PRESS_LIST.to_owned(), json)];
        files.push(("background.png".into(), read(&dir, &list.background)));
        for (entry, _) in &entries {
            files.push((entry.image.clone(), read(&dir, &entry.image)));
        }
        files
    })
}

fn read(dir: &std::path::Path, name: &str) -> Vec<u8> {
    std::fs::read(dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// The calibration input: see the module's doc.
pub fn presses(data: &[u8]) {
    let _ = calibrate_input(data);
}

/// [`presses`], returning the calibration's report where it accepted the input.
pub fn calibrate_input(data: &[u8]) -> Option<crate::calibrate::CalibrationReport> {
    let (&selector, bytes) = data.split_first()?;
    let set = valid_set();
    let dir = scratch("presses");
    for (name, contents) in set {
        std::fs::write(dir.join(name), contents).expect("scratch file");
    }
    let target = if selector % 2 == 0 {
        PRESS_LIST
    } else {
        set[2].0.as_str()
    };
    std::fs::write(dir.join(target), bytes).expect("scratch file");
    if let Ok(list) = serde_json::from_slice::<PressList>(bytes) {
        let names = std::iter::once(&list.background).chain(list.presses.iter().map(|p| &p.image));
        if names
            .into_iter()
            .any(|n| n.contains(['/', '\\']) || n.starts_with('.') || n.is_empty())
        {
            return None;
        }
    }
    let out = dir.join("out").join("optics.json");
    // A 9 x 9 table: the fit's code is the same at every size, and the default 41 x 41
    // took most of an input's time (58 inputs a second here against about 1,050).
    let options = CalibrateOptions {
        fit: FitOptions {
            bins: 9,
            ..FitOptions::default()
        },
        mirror: selector & 2 != 0,
        out: out.clone(),
        ..CalibrateOptions::new(dir.clone())
    };
    let report = calibrate(&options).ok()?;
    for p in &report.presses {
        let e = p.errors;
        assert!(
            [e.mae_contact, e.mae_image, e.ssim_contact, e.ssim_image]
                .iter()
                .all(|v| v.is_finite()),
            "press {}: non-finite scores {e:?}",
            p.image
        );
        assert!(p.contact.radius.is_finite() && p.contact.radius > 0.0);
    }
    CalibratedOptics::load(&out).expect("the optics a calibration wrote load back");
    Some(report)
}
