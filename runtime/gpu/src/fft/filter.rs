//! The DCT filter: a real, even spectrum applied to a frame's planes by a
//! DCT-II, a product and a DCT-III, in workgroup memory where both sides
//! fit (`fused.rs`, three dispatches), else by passes through device memory
//! (`dct.rs`). Apart from the stage that caches it per frame size
//! (`spectral`).

use super::dct::MultiPassFilter;
use super::fused::{FusedFilter, RowEnds, RowEndsSpec, fits_workgroup};
use super::kernels::{FftKernels, FusedVariant, check_binding};
use super::{FftError, FftPath};

/// A real, even spectrum applied to `channels` planes of one frame size:
/// out = DCT-III(gain · DCT-II(in)) per plane (both unnormalised; the
/// inverse carries 1/(w·h)), i.e. the mirrored frame's circular
/// convolution with the spectrum's kernel, cropped. `gains` holds one
/// plane of `height` rows of `width` values per channel, indexed by the
/// DCT's (ky, kx): the mirrored 2w×2h grid's spectrum at (ky, kx).
#[derive(Debug)]
pub struct DctFilter {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    imp: Imp,
    /// The workgroup-memory kernels' shape it was made with (the default:
    /// the heuristics'), and whether it is the adapter's tuned one.
    variant: FusedVariant,
    tuned: bool,
}

#[derive(Debug)]
enum Imp {
    Fused(FusedFilter),
    MultiPass(MultiPassFilter),
}

impl DctFilter {
    /// Prepares the filter for `width`×`height` frames of `channels`
    /// planes, with `gains` (see the type).
    pub fn new(
        kernels: &mut FftKernels,
        width: usize,
        height: usize,
        gains: &[Vec<f32>],
    ) -> Result<Self, FftError> {
        Self::with_gain_sets(kernels, width, height, &[gains])
    }

    /// The same with several sets of gains sharing the buffers and passes:
    /// [`DctFilter::record_set`] picks one per recording (the refinement's
    /// three operators). The kernels' [`FftPath`] picks the path.
    pub fn with_gain_sets(
        kernels: &mut FftKernels,
        width: usize,
        height: usize,
        sets: &[&[Vec<f32>]],
    ) -> Result<Self, FftError> {
        let channels = check_gains(width, height, sets)?;
        // Both lengths factor, or neither path runs (the error names it).
        super::radices(width)?;
        super::radices(height)?;
        let device = kernels.device.clone();
        let real_bytes = (channels * width * height * 4) as u64;
        check_binding(&device, "the frame's planes", real_bytes)?;
        let fused = kernels.path == FftPath::Auto
            && fits_workgroup(&device, width)
            && fits_workgroup(&device, height);
        // The adapter's tuned shape for this size, unless one was set.
        let explicit = kernels.variant;
        let tuned = match kernels.tuned_variant(width, height) {
            Some(v) if explicit == FusedVariant::default() && fused => {
                kernels.variant = v;
                true
            }
            _ => false,
        };
        let variant = kernels.variant;
        // A driver that refuses the generated kernels (a limit wgpu does not
        // report) still gets a filter: the fallback's.
        let made = fused.then(|| FusedFilter::new(kernels, width, height, sets));
        kernels.variant = explicit;
        let imp = match made {
            Some(Ok(f)) => Imp::Fused(f),
            Some(Err(e)) if !matches!(e, FftError::Device(_)) => return Err(e),
            _ => Imp::MultiPass(MultiPassFilter::with_gain_sets(
                kernels, width, height, sets,
            )?),
        };
        let in_memory = matches!(imp, Imp::Fused(_));
        Ok(Self {
            width,
            height,
            channels,
            imp,
            variant: if in_memory {
                variant
            } else {
                FusedVariant::default()
            },
            tuned: tuned && in_memory,
        })
    }

