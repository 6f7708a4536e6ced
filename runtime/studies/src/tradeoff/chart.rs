//! The speed-against-accuracy chart: one point per configuration, the
//! Pareto front, the device and the model hashes printed on it.

use std::path::Path;

use super::Table;
use crate::AppError;
use crate::charts::{ScatterFigure, ScatterPoint, write_scatter};

/// Writes `stem`.png and `stem`.svg for a table.
pub fn write(table: &Table, stem: &Path) -> Result<Vec<String>, AppError> {
    let points = table
        .records
        .iter()
        .filter_map(|r| {
            let (x, estimated) = match (r.point.latency_ms, r.estimated_ms) {
                (Some(ms), _) => (ms, false),
                (None, Some(e)) => (e, true),
                (None, None) => return None,
            };
            Some(ScatterPoint {
                label: r.point.name.clone(),
                x,
                y: r.point.mean_psnr_db,
                on_front: r.on_front,
                estimated,
            })
        })
        .collect();
    let mut models: Vec<String> = table
        .records
        .iter()
        .filter_map(|r| r.model.as_ref().zip(r.model_hash.as_ref()))
        .map(|(m, h)| format!("{m} {h}"))
        .collect();
    models.sort();
    models.dedup();
    let mut devices: Vec<&str> = table.records.iter().map(|r| r.device.as_str()).collect();
    devices.sort();
    devices.dedup();
    let mut footer = vec![format!("host: {}", table.host)];
    footer.extend(devices.iter().map(|d| format!("device: {d}")));
    footer.push(format!("D-CNN: {}", models.join("; ")));
    footer.push("hollow: latency estimated from the image runs, not measured".into());
    write_scatter(
        stem,
        (1100, 700 + 16 * footer.len() as u32),
        &ScatterFigure {
            title: format!(
                "Speed against accuracy, {}×{} frame",
                table.frame_width, table.frame_height
            ),
            footer,
            x_label: "latency per frame, ms (log)".into(),
            y_label: "mean PSNR vs sharp, 0–2.5 D (dB)".into(),
            points,
        },
    )
}
