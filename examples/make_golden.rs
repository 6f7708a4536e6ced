//! Writes tests/golden/vectors.json, the golden vectors the Python trainer
//! and the Rust tests check against:
//!
//!     cargo run --release --example make_golden [-- OUT.json]

use std::path::PathBuf;

fn main() -> anyhow::Result<()> {
    let out = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("tests/golden/vectors.json"));
    let calib = nedrt_core::calib::Calibration::default_embedded()?;
    let v = nedrt_optics::golden::vectors(&calib);
    nedrt_core::util::write_atomic(&out, serde_json::to_string(&v)?.as_bytes())?;
    println!("wrote {}", out.display());
    Ok(())
}
