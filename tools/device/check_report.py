"""The device check's report.md (tools/device/check.py writes it beside
summary.json): each step's status, then every table the steps brought back,
each naming the device and the commit, in the order docs/benchmarks.md
quotes them."""

import statistics

import timelines


def report(steps: dict, meta: dict) -> str:
    head = f"{meta['device']}, commit {meta['commit']}{' (+ local changes)' if meta.get('dirty') else ''}"
    md = [f"# Device check: {head}", "",
          f"Mode {meta['mode']}, {meta['date']}; `bash scripts/device-check.sh"
          f"{' --smoke' if meta['mode'] == 'smoke' else ''}{meta.get('call_flag', '')}`. Steps:", "",
          "| step | status | seconds | cap s | note |", "| --- | --- | --- | --- | --- |"]
    for s in steps.values():
        md.append(f"| {s.name} | {s.status} | {s.seconds:.1f} | {s.cap_s:.0f} | {s.note.replace('|', '/')} |")
    records = lambda name, kind: [x for x in getattr(steps.get(name), "records", []) if x.get("kind") == kind]
    text = lambda name: getattr(steps.get(name), "text", "")
    adapter = next(iter(records("setup", "adapter")), None)
    if adapter:
        name = adapter.get("name") or adapter.get("describe")
        md += ["", f"Adapter ({head}): {name}; cooperative matrices (M×N×K A·B→C): "
                   f"{adapter.get('cooperative_matrices_text', 'not reported')}; wgpu's "
                   f"EXPERIMENTAL_COOPERATIVE_MATRIX: "
                   f"{'offered' if adapter.get('cooperative_matrix_feature') else 'not offered'}."]
    ceil = next(iter(records("ceilings", "ceilings")), None)
    if ceil:
        rate = lambda k: "–" if ceil.get(k) is None else f"{ceil[k]:.1f}"
        md += ["", f"Ceilings ({head}): device copy {ceil['copy_gbps']:.0f} GB/s (read + write), GEMM "
                   f"{rate('f32_gemm_tflops')} TFLOP/s in f32 (TF32 off), {rate('tf32_gemm_tflops')} in TF32, "
                   f"{rate('f16_gemm_tflops')} in f16."]
    md += dcnn_table(records("wgsl", "dcnn_latency"), records("torch", "dcnn_latency"), head)
    if text("per-layer"):
        md += ["", f"## Per layer ({head})", "", "GPU time from timestamp queries, each layer in a pass of its "
               "own, against its CUDA-core floor and, on cooperative matrices, its tensor-core floor.",
               text("per-layer")]
    if text("fft"):
        md += ["", f"## The prefilters' DCT filter ({head})", "", text("fft")]
        for x in getattr(steps.get("fft"), "records", []):
            if x.get("backend") == "torch.fft":
                md.append(f"\ntorch.fft (mirror, rfft2, gain, irfft2) {x['width']}×{x['height']}: "
                          f"{x['median_s'] * 1e3:.3f} ms median on {x['device']}.")
    for network, name in (("refine10", "refine:10"), ("admm3", "admm:3"), ("admm10", "admm:10")):
        solver = next((x for x in records("pipeline", "pipeline") if x.get("network") == network), None)
        if solver:
            ms = lambda v: "–" if v is None else f"{v:.1f}"
            md += ["", f"## {name} per frame ({head})", "",
                   f"{solver['width']}×{solver['height']} on the {solver['frame_path']} path: GPU p50 "
                   f"{ms(solver.get('gpu_p50_ms'))} ms a frame (timestamps), end to end p50 "
                   f"{ms(solver.get('e2e_p50_ms'))} ms; {solver['presented']} shown, {solver['dropped']} dropped."]
    if text("pipeline"):
        md += ["", f"## The pipeline end to end ({head})", "", text("pipeline")]
        md += pacing_target(records("pipeline", "pipeline"), head)
        md += frame_budget(records("pipeline", "pipeline"), head)
        md += warm_up(records("pipeline", "frame_log"), head)
        steady = timelines.table(records("pipeline", "frame_log"))
        if steady:
            md += ["", f"The steady state ({head}): each case's frames after its 20th, from the frame logs "
                   "(tools/device/timelines.py; docs/benchmarks.md says what each column is).", "", *steady]
        split = timelines.overhead(records("pipeline", "frame_log"))
        if split:
            md += ["", f"Where the preprocess stage's own time goes beyond its stages ({head}; issue 56, "
                   "item 5): the host's recording, the device's work beyond the stages (uploads' copies, "
                   "unpacks, layers, encodes), and the submission's and the fence's latency, p50 ms.", "", *split]
    if text("openxr"):
        md += ["", f"## The OpenXR runtime ({head})", "", "The openxr crate's client through libnedrt_openxr.so "
               "into nedrt run --stereo --sink headless (docs/openxr.md): the copy-out of each view on the "
               "application's queue, its send to the service, and how the display times held.", "", text("openxr")]
    if text("tune"):
        table = next((x["file"] for x in records("tune", "tuning_table")), None)
        md += ["", f"## The conv tiles tuned ({head})", "", "nedrt bench tune on the shipped model (docs/tuning.md): "
               "each conv shape (register-tiled, and on cooperative matrices where the GPU has them) at the "
               "heuristics' tile and at the fastest, GPU time per layer."
               + (f" The table, {table}, is beside this report: commit it as tuning/{table}." if table else ""),
               text("tune")]
    if text("tradeoff"):
        md += ["", f"## Speed against accuracy with the GPU's rows ({head})", "",
               "tradeoff.md, .json, .svg and .png beside this report; the table:", "", text("tradeoff")]
    md += training(records("train", "train"), head)
    return "\n".join(md) + "\n"


