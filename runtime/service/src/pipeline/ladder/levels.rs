//! A view's levels, every one built at start-up, behind one engine: on
//! the host a [`Preprocess`], on the device a [`DeviceStage`], each
//! running the level its [`Selection`] names. A switch then costs no build
//! and no stall: the next frame records another level's passes.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use nedrt_core::Image;
use nedrt_core::preprocess::{HostTraffic, Preprocess, PreprocessError};
use nedrt_gpu::{DeviceStage, GpuError};

/// The level every view's engine runs, set by the controller before each
/// frame (shared: every view of a frame runs the same level).
#[derive(Debug, Clone, Default)]
pub struct Selection(Arc<AtomicUsize>);

impl Selection {
    pub fn get(&self) -> usize {
        self.0.load(Ordering::Relaxed)
    }
    pub fn set(&self, level: usize) {
        self.0.store(level, Ordering::Relaxed);
    }
}

/// A view's levels, cheapest first, and the selection they follow: on
/// the host [`HostLevels`], on the device [`DeviceLevels`] (one type, as
/// `FailsAfter` wraps either kind of engine).
#[derive(Debug)]
pub struct Levels<T> {
    levels: Vec<T>,
    selection: Selection,
}

/// A view's levels on the host.
pub type HostLevels = Levels<Box<dyn Preprocess>>;
/// A view's levels on the sink's device.
pub type DeviceLevels = Levels<Box<dyn DeviceStage>>;

impl<T> Levels<T> {
    /// `levels` cheapest first; none is a ladder of `no_work` alone.
    fn with(mut levels: Vec<T>, selection: Selection, no_work: impl FnOnce() -> T) -> Self {
        if levels.is_empty() {
            levels.push(no_work());
        }
        Self { levels, selection }
    }

    fn selected(&self) -> usize {
        self.selection.get().min(self.levels.len() - 1)
    }

    fn current(&self) -> &T {
        &self.levels[self.selected()]
    }

    fn current_mut(&mut self) -> &mut T {
        let j = self.selected();
        &mut self.levels[j]
    }

    /// Names the levels and the one selected, for reports.
    fn describe_with(&self, describe: impl Fn(&T) -> String) -> String {
        let names: Vec<String> = self.levels.iter().map(describe).collect();
        format!(
            "frame budget over {} levels ({}; now {})",
            names.len(),
            names.join(" < "),
            names[self.selected()]
        )
    }
}

impl HostLevels {
    /// `levels` cheapest first; none is a ladder of one level of no work.
    pub fn new(levels: Vec<Box<dyn Preprocess>>, selection: Selection) -> Self {
        Self::with(levels, selection, || {
            Box::new(nedrt_core::preprocess::Identity)
        })
    }
}

impl Preprocess for HostLevels {
    fn describe(&self) -> String {
        self.describe_with(|l| l.describe())
    }
    fn run(&mut self, input: &Image) -> Result<Image, PreprocessError> {
        self.current_mut().run(input)
    }
    fn last_gpu_ns(&self) -> Option<u64> {
        self.current().last_gpu_ns()
    }
    fn last_traffic(&self) -> HostTraffic {
        self.current().last_traffic()
    }
}

/// No work on the device: the frame's planes copied to the display
/// buffer (the encode clamps): the ladder's lowest level.
#[derive(Debug, Default)]
pub struct Unprocessed;

impl DeviceStage for Unprocessed {
    fn describe(&self) -> String {
        "none (the frame as it comes)".into()
    }
    fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        let bytes = (3 * width * height * std::mem::size_of::<f32>()) as u64;
        encoder.copy_buffer_to_buffer(input, 0, output, 0, bytes);
        Ok(())
    }
    fn passes_through(&self) -> bool {
        true
    }
}

impl DeviceLevels {
    /// `levels` cheapest first; none is a ladder of [`Unprocessed`] alone.
    pub fn new(levels: Vec<Box<dyn DeviceStage>>, selection: Selection) -> Self {
        Self::with(levels, selection, || Box::new(Unprocessed))
    }
}

impl DeviceStage for DeviceLevels {
    fn describe(&self) -> String {
        self.describe_with(|l| l.describe())
    }
    fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        self.current_mut()
            .record(encoder, input, output, width, height)
    }
    fn passes_through(&self) -> bool {
        self.current().passes_through()
    }
    /// Every level is made ready: a switch builds nothing.
    fn warm_up(
        &mut self,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        for level in &mut self.levels {
            level.warm_up(input, output, width, height)?;
        }
        Ok(())
    }
}
