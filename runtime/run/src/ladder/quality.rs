//! The tradeoff table's rows a ladder reads: each level's quality (and
//! the time the table measured), matched by the DOE's and the model's
//! content hash and the run's design. The table is nedrt-studies'
//! `Table`, above this crate: only these fields are read here.

use std::path::{Path, PathBuf};

use super::{DEFAULT_QUALITY_TABLE, Rung, doe_hash};
use crate::{AppError, CommonOptions};
use nedrt_optics::sim::Method;
use nedrt_stages::preprocess::Prefilter;

/// The rows of a tradeoff table a ladder reads.
#[derive(Debug, Clone, Default)]
pub struct QualityTable {
    pub source: Option<PathBuf>,
    pub(in crate::ladder) rows: Vec<QualityRow>,
}

#[derive(Debug, Clone)]
pub(in crate::ladder) struct QualityRow {
    pub(in crate::ladder) name: String,
    pub(in crate::ladder) method: String,
    pub(in crate::ladder) doe_hash: Option<String>,
    pub(in crate::ladder) model_hash: Option<String>,
    pub(in crate::ladder) mean_psnr_db: f64,
    /// None where the table only estimated it.
    pub(in crate::ladder) latency_ms: Option<f64>,
    pub(in crate::ladder) device: Option<String>,
    pub(in crate::ladder) size: String,
}

impl QualityTable {
    /// The table at `path`, or the default one where it exists (none: no
    /// quality known, the levels kept in their order). A table given and
    /// unreadable is an error naming it.
    pub fn load(path: Option<&Path>) -> Result<Self, AppError> {
        let (path, given) = match path {
            Some(p) => (p.to_path_buf(), true),
            None => (PathBuf::from(DEFAULT_QUALITY_TABLE), false),
        };
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if !given && e.kind() == std::io::ErrorKind::NotFound => {
                return Ok(Self::default());
            }
            Err(e) => {
                return Err(AppError::input(path.display(), format!("cannot read: {e}")));
            }
        };
        let bad = |why: String| AppError::input(path.display(), why);
        let json: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| bad(format!("not a table written by `nedrt tradeoff`: {e}")))?;
        let size = format!(
            "{}×{}",
            json["frame_width"].as_u64().unwrap_or(0),
            json["frame_height"].as_u64().unwrap_or(0)
        );
        let records = json["records"].as_array().ok_or_else(|| {
            bad("no \"records\" list: not a table written by `nedrt tradeoff`".into())
        })?;
        let mut rows = Vec::new();
        for (i, r) in records.iter().enumerate() {
            let text = |k: &str| r[k].as_str().map(str::to_string);
            let number = |k: &str| {
                r[k].as_f64()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| bad(format!("record {i}: {k:?} is not a finite number")))
            };
            rows.push(QualityRow {
                name: text("name").ok_or_else(|| bad(format!("record {i}: no \"name\"")))?,
                method: text("method").ok_or_else(|| bad(format!("record {i}: no \"method\"")))?,
                doe_hash: text("doe_hash"),
                model_hash: text("model_hash"),
                mean_psnr_db: number("mean_psnr_db")?,
                latency_ms: r["latency_ms"].as_f64().filter(|v| v.is_finite()),
                device: text("device"),
                size: size.clone(),
            });
        }
        Ok(Self {
            source: Some(path),
            rows,
        })
    }

    /// The first row measuring `rung` on the DOE `doe_hash` (the network's
    /// by its hash). A row's name is its method, its design, its
    /// prefilter and its backend, space-separated.
    pub(in crate::ladder) fn find(
        &self,
        rung: Rung,
        doe_hash: &str,
        design: Option<&str>,
        network: Option<&(String, String)>,
    ) -> Option<&QualityRow> {
        let prefilter_of = |row: &QualityRow| {
            row.name
                .split_whitespace()
                .find(|t| t.contains(':') || *t == "lsq" || t.starts_with("lsq@"))
                .map(str::to_string)
        };
        let same_doe = |row: &QualityRow| row.doe_hash.as_deref() == Some(doe_hash);
        // The design a row names (its second word, where that is not a
        // prefilter or a backend): a design's K may differ from the
        // calibration's on the same DOE.
        let design_of = |row: &QualityRow| {
            row.name
                .split_whitespace()
                .nth(1)
                .filter(|t| {
                    !(t.contains(':')
                        || t.starts_with("lsq")
                        || t.starts_with("optimal")
                        || ["cpu", "ort", "wgpu"].contains(t))
                })
                .map(str::to_string)
        };
        let matching = self.rows.iter().filter(|row| match rung {
            Rung::None => row.method == "doe-only" && same_doe(row),
            Rung::Wiener => {
                row.method == "doe+wiener" && same_doe(row) && prefilter_of(row).is_none()
            }
            Rung::Refine(_) | Rung::Admm(_) => {
                let full = rung.prefilter().to_string();
                let short = full
                    .strip_suffix(&format!("@{}", Prefilter::DEFAULT_OBJECTIVE.name()))
                    .unwrap_or(&full)
                    .to_string();
                row.method == "doe+wiener"
                    && same_doe(row)
                    && prefilter_of(row).is_some_and(|p| p == full || p == short)
            }
            Rung::Network(_) => {
                row.method == "proposed"
                    && network.is_some_and(|(_, hash)| row.model_hash.as_deref() == Some(hash))
            }
            // A fixed run's level is looked up by `fixed_quality`.
            Rung::Method => false,
        });
        let candidates: Vec<&QualityRow> = matching.collect();
        if matches!(rung, Rung::Network(_)) {
            return candidates.first().copied();
        }
        // The run's design's row first, then one of no design, then any.
        candidates
            .iter()
            .find(|r| design_of(r).as_deref() == design)
            .or_else(|| candidates.iter().find(|r| design_of(r).is_none()))
            .or(candidates.first())
            .copied()
    }
}

