//! The tuner behind `nedrt bench tune` (docs/tuning.md): every candidate
//! tile of every register-tiled convolution timed on the adapter, the
//! fastest per layer shape kept, and the tuned network checked against the
//! heuristics' bit for bit before its tiles are offered for a table.

use std::collections::HashMap;
use std::sync::Arc;

use super::codegen::ConvTile;
use super::tuning::{ConvShape, TileSource, TunedConv, TuningTable, candidate_tiles};
use super::{GpuBackend, err};
use crate::InferenceError;
use nedrt_core::Image;

/// What tuning one network at one frame size found.
#[derive(Debug, Clone)]
pub struct TuneResult {
    /// One entry per conv shape, in the network's order.
    pub convs: Vec<TunedConv>,
    /// Tiles timed (each for every layer it fits, in one frame).
    pub tiles_timed: usize,
}

impl GpuBackend {
    /// The adapter the backend runs on.
    pub fn adapter_info(&self) -> wgpu::AdapterInfo {
        self.device.adapter_info()
    }

    /// Tunes the network's register-tiled convolutions on `frame` (sides a
    /// multiple of the network's, small enough to run unbanded): each
    /// candidate tile in turn on every layer it fits, timed per layer
    /// (timestamp queries) `repeat` times after a warm-up, the best kept;
    /// per shape the tile with the least summed time, the heuristics' on a
    /// tie. `only` restricts the candidates to those tiles (the
    /// heuristics' always stays: every shape is timed against it); each
    /// tile is a kernel to compile, which a software adapter takes seconds
    /// over. Before returning, the network on the tuned tiles must compute
    /// the heuristics' output bit for bit (a tile only cuts the output
    /// among workgroups), else the result is an error. The backend is left
    /// on the heuristics' tiles, without a table.
    pub fn tune(
        &mut self,
        frame: &Image,
        repeat: usize,
        only: Option<&[ConvTile]>,
    ) -> Result<TuneResult, InferenceError> {
        let (w, h) = (frame.width, frame.height);
        self.set_tuning(None);
        self.force_conv_tiles(HashMap::new());
        let base = self.conv_tiles(w, h);
        let candidates: Vec<Vec<ConvTile>> = base
            .iter()
            .map(|t| {
                let s = t.shape;
                candidate_tiles(s.width, s.height, s.kernel, s.arith.into())
                    .into_iter()
                    .filter(|c| *c == t.tile || only.is_none_or(|o| o.contains(c)))
                    .collect()
            })
            .collect();
        // Every tile any layer may take, in a fixed order.
        let mut tiles: Vec<ConvTile> = Vec::new();
        for c in candidates.iter().flatten() {
            if !tiles.contains(c) {
                tiles.push(*c);
            }
        }
        // times[(layer, tile)]: the best device time of the layer at the tile.
        let timed = self.time_tiles(frame, repeat, &base, &candidates, &tiles);
        // Whatever happened, the tuner's tiles do not outlive it.
        self.force_conv_tiles(HashMap::new());
        let times = timed?;
        // Per shape, in the network's order: its heuristic tile and each
        // candidate's time summed over the layers of that shape (a shape's
        // candidates are the same for each of its layers).
        type ShapeTimes = (ConvShape, ConvTile, Vec<(ConvTile, u64)>);
        let mut shapes: Vec<ShapeTimes> = Vec::new();
        for (b, c) in base.iter().zip(&candidates) {
            debug_assert_eq!(b.source, TileSource::Heuristic);
            let i = match shapes.iter().position(|s| s.0 == b.shape) {
                Some(i) => i,
                None => {
                    shapes.push((b.shape, b.tile, c.iter().map(|t| (*t, 0)).collect()));
                    shapes.len() - 1
                }
            };
            for (tile, sum) in &mut shapes[i].2 {
                let ns = times.get(&(b.layer, *tile)).copied().unwrap_or(u64::MAX);
                *sum = sum.saturating_add(ns);
            }
        }
        let convs = shapes
            .into_iter()
            .map(|(shape, heuristic, per_tile)| {
                let heuristic_ns = per_tile
                    .iter()
                    .find(|(t, _)| *t == heuristic)
                    .map_or(u64::MAX, |p| p.1);
                let (tile, tuned_ns) = per_tile
                    .iter()
                    .copied()
                    // The heuristics' tile wins a tie.
                    .min_by_key(|&(t, ns)| (ns, t != heuristic))
                    .ok_or_else(|| err("a conv layer without a candidate tile"))?;
                Ok(TunedConv {
                    shape,
                    px: tile.px,
                    threads_y: tile.threads_y,
                    tuned_ns,
                    heuristic_ns,
                })
            })
            .collect::<Result<Vec<_>, InferenceError>>()?;
        // The tuned network against the heuristics', bit for bit.
        let reference = self.run_tensor(frame.data(), w, h)?;
        let table = TuningTable::new(
            super::tuning::AdapterKey::of(&self.adapter_info()),
            convs.clone(),
        );
        self.set_tuning(Some(Arc::new(table)));
        let tuned = self.run_tensor(frame.data(), w, h);
        self.set_tuning(None);
        let tuned = tuned?;
        let differ = reference
            .iter()
            .zip(&tuned)
            .filter(|(a, b)| a.to_bits() != b.to_bits())
            .count();
        if differ > 0 || reference.len() != tuned.len() {
            return Err(err(format!(
                "the tuned tiles change {differ} of {} output values of a {w}×{h} frame; a \
                 tile must only cut the output among workgroups (a kernel bug: no table \
                 is written)",
                reference.len()
            )));
        }
        Ok(TuneResult {
            convs,
            tiles_timed: tiles.len(),
        })
    }

    /// Each tile forced in turn on every layer whose candidates hold it,
    /// each layer's best time of `repeat` timings after a warm-up one.
    fn time_tiles(
        &mut self,
        frame: &Image,
        repeat: usize,
        base: &[super::tuning::LayerTile],
        candidates: &[Vec<ConvTile>],
        tiles: &[ConvTile],
    ) -> Result<HashMap<(usize, ConvTile), u64>, InferenceError> {
        let mut times = HashMap::new();
        for tile in tiles {
            let forced: HashMap<usize, ConvTile> = base
                .iter()
                .zip(candidates)
                .filter(|(_, c)| c.contains(tile))
                .map(|(b, _)| (b.layer, *tile))
                .collect();
            self.force_conv_tiles(forced.clone());
            // The warm-up builds the plan and its kernels; it is not timed.
            let mut best = self.layer_timings(frame)?;
            best.iter_mut().for_each(|b| b.gpu_ns = u64::MAX);
            for _ in 0..repeat.max(1) {
                for (b, n) in best.iter_mut().zip(self.layer_timings(frame)?) {
                    b.gpu_ns = b.gpu_ns.min(n.gpu_ns);
                }
            }
            for row in best {
                if forced.contains_key(&row.layer) {
                    times.insert((row.layer, *tile), row.gpu_ns);
                }
            }
        }
        Ok(times)
    }

    /// Kernel variants built so far (each tile of each kernel is one).
    pub fn kernels_built(&self) -> usize {
        self.pipelines.len()
    }
}
