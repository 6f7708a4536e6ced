//! The swapchain formats this runtime offers, and how their texels read.

use ash::vk;

/// The formats a swapchain may have, most preferred first: colour (sRGB
/// first: 8 bits hold the panel's codes best, §10.1's advice), then depth
/// (for XR_KHR_composition_layer_depth; never read back).
pub const FORMATS: [vk::Format; 7] = [
    vk::Format::R8G8B8A8_SRGB,
    vk::Format::B8G8R8A8_SRGB,
    vk::Format::R8G8B8A8_UNORM,
    vk::Format::B8G8R8A8_UNORM,
    vk::Format::D32_SFLOAT,
    vk::Format::D24_UNORM_S8_UINT,
    vk::Format::D16_UNORM,
];

/// A depth format's aspects; `None` for a colour format.
pub fn depth_aspect(f: vk::Format) -> Option<vk::ImageAspectFlags> {
    match f {
        vk::Format::D32_SFLOAT | vk::Format::D16_UNORM => Some(vk::ImageAspectFlags::DEPTH),
        vk::Format::D24_UNORM_S8_UINT => {
            Some(vk::ImageAspectFlags::DEPTH | vk::ImageAspectFlags::STENCIL)
        }
        _ => None,
    }
}

/// Whether a format's bytes are sRGB-encoded, and whether red and blue
/// are swapped (BGRA); `None` for a format this runtime does not offer.
pub fn format_layout(f: vk::Format) -> Option<(bool, bool)> {
    match f {
        vk::Format::R8G8B8A8_SRGB => Some((true, false)),
        vk::Format::B8G8R8A8_SRGB => Some((true, true)),
        vk::Format::R8G8B8A8_UNORM => Some((false, false)),
        vk::Format::B8G8R8A8_UNORM => Some((false, true)),
        _ => None,
    }
}
