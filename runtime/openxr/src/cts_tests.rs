//! The OpenXR-CTS's findings (docs/openxr.md, "The conformance suite")
//! that need no service or GPU, each as the CTS case saw it, so that CI
//! guards them without the CTS. Those that need a session are in
//! `examples/cts_regressions` (run by tests/service/openxr.rs).

use std::collections::VecDeque;
use std::ffi::{CString, c_char};
use std::ptr;

use openxr_sys as xr;
use openxr_sys::Handle as _;

use crate::{actions, get_instance_proc_addr, instance, pixels};

fn create_with(layers: &[&str], extensions: &[&str]) -> Result<xr::Instance, xr::Result> {
    crate::tests::create_with(layers, extensions, xr::Version::new(1, 0, 0))
}

fn destroy(i: xr::Instance) {
    // SAFETY: a live instance.
    unsafe { instance::destroy_instance(i) };
}

fn path(i: xr::Instance, s: &str) -> xr::Path {
    let c = CString::new(s).expect("c");
    let mut p = xr::Path::NULL;
    // SAFETY: a C string and an output.
    let r = unsafe { instance::string_to_path(i, c.as_ptr(), &mut p) };
    assert_eq!(r, xr::Result::SUCCESS, "{s}");
    p
}

/// Every case: the loader passes the application's create info on with
/// the API layers it loaded (the CTS's conformance layer); the runtime was
/// refusing it with XR_ERROR_API_LAYER_NOT_PRESENT.
#[test]
fn cts_every_case_api_layers_are_the_loaders() {
    let i = create_with(&["XR_APILAYER_KHRONOS_runtime_conformance"], &[]).expect("instance");
    destroy(i);
}

/// xrStructureTypeToString: an unknown value is XR_UNKNOWN_STRUCTURE_TYPE_N
/// (it was XR_TYPE_UNKNOWN_STRUCTURE_TYPE_N).
#[test]
fn cts_xr_structure_type_to_string_unknown_values() {
    let i = create_with(&[], &[]).expect("instance");
    let name = |value: i32| {
        let mut s = [0 as c_char; xr::MAX_STRUCTURE_NAME_SIZE];
        // SAFETY: a live instance and a buffer of the size written.
        let r = unsafe {
            instance::structure_type_to_string(
                i,
                xr::StructureType::from_raw(value),
                s.as_mut_ptr(),
            )
        };
        assert_eq!(r, xr::Result::SUCCESS);
        crate::ffi::read_fixed(&s).expect("a name")
    };
    assert_eq!(name(0x7fff_fffe), "XR_UNKNOWN_STRUCTURE_TYPE_2147483646");
    assert_eq!(name(1), "XR_TYPE_API_LAYER_PROPERTIES");
    destroy(i);
}

/// xrGetSystem: XR_FORM_FACTOR_MAX_ENUM is FORM_FACTOR_UNSUPPORTED (it was
/// VALIDATION_FAILURE). Answered before the service is looked for.
#[test]
fn cts_xr_get_system_unknown_form_factor() {
    let i = create_with(&[], &[]).expect("instance");
    let info = xr::SystemGetInfo {
        ty: xr::StructureType::SYSTEM_GET_INFO,
        next: ptr::null(),
        form_factor: xr::FormFactor::from_raw(0x7fff_ffff),
    };
    let mut system = xr::SystemId::NULL;
    // SAFETY: valid structures.
    let r = unsafe { instance::get_system(i, &info, &mut system) };
    assert_eq!(r, xr::Result::ERROR_FORM_FACTOR_UNSUPPORTED);
    destroy(i);
}

/// xrGetInstanceProcAddr (with -H): xrLocateSpaces resolves (it was
/// FUNCTION_UNSUPPORTED).
#[test]
fn cts_xr_get_instance_proc_addr_locate_spaces() {
    let i = create_with(&[], &[]).expect("instance");
    let name = CString::new("xrLocateSpaces").expect("name");
    let mut f = None;
    // SAFETY: a C string and a writable slot.
    let r = unsafe { get_instance_proc_addr(i, name.as_ptr(), &mut f) };
    assert_eq!(r, xr::Result::SUCCESS);
    assert!(f.is_some());
    destroy(i);
}

