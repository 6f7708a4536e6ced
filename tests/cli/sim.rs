//! `nedrt sim`: the README command, bad inputs, calibrations, designs.

use super::*;

#[test]
fn readme_main_command_runs_on_shipped_defaults() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("perceived.png");
    // From the repository root, as the README runs it (models/ is there).
    let readme = || {
        // Its own cache: the shared one's bound may evict an entry
        // between the two runs.
        nedrt()
            .current_dir(repo())
            .env("NEDRT_CACHE_DIR", dir.path().join("cache"))
            .args(["--sim", "--accom", "1.0", "--out", path(&out)])
            .output_within(deadline::COMMAND, "nedrt")
    };
    let o = readme();
    assert!(o.status.success(), "{}", stderr(&o));
    let s = stdout(&o);
    // The shipped system, and every method beside it, the best marked.
    assert!(s.contains("nedrt sim: method proposed at 1 D"), "{s}");
    for method in [
        "conventional",
        "ai",
        "doe-only",
        "doe+wiener",
        "proposed (shown)",
    ] {
        assert!(
            s.contains(&format!("\n| {method} | ")),
            "no {method} row in:\n{s}"
        );
    }
    assert_eq!(s.matches(" ◀ |").count(), 2, "one best a column:\n{s}");
    assert!(
        s.contains("| lens+dcnn (no models/dcnn-lens.onnx) | – | – |"),
        "{s}"
    );
    for needle in [
        "vs sharp",
        "vs target",
        "pupil step",
        "window",
        "veil",
        "integrated",
        "time",
    ] {
        assert!(s.contains(needle), "missing {needle:?} in:\n{s}");
    }
    let img = image::open(&out).expect("perceived image");
    assert_eq!(
        (img.width(), img.height()),
        (1024, 1024),
        "retinal grid is 2× the display"
    );
    // Second run: PSFs come from the cache.
    let o = readme();
    assert!(stdout(&o).contains("from cache"), "{}", stdout(&o));
}

#[test]
fn bad_images_are_clear_errors() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("p.png");
    let o = sim("1", &out, &["--input", "/no/such.png"]);
    assert_clean_error(&o, "/no/such.png: cannot read image");
    let junk = dir.path().join("junk.png");
    std::fs::write(&junk, b"this is not an image").expect("write");
    let o = sim("1", &out, &["--input", path(&junk)]);
    assert_clean_error(&o, "cannot decode image");
    let nan = dir.path().join("nan.tif");
    let mut im = image::Rgb32FImage::from_pixel(16, 16, image::Rgb([0.5, 0.5, 0.5]));
    im.put_pixel(3, 4, image::Rgb([f32::NAN, 0.5, 0.5]));
    image::DynamicImage::ImageRgb32F(im)
        .save(&nan)
        .expect("tiff");
    let o = sim("1", &out, &["--input", path(&nan)]);
    assert_clean_error(&o, "pixel 3,4 channel 0 is NaN");
    assert!(!out.exists(), "nothing written on failure");
}

