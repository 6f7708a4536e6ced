// "Same" K×K convolution, stride 1, with bias, ReLU, residual add and the
// panel clamp fused into the epilogue (in that order).
//
// A template: the fields in double braces are filled by
// runtime/infer/src/gpu/codegen.rs.
// Tiling: a workgroup of 8×16 threads computes a 32×16-pixel tile for OC
// output channels; each thread holds PX = 4 adjacent pixels × OC channels in
// registers. Input channels are taken CI at a time: the input tile with its
// K−1 halo and the OC×CI×K×K weights are staged in workgroup memory, so each
// input value read from memory serves 4·OC·K² multiply-adds across the tile.
// Tensors are NCHW planes addressed by element offsets (concat by layout).
{{ENABLE_F16}}

{{LAYER_BINDINGS}}

const K: u32 = {{K}}u;
const R: u32 = K / 2u;
const OC: u32 = 8u;
const CI: u32 = 4u;
const PX: u32 = 4u;
const THREADS_X: u32 = 8u;
const THREADS_Y: u32 = 16u;
const TILE_W: u32 = THREADS_X * PX;
const TILE_H: u32 = THREADS_Y;
const IN_W: u32 = TILE_W + K - 1u;
const IN_H: u32 = TILE_H + K - 1u;
const THREADS: u32 = THREADS_X * THREADS_Y;
const RELU: bool = {{RELU}};
const RESIDUAL: bool = {{RESIDUAL}};
const CLAMP: bool = {{CLAMP}};

var<workgroup> tile: array<f32, CI * IN_H * IN_W>;
var<workgroup> wtile: array<f32, OC * CI * K * K>;

@compute @workgroup_size(8, 16, 1)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let x0 = wg.x * TILE_W;
    let y0 = wg.y * TILE_H;
    let oc0 = wg.z * OC;
    let plane = p.width * p.height;
    var acc: array<f32, 32>; // OC × PX

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
        for (var i = li; i < OC * CI * K * K; i += THREADS) {
            let o = i / (CI * K * K);
            let rem = i % (CI * K * K);
            let c = c0 + rem / (K * K);
            var v = 0.0;
            if (oc0 + o < p.cout && c < p.cin) {
                v = f32(weights[p.w_offset + ((oc0 + o) * p.cin + c) * K * K + rem % (K * K)]);
            }
            wtile[i] = v;
        }
        workgroupBarrier();
        for (var ci = 0u; ci < CI; ci++) {
            for (var ky = 0u; ky < K; ky++) {
                var row: array<f32, {{ROW}}>; // PX + K − 1
                let base = (ci * IN_H + lid.y + ky) * IN_W + lid.x * PX;
                for (var j = 0u; j < PX + K - 1u; j++) {
                    row[j] = tile[base + j];
                }
                for (var kx = 0u; kx < K; kx++) {
                    for (var o = 0u; o < OC; o++) {
                        let wv = wtile[((o * CI + ci) * K + ky) * K + kx];
                        for (var px = 0u; px < PX; px++) {
                            acc[o * PX + px] = fma(wv, row[px + kx], acc[o * PX + px]);
                        }
                    }
                }
            }
        }
        workgroupBarrier();
    }

    let y = y0 + lid.y;
    if (y >= p.height) {
        return;
    }
    for (var o = 0u; o < OC; o++) {
        let oc = oc0 + o;
        if (oc >= p.cout) {
            break;
        }
        let bias = f32(weights[p.b_offset + oc]);
        for (var px = 0u; px < PX; px++) {
            let x = x0 + lid.x * PX + px;
            if (x < p.width) {
                let at = oc * plane + y * p.width + x;
                var v = acc[o * PX + px] + bias;
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
        }
    }
}
