// A K×K "same" convolution (bias, ReLU, residual, clamp fused), or the 2×2
// stride-2 transposed one (bias, ReLU), as an implicit GEMM on cooperative
// matrices (the tensor cores): M = 16 pixels of a row, K = 16 input
// channels of one tap, N = 16 output columns (16 channels, or for the
// transposed conv 4 channels × its 4 taps). f16 inputs, f32 accumulators.
// A template filled by runtime/infer/src/gpu/codegen/coop.rs; chosen only
// where the adapter lists the 16×16×16 f16 shape (docs/inference.md).
//
// A workgroup is SG_ROWS × SG_COLS subgroups of SG invocations (the
// adapter's one subgroup size; the builtins say which subgroup an
// invocation is in, so nothing assumes how invocations are grouped),
// covering 16 pixels × ROWS·SG_ROWS rows × BLOCKS·SG_COLS blocks of 16
// output columns (the tile, chosen per layer: `CoopTile`). Per CHUNKS
// 16-channel chunks (the K-slice) it stages their input tiles (ROWS·SG_ROWS
// + K − 1 rows of 16 + K − 1 pixels, 16 channels each, channels innermost so
// that a row of 16 pixels is a row-major 16×16 matrix with stride 16) in
// workgroup memory once, between two barriers;
// each subgroup then multiplies its ROWS rows of it by its own BLOCKS
// blocks of output columns, whose weights were packed at load as one
// row-major 16×16 matrix per block, chunk and tap (`codegen::pack_coop`),
// read straight from the weight buffer (every workgroup reads the same few
// KiB: they stay in cache). Each subgroup holds ROWS × BLOCKS accumulators
// (16 pixels × 16 columns each); the epilogue goes through workgroup
// memory, one matrix at a time, so that it can address pixels and
// channels. A tile changes which invocations compute an output, never the
// order of its sum. The stage is gathered flat (each value's index split
// into chunk, channel, row and column) or, with PLANE_GATHER, plane by
// plane: each invocation finds where its pixels of the tile lie once, then
// loads those pixels of each channel plane, one add and one compare a
// value. Either fills the same staged tile. With staged weights the
// workgroup also copies its column blocks' weights of the K-slice into
// workgroup memory (contiguous in the packed weights, so a coalesced
// copy), and the subgroups load their weight matrices from there.
enable f16;
enable wgpu_cooperative_matrix;

{{LAYER_BINDINGS}}

const K: u32 = {{K}}u;
const R: u32 = K / 2u;
const SG: u32 = {{SG}}u;
const ROWS: u32 = {{ROWS}}u;
const BLOCKS: u32 = {{BLOCKS}}u;
const SG_ROWS: u32 = {{SG_ROWS}}u;
const SG_COLS: u32 = {{SG_COLS}}u;
const CHUNKS: u32 = {{CHUNKS}}u;
const SUBGROUPS: u32 = SG_ROWS * SG_COLS;
const THREADS: u32 = SG * SUBGROUPS;
const IN_W: u32 = 16u + K - 1u;
const IN_H: u32 = ROWS * SG_ROWS + K - 1u;
// One chunk's staged tile.
const STAGE: u32 = IN_H * IN_W * 16u;
const PREFETCH: bool = {{PREFETCH}};
const PLANE_GATHER: bool = {{PLANE_GATHER}};
// Pixels of a chunk's staged tile, and how many each invocation gathers
// plane by plane.
const PIXELS: u32 = IN_H * IN_W;
const SLOTS: u32 = (PIXELS + THREADS - 1u) / THREADS;
// Each invocation's share of a stage: flat, its values; plane by plane,
// its pixels of each of the stage's planes (CoopTile::staged_per_invocation).
const PER_THREAD: u32 = {{PER_THREAD}}u;
// A plane offset for a pixel past the tile (staged nowhere), and for one
// of the tile outside the layer (staged as zero).
const PAST: u32 = 0xffffffffu;
const OUTSIDE: u32 = 0xfffffffeu;
// A column block's weights of a K-slice: one 16×16 matrix per chunk and
// tap, as packed.
const BLOCK_WEIGHTS: u32 = CHUNKS * K * K * 256u;
const TRANSPOSED: bool = {{TRANSPOSED}};
const RELU: bool = {{RELU}};
const RESIDUAL: bool = {{RESIDUAL}};
const CLAMP: bool = {{CLAMP}};

