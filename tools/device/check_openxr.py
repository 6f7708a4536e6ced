"""The device check's OpenXR step (issue 40, docs/openxr.md): the `openxr`
crate's client renders through libnedrt_openxr.so and the OpenXR loader
into `nedrt run --stereo --source socket --sink headless` on the GPU, and
the runtime's summary gives the copy-out per view, the send, and how the
predicted display times held; the service's report gives the frames shown
at their display time. On the smoke (CI, lavapipe) the same on the small
panel. `--prepare` carries the runtime, the client and the Debian loader
(libopenxr-loader1 and its libjsoncpp25) in .devcheck/openxr/."""
import json
import re
import signal
import statistics
import subprocess
import time

from check_runner import CARRY, REPO, Failed, Runner, Step, apt_download, strip_and_pack, unpack

#: Debian's OpenXR loader and what it links beyond the C and C++ runtimes.
XR_PACKAGES = ["libopenxr-loader1", "libjsoncpp25"]
#: What travels, built here by `--prepare`: (built path, carried name).
XR_FILES = [("target/release/libnedrt_openxr.so", "libnedrt_openxr.so.xz"),
            ("target/release/examples/openxr_client", "openxr_client.xz")]


def prepare_openxr() -> dict:
    """Builds the runtime and the client, strips and packs them into
    .devcheck/openxr/, with the loader packages; what it carries."""
    dest = CARRY / "openxr"
    dest.mkdir(parents=True, exist_ok=True)
    subprocess.run(["cargo", "build", "--release", "-p", "nedrt-openxr", "--lib", "--examples"], cwd=REPO,
                   check=True)
    for built, name in XR_FILES:
        strip_and_pack(REPO / built, dest / name).unlink()
    apt_download(dest, XR_PACKAGES)
    return {"openxr": sorted(p.name for p in dest.iterdir())}


def runtime_files(r: Runner) -> tuple:
    """The runtime library, the client and the environment that finds the
    loader, unpacked from what travels: .devcheck/openxr/ on the device;
    on the smoke, built and packed here first, so that the smoke unpacks
    them as the device does (the loader extracted beside them when the
    machine lacks it)."""
    env = {}
    packed = CARRY / "openxr"
    if r.smoke:
        r.sh(["cargo", "build", "--release", "-p", "nedrt-openxr", "--lib", "--examples"], 1800, parse_json=False)
        packed = r.work / "openxr-packed"
        packed.mkdir(exist_ok=True)
        for built, name in XR_FILES:
            strip_and_pack(REPO / built, packed / name).unlink()
    lib, client = [unpack(packed / name, r.work / name.removesuffix(".xz")) for _, name in XR_FILES]
    libs = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True).stdout
    if "libopenxr_loader.so.1" not in libs:
        debs = sorted((CARRY / "openxr").glob("*.deb"))
        if not debs:
            raise Failed("no OpenXR loader here and none carried (apt-get install libopenxr-loader1, or --prepare)")
        root = r.work / "xr-root"
        for deb in debs:
            r.sh(["dpkg", "-x", deb, root], 30, parse_json=False)
        found = sorted(root.rglob("libopenxr_loader.so.1"))
        if not found:
            raise Failed(f"{root}: the loader package holds no libopenxr_loader.so.1")
        env["LD_LIBRARY_PATH"] = ":".join([str(found[0].parent), r.env.get("LD_LIBRARY_PATH", "")]).rstrip(":")
    return lib, client, env


SUMMARY = re.compile(r"(\d+) frames sent; the service predicted the display time xrWaitFrame gave for (\d+), a later "
                     r"refresh for (\d+), an earlier one for (\d+); copy-out: (\d+) images, ([\d.]+) ms each on "
                     r"average \(([\d.]+) Mtexel/s\); sending a view to the service: ([\d.]+) ms")


