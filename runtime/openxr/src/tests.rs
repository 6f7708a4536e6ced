//! The entry points called as the loader calls them, without a service or
//! a GPU: wrong use gets the specification's error codes, never a crash.

use std::ffi::{CString, c_char};
use std::ptr;

use openxr_sys as xr;
use openxr_sys::Handle as _;
use proptest::prelude::*;

use crate::{actions, frame, get_instance_proc_addr, instance, session, spaces, swapchain, time};

fn app_info() -> xr::ApplicationInfo {
    let mut info = xr::ApplicationInfo {
        application_name: [0; xr::MAX_APPLICATION_NAME_SIZE],
        application_version: 1,
        engine_name: [0; xr::MAX_ENGINE_NAME_SIZE],
        engine_version: 0,
        api_version: xr::Version::new(1, 0, 0),
    };
    crate::ffi::write_fixed(&mut info.application_name, "nedrt-openxr tests");
    info
}

fn create(extensions: &[&str], api: xr::Version) -> Result<xr::Instance, xr::Result> {
    create_with(&[], extensions, api)
}

/// An instance with API layers named in its create info (as the loader
/// passes them on) and `extensions`, at `api`.
pub(crate) fn create_with(
    layers: &[&str],
    extensions: &[&str],
    api: xr::Version,
) -> Result<xr::Instance, xr::Result> {
    let c_strings = |names: &[&str]| -> Vec<CString> {
        names
            .iter()
            .map(|n| CString::new(*n).expect("name"))
            .collect()
    };
    let (layer_names, ext_names) = (c_strings(layers), c_strings(extensions));
    let layer_ptrs: Vec<*const c_char> = layer_names.iter().map(|n| n.as_ptr()).collect();
    let ptrs: Vec<*const c_char> = ext_names.iter().map(|n| n.as_ptr()).collect();
    let mut app = app_info();
    app.api_version = api;
    let info = xr::InstanceCreateInfo {
        ty: xr::StructureType::INSTANCE_CREATE_INFO,
        next: ptr::null(),
        create_flags: xr::InstanceCreateFlags::EMPTY,
        application_info: app,
        enabled_api_layer_count: layer_ptrs.len() as u32,
        enabled_api_layer_names: layer_ptrs.as_ptr(),
        enabled_extension_count: ptrs.len() as u32,
        enabled_extension_names: ptrs.as_ptr(),
    };
    let mut out = xr::Instance::NULL;
    // SAFETY: a valid create info whose strings outlive the call.
    let r = unsafe { instance::create_instance(&info, &mut out) };
    if r == xr::Result::SUCCESS {
        Ok(out)
    } else {
        Err(r)
    }
}

fn proc_addr(instance: xr::Instance, name: &str) -> xr::Result {
    let name = CString::new(name).expect("name");
    let mut f = None;
    // SAFETY: a C string and a writable slot.
    unsafe { get_instance_proc_addr(instance, name.as_ptr(), &mut f) }
}

