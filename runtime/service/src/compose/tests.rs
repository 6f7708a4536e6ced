use super::*;
use gpu::LayerBlender;
use nedrt_core::preprocess::HostTraffic;

fn view(w: usize, h: usize) -> ViewGeometry {
    ViewGeometry {
        width: w,
        height: h,
        pixels_per_tan: 1000.0,
    }
}

/// A uniform quad of premultiplied colour `c` (grey) and alpha `a`.
fn quad(layer: u32, z: i32, x: i64, y: i64, (w, h): (usize, usize), c: f32, a: f32) -> QuadLayer {
    QuadLayer {
        layer,
        z,
        placement: Placement::Pixels { x, y },
        width: w,
        height: h,
        rgba: [c, c, c, a].repeat(w * h),
    }
}

fn grey(w: usize, h: usize, v: f32) -> Image {
    Image::rgb(w, h, vec![v; 3 * w * h])
}

#[test]
fn premultiplied_over_adds_the_colour_and_keeps_one_minus_alpha_of_what_is_below() {
    let v = view(4, 4);
    let mut im = grey(4, 4, 1.0);
    // Half-covering with colour 0.25: premultiplied gives 0.25 + 0.5·1 =
    // 0.75 (straight alpha would give 0.625).
    let half = quad(1, 0, 0, 0, (2, 2), 0.25, 0.5)
        .place(&v)
        .expect("placed");
    // Alpha 0 and no colour: nothing.
    let clear = quad(2, 0, 2, 2, (1, 1), 0.0, 0.0)
        .place(&v)
        .expect("placed");
    blend(&mut im, &[half, clear]).expect("blends");
    for c in 0..3 {
        let p = im.plane(c);
        assert_eq!(p[0], 0.75);
        assert_eq!(p[5], 0.75);
        assert_eq!(p[2 * 4 + 2], 1.0);
        assert_eq!(p[3], 1.0, "uncovered pixels unchanged");
    }
}

#[test]
fn higher_z_is_nearer_whatever_the_submission_order_and_ties_go_by_layer_id() {
    let v = view(3, 1);
    let far = quad(7, -1, 0, 0, (3, 1), 0.1, 1.0)
        .place(&v)
        .expect("placed");
    let near = quad(3, 5, 1, 0, (1, 1), 0.9, 1.0)
        .place(&v)
        .expect("placed");
    for quads in [
        vec![far.clone(), near.clone()],
        vec![near.clone(), far.clone()],
    ] {
        let mut im = grey(3, 1, 0.5);
        blend(&mut im, &quads).expect("blends");
        assert_eq!(im.plane(0), &[0.1, 0.9, 0.1]);
    }
    // Equal z: the higher layer id is drawn last.
    let a = quad(1, 0, 0, 0, (1, 1), 0.3, 1.0)
        .place(&v)
        .expect("placed");
    let b = quad(2, 0, 0, 0, (1, 1), 0.6, 1.0)
        .place(&v)
        .expect("placed");
    for quads in [vec![a.clone(), b.clone()], vec![b, a]] {
        let mut im = grey(3, 1, 0.5);
        blend(&mut im, &quads).expect("blends");
        assert_eq!(im.plane(0)[0], 0.6);
    }
}

