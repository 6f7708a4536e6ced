//! The encode stage on the GPU (`shaders/panel_encode.wgsl`): a planar f32
//! display image already in a device buffer becomes the panel's RGBA8
//! codes in another, by the same 255 decision thresholds per channel (and
//! the same 4096-bin table to start each search) as
//! [`Transfer`], so a frame that stays on the device is encoded to the
//! codes the CPU path gives, bit for bit. The codes' rows are padded to
//! 256 bytes, the row pitch a buffer-to-texture copy needs, so the sink
//! copies them into its panel texture on the device. The thresholds are
//! made once per panel size; a frame records one dispatch.

use super::PresentError;
use super::transfer::{BINS, CODES, Transfer};

const SHADER: &str = include_str!("../../../../shaders/panel_encode.wgsl");

const STAGE: &str = "GPU encode";

fn err(reason: impl std::fmt::Display) -> PresentError {
    PresentError::frame(STAGE, reason)
}

/// The uniform block of `panel_encode.wgsl` (`Frame`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
struct FrameUniform {
    width: u32,
    height: u32,
    plane_stride: u32,
    row_texels: u32,
    base_texel: u32,
    _pad: [u32; 3],
}

/// Where an encoder writes its codes: rows `row_texels` apart from
/// `base_texel` on, in a buffer of `rows` such rows (a frame of its own,
/// or a view's region of a panel's codes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CodesTarget {
    pub row_texels: u32,
    pub base_texel: u32,
    pub rows: u32,
}

/// Encodes planar f32 display images of one panel size on one device.
#[derive(Debug)]
pub struct PanelEncoder {
    device: wgpu::Device,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    thresholds: wgpu::Buffer,
    frame: wgpu::Buffer,
    /// The count of non-finite pixels of the last frame, and where it is
    /// copied for the host to read once the frame's submission is done.
    non_finite: wgpu::Buffer,
    non_finite_host: wgpu::Buffer,
    width: u32,
    height: u32,
    plane_stride: u32,
    row_texels: u32,
    /// Rows of the codes buffer it writes into (its height, or a panel's).
    rows: u32,
    /// Bind groups made so far, by (display, codes) buffer: a frame into
    /// buffers seen before records without creating anything.
    bind_groups: Vec<(wgpu::Buffer, wgpu::Buffer, wgpu::BindGroup)>,
}

/// Bind groups a [`PanelEncoder`] keeps (a pool of codes buffers is a few).
const BIND_GROUPS_KEPT: usize = 16;

/// Texels per row of the codes: the width padded to 256 bytes.
pub fn row_texels(width: u32) -> u32 {
    width.next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT / 4)
}

/// Workgroups for `pixels` threads ([`nedrt_gpu::workgroups`]: the
/// shader's pixel is x + y · 65535 · 64).
pub(crate) fn workgroups(pixels: u32) -> [u32; 2] {
    nedrt_gpu::workgroups(u64::from(pixels))
}

