//! The cooperative-matrix kernel (`shaders/conv_coop.wgsl`) has no adapter
//! here to run on, so its dataflow is modelled on the CPU with the index
//! arithmetic of the WGSL, step for step (workgroups, subgroups, the staged
//! tile, the weight offsets, the 16×16 products and the drain), over the
//! weights `pack` writes for it, and held to the CPU twin. What the model
//! cannot show is the driver's own matrix instructions: the device check
//! compares the cooperative network with the tiled one on a GPU.

use super::codegen::coop::{CoopLimits, CoopTile};
use super::pack;
use crate::network::{Conv, ConvTranspose};
use crate::reference::{self, Epilogue};
use crate::synth::SplitMix;
use crate::tests::max_abs_diff;

/// The kernel's output at `tile` for an input of `cin`×`h`×`w`: a "same"
/// `k`×`k` conv, or (`transposed`) the 2×2 stride-2 one; no ReLU.
#[allow(clippy::too_many_arguments)]
fn model(
    input: &[f32],
    (w, h): (usize, usize),
    (cin, cout, k): (usize, usize, usize),
    packed: &[f32],
    bias: &[f32],
    transposed: bool,
    tile: CoopTile,
) -> Vec<f32> {
    let (rows, blocks) = (tile.rows as usize, tile.blocks as usize);
    let (sg_rows, sg_cols) = (tile.sg_rows as usize, tile.sg_cols as usize);
    let (pixel_rows, column_blocks) = (tile.pixel_rows() as usize, tile.column_blocks() as usize);
    let (in_w, in_h, r) = (16 + k - 1, pixel_rows + k - 1, (k / 2) as isize);
    let columns = if transposed { 4 * cout } else { cout };
    let chunks = cin.div_ceil(16);
    let slice = tile.chunks as usize;
    let plane = w * h;
    let mut out = vec![0f32; if transposed { 4 } else { 1 } * cout * plane];
    // Each output must be written exactly once: a tile that overlaps or
    // leaves a gap is a bug even where the values happen to agree.
    let mut written = vec![0u8; out.len()];
    // The dispatch plan.rs makes, and each subgroup's first row and block.
    let sgs = sg_rows * sg_cols;
    let row0 = |sg: usize| (sg / sg_cols) * rows;
    let blk0 = |gz: usize, sg: usize| (gz * sg_cols + sg % sg_cols) * blocks;
    for gz in 0..columns.div_ceil(16).div_ceil(column_blocks) {
        for gy in 0..h.div_ceil(pixel_rows) {
            for gx in 0..w.div_ceil(16) {
                let (x0, y0) = (gx * 16, gy * pixel_rows);
                // acc[sg][row][block][pixel][column]
                let mut acc = vec![[[0f32; 16]; 16]; sgs * rows * blocks];
                // Value `i` of the stage at chunk `first`, as `staged`.
                let stage = in_h * in_w * 16;
                let staged = |first: usize, i: usize| -> f32 {
                    let (s, ci, pix) = (i / stage, (i % stage) / (in_h * in_w), i % (in_h * in_w));
                    let gxx = (x0 + pix % in_w) as isize - r;
                    let gyy = (y0 + pix / in_w) as isize - r;
                    let c = (first + s) * 16 + ci;
                    if i < slice * stage
                        && c < cin
                        && gxx >= 0
                        && (gxx as usize) < w
                        && gyy >= 0
                        && (gyy as usize) < h
                    {
                        input[c * plane + gyy as usize * w + gxx as usize]
                    } else {
                        0.0
                    }
                };
                let tile_index = |i: usize| {
                    let (s, ci, pix) = (i / stage, (i % stage) / (in_h * in_w), i % (in_h * in_w));
                    s * stage + pix * 16 + ci
                };
                let threads = sgs * SUBGROUP;
                let per = tile.staged_per_invocation(k, SUBGROUP as u32) as usize;
                // The plane gather: pixel slot j of invocation li, as
                // `pixel_at` (None past the tile, Some(None) outside the
                // layer), found once a workgroup.
                let pixels = in_h * in_w;
                let slots = tile.gather_slots(k, SUBGROUP as u32) as usize;
                let pixel_at = |pix: usize| -> Option<Option<usize>> {
                    if pix >= pixels {
                        return None;
                    }
                    let gxx = (x0 + pix % in_w) as isize - r;
                    let gyy = (y0 + pix / in_w) as isize - r;
                    let inside = gxx >= 0 && (gxx as usize) < w && gyy >= 0 && (gyy as usize) < h;
                    Some(inside.then(|| gyy as usize * w + gxx as usize))
                };
                let at: Vec<Vec<Option<Option<usize>>>> = (0..threads)
                    .map(|li| (0..slots).map(|j| pixel_at(li + j * threads)).collect())
                    .collect();
                // Value j of invocation li's share of the stage at `first`,
                // and where it goes in the staged tile, as `share` and
                // `share_index`.
                let share = |first: usize, li: usize, j: usize| -> f32 {
                    if !tile.plane_gather {
                        return staged(first, li + j * threads);
                    }
                    let c = first * 16 + j / slots;
                    match at[li][j % slots] {
                        Some(Some(off)) if c < cin => input[c * plane + off],
                        _ => 0.0,
                    }
                };
                let share_index = |li: usize, j: usize| -> Option<usize> {
                    if !tile.plane_gather {
                        let i = li + j * threads;
                        return (i < slice * stage).then(|| tile_index(i));
                    }
                    let (q, pix) = (j / slots, li + (j % slots) * threads);
                    (pix < pixels).then_some((q / 16) * stage + pix * 16 + q % 16)
                };
                // The prefetch registers: [invocation][value], loaded for
                // the next stage while the current one is multiplied.
                let load = |first: usize| -> Vec<Vec<f32>> {
                    (0..threads)
                        .map(|li| (0..per).map(|j| share(first, li, j)).collect())
                        .collect()
                };
                let mut pre = if tile.prefetch { load(0) } else { Vec::new() };
                for first in (0..chunks).step_by(slice) {
                    // NaN where no invocation stages a value: a gap in the
                    // gather reaches the output.
                    let mut a_tile = vec![f32::NAN; slice * stage];
                    // Without a prefetch, the shares loaded now.
                    let shares = if tile.prefetch {
                        None
                    } else {
                        Some(load(first))
                    };
                    for (li, regs) in shares.as_ref().unwrap_or(&pre).iter().enumerate() {
                        for (j, v) in regs.iter().enumerate() {
                            if let Some(t) = share_index(li, j) {
                                a_tile[t] = *v;
                            }
                        }
                    }
                    // With stage_weights, the workgroup's column blocks'
                    // weights of the stage, as the kernel copies them.
                    let per_block = slice * k * k * 256;
                    let wbase = (gz * column_blocks * chunks + first) * k * k * 256;
                    let b_tile: Vec<f32> = (0..tile.staged_weights(k) as usize)
                        .map(|i| {
                            let (nb, rest) = (i / per_block, i % per_block);
                            if first + rest / (k * k * 256) < chunks {
                                packed[wbase + nb * chunks * k * k * 256 + rest]
                            } else {
                                0.0
                            }
                        })
                        .collect();
                    if tile.prefetch && first + slice < chunks {
                        pre = load(first + slice);
                    }
                    for (s, chunk) in (first..chunks.min(first + slice)).enumerate() {
                        let abase = s * stage;
                        for tap in 0..k * k {
                            let (ky, kx) = (tap / k, tap % k);
                            for sg in 0..sgs {
                                for nb in 0..blocks {
                                    let blk = blk0(gz, sg) + nb;
                                    let (weights, b) = if tile.stage_weights {
                                        let local = (sg % sg_cols) * blocks + nb;
                                        (&b_tile[..], ((local * slice + s) * k * k + tap) * 256)
                                    } else {
                                        (packed, ((blk * chunks + chunk) * k * k + tap) * 256)
                                    };
                                    assert!(b + 256 <= weights.len(), "a read past the weights");
                                    for row in 0..rows {
                                        let a = abase + ((row0(sg) + row + ky) * in_w + kx) * 16;
                                        let c = &mut acc[(sg * rows + row) * blocks + nb];
                                        for (m, c_row) in c.iter_mut().enumerate() {
                                            for (n, v) in c_row.iter_mut().enumerate() {
                                                for kk in 0..16 {
                                                    *v += a_tile[a + m * 16 + kk]
                                                        * weights[b + kk * 16 + n];
                                                }
                                            }
                                        }
                                    }
                                }
                            }
                        }
                    }
                }
                // The epilogue through workgroup memory, as `stores` and
                // `drain`: every subgroup stores a matrix, a barrier, every
                // subgroup drains it (one matrix a subgroup, slot sg), or
                // with drain_once all matrices, then all drained (slot
                // sg·mats + row·blocks + block). NaN where none stored.
                let mats = tile.drain_matrices() as usize;
                let mut c_tile = vec![f32::NAN; sgs * mats * 256];
                let order: Vec<(usize, usize)> = (0..rows)
                    .flat_map(|r| (0..blocks).map(move |n| (r, n)))
                    .collect();
                let slot = |sg: usize, row: usize, nb: usize| {
                    if tile.drain_once {
                        sg * mats + row * blocks + nb
                    } else {
                        sg
                    }
                };
                let phases: Vec<Vec<(usize, usize)>> = if tile.drain_once {
                    vec![order]
                } else {
                    order.into_iter().map(|m| vec![m]).collect()
                };
                for phase in &phases {
                    for sg in 0..sgs {
                        for &(row, nb) in phase {
                            let m = slot(sg, row, nb);
                            for (px, c_row) in
                                acc[(sg * rows + row) * blocks + nb].iter().enumerate()
                            {
                                c_tile[m * 256 + px * 16..m * 256 + px * 16 + 16]
                                    .copy_from_slice(c_row);
                            }
                        }
                    }
                    for sg in 0..sgs {
                        for &(row, nb) in phase {
                            let (m, blk) = (slot(sg, row, nb), blk0(gz, sg) + nb);
                            for i in 0..256 {
                                let (px, col) = (i % 16, i / 16);
                                let sum = c_tile[m * 256 + px * 16 + col];
                                let (x, y, n) = (x0 + px, y0 + row0(sg) + row, blk * 16 + col);
                                if x >= w || y >= h {
                                    continue;
                                }
                                if transposed {
                                    let (oc, tap) = (n / 4, n % 4);
                                    if oc < cout {
                                        let at = oc * 4 * plane
                                            + (2 * y + tap / 2) * 2 * w
                                            + 2 * x
                                            + tap % 2;
                                        out[at] = sum + bias[oc];
                                        written[at] += 1;
                                    }
                                } else if n < cout {
                                    out[n * plane + y * w + x] = sum + bias[n];
                                    written[n * plane + y * w + x] += 1;
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(
        written.iter().all(|&n| n == 1),
        "{tile:?}: outputs written other than once"
    );
    out
}

/// The tiles to hold to the CPU twin for a layer of `cin` input channels:
/// the default, the heuristics', every candidate the tuner would time on
/// the largest adapter a table allows, each one's K-slices, and each of
/// those prefetched where it can be.
fn tiles_for(columns: usize, h: usize, k: usize, cin: usize) -> Vec<CoopTile> {
    let largest = CoopLimits {
        workgroup_bytes: super::codegen::coop::MAX_TABLE_WORKGROUP_BYTES,
        invocations: 1024,
    };
    let mut tiles = CoopTile::candidates(columns, h as u32, k, 32, &largest);
    for t in [CoopTile::DEFAULT, CoopTile::for_layer(columns)] {
        if !tiles.contains(&t) {
            tiles.push(t);
        }
    }
    let slices: Vec<CoopTile> = tiles
        .iter()
        .flat_map(|t| t.slices(cin, k, 32, &largest))
        .collect();
    tiles.extend(slices);
    let gathered: Vec<CoopTile> = tiles.iter().map(|t| t.plane_gathered()).collect();
    tiles.extend(gathered);
    let staged: Vec<CoopTile> = tiles
        .iter()
        .filter_map(|t| t.weights_staged(k, 32, &largest))
        .collect();
    tiles.extend(staged);
    let drained: Vec<CoopTile> = tiles
        .iter()
        .filter_map(|t| t.drained_once(k, 32, &largest))
        .collect();
    tiles.extend(drained);
    let prefetched: Vec<CoopTile> = tiles.iter().filter_map(|t| t.prefetched(k, 32)).collect();
    tiles.extend(prefetched);
    tiles
}

/// The subgroup size the model's invocations are counted in.
const SUBGROUP: usize = 32;

#[test]
fn the_cooperative_kernels_addressing_computes_the_convolution() {
    // Channel counts that fill no matrix or workgroup exactly, a frame no
    // tile divides, 3×3 and 1×1.
    let mut rng = SplitMix::new(38);
    let (w, h) = (37, 11);
    for (cin, cout, k) in [
        (20, 10, 3),
        (16, 70, 3),
        (33, 5, 1),
        (32, 32, 3),
        (80, 32, 3),
    ] {
        let input: Vec<f32> = (0..cin * w * h).map(|_| rng.symmetric(1.0)).collect();
        let conv = Conv {
            input: 0,
            output: 1,
            cin,
            cout,
            kernel: k,
            weight: (0..cout * cin * k * k)
                .map(|_| rng.symmetric(0.3))
                .collect(),
            bias: (0..cout).map(|_| rng.symmetric(0.3)).collect(),
            relu: false,
            residual: None,
        };
        let want = reference::conv_same(
            &input,
            h,
            w,
            &conv,
            Epilogue {
                relu: false,
                residual: None,
                clamp: false,
            },
        );
        let packed = pack::coop_conv(&conv.weight, cin, cout, k);
        for tile in tiles_for(cout, h, k, cin) {
            let got = model(
                &input,
                (w, h),
                (cin, cout, k),
                &packed,
                &conv.bias,
                false,
                tile,
            );
            let d = max_abs_diff(&want, &got);
            assert!(d < 1e-4, "conv {k}×{k} {cin}→{cout} at {tile:?}: {d}");
        }
    }
    for (cin, cout) in [(20, 10), (64, 32)] {
        let input: Vec<f32> = (0..cin * w * h).map(|_| rng.symmetric(1.0)).collect();
        let ct = ConvTranspose {
            input: 0,
            output: 1,
            cin,
            cout,
            weight: (0..cin * cout * 4).map(|_| rng.symmetric(0.3)).collect(),
            bias: (0..cout).map(|_| rng.symmetric(0.3)).collect(),
            relu: false,
        };
        let want = reference::conv_transpose2(&input, h, w, &ct);
        let packed = pack::coop_conv_transpose(&ct.weight, cin, cout);
        for tile in tiles_for(4 * cout, h, 1, cin) {
            let got = model(
                &input,
                (w, h),
                (cin, cout, 1),
                &packed,
                &ct.bias,
                true,
                tile,
            );
            let d = max_abs_diff(&want, &got);
            assert!(d < 1e-4, "transposed {cin}→{cout} at {tile:?}: {d}");
        }
    }
}
