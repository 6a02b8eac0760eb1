//! The fuzzers' corpora replayed through their targets (`tacrom::fuzzing`) on the stable
//! toolchain: the seeds and every input a fuzzing run found worth keeping or that once
//! crashed a target (`fuzz/corpus/TARGET/`, committed). A target that panics on any of them
//! fails this test, naming the file. The coverage-guided runs themselves need nightly:
//! `make fuzz` (see docs/benchmarks.md).

use std::path::PathBuf;

fn corpus(target: &str) -> Vec<PathBuf> {
    let dir = tacrom::checkout_root().join("fuzz/corpus").join(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("a corpus entry").path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    files
}

#[test]
fn every_corpus_input_runs_through_its_target() {
    for &(name, target) in tacrom::fuzzing::TARGETS {
        let files = corpus(name);
        assert!(!files.is_empty(), "no corpus for target {name}");
        for file in files {
            let data = std::fs::read(&file).expect("a corpus file");
            let run = std::panic::catch_unwind(|| target(&data));
            assert!(run.is_ok(), "target {name} panics on {}", file.display());
        }
    }
}
