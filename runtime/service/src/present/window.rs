//! The window sink: a winit window of the panel's size (or fullscreen on a
//! named monitor) with a wgpu surface presenting with vsync (FIFO). The
//! event loop is pumped from the present loop, so the window lives on the
//! thread that presents and never needs a thread of its own. The surface's
//! device is offered to the D-CNN (`device()`), so a wgpu backend and the
//! window share one GPU context.

use std::sync::Arc;
use std::time::Duration;

use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::platform::pump_events::{EventLoopExtPumpEvents, PumpStatus};
use winit::window::{Fullscreen, Window, WindowId};

use super::gpu::PanelRenderer;
use super::{PanelCodes, PresentError, Presented, Sink};

fn err(reason: impl std::fmt::Display) -> PresentError {
    PresentError::open("window sink", reason)
}

/// How the window is opened.
#[derive(Debug, Clone, Default)]
pub struct WindowOptions {
    pub title: String,
    /// Borderless fullscreen (on `monitor`, else the primary monitor).
    pub fullscreen: bool,
    /// Monitor name as the windowing system reports it.
    pub monitor: Option<String>,
    /// Present with vsync (FIFO); without it, immediate where offered.
    pub vsync: bool,
    /// How wgpu's instance is made.
    pub gpu: nedrt_gpu::GpuSettings,
    /// Keep keyboard and mouse input for [`WindowSink::take_inputs`]
    /// (an interactive window; the service's window ignores input).
    pub collect_inputs: bool,
    /// What the caller suggests when there is no display (the command's
    /// way to run without one); the sink itself only says to set DISPLAY.
    pub no_display_hint: Option<String>,
    /// The window's inner size when it differs from the frames' (frames are
    /// drawn to it with nearest-pixel scaling).
    pub window_size: Option<(u32, u32)>,
}

/// Keyboard and mouse input of an interactive window, free of winit's types.
#[derive(Debug, Clone, PartialEq)]
pub enum WindowInput {
    /// A key pressed (repeats included).
    Key(KeyName),
    /// Mouse wheel, in lines (positive: away from the user).
    Wheel { lines: f64 },
    /// The cursor at a position in the window's physical pixels.
    Cursor { x: f64, y: f64 },
    /// The left mouse button pressed or released.
    LeftButton { pressed: bool },
}

/// The keys an interactive window tells apart.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum KeyName {
    Left,
    Right,
    Up,
    Down,
    PageUp,
    PageDown,
    Home,
    End,
    Space,
    Escape,
    Enter,
    /// A printable key, lower-cased.
    Char(char),
}

fn key_name(key: &Key) -> Option<KeyName> {
    Some(match key {
        Key::Named(NamedKey::ArrowLeft) => KeyName::Left,
        Key::Named(NamedKey::ArrowRight) => KeyName::Right,
        Key::Named(NamedKey::ArrowUp) => KeyName::Up,
        Key::Named(NamedKey::ArrowDown) => KeyName::Down,
        Key::Named(NamedKey::PageUp) => KeyName::PageUp,
        Key::Named(NamedKey::PageDown) => KeyName::PageDown,
        Key::Named(NamedKey::Home) => KeyName::Home,
        Key::Named(NamedKey::End) => KeyName::End,
        Key::Named(NamedKey::Space) => KeyName::Space,
        Key::Named(NamedKey::Escape) => KeyName::Escape,
        Key::Named(NamedKey::Enter) => KeyName::Enter,
        Key::Character(s) => KeyName::Char(s.chars().next()?.to_ascii_lowercase()),
        _ => return None,
    })
}

