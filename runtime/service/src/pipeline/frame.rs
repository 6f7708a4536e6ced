//! Frames as applications submit them: a pixel format, a payload, and the
//! checks every frame passes before it enters the pipeline (size, payload
//! length, finite values in [0, 1]). A rejected frame gets a
//! [`FrameError`] with a [`RejectReason`] the service counts and the
//! socket protocol replies with. Decoding to the D-CNN's planar linear
//! input is the upload stage's work ([`decode`]).

use nedrt_core::Image;

pub use nedrt_protocol::PixelFormat;

/// One frame from an application.
#[derive(Debug, Clone, PartialEq)]
pub struct SubmittedFrame {
    /// The application's frame number (echoed in replies and recordings).
    pub id: u64,
    /// When the application captured/rendered it, CLOCK_MONOTONIC ns
    /// (0: unknown; latency is then counted from submission).
    pub capture_ns: u64,
    pub width: usize,
    pub height: usize,
    pub format: PixelFormat,
    pub payload: Vec<u8>,
}

/// Why a frame was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RejectReason {
    /// Unreadable header, unknown magic or version.
    Malformed,
    /// A pixel format the service does not know.
    UnsupportedFormat,
    /// Payload shorter than width × height × bytes per pixel, or outside
    /// the shared memory.
    Truncated,
    /// Not the panel's resolution.
    WrongSize,
    /// NaN or infinity in a float frame.
    NonFinite,
    /// A float value outside the panel's [0, 1].
    OutOfRange,
    /// A view the service does not run (protocol v2: view 1 of a mono
    /// service).
    UnknownView,
}

impl RejectReason {
    pub const ALL: [RejectReason; 7] = [
        Self::Malformed,
        Self::UnsupportedFormat,
        Self::Truncated,
        Self::WrongSize,
        Self::NonFinite,
        Self::OutOfRange,
        Self::UnknownView,
    ];

    /// Status code in the socket protocol's reply (0 is "accepted").
    pub fn code(self) -> u32 {
        match self {
            Self::Malformed => 1,
            Self::UnsupportedFormat => 2,
            Self::Truncated => 3,
            Self::WrongSize => 4,
            Self::NonFinite => 5,
            Self::OutOfRange => 6,
            Self::UnknownView => 7,
        }
    }

    pub fn from_code(code: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|r| r.code() == code)
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Malformed => "malformed",
            Self::UnsupportedFormat => "unsupported-format",
            Self::Truncated => "truncated",
            Self::WrongSize => "wrong-size",
            Self::NonFinite => "non-finite",
            Self::OutOfRange => "out-of-range",
            Self::UnknownView => "unknown-view",
        }
    }

    pub fn index(self) -> usize {
        Self::ALL.iter().position(|&r| r == self).unwrap_or(0)
    }
}

/// A refused frame: the reason (counted) and what exactly was wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("frame {id} rejected ({}): {detail}", reason.name())]
pub struct FrameError {
    pub id: u64,
    pub reason: RejectReason,
    pub detail: String,
}

/// Checks a frame's size and payload length against a `width`×`height`
/// panel, before any payload is read (the socket source checks headers
/// with this).
pub fn check_shape(
    id: u64,
    (frame_w, frame_h): (usize, usize),
    format: PixelFormat,
    payload_len: u64,
    (width, height): (usize, usize),
) -> Result<(), FrameError> {
    let fail = |reason, detail: String| FrameError { id, reason, detail };
    if (frame_w, frame_h) != (width, height) {
        return Err(fail(
            RejectReason::WrongSize,
            format!("{frame_w}×{frame_h} frame for a {width}×{height} panel"),
        ));
    }
    let need = width * height * format.bytes_per_pixel();
    if payload_len != need as u64 {
        return Err(fail(
            RejectReason::Truncated,
            format!("{payload_len} payload bytes, {need} needed for {width}×{height} {format:?}"),
        ));
    }
    Ok(())
}

