// The refinement's warm start on the device (runtime/gpu/src/refine.rs,
// issue 54): whether this frame is the last one still, as nedrt-optics'
// `SolvedPrefilter::still_states` decides on the host: the RMS change of
// every value from the last frame at most `still_rms` (a quarter of an
// 8-bit code). `change` sums the squared change per workgroup and keeps
// this frame as the next one's last; `decide` adds the sums and sets the
// flag `start` (fista.wgsl) reads: 1 goes on from the last frame's x, y
// and t, 0 starts afresh. `state` holds per channel [1/L, t, m, u], then
// [warm, had_last, still_rms, 0].

struct Frame {
    plane: u32,
    channels: u32,
    groups_per_plane: u32,
    groups_x: u32,
}

@group(0) @binding(0) var<storage, read> f: Frame;
@group(0) @binding(1) var<storage, read> frame: array<f32>;
@group(0) @binding(2) var<storage, read_write> last: array<f32>;
@group(0) @binding(3) var<storage, read_write> partials: array<f32>;
@group(0) @binding(4) var<storage, read_write> state: array<f32>;

var<workgroup> sums: array<f32, 256>;

@compute @workgroup_size(64)
fn change(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
) {
    let i = gid.x + gid.y * f.groups_x * 64u;
    var term = 0.0;
    if i < f.plane {
        let at = gid.z * f.plane + i;
        let d = frame[at] - last[at];
        term = d * d;
        last[at] = frame[at];
    }
    sums[lane] = term;
    workgroupBarrier();
    for (var half = 32u; half > 0u; half >>= 1u) {
        if lane < half {
            sums[lane] += sums[lane + half];
        }
        workgroupBarrier();
    }
    if lane == 0u {
        partials[gid.z * f.groups_per_plane + wid.x + wid.y * f.groups_x] = sums[0];
    }
}

// One workgroup: every channel's sums.
@compute @workgroup_size(256)
fn decide(@builtin(local_invocation_index) lane: u32) {
    let n = f.groups_per_plane * f.channels;
    var acc = 0.0;
    for (var k = lane; k < n; k += 256u) {
        acc += partials[k];
    }
    sums[lane] = acc;
    workgroupBarrier();
    for (var half = 128u; half > 0u; half >>= 1u) {
        if lane < half {
            sums[lane] += sums[lane + half];
        }
        workgroupBarrier();
    }
    if lane == 0u {
        let at = 4u * f.channels;
        let rms = sqrt(sums[0] / f32(f.plane * f.channels));
        let still = state[at + 1u] > 0.5 && rms <= state[at + 2u];
        state[at] = select(0.0, 1.0, still);
        state[at + 1u] = 1.0;
    }
}
