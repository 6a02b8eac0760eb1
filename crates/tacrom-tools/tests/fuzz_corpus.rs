//! The command's fuzz corpus replayed through its target (`tacrom_tools::fuzzing`) on the
//! stable toolchain, as the plugin's are in `tests/fuzz_corpus.rs`: the seeds and every
//! input a fuzzing run kept or that once failed (`fuzz/corpus/presses/`, committed). A
//! panic on any of them fails this test, naming the file.

#[test]
fn every_corpus_input_runs_through_its_target() {
    for &(name, target) in tacrom_tools::fuzzing::TARGETS {
        tacrom::fuzzing::replay_corpus(name, target);
    }
}

/// The seeds are a valid set's files (a calibration that must succeed, mirrored or not)
/// and small faults of them; the target accepts the valid ones whole.
#[test]
fn the_valid_seed_calibrates() {
    let dir = tacrom::checkout_root().join("fuzz/corpus/presses");
    for seed in ["seed-list", "seed-list-mirrored"] {
        let data = std::fs::read(dir.join(seed)).expect("a seed");
        let list: tacrom_tools::calibrate::PressList =
            serde_json::from_slice(&data[1..]).expect("the seed is a press list");
        assert_eq!(list.presses.len(), 3);
        let report = tacrom_tools::fuzzing::calibrate_input(&data).expect("a calibration");
        assert_eq!(report.presses.len(), 3);
        assert_eq!(report.presses.iter().filter(|p| p.detected).count(), 2);
    }
}

/// Writes the seeds (`TACROM_WRITE_SEEDS=1 cargo test -p tacrom-tools --test fuzz_corpus
/// write_seeds`): the valid list plain and mirrored, the first image whole, and two faults
/// (a list naming a missing image, an image cut short).
#[test]
fn write_seeds() {
    if std::env::var_os("TACROM_WRITE_SEEDS").is_none() {
        return;
    }
    let dir = tacrom::checkout_root().join("fuzz/corpus/presses");
    std::fs::create_dir_all(&dir).expect("the corpus folder");
    let set = tacrom_tools::fuzzing::valid_set();
    let with = |selector: u8, bytes: &[u8]| [&[selector][..], bytes].concat();
    let list = &set[0].1;
    let image = &set[2].1;
    let missing =
        String::from_utf8(list.clone())
            .expect("utf-8")
            .replacen(&set[2].0, "press_999.png", 1);
    for (name, data) in [
        ("seed-list", with(0, list)),
        ("seed-list-mirrored", with(2, list)),
        ("seed-image", with(1, image)),
        ("seed-list-missing-image", with(0, missing.as_bytes())),
        ("seed-image-truncated", with(1, &image[..image.len() / 2])),
    ] {
        std::fs::write(dir.join(name), data).expect("a seed");
    }
}