#[test]
fn odd_gray_and_16_bit_images_are_converted_and_said_so() {
    let dir = tempfile::tempdir().expect("tmp");
    let odd = dir.path().join("odd.png");
    write_png(&odd, 37, 29);
    let out = dir.path().join("p.png");
    let o = sim("0.5", &out, &["--input", path(&odd)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = image::open(&out).expect("out");
    assert_eq!(
        (img.width(), img.height()),
        (74, 58),
        "cropped back to 2× the input"
    );

    let g16 = dir.path().join("g16.png");
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(24, 16, |x, _| {
        image::Luma([x as u16 * 2000])
    })
    .save(&g16)
    .expect("png16");
    let o = sim("0.5", &out, &["--input", path(&g16)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("grayscale image converted to RGB") && e.contains("16-bit image converted"),
        "{e}"
    );
}

#[test]
fn accommodation_is_checked() {
    let dir = tempfile::tempdir().expect("tmp");
    let input = dir.path().join("in.png");
    write_png(&input, 16, 16);
    let out = dir.path().join("p.png");
    let base = [
        "--sim",
        "--method",
        "conventional",
        "--input",
        path(&input),
        "--out",
        path(&out),
    ];
    let o = run(&[&base[..], &["--accom", "-0.5"]].concat());
    assert_clean_error(&o, "accommodation must be ≥ 0 D");
    for huge in ["1e308", "20.5"] {
        let o = run(&[&base[..], &["--accom", huge]].concat());
        assert_clean_error(&o, "beyond what an eye accommodates (at most 20 D");
    }
    let o = run(&[&base[..], &["--accom", "4"]].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("outside the calibrated range"),
        "{}",
        stderr(&o)
    );
    let o = run(&base);
    assert_clean_error(&o, "--sim needs --accom");
    let o = run(&[
        "--sim",
        "--input",
        path(&input),
        "--out",
        path(&out),
        "--accom",
        "1",
        "--method",
        "proposed",
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("D-CNN"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn malformed_calibration_and_doe_files_are_clear_errors() {
    let dir = tempfile::tempdir().expect("tmp");
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[panel\npixel_pitch_um = 8.7").expect("write");
    let o = run(&["--calib", path(&bad), "--sim", "--accom", "1"]);
    assert_clean_error(&o, "bad.toml: malformed TOML");
    let phys = dir.path().join("phys.toml");
    let text = std::fs::read_to_string(repo().join("calib/default.toml")).expect("calib");
    std::fs::write(
        &phys,
        text.replace("lens_distance_mm = 28.57", "lens_distance_mm = 31"),
    )
    .expect("write");
    let o = run(&["--calib", path(&phys), "--sim", "--accom", "1"]);
    assert_clean_error(&o, "no virtual image");

    let doe = dir.path().join("doe.safetensors");
    std::fs::write(&doe, b"\x08\x00\x00\x00\x00\x00\x00\x00{}      ").expect("write");
    let o = run(&[
        "--doe",
        path(&doe),
        "--sim",
        "--accom",
        "1",
        "--method",
        "doe-only",
    ]);
    assert_clean_error(&o, "invalid DOE file");
    // A valid file whose grid is too coarse for the aperture it is used with.
    let init = dir.path().join("init.safetensors");
    let o = run(&[
        "--calib",
        small_calib().to_str().expect("utf8"),
        "doe",
        "--write-init",
        path(&init),
        "--out-dir",
        path(dir.path()),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = run(&[
        "--doe",
        path(&init),
        "--sim",
        "--accom",
        "1",
        "--method",
        "doe-only",
    ]);
    assert_clean_error(&o, "does not cover");
}

#[test]
fn display_image_must_match_and_outputs_must_be_writable() {
    let dir = tempfile::tempdir().expect("tmp");
    let input = dir.path().join("in.png");
    let disp = dir.path().join("d.png");
    write_png(&input, 16, 16);
    write_png(&disp, 24, 16);
    let sim_on = |extra: &[&str]| {
        run(&[
            &["--sim", "--accom", "1", "--input", path(&input)][..],
            extra,
        ]
        .concat())
    };
    let o = sim_on(&["--display-image", path(&disp)]);
    assert_clean_error(&o, "must match");
    let o = sim_on(&["--out", "/no/such/dir/p.png"]);
    assert_clean_error(&o, "cannot write image");
    let o = sim_on(&["--out", path(&dir.path().join("p.jpg"))]);
    assert_clean_error(&o, "unsupported extension");
    // A display frame in a format that would lose it is refused before any
    // work, so the perceived image is not written either.
    let out = dir.path().join("p.png");
    let o = sim_on(&[
        "--out",
        path(&out),
        "--display-out",
        path(&dir.path().join("d.jpg")),
    ]);
    assert_clean_error(&o, "d.jpg: cannot write image: unsupported extension");
    assert!(!out.exists(), "nothing written on failure");
}

#[test]
fn display_image_is_simulated_through_the_chosen_optics() {
    let dir = tempfile::tempdir().expect("tmp");
    let input = dir.path().join("in.png");
    write_png(&input, 16, 16);
    let out = dir.path().join("p.png");
    let calib = small_calib();
    let o = run(&[
        "--calib",
        path(&calib),
        "--sim",
        "--accom",
        "1.5",
        "--input",
        path(&input),
        "--display-image",
        path(&input),
        "--out",
        path(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("through lens + DOE"), "{}", stdout(&o));
}

#[test]
fn designs_are_selected_by_name_and_bad_selections_are_refused() {
    let in_repo = |args: &[&str]| {
        nedrt()
            .current_dir(repo())
            .args(args)
            .output_within(deadline::COMMAND, "nedrt")
    };
    for name in ["allsharp", "multifocal"] {
        let o = in_repo(&["--design", name, "calib"]);
        assert!(o.status.success(), "{name}: {}", stderr(&o));
    }
    let o = in_repo(&["--design", "no-such-design", "calib"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("designs/no-such-design.toml") && stderr(&o).contains("allsharp"),
        "{}",
        stderr(&o)
    );
    let o = in_repo(&["--design", "allsharp", "--doe", "x.safetensors", "calib"]);
    assert!(!o.status.success(), "--design and --doe together");
}

#[test]
fn sim_refuses_images_smaller_than_8_pixels_a_side_like_eval() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (w, h) in [(1, 1), (300, 1), (7, 64)] {
        let img = dir.path().join(format!("{w}x{h}.png"));
        write_png(&img, w, h);
        let out = dir.path().join(format!("{w}x{h}-out.png"));
        let o = sim("1.0", &out, &["--input", path(&img)]);
        assert_clean_error(&o, "smaller than 8×8");
        assert!(
            stderr(&o).contains(&format!("{w}x{h}.png")),
            "{}",
            stderr(&o)
        );
        assert!(!out.exists(), "nothing written for {w}×{h}");
    }
    let img = dir.path().join("8x8.png");
    write_png(&img, 8, 8);
    let o = sim(
        "1.0",
        &dir.path().join("8x8-out.png"),
        &["--input", path(&img)],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stdout(&o).contains("NaN"), "{}", stdout(&o));
}

#[test]
fn oversized_calibrations_and_endless_doe_files_are_refused_with_a_short_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let shipped = std::fs::read_to_string(repo().join("calib/default.toml")).expect("read");
    // An unknown key with a 200 kB value: the error quotes it, bounded.
    let big = dir.path().join("big-key.toml");
    std::fs::write(
        &big,
        format!("{shipped}\n[extra]\nnote = \"{}\"\n", "x".repeat(200_000)),
    )
    .expect("write");
    let o = run(&["--calib", path(&big), "calib"]);
    assert_clean_error(&o, "big-key.toml");
    assert!(
        stderr(&o).len() < 2000,
        "{} bytes of error",
        stderr(&o).len()
    );
    // Past the 1 MiB cap the file is not parsed at all.
    let huge = dir.path().join("huge.toml");
    std::fs::write(&huge, format!("{shipped}\n# {}\n", "y".repeat(2 << 20))).expect("write");
    let o = run(&["--calib", path(&huge), "calib"]);
    assert_clean_error(&o, "larger than 1 MiB");
    // /dev/zero as the DOE: refused at the cap, not read forever.
    let out = dir.path().join("p.png");
    let o = sim("1.0", &out, &["--doe", "/dev/zero", "--method", "doe-only"]);
    assert_clean_error(&o, "larger than 512 MiB");
    assert!(!out.exists());
}

#[test]
fn the_papers_eye_is_the_default_and_the_eye_options_change_what_they_should() {
    // The default calibration, a calibration spelling the paper's eye out,
    // and overrides that matter only with a pupil give the same bytes; a
    // pupil, eye LCA or a field angle with a pupil do not (docs/model.md §4a).
    let dir = tempfile::tempdir().expect("tmp");
    let input = dir.path().join("in.png");
    write_png(&input, 48, 40);
    let text = std::fs::read_to_string(repo().join("calib/default.toml")).expect("calib");
    let start = text.find("\n[eye]").expect("an [eye] table");
    let cache = dir.path().join("cache");
    let without_eye = dir.path().join("no-eye.toml");
    std::fs::write(&without_eye, &text[..start]).expect("write");
    // The AI display (its planes carry the eye's LCA too) where it is
    // cheap; the conventional one through a pupil (153 PSFs less).
    let perceived = |name: &str, extra: &[&str]| {
        let out = dir.path().join(format!("{name}.tif"));
        let method = if extra.contains(&"--pupil-mm") {
            "conventional"
        } else {
            "ai"
        };
        let mut args = vec![
            "--method",
            method,
            "--input",
            path(&input),
            "--cache-dir",
            path(&cache),
        ];
        args.extend_from_slice(extra);
        let o = sim("0.5", &out, &args);
        assert!(o.status.success(), "{name}: {}", stderr(&o));
        (std::fs::read(&out).expect("perceived"), stdout(&o))
    };
    // The PSF cache stores f32: warm it, then compare runs that all load it.
    perceived("warm", &[]);
    let (default, text) = perceived("default", &[]);
    assert!(text.contains("the paper's eye"), "{text}");
    for (name, extra) in [
        ("no-eye", vec!["--calib", path(&without_eye)]),
        (
            "overrides",
            vec![
                "--eye-lca",
                "off",
                "--field-deg",
                "20",
                "--eye-relief-mm",
                "5",
            ],
        ),
    ] {
        assert!(perceived(name, &extra).0 == default, "{name} differs");
    }
    assert!(
        perceived("lca", &["--eye-lca", "on"]).0 != default,
        "the LCA changes nothing"
    );
    let (lens, _) = perceived("lens", &["--pupil-mm", "11", "--eye-relief-mm", "0"]);
    assert!(
        perceived("pupil", &["--pupil-mm", "4"]).0 != lens,
        "the pupil changes nothing"
    );
    let (on_axis, _) = perceived("on", &["--pupil-mm", "4", "--eye-lca", "on"]);
    let (off_axis, text) = perceived(
        "off",
        &["--pupil-mm", "4", "--eye-lca", "on", "--field-deg", "20"],
    );
    assert!(on_axis != off_axis, "the field angle changes nothing");
    assert!(
        text.contains("2-D path") && text.contains("20.0° field"),
        "{text}"
    );
    // Through a pupil the field is planned in zones, and said so; the
    // paper's eye has one PSF for the whole field and no such line.
    assert!(
        text.contains("\nzones     ") && text.contains("for 40 dB"),
        "{text}"
    );
    assert!(!perceived("paper", &[]).1.contains("\nzones"));
    let (one, text) = perceived(
        "one",
        &["--pupil-mm", "4", "--field-deg", "20", "--field-zones", "1"],
    );
    assert!(text.contains("1×1 (as asked)"), "{text}");
    let (two, _) = perceived(
        "two",
        &[
            "--pupil-mm",
            "4",
            "--field-deg",
            "20",
            "--field-zones",
            "2x1",
        ],
    );
    assert!(one != two, "two zones render as one");
    for (flag, value, says) in [
        ("--field-zones", "9", "--field-zones \"9\""),
        ("--field-zones", "0x2", "auto, N or NxM"),
        ("--zone-tolerance-db", "-3", "--zone-tolerance-db -3"),
    ] {
        let out = dir.path().join("bad-zones.png");
        let o = sim(
            "0.5",
            &out,
            &["--input", path(&input), "--pupil-mm", "4", flag, value],
        );
        assert_clean_error(&o, says);
        assert!(!out.exists());
    }
    // `nedrt calib` says which eye it resolved.
    let o = run(&["--pupil-mm", "3", "--eye-lca", "on", "calib"]);
    assert!(
        stdout(&o).contains("eye: pupil 3.0 mm at 15.0 mm") && stdout(&o).contains("B -0.68 D"),
        "{}",
        stdout(&o)
    );
    // Bad values are refused naming the field, nothing written.
    let out = dir.path().join("bad.png");
    let o = sim("0.5", &out, &["--input", path(&input), "--pupil-mm", "30"]);
    assert_clean_error(&o, "eye.pupil_diameter_mm");
    assert!(!out.exists());
}

/// `nedrt sim --level NAME` (issue 54): a level of `nedrt run`'s frame
/// budget by its report's name is that level's method and prefilter on
/// the shipped system's DOE, the image the run's level shows; a name that
/// is no level is refused with the names there are.
#[test]
fn a_frame_budget_level_is_simulated_by_its_name() {
    let dir = tempfile::tempdir().expect("tmp");
    let input = dir.path().join("in.png");
    write_png(&input, 16, 16);
    let calib = small_calib();
    let perceived = dir.path().join("p.png");
    let sim = |out: &Path, extra: &[&str]| {
        let mut args = vec![
            "--calib",
            path(&calib),
            "--sim",
            "--accom",
            "1.5",
            "--input",
            path(&input),
            "--display-out",
        ];
        args.push(path(out));
        args.extend_from_slice(&["--out", path(&perceived)]);
        args.extend_from_slice(extra);
        // From the repository, where the shipped network's DOE is.
        let o = nedrt()
            .current_dir(repo())
            .args(&args)
            .output_within(deadline::COMMAND, "nedrt sim");
        assert!(o.status.success(), "{extra:?}: {}", stderr(&o));
        std::fs::read(out).expect("display image")
    };
    let by_level = sim(&dir.path().join("level.png"), &["--level", "refine:3"]);
    let by_hand = sim(
        &dir.path().join("hand.png"),
        &[
            "--doe",
            path(&repo().join("models/dcnn.doe.safetensors")),
            "--method",
            "doe+wiener",
            "--prefilter",
            "refine:3",
        ],
    );
    assert_eq!(
        by_level, by_hand,
        "refine:3 is doe+wiener's refine:3 on the shipped DOE"
    );
    let wiener = sim(&dir.path().join("wiener.png"), &["--level", "wiener"]);
    assert_ne!(wiener, by_level, "the levels differ");
    let o = run(&[
        "--calib",
        path(&calib),
        "--sim",
        "--accom",
        "1",
        "--level",
        "refine:0",
    ]);
    assert_clean_error(&o, "--level refine:0: not a level of the frame budget");
}
