//! The runtime's objects behind the handles the application holds.
//!
//! Every handle is a number this runtime gave out and looks up here, so a
//! stale, foreign or forged handle is `XR_ERROR_HANDLE_INVALID`, never a
//! dereference. Objects are `Arc`s so that an entry point can release the
//! registry's lock before it blocks (`xrWaitFrame`) or talks to the
//! service (`xrEndFrame`).
//!
//! The objects' inner state lives here too (a session's state machine and
//! frame loop, a swapchain's images): the entry points (session.rs,
//! swapchain.rs, frame.rs) act on them through the registry, and nothing
//! here calls an entry point.

use std::collections::{BTreeSet, HashMap, VecDeque};
use std::sync::{Arc, LazyLock, Mutex, MutexGuard};

use ash::vk;
use openxr_sys as xr;
use openxr_sys::Handle as _;

use crate::ffi::{XrResult, lock, now_ns};
use crate::link::{Link, LinkError, SystemInfo};
use crate::space::{PoseSource, SpaceKind};
use crate::vulkan::Context;

#[derive(Debug, Default)]
pub struct Registry {
    next: u64,
    pub instances: HashMap<u64, Arc<Instance>>,
    pub sessions: HashMap<u64, Arc<Session>>,
    pub spaces: HashMap<u64, Arc<Space>>,
    pub swapchains: HashMap<u64, Arc<Swapchain>>,
    pub action_sets: HashMap<u64, Arc<ActionSet>>,
    pub actions: HashMap<u64, Arc<Action>>,
}

static REGISTRY: LazyLock<Mutex<Registry>> = LazyLock::new(|| Mutex::new(Registry::default()));

pub fn registry() -> MutexGuard<'static, Registry> {
    lock(&REGISTRY)
}

/// The object behind a handle of one type, or `XR_ERROR_HANDLE_INVALID`.
fn live<T>(objects: &HashMap<u64, Arc<T>>, h: u64) -> XrResult<Arc<T>> {
    objects
        .get(&h)
        .cloned()
        .ok_or(xr::Result::ERROR_HANDLE_INVALID)
}

impl Registry {
    /// A handle never given out before (0 is `XR_NULL_HANDLE`).
    pub fn new_handle(&mut self) -> u64 {
        self.next += 1;
        // Not small integers: a handle of one type passed where another is
        // expected is then never found by accident in the wrong map.
        self.next.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1
    }

    pub fn instance(&self, h: xr::Instance) -> XrResult<Arc<Instance>> {
        live(&self.instances, h.into_raw())
    }

    pub fn session(&self, h: xr::Session) -> XrResult<Arc<Session>> {
        live(&self.sessions, h.into_raw())
    }

    pub fn space(&self, h: xr::Space) -> XrResult<Arc<Space>> {
        live(&self.spaces, h.into_raw())
    }

    pub fn swapchain(&self, h: xr::Swapchain) -> XrResult<Arc<Swapchain>> {
        live(&self.swapchains, h.into_raw())
    }

    pub fn action_set(&self, h: xr::ActionSet) -> XrResult<Arc<ActionSet>> {
        live(&self.action_sets, h.into_raw())
    }

    pub fn action(&self, h: xr::Action) -> XrResult<Arc<Action>> {
        live(&self.actions, h.into_raw())
    }

    /// Removes a session and every object made from it (the specification
    /// destroys children with their parent).
    pub fn remove_session(&mut self, session: u64) -> Option<Arc<Session>> {
        self.spaces.retain(|_, s| s.session != session);
        self.swapchains.retain(|_, s| s.session != session);
        let removed = self.sessions.remove(&session)?;
        // Its queued events name a handle that is gone: the application
        // never sees them (the CTS's layer refuses an event of an unknown
        // session).
        if let Some(instance) = self.instances.get(&removed.instance) {
            lock(&instance.inner)
                .events
                .retain(|Event::SessionState { session: s, .. }| *s != session);
        }
        Some(removed)
    }