#[derive(Debug)]
struct App {
    size: PhysicalSize<u32>,
    options: WindowOptions,
    window: Option<Arc<Window>>,
    closed: bool,
    resized: Option<PhysicalSize<u32>>,
    error: Option<String>,
    inputs: Vec<WindowInput>,
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_some() || self.error.is_some() {
            return;
        }
        let mut attrs = Window::default_attributes()
            .with_title(self.options.title.clone())
            .with_inner_size(self.size)
            .with_resizable(false);
        if self.options.fullscreen {
            let monitor = match &self.options.monitor {
                Some(name) => {
                    let found = event_loop
                        .available_monitors()
                        .find(|m| m.name().as_deref() == Some(name.as_str()));
                    if found.is_none() {
                        let names: Vec<String> = event_loop
                            .available_monitors()
                            .filter_map(|m| m.name())
                            .collect();
                        self.error = Some(format!(
                            "no monitor named {name:?} (monitors: {})",
                            names.join(", ")
                        ));
                        return;
                    }
                    found
                }
                None => event_loop.primary_monitor(),
            };
            attrs = attrs.with_fullscreen(Some(Fullscreen::Borderless(monitor)));
        }
        match event_loop.create_window(attrs) {
            Ok(w) => self.window = Some(Arc::new(w)),
            Err(e) => self.error = Some(format!("cannot create the window: {e}")),
        }
    }

    fn window_event(&mut self, _: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested | WindowEvent::Destroyed => self.closed = true,
            WindowEvent::Resized(size) => self.resized = Some(size),
            _ if !self.options.collect_inputs => {}
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                if let Some(k) = key_name(&event.logical_key) {
                    self.inputs.push(WindowInput::Key(k));
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => f64::from(y),
                    // Pixel deltas (touchpads): about 20 pixels a line.
                    MouseScrollDelta::PixelDelta(p) => p.y / 20.0,
                };
                self.inputs.push(WindowInput::Wheel { lines });
            }
            WindowEvent::CursorMoved { position, .. } => self.inputs.push(WindowInput::Cursor {
                x: position.x,
                y: position.y,
            }),
            WindowEvent::MouseInput {
                state,
                button: MouseButton::Left,
                ..
            } => self.inputs.push(WindowInput::LeftButton {
                pressed: state == ElementState::Pressed,
            }),
            _ => {}
        }
    }
}

/// A window showing the panel.
#[derive(Debug)]
pub struct WindowSink {
    event_loop: EventLoop<()>,
    app: App,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    renderer: PanelRenderer,
    adapter_name: String,
}

