//! The tuner behind `nedrt bench tune` (docs/tuning.md): every candidate
//! tile of every convolution (register-tiled or cooperative) timed on the adapter, the
//! fastest per layer shape kept, and the tuned network checked against the
//! heuristics' bit for bit before its tiles are offered for a table.

use std::collections::HashMap;
use std::hash::Hash;
use std::sync::Arc;

use super::codegen::ConvTile;
use super::codegen::coop::{CoopLimits, CoopTile};
use super::codegen::fused::FusedTile;
use super::tuning::{
    CoopShape, LayerCoopTile, TunedConv, TunedCoop, TunedFused, TuningTable, candidate_tiles,
};
use super::{GpuBackend, err};
use crate::InferenceError;
use nedrt_core::Image;

/// What tuning one network at one frame size found.
#[derive(Debug, Clone)]
pub struct TuneResult {
    /// One entry per register-tiled conv shape, in the network's order.
    pub convs: Vec<TunedConv>,
    /// One entry per cooperative-matrix conv shape (none on an adapter
    /// without cooperative matrices).
    pub coops: Vec<TunedCoop>,
    /// One entry per shape of the levels that can run fused (none where
    /// the register-tiled layers were not tuned), each fused in the table
    /// where that was faster.
    pub fused: Vec<TunedFused>,
    /// Frames of tiles timed: each tile once, for every layer it fits,
    /// each round of variants (K-slices, gather, staged weights, drain,
    /// prefetch) once, and each fused tile once for every level it fits.
    pub tiles_timed: usize,
    /// The frames whose output was not the heuristics' bit for bit, each
    /// described (its layers and tiles, how many values differed): their
    /// tiles were passed over (a kernel bug on this adapter).
    pub passed_over: Vec<String>,
}

/// The heuristics' output of the frame being tuned, which every timed
/// frame's output must equal bit for bit, and the frames that did not.
pub(super) struct Check {
    reference: Vec<f32>,
    passed_over: Vec<String>,
}

impl Check {
    /// Names a tile (or a frame's tiles) whose output values differ.
    fn pass_over(&mut self, what: String) {
        let line = format!("{what} output values differ from the heuristics' tiles'; passed over");
        tracing::warn!("tuning: {line}");
        self.passed_over.push(line);
    }
}

/// How many values of `got` are not `reference`'s bit for bit (every one
/// where the lengths differ).
fn values_differing(reference: &[f32], got: &[f32]) -> usize {
    if reference.len() != got.len() {
        return reference.len().max(got.len());
    }
    reference
        .iter()
        .zip(got)
        .filter(|(a, b)| a.to_bits() != b.to_bits())
        .count()
}

/// The best device time of a layer at a tile: (layer, tile) → ns.
pub(super) type Times<T> = HashMap<(usize, T), u64>;

/// Which layers a tuning run times: the register-tiled ones, the ones on
/// cooperative matrices, or both ([`GpuBackend::tune_kinds`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TuneKinds {
    pub tiled: bool,
    pub coop: bool,
}

impl TuneKinds {
    pub const ALL: TuneKinds = TuneKinds {
        tiled: true,
        coop: true,
    };
}

/// Per shape, in the layers' order: the heuristics' tile and time, and the
/// fastest tile and its time, each summed over the layers of that shape
/// (a shape's candidates are the same for each of its layers); the
/// heuristics' tile wins a tie.
type Best<S, T> = (S, T, u64, T, u64);

fn best_per_shape<S: Copy + PartialEq, T: Copy + Eq + Hash>(
    layers: &[(usize, S, T)],
    candidates: &[Vec<T>],
    times: &Times<T>,
) -> Result<Vec<Best<S, T>>, InferenceError> {
    type ShapeTimes<S, T> = (S, T, Vec<(T, u64)>);
    let mut shapes: Vec<ShapeTimes<S, T>> = Vec::new();
    for (&(layer, shape, heuristic), c) in layers.iter().zip(candidates) {
        let i = match shapes.iter().position(|s| s.0 == shape) {
            Some(i) => i,
            None => {
                shapes.push((shape, heuristic, c.iter().map(|t| (*t, 0)).collect()));
                shapes.len() - 1
            }
        };
        for (tile, sum) in &mut shapes[i].2 {
            let ns = times.get(&(layer, *tile)).copied().unwrap_or(u64::MAX);
            *sum = sum.saturating_add(ns);
        }
    }
    shapes
        .into_iter()
        .map(|(shape, heuristic, per_tile)| {
            let heuristic_ns = per_tile
                .iter()
                .find(|(t, _)| *t == heuristic)
                .map_or(u64::MAX, |p| p.1);
            let (tile, tuned_ns) = per_tile
                .iter()
                .copied()
                .min_by_key(|&(t, ns)| (ns, t != heuristic))
                .ok_or_else(|| err("a conv layer without a candidate tile"))?;
            Ok((shape, heuristic, heuristic_ns, tile, tuned_ns))
        })
        .collect()
}

