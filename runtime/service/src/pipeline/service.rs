//! The service: stages on their own threads joined by bounded newest-wins
//! channels, and the present loop on the caller's thread.
//!
//! ```text
//! Compositor::submit ─► upload ─► preprocess ─► encode ─► NewestSlot ─► present loop ─► Sink
//!   (validate)          (decode)  (each view,   (clamp,   (newest      (just in time
//!                                 fallback)     transfer) wins)        for the refresh)
//! ```
//!
//! One pipeline for any number of views ([`Preprocessing`]): on the host path
//! the upload stage decodes each view's frame and blends its quads, the
//! preprocess stage runs each view's engine into its region of the panel
//! image ([`views`]) and the encode stage turns it into codes. On the
//! device path the upload stage passes each view's frame on as the client
//! sent it (or runs a host stage where the view has one: a network's
//! Wiener the device cannot run), the preprocess stage uploads it once
//! and records every view's unpack, layers, stage and encode on the sink's
//! device in one submission ([`super::device_frames`]), and the sink
//! copies the codes on the device: no read-back. If the device fails, the
//! preprocess stage switches to the host for good (each view's fallback,
//! the CPU encode), as the host path switches engines.
//!
//! Back-pressure: every hand-over keeps the newest frame. A stage that
//! falls behind works on the newest frame it can get; older ones are
//! dropped and counted (`dropped_queued`, `dropped_at_present`). Submitting
//! never blocks on the pipeline and the present loop never waits for a
//! frame: at each refresh it shows the newest finished frame, if any.

mod compositor;
mod control;
mod engine;
mod present_loop;
mod stages;
mod views;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

use crossbeam_channel::Receiver;

use super::channel::newest_channel;
use super::device_frames::DeviceFrames;
use super::frame::ViewFrame;
use super::pacing::{Clock, DisplaySchedule, Estimate, NewestSlot, Pacer, PresentGate};
use super::stats::{MARKED_STAGES, Outcome, Report, Stage, Stats};
use crate::compose::{LayerSet, ViewGeometry, ViewRegion};
use crate::pipeline::ladder::Ladder;
use crate::present::transfer::Transfer;
use crate::present::{DisplayFrame, PanelFrame};
pub use compositor::Compositor;
use compositor::{Submission, Timed, ViewSlot};
pub use control::Control;
use engine::{Budget, DeviceGate, Engine, Processed};
pub use stages::{DevicePreprocessing, FallbackFactory, HostPrep, PreprocessStage, Preprocessing};
use views::{HostViews, Intake, Uptake};

/// The panel the service drives.
#[derive(Debug, Clone)]
pub struct PanelConfig {
    pub width: usize,
    pub height: usize,
    pub refresh_hz: f64,
    pub transfer: Transfer,
    /// Pixels per unit of tan(angle) seen through the eyepiece, to place
    /// quad layers given in degrees ([`crate::compose::ViewGeometry`]).
    pub pixels_per_tan: f64,
    /// The views on the panel, each its own eyepiece and preprocessing;
    /// empty: one view, the whole panel.
    pub views: Vec<ViewRegion>,
}

