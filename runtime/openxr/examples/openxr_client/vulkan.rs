//! The example's Vulkan side: the device it renders with, and each
//! swapchain with the host buffer its images are copied from.

use ash::vk;
use ash::vk::Handle;
use openxr as xr;

/// A swapchain and a host buffer holding what each of its images gets.
pub(super) struct Target {
    pub(super) swapchain: xr::Swapchain<xr::Vulkan>,
    pub(super) images: Vec<vk::Image>,
    pub(super) size: (u32, u32),
    pub(super) buffer: vk::Buffer,
    pub(super) memory: vk::DeviceMemory,
}

pub(super) struct Gpu {
    /// The Vulkan loader, kept loaded: the runtime holds its
    /// vkGetInstanceProcAddr for the session's life.
    pub(super) _entry: ash::Entry,
    pub(super) instance: ash::Instance,
    pub(super) device: ash::Device,
    pub(super) physical: vk::PhysicalDevice,
    pub(super) queue: vk::Queue,
    pub(super) pool: vk::CommandPool,
    pub(super) fence: vk::Fence,
}

impl Gpu {
    /// A host-visible buffer holding `bytes`.
    pub(super) fn buffer(
        &self,
        bytes: &[u8],
    ) -> Result<(vk::Buffer, vk::DeviceMemory), vk::Result> {
        let info = vk::BufferCreateInfo::default()
            .size(bytes.len() as u64)
            .usage(vk::BufferUsageFlags::TRANSFER_SRC);
        // SAFETY: valid create infos on a live device; the memory type is
        // one the device lists as host visible and coherent, and the
        // mapping is written within its size.
        unsafe {
            let buffer = self.device.create_buffer(&info, None)?;
            let req = self.device.get_buffer_memory_requirements(buffer);
            let props = self
                .instance
                .get_physical_device_memory_properties(self.physical);
            let wanted =
                vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
            let index = (0..props.memory_type_count)
                .find(|&i| {
                    req.memory_type_bits & (1 << i) != 0
                        && props.memory_types[i as usize]
                            .property_flags
                            .contains(wanted)
                })
                .ok_or(vk::Result::ERROR_OUT_OF_HOST_MEMORY)?;
            let memory = self.device.allocate_memory(
                &vk::MemoryAllocateInfo::default()
                    .allocation_size(req.size)
                    .memory_type_index(index),
                None,
            )?;
            self.device.bind_buffer_memory(buffer, memory, 0)?;
            let p =
                self.device
                    .map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty())?;
            std::ptr::copy_nonoverlapping(bytes.as_ptr(), p.cast::<u8>(), bytes.len());
            self.device.unmap_memory(memory);
            Ok((buffer, memory))
        }
    }

    /// Copies `buffer` into `image` (acquired, in COLOR_ATTACHMENT_OPTIMAL,
    /// where it is left) and waits.
    pub(super) fn upload(
        &self,
        buffer: vk::Buffer,
        image: vk::Image,
        (w, h): (u32, u32),
    ) -> Result<(), vk::Result> {
        let range = vk::ImageSubresourceRange::default()
            .aspect_mask(vk::ImageAspectFlags::COLOR)
            .level_count(1)
            .layer_count(1);
        let to_dst = vk::ImageMemoryBarrier::default()
            .old_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
            .new_layout(vk::ImageLayout::TRANSFER_DST_OPTIMAL)
            .dst_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .image(image)
            .subresource_range(range);
        let back = to_dst
            .old_layout(vk::ImageLayout::TRANSFER_DST_OPTIMAL)
            .new_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::COLOR_ATTACHMENT_WRITE);
        let region = vk::BufferImageCopy::default()
            .image_subresource(
                vk::ImageSubresourceLayers::default()
                    .aspect_mask(vk::ImageAspectFlags::COLOR)
                    .layer_count(1),
            )
            .image_extent(vk::Extent3D {
                width: w,
                height: h,
                depth: 1,
            });
        // SAFETY: a primary buffer from our pool, recorded and submitted on
        // the queue the session was given, waited for before it is freed.
        unsafe {
            let cmd = self.device.allocate_command_buffers(
                &vk::CommandBufferAllocateInfo::default()
                    .command_pool(self.pool)
                    .command_buffer_count(1),
            )?[0];
            self.device
                .begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())?;
            self.device.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::TOP_OF_PIPE,
                vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &[to_dst],
            );
            self.device.cmd_copy_buffer_to_image(
                cmd,
                buffer,
                image,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[region],
            );
            self.device.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &[back],
            );
            self.device.end_command_buffer(cmd)?;
            let cmds = [cmd];
            self.device.queue_submit(
                self.queue,
                &[vk::SubmitInfo::default().command_buffers(&cmds)],
                self.fence,
            )?;
            self.device.wait_for_fences(&[self.fence], true, u64::MAX)?;
            self.device.reset_fences(&[self.fence])?;
            self.device.free_command_buffers(self.pool, &cmds);
        }
        Ok(())
    }
}

