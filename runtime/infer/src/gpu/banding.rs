//! Frame sizing and running for [`GpuBackend`]: how many rows fit the
//! adapter's storage bindings, and a frame run whole or in horizontal bands
//! (module docs of `gpu`). Apart from the backend's construction in the
//! parent so that each reads on its own.

use nedrt_core::preprocess::HostTraffic;
use nedrt_gpu::{map_and_wait, read_mapped};

use super::{GpuBackend, err, resident};
use crate::InferenceError;
use crate::network::ValueId;

impl GpuBackend {
    /// Bytes of the buffer of root value `v` (one not placed inside a
    /// concat) for a `width`×`height` frame.
    pub(super) fn activation_bytes(&self, v: ValueId, width: usize, height: usize) -> u64 {
        let info = &self.network.values[v];
        let elems = info.channels * (width >> info.level) * (height >> info.level);
        (elems * self.dtype(v).bytes()).next_multiple_of(4).max(4) as u64
    }

    /// The largest activation buffer a `width`×`height` frame needs, bytes.
    pub(crate) fn largest_activation_bytes(&self, width: usize, height: usize) -> u64 {
        (0..self.network.values.len())
            .filter(|v| !self.alias.contains_key(v))
            .map(|v| self.activation_bytes(v, width, height))
            .max()
            .unwrap_or(4)
    }

    /// How many rows of a `width`×`height` frame run at once: all of them
    /// where the activations fit, else the tallest band (a multiple of the
    /// network's multiple) that fits and keeps rows beyond its two halos.
    pub fn window_rows(&self, width: usize, height: usize) -> Result<usize, InferenceError> {
        if self.largest_activation_bytes(width, height) <= self.binding_cap {
            return Ok(height);
        }
        let m = self.network.multiple.max(1);
        let smallest = 2 * self.halo + m;
        let mut rows = height - height % m;
        while rows >= smallest {
            if self.largest_activation_bytes(width, rows) <= self.binding_cap {
                return Ok(rows);
            }
            rows -= m;
        }
        Err(InferenceError::FrameTooLarge(format!(
            "a {width}×{height} frame needs a {:.0} MiB activation buffer, and even a band of \
             {smallest} rows (the network sees {} rows either side) needs {:.0} MiB; the adapter \
             binds at most {:.0} MiB",
            self.largest_activation_bytes(width, height) as f64 / 1048576.0,
            self.halo,
            self.largest_activation_bytes(width, smallest) as f64 / 1048576.0,
            self.binding_cap as f64 / 1048576.0
        )))
    }

    /// Runs on a CHW tensor with the network's input channels; returns the
    /// output value (any channel count) as CHW f32. In bands where the
    /// whole frame's activations do not fit the adapter (module docs).
    pub fn run_tensor(
        &mut self,
        data: &[f32],
        width: usize,
        height: usize,
    ) -> Result<Vec<f32>, InferenceError> {
        let cin = self.network.values[0].channels;
        if data.len() != cin * width * height {
            return Err(err(format!(
                "{} values for a {width}×{height} input",
                data.len()
            )));
        }
        let rows = self.window_rows(width, height)?;
        self.last_traffic = HostTraffic::default();
        if rows == height {
            #[allow(unused_mut)]
            let (mut out, gpu_ns) = self.run_window(data, width, height)?;
            self.last_gpu_ns = gpu_ns;
            #[cfg(test)]
            if let Some(f) = self.fault_tile
                && self.forced_tiles.values().any(|t| *t == f)
            {
                out[0] = -out[0] - 1.0;
            }
            return Ok(out);
        }
        let cout = self.network.values[self.network.output].channels;
        self.report_banding(width, height, rows);
        let (plane, band_plane) = (width * height, width * rows);
        let mut out = vec![0.0f32; cout * plane];
        let mut window = vec![0.0f32; cin * band_plane];
        let mut gpu_ns = Some(0u64);
        // Every band's rows are multiples of the network's multiple, so the
        // pooling grid of the band is the frame's.
        for band in resident::bands(height, rows, self.halo) {
            let top = band.top;
            for c in 0..cin {
                window[c * band_plane..][..band_plane]
                    .copy_from_slice(&data[c * plane + top * width..][..band_plane]);
            }
            let (out_band, ns) = self.run_window(&window, width, rows)?;
            gpu_ns = gpu_ns.zip(ns).map(|(a, b)| a + b);
            let (y0, y1) = (band.keep_start, band.keep_end);
            let kept = (y1 - y0) * width;
            for c in 0..cout {
                out[c * plane + y0 * width..][..kept]
                    .copy_from_slice(&out_band[c * band_plane + (y0 - top) * width..][..kept]);
            }
        }
        self.last_gpu_ns = gpu_ns;
        Ok(out)
    }

