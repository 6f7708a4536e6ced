//! `Conv` (odd square kernels, 'same' padding) and `ConvTranspose` (2×2,
//! stride 2): the network's two weighted layers.

use super::attrs::{attr, bias_or_zero, check_attrs, int_or, ints_or};
use super::{Graph, Node};
use crate::network::{Conv, ConvTranspose, Layer, ValueId, ValueInfo};

/// A 'same' convolution with an odd square kernel.
pub(super) fn conv(n: &Node, g: &mut Graph) -> Result<ValueId, String> {
    let what = &n.what;
    let input = n.act(0)?;
    let (wd, weight) = n.init(1)?.ok_or_else(|| format!("{what}: no weight"))?;
    let info = g.values[input];
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
        ("group", vec![int_or(n.node, "group", 1)], vec![1]),
        ("strides", ints_or(n.node, "strides", &[1, 1]), vec![1, 1]),
        (
            "dilations",
            ints_or(n.node, "dilations", &[1, 1]),
            vec![1, 1],
        ),
        ("pads", ints_or(n.node, "pads", &[0, 0, 0, 0]), vec![p; 4]),
    ];
    check_attrs(what, "only 'same' convolutions are supported", checks)?;
    if attr(n.node, "auto_pad").is_some_and(|a| !a.s.is_empty() && a.s != b"NOTSET") {
        return Err(format!(
            "{what}: auto_pad is not supported, use explicit pads"
        ));
    }
    let bias = bias_or_zero(what, n.init(2)?, cout)?;
    let output = g.push_value(ValueInfo {
        channels: cout,
        level: info.level,
    });
    g.layers.push(Layer::Conv(Conv {
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
    Ok(output)
}

/// A 2×2 stride-2 transposed convolution (one pooling level up).
pub(super) fn conv_transpose(n: &Node, g: &mut Graph) -> Result<ValueId, String> {
    let what = &n.what;
    let input = n.act(0)?;
    let (wd, weight) = n.init(1)?.ok_or_else(|| format!("{what}: no weight"))?;
    let info = g.values[input];
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
        ("group", vec![int_or(n.node, "group", 1)], vec![1]),
        ("strides", ints_or(n.node, "strides", &[1, 1]), vec![2, 2]),
        (
            "dilations",
            ints_or(n.node, "dilations", &[1, 1]),
            vec![1, 1],
        ),
        ("pads", ints_or(n.node, "pads", &[0, 0, 0, 0]), vec![0; 4]),
        (
            "output_padding",
            ints_or(n.node, "output_padding", &[0, 0]),
            vec![0, 0],
        ),
    ];
    check_attrs(what, "only 2×2 stride-2 upsampling is supported", checks)?;
    if attr(n.node, "output_shape").is_some() {
        return Err(format!("{what}: output_shape is not supported"));
    }
    let cout = wd[1];
    let bias = bias_or_zero(what, n.init(2)?, cout)?;
    let output = g.push_value(ValueInfo {
        channels: cout,
        level: info.level - 1,
    });
    g.layers.push(Layer::ConvTranspose(ConvTranspose {
        input,
        output,
        cin: wd[0],
        cout,
        weight,
        bias,
        relu: false,
    }));
    Ok(output)
}
