//! Tests of the service with fake engines and sinks: the fallback on a
//! backend failure, rejection counting, delivery order.

use super::*;
use crate::deadline::{THREAD, join_within, recv_within, wait_until_within, within};
use crate::pipeline::frame::{PixelFormat, RejectReason, SubmittedFrame};
use crate::pipeline::pacing::SystemClock;
use crate::present::{PanelCodes, PresentError, Presented, Sink};
use nedrt_core::Image;
use nedrt_core::preprocess::HostTraffic;
use nedrt_core::preprocess::{Identity, Preprocess, PreprocessError};

/// A backend that works for `ok` frames and then fails like a lost GPU.
#[derive(Debug)]
struct Failing {
    ok: usize,
}

impl Preprocess for Failing {
    fn describe(&self) -> String {
        "failing test backend".into()
    }
    fn run(&mut self, frame: &Image) -> Result<Image, PreprocessError> {
        if self.ok == 0 {
            return Err(PreprocessError::Engine {
                engine: "wgpu".into(),
                reason: "device lost".into(),
            });
        }
        self.ok -= 1;
        // Inverts, so the test can tell which engine ran.
        let mut out = frame.clone();
        out.data_mut().iter_mut().for_each(|v| *v = 1.0 - *v);
        Ok(out)
    }
}

/// Collects presented frames.
#[derive(Debug, Default)]
struct Collect(Vec<DisplayFrame>);

impl Sink for Collect {
    fn describe(&self) -> String {
        "collect".into()
    }
    /// Codes on a device are read back (GPU tests only).
    fn present(&mut self, frame: PanelCodes<'_>) -> Result<Presented, PresentError> {
        let frame = match frame {
            PanelCodes::Host(frame) => frame.clone(),
            PanelCodes::Device(frame) => frame.to_host()?,
        };
        self.0.push(frame);
        Ok(Presented::Shown)
    }
    /// As a GPU sink: the frame's codes go up, nothing comes back.
    fn last_traffic(&self) -> HostTraffic {
        HostTraffic {
            to_device_bytes: self.0.last().map_or(0, |f| f.rgba8.len() as u64),
            uploads: 1,
            ..HostTraffic::default()
        }
    }
}

fn panel() -> PanelConfig {
    PanelConfig {
        width: 4,
        height: 2,
        refresh_hz: 1000.0,
        pixels_per_tan: 1000.0,
        views: Vec::new(),
        transfer: Transfer::from_gamma([1.0, 1.0, 1.0]),
    }
}

fn grey(id: u64, v: u8) -> SubmittedFrame {
    SubmittedFrame {
        id,
        capture_ns: 0,
        width: 4,
        height: 2,
        format: PixelFormat::Rgba8Linear,
        payload: vec![v; 32],
    }
}

/// Submits frames one at a time, waiting for each to be shown.
fn run_one_by_one(
    dcnn: PreprocessStage,
    frames: &[SubmittedFrame],
) -> (Vec<DisplayFrame>, crate::pipeline::stats::Report) {
    run_one_by_one_with(dcnn, frames, |_, _| {})
}

/// As [`run_one_by_one`], calling `before(i, compositor)` before frame `i`.
fn run_one_by_one_with(
    dcnn: PreprocessStage,
    frames: &[SubmittedFrame],
    before: impl Fn(usize, &Compositor) + Send + 'static,
) -> (Vec<DisplayFrame>, crate::pipeline::stats::Report) {
    run_engines_one_by_one(Preprocessing::host(dcnn), frames, before)
}

/// As [`run_one_by_one_with`], on any engines.
fn run_engines_one_by_one(
    engines: Preprocessing,
    frames: &[SubmittedFrame],
    before: impl Fn(usize, &Compositor) + Send + 'static,
) -> (Vec<DisplayFrame>, crate::pipeline::stats::Report) {
    run_laddered_one_by_one(engines, None, frames, before)
}

