//! Fault injection for `--inject-device-loss-after`: a stage that fails
//! like a lost GPU after some frames, on the host ([`Preprocess`]) or on
//! the device ([`DeviceStage`]) alike, so that the service's switch to its
//! fallback is tested on either path with one wrapper.

use nedrt_core::preprocess::{Preprocess, PreprocessError};
use nedrt_gpu::{DeviceStage, GpuError};

/// `inner` for `frames_left` frames, then failing as a lost device would.
#[derive(Debug)]
pub struct FailsAfter<S> {
    pub inner: S,
    pub frames_left: u64,
}

impl<S> FailsAfter<S> {
    pub fn new(inner: S, frames_left: u64) -> Self {
        Self { inner, frames_left }
    }

    /// Whether this frame fails; counts it down otherwise.
    fn lost(&mut self) -> bool {
        if self.frames_left == 0 {
            return true;
        }
        self.frames_left -= 1;
        false
    }
}

impl Preprocess for FailsAfter<Box<dyn Preprocess>> {
    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn run(&mut self, input: &nedrt_core::Image) -> Result<nedrt_core::Image, PreprocessError> {
        if self.lost() {
            return Err(PreprocessError::Engine {
                engine: self.inner.describe(),
                reason: "device lost (injected fault)".into(),
            });
        }
        self.inner.run(input)
    }

    fn last_gpu_ns(&self) -> Option<u64> {
        self.inner.last_gpu_ns()
    }

    fn last_traffic(&self) -> nedrt_core::preprocess::HostTraffic {
        self.inner.last_traffic()
    }
}

impl DeviceStage for FailsAfter<Box<dyn DeviceStage>> {
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
    ) -> Result<(), GpuError> {
        if self.lost() {
            return Err(GpuError::DeviceLost("injected fault".into()));
        }
        self.inner.record(encoder, input, output, width, height)
    }

    /// Not a frame: the faults count frames.
    fn warm_up(
        &mut self,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        self.inner.warm_up(input, output, width, height)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nedrt_core::preprocess::Identity;

    #[test]
    fn a_host_stage_fails_like_a_lost_device_after_its_frames() {
        let mut stage = FailsAfter::new(Box::new(Identity) as Box<dyn Preprocess>, 2);
        let frame = nedrt_core::Image::zeros(3, 2, 3);
        assert!(stage.run(&frame).is_ok());
        assert!(stage.run(&frame).is_ok());
        for _ in 0..2 {
            let e = stage.run(&frame).expect_err("lost");
            assert!(
                matches!(&e, PreprocessError::Engine { reason, .. } if reason.contains("device lost")),
                "{e}"
            );
        }
    }

    /// A device stage that records nothing.
    #[derive(Debug)]
    struct Nothing;

    impl DeviceStage for Nothing {
        fn describe(&self) -> String {
            "nothing".into()
        }
        fn record(
            &mut self,
            _: &mut wgpu::CommandEncoder,
            _: &wgpu::Buffer,
            _: &wgpu::Buffer,
            _: usize,
            _: usize,
        ) -> Result<(), GpuError> {
            Ok(())
        }
    }

    // Named for scripts/test.sh's hardware stage (`--ignored needs_`).
    mod needs_gpu {
        use super::*;

        /// Warming up is not a frame: the fault comes after as many frames
        /// however often the stage was made ready.
        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn a_device_stage_fails_after_its_frames_not_its_warm_ups() {
            let (device, _queue) = nedrt_gpu::test_device(false);
            let buffer = device.create_buffer(&wgpu::BufferDescriptor {
                label: None,
                size: 4 * 3 * 6,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            });
            let mut stage = FailsAfter::new(Box::new(Nothing) as Box<dyn DeviceStage>, 2);
            for _ in 0..3 {
                stage.warm_up(&buffer, &buffer, 3, 2).expect("warms up");
            }
            let mut encoder = device.create_command_encoder(&Default::default());
            for frame in 0..4 {
                let recorded = stage.record(&mut encoder, &buffer, &buffer, 3, 2);
                match frame {
                    0 | 1 => recorded.expect("in time"),
                    _ => assert!(
                        matches!(recorded, Err(GpuError::DeviceLost(_))),
                        "{recorded:?}"
                    ),
                }
            }
        }
    }
}
