//! Field zones (docs/model.md §4b): where the eye's pupil is the stop, the
//! part of the eyepiece it looks through moves with the field angle, so the
//! PSF changes across the image. The perceived image is then rendered once
//! per zone of field angle, each through the PSFs at its centre, and the
//! renderings are blended with bilinear weights between the zone centres
//! (the piecewise-shift-invariant model with interpolation, Nagy and
//! O'Leary 1998). The planner chooses the number of zones from a tolerance
//! and says what it chose; the paper's eye (no pupil) is one zone exactly.

use super::metrics::psnr;
use super::simulator::{Prepared, Simulator};
use super::{Method, SimError};
use nedrt_core::Progress;
use nedrt_core::calib::Calibration;
use nedrt_core::image::Image;

/// Most zones the planner puts along one axis.
pub const MAX_ZONES_PER_AXIS: usize = 8;
/// The planner's default: a zone's PSF, rendered, within this PSNR of its
/// neighbours' (about 1 % RMS of the full scale).
pub const DEFAULT_TOLERANCE_DB: f64 = 40.0;

/// How many zones to render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ZoneRequest {
    /// As many as the tolerance needs (dB, between a zone's centre and its edge).
    Auto { tolerance_db: f64 },
    /// Columns × rows, whatever the optics.
    Fixed(usize, usize),
}

impl Default for ZoneRequest {
    fn default() -> Self {
        Self::Auto {
            tolerance_db: DEFAULT_TOLERANCE_DB,
        }
    }
}

impl std::str::FromStr for ZoneRequest {
    type Err = String;
    /// `auto`, `N` (N × N) or `NxM` (N columns, M rows).
    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim();
        if s == "auto" {
            return Ok(Self::default());
        }
        let bad = || {
            format!(
                "{s:?}: give auto, N or NxM with 1 ≤ N, M ≤ {MAX_ZONES_PER_AXIS} (e.g. 3 or 3x2)"
            )
        };
        let count = |t: &str| -> Result<usize, String> {
            t.parse::<usize>()
                .ok()
                .filter(|n| (1..=MAX_ZONES_PER_AXIS).contains(n))
                .ok_or_else(bad)
        };
        match s.split_once(['x', '×']) {
            Some((a, b)) => Ok(Self::Fixed(count(a)?, count(b)?)),
            None => count(s).map(|n| Self::Fixed(n, n)),
        }
    }
}

/// Where each display pixel lies in the field: the image's centre at the
/// calibration's field angle (`eye.field_rad`, horizontal), columns to the
/// right and rows downwards as the image's, each display pixel
/// `pixel_pitch / z_d` wide as seen from the lens, (1 + e V)⁻¹ of that as
/// seen from the eye's pupil e behind it (V the design channel's image
/// vergence).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldGeometry {
    pub width: usize,
    pub height: usize,
    /// tan of the field angle at the image's centre, horizontal.
    pub centre_tan_x: f64,
    /// tan of the angle one display pixel spans from the eye's pupil.
    pub tan_per_px: f64,
}

impl FieldGeometry {
    pub fn of(calib: &Calibration, width: usize, height: usize) -> Self {
        let v = calib.vergence_d(calib.design_channel);
        Self {
            width,
            height,
            centre_tan_x: calib.eye.field_rad.tan(),
            tan_per_px: calib.pixel_pitch_m
                / calib.lens_distance_m
                / (1.0 + calib.eye.relief_m * v),
        }
    }

    /// tan of the field angles (horizontal, vertical) at display position
    /// (`x`, `y`), in pixels from the image's top-left corner.
    pub fn tan_at(&self, x: f64, y: f64) -> (f64, f64) {
        (
            self.centre_tan_x + (x - 0.5 * self.width as f64) * self.tan_per_px,
            (y - 0.5 * self.height as f64) * self.tan_per_px,
        )
    }
}

/// The zones chosen: `nx` × `ny` rectangles of equal size over the image.
#[derive(Debug, Clone, PartialEq)]
pub struct ZonePlan {
    pub nx: usize,
    pub ny: usize,
    pub field: FieldGeometry,
    /// Why this many, for the report.
    pub note: String,
}

impl ZonePlan {
    /// The centre of zone (`i`, `j`) in display pixels.
    pub fn centre_px(&self, i: usize, j: usize) -> (f64, f64) {
        (
            (i as f64 + 0.5) * self.field.width as f64 / self.nx as f64,
            (j as f64 + 0.5) * self.field.height as f64 / self.ny as f64,
        )
    }

    /// tan of the field angles at zone (`i`, `j`)'s centre.
    pub fn tan_at_zone(&self, i: usize, j: usize) -> (f64, f64) {
        let (x, y) = self.centre_px(i, j);
        self.field.tan_at(x, y)
    }