/// Whether a shape's heuristics' and fastest tiles both have a time: a
/// shape whose frames were all passed over gets no entry (the runtime
/// keeps the heuristics' there).
fn has_times<S, T>(best: &Best<S, T>) -> bool {
    best.2 != u64::MAX && best.4 != u64::MAX
}

/// A round of variants: each cooperative layer at `variant` of its
/// shape's fastest tile (`best`), where the layer takes one (layer →
/// tile); each such tile joins its layer's `candidates`.
fn variant_round(
    layers: &[LayerCoopTile],
    candidates: &mut [Vec<CoopTile>],
    best: &[Best<CoopShape, CoopTile>],
    variant: impl Fn(&LayerCoopTile, CoopTile) -> Option<CoopTile>,
) -> HashMap<usize, CoopTile> {
    let mut forced = HashMap::new();
    for (l, c) in layers.iter().zip(candidates.iter_mut()) {
        let Some(b) = best.iter().find(|b| b.0 == l.shape) else {
            continue;
        };
        if let Some(t) = variant(l, b.3) {
            forced.insert(l.layer, t);
            if !c.contains(&t) {
                c.push(t);
            }
        }
    }
    forced
}

/// The variants timed on each shape's fastest tile after the K-slices,
/// in this order, each on the fastest so far.
#[derive(Debug, Clone, Copy)]
enum Round {
    PlaneGather,
    StageWeights,
    DrainOnce,
    Prefetch,
}

impl Round {
    /// `tile` of layer `l` with this round's variant, if the layer takes
    /// it and does not have it already.
    fn of(self, l: &LayerCoopTile, tile: CoopTile, limits: &CoopLimits) -> Option<CoopTile> {
        let (kernel, sg) = (l.shape.kernel, l.subgroup_size);
        match self {
            Round::PlaneGather => (!tile.plane_gather).then(|| tile.plane_gathered()),
            Round::StageWeights => (!tile.stage_weights)
                .then(|| tile.weights_staged(kernel, sg, limits))
                .flatten(),
            Round::DrainOnce => (!tile.drain_once)
                .then(|| tile.drained_once(kernel, sg, limits))
                .flatten(),
            Round::Prefetch => (!tile.prefetch)
                .then(|| tile.prefetched(kernel, sg))
                .flatten(),
        }
    }
}

/// The K-slice of `chunks` of a layer's tile, if the layer takes it.
fn slice(l: &LayerCoopTile, tile: CoopTile, chunks: u32, limits: &CoopLimits) -> Option<CoopTile> {
    let s = tile.with_chunks(chunks);
    tile.slices(l.shape.cin, l.shape.kernel, l.subgroup_size, limits)
        .contains(&s)
        .then_some(s)
}

impl GpuBackend {
    /// The adapter the backend runs on.
    pub fn adapter_info(&self) -> wgpu::AdapterInfo {
        self.device.adapter_info()
    }

    /// Tunes the network's convolutions on `frame` (sides a multiple of
    /// the network's, small enough to run unbanded): each candidate tile in
    /// turn on every layer it fits, timed per layer (timestamp queries)
    /// `repeat` times after a warm-up, the best kept; per shape the tile
    /// with the least summed time, the heuristics' on a tie. The
    /// register-tiled layers first, then the cooperative-matrix ones, each
    /// kind with the other at its heuristics' tiles, then the fused levels
    /// at every fused tile (`tuner_fused.rs`). `only` restricts the
    /// register-tiled candidates to those tiles (the heuristics' always
    /// stays: every shape is timed against it); each tile is a kernel to
    /// compile, which a software adapter takes seconds over. Before
    /// returning, the network on the tuned tiles must compute the
    /// heuristics' output bit for bit (a tile only cuts the output among
    /// workgroups), else the result is an error. The backend is left on
    /// the heuristics' tiles, without a table.
    pub fn tune(
        &mut self,
        frame: &Image,
        repeat: usize,
        only: Option<&[ConvTile]>,
    ) -> Result<TuneResult, InferenceError> {
        self.tune_kinds(frame, repeat, only, None, TuneKinds::ALL)
    }

