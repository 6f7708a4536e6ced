// A U-Net level's two "same" convolutions, stride 1, fused into one kernel
// (issue 56, item 2): a workgroup computes the first convolution (bias,
// ReLU) over its output tile and the second's halo, keeps it in workgroup
// memory, and computes the second (its bias, ReLU, residual add and clamp:
// the shared epilogue) from there. The intermediate never goes through
// memory; the halo's values are computed once per workgroup that needs them.
//
// A template: the fields in double braces are filled by
// runtime/infer/src/gpu/codegen/fused.rs. Params: width, height and cin are
// the first convolution's input's; mid (the first's outputs, the second's
// inputs) and first_w_offset, first_b_offset its weights and bias;
// w_offset, b_offset, cout, out_offset and res_offset the second's. Both
// convolutions' weights are packed for conv.wgsl (gpu/pack.rs `conv`).
//
// Each output value is the unfused layers' bit for bit: its products are
// summed in conv.wgsl's order (input quads, kernel rows, kernel columns),
// each 4×4 product through the same `mac`, and the first's outputs pass
// through the activations' storage type (MID_T) on their way to the second,
// as they do through memory unfused. Halo pixels outside the layer are
// zero, the second convolution's "same" padding.
{{ENABLE_F16}}

{{LAYER_BINDINGS}}

alias T = {{ARITH}};
alias MID_T = {{MID_T}};
const K1: u32 = {{K1}}u;
const R1: u32 = K1 / 2u;
const K2: u32 = {{K2}}u;
const R2: u32 = K2 / 2u;
const TILE_W: u32 = {{TW}}u;
const TILE_H: u32 = {{TH}}u;
// The intermediate a workgroup keeps: its tile and the second's halo.
const MID_W: u32 = TILE_W + K2 - 1u;
const MID_H: u32 = TILE_H + K2 - 1u;
const MID_QUADS: u32 = {{MID_QUADS}}u;
const MID_VALUES: u32 = MID_QUADS * MID_H * MID_W;
const THREADS: u32 = {{THREADS}}u;
// Adjacent pixels of a row an invocation computes at once (tiles are
// multiples of 8 wide), and the input quads a kernel row of them reads.
const PX: u32 = 4u;
const MID_GROUPS: u32 = (MID_W + PX - 1u) / PX;
// Quads of the intermediate an invocation computes at once (4, 2 or 1,
// dividing MID_QUADS), and the items' blocks of them.
const MID_BLOCK: u32 = {{MID_BLOCK}}u;
const MID_BLOCKS: u32 = MID_QUADS / MID_BLOCK;
const OUT_GROUPS: u32 = TILE_W / PX;
const ROW1: u32 = PX + K1 - 1u;
const ROW2: u32 = PX + K2 - 1u;
// Output channels per block of the packed weights (`ConvTile::OC`).
const OC: u32 = {{OC}}u;
const FIRST_RELU: bool = {{FIRST_RELU}};
const RELU: bool = {{RELU}};
const RESIDUAL: bool = {{RESIDUAL}};
const CLAMP: bool = {{CLAMP}};

// [quad][row][column]: four intermediate channels at one pixel.
var<workgroup> mid: array<vec4<T>, MID_VALUES>;

// The 4×4 matrix (columns: input channels, rows: output channels) of input
// quad `q`, tap `tap` and output quad `o` of a conv packed at `base` with
// `quads` input quads and `taps` taps.
fn matrix(base: u32, quads: u32, taps: u32, q: u32, tap: u32, o: u32) -> mat4x4<T> {
    let blk = o / (OC / 4u);
    let at = base + 16u * (((blk * quads + q) * taps + tap) * (OC / 4u) + o % (OC / 4u));
    return mat4x4<T>(
        T(weights[at]), T(weights[at + 1u]), T(weights[at + 2u]), T(weights[at + 3u]),
        T(weights[at + 4u]), T(weights[at + 5u]), T(weights[at + 6u]), T(weights[at + 7u]),
        T(weights[at + 8u]), T(weights[at + 9u]), T(weights[at + 10u]), T(weights[at + 11u]),
        T(weights[at + 12u]), T(weights[at + 13u]), T(weights[at + 14u]), T(weights[at + 15u]),
    );
}

// The four input channels of quad `q` at (gx, gy), zero outside the layer
// and past cin (conv.wgsl's `input_at`).
fn input_quad(q: u32, gx: i32, gy: i32) -> vec4<T> {
    var v = vec4<T>(0.0);
    if (gx >= 0 && gx < i32(p.width) && gy >= 0 && gy < i32(p.height)) {
        let plane = p.width * p.height;
        let c = 4u * q;
        let at = p.in_offset + c * plane + u32(gy) * p.width + u32(gx);
        if (c < p.cin) { v.x = T(src[at]); }
        if (c + 1u < p.cin) { v.y = T(src[at + plane]); }
        if (c + 2u < p.cin) { v.z = T(src[at + 2u * plane]); }
        if (c + 3u < p.cin) { v.w = T(src[at + 3u * plane]); }
    }
    return v;
}

