//! Every message of the wire format read from hostile bytes, as a client
//! (and the OpenXR runtime, of the service's welcome) reads them: a hello,
//! both versions' headers, both versions' replies with their messages, and
//! the welcome's views and geometry. Whatever parses writes back to the
//! bytes it came from.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nedrt_protocol::v2::{HEADER_V2_LEN, HeaderV2, ReplyV2, pixels_per_tan, view_regions};
use nedrt_protocol::{FrameHeader, HEADER_LEN, HELLO_LEN, Hello, Reply};

fuzz_target!(|data: &[u8]| {
    if let Some(b) = data.first_chunk::<HELLO_LEN>()
        && let Ok(h) = Hello::parse(b)
    {
        assert!(Hello::parse(&h.to_bytes_version(Hello::version_of(b))).is_ok());
    }
    if let Some(b) = data.first_chunk::<HEADER_LEN>()
        && let Ok(h) = FrameHeader::parse(b)
    {
        assert_eq!(FrameHeader::parse(&h.to_bytes()), Ok(h));
    }
    if let Some(b) = data.first_chunk::<HEADER_V2_LEN>()
        && let Ok(h) = HeaderV2::parse(b)
    {
        assert_eq!(HeaderV2::parse(&h.to_bytes()), Ok(h));
    }
    if let Ok(r) = Reply::read_from(&mut &data[..]) {
        assert_eq!(Reply::read_from(&mut r.to_bytes().as_slice()).ok(), Some(r));
    }
    if let Ok(r) = ReplyV2::read_from(&mut &data[..]) {
        let _ = view_regions(&r.reply.message);
        let _ = pixels_per_tan(&r.reply.message);
        assert_eq!(ReplyV2::read_from(&mut r.to_bytes().as_slice()).ok(), Some(r));
    }
    let text = String::from_utf8_lossy(data);
    for [x, y, w, h] in view_regions(&text) {
        let _ = (x.checked_add(w), y.checked_add(h));
    }
    if let Some(p) = pixels_per_tan(&text) {
        assert!(p.is_finite() && p > 0.0);
    }
});
