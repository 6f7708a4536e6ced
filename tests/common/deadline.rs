//! Deadlines for tests (issue 39: no test can hang). A test that waits for
//! a thread, a channel, a condition or a child process waits through one of
//! these: past its limit the test fails with a message naming what did not
//! happen, instead of stalling CI. The limits are for hangs, never for
//! speed: each is generous for a debug build on a loaded 2-core machine.
//!
//! One file for every test crate: tests/cli and tests/service include it
//! as a module (as they do xwd.rs), and a crate's unit tests as
//! `#[cfg(test)] #[path = "../../../tests/common/deadline.rs"] mod deadline;`.
//! Each uses a part of it.
#![allow(dead_code)]

use std::io::Read;
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A thread of a test, or a message on a channel between a test and its
/// fakes: work of milliseconds.
pub const THREAD: Duration = Duration::from_secs(60);
/// A `nedrt` command: 10 minutes in a release build (CI's, whose whole
/// run, builds and every test, fits in its hour). A debug build is far
/// slower: with the test suite's own parallel load and other jobs on a
/// 2-core machine, the tradeoff study and eval over eyes ran over 10
/// minutes and one `--sim` of the default calibration over 30, so there
/// the deadline is 2 hours, still an end to a hang. The test is built in
/// the binary's profile, so its `debug_assertions` says which.
pub const COMMAND: Duration = if cfg!(debug_assertions) {
    Duration::from_secs(7200)
} else {
    Duration::from_secs(600)
};
/// A small tool (xwd, xdotool): seconds at most.
pub const TOOL: Duration = Duration::from_secs(60);

/// How often the waits below look.
const POLL: Duration = Duration::from_millis(5);
/// How long the output of a process that has exited may take to reach its
/// end (a grandchild holding the pipes open): past it, what came is kept.
const OUTPUT_GRACE: Duration = Duration::from_secs(10);

fn timed_out(limit: Duration, what: &str) -> String {
    format!(
        "timed out after {} s waiting for {what}",
        limit.as_secs_f64()
    )
}

/// Joins `handle`, failing the test if its thread has not ended within
/// `limit` (the thread is left behind: the test has failed). A panic on
/// the thread is passed on as it was.
pub fn join_within<T>(handle: JoinHandle<T>, limit: Duration, what: &str) -> T {
    let start = Instant::now();
    while !handle.is_finished() {
        assert!(start.elapsed() < limit, "{}", timed_out(limit, what));
        std::thread::sleep(POLL);
    }
    match handle.join() {
        Ok(v) => v,
        Err(panic) => std::panic::resume_unwind(panic),
    }
}

/// Runs `f` on a thread of its own, failing the test if it has not
/// returned within `limit`.
pub fn within<T: Send + 'static>(
    limit: Duration,
    what: &str,
    f: impl FnOnce() -> T + Send + 'static,
) -> T {
    let handle = std::thread::Builder::new()
        .name(what.chars().take(60).collect())
        .spawn(f)
        .unwrap_or_else(|e| panic!("cannot start a thread for {what}: {e}"));
    join_within(handle, limit, what)
}

/// The next message on `rx`, failing the test if none comes within
/// `limit` or every sender is gone first.
pub fn recv_within<T>(rx: &Receiver<T>, limit: Duration, what: &str) -> T {
    match rx.recv_timeout(limit) {
        Ok(v) => v,
        Err(RecvTimeoutError::Timeout) => panic!("{}", timed_out(limit, what)),
        Err(RecvTimeoutError::Disconnected) => {
            panic!("{what} never happened: every sender is gone")
        }
    }
}

/// Polls `done` until it holds, failing the test if it does not within
/// `limit`.
pub fn wait_until_within(limit: Duration, what: &str, mut done: impl FnMut() -> bool) {
    let start = Instant::now();
    while !done() {
        assert!(start.elapsed() < limit, "{}", timed_out(limit, what));
        std::thread::sleep(POLL);
    }
}

/// The last `n` characters of `bytes` as text.
fn tail(bytes: &[u8], n: usize) -> String {
    let text = String::from_utf8_lossy(bytes);
    let chars: Vec<char> = text.chars().collect();
    chars[chars.len().saturating_sub(n)..].iter().collect()
}

/// A child process whose stdout and stderr are read on threads as it runs
/// (a full pipe never blocks it), and which is killed if dropped while
/// running: a failed test leaves no process behind.
#[derive(Debug)]
pub struct Watched {
    child: Child,
    what: String,
    stdout: Arc<Mutex<Vec<u8>>>,
    stderr: Arc<Mutex<Vec<u8>>>,
    readers: Vec<JoinHandle<()>>,
}

/// Reads `from` to its end into `into`, as it comes.
fn reader(mut from: impl Read + Send + 'static, into: Arc<Mutex<Vec<u8>>>) -> JoinHandle<()> {
    std::thread::spawn(move || {
        let mut buf = [0u8; 8192];
        loop {
            match from.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => into
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(_) => break,
            }
        }
    })
}