/// As [`run_engines_one_by_one`], with a frame budget's ladder.
fn run_laddered_one_by_one(
    engines: Preprocessing,
    ladder: Option<crate::pipeline::ladder::Ladder>,
    frames: &[SubmittedFrame],
    before: impl Fn(usize, &Compositor) + Send + 'static,
) -> (Vec<DisplayFrame>, crate::pipeline::stats::Report) {
    let mut service =
        Service::start(panel(), engines, ladder, Arc::new(SystemClock)).expect("start");
    let compositor = service.compositor().expect("open");
    service.close_ingest();
    let feeder = {
        let frames = frames.to_vec();
        let stats = service.stats().clone();
        std::thread::spawn(move || {
            for (i, f) in frames.into_iter().enumerate() {
                before(i, &compositor);
                let _ = compositor.submit(f);
                wait_until_within(
                    THREAD,
                    &format!("frame {i} to be shown or rejected"),
                    || stats.presented.load(Ordering::Relaxed) + stats.rejected_total() > i as u64,
                );
            }
        })
    };
    let (report, sink, service) = present_until_drained(service, Control::default());
    join_within(feeder, THREAD, "the feeder to submit every frame");
    let report_after = within(THREAD, "the service to shut down", move || {
        service.shutdown()
    });
    assert_eq!(report.presented, report_after.presented);
    (sink.0, report)
}

/// Runs the present loop into a [`Collect`] until the pipeline drains, on
/// a thread of its own: a pipeline that never drains (a stage stuck) fails
/// the test instead of hanging it. The limit leaves a feeder's own
/// deadline ([`THREAD`] per frame) the first word.
fn present_until_drained(
    mut service: Service,
    control: Control,
) -> (crate::pipeline::stats::Report, Collect, Service) {
    within(
        2 * THREAD,
        "the present loop to end (the pipeline to drain)",
        move || {
            let mut sink = Collect::default();
            let report = service.present_loop(&mut sink, &control).expect("present");
            (report, sink, service)
        },
    )
}

#[test]
fn a_failing_backend_falls_back_without_losing_the_frame() {
    let fallback: FallbackFactory = Box::new(|| Ok(Box::new(Identity) as Box<dyn Preprocess>));
    let dcnn = PreprocessStage {
        primary: Box::new(Failing { ok: 2 }),
        fallback: Some(fallback),
    };
    let frames: Vec<_> = (0..5).map(|i| grey(i, 51)).collect();
    let (shown, report) = run_one_by_one(dcnn, &frames);
    assert_eq!(
        shown.len(),
        5,
        "the failing frame is re-run on the fallback"
    );
    // 51/255 = 0.2: inverted (0.8 → 204) by the primary, unchanged after the fallback.
    let codes: Vec<u8> = shown.iter().map(|f| f.rgba8[0]).collect();
    assert_eq!(codes, vec![204, 204, 51, 51, 51]);
    assert_eq!(report.dcnn_failures, 1);
    assert!(report.backend.starts_with("none"), "{}", report.backend);
}

#[test]
fn without_a_fallback_factory_the_panel_gets_the_unprocessed_frame() {
    let dcnn = PreprocessStage {
        primary: Box::new(Failing { ok: 0 }),
        fallback: None,
    };
    let (shown, report) = run_one_by_one(dcnn, &[grey(0, 100)]);
    assert_eq!(shown[0].rgba8[..3], [100, 100, 100]);
    assert_eq!(report.dcnn_failures, 1);
}

#[test]
fn rejected_frames_are_counted_and_the_rest_delivered_in_order() {
    let dcnn = PreprocessStage {
        primary: Box::new(Identity),
        fallback: None,
    };
    let mut frames = vec![grey(0, 10), grey(1, 20)];
    let mut wrong = grey(2, 30);
    wrong.width = 3;
    frames.push(wrong);
    let mut short = grey(3, 40);
    short.payload.pop();
    frames.push(short);
    frames.push(grey(4, 50));
    let (shown, report) = run_one_by_one(dcnn, &frames);
    assert_eq!(
        shown.iter().map(|f| f.id).collect::<Vec<_>>(),
        vec![0, 1, 4]
    );
    assert_eq!(report.submitted, 5);
    let count = |r: RejectReason| {
        report
            .rejected
            .iter()
            .find(|(n, _)| n == r.name())
            .map_or(0, |p| p.1)
    };
    assert_eq!(count(RejectReason::WrongSize), 1);
    assert_eq!(count(RejectReason::Truncated), 1);
    assert_eq!(
        report
            .stages
            .iter()
            .find(|s| s.stage == "end-to-end")
            .map(|s| s.count),
        Some(3)
    );
}

/// A backend that holds each frame until the test lets it go: it says on
/// `entered` that it has taken a frame, then waits on `release` (a message
/// lets one frame through; the sender dropped lets every later one
/// through).
#[derive(Debug)]
struct Gate {
    entered: std::sync::mpsc::Sender<()>,
    release: std::sync::mpsc::Receiver<()>,
}

