//! A tuning table's entries: the layer shapes it keys and the tiles it
//! gives them (`[[conv]]` and `[[coop]]`), the levels it fuses
//! (`[[fused]]`), and the DCT filter's shape per frame size (`[[fft]]`).

use serde::{Deserialize, Serialize};

use super::super::codegen::coop::{CoopLimits, CoopTile};
use super::super::codegen::fused::FusedTile;
use super::super::codegen::{ConvTile, Dtype};

/// A register-tiled convolution as the tuner and the backend see it: its
/// taps, channels, input size (the layer's, not the frame's), storage and
/// arithmetic types.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConvShape {
    pub kernel: usize,
    pub cin: usize,
    pub cout: usize,
    pub width: u32,
    pub height: u32,
    /// "f32" or "f16".
    pub weights: DtypeName,
    pub arith: DtypeName,
}

/// A [`Dtype`] as the table spells it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DtypeName {
    F32,
    F16,
}

impl From<Dtype> for DtypeName {
    fn from(d: Dtype) -> Self {
        match d {
            Dtype::F32 => Self::F32,
            Dtype::F16 => Self::F16,
        }
    }
}

impl From<DtypeName> for Dtype {
    fn from(d: DtypeName) -> Self {
        match d {
            DtypeName::F32 => Self::F32,
            DtypeName::F16 => Self::F16,
        }
    }
}

/// One shape's tile, with what the tuner measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TunedConv {
    #[serde(flatten)]
    pub shape: ConvShape,
    /// Output pixels per thread along x (a tile `8 × px` wide).
    pub px: u32,
    /// Threads (output rows) along y.
    pub threads_y: u32,
    /// The layers of this shape at this tile, summed: the best of the
    /// tuner's repetitions, nanoseconds of device time.
    pub tuned_ns: u64,
    /// The same at the heuristics' tile.
    pub heuristic_ns: u64,
}

impl TunedConv {
    pub fn tile(&self) -> ConvTile {
        ConvTile {
            px: self.px,
            threads_y: self.threads_y,
        }
    }
}

/// A convolution on cooperative matrices as the tuner and the backend see
/// it: its taps (1 for the 2×2 transposed conv), channels and input size.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CoopShape {
    pub kernel: usize,
    pub cin: usize,
    pub cout: usize,
    pub width: u32,
    pub height: u32,
    /// The 2×2 stride-2 transposed conv.
    pub transposed: bool,
}

impl CoopShape {
    /// The GEMM's columns: output channels, 4 each for the transposed conv.
    pub fn columns(&self) -> usize {
        if self.transposed {
            4 * self.cout
        } else {
            self.cout
        }
    }

    /// The tiles worth timing for this shape on a device with `limits`
    /// and subgroups of `subgroup_size` ([`CoopTile::candidates`]).
    pub fn candidates(&self, subgroup_size: u32, limits: &CoopLimits) -> Vec<CoopTile> {
        CoopTile::candidates(
            self.columns(),
            self.height,
            self.kernel,
            subgroup_size,
            limits,
        )
    }
}

/// One cooperative-matrix shape's tile, with what the tuner measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TunedCoop {
    #[serde(flatten)]
    pub shape: CoopShape,
    /// Pixel rows of 16 and blocks of 16 columns a subgroup accumulates.
    pub rows: u32,
    pub blocks: u32,
    /// Subgroups of a workgroup stacked over rows and side by side over
    /// columns.
    pub sg_rows: u32,
    pub sg_cols: u32,
    /// 16-channel chunks staged at once (the K-slice); 1 in tables
    /// written before it was tuned.
    #[serde(default = "one_chunk")]
    pub chunks: u32,
    /// The next stage prefetched through registers; false in tables
    /// written before it was tuned.
    #[serde(default)]
    pub prefetch: bool,
    /// The stage gathered plane by plane; false in tables written before
    /// it was tuned.
    #[serde(default)]
    pub plane_gather: bool,
    /// The K-slice's weights staged in workgroup memory; false in tables
    /// written before it was tuned.
    #[serde(default)]
    pub stage_weights: bool,
    /// Every accumulator stored before one barrier, then drained; false
    /// in tables written before it was tuned.
    #[serde(default)]
    pub drain_once: bool,
    /// As [`TunedConv`]'s.
    pub tuned_ns: u64,
    pub heuristic_ns: u64,
}

