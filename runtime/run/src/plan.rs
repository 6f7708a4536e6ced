//! What `nedrt run` will build, decided before anything is built: the
//! views, each view's stage chain, the frame path, where the network runs,
//! the pacing, and the reason for each choice. A pure function of the
//! options, the calibration's facts and the adapter found ([`Probe`]);
//! `nedrt run --plan` prints it and exits, and `run` builds what it says
//! (a part that then fails to build on the device falls back to the host,
//! and the report's frame path says so).

use std::fmt;

use super::ladder::{LadderFacts, PlannedLevel, Rung, fixed_level, plan_levels};
use super::ladder::{LadderInputs, LadderPlan};
use super::{AppError, FallbackKind, FramePath, RunOptions, SinkKind, SourceKind};
use nedrt_core::Named;
use nedrt_infer::{BackendKind, Precision};
use nedrt_optics::sim::Method;
use nedrt_service::compose::ViewRegion;

mod stages;
use stages::{prefilter_on_device, stages};

/// The GPU the sink offers, as probed.
#[derive(Debug, Clone, PartialEq)]
pub enum Probe {
    /// The sink keeps frames in host memory (a recorder): no GPU asked for.
    NotNeeded,
    /// An adapter: its name and whether it runs f16 shaders.
    Adapter { name: String, shader_f16: bool },
    /// None could be opened, and why.
    Missing(String),
}

/// The network a run uses, from its file and card.
#[derive(Debug, Clone, PartialEq)]
pub struct NetworkFacts {
    pub path: String,
    /// The Wiener stage it runs behind (its card's `wiener_k`), if any.
    pub behind_wiener_k: Option<f64>,
    /// An unrolled model's steps (its manifest's), for a D-CNN none.
    pub unrolled_steps: Option<usize>,
}

/// A view to plan: its name, region and design (from `[[view]]`, or the
/// panel's halves, or the whole panel).
#[derive(Debug, Clone, PartialEq)]
pub struct ViewFacts {
    pub name: String,
    pub region: ViewRegion,
    pub design: Option<String>,
}

/// Everything the plan is decided from.
#[derive(Debug, Clone)]
pub struct PlanInputs<'a> {
    pub opts: &'a RunOptions,
    pub panel: (usize, usize, f64),
    /// The views; one view covering the panel for a run without views.
    pub views: Vec<ViewFacts>,
    pub network: Option<NetworkFacts>,
    pub backend: BackendKind,
    pub precision: Precision,
    pub probe: Probe,
    /// `--preprocess auto`: the ladder's bounds and what its levels'
    /// quality is looked up by.
    pub ladder: Option<LadderInputs>,
}

/// Where the frames go between the client and the panel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlannedPath {
    Device,
    Host,
}

/// One view's plan.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewPlan {
    pub name: String,
    pub region: ViewRegion,
    /// The stages a frame goes through, in order.
    pub stages: Vec<String>,
}

/// What `nedrt run` builds, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct RunPlan {
    pub panel: String,
    pub source: String,
    pub sink: String,
    pub adapter: String,
    pub path: PlannedPath,
    pub path_reason: String,
    pub network: String,
    pub fallback: String,
    pub pacing: String,
    pub views: Vec<ViewPlan>,
    /// The levels every view runs: the ladder's that are kept, or a fixed
    /// run's one.
    pub levels: Vec<PlannedLevel>,
    pub ladder: Option<LadderPlan>,
}

