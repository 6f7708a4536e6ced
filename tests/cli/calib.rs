//! `nedrt calib`: the patterns a lab shows on the built display (read back
//! as a camera program would, against patterns.toml), captures to a PSF
//! bundle and bad captures, and `--psfs` in the commands, host and device.

use nedrt_app::calib_patterns::PatternsManifest;

use super::deadline::CommandWithin;
use super::{assert_clean_error, path, run, small_calib, small_panel, stdout};

/// On the 3 mm-aperture calibration (1920×1080): each dot image lights one
/// channel at exactly the grid patterns.toml gives, dots twice the margin
/// times the PSF's radius apart and that far from the edges; the
/// checkerboard, the flat fields (one a channel) and the dark field are what they say.
#[test]
fn patterns_are_what_their_manifest_says() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("patterns");
    let o = run(&[
        "--calib",
        path(&small_calib()),
        "calib",
        "patterns",
        "--out",
        path(&out),
    ]);
    assert!(o.status.success(), "{}", super::stderr(&o));
    assert!(stdout(&o).contains("patterns.toml"), "{}", stdout(&o));
    let m: PatternsManifest =
        toml::from_str(&std::fs::read_to_string(out.join("patterns.toml")).expect("manifest"))
            .expect("patterns.toml parses");
    assert_eq!((m.panel.width_px, m.panel.height_px), (1920, 1080));
    let g = &m.dots;
    assert!(g.psf_radius_px > 1.0 && g.margin >= 1.0, "{g:?}");
    assert!(
        g.spacing_px as f64 > 2.0 * g.margin * g.psf_radius_px,
        "{g:?}"
    );
    assert_eq!(g.shifts, 2);
    let room = (g.margin * g.psf_radius_px).ceil() as usize;
    let kinds: Vec<&str> = m.pattern.iter().map(|p| p.kind.as_str()).collect();
    let mut want_kinds = vec!["dots"; 3 * 4];
    want_kinds.extend(["checkerboard", "flat", "flat", "flat", "dark"]);
    assert_eq!(kinds, want_kinds);
    // Each channel's four grids: the first at the margin, the others half a
    // spacing across, down, or both.
    let origins: Vec<[usize; 2]> = m.pattern[..4]
        .iter()
        .map(|p| p.origin_px.expect("an origin"))
        .collect();
    let half = g.spacing_px / 2;
    assert_eq!(
        origins,
        [
            [room, room],
            [room + half, room],
            [room, room + half],
            [room + half, room + half]
        ]
    );
    for p in &m.pattern {
        let img = image::open(out.join(&p.file)).expect("a pattern").to_rgb8();
        assert_eq!(img.dimensions(), (1920, 1080), "{}", p.file);
        match p.kind.as_str() {
            "dots" => {
                let c = p.channel.expect("a dot pattern's channel");
                let origin = p.origin_px.expect("an origin");
                let (columns, rows) = (p.columns.expect("columns"), p.rows.expect("rows"));
                assert!(origin[0] >= room && origin[1] >= room, "{}", p.file);
                assert!(
                    origin[0] + (columns - 1) * g.spacing_px + room < 1920,
                    "{}",
                    p.file
                );
                assert!(
                    origin[1] + (rows - 1) * g.spacing_px + room < 1080,
                    "{}",
                    p.file
                );
                let mut lit = Vec::new();
                for (x, y, px) in img.enumerate_pixels() {
                    for (k, &v) in px.0.iter().enumerate() {
                        if v != 0 {
                            assert_eq!((k, v), (c, 255), "{} at ({x}, {y})", p.file);
                            lit.push((x as usize, y as usize));
                        }
                    }
                }
                let mut want = Vec::new();
                for j in 0..rows {
                    for i in 0..columns {
                        want.push((origin[0] + i * g.spacing_px, origin[1] + j * g.spacing_px));
                    }
                }
                lit.sort_by_key(|&(x, y)| (y, x));
                assert_eq!(lit, want, "{}", p.file);
            }
            "checkerboard" => {
                let q = p.square_px.expect("a square") as u32;
                assert_eq!(img.get_pixel(0, 0).0, [255; 3]);
                assert_eq!(img.get_pixel(q, 0).0, [0; 3]);
                assert_eq!(img.get_pixel(q, q).0, [255; 3]);
            }
            "flat" => {
                let c = p.channel.expect("a flat field's channel");
                let mut want = [0u8; 3];
                want[c] = 255;
                assert!(img.pixels().all(|px| px.0 == want), "{}", p.file);
            }
            "dark" => assert!(img.pixels().all(|px| px.0 == [0; 3])),
            other => panic!("an unknown kind {other}"),
        }
    }
}

