//! Instances, the system (the service's display), events, paths and the
//! Vulkan extensions' instance-level functions.

use std::ffi::c_char;
use std::sync::{Arc, Mutex};

use openxr_sys as xr;
use openxr_sys::Handle as _;

use crate::ffi::{
    expect_type, guard, lock, non_null, non_null_mut, read_cstr, read_fixed, two_call,
    two_call_str, two_call_with, write_fixed,
};
use crate::frame::MAX_LAYERS;
use crate::link::{Link, socket_path};
use crate::session::{system_of, view_configuration};
use crate::state::{Event, Instance, InstanceInner, SYSTEM_ID, registry};

pub const VULKAN_ENABLE: &str = "XR_KHR_vulkan_enable";
pub const VULKAN_ENABLE2: &str = "XR_KHR_vulkan_enable2";
pub const CONVERT_TIMESPEC_TIME: &str = "XR_KHR_convert_timespec_time";
/// Accepted: a projection view's depth (XrCompositionLayerDepthInfoKHR in
/// its chain) is a hint a compositor may use; this one does not.
pub const COMPOSITION_LAYER_DEPTH: &str = "XR_KHR_composition_layer_depth";

/// The extensions this runtime offers, with their versions.
pub const EXTENSIONS: [(&str, u32); 4] = [
    (VULKAN_ENABLE, 8),
    (VULKAN_ENABLE2, 2),
    (CONVERT_TIMESPEC_TIME, 1),
    (COMPOSITION_LAYER_DEPTH, 6),
];

/// The runtime's version (its crate's).
fn runtime_version() -> xr::Version {
    let n = |s: &str| s.parse::<u32>().unwrap_or(0);
    xr::Version::new(
        n(env!("CARGO_PKG_VERSION_MAJOR")) as u16,
        n(env!("CARGO_PKG_VERSION_MINOR")) as u16,
        n(env!("CARGO_PKG_VERSION_PATCH")),
    )
}

pub unsafe extern "system" fn enumerate_api_layer_properties(
    capacity: u32,
    count: *mut u32,
    props: *mut xr::ApiLayerProperties,
) -> xr::Result {
    guard("xrEnumerateApiLayerProperties", || {
        // SAFETY: the application's arrays; there are no layers to write.
        unsafe { two_call(capacity, count, props, &[]) }
    })
}

pub unsafe extern "system" fn enumerate_instance_extension_properties(
    layer: *const c_char,
    capacity: u32,
    count: *mut u32,
    props: *mut xr::ExtensionProperties,
) -> xr::Result {
    guard("xrEnumerateInstanceExtensionProperties", || {
        if !layer.is_null() {
            return Err(xr::Result::ERROR_API_LAYER_NOT_PRESENT);
        }
        // SAFETY: the application's array; each element's type is checked.
        unsafe {
            two_call_with(capacity, count, props, EXTENSIONS.len(), |p, i| {
                expect_type(p.ty, xr::StructureType::EXTENSION_PROPERTIES)?;
                write_fixed(&mut p.extension_name, EXTENSIONS[i].0);
                p.extension_version = EXTENSIONS[i].1;
                Ok(())
            })
        }
    })
}