/// A running pipeline.
#[derive(Debug)]
pub struct Service {
    panel: PanelConfig,
    compositor: Option<Compositor>,
    slot: Arc<NewestSlot<Timed<PanelFrame>>>,
    stats: Arc<Stats>,
    clock: Arc<dyn Clock>,
    schedule: Arc<DisplaySchedule>,
    /// The present loop's announcements for the device's submissions.
    gate: Arc<PresentGate>,
    /// Set when the last stage has finished (every sender dropped).
    drained: Arc<AtomicBool>,
    /// Set when the present loop has ended: stages then pass frames on
    /// unprocessed and count them as in flight at stop, so a stop never
    /// waits for a D-CNN run whose result nobody will see.
    stopping: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

/// What every stage thread shares besides its channels.
#[derive(Clone)]
struct StageContext {
    stats: Arc<Stats>,
    clock: Arc<dyn Clock>,
    stopping: Arc<AtomicBool>,
}

/// What a stage's work says of a frame besides its output.
#[derive(Debug, Default, Clone, Copy)]
pub(super) struct StageNotes {
    /// Time the stage held the frame back for other work (the device's
    /// yield to a present, pacing::gate).
    pub(super) waited_ns: u64,
    /// The device's own time for the frame's stages (timestamps; every
    /// view's summed).
    pub(super) gpu_ns: Option<u64>,
    /// The device path's host time up to the frame's submission, and its
    /// whole submission's time on the device (timestamps).
    pub(super) record_ns: Option<u64>,
    pub(super) frame_gpu_ns: Option<u64>,
    /// The frame budget's level the frame ran.
    pub(super) level: Option<u8>,
}

fn spawn_stage<I: Send + 'static, O: Send + 'static>(
    name: &'static str,
    stage: Stage,
    rx: Receiver<Timed<I>>,
    out: impl Fn(Timed<O>) + Send + 'static,
    StageContext {
        stats,
        clock,
        stopping,
    }: StageContext,
    // The frame's id and predicted refresh, the item, the counters, and
    // what the stage notes of the frame (the time it held the frame back
    // for other work, its device times).
    mut work: impl FnMut(u64, u64, I, &Stats, &mut StageNotes) -> Option<O> + Send + 'static,
) -> std::io::Result<JoinHandle<()>> {
    std::thread::Builder::new()
        .name(name.into())
        .spawn(move || {
            // How long this stage held its last frame back for other work.
            let mut last_hold_ns = 0;
            for t in rx {
                if stopping.load(Ordering::SeqCst) {
                    stats.in_flight_at_stop.fetch_add(1, Ordering::Relaxed);
                    continue;
                }
                let span = tracing::info_span!("stage", stage = %name, frame = t.id).entered();
                let t0 = clock.now_ns();
                // Its wait in this stage's queue, as far as the last
                // frame's hold made it longer: the hold passed on.
                let behind_hold_ns = t0.saturating_sub(t.ready_ns).min(last_hold_ns);
                let mut notes = StageNotes::default();
                let result = work(t.id, t.predicted_ns, t.item, &stats, &mut notes);
                let ns = clock.now_ns().saturating_sub(t0);
                last_hold_ns = notes.waited_ns.min(ns);
                drop(span);
                stats.record(stage, ns);
                if let Some(item) = result {
                    let mut stages_ns = t.stages_ns;
                    if let Some(m) = MARKED_STAGES.iter().position(|&s| s == stage) {
                        stages_ns[m] = [t0, t0 + ns];
                    }
                    out(Timed {
                        item,
                        id: t.id,
                        start_ns: t.start_ns,
                        work_ns: t.work_ns + ns,
                        waited_ns: t.waited_ns + last_hold_ns,
                        behind_hold_ns: t.behind_hold_ns + behind_hold_ns,
                        gpu_ns: notes.gpu_ns.or(t.gpu_ns),
                        record_ns: notes.record_ns.or(t.record_ns),
                        frame_gpu_ns: notes.frame_gpu_ns.or(t.frame_gpu_ns),
                        level: notes.level.or(t.level),
                        owner: t.owner,
                        submit_ns: t.submit_ns,
                        predicted_ns: t.predicted_ns,
                        hold: t.hold,
                        ready_ns: t0 + ns,
                        stages_ns,
                    });
                }
            }
        })
}

impl Service {
    /// Starts the stage threads with `engines`, one per view of `panel`
    /// (a panel without views is one view); frames flow once submitted
    /// through [`Service::compositor`], and reach a sink through
    /// [`Service::present_loop`]. With a `ladder` (engines whose views run
    /// [`crate::pipeline::ladder::HostLevels`] or
    /// [`crate::pipeline::ladder::DeviceLevels`] on its selection), each
    /// level whose time is not known is run first, and each frame runs the
    /// level the frame budget picks.
    pub fn start(
        panel: PanelConfig,
        engines: Preprocessing,
        ladder: Option<Ladder>,
        clock: Arc<dyn Clock>,
    ) -> std::io::Result<Self> {
        let regions = if panel.views.is_empty() {
            vec![ViewRegion {
                x: 0,
                y: 0,
                width: panel.width,
                height: panel.height,
            }]
        } else {
            panel.views.clone()
        };
        let n = regions.len();
        let counts_match = match &engines {
            Preprocessing::Host(stages) => stages.len() == n,
            Preprocessing::Device(d) => {
                d.frames.views() == n && d.host.len() == n && d.fallback.len() == n
            }
        };
        if !counts_match {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("engines for {} views on a panel of {n}", engines.views()),
            ));
        }
        views::check_regions(&regions, (panel.width, panel.height))?;
        let stats = Arc::new(Stats::default());
        stats.set_timeline_origin(clock.now_ns());
        let queued = stats.dropped_queued.clone();
        // A frame of each view may wait (two eyes alternating); an eye that
        // submits twice while the upload stage is busy can still evict the
        // other's one queued frame: the upload stage, a decode, is quick.
        let (ingest_tx, ingest_rx) = newest_channel(regions.len(), queued.clone());
        let (upload_tx, upload_rx) = newest_channel(1, queued.clone());
        let (dcnn_tx, dcnn_rx) = newest_channel(1, queued.clone());
        let slot = Arc::new(NewestSlot::<Timed<PanelFrame>>::new());
        let drained = Arc::new(AtomicBool::new(false));
        let stopping = Arc::new(AtomicBool::new(false));
        let context = StageContext {
            stats: stats.clone(),
            clock: clock.clone(),
            stopping: stopping.clone(),
        };
        let mut threads = Vec::new();
        // Quads are blended where the frame first is planes: on the host
        // after the decode, or on the device after the unpack of a frame
        // uploaded as it came.
        let slots: Vec<ViewSlot> = regions
            .iter()
            .map(|&region| ViewSlot {
                region,
                geometry: ViewGeometry {
                    width: region.width,
                    height: region.height,
                    pixels_per_tan: panel.pixels_per_tan,
                },
                layers: Arc::new(LayerSet::default()),
            })
            .collect();
        let size = (panel.width, panel.height);
        let layers = |v: usize| slots[v].layers.clone();
        let period_ns = Pacer::period_ns_of(panel.refresh_hz);
        let gate = Arc::new(PresentGate::new(period_ns));
        let (intake, mut engine, path) = match engines {
            Preprocessing::Host(stages) => {
                let intake = (0..n)
                    .map(|v| (regions[v], layers(v), Uptake::Decode))
                    .collect();
                let engine = stages
                    .into_iter()
                    .enumerate()
                    .map(|(v, stage)| (regions[v], layers(v), stage))
                    .collect();
                let path = match n {
                    1 => "host (decode, preprocess and encode on the CPU; the sink uploads the \
                          codes)"
                        .to_string(),
                    _ => format!("host: {n} views, each its engine on the CPU"),
                };
                (intake, Engine::Host(HostViews::new(size, engine)), path)
            }
            Preprocessing::Device(d) => {
                let DevicePreprocessing {
                    mut frames,
                    host,
                    fallback,
                } = *d;
                let preps: Vec<String> = host.iter().flatten().map(HostPrep::name).collect();
                let intake = host
                    .into_iter()
                    .enumerate()
                    .map(|(v, prep)| {
                        let uptake = match prep {
                            Some(prep) => Uptake::Prepared(prep),
                            None => {
                                // Blended on the device after the unpack.
                                frames.attach_layers(v, layers(v));
                                Uptake::AsSent
                            }
                        };
                        (regions[v], layers(v), uptake)
                    })
                    .collect();
                let path = match (n, preps.first()) {
                    (1, None) => "device (the frame is uploaded as it came; no read-back)".into(),
                    (1, Some(name)) => format!(
                        "device after a host stage ({name} on the CPU, its planes uploaded; no \
                         read-back)"
                    ),
                    (_, None) => format!(
                        "device: {n} views, each view's frame uploaded as it came, their stages \
                         and encodes in one submission; no read-back"
                    ),
                    (_, Some(_)) => format!(
                        "device: {n} views after host stages ({}), their stages and encodes in \
                         one submission; no read-back",
                        preps.join("; ")
                    ),
                };
                let engine = Engine::Device {
                    frames: Box::new(frames),
                    fallback,
                    panel: size,
                    views: (0..n).map(|v| (regions[v], layers(v))).collect(),
                    gate: DeviceGate {
                        gate: gate.clone(),
                        clock: clock.clone(),
                        work: Estimate::default(),
                    },
                };
                (intake, engine, path)
            }
        };
        let schedule = Arc::new(DisplaySchedule::new(period_ns, clock.now_ns()));
        let mut budget = ladder
            .map(|ladder| Budget::start(ladder, &mut engine, &regions, schedule.clone(), &*clock));
        *stats.backend.lock().unwrap_or_else(|p| p.into_inner()) = engine.describe();
        *stats.frame_path.lock().unwrap_or_else(|p| p.into_inner()) = path;
        let mut intake = Intake::new(size, intake);
        threads.push(spawn_stage(
            "upload",
            Stage::Upload,
            ingest_rx,
            move |t| upload_tx.send(t),
            context.clone(),
            move |_, _, (view, f): Submission, stats, _| intake.take(view, f, stats),
        )?);
        threads.push(spawn_stage(
            "preprocess",
            Stage::Preprocess,
            upload_rx,
            move |t| dcnn_tx.send(t),
            context.clone(),
            {
                let clock = clock.clone();
                move |id, predicted_ns, f: Vec<ViewFrame>, stats, notes| {
                    let Some(budget) = &mut budget else {
                        return engine.run(id, predicted_ns, f, stats, notes);
                    };
                    budget.select();
                    let _span = tracing::info_span!("level", name = budget.level_name()).entered();
                    let t0 = clock.now_ns();
                    let out = engine.run(id, predicted_ns, f, stats, notes);
                    notes.level = Some(budget.level_index());
                    // Only the stage's own time: a hold for a present is
                    // not the level's cost.
                    let own = clock
                        .now_ns()
                        .saturating_sub(t0)
                        .saturating_sub(notes.waited_ns);
                    budget.observe(own, stats);
                    out
                }
            },
        )?);
        let transfer = panel.transfer.clone();
        let slot_in = slot.clone();
        let (stats_in, stopping_in) = (stats.clone(), stopping.clone());
        let encode = spawn_stage(
            "encode",
            Stage::Encode,
            dcnn_rx,
            // A frame held for its display time is kept when a newer one
            // comes (it may be for a later refresh still).
            move |t| {
                let (by, at_ns) = (t.id, t.ready_ns);
                for old in slot_in.put_keeping_dropping(t, |old| old.hold) {
                    // Once the loop has ended these count as in flight at
                    // the stop (shutdown), not as replaced.
                    if !stopping_in.load(Ordering::SeqCst) {
                        stats_in.record_timeline(
                            &old.marks(),
                            Outcome::Replaced,
                            at_ns,
                            None,
                            Some(by),
                        );
                    }
                }
            },
            context,
            move |id, _, f: Processed, _, _| {
                Some(match f {
                    Processed::Host(f) => {
                        let mut rgba8 = Vec::new();
                        transfer.encode_rgba8(&f, &mut rgba8);
                        PanelFrame::Host(DisplayFrame {
                            id,
                            width: f.width,
                            height: f.height,
                            rgba8,
                        })
                    }
                    // Encoded on the device with the network.
                    Processed::Device(f) => PanelFrame::Device(f),
                })
            },
        )?;
        // Marks the pipeline drained once the encode stage has ended.
        let drained_flag = drained.clone();
        threads.push(
            std::thread::Builder::new()
                .name("drain".into())
                .spawn(move || {
                    let _ = encode.join();
                    drained_flag.store(true, Ordering::SeqCst);
                })?,
        );
        let compositor = Compositor {
            schedule: schedule.clone(),
            tx: ingest_tx,
            stats: stats.clone(),
            clock: clock.clone(),
            width: panel.width,
            height: panel.height,
            views: slots.into(),
            owner: 0,
        };
        Ok(Self {
            panel,
            compositor: Some(compositor),
            slot,
            stats,
            clock,
            schedule,
            gate,
            drained,
            stopping,
            threads,
        })
    }

    /// A handle to submit frames with.
    pub fn compositor(&self) -> Option<Compositor> {
        self.compositor.clone()
    }

    /// Drops the service's own handle: the pipeline drains once every
    /// other handle (the sources') is gone too.
    pub fn close_ingest(&mut self) {
        self.compositor = None;
    }

    pub fn stats(&self) -> &Arc<Stats> {
        &self.stats
    }

    /// Ends presenting: the slot's replacements so far are counted, and
    /// from here on the stages count frames as in flight at stop.
    fn stop_stages(&self) {
        self.stopping.store(true, Ordering::SeqCst);
        // No present is coming: device work waits for none.
        self.gate.done(PresentGate::CLOSED);
        self.stats
            .dropped_at_present
            .store(self.slot.dropped(), Ordering::Relaxed);
    }

    /// Drops the service's handle and joins the stage threads; the sources
    /// must have stopped (dropped their handles) first. Every submitted
    /// frame is then in one bucket of the report ([`Report::accounted`]).
    pub fn shutdown(mut self) -> Report {
        self.stop_stages();
        let counted_at_present = self.stats.dropped_at_present.load(Ordering::Relaxed);
        self.compositor = None;
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
        // Frames the encode stage finished as the loop ended are still in
        // the slot (or replaced one there): in flight, never shown.
        let late = self.slot.dropped() - counted_at_present + self.slot.drain();
        self.stats
            .in_flight_at_stop
            .fetch_add(late, Ordering::Relaxed);
        self.stats.snapshot()
    }
}

#[cfg(test)]
#[path = "service_tests.rs"]
mod tests;
