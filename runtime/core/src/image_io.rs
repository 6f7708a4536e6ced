//! Reading and writing images with every input problem named: missing or
//! unreadable files, non-RGB and 16-bit images (converted, and said so),
//! transparency (rejected), NaN/Inf or out-of-range values (rejected).

use std::path::Path;

use image::{DynamicImage, ImageBuffer, Rgb};

use super::image::Image;

/// The test image used when no `--input` is given (data/images/test/astronaut.png),
/// embedded so that a fresh checkout runs from any directory.
pub const DEFAULT_INPUT_PNG: &[u8] = include_bytes!("../../../data/images/test/astronaut.png");
pub const DEFAULT_INPUT_NAME: &str = "data/images/test/astronaut.png";

#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("{path}: cannot read image: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot decode image: {reason}")]
    Decode { path: String, reason: String },
    #[error("{path}: {reason}")]
    Invalid { path: String, reason: String },
    #[error("{path}: cannot write image: {reason}")]
    Write { path: String, reason: String },
}

/// A decoded input image and what was done to it on the way in.
#[derive(Debug, Clone)]
pub struct LoadedImage {
    pub image: Image,
    pub notes: Vec<String>,
}

/// The largest image file read (a 16-bit 8K TIFF is about 200 MB).
pub const MAX_IMAGE_FILE_BYTES: u64 = 512 << 20;
/// The largest image decoded: 8K UHD (7680×4320 = 33.2 Mpx) fits; the
/// loader holds about 24 bytes a pixel, so this bounds it near 800 MB
/// whatever a header claims.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 25;
/// The longest image side (the panel's own limit, `calib::MAX_PANEL_SIDE_PX`).
pub const MAX_IMAGE_SIDE_PX: u32 = crate::calib::MAX_PANEL_SIDE_PX as u32;

/// Reads an RGB image as linear intensity in [0, 1].
pub fn load(path: &Path) -> Result<LoadedImage, ImageError> {
    load_limited(path, None)
}

/// Reads an image that a `width`×`height` panel is to show: a larger one
/// is refused from its header, before anything is decoded (a 224-byte
/// JPEG can claim 20 megapixels, and simulating those takes 10 GB).
pub fn load_for_panel(path: &Path, panel: (usize, usize)) -> Result<LoadedImage, ImageError> {
    load_limited(path, Some(panel))
}

fn load_limited(path: &Path, panel: Option<(usize, usize)>) -> Result<LoadedImage, ImageError> {
    let name = path.display().to_string();
    let bytes = crate::util::read_capped(path, MAX_IMAGE_FILE_BYTES).map_err(|source| {
        ImageError::Read {
            path: name.clone(),
            source,
        }
    })?;
    decode_limited(&bytes, &name, panel)
}

/// Decodes image bytes; `name` is used in messages.
pub fn decode(bytes: &[u8], name: &str) -> Result<LoadedImage, ImageError> {
    decode_limited(bytes, name, None)
}

/// Decodes image bytes for a `width`×`height` panel ([`load_for_panel`]).
pub fn decode_for_panel(
    bytes: &[u8],
    name: &str,
    panel: (usize, usize),
) -> Result<LoadedImage, ImageError> {
    decode_limited(bytes, name, Some(panel))
}

