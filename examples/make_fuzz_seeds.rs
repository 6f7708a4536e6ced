//! Writes the fuzz targets' seed corpora (fuzz/seeds/<target>, committed;
//! scripts/fuzz.sh and docs/reliability.md): the repo's own calibrations
//! and DOE files, plus small valid inputs made here with the project's own
//! encoders, so every target starts from inputs that pass its parser and
//! libFuzzer mutates from deep inside it.
//!
//!     cargo run --example make_fuzz_seeds [-- OUT_DIR]

use std::path::{Path, PathBuf};

use nedrt_core::Image;
use nedrt_protocol::Placement;
use nedrt_protocol::v2::{HEADER_V2_LEN, HeaderV2, QuadFormat, VERSION_2};
use nedrt_protocol::{FrameHeader, Hello};
use nedrt_service::pipeline::frame::{PixelFormat, planar_payload};

fn write(dir: &Path, name: &str, bytes: &[u8]) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)?;
    nedrt_core::util::write_atomic(&dir.join(name), bytes)?;
    Ok(())
}

fn copy(dir: &Path, from: &str) -> anyhow::Result<()> {
    let name = from.replace('/', "_");
    write(dir, &name, &std::fs::read(from)?)
}

/// An 8×6 test pattern with values in [0, 1].
fn pattern(w: usize, h: usize) -> Image {
    let data = (0..3 * w * h)
        .map(|i| ((i * 37) % 101) as f32 / 100.0)
        .collect();
    Image::rgb(w, h, data)
}

fn encoded(img: image::DynamicImage, format: image::ImageFormat) -> anyhow::Result<Vec<u8>> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, format)?;
    Ok(out.into_inner())
}