impl Preprocess for Gate {
    fn describe(&self) -> String {
        "gated test backend".into()
    }
    fn run(&mut self, frame: &Image) -> Result<Image, PreprocessError> {
        use std::sync::mpsc::RecvTimeoutError;
        let _ = self.entered.send(());
        match self.release.recv_timeout(THREAD) {
            Ok(()) | Err(RecvTimeoutError::Disconnected) => Ok(frame.clone()),
            Err(RecvTimeoutError::Timeout) => {
                panic!("the test never released the gated frame within {THREAD:?}")
            }
        }
    }
}

#[test]
fn frames_inside_the_stages_at_a_stop_are_counted_in_flight_not_lost() {
    let (entered_tx, entered) = std::sync::mpsc::channel();
    let (release, release_rx) = std::sync::mpsc::channel();
    let dcnn = PreprocessStage {
        primary: Box::new(Gate {
            entered: entered_tx,
            release: release_rx,
        }),
        fallback: None,
    };
    let mut service = Service::start(
        panel(),
        Preprocessing::host(dcnn),
        None,
        Arc::new(SystemClock),
    )
    .expect("start");
    let compositor = service.compositor().expect("open");
    service.close_ingest();
    // One frame held inside the D-CNN, the next ones queued behind it (a
    // queue keeps only the newest, so each waits for the one before).
    // Frame 0 is waited for until the gated stage has taken it: its upload
    // alone does not say so, and under load a frame submitted meanwhile
    // replaces it in the queue before the stage gets there (the test then
    // waited for a frame the stage never ran: issue 39).
    compositor.submit(grey(0, 9)).expect("valid");
    recv_within(&entered, THREAD, "the D-CNN stage to take frame 0");
    compositor.submit(grey(1, 9)).expect("valid");
    wait_until_within(THREAD, "frame 1's upload", || {
        service.stats().histogram(Stage::Upload).count() >= 2
    });
    for id in 2..4 {
        compositor.submit(grey(id, 9)).expect("valid");
    }
    let control = Control::default();
    control.stop.store(true, Ordering::Relaxed);
    let mut sink = Collect::default();
    // Returns at once: the loop looks at `stop` before anything else.
    let mid = service.present_loop(&mut sink, &control).expect("present");
    assert_eq!(mid.presented, 0);
    assert!(
        mid.accounted() < mid.submitted,
        "frames still inside: {mid:?}"
    );
    drop(compositor);
    // The held frame finishes its D-CNN run; the stages, stopped, count
    // every later frame in flight instead of running it.
    drop(release);
    let report = within(THREAD, "the service to shut down", move || {
        service.shutdown()
    });
    assert_eq!(report.submitted, 4);
    assert_eq!(report.accounted(), 4, "{}", report.table());
    assert!(report.in_flight_at_stop >= 1, "{}", report.table());
    assert!(sink.0.is_empty());
}

/// An engine on a device that uploads the planar f32 frame and reads the
/// display image back, as the wgpu backend does today.
#[derive(Debug)]
struct OnDevice;

impl Preprocess for OnDevice {
    fn describe(&self) -> String {
        "device test backend".into()
    }
    fn run(&mut self, frame: &Image) -> Result<Image, PreprocessError> {
        Ok(frame.clone())
    }
    fn last_traffic(&self) -> HostTraffic {
        // 4×2 pixels, 3 planes of f32 each way.
        HostTraffic {
            to_device_bytes: 96,
            uploads: 1,
            to_host_bytes: 96,
            read_backs: 1,
        }
    }
}

#[test]
fn the_report_counts_host_traffic_per_frame_by_stage() {
    let frames: Vec<_> = (0..3).map(|i| grey(i, 77)).collect();
    let dcnn = PreprocessStage {
        primary: Box::new(OnDevice),
        fallback: None,
    };
    let (_, report) = run_one_by_one(dcnn, &frames);
    let per_frame = report.traffic_per_frame();
    assert_eq!(per_frame.to_device_bytes, 96.0 + 32.0);
    assert_eq!(per_frame.to_host_bytes, 96.0);
    assert_eq!(per_frame.read_backs, 1.0);
    assert_eq!(per_frame.uploads, 2.0);
    assert_eq!(
        report.traffic.iter().map(|t| t.frames).collect::<Vec<_>>(),
        [3, 3]
    );
    assert!(
        report.table().contains(
            "host traffic per presented frame: 0.0 MB to the device in 2.00 uploads, 0.0 MB back, \
             1.00 read-backs"
        ),
        "{}",
        report.table()
    );
    // A host engine moves nothing: only the sink's upload is left.
    let dcnn = PreprocessStage {
        primary: Box::new(Identity),
        fallback: None,
    };
    let (_, report) = run_one_by_one(dcnn, &frames);
    let per_frame = report.traffic_per_frame();
    assert_eq!(per_frame.to_device_bytes, 32.0);
    assert_eq!((per_frame.to_host_bytes, per_frame.read_backs), (0.0, 0.0));
}

