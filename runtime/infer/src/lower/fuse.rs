//! `Relu` and the residual `Add`: never layers of their own, they are
//! fused into the conv before them (when nothing else reads its output),
//! so the GPU and CPU kernels apply them in the conv's epilogue.

use super::{Graph, Node};
use crate::network::{Conv, ConvTranspose, Layer, ValueId};

/// The layer that computes `value`, if any.
fn producer_mut(layers: &mut [Layer], value: ValueId) -> Option<&mut Layer> {
    layers.iter_mut().find(|l| l.output() == value)
}

/// ReLU fused into the Conv or ConvTranspose before it.
pub(super) fn relu(n: &Node, g: &mut Graph) -> Result<ValueId, String> {
    let what = &n.what;
    let input = n.act(0)?;
    let fusable = n.single_use(0)?;
    match producer_mut(&mut g.layers, input) {
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
    Ok(input)
}

/// A residual Add fused into the single-use Conv computed after its other operand.
pub(super) fn add(n: &Node, g: &mut Graph) -> Result<ValueId, String> {
    let what = &n.what;
    let (a, b) = (n.act(0)?, n.act(1)?);
    if g.values[a] != g.values[b] {
        return Err(format!("{what}: operands of different shapes"));
    }
    // Fuse into whichever operand is a single-use conv computed after the other.
    let mut fused = None;
    for (conv_side, other, i) in [(b, a, 1), (a, b, 0)] {
        if conv_side > other
            && n.single_use(i)?
            && let Some(Layer::Conv(c)) = producer_mut(&mut g.layers, conv_side)
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
    })
}
