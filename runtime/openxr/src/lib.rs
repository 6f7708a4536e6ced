//! `libnedrt_openxr.so`: nedrt as an OpenXR 1.0 runtime.
//!
//! The OpenXR loader finds this library through a runtime manifest
//! (`XR_RUNTIME_JSON`, docs/openxr.md), negotiates with
//! [`xrNegotiateLoaderRuntimeInterface`] and reaches every other function
//! through [`get_instance_proc_addr`]. The runtime is a client of a running
//! `nedrt run --source socket` (protocol version 2): the system is the
//! service's display, `xrWaitFrame` paces on its refresh, and `xrEndFrame`
//! reads each released swapchain image back on the application's Vulkan
//! queue and sends it as its view's frame or as a quad layer.
//!
//! `unsafe` lives here only: the C ABI the loader and the application call,
//! and Vulkan. Each block says why it holds.

#[macro_use]
mod log;

mod actions;
mod ffi;
mod formats;
mod frame;
mod graphics;
mod instance;
mod link;
mod pixels;
mod profiles;
mod session;
mod space;
mod spaces;
mod state;
mod swapchain;
mod time;
mod vulkan;

use std::ffi::c_char;

use openxr_sys as xr;
use openxr_sys::Handle;

pub use frame::next_frame;
pub use link::{DEFAULT_SOCKET, SystemInfo, Timing};
pub use space::{FixedHead, Pose, PoseSource};

/// The OpenXR version this runtime implements.
pub const API_VERSION: xr::Version = xr::Version::new(1, 0, 0);

/// The loader's first call (loader–runtime interface version 1).
///
/// # Safety
/// Called by the OpenXR loader with its two structures.
#[unsafe(no_mangle)]
pub unsafe extern "system" fn xrNegotiateLoaderRuntimeInterface(
    loader: *const xr::NegotiateLoaderInfo,
    request: *mut xr::NegotiateRuntimeRequest,
) -> xr::Result {
    ffi::guard("xrNegotiateLoaderRuntimeInterface", || {
        let loader = ffi::non_null(loader).map_err(|_| xr::Result::ERROR_INITIALIZATION_FAILED)?;
        let request =
            ffi::non_null_mut(request).map_err(|_| xr::Result::ERROR_INITIALIZATION_FAILED)?;
        // SAFETY: non-null structures of the loader's.
        let (loader, request) = unsafe { (&*loader, &mut *request) };
        let ok = loader.struct_type == xr::NegotiateLoaderInfo::TYPE
            && loader.min_interface_version <= 1
            && loader.max_interface_version >= 1
            && loader.min_api_version <= API_VERSION
            && loader.max_api_version >= API_VERSION
            && request.struct_type == xr::NegotiateRuntimeRequest::TYPE;
        if !ok {
            return Err(xr::Result::ERROR_INITIALIZATION_FAILED);
        }
        request.runtime_interface_version = 1;
        request.runtime_api_version = API_VERSION;
        request.get_instance_proc_addr = Some(get_instance_proc_addr);
        Ok(xr::Result::SUCCESS)
    })
}

/// A function of the table as the loader stores it.
macro_rules! f {
    ($f:path) => {
        // SAFETY: every OpenXR function pointer is stored as
        // PFN_xrVoidFunction and cast back to its own type by the caller,
        // which looked it up by this name (§3.4).
        Some(unsafe { std::mem::transmute::<*const (), xr::pfn::VoidFunction>($f as *const ()) })
    };
}

