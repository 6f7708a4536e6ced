// The refinement's projected-gradient steps on the device (FISTA with
// gradient restart, O'Donoghue & Candès 2015; runtime/gpu/src/refine.rs), the
// same steps as nedrt-optics' `ProblemPlan::fista` per channel: the gradient
// g = Ay − b comes from the DCT filter (the objective's normal operator A),
// then
//   x⁺ = clamp(y − g/L, 0, 1)                 (project)
//   u  = Σ (y − x⁺)(x⁺ − x)                   (project's partial sums, reduce)
//   restart if u > 0: t⁺ = 1, m = 0; else t⁺ = (1 + √(1 + 4t²))/2, m = (t − 1)/t⁺
//   y = x⁺ + m(x⁺ − x), x = x⁺                (advance)
// `state` holds per channel [1/L, t, m, u], then still.wgsl's [warm, had_last,
// still_rms, 0]. Planes are `plane` values apart.

struct Frame {
    plane: u32,
    channels: u32,
    groups_per_plane: u32,  // project's workgroups per channel (its partial sums)
    groups_x: u32,          // project's workgroups along x (pixel = x + y·groups_x·64)
}

@group(0) @binding(0) var<storage, read> f: Frame;
@group(0) @binding(1) var<storage, read_write> state: array<f32>;
@group(0) @binding(2) var<storage, read_write> y: array<f32>;
@group(0) @binding(3) var<storage, read_write> x: array<f32>;
// x⁺; the linear prefilter's output at the start; the display image at the end (emit).
@group(0) @binding(4) var<storage, read_write> xn: array<f32>;
@group(0) @binding(5) var<storage, read> ay: array<f32>;
@group(0) @binding(6) var<storage, read> b: array<f32>;
@group(0) @binding(7) var<storage, read_write> partials: array<f32>;

var<workgroup> sums: array<f32, 256>;

fn pixel(gid: vec3<u32>) -> u32 {
    return gid.x + gid.y * f.groups_x * 64u;
}

// x = y = clamp(linear prefilter), t = 1; a warm start (still.wgsl's flag,
// after the channels' states) keeps the last frame's x, y and t instead.
@compute @workgroup_size(64)
fn start(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel(gid);
    if i >= f.plane || state[4u * f.channels] > 0.5 {
        return;
    }
    let at = gid.z * f.plane + i;
    let v = clamp(xn[at], 0.0, 1.0);
    x[at] = v;
    y[at] = v;
    if i == 0u {
        state[4u * gid.z + 1u] = 1.0;
    }
}

@compute @workgroup_size(64)
fn project(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
) {
    let i = pixel(gid);
    var term = 0.0;
    if i < f.plane {
        let at = gid.z * f.plane + i;
        let yv = y[at];
        let next = clamp(yv - state[4u * gid.z] * (ay[at] - b[at]), 0.0, 1.0);
        xn[at] = next;
        term = (yv - next) * (next - x[at]);
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

// One workgroup per channel: u, then t⁺ and m.
@compute @workgroup_size(256)
fn reduce(@builtin(local_invocation_index) lane: u32, @builtin(workgroup_id) wid: vec3<u32>) {
    let c = wid.z;
    var acc = 0.0;
    for (var k = lane; k < f.groups_per_plane; k += 256u) {
        acc += partials[c * f.groups_per_plane + k];
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
        let u = sums[0];
        let t = state[4u * c + 1u];
        var t_next = 1.0;
        var m = 0.0;
        if !(u > 0.0) {
            t_next = (1.0 + sqrt(1.0 + 4.0 * t * t)) / 2.0;
            m = (t - 1.0) / t_next;
        }
        state[4u * c + 1u] = t_next;
        state[4u * c + 2u] = m;
        state[4u * c + 3u] = u;
    }
}

@compute @workgroup_size(64)
fn advance(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel(gid);
    if i >= f.plane {
        return;
    }
    let at = gid.z * f.plane + i;
    let next = xn[at];
    y[at] = next + state[4u * gid.z + 2u] * (next - x[at]);
    x[at] = next;
}

// The display image: xn (bound to the output) = x.
@compute @workgroup_size(64)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel(gid);
    if i >= f.plane {
        return;
    }
    let at = gid.z * f.plane + i;
    xn[at] = x[at];
}
