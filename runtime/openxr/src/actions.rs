//! Actions (§11): accepted, checked, and inactive: the display has no
//! controllers, so no action is ever bound and every state reads inactive.

use std::ffi::c_char;
use std::sync::{Arc, Mutex};

use openxr_sys as xr;
use openxr_sys::Handle as _;

use crate::ffi::{
    XrResult, expect_type, guard, lock, non_null, non_null_mut, read_fixed, two_call, two_call_str,
};
use crate::instance::{path_string, valid_path};
use crate::profiles::{TOP_LEVEL_USER_PATHS, profile};
use crate::session::session_and_instance;
use crate::state::{Action, ActionSet, Instance, Session, registry};

/// An action's or action set's name (§11.2): empty is NAME_INVALID, a
/// character a path component may not hold is PATH_FORMAT_INVALID.
fn check_name(name: Option<String>) -> XrResult<String> {
    let name = name
        .filter(|n| !n.is_empty())
        .ok_or(xr::Result::ERROR_NAME_INVALID)?;
    if name
        .chars()
        .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || "-_.".contains(c))
    {
        Ok(name)
    } else {
        Err(xr::Result::ERROR_PATH_FORMAT_INVALID)
    }
}

fn check_localized_name(name: Option<String>) -> XrResult<String> {
    name.filter(|n| !n.is_empty())
        .ok_or(xr::Result::ERROR_LOCALIZED_NAME_INVALID)
}

/// Whether `set` is attached to the session (§11.5).
fn attached_to(s: &Session, set: u64) -> bool {
    lock(&s.inner)
        .attached_sets
        .as_ref()
        .is_some_and(|sets| sets.contains(&set))
}

/// A query's subaction path: none (0), or one of the action's own. A value
/// that is no path is PATH_INVALID; a path the action was not created
/// with is PATH_UNSUPPORTED (§11.6).
fn check_subaction_path(inst: &Instance, a: &Action, sub: u64) -> XrResult {
    if sub == 0 {
        return Ok(());
    }
    path_string(inst, sub).ok_or(xr::Result::ERROR_PATH_INVALID)?;
    if a.subaction_paths.contains(&sub) {
        Ok(())
    } else {
        Err(xr::Result::ERROR_PATH_UNSUPPORTED)
    }
}

