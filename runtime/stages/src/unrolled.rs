//! The unrolled preprocessor on the host (issue 55, docs/unrolled.md): K
//! steps of the split solver through the design's optics
//! ([`nedrt_optics::sim::SplitSteps`]), each followed by a small learned
//! correction between the data step and the panel's clamp, run by any
//! D-CNN backend (cpu, ort, wgpu). The trainer's `nedrt_train.unrolled`
//! computes the same, step for step; `nedrt_train.unrolled_export` writes
//! the manifest this reads (`NAME.unrolled.toml`) and one ONNX per step.
//!
//! load (the manifest, strictly; each step's network, its SHA-256 checked)
//! → check against the optics it runs through (method, DOE, objective, K)
//! → run.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use nedrt_core::preprocess::{HostTraffic, PreprocessError, check_frame};
use nedrt_core::{Image, Preprocess};
use nedrt_infer::{BackendKind, BackendOptions, Dcnn, ModelFile};
use nedrt_optics::sim::{DisplayProblem, Method, Objective, Prepared};
use serde::Deserialize;
use sha2::Digest;

use crate::EngineError;

/// The manifest's `format`.
pub const FORMAT: &str = "nedrt unrolled 1";
/// A manifest's name ends so.
pub const SUFFIX: &str = ".unrolled.toml";
/// Most steps a manifest may give.
pub const MAX_STEPS: usize = 64;
/// Largest manifest read.
const MAX_MANIFEST_BYTES: u64 = 1 << 20;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawManifest {
    format: String,
    method: String,
    objective: String,
    doe: String,
    calibration: String,
    k_reg: f64,
    kernels_sha256: String,
    trained_size: [usize; 2],
    step: Vec<RawStep>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStep {
    rho: f64,
    relaxation: f64,
    network: Option<String>,
    network_sha256: Option<String>,
}

/// One step: ρ_k = `rho` · L, relaxation α_k, and its correction's ONNX,
/// read once and checked against the manifest's SHA-256
/// (none: the classical step).
#[derive(Debug, Clone)]
pub struct StepSpec {
    pub rho: f32,
    pub relaxation: f32,
    pub network: Option<ModelFile>,
}

/// A validated manifest: what the model was trained through, and its steps.
#[derive(Debug, Clone)]
pub struct Manifest {
    pub path: PathBuf,
    /// The method whose optics the steps solve through ("doe+wiener").
    pub method: Method,
    pub objective: Objective,
    /// The DOE's content hash (nedrt's), as the kernels were made with.
    pub doe: String,
    /// The calibration the kernels were made with (provenance).
    pub calibration: String,
    /// The `lsq` start's K.
    pub k_reg: f64,
    pub kernels_sha256: String,
    /// The manifest's own content hash (SHA-256, 16 hex digits): with the
    /// steps' hashes inside it, it names the whole model.
    pub hash: String,
    /// Width and height of the crops it was trained on.
    pub trained_size: [usize; 2],
    pub steps: Vec<StepSpec>,
}

/// Whether `path` names an unrolled model's manifest (by its suffix).
pub fn is_manifest(path: &Path) -> bool {
    path.to_string_lossy().ends_with(SUFFIX)
}

impl Manifest {
    /// [`Manifest::read`] for `method`: the model must solve through its
    /// optics (the DOE's or the lens's).
    pub fn read_for(method: Method, path: &Path) -> Result<Self, EngineError> {
        let manifest = Self::read(path)?;
        if manifest.method.optics() != method.optics() {
            return Err(EngineError::input(
                path.display(),
                format!(
                    "solves through the optics of {}, not {method}'s",
                    manifest.method
                ),
            ));
        }
        Ok(manifest)
    }

    /// Reads and checks `path` (each step's network must exist beside it
    /// with the SHA-256 the manifest gives).
    pub fn read(path: &Path) -> Result<Self, EngineError> {
        let bad = |reason: String| EngineError::input(path.display(), reason);
        let bytes = nedrt_core::util::read_capped(path, MAX_MANIFEST_BYTES)
            .map_err(|e| bad(format!("cannot read the unrolled model's manifest: {e}")))?;
        let text = std::str::from_utf8(&bytes).map_err(|e| bad(format!("not UTF-8: {e}")))?;
        let raw: RawManifest = toml::from_str(text)
            .map_err(|e| bad(format!("not an unrolled model manifest: {e}")))?;
        if raw.format != FORMAT {
            return Err(bad(format!(
                "format {:?}; this nedrt reads {FORMAT:?}",
                raw.format
            )));
        }
        let method: Method = raw
            .method
            .parse()
            .map_err(|e| bad(format!("method: {e}")))?;
        let objective: Objective = raw
            .objective
            .parse()
            .map_err(|e| bad(format!("objective: {e}")))?;
        if !(raw.k_reg.is_finite() && raw.k_reg > 0.0) {
            return Err(bad(format!("k_reg = {}: a positive number", raw.k_reg)));
        }
        if raw.step.is_empty() || raw.step.len() > MAX_STEPS {
            return Err(bad(format!(
                "{} steps; from 1 to {MAX_STEPS}",
                raw.step.len()
            )));
        }
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut steps = Vec::new();
        for (k, s) in raw.step.iter().enumerate() {
            let at = |reason: String| bad(format!("step {}: {reason}", k + 1));
            if !(s.rho.is_finite() && s.rho > 0.0) {
                return Err(at(format!("rho = {}: a positive share of L", s.rho)));
            }
            if !(s.relaxation > 0.0 && s.relaxation < 2.0) {
                return Err(at(format!(
                    "relaxation = {}: between 0 and 2",
                    s.relaxation
                )));
            }
            let network = match (&s.network, &s.network_sha256) {
                (None, None) => None,
                (Some(name), Some(want)) => {
                    let file = dir.join(name);
                    let data = std::fs::read(&file)
                        .map_err(|e| at(format!("network {}: {e}", file.display())))?;
                    let got = hex(&sha2::Sha256::digest(&data));
                    if !got.eq_ignore_ascii_case(want) {
                        return Err(at(format!(
                            "network {} has SHA-256 {got}, the manifest says {want}: a changed \
                             or partly copied file",
                            file.display()
                        )));
                    }
                    // The bytes checked are the bytes run: not read again.
                    Some(ModelFile::from_bytes(&file, data)?)
                }
                _ => {
                    return Err(at(
                        "network and network_sha256 go together (both or neither)".into(),
                    ));
                }
            };
            steps.push(StepSpec {
                rho: s.rho as f32,
                relaxation: s.relaxation as f32,
                network,
            });
        }
        Ok(Self {
            path: path.to_path_buf(),
            method,
            objective,
            doe: raw.doe,
            calibration: raw.calibration,
            k_reg: raw.k_reg,
            kernels_sha256: raw.kernels_sha256,
            hash: hex(&sha2::Sha256::digest(&bytes))[..16].to_string(),
            trained_size: raw.trained_size,
            steps,
        })
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The unrolled preprocessor, ready to run on frames.
#[derive(Debug)]
pub struct Unrolled {
    pub manifest: Manifest,
    problem: Arc<DisplayProblem>,
    /// Per step: its correction's network, where it has one.
    networks: Vec<Option<Dcnn>>,
    engine: String,
}

impl Unrolled {
    /// Loads `manifest`'s networks on `kind` and checks it against the
    /// optics it will run through, `prepared`'s (their DOE); it solves the
    /// problem of the manifest's method and objective from the `lsq` start
    /// of the manifest's K.
    pub fn load(
        manifest: Manifest,
        prepared: &Prepared,
        kind: BackendKind,
        options: &BackendOptions,
    ) -> Result<Self, EngineError> {
        let problem = problem_for(&manifest, prepared)?;
        Self::with_problem(manifest, problem, kind, options)
    }

    /// [`Unrolled::load`] through `problem` as given (its method, DOE and
    /// objective the caller's to check).
    pub fn with_problem(
        manifest: Manifest,
        problem: DisplayProblem,
        kind: BackendKind,
        options: &BackendOptions,
    ) -> Result<Self, EngineError> {
        check_split(&manifest, &problem)?;
        let mut networks = Vec::new();
        for s in &manifest.steps {
            networks.push(match &s.network {
                None => None,
                Some(model) => {
                    let dcnn = Dcnn::from_model(model.clone(), kind, options)?;
                    check_planes(model, dcnn.input_channels(), &problem)?;
                    Some(dcnn)
                }
            });
        }
        let engine = networks
            .iter()
            .flatten()
            .next()
            .map_or_else(|| "no networks".to_string(), |d| d.describe());
        Ok(Self {
            manifest,
            problem: Arc::new(problem),
            networks,
            engine,
        })
    }

    /// Every check [`Unrolled::load`] makes (the DOE, the split, each
    /// step's planes), without preparing a network to run: what a caller
    /// that loads the model later, on another engine, checks first.
    pub fn check(manifest: &Manifest, prepared: &Prepared) -> Result<(), EngineError> {
        Self::check_with_problem(manifest, &problem_for(manifest, prepared)?)
    }

    /// [`Unrolled::check`] through `problem` as given.
    pub fn check_with_problem(
        manifest: &Manifest,
        problem: &DisplayProblem,
    ) -> Result<(), EngineError> {
        check_split(manifest, problem)?;
        for model in manifest.steps.iter().filter_map(|s| s.network.as_ref()) {
            let network = model.lower()?;
            check_planes(model, network.values[0].channels, problem)?;
        }
        Ok(())
    }

    /// K.
    pub fn steps(&self) -> usize {
        self.manifest.steps.len()
    }

    /// The model as one device stage (nedrt-gpu's `UnrolledStage`): its
    /// steps' filters and passes and its corrections on the wgpu backend
    /// on `device`, recorded into the frame's encoder, nothing read back.
    /// Its host twin is this [`Unrolled`] itself (its `run`).
    pub fn device_stage(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        adapter_name: &str,
        options: &BackendOptions,
    ) -> Result<nedrt_gpu::unrolled::UnrolledStage, EngineError> {
        stage_of(
            &self.manifest,
            self.problem.clone(),
            device,
            queue,
            adapter_name,
            options,
        )
    }
}

/// The model of `manifest` as one device stage through `prepared`'s
/// optics, without a host twin (a service's device level, whose fallback
/// is built apart): the checks of [`Unrolled::load`], then
/// [`Unrolled::device_stage`].
pub fn device_stage(
    manifest: &Manifest,
    prepared: &Prepared,
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    adapter_name: &str,
    options: &BackendOptions,
) -> Result<nedrt_gpu::unrolled::UnrolledStage, EngineError> {
    let problem = problem_for(manifest, prepared)?;
    check_split(manifest, &problem)?;
    stage_of(
        manifest,
        Arc::new(problem),
        device,
        queue,
        adapter_name,
        options,
    )
}

/// The problem `manifest` solves through `prepared`'s optics: its DOE
/// must be the one it was trained through, and the `lsq` start's K is the
/// model's own, as a D-CNN's card names its Wiener's (it was trained from
/// that start).
fn problem_for(manifest: &Manifest, prepared: &Prepared) -> Result<DisplayProblem, EngineError> {
    let doe_hash = prepared.doe_hash();
    if manifest.doe != doe_hash {
        return Err(EngineError::input(
            manifest.path.display(),
            format!(
                "trained through DOE {}, this display's is {doe_hash}: run it with the DOE it \
                 was trained through, or train it for this one",
                manifest.doe
            ),
        ));
    }
    let mut problem = prepared.display_problem(manifest.method, manifest.objective)?;
    problem.k_reg = manifest.k_reg;
    Ok(problem)
}

fn check_split(manifest: &Manifest, problem: &DisplayProblem) -> Result<(), EngineError> {
    if problem.has_split() {
        return Ok(());
    }
    Err(EngineError::input(
        manifest.path.display(),
        format!(
            "{}'s PSFs are not mirror-symmetric, so the split solver has no exact data step",
            manifest.method
        ),
    ))
}

fn stage_of(
    manifest: &Manifest,
    problem: Arc<DisplayProblem>,
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    adapter_name: &str,
    options: &BackendOptions,
) -> Result<nedrt_gpu::unrolled::UnrolledStage, EngineError> {
    let mut steps = Vec::new();
    for spec in &manifest.steps {
        let correction: Option<Box<dyn nedrt_gpu::DeviceStage>> = match &spec.network {
            None => None,
            Some(model) => Some(Box::new(nedrt_infer::gpu::DeviceDcnn::on_device(
                model.clone(),
                device,
                queue,
                adapter_name.to_string(),
                options,
            )?)),
        };
        steps.push(nedrt_gpu::unrolled::UnrolledStep {
            rho_share: spec.rho,
            relaxation: spec.relaxation,
            correction,
        });
    }
    let rhos: Vec<f32> = manifest.steps.iter().map(|s| s.rho).collect();
    let terms_for: nedrt_gpu::unrolled::UnrolledTermsFor = Box::new(move |w, h| {
        let t = problem.device_unrolled_terms(w, h, &rhos)?;
        Ok(nedrt_gpu::unrolled::UnrolledTerms {
            linear: t.linear,
            adjoint: t.adjoint,
            normal: t.normal,
            steps: t
                .steps
                .into_iter()
                .map(|s| nedrt_gpu::unrolled::UnrolledStepTerms { solve: s.solve })
                .collect(),
        })
    });
    let what = format!("unrolled {}", manifest.path.display());
    Ok(nedrt_gpu::unrolled::UnrolledStage::new(
        device, what, steps, terms_for,
    )?)
}

impl Preprocess for Unrolled {
    fn describe(&self) -> String {
        format!(
            "unrolled {} ({} split-solver steps @{} with learned corrections, on {})",
            self.manifest.path.display(),
            self.steps(),
            self.manifest.objective.name(),
            self.engine
        )
    }

    fn run(&mut self, input: &Image) -> Result<Image, PreprocessError> {
        check_frame(input, self.problem.channels())?;
        let engine = |e: String| PreprocessError::Engine {
            engine: "unrolled".into(),
            reason: e,
        };
        let mut state = self
            .problem
            .split_steps(input)
            .map_err(|e| engine(e.to_string()))?;
        for (spec, network) in self.manifest.steps.iter().zip(&mut self.networks) {
            state.relax(spec.rho, spec.relaxation);
            let correction = match network {
                None => None,
                Some(net) => Some(
                    net.run_unclamped(&state.correction_inputs())
                        .map_err(|e| engine(e.to_string()))?,
                ),
            };
            state
                .constrain(correction.as_ref())
                .map_err(|e| engine(e.to_string()))?;
        }
        Ok(state.display())
    }

    fn last_gpu_ns(&self) -> Option<u64> {
        let times: Vec<u64> = self
            .networks
            .iter()
            .flatten()
            .filter_map(|n| n.last_gpu_ns())
            .collect();
        (!times.is_empty()).then(|| times.iter().sum())
    }

    fn last_traffic(&self) -> HostTraffic {
        let mut all = HostTraffic::default();
        for n in self.networks.iter().flatten() {
            all.add(n.last_traffic());
        }
        all
    }
}

/// A step correction takes the point, dual and gradient planes of each of
/// the problem's channels.
fn check_planes(
    model: &nedrt_infer::ModelFile,
    planes: usize,
    problem: &DisplayProblem,
) -> Result<(), EngineError> {
    if planes != 3 * problem.channels() {
        return Err(EngineError::input(
            model.path.display(),
            format!(
                "a step correction of {planes} input planes; it takes {} (point, dual and \
                 gradient of each of {} channels)",
                3 * problem.channels(),
                problem.channels()
            ),
        ));
    }
    Ok(())
}
