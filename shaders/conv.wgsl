// "Same" K×K convolution, stride 1, with bias, ReLU, residual add and the
// panel clamp fused into the epilogue (in that order), as a register-tiled
// implicit GEMM: M = pixels, N = output channels, K = input channels × taps.
//
// A template: the fields in double braces are filled by
// runtime/infer/src/gpu/codegen.rs.
// Tiling (chosen per layer by `ConvTile::for_layer`): a workgroup of TX×TY
// threads computes a (TX·PX)×TY-pixel tile for OC output channels; each
// thread holds PX adjacent pixels × OC channels in registers. Input channels
// go in quads, CQ quads a step: the step's input tile (with its K−1 halo)
// is staged in workgroup memory as one vec4 per pixel (its four channels),
// and its weights as one 4×4 matrix per tap and four output channels
// (columns: input channels, rows: output channels), packed in that order
// once at load (`codegen::pack_conv`), so staging them is a contiguous copy.
// A multiply-add step is then one matrix load, one input vec4 reused over
// K taps and PX pixels, and 16 fused multiply-adds per pixel.
// Staging is double-buffered through registers: each thread loads its
// share of the next step from memory before it computes the current one,
// so the loads' latency hides behind the arithmetic.
// With f16 (ARITH f16) the 4×4 products of a tap are summed in f16 (packed
// pairs on GPUs that have them) and added to f32 accumulators.
// Tensors are NCHW planes addressed by element offsets (concat by layout);
// adjacent threads read adjacent pixels of one plane, so staging reads are
// contiguous across a workgroup.
{{ENABLE_F16}}

{{LAYER_BINDINGS}}

alias T = {{ARITH}};
const K: u32 = {{K}}u;
const R: u32 = K / 2u;
const OC: u32 = {{OC}}u;
const OC4: u32 = OC / 4u;
const CQ: u32 = {{CQ}}u;
const PX: u32 = {{PX}}u;
const THREADS_X: u32 = {{TX}}u;
const THREADS_Y: u32 = {{TY}}u;
const TILE_W: u32 = THREADS_X * PX;
const TILE_H: u32 = THREADS_Y;
const IN_W: u32 = TILE_W + K - 1u;
const IN_H: u32 = TILE_H + K - 1u;
const THREADS: u32 = THREADS_X * THREADS_Y;
const IN_VALUES: u32 = CQ * IN_H * IN_W;
// Columns of the step's weight matrices: CQ quads × K² taps × OC4 blocks × 4.
const W_COLUMNS: u32 = CQ * K * K * OC4 * 4u;
const RELU: bool = {{RELU}};
const RESIDUAL: bool = {{RESIDUAL}};
const CLAMP: bool = {{CLAMP}};

// [quad][row][column]: the four channels of a quad at one pixel.
var<workgroup> tile: array<vec4<T>, IN_VALUES>;
// [quad][ky][kx][oc/4]: one matrix per tap and four output channels.
var<workgroup> wtile: array<mat4x4<T>, W_COLUMNS / 4u>;

// The four channels of quad `q` of the step at `c0`, at tile position
// `i` (an index into `tile`), zero outside the layer.
fn input_at(c0: u32, i: u32, x0: u32, y0: u32) -> vec4<T> {
    let q = i / (IN_H * IN_W);
    let rem = i % (IN_H * IN_W);
    let gx = i32(x0 + rem % IN_W) - i32(R);
    let gy = i32(y0 + rem / IN_W) - i32(R);
    var v = vec4<T>(0.0);
    if (i < IN_VALUES && gx >= 0 && gx < i32(p.width) && gy >= 0 && gy < i32(p.height)) {
        let plane = p.width * p.height;
        let c = c0 + 4u * q;
        let at = p.in_offset + c * plane + u32(gy) * p.width + u32(gx);
        // Channels past cin read as zero (their packed weights are zero too,
        // but the memory past the tensor need not be finite).
        if (c < p.cin) { v.x = T(src[at]); }
        if (c + 1u < p.cin) { v.y = T(src[at + plane]); }
        if (c + 2u < p.cin) { v.z = T(src[at + 2u * plane]); }
        if (c + 3u < p.cin) { v.w = T(src[at + 3u * plane]); }
    }
    return v;
}

// Column `i` of the step at `c0`'s weight matrices for output block `blk`
// (packed: [block][quad][ky][kx][oc/4][column][row]); zero past the last
// quad.
fn weight_column(c0: u32, i: u32, blk: u32) -> vec4<T> {
    let quads = (p.cin + 3u) / 4u;
    var v = vec4<T>(0.0);
    if (i < W_COLUMNS && c0 / 4u + i / (K * K * OC4 * 4u) < quads) {
        let at = p.w_offset + 4u * ((blk * quads + c0 / 4u) * K * K * OC4 * 4u + i);
        v = vec4<T>(T(weights[at]), T(weights[at + 1u]), T(weights[at + 2u]), T(weights[at + 3u]));
    }
    return v;
}

@compute @workgroup_size({{TX}}, {{TY}}, 1)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let x0 = wg.x * TILE_W;
    let y0 = wg.y * TILE_H;
    let blk = wg.z;
    let oc0 = blk * OC;
    // The accumulators, PX × OC/4 named vec4s a{px}_{q}: named, not an
    // array, so that no compiler has to prove an index uniform.
{{ACC_DECL}}

    // This thread's share of the first step, then of each next one.
{{PREFETCH}}
    for (var c0 = 0u; c0 < p.cin; c0 += 4u * CQ) {
{{STORE_STAGED}}
        workgroupBarrier();
        let next = c0 + 4u * CQ;
        if (next < p.cin) {
{{PREFETCH_NEXT}}
        }
        for (var q = 0u; q < CQ; q++) {
            let rbase = (q * IN_H + lid.y) * IN_W + lid.x * PX;
            let wbase = q * K * K * OC4;
            // Unrolled by codegen: per kernel row, the PX + K − 1 input
            // vec4s r{j} once, then per tap and block of four output
            // channels one matrix and PX matrix-vector multiply-adds.
{{TAPS}}
        }
        workgroupBarrier();
    }

    let y = y0 + lid.y;
    if (y >= p.height) {
        return;
    }
    let x = x0 + lid.x * PX;
{{STORES}}
}

{{MAC}}

// One output value, if inside the layer, through the epilogue.
fn emit(x: u32, y: u32, oc: u32, sum: f32) {
    if (x >= p.width || oc >= p.cout) {
        return;
    }
    epilogue(oc * p.width * p.height + y * p.width + x, oc, sum);
}

{{CONV_EPILOGUE}}
