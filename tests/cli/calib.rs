//! `nedrt calib patterns`: the images a lab shows on the built display,
//! read back as a camera program would, against patterns.toml.

use nedrt_app::calib_patterns::PatternsManifest;

use super::{assert_clean_error, path, run, small_calib, small_panel, stdout};

/// On the 3 mm-aperture calibration (1920×1080): each dot image lights one
/// channel at exactly the grid patterns.toml gives, dots twice the margin
/// times the PSF's radius apart and that far from the edges; the
/// checkerboard, flat and dark fields are what they say.
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
    want_kinds.extend(["checkerboard", "flat", "dark"]);
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
            "flat" => assert!(img.pixels().all(|px| px.0 == [255; 3])),
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
