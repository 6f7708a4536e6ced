//! The simulator: gathers the PSFs a set of methods and depths needs into
//! one request per optics (lens, lens + DOE), computes or loads them once,
//! and renders perceived images and targets (paper Eqs. 4–5).

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use super::methods::{Method, Optics, psf_terms, target_blur_spec};
use super::optimal::{DisplayProblem, Objective};
use super::wiener::{WienerFilter, WienerPrefilter};
use super::{SimError, convolve::PreparedKernel};
use crate::bundle::PsfBundle;
use crate::cache::PsfCache;
use crate::{HeightMap, Psf, PsfRequest, PsfSet, PsfSpec, SamplingReport, doe_file};
use nedrt_core::Progress;
use nedrt_core::calib::Calibration;
use nedrt_core::image::Image;
use nedrt_core::preprocess::{Identity, Preprocess};

/// Calibration, DOE and PSF cache: everything a simulation is a function of.
#[derive(Debug)]
pub struct Simulator {
    pub calib: Calibration,
    pub doe: HeightMap,
    pub doe_hash: String,
    pub cache: PsfCache,
    /// Methods whose network runs behind their optics' Wiener
    /// ([`Prepared::wiener_filter`]): [`Simulator::prepare`] also gives
    /// them the accommodation sweep that filter averages over.
    wiener_stages: Vec<Method>,
    /// Measured PSFs of the built display ([`Simulator::with_measured`]):
    /// they stand for the lens + DOE optics' computed ones.
    measured: Option<Arc<PsfBundle>>,
}

impl Simulator {
    /// Loads the DOE (`doe_path`, else the calibration's file, else the
    /// three-lens initialisation on the design grid).
    pub fn new(
        calib: Calibration,
        doe_path: Option<&Path>,
        cache: PsfCache,
    ) -> Result<Self, SimError> {
        if calib.channels.len() != 3 {
            return Err(SimError::Invalid(format!(
                "{}: image simulation needs exactly 3 channels (R, G, B), the calibration has {}",
                calib.source,
                calib.channels.len()
            )));
        }
        let doe = match doe_path.or(calib.doe_file.as_deref()) {
            Some(p) => doe_file::load(p, &calib)?,
            None => HeightMap::three_lens_init(&calib, calib.doe_design_pitch_m),
        };
        Ok(Self::with_doe(calib, doe, cache))
    }

    /// A simulator of `doe` (a height map in memory: a built DOE's, a
    /// perturbed design's).
    pub fn with_doe(calib: Calibration, doe: HeightMap, cache: PsfCache) -> Self {
        let doe_hash = doe.content_hash();
        Self {
            calib,
            doe,
            doe_hash,
            cache,
            wiener_stages: Vec::new(),
            measured: None,
        }
    }

    /// The same simulator with the lens + DOE optics measured: every
    /// method through the DOE sees `bundle`'s PSFs, interpolated in
    /// diopters, in place of the computed ones (the lens-only methods,
    /// another display, keep theirs). The bundle's channels must be the
    /// calibration's.
    pub fn with_measured(mut self, bundle: Arc<PsfBundle>) -> Result<Self, SimError> {
        bundle.check_channels(self.calib.channels.len())?;
        self.doe_hash = format!(
            "measured:{}",
            &bundle.card.psfs_blake3[..16.min(bundle.card.psfs_blake3.len())]
        );
        self.measured = Some(bundle);
        Ok(self)
    }

    /// The measured bundle in place of the DOE optics, if any.
    pub fn measured_bundle(&self) -> Option<&Arc<PsfBundle>> {
        self.measured.as_ref()
    }

    /// The same simulator, preparing `methods` for a Wiener stage in front
    /// of their network (the sweep's PSFs, which only such a stage needs).
    pub fn with_wiener_stages(mut self, methods: Vec<Method>) -> Self {
        self.wiener_stages = methods;
        self
    }

    /// The same DOE and cache with another calibration (a field zone's eye).
    pub fn with_calibration(&self, calib: Calibration) -> Self {
        Self {
            calib,
            doe: self.doe.clone(),
            doe_hash: self.doe_hash.clone(),
            cache: self.cache.clone(),
            wiener_stages: self.wiener_stages.clone(),
            measured: self.measured.clone(),
        }
    }