// The first convolution's output channel `oc` from its sum, as the second
// reads it: bias, ReLU, through the storage type; zero past its channels.
fn first_out(oc: u32, sum: f32) -> T {
    if (oc >= p.mid) {
        return T(0.0);
    }
    var v = sum + f32(weights[p.first_b_offset + oc]);
    if (FIRST_RELU) {
        v = max(v, 0.0);
    }
    return T(MID_T(v));
}

@compute @workgroup_size({{THREADS}}, 1, 1)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let x0 = wg.x * TILE_W;
    let y0 = wg.y * TILE_H;
    let quads = (p.cin + 3u) / 4u;
    // The first convolution over the tile and its halo: an item is PX
    // adjacent pixels of a row × MID_BLOCK quads of channels, so each 4×4
    // matrix loaded serves PX products and each input quad loaded (from
    // memory, four planes) K1 · MID_BLOCK of them.
    for (var i = li; i < MID_BLOCKS * MID_H * MID_GROUPS; i += THREADS) {
        let o0 = (i / (MID_H * MID_GROUPS)) * MID_BLOCK;
        let rem = i % (MID_H * MID_GROUPS);
        let my = rem / MID_GROUPS;
        let mx0 = (rem % MID_GROUPS) * PX;
        let gy = i32(y0 + my) - i32(R2);
        let gx0 = i32(x0 + mx0) - i32(R2);
        // [quad of the block][pixel]
        var a: array<vec4<f32>, MID_BLOCK * PX>;
        for (var q = 0u; q < quads; q++) {
            for (var ky = 0u; ky < K1; ky++) {
                var r: array<vec4<T>, ROW1>;
                for (var j = 0u; j < ROW1; j++) {
                    r[j] = input_quad(q, gx0 + i32(j) - i32(R1), gy + i32(ky) - i32(R1));
                }
                for (var kx = 0u; kx < K1; kx++) {
                    for (var b = 0u; b < MID_BLOCK; b++) {
                        let m = matrix(p.first_w_offset, quads, K1 * K1, q, ky * K1 + kx, o0 + b);
                        for (var px = 0u; px < PX; px++) {
                            a[b * PX + px] = mac(m, r[px + kx], a[b * PX + px]);
                        }
                    }
                }
            }
        }
        for (var b = 0u; b < MID_BLOCK; b++) {
            let o = o0 + b;
            for (var px = 0u; px < PX; px++) {
                let gx = gx0 + i32(px);
                let s = a[b * PX + px];
                var v = vec4<T>(0.0);
                if (gx >= 0 && gx < i32(p.width) && gy >= 0 && gy < i32(p.height)) {
                    v = vec4<T>(
                        first_out(4u * o, s.x),
                        first_out(4u * o + 1u, s.y),
                        first_out(4u * o + 2u, s.z),
                        first_out(4u * o + 3u, s.w),
                    );
                }
                if (mx0 + px < MID_W) {
                    mid[(o * MID_H + my) * MID_W + mx0 + px] = v;
                }
            }
        }
    }
    workgroupBarrier();
    // The second from the workgroup's intermediate, PX pixels × four
    // channels an item; adjacent invocations store adjacent pixel groups.
    let plane = p.width * p.height;
    let out_quads = (p.cout + 3u) / 4u;
    for (var i = li; i < out_quads * TILE_H * OUT_GROUPS; i += THREADS) {
        let o = i / (TILE_H * OUT_GROUPS);
        let rem = i % (TILE_H * OUT_GROUPS);
        let ty = rem / OUT_GROUPS;
        let tx0 = (rem % OUT_GROUPS) * PX;
        let y = y0 + ty;
        if (y < p.height && x0 + tx0 < p.width) {
            var a: array<vec4<f32>, PX>;
            for (var q = 0u; q < MID_QUADS; q++) {
                for (var ky = 0u; ky < K2; ky++) {
                    var r: array<vec4<T>, ROW2>;
                    let row = (q * MID_H + ty + ky) * MID_W + tx0;
                    for (var j = 0u; j < ROW2; j++) {
                        r[j] = mid[row + j];
                    }
                    for (var kx = 0u; kx < K2; kx++) {
                        let m = matrix(p.w_offset, MID_QUADS, K2 * K2, q, ky * K2 + kx, o);
                        for (var px = 0u; px < PX; px++) {
                            a[px] = mac(m, r[px + kx], a[px]);
                        }
                    }
                }
            }
            for (var px = 0u; px < PX; px++) {
                let x = x0 + tx0 + px;
                if (x < p.width) {
                    let at = y * p.width + x;
                    for (var j = 0u; j < 4u; j++) {
                        let oc = 4u * o + j;
                        if (oc < p.cout) {
                            epilogue(oc * plane + at, oc, a[px][j]);
                        }
                    }
                }
            }
        }
    }
}

{{MAC}}

{{CONV_EPILOGUE}}
