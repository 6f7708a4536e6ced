//! The tuner and its tables on a real adapter (lavapipe in CI): the tuned
//! tiles are followed, compute the heuristics' output bit for bit, and an
//! adapter without a table falls back to the heuristics.

mod needs_gpu {
    use std::collections::HashSet;
    use std::sync::Arc;

    use crate::gpu::GpuBackend;
    use crate::gpu::codegen::ConvTile;
    use crate::gpu::tuning::{AdapterKey, TileSource, TunedConv, TuningTable, candidate_tiles};
    use crate::gpu_tests::gpu_device;
    use crate::tests::random_frame;
    use crate::{BackendOptions, Precision};

    /// Each tile is a kernel lavapipe takes seconds to compile: a network
    /// of two conv shapes (3×3 3→10 and 1×1 16→3), and one tile besides
    /// the heuristics'.
    const OTHER: ConvTile = ConvTile {
        px: 1,
        threads_y: 4,
    };

    fn net() -> crate::Network {
        crate::gpu_tests::pool_upsample_net(1)
    }

    fn backend(options: &BackendOptions) -> GpuBackend {
        let net = net();
        let (device, queue) = gpu_device(options.precision);
        GpuBackend::with_options(&device, &queue, "test".into(), &net, options).expect("builds")
    }

