//! XR_KHR_vulkan_enable and XR_KHR_vulkan_enable2 (§12.20, §12.21): the
//! device the application renders on, and its Vulkan instance and device
//! made through the runtime.

use std::ffi::c_char;
use std::sync::{Arc, Mutex};

use ash::vk;
use ash::vk::Handle;
use openxr_sys as xr;

use crate::ffi::{XrResult, expect_type, guard, lock, non_null, non_null_mut, two_call_str};
use crate::instance::{VULKAN_ENABLE, VULKAN_ENABLE2};
use crate::session::system_of;
use crate::state::Instance;
use crate::vulkan::{Entry, pick_physical_device};

/// An instance with one of the Vulkan extensions enabled.
fn vulkan_instance(
    instance: xr::Instance,
    system: xr::SystemId,
    ext: &str,
) -> XrResult<Arc<Instance>> {
    let (inst, _) = system_of(instance, system)?;
    inst.require_extension(ext)?;
    Ok(inst)
}

fn requirements(
    instance: xr::Instance,
    system: xr::SystemId,
    req: *mut xr::GraphicsRequirementsVulkanKHR,
    ext: &str,
) -> XrResult<xr::Result> {
    let req = non_null_mut(req)?;
    let inst = vulkan_instance(instance, system, ext)?;
    // SAFETY: non-null; the application initialised its type.
    let req = unsafe { &mut *req };
    expect_type(req.ty, xr::StructureType::GRAPHICS_REQUIREMENTS_VULKAN_KHR)?;
    // Vulkan 1.0 copies are all the runtime asks of the device.
    req.min_api_version_supported = xr::Version::new(1, 0, 0);
    req.max_api_version_supported = xr::Version::new(1, 3, 0);
    lock(&inst.inner).graphics_requirements_queried = true;
    Ok(xr::Result::SUCCESS)
}

pub unsafe extern "system" fn get_vulkan_graphics_requirements_khr(
    instance: xr::Instance,
    system: xr::SystemId,
    req: *mut xr::GraphicsRequirementsVulkanKHR,
) -> xr::Result {
    guard("xrGetVulkanGraphicsRequirementsKHR", || {
        requirements(instance, system, req, VULKAN_ENABLE)
    })
}

pub unsafe extern "system" fn get_vulkan_graphics_requirements2_khr(
    instance: xr::Instance,
    system: xr::SystemId,
    req: *mut xr::GraphicsRequirementsVulkanKHR,
) -> xr::Result {
    guard("xrGetVulkanGraphicsRequirements2KHR", || {
        requirements(instance, system, req, VULKAN_ENABLE2)
    })
}

/// The Vulkan extensions the runtime needs enabled: none (the copy-out is
/// Vulkan 1.0), as the empty string.
pub unsafe extern "system" fn get_vulkan_extensions_khr(
    instance: xr::Instance,
    system: xr::SystemId,
    capacity: u32,
    count: *mut u32,
    buffer: *mut c_char,
) -> xr::Result {
    guard("xrGetVulkanInstanceExtensionsKHR", || {
        vulkan_instance(instance, system, VULKAN_ENABLE)?;
        // SAFETY: the application's buffer.
        unsafe { two_call_str(capacity, count, buffer, "") }
    })
}

fn physical_device(
    entry: &Entry,
    vk_instance: *const std::ffi::c_void,
) -> XrResult<*const std::ffi::c_void> {
    if vk_instance.is_null() {
        return Err(xr::Result::ERROR_VALIDATION_FAILURE);
    }
    // SAFETY: the application's live VkInstance (§12.20).
    let pd = unsafe { pick_physical_device(entry, vk::Instance::from_raw(vk_instance as u64)) }
        .map_err(crate::vulkan::vk_error)?;
    Ok(pd.as_raw() as *const std::ffi::c_void)
}

