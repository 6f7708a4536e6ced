//! The captures a lab takes of the patterns (docs/calibration.md §2):
//! `captures.toml`, naming each photograph, and the camera model that
//! `nedrt calib synth` photographs through.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::AppError;
use crate::calib_patterns::PatternsManifest;

pub const MANIFEST: &str = "captures.toml";
/// Largest manifest read (a few KB in practice).
const MAX_MANIFEST_BYTES: u64 = 4 << 20;

/// `captures.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CapturesManifest {
    /// The patterns' manifest (`calib patterns`' patterns.toml), relative
    /// to this file's folder.
    pub patterns: String,
    /// Bits of the camera's raw values (at most 16); a pixel at
    /// 2^bits − 1 is saturated.
    pub bits: u32,
    pub capture: Vec<Capture>,
}

/// One photograph: a 16-bit grey PNG or TIFF of raw camera values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Capture {
    /// The image, relative to the manifest's folder.
    pub file: String,
    /// The pattern shown (a `file` of patterns.toml).
    pub pattern: String,
    /// Where the camera was focused, diopters (the eye's accommodation).
    pub accommodation_d: f64,
    pub exposure_ms: f64,
    /// Raw frames summed into the image (a lab averages frames against the
    /// noise; the sum keeps every bit): its values are at most
    /// frames × (2^bits − 1).
    #[serde(default = "one_frame")]
    pub frames: u32,
}

fn one_frame() -> u32 {
    1
}

/// A manifest read and checked, with its folder and patterns.
#[derive(Debug, Clone)]
pub struct Captures {
    pub dir: PathBuf,
    pub manifest: CapturesManifest,
    pub manifest_blake3: String,
    pub patterns: PatternsManifest,
}

fn read_capped(path: &Path, cap: u64) -> Result<String, AppError> {
    let bytes =
        nedrt_core::util::read_capped(path, cap).map_err(|e| AppError::input(path.display(), e))?;
    String::from_utf8(bytes).map_err(|_| AppError::input(path.display(), "not UTF-8 text"))
}

impl Captures {
    /// Reads `dir/captures.toml` and the patterns it names, checking every
    /// field; the error names the file and the field.
    pub fn load(dir: &Path) -> Result<Self, AppError> {
        let path = dir.join(MANIFEST);
        let text = read_capped(&path, MAX_MANIFEST_BYTES)?;
        let manifest: CapturesManifest =
            toml::from_str(&text).map_err(|e| AppError::input(path.display(), e.message()))?;
        let bad = |what: String| AppError::input(path.display(), what);
        if !(1..=16).contains(&manifest.bits) {
            return Err(bad(format!(
                "bits = {}: must lie in [1, 16]",
                manifest.bits
            )));
        }
        let patterns_path = dir.join(&manifest.patterns);
        let patterns: PatternsManifest =
            toml::from_str(&read_capped(&patterns_path, MAX_MANIFEST_BYTES)?)
                .map_err(|e| AppError::input(patterns_path.display(), e.message()))?;
        if manifest.capture.is_empty() {
            return Err(bad("no [[capture]]".into()));
        }
        for (i, c) in manifest.capture.iter().enumerate() {
            let at = format!("capture {} ({})", i + 1, c.file);
            if !patterns.pattern.iter().any(|p| p.file == c.pattern) {
                return Err(bad(format!(
                    "{at}: pattern {:?} is not in {}",
                    c.pattern,
                    patterns_path.display()
                )));
            }
            if !(c.accommodation_d.is_finite() && (-1.0..=20.0).contains(&c.accommodation_d)) {
                return Err(bad(format!(
                    "{at}: accommodation_d = {}: must lie in [−1, 20] D",
                    c.accommodation_d
                )));
            }
            if !(c.exposure_ms.is_finite() && c.exposure_ms > 0.0) {
                return Err(bad(format!(
                    "{at}: exposure_ms = {}: must be positive",
                    c.exposure_ms
                )));
            }
            let most = c.frames as u64 * ((1u64 << manifest.bits) - 1);
            if c.frames == 0 || most > u16::MAX as u64 {
                return Err(bad(format!(
                    "{at}: frames = {}: a 16-bit image holds at most {} summed frames of {} bits",
                    c.frames,
                    u16::MAX as u64 / ((1u64 << manifest.bits) - 1),
                    manifest.bits
                )));
            }
            if Path::new(&c.file).is_absolute() || c.file.contains("..") {
                return Err(bad(format!(
                    "{at}: file must lie inside the captures folder"
                )));
            }
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest,
            manifest_blake3: blake3::hash(text.as_bytes()).to_hex().to_string(),
            patterns,
        })
    }
}

/// A grey camera frame, raw values as read (DN).
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    pub values: Vec<f32>,
}

