//! Builds the D-CNN's ONNX graph in Rust, with PyTorch's default random
//! initialisation (uniform ±1/√fan_in), node for node as `torch.onnx.export`
//! writes the trainer's U-Net (models/nedrt_train/unet.py). Used for parity
//! tests at any width and depth, for the latency benchmark of sizes that have
//! no trained weights (latency does not depend on the weights' values), and
//! to make malformed models for the bad-input tests.

use prost::Message;
/// The ONNX protobuf types, for tests that edit a model.
pub use tract_onnx::pb;

/// Deterministic uniform numbers (SplitMix64), so a seed names a model.
#[derive(Debug, Clone)]
pub struct SplitMix(u64);

impl SplitMix {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    /// Uniform in [−b, b).
    pub fn symmetric(&mut self, b: f32) -> f32 {
        (2.0 * self.unit() - 1.0) * b
    }
    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f32 {
        let u = self.unit().max(1e-7);
        let v = self.unit();
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f32::consts::PI * v).cos()
    }
}

/// An ONNX graph under construction.
#[derive(Debug)]
pub struct GraphBuilder {
    pub graph: pb::GraphProto,
    rng: SplitMix,
    count: usize,
}

fn ints(name: &str, v: &[i64]) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: 7, // INTS
        ints: v.to_vec(),
        ..Default::default()
    }
}

fn int(name: &str, v: i64) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: 2, // INT
        i: v,
        ..Default::default()
    }
}

