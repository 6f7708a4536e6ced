//! Protocol version 2 (docs/protocol.md §6): a submission names its view
//! and its layer — the view's projection layer, a quad layer with its
//! placement and z-order, or the removal of a quad — and every reply
//! carries the refresh a frame submitted now is predicted to be shown at
//! and the refresh period, so a client renders for the time its frame is
//! seen. The hello and the shared memory are version 1's; a connection
//! speaks the version of its hello. Version 1 is served unchanged.

use std::io::Read;

use super::codec::{Le, LeMut};
use super::{FrameHeader, Malformed, REPLY_LEN, Reply};
use super::{PixelFormat, Placement};

pub const VERSION_2: u16 = 2;

/// The view byte of a panel-sized projection frame for every view.
pub const ALL_VIEWS: u8 = 255;
/// Submission header: version 1's 48 bytes, then kind u8, view u8,
/// placement u8, reserved u8, layer u32, z i32, x, y (i32 pixels or f32
/// degrees), reserved u32.
pub const HEADER_V2_LEN: usize = 72;
/// Reply: version 1's 28 bytes, then predicted display time u64, refresh
/// period u64, views u16, reserved u16; the message follows.
pub const REPLY_V2_LEN: usize = 48;
/// Reply status of a refused quad layer (outside the view, colour over
/// alpha, too many, …); frames keep version 1's codes (and 7, unknown view).
pub const STATUS_BAD_LAYER: u32 = 8;

/// Quad texels: premultiplied linear RGBA.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QuadFormat {
    /// 8-bit, value/255 (format code 4).
    Rgba8Premultiplied,
    /// 32-bit float, interleaved (format code 5).
    Rgba32fPremultiplied,
}

impl QuadFormat {
    pub fn from_code(code: u16) -> Option<Self> {
        match code {
            4 => Some(Self::Rgba8Premultiplied),
            5 => Some(Self::Rgba32fPremultiplied),
            _ => None,
        }
    }

    pub fn code(self) -> u16 {
        match self {
            Self::Rgba8Premultiplied => 4,
            Self::Rgba32fPremultiplied => 5,
        }
    }

    pub fn bytes_per_texel(self) -> usize {
        match self {
            Self::Rgba8Premultiplied => 4,
            Self::Rgba32fPremultiplied => 16,
        }
    }

    /// The texels as f32 RGBA (`payload` of the right length).
    pub fn decode(self, payload: &[u8]) -> Vec<f32> {
        match self {
            Self::Rgba8Premultiplied => payload.iter().map(|&b| f32::from(b) / 255.0).collect(),
            Self::Rgba32fPremultiplied => payload
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
        }
    }
}

/// What a submission does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Layer {
    /// The view's projection layer: a frame of the view's size (pixel
    /// formats 1–3, as version 1).
    Projection,
    /// A quad layer (formats 4–5): set, or replace the client's layer of
    /// that id.
    Quad {
        layer: u32,
        z: i32,
        placement: Placement,
    },
    /// Removes the client's quad layer of that id (no payload).
    Remove { layer: u32 },
}

/// A version 2 submission header.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeaderV2 {
    pub format: u16,
    pub width: u32,
    pub height: u32,
    pub frame_id: u64,
    pub capture_ns: u64,
    pub offset: u64,
    pub length: u64,
    pub view: u8,
    pub layer: Layer,
    /// A projection layer's display time: the refresh it was rendered for
    /// (an OpenXR frame's `displayTime`), CLOCK_MONOTONIC ns; 0 for none
    /// (the service predicts as it takes the frame). Bytes 60–67 of a
    /// projection; quads and removals have none.
    pub display_ns: u64,
}

impl HeaderV2 {
    /// This projection frame, rendered for the refresh at `display_ns`.
    pub fn for_display(self, display_ns: u64) -> Self {
        Self { display_ns, ..self }
    }

    /// A projection frame for `view`, its payload at offset 0.
    pub fn projection(
        view: u8,
        format: PixelFormat,
        (width, height): (usize, usize),
        frame_id: u64,
        capture_ns: u64,
    ) -> Self {
        Self {
            format: format.code(),
            width: width as u32,
            height: height as u32,
            frame_id,
            capture_ns,
            offset: 0,
            length: (width * height * format.bytes_per_pixel()) as u64,
            view,
            layer: Layer::Projection,
            display_ns: 0,
        }
    }

    /// A quad layer on `view`, its texels at `offset`.
    #[allow(clippy::too_many_arguments)]
    pub fn quad(
        view: u8,
        layer: u32,
        z: i32,
        placement: Placement,
        format: QuadFormat,
        (width, height): (usize, usize),
        frame_id: u64,
        offset: u64,
    ) -> Self {
        Self {
            format: format.code(),
            width: width as u32,
            height: height as u32,
            frame_id,
            capture_ns: 0,
            offset,
            length: (width * height * format.bytes_per_texel()) as u64,
            view,
            layer: Layer::Quad {
                layer,
                z,
                placement,
            },
            display_ns: 0,
        }
    }

