//! The one little-endian codec both versions' messages are read and
//! written with: fixed-width fields at byte offsets ([`Le`], [`LeMut`]),
//! and the frame fields both versions' headers begin with ([`FrameFields`]).
//! Bounds are the callers': every message is a fixed-size array.

use super::{FRAME_MAGIC, Malformed};

/// Fields read from a message's bytes.
#[derive(Clone, Copy)]
pub(crate) struct Le<'a>(pub &'a [u8]);

impl Le<'_> {
    fn array<const N: usize>(&self, at: usize) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.0[at..at + N]);
        a
    }

    pub(crate) fn u16(&self, at: usize) -> u16 {
        u16::from_le_bytes(self.array(at))
    }

    pub(crate) fn u32(&self, at: usize) -> u32 {
        u32::from_le_bytes(self.array(at))
    }

    pub(crate) fn u64(&self, at: usize) -> u64 {
        u64::from_le_bytes(self.array(at))
    }

    pub(crate) fn i32(&self, at: usize) -> i32 {
        i32::from_le_bytes(self.array(at))
    }

    pub(crate) fn f32(&self, at: usize) -> f32 {
        f32::from_le_bytes(self.array(at))
    }
}

/// Fields written into a message's bytes.
pub(crate) struct LeMut<'a>(pub &'a mut [u8]);

impl LeMut<'_> {
    pub(crate) fn bytes(&mut self, at: usize, b: &[u8]) {
        self.0[at..at + b.len()].copy_from_slice(b);
    }

    pub(crate) fn u16(&mut self, at: usize, v: u16) {
        self.bytes(at, &v.to_le_bytes());
    }

    pub(crate) fn u32(&mut self, at: usize, v: u32) {
        self.bytes(at, &v.to_le_bytes());
    }

    pub(crate) fn u64(&mut self, at: usize, v: u64) {
        self.bytes(at, &v.to_le_bytes());
    }

    pub(crate) fn i32(&mut self, at: usize, v: i32) {
        self.bytes(at, &v.to_le_bytes());
    }

    pub(crate) fn f32(&mut self, at: usize, v: f32) {
        self.bytes(at, &v.to_le_bytes());
    }
}

/// Bytes 0–47 of a frame header of either version: the magic, the
/// version, the payload's format and size, the frame's id and capture
/// time, and where the payload lies in the shared memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct FrameFields {
    pub version: u16,
    pub format: u16,
    pub width: u32,
    pub height: u32,
    pub frame_id: u64,
    pub capture_ns: u64,
    pub offset: u64,
    pub length: u64,
}

impl FrameFields {
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

    /// The fields of `b`, which must carry the frame magic and `version`.
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
}
