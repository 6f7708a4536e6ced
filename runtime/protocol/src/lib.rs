//! The application interface on the wire (docs/protocol.md): a Unix stream
//! socket carries fixed-size little-endian headers and replies; pixel
//! payloads travel in a POSIX shared-memory object (a file in /dev/shm)
//! that the client creates and names in its hello. The service reads each
//! payload once, replies, and the client may then reuse the memory.
//!
//! [`Client`] is the client side, used by `examples/stream_client.rs`
//! (this crate's), the OpenXR runtime and the tests; the service side is
//! nedrt-service's `source::socket`.
//!
//! nedrt-protocol, layer 0 of nedrt: the wire format alone, with no GPU or
//! window dependency, so that a client (an OpenXR runtime library, the
//! examples, the fuzz target) links nothing of the service.

use std::io::{Read, Write};
use std::os::unix::fs::{FileExt, OpenOptionsExt};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};

mod codec;
pub mod test_pattern;
pub mod v2;

/// CLOCK_MONOTONIC in nanoseconds: the protocol's clock (capture and
/// display times).
pub fn monotonic_ns() -> u64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
}

use codec::{Le, LeMut};

/// Pixel layouts the service takes. Values are display intensities, linear
/// unless the format says otherwise (docs/model.md §1: the D-CNN works on
/// linear intensity).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PixelFormat {
    /// 8-bit RGBA, interleaved, value/255 is linear intensity; alpha ignored.
    Rgba8Linear,
    /// 8-bit RGBA, interleaved, sRGB-encoded (a typical render target); alpha ignored.
    Rgba8Srgb,
    /// 32-bit float, planar R, G, B planes, little-endian, linear.
    Rgb32fPlanar,
}

impl PixelFormat {
    /// Wire codes of the socket protocol (docs/protocol.md).
    pub fn from_code(code: u16) -> Option<Self> {
        match code {
            1 => Some(Self::Rgba8Linear),
            2 => Some(Self::Rgba8Srgb),
            3 => Some(Self::Rgb32fPlanar),
            _ => None,
        }
    }

    pub fn code(self) -> u16 {
        match self {
            Self::Rgba8Linear => 1,
            Self::Rgba8Srgb => 2,
            Self::Rgb32fPlanar => 3,
        }
    }

    pub fn bytes_per_pixel(self) -> usize {
        match self {
            Self::Rgba8Linear | Self::Rgba8Srgb => 4,
            Self::Rgb32fPlanar => 12,
        }
    }
}

/// Where a quad sits on its view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Placement {
    /// Its top-left texel on the view's pixel (`x`, `y`), panel pixels.
    Pixels { x: i64, y: i64 },
    /// Its centre at a direction from the view's centre, degrees (x to the
    /// right, y up), through the view's pixels per unit of tan(angle) (nedrt-service's
    /// `ViewGeometry::pixels_per_tan`).
    Degrees { x_deg: f64, y_deg: f64 },
}

pub const VERSION: u16 = 1;
pub const HELLO_MAGIC: [u8; 4] = *b"NEDH";
pub const FRAME_MAGIC: [u8; 4] = *b"NEDF";
pub const REPLY_MAGIC: [u8; 4] = *b"NEDR";
/// Hello: magic, version u16, name length u16, shared-memory size u64.
pub const HELLO_LEN: usize = 16;
/// Frame header: magic, version u16, format u16, width u32, height u32,
/// frame id u64, capture ns u64, payload offset u64, payload length u64.
pub const HEADER_LEN: usize = 48;
/// Reply: magic, status u32, frame id u64, panel width u32, panel height
/// u32, message length u32; the UTF-8 message follows.
pub const REPLY_LEN: usize = 28;
/// Reply status of an accepted frame; rejections use `RejectReason::code`.
pub const STATUS_OK: u32 = 0;
/// Reply status of a refused hello (the service then closes).
pub const STATUS_BAD_HELLO: u32 = 100;
/// Longest shared-memory name.
pub const MAX_NAME: usize = 255;

/// Why a hello or a frame header is malformed: the reason the service
/// replies with.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct Malformed(pub String);

/// A client's hello: which shared-memory object it made and how big.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Hello {
    /// Length of the shared-memory name that follows the hello.
    pub name_len: usize,
    /// Announced size of the shared memory, bytes.
    pub shm_size: u64,
}

impl Hello {
    pub fn to_bytes(&self) -> [u8; HELLO_LEN] {
        self.to_bytes_version(VERSION)
    }

