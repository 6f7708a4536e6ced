//! Everything that depends on the frame size, built once per size: one
//! buffer per activation (a concat's inputs live inside its buffer at their
//! channel offsets), one parameter block and bind group per layer, the
//! dispatch sizes, and the read-back buffer. Per frame nothing is created.

use std::collections::HashMap;

use wgpu::util::DeviceExt;

use super::codegen::{self, KernelKey, KernelKind};
use super::params::Params;
use super::{GpuBackend, err};
use crate::InferenceError;
use crate::network::{Layer, ValueId};

/// Where a value lives: a buffer and an element offset into it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Place {
    pub(super) buffer: usize,
    pub(super) offset: usize,
}

/// One recorded dispatch.
#[derive(Debug)]
pub(super) struct Dispatch {
    /// The layer of the network it runs (a fused level's first).
    pub(super) layer: usize,
    /// A fused level: the layer and the next in one kernel.
    pub(super) fused: bool,
    pub(super) pipeline: wgpu::ComputePipeline,
    pub(super) bind_group: wgpu::BindGroup,
    pub(super) workgroups: [u32; 3],
}

/// Everything sized for one frame size.
#[derive(Debug)]
pub(super) struct SizedPlan {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) buffers: Vec<wgpu::Buffer>,
    pub(super) dispatches: Vec<Dispatch>,
    pub(super) input: Place,
    pub(super) output: Place,
    pub(super) output_elems: usize,
    pub(super) readback: wgpu::Buffer,
}

impl GpuBackend {
    /// Each register-tiled conv layer's tile for a `width`×`height` frame
    /// (a band's window where the frame runs in bands): the tuner's forced
    /// tile, else the adapter's table's, else the heuristics'.
    pub fn conv_tiles(&self, width: usize, height: usize) -> Vec<super::tuning::LayerTile> {
        use super::tuning::{ConvShape, LayerTile, TileSource};
        let net = &self.network;
        let mut out = Vec::new();
        for (li, (layer, key)) in net.layers.iter().zip(&self.layer_keys).enumerate() {
            let (Layer::Conv(c), Some(key)) = (layer, key) else {
                continue;
            };
            if !matches!(key.kind, KernelKind::Conv { .. }) {
                continue;
            }
            let level = net.values[c.input].level;
            let (w, h) = ((width >> level) as u32, (height >> level) as u32);
            let shape = ConvShape {
                kernel: c.kernel,
                cin: c.cin,
                cout: c.cout,
                width: w,
                height: h,
                weights: key.weights.into(),
                arith: key.arith.into(),
            };
            let (tile, source) = if let Some(t) = self.forced_tiles.get(&li) {
                (*t, TileSource::Forced)
            } else if let Some(t) = self.tuning.as_ref().and_then(|t| t.tile_for(&shape)) {
                (t, TileSource::Tuned)
            } else {
                (
                    codegen::ConvTile::for_layer(w, h, c.kernel, key.arith),
                    TileSource::Heuristic,
                )
            };
            out.push(LayerTile {
                layer: li,
                shape,
                tile,
                source,
            });
        }
        out
    }

    /// Each cooperative-matrix conv layer's tile for a `width`×`height`
    /// frame: the tuner's forced tile, else the adapter's table's, else the
    /// heuristics'.
    pub fn coop_tiles(&self, width: usize, height: usize) -> Vec<super::tuning::LayerCoopTile> {
        use super::tuning::{CoopShape, LayerCoopTile, TileSource};
        let net = &self.network;
        let limits = codegen::coop::CoopLimits::of(&self.device.limits());
        let mut out = Vec::new();
        for (li, (layer, key)) in net.layers.iter().zip(&self.layer_keys).enumerate() {
            let Some(KernelKey {
                kind:
                    KernelKind::CoopConv {
                        kernel,
                        transposed,
                        subgroup_size,
                        ..
                    },
                ..
            }) = key
            else {
                continue;
            };
            let (input, cin, cout) = match layer {
                Layer::Conv(c) => (c.input, c.cin, c.cout),
                Layer::ConvTranspose(c) => (c.input, c.cin, c.cout),
                _ => continue,
            };
            let level = net.values[input].level;
            let shape = CoopShape {
                kernel: *kernel,
                cin,
                cout,
                width: (width >> level) as u32,
                height: (height >> level) as u32,
                transposed: *transposed,
            };
            // A table's tile this device cannot run (a table carried to an
            // adapter with less workgroup memory under the same name) is
            // passed over for the heuristics'.
            let tuned = self
                .tuning
                .as_ref()
                .and_then(|t| t.coop_tile_for(&shape))
                .filter(|t| {
                    let fits = t.fits(*kernel, *subgroup_size, &limits);
                    if !fits {
                        tracing::warn!(
                            "D-CNN layer {li}: the tuning table's tile {t:?} does not fit this \
                             device ({limits:?}); the heuristics' tile is used"
                        );
                    }
                    fits
                });
            let (tile, source) = if let Some(t) = self.forced_coop.get(&li) {
                (*t, TileSource::Forced)
            } else if let Some(t) = tuned {
                (t, TileSource::Tuned)
            } else {
                (
                    codegen::coop::CoopTile::for_layer(shape.columns()),
                    TileSource::Heuristic,
                )
            };
            out.push(LayerCoopTile {
                layer: li,
                shape,
                tile,
                source,
                subgroup_size: *subgroup_size,
            });
        }
        out
    }