    /// Computes (or loads) every PSF that `methods` at `depths_d` need,
    /// the target blur, and the Wiener filters of the methods that use one.
    pub fn prepare(
        &self,
        methods: &[Method],
        depths_d: &[f64],
        progress: &dyn Progress,
    ) -> Result<Prepared, SimError> {
        self.prepare_with(methods, depths_d, true, progress)
    }

    /// Only what rendering `method` at `accommodation_d` needs (its PSFs
    /// there and the target blur): no Wiener filter nor its sweep. A field
    /// zone's preparation ([`Simulator::field_zones`]).
    pub fn prepare_seen(
        &self,
        method: Method,
        accommodation_d: f64,
        progress: &dyn Progress,
    ) -> Result<Prepared, SimError> {
        self.prepare_with(&[method], &[accommodation_d], false, progress)
    }

    fn prepare_with(
        &self,
        methods: &[Method],
        depths_d: &[f64],
        filters: bool,
        progress: &dyn Progress,
    ) -> Result<Prepared, SimError> {
        let c = &self.calib;
        let channels = 0..c.channels.len();
        let mut lens = SpecSet::default();
        let mut doe = SpecSet::default();
        let sweep = c.depth_sweep_d(c.wiener.average_step_d);
        for &m in methods {
            let set = match m.optics() {
                Optics::Lens => &mut lens,
                // Measured: nothing to compute (`system_psfs` reads the bundle).
                Optics::Doe if self.measured.is_some() => continue,
                Optics::Doe => &mut doe,
            };
            let depths = if filters && (m.uses_wiener() || self.wiener_stages.contains(&m)) {
                [depths_d, &sweep].concat()
            } else {
                depths_d.to_vec()
            };
            for d in depths {
                for ch in channels.clone() {
                    for (spec, _) in psf_terms(c, m, d, ch) {
                        set.add(spec);
                    }
                }
            }
        }
        if depths_d.iter().any(|d| !c.is_main_depth(*d)) {
            for ch in channels.clone() {
                lens.add(target_blur_spec(c, ch));
            }
        }
        progress.start("PSFs", (lens.specs.len() + doe.specs.len()) as u64);
        let tick = || progress.advance(1);
        let mut reports = Vec::new();
        let mut run = |specs: SpecSet, with_doe: bool| -> Result<Option<PsfTable>, SimError> {
            if specs.specs.is_empty() {
                return Ok(None);
            }
            let SpecSet { specs, index } = specs.canonical();
            let request = PsfRequest {
                specs,
                doe: with_doe.then_some(&self.doe),
            };
            let set = self.cache.get_or_compute(c, &request, &tick)?;
            reports.push((
                if with_doe { "lens + DOE" } else { "lens" }.to_string(),
                set.report.clone(),
            ));
            Ok(Some(PsfTable { set, index }))
        };
        let lens = run(lens, false)?;
        let doe = run(doe, true)?;
        progress.finish();
        let mut prepared = Prepared {
            calib: c.clone(),
            doe_hash: self.doe_hash.clone(),
            lens,
            doe,
            measured: self.measured.clone(),
            wiener: HashMap::new(),
            reports,
        };
        for &m in methods.iter().filter(|m| filters && m.uses_wiener()) {
            let k = match m {
                Method::Ai => c.wiener.ai_k,
                _ => {
                    if c.wiener.doe_k_tuned_for != self.doe_hash {
                        tracing::warn!(
                            "wiener.doe_k = {} was tuned for DOE {:?}, this DOE is {}; tune it again for this DOE",
                            c.wiener.doe_k,
                            c.wiener.doe_k_tuned_for,
                            self.doe_hash
                        );
                    }
                    c.wiener.doe_k
                }
            };
            let mean = prepared.mean_psfs(m, &sweep)?;
            let filter = WienerFilter::new(&mean, k);
            if let Some(w) = filter.blur_only_warning() {
                tracing::warn!("{m}: {w}");
            }
            prepared.wiener.insert(m, Arc::new(filter));
        }
        Ok(prepared)
    }
}

