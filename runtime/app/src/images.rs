//! The photographs a command reads from a folder: listed in name order,
//! loaded for the panel and cropped to multiples of 8 (docs/model.md §17).

use std::path::{Path, PathBuf};

use crate::AppError;
use nedrt_core::Image;
use nedrt_core::image_io;

/// Image files in a folder, sorted by name.
pub fn list_images(dir: &Path) -> Result<Vec<PathBuf>, AppError> {
    let entries = std::fs::read_dir(dir)
        .map_err(|e| AppError::output(dir, format!("cannot read folder: {e}")))?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension().is_some_and(|e| {
                matches!(
                    e.to_string_lossy().to_ascii_lowercase().as_str(),
                    "png" | "jpg" | "jpeg" | "tif" | "tiff" | "bmp" | "ppm"
                )
            })
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(AppError::input(
            dir.display(),
            "no images (png, jpg, tif, bmp, ppm) in this folder",
        ));
    }
    Ok(files)
}

/// Loads every image of `files` ([`load_cropped`]).
pub fn load_all(files: &[PathBuf], panel: (usize, usize)) -> Result<Vec<Image>, AppError> {
    files.iter().map(|f| load_cropped(f, panel)).collect()
}

/// Loads an image the `panel` (width, height) can show and crops it to
/// multiples of 8 (docs/model.md §17), saying so.
pub fn load_cropped(path: &Path, panel: (usize, usize)) -> Result<Image, AppError> {
    let l = image_io::load_for_panel(path, panel)?;
    for n in &l.notes {
        tracing::warn!("{n}");
    }
    let im = l.image;
    let (w, h) = (im.width / 8 * 8, im.height / 8 * 8);
    if w == 0 || h == 0 {
        return Err(AppError::input(path.display(), "smaller than 8×8 pixels"));
    }
    if (w, h) != (im.width, im.height) {
        tracing::warn!(
            "{}: cropped from {}×{} to {w}×{h} (multiples of 8)",
            path.display(),
            im.width,
            im.height
        );
        return Ok(im.crop(0, 0, w, h));
    }
    Ok(im)
}
