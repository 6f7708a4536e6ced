//! What the focus viewer and the sweeps show: one input seen through each
//! method at every depth of a grid, with the PSFs of the whole grid prepared
//! once (computed the first time, then read from the PSF cache) and each
//! method's display frame preprocessed once (it does not depend on where the
//! eye focuses). A perceived image is rendered on demand and the latest ones
//! are kept, so revisiting a depth costs nothing.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex};

use nedrt_core::calib::Calibration;
use nedrt_optics::sim::metrics::psnr;
use nedrt_optics::sim::{Image, Method, Prepared, Simulator};
use nedrt_stages::preprocess::Prefilter;
use rayon::prelude::*;

use crate::{AppError, CommonOptions};

/// One panel of the viewer: a method's display image, made by its own
/// preprocessing or by a prefilter on its optics (`nedrt run`'s frame
/// budget levels, `nedrt view --levels`), under a label.
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    pub label: String,
    pub method: Method,
    pub prefilter: Prefilter,
}

impl Panel {
    /// `method` with its own preprocessing, labelled by its name.
    pub fn of(method: Method) -> Self {
        Self {
            label: method.name().into(),
            method,
            prefilter: Prefilter::Native,
        }
    }
}

/// Which image the panels show.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Shown {
    /// What the eye sees through the method at the accommodation.
    #[default]
    Perceived,
    /// The input on the retinal grid (up2), the same for every method.
    Sharp,
    /// The multifocal target at the accommodation.
    Target,
}

impl Shown {
    pub fn label(self) -> &'static str {
        match self {
            Shown::Perceived => "perceived",
            Shown::Sharp => "sharp input",
            Shown::Target => "target",
        }
    }
}

/// One method at one depth: the perceived image encoded to 8 bits, its
/// scores, and the channel PSFs as a small picture.
#[derive(Debug)]
pub struct Rendered {
    /// Interleaved RGB8 on the retinal grid ([`encode8`] of the perceived image).
    pub perceived_rgb8: Vec<u8>,
    pub vs_sharp_db: f64,
    pub vs_target_db: f64,
    /// Interleaved RGB8, [`PSF_INSET_PX`] a side.
    pub psf_inset_rgb8: Vec<u8>,
}

/// Side of the PSF inset in pixels.
pub const PSF_INSET_PX: usize = 96;
/// Retinal cells a side the inset shows (the centre of the PSF window).
const PSF_INSET_CELLS: usize = 48;

/// The 8-bit code of a linear intensity: clamped to [0, 1] and rounded, the
/// convention of every 8-bit image nedrt reads and writes.
pub fn encode8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Interleaved RGB8 of a planar RGB image.
pub fn rgb8_of(image: &Image) -> Vec<u8> {
    let n = image.width * image.height;
    (0..n)
        .flat_map(|i| (0..3).map(move |c| (c, i)))
        .map(|(c, i)| encode8(image.plane(c)[i]))
        .collect()
}

/// Every method's view of one input over a grid of accommodations.
pub struct FocusScene {
    /// Each panel's method (the optics it is seen through) and label.
    pub methods: Vec<Method>,
    pub labels: Vec<String>,
    pub input_name: String,
    /// Accommodations the scene can show, ascending, in diopters.
    pub depths_d: Vec<f64>,
    /// Side lengths of every panel image (the retinal grid: twice the input).
    pub width: usize,
    pub height: usize,
    calib: Calibration,
    prepared: Prepared,
    displays: Vec<Image>,
    sharp: Image,
    sharp_rgb8: Vec<u8>,
    /// The target at every depth that is not a main depth (it does not vary).
    blurred_target: Option<Image>,
    blurred_target_rgb8: Option<Vec<u8>>,
    memo: Mutex<Memo>,
}

impl std::fmt::Debug for FocusScene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "FocusScene({}, {:?}, {} depths)",
            self.input_name,
            self.labels,
            self.depths_d.len()
        )
    }
}

/// The latest rendered views, bounded in bytes (oldest out first).
#[derive(Default)]
struct Memo {
    entries: HashMap<(usize, usize), Arc<Rendered>>,
    order: VecDeque<(usize, usize)>,
    bytes: usize,
}

/// What the memo of rendered views may hold.
const MEMO_BYTES: usize = 512 << 20;

