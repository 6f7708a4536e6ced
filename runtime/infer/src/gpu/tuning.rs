//! Tuned conv tiles per adapter (issue 56 item 4, docs/tuning.md).
//! `nedrt bench tune` times every convolution at each tile on the adapter
//! it runs on (the register-tiled kernel's [`ConvTile`]s; on an adapter
//! with cooperative matrices, their kernel's [`CoopTile`]s) and writes the
//! fastest per layer shape into a table, one TOML file per adapter and
//! driver under `tuning/`. The backend reads the table matching its
//! adapter and driver when it is made (`BackendOptions::tuning_dir`); a
//! layer shape the table lacks, or an adapter without a table, gets
//! [`ConvTile::for_layer`] or [`CoopTile::for_layer`], the heuristics. A
//! tile changes only how the output is cut among workgroups and
//! subgroups, never the order a pixel's products are summed in, so a tuned
//! network computes the heuristics' output bit for bit (the tuner checks
//! it before writing).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::codegen::coop::{self, CoopTile};
use super::codegen::fused::FusedTile;
use super::codegen::{ConvTile, Dtype, WORKGROUP_BYTES};
use crate::InferenceError;

/// The largest table read (a table holds a few hundred short entries).
const MAX_TABLE_BYTES: u64 = 1 << 20;

/// Which adapter and driver a table was measured on: a table is used only
/// where all of these match.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AdapterKey {
    pub name: String,
    pub vendor: u32,
    pub device: u32,
    pub driver: String,
    pub driver_info: String,
    /// wgpu's backend (Vulkan, Metal, Dx12, Gl).
    pub backend: String,
}

impl AdapterKey {
    pub fn of(info: &wgpu::AdapterInfo) -> Self {
        Self {
            name: info.name.clone(),
            vendor: info.vendor,
            device: info.device,
            driver: info.driver.clone(),
            driver_info: info.driver_info.clone(),
            backend: format!("{:?}", info.backend),
        }
    }

    /// The table's file name: the adapter's name and driver version, lower
    /// case, runs of other characters as one `-`, then its PCI vendor and
    /// device and wgpu's backend (so that two adapters of one name do not
    /// share a file).
    pub fn file_name(&self) -> String {
        let mut slug = String::new();
        for c in format!("{} {}", self.name, self.driver_info).chars() {
            if c.is_ascii_alphanumeric() {
                slug.push(c.to_ascii_lowercase());
            } else if !slug.ends_with('-') {
                slug.push('-');
            }
        }
        let slug: String = slug.trim_matches('-').chars().take(80).collect();
        let slug = slug.trim_end_matches('-');
        format!(
            "{}-{:04x}-{:04x}-{}.toml",
            if slug.is_empty() { "adapter" } else { slug },
            self.vendor,
            self.device,
            self.backend.to_ascii_lowercase()
        )
    }
}

mod entries;
pub use entries::{
    ConvShape, CoopShape, DtypeName, FusedShape, TunedConv, TunedCoop, TunedFft, TunedFused,
};

/// Every tile the template builds for a `kernel`×`kernel` conv summing in
/// `arith`: 8, 16 or 32 pixels wide, 1 to 16 rows, one quad's staging
/// within [`WORKGROUP_BYTES`].
pub fn tile_is_valid(tile: ConvTile, kernel: usize, arith: Dtype) -> bool {
    [1, 2, 4].contains(&tile.px)
        && tile.threads_y.is_power_of_two()
        && tile.threads_y <= ConvTile::LARGE.threads_y
        && tile.workgroup_bytes(kernel, 1, arith) <= WORKGROUP_BYTES
}

/// The tiles worth timing for a layer of `width`×`height`: the valid ones
/// no wider than the layer needs (8 pixels, or the power of two at least
/// its width) nor taller.
pub fn candidate_tiles(width: u32, height: u32, kernel: usize, arith: Dtype) -> Vec<ConvTile> {
    let (max_w, max_h) = (
        width.max(1).next_power_of_two().max(ConvTile::THREADS_X),
        height.max(1).next_power_of_two(),
    );
    let mut out = Vec::new();
    for px in [4, 2, 1] {
        for threads_y in [16, 8, 4, 2, 1] {
            let tile = ConvTile { px, threads_y };
            let (w, h) = tile.pixels();
            if w <= max_w && h <= max_h && tile_is_valid(tile, kernel, arith) {
                out.push(tile);
            }
        }
    }
    out
}

