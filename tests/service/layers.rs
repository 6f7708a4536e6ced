//! Protocol version 2 end to end: clients submit a projection layer and
//! quad layers; the recording is the D-CNN of the composition; bad layers
//! get their own status while everyone keeps being served; a client that
//! leaves takes its layers along; every reply carries the pacer's
//! prediction; version 1 clients are served beside version 2 ones.

use super::*;
use nedrt_protocol::v2::{HeaderV2, QuadFormat, STATUS_BAD_LAYER};
use nedrt_service::compose::{Placement, QuadLayer, ViewGeometry, blend};

/// A uniform premultiplied RGBA8 quad: colour `c` (per channel) at alpha `a`.
fn quad_texels(w: usize, h: usize, c: [u8; 3], a: u8) -> Vec<u8> {
    [c[0], c[1], c[2], a].repeat(w * h)
}

fn as_layer(
    layer: u32,
    z: i32,
    placement: Placement,
    (w, h): (usize, usize),
    t: &[u8],
) -> QuadLayer {
    QuadLayer {
        layer,
        z,
        placement,
        width: w,
        height: h,
        rgba: QuadFormat::Rgba8Premultiplied.decode(t),
    }
}

#[test]
fn quad_layers_from_two_clients_are_blended_before_the_dcnn_and_leave_with_their_client() {
    let service = Service::socket_recorder();
    let shm = W * H * 12;
    let connect = || service.client_v2(shm);
    let before = nedrt_service::pipeline::pacing::monotonic_ns();
    let mut a = connect();
    let mut b = connect();
    let mut old = service.client(shm);
    let welcome = a.timing.clone().expect("a version 2 welcome");
    // tests/data/small-panel.toml refreshes at 240 Hz.
    assert_eq!(welcome.refresh_period_ns, 4_166_667);
    assert_eq!(welcome.views, 1);
    // The welcome's prediction: a refresh after the hello, not in the past.
    assert!(
        welcome.predicted_display_ns >= before,
        "predicted {} for a hello sent at {before}",
        welcome.predicted_display_ns
    );

    let calib = Calibration::load(&small_panel()).expect("calib");
    let view = ViewGeometry::of_panel(W, H, calib.pixel_pitch_m, calib.lens_distance_m);
    // A: a half-transparent quad of layer 1 at pixels (10, 10). B: its own
    // layer 1 (another layer: another client), opaque, centred at 0°, above.
    let ta = quad_texels(8, 6, [60, 20, 100], 128);
    let a_at = Placement::Pixels { x: 10, y: 10 };
    let tb = quad_texels(6, 4, [200, 150, 30], 255);
    let b_at = Placement::Degrees {
        x_deg: 0.0,
        y_deg: 0.0,
    };
    let fmt = QuadFormat::Rgba8Premultiplied;
    let r = a
        .send_v2(&HeaderV2::quad(0, 1, 0, a_at, fmt, (8, 6), 1, 0), &ta)
        .expect("a reply to the frame");
    assert_eq!(r.reply.status, STATUS_OK, "{}", r.reply.message);
    let r = b
        .send_v2(&HeaderV2::quad(0, 1, 2, b_at, fmt, (6, 4), 1, 0), &tb)
        .expect("a reply to the frame");
    assert_eq!(r.reply.status, STATUS_OK, "{}", r.reply.message);
    // Bad submissions: each its status and reason; nobody is cut off.
    let outside = Placement::Pixels { x: 60, y: 0 };
    let r = b
        .send_v2(&HeaderV2::quad(0, 2, 0, outside, fmt, (6, 4), 2, 0), &tb)
        .expect("a reply to the frame");
    assert_eq!(r.reply.status, STATUS_BAD_LAYER);
    assert!(
        r.reply.message.contains("not inside"),
        "{}",
        r.reply.message
    );
    let glow = quad_texels(2, 2, [90, 0, 0], 10);
    let r = b
        .send_v2(&HeaderV2::quad(0, 3, 0, a_at, fmt, (2, 2), 3, 0), &glow)
        .expect("a reply to the frame");
    assert_eq!(r.reply.status, STATUS_BAD_LAYER);
    assert!(
        r.reply.message.contains("premultiplied"),
        "{}",
        r.reply.message
    );
    let r = b
        .send_v2(&HeaderV2::remove(0, 9, 4), &[])
        .expect("a reply to the frame");
    assert_eq!(r.reply.status, STATUS_BAD_LAYER);
    let frame = test_frame(5);
    let right_eye = HeaderV2::projection(1, PixelFormat::Rgb32fPlanar, (W, H), 5, 0);
    let r = a
        .send_v2(&right_eye, &planar_payload(&frame))
        .expect("a reply to the frame");
    assert_eq!(
        r.reply.status,
        RejectReason::UnknownView.code(),
        "{}",
        r.reply.message
    );

    let (mut dcnn, transfer) = reference();
    let rec = service.dir.path().join("rec");
    // Sends frame `id` and waits for its recording; whether it shows the
    // composition of `layers` (the D-CNN of the blend, exactly).
    let mut shows = |client: &mut Client, id: u64, layers: &[QuadLayer]| -> bool {
        let frame = test_frame(id);
        let h = HeaderV2::projection(0, PixelFormat::Rgb32fPlanar, (W, H), id, 0);
        let r = client
            .send_v2(&h, &planar_payload(&frame))
            .expect("a reply to the frame");
        assert_eq!(r.reply.status, STATUS_OK, "{}", r.reply.message);
        assert_eq!(r.refresh_period_ns, 4_166_667);
        wait_until("the frame to be recorded", || frame_path(&rec, id).exists());
        let placed: Vec<_> = layers
            .iter()
            .map(|q| q.place(&view).expect("placed"))
            .collect();
        let mut composed = frame.clone();
        blend(&mut composed, &placed).expect("blend");
        let got = image::open(frame_path(&rec, id))
            .expect("png")
            .to_rgb8()
            .into_raw();
        got == expected_rgb(&mut dcnn, &transfer, &composed)
    };
    let layer_a = as_layer(1, 0, a_at, (8, 6), &ta);
    let layer_b = as_layer(1, 2, b_at, (6, 4), &tb);
    assert!(
        shows(&mut a, 10, &[layer_a.clone(), layer_b.clone()]),
        "frame 10"
    );
    // A version 1 client's frame is composed with the same layers.
    let h = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 11, 0);
    let r = old
        .send(&h, &planar_payload(&test_frame(11)))
        .expect("a reply to the version 1 frame");
    assert_eq!(r.status, STATUS_OK, "{}", r.message);
    wait_until("the v1 frame", || frame_path(&rec, 11).exists());
    // A leaves: its quad goes with it once its thread has seen the hang-up
    // (it looks every 50 ms); until then B's frames may still show it.
    drop(a);
    let gone = (12..112).find(|&id| shows(&mut b, id, std::slice::from_ref(&layer_b)));
    assert!(gone.is_some(), "A's quad stayed after A left");
    // B removes its layer: the bare frame.
    let r = b
        .send_v2(&HeaderV2::remove(0, 1, 200), &[])
        .expect("a reply to the frame");
    assert_eq!(r.reply.status, STATUS_OK, "{}", r.reply.message);
    assert!(shows(&mut b, 201, &[]), "frame 201");

    let (out, dir) = service.stop();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r = report(dir.path());
    assert_eq!(r["layers_set"].as_u64(), Some(2));
    // Outside, colour over alpha, removing a layer never set.
    assert_eq!(r["layers_refused"].as_u64(), Some(3));
    assert!(r["frames_with_layers"].as_u64() >= Some(3));
    let rejected = r["rejected"].as_array().expect("rejected");
    assert!(
        rejected.iter().any(|e| e[0] == "unknown-view" && e[1] == 1),
        "{rejected:?}"
    );
    let shown: u64 = r["shown_vs_predicted"]
        .as_array()
        .expect("shown_vs_predicted")
        .iter()
        .map(|e| e[1].as_u64().unwrap_or(0))
        .sum();
    assert_eq!(shown, r["presented"].as_u64().expect("presented"));
    // Per client: A's, the version 1 client's and B's frames, each counted
    // once, with how far ahead of its predicted refresh each was submitted.
    let clients = r["clients"].as_array().expect("clients");
    let per_client: u64 = clients
        .iter()
        .map(|c| c["shown"].as_u64().unwrap_or(0))
        .sum();
    assert_eq!(per_client, shown);
    assert!(clients.len() >= 2, "{clients:?}");
    assert!(clients.iter().all(|c| c["client"].as_u64() > Some(0)));
    assert!(
        clients
            .iter()
            .all(|c| c["mean_lead_ms"].as_f64() >= Some(0.0))
    );
}

