//! Two views on one panel (a headset's eyes, issue 33), on the host path:
//! the upload stage keeps each view's newest projection with its own quad
//! layers blended in, and hands every view's newest on with each
//! submission; the dcnn stage runs each view through its own engine (two
//! fabricated DOEs are never identical: each eye has its own design) and
//! puts the outputs in their regions of one panel image, which the encode
//! and present stages take as a mono frame. A view whose image has not
//! changed since its engine last ran is not run again.
//!
//! Accounting is unchanged: each submission is one item through the
//! stages (a frame of one view, or a panel-sized frame of both).

use std::sync::Arc;
use std::sync::atomic::Ordering::Relaxed;

use super::{PreprocessStage, Stats};
use crate::compose::{LayerSet, ViewImage, ViewRegion, blend};
use crate::pipeline::frame::{SubmittedFrame, decode};
use crate::pipeline::resident::DeviceInput;
use nedrt_core::Image;

/// The upload stage's state with views.
#[derive(Debug)]
pub(super) struct ViewsUpload {
    regions: Vec<ViewRegion>,
    layers: Vec<Arc<LayerSet>>,
    latest: Vec<ViewImage>,
    generation: u64,
}

impl ViewsUpload {
    /// Views start black until their first frame.
    pub(super) fn new(regions: Vec<ViewRegion>, layers: Vec<Arc<LayerSet>>) -> Self {
        let latest = regions
            .iter()
            .map(|r| ViewImage {
                generation: 0,
                image: Arc::new(Image::zeros(r.width, r.height, 3)),
            })
            .collect();
        Self {
            regions,
            layers,
            latest,
            generation: 0,
        }
    }

    /// Takes a submission for `view` (a view-sized frame) or for every view
    /// (`None`: a panel-sized frame, cut into the views' regions).
    pub(super) fn take(
        &mut self,
        view: Option<u8>,
        f: &SubmittedFrame,
        stats: &Stats,
    ) -> Option<DeviceInput> {
        let decoded = decode(f);
        let views: Vec<usize> = match view {
            Some(v) => vec![usize::from(v)],
            None => (0..self.regions.len()).collect(),
        };
        let mut blended = false;
        for v in views {
            let (Some(region), Some(layers)) = (self.regions.get(v), self.layers.get(v)) else {
                // Validated at submit: a bug, not the client's.
                tracing::error!("frame {} for view {v} of {}", f.id, self.regions.len());
                stats.failed.fetch_add(1, Relaxed);
                return None;
            };
            let mut image = match view {
                Some(_) => decoded.clone(),
                None => decoded.crop(region.x, region.y, region.width, region.height),
            };
            let snap = layers.snapshot();
            if !snap.quads.is_empty() {
                match blend(&mut image, &snap.quads) {
                    Ok(()) => blended = true,
                    // The set holds at most MAX_QUADS: a bug, not the client's.
                    Err(e) => tracing::error!("blending frame {} of view {v}: {e}", f.id),
                }
            }
            self.generation += 1;
            self.latest[v] = ViewImage {
                generation: self.generation,
                image: Arc::new(image),
            };
        }
        if blended {
            stats.frames_with_layers.fetch_add(1, Relaxed);
        }
        // The other views, shown from their last frame (not waited for).
        let updated = match view {
            Some(_) => 1,
            None => self.regions.len(),
        };
        let reused = self.latest.iter().filter(|l| l.generation != 0).count();
        stats
            .view_frames_reused
            .fetch_add(reused.saturating_sub(updated) as u64, Relaxed);
        Some(DeviceInput::Views(self.latest.clone()))
    }
}

/// One view's engine and its last output.
struct ViewEngine {
    stage: PreprocessStage,
    last: Option<(u64, Image)>,
}

/// The dcnn stage with views.
pub(super) struct ViewEngines {
    regions: Vec<ViewRegion>,
    width: usize,
    height: usize,
    engines: Vec<ViewEngine>,
}

impl std::fmt::Debug for ViewEngines {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ViewEngines")
            .field("regions", &self.regions)
            .field("engines", &self.describe())
            .finish()
    }
}

impl ViewEngines {
    pub(super) fn new(
        (width, height): (usize, usize),
        regions: Vec<ViewRegion>,
        stages: Vec<PreprocessStage>,
    ) -> Self {
        Self {
            regions,
            width,
            height,
            engines: stages
                .into_iter()
                .map(|stage| ViewEngine { stage, last: None })
                .collect(),
        }
    }

    /// "view 0: …; view 1: …".
    pub(super) fn describe(&self) -> String {
        self.engines
            .iter()
            .enumerate()
            .map(|(v, e)| format!("view {v}: {}", e.stage.primary.describe()))
            .collect::<Vec<_>>()
            .join("; ")
    }

    /// The panel's display image: each view through its engine (again
    /// only if its image changed), in its region; black outside them and
    /// in a view that has had no frame yet.
    pub(super) fn run(&mut self, views: &[ViewImage], stats: &Stats) -> Option<Image> {
        let mut panel = Image::zeros(self.width, self.height, 3);
        // One traffic record for the frame, whichever eyes ran.
        let mut traffic = nedrt_core::preprocess::HostTraffic::default();
        for (v, (view, engine)) in views.iter().zip(&mut self.engines).enumerate() {
            // No frame for this view yet: black, its engine not run on nothing.
            if view.generation == 0 {
                continue;
            }
            let fresh = !matches!(&engine.last, Some((g, _)) if *g == view.generation);
            if fresh {
                let t0 = std::time::Instant::now();
                let out = engine.stage.run_uncounted(&view.image, stats)?;
                stats.record_view(v, t0.elapsed().as_nanos() as u64);
                traffic.add(engine.stage.primary.last_traffic());
                engine.last = Some((view.generation, out));
            }
            let Some((_, out)) = &engine.last else {
                return None;
            };
            paste(&mut panel, out, self.regions[v]);
        }
        stats.dcnn_traffic.record(traffic);
        Some(panel)
    }
}

/// Refuses views that are empty or not inside a `width`×`height` panel.
pub(super) fn check_regions(
    regions: &[ViewRegion],
    (width, height): (usize, usize),
) -> std::io::Result<()> {
    for r in regions {
        if !r.fits((width, height)) {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "a {}×{} view at ({}, {}) on a {width}×{height} panel",
                    r.width, r.height, r.x, r.y
                ),
            ));
        }
    }
    Ok(())
}

/// Copies `image` into `region` of `panel` (same channel count).
pub(super) fn paste(panel: &mut Image, image: &Image, region: ViewRegion) {
    let width = panel.width;
    let w = region.width.min(image.width);
    for c in 0..panel.channels().min(image.channels()) {
        let src = image.plane(c);
        let dst = panel.plane_mut(c);
        for row in 0..region.height.min(image.height) {
            let d = (region.y + row) * width + region.x;
            dst[d..d + w].copy_from_slice(&src[row * image.width..][..w]);
        }
    }
}
