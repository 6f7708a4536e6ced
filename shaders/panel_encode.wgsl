// The encode stage on the GPU: a planar linear display image (three f32
// planes, any values) to the panel's interleaved RGBA8 codes. Clamping to
// [0, 1] and the transfer curve are one step: the code of x is the number
// of the channel's 255 decision thresholds that are <= x
// (runtime/service/src/present/transfer.rs), found by a binary search of
// comparisons only, so the codes equal the CPU's bit for bit. Values below
// the first threshold (negatives included) give 0, values at or above the
// last give 255, NaN gives 0 like the CPU.

struct Frame {
    width: u32,
    height: u32,
    // Elements between the planes of `display` (width * height, or more
    // where the planes are padded).
    plane_stride: u32,
    // Texels from one row of `codes` to the next: the width padded to the
    // 256-byte pitch of a buffer-to-texture copy.
    row_texels: u32,
}

@group(0) @binding(0) var<storage, read> display: array<f32>;
// 3 x 255 thresholds, channel-major.
@group(0) @binding(1) var<storage, read> thresholds: array<f32>;
@group(0) @binding(2) var<uniform> frame: Frame;
// One packed RGBA8 texel per pixel, red in the low byte, rows padded.
@group(0) @binding(3) var<storage, read_write> codes: array<u32>;

fn is_nan(x: f32) -> bool {
    // By the bits: a shader compiler may assume finite floats.
    return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u;
}

fn code(channel: u32, x: f32) -> u32 {
    if (is_nan(x)) {
        return 0u;
    }
    let base = channel * 255u;
    var n = 0u;
    // Lower bound over 255 sorted thresholds: 8 halvings.
    for (var step = 128u; step > 0u; step = step >> 1u) {
        let probe = n + step - 1u;
        if (probe < 255u && thresholds[base + probe] <= x) {
            n = n + step;
        }
    }
    return n;
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let pixel = id.x + id.y * 65535u * 64u;
    if (pixel >= frame.width * frame.height) {
        return;
    }
    let r = code(0u, display[pixel]);
    let g = code(1u, display[frame.plane_stride + pixel]);
    let b = code(2u, display[2u * frame.plane_stride + pixel]);
    let row = pixel / frame.width;
    codes[row * frame.row_texels + pixel - row * frame.width] =
        r | (g << 8u) | (b << 16u) | (255u << 24u);
}
