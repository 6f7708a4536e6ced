// 2×2 transposed convolution with stride 2 (the U-Net's upsampling), bias
// and ReLU fused. A template filled by runtime/infer/src/gpu/codegen.rs.
// Each thread reads one input pixel per input channel and writes its 2×2
// output block for OC channels (4·OC accumulators in registers); the
// CI×OC×4 weights of a channel chunk are staged in workgroup memory and
// shared by the workgroup's 16×16 input pixels.
{{ENABLE_F16}}

{{LAYER_BINDINGS}}

const OC: u32 = 8u;
const CI: u32 = 16u;
const THREADS: u32 = 256u;
const RELU: bool = {{RELU}};

var<workgroup> wtile: array<f32, CI * OC * 4u>;

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
    var acc: array<f32, 32>; // OC × 4 taps

    for (var c0 = 0u; c0 < p.cin; c0 += CI) {
        for (var i = li; i < CI * OC * 4u; i += THREADS) {
            let ci = i / (OC * 4u);
            let o = (i / 4u) % OC;
            var v = 0.0;
            if (c0 + ci < p.cin && oc0 + o < p.cout) {
                v = f32(weights[p.w_offset + ((c0 + ci) * p.cout + oc0 + o) * 4u + i % 4u]);
            }
            wtile[i] = v;
        }
        workgroupBarrier();
        if (inside) {
            for (var ci = 0u; ci < CI; ci++) {
                if (c0 + ci >= p.cin) {
                    break;
                }
                let v = f32(src[p.in_offset + (c0 + ci) * plane + y * p.width + x]);
                for (var j = 0u; j < OC * 4u; j++) {
                    acc[j] = fma(v, wtile[ci * OC * 4u + j], acc[j]);
                }
            }
        }
        workgroupBarrier();
    }

    if (!inside) {
        return;
    }
    let ow = 2u * p.width;
    let oplane = 4u * plane;
    for (var o = 0u; o < OC; o++) {
        let oc = oc0 + o;
        if (oc >= p.cout) {
            break;
        }
        let bias = f32(weights[p.b_offset + oc]);
        for (var t = 0u; t < 4u; t++) {
            var v = acc[o * 4u + t] + bias;
            if (RELU) {
                v = max(v, 0.0);
            }
            let at = oc * oplane + (2u * y + t / 2u) * ow + 2u * x + t % 2u;
            dst[p.out_offset + at] = {{DST_T}}(v);
        }
    }
}