#[test]
fn quad_layers_are_blended_over_every_frame_until_their_owner_removes_them() {
    use crate::compose::{Placement, QuadLayer};
    let dcnn = PreprocessStage {
        primary: Box::new(Identity),
        fallback: None,
    };
    // An opaque quad of 0.8 on pixels (1, 0) and (2, 0) from client 1; a
    // half-transparent one of premultiplied 0.3 on (0, 1) and (1, 1) from
    // client 2: 0.3 + 0.5·0.2 = 0.4 (code 102 on this linear panel).
    let layer = |layer, x, y, c: f32, a: f32| QuadLayer {
        layer,
        z: 0,
        placement: Placement::Pixels { x, y },
        width: 2,
        height: 1,
        rgba: [c, c, c, a].repeat(2),
    };
    let frames: Vec<_> = (0..3).map(|i| grey(i, 51)).collect();
    let (shown, report) = run_one_by_one_with(dcnn, &frames, move |i, compositor| {
        let (one, two) = (compositor.for_owner(1), compositor.for_owner(2));
        match i {
            0 => {
                one.submit_layer(layer(7, 1, 0, 0.8, 1.0)).expect("inside");
                two.submit_layer(layer(7, 0, 1, 0.3, 0.5)).expect("inside");
                // Outside the 4×2 view: refused, counted, the others kept.
                assert!(two.submit_layer(layer(8, 3, 1, 0.1, 0.5)).is_err());
            }
            // Client 1 leaves: its layers go with it.
            1 => assert_eq!(one.remove_owner_layers(), 1),
            _ => assert!(two.remove_layer(7)),
        }
    });
    let row = |f: &DisplayFrame, y: usize| -> Vec<u8> {
        (0..4).map(|x| f.rgba8[4 * (4 * y + x)]).collect()
    };
    assert_eq!(row(&shown[0], 0), vec![51, 204, 204, 51]);
    assert_eq!(row(&shown[0], 1), vec![102, 102, 51, 51]);
    assert_eq!(row(&shown[1], 0), vec![51, 51, 51, 51]);
    assert_eq!(row(&shown[1], 1), vec![102, 102, 51, 51]);
    assert_eq!(row(&shown[2], 1), vec![51, 51, 51, 51]);
    assert_eq!((report.layers_set, report.layers_refused), (2, 1));
    assert_eq!(report.frames_with_layers, 2);
}

/// Two views side by side on the 4×2 panel through `engines`: a frame for
/// the left eye, one for the right under a quad of its own, two refused
/// submissions, and a panel-sized frame for both. The frames shown and the
/// report.
fn two_views_scenario(
    engines: Preprocessing,
) -> (Vec<DisplayFrame>, crate::pipeline::stats::Report) {
    use crate::compose::{Placement, QuadLayer, ViewRegion};
    let mut config = panel();
    config.views = ViewRegion::side_by_side(4, 2).to_vec();
    let mut service = Service::start(config, engines, None, Arc::new(SystemClock)).expect("start");
    let compositor = service.compositor().expect("open");
    service.close_ingest();
    let stats = service.stats().clone();
    let view_frame = |id, v: u8| SubmittedFrame {
        id,
        capture_ns: 0,
        width: 2,
        height: 2,
        format: PixelFormat::Rgba8Linear,
        payload: vec![v; 16],
    };
    let feeder = std::thread::spawn(move || {
        let wait_for = |n: u64| {
            wait_until_within(
                THREAD,
                &format!("frame {n} to be shown or rejected"),
                || stats.presented.load(Ordering::Relaxed) + stats.rejected_total() >= n,
            );
        };
        // Left 0.2; the right eye has had no frame yet: black.
        compositor.submit_view(0, view_frame(1, 51)).expect("left");
        wait_for(1);
        // Right 0.4, under a quad of its own (opaque 0.6 on its pixel (1, 0)).
        compositor
            .submit_layer_on(
                1,
                QuadLayer {
                    layer: 1,
                    z: 0,
                    placement: Placement::Pixels { x: 1, y: 0 },
                    width: 1,
                    height: 1,
                    rgba: vec![0.6, 0.6, 0.6, 1.0],
                },
            )
            .expect("inside view 1");
        compositor
            .submit_view(1, view_frame(2, 102))
            .expect("right");
        wait_for(2);
        // A frame of view 1's size is refused for a view that is not there,
        // and a panel-sized frame for one view.
        assert!(compositor.submit_view(2, view_frame(3, 0)).is_err());
        assert!(compositor.submit_view(0, grey(4, 0)).is_err());
        // A panel-sized frame feeds both views.
        compositor.submit(grey(5, 153)).expect("both");
        wait_for(5);
    });
    let (_, sink, service) = present_until_drained(service, Control::default());
    join_within(feeder, THREAD, "the feeder to submit every frame");
    let report = within(THREAD, "the service to shut down", move || {
        service.shutdown()
    });
    (sink.0, report)
}