    /// Removes an instance and everything made from it.
    pub fn remove_instance(&mut self, instance: u64) -> Option<Arc<Instance>> {
        let sessions: Vec<u64> = self
            .sessions
            .iter()
            .filter(|(_, s)| s.instance == instance)
            .map(|(&h, _)| h)
            .collect();
        for s in sessions {
            self.remove_session(s);
        }
        self.action_sets.retain(|_, a| a.instance != instance);
        self.actions.retain(|_, a| a.instance != instance);
        self.instances.remove(&instance)
    }
}

/// An event waiting for `xrPollEvent`.
#[derive(Debug, Clone, Copy)]
pub enum Event {
    SessionState {
        session: u64,
        state: xr::SessionState,
        time: i64,
    },
}

#[derive(Debug)]
pub struct Instance {
    pub handle: u64,
    pub extensions: Vec<String>,
    pub inner: Mutex<InstanceInner>,
}

#[derive(Debug, Default)]
pub struct InstanceInner {
    /// Path strings by `XrPath` value − 1.
    pub paths: Vec<String>,
    pub path_ids: HashMap<String, u64>,
    pub events: VecDeque<Event>,
    /// The head-mounted display, once `xrGetSystem` found the service.
    pub system: Option<SystemInfo>,
    /// The connection `xrGetSystem` opened, kept for the first session.
    pub link: Option<crate::link::Link>,
    /// `xrGetVulkanGraphicsRequirements(2)KHR` was called (a session may
    /// not be created before, §12.20).
    pub graphics_requirements_queried: bool,
    /// The `vkGetInstanceProcAddr` the application gave
    /// `xrCreateVulkanInstanceKHR`, for its sessions' Vulkan calls.
    pub vk_get_instance_proc_addr: Option<ash::vk::PFN_vkGetInstanceProcAddr>,
    /// A session of this instance has attached action sets: no more
    /// bindings may be suggested (§11.4).
    pub actions_attached: bool,
}

impl Instance {
    pub fn has_extension(&self, name: &str) -> bool {
        self.extensions.iter().any(|e| e == name)
    }

    /// An extension's function called on an instance that did not enable
    /// it: `XR_ERROR_FUNCTION_UNSUPPORTED`.
    pub fn require_extension(&self, name: &str) -> XrResult<()> {
        if self.has_extension(name) {
            Ok(())
        } else {
            Err(xr::Result::ERROR_FUNCTION_UNSUPPORTED)
        }
    }

    pub fn push_event(&self, e: Event) {
        lock(&self.inner).events.push_back(e);
    }
}

/// The one system this runtime offers.
pub const SYSTEM_ID: u64 = 1;

#[derive(Debug)]
pub struct Session {
    pub handle: u64,
    pub instance: u64,
    pub inner: Mutex<SessionInner>,
    /// Serialises `xrWaitFrame` calls (a second one blocks until the first
    /// frame began, §10.4) without holding `inner` while asleep.
    pub wait_lock: Mutex<()>,
}

#[derive(Debug)]
pub struct Space {
    pub session: u64,
    pub kind: SpaceKind,
    pub pose_in_parent: crate::space::Pose,
}

#[derive(Debug)]
pub struct Swapchain {
    pub session: u64,
    pub inner: Mutex<SwapchainInner>,
}

#[derive(Debug)]
pub struct ActionSet {
    pub instance: u64,
    pub name: String,
    pub localized_name: String,
    /// Once attached to a session, no action may be added (§11.5).
    pub attached: Mutex<bool>,
}

#[derive(Debug)]
pub struct Action {
    pub instance: u64,
    pub set: u64,
    pub name: String,
    pub localized_name: String,
    pub action_type: xr::ActionType,
    pub subaction_paths: Vec<u64>,
}

