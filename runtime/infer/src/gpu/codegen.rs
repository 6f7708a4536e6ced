//! WGSL generation: the kernel templates in `shaders/` filled in for one
//! layer's variant (kernel size, conv tile, fused epilogue, element types,
//! and the unrolled multiply-adds). Each distinct variant becomes one
//! pipeline, built when a frame size first needs it and kept.

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
/// pixels. Chosen per layer from its size (`for_layer`), so the small deep
/// levels of the U-Net do not run tiles mostly outside the layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ConvTile {
    pub px: u32,
    pub threads_y: u32,
}

impl ConvTile {
    /// Threads along x. lavapipe runs a workgroup's invocations in SIMD
    /// vectors along x only (8 lanes of its 256-bit vectors), so a narrower
    /// workgroup leaves lanes empty; GPUs are indifferent to the shape.
    pub const THREADS_X: u32 = 8;
    /// Output channels per thread (in vec4s of weights: a multiple of 4).
    pub const OC: u32 = 16;
    /// The tile for layers at least 32 pixels wide and 16 tall.
    pub const LARGE: ConvTile = ConvTile {
        px: 4,
        threads_y: 16,
    };

    /// The tile for a `width`×`height` layer: the most pixels per thread
    /// (4, 2 or 1: a tile 32, 16 or 8 wide) whose tile row the layer fills,
    /// and as many rows as the smallest power of two at least `height`, at
    /// most 16. Of 4–32 channels × 4–8 pixels per thread, 16 × 4 and 16 × 8
    /// ran fastest on lavapipe; 8 pixels took LLVM 18 s to compile, so 4
    /// (docs/benchmarks.md).
    pub fn for_layer(width: u32, height: u32) -> Self {
        let px = [4, 2, 1]
            .into_iter()
            .find(|&px| Self::THREADS_X * px <= width)
            .unwrap_or(1);
        let threads_y = height.max(1).next_power_of_two().min(Self::LARGE.threads_y);
        ConvTile { px, threads_y }
    }

    /// Input channels staged per step for a `kernel`×`kernel` conv: the
    /// most of 4, 2, 1 whose input tile and weights fit WebGPU's default
    /// 16 KiB of workgroup memory, which every adapter offers.
    pub fn input_channels(&self, kernel: usize) -> u32 {
        [4, 2, 1]
            .into_iter()
            .find(|&ci| self.workgroup_bytes(kernel, ci) <= 16384)
            .unwrap_or(1)
    }

    /// Workgroup memory of the template for `ci` staged input channels.
    fn workgroup_bytes(&self, kernel: usize, ci: u32) -> u32 {
        let k = kernel as u32;
        let (w, h) = self.pixels();
        let input = ci * (h + k - 1) * (w + k - 1);
        let weights = ci * k * k * Self::OC;
        4 * (input + weights)
    }

