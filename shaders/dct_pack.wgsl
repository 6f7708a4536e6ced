// Real sequences to the complex input of an FFT, two sequences a pair (one as
// the real part, one as the imaginary: one complex FFT transforms both), for
// the DCT-II and DCT-III of length N by one FFT of length N (Makhoul 1980;
// runtime/gpu/src/fft.rs). Sequences are the rows or the columns of planes:
// sequence s starts at (s / group)·plane + (s % group)·group_stride and its
// elements lie elem_stride apart. CPU twin: the mirrored-grid filter of
// realfft (nedrt-optics' WienerPlan), and the direct sums in fft.rs's tests.

struct Seqs {
    n: u32,
    count: u32,         // real sequences
    pairs: u32,         // ⌈count / 2⌉
    group: u32,
    plane: u32,
    group_stride: u32,
    elem_stride: u32,
    pair_stride: u32,   // complex: pair p, element j at p·pair_stride + j·celem_stride
    celem_stride: u32,
    pair_fastest: u32,  // 1: adjacent threads take adjacent pairs (columns)
    use_gain: u32,      // dct_unpack.wgsl: multiply by the gain at the output
    pad: u32,
}

@group(0) @binding(0) var<storage, read> q: Seqs;
@group(0) @binding(1) var<storage, read> real: array<f32>;
@group(0) @binding(2) var<storage, read_write> cplx: array<vec2<f32>>;
// e^{-iπk/(2N)}, k = 0..N, computed in f64 on the host.
@group(0) @binding(3) var<storage, read> quarter: array<vec2<f32>>;

fn seq_base(s: u32) -> u32 {
    return (s / q.group) * q.plane + (s % q.group) * q.group_stride;
}

// The thread's pair and element.
fn pair_elem(thread: u32) -> vec2<u32> {
    if q.pair_fastest == 1u {
        return vec2<u32>(thread % q.pairs, thread / q.pairs);
    }
    return vec2<u32>(thread / q.n, thread % q.n);
}

// Makhoul's order: v_j = x_{2j} for 2j < N, else x_{2(N−1−j)+1}.
fn perm(j: u32) -> u32 {
    return select(2u * (q.n - 1u - j) + 1u, 2u * j, 2u * j < q.n);
}

fn value(s: u32, i: u32) -> f32 {
    if s >= q.count {
        return 0.0;
    }
    return real[seq_base(s) + i * q.elem_stride];
}

// DCT-II's input: z_j = v_j(a) + i·v_j(b).
@compute @workgroup_size(64)
fn dct2_pack(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let thread = gid.x + gid.y * groups.x * 64u;
    if thread >= q.pairs * q.n {
        return;
    }
    let pj = pair_elem(thread);
    let i = perm(pj.y);
    cplx[pj.x * q.pair_stride + pj.y * q.celem_stride] =
        vec2<f32>(value(2u * pj.x, i), value(2u * pj.x + 1u, i));
}

// DCT-III's input from coefficients C: V_k = e^{iπk/(2N)}·(C_k − i·C_{N−k})
// (C_N = 0) per sequence, z_k = V_k(a) + i·V_k(b); its inverse FFT is
// N·(v(a) + i·v(b)).
@compute @workgroup_size(64)
fn dct3_pack(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let thread = gid.x + gid.y * groups.x * 64u;
    if thread >= q.pairs * q.n {
        return;
    }
    let pj = pair_elem(thread);
    let k = pj.y;
    let e = quarter[k];
    // e^{+iπk/2N} is the table's conjugate.
    let up = vec2<f32>(e.x, -e.y);
    var z = vec2<f32>(0.0, 0.0);
    for (var h = 0u; h < 2u; h++) {
        let s = 2u * pj.x + h;
        let c = value(s, k);
        let c_rev = select(value(s, select(q.n - k, 0u, k == 0u)), 0.0, k == 0u);
        // up·(c − i·c_rev)
        let vv = vec2<f32>(up.x * c + up.y * c_rev, up.y * c - up.x * c_rev);
        // z += vv (h = 0) or i·vv (h = 1)
        z += select(vv, vec2<f32>(-vv.y, vv.x), h == 1u);
    }
    cplx[pj.x * q.pair_stride + k * q.celem_stride] = z;
}
