//! Writes tests/golden/radial.json, the radial path's golden vectors for the
//! trainer's radial model (layout: `nedrt_optics::radial_golden`, and the
//! file's own `layout` and `conventions` fields):
//!
//!     cargo run --release --example make_radial_golden [-- OUT.json]
//!
//! The 2-D runs at a 3 µm pupil step take a few minutes on two cores.

use std::path::PathBuf;

fn main() -> anyhow::Result<()> {
    let out = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("tests/golden/radial.json"));
    let calib = nedrt_core::calib::Calibration::default_embedded()?;
    let v = nedrt_optics::radial_golden::vectors(&calib)?;
    for p in v["psfs"].as_array().into_iter().flatten() {
        println!(
            "{} {} D {}: max |radial − 2-D| = {:.2e} of the peak",
            p["channel"],
            p["accommodation_d"],
            p["optics"],
            p["max_abs_radial_minus_two_d_of_peak"]
                .as_f64()
                .unwrap_or(f64::NAN)
        );
    }
    nedrt_core::util::write_atomic(&out, serde_json::to_string(&v)?.as_bytes())?;
    println!("wrote {}", out.display());
    Ok(())
}