/// A panel too small for one dot (a margin of 20 asks 2300 px of room
/// around each dot of a 1920-pixel panel), and a margin under 1: clear
/// errors, no folder.
#[test]
fn patterns_that_cannot_be_made_are_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("patterns");
    let o = run(&[
        "--calib",
        path(&small_panel()),
        "calib",
        "patterns",
        "--out",
        path(&out),
    ]);
    assert_clean_error(&o, "panel holds no dot");
    assert!(!out.exists());
    let o = run(&[
        "--calib",
        path(&small_calib()),
        "calib",
        "patterns",
        "--out",
        path(&out),
        "--margin",
        "0.5",
    ]);
    assert_clean_error(&o, "--margin 0.5");
    assert!(!out.exists());
}

/// A bundle of `psf` at every accommodation of `depths_d` (3 channels).
fn bundle_of(
    dir: &std::path::Path,
    depths_d: &[f64],
    psf: &nedrt_optics::psf::Psf,
) -> std::path::PathBuf {
    let out = dir.join(format!("bundle-{}", depths_d.len()));
    let psfs = depths_d.iter().flat_map(|_| vec![psf.clone(); 3]).collect();
    nedrt_optics::bundle::PsfBundle::new(
        "test",
        depths_d.to_vec(),
        vec![600.0, 530.0, 450.0],
        psfs,
        None,
    )
    .expect("a bundle")
    .save(&out)
    .expect("saved");
    out
}

