//! Vulkan on the application's device: the swapchains' images, and the
//! copy of a released image back to the host (docs/openxr.md, "Copy-out").
//!
//! The application owns the instance, the device and the queue; this
//! runtime owns only what it creates on them (images, their memory, one
//! command pool, a fence, a staging buffer) and destroys those alone.

use std::sync::Mutex;

use ash::vk;

use openxr_sys as xr;

use crate::ffi::lock;

/// Vulkan's own answer, for the entry point to map.
pub type VkResult<T> = Result<T, vk::Result>;

/// Vulkan's answer as the entry point's: out of memory, or a runtime
/// failure (logged).
pub fn vk_error(e: vk::Result) -> xr::Result {
    log_error!("Vulkan: {e}");
    match e {
        vk::Result::ERROR_OUT_OF_HOST_MEMORY | vk::Result::ERROR_OUT_OF_DEVICE_MEMORY => {
            xr::Result::ERROR_OUT_OF_MEMORY
        }
        _ => xr::Result::ERROR_RUNTIME_FAILURE,
    }
}

/// How long a copy may take before the runtime calls the device lost.
const COPY_TIMEOUT_NS: u64 = 5_000_000_000;

/// A `vkGetInstanceProcAddr`: the application's (XR_KHR_vulkan_enable2) or
/// the system loader's.
pub enum Entry {
    App(ash::Entry),
    Loaded(ash::Entry),
}

impl std::fmt::Debug for Entry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::App(_) => "Entry::App",
            Self::Loaded(_) => "Entry::Loaded",
        })
    }
}

impl Entry {
    pub fn of_app(gipa: vk::PFN_vkGetInstanceProcAddr) -> Self {
        // SAFETY: the application handed this pointer to the runtime as
        // its vkGetInstanceProcAddr (XrVulkanInstanceCreateInfoKHR).
        Self::App(unsafe {
            ash::Entry::from_static_fn(ash::StaticFn {
                get_instance_proc_addr: gipa,
            })
        })
    }

    /// The system's Vulkan loader (libvulkan.so.1), for applications of
    /// XR_KHR_vulkan_enable, which never name theirs.
    pub fn load() -> Result<Self, ash::LoadingError> {
        // SAFETY: loading libvulkan runs its initialisers; it is the same
        // library the application's own Vulkan calls go through.
        unsafe { ash::Entry::load() }.map(Self::Loaded)
    }

    pub fn ash(&self) -> &ash::Entry {
        match self {
            Self::App(e) | Self::Loaded(e) => e,
        }
    }
}

/// The physical device a system's sessions render on: the first GPU,
/// else the first device (lavapipe, a CPU).
///
/// # Safety
/// `instance` must be a live instance of `entry`.
pub unsafe fn pick_physical_device(
    entry: &Entry,
    instance: vk::Instance,
) -> VkResult<vk::PhysicalDevice> {
    // SAFETY: guaranteed by the caller.
    let instance = unsafe { ash::Instance::load(entry.ash().static_fn(), instance) };
    // SAFETY: a live instance's function table.
    let devices = unsafe { instance.enumerate_physical_devices() }?;
    let gpu = devices.iter().copied().find(|&d| {
        // SAFETY: `d` was just enumerated from this instance.
        let t = unsafe { instance.get_physical_device_properties(d) }.device_type;
        matches!(
            t,
            vk::PhysicalDeviceType::DISCRETE_GPU | vk::PhysicalDeviceType::INTEGRATED_GPU
        )
    });
    gpu.or_else(|| devices.first().copied())
        .ok_or(vk::Result::ERROR_INITIALIZATION_FAILED)
}

/// A host-visible buffer the copies land in, grown as needed.
#[derive(Debug)]
struct Staging {
    buffer: vk::Buffer,
    memory: vk::DeviceMemory,
    size: u64,
    coherent: bool,
}