    /// Blends renderings on the retinal grid (2× the display's, row-major
    /// zones: `rendered[j * nx + i]`) with bilinear weights between the
    /// zone centres; beyond the outermost centres a zone's rendering holds.
    /// The weights sum to 1 at every pixel.
    pub fn blend(&self, rendered: &[Image]) -> Image {
        assert_eq!(rendered.len(), self.nx * self.ny, "one rendering per zone");
        let first = &rendered[0];
        let (w, h) = (first.width, first.height);
        // Retinal pixel k's centre in zone-index units along an axis of
        // `n` zones over `cells` retinal pixels: zone i's centre is at i.
        let axis = |cells: usize, n: usize| -> Vec<(usize, usize, f32)> {
            (0..cells)
                .map(|k| {
                    let t = (k as f64 + 0.5) * n as f64 / cells as f64 - 0.5;
                    let t = t.clamp(0.0, (n - 1) as f64);
                    let lo = (t.floor() as usize).min(n - 1);
                    let hi = (lo + 1).min(n - 1);
                    (lo, hi, (t - lo as f64) as f32)
                })
                .collect()
        };
        let (ax, ay) = (axis(w, self.nx), axis(h, self.ny));
        let planes = (0..first.channels())
            .map(|c| {
                let zone_planes: Vec<&[f32]> = rendered.iter().map(|r| r.plane(c)).collect();
                let mut out = vec![0.0f32; w * h];
                for (y, &(j0, j1, fy)) in ay.iter().enumerate() {
                    for (x, &(i0, i1, fx)) in ax.iter().enumerate() {
                        let k = y * w + x;
                        let at = |i: usize, j: usize| zone_planes[j * self.nx + i][k];
                        out[k] = (1.0 - fy) * ((1.0 - fx) * at(i0, j0) + fx * at(i1, j0))
                            + fy * ((1.0 - fx) * at(i0, j1) + fx * at(i1, j1));
                    }
                }
                out
            })
            .collect();
        Image::from_planes(w, h, planes)
    }
}

/// PSFs prepared per zone: the perceived image and the target rendered by
/// zones. One zone is the simulator's own preparation, exactly.
pub struct Zoned {
    pub plan: ZonePlan,
    /// Row-major; `None` where the zone is the centre's preparation.
    zones: Vec<Option<Prepared>>,
    /// Each zone's rendering of the display image the zones were planned
    /// for (row-major; empty with one zone): the planner measures them,
    /// and the perceived image blends them.
    rendered: Vec<Image>,
    /// Worst PSNR between the renderings of neighbouring zones (`None`
    /// with one zone): how far apart the interpolation reaches.
    pub neighbours_db: Option<f64>,
}

impl std::fmt::Debug for Zoned {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Zoned({}×{})", self.plan.nx, self.plan.ny)
    }
}

impl Simulator {
    /// The same simulator looking at field angles with tangents
    /// (`tan_x`, `tan_y`): the eye's pupil projected where that field's
    /// rays cross the lens plane.
    pub fn at_field(&self, tan_x: f64, tan_y: f64) -> Self {
        let mut calib = self.calib.clone();
        calib.eye.field_rad = tan_x.atan();
        calib.eye.field_y_rad = tan_y.atan();
        self.with_calibration(calib)
    }

