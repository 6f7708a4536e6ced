"""Each loss term against a hand-computed case, SSIM against scikit-image,
the U-Net's shape, size and residual, and its ONNX export round trip."""
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from nedrt_train import calib as calib_mod
from nedrt_train.loss import ALPHA, GAMMA, dark_channel, loss_terms, ssim, total
from nedrt_train.unet import UNet

REPO = Path(__file__).resolve().parents[2]


def test_ssim_matches_scikit_image():
    golden = json.loads((REPO / "tests/golden/metrics.json").read_text())
    for case in golden["cases"]:
        h, w = case["height"], case["width"]
        a = torch.tensor(case["a"], dtype=torch.float64).reshape(1, 3, h, w)
        b = torch.tensor(case["b"], dtype=torch.float64).reshape(1, 3, h, w)
        assert abs(ssim(a, b).item() - case["ssim"]) < 1e-9


def test_l1_and_range_by_hand():
    t = torch.zeros(1, 3, 16, 16)
    p = torch.full((1, 3, 16, 16), 0.25)
    d = torch.zeros(1, 3, 16, 16)
    d[0, 0, 0, 0] = 1.5   # 0.5 over the top
    d[0, 1, 0, 0] = -0.2  # 0.2 under the bottom
    terms = loss_terms(t, p, d)
    assert terms["l1"].item() == pytest.approx(0.25)
    assert terms["range"].item() == pytest.approx(0.7 / (3 * 256))


def test_dark_channel_by_hand():
    x = torch.ones(1, 3, 20, 20)
    x[0, 2, 10, 10] = 0.1  # one dark blue pixel
    j = dark_channel(x)
    assert j[0, 0, 10, 10].item() == pytest.approx(0.1)
    assert j[0, 0, 2, 2].item() == pytest.approx(0.1), "within 8 pixels: inside the 17×17 window"
    assert j[0, 0, 1, 1].item() == pytest.approx(1.0), "9 pixels away: outside"
    # R_dark weights the perceived dark channel by exp(−β J(target)).
    t = torch.zeros(1, 3, 20, 20)
    terms = loss_terms(t, x, torch.zeros_like(x))
    assert terms["dark"].item() == pytest.approx(dark_channel(x).mean().item())


def test_total_weights():
    terms = {k: torch.tensor(1.0) for k in ["l1", "ssim", "dark", "range"]}
    assert total(terms).item() == pytest.approx(2 + ALPHA + GAMMA)


def test_unet_shape_size_and_residual():
    net = UNet()
    n = sum(p.numel() for p in net.parameters())
    assert 1.9e6 < n < 2.0e6, n  # 1.93 M parameters for 32–256
    x = torch.rand(2, 3, 24, 40)
    assert net(x).shape == x.shape
    # Residual: with the last layer zeroed, the network is the identity.
    with torch.no_grad():
        net.out.weight.zero_()
        net.out.bias.zero_()
    assert torch.equal(net(x), x)
    assert net.forward_padded(torch.rand(1, 3, 21, 19)).shape == (1, 3, 21, 19)
    assert UNet().macs_per_pixel() == 140_736  # ≈ 141 k multiply-adds per pixel (issue 4)


def test_onnx_export_round_trip(tmp_path):
    ort = pytest.importorskip("onnxruntime")
    torch.manual_seed(0)
    net = UNet(width=8).eval()
    path = tmp_path / "dcnn.onnx"
    from nedrt_train.export import export_onnx
    export_onnx(net, path)
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    for h, w in [(32, 32), (24, 48)]:
        x = torch.rand(1, 3, h, w)
        want = net(x).detach().numpy()
        got = sess.run(None, {"image": x.numpy()})[0]
        assert np.abs(got - want).max() <= 1e-4


def test_bicubic_reproduces_quadratics_and_doe_file_loads_in_nedrt(tmp_path):
    from nedrt_train.export import resample, save_doe
    n, p = 41, 1e-5
    s = (np.arange(n) - (n - 1) / 2) * p
    f = lambda x, y: 1.0 + 1e3 * x + 2e3 * y + 1e6 * x * x + 3e6 * x * y  # noqa: E731
    h = f(s[None, :], s[:, None])
    fine = resample(h, p, 0.37e-5, 10.0)
    m = fine.shape[0]
    t = (np.arange(m) - (m - 1) / 2) * 0.37e-5
    want = f(t[None, :], t[:, None])
    assert np.abs(fine - want)[5:-5, 5:-5].max() < 1e-12
    # A file the Rust loader accepts: `nedrt doe --doe FILE` validates it.
    import subprocess
    cal = calib_mod.load(REPO / "calib" / "default.toml")
    from nedrt_train.optics import grid, three_lens_init
    sg = grid(cal, cal.doe_design_pitch_m)
    height = three_lens_init(cal, sg).numpy()
    path = tmp_path / "doe.safetensors"
    save_doe(path, height, cal.doe_design_pitch_m, cal.wave_height_m, "fused silica",
             cal.channels[cal.design_channel].wavelength_m, "test")
    exe = REPO / "target" / "release" / "nedrt"
    if not exe.exists():
        pytest.skip("nedrt not built")
    out = subprocess.run([str(exe), "doe", "--doe", str(path), "--out-dir", str(tmp_path)], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    assert "1668×1668 at 6.000 µm" in out.stdout
