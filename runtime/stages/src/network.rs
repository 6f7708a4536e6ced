//! What a network method (`proposed`, `lens+dcnn`) runs: a D-CNN (its
//! ONNX), or the unrolled preprocessor (its manifest, `NAME.unrolled.toml`,
//! [`crate::unrolled`]), which is built against the prepared optics when
//! the method's preprocessing is (it solves through their PSFs). Every
//! command that takes a D-CNN takes either, by the file it is given. Also
//! the D-CNN's own parts: its model card, which may put its optics' Wiener
//! in front of it ([`dcnn_system`], [`RawWiener`], [`Chain`]).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use nedrt_core::preprocess::{PreprocessError, check_frame};
use nedrt_core::{Image, Preprocess};
use nedrt_infer::{BackendKind, BackendOptions, Dcnn};
use nedrt_optics::sim::wiener::WienerFilter;
use nedrt_optics::sim::{Method, Prepared};

use crate::EngineError;
use crate::unrolled::{Manifest, Unrolled, is_manifest};

#[derive(Debug)]
pub enum Network {
    Dcnn(Dcnn),
    Unrolled {
        manifest: Manifest,
        kind: BackendKind,
        options: BackendOptions,
    },
}

impl Network {
    /// Reads the network at `path` for `method`: an unrolled manifest by its
    /// suffix (its optics must be the method's), else a D-CNN.
    pub fn load(
        method: Method,
        path: &Path,
        kind: BackendKind,
        options: &BackendOptions,
    ) -> Result<Self, EngineError> {
        if !is_manifest(path) {
            return Ok(Network::Dcnn(Dcnn::load(path, kind, options)?));
        }
        Ok(Network::Unrolled {
            manifest: Manifest::read_for(method, path)?,
            kind,
            options: options.clone(),
        })
    }

    pub fn path(&self) -> &Path {
        match self {
            Network::Dcnn(d) => &d.model.path,
            Network::Unrolled { manifest, .. } => &manifest.path,
        }
    }

    /// Its content hash: the ONNX file's, or the manifest's (which holds
    /// its steps' hashes).
    pub fn hash(&self) -> &str {
        match self {
            Network::Dcnn(d) => &d.model.hash,
            Network::Unrolled { manifest, .. } => &manifest.hash,
        }
    }

    /// The D-CNN, where this is one.
    pub fn dcnn(&self) -> Option<&Dcnn> {
        match self {
            Network::Dcnn(d) => Some(d),
            Network::Unrolled { .. } => None,
        }
    }

    /// Whether it needs the PSFs of the least-squares objective's depths
    /// (the unrolled model solves through them).
    pub fn needs_objective_depths(&self) -> bool {
        matches!(self, Network::Unrolled { .. })
    }

    /// One line for reports: file, content and engine.
    pub fn line(&self) -> String {
        match self {
            Network::Dcnn(d) => format!(
                "{} ({}) on {}{}",
                d.model.path.display(),
                d.model.hash,
                d.describe(),
                stage_note(&d.model.path)
            ),
            Network::Unrolled { manifest, kind, .. } => format!(
                "{} ({}; unrolled: {} split-solver steps @{} with learned corrections, DOE {}) \
                 on {}",
                manifest.path.display(),
                manifest.hash,
                manifest.steps.len(),
                manifest.objective.name(),
                manifest.doe,
                kind.name()
            ),
        }
    }

    /// The unrolled model built against `prepared` (a D-CNN as it is).
    pub fn into_preprocess(
        self,
        method: Method,
        prepared: &Prepared,
    ) -> Result<Box<dyn Preprocess>, EngineError> {
        match self {
            Network::Dcnn(d) => dcnn_system(method, d, prepared),
            Network::Unrolled {
                manifest,
                kind,
                options,
            } => Ok(Box::new(Unrolled::load(
                manifest, prepared, kind, &options,
            )?)),
        }
    }
}

/// What a D-CNN takes in, from its model card (`NAME.card.json` beside
/// `NAME.onnx`, written by `nedrt-train dcnn export`): the frame itself
/// (no card, or a card without `input`), or its optics' Wiener prefilter
/// output before the panel's clamp (`"input": "wiener-raw"` with the
/// filter's `"wiener_k"`), so that the network corrects the Wiener where
/// the clamp cuts it (docs/training.md).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DcnnInput {
    Frame,
    WienerRaw { k_reg: f64 },
}

/// Largest model card read.
const MAX_CARD_BYTES: u64 = 1 << 20;

/// The card of the model at `model`: `NAME.card.json` beside `NAME.onnx`.
pub fn card_path(model: &Path) -> PathBuf {
    model.with_extension("card.json")
}