    /// [`Self::tune`] over the layers of `kinds` only: the others keep
    /// their heuristics' tiles and have no entry in the result. The fused
    /// levels (with the register-tiled layers) at `only_fused`'s tiles
    /// (None: every tile each takes; none: no fused level is timed).
    pub fn tune_kinds(
        &mut self,
        frame: &Image,
        repeat: usize,
        only: Option<&[ConvTile]>,
        only_fused: Option<&[FusedTile]>,
        kinds: TuneKinds,
    ) -> Result<TuneResult, InferenceError> {
        let (w, h) = (frame.width, frame.height);
        self.set_tuning(None);
        self.force_conv_tiles(HashMap::new());
        self.force_coop_tiles(HashMap::new());
        let tiled: Vec<_> = self
            .conv_tiles(w, h)
            .iter()
            .filter(|_| kinds.tiled)
            .map(|t| (t.layer, t.shape, t.tile))
            .collect();
        let candidates: Vec<Vec<ConvTile>> = tiled
            .iter()
            .map(|&(_, s, heuristic)| {
                candidate_tiles(s.width, s.height, s.kernel, s.arith.into())
                    .into_iter()
                    .filter(|c| *c == heuristic || only.is_none_or(|o| o.contains(c)))
                    .collect()
            })
            .collect();
        let coop_layers: Vec<_> = self
            .coop_tiles(w, h)
            .into_iter()
            .filter(|_| kinds.coop)
            .collect();
        let coop: Vec<_> = coop_layers
            .iter()
            .map(|t| (t.layer, t.shape, t.tile))
            .collect();
        let limits = CoopLimits::of(&self.device.limits());
        let mut coop_candidates: Vec<Vec<CoopTile>> = coop_layers
            .iter()
            .map(|t| t.shape.candidates(t.subgroup_size, &limits))
            .collect();
        // The heuristics' output, which every timed frame must compute.
        let mut check = Check {
            reference: self.run_tensor(frame.data(), w, h)?,
            passed_over: Vec::new(),
        };
        let timed = self
            .time_tiles(
                frame,
                repeat,
                &tiled,
                &candidates,
                Self::force_conv_tiles,
                &mut check,
            )
            .and_then(|t| {
                // The tiled layers back on their heuristics' tiles while
                // the cooperative ones are timed.
                self.force_conv_tiles(HashMap::new());
                let c = self.time_coop(
                    frame,
                    repeat,
                    &coop_layers,
                    &mut coop_candidates,
                    &limits,
                    &mut check,
                )?;
                Ok((t, c))
            });
        // Whatever happened, the tuner's tiles do not outlive it.
        self.force_conv_tiles(HashMap::new());
        self.force_coop_tiles(HashMap::new());
        let ((times, n_tiled), (coop_times, n_coop)) = timed?;
        let convs: Vec<TunedConv> = best_per_shape(&tiled, &candidates, &times)?
            .into_iter()
            .filter(has_times)
            .map(|(shape, _, heuristic_ns, tile, tuned_ns)| TunedConv {
                shape,
                px: tile.px,
                threads_y: tile.threads_y,
                tuned_ns,
                heuristic_ns,
            })
            .collect();
        let coops: Vec<TunedCoop> = best_per_shape(&coop, &coop_candidates, &coop_times)?
            .into_iter()
            .filter(has_times)
            .map(|(shape, _, heuristic_ns, tile, tuned_ns)| TunedCoop {
                shape,
                rows: tile.rows,
                blocks: tile.blocks,
                sg_rows: tile.sg_rows,
                sg_cols: tile.sg_cols,
                chunks: tile.chunks,
                prefetch: tile.prefetch,
                plane_gather: tile.plane_gather,
                stage_weights: tile.stage_weights,
                drain_once: tile.drain_once,
                tuned_ns,
                heuristic_ns,
            })
            .collect();
        // Then the fused levels, against their layers at the tuned tiles.
        let (fused, n_fused) = if kinds.tiled {
            self.time_fused(frame, repeat, only_fused, &convs, &times, &mut check)?
        } else {
            (Vec::new(), 0)
        };
        // The tuned network against the heuristics', bit for bit: each
        // tile computed them in its own frame; this checks them together.
        let Check {
            reference,
            passed_over,
        } = check;
        let mut table = TuningTable::new(
            super::tuning::AdapterKey::of(&self.adapter_info()),
            convs.clone(),
            coops.clone(),
        );
        table.merge_fused(fused.clone());
        self.set_tuning(Some(Arc::new(table)));
        let tuned = self.run_tensor(frame.data(), w, h);
        self.set_tuning(None);
        let differ = values_differing(&reference, &tuned?);
        if differ > 0 {
            return Err(err(format!(
                "the tuned tiles change {differ} of {} output values of a {w}×{h} frame; a \
                 tile must only cut the output among workgroups (a kernel bug: no table \
                 is written)",
                reference.len()
            )));
        }
        Ok(TuneResult {
            convs,
            coops,
            fused,
            tiles_timed: n_tiled + n_coop + n_fused,
            passed_over,
        })
    }

