// 2×2 max pool, stride 2: one thread per output value (memory-bound; no
// reuse to stage). A template filled by runtime/src/inference/gpu/codegen.rs.
{{ENABLE_F16}}

struct Params {
    width: u32, // input width; the output is width/2 × height/2
    height: u32,
    cin: u32,
    cout: u32,
    in_offset: u32,
    out_offset: u32,
    res_offset: u32,
    w_offset: u32,
    b_offset: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<{{SRC_T}}>;
@group(0) @binding(2) var<storage, read> weights: array<{{W_T}}>;
@group(0) @binding(3) var<storage, read_write> dst: array<{{DST_T}}>;
@group(0) @binding(4) var<storage, read> residual: array<{{RES_T}}>;

@compute @workgroup_size(16, 16, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let ow = p.width / 2u;
    let oh = p.height / 2u;
    let c = gid.z;
    if (gid.x >= ow || gid.y >= oh || c >= p.cin) {
        return;
    }
    let base = p.in_offset + c * p.width * p.height + 2u * gid.y * p.width + 2u * gid.x;
    let m = max(
        max(src[base], src[base + 1u]),
        max(src[base + p.width], src[base + p.width + 1u]),
    );
    dst[p.out_offset + (c * oh + gid.y) * ow + gid.x] = {{DST_T}}(m);
}
