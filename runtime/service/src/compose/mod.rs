//! Layers: what applications submit on top of a view's projection layer,
//! blended in linear light before the preprocessing, so the D-CNN or the
//! prefilter sees what the eye should see (issue 33).
//!
//! A [`QuadLayer`] is premultiplied linear RGBA (a menu, a video panel, a
//! HUD) with a [`Placement`] on the view and a z-order. Quads are drawn
//! one texel to one panel pixel: a placement in degrees is rounded to the
//! nearest pixel, not resampled (a sub-pixel shift would need a filter the
//! preprocessing then has to undo; a compositor that wants one renders the
//! quad already shifted). A quad must lie wholly inside its view; one that
//! does not is refused (as a frame of the wrong size is), not clipped.
//!
//! Blending is Porter–Duff *over* with premultiplied colour,
//! `out = c + (1 − a)·below`, quads in ascending z (ties by layer id) over
//! the projection layer. Colour at most alpha (no additive "glow" texels)
//! keeps the composition in the panel's [0, 1] as every frame is:
//! `c + (1 − a)·below ≤ a + (1 − a) = 1`. [`blend`] is the CPU twin of the device kernel
//! [`gpu::LayerBlender`] (`shaders/layer_blend.wgsl`).

pub mod gpu;

use nedrt_core::Image;

/// The most quads blended on one view (the device kernel loops over them
/// for every pixel).
pub const MAX_QUADS: usize = 16;

/// The most quads of one submitter, so that one client cannot take every
/// slot.
pub const MAX_QUADS_PER_OWNER: usize = 8;

pub use nedrt_protocol::Placement;

/// Where a view (an eye) lies on the panel, in panel pixels: side by side
/// on one panel, or each on its own panel of a pair driven as one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct ViewRegion {
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

impl ViewRegion {
    /// Whether it is not empty and lies inside a `width`×`height` panel.
    pub fn fits(&self, (width, height): (usize, usize)) -> bool {
        self.width > 0
            && self.height > 0
            && self.x.checked_add(self.width).is_some_and(|e| e <= width)
            && self.y.checked_add(self.height).is_some_and(|e| e <= height)
    }

    /// The two halves of a `width`×`height` panel, left eye first.
    pub fn side_by_side(width: usize, height: usize) -> [ViewRegion; 2] {
        let half = width / 2;
        [
            ViewRegion {
                x: 0,
                y: 0,
                width: half,
                height,
            },
            ViewRegion {
                x: half,
                y: 0,
                width: width - half,
                height,
            },
        ]
    }
}

/// A view's newest planes (its projection with its quads blended) and a
/// number that changes with them (0: no frame yet).
#[derive(Debug, Clone)]
pub struct ViewImage {
    pub generation: u64,
    pub image: std::sync::Arc<Image>,
}

/// What a quad is placed on: the view's size, and how directions map to
/// its pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewGeometry {
    pub width: usize,
    pub height: usize,
    /// Pixels per unit of tan(angle) at the eyepiece: the panel's distance
    /// to the lens over its pixel pitch (a pixel subtends pitch/distance).
    pub pixels_per_tan: f64,
}

impl ViewGeometry {
    /// The geometry of a view on a panel `pixel_pitch_m` apart, at
    /// `lens_distance_m` from the eyepiece.
    pub fn of_panel(width: usize, height: usize, pixel_pitch_m: f64, lens_distance_m: f64) -> Self {
        Self {
            width,
            height,
            pixels_per_tan: lens_distance_m / pixel_pitch_m,
        }
    }
}

/// A layer above a view's projection layer.
#[derive(Debug, Clone, PartialEq)]
pub struct QuadLayer {
    /// The submitter's name for the layer: a newer submission with the same
    /// id replaces it.
    pub layer: u32,
    /// Higher is nearer the eye; the projection layer is below every quad.
    pub z: i32,
    pub placement: Placement,
    pub width: usize,
    pub height: usize,
    /// Premultiplied linear RGBA, interleaved, row-major; every value in
    /// [0, 1] and each colour at most its alpha.
    pub rgba: Vec<f32>,
}

/// A quad checked and placed: its rectangle on the view. Its texels are
/// shared (a snapshot of the set copies no texels).
#[derive(Debug, Clone, PartialEq)]
pub struct PlacedQuad {
    pub layer: u32,
    pub z: i32,
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
    pub rgba: std::sync::Arc<[f32]>,
}

