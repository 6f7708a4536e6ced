//! The application interface, service side (docs/protocol.md): a Unix
//! socket accepting any number of clients, one thread each. A client's
//! frames are read from its shared memory and submitted; every frame gets
//! a reply (accepted, or the rejection reason and message). A malformed
//! header is answered and the next one read (headers have a fixed size, so
//! the stream stays in step); a client that vanishes mid-frame is counted
//! and does no harm.

use std::io::{ErrorKind, Read, Write};
use std::os::unix::fs::{FileExt, FileTypeExt};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use super::{Source, SourceError};
use crate::pipeline::frame::{FrameError, PixelFormat, RejectReason, SubmittedFrame, check_shape};
use crate::pipeline::protocol::{
    FrameHeader, HEADER_LEN, HELLO_LEN, Hello, Reply, STATUS_BAD_HELLO, STATUS_OK, valid_shm_name,
};
use crate::pipeline::service::Compositor;

pub mod v2;

/// How often blocked reads and accepts look at the stop flag.
const POLL: Duration = Duration::from_millis(50);

/// How long a reply may wait for a client to make room by reading: a
/// client that stops reading is dropped after this, so it can hold off
/// neither the others nor shutdown.
pub const REPLY_DEADLINE: Duration = Duration::from_secs(2);

/// The listening socket.
#[derive(Debug)]
pub struct SocketSource {
    path: PathBuf,
    shm_dir: PathBuf,
    /// The socket file this source made (device, inode), once listening:
    /// only that one is removed at the end, never another service's.
    made: Option<(u64, u64)>,
}

/// The longest socket path Linux takes (`sun_path` is 108 bytes with its NUL).
const MAX_SOCKET_PATH: usize = 107;

impl SocketSource {
    /// Checks `path` and `shm_dir` now, so that a bad one is an error before
    /// anything starts: a stale socket left by a dead service is removed, a
    /// live one or any other file is an error. The socket listens only once
    /// the source runs, i.e. once the pipeline is prepared and can serve:
    /// a client that finds the socket is welcomed at once, not after the
    /// pipeline's preparation (seconds with a network).
    pub fn bind(path: &Path, shm_dir: &Path) -> Result<Self, SourceError> {
        let fail = |reason: String| SourceError::Socket {
            path: path.to_path_buf(),
            reason,
        };
        // Checked before listening: every client would be refused later.
        if !shm_dir.is_dir() {
            return Err(SourceError::Input {
                path: shm_dir.to_path_buf(),
                reason: "not a folder (the folder for the clients' shared memory)".into(),
            });
        }
        if let Ok(meta) = std::fs::symlink_metadata(path) {
            if !meta.file_type().is_socket() {
                return Err(fail("exists and is not a socket; not removing it".into()));
            }
            if UnixStream::connect(path).is_ok() {
                return Err(fail("another service is listening there".into()));
            }
            std::fs::remove_file(path)
                .map_err(|e| fail(format!("cannot remove the stale socket: {e}")))?;
        }
        // Whether it can listen there at all (a path too long, a missing
        // folder, no permission): found now, not when the source starts.
        use std::os::unix::ffi::OsStrExt;
        if path.as_os_str().as_bytes().len() > MAX_SOCKET_PATH {
            return Err(fail(format!(
                "cannot listen: {} bytes; a socket path holds at most {MAX_SOCKET_PATH}",
                path.as_os_str().as_bytes().len()
            )));
        }
        let dir = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        if !dir.is_dir() {
            return Err(fail(format!(
                "cannot listen: folder {} does not exist",
                dir.display()
            )));
        }
        let access = rustix::fs::Access::WRITE_OK | rustix::fs::Access::EXEC_OK;
        if let Err(e) = rustix::fs::access(dir, access) {
            return Err(fail(format!(
                "cannot listen: folder {} is not writable ({e})",
                dir.display()
            )));
        }
        Ok(Self {
            path: path.to_path_buf(),
            shm_dir: shm_dir.to_path_buf(),
            made: None,
        })
    }