impl Watched {
    /// Starts `command` with its stdout and stderr piped and no stdin (as
    /// `Command::output` runs it); `what` names it in failures.
    pub fn spawn(command: &mut Command, what: &str) -> Self {
        let child = command
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {what} ({command:?}): {e}"));
        let what = format!(
            "{what} (`{} {}`)",
            command.get_program().to_string_lossy(),
            command
                .get_args()
                .map(|a| a.to_string_lossy())
                .collect::<Vec<_>>()
                .join(" ")
        );
        let (stdout, stderr) = (Arc::default(), Arc::default());
        let mut watched = Self {
            child,
            what,
            stdout,
            stderr,
            readers: Vec::new(),
        };
        if let Some(out) = watched.child.stdout.take() {
            watched.readers.push(reader(out, watched.stdout.clone()));
        }
        if let Some(err) = watched.child.stderr.take() {
            watched.readers.push(reader(err, watched.stderr.clone()));
        }
        watched
    }

    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// The exit status, if the process has ended.
    pub fn try_wait(&mut self) -> Option<ExitStatus> {
        self.child
            .try_wait()
            .unwrap_or_else(|e| panic!("cannot wait for {}: {e}", self.what))
    }

    /// Waits for the process to exit; if it has not within `limit`, kills
    /// it and returns `Err` with what it wrote.
    pub fn try_exit_within(&mut self, limit: Duration) -> Result<ExitStatus, Output> {
        let start = Instant::now();
        loop {
            if let Some(status) = self.try_wait() {
                return Ok(status);
            }
            if start.elapsed() >= limit {
                let _ = self.child.kill();
                let status = self
                    .child
                    .wait()
                    .unwrap_or_else(|e| panic!("cannot wait for {}: {e}", self.what));
                return Err(self.output_so_far(status));
            }
            std::thread::sleep(POLL);
        }
    }

    /// Waits for the process to exit, failing the test (the process
    /// killed) if it has not within `limit`; `waiting_for` names what the
    /// exit means ("the stop after SIGTERM").
    pub fn exit_within(&mut self, limit: Duration, waiting_for: &str) -> ExitStatus {
        match self.try_exit_within(limit) {
            Ok(status) => status,
            Err(out) => panic!(
                "{}: {} is still running (killed); its stderr ends: {}",
                timed_out(limit, waiting_for),
                self.what,
                tail(&out.stderr, 3000)
            ),
        }
    }

    /// Waits for the process to exit and returns its output, failing the
    /// test (the process killed) if it has not exited within `limit`.
    pub fn wait_within(mut self, limit: Duration, waiting_for: &str) -> Output {
        self.exit_within(limit, waiting_for);
        self.output()
    }

    /// As [`Watched::wait_within`]; past `limit`, `Err` with the output
    /// the killed process left.
    pub fn try_wait_within(mut self, limit: Duration) -> Result<Output, Output> {
        self.try_exit_within(limit)?;
        Ok(self.output())
    }

    /// The output of a process that has exited (killed first if not).
    pub fn output(mut self) -> Output {
        let status = match self.try_wait() {
            Some(status) => status,
            None => {
                let _ = self.child.kill();
                self.child
                    .wait()
                    .unwrap_or_else(|e| panic!("cannot wait for {}: {e}", self.what))
            }
        };
        self.output_so_far(status)
    }

    /// The output the process left, once its pipes close (or
    /// [`OUTPUT_GRACE`] after its exit, if something else holds them).
    fn output_so_far(&mut self, status: ExitStatus) -> Output {
        let start = Instant::now();
        while self.readers.iter().any(|r| !r.is_finished()) && start.elapsed() < OUTPUT_GRACE {
            std::thread::sleep(POLL);
        }
        let take = |b: &Arc<Mutex<Vec<u8>>>| {
            std::mem::take(&mut *b.lock().unwrap_or_else(|e| e.into_inner()))
        };
        Output {
            status,
            stdout: take(&self.stdout),
            stderr: take(&self.stderr),
        }
    }
}

impl Drop for Watched {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// [`Command`] run under a deadline.
pub trait CommandWithin {
    /// As `Command::output`, failing the test (the process killed, with
    /// the end of its stderr) if it has not exited within `limit`.
    fn output_within(&mut self, limit: Duration, what: &str) -> Output;
    /// As [`CommandWithin::output_within`]; past `limit`, `Err` with the
    /// output the killed process left.
    fn try_output_within(&mut self, limit: Duration, what: &str) -> Result<Output, Output>;
    /// Starts the command as a [`Watched`] process.
    fn spawn_watched(&mut self, what: &str) -> Watched;
}

impl CommandWithin for Command {
    fn output_within(&mut self, limit: Duration, what: &str) -> Output {
        Watched::spawn(self, what).wait_within(limit, &format!("{what} to finish"))
    }

    fn try_output_within(&mut self, limit: Duration, what: &str) -> Result<Output, Output> {
        Watched::spawn(self, what).try_wait_within(limit)
    }

    fn spawn_watched(&mut self, what: &str) -> Watched {
        Watched::spawn(self, what)
    }
}
