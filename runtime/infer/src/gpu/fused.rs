//! Fused levels on the backend (issue 56, item 2; `shaders/conv_fused.wgsl`):
//! which pairs of layers can run as one kernel, which do at a frame size
//! (the tuner's forced tiles, else the adapter's table where fusing was
//! faster, else none: the heuristics keep every layer unfused), and the
//! fused kernel's key.

use std::collections::HashMap;

use super::GpuBackend;
use super::codegen::fused::{FusedLevel, FusedTile};
use super::codegen::{KernelKey, KernelKind};
use super::tuning::{FusedShape, TileSource};
use crate::network::{Conv, Layer, Network, ValueId};

/// A level that can run fused at one frame size, and how it runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LayerFused {
    /// The first convolution's layer; the second is the next layer.
    pub layer: usize,
    pub shape: FusedShape,
    /// The fused tile, or None: the two layers run unfused.
    pub tile: Option<FusedTile>,
    pub source: TileSource,
}

/// Whether any layer but `second`, or the network's output, reads `value`.
fn read_elsewhere(net: &Network, value: ValueId, second: usize) -> bool {
    net.output == value
        || net.layers.iter().enumerate().any(|(i, l)| {
            i != second
                && match l {
                    Layer::Conv(c) => c.input == value || c.residual == Some(value),
                    Layer::ConvTranspose(c) => c.input == value,
                    Layer::MaxPool { input, .. } => *input == value,
                    Layer::Concat { inputs, .. } => inputs.contains(&value),
                }
        })
}

/// The first layers of the network's pairs that can run fused: a conv
/// whose output only the next layer, a conv, reads, as its input only (not
/// its residual too: the intermediate is never written); both on the
/// register-tiled kernel (`keys`); the first without a residual; its
/// output not placed in a concat's buffer (`alias`), nor the second's in
/// the buffer the first reads (one kernel would read and write it); no
/// layer in two pairs (of three such convs in a row, the first two are
/// the pair).
pub(super) fn fusable_pairs(
    net: &Network,
    keys: &[Option<KernelKey>],
    alias: &HashMap<ValueId, (ValueId, usize)>,
) -> Vec<usize> {
    let tiled = |i: usize| {
        matches!(
            keys.get(i),
            Some(Some(KernelKey {
                kind: KernelKind::Conv { .. },
                ..
            }))
        )
    };
    // The buffer a value lives in (a concat's, for its inputs).
    let root = |mut v: ValueId| {
        while let Some(&(c, _)) = alias.get(&v) {
            v = c;
        }
        v
    };
    let mut firsts: Vec<usize> = Vec::new();
    for i in 0..net.layers.len().saturating_sub(1) {
        let (Layer::Conv(a), Layer::Conv(b)) = (&net.layers[i], &net.layers[i + 1]) else {
            continue;
        };
        // A layer is in one pair at most: the earlier pair takes it.
        let taken = firsts.last().is_some_and(|&f| f + 1 == i);
        if !taken
            && tiled(i)
            && tiled(i + 1)
            && b.input == a.output
            && a.residual.is_none()
            && b.residual != Some(a.output)
            && !alias.contains_key(&a.output)
            && root(a.input) != root(b.output)
            && !read_elsewhere(net, a.output, i + 1)
        {
            firsts.push(i);
        }
    }
    firsts
}

/// The two convolutions of the pair that starts at `layer`.
pub(super) fn pair(net: &Network, layer: usize) -> Option<(&Conv, &Conv)> {
    match (net.layers.get(layer)?, net.layers.get(layer + 1)?) {
        (Layer::Conv(a), Layer::Conv(b)) => Some((a, b)),
        _ => None,
    }
}

impl GpuBackend {
    /// Each level that can run fused at a `width`×`height` frame, and its
    /// tile: the tuner's forced one, else the adapter's table's where
    /// fusing was faster and the tile fits this device, else unfused.
    pub fn fused_levels(&self, width: usize, height: usize) -> Vec<LayerFused> {
        let net = &self.network;
        let limit = self.device.limits().max_compute_workgroup_storage_size;
        let mut out = Vec::new();
        for li in fusable_pairs(net, &self.layer_keys, &self.alias) {
            let (Some((a, b)), Some(key)) = (pair(net, li), self.layer_keys[li]) else {
                continue;
            };
            let level = net.values[a.input].level;
            let shape = FusedShape {
                first_kernel: a.kernel,
                kernel: b.kernel,
                cin: a.cin,
                mid: a.cout,
                cout: b.cout,
                width: (width >> level) as u32,
                height: (height >> level) as u32,
                weights: key.weights.into(),
                arith: key.arith.into(),
            };
            let fits = |t: &FusedTile| t.fits(b.kernel, a.cout, key.arith, limit);
            let tuned = self
                .tuning
                .as_ref()
                .and_then(|t| t.fused_tile_for(&shape))
                .filter(fits);
            let (tile, source) = if let Some(t) = self.forced_fused.get(&li) {
                (Some(*t), TileSource::Forced)
            } else if tuned.is_some() {
                (tuned, TileSource::Tuned)
            } else {
                (None, TileSource::Heuristic)
            };
            out.push(LayerFused {
                layer: li,
                shape,
                tile,
                source,
            });
        }
        out
    }

    /// The tiles the tuner may time on `level` on this device.
    pub(crate) fn fused_candidates(&self, level: &LayerFused) -> Vec<FusedTile> {
        let s = &level.shape;
        FusedTile::candidates(
            s.width,
            s.height,
            s.kernel,
            s.mid,
            s.arith.into(),
            self.device.limits().max_compute_workgroup_storage_size,
        )
    }

