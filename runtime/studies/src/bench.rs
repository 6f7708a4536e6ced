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
use nedrt_core::image_io::{DEFAULT_INPUT_NAME, DEFAULT_INPUT_PNG, decode};
use nedrt_optics::propagate::{crop_centred, exact_period_cells, fft_period_cells, mft_cells};
use nedrt_optics::psf::max_difference_of_peak;
use nedrt_optics::pupil::{PupilGrid, pupil_field};
use nedrt_optics::sim::{Method, Simulator, perceive};
use nedrt_optics::{PsfRequest, PsfSpec, SamplingReport, compute_psfs};

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
    nedrt_core::util::write_atomic(path, &bytes).map_err(|e| AppError::output(path, e))
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
        nedrt_optics::cache::PsfCache::disabled(),
    )?;
    // The 2-D propagators are timed here (`bench radial` times the radial path).
    let mut c = sim.calib.clone();
    c.simulation.propagator = nedrt_core::calib::PropagatorSetting::TwoD;
    let c = &c;
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
    // sub-sampling that the convergence rule of docs/model.md §18 (item 14)
    // reaches for DOE PSFs.
    let sub = 6;
    let step = report.channels[0].pupil_step_um * 1e-6;
    let period = report.channels[0].period_cells;
    let grid = PupilGrid::covering(c.aperture_radius_m, step);
    let lambda = c.channels[g].wavelength_m;
    let dtheta = c.retinal_step_rad();
    // Through an eye pupil (--pupil-mm) the planner propagates only the
    // stop's square (docs/model.md §4a): so do the propagators here.
    let (t_pupil, (q, grid)) = time(repeat, || {
        let phase = sim.doe.phase_on(grid, c, g);
        match c.eye_stop(g) {
            Some(stop) => nedrt_optics::pupil::pupil_field_through(
                grid,
                c.aperture_radius_m,
                spec.psi_rad,
                Some(&phase),
                stop,
            ),
            None => (
                pupil_field(grid, c.aperture_radius_m, spec.psi_rad, Some(&phase)),
                grid,
            ),
        }
    });
    let (t_exact, _) = time(repeat, || exact_period_cells(&q, grid, lambda, dtheta));
    let (t_fft, fft) = time(repeat, || fft_period_cells(&q, grid, lambda, dtheta, sub));
    let fft = crop_centred(
        &fft.ok_or_else(|| AppError::Internal("period not whole".into()))?,
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
    let prepared = sim.prepare(
        &[Method::DoeOnly, Method::Conventional],
        &[1.0],
        &nedrt_core::progress::Silent,
    )?;
    let mut out = String::new();
    write_f64(
        &dump.join("image.f64"),
        input.data().iter().map(|v| *v as f64),
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

/// Seconds of one call (no warm-up: for runs of minutes).
fn time_once<T>(f: impl FnOnce() -> T) -> (f64, T) {
    let t = Instant::now();
    let out = f();
    (t.elapsed().as_secs_f64(), out)
}

/// J0 evaluations and GEMM flops of a radial run whose window has
/// half-width `half` cells: per channel the kernel has (fine + coarse
/// annuli to the corner) × N_ρ entries and meets 2 columns per PSF.
fn radial_work(report: &SamplingReport, specs: &[PsfSpec], half: usize) -> (f64, f64) {
    let corner = std::f64::consts::SQRT_2 * (half as f64 + 0.5);
    let m = report.annuli_per_cell as f64;
    let angles = (corner * m).ceil() + (corner * m / 2.0).ceil();
    let nodes = report.channels.first().map_or(0, |c| c.pupil_samples) as f64;
    let mut per_channel = std::collections::BTreeMap::<usize, f64>::new();
    for s in specs {
        *per_channel.entry(s.channel).or_default() += 1.0;
    }
    let j0 = per_channel.len() as f64 * angles * nodes;
    let flops = per_channel.values().map(|n| 4.0 * angles * nodes * n).sum();
    (j0, flops)
}

/// The radial (Hankel) path against the 2-D path on the same requests, in
/// one run (docs/benchmarks.md): the evaluation's 7 depths × 3 channels
/// through the three-lens DOE as a radial profile at the fabrication pitch,
/// and the lens PSFs of the AI display's Wiener average. Both paths
/// simulate the same element (the 2-D path samples the profile at every
/// grid point); no cache.
pub fn radial(common: &CommonOptions, dump: &Path) -> Result<String, AppError> {
    create_dir(dump)?;
    let c = &common.calibration()?;
    let mut two_d = c.clone();
    two_d.simulation.propagator = nedrt_core::calib::PropagatorSetting::TwoD;
    let doe = nedrt_optics::HeightMap::three_lens_radial(c, c.doe_design_pitch_m)
        .resampled(c.doe_fabrication_pitch_m);
    let channels = 0..c.channels.len();
    let eval: Vec<PsfSpec> = c
        .depth_sweep_d(0.5)
        .into_iter()
        .flat_map(|d| {
            channels.clone().map(move |ch| PsfSpec {
                channel: ch,
                psi_rad: c.psi_rad(ch, d),
            })
        })
        .collect();
    let mut wiener: Vec<PsfSpec> = Vec::new();
    for d in c.depth_sweep_d(c.wiener.average_step_d) {
        for ch in channels.clone() {
            for (s, _) in nedrt_optics::sim::methods::psf_terms(c, Method::Ai, d, ch) {
                if !wiener.contains(&s) {
                    wiener.push(s);
                }
            }
        }
    }
    let (gflops, _) = ceilings();
    // The radial kernel's cost per entry (one core): 64 rows of the 3 µm
    // DOE request's shape, and libm's J0 for comparison.
    let (kernel_ns, libm_ns) = {
        let rho: Vec<f64> = (0..2391).map(|n| (n as f64 + 0.5) * 2.09e-6).collect();
        let t: Vec<f64> = (0..33_900)
            .map(|i| (i as f64 + 0.5) * c.retinal_step_rad() / 32.0)
            .collect();
        let k = 2.0 * std::f64::consts::PI / 530e-9;
        let (tk, s) = time_once(|| {
            t.chunks(64)
                .step_by(16)
                .map(|b| nedrt_optics::radial::j0_kernel(k, b, &rho)[0])
                .sum::<f64>()
        });
        std::hint::black_box(s);
        let entries = t.chunks(64).step_by(16).map(<[f64]>::len).sum::<usize>() * rho.len();
        let n = 2_000_000;
        let (tl, s) = time_once(|| (0..n).map(|i| libm::j0(2.0 + i as f64 * 1e-3)).sum::<f64>());
        std::hint::black_box(s);
        (tk / entries as f64 * 1e9, tl / n as f64 * 1e9)
    };
    let mut out = String::new();
    let mut rows = Vec::new();
    for (name, specs, element) in [
        (
            "three-lens radial DOE at the fabrication pitch, 7 depths × 3 channels",
            &eval,
            Some(&doe),
        ),
        ("lens alone, AI display's Wiener average", &wiener, None),
    ] {
        let request = PsfRequest {
            specs: specs.clone(),
            doe: element,
        };
        let (t_radial, radial) = time_once(|| compute_psfs(c, &request, &|| ()));
        let radial = radial?;
        let (t_2d, flat) = time_once(|| compute_psfs(&two_d, &request, &|| ()));
        let flat = flat?;
        let r = &radial.report;
        // The kernel covered the final window (the lens alone: its first
        // guess may have been wider) or, with a DOE, the 2-D period's cap.
        let half = match element {
            Some(_) => r
                .channels
                .iter()
                .map(|ch| (ch.period_cells - 1) / 2)
                .min()
                .unwrap_or(0),
            None => (r.window_cells - 1) / 2,
        };
        let (j0, flops) = radial_work(r, specs, half);
        let diff = max_difference_of_peak(&radial, &flat);
        let info = json!({
            "kind": "radial", "request": name, "psfs": specs.len(),
            "radial_s": t_radial, "two_d_s": t_2d, "ratio": t_2d / t_radial,
            "radial_report": r.summary(), "two_d_report": flat.report.summary(),
            "max_abs_radial_minus_two_d_of_peak": diff,
            "j0_evaluations": j0, "kernel_ns_each": kernel_ns, "libm_j0_ns_each": libm_ns,
            "kernel_s_one_core": j0 * kernel_ns * 1e-9,
            "gemm_flops": flops, "gemm_s_at_peak": flops / (gflops * 1e9), "f64_gemm_gflops": gflops,
            "threads": rayon::current_num_threads(),
        });
        let _ = writeln!(out, "{info}");
        rows.push(info);
    }
    super::write_text(&dump.join("radial.json"), &json!(rows).to_string())?;
    Ok(out)
}