#[test]
fn bad_layers_are_refused_with_their_reason() {
    let v = view(8, 6);
    let e = |q: QuadLayer| q.place(&v).expect_err("refused").to_string();
    assert!(e(quad(1, 0, 0, 0, (0, 2), 0.0, 0.0)).contains("at least one"));
    assert!(e(quad(1, 0, 7, 0, (2, 2), 0.1, 0.5)).contains("not inside the 8×6 view"));
    assert!(e(quad(1, 0, -1, 0, (2, 2), 0.1, 0.5)).contains("not inside"));
    assert!(e(quad(1, 0, 0, 0, (2, 2), 0.6, 0.5)).contains("premultiplied"));
    assert!(e(quad(1, 0, 0, 0, (2, 2), f32::NAN, 0.5)).contains("not a finite value"));
    assert!(e(quad(1, 0, 0, 0, (2, 2), 0.1, 1.5)).contains("not a finite value"));
    let mut short = quad(1, 0, 0, 0, (2, 2), 0.1, 0.5);
    short.rgba.pop();
    assert!(e(short).contains("15 values"));
    let mut far = quad(1, 0, 0, 0, (2, 2), 0.1, 0.5);
    far.placement = Placement::Degrees {
        x_deg: 89.999,
        y_deg: 0.0,
    };
    assert!(e(far).contains("not inside"));
    // 8-bit rounding of a premultiplied texel is not a refusal.
    let rounded = quad(1, 0, 0, 0, (1, 1), 128.0 / 255.0, 127.6 / 255.0);
    assert!(rounded.place(&v).is_ok());
    let many: Vec<_> = (0..=MAX_QUADS as u32)
        .map(|i| {
            quad(i, 0, 0, 0, (1, 1), 0.0, 0.0)
                .place(&v)
                .expect("placed")
        })
        .collect();
    assert!(
        blend(&mut grey(8, 6, 0.0), &many)
            .expect_err("too many")
            .to_string()
            .contains("at most")
    );
}

#[test]
fn a_placement_in_degrees_centres_the_quad_at_that_direction() {
    let v = view(100, 60);
    let mut q = quad(1, 0, 0, 0, (10, 4), 0.0, 0.0);
    q.placement = Placement::Degrees {
        x_deg: 0.0,
        y_deg: 0.0,
    };
    let p = q.place(&v).expect("placed");
    assert_eq!((p.x, p.y), (45, 28));
    // tan(1°)·1000 = 17.455 px right; 1° up is 17.455 px up.
    q.placement = Placement::Degrees {
        x_deg: 1.0,
        y_deg: 1.0,
    };
    let p = q.place(&v).expect("placed");
    assert_eq!((p.x, p.y), (62, 11));
    // The panel's own geometry: 8.7 µm pixels 40 mm from the lens.
    let g = ViewGeometry::of_panel(1920, 1080, 8.7e-6, 0.04);
    assert!((g.pixels_per_tan - 4597.7).abs() < 0.1);
}

mod needs_gpu {
    use super::*;
    use crate::present::transfer::Transfer;
    use wgpu::util::DeviceExt;