pub unsafe extern "system" fn get_vulkan_graphics_device_khr(
    instance: xr::Instance,
    system: xr::SystemId,
    vk_instance: xr::platform::VkInstance,
    out: *mut xr::platform::VkPhysicalDevice,
) -> xr::Result {
    guard("xrGetVulkanGraphicsDeviceKHR", || {
        let out = non_null_mut(out)?;
        vulkan_instance(instance, system, VULKAN_ENABLE)?;
        let entry = Entry::load().map_err(|e| {
            log_error!("the Vulkan loader could not be loaded: {e}");
            xr::Result::ERROR_RUNTIME_FAILURE
        })?;
        let pd = physical_device(&entry, vk_instance)?;
        // SAFETY: non-null output.
        unsafe { out.write(pd) };
        Ok(xr::Result::SUCCESS)
    })
}

/// The application's vkGetInstanceProcAddr as ash's type.
fn app_gipa(
    p: Option<xr::platform::VkGetInstanceProcAddr>,
) -> XrResult<vk::PFN_vkGetInstanceProcAddr> {
    let p = p.ok_or(xr::Result::ERROR_VALIDATION_FAILURE)?;
    // SAFETY: both are `vkGetInstanceProcAddr(instance, name)` with the
    // system calling convention; they differ only in how the handle and
    // the returned pointer are spelt.
    Ok(unsafe {
        std::mem::transmute::<xr::platform::VkGetInstanceProcAddr, vk::PFN_vkGetInstanceProcAddr>(p)
    })
}

