use super::*;
use std::path::PathBuf;

fn opts() -> RunOptions {
    RunOptions {
        preprocess: Method::Proposed,
        prefilter: nedrt_stages::preprocess::Prefilter::Native,
        ladder: None,
        ladder_quality: None,
        ladder_networks: Vec::new(),
        source: SourceKind::Pattern,
        input: None,
        socket: PathBuf::from("/tmp/nedrt.sock"),
        shm_dir: PathBuf::from("/dev/shm"),
        frames: None,
        source_rate_hz: None,
        sink: SinkKind::Window,
        record_dir: PathBuf::from("frames"),
        window: Default::default(),
        fallback: FallbackKind::Cpu,
        frame_path: FramePath::Device,
        panel_size: None,
        report_json: None,
        inject_device_loss_after: None,
        stereo: false,
    }
}

fn whole(w: usize, h: usize) -> Vec<ViewFacts> {
    vec![ViewFacts {
        name: "panel".into(),
        region: ViewRegion {
            x: 0,
            y: 0,
            width: w,
            height: h,
        },
        design: None,
    }]
}

fn gpu() -> Probe {
    Probe::Adapter {
        name: "test GPU".into(),
        shader_f16: true,
    }
}

fn network() -> Option<NetworkFacts> {
    Some(NetworkFacts {
        path: "models/dcnn.onnx".into(),
        behind_wiener_k: Some(0.01),
        unrolled_steps: None,
    })
}

fn inputs(opts: &RunOptions, views: Vec<ViewFacts>, probe: Probe) -> PlanInputs<'_> {
    PlanInputs {
        opts,
        panel: (1920, 1080, 90.0),
        views,
        network: network(),
        backend: BackendKind::Wgpu,
        precision: Precision::F16,
        probe,
        ladder: None,
    }
}

#[test]
fn the_default_run_keeps_frames_on_the_sinks_gpu() {
    let o = opts();
    let p = plan(&inputs(&o, whole(1920, 1080), gpu())).expect("plan");
    assert_eq!(p.path, PlannedPath::Device);
    assert_eq!(p.views.len(), 1);
    assert_eq!(
        p.views[0].stages,
        [
            "upload as sent, unpack on the GPU",
            "quad layers blended on the GPU",
            "Wiener prefilter of proposed (K = 1.000e-2) on the GPU",
            "D-CNN on the GPU",
            "clamp to [0, 1] and the panel's transfer curve on the GPU",
            "the sink copies the codes on the GPU",
        ]
    );
    assert_eq!(p.network, "models/dcnn.onnx: wgpu on the sink's GPU, f16");
    assert!(p.pacing.starts_with("paced by the display"), "{}", p.pacing);
    assert!(p.source.contains("just in time"), "{}", p.source);
    let text = p.to_string();
    assert!(
        text.contains("frame path: device, because the sink has a GPU"),
        "{text}"
    );
}

#[test]
fn each_reason_for_the_host_is_named() {
    let mut o = opts();
    o.frame_path = FramePath::Host;
    let p = plan(&inputs(&o, whole(64, 48), gpu())).expect("plan");
    assert_eq!(
        (p.path, p.path_reason.as_str()),
        (PlannedPath::Host, "--frame-path host")
    );
    // The network on the sink's GPU all the same, its output read back.
    assert_eq!(
        p.network,
        "models/dcnn.onnx: wgpu on the sink's GPU, f16, its output read back to the host"
    );

    let o = opts();
    let p = plan(&inputs(
        &o,
        whole(64, 48),
        Probe::Missing("no Vulkan ICD".into()),
    ))
    .expect("plan");
    assert_eq!(p.path, PlannedPath::Host);
    assert_eq!(p.path_reason, "no GPU adapter (no Vulkan ICD)");
    assert_eq!(p.adapter, "none: no Vulkan ICD");

    let mut o = opts();
    o.sink = SinkKind::Record;
    let p = plan(&inputs(&o, whole(64, 48), Probe::NotNeeded)).expect("plan");
    assert_eq!(p.path_reason, "the record sink takes frames in host memory");
    assert!(p.pacing.starts_with("just in time"), "{}", p.pacing);

    let o = opts();
    let mut i = inputs(&o, whole(64, 48), gpu());
    i.backend = BackendKind::Cpu;
    let p = plan(&i).expect("plan");
    assert_eq!(
        p.path_reason,
        "the network runs on the cpu backend, on the host"
    );

    let o = opts();
    let mut i = inputs(
        &o,
        whole(64, 48),
        Probe::Adapter {
            name: "old".into(),
            shader_f16: false,
        },
    );
    i.precision = Precision::F16;
    assert_eq!(plan(&i).expect("plan").path, PlannedPath::Host);
    i.precision = Precision::F32;
    assert_eq!(plan(&i).expect("plan").path, PlannedPath::Device);
}

