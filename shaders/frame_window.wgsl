// Copies planar f32 rows between the frame the service holds on the device
// and the network's input and output tensors, so a frame that stays on the
// GPU is padded, banded and cropped exactly as Dcnn::run_frame does it on
// the host. Into the network: every row of its input, read from the frame
// with the reflection of Image::pad_reflect past the frame's edges (the
// band's top row is `row_shift`). Out of it: the band's kept rows, written
// into the frame's rows [row0, row0 + rows) and cropped to its width.

struct Window {
    src_width: u32,
    src_height: u32,
    src_plane: u32,
    src_offset: u32,
    dst_width: u32,
    dst_plane: u32,
    dst_offset: u32,
    // Rows of the destination written: [row0, row0 + rows).
    row0: u32,
    rows: u32,
    channels: u32,
    // Source row of destination row y: y + row_shift (mirrored if reflect).
    row_shift: i32,
    reflect: u32,
}

// In a storage buffer, not a uniform one: see layer_bindings.wgsl.
@group(0) @binding(0) var<storage, read> window: Window;
@group(0) @binding(1) var<storage, read> src: array<f32>;
@group(0) @binding(2) var<storage, read_write> dst: array<f32>;

// Image::pad_reflect's index: mirror about the last sample, then hold it.
fn mirror(i: u32, n: u32) -> u32 {
    if (i < n) {
        return i;
    }
    if (i - n + 1u < n) {
        return 2u * (n - 1u) - i;
    }
    return n - 1u;
}

@compute @workgroup_size(16, 16, 1)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let x = id.x;
    let r = id.y;
    let c = id.z;
    if (x >= window.dst_width || r >= window.rows || c >= window.channels) {
        return;
    }
    let y = window.row0 + r;
    var sy = u32(i32(y) + window.row_shift);
    var sx = x;
    if (window.reflect != 0u) {
        sy = mirror(sy, window.src_height);
        sx = mirror(sx, window.src_width);
    }
    dst[window.dst_offset + c * window.dst_plane + y * window.dst_width + x] =
        src[window.src_offset + c * window.src_plane + sy * window.src_width + sx];
}
