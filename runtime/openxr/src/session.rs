//! Sessions, their state machine (§9.3), spaces and views.

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};

use ash::vk;
use ash::vk::Handle;
use openxr_sys as xr;
use openxr_sys::Handle as _;

use crate::ffi::{XrResult, expect_type, guard, lock, non_null, non_null_mut, two_call_with};
use crate::link::{Link, SystemInfo};
use crate::space::{FixedHead, Pose, in_local};
use crate::state::{FrameLoop, FrameStats, Instance, SYSTEM_ID, Session, SessionInner, registry};
use crate::vulkan::{Binding, Context, Entry};

/// The graphics binding in a create info's `next` chain.
///
/// # Safety
/// `next` must be null or a valid chain of OpenXR structures.
unsafe fn vulkan_binding(mut next: *const xr::BaseInStructure) -> Option<Binding> {
    while !next.is_null() {
        // SAFETY: a valid chain (caller).
        let base = unsafe { &*next };
        if base.ty == xr::StructureType::GRAPHICS_BINDING_VULKAN_KHR {
            // SAFETY: the type says which structure this is.
            let b = unsafe { &*next.cast::<xr::GraphicsBindingVulkanKHR>() };
            return Some(Binding {
                instance: vk::Instance::from_raw(b.instance as u64),
                physical_device: vk::PhysicalDevice::from_raw(b.physical_device as u64),
                device: vk::Device::from_raw(b.device as u64),
                queue_family: b.queue_family_index,
                queue_index: b.queue_index,
            });
        }
        next = base.next;
    }
    None
}