#[test]
fn two_views_each_get_their_stage_chain() {
    let mut o = opts();
    o.stereo = true;
    o.preprocess = Method::DoeWiener;
    let [left, right] = ViewRegion::side_by_side(1920, 1080);
    let views = vec![
        ViewFacts {
            name: "left".into(),
            region: left,
            design: Some("designs/a".into()),
        },
        ViewFacts {
            name: "right".into(),
            region: right,
            design: None,
        },
    ];
    let mut i = inputs(&o, views, gpu());
    i.network = None;
    let p = plan(&i).expect("plan");
    assert_eq!(p.path, PlannedPath::Device);
    assert!(
        p.path_reason
            .contains("every view's unpack, layers, stages and encode"),
        "{}",
        p.path_reason
    );
    assert_eq!(p.views[0].name, "left");
    assert_eq!(p.views[0].stages[0], "upload as sent, unpack on the GPU");
    assert_eq!(
        p.views[0].stages[2],
        "Wiener prefilter of doe+wiener (design designs/a) on the GPU"
    );
    assert_eq!(
        p.views[1].stages[2],
        "Wiener prefilter of doe+wiener on the GPU"
    );
    assert!(p.panel.ends_with("2 views"), "{}", p.panel);
    assert_eq!(p.network, "none (--preprocess doe+wiener has no network)");
    let text = p.to_string();
    assert!(
        text.contains("view \"right\" 960×1080 at (960, 0): upload as sent, unpack on the GPU"),
        "{text}"
    );
}

#[test]
fn a_conventional_run_has_no_network_and_no_prefilter_stage() {
    let mut o = opts();
    o.preprocess = Method::Conventional;
    o.sink = SinkKind::Headless;
    o.source_rate_hz = Some(60.0);
    let mut i = inputs(&o, whole(64, 48), gpu());
    i.network = None;
    let p = plan(&i).expect("plan");
    assert_eq!(p.path, PlannedPath::Device);
    assert_eq!(p.views[0].stages.len(), 4, "{:?}", p.views[0].stages);
    assert_eq!(p.fallback, "none needed (no network)");
    assert_eq!(p.source, "the test pattern at 60 Hz on its own timer");
    assert!(p.pacing.starts_with("just in time"), "{}", p.pacing);
}

#[test]
fn a_prefilter_the_device_lacks_runs_on_the_host_before_the_upload() {
    // `optimal` has no device stage: one view keeps the device path, with
    // the prefilter on the host first.
    let mut o = opts();
    o.preprocess = Method::DoeWiener;
    o.prefilter = "optimal".parse().expect("prefilter");
    let mut i = inputs(&o, whole(64, 48), gpu());
    i.network = None;
    let p = plan(&i).expect("plan");
    assert_eq!(p.path, PlannedPath::Device);
    assert_eq!(
        p.views[0].stages,
        [
            "decode on the host",
            "quad layers blended on the host",
            "optimal@target prefilter of doe+wiener on the host",
            "its planes uploaded",
            "clamp to [0, 1] and the panel's transfer curve on the GPU",
            "the sink copies the codes on the GPU",
        ]
    );
    // A network's Wiener on a side of prime 17: the Wiener on the host,
    // the network on the GPU.
    let o = opts();
    let p = plan(&inputs(&o, whole(68, 48), gpu())).expect("plan");
    assert_eq!(p.path, PlannedPath::Device);
    assert_eq!(p.views[0].stages[0], "decode on the host");
    assert!(
        p.views[0].stages[2].ends_with("on the host"),
        "{:?}",
        p.views[0].stages
    );
    assert_eq!(p.views[0].stages[3], "its planes uploaded");
    assert_eq!(p.views[0].stages[4], "D-CNN on the GPU");
    // Two views, one of them 34 wide: the same decision as one view's, in
    // each view: the device path, that view's prefilter on the host first.
    let views = vec![
        ViewFacts {
            name: "left".into(),
            region: ViewRegion {
                x: 0,
                y: 0,
                width: 34,
                height: 48,
            },
            design: None,
        },
        ViewFacts {
            name: "right".into(),
            region: ViewRegion {
                x: 34,
                y: 0,
                width: 30,
                height: 48,
            },
            design: None,
        },
    ];
    let mut o = opts();
    o.preprocess = Method::DoeWiener;
    let mut i = inputs(&o, views, gpu());
    i.network = None;
    let p = plan(&i).expect("plan");
    assert_eq!(p.path, PlannedPath::Device);
    assert_eq!(p.views[0].stages[0], "decode on the host");
    assert_eq!(
        p.views[0].stages[2],
        "Wiener prefilter of doe+wiener on the host"
    );
    assert_eq!(p.views[1].stages[0], "upload as sent, unpack on the GPU");
    assert_eq!(
        p.views[1].stages[2],
        "Wiener prefilter of doe+wiener on the GPU"
    );
    // An injected device loss needs a device stage in every view to fail.
    let mut o = o.clone();
    o.inject_device_loss_after = Some(3);
    let mut i = inputs(&o, i.views.clone(), gpu());
    i.network = None;
    let p = plan(&i).expect("plan");
    assert_eq!(
        (p.path, p.path_reason.as_str()),
        (
            PlannedPath::Host,
            "the injected device loss needs a stage on the device to fail"
        )
    );
}

