//! `nedrt run --preprocess auto[:LO..HI]` (issue 54): the ladder of
//! preprocessing levels this run can afford, cheapest first: none, the
//! DOE's Wiener prefilter, admm:K for a few K (the split solver, issue
//! 55: at every K it gains more than refine:K for the same FFT pairs, and
//! its device step is one pass lighter), and the network where
//! the run has one; each with its quality from the tradeoff study's table
//! (matched by DOE and model hash) and its time measured at start-up by
//! the service, which picks the level frame by frame
//! (`nedrt_service::pipeline::ladder`). Every level of every view is
//! built here, up front: a switch builds nothing.
//!
//! The levels run on the DOE of the run's system (the network's
//! companion DOE for `proposed`), so that every level shows the same
//! optics, and with the views' own designs where the calibration gives
//! them (the network is then left out: it runs on the DOE it was trained
//! with).

use super::build::prepared_for;
use super::{AppError, CommonOptions, RunOptions};
use nedrt_core::preprocess::{Identity, Preprocess};
use nedrt_optics::sim::{Method, Prepared, Simulator};
use nedrt_stages::preprocess::Prefilter;

mod quality;
pub use quality::{QualityTable, fixed_quality};

/// The admm:K levels a ladder offers.
pub const SOLVER_STEPS: [usize; 3] = [1, 3, 10];

/// The table the levels' quality comes from when `--ladder-quality` is
/// not given (relative to the working directory; `nedrt tradeoff` writes
/// it).
pub const DEFAULT_QUALITY_TABLE: &str = "docs/tradeoff/tradeoff.json";

/// The bounds of `--preprocess auto:LO..HI`: level names, either may be
/// left out (`auto` alone: every level).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct LadderSpec {
    pub lowest: Option<String>,
    pub highest: Option<String>,
}

impl LadderSpec {
    /// `auto`, `auto:LO..HI`, `auto:LO..` or `auto:..HI`; `None` for
    /// anything not starting with `auto`.
    pub fn parse(s: &str) -> Option<Result<Self, String>> {
        let rest = s.strip_prefix("auto")?;
        if rest.is_empty() {
            return Some(Ok(Self::default()));
        }
        let Some(bounds) = rest.strip_prefix(':') else {
            return Some(Err(format!(
                "{s:?}: give auto, or auto:LO..HI with level names ({})",
                level_names_help()
            )));
        };
        let Some((lo, hi)) = bounds.split_once("..") else {
            return Some(Err(format!(
                "{s:?}: the bounds are LO..HI (e.g. auto:wiener..admm:10; either may be left \
                 out)"
            )));
        };
        let name = |n: &str| (!n.trim().is_empty()).then(|| n.trim().to_string());
        Some(Ok(Self {
            lowest: name(lo),
            highest: name(hi),
        }))
    }
}

impl std::fmt::Display for LadderSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.lowest, &self.highest) {
            (None, None) => write!(f, "auto"),
            (lo, hi) => write!(
                f,
                "auto:{}..{}",
                lo.as_deref().unwrap_or(""),
                hi.as_deref().unwrap_or("")
            ),
        }
    }
}

fn level_names_help() -> String {
    let mut names = vec!["none".to_string(), "wiener".to_string()];
    names.extend(SOLVER_STEPS.iter().map(|k| format!("admm:{k}")));
    names.push("the network's file stem (dcnn, unrolled-k3)".into());
    names.join(", ")
}

/// What a level runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rung {
    None,
    Wiener,
    /// A least-squares solve of doe+wiener's optics, K steps against the
    /// default objective: `admm:K` in a ladder, `refine:K` by name only
    /// (`nedrt sim --level`, a fixed run's quality).
    Refine(usize),
    Admm(usize),
    /// The run's i-th network (`--ladder-network`'s, then `--dcnn`'s).
    Network(usize),
    /// A fixed run's method with its `--prefilter` (the method's Wiener,
    /// or a least-squares prefilter on its optics): never a ladder's.
    Method,
}

impl Rung {
    fn prefilter(self) -> Prefilter {
        match self {
            Rung::Refine(k) => Prefilter::Refine(k, Prefilter::DEFAULT_OBJECTIVE),
            Rung::Admm(k) => Prefilter::Admm(k, Prefilter::DEFAULT_OBJECTIVE),
            _ => Prefilter::Native,
        }
    }
}