/// Deduplicated specs of one request, with their index.
#[derive(Default)]
struct SpecSet {
    specs: Vec<PsfSpec>,
    index: HashMap<(usize, i64), usize>,
}

/// Ψ values equal to 1e-9 rad are the same PSF.
fn spec_key(s: PsfSpec) -> (usize, i64) {
    (s.channel, (s.psi_rad * 1e9).round() as i64)
}

impl SpecSet {
    /// Sorted by (channel, Ψ): the same PSFs make the same request (and cache key)
    /// whatever order the methods and depths asked for them in.
    fn canonical(mut self) -> Self {
        self.specs.sort_by(|a, b| {
            a.channel
                .cmp(&b.channel)
                .then(a.psi_rad.total_cmp(&b.psi_rad))
        });
        self.index = self
            .specs
            .iter()
            .enumerate()
            .map(|(i, s)| (spec_key(*s), i))
            .collect();
        self
    }

    fn add(&mut self, s: PsfSpec) {
        let n = self.specs.len();
        if let std::collections::hash_map::Entry::Vacant(e) = self.index.entry(spec_key(s)) {
            e.insert(n);
            self.specs.push(s);
        }
    }
}

struct PsfTable {
    set: PsfSet,
    index: HashMap<(usize, i64), usize>,
}

impl std::fmt::Debug for PsfTable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "PsfTable({} PSFs)", self.set.psfs.len())
    }
}

impl PsfTable {
    fn get(&self, s: PsfSpec) -> Option<&Psf> {
        self.index.get(&spec_key(s)).map(|&i| &self.set.psfs[i])
    }
}

/// PSFs and filters ready to render perceived images.
#[derive(Debug)]
pub struct Prepared {
    calib: Calibration,
    /// The DOE's content hash (the simulator's).
    doe_hash: String,
    lens: Option<PsfTable>,
    doe: Option<PsfTable>,
    measured: Option<Arc<PsfBundle>>,
    wiener: HashMap<Method, Arc<WienerFilter>>,
    /// What the PSF model chose, per request ("lens", "lens + DOE").
    pub reports: Vec<(String, SamplingReport)>,
}

impl Prepared {
    /// The content hash of the DOE these PSFs were computed through.
    pub fn doe_hash(&self) -> &str {
        &self.doe_hash
    }

    fn table(&self, optics: Optics) -> Result<&PsfTable, SimError> {
        match optics {
            Optics::Lens => self.lens.as_ref(),
            Optics::Doe => self.doe.as_ref(),
        }
        .ok_or_else(|| SimError::Invalid("PSFs for these optics were not prepared".into()))
    }

    fn lookup(&self, optics: Optics, spec: PsfSpec) -> Result<&Psf, SimError> {
        self.table(optics)?
            .get(spec)
            .ok_or_else(|| SimError::Invalid(format!("PSF {spec:?} was not prepared")))
    }

    /// Time-weighted sum of PSFs of one request (they share one window).
    fn mixture(&self, optics: Optics, terms: &[(PsfSpec, f64)]) -> Result<Psf, SimError> {
        let psfs = terms
            .iter()
            .map(|(spec, w)| Ok((self.lookup(optics, *spec)?, *w)))
            .collect::<Result<Vec<_>, SimError>>()?;
        Psf::weighted_sum(psfs.iter().copied())
            .ok_or_else(|| SimError::Invalid("a display with no PSF terms".into()))
    }

    /// The retinal PSF of `method` at `accommodation_d`, one per channel.
    pub fn system_psfs(&self, method: Method, accommodation_d: f64) -> Result<Vec<Psf>, SimError> {
        if let (Optics::Doe, Some(bundle)) = (method.optics(), &self.measured) {
            return (0..self.calib.channels.len())
                .map(|ch| Ok(bundle.at(accommodation_d, ch)?))
                .collect();
        }
        (0..self.calib.channels.len())
            .map(|ch| {
                self.mixture(
                    method.optics(),
                    &psf_terms(&self.calib, method, accommodation_d, ch),
                )
            })
            .collect()
    }

