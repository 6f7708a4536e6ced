//! The device engine against its host twins: one view and two.

use super::*;
use crate::pipeline::frame::{PixelFormat, SubmittedFrame, decode, planar_payload};
use crate::pipeline::test_stage::Stretch;
use crate::present::headless::HeadlessSink;
use crate::present::{PanelCodes, Presented, Sink};
use nedrt_gpu::test_device;

fn client(generation: u64, f: SubmittedFrame) -> ViewFrame {
    ViewFrame {
        generation,
        content: ViewContent::Client(Arc::new(f)),
    }
}

fn planar(generation: u64, im: Image) -> ViewFrame {
    ViewFrame {
        generation,
        content: ViewContent::Planar(Arc::new(im)),
    }
}

/// A `width`×`height` frame in `format` with every 8-bit code.
fn client_frame(id: u64, width: usize, height: usize, format: PixelFormat) -> SubmittedFrame {
    let n = width * height;
    let payload = match format {
        PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb => (0..4 * n)
            .map(|i| ((i * 37 + id as usize) % 256) as u8)
            .collect(),
        PixelFormat::Rgb32fPlanar => {
            let data: Vec<f32> = (0..3 * n).map(|i| (i * 7 % 1001) as f32 / 1000.0).collect();
            planar_payload(&Image::rgb(width, height, data))
        }
    };
    SubmittedFrame {
        id,
        capture_ns: 0,
        width,
        height,
        format,
        payload,
    }
}

mod needs_gpu {
    use super::*;

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_panel_shows_what_the_cpu_transfer_gives_for_the_device_display_image() {
        let (device, queue) = test_device(false);
        // 37 wide: the codes' rows are padded to the copy pitch.
        let (w, h) = (37usize, 21usize);
        let transfer = Transfer::from_gamma([2.2, 1.0, 2.4]);
        let mut sink =
            HeadlessSink::new(&device, &queue, "test".into(), w as u32, h as u32).expect("sink");
        for with_stage in [false, true] {
            let stage: Option<Box<dyn DeviceStage>> =
                with_stage.then(|| Box::new(Stretch::new(&device)) as _);
            let mut frames =
                DeviceFrames::single(&device, &queue, (w, h), &transfer, stage).expect("frames");
            let stamps = device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
            // The stage's pair and the frame's, with or without a stage.
            let timed = if stamps { 32 } else { 0 };
            let formats = [
                PixelFormat::Rgba8Linear,
                PixelFormat::Rgba8Srgb,
                PixelFormat::Rgb32fPlanar,
            ];
            let mut generation = 0;
            for (id, format) in formats.into_iter().enumerate() {
                let sent = client_frame(id as u64, w, h, format);
                let want_up = sent.payload.len() as u64;
                for input in [planar(0, decode(&sent)), client(0, sent.clone())] {
                    generation += 1;
                    let input = ViewFrame {
                        generation,
                        ..input
                    };
                    let planar = matches!(input.content, ViewContent::Planar(_));
                    let (frame, traffic) = frames.run(id as u64, &[input]).expect("runs");
                    // One upload of the frame as it came (or of the host's
                    // planes), nothing back.
                    let up = if planar {
                        (3 * 4 * w * h) as u64
                    } else {
                        want_up
                    };
                    assert_eq!(
                        traffic,
                        HostTraffic {
                            to_device_bytes: up,
                            uploads: 1,
                            // The non-finite count, and the timestamps
                            // where the device has them, back with the
                            // fence.
                            to_host_bytes: 4 + timed,
                            read_backs: 0
                        },
                        "{format:?}"
                    );
                    assert_eq!(frames.last_view_ns()[0].is_some(), with_stage && stamps);
                    assert_eq!(frames.last_frame_gpu_ns().is_some(), stamps);
                    assert_eq!(
                        sink.present(PanelCodes::Device(&frame)).expect("shown"),
                        Presented::Shown
                    );
                    assert_eq!(sink.last_traffic(), HostTraffic::default());
                    // Only the test reads back: the panel, and the display
                    // image it was encoded from.
                    let shown = sink.read_back().expect("panel");
                    let display = frames.read_display(0).expect("display");
                    if !with_stage {
                        // The device's unpack is the host decode, bit for bit.
                        assert!(display.data() == decode(&sent).data(), "{format:?}");
                    } else {
                        let clipped = display.data().iter().filter(|v| !(0.0..=1.0).contains(*v));
                        assert!(clipped.count() > 0, "the stage's output reaches the clamp");
                    }
                    let mut cpu = Vec::new();
                    transfer.encode_rgba8(&display, &mut cpu);
                    assert!(
                        shown == cpu,
                        "{format:?} stage {with_stage} planar {planar}"
                    );
                }
            }
        }
    }

