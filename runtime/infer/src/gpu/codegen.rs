//! WGSL generation: the kernel templates in `shaders/` filled in for one
//! layer's variant (kernel size, conv tile, fused epilogue, element types,
//! and the unrolled multiply-adds). Each distinct variant becomes one
//! pipeline, built when a frame size first needs it and kept.

pub mod coop;
pub mod fused;
mod tiled;

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

/// How the conv kernel tiles one layer: a workgroup of `THREADS_X` ×
/// `threads_y` threads; each thread computes `px` adjacent pixels of a row
/// for `OC` output channels, so a workgroup covers (8·`px`) × `threads_y`
/// pixels. Chosen per layer from its size and kernel (`for_layer`), so the
/// small deep levels of the U-Net do not run tiles mostly outside the layer
/// and every tile's staging fits the workgroup memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ConvTile {
    pub px: u32,
    pub threads_y: u32,
}

/// Workgroup memory every adapter offers (WebGPU's default limit), bytes.
pub const WORKGROUP_BYTES: u32 = 16384;

impl ConvTile {
    /// Threads along x. lavapipe runs a workgroup's invocations in SIMD
    /// vectors along x only (8 lanes of its 256-bit vectors), so a narrower
    /// workgroup leaves lanes empty; GPUs are indifferent to the shape.
    pub const THREADS_X: u32 = 8;
    /// Output channels per thread (in vec4s: a multiple of 4).
    pub const OC: u32 = 16;
    /// The tile for layers at least 32 pixels wide and 16 tall.
    pub const LARGE: ConvTile = ConvTile {
        px: 4,
        threads_y: 16,
    };

    /// The tile for a `width`×`height` layer of `kernel`×`kernel` taps in
    /// `arith`: the most pixels per thread (4, 2 or 1: a tile 32, 16 or 8
    /// wide) whose tile row the layer fills, and as many rows as the
    /// smallest power of two at least `height`, at most 16, halved while
    /// one quad's staging does not fit `WORKGROUP_BYTES`.
    pub fn for_layer(width: u32, height: u32, kernel: usize, arith: Dtype) -> Self {
        let px = [4, 2, 1]
            .into_iter()
            .find(|&px| Self::THREADS_X * px <= width)
            .unwrap_or(1);
        let mut tile = ConvTile {
            px,
            threads_y: height.max(1).next_power_of_two().min(Self::LARGE.threads_y),
        };
        while tile.threads_y > 1 && tile.workgroup_bytes(kernel, 1, arith) > WORKGROUP_BYTES {
            tile.threads_y /= 2;
        }
        tile
    }

    /// Input-channel quads staged per step: the most of 4, 2, 1 whose input
    /// tile and weights fit `WORKGROUP_BYTES`.
    pub fn quads(&self, kernel: usize, arith: Dtype) -> u32 {
        [4, 2, 1]
            .into_iter()
            .find(|&cq| self.workgroup_bytes(kernel, cq, arith) <= WORKGROUP_BYTES)
            .unwrap_or(1)
    }

    /// Workgroup memory of the template for `cq` staged quads: a vec4 per
    /// input pixel and quad, a 4×4 matrix per tap, quad and four outputs.
    pub fn workgroup_bytes(&self, kernel: usize, cq: u32, arith: Dtype) -> u32 {
        let k = kernel as u32;
        let (w, h) = self.pixels();
        let input = cq * (h + k - 1) * (w + k - 1) * 4;
        let weights = cq * k * k * Self::OC * 4;
        (input + weights) * arith.bytes() as u32
    }

    /// Output pixels a workgroup covers, (width, height).
    pub fn pixels(&self) -> (u32, u32) {
        (Self::THREADS_X * self.px, self.threads_y)
    }