/// The input the model at `model` was trained on, from its card.
pub fn dcnn_input(model: &Path) -> Result<DcnnInput, EngineError> {
    let path = card_path(model);
    if !path.is_file() {
        return Ok(DcnnInput::Frame);
    }
    let bad = |reason: String| EngineError::input(path.display(), reason);
    let bytes = nedrt_core::util::read_capped(&path, MAX_CARD_BYTES)
        .map_err(|e| bad(format!("cannot read the model card: {e}")))?;
    let card: serde_json::Value =
        serde_json::from_slice(&bytes).map_err(|e| bad(format!("not a model card (JSON): {e}")))?;
    match card.get("input").and_then(|v| v.as_str()) {
        None | Some("image") => Ok(DcnnInput::Frame),
        Some("wiener-raw") => match card.get("wiener_k").and_then(|v| v.as_f64()) {
            Some(k) if k.is_finite() && k > 0.0 => Ok(DcnnInput::WienerRaw { k_reg: k }),
            _ => Err(bad(
                "\"input\": \"wiener-raw\" needs \"wiener_k\", the Wiener filter's K (a positive number)"
                    .into(),
            )),
        },
        Some(other) => Err(bad(format!(
            "\"input\": {other:?} is not an input nedrt knows (image or wiener-raw)"
        ))),
    }
}

/// The methods among `dcnns` whose network runs behind its optics' Wiener
/// (for [`nedrt_optics::sim::Simulator::with_wiener_stages`]).
pub fn wiener_stages(dcnns: &HashMap<Method, Network>) -> Result<Vec<Method>, EngineError> {
    let mut out = Vec::new();
    for (m, d) in dcnns.iter().filter_map(|(m, n)| Some((m, n.dcnn()?))) {
        if let DcnnInput::WienerRaw { .. } = dcnn_input(&d.model.path)? {
            out.push(*m);
        }
    }
    Ok(out)
}

/// For reports: ", behind its optics' Wiener prefilter …" where the model
/// at `model` runs behind one, else nothing.
pub fn stage_note(model: &Path) -> String {
    match dcnn_input(model) {
        Ok(DcnnInput::WienerRaw { k_reg }) => {
            format!(", behind its optics' Wiener prefilter (K = {k_reg:e}) before the clamp")
        }
        _ => String::new(),
    }
}

/// The preprocessing of a D-CNN method: the network alone, or, for a
/// network trained on the Wiener's output, its optics' Wiener prefilter
/// (before the clamp) and then the network.
pub fn dcnn_system(
    method: Method,
    dcnn: Dcnn,
    prepared: &Prepared,
) -> Result<Box<dyn Preprocess>, EngineError> {
    Ok(match dcnn_input(&dcnn.model.path)? {
        DcnnInput::Frame => Box::new(dcnn),
        DcnnInput::WienerRaw { k_reg } => Box::new(Chain::behind_wiener(
            method,
            Arc::new(prepared.wiener_filter(method, k_reg)?),
            Box::new(dcnn),
        )),
    })
}

/// `method`'s Wiener prefilter before the clamp, on the host: a
/// network's input (in front of it in a [`Chain`]; where the device FFT
/// lacks the frame's size), and the service's host stage.
#[derive(Debug)]
pub struct RawWiener {
    pub method: Method,
    pub filter: Arc<WienerFilter>,
}

impl Preprocess for RawWiener {
    fn describe(&self) -> String {
        format!(
            "Wiener prefilter of {} (K = {:e}) before the clamp",
            self.method, self.filter.k_reg
        )
    }

    fn run(&mut self, input: &Image) -> Result<Image, PreprocessError> {
        check_frame(input, self.filter.channels())?;
        Ok(self.filter.apply_unclamped(input))
    }
}

/// Two preprocessors one after the other: a network behind its optics'
/// Wiener prefilter (on the host, [`RawWiener`],
/// or on the device, [`crate::device_prefilter::OnDevice`]), which sees the
/// Wiener's output before the panel's clamp and returns the display image.
/// The host twin of [`nedrt_gpu::Chain`]; its GPU time and traffic are the
/// second's (the network's).
#[derive(Debug)]
pub struct Chain {
    first: Box<dyn Preprocess>,
    second: Box<dyn Preprocess>,
}

impl Chain {
    pub fn new(first: Box<dyn Preprocess>, second: Box<dyn Preprocess>) -> Self {
        Self { first, second }
    }

    /// `network` behind `method`'s Wiener `filter` on the host.
    pub fn behind_wiener(
        method: Method,
        filter: Arc<WienerFilter>,
        network: Box<dyn Preprocess>,
    ) -> Self {
        let wiener = RawWiener { method, filter };
        Self::new(Box::new(wiener), network)
    }
}

impl Preprocess for Chain {
    fn describe(&self) -> String {
        format!("{}, then {}", self.first.describe(), self.second.describe())
    }

    fn run(&mut self, input: &Image) -> Result<Image, PreprocessError> {
        let middle = self.first.run(input)?;
        self.second.run(&middle)
    }

    fn last_gpu_ns(&self) -> Option<u64> {
        self.second.last_gpu_ns()
    }

    fn last_traffic(&self) -> nedrt_core::preprocess::HostTraffic {
        self.second.last_traffic()
    }
}

/// One line per network for reports: model file, content and engine.
pub fn dcnn_lines(dcnns: &HashMap<Method, Network>, methods: &[Method]) -> Vec<String> {
    methods
        .iter()
        .filter_map(|m| dcnns.get(m).map(|n| format!("{m}: {}", n.line())))
        .collect()
}