#[test]
fn two_views_each_get_their_frames_layers_and_engine_on_one_panel() {
    // View 0 shows its frames as they are; view 1 inverts (another design).
    let stages = vec![
        PreprocessStage {
            primary: Box::new(Identity),
            fallback: None,
        },
        PreprocessStage {
            primary: Box::new(Failing { ok: usize::MAX }),
            fallback: None,
        },
    ];
    let (shown, report) = two_views_scenario(Preprocessing::Host(stages));
    assert_eq!(report.presented, 3);
    assert_eq!(report.rejected_total(), 2);
    let rows = |f: &DisplayFrame| -> Vec<Vec<u8>> {
        (0..2)
            .map(|y| (0..4).map(|x| f.rgba8[4 * (4 * y + x)]).collect())
            .collect()
    };
    let shown: Vec<_> = shown.iter().map(rows).collect();
    // Frame 1: the left eye's 0.2; no frame for the right yet: black (its
    // engine is not run on nothing).
    assert_eq!(shown[0], vec![vec![51, 51, 0, 0], vec![51, 51, 0, 0]]);
    // Frame 2: the right eye's 0.4 with its quad's 0.6, inverted by its own
    // engine; the left eye keeps its frame.
    assert_eq!(
        shown[1],
        vec![vec![51, 51, 153, 102], vec![51, 51, 153, 153]]
    );
    // Frame 5: one panel-sized frame of 0.6 for both eyes.
    assert_eq!(
        shown[2],
        vec![vec![153, 153, 102, 102], vec![153, 153, 102, 102]]
    );
    assert_eq!(report.view_stages.len(), 2);
    // Frame 2 showed the left eye from its last frame (not waited for).
    assert_eq!(report.view_frames_reused, 1);
    // The left engine ran for frames 1 and 5 only (frame 2 left it as it was).
    assert_eq!(report.view_stages[0].count, 2);
    assert_eq!(report.view_stages[1].count, 2);
}

#[test]
fn one_view_smaller_than_the_panel_takes_frames_of_its_own_size() {
    use crate::compose::ViewRegion;
    let mut config = panel();
    config.views = vec![ViewRegion {
        x: 1,
        y: 0,
        width: 2,
        height: 2,
    }];
    let stages = vec![PreprocessStage {
        primary: Box::new(Identity),
        fallback: None,
    }];
    let service = Service::start(
        config,
        Preprocessing::Host(stages),
        None,
        Arc::new(SystemClock),
    )
    .expect("start");
    let compositor = service.compositor().expect("open");
    let view_frame = SubmittedFrame {
        id: 1,
        capture_ns: 0,
        width: 2,
        height: 2,
        format: PixelFormat::Rgba8Linear,
        payload: vec![51; 16],
    };
    assert!(compositor.submit_view(0, view_frame).is_ok());
    assert!(
        compositor.submit_view(0, grey(2, 51)).is_err(),
        "a panel-sized frame for the view"
    );
    assert!(
        compositor.submit(grey(3, 51)).is_ok(),
        "a panel-sized frame for every view"
    );
    // Regions outside the panel are refused at start.
    let mut bad = panel();
    bad.views = vec![ViewRegion {
        x: 3,
        y: 0,
        width: 2,
        height: 2,
    }];
    let stages = vec![PreprocessStage {
        primary: Box::new(Identity),
        fallback: None,
    }];
    assert!(
        Service::start(
            bad,
            Preprocessing::Host(stages),
            None,
            Arc::new(SystemClock)
        )
        .is_err()
    );
}

mod needs_gpu {
    use super::*;
    use crate::compose::ViewRegion;
    use crate::pipeline::device_frames::{DeviceFrames, DeviceView};
    use crate::pipeline::test_stage::Stretch;

    /// The host twin of [`Stretch`]: 1.4 · in − 0.2, clamped.
    #[derive(Debug)]
    struct StretchOnHost;