def step_openxr(r: Runner, s: Step, z: dict):
    r.need_gpu_adapter()
    lib, client, env = runtime_files(r)
    work = r.work / "openxr"
    work.mkdir(exist_ok=True)
    manifest = work / "nedrt_openxr.json"
    manifest.write_text(json.dumps({"file_format_version": "1.0.0",
                                    "runtime": {"name": "nedrt", "library_path": str(lib)}}))
    sock, report_json, client_json = work / "nedrt.sock", work / "report.json", work / "client.json"
    calib = ["--calib", str(REPO / "tests/data/small-panel.toml")] if r.smoke else []
    service_cmd = [str(r.nedrt), *calib, "run", "--stereo", "--preprocess", "conventional", "--source", "socket",
                   "--socket", str(sock), "--sink", "headless", "--report-json", str(report_json)]
    s.commands.append(" ".join(service_cmd) + " &")
    r.say(f"$ {' '.join(service_cmd)} &")
    log = open(work / "service.log", "w")
    service = subprocess.Popen(service_cmd, cwd=REPO, env=r.env, stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 30
        while not sock.exists():
            if service.poll() is not None or time.monotonic() > deadline:
                raise Failed(f"the service did not listen: {(work / 'service.log').read_text()[-400:]}")
            time.sleep(0.1)
        r.sh([client, "--frames", z["frames"], "--report", client_json], s.cap_s,
             env={**env, "XR_RUNTIME_JSON": str(manifest), "NEDRT_SOCKET": str(sock)}, parse_json=False)
    finally:
        if service.poll() is None:
            service.send_signal(signal.SIGTERM)
        try:
            service.wait(timeout=30)
        except subprocess.TimeoutExpired:
            service.kill()
        log.close()
    r.log.write((work / "service.log").read_text())
    # The runtime's summary is on the client's stderr, which r.sh logged.
    logged = (r.out / "log.txt").read_text()
    m = None
    for m in SUMMARY.finditer(logged):
        pass
    if m is None:
        raise Failed("no summary line from the runtime (nedrt-openxr: N frames sent; …) in the log")
    frames, same, later, earlier, copies, copy_ms, mtexel, send_ms = m.groups()
    c = json.loads(client_json.read_text())
    ends = sorted(c["end_frame_ms"])
    rec = {"kind": "openxr", "views": c["view_sizes"], "frames": int(frames), "predicted_as_service": int(same),
           "service_later": int(later), "service_earlier": int(earlier), "copies": int(copies),
           "copy_ms": float(copy_ms), "copy_mtexel_s": float(mtexel), "send_ms": float(send_ms),
           "end_frame_ms_median": statistics.median(ends), "end_frame_ms_p10": ends[len(ends) // 10],
           "end_frame_ms_p90": ends[9 * len(ends) // 10]}
    if report_json.is_file():
        for cl in json.loads(report_json.read_text()).get("clients", []):
            if cl.get("client", 0) > 0:
                rec.update({"shown": cl["shown"], "on_time": cl["on_time"], "late": cl["late"],
                            "early": cl["early"]})
    s.records.append(rec)
    (w, h) = rec["views"][0]
    s.text = (f"| views | copy-out a view | throughput | send a view | xrEndFrame median (p10–p90) | predicted as "
              f"the service did | shown at their display time |\n| --- | --- | --- | --- | --- | --- | --- |\n"
              f"| 2 × {w}×{h} | {rec['copy_ms']:.3f} ms | {rec['copy_mtexel_s']:.0f} Mtexel/s | "
              f"{rec['send_ms']:.3f} ms | {rec['end_frame_ms_median']:.2f} ms ({rec['end_frame_ms_p10']:.2f}–"
              f"{rec['end_frame_ms_p90']:.2f}) | {rec['predicted_as_service']} of {rec['frames']} | "
              f"{rec.get('on_time', '?')} of {rec.get('shown', '?')} ({rec.get('late', '?')} late, "
              f"{rec.get('early', '?')} early) |\n")
