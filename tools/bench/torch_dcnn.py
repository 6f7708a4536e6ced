"""PyTorch side of `nedrt bench inference`: the trainer's U-Net (random
weights; latency does not depend on them) at the same frame sizes, on CUDA
when present (f32 with TF32 off, TF32, f16) else on the CPU (f32). Prints
JSON lines like the Rust bench. Needs the trainer installed
(`.venv/bin/pip install --no-build-isolation -e models`, which
scripts/test.sh does). Run from the repo root:

    .venv/bin/python tools/bench/torch_dcnn.py --sizes 512x512,1920x1080

On a GPU the numbers include the arithmetic limit: the network's FLOPs per
frame over the device's peak for that precision (--peak-tflops f32,tf32,f16).
"""
import argparse
import json
import statistics
import time

import torch

from nedrt_train.unet import UNet


def timed(fn, repeat, cuda):
    fn()  # warm-up: cuDNN algorithm choice, allocator
    if cuda:
        torch.cuda.synchronize()
    times = []
    for _ in range(repeat):
        if cuda:
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
            fn()
            end.record()
            torch.cuda.synchronize()
            times.append(start.elapsed_time(end) / 1e3)
        else:
            t = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t)
    return statistics.median(times), min(times)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="512x512,1920x1080")
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--threads", type=int, default=0, help="CPU threads (0: torch default)")
    ap.add_argument("--peak-tflops", default="", help="f32,tf32,f16 dense peaks of the GPU")
    args = ap.parse_args()
    cuda = torch.cuda.is_available()
    dev = torch.device("cuda" if cuda else "cpu")
    if args.threads:
        torch.set_num_threads(args.threads)
    name = torch.cuda.get_device_name() if cuda else f"CPU ({torch.get_num_threads()} threads)"
    peaks = dict(zip(["f32", "tf32", "f16"], map(float, args.peak_tflops.split(",")))) if args.peak_tflops else {}
    torch.backends.cudnn.benchmark = True
    for model_name, width in [("full", 32), ("half", 16)]:
        torch.manual_seed(0)
        net = UNet(width=width, levels=4).to(dev).eval()
        macs = net.macs_per_pixel()
        for size in args.sizes.split(","):
            w, h = map(int, size.split("x"))
            x = torch.rand(1, 3, h, w, device=dev)
            modes = ["f32", "tf32", "f16"] if cuda else ["f32"]
            for mode in modes:
                torch.backends.cudnn.allow_tf32 = mode == "tf32"
                torch.backends.cuda.matmul.allow_tf32 = mode == "tf32"
                m = net.half() if mode == "f16" else net.float()
                xi = x.half() if mode == "f16" else x

                def run():
                    with torch.inference_mode():
                        return m.forward_padded(xi).clamp_(0, 1)

                med, mn = timed(run, args.repeat, cuda)
                flops = 2 * macs * w * h
                rec = {
                    "kind": "dcnn_latency", "model": model_name, "macs_per_pixel": macs,
                    "backend": "pytorch", "device": name, "precision": mode,
                    "width": w, "height": h, "median_s": med, "min_s": mn, "repeat": args.repeat,
                    "gmac_per_s": macs * w * h / med / 1e9, "torch": torch.__version__,
                }
                if mode in peaks:
                    rec["fraction_of_peak"] = flops / med / (peaks[mode] * 1e12)
                print(json.dumps(rec), flush=True)


if __name__ == "__main__":
    main()
