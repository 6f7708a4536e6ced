//! The socket protocol as the service reads it: a hello, its
//! shared-memory name, then frame headers (version 1's 48 bytes or version
//! 2's 72, as the hello asks), each admitted or rejected before any payload
//! is read; an admitted payload (taken from the input itself, standing in
//! for the client's shared memory) is validated and decoded as the upload
//! stage does, and a version 2 quad is decoded, checked and placed as the
//! compositor does.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nedrt_service::compose::{ViewGeometry, blend};
use nedrt_service::pipeline::frame::{self, SubmittedFrame};
use nedrt_protocol::v2::{HEADER_V2_LEN, VERSION_2};
use nedrt_protocol::{HEADER_LEN, HELLO_LEN, Hello, valid_shm_name};
use nedrt_service::pipeline::source::socket::admit;
use nedrt_service::pipeline::source::socket::v2::{self, AdmittedV2};

/// The test panel's size (tests/data/small-panel.toml).
const PANEL: (usize, usize) = (64, 48);

fuzz_target!(|data: &[u8]| {
    let Some((hello, rest)) = data.split_first_chunk::<HELLO_LEN>() else {
        return;
    };
    let version = Hello::version_of(hello);
    let Ok(hello) = Hello::parse(hello) else {
        return;
    };
    let Some((name, rest)) = rest.split_at_checked(hello.name_len) else {
        return;
    };
    if !valid_shm_name(&String::from_utf8_lossy(name)) {
        return;
    }
    // The input stands in for the shared memory; its announced size may lie.
    let shm = rest;
    if version == VERSION_2 {
        return version_2(shm, hello.shm_size);
    }
    let mut headers = rest;
    while let Some((header, next)) = headers.split_first_chunk::<HEADER_LEN>() {
        headers = next;
        let Ok(req) = admit(header, PANEL, hello.shm_size) else {
            continue;
        };
        if let Some(payload) = usize::try_from(req.offset)
            .ok()
            .and_then(|o| shm.get(o..o.checked_add(req.length)?))
        {
            check_frame(payload, req.format, req.capture_ns, PANEL);
        }
    }
});

/// The frame a payload of the input makes, checked as the pipeline does.
fn check_frame(
    payload: &[u8],
    format: frame::PixelFormat,
    capture_ns: u64,
    (w, h): (usize, usize),
) {
    let submitted = SubmittedFrame {
        id: 0,
        capture_ns,
        width: w,
        height: h,
        format,
        payload: payload.to_vec(),
    };
    if frame::validate(&submitted, w, h).is_ok() {
        let image = frame::decode(&submitted);
        assert!(image.data().iter().all(|v| (0.0..=1.0).contains(v)));
    }
}

/// Version 2 headers: projections as version 1's frames, quads decoded,
/// checked, placed and blended (the composition stays in [0, 1]).
fn version_2(shm: &[u8], shm_size: u64) {
    let mut headers = shm;
    while let Some((header, next)) = headers.split_first_chunk::<HEADER_V2_LEN>() {
        headers = next;
        // The panel as two views side by side: every path of the check.
        let views = [(PANEL.0 / 2, PANEL.1), (PANEL.0 - PANEL.0 / 2, PANEL.1)];
        let Ok(admitted) = v2::admit(header, PANEL, &views, shm_size) else {
            continue;
        };
        let slice = |offset: u64, length: usize| {
            usize::try_from(offset)
                .ok()
                .and_then(|o| shm.get(o..o.checked_add(length)?))
        };
        match admitted {
            AdmittedV2::Projection { view, frame: req, .. } => {
                let size = view.map_or(PANEL, |v| views[usize::from(v)]);
                if let Some(payload) = slice(req.offset, req.length) {
                    check_frame(payload, req.format, req.capture_ns, size);
                }
            }
            AdmittedV2::Quad(q) => {
                let Some(payload) = slice(q.offset, q.length) else {
                    continue;
                };
                let quad = q.layer_of(payload);
                let (vw, vh) = views[usize::from(q.view)];
                let geometry = ViewGeometry {
                    width: vw,
                    height: vh,
                    pixels_per_tan: 4597.7,
                };
                if let Ok(placed) = quad.place(&geometry) {
                    let mut im = nedrt_core::Image::rgb(vw, vh, vec![1.0; 3 * vw * vh]);
                    blend(&mut im, &[placed]).expect("one quad");
                    assert!(im.data().iter().all(|v| (0.0..=1.0 + 1e-5).contains(v)));
                }
            }
            AdmittedV2::Remove { .. } => {}
        }
    }
}
