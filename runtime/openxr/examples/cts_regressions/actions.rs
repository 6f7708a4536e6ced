//! xrAttachSessionActionSets, xrSuggestInteractionProfileBindings and
//! StateQueryFunctionsAndHaptics: the actions' findings that need a session.

use std::ptr;

use openxr as xr;
use xr::sys;

use crate::vulkan::Gpu;
use crate::{Checks, session, states};

pub(crate) fn check(
    instance: &xr::Instance,
    system: xr::SystemId,
    gpu: &Gpu,
    family: u32,
    c: &mut Checks,
) -> Result<(), Box<dyn std::error::Error>> {
    let fp = instance.fp();
    let set = instance.create_action_set("a_set", "a set", 0)?;
    let left = instance.string_to_path("/user/hand/left")?;
    let right = instance.string_to_path("/user/hand/right")?;
    let select = set.create_action::<bool>("select", "select", &[left, right])?;
    let buzz = set.create_action::<xr::Haptic>("buzz", "buzz", &[left, right])?;
    let (s, _waiter, _stream) = session(instance, system, gpu, family)?;
    let mut profile = sys::InteractionProfileState {
        ty: sys::InteractionProfileState::TYPE,
        next: ptr::null_mut(),
        interaction_profile: sys::Path::NULL,
    };
    // SAFETY: a live session and a typed output.
    let r = unsafe { (fp.get_current_interaction_profile)(s.as_raw(), left, &mut profile) };
    c.expect(
        "xrAttachSessionActionSets: interaction profile before attaching",
        r,
        sys::Result::ERROR_ACTIONSET_NOT_ATTACHED,
    );
    let haptic_info = |sub: sys::Path| sys::HapticActionInfo {
        ty: sys::HapticActionInfo::TYPE,
        next: ptr::null(),
        action: buzz.as_raw(),
        subaction_path: sub,
    };
    // SAFETY: a live session and a typed info.
    let r = unsafe { (fp.stop_haptic_feedback)(s.as_raw(), &haptic_info(sys::Path::NULL)) };
    c.check(
        "xrAttachSessionActionSets: haptics before attaching",
        matches!(
            r,
            sys::Result::ERROR_ACTIONSET_NOT_ATTACHED | sys::Result::SESSION_NOT_FOCUSED
        ),
        || format!("{r:?}"),
    );
    let sets = [set.as_raw()];
    let attach = |count: u32| sys::SessionActionSetsAttachInfo {
        ty: sys::SessionActionSetsAttachInfo::TYPE,
        next: ptr::null(),
        count_action_sets: count,
        action_sets: sets.as_ptr(),
    };
    // SAFETY: a live session and typed infos whose array outlives them.
    let (none, first, again) = unsafe {
        (
            (fp.attach_session_action_sets)(s.as_raw(), &attach(0)),
            (fp.attach_session_action_sets)(s.as_raw(), &attach(1)),
            (fp.attach_session_action_sets)(s.as_raw(), &attach(1)),
        )
    };
    c.expect(
        "xrAttachSessionActionSets: no sets",
        none,
        sys::Result::ERROR_VALIDATION_FAILURE,
    );
    c.expect(
        "xrAttachSessionActionSets: attach",
        first,
        sys::Result::SUCCESS,
    );
    c.expect(
        "xrAttachSessionActionSets: a second attach",
        again,
        sys::Result::ERROR_ACTIONSETS_ALREADY_ATTACHED,
    );
    let binding = sys::ActionSuggestedBinding {
        action: select.as_raw(),
        binding: instance.string_to_path("/user/hand/left/input/select/click")?,
    };
    let suggested = sys::InteractionProfileSuggestedBinding {
        ty: sys::InteractionProfileSuggestedBinding::TYPE,
        next: ptr::null(),
        interaction_profile: instance
            .string_to_path("/interaction_profiles/khr/simple_controller")?,
        count_suggested_bindings: 1,
        suggested_bindings: &binding,
    };
    // SAFETY: a live instance and a typed info whose binding outlives it.
    let r = unsafe { (fp.suggest_interaction_profile_bindings)(instance.as_raw(), &suggested) };
    c.expect(
        "xrSuggestInteractionProfileBindings: after attaching",
        r,
        sys::Result::ERROR_ACTIONSETS_ALREADY_ATTACHED,
    );
    let query = |sub: sys::Path| {
        let info = sys::ActionStateGetInfo {
            ty: sys::ActionStateGetInfo::TYPE,
            next: ptr::null(),
            action: select.as_raw(),
            subaction_path: sub,
        };
        let mut state = sys::ActionStateBoolean {
            ty: sys::ActionStateBoolean::TYPE,
            next: ptr::null_mut(),
            current_state: sys::FALSE,
            changed_since_last_sync: sys::FALSE,
            last_change_time: sys::Time::from_nanos(0),
            is_active: sys::FALSE,
        };
        // SAFETY: a live session and typed structures.
        unsafe { (fp.get_action_state_boolean)(s.as_raw(), &info, &mut state) }
    };
    c.expect(
        "StateQueryFunctionsAndHaptics: no such path",
        query(sys::Path::from_raw(0x1234)),
        sys::Result::ERROR_PATH_INVALID,
    );
    let gamepad = instance.string_to_path("/user/gamepad")?;
    c.expect(
        "StateQueryFunctionsAndHaptics: a path the action lacks",
        query(gamepad),
        sys::Result::ERROR_PATH_UNSUPPORTED,
    );
    // SAFETY: a live session and a typed info.
    let r = unsafe { (fp.stop_haptic_feedback)(s.as_raw(), &haptic_info(gamepad)) };
    c.expect(
        "StateQueryFunctionsAndHaptics: haptics on a path the action lacks",
        r,
        sys::Result::ERROR_PATH_UNSUPPORTED,
    );
    drop((_waiter, _stream, s));
    states(instance)?;
    // "Can attach to multiple sessions".
    let (s2, _w2, _st2) = session(instance, system, gpu, family)?;
    // SAFETY: as above.
    let r = unsafe { (fp.attach_session_action_sets)(s2.as_raw(), &attach(1)) };
    c.expect(
        "xrAttachSessionActionSets: the same set, another session",
        r,
        sys::Result::SUCCESS,
    );
    drop((_w2, _st2, s2));
    states(instance)?;
    Ok(())
}
