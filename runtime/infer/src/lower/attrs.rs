//! ONNX attribute and initializer access shared by the lowerings.

use tract_onnx::pb;

const FLOAT: i32 = 1;

pub(super) fn attr<'a>(node: &'a pb::NodeProto, name: &str) -> Option<&'a pb::AttributeProto> {
    node.attribute.iter().find(|a| a.name == name)
}

pub(super) fn ints_or(node: &pb::NodeProto, name: &str, default: &[i64]) -> Vec<i64> {
    attr(node, name).map_or_else(|| default.to_vec(), |a| a.ints.clone())
}

pub(super) fn int_or(node: &pb::NodeProto, name: &str, default: i64) -> i64 {
    attr(node, name).map_or(default, |a| a.i)
}

pub(super) fn describe(node: &pb::NodeProto) -> String {
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
pub(super) type Initializer = (Vec<usize>, Vec<f32>);

/// Float data of an initializer, checked against its dims.
pub(super) fn tensor_data(t: &pb::TensorProto) -> Result<Initializer, String> {
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
    // Checked: a file's dims can ask for more values than any memory holds
    // (found by the onnx_model fuzz target).
    let n = dims
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .filter(|n| n.checked_mul(4).is_some())
        .ok_or_else(|| {
            format!(
                "initializer '{}' has dims {dims:?}: more values than can be addressed",
                t.name
            )
        })?;
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

/// The most input channels a network may take (the unrolled
/// preprocessor's step corrections take 9: point, dual and gradient).
pub(super) const MAX_INPUT_CHANNELS: i64 = 64;

/// Checks a graph input or output is float 1×C×H×W with dynamic H and W
/// and C in `channels`; returns C (3 where the file does not say).
pub(super) fn check_image_signature(
    v: &pb::ValueInfoProto,
    what: &str,
    channels: std::ops::RangeInclusive<i64>,
) -> Result<usize, String> {
    let want = if channels.start() == channels.end() {
        format!("1×{}×H×W", channels.start())
    } else {
        format!(
            "1×C×H×W (C from {} to {})",
            channels.start(),
            channels.end()
        )
    };
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
        return Ok(3);
    };
    use pb::tensor_shape_proto::dimension::Value as D;
    let dims: Vec<Option<&D>> = shape.dim.iter().map(|d| d.value.as_ref()).collect();
    if dims.len() != 4 {
        return Err(format!(
            "{what} '{}' has rank {}, the runtime needs {want}",
            v.name,
            dims.len()
        ));
    }
    if let Some(D::DimValue(n)) = dims[0]
        && *n != 1
    {
        return Err(format!(
            "{what} '{}' has {n} along axis 0, the runtime needs {want}",
            v.name
        ));
    }
    let count = match dims[1] {
        Some(D::DimValue(n)) if channels.contains(n) => *n as usize,
        Some(D::DimValue(n)) => {
            return Err(format!(
                "{what} '{}' has {n} along axis 1, the runtime needs {want}",
                v.name
            ));
        }
        _ => 3,
    };
    if let (Some(D::DimValue(h)), Some(D::DimValue(w))) = (dims[2], dims[3]) {
        return Err(format!(
            "{what} '{}' has a fixed size {h}×{w}; the runtime feeds frames of any size, \
             so export with dynamic height and width (dynamic_axes)",
            v.name
        ));
    }
    Ok(count)
}

/// Compares each attribute with the one value the runtime implements.
pub(super) fn check_attrs<const N: usize>(
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

/// The bias, checked against the output channels, or zeros.
pub(super) fn bias_or_zero(
    what: &str,
    bias: Option<Initializer>,
    cout: usize,
) -> Result<Vec<f32>, String> {
    match bias {
        Some((dims, b)) if dims == [cout] => Ok(b),
        Some((dims, _)) => Err(format!("{what}: bias shape {dims:?}, expected [{cout}]")),
        None => Ok(vec![0.0; cout]),
    }
}