fn vs_sharp_db(o: &std::process::Output) -> f64 {
    stdout(o)
        .lines()
        .find_map(|l| l.strip_prefix("vs sharp  PSNR"))
        .and_then(|l| l.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no PSNR in {}", stdout(o)))
}

/// `--psfs` stands for the DOE's optics: a bundle of perfect PSFs (all the
/// light in one cell) makes doe-only's perceived image the display image
/// itself, against the computed DOE's blur without it; out of the
/// bundle's range, or a changed bundle, is a clear error.
#[test]
fn sim_sees_through_a_measured_bundle() {
    let dir = tempfile::tempdir().expect("tmp");
    let input = dir.path().join("in.png");
    image::RgbImage::from_fn(64, 48, |x, y| {
        image::Rgb([(x * 4) as u8, (y * 5) as u8, ((x + y) * 2) as u8])
    })
    .save(&input)
    .expect("input");
    let perfect = nedrt_optics::psf::Psf {
        window: 1,
        cells: vec![1.0],
        veil: 0.0,
    };
    let bundle = bundle_of(dir.path(), &[0.0, 1.5, 3.0], &perfect);
    let out = dir.path().join("p.png");
    let calib = small_panel();
    let base = [
        "--calib",
        path(&calib),
        "--sim",
        "--method",
        "doe-only",
        "--accom",
        "1.0",
        "--input",
        path(&input),
        "--out",
        path(&out),
    ];
    let designed = run(&base);
    assert!(designed.status.success(), "{}", super::stderr(&designed));
    let measured = run(&[&base[..], &["--psfs", path(&bundle)]].concat());
    assert!(measured.status.success(), "{}", super::stderr(&measured));
    assert!(vs_sharp_db(&designed) < 30.0, "{}", stdout(&designed));
    assert!(vs_sharp_db(&measured) > 60.0, "{}", stdout(&measured));
    // A bundle measured in 2×1 field zones, the left a point, the right a
    // blur: sim renders by its zones.
    let blur = nedrt_optics::psf::Psf::gaussian(2.0, 0.0);
    let zoned = dir.path().join("zoned");
    let n = blur.window;
    let per_zone = |p: &nedrt_optics::psf::Psf| vec![p.padded(n); 9];
    nedrt_optics::bundle::PsfBundle::new(
        "test",
        vec![0.0, 1.5, 3.0],
        vec![600.0, 530.0, 450.0],
        per_zone(&perfect),
        None,
    )
    .and_then(|b| b.with_zones(2, 1, [per_zone(&perfect), per_zone(&blur)].concat()))
    .expect("a zoned bundle")
    .save(&zoned)
    .expect("saved");
    let by_zones = run(&[&base[..], &["--psfs", path(&zoned)]].concat());
    assert!(by_zones.status.success(), "{}", super::stderr(&by_zones));
    assert!(
        stdout(&by_zones).contains("2×1 (the PSF bundle's measured zones)"),
        "{}",
        stdout(&by_zones)
    );
    // The whole field's PSFs are points (as `measured`'s, 144 dB): its
    // right zone's blur must show (51 dB).
    let db = vs_sharp_db(&by_zones);
    assert!(db < vs_sharp_db(&measured) - 40.0, "{}", stdout(&by_zones));
    // doe+wiener averages its filter over 0–3 D: a bundle of 0.5–1 D is refused.
    let short = bundle_of(dir.path(), &[0.5, 1.0], &perfect);
    let mut wiener = base.to_vec();
    wiener[4] = "doe+wiener";
    let o = run(&[&wiener[..], &["--psfs", path(&short)]].concat());
    assert_clean_error(&o, "was measured at 0.5–1 D");
    // A tensor file that is not the card's.
    let t = bundle.join("psfs.safetensors");
    let mut bytes = std::fs::read(&t).expect("read");
    let n = bytes.len() - 1;
    bytes[n] ^= 0x10;
    std::fs::write(&t, bytes).expect("write");
    let o = run(&[&base[..], &["--psfs", path(&bundle)]].concat());
    assert_clean_error(&o, "psfs.safetensors");
}

/// Captures of one accommodation through the design, on the 960×540
/// calibration loop panel: the patterns and `calib synth`'s photographs.
fn one_capture_set(dir: &std::path::Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let calib = super::repo().join("tests/data/calib-loop.toml");
    let patterns = dir.join("patterns");
    let captures = dir.join("captures");
    let o = run(&[
        "--calib",
        path(&calib),
        "calib",
        "patterns",
        "--out",
        path(&patterns),
        "--margin",
        "1",
        "--shifts",
        "1",
    ]);
    assert!(o.status.success(), "{}", super::stderr(&o));
    let o = run(&[
        "--calib",
        path(&calib),
        "calib",
        "synth",
        "--patterns",
        path(&patterns),
        "--out",
        path(&captures),
        "--accommodations",
        "1.5",
    ]);
    assert!(o.status.success(), "{}", super::stderr(&o));
    (calib, captures)
}

/// Bad captures (catalogue rows in docs/reliability.md): a missing file, a
/// saturated dot, mixed sizes, a checkerboard with no corners, a manifest
/// naming no such pattern; each a clear error naming the file, and no
/// bundle written. The good set makes a bundle whose registration and
/// dots `calib show` reports.
#[test]
fn bad_captures_are_refused_by_name() {
    let dir = tempfile::tempdir().expect("tmp");
    let (calib, good) = one_capture_set(dir.path());
    let psfs = |captures: &std::path::Path, out: &std::path::Path| {
        run(&[
            "--calib",
            path(&calib),
            "calib",
            "psfs",
            "--captures",
            path(captures),
            "--out",
            path(out),
        ])
    };
    let out = dir.path().join("bundle");
    let o = psfs(&good, &out);
    assert!(o.status.success(), "{}", super::stderr(&o));
    assert!(
        stdout(&o).contains("8/8/8 dots a channel"),
        "{}",
        stdout(&o)
    );
    let o = run(&[
        "--calib",
        path(&calib),
        "calib",
        "show",
        "--bundle",
        path(&out),
        "--against",
        path(&good.join("truth")),
        "--chart",
        path(&dir.path().join("show")),
    ]);
    assert!(o.status.success(), "{}", super::stderr(&o));
    assert!(stdout(&o).contains("| 1.5 | 2 |"), "{}", stdout(&o));
    for ext in ["png", "svg"] {
        assert!(
            dir.path().join("show").with_extension(ext).exists(),
            "the chart's {ext}"
        );
    }

    let copy = |name: &str| {
        let to = dir.path().join(name);
        std::fs::create_dir_all(to.join("a1.50")).expect("mkdir");
        for entry in ["captures.toml", "patterns.toml"] {
            std::fs::copy(good.join(entry), to.join(entry)).expect("copy");
        }
        for f in std::fs::read_dir(good.join("a1.50")).expect("dir") {
            let f = f.expect("entry").path();
            std::fs::copy(&f, to.join("a1.50").join(f.file_name().expect("name"))).expect("copy");
        }
        to
    };
    let refused = |captures: &std::path::Path, needle: &str| {
        let out = dir.path().join("refused");
        let o = psfs(captures, &out);
        assert_clean_error(&o, needle);
        assert!(!out.exists(), "a bundle was written for {needle}");
    };
    let grey = |w: u32, h: u32, v: u16| {
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_pixel(w, h, image::Luma([v]))
    };
    let (w, h) = image::image_dimensions(good.join("a1.50/dark.png")).expect("a capture");

    let missing = copy("missing");
    std::fs::remove_file(missing.join("a1.50/dots-g.png")).expect("rm");
    refused(&missing, "a1.50/dots-g.png");

    let saturated = copy("saturated");
    grey(w, h, 16 * 4095)
        .save(saturated.join("a1.50/dots-r.png"))
        .expect("write");
    refused(&saturated, "is saturated");

    let mixed = copy("mixed");
    grey(w - 8, h, 900)
        .save(mixed.join("a1.50/flat-b.png"))
        .expect("write");
    refused(&mixed, "every capture comes from one camera");

    let blank = copy("blank");
    grey(w, h, 16 * 64)
        .save(blank.join("a1.50/checkerboard.png"))
        .expect("write");
    refused(&blank, "registration failed");

    let unnamed = copy("unnamed");
    let m = std::fs::read_to_string(unnamed.join("captures.toml")).expect("manifest");
    std::fs::write(
        unnamed.join("captures.toml"),
        m.replacen("pattern = \"dots-r.png\"", "pattern = \"dots-x.png\"", 1),
    )
    .expect("write");
    refused(&unnamed, "pattern \"dots-x.png\" is not in");
}

mod needs_gpu {
    use super::super::deadline::CommandWithin;
    use super::super::{path, small_calib, stderr, stdout};
    use super::{bundle_of, run};

    /// `--psfs` on the device: doe+wiener's Wiener and refine:3's steps made
    /// from a measured bundle score on `--backend wgpu` what they score on
    /// the CPU, to 0.01 dB, and the device runs them.
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn a_measured_bundle_preprocesses_on_the_device_as_on_the_host() {
        let dir = tempfile::tempdir().expect("tmp");
        let input = dir.path().join("in.png");
        image::RgbImage::from_fn(40, 24, |x, y| {
            image::Rgb([(x * 6) as u8, (y * 9) as u8, ((x + y) * 3) as u8])
        })
        .save(&input)
        .expect("input");
        let bundle = bundle_of(
            dir.path(),
            &[0.0, 1.5, 3.0],
            &nedrt_optics::psf::Psf::gaussian(1.5, 0.02),
        );
        let out = dir.path().join("p.png");
        let calib = small_calib();
        for prefilter in ["native", "refine:3"] {
            let on = |backend: &str| {
                let o = run(&[
                    "--calib",
                    path(&calib),
                    "--sim",
                    "--accom",
                    "1.0",
                    "--out",
                    path(&out),
                    "--input",
                    path(&input),
                    "--method",
                    "doe+wiener",
                    "--prefilter",
                    prefilter,
                    "--psfs",
                    path(&bundle),
                    "--backend",
                    backend,
                ]);
                assert!(o.status.success(), "{prefilter} {backend}: {}", stderr(&o));
                o
            };
            let (cpu, gpu) = (on("cpu"), on("wgpu"));
            assert!(stdout(&gpu).contains("on the device"), "{}", stdout(&gpu));
            let (a, b) = (super::vs_sharp_db(&cpu), super::vs_sharp_db(&gpu));
            assert!((a - b).abs() <= 0.01, "{prefilter}: CPU {a}, device {b}");
        }
    }

    /// `--psfs` in `nedrt run` and `nedrt prefilter` on the device: the
    /// frame `run` records through doe+wiener made from a bundle, and
    /// `prefilter`'s refine:3 display images, are the CPU's (a code of the
    /// 8-bit frame; 1e-3 of the display values).
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn a_measured_bundle_runs_and_prefilters_on_the_device_as_on_the_host() {
        let dir = tempfile::tempdir().expect("tmp");
        let bundle = bundle_of(
            dir.path(),
            &[0.0, 1.5, 3.0],
            &nedrt_optics::psf::Psf::gaussian(1.5, 0.02),
        );
        let frame = dir.path().join("frame.png");
        super::super::write_png(&frame, 64, 48);
        let imgs = dir.path().join("imgs");
        std::fs::create_dir(&imgs).expect("dir");
        super::super::write_png(&imgs.join("a.png"), 24, 16);
        let calib = super::super::small_panel();
        let mut frames = Vec::new();
        let mut displays = Vec::new();
        for backend in ["cpu", "wgpu"] {
            let rec = dir.path().join(format!("rec-{backend}"));
            let o = super::super::nedrt()
                .current_dir(super::super::repo())
                .args(["run", "--calib", path(&calib), "--backend", backend])
                .args(["--preprocess", "doe+wiener", "--psfs", path(&bundle)])
                .args(["--source", "dir", "--input", path(&frame), "--frames", "1"])
                .args(["--sink", "record", "--record-dir", path(&rec)])
                .output_within(super::super::deadline::COMMAND, "nedrt run");
            assert!(o.status.success(), "run {backend}: {}", stderr(&o));
            frames.push(
                image::open(rec.join("frame-00000000.png"))
                    .expect("frame")
                    .to_rgb8(),
            );
            let out = dir.path().join(format!("pre-{backend}"));
            let o = run(&[
                "--calib",
                path(&calib),
                "--psfs",
                path(&bundle),
                "--backend",
                backend,
                "prefilter",
                "--images",
                path(&imgs),
                "--out-dir",
                path(&out),
                "--prefilter",
                "refine:3",
            ]);
            assert!(o.status.success(), "prefilter {backend}: {}", stderr(&o));
            let bytes = std::fs::read(out.join("displays.safetensors")).expect("displays");
            let t = safetensors::SafeTensors::deserialize(&bytes).expect("safetensors");
            displays.push(
                t.tensor("a")
                    .expect("a")
                    .data()
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                    .collect::<Vec<_>>(),
            );
            if backend == "wgpu" {
                let manifest = std::fs::read_to_string(out.join("prefilter.json")).expect("json");
                assert!(manifest.contains("device"), "{manifest}");
            }
        }
        let worst = frames[0]
            .as_raw()
            .iter()
            .zip(frames[1].as_raw())
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .expect("pixels");
        assert!(
            worst <= 1,
            "run: CPU and device frames differ by {worst} codes"
        );
        let worst = displays[0]
            .iter()
            .zip(&displays[1])
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst <= 1e-3, "prefilter: CPU and device differ by {worst}");
    }
}