fn main() -> anyhow::Result<()> {
    let root = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("fuzz/seeds"));

    let calib = root.join("calibration");
    for f in [
        "calib/default.toml",
        "tests/data/small-panel.toml",
        "tests/data/small-aperture.toml",
    ] {
        copy(&calib, f)?;
    }

    let doe = root.join("doe_file");
    for f in [
        "designs/multifocal/doe-design.safetensors",
        "designs/multifocal/doe-fabrication.safetensors",
        "designs/allsharp/doe-fabrication.safetensors",
    ] {
        copy(&doe, f)?;
    }

    // The trainer's U-Net, node for node, at the smallest width and depth
    // that still has every operator (conv, pool, transposed conv, concat).
    let onnx = root.join("onnx_model");
    for (width, levels) in [(2, 2), (2, 3)] {
        let model = nedrt_infer::synth::unet(width, levels, 1);
        write(
            &onnx,
            &format!("unet-w{width}-l{levels}.onnx"),
            &nedrt_infer::synth::encode(&model),
        )?;
    }

    // A hello, its name, then frames for the 64×48 test panel: the
    // payload follows the headers, at the offset the header names.
    let protocol = root.join("protocol");
    let (w, h) = (64usize, 48usize);
    for format in [
        PixelFormat::Rgba8Linear,
        PixelFormat::Rgba8Srgb,
        PixelFormat::Rgb32fPlanar,
    ] {
        let name = b"nedrt-seed";
        let payload = match format {
            PixelFormat::Rgb32fPlanar => planar_payload(&pattern(w, h)),
            _ => (0..w * h * 4).map(|i| (i * 7 % 256) as u8).collect(),
        };
        let headers_len = 2 * nedrt_protocol::HEADER_LEN;
        let mut bytes = Hello {
            name_len: name.len(),
            shm_size: (headers_len + payload.len()) as u64,
        }
        .to_bytes()
        .to_vec();
        bytes.extend_from_slice(name);
        for id in 0..2 {
            let mut header = FrameHeader::new(format, w, h, id, 1_000 + id);
            header.offset = headers_len as u64;
            bytes.extend_from_slice(&header.to_bytes());
        }
        bytes.extend_from_slice(&payload);
        write(&protocol, &format!("{format:?}.bin"), &bytes)?;
    }

    // Version 2: a projection frame, a quad in pixels, one in degrees,
    // and the removal of the first, their payloads after the headers.
    {
        let name = b"nedrt-seed";
        let frame = (0..w * h * 4)
            .map(|i| (i * 7 % 256) as u8)
            .collect::<Vec<u8>>();
        let quad: Vec<u8> = (0..6 * 4)
            .flat_map(|i| {
                let a = (i * 11 % 256) as u8;
                [a / 2, a / 3, a, a]
            })
            .collect();
        let headers_len = (4 * HEADER_V2_LEN) as u64;
        let quad_at = headers_len + frame.len() as u64;
        let headers = [
            HeaderV2 {
                offset: headers_len,
                ..HeaderV2::projection(0, PixelFormat::Rgba8Linear, (w, h), 1, 1_000)
            },
            HeaderV2::quad(
                0,
                7,
                1,
                Placement::Pixels { x: 3, y: 2 },
                QuadFormat::Rgba8Premultiplied,
                (6, 4),
                2,
                quad_at,
            ),
            HeaderV2::quad(
                0,
                8,
                -1,
                Placement::Degrees {
                    x_deg: 0.1,
                    y_deg: -0.05,
                },
                QuadFormat::Rgba8Premultiplied,
                (6, 4),
                3,
                quad_at,
            ),
            HeaderV2::remove(0, 7, 4),
        ];
        let mut bytes = Hello {
            name_len: name.len(),
            shm_size: quad_at + quad.len() as u64,
        }
        .to_bytes_version(VERSION_2)
        .to_vec();
        bytes.extend_from_slice(name);
        for header in &headers {
            bytes.extend_from_slice(&header.to_bytes());
        }
        bytes.extend_from_slice(&frame);
        bytes.extend_from_slice(&quad);
        write(&protocol, "v2-layers.bin", &bytes)?;
    }

    let images = root.join("image");
    let small = pattern(8, 6);
    let rgb8 = image::RgbImage::from_fn(8, 6, |x, y| {
        let v = |c: usize| (small.data()[c * 48 + (y * 8 + x) as usize] * 255.0) as u8;
        image::Rgb([v(0), v(1), v(2)])
    });
    let dynamic = image::DynamicImage::ImageRgb8(rgb8);
    for (name, img, format) in [
        ("rgb8.png", dynamic.clone(), image::ImageFormat::Png),
        (
            "rgb16.png",
            image::DynamicImage::ImageRgb16(dynamic.to_rgb16()),
            image::ImageFormat::Png,
        ),
        (
            "gray8.png",
            image::DynamicImage::ImageLuma8(dynamic.to_luma8()),
            image::ImageFormat::Png,
        ),
        (
            "rgba8.png",
            image::DynamicImage::ImageRgba8(dynamic.to_rgba8()),
            image::ImageFormat::Png,
        ),
        ("rgb8.jpg", dynamic.clone(), image::ImageFormat::Jpeg),
        ("rgb8.bmp", dynamic.clone(), image::ImageFormat::Bmp),
        ("rgb8.ppm", dynamic.clone(), image::ImageFormat::Pnm),
        ("rgb8.tif", dynamic.clone(), image::ImageFormat::Tiff),
    ] {
        write(&images, name, &encoded(img, format)?)?;
    }
    // The simulator's own 32-bit float TIFF (`sim --display-out x.tif`).
    let tif = std::env::temp_dir().join(format!("nedrt-seed-{}.tif", std::process::id()));
    nedrt_core::image_io::save(&small, &tif, &["tif"])?;
    let bytes = std::fs::read(&tif)?;
    std::fs::remove_file(&tif)?;
    write(&images, "rgb32f.tif", &bytes)?;

    println!("wrote the seeds under {}", root.display());
    Ok(())
}
