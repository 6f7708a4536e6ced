//! Focus sweeps as animated files that play anywhere: animated PNG
//! (lossless: every frame's codes are the viewer's) or GIF (256 colours a
//! frame, for slide software that lacks APNG), looping forever.

use std::path::Path;

use super::compose::Picture;
use crate::AppError;

/// The formats a sweep is written in, by extension.
pub const SWEEP_FORMATS: &[&str] = &["png", "apng", "gif"];

/// Checks a sweep's file name and rate before any work is done for it.
pub fn check_request(path: &Path, fps: f64) -> Result<String, AppError> {
    let ext = nedrt_core::image_io::check_extension(path, SWEEP_FORMATS)?;
    if !(fps.is_finite() && (0.1..=100.0).contains(&fps)) {
        return Err(AppError::option(
            format!("--fps {fps}"),
            "frames a second must lie in [0.1, 100]",
        ));
    }
    if ext == "gif" && fps > 50.0 {
        return Err(AppError::option(
            format!("--fps {fps}"),
            "a GIF plays at most 50 frames a second (delays in hundredths of a second); \
             write .png for more",
        ));
    }
    Ok(ext)
}

/// Encodes `frames` (all one size) shown `fps` times a second and writes
/// them to `path` atomically; the extension picks the format.
pub fn write(path: &Path, frames: &[Picture], fps: f64) -> Result<(), AppError> {
    let ext = check_request(path, fps)?;
    let Some(first) = frames.first() else {
        return Err(AppError::output(path, "no frames to write"));
    };
    if frames
        .iter()
        .any(|f| (f.width, f.height) != (first.width, first.height))
    {
        return Err(AppError::output(path, "frames differ in size"));
    }
    let bytes = match ext.as_str() {
        "gif" => gif(frames, fps),
        _ => apng(frames, fps),
    }
    .map_err(|e| AppError::output(path, e))?;
    nedrt_core::util::write_atomic(path, &bytes).map_err(|e| AppError::output(path, e))
}

fn apng(frames: &[Picture], fps: f64) -> Result<Vec<u8>, String> {
    let (w, h) = (frames[0].width as u32, frames[0].height as u32);
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, w, h);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let frame_count = u32::try_from(frames.len()).map_err(|e| e.to_string())?;
    encoder
        .set_animated(frame_count, 0)
        .map_err(|e| e.to_string())?;
    // The delay as a fraction of a second: milliseconds over 1000.
    let delay_ms = (1000.0 / fps).round().clamp(1.0, 10_000.0) as u16;
    encoder
        .set_frame_delay(delay_ms, 1000)
        .map_err(|e| e.to_string())?;
    let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
    for f in frames {
        writer
            .write_image_data(&f.rgb8)
            .map_err(|e| e.to_string())?;
    }
    writer.finish().map_err(|e| e.to_string())?;
    Ok(out)
}

fn gif(frames: &[Picture], fps: f64) -> Result<Vec<u8>, String> {
    use image::codecs::gif::{GifEncoder, Repeat};
    use image::{Delay, Frame, RgbaImage};
    let mut out = Vec::new();
    {
        let mut encoder = GifEncoder::new_with_speed(&mut out, 10);
        encoder
            .set_repeat(Repeat::Infinite)
            .map_err(|e| e.to_string())?;
        // GIF counts delays in hundredths of a second, and players treat
        // one hundredth as ten: whole hundredths, at least two.
        let hundredths = (100.0 / fps).round().max(2.0) as u32;
        let delay = Delay::from_numer_denom_ms(10 * hundredths, 1);
        for f in frames {
            let rgba = RgbaImage::from_raw(f.width as u32, f.height as u32, f.rgba8())
                .ok_or("frame buffer of the wrong size")?;
            encoder
                .encode_frame(Frame::from_parts(rgba, 0, 0, delay))
                .map_err(|e| e.to_string())?;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::AnimationDecoder;

    fn picture(v: u8) -> Picture {
        Picture {
            width: 5,
            height: 3,
            rgb8: (0..45).map(|i| v.wrapping_add(i as u8)).collect(),
        }
    }

    #[test]
    fn an_apng_holds_every_frame_code_for_code() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("s.png");
        let frames = [picture(0), picture(100), picture(200)];
        write(&path, &frames, 4.0).expect("write");
        let file = std::io::BufReader::new(std::fs::File::open(&path).expect("open"));
        let decoder = image::codecs::png::PngDecoder::new(file).expect("png");
        assert!(decoder.is_apng().expect("apng?"));
        let decoded: Vec<_> = decoder
            .apng()
            .expect("apng")
            .into_frames()
            .collect_frames()
            .expect("frames");
        assert_eq!(decoded.len(), 3);
        for (d, f) in decoded.iter().zip(&frames) {
            assert_eq!(d.delay().numer_denom_ms(), (250, 1));
            let rgb: Vec<u8> = d
                .buffer()
                .pixels()
                .flat_map(|p| [p[0], p[1], p[2]])
                .collect();
            assert_eq!(rgb, f.rgb8);
        }
    }

    #[test]
    fn a_gif_loops_with_every_frame() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("s.gif");
        write(&path, &[picture(0), picture(9)], 10.0).expect("write");
        let file = std::io::BufReader::new(std::fs::File::open(&path).expect("open"));
        let decoded = image::codecs::gif::GifDecoder::new(file)
            .expect("gif")
            .into_frames()
            .collect_frames()
            .expect("frames");
        assert_eq!(decoded.len(), 2);
        assert_eq!(decoded[0].buffer().dimensions(), (5, 3));
    }

    #[test]
    fn bad_requests_name_the_file_and_write_nothing() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("s.mp4");
        let e = write(&path, &[picture(0)], 4.0).expect_err("mp4");
        assert!(e.to_string().contains("s.mp4"), "{e}");
        let path = dir.path().join("s.png");
        let e = write(&path, &[], 4.0).expect_err("empty");
        assert!(e.to_string().contains("no frames"), "{e}");
        let e = write(&path, &[picture(0)], 0.0).expect_err("fps");
        assert!(e.to_string().contains("--fps"), "{e}");
        assert!(!path.exists());
    }
}