/// A folder holding one 24×16 image.
fn one_image(dir: &std::path::Path) -> std::path::PathBuf {
    let imgs = dir.join("imgs");
    std::fs::create_dir(&imgs).expect("dir");
    super::write_png(&imgs.join("a.png"), 24, 16);
    imgs
}

/// All the light in one cell: the perceived image is the display image.
fn perfect_psf() -> nedrt_optics::psf::Psf {
    nedrt_optics::psf::Psf {
        window: 1,
        cells: vec![1.0],
        veil: 0.0,
    }
}

/// `--psfs` reaches every command's optics: eval's doe-only scores, the
/// prefilter command's display images, `nedrt run`'s frames (the Wiener
/// made from a bundle) and the viewer's sweep all change with a bundle of
/// perfect PSFs, and a run through a bundle that misses the Wiener's range
/// stops before it starts.
#[test]
fn eval_prefilter_and_run_take_a_bundle() {
    let dir = tempfile::tempdir().expect("tmp");
    let (imgs, perfect) = (one_image(dir.path()), perfect_psf());
    let bundle = bundle_of(dir.path(), &[0.0, 1.5, 3.0], &perfect);
    let calib = small_panel();
    let with = |psfs: bool, args: &[&str], what: &str| {
        let globals: Vec<&str> = if psfs {
            vec!["--calib", path(&calib), "--psfs", path(&bundle)]
        } else {
            vec!["--calib", path(&calib)]
        };
        let o = run(&[&globals[..], args].concat());
        assert!(o.status.success(), "{what}: {}", super::stderr(&o));
        o
    };
    for (psfs, name) in [(false, "designed"), (true, "measured")] {
        let out = dir.path().join(format!("eval-{name}"));
        with(
            psfs,
            &[
                "eval",
                "--images",
                path(&imgs),
                "--out-dir",
                path(&out),
                "--methods",
                "doe-only",
            ],
            "eval",
        );
        let out = dir.path().join(format!("prefilter-{name}"));
        with(
            psfs,
            &[
                "prefilter",
                "--images",
                path(&imgs),
                "--out-dir",
                path(&out),
                "--method",
                "doe+wiener",
            ],
            "prefilter",
        );
    }
    let read = |p: &str| std::fs::read(dir.path().join(p)).expect(p);
    assert_ne!(
        read("eval-designed/eval.json"),
        read("eval-measured/eval.json")
    );
    assert_ne!(
        read("prefilter-designed/displays.safetensors"),
        read("prefilter-measured/displays.safetensors")
    );
    let frame = dir.path().join("frame.png");
    super::write_png(&frame, 64, 48);
    let frames = |psfs: Option<&std::path::Path>, rec: &std::path::Path| {
        let mut c = super::nedrt();
        c.current_dir(super::repo())
            .args([
                "run",
                "--calib",
                path(&calib),
                "--backend",
                "cpu",
                "--preprocess",
                "doe+wiener",
            ])
            .args(["--source", "dir", "--input", path(&frame), "--frames", "1"])
            .args(["--sink", "record", "--record-dir", path(rec)]);
        if let Some(p) = psfs {
            c.args(["--psfs", path(p)]);
        }
        c.output_within(super::deadline::COMMAND, "nedrt run")
    };
    let (designed, measured) = (dir.path().join("rec-d"), dir.path().join("rec-m"));
    for (p, rec) in [(None, &designed), (Some(bundle.as_path()), &measured)] {
        let o = frames(p, rec);
        assert!(o.status.success(), "{}", super::stderr(&o));
    }
    assert_ne!(
        std::fs::read(designed.join("frame-00000000.png")).expect("frame"),
        std::fs::read(measured.join("frame-00000000.png")).expect("frame")
    );
    // The viewer's sweep (the scene `nedrt view` draws), on the 3 mm
    // calibration: its DOE's PSFs are cheap.
    let small = small_calib();
    for (psfs, name) in [(false, "designed"), (true, "measured")] {
        let out = dir.path().join(format!("sweep-{name}.png"));
        let mut args = vec![
            "--calib",
            path(&small),
            "sweep",
            "--input",
            path(&frame),
            "--methods",
            "doe-only",
            "--from",
            "0.5",
            "--to",
            "1.5",
            "--step",
            "0.5",
            "--out",
            path(&out),
        ];
        if psfs {
            args.extend(["--psfs", path(&bundle)]);
        }
        let o = run(&args);
        assert!(o.status.success(), "sweep: {}", super::stderr(&o));
    }
    assert_ne!(read("sweep-designed.png"), read("sweep-measured.png"));
    let short = bundle_of(dir.path(), &[0.5, 1.0], &perfect);
    let o = frames(Some(&short), &dir.path().join("rec-s"));
    assert_clean_error(&o, "was measured at 0.5–1 D");
}