/// One level as planned: its name, what it runs, its quality and what
/// the table measured of its time, or why it is left out.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedLevel {
    pub name: String,
    pub rung: Rung,
    pub quality_db: Option<f64>,
    /// The table's time for it: (ms, at what size, on what device).
    pub table_ms: Option<(f64, String)>,
    pub left_out: Option<String>,
}

/// A network level: its name (the file's stem), its content hash (what
/// the quality table's rows name) and whether it is an unrolled model
/// (whose steps need the device FFT, as a prefilter's).
#[derive(Debug, Clone, PartialEq)]
pub struct NetworkLevel {
    pub name: String,
    pub hash: String,
    pub unrolled: bool,
}

/// What a ladder is planned from besides the run's facts.
#[derive(Debug, Clone)]
pub struct LadderInputs {
    pub spec: LadderSpec,
    pub table: QualityTable,
    /// The DOE the levels run on, by content hash, and the run's design.
    pub doe_hash: String,
    pub design: Option<String>,
    /// The run's networks, in the ladder's order.
    pub networks: Vec<NetworkLevel>,
}

/// The ladder of a run with `--preprocess auto`.
#[derive(Debug, Clone, PartialEq)]
pub struct LadderPlan {
    pub levels: Vec<PlannedLevel>,
    /// Where the levels' quality comes from.
    pub table: String,
    pub budget: String,
}

/// The facts a ladder is planned from.
#[derive(Debug, Clone)]
pub struct LadderFacts {
    /// The run's networks, in the ladder's order.
    pub networks: Vec<NetworkLevel>,
    /// Why no network can be a level here (another backend than the
    /// device's on the device path, a view's design).
    pub network_excluded: Option<String>,
    /// The DOE the levels run on, by content hash, and the design whose K
    /// its Wiener takes (`--design`; none: the calibration's).
    pub doe_hash: String,
    pub design: Option<String>,
    /// Whether the levels run on the device, and why a prefilter level
    /// cannot where it cannot (a size the device FFT lacks).
    pub on_device: bool,
    pub device_fft_refuses: Option<String>,
}

