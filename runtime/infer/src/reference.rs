//! Plain CPU implementations of the lowered layers: the "CPU twin" of each
//! WGSL kernel, written for clarity, used by the tests to check the GPU
//! kernels one by one and the lowering as a whole. Tensors are CHW f32.

use rayon::prelude::*;

use super::network::{Conv, ConvTranspose, Layer, Network};

/// Flags the GPU fuses into a conv's epilogue, in order: bias, ReLU,
/// residual add, clamp to [0, 1].
#[derive(Debug, Clone, Copy, Default)]
pub struct Epilogue<'a> {
    pub relu: bool,
    pub residual: Option<&'a [f32]>,
    pub clamp: bool,
}

impl Epilogue<'_> {
    #[inline]
    pub fn apply(&self, mut v: f32, index: usize) -> f32 {
        if self.relu {
            v = v.max(0.0);
        }
        if let Some(r) = self.residual {
            v += r[index];
        }
        if self.clamp {
            v = v.clamp(0.0, 1.0);
        }
        v
    }
}

/// "Same" k×k convolution of a `cin`×h×w tensor.
pub fn conv_same(input: &[f32], h: usize, w: usize, conv: &Conv, epi: Epilogue<'_>) -> Vec<f32> {
    let (cin, k) = (conv.cin, conv.kernel);
    let r = (k / 2) as isize;
    let plane = h * w;
    let mut out = vec![0f32; conv.cout * plane];
    out.par_chunks_mut(plane).enumerate().for_each(|(o, dst)| {
        dst.fill(conv.bias[o]);
        for c in 0..cin {
            let src = &input[c * plane..(c + 1) * plane];
            for ky in 0..k {
                for kx in 0..k {
                    let wgt = conv.weight[((o * cin + c) * k + ky) * k + kx];
                    let (dy, dx) = (ky as isize - r, kx as isize - r);
                    for y in 0..h {
                        let sy = y as isize + dy;
                        if sy < 0 || sy >= h as isize {
                            continue;
                        }
                        let row = &src[sy as usize * w..(sy as usize + 1) * w];
                        let x0 = (-dx).max(0) as usize;
                        let x1 = (w as isize - dx).min(w as isize).max(0) as usize;
                        for x in x0..x1 {
                            dst[y * w + x] += wgt * row[(x as isize + dx) as usize];
                        }
                    }
                }
            }
        }
        for (i, v) in dst.iter_mut().enumerate() {
            *v = epi.apply(*v, o * plane + i);
        }
    });
    out
}

/// 2×2 max pool, stride 2, of a c×h×w tensor (h, w even).
pub fn max_pool2(input: &[f32], c: usize, h: usize, w: usize) -> Vec<f32> {
    let (oh, ow) = (h / 2, w / 2);
    let mut out = vec![0f32; c * oh * ow];
    for ch in 0..c {
        for y in 0..oh {
            for x in 0..ow {
                let at = |dy: usize, dx: usize| input[(ch * h + 2 * y + dy) * w + 2 * x + dx];
                out[(ch * oh + y) * ow + x] = at(0, 0).max(at(0, 1)).max(at(1, 0)).max(at(1, 1));
            }
        }
    }
    out
}

/// 2×2 stride-2 transposed convolution of a `cin`×h×w tensor → `cout`×2h×2w.
pub fn conv_transpose2(input: &[f32], h: usize, w: usize, ct: &ConvTranspose) -> Vec<f32> {
    let (oh, ow) = (2 * h, 2 * w);
    let mut out = vec![0f32; ct.cout * oh * ow];
    out.par_chunks_mut(oh * ow)
        .enumerate()
        .for_each(|(o, dst)| {
            for y in 0..oh {
                for x in 0..ow {
                    let tap = (y % 2) * 2 + x % 2;
                    let mut acc = ct.bias[o];
                    for c in 0..ct.cin {
                        acc += input[(c * h + y / 2) * w + x / 2]
                            * ct.weight[(c * ct.cout + o) * 4 + tap];
                    }
                    dst[y * ow + x] = if ct.relu { acc.max(0.0) } else { acc };
                }
            }
        });
    out
}

/// Runs the lowered network on a 3×h×w frame (sides multiples of
/// `net.multiple`); a display image is clamped to [0, 1] like the GPU's.
pub fn run(net: &Network, frame: &[f32], h: usize, w: usize) -> Vec<f32> {
    let mut vals: Vec<Option<Vec<f32>>> = vec![None; net.values.len()];
    vals[0] = Some(frame.to_vec());
    let dims = |v: usize| (h >> net.values[v].level, w >> net.values[v].level);
    for layer in &net.layers {
        let out = match layer {
            Layer::Conv(c) => {
                let (lh, lw) = dims(c.input);
                let epi = Epilogue {
                    relu: c.relu,
                    residual: c.residual.and_then(|r| vals[r].as_deref()),
                    clamp: c.output == net.output && net.clamped,
                };
                conv_same(vals[c.input].as_deref().unwrap_or_default(), lh, lw, c, epi)
            }
            Layer::MaxPool { input, .. } => {
                let (lh, lw) = dims(*input);
                max_pool2(
                    vals[*input].as_deref().unwrap_or_default(),
                    net.values[*input].channels,
                    lh,
                    lw,
                )
            }
            Layer::ConvTranspose(c) => {
                let (lh, lw) = dims(c.input);
                conv_transpose2(vals[c.input].as_deref().unwrap_or_default(), lh, lw, c)
            }
            Layer::Concat { inputs, .. } => inputs
                .iter()
                .flat_map(|&i| vals[i].as_deref().unwrap_or_default().iter().copied())
                .collect(),
        };
        vals[layer.output()] = Some(out);
    }
    vals[net.output].take().unwrap_or_default()
}
