#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| tacrom::fuzzing::graph(data));
