// The real sequences of the DCT kernels (dct_pack.wgsl, dct_unpack.wgsl; fft.rs
// pastes this file in front of each): sequences are the rows or the columns of
// planes, sequence s starting at (s / group)·plane + (s % group)·group_stride
// with its elements elem_stride apart; pair p of sequences (2p, 2p + 1), element
// j, is complex value p·pair_stride + j·celem_stride. The block mirrors
// fft.rs's `SeqParams`.

struct Seqs {
    n: u32,
    count: u32,         // real sequences
    pairs: u32,         // ⌈count / 2⌉
    group: u32,
    plane: u32,
    group_stride: u32,
    elem_stride: u32,
    pair_stride: u32,
    celem_stride: u32,
    pair_fastest: u32,  // 1: adjacent threads take adjacent pairs (columns)
    use_gain: u32,      // dct_unpack.wgsl: multiply by the gain at the output
    pad: u32,
}

@group(0) @binding(0) var<storage, read> q: Seqs;

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

