//! The preprocessing registry: the one place that knows which
//! "input frame → display frame" ([`Preprocess`]) each display system runs.
//! `nedrt sim`, `nedrt eval`, the studies and `nedrt run --preprocess` all
//! build theirs here, so a method is never special-cased in a command. A
//! new preprocessor is one file in the layer that owns its physics or
//! engine, plus one arm in [`for_method`].

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use nedrt_core::calib::Calibration;
use nedrt_core::preprocess::{PreprocessError, check_frame};
use nedrt_core::{Image, Preprocess};
use nedrt_infer::Dcnn;
use nedrt_optics::sim::wiener::WienerFilter;
use nedrt_optics::sim::{
    Method, Objective, Prepared, SolveMode, SolvedPrefilter, objective_depths_d,
};

use crate::EngineError;

/// The preprocessing of `method`: none (conventional, DOE only), its
/// Wiener prefilter from `prepared` (AI, DOE + Wiener), or its D-CNN, taken
/// from `dcnns` (nedrt-command's `DcnnOptions::load_for` loads them).
pub fn for_method(
    method: Method,
    prepared: &Prepared,
    dcnns: &mut HashMap<Method, Dcnn>,
) -> Result<Box<dyn Preprocess>, EngineError> {
    if method.uses_dcnn() {
        return match dcnns.remove(&method) {
            Some(d) => dcnn_system(method, d, prepared),
            None => Err(EngineError::Unavailable(format!(
                "no D-CNN loaded for {method}"
            ))),
        };
    }
    Ok(prepared.preprocessor(method)?)
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
pub fn wiener_stages(dcnns: &HashMap<Method, Dcnn>) -> Result<Vec<Method>, EngineError> {
    let mut out = Vec::new();
    for (m, d) in dcnns {
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

/// One line per D-CNN for reports: model file, content hash and engine.
pub fn dcnn_lines(dcnns: &HashMap<Method, Dcnn>, methods: &[Method]) -> Vec<String> {
    methods
        .iter()
        .filter_map(|m| {
            dcnns.get(m).map(|d| {
                format!(
                    "{m}: {} ({}) on {}{}",
                    d.model.path.display(),
                    d.model.hash,
                    d.describe(),
                    stage_note(&d.model.path)
                )
            })
        })
        .collect()
}

/// How the display image is made from a frame, given a method's optics
/// (`--prefilter`): the method's own preprocessing, or one of the
/// least-squares family of nedrt-optics' `optimal` module, which solve for
/// the display image against `objective` over the headline depths.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Prefilter {
    /// The method's own: none, its Wiener prefilter, or its D-CNN.
    Native,
    /// The linear least-squares prefilter, clamped.
    Lsq(Objective),
    /// `lsq` and this many projected-gradient steps.
    Refine(usize, Objective),
    /// `lsq` and this many steps of the split solver (ADMM: the panel's
    /// box split off, the quadratic solved exactly each step).
    Admm(usize, Objective),
    /// The bounded least-squares optimum (to 0.001 dB).
    Optimal(Objective),
}

/// Most refinement steps `refine:K` takes (past it, use `optimal`).
pub const MAX_REFINE_STEPS: usize = 1000;

impl Prefilter {
    /// The objective of the least-squares family when none is named: the
    /// multifocal target, the quantity training optimises
    /// (evaluation protocol).
    pub const DEFAULT_OBJECTIVE: Objective = Objective::Target;

    pub fn is_native(self) -> bool {
        self == Prefilter::Native
    }

    /// The depths its PSFs must be prepared at (none for `native`).
    pub fn depths_d(self, calib: &Calibration) -> Vec<f64> {
        if self.is_native() {
            Vec::new()
        } else {
            objective_depths_d(calib)
        }
    }

    /// The depths every one of `prefilters` needs, deduplicated.
    pub fn all_depths_d(prefilters: &[Prefilter], calib: &Calibration) -> Vec<f64> {
        if prefilters.iter().all(|p| p.is_native()) {
            Vec::new()
        } else {
            objective_depths_d(calib)
        }
    }

    /// What it solves against (`None` for `native`).
    pub fn objective(self) -> Option<Objective> {
        match self {
            Prefilter::Native => None,
            Prefilter::Lsq(o)
            | Prefilter::Refine(_, o)
            | Prefilter::Admm(_, o)
            | Prefilter::Optimal(o) => Some(o),
        }
    }

    /// The same prefilter against `objective` (`native` stays itself).
    pub fn with_objective(self, objective: Objective) -> Self {
        match self {
            Prefilter::Native => Prefilter::Native,
            Prefilter::Lsq(_) => Prefilter::Lsq(objective),
            Prefilter::Refine(k, _) => Prefilter::Refine(k, objective),
            Prefilter::Admm(k, _) => Prefilter::Admm(k, objective),
            Prefilter::Optimal(_) => Prefilter::Optimal(objective),
        }
    }

    /// The row name of `method` with this prefilter ("ai", "ai optimal@target").
    pub fn label(self, method_name: &str) -> String {
        match self {
            Prefilter::Native => method_name.to_string(),
            other => format!("{method_name} {other}"),
        }
    }
}

impl std::fmt::Display for Prefilter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Prefilter::Native => f.write_str("native"),
            Prefilter::Lsq(o) => write!(f, "lsq@{}", o.name()),
            Prefilter::Refine(k, o) => write!(f, "refine:{k}@{}", o.name()),
            Prefilter::Admm(k, o) => write!(f, "admm:{k}@{}", o.name()),
            Prefilter::Optimal(o) => write!(f, "optimal@{}", o.name()),
        }
    }
}

