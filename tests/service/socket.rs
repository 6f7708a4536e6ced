//! The socket protocol end to end: exact recording, every kind of bad frame.

use super::*;

#[test]
fn socket_frames_are_recorded_exactly_as_the_backend_computes_them() {
    let service = Service::socket_recorder();
    let mut client = service.client(W * H * 12);
    assert_eq!(client.panel, (W, H));
    let n = 12u64;
    for id in 0..n {
        let frame = test_frame(id);
        let header = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, id, 0);
        let reply = client
            .send(&header, &planar_payload(&frame))
            .expect("a reply to the frame");
        assert_eq!(
            (reply.status, reply.frame_id),
            (STATUS_OK, id),
            "{}",
            reply.message
        );
    }
    let rec = service.dir.path().join("rec");
    wait_until("the last frame to be recorded", || {
        frame_path(&rec, n - 1).exists()
    });
    let (out, dir) = service.stop();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The socket listens only once the pipeline is prepared: a client that
    // finds it is welcomed at once.
    let log = String::from_utf8_lossy(&out.stderr);
    let prepared = log.find("preprocess:").expect("the pipeline's line");
    let listening = log.find("listening on").expect("the socket's line");
    assert!(prepared < listening, "{log}");
    let r = report(dir.path());
    let presented = r["presented"].as_u64().expect("presented");
    let dropped = r["dropped_queued"].as_u64().expect("dropped")
        + r["dropped_at_present"].as_u64().expect("dropped");
    assert_eq!(r["submitted"].as_u64(), Some(n));
    assert_eq!(
        presented + dropped,
        n,
        "every frame presented or counted as dropped"
    );
    let (mut dcnn, transfer) = reference();
    let mut checked = 0;
    for id in 0..n {
        let path = frame_path(&dir.path().join("rec"), id);
        if !path.exists() {
            continue;
        }
        let got = image::open(&path).expect("png").to_rgb8().into_raw();
        assert_eq!(
            got,
            expected_rgb(&mut dcnn, &transfer, &test_frame(id)),
            "frame {id}"
        );
        checked += 1;
    }
    assert_eq!(checked as u64, presented);
    assert!(checked >= 1);
}

#[test]
fn every_kind_of_bad_frame_is_rejected_and_good_frames_still_arrive() {
    let service = Service::socket_recorder();
    let shm = W * H * 12;
    let mut client = service.client(shm);
    let good = |id| {
        (
            FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, id, 0),
            planar_payload(&test_frame(id)),
        )
    };
    let mut nan = test_frame(0);
    nan.data_mut()[100] = f32::NAN;
    let mut bright = test_frame(0);
    bright.data_mut()[7] = 1.5;
    let mut bad_magic = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 901, 0).to_bytes();
    bad_magic[0] = b'X';
    let mut bad_version = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 902, 0).to_bytes();
    bad_version[4] = 9;
    let mut unknown_format = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 903, 0);
    unknown_format.format = 77;
    let wrong_size = FrameHeader::new(PixelFormat::Rgb32fPlanar, W / 2, H, 904, 0);
    let mut short = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 905, 0);
    short.length -= 4;
    let mut outside = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 906, 0);
    outside.offset = 8;
    let cases: Vec<(Vec<u8>, Option<Vec<u8>>, RejectReason)> = vec![
        (bad_magic.to_vec(), None, RejectReason::Malformed),
        (bad_version.to_vec(), None, RejectReason::Malformed),
        (
            unknown_format.to_bytes().to_vec(),
            None,
            RejectReason::UnsupportedFormat,
        ),
        (
            wrong_size.to_bytes().to_vec(),
            None,
            RejectReason::WrongSize,
        ),
        (short.to_bytes().to_vec(), None, RejectReason::Truncated),
        (outside.to_bytes().to_vec(), None, RejectReason::Truncated),
        (
            FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 907, 0)
                .to_bytes()
                .to_vec(),
            Some(planar_payload(&nan)),
            RejectReason::NonFinite,
        ),
        (
            FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 908, 0)
                .to_bytes()
                .to_vec(),
            Some(planar_payload(&bright)),
            RejectReason::OutOfRange,
        ),
    ];
    let mut id = 0u64;
    let rec = service.dir.path().join("rec");
    let send_good = |client: &mut Client, id: &mut u64| {
        let (h, p) = good(*id);
        let r = client.send(&h, &p).expect("good frame");
        assert_eq!(r.status, STATUS_OK, "good frame {id}: {}", r.message);
        // Each good frame recorded before the next is sent, so none is
        // replaced newest-wins however slow a loaded machine makes the
        // pipeline (a fixed 150 ms pause once lost one under load).
        let shown = *id;
        wait_until(&format!("good frame {shown} to be recorded"), || {
            frame_path(&rec, shown).exists()
        });
        *id += 1;
    };
    for (header, body, reason) in &cases {
        send_good(&mut client, &mut id);
        let r = match body {
            Some(b) => {
                let mut h = [0u8; HEADER_LEN];
                h.copy_from_slice(header);
                client
                    .send(&FrameHeader::parse(&h).expect("header"), b)
                    .expect("reply")
            }
            None => client.send_header_bytes(header).expect("reply"),
        };
        assert_eq!(
            RejectReason::from_code(r.status),
            Some(*reason),
            "{}",
            r.message
        );
        assert!(!r.message.is_empty());
    }
    // A client that vanishes mid-header, and one with a bad hello.
    {
        let mut half = service.client(16);
        use std::io::Write;
        half.stream()
            .write_all(&good(0).0.to_bytes()[..10])
            .expect("half a header");
    }
    {
        use std::io::{Read, Write};
        let mut raw = std::os::unix::net::UnixStream::connect(Service::socket(service.dir.path()))
            .expect("connect");
        // The service answers and hangs up; past the timeout the read
        // ends with what came, and the assertion below says so.
        raw.set_read_timeout(Some(REPLY_WITHIN)).expect("timeout");
        raw.write_all(b"HELLO, this is not the protocol")
            .expect("write");
        let mut buf = Vec::new();
        let _ = raw.read_to_end(&mut buf);
        assert!(
            String::from_utf8_lossy(&buf).contains("bad hello"),
            "{:?}",
            String::from_utf8_lossy(&buf)
        );
    }
    send_good(&mut client, &mut id);
    let (out, dir) = service.stop();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for good_id in 0..id {
        assert!(
            frame_path(&dir.path().join("rec"), good_id).exists(),
            "good frame {good_id} was not delivered"
        );
    }
    let r = report(dir.path());
    let rejected: std::collections::HashMap<String, u64> = r["rejected"]
        .as_array()
        .expect("rejected")
        .iter()
        .map(|p| {
            (
                p[0].as_str().expect("name").to_string(),
                p[1].as_u64().expect("n"),
            )
        })
        .collect();
    assert_eq!(rejected["malformed"], 2);
    assert_eq!(rejected["unsupported-format"], 1);
    assert_eq!(rejected["wrong-size"], 1);
    assert_eq!(rejected["truncated"], 2);
    assert_eq!(rejected["non-finite"], 1);
    assert_eq!(rejected["out-of-range"], 1);
    assert_eq!(r["disconnects_mid_frame"].as_u64(), Some(1));
    assert_eq!(r["submitted"].as_u64(), Some(id + cases.len() as u64));
    assert_eq!(
        r["presented"].as_u64(),
        Some(id),
        "{}",
        serde_json::to_string(&r).unwrap_or_default()
    );
}