    fn on_device(
        im: &Image,
        quads: &[PlacedQuad],
        generations: &[u64],
    ) -> (Image, Vec<HostTraffic>) {
        let (device, queue) = nedrt_gpu::test_device(false);
        let (w, h) = (im.width, im.height);
        let planes = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("test planes"),
            contents: bytemuck::cast_slice(im.data()),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        });
        let read = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("test read-back"),
            size: planes.size(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut blender = LayerBlender::new(&device, &queue).expect("blender");
        let mut traffic = Vec::new();
        // Blended once per generation; the test passes one blend per
        // distinct picture, so repeated generations re-blend the same quads.
        let mut encoder = device.create_command_encoder(&Default::default());
        for &g in generations {
            traffic.push(
                blender
                    .record(
                        &mut encoder,
                        &planes,
                        (w as u32, h as u32, (w * h) as u32),
                        quads,
                        g,
                    )
                    .expect("recorded"),
            );
        }
        encoder.copy_buffer_to_buffer(&planes, 0, &read, 0, planes.size());
        queue.submit([encoder.finish()]);
        nedrt_gpu::map_and_wait(&device, &read).expect("mapped");
        let data = nedrt_gpu::read_mapped(&read, |b| bytemuck::cast_slice::<u8, f32>(b).to_vec())
            .expect("read");
        (Image::rgb(w, h, data), traffic)
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_device_blend_equals_the_cpu_twin_within_one_code() {
        // 131×67: rows not a multiple of a workgroup; quads overlapping,
        // at the edges, in mixed z and submission order.
        let (w, h) = (131usize, 67usize);
        let projection = Image::rgb(
            w,
            h,
            (0..3 * w * h)
                .map(|i| ((i * 7919) % 1000) as f32 / 999.0)
                .collect(),
        );
        let v = view(w, h);
        let texels = |layer: u32, qw: usize, qh: usize| -> Vec<f32> {
            (0..qw * qh)
                .flat_map(|t| {
                    let a = ((t * 37 + layer as usize * 11) % 256) as f32 / 255.0;
                    let c = |k: usize| a * (((t * 13 + k * 71) % 101) as f32 / 100.0);
                    [c(0), c(1), c(2), a]
                })
                .collect()
        };
        let layer = |layer, z, x, y, qw, qh| QuadLayer {
            layer,
            z,
            placement: Placement::Pixels { x, y },
            width: qw,
            height: qh,
            rgba: texels(layer, qw, qh),
        };
        let quads: Vec<PlacedQuad> = [
            layer(4, 2, 20, 10, 60, 30),
            layer(1, -3, 0, 0, 131, 67),
            layer(9, 2, 50, 25, 81, 42),
            layer(2, 7, 0, 60, 5, 7),
        ]
        .iter()
        .map(|q| q.place(&v).expect("placed"))
        .collect();
        let mut cpu = projection.clone();
        blend(&mut cpu, &quads).expect("blends");
        let (gpu, traffic) = on_device(&projection, &quads, &[5]);
        let transfer = Transfer::from_gamma([2.2, 2.2, 2.2]);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        transfer.encode_rgba8(&cpu, &mut a);
        transfer.encode_rgba8(&gpu, &mut b);
        let worst = a
            .iter()
            .zip(&b)
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap_or(0);
        assert!(worst <= 1, "codes differ by {worst}");
        let max_f32 = cpu
            .data()
            .iter()
            .zip(gpu.data())
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        assert!(max_f32 < 1e-5, "linear values differ by {max_f32}");
        let texel_bytes: usize = quads.iter().map(|q| 4 * q.rgba.len()).sum();
        assert!(traffic[0].to_device_bytes as usize >= texel_bytes);
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn texels_go_up_once_per_generation_and_hand_made_cases_hold() {
        let v = view(3, 1);
        let quads = vec![
            quad(3, 5, 1, 0, (1, 1), 0.9, 1.0)
                .place(&v)
                .expect("placed"),
            quad(7, -1, 0, 0, (3, 1), 0.25, 0.5)
                .place(&v)
                .expect("placed"),
        ];
        // Two blends of the same generation: the second uploads only the
        // uniform, and blends again (0.25 + 0.5·(0.25 + 0.5·1) = 0.625).
        let (gpu, traffic) = on_device(&grey(3, 1, 1.0), &quads, &[1, 1]);
        assert_eq!(traffic[1].uploads, 1);
        assert!(traffic[0].uploads > traffic[1].uploads);
        assert_eq!(gpu.plane(0), &[0.625, 0.9, 0.625]);
        let mut cpu = grey(3, 1, 1.0);
        blend(&mut cpu, &quads).expect("blends");
        blend(&mut cpu, &quads).expect("blends");
        assert_eq!(cpu.plane(0), gpu.plane(0));
    }
}

#[test]
fn a_layer_set_keeps_the_newest_submission_of_each_layer_of_each_owner() {
    let v = view(4, 4);
    let set = LayerSet::default();
    let any = usize::MAX;
    let placed = |layer, z, x| {
        quad(layer, z, x, 0, (1, 1), 0.1, 1.0)
            .place(&v)
            .expect("placed")
    };
    let g0 = set.snapshot().generation;
    set.set(1, placed(5, 0, 0), any).expect("set");
    // The same layer id from another owner is another layer.
    set.set(2, placed(5, 1, 1), any).expect("set");
    // A newer submission replaces owner 1's layer 5.
    set.set(1, placed(5, 3, 2), any).expect("set");
    let snap = set.snapshot();
    assert!(snap.generation > g0);
    assert_eq!(snap.quads.len(), 2);
    assert_eq!(
        snap.quads.iter().map(|q| (q.z, q.x)).collect::<Vec<_>>(),
        vec![(1, 1), (3, 2)],
        "in blending order"
    );
    // Unchanged: the same snapshot, the same generation.
    assert_eq!(set.snapshot().generation, snap.generation);
    assert!(set.remove(2, 5));
    assert!(!set.remove(2, 5));
    assert_eq!(set.remove_owner(1), 1);
    assert!(set.snapshot().quads.is_empty());
}

#[test]
fn a_layer_set_caps_quads_per_view_per_owner_and_in_texels() {
    let v = view(4, 4);
    let set = LayerSet::default();
    let placed = |layer| {
        quad(layer, 0, 0, 0, (2, 2), 0.0, 0.0)
            .place(&v)
            .expect("placed")
    };
    for i in 0..MAX_QUADS_PER_OWNER as u32 {
        set.set(9, placed(i), usize::MAX).expect("room");
    }
    let e = set
        .set(9, placed(99), usize::MAX)
        .expect_err("one owner's cap");
    assert!(e.to_string().contains("8 of one client"), "{e}");
    // Replacing one of its own is no new quad.
    set.set(9, placed(0), usize::MAX).expect("replaced");
    for i in 0..(MAX_QUADS - MAX_QUADS_PER_OWNER) as u32 {
        set.set(7, placed(i), usize::MAX).expect("room");
    }
    assert!(set.set(6, placed(0), usize::MAX).is_err(), "the view's cap");
    // The texel budget counts what the set would hold after the change.
    let small = LayerSet::default();
    small.set(1, placed(0), 8).expect("4 of 8");
    small.set(1, placed(0), 8).expect("replacing: still 4 of 8");
    small.set(2, placed(0), 8).expect("8 of 8");
    let e = small.set(3, placed(0), 8).expect_err("12 of 8");
    assert!(e.to_string().contains("12 texels; at most 8"), "{e}");
}

#[test]
fn directions_behind_the_eye_are_refused_and_slack_colour_is_held_to_alpha() {
    let v = view(100, 60);
    let mut q = quad(1, 0, 0, 0, (2, 2), 0.0, 0.0);
    for (x_deg, y_deg) in [(180.0, 0.0), (0.0, -90.0), (1e30, 0.0)] {
        q.placement = Placement::Degrees { x_deg, y_deg };
        let e = q.place(&v).expect_err("behind").to_string();
        assert!(e.contains("not in front of the eye"), "{e}");
    }
    // Colour over alpha within the 8-bit slack: accepted, held to alpha.
    let glow = quad(1, 0, 0, 0, (1, 1), 0.0015, 0.0)
        .place(&v)
        .expect("within the slack");
    assert_eq!(&glow.rgba[..], &[0.0, 0.0, 0.0, 0.0]);
    let mut im = grey(100, 60, 1.0);
    blend(&mut im, &[glow]).expect("blends");
    assert!(im.data().iter().all(|&x| x <= 1.0));
}

#[test]
fn a_view_region_fits_a_panel_only_when_inside_and_not_empty() {
    let [left, right] = ViewRegion::side_by_side(75, 21);
    assert_eq!((left.width, right.x, right.width), (37, 37, 38));
    assert!(left.fits((75, 21)) && right.fits((75, 21)));
    assert!(!right.fits((74, 21)));
    let empty = ViewRegion { width: 0, ..left };
    assert!(!empty.fits((75, 21)));
    let far = ViewRegion {
        x: usize::MAX,
        ..left
    };
    assert!(!far.fits((75, 21)));
}
