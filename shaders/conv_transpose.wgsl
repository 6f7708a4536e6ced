// 2×2 transposed convolution with stride 2 (the U-Net's upsampling), bias
// and ReLU fused. A template filled by runtime/infer/src/gpu/codegen.rs.
// Each thread reads one input pixel per input channel and writes its 2×2
// output block for OC channels (OC vec4 accumulators, one per channel, its
// four taps); the CI×OC×4 weights of a channel chunk are staged in
// workgroup memory as one vec4 per input and output channel (one load on
// lavapipe, see conv.wgsl) and shared by the workgroup's 16×16 input
// pixels. The per-channel code is unrolled by codegen into named
// accumulators.
{{ENABLE_F16}}

{{LAYER_BINDINGS}}

const OC: u32 = {{OC}}u;
const CI: u32 = 16u;
const THREADS: u32 = 256u;
const RELU: bool = {{RELU}};

var<workgroup> wtile: array<vec4<f32>, CI * OC>;

@compute @workgroup_size(16, 16, 1)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let x = wg.x * 16u + lid.x;
    let y = wg.y * 16u + lid.y;
    let oc0 = wg.z * OC;
    let inside = x < p.width && y < p.height;
    let plane = p.width * p.height;
{{ACC_DECL}}

    for (var c0 = 0u; c0 < p.cin; c0 += CI) {
        for (var i = li; i < CI * OC; i += THREADS) {
            let ci = i / OC;
            let o = i % OC;
            var v = vec4<f32>(0.0);
            if (c0 + ci < p.cin && oc0 + o < p.cout) {
                let at = p.w_offset + ((c0 + ci) * p.cout + oc0 + o) * 4u;
                v = vec4<f32>(f32(weights[at]), f32(weights[at + 1u]), f32(weights[at + 2u]), f32(weights[at + 3u]));
            }
            wtile[i] = v;
        }
        workgroupBarrier();
        if (inside) {
            for (var ci = 0u; ci < CI; ci++) {
                if (c0 + ci >= p.cin) {
                    break;
                }
                let v = vec4<f32>(f32(src[p.in_offset + (c0 + ci) * plane + y * p.width + x]));
                let wbase = ci * OC;
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