/// One adapter's table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TuningTable {
    pub adapter: AdapterKey,
    /// The nedrt that measured it.
    pub nedrt: String,
    /// blake3 of the conv template the tiles were timed on (16 hex
    /// digits): a table from another template still computes the same
    /// output, but its times may no longer rank the tiles.
    pub template: String,
    #[serde(default, rename = "conv")]
    pub convs: Vec<TunedConv>,
    #[serde(default, rename = "coop", skip_serializing_if = "Vec::is_empty")]
    pub coops: Vec<TunedCoop>,
    /// The fused levels timed, each fused where it was faster.
    #[serde(default, rename = "fused", skip_serializing_if = "Vec::is_empty")]
    pub fused: Vec<TunedFused>,
    /// The DCT filter's shape per frame size (docs/tuning.md).
    #[serde(default, rename = "fft", skip_serializing_if = "Vec::is_empty")]
    pub ffts: Vec<TunedFft>,
}

/// The conv templates' hash (register-tiled, cooperative and fused), as tables
/// record it.
pub fn template_hash() -> String {
    let mut h = blake3::Hasher::new();
    h.update(super::codegen::CONV_TEMPLATE.as_bytes());
    h.update(super::codegen::COOP_TEMPLATE.as_bytes());
    h.update(super::codegen::FUSED_TEMPLATE.as_bytes());
    h.finalize().to_hex()[..16].to_string()
}

/// A table entry's taps: 1 to [`super::codegen::MAX_CONV_KERNEL`].
fn check_kernel(path: &Path, at: &str, kernel: usize) -> Result<(), InferenceError> {
    if kernel == 0 || kernel > super::codegen::MAX_CONV_KERNEL {
        return Err(bad(
            path,
            format!(
                "{at}: kernel must be 1 to {}",
                super::codegen::MAX_CONV_KERNEL
            ),
        ));
    }
    Ok(())
}

fn bad(path: &Path, reason: impl std::fmt::Display) -> InferenceError {
    InferenceError::Tuning {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    }
}

impl TuningTable {
    /// A table of `convs` and `coops` for `adapter`, stamped with this
    /// nedrt and the conv templates' hash.
    pub fn new(adapter: AdapterKey, convs: Vec<TunedConv>, coops: Vec<TunedCoop>) -> Self {
        Self {
            adapter,
            nedrt: env!("CARGO_PKG_VERSION").to_string(),
            template: template_hash(),
            convs,
            coops,
            fused: Vec::new(),
            ffts: Vec::new(),
        }
    }

