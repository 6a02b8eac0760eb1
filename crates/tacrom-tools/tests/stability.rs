//! The stability suite (see `tacrom_tools::stability`): every case, rigid and coarse, must keep
//! all outputs finite, depth within [0, T], det F within the clamp bounds, warn whenever
//! equilibrium is not reached, and leave a sensor that still works.

use std::path::PathBuf;

use tacrom_tools::stability::{cases, run_case, table};

fn patterns() -> PathBuf {
    let root = tacrom::checkout_root().to_path_buf();
    let shared = root.join("../shared/indenters/patterns");
    if shared.is_dir() {
        shared
    } else {
        root.join("tests/data")
    }
}

fn suite(physics: &str) {
    let dir = patterns();
    let rows: Vec<_> = cases(Some(&dir))
        .iter()
        .map(|c| run_case(c, physics, None))
        .collect();
    println!("{physics}\n{}", table(&rows));
    let failed: Vec<_> = rows
        .iter()
        .filter(|r| !r.ok())
        .map(|r| r.name.clone())
        .collect();
    assert!(
        failed.is_empty(),
        "{physics}: failing cases {failed:?}\n{}",
        table(&rows)
    );
}

#[test]
fn rigid_survives_every_case() {
    suite("rigid");
}

#[test]
fn coarse_survives_every_case() {
    suite("coarse");
}