/// The levels of `spec`, in order, with the ones left out and why.
pub fn plan_levels(
    spec: &LadderSpec,
    facts: &LadderFacts,
    table: &QualityTable,
) -> Result<Vec<PlannedLevel>, AppError> {
    let mut rungs = vec![("none".to_string(), Rung::None)];
    rungs.push(("wiener".into(), Rung::Wiener));
    rungs.extend(
        SOLVER_STEPS
            .iter()
            .map(|&k| (format!("admm:{k}"), Rung::Admm(k))),
    );
    rungs.extend(
        facts
            .networks
            .iter()
            .enumerate()
            .map(|(i, n)| (n.name.clone(), Rung::Network(i))),
    );
    let position = |bound: &Option<String>, default: usize| -> Result<usize, AppError> {
        match bound {
            None => Ok(default),
            Some(b) => rungs.iter().position(|(n, _)| n == b).ok_or_else(|| {
                AppError::option(
                    format!("--preprocess {spec}"),
                    format!(
                        "no level {b:?} in this run's ladder ({})",
                        rungs
                            .iter()
                            .map(|(n, _)| n.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                )
            }),
        }
    };
    let lo = position(&spec.lowest, 0)?;
    let hi = position(&spec.highest, rungs.len() - 1)?;
    if lo > hi {
        return Err(AppError::option(
            format!("--preprocess {spec}"),
            "the lowest level is above the highest",
        ));
    }
    Ok(rungs[lo..=hi]
        .iter()
        .map(|(name, rung)| {
            let device_fft = || match facts.on_device {
                true => facts.device_fft_refuses.clone(),
                false => None,
            };
            let network = match rung {
                Rung::Network(i) => facts.networks.get(*i),
                _ => None,
            };
            let left_out = match rung {
                // An unrolled model's steps are the device FFT's too.
                Rung::Network(_) => facts
                    .network_excluded
                    .clone()
                    .or_else(|| network.filter(|n| n.unrolled).and_then(|_| device_fft())),
                Rung::Wiener | Rung::Refine(_) | Rung::Admm(_) => device_fft(),
                _ => None,
            };
            let found = table.find(
                *rung,
                &facts.doe_hash,
                facts.design.as_deref(),
                network.map(|n| (n.name.clone(), n.hash.clone())).as_ref(),
            );
            PlannedLevel {
                name: name.clone(),
                rung: *rung,
                quality_db: found.map(|r| r.mean_psnr_db),
                table_ms: found.and_then(|r| {
                    r.latency_ms.map(|ms| {
                        (
                            ms,
                            format!("{} on {}", r.size, r.device.as_deref().unwrap_or("?")),
                        )
                    })
                }),
                left_out,
            }
        })
        .collect())
}

/// The one level of a run without a ladder: its network (behind its
/// Wiener stage where the card puts one), or its method's prefilter, or
/// nothing. The plan and the build both take it from here.
pub(super) fn fixed_level(opts: &RunOptions, network: bool) -> PlannedLevel {
    let method = opts.preprocess;
    let (name, rung) = if network {
        (method.name().to_string(), Rung::Network(0))
    } else if !method.uses_wiener() && opts.prefilter.is_native() {
        (method.name().to_string(), Rung::None)
    } else if opts.prefilter.is_native() {
        (format!("{method}'s Wiener"), Rung::Method)
    } else {
        (format!("{} of {method}", opts.prefilter), Rung::Method)
    };
    PlannedLevel {
        name,
        rung,
        quality_db: None,
        table_ms: None,
        left_out: None,
    }
}

/// `nedrt sim --level NAME`: a level of the frame budget by its name in
/// the run's report (none, wiener, admm:K or refine:K for any K ≥ 1, or the network's
/// file stem), as the method and prefilter it runs and the options of the
/// optics it runs on (the system's DOE, as the ladder's levels).
pub fn level_system(
    common: &CommonOptions,
    name: &str,
) -> Result<(CommonOptions, Method, Prefilter), AppError> {
    let stem = Some(super::network::level_name(&common.dcnn.path));
    let (method, prefilter) = match name {
        "none" => (Method::DoeOnly, Prefilter::Native),
        "wiener" => (Method::DoeWiener, Prefilter::Native),
        n if Some(n) == stem.as_deref() || n == "dcnn" => (Method::Proposed, Prefilter::Native),
        n => match n.parse::<Prefilter>() {
            Ok(p @ (Prefilter::Refine(..) | Prefilter::Admm(..))) if !n.contains('@') => {
                (Method::DoeWiener, p)
            }
            _ => {
                return Err(AppError::option(
                    format!("--level {name}"),
                    format!(
                        "not a level of the frame budget: none, wiener, admm:K or refine:K \
                         (K ≥ 1) or the network ({})",
                        stem.as_deref().unwrap_or("dcnn")
                    ),
                ));
            }
        },
    };
    Ok((ladder_common(common, Method::Proposed), method, prefilter))
}

/// The DOE the ladder's levels run on for a view with `design` (its own,
/// else the system's: the network's companion DOE for `proposed`).
pub(super) fn ladder_common(common: &CommonOptions, method: Method) -> CommonOptions {
    let mut c = common.clone();
    if c.doe.is_none() {
        c.doe = common.doe_path_for(&[method]);
    }
    c
}

/// The hash of the DOE `common` runs on (for the quality table).
pub(super) fn doe_hash(common: &CommonOptions) -> Result<String, AppError> {
    let sim = common.measured(Simulator::new(
        common.calibration()?,
        common.doe.as_deref(),
        nedrt_optics::cache::PsfCache::disabled(),
    )?)?;
    Ok(sim.doe_hash)
}

/// The host preprocessors of `levels` on a view's optics `prepared`
/// ([`prepared_levels`]); the network's, where a level is one, from
/// `network`.
pub(super) fn host_levels(
    prepared: Option<&Prepared>,
    levels: &[PlannedLevel],
    opts: &RunOptions,
    network: &mut dyn FnMut(usize) -> Result<Box<dyn Preprocess>, AppError>,
) -> Result<Vec<Box<dyn Preprocess>>, AppError> {
    let mut dcnns = std::collections::HashMap::new();
    levels
        .iter()
        .map(|l| -> Result<Box<dyn Preprocess>, AppError> {
            let prepared = || {
                prepared.ok_or_else(|| {
                    AppError::Internal("a prefilter level without its optics".into())
                })
            };
            Ok(match l.rung {
                Rung::None => Box::new(Identity),
                Rung::Network(i) => network(i)?,
                // A still scene converges over frames (docs/service.md).
                rung @ (Rung::Refine(_) | Rung::Admm(_)) => nedrt_stages::preprocess::solved(
                    Method::DoeWiener,
                    rung.prefilter(),
                    prepared()?,
                    true,
                )?,
                Rung::Method => nedrt_stages::preprocess::for_system(
                    opts.preprocess,
                    opts.prefilter,
                    prepared()?,
                    &mut dcnns,
                )?,
                rung => nedrt_stages::preprocess::for_system(
                    Method::DoeWiener,
                    rung.prefilter(),
                    prepared()?,
                    &mut dcnns,
                )?,
            })
        })
        .collect()
}

/// `common`'s optics prepared for every prefilter level of `levels`
/// (none where no level needs them), once for a view's host and device
/// levels alike.
pub(super) fn prepared_levels(
    common: &CommonOptions,
    opts: &RunOptions,
    levels: &[PlannedLevel],
) -> Result<Option<Prepared>, AppError> {
    if levels.iter().any(|l| l.rung == Rung::Method) {
        return Ok(Some(prepared_for(common, opts.preprocess, opts.prefilter)?));
    }
    let prefilters: Vec<Prefilter> = levels
        .iter()
        .filter(|l| matches!(l.rung, Rung::Wiener | Rung::Refine(_) | Rung::Admm(_)))
        .map(|l| l.rung.prefilter())
        .collect();
    if prefilters.is_empty() {
        return Ok(None);
    }
    let sim = common.measured(Simulator::new(
        common.calibration()?,
        common.doe.as_deref(),
        common.cache(),
    )?)?;
    let depths = Prefilter::all_depths_d(&prefilters, &sim.calib);
    Ok(Some(sim.prepare(
        &[Method::DoeWiener],
        &depths,
        common.progress(),
    )?))
}

/// The device stages of `levels` on a view's optics `prepared` for a view
/// of `size`; the network's from `network`.
pub(super) fn device_levels(
    prepared: Option<&Prepared>,
    levels: &[PlannedLevel],
    device: &wgpu::Device,
    size: (usize, usize),
    network: &mut dyn FnMut(usize) -> Result<Box<dyn nedrt_gpu::DeviceStage>, AppError>,
) -> Result<Vec<Box<dyn nedrt_gpu::DeviceStage>>, AppError> {
    levels
        .iter()
        .map(|l| -> Result<Box<dyn nedrt_gpu::DeviceStage>, AppError> {
            Ok(match l.rung {
                Rung::None => Box::new(nedrt_service::pipeline::ladder::Unprocessed),
                Rung::Network(i) => network(i)?,
                Rung::Method => {
                    return Err(AppError::Internal(
                        "a fixed method in a ladder of several levels".into(),
                    ));
                }
                rung => {
                    let prepared = prepared.ok_or_else(|| {
                        AppError::Internal("a prefilter level without its optics".into())
                    })?;
                    let what = format!("{} of doe+wiener", l.name);
                    nedrt_stages::device_prefilter::prefilter_stage(
                        device,
                        Method::DoeWiener,
                        rung.prefilter(),
                        prepared,
                        what,
                        Some(size),
                        // A still scene converges over frames, as on the host.
                        true,
                    )?
                    .ok_or_else(|| AppError::Internal(format!("{} has no device stage", l.name)))?
                }
            })
        })
        .collect()
}

/// The service's levels: each planned level kept, with its quality; its
/// time is measured at start-up.
pub(super) fn service_levels(
    levels: &[PlannedLevel],
) -> Vec<nedrt_service::pipeline::ladder::Level> {
    levels
        .iter()
        .map(|l| nedrt_service::pipeline::ladder::Level {
            name: l.name.clone(),
            quality_db: l.quality_db,
            reference_ns: 0,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::quality::QualityRow;
    use super::*;

    #[test]
    fn specs_parse_with_either_bound_left_out() {
        assert_eq!(LadderSpec::parse("proposed"), None);
        assert_eq!(LadderSpec::parse("auto"), Some(Ok(LadderSpec::default())));
        let spec = LadderSpec::parse("auto:wiener..admm:10")
            .expect("auto")
            .expect("parses");
        assert_eq!(spec.lowest.as_deref(), Some("wiener"));
        assert_eq!(spec.highest.as_deref(), Some("admm:10"));
        assert_eq!(spec.to_string(), "auto:wiener..admm:10");
        let spec = LadderSpec::parse("auto:..admm:3")
            .expect("auto")
            .expect("parses");
        assert_eq!(
            (spec.lowest, spec.highest.as_deref()),
            (None, Some("admm:3"))
        );
        assert!(LadderSpec::parse("auto:wiener").expect("auto").is_err());
        assert!(LadderSpec::parse("autox").expect("auto").is_err());
    }

    fn facts(network: bool) -> LadderFacts {
        LadderFacts {
            networks: network
                .then(|| NetworkLevel {
                    name: "dcnn".into(),
                    hash: "m1".into(),
                    unrolled: false,
                })
                .into_iter()
                .collect(),
            network_excluded: None,
            doe_hash: "d1".into(),
            design: None,
            on_device: true,
            device_fft_refuses: None,
        }
    }

    fn table() -> QualityTable {
        let row =
            |name: &str, method: &str, doe: Option<&str>, model: Option<&str>, q: f64| QualityRow {
                name: name.into(),
                method: method.into(),
                doe_hash: doe.map(str::to_string),
                model_hash: model.map(str::to_string),
                mean_psnr_db: q,
                latency_ms: Some(1.0),
                device: Some("cpu".into()),
                size: "8×8".into(),
            };
        QualityTable {
            source: None,
            rows: vec![
                row("doe-only", "doe-only", Some("d1"), None, 20.5),
                row("doe+wiener other", "doe+wiener", Some("d2"), None, 30.0),
                row(
                    "doe+wiener multifocal",
                    "doe+wiener",
                    Some("d1"),
                    None,
                    21.5,
                ),
                row("doe+wiener", "doe+wiener", Some("d1"), None, 21.6),
                row(
                    "doe+wiener multifocal admm:10@target wgpu",
                    "doe+wiener",
                    Some("d1"),
                    None,
                    22.0,
                ),
                row(
                    "doe+wiener multifocal lsq@target",
                    "doe+wiener",
                    Some("d1"),
                    None,
                    21.2,
                ),
                row(
                    "proposed dcnn cpu f32",
                    "proposed",
                    Some("d1"),
                    Some("m1"),
                    21.7,
                ),
            ],
        }
    }

    #[test]
    fn levels_take_their_quality_from_the_rows_of_their_doe_and_model() {
        let levels = plan_levels(&LadderSpec::default(), &facts(true), &table()).expect("plan");
        let got: Vec<(&str, Option<f64>)> = levels
            .iter()
            .map(|l| (l.name.as_str(), l.quality_db))
            .collect();
        assert_eq!(
            got,
            [
                ("none", Some(20.5)),
                ("wiener", Some(21.6)),
                ("admm:1", None),
                ("admm:3", None),
                ("admm:10", Some(22.0)),
                ("dcnn", Some(21.7)),
            ]
        );
    }

    #[test]
    fn a_designs_wiener_takes_its_own_row() {
        let mut f = facts(false);
        f.design = Some("multifocal".into());
        let levels = plan_levels(&LadderSpec::default(), &f, &table()).expect("plan");
        assert_eq!(levels[1].quality_db, Some(21.5));
        // admm:10's only row names the design: it is the run's too.
        assert_eq!(levels[4].quality_db, Some(22.0));
    }

    #[test]
    fn bounds_cut_the_ladder_and_unknown_names_are_refused() {
        let spec = LadderSpec::parse("auto:wiener..admm:3")
            .expect("auto")
            .expect("parses");
        let levels = plan_levels(&spec, &facts(false), &table()).expect("plan");
        let names: Vec<&str> = levels.iter().map(|l| l.name.as_str()).collect();
        assert_eq!(names, ["wiener", "admm:1", "admm:3"]);
        let spec = LadderSpec::parse("auto:..dcnn")
            .expect("auto")
            .expect("parses");
        let e = plan_levels(&spec, &facts(false), &table()).expect_err("no network");
        assert!(e.to_string().contains("no level \"dcnn\""), "{e}");
        let spec = LadderSpec::parse("auto:admm:3..wiener")
            .expect("auto")
            .expect("parses");
        assert!(plan_levels(&spec, &facts(false), &table()).is_err());
    }

    #[test]
    fn a_table_that_is_not_a_tradeoff_table_is_named() {
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("t.json");
        std::fs::write(&path, "{\"records\": [{\"name\": \"x\"}]}").expect("write");
        let e = QualityTable::load(Some(&path)).expect_err("bad");
        assert!(e.to_string().contains("t.json"), "{e}");
        assert!(e.to_string().contains("method"), "{e}");
        let missing = dir.path().join("none.json");
        assert!(QualityTable::load(Some(&missing)).is_err());
    }
}
