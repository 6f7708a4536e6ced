//! Imports the benchmark's ONNX models into burn at build time (burn-onnx's
//! `ModelGen`: Rust code plus the trained weights as a burnpack, embedded in
//! the binary), and records a hash of each ONNX file so that the binary can
//! check, at run time, that nedrt reads the very file burn was built from.

use std::path::Path;
use std::process::exit;

use burn_onnx::{LoadStrategy, ModelGen};

/// (ONNX path relative to this crate, environment variable for its hash).
const MODELS: [(&str, &str); 2] = [
    // The shipped, trained network (width 16).
    ("../../models/dcnn.onnx", "NEDRT_BENCH_FNV_DCNN"),
    // The full-width architecture (width 32), random weights: make-models.sh.
    ("models/dcnn_w32.onnx", "NEDRT_BENCH_FNV_DCNN_W32"),
];

/// FNV-1a, 64 bits: the same function as the binary's `fnv1a64`.
fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// The version of `name` in Cargo.lock, for the report.
fn locked_version(lock: &str, name: &str) -> Option<String> {
    let mut lines = lock.lines();
    while let Some(line) = lines.next() {
        if line == format!("name = \"{name}\"") {
            return lines
                .next()?
                .strip_prefix("version = \"")?
                .strip_suffix('"')
                .map(str::to_string);
        }
    }
    None
}

fn main() {
    let mut generator = ModelGen::new();
    for (path, var) in MODELS {
        println!("cargo:rerun-if-changed={path}");
        let bytes = match std::fs::read(path) {
            Ok(b) => b,
            Err(e) => {
                eprintln!(
                    "error: cannot read {path} ({e}). The shipped model is models/dcnn.onnx at the \
                     repository root; the full-width one is made by `./make-models.sh` in bench/burn."
                );
                exit(1);
            }
        };
        println!("cargo:rustc-env={var}={:016x}", fnv1a64(&bytes));
        generator.input(path);
    }
    println!("cargo:rerun-if-changed=Cargo.lock");
    let lock = std::fs::read_to_string("Cargo.lock").unwrap_or_default();
    for (crate_name, var) in [
        ("burn", "NEDRT_BENCH_BURN_VERSION"),
        ("burn-onnx", "NEDRT_BENCH_BURN_ONNX_VERSION"),
        ("wgpu", "NEDRT_BENCH_WGPU_VERSION"),
    ] {
        let v = locked_version(&lock, crate_name).unwrap_or_else(|| "unknown".into());
        println!("cargo:rustc-env={var}={v}");
    }
    // Embedded weights: the binary cannot lose its burnpack, and it never
    // falls back to random initialisation (`Model::new` would).
    generator
        .out_dir("model/")
        .load_strategy(LoadStrategy::Embedded)
        .run_from_script();
    if !Path::new(&std::env::var("OUT_DIR").unwrap_or_default())
        .join("model/dcnn.rs")
        .exists()
    {
        eprintln!("error: burn-onnx wrote no model/dcnn.rs");
        exit(1);
    }
}
