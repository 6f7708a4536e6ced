//! Validation and lowering of a decoded ONNX graph to [`Network`]: the
//! signature (one float 1×3×H×W input with dynamic H and W, one output of
//! the same shape), every operator and attribute against what the runtime
//! implements, symbolic shape propagation (channels and pooling level), and
//! the fusions (ReLU and the residual Add into the conv before them).
//! Errors are reasons; the caller adds the file name.

use std::collections::HashMap;

use tract_onnx::pb;

use super::network::{Conv, ConvTranspose, Layer, Network, ValueId, ValueInfo};

const FLOAT: i32 = 1;

fn attr<'a>(node: &'a pb::NodeProto, name: &str) -> Option<&'a pb::AttributeProto> {
    node.attribute.iter().find(|a| a.name == name)
}

fn ints_or(node: &pb::NodeProto, name: &str, default: &[i64]) -> Vec<i64> {
    attr(node, name).map_or_else(|| default.to_vec(), |a| a.ints.clone())
}

fn int_or(node: &pb::NodeProto, name: &str, default: i64) -> i64 {
    attr(node, name).map_or(default, |a| a.i)
}

fn describe(node: &pb::NodeProto) -> String {
    if node.name.is_empty() {
        format!(
            "{} node (output '{}')",
            node.op_type,
            node.output.first().map_or("", |s| s)
        )
    } else {
        format!("{} node '{}'", node.op_type, node.name)
    }
}

/// An initializer's dims and float data.
type Initializer = (Vec<usize>, Vec<f32>);

/// Float data of an initializer, checked against its dims.
fn tensor_data(t: &pb::TensorProto) -> Result<Initializer, String> {
    if t.data_type != FLOAT {
        return Err(format!(
            "initializer '{}' has ONNX data type {}, only float32 (1) is supported",
            t.name, t.data_type
        ));
    }
    if !t.external_data.is_empty() || t.data_location == Some(1) {
        return Err(format!(
            "initializer '{}' is stored in an external file; export a self-contained model \
             (torch.onnx.export(..., dynamo=False))",
            t.name
        ));
    }
    let dims: Vec<usize> = t
        .dims
        .iter()
        .map(|&d| usize::try_from(d).map_err(|_| format!("initializer '{}' has dim {d}", t.name)))
        .collect::<Result<_, _>>()?;
    let n: usize = dims.iter().product();
    let data: Vec<f32> = if !t.raw_data.is_empty() {
        if t.raw_data.len() != 4 * n {
            return Err(format!(
                "initializer '{}' holds {} bytes, its dims {:?} need {}",
                t.name,
                t.raw_data.len(),
                dims,
                4 * n
            ));
        }
        t.raw_data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    } else {
        if t.float_data.len() != n {
            return Err(format!(
                "initializer '{}' holds {} floats, its dims {:?} need {n}",
                t.name,
                t.float_data.len(),
                dims
            ));
        }
        t.float_data.clone()
    };
    if let Some(bad) = data.iter().find(|v| !v.is_finite()) {
        return Err(format!("initializer '{}' contains {bad}", t.name));
    }
    Ok((dims, data))
}

/// Checks a graph input or output is float 1×3×H×W; returns whether H and W
/// are symbolic (or absent).
fn check_image_signature(v: &pb::ValueInfoProto, what: &str) -> Result<(), String> {
    let Some(pb::type_proto::Value::TensorType(t)) =
        v.r#type.as_ref().and_then(|t| t.value.as_ref())
    else {
        return Err(format!("{what} '{}' is not a tensor", v.name));
    };
    if t.elem_type != FLOAT {
        return Err(format!(
            "{what} '{}' has ONNX element type {}, the runtime needs float32",
            v.name, t.elem_type
        ));
    }
    let Some(shape) = &t.shape else {
        return Ok(());
    };
    use pb::tensor_shape_proto::dimension::Value as D;
    let dims: Vec<Option<&D>> = shape.dim.iter().map(|d| d.value.as_ref()).collect();
    if dims.len() != 4 {
        return Err(format!(
            "{what} '{}' has rank {}, the runtime needs 1×3×H×W",
            v.name,
            dims.len()
        ));
    }
    for (axis, want) in [(0usize, 1i64), (1, 3)] {
        if let Some(D::DimValue(n)) = dims[axis]
            && *n != want
        {
            return Err(format!(
                "{what} '{}' has {n} along axis {axis}, the runtime needs 1×3×H×W",
                v.name
            ));
        }
    }
    if let (Some(D::DimValue(h)), Some(D::DimValue(w))) = (dims[2], dims[3]) {
        return Err(format!(
            "{what} '{}' has a fixed size {h}×{w}; the runtime feeds frames of any size, \
             so export with dynamic height and width (dynamic_axes)",
            v.name
        ));
    }
    Ok(())
}

