//! The cooperative-matrix path (`shaders/conv_coop.wgsl`): which layers
//! take it on which adapter, and the template's unrolled parts.

use super::Dtype;

/// The one matrix shape the template uses: M = N = K = 16.
pub const SIZE: u32 = 16;
/// Blocks of 16 output columns the packed weights are padded to a
/// multiple of: the most a workgroup covers, so none reads past its
/// layer's weights.
pub const MAX_COLUMN_BLOCKS: u32 = 8;
/// The most accumulators (16×16 f32 matrices) a subgroup holds.
pub const MAX_ACCUMULATORS: u32 = 8;
/// The most subgroups in a workgroup.
pub const MAX_SUBGROUPS: u32 = 8;
/// The most pixel rows of 16 a workgroup covers.
pub const MAX_PIXEL_ROWS: u32 = 16;
/// The most 16-channel chunks staged at once (a K-slice of 64 channels).
pub const MAX_CHUNKS: u32 = 4;
/// The most values of the next stage an invocation prefetches into
/// registers (f16s: 16 32-bit registers at most, beside the accumulators).
pub const MAX_PREFETCH: u32 = 32;
/// The most workgroup memory a tile may ask for in a tuning table: what
/// the largest desktop adapters offer (AMD's 64 KiB; NVIDIA's Vulkan
/// drivers 48 KiB). Whether a tile fits the adapter at hand is
/// [`CoopTile::fits`].
pub const MAX_TABLE_WORKGROUP_BYTES: u32 = 65536;

/// How the cooperative kernel cuts a layer among workgroups and subgroups:
/// a workgroup of `sg_rows` × `sg_cols` subgroups, each accumulating `rows`
/// pixel rows of 16 × `blocks` blocks of 16 output columns (`rows` ×
/// `blocks` matrices). A workgroup covers 16 pixels × `rows`·`sg_rows`
/// rows × `blocks`·`sg_cols` blocks and stages its input tile once per
/// 16-channel chunk for all its subgroups; a subgroup reuses each staged
/// input matrix over its `blocks` and each weight matrix over its `rows`.
/// `chunks` is the K-slice: the 16-channel chunks of input staged between
/// two barriers (1, 2 or 4), so that a workgroup waits at fewer barriers
/// and has more loads in flight at once, for that many times the staging
/// memory. Every output is the same sum of the same products in the same
/// order whatever the tile: a tile changes the speed, never a bit of the
/// output. With `prefetch` each invocation loads its share of the next
/// stage into registers before the current stage's products and stores it
/// after them (double buffering through registers). With `plane_gather`
/// each invocation finds where its pixels of the staged tile lie once a
/// workgroup, then stages those pixels of every channel plane of a stage,
/// where the flat gather splits each staged value's index into chunk,
/// channel, row and column (the staged tile is the same either way). With
/// `stage_weights` the workgroup also copies its column blocks' weights of
/// each K-slice into workgroup memory beside the input, and its subgroups
/// load their weight matrices from there, not from the weight buffer:
/// subgroups stacked over rows then share one copy. With `drain_once` each
/// subgroup stores all its accumulators to workgroup memory, then after
/// one barrier drains them all, where one matrix at a time takes two
/// barriers each (for `rows` × `blocks` times the epilogue's memory).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct CoopTile {
    pub rows: u32,
    pub blocks: u32,
    pub sg_rows: u32,
    pub sg_cols: u32,
    pub chunks: u32,
    pub prefetch: bool,
    pub plane_gather: bool,
    pub stage_weights: bool,
    pub drain_once: bool,
}

impl CoopTile {
    /// The tile every layer had before tiles were chosen per layer (the
    /// H200's figures of 2026-11-27/28): four subgroups side by side over
    /// four column blocks, four rows each.
    pub const DEFAULT: CoopTile = CoopTile {
        rows: 4,
        blocks: 1,
        sg_rows: 1,
        sg_cols: 4,
        chunks: 1,
        prefetch: false,
        plane_gather: false,
        stage_weights: false,
        drain_once: false,
    };