/// Checks `frame` against a `width`×`height` panel.
pub fn validate(frame: &SubmittedFrame, width: usize, height: usize) -> Result<(), FrameError> {
    let fail = |reason, detail: String| FrameError {
        id: frame.id,
        reason,
        detail,
    };
    check_shape(
        frame.id,
        (frame.width, frame.height),
        frame.format,
        frame.payload.len() as u64,
        (width, height),
    )?;
    if frame.format == PixelFormat::Rgb32fPlanar {
        for (i, b) in frame.payload.chunks_exact(4).enumerate() {
            let v = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            if (0.0..=1.0).contains(&v) {
                continue;
            }
            // Only a bad value pays for its message (a float frame holds millions).
            let (c, px) = (i / (width * height), i % (width * height));
            let at = format!("pixel {},{} channel {c}", px % width, px / width);
            if !v.is_finite() {
                return Err(fail(RejectReason::NonFinite, format!("{at} is {v}")));
            }
            return Err(fail(
                RejectReason::OutOfRange,
                format!("{at} is {v}; display intensities lie in [0, 1]"),
            ));
        }
    }
    Ok(())
}

/// The sRGB decoding function (IEC 61966-2-1), code value → linear.
fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// The linear intensity of each 8-bit code: code/255, or its sRGB
/// decode. The host decode and the device's unpack both read this table,
/// so they agree bit for bit.
pub fn code_lut(srgb: bool) -> [f32; 256] {
    std::array::from_fn(|v| {
        let x = v as f32 / 255.0;
        if srgb { srgb_to_linear(x) } else { x }
    })
}

/// Decodes a validated frame to the D-CNN's planar linear input.
pub fn decode(frame: &SubmittedFrame) -> Image {
    let n = frame.width * frame.height;
    let mut data = vec![0f32; 3 * n];
    match frame.format {
        PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb => {
            let lut = code_lut(frame.format == PixelFormat::Rgba8Srgb);
            for (i, px) in frame.payload.chunks_exact(4).enumerate() {
                for c in 0..3 {
                    data[c * n + i] = lut[px[c] as usize];
                }
            }
        }
        PixelFormat::Rgb32fPlanar => {
            for (v, b) in data.iter_mut().zip(frame.payload.chunks_exact(4)) {
                *v = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            }
        }
    }
    Image::rgb(frame.width, frame.height, data)
}

