use super::*;
use crate::psf::Psf;

fn plan(nx: usize, ny: usize, w: usize, h: usize) -> ZonePlan {
    ZonePlan {
        nx,
        ny,
        field: FieldGeometry {
            width: w,
            height: h,
            centre_tan_x: 0.0,
            tan_per_px: 1e-3,
        },
        note: String::new(),
    }
}

fn constant(w: usize, h: usize, v: f32) -> Image {
    Image::from_planes(w, h, vec![vec![v; w * h]; 3])
}

#[test]
fn requests_parse_and_bad_ones_say_why() {
    assert_eq!("auto".parse::<ZoneRequest>(), Ok(ZoneRequest::default()));
    assert_eq!("3".parse::<ZoneRequest>(), Ok(ZoneRequest::Fixed(3, 3)));
    assert_eq!("4x2".parse::<ZoneRequest>(), Ok(ZoneRequest::Fixed(4, 2)));
    for bad in ["0", "9", "2x", "x", "-1", "1.5", "many"] {
        let e = bad.parse::<ZoneRequest>().unwrap_err();
        assert!(e.contains("auto, N or NxM"), "{bad}: {e}");
    }
}

#[test]
fn the_weights_are_a_partition_of_unity_and_each_centre_is_its_zone() {
    // Zone k's rendering is the constant k: the blend is the weighted index.
    let (nx, ny, w, h) = (3, 2, 12, 8);
    let p = plan(nx, ny, w, h);
    let rendered: Vec<Image> = (0..nx * ny)
        .map(|k| constant(2 * w, 2 * h, k as f32))
        .collect();
    let ones: Vec<Image> = (0..nx * ny).map(|_| constant(2 * w, 2 * h, 1.0)).collect();
    let sum = p.blend(&ones);
    assert!(sum.plane(0).iter().all(|v| (v - 1.0).abs() < 1e-6));
    let b = p.blend(&rendered);
    // Bilinear weights reproduce a function linear in the zone indices
    // exactly: at a retinal pixel, the position in zone units (zone i's
    // centre at i), held at the outermost centres.
    let units = |k: usize, cells: usize, n: usize| {
        ((k as f64 + 0.5) / cells as f64 * n as f64 - 0.5).clamp(0.0, (n - 1) as f64)
    };
    for y in 0..2 * h {
        for x in 0..2 * w {
            let want = units(x, 2 * w, nx) + nx as f64 * units(y, 2 * h, ny);
            let got = b.plane(1)[y * 2 * w + x] as f64;
            assert!((got - want).abs() < 1e-5, "({x}, {y}): {got} vs {want}");
        }
    }
    // At an interior centre (zone 1, 0 on the display grid: x = 6, between
    // retinal pixels 11 and 12) the two neighbours average to that zone.
    let (cx, _) = p.centre_px(1, 0);
    assert_eq!(cx, 6.0);
    let mid = 0.5 * (b.plane(0)[11] + b.plane(0)[12]);
    assert!((mid - 1.0).abs() < 1e-6, "{mid}");
    // The corners are zones 0 and 5.
    assert_eq!(b.plane(2)[0], 0.0);
    assert_eq!(b.plane(2)[2 * w * 2 * h - 1], 5.0);
}

#[test]
fn one_zone_blends_to_itself() {
    let p = plan(1, 1, 5, 3);
    let img = Image::from_planes(
        10,
        6,
        (0..3)
            .map(|c| (0..60).map(|i| (i * (c + 1)) as f32).collect())
            .collect(),
    );
    assert_eq!(p.blend(std::slice::from_ref(&img)), img);
}

#[test]
fn the_field_geometry_puts_the_image_centre_at_the_calibrations_angle() {
    let mut c = Calibration::default_embedded().expect("calib");
    c.eye.field_rad = 10f64.to_radians();
    c.eye.relief_m = 0.0;
    let g = FieldGeometry::of(&c, 512, 256);
    let (tx, ty) = g.tan_at(256.0, 128.0);
    assert!((tx - 10f64.to_radians().tan()).abs() < 1e-12 && ty == 0.0);
    // With no relief a display pixel spans pitch / z_d, twice the retinal step.
    assert!((g.tan_per_px - 2.0 * c.retinal_step_rad()).abs() < 1e-15);
    let (tx1, ty1) = g.tan_at(257.0, 0.0);
    assert!((tx1 - tx - g.tan_per_px).abs() < 1e-15);
    assert!((ty1 + 128.0 * g.tan_per_px).abs() < 1e-15);
    // Seen from a pupil 15 mm behind the lens, (1 + eV)⁻¹ of it.
    c.eye.relief_m = 15e-3;
    let v = c.vergence_d(c.design_channel);
    let far = FieldGeometry::of(&c, 512, 256);
    assert!((far.tan_per_px * (1.0 + 15e-3 * v) - g.tan_per_px).abs() < 1e-15);
}