    /// Parses and checks a table: every tile one the template builds, no
    /// shape twice.
    pub fn parse(text: &str, path: &Path) -> Result<Self, InferenceError> {
        let table: Self = toml::from_str(text).map_err(|e| {
            let line = e.span().map_or(0, |r| {
                text[..r.start.min(text.len())].matches('\n').count() + 1
            });
            if line > 0 {
                bad(path, format!("line {line}: {}", e.message()))
            } else {
                bad(path, e.message())
            }
        })?;
        let mut seen = HashMap::new();
        for (i, c) in table.convs.iter().enumerate() {
            let at = format!(
                "conv entry {} ({}×{} {}→{} at {}×{})",
                i + 1,
                c.shape.kernel,
                c.shape.kernel,
                c.shape.cin,
                c.shape.cout,
                c.shape.width,
                c.shape.height
            );
            check_kernel(path, &at, c.shape.kernel)?;
            if !tile_is_valid(c.tile(), c.shape.kernel, c.shape.arith.into()) {
                return Err(bad(
                    path,
                    format!(
                        "{at}: px = {}, threads_y = {} is not a tile the conv kernel builds \
                     (px 1, 2 or 4; threads_y a power of two up to 16; within {WORKGROUP_BYTES} \
                     bytes of workgroup memory)",
                        c.px, c.threads_y
                    ),
                ));
            }
            if let Some(j) = seen.insert(c.shape, i) {
                return Err(bad(
                    path,
                    format!("{at}: the same shape as conv entry {}", j + 1),
                ));
            }
        }
        let mut seen = HashMap::new();
        for (i, c) in table.coops.iter().enumerate() {
            let s = c.shape;
            let at = format!(
                "coop entry {} ({}×{} {}→{}{} at {}×{})",
                i + 1,
                s.kernel,
                s.kernel,
                s.cin,
                s.cout,
                if s.transposed { " transposed" } else { "" },
                s.width,
                s.height
            );
            check_kernel(path, &at, s.kernel)?;
            if !c.tile().is_valid(s.kernel) {
                return Err(bad(
                    path,
                    format!(
                        "{at}: rows = {}, blocks = {}, sg_rows = {}, sg_cols = {}, chunks = {} \
                         is not a tile the cooperative kernel builds (powers of two; rows × \
                         blocks at most {}, sg_rows × sg_cols at most {}, blocks × sg_cols at \
                         most {}, rows × sg_rows at most {}, chunks at most {}; within {} \
                         bytes of workgroup memory)",
                        c.rows,
                        c.blocks,
                        c.sg_rows,
                        c.sg_cols,
                        c.chunks,
                        coop::MAX_ACCUMULATORS,
                        coop::MAX_SUBGROUPS,
                        coop::MAX_COLUMN_BLOCKS,
                        coop::MAX_PIXEL_ROWS,
                        coop::MAX_CHUNKS,
                        coop::MAX_TABLE_WORKGROUP_BYTES,
                    ),
                ));
            }
            if let Some(j) = seen.insert(s, i) {
                return Err(bad(
                    path,
                    format!("{at}: the same shape as coop entry {}", j + 1),
                ));
            }
        }
        let mut seen = HashMap::new();
        for (i, f) in table.fused.iter().enumerate() {
            let (s, at) = (f.shape, format!("fused entry {} ({})", i + 1, f.shape));
            check_kernel(path, &at, s.first_kernel)?;
            check_kernel(path, &at, s.kernel)?;
            if let Some(why) = f.invalid() {
                return Err(bad(path, format!("{at}: {why}")));
            }
            if let Some(j) = seen.insert(s, i) {
                return Err(bad(
                    path,
                    format!("{at}: the same shape as fused entry {}", j + 1),
                ));
            }
        }
        let mut seen = HashMap::new();
        for (i, f) in table.ffts.iter().enumerate() {
            let at = format!("fft entry {} ({}×{})", i + 1, f.width, f.height);
            if let Some(why) = f.invalid() {
                return Err(bad(path, format!("{at}: {why}")));
            }
            if let Some(j) = seen.insert((f.width, f.height), i) {
                return Err(bad(
                    path,
                    format!("{at}: the same frame size as fft entry {}", j + 1),
                ));
            }
        }
        Ok(table)
    }

    /// Reads one table file.
    pub fn read(path: &Path) -> Result<Self, InferenceError> {
        let bytes =
            nedrt_core::util::read_capped(path, MAX_TABLE_BYTES).map_err(|e| bad(path, e))?;
        let text = String::from_utf8(bytes).map_err(|_| bad(path, "not UTF-8 text"))?;
        Self::parse(&text, path)
    }

    /// The table in `dir` for `adapter`, with its path: the file of its
    /// [`AdapterKey::file_name`], if there is one and its `[adapter]` is
    /// this adapter. A broken file of that name is an error naming it;
    /// other files in `dir` are not read.
    pub fn find(
        dir: &Path,
        adapter: &AdapterKey,
    ) -> Result<Option<(PathBuf, Self)>, InferenceError> {
        let path = dir.join(adapter.file_name());
        if !path.is_file() {
            return Ok(None);
        }
        let table = Self::read(&path)?;
        if &table.adapter != adapter {
            tracing::warn!(
                "{} is the table of another adapter ({}, driver {}): not used",
                path.display(),
                table.adapter.name,
                table.adapter.driver_info
            );
            return Ok(None);
        }
        Ok(Some((path, table)))
    }

    /// The tuned tile for `shape`, if the table has it.
    pub fn tile_for(&self, shape: &ConvShape) -> Option<ConvTile> {
        self.convs
            .iter()
            .find(|c| &c.shape == shape)
            .map(TunedConv::tile)
    }

    /// The tuned cooperative tile for `shape`, if the table has it.
    pub fn coop_tile_for(&self, shape: &CoopShape) -> Option<CoopTile> {
        self.coops
            .iter()
            .find(|c| &c.shape == shape)
            .map(TunedCoop::tile)
    }

