//! Swapchains: images on the application's Vulkan device, handed out in
//! turn. A released image is copied out by `xrEndFrame` before it
//! returns, so an image is free again as soon as it is acquired, and
//! `xrWaitSwapchainImage` never waits.

use std::sync::{Arc, Mutex};

use ash::vk;
use ash::vk::Handle;
use openxr_sys as xr;
use openxr_sys::Handle as _;

use crate::ffi::{
    XrResult, expect_type, guard, lock, non_null, non_null_mut, two_call, two_call_with,
};
use crate::formats;
use crate::state::{ImageCycle, Swapchain, SwapchainInner, registry};
use crate::vulkan::vk_error;

/// Images a swapchain has: one being shown, one being rendered, one spare.
const IMAGES: u32 = 3;

fn usage_of(flags: xr::SwapchainUsageFlags) -> vk::ImageUsageFlags {
    let map = [
        (
            xr::SwapchainUsageFlags::COLOR_ATTACHMENT,
            vk::ImageUsageFlags::COLOR_ATTACHMENT,
        ),
        (
            xr::SwapchainUsageFlags::UNORDERED_ACCESS,
            vk::ImageUsageFlags::STORAGE,
        ),
        (
            xr::SwapchainUsageFlags::TRANSFER_SRC,
            vk::ImageUsageFlags::TRANSFER_SRC,
        ),
        (
            xr::SwapchainUsageFlags::TRANSFER_DST,
            vk::ImageUsageFlags::TRANSFER_DST,
        ),
        (
            xr::SwapchainUsageFlags::SAMPLED,
            vk::ImageUsageFlags::SAMPLED,
        ),
        (
            xr::SwapchainUsageFlags::DEPTH_STENCIL_ATTACHMENT,
            vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT,
        ),
        (
            xr::SwapchainUsageFlags::INPUT_ATTACHMENT,
            vk::ImageUsageFlags::INPUT_ATTACHMENT,
        ),
    ];
    // The copy-out reads every image: TRANSFER_SRC always.
    map.iter()
        .filter(|(x, _)| flags.contains(*x))
        .fold(vk::ImageUsageFlags::TRANSFER_SRC, |acc, (_, v)| acc | *v)
}

pub unsafe extern "system" fn enumerate_swapchain_formats(
    session: xr::Session,
    capacity: u32,
    count: *mut u32,
    formats: *mut i64,
) -> xr::Result {
    guard("xrEnumerateSwapchainFormats", || {
        registry().session(session)?;
        let list: Vec<i64> = formats::FORMATS
            .iter()
            .map(|f| i64::from(f.as_raw()))
            .collect();
        // SAFETY: the application's arrays, as the two-call idiom defines.
        unsafe { two_call(capacity, count, formats, &list) }
    })
}

