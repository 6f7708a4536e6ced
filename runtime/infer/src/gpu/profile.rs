//! Per-layer device time (`nedrt bench inference --per-layer`): each
//! dispatch of the plan in a compute pass of its own, with timestamps at
//! its start and end, so the table shows where a frame's time goes. Each
//! pass boundary costs a little, so the layers sum to somewhat more than
//! the one-pass frame; the frame's own time is `last_gpu_ns`.

use super::{GpuBackend, GpuTimer, err};
use crate::network::Layer;
use crate::{InferenceError, LayerTiming};
use nedrt_gpu::map_and_wait;

impl GpuBackend {
    /// The device time of each layer of the network on `frame` (sides a
    /// multiple of the network's, small enough to run unbanded).
    pub fn layer_timings(
        &mut self,
        frame: &nedrt_core::Image,
    ) -> Result<Vec<LayerTiming>, InferenceError> {
        let (width, height) = (frame.width, frame.height);
        if self.window_rows(width, height)? != height {
            return Err(err(format!(
                "a {width}×{height} frame runs in bands on this adapter; time the layers at a \
                 size whose activations fit one binding"
            )));
        }
        self.ensure_plan(width, height)?;
        let Some(plan) = &self.plan else {
            return Err(err("no plan"));
        };
        let n = plan.dispatches.len();
        let Some(timer) = GpuTimer::with_pairs(&self.device, &self.queue, n) else {
            return Err(err(format!(
                "{} has no timestamp queries: per-layer times need them",
                self.adapter_name
            )));
        };
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        self.queue.write_buffer(
            &plan.buffers[plan.input.buffer],
            (plan.input.offset * 4) as u64,
            bytemuck::cast_slice(frame.data()),
        );
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("dcnn per layer"),
            });
        for (i, d) in plan.dispatches.iter().enumerate() {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("dcnn layer"),
                timestamp_writes: Some(wgpu::ComputePassTimestampWrites {
                    query_set: &timer.queries,
                    beginning_of_pass_write_index: Some((2 * i) as u32),
                    end_of_pass_write_index: Some((2 * i + 1) as u32),
                }),
            });
            pass.set_pipeline(&d.pipeline);
            pass.set_bind_group(0, &d.bind_group, &[]);
            let [x, y, z] = d.workgroups;
            pass.dispatch_workgroups(x, y, z);
        }
        encoder.resolve_query_set(&timer.queries, 0..(2 * n) as u32, &timer.resolve, 0);
        encoder.copy_buffer_to_buffer(&timer.resolve, 0, &timer.readback, 0, (16 * n) as u64);
        self.queue.submit([encoder.finish()]);
        map_and_wait(&self.device, &timer.readback).map_err(err)?;
        let stamps: Vec<u64> = {
            let view = timer
                .readback
                .slice(..)
                .get_mapped_range()
                .map_err(|e| err(format!("reading the timestamps: {e}")))?;
            bytemuck::pod_collect_to_vec(&view[..16 * n])
        };
        timer.readback.unmap();
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(err(format!("timing the layers: {e}")));
        }
        let net = &self.network;
        let act = |v: usize| self.dtype(v).bytes() as u64;
        // Weights are stored at the backend's precision.
        let weight_bytes = super::storage_dtype(self.precision).bytes() as u64;
        let mut rows = Vec::with_capacity(n);
        for (i, d) in plan.dispatches.iter().enumerate() {
            let layer = &net.layers[d.layer];
            let out = layer.output();
            let lvl = |v: usize| {
                let l = net.values[v].level;
                ((width >> l) * (height >> l)) as u64
            };
            let (kind, macs, bytes) = match layer {
                Layer::Conv(c) => {
                    let k2 = (c.kernel * c.kernel) as u64;
                    let (cin, cout) = (c.cin as u64, c.cout as u64);
                    let px = lvl(c.input);
                    let mut bytes = cin * px * act(c.input)
                        + cout * px * act(c.output)
                        + (cin * cout * k2 + cout) * weight_bytes;
                    if let Some(r) = c.residual {
                        bytes += cout * px * act(r);
                    }
                    let kind = format!(
                        "conv {0}×{0}{1}{2}",
                        c.kernel,
                        if c.relu { " + relu" } else { "" },
                        if c.residual.is_some() {
                            " + residual + clamp"
                        } else {
                            ""
                        }
                    );
                    (kind, cin * cout * k2 * px, bytes)
                }
                Layer::ConvTranspose(c) => {
                    let (cin, cout) = (c.cin as u64, c.cout as u64);
                    let px = lvl(c.input);
                    let bytes = cin * px * act(c.input)
                        + 4 * cout * px * act(c.output)
                        + (cin * cout * 4 + cout) * weight_bytes;
                    let kind = format!("conv transpose 2×2{}", if c.relu { " + relu" } else { "" });
                    (kind, cin * cout * 4 * px, bytes)
                }
                Layer::MaxPool { input, output } => {
                    let c = net.values[*input].channels as u64;
                    let bytes = c * lvl(*input) * act(*input) + c * lvl(*output) * act(*output);
                    ("max pool 2×2".to_string(), 0, bytes)
                }
                Layer::Concat { .. } => continue,
            };
            let l = net.values[out].level;
            let ticks = stamps[2 * i + 1].saturating_sub(stamps[2 * i]);
            rows.push(LayerTiming {
                layer: d.layer,
                kind,
                output: [net.values[out].channels, height >> l, width >> l],
                macs,
                bytes,
                gpu_ns: (ticks as f64 * timer.period_ns) as u64,
            });
        }
        Ok(rows)
    }
}
