//! DOE height-map files: safetensors with one tensor `height_um` (N×N, F32 or
//! F64, row-major, centred on the axis; or N samples of a radial profile at
//! (n + ½)·pitch with `profile = "radial"`) and string metadata stating the
//! grid and the fabrication limits (docs/doe-format.md). The trainer writes
//! them; every field is validated at load time, once.

use std::collections::HashMap;
use std::path::Path;

use safetensors::{Dtype, SafeTensors};

use super::doe::{HeightMap, Profile};
use nedrt_core::calib::Calibration;

/// Value of the `format` metadata key.
pub const FORMAT: &str = "nedrt-doe";
/// Value of the `version` metadata key this code writes and reads.
pub const VERSION: &str = "1";
const TENSOR: &str = "height_um";
/// Metadata key and value marking a radial profile (absent or `map`: 2-D).
const PROFILE: &str = "profile";
const RADIAL: &str = "radial";
const MAP: &str = "map";

#[derive(Debug, thiserror::Error)]
pub enum DoeError {
    #[error("{path}: cannot read DOE file: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot write DOE file: {source}")]
    Write {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: invalid DOE file: {reason}")]
    Invalid { path: String, reason: String },
}

/// The largest DOE file read: a 2-D map at 1 µm over a 10 mm aperture is
/// 400 MB in f32; anything larger is not a height map (`/dev/zero`, a wrong path).
pub const MAX_DOE_FILE_BYTES: u64 = 512 << 20;

/// Reads and validates a height map against the calibration (material, aperture coverage).
pub fn load(path: &Path, calib: &Calibration) -> Result<HeightMap, DoeError> {
    let name = path.display().to_string();
    let bytes = nedrt_core::util::read_capped(path, MAX_DOE_FILE_BYTES).map_err(|source| {
        DoeError::Read {
            path: name.clone(),
            source,
        }
    })?;
    parse(&bytes, &name, calib)
}

/// Validates and decodes the bytes of a DOE file; `name` is used in messages.
pub fn parse(bytes: &[u8], name: &str, calib: &Calibration) -> Result<HeightMap, DoeError> {
    let bad = |reason: String| DoeError::Invalid {
        path: name.to_string(),
        reason,
    };
    let (_, header) = SafeTensors::read_metadata(bytes)
        .map_err(|e| bad(format!("not a safetensors file ({e})")))?;
    let meta = header.metadata().clone().ok_or_else(|| {
        bad("no metadata: pitch_um, max_height_um, levels and material are required".into())
    })?;
    let get = |key: &str| {
        meta.get(key)
            .ok_or_else(|| bad(format!("metadata key `{key}` is missing")))
    };
    let number = |key: &str| -> Result<f64, DoeError> {
        let text = get(key)?;
        let v: f64 = text
            .trim()
            .parse()
            .map_err(|_| bad(format!("metadata `{key}` = {text:?} is not a number")))?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(bad(format!("metadata `{key}` = {text:?} is not finite")))
        }
    };
    if get("format")? != FORMAT {
        return Err(bad(format!("metadata `format` must be {FORMAT:?}")));
    }
    if get("version")? != VERSION {
        return Err(bad(format!(
            "metadata `version` = {:?}; this nedrt reads version {VERSION}",
            get("version")?
        )));
    }
    let pitch_um = number("pitch_um")?;
    let max_height_um = number("max_height_um")?;
    let design_wavelength_nm = number("design_wavelength_nm")?;
    let levels_text = get("levels")?;
    let levels: u32 = levels_text.trim().parse().map_err(|_| {
        bad(format!(
            "metadata `levels` = {levels_text:?} is not a whole number"
        ))
    })?;
    let material = get("material")?.clone();
    if pitch_um <= 0.0 {
        return Err(bad(format!("pitch_um = {pitch_um} must be positive")));
    }
    if max_height_um <= 0.0 {
        return Err(bad(format!(
            "max_height_um = {max_height_um} must be positive"
        )));
    }
    if !(200.0..=2000.0).contains(&design_wavelength_nm) {
        return Err(bad(format!(
            "design_wavelength_nm = {design_wavelength_nm} is not an optical wavelength"
        )));
    }
    if levels == 1 {
        return Err(bad(
            "levels = 1 is a flat plate; use 0 (continuous) or ≥ 2".into()
        ));
    }
    if material != calib.material_name {
        return Err(bad(format!(
            "material {material:?} differs from the calibration's {:?} ({}), whose refractive indices give the DOE its phase",
            calib.material_name, calib.source
        )));
    }