pub unsafe extern "system" fn create_vulkan_instance_khr(
    instance: xr::Instance,
    info: *const xr::VulkanInstanceCreateInfoKHR,
    out: *mut xr::platform::VkInstance,
    vk_result: *mut xr::platform::VkResult,
) -> xr::Result {
    guard("xrCreateVulkanInstanceKHR", || {
        let info = non_null(info)?;
        let out = non_null_mut(out)?;
        let vk_result = non_null_mut(vk_result)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::VULKAN_INSTANCE_CREATE_INFO_KHR)?;
        let inst = vulkan_instance(instance, info.system_id, VULKAN_ENABLE2)?;
        let create = non_null(info.vulkan_create_info)?;
        let gipa = app_gipa(info.pfn_get_instance_proc_addr)?;
        let entry = Entry::of_app(gipa);
        // The application's own create info: the runtime needs no
        // instance extension of its own.
        // SAFETY: the application's valid VkInstanceCreateInfo and
        // allocator (§12.21).
        let made = unsafe {
            entry.ash().create_instance(
                &*create.cast::<vk::InstanceCreateInfo>(),
                info.vulkan_allocator
                    .cast::<vk::AllocationCallbacks>()
                    .as_ref(),
            )
        };
        match made {
            Ok(i) => {
                lock(&inst.inner).vk_get_instance_proc_addr = Some(gipa);
                // SAFETY: non-null outputs.
                unsafe {
                    out.write(i.handle().as_raw() as *const std::ffi::c_void);
                    vk_result.write(0);
                }
            }
            Err(e) => {
                // SAFETY: non-null output.
                unsafe { vk_result.write(e.as_raw()) };
            }
        }
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn create_vulkan_device_khr(
    instance: xr::Instance,
    info: *const xr::VulkanDeviceCreateInfoKHR,
    out: *mut xr::platform::VkDevice,
    vk_result: *mut xr::platform::VkResult,
) -> xr::Result {
    guard("xrCreateVulkanDeviceKHR", || {
        let info = non_null(info)?;
        let out = non_null_mut(out)?;
        let vk_result = non_null_mut(vk_result)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::VULKAN_DEVICE_CREATE_INFO_KHR)?;
        vulkan_instance(instance, info.system_id, VULKAN_ENABLE2)?;
        let create = non_null(info.vulkan_create_info)?;
        let gipa = app_gipa(info.pfn_get_instance_proc_addr)?;
        if info.vulkan_physical_device.is_null() {
            return Err(xr::Result::ERROR_VALIDATION_FAILURE);
        }
        let entry = Entry::of_app(gipa);
        // SAFETY: the physical device came from xrGetVulkanGraphicsDevice2KHR
        // on an instance of this vkGetInstanceProcAddr; vkCreateDevice is
        // an instance-level function of it.
        let made = unsafe {
            let vk_inst = find_instance_of(&entry, info.vulkan_physical_device)?;
            vk_inst.create_device(
                vk::PhysicalDevice::from_raw(info.vulkan_physical_device as u64),
                &*create.cast::<vk::DeviceCreateInfo>(),
                info.vulkan_allocator
                    .cast::<vk::AllocationCallbacks>()
                    .as_ref(),
            )
        };
        match made {
            Ok(d) => {
                // SAFETY: non-null outputs.
                unsafe {
                    out.write(d.handle().as_raw() as *const std::ffi::c_void);
                    vk_result.write(0);
                }
            }
            // SAFETY: non-null output.
            Err(e) => unsafe { vk_result.write(e.as_raw()) },
        }
        Ok(xr::Result::SUCCESS)
    })
}

/// The VkInstance a physical device handed out by this runtime belongs to
/// (remembered by `xrGetVulkanGraphicsDevice2KHR`), with its functions.
fn find_instance_of(entry: &Entry, pd: *const std::ffi::c_void) -> XrResult<ash::Instance> {
    let vk_instance =
        instance_of_physical_device(pd as u64).ok_or(xr::Result::ERROR_VALIDATION_FAILURE)?;
    // SAFETY: an instance the application created through this runtime
    // and queried with xrGetVulkanGraphicsDevice2KHR.
    Ok(
        unsafe {
            ash::Instance::load(entry.ash().static_fn(), vk::Instance::from_raw(vk_instance))
        },
    )
}

/// Physical devices handed out, with their instance.
static PHYSICAL_DEVICES: Mutex<Vec<(u64, u64)>> = Mutex::new(Vec::new());

/// Remembers that `pd` was handed out for `vk_instance`. A handle is an
/// address, so an instance made after another was destroyed may give its
/// physical device the same one: the newest instance replaces the older,
/// which may be gone (the CTS's repeated sessions found the dead one, and
/// the Vulkan loader aborted on it).
pub(crate) fn remember_physical_device(pd: u64, vk_instance: u64) {
    let mut known = lock(&PHYSICAL_DEVICES);
    known.retain(|&(p, _)| p != pd);
    known.push((pd, vk_instance));
}

/// The VkInstance `pd` was last handed out for.
pub(crate) fn instance_of_physical_device(pd: u64) -> Option<u64> {
    lock(&PHYSICAL_DEVICES)
        .iter()
        .find(|&&(p, _)| p == pd)
        .map(|&(_, i)| i)
}

pub unsafe extern "system" fn get_vulkan_graphics_device2_khr(
    instance: xr::Instance,
    info: *const xr::VulkanGraphicsDeviceGetInfoKHR,
    out: *mut xr::platform::VkPhysicalDevice,
) -> xr::Result {
    guard("xrGetVulkanGraphicsDevice2KHR", || {
        let info = non_null(info)?;
        let out = non_null_mut(out)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(
            info.ty,
            xr::StructureType::VULKAN_GRAPHICS_DEVICE_GET_INFO_KHR,
        )?;
        let inst = vulkan_instance(instance, info.system_id, VULKAN_ENABLE2)?;
        let gipa = lock(&inst.inner)
            .vk_get_instance_proc_addr
            .ok_or(xr::Result::ERROR_VALIDATION_FAILURE)?;
        let entry = Entry::of_app(gipa);
        let pd = physical_device(&entry, info.vulkan_instance)?;
        remember_physical_device(pd as u64, info.vulkan_instance as u64);
        // SAFETY: non-null output.
        unsafe { out.write(pd) };
        Ok(xr::Result::SUCCESS)
    })
}
