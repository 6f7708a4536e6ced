//! The one interface for "input frame → display frame": what the panel
//! shows for a frame. The simulator renders its output through the optics,
//! the service puts it on the panel; both hold a `Box<dyn Preprocess>` and
//! never ask which kind it is. Implementations: [`Identity`] here, the
//! Wiener prefilter in nedrt-optics, the D-CNN (any backend) in
//! nedrt-infer; nedrt-stages' registry names them for the command line.

use crate::Image;

/// Why a frame got no display image.
#[derive(Debug, thiserror::Error)]
pub enum PreprocessError {
    /// The frame itself is unusable (size, channels, values): the caller's
    /// fault, not the engine's.
    #[error("frame: {0}")]
    Frame(String),
    /// The engine failed (a lost GPU, a runtime error): the service
    /// switches to its fallback.
    #[error("{engine}: {reason}")]
    Engine { engine: String, reason: String },
}

/// What crossed between the host and a device for one frame: the figures
/// that show a path keeping frames on the GPU (or not) without a profiler.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct HostTraffic {
    /// Bytes written from host memory into device buffers or textures.
    pub to_device_bytes: u64,
    /// Writes from host memory to the device (each buffer or texture
    /// write once, however large).
    pub uploads: u64,
    /// Bytes copied from device memory back to the host.
    pub to_host_bytes: u64,
    /// Times the host waited for the device to hand buffers back for
    /// reading (one wait may map several buffers).
    pub read_backs: u64,
}

impl HostTraffic {
    pub fn add(&mut self, other: HostTraffic) {
        self.to_device_bytes += other.to_device_bytes;
        self.uploads += other.uploads;
        self.to_host_bytes += other.to_host_bytes;
        self.read_backs += other.read_backs;
    }
}

/// Turns an input frame into the display frame.
pub trait Preprocess: Send + std::fmt::Debug {
    /// What runs, for reports: "wiener (doe+wiener, K = 0.02)", "D-CNN … on wgpu f16 on …".
    fn describe(&self) -> String;
    /// The display frame for `input` (linear intensity, RGB), the same
    /// size, clamped to the panel's [0, 1].
    fn run(&mut self, input: &Image) -> Result<Image, PreprocessError>;
    /// The device's own time for the last run, where the engine measures it.
    fn last_gpu_ns(&self) -> Option<u64> {
        None
    }
    /// Host↔device traffic of the last run (none for an engine on the host).
    fn last_traffic(&self) -> HostTraffic {
        HostTraffic::default()
    }
}

/// No preprocessing: the frame as it came, clamped to [0, 1]. What the
/// conventional display and the DOE alone show, and the service's last
/// resort when no other engine can run.
#[derive(Debug, Default, Clone, Copy)]
pub struct Identity;

impl Preprocess for Identity {
    fn describe(&self) -> String {
        "none (the frame as it comes, clamped to [0, 1])".into()
    }
    fn run(&mut self, input: &Image) -> Result<Image, PreprocessError> {
        Ok(input.clone().clamped())
    }
}

/// Checks a frame every preprocessor can take: non-empty, `channels`
/// planes, finite values.
pub fn check_frame(input: &Image, channels: usize) -> Result<(), PreprocessError> {
    if input.width == 0 || input.height == 0 || input.channels() != channels {
        return Err(PreprocessError::Frame(format!(
            "{}×{} frame with {} channels; {channels} needed",
            input.width,
            input.height,
            input.channels()
        )));
    }
    if let Some(bad) = input.data().iter().find(|v| !v.is_finite()) {
        return Err(PreprocessError::Frame(format!("frame contains {bad}")));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_clamps_and_keeps_the_rest() {
        let im = Image::from_planes(2, 1, vec![vec![-0.5, 0.25], vec![1.5, 1.0], vec![0.0, 0.5]]);
        let out = Identity.run(&im).expect("identity");
        assert_eq!(out.data(), &[0.0, 0.25, 1.0, 1.0, 0.0, 0.5]);
    }

    #[test]
    fn frames_without_three_finite_planes_are_refused() {
        let gray = Image::zeros(4, 4, 1);
        assert!(check_frame(&gray, 3).is_err());
        let mut nan = Image::zeros(4, 4, 3);
        nan.data_mut()[5] = f32::NAN;
        let e = check_frame(&nan, 3).expect_err("NaN");
        assert!(e.to_string().contains("NaN"), "{e}");
        assert!(check_frame(&Image::zeros(4, 4, 3), 3).is_ok());
    }
}