    let tensors =
        SafeTensors::deserialize(bytes).map_err(|e| bad(format!("corrupt tensor data ({e})")))?;
    let view = tensors
        .tensor(TENSOR)
        .map_err(|_| bad(format!("tensor `{TENSOR}` is missing")))?;
    let shape = view.shape().to_vec();
    let profile = match meta.get(PROFILE).map(String::as_str) {
        None | Some(MAP) => Profile::Map,
        Some(RADIAL) => Profile::Radial,
        Some(other) => {
            return Err(bad(format!(
                "metadata `{PROFILE}` = {other:?}; it must be {MAP:?} (2-D, the default) or {RADIAL:?}"
            )));
        }
    };
    let samples = match (profile, shape.as_slice()) {
        (Profile::Map, &[rows, cols]) if rows == cols && rows >= 4 => rows,
        (Profile::Radial, &[n]) if n >= 4 => n,
        (Profile::Map, &[_]) => {
            return Err(bad(format!(
                "tensor `{TENSOR}` has shape {shape:?} (1-D) but metadata `{PROFILE}` is {}; \
                 a radial profile needs `{PROFILE}` = {RADIAL:?}",
                meta.get(PROFILE)
                    .map_or("absent (2-D map)".to_string(), |v| format!("{v:?}"))
            )));
        }
        (Profile::Radial, _) => {
            return Err(bad(format!(
                "metadata `{PROFILE}` = {RADIAL:?} but tensor `{TENSOR}` has shape {shape:?}; \
                 a radial profile is 1-D with N ≥ 4 samples"
            )));
        }
        (Profile::Map, _) => {
            return Err(bad(format!(
                "tensor `{TENSOR}` has shape {shape:?}; a square N×N grid with N ≥ 4 is required"
            )));
        }
    };
    // Where sample k lies, for messages.
    let at = |k: usize| match profile {
        Profile::Map => format!("row {}, column {}", k / samples, k % samples),
        Profile::Radial => format!("sample {k} (ρ = {:.2} µm)", (k as f64 + 0.5) * pitch_um),
    };
    let values: Vec<f64> = match view.dtype() {
        Dtype::F32 => view
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64)
            .collect(),
        Dtype::F64 => view
            .data()
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
            .collect(),
        other => {
            return Err(bad(format!(
                "tensor `{TENSOR}` has dtype {other:?}; F32 or F64 is required"
            )));
        }
    };
    if let Some(k) = values.iter().position(|v| !v.is_finite()) {
        return Err(bad(format!("height at {} is not finite", at(k))));
    }
    // f32 files hold heights to ~1e-7 relative: allow that much over the limits.
    let slack_um = max_height_um * 1e-6;
    if let Some(k) = values
        .iter()
        .position(|v| *v < -slack_um || *v > max_height_um + slack_um)
    {
        return Err(bad(format!(
            "height {} µm at {} lies outside [0, max_height_um = {max_height_um}]",
            values[k],
            at(k)
        )));
    }
    if levels >= 2 {
        let step = max_height_um / (levels - 1) as f64;
        if let Some(k) = values.iter().position(|v| {
            let q = (v / step).round() * step;
            (v - q).abs() > 1e-4 * step
        }) {
            return Err(bad(format!(
                "levels = {levels} but height {} µm at {} is not one of the {levels} levels from 0 to {max_height_um} µm",
                values[k],
                at(k)
            )));
        }
    }
    let pitch_m = pitch_um * 1e-6;
    let r = calib.aperture_radius_m;
    match profile {
        Profile::Map => {
            let half_extent_m = (samples as f64 - 1.0) / 2.0 * pitch_m;
            if half_extent_m < r * (1.0 - 1e-9) {
                return Err(bad(format!(
                    "the grid ({samples} × {pitch_um} µm, {:.4} mm across) does not cover the {:.4} mm aperture",
                    2.0 * half_extent_m * 1e3,
                    2.0 * r * 1e3
                )));
            }
        }
        Profile::Radial => {
            // Sample n covers [n, n + 1)·pitch: N·pitch must reach r.
            let extent_m = samples as f64 * pitch_m;
            if extent_m < r * (1.0 - 1e-9) {
                return Err(bad(format!(
                    "the radial profile ({samples} × {pitch_um} µm, reaching ρ = {:.4} mm) does not cover the {:.4} mm aperture radius",
                    extent_m * 1e3,
                    r * 1e3
                )));
            }
        }
    }
    if max_height_um * 1e-6 > calib.doe_max_height_m * (1.0 + 1e-9) {
        tracing::warn!(
            "{name}: max_height_um = {max_height_um} exceeds the fabrication depth doe.max_height_um = {} of {}",
            calib.doe_max_height_m * 1e6,
            calib.source
        );
    }
    let design_ch = &calib.channels[calib.design_channel];
    if (design_wavelength_nm * 1e-9 - design_ch.wavelength_m).abs() > 1e-12 {
        tracing::warn!(
            "{name}: designed for {design_wavelength_nm} nm, the calibration's design channel {} is {} nm",
            design_ch.name,
            design_ch.wavelength_m * 1e9
        );
    }
    Ok(HeightMap {
        profile,
        samples,
        pitch_m,
        height_m: values
            .iter()
            .map(|v| v.clamp(0.0, max_height_um) * 1e-6)
            .collect(),
        max_height_m: max_height_um * 1e-6,
        levels,
        material,
        design_wavelength_m: design_wavelength_nm * 1e-9,
        description: meta
            .get("description")
            .cloned()
            .unwrap_or_else(|| name.to_string()),
    })
}

