//! What one measurement takes: the deterministic input, one run of each
//! contender, their times and statistics, their agreement, and the
//! network's multiply-adds.

use std::time::Instant;

use anyhow::{Result, ensure};
use burn::tensor::{Device, Tensor, TensorData};
use nedrt_infer::Backend as _;
use nedrt_infer::gpu::GpuBackend;

use super::BurnNet;

/// Deterministic values in [0, 1) (xorshift64*), a frame's worth.
pub(super) fn random_input(len: usize, seed: u64) -> Vec<f32> {
    let mut s = seed.max(1);
    (0..len)
        .map(|_| {
            s ^= s >> 12;
            s ^= s << 25;
            s ^= s >> 27;
            let r = s.wrapping_mul(0x2545_f491_4f6c_dd1d);
            (r >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect()
}

/// Median, p90 (nearest rank) and min of `v`, in the unit given; None
/// for no values.
pub(super) fn stats(v: &[f64]) -> Option<(f64, f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let rank = |q: f64| s[((q * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1];
    let median = if s.len() % 2 == 1 {
        s[s.len() / 2]
    } else {
        (s[s.len() / 2 - 1] + s[s.len() / 2]) / 2.0
    };
    Some((median, rank(0.9), s[0]))
}

/// One contender's run times on one model and size, ms.
#[derive(Default)]
pub(super) struct Timings {
    pub(super) ms: Vec<f64>,
    /// nedrt's device (timestamp-query) times.
    pub(super) dev: Vec<f64>,
}

impl Timings {
    pub(super) fn push(&mut self, ms: f64, dev: Option<f64>) {
        self.ms.push(ms);
        self.dev.extend(dev);
    }
    pub(super) fn reset(&mut self) {
        self.ms.clear();
        self.dev.clear();
    }
}

/// Multiply-adds of one `size`×`size` frame through `network` (its convolutions).
pub(super) fn macs(network: &nedrt_infer::Network, size: usize) -> u64 {
    use nedrt_infer::network::Layer;
    let plane = |v: usize| {
        let side = (size >> network.values[v].level) as u64;
        side * side
    };
    network
        .layers
        .iter()
        .map(|l| match l {
            Layer::Conv(c) => (c.cin * c.cout * c.kernel * c.kernel) as u64 * plane(c.output),
            // Each input pixel feeds a 2×2 block of every output channel.
            Layer::ConvTranspose(c) => (c.cin * c.cout * 4) as u64 * plane(c.input),
            Layer::MaxPool { .. } | Layer::Concat { .. } => 0,
        })
        .sum()
}

/// One nedrt run: host tensor in, network, host tensor out.
pub(super) fn run_nedrt(
    be: &mut GpuBackend,
    input: &[f32],
    size: usize,
) -> Result<(f64, Option<f64>, Vec<f32>)> {
    let t = Instant::now();
    let out = be.run_tensor(input, size, size)?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    Ok((ms, be.last_gpu_ns().map(|ns| ns as f64 / 1e6), out))
}

/// One burn run: `Tensor::from_data` → forward → `into_data` (which waits for
/// the device). The host `TensorData` is made before the clock starts, as
/// nedrt's input slice exists before its run.
pub(super) fn run_burn(
    net: &BurnNet,
    device: &Device,
    input: &[f32],
    size: usize,
) -> Result<(f64, Vec<f32>)> {
    let data = TensorData::new(input.to_vec(), [1, 3, size, size]);
    let t = Instant::now();
    let x = Tensor::<4>::from_data(data, device);
    let y = net.forward(x);
    let dims = y.dims();
    let data = y.into_data();
    let dtype = data.dtype();
    let out = data
        .try_into_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("burn's output is {dtype:?}, not f32: {e:?}"))?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    ensure!(
        dims == [1, 3, size, size],
        "burn's output is {dims:?}, not [1, 3, {size}, {size}]"
    );
    Ok((ms, out))
}

/// How far apart the two outputs are. nedrt's last kernel clamps to [0, 1]
/// (the panel's range), the ONNX graph does not, so burn's output is clamped
/// on the host before the comparison (clamping never widens a difference).
pub(super) struct Agreement {
    pub(super) max_abs: f64,
    pub(super) max_abs_out: f64,
    /// Share of burn's outputs outside [0, 1], where the clamp hides the value.
    pub(super) clamped: f64,
    /// Largest |burn − input|: the size of the U-Net branch of `I + UNet(I)`,
    /// the scale against which the difference is relative.
    pub(super) max_abs_branch: f64,
    pub(super) non_finite: usize,
}

pub(super) fn agreement(input: &[f32], nedrt: &[f32], burn: &[f32]) -> Result<Agreement> {
    ensure!(
        nedrt.len() == burn.len(),
        "nedrt gave {} values, burn {}",
        nedrt.len(),
        burn.len()
    );
    let mut a = Agreement {
        max_abs: 0.0,
        max_abs_out: 0.0,
        clamped: 0.0,
        max_abs_branch: 0.0,
        non_finite: 0,
    };
    let mut clamped = 0usize;
    for ((&n, &b), &x) in nedrt.iter().zip(burn).zip(input) {
        if !n.is_finite() || !b.is_finite() {
            a.non_finite += 1;
            continue;
        }
        clamped += usize::from(!(0.0..=1.0).contains(&b));
        a.max_abs = a.max_abs.max(f64::from((n - b.clamp(0.0, 1.0)).abs()));
        a.max_abs_out = a.max_abs_out.max(f64::from(b.abs()));
        a.max_abs_branch = a.max_abs_branch.max(f64::from((b - x).abs()));
    }
    a.clamped = clamped as f64 / burn.len().max(1) as f64;
    Ok(a)
}