    /// Each tile forced in turn (by `force`) on every layer whose
    /// candidates hold it, each layer's best time of `repeat` timings after
    /// a warm-up one; with the number of distinct tiles timed.
    fn time_tiles<S, T: Copy + Eq + Hash + std::fmt::Debug>(
        &mut self,
        frame: &Image,
        repeat: usize,
        layers: &[(usize, S, T)],
        candidates: &[Vec<T>],
        force: fn(&mut Self, HashMap<usize, T>),
        check: &mut Check,
    ) -> Result<(Times<T>, usize), InferenceError> {
        // Every tile any layer may take, in a fixed order.
        let mut tiles: Vec<T> = Vec::new();
        for c in candidates.iter().flatten() {
            if !tiles.contains(c) {
                tiles.push(*c);
            }
        }
        let mut times = HashMap::new();
        for tile in &tiles {
            let forced: HashMap<usize, T> = layers
                .iter()
                .zip(candidates)
                .filter(|(_, c)| c.contains(tile))
                .map(|(l, _)| (l.0, *tile))
                .collect();
            times.extend(self.time_forced(frame, repeat, forced, force, check)?);
        }
        Ok((times, tiles.len()))
    }

    /// One frame's layers at `forced` tiles (layer → tile): each forced
    /// layer's best time of `repeat` timings after a warm-up one. First
    /// the frame's output must be the heuristics' bit for bit; where it is
    /// not, each forced layer's tile is tried alone, those that change the
    /// output are named in `check` and get no time (a tile without a time
    /// is never a shape's fastest), and the others are timed; where no
    /// tile alone does, the frame's tiles are named together and none is
    /// timed.
    pub(super) fn time_forced<T: Copy + Eq + Hash + std::fmt::Debug>(
        &mut self,
        frame: &Image,
        repeat: usize,
        forced: HashMap<usize, T>,
        force: fn(&mut Self, HashMap<usize, T>),
        check: &mut Check,
    ) -> Result<Times<T>, InferenceError> {
        force(self, forced.clone());
        let got = self.run_tensor(frame.data(), frame.width, frame.height)?;
        let differ = values_differing(&check.reference, &got);
        if differ > 0 {
            // Which layers' tiles change it, each alone (the others at the
            // heuristics'): those are passed over, the rest timed.
            let mut layers: Vec<(usize, T)> = forced.iter().map(|(l, t)| (*l, *t)).collect();
            layers.sort_by_key(|(l, _)| *l);
            let n = check.reference.len();
            let mut good = forced.clone();
            for &(layer, tile) in &layers {
                force(self, HashMap::from([(layer, tile)]));
                let alone = self.run_tensor(frame.data(), frame.width, frame.height)?;
                let d = values_differing(&check.reference, &alone);
                if d > 0 {
                    good.remove(&layer);
                    check.pass_over(format!("layer {layer} at {tile:?}: {d} of {n}"));
                }
            }
            if good.len() == forced.len() {
                // No tile alone, only the frame's together: none is timed.
                let at: Vec<String> = layers
                    .iter()
                    .map(|(l, t)| format!("layer {l} at {t:?}"))
                    .collect();
                check.pass_over(format!("{} together: {differ} of {n}", at.join(", ")));
                return Ok(Times::new());
            }
            return self.time_forced(frame, repeat, good, force, check);
        }
        // The warm-up builds the plan and its kernels; it is not timed.
        let mut best = self.layer_timings(frame)?;
        best.iter_mut().for_each(|b| b.gpu_ns = u64::MAX);
        for _ in 0..repeat.max(1) {
            for (b, n) in best.iter_mut().zip(self.layer_timings(frame)?) {
                b.gpu_ns = b.gpu_ns.min(n.gpu_ns);
            }
        }
        Ok(best
            .into_iter()
            .filter_map(|row| {
                let tile = forced.get(&row.layer)?;
                Some(((row.layer, *tile), row.gpu_ns))
            })
            .collect())
    }