#[test]
fn the_planner_adds_zones_as_the_tolerance_needs() {
    assert_eq!(zones_for(45.0, 40.0), 1);
    assert_eq!(zones_for(f64::INFINITY, 40.0), 1);
    assert_eq!(zones_for(40.0, 40.0), 1);
    // 6 dB short: twice as many zones halve the distance to a centre.
    assert_eq!(zones_for(34.0, 40.0), 2);
    assert_eq!(zones_for(30.0, 40.0), 4);
    assert_eq!(zones_for(5.0, 40.0), MAX_ZONES_PER_AXIS);
}

fn eye_calibration(pupil_mm: f64, relief_mm: f64, field_deg: f64) -> Calibration {
    let shipped = nedrt_core::calib::DEFAULT_CALIBRATION_TOML;
    let text = format!(
        "{}\n[eye]\npupil_diameter_mm = {pupil_mm}\nrelief_mm = {relief_mm}\nfield_deg = {field_deg}\n",
        &shipped[..shipped.find("\n[eye]").unwrap_or(shipped.len())]
    );
    Calibration::from_toml(&text, "eye.toml", None).expect("calibration")
}

fn ramp(w: usize, h: usize) -> Image {
    Image::from_planes(
        w,
        h,
        (0..3)
            .map(|c| {
                (0..w * h)
                    .map(|k| ((k % w + 3 * (k / w) + 5 * c) % 11) as f32 / 10.0)
                    .collect()
            })
            .collect(),
    )
}

#[test]
fn each_zone_renders_through_the_psfs_of_its_own_field_angle() {
    let sim = Simulator::new(eye_calibration(4.0, 15.0, 10.0), None, Default::default())
        .expect("simulator");
    let (method, d) = (Method::DoeOnly, 1.5);
    let display = ramp(24, 8);
    let quiet = nedrt_core::progress::Silent;
    let centre = sim.prepare(&[method], &[d], &quiet).expect("prepare");
    let zoned = sim
        .field_zones(
            &centre,
            method,
            &display,
            d,
            ZoneRequest::Fixed(2, 1),
            &quiet,
        )
        .expect("zones");
    assert_eq!((zoned.plan.nx, zoned.plan.ny), (2, 1));
    let seen = zoned
        .perceived(&centre, method, &display, d)
        .expect("perceived");
    // Outside the two zone centres (retinal columns < 12 and ≥ 36) each
    // zone's rendering holds alone: it must be the image through the PSFs
    // of a simulator looking at that zone's centre.
    for (i, columns) in [(0, 0..12), (1, 36..48)] {
        let (tx, ty) = zoned.plan.tan_at_zone(i, 0);
        assert_eq!(ty, 0.0);
        let own = sim.at_field(tx, ty);
        let alone = own
            .prepare_seen(method, d, &quiet)
            .and_then(|p| p.perceived(method, &display, d))
            .expect("one zone");
        for c in 0..3 {
            for y in 0..16 {
                for x in columns.clone() {
                    let k = y * 48 + x;
                    assert_eq!(seen.plane(c)[k], alone.plane(c)[k], "zone {i} ({x}, {y})");
                }
            }
        }
    }
    // The two zones look through different parts of the DOE.
    assert!(zoned.neighbours_db.is_some_and(|db| db.is_finite()));
}

#[test]
fn without_a_pupil_or_with_no_relief_the_field_is_one_zone() {
    let quiet = nedrt_core::progress::Silent;
    let display = ramp(16, 16);
    // The paper's eye: nothing is computed.
    let paper = Simulator::new(
        Calibration::default_embedded().expect("calib"),
        None,
        Default::default(),
    )
    .expect("simulator");
    let centre = paper
        .prepare(&[Method::Conventional], &[1.0], &quiet)
        .expect("prepare");
    let z = paper
        .field_zones(
            &centre,
            Method::Conventional,
            &display,
            1.0,
            ZoneRequest::default(),
            &quiet,
        )
        .expect("zones");
    assert_eq!((z.plan.nx, z.plan.ny, z.neighbours_db), (1, 1, None));
    // A pupil in the lens plane is never decentred: the planner's probes
    // render the centre's image exactly.
    let flush = Simulator::new(eye_calibration(4.0, 0.0, 0.0), None, Default::default())
        .expect("simulator");
    let centre = flush
        .prepare(&[Method::DoeOnly], &[1.0], &quiet)
        .expect("prepare");
    let z = flush
        .field_zones(
            &centre,
            Method::DoeOnly,
            &display,
            1.0,
            ZoneRequest::default(),
            &quiet,
        )
        .expect("zones");
    assert_eq!((z.plan.nx, z.plan.ny), (1, 1), "{}", z.plan.note);
    assert!(z.plan.note.contains("∞ dB (horizontal)"), "{}", z.plan.note);
}

