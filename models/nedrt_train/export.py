"""Exports: the D-CNN as ONNX (opset 17, input `image` and output `display`,
both 1×3×H×W float32 with dynamic H and W, the residual add inside the
graph) and the DOE as a height-map file in the format of docs/doe-format.md
(safetensors, tensor `height_um`, metadata), at the design pitch and
resampled (Keys bicubic, a = −½, like the Rust side) to the fabrication pitch."""
import json
import math
from pathlib import Path

import numpy as np
import torch

from .keys import keys_profile, keys_weight


def export_onnx(net: torch.nn.Module, path, opset: int = 17):
    net = net.eval()
    x = torch.rand(1, 3, 64, 64)
    torch.onnx.export(
        net, (x,), str(path), dynamo=False, opset_version=opset,
        input_names=["image"], output_names=["display"],
        dynamic_axes={"image": {2: "height", 3: "width"}, "display": {2: "height", 3: "width"}},
    )


def resample(height: np.ndarray, pitch_m: float, new_pitch_m: float, max_height_m: float) -> np.ndarray:
    """Keys bicubic resampling of a centred square grid onto a grid of
    `new_pitch_m` covering the same extent, clamped to [0, max]."""
    n = height.shape[0]
    half = (n - 1) / 2 * pitch_m
    m = 2 * math.floor(half / new_pitch_m + 1e-9) + 1
    u = (np.arange(m) - (m - 1) / 2) * new_pitch_m / pitch_m + (n - 1) / 2
    base = np.floor(u)
    f = u - base
    idx = np.stack([np.clip(base + k, 0, n - 1).astype(int) for k in (-1, 0, 1, 2)], axis=1)
    w = np.stack([keys_weight(1 + f), keys_weight(f), keys_weight(1 - f), keys_weight(2 - f)], axis=1)
    along_s = (height[:, idx] * w[None, :, :]).sum(axis=2)          # n × m
    out = (along_s[idx, :] * w[:, :, None]).sum(axis=1)             # m × m
    return np.clip(out, 0, max_height_m)


def save_doe(path, height_m: np.ndarray, pitch_m: float, max_height_m: float, material: str,
             design_wavelength_m: float, description: str, levels: int = 0):
    """A DOE file: a 2-D map (N×N, centred) or, for a 1-D array, a radial
    profile with samples at (n + ½)·pitch (docs/doe-format.md)."""
    from safetensors.numpy import save_file
    height_m = np.asarray(height_m)
    if height_m.ndim not in (1, 2):
        raise ValueError(f"{path}: a DOE is a radial profile (1-D) or a square map (2-D), not {height_m.shape}")
    meta = {
        "format": "nedrt-doe", "version": "1",
        "pitch_um": repr(pitch_m * 1e6), "max_height_um": repr(max_height_m * 1e6),
        "levels": str(levels), "material": material,
        "design_wavelength_nm": repr(design_wavelength_m * 1e9), "description": description,
        "profile": "radial" if height_m.ndim == 1 else "map",
    }
    tmp = Path(str(path) + ".tmp")
    save_file({"height_um": (np.asarray(height_m) * 1e6).astype(np.float32)}, str(tmp), metadata=meta)
    tmp.replace(path)


