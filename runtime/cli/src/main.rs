//! `nedrt`: the binary. Parses the command line ([`args`]), reads the
//! environment once ([`settings`]), supplies the terminal's progress
//! ([`console`]) and hands typed options to nedrt-run and nedrt-app
//! ([`commands`]); errors are printed on one line with a non-zero exit.

mod args;
mod bench_args;
mod calib_args;
mod commands;
mod console;
mod eye_args;
mod settings;
mod study_args;
mod view_args;

use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;

use args::{Cli, Command};

/// Logging to stderr, and with `trace` a Chrome/Perfetto trace of every
/// span; the returned guard writes the trace when dropped.
fn init_logging(
    verbose: u8,
    trace: Option<&std::path::Path>,
) -> Result<Option<tracing_chrome::FlushGuard>> {
    use tracing_subscriber::prelude::*;
    let default = match verbose {
        0 => "nedrt=info",
        1 => "nedrt=debug",
        _ => "nedrt=trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_env("NEDRT_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let fmt = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_target(false)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .without_time();
    let (chrome, guard) = match trace {
        Some(path) => {
            let file = std::fs::File::create(path)
                .with_context(|| format!("{}: cannot create the trace file", path.display()))?;
            let (layer, guard) = tracing_chrome::ChromeLayerBuilder::new()
                .writer(file)
                .include_args(true)
                .build();
            (Some(layer), Some(guard))
        }
        None => (None, None),
    };
    tracing_subscriber::registry()
        .with(filter)
        .with(fmt)
        .with(chrome)
        .init();
    Ok(guard)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let trace = match &cli.command {
        Some(Command::Run(a)) => a.trace.clone(),
        _ => None,
    };
    // `run` stops cleanly on a signal ([`install_signals`]); every other
    // command stops at once, leaving no output half-written.
    if !matches!(cli.command, Some(Command::Run(_)))
        && let Err(e) = exit_cleanly_on_signals()
    {
        eprintln!("error: cannot install the signal handler: {e}");
        return ExitCode::FAILURE;
    }
    let guard = match init_logging(cli.global.verbose, trace.as_deref()) {
        Ok(g) => g,
        Err(e) => {
            eprintln!("error: {e:#}");
            return ExitCode::FAILURE;
        }
    };
    let result = commands::run(cli);
    drop(guard);
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_line(&e));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line, leaving out a cause whose text an
/// outer message already quotes (library errors name their source in
/// their own message).
fn error_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string().replace('\n', " ");
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line += ": ";
        }
        line += &text;
    }
    if let Some(h) = hint(e) {
        line += "; ";
        line += h;
    }
    line
}

/// What to do instead, in the command line's words (the libraries' errors
/// name no flag).
fn hint(e: &anyhow::Error) -> Option<&'static str> {
    use nedrt_gpu::GpuError;
    use nedrt_infer::InferenceError;
    e.chain().find_map(|cause| {
        // A transparent AppError is its inner error, not a link before it.
        let inference = cause
            .downcast_ref::<InferenceError>()
            .or(match cause.downcast_ref::<nedrt_app::AppError>() {
                Some(nedrt_app::AppError::Inference(i)) => Some(i),
                _ => None,
            });
        if let Some(inference) = inference {
            match inference {
                InferenceError::FrameTooLarge(_) => {
                    return Some("try --precision f16 or a smaller frame");
                }
                InferenceError::ProviderMissing { .. } => return Some("or use --ort-provider cpu"),
                _ => {}
            }
        }
        let gpu = cause
            .downcast_ref::<GpuError>()
            .or(match cause.downcast_ref::<nedrt_app::AppError>() {
                Some(nedrt_app::AppError::Gpu(g)) => Some(g),
                _ => None,
            })?;
        match gpu {
            GpuError::NoAdapter(_) => Some(
                "--backend cpu runs the D-CNN on the CPU, and `nedrt run --sink record` needs no GPU",
            ),
            GpuError::NoShaderF16 { .. } => Some("use --precision f32"),
            GpuError::OutOfMemory(_) => {
                Some("a smaller panel or frame, or --backend cpu, needs less GPU memory")
            }
            GpuError::RequestDevice(_)
            | GpuError::DeviceLost(_)
            | GpuError::Validation(_)
            | GpuError::Map(_)
            | GpuError::Buffers(_)
            | GpuError::Fft(_)
            | GpuError::Stage(_) => None,
        }
    })
}

/// SIGINT and SIGTERM end a command at once: the temporaries of unfinished
/// atomic writes are removed first, so every output file is either whole
/// (written before) or absent. Exit status 128 + the signal, as the shell's.
fn exit_cleanly_on_signals() -> std::io::Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM])?;
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            if let Some(sig) = signals.forever().next() {
                eprintln!("error: stopped by signal {sig}; no output was left half-written");
                nedrt_core::util::exit_removing_temp_files(128 + sig);
            }
        })?;
    Ok(())
}

/// Signals that arrive within this of the first stop signal are the same
/// request (`timeout` signals the child and then its process group, so
/// nedrt gets SIGTERM twice within microseconds): only a later one exits
/// at once.
const SIGNAL_COALESCE: std::time::Duration = std::time::Duration::from_secs(1);

/// Ctrl-C and SIGTERM stop the service cleanly, with its report; a second
/// one more than [`SIGNAL_COALESCE`] later exits at once (status 130).
/// SIGUSR1 prints the latency table. Handled on a thread of their own.
pub(crate) fn install_signals(control: &nedrt_service::pipeline::service::Control) -> Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM, SIGUSR1};
    use std::sync::atomic::Ordering;
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGUSR1])?;
    let (stop, report) = (control.stop.clone(), control.report.clone());
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            let mut first_stop: Option<std::time::Instant> = None;
            for sig in signals.forever() {
                if sig == SIGUSR1 {
                    report.store(true, Ordering::Relaxed);
                    continue;
                }
                match first_stop {
                    None => {
                        first_stop = Some(std::time::Instant::now());
                        stop.store(true, Ordering::Relaxed);
                    }
                    Some(t) if t.elapsed() > SIGNAL_COALESCE => {
                        eprintln!("second stop signal: exiting at once, without the report");
                        nedrt_core::util::exit_removing_temp_files(130);
                    }
                    Some(_) => {}
                }
            }
        })?;
    Ok(())
}