fn decode_limited(
    bytes: &[u8],
    name: &str,
    panel: Option<(usize, usize)>,
) -> Result<LoadedImage, ImageError> {
    let invalid = |reason: String| ImageError::Invalid {
        path: name.to_string(),
        reason,
    };
    let undecodable = |e: &dyn std::fmt::Display| ImageError::Decode {
        path: name.to_string(),
        reason: crate::util::bounded(&e.to_string(), 300),
    };
    let open = || {
        image::ImageReader::new(std::io::Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| undecodable(&e))
    };
    // The header's size is checked before anything is allocated for it.
    let (w, h) = open()?.into_dimensions().map_err(|e| undecodable(&e))?;
    if let Some((pw, ph)) = panel
        && (w as usize > pw || h as usize > ph)
    {
        return Err(invalid(format!(
            "{w}×{h} image is larger than the {pw}×{ph} panel that shows it; crop or scale it"
        )));
    }
    if w > MAX_IMAGE_SIDE_PX
        || h > MAX_IMAGE_SIDE_PX
        || u64::from(w) * u64::from(h) > MAX_IMAGE_PIXELS
    {
        return Err(invalid(format!(
            "{w}×{h} image is larger than this loader takes (at most {MAX_IMAGE_SIDE_PX} px a \
             side and {MAX_IMAGE_PIXELS} pixels)"
        )));
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE_PX);
    limits.max_image_height = Some(MAX_IMAGE_SIDE_PX);
    // A 16-bit RGBA frame of the largest size, with room for the decoder's own buffers.
    limits.max_alloc = Some(MAX_IMAGE_PIXELS * 8 * 2);
    let mut reader = open()?;
    reader.limits(limits);
    let img = reader.decode().map_err(|e| undecodable(&e))?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    if w == 0 || h == 0 {
        return Err(invalid("image is empty".into()));
    }
    let mut notes = Vec::new();
    let color = img.color();
    if color.has_alpha() {
        let rgba = img.to_rgba32f();
        if let Some((x, y, _)) = rgba.enumerate_pixels().find(|(_, _, p)| p.0[3] < 1.0) {
            return Err(invalid(format!(
                "has transparency (pixel {x},{y} is not opaque); flatten it onto a background first"
            )));
        }
        notes.push(format!("{name}: opaque alpha channel dropped"));
    }
    if !color.has_color() {
        notes.push(format!(
            "{name}: grayscale image converted to RGB (channel repeated)"
        ));
    }
    let bits = color.bits_per_pixel() / color.channel_count() as u16;
    if bits == 16 {
        notes.push(format!(
            "{name}: 16-bit image converted to floating point at full precision"
        ));
    }
    let rgb = img.to_rgb32f();
    let mut planes: Vec<Vec<f32>> = (0..3).map(|_| Vec::with_capacity(w * h)).collect();
    for (x, y, p) in rgb.enumerate_pixels() {
        for (c, v) in p.0.iter().enumerate() {
            if !v.is_finite() {
                return Err(invalid(format!(
                    "pixel {x},{y} channel {c} is {v} (not finite)"
                )));
            }
            if !(0.0..=1.0).contains(v) {
                return Err(invalid(format!(
                    "pixel {x},{y} channel {c} is {v}; display intensities lie in [0, 1]"
                )));
            }
            planes[c].push(*v);
        }
    }
    if matches!(
        img,
        DynamicImage::ImageRgb32F(_) | DynamicImage::ImageRgba32F(_)
    ) {
        notes.push(format!(
            "{name}: floating-point image read as linear intensity"
        ));
    }
    Ok(LoadedImage {
        image: Image::from_planes(w, h, planes),
        notes,
    })
}

/// Writes an RGB image, clamped to [0, 1], as a 16-bit PNG (the only
/// format, so no precision is lost silently), atomically.
pub fn save_png16(image: &Image, path: &Path) -> Result<(), ImageError> {
    save(image, path, &["png"])
}

/// The lower-case extension of `path` if it is one of `allowed`, else an
/// error naming the file and the formats it could be.
pub fn check_extension(path: &Path, allowed: &[&str]) -> Result<String, ImageError> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if allowed.contains(&ext.as_str()) {
        return Ok(ext);
    }
    Err(ImageError::Write {
        path: path.display().to_string(),
        reason: format!(
            "unsupported extension {ext:?}; write {}",
            allowed
                .iter()
                .map(|e| format!(".{e}"))
                .collect::<Vec<_>>()
                .join(" or ")
        ),
    })
}