    /// The heuristics' tile for a layer of `columns` GEMM columns (output
    /// channels; for the transposed conv 4 per channel): four subgroups of
    /// four rows and one block, side by side over as many blocks as the
    /// layer has (up to four), the rest stacked over rows. [`Self::DEFAULT`]
    /// for 64 or more columns; with 32 (two blocks) it leaves no subgroup
    /// computing columns past the layer, where the default idles half.
    pub fn for_layer(columns: usize) -> Self {
        let needed = (columns.div_ceil(SIZE as usize) as u32).max(1);
        let sg_cols = needed.next_power_of_two().min(4);
        CoopTile {
            rows: 4,
            blocks: 1,
            sg_rows: 4 / sg_cols,
            sg_cols,
            chunks: 1,
            prefetch: false,
            plane_gather: false,
            stage_weights: false,
            drain_once: false,
        }
    }

    pub fn subgroups(&self) -> u32 {
        self.sg_rows * self.sg_cols
    }

    /// Pixel rows of 16 a workgroup covers.
    pub fn pixel_rows(&self) -> u32 {
        self.rows * self.sg_rows
    }

    /// Blocks of 16 columns a workgroup covers.
    pub fn column_blocks(&self) -> u32 {
        self.blocks * self.sg_cols
    }

    /// Workgroup memory: the staged input tiles (f16, 16 channels a
    /// pixel, one per chunk of the K-slice), with `stage_weights` the
    /// K-slice's weights, and the epilogue's 16×16 f32 matrices.
    pub fn workgroup_bytes(&self, kernel: usize) -> u32 {
        (self.stage_values(kernel) + self.staged_weights(kernel)) * 2
            + self.subgroups() * self.drain_matrices() * 256 * 4
    }

    /// The epilogue's matrices a subgroup: all its accumulators with
    /// `drain_once`, else one.
    pub fn drain_matrices(&self) -> u32 {
        if self.drain_once {
            self.rows * self.blocks
        } else {
            1
        }
    }

    /// This tile drained at once, where the device with `limits` has the
    /// memory for it.
    pub fn drained_once(self, kernel: usize, sg: u32, limits: &CoopLimits) -> Option<Self> {
        CoopTile {
            drain_once: true,
            ..self
        }
        .fitting(kernel, sg, limits)
    }

    /// This tile where the device with `limits` runs it.
    fn fitting(self, kernel: usize, sg: u32, limits: &CoopLimits) -> Option<Self> {
        self.fits(kernel, sg, limits).then_some(self)
    }

    /// f16 weights a workgroup stages a K-slice with `stage_weights`:
    /// one 16×16 matrix per column block, chunk and tap; else none.
    pub fn staged_weights(&self, kernel: usize) -> u32 {
        let taps = (kernel * kernel) as u32;
        if self.stage_weights {
            self.column_blocks() * self.chunks * taps * 256
        } else {
            0
        }
    }

    /// This tile with its weights staged in workgroup memory, where the
    /// device with `limits` has the memory for them.
    pub fn weights_staged(self, kernel: usize, sg: u32, limits: &CoopLimits) -> Option<Self> {
        CoopTile {
            stage_weights: true,
            ..self
        }
        .fitting(kernel, sg, limits)
    }

    /// f16 values of one stage: the K-slice's input tiles, each
    /// `pixel_rows` + K − 1 rows of 16 + K − 1 pixels, 16 channels.
    fn stage_values(&self, kernel: usize) -> u32 {
        let k = kernel as u32;
        self.chunks * (self.pixel_rows() + k - 1) * (SIZE + k - 1) * 16
    }

    /// Whether the template builds this tile for a `kernel`×`kernel` conv:
    /// powers of two, at most [`MAX_ACCUMULATORS`] matrices a subgroup,
    /// [`MAX_SUBGROUPS`], [`MAX_COLUMN_BLOCKS`] and [`MAX_PIXEL_ROWS`] a
    /// workgroup, [`MAX_CHUNKS`] a stage, within
    /// [`MAX_TABLE_WORKGROUP_BYTES`]. Whether an adapter runs it is
    /// [`Self::fits`].
    pub fn is_valid(&self, kernel: usize) -> bool {
        let p2 = |v: u32| v.is_power_of_two();
        p2(self.rows)
            && p2(self.blocks)
            && p2(self.sg_rows)
            && p2(self.sg_cols)
            && p2(self.chunks)
            && self.chunks <= MAX_CHUNKS
            && self.rows * self.blocks <= MAX_ACCUMULATORS
            && self.subgroups() <= MAX_SUBGROUPS
            && self.column_blocks() <= MAX_COLUMN_BLOCKS
            && self.pixel_rows() <= MAX_PIXEL_ROWS
            && self.workgroup_bytes(kernel) <= MAX_TABLE_WORKGROUP_BYTES
    }

