// The workgroup-memory FFT (runtime/gpu/src/fft/wgsl.rs generates the rest
// per length: N, WG, P, `sm` in front; fft_fwd, fft_inv and gain_and_repack
// behind). One workgroup per P pairs of real sequences (DCT entries) or P
// complex sequences (fft_*), sequence p at sm[p·N…]: loaded into `sm` once,
// every pass there, written once. Where the sequences are columns, P > 1
// makes the loads and stores coalesce: item t of a loop over the P·N values
// is sequence t % P, element t / P, so adjacent threads touch adjacent
// columns of one row. dct_seqs.wgsl (pasted in front) has the sequences' layout; the DCT
// by one complex FFT is Makhoul's (dct_pack.wgsl, dct_unpack.wgsl are the
// multi-pass twins). CPU twins: rustfft and the mirrored-grid filter (tests
// in fft.rs).

@group(0) @binding(1) var<storage, read> src: array<f32>;
@group(0) @binding(2) var<storage, read_write> dst: array<f32>;
// e^{-2πi m/N} and e^{-iπk/(2N)}, m, k < N, computed in f64 on the host.
@group(0) @binding(3) var<storage, read> twiddle: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read> quarter: array<vec2<f32>>;
// Per real value (the real layout), where use_gain is 1.
@group(0) @binding(5) var<storage, read> gain: array<f32>;

fn cmul(a: vec2<f32>, b: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

fn conj(a: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x, -a.y);
}

// The workgroup's index in a grid of rows of groups (more than 65,535 of them).
fn group_index(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}

// The pair's sequences' starts; b is a's when the count is odd (never
// written); w = 1 where the pair exists (the last workgroup's may not).
fn pair_bases(pair: u32) -> vec4<u32> {
    let sb = 2u * pair + 1u;
    let last = q.count - 1u;
    return vec4<u32>(seq_base(min(2u * pair, last)), seq_base(min(sb, last)), u32(sb < q.count),
                     u32(pair < q.pairs));
}

// Loads the workgroup's pairs (a, b) in Makhoul's order:
// sm[p·N + j] = x_a[perm j] + i·x_b[perm j]. WG is a multiple of P, so a
// thread's items are all of one pair, p = lid % P.
fn load_pairs(lid: u32, first: u32) {
    let p = lid % P;
    let b = pair_bases(first + p);
    for (var t = lid; t < N * P; t += WG) {
        let j = t / P;
        var v = vec2<f32>(0.0, 0.0);
        if b.w == 1u {
            let i = perm(j) * q.elem_stride;
            v = vec2<f32>(src[b.x + i], select(0.0, src[b.y + i], b.z == 1u));
        }
        sm[p * N + j] = v;
    }
}

// Z = FFT(v_a + i·v_b) in sm[o…] → (C_a[k], C_b[k]), each sequence's DCT-II:
// V_a = (Z_k + Z̄_{N−k})/2, V_b = (Z_k − Z̄_{N−k})/(2i), C = Re(e^{−iπk/2N}·V).
fn dct2_coeffs(o: u32, k: u32) -> vec2<f32> {
    let z = sm[o + k];
    let zc = conj(sm[o + (N - k) % N]);
    let va = 0.5 * (z + zc);
    let d = z - zc;
    let vb = vec2<f32>(0.5 * d.y, -0.5 * d.x);
    let e = quarter[k];
    return vec2<f32>(e.x * va.x - e.y * va.y, e.x * vb.x - e.y * vb.y);
}

// The DCT-III's FFT input at k from the pair's coefficients c = (C_a[k],
// C_b[k]) and c_rev = (C_a[N−k], C_b[N−k]) (0 at k = 0):
// V_k = e^{iπk/2N}·(C_k − i·C_{N−k}) per sequence, z = V_a + i·V_b.
fn dct3_input(k: u32, c: vec2<f32>, c_rev: vec2<f32>) -> vec2<f32> {
    let e = quarter[k];
    let up = vec2<f32>(e.x, -e.y);
    let va = vec2<f32>(up.x * c.x + up.y * c_rev.x, up.y * c.x - up.x * c_rev.x);
    let vb = vec2<f32>(up.x * c.y + up.y * c_rev.y, up.y * c.y - up.x * c_rev.y);
    return va + vec2<f32>(-vb.y, vb.x);
}

// The gains of the pair at element k.
fn gains(k: u32, ba: u32, bb: u32) -> vec2<f32> {
    let at = k * q.elem_stride;
    return vec2<f32>(gain[ba + at], gain[bb + at]);
}

// dct_filter's value at element k of pair p (its bases b): the DCT-II
// pair's coefficients × gain, repacked (0 for a pair that does not exist).
fn repacked(k: u32, p: u32, b: vec4<u32>) -> vec2<f32> {
    if b.w == 0u {
        return vec2<f32>(0.0, 0.0);
    }
    let o = p * N;
    let c = dct2_coeffs(o, k) * gains(k, b.x, b.y);
    var c_rev = vec2<f32>(0.0, 0.0);
    if k != 0u {
        c_rev = dct2_coeffs(o, N - k) * gains(N - k, b.x, b.y);
    }
    return dct3_input(k, c, c_rev);
}