pub unsafe extern "system" fn create_action_set(
    instance: xr::Instance,
    info: *const xr::ActionSetCreateInfo,
    out: *mut xr::ActionSet,
) -> xr::Result {
    guard("xrCreateActionSet", || {
        let info = non_null(info)?;
        let out = non_null_mut(out)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::ACTION_SET_CREATE_INFO)?;
        let inst = registry().instance(instance)?;
        let name = check_name(read_fixed(&info.action_set_name))?;
        let localized_name = check_localized_name(read_fixed(&info.localized_action_set_name))?;
        let mut reg = registry();
        let siblings = || {
            reg.action_sets
                .values()
                .filter(|s| s.instance == inst.handle)
        };
        if siblings().any(|s| s.name == name) {
            return Err(xr::Result::ERROR_NAME_DUPLICATED);
        }
        if siblings().any(|s| s.localized_name == localized_name) {
            return Err(xr::Result::ERROR_LOCALIZED_NAME_DUPLICATED);
        }
        let h = reg.new_handle();
        reg.action_sets.insert(
            h,
            Arc::new(ActionSet {
                instance: inst.handle,
                name,
                localized_name,
                attached: Mutex::new(false),
            }),
        );
        // SAFETY: non-null output.
        unsafe { out.write(xr::ActionSet::from_raw(h)) };
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn destroy_action_set(set: xr::ActionSet) -> xr::Result {
    guard("xrDestroyActionSet", || {
        let mut reg = registry();
        let h = set.into_raw();
        reg.action_sets
            .remove(&h)
            .ok_or(xr::Result::ERROR_HANDLE_INVALID)?;
        reg.actions.retain(|_, a| a.set != h);
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn create_action(
    set: xr::ActionSet,
    info: *const xr::ActionCreateInfo,
    out: *mut xr::Action,
) -> xr::Result {
    guard("xrCreateAction", || {
        let info = non_null(info)?;
        let out = non_null_mut(out)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::ACTION_CREATE_INFO)?;
        let s = registry().action_set(set)?;
        if *lock(&s.attached) {
            return Err(xr::Result::ERROR_ACTIONSETS_ALREADY_ATTACHED);
        }
        let name = check_name(read_fixed(&info.action_name))?;
        let localized_name = check_localized_name(read_fixed(&info.localized_action_name))?;
        let inst = registry()
            .instances
            .get(&s.instance)
            .cloned()
            .ok_or(xr::Result::ERROR_HANDLE_INVALID)?;
        let mut subaction_paths = Vec::new();
        if info.count_subaction_paths > 0 {
            let p = non_null(info.subaction_paths)?;
            for i in 0..info.count_subaction_paths as usize {
                // SAFETY: count_subaction_paths elements (the application).
                let path = unsafe { *p.add(i) }.into_raw();
                let text = path_string(&inst, path).ok_or(xr::Result::ERROR_PATH_INVALID)?;
                // Only the top-level user paths, each once (§11.3).
                if !TOP_LEVEL_USER_PATHS.contains(&text.as_str()) || subaction_paths.contains(&path)
                {
                    return Err(xr::Result::ERROR_PATH_UNSUPPORTED);
                }
                subaction_paths.push(path);
            }
        }
        let mut reg = registry();
        let h_set = set.into_raw();
        let siblings = || reg.actions.values().filter(|a| a.set == h_set);
        if siblings().any(|a| a.name == name) {
            return Err(xr::Result::ERROR_NAME_DUPLICATED);
        }
        if siblings().any(|a| a.localized_name == localized_name) {
            return Err(xr::Result::ERROR_LOCALIZED_NAME_DUPLICATED);
        }
        let h = reg.new_handle();
        reg.actions.insert(
            h,
            Arc::new(Action {
                instance: s.instance,
                set: h_set,
                name,
                localized_name,
                action_type: info.action_type,
                subaction_paths,
            }),
        );
        // SAFETY: non-null output.
        unsafe { out.write(xr::Action::from_raw(h)) };
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn destroy_action(action: xr::Action) -> xr::Result {
    guard("xrDestroyAction", || {
        registry()
            .actions
            .remove(&action.into_raw())
            .ok_or(xr::Result::ERROR_HANDLE_INVALID)?;
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn suggest_interaction_profile_bindings(
    instance: xr::Instance,
    info: *const xr::InteractionProfileSuggestedBinding,
) -> xr::Result {
    guard("xrSuggestInteractionProfileBindings", || {
        let info = non_null(info)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(
            info.ty,
            xr::StructureType::INTERACTION_PROFILE_SUGGESTED_BINDING,
        )?;
        let inst = registry().instance(instance)?;
        let profile_path = path_string(&inst, info.interaction_profile.into_raw())
            .ok_or(xr::Result::ERROR_PATH_INVALID)?;
        let profile = profile(&profile_path).ok_or(xr::Result::ERROR_PATH_UNSUPPORTED)?;
        if info.count_suggested_bindings == 0 {
            return Err(xr::Result::ERROR_VALIDATION_FAILURE);
        }
        let b = non_null(info.suggested_bindings)?;
        for i in 0..info.count_suggested_bindings as usize {
            // SAFETY: count_suggested_bindings elements (the application).
            let binding = unsafe { *b.add(i) };
            let action = registry().action(binding.action)?;
            if action.instance != inst.handle {
                return Err(xr::Result::ERROR_HANDLE_INVALID);
            }
            let path = path_string(&inst, binding.binding.into_raw())
                .ok_or(xr::Result::ERROR_PATH_INVALID)?;
            if !profile.binds(&path) {
                return Err(xr::Result::ERROR_PATH_UNSUPPORTED);
            }
        }
        if lock(&inst.inner).actions_attached {
            return Err(xr::Result::ERROR_ACTIONSETS_ALREADY_ATTACHED);
        }
        // Accepted; no device here will ever fill them.
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn attach_session_action_sets(
    session: xr::Session,
    info: *const xr::SessionActionSetsAttachInfo,
) -> xr::Result {
    guard("xrAttachSessionActionSets", || {
        let info = non_null(info)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::SESSION_ACTION_SETS_ATTACH_INFO)?;
        let (s, inst) = session_and_instance(session)?;
        if info.count_action_sets == 0 {
            return Err(xr::Result::ERROR_VALIDATION_FAILURE);
        }
        let p = non_null(info.action_sets)?;
        let mut sets = Vec::new();
        for i in 0..info.count_action_sets as usize {
            // SAFETY: count_action_sets elements (the application).
            let h = unsafe { *p.add(i) };
            sets.push((h.into_raw(), registry().action_set(h)?));
        }
        let mut inner = lock(&s.inner);
        // Once a session (§11.5); a set may be attached to several.
        if inner.attached_sets.is_some() {
            return Err(xr::Result::ERROR_ACTIONSETS_ALREADY_ATTACHED);
        }
        for (_, set) in &sets {
            *lock(&set.attached) = true;
        }
        inner.attached_sets = Some(sets.into_iter().map(|(h, _)| h).collect());
        lock(&inst.inner).actions_attached = true;
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn get_current_interaction_profile(
    session: xr::Session,
    top_level: xr::Path,
    out: *mut xr::InteractionProfileState,
) -> xr::Result {
    guard("xrGetCurrentInteractionProfile", || {
        let out = non_null_mut(out)?;
        let (s, inst) = session_and_instance(session)?;
        let path =
            path_string(&inst, top_level.into_raw()).ok_or(xr::Result::ERROR_PATH_INVALID)?;
        // SAFETY: non-null; the application initialised its type.
        let out = unsafe { &mut *out };
        expect_type(out.ty, xr::StructureType::INTERACTION_PROFILE_STATE)?;
        if lock(&s.inner).attached_sets.is_none() {
            return Err(xr::Result::ERROR_ACTIONSET_NOT_ATTACHED);
        }
        if !TOP_LEVEL_USER_PATHS.contains(&path.as_str()) {
            return Err(xr::Result::ERROR_PATH_UNSUPPORTED);
        }
        out.interaction_profile = xr::Path::NULL;
        Ok(xr::Result::SUCCESS)
    })
}

/// The action of a state query, checked against the type asked for.
fn action_for(
    session: xr::Session,
    info: *const xr::ActionStateGetInfo,
    types: &[xr::ActionType],
) -> XrResult<()> {
    let info = non_null(info)?;
    // SAFETY: non-null, from the application.
    let info = unsafe { &*info };
    expect_type(info.ty, xr::StructureType::ACTION_STATE_GET_INFO)?;
    let (s, inst) = session_and_instance(session)?;
    let a = registry().action(info.action)?;
    if !types.contains(&a.action_type) {
        return Err(xr::Result::ERROR_ACTION_TYPE_MISMATCH);
    }
    if !attached_to(&s, a.set) {
        return Err(xr::Result::ERROR_ACTIONSET_NOT_ATTACHED);
    }
    check_subaction_path(&inst, &a, info.subaction_path.into_raw())
}

macro_rules! inactive_state {
    ($name:ident, $label:literal, $ty:ty, $st:expr, $types:expr) => {
        pub unsafe extern "system" fn $name(
            session: xr::Session,
            info: *const xr::ActionStateGetInfo,
            state: *mut $ty,
        ) -> xr::Result {
            guard($label, || {
                let state = non_null_mut(state)?;
                action_for(session, info, &$types)?;
                // SAFETY: non-null; the application initialised its type.
                let state = unsafe { &mut *state };
                expect_type(state.ty, $st)?;
                // SAFETY: every field after the header is plain data, and
                // all-zero is "inactive, unchanged, zero".
                unsafe {
                    let header = std::mem::size_of::<xr::StructureType>()
                        + std::mem::size_of::<*mut std::ffi::c_void>();
                    let p = (state as *mut $ty).cast::<u8>().add(header);
                    std::ptr::write_bytes(p, 0, std::mem::size_of::<$ty>() - header);
                }
                Ok(xr::Result::SUCCESS)
            })
        }
    };
}

inactive_state!(
    get_action_state_boolean,
    "xrGetActionStateBoolean",
    xr::ActionStateBoolean,
    xr::StructureType::ACTION_STATE_BOOLEAN,
    [xr::ActionType::BOOLEAN_INPUT]
);
inactive_state!(
    get_action_state_float,
    "xrGetActionStateFloat",
    xr::ActionStateFloat,
    xr::StructureType::ACTION_STATE_FLOAT,
    [xr::ActionType::FLOAT_INPUT]
);
inactive_state!(
    get_action_state_vector2f,
    "xrGetActionStateVector2f",
    xr::ActionStateVector2f,
    xr::StructureType::ACTION_STATE_VECTOR2F,
    [xr::ActionType::VECTOR2F_INPUT]
);
inactive_state!(
    get_action_state_pose,
    "xrGetActionStatePose",
    xr::ActionStatePose,
    xr::StructureType::ACTION_STATE_POSE,
    [xr::ActionType::POSE_INPUT]
);

pub unsafe extern "system" fn sync_actions(
    session: xr::Session,
    info: *const xr::ActionsSyncInfo,
) -> xr::Result {
    guard("xrSyncActions", || {
        let info = non_null(info)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::ACTIONS_SYNC_INFO)?;
        let s = registry().session(session)?;
        if info.count_active_action_sets > 0 {
            let p = non_null(info.active_action_sets)?;
            for i in 0..info.count_active_action_sets as usize {
                // SAFETY: count_active_action_sets elements.
                let a = unsafe { *p.add(i) };
                registry().action_set(a.action_set)?;
                if !attached_to(&s, a.action_set.into_raw()) {
                    return Err(xr::Result::ERROR_ACTIONSET_NOT_ATTACHED);
                }
            }
        }
        let focused = lock(&s.inner).state == xr::SessionState::FOCUSED;
        Ok(if focused {
            xr::Result::SUCCESS
        } else {
            xr::Result::SESSION_NOT_FOCUSED
        })
    })
}

pub unsafe extern "system" fn enumerate_bound_sources_for_action(
    session: xr::Session,
    info: *const xr::BoundSourcesForActionEnumerateInfo,
    capacity: u32,
    count: *mut u32,
    sources: *mut xr::Path,
) -> xr::Result {
    guard("xrEnumerateBoundSourcesForAction", || {
        let info = non_null(info)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(
            info.ty,
            xr::StructureType::BOUND_SOURCES_FOR_ACTION_ENUMERATE_INFO,
        )?;
        let (s, a) = {
            let reg = registry();
            (reg.session(session)?, reg.action(info.action)?)
        };
        if !attached_to(&s, a.set) {
            return Err(xr::Result::ERROR_ACTIONSET_NOT_ATTACHED);
        }
        // SAFETY: the application's arrays; nothing is bound.
        unsafe { two_call(capacity, count, sources, &[]) }
    })
}

pub unsafe extern "system" fn get_input_source_localized_name(
    session: xr::Session,
    info: *const xr::InputSourceLocalizedNameGetInfo,
    capacity: u32,
    count: *mut u32,
    buffer: *mut c_char,
) -> xr::Result {
    guard("xrGetInputSourceLocalizedName", || {
        let info = non_null(info)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(
            info.ty,
            xr::StructureType::INPUT_SOURCE_LOCALIZED_NAME_GET_INFO,
        )?;
        if info.which_components.is_empty() {
            return Err(xr::Result::ERROR_VALIDATION_FAILURE);
        }
        let (s, inst) = session_and_instance(session)?;
        if lock(&s.inner).attached_sets.is_none() {
            return Err(xr::Result::ERROR_ACTIONSET_NOT_ATTACHED);
        }
        let path = path_string(&inst, info.source_path.into_raw())
            .filter(|p| valid_path(p))
            .ok_or(xr::Result::ERROR_PATH_INVALID)?;
        // SAFETY: the application's buffer.
        unsafe { two_call_str(capacity, count, buffer, &path) }
    })
}

pub unsafe extern "system" fn apply_haptic_feedback(
    session: xr::Session,
    info: *const xr::HapticActionInfo,
    _feedback: *const xr::HapticBaseHeader,
) -> xr::Result {
    haptic("xrApplyHapticFeedback", session, info)
}

pub unsafe extern "system" fn stop_haptic_feedback(
    session: xr::Session,
    info: *const xr::HapticActionInfo,
) -> xr::Result {
    haptic("xrStopHapticFeedback", session, info)
}

fn haptic(name: &str, session: xr::Session, info: *const xr::HapticActionInfo) -> xr::Result {
    guard(name, || {
        let info = non_null(info)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::HAPTIC_ACTION_INFO)?;
        let (s, inst) = session_and_instance(session)?;
        let a = registry().action(info.action)?;
        if a.action_type != xr::ActionType::VIBRATION_OUTPUT {
            return Err(xr::Result::ERROR_ACTION_TYPE_MISMATCH);
        }
        if !attached_to(&s, a.set) {
            return Err(xr::Result::ERROR_ACTIONSET_NOT_ATTACHED);
        }
        check_subaction_path(&inst, &a, info.subaction_path.into_raw())?;
        // No actuator: the specification's answer for an unbound output.
        Ok(xr::Result::SUCCESS)
    })
}