fn producer_mut(layers: &mut [Layer], value: ValueId) -> Option<&mut Layer> {
    layers.iter_mut().find(|l| l.output() == value)
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
            "the graph has {} inputs and {} outputs; the runtime needs one 1×3×H×W image in \
             and one out",
            inputs.len(),
            graph.output.len()
        ));
    }
    check_image_signature(inputs[0], "input")?;
    check_image_signature(&graph.output[0], "output")?;

    let mut uses: HashMap<&str, usize> = HashMap::new();
    for name in graph
        .node
        .iter()
        .flat_map(|n| n.input.iter())
        .chain([&graph.output[0].name])
    {
        *uses.entry(name.as_str()).or_default() += 1;
    }
    let mut values = vec![ValueInfo {
        channels: 3,
        level: 0,
    }];
    let mut names: HashMap<String, ValueId> = HashMap::new();
    names.insert(inputs[0].name.clone(), 0);
    let mut layers: Vec<Layer> = Vec::new();
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
        let input_name = |i: usize| -> Result<&str, String> {
            node.input
                .get(i)
                .map(String::as_str)
                .ok_or_else(|| format!("{what}: missing input {i}"))
        };
        let act = |i: usize| -> Result<ValueId, String> {
            let name = input_name(i)?;
            names.get(name).copied().ok_or_else(|| {
                format!("{what}: input '{name}' is not an activation computed earlier")
            })
        };
        let init = |i: usize| -> Result<Option<Initializer>, String> {
            match node.input.get(i).filter(|s| !s.is_empty()) {
                None => Ok(None),
                Some(name) => inits
                    .get(name.as_str())
                    .ok_or_else(|| format!("{what}: weight '{name}' is not an initializer"))
                    .and_then(|t| tensor_data(t).map(Some)),
            }
        };
        let single_use =
            |i: usize| -> Result<bool, String> { Ok(uses.get(input_name(i)?).copied() == Some(1)) };
        let out_value = match node.op_type.as_str() {
            "Conv" => {
                let input = act(0)?;
                let (wd, weight) = init(1)?.ok_or_else(|| format!("{what}: no weight"))?;
                let info = values[input];
                if wd.len() != 4 || wd[2] != wd[3] || wd[2] % 2 == 0 || wd[1] != info.channels {
                    return Err(format!(
                        "{what}: weight shape {wd:?} does not fit an input of {} channels \
                         (supported: [cout, cin, k, k] with odd k)",
                        info.channels
                    ));
                }
                let (cout, cin, k) = (wd[0], wd[1], wd[2]);
                let p = ((k - 1) / 2) as i64;
                let checks = [
                    ("group", vec![int_or(node, "group", 1)], vec![1]),
                    ("strides", ints_or(node, "strides", &[1, 1]), vec![1, 1]),
                    ("dilations", ints_or(node, "dilations", &[1, 1]), vec![1, 1]),
                    ("pads", ints_or(node, "pads", &[0, 0, 0, 0]), vec![p; 4]),
                ];
                check_attrs(&what, "only 'same' convolutions are supported", checks)?;
                if attr(node, "auto_pad").is_some_and(|a| !a.s.is_empty() && a.s != b"NOTSET") {
                    return Err(format!(
                        "{what}: auto_pad is not supported, use explicit pads"
                    ));
                }
                let bias = bias_or_zero(&what, init(2)?, cout)?;
                values.push(ValueInfo {
                    channels: cout,
                    level: info.level,
                });
                let output = values.len() - 1;
                layers.push(Layer::Conv(Conv {
                    input,
                    output,
                    cin,
                    cout,
                    kernel: k,
                    weight,
                    bias,
                    relu: false,
                    residual: None,
                }));
                output
            }
            "ConvTranspose" => {
                let input = act(0)?;
                let (wd, weight) = init(1)?.ok_or_else(|| format!("{what}: no weight"))?;
                let info = values[input];
                if wd.len() != 4 || wd[2] != 2 || wd[3] != 2 || wd[0] != info.channels {
                    return Err(format!(
                        "{what}: weight shape {wd:?}; supported is [cin = {}, cout, 2, 2]",
                        info.channels
                    ));
                }
                if info.level == 0 {
                    return Err(format!("{what}: upsamples above the frame's resolution"));
                }
                let checks = [
                    ("group", vec![int_or(node, "group", 1)], vec![1]),
                    ("strides", ints_or(node, "strides", &[1, 1]), vec![2, 2]),
                    ("dilations", ints_or(node, "dilations", &[1, 1]), vec![1, 1]),
                    ("pads", ints_or(node, "pads", &[0, 0, 0, 0]), vec![0; 4]),
                    (
                        "output_padding",
                        ints_or(node, "output_padding", &[0, 0]),
                        vec![0, 0],
                    ),
                ];
                check_attrs(&what, "only 2×2 stride-2 upsampling is supported", checks)?;
                if attr(node, "output_shape").is_some() {
                    return Err(format!("{what}: output_shape is not supported"));
                }
                let cout = wd[1];
                let bias = bias_or_zero(&what, init(2)?, cout)?;
                values.push(ValueInfo {
                    channels: cout,
                    level: info.level - 1,
                });
                let output = values.len() - 1;
                layers.push(Layer::ConvTranspose(ConvTranspose {
                    input,
                    output,
                    cin: wd[0],
                    cout,
                    weight,
                    bias,
                    relu: false,
                }));
                output
            }
            "MaxPool" => {
                let input = act(0)?;
                let checks = [
                    (
                        "kernel_shape",
                        ints_or(node, "kernel_shape", &[]),
                        vec![2, 2],
                    ),
                    ("strides", ints_or(node, "strides", &[1, 1]), vec![2, 2]),
                    ("pads", ints_or(node, "pads", &[0, 0, 0, 0]), vec![0; 4]),
                    ("dilations", ints_or(node, "dilations", &[1, 1]), vec![1, 1]),
                    ("ceil_mode", vec![int_or(node, "ceil_mode", 0)], vec![0]),
                    (
                        "storage_order",
                        vec![int_or(node, "storage_order", 0)],
                        vec![0],
                    ),
                ];
                check_attrs(&what, "only 2×2 stride-2 pooling is supported", checks)?;
                let info = values[input];
                values.push(ValueInfo {
                    channels: info.channels,
                    level: info.level + 1,
                });
                let output = values.len() - 1;
                layers.push(Layer::MaxPool { input, output });
                output
            }
            "Concat" => {
                let axis = int_or(node, "axis", i64::MIN);
                if axis != 1 && axis != -3 {
                    return Err(format!(
                        "{what}: axis {axis}; only channel concat (axis 1) is supported"
                    ));
                }
                let ins = (0..node.input.len())
                    .map(&act)
                    .collect::<Result<Vec<_>, _>>()?;
                let level = values[ins[0]].level;
                if ins.iter().any(|&i| values[i].level != level) {
                    return Err(format!("{what}: inputs have different sizes"));
                }
                let channels = ins.iter().map(|&i| values[i].channels).sum();
                values.push(ValueInfo { channels, level });
                let output = values.len() - 1;
                layers.push(Layer::Concat {
                    inputs: ins,
                    output,
                });
                output
            }
            "Relu" => {
                let input = act(0)?;
                let fusable = single_use(0)?;
                match producer_mut(&mut layers, input) {
                    Some(Layer::Conv(Conv {
                        relu: r @ false,
                        residual: None,
                        ..
                    }))
                    | Some(Layer::ConvTranspose(ConvTranspose {
                        relu: r @ false, ..
                    })) if fusable => {
                        *r = true;
                    }
                    _ => {
                        return Err(format!(
                            "{what}: ReLU is supported only directly after a Conv or \
                             ConvTranspose whose output nothing else reads"
                        ));
                    }
                }
                input
            }
            "Add" => {
                let (a, b) = (act(0)?, act(1)?);
                if values[a] != values[b] {
                    return Err(format!("{what}: operands of different shapes"));
                }
                // Fuse into whichever operand is a single-use conv computed after the other.
                let mut fused = None;
                for (conv_side, other, i) in [(b, a, 1), (a, b, 0)] {
                    if conv_side > other
                        && single_use(i)?
                        && let Some(Layer::Conv(c)) = producer_mut(&mut layers, conv_side)
                        && c.residual.is_none()
                    {
                        c.residual = Some(other);
                        fused = Some(conv_side);
                        break;
                    }
                }
                fused.ok_or_else(|| {
                    format!(
                        "{what}: Add is supported only as a residual added to the output of \
                         a Conv that nothing else reads"
                    )
                })?
            }
            "Identity" => act(0)?,
            other => {
                return Err(format!(
                    "{what}: operator '{other}' is not supported (supported: Conv, \
                     ConvTranspose, MaxPool, Concat, Relu, Add, Identity)"
                ));
            }
        };
        names.insert(node.output[0].clone(), out_value);
    }
    let out_name = &graph.output[0].name;
    let output = *names
        .get(out_name)
        .ok_or_else(|| format!("output '{out_name}' is not computed by any node"))?;
    if values[output]
        != (ValueInfo {
            channels: 3,
            level: 0,
        })
    {
        return Err(format!(
            "output '{out_name}' has {} channels at 1/{} of the frame size; the runtime needs \
             1×3×H×W",
            values[output].channels,
            1 << values[output].level
        ));
    }
    if !matches!(
        layers.iter().find(|l| l.output() == output),
        Some(Layer::Conv(_))
    ) {
        return Err(format!(
            "output '{out_name}' must come from a Conv (the panel clamp is fused into it)"
        ));
    }
    let deepest = values.iter().map(|v| v.level).max().unwrap_or(0);
    if deepest > 12 {
        return Err(format!(
            "{deepest} pooling levels; at most 12 are supported"
        ));
    }
    let macs_per_pixel = layers
        .iter()
        .map(|l| match l {
            Layer::Conv(c) => {
                (c.cin * c.cout * c.kernel * c.kernel) as f64
                    / 4f64.powi(values[c.output].level as i32)
            }
            Layer::ConvTranspose(c) => {
                (c.cin * c.cout) as f64 / 4f64.powi(values[c.output].level as i32)
            }
            _ => 0.0,
        })
        .sum();
    Ok(Network {
        layers,
        values,
        output,
        multiple: 1 << deepest,
        macs_per_pixel,
    })
}

fn check_attrs<const N: usize>(
    what: &str,
    rule: &str,
    checks: [(&str, Vec<i64>, Vec<i64>); N],
) -> Result<(), String> {
    for (name, got, want) in checks {
        if got != want {
            return Err(format!(
                "{what}: {name} = {got:?}; {rule} ({name} = {want:?})"
            ));
        }
    }
    Ok(())
}

fn bias_or_zero(what: &str, bias: Option<Initializer>, cout: usize) -> Result<Vec<f32>, String> {
    match bias {
        Some((dims, b)) if dims == [cout] => Ok(b),
        Some((dims, _)) => Err(format!("{what}: bias shape {dims:?}, expected [{cout}]")),
        None => Ok(vec![0.0; cout]),
    }
}