/// Why a layer is refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LayerError {
    #[error("layer {layer}: {width}×{height} texels (a quad needs at least one)")]
    Empty {
        layer: u32,
        width: usize,
        height: usize,
    },
    #[error("layer {layer}: {got} values for {width}×{height} RGBA texels ({want})")]
    Length {
        layer: u32,
        width: usize,
        height: usize,
        got: usize,
        want: usize,
    },
    #[error("layer {layer}: texel {texel} holds {value}, not a finite value in [0, 1]")]
    OutOfRange {
        layer: u32,
        texel: usize,
        value: f32,
    },
    #[error(
        "layer {layer}: texel {texel} has colour {colour} over alpha {alpha}; premultiplied \
         colour is at most its alpha"
    )]
    NotPremultiplied {
        layer: u32,
        texel: usize,
        colour: f32,
        alpha: f32,
    },
    #[error(
        "layer {layer}: a {width}×{height} quad at ({x}, {y}) is not inside the {view_width}×\
         {view_height} view"
    )]
    Outside {
        layer: u32,
        x: i64,
        y: i64,
        width: usize,
        height: usize,
        view_width: usize,
        view_height: usize,
    },
    #[error("{count} quads on one view; at most {MAX_QUADS}, {MAX_QUADS_PER_OWNER} of one client")]
    TooMany { count: usize },
    #[error(
        "layer {layer}: the view's quads would hold {texels} texels; at most {budget} (twice the \
         view's pixels)"
    )]
    TooLarge {
        layer: u32,
        texels: usize,
        budget: usize,
    },
    #[error(
        "layer {layer}: direction ({x_deg}°, {y_deg}°) is not in front of the eye (each within \
         ±90°)"
    )]
    Direction { layer: u32, x_deg: f64, y_deg: f64 },
    #[error("layer {layer}: view {view} (this service runs {views} view(s))")]
    UnknownView { layer: u32, view: u8, views: usize },
}

/// Premultiplied colour may exceed its alpha by this much (8-bit rounding
/// of a premultiplied texel) before it is refused.
const PREMULTIPLIED_SLACK: f32 = 0.5 / 255.0;

impl QuadLayer {
    /// Checks the texels and places the quad on `view`.
    pub fn place(&self, view: &ViewGeometry) -> Result<PlacedQuad, LayerError> {
        let layer = self.layer;
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return Err(LayerError::Empty {
                layer,
                width: w,
                height: h,
            });
        }
        let want = w.checked_mul(h).and_then(|n| n.checked_mul(4));
        if want != Some(self.rgba.len()) {
            return Err(LayerError::Length {
                layer,
                width: w,
                height: h,
                got: self.rgba.len(),
                want: want.unwrap_or(usize::MAX),
            });
        }
        let mut rgba = self.rgba.clone();
        for (texel, px) in rgba.chunks_exact_mut(4).enumerate() {
            if let Some(&value) = px.iter().find(|v| !(0.0..=1.0).contains(*v)) {
                return Err(LayerError::OutOfRange {
                    layer,
                    texel,
                    value,
                });
            }
            if let Some(&colour) = px[..3].iter().find(|&&c| c > px[3] + PREMULTIPLIED_SLACK) {
                return Err(LayerError::NotPremultiplied {
                    layer,
                    texel,
                    colour,
                    alpha: px[3],
                });
            }
            // Within the slack: held to its alpha, so that the composition
            // stays in [0, 1].
            let alpha = px[3];
            px[..3].iter_mut().for_each(|c| *c = c.min(alpha));
        }
        let (x, y) = match self.placement {
            Placement::Pixels { x, y } => (x, y),
            Placement::Degrees { x_deg, y_deg } => {
                // tan repeats every 180°: a direction behind the eye would
                // land in front of it.
                if !(x_deg.abs() < 90.0 && y_deg.abs() < 90.0) {
                    return Err(LayerError::Direction {
                        layer,
                        x_deg,
                        y_deg,
                    });
                }
                // The centre's pixel: the view's centre plus tan(angle) in
                // pixels, y down on the panel.
                let cx = view.width as f64 / 2.0 + x_deg.to_radians().tan() * view.pixels_per_tan;
                let cy = view.height as f64 / 2.0 - y_deg.to_radians().tan() * view.pixels_per_tan;
                let corner = |c: f64, size: usize| {
                    let v = (c - size as f64 / 2.0).round();
                    // Non-finite or absurd angles land far outside: refused below.
                    if v.is_finite() {
                        v.clamp(-1e15, 1e15) as i64
                    } else {
                        i64::MIN
                    }
                };
                (corner(cx, w), corner(cy, h))
            }
        };
        let inside = x >= 0
            && y >= 0
            && (x as u64).saturating_add(w as u64) <= view.width as u64
            && (y as u64).saturating_add(h as u64) <= view.height as u64;
        if !inside {
            return Err(LayerError::Outside {
                layer,
                x,
                y,
                width: w,
                height: h,
                view_width: view.width,
                view_height: view.height,
            });
        }
        Ok(PlacedQuad {
            layer,
            z: self.z,
            x: x as usize,
            y: y as usize,
            width: w,
            height: h,
            rgba: rgba.into(),
        })
    }
}

