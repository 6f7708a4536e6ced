//! Two views on the sink's device (issue 33): each eye its own device
//! stage (its design's prefilter, or none), and both eyes' uploads, stages
//! and encodes recorded into one command encoder and one submission that
//! writes the panel's codes, each view into its region; nothing comes back
//! but the non-finite counts and the timestamps. The views' planes come
//! from the host (the upload stage decodes each eye's newest frame and
//! blends its quads: `service::views`); a view whose image did not change
//! is encoded again from its last display planes without running its
//! stage.

use std::sync::Arc;

use crate::compose::{ViewImage, ViewRegion};
use crate::present::encode_gpu::{CodesTarget, PanelEncoder, row_texels};
use crate::present::transfer::Transfer;
use crate::present::{DeviceDisplayFrame, PresentError};
use nedrt_core::preprocess::HostTraffic;
use nedrt_gpu::{DeviceStage, PassTimer};

const STAGE: &str = "device views";

fn err(reason: impl std::fmt::Display) -> PresentError {
    PresentError::frame(STAGE, reason)
}

/// One eye on the device.
#[derive(Debug)]
struct DeviceView {
    region: ViewRegion,
    /// Three f32 planes: the view's frame, and its stage's output.
    frame: wgpu::Buffer,
    display: wgpu::Buffer,
    stage: Option<Box<dyn DeviceStage>>,
    /// Writes the view's codes into its region of the panel's.
    encoder: PanelEncoder,
    /// The image generation whose display planes are on the device (0:
    /// none yet).
    generation: u64,
}

/// The views of a panel on one device.
#[derive(Debug)]
pub struct DeviceViews {
    device: wgpu::Device,
    queue: wgpu::Queue,
    width: usize,
    height: usize,
    row_texels: u32,
    views: Vec<DeviceView>,
    /// Panel codes buffers; one is reused once no frame holds it.
    codes: Vec<Arc<wgpu::Buffer>>,
    /// A timestamp pair per view around its stage, where the device has them.
    timer: Option<PassTimer>,
    last_view_ns: Vec<Option<u64>>,
    last_ran: Vec<bool>,
}