    /// The system PSF averaged over `depths_d`, per channel (the Wiener H̄).
    pub fn mean_psfs(&self, method: Method, depths_d: &[f64]) -> Result<Vec<Psf>, SimError> {
        let per_depth = depths_d
            .iter()
            .map(|d| self.system_psfs(method, *d))
            .collect::<Result<Vec<_>, _>>()?;
        let w = 1.0 / depths_d.len() as f64;
        (0..self.calib.channels.len())
            .map(|ch| {
                Psf::weighted_sum(per_depth.iter().map(|psfs| (&psfs[ch], w)))
                    .ok_or_else(|| SimError::Invalid("no depths to average".into()))
            })
            .collect()
    }

    /// Whether `accommodation_d` is one of the calibration's main depths
    /// (where the target is the sharp image).
    pub fn is_main_depth(&self, accommodation_d: f64) -> bool {
        self.calib.is_main_depth(accommodation_d)
    }

    /// The Wiener filter of a method, if it uses one.
    pub fn wiener(&self, method: Method) -> Option<&WienerFilter> {
        self.wiener.get(&method).map(|f| &**f)
    }

    /// The same, shared (a device stage keeps it to make each frame size's gains).
    pub fn wiener_shared(&self, method: Method) -> Option<Arc<WienerFilter>> {
        self.wiener.get(&method).cloned()
    }

    /// The Wiener filter of `method`'s optics with `k_reg`, as the
    /// Wiener methods make theirs (the PSF averaged over the calibration's
    /// accommodation sweep): the first stage of a D-CNN trained on the
    /// Wiener's output (docs/training.md).
    pub fn wiener_filter(&self, method: Method, k_reg: f64) -> Result<WienerFilter, SimError> {
        if !(k_reg.is_finite() && k_reg > 0.0) {
            return Err(SimError::Invalid(format!(
                "Wiener K {k_reg}: must be a positive number"
            )));
        }
        let c = &self.calib;
        let mean = self.mean_psfs(method, &c.depth_sweep_d(c.wiener.average_step_d))?;
        Ok(WienerFilter::new(&mean, k_reg))
    }

    /// The preprocessing of `method` when it needs no trained network:
    /// its Wiener prefilter, or none. A D-CNN method is an error here (its
    /// network is loaded by nedrt-infer; nedrt-stages' registry builds every
    /// method's preprocessing).
    pub fn preprocessor(&self, method: Method) -> Result<Box<dyn Preprocess>, SimError> {
        if method.uses_dcnn() {
            return Err(SimError::Invalid(format!(
                "{method} preprocesses with a D-CNN, which the simulator does not load"
            )));
        }
        Ok(match self.wiener.get(&method) {
            Some(f) => Box::new(WienerPrefilter::new(method.name(), f.clone())),
            None if method.uses_wiener() => {
                return Err(SimError::Invalid(format!(
                    "the Wiener filter of {method} was not prepared"
                )));
            }
            None => Box::new(Identity),
        })
    }

    /// Perceived image at `accommodation_d` for `method` from a display image.
    pub fn perceived(
        &self,
        method: Method,
        display: &Image,
        accommodation_d: f64,
    ) -> Result<Image, SimError> {
        Ok(perceive(
            display,
            &self.system_psfs(method, accommodation_d)?,
        ))
    }

    /// The bounded least-squares problem of `method`'s optics for
    /// `objective` over [`objective_depths_d`] (`lsq`, `refine:k`,
    /// `optimal`; those depths must have been prepared). The linear
    /// prefilter's K is the method's Wiener K, else the calibration's for
    /// the optics (`wiener.ai_k` for the lens, `wiener.doe_k` with the DOE).
    pub fn display_problem(
        &self,
        method: Method,
        objective: Objective,
    ) -> Result<DisplayProblem, SimError> {
        let c = &self.calib;
        let depths = objective_depths_d(c);
        let mut psfs = vec![Vec::new(); c.channels.len()];
        for d in &depths {
            for (ch, p) in self.system_psfs(method, *d)?.into_iter().enumerate() {
                psfs[ch].push(p);
            }
        }
        let blurred: Vec<bool> = depths
            .iter()
            .map(|d| objective == Objective::Target && !c.is_main_depth(*d))
            .collect();
        let blur = if blurred.iter().any(|&b| b) {
            Some(self.target_blur_psfs()?)
        } else {
            None
        };
        let k_reg = self
            .wiener
            .get(&method)
            .map(|f| f.k_reg)
            .unwrap_or(match method.optics() {
                Optics::Lens => c.wiener.ai_k,
                Optics::Doe => c.wiener.doe_k,
            });
        DisplayProblem::new(objective, depths, psfs, blurred, blur, k_reg)
    }

