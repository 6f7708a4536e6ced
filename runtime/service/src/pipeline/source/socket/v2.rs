//! Protocol version 2 on a connection (docs/protocol.md §6): submissions
//! name their view and layer; a projection frame goes through the
//! pipeline as version 1's frames do, a quad layer is checked, placed and
//! set for this client, a removal removes it; every reply carries the
//! pacer's prediction. [`admit`] is pure, as version 1's, so the fuzz
//! target `protocol` runs what the service runs.

use std::io::ErrorKind;
use std::os::unix::fs::FileExt;
use std::os::unix::net::UnixStream;
use std::sync::atomic::AtomicBool;

use super::{
    Admitted, Fill, FrameFields, REPLY_DEADLINE, admit_frame, outside_shm, read_full, submit_frame,
    write_all_until,
};
use crate::compose::{Placement, QuadLayer};
use crate::pipeline::frame::RejectReason;
use crate::pipeline::protocol::v2::{
    HEADER_V2_LEN, HeaderV2, Layer, QuadFormat, ReplyV2, STATUS_BAD_LAYER, welcome_message,
};
use crate::pipeline::protocol::{Reply, STATUS_OK};
use crate::pipeline::service::Compositor;

pub use nedrt_protocol::v2::ALL_VIEWS;

/// A version 2 submission the service accepted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AdmittedV2 {
    /// A projection frame for view `view` (`None`: a panel-sized frame for
    /// every view).
    Projection {
        view: Option<u8>,
        frame: Admitted,
        /// The refresh the client rendered it for (its OpenXR display
        /// time): the frame's prediction; `None`: predicted as it is taken.
        display_ns: Option<u64>,
    },
    Quad(AdmittedQuad),
    Remove {
        view: u8,
        layer: u32,
    },
}

/// A quad the service accepted: where it goes, and where its texels lie
/// in the client's shared memory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdmittedQuad {
    pub view: u8,
    pub layer: u32,
    pub z: i32,
    pub placement: Placement,
    pub format: QuadFormat,
    pub width: usize,
    pub height: usize,
    pub offset: u64,
    pub length: usize,
}

impl AdmittedQuad {
    /// The quad layer its texels (`payload`, `length` bytes) make.
    pub fn layer_of(&self, payload: &[u8]) -> QuadLayer {
        QuadLayer {
            layer: self.layer,
            z: self.z,
            placement: self.placement,
            width: self.width,
            height: self.height,
            rgba: self.format.decode(payload),
        }
    }
}

/// A version 2 submission refused: the reply's status and message, and,
/// for a frame, the reason it is counted under (a quad is counted as a
/// refused layer).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("submission {id} refused (status {status}): {detail}")]
pub struct Refusal {
    pub id: u64,
    pub status: u32,
    pub detail: String,
    pub frame: Option<RejectReason>,
}

/// Checks a version 2 header against a `panel`-sized panel whose views
/// have `view_sizes` (one view: the panel) and a `shm_size`-byte shared
/// memory, before any payload is read.
pub fn admit(
    header: &[u8; HEADER_V2_LEN],
    panel: (usize, usize),
    view_sizes: &[(usize, usize)],
    shm_size: u64,
) -> Result<AdmittedV2, Refusal> {
    let mut id_bytes = [0u8; 8];
    id_bytes.copy_from_slice(&header[16..24]);
    let id = u64::from_le_bytes(id_bytes);
    let frame = |reason: RejectReason, detail: String| Refusal {
        id,
        status: reason.code(),
        detail,
        frame: Some(reason),
    };
    let layer_refused = |detail: String| Refusal {
        id,
        status: STATUS_BAD_LAYER,
        detail,
        frame: None,
    };
    // A header that is not version 2's (magic, version) or of no known kind
    // is malformed whatever it claims to be; a quad's or removal's own
    // fields that are wrong refuse that layer.
    let is_layer = header[0..4] == crate::pipeline::protocol::FRAME_MAGIC
        && header[4..6] == crate::pipeline::protocol::v2::VERSION_2.to_le_bytes()
        && matches!(header[48], 1 | 2);
    let hd = HeaderV2::parse(header).map_err(|m| {
        if is_layer {
            layer_refused(m.0)
        } else {
            frame(RejectReason::Malformed, m.0)
        }
    })?;
    let views = view_sizes.len();
    let all = hd.view == ALL_VIEWS && hd.layer == Layer::Projection;
    let view_size = match view_sizes.get(usize::from(hd.view)) {
        _ if all => panel,
        Some(&size) => size,
        None => {
            let detail = format!(
                "view {} (this service runs {views} view{}: 0{}{})",
                hd.view,
                if views == 1 { "" } else { "s" },
                if views == 2 { " left, 1 right" } else { "" },
                if hd.layer == Layer::Projection {
                    ", or 255 for a panel-sized frame of every view"
                } else {
                    ""
                }
            );
            return Err(match hd.layer {
                Layer::Projection => frame(RejectReason::UnknownView, detail),
                _ => layer_refused(detail),
            });
        }
    };
    match hd.layer {
        Layer::Projection => {
            let fields = FrameFields {
                id,
                format: hd.format,
                size: (hd.width, hd.height),
                capture_ns: hd.capture_ns,
                offset: hd.offset,
                length: hd.length,
            };
            let admitted = admit_frame(
                &fields,
                view_size,
                shm_size,
                " for a projection layer (1–3)",
            )
            .map_err(|e| frame(e.reason, e.detail))?;
            Ok(AdmittedV2::Projection {
                // View 0 of a service whose one view is the panel is the
                // panel's frame.
                view: {
                    let the_panel = views == 1 && view_size == panel;
                    (!(all || the_panel)).then_some(hd.view)
                },
                frame: admitted,
                display_ns: (hd.display_ns > 0).then_some(hd.display_ns),
            })
        }
        Layer::Quad {
            layer,
            z,
            placement,
        } => {
            let view = hd.view;
            let format = QuadFormat::from_code(hd.format).ok_or_else(|| {
                layer_refused(format!(
                    "layer {layer}: texel format {} (4 RGBA8, 5 RGBA f32; premultiplied linear)",
                    hd.format
                ))
            })?;
            let (w, h) = (hd.width as usize, hd.height as usize);
            // Bounds the allocation before anything is read: a quad larger
            // than its view could not lie inside it.
            if w == 0 || h == 0 || w > view_size.0 || h > view_size.1 {
                return Err(layer_refused(format!(
                    "layer {layer}: a {w}×{h} quad on a {}×{} view",
                    view_size.0, view_size.1
                )));
            }
            let want = (w * h * format.bytes_per_texel()) as u64;
            if hd.length != want {
                return Err(layer_refused(format!(
                    "layer {layer}: {} payload bytes, {want} needed",
                    hd.length
                )));
            }
            if let Some(detail) = outside_shm(hd.offset, hd.length, shm_size) {
                return Err(layer_refused(format!("layer {layer}: {detail}")));
            }
            Ok(AdmittedV2::Quad(AdmittedQuad {
                view,
                layer,
                z,
                placement,
                format,
                width: w,
                height: h,
                offset: hd.offset,
                length: hd.length as usize,
            }))
        }
        Layer::Remove { layer } => Ok(AdmittedV2::Remove {
            view: hd.view,
            layer,
        }),
    }
}

