// The unrolled preprocessor's per-pixel passes (runtime/gpu/src/unrolled.rs),
// the device twin of nedrt-optics' `SplitSteps`. The DCT filter makes, into
// `ax` and `c`: at the start the lsq image (ax) and b = Σ_D A_Dᵀ t_D / L (c);
// per step the data step x = L (N + ρ)⁻¹ v (ax), from v = b + ρ/L (z − u),
// then N r / L (ax). Per pixel:
//   start:     z = clamp(ax), u = 0, b = c, v = b + share · z
//   relax:     r = α ax + (1 − α) z;  planes = [r + u, u, ·]
//   gradient:  planes[2C..] = ax − b                         (∇f(r) / L)
//   constrain: z⁺ = clamp(r + u + aux), u⁺ = u + r − z⁺, v = b + share_next (z⁺ − u⁺)
//   emit:      aux = z
// `work` holds z, u and b (C planes each); `aux` is the step's correction
// (zeros for a classical step) or, to emit, the display image.

struct Frame {
    plane: u32,
    channels: u32,
    groups_x: u32,          // workgroups along x (pixel = x + y·groups_x·64)
    relaxation: f32,
    share: f32,             // this step's ρ / L
    share_next: f32,        // the next step's (0 after the last)
}

@group(0) @binding(0) var<storage, read> f: Frame;
@group(0) @binding(1) var<storage, read_write> work: array<f32>;
@group(0) @binding(2) var<storage, read_write> v: array<f32>;
@group(0) @binding(3) var<storage, read_write> r: array<f32>;
@group(0) @binding(4) var<storage, read> ax: array<f32>;
@group(0) @binding(5) var<storage, read> c: array<f32>;
@group(0) @binding(6) var<storage, read_write> planes: array<f32>;
@group(0) @binding(7) var<storage, read_write> aux: array<f32>;

fn pixel(gid: vec3<u32>) -> u32 {
    return gid.x + gid.y * f.groups_x * 64u;
}

// Offsets into `work` of z, u and b for the value at `at`.
fn z_at(at: u32) -> u32 { return at; }
fn u_at(at: u32) -> u32 { return f.channels * f.plane + at; }
fn b_at(at: u32) -> u32 { return 2u * f.channels * f.plane + at; }

@compute @workgroup_size(64)
fn start(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel(gid);
    if i >= f.plane {
        return;
    }
    let at = gid.z * f.plane + i;
    let s = clamp(ax[at], 0.0, 1.0);
    work[z_at(at)] = s;
    work[u_at(at)] = 0.0;
    work[b_at(at)] = c[at];
    v[at] = c[at] + f.share * s;
}

@compute @workgroup_size(64)
fn relax(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel(gid);
    if i >= f.plane {
        return;
    }
    let at = gid.z * f.plane + i;
    let a = f.relaxation;
    let rv = a * ax[at] + (1.0 - a) * work[z_at(at)];
    let uv = work[u_at(at)];
    r[at] = rv;
    planes[at] = rv + uv;
    planes[f.channels * f.plane + at] = uv;
}

@compute @workgroup_size(64)
fn gradient(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel(gid);
    if i >= f.plane {
        return;
    }
    let at = gid.z * f.plane + i;
    planes[2u * f.channels * f.plane + at] = ax[at] - work[b_at(at)];
}

@compute @workgroup_size(64)
fn constrain(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel(gid);
    if i >= f.plane {
        return;
    }
    let at = gid.z * f.plane + i;
    let rv = r[at];
    let uv = work[u_at(at)];
    let next = clamp(rv + uv + aux[at], 0.0, 1.0);
    let un = uv + rv - next;
    work[z_at(at)] = next;
    work[u_at(at)] = un;
    v[at] = work[b_at(at)] + f.share_next * (next - un);
}

@compute @workgroup_size(64)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = pixel(gid);
    if i >= f.plane {
        return;
    }
    let at = gid.z * f.plane + i;
    aux[at] = work[z_at(at)];
}