    /// The fused tile for `shape`'s levels, if the table has the shape and
    /// fusing it was faster.
    pub fn fused_tile_for(&self, shape: &FusedShape) -> Option<FusedTile> {
        self.fused
            .iter()
            .find(|f| &f.shape == shape && f.faster())
            .map(TunedFused::tile)
    }

    /// Merges `fused` in, a shape in both taking the new entry.
    pub fn merge_fused(&mut self, fused: Vec<TunedFused>) {
        for f in fused {
            match self.fused.iter_mut().find(|e| e.shape == f.shape) {
                Some(e) => *e = f,
                None => self.fused.push(f),
            }
        }
    }

    /// Writes the table into `dir` under its adapter's file name (made if
    /// missing), atomically: an existing table stays whole until the new
    /// one replaces it. A file of that name holding another adapter's
    /// table is not overwritten.
    pub fn save(&self, dir: &Path) -> Result<PathBuf, InferenceError> {
        std::fs::create_dir_all(dir).map_err(|e| bad(dir, e))?;
        let path = dir.join(self.adapter.file_name());
        if let Some(other) = path.is_file().then(|| Self::read(&path).ok()).flatten()
            && other.adapter != self.adapter
        {
            return Err(bad(
                &path,
                format!(
                    "holds the table of another adapter ({}, driver {}); move it before \
                     tuning {}",
                    other.adapter.name, other.adapter.driver_info, self.adapter.name
                ),
            ));
        }
        let text = toml::to_string(self).map_err(|e| bad(&path, e))?;
        let header = "# Conv tiles and DCT filter shapes tuned on this adapter by `nedrt bench tune` \
                      (docs/tuning.md).\n";
        nedrt_core::util::write_atomic(&path, format!("{header}{text}").as_bytes())
            .map_err(|e| bad(&path, e))?;
        Ok(path)
    }

    /// The DCT filter's tuned shapes: ((width, height), shape).
    pub fn fft_shapes(&self) -> Vec<((usize, usize), nedrt_gpu::fft::FusedVariant)> {
        self.ffts
            .iter()
            .map(|f| ((f.width, f.height), f.variant()))
            .collect()
    }

    /// Merges `ffts` in, a frame size in both taking the new entry.
    pub fn merge_ffts(&mut self, ffts: Vec<TunedFft>) {
        for f in ffts {
            match self
                .ffts
                .iter_mut()
                .find(|e| (e.width, e.height) == (f.width, f.height))
            {
                Some(e) => *e = f,
                None => self.ffts.push(f),
            }
        }
    }

    /// Merges `convs` and `coops` in, a shape in both taking the new entry.
    pub fn merge(&mut self, convs: Vec<TunedConv>, coops: Vec<TunedCoop>) {
        for c in convs {
            match self.convs.iter_mut().find(|e| e.shape == c.shape) {
                Some(e) => *e = c,
                None => self.convs.push(c),
            }
        }
        for c in coops {
            match self.coops.iter_mut().find(|e| e.shape == c.shape) {
                Some(e) => *e = c,
                None => self.coops.push(c),
            }
        }
    }
}

/// The table in `dir` for the adapter of `info`, said in the log either
/// way; a broken table in `dir` is an error naming it.
pub fn table_for(
    dir: &Path,
    info: &wgpu::AdapterInfo,
) -> Result<Option<std::sync::Arc<TuningTable>>, InferenceError> {
    let key = AdapterKey::of(info);
    match TuningTable::find(dir, &key)? {
        Some((path, table)) => {
            tracing::info!(
                "conv tiles of {} ({} shapes) tuned for {}",
                path.display(),
                table.convs.len() + table.coops.len() + table.fused.len(),
                key.name
            );
            if table.template != template_hash() {
                tracing::warn!(
                    "{} was tuned on another conv template ({}, this one is {}): its tiles \
                     compute the same output, but may no longer be the fastest; run \
                     `nedrt bench tune` again",
                    path.display(),
                    table.template,
                    template_hash()
                );
            }
            Ok(Some(std::sync::Arc::new(table)))
        }
        None => {
            tracing::info!(
                "no conv tiles tuned for {} (driver {}) in {}: the heuristics' tiles \
                 (`nedrt bench tune` tunes them)",
                key.name,
                key.driver_info,
                dir.display()
            );
            Ok(None)
        }
    }
}