    /// Removes quad `layer` from `view`.
    pub fn remove(view: u8, layer: u32, frame_id: u64) -> Self {
        Self {
            format: 0,
            width: 0,
            height: 0,
            frame_id,
            capture_ns: 0,
            offset: 0,
            length: 0,
            view,
            layer: Layer::Remove { layer },
            display_ns: 0,
        }
    }

    pub fn to_bytes(&self) -> [u8; HEADER_V2_LEN] {
        let mut b = [0u8; HEADER_V2_LEN];
        FrameHeader {
            version: VERSION_2,
            format: self.format,
            width: self.width,
            height: self.height,
            frame_id: self.frame_id,
            capture_ns: self.capture_ns,
            offset: self.offset,
            length: self.length,
        }
        .write(&mut b);
        let mut w = LeMut(&mut b);
        w.bytes(49, &[self.view]);
        let (kind, placement, layer, z) = match self.layer {
            Layer::Projection => {
                w.u64(60, self.display_ns);
                (0u8, 0u8, 0u32, 0i32)
            }
            Layer::Quad {
                layer,
                z,
                placement,
            } => match placement {
                Placement::Pixels { x, y } => {
                    w.i32(60, x.clamp(i32::MIN.into(), i32::MAX.into()) as i32);
                    w.i32(64, y.clamp(i32::MIN.into(), i32::MAX.into()) as i32);
                    (1, 0, layer, z)
                }
                Placement::Degrees { x_deg, y_deg } => {
                    w.f32(60, x_deg as f32);
                    w.f32(64, y_deg as f32);
                    (1, 1, layer, z)
                }
            },
            Layer::Remove { layer } => (2, 0, layer, 0),
        };
        w.bytes(48, &[kind]);
        w.bytes(50, &[placement]);
        w.u32(52, layer);
        w.i32(56, z);
        b
    }

    /// Parses a header; `Err` names what is wrong.
    pub fn parse(b: &[u8; HEADER_V2_LEN]) -> Result<Self, Malformed> {
        let f = FrameHeader::read(b, VERSION_2)?;
        let r = Le(b);
        if b[51] != 0 || r.u32(68) != 0 {
            return Err(Malformed("reserved bytes 51 and 68–71 must be 0".into()));
        }
        let (layer, z) = (r.u32(52), r.i32(56));
        let layer = match (b[48], b[50]) {
            (0, 0) if layer == 0 && z == 0 => Layer::Projection,
            (0, _) => {
                return Err(Malformed(
                    "a projection layer has no placement, layer id or z (bytes 50, 52–59 must be 0)"
                        .into(),
                ));
            }
            (1, 0) => Layer::Quad {
                layer,
                z,
                placement: Placement::Pixels {
                    x: i64::from(r.i32(60)),
                    y: i64::from(r.i32(64)),
                },
            },
            (1, 1) => {
                let (x_deg, y_deg) = (r.f32(60), r.f32(64));
                if !(x_deg.is_finite() && y_deg.is_finite()) {
                    return Err(Malformed(format!(
                        "placement ({x_deg}°, {y_deg}°) is not finite"
                    )));
                }
                Layer::Quad {
                    layer,
                    z,
                    placement: Placement::Degrees {
                        x_deg: f64::from(x_deg),
                        y_deg: f64::from(y_deg),
                    },
                }
            }
            (1, p) => {
                return Err(Malformed(format!(
                    "placement kind {p} (0 pixels, 1 degrees)"
                )));
            }
            (2, 0)
                if z == 0
                    && r.u64(60) == 0
                    && f.format == 0
                    && r.u64(8) == 0
                    && f.offset == 0
                    && f.length == 0 =>
            {
                Layer::Remove { layer }
            }
            (2, _) => {
                return Err(Malformed(
                    "a removal has only a layer id (format, size, payload, placement, z, x, y must be 0)"
                        .into(),
                ));
            }
            (k, _) => {
                return Err(Malformed(format!(
                    "layer kind {k} (0 projection, 1 quad, 2 remove a quad)"
                )));
            }
        };
        Ok(Self {
            format: f.format,
            width: f.width,
            height: f.height,
            frame_id: f.frame_id,
            capture_ns: f.capture_ns,
            offset: f.offset,
            length: f.length,
            view: b[49],
            display_ns: if layer == Layer::Projection {
                r.u64(60)
            } else {
                0
            },
            layer,
        })
    }
}

