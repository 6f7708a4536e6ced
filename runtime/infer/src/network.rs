//! The D-CNN as the runtime sees it once lowered: a short list of fused
//! layers (3×3 conv + bias + ReLU, 2×2 max pool, 2×2 stride-2 transposed
//! conv, channel concat, and the residual add fused into the last conv) over
//! activations described by their channels and resolution level. The WGSL
//! backend and the CPU reference run from these layers.
//!
//! This module only describes the result: reading, checking and lowering
//! the ONNX file is [`ModelFile`](crate::ModelFile)'s (`model_file.rs`), so
//! these types depend on nothing else in the crate.

/// Index of an activation tensor in [`Network::values`].
pub type ValueId = usize;

/// Shape of an activation: channels at a resolution level (level `l` has
/// sides 2^-l of the frame's).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ValueInfo {
    pub channels: usize,
    pub level: u32,
}

/// "Same" convolution, stride 1, odd square kernel, weight `[cout][cin][k][k]`.
#[derive(Debug, Clone)]
pub struct Conv {
    pub input: ValueId,
    pub output: ValueId,
    pub cin: usize,
    pub cout: usize,
    pub kernel: usize,
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
    pub relu: bool,
    /// Tensor added to the result (the D-CNN's residual `I + UNet(I)`).
    pub residual: Option<ValueId>,
}

/// 2×2 transposed convolution with stride 2, weight `[cin][cout][2][2]`.
#[derive(Debug, Clone)]
pub struct ConvTranspose {
    pub input: ValueId,
    pub output: ValueId,
    pub cin: usize,
    pub cout: usize,
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
    pub relu: bool,
}

/// One lowered layer, in execution order.
#[derive(Debug, Clone)]
pub enum Layer {
    Conv(Conv),
    /// 2×2 max pool, stride 2.
    MaxPool {
        input: ValueId,
        output: ValueId,
    },
    ConvTranspose(ConvTranspose),
    /// Channel concatenation, inputs in order.
    Concat {
        inputs: Vec<ValueId>,
        output: ValueId,
    },
}

/// A validated, lowered network. Input is value 0 (level 0; 3 channels for
/// a D-CNN, more for a network that takes other planes beside the image).
#[derive(Debug, Clone)]
pub struct Network {
    pub layers: Vec<Layer>,
    pub values: Vec<ValueInfo>,
    pub output: ValueId,
    /// Frame sides must be multiples of this (2^deepest level).
    pub multiple: usize,
    /// Multiply-adds per frame pixel (convolutions).
    pub macs_per_pixel: f64,
    /// Whether the output is a display image, clamped to the panel's
    /// [0, 1] in its last layer (a D-CNN), or a signed correction, not
    /// clamped (the ONNX metadata `nedrt.output = correction`: a step of
    /// the unrolled preprocessor).
    pub clamped: bool,
}

impl Layer {
    pub fn output(&self) -> ValueId {
        match self {
            Layer::Conv(c) => c.output,
            Layer::ConvTranspose(c) => c.output,
            Layer::MaxPool { output, .. } | Layer::Concat { output, .. } => *output,
        }
    }
}

impl Network {
    /// How far, in frame pixels, an output pixel can see: a bound on the
    /// distance from which any input pixel changes it (what a band of the
    /// frame needs around it to give the whole frame's result exactly).
    /// Conservative at pools and transposed convs (a whole cell of the
    /// coarser level counts).
    pub fn receptive_radius(&self) -> usize {
        let mut radius = vec![0usize; self.values.len()];
        let level = |v: ValueId| self.values[v].level;
        for layer in &self.layers {
            let reach = match layer {
                Layer::Conv(c) => {
                    let own = radius[c.input] + ((c.kernel / 2) << level(c.input));
                    c.residual.map_or(own, |r| own.max(radius[r]))
                }
                Layer::MaxPool { input, output }
                | Layer::ConvTranspose(ConvTranspose { input, output, .. }) => {
                    radius[*input] + (1usize << level(*input).max(level(*output)))
                }
                Layer::Concat { inputs, .. } => {
                    inputs.iter().map(|&i| radius[i]).max().unwrap_or(0)
                }
            };
            let out = layer.output();
            radius[out] = radius[out].max(reach);
        }
        radius[self.output]
    }
}