#[derive(Debug)]
pub struct SessionInner {
    pub state: xr::SessionState,
    pub running: bool,
    pub exit_requested: bool,
    /// The service went away: the frame functions answer
    /// SESSION_LOSS_PENDING, the others ERROR_SESSION_LOST.
    pub lost: bool,
    pub vk: Arc<Context>,
    pub link: Option<Link>,
    pub info: SystemInfo,
    pub poses: Arc<dyn PoseSource>,
    pub frame: FrameLoop,
    /// The quad layer ids set on each view by the last frame, removed when
    /// a frame no longer submits them.
    pub quads: Vec<BTreeSet<u32>>,
    pub stats: FrameStats,
    /// The action sets xrAttachSessionActionSets attached (once a session).
    pub attached_sets: Option<Vec<u64>>,
}

/// How the session's frames went, logged when it ends.
#[derive(Debug, Default)]
pub struct FrameStats {
    /// Frames whose projection reached the service.
    pub frames: u64,
    /// Of those, how the service's prediction as it took the frame (its
    /// reply's) compared with the display time the frame was rendered for
    /// (xrWaitFrame's): equal, later (the frame is late) or earlier.
    pub same: u64,
    pub later: u64,
    pub earlier: u64,
    /// Reading released images back to the host: copies and their time.
    pub copies: u64,
    pub copy_ns: u64,
    /// Texels read back.
    pub texels: u64,
    /// Sending projections to the service and waiting for its replies.
    pub send_ns: u64,
}

impl Drop for SessionInner {
    fn drop(&mut self) {
        let s = &self.stats;
        if s.frames > 0 {
            log_info!(
                "{} frames sent; the service predicted the display time xrWaitFrame gave for {}, \
                 a later refresh for {}, an earlier one for {}; copy-out: {} images, {:.3} ms \
                 each on average ({:.1} Mtexel/s); sending a view to the service: {:.3} ms",
                s.frames,
                s.same,
                s.later,
                s.earlier,
                s.copies,
                s.copy_ns as f64 / s.copies.max(1) as f64 / 1e6,
                s.texels as f64 / (s.copy_ns.max(1) as f64 / 1e9) / 1e6,
                s.send_ns as f64 / s.copies.max(1) as f64 / 1e6
            );
        }
    }
}

/// Where the frame loop is (§10.4).
#[derive(Debug, Default)]
pub struct FrameLoop {
    /// xrWaitFrame calls not yet followed by xrBeginFrame.
    pub waited: u32,
    pub begun: bool,
    /// When the frame in flight began: its capture time for the service.
    pub begun_ns: i64,
    /// The last predicted display time handed out.
    pub last_predicted: i64,
    /// When xrWaitFrame returned, by the display time it gave: a frame
    /// is made from its own wait, also where an application waits for the
    /// next frame before it ends this one (the CTS's pipelined case; with
    /// the last wait's time, the estimate jittered and frames skipped
    /// refreshes). The last few, newest last.
    pub wakes: std::collections::VecDeque<(i64, i64)>,
    /// How long a frame takes from then to its submission.
    pub make: MakeTime,
    pub frames_ended: u64,
}

impl FrameLoop {
    /// xrWaitFrame returned now with `predicted`.
    pub fn woke(&mut self, predicted: i64, now: i64) {
        if self.wakes.len() == 8 {
            self.wakes.pop_front();
        }
        self.wakes.push_back((predicted, now));
    }

    /// When the wait that gave display time `predicted` returned.
    pub fn woke_for(&self, predicted: i64) -> Option<i64> {
        self.wakes
            .iter()
            .rev()
            .find(|&&(p, _)| p == predicted)
            .map(|&(_, t)| t)
    }
}

impl SessionInner {
    /// Enters `state` and queues its event for `xrPollEvent`.
    pub fn set_state(&mut self, instance: &Instance, session: u64, state: xr::SessionState) {
        self.state = state;
        instance.push_event(Event::SessionState {
            session,
            state,
            time: now_ns(),
        });
    }