pub unsafe extern "system" fn create_instance(
    info: *const xr::InstanceCreateInfo,
    out: *mut xr::Instance,
) -> xr::Result {
    guard("xrCreateInstance", || {
        let info = non_null(info)?;
        let out = non_null_mut(out)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::INSTANCE_CREATE_INFO)?;
        let app = &info.application_info;
        let name = read_fixed(&app.application_name)
            .filter(|n| !n.is_empty())
            .ok_or(xr::Result::ERROR_NAME_INVALID)?;
        let v = app.api_version;
        // This runtime implements OpenXR 1.0.
        if v.major() != 1 || v.minor() != 0 {
            return Err(xr::Result::ERROR_API_VERSION_UNSUPPORTED);
        }
        // The API layers are the loader's: it loads them and passes the
        // application's create info on unchanged, names included, so a
        // runtime ignores them (the CTS runs with its conformance layer).
        let mut extensions = Vec::new();
        for i in 0..info.enabled_extension_count as usize {
            let names = non_null(info.enabled_extension_names)?;
            // SAFETY: enabled_extension_count C strings (the application).
            let e = unsafe { read_cstr(*names.add(i)) }?;
            if !EXTENSIONS.iter().any(|(n, _)| *n == e) {
                return Err(xr::Result::ERROR_EXTENSION_NOT_PRESENT);
            }
            extensions.push(e.to_owned());
        }
        let mut reg = registry();
        let h = reg.new_handle();
        reg.instances.insert(
            h,
            Arc::new(Instance {
                handle: h,
                extensions,
                inner: Mutex::new(InstanceInner::default()),
            }),
        );
        log_debug!("instance for {name}");
        // SAFETY: non-null output.
        unsafe { out.write(xr::Instance::from_raw(h)) };
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn destroy_instance(instance: xr::Instance) -> xr::Result {
    guard("xrDestroyInstance", || {
        registry()
            .remove_instance(instance.into_raw())
            .ok_or(xr::Result::ERROR_HANDLE_INVALID)?;
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn get_instance_properties(
    instance: xr::Instance,
    props: *mut xr::InstanceProperties,
) -> xr::Result {
    guard("xrGetInstanceProperties", || {
        let props = non_null_mut(props)?;
        registry().instance(instance)?;
        // SAFETY: non-null; the application initialised its type.
        let props = unsafe { &mut *props };
        expect_type(props.ty, xr::StructureType::INSTANCE_PROPERTIES)?;
        props.runtime_version = runtime_version();
        write_fixed(&mut props.runtime_name, "nedrt");
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn poll_event(
    instance: xr::Instance,
    buffer: *mut xr::EventDataBuffer,
) -> xr::Result {
    guard("xrPollEvent", || {
        let buffer = non_null_mut(buffer)?;
        let inst = registry().instance(instance)?;
        let Some(event) = lock(&inst.inner).events.pop_front() else {
            return Ok(xr::Result::EVENT_UNAVAILABLE);
        };
        match event {
            Event::SessionState {
                session,
                state,
                time,
            } => {
                let e = xr::EventDataSessionStateChanged {
                    ty: xr::StructureType::EVENT_DATA_SESSION_STATE_CHANGED,
                    next: std::ptr::null(),
                    session: xr::Session::from_raw(session),
                    state,
                    time: xr::Time::from_nanos(time),
                };
                // SAFETY: an XrEventDataBuffer (4000 bytes) holds every
                // event structure (§2.12); the write is unaligned-safe.
                unsafe {
                    buffer
                        .cast::<xr::EventDataSessionStateChanged>()
                        .write_unaligned(e)
                };
            }
        }
        Ok(xr::Result::SUCCESS)
    })
}

/// `XR_<NAME>` of an enumerant's Debug name, or the specification's
/// fallback for values this runtime does not know.
fn enum_name(debug: String, prefix: &str, fallback: String) -> String {
    if debug.contains('(')
        || debug.chars().any(|c| c.is_ascii_digit()) && debug.parse::<i64>().is_ok()
    {
        fallback
    } else {
        format!("{prefix}{debug}")
    }
}

pub unsafe extern "system" fn result_to_string(
    instance: xr::Instance,
    value: xr::Result,
    buffer: *mut c_char,
) -> xr::Result {
    guard("xrResultToString", || {
        let buffer = non_null_mut(buffer)?;
        registry().instance(instance)?;
        let raw = value.into_raw();
        let fallback = if raw >= 0 {
            format!("XR_UNKNOWN_SUCCESS_{raw}")
        } else {
            format!("XR_UNKNOWN_FAILURE_{}", -raw)
        };
        let s = enum_name(format!("{value:?}"), "XR_", fallback);
        // SAFETY: the buffer holds XR_MAX_RESULT_STRING_SIZE characters.
        let dst = unsafe { std::slice::from_raw_parts_mut(buffer, xr::MAX_RESULT_STRING_SIZE) };
        write_fixed(dst, &s);
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn structure_type_to_string(
    instance: xr::Instance,
    value: xr::StructureType,
    buffer: *mut c_char,
) -> xr::Result {
    guard("xrStructureTypeToString", || {
        let buffer = non_null_mut(buffer)?;
        registry().instance(instance)?;
        let fallback = format!("XR_UNKNOWN_STRUCTURE_TYPE_{}", value.into_raw());
        // The specification's names are XR_TYPE_…; openxr-sys's drop the prefix.
        // An unknown value keeps the generated XR_UNKNOWN_STRUCTURE_TYPE_N.
        let s = enum_name(format!("{value:?}"), "XR_TYPE_", fallback);
        // SAFETY: the buffer holds XR_MAX_STRUCTURE_NAME_SIZE characters.
        let dst = unsafe { std::slice::from_raw_parts_mut(buffer, xr::MAX_STRUCTURE_NAME_SIZE) };
        write_fixed(dst, &s);
        Ok(xr::Result::SUCCESS)
    })
}

/// A well-formed path (§6.1): absolute, components of lower-case letters,
/// digits, `-`, `_` and `.`, none empty or only dots.
pub fn valid_path(s: &str) -> bool {
    s.len() < xr::MAX_PATH_LENGTH
        && s.starts_with('/')
        && !s.ends_with('/')
        && s[1..].split('/').all(|c| {
            !c.is_empty()
                && !c.chars().all(|ch| ch == '.')
                && c.chars()
                    .all(|ch| ch.is_ascii_lowercase() || ch.is_ascii_digit() || "-_.".contains(ch))
        })
}

pub unsafe extern "system" fn string_to_path(
    instance: xr::Instance,
    s: *const c_char,
    out: *mut xr::Path,
) -> xr::Result {
    guard("xrStringToPath", || {
        let out = non_null_mut(out)?;
        let inst = registry().instance(instance)?;
        // SAFETY: the application's C string.
        let s = unsafe { read_cstr(s) }.map_err(|_| xr::Result::ERROR_PATH_FORMAT_INVALID)?;
        if !valid_path(s) {
            return Err(xr::Result::ERROR_PATH_FORMAT_INVALID);
        }
        let mut inner = lock(&inst.inner);
        let id = match inner.path_ids.get(s) {
            Some(&id) => id,
            None => {
                inner.paths.push(s.to_owned());
                let id = inner.paths.len() as u64;
                inner.path_ids.insert(s.to_owned(), id);
                id
            }
        };
        // SAFETY: non-null output.
        unsafe { out.write(xr::Path::from_raw(id)) };
        Ok(xr::Result::SUCCESS)
    })
}

/// A path's string, if the instance made it.
pub fn path_string(inst: &Instance, path: u64) -> Option<String> {
    let i = usize::try_from(path).ok()?.checked_sub(1)?;
    lock(&inst.inner).paths.get(i).cloned()
}

pub unsafe extern "system" fn path_to_string(
    instance: xr::Instance,
    path: xr::Path,
    capacity: u32,
    count: *mut u32,
    buffer: *mut c_char,
) -> xr::Result {
    guard("xrPathToString", || {
        let inst = registry().instance(instance)?;
        let s = path_string(&inst, path.into_raw()).ok_or(xr::Result::ERROR_PATH_INVALID)?;
        // SAFETY: the application's buffer.
        unsafe { two_call_str(capacity, count, buffer, &s) }
    })
}

pub unsafe extern "system" fn get_system(
    instance: xr::Instance,
    info: *const xr::SystemGetInfo,
    out: *mut xr::SystemId,
) -> xr::Result {
    guard("xrGetSystem", || {
        let info = non_null(info)?;
        let out = non_null_mut(out)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::SYSTEM_GET_INFO)?;
        let inst = registry().instance(instance)?;
        match info.form_factor {
            xr::FormFactor::HEAD_MOUNTED_DISPLAY => {}
            xr::FormFactor::HANDHELD_DISPLAY => {
                return Err(xr::Result::ERROR_FORM_FACTOR_UNSUPPORTED);
            }
            // Any other value names no form factor this runtime supports
            // (§5.1: FORM_FACTOR_UNSUPPORTED, as the CTS's xrGetSystem
            // case checks with XR_FORM_FACTOR_MAX_ENUM).
            _ => return Err(xr::Result::ERROR_FORM_FACTOR_UNSUPPORTED),
        }
        let mut inner = lock(&inst.inner);
        if inner.system.is_none() {
            // The display is the running service: without it the form
            // factor is there but unavailable (the application may retry).
            let link = Link::connect(&socket_path()).map_err(|e| {
                log_error!("{e}");
                xr::Result::ERROR_FORM_FACTOR_UNAVAILABLE
            })?;
            log_info!(
                "connected to the nedrt service at {}: panel {}×{}, {} view(s)",
                link.info.socket.display(),
                link.info.panel.0,
                link.info.panel.1,
                link.info.views.len()
            );
            inner.system = Some(link.info.clone());
            inner.link = Some(link);
        }
        // SAFETY: non-null output.
        unsafe { out.write(xr::SystemId::from_raw(SYSTEM_ID)) };
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn get_system_properties(
    instance: xr::Instance,
    system: xr::SystemId,
    props: *mut xr::SystemProperties,
) -> xr::Result {
    guard("xrGetSystemProperties", || {
        let props = non_null_mut(props)?;
        let (_, info) = system_of(instance, system)?;
        // SAFETY: non-null; the application initialised its type.
        let props = unsafe { &mut *props };
        expect_type(props.ty, xr::StructureType::SYSTEM_PROPERTIES)?;
        props.system_id = system;
        props.vendor_id = 0;
        let (w, h) = info.panel;
        write_fixed(
            &mut props.system_name,
            &format!(
                "nedrt multifocal display, panel {w}×{h}, {} view(s)",
                info.views.len()
            ),
        );
        props.graphics_properties = xr::SystemGraphicsProperties {
            max_swapchain_image_width: 8192,
            max_swapchain_image_height: 8192,
            max_layer_count: MAX_LAYERS,
        };
        props.tracking_properties = xr::SystemTrackingProperties {
            orientation_tracking: xr::FALSE,
            position_tracking: xr::FALSE,
        };
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn enumerate_view_configurations(
    instance: xr::Instance,
    system: xr::SystemId,
    capacity: u32,
    count: *mut u32,
    types: *mut xr::ViewConfigurationType,
) -> xr::Result {
    guard("xrEnumerateViewConfigurations", || {
        let (_, info) = system_of(instance, system)?;
        // SAFETY: the application's arrays.
        unsafe { two_call(capacity, count, types, &[view_configuration(&info)]) }
    })
}

pub unsafe extern "system" fn get_view_configuration_properties(
    instance: xr::Instance,
    system: xr::SystemId,
    kind: xr::ViewConfigurationType,
    props: *mut xr::ViewConfigurationProperties,
) -> xr::Result {
    guard("xrGetViewConfigurationProperties", || {
        let props = non_null_mut(props)?;
        let (_, info) = system_of(instance, system)?;
        if kind != view_configuration(&info) {
            return Err(xr::Result::ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED);
        }
        // SAFETY: non-null; the application initialised its type.
        let props = unsafe { &mut *props };
        expect_type(props.ty, xr::StructureType::VIEW_CONFIGURATION_PROPERTIES)?;
        props.view_configuration_type = kind;
        props.fov_mutable = xr::FALSE;
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn enumerate_view_configuration_views(
    instance: xr::Instance,
    system: xr::SystemId,
    kind: xr::ViewConfigurationType,
    capacity: u32,
    count: *mut u32,
    views: *mut xr::ViewConfigurationView,
) -> xr::Result {
    guard("xrEnumerateViewConfigurationViews", || {
        let (_, info) = system_of(instance, system)?;
        if kind != view_configuration(&info) {
            return Err(xr::Result::ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED);
        }
        // SAFETY: the application's array; each element's type is checked.
        unsafe {
            two_call_with(capacity, count, views, info.views.len(), |v, i| {
                expect_type(v.ty, xr::StructureType::VIEW_CONFIGURATION_VIEW)?;
                let (w, h) = info.view_size(i);
                // One swapchain pixel a panel pixel: the view's own size.
                v.recommended_image_rect_width = w as u32;
                v.recommended_image_rect_height = h as u32;
                v.max_image_rect_width = 8192;
                v.max_image_rect_height = 8192;
                v.recommended_swapchain_sample_count = 1;
                v.max_swapchain_sample_count = 1;
                Ok(())
            })
        }
    })
}

pub unsafe extern "system" fn enumerate_environment_blend_modes(
    instance: xr::Instance,
    system: xr::SystemId,
    kind: xr::ViewConfigurationType,
    capacity: u32,
    count: *mut u32,
    modes: *mut xr::EnvironmentBlendMode,
) -> xr::Result {
    guard("xrEnumerateEnvironmentBlendModes", || {
        let (_, info) = system_of(instance, system)?;
        if kind != view_configuration(&info) {
            return Err(xr::Result::ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED);
        }
        // SAFETY: the application's arrays.
        unsafe { two_call(capacity, count, modes, &[xr::EnvironmentBlendMode::OPAQUE]) }
    })
}
