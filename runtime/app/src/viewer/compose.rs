//! The side-by-side picture of the viewer and the sweeps: one column per
//! method (its name, the image, the accommodation, PSNR against the sharp
//! image and the target, and an inset of the channel PSFs), a slider of the
//! accommodation under them, and in the window a line of key help. Text is
//! drawn with plotters in the embedded font; the images are then copied in
//! code for code, so a column shows exactly the 8-bit perceived image.

use std::sync::Arc;

use plotters::prelude::*;

use super::scene::{FocusScene, PSF_INSET_PX, Rendered, Shown};
use crate::AppError;

const PAD: usize = 8;
const HEADER: usize = 26;
/// The labels and the PSF inset (its caption above it: `INSET_TOP`).
const FOOTER: usize = INSET_TOP + PSF_INSET_PX + PAD;
const INSET_TOP: usize = PAD + 10;
const SLIDER: usize = 64;
const HELP: usize = 22;
/// The narrowest column: room for the labels beside the PSF inset.
const MIN_COLUMN: usize = 300;
const TRACK_MARGIN: usize = 40;

const BACKGROUND: RGBColor = RGBColor(28, 28, 32);
const TEXT: RGBColor = RGBColor(235, 235, 235);
const DIM: RGBColor = RGBColor(150, 150, 160);
const ACCENT: RGBColor = RGBColor(255, 190, 60);

/// The help line of the window.
pub const KEY_HELP: &str = "←/→ or wheel: 0.05 D · PgUp/PgDn: 0.5 D · drag the slider · \
                            space: sweep · s/t/p: sharp/target/perceived · c: screenshot · q: quit";

/// Where everything sits in the picture, in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    pub width: usize,
    pub height: usize,
    /// Each panel image's size (the retinal grid).
    pub image_width: usize,
    pub image_height: usize,
    pub columns: usize,
    column_width: usize,
    help: bool,
}

/// An RGB8 picture.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Picture {
    pub width: usize,
    pub height: usize,
    /// Interleaved RGB8, row-major.
    pub rgb8: Vec<u8>,
}

impl Picture {
    /// Interleaved RGBA8 (alpha 255), what the window draws.
    pub fn rgba8(&self) -> Vec<u8> {
        self.rgb8
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect()
    }
}

impl Layout {
    pub fn new(columns: usize, image_width: usize, image_height: usize, help: bool) -> Self {
        let column_width = image_width.max(MIN_COLUMN);
        Self {
            width: PAD + columns * (column_width + PAD),
            height: PAD
                + HEADER
                + image_height
                + FOOTER
                + SLIDER
                + if help { HELP } else { 0 }
                + PAD,
            image_width,
            image_height,
            columns,
            column_width,
            help,
        }
    }

    /// For a scene.
    pub fn of(scene: &FocusScene, help: bool) -> Self {
        Self::new(scene.methods.len(), scene.width, scene.height, help)
    }

    fn column_x(&self, column: usize) -> usize {
        PAD + column * (self.column_width + PAD)
    }

    /// Top-left corner of column `column`'s image.
    pub fn image_origin(&self, column: usize) -> (usize, usize) {
        (
            self.column_x(column) + (self.column_width - self.image_width) / 2,
            PAD + HEADER,
        )
    }

    /// The labels under column `column`'s image: x, y, width, height.
    pub fn label_area(&self, column: usize) -> (usize, usize, usize, usize) {
        (
            self.column_x(column),
            PAD + HEADER + self.image_height,
            self.column_width,
            FOOTER,
        )
    }

    fn slider_y(&self) -> usize {
        PAD + HEADER + self.image_height + FOOTER
    }

    /// The slider's track: x at 0 and at `max_d`, and its row.
    pub(crate) fn track(&self) -> (f64, f64, i32) {
        (
            (PAD + TRACK_MARGIN) as f64,
            (self.width - PAD - TRACK_MARGIN) as f64,
            (self.slider_y() + 30) as i32,
        )
    }

    fn track_x(&self, accommodation_d: f64, max_d: f64) -> i32 {
        let (x0, x1, _) = self.track();
        (x0 + (x1 - x0) * (accommodation_d / max_d).clamp(0.0, 1.0)).round() as i32
    }

    /// The accommodation a point of the slider's band stands for, if the
    /// point is on the band.
    pub fn accommodation_at(&self, x: f64, y: f64, max_d: f64) -> Option<f64> {
        let band = self.slider_y() as f64..(self.slider_y() + SLIDER) as f64;
        if !band.contains(&y) {
            return None;
        }
        let (x0, x1, _) = self.track();
        Some(((x - x0) / (x1 - x0)).clamp(0.0, 1.0) * max_d)
    }
}

fn draw_err(e: impl std::fmt::Display) -> AppError {
    AppError::Draw(e.to_string())
}