    /// The frame budget's levels on the device: the level of no work
    /// records nothing and shows the frame; another level shows its
    /// output; a frame not changed since it ran keeps the output it got.
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn a_ladder_at_its_level_of_no_work_shows_the_frame_and_records_nothing() {
        use crate::pipeline::ladder::{DeviceLevels, Selection, Unprocessed};
        let (device, queue) = test_device(false);
        let (w, h) = (19usize, 11usize);
        let transfer = Transfer::from_gamma([2.2; 3]);
        let selection = Selection::default();
        let levels: Vec<Box<dyn DeviceStage>> =
            vec![Box::new(Unprocessed), Box::new(Stretch::new(&device))];
        let stage = Box::new(DeviceLevels::new(levels, selection.clone()));
        let mut frames =
            DeviceFrames::single(&device, &queue, (w, h), &transfer, Some(stage)).expect("frames");
        let mut sink =
            HeadlessSink::new(&device, &queue, "test".into(), w as u32, h as u32).expect("sink");
        let sent = client_frame(0, w, h, PixelFormat::Rgba8Linear);
        let plain = decode(&sent);
        let mut stretched = plain.clone();
        stretched
            .data_mut()
            .iter_mut()
            .for_each(|v| *v = 1.4 * *v - 0.2);
        let codes = |im: &Image| {
            let mut c = Vec::new();
            transfer.encode_rgba8(im, &mut c);
            c
        };
        let mut show = |generation: u64, level: usize| {
            selection.set(level);
            let (frame, _) = frames
                .run(generation, &[client(generation, sent.clone())])
                .expect("runs");
            let timed = frames.last_view_ns()[0].is_some();
            sink.present(PanelCodes::Device(&frame)).expect("shown");
            (sink.read_back().expect("panel"), timed)
        };
        let stamps = device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        let (shown, timed) = show(1, 0);
        assert!(shown == codes(&plain), "level 0 shows the frame");
        assert!(!timed, "level 0 records no stage");
        let (shown, timed) = show(2, 1);
        assert!(shown == codes(&stretched), "level 1 shows its output");
        assert_eq!(timed, stamps);
        // The same frame again at level 0: not run again, its output kept.
        let (shown, _) = show(2, 0);
        assert!(
            shown == codes(&stretched),
            "an unchanged frame keeps its output"
        );
        let (shown, _) = show(3, 0);
        assert!(shown == codes(&plain), "a new frame at level 0");
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn codes_buffers_are_reused_only_once_no_frame_holds_them() {
        let (device, queue) = test_device(false);
        let transfer = Transfer::from_gamma([2.2; 3]);
        let mut frames =
            DeviceFrames::single(&device, &queue, (8, 4), &transfer, None).expect("frames");
        let input = |g| [client(g, client_frame(0, 8, 4, PixelFormat::Rgba8Linear))];
        let (a, _) = frames.run(0, &input(1)).expect("runs");
        let (b, _) = frames.run(1, &input(2)).expect("runs");
        // Both held: two buffers.
        assert!(!Arc::ptr_eq(&a.codes, &b.codes));
        drop(a);
        let (c, _) = frames.run(2, &input(3)).expect("runs");
        assert!(!Arc::ptr_eq(&b.codes, &c.codes));
        assert_eq!(frames.codes.len(), 2);
        // A stage whose output is not finite fails the frame, as the
        // host path's engine failure, instead of showing black or white.
        let stage: Box<dyn DeviceStage> = Box::new(Stretch::with_poison(&device, true));
        let mut poisoned =
            DeviceFrames::single(&device, &queue, (8, 4), &transfer, Some(stage)).expect("frames");
        let e = poisoned
            .run(4, &input(1))
            .expect_err("non-finite")
            .to_string();
        assert!(e.contains("1 pixels that are not finite"), "{e}");
        // A frame of another size is refused, not drawn.
        let wrong = [client(4, client_frame(3, 4, 4, PixelFormat::Rgba8Linear))];
        let e = frames.run(3, &wrong).expect_err("wrong size").to_string();
        assert!(
            e.contains("a 4×4 frame of 3 planes for view 0 of 8×4"),
            "{e}"
        );
    }

    /// The uploads go through staging memory kept from frame to frame: a
    /// frame whose bytes do not fill whole words of its buffer is refused,
    /// and the frames after it (which reuse that memory) are shown as
    /// they came.
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn a_frame_the_staging_memory_cannot_take_is_refused_and_the_next_shown() {
        let (device, queue) = test_device(false);
        let (w, h) = (8usize, 4usize);
        let transfer = Transfer::from_gamma([2.2; 3]);
        let mut frames =
            DeviceFrames::single(&device, &queue, (w, h), &transfer, None).expect("frames");
        let mut short = client_frame(0, w, h, PixelFormat::Rgba8Linear);
        short.payload.pop();
        let e = frames
            .run(0, &[client(1, short)])
            .expect_err("a short payload")
            .to_string();
        assert!(
            e.contains("a frame of 127 bytes for a buffer of 128"),
            "{e}"
        );
        for (id, format) in [PixelFormat::Rgba8Srgb, PixelFormat::Rgb32fPlanar]
            .into_iter()
            .cycle()
            .take(6)
            .enumerate()
        {
            let sent = client_frame(id as u64, w, h, format);
            frames
                .run(id as u64, &[client(id as u64 + 2, sent.clone())])
                .expect("runs");
            let display = frames.read_display(0).expect("display");
            assert!(display.data() == decode(&sent).data(), "frame {id}");
        }
    }
}

/// Layers and views on the device (a module named for what it needs, so
/// that `scripts/test.sh` runs it with the hardware tests).
mod needs_gpu_layers_and_views {
    use super::*;

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn quad_layers_are_blended_on_the_device_as_on_the_host_and_uploaded_once() {
        use crate::compose::{Placement, QuadLayer, ViewGeometry, blend};
        let (device, queue) = test_device(false);
        let (w, h) = (37usize, 21usize);
        let transfer = Transfer::from_gamma([2.2, 2.0, 2.4]);
        let view = ViewGeometry {
            width: w,
            height: h,
            pixels_per_tan: 1000.0,
        };
        let layers = Arc::new(LayerSet::default());
        for (layer, z, x, y, qw, qh, a) in
            [(1, 0, 3, 2, 20, 10, 0.6f32), (2, 1, 15, 8, 22, 13, 1.0)]
        {
            let rgba = (0..qw * qh)
                .flat_map(|t| {
                    let c = |k: usize| a * (((t * 17 + k * 29 + layer) % 97) as f32 / 96.0);
                    [c(0), c(1), c(2), a]
                })
                .collect();
            let quad = QuadLayer {
                layer: layer as u32,
                z,
                placement: Placement::Pixels { x, y },
                width: qw,
                height: qh,
                rgba,
            };
            layers
                .set(9, quad.place(&view).expect("placed"), usize::MAX)
                .expect("set");
        }
        let mut frames =
            DeviceFrames::single(&device, &queue, (w, h), &transfer, None).expect("frames");
        frames.attach_layers(0, layers.clone());
        let sent = SubmittedFrame {
            id: 0,
            capture_ns: 0,
            width: w,
            height: h,
            format: PixelFormat::Rgba8Srgb,
            payload: (0..4 * w * h).map(|i| (i * 7 % 256) as u8).collect(),
        };
        let (frame, first) = frames.run(0, &[client(1, sent.clone())]).expect("runs");
        assert!(frames.last_blended());
        let on_device = frame.to_host().expect("codes").rgba8;
        let mut im = decode(&sent);
        blend(&mut im, &layers.snapshot().quads).expect("blends");
        let mut on_host = Vec::new();
        transfer.encode_rgba8(&im, &mut on_host);
        let worst = on_device
            .iter()
            .zip(&on_host)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap_or(0);
        assert!(worst <= 1, "codes differ by {worst}");
        // The same layers on the next frame: their texels stay on the device.
        let (_, second) = frames.run(1, &[client(2, sent)]).expect("runs");
        assert!(second.to_device_bytes < first.to_device_bytes);
        assert_eq!(second.read_backs, 0);
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn both_eyes_in_one_submission_equal_their_host_twins_in_their_regions() {
        let (device, queue) = nedrt_gpu::test_device(false);
        // 75×21: odd halves (37 and 38 wide), rows padded to 256 bytes.
        let (w, h) = (75usize, 21usize);
        let regions = [
            ViewRegion {
                x: 0,
                y: 0,
                width: 37,
                height: h,
            },
            ViewRegion {
                x: 37,
                y: 0,
                width: 38,
                height: h,
            },
        ];
        let transfer = Transfer::from_gamma([2.2, 2.0, 2.4]);
        let views = vec![
            DeviceView {
                region: regions[0],
                stage: None,
            },
            DeviceView {
                region: regions[1],
                stage: Some(Box::new(Stretch::new(&device))),
            },
        ];
        let mut views =
            DeviceFrames::new(&device, &queue, (w, h), views, &transfer).expect("views");
        // The host twin: view 0 as it is, view 1 stretched, each encoded.
        let host = |left: &Image, right: Option<&Image>| -> Vec<u8> {
            // Opaque black outside the views and in a view with no frame yet.
            let mut panel = [0u8, 0, 0, 255].repeat(w * h);
            let mut put = |im: &Image, r: ViewRegion| {
                let mut codes = Vec::new();
                transfer.encode_rgba8(im, &mut codes);
                for y in 0..r.height {
                    for x in 0..r.width {
                        let d = 4 * ((r.y + y) * w + r.x + x);
                        panel[d..d + 4].copy_from_slice(&codes[4 * (y * r.width + x)..][..4]);
                    }
                }
            };
            put(left, regions[0]);
            if let Some(right) = right {
                let mut s = right.clone();
                s.data_mut().iter_mut().for_each(|v| *v = 1.4 * *v - 0.2);
                put(&s, regions[1]);
            }
            panel
        };
        let worst = |a: &[u8], b: &[u8]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| x.abs_diff(*y))
                .max()
                .unwrap_or(0)
        };
        // The left eye sends sRGB bytes (unpacked on the device), the right
        // planes. The right eye has had no frame yet: black there.
        let sent = client_frame(1, 37, h, PixelFormat::Rgba8Srgb);
        let l = decode(&sent);
        let r = noise(38, h, 2);
        let (frame, first) = views
            .run(1, &[client(1, sent.clone()), planar(0, noise(38, h, 0))])
            .expect("runs");
        assert_eq!(frame.width, w);
        let got = frame.to_host().expect("codes").rgba8;
        // The left eye as its host twin; the right black.
        assert!(
            worst(&got, &host(&l, None)) <= 1,
            "codes differ by {}",
            worst(&got, &host(&l, None))
        );
        assert_eq!(views.last_ran(), &[true, false]);
        assert_eq!(first.to_device_bytes, sent.payload.len() as u64);
        // Both eyes, in one submission.
        let (frame, _) = views
            .run(2, &[client(1, sent.clone()), planar(2, r.clone())])
            .expect("runs");
        let got = frame.to_host().expect("codes").rgba8;
        assert!(
            worst(&got, &host(&l, Some(&r))) <= 1,
            "codes differ by {}",
            worst(&got, &host(&l, Some(&r)))
        );
        assert_eq!(views.last_ran(), &[false, true]);
        // Unchanged frames: nothing goes up, the same panel comes out.
        let (frame, again) = views
            .run(3, &[client(1, sent.clone()), planar(2, r.clone())])
            .expect("runs");
        assert_eq!(again.uploads, 0);
        assert_eq!(again.read_backs, 0);
        assert!(worst(&frame.to_host().expect("codes").rgba8, &host(&l, Some(&r))) <= 1);
        // The right eye as float planes from the client: the same panel.
        let floats = SubmittedFrame {
            id: 4,
            capture_ns: 0,
            width: 38,
            height: h,
            format: PixelFormat::Rgb32fPlanar,
            payload: planar_payload(&r),
        };
        let (frame, _) = views
            .run(4, &[client(1, sent), client(3, floats)])
            .expect("runs");
        assert!(worst(&frame.to_host().expect("codes").rgba8, &host(&l, Some(&r))) <= 1);
        // A frame of the wrong size is refused.
        let e = views
            .run(5, &[planar(5, noise(10, h, 0)), planar(2, r)])
            .expect_err("size")
            .to_string();
        assert!(
            e.contains("a 10×21 frame of 3 planes for view 0 of 37×21"),
            "{e}"
        );
    }