/// Encodes a height map or radial profile (heights as F32 µm) with its
/// metadata; a map is written exactly as before radial profiles existed
/// (no `profile` key).
pub fn to_bytes(map: &HeightMap) -> Result<Vec<u8>, safetensors::SafeTensorError> {
    let heights: Vec<u8> = map
        .height_m
        .iter()
        .flat_map(|h| ((h * 1e6) as f32).to_le_bytes())
        .collect();
    let shape = match map.profile {
        Profile::Map => vec![map.samples, map.samples],
        Profile::Radial => vec![map.samples],
    };
    let view = safetensors::tensor::TensorView::new(Dtype::F32, shape, &heights)?;
    let mut meta: HashMap<String, String> = [
        ("format", FORMAT.to_string()),
        ("version", VERSION.to_string()),
        ("pitch_um", format!("{}", map.pitch_m * 1e6)),
        ("max_height_um", format!("{}", map.max_height_m * 1e6)),
        ("levels", map.levels.to_string()),
        ("material", map.material.clone()),
        (
            "design_wavelength_nm",
            format!("{}", map.design_wavelength_m * 1e9),
        ),
        ("description", map.description.clone()),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    if map.profile == Profile::Radial {
        meta.insert(PROFILE.into(), RADIAL.into());
    }
    safetensors::serialize([(TENSOR, view)], Some(meta))
}

/// Writes a height map atomically (temporary file, then rename): a failed
/// write never leaves a half-written file behind.
pub fn save(map: &HeightMap, path: &Path) -> Result<(), DoeError> {
    let name = path.display().to_string();
    let bytes = to_bytes(map).map_err(|e| DoeError::Invalid {
        path: name.clone(),
        reason: e.to_string(),
    })?;
    nedrt_core::util::write_atomic(path, &bytes)
        .map_err(|source| DoeError::Write { path: name, source })
}

#[cfg(test)]
mod tests;