impl TunedCoop {
    pub fn tile(&self) -> CoopTile {
        CoopTile {
            rows: self.rows,
            blocks: self.blocks,
            sg_rows: self.sg_rows,
            sg_cols: self.sg_cols,
            chunks: self.chunks,
            prefetch: self.prefetch,
            plane_gather: self.plane_gather,
            stage_weights: self.stage_weights,
            drain_once: self.drain_once,
        }
    }
}

fn one_chunk() -> u32 {
    1
}

/// Two register-tiled convolutions that can run as one fused level
/// (`shaders/conv_fused.wgsl`): the first's taps and input channels, the
/// intermediate's channels, the second's taps and output channels, the
/// level's size, storage and arithmetic types.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FusedShape {
    pub first_kernel: usize,
    pub kernel: usize,
    pub cin: usize,
    pub mid: usize,
    pub cout: usize,
    pub width: u32,
    pub height: u32,
    pub weights: DtypeName,
    pub arith: DtypeName,
}

impl std::fmt::Display for FusedShape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{0}×{0} {1}→{2}, {3}×{3} →{4} at {5}×{6}",
            self.first_kernel, self.cin, self.mid, self.kernel, self.cout, self.width, self.height
        )
    }
}

/// One level's fastest fused tile, with what the tuner measured: the level
/// runs fused where `fused_ns` is below `unfused_ns`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TunedFused {
    #[serde(flatten)]
    pub shape: FusedShape,
    /// Output pixels a workgroup computes.
    pub tile_width: u32,
    pub tile_height: u32,
    /// The levels of this shape fused at this tile, summed: the best of
    /// the tuner's repetitions, nanoseconds of device time.
    pub fused_ns: u64,
    /// The same levels' two convolutions unfused, at their tuned tiles.
    pub unfused_ns: u64,
}

impl TunedFused {
    pub fn tile(&self) -> FusedTile {
        FusedTile {
            width: self.tile_width,
            height: self.tile_height,
        }
    }

    /// Whether the runtime fuses this shape's levels.
    pub fn faster(&self) -> bool {
        self.fused_ns < self.unfused_ns
    }

    /// Why the entry's tile is not one the fused kernel builds, if it is
    /// not.
    pub fn invalid(&self) -> Option<String> {
        (!self.tile().is_valid()).then(|| {
            format!(
                "tile_width = {}, tile_height = {} is not a tile the fused kernel builds (8×8, \
                 16×8, 8×16, 16×16, 32×8 or 32×16)",
                self.tile_width, self.tile_height
            )
        })
    }
}

/// The DCT filter's workgroup-memory kernels at one frame size (issue 56,
/// item 4): threads a workgroup and at most that many sequence pairs a
/// workgroup ([`nedrt_gpu::fft::FusedVariant`]); either left out is the
/// heuristics' choice.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TunedFft {
    pub width: usize,
    pub height: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threads: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pairs: Option<u32>,
    /// The filter of three planes at this shape and at the heuristics':
    /// the best of the tuner's repetitions, nanoseconds of device time.
    pub tuned_ns: u64,
    pub heuristic_ns: u64,
}

impl TunedFft {
    pub fn variant(&self) -> nedrt_gpu::fft::FusedVariant {
        nedrt_gpu::fft::FusedVariant {
            threads: self.threads,
            max_seqs: self.pairs,
        }
    }

    /// Why the entry is not one the kernels build, if it is not: threads
    /// 32 to 1024, pairs 1, 2, 4 or 8 (`nedrt bench fft --fft-variants`'
    /// range), sides of at least 1.
    pub fn invalid(&self) -> Option<String> {
        if self.width == 0 || self.height == 0 {
            return Some(format!("a {}×{} frame", self.width, self.height));
        }
        if let Some(t) = self.threads
            && !(32..=1024).contains(&t)
        {
            return Some(format!("threads = {t}: must be 32 to 1024"));
        }
        if let Some(p) = self.pairs
            && ![1, 2, 4, 8].contains(&p)
        {
            return Some(format!("pairs = {p}: must be 1, 2, 4 or 8"));
        }
        None
    }
}
