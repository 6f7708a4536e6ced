//! The network of a run, by the file `--dcnn` names: a D-CNN (its ONNX,
//! with its card's Wiener stage in front where the card puts one) or an
//! unrolled model (its manifest, `NAME.unrolled.toml`: split-solver steps
//! through the optics with a learned correction each, issue 55). Either is
//! the network level of a fixed run and of the frame budget's ladder, on
//! the sink's device or on the host, with `--fallback`'s behind it.

use std::path::Path;
use std::sync::Arc;

use super::{AppError, CommonOptions};
use nedrt_infer::ModelFile;
use nedrt_optics::sim::wiener::WienerFilter;
use nedrt_optics::sim::{Method, Prepared, Simulator};
use nedrt_stages::preprocess::DcnnInput;
use nedrt_stages::unrolled::{Manifest, Unrolled};

/// A network's Wiener stage: the method whose Wiener runs in front of it,
/// and the filter.
pub(crate) type WienerStage = Option<(Method, Arc<WienerFilter>)>;

/// A run's network. A run holds a few, once: their size does not matter.
#[derive(Debug, Clone)]
#[allow(clippy::large_enum_variant)]
pub(crate) enum RunNetwork {
    /// `wiener`: the stage its card puts in front of it, once
    /// [`RunNetwork::prepare`] has made it.
    Dcnn {
        model: ModelFile,
        input: DcnnInput,
        wiener: WienerStage,
    },
    /// `prepared`: the optics it solves through (the objective's depths
    /// of its method on the run's DOE), once [`RunNetwork::prepare`] has
    /// made them; a plan needs only the manifest.
    Unrolled {
        manifest: Manifest,
        prepared: Option<Arc<Prepared>>,
    },
}

impl RunNetwork {
    /// Reads the network at `path` for `method`: an unrolled manifest by its
    /// suffix (it must solve through `method`'s optics), else a D-CNN and
    /// its card.
    pub(crate) fn read(method: Method, path: &Path) -> Result<Self, AppError> {
        if !nedrt_stages::unrolled::is_manifest(path) {
            let model = ModelFile::read(path)?;
            let input = nedrt_stages::preprocess::dcnn_input(&model.path)?;
            return Ok(Self::Dcnn {
                model,
                input,
                wiener: None,
            });
        }
        Ok(Self::Unrolled {
            manifest: Manifest::read_for(method, path)?,
            prepared: None,
        })
    }

    pub(crate) fn path(&self) -> &Path {
        match self {
            Self::Dcnn { model, .. } => &model.path,
            Self::Unrolled { manifest, .. } => &manifest.path,
        }
    }

    /// Its content hash, as the tradeoff table's rows name it.
    pub(crate) fn hash(&self) -> &str {
        match self {
            Self::Dcnn { model, .. } => &model.hash,
            Self::Unrolled { manifest, .. } => &manifest.hash,
        }
    }

    /// Its level's name: the file's stem (`dcnn`, `unrolled-k3`).
    pub(crate) fn name(&self) -> String {
        level_name(self.path())
    }

    /// Its Wiener stage, where its card puts one in front of it.
    pub(crate) fn wiener(&self) -> WienerStage {
        match self {
            Self::Dcnn { wiener, .. } => wiener.clone(),
            Self::Unrolled { .. } => None,
        }
    }

    /// The K of the Wiener stage a D-CNN's card puts in front of it.
    pub(crate) fn behind_wiener_k(&self) -> Option<f64> {
        match self {
            Self::Dcnn {
                input: DcnnInput::WienerRaw { k_reg },
                ..
            } => Some(*k_reg),
            _ => None,
        }
    }

    /// An unrolled model's steps (none for a D-CNN).
    pub(crate) fn unrolled_steps(&self) -> Option<usize> {
        match self {
            Self::Unrolled { manifest, .. } => Some(manifest.steps.len()),
            Self::Dcnn { .. } => None,
        }
    }
}

/// What the networks need of `method`'s optics, made once for every view
/// and level before the sink opens: each D-CNN's Wiener stage where its
/// card puts one in front; the unrolled models' optics, prepared once for
/// all of them (each one's DOE and steps' networks checked here).
/// Prepared as the simulator prepares them, so that a run shows what
/// `nedrt sim` renders.
pub(crate) fn prepare(
    networks: Vec<RunNetwork>,
    common: &CommonOptions,
    method: Method,
) -> Result<Vec<RunNetwork>, AppError> {
    let sim = |wiener_stages: Vec<Method>| -> Result<Simulator, AppError> {
        Ok(common
            .measured(Simulator::new(
                common.calibration()?,
                common.doe_path_for(&[method]).as_deref(),
                common.cache(),
            )?)?
            .with_wiener_stages(wiener_stages))
    };
    let mut optics: Option<Arc<Prepared>> = None;
    networks
        .into_iter()
        .map(|n| match n {
            RunNetwork::Dcnn {
                model,
                input: DcnnInput::WienerRaw { k_reg },
                ..
            } => {
                let prepared = sim(vec![method])?.prepare(&[method], &[], common.progress())?;
                let filter = Arc::new(prepared.wiener_filter(method, k_reg)?);
                Ok(RunNetwork::Dcnn {
                    model,
                    input: DcnnInput::WienerRaw { k_reg },
                    wiener: Some((method, filter)),
                })
            }
            RunNetwork::Dcnn { .. } => Ok(n),
            RunNetwork::Unrolled { manifest, .. } => {
                let prepared = match &optics {
                    Some(p) => p.clone(),
                    None => {
                        let sim = sim(Vec::new())?;
                        let depths = nedrt_optics::sim::objective_depths_d(&sim.calib);
                        let p = Arc::new(sim.prepare(&[method], &depths, common.progress())?);
                        optics.insert(p).clone()
                    }
                };
                // Every check of a load (DOE, split, each step's planes)
                // now, without preparing the networks (the engine loads
                // them once, later): a model that cannot run fails before
                // anything opens.
                Unrolled::check(&manifest, &prepared)?;
                Ok(RunNetwork::Unrolled {
                    manifest,
                    prepared: Some(prepared),
                })
            }
        })
        .collect()
}

/// An unrolled model's prepared optics ([`prepare`] made them).
pub(crate) fn optics(prepared: &Option<Arc<Prepared>>) -> Result<&Prepared, AppError> {
    prepared
        .as_deref()
        .ok_or_else(|| AppError::Internal("an unrolled model not prepared".into()))
}

/// A network file's level name: its stem, without an unrolled manifest's
/// `.unrolled` (`models/unrolled/unrolled-k3.unrolled.toml` →
/// `unrolled-k3`).
pub fn level_name(path: &Path) -> String {
    let stem = path
        .file_stem()
        .map_or("network".into(), |s| s.to_string_lossy().into_owned());
    match stem.strip_suffix(".unrolled") {
        Some(s) if nedrt_stages::unrolled::is_manifest(path) => s.to_string(),
        _ => stem,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_names_are_file_stems_without_the_manifest_suffix() {
        assert_eq!(level_name(Path::new("models/dcnn.onnx")), "dcnn");
        assert_eq!(
            level_name(Path::new("models/unrolled/unrolled-k3.unrolled.toml")),
            "unrolled-k3"
        );
        assert_eq!(level_name(Path::new("a.unrolled.onnx")), "a.unrolled");
    }
}