/// A planar linear frame as an `Rgb32fPlanar` payload.
pub fn planar_payload(frame: &Image) -> Vec<u8> {
    frame.data().iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// A view's newest frame as it goes to its engine: as the client sent it
/// (uploaded as it came and unpacked on the device, its quads blended
/// there), or planes a host stage made (quads already blended).
#[derive(Debug, Clone)]
pub enum ViewContent {
    Client(std::sync::Arc<SubmittedFrame>),
    Planar(std::sync::Arc<Image>),
}

impl ViewContent {
    /// Width and height.
    pub fn size(&self) -> (usize, usize) {
        match self {
            Self::Client(f) => (f.width, f.height),
            Self::Planar(im) => (im.width, im.height),
        }
    }
}

/// A view's newest content and a number that changes with it (0: the view
/// has had no frame yet; it is black).
#[derive(Debug, Clone)]
pub struct ViewFrame {
    pub generation: u64,
    pub content: ViewContent,
}

/// The `width`×`height` part of a validated frame at (`left`, `top`), in
/// its own format (a panel-sized frame cut into its views).
pub fn crop(
    frame: &SubmittedFrame,
    (left, top): (usize, usize),
    (width, height): (usize, usize),
) -> SubmittedFrame {
    debug_assert!(left + width <= frame.width && top + height <= frame.height);
    let mut payload = Vec::with_capacity(width * height * frame.format.bytes_per_pixel());
    match frame.format {
        PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb => {
            for row in top..top + height {
                let start = 4 * (row * frame.width + left);
                payload.extend_from_slice(&frame.payload[start..start + 4 * width]);
            }
        }
        // Three planes of little-endian f32, each cut alike.
        PixelFormat::Rgb32fPlanar => {
            let plane = 4 * frame.width * frame.height;
            for c in 0..3 {
                for row in top..top + height {
                    let start = c * plane + 4 * (row * frame.width + left);
                    payload.extend_from_slice(&frame.payload[start..start + 4 * width]);
                }
            }
        }
    }
    SubmittedFrame {
        id: frame.id,
        capture_ns: frame.capture_ns,
        width,
        height,
        format: frame.format,
        payload,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn float_frame(values: &[f32]) -> SubmittedFrame {
        SubmittedFrame {
            id: 7,
            capture_ns: 0,
            width: 2,
            height: 1,
            format: PixelFormat::Rgb32fPlanar,
            payload: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }

    #[test]
    fn each_fault_has_its_reason() {
        let good = float_frame(&[0.0, 0.5, 1.0, 0.25, 0.75, 0.125]);
        assert_eq!(validate(&good, 2, 1), Ok(()));
        assert_eq!(
            decode(&good).into_data(),
            vec![0.0, 0.5, 1.0, 0.25, 0.75, 0.125]
        );
        let reason = |f: &SubmittedFrame| validate(f, 2, 1).unwrap_err().reason;
        assert_eq!(reason(&float_frame(&[0.0; 5])), RejectReason::Truncated);
        let nan = float_frame(&[0.0, 0.5, 1.0, f32::NAN, 0.75, 0.125]);
        let e = validate(&nan, 2, 1).unwrap_err();
        assert_eq!(e.reason, RejectReason::NonFinite);
        assert!(e.detail.contains("pixel 1,0 channel 1"), "{e}");
        assert_eq!(
            reason(&float_frame(&[0.0, 0.5, 1.5, 0.0, 0.0, 0.0])),
            RejectReason::OutOfRange
        );
        assert_eq!(
            validate(&good, 4, 4).unwrap_err().reason,
            RejectReason::WrongSize
        );
    }

    #[test]
    fn rgba_frames_decode_linear_or_srgb() {
        let mut f = SubmittedFrame {
            id: 1,
            capture_ns: 0,
            width: 1,
            height: 1,
            format: PixelFormat::Rgba8Linear,
            payload: vec![255, 128, 0, 17],
        };
        assert_eq!(validate(&f, 1, 1), Ok(()));
        assert_eq!(decode(&f).into_data(), vec![1.0, 128.0 / 255.0, 0.0]);
        f.format = PixelFormat::Rgba8Srgb;
        let d = decode(&f).into_data();
        assert_eq!(d[0], 1.0);
        assert!((d[1] - 0.2158605).abs() < 1e-6, "{}", d[1]);
        for r in RejectReason::ALL {
            assert_eq!(RejectReason::from_code(r.code()), Some(r));
        }
        for code in 1..=3 {
            assert_eq!(PixelFormat::from_code(code).map(|f| f.code()), Some(code));
        }
        assert_eq!(PixelFormat::from_code(9), None);
    }

    #[test]
    fn a_cropped_frame_decodes_to_the_crop_of_its_decode() {
        let (w, h) = (7usize, 5usize);
        for format in [
            PixelFormat::Rgba8Linear,
            PixelFormat::Rgba8Srgb,
            PixelFormat::Rgb32fPlanar,
        ] {
            let payload = match format {
                PixelFormat::Rgb32fPlanar => (0..3 * w * h)
                    .flat_map(|i| (i as f32 / 105.0).to_le_bytes())
                    .collect(),
                _ => (0..4 * w * h).map(|i| (i * 37 % 256) as u8).collect(),
            };
            let frame = SubmittedFrame {
                id: 3,
                capture_ns: 9,
                width: w,
                height: h,
                format,
                payload,
            };
            let part = crop(&frame, (2, 1), (4, 3));
            assert_eq!((part.width, part.height, part.id), (4, 3, 3));
            assert!(validate(&part, 4, 3).is_ok(), "{format:?}");
            assert_eq!(decode(&part), decode(&frame).crop(2, 1, 4, 3), "{format:?}");
        }
    }
}