impl WindowSink {
    /// Opens a window for a `width`×`height` panel on the default adapter.
    pub fn open(width: u32, height: u32, options: WindowOptions) -> Result<Self, PresentError> {
        let mut event_loop = EventLoop::new().map_err(|e| {
            let instead = match &options.no_display_hint {
                Some(hint) => format!(", or use {hint}"),
                None => String::new(),
            };
            err(format!(
                "no display ({e}); set DISPLAY (or run under xvfb-run){instead}"
            ))
        })?;
        let (window_w, window_h) = options.window_size.unwrap_or((width, height));
        let mut app = App {
            size: PhysicalSize::new(window_w, window_h),
            options,
            window: None,
            closed: false,
            resized: None,
            error: None,
            inputs: Vec::new(),
        };
        // The window is created in `resumed`, on the first pump.
        for _ in 0..100 {
            if let PumpStatus::Exit(code) =
                event_loop.pump_app_events(Some(Duration::from_millis(10)), &mut app)
            {
                return Err(err(format!("the event loop exited ({code})")));
            }
            if app.window.is_some() || app.error.is_some() {
                break;
            }
        }
        if let Some(e) = app.error.take() {
            return Err(err(e));
        }
        let window = app
            .window
            .clone()
            .ok_or_else(|| err("no window was created"))?;
        let instance = wgpu::Instance::new(
            app.options
                .gpu
                .descriptor()
                .with_display_handle(Box::new(event_loop.owned_display_handle())),
        );
        let surface = instance
            .create_surface(window.clone())
            .map_err(|e| err(format!("cannot create a surface: {e}")))?;
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: Some(&surface),
            apply_limit_buckets: false,
        }))
        .map_err(|e| err(format!("no GPU adapter can present to the window ({e})")))?;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("nedrt window"),
            required_features: adapter.features()
                & (wgpu::Features::SHADER_F16 | wgpu::Features::TIMESTAMP_QUERY),
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(|e| err(format!("requesting a device: {e}")))?;
        let caps = surface.get_capabilities(&adapter);
        let format = caps
            .formats
            .iter()
            .copied()
            .find(|f| {
                matches!(
                    f,
                    wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Rgba8Unorm
                )
            })
            .ok_or_else(|| {
                err(format!(
                    "the surface offers no 8-bit unorm format (offers {:?})",
                    caps.formats
                ))
            })?;
        let vsync = app.options.vsync;
        let present_mode = if !vsync && caps.present_modes.contains(&wgpu::PresentMode::Immediate) {
            wgpu::PresentMode::Immediate
        } else {
            wgpu::PresentMode::Fifo
        };
        let inner = window.inner_size();
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            format,
            width: inner.width.max(1),
            height: inner.height.max(1),
            present_mode,
            desired_maximum_frame_latency: 2,
            alpha_mode: caps
                .alpha_modes
                .first()
                .copied()
                .unwrap_or(wgpu::CompositeAlphaMode::Auto),
            view_formats: vec![],
            color_space: wgpu::SurfaceColorSpace::default(),
        };
        surface.configure(&device, &config);
        let mut renderer = PanelRenderer::new(&device, &queue, width, height, format)?;
        // Set with the surface; a draw after a resize sets it again.
        renderer.set_target_size([config.width, config.height]);
        let info = adapter.get_info();
        Ok(Self {
            event_loop,
            app,
            surface,
            config,
            renderer,
            adapter_name: format!("{} ({:?})", info.name, info.backend),
        })
    }

    /// The window's GPU context, for a D-CNN backend to share.
    pub fn device(&self) -> (wgpu::Device, wgpu::Queue, String) {
        (
            self.renderer.device().clone(),
            self.renderer.queue().clone(),
            self.adapter_name.clone(),
        )
    }

    /// The input gathered since the last call (pumped by [`Sink::poll`]);
    /// empty unless `collect_inputs` was set.
    pub fn take_inputs(&mut self) -> Vec<WindowInput> {
        std::mem::take(&mut self.app.inputs)
    }

    /// The surface's size in physical pixels (cursor positions are in these).
    pub fn surface_size(&self) -> (u32, u32) {
        (self.config.width, self.config.height)
    }

    fn reconfigure(&mut self) {
        if let Some(window) = &self.app.window {
            let size = window.inner_size();
            self.config.width = size.width.max(1);
            self.config.height = size.height.max(1);
        }
        self.surface.configure(self.renderer.device(), &self.config);
    }
}

impl Sink for WindowSink {
    fn describe(&self) -> String {
        format!(
            "window {}×{} ({:?}, {:?}) on {}",
            self.config.width,
            self.config.height,
            self.config.format,
            self.config.present_mode,
            self.adapter_name
        )
    }

    fn paced_by_display(&self) -> bool {
        self.config.present_mode == wgpu::PresentMode::Fifo
    }

    fn poll(&mut self) -> bool {
        if let PumpStatus::Exit(_) = self
            .event_loop
            .pump_app_events(Some(Duration::ZERO), &mut self.app)
        {
            self.app.closed = true;
        }
        if self.app.resized.take().is_some() {
            self.reconfigure();
        }
        !self.app.closed
    }

    fn renderer(&self) -> Option<&PanelRenderer> {
        Some(&self.renderer)
    }

    /// Draws onto the swapchain's next texture and queues it.
    fn present(&mut self, frame: PanelCodes<'_>) -> Result<Presented, PresentError> {
        let texture = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) => t,
            wgpu::CurrentSurfaceTexture::Suboptimal(t) => {
                self.reconfigure();
                t
            }
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => {
                return Ok(Presented::Skipped);
            }
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.reconfigure();
                return Ok(Presented::Skipped);
            }
            wgpu::CurrentSurfaceTexture::Validation => {
                return Err(PresentError::frame(
                    "window sink",
                    "acquiring the surface texture failed validation",
                ));
            }
        };
        let view = texture
            .texture
            .create_view(&wgpu::TextureViewDescriptor::default());
        self.renderer
            .draw(frame, &view, [self.config.width, self.config.height])?;
        if let Some(window) = &self.app.window {
            window.pre_present_notify();
        }
        self.renderer.queue().present(texture);
        Ok(Presented::Shown)
    }
}
