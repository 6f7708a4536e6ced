// Quad layers over a view's projection layer, in linear light, before the
// preprocessing (runtime/service/src/compose: the CPU twin is `blend`).
// Premultiplied "over": out = c + (1 - a) * below, the quads in the order
// the host sorted them (ascending z, ties by layer id). One thread per
// pixel loops over the quads; a pixel no quad covers is left untouched.

struct Blend {
    width: u32,
    height: u32,
    plane_stride: u32,
    quads: u32,
}

struct Quad {
    x: u32,
    y: u32,
    width: u32,
    height: u32,
    // The quad's first texel in `texels`.
    offset: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> blend: Blend;
@group(0) @binding(1) var<storage, read> quads: array<Quad>;
// Premultiplied linear RGBA, each quad's texels row-major from its offset.
@group(0) @binding(2) var<storage, read> texels: array<vec4<f32>>;
// R, G, B planes `plane_stride` values apart, blended in place.
@group(0) @binding(3) var<storage, read_write> planes: array<f32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let pixel = id.x + id.y * 65535u * 64u;
    if (pixel >= blend.width * blend.height) {
        return;
    }
    let x = pixel % blend.width;
    let y = pixel / blend.width;
    let s = blend.plane_stride;
    var rgb = vec3<f32>(planes[pixel], planes[s + pixel], planes[2u * s + pixel]);
    var touched = false;
    for (var i = 0u; i < blend.quads; i = i + 1u) {
        let q = quads[i];
        if (x >= q.x && x < q.x + q.width && y >= q.y && y < q.y + q.height) {
            let t = texels[q.offset + (y - q.y) * q.width + (x - q.x)];
            rgb = fma(vec3<f32>(1.0 - t.a), rgb, t.rgb);
            touched = true;
        }
    }
    if (touched) {
        planes[pixel] = rgb.r;
        planes[s + pixel] = rgb.g;
        planes[2u * s + pixel] = rgb.b;
    }
}
