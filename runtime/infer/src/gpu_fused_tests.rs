//! Fused levels (`shaders/conv_fused.wgsl`) on a real adapter (lavapipe in
//! CI): every level that can run fused, at the tiles it takes, computes
//! its two layers' unfused output bit for bit, and the CPU twin's within
//! the precision's tolerance, at frame sizes no tile divides; a table's
//! fused levels are followed where fusing was faster, and only there.

mod needs_gpu {
    use std::collections::HashMap;
    use std::sync::Arc;

    use crate::gpu::codegen::fused::FusedTile;
    use crate::gpu::tuning::{AdapterKey, TileSource, TunedFused, TuningTable};
    use crate::gpu::{ConvSupport, GpuBackend};
    use crate::gpu_tests::{conv, gpu_device, info, tolerance};
    use crate::network::{Layer, Network};
    use crate::synth::{self, SplitMix};
    use crate::tests::{max_abs_diff, model_from, random_frame};
    use crate::{ConvPath, Precision, reference};

    const TILE_8X8: FusedTile = FusedTile {
        width: 8,
        height: 8,
    };

    /// Pairs the U-Nets do not have: a 3×3 then a 5×5 into the residual
    /// and clamp, over 6 channels (not a quad's multiple); a 1×1 then a
    /// 3×3 over 20 channels (two blocks of 16), then a third conv, which
    /// the first pair has taken.
    fn pairs() -> Vec<(&'static str, Network, usize)> {
        let mut rng = SplitMix::new(7);
        let mut a = conv(&mut rng, 0, 1, 3, 6, 3);
        a.relu = true;
        let mut b = conv(&mut rng, 1, 2, 6, 3, 5);
        b.residual = Some(0);
        let mut c = conv(&mut rng, 0, 1, 3, 20, 1);
        c.relu = true;
        let mut d = conv(&mut rng, 1, 2, 20, 7, 3);
        d.relu = true;
        let mut e = conv(&mut rng, 2, 3, 7, 3, 3);
        e.residual = Some(0);
        let net = |layers: Vec<Layer>, values| Network {
            layers,
            values,
            output: 0,
            multiple: 1,
            macs_per_pixel: 0.0,
            clamped: true,
        };
        vec![
            (
                "3×3 3→6, 5×5 6→3 + residual + clamp",
                Network {
                    output: 2,
                    ..net(
                        vec![Layer::Conv(a), Layer::Conv(b)],
                        vec![info(3, 0), info(6, 0), info(3, 0)],
                    )
                },
                1,
            ),
            (
                "1×1 3→20, 3×3 20→7, 3×3 7→3 + residual + clamp",
                Network {
                    output: 3,
                    ..net(
                        vec![Layer::Conv(c), Layer::Conv(d), Layer::Conv(e)],
                        vec![info(3, 0), info(20, 0), info(7, 0), info(3, 0)],
                    )
                },
                1,
            ),
        ]
    }

    /// U-Nets of 3 and 4 levels (intermediates of 4 to 64 channels): each
    /// level's two convolutions, encoder and decoder, 2L − 1 pairs.
    fn unets() -> Vec<(&'static str, Network, usize)> {
        [("U-Net 4×3", 4, 3, 21), ("U-Net 8×4", 8, 4, 22)]
            .into_iter()
            .map(|(name, width, levels, seed)| {
                let model = model_from(&synth::unet(width, levels, seed), "random.onnx");
                (
                    name,
                    model.lower().expect("lowers"),
                    2 * levels as usize - 1,
                )
            })
            .collect()
    }

