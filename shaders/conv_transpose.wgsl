// 2×2 transposed convolution with stride 2 (the U-Net's upsampling), bias
// and ReLU fused. A template filled by runtime/infer/src/gpu/codegen.rs.
// Each thread reads one input pixel, four input channels (a quad) at a
// time, and writes its 2×2 output block for OC channels (OC vec4
// accumulators, one per channel, its four taps). The weights of CQ quads ×
// OC channels are staged in workgroup memory as one 4×4 matrix per quad
// and output channel (columns: input channels, rows: the four taps), packed
// in that order once at load (`codegen::pack_conv_transpose`), so staging
// them is a contiguous copy and a quad's multiply-adds are one matrix load
// and 16 fused multiply-adds per channel. The per-channel code is unrolled
// by codegen into named accumulators.
{{ENABLE_F16}}

{{LAYER_BINDINGS}}

alias T = {{ARITH}};
const OC: u32 = {{OC}}u;
const CQ: u32 = {{CQ}}u;
const THREADS: u32 = 256u;
const RELU: bool = {{RELU}};

var<workgroup> wtile: array<mat4x4<T>, CQ * OC>;

@compute @workgroup_size(16, 16, 1)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let x = wg.x * 16u + lid.x;
    let y = wg.y * 16u + lid.y;
    let blk = wg.z;
    let oc0 = blk * OC;
    let inside = x < p.width && y < p.height;
    let plane = p.width * p.height;
    let quads = (p.cin + 3u) / 4u;
{{ACC_DECL}}

    for (var q0 = 0u; q0 < quads; q0 += CQ) {
        // Packed: [block][quad][oc][column][row], CQ·OC matrices a step.
        for (var i = li; i < CQ * OC * 4u; i += THREADS) {
            var v = vec4<T>(0.0);
            if (q0 + i / (OC * 4u) < quads) {
                let at = p.w_offset + 4u * ((blk * quads + q0) * OC * 4u + i);
                v = vec4<T>(T(weights[at]), T(weights[at + 1u]), T(weights[at + 2u]), T(weights[at + 3u]));
            }
            wtile[i / 4u][i % 4u] = v;
        }
        workgroupBarrier();
        if (inside) {
            for (var qi = 0u; qi < CQ; qi++) {
                let c = 4u * (q0 + qi);
                if (c >= p.cin) {
                    break;
                }
                let at = p.in_offset + c * plane + y * p.width + x;
                var v = vec4<T>(0.0);
                v.x = T(src[at]);
                if (c + 1u < p.cin) { v.y = T(src[at + plane]); }
                if (c + 2u < p.cin) { v.z = T(src[at + 2u * plane]); }
                if (c + 3u < p.cin) { v.w = T(src[at + 3u * plane]); }
                let wbase = qi * OC;
{{TAPS}}
            }
        }
        workgroupBarrier();
    }

    if (!inside) {
        return;
    }
{{STORES}}
}

{{MAC}}

// The epilogue of one output channel's 2×2 block: bias, ReLU, store.
fn emit(x: u32, y: u32, oc: u32, taps: vec4<f32>) {
    if (oc >= p.cout) {
        return;
    }
    let ow = 2u * p.width;
    let base = p.out_offset + oc * 4u * p.width * p.height + 2u * y * ow + 2u * x;
    var v = taps + vec4<f32>(f32(weights[p.b_offset + oc]));
    if (RELU) {
        v = max(v, vec4<f32>(0.0));
    }
    dst[base] = {{DST_T}}(v.x);
    dst[base + 1u] = {{DST_T}}(v.y);
    dst[base + ow] = {{DST_T}}(v.z);
    dst[base + ow + 1u] = {{DST_T}}(v.w);
}