    /// The target blur h_b, one PSF per channel (prepared with any depth
    /// that is not a main depth).
    pub fn target_blur_psfs(&self) -> Result<Vec<Psf>, SimError> {
        (0..self.calib.channels.len())
            .map(|ch| {
                self.lookup(Optics::Lens, target_blur_spec(&self.calib, ch))
                    .cloned()
            })
            .collect()
    }

    /// The multifocal target: up2(I) at a main depth, up2(I) ∗ h_b elsewhere.
    pub fn target(&self, input: &Image, accommodation_d: f64) -> Result<Image, SimError> {
        if self.calib.is_main_depth(accommodation_d) {
            return Ok(input.up2());
        }
        Ok(perceive(input, &self.target_blur_psfs()?))
    }
}

/// The depths the optimal display image is solved over: the evaluation
/// depths of the headline range (docs/model.md §17).
pub fn objective_depths_d(calib: &Calibration) -> Vec<f64> {
    calib
        .evaluation_depths_d()
        .into_iter()
        .filter(|d| *d <= super::HEADLINE_MAX_D + 1e-9)
        .collect()
}

/// Î_p = up2(I_d) ∗ h + veil · mean(I_d), per channel, on the retinal grid.
pub fn perceive(display: &Image, psfs: &[Psf]) -> Image {
    PerceivePlan::new(psfs, display.width, display.height).apply(display)
}

/// Per-channel PSFs with their kernels transformed once for display images
/// of one size, for rendering many frames through the same optics.
#[derive(Debug)]
pub struct PerceivePlan {
    kernels: Vec<(PreparedKernel, f64)>,
}

impl PerceivePlan {
    pub fn new(psfs: &[Psf], display_width: usize, display_height: usize) -> Self {
        let kernels = psfs
            .iter()
            .map(|p| {
                let k =
                    PreparedKernel::new(&p.cells, p.window, 2 * display_width, 2 * display_height);
                (k, p.veil)
            })
            .collect();
        Self { kernels }
    }

    /// Î_p for a display image of the planned size.
    pub fn apply(&self, display: &Image) -> Image {
        let up = display.up2();
        let means = display.plane_means();
        let planes = up
            .planes()
            .zip(&self.kernels)
            .zip(means)
            .map(|((plane, (kernel, veil)), mean)| {
                let veil = (veil * mean) as f32;
                let mut out = kernel.apply(plane);
                out.iter_mut().for_each(|v| *v += veil);
                out
            })
            .collect();
        Image::from_planes(up.width, up.height, planes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cache::PsfCache;

    #[test]
    fn requests_are_canonical_whatever_the_order_asked() {
        let c = Calibration::default_embedded().expect("calib");
        let mut a = SpecSet::default();
        let mut b = SpecSet::default();
        let sweep = c.depth_sweep_d(0.1);
        assert!(
            sweep.contains(&1.5),
            "sweep depths are the listed depths exactly"
        );
        for d in [1.5, 0.0, 3.0] {
            a.add(PsfSpec {
                channel: 1,
                psi_rad: c.psi_rad(1, d),
            });
        }
        for d in sweep.iter().rev() {
            b.add(PsfSpec {
                channel: 1,
                psi_rad: c.psi_rad(1, *d),
            });
        }
        for d in &sweep {
            a.add(PsfSpec {
                channel: 1,
                psi_rad: c.psi_rad(1, *d),
            });
        }
        let (a, b) = (a.canonical(), b.canonical());
        let key = |s: &SpecSet| {
            PsfCache::key(
                &c,
                &PsfRequest {
                    specs: s.specs.clone(),
                    doe: None,
                },
            )
        };
        assert_eq!(key(&a), key(&b));
        assert_eq!(a.specs.len(), 31);
    }
}
