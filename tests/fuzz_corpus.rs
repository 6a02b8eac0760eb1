//! The fuzzers' corpora replayed through their targets (`tacrom::fuzzing`) on the stable
//! toolchain: the seeds and every input a fuzzing run found worth keeping or that once
//! crashed a target (`fuzz/corpus/TARGET/`, committed). A target that panics on any of them
//! fails this test, naming the file. The coverage-guided runs themselves need nightly:
//! `make fuzz` (see docs/benchmarks.md).

#[test]
fn every_corpus_input_runs_through_its_target() {
    for &(name, target) in tacrom::fuzzing::TARGETS {
        tacrom::fuzzing::replay_corpus(name, target);
    }
}