/// The quads now on a view: the newest submission of each layer of each
/// submitter (a client of the socket, an in-process caller). Shared by the
/// submitters (who set and remove) and the stage that blends (which takes
/// a [`LayerSnapshot`] per frame, never waiting on a submitter).
#[derive(Debug, Default)]
pub struct LayerSet {
    inner: std::sync::Mutex<LayerState>,
}

#[derive(Debug, Default)]
struct LayerState {
    quads: std::collections::BTreeMap<(u64, u32), PlacedQuad>,
    generation: u64,
    snapshot: Option<LayerSnapshot>,
}

/// The quads of a view at one moment, and a number that changes whenever
/// they do (the device blender uploads texels only then).
#[derive(Debug, Clone)]
pub struct LayerSnapshot {
    pub quads: std::sync::Arc<[PlacedQuad]>,
    pub generation: u64,
}

impl LayerSet {
    fn state(&self) -> std::sync::MutexGuard<'_, LayerState> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Sets (or replaces) `owner`'s layer `quad.layer`. Refused when the
    /// view would hold more than [`MAX_QUADS`] (or the owner more than
    /// [`MAX_QUADS_PER_OWNER`]), or its quads more than `texel_budget`
    /// texels.
    pub fn set(&self, owner: u64, quad: PlacedQuad, texel_budget: usize) -> Result<(), LayerError> {
        let mut s = self.state();
        let key = (owner, quad.layer);
        let replaced = s.quads.get(&key).map_or(0, |q| q.width * q.height);
        if replaced == 0 {
            let owned = s.quads.keys().filter(|(o, _)| *o == owner).count();
            if s.quads.len() >= MAX_QUADS || owned >= MAX_QUADS_PER_OWNER {
                return Err(LayerError::TooMany {
                    count: s.quads.len() + 1,
                });
            }
        }
        let texels: usize = s.quads.values().map(|q| q.width * q.height).sum::<usize>() - replaced
            + quad.width * quad.height;
        if texels > texel_budget {
            return Err(LayerError::TooLarge {
                layer: quad.layer,
                texels,
                budget: texel_budget,
            });
        }
        s.quads.insert(key, quad);
        s.generation += 1;
        s.snapshot = None;
        Ok(())
    }

    /// Removes `owner`'s layer `layer`; whether it was there.
    pub fn remove(&self, owner: u64, layer: u32) -> bool {
        let mut s = self.state();
        let removed = s.quads.remove(&(owner, layer)).is_some();
        if removed {
            s.generation += 1;
            s.snapshot = None;
        }
        removed
    }

    /// Removes every layer of `owner` (a client that left); how many.
    pub fn remove_owner(&self, owner: u64) -> usize {
        let mut s = self.state();
        let before = s.quads.len();
        s.quads.retain(|&(o, _), _| o != owner);
        let removed = before - s.quads.len();
        if removed > 0 {
            s.generation += 1;
            s.snapshot = None;
        }
        removed
    }

    /// The quads now, in [`blend_order`] (shared until the next change).
    pub fn snapshot(&self) -> LayerSnapshot {
        let mut s = self.state();
        if let Some(snap) = &s.snapshot {
            return snap.clone();
        }
        let mut quads: Vec<PlacedQuad> = s.quads.values().cloned().collect();
        blend_order(&mut quads);
        let snap = LayerSnapshot {
            quads: quads.into(),
            generation: s.generation,
        };
        s.snapshot = Some(snap.clone());
        snap
    }
}

/// The quads in blending order: ascending z, ties by layer id.
pub fn blend_order(quads: &mut [PlacedQuad]) {
    quads.sort_by_key(|q| (q.z, q.layer));
}

/// Blends `quads` over the projection layer `view` (linear RGB planes), in
/// [`blend_order`]: the CPU twin of [`gpu::LayerBlender`].
pub fn blend(view: &mut Image, quads: &[PlacedQuad]) -> Result<(), LayerError> {
    if quads.len() > MAX_QUADS {
        return Err(LayerError::TooMany { count: quads.len() });
    }
    let mut order: Vec<&PlacedQuad> = quads.iter().collect();
    order.sort_by_key(|q| (q.z, q.layer));
    let width = view.width;
    for q in order {
        for c in 0..3 {
            let plane = view.plane_mut(c);
            for row in 0..q.height {
                let dst = &mut plane[(q.y + row) * width + q.x..][..q.width];
                let src = &q.rgba[4 * row * q.width..][..4 * q.width];
                for (d, s) in dst.iter_mut().zip(src.chunks_exact(4)) {
                    // The kernel's fma (fused or not: equal within 1e-5).
                    *d = (1.0 - s[3]).mul_add(*d, s[c]);
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