fn set_info(name: &str, localized: &str) -> xr::ActionSetCreateInfo {
    let mut info = xr::ActionSetCreateInfo {
        ty: xr::StructureType::ACTION_SET_CREATE_INFO,
        next: ptr::null(),
        action_set_name: [0; xr::MAX_ACTION_SET_NAME_SIZE],
        localized_action_set_name: [0; xr::MAX_LOCALIZED_ACTION_SET_NAME_SIZE],
        priority: 0,
    };
    crate::ffi::write_fixed(&mut info.action_set_name, name);
    crate::ffi::write_fixed(&mut info.localized_action_set_name, localized);
    info
}

fn create_set(i: xr::Instance, name: &str, localized: &str) -> Result<xr::ActionSet, xr::Result> {
    let mut set = xr::ActionSet::NULL;
    // SAFETY: a valid create info and an output.
    let r = unsafe { actions::create_action_set(i, &set_info(name, localized), &mut set) };
    if r == xr::Result::SUCCESS {
        Ok(set)
    } else {
        Err(r)
    }
}

fn create_action(
    set: xr::ActionSet,
    name: &str,
    localized: &str,
    ty: xr::ActionType,
    subaction_paths: &[xr::Path],
) -> Result<xr::Action, xr::Result> {
    let mut info = xr::ActionCreateInfo {
        ty: xr::StructureType::ACTION_CREATE_INFO,
        next: ptr::null(),
        action_name: [0; xr::MAX_ACTION_NAME_SIZE],
        action_type: ty,
        count_subaction_paths: subaction_paths.len() as u32,
        subaction_paths: subaction_paths.as_ptr(),
        localized_action_name: [0; xr::MAX_LOCALIZED_ACTION_NAME_SIZE],
    };
    crate::ffi::write_fixed(&mut info.action_name, name);
    crate::ffi::write_fixed(&mut info.localized_action_name, localized);
    let mut action = xr::Action::NULL;
    // SAFETY: a valid create info whose paths outlive the call.
    let r = unsafe { actions::create_action(set, &info, &mut action) };
    if r == xr::Result::SUCCESS {
        Ok(action)
    } else {
        Err(r)
    }
}

/// xrCreateActionSet, "Naming rules": an empty name is NAME_INVALID (it
/// was PATH_FORMAT_INVALID); a localized name already used is
/// LOCALIZED_NAME_DUPLICATED (it was accepted), free again once its set is
/// destroyed.
#[test]
fn cts_xr_create_action_set_naming_rules() {
    let i = create_with(&[], &[]).expect("instance");
    assert_eq!(
        create_set(i, "", "a set"),
        Err(xr::Result::ERROR_NAME_INVALID)
    );
    assert_eq!(
        create_set(i, "a_set", ""),
        Err(xr::Result::ERROR_LOCALIZED_NAME_INVALID)
    );
    assert_eq!(
        create_set(i, "INVALID PATH COMPONENT", "a set"),
        Err(xr::Result::ERROR_PATH_FORMAT_INVALID)
    );
    let set = create_set(i, "a_set", "a set").expect("set");
    assert_eq!(
        create_set(i, "a_set", "another"),
        Err(xr::Result::ERROR_NAME_DUPLICATED)
    );
    assert_eq!(
        create_set(i, "set_2", "a set"),
        Err(xr::Result::ERROR_LOCALIZED_NAME_DUPLICATED)
    );
    // SAFETY: a live action set.
    let destroyed = unsafe { actions::destroy_action_set(set) };
    assert_eq!(destroyed, xr::Result::SUCCESS);
    create_set(i, "set_2", "a set").expect("the localized name is free again");
    destroy(i);
}