/// The DCT filter's tuned shapes in `dir` for the adapter of `info`
/// (nedrt-gpu's [`nedrt_gpu::fft::tuned`] source, installed by the
/// binary): none without a table; a broken table is said in the log (the
/// D-CNN's backend stops on it by name) and gives none.
pub fn fft_shapes_for(dir: &Path, info: &wgpu::AdapterInfo) -> nedrt_gpu::fft::tuned::TunedSizes {
    let key = AdapterKey::of(info);
    match TuningTable::find(dir, &key) {
        Ok(Some((path, table))) if !table.ffts.is_empty() => {
            let sizes: Vec<String> = table
                .ffts
                .iter()
                .map(|f| format!("{}×{}", f.width, f.height))
                .collect();
            tracing::info!(
                "DCT filter shapes of {} tuned for {} at {}",
                path.display(),
                key.name,
                sizes.join(", ")
            );
            std::sync::Arc::new(table.fft_shapes())
        }
        Ok(_) => Default::default(),
        Err(e) => {
            tracing::warn!("{e}: the DCT filter runs the heuristics' shapes");
            Default::default()
        }
    }
}

/// Where a layer's tile came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TileSource {
    /// Forced by the tuner.
    Forced,
    /// The adapter's table.
    Tuned,
    /// [`ConvTile::for_layer`].
    Heuristic,
}

/// A register-tiled conv layer's tile at one frame size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LayerTile {
    pub layer: usize,
    pub shape: ConvShape,
    pub tile: ConvTile,
    pub source: TileSource,
}

