// The client's 8-bit RGBA frame, uploaded as it came, to the three f32
// planes the network and the encode read. A code's value comes from the
// table the host decode uses (runtime/service/src/pipeline/frame.rs,
// code_lut: code/255 or its sRGB decode), so the planes equal the host's
// bit for bit whatever the device's division or pow; alpha is ignored.

struct Unpack {
    pixels: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> unpack: Unpack;
// One RGBA8 pixel per element, red in the low byte.
@group(0) @binding(1) var<storage, read> rgba: array<u32>;
// 256 values, one per code.
@group(0) @binding(2) var<storage, read> lut: array<f32>;
// R, G, B planes of `pixels` values each.
@group(0) @binding(3) var<storage, read_write> planes: array<f32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let pixel = id.x + id.y * 65535u * 64u;
    if (pixel >= unpack.pixels) {
        return;
    }
    let word = rgba[pixel];
    for (var c = 0u; c < 3u; c = c + 1u) {
        planes[c * unpack.pixels + pixel] = lut[(word >> (8u * c)) & 255u];
    }
}
