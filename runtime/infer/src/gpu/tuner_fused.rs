//! The tuner's fused levels (issue 56, items 2 and 4): each level that can
//! run fused, timed at every fused tile it takes, against its two layers
//! unfused at their tuned tiles. A level whose fused output is not the
//! heuristics' bit for bit is passed over, as a tile is.

use std::collections::HashMap;

use super::GpuBackend;
use super::codegen::ConvTile;
use super::codegen::fused::FusedTile;
use super::tuner::{Check, Times};
use super::tuning::{FusedShape, TunedConv, TunedFused};
use crate::InferenceError;
use nedrt_core::Image;

/// The fused levels' entries from their timings: per shape, in the
/// network's order, the tile with the least time summed over the shape's
/// levels (the smaller tile on a tie), against the same levels' two layers
/// at their shapes' tuned tiles (`convs`, timed in `tiled`). A shape none
/// of whose tiles has a time for every level, or whose layers have no
/// unfused time, gets no entry.
pub(super) fn fused_entries(
    levels: &[(usize, FusedShape, Vec<FusedTile>)],
    fused: &Times<FusedTile>,
    unfused: impl Fn(usize) -> Option<u64>,
) -> Vec<TunedFused> {
    let mut shapes: Vec<FusedShape> = Vec::new();
    for (_, s, _) in levels {
        if !shapes.contains(s) {
            shapes.push(*s);
        }
    }
    let mut out = Vec::new();
    for shape in shapes {
        let of_shape: Vec<_> = levels.iter().filter(|l| l.1 == shape).collect();
        let Some(unfused_ns) = of_shape.iter().map(|l| unfused(l.0)).sum::<Option<u64>>() else {
            continue;
        };
        let mut tiles: Vec<FusedTile> = of_shape[0].2.clone();
        tiles.sort();
        let best = tiles
            .iter()
            .filter_map(|t| {
                let ns: Option<u64> = of_shape.iter().map(|l| fused.get(&(l.0, *t))).sum();
                ns.map(|ns| (ns, *t))
            })
            .min();
        if let Some((fused_ns, tile)) = best {
            out.push(TunedFused {
                shape,
                tile_width: tile.width,
                tile_height: tile.height,
                fused_ns,
                unfused_ns,
            });
        }
    }
    out
}

impl GpuBackend {
    /// Each fused level at each tile it takes (of `only`, if given: one
    /// frame a tile, every level that takes it fused), the other layers at
    /// the heuristics' tiles; then the entries against the unfused layers'
    /// times in `tiled` at their shapes' tuned tiles (`convs`). Returns the
    /// entries and the frames timed.
    pub(super) fn time_fused(
        &mut self,
        frame: &Image,
        repeat: usize,
        only: Option<&[FusedTile]>,
        convs: &[TunedConv],
        tiled: &Times<ConvTile>,
        check: &mut Check,
    ) -> Result<(Vec<TunedFused>, usize), InferenceError> {
        let (w, h) = (frame.width, frame.height);
        self.force_fused(HashMap::new());
        let levels: Vec<(usize, FusedShape, Vec<FusedTile>)> = self
            .fused_levels(w, h)
            .iter()
            .map(|l| {
                let mut c = self.fused_candidates(l);
                c.retain(|t| only.is_none_or(|o| o.contains(t)));
                (l.layer, l.shape, c)
            })
            .collect();
        let mut tiles: Vec<FusedTile> = levels.iter().flat_map(|l| l.2.clone()).collect();
        tiles.sort();
        tiles.dedup();
        let mut times = Times::new();
        let timed = (|| {
            for tile in &tiles {
                let forced: HashMap<usize, FusedTile> = levels
                    .iter()
                    .filter(|l| l.2.contains(tile))
                    .map(|l| (l.0, *tile))
                    .collect();
                times.extend(self.time_forced(frame, repeat, forced, Self::force_fused, check)?);
            }
            Ok::<_, InferenceError>(())
        })();
        self.force_fused(HashMap::new());
        timed?;
        // A layer's unfused time: at its shape's tuned tile.
        let tiles_now = self.conv_tiles(w, h);
        let layer_ns = |layer: usize| {
            let t = tiles_now.iter().find(|t| t.layer == layer)?;
            let tuned = convs.iter().find(|c| c.shape == t.shape)?;
            tiled.get(&(layer, tuned.tile())).copied()
        };
        let entries = fused_entries(&levels, &times, |first| {
            Some(layer_ns(first)? + layer_ns(first + 1)?)
        });
        Ok((entries, tiles.len()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::tuning::DtypeName;

    fn shape(mid: usize) -> FusedShape {
        FusedShape {
            first_kernel: 3,
            kernel: 3,
            cin: 16,
            mid,
            cout: 16,
            width: 64,
            height: 32,
            weights: DtypeName::F32,
            arith: DtypeName::F32,
        }
    }

    const A: FusedTile = FusedTile {
        width: 8,
        height: 8,
    };
    const B: FusedTile = FusedTile {
        width: 16,
        height: 8,
    };

    #[test]
    fn a_shape_takes_its_fastest_tile_summed_over_its_levels_against_them_unfused() {
        // Layers 0 and 4 start levels of one shape, 7 another.
        let levels = vec![
            (0, shape(16), vec![A, B]),
            (4, shape(16), vec![A, B]),
            (7, shape(32), vec![A, B]),
        ];
        let fused: Times<FusedTile> = HashMap::from([
            ((0, A), 10),
            ((0, B), 4),
            ((4, A), 10),
            ((4, B), 7),
            // Shape 32: B was passed over on its level (no time).
            ((7, A), 9),
        ]);
        let unfused = |first: usize| Some(first as u64 + 5);
        let e = fused_entries(&levels, &fused, unfused);
        assert_eq!(e.len(), 2);
        assert_eq!((e[0].shape, e[0].tile(), e[0].fused_ns), (shape(16), B, 11));
        assert_eq!(e[0].unfused_ns, 5 + 9);
        assert!(e[0].faster());
        assert_eq!((e[1].tile(), e[1].fused_ns, e[1].unfused_ns), (A, 9, 12));
        // A tie goes to the smaller tile; a level without an unfused time
        // (its layers were passed over) gives its shape no entry.
        let tie: Times<FusedTile> = HashMap::from([((7, A), 5), ((7, B), 5)]);
        assert_eq!(fused_entries(&levels[2..], &tie, unfused)[0].tile(), A);
        assert!(fused_entries(&levels[2..], &tie, |_| None).is_empty());
        // A tile without a time on one of a shape's levels is not its best.
        let partial: Times<FusedTile> = HashMap::from([((0, B), 1), ((0, A), 50), ((4, A), 50)]);
        assert_eq!(fused_entries(&levels[..2], &partial, unfused)[0].tile(), A);
    }
}
