//! A folder of images (or a single image) played as a sequence, looping
//! until `count` frames were submitted. Every image is read and checked
//! once at start: a file of the wrong size is an error naming it, not a
//! stream of rejected frames.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use super::{Rate, Source, SourceError, SourceRate};
use crate::pipeline::frame::{PixelFormat, SubmittedFrame, planar_payload};
use crate::pipeline::pacing::Clock;
use crate::pipeline::service::Compositor;
use nedrt_core::image_io;

const EXTENSIONS: [&str; 7] = ["png", "jpg", "jpeg", "tif", "tiff", "bmp", "ppm"];

/// Images submitted in name order, looping.
#[derive(Debug)]
pub struct DirSource {
    path: PathBuf,
    /// Planar linear payloads, one per image.
    payloads: Vec<Vec<u8>>,
    width: usize,
    height: usize,
    /// Frames to submit; `None`: each image once.
    count: Option<u64>,
    rate: Rate,
}

impl DirSource {
    /// Reads every image in `path` (a folder or one file) for a
    /// `width`×`height` panel.
    pub fn load(
        path: &Path,
        width: usize,
        height: usize,
        count: Option<u64>,
        rate: SourceRate,
        clock: Arc<dyn Clock>,
    ) -> Result<Self, SourceError> {
        let input = |reason: String| SourceError::Input {
            path: path.to_path_buf(),
            reason,
        };
        let files: Vec<PathBuf> = if path.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(path)
                .map_err(|e| input(format!("cannot list: {e}")))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| {
                    p.extension()
                        .and_then(|e| e.to_str())
                        .is_some_and(|e| EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
                })
                .collect();
            files.sort();
            files
        } else if path.exists() {
            vec![path.to_path_buf()]
        } else {
            return Err(input("no such file or folder".into()));
        };
        if files.is_empty() {
            return Err(input(format!("no images ({})", EXTENSIONS.join(", "))));
        }
        let mut payloads = Vec::with_capacity(files.len());
        for f in &files {
            let loaded = image_io::load_for_panel(f, (width, height))?;
            for note in &loaded.notes {
                tracing::info!("{note}");
            }
            let img = loaded.image;
            if (img.width, img.height) != (width, height) {
                return Err(SourceError::Input {
                    path: f.clone(),
                    reason: format!(
                        "{}×{} image for a {width}×{height} panel (frames are not rescaled)",
                        img.width, img.height
                    ),
                });
            }
            if img.channels() != 3 {
                return Err(SourceError::Input {
                    path: f.clone(),
                    reason: format!("{} channels; the panel takes RGB", img.channels()),
                });
            }
            payloads.push(planar_payload(&img));
        }
        Ok(Self {
            path: path.to_path_buf(),
            payloads,
            width,
            height,
            count,
            rate: Rate::new(rate, clock),
        })
    }
}

impl Source for DirSource {
    fn describe(&self) -> String {
        format!("{} ({} images)", self.path.display(), self.payloads.len())
    }

    fn run(&mut self, compositor: Compositor, stop: &AtomicBool) -> Result<u64, SourceError> {
        let total = self.count.unwrap_or(self.payloads.len() as u64);
        for id in 0..total {
            if stop.load(Ordering::Relaxed) {
                return Ok(id);
            }
            let made_for = self.rate.wait(&compositor);
            let payload = self.payloads[(id % self.payloads.len() as u64) as usize].clone();
            let capture_ns = self.rate.made();
            // Validated at load; a refusal here is counted by the service.
            let frame = SubmittedFrame {
                id,
                capture_ns,
                width: self.width,
                height: self.height,
                format: PixelFormat::Rgb32fPlanar,
                payload,
            };
            let _ = compositor.submit_for(frame, made_for);
        }
        Ok(total)
    }
}