// [chunk of the stage][row][column][channel of the chunk].
var<workgroup> a_tile: array<f16, CHUNKS * STAGE>;
// Each subgroup's accumulators on their way out: [subgroup][matrix]
// [pixel][column], one matrix a subgroup (drained one at a time, two
// barriers each) or, drained at once, all of them (one barrier in all).
const DRAIN_MATS: u32 = {{DRAIN_MATS}}u;
var<workgroup> c_tile: array<f32, SUBGROUPS * DRAIN_MATS * 256u>;
{{B_TILE}}

@compute @workgroup_size({{THREADS}}, 1, 1)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
    @builtin(subgroup_id) sg: u32,
    @builtin(subgroup_invocation_id) lane: u32,
) {
    let x0 = wg.x * 16u;
    let y0 = wg.y * ROWS * SG_ROWS;
    // This subgroup's first pixel row in the tile and first block of 16
    // output columns.
    let row0 = (sg / SG_COLS) * ROWS;
    let blk0 = (wg.z * SG_COLS + sg % SG_COLS) * BLOCKS;
    let chunks = (p.cin + 15u) / 16u;
{{ACC_DECL}}

    // With PLANE_GATHER, where this invocation's pixels of the staged tile
    // lie in a plane, found once.
    var pix_at: array<u32, SLOTS>;
    if (PLANE_GATHER) {
        for (var j = 0u; j < SLOTS; j++) {
            pix_at[j] = pixel_at(li + j * THREADS, x0, y0);
        }
    }
    // With PREFETCH each invocation holds its share of the next stage in
    // registers, loaded before the current stage's products and stored
    // after them: the loads' latency hides behind the tensor cores.
    // (One element without a prefetch: never read then.)
    var pre: array<f16, {{PRE_LEN}}u>;
    if (PREFETCH) {
        for (var j = 0u; j < PER_THREAD; j++) {
            pre[j] = share(0u, li, j, &pix_at, x0, y0);
        }
    }
    for (var first = 0u; first < chunks; first += CHUNKS) {
        for (var j = 0u; j < PER_THREAD; j++) {
            let t = share_index(li, j);
            if (t != PAST) {
                if (PREFETCH) {
                    a_tile[t] = pre[j];
                } else {
                    a_tile[t] = share(first, li, j, &pix_at, x0, y0);
                }
            }
        }
{{COPY_WEIGHTS}}        workgroupBarrier();
        if (PREFETCH && first + CHUNKS < chunks) {
            for (var j = 0u; j < PER_THREAD; j++) {
                pre[j] = share(first + CHUNKS, li, j, &pix_at, x0, y0);
            }
        }
        // The same products in the same order as one chunk a stage: chunk
        // by chunk, tap by tap. (The stage's chunks past the layer bound
        // the loop rather than a branch: naga takes a loop's bound, not an
        // `if` on the parameters, as uniform around cooperative loads.)
        for (var s = 0u; s < min(CHUNKS, chunks - first); s++) {
            let chunk = first + s;
            let abase = s * STAGE;
            for (var tap = 0u; tap < K * K; tap++) {
                let ky = tap / K;
                let kx = tap % K;
{{TAPS}}
            }
        }
        workgroupBarrier();
    }

{{STORES}}
}

