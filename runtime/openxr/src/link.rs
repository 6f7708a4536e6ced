//! The connection to the running service (`nedrt run --source socket`,
//! docs/protocol.md version 2): what the system is, when frames are
//! shown, and where each submitted view and quad goes.

use std::path::{Path, PathBuf};

use nedrt_protocol::v2::{HeaderV2, QuadFormat};
use nedrt_protocol::{Client, PixelFormat, Placement, STATUS_OK};

/// Where the service listens unless `NEDRT_SOCKET` says otherwise
/// (`nedrt run`'s own default).
pub const DEFAULT_SOCKET: &str = "/tmp/nedrt.sock";

/// Shared memory announced at the hello: the largest submission is a quad
/// of a whole 1920×1080 view in RGBA f32 (33 MB). The object is sparse, so
/// only what is written takes memory.
const SHM_SIZE: u64 = 256 << 20;

#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error(
        "no nedrt service at {socket}: {source} (start `nedrt run --source socket`, or set NEDRT_SOCKET)"
    )]
    Connect {
        socket: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "the service at {socket} does not give its eyepiece's geometry (pixels per tan in its welcome): it is older than this runtime"
    )]
    NoGeometry { socket: PathBuf },
    #[error("the connection to the service was lost: {0}")]
    Lost(std::io::Error),
}

/// The head-mounted display as the service describes it.
#[derive(Debug, Clone, PartialEq)]
pub struct SystemInfo {
    pub socket: PathBuf,
    pub panel: (usize, usize),
    /// Each view's region on the panel: x, y, width, height.
    pub views: Vec<[usize; 4]>,
    /// A pixel subtends 1/pixels_per_tan of tan(angle) at the eyepiece.
    pub pixels_per_tan: f64,
    pub refresh_period_ns: u64,
}

impl SystemInfo {
    /// View `v`'s field of view: half-angles (left, right, up, down) in
    /// radians, symmetric about the view's centre, where the eyepiece's axis
    /// meets it, so that one pixel of a swapchain of the view's size is one
    /// pixel of the panel.
    pub fn fov(&self, v: usize) -> [f32; 4] {
        let [_, _, w, h] = self.views[v];
        let half = |n: usize| (n as f64 / 2.0 / self.pixels_per_tan).atan() as f32;
        [-half(w), half(w), half(h), -half(h)]
    }

    pub fn view_size(&self, v: usize) -> (usize, usize) {
        let [_, _, w, h] = self.views[v];
        (w, h)
    }
}

/// The socket `NEDRT_SOCKET` names, or the default.
pub fn socket_path() -> PathBuf {
    std::env::var_os("NEDRT_SOCKET").map_or_else(|| PathBuf::from(DEFAULT_SOCKET), PathBuf::from)
}

fn shm_dir() -> PathBuf {
    std::env::var_os("NEDRT_SHM_DIR").map_or_else(
        || PathBuf::from(nedrt_protocol::DEFAULT_SHM_DIR),
        PathBuf::from,
    )
}

/// A version 2 connection and the frame ids it has used.
#[derive(Debug)]
pub struct Link {
    client: Client,
    next_id: u64,
    /// When the last reply arrived (CLOCK_MONOTONIC ns): its prediction
    /// was for a frame submitted then.
    received_ns: i64,
    /// The last replies' leads (prediction less arrival), newest last.
    leads: std::collections::VecDeque<i64>,
    pub info: SystemInfo,
}

/// How many replies the lead is taken over.
const LEADS: usize = 8;

/// The service's prediction of when a frame submitted now is shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    pub predicted_display_ns: i64,
    pub period_ns: i64,
}

impl Link {
    pub fn connect(socket: &Path) -> Result<Self, LinkError> {
        let client = Client::connect_v2(socket, &shm_dir(), SHM_SIZE).map_err(|source| {
            LinkError::Connect {
                socket: socket.to_path_buf(),
                source,
            }
        })?;
        let pixels_per_tan = client.pixels_per_tan.ok_or_else(|| LinkError::NoGeometry {
            socket: socket.to_path_buf(),
        })?;
        let refresh_period_ns = client.timing.as_ref().map_or(0, |t| t.refresh_period_ns);
        let views = if client.views.is_empty() {
            vec![[0, 0, client.panel.0, client.panel.1]]
        } else {
            client.views.clone()
        };
        let info = SystemInfo {
            socket: socket.to_path_buf(),
            panel: client.panel,
            views,
            pixels_per_tan,
            refresh_period_ns,
        };
        Ok(Self {
            client,
            next_id: 1,
            received_ns: crate::ffi::now_ns(),
            leads: std::collections::VecDeque::with_capacity(LEADS),
            info,
        })
    }

