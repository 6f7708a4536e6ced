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