/// xrCreateAction, "Naming rules" and "Parameter validation": the same
/// naming rules within a set; a subaction path given twice, or one that is
/// no top-level user path, is PATH_UNSUPPORTED (both were accepted).
#[test]
fn cts_xr_create_action_names_and_subaction_paths() {
    let i = create_with(&[], &[]).expect("instance");
    let set = create_set(i, "a_set", "a set").expect("set");
    let boolean = xr::ActionType::BOOLEAN_INPUT;
    assert_eq!(
        create_action(set, "", "an action", boolean, &[]),
        Err(xr::Result::ERROR_NAME_INVALID)
    );
    create_action(set, "an_action", "an action", boolean, &[]).expect("action");
    assert_eq!(
        create_action(set, "action_2", "an action", boolean, &[]),
        Err(xr::Result::ERROR_LOCALIZED_NAME_DUPLICATED)
    );
    let head = path(i, "/user/head");
    assert_eq!(
        create_action(set, "twice", "twice", boolean, &[head, head]),
        Err(xr::Result::ERROR_PATH_UNSUPPORTED)
    );
    assert_eq!(
        create_action(
            set,
            "invalid",
            "invalid",
            boolean,
            &[path(i, "/user/invalid")]
        ),
        Err(xr::Result::ERROR_PATH_UNSUPPORTED)
    );
    assert_eq!(
        create_action(
            set,
            "unknown",
            "unknown",
            boolean,
            &[xr::Path::from_raw(0x1234)]
        ),
        Err(xr::Result::ERROR_PATH_INVALID)
    );
    create_action(
        set,
        "hands",
        "hands",
        boolean,
        &[path(i, "/user/hand/left"), path(i, "/user/hand/right")],
    )
    .expect("hands");
    destroy(i);
}

/// xrSuggestInteractionProfileBindings, "Path formats and known profiles"
/// and xrSuggestInteractionProfileBindings_avail: a profile or binding
/// OpenXR 1.0 does not define is PATH_UNSUPPORTED (both were accepted);
/// every path of every 1.0 profile is accepted.
#[test]
fn cts_xr_suggest_interaction_profile_bindings_known_paths() {
    let i = create_with(&[], &[]).expect("instance");
    let set = create_set(i, "a_set", "a set").expect("set");
    let action = create_action(set, "a", "a", xr::ActionType::BOOLEAN_INPUT, &[]).expect("action");
    let suggest = |profile: &str, binding: &str| {
        let b = xr::ActionSuggestedBinding {
            action,
            binding: path(i, binding),
        };
        let info = xr::InteractionProfileSuggestedBinding {
            ty: xr::StructureType::INTERACTION_PROFILE_SUGGESTED_BINDING,
            next: ptr::null(),
            interaction_profile: path(i, profile),
            count_suggested_bindings: 1,
            suggested_bindings: &b,
        };
        // SAFETY: valid structures that outlive the call.
        unsafe { actions::suggest_interaction_profile_bindings(i, &info) }
    };
    let simple = "/interaction_profiles/khr/simple_controller";
    assert_eq!(
        suggest(simple, "/user/hand/left/input/select/click"),
        xr::Result::SUCCESS
    );
    assert_eq!(
        suggest(simple, "/user/hand/left/input/select"),
        xr::Result::SUCCESS
    );
    for profile in [
        "/invalid",
        "/interaction_profiles",
        "/interaction_profiles/invalid",
        "/interaction_profiles/khr/simple_controller/invalid",
        "/interaction_profiles/khr/another_controller",
    ] {
        assert_eq!(
            suggest(profile, "/user/hand/left/input/select/click"),
            xr::Result::ERROR_PATH_UNSUPPORTED,
            "{profile}"
        );
    }
    for binding in [
        "/user/hand/right",
        "/user/hand/right/input",
        "/user/hand/left/input_bad/menu/click",
    ] {
        assert_eq!(
            suggest(simple, binding),
            xr::Result::ERROR_PATH_UNSUPPORTED,
            "{binding}"
        );
    }
    for p in crate::profiles::PROFILES {
        for user in p.user_paths {
            for &(only, sub) in p.components {
                if only.is_none_or(|u| u == *user) {
                    let binding = format!("{user}{sub}");
                    assert_eq!(
                        suggest(p.path, &binding),
                        xr::Result::SUCCESS,
                        "{} {binding}",
                        p.path
                    );
                }
            }
        }
    }
    destroy(i);
}

