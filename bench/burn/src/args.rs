//! The harness's command line: which models, sizes and budget, and
//! whether one contender runs alone.

use std::path::PathBuf;

use anyhow::{Context, Result, bail, ensure};

pub(super) struct Args {
    pub(super) json: Option<PathBuf>,
    pub(super) sizes: Vec<usize>,
    pub(super) models: Vec<String>,
    /// Fixed timed iterations per model and size (else from `budget_s`).
    pub(super) iters: Option<usize>,
    /// Seconds of timed runs (both contenders) per model and size: iterations
    /// go on until it is spent (within `min_iters` and `max_iters`).
    pub(super) budget_s: f64,
    pub(super) min_iters: usize,
    pub(super) max_iters: usize,
    pub(super) warmup: usize,
    /// Runs one contender alone (an isolation check): no comparison.
    pub(super) only: Option<Contender>,
}

pub(super) const USAGE: &str = "usage: nedrt-bench-burn [--json PATH] [--sizes 64,256,512] \
[--models dcnn,dcnn_w32] [--iters N | --budget SECONDS] [--min-iters N] [--max-iters N] [--warmup N] \
[--only nedrt|burn]";

pub(super) fn parse_args() -> Result<Args> {
    let mut a = Args {
        json: None,
        sizes: vec![64, 256, 512],
        models: vec!["dcnn".into(), "dcnn_w32".into()],
        iters: None,
        budget_s: 30.0,
        min_iters: 4,
        max_iters: 100,
        warmup: 1,
        only: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        if flag == "-h" || flag == "--help" {
            println!("{USAGE}");
            std::process::exit(0);
        }
        let value = it
            .next()
            .with_context(|| format!("{flag} needs a value\n{USAGE}"))?;
        let count = |v: &str| -> Result<usize> {
            v.parse()
                .with_context(|| format!("{flag}: '{v}' is not a count"))
        };
        match flag.as_str() {
            "--json" => a.json = Some(value.into()),
            "--sizes" => {
                a.sizes = value
                    .split(',')
                    .map(|s| count(s.trim()))
                    .collect::<Result<_>>()?
            }
            "--models" => a.models = value.split(',').map(|s| s.trim().to_string()).collect(),
            "--iters" => a.iters = Some(count(&value)?.max(1)),
            "--budget" => {
                a.budget_s = value
                    .parse()
                    .with_context(|| format!("--budget: '{value}' is not a number"))?
            }
            "--min-iters" => a.min_iters = count(&value)?.max(1),
            "--max-iters" => a.max_iters = count(&value)?.max(1),
            "--warmup" => a.warmup = count(&value)?.max(1),
            "--only" => {
                a.only = Some(match value.as_str() {
                    "nedrt" => Contender::Nedrt,
                    "burn" => Contender::Burn,
                    other => bail!("--only: '{other}' is not nedrt or burn"),
                })
            }
            other => bail!("unknown flag {other}\n{USAGE}"),
        }
    }
    ensure!(!a.sizes.is_empty(), "--sizes is empty");
    Ok(a)
}

/// A contender under test: nedrt's kernels or burn's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Contender {
    Nedrt,
    Burn,
}

impl Contender {
    pub(super) fn name(self) -> &'static str {
        match self {
            Contender::Nedrt => "nedrt",
            Contender::Burn => "burn",
        }
    }
}