    impl Preprocess for StretchOnHost {
        fn describe(&self) -> String {
            "stretch on the host".into()
        }
        fn run(&mut self, frame: &Image) -> Result<Image, PreprocessError> {
            let mut out = frame.clone();
            out.data_mut()
                .iter_mut()
                .for_each(|v| *v = (1.4 * *v - 0.2).clamp(0.0, 1.0));
            Ok(out)
        }
    }

    fn on_host(p: impl Preprocess + 'static) -> PreprocessStage {
        PreprocessStage {
            primary: Box::new(p),
            fallback: None,
        }
    }

    /// The left eye as it comes, the right stretched, on the device; each
    /// view's host twin its fallback. `poison`: the right eye's stage
    /// overflows (a network gone bad), so the device path fails there.
    fn on_device(device: &wgpu::Device, queue: &wgpu::Queue, poison: bool) -> Preprocessing {
        let [left, right] = ViewRegion::side_by_side(4, 2);
        let views = vec![
            DeviceView {
                region: left,
                stage: None,
            },
            DeviceView {
                region: right,
                stage: Some(Box::new(Stretch::with_poison(device, poison))),
            },
        ];
        let frames =
            DeviceFrames::new(device, queue, (4, 2), views, &panel().transfer).expect("frames");
        let identity: FallbackFactory = Box::new(|| Ok(Box::new(Identity)));
        let stretch: FallbackFactory = Box::new(|| Ok(Box::new(StretchOnHost)));
        Preprocessing::Device(Box::new(DevicePreprocessing {
            frames,
            host: vec![None, None],
            fallback: vec![Some(identity), Some(stretch)],
        }))
    }

