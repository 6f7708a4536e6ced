// The FFT of a pair of real sequences back to each sequence's DCT-II
// coefficients (optionally times a gain: the filter's spectrum), or the
// inverse FFT of a DCT-III pair back to the two real sequences in their
// natural order (runtime/gpu/src/fft.rs; dct_pack.wgsl has the layout).

@group(0) @binding(1) var<storage, read> cplx: array<vec2<f32>>;
@group(0) @binding(2) var<storage, read_write> real: array<f32>;
@group(0) @binding(3) var<storage, read> quarter: array<vec2<f32>>;
// Per output value (the real layout), where use_gain is 1.
@group(0) @binding(4) var<storage, read> gain: array<f32>;

fn put(s: u32, i: u32, v: f32) {
    if s < q.count {
        let at = seq_base(s) + i * q.elem_stride;
        real[at] = select(v, v * gain[at], q.use_gain == 1u);
    }
}

// Z = FFT(v(a) + i·v(b)): V(a)_k = (Z_k + Z̄_{N−k})/2, V(b)_k = (Z_k − Z̄_{N−k})/(2i),
// C_k = Re(e^{−iπk/(2N)}·V_k).
@compute @workgroup_size(64)
fn dct2_unpack(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let thread = gid.x + gid.y * groups.x * 64u;
    if thread >= q.pairs * q.n {
        return;
    }
    let pj = pair_elem(thread);
    let k = pj.y;
    let z = cplx[pj.x * q.pair_stride + k * q.celem_stride];
    let zr = cplx[pj.x * q.pair_stride + ((q.n - k) % q.n) * q.celem_stride];
    let zc = vec2<f32>(zr.x, -zr.y);
    let va = 0.5 * (z + zc);
    let d = z - zc;
    let vb = vec2<f32>(0.5 * d.y, -0.5 * d.x);
    let e = quarter[k];
    // Re((e.x + i e.y)(v.x + i v.y)) with e = e^{−iπk/2N}.
    put(2u * pj.x, k, e.x * va.x - e.y * va.y);
    put(2u * pj.x + 1u, k, e.x * vb.x - e.y * vb.y);
}

// Z = N·(v(a) + i·v(b)) from the inverse FFT: x_{perm(j)} = v_j.
@compute @workgroup_size(64)
fn dct3_unpack(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let thread = gid.x + gid.y * groups.x * 64u;
    if thread >= q.pairs * q.n {
        return;
    }
    let pj = pair_elem(thread);
    let z = cplx[pj.x * q.pair_stride + pj.y * q.celem_stride] / f32(q.n);
    let i = perm(pj.y);
    put(2u * pj.x, i, z.x);
    put(2u * pj.x + 1u, i, z.y);
}