#[test]
fn instances_check_their_version_extensions_and_structure() {
    assert_eq!(
        create(&["XR_KHR_opengl_enable"], xr::Version::new(1, 0, 0)),
        Err(xr::Result::ERROR_EXTENSION_NOT_PRESENT)
    );
    assert_eq!(
        create(&[], xr::Version::new(1, 1, 0)),
        Err(xr::Result::ERROR_API_VERSION_UNSUPPORTED)
    );
    let i = create(&[instance::VULKAN_ENABLE2], xr::Version::new(1, 0, 20)).expect("instance");
    // Only the instance's own extensions' functions are handed out.
    assert_eq!(
        proc_addr(i, "xrCreateVulkanInstanceKHR"),
        xr::Result::SUCCESS
    );
    assert_eq!(
        proc_addr(i, "xrGetVulkanGraphicsDeviceKHR"),
        xr::Result::ERROR_FUNCTION_UNSUPPORTED
    );
    assert_eq!(
        proc_addr(i, "xrNoSuchFunction"),
        xr::Result::ERROR_FUNCTION_UNSUPPORTED
    );
    // Without an instance, only the three §3.4 allows.
    assert_eq!(
        proc_addr(xr::Instance::NULL, "xrCreateInstance"),
        xr::Result::SUCCESS
    );
    assert_eq!(
        proc_addr(xr::Instance::NULL, "xrGetSystem"),
        xr::Result::ERROR_HANDLE_INVALID
    );
    let mut buf = xr::EventDataBuffer {
        ty: xr::StructureType::EVENT_DATA_BUFFER,
        next: ptr::null(),
        varying: [0; 4000],
    };
    // SAFETY: a live instance and an event buffer.
    let r = unsafe { instance::poll_event(i, &mut buf) };
    assert_eq!(r, xr::Result::EVENT_UNAVAILABLE);
    let mut s = [0 as c_char; xr::MAX_RESULT_STRING_SIZE];
    // SAFETY: a buffer of the size the function writes.
    unsafe { instance::result_to_string(i, xr::Result::ERROR_SESSION_LOST, s.as_mut_ptr()) };
    assert_eq!(
        crate::ffi::read_fixed(&s).as_deref(),
        Some("XR_ERROR_SESSION_LOST")
    );
    // SAFETY: as above.
    unsafe { instance::result_to_string(i, xr::Result::from_raw(-999_999), s.as_mut_ptr()) };
    assert_eq!(
        crate::ffi::read_fixed(&s).as_deref(),
        Some("XR_UNKNOWN_FAILURE_999999")
    );
    // SAFETY: a live instance, destroyed once.
    let r = unsafe { instance::destroy_instance(i) };
    assert_eq!(r, xr::Result::SUCCESS);
    // SAFETY: the same handle, now stale.
    let r = unsafe { instance::destroy_instance(i) };
    assert_eq!(r, xr::Result::ERROR_HANDLE_INVALID);
}

#[test]
fn without_a_service_the_system_is_unavailable() {
    // SAFETY: this test's own process environment, read by the runtime
    // only inside xrGetSystem below; no other test sets NEDRT_SOCKET.
    unsafe { std::env::set_var("NEDRT_SOCKET", "/nonexistent/nedrt.sock") };
    let i = create(&[instance::VULKAN_ENABLE2], xr::Version::new(1, 0, 0)).expect("instance");
    let info = xr::SystemGetInfo {
        ty: xr::StructureType::SYSTEM_GET_INFO,
        next: ptr::null(),
        form_factor: xr::FormFactor::HEAD_MOUNTED_DISPLAY,
    };
    let mut system = xr::SystemId::NULL;
    // SAFETY: valid structures.
    let r = unsafe { instance::get_system(i, &info, &mut system) };
    assert_eq!(r, xr::Result::ERROR_FORM_FACTOR_UNAVAILABLE);
    let handheld = xr::SystemGetInfo {
        form_factor: xr::FormFactor::HANDHELD_DISPLAY,
        ..info
    };
    // SAFETY: as above.
    let r = unsafe { instance::get_system(i, &handheld, &mut system) };
    assert_eq!(r, xr::Result::ERROR_FORM_FACTOR_UNSUPPORTED);
    // A system never found cannot be asked about.
    let mut props: xr::SystemProperties =
        // SAFETY: a plain C structure, all-zero then typed.
        unsafe { std::mem::zeroed() };
    props.ty = xr::StructureType::SYSTEM_PROPERTIES;
    // SAFETY: as above.
    let r = unsafe { instance::get_system_properties(i, xr::SystemId::from_raw(1), &mut props) };
    assert_eq!(r, xr::Result::ERROR_SYSTEM_INVALID);
    // SAFETY: a live instance.
    unsafe { instance::destroy_instance(i) };
}

