"""The ``fast`` detector's network, :class:`SeedNet` (torch; training and export only, inference runs its ONNX).

CenterNet-style and fully convolutional: for every full-resolution pixel a seed-centre logit, the four distances
(px) from the pixel to the seed's box edges and the sub-pixel offset to its keypoint (``N_OUT`` = 7 channels). A
full-resolution stem (``c1`` channels), one stride-2 convolution to half resolution, two 3x3 layers there (``c2``
channels, the second dilated), a 1x1 lateral projection upsampled onto the stem's features and a full-resolution
head: the skip keeps box edges pixel-exact, which a 5 px seed needs for IoU >= 0.5. With ``c3 > 0`` a quarter-
resolution context stage (stride-2 convolution, two 3x3 layers dilated 2 and 4, ``c3`` channels) is added to the
half-resolution features before the lateral projection: it sees ~4x further, enough to tell a seed from one
repeat of a woven or printed background (the photo network; docs/method/detection.md).
"""

from __future__ import annotations

import numpy as np

#: output channels of the network: heat logit, l, t, r, b (px), dx, dy (px)
N_OUT = 7


def net_channels(weights: dict[str, np.ndarray]) -> tuple[int, int, int]:
    """``(c1, c2, c3)`` of a network's parameters by torch name (``c3`` 0 without the context stage)."""
    c3 = int(weights["down2.weight"].shape[0]) if "down2.weight" in weights else 0
    return int(weights["stem.weight"].shape[0]), int(weights["down.weight"].shape[0]), c3


def build_net(c1: int = 8, c2: int = 16, c3: int = 0):
    """The torch :class:`SeedNet` with ``c1`` / ``c2`` / ``c3`` channels at full / half / quarter resolution
    (``c3`` = 0: no quarter-resolution stage)."""
    import torch
    from torch import nn

    class SeedNet(nn.Module):
        """Full-res stem -> half-res body (3 convs, one dilated) [-> quarter-res context] -> upsample + skip ->
        full-res head."""

        def __init__(self) -> None:
            super().__init__()
            self.c1, self.c2, self.c3 = c1, c2, c3
            self.stem = nn.Conv2d(3, c1, 3, padding=1)
            self.down = nn.Conv2d(c1, c2, 3, stride=2, padding=1)
            self.mid1 = nn.Conv2d(c2, c2, 3, padding=1)
            self.mid2 = nn.Conv2d(c2, c2, 3, padding=2, dilation=2)
            if c3:
                self.down2 = nn.Conv2d(c2, c3, 3, stride=2, padding=1)
                self.ctx1 = nn.Conv2d(c3, c3, 3, padding=2, dilation=2)
                self.ctx2 = nn.Conv2d(c3, c3, 3, padding=4, dilation=4)
                self.lat2 = nn.Conv2d(c3, c2, 1)
            self.lat = nn.Conv2d(c2, c1, 1)
            self.fuse = nn.Conv2d(c1, c1, 3, padding=1)
            self.head = nn.Conv2d(c1, N_OUT, 1)
            with torch.no_grad():
                self.head.bias.zero_()
                self.head.bias[0] = -4.0  # CenterNet prior: few pixels are centres
                self.head.bias[1:5] = 2.0

        def forward(self, x):  # noqa: ANN001, ANN201
            r = torch.relu
            s = r(self.stem(x))
            h = r(self.down(s))
            h = r(self.mid1(h))
            h = r(self.mid2(h))
            if self.c3:
                q = r(self.ctx2(r(self.ctx1(r(self.down2(h))))))
                v = nn.functional.interpolate(self.lat2(q), scale_factor=2.0, mode="nearest")
                h = r(h + v[:, :, : h.shape[2], : h.shape[3]])
            u = nn.functional.interpolate(self.lat(h), scale_factor=2.0, mode="nearest")
            u = u[:, :, : s.shape[2], : s.shape[3]]
            f = r(self.fuse(r(s + u)))
            return self.head(f)

    return SeedNet()