impl Frame {
    /// The mean of a (2r+1)² window around (u, v).
    pub fn local_mean(&self, u: f64, v: f64, r: isize) -> f64 {
        let f = self;
        let (cu, cv) = (u.round() as isize, v.round() as isize);
        let mut s = 0.0;
        let mut n = 0.0f64;
        for y in cv - r..=cv + r {
            for x in cu - r..=cu + r {
                if x >= 0 && y >= 0 && (x as usize) < f.width && (y as usize) < f.height {
                    s += f.values[y as usize * f.width + x as usize] as f64;
                    n += 1.0;
                }
            }
        }
        s / n.max(1.0)
    }

    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            values: vec![0.0; width * height],
        }
    }

    /// Bilinear sample at (x, y), pixel centres at integers; 0 outside.
    pub fn sample(&self, x: f64, y: f64) -> f64 {
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let at = |i: f64, j: f64| -> f64 {
            if i < 0.0 || j < 0.0 || i >= self.width as f64 || j >= self.height as f64 {
                0.0
            } else {
                self.values[j as usize * self.width + i as usize] as f64
            }
        };
        (1.0 - fy) * ((1.0 - fx) * at(x0, y0) + fx * at(x0 + 1.0, y0))
            + fy * ((1.0 - fx) * at(x0, y0 + 1.0) + fx * at(x0 + 1.0, y0 + 1.0))
    }

    /// Reads a 16-bit grey PNG or TIFF of `frames` summed frames of `bits`
    /// each, as one frame's mean.
    pub fn read(path: &Path, bits: u32, frames: u32) -> Result<Self, AppError> {
        let bad = |r: String| AppError::input(path.display(), r);
        let img = image::ImageReader::open(path)
            .map_err(|e| bad(e.to_string()))?
            .with_guessed_format()
            .map_err(|e| bad(e.to_string()))?
            .decode()
            .map_err(|e| bad(format!("not a readable image ({e})")))?;
        let grey = match img {
            image::DynamicImage::ImageLuma16(g) => g,
            other => {
                return Err(bad(format!(
                    "a {:?} image; a capture is a 16-bit grey image of raw camera values",
                    other.color()
                )));
            }
        };
        let most = frames.max(1) * ((1u32 << bits) - 1);
        if let Some(v) = grey.pixels().map(|p| p.0[0] as u32).find(|v| *v > most) {
            return Err(bad(format!(
                "holds the value {v}, beyond {frames} frame(s) of the manifest's {bits} bits ({most})"
            )));
        }
        let scale = 1.0 / frames.max(1) as f32;
        Ok(Self {
            width: grey.width() as usize,
            height: grey.height() as usize,
            values: grey.pixels().map(|p| p.0[0] as f32 * scale).collect(),
        })
    }

    /// Writes it as a 16-bit grey PNG (values rounded and clamped; fast
    /// compression: a capture is written once and read once).
    pub fn write(&self, path: &Path) -> Result<(), AppError> {
        use image::ImageEncoder;
        let bytes: Vec<u8> = self
            .values
            .iter()
            .flat_map(|v| (v.round().clamp(0.0, 65535.0) as u16).to_ne_bytes())
            .collect();
        let file = std::fs::File::create(path).map_err(|e| AppError::output(path, e))?;
        image::codecs::png::PngEncoder::new_with_quality(
            std::io::BufWriter::new(file),
            image::codecs::png::CompressionType::Fast,
            image::codecs::png::FilterType::Sub,
        )
        .write_image(
            &bytes,
            self.width as u32,
            self.height as u32,
            image::ExtendedColorType::L16,
        )
        .map_err(|e| AppError::output(path, e))
    }
}

/// The camera at the eye's position: a grey sensor whose pixels are
/// `pitch_cells` retinal cells wide, turned by `rotation_deg`, its centre
/// `offset_px` from the image's, with a little barrel or pincushion
/// distortion (`distortion_k1` at the sensor's half diagonal), shot and
/// read noise, a dark level and `bits` of quantisation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Camera {
    pub pitch_cells: f64,
    pub rotation_deg: f64,
    pub offset_px: [f64; 2],
    pub distortion_k1: f64,
    /// Electrons a pixel holds at its largest value.
    pub full_well_e: f64,
    pub read_noise_e: f64,
    pub dark_dn: f64,
    pub bits: u32,
    /// Frames summed into each capture.
    pub frames: u32,
    /// Quantum efficiency for each primary.
    pub qe: [f64; 3],
    /// Electrons per ms per pixel at full white of one primary (QE 1).
    pub flux_e_per_ms: f64,
    /// Of the image's extent, how much more the sensor sees each way.
    pub field_margin: f64,
}