def frame_budget(rows: list, head: str) -> list:
    """Issue 54's side-by-side table: each case on the device path, shown,
    dropped, late, end to end p50 and p99 and the quality delivered (the
    tradeoff table's for a fixed case, the levels' weighted by their frames
    for `auto`), then each `auto` case's frames per level. Nothing where no
    row has the quality (older binaries)."""
    rows = [x for x in rows if x.get("frame_path") == "device" and "quality_db" in x]
    if not rows:
        return []
    ms = lambda v: "–" if v is None else f"{v:.2f}"
    out = ["", f"The frame budget, side by side ({head}; issue 54: `auto` picks each frame's level; quality: "
           "mean PSNR vs sharp over 0–2.5 D).", "",
           "| case | views | shown | dropped | late | e2e p50 ms | e2e p99 ms | quality dB |",
           "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    levels = []
    for x in rows:
        out.append(f"| {x['network']} | {x.get('views', 1)} | {x.get('presented', 0)} | {x.get('dropped', 0)} | "
                   f"{x.get('late', 0)} | {ms(x.get('e2e_p50_ms'))} | {ms(x.get('e2e_p99_ms'))} | "
                   f"{ms(x.get('quality_db'))} |")
        budget = x.get("frame_budget")
        if budget:
            run = ", ".join(f"{lv['name']} {lv['frames']}" + (f" ({lv['left_late']} left late)"
                                                               if lv.get("left_late") else "")
                            for lv in budget.get("levels", []))
            dropped = budget.get("dropped") or []
            levels.append(f"- {x['network']}, {x.get('views', 1)} view(s): budget {budget['budget_ms']:.2f} ms; "
                          f"{run}" + (f"; left out: {', '.join(dropped)}" if dropped else ""))
    return out + ([""] + levels if levels else [])


def pacing_target(rows: list, head: str) -> list:
    """Issue 39's device line, case by case, for every case of the step on
    the device path (the line names no network and the shipped model, one
    view and two; the others stand beside them): end to end p50 within one
    refresh and no frame dropped, where the GPU time fits a refresh (two
    views: the eyes' p50s summed, their stages sharing one submission). A
    case that showed nothing, or whose network fell back (the bench's
    fallback is the frame itself: fast, and not the network), is not met.
    Rows without the refresh rate (older binaries) are left out. Beside the
    GPU's time: the preprocess stage's wall p50 (submission to fence) and its
    host part before the submission (record), where the rows have them."""
    out = []
    for x in rows:
        hz, p50 = x.get("refresh_hz"), x.get("e2e_p50_ms")
        if x.get("frame_path") != "device" or not hz or p50 is None:
            continue
        period = 1e3 / hz
        views = x.get("views", 1)
        eyes = [e["p50_ms"] for e in x.get("eyes", []) if str(e.get("stage", "")).startswith("preprocess view")]
        gpu = sum(eyes) if views > 1 and eyes else (x.get("gpu_p50_ms") or 0.0)
        if not x.get("presented"):
            met = "no (nothing shown)"
        elif x.get("dcnn_failures", 0) > 0 or not str(x.get("path_detail", "device")).startswith("device"):
            met = "no (fell back to the host or the fallback)"
        elif gpu >= period:
            met = "– (GPU time over a refresh)"
        else:
            met = "yes" if p50 <= period and x.get("dropped", 0) == 0 else "no"
        stage = {s.get("stage"): s for s in x.get("stages", []) if s.get("count")}
        wall = lambda name: f"{stage[name]['p50_ms']:.2f}" if name in stage else "–"
        out.append(f"| {x['network']} | {views} | {x.get('precision', 'f32')} | {x['width']}×{x['height']} | "
                   f"{period:.2f} | {gpu:.2f} | {wall('preprocess')} | {wall('preprocess-record')} | "
                   f"{p50:.2f} | {x.get('dropped', 0)} | {met} |")
    if not out:
        return []
    return ["", f"Issue 39's target ({head}): end to end p50 within one refresh and 0 dropped, for every case "
            "whose GPU time fits a refresh (the line names none and model, one view and two).", "",
            "| case | views | precision | panel | refresh ms | GPU p50 ms (two views: the eyes' summed) | "
            "stage p50 ms | of it recorded on the host ms | e2e p50 ms | dropped | met |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |", *out]


def warm_up(logs: list, head: str) -> list:
    """The warm-up case by case, from the frame logs (column by column): the
    first frame's preprocess stage (less any hold) and its GPU part against
    the medians of the frames after the tenth, and how many frames were
    replaced in the present slot in the first second and after it. A log
    without the GPU column (older binaries) shows "–" there."""
    def median(v):
        v = [x for x in v if x is not None]
        return statistics.median(v) if v else None
    ms = lambda v: "–" if v is None else f"{v:.2f}"
    out = []
    for x in logs:
        f = x.get("frames") or {}
        ids = f.get("id") or []
        if not ids:
            continue
        n = len(ids)
        gpu = f.get("gpu_ms") or [None] * n
        stage = [b[1][1] - b[1][0] - held for b, held in zip(f["stages_ms"], f["held_ms"])]
        order = sorted(range(n), key=lambda i: ids[i])
        first, rest = order[0], order[10:]
        t0 = min(f["submitted_ms"])
        replaced = [f["submitted_ms"][i] - t0 for i in range(n) if f["outcome"][i] == "replaced"]
        out.append(f"| {x['network']} | {x['views']} | {x['precision']} | {ms(stage[first])} | {ms(gpu[first])} | "
                   f"{ms(median(stage[i] for i in rest))} | {ms(median(gpu[i] for i in rest))} | "
                   f"{sum(t < 1e3 for t in replaced)} | {sum(t >= 1e3 for t in replaced)} |")
    if not out:
        return []
    return ["", f"The warm-up ({head}): each case's first frame against the frames after its tenth "
            "(docs/service.md, \"The warm-up\"), from the frame logs.", "",
            "| case | views | precision | first frame: preprocess ms | of it GPU ms | after the 10th: preprocess "
            "ms (median) | of it GPU ms | replaced in the first second | replaced after it |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |", *out]


def dcnn_table(wgsl: list, torch_rows: list, head: str) -> list:
    """nedrt's WGSL (wall and GPU time, per conv path) against PyTorch."""
    if not (wgsl or torch_rows):
        return []
    md = ["", f"## The D-CNN, nedrt's WGSL against PyTorch ({head})", "",
          "Wall: the host's view of a frame (upload, network, read-back, checks); GPU: the network's own time "
          "(timestamps); PyTorch: CUDA events around the network. Ratios against PyTorch at the same precision.",
          "", "| model | backend | precision | conv path | frame | wall median ms | GPU median ms | GMAC/s (GPU) | "
          "wall ÷ PyTorch | GPU ÷ PyTorch |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    ms = lambda v: "–" if v is None else f"{v * 1e3:.2f}"
    for x in wgsl + torch_rows:
        ratio = ["", ""]
        if x["backend"] == "wgpu":
            twin = "f32" if x["precision"] == "f32" else "f16"
            t = next((y for y in torch_rows if y["model"] == x["model"] and y["precision"] == twin
                      and (y["width"], y["height"]) == (x["width"], x["height"])), None)
            if t:
                ratio[0] = f"{x['median_s'] / t['median_s']:.2f}"
                if x.get("gpu_median_s") is not None:
                    ratio[1] = f"{x['gpu_median_s'] / t['median_s']:.2f}"
        rate = x.get("gpu_gmac_per_s") if x["backend"] == "wgpu" else x.get("gmac_per_s")
        md.append(f"| {x['model']} | {x['backend']} | {x['precision']} | {x.get('conv_path') or '–'} | "
                  f"{x['width']}×{x['height']} | {ms(x['median_s'])} | "
                  f"{ms(x.get('gpu_median_s') if x['backend'] == 'wgpu' else x['median_s'])} | "
                  f"{gmacs(rate)} | {ratio[0]} | {ratio[1]} |")
    return md


def gmacs(rate) -> str:
    """A GPU's rate whole, a CPU's (the smoke) with its first digits."""
    return "–" if rate is None else f"{rate:.0f}" if rate >= 100 else f"{rate:.3g}"


def training(rows: list, head: str) -> list:
    tr = next(iter(rows), None)
    if not tr:
        return []
    v = tr["validation"][0] if tr["validation"] else {}
    fmt = lambda k: f"{v[k]:.2f}" if isinstance(v.get(k), (int, float)) else "–"
    started = tr.get("started") or {}
    if "checkpoint" in started:
        n = started["sessions"]
        origin = (f"Continued `{started['checkpoint']}` from step {started['step']} ({n} session{'s' if n != 1 else ''} "
                  f"before this one): step {tr['steps']} now, batch {tr['batch']}, {tr['seconds']:.0f} s of "
                  f"training in all, this session's on {tr['device']}. ")
    else:
        origin = (f"Started fresh ({started.get('fresh', 'no checkpoint')}): {tr['steps']} steps of batch "
                  f"{tr['batch']} in {tr['seconds']:.0f} s on {tr['device']}. ")
    back = tr.get("checkpoint")
    carried = (f"The continued checkpoint came back as `{back['file']}` with its card (step {back['step']}, "
               f"{back['mib']} MiB, Adam's moments: {back['moments']}; docs/training.md says how to commit it). "
               if back else "")
    return ["", f"## The full-width D-CNN trained on the device ({head})", "",
            f"{origin}{carried}Validation (the trainer's, on data/images/val):", "",
            "| | mean / worst vs target dB | mean / worst vs sharp dB |", "| --- | --- | --- |",
            f"| D-CNN | {fmt('dcnn_mean_db')} / {fmt('dcnn_worst_db')} | "
            f"{fmt('dcnn_sharp_mean_db')} / {fmt('dcnn_sharp_worst_db')} |",
            f"| its Wiener | {fmt('wiener_mean_db')} / {fmt('wiener_worst_db')} | "
            f"{fmt('wiener_sharp_mean_db')} / {fmt('wiener_sharp_worst_db')} |"]