    /// The hello of a connection that speaks `version` (1 or 2).
    pub fn to_bytes_version(&self, version: u16) -> [u8; HELLO_LEN] {
        let mut b = [0u8; HELLO_LEN];
        let mut w = LeMut(&mut b);
        w.bytes(0, &HELLO_MAGIC);
        w.u16(4, version);
        w.u16(6, self.name_len.min(u16::MAX as usize) as u16);
        w.u64(8, self.shm_size);
        b
    }

    /// The version a hello asks for (checked by [`Hello::parse`]).
    pub fn version_of(b: &[u8; HELLO_LEN]) -> u16 {
        Le(b).u16(4)
    }

    /// Parses a hello of version 1 or 2; `Err` is the reason the service
    /// replies with.
    pub fn parse(b: &[u8; HELLO_LEN]) -> Result<Self, Malformed> {
        let version = Self::version_of(b);
        if b[0..4] != HELLO_MAGIC || !(VERSION..=v2::VERSION_2).contains(&version) {
            return Err(Malformed(format!(
                "bad hello (magic {:?}, version {version}; expected \"NEDH\", {VERSION} or {})",
                &b[0..4],
                v2::VERSION_2
            )));
        }
        let name_len = usize::from(Le(b).u16(6));
        if name_len == 0 || name_len > MAX_NAME {
            return Err(Malformed(format!(
                "shared-memory name of {name_len} bytes (1 to {MAX_NAME})"
            )));
        }
        Ok(Self {
            name_len,
            shm_size: Le(b).u64(8),
        })
    }
}

/// A frame header as sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameHeader {
    pub version: u16,
    pub format: u16,
    pub width: u32,
    pub height: u32,
    pub frame_id: u64,
    pub capture_ns: u64,
    pub offset: u64,
    pub length: u64,
}

impl FrameHeader {
    /// A header for a payload at offset 0 of the shared memory.
    pub fn new(
        format: PixelFormat,
        width: usize,
        height: usize,
        frame_id: u64,
        capture_ns: u64,
    ) -> Self {
        Self {
            version: VERSION,
            format: format.code(),
            width: width as u32,
            height: height as u32,
            frame_id,
            capture_ns,
            offset: 0,
            length: (width * height * format.bytes_per_pixel()) as u64,
        }
    }

    pub fn to_bytes(&self) -> [u8; HEADER_LEN] {
        let mut b = [0u8; HEADER_LEN];
        self.write(&mut b);
        b
    }

    /// Parses a header; `Err` names what is wrong (the frame id, if
    /// readable, is in the header's usual place).
    pub fn parse(b: &[u8; HEADER_LEN]) -> Result<Self, Malformed> {
        Self::read(b, VERSION)
    }

    /// Writes the header into bytes 0–47 of `b`: the magic, the version,
    /// the payload's format and size, the frame's id and capture time, and
    /// where the payload lies in the shared memory (a version 2 header
    /// begins with the same fields).
    pub(crate) fn write(&self, b: &mut [u8]) {
        let mut w = LeMut(b);
        w.bytes(0, &FRAME_MAGIC);
        w.u16(4, self.version);
        w.u16(6, self.format);
        w.u32(8, self.width);
        w.u32(12, self.height);
        w.u64(16, self.frame_id);
        w.u64(24, self.capture_ns);
        w.u64(32, self.offset);
        w.u64(40, self.length);
    }

    /// The header in bytes 0–47 of `b`, which must carry the frame magic
    /// and `version`.
    pub(crate) fn read(b: &[u8], version: u16) -> Result<Self, Malformed> {
        if b[0..4] != FRAME_MAGIC {
            return Err(Malformed(format!(
                "bad magic {:?} (expected \"NEDF\")",
                &b[0..4]
            )));
        }
        let r = Le(b);
        if r.u16(4) != version {
            return Err(Malformed(format!(
                "protocol version {} on a version {version} connection",
                r.u16(4)
            )));
        }
        Ok(Self {
            version,
            format: r.u16(6),
            width: r.u32(8),
            height: r.u32(12),
            frame_id: r.u64(16),
            capture_ns: r.u64(24),
            offset: r.u64(32),
            length: r.u64(40),
        })
    }

    /// The id field, readable even from a malformed header.
    pub fn id_of(b: &[u8; HEADER_LEN]) -> u64 {
        Le(b).u64(16)
    }
}

/// A reply from the service.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reply {
    pub status: u32,
    pub frame_id: u64,
    pub panel_width: u32,
    pub panel_height: u32,
    pub message: String,
}

