// The split solver's steps on the device (ADMM, runtime/gpu/src/split.rs),
// the same steps as nedrt-optics' `ProblemPlan::split_from` per channel at a
// constant penalty ρ. The DCT filter makes the data step's two parts:
//   c  = Σ_D A_Dᵀ t_D(I) / (N + ρ)          (once a frame, gain set 1)
//   ax = ρ / (N + ρ) · v,  v = z − u         (every step, gain set 2)
// then, per pixel (step):
//   x  = ax + c
//   r  = α x + (1 − α) z                    (relaxation)
//   z⁺ = clamp(r + u, 0, 1),  u⁺ = u + r − z⁺,  v = z⁺ − u⁺
// Planes are `plane` values apart.

struct Frame {
    plane: u32,
    channels: u32,
    groups_x: u32,          // workgroups along x (pixel = x + y·groups_x·64)
    relaxation: f32,
}

@group(0) @binding(0) var<storage, read> f: Frame;
@group(0) @binding(1) var<storage, read_write> z: array<f32>;
@group(0) @binding(2) var<storage, read_write> u: array<f32>;
@group(0) @binding(3) var<storage, read_write> v: array<f32>;
@group(0) @binding(4) var<storage, read> ax: array<f32>;
@group(0) @binding(5) var<storage, read> c: array<f32>;
// The linear prefilter's output at the start; the display image at the end (emit).
@group(0) @binding(6) var<storage, read_write> io: array<f32>;
// still.wgsl's state: after 4 values per channel, [warm, had_last, still_rms, 0].
@group(0) @binding(7) var<storage, read> state: array<f32>;

fn pixel(gid: vec3<u32>) -> u32 {
    return gid.x + gid.y * f.groups_x * 64u;
}

// z = clamp(linear prefilter), u = 0, v = z; a warm start (still.wgsl's
// flag) keeps the last frame's z, u and v instead.
@compute @workgroup_size(64)
fn start(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel(gid);
    if i >= f.plane || state[4u * f.channels] > 0.5 {
        return;
    }
    let at = gid.z * f.plane + i;
    let s = clamp(io[at], 0.0, 1.0);
    z[at] = s;
    u[at] = 0.0;
    v[at] = s;
}

@compute @workgroup_size(64)
fn step(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel(gid);
    if i >= f.plane {
        return;
    }
    let at = gid.z * f.plane + i;
    let a = f.relaxation;
    let zv = z[at];
    let r = a * (ax[at] + c[at]) + (1.0 - a) * zv;
    let uv = u[at];
    let next = clamp(r + uv, 0.0, 1.0);
    let un = uv + r - next;
    z[at] = next;
    u[at] = un;
    v[at] = next - un;
}

// The display image: io (bound to the output) = z.
@compute @workgroup_size(64)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel(gid);
    if i >= f.plane {
        return;
    }
    let at = gid.z * f.plane + i;
    io[at] = z[at];
}