/// Decides the run's plan; a ladder's bounds that name no level of it
/// are refused.
pub fn plan(inputs: &PlanInputs<'_>) -> Result<RunPlan, AppError> {
    let opts = inputs.opts;
    // A ladder leaves out the levels the device cannot run rather than
    // sending every level to the host.
    let laddered = inputs.ladder.is_some();
    let (width, height, refresh_hz) = inputs.panel;
    let two = inputs.views.len() > 1;
    let device = match &inputs.probe {
        Probe::Adapter { .. } => true,
        Probe::NotNeeded | Probe::Missing(_) => false,
    };
    let network_on_device = inputs.backend == BackendKind::Wgpu;
    let f16_missing = matches!(
        &inputs.probe,
        Probe::Adapter {
            shader_f16: false,
            ..
        }
    ) && inputs.precision == Precision::F16;
    // The same order of reasons as the build: the first that holds.
    let host_reason = if opts.frame_path == FramePath::Host {
        Some("--frame-path host".to_string())
    } else if let Probe::Missing(why) = &inputs.probe {
        Some(format!("no GPU adapter ({why})"))
    } else if !device {
        Some(format!(
            "the {} sink takes frames in host memory",
            opts.sink.name()
        ))
    } else if laddered {
        None
    } else if inputs.network.is_some() && !network_on_device {
        Some(network_on_host(inputs.backend))
    } else if inputs.network.is_some() && f16_missing {
        Some(NO_F16.to_string())
    } else if let Some(e) = inputs
        .network
        .as_ref()
        .filter(|n| n.unrolled_steps.is_some())
        .and_then(|_| {
            inputs
                .views
                .iter()
                .find_map(|v| prefilter_on_device(inputs, v).err())
        })
    {
        // Its steps' transforms are the device FFT's.
        Some(format!("the unrolled model's steps: {e}"))
    } else if inputs.network.is_none()
        && opts.inject_device_loss_after.is_some()
        && (fixed_level(opts, false).rung == Rung::None
            || inputs
                .views
                .iter()
                .any(|v| prefilter_on_device(inputs, v).is_err()))
    {
        Some("the injected device loss needs a stage on the device to fail".to_string())
    } else {
        None
    };
    let path = if host_reason.is_some() {
        PlannedPath::Host
    } else {
        PlannedPath::Device
    };
    let path_reason = host_reason.unwrap_or_else(|| {
        if two {
            "each view's frame uploaded as sent, every view's unpack, layers, stages and encode \
             in one submission on the sink's GPU; no read-back"
                .into()
        } else {
            "the sink has a GPU and every stage runs there: one upload, no read-back".into()
        }
    });
    let on_device = path == PlannedPath::Device;
    let ladder = match &inputs.ladder {
        None => None,
        Some(l) => Some(ladder_plan(inputs, l, on_device, f16_missing)?),
    };
    let network = match &inputs.network {
        None => format!("none ({} has no network)", method_line(opts)),
        Some(n) => {
            let engine = if on_device {
                format!(
                    "wgpu on the sink's GPU, {}",
                    precision_name(inputs.precision)
                )
            } else if inputs.backend == BackendKind::Wgpu {
                // The builder's host network (build::host_network).
                match &inputs.probe {
                    Probe::Adapter { shader_f16, .. }
                        if *shader_f16 || inputs.precision == Precision::F32 =>
                    {
                        format!(
                            "wgpu on the sink's GPU, {}, its output read back to the host",
                            precision_name(inputs.precision)
                        )
                    }
                    Probe::Adapter { .. } => "cpu on the host, f32".to_string(),
                    _ => format!(
                        "wgpu on a GPU of its own, {} (the CPU's tract, f32, if none starts)",
                        precision_name(inputs.precision)
                    ),
                }
            } else {
                format!(
                    "{} on the host, {}",
                    inputs.backend.name(),
                    precision_name(inputs.precision)
                )
            };
            match n.unrolled_steps {
                Some(k) => format!(
                    "{} (unrolled: {k} split-solver steps with learned corrections): {engine}",
                    n.path
                ),
                None => format!("{}: {engine}", n.path),
            }
        }
    };
    let fallback = match (&inputs.network, opts.fallback) {
        _ if ladder.is_some() => "each view's levels on the host (the network's by --fallback), \
                                 the same level, if the device fails"
            .to_string(),
        (None, _) => "none needed (no network)".to_string(),
        (Some(_), FallbackKind::Cpu) => {
            "the same network on the CPU (tract), if the engine fails".into()
        }
        (Some(n), FallbackKind::Passthrough) => match n.behind_wiener_k {
            Some(_) => "its Wiener stage alone, if the engine fails".into(),
            None => "the frame as submitted, if the engine fails".into(),
        },
    };
    let views = inputs
        .views
        .iter()
        .map(|v| ViewPlan {
            name: v.name.clone(),
            region: v.region,
            stages: stages(inputs, v, on_device, ladder.as_ref()),
        })
        .collect();
    let source = match (opts.source, opts.source_rate_hz) {
        (SourceKind::Socket, _) => format!(
            "applications on {} (they render for the predicted display time in each reply)",
            opts.socket.display()
        ),
        (kind, None) => format!(
            "{}, each frame made just in time for the refresh it is shown at",
            source_name(kind)
        ),
        (kind, Some(0.0)) => format!("{}, unpaced", source_name(kind)),
        (kind, Some(hz)) => format!("{} at {hz} Hz on its own timer", source_name(kind)),
    };
    let pacing = match opts.sink {
        SinkKind::Window => "paced by the display: the window's present waits for the refresh, \
                             and frames are taken a period ahead of it"
            .to_string(),
        _ => "just in time: the present loop wakes at each refresh minus its own work and a \
              margin it learns, and takes the newest finished frame then"
            .to_string(),
    };
    let adapter = match &inputs.probe {
        Probe::NotNeeded => "not used (the sink keeps frames in host memory)".to_string(),
        Probe::Adapter { name, shader_f16 } => format!(
            "{name} ({})",
            if *shader_f16 {
                "f16 shaders"
            } else {
                "no f16 shaders"
            }
        ),
        Probe::Missing(why) => format!("none: {why}"),
    };
    Ok(RunPlan {
        panel: format!(
            "{width}×{height} at {refresh_hz} Hz, {} view{}",
            inputs.views.len(),
            if two { "s" } else { "" }
        ),
        source,
        sink: format!("{} ({})", opts.sink.name(), opts.sink.help()),
        adapter,
        path,
        path_reason,
        network,
        fallback,
        pacing,
        views,
        levels: match &ladder {
            Some(l) => l
                .levels
                .iter()
                .filter(|l| l.left_out.is_none())
                .cloned()
                .collect(),
            None => vec![fixed_level(opts, inputs.network.is_some())],
        },
        ladder,
    })
}