fn put(base: u32, k: u32, v: f32) {
    let at = base + k * q.elem_stride;
    dst[at] = select(v, v * gain[at], q.use_gain == 1u);
}

// Writes the inverse FFTs of the DCT-III pairs (N·(v_a + i·v_b) in sm) in
// natural order.
fn store_dct3(lid: u32, first: u32) {
    let p = lid % P;
    let b = pair_bases(first + p);
    for (var t = lid; t < N * P; t += WG) {
        let j = t / P;
        if b.w == 1u {
            let z = sm[p * N + j] / f32(N);
            let i = perm(j);
            put(b.x, i, z.x);
            if b.z == 1u {
                put(b.y, i, z.y);
            }
        }
    }
}

// Writes the DCT-II coefficients of the pairs (their FFTs in sm).
fn store_dct2(lid: u32, first: u32) {
    let p = lid % P;
    let b = pair_bases(first + p);
    for (var t = lid; t < N * P; t += WG) {
        let k = t / P;
        if b.w == 1u {
            let c = dct2_coeffs(p * N, k);
            put(b.x, k, c.x);
            if b.z == 1u {
                put(b.y, k, c.y);
            }
        }
    }
}

// Loads the DCT-III's FFT input of the pairs from their DCT-II coefficients in src.
fn load_dct3(lid: u32, first: u32) {
    let p = lid % P;
    let b = pair_bases(first + p);
    for (var t = lid; t < N * P; t += WG) {
        let k = t / P;
        var v = vec2<f32>(0.0, 0.0);
        if b.w == 1u {
            let has_b = b.z == 1u;
            let at = k * q.elem_stride;
            let c = vec2<f32>(src[b.x + at], select(0.0, src[b.y + at], has_b));
            var c_rev = vec2<f32>(0.0, 0.0);
            if k != 0u {
                let rev = (N - k) * q.elem_stride;
                c_rev = vec2<f32>(src[b.x + rev], select(0.0, src[b.y + rev], has_b));
            }
            v = dct3_input(k, c, c_rev);
        }
        sm[p * N + k] = v;
    }
}

@compute @workgroup_size(WG)
fn dct2(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let first = group_index(wid, nwg) * P;
    if first >= q.pairs {
        return;
    }
    load_pairs(lid, first);
    workgroupBarrier();
    fft_fwd(lid);
    store_dct2(lid, first);
}

// DCT-II, × gain, DCT-III of the pairs: the filter's second axis in one pass.
@compute @workgroup_size(WG)
fn dct_filter(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let first = group_index(wid, nwg) * P;
    if first >= q.pairs {
        return;
    }
    load_pairs(lid, first);
    workgroupBarrier();
    fft_fwd(lid);
    gain_and_repack(lid, first);
    fft_inv(lid);
    store_dct3(lid, first);
}

// DCT-II coefficients of the pairs (in src) → their DCT-III (× gain where use_gain).
@compute @workgroup_size(WG)
fn dct3(
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
    store_dct3(lid, first);
}

// Complex sequences (interleaved f32 pairs; `Seqs` counts complex values):
// sequences first … first + P − 1, src → dst.
fn fft_load(lid: u32, first: u32) {
    let p = lid % P;
    let base = seq_base(min(first + p, q.count - 1u));
    for (var t = lid; t < N * P; t += WG) {
        let j = t / P;
        var v = vec2<f32>(0.0, 0.0);
        if first + p < q.count {
            let at = 2u * (base + j * q.elem_stride);
            v = vec2<f32>(src[at], src[at + 1u]);
        }
        sm[p * N + j] = v;
    }
}

fn fft_store(lid: u32, first: u32) {
    let p = lid % P;
    let base = seq_base(min(first + p, q.count - 1u));
    for (var t = lid; t < N * P; t += WG) {
        let j = t / P;
        if first + p < q.count {
            let at = 2u * (base + j * q.elem_stride);
            dst[at] = sm[p * N + j].x;
            dst[at + 1u] = sm[p * N + j].y;
        }
    }
}

@compute @workgroup_size(WG)
fn fft_forward(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let first = group_index(wid, nwg) * P;
    if first >= q.count {
        return;
    }
    fft_load(lid, first);
    workgroupBarrier();
    fft_fwd(lid);
    fft_store(lid, first);
}

@compute @workgroup_size(WG)
fn fft_inverse(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let first = group_index(wid, nwg) * P;
    if first >= q.count {
        return;
    }
    fft_load(lid, first);
    workgroupBarrier();
    fft_inv(lid);
    fft_store(lid, first);
}
