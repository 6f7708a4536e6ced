//! Test content unlike the D-CNN's training data (natural images and
//! dead leaves): text, line art, saturated colours, noise, flat fields,
//! full black and full white. Procedural and deterministic, so the study
//! needs no files.

use crate::synth::SplitMix;
use nedrt_core::Image;

/// A named test frame.
#[derive(Debug, Clone)]
pub struct Content {
    pub name: &'static str,
    pub image: Image,
}

fn grey(size: usize, f: impl Fn(usize, usize) -> f32) -> Image {
    let plane: Vec<f32> = (0..size * size).map(|i| f(i % size, i / size)).collect();
    Image::from_planes(size, size, vec![plane.clone(), plane.clone(), plane])
}

/// Black glyph-like strokes one to three pixels wide on white, like small
/// text: 5×7-cell characters drawn from a fixed random stroke set.
fn text(size: usize) -> Image {
    let mut rng = SplitMix::new(7);
    let mut ink = vec![false; size * size];
    let (cw, ch) = (6, 9);
    for row in 0..size / ch {
        for col in 0..size / cw {
            // Five to nine strokes per glyph on a 5×7 cell grid.
            let strokes = 5 + (rng.next_u64() % 5) as usize;
            for _ in 0..strokes {
                let x = (rng.next_u64() % 5) as usize;
                let y = (rng.next_u64() % 7) as usize;
                let horizontal = rng.next_u64().is_multiple_of(2);
                for t in 0..3 {
                    let (gx, gy) = if horizontal { (x + t, y) } else { (x, y + t) };
                    let (px, py) = (col * cw + gx.min(4), row * ch + gy.min(6) + 1);
                    if px < size && py < size {
                        ink[py * size + px] = true;
                    }
                }
            }
        }
    }
    grey(size, |x, y| if ink[y * size + x] { 0.0 } else { 1.0 })
}

/// One-pixel black lines (a grid and diagonals) on white.
fn line_art(size: usize) -> Image {
    grey(size, |x, y| {
        let on = x % 16 == 0 || y % 16 == 0 || (x + y) % 23 == 0 || x.abs_diff(y) % 31 == 0;
        if on { 0.0 } else { 1.0 }
    })
}

/// Fully saturated primaries and secondaries in bars and checks: every
/// value is 0 or 1, channels disagree everywhere.
fn saturated(size: usize) -> Image {
    let colours: [[f32; 3]; 6] = [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 1.0],
        [1.0, 0.0, 1.0],
    ];
    let planes = (0..3)
        .map(|c| {
            (0..size * size)
                .map(|i| {
                    let (x, y) = (i % size, i / size);
                    let k = (x * 6 / size + (y / 8) % 2 * 3) % 6;
                    colours[k][c]
                })
                .collect()
        })
        .collect();
    Image::from_planes(size, size, planes)
}

/// Independent uniform noise in every pixel and channel (no 1/f spectrum).
fn noise(size: usize) -> Image {
    let mut rng = SplitMix::new(11);
    let planes = (0..3)
        .map(|_| (0..size * size).map(|_| rng.unit()).collect())
        .collect();
    Image::from_planes(size, size, planes)
}

/// The content set of the study, `size`×`size` frames.
pub fn content_set(size: usize) -> Vec<Content> {
    vec![
        Content {
            name: "text",
            image: text(size),
        },
        Content {
            name: "line art",
            image: line_art(size),
        },
        Content {
            name: "saturated colours",
            image: saturated(size),
        },
        Content {
            name: "noise",
            image: noise(size),
        },
        Content {
            name: "flat grey 0.5",
            image: grey(size, |_, _| 0.5),
        },
        Content {
            name: "full black",
            image: grey(size, |_, _| 0.0),
        },
        Content {
            name: "full white",
            image: grey(size, |_, _| 1.0),
        },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_set_is_in_range_deterministic_and_as_named() {
        let a = content_set(64);
        let b = content_set(64);
        assert_eq!(a.len(), 7);
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(x.image.data(), y.image.data(), "{}", x.name);
            assert!(x.image.planes().flatten().all(|v| (0.0..=1.0).contains(v)));
        }
        let mean = |c: &Content| c.image.plane_means().iter().sum::<f64>() / 3.0;
        assert_eq!(mean(&a[5]), 0.0);
        assert_eq!(mean(&a[6]), 1.0);
        let ink = mean(&a[0]);
        assert!(ink > 0.5 && ink < 0.97, "text is mostly paper: {ink}");
        assert!(
            a[2].image
                .planes()
                .flatten()
                .all(|v| *v == 0.0 || *v == 1.0)
        );
        assert!((mean(&a[3]) - 0.5).abs() < 0.02);
    }
}
