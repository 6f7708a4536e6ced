//! `nedrt run --plan` (issue 39): what a run would build and why, printed
//! without starting anything, for the default run, two views, the host
//! frame path, a `[[view]]` calibration and a machine without an adapter.

use super::*;

/// `nedrt run --plan` on the small panel with `args`; its stdout.
fn plan(args: &[&str], envs: &[(&str, &str)]) -> String {
    let mut c = nedrt();
    c.current_dir(repo())
        .args(["run", "--plan", "--calib", path(&small_panel())])
        .args(args);
    for (k, v) in envs {
        c.env(k, v);
    }
    let o = c.output_within(deadline::COMMAND, "nedrt run --plan");
    assert!(o.status.success(), "{}", stderr(&o));
    stdout(&o)
}

fn line<'a>(text: &'a str, key: &str) -> &'a str {
    text.lines()
        .find(|l| l.starts_with(key))
        .unwrap_or_else(|| panic!("no {key:?} line in:\n{text}"))
}

#[test]
fn the_host_frame_path_says_why() {
    let text = plan(&["--frame-path", "host", "--sink", "record"], &[]);
    assert_eq!(
        line(&text, "frame path:"),
        "frame path: host, because --frame-path host"
    );
    assert_eq!(line(&text, "panel:"), "panel:      64×48 at 240 Hz, 1 view");
    assert_eq!(
        line(&text, "network:"),
        "network:    models/dcnn.onnx: wgpu on a GPU of its own, f32 (the CPU's tract, f32, if \
         none starts)"
    );
    assert!(
        line(&text, "view ").starts_with("view \"panel\" 64×48 at (0, 0): decode on the host"),
        "{text}"
    );
}

#[test]
fn a_missing_adapter_puts_frames_on_the_host_and_says_so() {
    let text = plan(
        &["--sink", "headless"],
        &[
            ("VK_ICD_FILENAMES", "/nonexistent"),
            ("WGPU_BACKEND", "vulkan"),
        ],
    );
    assert!(
        line(&text, "adapter:").starts_with("adapter:    none: "),
        "{text}"
    );
    assert!(
        line(&text, "frame path:").starts_with("frame path: host, because no GPU adapter ("),
        "{text}"
    );
}

#[test]
fn two_views_of_the_stereo_flag_are_the_panels_halves() {
    let text = plan(
        &[
            "--stereo",
            "--preprocess",
            "conventional",
            "--sink",
            "record",
        ],
        &[],
    );
    assert_eq!(
        line(&text, "panel:"),
        "panel:      64×48 at 240 Hz, 2 views"
    );
    assert_eq!(
        line(&text, "frame path:"),
        "frame path: host, because the record sink takes frames in host memory"
    );
    let views: Vec<&str> = text.lines().filter(|l| l.starts_with("view ")).collect();
    assert_eq!(views.len(), 2, "{text}");
    assert!(
        views[0].starts_with("view \"left\" 32×48 at (0, 0)"),
        "{text}"
    );
    assert!(
        views[1].starts_with("view \"right\" 32×48 at (32, 0)"),
        "{text}"
    );
}

#[test]
fn a_view_calibration_names_each_views_design() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = super::stereo::stereo_calibration(dir.path());
    let o = nedrt()
        .current_dir(repo())
        .args([
            "--calib",
            path(&calib),
            "run",
            "--plan",
            "--preprocess",
            "doe+wiener",
        ])
        .args(["--sink", "record"])
        .output_within(deadline::COMMAND, "nedrt run --plan");
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    let views: Vec<&str> = text.lines().filter(|l| l.starts_with("view ")).collect();
    assert_eq!(views.len(), 2, "{text}");
    assert!(views[0].contains("multifocal.toml"), "{text}");
    assert!(views[1].contains("allsharp.toml"), "{text}");
    assert!(
        views[0].contains("Wiener prefilter of doe+wiener"),
        "{text}"
    );
}

mod needs_gpu {
    use super::*;

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_default_run_keeps_frames_on_the_gpu() {
        let text = plan(&[], &[]);
        assert_eq!(
            line(&text, "frame path:"),
            "frame path: device, because the sink has a GPU and every stage runs there: one \
             upload, no read-back"
        );
        assert!(
            line(&text, "pacing:").starts_with("pacing:     paced by the display"),
            "{text}"
        );
        // The default is the frame budget, its ladder topped by the network.
        assert!(
            line(&text, "view ").contains("admm:10 < dcnn) on the GPU"),
            "{text}"
        );
        assert!(line(&text, "ladder:").contains("quality"), "{text}");
    }

