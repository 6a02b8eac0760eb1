//! Build script: finds MuJoCo, compiles the C shim, links libmujoco and provides bindings.
//!
//! MuJoCo comes from the pinned PyPI wheel (`mujoco==4.0.0`) in the project's `.venv`, or
//! from `MUJOCO_DIR` (a folder holding `libmujoco.so.4.0.0` and `include/mujoco/`).
//! The bindings in `src/mujoco/bindings.rs` were generated ahead for that version; the
//! `bindgen` feature regenerates them (needs libclang).

use std::env;
use std::fs;
use std::path::{Path, PathBuf};

/// The MuJoCo version the pre-generated bindings and the shim were written for.
const MUJOCO_VERSION: &str = "4.0.0";
/// `mjVERSION_HEADER` of that version.
const MUJOCO_VERSION_HEADER: u32 = 4_000_000;

fn main() {
    println!("cargo:rerun-if-env-changed=MUJOCO_DIR");
    println!("cargo:rerun-if-changed=include/tacrom_shim.c");
    println!("cargo:rerun-if-changed=include/tacrom.h");
    println!("cargo:rerun-if-changed=build.rs");

    // The crate is the workspace's root, which holds the `.venv`.
    let crate_dir =
        PathBuf::from(env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let mujoco = find_mujoco(&crate_dir);
    let include = mujoco.join("include");
    check_version(&include);

    let lib = format!("libmujoco.so.{MUJOCO_VERSION}");
    println!("cargo:rustc-link-search=native={}", mujoco.display());
    println!("cargo:rustc-link-lib=dylib:+verbatim={lib}");
    // The wheel's folder stays where it is: an rpath to it lets the library, tests and
    // binaries find libmujoco without LD_LIBRARY_PATH.
    println!("cargo:rustc-link-arg=-Wl,-rpath,{}", mujoco.display());
    println!("cargo:rustc-env=TACROM_MUJOCO_DIR={}", mujoco.display());

    // The shim holds the registration constructor. It must live in the cdylib only: linked
    // into the rlib as well, a test that links the rlib and then loads the cdylib would
    // register the plugin twice. So its objects go to the cdylib's link line alone.
    let objects = cc::Build::new()
        .file("include/tacrom_shim.c")
        .include(&include)
        .include("include")
        .flag_if_supported("-fexceptions")
        .flag_if_supported("-fvisibility=hidden")
        .warnings(true)
        .compile_intermediates();
    for object in objects {
        println!("cargo:rustc-cdylib-link-arg={}", object.display());
    }

    bindings(&include);
    physics_fingerprint(&crate_dir);
}

/// FNV-1a (64 bit) of every source file of the physics (`src/mpm`, `src/geometry`,
/// `src/sensor*`, `src/render*`), in path order, exported as `TACROM_PHYSICS_FINGERPRINT`:
/// the benchmark's reference cache and the reduced-order model's recipe name the solver
/// by it, so a change to the solver invalidates what was computed with the old one.
///
/// `TACROM_RELAXATION_FINGERPRINT` is the same hash over the files a gel solved by dynamic
/// relaxation alone runs: all of them but the other solvers' (`mpm/newton/`,
/// `mpm/linear.rs`, `mpm/total.rs`) and the unit tests. A relaxation reference (the benchmark's fine
/// presses, hours of solver time) then stays valid through a change to Newton's method
/// or the linear solver.
fn physics_fingerprint(crate_dir: &Path) {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        let Ok(entries) = fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    fn fnv<'a>(src: &Path, files: impl Iterator<Item = &'a PathBuf>) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for f in files {
            let rel = f
                .strip_prefix(src)
                .unwrap_or(f)
                .to_string_lossy()
                .into_owned();
            let text = fs::read(f).unwrap_or_default();
            for b in rel.bytes().chain([0]).chain(text).chain([0]) {
                h ^= u64::from(b);
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
        h
    }
    let src = crate_dir.join("src");
    let mut files = Vec::new();
    for entry in [
        "mpm",
        "geometry",
        "sensor",
        "render",
        "sensor.rs",
        "render.rs",
    ] {
        let p = src.join(entry);
        println!("cargo:rerun-if-changed={}", p.display());
        if p.is_dir() {
            walk(&p, &mut files);
        } else if p.is_file() {
            files.push(p);
        }
    }
    files.sort();
    let all = fnv(&src, files.iter());
    println!("cargo:rustc-env=TACROM_PHYSICS_FINGERPRINT={all:016x}");
    let relaxation_runs = |f: &&PathBuf| {
        let rel = f.strip_prefix(&src).unwrap_or(f);
        let name = rel.file_name().and_then(|n| n.to_str()).unwrap_or("");
        !(rel.starts_with("mpm/newton")
            || rel == Path::new("mpm/linear.rs")
            || rel == Path::new("mpm/total.rs")
            || name == "tests.rs"
            || name.ends_with("_tests.rs"))
    };
    let relaxation = fnv(&src, files.iter().filter(relaxation_runs));
    println!("cargo:rustc-env=TACROM_RELAXATION_FINGERPRINT={relaxation:016x}");
}

/// The folder with `libmujoco.so.<version>` and `include/mujoco`.
fn find_mujoco(root: &Path) -> PathBuf {
    let lib = format!("libmujoco.so.{MUJOCO_VERSION}");
    if let Ok(dir) = env::var("MUJOCO_DIR") {
        let dir = PathBuf::from(dir);
        if dir.join(&lib).is_file() && dir.join("include/mujoco/mujoco.h").is_file() {
            return dir;
        }
        panic!(
            "MUJOCO_DIR={} does not hold {lib} and include/mujoco/mujoco.h; point it at the \
             `mujoco` folder of an installed mujoco=={MUJOCO_VERSION} wheel",
            dir.display()
        );
    }
    let venv_lib = root.join(".venv/lib");
    if let Ok(entries) = fs::read_dir(&venv_lib) {
        let mut pythons: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
        pythons.sort();
        for python in pythons {
            let dir = python.join("site-packages/mujoco");
            if dir.join(&lib).is_file() {
                return dir;
            }
        }
    }
    panic!(
        "MuJoCo {MUJOCO_VERSION} not found. Run `make venv` (it installs the pinned \
         mujoco=={MUJOCO_VERSION} wheel into .venv), or set MUJOCO_DIR to a folder holding \
         {lib} and include/mujoco/."
    );
}

/// Refuses a MuJoCo whose headers are not the version the bindings were made for.
fn check_version(include: &Path) {
    let header = include.join("mujoco/mujoco.h");
    println!("cargo:rerun-if-changed={}", header.display());
    let text = fs::read_to_string(&header)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", header.display()));
    let found = text
        .lines()
        .find_map(|l| l.strip_prefix("#define mjVERSION_HEADER"))
        .and_then(|v| v.trim().parse::<u32>().ok());
    if found != Some(MUJOCO_VERSION_HEADER) && env::var_os("CARGO_FEATURE_BINDGEN").is_none() {
        panic!(
            "{} declares mjVERSION_HEADER {:?}, but tacrom's bindings are for MuJoCo \
             {MUJOCO_VERSION} ({MUJOCO_VERSION_HEADER}). Install mujoco=={MUJOCO_VERSION} \
             (`make venv`), or build with `--features bindgen` to regenerate the bindings \
             for this version.",
            header.display(),
            found
        );
    }
}

#[cfg(not(feature = "bindgen"))]
fn bindings(_include: &Path) {}

#[cfg(feature = "bindgen")]
fn bindings(include: &Path) {
    let out = PathBuf::from(env::var("OUT_DIR").expect("cargo sets OUT_DIR")).join("bindings.rs");
    bindgen::Builder::default()
        .header(include.join("mujoco/mujoco.h").to_string_lossy())
        .clang_arg(format!("-I{}", include.display()))
        // `mjv_initGeom`: the plugin's `visualize` callback fills scene geoms with it.
        .allowlist_function("mj_.*|mju_.*|mjp_.*|mjv_initGeom")
        .allowlist_type("mj.*")
        .allowlist_var("mj.*")
        .layout_tests(false)
        .derive_default(false)
        .prepend_enum_name(false)
        .generate()
        .expect("bindgen failed on mujoco.h")
        .write_to_file(&out)
        .expect("cannot write bindings");
}