pub unsafe extern "system" fn create_session(
    instance: xr::Instance,
    info: *const xr::SessionCreateInfo,
    out: *mut xr::Session,
) -> xr::Result {
    guard("xrCreateSession", || {
        let info = non_null(info)?;
        let out = non_null_mut(out)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::SESSION_CREATE_INFO)?;
        let inst = registry().instance(instance)?;
        if info.system_id.into_raw() != SYSTEM_ID {
            return Err(xr::Result::ERROR_SYSTEM_INVALID);
        }
        // SAFETY: the application's chain.
        let binding = unsafe { vulkan_binding(info.next.cast()) }
            .filter(|b| b.device != vk::Device::null() && b.instance != vk::Instance::null())
            .ok_or(xr::Result::ERROR_GRAPHICS_DEVICE_INVALID)?;
        if registry()
            .sessions
            .values()
            .any(|s| s.instance == inst.handle)
        {
            return Err(xr::Result::ERROR_LIMIT_REACHED);
        }
        let (system, probe, gipa) = {
            let mut i = lock(&inst.inner);
            if !i.graphics_requirements_queried {
                return Err(xr::Result::ERROR_GRAPHICS_REQUIREMENTS_CALL_MISSING);
            }
            let system = i.system.clone().ok_or(xr::Result::ERROR_SYSTEM_INVALID)?;
            (system, i.link.take(), i.vk_get_instance_proc_addr)
        };
        let link = match probe {
            Some(l) => l,
            None => Link::connect(&system.socket).map_err(|e| {
                log_error!("{e}");
                xr::Result::ERROR_RUNTIME_FAILURE
            })?,
        };
        let entry = match gipa {
            Some(g) => Entry::of_app(g),
            None => Entry::load().map_err(|e| {
                log_error!("the Vulkan loader could not be loaded: {e}");
                xr::Result::ERROR_RUNTIME_FAILURE
            })?,
        };
        // SAFETY: the application's live Vulkan objects (§12.20).
        let vk_ctx = unsafe { Context::new(entry, binding) }.map_err(crate::vulkan::vk_error)?;
        let views = system.views.len();
        let inner = SessionInner {
            state: xr::SessionState::UNKNOWN,
            running: false,
            exit_requested: false,
            lost: false,
            vk: Arc::new(vk_ctx),
            link: Some(link),
            info: system,
            poses: Arc::new(FixedHead::default()),
            frame: FrameLoop::default(),
            quads: vec![BTreeSet::new(); views],
            stats: FrameStats::default(),
            attached_sets: None,
        };
        let mut reg = registry();
        let h = reg.new_handle();
        let session = Arc::new(Session {
            handle: h,
            instance: inst.handle,
            inner: Mutex::new(inner),
            wait_lock: Mutex::new(()),
        });
        {
            let mut s = lock(&session.inner);
            s.set_state(&inst, h, xr::SessionState::IDLE);
            s.set_state(&inst, h, xr::SessionState::READY);
        }
        reg.sessions.insert(h, session);
        // SAFETY: non-null output.
        unsafe { out.write(xr::Session::from_raw(h)) };
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn destroy_session(session: xr::Session) -> xr::Result {
    guard("xrDestroySession", || {
        registry()
            .remove_session(session.into_raw())
            .ok_or(xr::Result::ERROR_HANDLE_INVALID)?;
        Ok(xr::Result::SUCCESS)
    })
}

/// The session and its instance.
pub fn session_and_instance(h: xr::Session) -> XrResult<(Arc<Session>, Arc<Instance>)> {
    let reg = registry();
    let s = reg.session(h)?;
    let i = reg
        .instances
        .get(&s.instance)
        .cloned()
        .ok_or(xr::Result::ERROR_HANDLE_INVALID)?;
    Ok((s, i))
}

pub unsafe extern "system" fn begin_session(
    session: xr::Session,
    info: *const xr::SessionBeginInfo,
) -> xr::Result {
    guard("xrBeginSession", || {
        let info = non_null(info)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::SESSION_BEGIN_INFO)?;
        let (s, _) = session_and_instance(session)?;
        let mut inner = lock(&s.inner);
        if inner.lost {
            return Err(xr::Result::ERROR_SESSION_LOST);
        }
        if info.primary_view_configuration_type != view_configuration(&inner.info) {
            return Err(xr::Result::ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED);
        }
        if inner.running {
            return Err(xr::Result::ERROR_SESSION_RUNNING);
        }
        if inner.state != xr::SessionState::READY {
            return Err(xr::Result::ERROR_SESSION_NOT_READY);
        }
        inner.running = true;
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn end_session(session: xr::Session) -> xr::Result {
    guard("xrEndSession", || {
        let (s, inst) = session_and_instance(session)?;
        let mut inner = lock(&s.inner);
        if !inner.running {
            return Err(xr::Result::ERROR_SESSION_NOT_RUNNING);
        }
        if inner.state != xr::SessionState::STOPPING {
            return Err(xr::Result::ERROR_SESSION_NOT_STOPPING);
        }
        inner.running = false;
        inner.frame = FrameLoop::default();
        inner.set_state(&inst, s.handle, xr::SessionState::IDLE);
        if inner.exit_requested {
            inner.set_state(&inst, s.handle, xr::SessionState::EXITING);
        }
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn request_exit_session(session: xr::Session) -> xr::Result {
    guard("xrRequestExitSession", || {
        let (s, inst) = session_and_instance(session)?;
        let mut inner = lock(&s.inner);
        inner.check_running()?;
        inner.exit_requested = true;
        inner.stop(&inst, s.handle);
        Ok(xr::Result::SUCCESS)
    })
}

/// The view configuration of the service's views.
pub fn view_configuration(info: &SystemInfo) -> xr::ViewConfigurationType {
    if info.views.len() == 2 {
        xr::ViewConfigurationType::PRIMARY_STEREO
    } else {
        xr::ViewConfigurationType::PRIMARY_MONO
    }
}

pub unsafe extern "system" fn locate_views(
    session: xr::Session,
    info: *const xr::ViewLocateInfo,
    state: *mut xr::ViewState,
    capacity: u32,
    count: *mut u32,
    views: *mut xr::View,
) -> xr::Result {
    guard("xrLocateViews", || {
        let info = non_null(info)?;
        let state = non_null_mut(state)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::VIEW_LOCATE_INFO)?;
        // SAFETY: non-null; the application initialised its type.
        let state = unsafe { &mut *state };
        expect_type(state.ty, xr::StructureType::VIEW_STATE)?;
        let (s, space) = {
            let reg = registry();
            (reg.session(session)?, reg.space(info.space)?)
        };
        if info.display_time.as_nanos() <= 0 {
            return Err(xr::Result::ERROR_TIME_INVALID);
        }
        let (system, poses) = {
            let inner = lock(&s.inner);
            (inner.info.clone(), inner.poses.clone())
        };
        if info.view_configuration_type != view_configuration(&system) {
            return Err(xr::Result::ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED);
        }
        let t = info.display_time.as_nanos();
        let base = in_local(poses.as_ref(), space.kind, space.pose_in_parent, t);
        let head = poses.head(t);
        let eyes = poses.eyes();
        let n = system.views.len();
        state.view_state_flags = if base.is_some() {
            xr::ViewStateFlags::ORIENTATION_VALID | xr::ViewStateFlags::POSITION_VALID
        } else {
            xr::ViewStateFlags::EMPTY
        };
        // SAFETY: the application's array, as the two-call idiom defines.
        unsafe {
            two_call_with(capacity, count, views, n, |view, v| {
                expect_type(view.ty, xr::StructureType::VIEW)?;
                let eye = if n == 2 { eyes[v] } else { Pose::IDENTITY };
                view.pose = base
                    .map_or(Pose::IDENTITY, |b| b.inverse().then(head.then(eye)))
                    .to_xr();
                let [l, r, u, d] = system.fov(v);
                view.fov = xr::Fovf {
                    angle_left: l,
                    angle_right: r,
                    angle_up: u,
                    angle_down: d,
                };
                Ok(())
            })
        }
    })
}

/// The instance a system query is for, with its system.
pub fn system_of(
    instance: xr::Instance,
    system: xr::SystemId,
) -> XrResult<(Arc<Instance>, SystemInfo)> {
    let inst = registry().instance(instance)?;
    if system.into_raw() != SYSTEM_ID {
        return Err(xr::Result::ERROR_SYSTEM_INVALID);
    }
    let info = lock(&inst.inner)
        .system
        .clone()
        .ok_or(xr::Result::ERROR_SYSTEM_INVALID)?;
    Ok((inst, info))
}
