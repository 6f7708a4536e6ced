//! The DCT filter as a device stage: gains computed on the host once per
//! frame size, filters cached per size. Apart from the filter itself, which
//! the refinement stage also records.

use super::FftError;
use super::filter::DctFilter;
use super::kernels::FftKernels;

/// Why a stage's host-side terms (gains, refinement terms) could not be
/// made: the caller's own error, boxed.
pub type TermsError = Box<dyn std::error::Error + Send + Sync>;

/// The gains of a frame size: `channels` planes of height×width (see
/// [`DctFilter`]), or why they cannot be made.
pub type GainsFor = Box<dyn FnMut(usize, usize) -> Result<Vec<Vec<f32>>, TermsError> + Send>;

/// A [`DctFilter`] as a [`crate::DeviceStage`]: the gains of each frame size
/// computed on the host once (`gains_for`), uploaded once; a frame records
/// the filter. The linear prefilters (the Wiener of every method and
/// design, the linear least-squares prefilter) on the device.
pub struct SpectralStage {
    name: String,
    kernels: FftKernels,
    gains_for: GainsFor,
    /// Filters of the sizes seen last, newest at the end.
    filters: Vec<DctFilter>,
}

impl std::fmt::Debug for SpectralStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SpectralStage")
            .field("name", &self.name)
            .field(
                "sizes",
                &self
                    .filters
                    .iter()
                    .map(|f| (f.width, f.height))
                    .collect::<Vec<_>>(),
            )
            .finish()
    }
}

/// Frame sizes whose filters a stage keeps (the service runs one).
pub(super) const FILTERS_KEPT: usize = 2;

impl SpectralStage {
    /// `name` for reports ("the Wiener prefilter of doe+wiener (K = …)").
    pub fn new(device: &wgpu::Device, name: String, gains_for: GainsFor) -> Result<Self, FftError> {
        Ok(Self {
            name,
            kernels: FftKernels::new(device)?,
            gains_for,
            filters: Vec::new(),
        })
    }

    /// The filter for `width`×`height`, made on first use.
    pub fn filter(&mut self, width: usize, height: usize) -> Result<&mut DctFilter, FftError> {
        if let Some(i) = self
            .filters
            .iter()
            .position(|f| (f.width, f.height) == (width, height))
        {
            let f = self.filters.remove(i);
            self.filters.push(f);
        } else {
            let gains =
                (self.gains_for)(width, height).map_err(|e| FftError::Gains(e.to_string()))?;
            let f = DctFilter::new(&mut self.kernels, width, height, &gains)?;
            if self.filters.len() == FILTERS_KEPT {
                self.filters.remove(0);
            }
            self.filters.push(f);
        }
        self.filters
            .last_mut()
            .ok_or_else(|| FftError::Device("no filter".into()))
    }
}

impl crate::DeviceStage for SpectralStage {
    fn describe(&self) -> String {
        format!("{} on the device (DCT-II · gain · DCT-III)", self.name)
    }

    fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), crate::GpuError> {
        self.filter(width, height)
            .and_then(|f| f.record(encoder, input, output))
            .map_err(crate::GpuError::from)
    }

    fn warm_up(
        &mut self,
        _input: &wgpu::Buffer,
        _output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), crate::GpuError> {
        self.filter(width, height)
            .map(|_| ())
            .map_err(crate::GpuError::from)
    }
}