/// What a session made on the application's device.
pub struct Context {
    // Kept alive: `Entry::Loaded` owns the loader library the tables point into.
    _entry: Entry,
    device: ash::Device,
    memory: vk::PhysicalDeviceMemoryProperties,
    queue: vk::Queue,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    /// Held from recording to the fence: one command buffer and fence serve
    /// calls an application may make from several threads at once (the
    /// CTS's multithreading case crashed or hung on them).
    submitting: Mutex<()>,
    staging: Mutex<Option<Staging>>,
}

impl std::fmt::Debug for Context {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Context")
            .field("device", &self.device.handle())
            .field("queue", &self.queue)
            .finish_non_exhaustive()
    }
}

/// The application's graphics binding (XrGraphicsBindingVulkanKHR).
#[derive(Debug, Clone, Copy)]
pub struct Binding {
    pub instance: vk::Instance,
    pub physical_device: vk::PhysicalDevice,
    pub device: vk::Device,
    pub queue_family: u32,
    pub queue_index: u32,
}

impl Context {
    /// # Safety
    /// The binding's handles must be live objects of `entry`'s Vulkan, the
    /// queue one the device was created with (the application guarantees
    /// both, §12.20).
    pub unsafe fn new(entry: Entry, b: Binding) -> VkResult<Self> {
        // SAFETY: guaranteed by the caller.
        let instance = unsafe { ash::Instance::load(entry.ash().static_fn(), b.instance) };
        // SAFETY: as above.
        let device = unsafe { ash::Device::load(instance.fp_v1_0(), b.device) };
        // SAFETY: the physical device belongs to the instance.
        let memory = unsafe { instance.get_physical_device_memory_properties(b.physical_device) };
        // SAFETY: the queue family and index were the device's (caller).
        let queue = unsafe { device.get_device_queue(b.queue_family, b.queue_index) };
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(b.queue_family)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        // SAFETY: a valid create info on a live device.
        let pool = unsafe { device.create_command_pool(&pool_info, None) }?;
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: the pool was just created on this device.
        let cmd = match unsafe { device.allocate_command_buffers(&alloc) } {
            Ok(c) => c[0],
            Err(e) => {
                // SAFETY: nothing else uses the pool yet.
                unsafe { device.destroy_command_pool(pool, None) };
                return Err(e);
            }
        };
        // SAFETY: a default fence on a live device.
        let fence = match unsafe { device.create_fence(&vk::FenceCreateInfo::default(), None) } {
            Ok(f) => f,
            Err(e) => {
                // SAFETY: as above.
                unsafe { device.destroy_command_pool(pool, None) };
                return Err(e);
            }
        };
        Ok(Self {
            _entry: entry,
            device,
            memory,
            queue,
            pool,
            cmd,
            fence,
            submitting: Mutex::new(()),
            staging: Mutex::new(None),
        })
    }

    fn memory_type(&self, bits: u32, wanted: vk::MemoryPropertyFlags) -> Option<u32> {
        (0..self.memory.memory_type_count).find(|&i| {
            bits & (1 << i) != 0
                && self.memory.memory_types[i as usize]
                    .property_flags
                    .contains(wanted)
        })
    }