    /// Whether a device with `limits` and subgroups of `subgroup_size`
    /// runs this tile: valid, within its workgroup memory and its
    /// invocations a workgroup.
    pub fn fits(&self, kernel: usize, subgroup_size: u32, limits: &CoopLimits) -> bool {
        self.is_valid(kernel)
            && self.workgroup_bytes(kernel) <= limits.workgroup_bytes
            && self.subgroups() * subgroup_size <= limits.invocations
    }

    /// This tile with a K-slice of `chunks`.
    pub fn with_chunks(self, chunks: u32) -> Self {
        CoopTile { chunks, ..self }
    }

    /// Values of a stage each invocation stages (and with `prefetch`
    /// holds in registers) for subgroups of `subgroup_size`: its share of
    /// the stage, or with `plane_gather` its pixels of the tile times the
    /// stage's channels (an invocation without a last pixel idles there).
    pub fn staged_per_invocation(&self, kernel: usize, subgroup_size: u32) -> u32 {
        let threads = self.subgroups() * subgroup_size;
        if self.plane_gather {
            self.chunks * 16 * self.gather_slots(kernel, subgroup_size)
        } else {
            self.stage_values(kernel).div_ceil(threads)
        }
    }

    /// Pixels of the staged tile (`pixel_rows` + K − 1 rows of 16 + K − 1)
    /// each invocation gathers with `plane_gather`.
    pub fn gather_slots(&self, kernel: usize, subgroup_size: u32) -> u32 {
        let k = kernel as u32;
        ((self.pixel_rows() + k - 1) * (SIZE + k - 1)).div_ceil(self.subgroups() * subgroup_size)
    }

    /// This tile staged plane by plane.
    pub fn plane_gathered(self) -> Self {
        CoopTile {
            plane_gather: true,
            ..self
        }
    }

    /// This tile with its next stage prefetched through registers, where
    /// the registers it takes are at most [`MAX_PREFETCH`] f16s an
    /// invocation (more would spill them to memory).
    pub fn prefetched(self, kernel: usize, subgroup_size: u32) -> Option<Self> {
        (self.staged_per_invocation(kernel, subgroup_size) <= MAX_PREFETCH).then_some(CoopTile {
            prefetch: true,
            ..self
        })
    }

    /// The tiles worth timing for a layer of `columns` GEMM columns and
    /// `height` rows, one chunk a stage: 2 to 8 rows and 1 or 2 blocks a
    /// subgroup, 4 or 8 subgroups, no block of columns wholly past the
    /// layer nor a row of tiles wholly below it, fitting the device; the
    /// heuristics' tile first, and [`Self::DEFAULT`] always (the tile
    /// earlier GPU runs measured, so that a run compares against it). The
    /// K-slices are [`Self::slices`] of the best of these.
    pub fn candidates(
        columns: usize,
        height: u32,
        kernel: usize,
        subgroup_size: u32,
        limits: &CoopLimits,
    ) -> Vec<CoopTile> {
        let needed = (columns.div_ceil(SIZE as usize) as u32).max(1);
        let (max_blocks, max_rows) = (
            needed.next_power_of_two(),
            height.max(1).next_power_of_two(),
        );
        let heuristic = Self::for_layer(columns);
        let mut out = vec![heuristic];
        if heuristic != Self::DEFAULT {
            out.push(Self::DEFAULT);
        }
        for rows in [2, 4, 8] {
            for blocks in [1, 2] {
                for (sg_rows, sg_cols) in [(1, 4), (2, 2), (4, 1), (1, 8), (2, 4), (4, 2), (8, 1)] {
                    let t = CoopTile {
                        rows,
                        blocks,
                        sg_rows,
                        sg_cols,
                        chunks: 1,
                        prefetch: false,
                        plane_gather: false,
                        stage_weights: false,
                        drain_once: false,
                    };
                    if t.fits(kernel, subgroup_size, limits)
                        && t.column_blocks() <= max_blocks
                        && t.pixel_rows() <= max_rows
                        && !out.contains(&t)
                    {
                        out.push(t);
                    }
                }
            }
        }
        out
    }

