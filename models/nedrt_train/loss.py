"""The training loss of docs/model.md §15 (SSIM as §16):

    E = L1(I_p, Î_p) + (1 − SSIM(I_p, Î_p)) + α R_dark + γ R_range
    R_dark  = mean(exp(−β J(I_p)) · J(Î_p)),  J = min over RGB and a 17×17 window
    R_range = mean(relu(I_d − 1) + relu(−I_d))
    α = 0.005, β = 10, γ = 150

SSIM is scikit-image's (Gaussian 11×11, σ = 1.5, K1 = 0.01, K2 = 0.03, data
range 1, population covariance, per channel, averaged over the windows
inside the frame), checked against tests/golden/metrics.json.
"""
import torch
import torch.nn.functional as F

ALPHA, BETA, GAMMA = 0.005, 10.0, 150.0
DARK_WINDOW = 17


def _gaussian(dtype, device, sigma=1.5, radius=5):
    x = torch.arange(-radius, radius + 1, dtype=dtype, device=device)
    g = torch.exp(-x ** 2 / (2 * sigma ** 2))
    return g / g.sum()


def ssim(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of (B, C, H, W) images, per image and channel, then averaged."""
    c = x.shape[1]
    g = _gaussian(x.dtype, x.device)
    gx = g.view(1, 1, 1, -1).expand(c, 1, 1, -1)
    gy = g.view(1, 1, -1, 1).expand(c, 1, -1, 1)

    def blur(t):
        return F.conv2d(F.conv2d(t, gx, groups=c), gy, groups=c)

    mx, my = blur(x), blur(y)
    vx = blur(x * x) - mx * mx
    vy = blur(y * y) - my * my
    vxy = blur(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    s = ((2 * mx * my + c1) * (2 * vxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return s.mean()


def dark_channel(x: torch.Tensor) -> torch.Tensor:
    """J: minimum over channels and a 17×17 window (edges: the window shrinks)."""
    m = x.min(dim=1, keepdim=True).values
    return -F.max_pool2d(-m, DARK_WINDOW, stride=1, padding=DARK_WINDOW // 2)


def loss_terms(target: torch.Tensor, perceived: torch.Tensor, display: torch.Tensor) -> dict:
    """The four terms, each a scalar tensor."""
    return {
        "l1": (target - perceived).abs().mean(),
        "ssim": 1 - ssim(target, perceived),
        "dark": (torch.exp(-BETA * dark_channel(target)) * dark_channel(perceived)).mean(),
        "range": (F.relu(display - 1) + F.relu(-display)).mean(),
    }


def total(terms: dict) -> torch.Tensor:
    return terms["l1"] + terms["ssim"] + ALPHA * terms["dark"] + GAMMA * terms["range"]
