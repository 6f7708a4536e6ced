//! The evaluation's Markdown: the tables of [`EvalResult`], per method and
//! depth, and the focus cues, from the typed rows alone.

use super::*;

/// The Fig. 6-style tables, one per reference.
pub fn markdown(r: &EvalResult, sim: &Simulator) -> String {
    let mut t = format!(
        "# Evaluation ({} image{}, {})\n\nImages: {}.  \nDOE: {} ({}).  \nPSNR dB / SSIM on the retinal grid; headline = over 0–{HEADLINE_MAX_D} D.\n",
        r.images.len(),
        if r.images.len() == 1 { "" } else { "s" },
        r.calibration,
        r.images.join(", "),
        sim.doe_hash,
        sim.doe.description
    );
    for (title, pick, head) in [
        ("vs sharp (paper Fig. 6 convention)", 0, 0),
        (
            "vs target (multifocal target, the training objective)",
            1,
            1,
        ),
    ] {
        let _ = write!(t, "\n## {title}\n\n| D |");
        for m in &r.methods {
            let _ = write!(t, " {} |", m.method);
        }
        let _ = write!(t, "\n| --- |{}\n", " --- |".repeat(r.methods.len()));
        let n_depths = r.methods.first().map_or(0, |m| m.rows.len());
        for di in (0..n_depths).rev() {
            let _ = write!(t, "| {:.1} |", r.methods[0].rows[di].accommodation_d);
            for m in &r.methods {
                let s = if pick == 0 {
                    m.rows[di].vs_sharp
                } else {
                    m.rows[di].vs_target
                };
                let _ = write!(t, " {:.2} / {:.3} |", s.psnr_db, s.ssim);
            }
            t.push('\n');
        }
        for (label, worst) in [("mean", false), ("worst", true)] {
            let _ = write!(t, "| {label} 0–{HEADLINE_MAX_D} |");
            for m in &r.methods {
                let h = if head == 0 {
                    &m.headline_vs_sharp
                } else {
                    &m.headline_vs_target
                };
                let s = if worst { h.worst } else { h.mean };
                let _ = write!(t, " **{:.2} / {:.3}** |", s.psnr_db, s.ssim);
            }
            t.push('\n');
        }
    }
    let cue_rows: Vec<(&str, &FocusCues)> = r
        .methods
        .iter()
        .filter_map(|m| m.focus_cues.as_ref().map(|c| (m.method.as_str(), c)))
        .collect();
    if !cue_rows.is_empty() {
        t.push_str(&focus_cues::markdown(&cue_rows));
    }
    for d in &r.dcnn {
        let _ = writeln!(t, "\nD-CNN {d}.");
    }
    if !r.not_evaluated.is_empty() {
        let _ = writeln!(
            t,
            "\nNot in this run (add with --methods): {}.",
            r.not_evaluated.join(", ")
        );
    }
    let _ = writeln!(t, "Wall time {:.1} s.", r.seconds);
    t
}
