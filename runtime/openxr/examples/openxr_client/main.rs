//! An OpenXR application written with the `openxr` crate, for the runtime's
//! tests and its copy-out benchmark: through the system's OpenXR loader
//! (`XR_RUNTIME_JSON` names nedrt's manifest) it renders a known pattern
//! into each eye's swapchain, adds a quad layer, and writes what it saw as
//! JSON: every predicted display time, each view's field of view, the
//! session states, and how long xrEndFrame took.
//!
//! ```sh
//! openxr_client [--frames N] [--quad WxH@DIST] [--depth] [--report FILE]
//! ```
//!
//! The patterns are [`projection_texel`] and [`quad_texel`] (sRGB codes);
//! the quad is sized to cover W×H panel pixels at DIST metres straight ahead
//! of the head (VIEW space), seen by both eyes.

use std::time::Instant;

use ash::vk;
use ash::vk::Handle;
use openxr as xr;

mod vulkan;
use vulkan::{draw, rect, target};

/// Eye `eye`'s sRGB codes at (x, y).
fn projection_texel(eye: usize, x: usize, y: usize) -> [u8; 4] {
    [
        ((x * 8 + 40 * eye) % 256) as u8,
        ((y * 5) % 256) as u8,
        (((x + y) * 3) % 256) as u8,
        255,
    ]
}

/// The quad's sRGB codes at (x, y): premultiplied, alpha 200/255.
fn quad_texel(x: usize, y: usize) -> [u8; 4] {
    [
        (40 + 20 * x).min(200) as u8,
        (30 * y).min(200) as u8,
        100,
        200,
    ]
}

struct Args {
    frames: usize,
    quad: Option<(u32, u32, f32)>,
    report: Option<std::path::PathBuf>,
    /// Also a depth swapchain per eye (XR_KHR_composition_layer_depth),
    /// acquired and released every frame as a renderer's depth buffer is.
    depth: bool,
}

fn args() -> Result<Args, String> {
    let mut a = Args {
        frames: 30,
        quad: None,
        report: None,
        depth: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let mut v = || it.next().ok_or(format!("{k} needs a value"));
        match k.as_str() {
            "--frames" => a.frames = v()?.parse().map_err(|e| format!("--frames: {e}"))?,
            "--quad" => {
                let s = v()?;
                let bad = || format!("--quad {s}: expected WxH@DIST, e.g. 8x6@20");
                let (size, dist) = s.split_once('@').ok_or_else(bad)?;
                let (w, h) = size.split_once('x').ok_or_else(bad)?;
                a.quad = Some((
                    w.parse().map_err(|_| bad())?,
                    h.parse().map_err(|_| bad())?,
                    dist.parse().map_err(|_| bad())?,
                ));
            }
            "--report" => a.report = Some(v()?.into()),
            "--depth" => a.depth = true,
            other => return Err(format!("unknown argument {other}")),
        }
    }
    Ok(a)
}