/// The submission's work: the reply's status and message.
fn handle(
    compositor: &Compositor,
    shm: &std::fs::File,
    id: u64,
    admitted: AdmittedV2,
) -> (u32, String) {
    match admitted {
        AdmittedV2::Projection {
            view,
            frame,
            display_ns,
        } => submit_frame(compositor, shm, id, view, &frame, display_ns),
        AdmittedV2::Quad(q) => {
            let mut payload = vec![0u8; q.length];
            if let Err(e) = shm.read_exact_at(&mut payload, q.offset) {
                compositor.count_layer_refused();
                return (
                    STATUS_BAD_LAYER,
                    format!("layer {}: reading the shared memory: {e}", q.layer),
                );
            }
            match compositor.submit_layer_on(q.view, q.layer_of(&payload)) {
                Ok(()) => (STATUS_OK, String::new()),
                Err(e) => (STATUS_BAD_LAYER, e.to_string()),
            }
        }
        AdmittedV2::Remove { view, layer } => {
            if compositor.remove_layer_on(view, layer) {
                (STATUS_OK, String::new())
            } else {
                compositor.count_layer_refused();
                (
                    STATUS_BAD_LAYER,
                    format!("layer {layer}: this client has no such quad layer"),
                )
            }
        }
    }
}

/// A version 2 connection after its hello: the welcome, then one reply per
/// submission, until the client hangs up or the service stops.
pub(super) fn serve(
    stream: &mut UnixStream,
    compositor: &Compositor,
    shm: &std::fs::File,
    shm_size: u64,
    stop: &AtomicBool,
) -> std::io::Result<()> {
    let (w, h) = compositor.panel_size();
    let views = compositor.view_count();
    let view_sizes: Vec<(usize, usize)> = (0..views)
        .map(|v| compositor.view_size(v as u8).unwrap_or((w, h)))
        .collect();
    let reply = |stream: &mut UnixStream, status: u32, frame_id: u64, message: String| {
        let r = ReplyV2 {
            reply: Reply {
                status,
                frame_id,
                panel_width: w as u32,
                panel_height: h as u32,
                message,
            },
            predicted_display_ns: compositor.predicted_display_ns(),
            refresh_period_ns: compositor.refresh_period_ns(),
            views: views as u16,
        };
        write_all_until(stream, &r.to_bytes(), stop, REPLY_DEADLINE)
    };
    let regions: Vec<[usize; 4]> = (0..views)
        .map(|v| compositor.view_region(v as u8).unwrap_or([0, 0, w, h]))
        .collect();
    reply(
        stream,
        STATUS_OK,
        0,
        welcome_message((w, h), &regions, compositor.view().pixels_per_tan),
    )?;
    loop {
        let mut header = [0u8; HEADER_V2_LEN];
        match read_full(stream, &mut header, stop)? {
            Fill::Full => {}
            Fill::Closed | Fill::Stopped => return Ok(()),
            Fill::Partial => {
                compositor.count_disconnect_mid_frame();
                tracing::warn!("a client disconnected in the middle of a header");
                return Ok(());
            }
        }
        let (id, status, message) = match admit(&header, (w, h), &view_sizes, shm_size) {
            Err(r) => {
                match r.frame {
                    Some(reason) => compositor.reject_before_submit(reason, r.id, &r.detail),
                    None => {
                        compositor.count_layer_refused();
                        tracing::warn!("{r}");
                    }
                }
                (r.id, r.status, r.detail)
            }
            Ok(admitted) => {
                let id = u64::from_le_bytes(header[16..24].try_into().unwrap_or([0; 8]));
                let (status, message) = handle(compositor, shm, id, admitted);
                (id, status, message)
            }
        };
        if let Err(e) = reply(stream, status, id, message) {
            if matches!(e.kind(), ErrorKind::BrokenPipe | ErrorKind::ConnectionReset) {
                return Ok(());
            }
            return Err(e);
        }
    }
}