#[test]
fn paths_are_checked_and_round_trip() {
    let i = create(&[], xr::Version::new(1, 0, 0)).expect("instance");
    let path = |s: &str| {
        let c = CString::new(s).expect("c");
        let mut p = xr::Path::NULL;
        // SAFETY: a C string and an output.
        let r = unsafe { instance::string_to_path(i, c.as_ptr(), &mut p) };
        (r, p)
    };
    let (r, p) = path("/user/hand/left");
    assert_eq!(r, xr::Result::SUCCESS);
    assert_eq!(path("/user/hand/left").1, p);
    for bad in ["user/hand", "/user//hand", "/User", "/user/", "/..", ""] {
        assert_eq!(path(bad).0, xr::Result::ERROR_PATH_FORMAT_INVALID, "{bad}");
    }
    let mut n = 0;
    let mut buf = [0 as c_char; 64];
    // SAFETY: a buffer of 64.
    let r = unsafe { instance::path_to_string(i, p, 64, &mut n, buf.as_mut_ptr()) };
    assert_eq!((r, n), (xr::Result::SUCCESS, 16));
    assert_eq!(
        crate::ffi::read_fixed(&buf).as_deref(),
        Some("/user/hand/left")
    );
    // SAFETY: an unknown path.
    let r = unsafe {
        instance::path_to_string(i, xr::Path::from_raw(999), 64, &mut n, buf.as_mut_ptr())
    };
    assert_eq!(r, xr::Result::ERROR_PATH_INVALID);
    // SAFETY: a live instance.
    unsafe { instance::destroy_instance(i) };
}

proptest! {
    /// Any handle the runtime did not give out is refused as invalid by
    /// every function that takes one, before anything else is read.
    #[test]
    fn forged_handles_are_invalid(raw in 1u64..) {
        // Handles the runtime gives out are odd; half of these are forged
        // odd ones too, and none is live (no test keeps one here).
        let invalid = xr::Result::ERROR_HANDLE_INVALID;
        let s = xr::Session::from_raw(raw);
        // SAFETY: every pointer argument is null or valid; the handle is
        // checked first.
        unsafe {
            prop_assert_eq!(session::destroy_session(s), invalid);
            prop_assert_eq!(session::end_session(s), invalid);
            prop_assert_eq!(session::request_exit_session(s), invalid);
            prop_assert_eq!(spaces::destroy_space(xr::Space::from_raw(raw)), invalid);
            prop_assert_eq!(swapchain::destroy_swapchain(xr::Swapchain::from_raw(raw)), invalid);
            prop_assert_eq!(actions::destroy_action(xr::Action::from_raw(raw)), invalid);
            prop_assert_eq!(actions::destroy_action_set(xr::ActionSet::from_raw(raw)), invalid);
            prop_assert_eq!(frame::begin_frame(s, ptr::null()), invalid);
            let mut index = 0;
            prop_assert_eq!(
                swapchain::acquire_swapchain_image(xr::Swapchain::from_raw(raw), ptr::null(), &mut index),
                invalid
            );
            let mut count = 0;
            prop_assert_eq!(
                swapchain::enumerate_swapchain_formats(s, 0, &mut count, ptr::null_mut()),
                invalid
            );
        }
    }
}

#[test]
fn timespec_conversion_is_offered_only_where_enabled_and_is_exact() {
    let plain = create(&[], xr::Version::new(1, 0, 0)).expect("instance");
    assert_eq!(
        proc_addr(plain, "xrConvertTimespecTimeToTimeKHR"),
        xr::Result::ERROR_FUNCTION_UNSUPPORTED
    );
    let i = create(
        &[instance::CONVERT_TIMESPEC_TIME],
        xr::Version::new(1, 0, 0),
    )
    .expect("instance");
    assert_eq!(
        proc_addr(i, "xrConvertTimespecTimeToTimeKHR"),
        xr::Result::SUCCESS
    );
    let ts = time::Timespec {
        tv_sec: 12,
        tv_nsec: 345,
    };
    let mut t = xr::Time::from_nanos(0);
    // SAFETY: valid pointers.
    let r = unsafe { time::convert_timespec_time_to_time_khr(i, &ts, &mut t) };
    assert_eq!((r, t.as_nanos()), (xr::Result::SUCCESS, 12_000_000_345));
    let mut back = time::Timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: valid pointers.
    let r = unsafe { time::convert_time_to_timespec_time_khr(i, t, &mut back) };
    assert_eq!((r, back), (xr::Result::SUCCESS, ts));
    // SAFETY: valid pointers; the extension is not enabled on `plain`.
    let r = unsafe { time::convert_time_to_timespec_time_khr(plain, t, &mut back) };
    assert_eq!(r, xr::Result::ERROR_FUNCTION_UNSUPPORTED);
    for h in [i, plain] {
        // SAFETY: live instances.
        unsafe { instance::destroy_instance(h) };
    }
}