    /// Threads in a workgroup.
    pub fn threads(&self) -> u32 {
        Self::THREADS_X * self.threads_y
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
        tile: ConvTile,
    },
    ConvTranspose {
        relu: bool,
    },
    MaxPool,
    /// A conv (`transposed`: the 2×2 stride-2 one) on cooperative
    /// matrices, for an adapter whose subgroups have `subgroup_size`
    /// invocations (`shaders/conv_coop.wgsl`).
    CoopConv {
        kernel: usize,
        relu: bool,
        residual: bool,
        clamp: bool,
        transposed: bool,
        subgroup_size: u32,
        tile: coop::CoopTile,
    },
    /// A level's two convolutions in one kernel (`shaders/conv_fused.wgsl`).
    FusedConv(fused::FusedLevel),
}

/// One pipeline variant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct KernelKey {
    pub kind: KernelKind,
    pub src: Dtype,
    pub dst: Dtype,
    pub residual: Dtype,
    /// The weights' storage type.
    pub weights: Dtype,
    /// The type the tiled kernels stage in and sum a tap's products in
    /// before the f32 accumulators: f16 where the weights are f16 and the
    /// adapter is a GPU (`ConvSupport::f16_arithmetic`).
    pub arith: Dtype,
}

/// Largest conv kernel the tiled template's workgroup memory fits.
pub const MAX_CONV_KERNEL: usize = 5;

const CONV: &str = include_str!("../../../../shaders/conv.wgsl");
/// The register-tiled conv template, whose hash a tuning table records.
pub(super) const CONV_TEMPLATE: &str = CONV;
const CONV_TRANSPOSE: &str = include_str!("../../../../shaders/conv_transpose.wgsl");
const MAX_POOL: &str = include_str!("../../../../shaders/max_pool.wgsl");
const CONV_COOP: &str = include_str!("../../../../shaders/conv_coop.wgsl");
/// The cooperative conv template, whose hash a tuning table records.
pub(super) const COOP_TEMPLATE: &str = CONV_COOP;
const LAYER_BINDINGS: &str = include_str!("../../../../shaders/layer_bindings.wgsl");
const CONV_EPILOGUE: &str = include_str!("../../../../shaders/conv_epilogue.wgsl");
const CONV_FUSED: &str = include_str!("../../../../shaders/conv_fused.wgsl");
/// The fused level's template, whose hash a tuning table records.
pub(super) const FUSED_TEMPLATE: &str = CONV_FUSED;

/// ConvTranspose input pixels per workgroup side and output channels.
pub const CONV_TRANSPOSE_TILE: (u32, u32) = (16, CONV_TRANSPOSE_OC);
/// Max-pool workgroup side.
pub const POOL_TILE: u32 = 16;

/// Output channels per thread of the transposed conv, as in its template.
const CONV_TRANSPOSE_OC: u32 = 8;
/// Input-channel quads the transposed conv stages a step.
const CONV_TRANSPOSE_QUADS: u32 = 4;

impl KernelKey {
    pub fn uses_f16(&self) -> bool {
        [self.src, self.dst, self.residual, self.weights, self.arith].contains(&Dtype::F16)
    }

