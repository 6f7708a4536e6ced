// refine:K's steps fused into the DCT filter's row passes (issue 56, item 3;
// runtime/gpu/src/refine.rs appends this to the rows' generated module,
// fft_fused.wgsl). A step is then four dispatches instead of six:
//   dct2_advance: y = x⁺ + m(x⁺ − x), x = x⁺ (fista.wgsl's advance) as the
//     rows' DCT-II loads y; src is x⁺, dst the filter's row buffer;
//   the columns' DCT-II × gain, DCT-III (unchanged);
//   dct3_project: the rows' DCT-III gives Ay, and as it is stored
//     x⁺ = clamp(y − (Ay − b)/L) (fista.wgsl's project) is written to dst;
//     the restart test's sum Σ (y − x⁺)(x⁺ − x) is written per row;
//   reduce (fista.wgsl), over the rows' sums.
// Each pixel is loaded and stored by exactly one workgroup, so the rows'
// kernels may write y and x in place. The channel of row s is s / q.group.

@group(1) @binding(0) var<storage, read> r_state: array<f32>;
@group(1) @binding(1) var<storage, read_write> r_y: array<f32>;
@group(1) @binding(2) var<storage, read_write> r_x: array<f32>;
@group(1) @binding(3) var<storage, read> r_b: array<f32>;
// Per row (sequence): its share of the restart test's sum.
@group(1) @binding(4) var<storage, read_write> r_partials: array<f32>;

// The momentum step at `at` of row `seq`: y (returned and written), x = x⁺.
fn advanced(seq: u32, at: u32) -> f32 {
    let next = src[at];
    let v = next + r_state[4u * (seq / q.group) + 2u] * (next - r_x[at]);
    r_y[at] = v;
    r_x[at] = next;
    return v;
}

// The projection at `at` of row `seq` given Ay there: writes x⁺, returns the
// restart test's term.
fn projected(seq: u32, at: u32, ay: f32) -> f32 {
    let yv = r_y[at];
    let next = clamp(yv - r_state[4u * (seq / q.group)] * (ay - r_b[at]), 0.0, 1.0);
    dst[at] = next;
    return (yv - next) * (next - r_x[at]);
}

@compute @workgroup_size(WG)
fn dct2_advance(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let first = group_index(wid, nwg) * P;
    if first >= q.pairs {
        return;
    }
    let p = lid % P;
    let pair = first + p;
    let b = pair_bases(pair);
    for (var t = lid; t < N * P; t += WG) {
        let j = t / P;
        var v = vec2<f32>(0.0, 0.0);
        if b.w == 1u {
            let i = perm(j) * q.elem_stride;
            v.x = advanced(2u * pair, b.x + i);
            if b.z == 1u {
                v.y = advanced(2u * pair + 1u, b.y + i);
            }
        }
        sm[p * N + j] = v;
    }
    workgroupBarrier();
    fft_fwd(lid);
    store_dct2(lid, first);
}

@compute @workgroup_size(WG)
fn dct3_project(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let first = group_index(wid, nwg) * P;
    if first >= q.pairs {
        return;
    }
    load_dct3(lid, first);
    workgroupBarrier();
    fft_inv(lid);
    let p = lid % P;
    let pair = first + p;
    let b = pair_bases(pair);
    // A thread's items are all of pair p: its terms of rows a and b.
    var acc = vec2<f32>(0.0, 0.0);
    for (var t = lid; t < N * P; t += WG) {
        let j = t / P;
        if b.w == 1u {
            let z = sm[p * N + j] / f32(N);
            let i = perm(j) * q.elem_stride;
            acc.x += projected(2u * pair, b.x + i, z.x);
            if b.z == 1u {
                acc.y += projected(2u * pair + 1u, b.y + i, z.y);
            }
        }
    }
    // Each pair's sums over its threads (lid ≡ p mod P) through sm, which
    // the store has finished reading: a tree over k = lid / P.
    workgroupBarrier();
    let live = min(WG, N * P);
    if lid < live {
        sm[lid] = acc;
    }
    workgroupBarrier();
    var width = live / P;
    loop {
        if width <= 1u {
            break;
        }
        let half = (width + 1u) / 2u;
        if lid / P + half < width {
            sm[lid] += sm[lid + half * P];
        }
        workgroupBarrier();
        width = half;
    }
    if lid < P && b.w == 1u {
        r_partials[2u * pair] = sm[lid].x;
        if b.z == 1u {
            r_partials[2u * pair + 1u] = sm[lid].y;
        }
    }
}
