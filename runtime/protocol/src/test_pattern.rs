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
    if width == 0 || height == 0 {
        return out;
    }
    let per_second = if rate_hz > 0.0 { rate_hz } else { 90.0 };
    let bar_w = (width / 16).max(1);
    let sweep = ((id as f64 / per_second) * width as f64 / 8.0) as usize;
    let bar_x = (sweep + width - shift % width) % width;
    // Rows of a kind differ only in the ramp's green: each kind is drawn
    // once and copied (a pixel at a time, 1920×1080 took 7 ms, longer
    // than a 90 Hz source can give it with the pipeline's own time).
    let mut ramp = vec![255u8; 4 * width];
    for (x, px) in ramp.chunks_exact_mut(4).enumerate() {
        px[0] = (255 * x / width) as u8;
        px[2] = 255 - px[0];
    }
    let checker = |parity: usize| -> Vec<u8> {
        (0..width)
            .flat_map(|x| {
                let v = if (x + parity).is_multiple_of(2) {
                    230
                } else {
                    25
                };
                [v, v, v, 255]
            })
            .collect()
    };
    let checkers = [checker(0), checker(1)];
    for (y, row) in out.chunks_exact_mut(4 * width).enumerate() {
        if y < height / 2 {
            row.copy_from_slice(&ramp);
            let green = (255 * y / height) as u8;
            row.chunks_exact_mut(4).for_each(|px| px[1] = green);
        } else {
            row.copy_from_slice(&checkers[y % 2]);
        }
        for k in 0..bar_w.min(width) {
            let x = (bar_x + k) % width;
            row[4 * x..4 * x + 3].fill(255);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The pattern a pixel at a time, as it was first written: the oracle.
    fn per_pixel(width: usize, height: usize, id: u64, rate_hz: f64, shift: usize) -> Vec<u8> {
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
                    let v = if (x + y).is_multiple_of(2) { 230 } else { 25 };
                    px[..3].fill(v);
                }
            }
        }
        out
    }

    #[test]
    fn the_panel_sized_pattern_is_the_per_pixel_one() {
        for (id, shift) in [(0, 0), (37, 0), (1000, 30), (7, 5000)] {
            assert!(
                pattern_rgba8_shifted(1920, 1080, id, 90.0, shift)
                    == per_pixel(1920, 1080, id, 90.0, shift),
                "frame {id}, shift {shift}"
            );
        }
    }

    proptest! {
        #[test]
        fn the_pattern_is_the_per_pixel_one(
            width in 0usize..70,
            height in 0usize..9,
            id in 0u64..100_000,
            rate in prop_oneof![Just(0.0), 1.0f64..500.0],
            shift in 0usize..200,
        ) {
            prop_assert_eq!(
                pattern_rgba8_shifted(width, height, id, rate, shift),
                per_pixel(width, height, id, rate, shift)
            );
        }
    }
}
