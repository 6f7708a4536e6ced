//! The fused level (`shaders/conv_fused.wgsl`, issue 56 item 2): two
//! "same" convolutions in one kernel, the first's output for a tile and
//! its halo kept in workgroup memory. Its tile, what that tile needs of
//! workgroup memory, and the template's fields.

use super::{ConvTile, Dtype};

/// Output pixels a workgroup of the fused level computes: `width` ×
/// `height`, with [`Self::threads`] invocations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct FusedTile {
    pub width: u32,
    pub height: u32,
}

/// The tiles the tuner times, smallest first.
const TILES: [(u32, u32); 6] = [(8, 8), (16, 8), (8, 16), (16, 16), (32, 8), (32, 16)];

impl FusedTile {
    /// Invocations of a workgroup: 64 for the 8×8 tile, 128 for the
    /// others (an item is four adjacent pixels × four channels, of the
    /// intermediate, tile and halo, then of the output).
    pub fn threads(&self) -> u32 {
        if self.width * self.height <= 64 {
            64
        } else {
            128
        }
    }

    /// Workgroup memory of the intermediate: `mid` channels, in quads, over
    /// the tile and the second convolution's (`kernel`) halo, in `arith`.
    pub fn workgroup_bytes(&self, kernel: usize, mid: usize, arith: Dtype) -> u64 {
        let halo = kernel as u64 - 1;
        let quads = mid.div_ceil(4) as u64;
        quads * (self.width as u64 + halo) * (self.height as u64 + halo) * 4 * arith.bytes() as u64
    }

    /// Whether the tile's intermediate fits `limit` bytes of workgroup
    /// memory (the device's).
    pub fn fits(&self, kernel: usize, mid: usize, arith: Dtype, limit: u32) -> bool {
        self.is_valid() && self.workgroup_bytes(kernel, mid, arith) <= limit as u64
    }

    /// One of the tiles the kernel is built for.
    pub fn is_valid(&self) -> bool {
        TILES.contains(&(self.width, self.height))
    }

    /// The tiles a `width`×`height` level whose intermediate has `mid`
    /// channels can take: those that fit `limit` and that the level fills
    /// along each side (the smallest tile always does).
    pub fn candidates(
        width: u32,
        height: u32,
        kernel: usize,
        mid: usize,
        arith: Dtype,
        limit: u32,
    ) -> Vec<FusedTile> {
        // A side under 8 counts as 8: the smallest tile, 8×8, always passes.
        TILES
            .iter()
            .map(|&(w, h)| FusedTile {
                width: w,
                height: h,
            })
            .filter(|t| t.width <= width.max(8) && t.height <= height.max(8))
            .filter(|t| t.fits(kernel, mid, arith, limit))
            .collect()
    }
}

/// What the fused kernel is compiled for, beside its key's element types.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct FusedLevel {
    /// The first convolution's kernel and ReLU.
    pub first_kernel: usize,
    pub first_relu: bool,
    /// Its output channels (the intermediate's), and their storage type
    /// unfused, which they pass through on their way to the second.
    pub mid: usize,
    pub mid_dtype: Dtype,
    /// The second's kernel and epilogue.
    pub kernel: usize,
    pub relu: bool,
    pub residual: bool,
    pub clamp: bool,
    pub tile: FusedTile,
}

impl FusedLevel {
    /// Quads of the intermediate an invocation of the first convolution
    /// computes at once: the most of 4, 2 and 1 that divides its quads.
    pub fn mid_block(&self) -> u32 {
        let quads = self.mid.div_ceil(4) as u32;
        [4, 2, 1]
            .into_iter()
            .find(|b| quads.is_multiple_of(*b))
            .unwrap_or(1)
    }
}

/// The template's fields for `level`.
pub(super) fn fields(level: &FusedLevel) -> Vec<(&'static str, String)> {
    vec![
        ("K1", level.first_kernel.to_string()),
        ("K2", level.kernel.to_string()),
        ("TW", level.tile.width.to_string()),
        ("TH", level.tile.height.to_string()),
        ("MID_QUADS", level.mid.div_ceil(4).to_string()),
        ("MID_BLOCK", level.mid_block().to_string()),
        ("MID_T", level.mid_dtype.wgsl().to_string()),
        ("THREADS", level.tile.threads().to_string()),
        ("OC", ConvTile::OC.to_string()),
        ("FIRST_RELU", level.first_relu.to_string()),
        ("RELU", level.relu.to_string()),
        ("RESIDUAL", level.residual.to_string()),
        ("CLAMP", level.clamp.to_string()),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tile_fits_by_its_intermediate_and_the_smallest_is_always_offered() {
        let t = FusedTile {
            width: 16,
            height: 8,
        };
        // 32 channels over 18 × 10 pixels: 23 040 bytes in f32, half in f16.
        assert_eq!(t.workgroup_bytes(3, 32, Dtype::F32), 23040);
        assert_eq!(t.workgroup_bytes(3, 30, Dtype::F16), 11520);
        assert!(!t.fits(3, 32, Dtype::F32, 16384));
        assert!(t.fits(3, 32, Dtype::F16, 16384));
        let c = FusedTile::candidates(4, 2, 3, 16, Dtype::F32, 16384);
        assert_eq!(
            c,
            [FusedTile {
                width: 8,
                height: 8
            }]
        );
        let c = FusedTile::candidates(1920, 1080, 3, 16, Dtype::F32, 49152);
        assert_eq!(c.len(), TILES.len());
        // 256 channels fit no tile of 48 KiB in f32.
        assert!(FusedTile::candidates(64, 64, 3, 256, Dtype::F32, 49152).is_empty());
        assert!(
            !FusedTile {
                width: 12,
                height: 8
            }
            .is_valid()
        );
    }

    #[test]
    fn the_first_convolution_blocks_the_most_quads_that_divide_its_outputs() {
        let level = |mid| FusedLevel {
            first_kernel: 3,
            first_relu: true,
            mid,
            mid_dtype: Dtype::F32,
            kernel: 3,
            relu: true,
            residual: false,
            clamp: false,
            tile: FusedTile {
                width: 8,
                height: 8,
            },
        };
        let blocks: Vec<u32> = [4, 6, 16, 20, 32, 64]
            .map(|m| level(m).mid_block())
            .to_vec();
        assert_eq!(blocks, [1, 2, 4, 1, 4, 4]);
    }
}