    /// `gpu` at every tile of `tiles` (each level that takes it), against
    /// its unfused output bit for bit and the CPU twin within `tol`.
    fn fused_equals_unfused(
        name: &str,
        gpu: &mut GpuBackend,
        net: &Network,
        (w, h): (usize, usize),
        tiles: &[FusedTile],
        tol: f32,
    ) {
        let frame = random_frame(w, h, (w * h) as u64);
        gpu.force_fused(HashMap::new());
        let levels = gpu.fused_levels(w, h);
        assert!(
            levels
                .iter()
                .all(|l| l.tile.is_none() && l.source == TileSource::Heuristic),
            "{name}: unfused without a table"
        );
        let unfused = gpu.run_tensor(frame.data(), w, h).expect("runs");
        let dispatches = gpu.dispatches();
        let twin = reference::run(net, frame.data(), h, w);
        for &tile in tiles {
            let forced: HashMap<usize, FusedTile> = levels
                .iter()
                .filter(|l| gpu.fused_candidates(l).contains(&tile))
                .map(|l| (l.layer, tile))
                .collect();
            if forced.is_empty() {
                continue;
            }
            gpu.force_fused(forced.clone());
            assert!(
                gpu.fused_levels(w, h)
                    .iter()
                    .all(|l| l.tile == forced.get(&l.layer).copied())
            );
            let got = gpu.run_tensor(frame.data(), w, h).expect("runs fused");
            // One dispatch a fused level, where its two layers had two.
            assert_eq!(
                gpu.dispatches() + forced.len(),
                dispatches,
                "{name} {tile:?}"
            );
            let differ = got
                .iter()
                .zip(&unfused)
                .filter(|(a, b)| a.to_bits() != b.to_bits())
                .count();
            assert_eq!(got.len(), unfused.len());
            assert_eq!(
                differ,
                0,
                "{name} {w}×{h} {tile:?} on layers {:?}: {differ} values differ from unfused",
                forced.keys()
            );
            let d = max_abs_diff(&twin, &got);
            assert!(d <= tol, "{name} {w}×{h} {tile:?}: {d} from the CPU twin");
        }
        gpu.force_fused(HashMap::new());
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn every_fused_level_is_its_two_layers_bit_for_bit() {
        let [t8x8, t16x8, t8x16, t16x16, t32x8, t32x16] =
            [(8, 8), (16, 8), (8, 16), (16, 16), (32, 8), (32, 16)]
                .map(|(width, height)| FusedTile { width, height });
        let every = [t8x8, t16x8, t8x16, t16x16, t32x8, t32x16];
        // f32 at every tile on the 20-channel pair and three on the small
        // U-Net; f16 storage summed in f32 (lavapipe's own choice) and f16
        // arithmetic (the GPUs' kernels, forced here) at fewer: each tile
        // of each level, and each register-tiled tile of each frame size,
        // is a kernel lavapipe takes seconds to compile. Sizes no tile
        // divides: every level's edge tiles are ragged, and at 6×50 a
        // single column of tiles wider than the frame.
        let (pairs, unets) = (self::pairs(), unets());
        let nets: Vec<_> = pairs.iter().chain(&unets).collect();
        let big = [(37, 21)];
        let both = [(37, 21), (6, 50)];
        let unet = [(40, 24)];
        let ends = vec![t8x8, t32x16];
        type Case<'a> = (usize, &'a [(usize, usize)], Vec<FusedTile>);
        let configs: [(Precision, bool, Vec<Case>); 3] = [
            (
                Precision::F32,
                false,
                vec![
                    (0, &big, ends.clone()),
                    (1, &both, every.to_vec()),
                    (2, &unet, vec![t8x8, t16x8, t32x16]),
                    (3, &unet, vec![t16x8]),
                ],
            ),
            (Precision::F16, false, vec![(1, &big, ends.clone())]),
            (
                Precision::F16,
                true,
                vec![(1, &both, ends.clone()), (2, &unet, vec![t16x8])],
            ),
        ];
        for (precision, f16_math, cases) in configs {
            let (device, queue) = gpu_device(precision);
            let support = ConvSupport {
                f16_arithmetic: f16_math,
                ..ConvSupport::of_device(&device, ConvPath::Tiled)
            };
            let tol = tolerance(precision);
            for (i, sizes, tiles) in cases {
                let (name, net, pairs) = nets[i];
                let mut gpu = GpuBackend::new_with(
                    &device,
                    &queue,
                    "test".into(),
                    net,
                    precision,
                    support.clone(),
                )
                .expect("builds");
                for &(w, h) in sizes {
                    assert_eq!(
                        gpu.fused_levels(w, h).len(),
                        *pairs,
                        "{name}: levels that can run fused"
                    );
                    let name = format!("{name} {precision:?} f16 math {f16_math}");
                    fused_equals_unfused(&name, &mut gpu, net, (w, h), &tiles, tol);
                }
            }
        }
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn a_tables_fused_levels_are_followed_where_fusing_was_faster() {
        let (name, net, _) = unets().remove(0);
        let (w, h) = (40, 24);
        let (device, queue) = gpu_device(Precision::F32);
        let mut gpu =
            GpuBackend::new(&device, &queue, "test".into(), &net, Precision::F32).expect("builds");
        let frame = random_frame(w, h, 5);
        let want = gpu.run_tensor(frame.data(), w, h).expect("runs");
        let levels = gpu.fused_levels(w, h);
        // Every level's shape at 8×8; the first level's fused kernel was
        // slower, so it stays unfused.
        let fused: Vec<TunedFused> = levels
            .iter()
            .enumerate()
            .map(|(i, l)| TunedFused {
                shape: l.shape,
                tile_width: 8,
                tile_height: 8,
                fused_ns: if i == 0 { 3 } else { 1 },
                unfused_ns: 2,
            })
            .collect();
        let mut table = TuningTable::new(AdapterKey::of(&gpu.adapter_info()), vec![], vec![]);
        table.merge_fused(fused);
        let mut gpu = gpu.with_tuning(Some(Arc::new(table)));
        let tuned = gpu.fused_levels(w, h);
        assert_eq!(tuned.len(), levels.len());
        for (i, l) in tuned.iter().enumerate() {
            if i == 0 {
                assert_eq!((l.tile, l.source), (None, TileSource::Heuristic), "{l:?}");
            } else {
                assert_eq!(
                    (l.tile, l.source),
                    (Some(TILE_8X8), TileSource::Tuned),
                    "{l:?}"
                );
            }
        }
        let got = gpu.run_tensor(frame.data(), w, h).expect("runs");
        assert_eq!(
            got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            "{name}: the table's fused levels change the output"
        );
        // The tuner's forced tiles go over the table's.
        gpu.force_fused(HashMap::from([(levels[0].layer, TILE_8X8)]));
        assert_eq!(gpu.fused_levels(w, h)[0].source, TileSource::Forced);
        // Another frame size's levels are not in the table.
        gpu.force_fused(HashMap::new());
        assert!(gpu.fused_levels(2 * w, h).iter().all(|l| l.tile.is_none()));
    }
}
