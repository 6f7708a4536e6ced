//! The views of a panel (one, or a headset's eyes) as the upload and the
//! preprocess stages see them. The upload stage ([`Intake`]) keeps each
//! view's newest frame: as the client sent it for a view on the device (it
//! is unpacked and its quads blended there), or decoded with its quads
//! blended, and through a host stage where the view has one. Every
//! submission hands each view's newest on. The host engine ([`HostViews`])
//! runs each view through its own preprocessing (two fabricated DOEs are
//! never identical: each eye has its own design) and puts the outputs in
//! their regions of one panel image; a view whose frame has not changed
//! since its engine last ran is not run again. One view on the whole
//! panel is N = 1: its output is the panel image.
//!
//! Accounting is the same for any N: each submission is one item through
//! the stages (a frame of one view, or a panel-sized frame of all).

use std::sync::Arc;
use std::sync::atomic::Ordering::Relaxed;

use super::{HostPrep, PreprocessStage, Stats};
use crate::compose::{LayerSet, ViewRegion, blend};
use crate::pipeline::frame::{SubmittedFrame, ViewContent, ViewFrame, crop, decode};
use nedrt_core::Image;
use nedrt_core::preprocess::PreprocessError;

/// Decodes `f` and blends `layers` over it (counted when there were any).
fn decoded_with_layers(f: &SubmittedFrame, layers: &LayerSet, view: usize) -> (Image, bool) {
    let mut im = decode(f);
    let snap = layers.snapshot();
    if snap.quads.is_empty() {
        return (im, false);
    }
    match blend(&mut im, &snap.quads) {
        Ok(()) => (im, true),
        // The set holds at most MAX_QUADS: a bug, not the client's.
        Err(e) => {
            tracing::error!("blending frame {} of view {view}: {e}", f.id);
            (im, false)
        }
    }
}

/// How the upload stage hands a view's frame on.
#[derive(Debug)]
pub(super) enum Uptake {
    /// Decoded, its quads blended (the host engine).
    Decode,
    /// As the client sent it (the device unpacks and blends).
    AsSent,
    /// Decoded, blended and through host work before the device; if that
    /// work fails, [`Uptake::Decode`] from then on.
    Prepared(HostPrep),
}

#[derive(Debug)]
struct ViewIntake {
    region: ViewRegion,
    layers: Arc<LayerSet>,
    uptake: Uptake,
    latest: ViewFrame,
}

/// The upload stage's state: each view's newest frame.
#[derive(Debug)]
pub(super) struct Intake {
    panel: (usize, usize),
    views: Vec<ViewIntake>,
    generation: u64,
}

impl Intake {
    /// Views start black (generation 0) until their first frame.
    pub(super) fn new(
        panel: (usize, usize),
        views: Vec<(ViewRegion, Arc<LayerSet>, Uptake)>,
    ) -> Self {
        let views = views
            .into_iter()
            .map(|(region, layers, uptake)| ViewIntake {
                region,
                layers,
                uptake,
                latest: ViewFrame {
                    generation: 0,
                    content: ViewContent::Planar(Arc::new(Image::zeros(0, 0, 3))),
                },
            })
            .collect();
        Self {
            panel,
            views,
            generation: 0,
        }
    }

    /// Takes a submission for `view` (a view-sized frame) or for every view
    /// (`None`: a panel-sized frame, cut into the views' regions); every
    /// view's newest frame, or `None` where a host stage refused the frame.
    pub(super) fn take(
        &mut self,
        view: Option<u8>,
        f: SubmittedFrame,
        stats: &Stats,
    ) -> Option<Vec<ViewFrame>> {
        let id = f.id;
        let whole =
            |r: &ViewRegion| (r.x, r.y, r.width, r.height) == (0, 0, self.panel.0, self.panel.1);
        let parts: Vec<(usize, SubmittedFrame)> = match view {
            Some(v) => vec![(usize::from(v), f)],
            None if self.views.len() == 1 && whole(&self.views[0].region) => vec![(0, f)],
            None => self
                .views
                .iter()
                .enumerate()
                .map(|(v, w)| {
                    let r = w.region;
                    (v, crop(&f, (r.x, r.y), (r.width, r.height)))
                })
                .collect(),
        };
        let updated = parts.len();
        let mut blended = false;
        for (v, part) in parts {
            let Some(intake) = self.views.get_mut(v) else {
                // Validated at submit: a bug, not the client's.
                tracing::error!("frame {id} for view {v} of {}", self.views.len());
                stats.failed.fetch_add(1, Relaxed);
                return None;
            };
            let content = match intake.uptake {
                Uptake::AsSent => ViewContent::Client(Arc::new(part)),
                Uptake::Decode | Uptake::Prepared(_) => {
                    let (im, b) = decoded_with_layers(&part, &intake.layers, v);
                    blended |= b;
                    let out = match &mut intake.uptake {
                        Uptake::Prepared(prep) => match prep.0.run(&im) {
                            Ok(out) => out,
                            Err(PreprocessError::Frame(e)) => {
                                tracing::error!("{} refused frame {id}: {e}", prep.name());
                                stats.failed.fetch_add(1, Relaxed);
                                return None;
                            }
                            Err(e) => {
                                let name = prep.name();
                                tracing::error!(
                                    "{name} failed: {e}; frames now go to the device without it"
                                );
                                stats.dcnn_failures.fetch_add(1, Relaxed);
                                *stats.frame_path.lock().unwrap_or_else(|p| p.into_inner()) =
                                    format!("device, without its host stage ({name} failed)");
                                intake.uptake = Uptake::Decode;
                                im
                            }
                        },
                        _ => im,
                    };
                    ViewContent::Planar(Arc::new(out))
                }
            };
            self.generation += 1;
            intake.latest = ViewFrame {
                generation: self.generation,
                content,
            };
        }
        if blended {
            stats.frames_with_layers.fetch_add(1, Relaxed);
        }
        // The other views, shown from their last frame (not waited for).
        let reused = self
            .views
            .iter()
            .filter(|w| w.latest.generation != 0)
            .count();
        stats
            .view_frames_reused
            .fetch_add(reused.saturating_sub(updated) as u64, Relaxed);
        Some(self.views.iter().map(|w| w.latest.clone()).collect())
    }
}

