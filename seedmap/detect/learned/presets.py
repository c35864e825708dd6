"""Named training recipes of the Faster R-CNN + pix2pix pipeline (``seedmap train detector|segmenter --preset``).

A preset is a partial training config applied first; a ``--config`` file and ``--set`` overrides go on top.

* ``paper`` — the paper's networks at full size: torchvision's VGG16 (``conv1_1 .. conv4_3``, stride 8) on the
  image upscaled 2x, anchors 8–24 px, a 1024-wide box head, the pix2pix U-Net + PatchGAN at 32 base channels.
  These are the training configs' own defaults.
* ``lite`` — the same pipeline made trainable on a CPU (``frcnn-pix2pix-lite``): every VGG16 width x 0.25, three
  VGG16 blocks (up to ``conv3_3``, stride 4) on the image at its own scale, so the anchors (4–12 px) lie 4 px apart
  as the paper preset's do on its 2x image; batch normalisation after each convolution (vgg16_bn); a 256-wide box
  head; only seeds with 10 or more visible pixels as targets; 128-px crops with 2,000 proposals, 128 sampled for
  the box loss, those of IoU 0.3–0.5 with a seed left out of it; one torch thread; the U-Net and PatchGAN at 16
  base channels.

The recipes the shipped ``frcnn-pix2pix-lite`` weights were trained with, and the measured time per step, are in
``docs/method/detection.md``.
"""

from __future__ import annotations

from seedmap.errors import SeedmapError

DETECTOR_PRESETS: dict[str, dict] = {
    "paper": {},
    "lite": {
        "steps": 2000, "batch_size": 2, "lr": 5e-4, "crop": 128, "min_gt_area": 10, "box_batch": 128,
        "box_bg_iou": 0.3,
        "rpn_pre_nms": 2000,
        "rpn_post_nms": 2000, "threads": 1,
        "arch": {"width": 0.25, "blocks": 3, "batch_norm": True, "upscale": 1.0, "anchor_sizes": [4.0, 6.0, 8.0, 12.0],
                 "representation": 256},
    },
}

SEGMENTER_PRESETS: dict[str, dict] = {
    "paper": {},
    "lite": {"steps": 1500, "batch_size": 64, "threads": 1, "arch": {"ngf": 16, "ndf": 16}},
}


def preset(kind: str, name: str | None) -> dict:
    """The partial config of preset ``name`` for ``kind`` (``detector`` | ``segmenter``); ``{}`` for None."""
    if name is None:
        return {}
    table = DETECTOR_PRESETS if kind == "detector" else SEGMENTER_PRESETS
    if name not in table:
        raise SeedmapError(f"unknown {kind} preset {name!r} (known: {', '.join(table)})")
    return dict(table[name])
