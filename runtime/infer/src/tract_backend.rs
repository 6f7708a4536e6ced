//! The `cpu` backend: tract, a pure-Rust ONNX engine, so the D-CNN runs on
//! a fresh clone with nothing beyond `cargo build`. tract optimises for
//! concrete shapes, so a plan is prepared per frame size and kept (a
//! headset's frame size does not change; the simulator's test images share
//! a few sizes).

use std::collections::HashMap;
use std::sync::Arc;

use tract_onnx::prelude::*;

use super::{Backend, BackendOptions, InferenceError, ModelFile};
use nedrt_core::Image;

type Plan = Arc<TypedRunnableModel>;

pub struct TractBackend {
    /// The decoded graph, parsed into tract's form once at load time.
    model: InferenceModel,
    plans: HashMap<(usize, usize, usize), Plan>,
}

impl std::fmt::Debug for TractBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TractBackend")
            .field("plans", &self.plans.keys().collect::<Vec<_>>())
            .finish()
    }
}

fn err(reason: impl std::fmt::Display) -> InferenceError {
    InferenceError::Backend {
        backend: "cpu",
        reason: reason.to_string(),
    }
}

impl TractBackend {
    pub fn new(model: &ModelFile, _options: &BackendOptions) -> Result<Self, InferenceError> {
        // PyTorch's exporters write value_info that tract cannot unify with
        // concrete input facts; the shapes are re-inferred anyway.
        let inference = tract_onnx::onnx()
            .with_ignore_value_info(true)
            .model_for_proto_model(&model.proto)
            .map_err(|e| InferenceError::Model {
                path: model.path.clone(),
                reason: format!("tract cannot load it: {e:#}"),
            })?;
        Ok(Self {
            model: inference,
            plans: HashMap::new(),
        })
    }

    fn plan(
        &mut self,
        channels: usize,
        width: usize,
        height: usize,
    ) -> Result<Plan, InferenceError> {
        if let Some(p) = self.plans.get(&(channels, width, height)) {
            return Ok(p.clone());
        }
        let plan = self
            .model
            .clone()
            .with_input_fact(0, f32::fact([1, channels, height, width]).into())
            .and_then(|m| m.into_optimized())
            .and_then(|m| m.into_runnable())
            .map_err(|e| err(format!("preparing {width}×{height}: {e:#}")))?;
        self.plans.insert((channels, width, height), plan.clone());
        Ok(plan)
    }
}

impl Backend for TractBackend {
    fn describe(&self) -> String {
        "cpu (tract 0.23, 1 thread)".into()
    }

    fn run(&mut self, frame: &Image) -> Result<Image, InferenceError> {
        let plan = self.plan(frame.channels(), frame.width, frame.height)?;
        let input = Tensor::from_shape(
            &[1, frame.channels(), frame.height, frame.width],
            frame.data(),
        )
        .map_err(err)?;
        let out = plan.run(tvec!(input.into())).map_err(err)?;
        let view = out[0].to_plain_array_view::<f32>().map_err(err)?;
        if view.shape() != [1, 3, frame.height, frame.width] {
            return Err(err(format!("output shape {:?}", view.shape())));
        }
        Ok(Image::rgb(
            frame.width,
            frame.height,
            view.iter().copied().collect(),
        ))
    }
}
