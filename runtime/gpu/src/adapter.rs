//! The adapter the wgpu steps take, as a bench's header names it: its name
//! and the cooperative-matrix shapes it lists (wgpu 30's
//! `Adapter::cooperative_matrix_properties`, the tensor cores' or matrix
//! units' operand shapes), so that a run on a lent GPU records what the
//! convolution kernels could use there (issue 38).

use crate::{GpuError, GpuSettings};

/// What the default adapter of some settings offers for matrix work.
#[derive(Debug, Clone)]
pub struct AdapterReport {
    /// "NVIDIA H200 (Vulkan, DiscreteGpu)": the form the backends print.
    pub name: String,
    /// Whether the adapter offers wgpu's `EXPERIMENTAL_COOPERATIVE_MATRIX`.
    pub cooperative_matrix_feature: bool,
    /// The shapes and types it lists, in its order (none on lavapipe).
    pub cooperative_matrices: Vec<wgpu::CooperativeMatrixProperties>,
}

impl AdapterReport {
    /// One line for a header: the name, the shapes and the feature.
    pub fn describe(&self) -> String {
        format!(
            "{}; cooperative matrices (M×N×K A·B→C): {} (wgpu's EXPERIMENTAL_COOPERATIVE_MATRIX: {})",
            self.name,
            describe_cooperative_matrices(&self.cooperative_matrices),
            if self.cooperative_matrix_feature {
                "offered"
            } else {
                "not offered"
            }
        )
    }
}

/// The adapter [`crate::open_device`] takes for `settings`
/// ([`crate::request_adapter`]), without opening a device on it.
pub fn default_adapter(settings: &GpuSettings) -> Result<AdapterReport, GpuError> {
    let adapter = crate::request_adapter(settings)?;
    let info = adapter.get_info();
    Ok(AdapterReport {
        name: format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type),
        cooperative_matrix_feature: adapter
            .features()
            .contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX),
        cooperative_matrices: adapter.cooperative_matrix_properties(),
    })
}

/// The scalar type's WGSL name.
pub fn scalar_name(t: wgpu::CooperativeScalarType) -> &'static str {
    match t {
        wgpu::CooperativeScalarType::F32 => "f32",
        wgpu::CooperativeScalarType::F16 => "f16",
        wgpu::CooperativeScalarType::I32 => "i32",
        wgpu::CooperativeScalarType::U32 => "u32",
    }
}

/// "16×16×16 f16·f16→f32, 8×8×8 f32·f32→f32 (saturating)", or "none
/// listed".
pub fn describe_cooperative_matrices(list: &[wgpu::CooperativeMatrixProperties]) -> String {
    if list.is_empty() {
        return "none listed".into();
    }
    list.iter()
        .map(|p| {
            let ab = scalar_name(p.ab_type);
            format!(
                "{}×{}×{} {ab}·{ab}→{}{}",
                p.m_size,
                p.n_size,
                p.k_size,
                scalar_name(p.cr_type),
                if p.saturating_accumulation {
                    " (saturating)"
                } else {
                    ""
                }
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape(
        m: u32,
        ab: wgpu::CooperativeScalarType,
        cr: wgpu::CooperativeScalarType,
        saturating: bool,
    ) -> wgpu::CooperativeMatrixProperties {
        wgpu::CooperativeMatrixProperties {
            m_size: m,
            n_size: m,
            k_size: m,
            ab_type: ab,
            cr_type: cr,
            saturating_accumulation: saturating,
        }
    }

    #[test]
    fn an_empty_list_says_none_listed() {
        assert_eq!(describe_cooperative_matrices(&[]), "none listed");
    }

    #[test]
    fn shapes_are_named_in_the_adapters_order() {
        use wgpu::CooperativeScalarType::{F16, F32, I32, U32};
        let list = [
            shape(16, F16, F32, false),
            shape(8, F32, F32, true),
            shape(16, U32, I32, false),
        ];
        assert_eq!(
            describe_cooperative_matrices(&list),
            "16×16×16 f16·f16→f32, 8×8×8 f32·f32→f32 (saturating), 16×16×16 u32·u32→i32"
        );
        let report = AdapterReport {
            name: "GPU (Vulkan, DiscreteGpu)".into(),
            cooperative_matrix_feature: true,
            cooperative_matrices: list[..1].to_vec(),
        };
        assert_eq!(
            report.describe(),
            "GPU (Vulkan, DiscreteGpu); cooperative matrices (M×N×K A·B→C): 16×16×16 f16·f16→f32 \
             (wgpu's EXPERIMENTAL_COOPERATIVE_MATRIX: offered)"
        );
    }
}
