//! What the study measures with: the host's name, the latency frame, the
//! timed median.

use std::time::Instant;

use crate::bench::median;
use nedrt_optics::sim::Image;

/// This machine's CPU and core count, for the chart and the table.
pub fn host_description() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    format!("{cpu}, {cores} cores")
}

/// A deterministic frame of `size` with edges and gradients (latency does
/// not depend on content; the values only keep every path busy).
pub fn latency_frame(size: (usize, usize)) -> Image {
    let (w, h) = size;
    let planes = (0..3)
        .map(|c| {
            (0..w * h)
                .map(|i| {
                    let (x, y) = (i % w, i / w);
                    (((x * (c + 3) + y * 7) % 97) as f32 / 96.0) * 0.8 + 0.1
                })
                .collect()
        })
        .collect();
    Image::from_planes(w, h, planes)
}

/// Median seconds of `repeat` timed calls after one warm-up.
pub(super) fn time_median<E>(
    repeat: usize,
    mut f: impl FnMut() -> Result<(), E>,
) -> Result<f64, E> {
    f()?;
    let mut times = Vec::new();
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        f()?;
        times.push(t.elapsed().as_secs_f64());
    }
    Ok(median(times))
}

/// A configuration's displays of the images and its latency on the frame.
pub(super) struct Measured {
    pub(super) displays: Vec<Image>,
    /// Measured, or (when measuring would take too long) estimated.
    pub(super) latency_ms: Option<f64>,
    pub(super) estimated_ms: Option<f64>,
}

/// `run` on each of `inputs` (their displays, for the quality), then its
/// latency on `frame`: the median of `repeat` timed runs, or, where that
/// would take longer than `max_seconds` in all (judged from the last,
/// warm input's time per pixel), an estimate, warned for `name`.
pub(super) fn displays_and_latency<E>(
    name: &str,
    inputs: &[Image],
    frame: &Image,
    repeat: usize,
    max_seconds: f64,
    mut run: impl FnMut(&Image) -> Result<Image, E>,
) -> Result<Measured, E> {
    let mut seconds_per_pixel = 0.0;
    let mut displays = Vec::with_capacity(inputs.len());
    for input in inputs {
        let t = Instant::now();
        displays.push(run(input)?);
        seconds_per_pixel = t.elapsed().as_secs_f64() / (input.width * input.height) as f64;
    }
    let estimate = seconds_per_pixel * (frame.width * frame.height) as f64;
    if estimate * (repeat + 1) as f64 > max_seconds {
        tracing::warn!(
            "{name}: latency at {}×{} not measured (≈ {estimate:.1} s per frame, over --max-seconds)",
            frame.width,
            frame.height
        );
        return Ok(Measured {
            displays,
            latency_ms: None,
            estimated_ms: Some(estimate * 1e3),
        });
    }
    let seconds = time_median(repeat, || {
        std::hint::black_box(run(frame)?);
        Ok(())
    })?;
    Ok(Measured {
        displays,
        latency_ms: Some(seconds * 1e3),
        estimated_ms: None,
    })
}