    /// The workgroup-memory kernels' shape the filter runs (the default:
    /// the heuristics'; the multi-pass filter has none).
    pub fn variant(&self) -> FusedVariant {
        self.variant
    }

    /// Whether that shape is the adapter's tuned one for this size.
    pub fn tuned(&self) -> bool {
        self.tuned
    }

    /// Whether the filter runs in workgroup memory (three dispatches) or
    /// by the multi-pass fallback.
    pub fn in_workgroup_memory(&self) -> bool {
        matches!(self.imp, Imp::Fused(_))
    }

    /// Bytes the filter moves through device memory per frame at least:
    /// every dispatch reads and writes its data once (the floor of
    /// docs/benchmarks.md's bytes-over-bandwidth).
    pub fn bytes_per_frame(&self) -> u64 {
        self.passes(0).iter().map(|(_, b)| b).sum()
    }

    /// Each dispatch of a frame with gain set `set`, in order: what it
    /// does and the bytes it moves at least.
    pub fn passes(&self, set: usize) -> Vec<(String, u64)> {
        match &self.imp {
            Imp::Fused(f) => f.passes(),
            Imp::MultiPass(f) => f.passes(set),
        }
    }

    /// As [`DctFilter::record`], each dispatch in a compute pass of its own
    /// between two of `timer`'s timestamps (pair i for dispatch i of
    /// [`DctFilter::passes`]); the timer needs that many pairs.
    pub fn record_timed(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        timer: &crate::PassTimer,
    ) -> Result<(), FftError> {
        self.check_buffers(input, &[(output, 0)])?;
        match &mut self.imp {
            Imp::MultiPass(f) => f.record_timed(encoder, input, output, timer),
            Imp::Fused(f) => {
                for (i, (pipeline, bind, groups)) in
                    f.steps(input, &[(output, 0)]).into_iter().enumerate()
                {
                    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                        label: Some("dct filter pass"),
                        timestamp_writes: Some(timer.pass(i)),
                    });
                    pass.set_pipeline(&pipeline);
                    pass.set_bind_group(0, &bind, &[]);
                    pass.dispatch_workgroups(groups[0], groups[1], 1);
                }
                Ok(())
            }
        }
    }

    /// Records the filter of the frame in `input` into `output` (each
    /// `channels` planes of width·height f32, planes width·height apart).
    pub fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
    ) -> Result<(), FftError> {
        self.record_sets(encoder, input, &[(output, 0)])
    }

    /// As [`DctFilter::record`], with gain set `set`.
    pub fn record_set(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        set: usize,
    ) -> Result<(), FftError> {
        self.record_sets(encoder, input, &[(output, set)])
    }

    /// The filter of one input with several gain sets, each into its own
    /// output: in workgroup memory the rows' forward transform runs once
    /// for all of them (the refinement's two opening filters).
    pub fn record_sets(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        outs: &[(&wgpu::Buffer, usize)],
    ) -> Result<(), FftError> {
        self.check_buffers(input, outs)?;
        match &mut self.imp {
            Imp::MultiPass(f) => {
                for &(output, set) in outs {
                    f.record_set(encoder, input, output, set)?;
                }
            }
            Imp::Fused(f) => {
                let steps = f.steps(input, outs);
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("dct filter"),
                    timestamp_writes: None,
                });
                for (pipeline, bind, groups) in &steps {
                    pass.set_pipeline(pipeline);
                    pass.set_bind_group(0, bind, &[]);
                    pass.dispatch_workgroups(groups[0], groups[1], 1);
                }
            }
        }
        Ok(())
    }

    /// `spec`'s kernels for this filter's rows (see [`RowEndsSpec`]), or
    /// none on the multi-pass path, where the caller keeps kernels of its
    /// own after and before the filter.
    pub fn row_ends(
        &self,
        kernels: &mut FftKernels,
        spec: &RowEndsSpec,
    ) -> Result<Option<RowEnds>, FftError> {
        let Imp::Fused(f) = &self.imp else {
            return Ok(None);
        };
        // Built at the filter's own shape (a tuned or explicit one), not
        // whatever the kernels hold now.
        let now = std::mem::replace(&mut kernels.variant, self.variant);
        let ends = f.row_ends(kernels, spec);
        kernels.variant = now;
        ends.map(Some)
    }

    /// The filter with gain set `set` from `input` to `output`, its rows'
    /// last dispatch `ends`' store and, where `load`, its first `ends'`
    /// load; `group` is their bind group 1 (of the spec's layout).
    #[allow(clippy::too_many_arguments)]
    pub fn record_with_ends(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        ends: &RowEnds,
        group: &wgpu::BindGroup,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        set: usize,
        load: bool,
    ) -> Result<(), FftError> {
        self.check_buffers(input, &[(output, set)])?;
        let Imp::Fused(f) = &mut self.imp else {
            return Err(FftError::Device(
                "row ends need the workgroup-memory filter; this one runs by passes".into(),
            ));
        };
        if !f.fits(ends) {
            return Err(FftError::Device(format!(
                "row ends built for another filter's rows (of {}, {:?} pairs a workgroup) \
                 recorded on rows of {}",
                ends.n, ends.seqs, self.width
            )));
        }
        let steps = f.steps_with_ends(ends, input, output, set, load);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("dct filter with row ends"),
            timestamp_writes: None,
        });
        for (pipeline, bind, groups, end) in &steps {
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, bind, &[]);
            if *end {
                pass.set_bind_group(1, group, &[]);
            }
            pass.dispatch_workgroups(groups[0], groups[1], 1);
        }
        Ok(())
    }

    fn sets(&self) -> usize {
        match &self.imp {
            Imp::Fused(f) => f.sets(),
            Imp::MultiPass(f) => f.sets(),
        }
    }

    fn check_buffers(
        &self,
        input: &wgpu::Buffer,
        outs: &[(&wgpu::Buffer, usize)],
    ) -> Result<(), FftError> {
        let need = (self.channels * self.width * self.height * 4) as u64;
        for (what, b) in
            std::iter::once(("input", input)).chain(outs.iter().map(|o| ("output", o.0)))
        {
            if b.size() < need {
                return Err(FftError::TooLarge {
                    what: format!("the filter's {what} buffer"),
                    bytes: need,
                    limit: b.size(),
                });
            }
        }
        if let Some((_, set)) = outs.iter().find(|(_, s)| *s >= self.sets()) {
            return Err(FftError::Gains(format!("no gain set {set}")));
        }
        Ok(())
    }
}

/// One or more gain sets of equally many channels, each of width·height
/// finite values: the channel count, or what is wrong.
fn check_gains(width: usize, height: usize, sets: &[&[Vec<f32>]]) -> Result<usize, FftError> {
    let Some(gains) = sets.first() else {
        return Err(FftError::Gains("no gains".into()));
    };
    let channels = gains.len();
    if sets.iter().any(|g| g.len() != channels) {
        return Err(FftError::Gains(
            "gain sets of different channel counts".into(),
        ));
    }
    if channels == 0 || width == 0 || height == 0 {
        return Err(FftError::Gains(format!(
            "{channels} channels of {width}×{height}: nothing to filter"
        )));
    }
    if let Some((c, g)) = sets
        .iter()
        .flat_map(|g| g.iter())
        .enumerate()
        .find(|(_, g)| g.len() != width * height)
    {
        return Err(FftError::Gains(format!(
            "channel {c} has {} values, a {width}×{height} frame needs {}",
            g.len(),
            width * height
        )));
    }
    if sets
        .iter()
        .flat_map(|g| g.iter())
        .flatten()
        .any(|v| !v.is_finite())
    {
        return Err(FftError::Gains("a gain is not finite".into()));
    }
    Ok(channels)
}