const NO_F16: &str = "the adapter has no f16 shaders for the f16 network";

fn network_on_host(backend: BackendKind) -> String {
    format!(
        "the network runs on the {} backend, on the host",
        backend.name()
    )
}

/// The ladder's levels: each one the frame path can run, and why not
/// where it cannot (a network off the device's backend, a view's own
/// design, a size the device FFT lacks).
fn ladder_plan(
    inputs: &PlanInputs<'_>,
    l: &LadderInputs,
    on_device: bool,
    f16_missing: bool,
) -> Result<LadderPlan, AppError> {
    let network_excluded = if inputs.views.iter().any(|v| v.design.is_some()) {
        Some(
            "a view has a design of its own: the network runs on the DOE it was trained with"
                .into(),
        )
    } else if on_device && inputs.backend != BackendKind::Wgpu {
        Some(network_on_host(inputs.backend))
    } else if on_device && f16_missing {
        Some(NO_F16.into())
    } else {
        None
    };
    let device_fft_refuses = on_device
        .then(|| {
            inputs.views.iter().find_map(|v| {
                let (w, h) = (v.region.width, v.region.height);
                [w, h].iter().find_map(|&side| {
                    nedrt_gpu::fft::radices(side)
                        .err()
                        .map(|e| format!("the device FFT takes no {w}×{h} frame: {e}"))
                })
            })
        })
        .flatten();
    let facts = LadderFacts {
        networks: l.networks.clone(),
        network_excluded,
        doe_hash: l.doe_hash.clone(),
        design: l.design.clone(),
        on_device,
        device_fft_refuses,
    };
    let levels = plan_levels(&l.spec, &facts, &l.table)?;
    let period_ms = 1e3 / inputs.panel.2;
    Ok(LadderPlan {
        levels,
        table: match &l.table.source {
            Some(p) => format!(
                "quality: mean PSNR vs sharp over 0–2.5 D from {}",
                p.display()
            ),
            None => format!(
                "quality: not known (no {}; `nedrt tradeoff` writes it): the levels keep \
                 their order",
                super::ladder::DEFAULT_QUALITY_TABLE
            ),
        },
        budget: format!(
            "a frame's preprocessing gets the refresh ({period_ms:.2} ms) less the present's \
             lead (learnt as it runs) and a 32nd ({:.2} ms); each level's time is measured at \
             start-up and learnt per frame, and a level no better than a faster one is dropped \
             then",
            period_ms / 32.0
        ),
    })
}

fn precision_name(p: Precision) -> &'static str {
    match p {
        Precision::F32 => "f32",
        Precision::F16 => "f16",
    }
}

fn source_name(kind: SourceKind) -> &'static str {
    match kind {
        SourceKind::Pattern => "the test pattern",
        SourceKind::Dir => "the images of --input",
        SourceKind::Socket => "applications",
    }
}

fn method_line(opts: &RunOptions) -> String {
    let m: Method = opts.preprocess;
    if opts.prefilter.is_native() {
        format!("--preprocess {m}")
    } else {
        format!("--preprocess {m} --prefilter {}", opts.prefilter)
    }
}

impl fmt::Display for RunPlan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "panel:      {}", self.panel)?;
        writeln!(f, "source:     {}", self.source)?;
        writeln!(f, "sink:       {}", self.sink)?;
        writeln!(f, "adapter:    {}", self.adapter)?;
        let path = match self.path {
            PlannedPath::Device => "device",
            PlannedPath::Host => "host",
        };
        writeln!(f, "frame path: {path}, because {}", self.path_reason)?;
        writeln!(f, "network:    {}", self.network)?;
        writeln!(f, "fallback:   {}", self.fallback)?;
        writeln!(f, "pacing:     {}", self.pacing)?;
        if let Some(l) = &self.ladder {
            writeln!(f, "ladder:     {}", l.table)?;
            for level in &l.levels {
                let quality = level
                    .quality_db
                    .map_or("quality not known".to_string(), |q| format!("{q:.2} dB"));
                let time = level
                    .table_ms
                    .as_ref()
                    .map_or("time measured at start-up".to_string(), |(ms, at)| {
                        format!("{ms:.2} ms in the table ({at}); measured at start-up")
                    });
                match &level.left_out {
                    Some(why) => writeln!(f, "  {:<10} left out: {why}", level.name)?,
                    None => writeln!(f, "  {:<10} {quality}, {time}", level.name)?,
                }
            }
            writeln!(f, "budget:     {}", l.budget)?;
        }
        for v in &self.views {
            let r = v.region;
            writeln!(
                f,
                "view {:?} {}×{} at ({}, {}): {}",
                v.name,
                r.width,
                r.height,
                r.x,
                r.y,
                v.stages.join(" → ")
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "plan_tests.rs"]
mod tests;