/// The studies through a bundle: in `tradeoff` a bundle of perfect PSFs
/// is what doe-only is seen through (its rows score far above the lens
/// alone's, which keeps its computed optics), and `stability` refuses a
/// bundle short of the range its Wiener needs before any work.
#[test]
fn tradeoff_and_stability_take_a_bundle() {
    let dir = tempfile::tempdir().expect("tmp");
    let (imgs, perfect) = (one_image(dir.path()), perfect_psf());
    let bundle = bundle_of(dir.path(), &[0.0, 1.5, 3.0], &perfect);
    let calib = small_panel();
    let out = dir.path().join("tradeoff");
    let (design, model) = (
        super::repo().join("designs/multifocal.toml"),
        super::dcnn_model(),
    );
    let o = run(&[
        "--calib",
        path(&calib),
        "--psfs",
        path(&bundle),
        "tradeoff",
        "--designs",
        path(&design),
        "--prefilter",
        "native",
        "--images",
        path(&imgs),
        "--out-dir",
        path(&out),
        "--size",
        "32x24",
        "--backends",
        "cpu",
        "--repeat",
        "1",
        "--no-fidelity",
        "--models",
        path(&model),
    ]);
    assert!(o.status.success(), "tradeoff: {}", super::stderr(&o));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("tradeoff.json")).expect("json"))
            .expect("parse");
    let db = |name: &str| {
        json["records"]
            .as_array()
            .expect("records")
            .iter()
            .find(|r| r["name"] == name)
            .and_then(|r| r["mean_psnr_db"].as_f64())
            .unwrap_or_else(|| panic!("no {name} row"))
    };
    assert!(
        db("doe-only") > db("conventional") + 10.0,
        "doe-only {} dB, conventional {} dB",
        db("doe-only"),
        db("conventional")
    );
    let short = bundle_of(dir.path(), &[0.5, 1.0], &perfect);
    let report = dir.path().join("stability.md");
    let o = run(&[
        "--calib",
        path(&calib),
        "--psfs",
        path(&short),
        "--dcnn",
        path(&model),
        "stability",
        "--images",
        path(&imgs),
        "--no-gpu",
        "--out",
        path(&report),
    ]);
    assert_clean_error(&o, "was measured at 0.5–1 D");
    assert!(!report.exists());
}