    /// Dispatches of the last frame size's plan (a fused level is one).
    #[cfg(test)]
    pub(crate) fn dispatches(&self) -> usize {
        self.plan.as_ref().map_or(0, |p| p.dispatches.len())
    }

    /// Forces `tiles` (first layer of a pair → fused tile) over the table,
    /// for the tuner and tests; an empty map lifts them.
    pub fn force_fused(&mut self, tiles: HashMap<usize, FusedTile>) {
        if tiles != self.forced_fused {
            self.forced_fused = tiles;
            self.plan = None;
            self.resident = None;
        }
    }

    /// `keys` (each layer's, sized) with each fused level's two layers
    /// replaced by one fused kernel on the first and none on the second.
    pub(super) fn fuse_keys(&self, keys: &mut [Option<KernelKey>], width: usize, height: usize) {
        let mut fused = Vec::new();
        for f in self.fused_levels(width, height) {
            let (Some(tile), Some((a, b))) = (f.tile, pair(&self.network, f.layer)) else {
                continue;
            };
            let (Some(first), Some(second)) = (keys[f.layer], keys[f.layer + 1]) else {
                continue;
            };
            let (
                KernelKind::Conv {
                    relu: first_relu, ..
                },
                KernelKind::Conv {
                    relu,
                    residual,
                    clamp,
                    ..
                },
            ) = (first.kind, second.kind)
            else {
                continue;
            };
            keys[f.layer] = Some(KernelKey {
                kind: KernelKind::FusedConv(FusedLevel {
                    first_kernel: a.kernel,
                    first_relu,
                    mid: a.cout,
                    mid_dtype: first.dst,
                    kernel: b.kernel,
                    relu,
                    residual,
                    clamp,
                    tile,
                }),
                src: first.src,
                dst: second.dst,
                residual: second.residual,
                weights: first.weights,
                arith: first.arith,
            });
            keys[f.layer + 1] = None;
            if f.source == TileSource::Tuned {
                fused.push(format!("{}+{}", f.layer, f.layer + 1));
            }
        }
        // The table's fusion said once a frame size (the tuner's is not).
        if !fused.is_empty() {
            tracing::info!(
                "D-CNN at {width}×{height}: layers {} fused (the tuning table)",
                fused.join(", ")
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::codegen::{ConvTile, Dtype};
    use crate::network::ValueInfo;

    fn conv(input: ValueId, output: ValueId, residual: Option<ValueId>) -> Layer {
        Layer::Conv(Conv {
            input,
            output,
            cin: 4,
            cout: 4,
            kernel: 3,
            weight: vec![0.0; 144],
            bias: vec![0.0; 4],
            relu: true,
            residual,
        })
    }

    /// `layers` over `values` values of 4 channels at level 0, output
    /// the last value: the pairs found, with the GPU backend's keys (every
    /// conv tiled) and concat aliases.
    fn pairs(layers: Vec<Layer>, values: usize) -> Vec<usize> {
        let net = Network {
            layers,
            values: vec![
                ValueInfo {
                    channels: 4,
                    level: 0
                };
                values
            ],
            output: values - 1,
            multiple: 1,
            macs_per_pixel: 0.0,
            clamped: false,
        };
        let keys: Vec<Option<KernelKey>> = net
            .layers
            .iter()
            .map(|l| {
                matches!(l, Layer::Conv(_)).then_some(KernelKey {
                    kind: KernelKind::Conv {
                        kernel: 3,
                        relu: true,
                        residual: false,
                        clamp: false,
                        tile: ConvTile::LARGE,
                    },
                    src: Dtype::F32,
                    dst: Dtype::F32,
                    residual: Dtype::F32,
                    weights: Dtype::F32,
                    arith: Dtype::F32,
                })
            })
            .collect();
        fusable_pairs(&net, &keys, &super::super::concat_aliases(&net))
    }

    #[test]
    fn a_pair_fuses_only_where_its_intermediate_is_the_seconds_input_alone() {
        // Two convs; three in a row (the first two are the pair).
        assert_eq!(pairs(vec![conv(0, 1, None), conv(1, 2, None)], 3), [0]);
        assert_eq!(
            pairs(
                vec![conv(0, 1, None), conv(1, 2, None), conv(2, 3, None)],
                4
            ),
            [0]
        );
        // The intermediate also the second's residual, or read by a third
        // layer, or the network's output: never written if fused.
        assert!(pairs(vec![conv(0, 1, None), conv(1, 2, Some(1))], 3).is_empty());
        assert!(
            pairs(
                vec![conv(0, 1, None), conv(1, 2, None), conv(1, 3, None)],
                4
            )
            .is_empty()
        );
        assert!(pairs(vec![conv(0, 1, None), conv(1, 2, None)], 2).is_empty());
        // The first with a residual.
        assert!(pairs(vec![conv(0, 1, Some(0)), conv(1, 2, None)], 3).is_empty());
        // concat(x, conv(conv(x))): x and the second's output share the
        // concat's buffer, which one fused kernel would read and write.
        let concat = Layer::Concat {
            inputs: vec![1, 3],
            output: 4,
        };
        let layers = vec![
            conv(0, 1, None),
            conv(1, 2, None),
            conv(2, 3, None),
            concat,
            conv(4, 5, None),
        ];
        assert!(pairs(layers, 6).is_empty());
        // The second's output into a concat the first does not read fuses.
        let concat = Layer::Concat {
            inputs: vec![2, 3],
            output: 4,
        };
        let layers = vec![
            conv(0, 1, None),
            conv(1, 2, None),
            conv(0, 3, None),
            concat,
            conv(4, 5, None),
        ];
        assert_eq!(pairs(layers, 6), [0]);
    }
}