/// A float32 N×C×H×W value with symbolic `height` and `width`.
pub fn image_value(name: &str, channels: i64) -> pb::ValueInfoProto {
    use pb::tensor_shape_proto::{Dimension, dimension::Value as D};
    let dim = |v: D| Dimension {
        value: Some(v),
        ..Default::default()
    };
    pb::ValueInfoProto {
        name: name.into(),
        r#type: Some(pb::TypeProto {
            value: Some(pb::type_proto::Value::TensorType(pb::type_proto::Tensor {
                elem_type: 1,
                shape: Some(pb::TensorShapeProto {
                    dim: vec![
                        dim(D::DimValue(1)),
                        dim(D::DimValue(channels)),
                        dim(D::DimParam("height".into())),
                        dim(D::DimParam("width".into())),
                    ],
                }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

impl GraphBuilder {
    pub fn new(seed: u64) -> Self {
        Self {
            graph: pb::GraphProto {
                name: "dcnn".into(),
                ..Default::default()
            },
            rng: SplitMix::new(seed),
            count: 0,
        }
    }

    fn fresh(&mut self, what: &str) -> String {
        self.count += 1;
        format!("/{what}_{}", self.count)
    }

    /// Adds a float initializer of `dims` drawn uniform in ±`bound`.
    pub fn weight(&mut self, dims: &[i64], bound: f32) -> String {
        let name = self.fresh("w");
        let n: i64 = dims.iter().product();
        let raw: Vec<u8> = (0..n)
            .flat_map(|_| self.rng.symmetric(bound).to_le_bytes())
            .collect();
        self.graph.initializer.push(pb::TensorProto {
            name: name.clone(),
            dims: dims.to_vec(),
            data_type: 1,
            raw_data: raw,
            ..Default::default()
        });
        name
    }

    pub fn node(&mut self, op: &str, inputs: &[&str], attrs: Vec<pb::AttributeProto>) -> String {
        let out = self.fresh(op);
        self.graph.node.push(pb::NodeProto {
            op_type: op.into(),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![out.clone()],
            attribute: attrs,
            ..Default::default()
        });
        out
    }

    pub fn conv(&mut self, x: &str, cin: i64, cout: i64, k: i64) -> String {
        let bound = 1.0 / ((cin * k * k) as f32).sqrt();
        let w = self.weight(&[cout, cin, k, k], bound);
        let b = self.weight(&[cout], bound);
        let p = (k - 1) / 2;
        self.node(
            "Conv",
            &[x, &w, &b],
            vec![
                ints("dilations", &[1, 1]),
                int("group", 1),
                ints("kernel_shape", &[k, k]),
                ints("pads", &[p, p, p, p]),
                ints("strides", &[1, 1]),
            ],
        )
    }

    pub fn conv_relu(&mut self, x: &str, cin: i64, cout: i64) -> String {
        let c = self.conv(x, cin, cout, 3);
        self.node("Relu", &[&c], vec![])
    }

    pub fn max_pool(&mut self, x: &str) -> String {
        self.node(
            "MaxPool",
            &[x],
            vec![
                int("ceil_mode", 0),
                ints("kernel_shape", &[2, 2]),
                ints("pads", &[0, 0, 0, 0]),
                ints("strides", &[2, 2]),
            ],
        )
    }

    pub fn conv_transpose(&mut self, x: &str, cin: i64, cout: i64) -> String {
        // PyTorch's fan_in for ConvTranspose2d weight [cin, cout, 2, 2] is cout·4.
        let bound = 1.0 / ((cout * 4) as f32).sqrt();
        let w = self.weight(&[cin, cout, 2, 2], bound);
        let b = self.weight(&[cout], bound);
        self.node(
            "ConvTranspose",
            &[x, &w, &b],
            vec![
                ints("kernel_shape", &[2, 2]),
                ints("pads", &[0, 0, 0, 0]),
                ints("strides", &[2, 2]),
            ],
        )
    }

    /// Wraps the graph with input `image` and output `display`.
    pub fn finish(self, output: &str) -> pb::ModelProto {
        self.finish_with(output, 3)
    }

    /// As [`GraphBuilder::finish`], for an input of `input_channels` planes.
    pub fn finish_with(mut self, output: &str, input_channels: i64) -> pb::ModelProto {
        self.graph.input = vec![image_value("image", input_channels)];
        if let Some(last) = self.graph.node.iter_mut().find(|n| n.output[0] == output) {
            last.output[0] = "display".into();
        }
        self.graph.output = vec![image_value("display", 3)];
        pb::ModelProto {
            ir_version: 8,
            producer_name: "nedrt synth".into(),
            opset_import: vec![pb::OperatorSetIdProto {
                domain: String::new(),
                version: 17,
            }],
            graph: Some(self.graph),
            ..Default::default()
        }
    }
}

/// The residual U-Net of docs/model.md §14 with channel widths width·2^i for
/// `levels` levels (32 and 4 are the full model), random weights.
pub fn unet(width: i64, levels: u32, seed: u64) -> pb::ModelProto {
    let mut g = GraphBuilder::new(seed);
    let widths: Vec<i64> = (0..levels).map(|i| width << i).collect();
    let mut h = "image".to_string();
    let mut skips = Vec::new();
    let mut cin = 3;
    for (i, &w) in widths.iter().enumerate() {
        let a = g.conv_relu(&h, cin, w);
        h = g.conv_relu(&a, w, w);
        cin = w;
        if i + 1 < widths.len() {
            skips.push(h.clone());
            h = g.max_pool(&h);
        }
    }
    for i in (0..widths.len() - 1).rev() {
        let (w_hi, w_lo) = (widths[i + 1], widths[i]);
        let up = g.conv_transpose(&h, w_hi, w_lo);
        let skip = skips.pop().unwrap_or_default();
        let cat = g.node("Concat", &[&skip, &up], vec![int("axis", 1)]);
        let a = g.conv_relu(&cat, 2 * w_lo, w_lo);
        h = g.conv_relu(&a, w_lo, w_lo);
    }
    let out = g.conv(&h, widths[0], 3, 1);
    let sum = g.node("Add", &["image", &out], vec![]);
    g.finish(&sum)
}

/// A step correction of the unrolled preprocessor, node for node as the
/// trainer exports it (models/nedrt_train/unrolled.py `StepCorrection`):
/// `layers` 3×3 convs from `cin` planes, `width` channels, ReLU between,
/// the last to 3 signed channels (metadata `nedrt.output = correction`).
pub fn step_correction(cin: i64, width: i64, layers: usize, seed: u64) -> pb::ModelProto {
    let mut g = GraphBuilder::new(seed);
    let mut h = "image".to_string();
    let mut c = cin;
    for _ in 1..layers {
        h = g.conv_relu(&h, c, width);
        c = width;
    }
    let out = g.conv(&h, c, 3, 3);
    let mut model = g.finish_with(&out, cin);
    model.metadata_props.push(pb::StringStringEntryProto {
        key: crate::OUTPUT_KEY.into(),
        value: "correction".into(),
    });
    model
}

/// The protobuf bytes of a model.
pub fn encode(model: &pb::ModelProto) -> Vec<u8> {
    model.encode_to_vec()
}