/// `calib truth` on a calibration whose eye pupil is the stop, through the
/// command line: the zones' truths differ (the decentred pupil sees the
/// DOE's rings off centre), and the perturbation's relief error leaves the
/// calibration's relief alone. (Its flag once shared the global
/// --eye-relief-mm's name, and clap then set the relief to 0: every zone
/// came out the same.)
#[test]
fn calib_truth_keeps_the_eye_and_its_zones_differ() {
    let dir = tempfile::tempdir().expect("tmp");
    let text = std::fs::read_to_string(super::repo().join("tests/data/calib-loop.toml"))
        .expect("the loop calibration");
    let calib = dir.path().join("eye.toml");
    std::fs::write(
        &calib,
        format!("{text}\n[eye]\npupil_diameter_mm = 2.0\nrelief_mm = 5.0\n"),
    )
    .expect("write");
    let out = dir.path().join("truth");
    let o = run(&[
        "--calib",
        path(&calib),
        "--no-cache",
        "calib",
        "truth",
        "--out",
        path(&out),
        "--accommodations",
        "1.5",
        "--field-zones",
        "2x1",
    ]);
    assert!(o.status.success(), "{}", super::stderr(&o));
    let b = nedrt_optics::bundle::PsfBundle::load(&out).expect("the truth");
    let (z0, z1) = (b.zone(0, 0).expect("zone 0"), b.zone(1, 0).expect("zone 1"));
    // Red, out of focus at 1.5 D: the two zones' PSFs lie 65 % apart.
    let apart = nedrt_optics::pixel::response_distance(z0.measured(0, 0), z1.measured(0, 0));
    assert!(apart > 0.3, "the zones' red PSFs are {apart} apart");
}
