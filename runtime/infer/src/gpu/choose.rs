//! Each layer's kernel, chosen once when the network is prepared: the
//! register-tiled kernels, or cooperative matrices (the tensor cores) for
//! the convolutions where the adapter and the layer allow them; with the
//! reason, for `nedrt bench inference` and `nedrt run` to print.

use super::codegen::{self, Dtype, KernelKind, coop};
use super::{err, pack};
use crate::network::{Layer, Network, ValueId};
use crate::{ConvPath, InferenceError};

/// What the convolutions may use on a device.
#[derive(Debug, Clone)]
pub struct ConvSupport {
    pub path: ConvPath,
    /// The adapter's cooperative-matrix support, or why there is none.
    pub coop: Result<coop::CoopAdapter, coop::NoCoop>,
    /// Whether the tiled kernels sum in f16 at `--precision f16`
    /// ([`f16_arithmetic_by_default`] unless `--f16-math` says).
    pub f16_arithmetic: bool,
}

impl ConvSupport {
    /// What `device` offers, under `path`.
    pub fn of_device(device: &wgpu::Device, path: ConvPath) -> Self {
        let info = device.adapter_info();
        Self {
            path,
            coop: coop::device_support(
                device.features(),
                (info.subgroup_min_size, info.subgroup_max_size),
            ),
            f16_arithmetic: f16_arithmetic_by_default(info.device_type, info.vendor),
        }
    }

    /// What `device` offers under `options`' conv path and f16 math.
    pub fn of_options(device: &wgpu::Device, options: &crate::BackendOptions) -> Self {
        Self::of_device(device, options.conv_path).with_f16_math(options.f16_math)
    }

    /// `math` over the device's default (`F16Math::Auto` keeps it).
    pub fn with_f16_math(self, math: crate::F16Math) -> Self {
        let f16_arithmetic = match math {
            crate::F16Math::Auto => self.f16_arithmetic,
            crate::F16Math::F16 => true,
            crate::F16Math::F32 => false,
        };
        Self {
            f16_arithmetic,
            ..self
        }
    }

    /// The cooperative path for a layer of `cin` → `cout` channels, or why not.
    fn coop_for(
        &self,
        cin: usize,
        cout: usize,
        weights: Dtype,
        transposed: bool,
    ) -> Result<u32, coop::NoCoop> {
        if self.path == ConvPath::Tiled {
            return Err(self
                .coop
                .as_ref()
                .err()
                .cloned()
                .unwrap_or(coop::NoCoop::TiledAsked));
        }
        let adapter = self.coop.as_ref().map_err(Clone::clone)?;
        coop::layer_fits(cin, cout, weights, transposed)?;
        Ok(adapter.subgroup_size)
    }
}

/// PCI vendor id of NVIDIA.
const NVIDIA: u32 = 0x10de;

/// `--f16-math auto`: whether the tiled kernels sum in f16 on an adapter.
/// Not on a CPU adapter (lavapipe), where LLVM converts every f16
/// operation to f32 and back; not on NVIDIA's, where the H200 ran both
/// networks faster summing in f32 on f16 storage (half width 5.13 against
/// 5.56 ms, full 12.53 against 12.71, 2026-11-27 evening,
/// docs/benchmarks.md); on other GPUs (the mobile ones of headsets among
/// them), whose f16 runs at twice the f32 rate, yes.
pub fn f16_arithmetic_by_default(device_type: wgpu::DeviceType, vendor: u32) -> bool {
    device_type != wgpu::DeviceType::Cpu && vendor != NVIDIA
}

/// One layer's kernel: what it runs, reads, and its packed weights.
#[derive(Debug)]
pub(super) struct LayerKernel {
    pub(super) kind: KernelKind,
    pub(super) input: ValueId,
    pub(super) residual: Option<ValueId>,
    /// Weights in the order the kernel reads them, then the bias.
    pub(super) weights: Vec<f32>,
    pub(super) bias: Vec<f32>,
    /// "tiled" or "cooperative matrix", and why, for convolutions.
    pub(super) path: Option<String>,
}