    /// Says once per frame size that a frame runs in bands, and why.
    pub(super) fn report_banding(&mut self, width: usize, height: usize, rows: usize) {
        if rows >= height || self.banded_size == Some((width, height)) {
            return;
        }
        self.banded_size = Some((width, height));
        tracing::info!(
            "wgpu: a {width}×{height} frame runs in {} bands of {rows} rows (each keeps {}, \
             the network sees {} rows either side): its largest activation needs {:.0} MiB, \
             the adapter binds {:.0} MiB",
            resident::bands(height, rows, self.halo).len(),
            rows - 2 * self.halo,
            self.halo,
            self.largest_activation_bytes(width, height) as f64 / 1048576.0,
            self.binding_cap as f64 / 1048576.0
        );
    }

    /// One dispatch of the network over a `width`×`height` tensor that fits
    /// the adapter; the output and the device's time for it.
    fn run_window(
        &mut self,
        data: &[f32],
        width: usize,
        height: usize,
    ) -> Result<(Vec<f32>, Option<u64>), InferenceError> {
        self.ensure_plan(width, height)?;
        let Some(plan) = &self.plan else {
            return Err(err("no plan"));
        };
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        self.queue.write_buffer(
            &plan.buffers[plan.input.buffer],
            (plan.input.offset * 4) as u64,
            bytemuck::cast_slice(data),
        );
        let mut traffic = HostTraffic {
            to_device_bytes: std::mem::size_of_val(data) as u64,
            uploads: 1,
            to_host_bytes: (plan.output_elems * 4) as u64,
            read_backs: 1,
        };
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("dcnn"),
            });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("dcnn"),
                timestamp_writes: self.timer.as_ref().map(|t| t.pass(0)),
            });
            for d in &plan.dispatches {
                pass.set_pipeline(&d.pipeline);
                pass.set_bind_group(0, &d.bind_group, &[]);
                let [x, y, z] = d.workgroups;
                pass.dispatch_workgroups(x, y, z);
            }
        }
        encoder.copy_buffer_to_buffer(
            &plan.buffers[plan.output.buffer],
            (plan.output.offset * 4) as u64,
            &plan.readback,
            0,
            (plan.output_elems * 4) as u64,
        );
        let timer_bytes = self.timer.as_ref().map_or(0, |t| t.resolve(&mut encoder));
        self.queue.submit([encoder.finish()]);
        if let Some(t) = &self.timer {
            // Mapped by the same wait as the image: bytes, not another wait.
            t.map();
            traffic.to_host_bytes += timer_bytes;
        }
        map_and_wait(&self.device, &plan.readback)?;
        let out = read_mapped(&plan.readback, |bytes| {
            bytemuck::cast_slice::<u8, f32>(&bytes[..plan.output_elems * 4]).to_vec()
        })?;
        let gpu_ns = self
            .timer
            .as_ref()
            .and_then(|t| t.spans_ns().ok())
            .and_then(|spans| spans.first().copied());
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(err(format!("running: {e}")));
        }
        self.last_traffic.add(traffic);
        Ok((out, gpu_ns))
    }
}
