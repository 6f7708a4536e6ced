//! The configurations the simulator itself runs (no D-CNN), priced in
//! order under the study's time budget: each one's quality and latency on
//! the CPU and, where the device runs its prefilter, on the device.

use std::time::Instant;

use super::measure::{Measured, displays_and_latency};
use super::quality::Scorer;
use super::{AppError, Record, TradeoffOptions, out_of_time};
use crate::preprocess::Prefilter;
use nedrt_optics::sim::{Image, Method};

/// One configuration: the scorer of its optics, its DOE's hash, the
/// method and its prefilter, and its name in the table.
pub(super) struct Config<'s> {
    pub(super) scorer: &'s Scorer,
    pub(super) doe_hash: &'s str,
    pub(super) method: Method,
    pub(super) prefilter: Prefilter,
    pub(super) name: String,
}

/// What the linear configurations are priced under: the budget, what
/// they are measured on, the progress bar.
pub(super) struct Priced<'a, 'r> {
    pub(super) o: &'a TradeoffOptions,
    pub(super) start: Instant,
    pub(super) run: &'a LinearRun<'r>,
    pub(super) bar: &'a nedrt_app::Phase<'r>,
}

impl Priced<'_, '_> {
    /// Prices each configuration in order into `records`; those past the
    /// budget go to `skipped` as not run.
    pub(super) fn linear<'s>(
        &self,
        configs: impl Iterator<Item = Config<'s>>,
        records: &mut Vec<Record>,
        skipped: &mut Vec<String>,
    ) -> Result<(), AppError> {
        for c in configs {
            if !out_of_time(self.o, self.start, &c.name, skipped) {
                records.extend(linear_records(self.run, &c)?);
            }
            self.bar.inc(1);
        }
        Ok(())
    }
}

/// The same configuration's records on the CPU and, where `run` has a
/// GPU and the device runs the prefilter (the Wiener, `lsq`, `refine:K`),
/// on the device too ("… wgpu": the frame up, the display image back).
fn linear_records(run: &LinearRun, c: &Config) -> Result<Vec<Record>, AppError> {
    let mut out = vec![linear_record_on(None, run, c, &c.name)?];
    if let (Some(gpu), true) = (
        &run.gpu,
        crate::device_prefilter::runs_on_device(c.method, c.prefilter),
    ) {
        out.push(linear_record_on(
            Some(gpu),
            run,
            c,
            &format!("{} wgpu", c.name),
        )?);
    }
    Ok(out)
}

/// The record `name`, on the CPU or `gpu`, of configuration `c`: its
/// quality on the images and its latency on the frame
/// ([`displays_and_latency`]).
fn linear_record_on(
    gpu: Option<&(crate::device_prefilter::Gpu, String)>,
    run: &LinearRun,
    c: &Config,
    name: &str,
) -> Result<Record, AppError> {
    let mut engine = crate::device_prefilter::for_system_on(
        gpu.map(|(g, _)| g),
        c.method,
        c.prefilter,
        &c.scorer.prepared,
        &mut Default::default(),
    )?;
    let Measured {
        displays,
        latency_ms,
        estimated_ms,
    } = displays_and_latency(
        name,
        run.inputs,
        run.frame,
        run.repeat,
        run.max_seconds,
        |i| engine.run(i),
    )?;
    let q = c.scorer.quality(c.method, &displays)?;
    Ok(q.record(
        name,
        c.method,
        latency_ms,
        estimated_ms,
        (c.method.optics() == nedrt_optics::sim::Optics::Doe).then(|| c.doe_hash.to_string()),
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
    pub(super) repeat: usize,
    pub(super) max_seconds: f64,
    pub(super) device: String,
    /// The GPU of `--backends …,wgpu`, for the prefilters' device rows.
    pub(super) gpu: Option<(crate::device_prefilter::Gpu, String)>,
}