fn main() {
    match run() {
        Ok(()) => {}
        Err(e) => {
            eprintln!("openxr_client: {e}");
            std::process::exit(1);
        }
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args = args()?;
    // SAFETY: the system's OpenXR loader (libopenxr_loader.so.1).
    let entry = unsafe { xr::Entry::load(&()) }?;
    let mut exts = xr::ExtensionSet::default();
    exts.khr_vulkan_enable2 = true;
    exts.khr_composition_layer_depth = args.depth;
    let instance = entry.create_instance(
        &xr::ApplicationInfo {
            application_name: "nedrt openxr_client",
            application_version: 1,
            engine_name: "none",
            engine_version: 0,
            api_version: xr::Version::new(1, 0, 0),
        },
        &exts,
        &[],
        &(),
    )?;
    let system = instance.system(xr::FormFactor::HEAD_MOUNTED_DISPLAY)?;
    let stereo = xr::ViewConfigurationType::PRIMARY_STEREO;
    let views = instance.enumerate_view_configuration_views(system, stereo)?;
    instance.graphics_requirements::<xr::Vulkan>(system)?;

    let (gpu, family) = vulkan::gpu_for(&instance, system)?;
    // SAFETY: the handles are the live objects made above.
    let (session, mut waiter, mut stream) = unsafe {
        instance.create_session::<xr::Vulkan>(
            system,
            &xr::vulkan::SessionCreateInfo {
                instance: gpu.instance.handle().as_raw() as _,
                physical_device: gpu.physical.as_raw() as _,
                device: gpu.device.handle().as_raw() as _,
                queue_family_index: family,
                queue_index: 0,
            },
        )
    }?;
    let space =
        session.create_reference_space(xr::ReferenceSpaceType::VIEW, xr::Posef::IDENTITY)?;
    let mut eyes = Vec::new();
    for (e, v) in views.iter().enumerate() {
        let size = (
            v.recommended_image_rect_width,
            v.recommended_image_rect_height,
        );
        eyes.push(target(&session, &gpu, size, |x, y| {
            projection_texel(e, x, y)
        })?);
    }
    let mut depths = Vec::new();
    if args.depth {
        for v in &views {
            let swapchain = session.create_swapchain(&xr::SwapchainCreateInfo {
                create_flags: xr::SwapchainCreateFlags::EMPTY,
                usage_flags: xr::SwapchainUsageFlags::DEPTH_STENCIL_ATTACHMENT,
                format: vk::Format::D32_SFLOAT.as_raw() as u32,
                sample_count: 1,
                width: v.recommended_image_rect_width,
                height: v.recommended_image_rect_height,
                face_count: 1,
                array_size: 1,
                mip_count: 1,
            })?;
            if swapchain.enumerate_images()?.is_empty() {
                return Err("a depth swapchain without images".into());
            }
            depths.push(swapchain);
        }
    }
    let mut quad = match args.quad {
        Some((w, h, _)) => Some(target(&session, &gpu, (w, h), quad_texel)?),
        None => None,
    };

    let mut predicted = Vec::new();
    let mut fov = Vec::new();
    let mut states = Vec::new();
    let mut end_ms = Vec::new();
    let mut running = false;
    let mut lost = false;
    let mut frames = 0usize;
    let mut buf = xr::EventDataBuffer::new();
    'main: loop {
        while let Some(event) = instance.poll_event(&mut buf)? {
            if let xr::Event::SessionStateChanged(e) = event {
                states.push(format!("{:?}", e.state()));
                match e.state() {
                    xr::SessionState::READY => {
                        session.begin(stereo)?;
                        running = true;
                    }
                    xr::SessionState::STOPPING => {
                        session.end()?;
                        running = false;
                    }
                    xr::SessionState::EXITING => break 'main,
                    xr::SessionState::LOSS_PENDING => {
                        lost = true;
                        break 'main;
                    }
                    _ => {}
                }
            }
        }
        if !running {
            std::thread::sleep(std::time::Duration::from_millis(5));
            continue;
        }
        let state = waiter.wait()?;
        stream.begin()?;
        predicted.push(state.predicted_display_time.as_nanos());
        if !state.should_render {
            stream.end(
                state.predicted_display_time,
                xr::EnvironmentBlendMode::OPAQUE,
                &[],
            )?;
            continue;
        }
        let (_, located) = session.locate_views(stereo, state.predicted_display_time, &space)?;
        if fov.is_empty() {
            fov = located
                .iter()
                .map(|v| {
                    [
                        v.fov.angle_left,
                        v.fov.angle_right,
                        v.fov.angle_up,
                        v.fov.angle_down,
                    ]
                })
                .collect();
        }
        for t in eyes.iter_mut() {
            draw(t, &gpu)?;
        }
        if let Some(q) = quad.as_mut() {
            draw(q, &gpu)?;
        }
        for d in depths.iter_mut() {
            d.acquire_image()?;
            d.wait_image(xr::Duration::INFINITE)?;
            d.release_image()?;
        }
        let proj_views: Vec<xr::CompositionLayerProjectionView<xr::Vulkan>> = eyes
            .iter()
            .zip(&located)
            .map(|(t, v)| {
                xr::CompositionLayerProjectionView::new()
                    .pose(v.pose)
                    .fov(v.fov)
                    .sub_image(
                        xr::SwapchainSubImage::new()
                            .swapchain(&t.swapchain)
                            .image_rect(rect(t.size)),
                    )
            })
            .collect();
        let projection = xr::CompositionLayerProjection::new()
            .space(&space)
            .views(&proj_views);
        let started = Instant::now();
        match (&quad, args.quad) {
            (Some(q), Some((w, h, dist))) => {
                // W×H panel pixels at DIST: the view's pixels per tan from
                // its field of view.
                let ppt = eyes[0].size.0 as f32 / 2.0 / fov[0][1].tan();
                let layer = xr::CompositionLayerQuad::new()
                    .space(&space)
                    .layer_flags(xr::CompositionLayerFlags::BLEND_TEXTURE_SOURCE_ALPHA)
                    .eye_visibility(xr::EyeVisibility::BOTH)
                    .sub_image(
                        xr::SwapchainSubImage::new()
                            .swapchain(&q.swapchain)
                            .image_rect(rect(q.size)),
                    )
                    .pose(xr::Posef {
                        orientation: xr::Quaternionf::IDENTITY,
                        position: xr::Vector3f {
                            x: 0.0,
                            y: 0.0,
                            z: -dist,
                        },
                    })
                    .size(xr::Extent2Df {
                        width: w as f32 * dist / ppt,
                        height: h as f32 * dist / ppt,
                    });
                stream.end(
                    state.predicted_display_time,
                    xr::EnvironmentBlendMode::OPAQUE,
                    &[&projection, &layer],
                )?;
            }
            _ => stream.end(
                state.predicted_display_time,
                xr::EnvironmentBlendMode::OPAQUE,
                &[&projection],
            )?,
        }
        end_ms.push(started.elapsed().as_secs_f64() * 1e3);
        frames += 1;
        if frames == args.frames {
            session.request_exit()?;
        }
    }
    let report = format!(
        "{{\"frames\": {frames}, \"lost\": {lost}, \"states\": {states:?}, \"predicted_ns\": {predicted:?}, \
         \"fov\": {fov:?}, \"view_sizes\": {sizes:?}, \"end_frame_ms\": {end_ms:?}}}",
        sizes = eyes
            .iter()
            .map(|t| [t.size.0, t.size.1])
            .collect::<Vec<_>>()
    );
    match &args.report {
        Some(p) => std::fs::write(p, report)?,
        None => println!("{report}"),
    }
    // SAFETY: every submission was waited for. The runtime's images go
    // with their swapchains and session, dropped before the device.
    unsafe {
        for t in eyes.iter().chain(quad.iter()) {
            gpu.device.destroy_buffer(t.buffer, None);
            gpu.device.free_memory(t.memory, None);
        }
        drop((eyes, quad, depths, space, stream, waiter, session));
        gpu.device.destroy_fence(gpu.fence, None);
        gpu.device.destroy_command_pool(gpu.pool, None);
        gpu.device.destroy_device(None);
        gpu.instance.destroy_instance(None);
    }
    Ok(())
}
