//! The study's outputs: the table written as Markdown, JSON and chart.
//! Apart from the measuring in the parent so that the study's formats
//! read on their own.

use std::fmt::Write as _;
use std::path::Path;

use super::{Record, Table, chart};
use crate::{AppError, write_text};

/// Writes the Markdown, JSON and chart of a table; returns the Markdown.
pub fn write_table(table: &Table, out_dir: &Path) -> Result<String, AppError> {
    let md = markdown(table);
    let json_path = out_dir.join("tradeoff.json");
    let json = serde_json::to_string_pretty(table).map_err(|e| AppError::output(&json_path, e))?;
    write_text(&json_path, &json)?;
    write_text(&out_dir.join("tradeoff.md"), &md)?;
    let written = chart::write(table, &out_dir.join("tradeoff"))?;
    Ok(format!(
        "{md}\nwrote {}, {} and {}\n",
        json_path.display(),
        out_dir.join("tradeoff.md").display(),
        written.join(", ")
    ))
}

/// The table in Markdown, fastest first.
pub fn markdown(t: &Table) -> String {
    let mut s = format!(
        "# Speed against accuracy\n\nLatency per {}×{} frame on {}; quality over 0–2.5 D against the sharp image on {} ({}).\n\
         ★ = on the Pareto front (no configuration is both faster and better).\n\n\
         | configuration | device | latency ms | mean PSNR dB | worst PSNR dB | mean SSIM | front |\n| --- | --- | --- | --- | --- | --- | --- |\n",
        t.frame_width,
        t.frame_height,
        t.host,
        t.images.join(", "),
        t.calibration
    );
    let mut order: Vec<&Record> = t.records.iter().collect();
    order.sort_by(|a, b| {
        let key = |r: &Record| r.point.latency_ms.or(r.estimated_ms).unwrap_or(f64::MAX);
        key(a).total_cmp(&key(b))
    });
    for r in order {
        let p = &r.point;
        let latency = match (p.latency_ms, r.estimated_ms) {
            (Some(ms), _) => format!("{ms:.2}"),
            (None, Some(e)) => format!("not measured (≈ {e:.0})"),
            (None, None) => "–".into(),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {latency} | {:.2} | {:.2} | {:.3} | {} |",
            p.name,
            r.device,
            p.mean_psnr_db,
            p.worst_psnr_db,
            p.mean_ssim,
            if r.on_front { "★" } else { "" }
        );
    }
    let mut hashes: Vec<String> = t
        .records
        .iter()
        .filter_map(|r| {
            r.model
                .as_ref()
                .zip(r.model_hash.as_ref())
                .map(|(m, h)| format!("{m} ({h})"))
        })
        .collect();
    hashes.sort();
    hashes.dedup();
    let mut does: Vec<&String> = t
        .records
        .iter()
        .filter_map(|r| r.doe_hash.as_ref())
        .collect();
    does.sort();
    does.dedup();
    let _ = writeln!(
        s,
        "\nD-CNN: {}. DOE: {}.",
        if hashes.is_empty() {
            "none".into()
        } else {
            hashes.join(", ")
        },
        does.iter()
            .map(|d| d.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    );
    for k in &t.skipped {
        let _ = writeln!(s, "- not run here: {k}");
    }
    s
}