    /// The K-slices worth timing beside this tile for a layer of `cin`
    /// input channels: 2 and 4 chunks a stage where the layer has that
    /// many chunks and the device the memory.
    pub fn slices(
        self,
        cin: usize,
        kernel: usize,
        subgroup_size: u32,
        limits: &CoopLimits,
    ) -> Vec<CoopTile> {
        let chunks = cin.div_ceil(SIZE as usize) as u32;
        [2, 4]
            .into_iter()
            .filter(|&c| c <= chunks)
            .map(|c| self.with_chunks(c))
            .filter(|t| t.fits(kernel, subgroup_size, limits))
            .collect()
    }
}

/// What a device allows one workgroup, as the cooperative tiles need it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CoopLimits {
    /// Bytes of workgroup memory.
    pub workgroup_bytes: u32,
    /// Invocations.
    pub invocations: u32,
}

impl CoopLimits {
    /// What every WebGPU adapter offers.
    pub const PORTABLE: CoopLimits = CoopLimits {
        workgroup_bytes: super::WORKGROUP_BYTES,
        invocations: 256,
    };

    /// A device's limits (as opened: `nedrt_gpu::open_device` asks for
    /// the adapter's own).
    pub fn of(limits: &wgpu::Limits) -> Self {
        CoopLimits {
            workgroup_bytes: limits.max_compute_workgroup_storage_size,
            invocations: limits.max_compute_invocations_per_workgroup,
        }
    }
}

/// Where the adapter can run the template: its subgroup size.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CoopAdapter {
    pub subgroup_size: u32,
}

/// Why a convolution does not run on cooperative matrices.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NoCoop {
    #[error(
        "the device has no cooperative matrices (its adapter lists no 16×16×16 f16→f32 shape, \
         or it was opened without f16)"
    )]
    NotOnDevice,
    #[error("the device was opened without {0}")]
    MissingFeatures(String),
    #[error("the adapter's subgroups are {min}–{max} invocations; the kernel needs one size")]
    SubgroupSizes { min: u32, max: u32 },
    #[error("tiled kernels asked for")]
    TiledAsked,
    #[error("needs f16 storage")]
    NeedsF16,
    #[error("{0} input channels, under one 16-channel matrix")]
    FewInputs(usize),
    #[error(
        "{cout} output channels, under {min}: the tiled kernel is faster there \
         (the H200, docs/benchmarks.md)"
    )]
    FewOutputs { cout: usize, min: usize },
}

/// Output channels under which a 3×3 convolution stays on the tiled
/// kernels: on the H200 (2026-11-27) the 16-channel layers at full
/// resolution took 1.17–1.22× the tiled f16 kernel's time on cooperative
/// matrices (each tile's staging feeds one 16-wide matrix column), the
/// 32-channel ones 0.60–0.65×.
pub const MIN_OUTPUTS: usize = 32;
/// The same for the 2×2 transposed convolutions: 32→16 took 1.35× the
/// tiled kernel's time there, 64→32 0.96–1.12×, 128→64 0.76–0.95×, 256→128 0.66×.
pub const MIN_OUTPUTS_TRANSPOSED: usize = 64;

/// The cooperative-matrix path on a device, or why not: its features
/// (`nedrt_gpu::open_device` enables cooperative matrices only where the
/// adapter lists the 16×16×16 f16→f32 shape) and its subgroup sizes.
pub fn device_support(
    features: wgpu::Features,
    subgroup_sizes: (u32, u32),
) -> Result<CoopAdapter, NoCoop> {
    if !features.contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX) {
        return Err(NoCoop::NotOnDevice);
    }
    let needed = wgpu::Features::SUBGROUP | wgpu::Features::SHADER_F16;
    if !features.contains(needed) {
        return Err(NoCoop::MissingFeatures(format!(
            "{:?}",
            needed - (features & needed)
        )));
    }
    let (min, max) = subgroup_sizes;
    if min != max || min == 0 || min > 128 || !min.is_power_of_two() {
        return Err(NoCoop::SubgroupSizes { min, max });
    }
    Ok(CoopAdapter { subgroup_size: min })
}

