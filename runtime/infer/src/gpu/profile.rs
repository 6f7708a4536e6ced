//! Per-layer device time (`nedrt bench inference --per-layer`): each
//! dispatch of the plan in a compute pass of its own, with timestamps at
//! its start and end, so the table shows where a frame's time goes. Each
//! pass boundary costs a little, so the layers sum to somewhat more than
//! the one-pass frame; the frame's own time is `last_gpu_ns`.

use super::{GpuBackend, err};
use crate::network::Layer;
use crate::{InferenceError, LayerTiming};
use nedrt_gpu::PassTimer;

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
        let Some(timer) = PassTimer::new(&self.device, &self.queue, n) else {
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
                timestamp_writes: Some(timer.pass(i)),
            });
            pass.set_pipeline(&d.pipeline);
            pass.set_bind_group(0, &d.bind_group, &[]);
            let [x, y, z] = d.workgroups;
            pass.dispatch_workgroups(x, y, z);
        }
        timer.resolve(&mut encoder);
        self.queue.submit([encoder.finish()]);
        timer.map_and_wait(&self.device)?;
        let spans = timer
            .spans_ns()
            .map_err(|e| err(format!("reading the timestamps: {e}")))?;
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
            let conv = |c: &crate::network::Conv| {
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
            };
            // A fused level: both convolutions, less the intermediate's
            // write and read, which stay in workgroup memory.
            let fused = d.fused.then(|| super::fused::pair(net, d.layer)).flatten();
            let out = fused.map_or(out, |(_, b)| b.output);
            let (kind, macs, bytes) = match layer {
                Layer::Conv(a) => match fused {
                    Some((_, b)) => {
                        let ((ka, ma, ba), (kb, mb, bb)) = (conv(a), conv(b));
                        let mid = 2 * a.cout as u64 * lvl(a.output) * act(a.output);
                        (format!("fused {ka}, {kb}"), ma + mb, ba + bb - mid)
                    }
                    None => conv(a),
                },
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
            rows.push(LayerTiming {
                layer: d.layer,
                kind,
                output: [net.values[out].channels, height >> l, width >> l],
                macs,
                bytes,
                gpu_ns: spans[i],
                tensor_cores: self.layer_keys[d.layer]
                    .is_some_and(|k| matches!(k.kind, super::codegen::KernelKind::CoopConv { .. })),
            });
        }
        Ok(rows)
    }
}