impl Default for Camera {
    fn default() -> Self {
        Self {
            pitch_cells: 0.8,
            rotation_deg: 0.7,
            offset_px: [6.3, -4.7],
            distortion_k1: 5e-4,
            full_well_e: 20000.0,
            read_noise_e: 3.0,
            dark_dn: 64.0,
            bits: 12,
            frames: 16,
            qe: [0.55, 0.8, 0.45],
            flux_e_per_ms: 4000.0,
            field_margin: 0.04,
        }
    }
}

impl Camera {
    /// A camera TOML (the fields it leaves out are the default's).
    pub fn load(path: &Path) -> Result<Self, AppError> {
        toml::from_str(&read_capped(path, MAX_MANIFEST_BYTES)?)
            .map_err(|e| AppError::input(path.display(), e.message()))
    }

    /// The sensor's size for retinal images of `width`×`height` cells.
    pub fn sensor(&self, width: usize, height: usize) -> (usize, usize) {
        let side = |n: usize| {
            ((n as f64 * (1.0 + 2.0 * self.field_margin)) / self.pitch_cells).ceil() as usize
        };
        (side(width), side(height))
    }

    /// Where camera pixel (u, v) looks on a retinal image of
    /// `width`×`height` cells (cell centres at integers): the inverse of the
    /// lens's distortion, the offset, the rotation and the pitch.
    pub fn to_retina(
        &self,
        u: f64,
        v: f64,
        sensor: (usize, usize),
        retina: (usize, usize),
    ) -> (f64, f64) {
        let (cu, cv) = ((sensor.0 as f64 - 1.0) / 2.0, (sensor.1 as f64 - 1.0) / 2.0);
        let r2_norm = cu * cu + cv * cv;
        let (du, dv) = (u - cu, v - cv);
        // Undistort: u_d = u_i (1 + k1 r_i²), by fixed-point iteration.
        let (mut iu, mut iv) = (du, dv);
        for _ in 0..6 {
            let s = 1.0 + self.distortion_k1 * (iu * iu + iv * iv) / r2_norm;
            iu = du / s;
            iv = dv / s;
        }
        let (x, y) = (
            (iu - self.offset_px[0]) * self.pitch_cells,
            (iv - self.offset_px[1]) * self.pitch_cells,
        );
        let (s, c) = self.rotation_deg.to_radians().sin_cos();
        let (cx, cy) = ((retina.0 as f64 - 1.0) / 2.0, (retina.1 as f64 - 1.0) / 2.0);
        (cx + c * x + s * y, cy - s * x + c * y)
    }
}

/// SplitMix64 (nedrt-infer's) with Box–Muller normals: reproducible noise
/// from a seed.
#[derive(Debug, Clone)]
pub struct Noise(nedrt_infer::synth::SplitMix);

impl Noise {
    pub fn new(seed: u64) -> Self {
        Self(nedrt_infer::synth::SplitMix::new(seed))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// Uniform in (0, 1].
    fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 1.0) / (1u64 << 53) as f64
    }

    pub fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }

    /// Poisson with mean `mean`: counted under 30, a normal above.
    pub fn poisson(&mut self, mean: f64) -> f64 {
        if mean <= 0.0 {
            return 0.0;
        }
        if mean > 30.0 {
            return (mean + mean.sqrt() * self.normal()).max(0.0).round();
        }
        let limit = (-mean).exp();
        let (mut k, mut p) = (0.0, 1.0);
        loop {
            p *= self.uniform();
            if p <= limit {
                return k;
            }
            k += 1.0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_has_its_moments() {
        let mut n = Noise::new(7);
        for mean in [0.5, 4.0, 100.0] {
            let xs: Vec<f64> = (0..20000).map(|_| n.poisson(mean)).collect();
            let m = xs.iter().sum::<f64>() / xs.len() as f64;
            let v = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / xs.len() as f64;
            assert!((m - mean).abs() < 0.05 * mean + 0.02, "{mean}: mean {m}");
            assert!((v - mean).abs() < 0.1 * mean + 0.05, "{mean}: variance {v}");
        }
    }

    #[test]
    fn an_ideal_camera_looks_at_the_retina_through_its_pitch() {
        let cam = Camera {
            rotation_deg: 0.0,
            offset_px: [0.0; 2],
            distortion_k1: 0.0,
            pitch_cells: 0.5,
            field_margin: 0.0,
            ..Default::default()
        };
        let sensor = cam.sensor(100, 60);
        assert_eq!(sensor, (200, 120));
        let (x, y) = cam.to_retina(99.5, 59.5, sensor, (100, 60));
        assert!((x - 49.5).abs() < 1e-12 && (y - 29.5).abs() < 1e-12);
        let (x, y) = cam.to_retina(101.5, 59.5, sensor, (100, 60));
        assert!((x - 50.5).abs() < 1e-12 && (y - 29.5).abs() < 1e-12);
    }
}