    /// The cooperative layers' tiles timed in rounds: every candidate at
    /// one chunk a stage; then each shape's fastest of those with the
    /// K-slices it takes (2 and 4 chunks a stage, one frame each, every
    /// layer at its shape's slice); then the fastest so far gathered plane
    /// by plane, with its weights staged in workgroup memory, drained at
    /// once, and with its next stage prefetched (one frame each,
    /// [`Round`]). Each joins the layers' `candidates`. None of these
    /// changes which invocations compute an output, only how operands and
    /// results pass through workgroup memory, so each is timed on the tile
    /// already best, not on every tile.
    fn time_coop(
        &mut self,
        frame: &Image,
        repeat: usize,
        layers: &[LayerCoopTile],
        candidates: &mut [Vec<CoopTile>],
        limits: &CoopLimits,
        check: &mut Check,
    ) -> Result<(Times<CoopTile>, usize), InferenceError> {
        let keyed: Vec<_> = layers.iter().map(|t| (t.layer, t.shape, t.tile)).collect();
        let (mut times, mut timed) = self.time_tiles(
            frame,
            repeat,
            &keyed,
            candidates,
            Self::force_coop_tiles,
            check,
        )?;
        let best = best_per_shape(&keyed, candidates, &times)?;
        let mut rounds = Vec::new();
        for chunks in [2, 4] {
            rounds.push(variant_round(layers, candidates, &best, |l, t| {
                slice(l, t, chunks, limits)
            }));
        }
        for forced in rounds.into_iter().filter(|f| !f.is_empty()) {
            times.extend(self.time_forced(frame, repeat, forced, Self::force_coop_tiles, check)?);
            timed += 1;
        }
        // Then the fastest so far gathered plane by plane, with its weights
        // staged, drained at once, with its next stage prefetched.
        for round in [
            Round::PlaneGather,
            Round::StageWeights,
            Round::DrainOnce,
            Round::Prefetch,
        ] {
            let best = best_per_shape(&keyed, candidates, &times)?;
            let forced = variant_round(layers, candidates, &best, |l, t| round.of(l, t, limits));
            if !forced.is_empty() {
                times.extend(self.time_forced(
                    frame,
                    repeat,
                    forced,
                    Self::force_coop_tiles,
                    check,
                )?);
                timed += 1;
            }
        }
        Ok((times, timed))
    }