/// A bundle measured in 2 × 1 zones, on the paper's eye (no pupil, so
/// only the bundle makes zones): the left zone a point, the right a blur,
/// the whole field between them.
fn zoned_bundle() -> crate::bundle::PsfBundle {
    let n = Psf::gaussian(2.0, 0.0).window;
    let three = |p: Psf| -> Vec<Psf> { (0..6).map(|_| p.padded(n)).collect() };
    let point = Psf {
        window: 1,
        cells: vec![1.0],
        veil: 0.0,
    };
    let zones = [three(point), three(Psf::gaussian(2.0, 0.0))].concat();
    crate::bundle::PsfBundle::new(
        "test",
        vec![1.0, 2.0],
        vec![610.0, 530.0, 460.0],
        three(Psf::gaussian(1.0, 0.0)),
        None,
    )
    .and_then(|b| b.with_zones(2, 1, zones))
    .expect("a zoned bundle")
}

#[test]
fn a_measured_bundle_with_zones_renders_each_zone_through_its_own_psfs() {
    let quiet = nedrt_core::progress::Silent;
    let bundle = std::sync::Arc::new(zoned_bundle());
    let sim = Simulator::new(
        Calibration::default_embedded().expect("calib"),
        None,
        Default::default(),
    )
    .and_then(|s| s.with_measured(bundle.clone()))
    .expect("simulator");
    let (method, d) = (Method::DoeOnly, 1.5);
    let display = ramp(24, 8);
    let centre = sim.prepare(&[method], &[d], &quiet).expect("prepare");
    // The bundle's zones, whatever was asked.
    for request in [ZoneRequest::default(), ZoneRequest::Fixed(3, 3)] {
        let zoned = sim
            .field_zones(&centre, method, &display, d, request, &quiet)
            .expect("zones");
        assert_eq!((zoned.plan.nx, zoned.plan.ny), (2, 1), "{request:?}");
        assert!(
            zoned.plan.note.contains("measured zones"),
            "{}",
            zoned.plan.note
        );
        let seen = zoned
            .perceived(&centre, method, &display, d)
            .expect("perceived");
        // Beyond the zone centres each zone's PSFs alone, and those are
        // the zone's, not the whole field's.
        let whole = centre.perceived(method, &display, d).expect("whole");
        for (i, columns) in [(0, 0..12), (1, 36..48)] {
            let own = Simulator::new(
                Calibration::default_embedded().expect("calib"),
                None,
                Default::default(),
            )
            .and_then(|s| s.with_measured(std::sync::Arc::new(bundle.zone(i, 0).expect("zone"))))
            .expect("zone simulator");
            let alone = own
                .prepare_seen(method, d, &quiet)
                .and_then(|p| p.perceived(method, &display, d))
                .expect("one zone");
            let mut differs = false;
            for c in 0..3 {
                for y in 0..16 {
                    for x in columns.clone() {
                        let k = y * 48 + x;
                        assert_eq!(seen.plane(c)[k], alone.plane(c)[k], "zone {i} ({x}, {y})");
                        differs |= (seen.plane(c)[k] - whole.plane(c)[k]).abs() > 1e-3;
                    }
                }
            }
            assert!(differs, "zone {i} renders as the whole field");
        }
    }
    // No zone beyond the grid.
    assert!(bundle.zone(2, 0).is_none() && bundle.zone(0, 1).is_none());
}

#[test]
fn a_zoned_bundle_saves_and_loads_and_a_wrong_zone_count_is_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let mut b = zoned_bundle();
    b.save(&dir.path().join("b")).expect("save");
    let back = crate::bundle::PsfBundle::load(&dir.path().join("b")).expect("load");
    assert_eq!(back.zones(), (2, 1));
    assert_eq!(back.zone_psfs, b.zone_psfs);
    assert_eq!(back.psfs, b.psfs);
    let short = b.zone_psfs[..6].to_vec();
    let e = zoned_bundle()
        .with_zones(2, 1, short)
        .expect_err("6 zone PSFs for 2 zones");
    assert!(e.to_string().contains("6 zone PSFs for 2 zones"), "{e}");
    let e = zoned_bundle()
        .with_zones(0, 1, Vec::new())
        .expect_err("no zones");
    assert!(e.to_string().contains("zones [0, 1]"), "{e}");
    // The mirrored bundle keeps its zones, and a zone its own hash.
    let (m, _) = b.mirrored();
    assert_eq!(m.zones(), (2, 1));
    let (z0, z1) = (b.zone(0, 0).expect("z0"), b.zone(1, 0).expect("z1"));
    assert_ne!(z0.card.psfs_blake3, z1.card.psfs_blake3);
    assert_ne!(z0.card.psfs_blake3[..16], b.card.psfs_blake3[..16]);
}
