//! Weights packed once at load into the order the kernels read them, so
//! that staging a step's weights is a contiguous copy (ONNX's OIHW order
//! would make each thread gather strided scalars every step).

use super::codegen::{CONV_TRANSPOSE_TILE, ConvTile, coop};

/// A conv's `[cout][cin][k][k]` weights for `shaders/conv.wgsl`: per block
/// of `ConvTile::OC` output channels, per quad of input channels, per tap,
/// per four output channels, a column-major 4×4 matrix (column: input
/// channel, row: output channel). Channels past `cin` and `cout` are zero,
/// so every block and quad is whole.
pub(super) fn conv(weight: &[f32], cin: usize, cout: usize, k: usize) -> Vec<f32> {
    let oc = ConvTile::OC as usize;
    let (blocks, quads) = (cout.div_ceil(oc), cin.div_ceil(4));
    let mut out = Vec::with_capacity(blocks * quads * k * k * oc * 4);
    for blk in 0..blocks {
        for q in 0..quads {
            for tap in 0..k * k {
                for o4 in 0..oc / 4 {
                    for col in 0..4 {
                        for row in 0..4 {
                            let (o, c) = (blk * oc + 4 * o4 + row, 4 * q + col);
                            out.push(if o < cout && c < cin {
                                weight[(o * cin + c) * k * k + tap]
                            } else {
                                0.0
                            });
                        }
                    }
                }
            }
        }
    }
    out
}

/// A 2×2 transposed conv's `[cin][cout][2][2]` weights for
/// `shaders/conv_transpose.wgsl`: per block of output channels, per quad of
/// input channels, per output channel, a column-major 4×4 matrix (column:
/// input channel, row: tap `2·dy + dx`). Zero past `cin` and `cout`.
pub(super) fn conv_transpose(weight: &[f32], cin: usize, cout: usize) -> Vec<f32> {
    let oc = CONV_TRANSPOSE_TILE.1 as usize;
    let (blocks, quads) = (cout.div_ceil(oc), cin.div_ceil(4));
    let mut out = Vec::with_capacity(blocks * quads * oc * 16);
    for blk in 0..blocks {
        for q in 0..quads {
            for o in blk * oc..(blk + 1) * oc {
                for c in 4 * q..4 * q + 4 {
                    for tap in 0..4 {
                        out.push(if o < cout && c < cin {
                            weight[(c * cout + o) * 4 + tap]
                        } else {
                            0.0
                        });
                    }
                }
            }
        }
    }
    out
}

/// Blocks of 16 output columns the cooperative kernel reads for `columns`
/// columns: whole workgroups' worth at any tile (zero blocks past the
/// last; a tile covers 1 to [`coop::MAX_COLUMN_BLOCKS`] blocks, a power of
/// two), so no subgroup reads past its layer's weights.
pub(super) fn coop_blocks(columns: usize) -> usize {
    let s = coop::MAX_COLUMN_BLOCKS as usize;
    columns.div_ceil(16).div_ceil(s) * s
}

/// A conv's `[cout][cin][k][k]` weights for `shaders/conv_coop.wgsl`: per
/// block of 16 output channels, per chunk of 16 input channels, per tap, a
/// row-major 16×16 matrix (row: input channel, column: output channel).
pub(super) fn coop_conv(weight: &[f32], cin: usize, cout: usize, k: usize) -> Vec<f32> {
    let (blocks, chunks) = (coop_blocks(cout), cin.div_ceil(16));
    let mut out = Vec::with_capacity(blocks * chunks * k * k * 256);
    for blk in 0..blocks {
        for chunk in 0..chunks {
            for tap in 0..k * k {
                for row in 0..16 {
                    for col in 0..16 {
                        let (o, c) = (16 * blk + col, 16 * chunk + row);
                        out.push(if o < cout && c < cin {
                            weight[(o * cin + c) * k * k + tap]
                        } else {
                            0.0
                        });
                    }
                }
            }
        }
    }
    out
}

