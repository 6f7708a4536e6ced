//! nedrt-studies, layer 5 of nedrt: the studies and their reports — the
//! evaluation (`eval`, with the eyes and the focus cues), speed against
//! accuracy (`tradeoff`, with the simulator's fidelity), where each method
//! breaks (`stability`), the paper's figures (`plots`) and the benchmarks —
//! each a library function with typed options and a printable report,
//! built on the commands: `nedrt run` (nedrt-run) and the others
//! (nedrt-app), with the options and error every command shares
//! (nedrt-command) and the engines' preprocessing registry.
//!
//! Rule: above nedrt-run and nedrt-app, below the binary; no clap, no
//! indicatif, no environment, as every library crate.

pub mod bench;
pub mod bench_fft;
pub mod bench_inference;
pub mod bench_layers;
pub mod bench_pipeline;
pub mod bench_tune;
pub mod bench_tune_fft;
pub mod eval;
pub mod focus_cues;
pub mod plots;
pub mod stability;
pub mod tradeoff;

// The wiring the studies are built on, under the names they use.
pub(crate) use nedrt_app::{
    AppError, CommonOptions, charts, check_output_folder, create_dir, design, gpu_for, sim, viewer,
    write_text,
};
pub(crate) use nedrt_run as run;
pub(crate) use nedrt_stages::{device_prefilter, preprocess};
