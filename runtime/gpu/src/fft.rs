//! The FFT on the device, and the filter every FFT prefilter of nedrt is:
//! a frame mirrored to 2w×2h, transformed, multiplied by a spectrum that is
//! real and even (the PSFs are mirror-symmetric), transformed back and
//! cropped to its first quadrant. That is exactly a 2-D DCT-II of the w×h
//! frame, a product with the spectrum's first quadrant, and a 2-D DCT-III
//! (docs/gpu-fft.md), which this module runs with half the data and a
//! quarter of the transforms' work of the mirrored FFT:
//!
//! - in workgroup memory (`fused.rs`, `wgsl.rs`, `fft_fused.wgsl`): one
//!   dispatch per axis, each workgroup holding a pair of rows or columns
//!   through every pass of its FFT, the radices written out with constant
//!   butterflies, the gain fused: three dispatches a filter, where both
//!   sides fit the adapter's workgroup memory;
//! - else by passes through device memory, the fallback:
//! - `fft_pass.wgsl`: one Stockham pass of a batched complex FFT (radices
//!   2 and 4, and a generic odd DFT up to [`MAX_PRIME`]); the passes of a
//!   length's radices give its DFT in natural order;
//! - `dct_pack.wgsl` / `dct_unpack.wgsl`: real rows or columns to and from
//!   the FFT's input and output by Makhoul's reordering, two real sequences
//!   in one complex FFT, the spectrum's gain applied on the way.
//!
//! Twiddles come from tables computed in f64 on the host (WGSL's `sin` and
//! `cos` are only specified to 2⁻¹¹). Everything a frame size needs
//! (buffers, bind groups, the passes' parameters) is made once per size; a
//! frame records its dispatches and allocates nothing. CPU twins: rustfft
//! (the tests below) and the CPU prefilters (nedrt-optics' `WienerPlan`).

mod complex;
mod dct;
mod filter;
mod fused;
mod kernels;
mod spectral;
pub mod tuned;
mod wgsl;

pub use complex::ComplexFft2d;
pub use filter::DctFilter;
pub use fused::{RowEnds, RowEndsSpec, fits_workgroup};
pub use kernels::{FftKernels, FusedVariant};
pub use spectral::{GainsFor, SpectralStage, TermsError};

#[cfg(test)]
use kernels::{FFT_SHADER, PACK_SHADER, PassParams, SeqParams, UNPACK_SHADER};

/// The largest prime factor of a transform length the device FFT takes
/// (the generic DFT's registers grow with it; `fft_pass.wgsl`'s MAX_RADIX).
pub const MAX_PRIME: usize = 13;

/// Which kernels the device transforms use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FftPath {
    /// One dispatch per axis in workgroup memory where every length fits
    /// the adapter's workgroup memory, else the multi-pass kernels.
    #[default]
    Auto,
    /// The multi-pass kernels (each radix a dispatch through device
    /// memory) at every size: the fallback, forced for comparisons.
    MultiPass,
}

/// Why a device transform cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum FftError {
    #[error(
        "an FFT of length {n}: its prime factor {prime} is above {MAX_PRIME}, the largest radix of the device FFT"
    )]
    UnsupportedLength { n: usize, prime: usize },
    #[error("an FFT of length 0")]
    Empty,
    #[error("{what} needs {bytes} bytes in one binding; this adapter allows {limit}")]
    TooLarge {
        what: String,
        bytes: u64,
        limit: u64,
    },
    #[error("the filter's gains: {0}")]
    Gains(String),
    #[error("the device refused the FFT's pipelines: {0}")]
    Device(String),
}

/// The radices of a length, 4s first (fewest passes), then 2, 3, 5, 7, 11, 13.
pub fn radices(n: usize) -> Result<Vec<u32>, FftError> {
    if n == 0 {
        return Err(FftError::Empty);
    }
    let mut rest = n;
    let mut out = Vec::new();
    while rest.is_multiple_of(4) {
        out.push(4);
        rest /= 4;
    }
    for p in [2, 3, 5, 7, 11, 13] {
        while rest.is_multiple_of(p) {
            out.push(p as u32);
            rest /= p;
        }
    }
    if rest > 1 {
        let prime = (2..=rest).find(|d| rest.is_multiple_of(*d)).unwrap_or(rest);
        return Err(FftError::UnsupportedLength { n, prime });
    }
    Ok(out)
}