    /// A 2-D image (with `layers` array layers) in device memory.
    pub fn create_image(
        &self,
        format: vk::Format,
        (width, height): (u32, u32),
        layers: u32,
        mips: u32,
        usage: vk::ImageUsageFlags,
        flags: vk::ImageCreateFlags,
    ) -> VkResult<(vk::Image, vk::DeviceMemory)> {
        let info = vk::ImageCreateInfo::default()
            .flags(flags)
            .image_type(vk::ImageType::TYPE_2D)
            .format(format)
            .extent(vk::Extent3D {
                width,
                height,
                depth: 1,
            })
            .mip_levels(mips)
            .array_layers(layers)
            .samples(vk::SampleCountFlags::TYPE_1)
            .tiling(vk::ImageTiling::OPTIMAL)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE)
            .initial_layout(vk::ImageLayout::UNDEFINED);
        // SAFETY: a valid create info on the application's live device.
        let image = unsafe { self.device.create_image(&info, None) }?;
        // SAFETY: the image was just created on this device.
        let req = unsafe { self.device.get_image_memory_requirements(image) };
        let destroy = |e| {
            // SAFETY: the image is ours and unused.
            unsafe { self.device.destroy_image(image, None) };
            e
        };
        let Some(type_index) = self
            .memory_type(req.memory_type_bits, vk::MemoryPropertyFlags::DEVICE_LOCAL)
            .or_else(|| self.memory_type(req.memory_type_bits, vk::MemoryPropertyFlags::empty()))
        else {
            return Err(destroy(vk::Result::ERROR_OUT_OF_DEVICE_MEMORY));
        };
        let alloc = vk::MemoryAllocateInfo::default()
            .allocation_size(req.size)
            .memory_type_index(type_index);
        // SAFETY: a type index the device listed.
        let memory = unsafe { self.device.allocate_memory(&alloc, None) }.map_err(destroy)?;
        // SAFETY: fresh image and memory of the size it asked for.
        if let Err(e) = unsafe { self.device.bind_image_memory(image, memory, 0) } {
            // SAFETY: ours, unused.
            unsafe { self.device.free_memory(memory, None) };
            return Err(destroy(e));
        }
        Ok((image, memory))
    }

    pub fn destroy_image(&self, image: vk::Image, memory: vk::DeviceMemory) {
        // SAFETY: the runtime made both; a swapchain is destroyed only
        // once the application no longer uses its images (§10.1), and
        // every copy of ours waited on its fence.
        unsafe {
            self.device.destroy_image(image, None);
            self.device.free_memory(memory, None);
        }
    }

    /// Records `record` into the command buffer, submits it to the
    /// application's queue and waits for it. The queue is the
    /// application's: OpenXR lets the runtime use it only inside
    /// xrBeginFrame, xrEndFrame, xrAcquireSwapchainImage and
    /// xrReleaseSwapchainImage (XR_KHR_vulkan_enable, "Concurrency"), which
    /// the application keeps from its own use of the queue.
    fn submit(&self, record: impl FnOnce(&ash::Device, vk::CommandBuffer)) -> VkResult<()> {
        let _one_at_a_time = lock(&self.submitting);
        let d = &self.device;
        // SAFETY: the buffer is ours, and idle: every submission waits for
        // its fence before returning.
        unsafe {
            d.reset_command_buffer(self.cmd, vk::CommandBufferResetFlags::empty())?;
            d.begin_command_buffer(
                self.cmd,
                &vk::CommandBufferBeginInfo::default()
                    .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
            )?;
        }
        record(d, self.cmd);
        let cmds = [self.cmd];
        let submit = vk::SubmitInfo::default().command_buffers(&cmds);
        // SAFETY: recorded above; the fence is unsignalled (reset after
        // each wait).
        unsafe {
            d.end_command_buffer(self.cmd)?;
            d.queue_submit(self.queue, &[submit], self.fence)?;
            let waited = d.wait_for_fences(&[self.fence], true, COPY_TIMEOUT_NS);
            d.reset_fences(&[self.fence])?;
            waited
        }
    }

    /// Moves new images to `layout`, where the application finds a
    /// swapchain image it acquires (§12.20: COLOR_ATTACHMENT_OPTIMAL for a
    /// colour swapchain).
    pub fn initial_layout(
        &self,
        images: &[vk::Image],
        layers: u32,
        format: vk::Format,
    ) -> VkResult<()> {
        let (layout, aspect, access) = match crate::formats::depth_aspect(format) {
            Some(aspect) => (
                vk::ImageLayout::DEPTH_STENCIL_ATTACHMENT_OPTIMAL,
                aspect,
                vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_WRITE,
            ),
            None => (
                vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                vk::ImageAspectFlags::COLOR,
                vk::AccessFlags::COLOR_ATTACHMENT_WRITE,
            ),
        };
        self.submit(|d, cmd| {
            let barriers: Vec<vk::ImageMemoryBarrier> = images
                .iter()
                .map(|&image| {
                    vk::ImageMemoryBarrier::default()
                        .old_layout(vk::ImageLayout::UNDEFINED)
                        .new_layout(layout)
                        .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                        .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                        .image(image)
                        .subresource_range(color_range(0, layers).aspect_mask(aspect))
                        .dst_access_mask(access)
                })
                .collect();
            // SAFETY: recording into our buffer between begin and end.
            unsafe {
                d.cmd_pipeline_barrier(
                    cmd,
                    vk::PipelineStageFlags::TOP_OF_PIPE,
                    vk::PipelineStageFlags::ALL_COMMANDS,
                    vk::DependencyFlags::empty(),
                    &[],
                    &[],
                    &barriers,
                )
            };
        })
    }

    fn staging(&self, size: u64) -> VkResult<(vk::Buffer, vk::DeviceMemory, bool)> {
        let mut slot = lock(&self.staging);
        if let Some(s) = slot.as_ref().filter(|s| s.size >= size) {
            return Ok((s.buffer, s.memory, s.coherent));
        }
        if let Some(old) = slot.take() {
            // SAFETY: every copy waited for its fence: the buffer is idle.
            unsafe {
                self.device.destroy_buffer(old.buffer, None);
                self.device.free_memory(old.memory, None);
            }
        }
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(vk::BufferUsageFlags::TRANSFER_DST)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: a valid create info on the live device.
        let buffer = unsafe { self.device.create_buffer(&info, None) }?;
        // SAFETY: just created.
        let req = unsafe { self.device.get_buffer_memory_requirements(buffer) };
        let host = vk::MemoryPropertyFlags::HOST_VISIBLE;
        let coherent_flags = host | vk::MemoryPropertyFlags::HOST_COHERENT;
        let (type_index, coherent) = match self.memory_type(req.memory_type_bits, coherent_flags) {
            Some(i) => (i, true),
            None => match self.memory_type(req.memory_type_bits, host) {
                Some(i) => (i, false),
                None => {
                    // SAFETY: ours, unused.
                    unsafe { self.device.destroy_buffer(buffer, None) };
                    return Err(vk::Result::ERROR_OUT_OF_HOST_MEMORY);
                }
            },
        };
        let alloc = vk::MemoryAllocateInfo::default()
            .allocation_size(req.size)
            .memory_type_index(type_index);
        // SAFETY: a listed memory type; the buffer is fresh.
        let memory = match unsafe { self.device.allocate_memory(&alloc, None) } {
            Ok(m) => m,
            Err(e) => {
                // SAFETY: ours, unused.
                unsafe { self.device.destroy_buffer(buffer, None) };
                return Err(e);
            }
        };
        // SAFETY: as above.
        if let Err(e) = unsafe { self.device.bind_buffer_memory(buffer, memory, 0) } {
            // SAFETY: ours, unused.
            unsafe {
                self.device.destroy_buffer(buffer, None);
                self.device.free_memory(memory, None);
            }
            return Err(e);
        }
        *slot = Some(Staging {
            buffer,
            memory,
            size,
            coherent,
        });
        Ok((buffer, memory, coherent))
    }

    /// The texels of `rect` (x, y, width, height) of array layer `layer`
    /// of a released colour image, as the image stores them
    /// (`bytes_per_texel` each, rows packed). The image is left in
    /// COLOR_ATTACHMENT_OPTIMAL, as the application released it.
    pub fn read_rect(
        &self,
        image: vk::Image,
        layer: u32,
        [x, y, w, h]: [u32; 4],
        bytes_per_texel: u32,
    ) -> VkResult<Vec<u8>> {
        let size = u64::from(w) * u64::from(h) * u64::from(bytes_per_texel);
        let (buffer, memory, coherent) = self.staging(size)?;
        self.submit(|d, cmd| {
            let to_src = vk::ImageMemoryBarrier::default()
                .old_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
                .new_layout(vk::ImageLayout::TRANSFER_SRC_OPTIMAL)
                .src_access_mask(vk::AccessFlags::COLOR_ATTACHMENT_WRITE)
                .dst_access_mask(vk::AccessFlags::TRANSFER_READ)
                .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .image(image)
                .subresource_range(color_range(layer, 1));
            let back = to_src
                .old_layout(vk::ImageLayout::TRANSFER_SRC_OPTIMAL)
                .new_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
                .src_access_mask(vk::AccessFlags::TRANSFER_READ)
                .dst_access_mask(
                    vk::AccessFlags::COLOR_ATTACHMENT_WRITE
                        | vk::AccessFlags::COLOR_ATTACHMENT_READ,
                );
            let region = vk::BufferImageCopy::default()
                .image_subresource(
                    vk::ImageSubresourceLayers::default()
                        .aspect_mask(vk::ImageAspectFlags::COLOR)
                        .mip_level(0)
                        .base_array_layer(layer)
                        .layer_count(1),
                )
                .image_offset(vk::Offset3D {
                    x: x as i32,
                    y: y as i32,
                    z: 0,
                })
                .image_extent(vk::Extent3D {
                    width: w,
                    height: h,
                    depth: 1,
                });
            let to_host = vk::BufferMemoryBarrier::default()
                .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
                .dst_access_mask(vk::AccessFlags::HOST_READ)
                .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .buffer(buffer)
                .size(vk::WHOLE_SIZE);
            // SAFETY: recording into our buffer; the image was released
            // by the application in COLOR_ATTACHMENT_OPTIMAL (§12.20) and
            // its rendering was submitted to this queue before the
            // release, so queue order covers it.
            unsafe {
                d.cmd_pipeline_barrier(
                    cmd,
                    vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::DependencyFlags::empty(),
                    &[],
                    &[],
                    &[to_src],
                );
                d.cmd_copy_image_to_buffer(
                    cmd,
                    image,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    buffer,
                    &[region],
                );
                d.cmd_pipeline_barrier(
                    cmd,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::PipelineStageFlags::HOST | vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT,
                    vk::DependencyFlags::empty(),
                    &[],
                    &[to_host],
                    &[back],
                );
            }
        })?;
        let len = usize::try_from(size).map_err(|_| vk::Result::ERROR_OUT_OF_HOST_MEMORY)?;
        // SAFETY: host-visible memory of at least `size` bytes; the copy's
        // fence was waited for, so the device wrote it all.
        unsafe {
            let p =
                self.device
                    .map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty())?;
            if !coherent {
                let range = vk::MappedMemoryRange::default()
                    .memory(memory)
                    .size(vk::WHOLE_SIZE);
                self.device.invalidate_mapped_memory_ranges(&[range])?;
            }
            let out = std::slice::from_raw_parts(p.cast::<u8>(), len).to_vec();
            self.device.unmap_memory(memory);
            Ok(out)
        }
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: the runtime's own objects; every submission was waited
        // for, so none is in use.
        unsafe {
            if let Some(s) = lock(&self.staging).take() {
                self.device.destroy_buffer(s.buffer, None);
                self.device.free_memory(s.memory, None);
            }
            self.device.destroy_fence(self.fence, None);
            self.device.destroy_command_pool(self.pool, None);
        }
    }
}

fn color_range(layer: u32, count: u32) -> vk::ImageSubresourceRange {
    vk::ImageSubresourceRange::default()
        .aspect_mask(vk::ImageAspectFlags::COLOR)
        .base_mip_level(0)
        .level_count(1)
        .base_array_layer(layer)
        .layer_count(count)
}
