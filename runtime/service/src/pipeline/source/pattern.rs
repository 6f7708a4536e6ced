//! A synthetic moving test pattern: colour ramps, a fine checkerboard
//! (the panel's Nyquist detail, where preprocessing matters most) and a
//! white bar sweeping one eighth of the width per second, so dropped or
//! stale frames are visible at a glance. On a panel with two views it is
//! drawn per eye, each view its own frame, the right eye's bar a few pixels
//! to the left of the left eye's (a crossed disparity: the bar floats in
//! front of the pattern).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use super::{Rate, Source, SourceError, SourceRate};
use crate::pipeline::frame::{PixelFormat, SubmittedFrame};
use crate::pipeline::pacing::Clock;
use crate::pipeline::service::Compositor;

/// The pattern at `rate`, `count` frames (`None`: until stopped).
#[derive(Debug)]
pub struct PatternSource {
    width: usize,
    height: usize,
    count: Option<u64>,
    rate: Rate,
}

impl PatternSource {
    pub fn new(
        width: usize,
        height: usize,
        count: Option<u64>,
        rate: SourceRate,
        clock: Arc<dyn Clock>,
    ) -> Self {
        Self {
            width,
            height,
            count,
            rate: Rate::new(rate, clock),
        }
    }
}

pub use nedrt_protocol::test_pattern::{pattern_rgba8, pattern_rgba8_shifted, stereo_disparity_px};

impl Source for PatternSource {
    fn describe(&self) -> String {
        let rate = match self.rate.rate() {
            SourceRate::Display => "each frame made for its refresh".to_string(),
            SourceRate::Hz(hz) => format!("at {hz} Hz"),
        };
        format!("test pattern {}×{} {rate}", self.width, self.height)
    }

    fn run(&mut self, compositor: Compositor, stop: &AtomicBool) -> Result<u64, SourceError> {
        if compositor.view_count() > 1 {
            return self.run_views(&compositor, stop);
        }
        let mut id = 0;
        let per_second = self.rate.frames_per_second(&compositor);
        while self.count.is_none_or(|n| id < n) && !stop.load(Ordering::Relaxed) {
            let made_for = self.rate.wait(&compositor);
            let payload = pattern_rgba8(self.width, self.height, id, per_second);
            let capture_ns = self.rate.made();
            let frame = SubmittedFrame {
                id,
                capture_ns,
                width: self.width,
                height: self.height,
                format: PixelFormat::Rgba8Linear,
                payload,
            };
            let _ = compositor.submit_for(frame, made_for);
            id += 1;
        }
        Ok(id)
    }
}

impl PatternSource {
    /// Each tick a frame per view (ids count submissions); `count` ticks.
    fn run_views(
        &mut self,
        compositor: &Compositor,
        stop: &AtomicBool,
    ) -> Result<u64, SourceError> {
        let (mut tick, mut id) = (0, 0);
        let per_second = self.rate.frames_per_second(compositor);
        while self.count.is_none_or(|n| tick < n) && !stop.load(Ordering::Relaxed) {
            let made_for = self.rate.wait(compositor);
            // Both eyes are made, then submitted with one capture time.
            let frames: Vec<(u8, SubmittedFrame)> = (0..compositor.view_count() as u8)
                .filter_map(|v| {
                    let (w, h) = compositor.view_size(v)?;
                    let shift = usize::from(v) * stereo_disparity_px(w);
                    let frame = SubmittedFrame {
                        id: 0,
                        capture_ns: 0,
                        width: w,
                        height: h,
                        format: PixelFormat::Rgba8Linear,
                        payload: pattern_rgba8_shifted(w, h, tick, per_second, shift),
                    };
                    Some((v, frame))
                })
                .collect();
            let capture_ns = self.rate.made();
            for (v, mut frame) in frames {
                frame.id = id;
                frame.capture_ns = capture_ns;
                let _ = compositor.submit_view_for(v, frame, made_for);
                id += 1;
            }
            tick += 1;
        }
        Ok(id)
    }
}
