//! `MaxPool` (2×2, stride 2) and `Concat` along channels: the U-Net's
//! down path and skip connections, which carry no weights.

use super::attrs::{check_attrs, int_or, ints_or};
use super::{Graph, Node};
use crate::network::{Layer, ValueId, ValueInfo};

/// A 2×2 stride-2 max pooling (one level down).
pub(super) fn max_pool(n: &Node, g: &mut Graph) -> Result<ValueId, String> {
    let what = &n.what;
    let input = n.act(0)?;
    let checks = [
        (
            "kernel_shape",
            ints_or(n.node, "kernel_shape", &[]),
            vec![2, 2],
        ),
        ("strides", ints_or(n.node, "strides", &[1, 1]), vec![2, 2]),
        ("pads", ints_or(n.node, "pads", &[0, 0, 0, 0]), vec![0; 4]),
        (
            "dilations",
            ints_or(n.node, "dilations", &[1, 1]),
            vec![1, 1],
        ),
        ("ceil_mode", vec![int_or(n.node, "ceil_mode", 0)], vec![0]),
        (
            "storage_order",
            vec![int_or(n.node, "storage_order", 0)],
            vec![0],
        ),
    ];
    check_attrs(what, "only 2×2 stride-2 pooling is supported", checks)?;
    let info = g.values[input];
    let output = g.push_value(ValueInfo {
        channels: info.channels,
        level: info.level + 1,
    });
    g.layers.push(Layer::MaxPool { input, output });
    Ok(output)
}

/// Channel concatenation of activations at the same level.
pub(super) fn concat(n: &Node, g: &mut Graph) -> Result<ValueId, String> {
    let what = &n.what;
    let axis = int_or(n.node, "axis", i64::MIN);
    if axis != 1 && axis != -3 {
        return Err(format!(
            "{what}: axis {axis}; only channel concat (axis 1) is supported"
        ));
    }
    let ins = (0..n.node.input.len())
        .map(|i| n.act(i))
        .collect::<Result<Vec<_>, _>>()?;
    let level = g.values[ins[0]].level;
    if ins.iter().any(|&i| g.values[i].level != level) {
        return Err(format!("{what}: inputs have different sizes"));
    }
    let channels = ins.iter().map(|&i| g.values[i].channels).sum();
    let output = g.push_value(ValueInfo { channels, level });
    g.layers.push(Layer::Concat {
        inputs: ins,
        output,
    });
    Ok(output)
}