/// `layer`'s kernel in `weights` storage, or None for a concat (it costs
/// nothing: its inputs are written in place).
pub(super) fn layer_kernel(
    layer: &Layer,
    network: &Network,
    weights: Dtype,
    support: &ConvSupport,
) -> Result<Option<LayerKernel>, InferenceError> {
    // How a tiled kernel sums at f16 storage, said with its placement.
    let arith = match (weights, support.f16_arithmetic) {
        (Dtype::F32, _) => "",
        (Dtype::F16, true) => ", f16 arithmetic",
        (Dtype::F16, false) => ", f32 arithmetic on f16 storage",
    };
    Ok(Some(match layer {
        Layer::Conv(c) => {
            if c.kernel > codegen::MAX_CONV_KERNEL {
                return Err(err(format!(
                    "{}×{} convolutions are not supported (at most {}×{})",
                    c.kernel,
                    c.kernel,
                    codegen::MAX_CONV_KERNEL,
                    codegen::MAX_CONV_KERNEL
                )));
            }
            let (relu, residual, clamp) = (
                c.relu,
                c.residual.is_some(),
                c.output == network.output && network.clamped,
            );
            let what = format!("conv {0}×{0} {1}→{2}", c.kernel, c.cin, c.cout);
            let (kind, packed, path) = match support.coop_for(c.cin, c.cout, weights, false) {
                Ok(subgroup_size) => (
                    KernelKind::CoopConv {
                        kernel: c.kernel,
                        relu,
                        residual,
                        clamp,
                        transposed: false,
                        subgroup_size,
                        tile: codegen::coop::CoopTile::DEFAULT,
                    },
                    pack::coop_conv(&c.weight, c.cin, c.cout, c.kernel),
                    format!("{what}: cooperative matrix 16×16×16 f16→f32"),
                ),
                Err(why) => (
                    KernelKind::Conv {
                        kernel: c.kernel,
                        relu,
                        residual,
                        clamp,
                        tile: codegen::ConvTile::LARGE,
                    },
                    pack::conv(&c.weight, c.cin, c.cout, c.kernel),
                    format!("{what}: tiled ({why}){arith}"),
                ),
            };
            LayerKernel {
                kind,
                input: c.input,
                residual: c.residual,
                weights: packed,
                bias: c.bias.clone(),
                path: Some(path),
            }
        }
        Layer::ConvTranspose(c) => {
            let what = format!("transposed conv 2×2 {}→{}", c.cin, c.cout);
            let (kind, packed, path) = match support.coop_for(c.cin, c.cout, weights, true) {
                Ok(subgroup_size) => (
                    KernelKind::CoopConv {
                        kernel: 1,
                        relu: c.relu,
                        residual: false,
                        clamp: false,
                        transposed: true,
                        subgroup_size,
                        tile: codegen::coop::CoopTile::DEFAULT,
                    },
                    pack::coop_conv_transpose(&c.weight, c.cin, c.cout),
                    format!("{what}: cooperative matrix 16×16×16 f16→f32"),
                ),
                Err(why) => (
                    KernelKind::ConvTranspose { relu: c.relu },
                    pack::conv_transpose(&c.weight, c.cin, c.cout),
                    format!("{what}: tiled ({why}){arith}"),
                ),
            };
            LayerKernel {
                kind,
                input: c.input,
                residual: None,
                weights: packed,
                bias: c.bias.clone(),
                path: Some(path),
            }
        }
        Layer::MaxPool { input, .. } => LayerKernel {
            kind: KernelKind::MaxPool,
            input: *input,
            residual: None,
            weights: Vec::new(),
            bias: Vec::new(),
            path: None,
        },
        Layer::Concat { .. } => return Ok(None),
    }))
}

/// The network with its cooperative-matrix layers against the same network
/// all tiled, on the default adapter, for one frame: the largest absolute
/// difference of their outputs, or None where no layer takes the
/// cooperative path (then there is nothing to compare). The device check's
/// proof that the tensor-core kernels compute what the tiled ones do, on
/// the one kind of machine that runs them.
pub fn cooperative_against_tiled(
    network: &Network,
    options: &crate::BackendOptions,
    frame: &nedrt_core::Image,
) -> Result<Option<f32>, InferenceError> {
    let auto = crate::BackendOptions {
        conv_path: ConvPath::Auto,
        ..options.clone()
    };
    let mut coop = super::GpuBackend::new_default(network, &auto)?;
    if !coop
        .conv_paths()
        .iter()
        .any(|l| l.contains(": cooperative matrix"))
    {
        return Ok(None);
    }
    let tiled = crate::BackendOptions {
        conv_path: ConvPath::Tiled,
        ..options.clone()
    };
    let mut reference = super::GpuBackend::new_default(network, &tiled)?;
    let (w, h) = (frame.width, frame.height);
    let a = coop.run_tensor(frame.data(), w, h)?;
    let b = reference.run_tensor(frame.data(), w, h)?;
    Ok(Some(
        a.iter()
            .zip(&b)
            // A NaN on either side is the largest difference, not none.
            .map(|(x, y)| (x - y).abs())
            .fold(
                0.0,
                |m, d| if d.is_nan() { f32::INFINITY } else { m.max(d) },
            ),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f16_sums_by_default_only_on_gpus_other_than_nvidias() {
        use wgpu::DeviceType::{Cpu, DiscreteGpu, IntegratedGpu};
        assert!(!f16_arithmetic_by_default(Cpu, 0x10005));
        assert!(!f16_arithmetic_by_default(DiscreteGpu, NVIDIA));
        assert!(!f16_arithmetic_by_default(IntegratedGpu, NVIDIA));
        // AMD, Intel, Qualcomm (a headset's Adreno), ARM (Mali).
        for vendor in [0x1002, 0x8086, 0x5143, 0x13b5] {
            assert!(
                f16_arithmetic_by_default(IntegratedGpu, vendor),
                "{vendor:#x}"
            );
        }
    }

    #[test]
    fn the_f16_math_overrides_the_adapters_default_only_when_named() {
        for default in [false, true] {
            let support = ConvSupport {
                path: ConvPath::Auto,
                coop: Err(coop::NoCoop::NotOnDevice),
                f16_arithmetic: default,
            };
            let math = |m| support.clone().with_f16_math(m).f16_arithmetic;
            assert_eq!(math(crate::F16Math::Auto), default);
            assert!(math(crate::F16Math::F16));
            assert!(!math(crate::F16Math::F32));
        }
    }
}
