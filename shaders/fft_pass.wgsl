// One Stockham pass of a batched complex FFT of length N (runtime/gpu/src/fft.rs):
// radix R = RADIX (an override constant, one pipeline per radix), sub-transforms
// of length ns·R from those of length ns. The passes of N's radices, in any
// order, take `src` to its DFT in natural order, ping-ponging two buffers; no
// bit reversal. Inputs of a butterfly lie N/R apart; outputs ns apart
// (Bainville's formulation). Each thread does one radix-R butterfly.
// CPU twin: rustfft (tests in fft.rs).

struct Pass {
    n: u32,            // transform length
    ns: u32,           // length of the sub-transforms this pass merges
    count: u32,        // sequences (the batch)
    elem_stride: u32,  // complex values between elements of a sequence
    seq_stride: u32,   // complex values between sequences
    seq_fastest: u32,  // 1: adjacent threads take adjacent sequences (columns)
    tw_step: u32,      // N / (ns·R): the twiddle table's step for k·r
    inverse: u32,      // 1: e^{+2πi…} (no 1/N: the caller scales)
    group: u32,        // sequence s starts at (s / group)·plane + (s % group)·seq_stride
    plane: u32,
}

override RADIX: u32 = 2u;
// Radices beyond 5 use the generic odd DFT; fft.rs refuses a prime factor above this.
const MAX_RADIX: u32 = 13u;

@group(0) @binding(0) var<storage, read> p: Pass;
@group(0) @binding(1) var<storage, read> src: array<vec2<f32>>;
@group(0) @binding(2) var<storage, read_write> dst: array<vec2<f32>>;
// e^{-2πi m/N}, m = 0..N, computed in f64 on the host.
@group(0) @binding(3) var<storage, read> twiddle: array<vec2<f32>>;

fn cmul(a: vec2<f32>, b: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

// e^{∓2πi m/N}: the table's value, conjugated for the inverse.
fn tw(m: u32) -> vec2<f32> {
    let w = twiddle[m % p.n];
    return select(w, vec2<f32>(w.x, -w.y), p.inverse == 1u);
}

// Multiplication by -i (forward) or +i (inverse).
fn rot(a: vec2<f32>) -> vec2<f32> {
    return select(vec2<f32>(a.y, -a.x), vec2<f32>(-a.y, a.x), p.inverse == 1u);
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let thread = gid.x + gid.y * groups.x * 64u;
    let per_seq = p.n / RADIX;
    if thread >= per_seq * p.count {
        return;
    }
    var s: u32;
    var t: u32;
    if p.seq_fastest == 1u {
        s = thread % p.count;
        t = thread / p.count;
    } else {
        t = thread % per_seq;
        s = thread / per_seq;
    }
    let base = (s / p.group) * p.plane + (s % p.group) * p.seq_stride;
    let k = t % p.ns;
    var v: array<vec2<f32>, MAX_RADIX>;
    for (var r = 0u; r < RADIX; r++) {
        let x = src[base + (t + r * per_seq) * p.elem_stride];
        v[r] = select(cmul(x, tw(k * r * p.tw_step)), x, r == 0u);
    }
    if RADIX == 2u {
        let a = v[0];
        v[0] = a + v[1];
        v[1] = a - v[1];
    } else if RADIX == 4u {
        let s0 = v[0] + v[2];
        let d0 = v[0] - v[2];
        let s1 = v[1] + v[3];
        let d1 = rot(v[1] - v[3]);
        v[0] = s0 + s1;
        v[1] = d0 + d1;
        v[2] = s0 - s1;
        v[3] = d0 - d1;
    } else {
        // The generic DFT: y_q = Σ_r v_r W^{qr}, W = e^{∓2πi/R} = the table's
        // entry (N/R)·1.
        var y: array<vec2<f32>, MAX_RADIX>;
        let step = p.n / RADIX;
        for (var q = 0u; q < RADIX; q++) {
            var acc = v[0];
            for (var r = 1u; r < RADIX; r++) {
                acc += cmul(v[r], tw(((q * r) % RADIX) * step));
            }
            y[q] = acc;
        }
        v = y;
    }
    let out0 = (t / p.ns) * p.ns * RADIX + k;
    for (var r = 0u; r < RADIX; r++) {
        dst[base + (out0 + r * p.ns) * p.elem_stride] = v[r];
    }
}