def sha256(path) -> str:
    import hashlib
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def export_run(run: Path, out: Path, name: str, calib=None) -> dict:
    """From a training run (checkpoint.pt, result.json) write `out/dcnn-NAME.onnx`,
    the DOE at the design and fabrication pitches, and `out/card-NAME.json`.
    The calibration is `calib` or, when None, the file the run recorded in
    its config (an error naming it if it is gone)."""
    import dataclasses
    import platform

    from . import calib as calib_mod
    from .optics import grid
    from .radial import radial_nodes
    from .train import System, config_from_saved

    state = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=False)
    cfg = config_from_saved(state["config"])
    if calib is not None:
        cfg = dataclasses.replace(cfg, calib=str(calib))
    elif cfg.calib is None or not Path(cfg.calib).is_file():
        raise FileNotFoundError(f"{cfg.calib}: the calibration recorded by {run / 'checkpoint.pt'} is not a file; "
                                "pass --calib FILE")
    cal = calib_mod.load(cfg.calib)
    system = System(cfg, cal)
    system.load_state_dict(state["system"])
    out.mkdir(parents=True, exist_ok=True)
    onnx_path = out / f"dcnn-{name}.onnx"
    export_onnx(system.net, onnx_path)
    height = system.optics.doe().detach().double().numpy()
    design = out / f"doe-{name}-design.safetensors"
    fab = out / f"doe-{name}-fabrication.safetensors"
    lam0 = cal.channels[cal.design_channel].wavelength_m
    desc = f"nedrt_train run {run.name}, step {state['step']}"
    save_doe(design, height, cal.doe_design_pitch_m, cal.doe_max_height_m, "fused silica", lam0, desc)
    if height.ndim == 1:
        fab_rho, _ = radial_nodes(cal.aperture_radius_m, cal.doe_fabrication_pitch_m)
        fine = keys_profile(height, cal.doe_design_pitch_m, fab_rho, cal.doe_max_height_m)
        how = " (Keys cubic to the fabrication pitch)"
    else:
        fine = resample(height, cal.doe_design_pitch_m, cal.doe_fabrication_pitch_m, cal.doe_max_height_m)
        how = " (bicubic)"
    save_doe(fab, fine, cal.doe_fabrication_pitch_m, cal.doe_max_height_m, "fused silica", lam0, desc + how)
    result = json.loads((run / "result.json").read_text()) if (run / "result.json").exists() else {}
    card = {
        "name": name, "config": dataclasses.asdict(cfg), "seed": cfg.seed, "steps": state["step"],
        "wall_time_s": result.get("seconds"), "validation": result.get("validation"),
        "hardware": {"platform": platform.platform(), "processor": platform.processor(), "torch": torch.__version__,
                     "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None},
        "parameters": sum(p.numel() for p in system.net.parameters()),
        "macs_per_pixel": system.net.macs_per_pixel(),
        "files": {p.name: sha256(p) for p in [onnx_path, design, fab]},
        "doe_profile": cfg.doe_profile,
        "grid_points": len(height) if height.ndim == 1 else len(grid(cal, cal.doe_design_pitch_m)),
    }
    (out / f"card-{name}.json").write_text(json.dumps(card, indent=1))
    return card


def main(argv=None, prog=None):
    import argparse

    from . import calib as calib_mod
    from .data import resolve_root
    ap = argparse.ArgumentParser(prog=prog, description="Export a training run: ONNX, DOE files, model card.")
    ap.add_argument("--run", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=Path("models"),
                    help="folder for the files (default: models under the current directory)")
    ap.add_argument("--name", required=True)
    ap.add_argument("--calib", metavar="FILE", help="calibration TOML (default: the one the run was trained with)")
    ap.add_argument("--displays", type=Path, help="also write the D-CNN outputs for the test photographs (--images's test/) here (16-bit PNG), for nedrt eval --display-dir")
    ap.add_argument("--images", metavar="DIR",
                    help="image root whose test/ --displays reads (default: data/images under the current directory)")
    args = ap.parse_args(argv)
    try:
        calib = calib_mod.resolve(args.calib) if args.calib is not None else None
        images = resolve_root(args.images) if args.displays else None
        files = export_run(args.run, args.out, args.name, calib)["files"]
    except (ValueError, FileNotFoundError) as e:
        raise SystemExit(f"error: {e}")
    print(json.dumps(files, indent=1))
    if args.displays:
        from .train import config_from_saved
        from .unet import UNet
        state = torch.load(args.run / "checkpoint.pt", map_location="cpu", weights_only=False)
        cfg = config_from_saved(state["config"])
        net = UNet(cfg.width, cfg.levels)
        net.load_state_dict({k[len("net."):]: v for k, v in state["system"].items() if k.startswith("net.")})
        for p in write_displays(net, images / "test", args.displays):
            print("wrote", p)



def write_png16(path, rgb: np.ndarray):
    """An RGB image in [0, 1] (H×W×3) as a 16-bit PNG (Pillow cannot write
    16-bit RGB): signature, IHDR, one zlib IDAT of filter-0 rows, IEND."""
    import struct
    import zlib
    h, w, _ = rgb.shape
    raw = (np.clip(rgb, 0, 1) * 65535 + 0.5).astype(">u2")
    rows = b"".join(b"\x00" + raw[y].tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(rows, 6)) + chunk(b"IEND", b""))
    tmp = Path(str(path) + ".tmp")
    tmp.write_bytes(png)
    tmp.replace(path)


@torch.no_grad()
def write_displays(net: torch.nn.Module, images_dir: Path, out_dir: Path) -> list:
    """The clamped D-CNN output (the panel's [0, 1]) for every PNG in
    `images_dir`, cropped to multiples of 8 like `nedrt eval`, as 16-bit PNGs
    of the same names in `out_dir`."""
    from PIL import Image
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for p in sorted(images_dir.glob("*.png")):
        img = np.asarray(Image.open(p).convert("RGB"), dtype=np.float32) / 255
        h, w = img.shape[0] // 8 * 8, img.shape[1] // 8 * 8
        x = torch.from_numpy(np.ascontiguousarray(img[:h, :w])).permute(2, 0, 1)[None]
        display = net.eval().forward_padded(x).clamp(0, 1)[0].permute(1, 2, 0).numpy()
        write_png16(out_dir / p.name, display)
        written.append(out_dir / p.name)
    return written


if __name__ == "__main__":
    main()