impl DeviceViews {
    /// Prepares a `width`×`height` panel of `regions`, each view through
    /// its `stages` entry (none: the frame as it comes, clamped).
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        (width, height): (usize, usize),
        regions: &[ViewRegion],
        transfer: &Transfer,
        stages: Vec<Option<Box<dyn DeviceStage>>>,
    ) -> Result<Self, PresentError> {
        if regions.len() != stages.len() || regions.is_empty() {
            return Err(err(format!(
                "{} stages for {} views",
                stages.len(),
                regions.len()
            )));
        }
        let (w32, h32) = match (u32::try_from(width), u32::try_from(height)) {
            (Ok(w), Ok(h)) if w > 0 && h > 0 => (w, h),
            _ => return Err(err(format!("a {width}×{height} panel"))),
        };
        let row = row_texels(w32);
        let mut views = Vec::new();
        for (region, stage) in regions.iter().zip(stages) {
            let pixels = region.width * region.height;
            if !region.fits((width, height)) {
                return Err(err(format!(
                    "a {}×{} view at ({}, {}) on a {width}×{height} panel",
                    region.width, region.height, region.x, region.y
                )));
            }
            let planes = |label| {
                device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size: 3 * 4 * pixels as u64,
                    usage: wgpu::BufferUsages::STORAGE
                        | wgpu::BufferUsages::COPY_DST
                        | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                })
            };
            let target = CodesTarget {
                row_texels: row,
                base_texel: (region.y as u32) * row + region.x as u32,
                rows: h32,
            };
            let encoder = PanelEncoder::new_into(
                device,
                queue,
                (region.width as u32, region.height as u32),
                pixels as u32,
                transfer,
                target,
            )?;
            views.push(DeviceView {
                region: *region,
                frame: planes("view frame planes"),
                display: planes("view display planes"),
                stage,
                encoder,
                generation: 0,
            });
        }
        let n = views.len();
        let timed = views.iter().any(|v| v.stage.is_some());
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            width,
            height,
            row_texels: row,
            views,
            codes: Vec::new(),
            timer: timed.then(|| PassTimer::new(device, queue, n)).flatten(),
            last_view_ns: vec![None; n],
            last_ran: vec![false; n],
        })
    }

    /// For reports: each view's stage.
    pub fn describe(&self) -> String {
        self.views
            .iter()
            .enumerate()
            .map(|(v, view)| {
                let what = view
                    .stage
                    .as_ref()
                    .map_or("none (the frame as it comes, clamped)".into(), |s| {
                        s.describe()
                    });
                format!("view {v} on the GPU: {what}")
            })
            .collect::<Vec<_>>()
            .join("; ")
    }

    /// Each view's own device time in the last frame, where it ran its
    /// stage and the device has timestamps.
    pub fn last_view_ns(&self) -> &[Option<u64>] {
        &self.last_view_ns
    }

    /// Whether each view ran its stage in the last frame (its image had
    /// changed).
    pub fn last_ran(&self) -> &[bool] {
        &self.last_ran
    }

    fn free_codes(&mut self) -> Arc<wgpu::Buffer> {
        if let Some(c) = self.codes.iter_mut().find_map(|c| {
            Arc::get_mut(c)?;
            Some(c.clone())
        }) {
            return c;
        }
        // Zeroed at creation: outside the views, and in a view that has had
        // no frame, the panel is black.
        let c = Arc::new(self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("panel codes (views)"),
            size: 4 * u64::from(self.row_texels) * self.height as u64,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        }));
        self.codes.push(c.clone());
        c
    }

    /// Uploads the views whose image changed, records every view's stage
    /// (where it changed) and encode into one submission, and waits for it.
    /// A view's generation, once it has had a frame, never goes back to 0
    /// (the service's upload stage counts up): 0 is "no frame yet".
    pub fn run(
        &mut self,
        id: u64,
        images: &[ViewImage],
    ) -> Result<(DeviceDisplayFrame, HostTraffic), PresentError> {
        if images.len() != self.views.len() {
            return Err(err(format!(
                "frame {id}: {} view images for {} views",
                images.len(),
                self.views.len()
            )));
        }
        for (image, view) in images.iter().zip(&self.views) {
            let r = view.region;
            let im = &image.image;
            if image.generation != 0
                && (im.width, im.height, im.channels()) != (r.width, r.height, 3)
            {
                return Err(err(format!(
                    "frame {id}: a {}×{} image for a {}×{} view",
                    im.width, im.height, r.width, r.height
                )));
            }
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let recorded = self.record(images);
        let validation = pollster::block_on(scope.pop());
        if let Some(e) = validation {
            return Err(PresentError::Gpu {
                stage: STAGE,
                source: e.into(),
            });
        }
        let (codes, traffic) = recorded?;
        Ok((
            DeviceDisplayFrame {
                id,
                width: self.width,
                height: self.height,
                codes,
                row_texels: self.row_texels,
                device: self.device.clone(),
                queue: self.queue.clone(),
            },
            traffic,
        ))
    }

    fn record(
        &mut self,
        images: &[ViewImage],
    ) -> Result<(Arc<wgpu::Buffer>, HostTraffic), PresentError> {
        let codes = self.free_codes();
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("device views"),
            });
        let mut traffic = HostTraffic::default();
        let mark = |encoder: &mut wgpu::CommandEncoder, writes| {
            encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("view timestamp"),
                timestamp_writes: Some(writes),
            });
        };
        // Which views were encoded into this submission (their non-finite
        // counts come back with it).
        let mut encoded = vec![false; self.views.len()];
        for (v, (image, view)) in images.iter().zip(&mut self.views).enumerate() {
            self.last_ran[v] = false;
            // No frame for this view yet: its region stays black.
            if image.generation == 0 {
                continue;
            }
            let (w, h) = (view.region.width, view.region.height);
            if image.generation != view.generation {
                let bytes: &[u8] = bytemuck::cast_slice(image.image.data());
                self.queue.write_buffer(&view.frame, 0, bytes);
                traffic.to_device_bytes += bytes.len() as u64;
                traffic.uploads += 1;
                if let Some(stage) = &mut view.stage {
                    if let Some(t) = &self.timer {
                        mark(&mut encoder, t.start(v));
                    }
                    stage
                        .record(&mut encoder, &view.frame, &view.display, w, h)
                        .map_err(PresentError::gpu(STAGE))?;
                    if let Some(t) = &self.timer {
                        mark(&mut encoder, t.end(v));
                    }
                }
                view.generation = image.generation;
                self.last_ran[v] = true;
            }
            let display = if view.stage.is_some() {
                &view.display
            } else {
                &view.frame
            };
            view.encoder.record(&mut encoder, display, &codes)?;
            encoded[v] = true;
        }
        let timer_bytes = self.timer.as_ref().map_or(0, |t| t.resolve(&mut encoder));
        let submission = self.queue.submit([encoder.finish()]);
        let ran: Vec<bool> = self.last_ran.clone();
        for (view, _) in self.views.iter().zip(&encoded).filter(|(_, e)| **e) {
            view.encoder.map_non_finite();
        }
        if let Some(t) = &self.timer {
            t.map();
        }
        nedrt_gpu::wait_for(&self.device, submission).map_err(PresentError::gpu(STAGE))?;
        let spans = self.timer.as_ref().and_then(|t| t.spans_ns().ok());
        for (v, ran) in ran.iter().enumerate() {
            // Only a view that ran a stage wrote its timestamps.
            let staged = *ran && self.views[v].stage.is_some();
            self.last_view_ns[v] = match (&spans, staged) {
                (Some(s), true) => s.get(v).copied(),
                _ => None,
            };
        }
        traffic.to_host_bytes += timer_bytes;
        // Every count read (and its buffer unmapped) before any is judged.
        let mut counts = Vec::new();
        for (v, view) in self.views.iter().enumerate().filter(|(v, _)| encoded[*v]) {
            traffic.to_host_bytes += 4;
            counts.push((v, view.encoder.non_finite_pixels()));
        }
        for (v, count) in counts {
            let non_finite = count?;
            if non_finite > 0 {
                return Err(err(format!(
                    "view {v}: the display image has {non_finite} pixels that are not finite"
                )));
            }
        }
        Ok((codes, traffic))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::test_stage::Stretch;
    use nedrt_core::Image;

    fn image(w: usize, h: usize, seed: usize) -> Image {
        Image::rgb(
            w,
            h,
            (0..3 * w * h)
                .map(|i| ((i * 7 + seed * 13) % 1001) as f32 / 1000.0)
                .collect(),
        )
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn both_eyes_in_one_submission_equal_their_host_twins_in_their_regions() {
        let (device, queue) = nedrt_gpu::test_device(false);
        // 75×21: odd halves (37 and 38 wide), rows padded to 256 bytes.
        let (w, h) = (75usize, 21usize);
        let regions = [
            ViewRegion {
                x: 0,
                y: 0,
                width: 37,
                height: h,
            },
            ViewRegion {
                x: 37,
                y: 0,
                width: 38,
                height: h,
            },
        ];
        let transfer = Transfer::from_gamma([2.2, 2.0, 2.4]);
        let stages: Vec<Option<Box<dyn DeviceStage>>> =
            vec![None, Some(Box::new(Stretch::new(&device)))];
        let mut views =
            DeviceViews::new(&device, &queue, (w, h), &regions, &transfer, stages).expect("views");
        let view = |generation, im: Image| ViewImage {
            generation,
            image: Arc::new(im),
        };
        // The host twin: view 0 as it is, view 1 stretched, each encoded.
        let host = |left: &Image, right: Option<&Image>| -> Vec<u8> {
            let mut panel = vec![0u8; 4 * w * h];
            let mut put = |im: &Image, r: ViewRegion| {
                let mut codes = Vec::new();
                transfer.encode_rgba8(im, &mut codes);
                for y in 0..r.height {
                    for x in 0..r.width {
                        let d = 4 * ((r.y + y) * w + r.x + x);
                        panel[d..d + 4].copy_from_slice(&codes[4 * (y * r.width + x)..][..4]);
                    }
                }
            };
            put(left, regions[0]);
            if let Some(right) = right {
                let mut s = right.clone();
                s.data_mut().iter_mut().for_each(|v| *v = 1.4 * *v - 0.2);
                put(&s, regions[1]);
            }
            panel
        };
        let worst = |a: &[u8], b: &[u8]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| x.abs_diff(*y))
                .max()
                .unwrap_or(0)
        };
        // The right eye has had no frame: black there.
        let (l, r) = (image(37, h, 1), image(38, h, 2));
        let (frame, first) = views
            .run(1, &[view(1, l.clone()), view(0, image(38, h, 0))])
            .expect("runs");
        assert_eq!(frame.width, w);
        let got = frame.to_host().expect("codes").rgba8;
        // The left eye as its host twin; the right black (codes 0).
        assert!(
            worst(&got, &host(&l, None)) <= 1,
            "codes differ by {}",
            worst(&got, &host(&l, None))
        );
        assert_eq!(views.last_ran(), &[true, false]);
        // Both eyes, in one submission.
        let (frame, _) = views
            .run(2, &[view(1, l.clone()), view(2, r.clone())])
            .expect("runs");
        let got = frame.to_host().expect("codes").rgba8;
        assert!(
            worst(&got, &host(&l, Some(&r))) <= 1,
            "codes differ by {}",
            worst(&got, &host(&l, Some(&r)))
        );
        assert_eq!(views.last_ran(), &[false, true]);
        // Unchanged images: nothing goes up, the same panel comes out.
        let (frame, again) = views
            .run(3, &[view(1, l.clone()), view(2, r.clone())])
            .expect("runs");
        assert_eq!(again.uploads, 0);
        assert!(first.uploads >= 1);
        assert_eq!(again.read_backs, 0);
        assert!(worst(&frame.to_host().expect("codes").rgba8, &host(&l, Some(&r))) <= 1);
        // A view image of the wrong size is refused.
        let e = views
            .run(4, &[view(5, image(10, h, 0)), view(2, r)])
            .expect_err("size")
            .to_string();
        assert!(e.contains("a 10×21 image for a 37×21 view"), "{e}");
    }
}