/// The welcome's message: the panel, where each view lies on it, and the
/// eyepiece's pixels per unit of tan(angle) (a pixel subtends pitch over
/// the lens distance, so an OpenXR runtime can give each view its field of
/// view), `panel 64×48; view 0 at 0,0 32×48; view 1 at 32,0 32×48; pixels
/// per tan 3283.908` (read back by [`view_regions`] and [`pixels_per_tan`]).
pub fn welcome_message(
    (w, h): (usize, usize),
    regions: &[[usize; 4]],
    pixels_per_tan: f64,
) -> String {
    let mut s = format!("panel {w}×{h}");
    for (v, [x, y, vw, vh]) in regions.iter().enumerate() {
        s += &format!("; view {v} at {x},{y} {vw}×{vh}");
    }
    s + &format!("; pixels per tan {pixels_per_tan:.3}")
}

/// The eyepiece's pixels per unit of tan(angle) of a welcome's message
/// ([`welcome_message`]); `None` from a service that does not say (older,
/// or a positive finite number is not there).
pub fn pixels_per_tan(message: &str) -> Option<f64> {
    message
        .split("; ")
        .find_map(|part| part.strip_prefix("pixels per tan ")?.parse::<f64>().ok())
        .filter(|p| p.is_finite() && *p > 0.0)
}

/// The views of a welcome's message ([`welcome_message`]): x, y, width,
/// height of each, in view order; empty if it names none.
pub fn view_regions(message: &str) -> Vec<[usize; 4]> {
    message
        .split("; ")
        .filter_map(|part| {
            let rest = part.strip_prefix("view ")?;
            let (_, rest) = rest.split_once(" at ")?;
            let (xy, size) = rest.split_once(' ')?;
            let (x, y) = xy.split_once(',')?;
            let (w, h) = size.split_once('×')?;
            Some([
                x.parse().ok()?,
                y.parse().ok()?,
                w.parse().ok()?,
                h.parse().ok()?,
            ])
        })
        .collect()
}

/// A version 2 reply: version 1's reply and the pacer's timing.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReplyV2 {
    pub reply: Reply,
    /// The refresh a frame submitted now is predicted to be shown at,
    /// CLOCK_MONOTONIC ns.
    pub predicted_display_ns: u64,
    pub refresh_period_ns: u64,
    /// Views the service runs (1: mono).
    pub views: u16,
}

impl ReplyV2 {
    pub fn to_bytes(&self) -> Vec<u8> {
        let msg = self.reply.message.as_bytes();
        let mut b = Vec::with_capacity(REPLY_V2_LEN + msg.len());
        b.extend_from_slice(&self.reply.head());
        let mut timing = [0u8; REPLY_V2_LEN - REPLY_LEN];
        let mut w = LeMut(&mut timing);
        w.u64(0, self.predicted_display_ns);
        w.u64(8, self.refresh_period_ns);
        w.u16(16, self.views);
        b.extend_from_slice(&timing);
        b.extend_from_slice(msg);
        b
    }

    /// Reads one version 2 reply from `r`.
    pub fn read_from(r: &mut impl Read) -> std::io::Result<Self> {
        let mut head = [0u8; REPLY_LEN];
        r.read_exact(&mut head)?;
        let (reply, len) = Reply::parse_head(&head)?;
        Self::read_after_head(r, reply, len)
    }