/// The function a name stands for; `None` if this runtime lacks it.
fn lookup(
    name: &str,
    has_instance: bool,
    has: impl Fn(&str) -> bool,
) -> Option<xr::pfn::VoidFunction> {
    // Before an instance exists only these three may be asked for (§3.4).
    let pre = match name {
        "xrEnumerateInstanceExtensionProperties" => {
            f!(instance::enumerate_instance_extension_properties)
        }
        "xrEnumerateApiLayerProperties" => f!(instance::enumerate_api_layer_properties),
        "xrCreateInstance" => f!(instance::create_instance),
        _ => None,
    };
    if pre.is_some() || !has_instance {
        return pre;
    }
    let v1 = instance::VULKAN_ENABLE;
    let v2 = instance::VULKAN_ENABLE2;
    match name {
        "xrGetInstanceProcAddr" => f!(get_instance_proc_addr),
        "xrDestroyInstance" => f!(instance::destroy_instance),
        "xrGetInstanceProperties" => f!(instance::get_instance_properties),
        "xrPollEvent" => f!(instance::poll_event),
        "xrResultToString" => f!(instance::result_to_string),
        "xrStructureTypeToString" => f!(instance::structure_type_to_string),
        "xrGetSystem" => f!(instance::get_system),
        "xrGetSystemProperties" => f!(instance::get_system_properties),
        "xrEnumerateEnvironmentBlendModes" => f!(instance::enumerate_environment_blend_modes),
        "xrEnumerateViewConfigurations" => f!(instance::enumerate_view_configurations),
        "xrGetViewConfigurationProperties" => f!(instance::get_view_configuration_properties),
        "xrEnumerateViewConfigurationViews" => f!(instance::enumerate_view_configuration_views),
        "xrStringToPath" => f!(instance::string_to_path),
        "xrPathToString" => f!(instance::path_to_string),
        "xrCreateSession" => f!(session::create_session),
        "xrDestroySession" => f!(session::destroy_session),
        "xrBeginSession" => f!(session::begin_session),
        "xrEndSession" => f!(session::end_session),
        "xrRequestExitSession" => f!(session::request_exit_session),
        "xrEnumerateReferenceSpaces" => f!(spaces::enumerate_reference_spaces),
        "xrCreateReferenceSpace" => f!(spaces::create_reference_space),
        "xrGetReferenceSpaceBoundsRect" => f!(spaces::get_reference_space_bounds_rect),
        "xrCreateActionSpace" => f!(spaces::create_action_space),
        "xrLocateSpace" => f!(spaces::locate_space),
        "xrLocateSpaces" => f!(spaces::locate_spaces),
        "xrDestroySpace" => f!(spaces::destroy_space),
        "xrLocateViews" => f!(session::locate_views),
        "xrEnumerateSwapchainFormats" => f!(swapchain::enumerate_swapchain_formats),
        "xrCreateSwapchain" => f!(swapchain::create_swapchain),
        "xrDestroySwapchain" => f!(swapchain::destroy_swapchain),
        "xrEnumerateSwapchainImages" => f!(swapchain::enumerate_swapchain_images),
        "xrAcquireSwapchainImage" => f!(swapchain::acquire_swapchain_image),
        "xrWaitSwapchainImage" => f!(swapchain::wait_swapchain_image),
        "xrReleaseSwapchainImage" => f!(swapchain::release_swapchain_image),
        "xrWaitFrame" => f!(frame::wait_frame),
        "xrBeginFrame" => f!(frame::begin_frame),
        "xrEndFrame" => f!(frame::end_frame),
        "xrCreateActionSet" => f!(actions::create_action_set),
        "xrDestroyActionSet" => f!(actions::destroy_action_set),
        "xrCreateAction" => f!(actions::create_action),
        "xrDestroyAction" => f!(actions::destroy_action),
        "xrSuggestInteractionProfileBindings" => f!(actions::suggest_interaction_profile_bindings),
        "xrAttachSessionActionSets" => f!(actions::attach_session_action_sets),
        "xrGetCurrentInteractionProfile" => f!(actions::get_current_interaction_profile),
        "xrGetActionStateBoolean" => f!(actions::get_action_state_boolean),
        "xrGetActionStateFloat" => f!(actions::get_action_state_float),
        "xrGetActionStateVector2f" => f!(actions::get_action_state_vector2f),
        "xrGetActionStatePose" => f!(actions::get_action_state_pose),
        "xrSyncActions" => f!(actions::sync_actions),
        "xrEnumerateBoundSourcesForAction" => f!(actions::enumerate_bound_sources_for_action),
        "xrGetInputSourceLocalizedName" => f!(actions::get_input_source_localized_name),
        "xrApplyHapticFeedback" => f!(actions::apply_haptic_feedback),
        "xrStopHapticFeedback" => f!(actions::stop_haptic_feedback),
        // XR_KHR_vulkan_enable, only where the instance enabled it.
        "xrGetVulkanInstanceExtensionsKHR" | "xrGetVulkanDeviceExtensionsKHR" if has(v1) => {
            f!(graphics::get_vulkan_extensions_khr)
        }
        "xrGetVulkanGraphicsDeviceKHR" if has(v1) => f!(graphics::get_vulkan_graphics_device_khr),
        "xrGetVulkanGraphicsRequirementsKHR" if has(v1) => {
            f!(graphics::get_vulkan_graphics_requirements_khr)
        }
        // XR_KHR_convert_timespec_time.
        "xrConvertTimespecTimeToTimeKHR" if has(instance::CONVERT_TIMESPEC_TIME) => {
            f!(time::convert_timespec_time_to_time_khr)
        }
        "xrConvertTimeToTimespecTimeKHR" if has(instance::CONVERT_TIMESPEC_TIME) => {
            f!(time::convert_time_to_timespec_time_khr)
        }
        // XR_KHR_vulkan_enable2.
        "xrCreateVulkanInstanceKHR" if has(v2) => f!(graphics::create_vulkan_instance_khr),
        "xrCreateVulkanDeviceKHR" if has(v2) => f!(graphics::create_vulkan_device_khr),
        "xrGetVulkanGraphicsDevice2KHR" if has(v2) => f!(graphics::get_vulkan_graphics_device2_khr),
        "xrGetVulkanGraphicsRequirements2KHR" if has(v2) => {
            f!(graphics::get_vulkan_graphics_requirements2_khr)
        }
        _ => None,
    }
}

/// `xrGetInstanceProcAddr`.
///
/// # Safety
/// `name` must be a C string and `function` writable, as §3.4 requires.
pub unsafe extern "system" fn get_instance_proc_addr(
    instance: xr::Instance,
    name: *const c_char,
    function: *mut Option<xr::pfn::VoidFunction>,
) -> xr::Result {
    ffi::guard("xrGetInstanceProcAddr", || {
        let function = ffi::non_null_mut(function)?;
        // SAFETY: non-null output; cleared first so a failure leaves NULL.
        unsafe { function.write(None) };
        // SAFETY: the caller's C string.
        let name = unsafe { ffi::read_cstr(name) }?;
        let inst = if instance == xr::Instance::NULL {
            None
        } else {
            Some(state::registry().instance(instance)?)
        };
        let found = lookup(name, inst.is_some(), |e| {
            inst.as_ref().is_some_and(|i| i.has_extension(e))
        });
        match found {
            Some(f) => {
                // SAFETY: non-null output.
                unsafe { function.write(Some(f)) };
                Ok(xr::Result::SUCCESS)
            }
            None if inst.is_none() => Err(xr::Result::ERROR_HANDLE_INVALID),
            None => Err(xr::Result::ERROR_FUNCTION_UNSUPPORTED),
        }
    })
}

#[cfg(test)]
mod cts_tests;
#[cfg(test)]
mod tests;