/// The picture of every method at grid depth `depth`.
pub fn compose(
    scene: &FocusScene,
    layout: &Layout,
    depth: usize,
    shown: Shown,
    rendered: &[Arc<Rendered>],
) -> Result<Picture, AppError> {
    crate::charts::register_font();
    let accommodation_d = scene.depths_d[depth];
    let max_d = scene.slider_max_d();
    let (w, h) = (layout.width, layout.height);
    let mut rgb8 = vec![0u8; 3 * w * h];
    {
        let root = BitMapBackend::with_buffer(&mut rgb8, (w as u32, h as u32)).into_drawing_area();
        root.fill(&BACKGROUND).map_err(draw_err)?;
        let font = |size: u32, color: &RGBColor| ("sans-serif", size).into_font().color(color);
        let main = scene.is_main_depth(accommodation_d);
        for (i, (label, r)) in scene.labels.iter().zip(rendered).enumerate() {
            let (x, _) = (layout.column_x(i) as i32, 0);
            root.draw(&Text::new(
                format!("{label}  ·  {}", shown.label()),
                (x, (PAD + 4) as i32),
                font(16, &TEXT),
            ))
            .map_err(draw_err)?;
            let (lx, ly, lw, _) = layout.label_area(i);
            let (lx, ly) = (lx as i32, (ly + PAD) as i32);
            let depth_line = format!(
                "{accommodation_d:.2} D{}",
                if main { "  (main depth)" } else { "" }
            );
            let lines = [
                (depth_line, if main { ACCENT } else { TEXT }),
                (format!("vs sharp   {:6.2} dB", r.vs_sharp_db), TEXT),
                (format!("vs target  {:6.2} dB", r.vs_target_db), TEXT),
                ("PSNR of the perceived image".to_string(), DIM),
            ];
            for (k, (line, color)) in lines.iter().enumerate() {
                root.draw(&Text::new(
                    line.clone(),
                    (lx, ly + 22 * k as i32),
                    font(if k == 3 { 12 } else { 15 }, color),
                ))
                .map_err(draw_err)?;
            }
            let inset_x = lx + (lw - PSF_INSET_PX) as i32;
            root.draw(&Text::new("PSF R G B", (inset_x, ly - 2), font(11, &DIM)))
                .map_err(draw_err)?;
        }
        // The slider: ticks every 0.5 D, the main depths marked, the handle.
        let (x0, x1, ty) = layout.track();
        root.draw(&PathElement::new(
            vec![(x0 as i32, ty), (x1 as i32, ty)],
            DIM.stroke_width(2),
        ))
        .map_err(draw_err)?;
        let ticks = (max_d / 0.5).round() as usize;
        for k in 0..=ticks {
            let d = k as f64 * 0.5;
            let x = layout.track_x(d, max_d);
            let color = if scene.is_main_depth(d) { ACCENT } else { DIM };
            root.draw(&PathElement::new(
                vec![(x, ty - 6), (x, ty + 6)],
                color.stroke_width(2),
            ))
            .map_err(draw_err)?;
            root.draw(&Text::new(
                format!("{d:.1}"),
                (x - 9, ty + 10),
                font(12, &color),
            ))
            .map_err(draw_err)?;
        }
        let hx = layout.track_x(accommodation_d, max_d);
        root.draw(&Circle::new((hx, ty), 7, ACCENT.filled()))
            .map_err(draw_err)?;
        let sy = layout.slider_y() as i32;
        root.draw(&Text::new(
            format!("accommodation {accommodation_d:.2} D"),
            (x0 as i32, sy + 2),
            font(15, &TEXT),
        ))
        .map_err(draw_err)?;
        root.draw(&Text::new(
            format!("{}   (main depths marked)", scene.input_name),
            (x0 as i32 + 220, sy + 4),
            font(12, &DIM),
        ))
        .map_err(draw_err)?;
        if layout.help {
            root.draw(&Text::new(
                KEY_HELP,
                (PAD as i32, (layout.slider_y() + SLIDER) as i32),
                font(12, &DIM),
            ))
            .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    let mut blit = |x: usize, y: usize, iw: usize, ih: usize, src: &[u8]| {
        for row in 0..ih {
            let dst = 3 * ((y + row) * w + x);
            rgb8[dst..dst + 3 * iw].copy_from_slice(&src[3 * row * iw..3 * (row + 1) * iw]);
        }
    };
    for (i, r) in rendered.iter().enumerate() {
        let (x, y) = layout.image_origin(i);
        let image = scene.shown_rgb8(shown, r, depth);
        blit(x, y, layout.image_width, layout.image_height, image);
        let (lx, ly, lw, _) = layout.label_area(i);
        blit(
            lx + lw - PSF_INSET_PX,
            ly + INSET_TOP,
            PSF_INSET_PX,
            PSF_INSET_PX,
            &r.psf_inset_rgb8,
        );
    }
    Ok(Picture {
        width: w,
        height: h,
        rgb8,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_slider_maps_its_ends_to_zero_and_the_largest_depth() {
        let l = Layout::new(3, 64, 64, true);
        let (x0, x1, ty) = l.track();
        let y = f64::from(ty);
        assert_eq!(l.accommodation_at(x0, y, 3.0), Some(0.0));
        assert_eq!(l.accommodation_at(x1, y, 3.0), Some(3.0));
        assert_eq!(l.accommodation_at(x1 + 50.0, y, 3.0), Some(3.0));
        let mid = l
            .accommodation_at((x0 + x1) / 2.0, y, 3.0)
            .expect("on the band");
        assert!((mid - 1.5).abs() < 1e-9);
        assert_eq!(l.accommodation_at(x0, 0.0, 3.0), None, "above the band");
        assert_eq!(l.track_x(1.5, 3.0), ((x0 + x1) / 2.0).round() as i32);
    }

    #[test]
    fn columns_and_labels_do_not_overlap() {
        let l = Layout::new(3, 400, 100, false);
        for i in 0..3 {
            let (x, y) = l.image_origin(i);
            let (lx, ly, lw, lh) = l.label_area(i);
            assert!(x + l.image_width <= lx + lw && x >= lx);
            assert_eq!(ly, y + l.image_height);
            assert!(ly + lh <= l.slider_y());
            assert!(
                ly + INSET_TOP + PSF_INSET_PX <= ly + lh,
                "the PSF inset ends inside the label area"
            );
            if i + 1 < 3 {
                assert!(lx + lw < l.label_area(i + 1).0);
            }
        }
        assert!(l.slider_y() + SLIDER + PAD <= l.height);
        assert_eq!(l.width, PAD + 3 * (400 + PAD));
    }
}
