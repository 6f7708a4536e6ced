//! `nedrt bench`: timings of the PSF and the perceived image, with the exact
//! inputs written to a folder so that `tools/bench/compare_numpy.py` can run
//! the same computations in numpy side by side (docs/benchmarks.md).
//! Performance is measured here, never asserted in tests.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use faer::{Accum, Mat, Par};
use serde_json::json;

use super::{AppError, CommonOptions, create_dir};
use crate::optics::propagate::{crop_centred, exact_period_cells, fft_period_cells, mft_cells};
use crate::optics::pupil::{PupilGrid, pupil_field};
use crate::optics::{PsfRequest, PsfSpec, compute_psfs};
use crate::sim::image_io::{DEFAULT_INPUT_NAME, DEFAULT_INPUT_PNG, decode};
use crate::sim::{Method, Simulator, perceive};

/// Median of timings (the upper one of an even count); `v` must not be empty.
pub(crate) fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn time<T>(repeat: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut out = f();
    let mut times = Vec::new();
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        out = f();
        times.push(t.elapsed().as_secs_f64());
    }
    (median(times), out)
}

fn write_f64(path: &Path, v: impl Iterator<Item = f64>) -> Result<(), AppError> {
    let bytes: Vec<u8> = v.flat_map(|x| x.to_le_bytes()).collect();
    crate::util::write_atomic(path, &bytes).map_err(|e| AppError::output(path, e))
}

/// Measured ceilings of this machine: f64 GEMM rate (GFLOP/s, all cores)
/// and copy bandwidth (GB/s, bytes read + written).
pub fn ceilings() -> (f64, f64) {
    let n = 1536;
    let a = Mat::<f64>::from_fn(n, n, |i, j| ((i * 7 + j * 13) % 17) as f64 * 0.1 + 1.0);
    let b = a.clone();
    let mut c = Mat::<f64>::zeros(n, n);
    let (t, _) = time(3, || {
        faer::linalg::matmul::matmul(
            c.as_mut(),
            Accum::Replace,
            a.as_ref(),
            b.as_ref(),
            1.0,
            Par::rayon(0),
        )
    });
    let gflops = 2.0 * (n as f64).powi(3) / t / 1e9;
    let src = vec![1.0f64; 32 << 20];
    let mut dst = vec![0.0f64; 32 << 20];
    let (t, _) = time(5, || dst.copy_from_slice(&src));
    let gbps = 2.0 * 8.0 * src.len() as f64 / t / 1e9;
    std::hint::black_box(&dst);
    (gflops, gbps)
}

/// One PSF (G, 1.0 D, three-lens DOE on its 6 µm grid) through the planner,
/// and the MFT and FFT propagators on its final sampling.
pub fn psf(common: &CommonOptions, dump: &Path, repeat: usize) -> Result<String, AppError> {
    create_dir(dump)?;
    let sim = Simulator::new(
        common.calibration()?,
        common.doe_path(),
        crate::optics::cache::PsfCache::disabled(),
    )?;
    let c = &sim.calib;
    let g = c.design_channel;
    let spec = PsfSpec {
        channel: g,
        psi_rad: c.psi_rad(g, 1.0),
    };
    let request = PsfRequest {
        specs: vec![spec],
        doe: Some(&sim.doe),
    };
    let (t_planner, set) = time(repeat, || compute_psfs(c, &request, &|| ()));
    let set = set?;
    let report = &set.report;
    let w = report.window_cells;
    // The propagators alone, on the planner's grid, at the 6×6 midpoint
    // sub-sampling that optics.md's convergence rule reaches for DOE PSFs.
    let sub = 6;
    let step = report.channels[0].pupil_step_um * 1e-6;
    let period = report.channels[0].period_cells;
    let grid = PupilGrid::covering(c.aperture_radius_m, step);
    let lambda = c.channels[g].wavelength_m;
    let dtheta = c.retinal_step_rad();
    let (t_pupil, q) = time(repeat, || {
        let phase = sim.doe.phase_on(grid, c, g);
        pupil_field(grid, c.aperture_radius_m, spec.psi_rad, Some(&phase))
    });
    let (t_exact, _) = time(repeat, || exact_period_cells(&q, grid, lambda, dtheta));
    let (t_fft, fft) = time(repeat, || fft_period_cells(&q, grid, lambda, dtheta, sub));
    let fft = crop_centred(
        &fft.ok_or_else(|| AppError::Usage("period not whole".into()))?,
        period,
        w,
    );
    let (t_mft, mft) = time(repeat.min(2), || {
        mft_cells(&q, grid, lambda, w, dtheta, sub)
    });
    let diff = fft
        .iter()
        .zip(&mft)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    write_f64(&dump.join("pupil.f64"), q.iter().flat_map(|z| [z.re, z.im]))?;
    write_f64(&dump.join("psf.f64"), mft.iter().copied())?;
    let n = grid.samples as f64;
    let k = (w * sub) as f64;
    let m = (sub * period) as f64;
    let mft_flops = 8.0 * k * n * n + 8.0 * k * k * n;
    let fft_flops = 2.0 * 5.0 * m * m * m.log2();
    let info = json!({
        "kind": "psf", "channel": c.channels[g].name, "accommodation_d": 1.0, "psi_rad": spec.psi_rad,
        "pupil_samples": grid.samples, "pupil_step_m": step, "wavelength_m": lambda, "cell_rad": dtheta,
        "window": w, "sub_samples": sub, "period_cells": period, "fft_size": sub * period,
        "planner_s": t_planner, "pupil_s": t_pupil, "exact_s": t_exact, "fft_s": t_fft, "mft_s": t_mft,
        "mft_flops": mft_flops, "fft_flops": fft_flops, "mft_vs_fft_max_abs": diff,
        "threads": rayon::current_num_threads(),
    });
    let path = dump.join("psf.json");
    super::write_text(&path, &info.to_string())?;
    Ok(info.to_string())
}

/// One perceived 512×512 display image (3 channels, one depth) through lens
/// + DOE at 1.0 D and through the lens alone.
pub fn perceived(common: &CommonOptions, dump: &Path, repeat: usize) -> Result<String, AppError> {
    create_dir(dump)?;
    let sim = Simulator::new(common.calibration()?, common.doe_path(), common.cache())?;
    let input = decode(DEFAULT_INPUT_PNG, DEFAULT_INPUT_NAME)?.image;
    let prepared = sim.prepare(&[Method::DoeOnly, Method::Conventional], &[1.0], None)?;
    let mut out = String::new();
    write_f64(
        &dump.join("image.f64"),
        input.planes.iter().flatten().map(|v| *v as f64),
    )?;
    for (name, method) in [("doe", Method::DoeOnly), ("lens", Method::Conventional)] {
        let psfs = prepared.system_psfs(method, 1.0)?;
        let (t, _) = time(repeat, || perceive(&input, &psfs));
        write_f64(
            &dump.join(format!("kernel_{name}.f64")),
            psfs.iter().flat_map(|p| p.cells.iter().copied()),
        )?;
        let info = json!({
            "kind": "perceived", "optics": name, "width": input.width, "height": input.height,
            "window": psfs[0].window, "veil": psfs.iter().map(|p| p.veil).collect::<Vec<_>>(),
            "seconds": t, "threads": rayon::current_num_threads(),
        });
        super::write_text(
            &dump.join(format!("perceived_{name}.json")),
            &info.to_string(),
        )?;
        let _ = writeln!(out, "{info}");
    }
    Ok(out)
}