    fn worst(a: &[DisplayFrame], b: &[DisplayFrame]) -> u8 {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .flat_map(|(x, y)| x.rgba8.iter().zip(&y.rgba8))
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap_or(0)
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_device_engine_shows_two_views_as_the_host_engine_does() {
        let (device, queue) = nedrt_gpu::test_device(false);
        let host = Preprocessing::Host(vec![on_host(Identity), on_host(StretchOnHost)]);
        let (want, host_report) = two_views_scenario(host);
        let (got, report) = two_views_scenario(on_device(&device, &queue, false));
        assert_eq!((report.presented, report.rejected_total()), (3, 2));
        assert!(
            worst(&got, &want) <= 1,
            "codes differ by {}: {:?} vs {:?}",
            worst(&got, &want),
            got.iter().map(|f| &f.rgba8).collect::<Vec<_>>(),
            want.iter().map(|f| &f.rgba8).collect::<Vec<_>>()
        );
        assert!(
            report.frame_path.starts_with("device: 2 views"),
            "{}",
            report.frame_path
        );
        assert_eq!(report.dcnn_failures, 0);
        // The right eye's quad was blended on the device, on its one frame
        // under it; the left eye was shown from its last frame once.
        assert_eq!(report.frames_with_layers, host_report.frames_with_layers);
        assert_eq!(report.view_frames_reused, host_report.view_frames_reused);
        // Each eye's frame went up as the client sent it (RGBA8): 16 bytes
        // a view, and nothing came back but counts and timestamps.
        let up = report
            .traffic
            .iter()
            .find(|t| t.stage == "preprocess")
            .expect("preprocess traffic");
        assert_eq!(up.total.read_backs, 0);
        assert!(up.total.to_device_bytes >= 4 * 16, "{up:?}");
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn a_host_stage_that_fails_is_switched_off_and_frames_go_up_decoded() {
        let (device, queue) = nedrt_gpu::test_device(false);
        let frames =
            DeviceFrames::single(&device, &queue, (4, 2), &panel().transfer, None).expect("frames");
        // Inverts one frame, then fails as an engine.
        let prep = HostPrep(Box::new(Failing { ok: 1 }));
        let engines = Preprocessing::Device(Box::new(DevicePreprocessing::single(
            frames,
            Some(prep),
            None,
        )));
        let (shown, report) = run_engines_one_by_one(
            engines,
            &[grey(1, 51), grey(2, 102), grey(3, 153)],
            |_, _| {},
        );
        let codes: Vec<u8> = shown.iter().map(|f| f.rgba8[0]).collect();
        // The first through the host stage (inverted), the rest as decoded.
        assert_eq!(codes, [204, 102, 153]);
        assert_eq!((report.presented, report.dcnn_failures), (3, 1));
        assert!(
            report
                .frame_path
                .starts_with("device, without its host stage (failing test backend failed)"),
            "{}",
            report.frame_path
        );
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn two_views_whose_device_fails_go_on_with_each_views_fallback_without_losing_a_frame() {
        let (device, queue) = nedrt_gpu::test_device(false);
        let host = Preprocessing::Host(vec![on_host(Identity), on_host(StretchOnHost)]);
        let (want, _) = two_views_scenario(host);
        let (got, report) = two_views_scenario(on_device(&device, &queue, true));
        // The right eye's first frame fails on the device; it and every
        // later frame are shown by the views' host engines.
        assert_eq!((report.presented, report.rejected_total()), (3, 2));
        assert_eq!(report.dcnn_failures, 1);
        assert!(
            report
                .frame_path
                .starts_with("host (after the device path failed)"),
            "{}",
            report.frame_path
        );
        assert!(
            worst(&got, &want) <= 1,
            "codes differ by {}: {:?} vs {:?}",
            worst(&got, &want),
            got.iter().map(|f| &f.rgba8).collect::<Vec<_>>(),
            want.iter().map(|f| &f.rgba8).collect::<Vec<_>>()
        );
    }
}

/// A service on the host with no preprocessing, and the one handle that
/// submits to it (the pipeline drains once it is dropped).
fn identity_service() -> (Service, Compositor) {
    let stage = PreprocessStage {
        primary: Box::new(Identity),
        fallback: None,
    };
    let mut service = Service::start(
        panel(),
        Preprocessing::host(stage),
        None,
        Arc::new(SystemClock),
    )
    .expect("start");
    let compositor = service.compositor().expect("open");
    service.close_ingest();
    (service, compositor)
}

/// One frame submitted 60 ms ahead of the refresh it names: with the
/// display time a client gives (`submit_at`), it waits for that refresh;
/// made for that refresh in process (`submit_for`, the pattern and folder
/// sources), it is shown as soon as it is ready, early; with none
/// (`submit`), it is shown when ready, never before its prediction.
/// 60 refreshes at 1 kHz: a frame shown at once is many refreshes early on
/// any machine, and one held is never early.
#[test]
fn a_frame_with_a_client_display_time_is_not_shown_before_it() {
    for how in ["submit_at", "submit_for", "submit"] {
        let (service, compositor) = identity_service();
        let display_ns = crate::pipeline::pacing::monotonic_ns() + 60_000_000;
        let submitted = match how {
            "submit_at" => compositor.submit_at(None, grey(0, 10), Some(display_ns)),
            "submit_for" => compositor.submit_for(grey(0, 10), Some(display_ns)),
            _ => compositor.submit(grey(0, 10)),
        };
        submitted.expect("submit");
        drop(compositor);
        let (report, sink, _service) = present_until_drained(service, Control::default());
        assert_eq!((report.presented, sink.0.len()), (1, 1), "{how}");
        let f = &report.frames[0];
        let shown_at_or_after = f.shown_ms.expect("shown") >= f.predicted_ms - 0.5;
        let c = report
            .clients
            .iter()
            .find(|c| c.client == 0)
            .unwrap_or_else(|| panic!("no in-process client: {:?}", report.clients));
        if how == "submit_for" {
            // Made for a refresh in process: shown when ready, early.
            assert_eq!(c.early, 1, "{how}: {c:?}");
            continue;
        }
        assert_eq!(c.early, 0, "{how}: {c:?}");
        assert!(shown_at_or_after, "{how}: {f:?}");
        if how != "submit" {
            // Held: taken no sooner than a refresh (1 ms) and a half
            // before the refresh it was made for, 60 ms on.
            assert!(f.predicted_ms > f.submitted_ms + 30.0, "{how}: {f:?}");
            assert!(
                f.taken_ms.expect("taken") >= f.predicted_ms - 1.5,
                "{how}: {f:?}"
            );
        }
    }
}

/// Every frame that reaches the panel's slot leaves its timeline: shown,
/// or replaced by the newer frame that took its refresh; each with its
/// stages in order on the service's clock. Two frames for one display time
/// 300 ms on: the first waits for it in the slot, and the second, ready
/// before it too, is the one shown.
#[test]
fn each_frame_at_the_panel_leaves_its_timeline_shown_or_replaced() {
    use crate::pipeline::stats::Outcome;
    let (service, compositor) = identity_service();
    let stats = service.stats().clone();
    let display_ns = crate::pipeline::pacing::monotonic_ns() + 300_000_000;
    let feeder = std::thread::spawn(move || {
        for (i, v) in [10, 20].into_iter().enumerate() {
            compositor
                .submit_at(None, grey(i as u64, v), Some(display_ns))
                .expect("submit");
            // In the slot before the next comes (the ingest queue holds one).
            wait_until_within(THREAD, &format!("frame {i} to be encoded"), || {
                stats.histogram(Stage::Encode).count() > i as u64
            });
        }
    });
    let (report, sink, service) = present_until_drained(service, Control::default());
    join_within(feeder, THREAD, "the feeder to submit both frames");
    drop(service);
    assert_eq!(sink.0.len(), 1);
    assert_eq!((report.presented, report.dropped_at_present), (1, 1));
    let f = &report.frames;
    let outcomes: Vec<(u64, Outcome, Option<u64>)> =
        f.iter().map(|t| (t.id, t.outcome, t.replaced_by)).collect();
    assert_eq!(
        outcomes,
        [(0, Outcome::Replaced, Some(1)), (1, Outcome::Shown, None)]
    );
    for t in f {
        let [upload, preprocess, encode] = t.stages_ms;
        let order = [
            t.submitted_ms,
            upload[0],
            upload[1],
            preprocess[0],
            preprocess[1],
            encode[0],
            encode[1],
        ];
        assert!(order.windows(2).all(|w| w[0] <= w[1]), "{t:?}");
        assert_eq!(t.ready_ms, encode[1], "{t:?}");
        let after = t.replaced_ms.or(t.taken_ms).expect("taken or replaced");
        assert!(after >= t.ready_ms, "{t:?}");
        // The display time the client gave, for both.
        assert_eq!(t.predicted_ms, f[0].predicted_ms, "{t:?}");
        assert!(t.predicted_ms > t.submitted_ms + 200.0, "{t:?}");
    }
    let shown = &f[1];
    let (taken, on) = (shown.taken_ms.unwrap(), shown.shown_ms.expect("shown"));
    // Held for its display time: taken at most a refresh (1 ms) and a
    // half before it, on the panel at or after it.
    assert!(
        taken >= shown.predicted_ms - 1.5 && on >= shown.predicted_ms - 0.5,
        "{shown:?}"
    );
}

/// A ladder's levels in the service (issue 54): each level measured at
/// start-up, each frame run at the level the budget picks and counted
/// there, its level in its timeline, and the report's quality delivered.
#[test]
fn a_ladder_runs_each_frame_at_the_budgets_level_and_reports_it() {
    use crate::pipeline::ladder::{HostLevels, Ladder, Level, Selection};
    let selection = Selection::default();
    // Two levels, both far inside a 1 ms refresh: the better one runs.
    let levels: Vec<Box<dyn Preprocess>> = vec![Box::new(Identity), Box::new(Failing { ok: 1000 })];
    let stage = PreprocessStage {
        primary: Box::new(HostLevels::new(levels, selection.clone())),
        fallback: None,
    };
    let level = |name: &str, quality_db| Level {
        name: name.into(),
        quality_db: Some(quality_db),
        reference_ns: 0,
    };
    let ladder = Ladder {
        levels: vec![level("none", 20.0), level("invert", 21.0)],
        selection,
    };
    let frames: Vec<SubmittedFrame> = (0..6).map(|i| grey(i, 40)).collect();
    let (shown, report) =
        run_laddered_one_by_one(Preprocessing::host(stage), Some(ladder), &frames, |_, _| {});
    assert_eq!(shown.len(), 6);
    let budget = report.frame_budget.clone().expect("the budget's report");
    // Both measured at start-up; one may be left out (no better than a
    // faster one), by how the two trivial levels timed here.
    assert_eq!(budget.levels.len() + budget.dropped.len(), 2, "{budget:?}");
    assert!(
        budget.levels.iter().all(|l| l.reference_ms > 0.0),
        "measured: {budget:?}"
    );
    let frames: u64 = budget.levels.iter().map(|l| l.frames).sum();
    assert_eq!(frames, 6, "every frame ran a level: {budget:?}");
    // Each frame's timeline names its level, and shows what that level
    // makes of it: the frame (40) or its inverse (255 − 40).
    for (timing, f) in report.frames.iter().zip(&shown) {
        let level = &budget.levels[usize::from(timing.level.expect("a level"))];
        let want = if level.name == "invert" { 215 } else { 40 };
        assert_eq!(f.rgba8[0], want, "{}", level.name);
    }
    let q = budget
        .quality_delivered_db
        .expect("every level has a quality");
    assert!((20.0..=21.0).contains(&q), "{q}");
    assert!(
        report.table().contains("frame budget: "),
        "{}",
        report.table()
    );
}
