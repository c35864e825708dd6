"""Facts about the shipped networks that several tests check against."""

from __future__ import annotations

from seedmap.detect.cnn import default_cnn_path
from seedmap.detect.config import TRAINED_SEED_PX
from seedmap.detect.train_validate import network_seed_px

#: the seed size (px) the shipped photo network declares it runs at
PHOTO_SEED_PX = network_seed_px(default_cnn_path("photo"), TRAINED_SEED_PX["photo"])