#[test]
fn two_eyes_from_a_stereo_client_and_an_overlay_client_are_each_counted_and_stop_promptly() {
    let service = Service::socket_recorder_with(&["--stereo"]);
    let connect = || service.client_v2(W * H * 12);
    let mut eyes = connect();
    let mut overlay = connect();
    assert_eq!(eyes.views, vec![[0, 0, W / 2, H], [W / 2, 0, W / 2, H]]);
    assert_eq!(eyes.timing.as_ref().map(|t| t.views), Some(2));
    // The overlay client: a quad on the right eye only.
    let hud = quad_texels(8, 4, [40, 40, 40], 200);
    let at = Placement::Pixels { x: 4, y: 4 };
    let q = HeaderV2::quad(1, 1, 0, at, QuadFormat::Rgba8Premultiplied, (8, 4), 1, 0);
    let r = overlay.send_v2(&q, &hud).expect("a reply to the frame");
    assert_eq!(r.reply.status, STATUS_OK, "{}", r.reply.message);
    // A frame of the whole panel's size for one eye is refused.
    let whole = HeaderV2::projection(0, PixelFormat::Rgb32fPlanar, (W, H), 1, 0);
    let r = eyes
        .send_v2(&whole, &planar_payload(&test_frame(1)))
        .expect("a reply to the frame");
    assert_eq!(
        r.reply.status,
        RejectReason::WrongSize.code(),
        "{}",
        r.reply.message
    );
    let rec = service.dir.path().join("rec");
    for id in 0..6u64 {
        for v in 0..2u8 {
            let frame = test_frame(id).crop(usize::from(v) * W / 2, 0, W / 2, H);
            let h = HeaderV2::projection(
                v,
                PixelFormat::Rgb32fPlanar,
                (W / 2, H),
                2 * id + u64::from(v),
                0,
            );
            let r = eyes
                .send_v2(&h, &planar_payload(&frame))
                .expect("a reply to the frame");
            assert_eq!(r.reply.status, STATUS_OK, "{}", r.reply.message);
        }
        wait_until("the pair to be recorded", || {
            frame_path(&rec, 2 * id + 1).exists()
        });
    }
    let started = Instant::now();
    let (out, dir) = service.stop();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        started.elapsed() < Duration::from_secs(10),
        "stopped in {:?}",
        started.elapsed()
    );
    let r = report(dir.path());
    let views = r["view_stages"].as_array().expect("view_stages");
    assert_eq!(views.len(), 2, "{views:?}");
    assert!(views.iter().all(|v| v["count"].as_u64() >= Some(1)));
    // Every submission accounted for: shown, dropped, rejected or in flight.
    let n = |k: &str| r[k].as_u64().unwrap_or(0);
    let rejected: u64 = r["rejected"]
        .as_array()
        .expect("rejected")
        .iter()
        .map(|e| e[1].as_u64().unwrap_or(0))
        .sum();
    assert_eq!(n("submitted"), 13);
    assert_eq!(
        n("presented")
            + n("dropped_queued")
            + n("dropped_at_present")
            + n("skipped")
            + rejected
            + n("in_flight_at_stop")
            + n("failed"),
        13
    );
    assert_eq!(n("layers_set"), 1);
    assert!(!r["clients"].as_array().expect("clients").is_empty());
}
