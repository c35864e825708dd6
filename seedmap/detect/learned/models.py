"""The paper's networks: Faster R-CNN with a VGG16 backbone, and pix2pix (U-Net + PatchGAN).

Seeds are only 4–8 px across at the default 1434x1050 resolution, so the detector (the full-size ``paper``
preset; ``lite`` keeps three VGG16 blocks, stride 4, at the image's own scale: the same 4-px anchor spacing for a
fifth of the convolutions)

* cuts VGG16 after ``conv4_3`` (stride 8, 512 channels) instead of the usual stride-16 ``conv5_3``
  — one feature cell then spans about one seed;
* runs on the image upscaled by ``upscale`` (default 2: seeds 8–16 px);
* uses small anchors (default 8, 12, 16, 24 px on the upscaled image) with aspect ratios 0.5–2.

``width`` scales every VGG channel count (1.0 = exactly torchvision's ``vgg16().features``, built
with ``weights=None`` — nothing is downloaded); the tests and CPU smoke runs use a narrow network.

The segmenter is pix2pix: a U-Net generator maps a padded, resized box crop (3 x S x S, S = 32 by
default) to a 1-channel mask in [-1, 1]; a PatchGAN discriminator judges (crop, mask) pairs.
"""

from __future__ import annotations

import torch
from torch import nn

from pydantic import Field

from seedmap.config import ConfigModel

VGG16_CFG: list = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512]  # up to conv4_3 (stride 8)
#: where each kept block count cuts VGG16_CFG: 3 blocks = conv3_3 (stride 4), 4 = conv4_3 (stride 8)
VGG16_CUTS = {3: 9, 4: 13}


#: anchor aspect ratios of the region proposals
ASPECT_RATIOS = (0.5, 1.0, 2.0)
#: RoIAlign output size
ROI_OUTPUT = 7


class DetectorArch(ConfigModel):
    """Architecture of the Faster R-CNN detector (saved with the weights)."""

    #: scales every VGG16 channel count (1.0 = torchvision's vgg16)
    width: float = 1.0
    #: VGG16 blocks kept: 4 = up to conv4_3 (stride 8), 3 = up to conv3_3 (stride 4: one cell per seed at scale 1)
    blocks: int = Field(4, ge=3, le=4)
    #: batch normalisation after every VGG16 convolution (torchvision's vgg16_bn layout; folded away in ONNX)
    batch_norm: bool = False
    #: anchor sizes (px on the upscaled image)
    anchor_sizes: list[float] = [8.0, 12.0, 16.0, 24.0]
    #: the detector sees the image upscaled by this factor
    upscale: float = 2.0
    #: hidden width of the box head
    representation: int = 1024
    #: region proposals kept after NMS at inference
    rpn_post_nms_test: int = 4000
    #: at most this many detections per image
    max_detections: int = 3000


class SegmenterArch(ConfigModel):
    """Architecture of the pix2pix segmenter (saved with the weights)."""

    #: side (px) of the square box crops
    crop_size: int = 32
    #: U-Net generator base width
    ngf: int = 32
    #: PatchGAN discriminator base width
    ndf: int = 32


def vgg16_trunk(width: float = 1.0, blocks: int = 4, batch_norm: bool = False) -> nn.Sequential:
    """VGG16 ``conv1_1 .. relu4_3`` (stride 8; ``blocks=3``: ``.. relu3_3``, stride 4), with batch normalisation
    after each convolution when asked. ``width == 1``, four blocks and no batch norm is torchvision's own module."""
    if width == 1.0 and blocks == 4 and not batch_norm:
        from torchvision.models import vgg16

        return vgg16(weights=None).features[:23]
    from torchvision.models.vgg import make_layers

    cfg = [c if c == "M" else max(4, int(round(c * width))) for c in VGG16_CFG[:VGG16_CUTS[blocks]]]
    return make_layers(cfg, batch_norm=batch_norm)