impl PanelEncoder {
    /// Prepares encoding `width`×`height` frames whose planes lie
    /// `plane_stride` elements apart, with `transfer`'s thresholds.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        width: u32,
        height: u32,
        plane_stride: u32,
        transfer: &Transfer,
    ) -> Result<Self, PresentError> {
        let target = CodesTarget {
            row_texels: row_texels(width),
            base_texel: 0,
            rows: height,
        };
        Self::new_into(
            device,
            queue,
            (width, height),
            plane_stride,
            transfer,
            target,
        )
    }

    /// As [`PanelEncoder::new`], writing into `target`: a view's region of
    /// a wider panel's codes.
    pub fn new_into(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        (width, height): (u32, u32),
        plane_stride: u32,
        transfer: &Transfer,
        target: CodesTarget,
    ) -> Result<Self, PresentError> {
        let pixels = u64::from(width) * u64::from(height);
        if pixels == 0 || u64::from(plane_stride) < pixels {
            return Err(err(format!(
                "a {width}×{height} frame with planes {plane_stride} values apart"
            )));
        }
        let row_texels = target.row_texels;
        let end = u64::from(target.base_texel)
            + u64::from(row_texels) * u64::from(height - 1)
            + u64::from(width);
        if row_texels < width || end > u64::from(row_texels) * u64::from(target.rows) {
            return Err(err(format!(
                "a {width}×{height} frame at texel {} does not fit codes of {} rows of {row_texels}",
                target.base_texel, target.rows
            )));
        }
        // The shader indexes in u32: three planes and the codes must fit,
        // and the codes one binding.
        let binding = device.limits().max_storage_buffer_binding_size;
        let code_bytes = 4 * u64::from(row_texels) * u64::from(target.rows);
        if 3 * u64::from(plane_stride) > u64::from(u32::MAX) || code_bytes > binding {
            return Err(err(format!(
                "a {width}×{height} frame is too large to encode in one dispatch on this adapter"
            )));
        }
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("panel_encode"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let storage = |binding, read_only| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("panel_encode"),
            entries: &[
                storage(0, true),
                storage(1, true),
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                storage(3, false),
                storage(4, false),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("panel_encode"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("panel_encode"),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
        // The thresholds, then each channel's bin start codes (as f32,
        // exact): the same two tables as the CPU's search.
        let table: Vec<f32> = (0..3)
            .flat_map(|c| transfer.thresholds(c).iter().copied())
            .chain((0..3).flat_map(|c| transfer.start_codes(c).iter().map(|&k| f32::from(k))))
            .collect();
        debug_assert_eq!(table.len(), 3 * (CODES - 1) + 3 * (BINS + 1));
        let buffer = |label, size: u64, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let thresholds = buffer(
            "panel thresholds",
            (table.len() * 4) as u64,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        );
        queue.write_buffer(&thresholds, 0, bytemuck::cast_slice(&table));
        let frame = buffer(
            "panel frame",
            std::mem::size_of::<FrameUniform>() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        let u = FrameUniform {
            width,
            height,
            plane_stride,
            row_texels,
            base_texel: target.base_texel,
            _pad: [0; 3],
        };
        queue.write_buffer(&frame, 0, bytemuck::bytes_of(&u));
        let non_finite = buffer(
            "panel non-finite count",
            4,
            wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
        );
        let non_finite_host = buffer(
            "panel non-finite count (host)",
            4,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(PresentError::kernel(STAGE, "the encode kernel", e));
        }
        Ok(Self {
            device: device.clone(),
            pipeline,
            layout,
            thresholds,
            frame,
            non_finite,
            non_finite_host,
            width,
            height,
            plane_stride,
            row_texels,
            rows: target.rows,
            bind_groups: Vec::new(),
        })
    }

    /// A buffer for one frame's codes ([`PanelEncoder::record`] writes it,
    /// a sink copies it to its texture).
    pub fn codes_buffer(&self) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("panel codes"),
            size: self.codes_bytes(),
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    fn codes_bytes(&self) -> u64 {
        4 * u64::from(self.row_texels) * u64::from(self.rows)
    }

    /// Texels from one row of the codes to the next (≥ the width).
    pub fn row_texels(&self) -> u32 {
        self.row_texels
    }

    /// Records the encode of `display` (three f32 planes as given to
    /// [`PanelEncoder::new`], a storage buffer) into `codes` (one RGBA8
    /// texel per pixel, red in the low byte, rows [`PanelEncoder::row_texels`] apart).
    pub fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        display: &wgpu::Buffer,
        codes: &wgpu::Buffer,
    ) -> Result<(), PresentError> {
        let needed = 3 * 4 * u64::from(self.plane_stride);
        if display.size() < needed || !display.usage().contains(wgpu::BufferUsages::STORAGE) {
            return Err(err(format!(
                "the display buffer ({} bytes, {:?}) is not a storage buffer of {needed} bytes",
                display.size(),
                display.usage()
            )));
        }
        if codes.size() < self.codes_bytes() || !codes.usage().contains(wgpu::BufferUsages::STORAGE)
        {
            return Err(err(format!(
                "the codes buffer ({} bytes, {:?}) is not a storage buffer of {} bytes",
                codes.size(),
                codes.usage(),
                self.codes_bytes()
            )));
        }
        let index = match self
            .bind_groups
            .iter()
            .position(|(d, c, _)| d == display && c == codes)
        {
            Some(i) => i,
            None => {
                if self.bind_groups.len() == BIND_GROUPS_KEPT {
                    self.bind_groups.remove(0);
                }
                let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("panel_encode"),
                    layout: &self.layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: display.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: self.thresholds.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: self.frame.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 3,
                            resource: codes.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 4,
                            resource: self.non_finite.as_entire_binding(),
                        },
                    ],
                });
                self.bind_groups
                    .push((display.clone(), codes.clone(), group));
                self.bind_groups.len() - 1
            }
        };
        let bind_group = &self.bind_groups[index].2;
        encoder.clear_buffer(&self.non_finite, 0, None);
        let [x, y] = workgroups(self.width * self.height);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("panel_encode"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, bind_group, &[]);
        pass.dispatch_workgroups(x, y, 1);
        drop(pass);
        encoder.copy_buffer_to_buffer(&self.non_finite, 0, &self.non_finite_host, 0, 4);
        Ok(())
    }

    /// Asks for the frame's non-finite count to come back with its
    /// submission: call after submitting what [`PanelEncoder::record`]
    /// recorded; the wait for that submission completes the mapping.
    pub fn map_non_finite(&self) {
        self.non_finite_host
            .slice(..)
            .map_async(wgpu::MapMode::Read, |_| {});
    }

    /// The number of pixels with a non-finite value in the frame last
    /// recorded, after [`PanelEncoder::map_non_finite`] and the wait for
    /// the frame's submission (this does not wait). 4 bytes come back.
    pub fn non_finite_pixels(&self) -> Result<u32, PresentError> {
        nedrt_gpu::read_mapped(&self.non_finite_host, |bytes| {
            u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]])
        })
        .map_err(PresentError::gpu(STAGE))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nedrt_gpu::{MAX_GROUPS_X, WORKGROUP, map_and_wait, test_device};
    use wgpu::util::DeviceExt;

    /// Encodes a `width`×`height` planar frame on the GPU and reads the
    /// codes back (the test's only read-back).
    fn encode_on_gpu(transfer: &Transfer, planes: [&[f32]; 3], width: u32) -> Vec<[u8; 4]> {
        let (device, queue) = test_device(false);
        let n = planes[0].len();
        assert!(planes.iter().all(|p| p.len() == n) && n.is_multiple_of(width as usize));
        let height = (n / width as usize) as u32;
        let data: Vec<f32> = planes.concat();
        let display = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("display"),
            contents: bytemuck::cast_slice(&data),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let mut enc =
            PanelEncoder::new(&device, &queue, width, height, n as u32, transfer).expect("encoder");
        let codes = enc.codes_buffer();
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: codes.size(),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut encoder = device.create_command_encoder(&Default::default());
        enc.record(&mut encoder, &display, &codes).expect("records");
        encoder.copy_buffer_to_buffer(&codes, 0, &readback, 0, codes.size());
        queue.submit([encoder.finish()]);
        map_and_wait(&device, &readback).expect("read back");
        let view = readback.slice(..).get_mapped_range().expect("mapped");
        // Rows are padded to the copy pitch; the padding is not the frame's.
        let pitch = 4 * enc.row_texels() as usize;
        assert!(pitch >= 4 * width as usize && pitch.is_multiple_of(256));
        view.chunks_exact(pitch)
            .flat_map(|row| row[..4 * width as usize].chunks_exact(4))
            .map(|p| [p[0], p[1], p[2], p[3]])
            .collect()
    }

    /// Every threshold of `channel` and the floats either side of it, and
    /// the values the clamp and the NaN rule decide.
    fn probes(transfer: &Transfer, channel: usize) -> Vec<f32> {
        let mut v = vec![
            0.0,
            -0.0,
            -1.0,
            1.0,
            2.0,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE,
            1e-30,
        ];
        for &t in transfer.thresholds(channel) {
            v.extend([
                f32::from_bits(t.to_bits() - 1),
                t,
                f32::from_bits(t.to_bits() + 1),
            ]);
        }
        v
    }

    #[test]
    fn the_dispatch_covers_every_pixel_once_in_rows_of_at_most_65535_groups() {
        for pixels in [
            1,
            63,
            64,
            65,
            65535 * 64,
            65535 * 64 + 1,
            1920 * 1080,
            7680 * 4320,
        ] {
            let [x, y] = workgroups(pixels);
            assert!(x <= MAX_GROUPS_X && y >= 1, "{pixels}");
            let threads = u64::from(x) * u64::from(y) * u64::from(WORKGROUP);
            assert!(threads >= u64::from(pixels), "{pixels}: {x}×{y}");
            // No row of groups is wholly past the frame.
            assert!(
                threads - u64::from(pixels) < u64::from(x) * u64::from(WORKGROUP),
                "{pixels}"
            );
            if y > 1 {
                assert_eq!(x, MAX_GROUPS_X, "{pixels}: rows before the last are full");
            }
        }
    }

    mod needs_gpu {
        use super::*;

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn the_gpu_encode_equals_the_transfer_at_every_threshold_and_either_side() {
            // A different curve per channel, each probed at its own thresholds.
            let transfer = Transfer::from_gamma([2.2, 1.0, 2.4]);
            let probes: Vec<Vec<f32>> = (0..3).map(|c| probes(&transfer, c)).collect();
            let n = probes[0].len();
            assert!(probes.iter().all(|p| p.len() == n));
            // 5 rows: the row length is not a multiple of the workgroup.
            let width = (n / 5) as u32;
            assert_eq!(width as usize * 5, n);
            let codes = encode_on_gpu(&transfer, [&probes[0], &probes[1], &probes[2]], width);
            for (i, px) in codes.iter().enumerate() {
                for c in 0..3 {
                    let x = probes[c][i];
                    assert_eq!(
                        px[c],
                        transfer.code(c, x),
                        "channel {c}, x = {x:e} ({:#x})",
                        x.to_bits()
                    );
                }
                assert_eq!(px[3], 255);
            }
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn a_frame_encodes_as_the_cpu_path_and_bad_sizes_are_refused() {
            let transfer = Transfer::from_gamma([2.2, 2.2, 2.2]);
            let (w, h) = (37usize, 21usize);
            let planes: Vec<Vec<f32>> = (0..3)
                .map(|c| {
                    (0..w * h)
                        .map(|i| ((i * 31 + c * 7) % 1000) as f32 / 900.0 - 0.05)
                        .collect()
                })
                .collect();
            let codes = encode_on_gpu(&transfer, [&planes[0], &planes[1], &planes[2]], w as u32);
            let frame = nedrt_core::Image::rgb(w, h, planes.concat());
            let mut cpu = Vec::new();
            transfer.encode_rgba8(&frame, &mut cpu);
            assert_eq!(codes.concat(), cpu);
            let (device, queue) = test_device(false);
            for (w, h, stride) in [(0, 4, 16), (4, 4, 15)] {
                let e = PanelEncoder::new(&device, &queue, w, h, stride, &transfer)
                    .expect_err("refused");
                assert!(e.to_string().contains("planes"), "{e}");
            }
            let mut enc = PanelEncoder::new(&device, &queue, 4, 4, 16, &transfer).expect("encoder");
            let short = device.create_buffer(&wgpu::BufferDescriptor {
                label: None,
                size: 3 * 4 * 15,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            });
            let mut encoder = device.create_command_encoder(&Default::default());
            let codes = enc.codes_buffer();
            let e = enc
                .record(&mut encoder, &short, &codes)
                .expect_err("too short");
            assert!(e.to_string().contains("192 bytes"), "{e}");
            let full = device.create_buffer(&wgpu::BufferDescriptor {
                label: None,
                size: 3 * 4 * 16,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            });
            let e = enc
                .record(&mut encoder, &full, &short)
                .expect_err("codes too short");
            assert!(e.to_string().contains("codes buffer"), "{e}");
        }
    }
}