    /// The service is gone: the application hears LOSS_PENDING once.
    pub fn lose(&mut self, instance: &Instance, session: u64, why: &LinkError) {
        if !self.lost {
            log_error!("{why}; the session is lost");
            self.lost = true;
            self.link = None;
            self.set_state(instance, session, xr::SessionState::LOSS_PENDING);
        }
    }

    pub fn check_running(&self) -> XrResult {
        if self.lost {
            Err(xr::Result::ERROR_SESSION_LOST)
        } else if !self.running {
            Err(xr::Result::ERROR_SESSION_NOT_RUNNING)
        } else {
            Ok(())
        }
    }

    /// xrRequestExitSession: down to STOPPING through the states between,
    /// as the specification's state machine allows (§9.3: FOCUSED →
    /// VISIBLE → SYNCHRONIZED → STOPPING; a session begun but not yet
    /// synchronised passes through SYNCHRONIZED).
    pub fn stop(&mut self, instance: &Instance, session: u64) {
        use xr::SessionState as S;
        let path: &[S] = match self.state {
            S::FOCUSED => &[S::VISIBLE, S::SYNCHRONIZED, S::STOPPING],
            S::VISIBLE => &[S::SYNCHRONIZED, S::STOPPING],
            S::READY | S::SYNCHRONIZED => &[S::SYNCHRONIZED, S::STOPPING],
            _ => &[],
        };
        let now = self.state;
        for &state in path.iter().skip_while(|&&st| st == now) {
            self.set_state(instance, session, state);
        }
    }

    /// Moves on after the application's frame (SYNCHRONIZED after the
    /// first wait, VISIBLE and FOCUSED after the first frame ends).
    pub fn advance(&mut self, instance: &Instance, session: u64) {
        match self.state {
            xr::SessionState::READY if self.running && self.frame.waited > 0 => {
                self.set_state(instance, session, xr::SessionState::SYNCHRONIZED);
            }
            xr::SessionState::SYNCHRONIZED if self.frame.frames_ended > 0 => {
                self.set_state(instance, session, xr::SessionState::VISIBLE);
                self.set_state(instance, session, xr::SessionState::FOCUSED);
            }
            _ => {}
        }
    }
}

/// A running estimate of how long a frame takes from xrWaitFrame's return
/// to its submission to the service: a mean and a mean deviation over
/// about 8 frames, bounded at mean + 2 deviations.
#[derive(Debug, Default, Clone, Copy)]
pub struct MakeTime {
    mean: f64,
    dev: f64,
    seen: bool,
}

impl MakeTime {
    pub fn record(&mut self, ns: i64) {
        let x = ns.max(0) as f64;
        if self.seen {
            let d = x - self.mean;
            self.mean += d / 8.0;
            self.dev += (d.abs() - self.dev) / 8.0;
        } else {
            (self.mean, self.seen) = (x, true);
        }
    }

    pub fn bound_ns(&self) -> i64 {
        (self.mean + 2.0 * self.dev) as i64
    }
}

#[derive(Debug)]
pub struct SwapchainInner {
    pub vk: Arc<Context>,
    pub images: Vec<(vk::Image, vk::DeviceMemory)>,
    pub format: vk::Format,
    pub size: (u32, u32),
    pub layers: u32,
    /// Which images the application holds.
    pub cycle: ImageCycle,
    /// The image `xrEndFrame` shows: the last one released.
    pub last_released: Option<u32>,
    /// The images are in the layout an acquired image is in (set at the
    /// first acquire).
    pub laid_out: bool,
}

/// The order a swapchain's images go through (§10.1): acquired one after
/// another, the oldest acquired waited for, then released; at most every
/// image acquired at once, and a static swapchain's one image once.
#[derive(Debug)]
pub struct ImageCycle {
    count: u32,
    /// Acquired and not yet released, oldest first.
    acquired: VecDeque<u32>,
    /// The oldest acquired image was waited for.
    waited: bool,
    next: u32,
    static_image: bool,
    acquired_ever: bool,
}

