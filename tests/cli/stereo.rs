//! `nedrt run` with two views (issue 33): each eye its own design, and each
//! half of the recorded panel is what `nedrt sim --display-out` gives for
//! that eye's design on that half of the input, in panel codes.

use super::*;

use nedrt_core::calib::Calibration;
use nedrt_service::present::transfer::Transfer;

/// The small-aperture calibration on a 64×48 panel at 240 Hz with two
/// `[[view]]` tables: left the multifocal design, right the all-sharp one.
pub(super) fn stereo_calibration(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(small_calib()).expect("small-aperture.toml");
    let text = text
        .replace("width_px = 1920", "width_px = 64")
        .replace("height_px = 1080", "height_px = 48")
        .replace("refresh_hz = 90.0", "refresh_hz = 240.0");
    let designs = repo().join("designs");
    let views = format!(
        "\n[[view]]\nname = \"left\"\nregion_px = [0, 0, 32, 48]\ndesign = {:?}\n\n\
         [[view]]\nname = \"right\"\nregion_px = [32, 0, 32, 48]\ndesign = {:?}\n",
        designs.join("multifocal.toml").display().to_string(),
        designs.join("allsharp.toml").display().to_string()
    );
    let path = dir.join("stereo.toml");
    std::fs::write(&path, text + &views).expect("write calibration");
    path
}

/// A smooth colour test image, `w`×`h`.
fn picture(w: u32, h: u32) -> image::RgbImage {
    image::RgbImage::from_fn(w, h, |x, y| {
        let v = |k: f32| {
            (127.0 + 120.0 * ((x as f32 * 0.31 + k).sin() * (y as f32 * 0.17 - k).cos())) as u8
        };
        image::Rgb([v(0.0), v(1.1), v(2.3)])
    })
}

#[test]
fn each_eye_shows_what_sim_gives_for_its_own_design() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = stereo_calibration(dir.path());
    let input = dir.path().join("input.png");
    picture(64, 48).save(&input).expect("input");
    let rec = dir.path().join("rec");
    let o = nedrt()
        .current_dir(repo())
        .args(["--calib", path(&calib), "run", "--preprocess", "doe+wiener"])
        .args(["--source", "dir", "--input", path(&input), "--frames", "1"])
        .args(["--sink", "record", "--record-dir", path(&rec)])
        .output_within(deadline::COMMAND, "nedrt run");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("2 views"), "{}", stderr(&o));
    let recorded = image::open(rec.join("frame-00000000.png"))
        .expect("recorded")
        .to_rgb8();
    assert_eq!(recorded.dimensions(), (64, 48));
    let panel = Calibration::load(&calib).expect("calibration").panel;
    let transfer = Transfer::from_panel(&panel);
    // The worst code difference between the recorded half at `x0` and
    // what sim gives for `design` on that half of the input.
    let worst_against = |x0: u32, design: &str| -> u8 {
        let half = dir.path().join(format!("half-{x0}.png"));
        image::imageops::crop_imm(&picture(64, 48), x0, 0, 32, 48)
            .to_image()
            .save(&half)
            .expect("half");
        let display = dir.path().join(format!("display-{x0}-{design}.tif"));
        let o = nedrt()
            .current_dir(repo())
            .args(["--calib", path(&small_calib()), "--design", design])
            .args(["sim", "--method", "doe+wiener", "--accom", "1.5"])
            .args([
                "--input",
                path(&half),
                "--out",
                path(&dir.path().join("p.png")),
            ])
            .args(["--display-out", path(&display)])
            .output_within(deadline::COMMAND, "nedrt sim");
        assert!(o.status.success(), "{}", stderr(&o));
        let display = nedrt_core::image_io::load(&display)
            .expect("display image")
            .image;
        let mut codes = Vec::new();
        transfer.encode_rgba8(&display, &mut codes);
        let mut worst = 0u8;
        for y in 0..48u32 {
            for x in 0..32u32 {
                let got = recorded.get_pixel(x0 + x, y).0;
                for c in 0..3 {
                    let want = codes[4 * (y * 32 + x) as usize + c];
                    worst = worst.max(got[c].abs_diff(want));
                }
            }
        }
        worst
    };
    for (x0, design) in [(0u32, "multifocal"), (32, "allsharp")] {
        let worst = worst_against(x0, design);
        assert!(worst <= 1, "{design}: codes differ by {worst}");
    }
    // The test tells the designs apart: the right eye is not the left's design.
    assert!(
        worst_against(32, "multifocal") > 1,
        "the designs show alike"
    );
}
