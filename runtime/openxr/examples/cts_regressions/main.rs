//! The OpenXR-CTS's findings that need a session, checked as an
//! application sees them: through the system's OpenXR loader
//! (`XR_RUNTIME_JSON` names nedrt's manifest) against a running service.
//! Each check is named after the CTS case that found the bug (docs/openxr.md,
//! "The conformance suite"); tests/service/openxr.rs runs this program, so
//! CI guards them without the CTS. It prints `ok NAME` or `FAIL NAME: why`
//! a check, and exits 1 if one failed.
//!
//! The last check submits a quad wider than the view, in one colour
//! ([`WIDE_QUAD`]), for several frames: the test reads the recorded panel.

use std::ptr;

use openxr as xr;
use xr::sys;

mod actions;
#[path = "../openxr_client/vulkan.rs"]
mod vulkan;
use vulkan::{Target, draw, rect, target};

/// The wide quad's sRGB code (opaque).
const WIDE_QUAD: [u8; 4] = [200, 120, 40, 255];
const STEREO: xr::ViewConfigurationType = xr::ViewConfigurationType::PRIMARY_STEREO;

#[derive(Default)]
pub(crate) struct Checks {
    failed: usize,
}

impl Checks {
    pub(crate) fn check(&mut self, name: &str, ok: bool, why: impl FnOnce() -> String) {
        if ok {
            println!("ok {name}");
        } else {
            println!("FAIL {name}: {}", why());
            self.failed += 1;
        }
    }

    pub(crate) fn expect(&mut self, name: &str, got: sys::Result, want: sys::Result) {
        self.check(name, got == want, || format!("{got:?}, not {want:?}"));
    }
}

fn main() {
    match run() {
        Ok(0) => {}
        Ok(n) => {
            eprintln!("cts_regressions: {n} check(s) failed");
            std::process::exit(1);
        }
        Err(e) => {
            eprintln!("cts_regressions: {e}");
            std::process::exit(2);
        }
    }
}

type Session = (
    xr::Session<xr::Vulkan>,
    xr::FrameWaiter,
    xr::FrameStream<xr::Vulkan>,
);

fn session(
    instance: &xr::Instance,
    system: xr::SystemId,
    gpu: &vulkan::Gpu,
    family: u32,
) -> xr::Result<Session> {
    use ash::vk::Handle;
    // SAFETY: the handles are the live objects `gpu_for` made.
    unsafe {
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
    }
}

/// The session states the queue holds now, in order; any other event is
/// an error (none is expected here).
pub(crate) fn states(instance: &xr::Instance) -> xr::Result<Vec<(sys::Session, xr::SessionState)>> {
    let mut buf = xr::EventDataBuffer::new();
    let mut out = Vec::new();
    while let Some(event) = instance.poll_event(&mut buf)? {
        if let xr::Event::SessionStateChanged(e) = event {
            out.push((e.session(), e.state()));
        }
    }
    Ok(out)
}

fn only_states(s: &[(sys::Session, xr::SessionState)]) -> Vec<xr::SessionState> {
    s.iter().map(|&(_, st)| st).collect()
}