    /// The last reply's prediction.
    pub fn timing(&self) -> Option<Timing> {
        let t = self.client.timing.as_ref()?;
        Some(Timing {
            predicted_display_ns: i64::try_from(t.predicted_display_ns).ok()?,
            period_ns: i64::try_from(t.refresh_period_ns).ok()?.max(1),
        })
    }

    /// The service's lead from a submission to its refresh: the least of
    /// the last replies' (prediction less arrival). One reply's is the
    /// pipeline's bound rounded up to the next refresh, so by up to a
    /// period more, depending on where in the period it came; the runtime
    /// rounds up to a refresh again when it predicts, and with one reply's
    /// lead frames skipped refreshes (the CTS's pipelined frame case at
    /// 240 Hz: one frame in two planned a refresh late).
    /// Before the first reply, the welcome's.
    pub fn lead_ns(&self) -> Option<i64> {
        self.leads.iter().copied().min().or_else(|| {
            self.timing()
                .map(|t| (t.predicted_display_ns - self.received_ns).max(0))
        })
    }

    /// Whether the service is still there: a closed socket reads as end
    /// of file (nothing else is ever sent unasked).
    pub fn alive(&mut self) -> Result<(), LinkError> {
        use rustix::net::{RecvFlags, recv};
        let mut probe = [0u8; 1];
        match recv(
            &*self.client.stream(),
            &mut probe,
            RecvFlags::PEEK | RecvFlags::DONTWAIT,
        ) {
            Ok((_, 0)) => Err(LinkError::Lost(std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                "the service closed the connection",
            ))),
            Ok(_) => Ok(()),
            Err(rustix::io::Errno::AGAIN) => Ok(()),
            Err(e) => Err(LinkError::Lost(e.into())),
        }
    }

    fn send(&mut self, header: &HeaderV2, payload: &[u8]) -> Result<(), LinkError> {
        let reply = self
            .client
            .send_v2(header, payload)
            .map_err(LinkError::Lost)?;
        self.received_ns = crate::ffi::now_ns();
        if let Some(t) = self.timing() {
            if self.leads.len() == LEADS {
                self.leads.pop_front();
            }
            self.leads
                .push_back((t.predicted_display_ns - self.received_ns).max(0));
        }
        if reply.reply.status != STATUS_OK {
            // A refused submission is the application's content (a quad
            // outside the view, say): logged, and the session goes on.
            log_warn!(
                "the service refused frame {} (status {}): {}",
                header.frame_id,
                reply.reply.status,
                reply.reply.message
            );
        }
        Ok(())
    }

    fn id(&mut self) -> u64 {
        self.next_id += 1;
        self.next_id - 1
    }

    /// View `view`'s projection layer, `rgba` of the view's size, rendered
    /// for the refresh at `display_ns` (the frame's prediction).
    pub fn projection(
        &mut self,
        view: u8,
        format: PixelFormat,
        size: (usize, usize),
        rgba: &[u8],
        (capture_ns, display_ns): (u64, u64),
    ) -> Result<(), LinkError> {
        let id = self.id();
        let header =
            HeaderV2::projection(view, format, size, id, capture_ns).for_display(display_ns);
        self.send(&header, rgba)
    }

    /// A quad layer over view `view`: premultiplied linear RGBA f32 texels,
    /// one a panel pixel.
    pub fn quad(
        &mut self,
        view: u8,
        layer: u32,
        z: i32,
        placement: Placement,
        size: (usize, usize),
        rgba: &[f32],
    ) -> Result<(), LinkError> {
        let id = self.id();
        let header = HeaderV2::quad(
            view,
            layer,
            z,
            placement,
            QuadFormat::Rgba32fPremultiplied,
            size,
            id,
            0,
        );
        let bytes: Vec<u8> = rgba.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.send(&header, &bytes)
    }

    pub fn remove_quad(&mut self, view: u8, layer: u32) -> Result<(), LinkError> {
        let id = self.id();
        self.send(&HeaderV2::remove(view, layer, id), &[])
    }
}
