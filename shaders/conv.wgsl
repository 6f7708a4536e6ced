// "Same" K×K convolution, stride 1, with bias, ReLU, residual add and the
// panel clamp fused into the epilogue (in that order).
//
// A template: the fields in double braces are filled by
// runtime/infer/src/gpu/codegen.rs.
// Tiling (chosen per layer by `ConvTile::for_layer`): a workgroup of TX×TY
// threads computes a (TX·PX)×TY-pixel tile for OC output channels; each
// thread holds PX adjacent pixels × OC channels in registers. Input channels
// are taken CI at a time (as many as fit 16 KiB): the input tile with its
// K−1 halo and the OC×CI×K×K weights are staged in workgroup memory, so each
// input value read from memory serves PX·OC·K² multiply-adds across the
// tile. The weights are staged as vec4s of four output channels: on
// lavapipe every workgroup-memory load is a loop over the SIMD lanes, so one
// vec4 load costs about what one scalar load does (docs/benchmarks.md).
// Tensors are NCHW planes addressed by element offsets (concat by layout).
{{ENABLE_F16}}

{{LAYER_BINDINGS}}

const K: u32 = {{K}}u;
const R: u32 = K / 2u;
const OC: u32 = {{OC}}u;
const CI: u32 = {{CI}}u;
const PX: u32 = {{PX}}u;
const THREADS_X: u32 = {{TX}}u;
const THREADS_Y: u32 = {{TY}}u;
const TILE_W: u32 = THREADS_X * PX;
const TILE_H: u32 = THREADS_Y;
const IN_W: u32 = TILE_W + K - 1u;
const IN_H: u32 = TILE_H + K - 1u;
const THREADS: u32 = THREADS_X * THREADS_Y;
const RELU: bool = {{RELU}};
const RESIDUAL: bool = {{RESIDUAL}};
const CLAMP: bool = {{CLAMP}};

var<workgroup> tile: array<f32, CI * IN_H * IN_W>;
const OC4: u32 = OC / 4u;
// [ci][ky][kx][oc/4]: a thread reads four output channels' weights in one load.
var<workgroup> wtile: array<vec4<f32>, CI * K * K * OC4>;

@compute @workgroup_size({{TX}}, {{TY}}, 1)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let x0 = wg.x * TILE_W;
    let y0 = wg.y * TILE_H;
    let oc0 = wg.z * OC;
    let plane = p.width * p.height;
    // The accumulators, PX × OC/4 named vec4s a{px}_{q}: named, not an
    // array, so that no compiler has to prove an index uniform.
{{ACC_DECL}}

    for (var c0 = 0u; c0 < p.cin; c0 += CI) {
        for (var i = li; i < CI * IN_H * IN_W; i += THREADS) {
            let ci = i / (IN_H * IN_W);
            let rem = i % (IN_H * IN_W);
            let gx = i32(x0 + rem % IN_W) - i32(R);
            let gy = i32(y0 + rem / IN_W) - i32(R);
            let c = c0 + ci;
            var v = 0.0;
            if (c < p.cin && gx >= 0 && gx < i32(p.width) && gy >= 0 && gy < i32(p.height)) {
                v = f32(src[p.in_offset + c * plane + u32(gy) * p.width + u32(gx)]);
            }
            tile[i] = v;
        }
        for (var i = li; i < CI * K * K * OC4; i += THREADS) {
            let q = i % OC4;
            let tap = i / OC4; // ci·K·K + ky·K + kx
            let c = c0 + tap / (K * K);
            var v = vec4<f32>(0.0);
            if (c < p.cin) {
                for (var j = 0u; j < 4u; j++) {
                    let o = oc0 + 4u * q + j;
                    if (o < p.cout) {
                        v[j] = f32(weights[p.w_offset + (o * p.cin + c) * K * K + tap % (K * K)]);
                    }
                }
            }
            wtile[i] = v;
        }
        workgroupBarrier();
        for (var ci = 0u; ci < CI; ci++) {
            let rbase = (ci * IN_H + lid.y) * IN_W + lid.x * PX;
            let wbase = ci * K * K * OC4;
            // Unrolled by codegen: per kernel row, the PX + K − 1 inputs r{j}
            // once, then per tap and vec4 of channels one weight load and PX
            // fused multiply-adds.
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

// The epilogue of one output value: bias, ReLU, residual, clamp, store.
fn emit(x: u32, y: u32, oc: u32, sum: f32) {
    if (x >= p.width || oc >= p.cout) {
        return;
    }
    let at = oc * p.width * p.height + y * p.width + x;
    var v = sum + f32(weights[p.b_offset + oc]);
    if (RELU) {
        v = max(v, 0.0);
    }
    if (RESIDUAL) {
        v += f32(residual[p.res_offset + at]);
    }
    if (CLAMP) {
        v = clamp(v, 0.0, 1.0);
    }
    dst[p.out_offset + at] = {{DST_T}}(v);
}