    /// Output pixels a workgroup covers, (width, height).
    pub fn pixels(&self) -> (u32, u32) {
        (Self::THREADS_X * self.px, self.threads_y)
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

/// ConvTranspose input pixels per workgroup side and output channels.
pub const CONV_TRANSPOSE_TILE: (u32, u32) = (16, CONV_TRANSPOSE_OC);
/// Max-pool workgroup side.
pub const POOL_TILE: u32 = 16;

/// The conv kernel's accumulators: `a{px}_{q}`, four output channels each.
fn conv_accumulators(tile: ConvTile) -> String {
    let mut s = String::new();
    for px in 0..tile.px {
        for q in 0..ConvTile::OC / 4 {
            s += &format!("    var a{px}_{q} = vec4<f32>(0.0);\n");
        }
    }
    s
}

/// One input channel's multiply-adds, unrolled: the compilers we target
/// (naga → SPIR-V → Mesa's NIR on lavapipe) do not unroll the whole nest,
/// and a rolled loop indexes the accumulators per SIMD lane.
fn conv_taps(kernel: usize, tile: ConvTile) -> String {
    let (k, px_n, oc4) = (kernel as u32, tile.px, ConvTile::OC / 4);
    let mut s = String::new();
    for ky in 0..k {
        for j in 0..px_n + k - 1 {
            s += &format!("            let r{j}_{ky} = tile[rbase + {ky}u * IN_W + {j}u];\n");
        }
        for kx in 0..k {
            for q in 0..oc4 {
                let w = (ky * k + kx) * oc4 + q;
                s += &format!("            let w{ky}_{kx}_{q} = wtile[wbase + {w}u];\n");
                for px in 0..px_n {
                    let r = px + kx;
                    s += &format!(
                        "            a{px}_{q} = fma(w{ky}_{kx}_{q}, vec4<f32>(r{r}_{ky}), a{px}_{q});\n"
                    );
                }
            }
        }
    }
    s
}

/// The conv kernel's stores: every accumulator lane through `emit`.
fn conv_stores(tile: ConvTile) -> String {
    let mut s = String::new();
    for px in 0..tile.px {
        for q in 0..ConvTile::OC / 4 {
            for (j, lane) in ["x", "y", "z", "w"].iter().enumerate() {
                let o = 4 * q + j as u32;
                s += &format!("    emit(x + {px}u, y, oc0 + {o}u, a{px}_{q}.{lane});\n");
            }
        }
    }
    s
}

/// Output channels per thread of the transposed conv, as in its template.
const CONV_TRANSPOSE_OC: u32 = 8;

/// The transposed conv's accumulators: `a{o}`, the 2×2 taps of channel o.
fn conv_transpose_accumulators() -> String {
    (0..CONV_TRANSPOSE_OC)
        .map(|o| format!("    var a{o} = vec4<f32>(0.0);\n"))
        .collect()
}

/// One input channel's multiply-adds into every accumulator, unrolled.
fn conv_transpose_taps() -> String {
    (0..CONV_TRANSPOSE_OC)
        .map(|o| format!("                a{o} = fma(v, wtile[wbase + {o}u], a{o});\n"))
        .collect()
}

/// The transposed conv's stores, one 2×2 block per channel.
fn conv_transpose_stores() -> String {
    (0..CONV_TRANSPOSE_OC)
        .map(|o| format!("    emit(x, y, oc0 + {o}u, a{o});\n"))
        .collect()
}

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
                tile,
            } => (
                CONV,
                vec![
                    ("K", kernel.to_string()),
                    ("PX", tile.px.to_string()),
                    ("CI", tile.input_channels(kernel).to_string()),
                    ("ACC_DECL", conv_accumulators(tile)),
                    ("TAPS", conv_taps(kernel, tile)),
                    ("STORES", conv_stores(tile)),
                    ("OC", ConvTile::OC.to_string()),
                    ("TX", ConvTile::THREADS_X.to_string()),
                    ("TY", tile.threads_y.to_string()),
                    ("RELU", relu.to_string()),
                    ("RESIDUAL", residual.to_string()),
                    ("CLAMP", clamp.to_string()),
                ],
            ),
            KernelKind::ConvTranspose { relu } => (
                CONV_TRANSPOSE,
                vec![
                    ("RELU", relu.to_string()),
                    ("OC", CONV_TRANSPOSE_OC.to_string()),
                    ("ACC_DECL", conv_transpose_accumulators()),
                    ("TAPS", conv_transpose_taps()),
                    ("STORES", conv_transpose_stores()),
                ],
            ),
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
                    tile: ConvTile::LARGE,
                },
                KernelKind::Conv {
                    kernel: 3,
                    relu: true,
                    residual: false,
                    clamp: false,
                    tile: ConvTile::for_layer(12, 5),
                },
                KernelKind::Conv {
                    kernel: 5,
                    relu: true,
                    residual: true,
                    clamp: true,
                    tile: ConvTile::for_layer(16, 1),
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
    fn a_layer_gets_the_largest_tile_it_fills() {
        let tile = |w, h| ConvTile::for_layer(w, h).pixels();
        assert_eq!(tile(1920, 1080), (32, 16));
        assert_eq!(ConvTile::for_layer(64, 64), ConvTile::LARGE);
        assert_eq!(tile(31, 16), (16, 16));
        assert_eq!(tile(16, 8), (16, 8));
        assert_eq!(tile(8, 8), (8, 8));
        assert_eq!(tile(9, 3), (8, 4));
        assert_eq!(tile(4, 1), (8, 1));
        assert_eq!(tile(1, 0), (8, 1));
    }

    #[test]
    fn every_tile_fits_the_default_workgroup_memory() {
        for kernel in 1..=MAX_CONV_KERNEL {
            for w in [1, 8, 16, 32, 64] {
                let tile = ConvTile::for_layer(w, 16);
                let ci = tile.input_channels(kernel);
                assert!(
                    tile.workgroup_bytes(kernel, ci) <= 16384,
                    "{tile:?} {kernel}"
                );
            }
        }
        assert_eq!(ConvTile::LARGE.input_channels(3), 4);
        assert_eq!(ConvTile::LARGE.input_channels(5), 2);
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