impl ImageCycle {
    pub fn new(count: u32, static_image: bool) -> Self {
        Self {
            count,
            acquired: VecDeque::new(),
            waited: false,
            next: 0,
            static_image,
            acquired_ever: false,
        }
    }

    /// `xrAcquireSwapchainImage`: the next image's index.
    /// Whether an image may be acquired now (`acquire` would succeed).
    pub fn check_acquire(&self) -> XrResult {
        if self.acquired.len() as u32 >= self.count || (self.static_image && self.acquired_ever) {
            Err(xr::Result::ERROR_CALL_ORDER_INVALID)
        } else {
            Ok(())
        }
    }

    pub fn acquire(&mut self) -> XrResult<u32> {
        self.check_acquire()?;
        let i = self.next;
        self.next = (i + 1) % self.count;
        self.acquired.push_back(i);
        self.acquired_ever = true;
        Ok(i)
    }

    /// `xrWaitSwapchainImage`: the oldest acquired image, once.
    pub fn wait(&mut self) -> XrResult {
        if self.acquired.is_empty() || self.waited {
            return Err(xr::Result::ERROR_CALL_ORDER_INVALID);
        }
        self.waited = true;
        Ok(())
    }

    /// `xrReleaseSwapchainImage`: the image waited for, now released.
    pub fn release(&mut self) -> XrResult<u32> {
        if !self.waited {
            return Err(xr::Result::ERROR_CALL_ORDER_INVALID);
        }
        self.waited = false;
        self.acquired
            .pop_front()
            .ok_or(xr::Result::ERROR_CALL_ORDER_INVALID)
    }
}

impl Drop for SwapchainInner {
    fn drop(&mut self) {
        for &(image, memory) in &self.images {
            self.vk.destroy_image(image, memory);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn images_are_acquired_waited_and_released_in_order() {
        let mut c = ImageCycle::new(3, false);
        // Nothing acquired: nothing to wait for or release.
        assert_eq!(c.wait(), Err(xr::Result::ERROR_CALL_ORDER_INVALID));
        assert_eq!(c.release(), Err(xr::Result::ERROR_CALL_ORDER_INVALID));
        assert_eq!(
            (c.acquire(), c.acquire(), c.acquire()),
            (Ok(0), Ok(1), Ok(2))
        );
        // Every image held: a fourth is refused.
        assert_eq!(c.acquire(), Err(xr::Result::ERROR_CALL_ORDER_INVALID));
        // Released only after a wait, oldest first; one wait per image.
        assert_eq!(c.release(), Err(xr::Result::ERROR_CALL_ORDER_INVALID));
        assert_eq!(c.wait(), Ok(()));
        assert_eq!(c.wait(), Err(xr::Result::ERROR_CALL_ORDER_INVALID));
        assert_eq!(c.release(), Ok(0));
        // The freed image comes round again after the others.
        assert_eq!(c.acquire(), Ok(0));
        assert_eq!((c.wait(), c.release()), (Ok(()), Ok(1)));
    }

    #[test]
    fn a_static_swapchain_hands_its_image_out_once() {
        let mut c = ImageCycle::new(1, true);
        assert_eq!(c.acquire(), Ok(0));
        assert_eq!((c.wait(), c.release()), (Ok(()), Ok(0)));
        assert_eq!(c.acquire(), Err(xr::Result::ERROR_CALL_ORDER_INVALID));
    }

    #[test]
    fn the_make_time_bound_follows_the_frames() {
        let mut m = MakeTime::default();
        assert_eq!(m.bound_ns(), 0);
        for _ in 0..64 {
            m.record(1_000_000);
        }
        assert_eq!(m.bound_ns(), 1_000_000);
        for i in 0..64 {
            m.record(if i % 2 == 0 { 1_000_000 } else { 3_000_000 });
        }
        let b = m.bound_ns();
        assert!(b > 3_000_000 && b < 5_000_000, "{b}");
    }
}
