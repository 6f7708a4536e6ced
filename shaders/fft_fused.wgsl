// The workgroup-memory FFT (runtime/gpu/src/fft/wgsl.rs generates the rest
// per length: N, WG, `sm` in front; fft_fwd, fft_inv and gain_and_repack
// behind). One workgroup per pair of real sequences (DCT entries) or per
// complex sequence (fft_*): loaded into `sm` once, every pass there, written
// once. dct_seqs.wgsl (pasted in front) has the sequences' layout; the DCT
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

// The workgroup's index in a grid of rows of groups (more than 65,535 pairs).
fn group_index(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}

// Loads the pair (a, b) in Makhoul's order: sm[j] = x_a[perm j] + i·x_b[perm j].
fn load_pair(lid: u32, ba: u32, bb: u32, has_b: bool) {
    for (var j = lid; j < N; j += WG) {
        let i = perm(j) * q.elem_stride;
        sm[j] = vec2<f32>(src[ba + i], select(0.0, src[bb + i], has_b));
    }
}

// Z = FFT(v_a + i·v_b) in sm → (C_a[k], C_b[k]), each sequence's DCT-II:
// V_a = (Z_k + Z̄_{N−k})/2, V_b = (Z_k − Z̄_{N−k})/(2i), C = Re(e^{−iπk/2N}·V).
fn dct2_coeffs(k: u32) -> vec2<f32> {
    let z = sm[k];
    let zc = conj(sm[(N - k) % N]);
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

// dct_filter's value at k: the DCT-II pair's coefficients × gain, repacked.
fn repacked(k: u32, ba: u32, bb: u32) -> vec2<f32> {
    let c = dct2_coeffs(k) * gains(k, ba, bb);
    var c_rev = vec2<f32>(0.0, 0.0);
    if k != 0u {
        c_rev = dct2_coeffs(N - k) * gains(N - k, ba, bb);
    }
    return dct3_input(k, c, c_rev);
}

fn put(base: u32, k: u32, v: f32) {
    let at = base + k * q.elem_stride;
    dst[at] = select(v, v * gain[at], q.use_gain == 1u);
}

// Writes the inverse FFT of a DCT-III pair (N·(v_a + i·v_b) in sm) in natural order.
fn store_dct3(lid: u32, ba: u32, bb: u32, has_b: bool) {
    for (var j = lid; j < N; j += WG) {
        let z = sm[j] / f32(N);
        let i = perm(j);
        put(ba, i, z.x);
        if has_b {
            put(bb, i, z.y);
        }
    }
}

// The pair's sequences' starts; b is a's when the count is odd (never written).
fn pair_bases(pair: u32) -> vec3<u32> {
    let sb = 2u * pair + 1u;
    return vec3<u32>(seq_base(2u * pair), seq_base(min(sb, q.count - 1u)), u32(sb < q.count));
}

@compute @workgroup_size(WG)
fn dct2(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let pair = group_index(wid, nwg);
    if pair >= q.pairs {
        return;
    }
    let b = pair_bases(pair);
    load_pair(lid, b.x, b.y, b.z == 1u);
    workgroupBarrier();
    fft_fwd(lid);
    for (var k = lid; k < N; k += WG) {
        let c = dct2_coeffs(k);
        put(b.x, k, c.x);
        if b.z == 1u {
            put(b.y, k, c.y);
        }
    }
}

// DCT-II, × gain, DCT-III of a pair: the filter's second axis in one pass.
@compute @workgroup_size(WG)
fn dct_filter(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let pair = group_index(wid, nwg);
    if pair >= q.pairs {
        return;
    }
    let b = pair_bases(pair);
    load_pair(lid, b.x, b.y, b.z == 1u);
    workgroupBarrier();
    fft_fwd(lid);
    gain_and_repack(lid, b.x, b.y);
    fft_inv(lid);
    store_dct3(lid, b.x, b.y, b.z == 1u);
}

// DCT-II coefficients of a pair (in src) → their DCT-III (× gain where use_gain).
@compute @workgroup_size(WG)
fn dct3(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let pair = group_index(wid, nwg);
    if pair >= q.pairs {
        return;
    }
    let b = pair_bases(pair);
    let has_b = b.z == 1u;
    for (var k = lid; k < N; k += WG) {
        let at = k * q.elem_stride;
        let c = vec2<f32>(src[b.x + at], select(0.0, src[b.y + at], has_b));
        var c_rev = vec2<f32>(0.0, 0.0);
        if k != 0u {
            let rev = (N - k) * q.elem_stride;
            c_rev = vec2<f32>(src[b.x + rev], select(0.0, src[b.y + rev], has_b));
        }
        sm[k] = dct3_input(k, c, c_rev);
    }
    workgroupBarrier();
    fft_inv(lid);
    store_dct3(lid, b.x, b.y, has_b);
}

// Complex sequences (interleaved f32 pairs; `Seqs` counts complex values):
// sequence = the workgroup, src → dst.
fn fft_load(lid: u32, base: u32) {
    for (var j = lid; j < N; j += WG) {
        let at = 2u * (base + j * q.elem_stride);
        sm[j] = vec2<f32>(src[at], src[at + 1u]);
    }
}

fn fft_store(lid: u32, base: u32) {
    for (var j = lid; j < N; j += WG) {
        let at = 2u * (base + j * q.elem_stride);
        dst[at] = sm[j].x;
        dst[at + 1u] = sm[j].y;
    }
}

@compute @workgroup_size(WG)
fn fft_forward(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let s = group_index(wid, nwg);
    if s >= q.count {
        return;
    }
    fft_load(lid, seq_base(s));
    workgroupBarrier();
    fft_fwd(lid);
    fft_store(lid, seq_base(s));
}

@compute @workgroup_size(WG)
fn fft_inverse(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let s = group_index(wid, nwg);
    if s >= q.count {
        return;
    }
    fft_load(lid, seq_base(s));
    workgroupBarrier();
    fft_inv(lid);
    fft_store(lid, seq_base(s));
}