    /// Plans the zones for rendering `display` (made for `method`) at
    /// `accommodation_d`, and prepares each zone's PSFs at that depth.
    /// `centre` is the preparation at the image's centre (the display
    /// image's own). Without an eye pupil the PSF does not change with the
    /// field: one zone, nothing computed. A measured bundle with field
    /// zones decides alone: its zones, each seen through its own PSFs
    /// (the methods through the DOE) and the eye at its centre (the
    /// others).
    pub fn field_zones(
        &self,
        centre: &Prepared,
        method: Method,
        display: &Image,
        accommodation_d: f64,
        request: ZoneRequest,
        progress: &dyn Progress,
    ) -> Result<Zoned, SimError> {
        let field = FieldGeometry::of(&self.calib, display.width, display.height);
        let single = |note: String| Zoned {
            plan: ZonePlan {
                nx: 1,
                ny: 1,
                field,
                note,
            },
            zones: vec![None],
            rendered: Vec::new(),
            neighbours_db: None,
        };
        let measured_zones = self
            .measured_bundle()
            .filter(|b| b.card.zones.is_some())
            .map(|b| (b.zones(), b.clone()));
        if measured_zones.is_none() && self.calib.eye.pupil_diameter_m.is_none() {
            return Ok(single(
                "1 (the eyepiece's aperture is the stop: the PSF is the same across the field)"
                    .into(),
            ));
        }
        let seen = |sim: &Simulator| -> Result<(Prepared, Image), SimError> {
            let p = sim.prepare_seen(method, accommodation_d, progress)?;
            let img = p.perceived(method, display, accommodation_d)?;
            Ok((p, img))
        };
        let (nx, ny, note) = match (request, &measured_zones) {
            (_, Some(((nx, ny), bundle))) => {
                if let ZoneRequest::Fixed(x, y) = request
                    && (x, y) != (*nx, *ny)
                {
                    tracing::warn!(
                        "{x}×{y} zones asked; the PSF bundle {} was measured in {nx}×{ny}, which are rendered",
                        bundle.path.display()
                    );
                }
                (
                    *nx,
                    *ny,
                    format!("{nx}×{ny} (the PSF bundle's measured zones)"),
                )
            }
            (ZoneRequest::Fixed(nx, ny), None) => (nx, ny, format!("{nx}×{ny} (as asked)")),
            (ZoneRequest::Auto { tolerance_db }, None) => {
                let here = centre.perceived(method, display, accommodation_d)?;
                // The far edges: the horizontal one farther from the axis,
                // and the top one (the bottom mirrors it).
                let edge_x = if field.centre_tan_x >= 0.0 {
                    field.width as f64
                } else {
                    0.0
                };
                let probe = |x: f64, y: f64| -> Result<f64, SimError> {
                    let (tx, ty) = field.tan_at(x, y);
                    Ok(psnr(&here, &seen(&self.at_field(tx, ty))?.1))
                };
                let mid = (0.5 * field.width as f64, 0.5 * field.height as f64);
                let (ex, ey) = (probe(edge_x, mid.1)?, probe(mid.0, 0.0)?);
                let need = |db: f64| zones_for(db, tolerance_db);
                let (nx, ny) = (need(ex), need(ey));
                (
                    nx,
                    ny,
                    format!(
                        "{nx}×{ny} for {tolerance_db} dB: one zone's edge renders {} dB (horizontal) \
                         and {} dB (vertical) from its centre",
                        fmt_db(ex),
                        fmt_db(ey)
                    ),
                )
            }
        };
        if (nx, ny) == (1, 1) && measured_zones.is_none() {
            return Ok(single(note));
        }
        let plan = ZonePlan {
            nx,
            ny,
            field,
            note,
        };
        let mut zones = Vec::with_capacity(nx * ny);
        let mut rendered = Vec::with_capacity(nx * ny);
        for j in 0..ny {
            for i in 0..nx {
                let (tx, ty) = plan.tan_at_zone(i, j);
                let mut sim = self.at_field(tx, ty);
                if let Some((_, bundle)) = &measured_zones {
                    let zone = bundle.zone(i, j).ok_or_else(|| {
                        SimError::Invalid(format!("the PSF bundle has no zone ({i}, {j})"))
                    })?;
                    sim = sim.with_measured(std::sync::Arc::new(zone))?;
                }
                let (p, img) = seen(&sim)?;
                zones.push(Some(p));
                rendered.push(img);
            }
        }
        let mut worst = f64::INFINITY;
        for j in 0..ny {
            for i in 0..nx {
                let k = j * nx + i;
                if i + 1 < nx {
                    worst = worst.min(psnr(&rendered[k], &rendered[k + 1]));
                }
                if j + 1 < ny {
                    worst = worst.min(psnr(&rendered[k], &rendered[k + nx]));
                }
            }
        }
        Ok(Zoned {
            plan,
            zones,
            rendered,
            neighbours_db: Some(worst),
        })
    }
}

/// Zones per axis so that a zone's half-width keeps its edge within
/// `tolerance_db` of its centre, from one zone's `edge_db`: the rendered
/// difference grows about linearly with the distance in the field, so n
/// zones gain 20·log10(n) dB.
pub fn zones_for(edge_db: f64, tolerance_db: f64) -> usize {
    // NaN (never expected: PSNR of finite images) counts as within tolerance.
    if edge_db >= tolerance_db || edge_db.is_nan() {
        return 1;
    }
    let n = 10f64.powf((tolerance_db - edge_db) / 20.0).ceil();
    (n as usize).clamp(1, MAX_ZONES_PER_AXIS)
}

fn fmt_db(db: f64) -> String {
    if db.is_finite() {
        format!("{db:.1}")
    } else {
        "∞".into()
    }
}

impl Zoned {
    /// One line for reports.
    pub fn summary(&self) -> String {
        match self.neighbours_db {
            Some(db) => format!(
                "{}; neighbouring zones render {} dB apart (the display image is the centre's)",
                self.plan.note,
                fmt_db(db)
            ),
            None => self.plan.note.clone(),
        }
    }

    fn each<'a>(&'a self, centre: &'a Prepared) -> impl Iterator<Item = &'a Prepared> {
        self.zones.iter().map(move |z| z.as_ref().unwrap_or(centre))
    }

    /// The perceived image of the display image the zones were planned
    /// for ([`Simulator::field_zones`]): the zones' renderings blended, or
    /// with one zone the centre's rendering.
    pub fn perceived(
        &self,
        centre: &Prepared,
        method: Method,
        display: &Image,
        accommodation_d: f64,
    ) -> Result<Image, SimError> {
        if self.rendered.is_empty() {
            return centre.perceived(method, display, accommodation_d);
        }
        Ok(self.plan.blend(&self.rendered))
    }

    /// The target through the same eye, by zones (a main depth's is the
    /// sharp image, the same in every zone).
    pub fn target(
        &self,
        centre: &Prepared,
        input: &Image,
        accommodation_d: f64,
    ) -> Result<Image, SimError> {
        if self.zones.len() == 1 || centre.is_main_depth(accommodation_d) {
            return centre.target(input, accommodation_d);
        }
        let rendered = self
            .each(centre)
            .map(|p| p.target(input, accommodation_d))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(self.plan.blend(&rendered))
    }
}

#[cfg(test)]
#[path = "zones_tests.rs"]
mod tests;