impl FocusScene {
    /// Prepares `panels` over `depths_d` for `input` (already loaded and
    /// checked against the panel), with the PSFs of `psf_depths_d`, which
    /// must hold every depth of `depths_d` (one request, so one cache entry,
    /// serves the viewer and every sweep on its grid).
    pub fn new(
        common: &CommonOptions,
        calib: &Calibration,
        input: Image,
        input_name: String,
        panels: &[Panel],
        depths_d: &[f64],
        psf_depths_d: &[f64],
    ) -> Result<Self, AppError> {
        if panels.is_empty() {
            return Err(AppError::Unavailable("no methods to show".into()));
        }
        if depths_d.is_empty() {
            return Err(AppError::Unavailable("no accommodations to show".into()));
        }
        for &d in depths_d {
            if let Some(w) = crate::check_accommodation(calib, d)? {
                tracing::warn!("{w}");
            }
        }
        let methods: Vec<Method> = panels.iter().map(|p| p.method).collect();
        let mut dcnns = common.dcnn.load_for(&methods)?;
        let sim = common
            .measured(Simulator::new(
                calib.clone(),
                common.doe_path_for(&methods).as_deref(),
                common.cache(),
            )?)?
            .with_wiener_stages(nedrt_stages::preprocess::wiener_stages(&dcnns)?);
        // A prefilter's objective depths beside the grid's.
        let prefilters: Vec<Prefilter> = panels.iter().map(|p| p.prefilter).collect();
        let mut psf_depths = psf_depths_d.to_vec();
        psf_depths.extend(Prefilter::all_depths_d(&prefilters, &sim.calib));
        if dcnns.values().any(|n| n.needs_objective_depths()) {
            psf_depths.extend(nedrt_optics::sim::objective_depths_d(&sim.calib));
        }
        psf_depths.sort_by(f64::total_cmp);
        psf_depths.dedup();
        let prepared = sim.prepare(&methods, &psf_depths, common.progress())?;
        let displays = panels
            .iter()
            .map(|p| -> Result<Image, AppError> {
                let mut preprocess = if p.prefilter.is_native() {
                    nedrt_stages::preprocess::for_method(p.method, &prepared, &mut dcnns)?
                } else {
                    nedrt_stages::preprocess::for_system(
                        p.method,
                        p.prefilter,
                        &prepared,
                        &mut dcnns,
                    )?
                };
                Ok(preprocess.run(&input)?)
            })
            .collect::<Result<Vec<_>, _>>()?;
        let sharp = input.up2();
        let blurred_target = match depths_d.iter().find(|d| !calib.is_main_depth(**d)) {
            Some(&d) => Some(prepared.target(&input, d)?),
            None => None,
        };
        let mut depths = depths_d.to_vec();
        depths.sort_by(f64::total_cmp);
        depths.dedup();
        Ok(Self {
            methods,
            labels: panels.iter().map(|p| p.label.clone()).collect(),
            input_name,
            depths_d: depths,
            width: sharp.width,
            height: sharp.height,
            sharp_rgb8: rgb8_of(&sharp),
            blurred_target_rgb8: blurred_target.as_ref().map(rgb8_of),
            calib: calib.clone(),
            prepared,
            displays,
            sharp,
            blurred_target,
            memo: Mutex::new(Memo::default()),
        })
    }

    /// The far end of the slider: the calibrated range's (the same for
    /// every sweep, whatever part of the range it covers).
    pub fn slider_max_d(&self) -> f64 {
        self.calib.range_d[1].max(1e-9)
    }

    pub fn is_main_depth(&self, accommodation_d: f64) -> bool {
        self.calib.is_main_depth(accommodation_d)
    }

    /// The grid index nearest to `accommodation_d`.
    pub fn nearest_depth(&self, accommodation_d: f64) -> usize {
        nearest_index(&self.depths_d, accommodation_d)
    }

    /// What the PSF model chose, per optics ("lens", "lens + DOE").
    pub fn psf_reports(&self) -> Vec<String> {
        self.prepared
            .reports
            .iter()
            .map(|(name, r)| format!("PSF model, {name}: {}", r.summary()))
            .collect()
    }

    /// The display frame a method shows (after its preprocessing).
    pub fn display(&self, method: usize) -> &Image {
        &self.displays[method]
    }

