// 2×2 max pool, stride 2: one thread per output value (memory-bound; no
// reuse to stage). A template filled by runtime/infer/src/gpu/codegen.rs.
{{ENABLE_F16}}

{{LAYER_BINDINGS}}

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