def build_frcnn(arch: DetectorArch) -> nn.Module:
    """torchvision FasterRCNN (2 classes: background, seed) on the stride-8 VGG16 trunk."""
    from torchvision.models.detection import FasterRCNN
    from torchvision.models.detection.anchor_utils import AnchorGenerator
    from torchvision.ops import MultiScaleRoIAlign

    backbone = vgg16_trunk(arch.width, arch.blocks, arch.batch_norm)
    backbone.out_channels = [m for m in backbone if isinstance(m, nn.Conv2d)][-1].out_channels
    anchors = AnchorGenerator(sizes=(tuple(arch.anchor_sizes),), aspect_ratios=(ASPECT_RATIOS,))
    roi = MultiScaleRoIAlign(featmap_names=["0"], output_size=ROI_OUTPUT, sampling_ratio=2)
    from torchvision.models.detection.faster_rcnn import FastRCNNPredictor, TwoMLPHead

    head = TwoMLPHead(backbone.out_channels * ROI_OUTPUT**2, arch.representation)
    model = FasterRCNN(
        backbone, num_classes=None, rpn_anchor_generator=anchors, box_roi_pool=roi, box_head=head,
        box_predictor=FastRCNNPredictor(arch.representation, 2),
        min_size=800, max_size=100000,  # replaced per call: see LearnedDetector / training (upscale)
        rpn_pre_nms_top_n_train=6000, rpn_post_nms_top_n_train=4000,
        rpn_pre_nms_top_n_test=8000, rpn_post_nms_top_n_test=arch.rpn_post_nms_test,
        rpn_batch_size_per_image=256, box_batch_size_per_image=512,
        box_detections_per_img=arch.max_detections, box_nms_thresh=0.3, box_score_thresh=0.05,
    )
    return model


def set_input_scale(model: nn.Module, height: int, width: int, upscale: float) -> None:
    """Make torchvision's transform resize an ``height x width`` image by exactly ``upscale``."""
    short = min(height, width)
    model.transform.min_size = (int(round(short * upscale)),)
    model.transform.max_size = int(round(max(height, width) * upscale)) + 1


def _down(cin: int, cout: int, norm: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = [nn.Conv2d(cin, cout, 4, 2, 1, bias=not norm)]
    if norm:
        layers.append(nn.BatchNorm2d(cout))
    layers.append(nn.LeakyReLU(0.2, inplace=True))
    return nn.Sequential(*layers)


def _up(cin: int, cout: int, dropout: bool = False) -> nn.Sequential:
    layers: list[nn.Module] = [nn.ConvTranspose2d(cin, cout, 4, 2, 1, bias=False), nn.BatchNorm2d(cout)]
    if dropout:
        layers.append(nn.Dropout(0.5))
    layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class UNetGenerator(nn.Module):
    """pix2pix U-Net: ``log2(S) - 1`` stride-2 levels down to 2x2, skip connections, tanh output."""

    def __init__(self, crop_size: int = 32, ngf: int = 32, in_ch: int = 3, out_ch: int = 1) -> None:
        super().__init__()
        n = max(2, int(round(torch.log2(torch.tensor(float(crop_size))).item())) - 1)
        chans = [min(ngf * 2**i, ngf * 8) for i in range(n)]
        self.downs = nn.ModuleList([_down(in_ch if i == 0 else chans[i - 1], chans[i], norm=i > 0) for i in range(n)])
        ups = []
        for i in reversed(range(1, n)):
            cin = chans[i] if i == n - 1 else chans[i] * 2
            ups.append(_up(cin, chans[i - 1], dropout=i >= n - 2 and n > 3))
        self.ups = nn.ModuleList(ups)
        self.out = nn.Sequential(nn.ConvTranspose2d(chans[0] * 2, out_ch, 4, 2, 1), nn.Tanh())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for d in self.downs:
            x = d(x)
            skips.append(x)
        skips.pop()
        for u in self.ups:
            x = u(x)
            x = torch.cat([x, skips.pop()], dim=1)
        return self.out(x)


class PatchDiscriminator(nn.Module):
    """PatchGAN: logits per overlapping patch of a (crop, mask) pair."""

    def __init__(self, ndf: int = 32, in_ch: int = 4) -> None:
        super().__init__()
        self.net = nn.Sequential(
            _down(in_ch, ndf, norm=False), _down(ndf, ndf * 2), _down(ndf * 2, ndf * 4),
            nn.Conv2d(ndf * 4, ndf * 4, 3, 1, 1, bias=False), nn.BatchNorm2d(ndf * 4), nn.LeakyReLU(0.2, True),
            nn.Conv2d(ndf * 4, 1, 3, 1, 1),
        )

    def forward(self, crop: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([crop, mask], dim=1))