    /// The WGSL source of this variant.
    pub fn wgsl(&self) -> String {
        let (template, fields): (&str, Vec<(&str, String)>) = match self.kind {
            KernelKind::Conv {
                kernel,
                relu,
                residual,
                clamp,
                tile,
            } => {
                let cq = tile.quads(kernel, self.arith);
                (
                    CONV,
                    vec![
                        ("K", kernel.to_string()),
                        ("PX", tile.px.to_string()),
                        ("CQ", cq.to_string()),
                        ("ACC_DECL", tiled::conv_accumulators(tile)),
                        (
                            "PREFETCH",
                            tiled::conv_prefetch(kernel, tile, cq, "0u", true),
                        ),
                        (
                            "PREFETCH_NEXT",
                            tiled::conv_prefetch(kernel, tile, cq, "next", false),
                        ),
                        ("STORE_STAGED", tiled::conv_store_staged(kernel, tile, cq)),
                        ("TAPS", tiled::conv_taps(kernel, tile)),
                        ("STORES", tiled::conv_stores(tile)),
                        ("OC", ConvTile::OC.to_string()),
                        ("TX", ConvTile::THREADS_X.to_string()),
                        ("TY", tile.threads_y.to_string()),
                        ("RELU", relu.to_string()),
                        ("RESIDUAL", residual.to_string()),
                        ("CLAMP", clamp.to_string()),
                    ],
                )
            }
            KernelKind::ConvTranspose { relu } => (
                CONV_TRANSPOSE,
                vec![
                    ("RELU", relu.to_string()),
                    ("OC", CONV_TRANSPOSE_OC.to_string()),
                    ("CQ", CONV_TRANSPOSE_QUADS.to_string()),
                    ("ACC_DECL", tiled::conv_transpose_accumulators()),
                    ("TAPS", tiled::conv_transpose_taps()),
                    ("STORES", tiled::conv_transpose_stores()),
                ],
            ),
            KernelKind::MaxPool => (MAX_POOL, vec![]),
            KernelKind::CoopConv {
                kernel,
                relu,
                residual,
                clamp,
                transposed,
                subgroup_size,
                tile,
            } => (
                CONV_COOP,
                vec![
                    ("K", kernel.to_string()),
                    ("SG", subgroup_size.to_string()),
                    ("THREADS", (tile.subgroups() * subgroup_size).to_string()),
                    ("ROWS", tile.rows.to_string()),
                    ("BLOCKS", tile.blocks.to_string()),
                    ("SG_ROWS", tile.sg_rows.to_string()),
                    ("SG_COLS", tile.sg_cols.to_string()),
                    ("CHUNKS", tile.chunks.to_string()),
                    ("PREFETCH", tile.prefetch.to_string()),
                    ("PLANE_GATHER", tile.plane_gather.to_string()),
                    (
                        "PRE_LEN",
                        if tile.prefetch {
                            tile.staged_per_invocation(kernel, subgroup_size)
                        } else {
                            1
                        }
                        .to_string(),
                    ),
                    ("B_TILE", coop::b_tile(tile, kernel)),
                    ("DRAIN_MATS", tile.drain_matrices().to_string()),
                    ("COPY_WEIGHTS", coop::copy_weights(tile)),
                    (
                        "PER_THREAD",
                        tile.staged_per_invocation(kernel, subgroup_size)
                            .to_string(),
                    ),
                    ("TRANSPOSED", transposed.to_string()),
                    ("RELU", relu.to_string()),
                    ("RESIDUAL", residual.to_string()),
                    ("CLAMP", clamp.to_string()),
                    ("ACC_DECL", coop::accumulators(tile)),
                    ("TAPS", coop::taps(tile)),
                    ("STORES", coop::stores(tile)),
                ],
            ),
            KernelKind::FusedConv(level) => (CONV_FUSED, fused::fields(&level)),
        };
        // The cooperative template enables f16 itself.
        let coop = matches!(self.kind, KernelKind::CoopConv { .. });
        let enable = if self.uses_f16() && !coop {
            "enable f16;"
        } else {
            ""
        };
        let mut s = template
            .replace("{{LAYER_BINDINGS}}", LAYER_BINDINGS)
            .replace("{{CONV_EPILOGUE}}", CONV_EPILOGUE)
            .replace("{{ENABLE_F16}}", enable)
            .replace("{{SRC_T}}", self.src.wgsl())
            .replace("{{DST_T}}", self.dst.wgsl())
            .replace("{{RES_T}}", self.residual.wgsl())
            .replace("{{W_T}}", self.weights.wgsl())
            .replace("{{ARITH}}", self.arith.wgsl())
            .replace("{{MAC}}", &tiled::mac(self.arith));
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
                    tile: ConvTile::LARGE,
                },
                KernelKind::Conv {
                    kernel: 3,
                    relu: true,
                    residual: false,
                    clamp: false,
                    tile: ConvTile::for_layer(12, 5, 3, t),
                },
                KernelKind::Conv {
                    kernel: 5,
                    relu: true,
                    residual: true,
                    clamp: true,
                    tile: ConvTile::for_layer(16, 1, 5, t),
                },
                KernelKind::ConvTranspose { relu: true },
                KernelKind::ConvTranspose { relu: false },
                KernelKind::MaxPool,
                KernelKind::FusedConv(fused::FusedLevel {
                    first_kernel: 3,
                    first_relu: true,
                    mid: 32,
                    mid_dtype: t,
                    kernel: 3,
                    relu: true,
                    residual: false,
                    clamp: false,
                    tile: fused::FusedTile {
                        width: 16,
                        height: 8,
                    },
                }),
                KernelKind::FusedConv(fused::FusedLevel {
                    first_kernel: 1,
                    first_relu: false,
                    mid: 6,
                    mid_dtype: t,
                    kernel: 5,
                    relu: false,
                    residual: true,
                    clamp: true,
                    tile: fused::FusedTile {
                        width: 32,
                        height: 16,
                    },
                }),
            ];
            for kind in kinds {
                keys.push(KernelKey {
                    kind,
                    src: t,
                    dst: t,
                    residual: Dtype::F32,
                    weights: t,
                    arith: t,
                });
                // f16 storage summed in f32 (a CPU adapter's choice).
                if t == Dtype::F16 {
                    keys.push(KernelKey {
                        kind,
                        src: t,
                        dst: t,
                        residual: Dtype::F32,
                        weights: t,
                        arith: Dtype::F32,
                    });
                }
            }
        }
        keys
    }

    #[test]
    fn a_layer_gets_the_largest_tile_it_fills() {
        let tile = |w, h| ConvTile::for_layer(w, h, 3, Dtype::F32).pixels();
        assert_eq!(tile(1920, 1080), (32, 16));
        assert_eq!(ConvTile::for_layer(64, 64, 3, Dtype::F32), ConvTile::LARGE);
        assert_eq!(tile(31, 16), (16, 16));
        assert_eq!(tile(16, 8), (16, 8));
        assert_eq!(tile(8, 8), (8, 8));
        assert_eq!(tile(9, 3), (8, 4));
        assert_eq!(tile(4, 1), (8, 1));
        assert_eq!(tile(1, 0), (8, 1));
        // A 5×5 kernel's halo and weights do not fit a 32×16 tile in f32.
        assert_eq!(ConvTile::for_layer(64, 64, 5, Dtype::F32).pixels(), (32, 8));
        assert_eq!(ConvTile::for_layer(64, 64, 5, Dtype::F16), ConvTile::LARGE);
    }

    #[test]
    fn every_tile_fits_the_default_workgroup_memory() {
        for arith in [Dtype::F32, Dtype::F16] {
            for kernel in 1..=MAX_CONV_KERNEL {
                for w in [1, 8, 16, 32, 64] {
                    let tile = ConvTile::for_layer(w, 16, kernel, arith);
                    let cq = tile.quads(kernel, arith);
                    assert!(
                        tile.workgroup_bytes(kernel, cq, arith) <= WORKGROUP_BYTES,
                        "{tile:?} {kernel} {arith:?}"
                    );
                }
            }
        }
        assert_eq!(ConvTile::LARGE.quads(3, Dtype::F32), 1);
        assert_eq!(ConvTile::LARGE.quads(3, Dtype::F16), 2);
    }

    #[test]
    fn every_placeholder_is_filled() {
        for key in all_keys() {
            let src = key.wgsl();
            assert!(!src.contains("{{"), "{}: unfilled placeholder", key.label());
            assert_eq!(src.contains("enable f16;"), key.uses_f16());
        }
    }

    /// The cooperative-matrix variants: 3×3 with each epilogue, and the
    /// transposed conv, for subgroups of 32 (NVIDIA) and 64 (AMD).
    fn coop_keys() -> Vec<KernelKey> {
        let mut keys = Vec::new();
        // The default tile, the most matrices a subgroup and the most
        // subgroups a workgroup hold, the largest K-slice, a prefetch, the
        // plane gather (prefetched, and of the largest slice), staged
        // weights (alone, and with all of those), and drained at once
        // (alone, and 8 matrices a subgroup with staged weights).
        let tiles = [
            coop::CoopTile::DEFAULT,
            coop::CoopTile {
                rows: 4,
                blocks: 2,
                sg_rows: 2,
                sg_cols: 4,
                chunks: 1,
                prefetch: false,
                plane_gather: false,
                stage_weights: false,
                drain_once: false,
            },
            coop::CoopTile::DEFAULT.with_chunks(coop::MAX_CHUNKS),
            coop::CoopTile::DEFAULT
                .with_chunks(2)
                .prefetched(3, 32)
                .expect("prefetched"),
            coop::CoopTile::DEFAULT
                .plane_gathered()
                .prefetched(3, 32)
                .expect("prefetched"),
            coop::CoopTile::DEFAULT
                .with_chunks(coop::MAX_CHUNKS)
                .plane_gathered(),
            coop::CoopTile {
                stage_weights: true,
                ..coop::CoopTile::DEFAULT
            },
            coop::CoopTile {
                stage_weights: true,
                ..coop::CoopTile::DEFAULT
                    .with_chunks(2)
                    .plane_gathered()
                    .prefetched(3, 32)
                    .expect("prefetched")
            },
            coop::CoopTile {
                drain_once: true,
                ..coop::CoopTile::DEFAULT
            },
            coop::CoopTile {
                drain_once: true,
                stage_weights: true,
                ..coop::CoopTile {
                    rows: 4,
                    blocks: 2,
                    sg_rows: 2,
                    sg_cols: 2,
                    ..coop::CoopTile::DEFAULT
                }
                .plane_gathered()
            },
        ];
        for (subgroup_size, tile) in [32, 64].into_iter().flat_map(|s| tiles.map(|t| (s, t))) {
            for (kernel, relu, residual, clamp, transposed) in [
                (3, true, false, false, false),
                (3, false, true, true, false),
                (1, false, true, true, false),
                (1, true, false, false, true),
            ] {
                keys.push(KernelKey {
                    kind: KernelKind::CoopConv {
                        kernel,
                        relu,
                        residual,
                        clamp,
                        transposed,
                        subgroup_size,
                        tile,
                    },
                    src: Dtype::F16,
                    dst: Dtype::F16,
                    residual: Dtype::F32,
                    weights: Dtype::F16,
                    arith: Dtype::F16,
                });
            }
        }
        keys
    }

    /// `key`'s module, parsed and validated by naga as wgpu would.
    fn validated(key: &KernelKey) -> (naga::Module, naga::valid::ModuleInfo) {
        use naga::valid::Capabilities as C;
        let src = key.wgsl();
        let module = naga::front::wgsl::parse_str(&src)
            .unwrap_or_else(|e| panic!("{}: {}", key.label(), e.emit_to_string(&src)));
        let caps = C::SHADER_FLOAT16 | C::SUBGROUP | C::COOPERATIVE_MATRIX;
        let info = naga::valid::Validator::new(naga::valid::ValidationFlags::all(), caps)
            .validate(&module)
            .unwrap_or_else(|e| panic!("{}: {e:?}", key.label()));
        (module, info)
    }

    #[test]
    fn every_variant_is_valid_wgsl() {
        // naga is what wgpu compiles WGSL with; validate without a device.
        for key in all_keys() {
            validated(&key);
        }
    }

    #[test]
    fn every_cooperative_variant_validates_and_compiles_to_spirv() {
        // No adapter here runs cooperative matrices (lavapipe lists none),
        // so naga's validation and SPIR-V output are what CI can check:
        // wgpu's Vulkan backend feeds drivers exactly this SPIR-V.
        for key in coop_keys() {
            let (module, info) = validated(&key);
            let options = naga::back::spv::Options {
                lang_version: (1, 4),
                ..Default::default()
            };
            let words = naga::back::spv::write_vec(&module, &info, &options, None)
                .unwrap_or_else(|e| panic!("{}: {e}", key.label()));
            // SPIR-V's magic number, and the capability the tensor cores need.
            assert_eq!(words[0], 0x0723_0203, "{}", key.label());
            let coop_capability = 6022; // CooperativeMatrixKHR
            assert!(
                words
                    .windows(2)
                    .any(|w| w == [(2 << 16) | 17, coop_capability]),
                "{}: no OpCapability CooperativeMatrixKHR",
                key.label()
            );
        }
    }
}