    /// A fixed method still plans its own stage on the device.
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_shipped_system_fixed_keeps_its_network_on_the_gpu() {
        let text = plan(&["--preprocess", "proposed"], &[]);
        assert!(line(&text, "view ").contains("D-CNN on the GPU"), "{text}");
        assert!(!text.contains("ladder:"), "{text}");
    }
}

/// `--preprocess auto`, the default (issue 54): the ladder, each level
/// with its quality from the tradeoff table (the repository's, matched by
/// the network's DOE and model) or left out and why, and the budget.
#[test]
fn the_default_plan_prints_the_ladder_with_each_levels_quality_and_the_budget() {
    let text = plan(&["--sink", "record"], &[]);
    assert_eq!(
        text,
        plan(&["--preprocess", "auto", "--sink", "record"], &[])
    );
    assert!(
        line(&text, "ladder:").contains("docs/tradeoff/tradeoff.json"),
        "{text}"
    );
    for level in ["none", "wiener", "admm:1", "admm:3", "admm:10", "dcnn"] {
        let l = line(&text, &format!("  {level} "));
        assert!(l.contains(" dB, "), "{level}: {l}");
        assert!(l.contains("measured at start-up"), "{level}: {l}");
    }
    // 240 Hz: a refresh of 4.17 ms, a 32nd of it 0.13 ms.
    let budget = line(&text, "budget:");
    assert!(
        budget.contains("(4.17 ms)") && budget.contains("(0.13 ms)"),
        "{budget}"
    );
    assert!(
        line(&text, "view ").contains(
            "the frame budget's level (none < wiener < admm:1 < admm:3 < admm:10 < dcnn) \
             on the host"
        ),
        "{text}"
    );
}

#[test]
fn the_default_stereo_plan_runs_the_whole_ladder_in_each_eye() {
    let text = plan(&["--stereo", "--sink", "record"], &[]);
    assert!(line(&text, "ladder:").contains("quality"), "{text}");
    assert!(line(&text, "budget:").contains("(4.17 ms)"), "{text}");
    let views: Vec<&str> = text.lines().filter(|l| l.starts_with("view ")).collect();
    assert_eq!(views.len(), 2, "{text}");
    for v in views {
        assert!(
            v.contains(
                "the frame budget's level (none < wiener < admm:1 < admm:3 < admm:10 < \
                 dcnn) on the host"
            ),
            "{v}"
        );
    }
}

/// A prefilter asked for without a method runs on the shipped system's
/// optics, as before the frame budget was the default.
#[test]
fn a_prefilter_without_a_method_is_the_shipped_systems() {
    let text = plan(&["--prefilter", "refine:3", "--sink", "record"], &[]);
    assert!(!text.contains("ladder:"), "{text}");
    assert!(
        line(&text, "view ").contains("refine:3@target prefilter of proposed"),
        "{text}"
    );
}

#[test]
fn auto_with_bounds_and_two_views_runs_the_same_levels_in_each_eye() {
    let text = plan(
        &[
            "--stereo",
            "--preprocess",
            "auto:wiener..admm:10",
            "--sink",
            "record",
        ],
        &[],
    );
    let views: Vec<&str> = text.lines().filter(|l| l.starts_with("view ")).collect();
    assert_eq!(views.len(), 2, "{text}");
    for v in views {
        assert!(
            v.contains("the frame budget's level (wiener < admm:1 < admm:3 < admm:10)"),
            "{v}"
        );
    }
    assert!(!text.contains("  none "), "{text}");
    assert!(!text.contains("  dcnn "), "{text}");
}

#[test]
fn auto_refuses_a_bound_that_names_no_level() {
    let o = nedrt()
        .current_dir(repo())
        .args(["run", "--plan", "--calib", path(&small_panel())])
        .args(["--preprocess", "auto:refine:7..", "--sink", "record"])
        .output_within(deadline::COMMAND, "nedrt run --plan");
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("--preprocess auto:refine:7.."), "{e}");
    assert!(e.contains("no level \"refine:7\""), "{e}");
    assert!(e.contains("admm:10"), "{e}");
    let o = nedrt()
        .current_dir(repo())
        .args(["run", "--plan", "--calib", path(&small_panel())])
        .args([
            "--preprocess",
            "auto",
            "--prefilter",
            "refine:3",
            "--sink",
            "record",
        ])
        .output_within(deadline::COMMAND, "nedrt run --plan");
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("the frame budget picks the prefilter"),
        "{}",
        stderr(&o)
    );
    let o = nedrt()
        .args(["run", "--plan", "--preprocess", "automatic"])
        .output_within(deadline::COMMAND, "nedrt run --plan");
    assert!(!o.status.success());
    assert!(stderr(&o).contains("auto:LO..HI"), "{}", stderr(&o));
}
