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
use crate::state::{Action, ActionSet, registry};

fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || "-_.".contains(c))
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
        let name = read_fixed(&info.action_set_name)
            .filter(|n| valid_name(n))
            .ok_or(xr::Result::ERROR_PATH_FORMAT_INVALID)?;
        read_fixed(&info.localized_action_set_name)
            .filter(|n| !n.is_empty())
            .ok_or(xr::Result::ERROR_LOCALIZED_NAME_INVALID)?;
        let mut reg = registry();
        if reg
            .action_sets
            .values()
            .any(|s| s.instance == inst.handle && s.name == name)
        {
            return Err(xr::Result::ERROR_NAME_DUPLICATED);
        }
        let h = reg.new_handle();
        reg.action_sets.insert(
            h,
            Arc::new(ActionSet {
                instance: inst.handle,
                name,
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
        let name = read_fixed(&info.action_name)
            .filter(|n| valid_name(n))
            .ok_or(xr::Result::ERROR_PATH_FORMAT_INVALID)?;
        read_fixed(&info.localized_action_name)
            .filter(|n| !n.is_empty())
            .ok_or(xr::Result::ERROR_LOCALIZED_NAME_INVALID)?;
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
                if path_string(&inst, path).is_none() {
                    return Err(xr::Result::ERROR_PATH_INVALID);
                }
                subaction_paths.push(path);
            }
        }
        let mut reg = registry();
        let h_set = set.into_raw();
        if reg
            .actions
            .values()
            .any(|a| a.set == h_set && a.name == name)
        {
            return Err(xr::Result::ERROR_NAME_DUPLICATED);
        }
        let h = reg.new_handle();
        reg.actions.insert(
            h,
            Arc::new(Action {
                instance: s.instance,
                set: h_set,
                name,
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
        let profile = path_string(&inst, info.interaction_profile.into_raw())
            .ok_or(xr::Result::ERROR_PATH_INVALID)?;
        if !profile.starts_with("/interaction_profiles/") {
            return Err(xr::Result::ERROR_PATH_UNSUPPORTED);
        }
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
            if !path.starts_with("/user/") {
                return Err(xr::Result::ERROR_PATH_UNSUPPORTED);
            }
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
        registry().session(session)?;
        let p = non_null(info.action_sets)?;
        let mut sets = Vec::new();
        for i in 0..info.count_action_sets as usize {
            // SAFETY: count_action_sets elements (the application).
            sets.push(registry().action_set(unsafe { *p.add(i) })?);
        }
        if sets.iter().any(|s| *lock(&s.attached)) {
            return Err(xr::Result::ERROR_ACTIONSETS_ALREADY_ATTACHED);
        }
        for s in sets {
            *lock(&s.attached) = true;
        }
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
        let s = registry().session(session)?;
        let inst = registry()
            .instances
            .get(&s.instance)
            .cloned()
            .ok_or(xr::Result::ERROR_HANDLE_INVALID)?;
        path_string(&inst, top_level.into_raw()).ok_or(xr::Result::ERROR_PATH_INVALID)?;
        // SAFETY: non-null; the application initialised its type.
        let out = unsafe { &mut *out };
        expect_type(out.ty, xr::StructureType::INTERACTION_PROFILE_STATE)?;
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
    let reg = registry();
    reg.session(session)?;
    let a = reg.action(info.action)?;
    if !types.contains(&a.action_type) {
        return Err(xr::Result::ERROR_ACTION_TYPE_MISMATCH);
    }
    let set = reg.action_set(xr::ActionSet::from_raw(a.set))?;
    if !*lock(&set.attached) {
        return Err(xr::Result::ERROR_ACTIONSET_NOT_ATTACHED);
    }
    let sub = info.subaction_path.into_raw();
    if sub != 0 && !a.subaction_paths.contains(&sub) {
        return Err(xr::Result::ERROR_PATH_UNSUPPORTED);
    }
    Ok(())
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
                let set = registry().action_set(a.action_set)?;
                if !*lock(&set.attached) {
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
        let reg = registry();
        reg.session(session)?;
        reg.action(info.action)?;
        drop(reg);
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
        let s = registry().session(session)?;
        let inst = registry()
            .instances
            .get(&s.instance)
            .cloned()
            .ok_or(xr::Result::ERROR_HANDLE_INVALID)?;
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
        let reg = registry();
        reg.session(session)?;
        let a = reg.action(info.action)?;
        if a.action_type != xr::ActionType::VIBRATION_OUTPUT {
            return Err(xr::Result::ERROR_ACTION_TYPE_MISMATCH);
        }
        // No actuator: the specification's answer for an unbound output.
        Ok(xr::Result::SUCCESS)
    })
}
