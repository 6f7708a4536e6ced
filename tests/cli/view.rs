//! `nedrt view` and `nedrt sweep`: the picture's size and layout, each
//! panel equal to `nedrt sim`'s perceived image at that depth after the
//! 8-bit encoding, the sweep's frames, and (under Xvfb with a GPU adapter)
//! the window following key presses.

use super::*;

use image::AnimationDecoder;
use nedrt_app::viewer::compose::Layout;
use nedrt_app::viewer::scene::encode8;

/// A 32×32 input (64×64 on the retinal grid) in a scratch folder.
fn input(dir: &Path) -> PathBuf {
    let p = dir.join("in.png");
    write_png(&p, 32, 32);
    p
}

/// `nedrt sim`'s perceived image of `method` at `accom` on the small
/// aperture, 8-bit encoded (from its exact 32-bit float output), RGB.
fn simulated_rgb8(dir: &Path, input: &Path, method: &str, accom: &str) -> (usize, usize, Vec<u8>) {
    let out = dir.join(format!("sim-{method}-{accom}.tif"));
    let o = run(&[
        "--calib",
        path(&small_calib()),
        "--sim",
        "--accom",
        accom,
        "--method",
        method,
        "--input",
        path(input),
        "--out",
        path(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let im = image::open(&out).expect("sim tif").into_rgb32f();
    let (w, h) = im.dimensions();
    let rgb = im.pixels().flat_map(|p| p.0.map(encode8)).collect();
    (w as usize, h as usize, rgb)
}

/// `nedrt view --headless` on the small aperture: the picture it writes to
/// `out`, with `args` after the input's.
fn headless_picture(input: &Path, out: &Path, args: &[&str]) -> image::RgbImage {
    let o = run(&[
        &[
            "--calib",
            path(&small_calib()),
            "view",
            "--headless",
            "--input",
            path(input),
            "--screenshot",
            path(out),
        ][..],
        args,
    ]
    .concat());
    assert!(o.status.success(), "{}", stderr(&o));
    image::open(out).expect("the picture").into_rgb8()
}

/// The `w`×`h` block at (`x`, `y`) of an RGB picture `width` wide.
fn block(rgb: &[u8], width: usize, (x, y): (usize, usize), w: usize, h: usize) -> Vec<u8> {
    (y..y + h)
        .flat_map(|row| rgb[3 * (row * width + x)..3 * (row * width + x + w)].to_vec())
        .collect()
}

/// The viewer and `nedrt sim` prepare different sets of PSFs (a grid of
/// depths against one), and a request's PSFs share one window and sampling
/// plan, the light outside the window a uniform veil (docs/viewer.md): the
/// two perceived images differ by ~1e-4 in intensity, which moves a value
/// across an 8-bit rounding boundary at about 1 % of the codes (measured:
/// 128 of 12 288). One code at most, at no more than 2 % of them.
fn assert_same_codes(shown: &[u8], simulated: &[u8], what: &str) {
    assert_eq!(shown.len(), simulated.len(), "{what}: sizes");
    let worst = shown
        .iter()
        .zip(simulated)
        .map(|(a, b)| a.abs_diff(*b))
        .max()
        .unwrap_or(0);
    let differ = shown.iter().zip(simulated).filter(|(a, b)| a != b).count();
    assert!(
        worst <= 1 && differ * 50 <= shown.len(),
        "{what}: {differ} of {} codes differ, by up to {worst}",
        shown.len()
    );
}

#[test]
fn a_sweep_has_a_frame_per_depth_each_panel_the_simulators_image() {
    let dir = tempfile::tempdir().expect("tempdir");
    let input = input(dir.path());
    let out = dir.path().join("sweep.png");
    let o = run(&[
        "--calib",
        path(&small_calib()),
        "sweep",
        "--input",
        path(&input),
        "--methods",
        "conventional,ai",
        "--from",
        "0.5",
        "--to",
        "1.5",
        "--step",
        "0.5",
        "--out",
        path(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("3 frames"), "{}", stdout(&o));
    let file = std::io::BufReader::new(std::fs::File::open(&out).expect("sweep"));
    let frames = image::codecs::png::PngDecoder::new(file)
        .expect("png")
        .apng()
        .expect("animated")
        .into_frames()
        .collect_frames()
        .expect("frames");
    let layout = Layout::new(2, 64, 64, false);
    assert_eq!(frames.len(), 3, "0.5, 1.0 and 1.5 D");
    let rgb: Vec<Vec<u8>> = frames
        .iter()
        .map(|f| {
            assert_eq!(
                f.buffer().dimensions(),
                (layout.width as u32, layout.height as u32)
            );
            f.buffer()
                .pixels()
                .flat_map(|p| [p[0], p[1], p[2]])
                .collect()
        })
        .collect();
    // Frame 0 is 0.5 D, a main depth; frame 2 is 1.5 D.
    for (frame, accom) in [(0, "0.5"), (2, "1.5")] {
        for (column, method) in ["conventional", "ai"].iter().enumerate() {
            let (w, h, want) = simulated_rgb8(dir.path(), &input, method, accom);
            assert_eq!((w, h), (64, 64));
            let shown = block(&rgb[frame], layout.width, layout.image_origin(column), w, h);
            assert_same_codes(&shown, &want, &format!("{method} at {accom} D"));
        }
    }
    // The sweep's frame at 1.0 D is the viewer's picture there, bit for bit
    // (the same PSFs, from one cached request on the viewer's grid).
    let view = headless_picture(
        &input,
        &dir.path().join("view.png"),
        &["--methods", "conventional,ai", "--accom", "1.0"],
    );
    assert!(
        view.as_raw() == &rgb[1],
        "the headless view at 1.0 D is the sweep's frame"
    );
    // The labels follow the depth.
    let (lx, ly, lw, lh) = layout.label_area(0);
    assert_ne!(
        block(&rgb[0], layout.width, (lx, ly), lw, lh),
        block(&rgb[1], layout.width, (lx, ly), lw, lh),
        "the labels of 0.5 D and 1.0 D differ"
    );
}

#[test]
fn the_headless_view_shows_the_sharp_input_and_the_perceived_image() {
    let dir = tempfile::tempdir().expect("tempdir");
    let input = input(dir.path());
    let layout = Layout::new(1, 64, 64, false);
    let shot = |show: &str| {
        let im = headless_picture(
            &input,
            &dir.path().join(format!("{show}.png")),
            &[
                "--methods",
                "conventional",
                "--step",
                "0.5",
                "--accom",
                "2.5",
                "--show",
                show,
            ],
        );
        assert_eq!(im.dimensions(), (layout.width as u32, layout.height as u32));
        block(im.as_raw(), layout.width, layout.image_origin(0), 64, 64)
    };
    // The sharp image is the input on the retinal grid, each pixel 2×2.
    let source = image::open(&input).expect("input").into_rgb8();
    let up2: Vec<u8> = (0..64u32)
        .flat_map(|y| (0..64u32).map(move |x| (x, y)))
        .flat_map(|(x, y)| source.get_pixel(x / 2, y / 2).0)
        .collect();
    assert_eq!(shot("sharp"), up2);
    let (_, _, want) = simulated_rgb8(dir.path(), &input, "conventional", "2.5");
    assert_same_codes(&shot("perceived"), &want, "conventional at 2.5 D");
}

#[test]
fn eval_writes_a_sweep_per_image_over_zero_to_three_diopters() {
    let dir = tempfile::tempdir().expect("tempdir");
    let images = dir.path().join("images");
    std::fs::create_dir(&images).expect("images");
    write_png(&images.join("a.png"), 32, 32);
    let sweeps = dir.path().join("sweeps");
    let o = run(&[
        "--calib",
        path(&small_calib()),
        "eval",
        "--images",
        path(&images),
        "--out-dir",
        path(&dir.path().join("eval")),
        "--methods",
        "conventional",
        "--sweeps",
        path(&sweeps),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let file = std::io::BufReader::new(std::fs::File::open(sweeps.join("a.png")).expect("sweep"));
    let frames = image::codecs::png::PngDecoder::new(file)
        .expect("png")
        .apng()
        .expect("animated")
        .into_frames()
        .collect_frames()
        .expect("frames");
    assert_eq!(frames.len(), 31, "0–3 D in 0.1 D steps");
    let layout = Layout::new(1, 64, 64, false);
    assert_eq!(
        frames[0].buffer().dimensions(),
        (layout.width as u32, layout.height as u32)
    );
}

#[test]
fn without_a_display_the_viewer_says_to_use_headless() {
    let dir = tempfile::tempdir().expect("tempdir");
    let input = input(dir.path());
    let o = nedrt()
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .args([
            "--calib",
            path(&small_calib()),
            "view",
            "--input",
            path(&input),
            "--methods",
            "conventional",
            "--step",
            "0.5",
        ])
        .output_within(deadline::COMMAND, "nedrt view");
    assert_clean_error(&o, "--headless");
    assert!(stderr(&o).contains("no display"), "{}", stderr(&o));
}

mod needs_gpu_and_window {
    use super::*;
    use std::time::{Duration, Instant};

    use super::super::xwd::screenshot;

    /// Waits until the viewer's window shows `want` in `column` (within the
    /// PSF-window tolerance) and returns the screenshot.
    fn wait_for(layout: &Layout, column: usize, want: &[u8], what: &str) -> Vec<u8> {
        let start = Instant::now();
        loop {
            let last = match screenshot("nedrt view") {
                Ok((w, h, rgb)) if (w, h) == (layout.width, layout.height) => {
                    let shown = block(&rgb, w, layout.image_origin(column), 64, 64);
                    let close = shown.iter().zip(want).all(|(a, b)| a.abs_diff(*b) <= 1);
                    if close {
                        assert_same_codes(&shown, want, what);
                        return rgb;
                    }
                    format!("{w}×{h}, column {column} not yet {what}")
                }
                Ok((w, h, _)) => format!(
                    "window {w}×{h}, expected {}×{}",
                    layout.width, layout.height
                ),
                Err(e) => e,
            };
            assert!(
                start.elapsed() < Duration::from_secs(120),
                "the window never showed {what}: {last}"
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// Key presses to the viewer as a user's (XTEST, to the focused
    /// window): `key --window` would send synthetic events, which winit
    /// ignores.
    fn keys(keys: &[&str]) {
        let xdotool = |args: &[&str]| {
            let o = Command::new("xdotool")
                .args(args)
                .output_within(deadline::TOOL, "xdotool");
            assert!(o.status.success(), "xdotool {args:?}: {}", stderr(&o));
            stdout(&o)
        };
        let found = xdotool(&["search", "--sync", "--name", "^nedrt view$"]);
        let window = found
            .lines()
            .next()
            .expect("the viewer's window")
            .trim()
            .to_string();
        xdotool(&["windowfocus", &window]);
        std::thread::sleep(Duration::from_millis(200));
        xdotool(&[&["key", "--delay", "50"][..], keys].concat());
    }

    #[test]
    #[ignore = "needs an X display and a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_viewer_follows_the_keys_and_shows_the_simulators_image() {
        assert!(
            std::env::var_os("DISPLAY").is_some(),
            "this test needs an X display and DISPLAY is not set (scripts/test.sh starts Xvfb)"
        );
        let dir = tempfile::tempdir().expect("tempdir");
        let input = input(dir.path());
        let at_half = simulated_rgb8(dir.path(), &input, "ai", "0.5").2;
        let at_one_and_half = simulated_rgb8(dir.path(), &input, "ai", "1.5").2;
        // Killed if an assertion fails first, so no window outlives the test.
        let mut child = nedrt()
            .args([
                "--calib",
                path(&small_calib()),
                "view",
                "--input",
                path(&input),
                "--methods",
                "conventional,ai",
                "--step",
                "0.5",
                "--accom",
                "0.5",
            ])
            .spawn_watched("nedrt view");
        let layout = Layout::new(2, 64, 64, true);
        let before = wait_for(&layout, 1, &at_half, "ai at 0.5 D");
        // Two steps of the 0.5 D grid: 1.5 D.
        keys(&["Right", "Right"]);
        let after = wait_for(&layout, 1, &at_one_and_half, "ai at 1.5 D");
        let (lx, ly, lw, lh) = layout.label_area(1);
        assert_ne!(
            block(&before, layout.width, (lx, ly), lw, lh),
            block(&after, layout.width, (lx, ly), lw, lh),
            "the labels changed with the accommodation"
        );
        keys(&["q"]);
        let status = child.exit_within(Duration::from_secs(20), "q to close the viewer");
        let out = child.output();
        assert!(status.success(), "{}", stderr(&out));
        assert!(stdout(&out).contains("pictures drawn"), "{}", stdout(&out));
    }
}

/// `nedrt view --levels` (issue 54): a level of the frame budget by its
/// report's name is a panel, labelled so, showing what `nedrt sim --level`
/// gives for it; a name that is no level is refused.
#[test]
fn the_viewer_shows_frame_budget_levels_by_name() {
    let dir = tempfile::tempdir().expect("tempdir");
    let input = input(dir.path());
    let layout = Layout::new(1, 64, 64, false);
    let im = headless_picture(
        &input,
        &dir.path().join("refine.png"),
        &["--levels", "refine:3", "--step", "0.5", "--accom", "1.5"],
    );
    let shown = block(im.as_raw(), layout.width, layout.image_origin(0), 64, 64);
    let out = dir.path().join("sim-refine.tif");
    let o = run(&[
        "--calib",
        path(&small_calib()),
        "--sim",
        "--accom",
        "1.5",
        "--level",
        "refine:3",
        "--input",
        path(&input),
        "--out",
        path(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let want: Vec<u8> = image::open(&out)
        .expect("sim tif")
        .into_rgb32f()
        .pixels()
        .flat_map(|p| p.0.map(encode8))
        .collect();
    assert_same_codes(&shown, &want, "refine:3 at 1.5 D");
    let o = run(&[
        "--calib",
        path(&small_calib()),
        "view",
        "--headless",
        "--levels",
        "wiener,refine:0",
    ]);
    assert_clean_error(&o, "--level refine:0: not a level of the frame budget");
}