    /// The rest of a version 2 reply whose fixed part (version 1's) was
    /// read: the timing, then the `len`-byte message.
    pub(super) fn read_after_head(
        r: &mut impl Read,
        mut reply: Reply,
        len: usize,
    ) -> std::io::Result<Self> {
        let mut t = [0u8; REPLY_V2_LEN - REPLY_LEN];
        r.read_exact(&mut t)?;
        reply.read_message(r, len)?;
        let t = Le(&t);
        Ok(Self {
            reply,
            predicted_display_ns: t.u64(0),
            refresh_period_ns: t.u64(8),
            views: t.u16(16),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn placement() -> impl Strategy<Value = Placement> {
        prop_oneof![
            (any::<i32>(), any::<i32>()).prop_map(|(x, y)| Placement::Pixels {
                x: x.into(),
                y: y.into()
            }),
            (-90.0f32..90.0, -90.0f32..90.0).prop_map(|(x, y)| Placement::Degrees {
                x_deg: x.into(),
                y_deg: y.into()
            }),
        ]
    }

    fn layer() -> impl Strategy<Value = Layer> {
        prop_oneof![
            Just(Layer::Projection),
            (any::<u32>(), any::<i32>(), placement()).prop_map(|(layer, z, placement)| {
                Layer::Quad {
                    layer,
                    z,
                    placement,
                }
            }),
            any::<u32>().prop_map(|layer| Layer::Remove { layer }),
        ]
    }

    proptest! {
        #[test]
        fn headers_round_trip(format in 0u16..8, w in any::<u32>(), h in any::<u32>(),
                              id in any::<u64>(), t in any::<u64>(), off in any::<u64>(),
                              len in any::<u64>(), view in any::<u8>(), layer in layer()) {
            let header = match layer {
                // A removal carries only its layer id.
                Layer::Remove { layer } => HeaderV2::remove(view, layer, id),
                Layer::Projection => HeaderV2 { format, width: w, height: h, frame_id: id,
                                capture_ns: t, offset: off, length: len, view, layer,
                                display_ns: t.rotate_left(7) },
                _ => HeaderV2 { format, width: w, height: h, frame_id: id, capture_ns: t,
                                offset: off, length: len, view, layer, display_ns: 0 },
            };
            prop_assert_eq!(HeaderV2::parse(&header.to_bytes()), Ok(header));
        }

        #[test]
        fn any_bytes_parse_or_fail_cleanly(bytes in proptest::collection::vec(any::<u8>(), HEADER_V2_LEN)) {
            let mut b = [0u8; HEADER_V2_LEN];
            b.copy_from_slice(&bytes);
            let _ = HeaderV2::parse(&b);
            let _ = ReplyV2::read_from(&mut bytes.as_slice());
        }

        #[test]
        fn replies_round_trip(status in any::<u32>(), id in any::<u64>(), msg in ".{0,40}",
                              at in any::<u64>(), period in any::<u64>(), views in 1u16..3) {
            let r = ReplyV2 {
                reply: Reply { status, frame_id: id, panel_width: 64, panel_height: 48, message: msg },
                predicted_display_ns: at, refresh_period_ns: period, views,
            };
            prop_assert_eq!(ReplyV2::read_from(&mut r.to_bytes().as_slice()).ok(), Some(r));
        }
    }

    #[test]
    fn the_welcome_names_each_view_and_reads_back() {
        let regions = [[0, 0, 32, 48], [32, 0, 32, 48]];
        let m = welcome_message((64, 48), &regions, 3283.9080459);
        assert_eq!(
            m,
            "panel 64×48; view 0 at 0,0 32×48; view 1 at 32,0 32×48; pixels per tan 3283.908"
        );
        assert_eq!(view_regions(&m), regions.to_vec());
        assert_eq!(pixels_per_tan(&m), Some(3283.908));
        assert!(view_regions("panel 64×48").is_empty());
        // An older service's welcome, or a value that is no geometry.
        assert_eq!(pixels_per_tan("panel 64×48; view 0 at 0,0 64×48"), None);
        assert_eq!(pixels_per_tan("panel 1×1; pixels per tan -2"), None);
        assert_eq!(pixels_per_tan("panel 1×1; pixels per tan NaN"), None);
    }

    #[test]
    fn bad_kinds_placements_and_reserved_bytes_are_named() {
        let good = HeaderV2::quad(
            0,
            3,
            1,
            Placement::Pixels { x: 1, y: 2 },
            QuadFormat::Rgba8Premultiplied,
            (2, 2),
            9,
            0,
        )
        .to_bytes();
        let with = |i: usize, v: u8| {
            let mut b = good;
            b[i] = v;
            HeaderV2::parse(&b).expect_err("refused").0
        };
        assert!(with(48, 3).contains("layer kind 3"));
        assert!(with(50, 2).contains("placement kind 2"));
        assert!(with(51, 1).contains("reserved"));
        assert!(with(4, 1).contains("version 1 on a version 2"));
        let mut removal = HeaderV2::remove(0, 3, 9).to_bytes();
        removal[40] = 1;
        assert!(
            HeaderV2::parse(&removal)
                .expect_err("a payload")
                .0
                .contains("only a layer id")
        );
        let mut projection =
            HeaderV2::projection(0, PixelFormat::Rgba8Linear, (2, 2), 1, 0).to_bytes();
        projection[56] = 1;
        assert!(
            HeaderV2::parse(&projection)
                .expect_err("z on a projection")
                .0
                .contains("no placement")
        );
        let mut degrees = HeaderV2::quad(
            0,
            3,
            1,
            Placement::Degrees {
                x_deg: 1.0,
                y_deg: 0.0,
            },
            QuadFormat::Rgba8Premultiplied,
            (2, 2),
            9,
            0,
        )
        .to_bytes();
        degrees[60..64].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(
            HeaderV2::parse(&degrees)
                .expect_err("nan")
                .0
                .contains("not finite")
        );
        assert_eq!(
            QuadFormat::Rgba32fPremultiplied.decode(&0.5f32.to_le_bytes()),
            vec![0.5]
        );
        assert_eq!(
            QuadFormat::Rgba8Premultiplied.decode(&[255, 0]),
            vec![1.0, 0.0]
        );
    }
}