    /// A table that gives every conv shape of `gpu` at `w`×`h` the tile
    /// `OTHER`, which is not the heuristics'.
    fn other_tiles(gpu: &GpuBackend, w: usize, h: usize) -> TuningTable {
        let mut convs: Vec<TunedConv> = Vec::new();
        for t in gpu.conv_tiles(w, h) {
            if convs.iter().any(|c| c.shape == t.shape) {
                continue;
            }
            let s = t.shape;
            assert!(candidate_tiles(s.width, s.height, s.kernel, s.arith.into()).contains(&OTHER));
            assert_ne!(t.tile, OTHER, "the heuristics' tile");
            let tile = OTHER;
            convs.push(TunedConv {
                shape: s,
                px: tile.px,
                threads_y: tile.threads_y,
                tuned_ns: 1,
                heuristic_ns: 1,
            });
        }
        TuningTable {
            adapter: AdapterKey::of(&gpu.adapter_info()),
            nedrt: "test".into(),
            template: crate::gpu::tuning::template_hash(),
            convs,
            coops: Vec::new(),
            fused: Vec::new(),
            ffts: Vec::new(),
        }
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn a_table_is_followed_and_computes_the_heuristics_output_bit_for_bit() {
        let (w, h) = (48, 40);
        let frame = random_frame(w, h, 3);
        for precision in [Precision::F32, Precision::F16] {
            let options = BackendOptions {
                precision,
                ..Default::default()
            };
            let mut gpu = backend(&options);
            let heuristic = gpu.conv_tiles(w, h);
            assert!(heuristic.iter().all(|t| t.source == TileSource::Heuristic));
            let want = gpu.run_tensor(frame.data(), w, h).expect("runs");
            let heuristic_kernels = gpu.kernels_built();
            let table = other_tiles(&gpu, w, h);
            let mut gpu = gpu.with_tuning(Some(Arc::new(table.clone())));
            let tuned = gpu.conv_tiles(w, h);
            let mut changed = 0;
            for (t, h0) in tuned.iter().zip(&heuristic) {
                assert_eq!(t.source, TileSource::Tuned, "layer {}", t.layer);
                assert_eq!(Some(t.tile), table.tile_for(&t.shape), "layer {}", t.layer);
                changed += usize::from(t.tile != h0.tile);
            }
            assert_eq!(changed, tuned.len(), "every tile is the table's");
            let got = gpu.run_tensor(frame.data(), w, h).expect("runs");
            // The frame ran on a plan made again: the table's tiles are
            // kernels of their own (each of the two conv kinds at OTHER).
            assert_eq!(gpu.kernels_built(), heuristic_kernels + 2, "{precision:?}");
            assert_eq!(got.len(), want.len());
            let differ = got
                .iter()
                .zip(&want)
                .filter(|(a, b)| a.to_bits() != b.to_bits())
                .count();
            assert_eq!(differ, 0, "{precision:?}: {differ} values differ");
            // Another frame size's layers are not in the table.
            assert!(
                gpu.conv_tiles(2 * w, h)
                    .iter()
                    .all(|t| t.source == TileSource::Heuristic)
            );
        }
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_tuner_times_every_candidate_and_keeps_the_fastest_per_shape() {
        let (w, h) = (48, 40);
        let options = BackendOptions::default();
        let mut gpu = backend(&options);
        let result = gpu
            .tune(&random_frame(w, h, 3), 1, Some(&[OTHER]))
            .expect("tunes");
        // Both conv kinds at both tiles, the pool and the transposed conv.
        assert_eq!(gpu.kernels_built(), 2 * 2 + 2);
        let shapes: HashSet<_> = gpu.conv_tiles(w, h).iter().map(|t| t.shape).collect();
        assert_eq!(result.convs.len(), shapes.len());
        // The heuristics' tile (32×16 at both shapes) and the other.
        assert_eq!(result.tiles_timed, 2);
        // Each tile's frame computed the heuristics' output.
        assert!(result.passed_over.is_empty(), "{:?}", result.passed_over);
        for c in &result.convs {
            let s = c.shape;
            let heuristic = ConvTile::for_layer(s.width, s.height, s.kernel, s.arith.into());
            assert!([heuristic, OTHER].contains(&c.tile()), "{c:?}");
            assert!(c.tuned_ns > 0 && c.tuned_ns <= c.heuristic_ns, "{c:?}");
            if c.tile() == heuristic {
                assert_eq!(c.tuned_ns, c.heuristic_ns);
            }
        }
        // The backend is left as it was: heuristics, no table.
        assert!(gpu.tuning().is_none());
        assert!(
            gpu.conv_tiles(w, h)
                .iter()
                .all(|t| t.source == TileSource::Heuristic)
        );
        // A tile whose output differs (a kernel bug, injected) is tried
        // layer by layer, named for each, and taken by no shape; the
        // others are tuned as before.
        gpu.fault_tile = Some(OTHER);
        let result = gpu
            .tune(&random_frame(w, h, 3), 1, Some(&[OTHER]))
            .expect("tunes, passing over the tile");
        assert!(!result.passed_over.is_empty());
        for line in &result.passed_over {
            assert!(
                line.starts_with("layer ")
                    && !line.contains("together")
                    && line.contains(": 1 of ")
                    && line.ends_with("passed over"),
                "{line}"
            );
        }
        assert_eq!(result.convs.len(), shapes.len());
        assert!(
            result.convs.iter().all(|c| c.tile() != OTHER),
            "{:?}",
            result.convs
        );
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_backend_reads_its_adapters_table_and_falls_back_without_one() {
        let (w, h) = (48, 40);
        let dir = tempfile::tempdir().expect("tempdir");
        let options = BackendOptions {
            tuning_dir: Some(dir.path().to_path_buf()),
            ..Default::default()
        };
        // An empty folder, then one with another adapter's table only.
        let gpu = backend(&options);
        assert!(gpu.tuning().is_none());
        let mut other = other_tiles(&gpu, w, h);
        other.adapter.name = "NVIDIA H200".into();
        other.adapter.vendor = 0x10de;
        other.save(dir.path()).expect("saves");
        let gpu = backend(&options);
        assert!(gpu.tuning().is_none());
        assert!(
            gpu.conv_tiles(w, h)
                .iter()
                .all(|t| t.source == TileSource::Heuristic)
        );
        // This adapter's table beside it is found and followed.
        let mine = other_tiles(&gpu, w, h);
        mine.save(dir.path()).expect("saves");
        let gpu = backend(&options);
        assert_eq!(gpu.tuning(), Some(&mine));
        let tiles = gpu.conv_tiles(w, h);
        assert!(tiles.iter().all(|t| t.source == TileSource::Tuned));
        assert!(tiles.iter().any(|t| t.tile
            != ConvTile::for_layer(
                t.shape.width,
                t.shape.height,
                t.shape.kernel,
                t.shape.arith.into()
            )));
        // A broken table stops the backend, naming the file.
        let path = dir.path().join(mine.adapter.file_name());
        std::fs::write(&path, "adapter = 3").expect("writes");
        let (device, queue) = gpu_device(Precision::F32);
        let e = GpuBackend::with_options(&device, &queue, "test".into(), &net(), &options)
            .expect_err("broken table")
            .to_string();
        assert!(e.contains(&path.display().to_string()), "{e}");
    }
}