/// `--preprocess auto`: what the device cannot run is a level left out
/// with its reason, not every level sent to the host.
#[test]
fn a_ladder_leaves_out_what_the_device_cannot_run_and_keeps_the_device_path() {
    use crate::ladder::{LadderInputs, LadderSpec, NetworkLevel, QualityTable};
    let o = opts();
    let network = |name: &str, unrolled| NetworkLevel {
        name: name.into(),
        hash: format!("{name} hash"),
        unrolled,
    };
    let ladder = || LadderInputs {
        spec: LadderSpec::default(),
        table: QualityTable::default(),
        doe_hash: "d".into(),
        design: None,
        networks: vec![network("unrolled-k1", true), network("dcnn", false)],
    };
    let mut i = inputs(&o, whole(1920, 1080), gpu());
    i.backend = BackendKind::Cpu;
    i.ladder = Some(ladder());
    let p = plan(&i).expect("plan");
    assert_eq!(p.path, PlannedPath::Device);
    let l = p.ladder.as_ref().expect("a ladder");
    let left_out: Vec<(&str, &str)> = l
        .levels
        .iter()
        .filter_map(|l| l.left_out.as_deref().map(|why| (l.name.as_str(), why)))
        .collect();
    let on_host = "the network runs on the cpu backend, on the host";
    assert_eq!(left_out, [("unrolled-k1", on_host), ("dcnn", on_host)]);
    assert!(
        p.views[0].stages[2].starts_with(
            "the frame budget's level (none < wiener < admm:1 < admm:3 < admm:10) on the GPU"
        ),
        "{:?}",
        p.views[0].stages
    );
    // A side the device FFT lacks (a prime factor over 13) leaves out the
    // prefilter levels and the unrolled model's (its steps are the FFT's);
    // none and the D-CNN stay.
    let mut i = inputs(&o, whole(17 * 8, 48), gpu());
    i.ladder = Some(ladder());
    let p = plan(&i).expect("plan");
    let kept: Vec<&str> = p
        .ladder
        .as_ref()
        .expect("a ladder")
        .levels
        .iter()
        .filter(|l| l.left_out.is_none())
        .map(|l| l.name.as_str())
        .collect();
    assert_eq!(kept, ["none", "dcnn"]);
    let text = p.to_string();
    assert!(text.contains("quality: not known"), "{text}");
    assert!(
        text.contains("  wiener     left out: the device FFT takes no"),
        "{text}"
    );
    assert!(text.contains("unrolled-k1"), "{text}");
    // On the GPU with the device's backend every network is a level.
    let mut i = inputs(&o, whole(1920, 1080), gpu());
    i.ladder = Some(ladder());
    let p = plan(&i).expect("plan");
    let names: Vec<&str> = p.levels.iter().map(|l| l.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "none",
            "wiener",
            "admm:1",
            "admm:3",
            "admm:10",
            "unrolled-k1",
            "dcnn"
        ]
    );
    assert!(
        p.levels
            .iter()
            .any(|l| l.name == "unrolled-k1" && l.rung == crate::ladder::Rung::Network(0))
    );
}