    /// Each layer's kernel for a `width`×`height` frame: every conv gets
    /// its tile from [`Self::conv_tiles`] or [`Self::coop_tiles`].
    fn sized_keys(&self, width: usize, height: usize) -> Vec<Option<KernelKey>> {
        let mut keys = self.layer_keys.clone();
        let tiles = self.conv_tiles(width, height);
        let coop = self.coop_tiles(width, height);
        let tuned = tiles
            .iter()
            .map(|t| t.source)
            .chain(coop.iter().map(|t| t.source))
            .filter(|s| *s == super::tuning::TileSource::Tuned)
            .count();
        if tuned > 0 {
            tracing::debug!(
                "{width}×{height}: {tuned} of {} conv tiles tuned",
                tiles.len() + coop.len()
            );
        }
        for t in coop {
            if let Some(KernelKey {
                kind: KernelKind::CoopConv { tile, .. },
                ..
            }) = &mut keys[t.layer]
            {
                *tile = t.tile;
            }
        }
        for t in tiles {
            if let Some(KernelKey {
                kind: KernelKind::Conv { tile, .. },
                ..
            }) = &mut keys[t.layer]
            {
                *tile = t.tile;
            }
        }
        self.fuse_keys(&mut keys, width, height);
        keys
    }

    /// Buffers, params and bind groups for a `width`×`height` frame.
    pub(super) fn prepare(
        &mut self,
        width: usize,
        height: usize,
    ) -> Result<SizedPlan, InferenceError> {
        let m = self.network.multiple;
        if !width.is_multiple_of(m) || !height.is_multiple_of(m) {
            return Err(err(format!("{width}×{height} is not a multiple of {m}")));
        }
        // The kernels this size needs and has not built yet; kept only once
        // they built cleanly, so a failed one is built (and fails) again.
        let keys = self.sized_keys(width, height);
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut fresh = HashMap::new();
        for key in keys.iter().flatten() {
            if !self.pipelines.contains_key(key) && !fresh.contains_key(key) {
                let pipeline = super::build_pipeline(&self.device, &self.pipeline_layout, key);
                fresh.insert(*key, pipeline);
            }
        }
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(err(format!(
                "building the kernels for {width}×{height}: {e}"
            )));
        }
        self.pipelines.extend(fresh);
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let net = &self.network;
        let plane = |v: ValueId| (width >> net.values[v].level) * (height >> net.values[v].level);
        let limits = self.device.limits();
        let cap = self.binding_cap;
        // Buffers: one per root value; aliased values sit at a channel offset.
        let mut buffers = Vec::new();
        let mut root_place: Vec<Option<Place>> = vec![None; net.values.len()];
        let mut places = Vec::with_capacity(net.values.len());
        // A fused level's intermediate stays in workgroup memory: no buffer
        // (nothing reads or writes its place; `fusable_pairs` made sure).
        let fused_mids: Vec<ValueId> = (0..net.layers.len())
            .filter(|&li| matches!(keys[li], Some(k) if matches!(k.kind, KernelKind::FusedConv(_))))
            .filter_map(|li| super::fused::pair(net, li).map(|(a, _)| a.output))
            .collect();
        for v in 0..net.values.len() {
            if fused_mids.contains(&v) {
                places.push(Place {
                    buffer: usize::MAX,
                    offset: 0,
                });
                continue;
            }
            let mut offset = 0;
            let mut r = v;
            while let Some(&(c, ch)) = self.alias.get(&r) {
                offset += ch * plane(c);
                r = c;
            }
            let base = match root_place[r] {
                Some(p) => p,
                None => {
                    let bytes = self.activation_bytes(r, width, height);
                    if bytes > cap {
                        return Err(InferenceError::FrameTooLarge(format!(
                            "a {width}×{height} frame needs a {:.0} MiB activation buffer; the \
                             adapter binds at most {:.0} MiB",
                            bytes as f64 / 1048576.0,
                            cap as f64 / 1048576.0
                        )));
                    }
                    buffers.push(self.device.create_buffer(&wgpu::BufferDescriptor {
                        label: Some("dcnn activation"),
                        size: bytes,
                        usage: wgpu::BufferUsages::STORAGE
                            | wgpu::BufferUsages::COPY_DST
                            | wgpu::BufferUsages::COPY_SRC,
                        mapped_at_creation: false,
                    }));
                    let p = Place {
                        buffer: buffers.len() - 1,
                        offset: 0,
                    };
                    root_place[r] = Some(p);
                    p
                }
            };
            places.push(Place {
                buffer: base.buffer,
                offset: base.offset + offset,
            });
        }
        let place_of = |v: ValueId| places[v];
        let input = place_of(0);
        let mut dispatches = Vec::new();
        for (li, layer) in net.layers.iter().enumerate() {
            // Concat costs nothing: its inputs were written in place; a
            // fused level's second layer runs in its first's kernel.
            let Some(key) = keys[li] else {
                continue;
            };
            // A fused level: the first layer's input and weights, the
            // second's output, residual and weights.
            let fused = match key.kind {
                KernelKind::FusedConv(_) => super::fused::pair(net, li),
                _ => None,
            };
            let out = place_of(fused.map_or(layer.output(), |(_, b)| b.output));
            let (input_v, residual, cin, cout) = match layer {
                Layer::Conv(c) => match fused {
                    Some((a, b)) => (a.input, b.residual, a.cin, b.cout),
                    None => (c.input, c.residual, c.cin, c.cout),
                },
                Layer::ConvTranspose(c) => (c.input, None, c.cin, c.cout),
                Layer::MaxPool { input, .. } => (
                    *input,
                    None,
                    net.values[*input].channels,
                    net.values[*input].channels,
                ),
                Layer::Concat { .. } => continue,
            };
            let src = place_of(input_v);
            let res = residual.map(place_of);
            if src.buffer == out.buffer || res.is_some_and(|r| r.buffer == out.buffer) {
                return Err(err(format!(
                    "layer {li} reads and writes the same concat buffer; not supported"
                )));
            }
            let (lw, lh) = (
                width >> net.values[input_v].level,
                height >> net.values[input_v].level,
            );
            let (first_w, first_b) = self.weight_offsets[li];
            let (w_off, b_off) = self.weight_offsets[li + usize::from(fused.is_some())];
            let params = Params {
                width: lw as u32,
                height: lh as u32,
                cin: cin as u32,
                cout: cout as u32,
                in_offset: src.offset as u32,
                out_offset: out.offset as u32,
                res_offset: res.map_or(0, |r| r.offset as u32),
                w_offset: w_off as u32,
                b_offset: b_off as u32,
                mid: fused.map_or(0, |(a, _)| a.cout as u32),
                first_w_offset: if fused.is_some() { first_w as u32 } else { 0 },
                first_b_offset: if fused.is_some() { first_b as u32 } else { 0 },
            };
            let params_buffer = self
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("dcnn layer params"),
                    contents: bytemuck::bytes_of(&params),
                    usage: wgpu::BufferUsages::STORAGE,
                });
            let buf = |p: Place| buffers[p.buffer].as_entire_binding();
            let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("dcnn layer"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: params_buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: buf(src),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: self.weights.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: buf(out),
                    },
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: res.map_or_else(|| self.dummy.as_entire_binding(), buf),
                    },
                ],
            });
            let (lw, lh, cout) = (lw as u32, lh as u32, cout as u32);
            let workgroups = match key.kind {
                KernelKind::Conv { tile, .. } => {
                    let (tw, th) = tile.pixels();
                    [
                        lw.div_ceil(tw),
                        lh.div_ceil(th),
                        cout.div_ceil(codegen::ConvTile::OC),
                    ]
                }
                KernelKind::ConvTranspose { .. } => {
                    let (t, oc) = codegen::CONV_TRANSPOSE_TILE;
                    [lw.div_ceil(t), lh.div_ceil(t), cout.div_ceil(oc)]
                }
                KernelKind::CoopConv {
                    transposed, tile, ..
                } => {
                    use codegen::coop;
                    let columns = if transposed { 4 * cout } else { cout };
                    [
                        lw.div_ceil(coop::SIZE),
                        lh.div_ceil(tile.pixel_rows()),
                        columns.div_ceil(coop::SIZE).div_ceil(tile.column_blocks()),
                    ]
                }
                KernelKind::FusedConv(level) => [
                    lw.div_ceil(level.tile.width),
                    lh.div_ceil(level.tile.height),
                    1,
                ],
                KernelKind::MaxPool => {
                    let t = codegen::POOL_TILE;
                    [(lw / 2).div_ceil(t), (lh / 2).div_ceil(t), cout]
                }
            };
            let max = limits.max_compute_workgroups_per_dimension;
            if workgroups.iter().any(|&n| n > max) {
                return Err(err(format!(
                    "{width}×{height} needs {workgroups:?} workgroups; the adapter allows {max} per dimension"
                )));
            }
            dispatches.push(Dispatch {
                layer: li,
                fused: fused.is_some(),
                pipeline: self.pipelines[&key].clone(),
                bind_group,
                workgroups,
            });
        }
        let output = place_of(net.output);
        let output_elems = net.values[net.output].channels * plane(net.output);
        let readback = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("dcnn readback"),
            size: (output_elems * 4).max(4) as u64,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(err(format!("preparing {width}×{height}: {e}")));
        }
        Ok(SizedPlan {
            width,
            height,
            buffers,
            dispatches,
            input,
            output,
            output_elems,
            readback,
        })
    }
}