/// The quality the table gives a fixed configuration of `nedrt run`
/// (`--preprocess METHOD [--prefilter P]`): none, the Wiener, refine:K
/// and the network as the ladder's levels are matched, `conventional` by
/// its own row; `None` where the table has no row for it.
pub fn fixed_quality(
    common: &CommonOptions,
    method: Method,
    prefilter: Prefilter,
    table: &QualityTable,
) -> Result<Option<f64>, AppError> {
    let design = common.design.as_ref().map(|d| d.name.as_str());
    let doe = || -> Result<String, AppError> {
        let mut c = common.clone();
        c.doe = common
            .doe
            .clone()
            .or_else(|| common.doe_path_for(&[method]));
        doe_hash(&c)
    };
    let rung = match (method, prefilter) {
        (Method::Conventional, Prefilter::Native) => {
            return Ok(table
                .rows
                .iter()
                .find(|r| r.method == "conventional")
                .map(|r| r.mean_psnr_db));
        }
        (Method::DoeOnly, Prefilter::Native) => Rung::None,
        (Method::DoeWiener, Prefilter::Native) => Rung::Wiener,
        (Method::DoeWiener, Prefilter::Refine(k, Prefilter::DEFAULT_OBJECTIVE)) => Rung::Refine(k),
        (Method::DoeWiener, Prefilter::Admm(k, Prefilter::DEFAULT_OBJECTIVE)) => Rung::Admm(k),
        (Method::Proposed, Prefilter::Native) => {
            let path = &common.dcnn.path;
            if !path.exists() {
                return Ok(None);
            }
            let hash = match nedrt_stages::unrolled::is_manifest(path) {
                true => nedrt_stages::unrolled::Manifest::read(path)?.hash,
                false => nedrt_infer::ModelFile::read(path)?.hash,
            };
            let network = (String::new(), hash);
            return Ok(table
                .find(Rung::Network(0), "", None, Some(&network))
                .map(|r| r.mean_psnr_db));
        }
        _ => return Ok(None),
    };
    Ok(table
        .find(rung, &doe()?, design, None)
        .map(|r| r.mean_psnr_db))
}