impl Reply {
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut b = self.head().to_vec();
        b.extend_from_slice(self.message.as_bytes());
        b
    }

    /// The fixed part, magic to message length (version 2 puts its timing
    /// between it and the message).
    pub(crate) fn head(&self) -> [u8; REPLY_LEN] {
        let mut b = [0u8; REPLY_LEN];
        let mut w = LeMut(&mut b);
        w.bytes(0, &REPLY_MAGIC);
        w.u32(4, self.status);
        w.u64(8, self.frame_id);
        w.u32(16, self.panel_width);
        w.u32(20, self.panel_height);
        w.u32(24, self.message.len() as u32);
        b
    }

    /// Parses the fixed part: the reply without its message, and the
    /// message's length (at most 64 KiB).
    pub(crate) fn parse_head(b: &[u8; REPLY_LEN]) -> std::io::Result<(Self, usize)> {
        let bad = |m: &str| std::io::Error::new(std::io::ErrorKind::InvalidData, m.to_string());
        if b[0..4] != REPLY_MAGIC {
            return Err(bad("reply with a bad magic"));
        }
        let r = Le(b);
        let len = r.u32(24) as usize;
        if len > 64 * 1024 {
            return Err(bad("reply message over 64 KiB"));
        }
        let reply = Self {
            status: r.u32(4),
            frame_id: r.u64(8),
            panel_width: r.u32(16),
            panel_height: r.u32(20),
            message: String::new(),
        };
        Ok((reply, len))
    }

    /// Reads the `len`-byte message that ends a reply.
    pub(crate) fn read_message(&mut self, r: &mut impl Read, len: usize) -> std::io::Result<()> {
        let mut msg = vec![0u8; len];
        r.read_exact(&mut msg)?;
        self.message = String::from_utf8_lossy(&msg).into_owned();
        Ok(())
    }

    /// Reads one reply from `r`.
    pub fn read_from(r: &mut impl Read) -> std::io::Result<Self> {
        let mut b = [0u8; REPLY_LEN];
        r.read_exact(&mut b)?;
        let (mut reply, len) = Self::parse_head(&b)?;
        reply.read_message(r, len)?;
        Ok(reply)
    }
}

/// Whether `name` may name a shared-memory object: one path component of
/// letters, digits, '.', '_', '-', not starting with '.'.
pub fn valid_shm_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= MAX_NAME
        && !name.starts_with('.')
        && name
            .bytes()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, b'.' | b'_' | b'-'))
}

/// The default folder of shared-memory objects.
pub const DEFAULT_SHM_DIR: &str = "/dev/shm";

/// A connection to the service.
#[derive(Debug)]
pub struct Client {
    stream: UnixStream,
    shm: std::fs::File,
    shm_size: u64,
    /// The panel's resolution, from the service's welcome.
    pub panel: (usize, usize),
    /// The protocol version of the connection (1 or 2).
    pub version: u16,
    /// Version 2: the last reply's prediction of when a frame submitted
    /// now is shown, the refresh period, and the views the service runs.
    pub timing: Option<v2::ReplyV2>,
    /// Version 2: where each view lies on the panel (x, y, width, height),
    /// from the welcome.
    pub views: Vec<[usize; 4]>,
    /// Version 2: the eyepiece's pixels per unit of tan(angle), from the
    /// welcome (`None` from a service that does not say).
    pub pixels_per_tan: Option<f64>,
}

impl Client {
    /// Connects, creating a private shared-memory object of `shm_size`
    /// bytes in `shm_dir`; the object's name is removed once the service
    /// has opened it, so nothing is left behind however either side ends.
    pub fn connect(socket: &Path, shm_dir: &Path, shm_size: u64) -> std::io::Result<Self> {
        Self::connect_version(socket, shm_dir, shm_size, VERSION)
    }

    /// As [`Client::connect`], speaking protocol version 2: layers, views,
    /// and the pacer's timing in every reply.
    pub fn connect_v2(socket: &Path, shm_dir: &Path, shm_size: u64) -> std::io::Result<Self> {
        Self::connect_version(socket, shm_dir, shm_size, v2::VERSION_2)
    }

