//! Fault injection for `--inject-device-loss-after`: a host preprocessor
//! and a device stage that fail like a lost GPU after some frames. Apart
//! because they are test scaffolding, not part of the pipeline proper.

use nedrt_core::preprocess::Preprocess;

/// A preprocessor that fails like a lost device after `frames_left`
/// frames: the service must switch to its fallback without losing a frame.
#[derive(Debug)]
pub(super) struct LosesDeviceAfter {
    pub(super) inner: Box<dyn Preprocess>,
    pub(super) frames_left: u64,
}

impl Preprocess for LosesDeviceAfter {
    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn run(
        &mut self,
        input: &nedrt_core::Image,
    ) -> Result<nedrt_core::Image, nedrt_core::PreprocessError> {
        if self.frames_left == 0 {
            return Err(nedrt_core::PreprocessError::Engine {
                engine: self.inner.describe(),
                reason: "device lost (injected fault)".into(),
            });
        }
        self.frames_left -= 1;
        self.inner.run(input)
    }
}

/// A device stage that fails like a lost device after `frames_left`
/// frames (the resident path's twin of [`LosesDeviceAfter`]).
#[derive(Debug)]
pub(super) struct DeviceLostAfter {
    pub(super) inner: Box<dyn nedrt_gpu::DeviceStage>,
    pub(super) frames_left: u64,
}

impl nedrt_gpu::DeviceStage for DeviceLostAfter {
    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), nedrt_gpu::GpuError> {
        if self.frames_left == 0 {
            return Err(nedrt_gpu::GpuError::DeviceLost("injected fault".into()));
        }
        self.frames_left -= 1;
        self.inner.record(encoder, input, output, width, height)
    }
}
