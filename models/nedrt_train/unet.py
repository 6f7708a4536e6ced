"""The D-CNN (docs/model.md §14): a residual U-Net, I_d = I + UNet(I). Encoder
levels of two 3×3 conv + ReLU (32, 64, 128, 256 channels by default) with
2×2 max-pooling between them; decoder levels of a 2×2 transposed conv, the
skip concatenated, two 3×3 conv + ReLU; a final 1×1 conv to 3 channels.
`width` scales the channels and `levels` sets the depth, for the reduced
models of the speed-against-accuracy chart. Inputs must have sides that are
multiples of 2^(levels−1) (8 by default); `forward_padded` reflects and crops.
"""
import torch
import torch.nn as nn
import torch.nn.functional as F


def _block(cin, cout):
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(cout, cout, 3, padding=1), nn.ReLU(inplace=True),
    )


class UNet(nn.Module):
    def __init__(self, width: int = 32, levels: int = 4, channels: int = 3):
        super().__init__()
        if levels < 1 or width < 1:
            raise ValueError("levels and width must be ≥ 1")
        widths = [width * 2 ** i for i in range(levels)]
        self.widths, self.levels = widths, levels
        self.down = nn.ModuleList()
        cin = channels
        for w in widths:
            self.down.append(_block(cin, w))
            cin = w
        self.up = nn.ModuleList()
        self.merge = nn.ModuleList()
        for w_hi, w_lo in zip(reversed(widths[1:]), reversed(widths[:-1])):
            self.up.append(nn.ConvTranspose2d(w_hi, w_lo, 2, stride=2))
            self.merge.append(_block(2 * w_lo, w_lo))
        self.out = nn.Conv2d(widths[0], channels, 1)

    @property
    def multiple(self) -> int:
        return 2 ** (self.levels - 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        h = x
        for i, block in enumerate(self.down):
            h = block(h)
            if i < self.levels - 1:
                skips.append(h)
                h = F.max_pool2d(h, 2)
        for up, merge in zip(self.up, self.merge):
            h = merge(torch.cat([skips.pop(), up(h)], dim=1))
        return x + self.out(h)

    def forward_padded(self, x: torch.Tensor) -> torch.Tensor:
        """Any size: reflect-pad to a multiple of 2^(levels−1), run, crop back."""
        h, w = x.shape[-2:]
        m = self.multiple
        ph, pw = (-h) % m, (-w) % m
        if ph or pw:
            x = F.pad(x, (0, pw, 0, ph), mode="reflect" if min(h, w) > max(ph, pw) else "replicate")
        return self(x)[..., :h, :w]

    def macs_per_pixel(self) -> int:
        """Multiply-adds per input pixel (convolutions only)."""
        total, scale = 0, 1.0
        cin = 3
        for i, w in enumerate(self.widths):
            total += scale * (9 * cin * w + 9 * w * w)
            cin = w
            if i < self.levels - 1:
                scale /= 4
        scale = 1 / 4 ** (self.levels - 1)
        for w_hi, w_lo in zip(reversed(self.widths[1:]), reversed(self.widths[:-1])):
            scale *= 4
            # 2×2 transposed conv: one tap per output pixel; then the merge block.
            total += scale * (w_hi * w_lo + 9 * 2 * w_lo * w_lo + 9 * w_lo * w_lo)
        return int(total + 3 * self.widths[0])
