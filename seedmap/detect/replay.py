"""Rehearsal images for a fine-tune: simulated grain photos whose crops are mixed with the user's.

A fine-tune on a handful of labelled photos sees one background, one light and one seed lot; on its own it forgets
what the starting network knew of everything else (other surfaces, look-alikes, lights) and fires on textures its
few images never showed. Mixing in crops of simulated photos of the training conditions (``seedmap simulate
photos``, rendered afresh from the training seed into a temporary folder) keeps that knowledge while the user's
crops adapt the network. Method and measured effect: docs/method/detection.md.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from seedmap.detect.cnn_targets import TrainImage, coco_image_targets
from seedmap.detect.labels import CocoSource
from seedmap.sim.photos import PhotoSimConfig, simulate_photos

#: simulated photos rendered for rehearsal (about 0.3 s each: small photos, the network sees them shrunk anyway)
REPLAY_PHOTOS = 40
#: their long side (px) and seed size range (px): both small, so that rendering stays cheap
REPLAY_LONG_SIDE = (320, 480)
REPLAY_SEED_PX = (6.0, 12.0)
#: random stream of the rehearsal photos (apart from the training seed's crop stream)
REPLAY_STREAM = 7


def replay_images(seed: int, net_seed_px: float, progress: bool = False, count: int = REPLAY_PHOTOS
                  ) -> list[TrainImage]:
    """``count`` simulated training-condition photos (drawn from ``seed``) with their targets, each resized so that
    its seeds measure ``net_seed_px``; every item has ``replay`` set."""
    cfg = PhotoSimConfig(seed=int(np.random.SeedSequence([seed, REPLAY_STREAM]).generate_state(1)[0]), count=count,
                         long_side=REPLAY_LONG_SIDE, seed_px=REPLAY_SEED_PX)
    items = []
    with tempfile.TemporaryDirectory(prefix="seedmap-replay-") as tmp:
        out = simulate_photos(cfg, Path(tmp) / "photos", progress=progress)
        src = CocoSource(out / "labels.json")
        for k in range(len(src)):
            own = src.seed_sides([k])
            size = float(np.median(own)) if len(own) else float(np.sqrt(np.prod(REPLAY_SEED_PX)))
            ti = coco_image_targets(src, k, float(net_seed_px) / size)
            ti.replay = True
            items.append(ti)
    return items
