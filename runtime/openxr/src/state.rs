//! The runtime's objects behind the handles the application holds.
//!
//! Every handle is a number this runtime gave out and looks up here, so a
//! stale, foreign or forged handle is `XR_ERROR_HANDLE_INVALID`, never a
//! dereference. Objects are `Arc`s so that an entry point can release the
//! registry's lock before it blocks (`xrWaitFrame`) or talks to the
//! service (`xrEndFrame`).

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, LazyLock, Mutex, MutexGuard};

use openxr_sys as xr;
use openxr_sys::Handle as _;

use crate::ffi::XrResult;
use crate::link::SystemInfo;
use crate::session::SessionInner;
use crate::space::SpaceKind;
use crate::swapchain::SwapchainInner;

/// Locks a mutex, recovering it if a panicking entry point poisoned it:
/// every entry point leaves its object consistent between statements, and
/// one failed call must not fail every later one.
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

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
        self.sessions.remove(&session)
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
    /// Once attached to a session, no action may be added (§11.5).
    pub attached: Mutex<bool>,
}

#[derive(Debug)]
pub struct Action {
    pub instance: u64,
    pub set: u64,
    pub name: String,
    pub action_type: xr::ActionType,
    pub subaction_paths: Vec<u64>,
}
