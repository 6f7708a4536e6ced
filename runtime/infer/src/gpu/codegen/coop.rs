//! The cooperative-matrix path (`shaders/conv_coop.wgsl`): which layers
//! take it on which adapter, and the template's unrolled parts.

use super::Dtype;

/// Pixel rows of 16 a subgroup accumulates (one 16×16 f32 matrix each).
pub const ROWS: u32 = 4;
/// Subgroups in a workgroup, each its own block of 16 output columns,
/// sharing the staged input tile.
pub const SUBGROUPS: u32 = 4;
/// The one matrix shape the template uses: M = N = K = 16.
pub const SIZE: u32 = 16;

/// Where the adapter can run the template: its subgroup size.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CoopAdapter {
    pub subgroup_size: u32,
}

/// Why a convolution does not run on cooperative matrices.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NoCoop {
    #[error(
        "the device has no cooperative matrices (its adapter lists no 16×16×16 f16→f32 shape, \
         or it was opened without f16)"
    )]
    NotOnDevice,
    #[error("the device was opened without {0}")]
    MissingFeatures(String),
    #[error("the adapter's subgroups are {min}–{max} invocations; the kernel needs one size")]
    SubgroupSizes { min: u32, max: u32 },
    #[error("tiled kernels asked for")]
    TiledAsked,
    #[error("needs f16 storage")]
    NeedsF16,
    #[error("{0} input channels, under one 16-channel matrix")]
    FewInputs(usize),
    #[error(
        "{cout} output channels, under {min}: the tiled kernel is faster there \
         (the H200, docs/benchmarks.md)"
    )]
    FewOutputs { cout: usize, min: usize },
}

/// Output channels under which a 3×3 convolution stays on the tiled
/// kernels: on the H200 (2026-11-27) the 16-channel layers at full
/// resolution took 1.17–1.22× the tiled f16 kernel's time on cooperative
/// matrices (each tile's staging feeds one 16-wide matrix column), the
/// 32-channel ones 0.60–0.65×.
pub const MIN_OUTPUTS: usize = 32;
/// The same for the 2×2 transposed convolutions: 32→16 took 1.35× the
/// tiled kernel's time there, 64→32 0.96–1.12×, 128→64 0.76–0.95×, 256→128 0.66×.
pub const MIN_OUTPUTS_TRANSPOSED: usize = 64;

/// The cooperative-matrix path on a device, or why not: its features
/// (`nedrt_gpu::open_device` enables cooperative matrices only where the
/// adapter lists the 16×16×16 f16→f32 shape) and its subgroup sizes.
pub fn device_support(
    features: wgpu::Features,
    subgroup_sizes: (u32, u32),
) -> Result<CoopAdapter, NoCoop> {
    if !features.contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX) {
        return Err(NoCoop::NotOnDevice);
    }
    let needed = wgpu::Features::SUBGROUP | wgpu::Features::SHADER_F16;
    if !features.contains(needed) {
        return Err(NoCoop::MissingFeatures(format!(
            "{:?}",
            needed - (features & needed)
        )));
    }
    let (min, max) = subgroup_sizes;
    if min != max || min == 0 || min > 128 || !min.is_power_of_two() {
        return Err(NoCoop::SubgroupSizes { min, max });
    }
    Ok(CoopAdapter { subgroup_size: min })
}

/// Whether a layer of `cin` → `cout` channels in `weights` storage can take
/// the cooperative-matrix path on a capable device, or why not.
pub fn layer_fits(cin: usize, cout: usize, weights: Dtype, transposed: bool) -> Result<(), NoCoop> {
    if weights != Dtype::F16 {
        return Err(NoCoop::NeedsF16);
    }
    if cin < SIZE as usize {
        return Err(NoCoop::FewInputs(cin));
    }
    let min = if transposed {
        MIN_OUTPUTS_TRANSPOSED
    } else {
        MIN_OUTPUTS
    };
    if cout < min {
        return Err(NoCoop::FewOutputs { cout, min });
    }
    Ok(())
}

/// The accumulators: `c{r}`, one 16×16 f32 matrix per pixel row.
pub(super) fn accumulators() -> String {
    (0..ROWS)
        .map(|r| format!("    var c{r} = coop_mat16x16<f32, C>();\n"))
        .collect()
}

/// One tap's products: per pixel row, its 16 pixels × 16 channels from
/// the staged tile times the tap's weights.
pub(super) fn taps() -> String {
    (0..ROWS)
        .map(|r| {
            format!(
                "            let a{r} = coopLoadT<coop_mat16x16<f16, A>>(&a_tile[(({r}u + ky) * IN_W + kx) * 16u], 16u);\n            c{r} = coopMultiplyAdd(a{r}, b, c{r});\n"
            )
        })
        .collect()
}

/// Each accumulator out through workgroup memory and the epilogue.
pub(super) fn stores() -> String {
    (0..ROWS)
        .map(|r| {
            format!(
                "    coopStoreT(c{r}, &c_tile[sg * 256u], 16u);\n    workgroupBarrier();\n    drain(sg, lane, blk, x0, y0 + {r}u);\n    workgroupBarrier();\n"
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_path_is_taken_only_where_device_and_layer_allow_it() {
        use wgpu::Features as F;
        let all = F::EXPERIMENTAL_COOPERATIVE_MATRIX | F::SUBGROUP | F::SHADER_F16;
        assert_eq!(
            device_support(all, (32, 32)),
            Ok(CoopAdapter { subgroup_size: 32 })
        );
        // lavapipe: no cooperative matrices listed, so none enabled.
        let e = device_support(F::SHADER_F16 | F::SUBGROUP, (8, 8)).expect_err("none");
        assert!(e.to_string().contains("no cooperative matrices"), "{e}");
        let e = device_support(F::EXPERIMENTAL_COOPERATIVE_MATRIX | F::SHADER_F16, (32, 32))
            .expect_err("no subgroups");
        assert!(e.to_string().contains("SUBGROUP"), "{e}");
        // A subgroup size that varies (AMD's 32–64) leaves the kernel unsure
        // how many subgroups a workgroup holds.
        let e = device_support(all, (32, 64)).expect_err("varies");
        assert!(e.to_string().contains("32–64"), "{e}");

        assert_eq!(layer_fits(16, 32, Dtype::F16, false), Ok(()));
        assert_eq!(layer_fits(32, 32, Dtype::F32, false), Err(NoCoop::NeedsF16));
        assert_eq!(
            layer_fits(3, 32, Dtype::F16, false),
            Err(NoCoop::FewInputs(3))
        );
        // The narrow layers, where the H200 ran the tiled kernels faster.
        assert_eq!(
            layer_fits(32, 16, Dtype::F16, false),
            Err(NoCoop::FewOutputs { cout: 16, min: 32 })
        );
        assert_eq!(layer_fits(128, 64, Dtype::F16, true), Ok(()));
        assert_eq!(
            layer_fits(64, 32, Dtype::F16, true),
            Err(NoCoop::FewOutputs { cout: 32, min: 64 })
        );
    }
}
