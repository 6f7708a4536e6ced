//! Each command: its arguments turned into typed options (nedrt-run's for
//! `nedrt run`, nedrt-app's and nedrt-studies' for the others), run,
//! and its report printed.

use std::sync::Arc;

use anyhow::{Context, Result, bail};
use nedrt_app::{self as app, CommonOptions};
use nedrt_infer::{BackendKind, BackendOptions, OrtLibrary};
use nedrt_service::pipeline::service::Control;
use nedrt_service::present::window::WindowOptions;
use nedrt_studies as studies;

use crate::args::{BenchKind, CalibAction, Cli, Command, RunPreprocess, ShownArg};
use crate::console::Console;
use crate::install_signals;
use crate::settings::Environment;
use nedrt_optics::sim::Method;

/// Runs the parsed command.
pub fn run(cli: Cli) -> Result<()> {
    let g = &cli.global;
    let env = Environment::capture();
    // The ort library is looked for only when the command may use it.
    let may_use_ort = g.backend == Some(BackendKind::Ort)
        || matches!(
            &cli.command,
            Some(Command::Tradeoff(a)) if a.backends.contains(&BackendKind::Ort)
        )
        || matches!(
            &cli.command,
            Some(Command::Bench(a)) if a.backends.contains(&BackendKind::Ort)
        );
    let design = g
        .design
        .as_deref()
        .map(app::design::Design::resolve)
        .transpose()?;
    let common = CommonOptions {
        calib: g.calib.clone(),
        cache_dir: if g.no_cache {
            None
        } else {
            g.cache_dir.clone().or_else(|| env.cache_dir())
        },
        cache_max_bytes: env.cache_max_bytes()?,
        doe: design
            .as_ref()
            .map(|d| d.doe.clone())
            .or_else(|| g.doe.clone()),
        design,
        psfs: g.psfs.clone().map(app::MeasuredPsfs::new),
        dcnn: app::DcnnOptions {
            path: g.dcnn.clone(),
            lens_path: g.dcnn_lens.clone(),
            backend: g.backend.unwrap_or(BackendKind::Cpu),
            backend_options: BackendOptions {
                threads: g.threads,
                precision: g.precision,
                conv_path: g.conv_path,
                f16_math: g.f16_math,
                tuning_dir: Some(g.tuning.clone()),
                ort_provider: g.ort_provider,
                gpu: env.gpu.clone(),
                ort_library: if may_use_ort {
                    env.ort_library()
                } else {
                    OrtLibrary::default()
                },
            },
        },
        eye: g.eye.overrides(),
        progress: Arc::new(Console::default()),
    };
    // The DCT filter's tuned shapes (issue 56, item 4): every device
    // prefilter asks for its adapter's table in --tuning once.
    let tuning = g.tuning.clone();
    nedrt_gpu::fft::tuned::install(Box::new(move |info| {
        nedrt_infer::gpu::tuning::fft_shapes_for(&tuning, info)
    }));
    match cli.command {
        Some(Command::Psf(a)) => match a.at {
            Some(d) => print!(
                "{}",
                app::frames::write_psfs(&common, a.method, d, &a.plot.out_dir)?
            ),
            None => print!(
                "{}",
                studies::plots::psf(&common, &a.plot.out_dir, a.plot.step)?
            ),
        },
        Some(Command::Mtf(a)) => print!("{}", studies::plots::mtf(&common, &a.out_dir, a.step)?),
        Some(Command::Doe(a)) => print!(
            "{}",
            studies::plots::doe(
                &common,
                &a.out_dir,
                a.write_init.as_deref(),
                a.write_fabrication.as_deref()
            )?
        ),
        Some(Command::Eval(a)) => {
            let external = a.display_dir.map(|dir| studies::eval::ExternalDisplays {
                name: a.display_name,
                dir,
                optics: a.display_optics,
            });
            if !a.eyes.is_empty() && a.sweeps.is_some() {
                anyhow::bail!("--sweeps with --eyes: give one eye (its flags) for the sweeps");
            }
            let extras = studies::eval::EvalExtras {
                external,
                designs: a
                    .designs
                    .iter()
                    .map(|n| app::design::Design::resolve(n))
                    .collect::<Result<_, _>>()?,
                focus_cues: a.focus_cues,
                sweeps: a.sweeps,
                prefilters: dedup(a.prefilter),
            };
            print!(
                "{}",
                if a.eyes.is_empty() {
                    studies::eval::run(&common, &a.images, &a.out_dir, &a.methods, &extras)?
                } else {
                    studies::eval::eyes::run(
                        &common, &a.images, &a.out_dir, &a.methods, &extras, &a.eyes,
                    )?
                }
            )
        }
        Some(Command::View(a)) => {
            let opts = app::viewer::ViewOptions {
                step_d: a.step,
                accommodation_d: a.accom,
                shown: match a.show {
                    ShownArg::Perceived => app::viewer::scene::Shown::Perceived,
                    ShownArg::Sharp => app::viewer::scene::Shown::Sharp,
                    ShownArg::Target => app::viewer::scene::Shown::Target,
                },
                headless: a.headless,
                screenshot: a.screenshot,
                screenshot_dir: a.screenshot_dir,
                max_window: (a.max_window.0 as u32, a.max_window.1 as u32),
                window: WindowOptions {
                    gpu: env.gpu.clone(),
                    vsync: true,
                    ..Default::default()
                },
            };
            let (common, scene) = a.scene.source(common)?;
            print!("{}", app::viewer::view(&common, &scene, &opts)?);
        }
        Some(Command::Sweep(a)) => {
            let opts = app::viewer::SweepOptions {
                from_d: a.from,
                to_d: a.to,
                step_d: a.step,
                fps: a.fps,
                out: a.out,
            };
            let (common, scene) = a.scene.source(common)?;
            print!("{}", app::viewer::sweep(&common, &scene, &opts)?);
        }
        Some(Command::TuneWiener(a)) => {
            print!("{}", app::tune::run(&common, &a.images, a.method, a.write)?)
        }
        Some(Command::Run(a)) => {
            let mut common = common;
            common.dcnn.backend = g.backend.unwrap_or(BackendKind::Wgpu);
            let control = Control {
                keep_open: a.keep_open,
                progress: common.progress.clone(),
                ..Default::default()
            };
            install_signals(&control)?;
            // The frame budget by default; a prefilter asked for runs as
            // asked, on the shipped system's optics (auto picks its own).
            let preprocess = a.preprocess.unwrap_or(if a.prefilter.is_native() {
                RunPreprocess::Auto(Default::default())
            } else {
                RunPreprocess::Method(Method::Proposed)
            });
            let (preprocess, ladder) = match preprocess {
                RunPreprocess::Method(m) => (m, None),
                RunPreprocess::Auto(spec) => (Method::Proposed, Some(spec)),
            };
            let opts = nedrt_run::RunOptions {
                preprocess,
                prefilter: a.prefilter,
                ladder,
                ladder_quality: a.ladder_quality,
                ladder_networks: a.ladder_network,
                source: a.source,
                input: a.input,
                socket: a.socket,
                shm_dir: a.shm_dir,
                frames: a.frames,
                source_rate_hz: a.source_rate,
                sink: a.sink,
                record_dir: a.record_dir,
                window: WindowOptions {
                    gpu: env.gpu.clone(),
                    title: "nedrt".into(),
                    fullscreen: a.fullscreen,
                    monitor: a.monitor,
                    vsync: !a.no_vsync,
                    no_display_hint: Some(
                        "--sink headless (needs a GPU, no display) or --sink record (neither)"
                            .into(),
                    ),
                    ..Default::default()
                },
                fallback: a.fallback,
                frame_path: a.frame_path,
                panel_size: None,
                report_json: a.report_json,
                inject_device_loss_after: a.inject_device_loss_after,
                stereo: a.stereo,
            };
            if a.plan {
                print!("{}", nedrt_run::plan_run(&common, &opts)?);
                return Ok(());
            }
            let report = nedrt_run::run(&common, &opts, &control)?;
            print!("{}", report.table());
        }
        Some(Command::Tolerance(t)) if t.replot => {
            print!("{}", app::tolerance::replot(&t.out, t.crop)?)
        }
        Some(Command::Tolerance(t)) => {
            if t.max_images == 0 || t.crop < 8 {
                return Err(app::AppError::option(
                    "--max-images/--crop",
                    "at least one image, and a crop of at least 8 px",
                )
                .into());
            }
            let mut images = app::images::list_images(&t.images)?;
            images.truncate(t.max_images);
            print!(
                "{}",
                app::tolerance::run(&common, &t.methods, &images, t.crop, &t.out)?
            )
        }
        Some(Command::Calib(a)) => match a.action {
            None => print!("{}", studies::plots::calib_summary(&common)?),
            Some(CalibAction::Patterns(p)) => {
                print!(
                    "{}",
                    app::calib_patterns::write(&common, &p.out, p.margin, p.shifts)?
                )
            }
            Some(CalibAction::Synth(s)) => {
                let camera = match &s.camera {
                    Some(path) => app::calib_capture::Camera::load(path)?,
                    None => Default::default(),
                };
                let opts = app::calib_synth::SynthOptions {
                    patterns_dir: s.patterns,
                    out: s.out,
                    accommodations_d: s.accommodations,
                    perturbation: s.built.perturbation(),
                    camera,
                    seed: s.seed,
                    field_zones: s.field_zones.0,
                };
                print!("{}", app::calib_synth::write(&common, &opts)?)
            }
            Some(CalibAction::Truth(t)) => {
                print!(
                    "{}",
                    app::calib_truth::write(
                        &common,
                        &t.built.perturbation(),
                        &t.accommodations,
                        t.field_zones.0,
                        &t.out
                    )?
                )
            }
            Some(CalibAction::Show(s)) => {
                print!(
                    "{}",
                    app::calib_show::show(
                        &common,
                        &s.bundle,
                        s.against.as_deref(),
                        s.chart.as_deref(),
                    )?
                )
            }
            Some(CalibAction::Psfs(p)) => {
                print!(
                    "{}",
                    app::calib_psfs::write(&common, &p.captures, &p.out, p.field_zones.0)?
                )
            }
        },
        Some(Command::Bench(a)) => match a.what {
            BenchKind::Psf => println!("{}", studies::bench::psf(&common, &a.dump, a.repeat)?),
            BenchKind::Perceived => {
                print!("{}", studies::bench::perceived(&common, &a.dump, a.repeat)?)
            }
            BenchKind::Radial => print!("{}", studies::bench::radial(&common, &a.dump)?),
            BenchKind::Inference => {
                let bench = studies::bench_inference::InferenceBench {
                    backends: a.backends,
                    sizes: a.sizes,
                    models: vec![("full".into(), 32), ("half".into(), 16)],
                    repeat: a.repeat,
                    max_seconds: a.max_seconds,
                    threads: g.threads,
                    per_layer: a.per_layer,
                    peaks: studies::bench_inference::Peaks {
                        gmacs: a.peak_gmacs,
                        tensor_gmacs: a.peak_tensor_gmacs,
                        gbps: a.peak_gbps,
                    },
                };
                if bench.per_layer {
                    print!("{}", studies::bench_layers::per_layer(&bench, &common)?);
                } else {
                    let table =
                        studies::bench_inference::run(&bench, &common, &mut |r| println!("{r}"))?;
                    print!("{table}");
                }
            }
            BenchKind::Pipeline => {
                let bench = studies::bench_pipeline::PipelineBench {
                    networks: a.networks,
                    paths: a.frame_paths,
                    frames: a.frames,
                    max_seconds: a.max_seconds,
                    panel_size: a.panel,
                    dump: a.dump,
                    stereo: a.stereo,
                    frame_log: a.frame_log,
                };
                let table =
                    studies::bench_pipeline::run(&bench, &common, &mut |r| println!("{r}"))?;
                print!("{table}");
            }
            BenchKind::Fft => {
                let bench = studies::bench_fft::FftBench {
                    sizes: a.sizes,
                    repeat: a.repeat,
                    peak_gbps: a.peak_gbps,
                    gpu: common.dcnn.backend_options.gpu.clone(),
                    per_pass: a.per_layer,
                    paths: a.fft_paths.iter().map(|p| (*p).into()).collect(),
                    variants: a.fft_variants.clone(),
                    refine_steps: a.refine_steps.map(usize::from),
                };
                let table = studies::bench_fft::run(&bench, &mut |r| println!("{r}"))?;
                print!("{table}");
            }
            BenchKind::Tune => {
                use studies::bench_pipeline::PipelineNetwork as N;
                let mut networks = Vec::new();
                for n in &a.networks {
                    match n {
                        N::Half => networks.push((
                            "half".to_string(),
                            studies::bench_inference::synth_model("half", 16)?,
                        )),
                        N::Full => networks.push((
                            "full".to_string(),
                            studies::bench_inference::synth_model("full", 32)?,
                        )),
                        N::Model => networks.push((
                            common.dcnn.path.display().to_string(),
                            nedrt_infer::ModelFile::read(&common.dcnn.path)?,
                        )),
                        _ => {}
                    }
                }
                let bench = studies::bench_tune::TuneBench {
                    networks,
                    sizes: a.sizes,
                    repeat: a.repeat,
                    dir: g.tuning.clone(),
                    tiles: (!a.tiles.is_empty()).then_some(a.tiles),
                    fused_tiles: if a.no_fused {
                        Some(Vec::new())
                    } else {
                        (!a.fused_tiles.is_empty()).then_some(a.fused_tiles)
                    },
                    coop_only: a.coop_only,
                    fft: !a.no_fft,
                };
                print!("{}", studies::bench_tune::run(&bench, &common)?.report);
            }
            BenchKind::Ceilings => {
                let (gflops, gbps) = studies::bench::ceilings();
                println!(
                    "{{\"kind\": \"ceilings\", \"f64_gemm_gflops\": {gflops:.2}, \"copy_gbps\": {gbps:.2}}}"
                );
            }
        },
        Some(Command::Tradeoff(a)) if a.replot => {
            print!("{}", studies::tradeoff::replot(&a.out_dir)?);
        }
        Some(Command::Tradeoff(a)) => {
            let calib = common.calibration()?;
            let opts = studies::tradeoff::TradeoffOptions {
                images_dir: a.images,
                out_dir: a.out_dir,
                size: a
                    .size
                    .unwrap_or((calib.panel.width_px, calib.panel.height_px)),
                models: a.models.unwrap_or_else(|| {
                    if a.add {
                        Vec::new()
                    } else {
                        vec!["models/dcnn.onnx".into()]
                    }
                }),
                backends: a.backends,
                repeat: a.repeat,
                max_seconds: a.max_seconds,
                threads: g.threads,
                fidelity: !a.no_fidelity,
                designs: app::design::Design::resolve_list(a.designs.as_deref())?,
                prefilters: dedup(a.prefilter),
                time_budget_s: match a.time_budget {
                    Some(s) if !(s.is_finite() && s >= 0.0) => {
                        bail!("--time-budget {s}: not a number of seconds ≥ 0")
                    }
                    b => b,
                },
                add: a.add,
            };
            print!("{}", studies::tradeoff::run(&common, &opts)?);
        }
        Some(Command::Pick(a)) => {
            for (name, v) in [("--min-psnr", a.min_psnr), ("--budget-ms", a.budget_ms)]
                .into_iter()
                .chain(a.min_worst_psnr.map(|w| ("--min-worst-psnr", w)))
            {
                if !v.is_finite() {
                    bail!("{name} {v}: not a number");
                }
            }
            let table = studies::tradeoff::Table::load(&a.table)?;
            let req = studies::tradeoff::pareto::Requirement {
                min_mean_psnr_db: a.min_psnr,
                min_worst_psnr_db: a.min_worst_psnr,
                max_latency_ms: a.budget_ms,
            };
            let points = table.points();
            let pick = studies::tradeoff::pareto::pick(&points, &req);
            if !matches!(pick, studies::tradeoff::pareto::Pick::Chosen(_)) {
                bail!(
                    "{pick} ({}, {}×{} frames on {})",
                    a.table.display(),
                    table.frame_width,
                    table.frame_height,
                    table.host
                );
            }
            println!("{pick}");
        }
        Some(Command::Stability(a)) => {
            if a.content_size < 8 {
                bail!("--content-size {}: at least 8 pixels", a.content_size);
            }
            let opts = studies::stability::StabilityOptions {
                images_dir: a.images,
                out: a.out,
                model: g.dcnn.clone(),
                content_size: a.content_size,
                gpu: !a.no_gpu,
                designs: app::design::Design::resolve_list(a.designs.as_deref())?,
                eyes: a.eyes,
            };
            print!("{}", studies::stability::run(&common, &opts)?);
        }
        Some(Command::Prefilter(a)) => {
            let opts = app::prefilter_batch::PrefilterOptions {
                images: a.images,
                out_dir: a.out_dir,
                method: a.method,
                prefilter: a.prefilter,
                operator_sizes: a.operator,
                unclamped: a.unclamped,
                mirror_psfs: a.mirror_psfs,
            };
            println!("{}", app::prefilter_batch::run(&common, &opts)?);
        }
        Some(Command::Sim(s)) => {
            let accommodation_d = s
                .accom
                .context("--sim needs --accom D (the eye's accommodation in diopters)")?;
            // A level of the frame budget: its method and prefilter, on the
            // optics the run's ladder puts it on.
            let (common, method, prefilter) = match &s.level {
                Some(level) => {
                    let (c, m, p) = nedrt_run::level_system(&common, level)?;
                    (c, Some(m), p)
                }
                None => (common, s.method, s.prefilter),
            };
            // No --method: the shipped system, and every method beside it.
            let compare = method.is_none() && s.display_image.is_none();
            let opts = app::sim::SimOptions {
                accommodation_d,
                input: s.input,
                method: method.unwrap_or_else(|| app::sim::SimOptions::shipped_method(&common)),
                compare,
                out: s.out,
                display_image: s.display_image,
                optics: s.optics,
                display_out: s.display_out,
                prefilter,
                zones: s.zones.request()?,
            };
            println!("{}", app::sim::run(&common, &opts)?);
        }
        None => {
            bail!("nothing to do: give a command, e.g. `nedrt sim --accom 1.0` (see nedrt --help)")
        }
    }
    Ok(())
}

/// A list without repeats, first occurrences in order.
fn dedup<T: PartialEq>(items: Vec<T>) -> Vec<T> {
    let mut out = Vec::with_capacity(items.len());
    for i in items {
        if !out.contains(&i) {
            out.push(i);
        }
    }
    out
}