pub(super) fn target(
    session: &xr::Session<xr::Vulkan>,
    gpu: &Gpu,
    (w, h): (u32, u32),
    texel: impl Fn(usize, usize) -> [u8; 4],
) -> Result<Target, Box<dyn std::error::Error>> {
    let swapchain = session.create_swapchain(&xr::SwapchainCreateInfo {
        create_flags: xr::SwapchainCreateFlags::EMPTY,
        usage_flags: xr::SwapchainUsageFlags::COLOR_ATTACHMENT
            | xr::SwapchainUsageFlags::TRANSFER_DST,
        format: vk::Format::R8G8B8A8_SRGB.as_raw() as u32,
        sample_count: 1,
        width: w,
        height: h,
        face_count: 1,
        array_size: 1,
        mip_count: 1,
    })?;
    let images = swapchain
        .enumerate_images()?
        .into_iter()
        .map(vk::Image::from_raw)
        .collect();
    let mut data = Vec::with_capacity((w * h * 4) as usize);
    for y in 0..h as usize {
        for x in 0..w as usize {
            data.extend_from_slice(&texel(x, y));
        }
    }
    let (buffer, memory) = gpu.buffer(&data)?;
    Ok(Target {
        swapchain,
        images,
        size: (w, h),
        buffer,
        memory,
    })
}

pub(super) fn draw(t: &mut Target, gpu: &Gpu) -> Result<(), Box<dyn std::error::Error>> {
    let i = t.swapchain.acquire_image()?;
    t.swapchain.wait_image(xr::Duration::INFINITE)?;
    gpu.upload(t.buffer, t.images[i as usize], t.size)?;
    t.swapchain.release_image()?;
    Ok(())
}

/// The application's Vulkan device, made through the runtime
/// (XR_KHR_vulkan_enable2) on the system's Vulkan loader, with a graphics
/// queue family; and that family.
pub(super) fn gpu_for(
    instance: &xr::Instance,
    system: xr::SystemId,
) -> Result<(Gpu, u32), Box<dyn std::error::Error>> {
    // SAFETY: the system's Vulkan loader.
    let vk_entry = unsafe { ash::Entry::load() }?;
    let app = vk::ApplicationInfo::default().api_version(vk::make_api_version(0, 1, 0, 0));
    let create = vk::InstanceCreateInfo::default().application_info(&app);
    let gipa = vk_entry.static_fn().get_instance_proc_addr;
    // SAFETY: the loader's own vkGetInstanceProcAddr, given to the runtime
    // as its type (the same function, spelt by another crate); the create
    // infos outlive the calls; the handles are the ones Vulkan returned.
    let (vk_instance, physical, device, family) = unsafe {
        let gipa: openxr::sys::platform::VkGetInstanceProcAddr = std::mem::transmute(gipa);
        let raw = instance
            .create_vulkan_instance(system, gipa, (&raw const create).cast())?
            .map_err(vk::Result::from_raw)?;
        let vk_instance =
            ash::Instance::load(vk_entry.static_fn(), vk::Instance::from_raw(raw as u64));
        let physical =
            vk::PhysicalDevice::from_raw(instance.vulkan_graphics_device(system, raw)? as u64);
        let family = vk_instance
            .get_physical_device_queue_family_properties(physical)
            .iter()
            .position(|q| q.queue_flags.contains(vk::QueueFlags::GRAPHICS))
            .ok_or("no graphics queue")? as u32;
        let priorities = [1.0];
        let queues = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(family)
            .queue_priorities(&priorities)];
        let dci = vk::DeviceCreateInfo::default().queue_create_infos(&queues);
        let raw_device = instance
            .create_vulkan_device(
                system,
                gipa,
                physical.as_raw() as _,
                (&raw const dci).cast(),
            )?
            .map_err(vk::Result::from_raw)?;
        let device = ash::Device::load(
            vk_instance.fp_v1_0(),
            vk::Device::from_raw(raw_device as u64),
        );
        (vk_instance, physical, device, family)
    };
    // SAFETY: live device, a queue family it was created with.
    let (queue, pool, fence) = unsafe {
        (
            device.get_device_queue(family, 0),
            device.create_command_pool(
                &vk::CommandPoolCreateInfo::default().queue_family_index(family),
                None,
            )?,
            device.create_fence(&vk::FenceCreateInfo::default(), None)?,
        )
    };
    let gpu = Gpu {
        _entry: vk_entry,
        instance: vk_instance,
        device,
        physical,
        queue,
        pool,
        fence,
    };
    Ok((gpu, family))
}

/// The whole of an image of `(w, h)` texels.
pub(super) fn rect((w, h): (u32, u32)) -> xr::Rect2Di {
    xr::Rect2Di {
        offset: xr::Offset2Di { x: 0, y: 0 },
        extent: xr::Extent2Di {
            width: w as i32,
            height: h as i32,
        },
    }
}
