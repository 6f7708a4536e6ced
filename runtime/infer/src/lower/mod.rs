//! Validation and lowering of a decoded ONNX graph to [`Network`]: the
//! signature (one float 1×C×H×W input with dynamic H and W, C = 3 for a
//! D-CNN and up to 64 for other networks, one 1×3×H×W output), every operator and attribute against what the runtime
//! implements, symbolic shape propagation (channels and pooling level), and
//! the fusions (ReLU and the residual Add into the conv before them).
//! Errors are reasons; the caller adds the file name. One file per
//! operator family (conv, pool, fuse), as tract lowers one op per file;
//! this module walks the graph and checks what comes in and out.

mod attrs;
mod conv;
mod fuse;
mod pool;

use std::collections::HashMap;

use tract_onnx::pb;

use super::network::{Layer, Network, ValueId, ValueInfo};
use attrs::{Initializer, MAX_INPUT_CHANNELS, check_image_signature, describe, tensor_data};

/// What the lowering has built so far: every activation's shape, and the layers.
pub(super) struct Graph {
    values: Vec<ValueInfo>,
    layers: Vec<Layer>,
}

impl Graph {
    /// Adds an activation; returns its id.
    fn push_value(&mut self, info: ValueInfo) -> ValueId {
        self.values.push(info);
        self.values.len() - 1
    }
}

/// One ONNX node with what it may read: activations computed earlier,
/// initializers, and how often each value is read (for the fusions).
pub(super) struct Node<'a> {
    node: &'a pb::NodeProto,
    /// The node as error messages name it.
    what: String,
    names: &'a HashMap<String, ValueId>,
    inits: &'a HashMap<&'a str, &'a pb::TensorProto>,
    uses: &'a HashMap<&'a str, usize>,
}

impl Node<'_> {
    fn input_name(&self, i: usize) -> Result<&str, String> {
        self.node
            .input
            .get(i)
            .map(String::as_str)
            .ok_or_else(|| format!("{}: missing input {i}", self.what))
    }

    /// Input `i` as an activation computed by an earlier node.
    fn act(&self, i: usize) -> Result<ValueId, String> {
        let name = self.input_name(i)?;
        self.names.get(name).copied().ok_or_else(|| {
            format!(
                "{}: input '{name}' is not an activation computed earlier",
                self.what
            )
        })
    }

    /// Input `i` as an initializer (weights), if the node has it.
    fn init(&self, i: usize) -> Result<Option<Initializer>, String> {
        match self.node.input.get(i).filter(|s| !s.is_empty()) {
            None => Ok(None),
            Some(name) => self
                .inits
                .get(name.as_str())
                .ok_or_else(|| format!("{}: weight '{name}' is not an initializer", self.what))
                .and_then(|t| tensor_data(t).map(Some)),
        }
    }

    /// Whether input `i` is read by this node only (so it may be fused).
    fn single_use(&self, i: usize) -> Result<bool, String> {
        Ok(self.uses.get(self.input_name(i)?).copied() == Some(1))
    }
}

