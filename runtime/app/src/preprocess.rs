//! The preprocessing registry: the one place that knows which
//! "input frame → display frame" ([`Preprocess`]) each display system runs.
//! `nedrt sim`, `nedrt eval`, the studies and `nedrt run --preprocess` all
//! build theirs here, so a method is never special-cased in a command. A
//! new preprocessor is one file in the layer that owns its physics or
//! engine, plus one arm in [`for_method`].

use std::collections::HashMap;

use nedrt_core::{Image, Preprocess};
use nedrt_infer::Dcnn;
use nedrt_optics::sim::{Method, Prepared};

use crate::AppError;

/// The preprocessing of `method`: none (conventional, DOE only), its
/// Wiener prefilter from `prepared` (AI, DOE + Wiener), or its D-CNN, taken
/// from `dcnns` (loaded by [`crate::DcnnOptions::load_for`]).
pub fn for_method(
    method: Method,
    prepared: &Prepared,
    dcnns: &mut HashMap<Method, Dcnn>,
) -> Result<Box<dyn Preprocess>, AppError> {
    if method.uses_dcnn() {
        return match dcnns.remove(&method) {
            Some(d) => Ok(Box::new(d)),
            None => Err(AppError::Usage(format!("no D-CNN loaded for {method}"))),
        };
    }
    Ok(prepared.preprocessor(method)?)
}

/// One line per D-CNN for reports: model file, content hash and engine.
pub fn dcnn_lines(dcnns: &HashMap<Method, Dcnn>, methods: &[Method]) -> Vec<String> {
    methods
        .iter()
        .filter_map(|m| {
            dcnns.get(m).map(|d| {
                format!(
                    "{m}: {} ({}) on {}",
                    d.model.path.display(),
                    d.model.hash,
                    d.describe()
                )
            })
        })
        .collect()
}

/// The preprocessing of each method of a run, built once.
#[derive(Debug)]
pub struct Preprocessors {
    engines: Vec<(Method, Box<dyn Preprocess>)>,
}

impl Preprocessors {
    /// Builds every method's preprocessing (see [`for_method`]).
    pub fn new(
        methods: &[Method],
        prepared: &Prepared,
        mut dcnns: HashMap<Method, Dcnn>,
    ) -> Result<Self, AppError> {
        let engines = methods
            .iter()
            .map(|&m| Ok((m, for_method(m, prepared, &mut dcnns)?)))
            .collect::<Result<_, AppError>>()?;
        Ok(Self { engines })
    }

    /// The display frame `method` puts on the panel for `input`.
    pub fn display(&mut self, method: Method, input: &Image) -> Result<Image, AppError> {
        let engine = self
            .engines
            .iter_mut()
            .find(|(m, _)| *m == method)
            .map(|(_, e)| e)
            .ok_or_else(|| AppError::Usage(format!("{method} was not prepared")))?;
        Ok(engine.run(input)?)
    }
}