pub(crate) fn storage(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Runs `make` in a validation scope: a shader or pipeline the device
/// refuses is an error, not a panic later.
pub(crate) fn checked<T>(device: &wgpu::Device, make: impl FnOnce() -> T) -> Result<T, FftError> {
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let out = make();
    match pollster::block_on(scope.pop()) {
        Some(e) => Err(FftError::Device(e.to_string())),
        None => Ok(out),
    }
}

pub(crate) fn init_buffer(device: &wgpu::Device, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: bytes,
        usage: wgpu::BufferUsages::STORAGE,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lengths_factor_into_the_kernels_radices_or_are_refused_by_name() {
        assert_eq!(radices(3840).ok(), Some(vec![4, 4, 4, 4, 3, 5]));
        assert_eq!(radices(1080).ok(), Some(vec![4, 2, 3, 3, 3, 5]));
        assert_eq!(radices(1).ok(), Some(vec![]));
        assert_eq!(radices(7 * 8).ok(), Some(vec![4, 2, 7]));
        for (n, p) in [(17, 17), (2 * 1031, 1031), (3 * 19 * 19, 19)] {
            match radices(n) {
                Err(FftError::UnsupportedLength { n: m, prime }) => assert_eq!((m, prime), (n, p)),
                other => panic!("{n}: {other:?}"),
            }
        }
        assert!(matches!(radices(0), Err(FftError::Empty)));
        let e = radices(34).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("34") && e.contains("17"), "{e}");
    }

    /// The field names of a WGSL struct, in order.
    fn wgsl_fields(source: &str, name: &str) -> Vec<String> {
        let start = source.find(&format!("struct {name} {{")).expect("struct");
        source[start..]
            .lines()
            .skip(1)
            .map(|l| l.split("//").next().unwrap_or("").trim())
            .take_while(|l| *l != "}")
            .filter_map(|l| l.split_once(':').map(|(f, _)| f.trim().to_string()))
            .collect()
    }

    #[test]
    fn the_shaders_parameter_blocks_are_the_rust_structs() {
        // Field for field, u32 each: a field added on one side only fails here.
        let pass = [
            "n",
            "ns",
            "count",
            "elem_stride",
            "seq_stride",
            "seq_fastest",
            "tw_step",
            "inverse",
            "group",
            "plane",
        ];
        assert_eq!(wgsl_fields(FFT_SHADER, "Pass"), pass);
        assert_eq!(std::mem::size_of::<PassParams>(), 4 * pass.len());
        let seqs = [
            "n",
            "count",
            "pairs",
            "group",
            "plane",
            "group_stride",
            "elem_stride",
            "pair_stride",
            "celem_stride",
            "pair_fastest",
            "use_gain",
            "pad",
        ];
        for shader in [PACK_SHADER, UNPACK_SHADER] {
            assert_eq!(wgsl_fields(shader, "Seqs"), seqs);
        }
        assert_eq!(std::mem::size_of::<SeqParams>(), 4 * seqs.len());
        // The Rust side, by a value with every field distinct.
        let q = SeqParams {
            n: 0,
            count: 1,
            pairs: 2,
            group: 3,
            plane: 4,
            group_stride: 5,
            elem_stride: 6,
            pair_stride: 7,
            celem_stride: 8,
            pair_fastest: 9,
            use_gain: 10,
            pad: 11,
        };
        assert_eq!(
            bytemuck::cast::<SeqParams, [u32; 12]>(q),
            [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]
        );
        let p = PassParams {
            n: 0,
            ns: 1,
            count: 2,
            elem_stride: 3,
            seq_stride: 4,
            seq_fastest: 5,
            tw_step: 6,
            inverse: 7,
            group: 8,
            plane: 9,
        };
        assert_eq!(
            bytemuck::cast::<PassParams, [u32; 10]>(p),
            [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
        );
    }

    mod needs_gpu {
        use super::super::*;
        use num_complex::Complex32 as c32;
        use rustfft::FftPlanner;
        use wgpu::util::DeviceExt;

        /// A deterministic, non-trivial signal (no zeros, no symmetry).
        fn signal(n: usize, seed: u64) -> Vec<f32> {
            let mut x = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (0..n)
                .map(|_| {
                    x = x
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    ((x >> 40) as f32 / (1u64 << 24) as f32) - 0.5
                })
                .collect()
        }

        fn read(
            device: &wgpu::Device,
            queue: &wgpu::Queue,
            buf: &wgpu::Buffer,
            bytes: u64,
        ) -> Vec<f32> {
            let host = device.create_buffer(&wgpu::BufferDescriptor {
                label: None,
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut enc = device.create_command_encoder(&Default::default());
            enc.copy_buffer_to_buffer(buf, 0, &host, 0, bytes);
            queue.submit([enc.finish()]);
            crate::map_and_wait(device, &host).expect("read-back");
            crate::read_mapped(&host, |b| bytemuck::cast_slice::<u8, f32>(b).to_vec())
                .expect("mapped")
        }

        fn data_buffer(
            device: &wgpu::Device,
            data: &[f32],
            extra: wgpu::BufferUsages,
        ) -> wgpu::Buffer {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: None,
                contents: bytemuck::cast_slice(data),
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | extra,
            })
        }

        /// rustfft's 2-D transform of row-major `rows`×`cols` complex data.
        fn cpu_fft2(data: &[c32], cols: usize, rows: usize, inverse: bool) -> Vec<c32> {
            let mut planner = FftPlanner::<f32>::new();
            let (rf, cf) = if inverse {
                (
                    planner.plan_fft_inverse(cols),
                    planner.plan_fft_inverse(rows),
                )
            } else {
                (
                    planner.plan_fft_forward(cols),
                    planner.plan_fft_forward(rows),
                )
            };
            let mut out = data.to_vec();
            for row in out.chunks_mut(cols) {
                rf.process(row);
            }
            let mut col = vec![c32::new(0.0, 0.0); rows];
            for x in 0..cols {
                for y in 0..rows {
                    col[y] = out[y * cols + x];
                }
                cf.process(&mut col);
                for y in 0..rows {
                    out[y * cols + x] = col[y];
                }
            }
            out
        }

        /// A device whose workgroup memory is `bytes` (the adapter's other
        /// limits): 16 KiB is WebGPU's default and the smallest an adapter
        /// offers, where 2160 no longer fits and the fallback runs.
        fn device_with_workgroup_bytes(bytes: u32) -> (wgpu::Device, wgpu::Queue) {
            let instance = wgpu::Instance::new(crate::GpuSettings::default().descriptor());
            let adapter = pollster::block_on(
                instance.request_adapter(&wgpu::RequestAdapterOptions::default()),
            )
            .expect("this test needs a GPU adapter");
            let mut limits = adapter.limits();
            limits.max_compute_workgroup_storage_size =
                bytes.min(limits.max_compute_workgroup_storage_size);
            pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
                required_limits: limits,
                ..Default::default()
            }))
            .expect("device")
        }

        /// The device 2-D FFT of one random array against rustfft, both
        /// directions: the largest error over the largest magnitude.
        fn fft2_error(cols: usize, rows: usize) -> (f32, bool) {
            let (device, queue) = crate::test_device(false);
            fft2_error_on(&device, &queue, cols, rows, FftPath::Auto)
        }

        /// As [`fft2_error`] on `device` by `path`; and whether the
        /// transform ran in workgroup memory.
        fn fft2_error_on(
            device: &wgpu::Device,
            queue: &wgpu::Queue,
            cols: usize,
            rows: usize,
            path: FftPath,
        ) -> (f32, bool) {
            let (device, queue) = (device.clone(), queue.clone());
            let mut kernels = FftKernels::new(&device).expect("kernels");
            kernels.set_path(path);
            let data = signal(2 * cols * rows, (cols * 31 + rows) as u64);
            let a = data_buffer(&device, &data, wgpu::BufferUsages::COPY_DST);
            let b = data_buffer(
                &device,
                &vec![f32::NAN; data.len()],
                wgpu::BufferUsages::empty(),
            );
            let fft = ComplexFft2d::new(&mut kernels, cols, rows, 1, &a, &b).expect("plan");
            let host: Vec<c32> = data.chunks(2).map(|p| c32::new(p[0], p[1])).collect();
            let mut worst = 0.0f32;
            for inverse in [false, true] {
                let mut enc = device.create_command_encoder(&Default::default());
                // Each direction from the same input: restore it first.
                let src = data_buffer(&device, &data, wgpu::BufferUsages::empty());
                enc.copy_buffer_to_buffer(&src, 0, &a, 0, a.size());
                queue.submit([enc.finish()]);
                let mut enc = device.create_command_encoder(&Default::default());
                let in_b = fft.record(&mut enc, inverse);
                queue.submit([enc.finish()]);
                let got = read(&device, &queue, if in_b { &b } else { &a }, a.size());
                let want = cpu_fft2(&host, cols, rows, inverse);
                let peak = want.iter().map(|v| v.norm()).fold(0.0f32, f32::max);
                let err = got
                    .chunks(2)
                    .zip(&want)
                    .map(|(g, w)| (c32::new(g[0], g[1]) - w).norm())
                    .fold(
                        0.0f32,
                        |m, e| if e.is_nan() { f32::INFINITY } else { m.max(e) },
                    );
                worst = worst.max(err / peak);
            }
            (worst, fft.in_workgroup_memory())
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn the_device_fft_equals_rustfft_at_the_prefilters_sizes() {
            // The mirrored grids of 1080p (both orientations) and 1080p
            // itself; radices 2, 3, 4, 5 and the generic 7, 11, 13.
            for (cols, rows) in [
                (3840, 2160),
                (1920, 1080),
                (2160, 3840),
                (7 * 16, 11 * 13),
                (98, 45),
            ] {
                let (e, fused) = fft2_error(cols, rows);
                eprintln!(
                    "device FFT {cols}×{rows} ({}): largest error {e:.2e} of the largest magnitude",
                    if fused {
                        "workgroup memory"
                    } else {
                        "multi-pass"
                    }
                );
                assert!(
                    e <= 1e-5,
                    "{cols}×{rows}: error {e:e} of the largest magnitude"
                );
            }
        }

        /// Every length the multi-pass kernels take factors into 2, 3, 4,
        /// 5, 7, 11 and 13: each radix alone, mixed, the prefilters' sides,
        /// and every factorable length up to 130, along rows and along
        /// columns, in workgroup memory and by the fallback.
        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn the_workgroup_fft_equals_rustfft_at_every_radix_and_mix() {
            let (device, queue) = crate::test_device(false);
            let mut lengths: Vec<usize> = (1..=130).filter(|n| radices(*n).is_ok()).collect();
            lengths.extend([
                3 * 5 * 7 * 11,
                13 * 11 * 4,
                5 * 5 * 5 * 3,
                1000,
                1080,
                1200,
                1280,
                1920,
            ]);
            for n in lengths {
                for (cols, rows) in [(n, 3), (2, n)] {
                    for path in [FftPath::Auto, FftPath::MultiPass] {
                        let (e, fused) = fft2_error_on(&device, &queue, cols, rows, path);
                        assert_eq!(fused, path == FftPath::Auto, "{cols}×{rows}");
                        assert!(
                            e <= 1e-5,
                            "{cols}×{rows} {path:?}: error {e:e} of the largest magnitude"
                        );
                    }
                }
            }
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn a_side_beyond_workgroup_memory_falls_back_to_the_passes() {
            // 16 KiB: 1920 complex values fit (15,360 bytes), 2160 do not.
            let (device, queue) = device_with_workgroup_bytes(16 * 1024);
            let (e, fused) = fft2_error_on(&device, &queue, 1920, 1080, FftPath::Auto);
            assert!(fused && e <= 1e-5, "{e:e}");
            let (e, fused) = fft2_error_on(&device, &queue, 2160, 1080, FftPath::Auto);
            assert!(!fused && e <= 1e-5, "{e:e}");
            let (e, w) = filter_error_on(&device, &queue, 2160, 9, 3, FftPath::Auto);
            assert!(!w && e <= 1e-5, "{e:e}");
            let (e, w) = filter_error_on(&device, &queue, 1920, 9, 3, FftPath::Auto);
            assert!(w && e <= 1e-5, "{e:e}");
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn a_length_with_a_large_prime_is_refused_not_transformed() {
            let (device, _) = crate::test_device(false);
            let mut kernels = FftKernels::new(&device).expect("kernels");
            let a = data_buffer(&device, &[0.0; 2 * 17 * 8], wgpu::BufferUsages::empty());
            let b = data_buffer(&device, &[0.0; 2 * 17 * 8], wgpu::BufferUsages::empty());
            let e = ComplexFft2d::new(&mut kernels, 17, 8, 1, &a, &b).err();
            assert!(
                matches!(e, Some(FftError::UnsupportedLength { n: 17, prime: 17 })),
                "{e:?}"
            );
            let gains = vec![vec![1.0; 17 * 8]; 3];
            let e = DctFilter::new(&mut kernels, 17, 8, &gains).err();
            assert!(
                matches!(e, Some(FftError::UnsupportedLength { n: 17, prime: 17 })),
                "{e:?}"
            );
        }

        /// The mirrored-grid filter the CPU prefilters run, by rustfft:
        /// mirror each plane to 2w×2h, multiply the spectrum by the even
        /// extension of `gain`, transform back, keep the first quadrant.
        fn cpu_mirrored_filter(plane: &[f32], gain: &[f32], w: usize, h: usize) -> Vec<f32> {
            let (w2, h2) = (2 * w, 2 * h);
            let at = |x: usize, n: usize| if x < n { x } else { 2 * n - 1 - x };
            let mirrored: Vec<c32> = (0..h2 * w2)
                .map(|i| c32::new(plane[at(i / w2, h) * w + at(i % w2, w)], 0.0))
                .collect();
            let mut spec = cpu_fft2(&mirrored, w2, h2, false);
            let even = |k: usize, n: usize| if k <= n { k } else { 2 * n - k };
            for (i, s) in spec.iter_mut().enumerate() {
                let (ky, kx) = (even(i / w2, h), even(i % w2, w));
                // The Nyquist bins (k = n) meet a zero coefficient of the
                // mirrored signal; any gain does.
                let g = if ky == h || kx == w {
                    0.0
                } else {
                    gain[ky * w + kx]
                };
                *s *= g;
            }
            let back = cpu_fft2(&spec, w2, h2, true);
            let scale = 1.0 / (w2 * h2) as f32;
            (0..h * w)
                .map(|i| back[(i / w) * w2 + i % w].re * scale)
                .collect()
        }

        fn filter_error(w: usize, h: usize, channels: usize) -> f32 {
            let (device, queue) = crate::test_device(false);
            let (auto, fused) = filter_error_on(&device, &queue, w, h, channels, FftPath::Auto);
            assert!(fused, "{w}×{h}: not in workgroup memory");
            let (passes, fused) =
                filter_error_on(&device, &queue, w, h, channels, FftPath::MultiPass);
            assert!(!fused);
            auto.max(passes)
        }

        /// The DCT filter by `path` against the mirrored-grid filter: the
        /// largest error over the largest value, and whether it ran in
        /// workgroup memory.
        fn filter_error_on(
            device: &wgpu::Device,
            queue: &wgpu::Queue,
            w: usize,
            h: usize,
            channels: usize,
            path: FftPath,
        ) -> (f32, bool) {
            let (frame, gains, got, fused) = filter_output(
                device,
                queue,
                (w, h, channels),
                path,
                FusedVariant::default(),
            );
            let mut worst = 0.0f32;
            for c in 0..channels {
                let plane = &frame[c * w * h..(c + 1) * w * h];
                let want = cpu_mirrored_filter(plane, &gains[c], w, h);
                let peak = want.iter().map(|v| v.abs()).fold(0.0f32, f32::max);
                for (g, v) in got[c * w * h..(c + 1) * w * h].iter().zip(&want) {
                    let e = (g - v).abs();
                    worst = worst.max(if e.is_nan() { f32::INFINITY } else { e / peak });
                }
            }
            (worst, fused)
        }

        /// The DCT filter by `path` and `variant` on a test frame: the
        /// frame, the gains, the output, and whether it ran in workgroup
        /// memory.
        #[allow(clippy::type_complexity)]
        fn filter_output(
            device: &wgpu::Device,
            queue: &wgpu::Queue,
            (w, h, channels): (usize, usize, usize),
            path: FftPath,
            variant: FusedVariant,
        ) -> (Vec<f32>, Vec<Vec<f32>>, Vec<f32>, bool) {
            let (device, queue) = (device.clone(), queue.clone());
            let mut kernels = FftKernels::new(&device).expect("kernels");
            kernels.set_path(path);
            kernels.set_fused_variant(variant);
            let frame = signal(channels * w * h, (w * 7 + h) as u64);
            // A smooth low-pass with a sharpening bump, different per channel.
            let gains: Vec<Vec<f32>> = (0..channels)
                .map(|c| {
                    (0..w * h)
                        .map(|i| {
                            let (fy, fx) = ((i / w) as f32 / h as f32, (i % w) as f32 / w as f32);
                            let r2 = fy * fy + fx * fx;
                            (1.0 + 0.5 * c as f32 * r2) * (-3.0 * r2).exp()
                        })
                        .collect()
                })
                .collect();
            let input = data_buffer(&device, &frame, wgpu::BufferUsages::empty());
            let output = data_buffer(
                &device,
                &vec![f32::NAN; frame.len()],
                wgpu::BufferUsages::empty(),
            );
            let mut filter = DctFilter::new(&mut kernels, w, h, &gains).expect("filter");
            let mut enc = device.create_command_encoder(&Default::default());
            filter.record(&mut enc, &input, &output).expect("record");
            queue.submit([enc.finish()]);
            let got = read(&device, &queue, &output, output.size());
            let fused = filter.in_workgroup_memory();
            (frame, gains, got, fused)
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn every_workgroup_variant_computes_the_heuristics_filter_bit_for_bit() {
            // Threads and sequences a workgroup only move butterflies
            // between threads: odd sides, ragged pairs, one channel and
            // three, threads not dividing the butterflies.
            let (device, queue) = crate::test_device(false);
            for (w, h, c) in [(40, 27, 3), (15, 9, 1), (98, 6, 3)] {
                let (_, _, want, fused) = filter_output(
                    &device,
                    &queue,
                    (w, h, c),
                    FftPath::Auto,
                    FusedVariant::default(),
                );
                assert!(fused);
                for (threads, max_seqs) in [
                    (Some(32), Some(1)),
                    (Some(96), Some(2)),
                    (Some(256), Some(8)),
                    (None, Some(8)),
                    (Some(64), None),
                ] {
                    let variant = FusedVariant { threads, max_seqs };
                    let (_, _, got, _) =
                        filter_output(&device, &queue, (w, h, c), FftPath::Auto, variant);
                    let differ = want
                        .iter()
                        .zip(&got)
                        .filter(|(a, b)| a.to_bits() != b.to_bits())
                        .count();
                    assert_eq!(
                        differ, 0,
                        "{w}×{h}×{c} at {variant:?}: {differ} values differ"
                    );
                    // The variant was built: its threads (a multiple of the
                    // workgroup's sequences) and no more sequences than asked.
                    let mut kernels = FftKernels::new(&device).expect("kernels");
                    kernels.set_fused_variant(variant);
                    let gains = vec![vec![1.0; w * h]; c];
                    DctFilter::new(&mut kernels, w, h, &gains).expect("filter");
                    assert!(!kernels.fused_modules.is_empty());
                    for &(_, seqs, t, _) in kernels.fused_modules.keys() {
                        assert!(
                            seqs <= max_seqs.unwrap_or(4),
                            "{variant:?}: {seqs} a workgroup"
                        );
                        if let Some(want) = threads {
                            assert_eq!(t, (want - want % seqs).max(seqs), "{variant:?}");
                        }
                    }
                }
            }
        }

        /// The adapter's tuned shape (issue 56, item 4) is followed at its
        /// size alone, computes the heuristics' output bit for bit, yields
        /// to a shape set explicitly, and an adapter the source does not
        /// know runs the heuristics. (The source is process-wide; no other
        /// test filters a 50×30 frame.)
        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn a_tuned_shape_is_followed_and_an_unknown_adapter_falls_back() {
            let (device, queue) = crate::test_device(false);
            let here = device.adapter_info().name;
            let shape = FusedVariant {
                threads: Some(128),
                max_seqs: Some(2),
            };
            let install = |adapter: String| {
                tuned::install(Box::new(move |info| {
                    std::sync::Arc::new(if info.name == adapter {
                        vec![((50, 30), shape)]
                    } else {
                        Vec::new()
                    })
                }))
            };
            let (w, h, c) = (50, 30, 3);
            let frame = signal(c * w * h, 5);
            let gains: Vec<Vec<f32>> = (0..c)
                .map(|k| {
                    (0..w * h)
                        .map(|i| 1.0 / (1.0 + (i + k) as f32 * 1e-3))
                        .collect()
                })
                .collect();
            let input = data_buffer(&device, &frame, wgpu::BufferUsages::empty());
            let output = data_buffer(&device, &frame, wgpu::BufferUsages::empty());
            let run = |kernels: &mut FftKernels, (w, h): (usize, usize)| {
                let g: Vec<Vec<f32>> = gains.iter().map(|p| p[..w * h].to_vec()).collect();
                let mut filter = DctFilter::new(kernels, w, h, &g).expect("filter");
                let mut enc = device.create_command_encoder(&Default::default());
                filter.record(&mut enc, &input, &output).expect("record");
                queue.submit([enc.finish()]);
                let got = read(&device, &queue, &output, (c * w * h * 4) as u64);
                (got, filter.variant(), filter.tuned())
            };
            install(here.clone());
            let mut kernels = FftKernels::new(&device).expect("kernels");
            assert_eq!(kernels.tuned_variant(w, h), Some(shape));
            let (tuned_out, variant, tuned) = run(&mut kernels, (w, h));
            assert_eq!((variant, tuned), (shape, true), "followed");
            let other = run(&mut kernels, (40, 30));
            assert_eq!(
                (other.1, other.2),
                (FusedVariant::default(), false),
                "its size alone"
            );
            let mut plain = FftKernels::new(&device).expect("kernels");
            plain.clear_tuned();
            let (heuristic_out, variant, tuned) = run(&mut plain, (w, h));
            assert_eq!((variant, tuned), (FusedVariant::default(), false));
            assert!(
                tuned_out
                    .iter()
                    .zip(&heuristic_out)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "the tuned shape's output is the heuristics' bit for bit"
            );
            let explicit = FusedVariant {
                threads: Some(64),
                max_seqs: Some(1),
            };
            kernels.set_fused_variant(explicit);
            let (_, variant, tuned) = run(&mut kernels, (w, h));
            assert_eq!(
                (variant, tuned),
                (explicit, false),
                "an explicit shape wins"
            );
            // Another adapter's table: this one runs the heuristics.
            install(format!("not {here}"));
            let mut unknown = FftKernels::new(&device).expect("kernels");
            assert_eq!(unknown.tuned_variant(w, h), None);
            let (_, variant, tuned) = run(&mut unknown, (w, h));
            assert_eq!((variant, tuned), (FusedVariant::default(), false));
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn the_dct_filter_is_the_mirrored_grid_filter() {
            // Odd and even sides, an odd number of sequences (a pair
            // with one sequence), one channel and three.
            for (w, h, c) in [
                (16, 12, 3),
                (15, 9, 1),
                (40, 27, 3),
                (7, 5, 3),
                (1, 1, 1),
                (1, 6, 3),
                (98, 1, 1),
                (143, 112, 3),
                (1920, 1080, 3),
            ] {
                let e = filter_error(w, h, c);
                eprintln!("DCT filter {w}×{h}×{c}: largest error {e:.2e} of the largest value");
                assert!(e <= 1e-5, "{w}×{h}×{c}: error {e:e} of the largest value");
            }
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn two_gain_sets_sharing_the_forward_rows_equal_two_filters() {
            let (device, queue) = crate::test_device(false);
            let (w, h) = (40, 27);
            let frame = signal(3 * w * h, 5);
            let set = |k: f32| -> Vec<Vec<f32>> {
                (0..3)
                    .map(|c| {
                        (0..w * h)
                            .map(|i| 1.0 / (1.0 + k * (i + c) as f32))
                            .collect()
                    })
                    .collect()
            };
            let (g0, g1) = (set(0.01), set(0.2));
            for path in [FftPath::Auto, FftPath::MultiPass] {
                let mut kernels = FftKernels::new(&device).expect("kernels");
                kernels.set_path(path);
                let mut filter =
                    DctFilter::with_gain_sets(&mut kernels, w, h, &[&g0, &g1]).expect("filter");
                let input = data_buffer(&device, &frame, wgpu::BufferUsages::empty());
                let outs: Vec<wgpu::Buffer> = (0..4)
                    .map(|_| {
                        data_buffer(
                            &device,
                            &vec![f32::NAN; frame.len()],
                            wgpu::BufferUsages::empty(),
                        )
                    })
                    .collect();
                let mut enc = device.create_command_encoder(&Default::default());
                filter
                    .record_sets(&mut enc, &input, &[(&outs[0], 1), (&outs[1], 0)])
                    .expect("record");
                filter
                    .record_set(&mut enc, &input, &outs[2], 1)
                    .expect("record");
                filter
                    .record_set(&mut enc, &input, &outs[3], 0)
                    .expect("record");
                queue.submit([enc.finish()]);
                let got: Vec<Vec<f32>> = outs
                    .iter()
                    .map(|b| read(&device, &queue, b, b.size()))
                    .collect();
                assert_eq!(got[0], got[2], "{path:?}: set 1");
                assert_eq!(got[1], got[3], "{path:?}: set 0");
                assert!(got[0].iter().all(|v| v.is_finite()));
                assert_ne!(got[0], got[1]);
                let mut enc = device.create_command_encoder(&Default::default());
                assert!(matches!(
                    filter.record_sets(&mut enc, &input, &[(&outs[0], 2)]),
                    Err(FftError::Gains(_))
                ));
            }
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn unit_gains_give_the_frame_back_and_bad_gains_are_refused() {
            let (device, queue) = crate::test_device(false);
            let mut kernels = FftKernels::new(&device).expect("kernels");
            let (w, h) = (30, 20);
            let frame = signal(3 * w * h, 9);
            let input = data_buffer(&device, &frame, wgpu::BufferUsages::empty());
            let output = data_buffer(
                &device,
                &vec![f32::NAN; frame.len()],
                wgpu::BufferUsages::empty(),
            );
            let mut filter =
                DctFilter::new(&mut kernels, w, h, &vec![vec![1.0; w * h]; 3]).expect("filter");
            let mut enc = device.create_command_encoder(&Default::default());
            filter.record(&mut enc, &input, &output).expect("record");
            queue.submit([enc.finish()]);
            let got = read(&device, &queue, &output, output.size());
            let err = got
                .iter()
                .zip(&frame)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(err < 1e-6, "{err}");
            let short = vec![vec![1.0; w * h - 1]; 3];
            assert!(matches!(
                DctFilter::new(&mut kernels, w, h, &short),
                Err(FftError::Gains(_))
            ));
            let nan = vec![vec![f32::NAN; w * h]; 3];
            assert!(matches!(
                DctFilter::new(&mut kernels, w, h, &nan),
                Err(FftError::Gains(_))
            ));
            let small = data_buffer(&device, &[0.0; 4], wgpu::BufferUsages::empty());
            let mut enc = device.create_command_encoder(&Default::default());
            assert!(matches!(
                filter.record(&mut enc, &small, &output),
                Err(FftError::TooLarge { .. })
            ));
        }
    }
}