/// Validates and lowers; errors are reasons (the caller adds the file).
/// ReLU is fused into the conv before it and the residual Add into the conv
/// whose output it takes, when nothing else reads the unfused value.
pub(super) fn lower(model: &pb::ModelProto) -> Result<Network, String> {
    let graph = model.graph.as_ref().ok_or("no graph")?;
    let inits: HashMap<&str, &pb::TensorProto> = graph
        .initializer
        .iter()
        .map(|t| (t.name.as_str(), t))
        .collect();
    let inputs: Vec<&pb::ValueInfoProto> = graph
        .input
        .iter()
        .filter(|i| !inits.contains_key(i.name.as_str()))
        .collect();
    if inputs.len() != 1 || graph.output.len() != 1 {
        return Err(format!(
            "the graph has {} inputs and {} outputs; the runtime needs one 1×C×H×W image in \
             and one 1×3×H×W out",
            inputs.len(),
            graph.output.len()
        ));
    }
    let input_channels = check_image_signature(inputs[0], "input", 1..=MAX_INPUT_CHANNELS)?;
    check_image_signature(&graph.output[0], "output", 3..=3)?;

    let mut uses: HashMap<&str, usize> = HashMap::new();
    for name in graph
        .node
        .iter()
        .flat_map(|n| n.input.iter())
        .chain([&graph.output[0].name])
    {
        *uses.entry(name.as_str()).or_default() += 1;
    }
    let mut g = Graph {
        values: vec![ValueInfo {
            channels: input_channels,
            level: 0,
        }],
        layers: Vec::new(),
    };
    let mut names: HashMap<String, ValueId> = HashMap::new();
    names.insert(inputs[0].name.clone(), 0);
    for node in &graph.node {
        let what = describe(node);
        if !node.domain.is_empty() && node.domain != "ai.onnx" {
            return Err(format!(
                "{what}: operator domain '{}' is not supported",
                node.domain
            ));
        }
        if node.output.len() != 1 {
            return Err(format!("{what}: {} outputs, expected 1", node.output.len()));
        }
        let n = Node {
            node,
            what,
            names: &names,
            inits: &inits,
            uses: &uses,
        };
        let out_value = match node.op_type.as_str() {
            "Conv" => conv::conv(&n, &mut g)?,
            "ConvTranspose" => conv::conv_transpose(&n, &mut g)?,
            "MaxPool" => pool::max_pool(&n, &mut g)?,
            "Concat" => pool::concat(&n, &mut g)?,
            "Relu" => fuse::relu(&n, &mut g)?,
            "Add" => fuse::add(&n, &mut g)?,
            "Identity" => n.act(0)?,
            other => {
                return Err(format!(
                    "{}: operator '{other}' is not supported (supported: Conv, \
                     ConvTranspose, MaxPool, Concat, Relu, Add, Identity)",
                    n.what
                ));
            }
        };
        names.insert(node.output[0].clone(), out_value);
    }
    let out_name = &graph.output[0].name;
    let output = *names
        .get(out_name)
        .ok_or_else(|| format!("output '{out_name}' is not computed by any node"))?;
    if g.values[output]
        != (ValueInfo {
            channels: 3,
            level: 0,
        })
    {
        return Err(format!(
            "output '{out_name}' has {} channels at 1/{} of the frame size; the runtime needs \
             1×3×H×W",
            g.values[output].channels,
            1 << g.values[output].level
        ));
    }
    if !matches!(
        g.layers.iter().find(|l| l.output() == output),
        Some(Layer::Conv(_))
    ) {
        return Err(format!(
            "output '{out_name}' must come from a Conv (the panel clamp is fused into it)"
        ));
    }
    let deepest = g.values.iter().map(|v| v.level).max().unwrap_or(0);
    if deepest > 12 {
        return Err(format!(
            "{deepest} pooling levels; at most 12 are supported"
        ));
    }
    let macs_per_pixel = g
        .layers
        .iter()
        .map(|l| match l {
            Layer::Conv(c) => {
                (c.cin * c.cout * c.kernel * c.kernel) as f64
                    / 4f64.powi(g.values[c.output].level as i32)
            }
            Layer::ConvTranspose(c) => {
                (c.cin * c.cout) as f64 / 4f64.powi(g.values[c.output].level as i32)
            }
            _ => 0.0,
        })
        .sum();
    Ok(Network {
        layers: g.layers,
        values: g.values,
        output,
        multiple: 1 << deepest,
        macs_per_pixel,
        clamped: output_is_clamped(model)?,
    })
}

/// The metadata key that says what the network's output is.
pub const OUTPUT_KEY: &str = "nedrt.output";

/// `nedrt.output`: `display` (the default: a display image, clamped) or
/// `correction` (signed, not clamped).
fn output_is_clamped(model: &pb::ModelProto) -> Result<bool, String> {
    match model
        .metadata_props
        .iter()
        .find(|p| p.key == OUTPUT_KEY)
        .map(|p| p.value.as_str())
    {
        None | Some("display") => Ok(true),
        Some("correction") => Ok(false),
        Some(other) => Err(format!(
            "metadata {OUTPUT_KEY} = {other:?}: choose display (a display image, clamped to \
             [0, 1]) or correction (signed, not clamped)"
        )),
    }
}