/// xrCreateSession (-H): a physical device handle is an address, reused
/// by a later VkInstance; the runtime looked up the first, destroyed
/// instance and the Vulkan loader aborted.
#[test]
fn cts_xr_create_session_reused_physical_device_handle() {
    let pd = 0x5eed_0000_0001;
    crate::graphics::remember_physical_device(pd, 0xdead);
    crate::graphics::remember_physical_device(pd, 0xbeef);
    assert_eq!(
        crate::graphics::instance_of_physical_device(pd),
        Some(0xbeef)
    );
}

/// Timed_Pipelined_Frame_Submission: an application that waits for its
/// next frame before it ends this one. Each frame's making time runs from
/// its own xrWaitFrame (by the display time it was given), not from the
/// last one; with the last, the estimate jittered and half the frames
/// skipped a refresh (overhead 1000 %, then 32–54 % with the quads cut).
#[test]
fn cts_timed_pipelined_frame_submission_make_time_per_wait() {
    let mut frames = crate::state::FrameLoop::default();
    frames.woke(1_000, 10);
    frames.woke(2_000, 20);
    assert_eq!(frames.woke_for(1_000), Some(10));
    assert_eq!(frames.woke_for(2_000), Some(20));
    assert_eq!(frames.woke_for(3_000), None);
    for k in 0..20 {
        frames.woke(10_000 + k, k);
    }
    assert_eq!(frames.woke_for(1_000), None, "only the last few are kept");
    let _: &VecDeque<(i64, i64)> = &frames.wakes;
}

/// Timed_Pipelined_Frame_Submission: the CTS's status text is a quad far
/// wider than a view (2463×212 panel pixels on a 32×48 view); the service
/// refuses a quad larger than a view, and resampling it to that size took
/// 20 ms a view. It is cut to the view, keeping the part of the image
/// there.
#[test]
fn cts_timed_pipelined_frame_submission_quads_cut_to_the_view() {
    let (centre, size, region) =
        crate::frame::cut_to_view([-1231.5, 1231.5, -106.0, 106.0], (32, 48)).expect("in view");
    assert_eq!(centre, (0.0, 0.0));
    assert_eq!(size, (32, 48));
    let [u0, v0, u1, v1] = region.0;
    assert!((u0 - (1231.5 - 16.0) / 2463.0).abs() < 1e-6);
    assert!((u1 - (1231.5 + 16.0) / 2463.0).abs() < 1e-6);
    assert!(
        (v0 - (106.0 - 24.0) / 212.0).abs() < 1e-6 && (v1 - (106.0 + 24.0) / 212.0).abs() < 1e-6
    );
    // Inside the view: the whole quad, as before.
    let (_, size, region) =
        crate::frame::cut_to_view([-4.0, 4.0, -3.0, 3.0], (32, 48)).expect("in view");
    assert_eq!((size, region), ((8, 6), pixels::Region::WHOLE));
    // Beside the view: nothing.
    assert!(crate::frame::cut_to_view([20.0, 30.0, -3.0, 3.0], (32, 48)).is_none());
    // The kept part, resampled: a ramp across the quad gives its middle.
    let ramp: Vec<f32> = (0..100).map(|x| x as f32).collect();
    let mid = pixels::resample_region(
        &ramp,
        (100, 1),
        pixels::Region([0.4, 0.0, 0.6, 1.0]),
        (2, 1),
        1,
    );
    assert!(
        (mid[0] - 44.5).abs() < 1e-4 && (mid[1] - 54.5).abs() < 1e-4,
        "{mid:?}"
    );
}
