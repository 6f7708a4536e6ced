//! WGSL generation: the kernel templates in `shaders/` filled in for one
//! layer's variant (kernel size, fused epilogue, element types). Each
//! distinct variant becomes one pipeline, built once when the network is
//! prepared.

/// Element type of a storage buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Dtype {
    F32,
    F16,
}

impl Dtype {
    pub fn wgsl(self) -> &'static str {
        match self {
            Dtype::F32 => "f32",
            Dtype::F16 => "f16",
        }
    }
    pub fn bytes(self) -> usize {
        match self {
            Dtype::F32 => 4,
            Dtype::F16 => 2,
        }
    }
}

/// Which kernel, with its compile-time options.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum KernelKind {
    Conv {
        kernel: usize,
        relu: bool,
        residual: bool,
        clamp: bool,
    },
    ConvTranspose {
        relu: bool,
    },
    MaxPool,
}

/// One pipeline variant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct KernelKey {
    pub kind: KernelKind,
    pub src: Dtype,
    pub dst: Dtype,
    pub residual: Dtype,
    pub weights: Dtype,
}

/// Largest conv kernel the tiled template's workgroup memory fits.
pub const MAX_CONV_KERNEL: usize = 5;

const CONV: &str = include_str!("../../../../shaders/conv.wgsl");
const CONV_TRANSPOSE: &str = include_str!("../../../../shaders/conv_transpose.wgsl");
const MAX_POOL: &str = include_str!("../../../../shaders/max_pool.wgsl");
const LAYER_BINDINGS: &str = include_str!("../../../../shaders/layer_bindings.wgsl");

/// Conv output tile per workgroup (pixels) and output channels per workgroup,
/// as fixed in conv.wgsl.
pub const CONV_TILE: (u32, u32, u32) = (32, 16, 8);
/// ConvTranspose input pixels per workgroup side and output channels.
pub const CONV_TRANSPOSE_TILE: (u32, u32) = (16, 8);
/// Max-pool workgroup side.
pub const POOL_TILE: u32 = 16;

impl KernelKey {
    pub fn uses_f16(&self) -> bool {
        [self.src, self.dst, self.residual, self.weights].contains(&Dtype::F16)
    }

    /// The WGSL source of this variant.
    pub fn wgsl(&self) -> String {
        let (template, fields): (&str, Vec<(&str, String)>) = match self.kind {
            KernelKind::Conv {
                kernel,
                relu,
                residual,
                clamp,
            } => (
                CONV,
                vec![
                    ("K", kernel.to_string()),
                    ("ROW", (4 + kernel - 1).to_string()),
                    ("RELU", relu.to_string()),
                    ("RESIDUAL", residual.to_string()),
                    ("CLAMP", clamp.to_string()),
                ],
            ),
            KernelKind::ConvTranspose { relu } => {
                (CONV_TRANSPOSE, vec![("RELU", relu.to_string())])
            }
            KernelKind::MaxPool => (MAX_POOL, vec![]),
        };
        let enable = if self.uses_f16() { "enable f16;" } else { "" };
        let mut s = template
            .replace("{{LAYER_BINDINGS}}", LAYER_BINDINGS)
            .replace("{{ENABLE_F16}}", enable)
            .replace("{{SRC_T}}", self.src.wgsl())
            .replace("{{DST_T}}", self.dst.wgsl())
            .replace("{{RES_T}}", self.residual.wgsl())
            .replace("{{W_T}}", self.weights.wgsl());
        for (name, value) in fields {
            s = s.replace(&format!("{{{{{name}}}}}"), &value);
        }
        s
    }

    pub fn label(&self) -> String {
        format!("{:?} {}→{}", self.kind, self.src.wgsl(), self.dst.wgsl())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all_keys() -> Vec<KernelKey> {
        let mut keys = Vec::new();
        for t in [Dtype::F32, Dtype::F16] {
            let kinds = [
                KernelKind::Conv {
                    kernel: 1,
                    relu: false,
                    residual: true,
                    clamp: true,
                },
                KernelKind::Conv {
                    kernel: 3,
                    relu: true,
                    residual: false,
                    clamp: false,
                },
                KernelKind::Conv {
                    kernel: 5,
                    relu: true,
                    residual: true,
                    clamp: true,
                },
                KernelKind::ConvTranspose { relu: true },
                KernelKind::ConvTranspose { relu: false },
                KernelKind::MaxPool,
            ];
            for kind in kinds {
                keys.push(KernelKey {
                    kind,
                    src: t,
                    dst: t,
                    residual: Dtype::F32,
                    weights: t,
                });
            }
        }
        keys
    }

    #[test]
    fn every_placeholder_is_filled() {
        for key in all_keys() {
            let src = key.wgsl();
            assert!(!src.contains("{{"), "{}: unfilled placeholder", key.label());
            assert_eq!(src.contains("enable f16;"), key.uses_f16());
        }
    }

    #[test]
    fn every_variant_is_valid_wgsl() {
        // naga is what wgpu compiles WGSL with; validate without a device.
        for key in all_keys() {
            let src = key.wgsl();
            let module = naga::front::wgsl::parse_str(&src)
                .unwrap_or_else(|e| panic!("{}: {}", key.label(), e.emit_to_string(&src)));
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::SHADER_FLOAT16,
            )
            .validate(&module)
            .unwrap_or_else(|e| panic!("{}: {e:?}", key.label()));
        }
    }
}