/// A 2×2 transposed conv's `[cin][cout][2][2]` weights for
/// `shaders/conv_coop.wgsl`: its output columns are (channel, tap) pairs,
/// four channels a block of 16; per block and chunk of 16 input channels,
/// one row-major 16×16 matrix (row: input channel, column: 4·channel + tap).
pub(super) fn coop_conv_transpose(weight: &[f32], cin: usize, cout: usize) -> Vec<f32> {
    let (blocks, chunks) = (coop_blocks(4 * cout), cin.div_ceil(16));
    let mut out = Vec::with_capacity(blocks * chunks * 256);
    for blk in 0..blocks {
        for chunk in 0..chunks {
            for row in 0..16 {
                for col in 0..16 {
                    let (o, tap, c) = (4 * blk + col / 4, col % 4, 16 * chunk + row);
                    out.push(if o < cout && c < cin {
                        weight[(c * cout + o) * 4 + tap]
                    } else {
                        0.0
                    });
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The conv's packed weight of (output `o`, input `c`, tap), read the
    /// way the kernel addresses it.
    fn packed_conv_at(p: &[f32], cin: usize, k: usize, o: usize, c: usize, tap: usize) -> f32 {
        let oc = ConvTile::OC as usize;
        let quads = cin.div_ceil(4);
        let (blk, o4, row) = (o / oc, (o % oc) / 4, o % 4);
        let (q, col) = (c / 4, c % 4);
        let matrix = ((blk * quads + q) * k * k + tap) * (oc / 4) + o4;
        p[matrix * 16 + col * 4 + row]
    }

    #[test]
    fn conv_weights_land_where_the_kernel_reads_them() {
        let (cin, cout, k) = (6, 19, 3);
        let w: Vec<f32> = (0..cout * cin * k * k).map(|i| i as f32 + 1.0).collect();
        let p = conv(&w, cin, cout, k);
        assert_eq!(p.len(), 2 * 2 * 9 * 16 * 4);
        for o in 0..cout {
            for c in 0..cin {
                for tap in 0..k * k {
                    assert_eq!(
                        packed_conv_at(&p, cin, k, o, c, tap),
                        w[(o * cin + c) * 9 + tap]
                    );
                }
            }
        }
        // Everything else is padding: zero.
        let nonzero = p.iter().filter(|&&v| v != 0.0).count();
        assert_eq!(nonzero, w.len());
    }

    #[test]
    fn conv_transpose_weights_land_where_the_kernel_reads_them() {
        let (cin, cout) = (5, 10);
        let w: Vec<f32> = (0..cin * cout * 4).map(|i| i as f32 + 1.0).collect();
        let p = conv_transpose(&w, cin, cout);
        let oc = CONV_TRANSPOSE_TILE.1 as usize;
        let quads = cin.div_ceil(4);
        assert_eq!(p.len(), 2 * quads * oc * 16);
        for c in 0..cin {
            for o in 0..cout {
                for tap in 0..4 {
                    let matrix = ((o / oc) * quads + c / 4) * oc + o % oc;
                    assert_eq!(
                        p[matrix * 16 + (c % 4) * 4 + tap],
                        w[(c * cout + o) * 4 + tap]
                    );
                }
            }
        }
        assert_eq!(p.iter().filter(|&&v| v != 0.0).count(), w.len());
    }

    #[test]
    fn coop_weights_land_where_the_kernel_reads_them() {
        let (cin, cout, k) = (20, 10, 3);
        let w: Vec<f32> = (0..cout * cin * k * k).map(|i| i as f32 + 1.0).collect();
        let p = coop_conv(&w, cin, cout, k);
        // One block of 16 channels, padded to the widest tile's eight; two
        // chunks.
        assert_eq!(p.len(), coop::MAX_COLUMN_BLOCKS as usize * 2 * 9 * 256);
        for o in 0..cout {
            for c in 0..cin {
                for tap in 0..9 {
                    let matrix = ((o / 16) * 2 + c / 16) * 9 + tap;
                    assert_eq!(
                        p[matrix * 256 + (c % 16) * 16 + o % 16],
                        w[(o * cin + c) * 9 + tap]
                    );
                }
            }
        }
        assert_eq!(p.iter().filter(|&&v| v != 0.0).count(), w.len());

        let w: Vec<f32> = (0..cin * cout * 4).map(|i| i as f32 + 1.0).collect();
        let p = coop_conv_transpose(&w, cin, cout);
        assert_eq!(p.len(), coop::MAX_COLUMN_BLOCKS as usize * 2 * 256);
        for c in 0..cin {
            for o in 0..cout {
                for tap in 0..4 {
                    let n = 4 * o + tap;
                    let matrix = (n / 16) * 2 + c / 16;
                    assert_eq!(
                        p[matrix * 256 + (c % 16) * 16 + n % 16],
                        w[(c * cout + o) * 4 + tap]
                    );
                }
            }
        }
        assert_eq!(p.iter().filter(|&&v| v != 0.0).count(), w.len());
    }
}
