//! The headless sink: frames are drawn onto an off-screen wgpu texture of
//! the panel's size, exactly as the window sink draws them, and each
//! present waits for the GPU. For machines without a display, soak tests
//! and benchmarks; `read_back` returns what the panel would show.

use super::gpu::{PanelRenderer, read_texture};
use super::{PanelCodes, PresentError, Presented, Sink};

const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// An off-screen panel.
#[derive(Debug)]
pub struct HeadlessSink {
    renderer: PanelRenderer,
    target: wgpu::Texture,
    view: wgpu::TextureView,
    adapter_name: String,
}

impl HeadlessSink {
    /// A `width`×`height` off-screen panel on a given device.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        adapter_name: String,
        width: u32,
        height: u32,
    ) -> Result<Self, PresentError> {
        let mut renderer = PanelRenderer::new(device, queue, width, height, FORMAT)?;
        // Set once here: the target never changes size, so no frame pays for it.
        renderer.set_target_size([width, height]);
        let target = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("headless panel"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let view = target.create_view(&wgpu::TextureViewDescriptor::default());
        Ok(Self {
            renderer,
            target,
            view,
            adapter_name,
        })
    }

    /// What the off-screen panel shows now, as RGBA8 rows.
    pub fn read_back(&self) -> Result<Vec<u8>, PresentError> {
        read_texture(self.renderer.device(), self.renderer.queue(), &self.target)
    }
}

impl Sink for HeadlessSink {
    fn describe(&self) -> String {
        format!(
            "headless {}×{} on {}",
            self.target.width(),
            self.target.height(),
            self.adapter_name
        )
    }

    fn renderer(&self) -> Option<&PanelRenderer> {
        Some(&self.renderer)
    }

    /// Draws and waits for the GPU.
    fn present(&mut self, frame: PanelCodes<'_>) -> Result<Presented, PresentError> {
        let size = [self.target.width(), self.target.height()];
        let submission = self.renderer.draw(frame, &self.view, size)?;
        nedrt_gpu::wait_for(self.renderer.device(), submission)
            .map_err(PresentError::gpu("headless sink"))?;
        Ok(Presented::Shown)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::present::DisplayFrame;
    use nedrt_gpu::test_device;

    mod needs_gpu {
        use super::*;

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn the_panel_receives_every_code_value_unchanged() {
            let (device, queue) = test_device(false);
            let name = "test adapter".to_string();
            // 37×21: not a multiple of any tile; every code value appears.
            let (w, h) = (37usize, 21usize);
            let rgba8: Vec<u8> = (0..4 * w * h)
                .map(|i| if i % 4 == 3 { 255 } else { (i * 7 % 256) as u8 })
                .collect();
            let frame = DisplayFrame {
                id: 1,
                width: w,
                height: h,
                rgba8,
            };
            let mut sink =
                HeadlessSink::new(&device, &queue, name, w as u32, h as u32).expect("sink");
            assert_eq!(
                sink.present(PanelCodes::Host(&frame)).expect("present"),
                Presented::Shown
            );
            assert_eq!(sink.read_back().expect("read back"), frame.rgba8);
            // A wrong-size frame is an error, not a panic.
            let small = DisplayFrame {
                id: 2,
                width: 2,
                height: 2,
                rgba8: vec![0; 16],
            };
            assert!(sink.present(PanelCodes::Host(&small)).is_err());
        }
    }
}