pub unsafe extern "system" fn create_swapchain(
    session: xr::Session,
    info: *const xr::SwapchainCreateInfo,
    out: *mut xr::Swapchain,
) -> xr::Result {
    guard("xrCreateSwapchain", || {
        let info = non_null(info)?;
        let out = non_null_mut(out)?;
        // SAFETY: non-null, and the application passes a valid structure.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::SWAPCHAIN_CREATE_INFO)?;
        let s = registry().session(session)?;
        let vk_ctx = {
            let inner = lock(&s.inner);
            if inner.lost {
                return Err(xr::Result::ERROR_SESSION_LOST);
            }
            inner.vk.clone()
        };
        let format = i32::try_from(info.format)
            .map(vk::Format::from_raw)
            .ok()
            .filter(|f| formats::FORMATS.contains(f))
            .ok_or(xr::Result::ERROR_SWAPCHAIN_FORMAT_UNSUPPORTED)?;
        if info.width == 0 || info.height == 0 || info.array_size == 0 || info.mip_count == 0 {
            return Err(xr::Result::ERROR_VALIDATION_FAILURE);
        }
        if info.face_count != 1 || info.sample_count != 1 {
            // Cube maps and multisampled images: nothing here shows them.
            return Err(xr::Result::ERROR_FEATURE_UNSUPPORTED);
        }
        // Depth formats are for depth attachments, colour ones for colour.
        let depth = formats::depth_aspect(format).is_some();
        let depth_usage = info
            .usage_flags
            .contains(xr::SwapchainUsageFlags::DEPTH_STENCIL_ATTACHMENT);
        let color_usage = info
            .usage_flags
            .contains(xr::SwapchainUsageFlags::COLOR_ATTACHMENT);
        if (depth && color_usage) || (!depth && depth_usage) {
            return Err(xr::Result::ERROR_SWAPCHAIN_FORMAT_UNSUPPORTED);
        }
        let static_image = info
            .create_flags
            .contains(xr::SwapchainCreateFlags::STATIC_IMAGE);
        let count = if static_image { 1 } else { IMAGES };
        let flags = if info
            .usage_flags
            .contains(xr::SwapchainUsageFlags::MUTABLE_FORMAT)
        {
            vk::ImageCreateFlags::MUTABLE_FORMAT
        } else {
            vk::ImageCreateFlags::empty()
        };
        let mut inner = SwapchainInner {
            vk: vk_ctx.clone(),
            images: Vec::new(),
            format,
            size: (info.width, info.height),
            layers: info.array_size,
            cycle: ImageCycle::new(count, static_image),
            last_released: None,
            laid_out: false,
        };
        for _ in 0..count {
            let made = vk_ctx
                .create_image(
                    format,
                    (info.width, info.height),
                    info.array_size,
                    info.mip_count,
                    usage_of(info.usage_flags),
                    flags,
                )
                .map_err(vk_error)?;
            // Pushed at once: a later failure drops `inner`, which frees it.
            inner.images.push(made);
        }
        let mut reg = registry();
        let h = reg.new_handle();
        reg.swapchains.insert(
            h,
            Arc::new(Swapchain {
                session: s.handle,
                inner: Mutex::new(inner),
            }),
        );
        // SAFETY: non-null output the application provided.
        unsafe { out.write(xr::Swapchain::from_raw(h)) };
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn destroy_swapchain(swapchain: xr::Swapchain) -> xr::Result {
    guard("xrDestroySwapchain", || {
        registry()
            .swapchains
            .remove(&swapchain.into_raw())
            .ok_or(xr::Result::ERROR_HANDLE_INVALID)?;
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn enumerate_swapchain_images(
    swapchain: xr::Swapchain,
    capacity: u32,
    count: *mut u32,
    images: *mut xr::SwapchainImageBaseHeader,
) -> xr::Result {
    guard("xrEnumerateSwapchainImages", || {
        let sc = registry().swapchain(swapchain)?;
        let inner = lock(&sc.inner);
        let handles: Vec<u64> = inner.images.iter().map(|(i, _)| i.as_raw()).collect();
        let out = images.cast::<xr::SwapchainImageVulkanKHR>();
        // SAFETY: a Vulkan session's images are XrSwapchainImageVulkanKHR
        // (§12.20); each element's type is checked before it is written.
        unsafe {
            two_call_with(capacity, count, out, handles.len(), |img, i| {
                expect_type(img.ty, xr::StructureType::SWAPCHAIN_IMAGE_VULKAN_KHR)?;
                img.image = handles[i];
                Ok(())
            })
        }
    })
}

pub unsafe extern "system" fn acquire_swapchain_image(
    swapchain: xr::Swapchain,
    info: *const xr::SwapchainImageAcquireInfo,
    index: *mut u32,
) -> xr::Result {
    guard("xrAcquireSwapchainImage", || {
        let index = non_null_mut(index)?;
        if !info.is_null() {
            // SAFETY: non-null, from the application.
            let ty = unsafe { (*info).ty };
            expect_type(ty, xr::StructureType::SWAPCHAIN_IMAGE_ACQUIRE_INFO)?;
        }
        let sc = registry().swapchain(swapchain)?;
        let mut inner = lock(&sc.inner);
        inner.cycle.check_acquire()?;
        if !inner.laid_out {
            // The images' first layout is set here, not in xrCreateSwapchain:
            // the queue is the runtime's only inside the calls
            // XR_KHR_vulkan_enable lists, and this is the first of them an
            // image meets.
            let images: Vec<_> = inner.images.iter().map(|&(image, _)| image).collect();
            inner
                .vk
                .initial_layout(&images, inner.layers, inner.format)
                .map_err(vk_error)?;
            inner.laid_out = true;
        }
        let i = inner.cycle.acquire()?;
        // SAFETY: non-null output.
        unsafe { index.write(i) };
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn wait_swapchain_image(
    swapchain: xr::Swapchain,
    info: *const xr::SwapchainImageWaitInfo,
) -> xr::Result {
    guard("xrWaitSwapchainImage", || {
        let info = non_null(info)?;
        // SAFETY: non-null, from the application.
        let ty = unsafe { (*info).ty };
        expect_type(ty, xr::StructureType::SWAPCHAIN_IMAGE_WAIT_INFO)?;
        let sc = registry().swapchain(swapchain)?;
        let mut inner = lock(&sc.inner);
        inner.cycle.wait()?;
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn release_swapchain_image(
    swapchain: xr::Swapchain,
    info: *const xr::SwapchainImageReleaseInfo,
) -> xr::Result {
    guard("xrReleaseSwapchainImage", || {
        if !info.is_null() {
            // SAFETY: non-null, from the application.
            let ty = unsafe { (*info).ty };
            expect_type(ty, xr::StructureType::SWAPCHAIN_IMAGE_RELEASE_INFO)?;
        }
        let sc = registry().swapchain(swapchain)?;
        let mut inner = lock(&sc.inner);
        inner.last_released = Some(inner.cycle.release()?);
        Ok(xr::Result::SUCCESS)
    })
}

/// A released image's texels: the rect of one array layer, as RGBA8 in
/// the image's encoding, and whether that encoding is sRGB.
pub fn read_released(
    sc: &Swapchain,
    rect: xr::Rect2Di,
    layer: u32,
) -> XrResult<(Vec<u8>, (usize, usize), bool)> {
    let inner = lock(&sc.inner);
    let index = inner.last_released.ok_or(xr::Result::ERROR_LAYER_INVALID)?;
    let (w, h) = inner.size;
    check_rect(rect, (w, h))?;
    let (x, y) = (rect.offset.x, rect.offset.y);
    let (rw, rh) = (rect.extent.width, rect.extent.height);
    if layer >= inner.layers {
        return Err(xr::Result::ERROR_VALIDATION_FAILURE);
    }
    // A depth swapchain is no colour layer.
    let (srgb, bgra) =
        formats::format_layout(inner.format).ok_or(xr::Result::ERROR_LAYER_INVALID)?;
    let image = inner.images[index as usize].0;
    let mut texels = inner
        .vk
        .read_rect(image, layer, [x as u32, y as u32, rw as u32, rh as u32], 4)
        .map_err(vk_error)?;
    if bgra {
        texels.chunks_exact_mut(4).for_each(|p| p.swap(0, 2));
    }
    Ok((texels, (rw as usize, rh as usize), srgb))
}

/// Checks a layer's sub-image without reading it (§10.5's validation).
pub fn check_sub_image(sub: &xr::SwapchainSubImage) -> XrResult<Arc<Swapchain>> {
    let sc = registry().swapchain(sub.swapchain)?;
    {
        let inner = lock(&sc.inner);
        // Released at least once, and colour: a layer shows colour.
        if inner.last_released.is_none() || formats::format_layout(inner.format).is_none() {
            return Err(xr::Result::ERROR_LAYER_INVALID);
        }
        // Every layer is checked before any is read or sent, so that a
        // refused frame leaves nothing half-shown (and stays begun, §10.5).
        check_rect(sub.image_rect, inner.size)?;
        if sub.image_array_index >= inner.layers {
            return Err(xr::Result::ERROR_VALIDATION_FAILURE);
        }
    }
    Ok(sc)
}

/// A sub-image's rectangle lies inside its swapchain's images.
fn check_rect(rect: xr::Rect2Di, (w, h): (u32, u32)) -> XrResult {
    let (x, y) = (rect.offset.x, rect.offset.y);
    let (rw, rh) = (rect.extent.width, rect.extent.height);
    let inside = x >= 0
        && y >= 0
        && rw > 0
        && rh > 0
        && (i64::from(x) + i64::from(rw)) <= i64::from(w)
        && (i64::from(y) + i64::from(rh)) <= i64::from(h);
    if inside {
        Ok(())
    } else {
        Err(xr::Result::ERROR_SWAPCHAIN_RECT_INVALID)
    }
}
