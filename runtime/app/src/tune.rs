//! `nedrt tune-wiener`: the Wiener constant K of a method, chosen on a grid
//! of quarter decades to maximise the mean PSNR against the sharp image over
//! 0–2.5 D on the training images (docs/model.md §13), and optionally written back
//! into the calibration file with its comments kept.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::images::{list_images, load_all};
use super::{AppError, CommonOptions, write_text};
use nedrt_core::calib::DEFAULT_CALIBRATION_NAME;
use nedrt_optics::sim::HEADLINE_MAX_D;
use nedrt_optics::sim::metrics::psnr;
use nedrt_optics::sim::simulator::PerceivePlan;
use nedrt_optics::sim::{Method, Simulator};

/// K grid: 10^(−6) … 10^0 in quarter decades.
pub fn k_grid() -> Vec<f64> {
    (0..=24)
        .map(|i| 10f64.powf(-6.0 + i as f64 / 4.0))
        .collect()
}

pub fn run(
    common: &CommonOptions,
    images_dir: &Path,
    method: Method,
    write: bool,
) -> Result<String, AppError> {
    if !method.uses_wiener() {
        return Err(AppError::option(
            format!("--method {method}"),
            "only ai and doe+wiener use a Wiener constant",
        ));
    }
    let files = list_images(images_dir)?;
    let images = load_all(&files, common.panel_px()?)?;
    let sim = common.measured(Simulator::new(
        common.calibration()?,
        common.doe_path(),
        common.cache(),
    )?)?;
    let depths: Vec<f64> = sim
        .calib
        .evaluation_depths_d()
        .into_iter()
        .filter(|d| *d <= HEADLINE_MAX_D + 1e-9)
        .collect();
    let prepared = sim.prepare(&[method], &depths, common.progress())?;
    let base = prepared
        .wiener(method)
        .ok_or_else(|| AppError::Unavailable("no Wiener filter prepared".into()))?;
    let psfs: Vec<_> = depths
        .iter()
        .map(|d| prepared.system_psfs(method, *d))
        .collect::<Result<_, _>>()?;
    let sharps: Vec<_> = images.iter().map(|im| im.up2()).collect();
    // Only the display image changes with K: transform the kernels once.
    let plans: Vec<Vec<PerceivePlan>> = images
        .iter()
        .map(|im| {
            psfs.iter()
                .map(|p| PerceivePlan::new(p, im.width, im.height))
                .collect()
        })
        .collect();

    let grid = k_grid();
    let bar = common.phase("K");
    bar.set_length(grid.len() as u64);
    let mut table = Vec::new();
    for &k in &grid {
        let filter = base.with_k(k);
        let mut total = 0.0;
        for ((im, sharp), plans) in images.iter().zip(&sharps).zip(&plans) {
            let display = filter.apply(im);
            for plan in plans {
                total += psnr(&plan.apply(&display), sharp);
            }
        }
        table.push((k, total / (images.len() * psfs.len()) as f64));
        bar.inc(1);
    }
    bar.finish_and_clear();
    let (best_k, best) =
        table.iter().copied().fold(
            (f64::NAN, f64::NEG_INFINITY),
            |a, b| if b.1 > a.1 { b } else { a },
        );
    let mut t = format!(
        "Wiener K for {method} on {} training images ({}), depths {:?} D, {}\n",
        images.len(),
        images_dir.display(),
        depths,
        sim.calib.source
    );
    for (k, p) in &table {
        let _ = writeln!(
            t,
            "  K = {k:9.3e}  mean PSNR vs sharp {p:7.3} dB{}",
            if *k == best_k { "  <- best" } else { "" }
        );
    }
    let _ = writeln!(t, "best K = {best_k:.4e} ({best:.3} dB)");
    if table.first().is_some_and(|f| f.0 == best_k) || table.last().is_some_and(|l| l.0 == best_k) {
        tracing::warn!(
            "the best K lies at the end of the search grid; the optimum may lie beyond it"
        );
    }
    if write {
        let path = common
            .calib
            .clone()
            .unwrap_or_else(|| PathBuf::from(DEFAULT_CALIBRATION_NAME));
        let doe_hash = (method == Method::DoeWiener).then_some(sim.doe_hash.as_str());
        write_k(&path, method, best_k, doe_hash)?;
        let _ = writeln!(
            t,
            "wrote K into {} (rebuild to embed a changed default)",
            path.display()
        );
    }
    Ok(t)
}

/// Sets `wiener.ai_k` or `wiener.doe_k` (and `doe_k_tuned_for`) in a
/// calibration file, keeping its comments and layout; checks the result
/// still parses before replacing the file.
pub fn write_k(
    path: &Path,
    method: Method,
    k: f64,
    doe_hash: Option<&str>,
) -> Result<(), AppError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| AppError::output(path, format!("cannot read: {e}")))?;
    let mut doc: toml_edit::DocumentMut = text
        .parse()
        .map_err(|e| AppError::output(path, format!("malformed TOML: {e}")))?;
    let rounded: f64 = format!("{k:.4e}").parse().unwrap_or(k);
    let wiener = doc
        .get_mut("wiener")
        .and_then(|w| w.as_table_mut())
        .ok_or_else(|| AppError::output(path, "no [wiener] table"))?;
    let key = if method == Method::Ai {
        "ai_k"
    } else {
        "doe_k"
    };
    let decor = wiener
        .get(key)
        .and_then(|v| v.as_value())
        .map(|v| v.decor().clone());
    let mut value = toml_edit::Value::from(rounded);
    if let Some(d) = decor {
        *value.decor_mut() = d;
    }
    wiener[key] = toml_edit::Item::Value(value);
    if let Some(h) = doe_hash {
        wiener["doe_k_tuned_for"] = toml_edit::value(h);
    }
    let out = doc.to_string();
    nedrt_core::calib::Calibration::from_toml(&out, &path.display().to_string(), path.parent())?;
    write_text(path, &out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_is_quarter_decades() {
        let g = k_grid();
        assert_eq!(g.len(), 25);
        assert!((g[4] / g[0] - 10.0).abs() < 1e-9);
    }

    #[test]
    fn write_k_keeps_comments_and_validates() {
        let dir = tempfile::tempdir().expect("tmp");
        let p = dir.path().join("c.toml");
        std::fs::write(&p, nedrt_core::calib::DEFAULT_CALIBRATION_TOML).expect("write");
        write_k(&p, Method::DoeWiener, 0.0031622, Some("abc123")).expect("write k");
        let text = std::fs::read_to_string(&p).expect("read");
        assert!(text.contains("# Wiener regularisation K"), "comments kept");
        let c = nedrt_core::calib::Calibration::load(&p).expect("valid");
        assert!((c.wiener.doe_k - 3.1622e-3).abs() < 1e-9);
        assert_eq!(c.wiener.doe_k_tuned_for, "abc123");
        let default = nedrt_core::calib::Calibration::default_embedded().expect("default");
        assert!(
            (c.wiener.ai_k - default.wiener.ai_k).abs() < 1e-12,
            "other K untouched"
        );
    }
}