/// Whether a layer of `cin` → `cout` channels in `weights` storage can take
/// the cooperative-matrix path on a capable device, or why not.
pub fn layer_fits(cin: usize, cout: usize, weights: Dtype, transposed: bool) -> Result<(), NoCoop> {
    if weights != Dtype::F16 {
        return Err(NoCoop::NeedsF16);
    }
    if cin < SIZE as usize {
        return Err(NoCoop::FewInputs(cin));
    }
    let min = if transposed {
        MIN_OUTPUTS_TRANSPOSED
    } else {
        MIN_OUTPUTS
    };
    if cout < min {
        return Err(NoCoop::FewOutputs { cout, min });
    }
    Ok(())
}

/// The accumulators: `c{r}_{n}`, one 16×16 f32 matrix per pixel row and
/// block of columns.
pub(super) fn accumulators(tile: CoopTile) -> String {
    let mut s = String::new();
    for r in 0..tile.rows {
        for n in 0..tile.blocks {
            s += &format!("    var c{r}_{n} = coop_mat16x16<f32, C>();\n");
        }
    }
    s
}

/// One tap's products: the tap's weights of each of the subgroup's column
/// blocks (from the weight buffer, or with `stage_weights` from the
/// workgroup's copy of the K-slice's), then per pixel row its 16 pixels ×
/// 16 channels from the staged tile times each of them.
pub(super) fn taps(tile: CoopTile) -> String {
    let mut s = String::new();
    let pad = "                ";
    for n in 0..tile.blocks {
        let at = if tile.stage_weights {
            format!(
                "&b_tile[((((sg % SG_COLS) * BLOCKS + {n}u) * CHUNKS + s) * K * K + tap) * 256u]"
            )
        } else {
            format!(
                "&weights[p.w_offset + (((blk0 + {n}u) * chunks + chunk) * K * K + tap) * 256u]"
            )
        };
        s += &format!("{pad}let b{n} = coopLoadT<coop_mat16x16<f16, B>>(\n{pad}    {at}, 16u);\n");
    }
    for r in 0..tile.rows {
        s += &format!(
            "{pad}let a{r} = coopLoadT<coop_mat16x16<f16, A>>(&a_tile[abase + ((row0 + {r}u + ky) * IN_W + kx) * 16u], 16u);\n"
        );
        for n in 0..tile.blocks {
            s += &format!("{pad}c{r}_{n} = coopMultiplyAdd(a{r}, b{n}, c{r}_{n});\n");
        }
    }
    s
}

/// With `stage_weights`, the staged weights' declaration (declared only
/// then: a declared array takes workgroup memory even where unread).
pub(super) fn b_tile(tile: CoopTile, kernel: usize) -> String {
    if !tile.stage_weights {
        return String::new();
    }
    format!(
        "// The staged weights: [column block of the workgroup][chunk of the
// stage][tap][row][column] (CoopTile::staged_weights).
const B_VALUES: u32 = {}u;
var<workgroup> b_tile: array<f16, B_VALUES>;",
        tile.staged_weights(kernel)
    )
}

/// With `stage_weights`, the copy of the workgroup's column blocks' weights
/// of the stage at chunk `first` into `b_tile`, before the stage's barrier.
pub(super) fn copy_weights(tile: CoopTile) -> String {
    if !tile.stage_weights {
        return String::new();
    }
    "        // The workgroup's first column block's weights of chunk `first`,
        // and from there the stage's (contiguous as packed); chunks past
        // the layer are never read.
        let wbase = p.w_offset + (wg.z * SG_COLS * BLOCKS * chunks + first) * K * K * 256u;
        for (var i = li; i < B_VALUES; i += THREADS) {
            let nb = i / BLOCK_WEIGHTS;
            let rest = i % BLOCK_WEIGHTS;
            var v = f16(0.0);
            if (first + rest / (K * K * 256u) < chunks) {
                v = weights[wbase + nb * chunks * K * K * 256u + rest];
            }
            b_tile[i] = v;
        }
"
    .into()
}

