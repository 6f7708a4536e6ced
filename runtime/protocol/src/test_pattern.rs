//! The service's test pattern, as RGBA8: what `nedrt run --source pattern`
//! draws, and what a protocol client can stream to get the same pixels
//! (`examples/stream_client.rs`). Colour ramps, a fine checkerboard (the
//! panel's Nyquist detail, where preprocessing matters most) and a white
//! bar sweeping one eighth of the width per second, so dropped or stale
//! frames are visible at a glance.

/// Frame `id` of the pattern as RGBA8 (linear values).
pub fn pattern_rgba8(width: usize, height: usize, id: u64, rate_hz: f64) -> Vec<u8> {
    pattern_rgba8_shifted(width, height, id, rate_hz, 0)
}

/// The bar's disparity between the eyes, pixels: 1/64 of a view's width.
pub fn stereo_disparity_px(view_width: usize) -> usize {
    (view_width / 64).max(1)
}

/// As [`pattern_rgba8`] with the bar `shift` pixels to the left (the right
/// eye's view of it).
pub fn pattern_rgba8_shifted(
    width: usize,
    height: usize,
    id: u64,
    rate_hz: f64,
    shift: usize,
) -> Vec<u8> {
    let mut out = vec![255u8; 4 * width * height];
    let per_second = if rate_hz > 0.0 { rate_hz } else { 90.0 };
    let bar_w = (width / 16).max(1);
    let sweep = ((id as f64 / per_second) * width as f64 / 8.0) as usize;
    let bar_x = (sweep + width.max(1) - shift % width.max(1)) % width.max(1);
    for y in 0..height {
        for x in 0..width {
            let px = &mut out[4 * (y * width + x)..4 * (y * width + x) + 4];
            let in_bar = (x + width - bar_x) % width < bar_w;
            if in_bar {
                px[..3].fill(255);
            } else if y < height / 2 {
                px[0] = (255 * x / width.max(1)) as u8;
                px[1] = (255 * y / height.max(1)) as u8;
                px[2] = 255 - px[0];
            } else {
                let v = if (x + y) % 2 == 0 { 230 } else { 25 };
                px[..3].fill(v);
            }
        }
    }
    out
}