fn run() -> Result<usize, Box<dyn std::error::Error>> {
    // SAFETY: the system's OpenXR loader (libopenxr_loader.so.1).
    let entry = unsafe { xr::Entry::load(&()) }?;
    let mut exts = xr::ExtensionSet::default();
    exts.khr_vulkan_enable2 = true;
    let instance = entry.create_instance(
        &xr::ApplicationInfo {
            application_name: "nedrt cts_regressions",
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
    let views = instance.enumerate_view_configuration_views(system, STEREO)?;
    instance.graphics_requirements::<xr::Vulkan>(system)?;
    let (gpu, family) = vulkan::gpu_for(&instance, system)?;
    let fp = instance.fp();
    let mut c = Checks::default();

    // xrCreateSession, "XR_SUCCESS in repetition": the events of a session
    // destroyed before they were polled named a handle that was gone.
    {
        let made = session(&instance, system, &gpu, family)?;
        let gone = made.0.as_raw();
        drop(made);
        let left = states(&instance)?;
        c.check(
            "xrCreateSession: no event of a destroyed session",
            left.iter().all(|&(s, _)| s != gone),
            || format!("polled {left:?}"),
        );
    }

    // FrameSubmission, "After_xrEndSession": an exit asked before any
    // frame went READY → STOPPING, which the state machine does not have.
    {
        let (s, _waiter, _stream) = session(&instance, system, &gpu, family)?;
        let made = only_states(&states(&instance)?);
        s.begin(STEREO)?;
        s.request_exit()?;
        let stopped = only_states(&states(&instance)?);
        c.check(
            "FrameSubmission: READY → SYNCHRONIZED → STOPPING",
            made == [xr::SessionState::IDLE, xr::SessionState::READY]
                && stopped == [xr::SessionState::SYNCHRONIZED, xr::SessionState::STOPPING],
            || format!("{made:?} then {stopped:?}"),
        );
        s.end()?;
        let ended = only_states(&states(&instance)?);
        c.check(
            "FrameSubmission: STOPPING → IDLE → EXITING",
            ended == [xr::SessionState::IDLE, xr::SessionState::EXITING],
            || format!("{ended:?}"),
        );
    }

    actions::check(&instance, system, &gpu, family, &mut c)?;

    // xrCreateSwapchain from several threads at once (multithreading): the
    // runtime's one command buffer and fence were shared unguarded, and it
    // used the application's queue inside xrCreateSwapchain.
    let (s, mut waiter, mut stream) = session(&instance, system, &gpu, family)?;
    {
        let size = (
            views[0].recommended_image_rect_width,
            views[0].recommended_image_rect_height,
        );
        let made: Vec<xr::Result<()>> = std::thread::scope(|scope| {
            let threads: Vec<_> = (0..8)
                .map(|_| {
                    let s = &s;
                    scope.spawn(move || {
                        for _ in 0..16 {
                            let sc = s.create_swapchain(&xr::SwapchainCreateInfo {
                                create_flags: xr::SwapchainCreateFlags::EMPTY,
                                usage_flags: xr::SwapchainUsageFlags::COLOR_ATTACHMENT
                                    | xr::SwapchainUsageFlags::TRANSFER_DST,
                                format: ash::vk::Format::R8G8B8A8_SRGB.as_raw() as u32,
                                sample_count: 1,
                                width: size.0,
                                height: size.1,
                                face_count: 1,
                                array_size: 1,
                                mip_count: 1,
                            })?;
                            let mut sc = sc;
                            sc.acquire_image()?;
                            sc.wait_image(xr::Duration::INFINITE)?;
                            sc.release_image()?;
                        }
                        Ok(())
                    })
                })
                .collect();
            threads
                .into_iter()
                .map(|t| t.join().unwrap_or(Err(sys::Result::ERROR_RUNTIME_FAILURE)))
                .collect()
        });
        c.check(
            "multithreading: swapchains made and cycled on eight threads",
            made.iter().all(Result::is_ok),
            || format!("{made:?}"),
        );
    }

    // A frame loop to FOCUSED, then the frame checks.
    let space = s.create_reference_space(xr::ReferenceSpaceType::LOCAL, xr::Posef::IDENTITY)?;
    let mut eyes: Vec<Target> = Vec::new();
    for v in &views {
        let size = (
            v.recommended_image_rect_width,
            v.recommended_image_rect_height,
        );
        eyes.push(target(&s, &gpu, size, |_, _| [30, 60, 90, 255])?);
    }
    let mut wide = target(&s, &gpu, (16, 4), |_, _| WIDE_QUAD)?;
    states(&instance)?;
    s.begin(STEREO)?;
    let mut focused = false;
    for _ in 0..20 {
        let st = waiter.wait()?;
        stream.begin()?;
        stream.end(
            st.predicted_display_time,
            xr::EnvironmentBlendMode::OPAQUE,
            &[],
        )?;
        if only_states(&states(&instance)?).contains(&xr::SessionState::FOCUSED) {
            focused = true;
            break;
        }
    }
    c.check("frames reach FOCUSED", focused, String::new);
    for t in eyes.iter_mut() {
        draw(t, &gpu)?;
    }
    draw(&mut wide, &gpu)?;
    let projection_views =
        |pose: xr::Posef, offset: i32| -> Vec<xr::CompositionLayerProjectionView<'_, xr::Vulkan>> {
            eyes.iter()
                .map(|t| {
                    let mut r = rect(t.size);
                    r.offset = xr::Offset2Di {
                        x: offset,
                        y: offset,
                    };
                    xr::CompositionLayerProjectionView::new()
                        .pose(pose)
                        .fov(xr::Fovf {
                            angle_left: -0.1,
                            angle_right: 0.1,
                            angle_up: 0.1,
                            angle_down: -0.1,
                        })
                        .sub_image(
                            xr::SwapchainSubImage::new()
                                .swapchain(&t.swapchain)
                                .image_rect(r),
                        )
                })
                .collect()
        };
    let end = |stream: &mut xr::FrameStream<xr::Vulkan>,
               time: xr::Time,
               layers: &[&xr::CompositionLayerBase<'_, xr::Vulkan>]| {
        stream
            .end(time, xr::EnvironmentBlendMode::OPAQUE, layers)
            .err()
            .unwrap_or(sys::Result::SUCCESS)
    };

    // XrCompositionLayerProjection, "Invalid pose" and "Invalid imageRect
    // out of bounds": a non-unit orientation was accepted; a refused
    // xrEndFrame ended the frame, so the next xrBeginFrame did not
    // discard it.
    {
        let st = waiter.wait()?;
        stream.begin()?;
        let bad_pose = xr::Posef {
            orientation: xr::Quaternionf {
                x: 0.1,
                y: 0.1,
                z: 0.1,
                w: 0.1,
            },
            position: xr::Vector3f::default(),
        };
        let pv = projection_views(bad_pose, 0);
        let layer = xr::CompositionLayerProjection::new()
            .space(&space)
            .views(&pv);
        let r = end(&mut stream, st.predicted_display_time, &[&layer]);
        c.expect(
            "XrCompositionLayerProjection: invalid pose",
            r,
            sys::Result::ERROR_POSE_INVALID,
        );
        let pv = projection_views(xr::Posef::IDENTITY, 1);
        let layer = xr::CompositionLayerProjection::new()
            .space(&space)
            .views(&pv);
        let r = end(&mut stream, st.predicted_display_time, &[&layer]);
        c.expect(
            "XrCompositionLayerProjection: rectangle out of bounds",
            r,
            sys::Result::ERROR_SWAPCHAIN_RECT_INVALID,
        );
        let st = waiter.wait()?;
        // SAFETY: a live session; no begin info.
        let r = unsafe { (fp.begin_frame)(s.as_raw(), ptr::null()) };
        c.expect(
            "XrCompositionLayerProjection: the refused frame is discarded",
            r,
            sys::Result::FRAME_DISCARDED,
        );
        let pv = projection_views(xr::Posef::IDENTITY, 0);
        let layer = xr::CompositionLayerProjection::new()
            .space(&space)
            .views(&pv);
        let r = end(&mut stream, st.predicted_display_time, &[&layer]);
        c.expect(
            "XrCompositionLayerProjection: a valid frame after",
            r,
            sys::Result::SUCCESS,
        );
    }

    // XrCompositionLayerQuad, "Sizes": a quad of size 0 × 0 was refused.
    let quad = |size: xr::Extent2Df| {
        xr::CompositionLayerQuad::new()
            .space(&space)
            .eye_visibility(xr::EyeVisibility::BOTH)
            .sub_image(
                xr::SwapchainSubImage::new()
                    .swapchain(&wide.swapchain)
                    .image_rect(rect(wide.size)),
            )
            .pose(xr::Posef {
                orientation: xr::Quaternionf::IDENTITY,
                position: xr::Vector3f {
                    x: 0.0,
                    y: 0.0,
                    z: -1.0,
                },
            })
            .size(size)
    };
    {
        let st = waiter.wait()?;
        stream.begin()?;
        let layer = quad(xr::Extent2Df {
            width: 0.0,
            height: 0.0,
        });
        let r = end(&mut stream, st.predicted_display_time, &[&layer]);
        c.expect(
            "XrCompositionLayerQuad: size 0 × 0",
            r,
            sys::Result::SUCCESS,
        );
    }

    // Timed_Pipelined_Frame_Submission: a quad far wider and taller than
    // a view (4 m × 1 m at 1 m) was resampled to thousands of pixels and
    // refused by the service; it is cut to the view.
    let mut wide_ok = true;
    for _ in 0..6 {
        let st = waiter.wait()?;
        stream.begin()?;
        let pv = projection_views(xr::Posef::IDENTITY, 0);
        let projection = xr::CompositionLayerProjection::new()
            .space(&space)
            .views(&pv);
        let layer = quad(xr::Extent2Df {
            width: 4.0,
            height: 1.0,
        });
        let r = end(
            &mut stream,
            st.predicted_display_time,
            &[&projection, &layer],
        );
        wide_ok &= r == sys::Result::SUCCESS;
    }
    c.check(
        "Timed_Pipelined_Frame_Submission: a quad wider than the view",
        wide_ok,
        || "xrEndFrame refused it".into(),
    );

    // SessionState: an exit asked in FOCUSED went straight to STOPPING.
    states(&instance)?;
    s.request_exit()?;
    let stopped = only_states(&states(&instance)?);
    c.check(
        "SessionState: FOCUSED → VISIBLE → SYNCHRONIZED → STOPPING",
        stopped
            == [
                xr::SessionState::VISIBLE,
                xr::SessionState::SYNCHRONIZED,
                xr::SessionState::STOPPING,
            ],
        || format!("{stopped:?}"),
    );
    s.end()?;

    // SAFETY: every submission was waited for. The runtime's images go
    // with their swapchains and session, dropped before the device.
    unsafe {
        for t in eyes.iter().chain(std::iter::once(&wide)) {
            gpu.device.destroy_buffer(t.buffer, None);
            gpu.device.free_memory(t.memory, None);
        }
        drop((eyes, wide, space, stream, waiter, s));
        gpu.device.destroy_fence(gpu.fence, None);
        gpu.device.destroy_command_pool(gpu.pool, None);
        gpu.device.destroy_device(None);
        gpu.instance.destroy_instance(None);
    }
    Ok(c.failed)
}
