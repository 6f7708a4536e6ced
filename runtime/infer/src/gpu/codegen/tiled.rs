//! The unrolled parts of the register-tiled templates (`shaders/conv.wgsl`,
//! `shaders/conv_transpose.wgsl`): the compilers we target (naga → SPIR-V
//! → Mesa's NIR on lavapipe, and the GPU drivers) do not unroll the whole
//! nest, and a rolled loop indexes the accumulators per SIMD lane.

use super::{CONV_TRANSPOSE_OC, ConvTile, Dtype};

/// The conv kernel's accumulators: `a{px}_{q}`, four output channels each.
pub(super) fn conv_accumulators(tile: ConvTile) -> String {
    let mut s = String::new();
    for px in 0..tile.px {
        for q in 0..ConvTile::OC / 4 {
            s += &format!("    var a{px}_{q} = vec4<f32>(0.0);\n");
        }
    }
    s
}

/// One quad's multiply-adds: per kernel row the PX + K − 1 input vec4s
/// once, then per tap and four output channels one matrix and PX
/// matrix-vector multiply-adds.
pub(super) fn conv_taps(kernel: usize, tile: ConvTile) -> String {
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
                        "            a{px}_{q} = mac(w{ky}_{kx}_{q}, r{r}_{ky}, a{px}_{q});\n"
                    );
                }
            }
        }
    }
    s
}

/// The conv kernel's stores: every accumulator lane through `emit`.
pub(super) fn conv_stores(tile: ConvTile) -> String {
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

/// Registers each thread stages through: `s{i}` input vec4s and `w{i}`
/// weight columns, as many as the step's values over the threads.
fn staged_counts(kernel: usize, tile: ConvTile, cq: u32) -> (u32, u32) {
    let k = kernel as u32;
    let (w, h) = tile.pixels();
    let inputs = cq * (h + k - 1) * (w + k - 1);
    let columns = cq * k * k * ConvTile::OC;
    let t = tile.threads();
    (inputs.div_ceil(t), columns.div_ceil(t))
}

/// The loads of this thread's share of a step (`c0`: its first channel)
/// into the staging registers; `declare` for the first step.
pub(super) fn conv_prefetch(
    kernel: usize,
    tile: ConvTile,
    cq: u32,
    c0: &str,
    declare: bool,
) -> String {
    let (n_in, n_w) = staged_counts(kernel, tile, cq);
    let (var, pad) = if declare {
        ("var ", "    ")
    } else {
        ("", "            ")
    };
    let mut s = String::new();
    for i in 0..n_in {
        s += &format!("{pad}{var}s{i} = input_at({c0}, li + {i}u * THREADS, x0, y0);\n");
    }
    for i in 0..n_w {
        s += &format!("{pad}{var}w{i} = weight_column({c0}, li + {i}u * THREADS, blk);\n");
    }
    s
}

/// The staging registers into workgroup memory.
pub(super) fn conv_store_staged(kernel: usize, tile: ConvTile, cq: u32) -> String {
    let (n_in, n_w) = staged_counts(kernel, tile, cq);
    let mut s = String::new();
    for i in 0..n_in {
        s += &format!(
            "        if (li + {i}u * THREADS < IN_VALUES) {{ tile[li + {i}u * THREADS] = s{i}; }}\n"
        );
    }
    for i in 0..n_w {
        s += &format!(
            "        if (li + {i}u * THREADS < W_COLUMNS) {{ let i = li + {i}u * THREADS; wtile[i / 4u][i % 4u] = w{i}; }}\n"
        );
    }
    s
}

/// `mac(m, v, a)`: `a + m·v`, a 4×4 matrix of `arith` by a vec4 into f32
/// accumulators. In f32 as four fused vec4 multiply-adds; in f16 the
/// product is summed in f16 (packed pairs on GPUs that have them) and
/// added to the f32 accumulator, so a rounding of f16 reaches the sum once
/// per four products, never through the whole reduction.
pub(super) fn mac(arith: Dtype) -> String {
    match arith {
        Dtype::F32 => "fn mac(m: mat4x4<f32>, v: vec4<f32>, a: vec4<f32>) -> vec4<f32> {
    return fma(m[3], vec4<f32>(v.w), fma(m[2], vec4<f32>(v.z), fma(m[1], vec4<f32>(v.y), fma(m[0], vec4<f32>(v.x), a))));
}"
        .into(),
        Dtype::F16 => "fn mac(m: mat4x4<f16>, v: vec4<f16>, a: vec4<f32>) -> vec4<f32> {
    return a + vec4<f32>(m * v);
}"
        .into(),
    }
}

/// The transposed conv's accumulators: `a{o}`, the 2×2 taps of channel o.
pub(super) fn conv_transpose_accumulators() -> String {
    (0..CONV_TRANSPOSE_OC)
        .map(|o| format!("    var a{o} = vec4<f32>(0.0);\n"))
        .collect()
}

/// One quad's multiply-adds into every accumulator, unrolled.
pub(super) fn conv_transpose_taps() -> String {
    (0..CONV_TRANSPOSE_OC)
        .map(|o| format!("                a{o} = mac(wtile[wbase + {o}u], v, a{o});\n"))
        .collect()
}

/// The transposed conv's stores, one 2×2 block per channel.
pub(super) fn conv_transpose_stores() -> String {
    (0..CONV_TRANSPOSE_OC)
        .map(|o| format!("    emit(x, y, oc0 + {o}u, a{o});\n"))
        .collect()
}