    /// Kernel variants built so far (each tile of each kernel is one).
    pub fn kernels_built(&self) -> usize {
        self.pipelines.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::tuning::TileSource;

    fn layer(layer: usize, cin: usize, height: u32) -> LayerCoopTile {
        LayerCoopTile {
            layer,
            shape: CoopShape {
                kernel: 3,
                cin,
                cout: 64,
                width: 64,
                height,
                transposed: false,
            },
            tile: CoopTile::DEFAULT,
            source: TileSource::Heuristic,
            subgroup_size: 32,
        }
    }

    #[test]
    fn a_shape_without_times_gets_no_entry() {
        let layers = [(0usize, 'a', 1u8), (1, 'b', 1)];
        let candidates = [vec![1u8, 2], vec![1, 2]];
        // Shape b's frames were all passed over: no time for either tile.
        let times = Times::from([((0, 1), 5), ((0, 2), 3)]);
        let best = best_per_shape(&layers, &candidates, &times).expect("best");
        assert_eq!((best[0].3, best[0].4), (2, 3));
        assert!(has_times(&best[0]) && !has_times(&best[1]));
    }

    #[test]
    fn a_frame_differs_by_any_bit_or_length() {
        let a = [1.0f32, 0.0, f32::NAN];
        assert_eq!(values_differing(&a, &a), 0);
        // -0.0 == 0.0, but not bit for bit.
        assert_eq!(values_differing(&a, &[1.0, -0.0, f32::NAN]), 1);
        assert_eq!(values_differing(&a, &[1.0, 0.0]), 3);
    }

    #[test]
    fn slices_gathers_staged_weights_and_prefetch_are_timed_on_each_shapes_fastest_tile() {
        let limits = CoopLimits {
            workgroup_bytes: 49152,
            invocations: 1024,
        };
        // Two layers of one 64-channel shape, one of 16 input channels.
        let layers = [layer(3, 64, 32), layer(7, 64, 32), layer(9, 16, 8)];
        let mut candidates: Vec<Vec<CoopTile>> = layers
            .iter()
            .map(|l| l.shape.candidates(32, &limits))
            .collect();
        let keyed: Vec<_> = layers.iter().map(|t| (t.layer, t.shape, t.tile)).collect();
        let fastest = candidates[0][2];
        assert_ne!(fastest, CoopTile::DEFAULT);
        // The fastest at one chunk a stage: candidate 2 of the first shape
        // on both its layers, the default on the other.
        let mut times = Times::new();
        for (l, c) in layers.iter().zip(&candidates) {
            for t in c {
                let ns = if *t == fastest { 10 } else { 20 };
                times.insert((l.layer, *t), ns);
            }
        }
        let best = best_per_shape(&keyed, &candidates, &times).expect("best");
        for chunks in [2, 4] {
            let forced = variant_round(&layers, &mut candidates, &best, |l, t| {
                slice(l, t, chunks, &limits)
            });
            let slice = fastest.with_chunks(chunks);
            assert_eq!(forced.get(&3), Some(&slice));
            assert_eq!(forced.get(&7), Some(&slice));
            // One chunk of input channels: nothing to slice.
            assert_eq!(forced.get(&9), None);
            assert!(candidates[0].contains(&slice) && candidates[1].contains(&slice));
            for (l, ns) in [(3, 11 - chunks as u64), (7, 12 - chunks as u64)] {
                times.insert((l, slice), ns);
            }
        }
        assert!(candidates[2].iter().all(|t| t.chunks == 1));
        // The slices now compete: 4 chunks (7 + 8 ns) beat 2 (9 + 10) and
        // the tile alone (10 + 10).
        let best = best_per_shape(&keyed, &candidates, &times).expect("best");
        assert_eq!(best[0].3, fastest.with_chunks(4));
        assert_eq!(best[0].4, 15);
        // The gather round on that: every layer, each at its shape's best.
        let round = |r: Round| move |l: &LayerCoopTile, t: CoopTile| r.of(l, t, &limits);
        let forced = variant_round(&layers, &mut candidates, &best, round(Round::PlaneGather));
        let gathered = fastest.with_chunks(4).plane_gathered();
        assert_eq!(forced.get(&3), Some(&gathered));
        assert_eq!(forced.get(&9), Some(&best[1].3.plane_gathered()));
        // Plane by plane wins on the first shape (6 + 6 ns), not the other.
        for (l, ns) in [(3, 6), (7, 6)] {
            times.insert((l, gathered), ns);
        }
        times.insert((9, best[1].3.plane_gathered()), 30);
        let best = best_per_shape(&keyed, &candidates, &times).expect("best");
        assert_eq!(best[0].3, gathered);
        assert!(!best[1].3.plane_gather);
        // Already gathered: no second round of it.
        assert_eq!(Round::PlaneGather.of(&layers[0], gathered, &limits), None);
        // Staged weights: where the memory allows (4 chunks of 4 blocks'
        // 3×3 weights are 72 KiB, over 48), so on the 16-channel layer
        // alone; they lose there (40 ns).
        let forced = variant_round(&layers, &mut candidates, &best, round(Round::StageWeights));
        assert_eq!(forced.get(&3), None);
        let staged = best[1].3.weights_staged(3, 32, &limits).expect("fits");
        assert_eq!(forced.get(&9), Some(&staged));
        times.insert((9, staged), 40);
        let best = best_per_shape(&keyed, &candidates, &times).expect("best");
        assert!(!best[1].3.stage_weights);
        // Drained at once: where the epilogue's matrices fit beside the
        // rest, never twice.
        let drained = Round::DrainOnce
            .of(&layers[2], best[1].3, &limits)
            .expect("fits");
        assert!(drained.drain_once && drained.workgroup_bytes(3) <= limits.workgroup_bytes);
        assert_eq!(Round::DrainOnce.of(&layers[2], drained, &limits), None);
        // The prefetch round on that: every layer whose registers allow.
        let forced = variant_round(&layers, &mut candidates, &best, round(Round::Prefetch));
        for (l, f) in &forced {
            assert!(
                f.prefetch && candidates.iter().any(|c| c.contains(f)),
                "{l}: {f:?}"
            );
        }
        assert_eq!(forced.get(&9), best[1].3.prefetched(3, 32).as_ref());
        assert!(forced.contains_key(&9));
    }
}