/// A cooperative-matrix conv layer's tile at one frame size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LayerCoopTile {
    pub layer: usize,
    pub shape: CoopShape,
    pub tile: CoopTile,
    pub source: TileSource,
    /// The adapter's subgroup size, which the kernel is built for.
    pub subgroup_size: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key() -> AdapterKey {
        AdapterKey {
            name: "llvmpipe (LLVM 15.0.6, 256 bits)".into(),
            vendor: 0x10005,
            device: 0,
            driver: "llvmpipe".into(),
            driver_info: "Mesa 22.3.6 (LLVM 15.0.6)".into(),
            backend: "Vulkan".into(),
        }
    }

    fn shape() -> ConvShape {
        ConvShape {
            kernel: 3,
            cin: 16,
            cout: 16,
            width: 64,
            height: 32,
            weights: DtypeName::F32,
            arith: DtypeName::F32,
        }
    }

    fn table() -> TuningTable {
        TuningTable {
            adapter: key(),
            nedrt: "0.1.0".into(),
            template: template_hash(),
            convs: vec![TunedConv {
                shape: shape(),
                px: 2,
                threads_y: 4,
                tuned_ns: 1000,
                heuristic_ns: 1500,
            }],
            coops: vec![TunedCoop {
                shape: coop_shape(),
                rows: 4,
                blocks: 1,
                sg_rows: 2,
                sg_cols: 2,
                chunks: 2,
                prefetch: true,
                plane_gather: true,
                stage_weights: true,
                drain_once: true,
                tuned_ns: 2000,
                heuristic_ns: 2500,
            }],
            fused: vec![TunedFused {
                shape: fused_shape(),
                tile_width: 16,
                tile_height: 8,
                fused_ns: 700,
                unfused_ns: 900,
            }],
            ffts: vec![
                TunedFft {
                    width: 1920,
                    height: 1080,
                    threads: Some(512),
                    pairs: Some(4),
                    tuned_ns: 900,
                    heuristic_ns: 1000,
                },
                TunedFft {
                    width: 64,
                    height: 48,
                    threads: None,
                    pairs: Some(2),
                    tuned_ns: 10,
                    heuristic_ns: 10,
                },
            ],
        }
    }

    fn fused_shape() -> FusedShape {
        FusedShape {
            first_kernel: 3,
            kernel: 3,
            cin: 3,
            mid: 16,
            cout: 16,
            width: 64,
            height: 32,
            weights: DtypeName::F32,
            arith: DtypeName::F32,
        }
    }

    fn coop_shape() -> CoopShape {
        CoopShape {
            kernel: 3,
            cin: 48,
            cout: 32,
            width: 960,
            height: 540,
            transposed: false,
        }
    }

    #[test]
    fn a_table_saves_and_reads_back_and_is_found_by_its_adapter_only() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = table().save(dir.path()).expect("saves");
        assert_eq!(
            path.file_name().and_then(|n| n.to_str()),
            Some("llvmpipe-llvm-15-0-6-256-bits-mesa-22-3-6-llvm-15-0-6-10005-0000-vulkan.toml")
        );
        let (found, t) = TuningTable::find(dir.path(), &key())
            .expect("reads")
            .expect("found");
        assert_eq!(found, path);
        assert_eq!(t, table());
        assert_eq!(
            t.tile_for(&shape()),
            Some(ConvTile {
                px: 2,
                threads_y: 4
            })
        );
        let other = ConvShape {
            width: 65,
            ..shape()
        };
        assert_eq!(t.tile_for(&other), None);
        assert_eq!(t.coop_tile_for(&coop_shape()), Some(t.coops[0].tile()));
        let transposed = CoopShape {
            transposed: true,
            ..coop_shape()
        };
        assert_eq!(t.coop_tile_for(&transposed), None);
        assert_eq!(
            t.fused_tile_for(&fused_shape()),
            Some(FusedTile {
                width: 16,
                height: 8
            })
        );
        // A level whose fused kernel was not faster runs unfused.
        let mut slower = table();
        slower.fused[0].fused_ns = slower.fused[0].unfused_ns;
        assert_eq!(slower.fused_tile_for(&fused_shape()), None);
        assert_eq!(
            t.fft_shapes(),
            vec![
                (
                    (1920, 1080),
                    nedrt_gpu::fft::FusedVariant {
                        threads: Some(512),
                        max_seqs: Some(4)
                    }
                ),
                (
                    (64, 48),
                    nedrt_gpu::fft::FusedVariant {
                        threads: None,
                        max_seqs: Some(2)
                    }
                )
            ]
        );
        let newer = AdapterKey {
            driver_info: "Mesa 24.0".into(),
            ..key()
        };
        assert!(
            TuningTable::find(dir.path(), &newer)
                .expect("reads")
                .is_none()
        );
        assert!(
            TuningTable::find(&dir.path().join("absent"), &key())
                .expect("none")
                .is_none()
        );
    }

    #[test]
    fn a_table_from_before_the_k_slices_reads_as_one_chunk_a_stage_flat_unstaged_unprefetched() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = table().save(dir.path()).expect("saves");
        let text = std::fs::read_to_string(&path).expect("reads");
        assert!(text.contains("chunks = 2\n"), "{text}");
        assert!(text.contains("plane_gather = true\n"), "{text}");
        assert!(text.contains("stage_weights = true\n"), "{text}");
        assert!(text.contains("drain_once = true\n"), "{text}");
        let old = text
            .replace("chunks = 2\n", "")
            .replace("prefetch = true\n", "")
            .replace("plane_gather = true\n", "")
            .replace("stage_weights = true\n", "")
            .replace("drain_once = true\n", "");
        std::fs::write(&path, old).expect("writes");
        let (_, t) = TuningTable::find(dir.path(), &key())
            .expect("reads")
            .expect("found");
        assert_eq!(
            t.coop_tile_for(&coop_shape()),
            Some(CoopTile {
                prefetch: false,
                plane_gather: false,
                stage_weights: false,
                drain_once: false,
                ..table().coops[0].tile().with_chunks(1)
            })
        );
    }

    #[test]
    fn a_bad_table_is_refused_naming_the_file_and_the_entry() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = table().save(dir.path()).expect("saves");
        let text = std::fs::read_to_string(&path).expect("reads");
        for (from, to, says) in [
            ("threads_y = 4", "threads_y = 3", "not a tile"),
            ("px = 2", "px = 8", "not a tile"),
            ("kernel = 3", "kernel = 9", "kernel must be"),
            ("cout = 16", "cout = \"x\"", "line 13: invalid type"),
            ("px = 2", "px = 2\nsurprise = 1", "unknown field"),
            (
                "sg_rows = 2",
                "sg_rows = 3",
                "coop entry 1 (3×3 48→32 at 960×540)",
            ),
            (
                "sg_cols = 2",
                "sg_cols = 8",
                "is not a tile the cooperative kernel builds",
            ),
            ("transposed = false", "transposed = 1", "invalid type"),
            ("chunks = 2", "chunks = 8", "chunks at most 4"),
            (
                "pairs = 4",
                "pairs = 3",
                "fft entry 1 (1920×1080): pairs = 3: must be 1, 2, 4 or 8",
            ),
            (
                "threads = 512",
                "threads = 2000",
                "threads = 2000: must be 32 to 1024",
            ),
            ("width = 1920", "width = 0", "a 0×1080 frame"),
            (
                "chunks = 2",
                "chunks = 0",
                "is not a tile the cooperative kernel builds",
            ),
            (
                "tile_width = 16",
                "tile_width = 12",
                "fused entry 1 (3×3 3→16, 3×3 →16 at 64×32): tile_width = 12, tile_height = 8 \
                 is not a tile the fused kernel builds",
            ),
            ("first_kernel = 3", "first_kernel = 9", "kernel must be"),
        ] {
            std::fs::write(&path, text.replace(from, to)).expect("writes");
            let e = TuningTable::find(dir.path(), &key())
                .expect_err(to)
                .to_string();
            assert!(e.contains(&path.display().to_string()), "{e}");
            assert!(e.contains(says), "{to}: {e}");
        }
        let mut twice = table();
        twice.convs.push(twice.convs[0].clone());
        std::fs::write(&path, toml::to_string(&twice).expect("toml")).expect("writes");
        let e = TuningTable::find(dir.path(), &key())
            .expect_err("twice")
            .to_string();
        assert!(
            e.contains("conv entry 2") && e.contains("same shape as conv entry 1"),
            "{e}"
        );
        let mut twice = table();
        twice.coops.push(twice.coops[0].clone());
        std::fs::write(&path, toml::to_string(&twice).expect("toml")).expect("writes");
        let e = TuningTable::find(dir.path(), &key())
            .expect_err("twice")
            .to_string();
        assert!(e.contains("same shape as coop entry 1"), "{e}");
        let mut twice = table();
        twice.fused.push(twice.fused[0].clone());
        std::fs::write(&path, toml::to_string(&twice).expect("toml")).expect("writes");
        let e = TuningTable::find(dir.path(), &key())
            .expect_err("twice")
            .to_string();
        assert!(e.contains("same shape as fused entry 1"), "{e}");
        let mut twice = table();
        twice.ffts.push(twice.ffts[1].clone());
        std::fs::write(&path, toml::to_string(&twice).expect("toml")).expect("writes");
        let e = TuningTable::find(dir.path(), &key())
            .expect_err("twice")
            .to_string();
        assert!(
            e.contains("fft entry 3 (64×48): the same frame size as fft entry 2"),
            "{e}"
        );
        // Only the adapter's own file is read: a broken other file (a
        // table from a newer nedrt, an unrelated TOML) stops nothing.
        std::fs::write(&path, text.clone()).expect("writes");
        std::fs::write(dir.path().join("notes.toml"), "not = [a table").expect("writes");
        assert!(
            TuningTable::find(dir.path(), &key())
                .expect("reads")
                .is_some()
        );
        // Another adapter's table under this adapter's name is not used,
        // nor overwritten by this adapter's tuning.
        let mut other = table();
        other.adapter.name = "another".into();
        std::fs::write(&path, toml::to_string(&other).expect("toml")).expect("writes");
        assert!(
            TuningTable::find(dir.path(), &key())
                .expect("reads")
                .is_none()
        );
        let e = table()
            .save(dir.path())
            .expect_err("another's file")
            .to_string();
        assert!(e.contains("holds the table of another adapter"), "{e}");
    }

    #[test]
    fn the_candidates_are_the_valid_tiles_the_layer_fills_and_include_the_heuristics() {
        for (w, h, kernel, arith) in [
            (64, 64, 3, Dtype::F32),
            (5, 3, 3, Dtype::F32),
            (240, 135, 5, Dtype::F32),
            (240, 135, 5, Dtype::F16),
            (1, 1, 1, Dtype::F16),
        ] {
            let c = candidate_tiles(w, h, kernel, arith);
            assert!(c.iter().all(|t| tile_is_valid(*t, kernel, arith)));
            let heuristic = ConvTile::for_layer(w, h, kernel, arith);
            assert!(
                c.contains(&heuristic),
                "{w}×{h} k{kernel}: {heuristic:?} not in {c:?}"
            );
        }
        assert_eq!(candidate_tiles(64, 64, 3, Dtype::F32).len(), 15);
        assert_eq!(
            candidate_tiles(5, 1, 3, Dtype::F32),
            vec![ConvTile {
                px: 1,
                threads_y: 1
            }]
        );
    }
}
