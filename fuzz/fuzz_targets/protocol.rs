//! The socket protocol as the service reads it: a hello, its
//! shared-memory name, then frame headers, each admitted or rejected before
//! any payload is read; an admitted payload (taken from the input itself,
//! standing in for the client's shared memory) is validated and decoded as
//! the upload stage does.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nedrt_service::pipeline::frame::{self, SubmittedFrame};
use nedrt_service::pipeline::protocol::{HEADER_LEN, HELLO_LEN, Hello, valid_shm_name};
use nedrt_service::pipeline::source::socket::admit;

/// The test panel's size (tests/data/small-panel.toml).
const PANEL: (usize, usize) = (64, 48);

fuzz_target!(|data: &[u8]| {
    let Some((hello, rest)) = data.split_first_chunk::<HELLO_LEN>() else {
        return;
    };
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
    let mut headers = rest;
    while let Some((header, next)) = headers.split_first_chunk::<HEADER_LEN>() {
        headers = next;
        let Ok(req) = admit(header, PANEL, hello.shm_size) else {
            continue;
        };
        let Some(payload) = usize::try_from(req.offset)
            .ok()
            .and_then(|o| shm.get(o..o.checked_add(req.length)?))
        else {
            continue;
        };
        let submitted = SubmittedFrame {
            id: 0,
            capture_ns: req.capture_ns,
            width: PANEL.0,
            height: PANEL.1,
            format: req.format,
            payload: payload.to_vec(),
        };
        if frame::validate(&submitted, PANEL.0, PANEL.1).is_ok() {
            let image = frame::decode(&submitted);
            assert!(image.data().iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }
});
