"""PyTorch side of `nedrt bench inference`: the trainer's U-Net (random
weights; latency does not depend on them) at the same frame sizes, on CUDA
when present (f32 with TF32 off, TF32, f16 channels-last; cuDNN's benchmark
mode picks each convolution's algorithm) else on the CPU (f32). Prints
JSON lines like the Rust bench. `--ceilings` instead measures the device's
two ceilings (a device-to-device copy, bytes read plus written; GEMMs in
f32 with TF32 off, TF32 and f16) for the floors of `nedrt bench inference
--per-layer` (scripts/device-check.sh passes them on). Needs the trainer installed
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


def ceilings(copy_mb: int, n: int, repeat: int):
    """The copy bandwidth (GB/s, read + write) and the GEMM rates (TFLOP/s)
    on random data, medians of `repeat` timed runs after a warm-up."""
    cuda = torch.cuda.is_available()
    dev = torch.device("cuda" if cuda else "cpu")
    src = torch.rand(copy_mb * (1 << 20) // 4, device=dev)
    dst = torch.empty_like(src)
    med, _ = timed(lambda: dst.copy_(src), repeat, cuda)
    rec = {"kind": "ceilings", "device": torch.cuda.get_device_name() if cuda else "CPU",
           "copy_gbps": 2 * src.numel() * 4 / med / 1e9, "copy_mb": copy_mb, "gemm_n": n, "torch": torch.__version__}
    for mode, dtype, tf32 in (("f32", torch.float32, False), ("tf32", torch.float32, True),
                              ("f16", torch.float16, False)):
        if dtype == torch.float16 and not cuda:
            rec[f"{mode}_gemm_tflops"] = None
            continue
        torch.backends.cuda.matmul.allow_tf32 = tf32
        a, b = torch.rand(n, n, device=dev, dtype=dtype), torch.rand(n, n, device=dev, dtype=dtype)
        med, _ = timed(lambda: a @ b, repeat, cuda)
        rec[f"{mode}_gemm_tflops"] = 2 * n ** 3 / med / 1e12
    torch.backends.cuda.matmul.allow_tf32 = False
    print(json.dumps(rec), flush=True)


def fft_filter(sizes: str, repeat: int):
    """The prefilters' transform in PyTorch (cuFFT on CUDA): each of three
    planes mirrored to 2w×2h, rfft2, times a real gain, irfft2, cropped:
    what `nedrt bench fft` times on the device as DCT-II · gain · DCT-III."""
    cuda = torch.cuda.is_available()
    dev = torch.device("cuda" if cuda else "cpu")
    for size in sizes.split(","):
        w, h = map(int, size.split("x"))
        x = torch.rand(3, h, w, device=dev)
        gain = torch.rand(3, 2 * h, w + 1, device=dev)

        def run():
            m = torch.cat([x, x.flip(-1)], dim=-1)
            m = torch.cat([m, m.flip(-2)], dim=-2)
            return torch.fft.irfft2(torch.fft.rfft2(m) * gain, s=(2 * h, 2 * w))[..., :h, :w]

        med, mn = timed(run, repeat, cuda)
        print(json.dumps({"kind": "fft_filter", "backend": "torch.fft", "width": w, "height": h,
                          "device": torch.cuda.get_device_name() if cuda else "CPU", "median_s": med,
                          "min_s": mn, "repeat": repeat, "torch": torch.__version__}), flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="512x512,1920x1080")
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--threads", type=int, default=0, help="CPU threads (0: torch default)")
    ap.add_argument("--peak-tflops", default="", help="f32,tf32,f16 dense peaks of the GPU")
    ap.add_argument("--ceilings", action="store_true", help="measure the copy bandwidth and GEMM rates instead")
    ap.add_argument("--copy-mb", type=int, default=2048, help="--ceilings: the copied buffer, MiB")
    ap.add_argument("--gemm", type=int, default=8192, help="--ceilings: the GEMMs' n (n×n by n×n)")
    ap.add_argument("--fft", action="store_true", help="time the prefilters' FFT filter (torch.fft) instead")
    args = ap.parse_args()
    if args.fft:
        fft_filter(args.sizes, args.repeat)
        return
    if args.ceilings:
        ceilings(args.copy_mb, args.gemm, args.repeat)
        return
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
                # f16 in channels-last, the layout cuDNN's tensor-core kernels take.
                layout = torch.channels_last if mode == "f16" else torch.contiguous_format
                m = (net.half() if mode == "f16" else net.float()).to(memory_format=layout)
                xi = (x.half() if mode == "f16" else x).contiguous(memory_format=layout)

                def run():
                    with torch.inference_mode():
                        return m.forward_padded(xi).clamp_(0, 1)

                med, mn = timed(run, args.repeat, cuda)
                flops = 2 * macs * w * h
                rec = {
                    "kind": "dcnn_latency", "model": model_name, "macs_per_pixel": macs,
                    "backend": "pytorch", "device": name, "precision": mode,
                    "layout": "channels_last" if mode == "f16" else "nchw",
                    "width": w, "height": h, "median_s": med, "min_s": mn, "repeat": args.repeat,
                    "gmac_per_s": macs * w * h / med / 1e9, "torch": torch.__version__,
                }
                if mode in peaks:
                    rec["fraction_of_peak"] = flops / med / (peaks[mode] * 1e12)
                print(json.dumps(rec), flush=True)


if __name__ == "__main__":
    main()
