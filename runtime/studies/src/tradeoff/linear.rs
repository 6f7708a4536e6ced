//! The configurations the simulator itself runs (no D-CNN), priced in
//! order under the study's time budget: each one's quality and latency on
//! the CPU and, where the device runs its prefilter, on the device.

use std::time::Instant;

use super::measure::time_median;
use super::quality::Scorer;
use super::{AppError, Record, TradeoffOptions, out_of_time};
use crate::preprocess::Prefilter;
use nedrt_optics::sim::{Image, Method};

/// Where the linear configurations' records go, under the time budget.
pub(super) struct Priced<'a, 'r> {
    pub(super) o: &'a TradeoffOptions,
    pub(super) start: Instant,
    pub(super) run: &'a LinearRun<'r>,
    pub(super) records: &'a mut Vec<Record>,
    pub(super) skipped: &'a mut Vec<String>,
    pub(super) bar: &'a nedrt_app::Phase<'r>,
}

impl Priced<'_, '_> {
    /// Prices each (scorer, DOE hash, method, prefilter, name) in order;
    /// those past the budget are listed as not run.
    pub(super) fn linear<'s>(
        &mut self,
        configs: impl Iterator<Item = (&'s Scorer, &'s str, Method, Prefilter, String)>,
    ) -> Result<(), AppError> {
        for (scorer, hash, m, p, name) in configs {
            if !out_of_time(self.o, self.start, &name, self.skipped) {
                self.records
                    .extend(linear_records(self.run, scorer, hash, m, p, &name)?);
            }
            self.bar.inc(1);
        }
        Ok(())
    }
}

/// The same configuration's records on the CPU and, where `run` has a
/// GPU and the device runs the prefilter (the Wiener, `lsq`, `refine:K`),
/// on the device too ("… wgpu": the frame up, the display image back).
fn linear_records(
    run: &LinearRun,
    scorer: &Scorer,
    doe_hash: &str,
    m: Method,
    prefilter: Prefilter,
    name: &str,
) -> Result<Vec<Record>, AppError> {
    let mut out = vec![linear_record_on(
        None, run, scorer, doe_hash, m, prefilter, name,
    )?];
    if let (Some(gpu), true) = (
        &run.gpu,
        crate::device_prefilter::runs_on_device(m, prefilter),
    ) {
        out.push(linear_record_on(
            Some(gpu),
            run,
            scorer,
            doe_hash,
            m,
            prefilter,
            &format!("{name} wgpu"),
        )?);
    }
    Ok(out)
}

/// The record, on the CPU or `gpu`, of a method the simulator itself runs
/// (no D-CNN), with `prefilter`: its quality on the images and its latency
/// on the frame (estimated from the images' time per pixel, and marked so, when
/// measuring would take longer than `max_seconds`).
#[allow(clippy::too_many_arguments)]
fn linear_record_on(
    gpu: Option<&(crate::device_prefilter::Gpu, String)>,
    run: &LinearRun,
    scorer: &Scorer,
    doe_hash: &str,
    m: Method,
    prefilter: Prefilter,
    name: &str,
) -> Result<Record, AppError> {
    let mut engine = crate::device_prefilter::for_system_on(
        gpu.map(|(g, _)| g),
        m,
        prefilter,
        &scorer.prepared,
        &mut Default::default(),
    )?;
    let mut seconds_per_pixel = 0.0;
    let displays: Vec<Image> = run
        .inputs
        .iter()
        .map(|i| {
            let t = Instant::now();
            let d = engine.run(i);
            seconds_per_pixel = t.elapsed().as_secs_f64() / (i.width * i.height) as f64;
            d
        })
        .collect::<Result<_, _>>()?;
    let q = scorer.quality(m, &displays)?;
    let estimate = seconds_per_pixel * (run.frame_size.0 * run.frame_size.1) as f64;
    let (latency_ms, estimated_ms) = if estimate * (run.repeat + 1) as f64 > run.max_seconds {
        tracing::warn!(
            "{name}: latency at {}×{} not measured (≈ {estimate:.1} s per frame, over --max-seconds)",
            run.frame_size.0,
            run.frame_size.1
        );
        (None, Some(estimate * 1e3))
    } else {
        let seconds = time_median(run.repeat, || {
            std::hint::black_box(engine.run(run.frame)?);
            Ok::<_, AppError>(())
        })?;
        (Some(seconds * 1e3), None)
    };
    Ok(q.record(
        name,
        m,
        latency_ms,
        estimated_ms,
        (m.optics() == nedrt_optics::sim::Optics::Doe).then(|| doe_hash.to_string()),
        match gpu {
            Some((_, adapter)) => ("wgpu", "f32", format!("{adapter} (frame up, display back)")),
            None => ("cpu", "f32", run.device.clone()),
        },
    ))
}

/// What every simulator-run configuration is measured on.
pub(super) struct LinearRun<'a> {
    pub(super) inputs: &'a [Image],
    /// The latency frame.
    pub(super) frame: &'a Image,
    pub(super) frame_size: (usize, usize),
    pub(super) repeat: usize,
    pub(super) max_seconds: f64,
    pub(super) device: String,
    /// The GPU of `--backends …,wgpu`, for the prefilters' device rows.
    pub(super) gpu: Option<(crate::device_prefilter::Gpu, String)>,
}
