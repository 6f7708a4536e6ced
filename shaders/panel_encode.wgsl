// The encode stage on the GPU: a planar linear display image (three f32
// planes, any values) to the panel's interleaved RGBA8 codes. Clamping to
// [0, 1] and the transfer curve are one step: the code of x is the number
// of the channel's 255 decision thresholds that are <= x
// (runtime/service/src/present/transfer.rs), found as the CPU finds it (a
// 4096-bin table, then comparisons only), so the codes equal the CPU's bit
// for bit. Values below the first threshold (negatives included) give 0,
// values at or above the last give 255, NaN gives 0 like the CPU.

struct Frame {
    width: u32,
    height: u32,
    // Elements between the planes of `display` (width * height, or more
    // where the planes are padded).
    plane_stride: u32,
    // Texels from one row of `codes` to the next: the width padded to the
    // 256-byte pitch of a buffer-to-texture copy (a view of a wider panel:
    // the panel's).
    row_texels: u32,
    // The frame's first texel in `codes` (a view: its region's corner).
    base_texel: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<storage, read> display: array<f32>;
// 3 x 255 thresholds, channel-major, then 3 x 4097 start codes (as f32):
// the code of i/4096 for i in 0..=4096, where the search for any x in bin
// i starts (present/transfer.rs keeps the same two tables).
@group(0) @binding(1) var<storage, read> thresholds: array<f32>;
@group(0) @binding(2) var<uniform> frame: Frame;
// One packed RGBA8 texel per pixel, red in the low byte, rows padded.
@group(0) @binding(3) var<storage, read_write> codes: array<u32>;

fn is_nan(x: f32) -> bool {
    // By the bits: a shader compiler may assume finite floats.
    return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u;
}

const BINS: f32 = 4096.0;

fn code(channel: u32, x: f32) -> u32 {
    if (is_nan(x) || x <= 0.0) {
        return 0u;
    }
    let base = channel * 255u;
    // Scaling by a power of two is exact, so bin/4096 <= x; +inf lands in
    // the last bin.
    let bin = u32(min(x * BINS, BINS));
    var n = u32(thresholds[3u * 255u + channel * 4097u + bin]);
    // A few steps (several only in the steep dark end of a gamma curve).
    loop {
        if (n >= 255u || thresholds[base + n] > x) {
            break;
        }
        n = n + 1u;
    }
    return n;
}

// Values that are not finite (NaN, ±inf), counted: a network that
// overflows is an engine failure, as on the host path, not black pixels.
@group(0) @binding(4) var<storage, read_write> non_finite: atomic<u32>;

fn is_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let pixel = id.x + id.y * 65535u * 64u;
    if (pixel >= frame.width * frame.height) {
        return;
    }
    let x = vec3<f32>(
        display[pixel],
        display[frame.plane_stride + pixel],
        display[2u * frame.plane_stride + pixel],
    );
    if (!(is_finite(x.x) && is_finite(x.y) && is_finite(x.z))) {
        atomicAdd(&non_finite, 1u);
    }
    let r = code(0u, x.x);
    let g = code(1u, x.y);
    let b = code(2u, x.z);
    let row = pixel / frame.width;
    codes[frame.base_texel + row * frame.row_texels + pixel - row * frame.width] =
        r | (g << 8u) | (b << 16u) | (255u << 24u);
}
