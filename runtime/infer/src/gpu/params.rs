//! The parameter block every kernel reads (a read-only storage buffer), mirrored byte for byte by the
//! `Params` struct in each `shaders/*.wgsl` (checked by the test below).

use bytemuck::{Pod, Zeroable};

/// Sizes in elements; offsets in elements of the bound buffer's type, so
/// one buffer can hold several tensors (concatenation by layout).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct Params {
    /// Width and height of the layer's input.
    pub width: u32,
    pub height: u32,
    pub cin: u32,
    pub cout: u32,
    pub in_offset: u32,
    pub out_offset: u32,
    pub res_offset: u32,
    pub w_offset: u32,
    pub b_offset: u32,
    /// The fused level's first convolution (`shaders/conv_fused.wgsl`; 0
    /// for every other kernel): its output channels, and its weights' and
    /// bias's offsets (`w_offset`, `b_offset` are the second's).
    pub mid: u32,
    pub first_w_offset: u32,
    pub first_b_offset: u32,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::codegen::{Dtype, KernelKey, KernelKind};

    #[test]
    fn wgsl_params_match_the_rust_struct() {
        let rust: Vec<(&str, usize)> = vec![
            ("width", std::mem::offset_of!(Params, width)),
            ("height", std::mem::offset_of!(Params, height)),
            ("cin", std::mem::offset_of!(Params, cin)),
            ("cout", std::mem::offset_of!(Params, cout)),
            ("in_offset", std::mem::offset_of!(Params, in_offset)),
            ("out_offset", std::mem::offset_of!(Params, out_offset)),
            ("res_offset", std::mem::offset_of!(Params, res_offset)),
            ("w_offset", std::mem::offset_of!(Params, w_offset)),
            ("b_offset", std::mem::offset_of!(Params, b_offset)),
            ("mid", std::mem::offset_of!(Params, mid)),
            (
                "first_w_offset",
                std::mem::offset_of!(Params, first_w_offset),
            ),
            (
                "first_b_offset",
                std::mem::offset_of!(Params, first_b_offset),
            ),
        ];
        for kind in [
            KernelKind::Conv {
                kernel: 3,
                relu: true,
                residual: true,
                clamp: true,
                tile: crate::gpu::codegen::ConvTile::LARGE,
            },
            KernelKind::ConvTranspose { relu: true },
            KernelKind::MaxPool,
        ] {
            let key = KernelKey {
                kind,
                src: Dtype::F32,
                dst: Dtype::F32,
                residual: Dtype::F32,
                weights: Dtype::F32,
                arith: Dtype::F32,
            };
            let module = naga::front::wgsl::parse_str(&key.wgsl()).expect("parses");
            let (_, ty) = module
                .types
                .iter()
                .find(|(_, t)| t.name.as_deref() == Some("Params"))
                .expect("Params in WGSL");
            let naga::TypeInner::Struct { members, span } = &ty.inner else {
                panic!("Params is not a struct");
            };
            assert_eq!(*span as usize, std::mem::size_of::<Params>(), "{kind:?}");
            for (name, offset) in &rust {
                let m = members
                    .iter()
                    .find(|m| m.name.as_deref() == Some(name))
                    .unwrap_or_else(|| panic!("{kind:?}: no member {name}"));
                assert_eq!(m.offset as usize, *offset, "{kind:?}: {name}");
            }
        }
    }
}