    /// What a stage was asked to do: warm up or record, for which size
    /// and between which buffers.
    type Calls = Arc<std::sync::Mutex<Vec<(&'static str, usize, wgpu::Buffer, wgpu::Buffer)>>>;

    /// [`Stretch`], noting each call.
    #[derive(Debug)]
    struct Noted {
        inner: Stretch,
        calls: Calls,
    }

    impl Noted {
        fn note(
            &self,
            what: &'static str,
            input: &wgpu::Buffer,
            output: &wgpu::Buffer,
            size: usize,
        ) {
            let call = (what, size, input.clone(), output.clone());
            self.calls.lock().expect("calls").push(call);
        }
    }

    impl DeviceStage for Noted {
        fn describe(&self) -> String {
            "noted stretch".into()
        }
        fn record(
            &mut self,
            encoder: &mut wgpu::CommandEncoder,
            input: &wgpu::Buffer,
            output: &wgpu::Buffer,
            width: usize,
            height: usize,
        ) -> Result<(), nedrt_gpu::GpuError> {
            self.note("record", input, output, width * 1000 + height);
            self.inner.record(encoder, input, output, width, height)
        }
        fn warm_up(
            &mut self,
            input: &wgpu::Buffer,
            output: &wgpu::Buffer,
            width: usize,
            height: usize,
        ) -> Result<(), nedrt_gpu::GpuError> {
            self.note("warm up", input, output, width * 1000 + height);
            Ok(())
        }
    }

    /// Each view's stage is made ready for its own size and buffers when
    /// the engine is made, before any frame, and its first frame records
    /// between those same buffers (so what the warm-up made is used).
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn every_view_s_stage_is_made_ready_before_its_first_frame() {
        let (device, queue) = nedrt_gpu::test_device(false);
        let h = 21;
        let calls: [Calls; 2] = Default::default();
        let views = (0..2)
            .map(|v| DeviceView {
                region: ViewRegion {
                    x: 37 * v,
                    y: 0,
                    width: 37 + v,
                    height: h,
                },
                stage: Some(Box::new(Noted {
                    inner: Stretch::new(&device),
                    calls: calls[v].clone(),
                }) as Box<dyn DeviceStage>),
            })
            .collect();
        let transfer = Transfer::from_gamma([2.2, 2.0, 2.4]);
        let mut frames =
            DeviceFrames::new(&device, &queue, (75, h), views, &transfer).expect("views");
        for (v, c) in calls.iter().enumerate() {
            let c = c.lock().expect("calls");
            let sizes: Vec<_> = c.iter().map(|(what, size, ..)| (*what, *size)).collect();
            assert_eq!(sizes, [("warm up", (37 + v) * 1000 + h)], "view {v}");
        }
        frames
            .run(1, &[planar(1, noise(37, h, 0)), planar(1, noise(38, h, 1))])
            .expect("runs");
        for (v, c) in calls.iter().enumerate() {
            let c = c.lock().expect("calls");
            assert_eq!(c.len(), 2, "view {v}");
            let (warm, record) = (&c[0], &c[1]);
            assert_eq!((record.0, record.1), ("record", warm.1), "view {v}");
            assert!(
                record.2 == warm.2 && record.3 == warm.3,
                "view {v}: other buffers"
            );
        }
    }
}

fn noise(w: usize, h: usize, seed: usize) -> Image {
    Image::rgb(
        w,
        h,
        (0..3 * w * h)
            .map(|i| ((i * 7 + seed * 13) % 1001) as f32 / 1000.0)
            .collect(),
    )
}