// Value `i` of the stage whose first chunk is `first` (the workgroup's
// tile at `x0`, `y0`): pixels innermost, so that neighbouring invocations
// read neighbouring pixels of one plane; zero outside the layer, in
// channels past it (of a chunk past its last, too) and past the stage.
fn staged(first: u32, i: u32, x0: u32, y0: u32) -> f16 {
    let s = i / STAGE;
    let ci = (i % STAGE) / (IN_H * IN_W);
    let pix = i % (IN_H * IN_W);
    let gx = i32(x0 + pix % IN_W) - i32(R);
    let gy = i32(y0 + pix / IN_W) - i32(R);
    let c = (first + s) * 16u + ci;
    var v = f16(0.0);
    if (i < CHUNKS * STAGE && c < p.cin && gx >= 0 && gx < i32(p.width) && gy >= 0 && gy < i32(p.height)) {
        v = f16(src[p.in_offset + c * p.width * p.height + u32(gy) * p.width + u32(gx)]);
    }
    return v;
}

// Where value `i` of a stage lies in `a_tile`: channels innermost.
fn tile_index(i: u32) -> u32 {
    let s = i / STAGE;
    let ci = (i % STAGE) / (IN_H * IN_W);
    let pix = i % (IN_H * IN_W);
    return s * STAGE + pix * 16u + ci;
}

// Where pixel `pix` of the staged tile (at `x0`, `y0`) lies in a plane:
// PAST past the tile, OUTSIDE outside the layer.
fn pixel_at(pix: u32, x0: u32, y0: u32) -> u32 {
    if (pix >= PIXELS) {
        return PAST;
    }
    let gx = i32(x0 + pix % IN_W) - i32(R);
    let gy = i32(y0 + pix / IN_W) - i32(R);
    if (gx < 0 || gx >= i32(p.width) || gy < 0 || gy >= i32(p.height)) {
        return OUTSIDE;
    }
    return u32(gy) * p.width + u32(gx);
}

// Value `j` of invocation `li`'s share of the stage whose first chunk is
// `first`. Plane by plane, value j is pixel slot j % SLOTS of the stage's
// plane j / SLOTS (chunk, then channel).
fn share(first: u32, li: u32, j: u32, pix_at: ptr<function, array<u32, SLOTS>>, x0: u32, y0: u32) -> f16 {
    if (!PLANE_GATHER) {
        return staged(first, li + j * THREADS, x0, y0);
    }
    let q = j / SLOTS;
    let c = first * 16u + q;
    let off = (*pix_at)[j % SLOTS];
    var v = f16(0.0);
    if (off < OUTSIDE && c < p.cin) {
        v = f16(src[p.in_offset + c * p.width * p.height + off]);
    }
    return v;
}

// Where value `j` of invocation `li`'s share lies in `a_tile`, or PAST.
fn share_index(li: u32, j: u32) -> u32 {
    if (!PLANE_GATHER) {
        let i = li + j * THREADS;
        if (i >= CHUNKS * STAGE) {
            return PAST;
        }
        return tile_index(i);
    }
    let q = j / SLOTS;
    let pix = li + (j % SLOTS) * THREADS;
    if (pix >= PIXELS) {
        return PAST;
    }
    return (q / 16u) * STAGE + pix * 16u + q % 16u;
}

// Matrix `m` of `c_tile` (a subgroup's accumulator of pixel row `y` and
// column block `blk`) out, each value through the epilogue.
fn drain(m: u32, lane: u32, blk: u32, x0: u32, y: u32) {
    for (var i = lane; i < 256u; i += SG) {
        // Pixels innermost: neighbouring invocations write neighbours.
        let px = i % 16u;
        let col = i / 16u;
        let sum = c_tile[m * 256u + px * 16u + col];
        emit(x0 + px, y, blk * 16u + col, sum);
    }
}

// One output value (column `n` of the GEMM), if inside the layer, through
// the epilogue (the transposed conv has no residual and no clamp).
fn emit(x: u32, y: u32, n: u32, sum: f32) {
    if (x >= p.width || y >= p.height) {
        return;
    }
    if (TRANSPOSED) {
        let oc = n / 4u;
        let tap = n % 4u;
        if (oc < p.cout) {
            let ow = 2u * p.width;
            epilogue(oc * 4u * p.width * p.height + (2u * y + tap / 2u) * ow + 2u * x + tap % 2u, oc, sum);
        }
    } else if (n < p.cout) {
        epilogue(n * p.width * p.height + y * p.width + x, n, sum);
    }
}

{{CONV_EPILOGUE}}
