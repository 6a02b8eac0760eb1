//! Many `MjData` in one process, as RL code holds them: 256 data of one model, each pressed
//! and solved from one thread, must not add an OS thread per data (the gels share the
//! calling thread's pool; a one-thread solve runs on the caller), and their results must
//! equal one data's. Alone in its test binary, so that the process's thread count is this
//! test's.

mod common;

use common::*;

/// `field` of /proc/self/status (kB for memory, a count for Threads).
fn status(field: &str) -> u64 {
    let text = std::fs::read_to_string("/proc/self/status").expect("/proc/self/status");
    text.lines()
        .find_map(|l| l.strip_prefix(field)?.strip_prefix(':'))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .expect("a status field")
}

/// Steps `n` data of a coarse press scene with `threads` solver threads and returns the
/// growth of the process's OS threads and resident memory (kB) per data.
fn step_many(n: usize, threads: &str) -> (u64, f64) {
    let threads0 = status("Threads");
    let m = load_xml(&press_scene(
        &config(&[
            ("physics", "coarse"),
            ("outputs", "depth force"),
            ("resolution", "32 24"),
            // A 10 x 10 mm gel (a fingertip): 256 cold solves stay within a few seconds.
            ("size", "0.01 0.01 0.004"),
            ("fov", "0.008 0.006"),
            ("threads", threads),
        ]),
        &sphere_body(0.005),
    ))
    .expect("model loads");
    let rss0 = status("VmRSS");
    let mut data: Vec<Data> = (0..n).map(|_| m.make_data()).collect();
    for d in &mut data {
        d.set_qpos(0, 0.3e-3);
        d.forward(&m);
    }
    let first = data[0].sensor(&m, 0);
    assert!(first.iter().any(|&v| v > 0.0), "the press reaches the gel");
    for (i, d) in data.iter().enumerate() {
        assert_eq!(d.sensor(&m, 0), first, "data {i} differs from data 0");
    }
    let grown = status("Threads") - threads0;
    let per_data = (status("VmRSS") as f64 - rss0 as f64) / n as f64;
    eprintln!(
        "{n} MjData, threads = {threads}: {grown} OS threads added, {per_data:.0} kB resident per \
         data"
    );
    (grown, per_data)
}

#[test]
fn many_data_share_the_callers_threads() {
    // One thread per solve: the calling thread itself, no OS thread added.
    let (grown, _) = step_many(256, "1");
    assert_eq!(grown, 0, "threads added for 256 one-thread gels");
    // Two threads per solve: one shared pool of two for the calling thread.
    let (grown, _) = step_many(64, "2");
    assert!(grown <= 2, "{grown} threads added for 64 two-thread gels");
}