/// Writes an RGB image, atomically: `.png` as 16-bit PNG (clamped to
/// [0, 1]), `.tif`/`.tiff` as 32-bit float TIFF (exact: every f32 value as
/// computed, for comparing display frames bit for bit).
pub fn save(image: &Image, path: &Path, allowed: &[&str]) -> Result<(), ImageError> {
    let name = path.display().to_string();
    let ext = check_extension(path, allowed)?;
    if image.channels() != 3 {
        return Err(ImageError::Write {
            path: name,
            reason: format!("{} channels; RGB needs 3", image.channels()),
        });
    }
    let (w, h) = (image.width as u32, image.height as u32);
    let value = |x: u32, y: u32, c: usize| image.plane(c)[y as usize * image.width + x as usize];
    let (dynamic, format) = if ext == "png" {
        let buf: ImageBuffer<Rgb<u16>, Vec<u16>> = ImageBuffer::from_fn(w, h, |x, y| {
            Rgb(std::array::from_fn(|c| {
                (value(x, y, c).clamp(0.0, 1.0) * 65535.0).round() as u16
            }))
        });
        (DynamicImage::ImageRgb16(buf), image::ImageFormat::Png)
    } else {
        let buf: ImageBuffer<Rgb<f32>, Vec<f32>> =
            ImageBuffer::from_fn(w, h, |x, y| Rgb(std::array::from_fn(|c| value(x, y, c))));
        (DynamicImage::ImageRgb32F(buf), image::ImageFormat::Tiff)
    };
    let mut bytes = Vec::new();
    dynamic
        .write_to(&mut std::io::Cursor::new(&mut bytes), format)
        .map_err(|e| ImageError::Write {
            path: name.clone(),
            reason: e.to_string(),
        })?;
    crate::util::write_atomic(path, &bytes).map_err(|e| ImageError::Write {
        path: name,
        reason: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{GrayImage, ImageBuffer, Luma, Rgb32FImage, Rgba, RgbaImage};

    fn encode(img: DynamicImage, format: image::ImageFormat) -> Vec<u8> {
        let mut b = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut b), format)
            .expect("encode");
        b
    }

    #[test]
    fn sizes_are_refused_from_the_header_before_decoding() {
        // 40000×1: past the loader's own side cap; 30×20: past a 24×16 panel.
        let wide = encode(
            DynamicImage::ImageLuma8(GrayImage::new(40000, 1)),
            image::ImageFormat::Png,
        );
        let e = decode(&wide, "wide.png").expect_err("past the cap");
        assert!(
            e.to_string()
                .contains("wide.png: 40000×1 image is larger than this loader takes"),
            "{e}"
        );
        let small = encode(
            DynamicImage::ImageLuma8(GrayImage::new(30, 20)),
            image::ImageFormat::Png,
        );
        assert!(decode(&small, "small.png").is_ok());
        let e = decode_for_panel(&small, "small.png", (24, 16)).expect_err("past the panel");
        assert!(
            e.to_string()
                .contains("30×20 image is larger than the 24×16 panel that shows it"),
            "{e}"
        );
        assert!(decode_for_panel(&small, "small.png", (30, 20)).is_ok());
    }

    #[test]
    fn default_input_decodes_as_rgb() {
        let l = decode(DEFAULT_INPUT_PNG, DEFAULT_INPUT_NAME).expect("decode");
        assert_eq!(
            (l.image.width, l.image.height, l.image.channels()),
            (512, 512, 3)
        );
        assert!(l.notes.is_empty());
    }

    #[test]
    fn grayscale_and_16_bit_are_converted_with_a_note() {
        let g = GrayImage::from_pixel(8, 8, Luma([128]));
        let l = decode(
            &encode(DynamicImage::ImageLuma8(g), image::ImageFormat::Png),
            "g.png",
        )
        .expect("ok");
        assert!(l.notes.iter().any(|n| n.contains("grayscale")));
        assert_eq!(l.image.plane(0), l.image.plane(2));
        let g16: ImageBuffer<Luma<u16>, Vec<u16>> = ImageBuffer::from_pixel(8, 8, Luma([40000]));
        let l = decode(
            &encode(DynamicImage::ImageLuma16(g16), image::ImageFormat::Png),
            "g16.png",
        )
        .expect("ok");
        assert!(l.notes.iter().any(|n| n.contains("16-bit")));
        assert!((l.image.plane(1)[0] - 40000.0 / 65535.0).abs() < 1e-6);
    }

    #[test]
    fn transparency_is_rejected_opaque_alpha_dropped() {
        let mut im = RgbaImage::from_pixel(4, 4, Rgba([10, 20, 30, 255]));
        let ok = decode(
            &encode(
                DynamicImage::ImageRgba8(im.clone()),
                image::ImageFormat::Png,
            ),
            "a.png",
        )
        .expect("opaque");
        assert!(ok.notes.iter().any(|n| n.contains("alpha")));
        im.put_pixel(1, 2, Rgba([0, 0, 0, 10]));
        let e = decode(
            &encode(DynamicImage::ImageRgba8(im), image::ImageFormat::Png),
            "a.png",
        )
        .expect_err("alpha");
        assert!(e.to_string().contains("transparency (pixel 1,2"), "{e}");
    }

    #[test]
    fn nan_inf_and_out_of_range_are_rejected() {
        for (bad, what) in [
            (f32::NAN, "not finite"),
            (f32::INFINITY, "not finite"),
            (1.5, "[0, 1]"),
            (-0.1, "[0, 1]"),
        ] {
            let mut im = Rgb32FImage::from_pixel(4, 4, image::Rgb([0.5, 0.5, 0.5]));
            im.put_pixel(3, 1, image::Rgb([0.5, bad, 0.5]));
            let b = encode(DynamicImage::ImageRgb32F(im), image::ImageFormat::Tiff);
            let e = decode(&b, "f.tif").expect_err("bad pixel");
            assert!(
                e.to_string().contains("pixel 3,1 channel 1") && e.to_string().contains(what),
                "{e}"
            );
        }
    }

    #[test]
    fn garbage_and_missing_files_are_errors() {
        assert!(matches!(
            decode(b"nope", "x.png"),
            Err(ImageError::Decode { .. })
        ));
        let e = load(Path::new("/definitely/not/here.png")).expect_err("missing");
        assert!(
            e.to_string()
                .starts_with("/definitely/not/here.png: cannot read image"),
            "{e}"
        );
    }

    #[test]
    fn png16_round_trip() {
        let dir = tempfile::tempdir().expect("tmp");
        let p = dir.path().join("o.png");
        let im = Image::from_planes(3, 2, vec![vec![0.0, 0.5, 1.0, 0.25, 0.75, 0.1]; 3]);
        save_png16(&im, &p).expect("save");
        let back = load(&p).expect("load").image;
        for (a, b) in back.plane(0).iter().zip(im.plane(0)) {
            assert!((a - b).abs() < 1.0 / 65535.0);
        }
        assert!(save_png16(&im, &dir.path().join("o.jpg")).is_err());
    }
}