/// A hello naming anything but the client's own regular file in the
/// shared-memory folder is refused at once with the reason, and the service
/// goes on and stops promptly: a link to another file (the service must
/// never read it: docs/protocol.md) and a FIFO (a blocking open would hold
/// the client's thread, and shutdown, forever).
#[test]
fn shared_memory_that_is_a_link_or_a_fifo_is_refused_at_once() {
    use nedrt_protocol::{HELLO_MAGIC, Reply, STATUS_BAD_HELLO, VERSION};
    use std::io::Write;
    let service = Service::socket_recorder();
    let shm = service.dir.path().join("shm");
    std::os::unix::fs::symlink(repo().join("models/dcnn.onnx"), shm.join("link")).expect("symlink");
    let made = Command::new("mkfifo")
        .arg(shm.join("fifo"))
        .status()
        .expect("mkfifo");
    assert!(made.success());
    for (name, reason) in [("link", "a symbolic link"), ("fifo", "not a regular file")] {
        let mut raw = std::os::unix::net::UnixStream::connect(Service::socket(service.dir.path()))
            .expect("connect");
        raw.set_read_timeout(Some(Duration::from_secs(10)))
            .expect("timeout");
        let mut hello = HELLO_MAGIC.to_vec();
        hello.extend_from_slice(&VERSION.to_le_bytes());
        hello.extend_from_slice(&(name.len() as u16).to_le_bytes());
        hello.extend_from_slice(&64u64.to_le_bytes());
        hello.extend_from_slice(name.as_bytes());
        raw.write_all(&hello).expect("hello");
        let reply = Reply::read_from(&mut raw).expect("an answer, not a hang");
        assert_eq!(reply.status, STATUS_BAD_HELLO, "{name}: {}", reply.message);
        assert!(reply.message.contains(reason), "{name}: {}", reply.message);
    }
    // A well-behaved client still gets through.
    let mut client = service.client(3 * W * H * 4);
    let payload = planar_payload(&test_frame(0));
    let header = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 0, 0);
    let r = client.send(&header, &payload).expect("good frame");
    assert_eq!(r.status, STATUS_OK, "{}", r.message);
    stop_promptly(service);
}

/// A client that sends and never reads its replies fills the socket's
/// buffer; the service drops it after the reply deadline, counts it, and
/// still stops promptly with its report.
#[test]
fn a_client_that_never_reads_its_replies_is_dropped_and_counted() {
    use std::io::Write;
    let service = Service::socket_recorder();
    let mut client = service.client(16);
    let mut stream = client.stream().try_clone().expect("clone");
    // Malformed headers: each gets a rejection reply nobody reads.
    let junk = [0u8; HEADER_LEN];
    let writer = std::thread::spawn(move || {
        for _ in 0..200_000 {
            if stream.write_all(&junk).is_err() {
                break;
            }
        }
    });
    let deadline = nedrt_service::pipeline::source::socket::REPLY_DEADLINE;
    std::thread::sleep(deadline * 3);
    let (out, dir) = stop_promptly(service);
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("read none of its replies"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(report(dir.path())["clients_dropped"].as_u64(), Some(1));
    drop(client);
    deadline::join_within(
        writer,
        REPLY_WITHIN,
        "the writer to stop once the service dropped its client",
    );
}

/// SIGTERM, which must end the service cleanly within 10 s whatever its
/// clients do.
fn stop_promptly(service: Service) -> (Output, tempfile::TempDir) {
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
    (out, dir)
}
