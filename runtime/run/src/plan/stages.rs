//! Each view's stage chain as the plan prints it, and whether a view's
//! prefilter has a stage on the device (what the builder then finds).

use super::{LadderPlan, PlanInputs, ViewFacts};
use nedrt_stages::device_prefilter::runs_on_device;

/// Whether view `v`'s prefilter (its method's Wiener, `lsq` or `refine:K`,
/// or its network's Wiener stage) has a stage on the device, or why not
/// (`optimal` has none; the device FFT takes sides whose prime factors are
/// at most 13). The same tests the build's device stages make.
pub(super) fn prefilter_on_device(inputs: &PlanInputs<'_>, v: &ViewFacts) -> Result<(), String> {
    let opts = inputs.opts;
    match &inputs.network {
        Some(n) if n.behind_wiener_k.is_none() && n.unrolled_steps.is_none() => return Ok(()),
        Some(_) => {}
        None if !opts.preprocess.uses_wiener() && opts.prefilter.is_native() => return Ok(()),
        None if !runs_on_device(opts.preprocess, opts.prefilter) => {
            return Err(format!("{} has no device stage", opts.prefilter));
        }
        None => {}
    }
    let (w, h) = (v.region.width, v.region.height);
    for side in [w, h] {
        nedrt_gpu::fft::radices(side)
            .map_err(|e| format!("the device FFT takes no {w}×{h} frame: {e}"))?;
    }
    Ok(())
}

/// The stages a frame of view `v` goes through: the ladder's level where
/// the run has one (its levels the device cannot run are left out of it),
/// else the method's stages.
pub(super) fn stages(
    inputs: &PlanInputs<'_>,
    v: &ViewFacts,
    on_device: bool,
    ladder: Option<&LadderPlan>,
) -> Vec<String> {
    let opts = inputs.opts;
    let here = if on_device {
        "on the GPU"
    } else {
        "on the host"
    };
    // A prefilter the device lacks runs on the host before the upload.
    let host_first = on_device && ladder.is_none() && prefilter_on_device(inputs, v).is_err();
    let prefilter_here = if host_first { "on the host" } else { here };
    let mut s = Vec::new();
    s.push(if on_device && !host_first {
        "upload as sent, unpack on the GPU".to_string()
    } else {
        "decode on the host".to_string()
    });
    s.push(format!(
        "quad layers blended {}",
        if host_first { "on the host" } else { here }
    ));
    let design = v
        .design
        .as_deref()
        .map(|d| format!(" (design {d})"))
        .unwrap_or_default();
    match (ladder, &inputs.network) {
        (Some(l), _) => {
            let names: Vec<&str> = l
                .levels
                .iter()
                .filter(|l| l.left_out.is_none())
                .map(|l| l.name.as_str())
                .collect();
            s.push(format!(
                "the frame budget's level ({}) {here}",
                names.join(" < ")
            ));
        }
        (None, Some(n)) => {
            if let Some(k) = n.behind_wiener_k {
                s.push(format!(
                    "Wiener prefilter of {} (K = {k:.3e}) {prefilter_here}",
                    opts.preprocess
                ));
                if host_first {
                    s.push("its planes uploaded".into());
                }
            }
            s.push(match n.unrolled_steps {
                Some(k) => format!(
                    "unrolled model: the lsq start, {k} split-solver steps with learned \
                     corrections {here}"
                ),
                None => format!("D-CNN {here}"),
            });
        }
        (None, None) if !opts.prefilter.is_native() => {
            s.push(format!(
                "{} prefilter of {}{design} {prefilter_here}",
                opts.prefilter, opts.preprocess
            ));
        }
        (None, None) if opts.preprocess.uses_wiener() => {
            s.push(format!(
                "Wiener prefilter of {}{design} {prefilter_here}",
                opts.preprocess
            ));
        }
        (None, None) => {}
    }
    if host_first && inputs.network.is_none() {
        s.push("its planes uploaded".into());
    }
    s.push(format!(
        "clamp to [0, 1] and the panel's transfer curve {here}"
    ));
    s.push(if on_device {
        "the sink copies the codes on the GPU".into()
    } else {
        "the sink takes the codes from host memory".into()
    });
    s
}