    /// The blurred target's when `depth` is not a main depth, else the sharp
    /// image's: `sharp` or `blurred` of the same kind (float or 8-bit).
    fn at_target<'a, T: ?Sized>(
        &self,
        depth: usize,
        sharp: &'a T,
        blurred: Option<&'a T>,
    ) -> &'a T {
        blurred
            .filter(|_| !self.is_main_depth(self.depths_d[depth]))
            .unwrap_or(sharp)
    }

    fn target(&self, depth: usize) -> &Image {
        self.at_target(depth, &self.sharp, self.blurred_target.as_ref())
    }

    /// The image `shown` asks for, as RGB8, for a method at a depth.
    pub fn shown_rgb8<'a>(
        &'a self,
        shown: Shown,
        rendered: &'a Rendered,
        depth: usize,
    ) -> &'a [u8] {
        match shown {
            Shown::Perceived => &rendered.perceived_rgb8,
            Shown::Sharp => &self.sharp_rgb8,
            Shown::Target => self.at_target(
                depth,
                &self.sharp_rgb8[..],
                self.blurred_target_rgb8.as_deref(),
            ),
        }
    }

    /// A method at grid depth `depth`, from the memo or rendered now.
    pub fn render(&self, method: usize, depth: usize) -> Result<Arc<Rendered>, AppError> {
        if let Some(r) = self.lock_memo().entries.get(&(method, depth)) {
            return Ok(r.clone());
        }
        let m = self.methods[method];
        let d = self.depths_d[depth];
        let perceived = self.prepared.perceived(m, &self.displays[method], d)?;
        let psfs = self.prepared.system_psfs(m, d)?;
        let rendered = Arc::new(Rendered {
            perceived_rgb8: rgb8_of(&perceived),
            vs_sharp_db: psnr(&perceived, &self.sharp),
            vs_target_db: psnr(&perceived, self.target(depth)),
            psf_inset_rgb8: psf_inset(&psfs),
        });
        let mut memo = self.lock_memo();
        let bytes = rendered.perceived_rgb8.len() + rendered.psf_inset_rgb8.len();
        while memo.bytes + bytes > MEMO_BYTES {
            let Some(old) = memo.order.pop_front() else {
                break;
            };
            if let Some(r) = memo.entries.remove(&old) {
                memo.bytes -= r.perceived_rgb8.len() + r.psf_inset_rgb8.len();
            }
        }
        if memo
            .entries
            .insert((method, depth), rendered.clone())
            .is_none()
        {
            memo.order.push_back((method, depth));
            memo.bytes += bytes;
        }
        Ok(rendered)
    }

    /// Every method at one depth, rendered on worker threads.
    pub fn render_all(&self, depth: usize) -> Result<Vec<Arc<Rendered>>, AppError> {
        (0..self.methods.len())
            .into_par_iter()
            .map(|m| self.render(m, depth))
            .collect()
    }

    fn lock_memo(&self) -> std::sync::MutexGuard<'_, Memo> {
        // A panic while holding the memo leaves it consistent enough: entries
        // and their byte count are updated together.
        self.memo.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// The index of the value of `grid` nearest to `value` (0 for an empty grid).
pub fn nearest_index(grid: &[f64], value: f64) -> usize {
    let mut best = 0;
    for (i, g) in grid.iter().enumerate() {
        if (g - value).abs() < (grid[best] - value).abs() {
            best = i;
        }
    }
    best
}

/// The channel PSFs as one RGB picture: the central cells of the window,
/// square-root scaled against the brightest cell of the three channels
/// (linear scaling shows only the peak), nearest-pixel enlarged.
pub fn psf_inset(psfs: &[nedrt_optics::Psf]) -> Vec<u8> {
    let peak = psfs
        .iter()
        .flat_map(|p| p.cells.iter().copied())
        .fold(0.0f64, f64::max)
        .max(f64::MIN_POSITIVE);
    let mut out = vec![0u8; 3 * PSF_INSET_PX * PSF_INSET_PX];
    for (c, p) in psfs.iter().enumerate().take(3) {
        let shown = PSF_INSET_CELLS.min(p.window);
        let offset = (p.window - shown) / 2;
        for y in 0..PSF_INSET_PX {
            for x in 0..PSF_INSET_PX {
                let (cx, cy) = (
                    offset + x * shown / PSF_INSET_PX,
                    offset + y * shown / PSF_INSET_PX,
                );
                let v = (p.cells[cy * p.window + cx] / peak).sqrt();
                out[3 * (y * PSF_INSET_PX + x) + c] = encode8(v as f32);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encode8_rounds_and_clamps() {
        assert_eq!(encode8(-0.1), 0);
        assert_eq!(encode8(0.5 / 255.0 - 1e-4), 0);
        assert_eq!(encode8(0.5 / 255.0 + 1e-4), 1);
        assert_eq!(encode8(1.7), 255);
    }

    #[test]
    fn the_inset_of_a_point_is_one_bright_centre() {
        let window = 5;
        let mut cells = vec![0.0; window * window];
        cells[12] = 1.0;
        let psf = nedrt_optics::Psf {
            window,
            cells,
            veil: 0.0,
        };
        let inset = psf_inset(&[psf.clone(), psf.clone(), psf]);
        let centre = 3 * ((PSF_INSET_PX / 2) * PSF_INSET_PX + PSF_INSET_PX / 2);
        assert_eq!(&inset[centre..centre + 3], &[255, 255, 255]);
        assert_eq!(&inset[0..3], &[0, 0, 0]);
    }
}