impl std::str::FromStr for Prefilter {
    type Err = String;
    /// `native`, `lsq`, `refine:K`, `admm:K` or `optimal`, all but the
    /// first with an optional `@sharp` or `@target`.
    fn from_str(s: &str) -> Result<Self, String> {
        const CHOICES: &str = "choose native, lsq, refine:K, admm:K or optimal (K ≥ 1 steps), \
             all but native optionally with @sharp or @target";
        let (kind, objective) = match s.split_once('@') {
            Some((k, o)) => (
                k,
                o.parse::<Objective>()
                    .map_err(|e| format!("prefilter {s:?}: {e}"))?,
            ),
            None => (s, Self::DEFAULT_OBJECTIVE),
        };
        match kind {
            "native" if !s.contains('@') => Ok(Prefilter::Native),
            "lsq" => Ok(Prefilter::Lsq(objective)),
            "optimal" => Ok(Prefilter::Optimal(objective)),
            _ => {
                let (make, k): (fn(usize, Objective) -> Prefilter, _) =
                    match (kind.strip_prefix("refine:"), kind.strip_prefix("admm:")) {
                        (Some(k), _) => (Prefilter::Refine, k),
                        (_, Some(k)) => (Prefilter::Admm, k),
                        _ => return Err(format!("unknown prefilter {s:?}; {CHOICES}")),
                    };
                match k.parse::<usize>() {
                    Ok(k) if (1..=MAX_REFINE_STEPS).contains(&k) => Ok(make(k, objective)),
                    _ => Err(format!(
                        "prefilter {s:?}: the number of steps must be a whole number from 1 to \
                         {MAX_REFINE_STEPS}"
                    )),
                }
            }
        }
    }
}

/// The preprocessing of `method` with `prefilter`: [`for_method`] for
/// `native`, else the method's optics' least-squares problem solved as asked.
pub fn for_system(
    method: Method,
    prefilter: Prefilter,
    prepared: &Prepared,
    dcnns: &mut HashMap<Method, Dcnn>,
) -> Result<Box<dyn Preprocess>, EngineError> {
    if prefilter.is_native() {
        return for_method(method, prepared, dcnns);
    }
    solved(method, prefilter, prepared, false)
}

/// A least-squares `prefilter` (not `native`) on `method`'s optics;
/// `warm`: `refine:K` and `admm:K` go on over still frames
/// ([`SolvedPrefilter::warm_started`], the frame budget's levels).
pub fn solved(
    method: Method,
    prefilter: Prefilter,
    prepared: &Prepared,
    warm: bool,
) -> Result<Box<dyn Preprocess>, EngineError> {
    let (mode, objective) = match prefilter {
        Prefilter::Native => {
            return Err(EngineError::Unavailable(format!(
                "{method}'s own preprocessing is not a least-squares solve"
            )));
        }
        Prefilter::Lsq(o) => (SolveMode::Linear, o),
        Prefilter::Refine(k, o) => (SolveMode::Refine(k), o),
        Prefilter::Admm(k, o) => (SolveMode::Admm(k), o),
        Prefilter::Optimal(o) => (SolveMode::Optimal, o),
    };
    let problem = prepared.display_problem(method, objective)?;
    if matches!(mode, SolveMode::Admm(_)) && !problem.has_split() {
        return Err(EngineError::Unavailable(format!(
            "{prefilter} of {method}: its PSFs are not mirror-symmetric, so the split solver has \
             no exact data step; use refine:K"
        )));
    }
    let solver = SolvedPrefilter::new(method.name(), Arc::new(problem), mode);
    Ok(Box::new(if warm { solver.warm_started() } else { solver }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prefilter_names_round_trip_and_bad_ones_explain() {
        for p in [
            Prefilter::Native,
            Prefilter::Lsq(Objective::Sharp),
            Prefilter::Refine(3, Objective::Target),
            Prefilter::Admm(5, Objective::Sharp),
            Prefilter::Optimal(Objective::Sharp),
        ] {
            assert_eq!(p.to_string().parse::<Prefilter>(), Ok(p));
        }
        assert_eq!(
            "optimal".parse::<Prefilter>(),
            Ok(Prefilter::Optimal(Objective::Target))
        );
        assert_eq!(
            "refine:10".parse::<Prefilter>(),
            Ok(Prefilter::Refine(10, Objective::Target))
        );
        assert_eq!(
            "admm:3".parse::<Prefilter>(),
            Ok(Prefilter::Admm(3, Objective::Target))
        );
        for (bad, says) in [
            ("wiener", "choose native"),
            ("refine:0", "from 1 to"),
            ("refine:", "from 1 to"),
            ("refine:x", "whole number"),
            ("refine:1001", "1000"),
            ("admm:0", "from 1 to"),
            ("admm:two", "whole number"),
            ("optimal@blurry", "sharp or target"),
            ("native@sharp", "choose native"),
        ] {
            let e = bad.parse::<Prefilter>().unwrap_err();
            assert!(e.contains(says) && e.contains(bad), "{bad}: {e}");
        }
        assert_eq!(Prefilter::Native.label("ai"), "ai");
        assert_eq!(
            Prefilter::Lsq(Objective::Sharp).label("doe+wiener"),
            "doe+wiener lsq@sharp"
        );
    }
}
