// Real sequences to the complex input of an FFT, two sequences a pair (one as
// the real part, one as the imaginary: one complex FFT transforms both), for
// the DCT-II and DCT-III of length N by one FFT of length N (Makhoul 1980;
// runtime/gpu/src/fft.rs). Sequences are the rows or the columns of planes:
// sequence s starts at (s / group)·plane + (s % group)·group_stride and its
// elements lie elem_stride apart (dct_seqs.wgsl). CPU twin: the mirrored-grid filter of
// realfft (nedrt-optics' WienerPlan), and the direct sums in fft.rs's tests.

@group(0) @binding(1) var<storage, read> real: array<f32>;
@group(0) @binding(2) var<storage, read_write> cplx: array<vec2<f32>>;
// e^{-iπk/(2N)}, k = 0..N, computed in f64 on the host.
@group(0) @binding(3) var<storage, read> quarter: array<vec2<f32>>;

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