    /// Starts listening (the source's first act).
    fn listen(&mut self) -> Result<UnixListener, SourceError> {
        let fail = |reason: String| SourceError::Socket {
            path: self.path.clone(),
            reason,
        };
        let listener =
            UnixListener::bind(&self.path).map_err(|e| fail(format!("cannot listen: {e}")))?;
        listener
            .set_nonblocking(true)
            .map_err(|e| fail(e.to_string()))?;
        self.made = std::fs::symlink_metadata(&self.path).ok().map(|m| {
            use std::os::unix::fs::MetadataExt;
            (m.dev(), m.ino())
        });
        tracing::info!("listening on {}", self.path.display());
        Ok(listener)
    }
}

impl Drop for SocketSource {
    /// Removes the socket this source made, if the path still names it.
    fn drop(&mut self) {
        use std::os::unix::fs::MetadataExt;
        let still_ours = std::fs::symlink_metadata(&self.path)
            .is_ok_and(|m| self.made == Some((m.dev(), m.ino())));
        if still_ours {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

impl Source for SocketSource {
    fn describe(&self) -> String {
        format!("socket {}", self.path.display())
    }

    fn run(&mut self, compositor: Compositor, stop: &AtomicBool) -> Result<u64, SourceError> {
        let listener = self.listen()?;
        std::thread::scope(|scope| {
            let mut clients = 0u64;
            while !stop.load(Ordering::Relaxed) {
                match listener.accept() {
                    Ok((stream, _)) => {
                        clients += 1;
                        let compositor = compositor.clone();
                        let shm_dir = self.shm_dir.clone();
                        let spawned = std::thread::Builder::new()
                            .name(format!("client-{clients}"))
                            .spawn_scoped(scope, move || {
                                // Each client sets its own layers (protocol v2).
                                let compositor = compositor.for_owner(clients);
                                match serve(stream, &compositor, &shm_dir, stop) {
                                    Err(e)
                                        if matches!(
                                            e.kind(),
                                            ErrorKind::WouldBlock | ErrorKind::TimedOut
                                        ) =>
                                    {
                                        compositor.count_client_dropped();
                                        tracing::warn!(
                                            "client {clients} read none of its replies for \
                                             {REPLY_DEADLINE:?}; dropped"
                                        );
                                    }
                                    Err(e) if e.kind() == ErrorKind::Interrupted => {
                                        tracing::debug!("client {clients}: {e}");
                                    }
                                    Err(e) => tracing::warn!("client {clients}: {e}"),
                                    Ok(()) => {}
                                }
                            });
                        if let Err(e) = spawned {
                            tracing::error!("cannot start a client thread: {e}");
                        }
                    }
                    Err(e) if e.kind() == ErrorKind::WouldBlock => std::thread::sleep(POLL),
                    Err(e) => tracing::warn!("accept: {e}"),
                }
            }
            Ok(clients)
        })
    }
}

/// How a fixed-size read ended.
enum Fill {
    Full,
    /// The peer closed before the first byte.
    Closed,
    /// The peer closed part-way.
    Partial,
    Stopped,
}

fn read_full(stream: &mut UnixStream, buf: &mut [u8], stop: &AtomicBool) -> std::io::Result<Fill> {
    let mut n = 0;
    while n < buf.len() {
        // Looked at on every read, not only when one times out: a client
        // that never pauses must not hold off shutdown either.
        if stop.load(Ordering::Relaxed) {
            return Ok(Fill::Stopped);
        }
        match stream.read(&mut buf[n..]) {
            Ok(0) => return Ok(if n == 0 { Fill::Closed } else { Fill::Partial }),
            Ok(k) => n += k,
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                ) => {}
            Err(e) => return Err(e),
        }
    }
    Ok(Fill::Full)
}

/// Writes all of `bytes` within `deadline`, looking at the stop flag
/// every [`POLL`]: a client that does not read can delay neither shutdown
/// (the write gives up at once) nor, past the deadline, anything else
/// (`TimedOut`: the client is dropped).
fn write_all_until(
    stream: &mut UnixStream,
    mut bytes: &[u8],
    stop: &AtomicBool,
    deadline: Duration,
) -> std::io::Result<()> {
    let started = std::time::Instant::now();
    while !bytes.is_empty() {
        match stream.write(bytes) {
            Ok(0) => return Err(ErrorKind::WriteZero.into()),
            Ok(k) => bytes = &bytes[k..],
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                ) =>
            {
                if stop.load(Ordering::Relaxed) {
                    return Err(std::io::Error::new(
                        ErrorKind::Interrupted,
                        "stopping with a reply unsent",
                    ));
                }
                if started.elapsed() >= deadline {
                    return Err(ErrorKind::TimedOut.into());
                }
            }
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// Opens a client's shared memory for reading so that a client can point
/// the service at nothing but a file of its own: the last path component
/// is not followed if it is a link, opening never blocks (a FIFO would hold
/// the client's thread, and shutdown, forever), and the opened object must
/// be a regular file, owned by the connecting peer (where the socket says
/// who that is), holding at least the announced size.
pub fn open_shared_memory(
    path: &Path,
    peer_uid: Option<u32>,
    announced: u64,
) -> Result<std::fs::File, SourceError> {
    use rustix::fs::{Mode, OFlags};
    let refused = |reason: String| SourceError::Input {
        path: path.to_path_buf(),
        reason,
    };
    let fd = rustix::fs::open(
        path,
        OFlags::RDONLY | OFlags::NOFOLLOW | OFlags::NONBLOCK | OFlags::CLOEXEC,
        Mode::empty(),
    )
    .map_err(|e| {
        if e == rustix::io::Errno::LOOP {
            refused("a symbolic link; shared memory must be a regular file".into())
        } else {
            refused(format!("cannot open: {e}"))
        }
    })?;
    let file = std::fs::File::from(fd);
    let meta = file.metadata().map_err(|e| refused(e.to_string()))?;
    if !meta.file_type().is_file() {
        return Err(refused(
            "not a regular file; shared memory must be one".into(),
        ));
    }
    if let Some(uid) = peer_uid {
        use std::os::unix::fs::MetadataExt;
        if meta.uid() != uid {
            return Err(refused(format!(
                "owned by uid {}, not by the connecting client (uid {uid})",
                meta.uid()
            )));
        }
    }
    if meta.len() < announced {
        return Err(refused(format!(
            "holds {} bytes, not the {announced} announced",
            meta.len()
        )));
    }
    Ok(file)
}

/// A frame header the service accepted: where its payload lies in the
/// client's shared memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Admitted {
    pub format: PixelFormat,
    pub capture_ns: u64,
    pub offset: u64,
    pub length: usize,
}

/// Checks a frame header against a `panel`-sized display and a
/// `shm_size`-byte shared memory before any payload is read; pure, so the
/// fuzz target `protocol` runs exactly what the service runs.
pub fn admit(
    header: &[u8; HEADER_LEN],
    panel: (usize, usize),
    shm_size: u64,
) -> Result<Admitted, FrameError> {
    let id = FrameHeader::id_of(header);
    let hd = FrameHeader::parse(header).map_err(|d| FrameError {
        id,
        reason: RejectReason::Malformed,
        detail: d.0,
    })?;
    let fields = FrameFields {
        id,
        format: hd.format,
        size: (hd.width, hd.height),
        capture_ns: hd.capture_ns,
        offset: hd.offset,
        length: hd.length,
    };
    admit_frame(&fields, panel, shm_size, "")
}

/// A frame header's fields, in either protocol version.
pub(crate) struct FrameFields {
    pub id: u64,
    pub format: u16,
    pub size: (u32, u32),
    pub capture_ns: u64,
    pub offset: u64,
    pub length: u64,
}

/// The checks every frame header passes before its payload is read: a
/// pixel format the service knows (`where_` says for what, in the
/// message), the expected size and payload length, the payload inside the
/// shared memory.
pub(crate) fn admit_frame(
    f: &FrameFields,
    expected: (usize, usize),
    shm_size: u64,
    where_: &str,
) -> Result<Admitted, FrameError> {
    let fail = |reason, detail: String| FrameError {
        id: f.id,
        reason,
        detail,
    };
    let format = PixelFormat::from_code(f.format).ok_or_else(|| {
        fail(
            RejectReason::UnsupportedFormat,
            format!("pixel format {}{where_}", f.format),
        )
    })?;
    check_shape(
        f.id,
        (f.size.0 as usize, f.size.1 as usize),
        format,
        f.length,
        expected,
    )?;
    if let Some(detail) = outside_shm(f.offset, f.length, shm_size) {
        return Err(fail(RejectReason::Truncated, detail));
    }
    Ok(Admitted {
        format,
        capture_ns: f.capture_ns,
        offset: f.offset,
        // check_shape bounded it by the expected frame size.
        length: f.length as usize,
    })
}

/// Why `length` bytes at `offset` are not inside a `shm_size`-byte shared
/// memory, if they are not.
pub(crate) fn outside_shm(offset: u64, length: u64, shm_size: u64) -> Option<String> {
    offset
        .checked_add(length)
        .is_none_or(|e| e > shm_size)
        .then(|| {
            format!("payload at {offset}+{length} lies outside the {shm_size}-byte shared memory")
        })
}

/// Reads an admitted frame's payload from the client's shared memory and
/// submits it: the reply's status and message.
fn submit_frame(
    compositor: &Compositor,
    shm: &std::fs::File,
    id: u64,
    view: Option<u8>,
    req: &Admitted,
    display_ns: Option<u64>,
) -> (u32, String) {
    let (w, h) = match view {
        Some(v) => compositor.view_size(v).unwrap_or((0, 0)),
        None => compositor.panel_size(),
    };
    let mut payload = vec![0u8; req.length];
    match shm.read_exact_at(&mut payload, req.offset) {
        Err(e) => {
            let detail = format!("reading the shared memory: {e}");
            compositor.reject_before_submit(RejectReason::Truncated, id, &detail);
            (RejectReason::Truncated.code(), detail)
        }
        Ok(()) => {
            let frame = SubmittedFrame {
                id,
                capture_ns: req.capture_ns,
                width: w,
                height: h,
                format: req.format,
                payload,
            };
            let submitted = compositor.submit_at(view, frame, display_ns);
            match submitted {
                Ok(()) => (STATUS_OK, String::new()),
                Err(e) => (e.reason.code(), e.detail),
            }
        }
    }
}

/// One client, from hello to hang-up.
fn serve(
    mut stream: UnixStream,
    compositor: &Compositor,
    shm_dir: &Path,
    stop: &AtomicBool,
) -> std::io::Result<()> {
    stream.set_nonblocking(false)?;
    stream.set_read_timeout(Some(POLL))?;
    stream.set_write_timeout(Some(POLL))?;
    let (w, h) = compositor.panel_size();
    let reply = |stream: &mut UnixStream, status: u32, frame_id: u64, message: String| {
        let r = Reply {
            status,
            frame_id,
            panel_width: w as u32,
            panel_height: h as u32,
            message,
        };
        write_all_until(stream, &r.to_bytes(), stop, REPLY_DEADLINE)
    };

    let mut hello = [0u8; HELLO_LEN];
    match read_full(&mut stream, &mut hello, stop)? {
        Fill::Full => {}
        _ => return Ok(()),
    }
    let refuse = |stream: &mut UnixStream, why: String| {
        tracing::warn!("refused a client: {why}");
        reply(stream, STATUS_BAD_HELLO, 0, why)
    };
    let Hello { name_len, shm_size } = match Hello::parse(&hello) {
        Ok(h) => h,
        Err(why) => return refuse(&mut stream, why.to_string()),
    };
    let mut name = vec![0u8; name_len];
    if !matches!(read_full(&mut stream, &mut name, stop)?, Fill::Full) {
        return Ok(());
    }
    let name = String::from_utf8_lossy(&name).into_owned();
    if !valid_shm_name(&name) {
        return refuse(
            &mut stream,
            format!("{name:?} is not a shared-memory name (letters, digits, '.', '_', '-')"),
        );
    }
    let peer_uid = rustix::net::sockopt::socket_peercred(&stream)
        .map(|c| c.uid.as_raw())
        .ok();
    let shm = match open_shared_memory(&shm_dir.join(&name), peer_uid, shm_size) {
        Ok(f) => f,
        Err(why) => return refuse(&mut stream, why.to_string()),
    };
    if Hello::version_of(&hello) == crate::pipeline::protocol::v2::VERSION_2 {
        let served = v2::serve(&mut stream, compositor, &shm, shm_size, stop);
        // A client that left takes its quad layers with it: an overlay
        // nobody updates or removes would stay on the panel for good.
        let removed = compositor.remove_owner_layers();
        if removed > 0 {
            tracing::info!("a client left; its {removed} quad layers removed");
        }
        return served;
    }
    reply(&mut stream, STATUS_OK, 0, format!("panel {w}×{h}"))?;

    loop {
        let mut header = [0u8; HEADER_LEN];
        match read_full(&mut stream, &mut header, stop)? {
            Fill::Full => {}
            Fill::Closed | Fill::Stopped => return Ok(()),
            Fill::Partial => {
                compositor.count_disconnect_mid_frame();
                tracing::warn!("a client disconnected in the middle of a frame header");
                return Ok(());
            }
        }
        let id = FrameHeader::id_of(&header);
        let (status, message) = match admit(&header, (w, h), shm_size) {
            Err(e) => {
                compositor.reject_before_submit(e.reason, id, &e.detail);
                (e.reason.code(), e.detail)
            }
            Ok(req) => submit_frame(compositor, &shm, id, None, &req, None),
        };
        if let Err(e) = reply(&mut stream, status, id, message) {
            if matches!(e.kind(), ErrorKind::BrokenPipe | ErrorKind::ConnectionReset) {
                return Ok(());
            }
            return Err(e);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn own_uid() -> u32 {
        use std::os::unix::fs::MetadataExt;
        std::fs::metadata(std::env::temp_dir())
            .map(|m| m.uid())
            .unwrap_or(0)
    }

    #[test]
    fn a_regular_file_of_the_client_opens() {
        let dir = tempfile::tempdir().expect("tmp");
        let shm = dir.path().join("frame");
        std::fs::write(&shm, vec![0u8; 64]).expect("write");
        let uid = {
            use std::os::unix::fs::MetadataExt;
            std::fs::metadata(&shm).expect("meta").uid()
        };
        assert!(open_shared_memory(&shm, Some(uid), 64).is_ok());
        let e = open_shared_memory(&shm, Some(uid), 65)
            .expect_err("short")
            .to_string();
        assert!(e.contains("holds 64 bytes, not the 65 announced"), "{e}");
        let e = open_shared_memory(&shm, Some(uid.wrapping_add(1)), 64)
            .expect_err("owner")
            .to_string();
        assert!(e.contains("not by the connecting client"), "{e}");
    }

    #[test]
    fn a_link_to_another_file_is_refused_not_followed() {
        let dir = tempfile::tempdir().expect("tmp");
        let secret = dir.path().join("secret");
        std::fs::write(&secret, vec![7u8; 64]).expect("write");
        let link = dir.path().join("frame");
        std::os::unix::fs::symlink(&secret, &link).expect("symlink");
        let e = open_shared_memory(&link, Some(own_uid()), 64)
            .expect_err("link")
            .to_string();
        assert!(e.contains("a symbolic link"), "{e}");
    }

    #[test]
    fn a_fifo_is_refused_at_once_instead_of_blocking() {
        let dir = tempfile::tempdir().expect("tmp");
        let fifo = dir.path().join("frame");
        rustix::fs::mknodat(
            rustix::fs::CWD,
            &fifo,
            rustix::fs::FileType::Fifo,
            rustix::fs::Mode::RUSR | rustix::fs::Mode::WUSR,
            0,
        )
        .expect("mkfifo");
        // A blocking open(2) would wait here for a writer, forever.
        let e = open_shared_memory(&fifo, Some(own_uid()), 0)
            .expect_err("fifo")
            .to_string();
        assert!(e.contains("not a regular file"), "{e}");
    }

    #[test]
    fn a_source_that_loses_the_race_for_its_path_leaves_the_winners_socket() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("s.sock");
        let shm = dir.path();
        // Both checked before either listens (two services started at once).
        let mut winner = SocketSource::bind(&path, shm).expect("checked");
        let mut loser = SocketSource::bind(&path, shm).expect("checked");
        let _listener = winner.listen().expect("listens");
        let e = loser.listen().expect_err("taken").to_string();
        assert!(e.contains("cannot listen"), "{e}");
        drop(loser);
        assert!(path.exists(), "the loser removed the winner's socket");
        // A third finds a live service there at once.
        let e = SocketSource::bind(&path, shm)
            .expect_err("live")
            .to_string();
        assert!(e.contains("another service is listening there"), "{e}");
        drop(winner);
        assert!(!path.exists(), "the winner removes its own socket");
        let long = dir.path().join("x".repeat(120));
        let e = SocketSource::bind(&long, shm)
            .expect_err("too long")
            .to_string();
        assert!(e.contains("a socket path holds at most 107"), "{e}");
        let e = SocketSource::bind(&dir.path().join("no/such/s.sock"), shm)
            .expect_err("no folder")
            .to_string();
        assert!(e.contains("does not exist"), "{e}");
    }
}