    fn connect_version(
        socket: &Path,
        shm_dir: &Path,
        shm_size: u64,
        version: u16,
    ) -> std::io::Result<Self> {
        use v2::{ReplyV2, VERSION_2};
        let stream = UnixStream::connect(socket)
            .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", socket.display())))?;
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let name = format!("nedrt-{}-{nanos}", std::process::id());
        let path: PathBuf = shm_dir.join(&name);
        let shm = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .mode(0o600)
            .open(&path)?;
        let result = (|| -> std::io::Result<(Reply, Option<ReplyV2>)> {
            shm.set_len(shm_size)?;
            let mut hello = Hello {
                name_len: name.len(),
                shm_size,
            }
            .to_bytes_version(version)
            .to_vec();
            hello.extend_from_slice(name.as_bytes());
            (&stream).write_all(&hello)?;
            // A refused hello is answered in version 1's reply: the
            // service may not have understood which version was asked for.
            let mut first = [0u8; REPLY_LEN];
            (&stream).read_exact(&mut first)?;
            let (reply, len) = Reply::parse_head(&first)?;
            if version == VERSION_2 && reply.status == STATUS_OK {
                let w = ReplyV2::read_after_head(&mut &stream, reply, len)?;
                Ok((w.reply.clone(), Some(w)))
            } else {
                let mut reply = reply;
                reply.read_message(&mut &stream, len)?;
                Ok((reply, None))
            }
        })();
        let _ = std::fs::remove_file(&path);
        let (welcome, timing) = result?;
        if welcome.status != STATUS_OK {
            return Err(std::io::Error::new(
                std::io::ErrorKind::ConnectionRefused,
                format!("service refused the connection: {}", welcome.message),
            ));
        }
        Ok(Self {
            stream,
            shm,
            shm_size,
            panel: (welcome.panel_width as usize, welcome.panel_height as usize),
            views: v2::view_regions(&welcome.message),
            pixels_per_tan: v2::pixels_per_tan(&welcome.message),
            version,
            timing,
        })
    }

    /// Version 2: writes `payload` at the header's offset, sends the
    /// header and waits for the reply (its timing is kept in
    /// [`Client::timing`]).
    pub fn send_v2(
        &mut self,
        header: &v2::HeaderV2,
        payload: &[u8],
    ) -> std::io::Result<v2::ReplyV2> {
        let end = header.offset.checked_add(payload.len() as u64);
        if end.is_none_or(|e| e > self.shm_size) {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "{} payload bytes at {} for {} of shared memory",
                    payload.len(),
                    header.offset,
                    self.shm_size
                ),
            ));
        }
        self.shm.write_all_at(payload, header.offset)?;
        self.stream.write_all(&header.to_bytes())?;
        let reply = v2::ReplyV2::read_from(&mut self.stream)?;
        self.timing = Some(reply.clone());
        Ok(reply)
    }

    /// Writes `payload` at offset 0 of the shared memory, sends `header`
    /// and waits for the reply.
    pub fn send(&mut self, header: &FrameHeader, payload: &[u8]) -> std::io::Result<Reply> {
        if payload.len() as u64 > self.shm_size {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "{} payload bytes for {} of shared memory",
                    payload.len(),
                    self.shm_size
                ),
            ));
        }
        self.shm.write_all_at(payload, 0)?;
        self.send_header_bytes(&header.to_bytes())
    }

    /// Sends raw header bytes (any, for fault tests) and waits for the reply.
    pub fn send_header_bytes(&mut self, header: &[u8]) -> std::io::Result<Reply> {
        self.stream.write_all(header)?;
        Reply::read_from(&mut self.stream)
    }

    /// The socket, for tests that misbehave on purpose.
    pub fn stream(&mut self) -> &mut UnixStream {
        &mut self.stream
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn headers_round_trip(format in 0u16..8, w in any::<u32>(), h in any::<u32>(), id in any::<u64>(),
                              t in any::<u64>(), off in any::<u64>(), len in any::<u64>()) {
            let header = FrameHeader { version: VERSION, format, width: w, height: h, frame_id: id,
                                       capture_ns: t, offset: off, length: len };
            prop_assert_eq!(FrameHeader::parse(&header.to_bytes()), Ok(header));
        }

        #[test]
        fn any_bytes_parse_or_fail_cleanly(bytes in proptest::collection::vec(any::<u8>(), HEADER_LEN)) {
            let mut b = [0u8; HEADER_LEN];
            b.copy_from_slice(&bytes);
            let _ = FrameHeader::parse(&b);
            let _ = FrameHeader::id_of(&b);
            let _ = Reply::read_from(&mut bytes.as_slice());
        }

        #[test]
        fn replies_round_trip(status in any::<u32>(), id in any::<u64>(), msg in ".{0,40}") {
            let r = Reply { status, frame_id: id, panel_width: 64, panel_height: 48, message: msg };
            prop_assert_eq!(Reply::read_from(&mut r.to_bytes().as_slice()).ok(), Some(r));
        }
    }

    #[test]
    fn bad_magic_and_version_are_named() {
        let mut b = FrameHeader::new(PixelFormat::Rgba8Linear, 4, 4, 9, 0).to_bytes();
        b[4] = 7;
        assert!(FrameHeader::parse(&b).unwrap_err().0.contains("version 7"));
        b[0] = b'X';
        assert!(FrameHeader::parse(&b).unwrap_err().0.contains("magic"));
        assert_eq!(FrameHeader::id_of(&b), 9);
        assert!(valid_shm_name("nedrt-12-34"));
        for bad in ["", ".hidden", "a/b", "../x", "a b"] {
            assert!(!valid_shm_name(bad), "{bad}");
        }
    }
}