/// Each accumulator out through workgroup memory and the epilogue.
pub(super) fn stores(tile: CoopTile) -> String {
    let mut s = String::new();
    let mats: Vec<(u32, u32)> = (0..tile.rows)
        .flat_map(|r| (0..tile.blocks).map(move |n| (r, n)))
        .collect();
    if tile.drain_once {
        // Matrix r·blocks + n of the subgroup's DRAIN_MATS.
        for &(r, n) in &mats {
            let m = r * tile.blocks + n;
            s += &format!(
                "    coopStoreT(c{r}_{n}, &c_tile[(sg * DRAIN_MATS + {m}u) * 256u], 16u);\n"
            );
        }
        s += "    workgroupBarrier();\n";
        for &(r, n) in &mats {
            let m = r * tile.blocks + n;
            s += &format!(
                "    drain(sg * DRAIN_MATS + {m}u, lane, blk0 + {n}u, x0, y0 + row0 + {r}u);\n"
            );
        }
        return s;
    }
    for (r, n) in mats {
        s += &format!(
            "    coopStoreT(c{r}_{n}, &c_tile[sg * 256u], 16u);\n    workgroupBarrier();\n    drain(sg, lane, blk0 + {n}u, x0, y0 + row0 + {r}u);\n    workgroupBarrier();\n"
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_layer_without_idle_subgroups() {
        // 64 columns and more: the tile the H200 measured.
        assert_eq!(CoopTile::for_layer(64), CoopTile::DEFAULT);
        assert_eq!(CoopTile::for_layer(4 * 128), CoopTile::DEFAULT);
        // 32 columns: two blocks side by side, two stacked over rows, where
        // the default gave two of its four subgroups columns past the layer.
        let t = CoopTile::for_layer(32);
        assert_eq!((t.sg_cols, t.sg_rows, t.subgroups()), (2, 2, 4));
        assert_eq!(t.column_blocks(), 2);
        let portable = CoopLimits::PORTABLE;
        for (columns, height, kernel) in [(32, 540, 3), (64, 1080, 3), (512, 68, 1), (48, 3, 3)] {
            let c = CoopTile::candidates(columns, height, kernel, 32, &portable);
            assert_eq!(c[0], CoopTile::for_layer(columns));
            assert!(c.contains(&CoopTile::DEFAULT));
            let needed = columns.div_ceil(16) as u32;
            for t in c.iter().filter(|t| **t != CoopTile::DEFAULT) {
                assert!(t.fits(kernel, 32, &portable), "{t:?}");
                assert!(t.workgroup_bytes(kernel) <= super::super::WORKGROUP_BYTES);
                assert_eq!(t.chunks, 1, "{t:?}");
                assert!(t.column_blocks() <= needed.next_power_of_two(), "{t:?}");
            }
            let unique: std::collections::HashSet<_> = c.iter().collect();
            assert_eq!(unique.len(), c.len());
            assert!(c.len() > 1, "{columns} columns: {c:?}");
        }
        // What the template cannot build.
        let ok = CoopTile::DEFAULT;
        for bad in [
            CoopTile { rows: 3, ..ok },
            CoopTile {
                rows: 8,
                blocks: 2,
                ..ok
            },
            CoopTile {
                sg_rows: 4,
                sg_cols: 4,
                ..ok
            },
            CoopTile {
                blocks: 4,
                sg_cols: 4,
                ..ok
            },
            CoopTile {
                rows: 8,
                sg_rows: 4,
                sg_cols: 1,
                ..ok
            },
            CoopTile { rows: 0, ..ok },
        ] {
            assert!(!bad.is_valid(3), "{bad:?}");
        }
    }

    #[test]
    fn an_adapter_with_more_workgroup_memory_gets_larger_tiles_and_k_slices() {
        let portable = CoopLimits::PORTABLE;
        // NVIDIA's Vulkan drivers: 48 KiB, 1024 invocations.
        let nvidia = CoopLimits {
            workgroup_bytes: 49152,
            invocations: 1024,
        };
        let small = CoopTile::candidates(64, 1080, 3, 32, &portable);
        let large = CoopTile::candidates(64, 1080, 3, 32, &nvidia);
        assert!(small.iter().all(|t| large.contains(t)));
        // 8 subgroups over 16 rows of 16 pixels: 18.1 KiB.
        let tall = CoopTile {
            rows: 8,
            blocks: 1,
            sg_rows: 2,
            sg_cols: 4,
            chunks: 1,
            prefetch: false,
            plane_gather: false,
            stage_weights: false,
            drain_once: false,
        };
        assert!(!small.contains(&tall) && large.contains(&tall), "{large:?}");
        assert!(tall.fits(3, 32, &nvidia) && !tall.fits(3, 32, &portable));
        // Eight subgroups of 64 are 512 invocations, over 256.
        assert!(!tall.fits(3, 64, &portable) && tall.fits(3, 64, &nvidia));
        // K-slices: as many chunks as the layer has, and the memory allows.
        let d = CoopTile::DEFAULT;
        assert_eq!(d.slices(16, 3, 32, &nvidia), vec![]);
        assert_eq!(d.slices(48, 3, 32, &nvidia), vec![d.with_chunks(2)]);
        assert_eq!(
            d.slices(64, 3, 32, &nvidia),
            vec![d.with_chunks(2), d.with_chunks(4)]
        );
        // 4 chunks of the default's 6×18 pixels are 13.5 KiB, with its
        // 4 KiB of epilogue over 16 KiB.
        assert_eq!(d.slices(64, 3, 32, &portable), vec![d.with_chunks(2)]);
        assert!(!d.with_chunks(3).is_valid(3) && !d.with_chunks(8).is_valid(3));
        assert!(!d.with_chunks(0).is_valid(3));
        // Prefetch: the default's 6 × 18 × 16 staged values over 128
        // invocations are 14 each; 4 chunks of it 54, over the registers.
        assert_eq!(d.staged_per_invocation(3, 32), 14);
        assert_eq!(d.with_chunks(4).staged_per_invocation(3, 32), 54);
        assert_eq!(d.prefetched(3, 32).map(|t| t.prefetch), Some(true));
        assert_eq!(d.with_chunks(4).prefetched(3, 32), None);
        assert!(
            CoopTile::candidates(64, 1080, 3, 32, &nvidia)
                .iter()
                .all(|t| !t.prefetch)
        );
    }

    #[test]
    fn the_path_is_taken_only_where_device_and_layer_allow_it() {
        use wgpu::Features as F;
        let all = F::EXPERIMENTAL_COOPERATIVE_MATRIX | F::SUBGROUP | F::SHADER_F16;
        assert_eq!(
            device_support(all, (32, 32)),
            Ok(CoopAdapter { subgroup_size: 32 })
        );
        // lavapipe: no cooperative matrices listed, so none enabled.
        let e = device_support(F::SHADER_F16 | F::SUBGROUP, (8, 8)).expect_err("none");
        assert!(e.to_string().contains("no cooperative matrices"), "{e}");
        let e = device_support(F::EXPERIMENTAL_COOPERATIVE_MATRIX | F::SHADER_F16, (32, 32))
            .expect_err("no subgroups");
        assert!(e.to_string().contains("SUBGROUP"), "{e}");
        // A subgroup size that varies (AMD's 32–64) leaves the kernel unsure
        // how many subgroups a workgroup holds.
        let e = device_support(all, (32, 64)).expect_err("varies");
        assert!(e.to_string().contains("32–64"), "{e}");

        assert_eq!(layer_fits(16, 32, Dtype::F16, false), Ok(()));
        assert_eq!(layer_fits(32, 32, Dtype::F32, false), Err(NoCoop::NeedsF16));
        assert_eq!(
            layer_fits(3, 32, Dtype::F16, false),
            Err(NoCoop::FewInputs(3))
        );
        // The narrow layers, where the H200 ran the tiled kernels faster.
        assert_eq!(
            layer_fits(32, 16, Dtype::F16, false),
            Err(NoCoop::FewOutputs { cout: 16, min: 32 })
        );
        assert_eq!(layer_fits(128, 64, Dtype::F16, true), Ok(()));
        assert_eq!(
            layer_fits(64, 32, Dtype::F16, true),
            Err(NoCoop::FewOutputs { cout: 32, min: 64 })
        );
    }
}