/// One view's engine on the host and its last output.
struct HostView {
    region: ViewRegion,
    layers: Arc<LayerSet>,
    stage: PreprocessStage,
    last: Option<(u64, Image)>,
}

/// The preprocess stage on the host: each view its own engine.
pub(super) struct HostViews {
    panel: (usize, usize),
    views: Vec<HostView>,
}

impl std::fmt::Debug for HostViews {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HostViews")
            .field("panel", &self.panel)
            .field("engines", &self.describe())
            .finish()
    }
}

impl HostViews {
    pub(super) fn new(
        panel: (usize, usize),
        views: Vec<(ViewRegion, Arc<LayerSet>, PreprocessStage)>,
    ) -> Self {
        let views = views
            .into_iter()
            .map(|(region, layers, stage)| HostView {
                region,
                layers,
                stage,
                last: None,
            })
            .collect();
        Self { panel, views }
    }

    /// One view's engine, or "view 0: …; view 1: …".
    pub(super) fn describe(&self) -> String {
        if let [one] = self.views.as_slice() {
            return one.stage.primary.describe();
        }
        self.views
            .iter()
            .enumerate()
            .map(|(v, e)| format!("view {v}: {}", e.stage.primary.describe()))
            .collect::<Vec<_>>()
            .join("; ")
    }

    /// The panel's display image: each view through its engine (again
    /// only if its frame changed), in its region; black outside them and
    /// in a view that has had no frame yet.
    pub(super) fn run(&mut self, frames: &[ViewFrame], stats: &Stats) -> Option<Image> {
        let (width, height) = self.panel;
        let planes = |f: &ViewFrame, h: &HostView, v| match &f.content {
            ViewContent::Planar(im) => im.clone(),
            // After the device path failed: decoded and blended here.
            ViewContent::Client(sent) => {
                let (im, blended) = decoded_with_layers(sent, &h.layers, v);
                if blended {
                    stats.frames_with_layers.fetch_add(1, Relaxed);
                }
                Arc::new(im)
            }
        };
        // One view on the whole panel: its output is the panel.
        if let ([h], [f]) = (self.views.as_mut_slice(), frames)
            && (h.region.width, h.region.height) == (width, height)
            && f.generation != 0
        {
            let im = planes(f, h, 0);
            return h.stage.run(&im, stats);
        }
        let mut panel = Image::zeros(width, height, 3);
        // One traffic record for the frame, whichever views ran.
        let mut traffic = nedrt_core::preprocess::HostTraffic::default();
        for (v, (f, h)) in frames.iter().zip(&mut self.views).enumerate() {
            // No frame for this view yet: black, its engine not run on nothing.
            if f.generation == 0 {
                continue;
            }
            let fresh = !matches!(&h.last, Some((g, _)) if *g == f.generation);
            if fresh {
                let im = planes(f, h, v);
                let t0 = std::time::Instant::now();
                let out = h.stage.run_uncounted(&im, stats)?;
                stats.record_view(v, t0.elapsed().as_nanos() as u64);
                traffic.add(h.stage.primary.last_traffic());
                h.last = Some((f.generation, out));
            }
            let Some((_, out)) = &h.last else {
                return None;
            };
            paste(&mut panel, out, h.region);
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
